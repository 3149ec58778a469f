//! Scenario-file configuration of the transfer-alignment scenarios (units in the key names).
use anyhow::{bail, Context as _, Result};
use nalgebra::Vector3;
use nav_core::transfer_alignment::{AxisFlexure, PaperCase, TaConfig};
use nav_core::Gate;
use serde::Deserialize;

/// Standard gravity used for "1 g" (accelerations and biases configured in g, µg), m/s².
pub const G0_M_S2: f64 = 9.80665;

/// Truth flexure model.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum TruthModel {
    /// 3rd-order Gauss-Markov (default; smooth θ̈_f).
    Markov3,
    /// 2nd-order Gauss-Markov (Schneider; θ̈_f is white).
    Markov2,
    /// Lightly damped wing-bending mode driven by 1st-order Markov turbulence.
    Bending,
}

/// Truth flexure.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FlexureTruthConfig {
    /// Model.
    pub model: TruthModel,
    /// Stationary 1σ of θ_f per axis X, Y, Z, deg.
    pub sigma_deg: [f64; 3],
    /// Correlation time per axis (Markov models), s.
    pub tau_s: [f64; 3],
    /// Bending-mode natural frequency per axis (bending model), Hz.
    #[serde(default = "default_bending_hz")]
    pub bending_frequency_hz: [f64; 3],
    /// Bending-mode damping ratio ζ (bending model), dimensionless.
    #[serde(default = "default_zeta")]
    pub bending_damping_ratio: f64,
    /// Correlation time of the turbulence forcing the bending mode, s.
    #[serde(default = "default_turb_tau")]
    pub turbulence_tau_s: f64,
}

fn default_bending_hz() -> [f64; 3] {
    [3.0, 5.0, 5.0]
}
fn default_zeta() -> f64 {
    0.03
}
fn default_turb_tau() -> f64 {
    0.2
}

/// IMU error model (1σ; noise densities and random-constant biases).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    /// Gyro angle random walk, deg/√h.
    pub gyro_arw_deg_rt_h: f64,
    /// Gyro random-constant bias 1σ, deg/h.
    pub gyro_bias_deg_h: f64,
    /// Accelerometer white-noise density, µg/√Hz.
    pub accel_noise_ug_rt_hz: f64,
    /// Accelerometer random-constant bias 1σ, µg.
    pub accel_bias_ug: f64,
}

impl ImuConfig {
    /// 1σ of one gyro sample over `dt_s`: ARW / √Δt, rad/s.
    pub fn gyro_sigma_per_sample_rad_s(&self, dt_s: f64) -> f64 {
        self.gyro_arw_deg_rt_h.to_radians() / 60.0 / dt_s.sqrt()
    }
    /// 1σ of one accelerometer sample over `dt_s`: density / √Δt, m/s².
    pub fn accel_sigma_per_sample_m_s2(&self, dt_s: f64) -> f64 {
        self.accel_noise_ug_rt_hz * 1e-6 * G0_M_S2 / dt_s.sqrt()
    }
}

/// One segment of the master trajectory (constant body acceleration and body rate).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileSegment {
    /// Segment length, s (the last segment lasts to the end of the run).
    pub duration_s: f64,
    /// Kinematic acceleration in master body axes, g (9.80665 m/s²).
    #[serde(default)]
    pub accel_g: [f64; 3],
    /// Body angular rate relative to NED, master body axes, deg/s.
    #[serde(default)]
    pub angular_rate_deg_s: [f64; 3],
}

/// The filters' flexure model and tuning (defaults: the truth's σ and τ).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    /// Flexure 1σ per axis, deg (default: truth).
    pub sigma_deg: Option<[f64; 3]>,
    /// Flexure correlation time per axis, s (default: truth).
    pub tau_s: Option<[f64; 3]>,
    /// χ²(1) NIS gate per scalar update (absent: no gate); the key every scenario file uses
    /// (`nis_gate`, its former spelling, still read).
    #[serde(alias = "nis_gate")]
    pub gate_nis: Option<f64>,
}

/// Configuration of `ta-case` (and the base of `ta-model-error`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CaseConfig {
    /// IMU and filter step, s.
    pub dt_s: f64,
    /// Run length, s.
    pub duration_s: f64,
    /// Latitude, deg (earth rate, gravity).
    pub latitude_deg: f64,
    /// Altitude, m.
    pub altitude_m: f64,
    /// Nominal lever arm L_0 (master axes), m.
    pub lever_arm_m: [f64; 3],
    /// Mounting misalignment 1σ per axis, deg (truth draw and filter P0).
    pub mount_sigma_deg: [f64; 3],
    /// Truth flexure.
    pub truth_flexure: FlexureTruthConfig,
    /// Filter model.
    #[serde(default)]
    pub filter: FilterConfig,
    /// Master IMU (navigation grade).
    pub master_imu: ImuConfig,
    /// Slave IMU (tactical grade).
    pub slave_imu: ImuConfig,
    /// Master trajectory.
    pub profile: Vec<ProfileSegment>,
    /// Float type the filters run in (`"f64"` default, `"f32"` as on the target).
    #[serde(default)]
    pub precision: Precision,
}

/// Float type of the filters.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// f32 (target).
    F32,
    /// f64 (host).
    #[default]
    F64,
}

impl CaseConfig {
    /// Checks ranges the types cannot express.
    pub fn check(&self) -> Result<()> {
        if !(self.dt_s > 0.0 && self.duration_s >= self.dt_s) {
            bail!("dt_s and duration_s must be positive with duration_s ≥ dt_s");
        }
        if self.profile.is_empty()
            || self
                .profile
                .iter()
                .any(|s| s.duration_s.is_nan() || s.duration_s <= 0.0)
        {
            bail!("profile: at least one segment, each with duration_s > 0");
        }
        Ok(())
    }

    /// Profile segment at time `t_s`.
    pub fn segment_at(&self, t_s: f64) -> &ProfileSegment {
        let mut start = 0.0;
        for s in &self.profile {
            if t_s < start + s.duration_s - 1e-9 {
                return s;
            }
            start += s.duration_s;
        }
        &self.profile[self.profile.len() - 1]
    }

    /// Start and end time of the first segment with a non-zero acceleration or rate (the
    /// manoeuvre), s.
    pub fn manoeuvre_window_s(&self) -> Option<(f64, f64)> {
        let mut start = 0.0;
        for s in &self.profile {
            let moving = s
                .accel_g
                .iter()
                .chain(&s.angular_rate_deg_s)
                .any(|v| *v != 0.0);
            if moving {
                return Some((start, start + s.duration_s));
            }
            start += s.duration_s;
        }
        None
    }

    /// Filter configuration (f64) with the filter's τ scaled by `1 + tau_error_pct/100`: the
    /// scenario's lever arm, flexure, mount σ, noise (master and slave per sample, combined),
    /// the specific-force-difference bias 1σ of the flight configuration (master and slave
    /// accelerometer bias σ, combined: the IMUs' specification, used by the flight filter only)
    /// and step, pairing tolerance 0.1 `dt_s`, the gate of `[filter] gate_nis` (absent: off), and
    /// the paper configuration's gap bridging and recovery policy ([`TaConfig::paper`]).
    pub fn filter_config(&self, tau_error_pct: f64) -> TaConfig<f64> {
        let sigma = self
            .filter
            .sigma_deg
            .unwrap_or(self.truth_flexure.sigma_deg);
        let tau = self.filter.tau_s.unwrap_or(self.truth_flexure.tau_s);
        let scale = 1.0 + tau_error_pct / 100.0;
        let ax = |i: usize| AxisFlexure {
            sigma_rad: sigma[i].to_radians(),
            tau_s: tau[i] * scale,
        };
        let rate = (self
            .master_imu
            .gyro_sigma_per_sample_rad_s(self.dt_s)
            .powi(2)
            + self
                .slave_imu
                .gyro_sigma_per_sample_rad_s(self.dt_s)
                .powi(2))
        .sqrt();
        let accel = (self
            .master_imu
            .accel_sigma_per_sample_m_s2(self.dt_s)
            .powi(2)
            + self
                .slave_imu
                .accel_sigma_per_sample_m_s2(self.dt_s)
                .powi(2))
        .sqrt();
        let accel_bias =
            (self.master_imu.accel_bias_ug.powi(2) + self.slave_imu.accel_bias_ug.powi(2)).sqrt()
                * 1e-6
                * G0_M_S2;
        TaConfig {
            lever_arm_m: Vector3::from(self.lever_arm_m),
            flexure: [ax(0), ax(1), ax(2)],
            mount_sigma_rad: Vector3::from(self.mount_sigma_deg).map(f64::to_radians),
            rate_noise_sigma_rad_s: rate,
            accel_noise_sigma_m_s2: accel,
            accel_bias_sigma_m_s2: Vector3::repeat(accel_bias),
            dt_s: self.dt_s,
            time_tolerance_s: 0.1 * self.dt_s,
            gate: self.filter.gate_nis.map_or(Gate::Off, Gate::Nis),
            ..TaConfig::paper(PaperCase::Case2)
        }
    }
}

/// Reads a shipped scenario file's kind-specific keys (for tests and tools).
pub fn load_scenario<T: serde::de::DeserializeOwned>(name: &str) -> Result<(T, usize, u64)> {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let text =
        std::fs::read_to_string(&path).with_context(|| format!("reading {}", path.display()))?;
    let mut doc: toml::Table = toml::from_str(&text)?;
    let runs = doc.get("runs").and_then(|v| v.as_integer()).unwrap_or(1) as usize;
    let seed = doc.get("seed").and_then(|v| v.as_integer()).unwrap_or(0) as u64;
    for key in ["kind", "description", "runs", "seed"] {
        doc.remove(key);
    }
    let cfg = T::deserialize(toml::Value::Table(doc))?;
    Ok((cfg, runs, seed))
}

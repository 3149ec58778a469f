//! Vertical channel damping (spec `vertical-channel.md`): the classical 3rd-order baro-inertial
//! loop against the velocity-aided loop with Riccati-designed gains.
//!
//! Kinds:
//! * `vc-response` (seed Fig. 3): one run; altitude and vertical-velocity response and error of
//!   both loops; `settle_time_s` on a noise-free twin (same profile and initial errors, sensor
//!   noise, biases and correlated errors off, baro lag kept).
//! * `vc-montecarlo` (seed Fig. 4): RMSE over runs vs time of h and V_z for both loops.
//! * `vc-tau-sweep`: the classical loop's τ swept (Monte Carlo RMSE and noise-free settle time),
//!   with the aided loop as the reference.
//!
//! Truth: piecewise-constant vertical acceleration (level / climb / level / descend / level,
//! with acceleration ramps). Sensors: vertical specific force with a random-constant bias and
//! white noise (true normal gravity with its altitude dependence); barometric altitude at its own
//! rate = first-order lag of the true altitude + 1st-order Gauss-Markov error + white noise;
//! vertical-velocity aid at its own rate with white noise. Optional aid dropouts.

//!
//! Files: `truth` (the flight profile), `sensors` (accelerometer, baro, velocity aid), `run`
//! (the loops over one run, Monte Carlo), `report` (the kinds' figures and summaries).

mod campaign;
mod report;
mod run;
pub(crate) mod sensors;
mod truth;

pub use campaign::{draw_variant, fly_variant, CAMPAIGN, CAMPAIGN_CLASSICAL, VARIANT_DURATION_S};
pub use run::{
    error_model, loop_configs, monte_carlo_rmse, nees_h_vz, one_run, push_consistency, simulate,
    McResult, RunOut, AXES, FILTERS,
};
pub use sensors::Noise;
pub use truth::Profile;

use crate::scenario::Kind;
use anyhow::{ensure, Result};
use report::{run_montecarlo, run_response, run_tau_sweep};
use serde::Deserialize;

/// `vc-response`.
pub const KIND_RESPONSE: Kind = Kind {
    kind: "vc-response",
    about: "vertical channel, Fig. 3: response and error of the classical and velocity-aided loops",
    run: run_response,
};
/// `vc-montecarlo`.
pub const KIND_MONTECARLO: Kind = Kind {
    kind: "vc-montecarlo",
    about: "vertical channel, Fig. 4: Monte Carlo RMSE vs time of h and V_z, both loops",
    run: run_montecarlo,
};
/// `vc-tau-sweep`.
pub const KIND_TAU_SWEEP: Kind = Kind {
    kind: "vc-tau-sweep",
    about: "vertical channel: classical loop time constant τ swept (RMSE, settle time)",
    run: run_tau_sweep,
};

/// Scenario configuration (shared by the three kinds).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// IMU (and loop) rate, Hz.
    pub imu_rate_hz: f64,
    /// Geodetic latitude, deg.
    pub latitude_deg: f64,
    /// Run length, s.
    pub duration_s: f64,
    /// Summary RMSE excludes the first this-many seconds, s.
    pub rmse_after_s: f64,
    /// Time-series output interval (CSV/plots), s.
    pub output_interval_s: f64,
    /// Loop arithmetic: "f32" (target) or "f64".
    pub precision: String,
    /// Flight profile.
    pub profile: ProfileConfig,
    /// Vertical accelerometer.
    pub imu: ImuConfig,
    /// Barometric altimeter.
    pub baro: BaroConfig,
    /// Vertical-velocity aid.
    pub velocity_aid: VelocityAidConfig,
    /// Initial estimation errors.
    pub initial_error: InitialErrorConfig,
    /// Classical loop design.
    pub classical: ClassicalDesign,
    /// Velocity-aided loop design.
    pub aided: AidedDesign,
    /// Aid dropouts (none by default).
    #[serde(default)]
    pub dropout: Vec<Dropout>,
    /// τ values of the classical loop for `vc-tau-sweep`, s.
    #[serde(default)]
    pub tau_sweep_s: Vec<f64>,
    /// Accelerometer noise densities assumed in the aided loop's Riccati design, swept by
    /// `vc-tau-sweep` as a sensitivity study (m/s²/√Hz); empty = no aided sweep.
    #[serde(default)]
    pub aided_design_sweep_m_s2_rt_hz: Vec<f64>,
}

/// Flight profile: legs flown in order.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProfileConfig {
    /// Start altitude, m.
    pub initial_altitude_m: f64,
    /// Magnitude of the vertical acceleration used to change the climb rate, m/s².
    pub accel_m_s2: f64,
    /// Legs.
    pub legs: Vec<Leg>,
}

/// One leg: a level hold or a climb/descent to an altitude at a rate.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Leg {
    /// Level flight for this long, s.
    #[serde(default)]
    pub hold_s: Option<f64>,
    /// Climb or descend to this altitude, m.
    #[serde(default)]
    pub to_altitude_m: Option<f64>,
    /// Vertical speed magnitude of the climb/descent, m/s.
    #[serde(default)]
    pub rate_m_s: Option<f64>,
}

/// Vertical accelerometer truth.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ImuConfig {
    /// Random-constant bias, 1σ, mg (1 mg = 9.80665e-3 m/s²).
    pub bias_sigma_mg: f64,
    /// White-noise density (σ), m/s²/√Hz.
    pub noise_m_s2_rt_hz: f64,
}

/// Barometric altimeter truth.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BaroConfig {
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// White noise per sample, 1σ, m.
    pub noise_m: f64,
    /// 1st-order Gauss-Markov correlated error, 1σ, m.
    pub markov_sigma_m: f64,
    /// Its correlation time, s.
    pub markov_tau_s: f64,
    /// First-order lag time constant, s.
    pub lag_s: f64,
}

/// Vertical-velocity aid truth.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VelocityAidConfig {
    /// Sample rate, Hz.
    pub rate_hz: f64,
    /// White noise per sample, 1σ, m/s.
    pub noise_m_s: f64,
}

/// Initial errors of both loops (estimate − truth).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialErrorConfig {
    /// Altitude error, m (the value, or 1σ when `gaussian`).
    pub altitude_m: f64,
    /// Vertical velocity error, m/s (the value, or 1σ when `gaussian`).
    pub vz_m_s: f64,
    /// "fixed" (the values) or "gaussian" (drawn per run with these σ).
    pub mode: String,
}

/// Classical loop design.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ClassicalDesign {
    /// Triple-pole time constant τ, s.
    pub tau_s: f64,
    /// C4, the altimeter lag compensation, s.
    pub lag_compensation_s: f64,
}

/// Velocity-aided loop design (the other noise parameters are the sensors').
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AidedDesign {
    /// Accelerometer bias random-walk density assumed in the design (σ), m/s²/√s.
    pub accel_bias_rw_m_s2_rt_s: f64,
    /// Altimeter lag compensation, s.
    pub lag_compensation_s: f64,
    /// Accelerometer white-noise density assumed in the design (σ), m/s²/√Hz; default: the
    /// simulated IMU's `imu.noise_m_s2_rt_hz` (a faithful design).
    #[serde(default)]
    pub accel_noise_design_m_s2_rt_hz: Option<f64>,
}

/// An aid outage.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Dropout {
    /// "baro" or "velocity".
    pub aid: String,
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
}

/// Loads the kind-specific configuration of a shipped scenario file (e.g. `"vc-montecarlo"`),
/// for tests and tools.
pub fn load_config(name: &str) -> Result<Config> {
    let (_, path) = crate::scenario::resolve(name, &crate::scenario::default_scenario_dir())?;
    let text = std::fs::read_to_string(&path)?;
    let mut doc: toml::Table = toml::from_str(&text)?;
    for key in ["kind", "description", "runs", "seed"] {
        doc.remove(key);
    }
    Ok(Config::deserialize(toml::Value::Table(doc))?)
}

/// One milli-g, m/s².
pub(crate) const MG: f64 = 9.806_65e-3;

pub(crate) fn validate(cfg: &Config) -> Result<()> {
    ensure!(cfg.imu_rate_hz > 0.0, "imu_rate_hz must be positive");
    ensure!(
        cfg.duration_s > cfg.rmse_after_s,
        "duration_s ≤ rmse_after_s"
    );
    ensure!(
        cfg.precision == "f32" || cfg.precision == "f64",
        "precision must be \"f32\" or \"f64\""
    );
    ensure!(
        cfg.initial_error.mode == "fixed" || cfg.initial_error.mode == "gaussian",
        "initial_error.mode must be \"fixed\" or \"gaussian\""
    );
    for d in &cfg.dropout {
        ensure!(
            d.aid == "baro" || d.aid == "velocity",
            "dropout.aid must be \"baro\" or \"velocity\""
        );
    }
    Ok(())
}

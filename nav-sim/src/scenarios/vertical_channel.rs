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

use crate::montecarlo::monte_carlo;
use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::rng::{normal, SimRng};
use crate::scenario::{Context, Kind};
use crate::stats::ensemble;
use anyhow::{anyhow, bail, ensure, Result};
use nav_core::earth::normal_gravity_m_s2;
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    AidTimeouts, AidedConfig, AidedLoop, BaroSample, ClassicalConfig, ClassicalLoop, ImuSample,
    InitialState, VelocitySample,
};
use nav_core::{Estimator, Real};
use serde::Deserialize;
use serde_json::{json, Value};

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

const MG: f64 = 9.806_65e-3;

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

/// Piecewise-constant-acceleration vertical truth.
#[derive(Debug, Clone)]
pub struct Profile {
    /// (start time s, start altitude m, start velocity m/s, acceleration m/s²).
    segments: Vec<(f64, f64, f64, f64)>,
}

impl Profile {
    /// Builds the profile from its legs.
    pub fn new(p: &ProfileConfig) -> Result<Self> {
        ensure!(p.accel_m_s2 > 0.0, "profile.accel_m_s2 must be positive");
        let mut segs = Vec::new();
        let (mut t, mut h) = (0.0, p.initial_altitude_m);
        for (i, leg) in p.legs.iter().enumerate() {
            match (leg.hold_s, leg.to_altitude_m, leg.rate_m_s) {
                (Some(d), None, None) => {
                    ensure!(d >= 0.0, "leg {i}: hold_s");
                    segs.push((t, h, 0.0, 0.0));
                    t += d;
                }
                (None, Some(target), Some(rate)) => {
                    ensure!(rate > 0.0, "leg {i}: rate_m_s");
                    let dh = target - h;
                    let s = dh.signum();
                    let ta = rate / p.accel_m_s2;
                    let ha = 0.5 * rate * ta;
                    ensure!(
                        dh.abs() >= 2.0 * ha,
                        "leg {i}: altitude change too small for the rate"
                    );
                    let tc = (dh.abs() - 2.0 * ha) / rate;
                    segs.push((t, h, 0.0, s * p.accel_m_s2));
                    segs.push((t + ta, h + s * ha, s * rate, 0.0));
                    segs.push((t + ta + tc, target - s * ha, s * rate, -s * p.accel_m_s2));
                    t += 2.0 * ta + tc;
                    h = target;
                }
                _ => bail!("leg {i}: either hold_s, or to_altitude_m with rate_m_s"),
            }
        }
        segs.push((t, h, 0.0, 0.0));
        Ok(Self { segments: segs })
    }

    /// (altitude m, vertical velocity m/s, acceleration m/s²) at time t.
    pub fn at(&self, t: f64) -> (f64, f64, f64) {
        let seg = self
            .segments
            .iter()
            .rev()
            .find(|s| s.0 <= t)
            .unwrap_or(&self.segments[0]);
        let dt = t - seg.0;
        (
            seg.1 + seg.2 * dt + 0.5 * seg.3 * dt * dt,
            seg.2 + seg.3 * dt,
            seg.3,
        )
    }
}

/// Series and statistics of one run.
#[derive(Debug, Clone, Default)]
pub struct RunOut {
    /// Output epochs, s.
    pub t: Vec<f64>,
    /// True altitude, m.
    pub h_true: Vec<f64>,
    /// True vertical velocity, m/s.
    pub vz_true: Vec<f64>,
    /// Latest baro sample, m.
    pub h_baro: Vec<f64>,
    /// Estimates [classical, aided].
    pub h_est: [Vec<f64>; 2],
    /// Vertical velocity estimates [classical, aided].
    pub vz_est: [Vec<f64>; 2],
    /// Altitude errors (estimate − truth) [classical, aided].
    pub err_h: [Vec<f64>; 2],
    /// Vertical velocity errors [classical, aided].
    pub err_vz: [Vec<f64>; 2],
    /// Σ err² at the IMU rate after `rmse_after_s`: [loop][h, vz].
    pub sumsq: [[f64; 2]; 2],
    /// Number of samples in `sumsq`.
    pub n: usize,
    /// Settle time (|err_h| ≤ 1 m from then to the end), per loop.
    pub settle_s: [Option<f64>; 2],
}

/// Sensor switches of a run.
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    /// Sensor noise, biases and correlated errors on.
    pub on: bool,
}

fn in_dropout(cfg: &Config, aid: &str, t: f64) -> bool {
    cfg.dropout
        .iter()
        .any(|d| d.aid == aid && t >= d.start_s && t < d.end_s)
}

/// Builds the nav-core loop configurations in the loops' float type (no gate; the aid
/// model and recovery of the papers' configuration).
pub fn loop_configs<T: Real>(cfg: &Config, tau_s: f64) -> (ClassicalConfig<T>, AidedConfig<T>) {
    let dt = 1.0 / cfg.imu_rate_hz;
    let baro_period = 1.0 / cfg.baro.rate_hz;
    let vel_period = 1.0 / cfg.velocity_aid.rate_hz;
    let baro_timeouts = AidTimeouts {
        stale_after_s: T::lit(1.5 * baro_period),
        lost_after_s: T::lit(0.5),
    };
    let vel_timeouts = AidTimeouts {
        stale_after_s: T::lit(1.5 * vel_period),
        lost_after_s: T::lit(1.0),
    };
    let lat = T::lit(cfg.latitude_deg.to_radians());
    (
        ClassicalConfig {
            imu_dt_s: T::lit(dt),
            latitude_rad: lat,
            tau_s: T::lit(tau_s),
            baro_lag_s: T::lit(cfg.classical.lag_compensation_s),
            baro_period_s: T::lit(baro_period),
            baro_timeouts,
            ..ClassicalConfig::paper()
        },
        AidedConfig {
            imu_dt_s: T::lit(dt),
            latitude_rad: lat,
            accel_noise_m_s2_rt_hz: T::lit(
                cfg.aided
                    .accel_noise_design_m_s2_rt_hz
                    .unwrap_or(cfg.imu.noise_m_s2_rt_hz),
            ),
            accel_bias_rw_m_s2_rt_s: T::lit(cfg.aided.accel_bias_rw_m_s2_rt_s),
            baro_noise_m: T::lit(cfg.baro.noise_m),
            baro_period_s: T::lit(baro_period),
            baro_lag_s: T::lit(cfg.aided.lag_compensation_s),
            velocity_noise_m_s: T::lit(cfg.velocity_aid.noise_m_s),
            velocity_period_s: T::lit(vel_period),
            baro_timeouts,
            velocity_timeouts: vel_timeouts,
            ..AidedConfig::paper()
        },
    )
}

fn ratio(a: f64, b: f64, what: &str) -> Result<usize> {
    let r = a / b;
    let n = r.round();
    ensure!(
        n >= 1.0 && (r - n).abs() < 1e-6,
        "{what}: must be an integer multiple of the IMU interval"
    );
    Ok(n as usize)
}

/// Simulates one run of both loops. `init_err` = (altitude m, vz m/s) estimate − truth.
pub fn simulate<T: Real>(
    cfg: &Config,
    profile: &Profile,
    tau_s: f64,
    init_err: (f64, f64),
    noise: Noise,
    rng: &mut SimRng,
) -> Result<RunOut> {
    let dt = 1.0 / cfg.imu_rate_hz;
    let steps = (cfg.duration_s / dt).round() as usize;
    let baro_every = ratio(cfg.imu_rate_hz, cfg.baro.rate_hz, "baro.rate_hz")?;
    let vel_every = ratio(
        cfg.imu_rate_hz,
        cfg.velocity_aid.rate_hz,
        "velocity_aid.rate_hz",
    )?;
    let out_every = ratio(cfg.output_interval_s, dt, "output_interval_s")?;
    let rmse_from = (cfg.rmse_after_s / dt).round() as usize;
    let lat = cfg.latitude_deg.to_radians();
    let (ccfg, acfg) = loop_configs::<T>(cfg, tau_s);
    let (h0, v0, _) = profile.at(0.0);
    let init = InitialState {
        time: Timestamp::ZERO,
        altitude_m: T::lit(h0 + init_err.0),
        vz_up_m_s: T::lit(v0 + init_err.1),
        accel_bias_m_s2: T::zero(),
    };
    let mut classical = ClassicalLoop::<T>::new(&ccfg, &init).map_err(|e| anyhow!("{e}"))?;
    let mut aided = AidedLoop::<T>::new(&acfg, &init).map_err(|e| anyhow!("{e}"))?;

    // Sensor error states.
    let bias = if noise.on {
        normal(rng, cfg.imu.bias_sigma_mg * MG)
    } else {
        0.0
    };
    let sigma_f = cfg.imu.noise_m_s2_rt_hz / dt.sqrt();
    let tb = baro_every as f64 * dt;
    let rho = (-tb / cfg.baro.markov_tau_s).exp();
    let markov_drive = cfg.baro.markov_sigma_m * (1.0 - rho * rho).sqrt();
    let mut markov = if noise.on {
        normal(rng, cfg.baro.markov_sigma_m)
    } else {
        0.0
    };
    let lag = cfg.baro.lag_s;
    let mut z_lag = h0 - lag * v0;
    let mut last_baro = f64::NAN;

    let mut out = RunOut::default();
    let mut last_big = [Some(0.0f64); 2]; // time after the last |err| > 1 m
    let (mut h_prev, mut v_prev, _) = profile.at(0.0);
    for k in 1..=steps {
        let t = k as f64 * dt;
        let stamp = Timestamp::from_secs_f64(t).map_err(|e| anyhow!("time stamp {t}: {e}"))?;
        let (h, v, _) = profile.at(t);
        // Mean specific force over the interval: Δv/Δt + g at mid-interval altitude.
        let (h_mid, _, _) = profile.at(t - 0.5 * dt);
        let mut f = (v - v_prev) / dt + normal_gravity_m_s2(lat, h_mid);
        if noise.on {
            f += bias + normal(rng, sigma_f);
        }
        // Baro lag: exact response of a first-order lag to the linear altitude ramp.
        if lag > 0.0 {
            let slope = (h - h_prev) / dt;
            let e = (-dt / lag).exp();
            z_lag = h - slope * lag + (z_lag - h_prev + slope * lag) * e;
        } else {
            z_lag = h;
        }
        let baro = if k % baro_every == 0 {
            if noise.on {
                markov = rho * markov + normal(rng, markov_drive);
            }
            let white = if noise.on {
                normal(rng, cfg.baro.noise_m)
            } else {
                0.0
            };
            let z = z_lag + markov + white;
            last_baro = z;
            (!in_dropout(cfg, "baro", t)).then_some(BaroSample {
                time: stamp,
                altitude_m: T::lit(z),
            })
        } else {
            None
        };
        let vel = if k % vel_every == 0 {
            let white = if noise.on {
                normal(rng, cfg.velocity_aid.noise_m_s)
            } else {
                0.0
            };
            (!in_dropout(cfg, "velocity", t)).then_some(VelocitySample {
                time: stamp,
                vz_up_m_s: T::lit(v + white),
            })
        } else {
            None
        };
        let imu = ImuSample {
            time: stamp,
            specific_force_up_m_s2: T::lit(f),
        };
        classical
            .step(&imu, baro.as_ref())
            .map_err(|e| anyhow!("classical loop at t = {t}: {e}"))?;
        aided
            .step(&imu, baro.as_ref(), vel.as_ref())
            .map_err(|e| anyhow!("aided loop at t = {t}: {e}"))?;
        let est = [
            (
                classical.altitude_m().to_f64(),
                classical.vz_up_m_s().to_f64(),
            ),
            (aided.altitude_m().to_f64(), aided.vz_up_m_s().to_f64()),
        ];
        for (l, (eh, ev)) in est.iter().enumerate() {
            let (dh, dv) = (eh - h, ev - v);
            if dh.abs() > 1.0 {
                last_big[l] = None;
            } else if last_big[l].is_none() {
                last_big[l] = Some(t);
            }
            if k >= rmse_from {
                out.sumsq[l][0] += dh * dh;
                out.sumsq[l][1] += dv * dv;
            }
        }
        if k >= rmse_from {
            out.n += 1;
        }
        if k % out_every == 0 {
            out.t.push(t);
            out.h_true.push(h);
            out.vz_true.push(v);
            out.h_baro.push(last_baro);
            for (l, (eh, ev)) in est.iter().enumerate() {
                out.h_est[l].push(*eh);
                out.vz_est[l].push(*ev);
                out.err_h[l].push(eh - h);
                out.err_vz[l].push(ev - v);
            }
        }
        h_prev = h;
        v_prev = v;
    }
    out.settle_s = last_big;
    Ok(out)
}

fn validate(cfg: &Config) -> Result<()> {
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

/// One run (noisy and, when asked, its noise-free twin) in the configured precision.
pub fn one_run(
    cfg: &Config,
    profile: &Profile,
    tau_s: f64,
    twin: bool,
    rng: &mut SimRng,
) -> Result<(RunOut, Option<RunOut>)> {
    let init_err = if cfg.initial_error.mode == "gaussian" {
        (
            normal(rng, cfg.initial_error.altitude_m),
            normal(rng, cfg.initial_error.vz_m_s),
        )
    } else {
        (cfg.initial_error.altitude_m, cfg.initial_error.vz_m_s)
    };
    let f = |noise: Noise, rng: &mut SimRng| {
        if cfg.precision == "f32" {
            simulate::<f32>(cfg, profile, tau_s, init_err, noise, rng)
        } else {
            simulate::<f64>(cfg, profile, tau_s, init_err, noise, rng)
        }
    };
    let noisy = f(Noise { on: true }, rng)?;
    let quiet = if twin {
        Some(f(Noise { on: false }, rng)?)
    } else {
        None
    };
    Ok((noisy, quiet))
}

const LOOPS: [&str; 2] = ["classical", "aided"];

fn settle_json(s: Option<f64>) -> Value {
    s.map_or(Value::Null, |v| json!(sig(v, 4)))
}

fn design_json(cfg: &Config, tau_s: f64) -> Result<Value> {
    let (ccfg, acfg) = loop_configs::<f64>(cfg, tau_s);
    let init = InitialState {
        time: Timestamp::ZERO,
        altitude_m: 0.0,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let c = ClassicalLoop::<f64>::new(&ccfg, &init).map_err(|e| anyhow!("{e}"))?;
    let a = AidedLoop::<f64>::new(&acfg, &init).map_err(|e| anyhow!("{e}"))?;
    let g = c.gains();
    let ag = a.gains();
    let poles: Vec<Value> = ag
        .error_matrix()
        .complex_eigenvalues()
        .iter()
        .map(|e| json!([sig(e.re, 4), sig(e.im, 4)]))
        .collect();
    Ok(json!({
        "classical": {
            "tau_s": tau_s, "c1_per_s": sig(g.c1_per_s, 6), "c2_per_s2": sig(g.c2_per_s2, 6),
            "c3_per_s3": sig(g.c3_per_s3, 6), "c4_s": g.c4_s,
        },
        "aided": {
            "riccati": "continuous ARE, Hamiltonian matrix sign function",
            "k1_per_s": sig(ag.k[(0, 0)], 6), "k2_per_s2": sig(ag.k[(1, 0)], 6),
            "k3_per_s3": sig(ag.k[(2, 0)], 6), "g1": sig(ag.k[(0, 1)], 6),
            "g2_per_s": sig(ag.k[(1, 1)], 6), "g3_per_s2": sig(ag.k[(2, 1)], 6),
            "closed_loop_poles_re_im": poles,
            "riccati_relative_residual": ag.relative_residual,
            "steady_state_sigma_h_m": sig(ag.p[(0, 0)].sqrt(), 4),
            "steady_state_sigma_vz_mps": sig(ag.p[(1, 1)].sqrt(), 4),
        }
    }))
}

fn run_response(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    validate(&cfg)?;
    let profile = Profile::new(&cfg.profile)?;
    let tau = cfg.classical.tau_s;
    let mut rng = crate::rng::run_rng(ctx.seed, 0);
    let (run, twin) = one_run(&cfg, &profile, tau, true, &mut rng)?;
    let twin = twin.ok_or_else(|| anyhow!("noise-free twin missing"))?;
    let n = run.n.max(1) as f64;
    let mut loops = serde_json::Map::new();
    for (l, name) in LOOPS.iter().enumerate() {
        let rh = (run.sumsq[l][0] / n).sqrt();
        let rv = (run.sumsq[l][1] / n).sqrt();
        println!(
            "  {name:<9} settle (noise-free) {:>8}  RMSE h {rh:.3} m  V_z {rv:.4} m/s",
            twin.settle_s[l].map_or("never".to_string(), |s| format!("{s:.2} s"))
        );
        loops.insert(
            name.to_string(),
            json!({
                "settle_time_s": settle_json(twin.settle_s[l]),
                "rmse_h_m": sig(rh, 4),
                "rmse_vz_mps": sig(rv, 4),
                "rmse_h_noise_free_m": sig((twin.sumsq[l][0] / twin.n.max(1) as f64).sqrt(), 4),
            }),
        );
    }
    write_csv(
        &ctx.out_dir.join("response.csv"),
        &[
            "t_s",
            "h_true_m",
            "vz_true_mps",
            "h_baro_m",
            "h_classical_m",
            "h_aided_m",
            "vz_classical_mps",
            "vz_aided_mps",
            "err_h_classical_m",
            "err_h_aided_m",
            "err_vz_classical_mps",
            "err_vz_aided_mps",
            "err_h_classical_noise_free_m",
            "err_h_aided_noise_free_m",
        ],
        &[
            &run.t,
            &run.h_true,
            &run.vz_true,
            &run.h_baro,
            &run.h_est[0],
            &run.h_est[1],
            &run.vz_est[0],
            &run.vz_est[1],
            &run.err_h[0],
            &run.err_h[1],
            &run.err_vz[0],
            &run.err_vz[1],
            &twin.err_h[0],
            &twin.err_h[1],
        ],
    )?;
    let t = &run.t;
    let label = |l: usize| {
        if l == 0 {
            format!("classical (τ = {tau} s)")
        } else {
            "velocity-aided (Riccati)".to_string()
        }
    };
    let fig = Figure {
        title: "Vertical channel response (seed Fig. 3): one run, initial errors 20 m / 2 m/s"
            .into(),
        x_label: "time, s".into(),
        columns: 2,
        panels: vec![
            Panel {
                title: "altitude".into(),
                y_label: "h, m".into(),
                series: vec![
                    Series::line("truth", t, &run.h_true, 3),
                    Series::dashed(label(0), t, &run.h_est[0], 1),
                    Series::dashed(label(1), t, &run.h_est[1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity".into(),
                y_label: "V_z, m/s".into(),
                series: vec![
                    Series::line("truth", t, &run.vz_true, 3),
                    Series::dashed(label(0), t, &run.vz_est[0], 1),
                    Series::dashed(label(1), t, &run.vz_est[1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "altitude error".into(),
                y_label: "δh, m".into(),
                series: vec![
                    Series::line(label(0), t, &run.err_h[0], 1),
                    Series::line(label(1), t, &run.err_h[1], 0),
                ],
                y_range: Some((-25.0, 25.0)),
            },
            Panel {
                title: "vertical velocity error".into(),
                y_label: "δV_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &run.err_vz[0], 1),
                    Series::line(label(1), t, &run.err_vz[1], 0),
                ],
                y_range: Some((-3.0, 3.0)),
            },
            Panel {
                title: "altitude error, noise-free twin (settle time: |δh| ≤ 1 m to the end)"
                    .into(),
                y_label: "δh, m".into(),
                series: vec![
                    Series::line(label(0), t, &twin.err_h[0], 1),
                    Series::line(label(1), t, &twin.err_h[1], 0),
                    Series::dashed("±1 m", &[0.0, cfg.duration_s], &[1.0, 1.0], 7),
                    Series::dashed("", &[0.0, cfg.duration_s], &[-1.0, -1.0], 7),
                ],
                y_range: Some((-25.0, 25.0)),
            },
            Panel {
                title: "vertical velocity error, noise-free twin".into(),
                y_label: "δV_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &twin.err_vz[0], 1),
                    Series::line(label(1), t, &twin.err_vz[1], 0),
                ],
                y_range: Some((-3.0, 3.0)),
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("fig3_response.png"), 1400, 1200)?;
    Ok(json!({
        "loops": loops,
        "design": design_json(&cfg, tau)?,
        "precision": cfg.precision,
    }))
}

/// Monte Carlo of both loops: per-epoch RMSE (over runs) and the overall RMSE.
#[derive(Debug, Clone)]
pub struct McResult {
    /// Output epochs, s.
    pub t: Vec<f64>,
    /// RMSE over runs vs time: [loop][h, vz].
    pub rmse_t: [[Vec<f64>; 2]; 2],
    /// RMSE over runs and time after `rmse_after_s`: [loop][h, vz].
    pub rmse: [[f64; 2]; 2],
    /// Noise-free settle times (per loop) with the configured initial errors taken as fixed.
    pub settle_s: [Option<f64>; 2],
}

/// Runs the Monte Carlo for one classical τ.
pub fn monte_carlo_rmse(
    cfg: &Config,
    tau_s: f64,
    runs: usize,
    seed: u64,
    progress: bool,
) -> Result<McResult> {
    validate(cfg)?;
    let profile = Profile::new(&cfg.profile)?;
    let results = monte_carlo("vertical channel", runs, seed, progress, |_, rng| {
        one_run(cfg, &profile, tau_s, false, rng)
    });
    let results: Vec<(RunOut, Option<RunOut>)> = results.into_iter().collect::<Result<_>>()?;
    // Settle time on the noise-free run with the configured (fixed) initial errors.
    let fixed = (cfg.initial_error.altitude_m, cfg.initial_error.vz_m_s);
    let mut unused = crate::rng::run_rng(seed, u64::MAX);
    let quiet = if cfg.precision == "f32" {
        simulate::<f32>(
            cfg,
            &profile,
            tau_s,
            fixed,
            Noise { on: false },
            &mut unused,
        )?
    } else {
        simulate::<f64>(
            cfg,
            &profile,
            tau_s,
            fixed,
            Noise { on: false },
            &mut unused,
        )?
    };
    let settle_s = quiet.settle_s;
    let mut rmse_t: [[Vec<f64>; 2]; 2] = Default::default();
    let mut rmse = [[0.0; 2]; 2];
    let n_total: f64 = results.iter().map(|r| r.0.n as f64).sum();
    for l in 0..2 {
        let eh: Vec<Vec<f64>> = results.iter().map(|r| r.0.err_h[l].clone()).collect();
        let ev: Vec<Vec<f64>> = results.iter().map(|r| r.0.err_vz[l].clone()).collect();
        rmse_t[l][0] = ensemble(&eh).rms;
        rmse_t[l][1] = ensemble(&ev).rms;
        for (q, item) in rmse[l].iter_mut().enumerate() {
            *item = (results.iter().map(|r| r.0.sumsq[l][q]).sum::<f64>() / n_total).sqrt();
        }
    }
    Ok(McResult {
        t: results.first().map(|r| r.0.t.clone()).unwrap_or_default(),
        rmse_t,
        rmse,
        settle_s,
    })
}

fn run_montecarlo(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    let tau = cfg.classical.tau_s;
    let mc = monte_carlo_rmse(&cfg, tau, ctx.runs, ctx.seed, ctx.progress)?;
    let mut loops = serde_json::Map::new();
    // RMSE over runs within windows, for the report.
    let window = |l: usize, q: usize, a: f64, b: f64| {
        let v: Vec<f64> =
            mc.t.iter()
                .zip(&mc.rmse_t[l][q])
                .filter(|(t, _)| **t >= a && **t < b)
                .map(|(_, r)| r * r)
                .collect();
        sig((v.iter().sum::<f64>() / v.len().max(1) as f64).sqrt(), 4)
    };
    for (l, name) in LOOPS.iter().enumerate() {
        println!(
            "  {name:<9} RMSE h {:.3} m  V_z {:.4} m/s",
            mc.rmse[l][0], mc.rmse[l][1]
        );
        loops.insert(
            name.to_string(),
            json!({
                "rmse_h_m": sig(mc.rmse[l][0], 4),
                "rmse_vz_mps": sig(mc.rmse[l][1], 4),
                "rmse_h_m_5_to_60_s": window(l, 0, 5.0, 60.0),
                "rmse_vz_mps_5_to_60_s": window(l, 1, 5.0, 60.0),
                "rmse_h_m_after_60_s": window(l, 0, 60.0, f64::INFINITY),
                "rmse_vz_mps_after_60_s": window(l, 1, 60.0, f64::INFINITY),
            }),
        );
    }
    let t = &mc.t;
    let label = |l: usize| {
        if l == 0 {
            format!("classical (τ = {tau} s)")
        } else {
            "velocity-aided (Riccati)".to_string()
        }
    };
    let cols: Vec<&[f64]> = vec![
        t,
        &mc.rmse_t[0][0],
        &mc.rmse_t[1][0],
        &mc.rmse_t[0][1],
        &mc.rmse_t[1][1],
    ];
    write_csv(
        &ctx.out_dir.join("rmse.csv"),
        &[
            "t_s",
            "rmse_h_classical_m",
            "rmse_h_aided_m",
            "rmse_vz_classical_mps",
            "rmse_vz_aided_mps",
        ],
        &cols,
    )?;
    let log10 = |v: &[f64]| v.iter().map(|x| x.max(1e-6).log10()).collect::<Vec<_>>();
    let fig = Figure {
        title: format!(
            "Vertical channel Monte Carlo RMSE (seed Fig. 4), {} runs",
            ctx.runs
        ),
        x_label: "time, s".into(),
        columns: 2,
        panels: vec![
            Panel {
                title: "altitude RMSE".into(),
                y_label: "RMSE h, m".into(),
                series: vec![
                    Series::line(label(0), t, &mc.rmse_t[0][0], 1),
                    Series::line(label(1), t, &mc.rmse_t[1][0], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE".into(),
                y_label: "RMSE V_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &mc.rmse_t[0][1], 1),
                    Series::line(label(1), t, &mc.rmse_t[1][1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "altitude RMSE (log10)".into(),
                y_label: "log10 RMSE h [m]".into(),
                series: vec![
                    Series::line(label(0), t, &log10(&mc.rmse_t[0][0]), 1),
                    Series::line(label(1), t, &log10(&mc.rmse_t[1][0]), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE (log10)".into(),
                y_label: "log10 RMSE V_z [m/s]".into(),
                series: vec![
                    Series::line(label(0), t, &log10(&mc.rmse_t[0][1]), 1),
                    Series::line(label(1), t, &log10(&mc.rmse_t[1][1]), 0),
                ],
                y_range: None,
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("fig4_rmse.png"), 1400, 900)?;
    Ok(json!({
        "loops": loops,
        "design": design_json(&cfg, tau)?,
        "precision": cfg.precision,
        "initial_error_mode": cfg.initial_error.mode,
    }))
}

fn run_tau_sweep(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    ensure!(!cfg.tau_sweep_s.is_empty(), "tau_sweep_s is empty");
    let mut rows = Vec::new();
    let (mut taus, mut rh, mut rv, mut st) = (vec![], vec![], vec![], vec![]);
    let mut aided_ref = None;
    for (i, &tau) in cfg.tau_sweep_s.iter().enumerate() {
        let mc = monte_carlo_rmse(&cfg, tau, ctx.runs, ctx.seed, ctx.progress)?;
        println!(
            "  τ = {tau:>6} s  classical RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
            mc.rmse[0][0],
            mc.rmse[0][1],
            mc.settle_s[0].map_or("never".into(), |s| format!("{s:.1} s"))
        );
        rows.push(json!({
            "tau_s": tau,
            "rmse_h_m": sig(mc.rmse[0][0], 4),
            "rmse_vz_mps": sig(mc.rmse[0][1], 4),
            "settle_time_s": settle_json(mc.settle_s[0]),
        }));
        taus.push(tau);
        rh.push(mc.rmse[0][0]);
        rv.push(mc.rmse[0][1]);
        st.push(mc.settle_s[0].unwrap_or(f64::NAN));
        if i == 0 {
            aided_ref = Some(json!({
                "rmse_h_m": sig(mc.rmse[1][0], 4),
                "rmse_vz_mps": sig(mc.rmse[1][1], 4),
                "settle_time_s": settle_json(mc.settle_s[1]),
            }));
            println!(
                "  aided reference: RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
                mc.rmse[1][0],
                mc.rmse[1][1],
                mc.settle_s[1].map_or("never".into(), |s| format!("{s:.1} s"))
            );
        }
    }
    let mut aided_rows = Vec::new();
    for &q in &cfg.aided_design_sweep_m_s2_rt_hz {
        let mut c2 = cfg.clone();
        c2.aided.accel_noise_design_m_s2_rt_hz = Some(q);
        let mc = monte_carlo_rmse(&c2, cfg.classical.tau_s, ctx.runs, ctx.seed, ctx.progress)?;
        println!(
            "  aided design accel noise {q:.1e} m/s²/√Hz: RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
            mc.rmse[1][0],
            mc.rmse[1][1],
            mc.settle_s[1].map_or("never".into(), |s| format!("{s:.1} s"))
        );
        aided_rows.push(json!({
            "accel_noise_design_m_s2_rt_hz": q,
            "rmse_h_m": sig(mc.rmse[1][0], 4),
            "rmse_vz_mps": sig(mc.rmse[1][1], 4),
            "settle_time_s": settle_json(mc.settle_s[1]),
        }));
    }
    write_csv(
        &ctx.out_dir.join("tau_sweep.csv"),
        &["tau_s", "rmse_h_m", "rmse_vz_mps", "settle_time_s"],
        &[&taus, &rh, &rv, &st],
    )?;
    let aided = aided_ref.clone().unwrap_or(Value::Null);
    let flat = |key: &str| {
        let v = aided[key].as_f64().unwrap_or(f64::NAN);
        vec![v; taus.len()]
    };
    let lt: Vec<f64> = taus.iter().map(|t| t.log10()).collect();
    let fig = Figure {
        title: format!(
            "Classical loop τ sweep ({} runs each); dashed: velocity-aided loop",
            ctx.runs
        ),
        x_label: "log10 τ [s]".into(),
        columns: 3,
        panels: vec![
            Panel {
                title: "altitude RMSE".into(),
                y_label: "m".into(),
                series: vec![
                    Series::line("classical", &lt, &rh, 1),
                    Series::dashed("aided", &lt, &flat("rmse_h_m"), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE".into(),
                y_label: "m/s".into(),
                series: vec![
                    Series::line("classical", &lt, &rv, 1),
                    Series::dashed("aided", &lt, &flat("rmse_vz_mps"), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "noise-free settle time (1 m)".into(),
                y_label: "s".into(),
                series: vec![
                    Series::line("classical", &lt, &st, 1),
                    Series::dashed("aided", &lt, &flat("settle_time_s"), 0),
                ],
                y_range: None,
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("tau_sweep.png"), 1500, 500)?;
    Ok(json!({
        "classical": rows,
        "aided_reference": aided,
        "aided_design_sweep": aided_rows,
        "precision": cfg.precision,
    }))
}

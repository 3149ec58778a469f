//! One run of both loops on the simulated sensors, and the Monte Carlo over runs.

use super::sensors::{Noise, Sensors};
use super::truth::Profile;
use super::{validate, Config, MG};
use crate::consistency::{Consistency, RunConsistency};
use crate::montecarlo::monte_carlo;
use crate::rng::{normal, SimRng};
use crate::stats::ensemble;
use anyhow::{anyhow, ensure, Result};
use nalgebra::Matrix2;
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    AidTimeouts, AidedConfig, AidedLoop, BaroSample, ClassicalConfig, ClassicalLoop, ErrorModel,
    ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, Real};

/// The filters whose consistency the scenarios report: the classical loop and the aided loop
/// with the σ their designs imply under the scenario's error model (nav-core's `sigma()`), and
/// the aided loop with the σ of its Riccati design (`gains().p`, the only σ the paper's design
/// gives: it ignores the correlated baro error).
pub const FILTERS: [&str; 3] = ["classical", "aided", "aided_riccati"];

/// NEES of `(δh, δV_z)` against a 2×2 covariance (m², m²/s, (m/s)²).
pub fn nees_h_vz(eh: f64, ev: f64, p: &Matrix2<f64>) -> f64 {
    let det = p.m11 * p.m22 - p.m12 * p.m21;
    (p.m22 * eh * eh - (p.m12 + p.m21) * eh * ev + p.m11 * ev * ev) / det
}

/// One consistency sample: time, errors and covariance of (h, V_z).
pub fn push_consistency(rc: &mut RunConsistency, t: f64, eh: f64, ev: f64, p: &Matrix2<f64>) {
    rc.push(
        t,
        nees_h_vz(eh, ev, p),
        &[(eh, p.m11.sqrt()), (ev, p.m22.sqrt())],
    );
}

/// Component names of the consistency objects.
pub const AXES: [&str; 2] = ["h", "vz"];

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
    /// Consistency samples at the output epochs, per [`FILTERS`].
    pub consistency: Vec<RunConsistency>,
}

fn in_dropout(cfg: &Config, aid: &str, t: f64) -> bool {
    cfg.dropout
        .iter()
        .any(|d| d.aid == aid && t >= d.start_s && t < d.end_s)
}

/// The scenario's sensors and initial errors as the loops' [`ErrorModel`] (the σ the loops
/// report is computed for what the simulated sensors do; the accelerometer bias is a random
/// constant, no random walk).
pub fn error_model<T: Real>(cfg: &Config) -> ErrorModel<T> {
    ErrorModel {
        accel_noise_m_s2_rt_hz: T::lit(cfg.imu.noise_m_s2_rt_hz),
        accel_bias_sigma_m_s2: T::lit(cfg.imu.bias_sigma_mg * MG),
        accel_bias_rw_m_s2_rt_s: T::zero(),
        baro_noise_m: T::lit(cfg.baro.noise_m),
        baro_markov_sigma_m: T::lit(cfg.baro.markov_sigma_m),
        baro_markov_tau_s: T::lit(cfg.baro.markov_tau_s),
        velocity_noise_m_s: T::lit(cfg.velocity_aid.noise_m_s),
        initial_altitude_sigma_m: T::lit(cfg.initial_error.altitude_m.abs().max(1e-3)),
        initial_vz_sigma_m_s: T::lit(cfg.initial_error.vz_m_s.abs().max(1e-3)),
    }
}

/// Builds the nav-core loop configurations in the loops' float type (no gate; the aid
/// model and recovery of the papers' configuration; the error model of [`error_model`]).
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
            error_model: error_model(cfg),
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
            error_model: error_model(cfg),
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

/// The step counts of a run: the IMU interval (s), the IMU steps, the IMU steps per baro,
/// velocity-aid and output sample, and the first step counted in the RMSE.
struct Schedule {
    dt: f64,
    steps: usize,
    baro_every: usize,
    vel_every: usize,
    out_every: usize,
    rmse_from: usize,
}

impl Schedule {
    fn of(cfg: &Config) -> Result<Self> {
        let dt = 1.0 / cfg.imu_rate_hz;
        Ok(Self {
            dt,
            steps: (cfg.duration_s / dt).round() as usize,
            baro_every: ratio(cfg.imu_rate_hz, cfg.baro.rate_hz, "baro.rate_hz")?,
            vel_every: ratio(
                cfg.imu_rate_hz,
                cfg.velocity_aid.rate_hz,
                "velocity_aid.rate_hz",
            )?,
            out_every: ratio(cfg.output_interval_s, dt, "output_interval_s")?,
            rmse_from: (cfg.rmse_after_s / dt).round() as usize,
        })
    }
}

/// IMU step `k` of a run: its time (s) and stamp, and the true altitude (m) and vertical
/// velocity (m/s, up) at it.
struct Epoch {
    k: usize,
    t: f64,
    stamp: Timestamp,
    h: f64,
    v: f64,
}

/// The aid samples at `at`: the baro sample (its value kept
/// in `last_baro`, m, in a dropout too) and the velocity-aid sample, each `None` when not due
/// or in a dropout.
fn aid_samples<T: Real>(
    cfg: &Config,
    sch: &Schedule,
    sensors: &mut Sensors,
    at: &Epoch,
    last_baro: &mut f64,
    rng: &mut SimRng,
) -> (Option<BaroSample<T>>, Option<VelocitySample<T>>) {
    let (k, t, stamp, v) = (at.k, at.t, at.stamp, at.v);
    let baro = if k % sch.baro_every == 0 {
        let z = sensors.baro(rng);
        *last_baro = z;
        (!in_dropout(cfg, "baro", t)).then_some(BaroSample {
            time: stamp,
            altitude_m: T::lit(z),
        })
    } else {
        None
    };
    let vel = if k % sch.vel_every == 0 {
        let z = sensors.velocity(v, rng);
        (!in_dropout(cfg, "velocity", t)).then_some(VelocitySample {
            time: stamp,
            vz_up_m_s: T::lit(z),
        })
    } else {
        None
    };
    (baro, vel)
}

impl RunOut {
    /// The errors of the estimates `est` ([classical, aided] (altitude m, vz m/s)) against the
    /// truth at `at`: the time after the last error over 1 m (`last_big`) and, from
    /// step `rmse_from` on, the RMSE sums.
    fn accumulate(
        &mut self,
        est: &[(f64, f64); 2],
        at: &Epoch,
        rmse_from: usize,
        last_big: &mut [Option<f64>; 2],
    ) {
        for (l, (eh, ev)) in est.iter().enumerate() {
            let (dh, dv) = (eh - at.h, ev - at.v);
            if dh.abs() > 1.0 {
                last_big[l] = None;
            } else if last_big[l].is_none() {
                last_big[l] = Some(at.t);
            }
            if at.k >= rmse_from {
                self.sumsq[l][0] += dh * dh;
                self.sumsq[l][1] += dv * dv;
            }
        }
        if at.k >= rmse_from {
            self.n += 1;
        }
    }

    /// One output epoch at `at`: the truth, the latest baro sample (m), the estimates `est` and
    /// the consistency samples of [`FILTERS`] (covariances of (h, V_z)).
    fn push_output(
        &mut self,
        at: &Epoch,
        last_baro: f64,
        est: &[(f64, f64); 2],
        covs: &[Matrix2<f64>; 3],
    ) {
        let (t, h, v) = (at.t, at.h, at.v);
        self.t.push(t);
        self.h_true.push(h);
        self.vz_true.push(v);
        self.h_baro.push(last_baro);
        for (l, (eh, ev)) in est.iter().enumerate() {
            self.h_est[l].push(*eh);
            self.vz_est[l].push(*ev);
            self.err_h[l].push(eh - h);
            self.err_vz[l].push(ev - v);
        }
        let (ec, ea) = ((est[0].0 - h, est[0].1 - v), (est[1].0 - h, est[1].1 - v));
        let covs = [(ec, covs[0]), (ea, covs[1]), (ea, covs[2])];
        for (rc, ((eh, ev), p)) in self.consistency.iter_mut().zip(covs.iter()) {
            push_consistency(rc, t, *eh, *ev, p);
        }
    }
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
    let sch = Schedule::of(cfg)?;
    let dt = sch.dt;
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

    let mut sensors = Sensors::new(cfg, noise, dt, sch.baro_every, (h0, v0), rng);
    let mut last_baro = f64::NAN;

    let mut out = RunOut {
        consistency: FILTERS.iter().map(|_| RunConsistency::new(&AXES)).collect(),
        ..RunOut::default()
    };
    let p_riccati = {
        let p = aided.gains().p;
        Matrix2::new(p.m11, p.m12, p.m21, p.m22)
    };
    let cov = |m: Matrix2<T>| m.map(|v| v.to_f64());
    let mut last_big = [Some(0.0f64); 2]; // time after the last |err| > 1 m
    let (mut h_prev, mut v_prev, _) = profile.at(0.0);
    for k in 1..=sch.steps {
        let t = k as f64 * dt;
        let stamp = Timestamp::from_secs_f64(t).map_err(|e| anyhow!("time stamp {t}: {e}"))?;
        let (h, v, _) = profile.at(t);
        let at = Epoch { k, t, stamp, h, v };
        // Mean specific force over the interval: Δv/Δt + g at mid-interval altitude.
        let (h_mid, _, _) = profile.at(t - 0.5 * dt);
        let f = sensors.specific_force((v - v_prev) / dt, h_mid, rng);
        sensors.advance_baro_lag(h, h_prev);
        let (baro, vel) = aid_samples::<T>(cfg, &sch, &mut sensors, &at, &mut last_baro, rng);
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
        out.accumulate(&est, &at, sch.rmse_from, &mut last_big);
        if k % sch.out_every == 0 {
            let covs = [
                cov(classical.covariance_h_vz()),
                cov(aided.covariance_h_vz()),
                p_riccati,
            ];
            out.push_output(&at, last_baro, &est, &covs);
        }
        h_prev = h;
        v_prev = v;
    }
    out.settle_s = last_big;
    Ok(out)
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
    /// Consistency over the runs, per [`FILTERS`].
    pub consistency: Vec<Consistency>,
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
    let consistency = (0..FILTERS.len())
        .map(|f| {
            let runs: Vec<RunConsistency> = results
                .iter()
                .filter_map(|r| r.0.consistency.get(f).cloned())
                .collect();
            Consistency::from_runs(2, &runs)
        })
        .collect();
    Ok(McResult {
        consistency,
        t: results.first().map(|r| r.0.t.clone()).unwrap_or_default(),
        rmse_t,
        rmse,
        settle_s,
    })
}

//! Stress campaign of the vertical loops (`ClassicalLoop`, `AidedLoop`, f32, public API only).
//!
//! Every case flies a 15 g vertical manoeuvre (altitude 20 km ± 2.4 km, |V_z| ≤ 590 m/s; or a
//! gentle one for a third of the cases) with a 5 mg accelerometer bias and white noise, through
//! a repeating 300 s fault cycle:
//!
//! - 0-150 s aided, with a 1 km baro spike (0.2 s) at 30 s and a frozen baro at 60-75 s;
//! - an IMU logging gap of 0.5-2 s at 100 s;
//! - 150-270 s both aids out (the loop coasts on the IMU), 270-300 s re-acquisition.
//!
//! IMU time stamps (integer microseconds, some cases starting at 10⁶ s or 10⁹ s) are jittered
//! by up to ±50 % of the nominal interval, and 2 % of the IMU samples are missing. IMU rates
//! 50-1000 Hz; classical τ 0.1-100 s, aided accelerometer noise 10⁻³-1 m/s²/√Hz; gate on and
//! off. Configurations the loops refuse (`InvalidConfig`) are counted, not run.
//!
//! Counted per call ([`super::Tally`]): refusals (every input is valid, so any `Err` is one),
//! every reported number for finiteness (estimate, innovations, variances, ages, gate
//! variance, NIS), the aided design's covariance P once per case, and the loops' σ covariance
//! of (h, V_z) every [`SIGMA_CHECK_EVERY`] steps. Findings beyond the
//! three failure counts (in the coverage text): the altitude error at the end of each aided
//! window (150 s of the cycle, 75 s after the frozen baro) beyond [`CHECKPOINT_BOUND_M`] with
//! the gate on, and steps spent in `NeedsReinitialisation`.

use super::{EstimatorStress, StressLevel, Tally};
use crate::rng::{normal, run_rng, SimRng};
use crate::truth::gravity_down_m_s2;
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    AidModel, AidReport, AidStatus, AidTimeouts, AidedConfig, AidedLoop, BaroSample,
    ClassicalConfig, ClassicalLoop, ErrorModel, ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, Gate, HealthState, NavError, RecoveryAction, RecoveryPolicy};
use rand::Rng;
use rayon::prelude::*;

mod totals;
use totals::Totals;

/// The loops' σ covariance of (h, V_z) is checked (finite, symmetric, PSD) every this many
/// steps (the check allocates; every step would dominate the campaign's time).
pub const SIGMA_CHECK_EVERY: u64 = 64;

fn sigma_check(tally: &mut Tally, at: &str, p: &nalgebra::Matrix2<f32>) {
    let v = [p[(0, 0)], p[(0, 1)], p[(1, 0)], p[(1, 1)]].map(f64::from);
    tally.covariance(at, &v, 2, f64::from(f32::EPSILON));
}

/// Largest accepted altitude error at the end of each aided window with the gate on, m.
pub const CHECKPOINT_BOUND_M: f64 = 50.0;

const LAT_RAD: f64 = 0.7;
const CYCLE_S: f64 = 300.0;
const BARO_PERIOD_S: f64 = 0.04;
const VEL_PERIOD_S: f64 = 0.1;

/// One case of the campaign.
#[derive(Debug, Clone)]
struct Case {
    aided: bool,
    rate_hz: f64,
    gate: bool,
    /// Classical τ, s, or the aided design's accelerometer noise, m/s²/√Hz.
    param: f64,
    manoeuvre_15g: bool,
    steps: u64,
    epoch_s: f64,
    seed: u64,
}

impl Case {
    fn name(&self) -> String {
        format!(
            "{} {} Hz gate {} {} {} {} steps from {} s",
            if self.aided { "aided" } else { "classical" },
            self.rate_hz,
            if self.gate { "on" } else { "off" },
            if self.aided {
                format!("accel noise {}", self.param)
            } else {
                format!("τ {} s", self.param)
            },
            if self.manoeuvre_15g { "15 g" } else { "gentle" },
            self.steps,
            self.epoch_s
        )
    }
}

/// The result of one case beyond the tally.
#[derive(Debug, Default, Clone)]
struct Extra {
    refused_config: bool,
    checkpoints: u64,
    checkpoint_failures: u64,
    worst_checkpoint_m: f64,
    needs_reinit_steps: u64,
    end_health: Option<HealthState>,
}

/// Either loop behind one interface.
enum Loop {
    Classical(Box<ClassicalLoop<f32>>),
    Aided(Box<AidedLoop<f32>>),
}

fn aid_values(r: &AidReport<f32>, out: &mut Vec<f64>) {
    let mut push = |v: Option<f32>| {
        if let Some(x) = v {
            out.push(f64::from(x));
        }
    };
    push(r.correction);
    push(match r.status {
        AidStatus::Fresh { age_s } | AidStatus::Stale { age_s } | AidStatus::Lost { age_s } => {
            Some(age_s)
        }
        AidStatus::NoData => None,
    });
    if let Some(c) = r.sample {
        out.extend([c.innovation, c.innovation_variance, c.nis, c.test_ratio].map(f64::from));
    }
}

/// The gated cases' aid model, gate (χ² 16) and recovery (re-anchor after 30 s).
fn aid_model() -> AidModel<f32> {
    AidModel {
        baro_sigma_m: 5.0,
        velocity_sigma_m_s: 0.5,
        starved_velocity_sigma_m_s: 0.5,
        starved_accel_sigma_m_s2: 0.1,
        recovery_hold_s: 60.0,
    }
}

fn gate(c: &Case) -> Gate<f32> {
    if c.gate {
        Gate::Nis(16.0)
    } else {
        Gate::Off
    }
}

fn recovery() -> RecoveryPolicy<f32> {
    RecoveryPolicy {
        starved_after_s: Some(30.0),
        action: RecoveryAction::Reanchor,
    }
}

fn build(c: &Case, t0: Timestamp, h0: f64, v0: f64) -> Result<Loop, NavError> {
    let dt = 1.0 / c.rate_hz;
    let to = |p: f64, lost: f64| AidTimeouts {
        stale_after_s: (2.5 * p) as f32,
        lost_after_s: lost as f32,
    };
    let init = InitialState {
        time: t0,
        altitude_m: h0 as f32,
        vz_up_m_s: v0 as f32,
        accel_bias_m_s2: 0.0,
    };
    if c.aided {
        let cfg = AidedConfig {
            imu_dt_s: dt as f32,
            latitude_rad: LAT_RAD as f32,
            accel_noise_m_s2_rt_hz: c.param as f32,
            accel_bias_rw_m_s2_rt_s: 1e-3,
            baro_noise_m: 1.0,
            baro_period_s: BARO_PERIOD_S as f32,
            baro_lag_s: 0.0,
            velocity_noise_m_s: 0.2,
            velocity_period_s: VEL_PERIOD_S as f32,
            baro_timeouts: to(BARO_PERIOD_S, 1.0),
            velocity_timeouts: to(VEL_PERIOD_S, 2.0),
            aid_model: aid_model(),
            gate: gate(c),
            recovery: recovery(),
            error_model: ErrorModel::paper(),
        };
        Ok(Loop::Aided(Box::new(AidedLoop::new(&cfg, &init)?)))
    } else {
        let cfg = ClassicalConfig {
            imu_dt_s: dt as f32,
            latitude_rad: LAT_RAD as f32,
            tau_s: c.param as f32,
            baro_lag_s: 0.0,
            baro_period_s: BARO_PERIOD_S as f32,
            baro_timeouts: to(BARO_PERIOD_S, 1.0),
            aid_model: aid_model(),
            gate: gate(c),
            recovery: recovery(),
            error_model: ErrorModel::paper(),
        };
        Ok(Loop::Classical(Box::new(ClassicalLoop::new(&cfg, &init)?)))
    }
}

impl Loop {
    /// One step with the IMU sample and the aid samples (`vv` ignored by the classical loop),
    /// the call and, every `SIGMA_CHECK_EVERY` steps, the σ covariance tallied, the report's
    /// values appended to `values`; returns the altitude, vertical velocity, accelerometer bias
    /// and health after it.
    fn step_checked(
        &mut self,
        imu: &ImuSample<f32>,
        b: Option<&BaroSample<f32>>,
        vv: Option<&VelocitySample<f32>>,
        step_index: u64,
        tally: &mut Tally,
        values: &mut Vec<f64>,
    ) -> (f32, f32, f32, HealthState) {
        match self {
            Loop::Classical(l) => {
                let r = l.step(imu, b);
                tally.call("classical step", &r);
                if let Ok(rep) = &r {
                    aid_values(&rep.baro, values);
                }
                if step_index % SIGMA_CHECK_EVERY == 0 {
                    sigma_check(tally, "classical σ covariance", &l.covariance_h_vz());
                }
                (
                    l.altitude_m(),
                    l.vz_up_m_s(),
                    l.accel_bias_m_s2(),
                    l.health().state,
                )
            }
            Loop::Aided(l) => {
                let r = l.step(imu, b, vv);
                tally.call("aided step", &r);
                if let Ok(rep) = &r {
                    aid_values(&rep.baro, values);
                    aid_values(&rep.velocity, values);
                }
                if step_index % SIGMA_CHECK_EVERY == 0 {
                    sigma_check(tally, "aided σ covariance", &l.covariance_h_vz());
                }
                (
                    l.altitude_m(),
                    l.vz_up_m_s(),
                    l.accel_bias_m_s2(),
                    l.health().state,
                )
            }
        }
    }
}
/// The next IMU interval after `t_prev_s`, µs: the nominal `dt_us` with ±50 % jitter, 2 %
/// missing samples, and a logging gap of 0.5-2 s once per cycle (`gap_done_cycle` the last
/// cycle that had it).
fn next_interval_us(rng: &mut SimRng, dt_us: u64, t_prev_s: f64, gap_done_cycle: &mut u64) -> u64 {
    let jitter = rng.random_range(0.5..1.5);
    let mut step = ((dt_us as f64) * jitter).round().max(1.0) as u64;
    if rng.random::<f64>() < 0.02 {
        step += dt_us;
    }
    let cycle = (t_prev_s / CYCLE_S) as u64;
    if t_prev_s % CYCLE_S >= 100.0 && *gap_done_cycle != cycle {
        *gap_done_cycle = cycle;
        step += rng.random_range(500_000..2_000_000);
    }
    step
}

/// The baro altitude at tick `tb` (s) of the true altitude `hb` (m): σ 1 m noise, a 1 km
/// glitch at 30 s of each cycle, frozen (`frozen` the held value) from 60 to 75 s.
fn baro_reading(tb: f64, hb: f64, rng: &mut SimRng, frozen: &mut Option<f64>) -> f64 {
    let tp = tb % CYCLE_S;
    let mut z = hb + normal(rng, 1.0);
    if (30.0..30.2).contains(&tp) {
        z += 1000.0;
    }
    if (60.0..75.0).contains(&tp) {
        z = *frozen.get_or_insert(z);
    } else {
        *frozen = None;
    }
    z
}

impl Extra {
    /// At the end of each aided window after the first cycle (once per cycle,
    /// `checkpoint_cycle` the last that had it): the altitude error `err_m` against its bound.
    fn checkpoint(&mut self, t: f64, err_m: f64, checkpoint_cycle: &mut u64) {
        let ph = t % CYCLE_S;
        let cyc = (t / CYCLE_S) as u64;
        if (149.0..150.0).contains(&ph) && *checkpoint_cycle != cyc && t > CYCLE_S {
            *checkpoint_cycle = cyc;
            let e = err_m.abs();
            self.checkpoints += 1;
            self.worst_checkpoint_m = self.worst_checkpoint_m.max(e);
            if e > CHECKPOINT_BOUND_M {
                self.checkpoint_failures += 1;
            }
        }
    }
}

/// The aided loop's design covariance must be symmetric positive semi-definite.
fn check_design(tally: &mut Tally, lp: &Loop) {
    if let Loop::Aided(a) = lp {
        let p = a.gains().p;
        let rows: Vec<f64> = (0..3)
            .flat_map(|i| (0..3).map(move |j| p[(i, j)]))
            .collect();
        tally.covariance("aided design P", &rows, 3, f64::EPSILON);
    }
}

/// The newest aid tick not after `t` (s; the ticks every `period` s from `next`, which is
/// advanced past `t`), none in an outage.
fn newest_tick(next: &mut f64, period: f64, t: f64, outage: bool) -> Option<f64> {
    let mut got = None;
    while *next <= t {
        got = Some(*next);
        *next += period;
    }
    got.filter(|_| !outage)
}

/// The aid samples of a baro altitude and a vertical velocity (each with its tick time, s
/// after `t0`), stamped at their ticks; the altitude clamped to the loops' range.
fn aid_samples(
    t0: Timestamp,
    baro: Option<(f64, f64)>,
    vel: Option<(f64, f64)>,
) -> (Option<BaroSample<f32>>, Option<VelocitySample<f32>>) {
    let stamp = |s: f64| t0.add_micros((s * 1e6).round() as u64);
    let b = baro.map(|(tb, z)| BaroSample {
        time: stamp(tb),
        altitude_m: z.clamp(-1_999.0, 59_999.0) as f32,
    });
    let vv = vel.map(|(tv, z)| VelocitySample {
        time: stamp(tv),
        vz_up_m_s: z as f32,
    });
    (b, vv)
}

fn run_case(c: &Case) -> (Tally, Extra) {
    let mut tally = Tally::new(c.name());
    let mut extra = Extra::default();
    let mut rng: SimRng = run_rng(c.seed, 0);
    // Truth: h = 20 km + A sin(ω t), 15 g peak (A ω² = 147 m/s²) or 0.5 g.
    let (amp, w) = if c.manoeuvre_15g {
        (147.0 / 0.0625, 0.25)
    } else {
        (200.0, 0.15)
    };
    let phase0 = rng.random::<f64>() * std::f64::consts::TAU;
    let truth = |t: f64| {
        let a = w * t + phase0;
        (20_000.0 + amp * a.sin(), amp * w * a.cos())
    };
    let bias = 0.05; // 5 mg
    let noise_density = 2e-3;
    let t0 = Timestamp::from_secs_f64(c.epoch_s).unwrap_or(Timestamp::ZERO);
    let (h0, v0) = truth(0.0);
    let mut lp = match build(c, t0, h0 + 10.0, v0 + 1.0) {
        Ok(l) => l,
        Err(_) => {
            extra.refused_config = true;
            return (tally, extra);
        }
    };
    check_design(&mut tally, &lp);
    let dt_us = (1e6 / c.rate_hz).round() as u64;
    let mut t_us: u64 = 0;
    let mut v_prev = v0;
    let (mut next_baro, mut next_vel) = (BARO_PERIOD_S, VEL_PERIOD_S);
    let mut frozen = None::<f64>;
    let mut gap_done_cycle = u64::MAX;
    let mut values = Vec::with_capacity(16);
    let mut checkpoint_cycle = u64::MAX;
    for step_index in 0..c.steps {
        let t_prev = t_us as f64 * 1e-6;
        t_us += next_interval_us(&mut rng, dt_us, t_prev, &mut gap_done_cycle);
        let t = t_us as f64 * 1e-6;
        let ph = t % CYCLE_S;
        let (h, v) = truth(t);
        let (hm, _) = truth(0.5 * (t + t_prev));
        let dts = t - t_prev;
        let f = (v - v_prev) / dts
            + gravity_down_m_s2(LAT_RAD, hm)
            + bias
            + normal(&mut rng, noise_density / dts.sqrt());
        v_prev = v;
        let outage = (150.0..270.0).contains(&ph);
        let baro = newest_tick(&mut next_baro, BARO_PERIOD_S, t, outage)
            .map(|tb| (tb, baro_reading(tb, truth(tb).0, &mut rng, &mut frozen)));
        let vel = newest_tick(&mut next_vel, VEL_PERIOD_S, t, outage)
            .map(|tv| (tv, truth(tv).1 + normal(&mut rng, 0.2)));
        let imu = ImuSample {
            time: t0.add_micros(t_us),
            specific_force_up_m_s2: f as f32,
        };
        let (b, vv) = aid_samples(t0, baro, vel);
        values.clear();
        let (alt, vz, bias, health) = lp.step_checked(
            &imu,
            b.as_ref(),
            vv.as_ref(),
            step_index,
            &mut tally,
            &mut values,
        );
        values.extend([alt, vz, bias].map(f64::from));
        let est_h = f64::from(alt);
        tally.finite("report", values.iter().copied());
        if health == HealthState::NeedsReinitialisation {
            extra.needs_reinit_steps += 1;
        }
        extra.end_health = Some(health);
        // Checkpoint at the end of each aided window (after the first cycle's transient).
        extra.checkpoint(t, est_h - h, &mut checkpoint_cycle);
    }
    (tally, extra)
}

fn cases(level: StressLevel) -> Vec<Case> {
    let full = level == StressLevel::Full;
    let grid_steps = |rate: f64| -> u64 {
        // Short: three fault cycles (1000 s) at any rate, capped; Full: 10⁶ steps per case.
        if full {
            1_000_000
        } else {
            ((1_000.0 * rate) as u64).min(400_000)
        }
    };
    let mut out = Vec::new();
    let mut seed = 7_100;
    for aided in [false, true] {
        let params: &[f64] = if aided {
            &[1e-3, 1e-2, 1e-1, 1.0]
        } else {
            &[0.1, 1.0, 5.0, 20.0, 100.0]
        };
        for rate_hz in [50.0, 100.0, 200.0, 500.0, 1000.0] {
            for gate in [false, true] {
                for (i, &param) in params.iter().enumerate() {
                    seed += 1;
                    out.push(Case {
                        aided,
                        rate_hz,
                        gate,
                        param,
                        manoeuvre_15g: (i + usize::from(gate)) % 3 != 2,
                        steps: grid_steps(rate_hz),
                        epoch_s: [0.0, 1.0e6, 1.0e9][(seed % 3) as usize],
                        seed,
                    });
                }
            }
        }
    }
    // The long runs: both loops, 15 g, outages, gate on (and off), 10⁷ steps each in Full.
    let long = if full { 10_000_000 } else { 1_000_000 };
    for (aided, param) in [(false, 20.0), (true, 1e-2)] {
        for (rate_hz, gate) in [(1000.0, true), (100.0, true), (1000.0, false)] {
            seed += 1;
            out.push(Case {
                aided,
                rate_hz,
                gate,
                param,
                manoeuvre_15g: true,
                steps: long,
                epoch_s: 1.0e6,
                seed,
            });
        }
    }
    out
}

/// Runs the campaign at `level`.
pub fn run(level: StressLevel) -> EstimatorStress {
    let all = cases(level);
    let results: Vec<(Case, Tally, Extra)> = all
        .into_par_iter()
        .map(|c| {
            let (t, e) = run_case(&c);
            (c, t, e)
        })
        .collect();
    let mut s = EstimatorStress::default();
    let mut totals = Totals::default();
    for (c, t, e) in results {
        if totals.add(&c, &e) {
            s.add(t);
        }
    }
    s.coverage = totals.coverage(level);
    s
}

//! Stress campaign of the transfer-alignment filters (both, f32, public API only).
//!
//! - **Envelope map**: every filter step of 100, 200, 500 and 1000 Hz × flexure σ 0.01°, 0.1°,
//!   0.5°, 2° × τ 0.05 s (5 steps at 100 Hz: the envelope's corner), 0.5 s, 5 s, 100 s, 10⁴ s,
//!   for both filters. Each case runs one of three input kinds:
//!   constant noise-free inputs (the case that stalled the older filter), noisy inputs with
//!   random manoeuvres and jittered time stamps (intervals uniform in 0.5-1.5 dt, occasional
//!   missing samples, dropouts bridged by `propagate`, gaps longer than `max_gap_steps`), and
//!   the same at the corners of the noise envelope (rate σ 1e-5 rad/s, accel σ 1e-4 m/s², or
//!   the largest ones).
//! - **Long runs**: both filters at 1 kHz with the clock starting at 10⁶ s, 10⁷ steps each
//!   (`Full`; 10⁵ for `Short`), noisy jittered inputs with manoeuvres.
//!
//! Every call is tallied; P ([`TransferAlignment::covariance`])
//! is checked every 100 steps and at the end with `eps = f32::EPSILON`; every report value,
//! θ and its σ with [`Tally::finite`].

use super::{EstimatorStress, StressLevel, Tally};
use crate::rng::{normal, run_rng, SimRng};
use nalgebra::Vector3;
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{
    AxisFlexure, Channel, MasterSample, PaperCase, SlaveSample, StepReport, TaConfig, TaInitial,
    TransferAlignment,
};
use nav_core::{Estimator, Gate, RecoveryAction, RecoveryPolicy};
use rand::Rng;
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Totals over the campaign: updates skipped, flexure re-initialisations (gaps reset),
/// covariance resets after gate starvation (epochs with a recovery) and channel recoveries
/// (the same resets counted on each starved channel).
static SKIPPED: AtomicU64 = AtomicU64::new(0);
static REINITS: AtomicU64 = AtomicU64::new(0);
static RESETS: AtomicU64 = AtomicU64::new(0);
static RECOVERIES: AtomicU64 = AtomicU64::new(0);

/// Recoveries of every channel, summed.
fn channel_recoveries<const K: usize, const N: usize>(f: &TransferAlignment<f32, K, N>) -> u64 {
    Channel::ALL
        .iter()
        .map(|c| u64::from(f.aid_counters(*c).recoveries))
        .sum()
}

const SEED: u64 = 0x7a_2026;
const PSD_EVERY: u64 = 100;

/// What the inputs of a case look like.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Inputs {
    /// Constant, noise-free, regular stamps.
    ConstantClean,
    /// Random manoeuvres, sensor noise, jittered stamps, missing samples, dropouts, long gaps.
    Hostile,
    /// As `Hostile` with the sensor noise σ at the envelope's corners.
    HostileNoiseCorners,
}

#[derive(Debug, Clone, Copy)]
struct Case {
    rate_hz: u32,
    sigma_deg: f64,
    tau_s: f64,
    proposed: bool,
    /// The flight configuration (15 states; `proposed` is then true too).
    flight: bool,
    inputs: Inputs,
    steps: u64,
    start_us: u64,
    seed: u64,
}

impl Case {
    fn name(&self, cfg: &TaConfig<f32>) -> String {
        format!(
            "{} f32 {} Hz σ {}° τ {} s {:?} (rate σ {} rad/s, accel σ {} m/s², gate {:?}) start {} s",
            if self.flight {
                "flight"
            } else if self.proposed {
                "proposed"
            } else {
                "conventional"
            },
            self.rate_hz,
            self.sigma_deg,
            self.tau_s,
            self.inputs,
            cfg.rate_noise_sigma_rad_s,
            cfg.accel_noise_sigma_m_s2,
            cfg.gate,
            self.start_us / 1_000_000
        )
    }
}

fn config(c: &Case, rng: &mut SimRng) -> TaConfig<f32> {
    let dt = 1.0 / f64::from(c.rate_hz);
    let (rate_sigma, accel_sigma) = match c.inputs {
        Inputs::ConstantClean | Inputs::Hostile => (3e-4, 5e-3),
        Inputs::HostileNoiseCorners => {
            if rng.random_bool(0.5) {
                (1e-4, 1e-3)
            } else {
                (0.1, 1.0)
            }
        }
    };
    let ax = AxisFlexure {
        sigma_rad: c.sigma_deg.to_radians() as f32,
        tau_s: c.tau_s as f32,
    };
    // The paper's lever arm and mount σ; the case's flexure, noise and rate; a gate half of
    // the time; recovery after 50 rejected epochs at every rate (0.5 s at 100 Hz, 50 ms at
    // 1 kHz: the campaign's recovery exercises the reset at every rate).
    TaConfig {
        flexure: [ax; 3],
        rate_noise_sigma_rad_s: rate_sigma as f32,
        accel_noise_sigma_m_s2: accel_sigma as f32,
        dt_s: dt as f32,
        time_tolerance_s: (0.1 * dt) as f32,
        max_gap_steps: 3,
        // The flight configuration's bias σ (ignored by the paper's filters).
        accel_bias_sigma_m_s2: if c.flight {
            TaConfig::<f32>::flight(PaperCase::Case2).accel_bias_sigma_m_s2
        } else {
            Vector3::zeros()
        },
        gate: if rng.random_bool(0.5) {
            Gate::Nis(25.0)
        } else {
            Gate::Off
        },
        recovery: RecoveryPolicy {
            starved_after_s: Some((50.0 * dt) as f32),
            action: RecoveryAction::ResetToPrior,
        },
        ..TaConfig::paper(PaperCase::Case2)
    }
}

/// The truth and sensors of a case, advanced sample by sample.
struct World {
    t_s: f64,
    theta_m: Vector3<f64>,
    phase: Vector3<f64>,
    omega: Vector3<f64>,
    force: Vector3<f64>,
    next_manoeuvre_s: f64,
}

impl World {
    /// A new manoeuvre: angular rate up to 1 rad/s (0.5 about z), specific force within
    /// ±30 m/s² of 1 g, held 0.5-3 s.
    fn manoeuvre(&mut self, rng: &mut SimRng) {
        self.omega = Vector3::new(
            rng.random_range(-1.0..1.0),
            rng.random_range(-1.0..1.0),
            rng.random_range(-0.5..0.5),
        );
        self.force = Vector3::new(
            rng.random_range(-30.0..30.0),
            rng.random_range(-30.0..30.0),
            -9.81 + rng.random_range(-30.0..30.0),
        );
        self.next_manoeuvre_s = self.t_s + rng.random_range(0.5..3.0);
    }

    /// The master and slave samples at `stamp`: the slave rotated by the mounting and flexure
    /// angles (σ `c.sigma_deg` at the correlation frequency 1/τ), with white noise of σ
    /// `noise = (rate rad/s, specific force m/s²)`.
    fn samples(
        &self,
        c: &Case,
        stamp: Timestamp,
        noise: (f64, f64),
        rng: &mut SimRng,
    ) -> (MasterSample<f32>, SlaveSample<f32>) {
        let (rate_sigma, accel_sigma) = noise;
        // Flexure: a sinusoid of amplitude σ at the correlation frequency, per axis.
        let om_f = 1.0 / c.tau_s;
        let arg = self.phase + Vector3::repeat(om_f * self.t_s);
        let sigma = c.sigma_deg.to_radians();
        let theta_f = arg.map(f64::sin) * sigma;
        let theta_f_dot = arg.map(f64::cos) * (sigma * om_f);
        let theta = self.theta_m + theta_f;
        let noise3 =
            |rng: &mut SimRng, s: f64| Vector3::new(normal(rng, s), normal(rng, s), normal(rng, s));
        let master = MasterSample {
            time: stamp,
            angular_rate_rad_s: self.omega.map(|v| v as f32),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: self.force.map(|v| v as f32),
        };
        let ws = self.omega - theta.cross(&self.omega) + theta_f_dot + noise3(rng, rate_sigma);
        let fs = self.force - theta.cross(&self.force) + noise3(rng, accel_sigma);
        let slave = SlaveSample {
            time: stamp,
            angular_rate_rad_s: ws.map(|v| v as f32),
            specific_force_m_s2: fs.map(|v| v as f32),
        };
        (master, slave)
    }
}

/// The interval to the next sample, µs: `dt_us`, or with hostile inputs jittered 0.5-1.5 dt
/// and, one time in a thousand, a few samples missing (sometimes beyond `max_gap_steps`).
fn next_interval_us(rng: &mut SimRng, dt_us: u64, hostile: bool) -> u64 {
    if hostile {
        let jitter = (dt_us as f64 * rng.random_range(0.5..1.5)).round() as u64;
        let missing = if rng.random_bool(1e-3) {
            // Missing samples: a few steps, sometimes beyond max_gap_steps.
            dt_us * rng.random_range(1..12)
        } else {
            0
        };
        jitter.max(1) + missing
    } else {
        dt_us
    }
}

fn record<T: Copy + Into<f64>>(tally: &mut Tally, rep: &StepReport<T>) {
    let vals = rep.updates.iter().flat_map(|u| {
        [
            u.innovation.into(),
            u.innovation_variance.into(),
            u.nis.into(),
            u.test_ratio.into(),
        ]
    });
    tally.finite("step report", vals);
}

fn check_outputs<const K: usize, const N: usize>(
    tally: &mut Tally,
    f: &TransferAlignment<f32, K, N>,
    psd: bool,
) {
    let vals = f
        .theta()
        .iter()
        .chain(f.theta_sigma_rad().iter())
        .chain(f.theta_m().iter())
        .map(|v| f64::from(*v))
        .collect::<Vec<_>>();
    tally.finite("θ, σ", vals);
    if psd {
        let p = f.covariance();
        let rows: Vec<f64> = (0..N)
            .flat_map(|i| (0..N).map(move |j| (i, j)))
            .map(|(i, j)| f64::from(p[(i, j)]))
            .collect();
        let diag: Vec<String> = (0..N).map(|i| format!("{:.1e}", rows[i * N + i])).collect();
        tally.covariance(
            &format!("P (diag {})", diag.join(" ")),
            &rows,
            N,
            f64::from(f32::EPSILON),
        );
    }
}

fn run_case<const K: usize, const N: usize>(c: &Case) -> Tally {
    let mut rng = run_rng(SEED, c.seed);
    let cfg = config(c, &mut rng);
    let mut tally = Tally::new(c.name(&cfg));
    let Ok(mut f) = TransferAlignment::<f32, K, N>::new(&cfg, &TaInitial::default()) else {
        tally.call("new", &Err::<(), _>("configuration refused"));
        return tally;
    };
    let dt_us = 1_000_000 / u64::from(c.rate_hz);
    let hostile = c.inputs != Inputs::ConstantClean;
    let (rate_sigma, accel_sigma) = if hostile {
        (
            f64::from(cfg.rate_noise_sigma_rad_s),
            f64::from(cfg.accel_noise_sigma_m_s2),
        )
    } else {
        (0.0, 0.0)
    };
    let mut w = World {
        t_s: 0.0,
        theta_m: Vector3::new(0.004, -0.003, 0.002),
        phase: Vector3::new(rng.random::<f64>(), rng.random(), rng.random())
            * std::f64::consts::TAU,
        omega: Vector3::zeros(),
        force: Vector3::new(0.0, 0.0, -9.81),
        next_manoeuvre_s: 1.0,
    };
    let mut now_us = c.start_us;
    let (mut resets, mut last_recoveries) = (0u64, 0u64);
    let mut k = 0u64;
    while k < c.steps {
        // Time stamp of the next sample.
        let interval = next_interval_us(&mut rng, dt_us, hostile);
        now_us += interval;
        w.t_s += interval as f64 * 1e-6;
        if hostile && w.t_s >= w.next_manoeuvre_s {
            w.manoeuvre(&mut rng);
        }
        let stamp = Timestamp::from_micros(now_us);
        let (master, slave) = w.samples(c, stamp, (rate_sigma, accel_sigma), &mut rng);
        let dropout = hostile && (k / 2000) % 10 == 9;
        if dropout {
            let r = f.propagate(stamp);
            tally.call("propagate", &r);
        } else {
            let r = f.step(&master, &slave);
            if tally.call("step", &r) {
                if let Ok(rep) = &r {
                    record(&mut tally, rep);
                }
            }
            // One covariance reset per epoch with a recovery, whatever the channels starved.
            let recoveries = channel_recoveries(&f);
            if recoveries > last_recoveries {
                resets += 1;
                last_recoveries = recoveries;
            }
        }
        k += 1;
        check_outputs(&mut tally, &f, k % PSD_EVERY == 0);
    }
    check_outputs(&mut tally, &f, true);
    let skipped = Channel::ALL.map(|c| u64::from(f.aid_counters(c).skipped));
    SKIPPED.fetch_add(skipped.iter().sum(), Ordering::Relaxed);
    REINITS.fetch_add(u64::from(f.health().gaps_reset), Ordering::Relaxed);
    RESETS.fetch_add(resets, Ordering::Relaxed);
    RECOVERIES.fetch_add(last_recoveries, Ordering::Relaxed);
    tally
}

fn run_one(c: &Case) -> Tally {
    if c.flight {
        run_case::<5, 15>(c)
    } else if c.proposed {
        run_case::<4, 12>(c)
    } else {
        run_case::<3, 9>(c)
    }
}

/// Runs the campaign at `level`.
pub fn run(level: StressLevel) -> EstimatorStress {
    let (grid_seconds, long_steps) = match level {
        StressLevel::Short => (10.0, 100_000),
        StressLevel::Full => (600.0, 10_000_000),
    };
    let cases = cases(grid_seconds, long_steps);
    for c in [&SKIPPED, &REINITS, &RESETS, &RECOVERIES] {
        c.store(0, Ordering::Relaxed);
    }
    let tallies: Vec<Tally> = cases.par_iter().map(run_one).collect();
    let mut out = EstimatorStress::default();
    for t in tallies {
        out.add(t);
    }
    out.coverage = coverage(grid_seconds, long_steps);
    out
}

/// The cases: both paper filters, then the flight configuration, over the grid of rates, σ,
/// τ and inputs (`grid_seconds` each), and the two long runs (`long_steps`); each its seed.
fn cases(grid_seconds: f64, long_steps: u64) -> Vec<Case> {
    let mut cases = Vec::new();
    let mut seed = 0u64;
    for rate_hz in [100u32, 200, 500, 1000] {
        for sigma_deg in [0.01, 0.1, 0.5, 2.0] {
            for tau_s in [0.05, 0.5, 5.0, 100.0, 1.0e4] {
                for proposed in [false, true] {
                    for inputs in [
                        Inputs::ConstantClean,
                        Inputs::Hostile,
                        Inputs::HostileNoiseCorners,
                    ] {
                        seed += 1;
                        cases.push(Case {
                            rate_hz,
                            sigma_deg,
                            tau_s,
                            proposed,
                            flight: false,
                            inputs,
                            steps: (grid_seconds * f64::from(rate_hz)) as u64,
                            start_us: 0,
                            seed,
                        });
                    }
                }
            }
        }
    }
    // The flight configuration over the same grid (appended: the paper filters' cases keep
    // their seeds).
    let mut flight_seed = 1_000_000u64;
    for rate_hz in [100u32, 200, 500, 1000] {
        for sigma_deg in [0.01, 0.1, 0.5, 2.0] {
            for tau_s in [0.05, 0.5, 5.0, 100.0, 1.0e4] {
                for inputs in [
                    Inputs::ConstantClean,
                    Inputs::Hostile,
                    Inputs::HostileNoiseCorners,
                ] {
                    flight_seed += 1;
                    cases.push(Case {
                        rate_hz,
                        sigma_deg,
                        tau_s,
                        proposed: true,
                        flight: true,
                        inputs,
                        steps: (grid_seconds * f64::from(rate_hz)) as u64,
                        start_us: 0,
                        seed: flight_seed,
                    });
                }
            }
        }
    }
    for proposed in [true, false] {
        seed += 1;
        cases.push(Case {
            rate_hz: 1000,
            sigma_deg: 0.5,
            tau_s: 2.146,
            proposed,
            flight: false,
            inputs: Inputs::Hostile,
            steps: long_steps,
            start_us: 1_000_000 * 1_000_000,
            seed,
        });
    }
    cases
}

/// The campaign's coverage lines.
fn coverage(grid_seconds: f64, long_steps: u64) -> Vec<String> {
    vec![
        format!(
            "both paper filters and the flight configuration (15 states), f32, 100/200/500/1000 Hz × σ 0.01/0.1/0.5/2° × τ 0.05/0.5/5/100/1e4 s × \
             (constant noise-free | noisy manoeuvres with jitter 0.5-1.5 dt, missing samples, \
             dropouts, long gaps | the same at the noise-envelope corners): {grid_seconds} s each"
        ),
        format!(
            "long runs: both filters at 1 kHz from t = 10⁶ s, {long_steps} steps each, noisy \
             jittered manoeuvres"
        ),
        "P checked every 100 calls and at the end (eps = f32::EPSILON); every report value, θ, \
         θ_m and σ checked finite"
            .into(),
        format!(
            "filters' own counts: {} updates skipped (not fusable in f32), {} flexure \
             re-initialisations (gaps beyond max_gap_steps), {} covariance resets (gate \
             starvation; {} channel recoveries)",
            SKIPPED.load(Ordering::Relaxed),
            REINITS.load(Ordering::Relaxed),
            RESETS.load(Ordering::Relaxed),
            RECOVERIES.load(Ordering::Relaxed)
        ),
    ]
}

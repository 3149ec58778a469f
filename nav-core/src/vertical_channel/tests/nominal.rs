//! The nominal step (`LoopCore::step_nominal`) against the general one: the same result and
//! the same loop, bit for bit, on every step of long seeded runs that visit every path —
//! nominal, jittered and bridged intervals, gaps too long to bridge, refused inputs of every
//! kind, gate rejections and rejection runs, lost aids and their re-acquisition, recovery
//! gates, starvation re-anchoring.

use super::super::core::{LoopCore, StepReports};
use super::*;
use std::format;

/// A small seeded generator (xorshift64*), reproducible across platforms.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    /// Uniform in [0, 1).
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    /// `true` with probability `p`.
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
    /// Uniform in [-a, a].
    fn sym(&mut self, a: f64) -> f64 {
        (2.0 * self.unit() - 1.0) * a
    }
}

/// What the run visited.
#[derive(Default, Debug)]
struct Visits {
    nominal: u32,
    general: u32,
    refused: u32,
    rejected: u32,
    reacquired: u32,
}

/// The hostile inputs of a run: the seeded generator, the clocks and the truth it draws from,
/// and the phases (outages of an aid, baro outliers, a large specific-force bias).
struct Hostile {
    rng: Rng,
    velocity_aid: bool,
    now_us: u64,
    last_baro_us: u64,
    last_vel_us: u64,
    alt: f64,
    vz: f64,
    baro_out: u32,
    vel_out: u32,
    outlier_run: u32,
    push: u32,
}

/// One step's inputs: the IMU sample (stamped `t_us`, µs) and the aid samples, if any.
struct Inputs<T> {
    t_us: u64,
    imu: ImuSample<T>,
    baro: Option<BaroSample<T>>,
    vel: Option<VelocitySample<T>>,
}

impl Hostile {
    fn new(seed: u64, velocity_aid: bool) -> Self {
        Self {
            rng: Rng(seed),
            velocity_aid,
            now_us: 0,
            last_baro_us: 0,
            last_vel_us: 0,
            alt: 500.0,
            vz: 0.0,
            baro_out: 0,
            vel_out: 0,
            outlier_run: 0,
            push: 0,
        }
    }

    /// The IMU sample: the interval mostly nominal, some jitter, some gaps, rarely a long gap
    /// or a stamp not after the loop's clock; the specific force sometimes NaN, out of range
    /// or biased.
    fn imu<T: Real>(&mut self) -> (u64, ImuSample<T>) {
        let rng = &mut self.rng;
        let dt_us: i64 = match rng.unit() {
            u if u < 0.80 => 10_000,
            u if u < 0.90 => 10_000 + (rng.sym(4_000.0) as i64),
            u if u < 0.95 => 10_000 * (2 + (rng.next() % 12) as i64),
            u if u < 0.953 => 10_500_000 + (rng.next() % 2_000_000) as i64,
            u if u < 0.96 => -((rng.next() % 20_000) as i64),
            _ => 10_000,
        };
        let t_us = (self.now_us as i64 + dt_us).max(0) as u64;
        if self.push == 0 && rng.chance(0.0005) {
            self.push = 3_000;
        }
        let bias = if self.push > 0 {
            self.push -= 1;
            150.0
        } else {
            0.0
        };
        let f = match rng.unit() {
            u if u < 0.003 => f64::NAN,
            u if u < 0.006 => 250.0,
            _ => 9.80 + bias + rng.sym(0.3),
        };
        let imu = ImuSample {
            time: Timestamp::from_micros(t_us),
            specific_force_up_m_s2: T::lit(f),
        };
        (t_us, imu)
    }

    /// The truth's step and the phases' counters.
    fn phases(&mut self) {
        let rng = &mut self.rng;
        self.vz += rng.sym(0.05);
        self.alt += self.vz * 0.01;
        if self.baro_out == 0 && rng.chance(0.002) {
            self.baro_out = (rng.next() % 300) as u32;
        }
        if self.vel_out == 0 && rng.chance(0.002) {
            self.vel_out = (rng.next() % 300) as u32;
        }
        if self.outlier_run == 0 && rng.chance(0.003) {
            self.outlier_run = (rng.next() % 40) as u32;
        }
        self.baro_out = self.baro_out.saturating_sub(1);
        self.vel_out = self.vel_out.saturating_sub(1);
        self.outlier_run = self.outlier_run.saturating_sub(1);
    }

    /// The next step's inputs.
    fn next<T: Real>(&mut self) -> Inputs<T> {
        let (t_us, imu) = self.imu::<T>();
        self.phases();
        // A sample's stamp: mostly the IMU's or a little before; sometimes in the future, not
        // after the previous one, or too old.
        let stamp = |rng: &mut Rng, last: &mut u64| -> u64 {
            let s = match rng.unit() {
                u if u < 0.85 => t_us.saturating_sub(rng.next() % 8_000),
                u if u < 0.90 => t_us + 1 + rng.next() % 5_000,
                u if u < 0.95 => *last,
                _ => t_us.saturating_sub(500_000 + rng.next() % 2_000_000),
            };
            *last = (*last).max(s);
            s
        };
        let (alt, vz, outlier_run) = (self.alt, self.vz, self.outlier_run);
        let rng = &mut self.rng;
        let baro = (self.baro_out == 0 && rng.chance(0.3)).then(|| {
            let value = match rng.unit() {
                u if u < 0.01 => f64::NAN,
                u if u < 0.02 => 70_000.0,
                _ if outlier_run > 0 => alt + 300.0,
                _ => alt + rng.sym(1.0),
            };
            BaroSample {
                time: Timestamp::from_micros(stamp(rng, &mut self.last_baro_us)),
                altitude_m: T::lit(value),
            }
        });
        let vel = (self.velocity_aid && self.vel_out == 0 && rng.chance(0.12)).then(|| {
            let value = match rng.unit() {
                u if u < 0.01 => f64::INFINITY,
                u if u < 0.02 => 2_000.0,
                _ if outlier_run > 0 => vz - 40.0,
                _ => vz + rng.sym(0.1),
            };
            VelocitySample {
                time: Timestamp::from_micros(stamp(rng, &mut self.last_vel_us)),
                vz_up_m_s: T::lit(value),
            }
        });
        Inputs {
            t_us,
            imu,
            baro,
            vel,
        }
    }
}

impl Visits {
    /// Counts one step: through the nominal step (`fast`) or the general one, and what its
    /// result `r` says.
    fn count<T: Real>(&mut self, fast: bool, r: &Result<StepReports<T>, NavError>) {
        if fast {
            self.nominal += 1;
        } else {
            self.general += 1;
        }
        match r {
            Err(_) => self.refused += 1,
            Ok(r) => {
                for rep in [&r.baro, &r.velocity] {
                    if let Some(s) = rep.sample {
                        if s.outcome == FusionOutcome::Rejected {
                            self.rejected += 1;
                        }
                    }
                    if !matches!(rep.reacquisition, Reacquisition::Tracking) {
                        self.reacquired += 1;
                    }
                }
            }
        }
    }
}

/// One hostile run of `steps` IMU samples through `a.step` and `b.step_general` (the same loop
/// twice); every result and the whole loop compared after every step (Debug strings: distinct
/// floats print differently, so this is bit-for-bit up to NaN payloads).
fn compare_run<T: Real>(mut a: LoopCore<T>, velocity_aid: bool, seed: u64, steps: u32) -> Visits {
    let mut b = a;
    let mut hostile = Hostile::new(seed, velocity_aid);
    let mut visits = Visits::default();
    for k in 0..steps {
        let Inputs {
            t_us,
            imu,
            baro,
            vel,
        } = hostile.next::<T>();
        let fast = {
            let mut c = a;
            c.step_nominal(&imu, baro.as_ref(), vel.as_ref()).is_some()
        };
        let ra = a.step(&imu, baro.as_ref(), vel.as_ref());
        let rb = b.step_general(&imu, baro.as_ref(), vel.as_ref());
        assert_eq!(
            format!("{ra:?}"),
            format!("{rb:?}"),
            "seed {seed} step {k}: reports differ"
        );
        assert_eq!(
            format!("{a:?}"),
            format!("{b:?}"),
            "seed {seed} step {k}: loops differ"
        );
        visits.count(fast, &ra);
        if ra.is_ok() {
            hostile.now_us = t_us;
        }
    }
    visits
}

fn gated<T: Real>(lp: &mut LoopCore<T>, gate: Gate<T>, starved_after_s: Option<f64>) {
    lp.set_gate(gate).unwrap();
    lp.set_recovery(RecoveryPolicy {
        starved_after_s: starved_after_s.map(T::lit),
        action: RecoveryAction::Reanchor,
    })
    .unwrap();
}

fn nominal_step_matches_general<T: Real>() {
    let mut total = Visits::default();
    for (seed, gate, starved) in [
        (1_u64, Gate::Off, None),
        (2, Gate::Nis(T::lit(10.83)), None),
        (3, Gate::Nis(T::lit(10.83)), Some(2.0)),
        (4, Gate::Nis(T::lit(3.84)), Some(0.5)),
    ] {
        let mut c = *ClassicalLoop::<T>::new(&classical_config(20.0, 0.2), &init(500.0))
            .unwrap()
            .core();
        gated(&mut c, gate, starved);
        let mut d = *AidedLoop::<T>::new(&aided_config(), &init(500.0))
            .unwrap()
            .core();
        gated(&mut d, gate, starved);
        for (lp, vel) in [(c, false), (d, true)] {
            let v = compare_run(lp, vel, seed * 7 + u64::from(vel), 10_000);
            total.nominal += v.nominal;
            total.general += v.general;
            total.refused += v.refused;
            total.rejected += v.rejected;
            total.reacquired += v.reacquired;
        }
    }
    std::println!("{} {total:?}", ::core::any::type_name::<T>());
    // The runs visited both paths and the rare events (so the comparison can fail).
    assert!(total.nominal > 40_000, "{total:?}");
    assert!(total.general > 20_000, "{total:?}");
    assert!(total.refused > 2_000, "{total:?}");
    assert!(total.rejected > 1_000, "{total:?}");
    assert!(total.reacquired > 200, "{total:?}");
}

#[test]
fn nominal_step_matches_general_step_bit_for_bit_f32_f64() {
    nominal_step_matches_general::<f32>();
    nominal_step_matches_general::<f64>();
}

/// The whole-µs timeouts of the nominal step: for limits across the configurable range
/// (including values at and just beside whole µs), the age in µs found is the last one whose
/// age in seconds is within the limit — the next one is not — in f32 and f64.
#[test]
fn age_limits_agree_with_the_comparison_in_seconds() {
    use super::super::age_limits::{last_micros_within, short_seconds};
    fn check<T: crate::Real + std::fmt::Debug>(limit_s: T) {
        let u = last_micros_within(limit_s);
        assert!(
            short_seconds::<T>(u) <= limit_s,
            "{limit_s:?}: {u} µs beyond"
        );
        if u < u32::MAX {
            assert!(
                short_seconds::<T>(u + 1) > limit_s,
                "{limit_s:?}: {} µs within",
                u + 1
            );
        }
    }
    let mut rng = Rng(0x5EED_0A6E);
    let mut limits = std::vec![1.0e-6, 0.02, 0.1, 0.25, 0.5, 1.0, 2.0, 3.0, 60.0, 3600.0];
    for _ in 0..2000 {
        limits.push(10f64.powf(rng.sym(4.0)));
    }
    for &l in &limits {
        for l in [l, l * (1.0 + 1e-7), l * (1.0 - 1e-7)] {
            check::<f32>(l as f32);
            check::<f64>(l);
        }
    }
    // Nothing is within a negative limit but an age of 0 is reported as the last (validated
    // timeouts are positive); every age is within one past 2³² µs.
    assert_eq!(last_micros_within(-1.0_f32), 0);
    assert_eq!(last_micros_within(1.0e4_f32), u32::MAX);
}

/// The nominal step's gate has no variance ceiling: an aid model whose variance could reach it
/// within the loss timeout (or has a negative term, so that its growth is not monotonic)
/// takes no sample in the nominal step; a model far below it keeps the whole-µs timeout.
#[test]
fn age_limits_leave_models_reaching_the_ceiling_to_the_general_step() {
    use super::super::age_limits::{last_micros_within, AgeLimits};
    use super::super::gate::AidGate;
    fn check<T: crate::Real + std::fmt::Debug>() {
        let to = AidTimeouts {
            stale_after_s: T::lit(0.2),
            lost_after_s: T::lit(1.0),
        };
        let aid = |tracking_var: f64, drift_rate: f64, drift_accel: f64| AidGate {
            tracking_var: T::lit(tracking_var),
            drift_rate: T::lit(drift_rate),
            drift_accel: T::lit(drift_accel),
        };
        let full = last_micros_within(to.lost_after_s);
        assert!(full > 0);
        assert_eq!(AgeLimits::new(&to, &aid(1.0, 2.0, 0.5)).lost_us, full);
        // d = 1e16 at the timeout: d² = 1e32 > the ceiling 1e30.
        assert_eq!(AgeLimits::new(&to, &aid(1.0, 1.0e16, 0.0)).lost_us, 0);
        assert_eq!(AgeLimits::new(&to, &aid(1.0, 0.0, 1.0e16)).lost_us, 0);
        assert_eq!(AgeLimits::new(&to, &aid(1.0, -1.0, 0.0)).lost_us, 0);
    }
    check::<f32>();
    check::<f64>();
}

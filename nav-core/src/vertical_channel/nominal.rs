//! The common step of normal flight, without the general machinery: an IMU interval of exactly
//! the nominal length, and each new aid sample one that the general step would fuse while
//! tracking (valid, after the held one, not lost, passing the gate, no recovery gate, no
//! rejection run, no re-anchoring pending; the new and the held sample younger than 2³² µs,
//! 71 min). Everything else — off-nominal and bridged intervals, refused inputs, rejections,
//! re-acquisitions, re-anchorings, a state that is not finite — is left to the general step
//! (`LoopCore::advance` and the gap bridge).
//!
//! The same formulas in the same order as the general step, so the two give bit-identical
//! results (the loops' tests run every case through both and compare): the difference is
//! only in what is checked and how. Nothing is written before every check has passed, so a
//! step that leaves here has changed nothing and the general step starts from the same state.

use super::core::{report, LoopCore, StepReports};
use super::gate::{saturate, AidGate, Verdict};
use super::samples::{AidChannel, AidStatus, AidTimeouts, BaroSample, ImuSample, VelocitySample};
use super::{Reacquisition, ALTITUDE_RANGE_M, MAX_SPECIFIC_FORCE_M_S2, MAX_VERTICAL_SPEED_M_S};
use crate::contract::{FusionOutcome, FusionReport};
use crate::time::Timestamp;
use crate::{HealthState, Real};
use nalgebra::Vector2;

/// A new sample that the nominal step can fuse: its value and age now (s and µs), and the
/// held sample's age now (s).
#[derive(Clone, Copy)]
struct Fresh<T> {
    time: Timestamp,
    value: T,
    age_s: T,
    old_age_s: T,
}

/// One channel's loss timeout as the nominal step tests it: the longest sample age in µs
/// (below 2³² µs) whose [`short_seconds`] is not above `lost_after_s`. A whole-µs age is
/// then lost exactly when it exceeds this — the same verdict as the comparison of its age in
/// seconds with the timeout, with one integer comparison instead of a float one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AgeLimits {
    lost_us: u32,
}

impl AgeLimits {
    /// The limit of `timeouts` (validated: positive, so an age of 0 is within it).
    pub(crate) fn new<T: Real>(timeouts: &AidTimeouts<T>) -> Self {
        Self {
            lost_us: last_micros_within(timeouts.lost_after_s),
        }
    }
}

/// The largest `u` (µs) with `short_seconds(u) ≤ limit_s` (0 if there is none), by bisection
/// over `u32` (`short_seconds` does not decrease with `u`: a conversion and a multiplication
/// by a positive constant, each monotonic). 32 halvings at most; run at construction only, so
/// one out-of-line copy.
#[inline(never)]
pub(super) fn last_micros_within<T: Real>(limit_s: T) -> u32 {
    let within = |u: u32| short_seconds::<T>(u) <= limit_s;
    if within(u32::MAX) {
        return u32::MAX;
    }
    // Invariant: `within(lo)` or `lo == 0`, and not `within(hi)`.
    let (mut lo, mut hi) = (0_u32, u32::MAX);
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if within(mid) {
            lo = mid;
        } else {
            hi = mid;
        }
    }
    lo
}

/// [`crate::time::micros_to_seconds`] of an interval shorter than 2³² µs (71 min), where it
/// is one conversion and one multiplication.
#[inline(always)]
pub(super) fn short_seconds<T: Real>(micros: u32) -> T {
    T::from_count(micros) * T::lit(1.0e-6)
}

/// `Some` when a new sample at `time` with `value` is one the nominal step fuses (the gate
/// test comes later): the value inside `range` (false for NaN), stamped after the held sample
/// and not after `now`, not older than `lost_after_s`, and the channel tracking (a sample held
/// and not lost, no recovery gate, no rejection run, no re-anchoring pending).
#[inline(always)]
fn fresh<T: Real>(
    ch: &AidChannel<T>,
    time: Timestamp,
    value: T,
    now: Timestamp,
    range: (f64, f64),
    limits: &AgeLimits,
) -> Option<Fresh<T>> {
    // In range (false for NaN); one test of the magnitude for a range symmetric about 0.
    let valid = if range.0 == -range.1 {
        value.abs() <= T::lit(range.1)
    } else {
        value >= T::lit(range.0) && value <= T::lit(range.1)
    };
    if !(ch.tracking && valid) {
        return None;
    }
    // The ages in µs, both below 2³² µs (longer ones are left to the general step): one
    // 64-bit difference each, its borrow and high word tested. The held sample was taken at
    // or before the loop's clock, so before `now`: its age does not wrap, and the new sample
    // is after it exactly when it is younger.
    let (age, late) = now.as_micros().overflowing_sub(time.as_micros());
    let age_us = u32::try_from(age).ok()?;
    let old_age_us = u32::try_from(now.as_micros().wrapping_sub(ch.last_time.as_micros())).ok()?;
    // Within `lost_after_s` (`AgeLimits`): the held sample, and so the younger new one.
    if late || age_us >= old_age_us || old_age_us > limits.lost_us {
        return None;
    }
    Some(Fresh {
        time,
        value,
        age_s: short_seconds::<T>(age_us),
        old_age_s: short_seconds::<T>(old_age_us),
    })
}

/// The gate of a new sample whose innovation is `innovation` (see `gate::admit`: the aid
/// model's variance from the drift since the held sample; the channel tracks, so no recovery
/// gate is held and the variance is the model's). `None`: rejected (left to the general step).
#[inline(always)]
fn gated<T: Real>(
    innovation: T,
    sample: &Fresh<T>,
    threshold: Option<T>,
    aid: &AidGate<T>,
) -> Option<Verdict<T>> {
    let nu2 = innovation * innovation;
    let gap = sample.old_age_s - sample.age_s;
    let d = gap * (aid.drift_rate + aid.drift_accel * gap);
    let model_var = saturate(aid.tracking_var + d * d);
    let (s, tested) = match threshold {
        Some(thr) => {
            let s = model_var;
            let pass = nu2 <= thr * s;
            if !pass {
                return None;
            }
            (s, Some(thr))
        }
        None => (model_var, None),
    };
    let nis = innovation * innovation / s;
    Some(Verdict {
        report: FusionReport {
            innovation,
            innovation_variance: s,
            nis,
            test_ratio: tested.map_or(T::zero(), |thr| nis / thr),
            outcome: FusionOutcome::Fused,
        },
        reacquisition: Reacquisition::Tracking,
    })
}

/// The held sample of a channel: its age now (s) and whether it is in use (received, not
/// lost).
#[inline(always)]
fn held<T: Real>(ch: &AidChannel<T>, now: Timestamp, to: &AidTimeouts<T>) -> (T, bool) {
    let age = ch.age(now);
    let lost = age > to.lost_after_s;
    (age, ch.received && !lost)
}

/// The freshness of a channel whose sample is `age_s` old (`new`: a sample that just entered,
/// received and not lost).
#[inline(always)]
fn status<T: Real>(ch: &AidChannel<T>, new: bool, age_s: T, to: &AidTimeouts<T>) -> AidStatus<T> {
    if !new {
        ch.status(age_s, to)
    } else if age_s > to.stale_after_s {
        AidStatus::Stale { age_s }
    } else {
        AidStatus::Fresh { age_s }
    }
}

impl<T: Real> LoopCore<T> {
    /// The nominal step (see the module documentation); `None` when this step is not one, and
    /// then nothing has changed.
    #[inline(always)]
    pub(crate) fn step_nominal(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Option<StepReports<T>> {
        let f = imu.specific_force_up_m_s2;
        let now = imu.time;
        // One test for finiteness and range (false for NaN), one for the interval.
        let force_ok = f.abs() <= T::lit(MAX_SPECIFIC_FORCE_M_S2);
        if !force_ok || self.nominal_us == 0 || now.micros_since(self.time) != Some(self.nominal_us)
        {
            return None;
        }
        let new_baro = match baro {
            Some(s) => Some(fresh(
                &self.baro,
                s.time,
                s.altitude_m,
                now,
                ALTITUDE_RANGE_M,
                &self.baro_limits,
            )?),
            None => None,
        };
        let new_velocity = match velocity {
            Some(s) => Some(fresh(
                &self.velocity,
                s.time,
                s.vz_up_m_s,
                now,
                (-MAX_VERTICAL_SPEED_M_S, MAX_VERTICAL_SPEED_M_S),
                &self.velocity_limits,
            )?),
            None => None,
        };
        // As `gate_samples` and `advance` with the nominal interval and no state moved.
        let x = self.x;
        let (alt, v, b) = (x.x, x.y, x.z);
        let h_ref = self.h_ref_m;
        let half_h = self.half_dt_s;
        let az = f - self.gravity.gravity_m_s2(h_ref + alt);
        let h_pred = alt - self.feedback.lag_s * v;
        let v_rate = az + self.feedback.bias_sign * b;
        let half = T::lit(0.5);
        // The sample each channel uses (new, else held) and whether it is in use.
        let (baro_value, baro_age, use_baro) = match &new_baro {
            Some(s) => (s.value, s.age_s, true),
            None => {
                let (age, in_use) = held(&self.baro, now, &self.baro_timeouts);
                (self.baro.last_value, age, in_use)
            }
        };
        let (vel_value, vel_age, use_vel) = match &new_velocity {
            Some(s) => (s.value, s.age_s, true),
            None => {
                let (age, in_use) = held(&self.velocity, now, &self.velocity_timeouts);
                (self.velocity.last_value, age, in_use)
            }
        };
        // Held samples extrapolated to the middle of the interval; for a new sample this is
        // its innovation.
        let nu_h = use_baro.then(|| {
            let age = baro_age - half_h;
            (baro_value - h_ref) + age * (v - half * v_rate * age) - h_pred
        });
        let nu_v = use_vel.then(|| vel_value + (vel_age - half_h) * v_rate - v);
        let threshold = self.gate.threshold;
        let baro_verdict = match (&new_baro, nu_h) {
            (Some(s), Some(nu)) => Some(gated(nu, s, threshold, &self.gate.baro)?),
            _ => None,
        };
        let vel_verdict = match (&new_velocity, nu_v) {
            (Some(s), Some(nu)) => Some(gated(nu, s, threshold, &self.gate.velocity)?),
            _ => None,
        };
        let mode = self.modes.select(use_baro, use_vel);
        let nu = Vector2::new(nu_h.unwrap_or(T::zero()), nu_v.unwrap_or(T::zero()));
        let drive = Vector2::new(v, v_rate);
        let x_new = x + (mode.n * drive + mode.g * nu);
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return None;
        }
        // Every check passed: commit.
        self.sigma.tick(self.nominal_us, use_baro, use_vel);
        if let Some(s) = new_baro {
            self.baro.last_time = s.time;
            self.baro.last_value = s.value;
        }
        if let Some(s) = new_velocity {
            self.velocity.last_time = s.time;
            self.velocity.last_value = s.value;
        }
        self.settle(x_new, h_ref);
        self.time = now;
        self.baro_tally.count(&baro_verdict);
        self.velocity_tally.count(&vel_verdict);
        // `health_state`, shortened where the checks above decided it: a new baro sample on a
        // tracking channel, and the velocity aid either never received or tracking with a new
        // sample, is `Nominal` unless the commit held the estimate at a limit.
        let velocity_fine = new_velocity.is_some() || !self.velocity.received;
        self.health.state = if new_baro.is_some() && velocity_fine && !self.baro.reanchor {
            HealthState::Nominal
        } else {
            self.health_state(false, use_baro, use_vel)
        };
        Some(StepReports {
            baro: report(
                status(
                    &self.baro,
                    new_baro.is_some(),
                    baro_age,
                    &self.baro_timeouts,
                ),
                nu_h,
                baro_verdict,
            ),
            velocity: report(
                status(
                    &self.velocity,
                    new_velocity.is_some(),
                    vel_age,
                    &self.velocity_timeouts,
                ),
                nu_v,
                vel_verdict,
            ),
            imu_intervals: 1,
        })
    }
}

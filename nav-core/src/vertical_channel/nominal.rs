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

use super::age_limits::{model_variance, short_seconds, AgeLimits};
use super::core::{report, LoopCore, StepReports};
use super::gate::{AidGate, Verdict};
use super::samples::{AidChannel, AidStatus, AidTimeouts, BaroSample, ImuSample, VelocitySample};
use super::{Reacquisition, ALTITUDE_RANGE_M, MAX_SPECIFIC_FORCE_M_S2, MAX_VERTICAL_SPEED_M_S};
use crate::contract::{FusionOutcome, FusionReport};
use crate::time::Timestamp;
use crate::{HealthState, Real};
use nalgebra::{Vector2, Vector3};

/// A new sample that the nominal step can fuse: its stamp (read again at the commit, not kept
/// in a register through the step), value and age now (s), and the held sample's age now (s).
#[derive(Clone, Copy)]
struct Fresh<'a, T> {
    time: &'a Timestamp,
    value: T,
    age_us: u32,
    age_s: T,
    old_age_s: T,
}

/// `Some` when a new sample at `time` with `value` is one the nominal step fuses (the gate
/// test comes later): the value inside `range` (false for NaN), stamped after the held sample
/// and not after `now`, not older than `lost_after_s`, and the channel tracking (a sample held
/// and not lost, no recovery gate, no rejection run, no re-anchoring pending).
#[inline(always)]
fn fresh<'a, T: Real>(
    ch: &AidChannel<T>,
    time: &'a Timestamp,
    value: T,
    now: Timestamp,
    range: (f64, f64),
    limits: &AgeLimits,
) -> Option<Fresh<'a, T>> {
    // In range (false for NaN); one test of the magnitude for a range symmetric about 0.
    let valid = if range.0 == -range.1 {
        value.abs() <= T::lit(range.1)
    } else {
        value >= T::lit(range.0) && value <= T::lit(range.1)
    };
    if !(ch.tracking && valid) {
        return None;
    }
    // The ages in µs, both below 2³² µs (longer ones are left to the general step). The held
    // sample's age first: within `lost_after_s` (`AgeLimits`, below 2³² µs), so also not
    // stamped after `now` (that age would wrap to beyond 2⁶⁴ − 2³² µs). The new sample is
    // after the held one and not after `now` exactly when its stamp's distance from the held
    // one's (wrapping) is in [1 µs, the held age]; its age is the held age less that distance.
    // Two 64-bit differences, their high words tested, the rest in 32 bits.
    let last = ch.last_time.as_micros();
    let old = now.as_micros().wrapping_sub(last);
    let gap = time.as_micros().wrapping_sub(last);
    let (old_hi, old_age_us) = ((old >> 32) as u32, old as u32);
    let (gap_hi, gap_us) = ((gap >> 32) as u32, gap as u32);
    if old_hi != 0 || old_age_us > limits.lost_us || gap_hi != 0 {
        return None;
    }
    let age_us = old_age_us.checked_sub(gap_us)?;
    if gap_us == 0 {
        return None;
    }
    Some(Fresh {
        time,
        value,
        age_us,
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
    sample: &Fresh<'_, T>,
    threshold: Option<T>,
    aid: &AidGate<T>,
) -> Option<Verdict<T>> {
    let nu2 = innovation * innovation;
    // Below the ceiling (`AgeLimits`): `saturate` would return it as it is.
    let model_var = model_variance(aid, sample.old_age_s - sample.age_s);
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

/// The freshness of a channel whose sample is `age_s` old (`new`: the age in µs of a sample
/// that just entered, received and not lost).
#[inline(always)]
fn status<T: Real>(
    ch: &AidChannel<T>,
    new: Option<u32>,
    age_s: T,
    to: &AidTimeouts<T>,
    limits: &AgeLimits,
) -> AidStatus<T> {
    match new {
        None => ch.status(age_s, to),
        Some(age_us) if age_us > limits.stale_us => AidStatus::Stale { age_s },
        Some(_) => AidStatus::Fresh { age_s },
    }
}

/// A new aid sample as the nominal step reads it: its stamp and value (m or m/s).
#[derive(Clone, Copy)]
struct Reading<'a, T> {
    time: &'a Timestamp,
    value: T,
}

/// One aid channel as the nominal step reads it: the channel, its age limits and timeouts,
/// its gate and the range its values are valid in (m or m/s).
struct ChannelView<'c, T> {
    ch: &'c AidChannel<T>,
    limits: &'c AgeLimits,
    timeouts: &'c AidTimeouts<T>,
    gate: &'c AidGate<T>,
    range: (f64, f64),
}

/// One channel's part of the nominal step: the new sample (if any), the correction `nu`
/// (m or m/s; 0 when not in use), whether the channel is in use, the age of the sample used
/// (s) and the new sample's verdict.
struct ChannelStep<'a, T> {
    new: Option<Fresh<'a, T>>,
    nu: T,
    in_use: bool,
    age_s: T,
    verdict: Option<Verdict<T>>,
}

/// A channel's part of the nominal step with `reading` (new) or the held sample:
/// `innovation(value, age_s)` is the sample extrapolated to the middle of the interval.
/// `None`: the new sample is not one the nominal step fuses (left to the general step).
#[inline(always)]
fn channel_step<'a, T: Real>(
    view: &ChannelView<'_, T>,
    reading: Option<Reading<'a, T>>,
    now: Timestamp,
    threshold: Option<T>,
    innovation: impl Fn(T, T) -> T,
) -> Option<ChannelStep<'a, T>> {
    match reading {
        Some(s) => {
            let new = fresh(view.ch, s.time, s.value, now, view.range, view.limits)?;
            let nu = innovation(new.value, new.age_s);
            let verdict = gated(nu, &new, threshold, view.gate)?;
            Some(ChannelStep {
                new: Some(new),
                nu,
                in_use: true,
                age_s: new.age_s,
                verdict: Some(verdict),
            })
        }
        None => {
            let (age, in_use) = held(view.ch, now, view.timeouts);
            let nu = if in_use {
                innovation(view.ch.last_value, age)
            } else {
                T::zero()
            };
            Some(ChannelStep {
                new: None,
                nu,
                in_use,
                age_s: age,
                verdict: None,
            })
        }
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
        let (interval_us, late) = now.as_micros().overflowing_sub(self.time.as_micros());
        if !force_ok || self.nominal_us == 0 || late || interval_us != u64::from(self.nominal_us) {
            return None;
        }
        // As `gate_samples` and `advance` with the nominal interval and no state moved.
        let x = self.x;
        let (alt, v, b) = (x.x, x.y, x.z);
        let h_ref = self.h_ref_m;
        let half_h = self.half_dt_s;
        let az = f - self.gravity.gravity_m_s2(h_ref + alt);
        let h_pred = alt - self.feedback.lag_s * v;
        let v_rate = az + self.feedback.bias_sign * b;
        let half = T::lit(0.5);
        let threshold = self.gate.threshold;
        // Each channel's sample (new, else held) extrapolated to the middle of the interval:
        // for a new sample this is its innovation, which the gate tests.
        let baro_nu = |value: T, age_s: T| {
            let age = age_s - half_h;
            (value - h_ref) + age * (v - half * v_rate * age) - h_pred
        };
        let vel_nu = |value: T, age_s: T| value + (age_s - half_h) * v_rate - v;
        // Per channel: the new sample (if any), the correction (0 when not in use), whether
        // the channel is in use, the age of the sample used and the new sample's verdict.
        let baro_ch = ChannelView {
            ch: &self.baro,
            limits: &self.baro_limits,
            timeouts: &self.baro_timeouts,
            gate: &self.gate.baro,
            range: ALTITUDE_RANGE_M,
        };
        let baro_reading = baro.map(|s| Reading {
            time: &s.time,
            value: s.altitude_m,
        });
        let b_step = channel_step(&baro_ch, baro_reading, now, threshold, baro_nu)?;
        let vel_ch = ChannelView {
            ch: &self.velocity,
            limits: &self.velocity_limits,
            timeouts: &self.velocity_timeouts,
            gate: &self.gate.velocity,
            range: (-MAX_VERTICAL_SPEED_M_S, MAX_VERTICAL_SPEED_M_S),
        };
        let vel_reading = velocity.map(|s| Reading {
            time: &s.time,
            value: s.vz_up_m_s,
        });
        let v_step = channel_step(&vel_ch, vel_reading, now, threshold, vel_nu)?;
        let (use_baro, use_vel) = (b_step.in_use, v_step.in_use);
        let mode = self.modes.select(use_baro, use_vel);
        let nu = Vector2::new(b_step.nu, v_step.nu);
        let drive = Vector2::new(v, v_rate);
        let x_new = x + (mode.n * drive + mode.g * nu);
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return None;
        }
        // Every check passed: commit.
        self.commit_nominal(now, x_new, h_ref, &b_step, &v_step);
        Some(self.nominal_reports(&b_step, &v_step))
    }

    /// The nominal step's commit, once every check has passed: σ's step, the new samples
    /// held, the state settled, the tallies and the health.
    #[inline(always)]
    fn commit_nominal(
        &mut self,
        now: Timestamp,
        x_new: Vector3<T>,
        h_ref: T,
        baro: &ChannelStep<'_, T>,
        velocity: &ChannelStep<'_, T>,
    ) {
        let (use_baro, use_vel) = (baro.in_use, velocity.in_use);
        if !self.sigma.holds(use_baro, use_vel) {
            self.tick_sigma_nominal(use_baro, use_vel);
        }
        if let Some(s) = baro.new {
            self.baro.last_time = *s.time;
            self.baro.last_value = s.value;
        }
        if let Some(s) = velocity.new {
            self.velocity.last_time = *s.time;
            self.velocity.last_value = s.value;
        }
        self.settle(x_new, h_ref);
        self.time = now;
        self.baro_tally.count(&baro.verdict);
        self.velocity_tally.count(&velocity.verdict);
        // `health_state`, shortened where the checks above decided it: a new baro sample on a
        // tracking channel, and the velocity aid either never received or tracking with a new
        // sample, is `Nominal` unless the commit held the estimate at a limit.
        let velocity_fine = velocity.new.is_some() || !self.velocity.received;
        self.health.state = if baro.new.is_some() && velocity_fine && !self.baro.reanchor {
            HealthState::Nominal
        } else {
            self.health_state(false, use_baro, use_vel)
        };
    }

    /// The nominal step's reports, after its commit.
    #[inline(always)]
    fn nominal_reports(
        &self,
        baro: &ChannelStep<'_, T>,
        velocity: &ChannelStep<'_, T>,
    ) -> StepReports<T> {
        StepReports {
            baro: report(
                status(
                    &self.baro,
                    baro.new.map(|s| s.age_us),
                    baro.age_s,
                    &self.baro_timeouts,
                    &self.baro_limits,
                ),
                baro.in_use.then_some(baro.nu),
                baro.verdict,
            ),
            velocity: report(
                status(
                    &self.velocity,
                    velocity.new.map(|s| s.age_us),
                    velocity.age_s,
                    &self.velocity_timeouts,
                    &self.velocity_limits,
                ),
                velocity.in_use.then_some(velocity.nu),
                velocity.verdict,
            ),
            imu_intervals: 1,
        }
    }

    /// σ's step over the nominal interval when it is not settled in the design mode (out of
    /// line: the interval is read here, not kept through the nominal step).
    #[cold]
    #[inline(never)]
    fn tick_sigma_nominal(&mut self, use_baro: bool, use_vel: bool) {
        self.sigma
            .tick(u64::from(self.nominal_us), use_baro, use_vel);
    }
}

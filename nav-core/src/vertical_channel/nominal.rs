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
use crate::Bounds;
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
    range: Bounds,
    limits: &AgeLimits,
) -> Option<Fresh<'a, T>> {
    // In range (false for NaN); one test of the magnitude for a range symmetric about 0.
    let valid = if range.low == -range.high {
        value.abs() <= T::lit(range.high)
    } else {
        value >= T::lit(range.low) && value <= T::lit(range.high)
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

/// A channel's part of the nominal step — the new sample (if any), the correction (0 when not
/// in use), whether the channel is in use, the age of the sample used and the new sample's
/// verdict — with the new sample `$sample` (its value in field `$value`, valid in `$range`)
/// or the held one, on the loop's channel `$self.$ch` (age limits `$self.$limits`, timeouts
/// `$self.$timeouts`, gate `$self.gate.$ch`, the gate's threshold `$threshold`);
/// `$nu(value, age_s)` is the sample extrapolated to the middle of the interval. A new sample
/// the nominal step does not fuse returns `None` from the step (left to the general step).
/// Written out in the step, not a function: the step's generated code stays that of the
/// straight-line form (as an `#[inline(always)]` function returning the channel's part it
/// cost the aided step 4 instructions and the classical 6, measured on QEMU).
macro_rules! channel_step {
    ($self:ident . $ch:ident, $limits:ident, $timeouts:ident; $sample:expr, $value:ident,
     $range:expr; $now:ident, $threshold:ident, $nu:ident) => {
        match $sample {
            Some(s) => {
                let new = fresh(&$self.$ch, &s.time, s.$value, $now, $range, &$self.$limits)?;
                let nu = $nu(new.value, new.age_s);
                let verdict = gated(nu, &new, $threshold, &$self.gate.$ch)?;
                (Some(new), nu, true, new.age_s, Some(verdict))
            }
            None => {
                let (age, in_use) = held(&$self.$ch, $now, &$self.$timeouts);
                let nu = if in_use {
                    $nu($self.$ch.last_value, age)
                } else {
                    T::zero()
                };
                (None, nu, in_use, age, None)
            }
        }
    };
}

/// The nominal step's new samples (if any) and whether each channel is in use.
struct NewSamples<'a, T> {
    baro: Option<Fresh<'a, T>>,
    velocity: Option<Fresh<'a, T>>,
    baro_in_use: bool,
    velocity_in_use: bool,
}

/// The verdicts on the nominal step's new samples.
struct Verdicts<'v, T> {
    baro: &'v Option<Verdict<T>>,
    velocity: &'v Option<Verdict<T>>,
}

/// What a channel's report of the nominal step says: the new sample's age (µs), the age of
/// the sample used (s), the correction (m or m/s; `None` when not in use) and the verdict.
struct ChannelReport<T> {
    new_age_us: Option<u32>,
    age_s: T,
    correction: Option<T>,
    verdict: Option<Verdict<T>>,
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
        // Each channel's sample (new, else held) at mid-interval: a new one's gated innovation.
        let baro_nu = |value: T, age_s: T| {
            let age = age_s - half_h;
            (value - h_ref) + age * (v - half * v_rate * age) - h_pred
        };
        let vel_nu = |value: T, age_s: T| value + (age_s - half_h) * v_rate - v;
        // Per channel (`channel_step!`): new sample, correction, in use, age, verdict.
        let (new_baro, nu_h, use_baro, baro_age, baro_verdict) = channel_step!(
            self.baro, baro_limits, baro_timeouts;
            baro, altitude_m, ALTITUDE_RANGE_M;
            now, threshold, baro_nu
        );
        let (new_velocity, nu_v, use_vel, vel_age, vel_verdict) = channel_step!(
            self.velocity, velocity_limits, velocity_timeouts;
            velocity, vz_up_m_s, Bounds { low: -MAX_VERTICAL_SPEED_M_S, high: MAX_VERTICAL_SPEED_M_S };
            now, threshold, vel_nu
        );
        let mode = self.modes.select(use_baro, use_vel);
        let nu = Vector2::new(nu_h, nu_v);
        let (nu_h, nu_v) = (use_baro.then_some(nu_h), use_vel.then_some(nu_v));
        let drive = Vector2::new(v, v_rate);
        let x_new = x + (mode.n * drive + mode.g * nu);
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return None;
        }
        // Every check passed: commit.
        self.commit_nominal(
            now,
            x_new,
            h_ref,
            NewSamples {
                baro: new_baro,
                velocity: new_velocity,
                baro_in_use: use_baro,
                velocity_in_use: use_vel,
            },
            Verdicts {
                baro: &baro_verdict,
                velocity: &vel_verdict,
            },
        );
        Some(self.nominal_reports(
            ChannelReport {
                new_age_us: new_baro.map(|s| s.age_us),
                age_s: baro_age,
                correction: nu_h,
                verdict: baro_verdict,
            },
            ChannelReport {
                new_age_us: new_velocity.map(|s| s.age_us),
                age_s: vel_age,
                correction: nu_v,
                verdict: vel_verdict,
            },
        ))
    }

    /// The nominal step's commit, once every check has passed: σ's step, the new samples
    /// held, the state settled, the tallies and the health.
    #[inline(always)]
    fn commit_nominal(
        &mut self,
        now: Timestamp,
        x_new: Vector3<T>,
        h_ref: T,
        new: NewSamples<'_, T>,
        verdicts: Verdicts<'_, T>,
    ) {
        let (use_baro, use_vel) = (new.baro_in_use, new.velocity_in_use);
        let (new_baro, new_velocity) = (new.baro, new.velocity);
        let (baro_verdict, vel_verdict) = (verdicts.baro, verdicts.velocity);
        if !self.sigma.holds(use_baro, use_vel) {
            self.tick_sigma_nominal(use_baro, use_vel);
        }
        if let Some(s) = new_baro {
            self.baro.last_time = *s.time;
            self.baro.last_value = s.value;
        }
        if let Some(s) = new_velocity {
            self.velocity.last_time = *s.time;
            self.velocity.last_value = s.value;
        }
        self.settle(x_new, h_ref);
        self.time = now;
        self.baro_tally.count(baro_verdict);
        self.velocity_tally.count(vel_verdict);
        // `health_state`, shortened where the checks above decided it: a new baro sample on a
        // tracking channel, and the velocity aid either never received or tracking with a new
        // sample, is `Nominal` unless the commit held the estimate at a limit.
        let velocity_fine = new_velocity.is_some() || !self.velocity.received;
        self.health.state = if new_baro.is_some() && velocity_fine && !self.baro.reanchor {
            HealthState::Nominal
        } else {
            self.health_state(false, use_baro, use_vel)
        };
    }

    /// The nominal step's reports, after its commit.
    #[inline(always)]
    fn nominal_reports(&self, b: ChannelReport<T>, v: ChannelReport<T>) -> StepReports<T> {
        StepReports {
            baro: report(
                status(
                    &self.baro,
                    b.new_age_us,
                    b.age_s,
                    &self.baro_timeouts,
                    &self.baro_limits,
                ),
                b.correction,
                b.verdict,
            ),
            velocity: report(
                status(
                    &self.velocity,
                    v.new_age_us,
                    v.age_s,
                    &self.velocity_timeouts,
                    &self.velocity_limits,
                ),
                v.correction,
                v.verdict,
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

//! Time-stamped inputs of the loops, the initial state, the aids' freshness and the held aid
//! sample of each channel, with their validation.

use super::{ALTITUDE_RANGE_M, MAX_ESTIMATE_BIAS_M_S2, MAX_ESTIMATE_SPEED_M_S};
use super::{MAX_SPECIFIC_FORCE_M_S2, MAX_TIMEOUT_S};
use crate::error::{require_positive, ConfigIssue};
use crate::time::{micros_to_seconds, Timestamp};
use crate::Bounds;
use crate::{NavError, Real};

/// One IMU sample: the vertical component of the specific force, averaged over the interval
/// that ends at `time`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample<T> {
    /// End of the IMU interval (the flight computer's clock).
    pub time: Timestamp,
    /// Vertical specific force, up positive, m/s² (≈ +g at rest). The loops integrate
    /// `V̇_z = specific_force_up_m_s2 − g(ĥ)`: on a vehicle moving over the earth add the
    /// vertical Coriolis and transport-rate acceleration `[(2ω_ie + ω_en) × v]_D` (≈ 3 mg at
    /// 200 m/s east), as the flight navigator does.
    pub specific_force_up_m_s2: T,
}

/// One barometric altitude sample.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BaroSample<T> {
    /// Time of validity (same clock as the IMU).
    pub time: Timestamp,
    /// Barometric altitude, m, up positive.
    pub altitude_m: T,
}

/// One vertical-velocity aid sample (GNSS Doppler, air data …).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocitySample<T> {
    /// Time of validity (same clock as the IMU).
    pub time: Timestamp,
    /// Vertical velocity, m/s, up positive.
    pub vz_up_m_s: T,
}

/// Initial (or re-initialisation) state of a loop.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InitialState<T> {
    /// Time of the initial state (the first IMU sample ends the first interval after it).
    pub time: Timestamp,
    /// Initial altitude estimate, m, up positive.
    pub altitude_m: T,
    /// Initial vertical velocity estimate, m/s, up positive.
    pub vz_up_m_s: T,
    /// Initial accelerometer bias estimate (measured − true), m/s².
    pub accel_bias_m_s2: T,
}

/// The aids of the vertical channel (the argument of `aid_counters`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Aid {
    /// Barometric altitude.
    Baro,
    /// Vertical velocity aid (the aided loop only; the classical loop reports zero counters).
    Velocity,
}

/// Freshness of an aid at the end of a step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AidStatus<T> {
    /// Latest sample not older than `stale_after_s`: used.
    Fresh {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// Latest sample older than `stale_after_s` but not than `lost_after_s`: still used,
    /// extrapolated with the estimated vertical velocity.
    Stale {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// Latest sample older than `lost_after_s`: dropped, the loop runs on the IMU alone.
    Lost {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// No sample received yet: the loop runs on the IMU alone.
    NoData,
}

impl<T> AidStatus<T> {
    /// `true` for `Fresh` and `Stale` (the aid corrects the loop).
    pub fn in_use(&self) -> bool {
        matches!(self, AidStatus::Fresh { .. } | AidStatus::Stale { .. })
    }
}

/// Freshness timeouts of one aid.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidTimeouts<T> {
    /// Age beyond which the aid is reported `Stale` (still used), s (> 0, ≤ [`MAX_TIMEOUT_S`]).
    pub stale_after_s: T,
    /// Age beyond which the aid is `Lost` (dropped), s; ≥ `stale_after_s`, ≤ [`MAX_TIMEOUT_S`].
    pub lost_after_s: T,
}

impl<T: Real> AidTimeouts<T> {
    /// Validates the timeouts; `stale` and `lost` name the fields in the error.
    #[inline(never)]
    pub(crate) fn validate(&self, stale: &'static str, lost: &'static str) -> Result<(), NavError> {
        require_positive(stale, self.stale_after_s)?;
        require_positive(lost, self.lost_after_s)?;
        for (field, v) in [(stale, self.stale_after_s), (lost, self.lost_after_s)] {
            if v > T::lit(MAX_TIMEOUT_S) {
                return Err(NavError::InvalidConfig {
                    field,
                    issue: ConfigIssue::OutOfRange,
                });
            }
        }
        if self.lost_after_s < self.stale_after_s {
            return Err(NavError::InvalidConfig {
                field: lost,
                issue: ConfigIssue::OutOfRange,
            });
        }
        Ok(())
    }
}

/// Seconds from `earlier` to `later` in the loop's float type (0 if `later` is earlier).
#[inline(always)]
pub(crate) fn secs_between<T: Real>(later: Timestamp, earlier: Timestamp) -> T {
    micros_to_seconds(later.micros_since(earlier).unwrap_or(0))
}

/// "No time" in the channels' optional time fields (the end of the clock).
pub(crate) const NEVER: Timestamp = Timestamp::from_micros(u64::MAX);

/// A validated aid sample (time and value), not yet gated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ValidSample<T> {
    pub(crate) time: Timestamp,
    pub(crate) value: T,
    /// Age at the step's IMU time (the time it was checked against and enters at), s.
    pub(crate) age_s: T,
}

/// A held aid sample, its recovery-gate state and its re-anchoring flag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AidChannel<T> {
    pub(crate) last_time: Timestamp,
    pub(crate) last_value: T,
    pub(crate) received: bool,
    /// Gate variance held after a re-acquisition until the innovations have stayed inside
    /// the tracking gate for `recovery_hold_s` (0: tracking).
    pub(crate) recovery_var: T,
    /// Time since which the innovations are inside the tracking gate during a recovery
    /// ([`NEVER`]: not inside).
    pub(crate) recovery_clear_since: Timestamp,
    /// Time stamp of the first sample of the current run of gate rejections ([`NEVER`]:
    /// the last sample was accepted).
    pub(crate) rejected_since: Timestamp,
    /// The next sample is accepted outside the gate and re-anchors the measured state.
    pub(crate) reanchor: bool,
    /// The channel tracks: a sample received, no re-anchoring pending, no rejection run, no
    /// recovery gate held — the state in which the nominal step may take its next sample
    /// (kept by [`Self::refresh_tracking`] after every change of the other fields).
    pub(crate) tracking: bool,
}

/// What one aid's sample is checked against: its name, physical range and timeouts.
pub(crate) struct SampleRule<T> {
    pub(crate) value_name: &'static str,
    pub(crate) range: Bounds,
    pub(crate) lost_after_s: T,
}

impl<T: Real> AidChannel<T> {
    pub(crate) fn new() -> Self {
        Self {
            last_time: Timestamp::ZERO,
            last_value: T::zero(),
            received: false,
            recovery_var: T::zero(),
            recovery_clear_since: NEVER,
            rejected_since: NEVER,
            reanchor: false,
            tracking: false,
        }
    }

    /// Sets [`Self::tracking`] from the other fields.
    #[inline(always)]
    pub(crate) fn refresh_tracking(&mut self) {
        let recovering = self.recovery_var > T::zero();
        self.tracking =
            self.received && !self.reanchor && self.rejected_since == NEVER && !recovering;
    }

    /// The channel after a gap too long to bridge: empty, the next sample re-anchors.
    pub(crate) fn after_long_gap() -> Self {
        Self {
            reanchor: true,
            ..Self::new()
        }
    }

    /// Validates a new sample against the channel and the current IMU time `now` (self is
    /// not modified); `emptied`: the channel is emptied before the sample enters (a gap too
    /// long to bridge), so the previous sample's time does not count. A sample older than the
    /// aid's `lost_after_s` at arrival would be `Lost` at once: it is refused
    /// (`MeasurementTimeOutOfWindow`, as one from the future).
    #[inline(always)]
    pub(crate) fn check(
        &self,
        time: Timestamp,
        value: T,
        now: Timestamp,
        rule: &SampleRule<T>,
        emptied: bool,
    ) -> Result<ValidSample<T>, NavError> {
        if !value.is_finite() {
            return Err(NavError::NonFiniteInput {
                input: rule.value_name,
            });
        }
        if value < T::lit(rule.range.low) || value > T::lit(rule.range.high) {
            return Err(NavError::InputOutOfRange {
                input: rule.value_name,
            });
        }
        let age_s = match now.micros_since(time).map(micros_to_seconds::<T>) {
            Some(age_s) if age_s <= rule.lost_after_s => age_s,
            _ => return Err(NavError::MeasurementTimeOutOfWindow),
        };
        if self.received && !emptied && time <= self.last_time {
            return Err(NavError::TimeNotIncreasing);
        }
        Ok(ValidSample { time, value, age_s })
    }

    /// The channel holding `sample` (gate state kept).
    #[inline(always)]
    pub(crate) fn with(&self, sample: ValidSample<T>) -> Self {
        Self {
            last_time: sample.time,
            last_value: sample.value,
            received: true,
            ..*self
        }
    }

    /// Age of the held sample at `now`, s (0 before the first sample).
    #[inline(always)]
    pub(crate) fn age(&self, now: Timestamp) -> T {
        if self.received {
            secs_between::<T>(now, self.last_time)
        } else {
            T::zero()
        }
    }

    /// Freshness with `age_s` the age of the held sample now.
    #[inline(always)]
    pub(crate) fn status(&self, age_s: T, to: &AidTimeouts<T>) -> AidStatus<T> {
        if !self.received {
            return AidStatus::NoData;
        }
        if age_s > to.lost_after_s {
            AidStatus::Lost { age_s }
        } else if age_s > to.stale_after_s {
            AidStatus::Stale { age_s }
        } else {
            AidStatus::Fresh { age_s }
        }
    }
}

/// Checks an IMU sample's values (the interval is checked by the loop).
#[inline(always)]
pub(crate) fn check_imu_values<T: Real>(imu: &ImuSample<T>) -> Result<(), NavError> {
    if !imu.specific_force_up_m_s2.is_finite() {
        return Err(NavError::NonFiniteInput {
            input: "specific_force_up_m_s2",
        });
    }
    if imu.specific_force_up_m_s2.abs() > T::lit(MAX_SPECIFIC_FORCE_M_S2) {
        return Err(NavError::InputOutOfRange {
            input: "specific_force_up_m_s2",
        });
    }
    Ok(())
}

/// Validates an initial state.
#[inline(never)]
pub(crate) fn check_initial<T: Real>(init: &InitialState<T>) -> Result<(), NavError> {
    for (name, v) in [
        ("initial altitude_m", init.altitude_m),
        ("initial vz_up_m_s", init.vz_up_m_s),
        ("initial accel_bias_m_s2", init.accel_bias_m_s2),
    ] {
        if !v.is_finite() {
            return Err(NavError::NonFiniteInput { input: name });
        }
    }
    if init.altitude_m < T::lit(ALTITUDE_RANGE_M.low)
        || init.altitude_m > T::lit(ALTITUDE_RANGE_M.high)
    {
        return Err(NavError::InputOutOfRange {
            input: "initial altitude_m",
        });
    }
    if init.vz_up_m_s.abs() > T::lit(MAX_ESTIMATE_SPEED_M_S) {
        return Err(NavError::InputOutOfRange {
            input: "initial vz_up_m_s",
        });
    }
    if init.accel_bias_m_s2.abs() > T::lit(MAX_ESTIMATE_BIAS_M_S2) {
        return Err(NavError::InputOutOfRange {
            input: "initial accel_bias_m_s2",
        });
    }
    Ok(())
}

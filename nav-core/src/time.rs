//! Time stamps as integer microseconds, so that the precision of `f32` never matters.
//!
//! Every estimator takes [`Timestamp`]s: the flight computer's clock in whole microseconds
//! since an arbitrary epoch (boot, GPS week, the start of a log). Differences are formed in
//! integers and converted to the filter's float type only as a *duration*, which is small and
//! exact enough in `f32` (a 10 ms interval is exact to 0.6 ns). A filter that has run for 10⁶ s
//! computes its intervals exactly as it did in its first second — no time stamp is ever held
//! in a float.
//!
//! ```
//! use nav_core::time::Timestamp;
//! let t0 = Timestamp::from_micros(3_600_000_000); // one hour after boot
//! let t1 = t0.add_micros(10_000);                  // 10 ms later
//! let dt: f32 = t1.seconds_since(t0).unwrap();
//! assert_eq!(dt, 0.01);
//! assert!(t0.seconds_since::<f32>(t1).is_err());    // time never runs backwards
//! ```
//!
//! The clock is `u64` microseconds, as PX4's `hrt_abstime`: 584 000 years of range.

use crate::{NavError, Real};

/// Microseconds per second.
pub const MICROS_PER_SECOND: u64 = 1_000_000;

/// A point in time: whole microseconds since the flight computer's epoch.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Timestamp {
    micros: u64,
}

impl Timestamp {
    /// The epoch itself (0 µs).
    pub const ZERO: Self = Self { micros: 0 };

    /// From whole microseconds since the epoch.
    #[inline]
    pub const fn from_micros(micros: u64) -> Self {
        Self { micros }
    }

    /// From whole milliseconds since the epoch (saturating at the end of the clock).
    #[inline]
    pub const fn from_millis(millis: u64) -> Self {
        Self {
            micros: millis.saturating_mul(1_000),
        }
    }

    /// From seconds since the epoch, rounded to the nearest microsecond. For host tools and
    /// logs whose clocks are floating-point seconds; refused (`NonFiniteInput` /
    /// `InputOutOfRange { input: "time stamp" }`) when not finite, negative or beyond 2⁵³ µs
    /// (285 years, where `f64` stops resolving a microsecond).
    pub fn from_secs_f64(seconds: f64) -> Result<Self, NavError> {
        if !seconds.is_finite() {
            return Err(NavError::NonFiniteInput {
                input: "time stamp",
            });
        }
        let micros = seconds * 1.0e6;
        if !(0.0..=9.007_199_254_740_992e15).contains(&micros) {
            return Err(NavError::InputOutOfRange {
                input: "time stamp",
            });
        }
        // In range and finite: the conversion is exact after rounding.
        Ok(Self {
            micros: libm::round(micros) as u64,
        })
    }

    /// Whole microseconds since the epoch.
    #[inline]
    pub const fn as_micros(self) -> u64 {
        self.micros
    }

    /// Seconds since the epoch as `f64` (for logs and plots; exact below 2⁵³ µs).
    #[inline]
    pub fn as_secs_f64(self) -> f64 {
        self.micros as f64 * 1.0e-6
    }

    /// This time plus `micros` (saturating at the end of the clock).
    #[inline]
    #[must_use]
    pub const fn add_micros(self, micros: u64) -> Self {
        Self {
            micros: self.micros.saturating_add(micros),
        }
    }

    /// Whole microseconds from `earlier` to `self`; `None` when `earlier` is later than `self`.
    #[inline]
    pub const fn micros_since(self, earlier: Self) -> Option<u64> {
        self.micros.checked_sub(earlier.micros)
    }

    /// The interval from `earlier` to `self` in seconds, in the filter's float type.
    /// `TimeNotIncreasing` unless `self` is strictly later than `earlier`.
    #[inline]
    pub fn seconds_since<T: Real>(self, earlier: Self) -> Result<T, NavError> {
        match self.micros.checked_sub(earlier.micros) {
            Some(d) if d > 0 => Ok(micros_to_seconds(d)),
            _ => Err(NavError::TimeNotIncreasing),
        }
    }

    /// The signed interval from `other` to `self` in seconds (negative when `self` is earlier).
    #[inline]
    pub fn signed_seconds_since<T: Real>(self, other: Self) -> T {
        if self.micros >= other.micros {
            micros_to_seconds(self.micros - other.micros)
        } else {
            -micros_to_seconds::<T>(other.micros - self.micros)
        }
    }
}

/// `micros` µs in seconds, rounded once to `T` for intervals up to 2³² µs (71 min) and to
/// within two roundings beyond. Integer-to-float conversions only (no `f64` on an `f32`
/// target).
#[inline]
pub fn micros_to_seconds<T: Real>(micros: u64) -> T {
    let hi = (micros >> 32) as u32;
    let lo = micros as u32;
    let lo_s = T::from_count(lo) * T::lit(1.0e-6);
    if hi == 0 {
        lo_s
    } else {
        T::from_count(hi) * T::lit(4_294.967_296) + lo_s
    }
}

/// A duration in seconds as whole microseconds, rounded to nearest; `None` when not finite,
/// negative or beyond `u32::MAX` µs (71 min). For configuration values (`dt_s`, timeouts).
pub fn seconds_to_micros<T: Real>(seconds: T) -> Option<u64> {
    (seconds * T::lit(1.0e6)).to_u32_rounded().map(u64::from)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn intervals_are_exact_after_a_long_run() {
        // 10⁶ s after the epoch a 1 ms interval still reads 1 ms in f32.
        let t0 = Timestamp::from_micros(1_000_000 * MICROS_PER_SECOND);
        let t1 = t0.add_micros(1_000);
        assert_eq!(t1.seconds_since::<f32>(t0), Ok(0.001_f32));
        assert_eq!(t1.seconds_since::<f64>(t0), Ok(0.001_f64));
        assert_eq!(
            t0.seconds_since::<f32>(t0),
            Err(NavError::TimeNotIncreasing)
        );
        assert_eq!(t0.signed_seconds_since::<f64>(t1), -0.001);
    }

    #[test]
    fn long_intervals_convert_within_rounding() {
        for us in [1_u64 << 32, (1 << 32) + 123_456, 10_000 * MICROS_PER_SECOND] {
            let s: f64 = micros_to_seconds(us);
            assert!((s - us as f64 * 1e-6).abs() <= 1e-9 * s, "{us}");
        }
    }

    #[test]
    fn seconds_round_trip() {
        let t = Timestamp::from_secs_f64(12.345_678_9).unwrap();
        assert_eq!(t.as_micros(), 12_345_679);
        assert!(Timestamp::from_secs_f64(-1.0).is_err());
        assert!(Timestamp::from_secs_f64(f64::NAN).is_err());
        assert!(Timestamp::from_secs_f64(1e300).is_err());
        assert_eq!(seconds_to_micros(0.01_f32), Some(10_000));
        assert_eq!(seconds_to_micros(-0.01_f32), None);
    }
}

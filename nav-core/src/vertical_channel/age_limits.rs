//! The aid timeouts as whole-µs ages ([`AgeLimits`]), for the nominal step's integer age
//! tests, with the conversion of short intervals they are exact for; kept apart from the
//! nominal step so that `core` (which holds the limits) and `nominal` (which reads them)
//! both depend on it and not on each other.

use super::gate::AidGate;
use super::samples::AidTimeouts;
use super::MAX_GATE_VARIANCE;
use crate::Real;

/// One channel's timeouts as the nominal step tests them: the longest sample age in µs
/// (below 2³² µs) whose [`short_seconds`] is not above `lost_after_s` (`stale_after_s`). A
/// whole-µs age is then lost (stale) exactly when it exceeds this — the same verdict as the
/// comparison of its age in seconds with the timeout, with one integer comparison instead of
/// a float one.
///
/// 0 (no new sample is taken by the nominal step) when the aid model's variance could reach
/// the gate's ceiling within that age: the nominal step's gate then needs no ceiling.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AgeLimits {
    pub(super) lost_us: u32,
    /// The same for `stale_after_s` (not 0 with the model: only the freshness reported).
    pub(super) stale_us: u32,
}

impl AgeLimits {
    /// The limit of `timeouts` (validated: positive, so an age of 0 is within it) with the aid
    /// model `aid` (validated, refreshed whenever it changes). Out of line: construction and
    /// the run-time setters share one copy.
    #[inline(never)]
    pub(crate) fn new<T: Real>(timeouts: &AidTimeouts<T>, aid: &AidGate<T>) -> Self {
        let lost_us = last_micros_within(timeouts.lost_after_s);
        // The model variance does not decrease with the gap when its terms are not negative
        // (each operation is monotonic then, rounding included), and the gap between two
        // samples the nominal step takes is at most the held sample's age: its value at the
        // longest age bounds every one the nominal step computes.
        let monotonic = aid.tracking_var >= T::zero()
            && aid.drift_rate >= T::zero()
            && aid.drift_accel >= T::zero();
        let worst = model_variance(aid, short_seconds::<T>(lost_us));
        let below_ceiling = worst <= T::lit(MAX_GATE_VARIANCE);
        Self {
            lost_us: if monotonic && below_ceiling {
                lost_us
            } else {
                0
            },
            stale_us: last_micros_within(timeouts.stale_after_s),
        }
    }
}

/// The aid model's variance after `gap_s` since the held sample, before the gate's ceiling
/// (`gate::admit`'s formula, in the same order).
#[inline(always)]
pub(super) fn model_variance<T: Real>(aid: &AidGate<T>, gap_s: T) -> T {
    let d = gap_s * (aid.drift_rate + aid.drift_accel * gap_s);
    aid.tracking_var + d * d
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

//! The one contract every estimator follows, learned once.
//!
//! ```text
//!   Config ──compute (ground, build time or boot)──▶ Design ──store (flash)──┐
//!     │                                                                      ▼
//!     └──────────────────────────────▶ Estimator::from_design(&config, &design, &initial)
//!                                      Estimator::new(&config, &initial)  (= compute + from_design)
//!
//!   per tick:     step / propagate with a time-stamped IMU sample (Timestamp, integer µs)
//!   per aid:      time-stamped samples; each scalar measurement answers with a FusionReport
//!   every tick:   health() → Health { state, counters }, aid_counters(aid) → AidCounters
//!   way back:     reinitialise(&initial), keeping what is still valid
//! ```
//!
//! - **[`Estimator`]**: the trait each estimator implements (`Config`, `Design`, `Initial`,
//!   `from_design`, `new`, `reinitialise`, `health`, `time`). Sensor inputs differ per estimator
//!   and stay inherent methods, but all carry a [`Timestamp`]; the estimator detects gaps itself.
//! - **[`Gate`]**: the χ² innovation gate of every aid (`Off` or a 1-dof NIS threshold).
//! - **[`RecoveryPolicy`]**: what an estimator does when its own gate starves it of an aid
//!   (every sample rejected for `starved_after_s`).
//! - **[`FusionReport`]**: one shape for every scalar measurement of every aid (innovation,
//!   innovation variance, NIS, test ratio, [`FusionOutcome`]), as PX4 EKF2's aid-source status.
//! - **[`AidCounters`]** per aid and **[`Health`]** per estimator: one counter shape.
//! - **[`DesignStamp`]**: every stored design carries the layout version and a fingerprint of
//!   the configuration it was computed for; `from_design` refuses a design computed for another
//!   configuration (`InvalidConfig { field: "design", issue: DesignMismatch }`).

use crate::time::Timestamp;
use crate::{HealthState, NavError, Real};

pub use crate::math::kalman::{FusionOutcome, FusionReport, Gate};

/// An estimator of nav-core: configured, designed, constructed, stepped, re-initialised the
/// same way as every other.
///
/// ```
/// use nav_core::contract::{Estimator, Health};
/// fn healthy<E: Estimator>(e: &E) -> bool {
///     e.health().state == nav_core::HealthState::Nominal
/// }
/// ```
pub trait Estimator: Sized {
    /// What the user chooses (units and σ-vs-variance on every field); validated on use.
    type Config;
    /// What is computed from the configuration on the ground (discretisation, gains …): may be
    /// stored and loaded on board without linking the design code.
    type Design;
    /// The initial (or re-initialisation) state: what the estimator starts from.
    type Initial;

    /// Computes the design for `config` (ground, build time or boot).
    fn design(config: &Self::Config) -> Result<Self::Design, NavError>;

    /// Builds the estimator from a stored design; checks that the design was computed for
    /// this configuration ([`DesignStamp`]) and validates the initial state.
    fn from_design(
        config: &Self::Config,
        design: &Self::Design,
        initial: &Self::Initial,
    ) -> Result<Self, NavError>;

    /// [`Estimator::design`] then [`Estimator::from_design`].
    fn new(config: &Self::Config, initial: &Self::Initial) -> Result<Self, NavError> {
        let design = Self::design(config)?;
        Self::from_design(config, &design, initial)
    }

    /// The way back from `NeedsReinitialisation` (or any time): restarts from `initial`,
    /// keeping the configuration, the design, and the counters (which count it). Refused input
    /// changes nothing.
    fn reinitialise(&mut self, initial: &Self::Initial) -> Result<(), NavError>;

    /// Health state and counters after the last call.
    fn health(&self) -> Health;

    /// Time stamp of the estimate (`None` before the first accepted sample).
    fn time(&self) -> Option<Timestamp>;
}

/// Recovery from starvation by the estimator's own gate: an aid whose samples have all been
/// rejected for `starved_after_s` means the estimate has drifted beyond what the covariance
/// admits (or a fault the model does not know left the filter overconfident); the estimator
/// then applies `action` so that the gate opens again, and counts it in
/// [`AidCounters::recoveries`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecoveryPolicy<T> {
    /// Time an aid must have been rejected without a break before the action, s (> 0);
    /// `None` disables recovery.
    pub starved_after_s: Option<T>,
    /// What is done then.
    pub action: RecoveryAction<T>,
}

/// What a [`RecoveryPolicy`] does. Each estimator documents which actions it supports and
/// refuses the others (`InvalidConfig { field: "recovery.action", issue: OutOfRange }`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RecoveryAction<T> {
    /// Multiply the variances of the states the aid observes by `variance_factor` (> 1) by a
    /// congruence `P ← D P D` (P stays symmetric PSD, correlations kept), within the
    /// estimator's variance ceilings.
    Inflate {
        /// Variance factor (σ × √factor).
        variance_factor: T,
    },
    /// Reset the covariance of the states the aid observes to its initial (prior) value,
    /// keeping the estimate.
    ResetToPrior,
    /// Fixed-gain loops (no covariance): accept the next sample outside the gate and move the
    /// measured state onto it.
    Reanchor,
}

/// Counters of one aid (one measurement channel). All saturate at `u32::MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidCounters {
    /// Samples (scalar measurements) fused.
    pub fused: u32,
    /// Samples rejected by the gate.
    pub rejected: u32,
    /// Valid samples skipped because they could not be fused ([`FusionOutcome::Skipped`]).
    pub skipped: u32,
    /// Current run of consecutive rejections (0 after a fused sample).
    pub consecutive_rejected: u32,
    /// Recoveries ([`RecoveryPolicy`]) done for this aid.
    pub recoveries: u32,
    /// Samples refused as invalid input (an `Err` was returned, nothing changed).
    pub refused: u32,
    /// Valid samples replaced by a newer sample of the same aid before their turn to be
    /// fused came (the navigator's held baro sample; never counted by the estimators alone).
    pub superseded: u32,
}

impl AidCounters {
    /// Counts one outcome.
    pub fn record(&mut self, outcome: FusionOutcome) {
        match outcome {
            FusionOutcome::Fused => {
                self.fused = self.fused.saturating_add(1);
                self.consecutive_rejected = 0;
            }
            FusionOutcome::Rejected => {
                self.rejected = self.rejected.saturating_add(1);
                self.consecutive_rejected = self.consecutive_rejected.saturating_add(1);
            }
            FusionOutcome::Skipped => self.skipped = self.skipped.saturating_add(1),
        }
    }

    /// Counts one recovery (the gate was re-opened; the run of rejections ends).
    pub fn record_recovery(&mut self) {
        self.recoveries = self.recoveries.saturating_add(1);
        self.consecutive_rejected = 0;
    }

    /// Counts one refused (invalid) sample.
    pub fn record_refused(&mut self) {
        self.refused = self.refused.saturating_add(1);
    }

    /// Counts one valid sample replaced by a newer one before it was fused.
    pub fn record_superseded(&mut self) {
        self.superseded = self.superseded.saturating_add(1);
    }
}

/// Health of an estimator: its [`HealthState`] and the counters of what it did to keep
/// running. The per-aid counters are read with each estimator's `aid_counters(aid)`. All
/// counters saturate at `u32::MAX`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Health {
    /// The state after the last call.
    pub state: HealthState,
    /// IMU intervals longer than nominal that were bridged (integrated in sub-steps, predicted
    /// over several steps, or held).
    pub gaps_bridged: u32,
    /// IMU gaps too long to bridge: part of the state was re-initialised or re-anchored.
    pub gaps_reset: u32,
    /// Times the covariance (or estimate) was held at an envelope limit: variance ceilings,
    /// repaired round-off, estimates held at their range.
    pub limits_hit: u32,
    /// Calls of `reinitialise` (and automatic re-initialisations).
    pub reinitialisations: u32,
    /// IMU samples refused as invalid input.
    pub imu_refused: u32,
}

impl Health {
    /// Adds one to a counter, saturating.
    pub fn bump(counter: &mut u32) {
        *counter = counter.saturating_add(1);
    }
}

/// Layout version and configuration fingerprint of a stored design.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DesignStamp {
    /// Layout version of the design's value list ([`crate::design::DesignValues`]); bumped
    /// whenever the list's content or order changes.
    pub version: u16,
    /// FNV-1a (32 bit) of the configuration values the design depends on, in a documented
    /// order ([`Fingerprint`]).
    pub fingerprint: u32,
}

impl DesignStamp {
    /// `Ok` when `self` (stored with the design) matches `expected` (computed from the
    /// configuration given to `from_design`), else
    /// `InvalidConfig { field: "design", issue: DesignMismatch }`.
    pub fn check(&self, expected: &DesignStamp) -> Result<(), NavError> {
        if self == expected {
            Ok(())
        } else {
            Err(NavError::InvalidConfig {
                field: "design",
                issue: crate::error::ConfigIssue::DesignMismatch,
            })
        }
    }
}

/// FNV-1a (32 bit) over the bit patterns of configuration values. The same value in `f32` and
/// `f64` hashes alike (every value is widened to `f64` first), so a design computed on the host
/// in `f64` from an `f32` configuration matches the configuration on board.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Fingerprint(u32);

impl Default for Fingerprint {
    fn default() -> Self {
        Self::new()
    }
}

impl Fingerprint {
    const OFFSET: u32 = 0x811c_9dc5;
    const PRIME: u32 = 0x0100_0193;

    /// An empty fingerprint.
    pub const fn new() -> Self {
        Self(Self::OFFSET)
    }

    /// Adds raw bytes. Out of line: stamps are computed when a filter is built or checked,
    /// never on a step, and one copy per width (4 and 8 bytes) serves every value of every
    /// stamp (inlined, each value was its own unrolled copy).
    #[inline(never)]
    fn bytes<const L: usize>(mut self, bytes: [u8; L]) -> Self {
        for b in bytes {
            self.0 ^= u32::from(b);
            self.0 = self.0.wrapping_mul(Self::PRIME);
        }
        self
    }

    /// Adds one value of any float type (as its `f64` bit pattern; −0 and +0 hash alike).
    #[must_use]
    pub fn real<T: Real>(self, v: T) -> Self {
        let w = v.to_f64();
        let w = if w == 0.0 { 0.0 } else { w };
        self.bytes(w.to_bits().to_le_bytes())
    }

    /// Adds an `f64` value.
    #[must_use]
    pub fn value(self, v: f64) -> Self {
        self.real(v)
    }

    /// Adds an integer.
    #[must_use]
    pub fn count(self, v: u32) -> Self {
        self.bytes(v.to_le_bytes())
    }

    /// The 32-bit fingerprint.
    pub fn finish(self) -> u32 {
        self.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fingerprint_distinguishes_values_and_order() {
        let a = Fingerprint::new().value(1.0).value(2.0).finish();
        let b = Fingerprint::new().value(2.0).value(1.0).finish();
        let c = Fingerprint::new().value(1.0).value(2.0 + 1e-12).finish();
        assert_ne!(a, b);
        assert_ne!(a, c);
        assert_eq!(a, Fingerprint::new().real(1.0_f32).real(2.0_f32).finish());
        assert_eq!(
            Fingerprint::new().value(0.0).finish(),
            Fingerprint::new().value(-0.0).finish()
        );
    }

    #[test]
    fn design_stamp_check() {
        let s = DesignStamp {
            version: 1,
            fingerprint: 7,
        };
        assert!(s.check(&s).is_ok());
        let other = DesignStamp {
            version: 2,
            fingerprint: 7,
        };
        assert!(s.check(&other).is_err());
    }

    #[test]
    fn aid_counters_record() {
        let mut c = AidCounters::default();
        c.record(FusionOutcome::Rejected);
        c.record(FusionOutcome::Rejected);
        assert_eq!(c.consecutive_rejected, 2);
        c.record(FusionOutcome::Skipped);
        assert_eq!(c.consecutive_rejected, 2);
        c.record(FusionOutcome::Fused);
        assert_eq!(
            (c.fused, c.rejected, c.skipped, c.consecutive_rejected),
            (1, 2, 1, 0)
        );
        c.consecutive_rejected = u32::MAX;
        c.record(FusionOutcome::Rejected);
        assert_eq!(c.consecutive_rejected, u32::MAX);
    }
}

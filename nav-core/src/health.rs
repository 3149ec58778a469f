//! The health state every estimator reports, in one shape.
//!
//! A flight loop reads it each step to decide what to trust and when to act: an estimator
//! never stops by itself on valid input, but it says how far its solution can be trusted and
//! when only a re-initialisation (a documented call on each estimator) can bring it back.

/// How healthy an estimator is now.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum HealthState {
    /// Constructed, no sample yet.
    #[default]
    Initialising,
    /// Running on its inputs and aids as designed.
    Nominal,
    /// Running, but not as designed: an aid lost or starved by the gate, a covariance bound
    /// hit, an update skipped for numerical reasons, an IMU gap bridged. The solution and its
    /// σ are still valid; the reason is in the estimator's counters.
    Degraded,
    /// The state left the range where the estimator's model holds (a diverged channel, a
    /// gap longer than can be bridged). Steps still run where they can, but the solution is
    /// not to be used until the estimator's `reinitialise` is called.
    NeedsReinitialisation,
}

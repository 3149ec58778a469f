//! The flight navigator's building blocks: the three estimators flown as one chain (spec
//! `flight-navigator.md`). An estimator module never uses another; this module composes them.
//!
//! * [`handover`]: the launch hand-over from the transfer alignment under the wing to the
//!   free-flight INS and its 17-state EKF — attitude, velocity and position carried through
//!   the lever arm, with their covariance mapped into the EKF's error state.

pub mod handover;

pub use handover::{
    hand_over, right_jacobian, AlignmentAtRelease, HandoverPriors, LeverArm, MasterAtRelease,
};

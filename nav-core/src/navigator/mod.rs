//! The flight navigator's building blocks: the three estimators flown as one chain (spec
//! `flight-navigator.md`). An estimator module never uses another; this module composes them.
//!
//! * [`Navigator`] (`flight`, `types`, [`baro`]): the phase state machine carry → released →
//!   midcourse → terminal around one missile INS, with the transfer alignment under the wing
//!   and the 17-state EKF after release (see "Flight navigator" below).
//! * [`handover`]: the launch hand-over from the transfer alignment under the wing to the
//!   free-flight INS and its 17-state EKF — attitude, velocity and position carried through
//!   the lever arm, with their covariance mapped into the EKF's error state.
//!
//! ```
//! use nalgebra::{Matrix3, Vector3};
//! use nav_core::navigator::{hand_over, AlignmentAtRelease, HandoverPriors, LeverArm, MasterAtRelease};
//! use nav_core::seeker_ins::{Position, ATT};
//!
//! let master = MasterAtRelease::<f32> {
//!     c_m_n: Matrix3::identity(),
//!     vel_ned_m_s: Vector3::new(180.0, 0.0, 0.0),
//!     position: Position { lat_rad: 0.6458, lon_rad: 2.2166, alt_m: 3000.0 },
//!     rate_nm_rad_s: Vector3::zeros(),
//!     attitude_sigma_rad: Vector3::new(2e-4, 2e-4, 8e-4),
//!     velocity_sigma_m_s: Vector3::new(0.05, 0.05, 0.08),
//!     position_sigma_m: Vector3::new(3.0, 3.0, 5.0),
//!     rate_sigma_rad_s: 1e-4,
//! };
//! let alignment = AlignmentAtRelease::<f32> {
//!     theta_rad: Vector3::new(0.01, -0.005, 0.02),
//!     theta_covariance_rad2: Matrix3::from_diagonal_element(1e-7),
//!     flexure_rad: Vector3::zeros(),
//!     flexure_rate_rad_s: Vector3::zeros(),
//!     flexure_rate_covariance: Matrix3::from_diagonal_element(1e-6),
//! };
//! let lever = LeverArm { nominal_m: Vector3::new(1.5, 4.0, 0.6), sigma_m: Vector3::from_element(0.01) };
//! let priors = HandoverPriors { accel_bias_sigma_m_s2: 1e-3, gyro_bias_sigma_rad_s: 5e-8, gimbal_bias_sigma_rad: 7e-4 };
//! let initial = hand_over(&master, &alignment, &lever, &priors)?; // → SeekerIns::new(&config, &initial)
//! // The yaw variance is the master's plus the alignment's.
//! let p_yaw = initial.covariance[(ATT + 2, ATT + 2)];
//! assert!((p_yaw - (8e-4f32 * 8e-4 + 1e-7)).abs() < 1e-9);
//! # Ok::<(), nav_core::NavError>(())
//! ```

// Flight navigator: see the section above.
pub mod baro;
mod flight;
pub mod handover;
#[cfg(test)]
mod tests;
mod types;

pub use baro::{BaroState, MAX_BARO_AGE_S};
pub use flight::{ConventionalNavigator, FlightNavigator, Navigator};
pub use handover::{
    hand_over, right_jacobian, AlignmentAtRelease, HandoverPriors, LeverArm, MasterAtRelease,
};
pub use types::{
    AidAvailability, AidState, AidStatus, AidTimeouts, Aids, BaroDamping, BaroErrorModel,
    Degradation, ImuTick, MasterNav, NavSolution, NavigatorConfig, NavigatorInitial, Phase,
    SeparationCheck, SeparationStatus, TickReport, Transition, TransitionCause,
};

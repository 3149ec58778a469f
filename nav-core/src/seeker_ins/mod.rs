//! Strapdown INS aided by 2-axis seeker gimbal angles to a known landmark: navigation
//! mechanization, 17-state error-state EKF and line-of-sight (LOS) measurement
//! (spec `shared/spec/seeker-aided-ins.md`, seed: Oh, Kim, Lee, Lee, Park 2006).
//!
//! * [`mechanization`]: strapdown INS in NED on WGS-84 from IMU increments (Δθ, Δv) with
//!   coning, sculling and rotation compensation; latitude, longitude and altitude are kept
//!   in `f64` in every build.
//! * [`error_model`]: the 17-state error model `δẋ = F δx + G w` (seed eqs. 2-3) for the
//!   n-frame misalignment `φ`, `Ĉ_b^n = (I − [φ×]) C_b^n`, and the sparse covariance
//!   propagation `P ← Φ P Φᵀ + Q_d`.
//! * [`measurement`]: the LOS residual `ê_landmark − ê_gimbal` (seed eqs. 4-23) projected on
//!   the two directions normal to the LOS, its Jacobians H1 (position), H3 (attitude),
//!   H6 (gimbal angle errors) and noise R.
//! * [`filter`]: the closed-loop error-state EKF (feedback into the INS, reset of δx).
//!
//! Error state (estimate minus truth), seed eq. 3:
//!
//! ```text
//! δx = [δL, δl, δh, δV_N, δV_E, δV_D, φ_N, φ_E, φ_D, ∇_x, ∇_y, ∇_z, ε_x, ε_y, ε_z, δθ_s, δψ_s]
//!        rad  rad  m   m/s   m/s   m/s  rad  rad  rad  m/s² (body)   rad/s (body)  rad   rad
//! ```
//!
//! `∇`, `ε` are the residual accelerometer and gyro biases (true bias minus the estimate
//! already removed from the increments), `δθ_s`, `δψ_s` the residual gimbal pitch and yaw
//! angle errors (measured minus true, minus the estimate already removed). All are random
//! constants.

pub mod error_model;
pub mod filter;
pub mod measurement;
pub mod mechanization;

pub use error_model::STATES;
pub use filter::{
    ClipFlags, HealthCounters, ImuFaultCounters, ImuFaultPolicy, LosCounters, LosReport,
    LosResidual, LosSkipReason, RecoveryPolicy, SeekerIns, SeekerInsConfig, VARIANCE_CEILING,
};
pub use measurement::{GimbalAngles, Landmark, LosModel};
pub use mechanization::{ImuIncrement, Ins, InsState, Position};

//! Strapdown INS aided by 2-axis seeker gimbal angles to a known landmark: navigation
//! mechanization, 17-state error-state EKF and line-of-sight (LOS) measurement
//! (spec `shared/spec/seeker-aided-ins.md`, seed: Oh, Kim, Lee, Lee, Park 2006).
//!
//! [`SeekerIns`] follows the estimator contract ([`crate::contract`]): a
//! [`SeekerInsConfig`] (with its [`Gate`](crate::contract::Gate),
//! [`RecoveryPolicy`](crate::contract::RecoveryPolicy) and [`ImuFaultPolicy`]), a
//! [`SeekerInsDesign`] (the noise PSDs, stored with a [`crate::contract::DesignStamp`]), a
//! [`SeekerInsInitial`] (navigation state and P0); time-stamped IMU samples
//! ([`ImuIncrement::time`]) and LOS samples ([`LosSample::time`]); gaps detected from the
//! stamps and bridged inside; one [`LosReport`] of two [`crate::contract::FusionReport`]s per
//! LOS sample; [`crate::contract::Health`] and the [`SeekerAid::Los`] counters.
//!
//! * mechanization: strapdown INS in NED on WGS-84 from IMU increments (Δθ, Δv) with coning,
//!   sculling and rotation compensation over the actual interval between samples; latitude,
//!   longitude and altitude are kept in `f64` in every build.
//! * error model: the 17-state error model `δẋ = F δx + G w` (seed eqs. 2-3) for the n-frame
//!   misalignment `φ`, `Ĉ_b^n = (I − [φ×]) C_b^n`, and the sparse covariance propagation
//!   `P ← Φ P Φᵀ + Q_d`.
//! * measurement: the LOS residual `ê_landmark − ê_gimbal` (seed eqs. 4-23) projected on the
//!   two directions normal to the LOS, its Jacobians H1 (position), H3 (attitude), H6 (gimbal
//!   angle errors) and noise R.
//! * the filter (`config`, `filter`, `propagation`, `update`, `health`): the closed-loop
//!   error-state EKF (feedback into the INS, reset of δx).
//! * the flight configuration ([`SeekerInsConfig::flight`], [`InstrumentErrors`]): the same
//!   17 states, with the IMU's scale-factor and misalignment σ accounted for after each
//!   covariance step (module `flight_noise`): the accelerometer-bias states are the
//!   equivalent bias `b + (S + M) f_ref` at a reference specific force, the accelerometers'
//!   S and M Schmidt consider parameters (module `consider`: the 17 × 9 cross-covariance
//!   beside P, so the error `(S + M) ∫(f − f_ref) dt` a departure makes stays correlated with
//!   every other the same S and M make); the gyro errors' bounded attitude error
//!   `(S + M) ∫ω dt` is charged to the attitude states.
//!   With every σ zero ([`SeekerInsConfig::paper`]) nothing is added.
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
//! constants. Because δx is zero after every feedback, the prediction only propagates P.
//!
//! # Flight loop
//!
//! ```
//! use nav_core::contract::{Estimator, RecoveryAction};
//! use nav_core::design::DesignValues;
//! use nav_core::seeker_ins::{
//!     gimbal_angles_of, landmark_vector_ned, paper_initial_covariance, ImuIncrement, InsState,
//!     Landmark, LosSample, Position, SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsDesign,
//!     SeekerInsInitial,
//! };
//! use nav_core::time::Timestamp;
//! use nav_core::HealthState;
//! use nalgebra::{Quaternion, Vector3};
//!
//! let start = Position { lat_rad: 0.6458, lon_rad: 2.2166, alt_m: 1000.0 };
//! let target = Position { lat_rad: 0.6461, lon_rad: 2.2266, alt_m: 0.0 };
//! let config = SeekerInsConfig::<f32>::paper(Landmark::new(target)?);
//!
//! // On the ground: design and store (4 values with the stamp).
//! let mut stored = [0.0_f64; SeekerInsDesign::<f32>::COUNT];
//! SeekerIns::design(&config)?.write_values(&mut stored)?;
//!
//! // On board: load the design, start level and at rest (a stand-in for the alignment).
//! let design = SeekerInsDesign::<f32>::read_values(&stored)?;
//! let initial = SeekerInsInitial {
//!     state: InsState {
//!         position: start,
//!         vel_ned_m_s: Vector3::zeros(),
//!         q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
//!     },
//!     covariance: paper_initial_covariance(),
//! };
//! let mut ins = SeekerIns::from_design(&config, &design, &initial)?;
//! let g = 9.80_f32;
//! for k in 1..=200_u64 {
//!     // 100 Hz IMU: the sample's time stamp is the end of the interval it covers.
//!     let time = Timestamp::from_micros(k * 10_000);
//!     let imu = ImuIncrement {
//!         time,
//!         delta_theta_rad: Vector3::zeros(),
//!         delta_v_m_s: Vector3::new(0.0, 0.0, -g * 0.01),
//!     };
//!     ins.propagate(&imu)?;
//!     if k % 10 == 0 {
//!         // 10 Hz seeker, stamped with its own measurement time.
//!         let s = ins.state();
//!         let d = landmark_vector_ned(&s.position, &config.landmark);
//!         let gimbal = gimbal_angles_of(&d.normalize());
//!         let report = ins.update_los(&LosSample { time, gimbal })?;
//!         let _ = (report.pitch.nis, report.yaw.outcome);
//!     }
//! }
//! assert_ne!(ins.health().state, HealthState::Initialising);
//! assert!(ins.aid_counters(SeekerAid::Los).fused > 0);
//! // The way back after NeedsReinitialisation (here: on demand).
//! ins.reinitialise(&initial)?;
//! assert_eq!(ins.health().reinitialisations, 1);
//! // The paper's recovery: 5 s of rejections, then the navigation variances × 4.
//! assert!(matches!(
//!     config.recovery.action,
//!     RecoveryAction::Inflate { variance_factor } if variance_factor == 4.0
//! ));
//! # Ok::<(), nav_core::NavError>(())
//! ```
//!
//! # Numerical envelope (f32 and f64)
//!
//! P stays symmetric PSD by construction:
//!
//! * **Variance ceilings.** After every covariance propagation, IMU-fault inflation and
//!   recovery inflation, a navigation-block variance above its physical ceiling
//!   ([`VARIANCE_CEILING`], the bounds accepted for P0: (1 rad)² in latitude and longitude,
//!   (10⁷ m)² in altitude, (10⁴ m/s)² in velocity, 10 rad² in attitude) is brought back to it
//!   by scaling its row and column (`P ← D P D`, D diagonal: a congruence, so P stays PSD and
//!   the correlations are kept), as PX4 EKF2 limits its variances.
//! * **Conditioned LOS update.** A scalar update removes from P the fraction
//!   `hᵀPh/(hᵀPh + r)` of the variance along h; when `hᵀPh/r` exceeds what the working
//!   precision can resolve ([`max_information_ratio`], `10⁻³/ε`: 8 389 in f32), the component
//!   is fused with r raised to `hᵀPh / ratio` (a less informative but consistent measurement;
//!   the next updates finish the job). Counted in [`SeekerCounters::conditioned`]. The 2-D
//!   update is the simple form `P − k Kᵀ` with stabilising noise, not the Joseph form
//!   ([`SeekerIns::update_los`] says why); the comparison 3-D residual uses the shared
//!   Joseph-form `fuse_scalar`.
//! * **Skipped, never refused.** A valid LOS that still cannot be fused (non-positive
//!   innovation variance, a variance that would turn negative, a non-finite correction) is
//!   reported as `Skipped` with a [`LosSkipReason`]; P and the state are unchanged. A
//!   propagated variance that rounds below zero is set to zero with its row and column
//!   (counted in `Health::limits_hit`).
//!
//! # Health and the way back
//!
//! `health()` says how far the solution can be trusted. When the position leaves the model
//! range (|L| ≥ 86°, |h| ≥ 1000 km; e.g. the unaided vertical channel diverging between rare
//! landmark sightings) the INS keeps integrating with gravity, radii and rates at the nearest
//! point of the range and the health is `NeedsReinitialisation`; so it is when a navigation
//! variance sits at its ceiling (e.g. after an IMU gap too long to bridge). `reinitialise`
//! restarts position, velocity, attitude and their covariance and keeps the bias and
//! gimbal-error estimates with their covariance.
//!
//! # Work per call (bounded)
//!
//! `propagate` / `propagate_clipped`: one INS step and at most one covariance propagation
//! (Cortex-M4F, `cargo xtask bench`: `ins_mech_step` + `eskf17_predict`); the sample that
//! ends a gap adds at most [`MAX_GAP_SAMPLES`] held steps. `update_los`: at most one covariance
//! propagation and one LOS update (`eskf17_los_update`). `reinitialise`, `predict_covariance`
//! and the setters: O(17²) at most. No call loops on data.

mod config;
mod consider;
mod covariance_health;
mod error_model;
mod filter;
mod flight_noise;
mod generated;
mod health;
mod los_components;
mod measurement;
mod mechanization;
mod paper;
mod propagation;
mod sparse_f;
mod update;
#[cfg(feature = "los-residual-3d")]
mod update_3d;

#[cfg(test)]
mod tests;

pub use config::{
    default_recovery, design_stamp, ImuFaultPolicy, LosResidual, SeekerInsConfig, SeekerInsDesign,
    AID_TIMEOUT_S, DESIGN_VERSION, MAX_FAULT_ACCEL_SIGMA_M_S2, MAX_FAULT_RATE_SIGMA_RAD_S,
    MAX_GAP_ATTITUDE_SIGMA_RAD, MAX_GAP_S, MAX_GAP_SAMPLES, MAX_GAP_VELOCITY_SIGMA_M_S,
    MAX_INFLATION_FACTOR, MAX_STARVED_AFTER_S, VARIANCE_CEILING,
};
pub use consider::CONSIDER;
pub(crate) use covariance_health::PsdMargin;
pub use covariance_health::{PROPAGATION_STABILISING_EPS, PSD_MARGIN_EPS};
#[cfg(test)]
pub(crate) use error_model::transition_times as transition_times_for_tests;
pub use error_model::{
    f_block, full_f, propagate_covariance, propagate_covariance_sparse, transition_block, ACC_BIAS,
    ATT, GIMBAL, GYRO_BIAS, POS, STATES, VEL,
};
pub use filter::{SeekerIns, SeekerInsInitial};
pub use flight_noise::{InstrumentErrors, MAX_MISALIGNMENT_RAD, MAX_SCALE_FACTOR};
pub use health::{SeekerAid, SeekerCounters};
pub use los_components::{max_information_ratio, STABILISING_EPS};
pub use measurement::{
    gimbal_angles_of, landmark_vector_ned, los_body, los_model, los_model_3d, los_model_at,
    validate_gimbal, GimbalAngles, Landmark, LosModel, LosModel3, MAX_GIMBAL_PITCH_RAD,
    MIN_LANDMARK_RANGE_M,
};
pub(crate) use mechanization::validate_increment;
pub use mechanization::{
    continuous_derivative, ImuIncrement, Ins, InsDerivative, InsState, Position, MAX_ALT_M,
    MAX_DELTA_THETA_RAD, MAX_DELTA_V_M_S, MAX_INTERVAL_S, MAX_LAT_RAD,
};
pub use paper::{
    paper_initial_covariance, PAPER_COVARIANCE_INTERVAL_STEPS, PAPER_IMU_DT_S, PAPER_IMU_DT_US,
};
pub use propagation::ClipFlags;
pub use sparse_f::{FBlock, SparseF};
pub(crate) use update::CrossColumn;
pub use update::{LosReport, LosSample, LosSkipReason};

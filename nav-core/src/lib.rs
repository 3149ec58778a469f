//! # nav-core
//!
//! Allocation-free, `no_std` navigation estimators for missile and UAV flight computers
//! (Cortex-M4F / M7, `f32`), with `f64` available on the host for analysis.
//!
//! The crate is a small shared layer ([`math`], [`earth`], [`error`]) under one module per
//! estimator, each following its specification in `shared/spec/`.
//!
//! Everything is fixed-size (nalgebra static matrices), nothing allocates, and every fallible
//! operation returns a typed [`NavError`] and leaves the state it was given untouched.
//!
//! ```
//! use nav_core::math::kalman::{fuse_scalar, FusionOutcome, Gate};
//! use nalgebra::{SMatrix, SVector};
//!
//! // Two-state filter [position m, velocity m/s]; measure position with σ = 2 m.
//! let mut x = SVector::<f32, 2>::new(0.0, 0.0);
//! let mut p = SMatrix::<f32, 2, 2>::new(100.0, 0.0, 0.0, 4.0);
//! let h = SVector::<f32, 2>::new(1.0, 0.0);
//! let z = 5.0_f32; // measured position, m
//! let innovation = z - h.dot(&x);
//! let report = fuse_scalar(&mut x, &mut p, &h, innovation, 2.0 * 2.0, Gate::Nis(9.0)).unwrap();
//! assert_eq!(report.outcome, FusionOutcome::Fused);
//! assert!((x[0] - 5.0 * 100.0 / 104.0).abs() < 1e-5);
//! assert!(p[(0, 0)] < 4.0); // the update shrank the position variance below R
//! ```
//!
//! ## Conventions
//! Body frames X forward, Y right, Z down; navigation frame NED; `[v×]` is the skew-symmetric
//! matrix with `[v×] u = v × u`; `C_a^b` transforms coordinates from frame a to frame b.
//! Angles in radians, rates in rad/s, specific force in m/s², distances in m.
#![no_std]
#![forbid(unsafe_code)]
#![deny(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing,
    clippy::unreachable
)]
#![cfg_attr(
    test,
    allow(
        clippy::unwrap_used,
        clippy::expect_used,
        clippy::panic,
        clippy::indexing_slicing
    )
)]
#![warn(missing_docs)]

#[cfg(any(test, feature = "test-support"))]
extern crate std;

pub mod contract;
pub mod design;
pub mod earth;
pub mod error;
pub mod health;
pub mod math;
pub mod navigator;
pub mod real;
pub mod seeker_ins;
pub mod time;
pub mod transfer_alignment;
pub mod vertical_channel;

pub use contract::{
    AidCounters, DesignStamp, Estimator, FusionOutcome, FusionReport, Gate, Health, RecoveryAction,
    RecoveryPolicy,
};
pub use error::{Bounds, NavError};
pub use health::HealthState;
pub use real::Real;
pub use time::Timestamp;

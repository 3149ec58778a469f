//! Transfer alignment of a wing-mounted slave INS by angular-rate and acceleration matching,
//! with wing flexure (spec `transfer-alignment.md`; Yang & Shim 2000): the conventional 9-state
//! ([`ConventionalFilter`], 2nd-order flexure) and the proposed 12-state ([`ProposedFilter`],
//! 3rd-order flexure with θ̈_f) Kalman filters, one implementation.
//!
//! The filters follow the [`Estimator`](crate::Estimator) contract: [`TaConfig`] (the paper's
//! in [`TaConfig::paper`]) → [`TaDesign`] (`Estimator::design` on the ground, stored as
//! [`DesignValues`](crate::design::DesignValues) in flight) → `Estimator::from_design(&config,
//! &design, &initial)` with [`TaInitial`], what the coarse alignment hands over. Each
//! [`TransferAlignment::step`] takes a time-stamped master sample and the slave IMU sample of
//! the same epoch, compensates the lever arm, predicts the state to the epoch and fuses the six
//! scalar measurements `dω_X, dω_Y, dω_Z, df_X, df_Y, df_Z` ([`Channel`]) sequentially
//! (rank-one form `P − k bᵀ` on the upper triangle) through the configured [`Gate`](crate::Gate), returning one
//! [`FusionReport`](crate::FusionReport) per update; [`TransferAlignment::aid_counters`] and
//! `health()` count what happened.
//!
//! # A flight loop
//!
//! ```
//! use nalgebra::Vector3;
//! use nav_core::design::DesignValues;
//! use nav_core::transfer_alignment::{
//!     Channel, MasterSample, PaperCase, ProposedFilter, SlaveSample, TaConfig, TaDesign,
//!     TaInitial,
//! };
//! use nav_core::{Estimator, FusionOutcome, HealthState, Timestamp};
//!
//! let config = TaConfig::<f32>::paper(PaperCase::Case2);
//! // On the ground: compute the design once and store it (flash, or generated at build time).
//! let mut stored = [0.0_f64; TaDesign::<f32, 4>::COUNT];
//! ProposedFilter::<f32>::design(&config)?.write_values(&mut stored)?;
//!
//! // On board: no design code; the coarse alignment hands over θ_m = 0 (its σ is in the
//! // configuration).
//! let design = TaDesign::<f32, 4>::read_values(&stored)?;
//! let mut ta = ProposedFilter::from_design(&config, &design, &TaInitial::default())?;
//!
//! let theta_true = Vector3::new(0.004_f32, -0.003, 0.002); // rad, the slave's misalignment
//! let mut rejected = 0;
//! for k in 0..300_u64 {
//!     let time = Timestamp::from_micros(10_000 * k); // the flight computer's clock, µs
//!     let w = Vector3::new(0.01_f32, 0.0, -0.02); // master angular rate, rad/s
//!     let f = Vector3::new(3.0_f32, 0.0, -9.8); // master specific force, m/s²
//!     let master = MasterSample {
//!         time,
//!         angular_rate_rad_s: w,
//!         angular_accel_rad_s2: Vector3::zeros(),
//!         specific_force_m_s2: f,
//!     };
//!     let slave = SlaveSample {
//!         time,
//!         angular_rate_rad_s: w - theta_true.cross(&w),
//!         specific_force_m_s2: f - theta_true.cross(&f),
//!     };
//!     // A refused pair (an `Err`) changes nothing: count it and go on.
//!     let Ok(report) = ta.step(&master, &slave) else { continue };
//!     if report.update(Channel::ForceX).map(|u| u.outcome) == Some(FusionOutcome::Rejected) {
//!         rejected += 1;
//!     }
//!     if ta.health().state == HealthState::NeedsReinitialisation {
//!         ta.reinitialise(&TaInitial::default())?;
//!     }
//! }
//! assert_eq!(rejected, 0);
//! assert_eq!(ta.health().state, HealthState::Nominal);
//! assert!((ta.theta() - theta_true).norm() < 1.0e-3);
//! assert!(ta.theta_sigma_rad().max() < 0.01); // rad: every axis known to better than 0.6°
//!
//! // A new coarse alignment (or the way back from `NeedsReinitialisation`): restart from it,
//! // keeping the clock and the counters.
//! ta.reinitialise(&TaInitial { mount_misalignment_rad: ta.theta_m() })?;
//! assert_eq!(ta.health().reinitialisations, 1);
//! assert_eq!(ta.aid_counters(Channel::ForceX).fused, 300);
//! # Ok::<(), nav_core::NavError>(())
//! ```
//!
//! # Time
//!
//! Time stamps are [`Timestamp`](crate::Timestamp)s (integer µs). The filter keeps its own
//! prediction grid: the time of its state, advanced by whole steps of `dt_s` (rounded once to
//! whole µs) in integer arithmetic. A sample stamped `t` is fused at the grid point nearest to
//! `t` (the filter predicts `round((t − grid) / dt)` steps, possibly 0 when jitter puts two
//! samples in one step), so any interval is accepted — jitter, late and missing samples — and
//! the grid never drifts from the flight computer's clock (|t − grid| ≤ dt/2 at every fused
//! epoch). Φ and Q_d stay the precomputed ones of `dt_s` (see docs/transfer-alignment.md for the measurement
//! behind this choice). A gap longer than `max_gap_steps` (at most [`MAX_GAP_STEPS`]) is not
//! predicted step by step: the flexure states are re-initialised to their stationary prior and
//! θ_m is kept (see [`GapOutcome::FlexureReinitialised`]), so the work of one call is bounded.
//! Late master data is matched with the slave sample of its epoch through a [`SlaveHistory`]
//! ([`TransferAlignment::step_delayed`]); a master-data dropout is bridged with
//! [`TransferAlignment::propagate`].
//!
//! # Parametrisation and numerics
//!
//! Internally each axis chain is `[θ, θ_f, θ̇_f(, θ̈_f)]` with the *total* misalignment
//! θ = θ_m + θ_f in place of θ_m (the measurements see only the sum; carrying θ_m and θ_f
//! separately makes their sum's variance a difference of two large, almost opposite numbers,
//! which f32 cannot hold). θ_m = θ − θ_f is an output. The design ([`TaDesign`]) is still
//! expressed in θ_m: `from_design` transforms it once (`Φ' = T Φ T⁻¹`, `Q' = T Q Tᵀ`, `T`
//! adding θ_f onto θ_m).
//!
//! Each scalar update is fused with a measurement variance of at least
//! `hᵀ P h / MAX_VARIANCE_REDUCTION` ([`MAX_VARIANCE_REDUCTION`]): one update never divides a
//! variance by more than that ratio, so the update never subtracts two numbers that agree
//! to more digits than f32 has. An update that still cannot be fused (innovation variance not
//! positive, a variance that would turn negative) is skipped
//! ([`FusionOutcome::Skipped`](crate::FusionOutcome::Skipped)): the step goes on with its
//! prediction and the time advances. Every committed covariance gets the diagonal loading of
//! [`PSD_LOADING_EPS`] and its variances are held at ceilings no consistent covariance reaches
//! (counted in `Health::limits_hit`).
//!
//! Structure used for the target:
//! - the state is stored axis-major, so Φ = blockdiag(Φ_X, Φ_Y, Φ_Z) (K×K each, first column
//!   e₁) and `P ← Φ P Φᵀ + Q_d` is done per pair of axis blocks a ≤ b;
//! - P is stored as its upper triangle only (column-major, rows `0..=col` of each column): the
//!   prediction, the six updates and the conditioning read and write nothing else, and the
//!   outputs read `P_ij` from the stored one of `(i, j)`, `(j, i)` (`covariance()` builds the
//!   full matrix); the rare paths written for a full matrix (the ceiling scaling, the gap
//!   reset) mirror it in place first;
//! - H rows are sparse: each of the six rows is built with a constant row number, so its
//!   pattern (at most 4 of the N columns; 12 in the flight configuration's df rows) folds to
//!   constants; `b = P h` is written out per row (its indices fold), the rank-one update
//!   (`P⁺ = P − k bᵀ`, k = b / s, on the upper triangle, P⁺'s diagonal checked first) is
//!   shared, one out-of-line copy per N;
//! - all work is done on copies and committed at the end: an error leaves the estimate
//!   untouched (the covariance is double-buffered).
//!
//! # Files
//!
//! `bias_charge` (the bias variance a manoeuvre's change of specific force needs), `config` (configuration, envelope, the paper's configurations), `model` (the flexure models
//! and the per-axis exact discretisation), `design` ([`TaDesign`]), `measurement` (samples,
//! lever arm, H rows), `history` ([`SlaveHistory`]), `covariance` (the numerics above),
//! `health` ([`Channel`], counters, health rules), `filter` (the estimator value and its
//! outputs), `step` (the per-epoch work), `rows` (the six scalar rows of an epoch), `fusion`
//! (the rank-one scalar update), `observability` (observability matrices and their
//! numerical rank, for analysis).
mod bias_charge;
mod config;
mod covariance;
mod design;
mod filter;
mod fusion;
mod health;
mod history;
mod measurement;
mod model;
mod observability;
mod rate_row;
mod rows;
mod step;
#[cfg(test)]
mod tests;

pub use bias_charge::{
    flexure_share_variance, level_carry_force, share_change_variance, share_charge,
};
pub use config::{
    default_recovery, slave_share_variance, PaperCase, TaConfig, ACCEL_NOISE_SIGMA_RANGE_M_S2,
    MAX_ACCEL_BIAS_SIGMA_M_S2, MAX_ANGULAR_ACCEL_RAD_S2, MAX_ANGULAR_RATE_RAD_S, MAX_DT_S,
    MAX_FLEXURE_SIGMA_RAD, MAX_FLEXURE_TAU_S, MAX_GAP_STEPS, MAX_LEVER_ARM_M, MAX_MISALIGNMENT_RAD,
    MAX_MOUNT_SIGMA_RAD, MAX_SPECIFIC_FORCE_M_S2, MAX_STARVED_AFTER_S, MIN_DT_S,
    MIN_FLEXURE_SIGMA_RAD, MIN_FLEXURE_TAU_S, MIN_TAU_STEPS, NIS_GATE_RANGE,
    RATE_NOISE_SIGMA_RANGE_RAD_S,
};
pub use covariance::{MAX_VARIANCE_REDUCTION, PSD_LOADING_EPS};
pub use design::{TaDesign, TA_DESIGN_VERSION};
pub use filter::{ConventionalFilter, FlightFilter, ProposedFilter, TaInitial, TransferAlignment};
pub use health::{Channel, DEGRADED_HOLD_EPOCHS, SKIPPED_EPOCHS_FOR_REINIT};
pub use history::SlaveHistory;
pub use measurement::{
    compensate_lever_arm, h_matrix, measurement, MasterSample, Matching, SlaveSample,
};
pub use model::{
    continuous_model, has_accel_bias, AxisChain, AxisFlexure, FlexureModel, BIAS_STATE,
    FLIGHT_CHAIN,
};
pub use observability::{segment, som_rank, RankReport, Segment};
pub use step::{GapOutcome, Propagation, StepReport};

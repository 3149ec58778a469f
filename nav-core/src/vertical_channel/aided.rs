//! Velocity-aided vertical channel (spec "Velocity-aided loop", seed Fig. 2, eqs. 2-9).
//!
//! Luenberger observer of the virtual system `x = [h, V_z, b]` (b: acceleration correction,
//! true acceleration = A_z + b, i.e. b = −accelerometer bias):
//!
//! ```text
//! A = | 0 1 0 |   B = | 0 0 |   C = | 1 −τ_b 0 |   K = | K1 G1 |
//!     | c 0 1 |       | 1 0 |       | 0   1  0 |       | K2 G2 |
//!     | 0 0 0 |       | 0 1 |                          | K3 G3 |
//!
//! ĥ'   = V̂_z + K1 (h_baro − (ĥ − τ_b V̂_z)) + G1 (V_ref − V̂_z)
//! V̂_z' = A_z + b̂ + K2 (…) + G2 (…),      A_z = f_up − g(ĥ)
//! b̂'   = K3 (…) + G3 (…)
//! ```
//!
//! The spec's C is `[1 0 0; 0 1 0]`; here the baro row carries the same lag compensation
//! `ĥ − τ_b V̂_z` as the classical loop's C4 (`baro_lag_s`, 0 gives the spec's C exactly).
//!
//! Gains: steady-state Kalman filter `K = P Cᵀ R⁻¹` (seed eq. 8) with P the stabilising
//! solution of the **continuous** ARE `A P + P Aᵀ + B Q Bᵀ − P Cᵀ R⁻¹ C P = 0` (seed eq. 9),
//! solved at configuration by [`super::riccati::solve_filter_care`] (in f64) from the noise
//! parameters:
//!
//! * `Q = diag(σ_a², σ_b²)`: accelerometer white-noise PSD ((m/s²)²/Hz) and bias
//!   random-walk PSD ((m/s²)²/s), from their densities.
//! * `R = diag(σ_h² T_h, σ_v² T_v)`: the PSD equivalent of white noise of per-sample σ sampled
//!   every T (m²·s and (m/s)²·s).

use super::common::{loop_common_methods, loop_estimator_items};
use super::config::{AidModel, AidedConfig};
use super::core::{CoreParts, LoopCore};
use super::design::{AidPair, AidedDesign};
use super::envelope::check_imu_dt;
use super::gate::{AidReport, GateParams, ReacquisitionCounters};
use super::samples::{Aid, BaroSample, ImuSample, InitialState, VelocitySample};
use crate::contract::{AidCounters, Estimator, Gate, Health, RecoveryPolicy};
use crate::time::Timestamp;
use crate::{NavError, Real};

pub use super::gains::AidedGains;

/// Report of one aided step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidedReport<T> {
    /// Baro: status, correction innovation `h_baro − (ĥ − τ_b V̂_z)` (m), verdict on a new
    /// sample.
    pub baro: AidReport<T>,
    /// Velocity aid: status, correction innovation `V_ref − V̂_z` (m/s), verdict on a new
    /// sample.
    pub velocity: AidReport<T>,
    /// Sub-steps the interval was integrated in: 1 for an interval up to 1.5 nominal IMU
    /// intervals, up to [`super::MAX_SUBSTEPS`] for a longer one.
    pub imu_intervals: u32,
}

/// The velocity-aided loop, discretised exactly at the IMU rate. Constructed through
/// [`Estimator`] (`new`, or `from_design` with a stored [`AidedDesign`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidedLoop<T: Real> {
    core: LoopCore<T>,
    gains: AidedGains,
    baro_innovation_variance: T,
    velocity_innovation_variance: T,
}

impl<T: Real> Estimator for AidedLoop<T> {
    type Config = AidedConfig<T>;
    type Design = AidedDesign<T>;
    type Initial = InitialState<T>;

    /// [`AidedDesign::compute`].
    fn design(config: &AidedConfig<T>) -> Result<AidedDesign<T>, NavError> {
        AidedDesign::compute(config)
    }

    /// Builds the loop from a design (computed on the ground, possibly stored as values, see
    /// [`crate::design`]) without running any design code (no Riccati, no discretisation, no
    /// f64 arithmetic: compares and copies only).
    ///
    /// Checks: the IMU interval and both aids' timeouts as the design does; that the design
    /// was computed for this configuration (its stamp: `InvalidConfig { field: "design",
    /// issue: DesignMismatch }`) and its step values are the configuration's
    /// (`design.imu_dt_s`, `design.baro_lag_s`); that its values are finite (`InvalidConfig {
    /// field: "design", issue: NotFinite }`) and its innovation variances positive; the aid
    /// model, gate and recovery (fields named); the initial state.
    fn from_design(
        config: &AidedConfig<T>,
        design: &AidedDesign<T>,
        initial: &InitialState<T>,
    ) -> Result<Self, NavError> {
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        config.velocity_timeouts.validate(
            "velocity_timeouts.stale_after_s",
            "velocity_timeouts.lost_after_s",
        )?;
        design.check(config)?;
        let gate = GateParams::compile(&config.run_time())?;
        let core = LoopCore::new(
            initial,
            CoreParts {
                bias_sign: 1.0,
                step: design.step,
                k: design.gains.k.cast::<T>(),
                modes: &design.modes,
                gravity: &design.gravity,
                baro_timeouts: config.baro_timeouts,
                velocity_timeouts: config.velocity_timeouts,
                run_time: config.run_time(),
                gate,
                sigma: &design.sigma,
            },
        )?;
        let variances = design.innovation_variances();
        Ok(Self {
            core,
            gains: design.gains,
            baro_innovation_variance: variances.baro,
            velocity_innovation_variance: variances.velocity,
        })
    }

    loop_estimator_items!();
}

impl<T: Real> AidedLoop<T> {
    /// One IMU step, with new aid samples if they arrived since the last step.
    /// On error the loop is unchanged but for the refused-input counter.
    pub fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Result<AidedReport<T>, NavError> {
        let r = self.core.step(imu, baro, velocity)?;
        Ok(AidedReport {
            baro: r.baro,
            velocity: r.velocity,
            imu_intervals: r.imu_intervals,
        })
    }

    loop_common_methods!();
    /// The Riccati design in use.
    pub fn gains(&self) -> &AidedGains {
        &self.gains
    }
    /// Design innovation σ of (baro m, velocity m/s): `√(C P Cᵀ + σ²)` of the steady state —
    /// a starting point for the [`AidModel`]'s σ₀ (the design ignores correlated baro errors).
    pub fn design_innovation_sigmas(&self) -> AidPair<T> {
        AidPair {
            baro: self.baro_innovation_variance.sqrt(),
            velocity: self.velocity_innovation_variance.sqrt(),
        }
    }
    #[cfg(test)]
    pub(crate) fn core(&self) -> &LoopCore<T> {
        &self.core
    }
}

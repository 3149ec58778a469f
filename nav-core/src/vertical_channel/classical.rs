//! Classical 3rd-order baro-inertial damping loop (spec "Classical 3rd-order loop", seed
//! Fig. 1, eqs. 1-2).
//!
//! ```text
//! e    = ĥ − C4 V̂_z − h_baro
//! ĥ'   = V̂_z − C1 e
//! V̂_z' = A_z − â − C2 e,      A_z = f_up − g(ĥ)
//! â'   = C3 e
//! ```
//!
//! Gains by pole placement, all three poles of the error dynamics at −1/τ (seed eq. 1):
//!
//! ```text
//! C1 = (c C4 τ³ + 3τ² + 3 C4 τ + C4²) / ((1 − c C4²) τ³)
//! C2 = (c (τ³ + 3 C4 τ²) + 3τ + C4)   / ((1 − c C4²) τ³)
//! C3 = 1 / τ³,          c = 2ω_s²
//! ```
//!
//! (with C4 = 0: C1 = 3/τ, C2 = c + 3/τ², C3 = 1/τ³; the seed's eq. 2 "C1 = 3/τ³" is a
//! misprint). C4 is the baro lag compensation: a first-order lag of time constant τ_b reads
//! `h_baro ≈ h − τ_b V_z`, so C4 = τ_b.

use super::common::{loop_common_methods, loop_estimator_items};
use super::config::{AidModel, ClassicalConfig};
use super::core::{CoreParts, LoopCore};
use super::design::ClassicalDesign;
use super::envelope::check_imu_dt;
use super::gate::{AidReport, GateParams, ReacquisitionCounters};
use super::samples::{Aid, BaroSample, ImuSample, InitialState};
use crate::contract::{AidCounters, Estimator, Gate, Health, RecoveryPolicy};
use crate::time::Timestamp;
use crate::{NavError, Real};
use nalgebra::Matrix3;

pub use super::gains::ClassicalGains;

/// Report of one classical step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassicalReport<T> {
    /// The baro: status, correction innovation `h_baro − (ĥ − C4 V̂_z)` (= −e, m) and the
    /// verdict on a new sample.
    pub baro: AidReport<T>,
    /// Sub-steps the interval was integrated in: 1 for an interval up to 1.5 nominal IMU
    /// intervals, up to [`super::MAX_SUBSTEPS`] for a longer one.
    pub imu_intervals: u32,
}

/// The classical damping loop, discretised exactly at the IMU rate. Constructed through
/// [`Estimator`] (`new`, or `from_design` with a stored [`ClassicalDesign`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicalLoop<T: Real> {
    core: LoopCore<T>,
    gains: ClassicalGains,
}

impl<T: Real> Estimator for ClassicalLoop<T> {
    type Config = ClassicalConfig<T>;
    type Design = ClassicalDesign<T>;
    type Initial = InitialState<T>;

    /// [`ClassicalDesign::compute`].
    fn design(config: &ClassicalConfig<T>) -> Result<ClassicalDesign<T>, NavError> {
        ClassicalDesign::compute(config)
    }

    /// Builds the loop from a design (computed on the ground, possibly stored as values, see
    /// [`crate::design`]) without running any design code or f64 arithmetic (compares and
    /// copies only).
    ///
    /// Checks: the IMU interval and the timeouts as the design does; that the design was
    /// computed for this configuration (its stamp, `InvalidConfig { field: "design", issue:
    /// DesignMismatch }`) and its step values are the configuration's (`design.imu_dt_s`,
    /// `design.baro_lag_s`); that its values are finite (`InvalidConfig { field: "design",
    /// issue: NotFinite }`); the aid model, gate and recovery (fields named); the initial
    /// state.
    fn from_design(
        config: &ClassicalConfig<T>,
        design: &ClassicalDesign<T>,
        initial: &InitialState<T>,
    ) -> Result<Self, NavError> {
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        design.check(config)?;
        let gate = GateParams::compile(&config.run_time())?;
        let core = LoopCore::new(
            initial,
            CoreParts {
                bias_sign: -1.0,
                step: design.step,
                k: design.gains.observer().0.cast::<T>(),
                modes: &design.modes,
                gravity: &design.gravity,
                baro_timeouts: config.baro_timeouts,
                velocity_timeouts: config.baro_timeouts,
                run_time: config.run_time(),
                gate,
                sigma: &design.sigma,
            },
        )?;
        Ok(Self {
            core,
            gains: design.gains,
        })
    }

    loop_estimator_items!();
}

impl<T: Real> ClassicalLoop<T> {
    /// One IMU step, with a new baro sample if one arrived since the last step.
    /// On error the loop is unchanged but for the refused-input counter.
    pub fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
    ) -> Result<ClassicalReport<T>, NavError> {
        let r = self.core.step(imu, baro, None)?;
        Ok(ClassicalReport {
            baro: r.baro,
            imu_intervals: r.imu_intervals,
        })
    }

    loop_common_methods!();
    /// The gains in use.
    pub fn gains(&self) -> &ClassicalGains {
        &self.gains
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.core.modes.phi_baro
    }
    #[cfg(test)]
    pub(crate) fn core(&self) -> &LoopCore<T> {
        &self.core
    }
}

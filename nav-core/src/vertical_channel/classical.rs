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

use super::design::ClassicalDesign;
use super::{AidReport, AidTimeouts, BaroSample, ImuSample, InitialState, LoopCore};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2};

/// Configuration of the classical loop (all in SI units; computed in `f64`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassicalConfig {
    /// IMU interval (the loop's step), s.
    pub imu_dt_s: f64,
    /// Geodetic latitude for the gravity model, rad.
    pub latitude_rad: f64,
    /// Time constant τ of the triple closed-loop pole at −1/τ, s.
    pub tau_s: f64,
    /// Altimeter lag compensation C4 (the baro's first-order lag time constant), s; 0 = none.
    pub baro_lag_s: f64,
    /// Baro sample interval, s (the longest expected; with the IMU interval it decides
    /// whether τ is stable in the multirate loop, see [`ClassicalDesign::compute`]).
    pub baro_period_s: f64,
    /// Baro freshness timeouts.
    pub baro_timeouts: AidTimeouts,
}

/// Gains of the classical loop.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassicalGains {
    /// C1, 1/s.
    pub c1_per_s: f64,
    /// C2, 1/s².
    pub c2_per_s2: f64,
    /// C3, 1/s³.
    pub c3_per_s3: f64,
    /// C4 (lag compensation), s.
    pub c4_s: f64,
    /// c = 2ω_s² used in the design, 1/s².
    pub c_per_s2: f64,
}

impl ClassicalGains {
    /// Pole placement (seed eq. 1): all three poles at −1/τ.
    ///
    /// Errors: `InvalidConfig` for a non-positive τ, a negative C4, or `1 − c C4² ≤ 0`.
    pub fn pole_placement(tau_s: f64, c4_s: f64, c_per_s2: f64) -> Result<Self, NavError> {
        require_positive("tau_s", tau_s)?;
        require_non_negative("baro_lag_s", c4_s)?;
        if tau_s > super::MAX_TAU_S {
            return Err(NavError::InvalidConfig {
                field: "tau_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        require_non_negative("c_per_s2", c_per_s2)?;
        let den0 = 1.0 - c_per_s2 * c4_s * c4_s;
        if den0 <= 0.0 {
            return Err(NavError::InvalidConfig {
                field: "baro_lag_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        let t3 = tau_s * tau_s * tau_s;
        let den = den0 * t3;
        let c1 =
            (c_per_s2 * c4_s * t3 + 3.0 * tau_s * tau_s + 3.0 * c4_s * tau_s + c4_s * c4_s) / den;
        let c2 = (c_per_s2 * (t3 + 3.0 * c4_s * tau_s * tau_s) + 3.0 * tau_s + c4_s) / den;
        Ok(Self {
            c1_per_s: c1,
            c2_per_s2: c2,
            c3_per_s3: 1.0 / t3,
            c4_s,
            c_per_s2,
        })
    }

    /// Error dynamics `δẋ = F δx` of `[δh, δV_z, δâ]` (estimate − truth) when the baro reads
    /// `h − C4 V_z` exactly; its characteristic polynomial is
    /// `s³ + (C1 − C2 C4) s² + (C2 − c(1 + C1 C4) − C3 C4) s + C3`.
    pub fn error_matrix(&self) -> Matrix3<f64> {
        let (c1, c2, c3, c4, c) = (
            self.c1_per_s,
            self.c2_per_s2,
            self.c3_per_s3,
            self.c4_s,
            self.c_per_s2,
        );
        Matrix3::new(
            -c1,
            1.0 + c1 * c4,
            0.0,
            c - c2,
            c2 * c4,
            -1.0,
            c3,
            -c3 * c4,
            0.0,
        )
    }

    /// The loop as an observer gain `K` (columns baro, velocity) on `e = −(z − C x̂)`.
    pub(crate) fn observer(&self) -> (Matrix3x2<f64>, Matrix2x3<f64>) {
        let k = Matrix3x2::new(
            self.c1_per_s,
            0.0,
            self.c2_per_s2,
            0.0,
            -self.c3_per_s3,
            0.0,
        );
        let c = Matrix2x3::new(1.0, -self.c4_s, 0.0, 0.0, 1.0, 0.0);
        (k, c)
    }
}

/// Report of one classical step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassicalReport<T> {
    /// The baro: status and innovation `h_baro − (ĥ − C4 V̂_z)` (= −e), m.
    pub baro: AidReport<T>,
    /// Sub-steps the interval was integrated in: 1 for an interval up to 1.5 nominal IMU
    /// intervals, up to [`super::MAX_SUBSTEPS`] for a longer one (see [`super::LoopStatus`]).
    pub imu_intervals: u32,
}

/// The classical damping loop, discretised exactly at the IMU rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicalLoop<T: Real> {
    pub(crate) core: LoopCore<T>,
    gains: ClassicalGains,
}

impl<T: Real> ClassicalLoop<T> {
    /// Validates the configuration, places the poles and discretises the loop.
    ///
    /// Errors: `InvalidConfig` (field named), `NonFiniteInput`/`InputOutOfRange` for the
    /// initial state, `NotConverged` if the discretisation fails.
    pub fn new(config: &ClassicalConfig, init: &InitialState<T>) -> Result<Self, NavError> {
        Self::from_design(config, &ClassicalDesign::compute(config)?, init)
    }

    /// Builds the loop from a precomputed design ([`ClassicalDesign::compute`] of this
    /// configuration, possibly stored as values, see [`crate::design`]) without running any
    /// design code or f64 arithmetic (casts and compares only).
    ///
    /// Checks: the IMU interval and the timeouts as [`Self::new`]; that the design's IMU
    /// interval and baro lag are the configuration's (`InvalidConfig { field:
    /// "design.imu_dt_s" | "design.baro_lag_s" }`); that its values are finite
    /// (`InvalidConfig { field: "design", issue: NotFinite }`); the initial state. The latitude
    /// and τ cannot be checked without the design code: that the design belongs to them is the
    /// caller's contract.
    pub fn from_design(
        config: &ClassicalConfig,
        design: &ClassicalDesign<T>,
        init: &InitialState<T>,
    ) -> Result<Self, NavError> {
        super::check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        design.check(config)?;
        let (gains, modes, gravity) = design.parts();
        let core = LoopCore::new(
            init,
            -1.0,
            design.step_values(),
            gains.observer().0.cast::<T>(),
            *modes,
            gravity,
            &config.baro_timeouts,
            &config.baro_timeouts,
        )?;
        Ok(Self {
            core,
            gains: *gains,
        })
    }

    /// One IMU step, with a new baro sample if one arrived since the last step.
    /// On error the loop is unchanged.
    pub fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
    ) -> Result<ClassicalReport<T>, NavError> {
        let (baro, _, imu_intervals) = self.core.step(imu, baro, None, (None, None))?;
        Ok(ClassicalReport {
            baro,
            imu_intervals,
        })
    }

    /// The gains in use.
    pub fn gains(&self) -> &ClassicalGains {
        &self.gains
    }
    /// Altitude estimate, m (up).
    pub fn altitude_m(&self) -> T {
        self.core.altitude_m()
    }
    /// Vertical velocity estimate, m/s (up).
    pub fn vz_up_m_s(&self) -> T {
        self.core.x.y
    }
    /// Accelerometer bias estimate (measured − true), m/s².
    pub fn accel_bias_m_s2(&self) -> T {
        self.core.accel_bias_m_s2()
    }
    /// Time of the estimate (of the last accepted IMU sample).
    pub fn time(&self) -> crate::time::Timestamp {
        self.core.time
    }
    /// Health after the last step ([`super::LoopStatus`] says why).
    pub fn health(&self) -> crate::HealthState {
        self.core.status.health
    }
    /// Health and the interval / divergence counters.
    pub fn status(&self) -> &super::LoopStatus {
        &self.core.status
    }
    /// Installs the χ² innovation gate ([`super::InnovationGate`]), or removes it with `None`
    /// (then every valid sample is accepted). Counters are kept. On error nothing changes.
    pub fn set_gate(&mut self, gate: Option<&super::InnovationGate>) -> Result<(), NavError> {
        self.core.set_gate(gate)
    }
    /// Restarts the state and clock from `init` (e.g. when the health is
    /// `NeedsReinitialisation` and an external altitude is known), keeping the design, the
    /// gate and the counters; held aid samples are dropped and the health is `Initialising`
    /// until the next step. On error nothing changes.
    pub fn reinitialise(&mut self, init: &InitialState<T>) -> Result<(), NavError> {
        self.core.reinitialise(init)
    }
    /// Gate counters of the baro.
    pub fn baro_counters(&self) -> &super::GateCounters {
        &self.core.baro_counters
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.core.modes.phi_baro
    }
}

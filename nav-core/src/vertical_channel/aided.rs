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

use super::design::AidedDesign;
use super::riccati::solve_filter_care;
use super::{
    AidReport, AidTimeouts, BaroSample, GravityModel, ImuSample, InitialState, LoopCore,
    VelocitySample,
};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2, Vector2, Vector3};

/// Configuration of the velocity-aided loop (SI units; the design is computed in `f64`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidedConfig {
    /// IMU interval (the loop's step), s.
    pub imu_dt_s: f64,
    /// Geodetic latitude for the gravity model, rad.
    pub latitude_rad: f64,
    /// Accelerometer white-noise density (σ, not PSD), m/s²/√Hz. PSD = value².
    pub accel_noise_m_s2_rt_hz: f64,
    /// Accelerometer bias random-walk density (σ), m/s²/√s. PSD = value².
    pub accel_bias_rw_m_s2_rt_s: f64,
    /// Baro white noise per sample, 1σ, m.
    pub baro_noise_m: f64,
    /// Baro sample interval, s.
    pub baro_period_s: f64,
    /// Baro lag compensation (the baro's first-order lag time constant), s; 0 = none.
    pub baro_lag_s: f64,
    /// Velocity-aid white noise per sample, 1σ, m/s.
    pub velocity_noise_m_s: f64,
    /// Velocity-aid sample interval, s.
    pub velocity_period_s: f64,
    /// Baro freshness timeouts.
    pub baro_timeouts: AidTimeouts,
    /// Velocity-aid freshness timeouts.
    pub velocity_timeouts: AidTimeouts,
}

/// The Riccati design of the aided loop.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidedGains {
    /// Gains, columns `[K1 K2 K3]ᵀ` (baro, 1/s, 1/s², 1/s³) and `[G1 G2 G3]ᵀ` (velocity,
    /// 1, 1/s, 1/s²).
    pub k: Matrix3x2<f64>,
    /// Steady-state error covariance (units m², (m/s)², (m/s²)²).
    pub p: Matrix3<f64>,
    /// System matrix A of the design (with c = 2ω_s²).
    pub a: Matrix3<f64>,
    /// Process-noise PSD on the states, `B Q Bᵀ`.
    pub q: Matrix3<f64>,
    /// Output matrix C.
    pub c: Matrix2x3<f64>,
    /// Measurement PSDs `[r_h, r_v]`.
    pub r: Vector2<f64>,
    /// Sign-function iterations of the ARE solver.
    pub riccati_iterations: u32,
    /// Relative residual of the ARE solution.
    pub relative_residual: f64,
}

impl AidedGains {
    /// Validates the noise parameters, builds (A, B Q Bᵀ, C, R) and solves the continuous ARE.
    pub fn design(config: &AidedConfig) -> Result<Self, NavError> {
        let gravity = GravityModel::at_latitude(config.latitude_rad)?;
        let sa = require_positive("accel_noise_m_s2_rt_hz", config.accel_noise_m_s2_rt_hz)?;
        let sb = require_positive("accel_bias_rw_m_s2_rt_s", config.accel_bias_rw_m_s2_rt_s)?;
        let sh = require_positive("baro_noise_m", config.baro_noise_m)?;
        let th = require_positive("baro_period_s", config.baro_period_s)?;
        let lag = require_non_negative("baro_lag_s", config.baro_lag_s)?;
        let sv = require_positive("velocity_noise_m_s", config.velocity_noise_m_s)?;
        let tv = require_positive("velocity_period_s", config.velocity_period_s)?;
        for (field, v) in [
            ("baro_period_s", th),
            ("velocity_period_s", tv),
            ("baro_lag_s", lag),
            ("accel_noise_m_s2_rt_hz", sa * sa),
            ("accel_bias_rw_m_s2_rt_s", sb * sb),
            ("baro_noise_m", sh * sh * th),
            ("velocity_noise_m_s", sv * sv * tv),
        ] {
            let zero_ok = field == "baro_lag_s" && v == 0.0;
            if !(v.is_finite()
                && v <= super::MAX_DESIGN_VALUE
                && (zero_ok || v >= super::MIN_DESIGN_VALUE))
            {
                return Err(NavError::InvalidConfig {
                    field,
                    issue: ConfigIssue::OutOfRange,
                });
            }
        }
        let c_grav = gravity.c_per_s2();
        let a = Matrix3::new(0.0, 1.0, 0.0, c_grav, 0.0, 1.0, 0.0, 0.0, 0.0);
        let q = Matrix3::from_diagonal(&Vector3::new(0.0, sa * sa, sb * sb));
        let c = Matrix2x3::new(1.0, -lag, 0.0, 0.0, 1.0, 0.0);
        let r = Vector2::new(sh * sh * th, sv * sv * tv);
        let sol = solve_filter_care(&a, &q, &c, &r)?;
        Ok(Self {
            k: sol.gain,
            p: sol.p,
            a,
            q,
            c,
            r,
            riccati_iterations: sol.iterations,
            relative_residual: sol.relative_residual,
        })
    }

    /// Error matrix `A − K C` (the spec's A_e, with the lag-compensated C).
    pub fn error_matrix(&self) -> Matrix3<f64> {
        self.a - self.k * self.c
    }
}

/// Report of one aided step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidedReport<T> {
    /// Baro: status, innovation `h_baro − (ĥ − τ_b V̂_z)` (m) and its design variance.
    pub baro: AidReport<T>,
    /// Velocity aid: status, innovation `V_ref − V̂_z` (m/s) and its design variance.
    pub velocity: AidReport<T>,
    /// Sub-steps the interval was integrated in: 1 for an interval up to 1.5 nominal IMU
    /// intervals, up to [`super::MAX_SUBSTEPS`] for a longer one (see [`super::LoopStatus`]).
    pub imu_intervals: u32,
}

/// The velocity-aided loop, discretised exactly at the IMU rate.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidedLoop<T: Real> {
    pub(crate) core: LoopCore<T>,
    gains: AidedGains,
    baro_innovation_variance: T,
    velocity_innovation_variance: T,
}

impl<T: Real> AidedLoop<T> {
    /// Validates the configuration, designs the gains (continuous ARE) and discretises.
    pub fn new(config: &AidedConfig, init: &InitialState<T>) -> Result<Self, NavError> {
        Self::from_design(config, &AidedDesign::compute(config)?, init)
    }

    /// Builds the loop from a precomputed design ([`AidedDesign::compute`] of this
    /// configuration, possibly stored as values, see [`crate::design`]) without running any
    /// design code (no Riccati, no discretisation, no f64 arithmetic: casts and compares
    /// only).
    ///
    /// Checks: the IMU interval and both aids' timeouts as [`Self::new`]; that the design's
    /// IMU interval and baro lag are the configuration's (`InvalidConfig { field:
    /// "design.imu_dt_s" | "design.baro_lag_s" }`); that its values are finite
    /// (`InvalidConfig { field: "design", issue: NotFinite }`) and its innovation variances
    /// positive; the initial state. The noise parameters and latitude cannot be checked
    /// without the design code: that the design belongs to them is the caller's contract.
    pub fn from_design(
        config: &AidedConfig,
        design: &AidedDesign<T>,
        init: &InitialState<T>,
    ) -> Result<Self, NavError> {
        super::check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        config.velocity_timeouts.validate(
            "velocity_timeouts.stale_after_s",
            "velocity_timeouts.lost_after_s",
        )?;
        design.check(config)?;
        let (gains, modes, gravity) = design.parts();
        let core = LoopCore::new(
            init,
            1.0,
            design.step_values(),
            gains.k.cast::<T>(),
            *modes,
            gravity,
            &config.baro_timeouts,
            &config.velocity_timeouts,
        )?;
        let (bv, vv) = design.innovation_variances();
        Ok(Self {
            core,
            gains: *gains,
            baro_innovation_variance: bv,
            velocity_innovation_variance: vv,
        })
    }

    /// One IMU step, with new aid samples if they arrived since the last step.
    /// On error the loop is unchanged.
    pub fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Result<AidedReport<T>, NavError> {
        let (baro, velocity, imu_intervals) = self.core.step(
            imu,
            baro,
            velocity,
            (
                Some(self.baro_innovation_variance),
                Some(self.velocity_innovation_variance),
            ),
        )?;
        Ok(AidedReport {
            baro,
            velocity,
            imu_intervals,
        })
    }

    /// The Riccati design in use.
    pub fn gains(&self) -> &AidedGains {
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
    /// Gate counters of the velocity aid.
    pub fn velocity_counters(&self) -> &super::GateCounters {
        &self.core.velocity_counters
    }
    /// Design innovation σ of (baro m, velocity m/s): `√(C P Cᵀ + σ²)` — a starting point for
    /// [`super::InnovationGate`]'s σ₀ (the design ignores correlated baro errors).
    pub fn design_innovation_sigmas(&self) -> (T, T) {
        (
            self.baro_innovation_variance.sqrt(),
            self.velocity_innovation_variance.sqrt(),
        )
    }
}

//! The continuous gains of both loops (configuration time, `f64`): pole placement for the
//! classical loop, the continuous ARE for the aided loop.

use super::config::AidedConfig;
use super::gravity::GravityModel;
use super::riccati::solve_filter_care;
use super::{MAX_DESIGN_VALUE, MAX_TAU_S, MIN_DESIGN_VALUE};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2, Vector2, Vector3};

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
        if tau_s > MAX_TAU_S {
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

    /// The loop as an observer: gain `K` (columns baro, velocity) on `e = −(z − C x̂)`, and
    /// the output matrix `C`.
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
    /// Validates the noise parameters, builds (A, B Q Bᵀ, C, R) and solves the continuous ARE
    /// (in `f64`, from the configuration's values widened).
    pub fn design<T: Real>(config: &AidedConfig<T>) -> Result<Self, NavError> {
        let gravity = GravityModel::at_latitude(config.latitude_rad.to_f64())?;
        let w = |v: T| v.to_f64();
        let sa = require_positive("accel_noise_m_s2_rt_hz", w(config.accel_noise_m_s2_rt_hz))?;
        let sb = require_positive("accel_bias_rw_m_s2_rt_s", w(config.accel_bias_rw_m_s2_rt_s))?;
        let sh = require_positive("baro_noise_m", w(config.baro_noise_m))?;
        let th = require_positive("baro_period_s", w(config.baro_period_s))?;
        let lag = require_non_negative("baro_lag_s", w(config.baro_lag_s))?;
        let sv = require_positive("velocity_noise_m_s", w(config.velocity_noise_m_s))?;
        let tv = require_positive("velocity_period_s", w(config.velocity_period_s))?;
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
            if !(v.is_finite() && v <= MAX_DESIGN_VALUE && (zero_ok || v >= MIN_DESIGN_VALUE)) {
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

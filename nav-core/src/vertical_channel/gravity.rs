//! Normal gravity as a quadratic in altitude at the configured latitude.

use crate::error::ConfigIssue;
use crate::{NavError, Real};

/// Normal gravity as a quadratic in altitude at a fixed latitude,
/// `g(h) = g₀ − g₁ h + g₂ h²` (m/s²), fitted exactly to [`crate::earth::normal_gravity_m_s2`]
/// (which is quadratic in h) at configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GravityModel<T> {
    /// Gravity on the ellipsoid, m/s².
    pub g0_m_s2: T,
    /// Vertical gradient −∂g/∂h at h = 0, 1/s².
    pub g1_per_s2: T,
    /// Second-order coefficient, 1/(m s²).
    pub g2_per_m_s2: T,
}

impl GravityModel<f64> {
    /// Model at a geodetic latitude (rad, |lat| ≤ π/2).
    pub fn at_latitude(latitude_rad: f64) -> Result<Self, NavError> {
        if !latitude_rad.is_finite() {
            return Err(NavError::InvalidConfig {
                field: "latitude_rad",
                issue: ConfigIssue::NotFinite,
            });
        }
        if latitude_rad.abs() > core::f64::consts::FRAC_PI_2 {
            return Err(NavError::InvalidConfig {
                field: "latitude_rad",
                issue: ConfigIssue::OutOfRange,
            });
        }
        let g = |h: f64| crate::earth::normal_gravity_m_s2(latitude_rad, h);
        let d = 1000.0;
        let (gm, g0, gp) = (g(-d), g(0.0), g(d));
        Ok(Self {
            g0_m_s2: g0,
            g1_per_s2: -(gp - gm) / (2.0 * d),
            g2_per_m_s2: (gp - 2.0 * g0 + gm) / (2.0 * d * d),
        })
    }

    /// The spec's `c = 2ω_s² = 2 g₀ / R₀`, 1/s² (used in the gain design).
    pub fn c_per_s2(&self) -> f64 {
        2.0 * crate::earth::schuler_frequency_sq(self.g0_m_s2)
    }

    /// The model in the loop's float type.
    pub(crate) fn cast<T: Real>(&self) -> GravityModel<T> {
        GravityModel {
            g0_m_s2: T::lit(self.g0_m_s2),
            g1_per_s2: T::lit(self.g1_per_s2),
            g2_per_m_s2: T::lit(self.g2_per_m_s2),
        }
    }
}

impl<T: Real> GravityModel<T> {
    /// g(h), m/s².
    #[inline(always)]
    pub fn gravity_m_s2(&self, altitude_m: T) -> T {
        self.g0_m_s2 - altitude_m * (self.g1_per_s2 - self.g2_per_m_s2 * altitude_m)
    }

    /// `true` when every coefficient is finite.
    pub(crate) fn is_finite(&self) -> bool {
        self.g0_m_s2.is_finite() && self.g1_per_s2.is_finite() && self.g2_per_m_s2.is_finite()
    }
}

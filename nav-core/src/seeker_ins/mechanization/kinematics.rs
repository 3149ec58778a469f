//! Earth-related radii and rates at a navigation state, shared by the mechanization's step
//! and the covariance step's F.
use super::{model_lat_alt, Position};
use crate::earth::EARTH_RATE_RAD_S;
use crate::math::trig;
use crate::Real;
use nalgebra::Vector3;

/// Earth-related radii at a position: what [`Kinematics`] needs of the position alone
/// (one `sin`/`cos` pair, one `sqrt` and the f64 → `T` conversions of latitude and height).
/// [`Ins::step_keeping_radii`](super::Ins::step_keeping_radii) returns those it evaluated at the start of its interval, so
/// that the covariance step's F does not evaluate them again (`SeekerIns`'s `radii`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct PositionKinematics<T> {
    pub(crate) sin_lat: T,
    pub(crate) cos_lat: T,
    /// R_M + h, m.
    pub(crate) rm_h: T,
    /// R_N + h, m.
    pub(crate) rn_h: T,
    /// dR_M/dL, m/rad.
    pub(crate) drm_dlat: T,
    /// dR_N/dL, m/rad.
    pub(crate) drn_dlat: T,
    /// Altitude at which gravity is evaluated (clamped into the model range), m.
    pub(crate) alt_m: T,
}

impl<T: Real> PositionKinematics<T> {
    pub(crate) fn new(pos: &Position) -> Self {
        let (lat, h) = model_lat_alt::<T>(pos);
        let (sin_lat, cos_lat) = trig::sin_cos(lat);
        let e2 = T::lit(crate::earth::ECCENTRICITY_SQ);
        let d = T::one() - e2 * sin_lat * sin_lat;
        let d_inv = T::one() / d;
        // Radii as crate::earth::radii_m, from sin L (no second sin).
        let rn = T::lit(crate::earth::SEMI_MAJOR_AXIS_M) / d.sqrt();
        let rm = rn * T::lit(1.0 - crate::earth::ECCENTRICITY_SQ) * d_inv;
        let sc = e2 * sin_lat * cos_lat * d_inv;
        Self {
            sin_lat,
            cos_lat,
            rm_h: rm + h,
            rn_h: rn + h,
            drm_dlat: T::lit(3.0) * rm * sc,
            drn_dlat: rn * sc,
            alt_m: h,
        }
    }
}

/// Earth-related rates and radii at a navigation state.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Kinematics<T> {
    pub(crate) sin_lat: T,
    pub(crate) cos_lat: T,
    /// R_M + h, m.
    pub(crate) rm_h: T,
    /// R_N + h, m.
    pub(crate) rn_h: T,
    /// dR_M/dL, m/rad.
    pub(crate) drm_dlat: T,
    /// dR_N/dL, m/rad.
    pub(crate) drn_dlat: T,
    /// ω_ie^n, rad/s.
    pub(crate) w_ie: Vector3<T>,
    /// ω_en^n, rad/s.
    pub(crate) w_en: Vector3<T>,
    /// Altitude at which gravity is evaluated (clamped into the model range), m.
    pub(crate) alt_m: T,
}

impl<T: Real> Kinematics<T> {
    pub(crate) fn new(pos: &Position, v: &Vector3<T>) -> Self {
        Self::at(&PositionKinematics::new(pos), v)
    }

    /// The rates at velocity `v` (m/s) from the radii of the position.
    #[inline(always)]
    pub(crate) fn at(p: &PositionKinematics<T>, v: &Vector3<T>) -> Self {
        let w = T::lit(EARTH_RATE_RAD_S);
        let inv_n = T::one() / p.rn_h;
        let inv_m = T::one() / p.rm_h;
        let tan_lat = p.sin_lat / p.cos_lat;
        Self {
            sin_lat: p.sin_lat,
            cos_lat: p.cos_lat,
            rm_h: p.rm_h,
            rn_h: p.rn_h,
            drm_dlat: p.drm_dlat,
            drn_dlat: p.drn_dlat,
            w_ie: Vector3::new(w * p.cos_lat, T::zero(), -w * p.sin_lat),
            w_en: Vector3::new(v.y * inv_n, -v.x * inv_m, -v.y * tan_lat * inv_n),
            alt_m: p.alt_m,
        }
    }
}

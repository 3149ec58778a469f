//! WGS-84 earth model: radii of curvature, normal gravity with altitude, earth rate, transport
//! rate.
//!
//! Constants are those of NIMA TR8350.2 (WGS-84, 3rd edition). Latitude `lat_rad` is geodetic,
//! altitude `alt_m` is height above the ellipsoid (up positive).

use crate::math::trig;
use crate::Real;
use nalgebra::Vector3;

/// Semi-major axis a, m.
pub const SEMI_MAJOR_AXIS_M: f64 = 6_378_137.0;
/// Flattening f (dimensionless).
pub const FLATTENING: f64 = 1.0 / 298.257_223_563;
/// First eccentricity squared e² = f (2 − f).
pub const ECCENTRICITY_SQ: f64 = FLATTENING * (2.0 - FLATTENING);
/// Semi-minor axis b = a (1 − f), m.
pub const SEMI_MINOR_AXIS_M: f64 = SEMI_MAJOR_AXIS_M * (1.0 - FLATTENING);
/// Earth rotation rate ω_ie, rad/s.
pub const EARTH_RATE_RAD_S: f64 = 7.292_115e-5;
/// Earth gravitational constant GM (including the atmosphere), m³/s².
pub const GM_M3_S2: f64 = 3.986_004_418e14;
/// Normal gravity at the equator γ_e, m/s².
pub const GRAVITY_EQUATOR_M_S2: f64 = 9.780_325_335_9;
/// Normal gravity at the poles γ_p, m/s².
pub const GRAVITY_POLE_M_S2: f64 = 9.832_184_937_8;
/// Somigliana constant k = (b γ_p − a γ_e) / (a γ_e).
pub const SOMIGLIANA_K: f64 = 0.001_931_852_652_41;
/// Mean earth radius used for Schuler-type approximations, R_0 = √(a b), m.
pub const MEAN_RADIUS_M: f64 = 6_367_435.679_7;

/// Meridian (north-south) radius of curvature R_M at geodetic latitude, m.
#[inline]
pub fn meridian_radius_m<T: Real>(lat_rad: T) -> T {
    let s = trig::sin(lat_rad);
    let e2 = T::lit(ECCENTRICITY_SQ);
    let d = T::one() - e2 * s * s;
    T::lit(SEMI_MAJOR_AXIS_M * (1.0 - ECCENTRICITY_SQ)) / (d * d.sqrt())
}

/// Transverse (prime-vertical, east-west) radius of curvature R_N at geodetic latitude, m.
#[inline]
pub fn transverse_radius_m<T: Real>(lat_rad: T) -> T {
    let s = trig::sin(lat_rad);
    let d = T::one() - T::lit(ECCENTRICITY_SQ) * s * s;
    T::lit(SEMI_MAJOR_AXIS_M) / d.sqrt()
}

/// Both radii of curvature `(R_M, R_N)` at geodetic latitude, m (one `sin` and one `sqrt`).
#[inline]
pub fn radii_m<T: Real>(lat_rad: T) -> (T, T) {
    let s = trig::sin(lat_rad);
    let d = T::one() - T::lit(ECCENTRICITY_SQ) * s * s;
    let sd = d.sqrt();
    let r_n = T::lit(SEMI_MAJOR_AXIS_M) / sd;
    let r_m = r_n * T::lit(1.0 - ECCENTRICITY_SQ) / d;
    (r_m, r_n)
}

/// Magnitude of normal gravity on the ellipsoid (Somigliana), m/s².
#[inline]
pub fn normal_gravity_surface_m_s2<T: Real>(lat_rad: T) -> T {
    let s2 = {
        let s = trig::sin(lat_rad);
        s * s
    };
    T::lit(GRAVITY_EQUATOR_M_S2) * (T::one() + T::lit(SOMIGLIANA_K) * s2)
        / (T::one() - T::lit(ECCENTRICITY_SQ) * s2).sqrt()
}

/// Magnitude of normal gravity at geodetic latitude and height above the ellipsoid, m/s²
/// (Somigliana on the ellipsoid with the second-order free-air correction of TR8350.2 eq. 4-3).
#[inline]
pub fn normal_gravity_m_s2<T: Real>(lat_rad: T, alt_m: T) -> T {
    normal_gravity_from_sin_m_s2(trig::sin(lat_rad), alt_m)
}

/// [`normal_gravity_m_s2`] from `sin L` (no trig call; the INS step has `sin L` already), m/s².
#[inline]
pub(crate) fn normal_gravity_from_sin_m_s2<T: Real>(sin_lat: T, alt_m: T) -> T {
    let s2 = sin_lat * sin_lat;
    let g0 = T::lit(GRAVITY_EQUATOR_M_S2) * (T::one() + T::lit(SOMIGLIANA_K) * s2)
        / (T::one() - T::lit(ECCENTRICITY_SQ) * s2).sqrt();
    let a = SEMI_MAJOR_AXIS_M;
    let m = EARTH_RATE_RAD_S * EARTH_RATE_RAD_S * a * a * SEMI_MINOR_AXIS_M / GM_M3_S2;
    let c1 = T::lit(2.0 / a * (1.0 + FLATTENING + m));
    let c1_lat = T::lit(2.0 / a * (-2.0 * FLATTENING));
    let c2 = T::lit(3.0 / (a * a));
    g0 * (T::one() - (c1 + c1_lat * s2) * alt_m + c2 * alt_m * alt_m)
}

/// Schuler frequency squared ω_s² = g / R_0 at the given gravity, rad²/s².
#[inline]
pub fn schuler_frequency_sq<T: Real>(gravity_m_s2: T) -> T {
    gravity_m_s2 / T::lit(MEAN_RADIUS_M)
}

/// Earth rate resolved in NED at geodetic latitude, rad/s: `[ω cos L, 0, −ω sin L]`.
#[inline]
pub fn earth_rate_ned<T: Real>(lat_rad: T) -> Vector3<T> {
    let w = T::lit(EARTH_RATE_RAD_S);
    Vector3::new(w * trig::cos(lat_rad), T::zero(), -w * trig::sin(lat_rad))
}

/// Transport rate ω_en of the NED frame over the earth, rad/s:
/// `[V_E/(R_N+h), −V_N/(R_M+h), −V_E tan L/(R_N+h)]`.
#[inline]
pub fn transport_rate_ned<T: Real>(lat_rad: T, alt_m: T, vel_ned_m_s: &Vector3<T>) -> Vector3<T> {
    let (r_m, r_n) = radii_m(lat_rad);
    let inv_n = T::one() / (r_n + alt_m);
    let inv_m = T::one() / (r_m + alt_m);
    Vector3::new(
        vel_ned_m_s.y * inv_n,
        -vel_ned_m_s.x * inv_m,
        -vel_ned_m_s.y * trig::tan(lat_rad) * inv_n,
    )
}

/// Normal gravity vector in NED (down positive), m/s².
#[inline]
pub fn gravity_ned<T: Real>(lat_rad: T, alt_m: T) -> Vector3<T> {
    Vector3::new(T::zero(), T::zero(), normal_gravity_m_s2(lat_rad, alt_m))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn published_wgs84_constants() {
        // TR8350.2 Table 3.3 / 3.4.
        assert!((SEMI_MINOR_AXIS_M - 6_356_752.314_2).abs() < 1e-3);
        assert!((ECCENTRICITY_SQ - 6.694_379_990_14e-3).abs() < 1e-14);
        // Somigliana constant from its definition.
        let k = (SEMI_MINOR_AXIS_M * GRAVITY_POLE_M_S2 - SEMI_MAJOR_AXIS_M * GRAVITY_EQUATOR_M_S2)
            / (SEMI_MAJOR_AXIS_M * GRAVITY_EQUATOR_M_S2);
        assert!((k - SOMIGLIANA_K).abs() < 1e-11);
    }

    #[test]
    fn gravity_at_equator_and_pole() {
        let ge: f64 = normal_gravity_m_s2(0.0, 0.0);
        let gp: f64 = normal_gravity_m_s2(core::f64::consts::FRAC_PI_2, 0.0);
        assert!((ge - 9.780_325_335_9).abs() < 1e-9, "{ge}");
        assert!((gp - 9.832_184_937_8).abs() < 1e-8, "{gp}");
        // Free-air gradient near the surface ≈ −3.086e-6 s⁻² at mid latitude.
        let l = 45f64.to_radians();
        let grad = (normal_gravity_m_s2(l, 1000.0) - normal_gravity_m_s2(l, 0.0)) / 1000.0;
        assert!((grad + 3.086e-6).abs() < 0.01e-6, "{grad}");
        // f32 agrees with f64.
        let g32: f32 = normal_gravity_m_s2(0.5f32, 2000.0);
        assert!((f64::from(g32) - normal_gravity_m_s2(0.5f64, 2000.0)).abs() < 2e-6);
    }

    #[test]
    fn radii_of_curvature() {
        let (rm0, rn0): (f64, f64) = radii_m(0.0);
        assert!((rm0 - 6_335_439.327).abs() < 1e-3, "{rm0}");
        assert!((rn0 - SEMI_MAJOR_AXIS_M).abs() < 1e-6);
        let (rmp, rnp): (f64, f64) = radii_m(core::f64::consts::FRAC_PI_2);
        assert!((rmp - 6_399_593.626).abs() < 1e-3, "{rmp}");
        assert!((rnp - rmp).abs() < 1e-6);
        let l = 0.7f64;
        assert!((meridian_radius_m(l) - radii_m(l).0).abs() < 1e-6);
        assert!((transverse_radius_m(l) - radii_m(l).1).abs() < 1e-6);
    }

    #[test]
    fn earth_and_transport_rate() {
        let l = 37f64.to_radians();
        let w = earth_rate_ned(l);
        assert!((w.norm() - EARTH_RATE_RAD_S).abs() < 1e-18);
        assert!(w.z < 0.0 && w.x > 0.0);
        // Flying east at 200 m/s: ω_en,N = V_E / (R_N + h).
        let v = Vector3::new(0.0, 200.0, 0.0);
        let rho = transport_rate_ned(l, 1000.0, &v);
        assert!((rho.x - 200.0 / (transverse_radius_m(l) + 1000.0)).abs() < 1e-15);
        assert!(rho.y == 0.0 && rho.z < 0.0);
        // Schuler period ≈ 84.4 min.
        let ws = schuler_frequency_sq(9.80665f64).sqrt();
        let period_min = 2.0 * core::f64::consts::PI / ws / 60.0;
        assert!((period_min - 84.4).abs() < 0.1, "{period_min}");
    }
}

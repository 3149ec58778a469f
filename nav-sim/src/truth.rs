//! The simulator's own earth model, rotations and line-of-sight geometry, for the truth.
//!
//! The truth must not share code with what it checks: an error in nav-core's earth model or
//! LOS geometry would otherwise move truth and estimate together and stay invisible to every
//! Monte Carlo. So the truth is computed here, differently:
//!
//! - **Gravity**: the exact normal gravity vector of the WGS-84 ellipsoid at any height, from
//!   its potential in ellipsoidal-harmonic coordinates. nav-core uses Somigliana's formula on
//!   the ellipsoid with a second-order free-air series in height, down only. The two agree to
//!   1.5·10⁻⁶ m/s² down up to 20 km; the truth's north component (plumb-line curvature,
//!   4·10⁻⁵ m/s² at 5 km) is a real effect the filters do not model. The tests bound both.
//! - **Geometry**: geodetic ↔ ECEF, and the landmark line of sight as the ECEF difference
//!   rotated into NED (nav-core forms the difference in small quantities to stay exact in f32).
//! - **Rotations**: nalgebra's `Rotation3` / `UnitQuaternion` (an independent implementation
//!   of the same conventions: ZYX Euler angles roll-pitch-yaw, `C_b^n`, Hamilton quaternions).
//!
//! Everything is `f64`.

use nalgebra::{Matrix3, Quaternion, Rotation3, UnitQuaternion, Vector3};

/// WGS-84 semi-major axis, m.
pub const A_M: f64 = 6_378_137.0;
/// WGS-84 inverse flattening.
pub const INV_FLATTENING: f64 = 298.257_223_563;
/// WGS-84 earth rotation rate, rad/s.
pub const OMEGA_RAD_S: f64 = 7.292_115e-5;
/// WGS-84 gravitational constant (with atmosphere), m³/s².
pub const GM_M3_S2: f64 = 3.986_004_418e14;

/// First eccentricity squared.
fn e2() -> f64 {
    let f = 1.0 / INV_FLATTENING;
    f * (2.0 - f)
}

/// Geodetic position (latitude, longitude in rad, height above the ellipsoid in m) → ECEF, m.
pub fn geodetic_to_ecef(lat_rad: f64, lon_rad: f64, alt_m: f64) -> Vector3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    let n = A_M / (1.0 - e2() * sl * sl).sqrt();
    Vector3::new(
        (n + alt_m) * cl * co,
        (n + alt_m) * cl * so,
        (n * (1.0 - e2()) + alt_m) * sl,
    )
}

/// `C_e^n`: ECEF → NED at a geodetic latitude and longitude.
pub fn ecef_to_ned(lat_rad: f64, lon_rad: f64) -> Matrix3<f64> {
    let (sl, cl) = lat_rad.sin_cos();
    let (so, co) = lon_rad.sin_cos();
    Matrix3::new(
        -sl * co,
        -sl * so,
        cl, //
        -so,
        co,
        0.0, //
        -cl * co,
        -cl * so,
        -sl,
    )
}

/// Normal gravity of the WGS-84 ellipsoid in NED, m/s², at a geodetic position: the gradient
/// of the normal potential in closed form in ellipsoidal-harmonic coordinates (u, β)
/// (Heiskanen & Moritz §2-7, §2-9; NGA TR8350.2 §4), valid at any height. Off the ellipsoid
/// it has a north component (the curvature of the normal plumb line, ≈ 0.17″ per km of
/// height × sin 2L) that nav-core's down-only model neglects.
pub fn gravity_ned_m_s2(lat_rad: f64, lon_rad: f64, alt_m: f64) -> Vector3<f64> {
    let b = A_M * (1.0 - 1.0 / INV_FLATTENING);
    let e_lin = (A_M * A_M - b * b).sqrt();
    let e_lin2 = e_lin * e_lin;
    let w2 = OMEGA_RAD_S * OMEGA_RAD_S;
    let q = |u: f64| 0.5 * ((1.0 + 3.0 * u * u / e_lin2) * (e_lin / u).atan() - 3.0 * u / e_lin);
    let r = geodetic_to_ecef(lat_rad, lon_rad, alt_m);
    let r2 = r.norm_squared();
    let p = r.x.hypot(r.y);
    let d = r2 - e_lin2;
    let u2 = 0.5 * d * (1.0 + (1.0 + 4.0 * e_lin2 * r.z * r.z / (d * d)).sqrt());
    let u = u2.sqrt();
    let s = (u2 + e_lin2).sqrt();
    let (sb, cb) = (r.z * s).atan2(u * p).sin_cos();
    let w = ((u2 + e_lin2 * sb * sb) / (u2 + e_lin2)).sqrt();
    let (q0, qu) = (q(b), q(u));
    let q_prime = 3.0 * (1.0 + u2 / e_lin2) * (1.0 - (u / e_lin) * (e_lin / u).atan()) - 1.0;
    let g_u = -(GM_M3_S2 / (u2 + e_lin2)
        + w2 * A_M * A_M * e_lin / (u2 + e_lin2) * (q_prime / q0) * (0.5 * sb * sb - 1.0 / 6.0)
        - w2 * u * cb * cb)
        / w;
    let g_beta = (w2 * A_M * A_M / s * (qu / q0) - w2 * s) * sb * cb / w;
    let (so, co) = lon_rad.sin_cos();
    let e_u = Vector3::new(u / s * cb * co, u / s * cb * so, sb) / w;
    let e_beta = Vector3::new(-sb * co, -sb * so, u / s * cb) / w;
    ecef_to_ned(lat_rad, lon_rad) * (e_u * g_u + e_beta * g_beta)
}

/// Down component of [`gravity_ned_m_s2`] (normal gravity does not depend on longitude), m/s²:
/// the gravity a simulated vertical accelerometer feels.
pub fn gravity_down_m_s2(lat_rad: f64, alt_m: f64) -> f64 {
    gravity_ned_m_s2(lat_rad, 0.0, alt_m).z
}

/// Radii of curvature `(meridian R_M, prime vertical R_N)` at a geodetic latitude, m.
pub fn radii_of_curvature_m(lat_rad: f64) -> (f64, f64) {
    let w2 = 1.0 - e2() * lat_rad.sin().powi(2);
    let r_n = A_M / w2.sqrt();
    (r_n * (1.0 - e2()) / w2, r_n)
}

/// Earth rate in NED, rad/s: `C_e^n [0, 0, ω]`.
pub fn earth_rate_ned_rad_s(lat_rad: f64) -> Vector3<f64> {
    ecef_to_ned(lat_rad, 0.0) * Vector3::new(0.0, 0.0, OMEGA_RAD_S)
}

/// Transport rate ω_en (rate of NED over the earth) in NED, rad/s, from the rates of latitude
/// and longitude that the NED velocity implies: `ω_en = [l̇ cos L, −L̇, −l̇ sin L]`.
pub fn transport_rate_ned_rad_s(
    lat_rad: f64,
    alt_m: f64,
    v_ned_m_s: &Vector3<f64>,
) -> Vector3<f64> {
    let (r_m, r_n) = radii_of_curvature_m(lat_rad);
    let lat_rate = v_ned_m_s.x / (r_m + alt_m);
    let lon_rate = v_ned_m_s.y / ((r_n + alt_m) * lat_rad.cos());
    Vector3::new(
        lon_rate * lat_rad.cos(),
        -lat_rate,
        -lon_rate * lat_rad.sin(),
    )
}

/// Vector from a vehicle to a landmark (both geodetic) in the vehicle's NED frame, m.
pub fn landmark_vector_ned_m(vehicle: (f64, f64, f64), landmark: (f64, f64, f64)) -> Vector3<f64> {
    let (lat, lon, alt) = vehicle;
    let d = geodetic_to_ecef(landmark.0, landmark.1, landmark.2) - geodetic_to_ecef(lat, lon, alt);
    ecef_to_ned(lat, lon) * d
}

/// Gimbal angles (pitch, yaw) in rad of a line-of-sight direction `u_b` in body axes (X
/// forward, Y right, Z down): pitch up positive, yaw right positive.
pub fn gimbal_angles_rad(u_b: &Vector3<f64>) -> (f64, f64) {
    let u = u_b.normalize();
    let pitch = (-u.z).asin();
    let yaw = u.y.atan2(u.x);
    (pitch, yaw)
}

/// `C_b^n` from ZYX Euler angles (roll φ, pitch θ, yaw ψ), rad.
pub fn dcm_from_euler(roll_rad: f64, pitch_rad: f64, yaw_rad: f64) -> Matrix3<f64> {
    Rotation3::from_euler_angles(roll_rad, pitch_rad, yaw_rad).into_inner()
}

/// ZYX Euler angles (roll, pitch, yaw), rad, of a `C_b^n`.
pub fn euler_from_dcm(c_b_n: &Matrix3<f64>) -> (f64, f64, f64) {
    Rotation3::from_matrix_unchecked(*c_b_n).euler_angles()
}

/// `exp([φ×])`: the rotation by the rotation vector φ, rad.
pub fn rotation_from_vector(phi_rad: &Vector3<f64>) -> Matrix3<f64> {
    Rotation3::new(*phi_rad).into_inner()
}

/// The rotation vector of a rotation matrix, rad (angle in [0, π]).
pub fn vector_from_rotation(c: &Matrix3<f64>) -> Vector3<f64> {
    Rotation3::from_matrix(c).scaled_axis()
}

/// Hamilton quaternion (scalar first) of a `C_b^n`.
pub fn quaternion_from_dcm(c_b_n: &Matrix3<f64>) -> Quaternion<f64> {
    *UnitQuaternion::from_matrix(c_b_n).quaternion()
}

/// `C_b^n` of a Hamilton quaternion (normalised first).
pub fn dcm_from_quaternion(q: &Quaternion<f64>) -> Matrix3<f64> {
    UnitQuaternion::from_quaternion(*q)
        .to_rotation_matrix()
        .into_inner()
}

/// The skew-symmetric matrix `[v×]`.
pub fn cross_matrix(v: &Vector3<f64>) -> Matrix3<f64> {
    v.cross_matrix()
}

#[cfg(test)]
mod tests {
    //! Cross-checks against nav-core: the two implementations must agree within the stated
    //! physical differences; a disagreement beyond them is a bug in one of them.
    use super::*;
    use nav_core::earth;
    use nav_core::math::rotation;

    #[test]
    fn gravity_agrees_with_nav_core_within_the_free_air_series_and_plumb_line_terms() {
        let mut worst_down = 0.0_f64;
        let mut worst_horizontal = 0.0_f64;
        for lat_deg in (-80..=80).step_by(5) {
            for alt in [0.0, 1_000.0, 5_000.0, 20_000.0] {
                let lat = f64::from(lat_deg).to_radians();
                let g = gravity_ned_m_s2(lat, 0.3, alt);
                let g_core = earth::normal_gravity_m_s2(lat, alt);
                worst_down = worst_down.max((g.z - g_core).abs());
                worst_horizontal = worst_horizontal.max(g.x.abs().max(g.y.abs()));
            }
        }
        // Truncation of the free-air series: 1.44·10⁻⁶ m/s² at 20 km.
        assert!(
            worst_down < 2e-6,
            "down component differs by {worst_down} m/s²"
        );
        // Plumb-line curvature: 0.17″/km × sin 2L → 1.6·10⁻⁴ m/s² at 20 km, 45°.
        assert!(
            worst_horizontal < 2e-4,
            "horizontal component {worst_horizontal} m/s²"
        );
        // On the ellipsoid the normal field is normal to it, with Somigliana's magnitude.
        let g0 = gravity_ned_m_s2(0.7, -1.0, 0.0);
        assert!(g0.x.abs() < 1e-12 && g0.y.abs() < 1e-12);
        assert!((g0.z - earth::normal_gravity_surface_m_s2(0.7)).abs() < 1e-10);
    }

    #[test]
    fn radii_and_rates_agree_with_nav_core() {
        for lat_deg in (-85..=85).step_by(5) {
            let lat = f64::from(lat_deg).to_radians();
            let (rm, rn) = radii_of_curvature_m(lat);
            let (rm_c, rn_c) = earth::radii_m(lat);
            assert!((rm - rm_c).abs() < 1e-6 * rm && (rn - rn_c).abs() < 1e-6 * rn);
            let w = earth_rate_ned_rad_s(lat) - earth::earth_rate_ned(lat);
            assert!(w.norm() < 1e-15);
            let v = Vector3::new(230.0, -140.0, 12.0);
            let t = transport_rate_ned_rad_s(lat, 3_000.0, &v)
                - earth::transport_rate_ned(lat, 3_000.0, &v);
            assert!(
                t.norm() < 1e-13,
                "transport rate differs by {t:?} at {lat_deg}°"
            );
        }
    }

    #[test]
    fn landmark_vector_agrees_with_nav_core_and_has_the_ecef_range() {
        use nav_core::seeker_ins::landmark_vector_ned;
        use nav_core::seeker_ins::{Landmark, Position};
        let veh = (0.61, 2.2, 3_000.0);
        for (dlat, dlon, dalt) in [
            (0.01, 0.0, -3_000.0),
            (-0.004, 0.012, 500.0),
            (0.0, -0.015, 0.0),
        ] {
            let lm = (veh.0 + dlat, veh.1 + dlon, veh.2 + dalt);
            let d = landmark_vector_ned_m(veh, lm);
            let range =
                (geodetic_to_ecef(lm.0, lm.1, lm.2) - geodetic_to_ecef(veh.0, veh.1, veh.2)).norm();
            assert!((d.norm() - range).abs() < 1e-6);
            let core_lm = Landmark::<f64>::new(Position {
                lat_rad: lm.0,
                lon_rad: lm.1,
                alt_m: lm.2,
            })
            .unwrap();
            let core = landmark_vector_ned(
                &Position {
                    lat_rad: veh.0,
                    lon_rad: veh.1,
                    alt_m: veh.2,
                },
                &core_lm,
            );
            assert!((core - d).norm() < 1e-6 * range, "{core:?} vs {d:?}");
        }
    }

    #[test]
    fn rotations_agree_with_nav_core_conventions() {
        let (r, p, y) = (0.3, -0.7, 2.5);
        let c = dcm_from_euler(r, p, y);
        assert!((c - rotation::euler_to_dcm(r, p, y)).norm() < 1e-14);
        let (r2, p2, y2) = euler_from_dcm(&c);
        assert!((r2 - r).abs() < 1e-12 && (p2 - p).abs() < 1e-12 && (y2 - y).abs() < 1e-12);
        let q = quaternion_from_dcm(&c);
        let qc = rotation::dcm_to_quat(&c);
        // Same rotation (q and −q are the same).
        assert!((q.coords - qc.coords).norm() < 1e-12 || (q.coords + qc.coords).norm() < 1e-12);
        assert!((dcm_from_quaternion(&q) - c).norm() < 1e-12);
        let phi = Vector3::new(0.2, -0.1, 0.4);
        assert!((rotation_from_vector(&phi) - rotation::exp_so3(&phi)).norm() < 1e-14);
        assert!((vector_from_rotation(&rotation_from_vector(&phi)) - phi).norm() < 1e-12);
        let u = Vector3::new(0.8, 0.3, -0.2);
        let (pitch, yaw) = gimbal_angles_rad(&u);
        let core = nav_core::seeker_ins::gimbal_angles_of(&u.normalize());
        assert!((pitch - core.pitch_rad).abs() < 1e-14 && (yaw - core.yaw_rad).abs() < 1e-14);
    }
}

//! Rotation helpers with explicit conventions.
//!
//! * `C_a^b` (a direction cosine matrix, DCM) transforms coordinates from frame a to frame b:
//!   `v_b = C_a^b v_a`.
//! * A rotation vector `φ` (axis × angle, rad) that turns frame a into frame b, expressed in a,
//!   gives `C_b^a = exp([φ×])` (Rodrigues) and `C_a^b = exp(−[φ×])`.
//! * Quaternions are Hamilton, scalar first `q = [w, x, y, z]`; `q_b^n` rotates body to
//!   navigation: `C_b^n = R(q_b^n)`.
//! * Euler angles are the aerospace 3-2-1 sequence (yaw ψ about z, pitch θ about y, roll φ
//!   about x) from navigation to body.

use crate::math::trig;
use crate::Real;
use nalgebra::{Matrix3, Quaternion, Vector3};

/// Skew-symmetric (cross-product) matrix `[v×]`, so that `[v×] u = v × u`.
#[inline]
pub fn skew<T: Real>(v: &Vector3<T>) -> Matrix3<T> {
    let z = T::zero();
    Matrix3::new(z, -v.z, v.y, v.z, z, -v.x, -v.y, v.x, z)
}

/// The vector of a skew-symmetric matrix (inverse of [`skew`]); uses the antisymmetric part.
#[inline]
pub fn unskew<T: Real>(m: &Matrix3<T>) -> Vector3<T> {
    let half = T::lit(0.5);
    Vector3::new(
        half * (m.m32 - m.m23),
        half * (m.m13 - m.m31),
        half * (m.m21 - m.m12),
    )
}

/// Rodrigues' formula `exp([φ×]) = I + (sin θ/θ)[φ×] + ((1 − cos θ)/θ²)[φ×]²`, θ = |φ|.
///
/// Uses series for the coefficients below θ = 1e-4 rad, so it is exact to working precision for
/// every angle, including zero.
#[inline]
pub fn exp_so3<T: Real>(phi: &Vector3<T>) -> Matrix3<T> {
    let th2 = phi.norm_squared();
    let (a, b) = if th2 < T::lit(1e-8) {
        // sin θ/θ = 1 − θ²/6 + θ⁴/120; (1 − cos θ)/θ² = 1/2 − θ²/24 + θ⁴/720
        (
            T::one() - th2 / T::lit(6.0) + th2 * th2 / T::lit(120.0),
            T::lit(0.5) - th2 / T::lit(24.0) + th2 * th2 / T::lit(720.0),
        )
    } else {
        let th = th2.sqrt();
        (trig::sin(th) / th, (T::one() - trig::cos(th)) / th2)
    };
    let k = skew(phi);
    Matrix3::identity() + k * a + k * k * b
}

/// Rotation vector of a proper rotation matrix (inverse of [`exp_so3`]) for angles below π.
pub fn log_so3<T: Real>(c: &Matrix3<T>) -> Vector3<T> {
    let half = T::lit(0.5);
    let cos_th = ((c.trace() - T::one()) * half).clamp(-T::one(), T::one());
    let th = cos_th.acos();
    let w = unskew(c);
    if th < T::lit(1e-4) {
        // sin θ/θ ≈ 1 − θ²/6
        w * (T::one() + th * th / T::lit(6.0))
    } else {
        w * (th / trig::sin(th))
    }
}

/// Small-angle DCM `I − [θ×]`, the first-order form of `exp(−[θ×])` (e.g. `C_m^s` of the
/// transfer-alignment spec).
#[inline]
pub fn small_angle_dcm<T: Real>(theta: &Vector3<T>) -> Matrix3<T> {
    Matrix3::identity() - skew(theta)
}

/// Quaternion from a rotation vector φ (rad): `[cos(θ/2), sin(θ/2) φ/θ]`.
#[inline]
pub fn quat_from_rotation_vector<T: Real>(phi: &Vector3<T>) -> Quaternion<T> {
    let th2 = phi.norm_squared();
    let half = T::lit(0.5);
    let (c, s_over_th) = if th2 < T::lit(1e-8) {
        // cos(θ/2) ≈ 1 − θ²/8 + θ⁴/384; sin(θ/2)/θ ≈ 1/2 − θ²/48 + θ⁴/3840
        (
            T::one() - th2 / T::lit(8.0) + th2 * th2 / T::lit(384.0),
            half - th2 / T::lit(48.0) + th2 * th2 / T::lit(3840.0),
        )
    } else {
        let th = th2.sqrt();
        (trig::cos(th * half), trig::sin(th * half) / th)
    };
    Quaternion::new(c, phi.x * s_over_th, phi.y * s_over_th, phi.z * s_over_th)
}

/// DCM of a unit quaternion `q_b^n`: returns `C_b^n`. The quaternion is not re-normalised.
#[inline]
pub fn quat_to_dcm<T: Real>(q: &Quaternion<T>) -> Matrix3<T> {
    let (w, x, y, z) = (q.w, q.i, q.j, q.k);
    let two = T::lit(2.0);
    let (ww, xx, yy, zz) = (w * w, x * x, y * y, z * z);
    Matrix3::new(
        ww + xx - yy - zz,
        two * (x * y - w * z),
        two * (x * z + w * y),
        two * (x * y + w * z),
        ww - xx + yy - zz,
        two * (y * z - w * x),
        two * (x * z - w * y),
        two * (y * z + w * x),
        ww - xx - yy + zz,
    )
}

/// Unit quaternion of a proper rotation matrix (Shepperd's method), `C_b^n → q_b^n`, with
/// non-negative scalar part.
pub fn dcm_to_quat<T: Real>(c: &Matrix3<T>) -> Quaternion<T> {
    let one = T::one();
    let quarter = T::lit(0.25);
    let tr = c.trace();
    let q = if tr > c.m11 && tr > c.m22 && tr > c.m33 {
        let s = (one + tr).sqrt() * T::lit(2.0); // 4w
        Quaternion::new(
            quarter * s,
            (c.m32 - c.m23) / s,
            (c.m13 - c.m31) / s,
            (c.m21 - c.m12) / s,
        )
    } else if c.m11 > c.m22 && c.m11 > c.m33 {
        let s = (one + c.m11 - c.m22 - c.m33).sqrt() * T::lit(2.0); // 4x
        Quaternion::new(
            (c.m32 - c.m23) / s,
            quarter * s,
            (c.m12 + c.m21) / s,
            (c.m13 + c.m31) / s,
        )
    } else if c.m22 > c.m33 {
        let s = (one + c.m22 - c.m11 - c.m33).sqrt() * T::lit(2.0); // 4y
        Quaternion::new(
            (c.m13 - c.m31) / s,
            (c.m12 + c.m21) / s,
            quarter * s,
            (c.m23 + c.m32) / s,
        )
    } else {
        let s = (one + c.m33 - c.m11 - c.m22).sqrt() * T::lit(2.0); // 4z
        Quaternion::new(
            (c.m21 - c.m12) / s,
            (c.m13 + c.m31) / s,
            (c.m23 + c.m32) / s,
            quarter * s,
        )
    };
    let q = if q.w < T::zero() { -q } else { q };
    let n = q.norm();
    q / n
}

/// Hamilton product `a ⊗ b` (for `q_b^n ⊗ q_c^b = q_c^n`).
#[inline]
pub fn quat_mul<T: Real>(a: &Quaternion<T>, b: &Quaternion<T>) -> Quaternion<T> {
    Quaternion::new(
        a.w * b.w - a.i * b.i - a.j * b.j - a.k * b.k,
        a.w * b.i + a.i * b.w + a.j * b.k - a.k * b.j,
        a.w * b.j - a.i * b.k + a.j * b.w + a.k * b.i,
        a.w * b.k + a.i * b.j - a.j * b.i + a.k * b.w,
    )
}

/// Normalises a quaternion to unit length; returns `None` if its norm is zero or not finite.
#[inline]
pub fn quat_normalize<T: Real>(q: &Quaternion<T>) -> Option<Quaternion<T>> {
    let n2 = q.norm_squared();
    if n2.is_finite() && n2 > T::zero() {
        Some(q / n2.sqrt())
    } else {
        None
    }
}

/// `C_b^n` from 3-2-1 Euler angles (roll φ, pitch θ, yaw ψ), rad.
#[inline]
pub fn euler_to_dcm<T: Real>(roll: T, pitch: T, yaw: T) -> Matrix3<T> {
    let (sr, cr) = trig::sin_cos(roll);
    let (sp, cp) = trig::sin_cos(pitch);
    let (sy, cy) = trig::sin_cos(yaw);
    Matrix3::new(
        cp * cy,
        sr * sp * cy - cr * sy,
        cr * sp * cy + sr * sy,
        cp * sy,
        sr * sp * sy + cr * cy,
        cr * sp * sy - sr * cy,
        -sp,
        sr * cp,
        cr * cp,
    )
}

/// 3-2-1 Euler angles `(roll, pitch, yaw)` in rad of `C_b^n`; pitch is clamped to ±π/2.
#[inline]
pub fn dcm_to_euler<T: Real>(c: &Matrix3<T>) -> (T, T, T) {
    let pitch = (-c.m31).clamp(-T::one(), T::one()).asin();
    let roll = c.m32.atan2(c.m33);
    let yaw = c.m21.atan2(c.m11);
    (roll, pitch, yaw)
}

/// Elementary frame rotation about x by angle a: `R_x(a)` maps coordinates of the old frame to
/// the new frame rotated by +a about x.
#[inline]
pub fn frame_rotation_x<T: Real>(a: T) -> Matrix3<T> {
    let (s, c) = trig::sin_cos(a);
    let (o, z) = (T::one(), T::zero());
    Matrix3::new(o, z, z, z, c, s, z, -s, c)
}

/// Elementary frame rotation about y by angle a (see [`frame_rotation_x`]).
#[inline]
pub fn frame_rotation_y<T: Real>(a: T) -> Matrix3<T> {
    let (s, c) = trig::sin_cos(a);
    let (o, z) = (T::one(), T::zero());
    Matrix3::new(c, z, -s, z, o, z, s, z, c)
}

/// Elementary frame rotation about z by angle a (see [`frame_rotation_x`]).
#[inline]
pub fn frame_rotation_z<T: Real>(a: T) -> Matrix3<T> {
    let (s, c) = trig::sin_cos(a);
    let (o, z) = (T::one(), T::zero());
    Matrix3::new(c, s, z, -s, c, z, z, z, o)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn close(a: &Matrix3<f64>, b: &Matrix3<f64>, tol: f64) -> bool {
        (a - b).abs().max() < tol
    }

    #[test]
    fn skew_is_cross_product_and_unskew_inverts() {
        let v = Vector3::new(0.3, -1.2, 2.5);
        let u = Vector3::new(-0.7, 0.4, 1.1);
        assert!((skew(&v) * u - v.cross(&u)).norm() < 1e-15);
        assert!((unskew(&skew(&v)) - v).norm() < 1e-15);
    }

    #[test]
    fn rodrigues_round_trip_and_orthonormal() {
        for phi in [
            Vector3::new(0.0, 0.0, 0.0),
            Vector3::new(1e-7, -2e-7, 3e-7),
            Vector3::new(0.1, -0.2, 0.3),
            Vector3::new(1.0, 2.0, -0.5),
        ] {
            let c = exp_so3(&phi);
            assert!(close(&(c * c.transpose()), &Matrix3::identity(), 1e-14));
            assert!((c.determinant() - 1.0).abs() < 1e-14);
            assert!((log_so3(&c) - phi).norm() < 1e-12, "{phi:?}");
            // Rotation about its own axis leaves the axis fixed.
            assert!((c * phi - phi).norm() < 1e-14);
        }
        // Against nalgebra's independent implementation.
        let phi = Vector3::new(0.4, -0.1, 0.9);
        let r = nalgebra::Rotation3::from_scaled_axis(phi);
        assert!(close(&exp_so3(&phi), r.matrix(), 1e-14));
    }

    #[test]
    fn small_angle_matches_exact_to_second_order() {
        let th = Vector3::new(1e-3, -2e-3, 0.5e-3);
        let exact = exp_so3(&(-th));
        let err = (small_angle_dcm(&th) - exact).abs().max();
        assert!(err < 1e-5 && err > 1e-8, "{err}");
    }

    #[test]
    fn quaternion_dcm_round_trip() {
        let phi = Vector3::new(0.3_f64, -0.8, 1.9);
        let q = quat_from_rotation_vector(&phi);
        assert!((q.norm() - 1.0).abs() < 1e-15);
        let c = quat_to_dcm(&q);
        assert!(close(&c, &exp_so3(&phi), 1e-14));
        let q2 = dcm_to_quat(&c);
        assert!((q2.coords - q.coords).norm() < 1e-14);
        // All four Shepperd branches.
        for phi in [
            Vector3::new(3.0, 0.1, 0.1),
            Vector3::new(0.1, 3.0, 0.1),
            Vector3::new(0.1, 0.1, 3.0),
        ] {
            let c = exp_so3(&phi);
            assert!(close(&quat_to_dcm(&dcm_to_quat(&c)), &c, 1e-13));
        }
        // Composition: q_ab ⊗ q_bc ↔ C_ab C_bc.
        let a = quat_from_rotation_vector(&Vector3::new(0.2, 0.1, -0.3));
        let b = quat_from_rotation_vector(&Vector3::new(-0.5, 0.4, 0.05));
        assert!(close(
            &quat_to_dcm(&quat_mul(&a, &b)),
            &(quat_to_dcm(&a) * quat_to_dcm(&b)),
            1e-14
        ));
        assert!(quat_normalize(&Quaternion::new(0.0, 0.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn euler_round_trip_and_elementary_rotations() {
        let (r, p, y) = (0.3_f64, -0.4, 2.0);
        let c = euler_to_dcm(r, p, y);
        let (r2, p2, y2) = dcm_to_euler(&c);
        assert!((r - r2).abs() < 1e-14 && (p - p2).abs() < 1e-14 && (y - y2).abs() < 1e-14);
        // C_n^b = R_x(roll) R_y(pitch) R_z(yaw).
        let cnb = frame_rotation_x(r) * frame_rotation_y(p) * frame_rotation_z(y);
        assert!(close(&cnb.transpose(), &c, 1e-14));
    }
}

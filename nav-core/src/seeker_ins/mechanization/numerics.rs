//! The compensated numerics of the mechanization's step: the attitude increment formed
//! without cancellation, `q(φ) − 1`, Kahan sums, the DCM of a non-unit quaternion.
use crate::math::rotation::{quat_mul, quat_to_dcm};
use crate::math::trig;
use crate::{NavError, Real};
use nalgebra::{Matrix3, Quaternion, Vector3, Vector4};

/// The attitude over one interval, `q` with its compensation `q_lo` → the new pair, from the
/// body rotation `alpha` (rad) and the navigation frame's rotation `zeta` (rad):
/// q₊ = (1 + n) ⊗ q ⊗ (1 + b) with the small parts n = q(−ζ) − 1, b = q(α) − 1, so the
/// increment Δ = n⊗q + q⊗b + n⊗q⊗b is formed without cancellation and added with
/// compensation; renormalised when |q₊|² departs from 1 by more than 16 ε.
/// `NonFiniteInput` if |q₊|² is not finite and > 0.
#[inline(always)]
pub(super) fn attitude_step<T: Real>(
    q: &Quaternion<T>,
    q_lo: &Vector4<T>,
    alpha: &Vector3<T>,
    zeta: &Vector3<T>,
) -> Result<(Vector4<T>, Vector4<T>), NavError> {
    let b = quat_minus_one(alpha);
    let n = quat_minus_one(&(-zeta));
    let qb = quat_mul(q, &b);
    let delta = quat_mul(&n, q).coords + qb.coords + quat_mul(&n, &qb).coords;
    let (mut q_hi, mut q_lo) = kahan_add4(&q.coords, q_lo, &delta);
    let n2 = q_hi.norm_squared();
    if !n2.is_finite() || n2 <= T::zero() {
        return Err(NavError::NonFiniteInput {
            input: "attitude quaternion",
        });
    }
    if (n2 - T::one()).abs() > T::EPS * T::lit(16.0) {
        let inv = T::one() / n2.sqrt();
        q_hi *= inv;
        q_lo *= inv;
    }
    Ok((q_hi, q_lo))
}

/// C_b^n of a quaternion of any non-zero norm: the homogeneous DCM formula divided by |q|².
pub(super) fn unit_dcm<T: Real>(q: &Quaternion<T>) -> Matrix3<T> {
    quat_to_dcm(q) * (T::one() / q.norm_squared())
}

/// `q(φ) − 1` for a rotation vector φ (|φ| < 1 rad): scalar part `cos(θ/2) − 1 = −2 sin²(θ/4)`
/// without cancellation, vector part `sin(θ/2) φ/θ`.
fn quat_minus_one<T: Real>(phi: &Vector3<T>) -> Quaternion<T> {
    let th2 = phi.norm_squared();
    let (w_m1, s_over_th) = if th2 < T::lit(1e-8) {
        (
            -th2 / T::lit(8.0) + th2 * th2 / T::lit(384.0),
            T::lit(0.5) - th2 / T::lit(48.0) + th2 * th2 / T::lit(3840.0),
        )
    } else {
        let th = th2.sqrt();
        let s4 = trig::sin(th * T::lit(0.25));
        (-T::lit(2.0) * s4 * s4, trig::sin(th * T::lit(0.5)) / th)
    };
    Quaternion::new(
        w_m1,
        phi.x * s_over_th,
        phi.y * s_over_th,
        phi.z * s_over_th,
    )
}

/// Kahan compensated sum `s + x` with running compensation `c`: returns the new `(s, c)`.
/// Slowly varying increments (a constant acceleration, a steady turn) otherwise round the same
/// way step after step: in f32 that alone is ≈ 0.1 m/s and 2e-4 rad after 240 s.
pub(super) fn kahan_add<T: Real>(
    s: &Vector3<T>,
    c: &Vector3<T>,
    x: &Vector3<T>,
) -> (Vector3<T>, Vector3<T>) {
    let y = x - c;
    let t = s + y;
    let c_new = (t - s) - y;
    (t, c_new)
}

/// [`kahan_add`] for quaternion coordinates.
fn kahan_add4<T: Real>(s: &Vector4<T>, c: &Vector4<T>, x: &Vector4<T>) -> (Vector4<T>, Vector4<T>) {
    let y = x - c;
    let t = s + y;
    let c_new = (t - s) - y;
    (t, c_new)
}

//! The accelerometer part of the flight configuration's charge: the departure of the specific
//! force from the reference, split into its sustained part (to the bias states) and its
//! transient rest (to the velocity), each **correlated with the reference's share** of the
//! bias states' error through the one set of S and M (module [`super`] doc, "The departure's
//! correlation with the reference").

use super::{
    charge_above, equivalent_covariance, equivalent_variance, EquivalentBiasCharge,
    InstrumentErrors, SUSTAINED_TIME_CONSTANT_S,
};
use crate::seeker_ins::error_model::{ACC_BIAS, STATES, VEL};
use crate::Real;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Per axis `num / den`, zero where `den` is not positive (no reference variance: nothing to
/// regress on).
fn ratio<T: Real>(num: &Vector3<T>, den: &Vector3<T>) -> Vector3<T> {
    num.zip_map(den, |n, d| if d > T::zero() { n / d } else { T::zero() })
}

/// The bias states' variances, per body axis, (m/s²)².
fn bias_diagonal<T: Real>(p: &SMatrix<T, STATES, STATES>) -> Vector3<T> {
    Vector3::from_fn(|i, _| {
        p.get((ACC_BIAS + i, ACC_BIAS + i))
            .copied()
            .unwrap_or(T::zero())
    })
}

/// One covariance step's accelerometer departure (reference `f0`, body specific force `f_b`,
/// both m/s², over `dt_s`, attitude `c_b_n`): applies the transfer `P ← T P Tᵀ` (the parts of
/// the departure's errors the reference's bias error explains) and returns the variances not
/// explained, `(velocity per NED axis, bias per body axis)`, to add as a diagonal, with the
/// charge's new memory in `next` (module [`super`] doc).
#[allow(clippy::too_many_arguments)]
pub(super) fn accel_departure<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &EquivalentBiasCharge<T>,
    next: &mut EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    c_b_n: &Matrix3<T>,
    f0: &Vector3<T>,
    f_b: &Vector3<T>,
    dt_s: T,
) -> (Vector3<T>, Vector3<T>) {
    let (sa, ma) = (errors.accel_scale_factor, errors.accel_misalignment_rad);
    let one = Vector3::repeat(T::one());
    let p_ref = charge.reference_var_m2_s4;
    // Sustained part: the running mean of the departure (first-order lag, time constant `τ`,
    // `α = Δt / (τ + Δt)` stable for any step).
    let departure = f_b - f0;
    let tau = T::lit(SUSTAINED_TIME_CONSTANT_S);
    let alpha = dt_s / (tau + dt_s);
    let sustained = charge.sustained_f_b_m_s2 + (departure - charge.sustained_f_b_m_s2) * alpha;
    next.sustained_f_b_m_s2 = sustained;
    // Its regression on the reference's bias error: gain `k = c(f_ref, f̄) / P_ref` (≥ 0, as
    // the mean stands), the bias error scaled by `(1 + k) / (1 + k_before)`; the rest,
    // `v(f̄) − k c`, independent. The later steps' scales scale what is added now, so the
    // rest is kept divided by `(1 + k)²` (its largest so far) and added times it.
    let c_sus = equivalent_covariance(f0, &sustained, sa, ma).map(|x| x.max(T::zero()));
    let gain_now = ratio(&c_sus, &p_ref);
    let gain = gain_now;
    next.sustained_gain = gain;
    let scale = (gain + one).component_div(&(charge.sustained_gain + one));
    let scale_sq = (gain + one).component_mul(&(gain + one));
    let rest = (equivalent_variance(&sustained, sa, ma) - gain_now.component_mul(&c_sus))
        .map(|x| x.max(T::zero()))
        .component_div(&scale_sq);
    let (add_rest, charged) = charge_above(&rest, &charge.charged_bias_m2_s4);
    let add_bias = add_rest.component_mul(&scale_sq);
    next.charged_bias_m2_s4 = charged;
    // Transient rest: `ΔD = (f − f_ref − f̄) Δt`, its velocity error `C (S + M) ΔD` regressed
    // on the (scaled) bias error, gain `c(f_ref, ΔD) / (P_ref (1 + k))` per body axis.
    let d_dv = (departure - sustained) * dt_s;
    let excess = charge.excess_dv_b_m_s + d_dv;
    next.excess_dv_b_m_s = excess;
    let p_ref_scaled = p_ref.component_mul(&(gain + one));
    let g_v = ratio(&equivalent_covariance(f0, &d_dv, sa, ma), &p_ref_scaled);
    // `E[V, ∇] = C_b^n diag(g_v)`: the columns of C_b^n scaled.
    let a = Matrix3::from_fn(|r, m| {
        c_b_n.get((r, m)).copied().unwrap_or(T::zero()) * g_v.get(m).copied().unwrap_or(T::zero())
    });
    transfer_from_bias(&mut p.data.0, &a, &scale);
    // What the transfers do not explain of `v(D)`: the variance they carry,
    // `(c(f_ref, D) / (P_ref (1 + k)))² P_bias`, with `P_bias` at most `P_ref (1 + k)²` (the
    // reference's share of a bias error the LOS has narrowed is in the estimate, not the error).
    let carried_gain = ratio(&equivalent_covariance(f0, &excess, sa, ma), &p_ref_scaled);
    let p_bias = bias_diagonal(p).inf(&p_ref_scaled.component_mul(&(gain + one)));
    let rest_d = (equivalent_variance(&excess, sa, ma)
        - carried_gain
            .component_mul(&carried_gain)
            .component_mul(&p_bias))
    .map(|x| x.max(T::zero()));
    let w = c_b_n.component_mul(c_b_n) * rest_d;
    let (add_vel, charged) = charge_above(&w, &charge.charged_vel_m2_s2);
    next.charged_vel_m2_s2 = charged;
    (add_vel, add_bias)
}

/// `P ← T P Tᵀ` (column-major storage, `p[col][row]`, exactly symmetric), `T` the identity
/// but for the bias columns of the velocity and bias rows: `T[V, ∇] = a` (`C_b^n diag(g_v)`)
/// and `T[∇, ∇] = diag(scale)`. Symmetric bit for bit (each mirrored pair written from one
/// value) and PSD whatever `a` and `scale` (a congruence, as `Φ P Φᵀ`). Outside the six
/// rows each column needs only its own three bias elements, `(T P)[V, c] = P[V, c] + a P[∇, c]`
/// and `(T P)[∇, c] = scale P[∇, c]`; the six rows' block from its old values. Cost: 11 × 12
/// + 3 × 27 multiply-adds, in a frame of its own.
#[inline(never)]
pub(super) fn transfer_from_bias<T: Real>(
    p: &mut [[T; STATES]; STATES],
    a: &Matrix3<T>,
    scale: &Vector3<T>,
) {
    let z = T::zero();
    let at = |p: &[[T; STATES]; STATES], r: usize, c: usize| {
        p.get(c).and_then(|col| col.get(r)).copied().unwrap_or(z)
    };
    let set = |p: &mut [[T; STATES]; STATES], r: usize, c: usize, x: T| {
        if let Some(y) = p.get_mut(c).and_then(|col| col.get_mut(r)) {
            *y = x;
        }
        if let Some(y) = p.get_mut(r).and_then(|col| col.get_mut(c)) {
            *y = x;
        }
    };
    // The six rows' block before the transfer: `P[∇, ∇]`, `P[V, ∇]`.
    let pbb = Matrix3::from_fn(|m, n| at(p, ACC_BIAS + m, ACC_BIAS + n));
    let pvb = Matrix3::from_fn(|r, n| at(p, VEL + r, ACC_BIAS + n));
    for c in
        (0..STATES).filter(|c| !(VEL..VEL + 3).contains(c) && !(ACC_BIAS..ACC_BIAS + 3).contains(c))
    {
        let b = Vector3::from_fn(|m, _| at(p, ACC_BIAS + m, c));
        let v = Vector3::from_fn(|r, _| at(p, VEL + r, c)) + a * b;
        let sb = b.component_mul(scale);
        for i in 0..3 {
            set(p, VEL + i, c, v.get(i).copied().unwrap_or(z));
            set(p, ACC_BIAS + i, c, sb.get(i).copied().unwrap_or(z));
        }
    }
    // `X = P[V, ∇] + a P[∇, ∇]`: `P'[V, ∇] = X diag(scale)`, `P'[V, V] = P[V, V] + a P[∇, V]
    // + X aᵀ` (upper triangle, mirrored), `P'[∇, ∇] = diag(scale) P[∇, ∇] diag(scale)` (one
    // product `s_m s_n` per pair).
    let x = pvb + a * pbb;
    let y = a * pvb.transpose() + x * a.transpose();
    for r in 0..3 {
        let s_r = scale.get(r).copied().unwrap_or(z);
        for n in 0..3 {
            let s_n = scale.get(n).copied().unwrap_or(z);
            let xv = x.get((r, n)).copied().unwrap_or(z);
            set(p, VEL + r, ACC_BIAS + n, xv * s_n);
            if n >= r {
                let bb = pbb.get((r, n)).copied().unwrap_or(z);
                set(p, ACC_BIAS + r, ACC_BIAS + n, bb * (s_r * s_n));
                let vv = at(p, VEL + r, VEL + n) + y.get((r, n)).copied().unwrap_or(z);
                set(p, VEL + r, VEL + n, vv);
            }
        }
    }
}

#[cfg(test)]
#[path = "accel_departure_tests.rs"]
mod tests;

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

/// Rows of the congruence `T = I + E` (velocity, then accelerometer bias).
const ROWS: [usize; 6] = [VEL, VEL + 1, VEL + 2, ACC_BIAS, ACC_BIAS + 1, ACC_BIAS + 2];

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
    let mut e = SMatrix::<T, 6, 3>::zeros();
    for i in 0..3 {
        let g = g_v.get(i).copied().unwrap_or(T::zero());
        for r in 0..3 {
            if let (Some(x), Some(c)) = (e.get_mut((r, i)), c_b_n.get((r, i))) {
                *x = *c * g;
            }
        }
        if let (Some(x), Some(s)) = (e.get_mut((3 + i, i)), scale.get(i)) {
            *x = *s - T::one();
        }
    }
    transfer_from_bias(p, &e);
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

/// `P ← T P Tᵀ`, `T = I + E` with `E` zero but for the bias columns of the velocity and bias
/// rows (`e`: rows velocity then bias, columns the three bias states): symmetric by
/// construction (each pair of mirrored elements gets one sum) and PSD whatever `E` (a
/// congruence, as `Φ P Φᵀ`). Column by column outside the six rows (each needs only its own
/// three bias elements), then the rows × rows block from its bias columns kept before: no
/// copy of P's rows on the stack. Cost: 6 × 3 × 11 + 6 × 6 × 3 + 6 × 3 × 3 + 6 × 6 × 3
/// multiply-adds.
fn transfer_from_bias<T: Real>(p: &mut SMatrix<T, STATES, STATES>, e: &SMatrix<T, 6, 3>) {
    let at = |p: &SMatrix<T, STATES, STATES>, r: usize, c: usize| {
        p.get((r, c)).copied().unwrap_or(T::zero())
    };
    // The six rows' bias columns before the transfer (`P` symmetric: also the bias rows'
    // elements in the six columns).
    let pr = SMatrix::<T, 6, 3>::from_fn(|j, m| {
        ROWS.get(j).map_or(T::zero(), |&r| at(p, r, ACC_BIAS + m))
    });
    for c in (0..STATES).filter(|c| !ROWS.contains(c)) {
        let u = e * Vector3::from_fn(|m, _| at(p, ACC_BIAS + m, c)); // (E P)'s column c
        for (j, &r) in ROWS.iter().enumerate() {
            let add = u.get(j).copied().unwrap_or(T::zero());
            if let Some(x) = p.get_mut((r, c)) {
                *x += add;
            }
            if let Some(x) = p.get_mut((c, r)) {
                *x += add;
            }
        }
    }
    let pbb = Matrix3::from_fn(|i, m| pr.get((3 + i, m)).copied().unwrap_or(T::zero()));
    let u = e * pr.transpose(); // E P on the rows × rows block
    let w = e * pbb * e.transpose(); // E P Eᵀ there
    let u_at = |j: usize, l: usize| u.get((j, l)).copied().unwrap_or(T::zero());
    for (j, &r) in ROWS.iter().enumerate() {
        for (l, &s) in ROWS.iter().enumerate().skip(j) {
            let add = u_at(j, l) + u_at(l, j) + w.get((j, l)).copied().unwrap_or(T::zero());
            if let Some(x) = p.get_mut((r, s)) {
                *x += add;
            }
            if l != j {
                if let Some(x) = p.get_mut((s, r)) {
                    *x += add;
                }
            }
        }
    }
}

#[cfg(test)]
#[path = "accel_departure_tests.rs"]
mod tests;

//! The accelerometer part of the flight configuration's charge: the departure of the specific
//! force from the reference, split into its sustained part (to the bias states) and its
//! transient rest (to the velocity), each **correlated with the reference's share** of the
//! bias states' error through the one set of S and M (module [`super`] doc, "The departure's
//! correlation with the reference").

use super::{
    charge_above, equivalent_covariance, equivalent_variance, EquivalentBiasCharge,
    InstrumentErrors, SUSTAINED_TIME_CONSTANT_S,
};
#[cfg(test)]
use crate::seeker_ins::error_model::VEL;
use crate::seeker_ins::error_model::{ACC_BIAS, STATES};
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

/// One covariance step's accelerometer departure, planned before the step from the charge
/// alone (P is not read): the transfer `T = I + E`, `E` zero but for the bias columns,
/// `E[V, ∇] = C_b^n diag(gain_v)` and `E[∇, ∇] = diag(scale − 1)`, with what the part after
/// the step needs. The transfer is applied as `P ← S (Φ' P Φ'ᵀ + Q_d) S`: `Φ' = Φ + E[V, ∇]`
/// (the covariance kernel's `G[V, ∇] = C_b^n diag(Δt + gain_v)`, [`Self::dt_acc_s`]) and
/// `S = I + E[∇, ∇]` ([`apply_scale`]). That is `T (Φ P Φᵀ + Q_d) Tᵀ` with `T = S (I + E_v +
/// H E_v)`: Φ's and Q_d's bias rows are those of the identity and zero (random-constant
/// biases), so `E Φ = E` and `E Q_d = 0`, and the step's second-order couplings H
/// (position ← velocity, `½ G[P, V]`) give the transfer its position effect over the step,
/// `½ Δt E_v` (test `the_folded_velocity_transfer_equals_the_congruence_after_the_step`).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(in crate::seeker_ins) struct Departure<T> {
    /// The transient's velocity gain per body axis, s: the velocity error gains
    /// `C_b^n diag(gain_v) ∇`.
    pub(super) gain_v: Vector3<T>,
    /// The bias error's scale per body axis (1: unchanged).
    pub(super) scale: Vector3<T>,
    /// The bias variance not explained, per body axis, (m/s²)², added after the step.
    add_bias: Vector3<T>,
    /// The sustained gain `k` now.
    gain: Vector3<T>,
    /// `Σ (f − f_ref − f̄) Δt` so far, body axes, m/s.
    excess: Vector3<T>,
}

impl<T: Real> Departure<T> {
    /// The kernel's step of `G[V, ∇]`'s columns, s: `dt_s + gain_v`.
    pub(in crate::seeker_ins) fn dt_acc_s(&self, dt_s: T) -> [T; 3] {
        [
            dt_s + self.gain_v.x,
            dt_s + self.gain_v.y,
            dt_s + self.gain_v.z,
        ]
    }
}

/// Plans the departure of one covariance step (reference `f0`, mean body specific force
/// `f_b`, both m/s², over `dt_s`), the charge's new memory written to `next` (module
/// [`super`] doc).
pub(super) fn plan_departure<T: Real>(
    charge: &EquivalentBiasCharge<T>,
    next: &mut EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    f0: &Vector3<T>,
    f_b: &Vector3<T>,
    dt_s: T,
) -> Departure<T> {
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
    let gain = ratio(&c_sus, &p_ref);
    next.sustained_gain = gain;
    let scale = (gain + one).component_div(&(charge.sustained_gain + one));
    let scale_sq = (gain + one).component_mul(&(gain + one));
    let rest = (equivalent_variance(&sustained, sa, ma) - gain.component_mul(&c_sus))
        .map(|x| x.max(T::zero()))
        .component_div(&scale_sq);
    let (add_rest, charged) = charge_above(&rest, &charge.charged_bias_m2_s4);
    next.charged_bias_m2_s4 = charged;
    // Transient rest: `ΔD = (f − f_ref − f̄) Δt`, its velocity error `C (S + M) ΔD` regressed
    // on the (scaled) bias error, gain `c(f_ref, ΔD) / (P_ref (1 + k))` per body axis.
    let d_dv = (departure - sustained) * dt_s;
    let excess = charge.excess_dv_b_m_s + d_dv;
    next.excess_dv_b_m_s = excess;
    let gain_v = ratio(
        &equivalent_covariance(f0, &d_dv, sa, ma),
        &p_ref.component_mul(&(gain + one)),
    );
    Departure {
        gain_v,
        scale,
        add_bias: add_rest.component_mul(&scale_sq),
        gain,
        excess,
    }
}

/// `P ← S P S`, `S` the identity but for the bias states' `scale` (the bias part of the
/// departure's transfer, [`Departure`]): their rows and columns scaled, symmetric bit for bit
/// (each entry once, by the same product in both triangles) and PSD (a congruence).
pub(super) fn apply_scale<T: Real>(p: &mut SMatrix<T, STATES, STATES>, scale: &Vector3<T>) {
    let s = [scale.x, scale.y, scale.z];
    for (c, col) in p.data.0.iter_mut().enumerate() {
        match c.checked_sub(ACC_BIAS).and_then(|j| s.get(j)).copied() {
            // Column c outside the bias states: its three bias rows.
            None => {
                for (x, a) in col.iter_mut().skip(ACC_BIAS).zip(s) {
                    *x *= a;
                }
            }
            // A bias column: the other rows by its scale, the bias block's entries by both
            // (one product `s_r s_c`, the same bits in both triangles).
            Some(s_c) => {
                let (head, tail) = col.split_at_mut(ACC_BIAS);
                for x in head.iter_mut().chain(tail.iter_mut().skip(3)) {
                    *x *= s_c;
                }
                for (x, a) in tail.iter_mut().zip(s) {
                    *x *= a * s_c;
                }
            }
        }
    }
}

/// After the step (P through the transfer): the variances the transfers do not explain,
/// `(velocity per NED axis, bias per body axis)`, to add as a diagonal; the velocity charge's
/// memory written to `next` (attitude `c_b_n`, reference `f0`, m/s²).
pub(super) fn finish_departure<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    charge: &EquivalentBiasCharge<T>,
    next: &mut EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    c_b_n: &Matrix3<T>,
    f0: &Vector3<T>,
    dep: &Departure<T>,
) -> (Vector3<T>, Vector3<T>) {
    let (sa, ma) = (errors.accel_scale_factor, errors.accel_misalignment_rad);
    let one = Vector3::repeat(T::one());
    let p_ref_scaled = charge.reference_var_m2_s4.component_mul(&(dep.gain + one));
    // What the transfers do not explain of `v(D)`: the variance they carry,
    // `(c(f_ref, D) / (P_ref (1 + k)))² P_bias`, with `P_bias` at most `P_ref (1 + k)²` (the
    // reference's share of a bias error the LOS has narrowed is in the estimate, not the error).
    let carried_gain = ratio(
        &equivalent_covariance(f0, &dep.excess, sa, ma),
        &p_ref_scaled,
    );
    let p_bias = bias_diagonal(p).inf(&p_ref_scaled.component_mul(&(dep.gain + one)));
    let rest_d = (equivalent_variance(&dep.excess, sa, ma)
        - carried_gain
            .component_mul(&carried_gain)
            .component_mul(&p_bias))
    .map(|x| x.max(T::zero()));
    let w = c_b_n.component_mul(c_b_n) * rest_d;
    let (add_vel, charged) = charge_above(&w, &charge.charged_vel_m2_s2);
    next.charged_vel_m2_s2 = charged;
    (add_vel, dep.add_bias)
}

/// `P ← (I + E_v) P (I + E_v)ᵀ`, `E_v = C_b^n diag(gain_v)` from the bias columns into the
/// velocity rows, written out on P (the tests' reference for the folded form, which the
/// covariance kernel applies in Φ).
#[cfg(test)]
pub(super) fn transfer_to_velocity<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    c_b_n: &Matrix3<T>,
    gain_v: &Vector3<T>,
) {
    let mut t = SMatrix::<T, STATES, STATES>::identity();
    for r in 0..3 {
        for m in 0..3 {
            t[(VEL + r, ACC_BIAS + m)] = c_b_n[(r, m)] * gain_v[m];
        }
    }
    let next = t * *p * t.transpose();
    *p = (next + next.transpose()) * T::lit(0.5);
}

#[cfg(test)]
#[path = "accel_departure_tests.rs"]
mod tests;

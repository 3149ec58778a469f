//! Tests of the accelerometer departure's charge correlated with the reference's share
//! (module `accel_departure`).

use super::super::{
    add_instrument_noise, charge_above, charge_ned, equivalent_covariance, equivalent_variance,
    set_reference, EquivalentBiasCharge, InstrumentErrors, SUSTAINED_TIME_CONSTANT_S,
};
use super::transfer_from_bias;
use crate::math::kalman::is_psd;
use crate::seeker_ins::error_model::{ACC_BIAS, ATT, STATES, VEL};
use crate::Real;
use nalgebra::{Matrix3, SMatrix, Vector3};

type P<T> = SMatrix<T, STATES, STATES>;

/// Standard gravity, m/s².
const G_M_S2: f64 = 9.806_65;
/// The tests' covariance step, s.
const DT_S: f64 = 0.1;
/// The hand-over's accelerometer-bias σ (b alone), m/s² (100 µg).
const BIAS_SIGMA_M_S2: f64 = 100e-6 * G_M_S2;
/// Attitude σ, rad, and velocity σ, m/s, at the hand-over.
const ATT_SIGMA_RAD: f64 = 2e-4;
const VEL_SIGMA_M_S: f64 = 0.05;
/// Correlation of the north tilt with the y bias and of the east tilt with the x bias (the
/// alignment's `g φ ≈ −∇`).
const TILT_BIAS_CORRELATION: f64 = -0.6;

/// The flight configuration's accelerometer σ (200 ppm, 10″), gyro errors off.
fn errors<T: Real>() -> InstrumentErrors<T> {
    InstrumentErrors {
        accel_scale_factor: T::lit(200e-6),
        accel_misalignment_rad: T::lit(10.0 / 206_264.8),
        gyro_scale_factor: T::zero(),
        gyro_misalignment_rad: T::zero(),
    }
}

/// A hand-over's P (tilt and level bias correlated) with the reference set at level carry.
fn handed_over<T: Real>() -> (P<T>, EquivalentBiasCharge<T>) {
    let mut p = P::<T>::identity() * T::lit(1e-6);
    for i in 0..3 {
        p[(VEL + i, VEL + i)] = T::lit(VEL_SIGMA_M_S * VEL_SIGMA_M_S);
        p[(ATT + i, ATT + i)] = T::lit(ATT_SIGMA_RAD * ATT_SIGMA_RAD);
        p[(ACC_BIAS + i, ACC_BIAS + i)] = T::lit(BIAS_SIGMA_M_S2 * BIAS_SIGMA_M_S2);
    }
    let c = T::lit(TILT_BIAS_CORRELATION * ATT_SIGMA_RAD * BIAS_SIGMA_M_S2);
    for (a, b) in [(ATT, ACC_BIAS + 1), (ATT + 1, ACC_BIAS)] {
        p[(a, b)] = c;
        p[(b, a)] = c;
    }
    let f_level = Vector3::new(T::zero(), T::zero(), T::lit(-G_M_S2));
    let ch = set_reference(&mut p, &Default::default(), &errors(), &f_level).unwrap();
    (p, ch)
}

/// Flies `seconds` at body specific force `f` (m/s²), level, no rotation.
fn fly<T: Real>(
    p: &mut P<T>,
    ch: EquivalentBiasCharge<T>,
    f: &Vector3<T>,
    seconds: f64,
) -> EquivalentBiasCharge<T> {
    let (i3, e) = (Matrix3::identity(), errors());
    let mut ch = ch;
    for _ in 0..(seconds / DT_S).round() as usize {
        ch = add_instrument_noise(p, &ch, &e, &i3, f, &Vector3::zeros(), T::lit(DT_S));
    }
    ch
}

/// P symmetric bit for bit and PSD after scaling to unit diagonal (the bias block is 10⁻¹⁰
/// of the velocity's: a trace-relative test would not see it).
fn assert_psd<T: Real>(p: &P<T>, what: &str) {
    assert!(*p == p.transpose(), "{what}: not symmetric");
    let d = SMatrix::<f64, STATES, 1>::from_fn(|i, _| p[(i, i)].to_f64().sqrt());
    assert!(d.iter().all(|x| *x > 0.0), "{what}: diagonal {d:?}");
    let r = P::<f64>::from_fn(|i, j| p[(i, j)].to_f64() / (d[i] * d[j]));
    assert!(is_psd(&r, 1e-9), "{what}: not PSD");
}

/// A turn's load factor held (2.24 g on the lift axis for 10 τ) from a level reference, the
/// bias not observed meanwhile: each bias variance becomes the total equivalent bias's,
/// `P_ref + v(f_ref + f̄) − v(f_ref)` (the cross term `2 c(f_ref, f̄)` included, not
/// `P_ref + v(f̄)`), and the tilt–bias covariance is scaled with the bias error, `1 + k`;
/// back at the reference the share is gone again.
#[test]
fn a_sustained_turn_charges_the_total_equivalent_bias_and_keeps_its_correlations() {
    let e = errors::<f64>();
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let (mut p, ch) = handed_over::<f64>();
    let (p0, f0) = (p, ch.reference_f_b_m_s2.unwrap());
    let f_turn = Vector3::new(0.0, 0.0, -2.24 * G_M_S2);
    let ch = fly(&mut p, ch, &f_turn, 10.0 * SUSTAINED_TIME_CONSTANT_S);
    let f_bar = f_turn - f0;
    let want = equivalent_variance(&f_turn, sa, ma) - equivalent_variance(&f0, sa, ma);
    let independent = equivalent_variance(&f_bar, sa, ma);
    let gain = equivalent_covariance(&f0, &f_bar, sa, ma).component_div(&ch.reference_var_m2_s4);
    for i in 0..3 {
        let (b, b0) = (ACC_BIAS + i, p0[(ACC_BIAS + i, ACC_BIAS + i)]);
        let added = p[(b, b)] - b0;
        assert!(
            (added - want[i]).abs() <= 1e-3 * want[i],
            "axis {i}: {added} vs {}",
            want[i]
        );
        assert!(added > 1.5 * independent[i], "axis {i}: the cross term");
        for a in 0..3 {
            let (c, c0) = (p[(ATT + a, b)], p0[(ATT + a, b)]);
            assert!((c - c0 * (1.0 + gain[i])).abs() <= 1e-3 * c0.abs() + 1e-30);
        }
    }
    assert_psd(&p, "turn");
    // Back to level for 10 τ: the share returns with the mean, the bias variance to `P_ref`
    // and the independent rest (its largest over `(1 + k)²`).
    let f_level = Vector3::new(0.0, 0.0, -G_M_S2);
    let ch = fly(&mut p, ch, &f_level, 10.0 * SUSTAINED_TIME_CONSTANT_S);
    for i in 0..3 {
        let b = ACC_BIAS + i;
        let (added, rest) = (p[(b, b)] - p0[(b, b)], ch.charged_bias_m2_s4[i]);
        assert!(
            (added - rest).abs() <= 1e-3 * p0[(b, b)],
            "axis {i}: {added} vs {rest}"
        );
        assert!(
            rest < independent[i],
            "axis {i}: less than the independent charge left"
        );
    }
    assert_psd(&p, "after the turn");
}

/// A 1 s drop to 0 g from the reference: its velocity error `(S + M)(−f_ref) Δt'` is
/// anti-correlated with the reference's share of the bias, `cov = c(f_ref, ΔD)`, and its
/// variance is still `v(ΔD)` in all (transfer and rest) while the bias is unobserved.
#[test]
fn a_drop_is_anti_correlated_with_the_reference_share() {
    let e = errors::<f64>();
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let (mut p, ch) = handed_over::<f64>();
    let p0 = p;
    let f0 = ch.reference_f_b_m_s2.unwrap();
    let ch = fly(&mut p, ch, &Vector3::zeros(), 1.0);
    let d = ch.excess_dv_b_m_s;
    let cov = equivalent_covariance(&f0, &d, sa, ma);
    let var = equivalent_variance(&d, sa, ma);
    for i in 0..3 {
        let (v, b) = (VEL + i, ACC_BIAS + i);
        assert!(cov[i] < 0.0);
        assert!(
            (p[(v, b)] - cov[i]).abs() <= 0.02 * cov[i].abs(),
            "axis {i}"
        );
        let added = p[(v, v)] - p0[(v, v)];
        assert!((added - var[i]).abs() <= 0.02 * var[i], "axis {i}");
    }
    assert_psd(&p, "drop");
}

/// A push-over (the lift axis's force held opposite the reference, −0.5 g, for 3 τ, then
/// back to level for 5 τ) never removes bias variance and keeps P symmetric PSD, f32 and
/// f64.
fn push_over_stays_psd<T: Real>() {
    let (mut p, ch) = handed_over::<T>();
    let p0 = p;
    let f_push = Vector3::new(T::zero(), T::zero(), T::lit(0.5 * G_M_S2));
    let ch = fly(&mut p, ch, &f_push, 3.0 * SUSTAINED_TIME_CONSTANT_S);
    assert_psd(&p, "push-over");
    let f_level = Vector3::new(T::zero(), T::zero(), T::lit(-G_M_S2));
    let _ = fly(&mut p, ch, &f_level, 5.0 * SUSTAINED_TIME_CONSTANT_S);
    assert_psd(&p, "after the push-over");
    for i in 0..3 {
        let b = ACC_BIAS + i;
        assert!(p[(b, b)] >= p0[(b, b)], "bias axis {i}");
    }
}

#[test]
fn a_push_over_keeps_p_psd_f32_and_f64() {
    push_over_stays_psd::<f32>();
    push_over_stays_psd::<f64>();
}

/// A full symmetric PSD P with every element non-zero (`L Lᵀ`, `L` lower triangular from a
/// fixed sequence), scaled per state as a filter's.
fn full_p() -> P<f64> {
    let mut x = 0.618_f64;
    let l = P::<f64>::from_fn(|i, j| {
        x = (x * 997.0 + 0.123).fract();
        if j <= i {
            x - 0.3
        } else {
            0.0
        }
    });
    let d = SMatrix::<f64, STATES, 1>::from_fn(|i, _| if i >= ACC_BIAS { 1e-3 } else { 1.0 });
    let p = l * l.transpose();
    P::<f64>::from_fn(|i, j| p[(i, j)] * d[i] * d[j])
}

/// The written-out transfer equals the congruence `T P Tᵀ` on the full P (dense product, T the
/// identity but for `T[V, ∇] = a`, `T[∇, ∇] = diag(scale)`) and is symmetric bit for bit.
#[test]
fn the_transfer_is_the_congruence_on_the_full_p() {
    let p0 = full_p();
    let a = Matrix3::new(0.3, -0.2, 0.05, 0.1, 0.4, -0.3, -0.25, 0.15, 0.2);
    let scale = Vector3::new(1.1, 0.95, 1.3);
    let mut t = P::<f64>::identity();
    for r in 0..3 {
        for m in 0..3 {
            t[(VEL + r, ACC_BIAS + m)] = a[(r, m)];
        }
        t[(ACC_BIAS + r, ACC_BIAS + r)] = scale[r];
    }
    let want = t * p0 * t.transpose();
    let mut p = p0;
    transfer_from_bias(&mut p.data.0, &a, &scale);
    assert!(p == p.transpose(), "not symmetric");
    for i in 0..STATES {
        for j in 0..STATES {
            let tol = 1e-13 * (want[(i, i)] * want[(j, j)]).sqrt();
            assert!(
                (p[(i, j)] - want[(i, j)]).abs() <= tol,
                "({i}, {j}): {} vs {}",
                p[(i, j)],
                want[(i, j)]
            );
        }
    }
    assert_psd(&p, "transfer");
    // The identity transfer leaves P bit for bit.
    let mut q = p0;
    transfer_from_bias(&mut q.data.0, &Matrix3::zeros(), &Vector3::repeat(1.0));
    assert_eq!(q, p0);
}

/// With no share to regress on (a reference of zero force: `c(f_ref, ·) = 0`, so `k = 0` and
/// no velocity transfer) the charge is the independent one bit for bit: the sustained mean's
/// `v(f̄)` to the bias states and the transient's `C_b^n diag(v(D)) C_n^b` to the velocity,
/// each the part of its largest so far not added before.
#[test]
fn zero_gain_is_the_independent_charge() {
    let e = errors::<f64>();
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let (mut p, _) = handed_over::<f64>();
    let ch = set_reference(&mut p, &Default::default(), &e, &Vector3::zeros()).unwrap();
    let c_b_n = Matrix3::new(0.8, -0.6, 0.0, 0.6, 0.8, 0.0, 0.0, 0.0, 1.0);
    let (mut q, mut ch, mut want) = (p, ch, ch);
    let tau = SUSTAINED_TIME_CONSTANT_S;
    let forces = [(-9.8, 30), (0.0, 10), (-22.0, 300), (-9.8, 100), (4.9, 50)];
    for (fz, steps) in forces {
        let f = Vector3::new(0.5, -0.2, fz);
        for _ in 0..steps {
            let zero = Vector3::zeros();
            ch = add_instrument_noise(&mut p, &ch, &e, &c_b_n, &f, &zero, DT_S);
            assert_eq!(ch.sustained_gain, Vector3::zeros());
            // The independent charge, written out.
            let alpha = DT_S / (tau + DT_S);
            want.sustained_f_b_m_s2 += (f - want.sustained_f_b_m_s2) * alpha;
            let w = equivalent_variance(&want.sustained_f_b_m_s2, sa, ma);
            let (add_bias, charged) = charge_above(&w, &want.charged_bias_m2_s4);
            want.charged_bias_m2_s4 = charged;
            want.excess_dv_b_m_s += (f - want.sustained_f_b_m_s2) * DT_S;
            let d = want.excess_dv_b_m_s;
            let (add_vel, charged) = charge_ned(&c_b_n, &d, sa, ma, &want.charged_vel_m2_s2);
            want.charged_vel_m2_s2 = charged;
            for i in 0..3 {
                q[(ACC_BIAS + i, ACC_BIAS + i)] += add_bias[i];
                q[(VEL + i, VEL + i)] += add_vel[i];
            }
            assert_eq!(p, q);
        }
    }
    assert_psd(&p, "zero gain");
}

//! Tests of the accelerometer departure's charge correlated with the reference's share
//! (module `accel_departure`).

use super::super::{
    add_instrument_noise_explicit, equivalent_covariance, equivalent_variance, set_reference,
    EquivalentBiasCharge, InstrumentErrors, SUSTAINED_TIME_CONSTANT_S,
};
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
        ch = add_instrument_noise_explicit(p, &ch, &e, &i3, f, &Vector3::zeros(), T::lit(DT_S));
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

//! Tests of the flight configuration's instrument-error charges (module `flight_noise`).

use super::*;

fn errors() -> InstrumentErrors<f64> {
    InstrumentErrors {
        accel_scale_factor: 200e-6,
        accel_misalignment_rad: 10.0 / 206_264.8,
        gyro_scale_factor: 20e-6,
        gyro_misalignment_rad: 10.0 / 206_264.8,
    }
}

/// `v(u)` against the variance of `Σ_j m_ij u_j` written out element by element (σ_S on
/// the diagonal, σ_M off it).
#[test]
fn equivalent_variance_is_the_variance_of_the_error_sum() {
    let e = errors();
    let u = Vector3::new(2.0, -1.0, -9.8);
    let v = equivalent_variance(&u, e.accel_scale_factor, e.accel_misalignment_rad);
    for i in 0..3 {
        let mut want = 0.0;
        for j in 0..3 {
            let s = if i == j {
                e.accel_scale_factor
            } else {
                e.accel_misalignment_rad
            };
            want += s * s * u[j] * u[j];
        }
        assert!(
            (v[i] - want).abs() <= 1e-15 * want,
            "axis {i}: {} vs {want}",
            v[i]
        );
    }
    // Level flight: 200 ppm × g ≈ 196 µg on z, 10″ × g ≈ 48 µg on x and y.
    let lv = equivalent_variance(
        &Vector3::new(0.0, 0.0, -9.806_65),
        e.accel_scale_factor,
        e.accel_misalignment_rad,
    );
    let ug = 9.806_65e-6;
    assert!((lv.z.sqrt() / ug - 200.0).abs() < 0.1);
    assert!((lv.x.sqrt() / ug - 48.5).abs() < 0.1);
}

type P = SMatrix<f64, STATES, STATES>;

/// The variances of the three states from `at` (P's diagonal).
fn diag(p: &P, at: usize) -> Vector3<f64> {
    Vector3::new(p[(at, at)], p[(at + 1, at + 1)], p[(at + 2, at + 2)])
}

/// The level specific force of the charge tests (m/s², body).
const F_LEVEL_M_S2: [f64; 3] = [0.0, 0.0, -9.8];
/// The charge tests' step (s).
const DT_S: f64 = 0.1;

/// One charge step at specific force `f` (m/s², body), level attitude, no rotation.
fn charge(
    p: &mut P,
    ch: &EquivalentBiasCharge<f64>,
    e: &InstrumentErrors<f64>,
    f: &Vector3<f64>,
) -> EquivalentBiasCharge<f64> {
    let i3 = Matrix3::identity();
    add_instrument_noise(p, ch, e, &i3, f, &Vector3::zeros(), DT_S)
}

/// A transient (1 s at 0 g, then level for 2 s) is charged to the velocity as the error it
/// makes, `v(Σ (f − f_ref) Δt)`, and only its running mean's small share to the bias.
fn check_transient(
    p: &mut P,
    ch: EquivalentBiasCharge<f64>,
    e: &InstrumentErrors<f64>,
) -> EquivalentBiasCharge<f64> {
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let tau = SUSTAINED_TIME_CONSTANT_S;
    let f_level = Vector3::from(F_LEVEL_M_S2);
    let (bias0, vel0) = (diag(p, ACC_BIAS), diag(p, VEL));
    let mut ch = ch;
    for k in 0..30 {
        let f = if k < 10 { Vector3::zeros() } else { f_level };
        ch = charge(p, &ch, e, &f);
    }
    let drop = equivalent_variance(&(-f_level), sa, ma); // v(Σ (f − f_ref) Δt), 1 s
    let (bias_add, vel_add) = (diag(p, ACC_BIAS) - bias0, diag(p, VEL) - vel0);
    for i in 0..3 {
        assert!(
            bias_add[i] <= drop[i] * (1.0 / tau).powi(2) * 1.0001,
            "transient's bias share, axis {i}: {} vs {}",
            bias_add[i],
            drop[i]
        );
        // The part correlated with the reference's share follows `D`, which the running
        // mean's share of the drop lowers by ≈ 2 s / τ in the 2 s after it.
        assert!(
            (vel_add[i] - drop[i]).abs() <= 0.2 * drop[i],
            "transient's velocity charge, axis {i}: {} vs {}",
            vel_add[i],
            drop[i]
        );
    }
    ch
}

/// A sustained departure (x specific force held 2 m/s² above the reference for 10 τ) is
/// charged to the bias as `v(Δf)` (counted from `bias0`, the bias variances before the
/// transient) and to the velocity only for the lag of the mean, `v(Δf τ)` at most, not
/// growing with the time it is held.
fn check_sustained(
    p: &mut P,
    ch: EquivalentBiasCharge<f64>,
    e: &InstrumentErrors<f64>,
    bias0: &Vector3<f64>,
) -> EquivalentBiasCharge<f64> {
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let tau = SUSTAINED_TIME_CONSTANT_S;
    let f_level = Vector3::from(F_LEVEL_M_S2);
    let vel1 = diag(p, VEL);
    let step = Vector3::new(2.0, 0.0, 0.0);
    let mut vel_after_7tau = Vector3::zeros();
    let steps = (10.0 * tau / DT_S) as usize;
    let mut ch = ch;
    for k in 0..steps {
        ch = charge(p, &ch, e, &(f_level + step));
        if k + 1 == steps * 7 / 10 {
            vel_after_7tau = diag(p, VEL);
        }
    }
    // The bias charge is the largest `v(mean)` so far: counted from before the drop.
    let (bias_add, vel_add) = (diag(p, ACC_BIAS) - bias0, diag(p, VEL) - vel1);
    let want_bias = equivalent_variance(&step, sa, ma);
    let lag = equivalent_variance(&(step * tau), sa, ma);
    for i in 0..3 {
        assert!(
            (bias_add[i] - want_bias[i]).abs() <= 0.01 * want_bias[i],
            "sustained's bias charge, axis {i}: {} vs {}",
            bias_add[i],
            want_bias[i]
        );
        assert!(
            vel_add[i] <= lag[i] * 1.0001,
            "sustained's velocity charge, axis {i}: {} vs at most {}",
            vel_add[i],
            lag[i]
        );
        assert!(
            diag(p, VEL)[i] - vel_after_7tau[i] <= 0.01 * lag[i],
            "the velocity charge stops growing, axis {i}"
        );
    }
    ch
}

/// The first step without a reference adds the whole `v(f)` to the bias states and takes
/// `f` as the reference. A transient (a 1 s drop to 0 g) is charged to the velocity as the
/// error it makes, `v(Σ (f − f_ref) Δt)`, and only its running mean's small share (the
/// drop's duration over `τ`) to the bias; a sustained departure (x specific force held at
/// 2 m/s² for 10 τ) is charged to the bias as `v(Δf)` and to the velocity only for the
/// lag of the mean, `v(Δf τ)` at most, not growing with the time it is held; a return to
/// the reference charges nothing more; zero σ adds nothing.
#[test]
fn charge_splits_sustained_from_transient_and_zero_sigma_is_the_paper_filter() {
    let e = errors();
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let tau = SUSTAINED_TIME_CONSTANT_S;
    let mut p = P::identity() * 1e-8;
    let p_start = p;
    let f_level = Vector3::from(F_LEVEL_M_S2);
    let c = charge(&mut p, &Default::default(), &e, &f_level);
    let v0 = equivalent_variance(&f_level, sa, ma);
    assert!((p[(ACC_BIAS + 2, ACC_BIAS + 2)] - 1e-8 - v0.z).abs() < 1e-20);
    assert_eq!(c.reference_f_b_m_s2, Some(f_level));
    let bias0 = diag(&p, ACC_BIAS);
    let ch = check_transient(&mut p, c, &e);
    let mut ch = check_sustained(&mut p, ch, &e, &bias0);
    // Back to level (the mean returns within a few τ): nothing more once it has but the
    // correlated transfer following the mean's last decay (below 10⁻⁷ of any element).
    let steps = (10.0 * tau / DT_S) as usize;
    for _ in 0..steps {
        ch = charge(&mut p, &ch, &e, &f_level);
    }
    let before = p;
    let _ = charge(&mut p, &ch, &e, &f_level);
    for (a, b) in p.iter().zip(before.iter()) {
        assert!((a - b).abs() <= 1e-7 * b.abs(), "{a} vs {b}");
    }
    // Zero σ: P untouched, charge unchanged.
    let mut q = p_start;
    let none = InstrumentErrors::<f64>::default();
    let c0 = charge(&mut q, &Default::default(), &none, &f_level);
    assert_eq!(q, p_start);
    assert_eq!(c0, EquivalentBiasCharge::default());
}

/// A reference set before the first step is the bias states' (their variance gains
/// `v(f_ref)`, the first step adds nothing to them) and a specific force away from it is
/// the velocity's charge from the first step on; a second reference, or a non-finite one,
/// is refused with P unchanged.
#[test]
fn a_set_reference_is_the_bias_states_and_only_once() {
    let e = errors();
    let mut p = SMatrix::<f64, STATES, STATES>::identity() * 1e-8;
    let f_carry = Vector3::new(0.3, -0.2, -9.9);
    let c = set_reference(&mut p, &Default::default(), &e, &f_carry).unwrap();
    let v = equivalent_variance(&f_carry, e.accel_scale_factor, e.accel_misalignment_rad);
    for i in 0..3 {
        assert!((p[(ACC_BIAS + i, ACC_BIAS + i)] - 1e-8 - v[i]).abs() < 1e-20);
    }
    let before = p;
    assert!(set_reference(&mut p, &c, &e, &f_carry).is_none());
    assert!(set_reference(
        &mut p,
        &Default::default(),
        &e,
        &Vector3::new(f64::NAN, 0.0, 0.0)
    )
    .is_none());
    assert_eq!(p, before);
    // One step of free fall (f = 0) for 1 s: the running mean takes `α = 1 / (τ + 1)` of
    // the departure `−f_carry` (its variance to the bias), the velocity the rest.
    let i3 = Matrix3::identity();
    let alpha = 1.0 / (SUSTAINED_TIME_CONSTANT_S + 1.0);
    let c1 = add_instrument_noise(
        &mut p,
        &c,
        &e,
        &i3,
        &Vector3::zeros(),
        &Vector3::zeros(),
        1.0,
    );
    for i in 0..3 {
        let (b, b0) = (
            p[(ACC_BIAS + i, ACC_BIAS + i)],
            before[(ACC_BIAS + i, ACC_BIAS + i)],
        );
        let want_b = alpha * alpha * v[i];
        assert!((b - b0 - want_b).abs() < 1e-9 * want_b, "bias axis {i}");
        let want_v = (1.0 - alpha) * (1.0 - alpha) * v[i];
        assert!((p[(VEL + i, VEL + i)] - 1e-8 - want_v).abs() < 1e-9 * want_v);
    }
    assert!((c1.excess_dv_b_m_s + f_carry * (1.0 - alpha)).norm() < 1e-12);
    assert!((c1.sustained_f_b_m_s2 + f_carry * alpha).norm() < 1e-12);
}

/// Each σ outside [0, its maximum] or non-finite is refused naming its field, by the
/// filter's construction too; the flight configuration itself is accepted.
#[test]
fn instrument_errors_are_validated_by_field() {
    use crate::contract::Estimator;
    use crate::error::ConfigIssue;
    use crate::seeker_ins::{Landmark, Position, SeekerIns, SeekerInsConfig};
    let lm = Landmark::new(Position {
        lat_rad: 0.6461,
        lon_rad: 2.2266,
        alt_m: 0.0,
    })
    .unwrap();
    let flight = SeekerInsConfig::<f32>::flight(lm);
    assert!(SeekerIns::design(&flight).is_ok());
    assert!(!flight.instrument_errors.is_zero());
    assert!(SeekerInsConfig::<f32>::paper(lm)
        .instrument_errors
        .is_zero());
    type Set = fn(&mut InstrumentErrors<f32>, f32);
    let fields: [(&str, Set); 4] = [
        ("instrument_errors.accel_scale_factor", |e, v| {
            e.accel_scale_factor = v
        }),
        ("instrument_errors.accel_misalignment_rad", |e, v| {
            e.accel_misalignment_rad = v
        }),
        ("instrument_errors.gyro_scale_factor", |e, v| {
            e.gyro_scale_factor = v
        }),
        ("instrument_errors.gyro_misalignment_rad", |e, v| {
            e.gyro_misalignment_rad = v
        }),
    ];
    for (name, set) in fields {
        for (v, issue) in [
            (-1e-6, ConfigIssue::OutOfRange),
            (0.011, ConfigIssue::OutOfRange),
            (f32::NAN, ConfigIssue::NotFinite),
        ] {
            let mut cfg = flight;
            set(&mut cfg.instrument_errors, v);
            assert_eq!(
                SeekerIns::design(&cfg).err(),
                Some(NavError::InvalidConfig { field: name, issue }),
                "{name} = {v}"
            );
        }
    }
}

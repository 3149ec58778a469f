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

/// The first step without a reference adds the whole `v(f)` to the bias states and takes
/// `f` as the reference; later departures from it (a 1 s drop to 0 g, a 2 m/s² pull held
/// for minutes) add nothing to P's diagonal (they are the consider parameters', module
/// `consider`), nor does a return to the reference; zero σ adds nothing at all.
#[test]
fn departures_are_left_to_the_consider_parameters_and_zero_sigma_is_the_paper_filter() {
    let e = errors();
    let (sa, ma) = (e.accel_scale_factor, e.accel_misalignment_rad);
    let mut p = P::identity() * 1e-8;
    let p_start = p;
    let f_level = Vector3::from(F_LEVEL_M_S2);
    let mut ch = charge(&mut p, &Default::default(), &e, &f_level);
    let v0 = equivalent_variance(&f_level, sa, ma);
    assert!((p[(ACC_BIAS + 2, ACC_BIAS + 2)] - 1e-8 - v0.z).abs() < 1e-20);
    assert_eq!(ch.reference_f_b_m_s2, Some(f_level));
    let after_reference = p;
    let drop = Vector3::zeros();
    let pull = Vector3::new(2.0, 0.0, -9.8);
    for f in [drop; 10]
        .iter()
        .chain([pull; 3000].iter())
        .chain([f_level; 10].iter())
    {
        ch = charge(&mut p, &ch, &e, f);
    }
    assert_eq!(p, after_reference);
    assert_eq!(ch.reference_f_b_m_s2, Some(f_level));
    // Zero σ: P untouched, charge unchanged.
    let mut q = p_start;
    let none = InstrumentErrors::<f64>::default();
    let c0 = charge(&mut q, &Default::default(), &none, &f_level);
    assert_eq!(q, p_start);
    assert_eq!(c0, EquivalentBiasCharge::default());
}

/// A reference set before the first step is the bias states' (their variance gains
/// `v(f_ref)`); a second reference, or a non-finite one, is refused with P unchanged.
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

//! The loops running: convergence without noise, drop-outs and inertial coasting, refused
//! input that changes nothing, the gravity model.

use super::*;

/// Noise-free closed-loop run: truth climbs at constant rate with a constant accelerometer
/// bias; the estimate starts 20 m / 2 m/s off. Returns final errors (h, V, bias).
fn run_noise_free<T: Real>(aided: bool, t_end: f64) -> (f64, f64, f64) {
    let dt = 0.01;
    let g = GravityModel::at_latitude(LAT).unwrap();
    let bias = 0.0098; // 1 mg
    let (h0, vz) = (500.0, 5.0);
    let mut init0 = init::<T>(h0 + 20.0);
    init0.vz_up_m_s = T::lit(vz + 2.0);
    let mut cl = ClassicalLoop::<T>::new(&classical_config(10.0, 0.0), &init0).unwrap();
    let mut al = AidedLoop::<T>::new(&aided_config(), &init0).unwrap();
    let n = (t_end / dt) as usize;
    for k in 1..=n {
        let t = k as f64 * dt;
        let h = h0 + vz * t;
        let f = g.gravity_m_s2(h - 0.5 * vz * dt) + bias;
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: T::lit(f),
        };
        // baro with no lag (the classical loop here has C4 = 0; aided compensates 0.2 s of
        // lag, so give it a lagged reading h − 0.2 V, exact for a constant climb).
        let baro_c = (k % 4 == 0).then(|| BaroSample {
            time: ts(t),
            altitude_m: T::lit(h),
        });
        let baro_a = (k % 4 == 0).then(|| BaroSample {
            time: ts(t),
            altitude_m: T::lit(h - 0.2 * vz),
        });
        let vel = (k % 10 == 0).then(|| VelocitySample {
            time: ts(t),
            vz_up_m_s: T::lit(vz),
        });
        if aided {
            al.step(&imu, baro_a.as_ref(), vel.as_ref()).unwrap();
        } else {
            cl.step(&imu, baro_c.as_ref()).unwrap();
        }
    }
    let h = h0 + vz * t_end;
    if aided {
        (
            al.altitude_m().to_f64() - h,
            al.vz_up_m_s().to_f64() - vz,
            al.accel_bias_m_s2().to_f64() - bias,
        )
    } else {
        (
            cl.altitude_m().to_f64() - h,
            cl.vz_up_m_s().to_f64() - vz,
            cl.accel_bias_m_s2().to_f64() - bias,
        )
    }
}

#[test]
fn loops_converge_noise_free_f32_and_f64() {
    for aided in [false, true] {
        let (eh, ev, eb) = run_noise_free::<f64>(aided, 1000.0);
        assert!(
            eh.abs() < 0.05 && ev.abs() < 0.005 && eb.abs() < 1e-4,
            "{aided}: {eh} {ev} {eb}"
        );
        let (eh, ev, eb) = run_noise_free::<f32>(aided, 1000.0);
        assert!(
            eh.abs() < 0.2 && ev.abs() < 0.02 && eb.abs() < 5e-4,
            "{aided}: {eh} {ev} {eb}"
        );
    }
}

#[test]
fn dropout_status_and_inertial_coasting() {
    let mut lp = AidedLoop::<f32>::new(&aided_config(), &init(100.0)).unwrap();
    let g = GravityModel::at_latitude(LAT).unwrap();
    let f = g.gravity_m_s2(100.0) as f32;
    let mut last = None;
    for k in 1..=300u32 {
        let t = f64::from(k) * 0.01;
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: f,
        };
        // Both aids until 1 s, then the velocity aid drops out; baro throughout.
        let baro = (k % 4 == 0).then_some(BaroSample {
            time: ts(t),
            altitude_m: 100.0,
        });
        let vel = (k % 10 == 0 && k <= 100).then_some(VelocitySample {
            time: ts(t),
            vz_up_m_s: 0.0,
        });
        let rep = lp.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
        if k == 50 {
            assert!(matches!(rep.velocity.status, AidStatus::Fresh { .. }));
            assert!(rep.velocity.correction.is_some());
            let s = rep.velocity.sample.unwrap();
            assert!(s.innovation_variance > 0.0 && s.test_ratio == 0.0, "{s:?}");
        }
        if k == 130 {
            assert!(
                matches!(rep.velocity.status, AidStatus::Stale { age_s } if (age_s - 0.3).abs() < 1e-4),
                "{:?}",
                rep.velocity.status
            );
            assert!(rep.velocity.correction.is_some());
        }
        last = Some(rep);
    }
    let rep = last.unwrap();
    assert!(matches!(rep.velocity.status, AidStatus::Lost { age_s } if age_s > 1.9));
    assert_eq!(rep.velocity.correction, None);
    assert!(matches!(rep.baro.status, AidStatus::Fresh { .. }));
    assert!((lp.altitude_m() - 100.0).abs() < 0.5);

    // Classical loop with no baro at all: NoData, pure inertial propagation.
    let mut cl = ClassicalLoop::<f64>::new(&classical_config(20.0, 0.0), &init(100.0)).unwrap();
    let imu = ImuSample {
        time: ts(0.01),
        specific_force_up_m_s2: g.gravity_m_s2(100.0) + 1.0,
    };
    let rep = cl.step(&imu, None).unwrap();
    assert_eq!(rep.baro.status, AidStatus::NoData);
    assert_eq!(rep.baro.correction, None);
    assert!((cl.vz_up_m_s() - 0.01).abs() < 1e-9, "{}", cl.vz_up_m_s());
    assert!((cl.altitude_m() - 100.00005).abs() < 1e-9);
}

/// A sample and its aids.
type Case = (
    ImuSample<f64>,
    Option<BaroSample<f64>>,
    Option<VelocitySample<f64>>,
);

/// Six inputs an aided loop that has run to 0.01 s refuses: a NaN and a stale IMU sample, a
/// non-finite and a future baro sample, an out-of-range velocity, an out-of-range specific
/// force (`imu` a valid IMU sample at 0.02 s).
fn refused_inputs(imu: ImuSample<f64>) -> [Case; 6] {
    [
        (
            ImuSample {
                time: ts(0.02),
                specific_force_up_m_s2: f64::NAN,
            },
            None,
            None,
        ),
        (
            ImuSample {
                time: ts(0.01),
                specific_force_up_m_s2: 9.8,
            },
            None,
            None,
        ),
        (
            imu,
            Some(BaroSample {
                time: ts(0.02),
                altitude_m: f64::INFINITY,
            }),
            None,
        ),
        (
            imu,
            Some(BaroSample {
                time: ts(0.03),
                altitude_m: 100.0,
            }),
            None,
        ),
        (
            imu,
            Some(BaroSample {
                time: ts(0.02),
                altitude_m: 100.0,
            }),
            Some(VelocitySample {
                time: ts(0.02),
                vz_up_m_s: 1e6,
            }),
        ),
        (
            ImuSample {
                time: ts(0.02),
                specific_force_up_m_s2: 1e4,
            },
            None,
            None,
        ),
    ]
}

#[test]
fn bad_input_leaves_state_unchanged() {
    let mut lp = AidedLoop::<f64>::new(&aided_config(), &init(100.0)).unwrap();
    let good = ImuSample {
        time: ts(0.01),
        specific_force_up_m_s2: 9.8,
    };
    lp.step(&good, None, None).unwrap();
    let before = lp;
    let imu = ImuSample {
        time: ts(0.02),
        specific_force_up_m_s2: 9.8,
    };
    let cases = refused_inputs(imu);
    // The input each case refuses: IMU (None) or the aid.
    let refused = [
        None,
        None,
        Some(Aid::Baro),
        Some(Aid::Baro),
        Some(Aid::Velocity),
        None,
    ];
    for (i, (imu, b, v)) in cases.iter().enumerate() {
        let counts = |lp: &AidedLoop<f64>| {
            (
                lp.health().imu_refused,
                lp.aid_counters(Aid::Baro).refused,
                lp.aid_counters(Aid::Velocity).refused,
            )
        };
        let n0 = counts(&lp);
        assert!(lp.step(imu, b.as_ref(), v.as_ref()).is_err(), "case {i}");
        assert_eq!(
            lp.core().without_refusals(),
            before.core().without_refusals(),
            "case {i}"
        );
        let n1 = counts(&lp);
        let expect = match refused[i] {
            None => (n0.0 + 1, n0.1, n0.2),
            Some(Aid::Baro) => (n0.0, n0.1 + 1, n0.2),
            Some(Aid::Velocity) => (n0.0, n0.1, n0.2 + 1),
        };
        assert_eq!(n1, expect, "case {i}");
    }
    // An old sample after a newer one is refused.
    lp.step(
        &imu,
        Some(&BaroSample {
            time: ts(0.02),
            altitude_m: 100.0,
        }),
        None,
    )
    .unwrap();
    let before = lp;
    let r = lp.step(
        &ImuSample {
            time: ts(0.03),
            specific_force_up_m_s2: 9.8,
        },
        Some(&BaroSample {
            time: ts(0.015),
            altitude_m: 100.0,
        }),
        None,
    );
    assert_eq!(r, Err(NavError::TimeNotIncreasing));
    assert_eq!(
        lp.core().without_refusals(),
        before.core().without_refusals()
    );
    assert_eq!(lp.aid_counters(Aid::Baro).refused, 3);
}

#[test]
fn gravity_model_matches_earth_model() {
    let g = GravityModel::at_latitude(LAT).unwrap();
    for h in [-500.0, 0.0, 1234.0, 10_000.0] {
        let e = crate::earth::normal_gravity_m_s2(LAT, h);
        assert!((g.gravity_m_s2(h) - e).abs() < 1e-9, "{h}");
    }
    // c = 2ω_s² is the vertical gradient to within the ellipsoidal corrections (< 1 %).
    assert!((g.c_per_s2() - g.g1_per_s2).abs() < 0.01 * g.g1_per_s2);
}

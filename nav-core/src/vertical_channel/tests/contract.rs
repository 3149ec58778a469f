//! The estimator contract of the loops: stored designs and their stamps, run-time settings
//! and their refusals, the starvation recovery.

use super::*;

fn nan_refused<T: Real>() {
    let nf = Err(NavError::InvalidConfig {
        field: "design",
        issue: crate::error::ConfigIssue::NotFinite,
    });
    let cc = classical_config::<T>(10.0, 0.0);
    let i0 = init::<T>(100.0);
    let good = ClassicalDesign::<T>::compute(&cc).unwrap();
    assert!(ClassicalLoop::from_design(&cc, &good, &i0).is_ok());
    let mut d = good;
    d.modes.both.g.m21 = T::lit(f64::NAN);
    assert_eq!(ClassicalLoop::from_design(&cc, &d, &i0).map(|_| ()), nf);
    let mut d = good;
    d.gravity.g1_per_s2 = T::lit(f64::INFINITY);
    assert_eq!(ClassicalLoop::from_design(&cc, &d, &i0).map(|_| ()), nf);
    let mut d = good;
    d.step.half_dt_s = T::zero();
    assert!(ClassicalLoop::from_design(&cc, &d, &i0).is_err());

    let ac = aided_config::<T>();
    let good = AidedDesign::<T>::compute(&ac).unwrap();
    assert!(AidedLoop::from_design(&ac, &good, &i0).is_ok());
    for corrupt in 0..3 {
        let mut d = good;
        match corrupt {
            0 => d.modes.none.n.m12 = T::lit(f64::NAN),
            1 => d.modes.phi_baro.m33 = T::lit(f64::NAN),
            _ => d.velocity_innovation_variance = T::lit(f64::NAN),
        }
        assert_eq!(
            AidedLoop::from_design(&ac, &d, &i0).map(|_| ()),
            nf,
            "{corrupt}"
        );
    }
}

#[test]
fn from_design_refuses_non_finite_designs_f32_f64() {
    nan_refused::<f32>();
    nan_refused::<f64>();
}

fn mismatch() -> Result<(), NavError> {
    Err(NavError::InvalidConfig {
        field: "design",
        issue: crate::error::ConfigIssue::DesignMismatch,
    })
}

/// A design computed for another configuration (any value the design depends on) is
/// refused; one that differs only in run-time fields (aid model, gate, recovery, timeouts) is
/// accepted; the stamp survives the value round trip.
fn stamps<T: Real>() {
    let cc = ClassicalConfig::<T>::paper();
    let d = ClassicalLoop::design(&cc).unwrap();
    let i0 = init::<T>(500.0);
    let mut values = [0.0; ClassicalDesign::<f32>::COUNT];
    d.write_values(&mut values).unwrap();
    assert_eq!(ClassicalDesign::<T>::read_values(&values).unwrap(), d);
    type CSet<T> = fn(&mut ClassicalConfig<T>);
    let changes: [CSet<T>; 5] = [
        |c| c.imu_dt_s = T::lit(0.005),
        |c| c.latitude_rad = T::lit(0.1),
        |c| c.tau_s = T::lit(30.0),
        |c| c.baro_lag_s = T::lit(0.1),
        |c| c.baro_period_s = T::lit(0.02),
    ];
    for (i, f) in changes.iter().enumerate() {
        let mut other = cc;
        f(&mut other);
        assert_ne!(classical_stamp(&other), d.stamp(), "{i}");
        assert_eq!(
            ClassicalLoop::from_design(&other, &d, &i0).map(|_| ()),
            mismatch(),
            "{i}"
        );
    }
    let run_time_only = ClassicalConfig {
        gate: Gate::Nis(T::lit(9.0)),
        aid_model: AidModel {
            baro_sigma_m: T::lit(5.0),
            ..AidModel::paper()
        },
        ..cc
    };
    assert!(ClassicalLoop::from_design(&run_time_only, &d, &i0).is_ok());

    let ac = AidedConfig::<T>::paper();
    let d = AidedLoop::design(&ac).unwrap();
    let other = AidedConfig {
        velocity_noise_m_s: T::lit(0.2),
        ..ac
    };
    assert_eq!(
        AidedLoop::from_design(&other, &d, &i0).map(|_| ()),
        mismatch()
    );
    assert_eq!(d.stamp().version, AIDED_DESIGN_VERSION);
}

#[test]
fn design_stamps_refuse_other_configurations_f32_f64() {
    stamps::<f32>();
    stamps::<f64>();
}

/// Recovery policies outside the vertical loops' envelope, with the field each is refused on.
fn bad_recoveries<T: Real>() -> [(RecoveryPolicy<T>, &'static str); 4] {
    [
        (
            RecoveryPolicy {
                starved_after_s: Some(T::zero()),
                action: RecoveryAction::Reanchor,
            },
            "recovery.starved_after_s",
        ),
        (
            RecoveryPolicy {
                starved_after_s: Some(T::lit(2.0e6)),
                action: RecoveryAction::Reanchor,
            },
            "recovery.starved_after_s",
        ),
        (
            RecoveryPolicy {
                starved_after_s: Some(T::lit(1.0)),
                action: RecoveryAction::ResetToPrior,
            },
            "recovery.action",
        ),
        (
            RecoveryPolicy {
                starved_after_s: None,
                action: RecoveryAction::Inflate {
                    variance_factor: T::lit(2.0),
                },
            },
            "recovery.action",
        ),
    ]
}

/// Setters and configuration refuse out-of-envelope gates, recoveries and aid models with the
/// field named and leave the loop unchanged; the covariance recovery actions are refused.
fn run_time_refusals<T: Real>() {
    let cc = ClassicalConfig::<T>::paper();
    let i0 = init::<T>(500.0);
    let mut lp = ClassicalLoop::new(&cc, &i0).unwrap();
    let before = lp;
    let field = |r: Result<(), NavError>| match r {
        Err(NavError::InvalidConfig { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    for g in [0.0, -1.0, 1e-4, 1e5, f64::NAN] {
        assert_eq!(field(lp.set_gate(Gate::Nis(T::lit(g)))), "gate", "{g}");
        let c = ClassicalConfig {
            gate: Gate::Nis(T::lit(g)),
            ..cc
        };
        assert_eq!(field(ClassicalLoop::new(&c, &i0).map(|_| ())), "gate");
    }
    let bad_recoveries = bad_recoveries::<T>();
    for (r, name) in bad_recoveries {
        assert_eq!(field(lp.set_recovery(r)), name);
    }
    type MSet<T> = fn(&mut AidModel<T>);
    let bad_models: [(MSet<T>, &str); 6] = [
        (|m| m.baro_sigma_m = T::zero(), "aid_model.baro_sigma_m"),
        (|m| m.baro_sigma_m = T::lit(1e7), "aid_model.baro_sigma_m"),
        (
            |m| m.velocity_sigma_m_s = T::lit(1e-7),
            "aid_model.velocity_sigma_m_s",
        ),
        (
            |m| m.starved_velocity_sigma_m_s = T::lit(-1.0),
            "aid_model.starved_velocity_sigma_m_s",
        ),
        (
            |m| m.starved_accel_sigma_m_s2 = T::lit(1e-9),
            "aid_model.starved_accel_sigma_m_s2",
        ),
        (
            |m| m.recovery_hold_s = T::lit(2.0e6),
            "aid_model.recovery_hold_s",
        ),
    ];
    for (f, name) in bad_models {
        let mut m = AidModel::paper();
        f(&mut m);
        assert_eq!(field(lp.set_aid_model(m)), name);
    }
    assert_eq!(lp, before);
    // Valid settings are taken (and zero drift is legal).
    lp.set_gate(Gate::Nis(T::lit(9.0))).unwrap();
    lp.set_recovery(RecoveryPolicy {
        starved_after_s: None,
        action: RecoveryAction::Reanchor,
    })
    .unwrap();
    lp.set_aid_model(AidModel {
        starved_accel_sigma_m_s2: T::zero(),
        ..AidModel::paper()
    })
    .unwrap();
    assert_ne!(lp, before);
}

#[test]
fn run_time_settings_refused_with_field_named_f32_f64() {
    run_time_refusals::<f32>();
    run_time_refusals::<f64>();
}

/// The starvation recovery maps the old "re-anchor after `starved_after_s` of rejections":
/// with every baro sample 500 m off, the gate rejects until 2 s of rejections have passed,
/// then re-anchors (one recovery); with `starved_after_s: None` it never does.
#[test]
fn starvation_reanchors_after_starved_after_s_only_when_enabled() {
    for limit in [Some(2.0), None] {
        let cfg = ClassicalConfig {
            gate: Gate::Nis(9.0),
            recovery: RecoveryPolicy {
                starved_after_s: limit,
                action: RecoveryAction::Reanchor,
            },
            ..ClassicalConfig::<f64>::paper()
        };
        let mut lp = ClassicalLoop::new(&cfg, &init(500.0)).unwrap();
        let g = GravityModel::at_latitude(PAPER_LATITUDE_RAD).unwrap();
        let mut reanchored_at = None;
        for k in 1..=500u64 {
            let time = Timestamp::from_micros(k * 10_000);
            let imu = ImuSample {
                time,
                specific_force_up_m_s2: g.gravity_m_s2(500.0),
            };
            // One good sample, then 500 m off.
            let alt = if k == 4 { 500.0 } else { 1000.0 };
            let baro = (k % 4 == 0).then_some(BaroSample {
                time,
                altitude_m: alt,
            });
            let r = lp.step(&imu, baro.as_ref()).unwrap();
            if r.baro.reacquisition == Reacquisition::Reanchored && reanchored_at.is_none() {
                reanchored_at = Some(k);
                let s = r.baro.sample.unwrap();
                assert_eq!((s.outcome, s.test_ratio), (FusionOutcome::Fused, 0.0));
            }
        }
        let c = lp.aid_counters(Aid::Baro);
        match limit {
            // First rejection at k = 8 (0.08 s): re-anchored at the first sample ≥ 2.08 s.
            Some(_) => {
                assert_eq!(reanchored_at, Some(208), "{c:?}");
                assert_eq!(c.recoveries, 1, "{c:?}");
                assert!((lp.altitude_m() - 1000.0).abs() < 1.0);
            }
            None => {
                assert_eq!(reanchored_at, None);
                assert_eq!((c.recoveries, c.fused), (0, 1), "{c:?}");
            }
        }
    }
}

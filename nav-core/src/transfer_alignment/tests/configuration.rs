//! Configuration and design: validation, the initial covariance, the paper's cases, setters
//! that refuse without change, the design stamp.

use super::*;

#[test]
fn config_validation() {
    let ok = cfg::<f32>();
    assert!(new::<f32, 4, 12>(ok).is_ok());
    let mut c = ok;
    c.flexure[1].tau_s = 0.0;
    assert!(matches!(
        new::<f32, 4, 12>(c),
        Err(NavError::InvalidConfig {
            field: "flexure.tau_s",
            ..
        })
    ));
    let mut c = ok;
    c.accel_noise_sigma_m_s2 = -1.0;
    assert!(matches!(
        new::<f32, 3, 9>(c),
        Err(NavError::InvalidConfig {
            field: "accel_noise_sigma_m_s2",
            ..
        })
    ));
    let mut c = ok;
    c.lever_arm_m.y = f32::INFINITY;
    assert!(new::<f32, 4, 12>(c).is_err());
    let mut c = ok;
    c.time_tolerance_s = 0.006;
    assert!(new::<f32, 4, 12>(c).is_err());
    let mut c = ok;
    c.max_gap_steps = 0;
    assert!(new::<f32, 4, 12>(c).is_err());
    let mut c = ok;
    c.max_gap_steps = MAX_GAP_STEPS + 1;
    assert!(matches!(
        new::<f32, 4, 12>(c),
        Err(NavError::InvalidConfig {
            field: "max_gap_steps",
            ..
        })
    ));
    let mut c = ok;
    c.flexure[0].tau_s = 0.04; // < 5 dt
    assert!(new::<f32, 4, 12>(c).is_err());
    let mut c = ok;
    c.gate = Gate::Nis(0.0);
    assert!(new::<f32, 4, 12>(c).is_err());
    assert!(new::<f32, 4, 9>(ok).is_err());
}

#[test]
fn set_block_diagonal_places_the_axis_blocks() {
    fn check<T: Real, const K: usize, const N: usize>() {
        let f = new::<T, K, N>(cfg::<T>()).unwrap();
        let mut chains = *f.chains();
        // Distinct values everywhere, so a misplaced element shows.
        for (a, ch) in chains.iter_mut().enumerate() {
            for (i, v) in ch.p0.iter_mut().enumerate() {
                *v = T::lit((100 * a + i + 1) as f64);
            }
        }
        let mut p = SMatrix::<T, N, N>::zeros();
        let blocks = [
            chains[0].p0.as_slice(),
            chains[1].p0.as_slice(),
            chains[2].p0.as_slice(),
        ];
        crate::math::checks::set_block_diagonal(p.as_mut_slice(), N, &blocks, K);
        let mut expect = SMatrix::<T, N, N>::zeros();
        for (a, ch) in chains.iter().enumerate() {
            expect
                .fixed_view_mut::<K, K>(K * a, K * a)
                .copy_from(&ch.p0);
        }
        assert_eq!(p, expect);
    }
    check::<f32, 3, 9>();
    check::<f64, 3, 9>();
    check::<f32, 4, 12>();
    check::<f64, 4, 12>();
}

#[test]
fn initial_covariance_and_outputs() {
    let f = new::<f64, 4, 12>(cfg()).unwrap();
    let sm = 0.5_f64.to_radians();
    assert!((f.theta_m_covariance()[(0, 0)] - sm * sm).abs() < 1e-15);
    // θ covariance = σ_m² + σ_f² per axis at the start.
    let s = f.theta_sigma_rad();
    assert!((s.x - (2.0 * sm * sm).sqrt()).abs() < 1e-12);
    assert!(f.theta_f_accel().is_some());
    assert!(new::<f64, 3, 9>(cfg()).unwrap().theta_f_accel().is_none());
    // C_n^s for zero misalignment is C_n^m.
    let c = crate::math::rotation::euler_to_dcm(0.1, 0.2, 0.3).transpose();
    assert!((f.slave_attitude(&c) - c).abs().max() < 1e-15);
}

#[test]
fn config_paper_cases_and_default_recovery() {
    let c1 = TaConfig::<f64>::paper(PaperCase::Case1);
    let c3 = TaConfig::<f64>::paper(PaperCase::Case3);
    assert_eq!(c1.flexure[0].tau_s, 2.146);
    assert_eq!(c3.flexure[0].tau_s, 0.2);
    assert_eq!(c1.flexure[1], c3.flexure[1]);
    for c in [c1, c3, TaConfig::paper(PaperCase::Case2)] {
        c.validate().unwrap();
    }
    // 0.5 s at 100 Hz is 50 epochs, at 1 kHz 500; anything shorter than a step is refused.
    assert_eq!(
        config::validate_recovery(&default_recovery::<f32>(), 10_000),
        Ok(Some(50))
    );
    assert_eq!(
        config::validate_recovery(&default_recovery::<f32>(), 1_000),
        Ok(Some(500))
    );
    let short = RecoveryPolicy {
        starved_after_s: Some(0.005_f32),
        action: RecoveryAction::ResetToPrior,
    };
    assert!(config::validate_recovery(&short, 10_000).is_err());
}

fn setters_refuse_without_change<T: Real, const K: usize, const N: usize>() {
    let mut f = new::<T, K, N>(cfg()).unwrap();
    let before = format!("{f:?}");
    let field = |e: Result<(), NavError>| match e {
        Err(NavError::InvalidConfig { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    assert_eq!(field(f.set_gate(Gate::Nis(T::lit(0.5)))), "gate");
    assert_eq!(field(f.set_gate(Gate::Nis(T::lit(f64::NAN)))), "gate");
    for action in [
        RecoveryAction::Inflate {
            variance_factor: T::lit(4.0),
        },
        RecoveryAction::Reanchor,
    ] {
        let policy = RecoveryPolicy {
            starved_after_s: Some(T::lit(0.5)),
            action,
        };
        assert_eq!(field(f.set_recovery(policy)), "recovery.action");
    }
    for s in [0.0, -1.0, 0.001, 1.0e5, f64::INFINITY] {
        let policy = RecoveryPolicy {
            starved_after_s: Some(T::lit(s)),
            action: RecoveryAction::ResetToPrior,
        };
        assert_eq!(
            field(f.set_recovery(policy)),
            "recovery.starved_after_s",
            "{s}"
        );
    }
    assert_eq!(format!("{f:?}"), before);
    // The same checks at construction.
    let mut c = cfg::<T>();
    c.recovery.action = RecoveryAction::Reanchor;
    assert_eq!(field(new::<T, K, N>(c).map(|_| ())), "recovery.action");
    // Accepted settings are in force.
    f.set_gate(Gate::Off).unwrap();
    assert_eq!(f.config().gate, Gate::Off);
    let off = RecoveryPolicy {
        starved_after_s: None,
        action: RecoveryAction::ResetToPrior,
    };
    f.set_recovery(off).unwrap();
    assert_eq!(f.config().recovery, off);
}

#[test]
fn setters_refuse_without_change_f32_f64() {
    setters_refuse_without_change::<f32, 4, 12>();
    setters_refuse_without_change::<f64, 3, 9>();
    setters_refuse_without_change::<f32, 5, 15>();
}

fn design_stamp_and_initial<T: Real, const K: usize, const N: usize>() {
    let c = cfg::<T>();
    let design = TransferAlignment::<T, K, N>::design(&c).unwrap();
    let init = TaInitial {
        mount_misalignment_rad: Vector3::new(T::lit(0.01), T::lit(-0.02), T::lit(0.005)),
    };
    let f = TransferAlignment::<T, K, N>::from_design(&c, &design, &init).unwrap();
    assert_eq!(f.theta_m(), init.mount_misalignment_rad);
    assert_eq!(f.theta(), init.mount_misalignment_rad);
    // Settings the design does not depend on may differ; the flexure, mount σ and dt may not.
    let mut other = c;
    other.gate = Gate::Off;
    other.rate_noise_sigma_rad_s = T::lit(1e-3);
    assert!(TransferAlignment::<T, K, N>::from_design(&other, &design, &init).is_ok());
    let mismatch = Err(NavError::InvalidConfig {
        field: "design",
        issue: crate::error::ConfigIssue::DesignMismatch,
    });
    for change in 0..3 {
        let mut other = c;
        match change {
            0 => other.flexure[2].tau_s = T::lit(2.0),
            1 => other.mount_sigma_rad.y = T::lit(0.005),
            _ => other.dt_s = T::lit(0.005),
        }
        assert_eq!(
            TransferAlignment::<T, K, N>::from_design(&other, &design, &init).map(|_| ()),
            mismatch
        );
    }
    for (v, e) in [
        (
            f64::NAN,
            NavError::NonFiniteInput {
                input: "initial.mount_misalignment_rad",
            },
        ),
        (
            0.31,
            NavError::InputOutOfRange {
                input: "initial.mount_misalignment_rad",
            },
        ),
    ] {
        let mut bad = init;
        bad.mount_misalignment_rad.z = T::lit(v);
        assert_eq!(
            TransferAlignment::<T, K, N>::from_design(&c, &design, &bad).map(|_| ()),
            Err(e)
        );
    }
}

#[test]
fn design_stamp_and_initial_f32_f64() {
    design_stamp_and_initial::<f32, 4, 12>();
    design_stamp_and_initial::<f64, 3, 9>();
    design_stamp_and_initial::<f32, 5, 15>();
    design_stamp_and_initial::<f64, 5, 15>();
    // The bias σ is in the flight design's stamp only.
    let c = cfg::<f32>();
    let mut other = c;
    other.accel_bias_sigma_m_s2.z = 1e-3;
    let flight = FlightFilter::<f32>::design(&c).unwrap();
    assert!(FlightFilter::from_design(&other, &flight, &TaInitial::default()).is_err());
    let paper = ProposedFilter::<f32>::design(&c).unwrap();
    assert!(ProposedFilter::from_design(&other, &paper, &TaInitial::default()).is_ok());
    other.accel_bias_sigma_m_s2.y = -1e-3;
    assert!(matches!(
        FlightFilter::<f32>::design(&other),
        Err(NavError::InvalidConfig {
            field: "accel_bias_sigma_m_s2",
            ..
        })
    ));
    other.accel_bias_sigma_m_s2 = Vector3::new(1e-3, 1e-3, 0.6);
    assert!(FlightFilter::<f32>::design(&other).is_err());
}

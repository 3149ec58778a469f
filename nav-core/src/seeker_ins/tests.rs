//! Unit tests of the filter's configuration and construction (the behaviour is tested
//! cross-crate in `tests/tests/seeker_ins*.rs`).

use super::*;
use crate::contract::{Estimator, Gate, RecoveryAction, RecoveryPolicy};
use crate::design::DesignValues;
use crate::error::ConfigIssue;
use crate::NavError;
use nalgebra::{Quaternion, SMatrix, Vector3};

fn setup(residual: LosResidual) -> (SeekerInsConfig<f32>, SeekerInsInitial<f32>) {
    let start = Position {
        lat_rad: 37f64.to_radians(),
        lon_rad: 127f64.to_radians(),
        alt_m: 1000.0,
    };
    let target = Position {
        lat_rad: 37.05f64.to_radians(),
        ..start
    };
    let cfg = SeekerInsConfig {
        residual,
        ..SeekerInsConfig::paper(Landmark::new(target).unwrap())
    };
    let init = SeekerInsInitial {
        state: InsState {
            position: start,
            vel_ned_m_s: Vector3::new(200.0, 0.0, 0.0),
            q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        },
        covariance: SMatrix::<f32, 17, 17>::from_diagonal_element(1e-8),
    };
    (cfg, init)
}

/// Without the `los-residual-3d` feature (a flight build), the comparison residual is
/// refused at configuration and the design choice still works
/// (`cargo test -p nav-core --no-default-features`, run by `cargo xtask ci`).
#[cfg(not(feature = "los-residual-3d"))]
#[test]
fn full_rank_3d_needs_its_feature() {
    let (cfg, init) = setup(LosResidual::FullRank3d);
    assert_eq!(
        SeekerIns::new(&cfg, &init).err(),
        Some(NavError::InvalidConfig {
            field: "residual",
            issue: ConfigIssue::OutOfRange,
        })
    );
    let (cfg, init) = setup(LosResidual::Projected2d);
    assert!(SeekerIns::new(&cfg, &init).is_ok());
}

#[cfg(feature = "los-residual-3d")]
#[test]
fn both_residuals_configure_with_the_feature() {
    for residual in [LosResidual::Projected2d, LosResidual::FullRank3d] {
        let (cfg, init) = setup(residual);
        assert!(SeekerIns::new(&cfg, &init).is_ok());
    }
}

#[test]
fn stored_design_round_trips_and_is_checked() {
    let (cfg, init) = setup(LosResidual::Projected2d);
    let design = SeekerIns::design(&cfg).unwrap();
    let mut stored = [0.0; SeekerInsDesign::<f32>::COUNT];
    design.write_values(&mut stored).unwrap();
    let loaded = SeekerInsDesign::<f32>::read_values(&stored).unwrap();
    assert_eq!(loaded, design);
    let a = SeekerIns::from_design(&cfg, &loaded, &init).unwrap();
    assert_eq!(a, SeekerIns::new(&cfg, &init).unwrap());
    // A design of another configuration is refused.
    let other = SeekerInsConfig {
        gyro_noise_density_rad_s_rt_hz: cfg.gyro_noise_density_rad_s_rt_hz * 2.0,
        ..cfg
    };
    assert_eq!(
        SeekerIns::from_design(&other, &loaded, &init).err(),
        Some(NavError::InvalidConfig {
            field: "design",
            issue: ConfigIssue::DesignMismatch,
        })
    );
    stored[0] = 1.5;
    assert!(SeekerInsDesign::<f32>::read_values(&stored).is_err());
}

#[test]
fn gate_and_recovery_are_validated_and_refusals_change_nothing() {
    let (cfg, init) = setup(LosResidual::Projected2d);
    let mut f = SeekerIns::new(&cfg, &init).unwrap();
    let before = f;
    let bad_gate = |field| NavError::InvalidConfig {
        field,
        issue: ConfigIssue::OutOfRange,
    };
    assert_eq!(f.set_gate(Gate::Nis(0.5)), Err(bad_gate("gate")));
    for action in [RecoveryAction::ResetToPrior, RecoveryAction::Reanchor] {
        let r = RecoveryPolicy {
            starved_after_s: Some(5.0),
            action,
        };
        assert_eq!(f.set_recovery(r), Err(bad_gate("recovery.action")));
    }
    let r = RecoveryPolicy {
        starved_after_s: Some(0.0),
        action: RecoveryAction::Inflate {
            variance_factor: 4.0,
        },
    };
    assert_eq!(f.set_recovery(r), Err(bad_gate("recovery.starved_after_s")));
    let pol = ImuFaultPolicy {
        max_gap_s: 10.0,
        ..ImuFaultPolicy::default()
    };
    assert_eq!(f.set_imu_faults(pol), Err(bad_gate("imu_faults.max_gap_s")));
    assert_eq!(f, before);
    let bad = SeekerInsConfig {
        gate: Gate::Nis(f32::NAN),
        ..cfg
    };
    assert!(matches!(
        SeekerIns::new(&bad, &init),
        Err(NavError::InvalidConfig { field: "gate", .. })
    ));
    f.set_gate(Gate::Off).unwrap();
    assert_eq!(f.config().gate, Gate::Off);
}

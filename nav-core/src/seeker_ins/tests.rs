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

/// Smallest eigenvalue of P's correlation matrix (states with a zero variance left out).
fn min_correlation_eigenvalue(p: &SMatrix<f32, 17, 17>) -> f64 {
    let p = p.map(f64::from);
    let d: nalgebra::SVector<f64, 17> =
        p.diagonal()
            .map(|v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 });
    let c = SMatrix::<f64, 17, 17>::from_fn(|i, j| {
        if d[i] == 0.0 || d[j] == 0.0 {
            if i == j {
                1.0
            } else {
                0.0
            }
        } else {
            0.5 * (p[(i, j)] + p[(j, i)]) * d[i] * d[j]
        }
    });
    c.symmetric_eigen().eigenvalues.min()
}

/// A long run on the IMU alone in f32 (no LOS update, whose stabilising noise would restore
/// the margin), with a vertical accelerometer error that drives the unaided vertical channel
/// out of the model range: after every covariance step the correlation matrix of P stays
/// PSD to the stress campaign's tolerance (17 · 64 ε). Without the covariance health check
/// (and without any other stabilising noise) the rounding of 10⁵ covariance steps drove its
/// smallest eigenvalue to −1.3e-4.
#[test]
fn p_stays_psd_over_a_long_unaided_run_in_f32() {
    let (cfg, mut init) = setup(LosResidual::Projected2d);
    init.covariance = paper_initial_covariance();
    let mut f = SeekerIns::new(&cfg, &init).unwrap();
    let dt_us = 10_000u64;
    let tol = 17.0 * 64.0 * f64::from(f32::EPSILON);
    let mut worst = f64::INFINITY;
    for k in 1..=1_000_000u64 {
        let sample = ImuIncrement {
            time: crate::time::Timestamp::from_micros(k * dt_us),
            delta_theta_rad: Vector3::new(0.0, 0.0, 0.0),
            // Gravity plus a 0.5 m/s² vertical error the filter does not model.
            delta_v_m_s: Vector3::new(0.0, 0.0, (-9.80 + 0.5) * 0.01),
        };
        f.propagate(&sample).unwrap();
        if k % 1000 == 0 {
            worst = worst.min(min_correlation_eigenvalue(f.covariance()));
        }
    }
    assert!(worst >= -tol, "smallest correlation eigenvalue {worst:e}");
}

//! Recovery after a starved channel and re-initialisation.

use super::*;

/// A constant bias on df_X rejected by the gate at every epoch: the covariance is reset after
/// exactly `⌈starved_after_s / dt_s⌉` epochs, counted on that channel only.
fn recovery_after_starvation<T: Real, const K: usize, const N: usize>() {
    let mut f = new::<T, K, N>(cfg()).unwrap();
    f.set_recovery(RecoveryPolicy {
        starved_after_s: Some(T::lit(0.2)),
        action: RecoveryAction::ResetToPrior,
    })
    .unwrap();
    for k in 0..40 {
        let (m, mut s) = samples::<T>(0.01 * k as f64);
        if k >= 10 {
            s.specific_force_m_s2.x += T::lit(5.0);
        }
        f.step(&m, &s).unwrap();
        let c = f.aid_counters(Channel::ForceX);
        // Rejected from epoch 10 on; 20 rejected epochs (0.2 s) starve the channel.
        match k {
            10..=28 => assert_eq!((c.consecutive_rejected, c.recoveries), (k - 9, 0)),
            29 => {
                assert_eq!((c.consecutive_rejected, c.recoveries), (0, 1));
                // P ← P0: θ's σ is the initial one again (up to the PSD loading).
                let s0 = new::<T, K, N>(cfg()).unwrap().theta_sigma_rad();
                let ds = (f.theta_sigma_rad() - s0).abs().max().to_f64();
                assert!(ds < 1e-4 * s0.max().to_f64(), "{ds}");
                assert_eq!(f.theta_f(), Vector3::zeros());
            }
            _ => {}
        }
    }
    assert!(f.aid_counters(Channel::ForceX).rejected >= 20);
    assert_eq!(f.aid_counters(Channel::RateX).recoveries, 0);
    assert_eq!(f.health().state, crate::HealthState::Degraded);
}

#[test]
fn recovery_after_starvation_f32_f64() {
    recovery_after_starvation::<f32, 4, 12>();
    recovery_after_starvation::<f64, 3, 9>();
    recovery_after_starvation::<f32, 5, 15>();
}
fn reinitialise_restarts_from_initial<T: Real, const K: usize, const N: usize>() {
    let mut f = new::<T, K, N>(cfg()).unwrap();
    for k in 0..20 {
        let (m, s) = samples::<T>(0.01 * k as f64);
        f.step(&m, &s).unwrap();
    }
    assert_eq!(f.health().state, crate::HealthState::Nominal);
    let fused = f.aid_counters(Channel::RateY).fused;
    let before = format!("{f:?}");
    let bad = TaInitial {
        mount_misalignment_rad: Vector3::repeat(T::lit(1.0)),
    };
    assert!(f.reinitialise(&bad).is_err());
    assert_eq!(format!("{f:?}"), before);
    let init = TaInitial {
        mount_misalignment_rad: Vector3::new(T::lit(0.001), T::zero(), T::zero()),
    };
    f.reinitialise(&init).unwrap();
    assert_eq!(f.theta(), init.mount_misalignment_rad);
    let fresh = new::<T, K, N>(cfg()).unwrap();
    assert_eq!(f.covariance(), fresh.covariance());
    assert_eq!(f.health().reinitialisations, 1);
    assert_eq!(f.health().state, crate::HealthState::Degraded);
    assert_eq!(f.aid_counters(Channel::RateY).fused, fused);
    // The clock is kept: an old stamp is still refused.
    let (m, s) = samples::<T>(0.1);
    assert_eq!(f.step(&m, &s), Err(NavError::TimeNotIncreasing));
    let (m, s) = samples::<T>(0.2);
    assert_eq!(f.step(&m, &s).unwrap().gap, GapOutcome::Predicted);
}

#[test]
fn reinitialise_restarts_from_initial_f32_f64() {
    reinitialise_restarts_from_initial::<f32, 4, 12>();
    reinitialise_restarts_from_initial::<f64, 3, 9>();
    reinitialise_restarts_from_initial::<f32, 5, 15>();
}

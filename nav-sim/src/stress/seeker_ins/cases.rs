//! The cases of the campaign: configurations, policies, sightings and faults at the extremes
//! of the documented ranges.

use super::*;

/// Every case at `level`, each with its own seed.
pub(super) fn cases(level: StressLevel) -> Vec<Case> {
    let full = level == StressLevel::Full;
    let long = if full { 1_000_000 } else { 120_000 };
    let medium = if full { 300_000 } else { 40_000 };
    let base = Case {
        name: String::new(),
        steps: medium,
        seed: 0,
        imu_dt_s: 0.01,
        covariance_interval_steps: 10,
        accel_density: ACCEL_DENSITY,
        gyro_density: GYRO_DENSITY,
        seeker_noise_rad: SEEKER_NOISE_RAD,
        gate_nis: 16.0,
        policy: default_policy(),
        recovery: default_recovery(),
        sightings: Sightings::Continuous,
        faults: Faults::None,
        vertical_accel_error_m_s2: 0.0,
        landmark_on_path: false,
        landmark_alt_m: 0.0,
        reinitialise: false,
        f64: false,
    };
    let mut v = sighting_cases(&base, long);
    v.extend(imu_fault_cases(&base, long));
    v.extend(envelope_cases(&base, medium));
    // The precision limit: the finest seeker σ with zero process noise (the updates make P as
    // ill-conditioned as they can), several draws, and two coarser σ.
    for (i, sigma) in [1e-5, 1e-5, 1e-5, 1e-5, 3e-5, 1e-4].iter().enumerate() {
        v.push(Case {
            name: format!("seeker σ {sigma:e} rad, densities 0, gaps and clipping (draw {i})"),
            seeker_noise_rad: *sigma,
            accel_density: 0.0,
            gyro_density: 0.0,
            faults: Faults::Mixed,
            ..base.clone()
        });
    }
    for (i, c) in v.iter_mut().enumerate() {
        c.seed = 11_000 + i as u64;
    }
    v
}

/// The landmark seen 20 s in every 1000 s.
const RARE: Sightings = Sightings::Rare {
    on_s: 20.0,
    period_s: 1000.0,
};

/// Inflation at the first fully rejected LOS sample (0.1 s after the one before).
fn hostile_recovery() -> RecoveryPolicy<f64> {
    RecoveryPolicy {
        starved_after_s: Some(0.1),
        action: RecoveryAction::Inflate {
            variance_factor: 100.0,
        },
    }
}

/// Continuous and rare sightings, with vertical accelerometer errors the filter does not model.
fn sighting_cases(base: &Case, long: u64) -> Vec<Case> {
    vec![
        Case {
            name: "nominal 100 Hz, continuous LOS with loss and false lock".into(),
            ..base.clone()
        },
        Case {
            name: "rare landmark (20 s per 1000 s), vertical accel error 0.02 m/s²".into(),
            steps: long,
            sightings: RARE,
            vertical_accel_error_m_s2: 0.02,
            ..base.clone()
        },
        Case {
            name: "rare landmark, vertical accel error 0.5 m/s² (position leaves the range)".into(),
            steps: long,
            sightings: RARE,
            vertical_accel_error_m_s2: 0.5,
            ..base.clone()
        },
        Case {
            name: "rare landmark, vertical error 0.5 m/s², reinitialise when needed".into(),
            steps: long,
            sightings: RARE,
            vertical_accel_error_m_s2: 0.5,
            reinitialise: true,
            ..base.clone()
        },
    ]
}

/// Long clipping, long gaps and both, at the extremes of the IMU fault policy.
fn imu_fault_cases(base: &Case, long: u64) -> Vec<Case> {
    vec![
        Case {
            name: "long clipping (6000 consecutive), default policy".into(),
            faults: Faults::Clipping {
                samples: 6000,
                every_s: 150.0,
            },
            ..base.clone()
        },
        Case {
            name: "long clipping (6000 consecutive), extreme policy, hostile recovery".into(),
            faults: Faults::Clipping {
                samples: 6000,
                every_s: 150.0,
            },
            policy: extreme_policy(0.01),
            recovery: hostile_recovery(),
            ..base.clone()
        },
        Case {
            name: "long gaps (1 s every 5 s), extreme policy".into(),
            faults: Faults::Gaps { every_s: 5.0 },
            policy: extreme_policy(0.01),
            ..base.clone()
        },
        Case {
            name: "gaps and clipping, zero-σ policy, hostile recovery, gate 1".into(),
            faults: Faults::Mixed,
            policy: zero_policy(),
            recovery: hostile_recovery(),
            gate_nis: 1.0,
            ..base.clone()
        },
        Case {
            name: "gaps and clipping, extreme policy, rare landmark, gate 1e4".into(),
            steps: long,
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            sightings: RARE,
            gate_nis: 1e4,
            vertical_accel_error_m_s2: 0.1,
            ..base.clone()
        },
    ]
}

/// The envelope's edges: seeker σ and densities at their maxima, the landmark overflown, 10 Hz
/// and 1 kHz IMUs, one f64 case.
fn envelope_cases(base: &Case, medium: u64) -> Vec<Case> {
    vec![
        Case {
            name: "seeker σ 0.1 rad, densities at their maxima".into(),
            seeker_noise_rad: 0.1,
            accel_density: 0.1,
            gyro_density: 0.01,
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            ..base.clone()
        },
        Case {
            name: "landmark overflown at 50 m (minimum range), 100 Hz".into(),
            landmark_on_path: true,
            landmark_alt_m: -50.0,
            faults: Faults::Mixed,
            ..base.clone()
        },
        Case {
            name: "10 Hz IMU, covariance every 1 s, extreme policy".into(),
            imu_dt_s: 0.1,
            covariance_interval_steps: 10,
            steps: medium / 4,
            faults: Faults::Mixed,
            policy: extreme_policy(0.1),
            recovery: hostile_recovery(),
            ..base.clone()
        },
        Case {
            name: "1 kHz IMU, covariance every sample, extreme policy".into(),
            imu_dt_s: 0.001,
            covariance_interval_steps: 1,
            steps: medium,
            faults: Faults::Mixed,
            policy: extreme_policy(0.001),
            ..base.clone()
        },
        Case {
            name: "f64: gaps and clipping, extreme policy, hostile recovery, rare landmark".into(),
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            recovery: hostile_recovery(),
            sightings: RARE,
            vertical_accel_error_m_s2: 0.5,
            f64: true,
            ..base.clone()
        },
    ]
}

//! The step with deferred checks against the per-update checks alone.
use super::super::config::{PaperCase, TaConfig};
use super::super::filter::TaInitial;
use super::*;
use crate::contract::Estimator;
use crate::math::kalman::FusionOutcome;
use std::format;

fn samples<T: Real>(k: u32) -> (MasterSample<T>, SlaveSample<T>) {
    let time = Timestamp::from_micros(u64::from(k) * 10_000);
    // A slow manoeuvre so that every row carries information.
    let a = f64::from(k) * 0.05;
    let (w, f) = (
        Vector3::new(0.02 * a.sin(), -0.01, 0.015 * a.cos()),
        Vector3::new(3.0 * a.cos(), 0.5, -9.8),
    );
    let m = MasterSample {
        time,
        angular_rate_rad_s: w.map(T::lit),
        angular_accel_rad_s2: Vector3::new(0.001 * a.cos(), 0.0, -0.00075 * a.sin()).map(T::lit),
        specific_force_m_s2: f.map(T::lit),
    };
    let theta = Vector3::new(0.004, -0.003, 0.002);
    let s = SlaveSample {
        time,
        angular_rate_rad_s: (w - theta.cross(&w)).map(T::lit),
        specific_force_m_s2: (f - theta.cross(&f)).map(T::lit),
    };
    (m, s)
}

fn filter<T: Real, const K: usize, const N: usize>() -> TransferAlignment<T, K, N> {
    let cfg = TaConfig {
        accel_bias_sigma_m_s2: TaConfig::<T>::flight(PaperCase::Case2).accel_bias_sigma_m_s2,
        ..TaConfig::paper(PaperCase::Case2)
    };
    TransferAlignment::new(&cfg, &TaInitial::default()).unwrap()
}

/// The step with deferred checks against the per-update checks alone: the same filter
/// (state, covariance, clock, counters) and the same reports, bit for bit, epoch after
/// epoch — in the normal case (the deferred check passes) and with a covariance made
/// indefinite before some epochs (updates the per-update checks refuse: the deferred run
/// fails its check and the epoch is run again), and with outliers the gate rejects in one
/// row of a pair. Returns the number of `Skipped` reports.
fn deferred_equals_per_update<T: Real, const K: usize, const N: usize>() -> (u32, usize) {
    let mut deferred = filter::<T, K, N>();
    let mut reference = deferred.clone();
    let (mut skipped, mut rejected) = (0, 0);
    for k in 0..120u32 {
        if k % 40 == 39 {
            // An indefinite covariance: θ_X's variance tiny, its correlation with the next
            // state far beyond 1 (an update driving a variance below zero).
            for f in [&mut deferred, &mut reference] {
                let cur = usize::from(f.second);
                if let Some(p) = f.p.get_mut(cur) {
                    p[(1, 1)] = T::lit(1e-12);
                    p[(0, 1)] = T::lit(1e-3);
                    p[(K + 1, K + 1)] = T::lit(1e-12);
                    p[(K, K + 1)] = T::lit(-1e-3);
                }
            }
        }
        if k % 3 == 1 {
            // Predictions prepared ahead are used up by the deferred run.
            assert_eq!(deferred.predict_ahead(), reference.predict_ahead());
        }
        let (m, mut s) = samples::<T>(k);
        // Outliers the gate rejects, in the first or the second row of a pair (the paper
        // filters fuse rows 0-1, 2-3, 4-5 in pairs), so that a pair also runs with one fused.
        match k % 7 {
            3 => s.angular_rate_rad_s.x += T::lit(0.5),
            5 => s.specific_force_m_s2.x += T::lit(5.0),
            6 => s.specific_force_m_s2.z += T::lit(5.0),
            _ => {}
        }
        let a = deferred.step_guarded(&m, &s, Guard::Deferred);
        let b = reference.step_guarded(&m, &s, Guard::PerUpdate);
        assert_eq!(a, b, "epoch {k}");
        assert_eq!(
            format!("{deferred:?}"),
            format!("{reference:?}"),
            "epoch {k}"
        );
        if let Ok(r) = a {
            skipped += r
                .updates
                .iter()
                .filter(|u| u.outcome == FusionOutcome::Skipped)
                .count();
            // Pairs of rows (the paper filters fuse them in pairs) with one rejected.
            rejected += r
                .updates
                .chunks(2)
                .filter(|pair| {
                    pair.iter()
                        .filter(|u| u.outcome == FusionOutcome::Rejected)
                        .count()
                        == 1
                })
                .count();
        }
    }
    assert_eq!(reference.reruns, 0);
    assert!(
        rejected > 0,
        "no pair of rows with one rejected by the gate"
    );
    (deferred.reruns, skipped)
}

#[test]
fn deferred_checks_give_the_per_update_result() {
    // Each filter refuses some updates after the covariance was made indefinite (the
    // fall-back to the per-update checks was taken), and agrees bit for bit throughout.
    let runs = [
        deferred_equals_per_update::<f32, 3, 9>(),
        deferred_equals_per_update::<f32, 4, 12>(),
        deferred_equals_per_update::<f32, 5, 15>(),
        deferred_equals_per_update::<f64, 4, 12>(),
        deferred_equals_per_update::<f64, 5, 15>(),
    ];
    for (reruns, skipped) in runs {
        assert!(reruns > 0 && skipped > 0, "{runs:?}");
    }
}

//! Transfer alignment at the edges of its envelope: the stalls, time-stamp refusals and
//! unbounded work that earlier versions showed on valid input, as regression tests (public API
//! only, f32 unless said otherwise).
use nalgebra::{SMatrix, Vector3};
use nav_core::math::kalman::{asymmetry, FusionOutcome};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::*;
use nav_core::{Estimator, HealthState, NavError, Real};

mod transfer_alignment_fixture;
use transfer_alignment_fixture::{filter, snapshot};

/// The paper's case 2 with one flexure model on every axis and the given rate and tolerances.
fn cfg<T: Real>(sigma_deg: f64, tau_s: f64, dt_s: f64, tol_s: f64, gap: u32) -> TaConfig<T> {
    let ax = AxisFlexure {
        sigma_rad: T::lit(sigma_deg.to_radians()),
        tau_s: T::lit(tau_s),
    };
    TaConfig {
        flexure: [ax; 3],
        rate_noise_sigma_rad_s: T::lit(3e-4),
        dt_s: T::lit(dt_s),
        time_tolerance_s: T::lit(tol_s),
        max_gap_steps: gap,
        ..TaConfig::paper(PaperCase::Case2)
    }
}

/// Constant, noise-free master and slave samples at `time` (level, at rest: ω = 0, f = −g).
fn still<T: Real>(time: Timestamp) -> (MasterSample<T>, SlaveSample<T>) {
    let f = Vector3::new(T::zero(), T::zero(), T::lit(-9.81));
    (
        MasterSample {
            time,
            angular_rate_rad_s: Vector3::zeros(),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: f,
        },
        SlaveSample {
            time,
            angular_rate_rad_s: Vector3::zeros(),
            specific_force_m_s2: f,
        },
    )
}

/// Smallest eigenvalue of the correlation matrix of P (f64), for a PSD check that does not
/// depend on the states' scales.
fn min_correlation_eigenvalue<const N: usize>(p: &SMatrix<f32, N, N>) -> f64 {
    let d: Vec<f64> = (0..N).map(|i| f64::from(p[(i, i)]).sqrt()).collect();
    let c = nalgebra::DMatrix::from_fn(N, N, |i, j| f64::from(p[(i, j)]) / (d[i] * d[j]));
    c.symmetric_eigen().eigenvalues.min()
}

fn runs_clean_at_500_hz<const K: usize, const N: usize>() {
    // The older filter refused step 1773 (proposed; the conventional one soon after) with
    // `InnovationVarianceNotPositive` and then every later step with `InvalidTimeStep`.
    let mut f = filter::<f32, K, N>(cfg(0.5, 2.146, 0.002, 0.0008, 3)).unwrap();
    for k in 0..20_000u64 {
        let t = Timestamp::from_micros(2_000 * k);
        let (m, s) = still::<f32>(t);
        let rep = f.step(&m, &s).unwrap_or_else(|e| panic!("step {k}: {e:?}"));
        assert_eq!(f.time(), Some(t));
        assert!(rep
            .updates
            .iter()
            .all(|u| u.outcome == FusionOutcome::Fused));
        if k % 100 == 0 {
            let p = f.covariance();
            assert_eq!(asymmetry(&p), 0.0);
            let e = min_correlation_eigenvalue(&p);
            assert!(e > -1e-4, "step {k}: correlation eigenvalue {e}");
        }
    }
    assert_eq!(f.health().state, HealthState::Nominal);
}

/// A stall the older filter showed: 500 Hz, σ = 0.5°, τ = 2.146 s, constant noise-free inputs.
#[test]
fn constant_inputs_at_500_hz_do_not_stall() {
    runs_clean_at_500_hz::<4, 12>();
    runs_clean_at_500_hz::<3, 9>();
}

/// Refused (invalid) samples never freeze the clock. The
/// older filter did not advance its clock on a refusal, so after `max_gap_steps` refused
/// samples every later valid one was off its grid for good.
#[test]
fn refused_samples_do_not_stop_later_valid_ones() {
    let mut f = filter::<f32, 4, 12>(cfg(0.5, 2.146, 0.002, 0.0008, 3)).unwrap();
    let mut k = 0u64;
    let t = |k: u64| Timestamp::from_micros(2_000 * k);
    while k < 100 {
        let (m, s) = still::<f32>(t(k));
        f.step(&m, &s).unwrap();
        k += 1;
    }
    // Ten invalid samples in a row (NaN specific force): refused, filter unchanged but for
    // the count of refusals.
    for j in 0..10 {
        let (m, mut s) = still::<f32>(t(k));
        s.specific_force_m_s2.x = f32::NAN;
        let before = snapshot(&f);
        assert!(matches!(
            f.step(&m, &s),
            Err(NavError::NonFiniteInput { .. })
        ));
        assert_eq!(snapshot(&f), before);
        assert_eq!(f.health().imu_refused, j + 1);
        k += 1;
    }
    // The next valid sample is 11 steps after the last accepted one (> max_gap_steps): the
    // flexure is re-initialised, θ_m kept, and the filter runs on.
    let theta_m = f.theta_m();
    let (m, s) = still::<f32>(t(k));
    let rep = f.step(&m, &s).unwrap();
    assert_eq!(rep.gap, GapOutcome::FlexureReinitialised);
    assert_eq!(f.theta_m(), theta_m);
    assert_eq!(f.health().state, HealthState::Degraded);
    for j in 1..=200 {
        let (m, s) = still::<f32>(t(k + j));
        assert_eq!(f.step(&m, &s).unwrap().predictions, 1);
    }
    assert_eq!(f.health().state, HealthState::Nominal);
    assert_eq!(f.health().gaps_reset, 1);
}

/// f32 time stamps (the older filter's): At 100 Hz with a 1e-4 s tolerance the older filter
/// (stamps in f32 seconds) refused almost every step beyond t ≈ 4000 s, and 999 of 1000 beyond
/// 10⁶ s even with the largest tolerance. Integer-µs stamps: every step is one prediction.
#[test]
fn stamps_past_a_million_seconds_are_exact() {
    let mut f = filter::<f32, 4, 12>(cfg(0.5, 2.146, 0.01, 1e-4, 3)).unwrap();
    let start = 1_000_000 * 1_000_000u64;
    for k in 0..1000u64 {
        let t = Timestamp::from_micros(start + 10_000 * k);
        let (m, s) = still::<f32>(t);
        let rep = f.step(&m, &s).unwrap();
        assert_eq!(rep.predictions, u32::from(k > 0));
        assert_eq!(f.grid_time(), Some(t));
    }
}

/// Real time stamps: jitter (intervals 0.5-1.5 dt), late and missing samples are taken as
/// they come; the grid stays within dt/2 of the stamps and never drifts.
#[test]
fn jittered_stamps_are_taken_as_they_come() {
    let mut f = filter::<f32, 3, 9>(cfg(0.5, 2.146, 0.001, 1e-4, 5)).unwrap();
    let mut now = 3_600_000_000u64;
    let mut lcg = 12345u64;
    let mut predictions = 0u64;
    for _ in 0..20_000 {
        lcg = lcg
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        let interval = 500 + (lcg >> 33) % 1001; // 0.5-1.5 ms
        now += interval;
        let (m, s) = still::<f32>(Timestamp::from_micros(now));
        let rep = f.step(&m, &s).unwrap();
        assert!(rep.predictions <= 2);
        predictions += u64::from(rep.predictions);
        let grid = f.grid_time().unwrap().as_micros();
        assert!(grid.abs_diff(now) <= 500, "{grid} vs {now}");
    }
    // One prediction per elapsed millisecond, in all.
    let elapsed_ms = (f.grid_time().unwrap().as_micros() - 3_600_000_000) / 1_000;
    assert!(predictions.abs_diff(elapsed_ms) <= 1);
}

/// `max_gap_steps` had no upper limit (u32::MAX: one step over a
/// 20 000 s gap ran 2 million predictions). Now it is bounded by `MAX_GAP_STEPS`, and a longer
/// gap costs no prediction at all.
#[test]
fn max_gap_steps_is_bounded_and_long_gaps_cost_nothing() {
    for gap in [0, MAX_GAP_STEPS + 1, u32::MAX] {
        assert!(matches!(
            filter::<f32, 4, 12>(cfg(0.5, 2.146, 0.01, 1e-3, gap)),
            Err(NavError::InvalidConfig {
                field: "max_gap_steps",
                ..
            })
        ));
    }
    let mut f = filter::<f64, 4, 12>(cfg(0.5, 2.146, 0.01, 1e-3, MAX_GAP_STEPS)).unwrap();
    for k in 0..300u64 {
        let (m, s) = still::<f64>(Timestamp::from_micros(10_000 * k));
        f.step(&m, &s).unwrap();
    }
    // A gap of exactly the bound is predicted step by step.
    let (m, s) = still::<f64>(Timestamp::from_micros(
        10_000 * (299 + u64::from(MAX_GAP_STEPS)),
    ));
    let rep = f.step(&m, &s).unwrap();
    assert_eq!(
        (rep.predictions, rep.gap),
        (MAX_GAP_STEPS, GapOutcome::Predicted)
    );
    // 20 000 s later: no prediction, flexure re-initialised, θ_m and its σ kept (grown).
    let theta_m = f.theta_m();
    let var_m = f.theta_m_covariance();
    let t = f.time().unwrap().add_micros(20_000 * 1_000_000);
    let p = f.propagate(t).unwrap();
    assert_eq!(
        (p.predictions, p.gap),
        (0, GapOutcome::FlexureReinitialised)
    );
    assert!((f.theta_m() - theta_m).norm() < 1e-15);
    assert_eq!(f.theta_f(), Vector3::zeros());
    let var_f = (0.5_f64.to_radians()).powi(2);
    for a in 0..3 {
        let grown = f.theta_m_covariance()[(a, a)];
        assert!(grown >= var_m[(a, a)], "axis {a}");
        assert!(grown <= var_m[(a, a)] + var_f * (1.0 + 1e-9), "axis {a}");
    }
    assert_eq!(f.health().gaps_reset, 1);
    assert_eq!(f.health().state, HealthState::Degraded);
}

/// The documented way back: `reinitialise` restarts from what the caller hands over (here the
/// filter's own θ_m), with the prior covariance, and the filter returns to `Nominal` after the
/// hold.
#[test]
fn reinitialise_restarts_from_the_handed_over_misalignment() {
    let mut f = filter::<f32, 4, 12>(cfg(0.5, 2.146, 0.01, 1e-3, 3)).unwrap();
    let sigma0 = f.theta_sigma_rad();
    assert_eq!(f.health().state, HealthState::Initialising);
    // A 0.2° roll misalignment of the slave: f_s = f − θ × f.
    let th = Vector3::new(0.2_f32.to_radians(), 0.0, 0.0);
    for k in 0..500u64 {
        let (m, mut s) = still::<f32>(Timestamp::from_micros(10_000 * k));
        s.specific_force_m_s2 -= th.cross(&m.specific_force_m_s2);
        f.step(&m, &s).unwrap();
    }
    assert_eq!(f.health().state, HealthState::Nominal);
    assert!((f.theta().x - th.x).abs() < 1e-4, "{}", f.theta());
    let theta_m = f.theta_m();
    f.reinitialise(&TaInitial {
        mount_misalignment_rad: theta_m,
    })
    .unwrap();
    assert_eq!(f.theta_m(), theta_m);
    assert_eq!(f.theta_f(), Vector3::zeros());
    assert_eq!(f.theta_sigma_rad(), sigma0);
    assert_eq!(f.health().state, HealthState::Degraded);
    assert_eq!(f.health().reinitialisations, 1);
    for k in 500..(500 + u64::from(DEGRADED_HOLD_EPOCHS)) {
        let (m, mut s) = still::<f32>(Timestamp::from_micros(10_000 * k));
        s.specific_force_m_s2 -= th.cross(&m.specific_force_m_s2);
        f.step(&m, &s).unwrap();
    }
    assert_eq!(f.health().state, HealthState::Nominal);
    assert!((f.theta().x - th.x).abs() < 1e-4, "{}", f.theta());
}

/// The envelope is explicit: σ, τ, dt and the noise σ outside their ranges are refused naming
/// the field.
#[test]
fn envelope_is_validated() {
    let field = |c: TaConfig<f32>| match filter::<f32, 4, 12>(c).map(|_| ()) {
        Err(NavError::InvalidConfig { field, .. }) => field,
        other => panic!("{other:?}"),
    };
    assert_eq!(field(cfg(0.5, 0.04, 0.001, 0.0, 3)), "flexure.tau_s");
    assert_eq!(field(cfg(0.5, 2.0e4, 0.001, 0.0, 3)), "flexure.tau_s");
    assert_eq!(field(cfg(3.0, 2.0, 0.001, 0.0, 3)), "flexure.sigma_rad");
    assert_eq!(field(cfg(0.005, 2.0, 0.001, 0.0, 3)), "flexure.sigma_rad");
    assert_eq!(field(cfg(0.5, 2.0, 0.02, 0.0, 3)), "dt_s");
    assert_eq!(field(cfg(0.5, 2.0, 0.000_5, 0.0, 3)), "dt_s");
    assert_eq!(field(cfg(0.5, 2.0, 0.001_000_4, 0.0, 3)), "dt_s");
    assert_eq!(field(cfg(0.5, 2.0, 0.001, 0.000_5, 3)), "time_tolerance_s");
    let mut c = cfg::<f32>(0.5, 2.0, 0.001, 0.0, 3);
    c.rate_noise_sigma_rad_s = 1e-5;
    assert_eq!(field(c), "rate_noise_sigma_rad_s");
    let mut c = cfg::<f32>(0.5, 2.0, 0.001, 0.0, 3);
    c.lever_arm_m.y = 500.0;
    assert_eq!(field(c), "lever_arm_m");
    // The corners of the envelope are accepted.
    for (sigma, tau, dt) in [(0.01, 0.05, 0.01), (2.0, 1.0e4, 0.001), (2.0, 0.05, 0.01)] {
        assert!(filter::<f32, 4, 12>(cfg(sigma, tau, dt, 0.0, MAX_GAP_STEPS)).is_ok());
        assert!(filter::<f32, 3, 9>(cfg(sigma, tau, dt, 0.0, 1)).is_ok());
    }
}

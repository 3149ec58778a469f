//! Transfer alignment under random configurations and inputs: property tests (f32 and f64), bad
//! input refused without damage, χ² gate counters and the covariance-reset recovery, soak,
//! fault-transfer recovery.
use nalgebra::{SMatrix, Vector3};
use nav_core::math::kalman::{asymmetry, is_psd, FusionOutcome};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::*;
use nav_core::{Estimator, Gate, NavError, Real, RecoveryAction, RecoveryPolicy};
use proptest::prelude::*;

mod transfer_alignment_fixture;
use transfer_alignment_fixture::{filter, snapshot};

/// The paper's case 2 with the given flexure, lever arm and gate.
fn cfg<T: Real>(sig: [f64; 3], tau: [f64; 3], lever: [f64; 3], gate: Option<f64>) -> TaConfig<T> {
    let ax = |i: usize| AxisFlexure {
        sigma_rad: T::lit(sig[i]),
        tau_s: T::lit(tau[i]),
    };
    TaConfig {
        lever_arm_m: Vector3::from(lever).map(T::lit),
        flexure: [ax(0), ax(1), ax(2)],
        rate_noise_sigma_rad_s: T::lit(3e-4),
        time_tolerance_s: T::lit(0.004),
        max_gap_steps: 3,
        gate: gate.map_or(Gate::Off, |g| Gate::Nis(T::lit(g))),
        ..TaConfig::paper(PaperCase::Case2)
    }
}

/// Deterministic pseudo-random inputs: step k of a sequence with a manoeuvre amplitude.
fn inputs<T: Real>(k: u64, seed: u64, amp: f64) -> (MasterSample<T>, SlaveSample<T>) {
    let h = |i: u64| {
        let x = (seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(k * 31 + i)) as f64;
        (x * 0.618_033_988_75).sin()
    };
    let w = Vector3::new(amp * 0.5 * h(1), amp * 0.5 * h(2), amp * 0.3 * h(3));
    let f = Vector3::new(
        amp * 10.0 * h(4),
        amp * 10.0 * h(5),
        -9.8 + amp * 10.0 * h(6),
    );
    let theta = Vector3::new(0.004, -0.003, 0.002) + Vector3::new(h(7), h(8), h(9)) * 1e-3;
    let v = |x: Vector3<f64>| x.map(T::lit);
    let m = MasterSample {
        time: Timestamp::from_micros(k * 10_000),
        angular_rate_rad_s: v(w),
        angular_accel_rad_s2: v(Vector3::new(h(10), h(11), h(12)) * amp * 5.0),
        specific_force_m_s2: v(f),
    };
    let s = SlaveSample {
        time: Timestamp::from_micros(k * 10_000),
        angular_rate_rad_s: v(w - theta.cross(&w) + Vector3::new(h(13), h(14), h(15)) * 3e-4),
        specific_force_m_s2: v(f - theta.cross(&f) + Vector3::new(h(16), h(17), h(18)) * 5e-3),
    };
    (m, s)
}

/// Runs `steps` steps and checks P symmetric PSD, finite outputs and variance bounds at every
/// step: θ_m variance ≤ its initial σ_m², flexure variances ≤ 1.01 × their stationary values
/// (measurements only reduce variance, the flexure process is stationary).
fn healthy_run<T: Real, const K: usize, const N: usize>(
    c: TaConfig<T>,
    steps: u64,
    seed: u64,
    amp: f64,
) where
    nalgebra::Const<N>: nalgebra::DimMin<nalgebra::Const<N>, Output = nalgebra::Const<N>>,
{
    let mut f = filter::<T, K, N>(c).unwrap();
    let p0: SMatrix<T, N, N> = f.covariance();
    for k in 0..steps {
        let (m, s) = inputs::<T>(k, seed, amp);
        f.step(&m, &s).unwrap();
        let p = f.covariance();
        assert_eq!(asymmetry(&p), T::zero());
        assert!(is_psd(&p, T::lit(1e-5)), "P not PSD at step {k}");
        for i in 0..N {
            assert!(
                p[(i, i)] <= p0[(i, i)] * T::lit(1.01) + T::lit(1e-12),
                "variance {i} above bound at {k}"
            );
        }
        assert!(f.theta().iter().all(|v| v.is_finite()));
        assert!(f.state().iter().all(|v| v.is_finite()));
    }
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 12, .. ProptestConfig::default() })]
    #[test]
    fn random_configs_and_inputs_stay_healthy(
        sx in 0.05f64..1.0, sy in 0.05f64..1.0, sz in 0.05f64..1.0,
        tx in 0.3f64..5.0, ty in 0.3f64..5.0, tz in 0.3f64..5.0,
        lx in -3.0f64..3.0, ly in 0.5f64..10.0,
        amp in 0.0f64..3.0, seed in any::<u64>(), gated in any::<bool>(),
    ) {
        let sig = [sx.to_radians(), sy.to_radians(), sz.to_radians()];
        let gate = gated.then_some(25.0);
        healthy_run::<f64, 4, 12>(cfg(sig, [tx, ty, tz], [lx, ly, 0.0], gate), 400, seed, amp);
        healthy_run::<f32, 4, 12>(cfg(sig, [tx, ty, tz], [lx, ly, 0.0], gate), 400, seed, amp);
        healthy_run::<f64, 3, 9>(cfg(sig, [tx, ty, tz], [lx, ly, 0.0], gate), 400, seed, amp);
        healthy_run::<f32, 3, 9>(cfg(sig, [tx, ty, tz], [lx, ly, 0.0], gate), 400, seed, amp);
    }
}

#[test]
fn extreme_legal_dynamics_long_run() {
    let sig = [
        1.0_f64.to_radians(),
        0.5_f64.to_radians(),
        0.5_f64.to_radians(),
    ];
    // 30 rad/s rates, 300 m/s² specific force, 3000 steps.
    healthy_run::<f32, 4, 12>(
        cfg(sig, [0.2, 0.2, 0.2], [0.0, 5.0, 0.0], Some(25.0)),
        3000,
        7,
        60.0,
    );
    healthy_run::<f64, 3, 9>(
        cfg(sig, [0.2, 0.2, 0.2], [0.0, 5.0, 0.0], None),
        3000,
        7,
        60.0,
    );
}

/// f32 and f64 on the same 5000 inputs: θ agrees within 1e-4 rad (0.1 mrad) and the θ σ within
/// 2 % over the whole run.
#[test]
fn f32_matches_f64_over_a_long_run() {
    let sig = [
        0.5_f64.to_radians(),
        0.1_f64.to_radians(),
        0.1_f64.to_radians(),
    ];
    let mut a =
        filter::<f32, 4, 12>(cfg(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0))).unwrap();
    let mut b =
        filter::<f64, 4, 12>(cfg(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0))).unwrap();
    let mut worst = 0.0_f64;
    for k in 0..5000 {
        let (m, s) = inputs::<f32>(k, 11, 1.0);
        let (m64, s64) = inputs::<f64>(k, 11, 1.0);
        a.step(&m, &s).unwrap();
        b.step(&m64, &s64).unwrap();
        let d = (a.theta().map(f64::from) - b.theta()).abs().max();
        worst = worst.max(d);
        let sa = a.theta_sigma_rad().map(f64::from);
        let sb = b.theta_sigma_rad();
        for i in 0..3 {
            assert!(
                (sa[i] - sb[i]).abs() <= 0.02 * sb[i] + 1e-7,
                "σ {i} at {k}: {} vs {}",
                sa[i],
                sb[i]
            );
        }
    }
    assert!(worst < 1e-4, "largest θ difference {worst} rad");
}

fn refused<T: Real, const K: usize, const N: usize>(
    f: &mut TransferAlignment<T, K, N>,
    m: &MasterSample<T>,
    s: &SlaveSample<T>,
) -> NavError {
    let before = snapshot(f);
    let refusals = f.health().imu_refused;
    let e = f.step(m, s).unwrap_err();
    assert_eq!(
        snapshot(f),
        before,
        "state changed by a refused step ({e:?})"
    );
    assert_eq!(f.health().imu_refused, refusals + 1, "refusal not counted");
    e
}

fn bad_inputs<T: Real, const K: usize, const N: usize>() {
    let sig = [
        0.5_f64.to_radians(),
        0.1_f64.to_radians(),
        0.1_f64.to_radians(),
    ];
    let mut f =
        filter::<T, K, N>(cfg(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0))).unwrap();
    for k in 0..5 {
        let (m, s) = inputs::<T>(k, 3, 1.0);
        f.step(&m, &s).unwrap();
    }
    let (m, s) = inputs::<T>(5, 3, 1.0);
    let specials = [f64::NAN, f64::INFINITY, f64::NEG_INFINITY, 1e30, -1e30];
    // Refused as non-finite or out of range (and nothing changed, `refused`).
    let mut non_finite = |mm: &MasterSample<T>, ss: &SlaveSample<T>| {
        let e = refused(&mut f, mm, ss);
        assert!(
            matches!(
                e,
                NavError::NonFiniteInput { .. } | NavError::InputOutOfRange { .. }
            ),
            "{e:?}"
        );
    };
    for &v in &specials {
        let x = T::lit(v);
        for c in 0..3 {
            let mut mm = m;
            mm.angular_rate_rad_s[c] = x;
            non_finite(&mm, &s);
            let mut mm = m;
            mm.angular_accel_rad_s2[c] = x;
            non_finite(&mm, &s);
            let mut mm = m;
            mm.specific_force_m_s2[c] = x;
            non_finite(&mm, &s);
            let mut ss = s;
            ss.angular_rate_rad_s[c] = x;
            non_finite(&m, &ss);
            let mut ss = s;
            ss.specific_force_m_s2[c] = x;
            non_finite(&m, &ss);
        }
    }
    // Repeating, backwards, master/slave out of sync (any later stamp is valid: jitter and
    // gaps are taken as they come).
    let (m4, s4) = inputs::<T>(4, 3, 1.0);
    assert_eq!(refused(&mut f, &m4, &s4), NavError::TimeNotIncreasing);
    let (m0, s0) = inputs::<T>(0, 3, 1.0);
    assert_eq!(refused(&mut f, &m0, &s0), NavError::TimeNotIncreasing);
    let mut ms = m;
    ms.time = Timestamp::from_micros(30_000);
    assert_eq!(
        refused(&mut f, &ms, &s),
        NavError::MeasurementTimeOutOfWindow
    );
    // Propagation: bad times are refused without damage too.
    for t in [0, 40_000] {
        let before = snapshot(&f);
        assert!(f.propagate(Timestamp::from_micros(t)).is_err());
        assert_eq!(snapshot(&f), before);
    }
    // Master data older than the slave history can match.
    let mut hist = SlaveHistory::<T, 4>::new();
    for k in 5..12 {
        hist.push(&inputs::<T>(k, 3, 1.0).1).unwrap();
    }
    let (m_old, _) = inputs::<T>(6, 3, 1.0); // history holds 8..11
    let before = snapshot(&f);
    let refusals = f.health().imu_refused;
    assert_eq!(
        f.step_delayed(&m_old, &hist).unwrap_err(),
        NavError::MeasurementTimeOutOfWindow
    );
    let (m_new, _) = inputs::<T>(12, 3, 1.0);
    assert_eq!(
        f.step_delayed(&m_new, &hist).unwrap_err(),
        NavError::MeasurementTimeOutOfWindow
    );
    assert_eq!(snapshot(&f), before);
    assert_eq!(f.health().imu_refused, refusals + 2);
    // History refuses repeated / backwards / NaN slave samples without damage.
    let hb = hist.clone();
    assert_eq!(
        hist.push(&inputs::<T>(11, 3, 1.0).1),
        Err(NavError::TimeNotIncreasing)
    );
    let mut sn = inputs::<T>(12, 3, 1.0).1;
    sn.specific_force_m_s2.y = T::lit(f64::NAN);
    assert!(hist.push(&sn).is_err());
    assert_eq!(hist, hb);
    // The state is still usable: the next valid epoch (gap of 1 step) is processed.
    let (m5, s5) = inputs::<T>(5, 3, 1.0);
    assert_eq!(f.step(&m5, &s5).unwrap().predictions, 1);
}

#[test]
fn bad_input_is_refused_and_changes_nothing_f32_f64() {
    bad_inputs::<f32, 4, 12>();
    bad_inputs::<f64, 4, 12>();
    bad_inputs::<f32, 3, 9>();
    bad_inputs::<f64, 3, 9>();
}

fn bad_configs<T: Real, const K: usize, const N: usize>() {
    let sig = [
        0.5_f64.to_radians(),
        0.1_f64.to_radians(),
        0.1_f64.to_radians(),
    ];
    let ok = cfg::<T>(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0));
    assert!(filter::<T, K, N>(ok).is_ok());
    let bads = [0.0, -1.0, f64::NAN, f64::INFINITY, f64::NEG_INFINITY];
    type Setter<T> = fn(&mut TaConfig<T>, T);
    let fields: [(&str, Setter<T>); 12] = [
        ("flexure.sigma_rad", |c, v| c.flexure[0].sigma_rad = v),
        ("flexure.tau_s", |c, v| c.flexure[1].tau_s = v),
        ("flexure.sigma_rad", |c, v| c.flexure[2].sigma_rad = v),
        ("rate_noise_sigma_rad_s", |c, v| {
            c.rate_noise_sigma_rad_s = v
        }),
        ("accel_noise_sigma_m_s2", |c, v| {
            c.accel_noise_sigma_m_s2 = v
        }),
        ("dt_s", |c, v| c.dt_s = v),
        ("gate", |c, v| c.gate = Gate::Nis(v)),
        ("recovery.starved_after_s", |c, v| {
            c.recovery.starved_after_s = Some(v)
        }),
        ("mount_sigma_rad", |c, v| c.mount_sigma_rad.y = v),
        ("time_tolerance_s", |c, v| c.time_tolerance_s = v),
        ("lever_arm_m", |c, v| c.lever_arm_m.x = v),
        ("flexure.tau_s", |c, v| c.flexure[0].tau_s = v),
    ];
    for (name, set) in fields {
        for &b in &bads {
            // Zero is legal for the mounting σ, time tolerance and lever arm.
            if b == 0.0 && matches!(name, "mount_sigma_rad" | "time_tolerance_s" | "lever_arm_m") {
                continue;
            }
            if b == -1.0 && name == "lever_arm_m" {
                continue;
            }
            let mut c = ok;
            set(&mut c, T::lit(b));
            let e = filter::<T, K, N>(c).unwrap_err();
            assert!(
                matches!(e, NavError::InvalidConfig { .. }),
                "{name} = {b}: {e:?}"
            );
        }
    }
    // Huge values that would overflow R or P.
    let mut c = ok;
    c.accel_noise_sigma_m_s2 = T::lit(1e30);
    assert!(matches!(
        filter::<T, K, N>(c),
        Err(NavError::InvalidConfig {
            field: "accel_noise_sigma_m_s2",
            ..
        })
    ));
    let mut c = ok;
    c.rate_noise_sigma_rad_s = T::lit(1e30);
    assert!(matches!(
        filter::<T, K, N>(c),
        Err(NavError::InvalidConfig {
            field: "rate_noise_sigma_rad_s",
            ..
        })
    ));
    let mut c = ok;
    c.max_gap_steps = 0;
    assert!(filter::<T, K, N>(c).is_err());
    let mut f = filter::<T, K, N>(ok).unwrap();
    // The run-time setters refuse what the configuration refuses, changing nothing.
    let before = format!("{f:?}");
    let zero = RecoveryPolicy {
        starved_after_s: Some(T::zero()),
        action: RecoveryAction::ResetToPrior,
    };
    assert!(f.set_recovery(zero).is_err());
    let inflate = RecoveryPolicy {
        action: RecoveryAction::Inflate {
            variance_factor: T::lit(2.0),
        },
        ..zero
    };
    assert!(f.set_recovery(inflate).is_err());
    assert!(f.set_gate(Gate::Nis(T::lit(f64::NAN))).is_err());
    assert_eq!(format!("{f:?}"), before);
}

#[test]
fn every_config_field_is_validated_f32_f64() {
    bad_configs::<f32, 4, 12>();
    bad_configs::<f64, 3, 9>();
}

/// A persistent fault the gate rejects (a 1 m/s² offset on the slave X accelerometer) starves
/// df_X: rejections are counted and after 0.5 s of them (50 epochs at 100 Hz, the default
/// policy) the covariance is reset, then the filter keeps running healthy.
fn gate_and_recovery<T: Real, const K: usize, const N: usize>()
where
    nalgebra::Const<N>: nalgebra::DimMin<nalgebra::Const<N>, Output = nalgebra::Const<N>>,
{
    let sig = [
        0.5_f64.to_radians(),
        0.1_f64.to_radians(),
        0.1_f64.to_radians(),
    ];
    let mut f =
        filter::<T, K, N>(cfg(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0))).unwrap();
    for k in 0..300 {
        let (m, s) = inputs::<T>(k, 5, 0.3);
        f.step(&m, &s).unwrap();
    }
    let h0 = f.aid_counters(Channel::ForceX);
    let mut rejected_df_x = 0;
    for k in 300..400 {
        let (m, mut s) = inputs::<T>(k, 5, 0.3);
        s.specific_force_m_s2.x += T::lit(1.0);
        let rep = f.step(&m, &s).unwrap();
        if rep.updates[3].outcome == FusionOutcome::Rejected {
            rejected_df_x += 1;
        }
        assert!(is_psd(&f.covariance(), T::lit(1e-5)));
    }
    let h = f.aid_counters(Channel::ForceX);
    assert!(rejected_df_x >= 50, "{rejected_df_x}");
    assert_eq!(h.rejected - h0.rejected, rejected_df_x);
    assert!(h.recoveries >= 1);
    assert_eq!(f.aid_counters(Channel::RateX).recoveries, 0);
    // Without a recovery policy, no reset.
    let mut g =
        filter::<T, K, N>(cfg(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0))).unwrap();
    g.set_recovery(RecoveryPolicy {
        starved_after_s: None,
        action: RecoveryAction::ResetToPrior,
    })
    .unwrap();
    for k in 0..400 {
        let (m, mut s) = inputs::<T>(k, 5, 0.3);
        if k >= 300 {
            s.specific_force_m_s2.x += T::lit(1.0);
        }
        g.step(&m, &s).unwrap();
    }
    assert_eq!(g.aid_counters(Channel::ForceX).recoveries, 0);
    assert!(g.aid_counters(Channel::ForceX).consecutive_rejected >= 50);
}

#[test]
fn gate_counts_rejections_and_resets_when_starved_f32_f64() {
    gate_and_recovery::<f32, 4, 12>();
    gate_and_recovery::<f64, 3, 9>();
}

/// f32 soak: `NAV_SOAK_STEPS` steps (default 20 000) of random valid inputs with dropouts
/// bridged by `propagate`: no error, no NaN, P symmetric, PSD and bounded.
#[test]
fn soak_f32() {
    let steps: u64 = std::env::var("NAV_SOAK_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(20_000);
    let sig = [
        0.5_f64.to_radians(),
        0.1_f64.to_radians(),
        0.1_f64.to_radians(),
    ];
    let mut c = cfg::<f32>(sig, [0.358, 2.146, 2.146], [0.0, 5.0, 0.0], Some(25.0));
    // f32 time stamps up to 10⁴ s have a 1 ms ulp: the tolerance must cover it.
    c.time_tolerance_s = 0.004;
    let mut a = filter::<f32, 4, 12>(c).unwrap();
    let mut b = filter::<f32, 3, 9>(c).unwrap();
    let p0a = a.covariance();
    let p0b = b.covariance();
    for k in 0..steps {
        let (m, s) = inputs::<f32>(k, 99, if (k / 1000) % 2 == 0 { 0.2 } else { 2.0 });
        if k % 997 < 3 && k > 10 {
            a.propagate(s.time).unwrap();
            b.propagate(s.time).unwrap();
        } else {
            a.step(&m, &s).unwrap();
            b.step(&m, &s).unwrap();
        }
        if k % 500 == 0 || k + 1 == steps {
            let (pa, pb) = (a.covariance(), b.covariance());
            assert!(is_psd(&pa, 1e-5) && is_psd(&pb, 1e-5), "P not PSD at {k}");
            assert_eq!(asymmetry(&pa), 0.0);
            for i in 0..12 {
                assert!(pa[(i, i)] <= p0a[(i, i)] * 1.01);
            }
            for i in 0..9 {
                assert!(pb[(i, i)] <= p0b[(i, i)] * 1.01);
            }
            assert!(a
                .theta()
                .iter()
                .chain(b.theta().iter())
                .all(|v| v.is_finite()));
        }
    }
}

/// fault-transfer at a reduced run count: 50 ms latency matched through the slave history
/// (nothing unmatched, no step error) and recovery after the first 1 s dropout, which is
/// followed by a manoeuvre.
#[test]
fn fault_transfer_recovers() {
    use nav_sim::scenarios::transfer_alignment::fault::{analyse, FaultConfig};
    let (cfg, _, seed): (FaultConfig, usize, u64) =
        nav_sim::scenarios::transfer_alignment::config::load_scenario("fault-transfer").unwrap();
    let (summary, _, rms, _, _) = analyse(&cfg, 4, seed, false).unwrap();
    assert_eq!(summary["step_errors"], 0);
    assert_eq!(summary["unmatched_master_samples"], 0);
    assert!(summary["propagation_only_epochs"].as_u64().unwrap() >= 4 * 2 * 100);
    let first = &summary["recoveries"][0];
    assert_eq!(first["recovered"], true, "{summary}");
    assert!(first["recovery_time_s"].as_f64().unwrap() < 5.0);
    // The dropout really hurt (peak well above the bound) and the end is back near it.
    assert!(
        first["peak_mrad"].as_f64().unwrap()
            > 3.0 * first["pre_fault_bound_mrad"].as_f64().unwrap()
    );
    assert!(rms.last().unwrap().is_finite());
}

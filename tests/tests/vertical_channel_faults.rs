//! Vertical channel fault injection: the `fault-baro` scenario at a reduced run
//! count — the gate rejects the spike and the frozen baro, both loops re-acquire after the
//! dropout and return within their pre-fault error bound — and the soak test (`NAV_SOAK_STEPS`).

use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    Aid, AidModel, AidStatus, AidedLoop, BaroSample, ClassicalLoop, ImuSample, InitialState,
    Reacquisition, VelocitySample,
};
use nav_core::{
    Estimator, FusionOutcome, Gate, HealthState, NavError, Real, RecoveryAction, RecoveryPolicy,
};
use nav_sim::rng::{normal, run_rng};
use nav_sim::scenarios::vertical_channel::{load_config, loop_configs};
use nav_sim::scenarios::vertical_channel_faults::{
    load_fault_config, recovery, run_monte_carlo, summarise, Summary as Value,
};

const RUNS: usize = 6;

/// A gate of these tests: χ² `threshold` on the aid model, re-anchoring after 60 s of
/// rejections.
struct Gating<T> {
    aid_model: AidModel<T>,
    gate: Gate<T>,
    recovery: RecoveryPolicy<T>,
}

impl<T: Real> Gating<T> {
    /// σ₀ of the baro (m) and velocity (m/s), re-inflation σ_v0 = 0.5 m/s and `sigma_a0`.
    fn new(threshold: f64, baro_sigma_m: f64, velocity_sigma_m_s: f64, sigma_a0: f64) -> Self {
        Self {
            aid_model: AidModel {
                baro_sigma_m: T::lit(baro_sigma_m),
                velocity_sigma_m_s: T::lit(velocity_sigma_m_s),
                starved_velocity_sigma_m_s: T::lit(0.5),
                starved_accel_sigma_m_s2: T::lit(sigma_a0),
                recovery_hold_s: T::lit(60.0),
            },
            gate: Gate::Nis(T::lit(threshold)),
            recovery: RecoveryPolicy {
                starved_after_s: Some(T::lit(60.0)),
                action: RecoveryAction::Reanchor,
            },
        }
    }
    fn classical(&self, lp: &mut ClassicalLoop<T>) -> Result<(), NavError> {
        lp.set_aid_model(self.aid_model)?;
        lp.set_recovery(self.recovery)?;
        lp.set_gate(self.gate)
    }
    fn aided(&self, lp: &mut AidedLoop<T>) -> Result<(), NavError> {
        lp.set_aid_model(self.aid_model)?;
        lp.set_recovery(self.recovery)?;
        lp.set_gate(self.gate)
    }
}

fn ts(seconds: f64) -> Timestamp {
    Timestamp::from_secs_f64(seconds).unwrap()
}

fn get<'a>(v: &'a Value, path: &[&str]) -> &'a Value {
    path.iter().fold(v, |v, k| &v[*k])
}

fn num(v: &Value, path: &[&str]) -> f64 {
    get(v, path)
        .as_f64()
        .unwrap_or_else(|| panic!("{path:?} missing in {v}"))
}

#[test]
fn fault_baro_gate_rejects_spike_and_frozen_and_loops_recover() {
    let fc = load_fault_config("fault-baro").unwrap();
    let (runs, dt) = run_monte_carlo(&fc, RUNS, 99, false).unwrap();
    let s = summarise(&runs, dt, &fc);
    let frozen_samples = (fc.frozen.end_s - fc.frozen.start_s) * 25.0;
    for lp in ["classical", "aided"] {
        let gated = &s[format!("{lp}_gated")];
        let twin = &s[format!("{lp}_gated_fault_free_twin")];
        let ungated = &s[format!("{lp}_ungated")];
        // Every frozen sample that departs from the inertial solution is rejected (the first
        // few, while the climb has not yet moved the truth away, may pass), and the spike.
        let rej = num(gated, &["baro_gate_mean_per_run", "rejected"]);
        assert!(rej >= frozen_samples - 25.0, "{lp}: {rej} rejections");
        assert!(num(gated, &["baro_gate_mean_per_run", "reacquisitions"]) >= 2.0);
        // The spike changes nothing: peak error as in the fault-free twin.
        let p = num(gated, &["faults", "spike", "peak_abs_error_m", "max"]);
        let p0 = num(twin, &["faults", "spike", "peak_abs_error_m", "max"]);
        assert!(p <= p0 + 0.5, "{lp}: spike peak {p} vs twin {p0}");
        // Frozen baro and dropout: the gated error stays within a few metres of normal, while
        // without the gate the frozen baro drags the loop hundreds of metres off.
        for f in ["frozen", "dropout"] {
            let p = num(gated, &["faults", f, "peak_abs_error_m", "max"]);
            let p0 = num(twin, &["faults", f, "peak_abs_error_m", "max"]);
            assert!(p <= p0 + 15.0, "{lp} {f}: peak {p} vs twin {p0}");
        }
        let pu = num(ungated, &["faults", "frozen", "peak_abs_error_m", "max"]);
        assert!(pu > 300.0, "{lp}: ungated frozen peak {pu}");
        // Recovery: after every fault the gated loop returns within its pre-fault bound in as
        // many runs as the fault-free twin does (the twin shows what the baro's own correlated
        // error allows). The recovery times are reported in the summary (README).
        for f in ["spike", "frozen", "dropout"] {
            let n = num(gated, &["faults", f, "returned_within_bound_runs"]);
            let n0 = num(twin, &["faults", f, "returned_within_bound_runs"]);
            assert!(
                n >= n0 - 1.0 && n >= RUNS as f64 - 2.0,
                "{lp} {f}: {n} vs twin {n0}"
            );
            let t = num(gated, &["faults", f, "recovery_time_s", "max"]);
            assert!(t.is_finite() && t >= 0.0, "{lp} {f}: recovery {t} s");
        }
    }
    // The recovery metric itself can fail: a series that never comes back is reported so.
    let mut never = vec![0.5; (400.0 / dt) as usize];
    for e in never.iter_mut().skip((fc.spike.start_s / dt) as usize) {
        *e = 100.0;
    }
    let (_, rec) = recovery(&never, dt, &fc);
    assert!(rec.iter().all(|r| r.recovery_s.is_none()));
}

/// Re-acquisition after a long starvation with a large coast error resets ĥ (no velocity
/// transient), while a small one is absorbed without a reset.
#[test]
fn reacquisition_after_starvation_resets_large_errors_only() {
    for (bias_m_s2, expect_reset) in [(0.0, false), (0.3, true)] {
        let cfg = load_config("vc-response").unwrap();
        let (ccfg, _) = loop_configs::<f32>(&cfg, 20.0);
        let init = InitialState::<f32> {
            time: Timestamp::ZERO,
            altitude_m: 500.0,
            vz_up_m_s: 0.0,
            accel_bias_m_s2: 0.0,
        };
        let mut lp = ClassicalLoop::new(&ccfg, &init).unwrap();
        Gating::new(16.0, 2.0, 0.3, 0.5).classical(&mut lp).unwrap();
        let g = nav_core::earth::normal_gravity_m_s2(cfg.latitude_deg.to_radians(), 500.0);
        let mut max_dv: f32 = 0.0;
        let mut after = Vec::new();
        for k in 1..=40_000u32 {
            let t = k as f64 * 0.01;
            // A bias appears during the 60 s outage (t ∈ [50, 110) s): the loop coasts on it.
            let b = if (50.0..110.0).contains(&t) {
                bias_m_s2
            } else {
                0.0
            };
            let imu = ImuSample {
                time: ts(t),
                specific_force_up_m_s2: (g + b) as f32,
            };
            let baro = (k % 4 == 0 && !(50.0..110.0).contains(&t)).then_some(BaroSample {
                time: ts(t),
                altitude_m: 500.0,
            });
            let v0 = lp.vz_up_m_s();
            let r = lp.step(&imu, baro.as_ref()).unwrap();
            if t > 110.0 {
                max_dv = max_dv.max((lp.vz_up_m_s() - v0).abs());
                after.push(lp.altitude_m());
            }
            if let Some(c) = r.baro.sample {
                let reset = r.baro.reacquisition == Reacquisition::Reset;
                if r.baro.reacquisition != Reacquisition::Tracking {
                    assert_eq!(c.outcome, FusionOutcome::Fused);
                    assert_eq!(reset, expect_reset, "bias {bias_m_s2}");
                }
                if reset {
                    println!("t = {t:.2}: reset by {:.1} m", c.innovation);
                }
            }
            if (60.0..110.0).contains(&t) {
                assert!(matches!(r.baro.status, AidStatus::Lost { .. }));
            }
        }
        let c = lp.reacquisition_counters(Aid::Baro);
        if expect_reset {
            // The reset removes the altitude error but not the ≈ 18 m/s velocity error, so the
            // next samples fail the tracking gate again: a few reject / Lost / re-acquire /
            // reset cycles until the loop has absorbed it (bounded, then tracking).
            assert!(
                (1..=10).contains(&c.reacquisitions) && c.resets == c.reacquisitions,
                "{c:?}"
            );
        } else {
            assert_eq!((c.reacquisitions, c.resets), (1, 0), "{c:?}");
        }
        assert_eq!(lp.aid_counters(Aid::Baro).consecutive_rejected, 0, "{c:?}");
        // No destabilising jump: the velocity never moves by more than 0.05 m/s per step
        // (with the 0.3 m/s² bias the coast error is ≈ 540 m; without the reset the τ = 20 s
        // loop would turn it into a velocity transient of tens of m/s).
        assert!(max_dv < 0.05, "bias {bias_m_s2}: max ΔV̂ per step {max_dv}");
        let last = *after.last().unwrap();
        assert!(
            (last - 500.0).abs() < 5.0,
            "bias {bias_m_s2}: final h {last}"
        );
    }
}

fn soak_steps() -> usize {
    std::env::var("NAV_SOAK_STEPS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000)
}

/// Soak: both loops in f32 for `NAV_SOAK_STEPS` IMU steps (default 10⁶ = 10 000 s at
/// 100 Hz, ≈ 0.2 s in the test profile, so CI runs the full size) with random valid inputs: a
/// random vertical manoeuvre, noisy sensors, random sample drops, a 20 s outage and a 200 m
/// baro spike every 100 s, the gate on. Every step must succeed with finite, bounded state.
#[test]
fn soak_vertical_channel_f32() {
    let n = soak_steps();
    let cfg = load_config("vc-response").unwrap();
    let (ccfg, acfg) = loop_configs(&cfg, 20.0);
    let lat = cfg.latitude_deg.to_radians();
    let mut rng = run_rng(2024, 0);
    let truth = |t: f64| {
        // Sum of two slow sinusoids: |a| ≤ 6 m/s², |v| ≤ 200 m/s, h ∈ [1 km, 11 km].
        let (a1, w1, a2, w2) = (4000.0, 0.02, 1000.0, 0.06);
        (
            6000.0 + a1 * (w1 * t).sin() + a2 * (w2 * t).sin(),
            a1 * w1 * (w1 * t).cos() + a2 * w2 * (w2 * t).cos(),
        )
    };
    let (h0, v0) = truth(0.0);
    let init = InitialState::<f32> {
        time: Timestamp::ZERO,
        altitude_m: h0 as f32,
        vz_up_m_s: v0 as f32,
        accel_bias_m_s2: 0.0,
    };
    let gate = Gating::new(16.0, 3.0, 0.3, 0.05);
    let mut c = ClassicalLoop::<f32>::new(&ccfg, &init).unwrap();
    let mut a = AidedLoop::<f32>::new(&acfg, &init).unwrap();
    gate.classical(&mut c).unwrap();
    gate.aided(&mut a).unwrap();
    let dt = 0.01;
    let bias = 0.5 * 9.81e-3;
    let mut v_prev = v0;
    let mut worst: [f64; 2] = [0.0; 2];
    for k in 1..=n {
        let t = k as f64 * dt;
        let (h, v) = truth(t);
        let (hm, _) = truth(t - 0.5 * dt);
        let f = (v - v_prev) / dt
            + nav_core::earth::normal_gravity_m_s2(lat, hm)
            + bias
            + normal(&mut rng, 1e-3 / dt.sqrt());
        v_prev = v;
        let phase = t % 100.0;
        let outage = (60.0..80.0).contains(&phase);
        let drop = normal(&mut rng, 1.0) > 2.0; // ≈ 2 % of samples lost
        let baro = (k % 4 == 0 && !outage && !drop).then(|| {
            let spike = if (30.0..30.2).contains(&phase) {
                200.0
            } else {
                0.0
            };
            BaroSample {
                time: ts(t),
                altitude_m: (h - 0.2 * v + normal(&mut rng, 1.0) + spike) as f32,
            }
        });
        let vel = (k % 10 == 0 && !outage).then(|| VelocitySample {
            time: ts(t),
            vz_up_m_s: (v + normal(&mut rng, 0.1)) as f32,
        });
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: f as f32,
        };
        c.step(&imu, baro.as_ref()).unwrap();
        a.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
        for (i, (eh, ev, eb)) in [
            (c.altitude_m(), c.vz_up_m_s(), c.accel_bias_m_s2()),
            (a.altitude_m(), a.vz_up_m_s(), a.accel_bias_m_s2()),
        ]
        .into_iter()
        .enumerate()
        {
            assert!(
                eh.is_finite() && ev.is_finite() && eb.is_finite(),
                "step {k}"
            );
            let dh = (eh.to_f64() - h).abs();
            assert!(dh < 100.0, "loop {i} step {k}: |δh| = {dh}");
            assert!((ev.to_f64() - v).abs() < 10.0, "loop {i} step {k}");
            assert!(eb.abs() < 0.5, "loop {i} step {k}: bias {eb}");
            worst[i] = worst[i].max(dh);
        }
    }
    // Every spike rejected, nothing lost for good.
    let spikes = (n as f64 * dt / 100.0).floor() as u32;
    assert!(c.aid_counters(Aid::Baro).rejected >= 4 * spikes.saturating_sub(1));
    assert!(a.aid_counters(Aid::Baro).rejected >= 4 * spikes.saturating_sub(1));
    println!(
        "soak {n} steps: worst |δh| classical {:.2} m, aided {:.2} m",
        worst[0], worst[1]
    );
}

/// The gate's variance and verdict follow the documented formula, for both aids:
/// baro S = σ_h² + (gap (σ_v0 + ½ σ_a0 gap))², velocity S = σ_v² + (σ_a0 gap)², rejected iff
/// ν²/S > threshold; a rejected sample is not adopted (the held one keeps ageing).
#[test]
fn gate_variance_and_verdict_follow_the_formula() {
    let cfg = load_config("vc-response").unwrap();
    let (_, acfg) = loop_configs::<f64>(&cfg, 20.0);
    let gate = Gating::new(9.0, 2.0, 0.3, 0.1);
    let init = InitialState::<f64> {
        time: Timestamp::ZERO,
        altitude_m: 500.0,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let mut lp = AidedLoop::new(&acfg, &init).unwrap();
    gate.aided(&mut lp).unwrap();
    let g = nav_core::earth::normal_gravity_m_s2(cfg.latitude_deg.to_radians(), 500.0);
    let mut rng = run_rng(5, 0);
    let (mut last_b, mut last_v) = (None::<f64>, None::<f64>);
    let (mut n_rej, mut n_pass) = (0, 0);
    for k in 1..=3000u32 {
        let t = f64::from(k) * 0.01;
        // Samples with occasional gaps and outliers of random size.
        let gap_b = k % 4 == 0 && !(1000..1300).contains(&k);
        let gap_v = k % 10 == 0 && !(2000..2200).contains(&k);
        let out = normal(&mut rng, 1.0).abs() > 1.5;
        let b = gap_b.then(|| BaroSample {
            time: ts(t),
            altitude_m: 500.0 + normal(&mut rng, if out { 20.0 } else { 1.0 }),
        });
        let v = gap_v.then(|| VelocitySample {
            time: ts(t),
            vz_up_m_s: normal(&mut rng, if out { 3.0 } else { 0.1 }),
        });
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: g,
        };
        let r = lp.step(&imu, b.as_ref(), v.as_ref()).unwrap();
        for (rep, last, sig0, is_baro) in [
            (r.baro, &mut last_b, 2.0, true),
            (r.velocity, &mut last_v, 0.3, false),
        ] {
            let Some(c) = rep.sample else { continue };
            let Some(prev) = *last else {
                // First sample: acquisition, ungated (test ratio 0), S = σ₀².
                assert_eq!(c.test_ratio, 0.0);
                assert!((c.innovation_variance - sig0 * sig0).abs() < 1e-12);
                *last = Some(t);
                continue;
            };
            let gap = t - prev;
            let d = if is_baro {
                gap * (0.5 + 0.5 * 0.1 * gap)
            } else {
                0.1 * gap
            };
            let s = sig0 * sig0 + d * d;
            let gv = c.innovation_variance;
            assert!(
                (gv - s).abs() <= 1e-9 * s || gv > s,
                "{is_baro} t {t}: S {gv} vs {s}"
            );
            assert!((c.nis - c.innovation * c.innovation / gv).abs() <= 1e-12 * c.nis.max(1.0));
            assert!((c.test_ratio - c.nis / 9.0).abs() <= 1e-12 * c.nis.max(1.0));
            let pass = c.nis <= 9.0;
            assert_eq!(c.outcome == FusionOutcome::Fused, pass, "t {t}: {c:?}");
            if pass {
                *last = Some(t);
                n_pass += 1;
                // The accepted sample is the one the loop now corrects with.
                assert!(
                    (rep.correction.unwrap() - c.innovation).abs() < 1e-9
                        || rep.reacquisition != Reacquisition::Tracking
                );
            } else {
                n_rej += 1;
            }
        }
    }
    assert!(n_rej > 20 && n_pass > 500, "{n_rej} {n_pass}");
}

/// Missing IMU samples: an interval of n nominal intervals is integrated in min(n, 8)
/// sub-steps (beyond 8, a coast first), reported and counted; a gap longer than 10 s is not
/// integrated: the state is kept, the health says `NeedsReinitialisation` and the next baro
/// sample re-anchors the altitude; `reinitialise` restarts.
#[test]
fn imu_gaps_are_bridged_or_reanchored_and_reinitialise_restarts() {
    let cfg = load_config("vc-response").unwrap();
    let (ccfg, acfg) = loop_configs::<f64>(&cfg, 20.0);
    let g = nav_core::earth::normal_gravity_m_s2(cfg.latitude_deg.to_radians(), 500.0);
    let init = InitialState::<f64> {
        time: Timestamp::ZERO,
        altitude_m: 500.0,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let mut c = ClassicalLoop::new(&ccfg, &init).unwrap();
    let mut a = AidedLoop::new(&acfg, &init).unwrap();
    let mut t = 0.0;
    for (n, sub) in [(1u32, 1u32), (2, 2), (3, 3), (10, 8), (100, 8), (999, 8)] {
        t += f64::from(n) * 0.01;
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: g,
        };
        let baro = BaroSample {
            time: ts(t - 0.005),
            altitude_m: 500.0,
        };
        assert_eq!(c.step(&imu, Some(&baro)).unwrap().imu_intervals, sub);
        assert_eq!(a.step(&imu, Some(&baro), None).unwrap().imu_intervals, sub);
        assert!((c.altitude_m() - 500.0).abs() < 0.5 && (a.altitude_m() - 500.0).abs() < 0.5);
        assert_eq!(c.time(), Some(ts(t)));
        let want = if n == 1 {
            HealthState::Nominal
        } else {
            HealthState::Degraded
        };
        assert_eq!(c.health().state, want, "{n}");
    }
    assert_eq!(c.health().gaps_bridged, 5);
    // 20 s: not integrated, state kept, the baro sample with it re-anchors at once.
    let h_before = c.altitude_m();
    t += 20.0;
    let imu = ImuSample {
        time: ts(t),
        specific_force_up_m_s2: g,
    };
    c.step(&imu, None).unwrap();
    a.step(&imu, None, None).unwrap();
    assert_eq!(c.health().state, HealthState::NeedsReinitialisation);
    assert_eq!(a.health().state, HealthState::NeedsReinitialisation);
    assert_eq!(c.health().gaps_reset, 1);
    assert!((c.altitude_m() - h_before).abs() < 1e-3);
    t += 0.01;
    let imu = ImuSample {
        time: ts(t),
        specific_force_up_m_s2: g,
    };
    let baro = BaroSample {
        time: ts(t),
        altitude_m: 530.0,
    };
    let r = c.step(&imu, Some(&baro)).unwrap();
    assert_eq!(r.baro.reacquisition, Reacquisition::Reanchored, "{r:?}");
    assert!((c.altitude_m() - 530.0).abs() < 0.1, "{}", c.altitude_m());
    assert_ne!(c.health().state, HealthState::NeedsReinitialisation);
    assert_eq!(c.aid_counters(Aid::Baro).recoveries, 1);
    // reinitialise: refused input changes nothing; a valid one restarts (Initialising).
    let (bc, ba) = (format!("{c:?}"), format!("{a:?}"));
    let bad = InitialState {
        altitude_m: f64::NAN,
        ..init
    };
    assert!(c.reinitialise(&bad).is_err() && a.reinitialise(&bad).is_err());
    assert_eq!((format!("{c:?}"), format!("{a:?}")), (bc, ba));
    let again = InitialState {
        time: ts(t),
        ..init
    };
    c.reinitialise(&again).unwrap();
    a.reinitialise(&again).unwrap();
    assert_eq!(c.health().state, HealthState::Initialising);
    assert_eq!(c.health().reinitialisations, 1);
    let imu = ImuSample {
        time: ts(t + 0.01),
        specific_force_up_m_s2: g,
    };
    assert_eq!(c.step(&imu, None).unwrap().imu_intervals, 1);
    assert_eq!(a.step(&imu, None, None).unwrap().imu_intervals, 1);
}

/// The velocity aid has the same recovery path: after a 30 s velocity outage during which a
/// 0.3 m/s² bias acts (no baro), the re-acquiring sample resets V̂_z, and the loop tracks again.
#[test]
fn velocity_aid_reacquisition_resets_the_velocity() {
    let cfg = load_config("vc-response").unwrap();
    let (_, acfg) = loop_configs::<f32>(&cfg, 20.0);
    let init = InitialState::<f32> {
        time: Timestamp::ZERO,
        altitude_m: 500.0,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let mut lp = AidedLoop::new(&acfg, &init).unwrap();
    Gating::new(16.0, 2.0, 0.3, 0.5).aided(&mut lp).unwrap();
    let g = nav_core::earth::normal_gravity_m_s2(cfg.latitude_deg.to_radians(), 500.0);
    let mut v_before_reacq = None;
    for k in 1..=12_000u32 {
        let t = f64::from(k) * 0.01;
        let out = (30.0..60.0).contains(&t);
        let b = if out { 0.3 } else { 0.0 };
        let imu = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: (g + b) as f32,
        };
        let vel = (k % 10 == 0 && !out).then_some(VelocitySample {
            time: ts(t),
            vz_up_m_s: 0.0,
        });
        let v0 = lp.vz_up_m_s();
        let r = lp.step(&imu, None, vel.as_ref()).unwrap();
        let reacquired = r.velocity.reacquisition != Reacquisition::Tracking;
        if let Some(c) = r.velocity.sample.filter(|_| reacquired) {
            assert_eq!(r.velocity.reacquisition, Reacquisition::Reset, "{c:?}");
            assert!(
                (c.innovation + v0).abs() < 0.5,
                "ν {} vs −V̂ {}",
                c.innovation,
                v0
            );
            v_before_reacq = Some(v0);
        }
    }
    let v0 = v_before_reacq.expect("a re-acquisition");
    assert!(v0 > 5.0, "coast velocity error {v0}");
    let c = lp.reacquisition_counters(Aid::Velocity);
    assert_eq!((c.reacquisitions, c.resets), (1, 1), "{c:?}");
    assert!(lp.vz_up_m_s().abs() < 0.2, "V̂ {}", lp.vz_up_m_s());
}

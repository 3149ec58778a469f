//! The loops' dynamics: continuous and discrete poles, the step's Jacobian, the Riccati gains
//! against the Riccati equation integrated to steady state, the multirate stability analysis
//! against simulation.

use super::*;
use nalgebra::{Matrix2, Matrix2x3};

#[test]
fn classical_poles_at_minus_one_over_tau_with_and_without_c4() {
    for &(tau, c4) in &[
        (10.0, 0.0),
        (20.0, 0.0),
        (20.0, 0.2),
        (50.0, 0.5),
        (5.0, 1.0),
    ] {
        let g = ClassicalGains::pole_placement(tau, c4, c_grav()).unwrap();
        let f = g.error_matrix();
        // Characteristic polynomial equals (s + 1/τ)³ = s³ + 3/τ s² + 3/τ² s + 1/τ³.
        let [a2, a1, a0] = char_poly3(&f);
        let p = 1.0 / tau;
        assert!(
            (a2 - 3.0 * p).abs() < 1e-12 * 3.0 * p,
            "{tau} {c4}: a2 {a2}"
        );
        assert!(
            (a1 - 3.0 * p * p).abs() < 1e-10 * 3.0 * p * p,
            "{tau} {c4}: a1 {a1}"
        );
        assert!(
            (a0 - p * p * p).abs() < 1e-10 * p * p * p,
            "{tau} {c4}: a0 {a0}"
        );
        // Eigenvalues (a triple root is perturbed by ~ε^(1/3) relative).
        for ev in f.complex_eigenvalues().iter() {
            assert!((ev.re + p).abs() < 1e-4 * p, "{tau} {c4}: {ev}");
            assert!(ev.im.abs() < 1e-4 * p, "{tau} {c4}: {ev}");
        }
    }
    // C4 = 0 closed form: C1 = 3/τ, C2 = c + 3/τ², C3 = 1/τ³.
    let g = ClassicalGains::pole_placement(20.0, 0.0, c_grav()).unwrap();
    assert!((g.c1_per_s - 3.0 / 20.0).abs() < 1e-15);
    assert!((g.c2_per_s2 - (c_grav() + 3.0 / 400.0)).abs() < 1e-15);
    assert!((g.c3_per_s3 - 1.0 / 8000.0).abs() < 1e-18);
}

/// Jacobian of one loop step with respect to the state, by central finite differences
/// (truth at rest at 500 m, a fresh baro sample at the step's end reading 500 m).
fn step_jacobian(make: &dyn Fn() -> LoopCore<f64>, vel: bool) -> Matrix3<f64> {
    let g = GravityModel::at_latitude(LAT).unwrap();
    let mut jac = Matrix3::zeros();
    for i in 0..3 {
        let d = [1e-3, 1e-4, 1e-6][i];
        let mut out = [nalgebra::Vector3::zeros(); 2];
        for (j, s) in [1.0, -1.0].iter().enumerate() {
            let mut core = make();
            core.x[i] += s * d;
            let imu = ImuSample {
                time: ts(0.01),
                specific_force_up_m_s2: g.gravity_m_s2(500.0),
            };
            let baro = BaroSample {
                time: ts(0.01),
                altitude_m: 500.0,
            };
            let v = VelocitySample {
                time: ts(0.01),
                vz_up_m_s: 0.0,
            };
            core.step(&imu, Some(&baro), vel.then_some(&v)).unwrap();
            out[j] = core.x;
        }
        jac.set_column(i, &((out[0] - out[1]) / (2.0 * d)));
    }
    jac
}

#[test]
fn classical_discrete_loop_poles_near_exp_minus_dt_over_tau() {
    // The step's Jacobian (finite differences through the gravity model, the held-baro
    // extrapolation and Φ, Γ) has all three eigenvalues at ≈ e^{−Δt/τ}: the discretised loop
    // keeps the continuous pole placement, including the c δh gravity feedback.
    for &(tau, c4) in &[(10.0, 0.0), (20.0, 0.2), (50.0, 0.5)] {
        let make = || {
            let mut init0 = init::<f64>(500.0);
            init0.time = Timestamp::ZERO;
            let lp = ClassicalLoop::<f64>::new(&classical_config(tau, c4), &init0).unwrap();
            *lp.core()
        };
        let jac = step_jacobian(&make, false);
        let target = (-0.01 / tau).exp();
        let [a2, a1, a0] = char_poly3(&jac);
        // (z − r)³ = z³ − 3r z² + 3r² z − r³; ZOH/extrapolation perturb it at O((Δt/τ)²).
        let tol = 5.0 * (0.01 / tau) * (0.01 / tau);
        assert!((a2 + 3.0 * target).abs() < tol, "{tau} {c4}: {a2}");
        assert!((a1 - 3.0 * target * target).abs() < tol, "{tau} {c4}: {a1}");
        assert!((a0 + target.powi(3)).abs() < tol, "{tau} {c4}: {a0}");
        // Compare with the exact exponential of the continuous error matrix.
        let g = ClassicalGains::pole_placement(tau, c4, c_grav()).unwrap();
        let (phi_err, _) =
            crate::math::discretize::discretize(&g.error_matrix(), &Matrix3::zeros(), 0.01)
                .unwrap();
        let [b2, b1, b0] = char_poly3(&phi_err);
        assert!((a2 - b2).abs() < tol && (a1 - b1).abs() < tol && (a0 - b0).abs() < tol);
    }
}

#[test]
fn aided_discrete_loop_matches_continuous_error_matrix() {
    let make = || {
        *AidedLoop::<f64>::new(&aided_config(), &init(500.0))
            .unwrap()
            .core()
    };
    let jac = step_jacobian(&make, true);
    let g = AidedGains::design(&aided_config::<f64>()).unwrap();
    let (phi_err, _) =
        crate::math::discretize::discretize(&g.error_matrix(), &Matrix3::zeros(), 0.01).unwrap();
    let ev_j = jac.complex_eigenvalues();
    let ev_c = phi_err.complex_eigenvalues();
    let mut mj: std::vec::Vec<f64> = ev_j
        .iter()
        .map(|e| (e.re * e.re + e.im * e.im).sqrt())
        .collect();
    let mut mc: std::vec::Vec<f64> = ev_c
        .iter()
        .map(|e| (e.re * e.re + e.im * e.im).sqrt())
        .collect();
    mj.sort_by(f64::total_cmp);
    mc.sort_by(f64::total_cmp);
    for (a, b) in mj.iter().zip(&mc) {
        assert!(
            (a - b).abs() < 2e-3 * (1.0 - b).max(1e-6) + 1e-9,
            "{mj:?} {mc:?}"
        );
        assert!(*a < 1.0);
    }
}

#[test]
fn classical_rejects_bad_config() {
    let mut c = classical_config::<f32>(20.0, 0.2);
    c.tau_s = -1.0;
    assert!(matches!(
        ClassicalLoop::<f32>::new(&c, &init(0.0)),
        Err(NavError::InvalidConfig { field: "tau_s", .. })
    ));
    let mut c = classical_config::<f32>(20.0, 0.2);
    c.baro_lag_s = f32::NAN;
    assert!(matches!(
        ClassicalLoop::<f32>::new(&c, &init(0.0)),
        Err(NavError::InvalidConfig {
            field: "baro_lag_s",
            ..
        })
    ));
    let mut c = classical_config::<f32>(20.0, 0.2);
    c.baro_timeouts.lost_after_s = 0.05;
    assert!(matches!(
        ClassicalLoop::<f32>::new(&c, &init(0.0)),
        Err(NavError::InvalidConfig { .. })
    ));
    let mut c = aided_config::<f64>();
    c.velocity_noise_m_s = 0.0;
    assert!(matches!(
        AidedLoop::<f64>::new(&c, &init(0.0)),
        Err(NavError::InvalidConfig {
            field: "velocity_noise_m_s",
            ..
        })
    ));
}

#[test]
fn riccati_solution_residual_and_stability() {
    let g = AidedGains::design(&aided_config::<f64>()).unwrap();
    let (_, rel) = care_residual(&g.a, &g.q, &g.c, &g.r, &g.p);
    assert!(rel < 1e-10, "relative residual {rel}");
    assert!(g.relative_residual < 1e-10);
    assert!(is_hurwitz3(&g.error_matrix()));
    for ev in g.error_matrix().complex_eigenvalues().iter() {
        assert!(ev.re < 0.0, "{ev}");
    }
    // K = P Cᵀ R⁻¹.
    let r_inv = Matrix2::from_diagonal(&g.r.map(|r| 1.0 / r));
    assert!((g.k - g.p * g.c.transpose() * r_inv).abs().max() < 1e-12 * g.k.abs().max());
}

/// Integrates the Riccati differential equation Ṗ = AP + PAᵀ + Q − PCᵀR⁻¹CP (RK4) from P(0)
/// to steady state: a route independent of the Hamiltonian sign function.
fn riccati_ode_steady_state(g: &AidedGains, p0: Matrix3<f64>, dt: f64, t_end: f64) -> Matrix3<f64> {
    let r_inv = Matrix2::from_diagonal(&g.r.map(|r| 1.0 / r));
    let gm = g.c.transpose() * r_inv * g.c;
    let f = |p: &Matrix3<f64>| g.a * p + p * g.a.transpose() + g.q - p * gm * p;
    let mut p = p0;
    let steps = (t_end / dt) as usize;
    for _ in 0..steps {
        let k1 = f(&p);
        let k2 = f(&(p + k1 * (dt / 2.0)));
        let k3 = f(&(p + k2 * (dt / 2.0)));
        let k4 = f(&(p + k3 * dt));
        p += (k1 + k2 * 2.0 + k3 * 2.0 + k4) * (dt / 6.0);
        p = (p + p.transpose()) * 0.5;
    }
    p
}

#[test]
fn riccati_gains_match_riccati_ode_steady_state() {
    let g = AidedGains::design(&aided_config::<f64>()).unwrap();
    let p0 = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 0.01, 1e-6));
    let p = riccati_ode_steady_state(&g, p0, 0.005, 3000.0);
    let r_inv = Matrix2::from_diagonal(&g.r.map(|r| 1.0 / r));
    let k_ode: Matrix3x2<f64> = p * g.c.transpose() * r_inv;
    for (a, b) in g.k.iter().zip(k_ode.iter()) {
        assert!(
            (a - b).abs() <= 1e-6 * a.abs().max(1e-9),
            "{} vs {}",
            g.k,
            k_ode
        );
    }
}

/// A perfect-sensor run of the classical loop core configured by `cfg` with observer gains
/// `(k, c)`, a baro sample every `m` IMU intervals, truth at rest at 500 m (the estimate 1 mm
/// and 0.1 mm/s off), for 100 τ (`tau_s`) or 100 baro periods, at most 50 000 steps: stable
/// when every step succeeds without a limit hit and the final altitude error is below 1 µm.
/// Returns the verdict and the final |δh| in m.
fn perfect_sensor_run(
    cfg: &ClassicalConfig<f64>,
    k: Matrix3x2<f64>,
    c: Matrix2x3<f64>,
    m: u32,
    tau: f64,
) -> (bool, f64) {
    let dt = cfg.imu_dt_s;
    let grav = GravityModel::at_latitude(LAT).unwrap();
    let modes = discretise_modes::<f64>(&open_loop(-1.0), &k, &c, dt).unwrap();
    let mut init0 = init::<f64>(500.001);
    init0.vz_up_m_s = 1e-4;
    let rt = cfg.run_time();
    let mut core = LoopCore::<f64>::new(
        &init0,
        CoreParts {
            bias_sign: -1.0,
            step: StepValues {
                dt_s: dt,
                half_dt_s: 0.5 * dt,
                baro_lag_s: 0.0,
            },
            k,
            modes: &modes,
            gravity: &grav,
            baro_timeouts: cfg.baro_timeouts,
            velocity_timeouts: cfg.baro_timeouts,
            run_time: rt,
            gate: super::gate::GateParams::compile(&rt).unwrap(),
            sigma: &ClassicalDesign::<f64>::compute(&ClassicalConfig::paper())
                .unwrap()
                .sigma,
        },
    )
    .unwrap();
    let f = grav.gravity_m_s2(500.0);
    let dt_us = (dt * 1e6).round() as u64;
    let n = ((100.0 * tau / dt) as u64)
        .max(100 * u64::from(m))
        .min(50_000);
    let mut e = 0.0f64;
    let mut ok = true;
    for kk in 1..=n {
        let t = Timestamp::from_micros(kk * dt_us);
        let b = (kk % u64::from(m) == 0).then_some(BaroSample {
            time: t,
            altitude_m: 500.0,
        });
        if core
            .step(
                &ImuSample {
                    time: t,
                    specific_force_up_m_s2: f,
                },
                b.as_ref(),
                None,
            )
            .is_err()
        {
            ok = false;
            break;
        }
        e = (core.altitude_m() - 500.0).abs();
        if core.health.limits_hit > 0 {
            ok = false;
            break;
        }
    }
    (ok && e < 1e-6, e)
}

/// The multirate stability analysis (Jury test of the monodromy over one baro period) against
/// a perfect-sensor simulation of the loop itself, over τ × IMU interval × baro period,
/// stable and unstable cases: they agree everywhere (τ = 0.01 s with a 1 kHz IMU and a
/// 25 Hz baro is unstable).
#[test]
fn multirate_stability_analysis_agrees_with_simulation() {
    let (mut agree, mut total, mut unstable) = (0, 0, 0);
    for dt in [0.001, 0.01] {
        for m in [1u32, 4, 10, 40] {
            for tau in [0.01, 0.02, 0.05, 0.2] {
                let mut cfg = classical_config::<f64>(tau, 0.0);
                cfg.imu_dt_s = dt;
                cfg.baro_period_s = f64::from(m) * dt;
                cfg.baro_timeouts = AidTimeouts {
                    stale_after_s: 1e5,
                    lost_after_s: 1e5,
                };
                let Ok(gains) = ClassicalGains::pole_placement(tau, 0.0, c_grav()) else {
                    continue;
                };
                let (k, c) = gains.observer();
                let lm = LoopModel {
                    a0: open_loop(-1.0),
                    k,
                    c,
                    lag: 0.0,
                    bias_sign: -1.0,
                    c_grav: c_grav(),
                    dt,
                };
                let verdict = lm.multirate_stable(Some(m), None).unwrap();
                let field = ClassicalDesign::<f64>::compute(&cfg).err();
                let (sim_stable, e) = perfect_sensor_run(&cfg, k, c, m, tau);
                total += 1;
                if !verdict {
                    unstable += 1;
                }
                assert_eq!(sim_stable, verdict, "dt {dt} m {m} τ {tau}: |δh| {e:e}");
                agree += 1;
                if !verdict {
                    assert!(
                        matches!(field, Some(NavError::InvalidConfig { field: "tau_s", .. })),
                        "{field:?}"
                    );
                }
            }
        }
    }
    assert_eq!(agree, total);
    assert!(unstable >= 5 && unstable < total, "{unstable} of {total}");
    let fast = ClassicalConfig {
        imu_dt_s: 0.001,
        baro_period_s: 0.04,
        ..classical_config::<f32>(0.01, 0.0)
    };
    assert!(matches!(
        ClassicalDesign::<f32>::compute(&fast),
        Err(NavError::InvalidConfig { field: "tau_s", .. })
    ));
}

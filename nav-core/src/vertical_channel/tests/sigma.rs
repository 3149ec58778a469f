//! The σ the design implies: against the Riccati solution, the Lyapunov equation, and an
//! independent Monte Carlo of the loops (transient, steady state, baro outage).

use super::*;
use crate::contract::Estimator;
use crate::Timestamp;
use nalgebra::Matrix4;
use std::vec;
use std::vec::Vec;

/// A small seeded generator (xorshift64*) with Box-Muller normals (the test is independent of
/// the simulator).
struct Rng(u64, Option<f64>);

impl Rng {
    fn uniform(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        let v = self.0.wrapping_mul(0x2545_F491_4F6C_DD1D);
        ((v >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }
    fn normal(&mut self) -> f64 {
        if let Some(v) = self.1.take() {
            return v;
        }
        let (u1, u2) = (self.uniform(), self.uniform());
        let r = (-2.0 * u1.ln()).sqrt();
        let a = 2.0 * ::core::f64::consts::PI * u2;
        self.1 = Some(r * a.sin());
        r * a.cos()
    }
}

fn matched_aided() -> AidedConfig<f64> {
    let mut c = AidedConfig::<f64>::paper();
    c.error_model.accel_bias_rw_m_s2_rt_s = c.accel_bias_rw_m_s2_rt_s;
    c.error_model.baro_markov_sigma_m = 0.0;
    c
}

#[test]
fn aided_steady_covariance_is_the_riccati_solution_when_the_model_is_the_design() {
    // The stationary covariance of the continuous closed loop does not depend on the sampling:
    // with the error model equal to the design's noise and no correlated baro error, the
    // discrete Lyapunov solution at the covariance interval is the continuous ARE's P.
    let d = AidedDesign::<f64>::compute(&matched_aided()).unwrap();
    let p = d.steady_covariance();
    let pr = d.gains().p;
    for i in 0..3 {
        for j in 0..3 {
            let scale = (pr[(i, i)] * pr[(j, j)]).sqrt();
            assert!(
                (p[(i, j)] - pr[(i, j)]).abs() <= 1e-6 * scale,
                "P[{i},{j}] {} vs Riccati {}",
                p[(i, j)],
                pr[(i, j)]
            );
        }
    }
    // With the paper's 3 m / 60 s correlated baro error the σ of ĥ is far above the Riccati's.
    let paper = AidedDesign::<f64>::compute(&AidedConfig::paper()).unwrap();
    let s = paper.steady_sigma();
    assert!(s.altitude_m > 3.0 * pr[(0, 0)].sqrt(), "{s:?}");
    assert!(s.altitude_m < 3.2, "{s:?}");
}

#[test]
fn steady_covariance_solves_the_discrete_lyapunov_equation() {
    for design in [
        ClassicalDesign::<f64>::compute(&ClassicalConfig::paper())
            .unwrap()
            .sigma,
        AidedDesign::<f64>::compute(&AidedConfig::paper())
            .unwrap()
            .sigma,
    ] {
        let step = if design.design_uses_velocity {
            design.both
        } else {
            design.baro
        };
        let p = design.p_steady;
        let r: Matrix4<f64> = step.phi * p * step.phi.transpose() + step.q - p;
        assert!(r.abs().max() < 1e-9 * p.abs().max(), "{r}");
        // Symmetric positive definite.
        assert!(p.cholesky().is_some());
    }
}

#[test]
fn stamp_and_values_carry_the_error_model() {
    let a = ClassicalConfig::<f32>::paper();
    let mut b = a;
    b.error_model.baro_markov_sigma_m = 2.0;
    assert_ne!(classical_stamp(&a), classical_stamp(&b));
    let d = ClassicalDesign::compute(&a).unwrap();
    let start = InitialState {
        time: Timestamp::ZERO,
        altitude_m: 0.0_f32,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    assert!(ClassicalLoop::from_design(&b, &d, &start).is_err());
    let mut v = [0.0; ClassicalDesign::<f32>::COUNT];
    d.write_values(&mut v).unwrap();
    assert_eq!(ClassicalDesign::<f32>::read_values(&v).unwrap(), d);
    let mut bad = a;
    bad.error_model.baro_markov_tau_s = 0.0;
    assert!(matches!(
        ClassicalDesign::compute(&bad),
        Err(NavError::InvalidConfig {
            field: "error_model.baro_markov_tau_s",
            ..
        })
    ));
}

fn init(h: f64) -> InitialState<f64> {
    InitialState {
        time: Timestamp::ZERO,
        altitude_m: h,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    }
}

/// Ensemble of `runs` f64 runs at rest at 1000 m with the paper's sensors (drawn from the
/// configuration's error model): per check epoch, the mean of δh², δV_z² and of the σ² the loop
/// reports. The baro is out in `[outage.0, outage.1)` s.
fn ensemble(aided: bool, runs: usize, checks_s: &[f64], outage: (f64, f64)) -> Vec<[f64; 4]> {
    let cc = ClassicalConfig::<f64>::paper();
    let ac = AidedConfig::<f64>::paper();
    let m = cc.error_model;
    let dt = 0.01;
    let g = GravityModel::<f64>::at_latitude(cc.latitude_rad).unwrap();
    let h = 1000.0;
    let last = checks_s.iter().copied().fold(0.0, f64::max);
    let steps = (last / dt).round() as u64;
    let mut acc = vec![[0.0; 4]; checks_s.len()];
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15, None);
    for _ in 0..runs {
        let e0 = (
            m.initial_altitude_sigma_m * rng.normal(),
            m.initial_vz_sigma_m_s * rng.normal(),
        );
        let start = InitialState {
            altitude_m: h + e0.0,
            vz_up_m_s: e0.1,
            ..init(h)
        };
        let mut cl = ClassicalLoop::new(&cc, &start).unwrap();
        let mut al = AidedLoop::new(&ac, &start).unwrap();
        let bias = m.accel_bias_sigma_m_s2 * rng.normal();
        let rho = (-0.04 / m.baro_markov_tau_s).exp();
        let mut markov = m.baro_markov_sigma_m * rng.normal();
        for k in 1..=steps {
            let t = k as f64 * dt;
            let time = Timestamp::from_micros(k * 10_000);
            let imu = ImuSample {
                time,
                specific_force_up_m_s2: g.gravity_m_s2(h)
                    + bias
                    + m.accel_noise_m_s2_rt_hz / dt.sqrt() * rng.normal(),
            };
            let baro = (k % 4 == 0).then(|| {
                markov =
                    rho * markov + m.baro_markov_sigma_m * (1.0 - rho * rho).sqrt() * rng.normal();
                BaroSample {
                    time,
                    altitude_m: h + markov + m.baro_noise_m * rng.normal(),
                }
            });
            let baro = baro.filter(|_| !(t >= outage.0 && t < outage.1));
            let vel = (k % 10 == 0).then(|| VelocitySample {
                time,
                vz_up_m_s: m.velocity_noise_m_s * rng.normal(),
            });
            let (eh, ev, s) = if aided {
                al.step(&imu, baro.as_ref(), vel.as_ref()).unwrap();
                (al.altitude_m() - h, al.vz_up_m_s(), al.sigma())
            } else {
                cl.step(&imu, baro.as_ref()).unwrap();
                (cl.altitude_m() - h, cl.vz_up_m_s(), cl.sigma())
            };
            for (i, &tc) in checks_s.iter().enumerate() {
                if (t - tc).abs() < 0.5 * dt {
                    let a = &mut acc[i];
                    a[0] += eh * eh;
                    a[1] += ev * ev;
                    a[2] += s.altitude_m * s.altitude_m;
                    a[3] += s.vz_m_s * s.vz_m_s;
                }
            }
        }
    }
    for a in &mut acc {
        for v in a.iter_mut() {
            *v /= runs as f64;
        }
    }
    acc
}

/// The ensemble's error variance against the reported σ²: a ratio in `[lo, hi]` at every
/// check epoch (200 runs: the sample variance is within ±20 % at 2σ).
fn check(aided: bool, checks: &[f64], outage: (f64, f64), lo: f64, hi: f64) {
    let acc = ensemble(aided, 200, checks, outage);
    for (t, a) in checks.iter().zip(&acc) {
        let rh = a[0] / a[2];
        let rv = a[1] / a[3];
        std::println!(
            "aided {aided} t {t:6.1} s: σ_h {:.3} m (MC {:.3}), σ_v {:.4} m/s (MC {:.4})",
            a[2].sqrt(),
            a[0].sqrt(),
            a[3].sqrt(),
            a[1].sqrt()
        );
        assert!(rh > lo && rh < hi, "aided {aided} t {t}: δh²/σ_h² = {rh}");
        assert!(rv > lo && rv < hi, "aided {aided} t {t}: δV²/σ_v² = {rv}");
    }
}

#[test]
fn sigma_matches_a_monte_carlo_of_the_classical_loop_from_start_to_steady_state() {
    check(
        false,
        &[6.0, 20.0, 60.0, 150.0, 300.0],
        (1e9, 1e9),
        0.7,
        1.35,
    );
}

#[test]
fn sigma_matches_a_monte_carlo_of_the_aided_loop_from_start_to_steady_state() {
    check(
        true,
        &[6.0, 20.0, 60.0, 150.0, 300.0],
        (1e9, 1e9),
        0.7,
        1.35,
    );
}

#[test]
fn sigma_grows_honestly_in_a_baro_outage() {
    // Baro out from 200 s to 230 s: the σ must cover the error at the end of the outage and
    // after the baro is back.
    check(false, &[229.9, 240.0], (200.0, 230.0), 0.6, 1.35);
    check(true, &[229.9, 240.0], (200.0, 230.0), 0.6, 1.35);
}

#[test]
fn sigma_settles_to_the_steady_state_and_stays_there() {
    let cfg = ClassicalConfig::<f32>::paper();
    let mut lp = ClassicalLoop::new(
        &cfg,
        &InitialState {
            time: Timestamp::ZERO,
            altitude_m: 500.0_f32,
            vz_up_m_s: 0.0,
            accel_bias_m_s2: 0.0,
        },
    )
    .unwrap();
    let g = GravityModel::at_latitude(cfg.latitude_rad.to_f64()).unwrap();
    let s0 = lp.sigma();
    assert_eq!(s0.altitude_m, 20.0);
    let mut prev = s0.altitude_m;
    for k in 1..=60_000_u64 {
        let time = Timestamp::from_micros(k * 10_000);
        let imu = ImuSample {
            time,
            specific_force_up_m_s2: g.gravity_m_s2(500.0) as f32,
        };
        let baro = (k % 4 == 0).then_some(BaroSample {
            time,
            altitude_m: 500.0,
        });
        lp.step(&imu, baro.as_ref()).unwrap();
        let s = lp.sigma().altitude_m;
        assert!(s.is_finite() && s > 0.0);
        prev = s;
    }
    assert_eq!(lp.sigma(), lp.steady_sigma());
    assert!(lp.core().sigma.p == lp.core().sigma.design.p_steady);
    assert!((prev - lp.steady_sigma().altitude_m).abs() < 1e-6);
}

/// `set_covariance_h_vz`: a bad block is refused with the loop unchanged; a good one replaces
/// the (h, V_z) block, zeroes its cross terms with the bias and the baro error, keeps theirs,
/// and σ propagates from it to the same steady state.
#[test]
fn covariance_h_vz_set_from_outside() {
    let cfg = ClassicalConfig::<f64>::paper();
    let mut lp = ClassicalLoop::new(
        &cfg,
        &InitialState {
            time: Timestamp::ZERO,
            altitude_m: 500.0,
            vz_up_m_s: 0.0,
            accel_bias_m_s2: 0.0,
        },
    )
    .unwrap();
    let g = GravityModel::at_latitude(cfg.latitude_rad).unwrap();
    let step = |lp: &mut ClassicalLoop<f64>, k: u64| {
        let time = Timestamp::from_micros(k * 10_000);
        let imu = ImuSample {
            time,
            specific_force_up_m_s2: g.gravity_m_s2(500.0),
        };
        let baro = (k % 4 == 0).then_some(BaroSample {
            time,
            altitude_m: 500.0,
        });
        lp.step(&imu, baro.as_ref()).unwrap();
    };
    for k in 1..=50 {
        step(&mut lp, k);
    }
    let before = lp;
    let m = nalgebra::Matrix2::new;
    for (bad, err) in [
        (m(f64::NAN, 0.0, 0.0, 1.0), "NonFiniteInput"),
        (m(4.0, 0.1, 0.2, 1.0), "InputOutOfRange"),
        (m(-4.0, 0.0, 0.0, 1.0), "InputOutOfRange"),
        (m(4.0, 0.0, 0.0, -1e-9), "InputOutOfRange"),
        (m(4.0, 2.01, 2.01, 1.0), "InputOutOfRange"),
    ] {
        let e = lp.set_covariance_h_vz(&bad).unwrap_err();
        assert!(std::format!("{e:?}").starts_with(err), "{e:?}");
        assert_eq!(lp, before, "a refused block changes nothing");
    }
    let good = m(4.0, -0.3, -0.3, 0.09);
    lp.set_covariance_h_vz(&good).unwrap();
    assert_eq!(lp.covariance_h_vz(), good);
    let p = lp.core().sigma.p;
    let p0 = before.core().sigma.p;
    for (i, j) in [
        (0, 2),
        (0, 3),
        (1, 2),
        (1, 3),
        (2, 0),
        (3, 0),
        (2, 1),
        (3, 1),
    ] {
        assert_eq!(p[(i, j)], 0.0);
    }
    for (i, j) in [(2, 2), (2, 3), (3, 2), (3, 3)] {
        assert_eq!(p[(i, j)], p0[(i, j)]);
    }
    assert!(p.cholesky().is_some(), "P stays positive definite");
    for k in 51..=60_000 {
        step(&mut lp, k);
    }
    assert_eq!(lp.sigma(), lp.steady_sigma());
}

//! Cross-crate tests of the transfer-alignment filters (nav-core) against the simulated truth
//! (nav-sim): Markov Q, H against the exact rotation-based model, observability ranks, and the
//! paper's claims that reproduce, at reduced run counts.
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use nav_core::math::rotation::{exp_so3, skew};
use nav_core::transfer_alignment::{h_matrix, AxisChain, AxisFlexure};
use nav_core::Real;
use nav_sim::processes::psd_sqrt;
use nav_sim::rng::{gauss, run_rng};
use nav_sim::scenarios::transfer_alignment::config::{load_scenario, CaseConfig, Precision};
use nav_sim::scenarios::transfer_alignment::estimate::{run_case, CaseResult};
use nav_sim::scenarios::transfer_alignment::truth::right_jacobian;
use nav_sim::scenarios::transfer_alignment::{
    observability_ranks, ModelErrorConfig, ObservabilityConfig,
};
use nav_sim::stats::autocorrelation;

/// Simulates the flexure block of the filter's own discrete chain (Φ, Q_d) and returns the
/// sample σ and the autocorrelation at lag τ.
fn chain_statistics<T: Real, const K: usize>(
    sigma: f64,
    tau: f64,
    dt: f64,
    steps: usize,
) -> (f64, f64) {
    let fl = AxisFlexure {
        sigma_rad: T::lit(sigma),
        tau_s: T::lit(tau),
    };
    let ch = AxisChain::<T, K>::new(&fl, T::zero(), T::lit(dt)).unwrap();
    let phi = ch.phi.map(|v| v.to_f64());
    let qd = ch.q_d.map(|v| v.to_f64());
    let sq = psd_sqrt(&qd);
    let sp = psd_sqrt(&ch.p0.map(|v| v.to_f64()));
    let mut rng = run_rng(77, K as u64);
    let draw = |rng: &mut nav_sim::rng::SimRng| SVector::<f64, K>::from_fn(|_, _| gauss(rng));
    let mut x = sp * draw(&mut rng);
    let mut th = Vec::with_capacity(steps);
    for _ in 0..steps {
        x = phi * x + sq * draw(&mut rng);
        th.push(x[1]);
    }
    let var = th.iter().map(|v| v * v).sum::<f64>() / steps as f64;
    let lag = (tau / dt).round() as usize;
    (var.sqrt(), autocorrelation(&th, lag))
}

#[test]
fn markov_q_gives_configured_sigma_and_tau() {
    let sigma = 0.5_f64.to_radians();
    let e_inv = (-1.0f64).exp();
    for (k, (s, r)) in [
        (3, chain_statistics::<f64, 3>(sigma, 0.358, 0.01, 300_000)),
        (4, chain_statistics::<f64, 4>(sigma, 0.358, 0.01, 300_000)),
        (3, chain_statistics::<f32, 3>(sigma, 0.358, 0.01, 300_000)),
        (4, chain_statistics::<f32, 4>(sigma, 0.358, 0.01, 300_000)),
    ] {
        assert!((s / sigma - 1.0).abs() < 0.05, "K={k}: σ {s} vs {sigma}");
        assert!((r - e_inv).abs() < 0.04, "K={k}: ρ(τ) {r} vs 1/e");
    }
}

/// Exact (rotation-based) measurement z(x) of the spec's kinematics for the 12-state x (spec
/// order), master rate ω, angular acceleration ω̇, specific force f_m and lever arm L_0.
fn z_exact(
    x: &SVector<f64, 12>,
    w: &Vector3<f64>,
    w_dot: &Vector3<f64>,
    f_m: &Vector3<f64>,
    l0: &Vector3<f64>,
) -> SVector<f64, 6> {
    let v = |i: usize| Vector3::new(x[3 * i], x[3 * i + 1], x[3 * i + 2]);
    let (th_m, th_f, th_fd, th_fdd) = (v(0), v(1), v(2), v(3));
    let theta = th_m + th_f;
    let l = l0 + th_f.cross(l0);
    let a_rel = w_dot.cross(&l)
        + w.cross(&w.cross(&l))
        + 2.0 * w.cross(&th_fd.cross(l0))
        + th_fdd.cross(l0);
    let c_m_s = exp_so3(&(-theta));
    let f_s = c_m_s * (f_m + a_rel);
    let w_s = c_m_s * w + right_jacobian(&theta) * th_fd;
    let f_comp = f_m + w_dot.cross(l0) + w.cross(&w.cross(l0));
    let dw = w - w_s;
    let df = f_comp - f_s;
    SVector::<f64, 6>::new(dw.x, dw.y, dw.z, df.x, df.y, df.z)
}

fn jacobian(
    w: &Vector3<f64>,
    w_dot: &Vector3<f64>,
    f_m: &Vector3<f64>,
    l0: &Vector3<f64>,
) -> SMatrix<f64, 6, 12> {
    let h = 1e-6;
    let mut j = SMatrix::<f64, 6, 12>::zeros();
    for c in 0..12 {
        let mut xp = SVector::<f64, 12>::zeros();
        xp[c] = h;
        let d = (z_exact(&xp, w, w_dot, f_m, l0) - z_exact(&(-xp), w, w_dot, f_m, l0)) / (2.0 * h);
        j.set_column(c, &d);
    }
    j
}

#[test]
fn h_of_both_filters_matches_finite_differences_of_the_exact_model() {
    let l0 = Vector3::new(0.0, 5.0, 0.0);
    let f_m = Vector3::new(9.80665, 1.3, -9.79);
    // (a) no rotation: H is the exact Jacobian at x = 0 (f_s = f̃_m = f_m there).
    let zero = Vector3::zeros();
    let j = jacobian(&zero, &zero, &f_m, &l0);
    let hp = h_matrix::<f64, 4, 12>(&zero, &f_m, &l0).unwrap();
    let hc = h_matrix::<f64, 3, 9>(&zero, &f_m, &l0).unwrap();
    assert!((j - hp).abs().max() < 1e-7, "{}", j - hp);
    assert!((j.fixed_columns::<9>(0) - hc).abs().max() < 1e-7);
    // The conventional model misses exactly the L_0 × θ̈_f column block.
    assert!((j.fixed_view::<3, 3>(3, 9) - skew(&l0)).abs().max() < 1e-7);
    // f32 H agrees too.
    let hp32 = h_matrix::<f32, 4, 12>(&zero.cast(), &f_m.cast(), &l0.cast()).unwrap();
    assert!((j - hp32.cast::<f64>()).abs().max() < 1e-5);
    // (b) rotating master: gyro rows and the θ_m columns are exact; the acceleration rows of the
    // θ_f and θ̇_f columns differ by exactly the lever-arm flexure terms the spec neglects:
    // ([ω̇×] + [ω×]²)[L_0×] on θ_f and 2[ω×][L_0×] on θ̇_f.
    let w = Vector3::new(0.05, -0.2, 0.3);
    let w_dot = Vector3::new(0.5, 0.1, -0.4);
    let f_comp = f_m + w_dot.cross(&l0) + w.cross(&w.cross(&l0));
    let j = jacobian(&w, &w_dot, &f_m, &l0);
    let hp = h_matrix::<f64, 4, 12>(&w, &f_comp, &l0).unwrap();
    let mut expected = hp;
    let (wx, wdx, lx) = (skew(&w), skew(&w_dot), skew(&l0));
    let n_f: Matrix3<f64> = (wdx + wx * wx) * lx;
    let n_fd: Matrix3<f64> = 2.0 * wx * lx;
    let mut blk = expected.fixed_view_mut::<3, 3>(3, 3);
    blk += n_f;
    let mut blk = expected.fixed_view_mut::<3, 3>(3, 6);
    blk += n_fd;
    assert!((j - expected).abs().max() < 1e-7, "{}", j - expected);
    assert!((j.fixed_rows::<3>(0) - hp.fixed_rows::<3>(0)).abs().max() < 1e-7);
}

#[test]
fn observability_ranks_equal_the_spec_table() {
    let (cfg, _, _): (ObservabilityConfig, _, _) = load_scenario("ta-observability").unwrap();
    let (seg, som) = observability_ranks::<4, 12>(&cfg).unwrap();
    assert_eq!(seg.map(|r| r.rank), [11, 11, 11, 11]);
    assert_eq!(som.map(|r| r.rank), [12, 12, 12]);
    // A clear gap behind every rank decision.
    for r in seg.iter().chain(&som) {
        assert!(
            r.smallest_accepted > 1e-3 && r.largest_rejected < 1e-12,
            "{r:?}"
        );
    }
}

const RUNS: usize = 8;

fn case(name: &str) -> CaseResult {
    let (cfg, _, seed): (CaseConfig, _, _) = load_scenario(name).unwrap();
    run_case(&cfg, RUNS, seed, 0.0, false, name).unwrap()
}

#[test]
fn claim1_case1_x_y_within_a_second_z_after_acceleration() {
    let r = case("ta-case1");
    let (c, p) = (&r.conventional.axes, &r.proposed.axes);
    // X for both, Y for the proposed: better than 1 mrad in late cruise.
    assert!(c[0].rms_cruise_mrad < 1.0 && p[0].rms_cruise_mrad < 1.0);
    assert!(p[1].rms_cruise_mrad < 1.0);
    // Z is not estimated during cruise (error at the level of the 0.5° prior) and converges
    // once the X acceleration starts.
    for m in [c, p] {
        assert!(m[2].rms_cruise_mrad > 5.0);
        assert!(m[2].rms_after_accel_mrad < 1.0);
    }
}

#[test]
fn claim2_and_3_conventional_degrades_with_flexure_acceleration_proposed_does_not() {
    let r1 = case("ta-case1");
    let r2 = case("ta-case2");
    let r3 = case("ta-case3");
    let cx = |r: &CaseResult| r.conventional.axes[0].rms_after_accel_mrad;
    assert!(cx(&r3) > cx(&r2) && cx(&r2) > 3.0 * cx(&r1));
    for r in [&r2, &r3] {
        for a in 0..2 {
            let (c, p) = (&r.conventional.axes[a], &r.proposed.axes[a]);
            assert!(
                c.rms_after_accel_mrad > 3.0 * p.rms_after_accel_mrad,
                "axis {a}"
            );
            // The proposed estimates hardly change from case 1.
            assert!(p.rms_after_accel_mrad < 1.5 * r1.proposed.axes[a].rms_after_accel_mrad + 0.1);
        }
        assert!(r.proposed.axes[2].rms_after_accel_mrad < 1.0);
    }
    // Claim 3 (case 2): the proposed Monte Carlo 1σ is below the conventional one from 0.1 s
    // on in X and Y, and in Z after the acceleration starts.
    let t = &r2.t_s;
    for a in 0..3 {
        let from = if a == 2 { 1.05 } else { 0.1 };
        let mean = |v: &[f64]| {
            let s: Vec<f64> = v
                .iter()
                .zip(t)
                .filter(|(_, tt)| **tt >= from)
                .map(|(x, _)| *x)
                .collect();
            s.iter().sum::<f64>() / s.len() as f64
        };
        assert!(
            mean(&r2.proposed.std_mrad[a]) < 0.5 * mean(&r2.conventional.std_mrad[a]),
            "axis {a}"
        );
    }
}

#[test]
fn claim4_model_error_proposed_stays_satisfactory() {
    let (cfg, _, seed): (ModelErrorConfig, _, _) = load_scenario("ta-model-error").unwrap();
    let base = run_case(&cfg.case, RUNS, seed, 0.0, false, "0").unwrap();
    for pct in [20.0, 50.0] {
        let r = run_case(&cfg.case, RUNS, seed, pct, false, "pct").unwrap();
        for a in 0..3 {
            let (p, b) = (&r.proposed.axes[a], &base.proposed.axes[a]);
            assert!(p.rms_after_accel_mrad < 1.0, "τ +{pct} %, axis {a}");
            assert!(
                p.rms_after_accel_mrad < 1.3 * b.rms_after_accel_mrad,
                "τ +{pct} %, axis {a}"
            );
        }
    }
}

#[test]
fn f32_filters_match_f64_on_case2() {
    let (mut cfg, _, seed): (CaseConfig, _, _) = load_scenario("ta-case2").unwrap();
    let r64 = run_case(&cfg, 4, seed, 0.0, false, "f64").unwrap();
    cfg.precision = Precision::F32;
    let r32 = run_case(&cfg, 4, seed, 0.0, false, "f32").unwrap();
    for a in 0..3 {
        let (x, y) = (r32.proposed.axes[a], r64.proposed.axes[a]);
        assert!(
            (x.final_rms_mrad - y.final_rms_mrad).abs() < 0.05 + 0.1 * y.final_rms_mrad,
            "axis {a}"
        );
        let (x, y) = (r32.conventional.axes[a], r64.conventional.axes[a]);
        assert!(
            (x.rms_after_accel_mrad - y.rms_after_accel_mrad).abs()
                < 0.1 + 0.2 * y.rms_after_accel_mrad,
            "axis {a}"
        );
    }
}

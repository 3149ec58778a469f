//! Vertical channel: the simulator's reproduction of the paper's claims at reduced
//! run counts, the summary keys fixed by the issue, and the loops through an aid dropout.

use nav_sim::scenario::{default_scenario_dir, resolve, RunOptions};
use nav_sim::scenarios::run_file;
use nav_sim::scenarios::vertical_channel::{load_config, monte_carlo_rmse};

const RUNS: usize = 20;

#[test]
fn claim2_aided_vz_rmse_lower_than_classical_reduced_runs() {
    // Paper claim 2 (Fig. 4): the velocity-aided loop's RMSE is lower than the classical
    // loop's. With the default (faithful) design it holds for V_z by a clear margin; for h it
    // holds only marginally at 100 runs (3.95 vs 4.04 m), dominated by the 3 m baro Markov
    // error neither loop can remove, so only "not worse by more than 5 %" is asserted for h.
    let cfg = load_config("vc-montecarlo").unwrap();
    let mc = monte_carlo_rmse(&cfg, cfg.classical.tau_s, RUNS, 77, false).unwrap();
    let [[ch, cv], [ah, av]] = mc.rmse;
    assert!(av < 0.9 * cv, "V_z RMSE aided {av} vs classical {cv}");
    assert!(ah < 1.05 * ch, "h RMSE aided {ah} vs classical {ch}");
    // Both loops are damped: the RMSE at the end is far below the initial 20 m / 2 m/s.
    for l in 0..2 {
        let h_end = *mc.rmse_t[l][0].last().unwrap();
        let v_end = *mc.rmse_t[l][1].last().unwrap();
        assert!(h_end < 8.0 && v_end < 0.5, "loop {l}: {h_end} {v_end}");
    }
}

#[test]
fn aided_settles_faster_as_design_trusts_the_accelerometer_less() {
    // The aided loop's transient speed is set by its Riccati design: a larger assumed
    // accelerometer noise gives larger gains and a faster noise-free settle (claim 1 holds only
    // for such designs; with the faithful design it does not, see docs/vertical-channel.md,
    // "Why claim 1 does not reproduce").
    let mut cfg = load_config("vc-response").unwrap();
    let mut settle = Vec::new();
    for q in [1e-3, 1e-2] {
        cfg.aided.accel_noise_design_m_s2_rt_hz = Some(q);
        let mc = monte_carlo_rmse(&cfg, cfg.classical.tau_s, 1, 1, false).unwrap();
        settle.push(mc.settle_s[1].unwrap());
    }
    assert!(settle[1] < 0.5 * settle[0], "{settle:?}");
    // And the classical loop settles faster with a smaller τ (triple pole at −1/τ).
    let fast = monte_carlo_rmse(&cfg, 5.0, 1, 1, false).unwrap().settle_s[0].unwrap();
    let slow = monte_carlo_rmse(&cfg, 20.0, 1, 1, false).unwrap().settle_s[0].unwrap();
    assert!(fast < 0.5 * slow, "{fast} {slow}");
}

#[test]
fn f32_and_f64_loops_agree() {
    let mut cfg = load_config("vc-montecarlo").unwrap();
    cfg.precision = "f64".into();
    let a = monte_carlo_rmse(&cfg, 20.0, 4, 5, false).unwrap();
    cfg.precision = "f32".into();
    let b = monte_carlo_rmse(&cfg, 20.0, 4, 5, false).unwrap();
    for l in 0..2 {
        for q in 0..2 {
            let (x, y) = (a.rmse[l][q], b.rmse[l][q]);
            assert!((x - y).abs() < 0.02 * x, "loop {l} q {q}: f64 {x} f32 {y}");
        }
    }
}

#[test]
fn loops_coast_through_aid_dropouts() {
    // Velocity aid lost 150-250 s and baro lost 300-330 s: the loops keep running on the IMU
    // alone and recover; the error stays bounded.
    let mut cfg = load_config("vc-montecarlo").unwrap();
    let base = monte_carlo_rmse(&cfg, 20.0, 4, 9, false).unwrap();
    cfg.dropout = toml_dropouts();
    let mc = monte_carlo_rmse(&cfg, 20.0, 4, 9, false).unwrap();
    for l in 0..2 {
        assert!(mc.rmse[l][0] < 2.0 * base.rmse[l][0] + 1.0, "{:?}", mc.rmse);
        assert!(mc.rmse[l][1] < 2.0 * base.rmse[l][1] + 0.1, "{:?}", mc.rmse);
    }
    // The dropout changed something for the aided loop (the velocity aid was really missing).
    assert!(mc.rmse[1] != base.rmse[1]);
}

fn toml_dropouts() -> Vec<nav_sim::scenarios::vertical_channel::Dropout> {
    use nav_sim::scenarios::vertical_channel::Dropout;
    vec![
        Dropout {
            aid: "velocity".into(),
            start_s: 150.0,
            end_s: 250.0,
        },
        Dropout {
            aid: "baro".into(),
            start_s: 300.0,
            end_s: 330.0,
        },
    ]
}

#[test]
fn vc_response_summary_has_its_keys() {
    let out = std::env::temp_dir().join(format!("nav-tests-vc-{}", std::process::id()));
    let (name, path) = resolve("vc-response", &default_scenario_dir()).unwrap();
    let opts = RunOptions {
        runs: None,
        seed: None,
        out_root: out.clone(),
        progress: false,
    };
    let s = run_file(&name, &path, &opts).unwrap();
    assert_eq!(s["scenario"], "vc-response");
    assert_eq!(s["runs"], 1);
    assert!(s["seed"].is_u64());
    for l in ["classical", "aided"] {
        let lp = &s["loops"][l];
        assert!(lp["settle_time_s"].is_number() || lp["settle_time_s"].is_null());
        assert!(lp["rmse_h_m"].as_f64().unwrap() > 0.0);
        assert!(lp["rmse_vz_mps"].as_f64().unwrap() > 0.0);
    }
    assert!(out.join("vc-response/fig3_response.png").exists());
    let _ = std::fs::remove_dir_all(&out);
}

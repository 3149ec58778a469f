//! The kinds' runners: figures, CSV and summaries of `vc-response`, `vc-montecarlo` and
//! `vc-tau-sweep`.

use super::run::{loop_configs, monte_carlo_rmse, one_run, McResult, RunOut, FILTERS};
use super::truth::Profile;
use super::{validate, Config};
use crate::consistency::Consistency;
use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::Context;
use anyhow::{anyhow, ensure, Result};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{AidedLoop, ClassicalLoop, InitialState};
use nav_core::Estimator;
use serde_json::{json, Value};

const LOOPS: [&str; 2] = ["classical", "aided"];

fn settle_json(s: Option<f64>) -> Value {
    s.map_or(Value::Null, |v| json!(sig(v, 4)))
}

fn design_json(cfg: &Config, tau_s: f64) -> Result<Value> {
    let (ccfg, acfg) = loop_configs::<f64>(cfg, tau_s);
    let init = InitialState {
        time: Timestamp::ZERO,
        altitude_m: 0.0,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let c = ClassicalLoop::<f64>::new(&ccfg, &init).map_err(|e| anyhow!("{e}"))?;
    let a = AidedLoop::<f64>::new(&acfg, &init).map_err(|e| anyhow!("{e}"))?;
    let g = c.gains();
    let ag = a.gains();
    let poles: Vec<Value> = ag
        .error_matrix()
        .complex_eigenvalues()
        .iter()
        .map(|e| json!([sig(e.re, 4), sig(e.im, 4)]))
        .collect();
    Ok(json!({
        "classical": {
            "tau_s": tau_s, "c1_per_s": sig(g.c1_per_s, 6), "c2_per_s2": sig(g.c2_per_s2, 6),
            "c3_per_s3": sig(g.c3_per_s3, 6), "c4_s": g.c4_s,
            "design_sigma_h_m": sig(c.steady_sigma().altitude_m, 4),
            "design_sigma_vz_mps": sig(c.steady_sigma().vz_m_s, 4),
            "design_sigma": "steady state of the closed loop under the scenario's error model \
                (discrete Lyapunov equation, correlated baro error included)",
        },
        "aided": {
            "riccati": "continuous ARE, Hamiltonian matrix sign function",
            "k1_per_s": sig(ag.k[(0, 0)], 6), "k2_per_s2": sig(ag.k[(1, 0)], 6),
            "k3_per_s3": sig(ag.k[(2, 0)], 6), "g1": sig(ag.k[(0, 1)], 6),
            "g2_per_s": sig(ag.k[(1, 1)], 6), "g3_per_s2": sig(ag.k[(2, 1)], 6),
            "closed_loop_poles_re_im": poles,
            "riccati_relative_residual": ag.relative_residual,
            "riccati_sigma_h_m": sig(ag.p[(0, 0)].sqrt(), 4),
            "riccati_sigma_vz_mps": sig(ag.p[(1, 1)].sqrt(), 4),
            "design_sigma_h_m": sig(a.steady_sigma().altitude_m, 4),
            "design_sigma_vz_mps": sig(a.steady_sigma().vz_m_s, 4),
        }
    }))
}

pub(super) fn run_response(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    validate(&cfg)?;
    let profile = Profile::new(&cfg.profile)?;
    let tau = cfg.classical.tau_s;
    let mut rng = crate::rng::run_rng(ctx.seed, 0);
    let (run, twin) = one_run(&cfg, &profile, tau, true, &mut rng)?;
    let twin = twin.ok_or_else(|| anyhow!("noise-free twin missing"))?;
    let n = run.n.max(1) as f64;
    let mut loops = serde_json::Map::new();
    for (l, name) in LOOPS.iter().enumerate() {
        let rh = (run.sumsq[l][0] / n).sqrt();
        let rv = (run.sumsq[l][1] / n).sqrt();
        println!(
            "  {name:<9} settle (noise-free) {:>8}  RMSE h {rh:.3} m  V_z {rv:.4} m/s",
            twin.settle_s[l].map_or("never".to_string(), |s| format!("{s:.2} s"))
        );
        loops.insert(
            name.to_string(),
            json!({
                "settle_time_s": settle_json(twin.settle_s[l]),
                "rmse_h_m": sig(rh, 4),
                "rmse_vz_mps": sig(rv, 4),
                "rmse_h_noise_free_m": sig((twin.sumsq[l][0] / twin.n.max(1) as f64).sqrt(), 4),
            }),
        );
    }
    write_response_csv(ctx, &run, &twin)?;
    render_response(ctx, &cfg, tau, &run, &twin)?;
    let cons: Vec<Consistency> = run
        .consistency
        .iter()
        .map(|rc| Consistency::from_runs(2, std::slice::from_ref(rc)))
        .collect();
    nees_figure(
        "vc-response: NEES of (h, V_z), one run (band of one run: χ²(2))",
        &cons,
        &ctx.out_dir.join("nees.png"),
    )?;
    Ok(json!({
        "consistency": consistency_json(&cons),
        "loops": loops,
        "design": design_json(&cfg, tau)?,
        "precision": cfg.precision,
    }))
}

/// `response.csv`: truth, baro, both loops' estimates and errors, and the noise-free twin's
/// altitude errors.
fn write_response_csv(ctx: &Context, run: &RunOut, twin: &RunOut) -> Result<()> {
    write_csv(
        &ctx.out_dir.join("response.csv"),
        &[
            "t_s",
            "h_true_m",
            "vz_true_mps",
            "h_baro_m",
            "h_classical_m",
            "h_aided_m",
            "vz_classical_mps",
            "vz_aided_mps",
            "err_h_classical_m",
            "err_h_aided_m",
            "err_vz_classical_mps",
            "err_vz_aided_mps",
            "err_h_classical_noise_free_m",
            "err_h_aided_noise_free_m",
        ],
        &[
            &run.t,
            &run.h_true,
            &run.vz_true,
            &run.h_baro,
            &run.h_est[0],
            &run.h_est[1],
            &run.vz_est[0],
            &run.vz_est[1],
            &run.err_h[0],
            &run.err_h[1],
            &run.err_vz[0],
            &run.err_vz[1],
            &twin.err_h[0],
            &twin.err_h[1],
        ],
    )?;
    Ok(())
}

/// The legend of loop `l` (0 classical with its τ in s, 1 aided).
fn loop_label(l: usize, tau: f64) -> String {
    if l == 0 {
        format!("classical (τ = {tau} s)")
    } else {
        "velocity-aided (Riccati)".to_string()
    }
}

/// `fig3_response.png`: altitude, vertical velocity and their errors of both loops, with the
/// noise-free twin's errors.
fn render_response(
    ctx: &Context,
    cfg: &Config,
    tau: f64,
    run: &RunOut,
    twin: &RunOut,
) -> Result<()> {
    let t = &run.t;
    let label = |l: usize| loop_label(l, tau);
    let fig = Figure {
        title: "Vertical channel response (seed Fig. 3): one run, initial errors 20 m / 2 m/s"
            .into(),
        x_label: "time, s".into(),
        columns: 2,
        panels: vec![
            Panel {
                title: "altitude".into(),
                y_label: "h, m".into(),
                series: vec![
                    Series::line("truth", t, &run.h_true, 3),
                    Series::dashed(label(0), t, &run.h_est[0], 1),
                    Series::dashed(label(1), t, &run.h_est[1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity".into(),
                y_label: "V_z, m/s".into(),
                series: vec![
                    Series::line("truth", t, &run.vz_true, 3),
                    Series::dashed(label(0), t, &run.vz_est[0], 1),
                    Series::dashed(label(1), t, &run.vz_est[1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "altitude error".into(),
                y_label: "δh, m".into(),
                series: vec![
                    Series::line(label(0), t, &run.err_h[0], 1),
                    Series::line(label(1), t, &run.err_h[1], 0),
                ],
                y_range: Some((-25.0, 25.0)),
            },
            Panel {
                title: "vertical velocity error".into(),
                y_label: "δV_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &run.err_vz[0], 1),
                    Series::line(label(1), t, &run.err_vz[1], 0),
                ],
                y_range: Some((-3.0, 3.0)),
            },
            Panel {
                title: "altitude error, noise-free twin (settle time: |δh| ≤ 1 m to the end)"
                    .into(),
                y_label: "δh, m".into(),
                series: vec![
                    Series::line(label(0), t, &twin.err_h[0], 1),
                    Series::line(label(1), t, &twin.err_h[1], 0),
                    Series::dashed("±1 m", &[0.0, cfg.duration_s], &[1.0, 1.0], 7),
                    Series::dashed("", &[0.0, cfg.duration_s], &[-1.0, -1.0], 7),
                ],
                y_range: Some((-25.0, 25.0)),
            },
            Panel {
                title: "vertical velocity error, noise-free twin".into(),
                y_label: "δV_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &twin.err_vz[0], 1),
                    Series::line(label(1), t, &twin.err_vz[1], 0),
                ],
                y_range: Some((-3.0, 3.0)),
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("fig3_response.png"), 1400, 1200)?;
    Ok(())
}

pub(super) fn run_montecarlo(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    let tau = cfg.classical.tau_s;
    let mc = monte_carlo_rmse(&cfg, tau, ctx.runs, ctx.seed, ctx.progress)?;
    let mut loops = serde_json::Map::new();
    // RMSE over runs within windows, for the report.
    let window = |l: usize, q: usize, a: f64, b: f64| {
        let v: Vec<f64> =
            mc.t.iter()
                .zip(&mc.rmse_t[l][q])
                .filter(|(t, _)| **t >= a && **t < b)
                .map(|(_, r)| r * r)
                .collect();
        sig((v.iter().sum::<f64>() / v.len().max(1) as f64).sqrt(), 4)
    };
    for (l, name) in LOOPS.iter().enumerate() {
        println!(
            "  {name:<9} RMSE h {:.3} m  V_z {:.4} m/s",
            mc.rmse[l][0], mc.rmse[l][1]
        );
        loops.insert(
            name.to_string(),
            json!({
                "rmse_h_m": sig(mc.rmse[l][0], 4),
                "rmse_vz_mps": sig(mc.rmse[l][1], 4),
                "rmse_h_m_5_to_60_s": window(l, 0, 5.0, 60.0),
                "rmse_vz_mps_5_to_60_s": window(l, 1, 5.0, 60.0),
                "rmse_h_m_after_60_s": window(l, 0, 60.0, f64::INFINITY),
                "rmse_vz_mps_after_60_s": window(l, 1, 60.0, f64::INFINITY),
            }),
        );
    }
    write_rmse(ctx, tau, &mc)?;
    print_consistency(&mc);
    nees_figure(
        &format!("vc-montecarlo: NEES of (h, V_z), {} runs", ctx.runs),
        &mc.consistency,
        &ctx.out_dir.join("nees.png"),
    )?;
    Ok(json!({
        "consistency": consistency_json(&mc.consistency),
        "loops": loops,
        "design": design_json(&cfg, tau)?,
        "precision": cfg.precision,
        "initial_error_mode": cfg.initial_error.mode,
    }))
}

/// `rmse.csv` and `fig4_rmse.png`: both loops' RMSE over the runs against time (linear and
/// log10).
fn write_rmse(ctx: &Context, tau: f64, mc: &McResult) -> Result<()> {
    let t = &mc.t;
    let label = |l: usize| loop_label(l, tau);
    let cols: Vec<&[f64]> = vec![
        t,
        &mc.rmse_t[0][0],
        &mc.rmse_t[1][0],
        &mc.rmse_t[0][1],
        &mc.rmse_t[1][1],
    ];
    write_csv(
        &ctx.out_dir.join("rmse.csv"),
        &[
            "t_s",
            "rmse_h_classical_m",
            "rmse_h_aided_m",
            "rmse_vz_classical_mps",
            "rmse_vz_aided_mps",
        ],
        &cols,
    )?;
    let log10 = |v: &[f64]| v.iter().map(|x| x.max(1e-6).log10()).collect::<Vec<_>>();
    let fig = Figure {
        title: format!(
            "Vertical channel Monte Carlo RMSE (seed Fig. 4), {} runs",
            ctx.runs
        ),
        x_label: "time, s".into(),
        columns: 2,
        panels: vec![
            Panel {
                title: "altitude RMSE".into(),
                y_label: "RMSE h, m".into(),
                series: vec![
                    Series::line(label(0), t, &mc.rmse_t[0][0], 1),
                    Series::line(label(1), t, &mc.rmse_t[1][0], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE".into(),
                y_label: "RMSE V_z, m/s".into(),
                series: vec![
                    Series::line(label(0), t, &mc.rmse_t[0][1], 1),
                    Series::line(label(1), t, &mc.rmse_t[1][1], 0),
                ],
                y_range: None,
            },
            Panel {
                title: "altitude RMSE (log10)".into(),
                y_label: "log10 RMSE h [m]".into(),
                series: vec![
                    Series::line(label(0), t, &log10(&mc.rmse_t[0][0]), 1),
                    Series::line(label(1), t, &log10(&mc.rmse_t[1][0]), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE (log10)".into(),
                y_label: "log10 RMSE V_z [m/s]".into(),
                series: vec![
                    Series::line(label(0), t, &log10(&mc.rmse_t[0][1]), 1),
                    Series::line(label(1), t, &log10(&mc.rmse_t[1][1]), 0),
                ],
                y_range: None,
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("fig4_rmse.png"), 1400, 900)?;
    Ok(())
}

pub(super) fn run_tau_sweep(ctx: &Context) -> Result<Value> {
    let cfg: Config = ctx.config()?;
    ensure!(!cfg.tau_sweep_s.is_empty(), "tau_sweep_s is empty");
    let mut rows = Vec::new();
    let (mut taus, mut rh, mut rv, mut st) = (vec![], vec![], vec![], vec![]);
    let mut aided_ref = None;
    let mut nees: Vec<(Consistency, String)> = Vec::new();
    for (i, &tau) in cfg.tau_sweep_s.iter().enumerate() {
        let mc = monte_carlo_rmse(&cfg, tau, ctx.runs, ctx.seed, ctx.progress)?;
        println!(
            "  τ = {tau:>6} s  classical RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
            mc.rmse[0][0],
            mc.rmse[0][1],
            mc.settle_s[0].map_or("never".into(), |s| format!("{s:.1} s"))
        );
        nees.push((
            mc.consistency[0].clone(),
            format!("classical loop τ = {tau} s, design σ"),
        ));
        rows.push(json!({
            "consistency": mc.consistency[0].summary(),
            "tau_s": tau,
            "rmse_h_m": sig(mc.rmse[0][0], 4),
            "rmse_vz_mps": sig(mc.rmse[0][1], 4),
            "settle_time_s": settle_json(mc.settle_s[0]),
        }));
        taus.push(tau);
        rh.push(mc.rmse[0][0]);
        rv.push(mc.rmse[0][1]);
        st.push(mc.settle_s[0].unwrap_or(f64::NAN));
        if i == 0 {
            nees.push((
                mc.consistency[1].clone(),
                "velocity-aided loop, design σ".into(),
            ));
            nees.push((
                mc.consistency[2].clone(),
                "velocity-aided loop, Riccati σ (paper)".into(),
            ));
            aided_ref = Some(json!({
                "consistency": mc.consistency[1].summary(),
                "consistency_riccati": mc.consistency[2].summary(),
                "rmse_h_m": sig(mc.rmse[1][0], 4),
                "rmse_vz_mps": sig(mc.rmse[1][1], 4),
                "settle_time_s": settle_json(mc.settle_s[1]),
            }));
            println!(
                "  aided reference: RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
                mc.rmse[1][0],
                mc.rmse[1][1],
                mc.settle_s[1].map_or("never".into(), |s| format!("{s:.1} s"))
            );
        }
    }
    let aided_rows = aided_design_sweep(ctx, &cfg)?;
    let aided = aided_ref.clone().unwrap_or(Value::Null);
    write_tau_sweep(ctx, &taus, [&rh, &rv, &st], &aided)?;
    nees_panels(
        &format!("vc-tau-sweep: NEES of (h, V_z), {} runs per τ", ctx.runs),
        nees.iter().map(|(c, a)| (c, a.clone())).collect(),
        &ctx.out_dir.join("nees.png"),
    )?;
    Ok(json!({
        "classical": rows,
        "aided_reference": aided,
        "aided_design_sweep": aided_rows,
        "precision": cfg.precision,
    }))
}

/// The aided loop over the design accelerometer noises of `aided_design_sweep_m_s2_rt_hz`:
/// one summary row each.
fn aided_design_sweep(ctx: &Context, cfg: &Config) -> Result<Vec<Value>> {
    let mut aided_rows = Vec::new();
    for &q in &cfg.aided_design_sweep_m_s2_rt_hz {
        let mut c2 = cfg.clone();
        c2.aided.accel_noise_design_m_s2_rt_hz = Some(q);
        let mc = monte_carlo_rmse(&c2, cfg.classical.tau_s, ctx.runs, ctx.seed, ctx.progress)?;
        println!(
            "  aided design accel noise {q:.1e} m/s²/√Hz: RMSE h {:.3} m  V_z {:.4} m/s  settle {}",
            mc.rmse[1][0],
            mc.rmse[1][1],
            mc.settle_s[1].map_or("never".into(), |s| format!("{s:.1} s"))
        );
        aided_rows.push(json!({
            "consistency": mc.consistency[1].summary(),
            "accel_noise_design_m_s2_rt_hz": q,
            "rmse_h_m": sig(mc.rmse[1][0], 4),
            "rmse_vz_mps": sig(mc.rmse[1][1], 4),
            "settle_time_s": settle_json(mc.settle_s[1]),
        }));
    }
    Ok(aided_rows)
}

/// `tau_sweep.csv` and `tau_sweep.png`: the classical loop's altitude and velocity RMSE (m,
/// m/s) and noise-free settle time (s) against τ (`taus`, s), the aided loop's (`aided`) as
/// reference.
fn write_tau_sweep(
    ctx: &Context,
    taus: &[f64],
    [rh, rv, st]: [&[f64]; 3],
    aided: &Value,
) -> Result<()> {
    write_csv(
        &ctx.out_dir.join("tau_sweep.csv"),
        &["tau_s", "rmse_h_m", "rmse_vz_mps", "settle_time_s"],
        &[taus, rh, rv, st],
    )?;
    let flat = |key: &str| {
        let v = aided[key].as_f64().unwrap_or(f64::NAN);
        vec![v; taus.len()]
    };
    let lt: Vec<f64> = taus.iter().map(|t| t.log10()).collect();
    let fig = Figure {
        title: format!(
            "Classical loop τ sweep ({} runs each); dashed: velocity-aided loop",
            ctx.runs
        ),
        x_label: "log10 τ [s]".into(),
        columns: 3,
        panels: vec![
            Panel {
                title: "altitude RMSE".into(),
                y_label: "m".into(),
                series: vec![
                    Series::line("classical", &lt, rh, 1),
                    Series::dashed("aided", &lt, &flat("rmse_h_m"), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity RMSE".into(),
                y_label: "m/s".into(),
                series: vec![
                    Series::line("classical", &lt, rv, 1),
                    Series::dashed("aided", &lt, &flat("rmse_vz_mps"), 0),
                ],
                y_range: None,
            },
            Panel {
                title: "noise-free settle time (1 m)".into(),
                y_label: "s".into(),
                series: vec![
                    Series::line("classical", &lt, st, 1),
                    Series::dashed("aided", &lt, &flat("settle_time_s"), 0),
                ],
                y_range: None,
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("tau_sweep.png"), 1500, 500)?;
    Ok(())
}

/// The `consistency` object of every filter ([`FILTERS`]).
fn consistency_json(cons: &[Consistency]) -> Value {
    let mut m = serde_json::Map::new();
    for (name, c) in FILTERS.iter().zip(cons) {
        m.insert((*name).to_string(), c.summary());
    }
    Value::Object(m)
}

/// NEES plots of every filter with their 95 % bands.
fn nees_figure(title: &str, cons: &[Consistency], path: &std::path::Path) -> Result<()> {
    let about = [
        "classical loop, design σ".to_string(),
        "velocity-aided loop, design σ".to_string(),
        "velocity-aided loop, Riccati σ (paper)".to_string(),
    ];
    nees_panels(title, cons.iter().zip(about).collect(), path)
}

/// A figure of NEES panels (one per filter, labelled).
fn nees_panels(
    title: &str,
    filters: Vec<(&Consistency, String)>,
    path: &std::path::Path,
) -> Result<()> {
    let rows = filters.len() as u32;
    let panels = filters
        .into_iter()
        .map(|(c, a)| {
            let mut p = c.nees_panel(&a);
            // The Riccati σ ignores the correlated baro error: its NEES is orders of magnitude
            // above the band; plotted in log10 so the band stays visible.
            if c.nees_mean.iter().any(|v| *v > 1e3) {
                for s in &mut p.series {
                    for y in &mut s.y {
                        *y = y.max(1e-3).log10();
                    }
                }
                p.y_label = "log10 NEES".into();
                p.title = format!("{} (log10)", p.title);
            }
            p
        })
        .collect();
    let fig = Figure {
        title: title.into(),
        x_label: "time, s".into(),
        columns: 1,
        panels,
    };
    render(&fig, path, 1200, 120 + 330 * rows)
}

/// The consistency of a Monte Carlo, printed.
fn print_consistency(mc: &McResult) {
    for (name, c) in FILTERS.iter().zip(&mc.consistency) {
        let s = c.summary();
        println!(
            "  {name:<14} NEES {} (band {}), in band {}, e²/σ² h {} V_z {}",
            s["nees_mean"],
            s["nees_band_95"],
            s["frac_in_band"],
            s["normalized_error_sq"]["h"],
            s["normalized_error_sq"]["vz"]
        );
    }
}

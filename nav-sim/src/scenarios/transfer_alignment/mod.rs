//! Transfer-alignment scenarios (spec `transfer-alignment.md`):
//!
//! - `ta-case` (files `ta-case1..3`): Monte Carlo of the conventional 9-state and proposed
//!   12-state filters on one flexure case; Figs. 2-6 of the paper.
//! - `ta-model-error` (file `ta-model-error`): the filters' τ 0/20/50/70 % longer than the truth
//!   (case 2); Fig. 7.
//! - `ta-observability` (file `ta-observability`): ranks of the observability matrices of the
//!   constant segments and the stripped observability matrices (Tables 1 and 2).
pub mod campaign;
pub mod config;
pub mod estimate;
pub mod fault;
pub mod truth;

use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::{Context, Kind};
use anyhow::{anyhow, Result};
use config::CaseConfig;
use estimate::{run_case, AxisMetrics, CaseResult, MethodStats};
use nalgebra::Vector3;
use nav_core::math::markov::MarkovOrder;
use nav_core::transfer_alignment::{segment, som_rank, AxisFlexure, RankReport, Segment};
use serde::Deserialize;
use serde_json::{json, Value};

/// `ta-case` registry entry.
pub const KIND_CASE: Kind = Kind {
    kind: "ta-case",
    about: "transfer alignment: conventional 9-state vs proposed 12-state filter, one flexure case (Figs. 2-6)",
    run: run_case_scenario,
};
/// `ta-model-error` registry entry.
pub const KIND_MODEL_ERROR: Kind = Kind {
    kind: "ta-model-error",
    about: "transfer alignment: filter correlation time longer than the truth (Fig. 7)",
    run: run_model_error,
};
/// `ta-observability` registry entry.
pub const KIND_OBSERVABILITY: Kind = Kind {
    kind: "ta-observability",
    about: "transfer alignment: observability / stripped observability matrix ranks (Tables 1-2)",
    run: run_observability,
};

const AXES: [&str; 3] = ["x", "y", "z"];

fn axes_json(m: &[AxisMetrics; 3]) -> Value {
    let mut o = serde_json::Map::new();
    for (name, a) in AXES.iter().zip(m) {
        o.insert(
            (*name).into(),
            json!({
                "rms_cruise_mrad": sig(a.rms_cruise_mrad, 4),
                "rms_after_accel_mrad": sig(a.rms_after_accel_mrad, 4),
                "final_rms_mrad": sig(a.final_rms_mrad, 4),
            }),
        );
    }
    Value::Object(o)
}

fn method_json(m: &MethodStats) -> Value {
    json!({
        "axes": axes_json(&m.axes),
        "mean_nis": m.mean_nis.iter().map(|v| sig(*v, 3)).collect::<Vec<_>>(),
        "rejected_fraction": sig(m.rejected_fraction, 3),
        "consistency": m.consistency.summary(),
    })
}

fn mrad(v: &[f64]) -> Vec<f64> {
    v.iter().map(|x| x * 1e3).collect()
}

fn print_consistency(r: &CaseResult) {
    for (label, m) in [
        ("conventional", &r.conventional),
        ("proposed", &r.proposed),
        ("flight", &r.flight),
    ] {
        let c = &m.consistency;
        let nes: Vec<String> = c
            .normalized_error_sq
            .iter()
            .map(|(n, v)| format!("{n} {v:.2}"))
            .collect();
        println!(
            "  {label:<13}NEES {:.2} (band {:.2}-{:.2}), in band {:.2}; e²/σ²: {}",
            c.mean_nees(),
            crate::consistency::nees_band_95(c.dof, c.runs).0,
            crate::consistency::nees_band_95(c.dof, c.runs).1,
            c.frac_in_band(),
            nes.join(", ")
        );
    }
}

fn print_method(label: &str, m: &MethodStats) {
    for (name, a) in AXES.iter().zip(&m.axes) {
        println!(
            "  {label:<13}{name}: cruise {:>8.3}  after accel {:>8.3}  final {:>8.3} mrad",
            a.rms_cruise_mrad, a.rms_after_accel_mrad, a.final_rms_mrad
        );
    }
}

fn write_case_outputs(ctx: &Context, cfg: &CaseConfig, r: &CaseResult) -> Result<Value> {
    let acc = write_flexure_accel(ctx, r)?;
    write_single_run(ctx, r)?;
    write_monte_carlo(ctx, r)?;
    // NEES of θ of the three filters with their 95 % bands.
    render_nees(ctx, r)?;
    // Flexure angular-acceleration level of this case (theory β²σ for the 3rd-order truth).
    let acc_rms: Vec<f64> = acc
        .iter()
        .map(|v| (v.iter().map(|x| x * x).sum::<f64>() / v.len() as f64).sqrt())
        .collect();
    let theory: Vec<f64> = (0..3)
        .map(|a| {
            let b = MarkovOrder::Third.beta_tau() / cfg.truth_flexure.tau_s[a];
            b * b * cfg.truth_flexure.sigma_deg[a].to_radians()
        })
        .collect();
    Ok(json!({
        "flexure_accel_rms_rad_s2_run0": acc_rms.iter().map(|v| sig(*v, 3)).collect::<Vec<_>>(),
        "flexure_accel_rms_rad_s2_markov3_theory": theory.iter().map(|v| sig(*v, 3)).collect::<Vec<_>>(),
    }))
}

/// Fig. 2: `flexure_accel.{csv,png}`, the flexure angular acceleration of the case (run 0);
/// returns it per axis, rad/s².
fn write_flexure_accel(ctx: &Context, r: &CaseResult) -> Result<Vec<Vec<f64>>> {
    let t = &r.t_s;
    let dir = &ctx.out_dir;
    let truth = &r.run0.0;
    // Fig. 2: flexure angular acceleration of this case (run 0).
    let acc: Vec<Vec<f64>> = (0..3)
        .map(|a| truth.theta_f_accel_rad_s2.iter().map(|v| v[a]).collect())
        .collect();
    write_csv(
        &dir.join("flexure_accel.csv"),
        &[
            "t_s",
            "theta_f_dd_x_rad_s2",
            "theta_f_dd_y_rad_s2",
            "theta_f_dd_z_rad_s2",
        ],
        &[t, &acc[0], &acc[1], &acc[2]],
    )?;
    render(
        &Figure {
            title: format!("{}: flexure angular acceleration θ̈_f (run 0)", ctx.name),
            x_label: "time, s".into(),
            columns: 1,
            panels: (0..3)
                .map(|a| Panel {
                    title: format!("{} axis", AXES[a].to_uppercase()),
                    y_label: "rad/s²".into(),
                    series: vec![Series::line("θ̈_f", t, &acc[a], 0)],
                    y_range: None,
                })
                .collect(),
        },
        &dir.join("flexure_accel.png"),
        1000,
        900,
    )?;
    Ok(acc)
}

/// Figs. 3-5: `single_run.{csv,png}`, the estimation error of both paper filters in run 0.
fn write_single_run(ctx: &Context, r: &CaseResult) -> Result<()> {
    let t = &r.t_s;
    let dir = &ctx.out_dir;
    let (truth, conv, prop) = &r.run0;
    // Figs. 3-5: one run, estimation error of both methods.
    let ec: Vec<Vec<f64>> = conv.err_rad.iter().map(|v| mrad(v)).collect();
    let ep: Vec<Vec<f64>> = prop.err_rad.iter().map(|v| mrad(v)).collect();
    let th: Vec<Vec<f64>> = (0..3)
        .map(|a| truth.theta_rad.iter().map(|v| v[a] * 1e3).collect())
        .collect();
    write_csv(
        &dir.join("single_run.csv"),
        &[
            "t_s",
            "theta_x_mrad",
            "theta_y_mrad",
            "theta_z_mrad",
            "err_conv_x_mrad",
            "err_conv_y_mrad",
            "err_conv_z_mrad",
            "err_prop_x_mrad",
            "err_prop_y_mrad",
            "err_prop_z_mrad",
        ],
        &[
            t, &th[0], &th[1], &th[2], &ec[0], &ec[1], &ec[2], &ep[0], &ep[1], &ep[2],
        ],
    )?;
    let span = |a: usize| {
        // Range: the larger of the errors after 0.2 s, at most ±20 mrad (the Z error starts at
        // the mounting misalignment and is not estimated during the first cruise).
        let m = ec[a]
            .iter()
            .chain(&ep[a])
            .zip(t.iter().chain(t))
            .filter(|(_, tt)| **tt > 0.2)
            .fold(0.5f64, |m, (v, _)| m.max(v.abs()))
            .min(20.0)
            * 1.1;
        Some((-m, m))
    };
    render(
        &Figure {
            title: format!("{}: estimation error of θ = θ_m + θ_f, one run", ctx.name),
            x_label: "time, s".into(),
            columns: 1,
            panels: (0..3)
                .map(|a| Panel {
                    title: format!("{} axis", AXES[a].to_uppercase()),
                    y_label: "error, mrad".into(),
                    series: vec![
                        Series::line("conventional (9 states)", t, &ec[a], 1),
                        Series::line("proposed (12 states)", t, &ep[a], 0),
                    ],
                    y_range: span(a),
                })
                .collect(),
        },
        &dir.join("single_run.png"),
        1000,
        900,
    )?;
    Ok(())
}

/// Fig. 6: `monte_carlo.{csv,png}`, the Monte Carlo 1σ of both paper filters' errors with
/// their own σ.
/// `monte_carlo.csv`: per axis, RMS and 1σ of the error over the runs and the filter's σ, of
/// the conventional (`c`) and the proposed (`p`) filter, mrad.
fn write_monte_carlo_csv(
    dir: &std::path::Path,
    t: &[f64],
    c: &MethodStats,
    p: &MethodStats,
) -> Result<()> {
    write_csv(
        &dir.join("monte_carlo.csv"),
        &[
            "t_s",
            "conv_rms_x_mrad",
            "conv_rms_y_mrad",
            "conv_rms_z_mrad",
            "conv_std_x_mrad",
            "conv_std_y_mrad",
            "conv_std_z_mrad",
            "conv_sigma_x_mrad",
            "conv_sigma_y_mrad",
            "conv_sigma_z_mrad",
            "prop_rms_x_mrad",
            "prop_rms_y_mrad",
            "prop_rms_z_mrad",
            "prop_std_x_mrad",
            "prop_std_y_mrad",
            "prop_std_z_mrad",
            "prop_sigma_x_mrad",
            "prop_sigma_y_mrad",
            "prop_sigma_z_mrad",
        ],
        &[
            t,
            &c.rms_mrad[0],
            &c.rms_mrad[1],
            &c.rms_mrad[2],
            &c.std_mrad[0],
            &c.std_mrad[1],
            &c.std_mrad[2],
            &c.filter_sigma_mrad[0],
            &c.filter_sigma_mrad[1],
            &c.filter_sigma_mrad[2],
            &p.rms_mrad[0],
            &p.rms_mrad[1],
            &p.rms_mrad[2],
            &p.std_mrad[0],
            &p.std_mrad[1],
            &p.std_mrad[2],
            &p.filter_sigma_mrad[0],
            &p.filter_sigma_mrad[1],
            &p.filter_sigma_mrad[2],
        ],
    )?;
    Ok(())
}

fn write_monte_carlo(ctx: &Context, r: &CaseResult) -> Result<()> {
    let t = &r.t_s;
    let dir = &ctx.out_dir;
    // Fig. 6: Monte Carlo 1σ with the filters' own σ.
    let (c, p) = (&r.conventional, &r.proposed);
    write_monte_carlo_csv(dir, t, c, p)?;
    let mc_span = |a: usize| {
        let m = [
            &c.std_mrad[a],
            &p.std_mrad[a],
            &c.filter_sigma_mrad[a],
            &p.filter_sigma_mrad[a],
        ]
        .iter()
        .flat_map(|v| {
            v.iter()
                .zip(t)
                .filter(|(_, tt)| **tt > 0.2)
                .map(|(x, _)| *x)
        })
        .fold(0.5f64, f64::max)
        .min(20.0)
            * 1.1;
        Some((0.0, m))
    };
    render(
        &Figure {
            title: format!(
                "{}: Monte Carlo 1σ of the error ({} runs, solid) and filter σ (dashed)",
                ctx.name, ctx.runs
            ),
            x_label: "time, s".into(),
            columns: 1,
            panels: (0..3)
                .map(|a| Panel {
                    title: format!("{} axis", AXES[a].to_uppercase()),
                    y_label: "1σ, mrad".into(),
                    series: vec![
                        Series::line("conventional MC 1σ", t, &c.std_mrad[a], 1),
                        Series::dashed("conventional filter σ", t, &c.filter_sigma_mrad[a], 1),
                        Series::line("proposed MC 1σ", t, &p.std_mrad[a], 0),
                        Series::dashed("proposed filter σ", t, &p.filter_sigma_mrad[a], 0),
                    ],
                    y_range: mc_span(a),
                })
                .collect(),
        },
        &dir.join("monte_carlo.png"),
        1000,
        900,
    )?;
    Ok(())
}

/// `nees.png`: the run-averaged NEES of θ of each filter (paper filters and the flight
/// configuration) with its 95 % χ² band, one panel each (each on its own scale).
fn render_nees(ctx: &Context, r: &CaseResult) -> Result<()> {
    let panels = [
        ("conventional 9-state (paper)", &r.conventional),
        ("proposed 12-state (paper)", &r.proposed),
        ("flight configuration (15 states)", &r.flight),
    ]
    .iter()
    .map(|(name, m)| m.consistency.nees_panel(name))
    .collect();
    render(
        &Figure {
            title: format!("{}: NEES of θ (3 states)", ctx.name),
            x_label: "time, s".into(),
            columns: 1,
            panels,
        },
        &ctx.out_dir.join("nees.png"),
        1000,
        900,
    )
}

fn run_case_scenario(ctx: &Context) -> Result<Value> {
    let cfg: CaseConfig = ctx.config()?;
    let r = run_case(&cfg, ctx.runs, ctx.seed, 0.0, ctx.progress, &ctx.name)?;
    print_method("conventional", &r.conventional);
    print_method("proposed", &r.proposed);
    print_method("flight", &r.flight);
    print_consistency(&r);
    let extra = write_case_outputs(ctx, &cfg, &r)?;
    let fc = cfg.filter_config(0.0);
    Ok(json!({
        "methods": {
            "conventional": method_json(&r.conventional),
            "proposed": method_json(&r.proposed),
            "flight": method_json(&r.flight),
        },
        "nees_states": "theta_x, theta_y, theta_z (total misalignment θ = θ_m + θ_f)",
        "truth_flexure_model": format!("{:?}", cfg.truth_flexure.model),
        "flexure_sigma_deg": cfg.truth_flexure.sigma_deg,
        "flexure_tau_s": cfg.truth_flexure.tau_s,
        "filter_rate_noise_sigma_rad_s": sig(fc.rate_noise_sigma_rad_s, 4),
        "filter_accel_noise_sigma_m_s2": sig(fc.accel_noise_sigma_m_s2, 4),
        "flight_accel_bias_sigma_m_s2": fc.accel_bias_sigma_m_s2.iter().map(|v| sig(*v, 4)).collect::<Vec<_>>(),
        "precision": format!("{:?}", cfg.precision),
        "windows_s": {"cruise": estimate::CRUISE_WINDOW_S, "after_accel_from": estimate::AFTER_ACCEL_FROM_S},
        "flexure": extra,
    }))
}

/// `ta-model-error` configuration: the τ errors and the case the truth comes from.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelErrorConfig {
    /// Filter τ error levels, % longer than the truth.
    pub tau_error_pct: Vec<f64>,
    /// The case (truth, sensors, profile).
    pub case: CaseConfig,
}

fn run_model_error(ctx: &Context) -> Result<Value> {
    let cfg: ModelErrorConfig = ctx.config()?;
    let mut levels = Vec::new();
    let mut results = Vec::new();
    for pct in &cfg.tau_error_pct {
        // Same seed: every level sees the same truth.
        let r = run_case(
            &cfg.case,
            ctx.runs,
            ctx.seed,
            *pct,
            ctx.progress,
            &format!("τ +{pct}%"),
        )?;
        println!("τ error +{pct} %:");
        print_method("proposed", &r.proposed);
        print_method("conventional", &r.conventional);
        levels.push(json!({
            "tau_error_pct": pct,
            "filter_tau_s": cfg.case.truth_flexure.tau_s.map(|t| sig(t * (1.0 + pct / 100.0), 4)),
            "proposed": method_json(&r.proposed),
            "conventional": method_json(&r.conventional),
            "flight": method_json(&r.flight),
        }));
        results.push((*pct, r));
    }
    let t = results
        .first()
        .map(|(_, r)| r.t_s.clone())
        .ok_or_else(|| anyhow!("no τ error levels"))?;
    let mut headers = vec!["t_s".to_string()];
    let mut cols: Vec<&[f64]> = vec![&t];
    for (pct, r) in &results {
        for (a, name) in AXES.iter().enumerate() {
            headers.push(format!("prop_rms_{name}_mrad_tau_plus_{pct}pct"));
            cols.push(&r.proposed.rms_mrad[a]);
        }
    }
    let h: Vec<&str> = headers.iter().map(String::as_str).collect();
    write_csv(&ctx.out_dir.join("model_error.csv"), &h, &cols)?;
    let panels = (0..3)
        .map(|a| {
            let m = results
                .iter()
                .flat_map(|(_, r)| r.proposed.rms_mrad[a].iter().zip(&t))
                .filter(|(_, tt)| **tt > 0.2)
                .fold(0.5f64, |m, (v, _)| m.max(*v))
                .min(20.0)
                * 1.1;
            Panel {
                title: format!("{} axis, proposed filter", AXES[a].to_uppercase()),
                y_label: "RMS error, mrad".into(),
                series: results
                    .iter()
                    .enumerate()
                    .map(|(i, (pct, r))| {
                        Series::line(format!("τ +{pct} %"), &t, &r.proposed.rms_mrad[a], i)
                    })
                    .collect(),
                y_range: Some((0.0, m)),
            }
        })
        .collect();
    render(
        &Figure {
            title: format!(
                "{}: Monte Carlo RMS error vs filter correlation-time error ({} runs)",
                ctx.name, ctx.runs
            ),
            x_label: "time, s".into(),
            columns: 1,
            panels,
        },
        &ctx.out_dir.join("model_error.png"),
        1000,
        900,
    )?;
    Ok(json!({ "levels": levels }))
}

/// `ta-observability` configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ObservabilityConfig {
    /// Lever arm L_0, m.
    pub lever_arm_m: [f64; 3],
    /// Flexure 1σ per axis, deg.
    pub sigma_deg: [f64; 3],
    /// Flexure correlation time per axis, s.
    pub tau_s: [f64; 3],
    /// Gravity, m/s².
    pub gravity_m_s2: f64,
    /// Horizontal acceleration of the accelerated segments, g.
    pub accel_g: f64,
    /// Relative residual threshold of the rank.
    pub rel_tol: f64,
}

/// Segment and SOM names of the observability tables.
pub const SEGMENT_NAMES: [&str; 4] = ["cruise", "accel_x", "accel_y", "accel_xy"];
/// SOM names: cruise followed by each accelerated segment.
pub const SOM_NAMES: [&str; 3] = ["cruise+accel_x", "cruise+accel_y", "cruise+accel_xy"];

/// Ranks of the four segments and of the three SOMs.
pub type ObservabilityRanks = ([RankReport<f64>; 4], [RankReport<f64>; 3]);

/// Rank reports of the four segments and the three SOMs for the K-per-axis model.
pub fn observability_ranks<const K: usize, const N: usize>(
    cfg: &ObservabilityConfig,
) -> Result<ObservabilityRanks> {
    let flex: [AxisFlexure<f64>; 3] = std::array::from_fn(|a| AxisFlexure {
        sigma_rad: cfg.sigma_deg[a].to_radians(),
        tau_s: cfg.tau_s[a],
    });
    let g = cfg.gravity_m_s2;
    let a = cfg.accel_g * config::G0_M_S2;
    let l0 = Vector3::from(cfg.lever_arm_m);
    let w = Vector3::zeros();
    let seg = |f: Vector3<f64>| -> Result<Segment<f64, N, 6>> {
        segment::<f64, K, N>(&flex, &f, &w, &l0).map_err(|e| anyhow!("{e}"))
    };
    let segs = [
        seg(Vector3::new(0.0, 0.0, -g))?,
        seg(Vector3::new(a, 0.0, -g))?,
        seg(Vector3::new(0.0, a, -g))?,
        seg(Vector3::new(a, a, -g))?,
    ];
    let tol = cfg.rel_tol;
    let singles = std::array::from_fn(|i| som_rank(&segs[i..=i], tol));
    let soms = std::array::from_fn(|i| som_rank(&[segs[0], segs[i + 1]], tol));
    Ok((singles, soms))
}

fn rank_json(name: &str, r: &RankReport<f64>) -> Value {
    json!({
        "name": name,
        "rank": r.rank,
        "smallest_accepted_residual": sig(r.smallest_accepted, 3),
        "largest_rejected_residual": sig(r.largest_rejected, 3),
    })
}

fn run_observability(ctx: &Context) -> Result<Value> {
    let cfg: ObservabilityConfig = ctx.config()?;
    let (s12, m12) = observability_ranks::<4, 12>(&cfg)?;
    let (s9, m9) = observability_ranks::<3, 9>(&cfg)?;
    let mut rows = Vec::new();
    for (n, r) in SEGMENT_NAMES
        .iter()
        .zip(&s12)
        .chain(SOM_NAMES.iter().zip(&m12))
    {
        println!(
            "  12-state {n:<18} rank {:>2}  (smallest accepted residual {:.2e}, largest rejected {:.2e})",
            r.rank, r.smallest_accepted, r.largest_rejected
        );
        rows.push(format!("{n},{}", r.rank));
    }
    for (n, r) in SEGMENT_NAMES
        .iter()
        .zip(&s9)
        .chain(SOM_NAMES.iter().zip(&m9))
    {
        println!("  9-state  {n:<18} rank {:>2}", r.rank);
    }
    std::fs::write(
        ctx.out_dir.join("ranks.csv"),
        format!("name,rank_12_state\n{}\n", rows.join("\n")),
    )?;
    Ok(json!({
        "segments": SEGMENT_NAMES.iter().zip(&s12).map(|(n, r)| rank_json(n, r)).collect::<Vec<_>>(),
        "som": SOM_NAMES.iter().zip(&m12).map(|(n, r)| rank_json(n, r)).collect::<Vec<_>>(),
        "full_rank": 12,
        "conventional_9_state": {
            "segments": SEGMENT_NAMES.iter().zip(&s9).map(|(n, r)| rank_json(n, r)).collect::<Vec<_>>(),
            "som": SOM_NAMES.iter().zip(&m9).map(|(n, r)| rank_json(n, r)).collect::<Vec<_>>(),
            "full_rank": 9,
        },
    }))
}

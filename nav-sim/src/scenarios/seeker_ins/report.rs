//! Ensemble statistics, consistency figures, summaries, CSV and plots of the Monte Carlo runs.

use super::config::Config;
use super::errors::RunOutput;
use super::trajectory::Truth;
use crate::consistency::Consistency;
use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::Context;
use crate::stats::ensemble;
use crate::truth::radii_of_curvature_m as radii_m;
use anyhow::Result;
use nav_core::seeker_ins::STATES;
use serde_json::json;

/// Ensemble statistics of a batch of runs.
#[derive(Debug, Clone)]
pub struct Stats {
    /// Output times, s.
    pub t_s: Vec<f64>,
    /// Per channel (9): mean error over runs.
    pub mean: Vec<Vec<f64>>,
    /// Per channel: Monte Carlo σ about the mean.
    pub std: Vec<Vec<f64>>,
    /// Per channel: RMS over runs.
    pub rms: Vec<Vec<f64>>,
    /// Per channel: filter σ (RMS over runs).
    pub filter_sigma: Vec<Vec<f64>>,
    /// NEES averaged over runs (17, pos, vel, att).
    pub nees: Vec<Vec<f64>>,
    /// Totals.
    pub fused: usize,
    /// Totals.
    pub rejected: usize,
    /// Mean NIS per scalar component.
    pub nis_mean: f64,
    /// Out-of-field seeker epochs (run 0).
    pub out_of_field: usize,
    /// Refused updates (all runs).
    pub errors: usize,
    /// Runs.
    pub runs: usize,
    /// NEES of the 17 states against its band and per state group ([`super::errors::GROUPS`]).
    pub consistency: Consistency,
}

/// Statistics over runs.
pub fn statistics(runs: &[RunOutput], t_s: Vec<f64>) -> Stats {
    let mut st = Stats {
        t_s,
        mean: vec![],
        std: vec![],
        rms: vec![],
        filter_sigma: vec![],
        nees: vec![],
        fused: runs.iter().map(|r| r.fused).sum(),
        rejected: runs.iter().map(|r| r.rejected).sum(),
        nis_mean: 0.0,
        out_of_field: runs.first().map_or(0, |r| r.out_of_field),
        errors: runs.iter().map(|r| r.errors).sum(),
        runs: runs.len(),
        consistency: Consistency::from_runs(
            STATES,
            &runs
                .iter()
                .map(|r| r.consistency.clone())
                .collect::<Vec<_>>(),
        ),
    };
    let comps = st.fused + st.rejected;
    st.nis_mean = runs.iter().map(|r| r.nis_sum).sum::<f64>() / comps.max(1) as f64;
    for i in 0..9 {
        let series: Vec<Vec<f64>> = runs.iter().map(|r| r.err[i].clone()).collect();
        let e = ensemble(&series);
        st.mean.push(e.mean);
        st.std.push(e.std);
        st.rms.push(e.rms);
        let sig: Vec<Vec<f64>> = runs.iter().map(|r| r.sigma[i].clone()).collect();
        st.filter_sigma.push(ensemble(&sig).rms);
    }
    for b in 0..4 {
        let series: Vec<Vec<f64>> = runs.iter().map(|r| r.nees[b].clone()).collect();
        st.nees.push(ensemble(&series).mean);
    }
    st
}

/// Channel names (summary keys) in the order of [`RunOutput::err`].
pub const CHANNELS: [&str; 9] = [
    "lat_m",
    "lon_m",
    "alt_m",
    "vn_mps",
    "ve_mps",
    "vd_mps",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
];

fn channel_json(values: impl Fn(usize) -> f64, n: usize) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for (i, name) in CHANNELS.iter().enumerate().take(n) {
        m.insert((*name).into(), json!(sig(values(i), 4)));
    }
    serde_json::Value::Object(m)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

pub(super) fn summary_block(st: &Stats) -> serde_json::Value {
    json!({
        "max_abs_mean_error": channel_json(|i| max_abs(&st.mean[i]), 3),
        "final_rms": channel_json(|i| *st.rms[i].last().unwrap_or(&f64::NAN), 9),
        "max_rms": channel_json(|i| max_abs(&st.rms[i]), 9),
        "final_mc_std": channel_json(|i| *st.std[i].last().unwrap_or(&f64::NAN), 9),
        "final_filter_sigma": channel_json(|i| *st.filter_sigma[i].last().unwrap_or(&f64::NAN), 9),
        "max_abs_mean_error_all": channel_json(|i| max_abs(&st.mean[i]), 9),
    })
}

pub(super) fn write_outputs(
    ctx: &Context,
    cfg: &Config,
    truth: &Truth,
    aided: &Stats,
    free: &Stats,
    first: &RunOutput,
) -> Result<()> {
    write_errors_csv(ctx, aided, free)?;
    let shape = format!("{:?}", cfg.trajectory.shape);
    write_error_figures(ctx, &shape, aided, free)?;
    write_nees_figure(ctx, &shape, aided)?;
    write_trajectory(ctx, cfg, &shape, truth, first)
}

/// Titles of the nine error channels.
const TITLES: [&str; 9] = [
    "latitude error",
    "longitude error",
    "altitude error",
    "north velocity error",
    "east velocity error",
    "down velocity error",
    "roll error",
    "pitch error",
    "yaw error",
];

/// Units of the channels.
const UNITS: [&str; 9] = ["m", "m", "m", "m/s", "m/s", "m/s", "deg", "deg", "deg"];

/// `errors.csv`: per channel the error mean, Monte Carlo σ, filter σ and RMS of the aided
/// filter and the free INS's RMS; the NEES of the 17 states and of each block.
fn write_errors_csv(ctx: &Context, aided: &Stats, free: &Stats) -> Result<()> {
    // CSV: per channel mean, MC std, filter σ (aided), RMS aided and free; NEES.
    let mut headers: Vec<String> = vec!["t_s".into()];
    let mut cols: Vec<&[f64]> = vec![&aided.t_s];
    for (i, name) in CHANNELS.iter().enumerate() {
        headers.push(format!("{name}_mean"));
        cols.push(&aided.mean[i]);
        headers.push(format!("{name}_mc_std"));
        cols.push(&aided.std[i]);
        headers.push(format!("{name}_filter_sigma"));
        cols.push(&aided.filter_sigma[i]);
        headers.push(format!("{name}_rms"));
        cols.push(&aided.rms[i]);
        headers.push(format!("{name}_free_rms"));
        cols.push(&free.rms[i]);
    }
    for (b, name) in ["nees", "nees_pos", "nees_vel", "nees_att"]
        .iter()
        .enumerate()
    {
        headers.push((*name).into());
        cols.push(&aided.nees[b]);
    }
    let hdr: Vec<&str> = headers.iter().map(String::as_str).collect();
    write_csv(&ctx.out_dir.join("errors.csv"), &hdr, &cols)?;
    Ok(())
}

/// `errors.png` (error mean, Monte Carlo σ and filter σ per channel) and `aided_vs_free.png`
/// (RMS of the aided filter and the free INS).
fn write_error_figures(ctx: &Context, shape: &str, aided: &Stats, free: &Stats) -> Result<()> {
    let t = &aided.t_s;
    let neg = |v: &[f64]| v.iter().map(|x| -x).collect::<Vec<f64>>();
    let mut panels = Vec::new();
    for i in 0..9 {
        panels.push(Panel {
            title: TITLES[i].into(),
            y_label: UNITS[i].into(),
            series: vec![
                Series::line("error mean", t, &aided.mean[i], 0),
                Series::line("MC σ", t, &aided.std[i], 1),
                Series::line("", t, &neg(&aided.std[i]), 1),
                Series::dashed("filter σ", t, &aided.filter_sigma[i], 2),
                Series::dashed("", t, &neg(&aided.filter_sigma[i]), 2),
            ],
            y_range: None,
        });
    }
    render(
        &Figure {
            title: format!(
                "INS/seeker, {shape} trajectory: error mean, Monte Carlo σ and filter σ ({} runs)",
                aided.runs
            ),
            x_label: "time, s".into(),
            panels,
            columns: 3,
        },
        &ctx.out_dir.join("errors.png"),
        1500,
        1100,
    )?;
    // Aided vs free INS, RMS.
    let mut panels = Vec::new();
    for i in [0usize, 1, 2, 4, 7, 8] {
        panels.push(Panel {
            title: format!("{} RMS", TITLES[i]),
            y_label: UNITS[i].into(),
            series: vec![
                Series::line("aided", t, &aided.rms[i], 0),
                Series::dashed("free INS", t, &free.rms[i], 1),
            ],
            y_range: None,
        });
    }
    render(
        &Figure {
            title: format!("{shape}: RMS error over runs, seeker-aided vs free INS"),
            x_label: "time, s".into(),
            panels,
            columns: 3,
        },
        &ctx.out_dir.join("aided_vs_free.png"),
        1500,
        800,
    )?;
    Ok(())
}

/// `nees.png`: the run-averaged NEES of the 17 states and of each block with its 95 % band.
fn write_nees_figure(ctx: &Context, shape: &str, aided: &Stats) -> Result<()> {
    let t = &aided.t_s;
    // NEES.
    let runs = aided.runs.max(1) as f64;
    let mut panels = Vec::new();
    for (b, (name, dof)) in [
        ("17 states", 17.0),
        ("position", 3.0),
        ("velocity", 3.0),
        ("attitude", 3.0),
    ]
    .iter()
    .enumerate()
    {
        let (lo, hi) = crate::consistency::nees_band_95(*dof as usize, runs as usize);
        panels.push(Panel {
            title: format!("NEES, {name} (averaged over runs)"),
            y_label: "NEES".into(),
            series: vec![
                Series::line("NEES", t, &aided.nees[b], 0),
                Series::dashed("95 % bounds", t, &vec![lo; t.len()], 1),
                Series::dashed("", t, &vec![hi; t.len()], 1),
            ],
            y_range: Some((
                0.0,
                (3.0 * hi).max(
                    aided.nees[b]
                        .iter()
                        .skip(1)
                        .fold(0.0, |m: f64, x| m.max(x.min(10.0 * hi))),
                ),
            )),
        });
    }
    render(
        &Figure {
            title: format!("{shape}: filter consistency (NEES)"),
            x_label: "time, s".into(),
            panels,
            columns: 2,
        },
        &ctx.out_dir.join("nees.png"),
        1300,
        900,
    )?;
    Ok(())
}

/// `trajectory.png`: the ground track with the landmark, and the true gimbal angles of run 0
/// with their limit.
fn write_trajectory(
    ctx: &Context,
    cfg: &Config,
    shape: &str,
    truth: &Truth,
    first: &RunOutput,
) -> Result<()> {
    // Trajectory and gimbal angles.
    let lat0 = truth.position[0].lat_rad;
    let (rm, rn) = radii_m(lat0);
    let north: Vec<f64> = truth
        .position
        .iter()
        .map(|p| (p.lat_rad - lat0) * (rm + p.alt_m) / 1000.0)
        .collect();
    let east: Vec<f64> = truth
        .position
        .iter()
        .map(|p| (p.lon_rad - truth.position[0].lon_rad) * (rn + p.alt_m) * lat0.cos() / 1000.0)
        .collect();
    let mut lm_series = Series::line(
        "landmark",
        &[cfg.landmark.east_m / 1000.0],
        &[cfg.landmark.north_m / 1000.0],
        1,
    );
    lm_series.style = crate::plot::Style::Points;
    let tg: Vec<f64> = first.gimbal_deg.iter().map(|g| g.0).collect();
    let gp: Vec<f64> = first.gimbal_deg.iter().map(|g| g.1).collect();
    let gy: Vec<f64> = first.gimbal_deg.iter().map(|g| g.2).collect();
    let lim = cfg.rates.gimbal_limit_deg;
    render(
        &Figure {
            title: format!("{shape} trajectory (x: east, km) and true gimbal angles"),
            x_label: "east, km  |  time, s".into(),
            panels: vec![
                Panel {
                    title: "ground track".into(),
                    y_label: "north, km".into(),
                    series: vec![Series::line("truth", &east, &north, 0), lm_series],
                    y_range: Some((-10.0, 10.0)),
                },
                Panel {
                    title: "gimbal angles".into(),
                    y_label: "deg".into(),
                    series: vec![
                        Series::line("pitch θ_s", &tg, &gp, 0),
                        Series::line("yaw ψ_s", &tg, &gy, 2),
                        Series::dashed("limit", &tg, &vec![lim; tg.len()], 1),
                        Series::dashed("", &tg, &vec![-lim; tg.len()], 1),
                    ],
                    y_range: None,
                },
            ],
            columns: 1,
        },
        &ctx.out_dir.join("trajectory.png"),
        1200,
        900,
    )?;
    Ok(())
}

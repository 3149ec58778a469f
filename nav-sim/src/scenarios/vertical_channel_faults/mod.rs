//! Vertical channel fault injection, kind `vc-fault-baro` (scenario `fault-baro`).
//!
//! The base experiment (`base_scenario`, the vertical-channel truth and sensors) is flown with
//! three baro faults in sequence: a spike (the baro reads `offset_m` too high for
//! `duration_s`), a frozen baro (it repeats its last good reading with fresh time stamps), and
//! a dropout (no samples). Both loops run twice on the same sensor stream: with the χ²
//! innovation gate (([`nav_core::vertical_channel::AidModel`], [`nav_core::Gate`])) and without it. A
//! fault-free twin (same noise, no faults) of each gated loop is the reference for "normal".
//!
//! Figures of merit, per loop and run: the pre-fault bound (max |δh| over
//! `pre_fault_window_s`), per fault the peak |δh| from its start to the next fault, and the
//! recovery time: from the end of the fault until |δh| is back within the pre-fault bound and
//! stays there for `hold_within_s` (0 if it never left). Gate counters (rejections,
//! re-acquisitions, resets) and the steps spent with the baro `Lost` are reported.

use crate::consistency::{Consistency, RunConsistency};
use crate::montecarlo::monte_carlo;
use crate::output::write_csv;
use crate::plot::{render, Figure, Panel, Series};
use crate::rng::{normal, SimRng};
use crate::scenario::{Context, Kind};
use crate::scenarios::vertical_channel::{
    load_config, loop_configs, push_consistency, Config, Profile, AXES,
};
use crate::truth::gravity_down_m_s2;
use anyhow::{anyhow, ensure, Result};
use nalgebra::Matrix2;
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    Aid, AidModel, AidStatus, AidedLoop, BaroSample, ClassicalLoop, ImuSample, InitialState,
    ReacquisitionCounters, VelocitySample,
};
use nav_core::{AidCounters, Estimator, Gate, Real, RecoveryAction, RecoveryPolicy};
use serde::Deserialize;
use serde_json::{json, Value};

mod simulate;
pub use simulate::simulate;

/// The JSON summary type (re-exported for the cross-crate tests).
pub type Summary = Value;

/// `vc-fault-baro`.
pub const KIND: Kind = Kind {
    kind: "vc-fault-baro",
    about: "vertical channel: baro spike, frozen baro, baro dropout; gate, recovery",
    run: run_fault_baro,
};

/// A fault over a time window.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
}

impl Window {
    fn has(&self, t: f64) -> bool {
        t >= self.start_s && t < self.end_s
    }
}

/// Gate configuration (units in the names; see `nav_core::vertical_channel::AidModel`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GateConfig {
    /// χ² threshold on ν²/S (1 dof).
    pub nis_threshold: f64,
    /// Baro innovation σ₀ of a tracking loop, m.
    pub baro_sigma_m: f64,
    /// Velocity-aid innovation σ₀, m/s.
    pub velocity_sigma_m_s: f64,
    /// Re-inflation: velocity uncertainty of the inertial solution, m/s.
    pub starved_velocity_sigma_m_s: f64,
    /// Re-inflation: acceleration uncertainty, m/s².
    pub starved_accel_sigma_m_s2: f64,
    /// Recovery gate hold after a re-acquisition, s.
    pub recovery_hold_s: f64,
    /// Starvation limit: samples rejected without a break this long re-anchor the loop, s.
    pub starved_reset_after_s: f64,
}

impl GateConfig {
    /// The nav-core aid model these values describe.
    pub fn aid_model<T: Real>(&self) -> AidModel<T> {
        AidModel {
            baro_sigma_m: T::lit(self.baro_sigma_m),
            velocity_sigma_m_s: T::lit(self.velocity_sigma_m_s),
            starved_velocity_sigma_m_s: T::lit(self.starved_velocity_sigma_m_s),
            starved_accel_sigma_m_s2: T::lit(self.starved_accel_sigma_m_s2),
            recovery_hold_s: T::lit(self.recovery_hold_s),
        }
    }

    /// The nav-core gate.
    pub fn gate<T: Real>(&self) -> Gate<T> {
        Gate::Nis(T::lit(self.nis_threshold))
    }

    /// The nav-core recovery: re-anchor after `starved_reset_after_s` of rejections.
    pub fn recovery<T: Real>(&self) -> RecoveryPolicy<T> {
        RecoveryPolicy {
            starved_after_s: Some(T::lit(self.starved_reset_after_s)),
            action: RecoveryAction::Reanchor,
        }
    }
}

/// The baro counters of one loop.
#[derive(Debug, Clone, Copy, Default)]
pub struct BaroCounts {
    /// Fused, rejected … samples.
    pub counters: AidCounters,
    /// Re-acquisitions and resets.
    pub reacquisition: ReacquisitionCounters,
}

/// `fault-baro` configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    /// Scenario whose truth, sensors and loop designs are used (e.g. "vc-response").
    pub base_scenario: String,
    /// Initial altitude error (estimate − truth), m (overrides the base: start converged).
    pub initial_error_m: f64,
    /// Initial vertical-velocity error, m/s.
    pub initial_error_m_s: f64,
    /// Window over which the pre-fault bound (max |δh|) is taken, [start, end) s.
    pub pre_fault_window_s: [f64; 2],
    /// A recovery counts once |δh| stays within the pre-fault bound this long, s.
    pub hold_within_s: f64,
    /// Baro spike: reads `spike_offset_m` too high over the window.
    pub spike: Window,
    /// Spike size, m.
    pub spike_offset_m: f64,
    /// Frozen baro: repeats its last reading (fresh time stamps) over the window.
    pub frozen: Window,
    /// Baro dropout: no samples over the window.
    pub dropout: Window,
    /// The innovation gate of the gated loops.
    pub gate: GateConfig,
}

/// The loops of a run: classical and aided, gated and not.
pub const VARIANTS: [&str; 4] = [
    "classical_gated",
    "classical_ungated",
    "aided_gated",
    "aided_ungated",
];

/// One run's series (at the output interval) and figures of merit.
#[derive(Debug, Clone, Default)]
pub struct FaultRun {
    /// Output epochs, s.
    pub t: Vec<f64>,
    /// True altitude, m.
    pub h_true: Vec<f64>,
    /// Baro reading delivered to the loops (NaN when none), m.
    pub h_baro: Vec<f64>,
    /// δh per variant (and the gated twins: index 4 classical, 5 aided), m.
    pub err_h: [Vec<f64>; 6],
    /// |δh| at the IMU rate per variant and twin (for the metrics), m.
    abs_err: [Vec<f64>; 6],
    /// Baro gate counters per variant (and twins).
    pub counters: [BaroCounts; 6],
    /// IMU steps with the baro `Lost` per variant.
    pub lost_steps: [usize; 6],
    /// Consistency samples of (h, V_z) at the output epochs per variant and twin, with the σ
    /// the loops report.
    pub consistency: Vec<RunConsistency>,
}

/// The three faults in time order with their names.
fn faults(fc: &FaultConfig) -> [(&'static str, &Window); 3] {
    [
        ("spike", &fc.spike),
        ("frozen", &fc.frozen),
        ("dropout", &fc.dropout),
    ]
}

/// Recovery metrics of one error series (|δh| at the IMU rate).
#[derive(Debug, Clone, Copy)]
pub struct Recovery {
    /// Peak |δh| from the fault's start to the next fault's start (or the end), m.
    pub peak_m: f64,
    /// Time from the fault's end until |δh| is within the bound for `hold_within_s`; `None`
    /// if that does not happen before the next fault (or the end).
    pub recovery_s: Option<f64>,
}

/// Pre-fault bound and per-fault recovery of one series.
pub fn recovery(abs_err: &[f64], dt: f64, fc: &FaultConfig) -> (f64, [Recovery; 3]) {
    let idx = |t: f64| {
        ((t / dt).round() as usize)
            .saturating_sub(1)
            .min(abs_err.len())
    };
    let pre = &abs_err[idx(fc.pre_fault_window_s[0])..idx(fc.pre_fault_window_s[1])];
    let bound = pre.iter().cloned().fold(0.0, f64::max);
    let fs = faults(fc);
    let hold = (fc.hold_within_s / dt).round() as usize;
    let rec = core::array::from_fn(|i| {
        let (_, w) = fs[i];
        let next = fs.get(i + 1).map_or(abs_err.len(), |(_, n)| idx(n.start_s));
        let peak_m = abs_err[idx(w.start_s)..next]
            .iter()
            .cloned()
            .fold(0.0, f64::max);
        let end = idx(w.end_s);
        // First k ≥ end with |δh| ≤ bound over [k, k + hold).
        let mut run = 0usize;
        let mut found = None;
        for (k, &e) in abs_err.iter().enumerate().take(next).skip(end) {
            if e <= bound {
                run += 1;
                if run >= hold {
                    found = Some(k + 1 - run);
                    break;
                }
            } else {
                run = 0;
            }
        }
        Recovery {
            peak_m,
            recovery_s: found.map(|k| (k.saturating_sub(end)) as f64 * dt),
        }
    });
    (bound, rec)
}

/// Summary statistics over runs of each variant.
pub fn summarise(runs: &[FaultRun], dt: f64, fc: &FaultConfig) -> Value {
    let mut per = serde_json::Map::new();
    let names = [
        "classical_gated",
        "classical_ungated",
        "aided_gated",
        "aided_ungated",
        "classical_gated_fault_free_twin",
        "aided_gated_fault_free_twin",
    ];
    for (s, name) in names.iter().enumerate() {
        let mets: Vec<(f64, [Recovery; 3])> = runs
            .iter()
            .map(|r| recovery(&r.abs_err[s], dt, fc))
            .collect();
        let bounds: Vec<f64> = mets.iter().map(|m| m.0).collect();
        let mut fj = serde_json::Map::new();
        for (i, (fname, _)) in faults(fc).iter().enumerate() {
            let peaks: Vec<f64> = mets.iter().map(|m| m.1[i].peak_m).collect();
            let recs: Vec<Option<f64>> = mets.iter().map(|m| m.1[i].recovery_s).collect();
            let ok: Vec<f64> = recs.iter().flatten().cloned().collect();
            fj.insert(
                fname.to_string(),
                json!({
                    "peak_abs_error_m": { "mean": mean(&peaks), "max": max(&peaks) },
                    "returned_within_bound_runs": ok.len(),
                    "returned_within_bound_fraction": ok.len() as f64 / runs.len() as f64,
                    "recovery_time_s": {
                        "mean": if ok.is_empty() { Value::Null } else { json!(mean(&ok)) },
                        "max": if ok.is_empty() { Value::Null } else { json!(max(&ok)) },
                    },
                }),
            );
        }
        let c = |f: fn(&BaroCounts) -> u32| -> f64 {
            runs.iter().map(|r| f(&r.counters[s]) as f64).sum::<f64>() / runs.len() as f64
        };
        let lost: Vec<f64> = runs.iter().map(|r| r.lost_steps[s] as f64 * dt).collect();
        per.insert(
            name.to_string(),
            json!({
                "pre_fault_bound_m": { "mean": mean(&bounds), "max": max(&bounds) },
                "faults": fj,
                "baro_gate_mean_per_run": {
                    "accepted": c(|g| g.counters.fused),
                    "rejected": c(|g| g.counters.rejected),
                    "reacquisitions": c(|g| g.reacquisition.reacquisitions),
                    "resets": c(|g| g.reacquisition.resets),
                },
                "baro_lost_time_s_mean": mean(&lost),
            }),
        );
    }
    Value::Object(per)
}

fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

fn max(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
}

/// Loads the base configuration of a fault configuration.
pub fn base_config(fc: &FaultConfig) -> Result<Config> {
    load_config(&fc.base_scenario)
}

/// Runs the Monte Carlo (for the runner and the tests).
pub fn run_monte_carlo(
    fc: &FaultConfig,
    runs: usize,
    seed: u64,
    progress: bool,
) -> Result<(Vec<FaultRun>, f64)> {
    let cfg = base_config(fc)?;
    ensure!(
        fc.pre_fault_window_s[0] < fc.pre_fault_window_s[1]
            && fc.pre_fault_window_s[1] <= fc.spike.start_s
            && fc.spike.end_s <= fc.frozen.start_s
            && fc.frozen.end_s <= fc.dropout.start_s
            && fc.dropout.end_s < cfg.duration_s,
        "faults must follow the pre-fault window in order: spike, frozen, dropout"
    );
    let dt = 1.0 / cfg.imu_rate_hz;
    let out = monte_carlo("fault-baro", runs, seed, progress, |_, rng| {
        if cfg.precision == "f64" {
            simulate::<f64>(&cfg, fc, rng)
        } else {
            simulate::<f32>(&cfg, fc, rng)
        }
    });
    Ok((out.into_iter().collect::<Result<Vec<_>>>()?, dt))
}

/// Loads a shipped fault configuration (e.g. `"fault-baro"`), for tests.
pub fn load_fault_config(name: &str) -> Result<FaultConfig> {
    let (_, path) = crate::scenario::resolve(name, &crate::scenario::default_scenario_dir())?;
    let text = std::fs::read_to_string(&path)?;
    let mut doc: toml::Table = toml::from_str(&text)?;
    for key in ["kind", "description", "runs", "seed"] {
        doc.remove(key);
    }
    Ok(FaultConfig::deserialize(toml::Value::Table(doc))?)
}

fn run_fault_baro(ctx: &Context) -> Result<Value> {
    let fc: FaultConfig = ctx.config()?;
    let (runs, dt) = run_monte_carlo(&fc, ctx.runs, ctx.seed, ctx.progress)?;
    let r0 = runs
        .first()
        .ok_or_else(|| anyhow!("at least one run is needed"))?;
    write_run0(ctx, r0)?;
    let consistency = write_consistency(ctx, &runs)?;

    Ok(json!({
        "faults": {
            "spike": { "start_s": fc.spike.start_s, "end_s": fc.spike.end_s, "offset_m": fc.spike_offset_m },
            "frozen": { "start_s": fc.frozen.start_s, "end_s": fc.frozen.end_s },
            "dropout": { "start_s": fc.dropout.start_s, "end_s": fc.dropout.end_s },
        },
        "pre_fault_window_s": fc.pre_fault_window_s,
        "hold_within_s": fc.hold_within_s,
        "consistency": consistency,
        "loops": summarise(&runs, dt, &fc),
    }))
}

/// `fault_baro.csv`: run 0's truth, delivered baro and every loop's altitude error.
fn write_run0_csv(ctx: &Context, r0: &FaultRun) -> Result<()> {
    let mut cols: Vec<(&str, &[f64])> = vec![
        ("t_s", &r0.t),
        ("h_true_m", &r0.h_true),
        ("h_baro_delivered_m", &r0.h_baro),
    ];
    let names = [
        "err_h_classical_gated_m",
        "err_h_classical_ungated_m",
        "err_h_aided_gated_m",
        "err_h_aided_ungated_m",
        "err_h_classical_twin_m",
        "err_h_aided_twin_m",
    ];
    for (i, n) in names.iter().enumerate() {
        cols.push((n, &r0.err_h[i]));
    }
    let headers: Vec<&str> = cols.iter().map(|c| c.0).collect();
    let columns: Vec<&[f64]> = cols.iter().map(|c| c.1).collect();
    write_csv(&ctx.out_dir.join("fault_baro.csv"), &headers, &columns)?;
    Ok(())
}

/// `fault_baro.csv` and `fault_baro.png`: run 0's truth, delivered baro and every loop's
/// altitude error.
fn write_run0(ctx: &Context, r0: &FaultRun) -> Result<()> {
    write_run0_csv(ctx, r0)?;

    let baro_err: Vec<f64> = r0
        .h_baro
        .iter()
        .zip(&r0.h_true)
        .map(|(b, h)| b - h)
        .collect();
    // Clipped to the plot range; gaps (no baro sample) dropped.
    let clip = |v: &[f64]| -> (Vec<f64>, Vec<f64>) {
        r0.t.iter()
            .zip(v)
            .filter(|(_, e)| e.is_finite())
            .map(|(t, e)| (*t, e.clamp(-60.0, 60.0)))
            .unzip()
    };
    let line = |label: &str, v: &[f64], color: usize| {
        let (x, y) = clip(v);
        Series::line(label, &x, &y, color)
    };
    let dashed = |label: &str, v: &[f64], color: usize| {
        let (x, y) = clip(v);
        Series::dashed(label, &x, &y, color)
    };
    let fig = Figure {
        title: "fault-baro: 1 km spike, frozen baro 30 s, dropout 60 s (run 0)".into(),
        x_label: "t (s)".into(),
        columns: 1,
        panels: vec![
            Panel {
                title: "baro delivered − true altitude (clipped ±60 m)".into(),
                y_label: "m".into(),
                series: vec![line(
                    "baro error (dropout: straight segment, no samples)",
                    &baro_err,
                    0,
                )],
                y_range: Some((-60.0, 60.0)),
            },
            Panel {
                title: "classical loop altitude error (clipped ±60 m)".into(),
                y_label: "δh (m)".into(),
                series: vec![
                    dashed("ungated", &r0.err_h[1], 1),
                    line("gated", &r0.err_h[0], 0),
                    line("gated, no faults", &r0.err_h[4], 2),
                ],
                y_range: Some((-60.0, 60.0)),
            },
            Panel {
                title: "velocity-aided loop altitude error (clipped ±60 m)".into(),
                y_label: "δh (m)".into(),
                series: vec![
                    dashed("ungated", &r0.err_h[3], 1),
                    line("gated", &r0.err_h[2], 0),
                    line("gated, no faults", &r0.err_h[5], 2),
                ],
                y_range: Some((-60.0, 60.0)),
            },
        ],
    };
    render(&fig, &ctx.out_dir.join("fault_baro.png"), 1200, 1100)?;
    Ok(())
}

/// `nees.png` and the `consistency` object: every loop's NEES of (h, V_z) with the σ it
/// reports, over the runs.
fn write_consistency(ctx: &Context, runs: &[FaultRun]) -> Result<Value> {
    // Consistency of every loop with the σ it reports (spike and frozen baro: the ungated
    // loops follow the fault, their NEES leaves the band; the dropout: the σ grows open-loop).
    let twin_names = [
        "classical_gated",
        "classical_ungated",
        "aided_gated",
        "aided_ungated",
        "classical_twin",
        "aided_twin",
    ];
    let mut consistency = serde_json::Map::new();
    let mut panels = Vec::new();
    for (j, name) in twin_names.iter().enumerate() {
        let rcs: Vec<RunConsistency> = runs
            .iter()
            .filter_map(|r| r.consistency.get(j).cloned())
            .collect();
        let c = Consistency::from_runs(2, &rcs);
        consistency.insert((*name).to_string(), c.summary());
        let mut p = c.nees_panel(name);
        for s in &mut p.series {
            for y in &mut s.y {
                *y = y.max(1e-3).log10();
            }
        }
        p.y_label = "log10 NEES".into();
        p.title = format!("{} (log10)", p.title);
        panels.push(p);
    }
    let fig = Figure {
        title: format!(
            "fault-baro: NEES of (h, V_z) with the loops' σ, {} runs (twins: no faults)",
            runs.len()
        ),
        x_label: "t (s)".into(),
        columns: 2,
        panels,
    };
    render(&fig, &ctx.out_dir.join("nees.png"), 1400, 1100)?;
    Ok(Value::Object(consistency))
}

//! `seeker-fault`: fault injection for the seeker-aided INS: seeker loss of lock,
//! false lock on a point off the landmark, accelerometer clipping in a vibration burst, IMU
//! sample gaps. The scenario file names a base scenario (`seeker-straight`, `seeker-s-turn`)
//! whose trajectory, sensors and filter it reuses, and adds the faults. Each run is flown twice
//! with the same random numbers: with the faults and without (baseline); the summary gives,
//! per fault, the pre-fault error bound (largest ensemble RMS in a window before the fault),
//! the peak, whether and when the RMS came back within the bound.

use super::injection::{Clipping, FalseLock, Faults, Window};
use super::{load_config, output_epochs, simulate_run_faulted, trajectory, RunOutput};
use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::{Context, Kind};
use crate::stats::ensemble;
use anyhow::{bail, Result};
use nav_core::seeker_ins::ImuFaultPolicy;
use serde::Deserialize;
use serde_json::{json, Value};

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "seeker-fault",
    about: "Seeker-aided INS under faults: loss of lock, false lock, IMU clipping and gaps",
    run,
};

/// The filter's IMU fault policy ([`ImuFaultPolicy`]), TOML table `[imu_policy]`.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PolicyConfig {
    /// Longest bridged gap, s.
    pub max_gap_s: f64,
    /// σ of the specific-force change missed by the hold, m/s².
    pub gap_accel_sigma_m_s2: f64,
    /// σ of the rate change missed by the hold, rad/s.
    pub gap_rate_sigma_rad_s: f64,
    /// σ of the specific-force excess of a clipped sample, m/s².
    pub clip_accel_sigma_m_s2: f64,
    /// σ of the rate excess of a clipped sample, rad/s.
    pub clip_rate_sigma_rad_s: f64,
}

/// The summary JSON type (for tests outside this crate).
pub type Summary = Value;

/// Loads a shipped fault scenario file (`nav-sim/scenarios/<name>.toml`) without its header.
pub fn load_fault_config(name: &str) -> Result<FaultConfig> {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
    for k in ["kind", "description", "runs", "seed"] {
        doc.remove(k);
    }
    Ok(FaultConfig::deserialize(toml::Value::Table(doc))?)
}

/// Scenario file (besides the header).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    /// Base scenario file (`nav-sim/scenarios/<base>.toml`, kind `seeker-ins`).
    pub base: String,
    /// "f32" or "f64" (overrides the base).
    pub precision: String,
    /// Output (statistics) rate, Hz (overrides the base).
    pub output_hz: f64,
    /// Length of the window before a fault whose largest ensemble RMS is the bound, s.
    pub bound_window_s: f64,
    /// Loss of lock windows (no seeker measurement).
    #[serde(default)]
    pub loss_of_lock: Vec<Window>,
    /// False locks.
    #[serde(default)]
    pub false_lock: Vec<FalseLock>,
    /// Accelerometer clipping bursts.
    #[serde(default)]
    pub clipping: Vec<Clipping>,
    /// Whether the IMU flags clipped samples (then `propagate_clipped`, else `propagate`).
    #[serde(default = "yes")]
    pub flag_clipped: bool,
    /// IMU gaps (samples lost), `[start_s, duration_s]`.
    #[serde(default)]
    pub imu_gap: Vec<Window>,
    /// Filter IMU fault policy (default: [`ImuFaultPolicy::default`]).
    #[serde(default)]
    pub imu_policy: Option<PolicyConfig>,
}

fn yes() -> bool {
    true
}

/// Recovery from one fault.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Recovery {
    /// Largest ensemble RMS in the window before the fault.
    pub pre_fault_bound: f64,
    /// Largest ensemble RMS from the fault start until recovery (or the next fault / end).
    pub peak: f64,
    /// Time of the peak, s.
    pub peak_time_s: f64,
    /// Whether the RMS came back within the bound and stayed there until the next fault / end.
    pub recovered: bool,
    /// From the end of the fault to recovery, s (`None`: never).
    pub recovery_time_s: Option<f64>,
}

/// Bound, peak and recovery of one fault `[start, end)` in an RMS series; `next` is the start
/// of the next fault (or +∞).
pub fn recovery(t: &[f64], rms: &[f64], start: f64, end: f64, next: f64, window: f64) -> Recovery {
    let bound = t
        .iter()
        .zip(rms)
        .filter(|(t, _)| **t >= start - window && **t < start)
        .map(|(_, r)| *r)
        .fold(0.0, f64::max);
    let span: Vec<(f64, f64)> = t
        .iter()
        .zip(rms)
        .filter(|(t, _)| **t >= start && **t < next)
        .map(|(t, r)| (*t, *r))
        .collect();
    let last_bad = span
        .iter()
        .filter(|(t, r)| *t >= end - 1e-9 && (r.is_nan() || *r > bound))
        .map(|(t, _)| *t)
        .fold(f64::NEG_INFINITY, f64::max);
    let rec_t = span
        .iter()
        .map(|(t, _)| *t)
        .find(|t| *t >= end - 1e-9 && *t > last_bad);
    let (peak_time_s, peak) = span
        .iter()
        .filter(|(t, _)| rec_t.is_none_or(|rt| *t <= rt))
        .fold(
            (start, 0.0),
            |(pt, p), (t, r)| if *r > p { (*t, *r) } else { (pt, p) },
        );
    Recovery {
        pre_fault_bound: bound,
        peak,
        peak_time_s,
        recovered: rec_t.is_some(),
        recovery_time_s: rec_t.map(|t| (t - end).max(0.0)),
    }
}

/// One fault in time order: name, start, end.
fn fault_list(c: &FaultConfig) -> Vec<(String, f64, f64)> {
    let mut v: Vec<(String, f64, f64)> = vec![];
    for w in &c.loss_of_lock {
        v.push(("loss_of_lock".into(), w[0], w[0] + w[1]));
    }
    for f in &c.false_lock {
        v.push(("false_lock".into(), f.start_s, f.start_s + f.duration_s));
    }
    for f in &c.clipping {
        v.push(("accel_clipping".into(), f.start_s, f.start_s + f.duration_s));
    }
    for w in &c.imu_gap {
        v.push(("imu_gap".into(), w[0], w[0] + w[1]));
    }
    v.sort_by(|a, b| a.1.total_cmp(&b.1));
    v
}

/// Error metrics per epoch of one run: |δp| m, |δV| m/s, |δ(roll, pitch, yaw)| deg.
fn metrics(r: &RunOutput) -> [Vec<f64>; 3] {
    let n = r.err[0].len();
    let norm = |i0: usize, k: usize| -> f64 {
        (i0..i0 + 3)
            .map(|i| r.err[i].get(k).copied().unwrap_or(f64::NAN).powi(2))
            .sum::<f64>()
            .sqrt()
    };
    [
        (0..n).map(|k| norm(0, k)).collect(),
        (0..n).map(|k| norm(3, k)).collect(),
        (0..n).map(|k| norm(6, k)).collect(),
    ]
}

/// Metric names and units.
pub const METRICS: [(&str, &str); 3] =
    [("position", "m"), ("velocity", "m/s"), ("attitude", "deg")];

/// Result of the Monte Carlo: summary, times, RMS per metric with faults and baseline.
#[derive(Debug, Clone)]
pub struct FaultResult {
    /// Summary JSON.
    pub summary: Value,
    /// Output times, s.
    pub t_s: Vec<f64>,
    /// Ensemble RMS per metric, faulted.
    pub rms: [Vec<f64>; 3],
    /// Ensemble RMS per metric, baseline (same runs without faults).
    pub baseline: [Vec<f64>; 3],
    /// Fault windows (name, start, end).
    pub faults: Vec<(String, f64, f64)>,
    /// NEES of the 17 states with and without the faults (same runs).
    pub consistency: [crate::consistency::Consistency; 2],
}

/// Runs the faulted and baseline Monte Carlo and the recovery analysis.
pub fn analyse(fc: &FaultConfig, runs: usize, seed: u64, progress: bool) -> Result<FaultResult> {
    let mut cfg = load_config(&fc.base)?;
    cfg.filter.precision = fc.precision.clone();
    cfg.rates.output_hz = fc.output_hz;
    let f32_mode = match fc.precision.as_str() {
        "f32" => true,
        "f64" => false,
        p => bail!("precision `{p}`: must be \"f32\" or \"f64\""),
    };
    let faults = injected_faults(fc);
    let none = Faults {
        policy: faults.policy,
        ..Faults::default()
    };
    let truth = trajectory::generate(&cfg.trajectory, 1.0 / cfg.rates.imu_hz);
    let epochs = output_epochs(&truth, &cfg);
    let res = crate::montecarlo::monte_carlo("seeker-fault", runs, seed, progress, |_, rng| {
        let mut rng_base = rng.clone();
        let sim = |rng: &mut crate::rng::SimRng, f: &Faults| {
            if f32_mode {
                simulate_run_faulted::<f32>(&cfg, &truth, &epochs, rng, true, f)
            } else {
                simulate_run_faulted::<f64>(&cfg, &truth, &epochs, rng, true, f)
            }
        };
        let a = sim(rng, &faults)?;
        let b = sim(&mut rng_base, &none)?;
        Ok::<_, anyhow::Error>((a, b))
    });
    let mut fr = vec![];
    let mut br = vec![];
    for r in res {
        let (a, b) = r?;
        fr.push(a);
        br.push(b);
    }
    let t: Vec<f64> = epochs.iter().map(|&k| truth.t_s[k]).collect();
    let rms_of = |rs: &[RunOutput]| -> [Vec<f64>; 3] {
        let m: Vec<[Vec<f64>; 3]> = rs.iter().map(metrics).collect();
        std::array::from_fn(|i| {
            let series: Vec<Vec<f64>> = m.iter().map(|x| x[i].clone()).collect();
            ensemble(&series).rms
        })
    };
    let rms = rms_of(&fr);
    let baseline = rms_of(&br);
    let list = fault_list(fc);
    let per_fault = per_fault_summary(fc, &t, &rms, &baseline, &list);
    let of = |rs: &[RunOutput]| {
        crate::consistency::Consistency::from_runs(
            nav_core::seeker_ins::STATES,
            &rs.iter().map(|r| r.consistency.clone()).collect::<Vec<_>>(),
        )
    };
    let consistency = [of(&fr), of(&br)];
    let summary = fault_summary(
        fc,
        &Flown {
            faulted: &fr,
            baseline: &br,
            rms: &rms,
            baseline_rms: &baseline,
            consistency: &consistency,
        },
        per_fault,
        per_fault_all(&t, &rms, &list, fc.bound_window_s),
    );
    Ok(FaultResult {
        summary,
        t_s: t,
        rms,
        baseline,
        faults: list,
        consistency,
    })
}

/// The faults the configuration injects, with its IMU fault policy.
fn injected_faults(fc: &FaultConfig) -> Faults {
    Faults {
        loss_of_lock: fc.loss_of_lock.clone(),
        false_lock: fc.false_lock.clone(),
        clipping: fc.clipping.clone(),
        flag_clipped: fc.flag_clipped,
        imu_gap: fc.imu_gap.clone(),
        policy: fc.imu_policy.as_ref().map(|p| ImuFaultPolicy {
            max_gap_s: p.max_gap_s,
            gap_accel_sigma_m_s2: p.gap_accel_sigma_m_s2,
            gap_rate_sigma_rad_s: p.gap_rate_sigma_rad_s,
            clip_accel_sigma_m_s2: p.clip_accel_sigma_m_s2,
            clip_rate_sigma_rad_s: p.clip_rate_sigma_rad_s,
        }),
    }
}

/// Per fault of `list` (name, start s, end s): the recovery of each metric's ensemble RMS
/// (`rms`, with faults; `baseline`, the same runs without) at times `t` (s).
fn per_fault_summary(
    fc: &FaultConfig,
    t: &[f64],
    rms: &[Vec<f64>; 3],
    baseline: &[Vec<f64>; 3],
    list: &[(String, f64, f64)],
) -> Vec<Value> {
    let mut per_fault = vec![];
    for (i, (name, start, end)) in list.iter().enumerate() {
        let next = list.get(i + 1).map_or(f64::INFINITY, |f| f.1);
        let mut m = serde_json::Map::new();
        m.insert("fault".into(), json!(name));
        m.insert("start_s".into(), json!(start));
        m.insert("end_s".into(), json!(sig(*end, 6)));
        for (j, (metric, unit)) in METRICS.iter().enumerate() {
            let r = recovery(t, &rms[j], *start, *end, next, fc.bound_window_s);
            let b = recovery(t, &baseline[j], *start, *end, next, fc.bound_window_s);
            let to_base = back_to_baseline(t, &rms[j], &baseline[j], *end, next);
            m.insert(
                format!("{metric}_rms_{}", unit.replace('/', "_")),
                json!({
                    "pre_fault_bound": sig(r.pre_fault_bound, 4),
                    "peak": sig(r.peak, 4),
                    "peak_time_s": sig(r.peak_time_s, 5),
                    "baseline_peak_same_span": sig(b.peak, 4),
                    "recovered": r.recovered,
                    "recovery_time_s": r.recovery_time_s.map(|x| sig(x, 4)),
                    "back_within_10pct_of_baseline_after_s": to_base.map(|x| sig(x, 4)),
                }),
            );
        }
        per_fault.push(Value::Object(m));
    }
    per_fault
}

/// The runs flown with and without the faults, and what the analysis made of them.
struct Flown<'a> {
    faulted: &'a [RunOutput],
    baseline: &'a [RunOutput],
    rms: &'a [Vec<f64>; 3],
    baseline_rms: &'a [Vec<f64>; 3],
    consistency: &'a [crate::consistency::Consistency; 2],
}

/// The summary JSON of the analysis.
fn fault_summary(
    fc: &FaultConfig,
    flown: &Flown<'_>,
    per_fault: Vec<Value>,
    all_recovered: bool,
) -> Value {
    let sum = |f: fn(&RunOutput) -> u64| flown.faulted.iter().map(f).sum::<u64>();
    let base_sum = |f: fn(&RunOutput) -> u64| flown.baseline.iter().map(f).sum::<u64>();
    let last = |v: &[f64]| sig(v.last().copied().unwrap_or(f64::NAN), 4);
    json!({
        "base": fc.base,
        "filter_precision": fc.precision,
        "consistency": {
            "paper_with_faults": flown.consistency[0].summary(),
            "paper_without_faults": flown.consistency[1].summary(),
        },
        "bound_window_s": fc.bound_window_s,
        "filter_did": {
            "los_components_fused": sum(|r| r.fused as u64),
            "los_components_rejected": sum(|r| r.rejected as u64),
            "false_lock_components_fused": sum(|r| r.false_lock_fused as u64),
            "false_lock_components_rejected": sum(|r| r.false_lock_rejected as u64),
            "covariance_reinflations": sum(|r| u64::from(r.inflations)),
            "seeker_epochs_dropped": sum(|r| r.seeker_dropped as u64),
            "imu_gaps_bridged": sum(|r| u64::from(r.imu_faults.gaps)),
            "imu_samples_held": sum(|r| u64::from(r.imu_faults.held_samples)),
            "imu_samples_clipped": sum(|r| u64::from(r.imu_faults.clipped_samples)),
            "updates_refused": sum(|r| r.errors as u64),
        },
        "baseline_did": {
            "los_components_rejected": base_sum(|r| r.rejected as u64),
            "covariance_reinflations": base_sum(|r| u64::from(r.inflations)),
        },
        "faults": per_fault,
        "all_recovered": all_recovered,
        "final_rms": {
            "position_m": last(&flown.rms[0]), "velocity_m_s": last(&flown.rms[1]), "attitude_deg": last(&flown.rms[2]),
            "baseline_position_m": last(&flown.baseline_rms[0]), "baseline_velocity_m_s": last(&flown.baseline_rms[1]),
            "baseline_attitude_deg": last(&flown.baseline_rms[2]),
        },
    })
}

/// Time from `end` until the faulted RMS is back within 10 % of the no-fault RMS of the same
/// runs and stays there until `next` (`None`: never).
pub fn back_to_baseline(t: &[f64], rms: &[f64], base: &[f64], end: f64, next: f64) -> Option<f64> {
    let span: Vec<(f64, bool)> = t
        .iter()
        .zip(rms.iter().zip(base))
        .filter(|(t, _)| **t >= end - 1e-9 && **t < next)
        .map(|(t, (r, b))| (*t, *r <= 1.1 * b))
        .collect();
    let last_bad = span
        .iter()
        .filter(|(_, ok)| !ok)
        .map(|(t, _)| *t)
        .fold(f64::NEG_INFINITY, f64::max);
    span.iter()
        .map(|(t, _)| *t)
        .find(|t| *t > last_bad)
        .map(|t| (t - end).max(0.0))
}

fn per_fault_all(t: &[f64], rms: &[Vec<f64>; 3], list: &[(String, f64, f64)], w: f64) -> bool {
    list.iter().enumerate().all(|(i, (_, s, e))| {
        let next = list.get(i + 1).map_or(f64::INFINITY, |f| f.1);
        rms.iter()
            .all(|r| recovery(t, r, *s, *e, next, w).recovered)
    })
}

fn run(ctx: &Context) -> Result<Value> {
    let fc: FaultConfig = ctx.config()?;
    let r = analyse(&fc, ctx.runs, ctx.seed, ctx.progress)?;
    write_errors_csv(ctx, &r)?;
    errors_figure(ctx, &fc, &r)?;
    consistency_figure(ctx, &fc, &r)?;
    println!(
        "  all faults recovered: {}",
        r.summary["all_recovered"].as_bool().unwrap_or(false)
    );
    Ok(r.summary)
}

/// `errors.csv`: the ensemble RMS per metric with the faults and without (same runs).
fn write_errors_csv(ctx: &Context, r: &FaultResult) -> Result<()> {
    write_csv(
        &ctx.out_dir.join("errors.csv"),
        &[
            "t_s",
            "position_rms_m",
            "velocity_rms_m_s",
            "attitude_rms_deg",
            "baseline_position_rms_m",
            "baseline_velocity_rms_m_s",
            "baseline_attitude_rms_deg",
        ],
        &[
            &r.t_s,
            &r.rms[0],
            &r.rms[1],
            &r.rms[2],
            &r.baseline[0],
            &r.baseline[1],
            &r.baseline[2],
        ],
    )
}

/// `errors.png`: the ensemble RMS per metric with and without the faults, fault windows marked.
fn errors_figure(ctx: &Context, fc: &FaultConfig, r: &FaultResult) -> Result<()> {
    let mut panels = vec![];
    for (j, (metric, unit)) in METRICS.iter().enumerate() {
        let ymax = r.rms[j]
            .iter()
            .chain(&r.baseline[j])
            .copied()
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max);
        let mut series = vec![
            Series::line("with faults", &r.t_s, &r.rms[j], 0),
            Series::dashed("no fault (same runs)", &r.t_s, &r.baseline[j], 2),
        ];
        for (i, (name, s, e)) in r.faults.iter().enumerate() {
            // Fault window as a bracket (a 0.1 s gap is a single bar at this scale).
            series.push(Series::dashed(
                if j == 0 { name.clone() } else { String::new() },
                &[*s, *s, *e, *e],
                &[0.0, ymax * 1.05, ymax * 1.05, 0.0],
                3 + i,
            ));
        }
        panels.push(Panel {
            title: format!("ensemble RMS of |{metric} error|"),
            y_label: (*unit).into(),
            series,
            y_range: Some((0.0, ymax * 1.1)),
        });
    }
    render(
        &Figure {
            title: format!(
                "{}: seeker-aided INS ({}), {} runs, fault windows marked",
                ctx.name, fc.base, ctx.runs
            ),
            x_label: "time, s".into(),
            panels,
            columns: 1,
        },
        &ctx.out_dir.join("errors.png"),
        1300,
        1100,
    )
}

/// `consistency.png`: the NEES of the 17 states with and without the faults.
fn consistency_figure(ctx: &Context, fc: &FaultConfig, r: &FaultResult) -> Result<()> {
    let mut nees_panels = vec![
        r.consistency[0].nees_panel("paper filter with the faults"),
        r.consistency[1].nees_panel("paper filter, same runs without faults"),
    ];
    let (_, hi) = crate::consistency::nees_band_95(r.consistency[0].dof, r.consistency[0].runs);
    for p in &mut nees_panels {
        p.y_range = Some((0.0, 4.0 * hi));
    }
    render(
        &Figure {
            title: format!(
                "{}: NEES of the 17 states ({}), fault windows as in errors.png",
                ctx.name, fc.base
            ),
            x_label: "time, s".into(),
            panels: nees_panels,
            columns: 1,
        },
        &ctx.out_dir.join("consistency.png"),
        1200,
        800,
    )
}

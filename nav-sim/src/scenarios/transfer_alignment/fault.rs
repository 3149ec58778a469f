//! `fault-transfer`: the proposed 12-state filter (f32, as on the target) with master data that
//! arrives late (time-tagged, matched with the slave history) and drops out.
//!
//! At each slave epoch j the slave sample is pushed into a [`SlaveHistory`]; the master sample
//! tagged t_{j−L} (latency L epochs) arrives and is matched with the slave sample of its epoch
//! ([`nav_core::transfer_alignment::TransferAlignment::step_delayed`]). During a dropout no master sample arrives and the
//! filter is propagated to t_{j−L} ([`nav_core::transfer_alignment::TransferAlignment::propagate`]), so it keeps the same lag
//! and its covariance grows with the flexure process. The error of θ is taken at the filter's
//! epoch. Recovery: after each dropout, the first epoch from which the ensemble RMS of |θ error|
//! stays within the pre-fault bound (the largest RMS over the 2 s before the dropout) until
//! the next dropout or the end.
use super::config::CaseConfig;
use super::estimate::cast_config;
use super::estimate::{NEES_COMPONENTS, NEES_DOF};
use super::truth::simulate;
use crate::consistency::{Consistency, RunConsistency};
use crate::montecarlo::monte_carlo;
use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::{Context, Kind};
use crate::stats::ensemble;
use anyhow::{anyhow, Result};
use nalgebra::Vector3;
use nav_core::transfer_alignment::{
    Channel, MasterSample, SlaveHistory, SlaveSample, TaInitial, TransferAlignment,
};
use nav_core::FusionOutcome;
use nav_core::{Estimator, Gate};
use serde::Deserialize;
use serde_json::{json, Value};

/// `fault-transfer` registry entry.
pub const KIND_FAULT: Kind = Kind {
    kind: "ta-fault",
    about: "transfer alignment under master-data latency (time-tagged) and dropouts",
    run: run_fault,
};

/// Slave history length (epochs): covers latencies up to 150 ms at 100 Hz.
pub const HISTORY: usize = 16;

/// Configuration: a `ta-case` configuration plus the faults (unknown keys are refused by the
/// flattened `CaseConfig`).
#[derive(Debug, Clone, Deserialize)]
pub struct FaultConfig {
    /// Master data latency, s (a whole number of `dt_s`).
    pub master_latency_s: f64,
    /// Dropouts `[start_s, duration_s]` of the master data (by time tag).
    pub dropouts_s: Vec<[f64; 2]>,
    /// Length of the pre-fault window defining the bound, s.
    pub bound_window_s: f64,
    /// The underlying case (truth, sensors, profile, filter).
    #[serde(flatten)]
    pub case: CaseConfig,
}

/// One run: error norm of θ (rad) and filter σ norm per epoch, and counters.
#[derive(Debug, Clone, Default)]
pub struct FaultRun {
    /// |θ̂ − θ| per slave epoch (NaN before the filter starts), rad.
    pub err_rad: Vec<f64>,
    /// Filter 1σ norm of θ per epoch, rad.
    pub sigma_rad: Vec<f64>,
    /// Measurements rejected by the gate.
    pub rejected: u64,
    /// Recoveries by the gate-starvation policy (covariance reset to the prior), counted on
    /// each starved channel.
    pub recoveries: u32,
    /// Steps refused with an error (should be 0).
    pub errors: u64,
    /// Master samples that could not be matched with the slave history.
    pub unmatched: u64,
    /// Propagation-only epochs.
    pub propagations: u64,
    /// NEES of θ (3 states) and `e²/σ²` per axis from the filter's first epoch on.
    pub consistency: RunConsistency,
}

fn in_dropout(cfg: &FaultConfig, t: f64) -> bool {
    cfg.dropouts_s
        .iter()
        .any(|[s, d]| t >= s - 1e-9 && t < s + d - 1e-9)
}

/// Runs one seeded realisation with the proposed filter (`FaultRun` of the flight
/// configuration on the same truth: [`run_once_both`]).
pub fn run_once(cfg: &FaultConfig, rng: &mut crate::rng::SimRng) -> Result<FaultRun> {
    let truth = simulate(&cfg.case, rng)?;
    run_filter_once::<4, 12>(cfg, &truth)
}

/// One seeded realisation flown by the proposed filter and the flight configuration.
pub fn run_once_both(
    cfg: &FaultConfig,
    rng: &mut crate::rng::SimRng,
) -> Result<(FaultRun, FaultRun)> {
    let truth = simulate(&cfg.case, rng)?;
    Ok((
        run_filter_once::<4, 12>(cfg, &truth)?,
        run_filter_once::<5, 15>(cfg, &truth)?,
    ))
}

fn run_filter_once<const K: usize, const N: usize>(
    cfg: &FaultConfig,
    truth: &super::truth::TruthRun,
) -> Result<FaultRun> {
    let mut fc = cast_config::<f32>(&cfg.case.filter_config(0.0));
    if fc.gate == Gate::Off {
        fc.gate = Gate::Nis(25.0);
    }
    let mut f = TransferAlignment::<f32, K, N>::new(&fc, &TaInitial::default())
        .map_err(|e| anyhow!("{e}"))?;
    let mut hist = SlaveHistory::<f32, HISTORY>::new();
    let lag = (cfg.master_latency_s / cfg.case.dt_s).round() as usize;
    let n = truth.t_s.len();
    let mut out = FaultRun {
        err_rad: vec![f64::NAN; n],
        sigma_rad: vec![f64::NAN; n],
        consistency: RunConsistency::new(&NEES_COMPONENTS),
        ..Default::default()
    };
    let v = |x: &Vector3<f64>| x.map(|e| e as f32);
    for j in 0..n {
        let s = &truth.slave[j];
        hist.push(&SlaveSample {
            time: s.time,
            angular_rate_rad_s: v(&s.angular_rate_rad_s),
            specific_force_m_s2: v(&s.specific_force_m_s2),
        })
        .map_err(|e| anyhow!("slave history: {e}"))?;
        let Some(k) = j.checked_sub(lag) else {
            continue;
        };
        let m = &truth.master[k];
        if in_dropout(cfg, m.time.as_secs_f64()) {
            if f.time().is_some() {
                match f.propagate(m.time) {
                    Ok(_) => out.propagations += 1,
                    Err(_) => out.errors += 1,
                }
            }
        } else {
            let mt = MasterSample {
                time: m.time,
                angular_rate_rad_s: v(&m.angular_rate_rad_s),
                angular_accel_rad_s2: v(&m.angular_accel_rad_s2),
                specific_force_m_s2: v(&m.specific_force_m_s2),
            };
            match f.step_delayed(&mt, &hist) {
                Ok(rep) => {
                    out.rejected += rep
                        .updates
                        .iter()
                        .filter(|u| u.outcome == FusionOutcome::Rejected)
                        .count() as u64;
                }
                Err(nav_core::NavError::MeasurementTimeOutOfWindow) => out.unmatched += 1,
                Err(_) => out.errors += 1,
            }
        }
        if f.time().is_some() {
            let e = f.theta().map(f64::from) - truth.theta_rad[k];
            out.err_rad[j] = e.norm();
            let sg = f.theta_sigma_rad().map(f64::from);
            out.sigma_rad[j] = sg.norm();
            let p = f.theta_covariance().map(f64::from);
            let nees = p.try_inverse().map_or(f64::NAN, |pi| e.dot(&(pi * e)));
            let es: [(f64, f64); 3] = std::array::from_fn(|a| (e[a], sg[a]));
            out.consistency
                .push(truth.t_s[j] - truth.t_s[lag.min(n - 1)], nees, &es);
        }
    }
    out.recoveries = Channel::ALL
        .iter()
        .map(|c| f.aid_counters(*c).recoveries)
        .sum();
    Ok(out)
}

/// Recovery of one dropout.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Recovery {
    /// Dropout start (master time tag), s.
    pub start_s: f64,
    /// Dropout length, s.
    pub duration_s: f64,
    /// Pre-fault bound: largest ensemble RMS |θ error| in the window before, mrad.
    pub pre_fault_bound_mrad: f64,
    /// Largest ensemble RMS during the dropout and until recovery, mrad.
    pub peak_mrad: f64,
    /// Whether the RMS came back within the bound (and stayed until the next fault / end).
    pub recovered: bool,
    /// Time from the end of the dropout to recovery, s (`None` if not recovered).
    pub recovery_time_s: Option<f64>,
}

/// Ensemble analysis: per dropout, bound, peak and recovery time. `t_tag` are the master time
/// tags of the epochs, `rms` the ensemble RMS of |θ error| per epoch (mrad).
pub fn recoveries(cfg: &FaultConfig, t_tag: &[f64], rms: &[f64]) -> Vec<Recovery> {
    let mut out = vec![];
    for (i, [start, dur]) in cfg.dropouts_s.iter().enumerate() {
        let end = start + dur;
        let next = cfg.dropouts_s.get(i + 1).map_or(f64::INFINITY, |d| d[0]);
        let bound = t_tag
            .iter()
            .zip(rms)
            .filter(|(t, r)| **t >= start - cfg.bound_window_s && **t < *start && r.is_finite())
            .map(|(_, r)| *r)
            .fold(0.0, f64::max);
        let window: Vec<(f64, f64)> = t_tag
            .iter()
            .zip(rms)
            .filter(|(t, _)| **t >= *start && **t < next)
            .map(|(t, r)| (*t, *r))
            .collect();
        // Last epoch after the dropout at which the RMS is above the bound.
        let last_bad = window
            .iter()
            .filter(|(t, r)| *t >= end - 1e-9 && *r > bound)
            .map(|(t, _)| *t)
            .fold(f64::NEG_INFINITY, f64::max);
        let after: Vec<f64> = window
            .iter()
            .filter(|(t, _)| *t >= end - 1e-9)
            .map(|(t, _)| *t)
            .collect();
        let rec_t = if last_bad == f64::NEG_INFINITY {
            after.first().copied()
        } else {
            after.iter().copied().find(|t| *t > last_bad)
        };
        let peak = window
            .iter()
            .filter(|(t, _)| rec_t.is_none_or(|rt| *t <= rt))
            .map(|(_, r)| *r)
            .fold(0.0, f64::max);
        out.push(Recovery {
            start_s: *start,
            duration_s: *dur,
            pre_fault_bound_mrad: bound,
            peak_mrad: peak,
            recovered: rec_t.is_some(),
            recovery_time_s: rec_t.map(|t| (t - end).max(0.0)),
        });
    }
    out
}

/// Summary, master time tags (s), ensemble RMS of |θ error| and mean filter σ (mrad).
pub type FaultAnalysis = (Value, Vec<f64>, Vec<f64>, Vec<f64>, [Consistency; 2]);

/// Runs the Monte Carlo and the analysis; returns the summary, `t_tag`, the RMS / σ series of
/// the proposed filter, and the consistency of the proposed filter and of the flight
/// configuration flown on the same runs.
pub fn analyse(cfg: &FaultConfig, runs: usize, seed: u64, progress: bool) -> Result<FaultAnalysis> {
    let both: Vec<Result<(FaultRun, FaultRun)>> =
        monte_carlo("fault-transfer", runs, seed, progress, |_, rng| {
            run_once_both(cfg, rng)
        });
    let both: Vec<(FaultRun, FaultRun)> = both.into_iter().collect::<Result<_>>()?;
    let consistency = |pick: fn(&(FaultRun, FaultRun)) -> &FaultRun| {
        let rc: Vec<RunConsistency> = both.iter().map(|r| pick(r).consistency.clone()).collect();
        Consistency::from_runs(NEES_DOF, &rc)
    };
    let (c_prop, c_flight) = (consistency(|r| &r.0), consistency(|r| &r.1));
    let res: Vec<FaultRun> = both.into_iter().map(|r| r.0).collect();
    let lag = (cfg.master_latency_s / cfg.case.dt_s).round();
    let n = res.first().map_or(0, |r| r.err_rad.len());
    let t_tag: Vec<f64> = (0..n).map(|j| (j as f64 - lag) * cfg.case.dt_s).collect();
    let e: Vec<Vec<f64>> = res
        .iter()
        .map(|r| r.err_rad.iter().map(|v| v * 1e3).collect())
        .collect();
    let s: Vec<Vec<f64>> = res
        .iter()
        .map(|r| r.sigma_rad.iter().map(|v| v * 1e3).collect())
        .collect();
    let rms = ensemble(&e).rms;
    let sigma = ensemble(&s).mean;
    let rec = recoveries(cfg, &t_tag, &rms);
    let sum = |f: fn(&FaultRun) -> u64| res.iter().map(f).sum::<u64>();
    let summary = json!({
        "filter": "proposed 12-state, f32",
        "master_latency_s": cfg.master_latency_s,
        "slave_history_epochs": HISTORY,
        "dropouts_s": cfg.dropouts_s,
        "rejections": sum(|r| r.rejected),
        "channel_recoveries": res.iter().map(|r| u64::from(r.recoveries)).sum::<u64>(),
        "step_errors": sum(|r| r.errors),
        "unmatched_master_samples": sum(|r| r.unmatched),
        "propagation_only_epochs": sum(|r| r.propagations),
        "recoveries": rec.iter().map(|r| json!({
            "start_s": r.start_s,
            "duration_s": r.duration_s,
            "pre_fault_bound_mrad": sig(r.pre_fault_bound_mrad, 4),
            "peak_mrad": sig(r.peak_mrad, 4),
            "recovered": r.recovered,
            "recovery_time_s": r.recovery_time_s.map(|t| sig(t, 4)),
        })).collect::<Vec<_>>(),
        "all_recovered": rec.iter().all(|r| r.recovered),
        "final_rms_mrad": sig(rms.last().copied().unwrap_or(f64::NAN), 4),
        "nees_states": "theta_x, theta_y, theta_z (total misalignment), from the filter's first epoch; time in the summaries' consistency objects is from that epoch",
        "consistency": {
            "proposed": c_prop.summary(),
            "flight": c_flight.summary(),
        },
    });
    Ok((summary, t_tag, rms, sigma, [c_prop, c_flight]))
}

fn run_fault(ctx: &Context) -> Result<Value> {
    let cfg: FaultConfig = ctx.config()?;
    let (summary, t, rms, sigma, [c_prop, c_flight]) =
        analyse(&cfg, ctx.runs, ctx.seed, ctx.progress)?;
    render(
        &Figure {
            title: format!(
                "{}: NEES of θ (3 states), time from the first epoch",
                ctx.name
            ),
            x_label: "time, s".into(),
            columns: 1,
            panels: vec![
                c_prop.nees_panel("proposed 12-state (paper)"),
                c_flight.nees_panel("flight configuration (15 states)"),
            ],
        },
        &ctx.out_dir.join("nees.png"),
        1000,
        700,
    )?;
    write_csv(
        &ctx.out_dir.join("error.csv"),
        &["t_master_s", "rms_theta_err_mrad", "mean_filter_sigma_mrad"],
        &[&t, &rms, &sigma],
    )?;
    let fin: Vec<usize> = (0..t.len()).filter(|&i| rms[i].is_finite()).collect();
    let tx: Vec<f64> = fin.iter().map(|&i| t[i]).collect();
    let ry: Vec<f64> = fin.iter().map(|&i| rms[i]).collect();
    let sy: Vec<f64> = fin.iter().map(|&i| sigma[i]).collect();
    let fig = Figure {
        title: format!(
            "{}: |θ error|, master latency {} s, dropouts {:?}",
            ctx.name, cfg.master_latency_s, cfg.dropouts_s
        ),
        x_label: "master time tag, s".into(),
        panels: vec![Panel {
            title: "ensemble RMS of |θ̂ − θ| and filter σ".into(),
            y_label: "mrad".into(),
            series: vec![
                Series::line("RMS error", &tx, &ry, 0),
                Series::dashed("filter σ (mean)", &tx, &sy, 1),
            ],
            y_range: Some((0.0, 20.0)),
        }],
        columns: 1,
    };
    render(&fig, &ctx.out_dir.join("error.png"), 1000, 500)?;
    Ok(summary)
}

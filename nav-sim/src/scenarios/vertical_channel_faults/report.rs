//! The figures of merit of `fault-baro` (pre-fault bound, per-fault peak and recovery), the
//! summary over runs and the outputs (`fault_baro.csv`, `fault_baro.png`, the consistency).

use super::*;

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

pub(super) fn mean(v: &[f64]) -> f64 {
    if v.is_empty() {
        f64::NAN
    } else {
        v.iter().sum::<f64>() / v.len() as f64
    }
}

pub(super) fn max(v: &[f64]) -> f64 {
    v.iter().cloned().fold(f64::NEG_INFINITY, f64::max)
}

/// `fault_baro.csv`: run 0's truth, delivered baro and every loop's altitude error.
pub(super) fn write_run0_csv(ctx: &Context, r0: &FaultRun) -> Result<()> {
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
pub(super) fn write_run0(ctx: &Context, r0: &FaultRun) -> Result<()> {
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
pub(super) fn write_consistency(ctx: &Context, runs: &[FaultRun]) -> Result<Value> {
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

//! The consistency campaign: every estimator's flight configuration over randomized variants
//! of its scenario that nobody tuned, with the paper filter flown on the same runs for the
//! accuracy comparison.
//!
//! Each estimator contributes one [`Campaign`]: a function that draws `variants` variants from
//! the campaign seed (variant `v` uses stream `v` of it), flies `runs` seeded Monte Carlo runs
//! of each, and returns one [`VariantResult`] per (variant, filter). This module judges them
//! against the same targets for every estimator and writes the worst cases:
//!
//! - `frac_in_band` ≥ [`MIN_FRAC_IN_BAND`] (run-averaged NEES inside its 95 % χ² band),
//! - every `normalized_error_sq` in [[`NES_MIN`], [`NES_MAX`]],
//! - RMS error on every axis at most [`MAX_ACCURACY_LOSS`] × the paper filter's on the same
//!   runs.
//!
//! Outputs in the scenario directory: `summary.json` (per estimator: variants, passes, the
//! worst cases by each criterion, the targets), `variants.csv` (one row per variant and
//! filter, with its RMS per axis) and `consistency.png` (per estimator, each variant's mean
//! NEES per state with the 95 % band, and its fraction of epochs in band).

use crate::consistency::nees_band_95;
use crate::plot::{self, Figure, Panel, Series, Style};
use crate::scenario::{Context, Kind};
use crate::scenarios::campaign_plan::{
    Campaign, CampaignPlan, VariantResult, MAX_ACCURACY_LOSS, MIN_FRAC_IN_BAND, NES_MAX, NES_MIN,
};
use anyhow::Result;
use serde::Deserialize;
use serde_json::{json, Map, Value};
use std::fmt::Write as _;

#[path = "consistency_judged_panels.rs"]
mod judged_panels;

/// The NEES per state plotted is clipped here (a paper filter can be 10⁴ too large, which
/// would flatten the flight configuration's points onto one).
const RATIO_CLIP: f64 = 3.0;

/// The campaigns, one per estimator's flight configuration.
pub static CAMPAIGNS: &[Campaign] = &[
    crate::scenarios::transfer_alignment::campaign::CAMPAIGN,
    crate::scenarios::seeker_ins::campaign::CAMPAIGN,
    crate::scenarios::seeker_ins::campaign::CAMPAIGN_F32,
    crate::scenarios::vertical_channel::CAMPAIGN,
    crate::scenarios::vertical_channel::CAMPAIGN_CLASSICAL,
    crate::scenarios::navigator_campaign::CAMPAIGN,
];

/// Scenario kind `consistency`.
pub const KIND: Kind = Kind {
    kind: "consistency",
    about: "every estimator's flight configuration over randomized variants: NEES in band, \
            normalized errors, accuracy against the paper filter; worst cases",
    run,
};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Params {
    /// Variants per estimator.
    variants: usize,
    /// Only these estimators (all when absent).
    #[serde(default)]
    only: Option<Vec<String>>,
}

/// False-alarm rate of the statistical criterion per variant (the two-sided 95 % band).
pub const STATISTICAL_ALPHA: f64 = 0.05;

/// P(X ≥ k) for X ~ Binomial(n, p): how likely a consistent filter fails at least `k` of `n`
/// variants on a criterion with false-alarm rate `p`.
pub fn binomial_tail(n: usize, p: f64, k: usize) -> f64 {
    let mut term = (1.0 - p).powi(n as i32); // P(X = 0)
    let mut below = 0.0;
    for j in 0..k.min(n + 1) {
        below += term;
        term *= (n - j) as f64 / (j + 1) as f64 * p / (1.0 - p);
    }
    (1.0 - below).max(0.0)
}

/// Simulated ideal filters per flight variant
/// ([`Consistency::ideal_frac_in_band`](crate::consistency::Consistency::ideal_frac_in_band)).
pub const IDEAL_ENSEMBLES: usize = 200;

/// Verdict of one flight variant against the targets.
#[derive(Debug, Clone)]
struct Verdict {
    frac_in_band: f64,
    nes_worst: (String, f64),
    accuracy_worst: (String, f64),
    /// The literal criterion: `frac_in_band` ≥ [`MIN_FRAC_IN_BAND`], normalized errors and
    /// accuracy.
    pass: bool,
    /// Time-averaged NEES inside its band for the filter's time correlation
    /// ([`Consistency::mean_nees_band_95`](crate::consistency::Consistency::mean_nees_band_95)),
    /// normalized errors and accuracy: a consistent
    /// filter fails it with probability ≈ 5 %.
    pass_statistical: bool,
    /// Band of the time-averaged NEES.
    mean_band: (f64, f64),
    /// Ideal filters with the same states, runs and time correlation: fraction with
    /// `frac_in_band` < [`MIN_FRAC_IN_BAND`] and their 5th percentile of `frac_in_band`
    /// (NaN for the paper filter, not simulated).
    ideal_p_below: f64,
    ideal_p5: f64,
}

/// Seed of a flight variant's ideal-filter reference (the campaign seed, estimator and
/// variant: reproducible, different for every variant).
fn ideal_seed(seed: u64, estimator: &str, variant: usize) -> u64 {
    let name = estimator.bytes().fold(0xcbf2_9ce4_8422_2325_u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01b3)
    });
    seed ^ name ^ (variant as u64).wrapping_mul(0x9e37_79b9_7f4a_7c15)
}

fn judge(
    flight: &VariantResult,
    paper: Option<&VariantResult>,
    ideal_seed: Option<u64>,
) -> Verdict {
    let frac = flight.consistency.frac_in_band();
    let (ideal_p_below, ideal_p5) = match ideal_seed {
        Some(seed) => {
            let ideal = flight.consistency.ideal_frac_in_band(IDEAL_ENSEMBLES, seed);
            let n = ideal.len().max(1) as f64;
            (
                ideal.iter().filter(|&&f| f < MIN_FRAC_IN_BAND).count() as f64 / n,
                ideal.get(ideal.len() / 20).copied().unwrap_or(f64::NAN),
            )
        }
        None => (f64::NAN, f64::NAN),
    };
    let mean_band = flight.consistency.mean_nees_band_95();
    let mean_ok = (mean_band.0..=mean_band.1).contains(&flight.consistency.mean_nees());
    let nes_worst = flight
        .consistency
        .normalized_error_sq
        .iter()
        .map(|(n, v)| (n.clone(), *v))
        .max_by(|a, b| nes_badness(a.1).total_cmp(&nes_badness(b.1)))
        .unwrap_or_else(|| ("none".into(), f64::NAN));
    let accuracy_worst = paper
        .map(|p| {
            flight
                .rms
                .iter()
                .filter_map(|(axis, r)| {
                    p.rms
                        .iter()
                        .find(|(a, _)| a == axis)
                        .map(|(_, rp)| (axis.clone(), r / rp))
                })
                .max_by(|a, b| a.1.total_cmp(&b.1))
                .unwrap_or_else(|| ("none".into(), f64::NAN))
        })
        .unwrap_or_else(|| ("no paper filter".into(), f64::NAN));
    let nes_ok = flight
        .consistency
        .normalized_error_sq
        .iter()
        .all(|(_, v)| (NES_MIN..=NES_MAX).contains(v));
    let acc_ok = !accuracy_worst.1.is_finite() || accuracy_worst.1 <= MAX_ACCURACY_LOSS;
    Verdict {
        frac_in_band: frac,
        nes_worst,
        accuracy_worst,
        pass: frac >= MIN_FRAC_IN_BAND && nes_ok && acc_ok,
        pass_statistical: mean_ok && nes_ok && acc_ok,
        mean_band,
        ideal_p_below,
        ideal_p5,
    }
}

/// How far a normalized error squared is from 1, symmetric in log (0.5 and 2 are equally bad).
fn nes_badness(v: f64) -> f64 {
    if v.is_finite() && v > 0.0 {
        v.ln().abs()
    } else {
        f64::INFINITY
    }
}

fn run(ctx: &Context) -> Result<Value> {
    let p: Params = ctx.config()?;
    let plan = CampaignPlan {
        variants: p.variants,
        runs: ctx.runs,
        seed: ctx.seed,
        progress: ctx.progress,
    };
    let selected: Vec<&Campaign> = CAMPAIGNS
        .iter()
        .filter(|c| {
            p.only
                .as_ref()
                .is_none_or(|o| o.iter().any(|n| n == c.estimator))
        })
        .collect();
    let mut csv = String::from(
        "estimator,variant,filter,nees_dof,runs,nees_mean,band_lo,band_hi,frac_in_band,\
         worst_nes_axis,worst_nes,worst_accuracy_axis,worst_accuracy_ratio,pass,\
         nees_effective_epochs,mean_band_lo,mean_band_hi,pass_statistical,ideal_p_below,\
         ideal_p5,normalized_error_sq,rms,params\n",
    );
    let mut estimators = Map::new();
    let mut panels = Vec::new();
    for c in selected {
        let results = (c.run)(&plan)?;
        let mut verdicts = Vec::new();
        for r in &results {
            let paper = results
                .iter()
                .find(|q| q.variant == r.variant && q.filter == "paper");
            let v = if r.filter == "paper" {
                judge(r, None, None)
            } else {
                // The flight filter's reference seed as it always was; other judged filters
                // (the navigator's phases) their own.
                let name = if r.filter == "flight" {
                    c.estimator.to_string()
                } else {
                    format!("{}/{}", c.estimator, r.filter)
                };
                judge(r, paper, Some(ideal_seed(ctx.seed, &name, r.variant)))
            };
            csv_row(&mut csv, c.estimator, r, &v);
            verdicts.push((r, v));
        }
        estimators.insert(c.estimator.into(), estimator_summary(c, &verdicts));
        panels.extend(estimator_panels(c, &verdicts));
    }
    std::fs::write(ctx.out_dir.join("variants.csv"), csv)?;
    if !panels.is_empty() {
        let fig = Figure {
            title: format!(
                "Consistency campaign, {} runs per variant: literal target in band ≥ \
                 {MIN_FRAC_IN_BAND} of epochs; statistical: time-averaged NEES in its band",
                ctx.runs
            ),
            x_label: "variant".into(),
            panels,
            columns: 2,
        };
        let rows = fig.panels.len().div_ceil(2) as u32;
        plot::render(&fig, &ctx.out_dir.join("consistency.png"), 1400, 380 * rows)?;
    }
    Ok(json!({
        "targets": {
            "min_frac_in_band": MIN_FRAC_IN_BAND,
            "statistical": "time-averaged NEES inside its 95 % band for the filter's time \
                correlation (nees_mean_band_95); false-alarm rate 0.05 per variant",
            "normalized_error_sq": [NES_MIN, NES_MAX],
            "max_rms_ratio_to_paper": MAX_ACCURACY_LOSS,
        },
        "variants_per_estimator": p.variants,
        "estimators": Value::Object(estimators),
    }))
}

/// One row of `variants.csv`: a variant of `estimator` with its filter's verdict; `rms` is
/// the row's RMS per axis (units in the names; the navigator's `final` row: the horizontal
/// RMS and σ at the last epoch, `horizontal_m`, `horizontal_sigma_m`).
fn csv_row(csv: &mut String, estimator: &str, r: &VariantResult, v: &Verdict) {
    let (lo, hi) = nees_band_95(r.consistency.dof, r.consistency.runs);
    let _ = writeln!(
        csv,
        "{},{},{},{},{},{:.4},{:.4},{:.4},{:.4},{},{:.4},{},{:.4},{},{:.2},{:.4},{:.4},{},{:.3},\
         {:.4},{},{},\"{}\"",
        estimator,
        r.variant,
        r.filter,
        r.consistency.dof,
        r.consistency.runs,
        r.consistency.mean_nees(),
        lo,
        hi,
        v.frac_in_band,
        v.nes_worst.0,
        v.nes_worst.1,
        v.accuracy_worst.0,
        v.accuracy_worst.1,
        v.pass,
        r.consistency.nees_effective_epochs,
        v.mean_band.0,
        v.mean_band.1,
        v.pass_statistical,
        v.ideal_p_below,
        v.ideal_p5,
        r.consistency
            .normalized_error_sq
            .iter()
            .map(|(n, x)| format!("{n}={x:.4}"))
            .collect::<Vec<_>>()
            .join(" "),
        r.rms
            .iter()
            .map(|(n, x)| format!("{n}={x:.4}"))
            .collect::<Vec<_>>()
            .join(" "),
        r.params.to_string().replace('"', "'")
    );
}

/// The filters an estimator's results are judged on (every one but the paper filter), in
/// order of first appearance: `flight` for the estimators flown beside their paper filter, the
/// phases, hand-over and last epoch for the navigator.
fn judged_filters<'a>(verdicts: &[(&'a VariantResult, Verdict)]) -> Vec<&'a str> {
    let mut out: Vec<&str> = Vec::new();
    for (r, _) in verdicts {
        if r.filter != "paper" && !out.contains(&r.filter.as_str()) {
            out.push(r.filter.as_str());
        }
    }
    out
}

fn estimator_summary(c: &Campaign, verdicts: &[(&VariantResult, Verdict)]) -> Value {
    let judged = judged_filters(verdicts);
    if judged == ["flight"] {
        let mut m = filter_summary(verdicts, "flight");
        m.insert("about".into(), json!(c.about));
        return Value::Object(m);
    }
    // Several judged filters (the navigator's phases): the same summary for each.
    let by_filter: Map<String, Value> = judged
        .iter()
        .map(|f| ((*f).to_string(), Value::Object(filter_summary(verdicts, f))))
        .collect();
    json!({
        "about": c.about,
        "judged": judged,
        "by_filter": Value::Object(by_filter),
    })
}

/// The summary of one judged filter over the variants (the paper filter's rows beside it).
fn filter_summary(verdicts: &[(&VariantResult, Verdict)], filter: &str) -> Map<String, Value> {
    let flight: Vec<&(&VariantResult, Verdict)> = verdicts
        .iter()
        .filter(|(r, _)| r.filter == filter)
        .collect();
    let paper: Vec<&(&VariantResult, Verdict)> = verdicts
        .iter()
        .filter(|(r, _)| r.filter == "paper")
        .collect();
    let case = |(r, v): &(&VariantResult, Verdict)| {
        json!({
            "variant": r.variant,
            "params": r.params,
            "consistency": r.consistency.summary(),
            "rms": r.rms.iter().map(|(a, x)| (a.clone(), json!(crate::output::sig(*x, 4))))
                .collect::<Map<String, Value>>(),
            "worst_normalized_error_sq": [v.nes_worst.0, crate::output::sig(v.nes_worst.1, 4)],
            "worst_rms_ratio_to_paper": [v.accuracy_worst.0,
                crate::output::sig(v.accuracy_worst.1, 4)],
            "pass": v.pass,
            "pass_statistical": v.pass_statistical,
            "nees_mean_band_95": [crate::output::sig(v.mean_band.0, 4),
                crate::output::sig(v.mean_band.1, 4)],
            "ideal_p_frac_below_target": crate::output::sig(v.ideal_p_below, 3),
            "ideal_frac_in_band_p5": crate::output::sig(v.ideal_p5, 3),
        })
    };
    let worst_by = |key: &dyn Fn(&Verdict) -> f64| -> Value {
        flight
            .iter()
            .max_by(|a, b| key(&a.1).total_cmp(&key(&b.1)))
            .map(|x| case(x))
            .unwrap_or(Value::Null)
    };
    let paper_frac: Vec<f64> = paper.iter().map(|(_, v)| v.frac_in_band).collect();
    let n = flight.len();
    let stat_fail = flight.iter().filter(|(_, v)| !v.pass_statistical).count();
    let ideal_expected: f64 = flight.iter().map(|(_, v)| v.ideal_p_below).sum();
    let out = json!({
        "flight_variants": n,
        "flight_pass": flight.iter().filter(|(_, v)| v.pass).count(),
        "flight_pass_statistical": n - stat_fail,
        "statistical_p_value": crate::output::sig(binomial_tail(n, STATISTICAL_ALPHA, stat_fail), 3),
        "ideal_expected_literal_failures": crate::output::sig(ideal_expected, 3),
        "ideal_mean_p_frac_below_target": crate::output::sig(ideal_expected / n.max(1) as f64, 3),
        "flight_below_ideal_p5": flight.iter()
            .filter(|(_, v)| v.frac_in_band < v.ideal_p5).count(),
        "flight_min_frac_in_band": flight.iter().map(|(_, v)| v.frac_in_band)
            .fold(f64::INFINITY, f64::min),
        "paper_mean_frac_in_band": if paper_frac.is_empty() { Value::Null } else {
            json!(paper_frac.iter().sum::<f64>() / paper_frac.len() as f64) },
        "worst_frac_in_band": worst_by(&|v| -v.frac_in_band),
        "worst_normalized_error_sq": worst_by(&|v| nes_badness(v.nes_worst.1)),
        "worst_accuracy": worst_by(&|v| v.accuracy_worst.1),
    });
    match out {
        Value::Object(m) => m,
        _ => Map::new(),
    }
}

fn estimator_panels(c: &Campaign, verdicts: &[(&VariantResult, Verdict)]) -> Vec<Panel> {
    let judged = judged_filters(verdicts);
    if judged != ["flight"] {
        return judged_panels::judged_filter_panels(c, verdicts, &judged);
    }
    let mut ratio = Panel {
        title: format!(
            "{}: mean NEES / states (1 if consistent; > {RATIO_CLIP} drawn at {RATIO_CLIP})",
            c.estimator
        ),
        y_label: "NEES / states".into(),
        y_range: Some((0.0, RATIO_CLIP * 1.05)),
        ..Panel::default()
    };
    let mut frac = Panel {
        title: format!("{}: fraction of epochs in the NEES band", c.estimator),
        y_label: "fraction in band".into(),
        y_range: Some((0.0, 1.05)),
        ..Panel::default()
    };
    let flight_rows: Vec<&(&VariantResult, Verdict)> = verdicts
        .iter()
        .filter(|(r, _)| r.filter == "flight")
        .collect();
    // Drawn last, over the flight filter's points.
    let fails = flight_band_series(&flight_rows, &mut ratio, &mut frac);
    for (color, filter) in [(0usize, "flight"), (1, "paper")] {
        let rows: Vec<&(&VariantResult, Verdict)> = verdicts
            .iter()
            .filter(|(r, _)| r.filter == filter)
            .collect();
        if rows.is_empty() {
            continue;
        }
        let x: Vec<f64> = rows.iter().map(|(r, _)| r.variant as f64).collect();
        let y_ratio: Vec<f64> = rows
            .iter()
            .map(|(r, _)| (r.consistency.mean_nees() / r.consistency.dof as f64).min(RATIO_CLIP))
            .collect();
        let y_frac: Vec<f64> = rows.iter().map(|(_, v)| v.frac_in_band).collect();
        let mut s = Series::line(format!("{filter} filter"), &x, &y_ratio, color);
        s.style = Style::Points;
        ratio.series.push(s);
        let label = if filter == "flight" {
            let stat = rows.iter().filter(|(_, v)| v.pass_statistical).count();
            let lit = rows.iter().filter(|(_, v)| v.pass).count();
            format!(
                "flight filter (pass: literal {lit}, statistical {stat} of {})",
                rows.len()
            )
        } else {
            format!("{filter} filter")
        };
        let mut s = Series::line(label, &x, &y_frac, color);
        s.style = Style::Points;
        frac.series.push(s);
    }
    ratio.series.extend(fails);
    add_bands(verdicts, &mut ratio, &mut frac);
    vec![ratio, frac]
}

/// The flight filter's points drawn under the others: the band of its time-averaged NEES per
/// state on `ratio`, the ideal filter's 5th percentile on `frac`; returns the series of the
/// variants outside their band (drawn last), none without flight rows.
fn flight_band_series(
    flight_rows: &[&(&VariantResult, Verdict)],
    ratio: &mut Panel,
    frac: &mut Panel,
) -> Option<Series> {
    if flight_rows.is_empty() {
        return None;
    }
    let x: Vec<f64> = flight_rows.iter().map(|(r, _)| r.variant as f64).collect();
    let per_state = |f: &dyn Fn(&(&VariantResult, Verdict)) -> f64| -> Vec<f64> {
        flight_rows
            .iter()
            .map(|rv| (f(rv) / rv.0.consistency.dof as f64).min(RATIO_CLIP))
            .collect()
    };
    let lo = per_state(&|(_, v)| v.mean_band.0);
    let hi = per_state(&|(_, v)| v.mean_band.1);
    let mut s = Series::line("band of the time average (ideal: 5 % outside)", &x, &lo, 2);
    s.style = Style::Points;
    ratio.series.push(s);
    let mut s = Series::line("", &x, &hi, 2);
    s.style = Style::Points;
    ratio.series.push(s);
    let (fx, fy): (Vec<f64>, Vec<f64>) = flight_rows
        .iter()
        .filter(|(_, v)| !v.pass_statistical)
        .map(|(r, _)| {
            (
                r.variant as f64,
                (r.consistency.mean_nees() / r.consistency.dof as f64).min(RATIO_CLIP),
            )
        })
        .unzip();
    let mut s = Series::line("flight: outside the band of its time average", &fx, &fy, 4);
    s.style = Style::Points;
    let fails = Some(s);
    let p5: Vec<f64> = flight_rows.iter().map(|(_, v)| v.ideal_p5).collect();
    let mut s = Series::line("ideal filter: 5th percentile", &x, &p5, 2);
    s.style = Style::Points;
    frac.series.push(s);

    fails
}

/// The 95 % band of one epoch's NEES per state on `ratio`, the target on `frac`, and room on
/// the right of both for the legend.
fn add_bands(verdicts: &[(&VariantResult, Verdict)], ratio: &mut Panel, frac: &mut Panel) {
    if let Some(n) = verdicts.iter().map(|(r, _)| r.variant).max() {
        let x = [0.0, n as f64];
        // The 95 % band of the run-averaged NEES per state (same states and runs for every
        // variant of an estimator).
        if let Some((r, _)) = verdicts.first() {
            let dof = r.consistency.dof as f64;
            let (lo, hi) = nees_band_95(r.consistency.dof, r.consistency.runs);
            ratio.series.push(Series::dashed(
                "95 % band of one epoch",
                &x,
                &[lo / dof, lo / dof],
                3,
            ));
            ratio
                .series
                .push(Series::dashed("", &x, &[hi / dof, hi / dof], 3));
        }
        frac.series.push(Series::dashed(
            "target",
            &x,
            &[MIN_FRAC_IN_BAND, MIN_FRAC_IN_BAND],
            3,
        ));
        // Room on the right for the legend (the series' points stay clear of it): a
        // one-point line draws nothing but widens the x range.
        let room = [n as f64 * 1.6];
        ratio.series.push(Series::line("", &room, &[0.0], 3));
        frac.series.push(Series::line("", &room, &[0.0], 3));
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::consistency::{Consistency, RunConsistency};

    fn result(filter: &str, scale: f64, rms: f64) -> VariantResult {
        // Deterministic errors: e = scale·σ·(±1) alternating, σ = 1, 3 components.
        let runs: Vec<RunConsistency> = (0..10)
            .map(|r| {
                let mut rc = RunConsistency::new(&["x", "y", "z"]);
                for k in 0..100 {
                    let sgn = if (k + r) % 2 == 0 { 1.0 } else { -1.0 };
                    let e = [(scale * sgn, 1.0); 3];
                    rc.push(f64::from(k) * 0.1, 3.0 * scale * scale, &e);
                }
                rc
            })
            .collect();
        VariantResult {
            variant: 0,
            filter: filter.into(),
            params: json!({}),
            consistency: Consistency::from_runs(3, &runs),
            rms: vec![("x_m".into(), rms)],
        }
    }

    #[test]
    fn judge_accepts_consistent_and_rejects_overconfident_or_less_accurate() {
        let paper = result("paper", 3.0, 1.0);
        assert!(judge(&result("flight", 1.0, 1.05), Some(&paper), Some(1)).pass);
        // Overconfident: e²/σ² = 4.
        let v = judge(&result("flight", 2.0, 1.0), Some(&paper), Some(1));
        assert!(!v.pass && v.nes_worst.1 > 3.9, "{v:?}");
        // Consistent but 20 % less accurate than the paper filter.
        let v = judge(&result("flight", 1.0, 1.2), Some(&paper), Some(1));
        assert!(!v.pass && (v.accuracy_worst.1 - 1.2).abs() < 1e-12, "{v:?}");
    }
}

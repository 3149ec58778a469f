//! The transfer alignment's contribution to the consistency campaign
//! ([`crate::scenarios::consistency_campaign`]): the flight configuration
//! ([`nav_core::transfer_alignment::FlightFilter`]) and the paper's proposed 12-state filter
//! flown on the same truth and sensor draws over randomized variants of the paper's cases.
//!
//! Variant `v` draws, from stream `v` of the campaign seed: the base case (`ta-case1..3`,
//! uniformly), the lever arm l (L_0 = [0, l, 0], l uniform in 1–10 m), one scale of every
//! flexure correlation time (log-uniform ×0.5–×2; truth and filters, as in the scenario
//! files), and the manoeuvre (1 s of 1 g along ±X or ±Y, starting uniformly in 0.5–3 s; it
//! ends before the consistency figures start at [`crate::consistency::SETTLE_S`]), then the
//! seed of its Monte Carlo runs. Each run is the scenario's 10 s at 100 Hz, with the
//! scenario's sensors and biases; the NEES is that of θ (3 states, as in the `ta-case`
//! summaries) and the RMS per axis is over runs and the settled epochs.

use super::config::{load_scenario, CaseConfig, ProfileSegment};
use super::estimate::{run_precision, MethodRun, NEES_COMPONENTS, NEES_DOF};
use super::truth::simulate;
use crate::consistency::{Consistency, RunConsistency, SETTLE_S};
use crate::montecarlo::monte_carlo;
use crate::rng::run_rng;
use crate::scenarios::campaign_plan::{Campaign, CampaignPlan, VariantResult};
use anyhow::Result;
use rand::Rng;
use serde_json::json;

/// The transfer alignment's campaign.
pub const CAMPAIGN: Campaign = Campaign {
    estimator: "transfer_alignment",
    about: "flight 15-state filter vs paper proposed 12-state on ta-case1..3 with lever arm \
            1-10 m, flexure τ ×0.5-×2, manoeuvre start 0.5-3 s along ±X or ±Y",
    run: run_campaign,
};

/// Range of the drawn lever arm, m.
pub const LEVER_ARM_RANGE_M: (f64, f64) = (1.0, 10.0);
/// Range of the flexure correlation-time scale (log-uniform), dimensionless.
pub const TAU_SCALE_RANGE: (f64, f64) = (0.5, 2.0);
/// Range of the manoeuvre start, s.
pub const MANOEUVRE_START_RANGE_S: (f64, f64) = (0.5, 3.0);
/// Manoeuvre: duration, s, and acceleration, g.
pub const MANOEUVRE: (f64, f64) = (1.0, 1.0);

/// One drawn variant.
#[derive(Debug, Clone)]
pub struct Variant {
    /// The case with the drawn parameters applied.
    pub case: CaseConfig,
    /// The drawn parameters (units in the key names).
    pub params: serde_json::Value,
    /// Seed of the variant's Monte Carlo runs.
    pub runs_seed: u64,
}

/// Draws variant `v` of the campaign seed `seed`.
pub fn draw_variant(seed: u64, v: usize) -> Result<Variant> {
    let mut rng = run_rng(seed, v as u64);
    let base = ["ta-case1", "ta-case2", "ta-case3"][rng.random_range(0..3)];
    let (mut case, _, _): (CaseConfig, usize, u64) = load_scenario(base)?;
    let lever = rng.random_range(LEVER_ARM_RANGE_M.0..=LEVER_ARM_RANGE_M.1);
    let (lo, hi) = (TAU_SCALE_RANGE.0.ln(), TAU_SCALE_RANGE.1.ln());
    let tau_scale = rng.random_range(lo..=hi).exp();
    let start = rng.random_range(MANOEUVRE_START_RANGE_S.0..=MANOEUVRE_START_RANGE_S.1);
    let axis = rng.random_range(0..2usize);
    let sign = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
    let runs_seed: u64 = rng.random();
    case.lever_arm_m = [0.0, lever, 0.0];
    for t in case.truth_flexure.tau_s.iter_mut() {
        *t *= tau_scale;
    }
    if let Some(t) = case.filter.tau_s.as_mut() {
        for t in t.iter_mut() {
            *t *= tau_scale;
        }
    }
    let mut accel_g = [0.0; 3];
    accel_g[axis] = sign * MANOEUVRE.1;
    let (d, total) = (MANOEUVRE.0, case.duration_s);
    case.profile = vec![
        ProfileSegment {
            duration_s: start,
            accel_g: [0.0; 3],
            angular_rate_deg_s: [0.0; 3],
        },
        ProfileSegment {
            duration_s: d,
            accel_g,
            angular_rate_deg_s: [0.0; 3],
        },
        ProfileSegment {
            duration_s: (total - start - d).max(case.dt_s),
            accel_g: [0.0; 3],
            angular_rate_deg_s: [0.0; 3],
        },
    ];
    let axis_name = format!("{}{}", if sign > 0.0 { "+" } else { "-" }, ["x", "y"][axis]);
    let params = json!({
        "base_case": base,
        "lever_arm_m": crate::output::sig(lever, 4),
        "flexure_tau_scale": crate::output::sig(tau_scale, 4),
        "truth_flexure_tau_s": case.truth_flexure.tau_s.map(|t| crate::output::sig(t, 4)),
        "manoeuvre_start_s": crate::output::sig(start, 4),
        "manoeuvre_axis": axis_name,
        "manoeuvre_accel_g": MANOEUVRE.1,
        "manoeuvre_duration_s": MANOEUVRE.0,
    });
    Ok(Variant {
        case,
        params,
        runs_seed,
    })
}

/// RMS of θ's error per axis over the runs and the settled epochs, mrad.
fn rms_settled(runs: &[&MethodRun], t_s: &[f64]) -> Vec<(String, f64)> {
    let t0 = t_s.first().copied().unwrap_or(0.0);
    (0..3)
        .map(|a| {
            let (mut sum, mut n) = (0.0, 0usize);
            for r in runs {
                for (k, e) in r.err_rad[a].iter().enumerate() {
                    if t_s.get(k).is_some_and(|t| *t >= t0 + SETTLE_S) {
                        sum += e * e;
                        n += 1;
                    }
                }
            }
            (
                format!("theta_{}_mrad", ["x", "y", "z"][a]),
                1e3 * (sum / n.max(1) as f64).sqrt(),
            )
        })
        .collect()
}

/// `RunConsistency` of a filter whose covariance were scaled by `sigma_scale²` (1: as flown).
fn scaled(rc: &RunConsistency, sigma_scale: f64) -> RunConsistency {
    let k = 1.0 / (sigma_scale * sigma_scale);
    let mut out = rc.clone();
    out.nees.iter_mut().for_each(|v| *v *= k);
    for (_, s) in out.normalized.iter_mut() {
        s.iter_mut().for_each(|v| *v *= k);
    }
    out
}

/// Flies variant `v`: the flight configuration and the paper's proposed filter on the same
/// `runs` truth and sensor draws. `sigma_scale` scales the flight filter's σ in the
/// consistency figures only (1 as flown; the test uses it to show that an overconfident filter
/// fails).
pub fn fly_variant(plan: &CampaignPlan, v: usize, sigma_scale: f64) -> Result<[VariantResult; 2]> {
    let var = draw_variant(plan.seed, v)?;
    let case = &var.case;
    case.check()?;
    let fcfg = case.filter_config(0.0);
    let results = monte_carlo(
        &format!("TA variant {v}"),
        plan.runs.max(1),
        var.runs_seed,
        plan.progress,
        |_, rng| -> Result<_> {
            let truth = simulate(case, rng)?;
            let flight = run_precision::<5, 15>(case.precision, &fcfg, &truth)?;
            let paper = run_precision::<4, 12>(case.precision, &fcfg, &truth)?;
            Ok((truth.t_s, flight, paper))
        },
    );
    let results: Vec<(Vec<f64>, MethodRun, MethodRun)> =
        results.into_iter().collect::<Result<_>>()?;
    let t_s = results.first().map(|r| r.0.clone()).unwrap_or_default();
    let flight: Vec<&MethodRun> = results.iter().map(|r| &r.1).collect();
    let paper: Vec<&MethodRun> = results.iter().map(|r| &r.2).collect();
    let consistency = |runs: &[&MethodRun], s: f64| {
        let rc: Vec<RunConsistency> = runs.iter().map(|r| scaled(&r.consistency, s)).collect();
        Consistency::from_runs(NEES_DOF, &rc)
    };
    debug_assert_eq!(NEES_COMPONENTS.len(), NEES_DOF);
    Ok([
        VariantResult {
            variant: v,
            filter: "flight".into(),
            params: var.params.clone(),
            consistency: consistency(&flight, sigma_scale),
            rms: rms_settled(&flight, &t_s),
        },
        VariantResult {
            variant: v,
            filter: "paper".into(),
            params: var.params,
            consistency: consistency(&paper, 1.0),
            rms: rms_settled(&paper, &t_s),
        },
    ])
}

fn run_campaign(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let mut out = Vec::with_capacity(2 * plan.variants);
    for v in 0..plan.variants {
        out.extend(fly_variant(plan, v, 1.0)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenarios::campaign_plan::{MAX_ACCURACY_LOSS, NES_MAX, NES_MIN};

    fn plan(variants: usize, runs: usize) -> CampaignPlan {
        CampaignPlan {
            variants,
            runs,
            seed: 4242,
            progress: false,
        }
    }

    fn numbers(r: &[VariantResult]) -> Vec<f64> {
        r.iter()
            .flat_map(|x| {
                let mut v = vec![x.consistency.mean_nees(), x.consistency.frac_in_band()];
                v.extend(x.consistency.normalized_error_sq.iter().map(|(_, e)| *e));
                v.extend(x.rms.iter().map(|(_, e)| *e));
                v
            })
            .collect()
    }

    #[test]
    fn reproducible_and_variants_differ() {
        let p = plan(2, 4);
        let a = run_campaign(&p).unwrap();
        let b = run_campaign(&p).unwrap();
        assert_eq!(a.len(), 4);
        assert_eq!(numbers(&a), numbers(&b));
        assert_eq!(a[0].params, b[0].params);
        assert_ne!(a[0].params, a[2].params);
        // Both filters flew the same variant with the same axis names.
        let names = |r: &VariantResult| r.rms.iter().map(|x| x.0.clone()).collect::<Vec<_>>();
        assert_eq!(names(&a[0]), names(&a[1]));
        assert_eq!(
            (a[0].filter.as_str(), a[1].filter.as_str()),
            ("flight", "paper")
        );
        // The drawn parameters stay in their ranges.
        for v in 0..20 {
            let d = draw_variant(4242, v).unwrap();
            let l = d.case.lever_arm_m[1];
            assert!((LEVER_ARM_RANGE_M.0..=LEVER_ARM_RANGE_M.1).contains(&l));
            let s = d.params["flexure_tau_scale"].as_f64().unwrap();
            assert!((0.499..=2.001).contains(&s));
            let start = d.case.manoeuvre_window_s().unwrap().0;
            assert!(start + MANOEUVRE.0 < SETTLE_S);
        }
    }

    /// On one variant, the flight configuration meets the targets (the time-averaged NEES in
    /// its band, the statistical criterion: the literal `frac_in_band` ≥ 0.9 is missed by an
    /// ideal filter in 13–17 % of the variants, so one draw cannot be held to it), and the same
    /// runs with its σ scaled by 0.3 fail them (and are almost never in the band).
    #[test]
    fn overconfident_filter_is_judged_failing() {
        let p = plan(1, 30);
        let [flight, paper] = fly_variant(&p, 0, 1.0).unwrap();
        let [over, _] = fly_variant(&p, 0, 0.3).unwrap();
        let pass = |r: &VariantResult| {
            let (lo, hi) = r.consistency.mean_nees_band_95();
            (lo..=hi).contains(&r.consistency.mean_nees())
                && r.consistency
                    .normalized_error_sq
                    .iter()
                    .all(|(_, v)| (NES_MIN..=NES_MAX).contains(v))
        };
        assert!(pass(&flight), "{:?}", flight.consistency.summary());
        for ((_, f), (_, q)) in flight.rms.iter().zip(&paper.rms) {
            assert!(
                f <= &(MAX_ACCURACY_LOSS * q),
                "{:?} {:?}",
                flight.rms,
                paper.rms
            );
        }
        assert!(!pass(&over), "{:?}", over.consistency.summary());
        assert!(over.consistency.frac_in_band() < 0.1);
        // The paper filter (no bias states) fails on the same runs.
        assert!(!pass(&paper), "{:?}", paper.consistency.summary());
    }
}

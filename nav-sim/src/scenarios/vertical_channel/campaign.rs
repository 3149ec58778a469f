//! The vertical channel's contribution to the consistency campaign
//! ([`crate::scenarios::consistency_campaign`]): the velocity-aided loop over randomized
//! variants of the `vc-montecarlo` scenario.
//!
//! Filters (same loop, same runs, same estimates; only the σ differs):
//! - `"flight"`: the loop's `sigma()` / `covariance_h_vz()` — the covariance its design implies
//!   under the variant's error model (nav-core's discrete Lyapunov steady state, propagated
//!   through the start transient);
//! - `"paper"`: the σ of the paper's Riccati design (`gains().p`), constant, which ignores the
//!   baro's correlated error and the start transient.
//!
//! The accuracy of both is the same by construction (the flight configuration is the paper's
//! loop; σ is an output, not a gain).
//!
//! Variant `v` draws its parameters from stream `v` of the campaign seed; its runs use streams
//! `0…runs` of the seed `seed + (v + 1)·2³²`. Randomized (uniform unless stated): start
//! altitude 0.5–5 km; a climb of 0.4–1.2 km at 5–30 m/s (at least Δh/60 s), a descent at
//! 8–20 m/s of 0.4 km up to what 60 s allow (not below 300 m), level holds of 10–40 s; baro
//! white noise 0.5–2 m, correlated error 1–5 m with 20–200 s correlation time; accelerometer
//! bias 0.2–3 mg (1σ, random constant); IMU rate one of 100, 200, 250, 500, 1000 Hz. Each
//! variant flies [`VARIANT_DURATION_S`].

use super::run::one_run;
use super::truth::Profile;
use super::{load_config, Config, Leg};
use crate::consistency::{Consistency, RunConsistency};
use crate::montecarlo::monte_carlo;
use crate::rng::{run_rng, SimRng};
use crate::scenarios::campaign_plan::{Campaign, CampaignPlan, VariantResult};
use anyhow::Result;
use rand::Rng;
use serde_json::{json, Value};

/// The campaign of the vertical channel.
pub const CAMPAIGN: Campaign = Campaign {
    estimator: "vertical_channel",
    about: "velocity-aided loop: start altitude, climb/descent profile, baro white and \
            correlated error (σ, τ), accelerometer bias, IMU rate 100-1000 Hz",
    run,
};

/// Flight time of one variant's runs, s (the whole `vc-montecarlo` profile is 400 s; 240 s
/// holds the randomized profile and keeps the campaign within its time budget).
pub const VARIANT_DURATION_S: f64 = 240.0;

/// The IMU rates a variant is drawn from, Hz (multiples of the aids' 25 and 10 Hz).
pub const IMU_RATES_HZ: [f64; 5] = [100.0, 200.0, 250.0, 500.0, 1000.0];

fn uniform(rng: &mut SimRng, lo: f64, hi: f64) -> f64 {
    lo + (hi - lo) * rng.random::<f64>()
}

/// Draws variant `v`'s scenario from the base (`vc-montecarlo`) and its parameters (units in
/// the key names).
pub fn draw_variant(base: &Config, seed: u64, v: usize) -> (Config, Value) {
    let mut rng = run_rng(seed, v as u64);
    let mut c = base.clone();
    let h0 = uniform(&mut rng, 500.0, 5000.0);
    let climb = uniform(&mut rng, 400.0, 1200.0);
    let climb_rate = uniform(&mut rng, (climb / 60.0).max(5.0), 30.0);
    let descent_rate = uniform(&mut rng, 8.0, 20.0);
    let top = h0 + climb;
    let descent = uniform(&mut rng, 400.0, (top - 300.0).min(60.0 * descent_rate));
    let holds = [uniform(&mut rng, 10.0, 40.0), uniform(&mut rng, 10.0, 40.0)];
    let hold = |s: f64| Leg {
        hold_s: Some(s),
        to_altitude_m: None,
        rate_m_s: None,
    };
    let go = |to: f64, rate: f64| Leg {
        hold_s: None,
        to_altitude_m: Some(to),
        rate_m_s: Some(rate),
    };
    c.profile.initial_altitude_m = h0;
    c.profile.legs = vec![
        hold(holds[0]),
        go(top, climb_rate),
        hold(holds[1]),
        go(top - descent, descent_rate),
        hold(1.0),
    ];
    c.baro.noise_m = uniform(&mut rng, 0.5, 2.0);
    c.baro.markov_sigma_m = uniform(&mut rng, 1.0, 5.0);
    c.baro.markov_tau_s = uniform(&mut rng, 20.0, 200.0);
    c.imu.bias_sigma_mg = uniform(&mut rng, 0.2, 3.0);
    let k = rng.random_range(0..IMU_RATES_HZ.len());
    c.imu_rate_hz = IMU_RATES_HZ.get(k).copied().unwrap_or(100.0);
    c.duration_s = VARIANT_DURATION_S;
    c.initial_error.mode = "gaussian".into();
    let params = json!({
        "start_altitude_m": h0,
        "climb_m": climb,
        "climb_rate_m_s": climb_rate,
        "descent_m": descent,
        "descent_rate_m_s": descent_rate,
        "baro_noise_m": c.baro.noise_m,
        "baro_markov_sigma_m": c.baro.markov_sigma_m,
        "baro_markov_tau_s": c.baro.markov_tau_s,
        "accel_bias_sigma_mg": c.imu.bias_sigma_mg,
        "imu_rate_hz": c.imu_rate_hz,
        "duration_s": c.duration_s,
    });
    (c, params)
}

/// The classical (baro-only, third-order) loop over the same variants and runs: its σ as the
/// flight configuration, no paper filter beside it (its design σ is the same loop's).
pub const CAMPAIGN_CLASSICAL: Campaign = Campaign {
    estimator: "vertical_channel_classical",
    about: "classical baro loop over the velocity-aided loop's variants (same draws and runs)",
    run: run_classical,
};

fn run_classical(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let base = load_config("vc-montecarlo")?;
    let mut out = Vec::new();
    for v in 0..plan.variants {
        let (cfg, params) = draw_variant(&base, plan.seed, v);
        let profile = Profile::new(&cfg.profile)?;
        let run_seed = seed_of_runs(plan.seed, v);
        let runs: Vec<(RunConsistency, [f64; 2], usize)> = monte_carlo(
            "vc classical",
            plan.runs,
            run_seed,
            plan.progress,
            |_, rng| {
                let (out, _) = one_run(&cfg, &profile, cfg.classical.tau_s, false, rng)?;
                let Some(classical) = out.consistency.into_iter().next() else {
                    anyhow::bail!("classical consistency missing");
                };
                Ok((classical, out.sumsq[0], out.n))
            },
        )
        .into_iter()
        .collect::<Result<_>>()?;
        let n: usize = runs.iter().map(|r| r.2).sum();
        let rms = |q: usize| (runs.iter().map(|r| r.1[q]).sum::<f64>() / n.max(1) as f64).sqrt();
        let rc: Vec<RunConsistency> = runs.iter().map(|r| r.0.clone()).collect();
        out.push(VariantResult {
            variant: v,
            filter: "flight".into(),
            params,
            consistency: Consistency::from_runs(2, &rc),
            rms: vec![("h_m".to_string(), rms(0)), ("vz_m_s".to_string(), rms(1))],
        });
    }
    Ok(out)
}

/// Seed of variant `v`'s runs (module documentation).
fn seed_of_runs(seed: u64, v: usize) -> u64 {
    seed.wrapping_add((v as u64 + 1) << 32)
}

/// The runs of one variant: per run, the consistency samples of the flight and paper filters
/// and the squared errors (h, V_z) with their count.
pub type VariantRuns = Vec<(RunConsistency, RunConsistency, [f64; 2], usize)>;

/// Flies `runs` runs of a variant (seeded as the module documentation says).
pub fn fly_variant(
    cfg: &Config,
    seed: u64,
    v: usize,
    runs: usize,
    progress: bool,
) -> Result<VariantRuns> {
    let profile = Profile::new(&cfg.profile)?;
    let run_seed = seed_of_runs(seed, v);
    monte_carlo("vc variant", runs, run_seed, progress, |_, rng| {
        let (out, _) = one_run(cfg, &profile, cfg.classical.tau_s, false, rng)?;
        let mut c = out.consistency.into_iter().skip(1);
        let (Some(flight), Some(paper)) = (c.next(), c.next()) else {
            anyhow::bail!("aided consistency missing");
        };
        Ok((flight, paper, out.sumsq[1], out.n))
    })
    .into_iter()
    .collect()
}

/// The two [`VariantResult`]s of a variant's runs.
pub fn results(v: usize, params: &Value, runs: &VariantRuns) -> Vec<VariantResult> {
    let n: usize = runs.iter().map(|r| r.3).sum();
    let rms = |q: usize| (runs.iter().map(|r| r.2[q]).sum::<f64>() / n.max(1) as f64).sqrt();
    let rms = vec![("h_m".to_string(), rms(0)), ("vz_m_s".to_string(), rms(1))];
    let flight: Vec<RunConsistency> = runs.iter().map(|r| r.0.clone()).collect();
    let paper: Vec<RunConsistency> = runs.iter().map(|r| r.1.clone()).collect();
    vec![
        VariantResult {
            variant: v,
            filter: "flight".into(),
            params: params.clone(),
            consistency: Consistency::from_runs(2, &flight),
            rms: rms.clone(),
        },
        VariantResult {
            variant: v,
            filter: "paper".into(),
            params: params.clone(),
            consistency: Consistency::from_runs(2, &paper),
            rms,
        },
    ]
}

fn run(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let base = load_config("vc-montecarlo")?;
    let mut out = Vec::new();
    for v in 0..plan.variants {
        let (cfg, params) = draw_variant(&base, plan.seed, v);
        let runs = fly_variant(&cfg, plan.seed, v, plan.runs, plan.progress)?;
        out.extend(results(v, &params, &runs));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::scenarios::campaign_plan::{MIN_FRAC_IN_BAND, NES_MAX};

    /// The same consistency with every σ scaled by `s` (NEES and e²/σ² by 1/s²).
    fn scaled(rc: &RunConsistency, s: f64) -> RunConsistency {
        let k = 1.0 / (s * s);
        RunConsistency {
            t_s: rc.t_s.clone(),
            nees: rc.nees.iter().map(|x| x * k).collect(),
            normalized: rc
                .normalized
                .iter()
                .map(|(n, v)| (n.clone(), v.iter().map(|x| x * k).collect()))
                .collect(),
        }
    }

    /// The classical loop's campaign is reproducible, flies the aided campaign's variants and
    /// reports the classical loop (its own errors and σ, not the aided loop's).
    #[test]
    fn classical_campaign_is_reproducible_and_flies_the_classical_loop() {
        let plan = CampaignPlan {
            variants: 1,
            runs: 3,
            seed: 21,
            progress: false,
        };
        let a = run_classical(&plan).unwrap();
        let b = run_classical(&plan).unwrap();
        crate::scenarios::campaign_plan::assert_same_results(&a, &b);
        let aided = run(&plan).unwrap();
        assert_eq!(a.len(), 1);
        assert_eq!(a[0].params, aided[0].params);
        assert_ne!(a[0].rms, aided[0].rms);
        assert_ne!(a[0].consistency.nees_mean, aided[0].consistency.nees_mean);
    }

    #[test]
    fn campaign_is_reproducible_and_judges_an_overconfident_sigma_failing() {
        let plan = CampaignPlan {
            variants: 2,
            runs: 6,
            seed: 77,
            progress: false,
        };
        let a = run(&plan).unwrap();
        let b = run(&plan).unwrap();
        assert_eq!(a.len(), 4);
        crate::scenarios::campaign_plan::assert_same_results(&a, &b);
        // Another seed draws other variants.
        let (_, p0) = draw_variant(&load_config("vc-montecarlo").unwrap(), 78, 0);
        assert_ne!(p0, a[0].params);
        // The flight σ of one variant, and the same σ scaled by 0.3.
        let base = load_config("vc-montecarlo").unwrap();
        let (cfg, _) = draw_variant(&base, 77, 0);
        let runs = fly_variant(&cfg, 77, 0, 10, false).unwrap();
        let honest: Vec<RunConsistency> = runs.iter().map(|r| r.0.clone()).collect();
        let c = Consistency::from_runs(2, &honest);
        let worst = |c: &Consistency| {
            c.normalized_error_sq
                .iter()
                .map(|(_, v)| *v)
                .fold(0.0, f64::max)
        };
        assert!(worst(&c) < NES_MAX, "{:?}", c.normalized_error_sq);
        let over: Vec<RunConsistency> = honest.iter().map(|r| scaled(r, 0.3)).collect();
        let c = Consistency::from_runs(2, &over);
        assert!(c.frac_in_band() < MIN_FRAC_IN_BAND, "{}", c.frac_in_band());
        assert!(worst(&c) > NES_MAX, "{:?}", c.normalized_error_sq);
    }

    /// Evidence for docs/vertical-channel.md (run by hand, `--ignored --nocapture`): the campaign's variants
    /// re-flown with other run seeds (same parameters). A variant whose pass or fail flips with
    /// the seed fails by the sampling spread of 30 runs of slowly correlated errors, not by a
    /// σ that is wrong for it.
    #[test]
    #[ignore]
    fn variants_with_other_run_seeds() {
        let base = load_config("vc-montecarlo").unwrap();
        for v in 0..30 {
            let (cfg, _) = draw_variant(&base, 9100, v);
            let mut line = format!("variant {v:2}:");
            for s in 0..3u64 {
                let runs = fly_variant(&cfg, 9100 + s * 1_000_003, v, 30, false).unwrap();
                let r = results(v, &Value::Null, &runs);
                let c = &r[0].consistency;
                line += &format!(
                    "  seed {s}: frac {:.3} NEES {:.2} nes {:.2}/{:.2}",
                    c.frac_in_band(),
                    c.mean_nees(),
                    c.normalized_error_sq[0].1,
                    c.normalized_error_sq[1].1
                );
            }
            println!("{line}");
        }
    }
}

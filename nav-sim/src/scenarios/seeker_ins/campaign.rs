//! The seeker-aided INS's contribution to the consistency campaign
//! ([`crate::scenarios::consistency_campaign`]): the flight configuration and the paper filter
//! flown on the same runs of randomized variants of the seeker scenario.
//!
//! Variant `v` draws from stream `v` of the campaign seed ([`crate::rng::run_rng`]):
//!
//! | parameter | range |
//! | --- | --- |
//! | landmark bearing from the start | 0–360° |
//! | landmark range from the start | 30–120 km (on the ground) |
//! | speed | 100–300 m/s |
//! | altitude | 0.5–5 km |
//! | heading | the landmark bearing ± 15° |
//! | manoeuvre axis | along-track (straight, then a 1–3 m/s² acceleration) or lateral (S-turns of 10–30° amplitude, 40–120 s period) |
//! | manoeuvre time | along-track: start at 20–70 % of the flight; lateral: the period |
//!
//! Every variant flies [`DURATION_S`] s (shortened so that the vehicle stays at least
//! [`MIN_END_RANGE_M`] from the landmark: a short-range, fast variant ends earlier), at the
//! scenario's rates and with the Table 3 / Table 4 errors of `seeker-straight.toml`, in f64
//! ([`CAMPAIGN`]: the covariance model) and, on the same variants and runs, with the flight
//! configuration in f32 as on the target ([`CAMPAIGN_F32`]; the paper filter, the accuracy
//! reference, stays f64). Its runs draw from the streams of a seed drawn from the variant's
//! stream; both filters fly each run from the same stream.

use super::config::{load_config, output_epochs, Config};
use super::errors::RunOutput;
use super::run::{simulate_run_with, FilterKind};
use super::trajectory::{self, Shape};
use crate::consistency::Consistency;
use crate::rng::run_rng;
use crate::scenarios::campaign_plan::{Campaign, CampaignPlan, VariantResult};
use anyhow::Result;
use nav_core::seeker_ins::STATES;
use rand::Rng;
use serde_json::json;

/// Longest flight time of a variant, s (the paper scenarios' 240 s; the whole campaign, 30
/// variants × 30 runs × 2 filters, runs in well under 3 minutes on one core at that length).
pub const DURATION_S: f64 = 240.0;
/// Closest range to the landmark at the end of a variant, m.
pub const MIN_END_RANGE_M: f64 = 10_000.0;
/// Shortest variant, s (a variant that would end earlier flies more slowly).
const MIN_DURATION_S: f64 = 60.0;

/// The campaign entry.
pub const CAMPAIGN: Campaign = Campaign {
    estimator: "seeker_ins",
    about: "landmark bearing 0-360 deg and range 30-120 km, speed 100-300 m/s, altitude \
            0.5-5 km, along-track acceleration or S-turns (time, size); f64",
    run,
};

/// The drawn parameters of one variant and its scenario configuration.
struct Variant {
    params: serde_json::Value,
    cfg: Config,
    run_seed: u64,
}

/// Draws variant `v` from stream `v` of `seed`.
fn draw_variant(base: &Config, seed: u64, v: usize) -> Variant {
    let mut rng = run_rng(seed, v as u64);
    let bearing_deg: f64 = rng.random_range(0.0..360.0);
    let range_m: f64 = rng.random_range(30_000.0..120_000.0);
    let mut speed_m_s: f64 = rng.random_range(100.0..300.0);
    let alt_m: f64 = rng.random_range(500.0..5000.0);
    let heading_offset_deg: f64 = rng.random_range(-15.0..15.0);
    let lateral = rng.random_bool(0.5);
    let accel_m_s2: f64 = rng.random_range(1.0..3.0);
    let accel_start_frac: f64 = rng.random_range(0.2..0.7);
    let s_amplitude_deg: f64 = rng.random_range(10.0..30.0);
    let s_period_s: f64 = rng.random_range(40.0..120.0);
    let run_seed: u64 = rng.random();
    // Distance flown (upper bound: the along-track acceleration for the whole flight).
    let reach = |speed: f64, d: f64| {
        if lateral {
            speed * d
        } else {
            speed * d + 0.5 * accel_m_s2 * d * d
        }
    };
    let budget = range_m - MIN_END_RANGE_M;
    let mut duration_s = DURATION_S;
    while duration_s > MIN_DURATION_S && reach(speed_m_s, duration_s) > budget {
        duration_s -= 5.0;
    }
    if reach(speed_m_s, duration_s) > budget {
        speed_m_s = (budget
            - if lateral {
                0.0
            } else {
                0.5 * accel_m_s2 * duration_s * duration_s
            })
            / duration_s;
    }
    let mut cfg = base.clone();
    let t = &mut cfg.trajectory;
    t.shape = if lateral {
        Shape::STurn
    } else {
        Shape::Straight
    };
    t.speed_m_s = speed_m_s;
    t.alt_m = alt_m;
    t.heading_deg = bearing_deg + heading_offset_deg;
    t.duration_s = duration_s;
    t.accel_m_s2 = if lateral { 0.0 } else { accel_m_s2 };
    t.accel_start_s = accel_start_frac * duration_s;
    t.s_amplitude_deg = s_amplitude_deg;
    t.s_period_s = s_period_s;
    let b = bearing_deg.to_radians();
    cfg.landmark.north_m = range_m * b.cos();
    cfg.landmark.east_m = range_m * b.sin();
    cfg.landmark.alt_m = 0.0;
    cfg.filter.precision = "f64".into();
    let manoeuvre = if lateral {
        json!({"axis": "lateral", "s_amplitude_deg": s_amplitude_deg, "s_period_s": s_period_s})
    } else {
        json!({"axis": "along-track", "accel_m_s2": accel_m_s2,
               "accel_start_s": accel_start_frac * duration_s})
    };
    Variant {
        params: json!({
            "landmark_bearing_deg": bearing_deg,
            "landmark_range_m": range_m,
            "speed_m_s": speed_m_s,
            "alt_m": alt_m,
            "heading_deg": bearing_deg + heading_offset_deg,
            "duration_s": duration_s,
            "manoeuvre": manoeuvre,
        }),
        cfg,
        run_seed,
    }
}

/// Axis names of the RMS (units in the names), in the order of [`RunOutput::err`].
const AXES: [&str; 9] = [
    "lat_m",
    "lon_m",
    "alt_m",
    "vn_m_s",
    "ve_m_s",
    "vd_m_s",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
];

/// RMS per axis over the runs and the settled epochs.
fn rms(runs: &[RunOutput], t_s: &[f64]) -> Vec<(String, f64)> {
    let t0 = t_s.first().copied().unwrap_or(0.0);
    AXES.iter()
        .enumerate()
        .map(|(i, name)| {
            let (mut s2, mut n) = (0.0, 0usize);
            for r in runs {
                for (k, e) in r.err[i].iter().enumerate() {
                    if t_s
                        .get(k)
                        .is_some_and(|t| *t >= t0 + crate::consistency::SETTLE_S)
                    {
                        s2 += e * e;
                        n += 1;
                    }
                }
            }
            ((*name).to_string(), (s2 / n.max(1) as f64).sqrt())
        })
        .collect()
}

/// The flight configuration flown in f32, as on the target, over the same variants and runs;
/// the paper filter beside it in f64 (the accuracy reference).
pub const CAMPAIGN_F32: Campaign = Campaign {
    estimator: "seeker_ins_f32",
    about: "the seeker_ins variants and runs with the flight configuration in f32 (the paper \
            filter, the accuracy reference, in f64)",
    run: run_f32,
};

/// Flies one variant with both filters, the flight configuration in float type `T`.
fn fly_variant<T: nav_core::Real>(
    v: usize,
    var: &Variant,
    runs: usize,
    progress: bool,
) -> Result<[VariantResult; 2]> {
    let cfg = &var.cfg;
    let truth = trajectory::generate(&cfg.trajectory, 1.0 / cfg.rates.imu_hz);
    let epochs = output_epochs(&truth, cfg);
    let t_s: Vec<f64> = epochs.iter().map(|&k| truth.t_s[k]).collect();
    let none = super::injection::Faults::default();
    let label = format!("seeker v{v}");
    let out = crate::montecarlo::monte_carlo(&label, runs, var.run_seed, progress, |_, rng| {
        let mut r = rng.clone();
        let flight = simulate_run_with::<T>(
            cfg,
            &truth,
            &epochs,
            &mut r,
            true,
            FilterKind::Flight,
            &none,
        )?;
        let mut r = rng.clone();
        let paper =
            simulate_run_with::<f64>(cfg, &truth, &epochs, &mut r, true, FilterKind::Paper, &none)?;
        Ok::<_, anyhow::Error>((flight, paper))
    });
    let mut flight = Vec::with_capacity(runs);
    let mut paper = Vec::with_capacity(runs);
    for r in out {
        let (f, p) = r?;
        flight.push(f);
        paper.push(p);
    }
    let result = |kind: FilterKind, rs: &[RunOutput]| VariantResult {
        variant: v,
        filter: kind.name().into(),
        params: var.params.clone(),
        consistency: Consistency::from_runs(
            STATES,
            &rs.iter().map(|r| r.consistency.clone()).collect::<Vec<_>>(),
        ),
        rms: rms(rs, &t_s),
    };
    Ok([
        result(FilterKind::Flight, &flight),
        result(FilterKind::Paper, &paper),
    ])
}

/// The campaign's `run`.
fn run(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let base = load_config("seeker-straight")?;
    let mut out = Vec::with_capacity(2 * plan.variants);
    for v in 0..plan.variants {
        let var = draw_variant(&base, plan.seed, v);
        out.extend(fly_variant::<f64>(v, &var, plan.runs, plan.progress)?);
    }
    Ok(out)
}

/// [`CAMPAIGN_F32`]'s `run`.
fn run_f32(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let base = load_config("seeker-straight")?;
    let mut out = Vec::with_capacity(2 * plan.variants);
    for v in 0..plan.variants {
        let mut var = draw_variant(&base, plan.seed, v);
        var.cfg.filter.precision = "f32".into();
        out.extend(fly_variant::<f32>(v, &var, plan.runs, plan.progress)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::consistency::nees_band_95;
    use crate::scenarios::campaign_plan::{MIN_FRAC_IN_BAND, NES_MAX};

    /// Same seed, same numbers; the variants stay inside the drawn ranges.
    #[test]
    fn campaign_is_reproducible() {
        let plan = CampaignPlan {
            variants: 2,
            runs: 2,
            seed: 17,
            progress: false,
        };
        let a = run(&plan).unwrap();
        let b = run(&plan).unwrap();
        assert_eq!(a.len(), 4);
        crate::scenarios::campaign_plan::assert_same_results(&a, &b);
        let other = run(&CampaignPlan { seed: 18, ..plan }).unwrap();
        assert_ne!(a[0].params, other[0].params);
        for r in &a {
            let p = &r.params;
            let range = p["landmark_range_m"].as_f64().unwrap();
            assert!((30_000.0..120_000.0).contains(&range));
            let alt = p["alt_m"].as_f64().unwrap();
            assert!((500.0..5000.0).contains(&alt));
        }
    }

    /// The f32 campaign flies the same variants and runs: the paper filter (f64 in both) gives
    /// the same numbers bit for bit, the flight configuration in f32 a NEES within 15 % of f64's.
    #[test]
    fn f32_campaign_flies_the_same_runs() {
        let plan = CampaignPlan {
            variants: 1,
            runs: 2,
            seed: 17,
            progress: false,
        };
        let a = run(&plan).unwrap();
        let b = run_f32(&plan).unwrap();
        assert_eq!(a[0].params, b[0].params);
        assert_eq!(a[1].filter, "paper");
        assert_eq!(a[1].consistency.nees_mean, b[1].consistency.nees_mean);
        let ratio = b[0].consistency.mean_nees() / a[0].consistency.mean_nees();
        assert!((0.85..1.15).contains(&ratio), "f32/f64 NEES {ratio}");
        assert_ne!(a[0].consistency.nees_mean, b[0].consistency.nees_mean);
    }

    /// The flight configuration's covariance scaled by 0.3² (σ × 0.3, an overconfident
    /// filter) is judged failing by the campaign's targets: NEES scales by 1/0.09.
    #[test]
    fn an_overconfident_filter_fails_the_targets() {
        let plan = CampaignPlan {
            variants: 1,
            runs: 4,
            seed: 5,
            progress: false,
        };
        let res = run(&plan).unwrap();
        let flight = res.iter().find(|r| r.filter == "flight").unwrap();
        let mut c = flight.consistency.clone();
        let k = 1.0 / (0.3 * 0.3);
        c.nees_mean.iter_mut().for_each(|x| *x *= k);
        c.normalized_error_sq.iter_mut().for_each(|(_, x)| *x *= k);
        let (_, hi) = nees_band_95(c.dof, c.runs);
        assert!(c.mean_nees() > hi, "{} vs {hi}", c.mean_nees());
        assert!(c.frac_in_band() < MIN_FRAC_IN_BAND);
        assert!(c.normalized_error_sq.iter().any(|(_, x)| *x > NES_MAX));
    }
}

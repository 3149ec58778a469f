//! The mission: one truth from captive carry to the landmark area, the ground on which the
//! three estimators are flown as one chain by the flight navigator.
//!
//! `mission` (scenario files `mission`, `mission-s-turn`): per Monte Carlo run one truth
//! ([`truth`]), the flight computer's inputs ([`sensors`]) and a Table 4 draw at release, then
//! every variant of the chain on those same numbers ([`run`]): `full` (flight transfer
//! alignment, hand-over, baro EKF, seeker), `conventional_alignment` (9-state alignment),
//! `table4_initial` (released with the seeker paper's Table 4 initial errors, no alignment),
//! `no_baro`, `no_seeker`, `baro_loop` (baro through the baro-inertial loop). Statistics,
//! summary and figures in [`report`].

pub mod config;
pub mod fault;
pub mod navigator_setup;
pub mod profile;
pub mod report;
pub mod run;
pub mod sensors;
pub mod truth;

use crate::montecarlo::monte_carlo;
use crate::output::sig;
use crate::plot::{render, Figure, Panel, Series};
use crate::scenario::{Context, Kind};
use anyhow::{anyhow, Result};
use config::MissionConfig;
use navigator_setup::{NavigatorSettings, Variant};
use report::{reduce, PhaseTag, VariantStats};
use run::{simulate_run, MissionRun};
use sensors::MissionFaults;
use serde::Deserialize;
use serde_json::{json, Map, Value};

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "mission",
    about:
        "flight navigator take-off to impact (TA → hand-over → baro → seeker): what each link buys",
    run: run_scenario,
};

/// A mission scenario file without its header: the truth and sensors, the navigator's
/// settings, the variants to fly.
#[derive(Debug, Clone)]
pub struct MissionScenario {
    /// Truth and sensors.
    pub mission: MissionConfig,
    /// The navigator's design.
    pub navigator: NavigatorSettings,
    /// Variants flown.
    pub variants: Vec<Variant>,
}

/// Splits a scenario table into its parts (`navigator`, `variants`, `faults` are the
/// navigator's and the runner's; the rest is [`MissionConfig`]).
pub fn parse_scenario(mut doc: toml::Table) -> Result<(MissionScenario, Option<toml::Value>)> {
    let nav = doc
        .remove("navigator")
        .ok_or_else(|| anyhow!("missing [navigator]"))?;
    let variants: Vec<String> = match doc.remove("variants") {
        Some(v) => Vec::<String>::deserialize(v)?,
        None => Variant::ALL.iter().map(|v| v.name().to_string()).collect(),
    };
    let faults = doc.remove("faults");
    let mission = MissionConfig::deserialize(toml::Value::Table(doc))?;
    mission.check()?;
    Ok((
        MissionScenario {
            mission,
            navigator: NavigatorSettings::deserialize(nav)?,
            variants: variants
                .iter()
                .map(|v| Variant::from_name(v))
                .collect::<Result<_>>()?,
        },
        faults,
    ))
}

/// Loads a shipped scenario file (`nav-sim/scenarios/<name>.toml`) without its header.
pub fn load_scenario(name: &str) -> Result<(MissionScenario, Option<toml::Value>)> {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
    for k in ["kind", "description", "runs", "seed"] {
        doc.remove(k);
    }
    parse_scenario(doc)
}

/// The runs of a scenario: `runs` runs from `seed` (rayon; run `i` draws from its own stream,
/// so the result does not depend on the threads).
pub fn monte_carlo_runs(
    sc: &MissionScenario,
    faults: &MissionFaults,
    runs: usize,
    seed: u64,
    progress: bool,
    label: &str,
) -> Result<Vec<MissionRun>> {
    monte_carlo(label, runs.max(1), seed, progress, |i, rng| {
        simulate_run(
            &sc.mission,
            &sc.navigator,
            &sc.variants,
            faults,
            i == 0,
            rng,
        )
        .map_err(|e| anyhow!("run {i}: {e}"))
    })
    .into_iter()
    .collect()
}

/// The statistics of every variant.
pub fn variant_stats(sc: &MissionScenario, runs: &[MissionRun]) -> Vec<VariantStats> {
    sc.variants
        .iter()
        .enumerate()
        .map(|(i, v)| {
            let recs: Vec<&report::FlightRecord> = runs.iter().map(|r| &r.records[i]).collect();
            reduce(v.name(), &recs)
        })
        .collect()
}

fn run_scenario(ctx: &Context) -> Result<Value> {
    let (sc, _) = parse_scenario(ctx.params.clone())?;
    let runs = monte_carlo_runs(
        &sc,
        &MissionFaults::default(),
        ctx.runs,
        ctx.seed,
        ctx.progress,
        &ctx.name,
    )?;
    let stats = variant_stats(&sc, &runs);
    let find = |n: &str| stats.iter().find(|s| s.name == n);
    // Figures.
    if let Some(full) = find("full") {
        report::error_csv(full, &ctx.out_dir.join("errors.csv"))?;
        report::error_figure(
            full,
            &format!(
                "{}: full chain, error and σ through all phases ({} runs)",
                ctx.name, full.runs
            ),
            &ctx.out_dir.join("errors.png"),
        )?;
    }
    let nees_vs: Vec<&VariantStats> = ["full", "conventional_alignment", "table4_initial"]
        .iter()
        .filter_map(|n| find(n))
        .collect();
    report::nees_figure(
        &nees_vs,
        &format!("{}: NEES of the navigator through all phases", ctx.name),
        &ctx.out_dir.join("nees.png"),
    )?;
    report::links_figure(
        &stats.iter().collect::<Vec<_>>(),
        &format!(
            "{}: what each link buys (same seeds, {} runs)",
            ctx.name, ctx.runs
        ),
        &ctx.out_dir.join("links.png"),
    )?;
    if let Some(truth) = runs.first().and_then(|r| r.truth.as_ref()) {
        trajectory_figure(ctx, &sc.mission, truth, &runs[0].records[0])?;
    }
    // Summary.
    let mut variants = Map::new();
    for s in &stats {
        variants.insert(s.name.clone(), s.summary());
    }
    let lock: Vec<f64> = runs.iter().filter_map(|r| r.first_lock_s).collect();
    let targets = targets(&stats);
    for s in &stats {
        println!(
            "  {:>22}: final RMS N {:.1} E {:.1} D {:.1} m | NEES in band {:.2} | hand-over e²/σ² {}",
            s.name,
            s.final_rms(0),
            s.final_rms(1),
            s.final_rms(2),
            s.consistency.frac_in_band(),
            s.handover_summary()["normalized_error_sq_mean"]
        );
    }
    Ok(json!({
        "precision": format!("{:?}", sc.navigator.precision).to_lowercase(),
        "first_lock_s_mean": sig(lock.iter().sum::<f64>() / lock.len().max(1) as f64, 5),
        "variants": Value::Object(variants),
        "targets": targets,
        "error_convention": "navigator − truth; position NED m, velocity NED m/s, attitude φ NED rad with Ĉ_b^n = (I − [φ×]) C_b^n (the navigator's covariance order)",
    }))
}

/// The targets measured (not tuned): NEES in band ≥ 90 % of epochs in every phase; hand-over
/// normalized error² in [0.5, 2]; full final position RMS ≤ table4_initial's; vertical RMS
/// < 50 m through midcourse without the seeker.
fn targets(stats: &[VariantStats]) -> Value {
    let find = |n: &str| stats.iter().find(|s| s.name == n);
    let mut out = Map::new();
    if let Some(full) = find("full") {
        let mut ph = Map::new();
        for (p, c, _) in &full.phases {
            let f = c.frac_in_band();
            ph.insert(
                p.name().into(),
                json!({"frac_in_band": sig(f, 3), "met": f >= 0.9}),
            );
        }
        out.insert(
            "full_nees_in_band_per_phase_ge_0_9".into(),
            Value::Object(ph),
        );
        let h = full.handover_summary()["normalized_error_sq_mean"].as_f64();
        out.insert(
            "full_handover_normalized_error_sq_in_0_5_2".into(),
            json!({"value": h, "met": h.is_some_and(|v| (0.5..=2.0).contains(&v))}),
        );
        if let Some(t4) = find("table4_initial") {
            let f = full
                .final_rms(0)
                .hypot(full.final_rms(1))
                .hypot(full.final_rms(2));
            let t = t4
                .final_rms(0)
                .hypot(t4.final_rms(1))
                .hypot(t4.final_rms(2));
            out.insert(
                "full_final_position_rms_le_table4".into(),
                json!({"full_m": sig(f, 4), "table4_initial_m": sig(t, 4), "met": f <= t}),
            );
        }
    }
    if let (Some(ekf), Some(lp)) = (find("full"), find("baro_loop")) {
        let row = |v: &VariantStats| {
            let nees = |p: PhaseTag| {
                v.phases
                    .iter()
                    .find(|(q, _, _)| *q == p)
                    .map(|(_, c, _)| sig(c.mean_nees(), 4))
            };
            json!({
                "midcourse_rms_down_m": sig(v.phase_rms(PhaseTag::Midcourse, 2), 4),
                "midcourse_rms_vel_down_m_s": sig(v.phase_rms(PhaseTag::Midcourse, 5), 4),
                "terminal_rms_down_m": sig(v.phase_rms(PhaseTag::Terminal, 2), 4),
                "final_rms_down_m": sig(v.final_rms(2), 4),
                "midcourse_nees_mean": nees(PhaseTag::Midcourse),
                "terminal_nees_mean": nees(PhaseTag::Terminal),
            })
        };
        out.insert(
            "baro_damping_by_measurement".into(),
            json!({"ekf": row(ekf), "inertial_loop": row(lp)}),
        );
    }
    if let Some(ns) = find("no_seeker") {
        let v = ns.phase_max_rms(PhaseTag::Midcourse, 2);
        out.insert(
            "no_seeker_vertical_rms_lt_50_m_through_midcourse".into(),
            json!({"max_rms_down_m": sig(v, 4), "met": v < 50.0}),
        );
    }
    Value::Object(out)
}

/// `trajectory.png`: the first run's missile track (north-east) and altitude, coloured by the
/// navigator's phase.
fn trajectory_figure(
    ctx: &Context,
    cfg: &MissionConfig,
    truth: &truth::MissionTruth,
    rec0: &report::FlightRecord,
) -> Result<()> {
    let (mut track, alt) = phase_tracks(truth, rec0);
    track.push(Series {
        style: crate::plot::Style::Points,
        ..Series::line(
            "landmark",
            &[cfg.landmark.east_m * 1e-3],
            &[cfg.landmark.north_m * 1e-3],
            5,
        )
    });
    render(
        &Figure {
            title: format!(
                "{}: run 0 — missile track and altitude by navigator phase",
                ctx.name
            ),
            x_label: "east, km (top) / time, s (bottom)".into(),
            panels: vec![
                Panel {
                    title: "track: north vs east".into(),
                    y_label: "north, km".into(),
                    series: track,
                    y_range: None,
                },
                Panel {
                    title: "altitude".into(),
                    y_label: "m".into(),
                    series: alt,
                    y_range: None,
                },
            ],
            columns: 1,
        },
        &ctx.out_dir.join("trajectory.png"),
        1200,
        1000,
    )
}

/// The first run's missile track (north-east, km) and altitude (m against time, s), one
/// series per navigator phase, every 50th epoch.
fn phase_tracks(
    truth: &truth::MissionTruth,
    rec0: &report::FlightRecord,
) -> (Vec<Series>, Vec<Series>) {
    let m = &truth.missile;
    let p0 = m.position[0];
    let ne = |k: usize| {
        let p = &m.position[k];
        crate::truth::landmark_vector_ned_m(
            (p0.lat_rad, p0.lon_rad, p0.alt_m),
            (p.lat_rad, p.lon_rad, p.alt_m),
        )
    };
    let phase_at = |t: f64| {
        rec0.transitions
            .iter()
            .rev()
            .find(|(tt, _)| *tt <= t + 1e-9)
            .map(|(_, p)| *p)
    };
    let mut track = Vec::new();
    let mut alt = Vec::new();
    for (i, p) in PhaseTag::ALL.iter().enumerate() {
        let ks: Vec<usize> = (0..m.t_s.len())
            .step_by(50)
            .filter(|&k| phase_at(m.t_s[k]) == Some(*p))
            .collect();
        if ks.is_empty() {
            continue;
        }
        let d: Vec<_> = ks.iter().map(|&k| ne(k)).collect();
        track.push(Series {
            style: crate::plot::Style::Points,
            ..Series::line(
                p.name(),
                &d.iter().map(|v| v.y * 1e-3).collect::<Vec<_>>(),
                &d.iter().map(|v| v.x * 1e-3).collect::<Vec<_>>(),
                i,
            )
        });
        alt.push(Series {
            style: crate::plot::Style::Points,
            ..Series::line(
                p.name(),
                &ks.iter().map(|&k| m.t_s[k]).collect::<Vec<_>>(),
                &ks.iter().map(|&k| m.position[k].alt_m).collect::<Vec<_>>(),
                i,
            )
        });
    }
    (track, alt)
}

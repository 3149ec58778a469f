//! `nav-sim`: run the simulator's scenarios from the command line.

use anyhow::Result;
use clap::{Parser, Subcommand};
use nav_sim::scenario::{self, RunOptions};
use nav_sim::scenarios;
use std::path::{Path, PathBuf};
use std::time::Instant;

#[derive(Debug, Parser)]
#[command(
    name = "nav-sim",
    about = "Host simulator and paper reproductions for nav-core"
)]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
}

#[derive(Debug, Subcommand)]
enum Cmd {
    /// List the scenario files and the scenario kinds.
    List {
        /// Directory of scenario files.
        #[arg(long)]
        scenario_dir: Option<PathBuf>,
    },
    /// Record the golden vectors the firmware replays on QEMU (`cargo xtask qemu`).
    Golden {
        /// Output directory.
        #[arg(long, default_value = "target/golden")]
        out: PathBuf,
        /// Seed of the recorded runs.
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
    /// The stress campaign: every estimator over its envelope, long runs; writes
    /// OUT/report.json and fails when any estimator stalled, committed a non-PSD covariance or
    /// returned a non-finite value.
    Stress {
        /// The full campaign (10⁶-10⁷ steps per long run) instead of CI's short one.
        #[arg(long)]
        full: bool,
        /// Output directory.
        #[arg(long, default_value = "target/stress")]
        out: PathBuf,
        /// Run one estimator's campaign only: transfer_alignment, seeker_ins,
        /// vertical_channel or navigator (the report then says the others did not run).
        #[arg(long)]
        only: Option<String>,
    },
    /// Replay a flight log (a PX4 .ulg file or a directory of CSV files in the documented
    /// schema) through the vertical-channel loops and, where the log has gyro, accelerometer and
    /// attitude, the strapdown INS; writes OUT/{summary.json, timeseries.csv, replay.png,
    /// ins.png}.
    Replay {
        /// The log: a `.ulg` file or a directory with imu.csv, baro.csv (gnss.csv,
        /// estimate.csv optional).
        log: PathBuf,
        /// Replay configuration (TOML); defaults for every absent field.
        #[arg(long)]
        config: Option<PathBuf>,
        /// Output directory.
        #[arg(long, default_value = "target/replay")]
        out: PathBuf,
    },
    /// Run a scenario (by name, or a path to a .toml file), or `all`.
    Run {
        /// Scenario name, path to a scenario file, or `all`.
        scenario: String,
        /// Monte Carlo runs (default: the scenario file's).
        #[arg(long)]
        runs: Option<usize>,
        /// Seed (default: the scenario file's).
        #[arg(long)]
        seed: Option<u64>,
        /// Output root; each scenario writes into OUT/<scenario>/.
        #[arg(long, default_value = "target/sim")]
        out: PathBuf,
        /// Directory of scenario files.
        #[arg(long)]
        scenario_dir: Option<PathBuf>,
        /// No progress bars.
        #[arg(long)]
        quiet: bool,
    },
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    match cli.cmd {
        Cmd::List { scenario_dir } => list(scenario_dir),
        Cmd::Golden { out, seed } => golden(&out, seed),
        Cmd::Replay { log, config, out } => replay(&log, config, &out),
        Cmd::Stress { full, out, only } => stress(full, &out, only.as_deref()),
        Cmd::Run {
            scenario: which,
            runs,
            seed,
            out,
            scenario_dir,
            quiet,
        } => run(which, runs, seed, out, scenario_dir, quiet),
    }
}

/// `list`: the scenario files in `scenario_dir` (default the shipped ones) and the kinds.
fn list(scenario_dir: Option<PathBuf>) -> Result<()> {
    let dir = scenario_dir.unwrap_or_else(scenario::default_scenario_dir);
    println!("scenario files in {}:", dir.display());
    for (name, path) in scenario::list(&dir)? {
        println!("  {name:<20} {}", path.display());
    }
    println!("scenario kinds:");
    for k in scenarios::REGISTRY {
        println!("  {:<20} {}", k.kind, k.about);
    }
    Ok(())
}

/// `golden`: records the golden vectors into `out`.
fn golden(out: &Path, seed: u64) -> Result<()> {
    for (case, steps) in nav_sim::golden::record(out, seed)? {
        println!(
            "golden {:<14} {steps:>5} steps -> {}",
            case.name(),
            out.display()
        );
    }
    Ok(())
}

/// `replay`: one log with the configuration file `config` (default settings without) into
/// `out`, and what it found on the terminal.
fn replay(log: &Path, config: Option<PathBuf>, out: &Path) -> Result<()> {
    let cfg = match config {
        Some(p) => nav_sim::replay::ReplayConfig::from_file(&p)?,
        None => nav_sim::replay::ReplayConfig::default(),
    };
    let summary = nav_sim::replay::replay(log, &cfg, out)?;
    println!("{}", serde_json::to_string_pretty(&summary["loops"])?);
    let ins = &summary["ins"];
    match ins["status"].as_str() {
        Some("Available") => println!(
            "INS: free {} / re-levelled {} (differences to the autopilot)",
            ins["free"]["attitude_vs_autopilot"], ins["relevelled"]["attitude_vs_autopilot"]
        ),
        _ => println!(
            "strapdown INS not run ({}): {}; the vertical loops ran",
            ins["reason"], ins["detail"]
        ),
    }
    let gaps: Vec<String> = summary["streams"]
        .as_object()
        .into_iter()
        .flatten()
        .filter(|(_, v)| v["gap_count"].as_u64().unwrap_or(0) > 0)
        .map(|(k, v)| format!("{k} {}", v["gap_count"]))
        .collect();
    if !gaps.is_empty() {
        println!("gaps (summary.json streams.*.gaps): {}", gaps.join(", "));
    }
    for (k, v) in summary["log_findings"].as_object().into_iter().flatten() {
        if !(v.is_null() || v.as_array().is_some_and(Vec::is_empty)) {
            println!("log finding {k}: {v}");
        }
    }
    println!("baro units check: {}", summary["baro_units_check"]);
    println!(
        "wrote {}/{{summary.json, timeseries.csv, replay.png, ins.png where the INS ran}}",
        out.display()
    );
    Ok(())
}

/// `stress`: the campaign (full or short, one estimator's only) into `out/report.json`, and
/// its table on the terminal; fails unless clean.
fn stress(full: bool, out: &Path, only: Option<&str>) -> Result<()> {
    use nav_sim::stress::{self, StressLevel};
    let level = if full {
        StressLevel::Full
    } else {
        StressLevel::Short
    };
    let report = stress::run_only(level, only)?;
    std::fs::create_dir_all(out)?;
    let path = out.join("report.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)? + "\n")?;
    println!(
        "stress ({}, {:.0} s) -> {}",
        report.level,
        report.elapsed_s,
        path.display()
    );
    println!(
        "{:<20} {:>6} {:>12} {:>8} {:>8} {:>10} {:>12} {:>9}",
        "estimator",
        "cases",
        "steps",
        "stalls",
        "non-PSD",
        "non-finite",
        "max refusals",
        "hostile!"
    );
    for (name, e) in [
        ("transfer_alignment", &report.transfer_alignment),
        ("seeker_ins", &report.seeker_ins),
        ("vertical_channel", &report.vertical_channel),
        ("navigator", &report.navigator),
    ] {
        println!(
            "{name:<20} {:>6} {:>12} {:>8} {:>8} {:>10} {:>12} {:>9}",
            e.cases,
            e.steps,
            e.permanent_stalls,
            e.non_psd_commits,
            e.non_finite_reports,
            e.max_consecutive_refusals,
            e.hostile_not_refused
        );
        for f in &e.findings {
            println!("    {}: {}", f.case, f.finding);
        }
    }
    if report.clean {
        Ok(())
    } else {
        anyhow::bail!("stress campaign not clean (see {})", path.display())
    }
}

/// `run`: the scenario `which` (a name, a file, or `all`) from `scenario_dir` with the
/// overrides, each into `out/<scenario>/`; fails when any failed.
fn run(
    which: String,
    runs: Option<usize>,
    seed: Option<u64>,
    out: PathBuf,
    scenario_dir: Option<PathBuf>,
    quiet: bool,
) -> Result<()> {
    let dir = scenario_dir.unwrap_or_else(scenario::default_scenario_dir);
    let targets = if which == "all" {
        scenario::list(&dir)?
    } else {
        vec![scenario::resolve(&which, &dir)?]
    };
    let opts = RunOptions {
        runs,
        seed,
        out_root: out.clone(),
        progress: !quiet,
    };
    let mut failures = Vec::new();
    for (name, path) in &targets {
        let t0 = Instant::now();
        eprintln!("== {name} ({})", path.display());
        match scenarios::run_file(name, path, &opts) {
            Ok(_) => eprintln!(
                "   wrote {} ({:.1} s)",
                out.join(name).join("summary.json").display(),
                t0.elapsed().as_secs_f64()
            ),
            Err(e) => {
                eprintln!("   FAILED: {e:#}");
                failures.push(name.clone());
            }
        }
    }
    if failures.is_empty() {
        Ok(())
    } else {
        anyhow::bail!(
            "{} scenario(s) failed: {}",
            failures.len(),
            failures.join(", ")
        )
    }
}

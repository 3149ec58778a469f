//! Scenario files and the registry of scenario kinds.
//!
//! A scenario is a TOML file. Its header keys are common to all kinds:
//!
//! ```toml
//! kind = "flexure-process"   # selects the runner in REGISTRY
//! description = "…"
//! runs = 30                  # default Monte Carlo run count
//! seed = 1                   # default seed
//! ```
//!
//! Every other key belongs to the kind's own configuration (`Context::params`), which the
//! runner deserialises with unknown fields denied, so a typo is an error, not a default.

use anyhow::{bail, Context as _, Result};
use serde::de::DeserializeOwned;
use serde::Deserialize;
use std::path::{Path, PathBuf};

/// Everything a runner gets.
#[derive(Debug, Clone)]
pub struct Context {
    /// Scenario name (the file stem).
    pub name: String,
    /// Monte Carlo run count in force (file default or command-line override).
    pub runs: usize,
    /// Seed in force.
    pub seed: u64,
    /// Output directory of this scenario (created), e.g. `target/sim/<name>`.
    pub out_dir: PathBuf,
    /// Draw progress bars.
    pub progress: bool,
    /// The kind-specific keys of the file.
    pub params: toml::Table,
}

impl Context {
    /// Deserialises the kind-specific configuration.
    pub fn config<T: DeserializeOwned>(&self) -> Result<T> {
        T::deserialize(toml::Value::Table(self.params.clone()))
            .with_context(|| format!("scenario `{}`: configuration", self.name))
    }
}

/// A runner: simulates, writes CSV/PNG into `ctx.out_dir`, returns the summary JSON (the
/// caller adds `scenario`, `runs` and `seed` and writes `summary.json`).
pub type Runner = fn(&Context) -> Result<serde_json::Value>;

/// A registered scenario kind.
#[derive(Debug, Clone, Copy)]
pub struct Kind {
    /// Value of the `kind` key.
    pub kind: &'static str,
    /// One line on what it reproduces.
    pub about: &'static str,
    /// The runner.
    pub run: Runner,
}

/// Every scenario kind nav-sim knows.
pub static REGISTRY: &[Kind] = &[
    crate::scenarios::flexure_process::KIND,
    crate::scenarios::transfer_alignment::KIND_CASE,
    crate::scenarios::transfer_alignment::KIND_MODEL_ERROR,
    crate::scenarios::transfer_alignment::KIND_OBSERVABILITY,
    crate::scenarios::transfer_alignment::fault::KIND_FAULT,
    crate::scenarios::seeker_ins::KIND,
    crate::scenarios::seeker_ins::fault::KIND,
    crate::scenarios::vertical_channel::KIND_RESPONSE,
    crate::scenarios::vertical_channel::KIND_MONTECARLO,
    crate::scenarios::vertical_channel_faults::KIND,
    crate::scenarios::vertical_channel::KIND_TAU_SWEEP,
    crate::scenarios::consistency_campaign::KIND,
    crate::scenarios::mission::KIND,
    crate::scenarios::mission::fault::KIND,
];

#[derive(Debug, Deserialize)]
struct Header {
    kind: String,
    #[serde(default)]
    description: String,
    runs: usize,
    seed: u64,
}

/// The scenario files shipped with nav-sim.
pub fn default_scenario_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios")
}

/// Scenario files in `dir`, sorted by name: `(name, path)`.
pub fn list(dir: &Path) -> Result<Vec<(String, PathBuf)>> {
    let mut out = Vec::new();
    for entry in std::fs::read_dir(dir).with_context(|| format!("reading {}", dir.display()))? {
        let path = entry?.path();
        if path.extension().is_some_and(|e| e == "toml") {
            if let Some(stem) = path.file_stem().and_then(|s| s.to_str()) {
                out.push((stem.to_string(), path));
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Resolves a scenario name (a file in `dir`) or a path to a `.toml` file.
pub fn resolve(name_or_path: &str, dir: &Path) -> Result<(String, PathBuf)> {
    let p = Path::new(name_or_path);
    if p.extension().is_some_and(|e| e == "toml") && p.exists() {
        let stem = p.file_stem().and_then(|s| s.to_str()).unwrap_or("scenario");
        return Ok((stem.to_string(), p.to_path_buf()));
    }
    let candidate = dir.join(format!("{name_or_path}.toml"));
    if candidate.exists() {
        return Ok((name_or_path.to_string(), candidate));
    }
    let known: Vec<String> = list(dir)?.into_iter().map(|(n, _)| n).collect();
    bail!(
        "unknown scenario `{name_or_path}`; known: {}",
        known.join(", ")
    )
}

/// Options from the command line.
#[derive(Debug, Clone)]
pub struct RunOptions {
    /// Override of the file's run count.
    pub runs: Option<usize>,
    /// Override of the file's seed.
    pub seed: Option<u64>,
    /// Root output directory; the scenario writes into `out_root/<name>`.
    pub out_root: PathBuf,
    /// Draw progress bars.
    pub progress: bool,
}

/// Loads and runs one scenario file; writes `summary.json` and returns it.
pub fn run_file(name: &str, path: &Path, opts: &RunOptions) -> Result<serde_json::Value> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))?;
    let mut doc: toml::Table =
        toml::from_str(&text).with_context(|| format!("parsing {}", path.display()))?;
    let header: Header = Header::deserialize(toml::Value::Table(doc.clone()))
        .with_context(|| format!("{}: header (kind, runs, seed)", path.display()))?;
    for key in ["kind", "description", "runs", "seed"] {
        doc.remove(key);
    }
    let Some(kind) = REGISTRY.iter().find(|k| k.kind == header.kind) else {
        let known: Vec<&str> = REGISTRY.iter().map(|k| k.kind).collect();
        bail!(
            "{}: unknown kind `{}`; known: {}",
            path.display(),
            header.kind,
            known.join(", ")
        );
    };
    let out_dir = opts.out_root.join(name);
    std::fs::create_dir_all(&out_dir).with_context(|| format!("creating {}", out_dir.display()))?;
    let ctx = Context {
        name: name.to_string(),
        runs: opts.runs.unwrap_or(header.runs).max(1),
        seed: opts.seed.unwrap_or(header.seed),
        out_dir: out_dir.clone(),
        progress: opts.progress,
        params: doc,
    };
    let body = (kind.run)(&ctx)?;
    let mut summary = serde_json::Map::new();
    summary.insert("scenario".into(), name.into());
    summary.insert("kind".into(), header.kind.clone().into());
    summary.insert("description".into(), header.description.clone().into());
    summary.insert("runs".into(), ctx.runs.into());
    summary.insert("seed".into(), ctx.seed.into());
    if let serde_json::Value::Object(m) = body {
        for (k, v) in m {
            summary.insert(k, v);
        }
    } else {
        summary.insert("result".into(), body);
    }
    let summary = serde_json::Value::Object(summary);
    crate::output::write_summary(&out_dir, &summary)?;
    Ok(summary)
}

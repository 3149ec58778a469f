//! Scenario files and what a scenario kind is: the [`Context`] a runner gets and the [`Kind`]
//! it registers (the registry, [`crate::scenarios::REGISTRY`], and the loading of a file,
//! [`crate::scenarios::run_file`], are with the runners).
//!
//! A scenario is a TOML file. Its header keys are common to all kinds:
//!
//! ```toml
//! kind = "flexure-process"   # selects the runner in `scenarios::REGISTRY`
//! description = "…"
//! runs = 30                  # default Monte Carlo run count
//! seed = 1                   # default seed
//! ```
//!
//! Every other key belongs to the kind's own configuration (`Context::params`), which the
//! runner deserialises with unknown fields denied, so a typo is an error, not a default.

use anyhow::{bail, Context as _, Result};
use serde::de::DeserializeOwned;
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

//! Scenario runners, one module per scenario kind, their registry and the loading and running
//! of a scenario file.

pub mod campaign_plan;
pub mod consistency_campaign;
pub mod flexure_process;
pub mod mission;
pub mod navigator_campaign;
pub mod seeker_ins;
pub mod transfer_alignment;
pub mod vertical_channel;
pub mod vertical_channel_faults;

use crate::scenario::{Context, Kind, RunOptions};
use anyhow::{bail, Context as _, Result};
use serde::Deserialize;
use std::path::Path;

/// Every scenario kind nav-sim knows.
pub static REGISTRY: &[Kind] = &[
    flexure_process::KIND,
    transfer_alignment::KIND_CASE,
    transfer_alignment::KIND_MODEL_ERROR,
    transfer_alignment::KIND_OBSERVABILITY,
    transfer_alignment::fault::KIND_FAULT,
    seeker_ins::KIND,
    seeker_ins::fault::KIND,
    vertical_channel::KIND_RESPONSE,
    vertical_channel::KIND_MONTECARLO,
    vertical_channel_faults::KIND,
    vertical_channel::KIND_TAU_SWEEP,
    consistency_campaign::KIND,
    mission::KIND,
    mission::fault::KIND,
];

#[derive(Debug, Deserialize)]
struct Header {
    kind: String,
    #[serde(default)]
    description: String,
    runs: usize,
    seed: u64,
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

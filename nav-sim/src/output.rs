//! Scenario outputs: CSV time series and `summary.json`.

use anyhow::{ensure, Context, Result};
use std::fmt::Write as _;
use std::path::Path;

/// Writes a CSV file with a header row and equally long columns.
pub fn write_csv(path: &Path, headers: &[&str], columns: &[&[f64]]) -> Result<()> {
    ensure!(
        headers.len() == columns.len(),
        "CSV {}: header/column count",
        path.display()
    );
    let n = columns.first().map_or(0, |c| c.len());
    ensure!(
        columns.iter().all(|c| c.len() == n),
        "CSV {}: columns of different lengths",
        path.display()
    );
    let mut s = String::with_capacity(n * columns.len() * 14);
    s.push_str(&headers.join(","));
    s.push('\n');
    for k in 0..n {
        for (j, c) in columns.iter().enumerate() {
            if j > 0 {
                s.push(',');
            }
            let _ = write!(s, "{}", c[k]);
        }
        s.push('\n');
    }
    std::fs::write(path, s).with_context(|| format!("writing {}", path.display()))
}

/// Writes `summary.json` (pretty-printed) into `dir`.
pub fn write_summary(dir: &Path, summary: &serde_json::Value) -> Result<()> {
    let path = dir.join("summary.json");
    let text = serde_json::to_string_pretty(summary)?;
    std::fs::write(&path, text + "\n").with_context(|| format!("writing {}", path.display()))
}

/// Rounds to `digits` significant digits for human-facing summaries (NaN/Inf → null-safe 0).
pub fn sig(x: f64, digits: i32) -> f64 {
    if !x.is_finite() || x == 0.0 {
        return x;
    }
    let p = 10f64.powi(digits - 1 - x.abs().log10().floor() as i32);
    (x * p).round() / p
}

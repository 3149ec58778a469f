//! Filter consistency measured the same way for every filter: NEES against its χ² band and the
//! normalised error squared per axis or state group.
//!
//! For each run `r` and epoch `k` a filter provides its NEES `e_kᵀ P_k⁻¹ e_k` (`dof` states)
//! and, per named component `c`, `e_c² / σ_c²`. Over `R` runs, the run-averaged NEES of a
//! consistent filter is distributed as `χ²(dof · R) / R`; its two-sided 95 % band is
//! [`nees_band_95`]. [`Consistency::summary`] gives the `consistency` object every scenario
//! writes into its `summary.json`:
//!
//! ```json
//! { "nees_dof": 17, "runs": 30, "nees_mean": 17.4, "nees_band_95": [15.9, 18.2],
//!   "frac_in_band": 0.93, "settle_s": 5.0,
//!   "normalized_error_sq": { "pos_n": 1.1, "vel_n": 0.9 } }
//! ```
//!
//! `nees_mean` and `frac_in_band` use the epochs from `settle_s` (5 s) after the first on;
//! `normalized_error_sq` is the ensemble mean of `e²/σ²` over runs and those epochs (1 when
//! consistent, > 1 when σ is too small).

use crate::plot::{Panel, Series};
use serde_json::{json, Map, Value};

/// Epochs before this time after the first are left out of the consistency figures, s.
pub const SETTLE_S: f64 = 5.0;

/// Quantile of χ²(k) at the standard-normal quantile `z` (Wilson–Hilferty; relative error
/// below 10⁻³ for k ≥ 10, the run counts used here).
pub fn chi2_quantile(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Two-sided 95 % band of the run-averaged NEES of a consistent filter: `dof` states averaged
/// over `runs` runs.
pub fn nees_band_95(dof: usize, runs: usize) -> (f64, f64) {
    let n = (dof * runs) as f64;
    let r = runs as f64;
    (
        chi2_quantile(n, -1.959_964) / r,
        chi2_quantile(n, 1.959_964) / r,
    )
}

/// One run's consistency samples, epoch by epoch.
#[derive(Debug, Clone, Default)]
pub struct RunConsistency {
    /// Epoch times, s.
    pub t_s: Vec<f64>,
    /// NEES per epoch.
    pub nees: Vec<f64>,
    /// Per named component, `e²/σ²` per epoch (same length as `t_s`).
    pub normalized: Vec<(String, Vec<f64>)>,
}

impl RunConsistency {
    /// An empty run with the given component names.
    pub fn new(components: &[&str]) -> Self {
        Self {
            t_s: Vec::new(),
            nees: Vec::new(),
            normalized: components
                .iter()
                .map(|c| ((*c).to_string(), Vec::new()))
                .collect(),
        }
    }

    /// Adds one epoch: time, NEES, and `(error, σ)` of each component in the order given to
    /// [`RunConsistency::new`].
    pub fn push(&mut self, t_s: f64, nees: f64, errors_sigmas: &[(f64, f64)]) {
        self.t_s.push(t_s);
        self.nees.push(nees);
        for ((_, series), &(e, s)) in self.normalized.iter_mut().zip(errors_sigmas) {
            series.push(if s > 0.0 { (e / s).powi(2) } else { f64::NAN });
        }
    }
}

/// Consistency of one filter over a Monte Carlo ensemble.
#[derive(Debug, Clone)]
pub struct Consistency {
    /// States in the NEES.
    pub dof: usize,
    /// Epoch times of the run-averaged series, s.
    pub t_s: Vec<f64>,
    /// Run-averaged NEES per epoch.
    pub nees_mean: Vec<f64>,
    /// Runs.
    pub runs: usize,
    /// Per component, the ensemble mean of `e²/σ²` over runs and settled epochs.
    pub normalized_error_sq: Vec<(String, f64)>,
    /// Epochs before this time after the first are left out of the figures, s.
    pub settle_s: f64,
}

impl Consistency {
    /// Averages the runs (all of the same epochs; a shorter run limits the series).
    pub fn from_runs(dof: usize, runs: &[RunConsistency]) -> Self {
        Self::from_runs_settled(dof, runs, SETTLE_S)
    }

    /// [`Consistency::from_runs`] with the settling time `settle_s` (s) instead of
    /// [`SETTLE_S`] (0 for a series that starts from a settled filter, e.g. one phase of a
    /// longer run).
    pub fn from_runs_settled(dof: usize, runs: &[RunConsistency], settle_s: f64) -> Self {
        let n = runs.iter().map(|r| r.nees.len()).min().unwrap_or(0);
        let t_s: Vec<f64> = runs
            .first()
            .map(|r| r.t_s[..n].to_vec())
            .unwrap_or_default();
        let rc = runs.len().max(1) as f64;
        let nees_mean: Vec<f64> = (0..n)
            .map(|k| runs.iter().map(|r| r.nees[k]).sum::<f64>() / rc)
            .collect();
        let t0 = t_s.first().copied().unwrap_or(0.0);
        let settled: Vec<usize> = (0..n).filter(|&k| t_s[k] >= t0 + settle_s).collect();
        let names: Vec<String> = runs
            .first()
            .map(|r| r.normalized.iter().map(|(c, _)| c.clone()).collect())
            .unwrap_or_default();
        let normalized_error_sq = names
            .iter()
            .enumerate()
            .map(|(i, name)| {
                let (mut sum, mut count) = (0.0, 0usize);
                for r in runs {
                    for &k in &settled {
                        let v = r.normalized[i].1[k];
                        if v.is_finite() {
                            sum += v;
                            count += 1;
                        }
                    }
                }
                (name.clone(), sum / count.max(1) as f64)
            })
            .collect();
        Self {
            dof,
            t_s,
            nees_mean,
            runs: runs.len(),
            normalized_error_sq,
            settle_s,
        }
    }

    /// Settled epochs (from [`SETTLE_S`] after the first).
    fn settled(&self) -> impl Iterator<Item = usize> + '_ {
        let t0 = self.t_s.first().copied().unwrap_or(0.0);
        (0..self.t_s.len()).filter(move |&k| self.t_s[k] >= t0 + self.settle_s)
    }

    /// Mean of the run-averaged NEES over the settled epochs.
    pub fn mean_nees(&self) -> f64 {
        let v: Vec<f64> = self.settled().map(|k| self.nees_mean[k]).collect();
        v.iter().sum::<f64>() / v.len().max(1) as f64
    }

    /// Fraction of settled epochs whose run-averaged NEES is inside the 95 % band.
    pub fn frac_in_band(&self) -> f64 {
        let (lo, hi) = nees_band_95(self.dof, self.runs);
        let v: Vec<f64> = self.settled().map(|k| self.nees_mean[k]).collect();
        v.iter().filter(|&&x| x >= lo && x <= hi).count() as f64 / v.len().max(1) as f64
    }

    /// The `consistency` object of `summary.json` (module doc).
    pub fn summary(&self) -> Value {
        let (lo, hi) = nees_band_95(self.dof, self.runs);
        let mut normalized = Map::new();
        for (name, v) in &self.normalized_error_sq {
            normalized.insert(name.clone(), json!(crate::output::sig(*v, 4)));
        }
        json!({
            "nees_dof": self.dof,
            "runs": self.runs,
            "nees_mean": crate::output::sig(self.mean_nees(), 4),
            "nees_band_95": [crate::output::sig(lo, 4), crate::output::sig(hi, 4)],
            "frac_in_band": crate::output::sig(self.frac_in_band(), 4),
            "settle_s": self.settle_s,
            "normalized_error_sq": Value::Object(normalized),
        })
    }

    /// A plot panel: run-averaged NEES over time with its 95 % band.
    pub fn nees_panel(&self, title: &str) -> Panel {
        let (lo, hi) = nees_band_95(self.dof, self.runs);
        let lo_v = vec![lo; self.t_s.len()];
        let hi_v = vec![hi; self.t_s.len()];
        Panel {
            title: format!(
                "{title}: NEES ({} states, mean of {} runs) and its 95 % band",
                self.dof, self.runs
            ),
            y_label: "NEES".into(),
            series: vec![
                Series::line("NEES", &self.t_s, &self.nees_mean, 0),
                Series::dashed("95 % band", &self.t_s, &lo_v, 3),
                Series::dashed("", &self.t_s, &hi_v, 3),
            ],
            ..Panel::default()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_distr::{Distribution, StandardNormal};

    /// A consistent "filter" (errors drawn with the σ it reports) lands in its band; one whose
    /// σ is half the error does not.
    #[test]
    fn consistent_errors_are_in_band_and_overconfident_ones_are_not() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for (scale, expect_ok) in [(1.0, true), (2.0, false)] {
            let runs: Vec<RunConsistency> = (0..30)
                .map(|_| {
                    let mut r = RunConsistency::new(&["x", "y", "z"]);
                    for k in 0..200 {
                        let e: Vec<(f64, f64)> = (0..3)
                            .map(|_| {
                                let n: f64 = StandardNormal.sample(&mut rng);
                                (scale * 2.0 * n, 2.0)
                            })
                            .collect();
                        let nees = e.iter().map(|(e, s)| (e / s).powi(2)).sum();
                        r.push(f64::from(k) * 0.1, nees, &e);
                    }
                    r
                })
                .collect();
            let c = Consistency::from_runs(3, &runs);
            let summary = c.summary();
            let frac = summary["frac_in_band"].as_f64().unwrap();
            let nx = summary["normalized_error_sq"]["x"].as_f64().unwrap();
            if expect_ok {
                assert!(frac > 0.85, "consistent filter: frac_in_band {frac}");
                assert!((nx - 1.0).abs() < 0.1, "consistent filter: e²/σ² {nx}");
            } else {
                assert!(frac < 0.05, "overconfident filter: frac_in_band {frac}");
                assert!(nx > 3.0, "overconfident filter: e²/σ² {nx}");
            }
            assert_eq!(summary["nees_dof"], 3);
        }
    }

    #[test]
    fn band_matches_tabulated_chi2() {
        // χ²(100) 2.5 % and 97.5 % quantiles: 74.22 and 129.56.
        let (lo, hi) = nees_band_95(10, 10);
        assert!(
            (lo - 7.422).abs() < 0.02 && (hi - 12.956).abs() < 0.02,
            "{lo} {hi}"
        );
    }
}

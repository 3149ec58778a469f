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

/// Most epochs [`Consistency::ideal_frac_in_band`] simulates per run (longer runs are thinned).
pub const IDEAL_MAX_EPOCHS: usize = 400;

/// Effective number of independent settled epochs of a run's NEES: `n / (1 + 2 Σ_k (1 − k/n)
/// r_k)`, `r_k` the lag-`k` autocorrelation of the NEES's deviation from the run-averaged
/// NEES at the same epoch, pooled over the runs, summed until it first falls to 0 or below
/// (the time average of `n` epochs then has the variance of `n_eff` independent ones). 1 for
/// errors constant over the run, `n` for errors white in time.
fn effective_epochs(runs: &[RunConsistency], nees_mean: &[f64], settled: &[usize]) -> f64 {
    let n = settled.len();
    if n < 2 || runs.len() < 2 {
        return n.max(1) as f64;
    }
    let dev: Vec<Vec<f64>> = runs
        .iter()
        .map(|r| settled.iter().map(|&k| r.nees[k] - nees_mean[k]).collect())
        .collect();
    let cov = |lag: usize| -> f64 {
        let (mut s, mut c) = (0.0, 0usize);
        for d in &dev {
            for (x, y) in d.iter().zip(d.iter().skip(lag)) {
                s += x * y;
                c += 1;
            }
        }
        s / c.max(1) as f64
    };
    let c0 = cov(0);
    if c0.is_nan() || c0 <= 0.0 {
        return n as f64;
    }
    let mut inflation = 1.0;
    for lag in 1..n {
        let r = cov(lag) / c0;
        if r.is_nan() || r <= 0.0 {
            break;
        }
        inflation += 2.0 * (1.0 - lag as f64 / n as f64) * r;
    }
    (n as f64 / inflation).clamp(1.0, n as f64)
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
    /// Effective number of independent settled epochs of one run's NEES (`effective_epochs`):
    /// the settled epochs divided by the variance inflation of their time average.
    pub nees_effective_epochs: f64,
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
        let nees_effective_epochs = effective_epochs(runs, &nees_mean, &settled);
        Self {
            dof,
            t_s,
            nees_mean,
            runs: runs.len(),
            normalized_error_sq,
            settle_s,
            nees_effective_epochs,
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

    /// Two-sided 95 % band of [`Consistency::mean_nees`] for a consistent filter with this
    /// filter's time correlation: the time average of the run-averaged NEES over the settled
    /// epochs is distributed (moments matched) as `χ²(dof · runs · n_eff) / (runs · n_eff)` with
    /// `n_eff` = [`Consistency::nees_effective_epochs`]. A consistent filter falls outside it
    /// with probability ≈ 5 %, however correlated its errors are in time.
    pub fn mean_nees_band_95(&self) -> (f64, f64) {
        let m = self.runs as f64 * self.nees_effective_epochs.max(1.0);
        let n = self.dof as f64 * m;
        (
            chi2_quantile(n, -1.959_964) / m,
            chi2_quantile(n, 1.959_964) / m,
        )
    }

    /// `frac_in_band` of `ensembles` simulated ideal filters with this one's states, runs,
    /// settled epochs and time correlation: each run's normalized error is `dof` independent
    /// unit Gauss-Markov sequences whose squares' lag-1 correlation `φ` gives the measured
    /// [`Consistency::nees_effective_epochs`] (`n_eff = n (1 − φ)/(1 + φ)`), so their NEES is
    /// exactly χ²(dof) at every epoch and as correlated in time as this filter's. Sorted
    /// ascending. Epochs are thinned to at most [`IDEAL_MAX_EPOCHS`] (same correlation per
    /// retained step); seeded, reproducible.
    pub fn ideal_frac_in_band(&self, ensembles: usize, seed: u64) -> Vec<f64> {
        use rand::SeedableRng;
        use rand_distr::{Distribution, StandardNormal};
        let n = self.settled().count();
        if n == 0 || self.runs == 0 {
            return Vec::new();
        }
        let n_eff = self.nees_effective_epochs.clamp(1.0, n as f64);
        // Lag-1 correlation of the squares φ = a² (a the Gauss-Markov coefficient), solved so
        // that n epochs of it have the measured n_eff (bisection: the inflation grows with φ).
        let inflation = |phi: f64| {
            let (mut s, mut p) = (1.0, 1.0);
            for k in 1..n {
                p *= phi;
                s += 2.0 * (1.0 - k as f64 / n as f64) * p;
            }
            s
        };
        let target = n as f64 / n_eff;
        let (mut lo_phi, mut hi_phi) = (0.0_f64, 1.0_f64);
        for _ in 0..60 {
            let mid = 0.5 * (lo_phi + hi_phi);
            if inflation(mid) < target {
                lo_phi = mid;
            } else {
                hi_phi = mid;
            }
        }
        let phi = 0.5 * (lo_phi + hi_phi);
        let step = n.div_ceil(IDEAL_MAX_EPOCHS);
        let epochs = n.div_ceil(step);
        let a = phi.sqrt().powi(step as i32);
        let w = (1.0 - a * a).sqrt();
        let (lo, hi) = nees_band_95(self.dof, self.runs);
        let mut out: Vec<f64> = (0..ensembles)
            .map(|e| {
                let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(e as u64);
                let mut sum = vec![0.0; epochs];
                for _ in 0..self.runs {
                    for _ in 0..self.dof {
                        let mut u: f64 = StandardNormal.sample(&mut rng);
                        for (k, s) in sum.iter_mut().enumerate() {
                            if k > 0 {
                                let z: f64 = StandardNormal.sample(&mut rng);
                                u = a * u + w * z;
                            }
                            *s += u * u;
                        }
                    }
                }
                let r = self.runs as f64;
                sum.iter()
                    .filter(|&&v| (lo..=hi).contains(&(v / r)))
                    .count() as f64
                    / epochs as f64
            })
            .collect();
        out.sort_by(f64::total_cmp);
        out
    }

    /// The `consistency` object of `summary.json` (module doc).
    pub fn summary(&self) -> Value {
        let (lo, hi) = nees_band_95(self.dof, self.runs);
        let (mlo, mhi) = self.mean_nees_band_95();
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
            "nees_effective_epochs": crate::output::sig(self.nees_effective_epochs, 4),
            "nees_mean_band_95": [crate::output::sig(mlo, 4), crate::output::sig(mhi, 4)],
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

    /// 30 runs of a filter whose 3 normalized errors are a random constant (weight `c`) plus
    /// white noise, scaled by `scale` (1: consistent), 300 epochs after the settling time.
    fn correlated_runs(rng: &mut rand_chacha::ChaCha8Rng, c: f64, scale: f64) -> Consistency {
        let runs: Vec<RunConsistency> = (0..30)
            .map(|_| {
                let mut r = RunConsistency::new(&["x", "y", "z"]);
                let k0: [f64; 3] = std::array::from_fn(|_| StandardNormal.sample(&mut *rng));
                for k in 0..(50 + 300) {
                    let e: Vec<(f64, f64)> = (0..3)
                        .map(|i| {
                            let w: f64 = StandardNormal.sample(&mut *rng);
                            (scale * (c.sqrt() * k0[i] + (1.0 - c).sqrt() * w), 1.0)
                        })
                        .collect();
                    let nees = e.iter().map(|(e, s)| (e / s).powi(2)).sum();
                    r.push(f64::from(k) * 0.1, nees, &e);
                }
                r
            })
            .collect();
        Consistency::from_runs(3, &runs)
    }

    /// The time-averaged NEES band holds a consistent filter with ≈ 5 % false alarms whether
    /// its errors are white or mostly constant over a run (where `frac_in_band` ≥ 0.9 fails
    /// far more often, as the ideal-filter reference predicts), and rejects a filter whose σ is
    /// 20 % too small when its errors are white.
    #[test]
    fn time_averaged_band_has_its_false_alarm_rate_and_ideal_reference_matches() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
        for (c, min_p_below) in [(0.0, 0.0), (0.8, 0.06)] {
            let trials = 150;
            let (mut outside, mut frac_below, mut p_below_ideal) = (0, 0, 0.0);
            for t in 0..trials {
                let t: u32 = t;
                let k = correlated_runs(&mut rng, c, 1.0);
                let (lo, hi) = k.mean_nees_band_95();
                if !(lo..=hi).contains(&k.mean_nees()) {
                    outside += 1;
                }
                if k.frac_in_band() < 0.9 {
                    frac_below += 1;
                }
                if t < 10 {
                    let ideal = k.ideal_frac_in_band(100, u64::from(t));
                    p_below_ideal +=
                        ideal.iter().filter(|&&f| f < 0.9).count() as f64 / ideal.len() as f64;
                }
            }
            let rate = f64::from(outside) / f64::from(trials);
            assert!((0.0..=0.12).contains(&rate), "c = {c}: false alarms {rate}");
            let observed = f64::from(frac_below) / f64::from(trials);
            let predicted = p_below_ideal / 10.0;
            assert!(observed >= min_p_below, "c = {c}: P(frac < 0.9) {observed}");
            assert!(
                (observed - predicted).abs() < 0.1,
                "c = {c}: P(frac < 0.9) {observed}, ideal reference {predicted}"
            );
        }
        let over = correlated_runs(&mut rng, 0.0, 1.2);
        let (lo, hi) = over.mean_nees_band_95();
        assert!(over.mean_nees() > hi && lo < 3.0, "{:?}", over.summary());
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

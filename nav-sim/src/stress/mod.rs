//! The stress campaign (`nav-sim stress`, `cargo xtask stress`): maps each estimator's
//! operating envelope and runs it long, through the public API only, counting the failures a
//! flight computer cannot afford.
//!
//! Every estimator's campaign returns an [`EstimatorStress`] built with a [`Tally`], so the
//! counts mean the same thing everywhere:
//!
//! - `cases`, `steps`: configurations run and calls made (every public call counts as a step);
//! - `permanent_stalls`: cases that end with the filter refusing valid input
//!   ([`STALL_TAIL_CALLS`] or more consecutive refusals of valid calls at the end of the case,
//!   or any run of refusals of valid calls longer than [`STALL_RUN_CALLS`]);
//! - `non_psd_commits`: committed covariances (checked after accepted calls) that are not
//!   symmetric positive semi-definite to the float type's precision, see [`psd_defect`];
//! - `non_finite_reports`: returned values (reports, outputs, σ) that are NaN or ±∞;
//! - `max_consecutive_refusals`: the longest run of refused valid calls in any case (a gate
//!   rejecting a measurement is not a refusal; an `Err` on valid input is).
//!
//! A valid call is one whose input lies in the estimator's documented envelope; the campaigns
//! feed only such calls (hostile-but-legal), so any `Err` counts as a refusal.

pub mod navigator;
pub mod seeker_ins;
pub mod transfer_alignment;
pub mod vertical_channel;

use serde::Serialize;

/// A case whose last this-many valid calls were all refused has stalled for good.
pub const STALL_TAIL_CALLS: u64 = 100;
/// A run of refusals of valid calls longer than this is a stall even if the filter came back.
pub const STALL_RUN_CALLS: u64 = 10_000;

/// How long to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StressLevel {
    /// What CI runs: every envelope point, short runs (a few minutes in all).
    Short,
    /// The full campaign: 10⁶-10⁷ steps per long run.
    Full,
}

/// One case's worst finding, kept for the report.
#[derive(Debug, Clone, Serialize)]
pub struct CaseFinding {
    /// What the case was (configuration, rate, fault).
    pub case: String,
    /// What went wrong (or the longest refusal run).
    pub finding: String,
}

/// The campaign's result for one estimator (the report's per-estimator object).
#[derive(Debug, Clone, Default, Serialize)]
pub struct EstimatorStress {
    /// Configurations run.
    pub cases: u64,
    /// Calls made.
    pub steps: u64,
    /// Cases that stalled (see the module docs).
    pub permanent_stalls: u64,
    /// Committed covariances that were not PSD.
    pub non_psd_commits: u64,
    /// Returned values that were not finite.
    pub non_finite_reports: u64,
    /// Longest run of refused valid calls in any case.
    pub max_consecutive_refusals: u64,
    /// Calls refused in all (valid input refused, e.g. a numerically impossible update that
    /// was skipped by returning an error).
    pub refusals: u64,
    /// PSD checks made.
    pub psd_checks: u64,
    /// Hostile inputs (NaN, ∞, out of range) made; only the navigator's part makes them.
    pub hostile_inputs: u64,
    /// Hostile inputs that were accepted or changed the estimator although refused.
    pub hostile_not_refused: u64,
    /// Up to 20 findings (stalls, non-PSD, non-finite), first come.
    pub findings: Vec<CaseFinding>,
    /// What the campaign covered, in words.
    pub coverage: Vec<String>,
}

impl EstimatorStress {
    /// Adds a finished case.
    pub fn add(&mut self, t: Tally) {
        self.cases += 1;
        self.steps += t.steps;
        self.refusals += t.refusals;
        self.psd_checks += t.psd_checks;
        self.non_psd_commits += t.non_psd;
        self.non_finite_reports += t.non_finite;
        self.max_consecutive_refusals = self.max_consecutive_refusals.max(t.max_run);
        let stalled = t.run >= STALL_TAIL_CALLS || t.max_run > STALL_RUN_CALLS;
        if stalled {
            self.permanent_stalls += 1;
        }
        let mut note = |finding: String| {
            if self.findings.len() < 20 {
                self.findings.push(CaseFinding {
                    case: t.case.clone(),
                    finding,
                });
            }
        };
        if stalled {
            note(format!(
                "stalled: {} refusals at the end, longest run {} (first refusal: {})",
                t.run, t.max_run, t.first_refusal
            ));
        }
        if t.non_psd > 0 {
            note(format!(
                "{} non-PSD commits (first: {})",
                t.non_psd, t.first_non_psd
            ));
        }
        if t.non_finite > 0 {
            note(format!(
                "{} non-finite values (first: {})",
                t.non_finite, t.first_non_finite
            ));
        }
    }

    /// Merges another part of the same estimator's campaign.
    pub fn merge(&mut self, other: EstimatorStress) {
        self.cases += other.cases;
        self.steps += other.steps;
        self.permanent_stalls += other.permanent_stalls;
        self.non_psd_commits += other.non_psd_commits;
        self.non_finite_reports += other.non_finite_reports;
        self.max_consecutive_refusals = self
            .max_consecutive_refusals
            .max(other.max_consecutive_refusals);
        self.refusals += other.refusals;
        self.psd_checks += other.psd_checks;
        self.hostile_inputs += other.hostile_inputs;
        self.hostile_not_refused += other.hostile_not_refused;
        for f in other.findings {
            if self.findings.len() < 20 {
                self.findings.push(f);
            }
        }
        self.coverage.extend(other.coverage);
    }

    /// `true` when the campaign ran and all failure counts are 0.
    pub fn clean(&self) -> bool {
        self.cases > 0
            && self.hostile_not_refused == 0
            && self.permanent_stalls == 0
            && self.non_psd_commits == 0
            && self.non_finite_reports == 0
    }
}

/// Counts one case's calls.
#[derive(Debug, Clone, Default)]
pub struct Tally {
    /// The case's description.
    pub case: String,
    steps: u64,
    refusals: u64,
    run: u64,
    max_run: u64,
    psd_checks: u64,
    non_psd: u64,
    non_finite: u64,
    first_refusal: String,
    first_non_psd: String,
    first_non_finite: String,
}

impl Tally {
    /// A new case.
    pub fn new(case: impl Into<String>) -> Self {
        Self {
            case: case.into(),
            ..Self::default()
        }
    }

    /// One call of valid input: `Ok` accepted, `Err` refused (the error is kept for the first
    /// refusal's finding).
    pub fn call<T, E: std::fmt::Debug>(&mut self, at: &str, r: &Result<T, E>) -> bool {
        self.steps += 1;
        match r {
            Ok(_) => {
                self.run = 0;
                true
            }
            Err(e) => {
                self.refusals += 1;
                self.run += 1;
                self.max_run = self.max_run.max(self.run);
                if self.first_refusal.is_empty() {
                    self.first_refusal = format!("{at}: {e:?}");
                }
                false
            }
        }
    }

    /// Values returned by an accepted call (reports, outputs, σ): each non-finite one counts.
    pub fn finite(&mut self, at: &str, values: impl IntoIterator<Item = f64>) {
        let bad = values.into_iter().filter(|v| !v.is_finite()).count() as u64;
        if bad > 0 {
            if self.first_non_finite.is_empty() {
                self.first_non_finite = at.to_string();
            }
            self.non_finite += bad;
        }
    }

    /// A committed covariance (row-major n×n, widened to f64), checked for symmetry and
    /// positive semi-definiteness with the tolerance of the float type it was computed in
    /// (`eps`: `f32::EPSILON` or `f64::EPSILON`).
    pub fn covariance(&mut self, at: &str, p: &[f64], n: usize, eps: f64) {
        self.psd_checks += 1;
        if let Some(defect) = psd_defect(p, n, eps) {
            if self.first_non_psd.is_empty() {
                self.first_non_psd = format!("{at}: {defect}");
            }
            self.non_psd += 1;
        }
    }
}

/// Why a covariance is not PSD, or `None`. Checks: every entry finite, the diagonal
/// non-negative, exact symmetry up to `64 eps` relative, and the smallest eigenvalue of the
/// correlation matrix D^-½ P D^-½ (zero-variance states dropped) at least `−n · 64 eps`.
pub fn psd_defect(p: &[f64], n: usize, eps: f64) -> Option<String> {
    if p.len() != n * n {
        return Some(format!("{} values for {n}×{n}", p.len()));
    }
    if let Some(i) = p.iter().position(|v| !v.is_finite()) {
        return Some(format!("P[{},{}] = {}", i / n, i % n, p[i]));
    }
    for i in 0..n {
        if p[i * n + i] < 0.0 {
            return Some(format!("P[{i},{i}] = {:e} < 0", p[i * n + i]));
        }
    }
    let tol = 64.0 * eps;
    for i in 0..n {
        for j in 0..i {
            let a = p[i * n + j];
            let b = p[j * n + i];
            let scale = (p[i * n + i] * p[j * n + j]).sqrt();
            if (a - b).abs() > tol * scale.max(f64::MIN_POSITIVE) {
                return Some(format!("asymmetric at [{i},{j}]: {a:e} vs {b:e}"));
            }
        }
    }
    let min_eig = min_correlation_eigenvalue(p, n);
    if min_eig < -(n as f64) * tol {
        return Some(format!("correlation eigenvalue {min_eig:e}"));
    }
    None
}

/// Smallest eigenvalue of the correlation matrix `D^-½ P D^-½` of the row-major `n × n` matrix
/// `p` (symmetrised; states with a zero variance dropped; 1 when none is left, the identity's).
pub fn min_correlation_eigenvalue(p: &[f64], n: usize) -> f64 {
    let keep: Vec<usize> = (0..n).filter(|&i| p[i * n + i] > 0.0).collect();
    let m = keep.len();
    if m == 0 {
        return 1.0;
    }
    let corr = nalgebra::DMatrix::from_fn(m, m, |a, b| {
        let (i, j) = (keep[a], keep[b]);
        let s = 0.5 * (p[i * n + j] + p[j * n + i]);
        s / (p[i * n + i].sqrt() * p[j * n + j].sqrt())
    });
    corr.symmetric_eigen()
        .eigenvalues
        .iter()
        .copied()
        .fold(f64::INFINITY, f64::min)
}

/// The whole report (`target/stress/report.json`).
#[derive(Debug, Clone, Serialize)]
pub struct StressReport {
    /// `short` or `full`.
    pub level: &'static str,
    /// Seconds the campaign took.
    pub elapsed_s: f64,
    /// Per estimator.
    pub transfer_alignment: EstimatorStress,
    /// Per estimator.
    pub seeker_ins: EstimatorStress,
    /// Per estimator.
    pub vertical_channel: EstimatorStress,
    /// The flight navigator (the three estimators as one chain).
    pub navigator: EstimatorStress,
    /// `true` when every estimator's three failure counts are 0.
    pub clean: bool,
}

/// Runs one estimator's campaign (`Some(name)`) or all four; the others report 0 cases.
pub fn run_only(level: StressLevel, only: Option<&str>) -> anyhow::Result<StressReport> {
    let Some(name) = only else {
        return Ok(run(level));
    };
    let t0 = std::time::Instant::now();
    let mut report = StressReport {
        level: match level {
            StressLevel::Short => "short",
            StressLevel::Full => "full",
        },
        elapsed_s: 0.0,
        transfer_alignment: EstimatorStress::default(),
        seeker_ins: EstimatorStress::default(),
        vertical_channel: EstimatorStress::default(),
        navigator: EstimatorStress::default(),
        clean: false,
    };
    match name {
        "transfer_alignment" => report.transfer_alignment = transfer_alignment::run(level),
        "seeker_ins" => report.seeker_ins = seeker_ins::run(level),
        "vertical_channel" => report.vertical_channel = vertical_channel::run(level),
        "navigator" => report.navigator = navigator::run(level),
        other => anyhow::bail!(
            "unknown estimator `{other}` (transfer_alignment, seeker_ins, vertical_channel, navigator)"
        ),
    }
    report.elapsed_s = t0.elapsed().as_secs_f64();
    Ok(report)
}

/// Runs the four campaigns (in parallel).
pub fn run(level: StressLevel) -> StressReport {
    let t0 = std::time::Instant::now();
    let ((ta, seeker), (vc, nav)) = rayon::join(
        || rayon::join(|| transfer_alignment::run(level), || seeker_ins::run(level)),
        || rayon::join(|| vertical_channel::run(level), || navigator::run(level)),
    );
    let clean = ta.clean() && seeker.clean() && vc.clean() && nav.clean();
    StressReport {
        level: match level {
            StressLevel::Short => "short",
            StressLevel::Full => "full",
        },
        elapsed_s: t0.elapsed().as_secs_f64(),
        transfer_alignment: ta,
        seeker_ins: seeker,
        vertical_channel: vc,
        navigator: nav,
        clean,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn psd_check_finds_what_it_should() {
        let good = [4.0, 1.0, 1.0, 1.0];
        assert_eq!(psd_defect(&good, 2, f64::EPSILON), None);
        let indefinite = [1.0, 2.0, 2.0, 1.0];
        assert!(psd_defect(&indefinite, 2, f64::EPSILON).is_some());
        let asym = [1.0, 0.5, 0.4, 1.0];
        assert!(psd_defect(&asym, 2, f64::EPSILON).is_some());
        assert!(psd_defect(&[f64::NAN, 0.0, 0.0, 1.0], 2, f64::EPSILON).is_some());
        assert!(psd_defect(&[-1e-3, 0.0, 0.0, 1.0], 2, f64::EPSILON).is_some());
    }

    #[test]
    fn tally_counts_stalls() {
        let mut t = Tally::new("x");
        for i in 0..200 {
            let r: Result<(), ()> = if i < 50 { Ok(()) } else { Err(()) };
            t.call("step", &r);
        }
        let mut s = EstimatorStress::default();
        s.add(t);
        assert_eq!(s.permanent_stalls, 1);
        assert_eq!(s.max_consecutive_refusals, 150);
        assert!(!s.clean());
    }
}

//! What an estimator's part of the consistency campaign is (module
//! [`crate::scenarios::consistency_campaign`]): the [`CampaignPlan`] it is asked to fly, the
//! [`VariantResult`]s it returns, its [`Campaign`] entry, and the targets every estimator is
//! judged against. The estimators' scenario modules and the campaign both use it; it uses
//! neither.

use crate::consistency::Consistency;
use anyhow::Result;
use serde_json::Value;

/// Minimum fraction of settled epochs with the run-averaged NEES in its 95 % band.
pub const MIN_FRAC_IN_BAND: f64 = 0.9;
/// Lower limit of every per-axis `normalized_error_sq` (σ at most √2 too large).
pub const NES_MIN: f64 = 0.5;
/// Upper limit of every per-axis `normalized_error_sq` (σ at most √2 too small).
pub const NES_MAX: f64 = 2.0;
/// Largest accepted ratio of the flight configuration's RMS error to the paper filter's, per
/// axis (accuracy may not get worse by more than 10 %).
pub const MAX_ACCURACY_LOSS: f64 = 1.1;

/// What a campaign is asked to fly.
#[derive(Debug, Clone, Copy)]
pub struct CampaignPlan {
    /// Randomized variants to draw.
    pub variants: usize,
    /// Monte Carlo runs per variant.
    pub runs: usize,
    /// Campaign seed: variant `v` draws its parameters from stream `v`, its runs from their own
    /// streams derived from it.
    pub seed: u64,
    /// Draw progress bars.
    pub progress: bool,
}

/// One variant flown by one filter.
#[derive(Debug, Clone)]
pub struct VariantResult {
    /// Variant index (0-based) within the estimator's campaign.
    pub variant: usize,
    /// Filter flown: `"flight"` (judged) or `"paper"` (the paper's filter, for comparison).
    pub filter: String,
    /// The drawn parameters, with units in the key names (e.g. `"lever_arm_m"`).
    pub params: Value,
    /// The consistency over the variant's runs.
    pub consistency: Consistency,
    /// RMS error per axis over the runs and settled epochs, in the axis's unit
    /// (`(axis name with unit, rms)`), same axes for both filters.
    pub rms: Vec<(String, f64)>,
}

/// An estimator's contribution to the campaign.
#[derive(Debug, Clone, Copy)]
pub struct Campaign {
    /// Estimator name as it appears in the outputs.
    pub estimator: &'static str,
    /// What is randomized, one line.
    pub about: &'static str,
    /// Flies the variants.
    pub run: fn(&CampaignPlan) -> Result<Vec<VariantResult>>,
}

/// Two flights of a campaign gave the same variants and the same numbers (the campaigns'
/// reproducibility tests).
#[cfg(test)]
pub(crate) fn assert_same_results(a: &[VariantResult], b: &[VariantResult]) {
    assert_eq!(a.len(), b.len());
    for (x, y) in a.iter().zip(b) {
        assert_eq!(x.params, y.params);
        assert_eq!(x.consistency.nees_mean, y.consistency.nees_mean);
        assert_eq!(x.rms, y.rms);
    }
}

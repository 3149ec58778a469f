//! Stress campaign of the seeker ins estimator (placeholder until its campaign is written:
//! reports no cases, so `cargo xtask stress` shows it as not covered).

use super::{EstimatorStress, StressLevel};

/// Runs the campaign at `level`.
pub fn run(_level: StressLevel) -> EstimatorStress {
    EstimatorStress {
        coverage: vec!["not yet covered".into()],
        ..EstimatorStress::default()
    }
}

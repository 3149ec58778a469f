//! The EKF's PSD-margin check, deferred to a tick with room for it.
//!
//! The stand-alone seeker INS checks P's PSD margin after each covariance step on an IMU
//! sample (an LDLᵀ of P in place, `SeekerIns::check_psd_margin`: ≈ 9 000 instructions on the
//! M4F) and lifts the variances only when a relative pivot falls below 16 ε. The navigator's
//! ticks that run a covariance step (≈ 13 000 instructions, with an update up to ≈ 20 000)
//! cannot carry it, but most of its ticks run neither a covariance step nor an update
//! (≈ 3 000). P changes only in covariance steps and updates, so the check runs on the first
//! tick after such a change that changes P no more: it checks the P the next covariance step
//! starts from. A covariance step from a checked P adds nothing (`PsdMargin::Deferred`): its
//! rounding moves the relative pivots by a few ε, within the 16 ε margin the check left, so
//! an update on the same tick reads a positive definite P. A covariance step from a P not
//! checked since its last change (no quiet tick in between: an update or step on the
//! previous tick) keeps the constant 4 ε of every variance (`PsdMargin::Constant`).
//!
//! An update reads the P of a covariance step that was not checked on its own: checking
//! before the update would put the check on the busiest ticks (a LOS and a baro update on
//! the same tick: ≈ 19 800 instructions), and the update's own stabilising noise and result
//! checks are those of the stand-alone filter's updates, which read a P checked one
//! covariance step before as well. The check after the update covers the update's result.

use super::Navigator;
use crate::contract::Estimator;
use crate::seeker_ins::PsdMargin;
use crate::Real;

/// Where the EKF's P stands with respect to its PSD-margin check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PsdCheck {
    /// Checked (and lifted if its margin was small) since its last change.
    Checked,
    /// Changed by a covariance step or an update on this tick.
    ChangedNow,
    /// Changed on an earlier tick and not checked since: the check is due.
    Due,
}

impl PsdCheck {
    /// How a covariance step keeps P's PSD margin from this state: nothing added when P
    /// was checked since its last change, else the constant noise.
    pub(super) fn margin(self) -> PsdMargin {
        match self {
            Self::Checked => PsdMargin::Deferred,
            Self::ChangedNow | Self::Due => PsdMargin::Constant,
        }
    }

    /// The state after the tick's IMU part, `stepped` when it ran a covariance step: a change
    /// of an earlier tick becomes due.
    pub(super) fn after_imu(self, stepped: bool) -> Self {
        match (stepped, self) {
            (true, _) => Self::ChangedNow,
            (false, Self::ChangedNow) => Self::Due,
            (false, other) => other,
        }
    }
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// At the end of a flight tick: the check when it is due (P changed on an earlier tick,
    /// not on this one), the baro column forgotten when a variance was limited (a congruence
    /// the column does not follow; a lift alone keeps the joint covariance PSD: it adds a
    /// positive diagonal to P's block). Not inlined: its frame is not on the tick's path
    /// under the kernels.
    #[inline(never)]
    pub(super) fn check_psd_when_due(&mut self) {
        if self.psd != PsdCheck::Due {
            return;
        }
        if let Some(ekf) = self.ekf.as_mut() {
            let limits = ekf.health().limits_hit;
            ekf.check_psd_margin();
            if ekf.health().limits_hit != limits {
                self.baro_state.cross = nalgebra::SVector::zeros();
            }
        }
        self.psd = PsdCheck::Checked;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_step_adds_nothing_only_from_a_checked_p() {
        assert_eq!(PsdCheck::Checked.margin(), PsdMargin::Deferred);
        assert_eq!(PsdCheck::ChangedNow.margin(), PsdMargin::Constant);
        assert_eq!(PsdCheck::Due.margin(), PsdMargin::Constant);
    }

    #[test]
    fn a_change_becomes_due_on_the_next_tick_without_a_step() {
        for s in [PsdCheck::Checked, PsdCheck::ChangedNow, PsdCheck::Due] {
            assert_eq!(s.after_imu(true), PsdCheck::ChangedNow);
        }
        assert_eq!(PsdCheck::ChangedNow.after_imu(false), PsdCheck::Due);
        assert_eq!(PsdCheck::Due.after_imu(false), PsdCheck::Due);
        assert_eq!(PsdCheck::Checked.after_imu(false), PsdCheck::Checked);
    }
}

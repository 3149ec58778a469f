//! The EKF's PSD-margin check, deferred to a tick with room for it.
//!
//! The stand-alone seeker INS checks P's PSD margin after each covariance step on an IMU
//! sample (an LDLᵀ of P in place, `SeekerIns::check_psd_margin`: ≈ 9 000 instructions on the
//! M4F) and lifts the variances only when a relative pivot falls below 16 ε. The navigator's
//! ticks that run a covariance step (≈ 13 000 instructions, with an update up to ≈ 20 000)
//! cannot carry it, but most of its ticks run neither a covariance step nor an update
//! (≈ 3 000). P changes only in covariance steps and updates, so the check runs on the first
//! tick after such a change that changes P no more (at its end): it checks the P the next
//! covariance step starts from. A covariance step from a checked P adds nothing
//! (`PsdMargin::Deferred`): its rounding moves the relative pivots by a few ε, within the
//! 16 ε margin the check left, so an update on the same tick reads a positive definite P. A
//! covariance step from a P not checked since its last change (no quiet tick in between: an
//! update or step on the previous tick) is followed by the constant 4 ε of every variance,
//! before any update reads P.
//!
//! An update reads the P of a covariance step that was not checked on its own: checking
//! before the update would put the check on the busiest ticks (a LOS update with its
//! covariance step: ≈ 14 500 instructions; one heavy update per tick, module `baro_hold`),
//! and the update's own stabilising noise and result
//! checks are those of the stand-alone filter's updates, which read a P checked one
//! covariance step before as well. The check after the update covers the update's result.
//!
//! In the missions (`nav-sim`: `mission`, `mission-s-turn`) the check never lifted (smallest
//! relative pivot 1.7e-2) and no step started from an unchecked P. With almost no process
//! noise (a seeker precise to 1e-5 rad, a hundredth of the IMUs' noise, no instrument errors)
//! baro and LOS updates used to turn P indefinite (10 times in 20 missions, docs/stress.md) until the
//! baro update's stabilising noise got its floor of one ε (module `baro`): never since.

use super::Navigator;
use crate::contract::Estimator;
use crate::Real;

/// Where the EKF's P stands with respect to its PSD-margin check.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum PsdCheck {
    /// Checked (and lifted if its margin was small) since its last change.
    Checked,
    /// Changed by a covariance step or an update on this tick.
    ChangedNow,
    /// Changed on this tick by the IMU part's covariance step from a P not checked since
    /// its last change: the constant noise is added before an update reads P, at the latest
    /// at the end of the tick.
    SteppedUnchecked,
    /// Changed on an earlier tick and not checked since: the check is due.
    Due,
}

impl PsdCheck {
    /// The state after the tick's IMU part, `stepped` when it ran a covariance step.
    #[inline(always)]
    pub(super) fn after_imu(self, stepped: bool) -> Self {
        match (stepped, self) {
            (false, s) => s,
            (true, Self::Checked) => Self::ChangedNow,
            (true, _) => Self::SteppedUnchecked,
        }
    }
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// Before an update, after the flush of its pending covariance step (run without noise,
    /// `PsdMargin::Deferred`): the constant noise when a covariance step of this tick started
    /// from a P not checked since its last change (the IMU part's, or the flush's: P changed on
    /// the tick before, no quiet tick in between); then P changed now. A flush runs a step
    /// when nothing of this tick changed P before it and no sample is pending after it (every
    /// tick adds one).
    #[inline(never)]
    pub(super) fn psd_after_flush(&mut self) {
        let flushed = self.ekf.as_ref().is_some_and(|e| e.steps_pending() == 0);
        match self.psd {
            PsdCheck::SteppedUnchecked => self.add_fallback_noise(),
            PsdCheck::Due if flushed => self.add_fallback_noise(),
            PsdCheck::Checked | PsdCheck::ChangedNow | PsdCheck::Due => {}
        }
        self.psd = PsdCheck::ChangedNow;
    }

    /// At the end of a flight tick: the check when it is due (P changed on an earlier tick,
    /// not on this one), the baro column forgotten when a variance was limited (a congruence
    /// the column does not follow; a lift alone keeps the joint covariance PSD: it adds a
    /// positive diagonal to P's block); a change of this tick becomes due. Not inlined: its
    /// frame is not on the tick's path under the kernels.
    #[inline(never)]
    pub(super) fn psd_end_of_tick(&mut self) {
        match self.psd {
            PsdCheck::Checked => {}
            PsdCheck::ChangedNow => self.psd = PsdCheck::Due,
            PsdCheck::SteppedUnchecked => {
                self.add_fallback_noise();
                self.psd = PsdCheck::Due;
            }
            PsdCheck::Due => {
                if let Some(ekf) = self.ekf.as_mut() {
                    let limits = ekf.health().limits_hit;
                    ekf.check_psd_margin();
                    if ekf.health().limits_hit != limits {
                        self.baro_state.cross = nalgebra::SVector::zeros();
                        ekf.consider_external_forget();
                    }
                }
                self.psd = PsdCheck::Checked;
            }
        }
    }

    /// The constant noise after a covariance step from an unchecked P
    /// (`SeekerIns::add_stabilising_noise`), the baro column forgotten if a variance was
    /// limited.
    fn add_fallback_noise(&mut self) {
        if let Some(ekf) = self.ekf.as_mut() {
            let limits = ekf.health().limits_hit;
            ekf.add_stabilising_noise();
            if ekf.health().limits_hit != limits {
                self.baro_state.cross = nalgebra::SVector::zeros();
                ekf.consider_external_forget();
            }
        }
    }
}

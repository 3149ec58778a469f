//! Health and counters of the transfer-alignment filters: the measurement [`Channel`]s, their
//! [`AidCounters`], the estimator's [`Health`] and the rules behind its [`HealthState`].
use crate::contract::{AidCounters, FusionOutcome, FusionReport, Health};
use crate::health::HealthState;

/// Epochs without an anomaly (skipped update, flexure re-initialised after a long gap,
/// covariance reset by the recovery policy, `reinitialise`) after which
/// [`HealthState::Degraded`] returns to [`HealthState::Nominal`].
pub const DEGRADED_HOLD_EPOCHS: u32 = 100;
/// Consecutive epochs with every update skipped after which the filter reports
/// [`HealthState::NeedsReinitialisation`].
pub const SKIPPED_EPOCHS_FOR_REINIT: u32 = 100;

/// The six scalar measurements of an epoch, the filter's aids (read their counters with
/// [`super::TransferAlignment::aid_counters`]), in the order of
/// [`super::StepReport::updates`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Channel {
    /// Angular-rate difference dω_X, rad/s.
    RateX,
    /// Angular-rate difference dω_Y, rad/s.
    RateY,
    /// Angular-rate difference dω_Z, rad/s.
    RateZ,
    /// Specific-force difference df_X, m/s².
    ForceX,
    /// Specific-force difference df_Y, m/s².
    ForceY,
    /// Specific-force difference df_Z, m/s².
    ForceZ,
}

impl Channel {
    /// Every channel, in update order.
    pub const ALL: [Channel; 6] = [
        Channel::RateX,
        Channel::RateY,
        Channel::RateZ,
        Channel::ForceX,
        Channel::ForceY,
        Channel::ForceZ,
    ];

    /// Position in [`super::StepReport::updates`] (0 to 5).
    pub const fn index(self) -> usize {
        self as usize
    }
}

/// The counters and the runs behind the health state (committed with the step).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct Monitor {
    pub health: Health,
    pub channels: [AidCounters; 6],
    /// Current run of epochs in which every update was skipped.
    pub all_skipped_run: u32,
    /// Epochs since the last anomaly (saturating).
    pub epochs_since_anomaly: u32,
}

impl Monitor {
    pub fn new() -> Self {
        Self {
            health: Health::default(),
            channels: [AidCounters::default(); 6],
            all_skipped_run: 0,
            epochs_since_anomaly: DEGRADED_HOLD_EPOCHS,
        }
    }

    /// Counts the outcomes of one epoch's updates. A skipped update ends the channel's run of
    /// rejections, as a fused one does. Returns `true` when a channel's run reached
    /// `starved_epochs` (the recovery is then due: [`Self::record_recovery`]) and whether the
    /// epoch had an anomaly (a skipped update).
    pub fn record_updates(
        &mut self,
        updates: &[FusionReport<impl Copy>; 6],
        starved_epochs: Option<u32>,
    ) -> EpochCount {
        let mut count = EpochCount {
            starved: false,
            skipped: false,
        };
        // The common epoch, every update fused: what the general count below does for it
        // (each channel's fused count up, its run of rejections ended; no run of all-skipped
        // epochs), without the per-outcome branches.
        if updates
            .iter()
            .fold(true, |all, rep| all & (rep.outcome == FusionOutcome::Fused))
        {
            for c in self.channels.iter_mut() {
                c.fused = c.fused.saturating_add(1);
                c.consecutive_rejected = 0;
            }
            self.all_skipped_run = 0;
            return count;
        }
        let mut all_skipped = true;
        for (rep, c) in updates.iter().zip(self.channels.iter_mut()) {
            let outcome = rep.outcome;
            count.starved |= record_channel(c, outcome, starved_epochs);
            count.skipped |= outcome == FusionOutcome::Skipped;
            all_skipped &= outcome == FusionOutcome::Skipped;
        }
        self.all_skipped_run = if all_skipped {
            self.all_skipped_run.saturating_add(1)
        } else {
            0
        };
        count
    }

    /// Counts a recovery on every channel whose run reached `starved_epochs` and ends every
    /// channel's run (the covariance was reset: the gate opens again for all).
    pub fn record_recovery(&mut self, starved_epochs: u32) {
        for c in self.channels.iter_mut() {
            if c.consecutive_rejected >= starved_epochs {
                c.record_recovery();
            }
            c.consecutive_rejected = 0;
        }
    }

    /// Ends the epoch: the anomaly hold, then the state (`diverged`: |θ| beyond
    /// [`super::MAX_MISALIGNMENT_RAD`]).
    pub fn end_epoch(&mut self, anomaly: bool, diverged: bool) {
        self.epochs_since_anomaly = if anomaly {
            0
        } else {
            self.epochs_since_anomaly.saturating_add(1)
        };
        self.health.state = self.classify(diverged);
    }

    /// Ends a prediction-only call: the state is re-classified once the filter has started.
    pub fn end_prediction(&mut self, anomaly: bool, diverged: bool) {
        if anomaly {
            self.epochs_since_anomaly = 0;
        }
        if self.health.state != HealthState::Initialising {
            self.health.state = self.classify(diverged);
        }
    }

    /// The state for these runs.
    fn classify(&self, diverged: bool) -> HealthState {
        if diverged || self.all_skipped_run >= SKIPPED_EPOCHS_FOR_REINIT {
            HealthState::NeedsReinitialisation
        } else if self.epochs_since_anomaly < DEGRADED_HOLD_EPOCHS {
            HealthState::Degraded
        } else {
            HealthState::Nominal
        }
    }
}

/// What [`Monitor::record_updates`] found.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) struct EpochCount {
    /// A channel's run of rejections reached the recovery policy's length.
    pub starved: bool,
    /// An update was skipped.
    pub skipped: bool,
}

/// Counts one channel's outcome; `true` when its run of rejections reached `starved_epochs`.
/// A skipped update ends the run, as a fused one does. Out of line: one body for the six
/// channels (the unrolled per-channel copies cost ≈ 1 KB of flash for a few instructions
/// saved per epoch).
#[inline(never)]
fn record_channel(
    c: &mut AidCounters,
    outcome: FusionOutcome,
    starved_epochs: Option<u32>,
) -> bool {
    c.record(outcome);
    match outcome {
        FusionOutcome::Rejected => starved_epochs.is_some_and(|n| c.consecutive_rejected >= n),
        FusionOutcome::Skipped => {
            c.consecutive_rejected = 0;
            false
        }
        FusionOutcome::Fused => false,
    }
}

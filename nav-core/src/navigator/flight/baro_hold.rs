//! One heavy EKF update per flight tick (module doc of [`super::super`], "One heavy update
//! per tick"): a baro sample that arrives on a tick whose LOS sample goes through the EKF is
//! checked and held in a one-sample slot, and fused at its own time stamp on the next tick
//! without a LOS update.
//!
//! * The held sample's age grows by the ticks it waits; the baro update already takes the
//!   age as lag (`tau = lag + age`, module `baro`). A held sample older than the baro model
//!   accepts ([`MAX_BARO_AGE_S`](crate::navigator::MAX_BARO_AGE_S), 1 s: only when LOS
//!   updates took every tick for that long) is dropped, counted `skipped`.
//! * A newer valid baro sample replaces the held one (counted `superseded`): the newest is
//!   the one fused or held, so a baro at the IMU rate never stalls.
//! * A refused sample (non-finite, out of its time window, not later than the held or last
//!   fused one) changes nothing: the held sample stays as it was, and is fused on this tick
//!   if no LOS update takes it, exactly as without the refused sample (the tick reports
//!   `Refused`, the counters say what became of the held one).
//! * The baro timeout counts accepted samples: a held sample is accepted on the tick it
//!   arrives.
//! * Phases: the terminal entry keeps the held sample (the same filter and baro model); only
//!   the EKF's baro damping in midcourse and terminal holds samples, and no phase leaves
//!   those two (a phase without baro damping in the EKF drops the slot). An IMU gap, a
//!   variance limit or a column reset keep it: its time stamp is its own, its age checked
//!   when it is fused.

use super::super::baro::baro_age_s;
use super::super::types::{AidAvailability, AidState};
use super::Navigator;
use crate::contract::FusionOutcome;
use crate::vertical_channel::BaroSample;
use crate::{NavError, Real};

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// The baro sample held for the next tick without a LOS update, if any (module doc of
    /// [`super::super`], "One heavy update per tick").
    pub fn held_baro(&self) -> Option<&BaroSample<T>> {
        self.held_baro.as_ref()
    }

    /// The baro's tick with the EKF's baro damping: this tick's `sample` is checked first (a
    /// refused one is counted and changes nothing); then the tick's candidate is the newest
    /// valid sample (the held one it replaces counted superseded) or the held one. When the
    /// seeker's LOS update took the tick (`los_ran`) the candidate is held (`Held`), else it
    /// is fused ([`Self::fuse_baro`]). A refusal is the tick's reported state.
    pub(super) fn baro_aid(&mut self, sample: Option<&BaroSample<T>>, los_ran: bool) -> AidState {
        let Some(model) = self.baro_model() else {
            // No baro in the EKF in this phase: nothing to hold.
            self.held_baro = None;
            return AidState::NotUsedInPhase;
        };
        self.expire_held();
        let mut refused = None;
        let mut fresh = None;
        if let Some(b) = sample {
            match self.check_baro(b) {
                Ok(()) => fresh = Some(*b),
                Err(e) => {
                    self.baro.counters.record_refused();
                    refused = Some(e);
                }
            }
        }
        let candidate = match (fresh, self.held_baro.take()) {
            (Some(b), Some(_)) => {
                self.baro.counters.record_superseded();
                Some(b)
            }
            (Some(b), None) => Some(b),
            (None, held) => held,
        };
        let mut state = AidState::Waiting;
        if let Some(b) = candidate {
            state = if los_ran {
                self.held_baro = Some(b);
                AidState::Held
            } else {
                self.fuse_baro(&model, &b).unwrap_or_else(|e| {
                    self.baro.counters.record_refused();
                    AidState::Refused(e)
                })
            };
            if fresh.is_some() && !matches!(state, AidState::Refused(_)) {
                // Accepted now (fused, rejected, skipped or held): the timeout's clock.
                self.baro.last_ok = Some(self.time);
            }
        }
        if let Some(e) = refused {
            return AidState::Refused(e);
        }
        if state == AidState::Waiting && self.baro_availability() == AidAvailability::TimedOut {
            state = AidState::TimedOut;
        }
        state
    }

    /// A baro sample's checks before it is held or fused: finite, within its time window
    /// (`baro_age_s`), later than the held sample or the last fused one.
    fn check_baro(&self, b: &BaroSample<T>) -> Result<(), NavError> {
        baro_age_s::<T>(b, self.time)?;
        // A held sample is later than the last fused one.
        let last = self.held_baro.map(|h| h.time).or(self.last_baro_time);
        if last.is_some_and(|t| b.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        Ok(())
    }

    /// The held sample dropped (counted skipped) when it has grown older than the baro model
    /// accepts ([`MAX_BARO_AGE_S`](crate::navigator::MAX_BARO_AGE_S), 1 s).
    fn expire_held(&mut self) {
        if let Some(h) = &self.held_baro {
            if baro_age_s::<T>(h, self.time).is_err() {
                self.held_baro = None;
                self.baro.counters.record(FusionOutcome::Skipped);
            }
        }
    }
}

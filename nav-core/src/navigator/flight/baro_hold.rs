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
use crate::time::Timestamp;
use crate::vertical_channel::BaroSample;
use crate::{NavError, Real};

/// A baro sample that passed [`Navigator::check_baro`] at this tick's time, with its age then
/// (the update's lag, module `baro`). Only the check builds one: the fusion
/// ([`Navigator::fuse_baro`]) takes it and checks nothing again.
#[derive(Clone, Copy)]
pub(super) struct CheckedBaro<T> {
    // The sample's fields beside its age: 16 B without padding (f32).
    time: Timestamp,
    altitude_m: T,
    age_s: T,
}

impl<T: Real> CheckedBaro<T> {
    /// The sample.
    pub(super) fn sample(&self) -> BaroSample<T> {
        BaroSample {
            time: self.time,
            altitude_m: self.altitude_m,
        }
    }

    /// Its age at the tick it was checked on, s.
    pub(super) fn age_s(&self) -> T {
        self.age_s
    }
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// The baro sample held for the next tick without a LOS update, if any (module doc of
    /// [`super::super`], "One heavy update per tick").
    pub fn held_baro(&self) -> Option<&BaroSample<T>> {
        self.held_baro.as_ref()
    }

    /// The baro's tick with the EKF's baro damping: the held sample is checked again at this
    /// tick's time (one grown older than the baro model accepts is dropped, counted skipped),
    /// then this tick's `sample` (a refused one is counted and changes nothing); the tick's
    /// candidate is the newest valid sample (the held one it replaces counted superseded) or
    /// the held one. When the seeker's LOS update took the tick (`los_ran`) the candidate is
    /// held (`Held`), else it is fused ([`Self::fuse_baro`]). A refusal is the tick's reported
    /// state.
    pub(super) fn baro_aid(&mut self, sample: Option<&BaroSample<T>>, los_ran: bool) -> AidState {
        let Some(model) = self.baro_model() else {
            // No baro in the EKF in this phase: nothing to hold.
            self.held_baro = None;
            return AidState::NotUsedInPhase;
        };
        let mut candidate = match self.held_baro.take() {
            Some(h) => match self.check_baro(&h, self.last_baro_time) {
                Ok(c) => Some(c),
                Err(_) => {
                    self.baro.counters.record(FusionOutcome::Skipped);
                    None
                }
            },
            None => None,
        };
        let mut refused = None;
        let mut fresh = false;
        if let Some(b) = sample {
            // A held sample is later than the last fused one.
            let after = candidate.map(|h| h.time).or(self.last_baro_time);
            match self.check_baro(b, after) {
                Ok(c) => {
                    if candidate.replace(c).is_some() {
                        self.baro.counters.record_superseded();
                    }
                    fresh = true;
                }
                Err(e) => {
                    self.baro.counters.record_refused();
                    refused = Some(e);
                }
            }
        }
        let mut state = AidState::Waiting;
        if let Some(b) = candidate {
            state = if los_ran {
                self.held_baro = Some(b.sample());
                AidState::Held
            } else {
                self.fuse_baro(&model, &b).unwrap_or_else(|e| {
                    self.baro.counters.record_refused();
                    AidState::Refused(e)
                })
            };
            if fresh && !matches!(state, AidState::Refused(_)) {
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

    /// The one check of a baro sample, before it is held or fused and again on each tick it
    /// is held: finite, within its time window at this tick's time (`baro_age_s`, which the
    /// held sample's growing age can leave), later than `after` (the held sample or the last
    /// fused one).
    fn check_baro(
        &self,
        b: &BaroSample<T>,
        after: Option<Timestamp>,
    ) -> Result<CheckedBaro<T>, NavError> {
        let age_s = baro_age_s::<T>(b, self.time)?;
        if after.is_some_and(|t| b.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        Ok(CheckedBaro {
            time: b.time,
            altitude_m: b.altitude_m,
            age_s,
        })
    }
}

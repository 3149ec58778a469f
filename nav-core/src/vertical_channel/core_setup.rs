//! The cold half of [`LoopCore`]: construction from a design's values, re-initialisation,
//! run-time configuration changes and counter queries (none of them on the step path).

use super::super::age_limits::AgeLimits;
use super::super::config::{AidModel, RunTime};
use super::super::gate::{AidTally, GateParams, ReacquisitionCounters};
use super::super::modes::Feedback;
use super::super::samples::{check_initial, Aid, AidChannel, InitialState};
use super::super::sigma::SigmaTrack;
use super::{CoreParts, LoopCore, StepValues};
use crate::contract::{AidCounters, Gate, Health, RecoveryPolicy};
use crate::error::ConfigIssue;
use crate::time::micros_to_seconds;
use crate::{HealthState, NavError, Real};
use nalgebra::Vector3;

impl<T: Real> LoopCore<T> {
    /// The loop at `init` with a design's values (copies only: no f64 arithmetic).
    // Runs once per flight, or after a failure: cold and out of line, so that the caller's
    // hot path does not carry an inlined copy.
    #[cold]
    #[inline(never)]
    pub(crate) fn new(init: &InitialState<T>, parts: CoreParts<'_, T>) -> Result<Self, NavError> {
        check_initial(init)?;
        let StepValues {
            dt_s,
            half_dt_s,
            baro_lag_s,
        } = parts.step;
        let dt_us = match crate::time::seconds_to_micros(dt_s) {
            Some(us) if us > 0 => us,
            _ => {
                return Err(NavError::InvalidConfig {
                    field: "design.imu_dt_s",
                    issue: ConfigIssue::OutOfRange,
                })
            }
        };
        if !crate::math::checks::all_finite(parts.k.as_slice()) {
            return Err(NavError::InvalidConfig {
                field: "design",
                issue: ConfigIssue::NotFinite,
            });
        }
        let bias_sign = T::lit(parts.bias_sign);
        Ok(Self {
            h_ref_m: init.altitude_m,
            x: Vector3::new(T::zero(), init.vz_up_m_s, -init.accel_bias_m_s2 * bias_sign),
            time: init.time,
            dt_s,
            dt_us,
            single_step_max_us: dt_us.saturating_add(dt_us / 2),
            nominal_us: match u32::try_from(dt_us) {
                Ok(us) if micros_to_seconds::<T>(dt_us) == dt_s => us,
                _ => 0,
            },
            half_dt_s,
            modes: *parts.modes,
            feedback: Feedback {
                k: parts.k,
                lag_s: baro_lag_s,
                bias_sign,
            },
            gravity: *parts.gravity,
            baro: AidChannel::new(),
            velocity: AidChannel::new(),
            baro_timeouts: parts.baro_timeouts,
            velocity_timeouts: parts.velocity_timeouts,
            baro_limits: AgeLimits::new(&parts.baro_timeouts, &parts.gate.baro),
            velocity_limits: AgeLimits::new(&parts.velocity_timeouts, &parts.gate.velocity),
            run_time: parts.run_time,
            gate: parts.gate,
            baro_tally: AidTally::default(),
            velocity_tally: AidTally::default(),
            health: Health::default(),
            sigma: SigmaTrack::new(*parts.sigma),
        })
    }

    /// Restarts the state and clock from `init`, keeping the design, the gate and the
    /// counters (held aid samples are dropped; health `Initialising`). On error nothing
    /// changes.
    // Runs once per flight, or after a failure: cold and out of line, so that the caller's
    // hot path does not carry an inlined copy.
    #[cold]
    #[inline(never)]
    pub(crate) fn reinitialise(&mut self, init: &InitialState<T>) -> Result<(), NavError> {
        check_initial(init)?;
        self.h_ref_m = init.altitude_m;
        self.x = Vector3::new(
            T::zero(),
            init.vz_up_m_s,
            -init.accel_bias_m_s2 * self.feedback.bias_sign,
        );
        self.time = init.time;
        self.baro = AidChannel::new();
        self.velocity = AidChannel::new();
        self.health.state = HealthState::Initialising;
        self.sigma.restart();
        Health::bump(&mut self.health.reinitialisations);
        Ok(())
    }

    /// Installs a new run-time configuration (validated and compiled; refused: nothing
    /// changes).
    fn set_run_time(&mut self, rt: RunTime<T>) -> Result<(), NavError> {
        self.gate = GateParams::compile(&rt)?;
        self.baro_limits = AgeLimits::new(&self.baro_timeouts, &self.gate.baro);
        self.velocity_limits = AgeLimits::new(&self.velocity_timeouts, &self.gate.velocity);
        self.run_time = rt;
        Ok(())
    }

    pub(crate) fn set_gate(&mut self, gate: Gate<T>) -> Result<(), NavError> {
        self.set_run_time(RunTime {
            gate,
            ..self.run_time
        })
    }

    pub(crate) fn set_recovery(&mut self, recovery: RecoveryPolicy<T>) -> Result<(), NavError> {
        self.set_run_time(RunTime {
            recovery,
            ..self.run_time
        })
    }

    pub(crate) fn set_aid_model(&mut self, aid_model: AidModel<T>) -> Result<(), NavError> {
        self.set_run_time(RunTime {
            aid_model,
            ..self.run_time
        })
    }

    fn tally(&self, aid: Aid) -> &AidTally {
        match aid {
            Aid::Baro => &self.baro_tally,
            Aid::Velocity => &self.velocity_tally,
        }
    }

    pub(crate) fn aid_counters(&self, aid: Aid) -> AidCounters {
        self.tally(aid).counters
    }

    pub(crate) fn reacquisition_counters(&self, aid: Aid) -> ReacquisitionCounters {
        self.tally(aid).reacquisition
    }

    /// The loop with its refused-input counters cleared (tests compare everything else).
    #[cfg(test)]
    pub(crate) fn without_refusals(&self) -> Self {
        let mut c = *self;
        c.health.imu_refused = 0;
        c.baro_tally.counters.refused = 0;
        c.velocity_tally.counters.refused = 0;
        c
    }
}

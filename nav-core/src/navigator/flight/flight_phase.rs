//! The flight phases' tick (module doc of [`super::super`]): released, midcourse and
//! terminal in place — the EKF's IMU part with the baro column, the baro and LOS updates each
//! beside its covariance step, the baro-inertial loop.

use super::super::baro::{baro_gain, BaroState};
use super::super::types::{
    AidAvailability, AidState, Aids, BaroDamping, ImuTick, Phase, TickReport, Transition,
    TransitionCause, INERTIAL_LOOP,
};
use super::baro_hold::CheckedBaro;
use super::{elapsed, LoopBaro, Navigator};
use crate::contract::{Estimator, FusionOutcome};
use crate::seeker_ins::{
    ClipFlags, CrossColumn, ImuIncrement, LosSample, PsdMargin, SeekerIns, STATES,
};
use crate::time::Timestamp;
use crate::vertical_channel::{BaroSample, ClassicalLoop, ImuSample as VerticalImu};
use crate::{NavError, Real};

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    pub(super) fn baro_model(&self) -> Option<super::super::types::BaroErrorModel<T>> {
        match self.config.baro {
            BaroDamping::Ekf(m) if matches!(self.phase, Phase::Midcourse | Phase::Terminal) => {
                Some(m)
            }
            _ => None,
        }
    }

    /// The flight phases' tick, in place: everything that can refuse the IMU sample is
    /// checked before the filter changes (the EKF's propagation is atomic without a copy of
    /// the filter, `SeekerIns::propagate_cross`), then each aid is validated before it
    /// touches anything. Inlined into [`Self::tick_into`] (one frame, one register save, on
    /// the path under which the kernels run); the carry phase has its own frame.
    #[inline(always)]
    pub(super) fn tick_flight(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
        out: &mut TickReport<T>,
    ) -> Result<(), NavError> {
        let inc = &imu.increment;
        let clip = (imu.clipped.accel || imu.clipped.gyro).then_some(imu.clipped);
        let loop_baro = if INERTIAL_LOOP && self.vloop.is_some() {
            Some(self.loop_imu(inc, clip, aids.baro)?)
        } else {
            self.ekf_imu(inc, clip)?;
            None
        };
        self.time = inc.time;
        self.after_imu(aids, transition, loop_baro, out)
    }

    /// The EKF's IMU part in place (atomic), the baro column in step with its covariance step;
    /// the step's PSD margin per module `psd_check`.
    #[inline(always)]
    fn ekf_imu(&mut self, inc: &ImuIncrement<T>, clip: Option<ClipFlags>) -> Result<(), NavError> {
        let model = self.baro_model();
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        if let Some(model) = model {
            let bs = &mut self.baro_state;
            let before = (ekf.health().limits_hit, ekf.health().gaps_reset);
            if let Some(dt) = ekf.propagate_cross(inc, clip, &mut bs.cross)? {
                ekf.consider_external_decay(bs.decay(&model, dt));
            }
            if (ekf.health().limits_hit, ekf.health().gaps_reset) != before {
                bs.cross = nalgebra::SVector::zeros();
                ekf.consider_external_forget();
            }
        } else {
            ekf.propagate_uncounted(inc, clip)?;
        }
        self.psd = self.psd.after_imu(ekf.steps_pending() == 0);
        Ok(())
    }

    /// The IMU part with the baro-inertial loop: the loop can refuse the IMU part after the
    /// EKF has integrated it, so the EKF and the loop step on copies committed together (more
    /// stack; the loop configuration only). Returns the baro sample's outcome in the loop.
    #[inline(never)]
    fn loop_imu(
        &mut self,
        inc: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        baro: Option<&BaroSample<T>>,
    ) -> Result<LoopBaro<T>, NavError> {
        let (Some(mut ekf), Some(mut lp)) = (self.ekf, self.vloop) else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        // On the copy: a refusal is dropped with it, as on the in-place path.
        ekf.propagate_uncounted(inc, clip)?;
        let outcome = Self::loop_step(&mut lp, &mut ekf, inc.time, baro)?;
        self.psd = self.psd.after_imu(ekf.steps_pending() == 0);
        self.ekf = Some(ekf);
        self.vloop = Some(lp);
        Ok(outcome)
    }

    /// After the committed IMU part: the phase by time, then the aids (inlined: no frame of
    /// its own under the aids' kernels).
    #[inline(always)]
    fn after_imu(
        &mut self,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
        loop_baro: Option<LoopBaro<T>>,
        out: &mut TickReport<T>,
    ) -> Result<(), NavError> {
        // Phase by time.
        if self.phase == Phase::Released
            && self
                .released_at
                .is_some_and(|t| elapsed::<T>(self.time, t) >= self.config.separation.coast_s)
        {
            self.phase = Phase::Midcourse;
            self.midcourse_at = Some(self.time);
            if let BaroDamping::Ekf(m) = &self.config.baro {
                self.baro_state = BaroState::start(m);
                if let Some(ekf) = self.ekf.as_mut() {
                    ekf.consider_external_forget();
                }
            }
            self.start_loop();
            transition.get_or_insert(Transition {
                from: Phase::Released,
                to: Phase::Midcourse,
                cause: TransitionCause::CoastElapsed,
                time: self.time,
            });
        }
        // The aid reports, written into the caller's report (nothing here fails). The seeker
        // first: a LOS sample it takes through the EKF is the tick's one heavy update, and the
        // tick's baro sample is then held for the next tick (module `baro_hold`).
        let (seeker, los_ran) = self.seeker_aid(aids.seeker, transition);
        let baro = match loop_baro {
            Some(outcome) => self.loop_baro_status(outcome),
            None => self.baro_aid(aids.baro, los_ran),
        };
        self.baro.write(baro, &mut out.baro);
        self.seeker.write(seeker, &mut out.seeker);
        self.master.write(AidState::NotUsedInPhase, &mut out.master);
        Ok(())
    }

    /// Midcourse start with [`BaroDamping::InertialLoop`]: the loop from the INS's vertical
    /// state. A loop the design refuses to start (an INS altitude outside its range) leaves the
    /// vertical channel free (the baro then reports `NotUsedInPhase`).
    #[cold]
    #[inline(never)]
    fn start_loop(&mut self) {
        if !INERTIAL_LOOP {
            return;
        }
        let (BaroDamping::InertialLoop(cfg), Some(design), Some(ekf)) =
            (&self.config.baro, &self.loop_design, &self.ekf)
        else {
            return;
        };
        self.vloop = super::super::baro::start_inertial_loop(cfg, design, ekf, self.time);
    }

    /// One step of the baro-inertial loop on the INS's vertical specific force, then ĥ, V̂_D
    /// into the INS and the loop's σ into the EKF's (δh, δV_D) block, cross-covariances zero
    /// (P stays PSD: the new P is block diagonal in {δh, δV_D} and the rest, each block PSD —
    /// the rest a principal submatrix of a PSD matrix, the vertical block the loop's
    /// covariance; keeping the old cross terms beside a new vertical block could make P
    /// indefinite). A baro sample the loop refuses is dropped (`Refused`) and the loop steps on
    /// the IMU alone. Returns the baro's outcome.
    fn loop_step(
        lp: &mut ClassicalLoop<T>,
        ekf: &mut SeekerIns<T>,
        time: Timestamp,
        baro: Option<&BaroSample<T>>,
    ) -> Result<LoopBaro<T>, NavError> {
        let imu = VerticalImu {
            time,
            specific_force_up_m_s2: super::super::baro::loop_vertical_input_m_s2(
                ekf.state(),
                &ekf.ins().specific_force_ned_m_s2(),
            ),
        };
        let mut next = *lp;
        let outcome = match next.step(&imu, baro) {
            Ok(r) => LoopBaro::Report(r.baro.sample),
            Err(e) if baro.is_some() => {
                next = *lp;
                next.step(&imu, None)?;
                LoopBaro::Refused(e)
            }
            Err(e) => return Err(e),
        };
        let s = ekf.state();
        let mut x = nalgebra::SVector::<T, STATES>::zeros();
        let (ih, iv) = (crate::seeker_ins::POS + 2, crate::seeker_ins::VEL + 2);
        if let Some(v) = x.get_mut(ih) {
            *v = T::lit(s.position.alt_m) - next.altitude_m();
        }
        if let Some(v) = x.get_mut(iv) {
            *v = s.vel_ned_m_s.z + next.vz_up_m_s();
        }
        let c = next.covariance_h_vz();
        // (δh, δV_D) with δV_D = −δV_z; P changed in place (no copy).
        ekf.set_vertical_block(&x, c.m11, c.m22, -c.m12)?;
        *lp = next;
        Ok(outcome)
    }

    fn loop_baro_status(&mut self, outcome: LoopBaro<T>) -> AidState {
        let state = match outcome {
            LoopBaro::Refused(e) => {
                self.baro.counters.record_refused();
                AidState::Refused(e)
            }
            LoopBaro::Report(None) => AidState::Waiting,
            LoopBaro::Report(Some(r)) => {
                self.baro.counters.record(r.outcome);
                self.baro.last = Some(r);
                self.baro.last_ok = Some(self.time);
                match r.outcome {
                    FusionOutcome::Fused => AidState::Fused,
                    FusionOutcome::Rejected => AidState::Rejected,
                    FusionOutcome::Skipped => AidState::Waiting,
                }
            }
        };
        if state == AidState::Waiting && self.baro_availability() == AidAvailability::TimedOut {
            AidState::TimedOut
        } else {
            state
        }
    }

    /// The baro's joint update (module `baro`), in place, of a sample checked at this tick's
    /// time ([`CheckedBaro`]: nothing is checked again): the pending covariance step
    /// ([`Self::flush_baro_column`]), then the update ([`Self::baro_update`]).
    #[inline(always)]
    pub(super) fn fuse_baro(
        &mut self,
        model: &super::super::types::BaroErrorModel<T>,
        b: &CheckedBaro<T>,
    ) -> Result<AidState, NavError> {
        self.flush_baro_column(model)?;
        Ok(self.baro_update(model, &b.sample(), b.age_s()))
    }

    /// The EKF's pending covariance step (atomic) with the baro column in step with it. Its
    /// kernel runs under this small frame, not under the update's.
    #[inline(never)]
    fn flush_baro_column(
        &mut self,
        model: &super::super::types::BaroErrorModel<T>,
    ) -> Result<(), NavError> {
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        let bs = &mut self.baro_state;
        if let Some(dt) = ekf.predict_covariance_cross(&mut bs.cross)? {
            ekf.consider_external_decay(bs.decay(model, dt));
        }
        self.psd_after_flush();
        Ok(())
    }

    /// The baro update after [`Self::fuse_baro`]'s covariance step: checked on the
    /// gain and on P's result before it is applied (`SeekerIns::update_rank_one`). A result
    /// that is not a covariance, or a correction the INS refuses, is not applied (`Skipped`):
    /// the covariance step stays, as for every outcome.
    #[inline(never)]
    fn baro_update(
        &mut self,
        model: &super::super::types::BaroErrorModel<T>,
        b: &BaroSample<T>,
        age: T,
    ) -> AidState {
        let bs = &mut self.baro_state;
        let outcome = match self.ekf.as_mut() {
            None => FusionOutcome::Skipped,
            Some(ekf) => {
                let tau = model.lag_s + age;
                let y = bs.predicted_m(ekf, tau) - b.altitude_m;
                let r = bs.measurement_variance_m2(model, ekf, tau, b, self.last_baro_time);
                let gate = self.config.ins.gate;
                match baro_gain(ekf.covariance(), bs, tau, y, r, gate) {
                    None => FusionOutcome::Skipped,
                    Some(Err(report)) => {
                        self.baro.last = Some(report);
                        report.outcome
                    }
                    Some(Ok(g)) => {
                        if ekf
                            .update_rank_one(&g.dx, &g.u, &g.k, g.delta)
                            .unwrap_or(false)
                        {
                            ekf.consider_after_baro(tau, &g.k, g.k_b);
                            bs.cross = g.cross;
                            bs.variance_m2 = g.variance_m2;
                            bs.bias_m -= g.db_m;
                            self.baro.last = Some(g.report);
                            g.report.outcome
                        } else {
                            FusionOutcome::Skipped
                        }
                    }
                }
            }
        };
        self.last_baro_time = Some(b.time);
        self.baro.counters.record(outcome);
        match outcome {
            FusionOutcome::Fused => AidState::Fused,
            FusionOutcome::Rejected => AidState::Rejected,
            FusionOutcome::Skipped => AidState::Waiting,
        }
    }

    /// The seeker's tick, and whether a LOS sample went through the EKF (checked, its
    /// covariance step and update run: the tick's heavy update).
    fn seeker_aid(
        &mut self,
        sample: Option<&LosSample<T>>,
        transition: &mut Option<Transition>,
    ) -> (AidState, bool) {
        if self.phase == Phase::Released {
            return (AidState::NotUsedInPhase, false);
        }
        let mut state = AidState::Waiting;
        let mut ran = false;
        if let Some(s) = sample {
            state = match self.fuse_los(s) {
                Ok(st) => {
                    ran = true;
                    st
                }
                Err(e) => {
                    self.seeker.counters.record_refused();
                    AidState::Refused(e)
                }
            };
        }
        if state == AidState::Fused && self.phase == Phase::Midcourse {
            self.phase = Phase::Terminal;
            transition.get_or_insert(Transition {
                from: Phase::Midcourse,
                to: Phase::Terminal,
                cause: TransitionCause::SeekerFused,
                time: self.time,
            });
        }
        if state == AidState::Waiting && self.seeker_availability() == AidAvailability::TimedOut {
            state = AidState::TimedOut;
        }
        (state, ran)
    }

    /// One LOS sample through the EKF, in place: a sample the EKF would refuse is refused
    /// before the pending covariance step runs (nothing of it changes the filter), then the
    /// step (atomic) and the update ([`Self::los_update`]), with the baro column when the baro
    /// is in the EKF. The covariance step's kernel runs under this small frame, not under the
    /// update's.
    #[inline(never)]
    fn fuse_los(&mut self, s: &LosSample<T>) -> Result<AidState, NavError> {
        let model = self.baro_model();
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        ekf.check_los(s)?;
        // The pending covariance step first (in place, atomic; the update then needs no copy
        // of the filter), the baro column in step with it.
        if let Some(model) = model {
            let bs = &mut self.baro_state;
            if let Some(dt) = ekf.predict_covariance_cross(&mut bs.cross)? {
                ekf.consider_external_decay(bs.decay(&model, dt));
            }
        } else if ekf.los_at_ins_time(s) {
            // As `update_los` would on a copy of the filter.
            ekf.predict_covariance_with(PsdMargin::Deferred)?;
        }
        self.los_update(s, model.is_some())
    }

    /// The LOS update after [`Self::fuse_los`]'s check and covariance step; with `baro_column`
    /// the baro column follows the components the update fused (module `baro`). The PSD
    /// state after the flush first (module `psd_check`; here, not in `fuse_los`, whose frame
    /// it would grow).
    #[inline(never)]
    fn los_update(&mut self, s: &LosSample<T>, baro_column: bool) -> Result<AidState, NavError> {
        self.psd_after_flush();
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        let report = if baro_column {
            let bs = &mut self.baro_state;
            let mut col = CrossColumn {
                cross: bs.cross,
                variance: bs.variance_m2,
                correction: T::zero(),
            };
            let r = ekf.update_los_cross(s, &mut col)?;
            bs.cross = col.cross;
            bs.variance_m2 = col.variance;
            bs.bias_m -= col.correction;
            r
        } else {
            ekf.update_los(s)?
        };
        let (pitch, yaw) = (&report.pitch, &report.yaw);
        self.seeker.counters.record(pitch.outcome);
        self.seeker.counters.record(yaw.outcome);
        self.seeker.last = Some(if pitch.nis >= yaw.nis { *pitch } else { *yaw });
        let any = |o: FusionOutcome| pitch.outcome == o || yaw.outcome == o;
        if any(FusionOutcome::Fused) {
            self.seeker.last_ok = Some(self.time);
            return Ok(AidState::Fused);
        }
        Ok(if any(FusionOutcome::Rejected) {
            AidState::Rejected
        } else {
            AidState::Waiting
        })
    }
}

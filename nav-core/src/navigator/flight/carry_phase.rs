//! The carry phase's tick (module doc of [`super::super`]): the INS on the slave IMU slaved
//! to the late master through the transfer alignment's hand-over, the alignment's predictions
//! run ahead, the IMU-confirmed separation and the EKF's start.

use super::super::carry::CueLimits;
use super::super::design::{flexure_share, slave_share};
use super::super::handover::{
    hand_over_checked_master, refer_to_carry, validate_master, AlignmentAtRelease, MasterAtRelease,
    NavBlocks,
};
use super::super::types::{
    AidAvailability, AidState, Aids, ImuTick, MasterNav, NavigatorConfig, SeparationStatus,
    TickReport, Transition, TransitionCause,
};
use super::{
    elapsed, ned_factors, Correction, MasterRecord, Navigator, Snapshot, SnapshotFix,
    MAX_AHEAD_PER_TICK,
};
use crate::contract::{Estimator, FusionOutcome, FusionReport};
use crate::earth::{earth_rate_ned, transport_rate_ned};
use crate::seeker_ins::{validate_increment, ImuIncrement, Ins, SeekerIns, SeekerInsInitial};
use crate::time::Timestamp;
use crate::transfer_alignment::{
    compensate_lever_arm, GapOutcome, MasterSample, SlaveSample, StepReport, TransferAlignment,
};
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, Vector3};

/// The hand-over's 9 × 9 navigation block `[δr, δv, φ]` (zero cross blocks) in the carry
/// solution's NED convention, written in place into `out` (no 9 × 9 temporary, no copy through
/// the stack). The numbers of scaling the block-diagonal matrix's rows then columns
/// i = 0, 1, 2 by the factors `d` of the position states ([`super::nav_block_to_ned`]'s
/// scheme: element (r, c) times the factor of each position index among r, c, the smaller
/// first), written from its structure: the position block `P_rc d_min(r,c) d_max(r,c)`, the
/// zeros beside it in row or column i `0 · d_i` (signed as the product gives), the velocity
/// and attitude blocks and the other zeros unscaled.
fn write_nav9_ned<T: Real>(blocks: &NavBlocks<T>, d: [T; 3], out: &mut SMatrix<T, 9, 9>) {
    let zero = T::zero();
    let scaled_zero = d.map(|di| zero * di);
    for (c, dst) in out.as_mut_slice().chunks_exact_mut(9).enumerate() {
        let (rows_pos, rows_rest) = dst.split_at_mut(3);
        match (c, scaled_zero.get(c)) {
            // A position column: the position block scaled, zeros scaled by its factor below.
            (_, Some(&zc)) => {
                for (r, o) in rows_pos.iter_mut().enumerate() {
                    let x = blocks.pos.get((r, c)).copied().unwrap_or(zero);
                    let (lo, hi) = (d.get(r.min(c)), d.get(r.max(c)));
                    *o = match (lo, hi) {
                        (Some(&lo), Some(&hi)) => x * lo * hi,
                        _ => x,
                    };
                }
                rows_rest.fill(zc);
            }
            // A velocity or attitude column: zeros in the position rows scaled by theirs,
            // its own block unscaled, zeros elsewhere.
            _ => {
                rows_pos.copy_from_slice(&scaled_zero);
                let (block, at) = if c < 6 {
                    (&blocks.vel, 0)
                } else {
                    (&blocks.att, 3)
                };
                for (r, o) in rows_rest.iter_mut().enumerate() {
                    *o = if r / 3 == at / 3 {
                        block.get((r % 3, c % 3)).copied().unwrap_or(zero)
                    } else {
                        zero
                    };
                }
            }
        }
    }
}

/// The master's quality and motion in the hand-over's shape, written field by field into
/// `out` (no temporary). Its body-rate 1σ is not on the bus: the alignment's rate-difference
/// noise (master and slave gyro noise per sample) bounds it.
fn write_at_release<T: Real>(m: &MasterNav<T>, rate_sigma_rad_s: T, out: &mut MasterAtRelease<T>) {
    let lat = T::lit(m.position.lat_rad);
    let alt = T::lit(m.position.alt_m);
    let w_in = earth_rate_ned(lat) + transport_rate_ned(lat, alt, &m.vel_ned_m_s);
    out.c_m_n = m.c_m_n;
    out.vel_ned_m_s = m.vel_ned_m_s;
    out.position = m.position;
    out.rate_nm_rad_s = m.angular_rate_rad_s - m.c_m_n.transpose() * w_in;
    out.attitude_sigma_rad = m.attitude_sigma_rad;
    out.velocity_sigma_m_s = m.velocity_sigma_m_s;
    out.position_sigma_m = m.position_sigma_m;
    out.rate_sigma_rad_s = rate_sigma_rad_s;
}

/// Scratch of a master tick: the master sample checked and matched for the alignment's step
/// (what the step and the hand-over read), written in place by the checks and read by the
/// step of the same tick only — no state: stale between master ticks and after a refused
/// sample, never read then (its `Debug` shows nothing). Held in the navigator so that the step
/// runs under a small frame and nothing is copied into it.
#[derive(Clone, Copy)]
pub(super) struct MasterEpoch<T> {
    /// The master's sample for the alignment.
    sample: MasterSample<T>,
    /// The slave's sample at the master's epoch.
    slave: SlaveSample<T>,
    /// The master in the hand-over's shape (checked).
    at: MasterAtRelease<T>,
    /// The stamp of the INS snapshot nearest the master's epoch.
    snap_time: Timestamp,
    /// The alignment's report of the step on this epoch (written in place by the step).
    report: StepReport<T>,
}

impl<T> core::fmt::Debug for MasterEpoch<T> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("MasterEpoch").finish_non_exhaustive()
    }
}

impl<T: Real> MasterEpoch<T> {
    /// Blank scratch (zeros; the first master tick overwrites it before reading).
    pub(super) fn blank() -> Self {
        let zero3 = Vector3::zeros();
        let position = crate::seeker_ins::Position {
            lat_rad: 0.0,
            lon_rad: 0.0,
            alt_m: 0.0,
        };
        let time = Timestamp::from_micros(0);
        Self {
            sample: MasterSample {
                time,
                angular_rate_rad_s: zero3,
                angular_accel_rad_s2: zero3,
                specific_force_m_s2: zero3,
            },
            slave: SlaveSample {
                time,
                angular_rate_rad_s: zero3,
                specific_force_m_s2: zero3,
            },
            at: MasterAtRelease {
                c_m_n: Matrix3::identity(),
                vel_ned_m_s: zero3,
                position,
                rate_nm_rad_s: zero3,
                attitude_sigma_rad: zero3,
                velocity_sigma_m_s: zero3,
                position_sigma_m: zero3,
                rate_sigma_rad_s: T::zero(),
            },
            snap_time: time,
            report: StepReport::blank(time),
        }
    }
}

/// Where a master sample's hand-over is committed: the navigator's carry fields.
struct CarryTargets<'a, T: Real> {
    ins: &'a mut Ins<T>,
    carry_cov: &'a mut SMatrix<T, 9, 9>,
    handover: &'a mut Option<NavBlocks<T>>,
    snapshot_fix: &'a mut Option<SnapshotFix<T>>,
}

/// The hand-over at the master's epoch with the (updated) alignment `ta`, and the INS slaved
/// to it, committed into `out` only when nothing failed: the carry covariance (the
/// hand-over's 9×9 navigation block, NED convention, and its blocks in the EKF's), the INS
/// corrected in place (`Ins::correct` is atomic and the last fallible step), and the
/// correction its snapshots since `snap` take (checked finite, applied on the next tick).
/// Nothing is returned by value.
fn slave_to<T: Real, const K: usize, const N: usize>(
    config: &NavigatorConfig<T>,
    ta: &TransferAlignment<T, K, N>,
    master: &MasterAtRelease<T>,
    snap: &Snapshot<T>,
    now: Timestamp,
    out: CarryTargets<'_, T>,
) -> Result<(), NavError> {
    let nav = hand_over_checked_master(
        master,
        &AlignmentAtRelease::from_filter(ta)
            .with_slave_share(&slave_share(config))
            .with_flexure_share(&flexure_share(config)),
        &config.lever_arm,
    )?;
    let corr = Correction::between(&snap.state, &nav.state);
    // A finite correction applies to every stored state (finite, unit quaternion): checked
    // once here instead of on each snapshot.
    if !corr.is_finite() {
        return Err(NavError::NonFiniteInput {
            input: "master correction",
        });
    }
    out.ins.correct(
        corr.d_lat_rad,
        corr.d_lon_rad,
        corr.d_alt_m,
        &corr.d_vel_m_s,
        &corr.phi_rad,
    )?;
    // Commit (nothing below fails).
    write_nav9_ned(&nav.blocks, ned_factors(&nav.state), out.carry_cov);
    *out.handover = Some(nav.blocks);
    *out.snapshot_fix = Some(SnapshotFix {
        correction: corr,
        from: snap.time,
        until: now,
    });
    Ok(())
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// [`Self::tick_carry`] in a frame of its own (not inlined): the carry phase's stack is
    /// not on the flight phases' path.
    #[inline(never)]
    pub(super) fn tick_carry_apart(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
        out: &mut TickReport<T>,
    ) -> Result<(), NavError> {
        self.tick_carry(imu, aids, transition, out)
    }

    fn tick_carry(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
        out: &mut TickReport<T>,
    ) -> Result<(), NavError> {
        let f_s_m_s2 = self.carry_imu(&imu.increment)?;
        let mut master_state = AidState::Waiting;
        if let Some(m) = aids.master {
            master_state = match self.fuse_master(m) {
                Ok(s) => s,
                Err(e) => {
                    self.master.counters.record_refused();
                    AidState::Refused(e)
                }
            };
        } else {
            self.run_ahead();
        }
        let master_lost = self.master_availability() == AidAvailability::TimedOut;
        if master_lost && master_state == AidState::Waiting {
            master_state = AidState::TimedOut;
        }
        self.separation_check(aids.separation, &f_s_m_s2, master_lost, transition);
        // The aid reports, written into the caller's report (nothing above failed).
        self.master.write(master_state, &mut out.master);
        self.baro.write(AidState::NotUsedInPhase, &mut out.baro);
        self.seeker.write(AidState::NotUsedInPhase, &mut out.seeker);
        Ok(())
    }

    /// The carry tick's IMU part, in a frame of its own (not under the master's step): the INS
    /// stepped in place, the slave's sample into the history, the INS snapshot stored (the
    /// last master's correction of the snapshots applied first). Returns the slave's specific
    /// force, m/s². Refused (`Err`): nothing changed.
    #[inline(never)]
    fn carry_imu(&mut self, inc: &ImuIncrement<T>) -> Result<Vector3<T>, NavError> {
        // The interval the INS step integrates (`Ins::step` takes the same), so that the slave
        // sample is checked before the INS steps in place (no copy of the INS).
        let dt = self.ins.interval_to(inc.time)?;
        // The step's own checks, in its order: finite increments within their bounds over an
        // interval of at least 1 µs make the slave's rates finite (what the history checks).
        validate_increment(inc)?;
        let slave = SlaveSample {
            time: inc.time,
            angular_rate_rad_s: inc.delta_theta_rad / dt,
            specific_force_m_s2: inc.delta_v_m_s / dt,
        };
        if self.history.newest().is_some_and(|s| s.time >= inc.time) {
            return Err(NavError::TimeNotIncreasing);
        }
        // Atomic: refused, the INS is unchanged.
        self.ins.step(inc)?;
        // Commit the IMU part (nothing below fails the tick: the history's refusals — a
        // non-finite or not later sample — were checked above, and a full history drops its
        // oldest first).
        self.history.push(&slave)?;
        self.time = inc.time;
        self.apply_snapshot_fix();
        if self.snapshots.is_full() {
            let _ = self.snapshots.pop_front();
        }
        let _ = self.snapshots.push_back(Snapshot {
            time: inc.time,
            state: *self.ins.state(),
        });
        Ok(slave.specific_force_m_s2)
    }

    /// The carry tick's separation logic: a release `signal` (its time) recorded, then the
    /// IMU's confirmation (the slave's specific force `f_s_m_s2`, m/s², against the last
    /// master's) within the window, or an unsignalled release (the master lost, and the IMU
    /// unloading since the master's loss or falling: [`ReleaseEvidence`](super::super::carry::ReleaseEvidence));
    /// a release confirmed starts the EKF and reports the transition. In a frame of its own
    /// (not above the master's step).
    #[inline(never)]
    fn separation_check(
        &mut self,
        signal: Option<Timestamp>,
        f_s_m_s2: &Vector3<T>,
        master_lost: bool,
        transition: &mut Option<Transition>,
    ) {
        if let Some(sig) = signal {
            if matches!(
                self.separation,
                SeparationStatus::NotSignalled
                    | SeparationStatus::SeparationUnconfirmed
                    | SeparationStatus::AwaitingConfirmation
            ) && self.signal.is_none_or(|s| sig > s)
            {
                self.signal = Some(sig);
                self.separation = SeparationStatus::AwaitingConfirmation;
            }
        }
        // The IMU's evidence without a signal, recorded on every carry tick (the unloading
        // starts before the master times out).
        let limits = CueLimits {
            jump_m_s2: self.config.separation.specific_force_jump_m_s2,
            onset_s: self.config.separation.unsignalled_onset_s,
        };
        let cue = self.release_evidence.update(
            self.time,
            f_s_m_s2,
            self.last_master.as_ref().map(|lm| &lm.carried),
            &limits,
        );
        let mut release = None;
        match (self.separation, self.signal) {
            (SeparationStatus::AwaitingConfirmation, Some(sig)) => {
                let age = elapsed::<T>(self.time, sig);
                // The IMU's confirmation against the last master's force in slave axes.
                let imu_sees = self.last_master.is_some_and(|lm| {
                    (f_s_m_s2 - lm.f_slave_m_s2()).norm()
                        > self.config.separation.specific_force_jump_m_s2
                });
                if imu_sees {
                    release = Some((
                        SeparationStatus::Confirmed,
                        TransitionCause::SeparationConfirmed,
                    ));
                } else if age > self.config.separation.confirm_window_s {
                    self.separation = SeparationStatus::SeparationUnconfirmed;
                }
            }
            _ => {
                if master_lost && cue.is_some() {
                    release = Some((
                        SeparationStatus::UnsignalledRelease,
                        TransitionCause::UnsignalledSeparation,
                    ));
                }
            }
        }
        if let Some((status, cause)) = release {
            if self.hand_over_now() {
                self.enter_released(status, cause);
                *transition = self.pending.take();
            }
        }
    }

    /// A tick without master data carries the alignment's next predictions, as many as the
    /// last master sample needed (at most [`MAX_AHEAD_PER_TICK`] a tick): the master tick then
    /// has those less to do.
    fn run_ahead(&mut self) {
        let mut run = 0;
        while run < MAX_AHEAD_PER_TICK
            && self.ta.steps_ahead() < self.master_steps
            && self.ta.predict_ahead()
        {
            run += 1;
        }
    }

    /// Starts the EKF (`self.ekf`) at this tick from the last master and the alignment;
    /// `false` (nothing changed) without a master or when the EKF refuses the state: the
    /// current INS state with the hand-over P0 of the last fused master sample (its
    /// navigation blocks kept from that tick: the alignment has not changed since, so the
    /// hand-over would give them again bit for bit), written in place into the new EKF, its
    /// accelerometer-bias states referred to the carry's specific force ([`refer_to_carry`],
    /// the last master's in slave axes, [`MasterRecord::f_slave_m_s2`]).
    #[inline(never)]
    fn hand_over_now(&mut self) -> bool {
        let (Some(lm), Some(blocks)) = (self.last_master, self.handover) else {
            return false;
        };
        let priors = self.config.priors;
        let started = if blocks.p0_passes_checks(&priors) {
            SeekerIns::start_in(
                &mut self.ekf,
                &self.config.ins,
                &self.design,
                self.ins.state(),
                |p0| blocks.write_p0(&priors, p0),
            )
            .is_ok()
        } else {
            // Blocks the cheap check cannot vouch for: the EKF's own dense check decides.
            self.hand_over_dense(&blocks)
        };
        started && refer_to_carry(&mut self.ekf, &lm.f_slave_m_s2())
    }

    /// [`Self::hand_over_now`] through the EKF's public constructor and its dense checks.
    #[cold]
    #[inline(never)]
    fn hand_over_dense(&mut self, blocks: &NavBlocks<T>) -> bool {
        let mut initial = SeekerInsInitial {
            state: *self.ins.state(),
            covariance: SMatrix::zeros(),
        };
        blocks.write_p0(&self.config.priors, &mut initial.covariance);
        match SeekerIns::from_design(&self.config.ins, &self.design, &initial) {
            Ok(ekf) => {
                self.ekf = Some(ekf);
                true
            }
            Err(_) => false,
        }
    }

    /// The last master sample's correction into the snapshots it covers (the same
    /// operations, in the same order, as when applied at that master's tick: the snapshots
    /// are read at the next master sample only).
    fn apply_snapshot_fix(&mut self) {
        let Some(fix) = self.snapshot_fix.take() else {
            return;
        };
        // Newest first, up to the fix's start (the older ones are not touched: a deep ring
        // costs nothing here).
        for s in self
            .snapshots
            .iter_mut()
            .rev()
            .take_while(|s| s.time >= fix.from)
            .filter(|s| s.time <= fix.until)
        {
            if let Some(corrected) = fix.correction.apply(&s.state) {
                s.state = corrected;
            }
        }
    }

    /// Alignment step at the master's epoch, hand-over and the INS slaved to it; atomic: the
    /// cheap checks first ([`Self::prepare_master`], in a frame of its own), then the alignment
    /// steps in place and is undone ([`TransferAlignment::step_then`]) when the hand-over or
    /// the slaving fails (no copy of the filter). The matched epoch is the navigator's
    /// scratch ([`MasterEpoch`]), so that the step and the hand-over run under a small frame.
    #[inline(never)]
    fn fuse_master(&mut self, m: &MasterNav<T>) -> Result<AidState, NavError> {
        if !self.prepare_master(m)? {
            return Ok(AidState::NotUsedInPhase);
        }
        self.step_master()
    }

    /// The checks and the matching of a master sample `m` before the alignment steps (a bad
    /// sample touches no state: only the scratch `self.epoch`, written in place);
    /// `Ok(false)`: not fused now.
    #[inline(never)]
    fn prepare_master(&mut self, m: &MasterNav<T>) -> Result<bool, NavError> {
        // A separation signalled at `s` and awaiting the IMU's confirmation: a master sample
        // whose slave interpolation reaches past `s` (epoch later than one IMU interval before
        // it) would pair the aircraft on the lever arm with the missile already dropping (the
        // flexure's motion gone from its IMU); it is not fused (nothing changes, nothing
        // counted) and the hand-over uses the samples before. Fused again if the IMU does not
        // confirm the separation.
        let imu_dt_us = crate::time::seconds_to_micros(self.config.imu_dt_s).unwrap_or(0);
        if self.separation == SeparationStatus::AwaitingConfirmation
            && self
                .signal
                .is_some_and(|s| m.time.as_micros().saturating_add(imu_dt_us) > s.as_micros())
        {
            return Ok(false);
        }
        let tol = self.ta_tolerance_us();
        let e = &mut self.epoch;
        e.snap_time = self
            .snapshots
            .iter()
            .rev()
            .find(|s| s.time.as_micros().abs_diff(m.time.as_micros()) <= tol)
            .ok_or(NavError::MeasurementTimeOutOfWindow)?
            .time;
        e.sample = MasterSample {
            time: m.time,
            angular_rate_rad_s: m.angular_rate_rad_s,
            angular_accel_rad_s2: m.angular_accel_rad_s2,
            specific_force_m_s2: m.specific_force_m_s2,
        };
        e.sample.validate()?;
        // The hand-over's checks of the master before the alignment steps: a bad master
        // sample does not touch the alignment.
        write_at_release(m, self.config.alignment.rate_noise_sigma_rad_s, &mut e.at);
        validate_master(&e.at, &self.config.lever_arm, &self.config.priors)?;
        // The slave's interval means interpolated at the master's (instantaneous) epoch; the
        // end-stamped sample of that epoch when they cannot be (the first tick).
        e.slave = self
            .history
            .at_time(m.time)
            .or_else(|_| self.history.find(m.time, tol))?;
        Ok(true)
    }

    /// The alignment's step on the epoch [`Self::prepare_master`] wrote (`self.epoch`), the
    /// hand-over and the slaving in its `then`, the master's records.
    fn step_master(&mut self) -> Result<AidState, NavError> {
        let now = self.time;
        let Self {
            ta,
            config,
            ins,
            carry_cov,
            handover,
            snapshot_fix,
            epoch,
            snapshots,
            ..
        } = self;
        let MasterEpoch {
            sample,
            slave,
            at,
            snap_time,
            report,
        } = epoch;
        // The snapshot the checks found (read in place, not copied).
        let snap = snapshots
            .iter()
            .rev()
            .find(|s| s.time == *snap_time)
            .ok_or(NavError::MeasurementTimeOutOfWindow)?;
        // The report written into the navigator's scratch epoch (not returned by value).
        ta.step_then(sample, slave, report, |ta| {
            let out = CarryTargets {
                ins,
                carry_cov,
                handover,
                snapshot_fix,
            };
            slave_to(config, ta, at, snap, now, out)
        })?;
        let e = &self.epoch;
        // The bias states' share of the force's change (`transfer_alignment::bias_charge`).
        let f_now = compensate_lever_arm(&e.sample, &self.config.lever_arm.nominal_m);
        let ie = &self.config.ins.instrument_errors;
        self.ta.charge_share_change(
            ie.accel_scale_factor,
            ie.accel_misalignment_rad,
            self.last_master.map(|lm| lm.f_master_m_s2),
            &f_now,
        );
        // What the next sample will likely need: as many predictions as this one; after the
        // first epoch (nothing predicted, the master's interval not known yet) as many as a
        // tick runs ahead, so that the next master tick predicts nothing itself (predictions
        // run ahead but not needed are discarded by the step: the cost is that of today's).
        self.master_steps = if e.report.gap == GapOutcome::Started {
            MAX_AHEAD_PER_TICK
        } else {
            e.report.predictions.max(1)
        };
        self.last_master = Some(MasterRecord::new(e.sample.time, &f_now, &self.ta.theta()));
        Ok(self.record_master())
    }

    /// The master track after a fused sample's updates (the step's report in the scratch
    /// epoch): counters, the component with the largest NIS, the time of the last fusion;
    /// `Fused` when one component was.
    fn record_master(&mut self) -> AidState {
        let mut worst: Option<FusionReport<T>> = None;
        let mut any_fused = false;
        for u in &self.epoch.report.updates {
            self.master.counters.record(u.outcome);
            any_fused |= u.outcome == FusionOutcome::Fused;
            if worst.is_none_or(|w| u.nis > w.nis) {
                worst = Some(*u);
            }
        }
        self.master.last = worst;
        if any_fused {
            self.master.last_ok = Some(self.time);
            AidState::Fused
        } else {
            AidState::Rejected
        }
    }

    fn ta_tolerance_us(&self) -> u64 {
        crate::time::seconds_to_micros(self.config.alignment.time_tolerance_s).unwrap_or(0)
    }
}

//! Propagation: time-stamped IMU samples, gap detection and bridging, clipped samples, and
//! the covariance steps.

use super::config::VARIANCE_CEILING;
use super::covariance_health::PsdMargin;
use super::error_model::{propagate_covariance_sparse, transition_column, ATT, STATES, VEL};
use super::filter::SeekerIns;
use super::flight_noise::flight_noise_step;
use super::mechanization::{ImuIncrement, Ins, PositionKinematics};
use super::sparse_f::SparseF;
use crate::contract::Health;
use crate::time::{micros_to_seconds, seconds_to_micros, Timestamp};
use crate::{NavError, Real};
use nalgebra::Vector3;

/// Which sensor of an IMU sample is clipped ([`SeekerIns::propagate_clipped`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClipFlags {
    /// An accelerometer axis is at its range.
    pub accel: bool,
    /// A gyro axis is at its range.
    pub gyro: bool,
}

/// When the covariance step runs: every `covariance_interval_steps` samples, or when the
/// caller asks ([`SeekerIns::predict_covariance_cross`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum CovarianceSchedule {
    Interval,
    /// As `Interval`, P's PSD check left to the caller ([`PsdMargin::Deferred`]: the flight
    /// navigator's steps, its tick budget).
    Unchecked,
    /// As `Unchecked` with the constant noise ([`PsdMargin::Constant`]): the held samples of
    /// a gap bridged under `Unchecked` (more steps follow before the caller's check).
    Stabilised,
    Deferred,
    /// As `Unchecked`, with an external column propagated by the same Φ
    /// ([`SeekerIns::propagate_cross`]; regular, unclipped samples only).
    Cross,
}

impl<T: Real> SeekerIns<T> {
    /// One IMU sample: bias compensation, INS step over the interval since the previous
    /// sample ([`Ins::step`]) and (every `covariance_interval_steps` samples) covariance
    /// propagation.
    ///
    /// **Gaps** are detected from the time stamps: an interval longer than 1.5 × `imu_dt_s`
    /// means `round(interval / imu_dt_s) − 1` samples were lost (their increments with them;
    /// the sample's own increments cover its last nominal interval). Up to
    /// `ImuFaultPolicy::max_gap_s` they are bridged by a zero-order hold: the INS integrates
    /// the last compensated increment at the nominal rate (body rate and specific force held
    /// in the body frame), P is propagated as for real samples and the error of the hold is
    /// accounted for in P per [`super::ImuFaultPolicy`] (`gap_*_sigma`, fully correlated over
    /// the gap); counted in `Health::gaps_bridged`. A longer gap is not bridged: the INS
    /// restarts its interval at the sample (the gap's motion is lost), the navigation block of
    /// P goes to its ceilings ([`VARIANCE_CEILING`], correlations dropped) and the health to
    /// `NeedsReinitialisation`; counted in `Health::gaps_reset`. Jitter within 1.5 × the
    /// nominal interval is no gap: the sample is integrated over its actual interval.
    ///
    /// Errors (filter unchanged but for `Health::imu_refused`, the clock too: a later sample
    /// is accepted): `TimeNotIncreasing`, `NonFiniteInput`, `InputOutOfRange` (increments
    /// beyond their range).
    pub fn propagate(&mut self, sample: &ImuIncrement<T>) -> Result<(), NavError> {
        self.counted(sample, None, CovarianceSchedule::Interval)
    }

    /// One IMU sample that the IMU flags as clipped (over-range on at least one axis of the
    /// sensors in `clipped`; the driver knows it from the status word or from a component at
    /// full scale). As [`SeekerIns::propagate`]; only the flagged sensor's block of P is
    /// inflated (accelerometer → velocity, gyro → attitude).
    ///
    /// Design: the sample is integrated as delivered: its unclipped axes are exact and a
    /// clipped axis reads the range, the value closest to the truth that is known (a hold of
    /// the previous sample is further off in a burst that grows past the range, and dropping
    /// the sample loses the unclipped axes). The unknown excess is accounted for in P per
    /// [`super::ImuFaultPolicy`] (`clip_*_sigma`, fully correlated over a burst of consecutive
    /// clipped samples).
    pub fn propagate_clipped(
        &mut self,
        sample: &ImuIncrement<T>,
        clipped: ClipFlags,
    ) -> Result<(), NavError> {
        self.counted(sample, Some(clipped), CovarianceSchedule::Interval)
    }

    /// As [`SeekerIns::propagate`] / [`SeekerIns::propagate_clipped`] (`clip`), but the
    /// covariance step is left pending whatever `covariance_interval_steps` says: the caller
    /// runs it with [`SeekerIns::predict_covariance_cross`] (the flight navigator, which
    /// carries a state of its own beside the 17 and needs the same Φ). Atomic as
    /// `propagate`.
    pub(crate) fn propagate_deferred(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
    ) -> Result<(), NavError> {
        self.counted(sample, clip, CovarianceSchedule::Deferred)
    }

    /// [`SeekerIns::propagate`] / [`SeekerIns::propagate_clipped`] (`clip`) without counting
    /// a refused sample in `Health::imu_refused` (the flight navigator's refused tick changes
    /// nothing) and without the PSD check (the navigator's tick budget: it checks P on a later
    /// tick, [`PsdMargin::Deferred`]). Atomic without a copy of the filter on the regular
    /// path.
    pub(crate) fn propagate_uncounted(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
    ) -> Result<(), NavError> {
        self.propagate_sample(sample, clip, CovarianceSchedule::Unchecked)
    }

    /// IMU samples integrated since the last covariance step (0 after a sample: its step ran).
    pub(crate) fn steps_pending(&self) -> u16 {
        self.steps_pending
    }

    /// [`SeekerIns::propagate_deferred`] followed, when `covariance_interval_steps` samples
    /// are pending, by [`SeekerIns::predict_covariance_cross`] on `cross`: the same numbers,
    /// atomic as a whole (filter and `cross` unchanged on error) without a copy of the
    /// filter on the regular path — the INS steps on a copy of the INS and the covariance
    /// step (itself atomic) runs before the INS is committed. A clipped sample or a gap (P
    /// changes before the covariance step) takes the general path on a copy of the filter
    /// (more stack). Returns the interval of the covariance step that ran, s (`None`: none).
    /// A refused sample is not counted in `Health::imu_refused` (the flight navigator's
    /// refused tick changes nothing).
    pub(crate) fn propagate_cross(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        cross: &mut nalgebra::SVector<T, STATES>,
    ) -> Result<Option<T>, NavError> {
        let dt_us = self.ins.dt_us();
        let gap = self.ins.time().is_some_and(|prev| {
            sample
                .time
                .micros_since(prev)
                .is_some_and(|us| us.saturating_mul(2) > dt_us.saturating_mul(3))
        });
        if clip.is_some() || gap {
            return self.propagate_cross_on_copy(sample, clip, cross);
        }
        if self.clock.is_some_and(|t| sample.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        self.step_sample(sample, None, CovarianceSchedule::Cross, Some(cross))
    }

    /// [`SeekerIns::propagate_cross`]'s general path: deferred propagation and the covariance
    /// step on a copy, committed together.
    #[inline(never)]
    fn propagate_cross_on_copy(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        cross: &mut nalgebra::SVector<T, STATES>,
    ) -> Result<Option<T>, NavError> {
        let mut next = *self;
        next.propagate_deferred(sample, clip)?;
        let mut c = *cross;
        let dt = if next.steps_pending >= next.config.covariance_interval_steps {
            next.predict_covariance_cross(&mut c)?
        } else {
            None
        };
        *self = next;
        *cross = c;
        Ok(dt)
    }

    /// [`SeekerIns::predict_covariance`] that also applies the step's transition matrix Φ
    /// (the very Φ of the generated kernel, [`super::error_model::transition_times`]) to `cross`, a covariance
    /// column `E[δx δb]` of an external state b kept beside the 17. Returns the interval
    /// covered, s (`None`: nothing was pending). When the step changed P other than by
    /// `Φ P Φᵀ + Q` (a variance repaired or held at its ceiling: a congruence the column
    /// does not follow), or when `Φ c` is not finite, `cross` is set to zero (the joint
    /// covariance stays PSD; that correlation is forgotten). P's PSD margin is the caller's
    /// to check ([`PsdMargin::Deferred`]). Errors leave the filter and `cross` unchanged.
    pub(crate) fn predict_covariance_cross(
        &mut self,
        cross: &mut nalgebra::SVector<T, STATES>,
    ) -> Result<Option<T>, NavError> {
        if self.steps_pending == 0 {
            return Ok(None);
        }
        let dt_total = self.pending_interval_s(self.steps_pending, self.pending_us);
        let dv = self.dv_ned_pending_m_s;
        self.covariance_step_cross(None, dt_total, &dv, cross)?;
        self.steps_pending = 0;
        self.pending_us = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        Ok(Some(dt_total))
    }

    /// Counts a refused sample.
    fn counted(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        schedule: CovarianceSchedule,
    ) -> Result<(), NavError> {
        let r = self.propagate_sample(sample, clip, schedule);
        if r.is_err() {
            Health::bump(&mut self.health.imu_refused);
        }
        r
    }

    /// Time check, gap detection, then the sample; atomic.
    fn propagate_sample(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        schedule: CovarianceSchedule,
    ) -> Result<(), NavError> {
        if self.clock.is_some_and(|t| sample.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        let Some(prev) = self.ins.time() else {
            // First sample after construction or re-initialisation: the nominal interval.
            return self.step_sample(sample, clip, schedule, None).map(|_| ());
        };
        let us = sample
            .time
            .micros_since(prev)
            .ok_or(NavError::TimeNotIncreasing)?;
        let dt_us = self.ins.dt_us();
        if us.saturating_mul(2) <= dt_us.saturating_mul(3) {
            return self.step_sample(sample, clip, schedule, None).map(|_| ());
        }
        self.propagate_after_gap(sample, clip, schedule, prev, us)
    }

    /// [`Self::propagate_sample`] after a gap of `us` µs since the sample at `prev`: bridged
    /// or reset on a copy of the filter, committed with the sample. Out of line: the copy's
    /// frame is not on the regular path's stack.
    #[cold]
    #[inline(never)]
    fn propagate_after_gap(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        schedule: CovarianceSchedule,
        prev: Timestamp,
        us: u64,
    ) -> Result<(), NavError> {
        let dt_us = self.ins.dt_us();
        // round(us / dt_us) − 1 ≥ 1 (dt_us > 0 by construction: no division by zero).
        let missing = us
            .saturating_add(dt_us / 2)
            .checked_div(dt_us)
            .unwrap_or(0)
            .saturating_sub(1);
        let max_us = seconds_to_micros(self.config.imu_faults.max_gap_s).unwrap_or(0);
        let mut next = *self;
        if missing.saturating_mul(dt_us) <= max_us {
            let held = match schedule {
                CovarianceSchedule::Unchecked => CovarianceSchedule::Stabilised,
                other => other,
            };
            next.bridge_gap(prev, missing, held)?;
        } else {
            next.reset_after_gap()?;
        }
        next.step_sample(sample, clip, schedule, None)?;
        next.last_imu_fault = Some(sample.time);
        *self = next;
        Ok(())
    }

    /// Bias compensation, INS step and covariance step; the clipping inflation when flagged.
    fn step_sample(
        &mut self,
        sample: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        schedule: CovarianceSchedule,
        cross: Option<&mut nalgebra::SVector<T, STATES>>,
    ) -> Result<Option<T>, NavError> {
        let dt = self.ins.interval_to(sample.time)?;
        let compensated = ImuIncrement {
            time: sample.time,
            delta_theta_rad: sample.delta_theta_rad - self.gyro_bias_rad_s * dt,
            delta_v_m_s: sample.delta_v_m_s - self.accel_bias_m_s2 * dt,
        };
        let stepped = self.propagate_compensated(&compensated, schedule, cross)?;
        self.held_run = 0;
        if self.fusion_ref.is_none() {
            // The aid timeout runs from the start of the interval of the first sample.
            self.fusion_ref = Some(Timestamp::from_micros(
                sample.time.as_micros().saturating_sub(self.ins.dt_us()),
            ));
        }
        self.clock = Some(sample.time);
        match clip {
            None => self.clipped_run = 0,
            Some(flags) => {
                self.clipped_run = self.clipped_run.saturating_add(1);
                let pol = &self.config.imu_faults;
                let pick = |on: bool, s: T| if on { s } else { T::zero() };
                let sa = pick(flags.accel, pol.clip_accel_sigma_m_s2);
                let sw = pick(flags.gyro, pol.clip_rate_sigma_rad_s);
                let dt = self.ins.last_interval_s();
                self.inflate_degraded(self.clipped_run, dt, sa, sw);
                Health::bump(&mut self.counters.clipped_samples);
                self.last_imu_fault = Some(sample.time);
            }
        }
        Ok(stepped)
    }

    /// The zero-order hold over `missing` samples after the one at `prev`.
    fn bridge_gap(
        &mut self,
        prev: Timestamp,
        missing: u64,
        schedule: CovarianceSchedule,
    ) -> Result<(), NavError> {
        let mut held = self.ins.last_increment().ok_or(NavError::InputOutOfRange {
            input: "IMU gap before the first sample (nothing to hold)",
        })?;
        let (sa, sw) = (
            self.config.imu_faults.gap_accel_sigma_m_s2,
            self.config.imu_faults.gap_rate_sigma_rad_s,
        );
        let dt_us = self.ins.dt_us();
        let dt = self.config.imu_dt_s;
        self.clipped_run = 0;
        held.time = prev;
        for _ in 0..missing {
            held.time = held.time.add_micros(dt_us);
            self.propagate_compensated(&held, schedule, None)?;
            self.held_run = self.held_run.saturating_add(1);
            self.inflate_degraded(self.held_run, dt, sa, sw);
        }
        Health::bump(&mut self.health.gaps_bridged);
        let held_samples = u32::try_from(missing).unwrap_or(u32::MAX);
        self.counters.held_samples = self.counters.held_samples.saturating_add(held_samples);
        Ok(())
    }

    /// A gap too long to bridge: the INS restarts its interval at the next sample, the
    /// navigation block of P goes to its ceilings (correlations dropped).
    fn reset_after_gap(&mut self) -> Result<(), NavError> {
        self.ins = Ins::new(*self.ins.state(), self.config.imu_dt_s)?;
        self.radii = None;
        let zero = T::zero();
        for (j, col) in self.p.as_mut_slice().chunks_exact_mut(STATES).enumerate() {
            for (i, v) in col.iter_mut().enumerate() {
                if i < 9 || j < 9 {
                    *v = if i == j {
                        VARIANCE_CEILING.get(i).map_or(zero, |m| T::lit(*m))
                    } else {
                        zero
                    };
                }
            }
        }
        self.consider.forget_navigation();
        self.steps_pending = 0;
        self.pending_us = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        self.held_run = 0;
        self.clipped_run = 0;
        Health::bump(&mut self.health.gaps_reset);
        Ok(())
    }

    /// Adds `(2c − 1)(σ Δt)²` to the velocity and attitude variances ([`super::ImuFaultPolicy`]),
    /// then limits them to their ceilings. Not inlined: one copy serves the gap and the
    /// clipping paths.
    #[inline(never)]
    fn inflate_degraded(&mut self, c: u16, dt: T, accel_sigma: T, rate_sigma: T) {
        let w = T::lit(2.0 * f64::from(c) - 1.0) * dt * dt;
        let (qa, qw) = (w * accel_sigma * accel_sigma, w * rate_sigma * rate_sigma);
        for i in VEL..VEL + 3 {
            if let Some(v) = self.p.get_mut((i, i)) {
                *v += qa;
            }
        }
        for i in ATT..ATT + 3 {
            if let Some(v) = self.p.get_mut((i, i)) {
                *v += qw;
            }
        }
        self.limit_variances();
    }

    /// Brings every navigation variance above its ceiling back to it by scaling its row and
    /// column (a congruence: P stays symmetric PSD, correlations are kept). Nine compares when
    /// nothing is limited.
    #[inline(never)]
    pub(super) fn limit_variances(&mut self) {
        // The ceilings as literals of T: converted at compile time (an f64 → f32 conversion
        // per state in the loop is a soft-float call on the M4F).
        let [c0, c1, c2, c3, c4, c5, c6, c7, c8, ..] = VARIANCE_CEILING;
        let caps = [c0, c1, c2, c3, c4, c5, c6, c7, c8].map(T::lit);
        // Nine compares on the common path (nothing at its ceiling), no loop state kept.
        let over = |(i, cap): (usize, &T)| self.p.get((i, i)).is_some_and(|d| *d > *cap);
        if !caps.iter().enumerate().any(over) {
            return;
        }
        for (i, cap) in caps.into_iter().enumerate() {
            let Some(d) = self.p.get((i, i)).copied() else {
                continue;
            };
            if d > cap {
                let f = (cap / d).sqrt();
                for v in self.p.column_mut(i).iter_mut() {
                    *v *= f;
                }
                for v in self.p.row_mut(i).iter_mut() {
                    *v *= f;
                }
                self.consider.scale_row(i, f);
                Health::bump(&mut self.health.limits_hit);
            }
        }
    }

    /// INS step with a bias-compensated increment and the covariance step when due; atomic.
    fn propagate_compensated(
        &mut self,
        compensated: &ImuIncrement<T>,
        schedule: CovarianceSchedule,
        cross: Option<&mut nalgebra::SVector<T, STATES>>,
    ) -> Result<Option<T>, NavError> {
        // The INS steps on a copy (P, the large part, is not copied: the covariance step below
        // is atomic), and everything is committed only when both succeeded.
        let mut ins = self.ins;
        let interval_us = ins
            .time()
            .and_then(|t| compensated.time.micros_since(t))
            .unwrap_or(ins.dt_us());
        let radii = ins.step_keeping_radii(compensated)?;
        let dt = ins.last_interval_s();
        let dv_pending = self.dv_ned_pending_m_s + ins.specific_force_ned_m_s2() * dt;
        let steps = self.steps_pending.saturating_add(1);
        let pending_us = self.pending_us.saturating_add(interval_us);
        let mut stepped = None;
        if steps >= self.config.covariance_interval_steps
            && schedule != CovarianceSchedule::Deferred
        {
            let dt_total = self.pending_interval_s(steps, pending_us);
            match cross {
                Some(c) => {
                    self.covariance_step_cross(Some((&ins, &radii)), dt_total, &dv_pending, c)?
                }
                None => {
                    let margin = match schedule {
                        CovarianceSchedule::Interval => PsdMargin::Checked,
                        CovarianceSchedule::Unchecked | CovarianceSchedule::Cross => {
                            PsdMargin::Deferred
                        }
                        CovarianceSchedule::Stabilised | CovarianceSchedule::Deferred => {
                            PsdMargin::Constant
                        }
                    };
                    self.covariance_step_at(Some((&ins, &radii)), dt_total, &dv_pending, margin)?;
                }
            }
            stepped = Some(dt_total);
            self.steps_pending = 0;
            self.pending_us = 0;
            self.dv_ned_pending_m_s = Vector3::zeros();
        } else {
            self.steps_pending = steps;
            self.pending_us = pending_us;
            self.dv_ned_pending_m_s = dv_pending;
        }
        if !ins.state().position.is_in_range() {
            Health::bump(&mut self.counters.out_of_range_samples);
        }
        self.ins = ins;
        self.radii = Some(radii);
        Ok(stepped)
    }

    /// The covariance step over `dt_total_s` at the INS `ins` with the radii its step kept
    /// (`None`: the filter's own INS and `radii`) and the velocity increment `dv_ned_m_s`
    /// (m/s) of the interval: `Φ P Φᵀ + Q`, the flight configuration's instrument-error noise,
    /// repairs, stabilising noise (`margin`) and ceilings. The pending counters are the
    /// caller's. Atomic (P unchanged on error).
    fn covariance_step_at(
        &mut self,
        ins: Option<(&Ins<T>, &PositionKinematics<T>)>,
        dt_total_s: T,
        dv_ned_m_s: &Vector3<T>,
        margin: PsdMargin,
    ) -> Result<(), NavError> {
        let f = match ins {
            Some((at, radii)) => SparseF::at_ins(at, Some(radii), dv_ned_m_s, dt_total_s),
            None => SparseF::at_ins(&self.ins, self.radii.as_ref(), dv_ned_m_s, dt_total_s),
        };
        let repairs = self.covariance_step_f(&f, ins.map(|(i, _)| i), dt_total_s)?;
        self.after_covariance_step(repairs, margin);
        Ok(())
    }

    /// [`Self::covariance_step_at`] with F given (its mean specific force is the interval's
    /// `dv / Δt`), without the PSD margin and the ceilings (the caller's
    /// [`Self::after_covariance_step`]); the repairs. Not inlined: one copy serves every
    /// covariance step.
    #[inline(never)]
    fn covariance_step_f(
        &mut self,
        f: &SparseF<T>,
        ins: Option<&Ins<T>>,
        dt_total_s: T,
    ) -> Result<u32, NavError> {
        let repairs = propagate_covariance_sparse(
            &mut self.p,
            f,
            dt_total_s,
            self.design.accel_psd_m2_s3,
            self.design.gyro_psd_rad2_s,
        )?;
        // The accelerometers' S and M (consider parameters), then the instrument-error charge.
        let had_reference = self.consider_step(f, dt_total_s, repairs > 0);
        flight_noise_step(
            &mut self.p,
            &mut self.bias_charge,
            &self.config.instrument_errors,
            ins.unwrap_or(&self.ins),
            f,
            dt_total_s,
        );
        self.consider_start_if(!had_reference);
        Ok(repairs)
    }

    /// [`Self::covariance_step_at`] that also applies the step's Φ to `cross` (module doc of
    /// [`Self::predict_covariance_cross`]); atomic (P and `cross` unchanged on error). `ins`:
    /// the INS of the step with the radii its step kept (`None`: the filter's own).
    fn covariance_step_cross(
        &mut self,
        ins: Option<(&Ins<T>, &PositionKinematics<T>)>,
        dt_total_s: T,
        dv_ned_m_s: &Vector3<T>,
        cross: &mut nalgebra::SVector<T, STATES>,
    ) -> Result<(), NavError> {
        let f = match ins {
            Some((at, radii)) => SparseF::at_ins(at, Some(radii), dv_ned_m_s, dt_total_s),
            None => SparseF::at_ins(&self.ins, self.radii.as_ref(), dv_ned_m_s, dt_total_s),
        };
        let limits_before = self.health.limits_hit;
        // The flight navigator's steps: no PSD check (its tick budget; it checks P later).
        let repairs = self.covariance_step_f(&f, ins.map(|(i, _)| i), dt_total_s)?;
        self.after_covariance_step(repairs, PsdMargin::Deferred);
        // Φ c after the step (Φ is finite: the step succeeded), in a frame of its own beside
        // the kernel's; a column that overflows is forgotten as after a repair.
        if self.health.limits_hit == limits_before {
            transition_column(&f, dt_total_s, cross);
            self.consider_external_step(&f, dt_total_s, cross);
        } else {
            *cross = nalgebra::SVector::zeros();
            self.consider.p_ec = nalgebra::SVector::zeros();
        }
        Ok(())
    }

    /// The interval of `steps` samples spanning `pending_us` µs, s: `steps × imu_dt_s` when
    /// they were regular (the same bits as before time stamps), else the measured one.
    fn pending_interval_s(&self, steps: u16, pending_us: u64) -> T {
        if pending_us == u64::from(steps) * self.ins.dt_us() {
            self.config.imu_dt_s * T::lit(f64::from(steps))
        } else {
            micros_to_seconds(pending_us)
        }
    }

    /// Propagates P over the IMU samples accumulated since the last covariance step (no-op if
    /// none; the LOS update does it itself). Errors leave the filter unchanged.
    pub fn predict_covariance(&mut self) -> Result<(), NavError> {
        self.predict_covariance_with(PsdMargin::Constant)
    }

    /// [`Self::predict_covariance`], P's PSD margin kept per `margin` (the flight navigator:
    /// [`PsdMargin::Deferred`]).
    pub(crate) fn predict_covariance_with(&mut self, margin: PsdMargin) -> Result<(), NavError> {
        if self.steps_pending == 0 {
            return Ok(());
        }
        let dt_total = self.pending_interval_s(self.steps_pending, self.pending_us);
        let dv = self.dv_ned_pending_m_s;
        self.covariance_step_at(None, dt_total, &dv, margin)?;
        self.steps_pending = 0;
        self.pending_us = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        Ok(())
    }
}

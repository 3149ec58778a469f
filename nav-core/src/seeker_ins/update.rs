//! The LOS update: time check, the two scalar components gated by the shared gate
//! ([`crate::math::kalman::gate_scalar`]), fused in the simple form, feedback, counters and
//! the recovery from gate starvation.

use super::config::starved_after_us;
#[cfg(feature = "los-residual-3d")]
use super::config::LosResidual;
use super::consider::LOS_COLS;
use super::error_model::{ACC_BIAS, ATT, GIMBAL, GYRO_BIAS, POS, STATES, VEL};
use super::filter::SeekerIns;
use super::generated::los17::{rank_two_update, rank_two_variances_ok};
use super::health::LastUpdate;
use super::los_components::{skipped_report, stabilising_delta, two_components, TwoComponents};
use super::measurement::{
    landmark_vector_ned, los_model_at, validate_gimbal, GimbalAngles, LosModel,
    MIN_LANDMARK_RANGE_M,
};
use crate::contract::{FusionOutcome, FusionReport, RecoveryAction};
use crate::time::Timestamp;
use crate::{NavError, Real};
use nalgebra::SVector;

/// One seeker sample: the measured gimbal angles and when they were measured.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosSample<T> {
    /// Measurement time (the flight computer's clock, µs). Fused only within one nominal IMU
    /// interval of the INS time (else skipped, [`LosSkipReason::NotAtInsTime`]).
    pub time: Timestamp,
    /// Measured gimbal pitch and yaw, rad.
    pub gimbal: GimbalAngles<T>,
}

/// Outcome of one seeker update.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosReport<T> {
    /// Pitch-direction component (innovation rad, variance rad², NIS, fused/rejected/skipped).
    pub pitch: FusionReport<T>,
    /// Yaw-direction component.
    pub yaw: FusionReport<T>,
    /// Range from the INS position to the landmark, m (0 when not computed).
    pub range_m: T,
    /// Why a component was skipped (`None` when none was).
    pub skipped: Option<LosSkipReason>,
}

/// Why a valid LOS measurement was not fused ([`FusionOutcome::Skipped`]; nothing changed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LosSkipReason {
    /// The INS position is closer to the landmark than [`MIN_LANDMARK_RANGE_M`]: the LOS
    /// direction carries no usable information (both components skipped).
    LandmarkTooClose,
    /// The working precision cannot fuse it: innovation variance not positive and finite, or
    /// a variance that would turn negative or non-finite.
    NumericalLimit,
    /// The correction it implies is not finite (both components skipped).
    CorrectionNotFinite,
    /// The gimbal angles are valid but, corrected by the estimated gimbal errors, beyond the
    /// ±80° pitch (or ±π yaw) the LOS model accepts (both components skipped).
    GimbalBeyondLimit,
    /// The INS position is outside the range where the error model holds (health
    /// `NeedsReinitialisation`): the linearisation is not to be trusted and the update would
    /// corrupt the covariance (both components skipped until `reinitialise`).
    PositionOutOfRange,
    /// The sample is more than one nominal IMU interval away from the INS time (or no IMU
    /// sample yet): the INS was not where the seeker looked from (both components skipped).
    NotAtInsTime,
}

impl<T: Real> SeekerIns<T> {
    /// Fuses one seeker sample (gimbal angles, rad) to the configured landmark.
    ///
    /// Each of the two residual components is gated separately by the configured
    /// [`Gate`](crate::contract::Gate) (χ², 1 dof); the report says which were fused,
    /// [`SeekerIns::aid_counters`] counts them, and the recovery policy re-inflates P when the
    /// gate starves the filter. Errors (filter unchanged but for the aid's `refused` counter):
    /// `TimeNotIncreasing` (not later than the previous LOS sample), `NonFiniteInput`,
    /// `InputOutOfRange` (gimbal pitch beyond ±80°).
    ///
    /// The fusion is the simple form `P⁺ = P − k Kᵀ` (`k = P h`, `K = k / s`), not the
    /// Joseph form of [`crate::math::kalman::fuse_scalar`]: with P propagated up to date
    /// (the usual case at the seeker rate) the update works in place with no copy of P, the
    /// two scalar updates computed as rank-one terms `P⁺ = P − k₁K₁ᵀ − k₂K₂ᵀ`, checked
    /// (variances stay ≥ 0, all finite, feedback valid) and only then applied; the
    /// stabilising noise (`ρ ε`) and the conditioned r keep P PSD in f32 (module
    /// doc of [`super`]). With IMU samples pending, P is first propagated on a copy of the
    /// filter (more stack) and committed with the update.
    pub fn update_los(&mut self, sample: &LosSample<T>) -> Result<LosReport<T>, NavError> {
        self.update_los_col(sample, None)
    }

    /// [`Self::update_los`], with `col` (when given, and P up to date with the 2-D residual)
    /// updated from the very components fused (`update_los_cross`). Inlined: no frame of its
    /// own between the caller's and the update's (the flight navigator's LOS path).
    #[inline(always)]
    fn update_los_col(
        &mut self,
        sample: &LosSample<T>,
        col: Option<&mut CrossColumn<T>>,
    ) -> Result<LosReport<T>, NavError> {
        let r = self.update_los_checked(sample, col);
        match r {
            Ok(_) => self.last_los = Some(sample.time),
            Err(_) => self.los.record_refused(),
        }
        r
    }

    /// What makes [`Self::update_los`] refuse `sample` (`Err`, nothing changed but the
    /// refusal counter): not later than the previous LOS sample, gimbal angles not finite or
    /// beyond their limits. A sample that passes is not refused by `update_los` (the filter's
    /// INS state and P do not enter these checks).
    pub(crate) fn check_los(&self, sample: &LosSample<T>) -> Result<(), NavError> {
        if self.last_los.is_some_and(|t| sample.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        validate_gimbal(&sample.gimbal, self.config.seeker_noise_rad)
    }

    /// Whether `sample` is within one IMU interval of the INS time (else `update_los` skips
    /// it, `NotAtInsTime`, without propagating P).
    pub(crate) fn los_at_ins_time(&self, sample: &LosSample<T>) -> bool {
        self.ins.time().is_some_and(|t| {
            let d = t.as_micros().abs_diff(sample.time.as_micros());
            d <= self.ins.dt_us()
        })
    }

    fn update_los_checked(
        &mut self,
        sample: &LosSample<T>,
        col: Option<&mut CrossColumn<T>>,
    ) -> Result<LosReport<T>, NavError> {
        self.check_los(sample)?;
        if !self.los_at_ins_time(sample) {
            return Ok(self.skip_all(sample, T::zero(), LosSkipReason::NotAtInsTime));
        }
        if self.steps_pending > 0 {
            return self.update_los_pending(sample);
        }
        self.update_los_now(sample, col)
    }

    #[inline(never)]
    fn update_los_pending(&mut self, sample: &LosSample<T>) -> Result<LosReport<T>, NavError> {
        let mut next = *self;
        next.predict_covariance()?;
        let report = next.update_los_now(sample, None)?;
        *self = next;
        Ok(report)
    }

    /// Not inlined: one copy serves the direct and the pending-prediction paths. `col` (the
    /// 2-D residual only): updated after a committed fusion, from the same components.
    #[inline(never)]
    fn update_los_now(
        &mut self,
        sample: &LosSample<T>,
        col: Option<&mut CrossColumn<T>>,
    ) -> Result<LosReport<T>, NavError> {
        let sigma = self.config.seeker_noise_rad;
        let measured = &sample.gimbal;
        let corrected = GimbalAngles {
            pitch_rad: measured.pitch_rad - self.gimbal_bias_rad.x,
            yaw_rad: measured.yaw_rad - self.gimbal_bias_rad.y,
        };
        let s = self.ins.state();
        let d = landmark_vector_ned(&s.position, &self.config.landmark);
        let range = d.norm();
        let finite_range = if range.is_finite() { range } else { T::zero() };
        if !s.position.is_in_range() {
            return Ok(self.skip_all(sample, finite_range, LosSkipReason::PositionOutOfRange));
        }
        if !range.is_finite() || range < T::lit(MIN_LANDMARK_RANGE_M) {
            return Ok(self.skip_all(sample, finite_range, LosSkipReason::LandmarkTooClose));
        }
        if validate_gimbal(&corrected, sigma).is_err() {
            return Ok(self.skip_all(sample, range, LosSkipReason::GimbalBeyondLimit));
        }
        let gate = self.config.gate;
        let c_b_n = self.ins.c_b_n();
        #[cfg(feature = "los-residual-3d")]
        if self.config.residual == LosResidual::FullRank3d {
            return self.update_los_3d(sample, &corrected, &c_b_n, gate);
        }
        let model = los_model_at(&s.position, &d, &c_b_n, &corrected, sigma)?;
        let c = two_components(&self.p, &model, gate);
        let report = self.commit_two(sample, &model, &c);
        let fused = |r: &FusionReport<T>| r.outcome == FusionOutcome::Fused;
        if fused(&report.pitch) || fused(&report.yaw) {
            if self.consider.active {
                let committed = [fused(&report.pitch), fused(&report.yaw)];
                let cross = col.as_deref().map(|k| &k.cross);
                let at = |h: &SVector<T, STATES>| {
                    LOS_COLS.map(|i| h.get(i).copied().unwrap_or_default())
                };
                let h = [at(&model.h_pitch), at(&model.h_yaw)];
                self.consider_after_los(committed, &h, &c, cross);
            }
            if let Some(col) = col {
                cross_after_los(&report, &model, &c, col);
            }
        }
        Ok(report)
    }

    /// Checks and applies a computed 2-D update (or reports why not).
    fn commit_two(
        &mut self,
        sample: &LosSample<T>,
        model: &LosModel<T>,
        c: &TwoComponents<T>,
    ) -> LosReport<T> {
        let (fused1, fused2) = (
            c.rep1.outcome == FusionOutcome::Fused,
            c.rep2.outcome == FusionOutcome::Fused,
        );
        let skipped = (c.rep1.outcome == FusionOutcome::Skipped
            || c.rep2.outcome == FusionOutcome::Skipped)
            .then_some(LosSkipReason::NumericalLimit);
        let report = LosReport {
            pitch: c.rep1,
            yaw: c.rep2,
            range_m: model.range_m,
            skipped,
        };
        if !(fused1 || fused2) {
            self.note_no_fusion(sample, &[c.rep1.outcome, c.rep2.outcome]);
            return report;
        }
        // Check before anything changes: variances stay ≥ 0 and everything is finite.
        if !rank_two_variances_ok(&self.p.data.0, &c.k1, &c.kk1, &c.k2, &c.kk2) {
            return self.skip_attempt(sample, report, LosSkipReason::NumericalLimit);
        }
        let xv = SVector::<T, STATES>::from(c.x);
        // Feedback first: it is atomic (the INS validates before it changes) and only P, which
        // cannot fail any more, follows.
        if self.feed_back_parts(&xv).is_err() {
            return self.skip_attempt(sample, report, LosSkipReason::CorrectionNotFinite);
        }
        // P: upper triangle, mirrored (exactly symmetric).
        // The stabilising noise ([`stabilise`]) in the same pass.
        rank_two_update(
            &mut self.p.data.0,
            &c.k1,
            &c.kk1,
            &c.k2,
            &c.kk2,
            stabilising_delta(c.info_ratio),
        );
        let conditioned = u32::from(fused1 && c.cond1) + u32::from(fused2 && c.cond2);
        self.note_fusion(sample, &[c.rep1.outcome, c.rep2.outcome], conditioned);
        report
    }

    /// Counts a fusion: components by outcome, `conditioned` of them fused with raised r.
    pub(super) fn note_fusion(
        &mut self,
        sample: &LosSample<T>,
        outcomes: &[FusionOutcome],
        conditioned: u32,
    ) {
        let count = |o: FusionOutcome| outcomes.iter().filter(|x| **x == o).count() as u32;
        let c = &mut self.los;
        c.fused = c.fused.saturating_add(count(FusionOutcome::Fused));
        c.rejected = c.rejected.saturating_add(count(FusionOutcome::Rejected));
        c.skipped = c.skipped.saturating_add(count(FusionOutcome::Skipped));
        c.consecutive_rejected = 0;
        self.run_start = None;
        self.counters.conditioned = self.counters.conditioned.saturating_add(conditioned);
        self.fusion_ref = Some(sample.time);
        self.last_update = if count(FusionOutcome::Skipped) > 0 || conditioned > 0 {
            LastUpdate::Degraded
        } else {
            LastUpdate::Clean
        };
    }

    /// Every component skipped for `reason` before an attempt (nothing computed): counted,
    /// nothing else changes.
    fn skip_all(
        &mut self,
        sample: &LosSample<T>,
        range_m: T,
        reason: LosSkipReason,
    ) -> LosReport<T> {
        let none = skipped_report(T::zero());
        let report = LosReport {
            pitch: none,
            yaw: none,
            range_m,
            skipped: Some(reason),
        };
        self.note_no_fusion(sample, &[FusionOutcome::Skipped, FusionOutcome::Skipped]);
        report
    }

    /// An attempted update that cannot be committed: its fused components become skipped.
    pub(super) fn skip_attempt(
        &mut self,
        sample: &LosSample<T>,
        mut report: LosReport<T>,
        reason: LosSkipReason,
    ) -> LosReport<T> {
        for c in [&mut report.pitch, &mut report.yaw] {
            if c.outcome == FusionOutcome::Fused {
                c.outcome = FusionOutcome::Skipped;
            }
        }
        report.skipped = Some(reason);
        self.note_no_fusion(sample, &[report.pitch.outcome, report.yaw.outcome]);
        report
    }

    /// No component fused: count; when every component was rejected by the gate, count the
    /// run and apply the recovery policy once the run has lasted `starved_after_s` (from the
    /// LOS sample before the run's first rejection).
    pub(super) fn note_no_fusion(&mut self, sample: &LosSample<T>, outcomes: &[FusionOutcome]) {
        let count = |o: FusionOutcome| outcomes.iter().filter(|x| **x == o).count() as u32;
        let skipped = count(FusionOutcome::Skipped);
        let c = &mut self.los;
        c.rejected = c.rejected.saturating_add(count(FusionOutcome::Rejected));
        c.skipped = c.skipped.saturating_add(skipped);
        if skipped > 0 {
            self.last_update = LastUpdate::Degraded;
            return;
        }
        self.last_update = LastUpdate::Clean;
        if c.consecutive_rejected == 0 {
            self.run_start = Some(self.last_los.unwrap_or(sample.time));
        }
        c.consecutive_rejected = c.consecutive_rejected.saturating_add(1);
        let starved = match (starved_after_us(&self.config.recovery), self.run_start) {
            (Some(limit), Some(start)) => sample
                .time
                .micros_since(start)
                .is_some_and(|us| us >= limit),
            _ => false,
        };
        if let (true, RecoveryAction::Inflate { variance_factor }) =
            (starved, self.config.recovery.action)
        {
            self.inflate_navigation(variance_factor);
            self.los.record_recovery();
            self.run_start = None;
        }
    }

    /// `P ← D P D` with `D = diag(√f I₉, I₈)`: the navigation block (δL … φ) times f, its
    /// correlations with the rest times √f (a congruence: P stays symmetric PSD), then the
    /// variance ceilings.
    fn inflate_navigation(&mut self, f: T) {
        let sf = f.sqrt();
        for (j, col) in self.p.as_mut_slice().chunks_exact_mut(STATES).enumerate() {
            for (i, v) in col.iter_mut().enumerate() {
                match (i < 9, j < 9) {
                    (true, true) => *v *= f,
                    (false, false) => {}
                    _ => *v *= sf,
                }
            }
        }
        self.consider.scale_navigation_rows(sf);
        self.limit_variances();
    }

    /// Closed-loop feedback of δx and reset (δx = 0 afterwards; P is kept: the reset of an
    /// additive error state is the identity to first order). Atomic: on error (corrected
    /// position invalid) nothing changed.
    pub(super) fn feed_back_parts(&mut self, x: &SVector<T, STATES>) -> Result<(), NavError> {
        let v3 = |i: usize| x.fixed_rows::<3>(i).into_owned();
        let dp = v3(POS);
        self.ins.correct(
            dp.x.to_f64(),
            dp.y.to_f64(),
            dp.z.to_f64(),
            &v3(VEL),
            &v3(ATT),
        )?;
        self.accel_bias_m_s2 += v3(ACC_BIAS);
        self.gyro_bias_rad_s += v3(GYRO_BIAS);
        self.gimbal_bias_rad += x.fixed_rows::<2>(GIMBAL);
        Ok(())
    }
}

impl<T: Real> SeekerIns<T> {
    /// After a committed 2-D LOS update whose components `c` (gains `kk1`, `kk2`, zero for a
    /// component not fused, of the rows `h`, their values at `LOS_COLS`; `committed` the
    /// fused ones) were computed against P before it: `P_xc` (and, with `cross` the column of
    /// a state kept beside the 17 as it was before the update, `P_ec`) corrected per fused
    /// component, the second against the first's result, in one pass
    /// (`ConsiderCross::after_los_pair`, module `consider`). Not inlined: the update's frame
    /// does not carry it (the stand-alone filter without consider parameters never calls it).
    #[inline(never)]
    fn consider_after_los(
        &mut self,
        committed: [bool; 2],
        h: &[[T; LOS_COLS.len()]; 2],
        c: &TwoComponents<T>,
        cross: Option<&SVector<T, STATES>>,
    ) {
        let inv = |fused: bool, rep: &FusionReport<T>| {
            if fused {
                T::one() / rep.innovation_variance
            } else {
                T::zero()
            }
        };
        let inv_s = [inv(committed[0], &c.rep1), inv(committed[1], &c.rep2)];
        self.consider
            .after_los_pair(h, [&c.kk1, &c.kk2], cross.map(|cr| (cr, inv_s)));
    }
}

#[cfg(test)]
#[path = "update_tests.rs"]
mod tests;

/// A covariance column `c = E[δx δb]` and variance `s = var(δb)` of a state b kept beside the
/// 17 (the flight navigator's baro error), with the correction of b's estimate accumulated by
/// updates (`δb̂`, to be subtracted from b̂ by the owner).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CrossColumn<T> {
    pub(crate) cross: SVector<T, STATES>,
    pub(crate) variance: T,
    pub(crate) correction: T,
}

impl<T: Real> CrossColumn<T> {
    /// The correlation forgotten (`c ← 0`): the joint covariance stays PSD.
    pub(crate) fn forget(&mut self) {
        self.cross = SVector::zeros();
    }
}

impl<T: Real> SeekerIns<T> {
    /// [`SeekerIns::update_los`] with the column of a state kept beside the 17 updated as the
    /// 18-state sequential update would (b does not enter the LOS: `h_aug = [h, 0]`):
    /// per fused component, `g = h c`, `c ← c − K g`, `s ← s − g²/S`, `δb̂ += g ν / S` with the
    /// component's gain `K = P h / S`, S and ν as fused (the second against the first's
    /// result). The column is formed from the very components the update fused (computed
    /// once, against P before the update; no copy of the filter); the filter's own update is
    /// `update_los`'s, unchanged. When P
    /// changed otherwise (pending IMU samples propagated first, a recovery inflation, the 3-D
    /// residual) the correlation is forgotten (`c ← 0`). Errors as `update_los` (the column
    /// unchanged).
    pub(crate) fn update_los_cross(
        &mut self,
        sample: &LosSample<T>,
        col: &mut CrossColumn<T>,
    ) -> Result<LosReport<T>, NavError> {
        let recoveries = self.los.recoveries;
        let projected_2d = self.steps_pending == 0 && {
            #[cfg(feature = "los-residual-3d")]
            {
                self.config.residual == LosResidual::Projected2d
            }
            #[cfg(not(feature = "los-residual-3d"))]
            {
                true
            }
        };
        let report = self.update_los_col(sample, projected_2d.then_some(&mut *col))?;
        let fused = |r: &FusionReport<T>| r.outcome == FusionOutcome::Fused;
        if !(fused(&report.pitch) || fused(&report.yaw)) {
            if self.los.recoveries != recoveries {
                col.forget();
            }
        } else if !projected_2d {
            col.forget();
        }
        Ok(report)
    }
}

/// The column after the fused components of `report`, in place (forgotten, `c ← 0` with `s`
/// and `δb̂` as they were, when it cannot be formed): the components `c` of `model` as computed
/// against P before the update.
fn cross_after_los<T: Real>(
    report: &LosReport<T>,
    model: &LosModel<T>,
    c: &TwoComponents<T>,
    col: &mut CrossColumn<T>,
) {
    let (variance, correction) = (col.variance, col.correction);
    let steps = [
        (&report.pitch, &c.rep1, &model.h_pitch, &c.kk1),
        (&report.yaw, &c.rep2, &model.h_yaw, &c.kk2),
    ];
    for (committed, rep, h, kk) in steps {
        if committed.outcome != FusionOutcome::Fused {
            continue;
        }
        let g = h.dot(&col.cross);
        let inv_s = T::one() / rep.innovation_variance;
        col.cross -= SVector::<T, STATES>::from(*kk) * g;
        col.variance -= g * g * inv_s;
        col.correction += g * inv_s * rep.innovation;
    }
    let ok = col.variance >= T::zero()
        && col.variance.is_finite()
        && col.correction.is_finite()
        && crate::math::checks::all_finite(col.cross.as_slice());
    if !ok {
        col.variance = variance;
        col.correction = correction;
        col.forget();
    }
}

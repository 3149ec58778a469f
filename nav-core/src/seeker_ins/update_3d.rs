//! The comparison LOS residual ([`super::LosResidual::FullRank3d`]): three scalar updates with
//! the shared Joseph-form [`fuse_scalar`] on a copy of the filter.

use super::error_model::STATES;
use super::filter::SeekerIns;
use super::los_components::{
    conditioned_noise, information_ratio, max_information_ratio, skipped_report, stabilise,
};
use super::measurement::{los_model_3d, GimbalAngles};
use super::update::{LosReport, LosSample, LosSkipReason};
use crate::contract::{FusionOutcome, FusionReport, Gate};
use crate::math::kalman::fuse_scalar;
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector};

impl<T: Real> SeekerIns<T> {
    /// Three scalar updates with the shared `fuse_scalar` on a copy (not inlined: its copy of
    /// the filter stays out of the 2-D path's stack frame). The same conditioning of r; a
    /// component `fuse_scalar` cannot fuse is skipped.
    #[inline(never)]
    pub(super) fn update_los_3d(
        &mut self,
        sample: &LosSample<T>,
        corrected: &GimbalAngles<T>,
        c_b_n: &nalgebra::Matrix3<T>,
        gate: Gate<T>,
    ) -> Result<LosReport<T>, NavError> {
        let mut next = *self;
        let s = next.ins.state();
        let model = los_model_3d(
            &s.position,
            c_b_n,
            corrected,
            &self.config.landmark,
            self.config.seeker_noise_rad,
        )?;
        let mut x = SVector::<T, STATES>::zeros();
        let r = model.variance_rad2;
        let kappa = max_information_ratio::<T>();
        let mut conditioned = 0u32;
        let mut info_ratio = T::zero();
        let mut fuse = |x: &mut SVector<T, STATES>,
                        p: &mut SMatrix<T, STATES, STATES>,
                        h: &SVector<T, STATES>,
                        z: T|
         -> FusionReport<T> {
            let nu = z - h.dot(x);
            let hph = (*p * h).dot(h);
            let (r_eff, cond) = conditioned_noise(hph, r, kappa);
            match fuse_scalar(x, p, h, nu, r_eff, gate) {
                Ok(rep) => {
                    if cond && rep.outcome == FusionOutcome::Fused {
                        conditioned += 1;
                    }
                    info_ratio = info_ratio.max(information_ratio(&rep, hph, r_eff));
                    rep
                }
                Err(_) => skipped_report(nu),
            }
        };
        let n = fuse(&mut x, &mut next.p, &model.h_north, model.residual.x);
        let e = fuse(&mut x, &mut next.p, &model.h_east, model.residual.y);
        let d = fuse(&mut x, &mut next.p, &model.h_down, model.residual.z);
        let outcomes = [n.outcome, e.outcome, d.outcome];
        let any_skipped = outcomes.contains(&FusionOutcome::Skipped);
        let report = LosReport {
            pitch: n,
            yaw: e,
            range_m: model.range_m,
            skipped: any_skipped.then_some(LosSkipReason::NumericalLimit),
        };
        if outcomes.contains(&FusionOutcome::Fused) {
            if next.feed_back_parts(&x).is_err() {
                return Ok(self.skip_attempt(sample, report, LosSkipReason::CorrectionNotFinite));
            }
            stabilise(&mut next.p, info_ratio);
            next.note_fusion(sample, &outcomes, conditioned);
        } else {
            next.note_no_fusion(sample, &outcomes);
        }
        *self = next;
        Ok(report)
    }
}

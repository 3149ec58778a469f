//! The rare paths of a step: an IMU interval longer than 1.5 nominal intervals (sub-steps, an
//! exact inertial coast) or longer than [`super::MAX_BRIDGED_GAP_S`] (re-anchoring).

use super::core::{LoopCore, NewSamples, StepReports, SubStep, MAX_BRIDGED_GAP_US};
use super::samples::{AidChannel, ImuSample};
use super::MAX_SUBSTEPS;
use crate::contract::Health;
use crate::time::{micros_to_seconds, Timestamp};
use crate::{NavError, Real};
use nalgebra::Vector3;

impl<T: Real> LoopCore<T> {
    /// An interval longer than 1.5 dt (rare path, on a copy): sub-steps, a coast first if
    /// longer than [`super::MAX_SUBSTEPS`] intervals, or a re-anchoring beyond
    /// [`super::MAX_BRIDGED_GAP_S`]. The new aid samples enter the last sub-step.
    #[cold]
    #[inline(never)]
    pub(crate) fn bridge(
        &mut self,
        us: u64,
        imu: &ImuSample<T>,
        samples: &NewSamples<T>,
    ) -> Result<StepReports<T>, NavError> {
        let mut tmp = *self;
        let f = imu.specific_force_up_m_s2;
        let dt_us = self.dt_us.max(1);
        if us > MAX_BRIDGED_GAP_US {
            // Not integrated: keep the state, restart the clock one interval before the
            // sample, drop the held aid samples and re-anchor on the next ones.
            tmp.time = Timestamp::from_micros(imu.time.as_micros().saturating_sub(dt_us));
            tmp.baro = AidChannel::after_long_gap();
            tmp.velocity = AidChannel::after_long_gap();
            Health::bump(&mut tmp.health.gaps_reset);
            // The covariance grows open-loop over the gap (its last interval is the step).
            tmp.sigma.tick(us.saturating_sub(dt_us), false, false);
            let reports = tmp.advance_outlined(imu.time, dt_us, f, samples)?;
            *self = tmp;
            return Ok(reports);
        }
        let max_sub = u64::from(MAX_SUBSTEPS);
        let sub_span = max_sub.saturating_mul(dt_us);
        let (n, coast_us) = if us > sub_span.saturating_add(dt_us / 2) {
            (max_sub, us.saturating_sub(sub_span))
        } else {
            (
                us.saturating_add(dt_us / 2).checked_div(dt_us).unwrap_or(2),
                0,
            )
        };
        let n = n.clamp(2, max_sub);
        if coast_us > 0 {
            tmp.coast(coast_us, f);
            tmp.sigma.tick(coast_us, false, false);
        }
        let start = tmp.time;
        let span = us.saturating_sub(coast_us);
        for i in 1..n {
            let end = start.add_micros(span.saturating_mul(i).checked_div(n).unwrap_or(0));
            let h = end.micros_since(tmp.time).unwrap_or(0);
            tmp.advance_outlined(end, h, f, &NewSamples::NONE)?;
        }
        let h = imu.time.micros_since(tmp.time).unwrap_or(0);
        let reports = tmp.advance_outlined(imu.time, h, f, samples)?;
        Health::bump(&mut tmp.health.gaps_bridged);
        *self = tmp;
        Ok(StepReports {
            // n ≤ MAX_SUBSTEPS: the conversion cannot truncate.
            imu_intervals: n as u32,
            ..reports
        })
    }

    /// One bridged sub-step ([`Self::advance`] from the current state).
    #[inline(always)]
    fn advance_outlined(
        &mut self,
        now: Timestamp,
        h_us: u64,
        specific_force: T,
        samples: &NewSamples<T>,
    ) -> Result<StepReports<T>, NavError> {
        let sub = SubStep {
            x: self.x,
            h_ref: self.h_ref_m,
            now,
            h_us,
            specific_force,
            bridged: true,
        };
        self.advance(&sub, samples)
    }

    /// Exact inertial coast over `us` µs on the specific force `f` (no aid; gravity at the
    /// mid-interval altitude).
    #[inline(never)]
    fn coast(&mut self, us: u64, f: T) {
        let h = micros_to_seconds::<T>(us);
        let half = T::lit(0.5);
        let (alt, v, b) = (self.x.x, self.x.y, self.x.z);
        let g = self.gravity.gravity_m_s2(self.h_ref_m + alt + v * h * half);
        let rate = f - g + self.feedback.bias_sign * b;
        let x_new = Vector3::new(alt + h * (v + half * h * rate), v + h * rate, b);
        self.settle(x_new, self.h_ref_m);
        self.time = self.time.add_micros(us);
    }
}

//! Health of the seeker INS: the [`HealthState`] derived from the state, P and the clocks,
//! the per-aid counters and the few counters that do not fit [`crate::contract::Health`].

use super::config::{AID_TIMEOUT_US, VARIANCE_CEILING};

/// 99 % of the navigation states' [`VARIANCE_CEILING`]s, computed at compile time (the health
/// check runs every step; on the f32 target an f64 product per state is emulated).
const NAV_CEILING_99: [f64; 9] = {
    let [a, b, c, d, e, f, g, h, i, ..] = VARIANCE_CEILING;
    [
        0.99 * a,
        0.99 * b,
        0.99 * c,
        0.99 * d,
        0.99 * e,
        0.99 * f,
        0.99 * g,
        0.99 * h,
        0.99 * i,
    ]
};
use super::filter::SeekerIns;
use crate::contract::AidCounters;
use crate::{HealthState, Real};

/// The aids of the seeker INS, for [`SeekerIns::aid_counters`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SeekerAid {
    /// The seeker's line of sight to the landmark. Each scalar LOS component counts once in
    /// `fused`, `rejected` and `skipped`; `consecutive_rejected` counts LOS samples in a row
    /// with every component rejected (the run the [`crate::contract::RecoveryPolicy`]
    /// watches), `recoveries` the covariance inflations, `refused` the samples refused with
    /// an error.
    Los,
}

/// Counters of the seeker INS beyond [`crate::contract::Health`] (all saturating). Where the
/// rest went: a bridged IMU gap bumps `Health::gaps_bridged`, a gap beyond
/// `ImuFaultPolicy::max_gap_s` `Health::gaps_reset`, a navigation variance brought back to
/// its ceiling or a propagated variance that rounded below zero `Health::limits_hit`, a
/// refused IMU sample `Health::imu_refused`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SeekerCounters {
    /// LOS components fused with r raised to the precision limit (the module doc's
    /// conditioned update).
    pub conditioned: u32,
    /// IMU samples bridged by the hold (the sum of the bridged gaps' missing samples).
    pub held_samples: u32,
    /// IMU samples flagged clipped and integrated with the clipping inflation.
    pub clipped_samples: u32,
    /// IMU samples integrated with the position outside the model range.
    pub out_of_range_samples: u32,
}

/// How the last LOS update went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum LastUpdate {
    /// None since construction or re-initialisation.
    None,
    /// Every component fused or rejected, none conditioned or skipped.
    Clean,
    /// A component was conditioned or skipped.
    Degraded,
}

impl<T: Real> SeekerIns<T> {
    /// How far the solution can be trusted now:
    ///
    /// * `Initialising`: no IMU sample since construction or re-initialisation;
    /// * `NeedsReinitialisation`: the position is outside the model range (|L| ≥ 86°,
    ///   |h| ≥ 1000 km), or a navigation variance is at its ceiling ([`VARIANCE_CEILING`]:
    ///   the filter knows nothing there any more, e.g. after a gap too long to bridge). The
    ///   filter keeps running (and comes back by itself if LOS updates bring the state and P
    ///   back), but its solution is not to be used until then or until `reinitialise`;
    /// * `Degraded`: no LOS component fused for [`super::AID_TIMEOUT_S`], the gate rejecting
    ///   every component of the last LOS samples, the last update conditioned or skipped, or
    ///   an IMU gap or clipped sample within the last [`super::AID_TIMEOUT_S`];
    /// * `Nominal` otherwise.
    pub(super) fn health_state(&self) -> HealthState {
        let Some(now) = self.ins.time() else {
            return HealthState::Initialising;
        };
        let at_ceiling = NAV_CEILING_99
            .iter()
            .enumerate()
            .any(|(i, m)| self.p.get((i, i)).is_some_and(|v| *v >= T::lit(*m)));
        if at_ceiling || !self.ins.state().position.is_in_range() {
            return HealthState::NeedsReinitialisation;
        }
        let since = |t: Option<_>| t.and_then(|t| now.micros_since(t));
        let aid_lost = since(self.fusion_ref).is_some_and(|us| us > AID_TIMEOUT_US);
        let imu_fault = since(self.last_imu_fault).is_some_and(|us| us <= AID_TIMEOUT_US);
        if aid_lost
            || imu_fault
            || self.los.consecutive_rejected > 0
            || self.last_update == LastUpdate::Degraded
        {
            return HealthState::Degraded;
        }
        HealthState::Nominal
    }

    /// Counters of one aid ([`SeekerAid`] says what each counts).
    pub fn aid_counters(&self, aid: SeekerAid) -> AidCounters {
        match aid {
            SeekerAid::Los => self.los,
        }
    }

    /// The counters that do not fit [`crate::contract::Health`].
    pub fn seeker_counters(&self) -> SeekerCounters {
        self.counters
    }
}

//! The seeker INS's aids, its per-aid counters, the few counters that do not fit
//! [`crate::contract::Health`] and the kind of the last update (the [`crate::HealthState`]
//! derived from them, the state, P and the clocks is in `filter`).

/// The aids of the seeker INS, for [`super::SeekerIns::aid_counters`].
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

//! The hand-over's accelerometer-bias start: the EKF's bias states from the flight
//! alignment's difference-bias estimate (behind [`HAND_OVER_BIAS_ESTIMATE`]), and their
//! reference specific force (the carry's).
use super::{diag_times, symmetrised, times_diag, NavBlocks};
use crate::Real;
use nalgebra::{Matrix3, Vector3};

/// Hands the flight alignment's difference-bias estimate over to the EKF's
/// accelerometer-bias states (estimate `−β b̂`, covariance from the alignment's `P_bb`;
/// module doc) instead of starting them at zero with the priors' σ. Off: measured (README,
/// "The alignment's bias prior, and the bias hand-over measured").
pub const HAND_OVER_BIAS_ESTIMATE: bool = false;

/// The EKF's accelerometer-bias start from the alignment ([`NavBlocks::bias_start`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BiasStart<T> {
    /// Estimate of the slave's equivalent bias at the carry's force, m/s².
    pub(crate) estimate_m_s2: Vector3<T>,
    /// Its error covariance, (m/s²)².
    pub(crate) covariance_m2_s4: Matrix3<T>,
}

impl<T: Real> NavBlocks<T> {
    /// The EKF's accelerometer-bias start from the alignment's estimate
    /// ([`HAND_OVER_BIAS_ESTIMATE`]; module doc): estimate `−β b̂` and covariance
    /// `diag(β) P_bb diag(β) + diag(β σ_bm²)` (`σ_bm² = total − ab − v`, the master's part
    /// of the prior), which holds the share at the carry's force already. `None` without the
    /// switch or without a difference-bias state (then the priors' `ab`).
    pub(crate) fn bias_start(&self, ab: T) -> Option<BiasStart<T>> {
        if HAND_OVER_BIAS_ESTIMATE {
            self.bias_start_from_estimate(ab)
        } else {
            None
        }
    }

    /// [`Self::bias_start`] whatever the switch: `None` without a difference-bias state.
    pub(crate) fn bias_start_from_estimate(&self, ab: T) -> Option<BiasStart<T>> {
        let var = &self.bias_prior_variance_m2_s4;
        if !var.iter().any(|v| *v > T::zero()) {
            return None;
        }
        let beta = self.beta(ab);
        let master = var.zip_zip_map(&self.slave_share_m2_s4, &beta, |total, share, b| {
            (total - ab - share).max(T::zero()) * b
        });
        let c = diag_times(&beta, &times_diag(&self.bias_covariance_m2_s4, &beta));
        // The level axes' misalignment share: `M_yz f_z` enters df_y as a tilt `θ_x f_z`
        // does (and `M_xz f_z` df_x as `θ_y f_z`), for every f, so the alignment's b̂ cannot
        // hold it (it goes with θ̂): its variance at the carry's force (the share `v` on X, Y)
        // is added as the EKF adds it without the hand-over.
        let level = Vector3::new(
            self.slave_share_m2_s4.x,
            self.slave_share_m2_s4.y,
            T::zero(),
        );
        Some(BiasStart {
            estimate_m_s2: -self.bias_m_s2.component_mul(&beta),
            covariance_m2_s4: symmetrised(&c) + Matrix3::from_diagonal(&(master + level)),
        })
    }
}

/// The carry's specific force as the reference of the new EKF's accelerometer-bias states
/// (`SeekerIns::set_specific_force_reference`): the alignment levelled the slave against its
/// own accelerometers at the carry's specific force, so the equivalent bias `b + (S + M) f`
/// the EKF starts from is the one of that force, not of the drop's first covariance step.
/// `f_slave_m_s2`: the last fused master epoch's lever-arm-compensated specific force in slave
/// axes, m/s². Always `true` (the hand-over stands: a force the EKF refuses leaves its first
/// step's specific force as the reference).
pub(crate) fn refer_to_carry<T: Real>(
    ekf: &mut Option<crate::seeker_ins::SeekerIns<T>>,
    f_slave_m_s2: &Vector3<T>,
    bias_start: Option<&BiasStart<T>>,
) -> bool {
    if let Some(e) = ekf.as_mut() {
        // Refused only for a non-finite force (the master's samples are checked finite) or a
        // reference already set (a new EKF has none): nothing to undo either way.
        let _ = match bias_start {
            // P0's bias block holds the share at the carry's force already.
            Some(b) => e.start_accel_bias_at(&b.estimate_m_s2, f_slave_m_s2),
            None => e.set_specific_force_reference(f_slave_m_s2),
        };
    }
    true
}

#[cfg(test)]
mod tests {
    use super::super::tests::{alignment, master, LEVER, PRIORS};
    use super::super::{hand_over, hand_over_nav};
    use super::*;
    use crate::seeker_ins::ACC_BIAS;

    /// The EKF's accelerometer-bias start from the alignment's estimate (behind
    /// [`HAND_OVER_BIAS_ESTIMATE`], module doc): `−β b̂`, covariance `diag(β) P_bb diag(β) +
    /// diag(β σ_bm²)` plus the level axes' misalignment share; none without a bias state; with
    /// the switch off the P0's bias block is the priors' diagonal.
    #[test]
    fn bias_start_from_the_alignment_estimate() {
        let a = alignment();
        let nav = hand_over_nav(&master(), &a, &LEVER, &PRIORS).unwrap();
        let ab = PRIORS.accel_bias_sigma_m_s2.powi(2);
        let v = a.slave_share_variance_m2_s4;
        let total = a.bias_prior_variance_m2_s4;
        let beta = Vector3::from_fn(|i, _| (ab + v[i]) / total[i]);
        let start = nav.blocks.bias_start_from_estimate(ab).unwrap();
        let want_b = -a.bias_m_s2.component_mul(&beta);
        assert!((start.estimate_m_s2 - want_b).norm() <= 1e-15 * want_b.norm());
        let db = Matrix3::from_diagonal(&beta);
        let master_part = Vector3::from_fn(|i, _| beta[i] * (total[i] - ab - v[i]));
        let level = Vector3::new(v.x, v.y, 0.0);
        let want =
            db * a.bias_covariance_m2_s4 * db + Matrix3::from_diagonal(&(master_part + level));
        assert!(
            (start.covariance_m2_s4 - want).norm() <= 1e-12 * want.norm(),
            "{} vs {want}",
            start.covariance_m2_s4
        );
        assert_eq!(start.covariance_m2_s4, start.covariance_m2_s4.transpose());
        assert!(start.covariance_m2_s4.cholesky().is_some());
        let mut none = a;
        none.bias_prior_variance_m2_s4 = Vector3::zeros();
        let nav_none = hand_over_nav(&master(), &none, &LEVER, &PRIORS).unwrap();
        assert!(nav_none.blocks.bias_start_from_estimate(ab).is_none());
        let out = hand_over(&master(), &a, &LEVER, &PRIORS).unwrap();
        let bb = out
            .covariance
            .fixed_view::<3, 3>(ACC_BIAS, ACC_BIAS)
            .into_owned();
        if HAND_OVER_BIAS_ESTIMATE {
            assert_eq!(bb, start.covariance_m2_s4);
        } else {
            assert_eq!(bb, Matrix3::from_diagonal_element(ab));
        }
    }
}

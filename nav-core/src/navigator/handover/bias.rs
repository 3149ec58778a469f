//! The hand-over's accelerometer-bias start: the EKF's bias states from the flight
//! alignment's difference-bias estimate (behind [`HAND_OVER_BIAS_ESTIMATE`]), and their
//! reference specific force (the carry's).
use super::{diag_times, symmetrised, times_diag, HandoverPriors, NavBlocks};
use crate::seeker_ins::{ACC_BIAS, STATES};
use crate::transfer_alignment::TransferAlignment;
use crate::Real;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Hands the flight alignment's difference-bias estimate over to the EKF's
/// accelerometer-bias states (estimate `−β b̂`, covariance from the alignment's `P_bb`;
/// module doc) instead of starting them at zero with the priors' σ. Off: measured (README,
/// "The alignment's bias prior, and the bias hand-over measured").
pub const HAND_OVER_BIAS_ESTIMATE: bool = false;

/// The EKF's accelerometer-bias start from the alignment ([`bias_start`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct BiasStart<T> {
    /// Estimate of the slave's equivalent bias at the carry's force, m/s².
    pub(crate) estimate_m_s2: Vector3<T>,
    /// Its error covariance, (m/s²)².
    pub(crate) covariance_m2_s4: Matrix3<T>,
}

impl<T: Real> BiasStart<T> {
    /// Writes the bias block of a hand-over P0 (after [`NavBlocks::write_p0`], which wrote
    /// the priors' diagonal there).
    pub(crate) fn write_into(&self, p0: &mut SMatrix<T, STATES, STATES>) {
        p0.fixed_view_mut::<3, 3>(ACC_BIAS, ACC_BIAS)
            .copy_from(&self.covariance_m2_s4);
    }
}

/// The EKF's accelerometer-bias start from the alignment's estimate `b̂` (`estimate_m_s2`,
/// m/s²) with error covariance `p_bb` ((m/s²)²), read from the alignment at the separation
/// tick (it has not changed since the last master sample): estimate `−β b̂` and covariance
/// `diag(β) P_bb diag(β) + diag(β σ_bm²)` (`σ_bm² = total − ab − v`, the master's part of the
/// prior; `ab` the slave's bias prior variance, (m/s²)²), plus the level axes' misalignment
/// share (below); it holds the share at the carry's force already. `None` without a
/// difference-bias state. Used with [`HAND_OVER_BIAS_ESTIMATE`] only.
pub(crate) fn bias_start<T: Real>(
    blocks: &NavBlocks<T>,
    estimate_m_s2: &Vector3<T>,
    p_bb: &Matrix3<T>,
    ab: T,
) -> Option<BiasStart<T>> {
    let var = &blocks.bias_prior_variance_m2_s4;
    if !var.iter().any(|v| *v > T::zero()) {
        return None;
    }
    let share = &blocks.slave_share_m2_s4;
    let beta = blocks.beta(ab);
    let master = var.zip_zip_map(share, &beta, |total, v, b| {
        (total - ab - v).max(T::zero()) * b
    });
    let c = diag_times(&beta, &times_diag(p_bb, &beta));
    // The level axes' misalignment share: `M_yz f_z` enters df_y as a tilt `θ_x f_z` does
    // (and `M_xz f_z` df_x as `θ_y f_z`), for every f, so the alignment's b̂ cannot hold it
    // (it goes with θ̂): its variance at the carry's force (the share `v` on X, Y) is added
    // as the EKF adds it without the hand-over.
    let level = Vector3::new(share.x, share.y, T::zero());
    Some(BiasStart {
        estimate_m_s2: -estimate_m_s2.component_mul(&beta),
        covariance_m2_s4: symmetrised(&c) + Matrix3::from_diagonal(&(master + level)),
    })
}

/// [`bias_start`] from the alignment `ta` (its bias estimate and covariance now: unchanged
/// since the last master sample's hand-over blocks `blocks`) and the slave's bias prior of
/// `priors`, with [`HAND_OVER_BIAS_ESTIMATE`]; `None` without it (the priors' diagonal).
pub(crate) fn alignment_bias_start<T: Real, const K: usize, const N: usize>(
    ta: &TransferAlignment<T, K, N>,
    blocks: &NavBlocks<T>,
    priors: &HandoverPriors<T>,
) -> Option<BiasStart<T>> {
    if !HAND_OVER_BIAS_ESTIMATE {
        return None;
    }
    let ab = priors.accel_bias_sigma_m_s2 * priors.accel_bias_sigma_m_s2;
    let p_bb = ta.accel_bias_covariance();
    ta.accel_bias()
        .and_then(|(b, _)| bias_start(blocks, &b, &p_bb, ab))
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

    /// The EKF's accelerometer-bias start from the alignment's estimate (behind
    /// [`HAND_OVER_BIAS_ESTIMATE`], module doc): `−β b̂`, covariance `diag(β) P_bb diag(β) +
    /// diag(β σ_bm²)` plus the level axes' misalignment share, written over P0's bias block;
    /// none without a bias state.
    #[test]
    fn bias_start_from_the_alignment_estimate() {
        let a = alignment();
        let nav = hand_over_nav(&master(), &a, &LEVER, &PRIORS).unwrap();
        let ab = PRIORS.accel_bias_sigma_m_s2.powi(2);
        let v = a.slave_share_variance_m2_s4;
        let total = a.bias_prior_variance_m2_s4;
        let beta = Vector3::from_fn(|i, _| (ab + v[i]) / total[i]);
        let b_hat = Vector3::new(2e-4, -1e-4, 3e-4);
        let p_bb = Matrix3::new(5.0, 1.0, 0.0, 1.0, 4.0, 0.5, 0.0, 0.5, 9.0) * 1e-8;
        let start = bias_start(&nav.blocks, &b_hat, &p_bb, ab).unwrap();
        let want_b = -b_hat.component_mul(&beta);
        assert!((start.estimate_m_s2 - want_b).norm() <= 1e-15 * want_b.norm());
        let db = Matrix3::from_diagonal(&beta);
        let master_part = Vector3::from_fn(|i, _| beta[i] * (total[i] - ab - v[i]));
        let level = Vector3::new(v.x, v.y, 0.0);
        let want = db * p_bb * db + Matrix3::from_diagonal(&(master_part + level));
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
        assert!(bias_start(&nav_none.blocks, &b_hat, &p_bb, ab).is_none());
        // Written over the priors' diagonal of a hand-over P0.
        let mut p0 = hand_over(&master(), &a, &LEVER, &PRIORS)
            .unwrap()
            .covariance;
        start.write_into(&mut p0);
        let bb = p0.fixed_view::<3, 3>(ACC_BIAS, ACC_BIAS).into_owned();
        assert_eq!(bb, start.covariance_m2_s4);
    }
}

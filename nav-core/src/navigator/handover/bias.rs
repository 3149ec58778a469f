//! The hand-over's accelerometer-bias reference: the specific force the EKF's bias states
//! refer to (the carry's). The states start from the priors (zero estimate); handing over the
//! flight alignment's difference-bias estimate was measured and removed (module doc of
//! [`super`], docs/navigator.md, "The bias hand-over, measured again").
use crate::Real;
use nalgebra::Vector3;

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
) -> bool {
    if let Some(e) = ekf.as_mut() {
        // Refused only for a non-finite force (the master's samples are checked finite) or a
        // reference already set (a new EKF has none): nothing to undo either way.
        let _ = e.set_specific_force_reference(f_slave_m_s2);
    }
    true
}

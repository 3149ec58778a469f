//! The navigator's configuration-time design: the alignment filter's discretised chains, the
//! EKF's noise PSDs and (with [`BaroDamping::InertialLoop`]) the baro-inertial loop's design —
//! computed on the ground by [`Navigator::design`](super::Navigator::design) and stored, so a
//! flight image built with [`Navigator::from_design`](super::Navigator::from_design) links
//! none of the design code (discretisation, Riccati solver, f64 gravity fit).

use super::types::{BaroDamping, NavigatorConfig, INERTIAL_LOOP};
use crate::design::{DesignValues, ValueReader, ValueWriter, BAD_VALUES};
use crate::seeker_ins::{design_stamp, SeekerInsDesign};
use crate::transfer_alignment::{flexure_share_variance, slave_share_variance, TaConfig, TaDesign};
use crate::vertical_channel::{classical_stamp, ClassicalDesign};
use crate::{NavError, Real};
use nalgebra::Vector3;

/// The slave accelerometers' scale-factor and misalignment share of the alignment's
/// difference-bias prior per axis X, Y, Z, (m/s²)²: the variance of `(S + M) f` at level
/// carry's specific force for the EKF's instrument errors (`config.ins.instrument_errors`: the
/// same accelerometers), [`slave_share_variance`].
pub(super) fn slave_share<T: Real>(config: &NavigatorConfig<T>) -> Vector3<T> {
    let e = &config.ins.instrument_errors;
    slave_share_variance(e.accel_scale_factor, e.accel_misalignment_rad)
}

/// The slave accelerometers' scale-factor share of the alignment's θ̂ through the flexure's
/// lever-arm acceleration, rad² ([`flexure_share_variance`]; the EKF's instrument errors, the
/// nominal lever arm), about the slave's Z axis only: in carry the level axes are known from
/// gravity (`g θ`, far above the pylon's acceleration), the heading from the lever arm.
pub(super) fn flexure_share<T: Real>(config: &NavigatorConfig<T>) -> Vector3<T> {
    let s = config.ins.instrument_errors.accel_scale_factor;
    let v = flexure_share_variance(s, &config.lever_arm.nominal_m);
    Vector3::new(T::zero(), T::zero(), v.z)
}

/// The alignment filter's configuration as the navigator runs it: `config.alignment` (whose
/// `accel_bias_sigma_m_s2` is the instruments' own biases, master and slave) with the
/// slave's scale-factor and misalignment share of level carry added to the bias prior
/// ([`TaConfig::with_slave_share`]): the difference bias the alignment estimates is the
/// master's minus the slave's *equivalent* bias `b_s + (S + M) f`, ≈ 1 g times the scale
/// factor on the down axis. Without instrument errors `config.alignment` itself. A sum beyond
/// [`crate::transfer_alignment::MAX_ACCEL_BIAS_SIGMA_M_S2`] is refused where the navigator
/// designs its alignment (`InvalidConfig { field: "accel_bias_sigma_m_s2" }`).
pub fn alignment_config<T: Real>(config: &NavigatorConfig<T>) -> TaConfig<T> {
    let e = &config.ins.instrument_errors;
    config
        .alignment
        .with_slave_share(e.accel_scale_factor, e.accel_misalignment_rad)
}

/// The designs a [`Navigator`](super::Navigator) is built from (see the module doc).
///
/// Stored as [`DesignValues`]: the alignment's values ([`TaDesign`]), the EKF's
/// ([`SeekerInsDesign`]), one flag (1: a baro-loop design follows, 0: none) and the
/// [`ClassicalDesign`]'s values (zeros when the flag is 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigatorDesign<T: Real, const K: usize> {
    /// The transfer-alignment filter's design (for [`alignment_config`]: `config.alignment`
    /// with the slave's scale-factor and misalignment share in its bias prior).
    pub alignment: TaDesign<T, K>,
    /// The 17-state EKF's design (for `config.ins`).
    pub ins: SeekerInsDesign<T>,
    /// The baro-inertial loop's design (`Some` exactly with [`BaroDamping::InertialLoop`]).
    pub baro_loop: Option<ClassicalDesign<T>>,
}

impl<T: Real, const K: usize> NavigatorDesign<T, K> {
    /// The EKF's design is the one of `config.ins` (stamp) with finite PSDs ≥ 0, as the EKF
    /// checks it when it starts at release — here already at construction. Errors:
    /// `InvalidConfig { field: "design", issue: DesignMismatch | OutOfRange }`.
    pub(super) fn check_ins(&self, config: &NavigatorConfig<T>) -> Result<(), NavError> {
        self.ins.stamp.check(&design_stamp(&config.ins))?;
        for v in [self.ins.accel_psd_m2_s3, self.ins.gyro_psd_rad2_s] {
            if !v.is_finite() || v < T::zero() {
                return Err(NavError::InvalidConfig {
                    field: "design",
                    issue: crate::error::ConfigIssue::OutOfRange,
                });
            }
        }
        Ok(())
    }

    /// Checks the parts the alignment and the EKF do not check themselves at construction:
    /// the baro-loop design is present exactly when the configuration asks for the loop, and
    /// is the loop's (stamp). Errors: `InvalidConfig { field: "design.baro_loop" }` (missing or
    /// superfluous), `InvalidConfig { field: "design", issue: DesignMismatch }` (stamp).
    pub(super) fn check_baro_loop(&self, config: &NavigatorConfig<T>) -> Result<(), NavError> {
        match (&config.baro, &self.baro_loop) {
            (BaroDamping::InertialLoop(c), Some(d)) if INERTIAL_LOOP => {
                d.stamp().check(&classical_stamp(c))
            }
            (BaroDamping::InertialLoop(_), _)
            | (BaroDamping::Off | BaroDamping::Ekf(_), Some(_)) => Err(NavError::InvalidConfig {
                field: "design.baro_loop",
                issue: crate::error::ConfigIssue::DesignMismatch,
            }),
            (BaroDamping::Off | BaroDamping::Ekf(_), None) => Ok(()),
        }
    }
}

impl<T: Real, const K: usize> DesignValues for NavigatorDesign<T, K> {
    const COUNT: usize =
        TaDesign::<T, K>::COUNT + SeekerInsDesign::<T>::COUNT + 1 + ClassicalDesign::<T>::COUNT;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        if out.len() != Self::COUNT {
            return Err(NavError::CapacityExceeded);
        }
        let cap = NavError::CapacityExceeded;
        let (ta, rest) = out
            .split_at_mut_checked(TaDesign::<T, K>::COUNT)
            .ok_or(cap)?;
        let (ins, rest) = rest
            .split_at_mut_checked(SeekerInsDesign::<T>::COUNT)
            .ok_or(cap)?;
        let (flag, lp) = rest.split_at_mut_checked(1).ok_or(cap)?;
        self.alignment.write_values(ta)?;
        self.ins.write_values(ins)?;
        let mut w = ValueWriter::new(flag, 1)?;
        w.push(if self.baro_loop.is_some() { 1.0 } else { 0.0 });
        w.finish()?;
        match &self.baro_loop {
            Some(d) => d.write_values(lp),
            None => {
                lp.fill(0.0);
                Ok(())
            }
        }
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        if values.len() != Self::COUNT {
            return Err(BAD_VALUES);
        }
        let (ta, rest) = values
            .split_at_checked(TaDesign::<T, K>::COUNT)
            .ok_or(BAD_VALUES)?;
        let (ins, rest) = rest
            .split_at_checked(SeekerInsDesign::<T>::COUNT)
            .ok_or(BAD_VALUES)?;
        let (flag, lp) = rest.split_at_checked(1).ok_or(BAD_VALUES)?;
        let flag = ValueReader::new(flag, 1)?.value()?;
        // Without the feature `baro-inertial-loop` a design with a loop is refused here (its
        // reading not linked).
        let baro_loop = if flag == 1.0 && INERTIAL_LOOP {
            Some(ClassicalDesign::read_values(lp)?)
        } else if flag == 0.0 {
            None
        } else {
            return Err(BAD_VALUES);
        };
        Ok(Self {
            alignment: TaDesign::read_values(ta)?,
            ins: SeekerInsDesign::read_values(ins)?,
            baro_loop,
        })
    }
}

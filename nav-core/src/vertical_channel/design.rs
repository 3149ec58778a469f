//! The configuration-time designs of the loops (see [`crate::design`]): gains (pole placement
//! or continuous ARE, `f64`), the exact discretisation of the four aid modes, the gravity fit
//! at the latitude and (aided loop) the design innovation variances, stamped with the
//! configuration they were computed for.
//!
//! [`ClassicalDesign::compute`] / [`AidedDesign::compute`] (= [`crate::Estimator::design`])
//! run the design code (f64, `sin`, Riccati, matrix exponentials); `from_design` only checks
//! and copies the stored result, so a flight build that uses it links none of the design code.

use super::config::{AidedConfig, ClassicalConfig};
use super::core::StepValues;
use super::envelope::{check_imu_dt, check_period, LoopModel};
use super::gains::{AidedGains, ClassicalGains};
use super::gravity::GravityModel;
use super::modes::{discretise_modes, open_loop, Mode, Modes};
use super::sigma::{ErrorModel, SigmaDesign, SigmaInputs, VerticalSigma};
use crate::contract::{DesignStamp, Fingerprint};
use crate::design::{ValueReader, ValueWriter, BAD_VALUES};
use crate::error::ConfigIssue;
use crate::math::checks::all_finite_parts;
use crate::{NavError, Real};
use nalgebra::{Matrix3, Matrix3x2};

/// Layout version of [`ClassicalDesign`]'s value list.
pub const CLASSICAL_DESIGN_VERSION: u16 = 3;
/// Layout version of [`AidedDesign`]'s value list.
pub const AIDED_DESIGN_VERSION: u16 = 3;

/// The stamp a classical design for `config` carries: [`CLASSICAL_DESIGN_VERSION`] and the
/// fingerprint of `imu_dt_s, latitude_rad, tau_s, baro_lag_s, baro_period_s` and the
/// [`ErrorModel`]'s fields in that order.
pub fn classical_stamp<T: Real>(config: &ClassicalConfig<T>) -> DesignStamp {
    let c = config;
    let f = Fingerprint::new()
        .real(c.imu_dt_s)
        .real(c.latitude_rad)
        .real(c.tau_s)
        .real(c.baro_lag_s)
        .real(c.baro_period_s);
    DesignStamp {
        version: CLASSICAL_DESIGN_VERSION,
        fingerprint: error_model_print(f, &c.error_model).finish(),
    }
}

fn error_model_print<T: Real>(mut f: Fingerprint, m: &ErrorModel<T>) -> Fingerprint {
    for v in m.values() {
        f = f.real(v);
    }
    f
}

/// The stamp an aided design for `config` carries: [`AIDED_DESIGN_VERSION`] and the
/// fingerprint of `imu_dt_s, latitude_rad, accel_noise_m_s2_rt_hz, accel_bias_rw_m_s2_rt_s,
/// baro_noise_m, baro_period_s, baro_lag_s, velocity_noise_m_s, velocity_period_s` and the
/// [`ErrorModel`]'s fields in that order.
pub fn aided_stamp<T: Real>(config: &AidedConfig<T>) -> DesignStamp {
    let c = config;
    let f = Fingerprint::new()
        .real(c.imu_dt_s)
        .real(c.latitude_rad)
        .real(c.accel_noise_m_s2_rt_hz)
        .real(c.accel_bias_rw_m_s2_rt_s)
        .real(c.baro_noise_m)
        .real(c.baro_period_s)
        .real(c.baro_lag_s)
        .real(c.velocity_noise_m_s)
        .real(c.velocity_period_s);
    DesignStamp {
        version: AIDED_DESIGN_VERSION,
        fingerprint: error_model_print(f, &c.error_model).finish(),
    }
}

fn write_stamp(w: &mut ValueWriter<'_>, s: &DesignStamp) {
    w.push(f64::from(s.version));
    w.push(f64::from(s.fingerprint));
}

/// Reads a stamp (two exact integers).
fn read_stamp(r: &mut ValueReader<'_>) -> Result<DesignStamp, NavError> {
    let v = r.value()?;
    let f = r.value()?;
    let (version, fingerprint) = (v as u16, f as u32);
    if f64::from(version) != v || f64::from(fingerprint) != f {
        return Err(BAD_VALUES);
    }
    Ok(DesignStamp {
        version,
        fingerprint,
    })
}

impl<T: Real> StepValues<T> {
    fn new(imu_dt_s: f64, baro_lag_s: f64) -> Self {
        Self {
            dt_s: T::lit(imu_dt_s),
            half_dt_s: T::lit(0.5 * imu_dt_s),
            baro_lag_s: T::lit(baro_lag_s),
        }
    }

    /// The design's step values must be those of the configuration (compares only),
    /// positive (lag non-negative).
    fn check(&self, imu_dt_s: T, baro_lag_s: T) -> Result<(), NavError> {
        if !(self.dt_s == imu_dt_s && self.dt_s > T::zero() && self.half_dt_s > T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.imu_dt_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        if !(self.baro_lag_s == baro_lag_s && self.baro_lag_s >= T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.baro_lag_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        Ok(())
    }

    fn write(&self, w: &mut ValueWriter<'_>) {
        w.real(self.dt_s);
        w.real(self.half_dt_s);
        w.real(self.baro_lag_s);
    }
}

fn write_gravity<T: Real>(w: &mut ValueWriter<'_>, g: &GravityModel<T>) {
    w.real(g.g0_m_s2);
    w.real(g.g1_per_s2);
    w.real(g.g2_per_m_s2);
}

/// The gravity model, the step values and the `N` values they were read from.
type GravityStep<T, const N: usize> = (GravityModel<T>, StepValues<T>, [T; N]);

/// Reads `N ≥ 6` values of the float type through one looping reader ([`ValueReader::fill`]):
/// the gravity model and the step values (the first six), and all `N` values.
fn read_gravity_step<T: Real, const N: usize>(
    r: &mut ValueReader<'_>,
) -> Result<GravityStep<T, N>, NavError> {
    let mut v = [T::zero(); N];
    r.fill(&mut v)?;
    let [g0_m_s2, g1_per_s2, g2_per_m_s2, dt_s, half_dt_s, baro_lag_s, ..] = *v.as_slice() else {
        return Err(BAD_VALUES);
    };
    Ok((
        GravityModel {
            g0_m_s2,
            g1_per_s2,
            g2_per_m_s2,
        },
        StepValues {
            dt_s,
            half_dt_s,
            baro_lag_s,
        },
        v,
    ))
}

/// Number of values of [`Modes`]: Φ_baro (9), then N and G (6 each) of the modes none, baro,
/// velocity, both.
const MODES_COUNT: usize = 9 + 4 * 12;

fn write_modes<T: Real>(w: &mut ValueWriter<'_>, m: &Modes<T>) {
    w.matrix(&m.phi_baro);
    for mode in [&m.none, &m.baro, &m.velocity, &m.both] {
        w.matrix(&mode.n);
        w.matrix(&mode.g);
    }
}

#[inline(never)]
fn read_modes<T: Real>(r: &mut ValueReader<'_>) -> Result<Modes<T>, NavError> {
    let z = Matrix3x2::<T>::zeros();
    let zm = Mode { n: z, g: z };
    let mut m = Modes {
        phi_baro: Matrix3::zeros(),
        none: zm,
        baro: zm,
        velocity: zm,
        both: zm,
    };
    // Same order as `write_modes` (one looping reader for all nine matrices).
    r.fill_parts(&mut [
        m.phi_baro.as_mut_slice(),
        m.none.n.as_mut_slice(),
        m.none.g.as_mut_slice(),
        m.baro.n.as_mut_slice(),
        m.baro.g.as_mut_slice(),
        m.velocity.n.as_mut_slice(),
        m.velocity.g.as_mut_slice(),
        m.both.n.as_mut_slice(),
        m.both.g.as_mut_slice(),
    ])?;
    Ok(m)
}

/// Out of line: both designs' checks share one copy.
#[inline(never)]
fn modes_finite<T: Real>(m: &Modes<T>) -> bool {
    all_finite_parts(&[
        m.phi_baro.as_slice(),
        m.none.n.as_slice(),
        m.none.g.as_slice(),
        m.baro.n.as_slice(),
        m.baro.g.as_slice(),
        m.velocity.n.as_slice(),
        m.velocity.g.as_slice(),
        m.both.n.as_slice(),
        m.both.g.as_slice(),
    ])
}

#[cold]
#[inline(never)]
fn not_finite() -> NavError {
    NavError::InvalidConfig {
        field: "design",
        issue: ConfigIssue::NotFinite,
    }
}

/// One value per aid of the aided loop (baro, velocity aid); the method returning it gives the
/// quantity and its units.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidPair<T> {
    /// The baro's value (altitude unit: m, m²).
    pub baro: T,
    /// The velocity aid's value (vertical velocity unit: m/s, (m/s)²).
    pub velocity: T,
}

/// Precomputed design of a [`super::ClassicalLoop`]: its stamp, the pole-placement gains
/// (`f64` data, for reporting only), the discretised aid modes, the gravity model and the
/// step values in the loop's float type `T`.
///
/// Obtained from [`ClassicalDesign::compute`] or
/// [`DesignValues::read_values`](crate::design::DesignValues::read_values) only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicalDesign<T: Real> {
    pub(crate) stamp: DesignStamp,
    pub(crate) gains: ClassicalGains,
    pub(crate) modes: Modes<T>,
    pub(crate) gravity: GravityModel<T>,
    pub(crate) step: StepValues<T>,
    pub(crate) sigma: SigmaDesign<T>,
}

impl<T: Real> ClassicalDesign<T> {
    /// Validates the configuration (IMU interval, timeouts, latitude, τ, C4, baro period;
    /// the values widened to `f64`), fits the gravity model at the latitude, places the poles
    /// (seed eq. 1), checks the envelope and discretises the four aid modes exactly at
    /// `imu_dt_s`.
    pub fn compute(config: &ClassicalConfig<T>) -> Result<Self, NavError> {
        let dt = config.imu_dt_s.to_f64();
        let lag = config.baro_lag_s.to_f64();
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        let gravity = GravityModel::at_latitude(config.latitude_rad.to_f64())?;
        let gains = ClassicalGains::pole_placement(config.tau_s.to_f64(), lag, gravity.c_per_s2())?;
        let period = check_period("baro_period_s", config.baro_period_s.to_f64(), dt)?;
        let (k, c) = gains.observer();
        let loop_ = LoopModel {
            a0: open_loop(-1.0),
            k,
            c,
            lag,
            bias_sign: -1.0,
            c_grav: gravity.c_per_s2(),
            dt,
        };
        if !loop_.multirate_stable(Some(period), None)? {
            return Err(NavError::InvalidConfig {
                field: "tau_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        loop_.check_intervals()?;
        let modes = discretise_modes::<T>(&open_loop(-1.0), &k, &c, dt)?;
        config.error_model.validate()?;
        let sigma = SigmaDesign::compute(
            &SigmaInputs {
                bias_sign: -1.0,
                c_grav: gravity.c_per_s2(),
                k: &k,
                c: &c,
                imu_dt_s: dt,
                baro_period_s: config.baro_period_s.to_f64(),
                velocity_period_s: config.baro_period_s.to_f64(),
                design_uses_velocity: false,
            },
            &config.error_model.cast(),
        )?;
        Ok(Self {
            stamp: classical_stamp(config),
            gains,
            modes,
            gravity: gravity.cast(),
            step: StepValues::new(dt, lag),
            sigma,
        })
    }

    /// The steady-state σ of (altitude, vertical velocity) the design implies under the
    /// configuration's [`ErrorModel`] (discrete Lyapunov equation of the closed loop).
    pub fn steady_sigma(&self) -> VerticalSigma<T> {
        self.sigma.steady_sigma()
    }
    /// The steady-state covariance of `[δh, δV_z, δb, m]` (m², (m/s)², (m/s²)², m²; m the
    /// baro's correlated error).
    pub fn steady_covariance(&self) -> nalgebra::Matrix4<T> {
        self.sigma.p_steady
    }

    /// The configuration stamp.
    pub fn stamp(&self) -> DesignStamp {
        self.stamp
    }
    /// The pole-placement gains.
    pub fn gains(&self) -> &ClassicalGains {
        &self.gains
    }
    /// The gravity model in the loop's float type.
    pub fn gravity(&self) -> &GravityModel<T> {
        &self.gravity
    }
    /// The IMU interval the modes were discretised at, s.
    pub fn imu_dt_s(&self) -> T {
        self.step.dt_s
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.modes.phi_baro
    }

    /// Checks the design against the configuration (stamp, step values) and its own
    /// finiteness (used by `from_design`; compares only).
    pub(crate) fn check(&self, config: &ClassicalConfig<T>) -> Result<(), NavError> {
        self.stamp.check(&classical_stamp(config))?;
        self.step.check(config.imu_dt_s, config.baro_lag_s)?;
        if !(modes_finite(&self.modes) && self.gravity.is_finite() && self.sigma.is_finite()) {
            return Err(not_finite());
        }
        Ok(())
    }
}

/// Precomputed design of an [`super::AidedLoop`]: its stamp, the Riccati gains (`f64` data,
/// for reporting), the discretised aid modes, the gravity model, the step values and the
/// design innovation variances, in the loop's float type `T`.
///
/// Obtained from [`AidedDesign::compute`] or
/// [`DesignValues::read_values`](crate::design::DesignValues::read_values) only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidedDesign<T: Real> {
    pub(crate) stamp: DesignStamp,
    pub(crate) gains: AidedGains,
    pub(crate) modes: Modes<T>,
    pub(crate) gravity: GravityModel<T>,
    pub(crate) step: StepValues<T>,
    pub(crate) baro_innovation_variance: T,
    pub(crate) velocity_innovation_variance: T,
    pub(crate) sigma: SigmaDesign<T>,
}

impl<T: Real> AidedDesign<T> {
    /// Validates the configuration (the values widened to `f64`), solves the continuous ARE
    /// for the gains (seed eqs. 8-9), fits the gravity model, checks the envelope,
    /// discretises the four aid modes exactly at `imu_dt_s` and computes the design
    /// innovation variances `C P Cᵀ + σ²` of both aids.
    pub fn compute(config: &AidedConfig<T>) -> Result<Self, NavError> {
        let dt = config.imu_dt_s.to_f64();
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        config.velocity_timeouts.validate(
            "velocity_timeouts.stale_after_s",
            "velocity_timeouts.lost_after_s",
        )?;
        let gains = AidedGains::design(config)?;
        let gravity = GravityModel::at_latitude(config.latitude_rad.to_f64())?;
        let tb = check_period("baro_period_s", config.baro_period_s.to_f64(), dt)?;
        let tv = check_period("velocity_period_s", config.velocity_period_s.to_f64(), dt)?;
        let lag = config.baro_lag_s.to_f64();
        let loop_ = LoopModel {
            a0: open_loop(1.0),
            k: gains.k,
            c: gains.c,
            lag,
            bias_sign: 1.0,
            c_grav: gravity.c_per_s2(),
            dt,
        };
        // The design mode (both aids). A single-aid mode is what the joint design leaves when
        // the other aid drops out: the velocity aid alone cannot hold the altitude (its error
        // diverges slowly through gravity's c δh in any design), and the baro column of a
        // design that leans on the velocity aid can be slowly unstable alone too; the health
        // says `Degraded` while an aid is lost.
        if !loop_.multirate_stable(Some(tb), Some(tv))? {
            return Err(NavError::InvalidConfig {
                field: if tb >= tv {
                    "baro_period_s"
                } else {
                    "velocity_period_s"
                },
                issue: ConfigIssue::OutOfRange,
            });
        }
        loop_.check_intervals()?;
        let modes = discretise_modes::<T>(&open_loop(1.0), &gains.k, &gains.c, dt)?;
        let cb = gains.c.row(0).transpose();
        let (sh, sv) = (
            config.baro_noise_m.to_f64(),
            config.velocity_noise_m_s.to_f64(),
        );
        let bv = (cb.transpose() * gains.p * cb).x + sh * sh;
        let vv = gains.p.m22 + sv * sv;
        config.error_model.validate()?;
        let sigma = SigmaDesign::compute(
            &SigmaInputs {
                bias_sign: 1.0,
                c_grav: gravity.c_per_s2(),
                k: &gains.k,
                c: &gains.c,
                imu_dt_s: dt,
                baro_period_s: config.baro_period_s.to_f64(),
                velocity_period_s: config.velocity_period_s.to_f64(),
                design_uses_velocity: true,
            },
            &config.error_model.cast(),
        )?;
        Ok(Self {
            stamp: aided_stamp(config),
            gains,
            modes,
            gravity: gravity.cast(),
            step: StepValues::new(dt, lag),
            baro_innovation_variance: T::lit(bv),
            velocity_innovation_variance: T::lit(vv),
            sigma,
        })
    }

    /// The steady-state σ of (altitude, vertical velocity) the design implies under the
    /// configuration's [`ErrorModel`] (discrete Lyapunov equation of the closed loop; unlike
    /// the Riccati P of the gains it includes the baro's correlated error).
    pub fn steady_sigma(&self) -> VerticalSigma<T> {
        self.sigma.steady_sigma()
    }
    /// The steady-state covariance of `[δh, δV_z, δb, m]` (m², (m/s)², (m/s²)², m²).
    pub fn steady_covariance(&self) -> nalgebra::Matrix4<T> {
        self.sigma.p_steady
    }

    /// The configuration stamp.
    pub fn stamp(&self) -> DesignStamp {
        self.stamp
    }
    /// The Riccati design.
    pub fn gains(&self) -> &AidedGains {
        &self.gains
    }
    /// The gravity model in the loop's float type.
    pub fn gravity(&self) -> &GravityModel<T> {
        &self.gravity
    }
    /// The IMU interval the modes were discretised at, s.
    pub fn imu_dt_s(&self) -> T {
        self.step.dt_s
    }
    /// Design innovation variances (baro m², velocity (m/s)²): `C P Cᵀ + σ²`.
    pub fn innovation_variances(&self) -> AidPair<T> {
        AidPair {
            baro: self.baro_innovation_variance,
            velocity: self.velocity_innovation_variance,
        }
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.modes.phi_baro
    }

    /// Checks the design against the configuration (stamp, step values) and its own values
    /// (used by `from_design`; compares only).
    pub(crate) fn check(&self, config: &AidedConfig<T>) -> Result<(), NavError> {
        self.stamp.check(&aided_stamp(config))?;
        self.step.check(config.imu_dt_s, config.baro_lag_s)?;
        let AidPair {
            baro: bv,
            velocity: vv,
        } = self.innovation_variances();
        if !(modes_finite(&self.modes)
            && self.gravity.is_finite()
            && self.sigma.is_finite()
            && bv.is_finite()
            && vv.is_finite())
        {
            return Err(not_finite());
        }
        if !(bv > T::zero() && vv > T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.innovation_variances",
                issue: ConfigIssue::NotPositive,
            });
        }
        Ok(())
    }
}

#[path = "design_values.rs"]
mod values;

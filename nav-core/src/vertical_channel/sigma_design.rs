//! The design-time σ (`f64`, on the ground): each mode's continuous error dynamics, their
//! exact discretisation over the covariance interval, the design mode's steady state (discrete
//! Lyapunov equation) and the stored value list of a [`SigmaDesign`].

use super::super::modes::open_loop;
use super::{
    CovStep, ErrorModel, SigmaDesign, SigmaInputs, VerticalSigma, COVARIANCE_INTERVAL_S,
    LYAPUNOV_DOUBLINGS,
};
use crate::design::{ValueReader, ValueWriter, BAD_VALUES};
use crate::error::ConfigIssue;
use crate::math::checks::all_finite;
use crate::math::discretize::discretize;
use crate::{NavError, Real};
use nalgebra::{Matrix2, Matrix3, Matrix4, Vector4};

/// One mode's covariance step in the float type and its (Φ, Q) in `f64`.
type StepF64<T> = (CovStep<T>, Matrix4<f64>, Matrix4<f64>);

/// Continuous error dynamics (F, Q_c) of one aid mode (module documentation).
pub(crate) fn error_dynamics(
    inp: &SigmaInputs<'_>,
    model: &ErrorModel<f64>,
    baro: bool,
    velocity: bool,
) -> (Matrix4<f64>, Matrix4<f64>) {
    let mut k = *inp.k;
    if !baro {
        k.set_column(0, &nalgebra::Vector3::zeros());
    }
    if !velocity {
        k.set_column(1, &nalgebra::Vector3::zeros());
    }
    let mut a: Matrix3<f64> = open_loop(inp.bias_sign);
    a.m21 = inp.c_grav;
    let f3 = a - k * inp.c;
    let mut f = Matrix4::zeros();
    f.fixed_view_mut::<3, 3>(0, 0).copy_from(&f3);
    f.fixed_view_mut::<3, 1>(0, 3).copy_from(&k.column(0));
    f.m44 = -1.0 / model.baro_markov_tau_s;
    let r = Matrix2::from_diagonal(&nalgebra::Vector2::new(
        model.baro_noise_m * model.baro_noise_m * inp.baro_period_s,
        model.velocity_noise_m_s * model.velocity_noise_m_s * inp.velocity_period_s,
    ));
    let krk = k * r * k.transpose();
    let mut q = Matrix4::zeros();
    q.fixed_view_mut::<3, 3>(0, 0).copy_from(&krk);
    q.m22 += model.accel_noise_m_s2_rt_hz * model.accel_noise_m_s2_rt_hz;
    q.m33 += model.accel_bias_rw_m_s2_rt_s * model.accel_bias_rw_m_s2_rt_s;
    q.m44 = 2.0 * model.baro_markov_sigma_m * model.baro_markov_sigma_m / model.baro_markov_tau_s;
    (f, q)
}

/// Solves `P = Φ P Φᵀ + Q` by doubling (`Φ` stable); `NotConverged` otherwise.
pub(crate) fn discrete_lyapunov(
    phi: &Matrix4<f64>,
    q: &Matrix4<f64>,
) -> Result<Matrix4<f64>, NavError> {
    let mut a = *phi;
    let mut p = *q;
    for i in 0..LYAPUNOV_DOUBLINGS {
        p += a * p * a.transpose();
        a = a * a;
        let na = a.abs().max();
        if !(na.is_finite() && p.iter().all(|v| v.is_finite())) {
            break;
        }
        if na < 1.0e-18 {
            return Ok((p + p.transpose()) * 0.5);
        }
        if i + 1 == LYAPUNOV_DOUBLINGS {
            break;
        }
    }
    Err(NavError::NotConverged {
        iterations: LYAPUNOV_DOUBLINGS,
    })
}

impl<T: Real> SigmaDesign<T> {
    /// The σ design of a loop (f64): per-mode covariance steps over the covariance interval,
    /// the design mode's steady state, the initial covariance.
    pub(crate) fn compute(
        inp: &SigmaInputs<'_>,
        model: &ErrorModel<f64>,
    ) -> Result<Self, NavError> {
        let n = libm::round(COVARIANCE_INTERVAL_S / inp.imu_dt_s).max(1.0);
        let tc = n * inp.imu_dt_s;
        let interval_us = libm::round(tc * 1.0e6);
        if !(1.0..1.0e12).contains(&interval_us) {
            return Err(NavError::InvalidConfig {
                field: "imu_dt_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        let step = |baro: bool, velocity: bool| -> Result<StepF64<T>, NavError> {
            let (f, qc) = error_dynamics(inp, model, baro, velocity);
            let (phi, q) = discretize(&f, &qc, tc)?;
            let q = (q + q.transpose()) * 0.5;
            Ok((
                CovStep {
                    phi: phi.cast::<T>(),
                    q: q.cast::<T>(),
                },
                phi,
                q,
            ))
        };
        let (none, _, _) = step(false, false)?;
        let (baro, phi_b, q_b) = step(true, false)?;
        let (velocity, _, _) = step(false, true)?;
        let (both, phi_bv, q_bv) = step(true, true)?;
        let (phi_d, q_d) = if inp.design_uses_velocity {
            (phi_bv, q_bv)
        } else {
            (phi_b, q_b)
        };
        let p_steady = discrete_lyapunov(&phi_d, &q_d)?;
        let p_initial = Matrix4::from_diagonal(&Vector4::new(
            model.initial_altitude_sigma_m * model.initial_altitude_sigma_m,
            model.initial_vz_sigma_m_s * model.initial_vz_sigma_m_s,
            model.accel_bias_sigma_m_s2 * model.accel_bias_sigma_m_s2,
            model.baro_markov_sigma_m * model.baro_markov_sigma_m,
        ));
        let lag = -inp.c.m12;
        let d = Self {
            interval_us: interval_us as u64,
            none,
            baro,
            velocity,
            both,
            design_uses_velocity: inp.design_uses_velocity,
            p_steady: p_steady.cast::<T>(),
            p_initial: p_initial.cast::<T>(),
            baro_var: T::lit(model.baro_noise_m * model.baro_noise_m),
            velocity_var: T::lit(model.velocity_noise_m_s * model.velocity_noise_m_s),
            lag_s: T::lit(lag),
        };
        if !d.is_finite() {
            return Err(NavError::InvalidConfig {
                field: "error_model",
                issue: ConfigIssue::NotFinite,
            });
        }
        Ok(d)
    }

    pub(crate) fn is_finite(&self) -> bool {
        let m = [
            &self.none.phi,
            &self.none.q,
            &self.baro.phi,
            &self.baro.q,
            &self.velocity.phi,
            &self.velocity.q,
            &self.both.phi,
            &self.both.q,
            &self.p_steady,
            &self.p_initial,
        ];
        m.iter().all(|m| all_finite(m.as_slice()))
            && all_finite(&[self.baro_var, self.velocity_var, self.lag_s])
    }

    /// σ of the steady state (altitude m, vertical velocity m/s).
    pub(crate) fn steady_sigma(&self) -> VerticalSigma<T> {
        VerticalSigma {
            altitude_m: self.p_steady.m11.sqrt(),
            vz_m_s: self.p_steady.m22.sqrt(),
        }
    }

    pub(crate) fn write(&self, w: &mut ValueWriter<'_>) {
        // An integer below 10¹²: exact in f64.
        w.push(self.interval_us as f64);
        for s in [&self.none, &self.baro, &self.velocity, &self.both] {
            w.matrix(&s.phi);
            w.matrix(&s.q);
        }
        w.push(if self.design_uses_velocity { 1.0 } else { 0.0 });
        w.matrix(&self.p_steady);
        w.matrix(&self.p_initial);
        w.real(self.baro_var);
        w.real(self.velocity_var);
        w.real(self.lag_s);
    }

    #[inline(never)]
    pub(crate) fn read(r: &mut ValueReader<'_>) -> Result<Self, NavError> {
        let us = r.value()?;
        let interval_us = us as u64;
        if !(us >= 1.0 && interval_us as f64 == us) {
            return Err(BAD_VALUES);
        }
        let z = CovStep {
            phi: Matrix4::zeros(),
            q: Matrix4::zeros(),
        };
        let mut d = Self {
            interval_us,
            none: z,
            baro: z,
            velocity: z,
            both: z,
            design_uses_velocity: false,
            p_steady: Matrix4::zeros(),
            p_initial: Matrix4::zeros(),
            baro_var: T::zero(),
            velocity_var: T::zero(),
            lag_s: T::zero(),
        };
        r.fill_parts(&mut [
            d.none.phi.as_mut_slice(),
            d.none.q.as_mut_slice(),
            d.baro.phi.as_mut_slice(),
            d.baro.q.as_mut_slice(),
            d.velocity.phi.as_mut_slice(),
            d.velocity.q.as_mut_slice(),
            d.both.phi.as_mut_slice(),
            d.both.q.as_mut_slice(),
        ])?;
        let flag = r.value()?;
        d.design_uses_velocity = match flag {
            1.0 => true,
            0.0 => false,
            _ => return Err(BAD_VALUES),
        };
        let mut tail = [T::zero(); 3];
        r.fill_parts(&mut [
            d.p_steady.as_mut_slice(),
            d.p_initial.as_mut_slice(),
            &mut tail,
        ])?;
        let [baro_var, velocity_var, lag_s] = tail;
        d.baro_var = baro_var;
        d.velocity_var = velocity_var;
        d.lag_s = lag_s;
        Ok(d)
    }
}

//! Closed-loop 17-state error-state EKF of the seeker-aided INS (spec, seed Fig. 2).
//!
//! * [`SeekerIns::propagate`] (every IMU sample): removes the estimated biases from the
//!   increments, advances the INS ([`super::mechanization`]) and every
//!   `covariance_interval_steps` samples propagates P over the accumulated interval
//!   ([`super::error_model::propagate_covariance_sparse`], F at the current state and the mean
//!   specific force of the interval).
//! * [`SeekerIns::update_los`] (seeker rate): first propagates P over any pending interval,
//!   then fuses the two LOS residual components ([`super::measurement`]) as sequential scalar
//!   Joseph updates with a χ² gate, feeds the estimate back (position, velocity, attitude into
//!   the INS; biases and gimbal errors into the compensations) and resets δx to zero.
//!
//! Because δx is zero after every feedback, the prediction only propagates P.
//! Every method that returns an error leaves the whole filter exactly as it was.

use super::error_model::{
    propagate_covariance_sparse, SparseF, ACC_BIAS, ATT, GIMBAL, GYRO_BIAS, POS, STATES, VEL,
};
use super::measurement::{los_model, los_model_3d, GimbalAngles, Landmark};
use super::mechanization::{ImuIncrement, Ins, InsState};
use crate::error::ConfigIssue;
use crate::math::kalman::{fuse_scalar, FusionOutcome, FusionReport, Gate};
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector, Vector2, Vector3};

/// Filter configuration. σ are standard deviations, densities are √PSD.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeekerInsConfig<T> {
    /// IMU sample interval, s.
    pub imu_dt_s: T,
    /// Covariance propagation every this many IMU samples (≥ 1); e.g. 10 at 100 Hz → 10 Hz.
    pub covariance_interval_steps: u16,
    /// Accelerometer white noise density (velocity random walk), m/s²/√Hz.
    pub accel_noise_density_m_s2_rt_hz: T,
    /// Gyro white noise density (angle random walk), rad/s/√Hz = rad/√s.
    pub gyro_noise_density_rad_s_rt_hz: T,
    /// Seeker gimbal-angle white noise, 1σ per angle, rad.
    pub seeker_noise_rad: T,
    /// χ² (1 degree of freedom) gate on each scalar component's NIS, e.g. 16 (4σ).
    pub gate_nis: T,
    /// The landmark the seeker tracks.
    pub landmark: Landmark<T>,
    /// Residual form (the spec's first open point; [`LosResidual::Projected2d`] is the design
    /// choice, the other is kept for comparison).
    pub residual: LosResidual,
}

/// Form of the LOS residual fused by [`SeekerIns::update_los`].
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LosResidual {
    /// Two components in the plane normal to the LOS, `R = diag(σ², σ² cos² θ_s)`
    /// ([`super::measurement::los_model`]).
    #[default]
    Projected2d,
    /// The NED 3-vector with full-rank `R = σ² I₃` ([`super::measurement::los_model_3d`]);
    /// the report's `pitch`/`yaw` then hold the N and E components, the D component is fused
    /// as well but reported only through the state.
    FullRank3d,
}

/// Outcome of one seeker update.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosReport<T> {
    /// Pitch-direction component (innovation rad, variance rad², NIS, fused/rejected).
    pub pitch: FusionReport<T>,
    /// Yaw-direction component.
    pub yaw: FusionReport<T>,
    /// Range from the INS position to the landmark, m.
    pub range_m: T,
}

/// The seeker-aided INS: INS + error covariance + bias and gimbal-error compensations.
#[derive(Debug, Clone, Copy)]
pub struct SeekerIns<T> {
    ins: Ins<T>,
    p: SMatrix<T, STATES, STATES>,
    accel_bias_m_s2: Vector3<T>,
    gyro_bias_rad_s: Vector3<T>,
    gimbal_bias_rad: Vector2<T>,
    steps_pending: u16,
    dv_ned_pending_m_s: Vector3<T>,
    q_accel: T,
    q_gyro: T,
    config: SeekerInsConfig<T>,
}

impl<T: Real> PartialEq for SeekerIns<T> {
    fn eq(&self, o: &Self) -> bool {
        self.ins == o.ins
            && self.p == o.p
            && self.accel_bias_m_s2 == o.accel_bias_m_s2
            && self.gyro_bias_rad_s == o.gyro_bias_rad_s
            && self.gimbal_bias_rad == o.gimbal_bias_rad
            && self.steps_pending == o.steps_pending
            && self.dv_ned_pending_m_s == o.dv_ned_pending_m_s
            && self.config == o.config
    }
}

impl<T: Real> SeekerIns<T> {
    /// Filter at the initial INS state with initial covariance `p0` (units of the error state,
    /// see the module [`super`] doc).
    ///
    /// Errors: `InvalidConfig` (non-positive interval, densities, σ or gate; zero
    /// `covariance_interval_steps`), `InvalidTimeStep`, `NonFiniteInput`,
    /// `CovarianceNotPositiveSemiDefinite` (p0 not symmetric PSD).
    pub fn new(
        config: SeekerInsConfig<T>,
        initial: InsState<T>,
        p0: &SMatrix<T, STATES, STATES>,
    ) -> Result<Self, NavError> {
        use crate::error::{require_non_negative, require_positive};
        require_positive("imu_dt_s", config.imu_dt_s)?;
        require_non_negative(
            "accel_noise_density_m_s2_rt_hz",
            config.accel_noise_density_m_s2_rt_hz,
        )?;
        require_non_negative(
            "gyro_noise_density_rad_s_rt_hz",
            config.gyro_noise_density_rad_s_rt_hz,
        )?;
        require_positive("seeker_noise_rad", config.seeker_noise_rad)?;
        require_positive("gate_nis", config.gate_nis)?;
        if config.covariance_interval_steps == 0 {
            return Err(NavError::InvalidConfig {
                field: "covariance_interval_steps",
                issue: ConfigIssue::NotPositive,
            });
        }
        if !p0.iter().all(|v| v.is_finite()) {
            return Err(NavError::NonFiniteInput { input: "p0" });
        }
        if crate::math::kalman::asymmetry(p0) > T::zero()
            || !crate::math::kalman::is_psd(p0, T::lit(1e-6))
        {
            return Err(NavError::CovarianceNotPositiveSemiDefinite);
        }
        let ins = Ins::new(initial, config.imu_dt_s)?;
        let a = config.accel_noise_density_m_s2_rt_hz;
        let g = config.gyro_noise_density_rad_s_rt_hz;
        Ok(Self {
            ins,
            p: *p0,
            accel_bias_m_s2: Vector3::zeros(),
            gyro_bias_rad_s: Vector3::zeros(),
            gimbal_bias_rad: Vector2::zeros(),
            steps_pending: 0,
            dv_ned_pending_m_s: Vector3::zeros(),
            q_accel: a * a,
            q_gyro: g * g,
            config,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &SeekerInsConfig<T> {
        &self.config
    }

    /// Navigation state (after all feedback so far).
    pub fn state(&self) -> &InsState<T> {
        self.ins.state()
    }

    /// The INS.
    pub fn ins(&self) -> &Ins<T> {
        &self.ins
    }

    /// Error covariance P (propagated up to the last covariance step).
    pub fn covariance(&self) -> &SMatrix<T, STATES, STATES> {
        &self.p
    }

    /// Estimated accelerometer bias (body), m/s².
    pub fn accel_bias_m_s2(&self) -> Vector3<T> {
        self.accel_bias_m_s2
    }

    /// Estimated gyro bias (body), rad/s.
    pub fn gyro_bias_rad_s(&self) -> Vector3<T> {
        self.gyro_bias_rad_s
    }

    /// Estimated gimbal angle errors `[δθ_s, δψ_s]`, rad.
    pub fn gimbal_bias_rad(&self) -> Vector2<T> {
        self.gimbal_bias_rad
    }

    /// One IMU sample: bias compensation, INS step and (every `covariance_interval_steps`)
    /// covariance propagation. Errors leave the filter unchanged.
    pub fn propagate(&mut self, inc: &ImuIncrement<T>) -> Result<(), NavError> {
        let dt = self.config.imu_dt_s;
        let compensated = ImuIncrement {
            delta_theta_rad: inc.delta_theta_rad - self.gyro_bias_rad_s * dt,
            delta_v_m_s: inc.delta_v_m_s - self.accel_bias_m_s2 * dt,
        };
        // The INS steps on a copy (P, the large part, is not copied: the covariance step below
        // is atomic), and everything is committed only when both succeeded.
        let mut ins = self.ins;
        ins.step(&compensated)?;
        let dv_pending = self.dv_ned_pending_m_s + ins.specific_force_ned_m_s2() * dt;
        let steps = self.steps_pending.saturating_add(1);
        if steps >= self.config.covariance_interval_steps {
            Self::covariance_step(
                &mut self.p,
                &ins,
                steps,
                &dv_pending,
                &self.config,
                self.q_accel,
                self.q_gyro,
            )?;
            self.steps_pending = 0;
            self.dv_ned_pending_m_s = Vector3::zeros();
        } else {
            self.steps_pending = steps;
            self.dv_ned_pending_m_s = dv_pending;
        }
        self.ins = ins;
        Ok(())
    }

    /// Propagates P over the IMU samples accumulated since the last covariance step (no-op if
    /// none). Errors leave the filter unchanged.
    pub fn predict_covariance(&mut self) -> Result<(), NavError> {
        if self.steps_pending == 0 {
            return Ok(());
        }
        Self::covariance_step(
            &mut self.p,
            &self.ins,
            self.steps_pending,
            &self.dv_ned_pending_m_s,
            &self.config,
            self.q_accel,
            self.q_gyro,
        )?;
        self.steps_pending = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        Ok(())
    }

    /// `P ← Φ P Φᵀ + Q_d` over `steps` IMU intervals with F at the INS state and the mean
    /// specific force `dv_ned / (steps Δt)`; atomic (P unchanged on error).
    fn covariance_step(
        p: &mut SMatrix<T, STATES, STATES>,
        ins: &Ins<T>,
        steps: u16,
        dv_ned_m_s: &Vector3<T>,
        config: &SeekerInsConfig<T>,
        q_accel: T,
        q_gyro: T,
    ) -> Result<(), NavError> {
        let dt_total = config.imu_dt_s * T::lit(f64::from(steps));
        let f_ned = dv_ned_m_s / dt_total;
        let s = ins.state();
        let f = SparseF::new(&s.position, &s.vel_ned_m_s, &ins.c_b_n(), &f_ned);
        propagate_covariance_sparse(p, &f, dt_total, q_accel, q_gyro)
    }

    /// Fuses one pair of measured gimbal angles (rad) to the configured landmark.
    ///
    /// Each of the two residual components is gated separately (χ², 1 dof); the report says
    /// which were fused. Errors (filter unchanged): `NonFiniteInput`, `InputOutOfRange`,
    /// `InnovationVarianceNotPositive`, `CovarianceNotPositiveSemiDefinite`.
    pub fn update_los(&mut self, measured: &GimbalAngles<T>) -> Result<LosReport<T>, NavError> {
        let mut next = *self;
        next.predict_covariance()?;
        let corrected = GimbalAngles {
            pitch_rad: measured.pitch_rad - next.gimbal_bias_rad.x,
            yaw_rad: measured.yaw_rad - next.gimbal_bias_rad.y,
        };
        let s = next.ins.state();
        let gate = Gate::Nis(self.config.gate_nis);
        let mut x = SVector::<T, STATES>::zeros();
        let c_b_n = next.ins.c_b_n();
        let (pitch, yaw, range_m, any_fused) = match self.config.residual {
            LosResidual::Projected2d => {
                let model = los_model(
                    &s.position,
                    &c_b_n,
                    &corrected,
                    &self.config.landmark,
                    self.config.seeker_noise_rad,
                )?;
                let pitch = fuse_scalar(
                    &mut x,
                    &mut next.p,
                    &model.h_pitch,
                    model.residual_rad.x,
                    model.variance_rad2.x,
                    gate,
                )?;
                let nu_yaw = model.residual_rad.y - model.h_yaw.dot(&x);
                let yaw = fuse_scalar(
                    &mut x,
                    &mut next.p,
                    &model.h_yaw,
                    nu_yaw,
                    model.variance_rad2.y,
                    gate,
                )?;
                let fused =
                    pitch.outcome == FusionOutcome::Fused || yaw.outcome == FusionOutcome::Fused;
                (pitch, yaw, model.range_m, fused)
            }
            LosResidual::FullRank3d => {
                let model = los_model_3d(
                    &s.position,
                    &c_b_n,
                    &corrected,
                    &self.config.landmark,
                    self.config.seeker_noise_rad,
                )?;
                let r = model.variance_rad2;
                let n = fuse_scalar(
                    &mut x,
                    &mut next.p,
                    &model.h_north,
                    model.residual.x,
                    r,
                    gate,
                )?;
                let nu_e = model.residual.y - model.h_east.dot(&x);
                let e = fuse_scalar(&mut x, &mut next.p, &model.h_east, nu_e, r, gate)?;
                let nu_d = model.residual.z - model.h_down.dot(&x);
                let d = fuse_scalar(&mut x, &mut next.p, &model.h_down, nu_d, r, gate)?;
                let fused = [n, e, d].iter().any(|c| c.outcome == FusionOutcome::Fused);
                (n, e, model.range_m, fused)
            }
        };
        if any_fused {
            next.feed_back(&x)?;
        }
        *self = next;
        Ok(LosReport {
            pitch,
            yaw,
            range_m,
        })
    }

    /// Closed-loop feedback of δx and reset (δx = 0 afterwards; P is kept: the reset of an
    /// additive error state is the identity to first order).
    fn feed_back(&mut self, x: &SVector<T, STATES>) -> Result<(), NavError> {
        let v3 = |i: usize| x.fixed_rows::<3>(i).into_owned();
        let dp = v3(POS);
        self.ins.correct(
            dp.x.to_f64(),
            dp.y.to_f64(),
            dp.z.to_f64(),
            &v3(VEL),
            &v3(ATT),
        )?;
        self.accel_bias_m_s2 += v3(ACC_BIAS);
        self.gyro_bias_rad_s += v3(GYRO_BIAS);
        self.gimbal_bias_rad += x.fixed_rows::<2>(GIMBAL);
        Ok(())
    }
}

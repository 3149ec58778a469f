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
#[cfg(feature = "los-residual-3d")]
use super::measurement::los_model_3d;
use super::measurement::{los_model, GimbalAngles, Landmark};
use super::mechanization::{ImuIncrement, Ins, InsState};
use crate::error::ConfigIssue;
use crate::math::checks::opaque;
#[cfg(feature = "los-residual-3d")]
use crate::math::kalman::fuse_scalar;
use crate::math::kalman::{FusionOutcome, FusionReport, Gate};
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
    /// as well but reported only through the state. Needs the crate feature
    /// `los-residual-3d` (default); without it [`SeekerIns::new`] refuses it
    /// (`InvalidConfig { field: "residual" }`).
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
    counters: LosCounters,
    recovery: RecoveryPolicy<T>,
    imu_policy: ImuFaultPolicy<T>,
    imu_counters: ImuFaultCounters,
    /// Consecutive IMU samples bridged by the hold / clipped (fully correlated inflation).
    held_run: u16,
    clipped_run: u16,
}

/// Counts of what the LOS updates did (each scalar component counts once).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosCounters {
    /// Components fused.
    pub fused: u32,
    /// Components rejected by the χ² gate.
    pub rejected: u32,
    /// Seeker updates in a row in which both components were rejected.
    pub consecutive_rejections: u32,
    /// Covariance re-inflations done by the recovery path ([`RecoveryPolicy`]).
    pub inflations: u32,
}

/// Recovery when the filter is starved of measurements by its own gate (the estimate drifted
/// beyond what P admits, so every LOS is rejected): after `max_consecutive_rejections` seeker
/// updates with both components rejected, P's navigation block (δL … φ, states 0..9) is
/// re-inflated, `P ← D P D` with `D = diag(√inflation_factor I₉, I₈)` (a congruence: P stays
/// symmetric PSD, correlations are kept), so that the gate opens again. Loss of lock (no
/// update calls) needs no recovery: P grows by propagation. Default: 50 updates (5 s at
/// 10 Hz; a 10 s false lock 2° off causes at most two inflations, σ × 4, still rejected),
/// factor 4 (σ × 2).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecoveryPolicy<T> {
    /// Consecutive fully rejected seeker updates before an inflation (0 disables recovery).
    pub max_consecutive_rejections: u32,
    /// Variance factor on the navigation block (> 1).
    pub inflation_factor: T,
}

impl<T: Real> Default for RecoveryPolicy<T> {
    fn default() -> Self {
        Self {
            max_consecutive_rejections: 50,
            inflation_factor: T::lit(4.0),
        }
    }
}

/// IMU fault handling: bridging of missing samples ([`SeekerIns::propagate_gap`]) and of
/// samples the IMU flags as clipped at its measurement range ([`SeekerIns::propagate_clipped`]).
///
/// In both cases the INS integrates an increment known to be wrong by an unknown amount:
/// the held increment misses the change of specific force / rate since the last good sample,
/// the clipped one the excess beyond the range. That error is modelled as a random constant
/// over a run of consecutive degraded samples (fully correlated: a manoeuvre or a clipped
/// vibration does not average out over 10 ms), per NED axis, with σ `*_accel_sigma_m_s2`
/// and `*_rate_sigma_rad_s`. After `c` consecutive degraded samples of interval Δt it has put
/// `c σ_a Δt` into the velocity error and `c σ_ω Δt` into the misalignment, so sample `c`
/// adds `(2c − 1)(σ Δt)²` to the diagonal of the velocity (states 3..6) and attitude (6..9)
/// blocks of P (the sum over `c = 1..n` is `(n σ Δt)²`); the position follows through Φ.
/// Adding to the diagonal keeps P symmetric PSD. Isotropic in NED (the clipped body axis is
/// not resolved: conservative by at most the two other axes).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuFaultPolicy<T> {
    /// Longest gap [`SeekerIns::propagate_gap`] bridges, IMU samples (≥ 1); a longer one is
    /// refused (`InvalidTimeStep`): the hold is no model for it and the caller must re-align.
    pub max_gap_samples: u16,
    /// σ of the specific-force change the hold misses during a gap, m/s² (per NED axis).
    pub gap_accel_sigma_m_s2: T,
    /// σ of the angular-rate change the hold misses during a gap, rad/s (per axis).
    pub gap_rate_sigma_rad_s: T,
    /// σ of the unknown specific-force excess beyond the range in a clipped sample, m/s².
    pub clip_accel_sigma_m_s2: T,
    /// σ of the unknown rate excess beyond the range in a clipped sample, rad/s.
    pub clip_rate_sigma_rad_s: T,
}

impl<T: Real> Default for ImuFaultPolicy<T> {
    /// 50 samples (0.5 s at 100 Hz); gap: 2 m/s², 0.01 rad/s; clipping: 10 m/s² (≈ 1 g beyond
    /// the range), 0.5 rad/s.
    fn default() -> Self {
        Self {
            max_gap_samples: 50,
            gap_accel_sigma_m_s2: T::lit(2.0),
            gap_rate_sigma_rad_s: T::lit(0.01),
            clip_accel_sigma_m_s2: T::lit(10.0),
            clip_rate_sigma_rad_s: T::lit(0.5),
        }
    }
}

/// Which sensor of an IMU sample is clipped ([`SeekerIns::propagate_clipped`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClipFlags {
    /// An accelerometer axis is at its range.
    pub accel: bool,
    /// A gyro axis is at its range.
    pub gyro: bool,
}

/// What the IMU fault handling did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuFaultCounters {
    /// Gaps bridged by [`SeekerIns::propagate_gap`].
    pub gaps: u32,
    /// IMU samples bridged by the hold (sum of the gap lengths).
    pub held_samples: u32,
    /// Clipped samples integrated by [`SeekerIns::propagate_clipped`].
    pub clipped_samples: u32,
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
            && self.counters == o.counters
            && self.recovery == o.recovery
            && self.imu_policy == o.imu_policy
            && self.imu_counters == o.imu_counters
            && self.held_run == o.held_run
            && self.clipped_run == o.clipped_run
    }
}

impl<T: Real> SeekerIns<T> {
    /// Filter at the initial INS state with initial covariance `p0` (units of the error state,
    /// see the module [`super`] doc).
    ///
    /// Errors: `InvalidConfig` (non-positive interval, σ or gate, negative or NaN densities;
    /// zero `covariance_interval_steps`), `InvalidTimeStep` (interval not in (0, 1] s),
    /// `NonFiniteInput`, `InputOutOfRange` (a variance of p0 beyond its physical bound),
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
        if cfg!(not(feature = "los-residual-3d")) && config.residual == LosResidual::FullRank3d {
            return Err(NavError::InvalidConfig {
                field: "residual",
                issue: ConfigIssue::OutOfRange,
            });
        }
        if config.covariance_interval_steps == 0 {
            return Err(NavError::InvalidConfig {
                field: "covariance_interval_steps",
                issue: ConfigIssue::NotPositive,
            });
        }
        if !crate::math::checks::all_finite(p0.as_slice()) {
            return Err(NavError::NonFiniteInput { input: "p0" });
        }
        // Physical bounds on the initial variances (units of the error state): position
        // (1 rad)², altitude (10⁷ m)², velocity (10⁴ m/s)², attitude 10 rad², accelerometer
        // bias (100 m/s²)², gyro bias (1 rad/s)², gimbal errors 10 rad².
        const MAX_VARIANCE: [f64; STATES] = [
            1.0, 1.0, 1e14, 1e8, 1e8, 1e8, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4, 1.0, 1.0, 1.0, 10.0,
            10.0,
        ];
        let cols = p0.as_slice().chunks_exact(STATES).zip(MAX_VARIANCE.iter());
        for (i, (col, m)) in cols.enumerate() {
            let i = opaque(i); // keeps the loop rolled (configuration time only)
            if col.get(i).is_some_and(|v| *v > T::lit(*m)) {
                return Err(NavError::InputOutOfRange { input: "p0" });
            }
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
            counters: LosCounters::default(),
            recovery: RecoveryPolicy::default(),
            imu_policy: ImuFaultPolicy::default(),
            imu_counters: ImuFaultCounters::default(),
            held_run: 0,
            clipped_run: 0,
        })
    }

    /// Counters of fused / rejected LOS components and recovery inflations.
    pub fn counters(&self) -> LosCounters {
        self.counters
    }

    /// The recovery policy in force.
    pub fn recovery_policy(&self) -> RecoveryPolicy<T> {
        self.recovery
    }

    /// Replaces the recovery policy. Errors (filter unchanged): `InvalidConfig` when the factor
    /// is not finite and > 1.
    pub fn set_recovery_policy(&mut self, policy: RecoveryPolicy<T>) -> Result<(), NavError> {
        if !policy.inflation_factor.is_finite() || policy.inflation_factor <= T::one() {
            return Err(NavError::InvalidConfig {
                field: "inflation_factor",
                issue: ConfigIssue::OutOfRange,
            });
        }
        self.recovery = policy;
        Ok(())
    }

    /// The IMU fault policy in force.
    pub fn imu_fault_policy(&self) -> ImuFaultPolicy<T> {
        self.imu_policy
    }

    /// Counters of bridged gaps and clipped samples.
    pub fn imu_fault_counters(&self) -> ImuFaultCounters {
        self.imu_counters
    }

    /// Replaces the IMU fault policy. Errors (filter unchanged): `InvalidConfig` when
    /// `max_gap_samples` is 0 or a σ is negative or not finite.
    pub fn set_imu_fault_policy(&mut self, policy: ImuFaultPolicy<T>) -> Result<(), NavError> {
        use crate::error::require_non_negative;
        if policy.max_gap_samples == 0 {
            return Err(NavError::InvalidConfig {
                field: "max_gap_samples",
                issue: ConfigIssue::NotPositive,
            });
        }
        for (field, v) in [
            ("gap_accel_sigma_m_s2", policy.gap_accel_sigma_m_s2),
            ("gap_rate_sigma_rad_s", policy.gap_rate_sigma_rad_s),
            ("clip_accel_sigma_m_s2", policy.clip_accel_sigma_m_s2),
            ("clip_rate_sigma_rad_s", policy.clip_rate_sigma_rad_s),
        ] {
            require_non_negative(field, v)?;
        }
        self.imu_policy = policy;
        Ok(())
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
        self.propagate_compensated(&compensated)?;
        self.held_run = 0;
        self.clipped_run = 0;
        Ok(())
    }

    /// One IMU sample that the IMU flags as clipped (over-range on at least one axis of the
    /// sensors in `clipped`; the driver knows it from the status word or from a component at
    /// full scale). Only the flagged sensor's block of P is inflated (accelerometer →
    /// velocity, gyro → attitude).
    ///
    /// Design: the sample is integrated as delivered: its unclipped axes are exact and a
    /// clipped axis reads the range, the value closest to the truth that is known (a hold of
    /// the previous sample is further off in a burst that grows past the range, and dropping
    /// the sample loses the unclipped axes). The unknown excess is accounted for in P per
    /// [`ImuFaultPolicy`] (`clip_*_sigma`, fully correlated over a burst of consecutive clipped
    /// samples). Errors (filter unchanged): as [`SeekerIns::propagate`].
    pub fn propagate_clipped(
        &mut self,
        inc: &ImuIncrement<T>,
        clipped: ClipFlags,
    ) -> Result<(), NavError> {
        let dt = self.config.imu_dt_s;
        let compensated = ImuIncrement {
            delta_theta_rad: inc.delta_theta_rad - self.gyro_bias_rad_s * dt,
            delta_v_m_s: inc.delta_v_m_s - self.accel_bias_m_s2 * dt,
        };
        self.propagate_compensated(&compensated)?;
        self.held_run = 0;
        self.clipped_run = self.clipped_run.saturating_add(1);
        let zero = T::zero();
        let pol = &self.imu_policy;
        let sa = if clipped.accel {
            pol.clip_accel_sigma_m_s2
        } else {
            zero
        };
        let sw = if clipped.gyro {
            pol.clip_rate_sigma_rad_s
        } else {
            zero
        };
        self.inflate_degraded(self.clipped_run, sa, sw);
        self.imu_counters.clipped_samples = self.imu_counters.clipped_samples.saturating_add(1);
        Ok(())
    }

    /// Bridges a gap of `missing_samples` whole IMU intervals (samples lost on the bus, a
    /// sensor reset), to be called before the first sample after the gap so that the INS
    /// and P are back on the IMU time grid.
    ///
    /// Design: zero-order hold. The INS integrates the last compensated increment
    /// ([`Ins::last_increment`]; body rate and specific force held constant in the body
    /// frame, so coning/sculling terms vanish), P is propagated as for real samples, and the
    /// error of the hold is accounted for in P per [`ImuFaultPolicy`] (`gap_*_sigma`, fully
    /// correlated over the gap: after a gap of duration T, velocity σ grows by σ_a T and
    /// misalignment σ by σ_ω T, plus what Φ carries into position). Seeker measurements
    /// taken during the gap are best dropped (the INS was not at their time).
    ///
    /// Errors (filter unchanged, nothing counted): `InvalidTimeStep` if `missing_samples` is
    /// 0 or exceeds [`ImuFaultPolicy::max_gap_samples`]; `InputOutOfRange` before the first
    /// IMU sample (nothing to hold); any error of the INS step or covariance propagation.
    /// The bridge works on a copy of the filter and commits at the end.
    pub fn propagate_gap(&mut self, missing_samples: u16) -> Result<(), NavError> {
        if missing_samples == 0 || missing_samples > self.imu_policy.max_gap_samples {
            return Err(NavError::InvalidTimeStep);
        }
        let held = self.ins.last_increment().ok_or(NavError::InputOutOfRange {
            input: "IMU gap before the first sample (nothing to hold)",
        })?;
        let mut next = *self;
        let (sa, sw) = (
            self.imu_policy.gap_accel_sigma_m_s2,
            self.imu_policy.gap_rate_sigma_rad_s,
        );
        next.clipped_run = 0;
        for _ in 0..missing_samples {
            next.propagate_compensated(&held)?;
            next.held_run = next.held_run.saturating_add(1);
            next.inflate_degraded(next.held_run, sa, sw);
        }
        next.imu_counters.gaps = next.imu_counters.gaps.saturating_add(1);
        next.imu_counters.held_samples = next
            .imu_counters
            .held_samples
            .saturating_add(u32::from(missing_samples));
        *self = next;
        Ok(())
    }

    /// Adds `(2c − 1)(σ Δt)²` to the velocity and attitude variances ([`ImuFaultPolicy`]).
    /// Not inlined: one copy serves the gap and the clipping paths.
    #[inline(never)]
    fn inflate_degraded(&mut self, c: u16, accel_sigma: T, rate_sigma: T) {
        let dt = self.config.imu_dt_s;
        let w = T::lit(2.0 * f64::from(c) - 1.0) * dt * dt;
        let (qa, qw) = (w * accel_sigma * accel_sigma, w * rate_sigma * rate_sigma);
        for i in VEL..VEL + 3 {
            if let Some(v) = self.p.get_mut((i, i)) {
                *v += qa;
            }
        }
        for i in ATT..ATT + 3 {
            if let Some(v) = self.p.get_mut((i, i)) {
                *v += qw;
            }
        }
    }

    /// INS step with a bias-compensated increment and the covariance step when due; atomic.
    fn propagate_compensated(&mut self, compensated: &ImuIncrement<T>) -> Result<(), NavError> {
        let dt = self.config.imu_dt_s;
        // The INS steps on a copy (P, the large part, is not copied: the covariance step below
        // is atomic), and everything is committed only when both succeeded.
        let mut ins = self.ins;
        ins.step(compensated)?;
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
    /// specific force `dv_ned / (steps Δt)`; atomic (P unchanged on error). Not inlined: one
    /// copy serves `predict_covariance` and the pending-prediction path of `update_los`.
    #[inline(never)]
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
    /// which were fused, [`SeekerIns::counters`] counts them, and [`RecoveryPolicy`] re-inflates
    /// P when the gate starves the filter. Errors (filter unchanged): `NonFiniteInput`,
    /// `InputOutOfRange` (gimbal pitch beyond ±80°, landmark closer than 1 m),
    /// `InnovationVarianceNotPositive`, `CovarianceNotPositiveSemiDefinite`.
    ///
    /// With P propagated up to date (the usual case at the seeker rate) the update works in
    /// place with no copy of P: the two scalar updates are computed as rank-one terms
    /// `P⁺ = P − k₁K₁ᵀ − k₂K₂ᵀ` (`k = P⁻h`, `K = k/s`), checked (variances stay ≥ 0, all
    /// finite, feedback valid) and only then applied. With IMU samples pending, P is first
    /// propagated on a copy of the filter (more stack) and committed with the update.
    pub fn update_los(&mut self, measured: &GimbalAngles<T>) -> Result<LosReport<T>, NavError> {
        if self.steps_pending > 0 {
            return self.update_los_pending(measured);
        }
        self.update_los_now(measured)
    }

    #[inline(never)]
    fn update_los_pending(&mut self, measured: &GimbalAngles<T>) -> Result<LosReport<T>, NavError> {
        let mut next = *self;
        next.predict_covariance()?;
        let report = next.update_los_now(measured)?;
        *self = next;
        Ok(report)
    }

    /// Not inlined: one copy serves the direct and the pending-prediction paths.
    #[inline(never)]
    fn update_los_now(&mut self, measured: &GimbalAngles<T>) -> Result<LosReport<T>, NavError> {
        let corrected = GimbalAngles {
            pitch_rad: measured.pitch_rad - self.gimbal_bias_rad.x,
            yaw_rad: measured.yaw_rad - self.gimbal_bias_rad.y,
        };
        let s = self.ins.state();
        let gate = Gate::Nis(self.config.gate_nis);
        let c_b_n = self.ins.c_b_n();
        #[cfg(feature = "los-residual-3d")]
        if self.config.residual == LosResidual::FullRank3d {
            return self.update_los_3d(&corrected, &c_b_n, gate);
        }
        let model = los_model(
            &s.position,
            &c_b_n,
            &corrected,
            &self.config.landmark,
            self.config.seeker_noise_rad,
        )?;
        let zero = T::zero();
        let p = &self.p;
        // k = P h over the 8 non-zero entries of h (columns 0..3, 6..9, 15..17 of P).
        let ph = |h: &SVector<T, STATES>| -> [T; STATES] { covariance_times_dense_row(p, h) };
        let dot = |a: &[T; STATES], h: &SVector<T, STATES>| -> T { dot_rolled(a, h.as_slice()) };
        // Component 1 (pitch direction).
        let h1 = &model.h_pitch;
        let k1 = ph(h1);
        let (rep1, inv_s1) = scalar_report(
            dot(&k1, h1),
            model.variance_rad2.x,
            model.residual_rad.x,
            gate,
        )?;
        let fused1 = rep1.outcome == FusionOutcome::Fused;
        // Component 2 (yaw direction), against P after component 1: k₂ = P h₂ − k₁ (K₁·h₂).
        let h2 = &model.h_yaw;
        let mut k2 = ph(h2);
        let mut x = [zero; STATES];
        let mut kk1 = [zero; STATES];
        if fused1 {
            let c = dot(&k1, h2) * inv_s1;
            let it = opaque(&mut k2[..])
                .iter_mut()
                .zip(k1.iter())
                .zip(x.iter_mut())
                .zip(kk1.iter_mut());
            for (((k2i, k1i), xi), kk) in it {
                *k2i -= *k1i * c;
                *kk = *k1i * inv_s1;
                *xi = *kk * rep1.innovation;
            }
        }
        let nu2 = model.residual_rad.y - dot_rolled(h2.as_slice(), &x);
        let (rep2, inv_s2) = scalar_report(dot(&k2, h2), model.variance_rad2.y, nu2, gate)?;
        let fused2 = rep2.outcome == FusionOutcome::Fused;
        let mut kk2 = [zero; STATES];
        if fused2 {
            for ((kk, k2i), xi) in opaque(&mut kk2[..])
                .iter_mut()
                .zip(k2.iter())
                .zip(x.iter_mut())
            {
                *kk = *k2i * inv_s2;
                *xi += *kk * rep2.innovation;
            }
        }
        let report = LosReport {
            pitch: rep1,
            yaw: rep2,
            range_m: model.range_m,
        };
        if !(fused1 || fused2) {
            self.note_rejection();
            return Ok(report);
        }
        // Check before anything changes: variances stay ≥ 0 and everything is finite.
        let updated = |i: usize, j: usize, pij: T| -> T {
            let g = |a: &[T; STATES], i: usize| a.get(i).copied().unwrap_or(zero);
            pij - g(&k1, i) * g(&kk1, j) - g(&k2, i) * g(&kk2, j)
        };
        for (i, col) in p.as_slice().chunks_exact(STATES).enumerate() {
            let i = opaque(i); // keeps the loop rolled
            let d = updated(i, i, col.get(i).copied().unwrap_or(zero));
            if !d.is_finite() || d < zero {
                return Err(NavError::CovarianceNotPositiveSemiDefinite);
            }
        }
        let xv = SVector::<T, STATES>::from(x);
        // Feedback first: it is atomic (the INS validates before it changes) and only P, which
        // cannot fail any more, follows.
        self.feed_back_parts(&xv)?;
        // P: upper triangle, mirrored (exactly symmetric).
        for j in 0..STATES {
            for i in 0..=j {
                if let Some(v) = self.p.get((i, j)).copied() {
                    let u = updated(i, j, v);
                    if let Some(d) = self.p.get_mut((i, j)) {
                        *d = u;
                    }
                    if let Some(d) = self.p.get_mut((j, i)) {
                        *d = u;
                    }
                }
            }
        }
        self.counters.fused = self
            .counters
            .fused
            .saturating_add(u32::from(fused1) + u32::from(fused2));
        self.counters.rejected = self
            .counters
            .rejected
            .saturating_add(u32::from(!fused1) + u32::from(!fused2));
        self.counters.consecutive_rejections = 0;
        Ok(report)
    }

    /// Both components rejected: count, and re-inflate P per [`RecoveryPolicy`].
    fn note_rejection(&mut self) {
        let c = &mut self.counters;
        c.rejected = c.rejected.saturating_add(2);
        c.consecutive_rejections = c.consecutive_rejections.saturating_add(1);
        let max = self.recovery.max_consecutive_rejections;
        if max > 0 && c.consecutive_rejections >= max {
            let f = self.recovery.inflation_factor;
            let sf = f.sqrt();
            // (`opaque`: runtime lengths, the loops stay rolled.)
            let cols = opaque(self.p.as_mut_slice()).chunks_exact_mut(STATES);
            for (j, col) in cols.enumerate() {
                for (i, v) in opaque(col).iter_mut().enumerate() {
                    match (i < 9, j < 9) {
                        (true, true) => *v *= f,
                        (false, false) => {}
                        _ => *v *= sf,
                    }
                }
            }
            c.consecutive_rejections = 0;
            c.inflations = c.inflations.saturating_add(1);
        }
    }

    /// The comparison variant: three scalar updates with the shared `fuse_scalar` on a copy
    /// (not inlined: its copy of the filter stays out of the 2-D path's stack frame).
    #[cfg(feature = "los-residual-3d")]
    #[inline(never)]
    fn update_los_3d(
        &mut self,
        corrected: &GimbalAngles<T>,
        c_b_n: &nalgebra::Matrix3<T>,
        gate: Gate<T>,
    ) -> Result<LosReport<T>, NavError> {
        let mut next = *self;
        let s = next.ins.state();
        let model = los_model_3d(
            &s.position,
            c_b_n,
            corrected,
            &self.config.landmark,
            self.config.seeker_noise_rad,
        )?;
        let mut x = SVector::<T, STATES>::zeros();
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
        let fused = [n, e, d]
            .iter()
            .filter(|c| c.outcome == FusionOutcome::Fused)
            .count() as u32;
        if fused > 0 {
            next.feed_back_parts(&x)?;
            next.counters.fused = next.counters.fused.saturating_add(fused);
            next.counters.rejected = next.counters.rejected.saturating_add(3 - fused);
            next.counters.consecutive_rejections = 0;
        } else {
            next.note_rejection();
        }
        *self = next;
        Ok(LosReport {
            pitch: n,
            yaw: e,
            range_m: model.range_m,
        })
    }

    /// Closed-loop feedback of δx and reset (δx = 0 afterwards; P is kept: the reset of an
    /// additive error state is the identity to first order). Atomic: on error (corrected
    /// position invalid) nothing changed.
    fn feed_back_parts(&mut self, x: &SVector<T, STATES>) -> Result<(), NavError> {
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

/// `Σ aᵢ bᵢ` folded from zero in index order (the shorter length), one rolled copy for every
/// dot product of the LOS update (`opaque`: not specialised to 17 and unrolled).
#[inline(never)]
fn dot_rolled<T: Real>(a: &[T], b: &[T]) -> T {
    let (a, b) = opaque((a, b));
    a.iter().zip(b).fold(T::zero(), |acc, (x, y)| acc + *x * *y)
}

/// `k = P h`, skipping the zero entries of h (8 of 17 for a LOS row). Not inlined: one copy
/// serves both LOS components.
#[inline(never)]
fn covariance_times_dense_row<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    h: &SVector<T, STATES>,
) -> [T; STATES] {
    let zero = T::zero();
    let mut k = [zero; STATES];
    for (col, hj) in p.as_slice().chunks_exact(STATES).zip(h.iter()) {
        if *hj != zero {
            for (ki, pij) in k.iter_mut().zip(col) {
                *ki += *hj * *pij;
            }
        }
    }
    k
}

/// Innovation variance, NIS and χ² gate of one scalar component with `hᵀPh = hph`: the report
/// and `1/s`. Errors: `InnovationVarianceNotPositive` (s not finite and > 0, or hᵀPh < 0).
fn scalar_report<T: Real>(
    hph: T,
    r: T,
    innovation: T,
    gate: Gate<T>,
) -> Result<(FusionReport<T>, T), NavError> {
    let s = hph + r;
    if !s.is_finite() || s <= T::zero() || hph < T::zero() || !innovation.is_finite() {
        return Err(NavError::InnovationVarianceNotPositive);
    }
    let inv_s = T::one() / s;
    let nis = innovation * innovation * inv_s;
    let (test_ratio, rejected) = match gate {
        Gate::Off => (T::zero(), false),
        Gate::Nis(threshold) => {
            let ratio = nis / threshold;
            // A NaN ratio or a non-positive threshold rejects.
            let within = matches!(
                ratio.partial_cmp(&T::one()),
                Some(core::cmp::Ordering::Less | core::cmp::Ordering::Equal)
            );
            (ratio, !within || threshold <= T::zero())
        }
    };
    Ok((
        FusionReport {
            innovation,
            innovation_variance: s,
            nis,
            test_ratio,
            outcome: if rejected {
                FusionOutcome::Rejected
            } else {
                FusionOutcome::Fused
            },
        },
        inv_s,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::seeker_ins::mechanization::Position;
    use nalgebra::Quaternion;

    fn setup(residual: LosResidual) -> (SeekerInsConfig<f32>, InsState<f32>, SMatrix<f32, 17, 17>) {
        let start = Position {
            lat_rad: 37f64.to_radians(),
            lon_rad: 127f64.to_radians(),
            alt_m: 1000.0,
        };
        let target = Position {
            lat_rad: 37.05f64.to_radians(),
            ..start
        };
        let cfg = SeekerInsConfig {
            imu_dt_s: 0.01,
            covariance_interval_steps: 10,
            accel_noise_density_m_s2_rt_hz: 5e-5,
            gyro_noise_density_rad_s_rt_hz: 3e-6,
            seeker_noise_rad: 3e-3,
            gate_nis: 16.0,
            landmark: Landmark::new(target).unwrap(),
            residual,
        };
        let init = InsState {
            position: start,
            vel_ned_m_s: Vector3::new(200.0, 0.0, 0.0),
            q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        };
        let p0 = SMatrix::<f32, 17, 17>::from_diagonal_element(1e-8);
        (cfg, init, p0)
    }

    /// Without the `los-residual-3d` feature (a flight build), the comparison residual is
    /// refused at configuration and the design choice still works
    /// (`cargo test -p nav-core --no-default-features`, run by `cargo xtask ci`).
    #[cfg(not(feature = "los-residual-3d"))]
    #[test]
    fn full_rank_3d_needs_its_feature() {
        let (cfg, init, p0) = setup(LosResidual::FullRank3d);
        assert_eq!(
            SeekerIns::new(cfg, init, &p0).err(),
            Some(NavError::InvalidConfig {
                field: "residual",
                issue: ConfigIssue::OutOfRange,
            })
        );
        let (cfg, init, p0) = setup(LosResidual::Projected2d);
        assert!(SeekerIns::new(cfg, init, &p0).is_ok());
    }

    #[cfg(feature = "los-residual-3d")]
    #[test]
    fn both_residuals_configure_with_the_feature() {
        for residual in [LosResidual::Projected2d, LosResidual::FullRank3d] {
            let (cfg, init, p0) = setup(residual);
            assert!(SeekerIns::new(cfg, init, &p0).is_ok());
        }
    }
}

//! Closed-loop 17-state error-state EKF of the seeker-aided INS (spec, seed Fig. 2).
//!
//! * [`SeekerIns::propagate`] (every IMU sample): removes the estimated biases from the
//!   increments, advances the INS ([`super::mechanization`]) and every
//!   `covariance_interval_steps` samples propagates P over the accumulated interval
//!   ([`super::error_model::propagate_covariance_sparse`], F at the current state and the mean
//!   specific force of the interval).
//! * [`SeekerIns::update_los`] (seeker rate): first propagates P over any pending interval,
//!   then fuses the two LOS residual components ([`super::measurement`]) as sequential scalar
//!   updates in the simple form `P⁺ = P − k kᵀ/s` with a χ² gate, feeds the estimate back
//!   (position, velocity, attitude into the INS; biases and gimbal errors into the
//!   compensations) and resets δx to zero.
//!
//! Because δx is zero after every feedback, the prediction only propagates P.
//! Every method that returns an error leaves the whole filter exactly as it was.
//!
//! # Numerical envelope (f32 and f64)
//!
//! P stays symmetric PSD by construction:
//!
//! * **Variance ceilings.** After every covariance propagation, IMU-fault inflation and
//!   recovery inflation, a navigation-block variance above its physical ceiling
//!   ([`VARIANCE_CEILING`], the bounds [`SeekerIns::new`] accepts for p0: (1 rad)² in latitude
//!   and longitude, (10⁷ m)² in altitude, (10⁴ m/s)² in velocity, 10 rad² in attitude) is brought
//!   back to it by scaling its row and column (`P ← D P D`, D diagonal: a congruence, so P stays
//!   PSD and the correlations are kept), as PX4 EKF2 limits its variances.
//! * **Conditioned LOS update.** A scalar update removes from P the fraction `hᵀPh/(hᵀPh + r)`
//!   of the variance along h; when `hᵀPh/r` exceeds what the working precision can resolve
//!   ([`max_information_ratio`], `10⁻³/ε`: 8 389 in f32), the component is fused with r raised
//!   to `hᵀPh / ratio` (a less informative but consistent measurement; the next updates finish
//!   the job). Counted in [`LosCounters::conditioned`].
//! * **Skipped, never refused.** A valid LOS that still cannot be fused (non-positive
//!   innovation variance, a variance that would turn negative, a non-finite correction) is
//!   reported as [`FusionOutcome::Skipped`] with a [`LosSkipReason`]; P and the state are
//!   unchanged. A propagated variance that rounds below zero is set to zero with its row and
//!   column (counted in [`HealthCounters::covariance_repairs`]).
//!
//! # Health and the way back
//!
//! [`SeekerIns::health`] says how far the solution can be trusted ([`crate::HealthState`]),
//! [`SeekerIns::health_counters`] why. When the position leaves the model range (|L| ≥ 86°,
//! |h| ≥ 1000 km; e.g. the unaided vertical channel diverging between rare landmark sightings)
//! the INS keeps integrating with gravity, radii and rates at the nearest point of the range
//! and the health is `NeedsReinitialisation`; so it is when a navigation variance sits at its
//! ceiling. [`SeekerIns::reinitialise`] restarts position, velocity, attitude and their
//! covariance and keeps the bias and gimbal-error estimates with their covariance.
//!
//! # Work per call (bounded)
//!
//! `propagate` / `propagate_clipped`: one INS step and at most one covariance propagation
//! (Cortex-M4F, `cargo xtask bench`: `ins_mech_step` + `eskf17_predict`). `propagate_gap(n)`:
//! n ≤ [`MAX_GAP_SAMPLES`] of those. `update_los`: at most one covariance propagation and one
//! LOS update (`eskf17_los_update`). `reinitialise`, `predict_covariance` and the setters:
//! O(17²) at most. No call loops on data.

use super::error_model::{
    propagate_covariance_sparse, SparseF, ACC_BIAS, ATT, GIMBAL, GYRO_BIAS, POS, STATES, VEL,
};
#[cfg(feature = "los-residual-3d")]
use super::measurement::los_model_3d;
use super::measurement::{
    landmark_vector_ned, los_model_at, validate_gimbal, GimbalAngles, Landmark,
    MIN_LANDMARK_RANGE_M,
};
use super::mechanization::{ImuIncrement, Ins, InsState};
use crate::error::ConfigIssue;
use crate::math::checks::opaque;
#[cfg(feature = "los-residual-3d")]
use crate::math::kalman::fuse_scalar;
use crate::math::kalman::{FusionOutcome, FusionReport, Gate};
use crate::{HealthState, NavError, Real};
use nalgebra::{SMatrix, SVector, Vector2, Vector3};

/// Physical ceilings of the error-state variances (units of the error state, see the module
/// [`super`] doc): latitude and longitude (1 rad)², altitude (10⁷ m)², velocity (10⁴ m/s)²,
/// attitude 10 rad² (≈ π², nothing known), accelerometer bias (100 m/s²)², gyro bias
/// (1 rad/s)², gimbal errors 10 rad². [`SeekerIns::new`] refuses a p0 beyond them; the
/// navigation block (states 0..9) is limited to them at run time (module doc).
pub const VARIANCE_CEILING: [f64; STATES] = [
    1.0, 1.0, 1e14, 1e8, 1e8, 1e8, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4, 1.0, 1.0, 1.0, 10.0, 10.0,
];

/// Largest ratio `hᵀPh / r` a LOS component is fused with in the working precision:
/// `10⁻³ / ε` (8 389 in f32, 4.5e12 in f64). Beyond it r is raised (module doc).
pub fn max_information_ratio<T: Real>() -> T {
    T::lit(1e-3) / T::EPS
}

/// Without a fused LOS component for this long the health is `Degraded` (aid lost), s.
pub const AID_TIMEOUT_S: f64 = 10.0;

/// Largest accepted [`ImuFaultPolicy::max_gap_samples`], IMU samples (bounds the work of one
/// [`SeekerIns::propagate_gap`]).
pub const MAX_GAP_SAMPLES: u16 = 500;
/// Largest accepted gap duration `max_gap_samples × imu_dt_s`, s: beyond it a zero-order hold
/// is no model of the motion.
pub const MAX_GAP_S: f64 = 1.0;
/// Largest accepted accelerometer σ of the IMU fault policy (gap and clipping), m/s² (≈ 100 g).
pub const MAX_FAULT_ACCEL_SIGMA_M_S2: f64 = 1000.0;
/// Largest accepted rate σ of the IMU fault policy (gap and clipping), rad/s.
pub const MAX_FAULT_RATE_SIGMA_RAD_S: f64 = 50.0;
/// Largest attitude σ one full gap may add, `gap_rate_sigma × max_gap_samples × imu_dt_s`, rad
/// (the error model is a small-angle model).
pub const MAX_GAP_ATTITUDE_SIGMA_RAD: f64 = 1.0;
/// Largest velocity σ one full gap may add, `gap_accel_sigma × max_gap_samples × imu_dt_s`,
/// m/s.
pub const MAX_GAP_VELOCITY_SIGMA_M_S: f64 = 100.0;
/// Largest accepted [`RecoveryPolicy::inflation_factor`] (variance factor; σ × 10).
pub const MAX_INFLATION_FACTOR: f64 = 100.0;

/// Filter configuration. σ are standard deviations, densities are √PSD. The ranges below are
/// the envelope in which the filter is known to work (stress campaign, README); outside them
/// [`SeekerIns::new`] returns `InvalidConfig` naming the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeekerInsConfig<T> {
    /// IMU sample interval, s: [1e-4, 0.1] (10 kHz to 10 Hz).
    pub imu_dt_s: T,
    /// Covariance propagation every this many IMU samples, ≥ 1, with
    /// `covariance_interval_steps × imu_dt_s ≤ 1 s` (the second-order transition matrix);
    /// e.g. 10 at 100 Hz → 10 Hz.
    pub covariance_interval_steps: u16,
    /// Accelerometer white noise density (velocity random walk), m/s²/√Hz: [0, 0.1].
    pub accel_noise_density_m_s2_rt_hz: T,
    /// Gyro white noise density (angle random walk), rad/s/√Hz = rad/√s: [0, 0.01].
    pub gyro_noise_density_rad_s_rt_hz: T,
    /// Seeker gimbal-angle white noise, 1σ per angle, rad: [1e-5, 0.1] (below 1e-5 rad the
    /// f32 LOS residual, a difference of unit vectors, is no longer resolved).
    pub seeker_noise_rad: T,
    /// χ² (1 degree of freedom) gate on each scalar component's NIS, e.g. 16 (4σ): [1, 10⁴].
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
    /// Pitch-direction component (innovation rad, variance rad², NIS, fused/rejected/skipped).
    pub pitch: FusionReport<T>,
    /// Yaw-direction component.
    pub yaw: FusionReport<T>,
    /// Range from the INS position to the landmark, m.
    pub range_m: T,
    /// Why a component was skipped (`None` when none was).
    pub skipped: Option<LosSkipReason>,
}

/// Why a valid LOS measurement was not fused ([`FusionOutcome::Skipped`]; nothing changed).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LosSkipReason {
    /// The INS position is closer to the landmark than
    /// [`super::measurement::MIN_LANDMARK_RANGE_M`]: the LOS direction carries no usable
    /// information (both components skipped).
    LandmarkTooClose,
    /// The working precision cannot fuse it: innovation variance not positive and finite, or
    /// a variance that would turn negative or non-finite.
    NumericalLimit,
    /// The correction it implies is not finite (both components skipped).
    CorrectionNotFinite,
    /// The gimbal angles are valid but, corrected by the estimated gimbal errors, beyond the
    /// ±80° pitch (or ±π yaw) the LOS model accepts (both components skipped).
    GimbalBeyondLimit,
    /// The INS position is outside the range where the error model holds (health
    /// `NeedsReinitialisation`): the linearisation is not to be trusted and the update would
    /// corrupt the covariance (both components skipped until `reinitialise`).
    PositionOutOfRange,
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
    health: HealthCounters,
    /// IMU samples since the last gap or clipped sample (saturating).
    samples_since_imu_fault: u32,
    /// How the last LOS update went (for the health state).
    last_update: LastUpdate,
}

/// How the last LOS update went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum LastUpdate {
    /// None since construction or re-initialisation.
    None,
    /// Every component fused or rejected, none conditioned or skipped.
    Clean,
    /// A component was conditioned or skipped.
    Degraded,
}

/// What the filter did to stay in its numerical envelope, and where its solution stands
/// ([`SeekerIns::health`] derives the [`crate::HealthState`] from it and the state).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct HealthCounters {
    /// IMU samples since a LOS component was last fused (saturating).
    pub samples_since_fusion: u32,
    /// Navigation variances brought back to their ceiling ([`VARIANCE_CEILING`]).
    pub variance_limits: u32,
    /// Propagated variances that rounded below zero and were zeroed with their row and
    /// column.
    pub covariance_repairs: u32,
    /// IMU samples integrated with the position outside the model range.
    pub out_of_range_samples: u32,
    /// Calls of [`SeekerIns::reinitialise`].
    pub reinitialisations: u32,
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
    /// Components skipped ([`FusionOutcome::Skipped`], [`LosSkipReason`]).
    pub skipped: u32,
    /// Components fused with r raised to the precision limit ([`max_information_ratio`]).
    pub conditioned: u32,
}

/// Recovery when the filter is starved of measurements by its own gate (the estimate drifted
/// beyond what P admits, so every LOS is rejected): after `max_consecutive_rejections` seeker
/// updates with both components rejected, P's navigation block (δL … φ, states 0..9) is
/// re-inflated, `P ← D P D` with `D = diag(√inflation_factor I₉, I₈)` (a congruence: P stays
/// symmetric PSD, correlations are kept), so that the gate opens again. Loss of lock (no
/// update calls) needs no recovery: P grows by propagation. Default: 50 updates (5 s at
/// 10 Hz; a 10 s false lock 2° off causes at most two inflations, σ × 4, still rejected),
/// factor 4 (σ × 2). The inflated variances are limited to [`VARIANCE_CEILING`].
///
/// Valid ranges ([`SeekerIns::set_recovery_policy`]): `max_consecutive_rejections` any (0
/// disables), `inflation_factor` in (1, [`MAX_INFLATION_FACTOR`]].
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
/// not resolved: conservative by at most the two other axes). The variances are limited to
/// [`VARIANCE_CEILING`], so a clipping burst of any length keeps P bounded and PSD.
///
/// Valid ranges ([`SeekerIns::set_imu_fault_policy`]): `max_gap_samples` in
/// [1, [`MAX_GAP_SAMPLES`]] with `max_gap_samples × imu_dt_s ≤` [`MAX_GAP_S`]; accelerometer σ
/// in [0, [`MAX_FAULT_ACCEL_SIGMA_M_S2`]] m/s², rate σ in [0, [`MAX_FAULT_RATE_SIGMA_RAD_S`]]
/// rad/s; over one full gap `gap_rate_sigma × max_gap_samples × imu_dt_s ≤`
/// [`MAX_GAP_ATTITUDE_SIGMA_RAD`] and `gap_accel_sigma × max_gap_samples × imu_dt_s ≤`
/// [`MAX_GAP_VELOCITY_SIGMA_M_S`].
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
            && self.health == o.health
            && self.samples_since_imu_fault == o.samples_since_imu_fault
            && self.last_update == o.last_update
    }
}

impl<T: Real> SeekerIns<T> {
    /// Filter at the initial INS state with initial covariance `p0` (units of the error state,
    /// see the module [`super`] doc).
    ///
    /// Errors: `InvalidConfig` (a field outside its range, see [`SeekerInsConfig`]),
    /// `NonFiniteInput`, `InputOutOfRange` (a variance of p0 beyond [`VARIANCE_CEILING`], an
    /// initial position outside the model range), `CovarianceNotPositiveSemiDefinite` (p0 not
    /// symmetric PSD).
    pub fn new(
        config: SeekerInsConfig<T>,
        initial: InsState<T>,
        p0: &SMatrix<T, STATES, STATES>,
    ) -> Result<Self, NavError> {
        validate_config(&config)?;
        if !crate::math::checks::all_finite(p0.as_slice()) {
            return Err(NavError::NonFiniteInput { input: "p0" });
        }
        let cols = p0
            .as_slice()
            .chunks_exact(STATES)
            .zip(VARIANCE_CEILING.iter());
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
            health: HealthCounters::default(),
            samples_since_imu_fault: u32::MAX,
            last_update: LastUpdate::None,
        })
    }

    /// Restarts the navigation solution: position, velocity and attitude from `state`, their
    /// covariance (states 0..9, units of the error state) from `nav_covariance`. Kept: the
    /// accelerometer, gyro and gimbal-error estimates with their covariance block (states
    /// 9..17; their correlations with the old navigation errors are dropped, so P stays PSD),
    /// the configuration, the policies and every counter. Cleared: the pending covariance
    /// interval, the IMU-fault runs, the rejection run; the health restarts at
    /// `Initialising` (until the next IMU sample). Counted in
    /// [`HealthCounters::reinitialisations`].
    ///
    /// Errors (filter unchanged): `NonFiniteInput`, `InputOutOfRange` (position outside the
    /// model range, a variance beyond [`VARIANCE_CEILING`]),
    /// `CovarianceNotPositiveSemiDefinite` (`nav_covariance` not symmetric PSD).
    pub fn reinitialise(
        &mut self,
        state: InsState<T>,
        nav_covariance: &SMatrix<T, 9, 9>,
    ) -> Result<(), NavError> {
        if !crate::math::checks::all_finite(nav_covariance.as_slice()) {
            return Err(NavError::NonFiniteInput {
                input: "nav_covariance",
            });
        }
        for (i, m) in VARIANCE_CEILING.iter().take(9).enumerate() {
            if nav_covariance.get((i, i)).is_some_and(|v| *v > T::lit(*m)) {
                return Err(NavError::InputOutOfRange {
                    input: "nav_covariance",
                });
            }
        }
        if crate::math::kalman::asymmetry(nav_covariance) > T::zero()
            || !crate::math::kalman::is_psd(nav_covariance, T::lit(1e-6))
        {
            return Err(NavError::CovarianceNotPositiveSemiDefinite);
        }
        let ins = Ins::new(state, self.config.imu_dt_s)?;
        let zero = T::zero();
        for (j, col) in self.p.as_mut_slice().chunks_exact_mut(STATES).enumerate() {
            for (i, v) in col.iter_mut().enumerate() {
                if i < 9 && j < 9 {
                    *v = nav_covariance.get((i, j)).copied().unwrap_or(zero);
                } else if i < 9 || j < 9 {
                    *v = zero;
                }
            }
        }
        self.ins = ins;
        self.steps_pending = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        self.held_run = 0;
        self.clipped_run = 0;
        self.counters.consecutive_rejections = 0;
        self.health.samples_since_fusion = 0;
        self.health.reinitialisations = self.health.reinitialisations.saturating_add(1);
        self.samples_since_imu_fault = u32::MAX;
        self.last_update = LastUpdate::None;
        Ok(())
    }

    /// How far the solution can be trusted now:
    ///
    /// * `Initialising`: no IMU sample since construction or [`SeekerIns::reinitialise`];
    /// * `NeedsReinitialisation`: the position is outside the model range (|L| ≥ 86°,
    ///   |h| ≥ 1000 km), or a navigation variance is at its ceiling ([`VARIANCE_CEILING`]:
    ///   the filter knows nothing there any more). The filter keeps running (and comes back by
    ///   itself if LOS updates bring the state and P back), but its solution is not to be used
    ///   until then or until [`SeekerIns::reinitialise`];
    /// * `Degraded`: no LOS component fused for [`AID_TIMEOUT_S`], the gate rejecting every
    ///   component of the last updates, the last update conditioned or skipped, or an IMU gap
    ///   or clipped sample within the last [`AID_TIMEOUT_S`];
    /// * `Nominal` otherwise.
    pub fn health(&self) -> HealthState {
        if self.ins.last_increment().is_none() {
            return HealthState::Initialising;
        }
        let at_ceiling = VARIANCE_CEILING
            .iter()
            .take(9)
            .enumerate()
            .any(|(i, m)| self.p.get((i, i)).is_some_and(|v| *v >= T::lit(0.99 * m)));
        if at_ceiling || !self.ins.state().position.is_in_range() {
            return HealthState::NeedsReinitialisation;
        }
        let timeout = self.aid_timeout_samples();
        if self.health.samples_since_fusion > timeout
            || self.samples_since_imu_fault <= timeout
            || self.counters.consecutive_rejections > 0
            || self.last_update == LastUpdate::Degraded
        {
            return HealthState::Degraded;
        }
        HealthState::Nominal
    }

    /// [`AID_TIMEOUT_S`] in IMU samples.
    fn aid_timeout_samples(&self) -> u32 {
        (T::lit(AID_TIMEOUT_S) / self.config.imu_dt_s)
            .to_u32_rounded()
            .unwrap_or(u32::MAX)
    }

    /// What the filter did to stay in its envelope, and the samples since the last fusion.
    pub fn health_counters(&self) -> HealthCounters {
        self.health
    }

    /// Counters of fused / rejected LOS components and recovery inflations.
    pub fn counters(&self) -> LosCounters {
        self.counters
    }

    /// The recovery policy in force.
    pub fn recovery_policy(&self) -> RecoveryPolicy<T> {
        self.recovery
    }

    /// Replaces the recovery policy. Errors (filter unchanged): `InvalidConfig
    /// { field: "inflation_factor" }` unless the factor is in (1, [`MAX_INFLATION_FACTOR`]].
    pub fn set_recovery_policy(&mut self, policy: RecoveryPolicy<T>) -> Result<(), NavError> {
        in_range(
            "inflation_factor",
            policy.inflation_factor,
            T::one(),
            T::lit(MAX_INFLATION_FACTOR),
        )?;
        if policy.inflation_factor <= T::one() {
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

    /// Replaces the IMU fault policy. Errors (filter unchanged): `InvalidConfig` naming the
    /// field outside its range ([`ImuFaultPolicy`]; the joint gap conditions name
    /// `max_gap_samples`, `gap_rate_sigma_rad_s` or `gap_accel_sigma_m_s2`).
    pub fn set_imu_fault_policy(&mut self, policy: ImuFaultPolicy<T>) -> Result<(), NavError> {
        let out_of_range = |field| NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        };
        if policy.max_gap_samples == 0 {
            return Err(NavError::InvalidConfig {
                field: "max_gap_samples",
                issue: ConfigIssue::NotPositive,
            });
        }
        let gap_s = self.config.imu_dt_s * T::from_count(u32::from(policy.max_gap_samples));
        if policy.max_gap_samples > MAX_GAP_SAMPLES || gap_s > T::lit(MAX_GAP_S) {
            return Err(out_of_range("max_gap_samples"));
        }
        let (amax, wmax) = (
            T::lit(MAX_FAULT_ACCEL_SIGMA_M_S2),
            T::lit(MAX_FAULT_RATE_SIGMA_RAD_S),
        );
        for (field, v, max) in [
            ("gap_accel_sigma_m_s2", policy.gap_accel_sigma_m_s2, amax),
            ("gap_rate_sigma_rad_s", policy.gap_rate_sigma_rad_s, wmax),
            ("clip_accel_sigma_m_s2", policy.clip_accel_sigma_m_s2, amax),
            ("clip_rate_sigma_rad_s", policy.clip_rate_sigma_rad_s, wmax),
        ] {
            in_range(field, v, T::zero(), max)?;
        }
        if policy.gap_rate_sigma_rad_s * gap_s > T::lit(MAX_GAP_ATTITUDE_SIGMA_RAD) {
            return Err(out_of_range("gap_rate_sigma_rad_s"));
        }
        if policy.gap_accel_sigma_m_s2 * gap_s > T::lit(MAX_GAP_VELOCITY_SIGMA_M_S) {
            return Err(out_of_range("gap_accel_sigma_m_s2"));
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
            time: inc.time,
            delta_theta_rad: inc.delta_theta_rad - self.gyro_bias_rad_s * dt,
            delta_v_m_s: inc.delta_v_m_s - self.accel_bias_m_s2 * dt,
        };
        self.propagate_compensated(&compensated)?;
        self.held_run = 0;
        self.clipped_run = 0;
        self.samples_since_imu_fault = self.samples_since_imu_fault.saturating_add(1);
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
            time: inc.time,
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
        self.samples_since_imu_fault = 0;
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
        let mut held = held;
        for _ in 0..missing_samples {
            held.time = held.time.add_micros(self.ins.dt_us());
            next.propagate_compensated(&held)?;
            next.held_run = next.held_run.saturating_add(1);
            next.inflate_degraded(next.held_run, sa, sw);
        }
        next.imu_counters.gaps = next.imu_counters.gaps.saturating_add(1);
        next.imu_counters.held_samples = next
            .imu_counters
            .held_samples
            .saturating_add(u32::from(missing_samples));
        next.samples_since_imu_fault = 0;
        *self = next;
        Ok(())
    }

    /// Adds `(2c − 1)(σ Δt)²` to the velocity and attitude variances ([`ImuFaultPolicy`]),
    /// then limits them to their ceilings. Not inlined: one copy serves the gap and the
    /// clipping paths.
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
        self.limit_variances();
    }

    /// Brings every navigation variance above its ceiling back to it by scaling its row and
    /// column (a congruence: P stays symmetric PSD, correlations are kept). Nine compares when
    /// nothing is limited.
    #[inline(never)]
    fn limit_variances(&mut self) {
        for (i, m) in VARIANCE_CEILING.iter().take(9).enumerate() {
            let i = opaque(i);
            let cap = T::lit(*m);
            let Some(d) = self.p.get((i, i)).copied() else {
                continue;
            };
            if d > cap {
                let f = (cap / d).sqrt();
                for v in self.p.column_mut(i).iter_mut() {
                    *v *= f;
                }
                for v in self.p.row_mut(i).iter_mut() {
                    *v *= f;
                }
                self.health.variance_limits = self.health.variance_limits.saturating_add(1);
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
            let repairs = Self::covariance_step(
                &mut self.p,
                &ins,
                steps,
                &dv_pending,
                &self.config,
                self.q_accel,
                self.q_gyro,
            )?;
            self.after_covariance_step(repairs);
            self.steps_pending = 0;
            self.dv_ned_pending_m_s = Vector3::zeros();
        } else {
            self.steps_pending = steps;
            self.dv_ned_pending_m_s = dv_pending;
        }
        let h = &mut self.health;
        h.samples_since_fusion = h.samples_since_fusion.saturating_add(1);
        if !ins.state().position.is_in_range() {
            h.out_of_range_samples = h.out_of_range_samples.saturating_add(1);
        }
        self.ins = ins;
        Ok(())
    }

    /// Counts the repairs of a covariance step and limits the variances.
    fn after_covariance_step(&mut self, repairs: u32) {
        self.health.covariance_repairs = self.health.covariance_repairs.saturating_add(repairs);
        self.limit_variances();
    }

    /// Propagates P over the IMU samples accumulated since the last covariance step (no-op if
    /// none). Errors leave the filter unchanged.
    pub fn predict_covariance(&mut self) -> Result<(), NavError> {
        if self.steps_pending == 0 {
            return Ok(());
        }
        let repairs = Self::covariance_step(
            &mut self.p,
            &self.ins,
            self.steps_pending,
            &self.dv_ned_pending_m_s,
            &self.config,
            self.q_accel,
            self.q_gyro,
        )?;
        self.after_covariance_step(repairs);
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
    ) -> Result<u32, NavError> {
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
        let sigma = self.config.seeker_noise_rad;
        validate_gimbal(measured, sigma)?;
        let corrected = GimbalAngles {
            pitch_rad: measured.pitch_rad - self.gimbal_bias_rad.x,
            yaw_rad: measured.yaw_rad - self.gimbal_bias_rad.y,
        };
        let s = self.ins.state();
        let d = landmark_vector_ned(&s.position, &self.config.landmark);
        let range = d.norm();
        if !s.position.is_in_range() {
            let range = if range.is_finite() { range } else { T::zero() };
            return Ok(self.skip_all(range, LosSkipReason::PositionOutOfRange));
        }
        if !range.is_finite() || range < T::lit(MIN_LANDMARK_RANGE_M) {
            let range = if range.is_finite() { range } else { T::zero() };
            return Ok(self.skip_all(range, LosSkipReason::LandmarkTooClose));
        }
        if validate_gimbal(&corrected, sigma).is_err() {
            return Ok(self.skip_all(range, LosSkipReason::GimbalBeyondLimit));
        }
        let gate = Gate::Nis(self.config.gate_nis);
        let c_b_n = self.ins.c_b_n();
        #[cfg(feature = "los-residual-3d")]
        if self.config.residual == LosResidual::FullRank3d {
            return self.update_los_3d(&corrected, &c_b_n, gate);
        }
        let model = los_model_at(&s.position, &d, &c_b_n, &corrected, sigma)?;
        let zero = T::zero();
        let kappa = max_information_ratio::<T>();
        let p = &self.p;
        // k = P h over the 8 non-zero entries of h (columns 0..3, 6..9, 15..17 of P).
        let ph = |h: &SVector<T, STATES>| -> [T; STATES] { covariance_times_dense_row(p, h) };
        let dot = |a: &[T; STATES], h: &SVector<T, STATES>| -> T { dot_rolled(a, h.as_slice()) };
        // Component 1 (pitch direction).
        let h1 = &model.h_pitch;
        let k1 = ph(h1);
        let hph1 = dot(&k1, h1);
        let (r1, cond1) = conditioned_noise(hph1, model.variance_rad2.x, kappa);
        let (rep1, inv_s1) = scalar_report(hph1, r1, model.residual_rad.x, gate);
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
        let hph2 = dot(&k2, h2);
        let (r2, cond2) = conditioned_noise(hph2, model.variance_rad2.y, kappa);
        let (rep2, inv_s2) = scalar_report(hph2, r2, nu2, gate);
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
        let skipped = (rep1.outcome == FusionOutcome::Skipped
            || rep2.outcome == FusionOutcome::Skipped)
            .then_some(LosSkipReason::NumericalLimit);
        let report = LosReport {
            pitch: rep1,
            yaw: rep2,
            range_m: model.range_m,
            skipped,
        };
        if !(fused1 || fused2) {
            self.note_no_fusion(&[rep1.outcome, rep2.outcome]);
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
                return Ok(self.skip_attempt(report, LosSkipReason::NumericalLimit));
            }
        }
        let xv = SVector::<T, STATES>::from(x);
        // Feedback first: it is atomic (the INS validates before it changes) and only P, which
        // cannot fail any more, follows.
        if self.feed_back_parts(&xv).is_err() {
            return Ok(self.skip_attempt(report, LosSkipReason::CorrectionNotFinite));
        }
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
        stabilise(&mut self.p);
        let conditioned = (fused1 && cond1) || (fused2 && cond2);
        self.note_fusion(
            &[rep1.outcome, rep2.outcome],
            u32::from(fused1 && cond1) + u32::from(fused2 && cond2),
        );
        if conditioned {
            self.last_update = LastUpdate::Degraded;
        }
        Ok(report)
    }

    /// Counts a fusion: components by outcome, `conditioned` of them fused with raised r.
    fn note_fusion(&mut self, outcomes: &[FusionOutcome], conditioned: u32) {
        let count = |o: FusionOutcome| outcomes.iter().filter(|x| **x == o).count() as u32;
        let c = &mut self.counters;
        c.fused = c.fused.saturating_add(count(FusionOutcome::Fused));
        c.rejected = c.rejected.saturating_add(count(FusionOutcome::Rejected));
        c.skipped = c.skipped.saturating_add(count(FusionOutcome::Skipped));
        c.conditioned = c.conditioned.saturating_add(conditioned);
        c.consecutive_rejections = 0;
        self.health.samples_since_fusion = 0;
        self.last_update = if count(FusionOutcome::Skipped) > 0 {
            LastUpdate::Degraded
        } else {
            LastUpdate::Clean
        };
    }

    /// Every component skipped for `reason` before an attempt (nothing computed): counted,
    /// nothing else changes.
    fn skip_all(&mut self, range_m: T, reason: LosSkipReason) -> LosReport<T> {
        let zero = T::zero();
        let none = FusionReport {
            innovation: zero,
            innovation_variance: zero,
            nis: zero,
            test_ratio: zero,
            outcome: FusionOutcome::Skipped,
        };
        let report = LosReport {
            pitch: none,
            yaw: none,
            range_m,
            skipped: Some(reason),
        };
        self.note_no_fusion(&[FusionOutcome::Skipped, FusionOutcome::Skipped]);
        report
    }

    /// An attempted update that cannot be committed: its fused components become skipped.
    fn skip_attempt(&mut self, mut report: LosReport<T>, reason: LosSkipReason) -> LosReport<T> {
        for c in [&mut report.pitch, &mut report.yaw] {
            if c.outcome == FusionOutcome::Fused {
                c.outcome = FusionOutcome::Skipped;
            }
        }
        report.skipped = Some(reason);
        self.note_no_fusion(&[report.pitch.outcome, report.yaw.outcome]);
        report
    }

    /// No component fused: count; when every component was rejected by the gate, count the
    /// run and re-inflate P per [`RecoveryPolicy`].
    fn note_no_fusion(&mut self, outcomes: &[FusionOutcome]) {
        let count = |o: FusionOutcome| outcomes.iter().filter(|x| **x == o).count() as u32;
        let skipped = count(FusionOutcome::Skipped);
        let c = &mut self.counters;
        c.rejected = c.rejected.saturating_add(count(FusionOutcome::Rejected));
        c.skipped = c.skipped.saturating_add(skipped);
        if skipped > 0 {
            self.last_update = LastUpdate::Degraded;
            return;
        }
        self.last_update = LastUpdate::Clean;
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
            self.limit_variances();
        }
    }

    /// The comparison variant: three scalar updates with the shared `fuse_scalar` on a copy
    /// (not inlined: its copy of the filter stays out of the 2-D path's stack frame). The same
    /// conditioning of r; a component `fuse_scalar` cannot fuse is skipped.
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
        let kappa = max_information_ratio::<T>();
        let mut conditioned = 0u32;
        let mut fuse = |x: &mut SVector<T, STATES>,
                        p: &mut SMatrix<T, STATES, STATES>,
                        h: &SVector<T, STATES>,
                        z: T|
         -> FusionReport<T> {
            let nu = z - h.dot(x);
            let hph = (*p * h).dot(h);
            let (r_eff, cond) = conditioned_noise(hph, r, kappa);
            match fuse_scalar(x, p, h, nu, r_eff, gate) {
                Ok(rep) => {
                    if cond && rep.outcome == FusionOutcome::Fused {
                        conditioned += 1;
                    }
                    rep
                }
                Err(_) => skipped_report(nu),
            }
        };
        let n = fuse(&mut x, &mut next.p, &model.h_north, model.residual.x);
        let e = fuse(&mut x, &mut next.p, &model.h_east, model.residual.y);
        let d = fuse(&mut x, &mut next.p, &model.h_down, model.residual.z);
        let outcomes = [n.outcome, e.outcome, d.outcome];
        let any_skipped = outcomes.contains(&FusionOutcome::Skipped);
        let report = LosReport {
            pitch: n,
            yaw: e,
            range_m: model.range_m,
            skipped: any_skipped.then_some(LosSkipReason::NumericalLimit),
        };
        if outcomes.contains(&FusionOutcome::Fused) {
            if next.feed_back_parts(&x).is_err() {
                return Ok(self.skip_attempt(report, LosSkipReason::CorrectionNotFinite));
            }
            stabilise(&mut next.p);
            next.note_fusion(&outcomes, conditioned);
            if conditioned > 0 {
                next.last_update = LastUpdate::Degraded;
            }
        } else {
            next.note_no_fusion(&outcomes);
        }
        *self = next;
        Ok(report)
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

/// Relative variance added to every state after a fused LOS update, in units of ε of the
/// working precision (`stabilise`).
pub const STABILISING_EPS: f64 = 256.0;

/// Stabilising noise `P ← P + δ diag(P)`, `δ = STABILISING_EPS · ε` (3.1e-5 in f32): the
/// correlation matrix becomes `(C + δ I)/(1 + δ)`, so its smallest eigenvalue is at least
/// `δ/(1 + δ)` — a margin above the rounding of the next propagation and update. Without it an
/// f32 P that the updates have made singular to working precision (a combination of states
/// known to the seeker's precision) turns indefinite, and the next precise LOS, fused into an
/// indefinite prior, commits a P with a correlation eigenvalue of −0.27 (measured, seeker
/// σ = 1e-5 rad).
#[inline(never)]
fn stabilise<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>) {
    let delta = T::lit(STABILISING_EPS) * T::EPS;
    for i in 0..N {
        if let Some(v) = p.get_mut((i, i)) {
            *v += *v * delta;
        }
    }
}

/// Checks a configuration value: finite and in [lo, hi] (`InvalidConfig` naming `field`).
#[inline(never)]
fn in_range<T: Real>(field: &'static str, v: T, lo: T, hi: T) -> Result<(), NavError> {
    if !v.is_finite() {
        return Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotFinite,
        });
    }
    if v < lo || v > hi {
        return Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
}

/// The ranges of [`SeekerInsConfig`] (its field docs).
fn validate_config<T: Real>(config: &SeekerInsConfig<T>) -> Result<(), NavError> {
    use crate::error::{require_non_negative, require_positive};
    let c = config;
    require_positive("imu_dt_s", c.imu_dt_s)?;
    in_range("imu_dt_s", c.imu_dt_s, T::lit(1e-4), T::lit(0.1))?;
    let (a, g) = (
        c.accel_noise_density_m_s2_rt_hz,
        c.gyro_noise_density_rad_s_rt_hz,
    );
    require_non_negative("accel_noise_density_m_s2_rt_hz", a)?;
    in_range("accel_noise_density_m_s2_rt_hz", a, T::zero(), T::lit(0.1))?;
    require_non_negative("gyro_noise_density_rad_s_rt_hz", g)?;
    in_range("gyro_noise_density_rad_s_rt_hz", g, T::zero(), T::lit(0.01))?;
    require_positive("seeker_noise_rad", c.seeker_noise_rad)?;
    in_range(
        "seeker_noise_rad",
        c.seeker_noise_rad,
        T::lit(1e-5),
        T::lit(0.1),
    )?;
    require_positive("gate_nis", c.gate_nis)?;
    in_range("gate_nis", c.gate_nis, T::one(), T::lit(1e4))?;
    if cfg!(not(feature = "los-residual-3d")) && c.residual == LosResidual::FullRank3d {
        return Err(NavError::InvalidConfig {
            field: "residual",
            issue: ConfigIssue::OutOfRange,
        });
    }
    if c.covariance_interval_steps == 0 {
        return Err(NavError::InvalidConfig {
            field: "covariance_interval_steps",
            issue: ConfigIssue::NotPositive,
        });
    }
    let interval_s = c.imu_dt_s * T::from_count(u32::from(c.covariance_interval_steps));
    if interval_s > T::lit(1.0) {
        return Err(NavError::InvalidConfig {
            field: "covariance_interval_steps",
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
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

/// The noise variance a scalar component is fused with: `r`, or `hph / kappa` when the
/// component would carry more information than the working precision resolves
/// ([`max_information_ratio`]); `true` when raised.
#[inline(always)]
fn conditioned_noise<T: Real>(hph: T, r: T, kappa: T) -> (T, bool) {
    let floor = hph / kappa;
    if floor > r {
        (floor, true)
    } else {
        (r, false)
    }
}

/// The report of a component that could not be fused (non-finite numbers reported as 0).
fn skipped_report<T: Real>(innovation: T) -> FusionReport<T> {
    let zero = T::zero();
    FusionReport {
        innovation: if innovation.is_finite() {
            innovation
        } else {
            zero
        },
        innovation_variance: zero,
        nis: zero,
        test_ratio: zero,
        outcome: FusionOutcome::Skipped,
    }
}

/// Innovation variance, NIS and χ² gate of one scalar component with `hᵀPh = hph`: the report
/// and `1/s`. A component whose s is not finite and > 0 (or hᵀPh < 0, or a non-finite
/// innovation) is reported [`FusionOutcome::Skipped`] with `1/s = 0`.
fn scalar_report<T: Real>(hph: T, r: T, innovation: T, gate: Gate<T>) -> (FusionReport<T>, T) {
    let s = hph + r;
    if !s.is_finite() || s <= T::zero() || hph < T::zero() || !innovation.is_finite() {
        return (skipped_report(innovation), T::zero());
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
    (
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
    )
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

//! The transfer-alignment Kalman filter: one implementation for the conventional 9-state
//! ([`ConventionalFilter`], 2nd-order flexure) and the proposed 12-state
//! ([`ProposedFilter`], 3rd-order flexure with θ̈_f) models.
//!
//! Each [`TransferAlignment::step`] takes a time-stamped master sample and the slave IMU sample
//! of the same epoch, compensates the lever arm, predicts the state to the epoch and fuses the
//! six scalar measurements `dω_X, dω_Y, dω_Z, df_X, df_Y, df_Z` sequentially (Joseph form,
//! [`fuse_scalar`]) with an optional NIS gate, returning one report per update.
//!
//! # Time
//!
//! Time stamps are [`Timestamp`]s (integer µs). The filter keeps its own prediction grid: the
//! time of its state, advanced by whole steps of `dt_s` (rounded once to whole µs) in integer
//! arithmetic. A sample stamped `t` is fused at the grid point nearest to `t` (the filter
//! predicts `round((t − grid) / dt)` steps, possibly 0 when jitter puts two samples in one
//! step), so any interval is accepted — jitter, late and missing samples — and the grid never
//! drifts from the flight computer's clock (|t − grid| ≤ dt/2 at every fused epoch). Φ and Q_d
//! stay the precomputed ones of `dt_s` (see the README for the measurement behind this choice).
//! A gap longer than `max_gap_steps` (at most [`MAX_GAP_STEPS`]) is not predicted step by step:
//! the flexure states are re-initialised to their stationary prior and θ_m is kept (see
//! [`GapOutcome::FlexureReinitialised`]), so the work of one call is bounded.
//!
//! # Parametrisation and numerics
//!
//! Internally each axis chain is `[θ, θ_f, θ̇_f(, θ̈_f)]` with the *total* misalignment
//! θ = θ_m + θ_f in place of θ_m (the measurements see only the sum; carrying θ_m and θ_f
//! separately makes their sum's variance a difference of two large, almost opposite numbers,
//! which f32 cannot hold: the stalls of the older filter). θ_m = θ − θ_f is an output. The
//! design ([`TaDesign`]) is still expressed in θ_m: [`TransferAlignment::from_design`]
//! transforms it once (`Φ' = T Φ T⁻¹`, `Q' = T Q Tᵀ`, `T` adding θ_f onto θ_m).
//!
//! Each scalar update is fused with a measurement variance of at least
//! `hᵀ P h / MAX_VARIANCE_REDUCTION` ([`MAX_VARIANCE_REDUCTION`]): one update never divides a
//! variance by more than that ratio, so the Joseph update never subtracts two numbers that agree
//! to more digits than f32 has (a conservative update; it only acts on the first epochs of a
//! very precise sensor against a wide prior). An update that still cannot be fused (innovation
//! variance not positive, a variance that would turn negative) is skipped
//! ([`FusionOutcome::Skipped`]): the step goes on with its prediction and the time advances.
//!
//! Structure used for the target:
//! - the state is stored axis-major, so Φ = blockdiag(Φ_X, Φ_Y, Φ_Z) (K×K each, first column
//!   e₁) and `P ← Φ P Φᵀ + Q_d` is done per 3×3 pair of axis blocks, upper triangle only,
//!   mirrored;
//! - H rows are sparse: each of the six rows is built with a constant row number, so its
//!   pattern (at most 4 of the N columns) folds to constants; `b = P h`
//!   ([`covariance_times_row`]) and the Joseph update ([`fuse_scalar_prepared`]) are shared, one
//!   out-of-line copy per N;
//! - all work is done on copies and committed at the end: an error leaves the filter untouched.
use super::design::TaDesign;
use super::measurement::{h_row_total, measurement, MasterSample, SlaveSample};
use super::model::{axis_index, AxisChain, AxisFlexure, FlexureModel};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::health::HealthState;
use crate::math::checks::all_finite_parts;
#[allow(unused_imports)]
use crate::math::kalman::fuse_scalar;
use crate::math::kalman::{
    covariance_times_row, fuse_scalar_prepared, FusionOutcome, FusionReport, Gate,
};
use crate::math::rotation::exp_so3;
use crate::time::{seconds_to_micros, Timestamp};
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Shortest filter step, s (1 kHz).
pub const MIN_DT_S: f64 = 1.0e-3;
/// Longest filter step, s (100 Hz).
pub const MAX_DT_S: f64 = 1.0e-2;
/// Smallest stationary flexure 1σ, rad (0.01°).
pub const MIN_FLEXURE_SIGMA_RAD: f64 = 1.745_329_251_994_33e-4;
/// Largest stationary flexure 1σ, rad (2°).
pub const MAX_FLEXURE_SIGMA_RAD: f64 = 3.490_658_503_988_66e-2;
/// Shortest flexure correlation time, s.
pub const MIN_FLEXURE_TAU_S: f64 = 0.05;
/// Longest flexure correlation time, s.
pub const MAX_FLEXURE_TAU_S: f64 = 1.0e4;
/// The correlation time must be at least this many filter steps (β dt ≤ 0.58 for the 3rd order
/// model: the flexure is resolved by the step).
pub const MIN_TAU_STEPS: f64 = 5.0;
/// Largest initial 1σ of the mounting misalignment, rad (≈ 5.7°, small-angle model).
pub const MAX_MOUNT_SIGMA_RAD: f64 = 0.1;
/// Range of the rate-difference 1σ `rate_noise_sigma_rad_s`, rad/s.
pub const RATE_NOISE_SIGMA_RANGE_RAD_S: (f64, f64) = (1.0e-4, 0.1);
/// Range of the specific-force-difference 1σ `accel_noise_sigma_m_s2`, m/s².
pub const ACCEL_NOISE_SIGMA_RANGE_M_S2: (f64, f64) = (1.0e-3, 1.0);
/// Largest |lever-arm component|, m.
pub const MAX_LEVER_ARM_M: f64 = 100.0;
/// Range of the χ²(1) NIS gate threshold.
pub const NIS_GATE_RANGE: (f64, f64) = (1.0, 1.0e4);
/// Largest `max_gap_steps`: the most predictions one call can run (bounded work per call:
/// see the README for the instruction count).
pub const MAX_GAP_STEPS: u32 = 100;
/// One scalar update divides a variance by at most this ratio (`r ≥ hᵀPh / ratio`): keeps the
/// Joseph update's subtraction within f32's digits (chosen by the stress campaign).
pub const MAX_VARIANCE_REDUCTION: f64 = 1.0e4;
/// Every committed covariance gets `P_ii ← P_ii (1 + PSD_LOADING_EPS · ε)` (ε the float type's
/// machine epsilon: ≈ 1.5e-5 in f32, 2.8e-14 in f64): a PSD diagonal that keeps the
/// correlation matrix's smallest eigenvalue above the rounding of one step (chosen by the
/// stress campaign).
pub const PSD_LOADING_EPS: f64 = 16.0;

/// Epochs without an anomaly (skipped update, re-initialised flexure, covariance reset) after
/// which [`HealthState::Degraded`] returns to [`HealthState::Nominal`].
pub const DEGRADED_HOLD_EPOCHS: u32 = 100;
/// Consecutive epochs with every update skipped after which the filter reports
/// [`HealthState::NeedsReinitialisation`].
pub const SKIPPED_EPOCHS_FOR_REINIT: u32 = 100;
/// |θ| beyond which (any axis, rad) the small-angle model no longer holds and the filter
/// reports [`HealthState::NeedsReinitialisation`] (≈ 17°).
pub const MAX_MISALIGNMENT_RAD: f64 = 0.3;

/// Configuration of a transfer-alignment filter (all units in the names; σ are 1σ).
///
/// The envelope (checked by [`Self::validate`], `InvalidConfig { field }` outside it) is where
/// the stress campaign has run the filter in f32 without a stall, a non-PSD covariance or a
/// non-finite output: see the `MIN_*`/`MAX_*` constants of this module.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaConfig<T> {
    /// Nominal lever arm L_0 from the master to the slave IMU, master axes, m (spec: `[0, l, 0]`);
    /// each component within ±[`MAX_LEVER_ARM_M`].
    pub lever_arm_m: Vector3<T>,
    /// Flexure model per axis X, Y, Z: stationary 1σ of θ_f (rad, [`MIN_FLEXURE_SIGMA_RAD`] to
    /// [`MAX_FLEXURE_SIGMA_RAD`]) and correlation time (s, [`MIN_FLEXURE_TAU_S`] to
    /// [`MAX_FLEXURE_TAU_S`], and at least [`MIN_TAU_STEPS`] × `dt_s`).
    pub flexure: [AxisFlexure<T>; 3],
    /// Initial 1σ of the mounting misalignment θ_m per axis, rad (spec: 0.5°; 0 to
    /// [`MAX_MOUNT_SIGMA_RAD`]).
    pub mount_sigma_rad: Vector3<T>,
    /// 1σ of one angular-rate difference sample dω (master + slave gyro noise), rad/s
    /// ([`RATE_NOISE_SIGMA_RANGE_RAD_S`]).
    pub rate_noise_sigma_rad_s: T,
    /// 1σ of one specific-force difference sample df (master + slave accelerometer noise), m/s²
    /// ([`ACCEL_NOISE_SIGMA_RANGE_M_S2`]).
    pub accel_noise_sigma_m_s2: T,
    /// Filter step (= nominal slave IMU sample interval), s: [`MIN_DT_S`] to [`MAX_DT_S`], a
    /// whole number of µs.
    pub dt_s: T,
    /// Allowed |t_master − t_slave| when pairing samples, s (0 ≤ tolerance < dt_s / 2; rounded
    /// to whole µs).
    pub time_tolerance_s: T,
    /// Longest gap, in steps, bridged by repeated prediction (1 to [`MAX_GAP_STEPS`]); a longer
    /// gap re-initialises the flexure states ([`GapOutcome::FlexureReinitialised`]).
    pub max_gap_steps: u32,
    /// χ²(1) NIS gate of each scalar update (e.g. 25 = 5σ; [`NIS_GATE_RANGE`]); `None` fuses
    /// everything.
    pub nis_gate: Option<T>,
}

#[cold]
#[inline(never)]
fn out_of_range(field: &'static str) -> NavError {
    NavError::InvalidConfig {
        field,
        issue: ConfigIssue::OutOfRange,
    }
}

/// `Ok` when `lo ≤ v ≤ hi` (v already known finite and positive or non-negative).
fn within<T: Real>(field: &'static str, v: T, lo: f64, hi: f64) -> Result<(), NavError> {
    if v >= T::lit(lo) && v <= T::lit(hi) {
        Ok(())
    } else {
        Err(out_of_range(field))
    }
}

impl<T: Real> TaConfig<T> {
    /// Validates every field against the envelope (typed `InvalidConfig` naming the field):
    /// finiteness and sign first, then the ranges of the `MIN_*`/`MAX_*` constants and the joint
    /// conditions (τ ≥ [`MIN_TAU_STEPS`] dt, tolerance < dt/2, dt a whole number of µs).
    pub fn validate(&self) -> Result<(), NavError> {
        // (`opaque`: the loops stay rolled, configuration time only.)
        use crate::math::checks::opaque;
        for v in opaque(self.lever_arm_m.as_slice()) {
            crate::error::require_finite("lever_arm_m", *v)?;
            within("lever_arm_m", v.abs(), 0.0, MAX_LEVER_ARM_M)?;
        }
        require_positive("dt_s", self.dt_s)?;
        within("dt_s", self.dt_s, MIN_DT_S, MAX_DT_S)?;
        let dt_us = self.dt_us()?;
        for fl in opaque(self.flexure.as_slice()) {
            require_positive("flexure.sigma_rad", fl.sigma_rad)?;
            require_positive("flexure.tau_s", fl.tau_s)?;
            within(
                "flexure.sigma_rad",
                fl.sigma_rad,
                MIN_FLEXURE_SIGMA_RAD,
                MAX_FLEXURE_SIGMA_RAD,
            )?;
            within(
                "flexure.tau_s",
                fl.tau_s,
                MIN_FLEXURE_TAU_S,
                MAX_FLEXURE_TAU_S,
            )?;
            if fl.tau_s < T::lit(MIN_TAU_STEPS) * self.dt_s {
                return Err(out_of_range("flexure.tau_s"));
            }
        }
        for v in opaque(self.mount_sigma_rad.as_slice()) {
            require_non_negative("mount_sigma_rad", *v)?;
            within("mount_sigma_rad", *v, 0.0, MAX_MOUNT_SIGMA_RAD)?;
        }
        require_positive("rate_noise_sigma_rad_s", self.rate_noise_sigma_rad_s)?;
        within(
            "rate_noise_sigma_rad_s",
            self.rate_noise_sigma_rad_s,
            RATE_NOISE_SIGMA_RANGE_RAD_S.0,
            RATE_NOISE_SIGMA_RANGE_RAD_S.1,
        )?;
        require_positive("accel_noise_sigma_m_s2", self.accel_noise_sigma_m_s2)?;
        within(
            "accel_noise_sigma_m_s2",
            self.accel_noise_sigma_m_s2,
            ACCEL_NOISE_SIGMA_RANGE_M_S2.0,
            ACCEL_NOISE_SIGMA_RANGE_M_S2.1,
        )?;
        require_non_negative("time_tolerance_s", self.time_tolerance_s)?;
        match seconds_to_micros(self.time_tolerance_s) {
            Some(tol) if 2 * tol < dt_us => {}
            _ => return Err(out_of_range("time_tolerance_s")),
        }
        if self.max_gap_steps == 0 || self.max_gap_steps > MAX_GAP_STEPS {
            return Err(out_of_range("max_gap_steps"));
        }
        if let Some(g) = self.nis_gate {
            require_positive("nis_gate", g)?;
            within("nis_gate", g, NIS_GATE_RANGE.0, NIS_GATE_RANGE.1)?;
        }
        Ok(())
    }

    /// `dt_s` in whole µs; `InvalidConfig { field: "dt_s" }` unless it is one to within 0.01 µs.
    fn dt_us(&self) -> Result<u64, NavError> {
        let us = seconds_to_micros(self.dt_s).ok_or_else(|| out_of_range("dt_s"))?;
        let exact = self.dt_s * T::lit(1.0e6);
        // us ≤ 10⁴: exact in f32.
        let whole = T::from_count(u32::try_from(us).unwrap_or(u32::MAX));
        if (exact - whole).abs() > T::lit(0.01) {
            return Err(out_of_range("dt_s"));
        }
        Ok(us)
    }
}

impl<T: Real> TaConfig<T> {
    /// [`Self::validate`], then `(R_rate, R_accel, dt µs, tolerance µs)` (`σ²` of the rate and
    /// specific-force differences, (rad/s)² and (m/s²)²). Shared by both filters'
    /// `from_design` (one out-of-line copy per float type).
    #[inline(never)]
    fn validated_noise(&self) -> Result<(T, T, u64, u64), NavError> {
        self.validate()?;
        let r_rate = self.rate_noise_sigma_rad_s * self.rate_noise_sigma_rad_s;
        let r_accel = self.accel_noise_sigma_m_s2 * self.accel_noise_sigma_m_s2;
        let dt_us = self.dt_us()?;
        let tol_us = seconds_to_micros(self.time_tolerance_s)
            .ok_or_else(|| out_of_range("time_tolerance_s"))?;
        Ok((r_rate, r_accel, dt_us, tol_us))
    }
}

/// How the filter got from its previous epoch to this one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GapOutcome {
    /// The first epoch: the clock started here, nothing predicted.
    Started,
    /// Predicted `predictions` steps (0 when jitter put this sample in the previous one's step).
    Predicted,
    /// The gap was longer than `max_gap_steps`: the flexure states were re-initialised to their
    /// stationary prior (mean 0, stationary covariance, no correlation with θ_m), θ_m was kept
    /// and its variance grown by the flexure's stationary variance (the part of θ that the
    /// filter may have put in θ_m), capped at the initial σ_m² plus that variance. Counted in
    /// [`TaHealth::flexure_reinitialisations`].
    FlexureReinitialised,
}

/// What the prediction part of a call did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Propagation {
    /// Prediction steps run (at most `max_gap_steps`).
    pub predictions: u32,
    /// How the gap was bridged.
    pub gap: GapOutcome,
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport<T> {
    /// Time stamp of the epoch (the slave sample's).
    pub time: Timestamp,
    /// Number of prediction steps done before the update (0 at the first epoch).
    pub predictions: u32,
    /// How the gap from the previous epoch was bridged.
    pub gap: GapOutcome,
    /// One report per scalar update, in the order dω_X, dω_Y, dω_Z, df_X, df_Y, df_Z. Every
    /// number is finite.
    pub updates: [FusionReport<T>; 6],
}

/// Largest |ω_m|, |ω_s| accepted per axis, rad/s (≈ 2 900 °/s, above any tactical gyro's range).
pub const MAX_ANGULAR_RATE_RAD_S: f64 = 50.0;
/// Largest |ω̇_m| accepted per axis, rad/s².
pub const MAX_ANGULAR_ACCEL_RAD_S2: f64 = 1.0e4;
/// Largest |f_m|, |f_s| accepted per axis, m/s² (≈ 200 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 2.0e3;

/// Recovery from measurement starvation by the χ² gate (see [`TransferAlignment::health`]).
///
/// When one measurement channel has been rejected by the gate at `reset_after_rejections`
/// consecutive epochs, the filter concludes that its covariance is too small for what it sees
/// (a fault it did not model, or a transient that left it overconfident) and re-inflates it:
/// P ← P0 (the initial covariance: σ_m² on θ_m, the stationary flexure covariance), the flexure
/// states are reset to their prior mean 0, θ_m keeps its estimate. The reset is counted in
/// [`TaHealth::covariance_resets`]. `None` disables it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecoveryPolicy {
    /// Consecutive gated epochs of one channel that trigger the covariance reset (≥ 1).
    pub reset_after_rejections: Option<u32>,
}

impl Default for RecoveryPolicy {
    /// Reset after 50 consecutive rejections of a channel (0.5 s at 100 Hz).
    fn default() -> Self {
        Self {
            reset_after_rejections: Some(50),
        }
    }
}

/// Health of the filter: its [`HealthState`] and the counters behind it (channels dω_X..Z,
/// df_X..Z).
///
/// - `Initialising` until the first epoch;
/// - `Degraded` for [`DEGRADED_HOLD_EPOCHS`] epochs after an update was skipped, the flexure
///   was re-initialised after a long gap, or the [`RecoveryPolicy`] reset the covariance;
/// - `NeedsReinitialisation` when every update has been skipped for
///   [`SKIPPED_EPOCHS_FOR_REINIT`] epochs or |θ| left the small-angle range
///   ([`MAX_MISALIGNMENT_RAD`]); steps still run, and
///   [`TransferAlignment::reinitialise`] is the way back;
/// - `Nominal` otherwise.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaHealth {
    /// The state.
    pub state: HealthState,
    /// Measurements rejected by the χ² gate since construction, per channel.
    pub rejected: [u32; 6],
    /// Current run of consecutive rejections, per channel.
    pub consecutive_rejected: [u32; 6],
    /// Measurements skipped because they could not be fused in the working precision, per
    /// channel.
    pub skipped: [u32; 6],
    /// Current run of epochs in which every update was skipped.
    pub consecutive_all_skipped: u32,
    /// Covariance resets done by the [`RecoveryPolicy`].
    pub covariance_resets: u32,
    /// Flexure re-initialisations after gaps longer than `max_gap_steps`, and by
    /// [`TransferAlignment::reinitialise`].
    pub flexure_reinitialisations: u32,
    /// Epochs since the last anomaly (saturating).
    pub epochs_since_anomaly: u32,
}

/// Transfer-alignment filter with `K` states per axis chain and `N = 3 K` states.
/// Use [`ConventionalFilter`] (K = 3) or [`ProposedFilter`] (K = 4).
///
/// The covariance is double-buffered: a step predicts from the current buffer into the other
/// one, fuses there, and only then makes it current, so an error leaves the filter untouched
/// without copying P. The `Debug` output shows the state (current buffer only).
#[derive(Clone)]
pub struct TransferAlignment<T: Real, const K: usize, const N: usize> {
    cfg: TaConfig<T>,
    model: FlexureModel,
    /// The design (θ_m parametrisation, as computed by [`TaDesign`]).
    chains: [AxisChain<T, K>; 3],
    /// Per-axis transition in the filter's θ parametrisation (first column e₁).
    phi: [SMatrix<T, K, K>; 3],
    /// Per-axis discrete process noise in the θ parametrisation.
    q_d: [SMatrix<T, K, K>; 3],
    /// Variance ceilings, axis-major (see [`condition`]).
    ceiling: SVector<T, N>,
    /// State, axis-major, θ parametrisation.
    x: SVector<T, N>,
    /// Covariance, axis-major: `p[cur]` is current, the other one scratch.
    p: [SMatrix<T, N, N>; 2],
    second: bool,
    r_rate: T,
    r_accel: T,
    dt_us: u64,
    tol_us: u64,
    /// Time of the state (the prediction grid), once started.
    grid: Option<Timestamp>,
    /// Time stamp of the last accepted sample.
    last: Option<Timestamp>,
    recovery: RecoveryPolicy,
    health: TaHealth,
}

impl<T: Real, const K: usize, const N: usize> core::fmt::Debug for TransferAlignment<T, K, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TransferAlignment")
            .field("cfg", &self.cfg)
            .field("model", &self.model)
            .field("chains", &self.chains)
            .field("phi", &self.phi)
            .field("q_d", &self.q_d)
            .field("ceiling", &self.ceiling)
            .field("x", &self.x)
            .field("p", self.p_cur())
            .field("r_rate", &self.r_rate)
            .field("r_accel", &self.r_accel)
            .field("dt_us", &self.dt_us)
            .field("tol_us", &self.tol_us)
            .field("grid", &self.grid)
            .field("last", &self.last)
            .field("recovery", &self.recovery)
            .field("health", &self.health)
            .finish()
    }
}

/// The conventional 9-state filter (2nd-order Markov flexure, seed eq. 5).
pub type ConventionalFilter<T> = TransferAlignment<T, 3, 9>;
/// The proposed 12-state filter (3rd-order Markov flexure with θ̈_f, seed eqs. 12-14).
pub type ProposedFilter<T> = TransferAlignment<T, 4, 12>;

#[inline(always)]
fn at<T: Real, const K: usize>(m: &SMatrix<T, K, K>, r: usize, c: usize) -> T {
    m.get((r, c)).copied().unwrap_or_else(T::zero)
}

#[inline(always)]
fn put<T: Real, const K: usize>(m: &mut SMatrix<T, K, K>, r: usize, c: usize, v: T) {
    if let Some(e) = m.get_mut((r, c)) {
        *e = v;
    }
}

/// `T M Tᵀ` (`T` adds row/column 1 onto row/column 0): a θ_m-parametrised covariance block
/// in the θ = θ_m + θ_f parametrisation.
fn to_total_cov<T: Real, const K: usize>(m: &SMatrix<T, K, K>) -> SMatrix<T, K, K> {
    let mut out = *m;
    for c in 0..K {
        put(&mut out, 0, c, at(m, 0, c) + at(m, 1, c));
    }
    let rows = out;
    for r in 0..K {
        put(&mut out, r, 0, at(&rows, r, 0) + at(&rows, r, 1));
    }
    out
}

/// `T Φ T⁻¹`: the transition in the θ parametrisation (row 0 += row 1, then column 1 −=
/// column 0).
fn to_total_phi<T: Real, const K: usize>(m: &SMatrix<T, K, K>) -> SMatrix<T, K, K> {
    let mut out = *m;
    for c in 0..K {
        put(&mut out, 0, c, at(m, 0, c) + at(m, 1, c));
    }
    for r in 0..K {
        let v = at(&out, r, 1) - at(&out, r, 0);
        put(&mut out, r, 1, v);
    }
    out
}

/// `Φ_a S Φ_bᵀ` for one K×K block, using Φ's first column e₁ (θ_m is a random constant, so
/// in either parametrisation nothing feeds the first state but itself). `upper` computes
/// only the upper triangle and mirrors it (for a diagonal block, which is symmetric).
#[inline(always)]
fn propagate_block<T: Real, const K: usize>(
    pa: &SMatrix<T, K, K>,
    pb: &SMatrix<T, K, K>,
    s: &SMatrix<T, K, K>,
    upper: bool,
) -> SMatrix<T, K, K> {
    // t_mj = Σ_n S_mn Φb_jn = S_m0 δ_j0 + Σ_{n≥1} S_mn Φb_jn.
    let mut t = SMatrix::<T, K, K>::zeros();
    for j in 0..K {
        for m in 0..K {
            let mut acc = if j == 0 { at(s, m, 0) } else { T::zero() };
            for n in 1..K {
                acc += at(s, m, n) * at(pb, j, n);
            }
            put(&mut t, m, j, acc);
        }
    }
    // d_ij = Σ_m Φa_im t_mj = t_0j δ_i0 + Σ_{m≥1} Φa_im t_mj.
    let mut d = SMatrix::<T, K, K>::zeros();
    for i in 0..K {
        let j0 = if upper { i } else { 0 };
        for j in j0..K {
            let mut acc = if i == 0 { at(&t, 0, j) } else { T::zero() };
            for m in 1..K {
                acc += at(pa, i, m) * at(&t, m, j);
            }
            put(&mut d, i, j, acc);
            if upper {
                put(&mut d, j, i, acc);
            }
        }
    }
    d
}

/// Conditions a committed covariance, keeping it PSD (both operations map a PSD matrix to a PSD
/// matrix): the diagonal loading of [`PSD_LOADING_EPS`], then, for a variance above its
/// ceiling (a bound no consistent covariance reaches: the stationary flexure variances, and
/// `(√(σ_m² + σ_f²) + σ_f)²` for θ), row and column scaled by `√(ceiling / P_ii)` (a
/// congruence). Keeps unobservable directions from growing without bound under the loading.
#[inline(never)]
fn condition<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>, ceiling: &SVector<T, N>) {
    let load = T::one() + T::lit(PSD_LOADING_EPS) * T::EPS;
    for i in 0..N {
        if let Some(d) = p.get_mut((i, i)) {
            *d *= load;
        }
    }
    for (i, &c) in ceiling.iter().enumerate() {
        let d = p.get((i, i)).copied().unwrap_or_else(T::zero);
        if d > c {
            let s = (c / d).sqrt();
            for j in 0..N {
                if let Some(v) = p.get_mut((i, j)) {
                    *v *= s;
                }
                if let Some(v) = p.get_mut((j, i)) {
                    *v *= s;
                }
            }
        }
    }
}

/// `|v| ≤ lim`, false for NaN.
#[inline(always)]
fn within_limit<T: Real>(v: T, lim: T) -> bool {
    matches!(
        v.abs().partial_cmp(&lim),
        Some(core::cmp::Ordering::Less | core::cmp::Ordering::Equal)
    )
}

/// `0` when every component is finite, NaN otherwise (`v·0` is ±0 for finite v and NaN for
/// ±∞ or NaN): a finiteness test that costs one multiply-add per value on the target.
#[inline(always)]
fn zero_if_finite<T: Real>(v: &Vector3<T>) -> T {
    v.x * T::zero() + v.y * T::zero() + v.z * T::zero()
}

fn in_range3<T: Real>(input: &'static str, v: &Vector3<T>, limit: f64) -> Result<(), NavError> {
    let lim = T::lit(limit);
    if v.as_slice().iter().all(|c| c.abs() <= lim) {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input })
    }
}

/// Writes the `k × k` blocks (column-major slices) on the block diagonal of the column-major
/// `n × n` matrix `p` (block `a` at rows and columns `k·a ..`), leaving the rest of `p` as it
/// is. Configuration time only: not generic over the dimensions and out of line.
#[inline(never)]
fn block_diagonal<T: Real>(p: &mut [T], n: usize, blocks: &[&[T]], k: usize) {
    let (p, n, blocks, k) = crate::math::checks::opaque((p, n, blocks, k));
    if k == 0 {
        return;
    }
    for (a, block) in blocks.iter().enumerate() {
        for (c, col) in block.chunks_exact(k).enumerate() {
            let start = (k * a + c) * n + k * a;
            if let Some(dst) = p.get_mut(start..start + k) {
                dst.copy_from_slice(col);
            }
        }
    }
}

/// The time plan of one call: predictions to run and the new grid time.
#[derive(Debug, Clone, Copy)]
struct Plan {
    predictions: u32,
    gap: GapOutcome,
    grid: Timestamp,
}

/// The report of an update that could not be fused: finite numbers only.
#[cold]
#[inline(never)]
fn skipped_report<T: Real>(innovation: T, s: T) -> FusionReport<T> {
    let finite_or_zero = |v: T| if v.is_finite() { v } else { T::zero() };
    FusionReport {
        innovation: finite_or_zero(innovation),
        innovation_variance: finite_or_zero(s),
        nis: T::zero(),
        test_ratio: T::zero(),
        outcome: FusionOutcome::Skipped,
    }
}

/// One scalar update with the variance-reduction bound ([`MAX_VARIANCE_REDUCTION`]); a
/// numerical refusal becomes a `Skipped` report (x and P untouched).
#[inline(always)]
fn fuse_bounded<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    b: &SVector<T, N>,
    hph: T,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> FusionReport<T> {
    let r_eff = r.max(hph * T::lit(1.0 / MAX_VARIANCE_REDUCTION));
    match fuse_scalar_prepared(x, p, b, hph, innovation, r_eff, gate) {
        Ok(rep) => rep,
        Err(_) => skipped_report(innovation, hph + r_eff),
    }
}

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// Validates the configuration, discretises the per-axis chains at `dt_s` and starts from
    /// x = 0 with P = blockdiag(σ_m², stationary flexure covariance).
    ///
    /// Same as `from_design(cfg, &TaDesign::compute(&cfg)?)`.
    pub fn new(cfg: TaConfig<T>) -> Result<Self, NavError> {
        let design = TaDesign::<T, K>::compute(&cfg)?;
        Self::from_design(cfg, &design)
    }

    /// Builds the filter from a precomputed design ([`TaDesign::compute`] of this
    /// configuration, possibly stored as values, see [`crate::design`]) without running the
    /// discretisation; starts from x = 0 with P = blockdiag(P0_X, P0_Y, P0_Z) (transformed
    /// to the filter's θ parametrisation).
    ///
    /// Checks (cheap): the configuration ([`TaConfig::validate`]), every Φ, Q_d, P0 value
    /// finite (`InvalidConfig { field: "flexure" }` as [`Self::new`]), then the design's
    /// structure (Q_d and P0 exactly symmetric with a non-negative diagonal, Φ's θ_m row and
    /// column e₁, P0's θ_m variance equal to `mount_sigma_rad²`: `InvalidConfig { field:
    /// "design.q_d" | "design.p0" | "design.phi" }`). It cannot check that the design was
    /// computed for this `flexure` and `dt_s`: that is the caller's contract.
    pub fn from_design(cfg: TaConfig<T>, design: &TaDesign<T, K>) -> Result<Self, NavError> {
        let model = FlexureModel::for_dims::<K, N>()?;
        let (r_rate, r_accel, dt_us, tol_us) = cfg.validated_noise()?;
        let chains = design.chains;
        let [cx, cy, cz] = &chains;
        if !all_finite_parts(&[
            cx.p0.as_slice(),
            cx.phi.as_slice(),
            cx.q_d.as_slice(),
            cy.p0.as_slice(),
            cy.phi.as_slice(),
            cy.q_d.as_slice(),
            cz.p0.as_slice(),
            cz.phi.as_slice(),
            cz.q_d.as_slice(),
        ]) {
            return Err(out_of_range("flexure"));
        }
        design.check_structure(&cfg)?;
        let phi = [
            to_total_phi(&cx.phi),
            to_total_phi(&cy.phi),
            to_total_phi(&cz.phi),
        ];
        let q_d = [
            to_total_cov(&cx.q_d),
            to_total_cov(&cy.q_d),
            to_total_cov(&cz.q_d),
        ];
        let p = Self::initial_covariance(&chains);
        let mut ceiling = SVector::<T, N>::zeros();
        for (a, ch) in chains.iter().enumerate() {
            let var_f = at(&ch.p0, 1, 1);
            let theta = (at(&ch.p0, 0, 0) + var_f).sqrt() + var_f.sqrt();
            for d in 0..K {
                if let Some(c) = ceiling.get_mut(K * a + d) {
                    *c = if d == 0 {
                        theta * theta
                    } else {
                        at(&ch.p0, d, d) * T::lit(1.001)
                    };
                }
            }
        }
        Ok(Self {
            cfg,
            model,
            chains,
            phi,
            q_d,
            ceiling,
            x: SVector::zeros(),
            p: [p, p],
            second: false,
            r_rate,
            r_accel,
            dt_us,
            tol_us,
            grid: None,
            last: None,
            recovery: RecoveryPolicy::default(),
            health: TaHealth {
                epochs_since_anomaly: DEGRADED_HOLD_EPOCHS,
                ..TaHealth::default()
            },
        })
    }

    /// The initial covariance in the θ parametrisation.
    fn initial_covariance(chains: &[AxisChain<T, K>; 3]) -> SMatrix<T, N, N> {
        let mut p = SMatrix::<T, N, N>::zeros();
        let blocks = [
            to_total_cov(&chains[0].p0),
            to_total_cov(&chains[1].p0),
            to_total_cov(&chains[2].p0),
        ];
        block_diagonal(
            p.as_mut_slice(),
            N,
            &[
                blocks[0].as_slice(),
                blocks[1].as_slice(),
                blocks[2].as_slice(),
            ],
            K,
        );
        p
    }

    /// Sets the recovery policy (default [`RecoveryPolicy::default`]); `InvalidConfig` for a
    /// zero count.
    pub fn set_recovery(&mut self, policy: RecoveryPolicy) -> Result<(), NavError> {
        if policy.reset_after_rejections == Some(0) {
            return Err(NavError::InvalidConfig {
                field: "reset_after_rejections",
                issue: ConfigIssue::NotPositive,
            });
        }
        self.recovery = policy;
        Ok(())
    }

    /// The recovery policy in force.
    pub fn recovery(&self) -> RecoveryPolicy {
        self.recovery
    }

    /// Health state and counters (gate rejections, skipped updates, resets).
    pub fn health(&self) -> TaHealth {
        self.health
    }

    /// The configuration in force.
    pub fn config(&self) -> &TaConfig<T> {
        &self.cfg
    }

    /// Which model this filter runs.
    pub fn model(&self) -> FlexureModel {
        self.model
    }

    /// Per-axis discrete chains of the design (Φ_j, Q_d,j, P0_j in the θ_m parametrisation).
    pub fn chains(&self) -> &[AxisChain<T, K>; 3] {
        &self.chains
    }

    /// Time stamp of the last accepted sample (`None` before the first).
    pub fn time(&self) -> Option<Timestamp> {
        self.last
    }

    /// Time of the state on the filter's prediction grid (within dt/2 of [`Self::time`]).
    pub fn grid_time(&self) -> Option<Timestamp> {
        self.grid
    }

    /// The filter step in whole µs.
    pub fn dt_us(&self) -> u64 {
        self.dt_us
    }

    fn p_cur(&self) -> &SMatrix<T, N, N> {
        let [a, b] = &self.p;
        if self.second {
            b
        } else {
            a
        }
    }

    /// (current, scratch) covariance buffers.
    fn buffers(&mut self) -> (&SMatrix<T, N, N>, &mut SMatrix<T, N, N>) {
        let [a, b] = &mut self.p;
        if self.second {
            (&*b, a)
        } else {
            (&*a, b)
        }
    }

    /// One prediction over `dt_s`: per pair of axes a ≤ b, `P_ab ← Φ_a P_ab Φ_bᵀ (+ Q_d,a if
    /// a = b)` written to both (a, b) and (b, a) of `dst`, reading `src` (which may hold the
    /// same values as `dst`: each block is read before it is written and read only once).
    fn predict_cov(
        phi: &[SMatrix<T, K, K>; 3],
        q_d: &[SMatrix<T, K, K>; 3],
        src: Option<&SMatrix<T, N, N>>,
        dst: &mut SMatrix<T, N, N>,
    ) {
        // N = 3 K is checked at construction; stating it here lets the compiler prove every
        // block view below in bounds (no reachable panic on the target).
        if N != 3 * K {
            return;
        }
        for a in 0..3usize {
            for b in a..3usize {
                let (Some(pa), Some(pb), Some(qa)) = (phi.get(a), phi.get(b), q_d.get(a)) else {
                    continue;
                };
                // copy_from rather than into_owned: the latter builds from an iterator whose
                // length check the compiler cannot remove (a reachable panic on the target).
                let mut s = SMatrix::<T, K, K>::zeros();
                match src {
                    Some(m) => s.copy_from(&m.fixed_view::<K, K>(K * a, K * b)),
                    None => s.copy_from(&dst.fixed_view::<K, K>(K * a, K * b)),
                }
                let mut next = propagate_block(pa, pb, &s, a == b);
                if a == b {
                    next += qa;
                } else {
                    dst.fixed_view_mut::<K, K>(K * b, K * a)
                        .copy_from(&next.transpose());
                }
                dst.fixed_view_mut::<K, K>(K * a, K * b).copy_from(&next);
            }
        }
    }

    fn predict_state(phi: &[SMatrix<T, K, K>; 3], x: &mut SVector<T, N>) {
        for (a, ph) in phi.iter().enumerate() {
            let xa = ph * x.fixed_rows::<K>(K * a);
            x.fixed_rows_mut::<K>(K * a).copy_from(&xa);
        }
    }

    /// One prediction on (x, P) in place (tests).
    #[cfg(test)]
    fn predict_into(&self, x: &mut SVector<T, N>, p: &mut SMatrix<T, N, N>) {
        Self::predict_state(&self.phi, x);
        Self::predict_cov(&self.phi, &self.q_d, None, p);
    }

    /// Re-initialises the flexure states of (x, P) (θ parametrisation) to their stationary
    /// prior, keeping θ_m = θ − θ_f and its covariance grown as documented in
    /// [`GapOutcome::FlexureReinitialised`]. `reset_mount`: also put a θ_m estimate beyond
    /// [`MAX_MISALIGNMENT_RAD`] back to 0 with its initial variance.
    #[inline(never)]
    fn reinit_flexure(
        chains: &[AxisChain<T, K>; 3],
        x: &mut SVector<T, N>,
        p: &mut SMatrix<T, N, N>,
        reset_mount: bool,
    ) {
        let g = |m: &SMatrix<T, N, N>, r: usize, c: usize| {
            m.get((r, c)).copied().unwrap_or_else(T::zero)
        };
        // θ_m covariance across axes: P_θθ − P_θf − P_fθ + P_ff.
        let mut c = Matrix3::<T>::zeros();
        for a in 0..3 {
            for b in 0..3 {
                let (ta, tb) = (K * a, K * b);
                let v = g(p, ta, tb) - g(p, ta, tb + 1) - g(p, ta + 1, tb) + g(p, ta + 1, tb + 1);
                if let Some(e) = c.get_mut((a, b)) {
                    *e = v;
                }
            }
        }
        let lim = T::lit(MAX_MISALIGNMENT_RAD);
        let mut mount = [T::zero(); 3];
        for (a, (m, ch)) in mount.iter_mut().zip(chains.iter()).enumerate() {
            let theta_m = x.get(K * a).copied().unwrap_or_else(T::zero)
                - x.get(K * a + 1).copied().unwrap_or_else(T::zero);
            let p0_mm = at(&ch.p0, 0, 0);
            let var_f = at(&ch.p0, 1, 1);
            let caa = c
                .get((a, a))
                .copied()
                .unwrap_or_else(T::zero)
                .max(T::zero());
            let reset = reset_mount && !within_limit(theta_m, lim);
            let var = if reset {
                // Decorrelate this axis: its estimate is thrown away.
                for b in 0..3 {
                    if b != a {
                        if let Some(e) = c.get_mut((a, b)) {
                            *e = T::zero();
                        }
                        if let Some(e) = c.get_mut((b, a)) {
                            *e = T::zero();
                        }
                    }
                }
                p0_mm
            } else {
                (caa + var_f).min((p0_mm + var_f).max(caa))
            };
            if let Some(e) = c.get_mut((a, a)) {
                *e = var;
            }
            *m = if reset { T::zero() } else { theta_m };
        }
        // P in the θ_m parametrisation: θ_m block c, flexure blocks P0, nothing else.
        p.fill(T::zero());
        for a in 0..3 {
            for b in 0..3 {
                if let Some(e) = p.get_mut((K * a, K * b)) {
                    *e = c.get((a, b)).copied().unwrap_or_else(T::zero);
                }
            }
            if let Some(ch) = chains.get(a) {
                for r in 1..K {
                    for col in 1..K {
                        if let Some(e) = p.get_mut((K * a + r, K * a + col)) {
                            *e = at(&ch.p0, r, col);
                        }
                    }
                }
            }
        }
        // To the θ parametrisation: row/column θ_a += row/column θ_f,a.
        for a in 0..3 {
            let (t, f) = (K * a, K * a + 1);
            for col in 0..N {
                let v = g(p, t, col) + g(p, f, col);
                if let Some(e) = p.get_mut((t, col)) {
                    *e = v;
                }
            }
            for row in 0..N {
                let v = g(p, row, t) + g(p, row, f);
                if let Some(e) = p.get_mut((row, t)) {
                    *e = v;
                }
            }
        }
        for (a, m) in mount.iter().enumerate() {
            for d in 0..K {
                if let Some(e) = x.get_mut(K * a + d) {
                    *e = if d == 0 { *m } else { T::zero() };
                }
            }
        }
    }

    /// Runs the time plan from the current covariance into the scratch buffer: `n`
    /// predictions, a copy (n = 0), or the flexure re-initialisation of a long gap.
    #[inline(never)] // one copy serves `step` and `propagate`
    fn advance_to_scratch(&mut self, x: &mut SVector<T, N>, plan: &Plan) {
        // Borrow the fields separately: no copy of the matrices.
        let Self {
            chains,
            phi,
            q_d,
            p,
            second,
            ..
        } = self;
        let [a, b] = p;
        let (cur, scratch) = if *second { (&*b, a) } else { (&*a, b) };
        if plan.gap == GapOutcome::FlexureReinitialised {
            scratch.copy_from(cur);
            Self::reinit_flexure(chains, x, scratch, false);
            return;
        }
        if plan.predictions == 0 {
            scratch.copy_from(cur);
            return;
        }
        Self::predict_state(phi, x);
        Self::predict_cov(phi, q_d, Some(cur), scratch);
        for _ in 1..plan.predictions {
            Self::predict_state(phi, x);
            Self::predict_cov(phi, q_d, None, scratch);
        }
    }

    /// The time plan to a sample stamped `time` (see the module docs): `TimeNotIncreasing`
    /// unless later than the last accepted sample.
    fn plan(&self, time: Timestamp) -> Result<Plan, NavError> {
        let (Some(grid), Some(last)) = (self.grid, self.last) else {
            return Ok(Plan {
                predictions: 0,
                gap: GapOutcome::Started,
                grid: time,
            });
        };
        if time <= last {
            return Err(NavError::TimeNotIncreasing);
        }
        // time > last ≥ grid − dt/2, so `ahead` > 0.
        let ahead = time
            .add_micros(self.dt_us / 2)
            .micros_since(grid)
            .unwrap_or(0);
        let steps = ahead / self.dt_us.max(1);
        let grid = grid.add_micros(steps.saturating_mul(self.dt_us));
        match u32::try_from(steps) {
            Ok(n) if n <= self.cfg.max_gap_steps => Ok(Plan {
                predictions: n,
                gap: GapOutcome::Predicted,
                grid,
            }),
            _ => Ok(Plan {
                predictions: 0,
                gap: GapOutcome::FlexureReinitialised,
                grid,
            }),
        }
    }

    /// Checks the physical range of the inputs (`InputOutOfRange`; limits
    /// [`MAX_ANGULAR_RATE_RAD_S`], [`MAX_ANGULAR_ACCEL_RAD_S2`], [`MAX_SPECIFIC_FORCE_M_S2`]).
    fn check_ranges(master: &MasterSample<T>, slave: &SlaveSample<T>) -> Result<(), NavError> {
        in_range3(
            "master.angular_rate_rad_s",
            &master.angular_rate_rad_s,
            MAX_ANGULAR_RATE_RAD_S,
        )?;
        in_range3(
            "master.angular_accel_rad_s2",
            &master.angular_accel_rad_s2,
            MAX_ANGULAR_ACCEL_RAD_S2,
        )?;
        in_range3(
            "master.specific_force_m_s2",
            &master.specific_force_m_s2,
            MAX_SPECIFIC_FORCE_M_S2,
        )?;
        in_range3(
            "slave.angular_rate_rad_s",
            &slave.angular_rate_rad_s,
            MAX_ANGULAR_RATE_RAD_S,
        )?;
        in_range3(
            "slave.specific_force_m_s2",
            &slave.specific_force_m_s2,
            MAX_SPECIFIC_FORCE_M_S2,
        )
    }

    /// The health state for these counters and state.
    fn classify(&self, h: &TaHealth, x: &SVector<T, N>) -> HealthState {
        let lim = T::lit(MAX_MISALIGNMENT_RAD);
        let diverged = (0..3).any(|a| {
            let v = x.get(K * a).copied().unwrap_or_else(T::zero);
            !within_limit(v, lim)
        });
        if diverged || h.consecutive_all_skipped >= SKIPPED_EPOCHS_FOR_REINIT {
            HealthState::NeedsReinitialisation
        } else if h.epochs_since_anomaly < DEGRADED_HOLD_EPOCHS {
            HealthState::Degraded
        } else {
            HealthState::Nominal
        }
    }

    /// Processes one epoch: checks the inputs and time stamps, predicts from the previous epoch
    /// to the grid point nearest the slave's time stamp (see the module docs; none at the
    /// first epoch, the flexure re-initialised after a gap longer than `max_gap_steps`), then
    /// fuses the six scalar measurements (the sparse form of [`fuse_scalar`]: `b = P h` from
    /// the row's few columns, [`covariance_times_row`], then [`fuse_scalar_prepared`]).
    ///
    /// Refused (`Err`, the filter unchanged bit for bit) only for invalid input:
    /// `NonFiniteInput`, `InputOutOfRange` (an input beyond the `MAX_*` limits),
    /// `TimeNotIncreasing` (the slave's stamp not later than the last accepted sample's), and
    /// `MeasurementTimeOutOfWindow` (master and slave stamps differ by more than the
    /// tolerance; match delayed master data with a [`super::SlaveHistory`]). Any later time
    /// stamp is accepted.
    ///
    /// A measurement rejected by the χ² gate is reported (`Rejected`) and counted in
    /// [`Self::health`]; see [`RecoveryPolicy`] for what happens when a channel is starved. A
    /// measurement that cannot be fused numerically is reported `Skipped` and counted; the
    /// step still commits its prediction and the other updates.
    pub fn step(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
    ) -> Result<StepReport<T>, NavError> {
        // Fast path: one sum decides that all 15 inputs are finite; the per-field checks (which
        // name the offending input) only run when some input is not.
        let probe = zero_if_finite(&master.angular_rate_rad_s)
            + zero_if_finite(&master.angular_accel_rad_s2)
            + zero_if_finite(&master.specific_force_m_s2)
            + zero_if_finite(&slave.angular_rate_rad_s)
            + zero_if_finite(&slave.specific_force_m_s2);
        if probe != T::zero() {
            master.validate()?;
            slave.validate()?;
        }
        Self::check_ranges(master, slave)?;
        let skew = master
            .time
            .micros_since(slave.time)
            .or_else(|| slave.time.micros_since(master.time))
            .unwrap_or(u64::MAX);
        if skew > self.tol_us {
            return Err(NavError::MeasurementTimeOutOfWindow);
        }
        let plan = self.plan(slave.time)?;
        let (z, f_comp) = measurement(master, slave, &self.cfg.lever_arm_m);
        let z_probe = z
            .as_slice()
            .iter()
            .fold(zero_if_finite(&f_comp), |acc, v| acc + *v * T::zero());
        if z_probe != T::zero() {
            return Err(NavError::InputOutOfRange {
                input: "measurement",
            });
        }
        let f_h = match self.model {
            FlexureModel::Conventional => f_comp,
            FlexureModel::Proposed => slave.specific_force_m_s2,
        };
        let gate = match self.cfg.nis_gate {
            Some(g) => Gate::Nis(g),
            None => Gate::Off,
        };
        let (model, lever, r_rate, r_accel) =
            (self.model, self.cfg.lever_arm_m, self.r_rate, self.r_accel);
        let mut x = self.x;
        self.advance_to_scratch(&mut x, &plan);
        let (_, p) = self.buffers();
        let empty = FusionReport {
            innovation: T::zero(),
            innovation_variance: T::zero(),
            nis: T::zero(),
            test_ratio: T::zero(),
            outcome: FusionOutcome::Rejected,
        };
        let mut updates = [empty; 6];
        // The six rows are written out with constant row indices (and the model follows from K
        // at compile time), so each row's sparsity pattern is known to the compiler: the
        // index-driven loops of the sparse update become straight-line code.
        let model_k = if K == 4 {
            FlexureModel::Proposed
        } else {
            FlexureModel::Conventional
        };
        debug_assert!(model_k == model);
        macro_rules! fuse_row {
            ($row:literal) => {
                if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                    let h = h_row_total::<T, K>(
                        model_k,
                        $row,
                        &master.angular_rate_rad_s,
                        &f_h,
                        &lever,
                    );
                    let r = if $row < 3 { r_rate } else { r_accel };
                    let innovation = zi - h.dot(&x);
                    // Built from validated, range-checked inputs with in-range ascending
                    // indices by construction (tested): no per-entry validation.
                    let b = covariance_times_row(p, &h);
                    let hph = h.dot(&b);
                    *rep = fuse_bounded(&mut x, p, &b, hph, innovation, r, gate);
                }
            };
        }
        fuse_row!(0);
        fuse_row!(1);
        fuse_row!(2);
        fuse_row!(3);
        fuse_row!(4);
        fuse_row!(5);
        // Commit: counters, recovery, state, buffer swap, time.
        let mut health = self.health;
        let mut starved = false;
        let mut anomaly = plan.gap == GapOutcome::FlexureReinitialised;
        let mut all_skipped = true;
        for (((rep, total), run), skipped) in updates
            .iter()
            .zip(health.rejected.iter_mut())
            .zip(health.consecutive_rejected.iter_mut())
            .zip(health.skipped.iter_mut())
        {
            match rep.outcome {
                FusionOutcome::Rejected => {
                    all_skipped = false;
                    *total = total.saturating_add(1);
                    *run = run.saturating_add(1);
                    starved |= self
                        .recovery
                        .reset_after_rejections
                        .is_some_and(|n| *run >= n);
                }
                FusionOutcome::Skipped => {
                    anomaly = true;
                    *skipped = skipped.saturating_add(1);
                    *run = 0;
                }
                FusionOutcome::Fused => {
                    all_skipped = false;
                    *run = 0;
                }
            }
        }
        health.consecutive_all_skipped = if all_skipped {
            health.consecutive_all_skipped.saturating_add(1)
        } else {
            0
        };
        if plan.gap == GapOutcome::FlexureReinitialised {
            health.flexure_reinitialisations = health.flexure_reinitialisations.saturating_add(1);
        }
        if starved {
            anomaly = true;
            health.covariance_resets = health.covariance_resets.saturating_add(1);
            health.consecutive_rejected = [0; 6];
            let p0 = Self::initial_covariance(&self.chains);
            let (_, p) = self.buffers();
            *p = p0;
            for a in 0..3 {
                let theta_m = x.get(K * a).copied().unwrap_or_else(T::zero)
                    - x.get(K * a + 1).copied().unwrap_or_else(T::zero);
                for d in 0..K {
                    if let Some(v) = x.get_mut(K * a + d) {
                        *v = if d == 0 { theta_m } else { T::zero() };
                    }
                }
            }
        }
        health.epochs_since_anomaly = if anomaly {
            0
        } else {
            health.epochs_since_anomaly.saturating_add(1)
        };
        health.state = self.classify(&health, &x);
        let ceiling = self.ceiling;
        let (_, p) = self.buffers();
        condition(p, &ceiling);
        self.health = health;
        self.x = x;
        self.second = !self.second;
        self.grid = Some(plan.grid);
        self.last = Some(slave.time);
        Ok(StepReport {
            time: slave.time,
            predictions: plan.predictions,
            gap: plan.gap,
            updates,
        })
    }

    /// Prediction only, to the grid point nearest `time`: how a firmware loop keeps the
    /// filter running through a master-data dropout (call it at each slave epoch without
    /// master data). Before the first epoch it starts the clock (nothing predicted). A gap
    /// longer than `max_gap_steps` re-initialises the flexure as in [`Self::step`]. Errors:
    /// `TimeNotIncreasing` (the filter unchanged).
    pub fn propagate(&mut self, time: Timestamp) -> Result<Propagation, NavError> {
        let plan = self.plan(time)?;
        let mut x = self.x;
        self.advance_to_scratch(&mut x, &plan);
        let mut health = self.health;
        if plan.gap == GapOutcome::FlexureReinitialised {
            health.flexure_reinitialisations = health.flexure_reinitialisations.saturating_add(1);
            health.epochs_since_anomaly = 0;
        }
        if health.state != HealthState::Initialising {
            health.state = self.classify(&health, &x);
        }
        let ceiling = self.ceiling;
        let (_, p) = self.buffers();
        condition(p, &ceiling);
        self.health = health;
        self.x = x;
        self.second = !self.second;
        self.grid = Some(plan.grid);
        self.last = Some(time);
        Ok(Propagation {
            predictions: plan.predictions,
            gap: plan.gap,
        })
    }

    /// The documented way back from [`HealthState::NeedsReinitialisation`] (or any time):
    /// re-initialises the flexure states to their stationary prior and keeps θ_m with its
    /// covariance grown, exactly as after a long gap ([`GapOutcome::FlexureReinitialised`]);
    /// a θ_m estimate beyond [`MAX_MISALIGNMENT_RAD`] is put back to 0 with its initial
    /// variance. Clears the runs of rejections and skips, keeps the clock and the totals;
    /// counted in [`TaHealth::flexure_reinitialisations`]. The filter then reports
    /// [`HealthState::Degraded`] for [`DEGRADED_HOLD_EPOCHS`] epochs.
    pub fn reinitialise(&mut self) {
        let mut x = self.x;
        {
            let Self {
                chains, p, second, ..
            } = self;
            let [a, b] = p;
            let (cur, scratch) = if *second { (&*b, a) } else { (&*a, b) };
            scratch.copy_from(cur);
            Self::reinit_flexure(chains, &mut x, scratch, true);
        }
        self.second = !self.second;
        self.x = x;
        let mut health = self.health;
        health.flexure_reinitialisations = health.flexure_reinitialisations.saturating_add(1);
        health.consecutive_rejected = [0; 6];
        health.consecutive_all_skipped = 0;
        health.epochs_since_anomaly = 0;
        if health.state != HealthState::Initialising {
            health.state = self.classify(&health, &x);
        }
        self.health = health;
    }

    /// Matches time-tagged (possibly delayed) master data with the slave sample of the same
    /// epoch in `history` and runs [`Self::step`] on the pair. Errors: those of
    /// [`super::SlaveHistory::find`] and of [`Self::step`]; on error the filter is unchanged.
    pub fn step_delayed<const H: usize>(
        &mut self,
        master: &MasterSample<T>,
        history: &super::SlaveHistory<T, H>,
    ) -> Result<StepReport<T>, NavError> {
        let slave = history.find(master.time, self.tol_us)?;
        self.step(master, &slave)
    }

    fn block(&self, d: usize) -> Vector3<T> {
        let g = |a: usize| {
            self.x
                .get(axis_index::<K>(d, a))
                .copied()
                .unwrap_or_else(T::zero)
        };
        Vector3::new(g(0), g(1), g(2))
    }

    /// Estimated mounting misalignment θ_m = θ − θ_f, rad.
    pub fn theta_m(&self) -> Vector3<T> {
        self.block(0) - self.block(1)
    }

    /// Estimated flexure angle θ_f, rad.
    pub fn theta_f(&self) -> Vector3<T> {
        self.block(1)
    }

    /// Estimated flexure rate θ̇_f, rad/s.
    pub fn theta_f_rate(&self) -> Vector3<T> {
        self.block(2)
    }

    /// Estimated flexure angular acceleration θ̈_f, rad/s² (`None` for the conventional filter,
    /// which has no such state).
    pub fn theta_f_accel(&self) -> Option<Vector3<T>> {
        (K == 4).then(|| self.block(3))
    }

    /// Estimated total misalignment θ = θ_m + θ_f, rad (a state of the filter).
    pub fn theta(&self) -> Vector3<T> {
        self.block(0)
    }

    fn p_at(&self, r: usize, c: usize) -> T {
        self.p_cur().get((r, c)).copied().unwrap_or_else(T::zero)
    }

    /// Covariance of θ = θ_m + θ_f (rad², the filter's own θ block).
    pub fn theta_covariance(&self) -> Matrix3<T> {
        Matrix3::from_fn(|a, b| self.p_at(K * a, K * b))
    }

    /// Covariance of θ_m = θ − θ_f (rad²): `P_θθ − P_θf − P_fθ + P_ff`.
    pub fn theta_m_covariance(&self) -> Matrix3<T> {
        Matrix3::from_fn(|a, b| {
            let (i, j) = (K * a, K * b);
            self.p_at(i, j) - self.p_at(i, j + 1) - self.p_at(i + 1, j) + self.p_at(i + 1, j + 1)
        })
    }

    /// 1σ of θ per axis, rad.
    pub fn theta_sigma_rad(&self) -> Vector3<T> {
        self.theta_covariance()
            .diagonal()
            .map(|v| v.max(T::zero()).sqrt())
    }

    /// State in derivative-major order `[θ, θ_f, θ̇_f(, θ̈_f)]` (the spec's ordering, with the
    /// total misalignment θ = θ_m + θ_f in place of θ_m: the filter's parametrisation).
    pub fn state(&self) -> SVector<T, N> {
        let mut s = SVector::<T, N>::zeros();
        for a in 0..3 {
            for d in 0..K {
                if let (Some(dst), Some(src)) = (
                    s.get_mut(super::model::spec_index(d, a)),
                    self.x.get(axis_index::<K>(d, a)),
                ) {
                    *dst = *src;
                }
            }
        }
        s
    }

    /// Covariance of [`Self::state`], in its ordering.
    pub fn covariance(&self) -> SMatrix<T, N, N> {
        super::model::to_spec_order::<T, K, N>(self.p_cur())
    }

    /// Estimated slave attitude `C_n^s = C_m^s C_n^m` given the master's `C_n^m`, with
    /// `C_m^s = exp(−[θ̂×])` (the spec's sign, exact rotation).
    pub fn slave_attitude(&self, c_n_m: &Matrix3<T>) -> Matrix3<T> {
        exp_so3(&(-self.theta())) * c_n_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::kalman::{propagate_dense, FusionOutcome};
    use crate::transfer_alignment::model::assemble_spec;
    use std::format;

    fn cfg<T: Real>() -> TaConfig<T> {
        let d = |x: f64| T::lit(x.to_radians());
        TaConfig {
            lever_arm_m: Vector3::new(T::zero(), T::lit(5.0), T::zero()),
            flexure: [
                AxisFlexure {
                    sigma_rad: d(0.5),
                    tau_s: T::lit(0.358),
                },
                AxisFlexure {
                    sigma_rad: d(0.1),
                    tau_s: T::lit(2.146),
                },
                AxisFlexure {
                    sigma_rad: d(0.1),
                    tau_s: T::lit(2.146),
                },
            ],
            mount_sigma_rad: Vector3::repeat(d(0.5)),
            rate_noise_sigma_rad_s: T::lit(3e-4),
            accel_noise_sigma_m_s2: T::lit(5e-3),
            dt_s: T::lit(0.01),
            time_tolerance_s: T::lit(1e-4),
            max_gap_steps: 3,
            nis_gate: Some(T::lit(25.0)),
        }
    }

    fn samples<T: Real>(t: f64) -> (MasterSample<T>, SlaveSample<T>) {
        let time = Timestamp::from_secs_f64(t).unwrap();
        let m = MasterSample {
            time,
            angular_rate_rad_s: Vector3::new(T::lit(0.01), T::zero(), T::lit(-0.02)),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: Vector3::new(T::lit(3.0), T::zero(), T::lit(-9.8)),
        };
        let s = SlaveSample {
            time,
            angular_rate_rad_s: Vector3::new(T::lit(0.0101), T::lit(0.0002), T::lit(-0.0199)),
            specific_force_m_s2: Vector3::new(T::lit(3.02), T::lit(0.03), T::lit(-9.79)),
        };
        (m, s)
    }

    fn structured_predict_equals_dense<T: Real, const K: usize, const N: usize>(tol: f64) {
        let f = TransferAlignment::<T, K, N>::new(cfg()).unwrap();
        // A full symmetric P with cross-axis terms.
        let mut p = SMatrix::<T, N, N>::zeros();
        for i in 0..N {
            for j in 0..N {
                p[(i, j)] = T::lit(1e-4 / (1.0 + (i as f64 - j as f64).abs()));
            }
        }
        let mut x = SVector::<T, N>::from_fn(|i, _| T::lit(1e-3 * (i as f64 + 1.0)));
        let (x0, p0) = (x, p);
        f.predict_into(&mut x, &mut p);
        // Dense reference on the same axis-major layout.
        let mut phi = SMatrix::<T, N, N>::zeros();
        let mut qd = SMatrix::<T, N, N>::zeros();
        for a in 0..3 {
            phi.fixed_view_mut::<K, K>(K * a, K * a)
                .copy_from(&f.phi[a]);
            qd.fixed_view_mut::<K, K>(K * a, K * a).copy_from(&f.q_d[a]);
        }
        let mut pd = p0;
        propagate_dense(&mut pd, &phi, &qd);
        assert!(
            ((pd - p).abs().max()).to_f64() < tol * 1e-4,
            "{}",
            (pd - p).abs().max()
        );
        assert!(((phi * x0 - x).abs().max()).to_f64() < tol * 1e-2);
        assert_eq!(crate::math::kalman::asymmetry(&p), T::zero());
        // And the blocks equal exp(F dt) of the spec-ordered model.
        let (fs, _) =
            crate::transfer_alignment::model::continuous_model::<T, K, N>(&f.cfg.flexure).unwrap();
        let (phis, _) =
            crate::math::discretize::discretize(&fs, &SMatrix::zeros(), f.cfg.dt_s).unwrap();
        let blocks = [&f.chains[0].phi, &f.chains[1].phi, &f.chains[2].phi];
        let phi_spec = assemble_spec::<T, K, N>(blocks);
        assert!(((phis - phi_spec).abs().max()).to_f64() < tol);
    }

    #[test]
    fn structured_predict_f32_f64() {
        structured_predict_equals_dense::<f64, 4, 12>(1e-12);
        structured_predict_equals_dense::<f64, 3, 9>(1e-12);
        structured_predict_equals_dense::<f32, 4, 12>(1e-5);
        structured_predict_equals_dense::<f32, 3, 9>(1e-5);
    }

    fn step_and_errors<T: Real, const K: usize, const N: usize>() {
        let mut f = TransferAlignment::<T, K, N>::new(cfg()).unwrap();
        let (m, s) = samples::<T>(0.0);
        let rep = f.step(&m, &s).unwrap();
        assert_eq!(rep.predictions, 0);
        assert_eq!(rep.gap, GapOutcome::Started);
        assert!(rep
            .updates
            .iter()
            .all(|u| u.outcome == FusionOutcome::Fused));
        assert!(rep
            .updates
            .iter()
            .all(|u| u.innovation_variance > T::zero()));
        let (m1, s1) = samples::<T>(0.01);
        assert_eq!(f.step(&m1, &s1).unwrap().predictions, 1);
        let before = format!("{f:?}");
        let unchanged = |f: &TransferAlignment<T, K, N>| {
            assert_eq!(format!("{f:?}"), before);
        };
        // Same time again.
        assert_eq!(f.step(&m1, &s1), Err(NavError::TimeNotIncreasing));
        unchanged(&f);
        // Master and slave out of sync.
        let (m4, _) = samples::<T>(0.021);
        let (_, s4) = samples::<T>(0.02);
        assert_eq!(f.step(&m4, &s4), Err(NavError::MeasurementTimeOutOfWindow));
        unchanged(&f);
        // NaN input.
        let (mut m5, s5) = samples::<T>(0.02);
        m5.specific_force_m_s2.x = T::lit(f64::NAN);
        assert!(matches!(
            f.step(&m5, &s5),
            Err(NavError::NonFiniteInput { .. })
        ));
        unchanged(&f);
        // Half a step: fused on the grid point 0.02 s (one prediction).
        let (m2, s2) = samples::<T>(0.016);
        let rep = f.step(&m2, &s2).unwrap();
        assert_eq!((rep.predictions, rep.gap), (1, GapOutcome::Predicted));
        assert_eq!(f.grid_time(), Some(Timestamp::from_millis(20)));
        // 0.022 s rounds to the same grid point: no prediction.
        let (m2, s2) = samples::<T>(0.022);
        assert_eq!(f.step(&m2, &s2).unwrap().predictions, 0);
        // Gap of 2 steps is bridged.
        let (m6, s6) = samples::<T>(0.04);
        assert_eq!(f.step(&m6, &s6).unwrap().predictions, 2);
        // An outlier in df_X is rejected by the gate and reported.
        let (m7, mut s7) = samples::<T>(0.05);
        s7.specific_force_m_s2.x += T::lit(50.0);
        let rep = f.step(&m7, &s7).unwrap();
        assert_eq!(rep.updates[3].outcome, FusionOutcome::Rejected);
        assert!(rep.updates[3].test_ratio > T::one());
        assert_eq!(rep.updates[4].outcome, FusionOutcome::Fused);
        // Gap too long (4 steps, max 3): the flexure is re-initialised, θ_m kept.
        let theta_m = f.theta_m();
        let (m3, s3) = samples::<T>(0.09);
        let rep = f.step(&m3, &s3).unwrap();
        assert_eq!(
            (rep.predictions, rep.gap),
            (0, GapOutcome::FlexureReinitialised)
        );
        assert_eq!(f.health().flexure_reinitialisations, 1);
        assert_eq!(f.health().state, crate::HealthState::Degraded);
        let _ = theta_m;
    }

    #[test]
    fn step_reports_and_errors_leave_state_f32_f64() {
        step_and_errors::<f64, 4, 12>();
        step_and_errors::<f64, 3, 9>();
        step_and_errors::<f32, 4, 12>();
        step_and_errors::<f32, 3, 9>();
    }

    #[test]
    fn config_validation() {
        let ok = cfg::<f32>();
        assert!(ProposedFilter::new(ok).is_ok());
        let mut c = ok;
        c.flexure[1].tau_s = 0.0;
        assert!(matches!(
            ProposedFilter::new(c),
            Err(NavError::InvalidConfig {
                field: "flexure.tau_s",
                ..
            })
        ));
        let mut c = ok;
        c.accel_noise_sigma_m_s2 = -1.0;
        assert!(matches!(
            ConventionalFilter::new(c),
            Err(NavError::InvalidConfig {
                field: "accel_noise_sigma_m_s2",
                ..
            })
        ));
        let mut c = ok;
        c.lever_arm_m.y = f32::INFINITY;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.time_tolerance_s = 0.006;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.max_gap_steps = 0;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.max_gap_steps = MAX_GAP_STEPS + 1;
        assert!(matches!(
            ProposedFilter::new(c),
            Err(NavError::InvalidConfig {
                field: "max_gap_steps",
                ..
            })
        ));
        let mut c = ok;
        c.flexure[0].tau_s = 0.04; // < 5 dt
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.nis_gate = Some(0.0);
        assert!(ProposedFilter::new(c).is_err());
        assert!(TransferAlignment::<f32, 4, 9>::new(ok).is_err());
    }

    #[test]
    fn block_diagonal_equals_initial_covariance() {
        fn check<T: Real, const K: usize, const N: usize>() {
            let f = TransferAlignment::<T, K, N>::new(cfg::<T>()).unwrap();
            let mut chains = *f.chains();
            // Distinct values everywhere, so a misplaced element shows.
            for (a, ch) in chains.iter_mut().enumerate() {
                for (i, v) in ch.p0.iter_mut().enumerate() {
                    *v = T::lit((100 * a + i + 1) as f64);
                }
            }
            let mut p = SMatrix::<T, N, N>::zeros();
            let blocks = [
                chains[0].p0.as_slice(),
                chains[1].p0.as_slice(),
                chains[2].p0.as_slice(),
            ];
            block_diagonal(p.as_mut_slice(), N, &blocks, K);
            let mut expect = SMatrix::<T, N, N>::zeros();
            for (a, ch) in chains.iter().enumerate() {
                expect
                    .fixed_view_mut::<K, K>(K * a, K * a)
                    .copy_from(&ch.p0);
            }
            assert_eq!(p, expect);
        }
        check::<f32, 3, 9>();
        check::<f64, 3, 9>();
        check::<f32, 4, 12>();
        check::<f64, 4, 12>();
    }

    #[test]
    fn initial_covariance_and_outputs() {
        let f = ProposedFilter::<f64>::new(cfg()).unwrap();
        let sm = 0.5_f64.to_radians();
        assert!((f.theta_m_covariance()[(0, 0)] - sm * sm).abs() < 1e-15);
        // θ covariance = σ_m² + σ_f² per axis at the start.
        let s = f.theta_sigma_rad();
        assert!((s.x - (2.0 * sm * sm).sqrt()).abs() < 1e-12);
        assert!(f.theta_f_accel().is_some());
        assert!(ConventionalFilter::<f64>::new(cfg())
            .unwrap()
            .theta_f_accel()
            .is_none());
        // C_n^s for zero misalignment is C_n^m.
        let c = crate::math::rotation::euler_to_dcm(0.1, 0.2, 0.3).transpose();
        assert!((f.slave_attitude(&c) - c).abs().max() < 1e-15);
    }
}

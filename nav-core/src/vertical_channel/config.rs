//! What the user chooses: the loops' configurations, the aid model behind the gate and the
//! recovery, their validation, and the papers' configuration.

use super::samples::AidTimeouts;
use super::sigma::ErrorModel;
use super::MAX_TIMEOUT_S;
use crate::contract::{Gate, RecoveryAction, RecoveryPolicy};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::math::checks::{first_outside, LowerBound, RangeCheck};
use crate::Bounds;
use crate::{NavError, Real};

/// Configuration of the classical loop (SI units; the design is computed from it in `f64`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ClassicalConfig<T> {
    /// IMU interval (the loop's step), s ([`super::IMU_DT_RANGE_S`]).
    pub imu_dt_s: T,
    /// Geodetic latitude for the gravity model, rad.
    pub latitude_rad: T,
    /// Time constant τ of the triple closed-loop pole at −1/τ, s (≤ [`super::MAX_TAU_S`]).
    pub tau_s: T,
    /// Altimeter lag compensation C4 (the baro's first-order lag time constant), s; 0 = none.
    pub baro_lag_s: T,
    /// Baro sample interval, s (the longest expected; with the IMU interval it decides
    /// whether τ is stable in the multirate loop).
    pub baro_period_s: T,
    /// Baro freshness timeouts.
    pub baro_timeouts: AidTimeouts<T>,
    /// Aid model behind the gate: tracking σ₀, re-inflation while starved, recovery hold.
    pub aid_model: AidModel<T>,
    /// χ² gate of every new aid sample ([`Gate::Off`]: every valid sample is fused).
    pub gate: Gate<T>,
    /// Starvation recovery: only [`RecoveryAction::Reanchor`] (see [`AidModel`]).
    pub recovery: RecoveryPolicy<T>,
    /// The sensors' and initial state's noise the loop's σ is computed for (part of the
    /// design and its stamp).
    pub error_model: ErrorModel<T>,
}

/// Configuration of the velocity-aided loop (SI units; the design is computed in `f64`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidedConfig<T> {
    /// IMU interval (the loop's step), s ([`super::IMU_DT_RANGE_S`]).
    pub imu_dt_s: T,
    /// Geodetic latitude for the gravity model, rad.
    pub latitude_rad: T,
    /// Accelerometer white-noise density (σ, not PSD), m/s²/√Hz. PSD = value².
    pub accel_noise_m_s2_rt_hz: T,
    /// Accelerometer bias random-walk density (σ), m/s²/√s. PSD = value².
    pub accel_bias_rw_m_s2_rt_s: T,
    /// Baro white noise per sample, 1σ, m.
    pub baro_noise_m: T,
    /// Baro sample interval, s.
    pub baro_period_s: T,
    /// Baro lag compensation (the baro's first-order lag time constant), s; 0 = none.
    pub baro_lag_s: T,
    /// Velocity-aid white noise per sample, 1σ, m/s.
    pub velocity_noise_m_s: T,
    /// Velocity-aid sample interval, s.
    pub velocity_period_s: T,
    /// Baro freshness timeouts.
    pub baro_timeouts: AidTimeouts<T>,
    /// Velocity-aid freshness timeouts.
    pub velocity_timeouts: AidTimeouts<T>,
    /// Aid model behind the gate: tracking σ₀, re-inflation while starved, recovery hold.
    pub aid_model: AidModel<T>,
    /// χ² gate of every new aid sample ([`Gate::Off`]: every valid sample is fused).
    pub gate: Gate<T>,
    /// Starvation recovery: only [`RecoveryAction::Reanchor`] (see [`AidModel`]).
    pub recovery: RecoveryPolicy<T>,
    /// The sensors' and initial state's noise the loop's σ is computed for (part of the
    /// design and its stamp).
    pub error_model: ErrorModel<T>,
}

/// The aids' innovation model of the fixed-gain loops. They carry no running covariance, so
/// the innovation variance of a new sample (the `innovation_variance` of its
/// [`crate::FusionReport`], against which the [`Gate`] tests it) comes from this model:
///
/// ```text
/// baro:      S = σ_h² + (gap · (σ_v0 + ½ σ_a0 · gap))²
/// velocity:  S = σ_v² + (σ_a0 · gap)²
/// ```
///
/// with `gap` the time since the last **accepted** sample of that aid. σ₀ is the innovation
/// σ of a tracking loop (for the aided loop, [`super::AidedLoop::design_innovation_sigmas`]
/// gives the design's steady state `√(C P Cᵀ + σ²)` as a starting point; it ignores
/// correlated baro errors); the second term is the open-loop (inertial-only) error growth
/// from a velocity uncertainty σ_v0 and an acceleration uncertainty σ_a0. S saturates at
/// [`super::MAX_GATE_VARIANCE`]. A rejected sample is discarded: the last accepted one keeps
/// ageing (`Stale`, then `Lost`, the loop coasting on the IMU).
///
/// Recovery of a starved loop, with a gate ([`Gate::Nis`]):
///
/// 1. **Re-inflation**: while starved, S grows as the inertial solution's plausible drift,
///    until a sample consistent with it is accepted. A persistent wrong reading that departs
///    from the inertial solution faster than the drift (a frozen baro in a climb, a spike)
///    stays rejected.
/// 2. **Recovery gate**: the variance that admitted a re-acquiring sample is held,
///    bounded by `σ₀² + ν²` of that sample (a 3 km spike cannot pass a gate held open by a
///    long outage), until the innovations have stayed inside the *tracking* gate
///    (`ν² ≤ threshold · σ₀²`) for `recovery_hold_s`.
/// 3. **Reset on re-acquisition**: a sample that ends a `Lost` period with an innovation
///    beyond the tracking gate moves the measured state (ĥ for the baro, V̂_z for the velocity
///    aid) by ν; the other states are kept ([`super::Reacquisition::Reset`]).
/// 4. **Starvation**: when an aid's samples have been rejected without a break for
///    [`RecoveryPolicy::starved_after_s`], the next sample is accepted outside the gate and
///    re-anchors the measured state ([`RecoveryAction::Reanchor`], the only action these
///    loops support; [`super::Reacquisition::Reanchored`]). The same re-anchoring follows a
///    gap longer than [`super::MAX_BRIDGED_GAP_S`] and an estimate held at its limits, gate
///    or not.
///
/// The first sample an aid ever delivers is accepted ungated (acquisition). With
/// [`Gate::Off`] every valid sample is fused and nothing is reset on re-acquisition.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidModel<T> {
    /// Baro innovation σ₀ of a tracking loop, m (10⁻⁶ … 10⁶).
    pub baro_sigma_m: T,
    /// Velocity-aid innovation σ₀ of a tracking loop, m/s (10⁻⁶ … 10⁶; unused by the
    /// classical loop).
    pub velocity_sigma_m_s: T,
    /// Velocity uncertainty σ_v0 of the inertial solution driving the re-inflation, m/s
    /// (0, or 10⁻⁶ … 10⁶).
    pub starved_velocity_sigma_m_s: T,
    /// Acceleration uncertainty σ_a0 driving the re-inflation, m/s² (0, or 10⁻⁶ … 10⁶).
    pub starved_accel_sigma_m_s2: T,
    /// How long the innovations must stay inside the tracking gate after a re-acquisition
    /// before the recovery gate is released, s (> 0, ≤ [`MAX_TIMEOUT_S`]; a few loop time
    /// constants, e.g. 3τ).
    pub recovery_hold_s: T,
}

/// Accepted χ² threshold of [`Gate::Nis`]: `[low, high)`.
pub const NIS_THRESHOLD_RANGE: Bounds = Bounds {
    low: 1.0e-3,
    high: 1.0e4,
};
/// Accepted range of the aid model's σ values: `[low, high)` (σ_v0 and σ_a0 may be 0).
pub const AID_SIGMA_RANGE: Bounds = Bounds {
    low: 1.0e-6,
    high: 1.0e6,
};

impl<T: Real> AidModel<T> {
    /// The model of the papers' configuration (and of the firmware images): σ₀ 30 m baro,
    /// 3 m/s velocity; re-inflation from σ_v0 = 0.5 m/s, σ_a0 = 0.02 m/s²; 60 s recovery hold.
    pub fn paper() -> Self {
        Self {
            baro_sigma_m: T::lit(30.0),
            velocity_sigma_m_s: T::lit(3.0),
            starved_velocity_sigma_m_s: T::lit(0.5),
            starved_accel_sigma_m_s2: T::lit(0.02),
            recovery_hold_s: T::lit(60.0),
        }
    }

    /// Validates the model (errors name `aid_model.<field>`). The squares formed from it stay
    /// finite and normal in f32.
    #[inline(never)]
    pub(crate) fn validate(&self) -> Result<(), NavError> {
        require_positive("aid_model.baro_sigma_m", self.baro_sigma_m)?;
        require_positive("aid_model.velocity_sigma_m_s", self.velocity_sigma_m_s)?;
        require_non_negative(
            "aid_model.starved_velocity_sigma_m_s",
            self.starved_velocity_sigma_m_s,
        )?;
        require_non_negative(
            "aid_model.starved_accel_sigma_m_s2",
            self.starved_accel_sigma_m_s2,
        )?;
        require_positive("aid_model.recovery_hold_s", self.recovery_hold_s)?;
        let sigma = |field, value, low| RangeCheck {
            field,
            value,
            low,
            high: T::lit(AID_SIGMA_RANGE.high),
        };
        let min = T::lit(AID_SIGMA_RANGE.low);
        let checks = [
            sigma(
                "aid_model.baro_sigma_m",
                self.baro_sigma_m,
                LowerBound::AtLeast(min),
            ),
            sigma(
                "aid_model.velocity_sigma_m_s",
                self.velocity_sigma_m_s,
                LowerBound::AtLeast(min),
            ),
            sigma(
                "aid_model.starved_velocity_sigma_m_s",
                self.starved_velocity_sigma_m_s,
                LowerBound::ZeroOrAtLeast(min),
            ),
            sigma(
                "aid_model.starved_accel_sigma_m_s2",
                self.starved_accel_sigma_m_s2,
                LowerBound::ZeroOrAtLeast(min),
            ),
        ];
        let field = match first_outside(&checks) {
            Some(field) => field,
            None if self.recovery_hold_s > T::lit(MAX_TIMEOUT_S) => "aid_model.recovery_hold_s",
            None => return Ok(()),
        };
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        })
    }
}

/// Validates a gate (`InvalidConfig { field: "gate" }`): a threshold finite, positive and in
/// [`NIS_THRESHOLD_RANGE`].
#[inline(never)]
pub(crate) fn validate_gate<T: Real>(gate: &Gate<T>) -> Result<(), NavError> {
    if let Gate::Nis(thr) = *gate {
        require_positive("gate", thr)?;
        if !(thr >= T::lit(NIS_THRESHOLD_RANGE.low) && thr < T::lit(NIS_THRESHOLD_RANGE.high)) {
            return Err(NavError::InvalidConfig {
                field: "gate",
                issue: ConfigIssue::OutOfRange,
            });
        }
    }
    Ok(())
}

/// Validates a recovery policy: `starved_after_s` positive and ≤ [`MAX_TIMEOUT_S`]
/// (`recovery.starved_after_s`), the action [`RecoveryAction::Reanchor`]
/// (`recovery.action`, `OutOfRange` for the covariance actions these loops cannot take).
#[inline(never)]
pub(crate) fn validate_recovery<T: Real>(recovery: &RecoveryPolicy<T>) -> Result<(), NavError> {
    if let Some(s) = recovery.starved_after_s {
        require_positive("recovery.starved_after_s", s)?;
        if s > T::lit(MAX_TIMEOUT_S) {
            return Err(NavError::InvalidConfig {
                field: "recovery.starved_after_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
    }
    match recovery.action {
        RecoveryAction::Reanchor => Ok(()),
        RecoveryAction::Inflate { .. } | RecoveryAction::ResetToPrior => {
            Err(NavError::InvalidConfig {
                field: "recovery.action",
                issue: ConfigIssue::OutOfRange,
            })
        }
    }
}

/// The run-time part of a configuration (what `from_design` and the setters validate).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct RunTime<T> {
    pub(crate) aid_model: AidModel<T>,
    pub(crate) gate: Gate<T>,
    pub(crate) recovery: RecoveryPolicy<T>,
}

impl<T: Real> RunTime<T> {
    /// Validates the aid model, the gate and the recovery, in that order.
    pub(crate) fn validate(&self) -> Result<(), NavError> {
        self.aid_model.validate()?;
        validate_gate(&self.gate)?;
        validate_recovery(&self.recovery)
    }
}

/// The papers' recovery: re-anchor an aid rejected without a break for 60 s.
fn paper_recovery<T: Real>() -> RecoveryPolicy<T> {
    RecoveryPolicy {
        starved_after_s: Some(T::lit(60.0)),
        action: RecoveryAction::Reanchor,
    }
}

/// The papers' baro timeouts: stale after 1.5 periods (0.06 s), lost after 0.5 s.
fn paper_baro_timeouts<T: Real>() -> AidTimeouts<T> {
    AidTimeouts {
        stale_after_s: T::lit(0.06),
        lost_after_s: T::lit(0.5),
    }
}

/// Latitude of the papers' experiment, rad (37° N).
pub const PAPER_LATITUDE_RAD: f64 = 0.645_771_823_2;

impl<T: Real> ClassicalConfig<T> {
    /// The spec's experiment (`vertical-channel.md`, the `vc-response` scenario): IMU at
    /// 100 Hz, 37° N, τ = 20 s, baro at 25 Hz with a 0.2 s lag compensated (C4), baro stale
    /// after 0.06 s and lost after 0.5 s, [`AidModel::paper`], no gate ([`Gate::Off`]; the
    /// firmware images set `Gate::Nis(10.83)`, 0.1 % false alarms), re-anchoring after 60 s
    /// of rejections.
    pub fn paper() -> Self {
        Self {
            imu_dt_s: T::lit(0.01),
            latitude_rad: T::lit(PAPER_LATITUDE_RAD),
            tau_s: T::lit(20.0),
            baro_lag_s: T::lit(0.2),
            baro_period_s: T::lit(0.04),
            baro_timeouts: paper_baro_timeouts(),
            aid_model: AidModel::paper(),
            gate: Gate::Off,
            recovery: paper_recovery(),
            error_model: ErrorModel::paper(),
        }
    }

    pub(crate) fn run_time(&self) -> RunTime<T> {
        RunTime {
            aid_model: self.aid_model,
            gate: self.gate,
            recovery: self.recovery,
        }
    }
}

impl<T: Real> AidedConfig<T> {
    /// The spec's experiment: IMU at 100 Hz (accelerometer noise 10⁻³ m/s²/√Hz, design bias
    /// random walk 10⁻⁵ m/s²/√s), 37° N, baro at 25 Hz with 1 m noise and a 0.2 s lag
    /// compensated, velocity aid at 10 Hz with 0.1 m/s noise; timeouts baro 0.06 / 0.5 s,
    /// velocity 0.15 / 1 s; [`AidModel::paper`], no gate, re-anchoring after 60 s of
    /// rejections (as [`ClassicalConfig::paper`]).
    pub fn paper() -> Self {
        Self {
            imu_dt_s: T::lit(0.01),
            latitude_rad: T::lit(PAPER_LATITUDE_RAD),
            accel_noise_m_s2_rt_hz: T::lit(1e-3),
            accel_bias_rw_m_s2_rt_s: T::lit(1e-5),
            baro_noise_m: T::lit(1.0),
            baro_period_s: T::lit(0.04),
            baro_lag_s: T::lit(0.2),
            velocity_noise_m_s: T::lit(0.1),
            velocity_period_s: T::lit(0.1),
            baro_timeouts: paper_baro_timeouts(),
            velocity_timeouts: AidTimeouts {
                stale_after_s: T::lit(0.15),
                lost_after_s: T::lit(1.0),
            },
            aid_model: AidModel::paper(),
            gate: Gate::Off,
            recovery: paper_recovery(),
            error_model: ErrorModel::paper(),
        }
    }

    pub(crate) fn run_time(&self) -> RunTime<T> {
        RunTime {
            aid_model: self.aid_model,
            gate: self.gate,
            recovery: self.recovery,
        }
    }
}

/// A value of one float type in another (`f64` → `f32` rounds to nearest).
#[inline(always)]
fn to<T: Real, U: Real>(v: T) -> U {
    U::lit(v.to_f64())
}

fn cast_gate<T: Real, U: Real>(g: &Gate<T>) -> Gate<U> {
    match *g {
        Gate::Off => Gate::Off,
        Gate::Nis(t) => Gate::Nis(to(t)),
    }
}

fn cast_recovery<T: Real, U: Real>(r: &RecoveryPolicy<T>) -> RecoveryPolicy<U> {
    RecoveryPolicy {
        starved_after_s: r.starved_after_s.map(to),
        action: match r.action {
            RecoveryAction::Inflate { variance_factor } => RecoveryAction::Inflate {
                variance_factor: to(variance_factor),
            },
            RecoveryAction::ResetToPrior => RecoveryAction::ResetToPrior,
            RecoveryAction::Reanchor => RecoveryAction::Reanchor,
        },
    }
}

impl<T: Real> AidTimeouts<T> {
    /// The timeouts in another float type.
    pub fn cast<U: Real>(&self) -> AidTimeouts<U> {
        AidTimeouts {
            stale_after_s: to(self.stale_after_s),
            lost_after_s: to(self.lost_after_s),
        }
    }
}

impl<T: Real> AidModel<T> {
    /// The model in another float type.
    pub fn cast<U: Real>(&self) -> AidModel<U> {
        AidModel {
            baro_sigma_m: to(self.baro_sigma_m),
            velocity_sigma_m_s: to(self.velocity_sigma_m_s),
            starved_velocity_sigma_m_s: to(self.starved_velocity_sigma_m_s),
            starved_accel_sigma_m_s2: to(self.starved_accel_sigma_m_s2),
            recovery_hold_s: to(self.recovery_hold_s),
        }
    }
}

impl<T: Real> ClassicalConfig<T> {
    /// The configuration in another float type (e.g. written in `f64` on the ground for an
    /// `f32` loop: every value rounded to nearest; the design is computed from those values).
    pub fn cast<U: Real>(&self) -> ClassicalConfig<U> {
        ClassicalConfig {
            imu_dt_s: to(self.imu_dt_s),
            latitude_rad: to(self.latitude_rad),
            tau_s: to(self.tau_s),
            baro_lag_s: to(self.baro_lag_s),
            baro_period_s: to(self.baro_period_s),
            baro_timeouts: self.baro_timeouts.cast(),
            aid_model: self.aid_model.cast(),
            gate: cast_gate(&self.gate),
            recovery: cast_recovery(&self.recovery),
            error_model: self.error_model.cast(),
        }
    }
}

impl<T: Real> AidedConfig<T> {
    /// The configuration in another float type (see [`ClassicalConfig::cast`]).
    pub fn cast<U: Real>(&self) -> AidedConfig<U> {
        AidedConfig {
            imu_dt_s: to(self.imu_dt_s),
            latitude_rad: to(self.latitude_rad),
            accel_noise_m_s2_rt_hz: to(self.accel_noise_m_s2_rt_hz),
            accel_bias_rw_m_s2_rt_s: to(self.accel_bias_rw_m_s2_rt_s),
            baro_noise_m: to(self.baro_noise_m),
            baro_period_s: to(self.baro_period_s),
            baro_lag_s: to(self.baro_lag_s),
            velocity_noise_m_s: to(self.velocity_noise_m_s),
            velocity_period_s: to(self.velocity_period_s),
            baro_timeouts: self.baro_timeouts.cast(),
            velocity_timeouts: self.velocity_timeouts.cast(),
            aid_model: self.aid_model.cast(),
            gate: cast_gate(&self.gate),
            recovery: cast_recovery(&self.recovery),
            error_model: self.error_model.cast(),
        }
    }
}

//! Configuration of the transfer-alignment filters: [`TaConfig`], its envelope (the `MIN_*` /
//! `MAX_*` constants), the paper's configurations ([`TaConfig::paper`]) and the validation of
//! every field, including the run-time setters' gate and recovery policy.
use super::model::AxisFlexure;
use crate::contract::{Gate, RecoveryAction, RecoveryPolicy};
use crate::error::{require_finite, require_non_negative, require_positive, ConfigIssue};
use crate::time::seconds_to_micros;
use crate::Bounds;
use crate::{NavError, Real};
use nalgebra::Vector3;

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
/// Largest 1σ of the specific-force-difference bias `accel_bias_sigma_m_s2`, m/s² (≈ 50 mg,
/// far above any accelerometer that can align a missile).
pub const MAX_ACCEL_BIAS_SIGMA_M_S2: f64 = 0.5;
/// Largest |lever-arm component|, m.
pub const MAX_LEVER_ARM_M: f64 = 100.0;
/// Range of the χ²(1) NIS gate threshold ([`Gate::Nis`]), dimensionless.
pub const NIS_GATE_RANGE: Bounds = Bounds {
    low: 1.0,
    high: 1.0e4,
};
/// Largest `max_gap_steps`: the most predictions one call can run (bounded work per call:
/// see the README for the instruction count).
pub const MAX_GAP_STEPS: u32 = 100;
/// Longest `recovery.starved_after_s`, s (one hour).
pub const MAX_STARVED_AFTER_S: f64 = 3600.0;
/// Largest |ω_m|, |ω_s| accepted per axis, rad/s (≈ 2 900 °/s, above any tactical gyro's range).
pub const MAX_ANGULAR_RATE_RAD_S: f64 = 50.0;
/// Largest |ω̇_m| accepted per axis, rad/s².
pub const MAX_ANGULAR_ACCEL_RAD_S2: f64 = 1.0e4;
/// Largest |f_m|, |f_s| accepted per axis, m/s² (≈ 200 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 2.0e3;
/// |θ| beyond which (any axis, rad) the small-angle model no longer holds: the filter reports
/// `NeedsReinitialisation`, and an initial misalignment beyond it is refused (≈ 17°).
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
    /// [`MAX_MOUNT_SIGMA_RAD`]): the uncertainty of the coarse alignment that hands over
    /// [`super::TaInitial`].
    pub mount_sigma_rad: Vector3<T>,
    /// 1σ of one angular-rate difference sample dω (master + slave gyro noise), rad/s
    /// ([`RATE_NOISE_SIGMA_RANGE_RAD_S`]).
    pub rate_noise_sigma_rad_s: T,
    /// 1σ of one specific-force difference sample df (master + slave accelerometer noise), m/s²
    /// ([`ACCEL_NOISE_SIGMA_RANGE_M_S2`]).
    pub accel_noise_sigma_m_s2: T,
    /// 1σ per axis X, Y, Z of the random-constant bias of the specific-force difference df,
    /// m/s² (each 0 to [`MAX_ACCEL_BIAS_SIGMA_M_S2`]): master minus slave *equivalent*
    /// accelerometer bias, `b_m − (b_s + (S + M) f)` — the slave's scale-factor and
    /// misalignment error at the carry's specific force `f` is as constant as its bias while
    /// `f` is (≈ 1 g along the down axis in level carry; [`Self::with_slave_share`] adds it).
    /// Only the flight configuration ([`super::FlightFilter`]) estimates it (and its
    /// design's stamp includes it); the paper's filters have no bias state and ignore it (0
    /// in [`Self::paper`]).
    pub accel_bias_sigma_m_s2: Vector3<T>,
    /// Filter step (= nominal slave IMU sample interval), s: [`MIN_DT_S`] to [`MAX_DT_S`], a
    /// whole number of µs.
    pub dt_s: T,
    /// Allowed |t_master − t_slave| when pairing samples, s (0 ≤ tolerance < dt_s / 2; rounded
    /// to whole µs).
    pub time_tolerance_s: T,
    /// Longest gap, in steps, bridged by repeated prediction (1 to [`MAX_GAP_STEPS`]); a longer
    /// gap re-initialises the flexure states ([`super::GapOutcome::FlexureReinitialised`]).
    pub max_gap_steps: u32,
    /// χ²(1) NIS gate of each scalar update: [`Gate::Off`] fuses everything,
    /// [`Gate::Nis`] rejects above the threshold (e.g. 25 = 5σ; [`NIS_GATE_RANGE`]).
    pub gate: Gate<T>,
    /// What the filter does when the gate starves one of its channels (see
    /// [`super::TransferAlignment`], "Recovery"). `starved_after_s`: at least `dt_s` and at most
    /// [`MAX_STARVED_AFTER_S`] (or `None`: no recovery); `action`: only
    /// [`RecoveryAction::ResetToPrior`] is supported.
    pub recovery: RecoveryPolicy<T>,
}

/// The three cases of the paper's experiment (spec "The paper's experiment"): the X-axis
/// flexure correlation time, which sets the flexure angular acceleration.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum PaperCase {
    /// Small flexure angular acceleration: τ_X = 2.146 s (θ̈_f,X RMS ≈ 0.016 rad/s²).
    Case1,
    /// Large: τ_X = 0.358 s, the value of the paper's Table 3 (≈ 0.57 rad/s²).
    Case2,
    /// Very large: τ_X = 0.2 s (≈ 1.8 rad/s²).
    Case3,
}

impl PaperCase {
    /// Flexure correlation time of the X axis, s (Y and Z: 2.146 s in every case).
    pub const fn tau_x_s(self) -> f64 {
        match self {
            PaperCase::Case1 => 2.146,
            PaperCase::Case2 => 0.358,
            PaperCase::Case3 => 0.2,
        }
    }
}

/// The default recovery: a channel rejected by the gate for 0.5 s (50 epochs at 100 Hz)
/// resets the covariance to its prior ([`RecoveryAction::ResetToPrior`]).
pub fn default_recovery<T: Real>() -> RecoveryPolicy<T> {
    RecoveryPolicy {
        starved_after_s: Some(T::lit(0.5)),
        action: RecoveryAction::ResetToPrior,
    }
}

impl<T: Real> TaConfig<T> {
    /// The paper's configuration of `case` (the one definition used by the tests, the golden
    /// vectors, the firmware and the simulator's defaults):
    ///
    /// - lever arm L_0 = [0, 5, 0] m (assumed l = 5 m), filter at 100 Hz (`dt_s` = 0.01 s);
    /// - flexure 1σ 0.5° (X), 0.1° (Y, Z); τ_X of the case, τ_Y = τ_Z = 2.146 s;
    /// - mounting misalignment 1σ 0.5° per axis;
    /// - measurement noise of the spec's assumed sensors at 100 Hz: slave gyro ARW 0.1°/√h with
    ///   a navigation-grade master (0.002°/√h): 2.9 × 10⁻⁴ rad/s per sample; slave accelerometer
    ///   50 µg/√Hz, master 10 µg/√Hz: 5.0 × 10⁻³ m/s² per sample;
    /// - operational choices the paper does not make: pairing tolerance 1 ms, gaps bridged up
    ///   to 5 steps, a 5σ gate ([`Gate::Nis`] 25), [`default_recovery`].
    pub fn paper(case: PaperCase) -> Self {
        let deg = |v: f64| T::lit(v.to_radians());
        let axis = |sigma_deg: f64, tau_s: f64| AxisFlexure {
            sigma_rad: deg(sigma_deg),
            tau_s: T::lit(tau_s),
        };
        Self {
            lever_arm_m: Vector3::new(T::zero(), T::lit(5.0), T::zero()),
            flexure: [
                axis(0.5, case.tau_x_s()),
                axis(0.1, 2.146),
                axis(0.1, 2.146),
            ],
            mount_sigma_rad: Vector3::repeat(deg(0.5)),
            rate_noise_sigma_rad_s: T::lit(2.9e-4),
            accel_noise_sigma_m_s2: T::lit(5.0e-3),
            accel_bias_sigma_m_s2: Vector3::zeros(),
            dt_s: T::lit(0.01),
            time_tolerance_s: T::lit(0.001),
            max_gap_steps: 5,
            gate: Gate::Nis(T::lit(25.0)),
            recovery: default_recovery(),
        }
    }
}

impl<T: Real> TaConfig<T> {
    /// The flight configuration of a paper case: [`Self::paper`] with the specific-force
    /// difference bias 1σ of a tactical-grade slave accelerometer, 300 µg (2.94e-3 m/s²,
    /// combined with a 25 µg navigation-grade master: 3.0e-3 m/s²) on every axis, for
    /// [`super::FlightFilter`] (the instruments' biases only: [`Self::with_slave_share`]
    /// adds the slave's scale-factor and misalignment share).
    pub fn flight(case: PaperCase) -> Self {
        Self {
            accel_bias_sigma_m_s2: Vector3::repeat(T::lit(3.0e-3)),
            ..Self::paper(case)
        }
    }

    /// This configuration with the slave accelerometers' scale-factor and misalignment share
    /// of the equivalent bias added to the bias prior: per axis `σ_i² + v_i`, with `v_i`
    /// ((m/s²)², [`slave_share_variance`]) the variance of `((S + M) f)_i` in level carry.
    /// `scale_factor`: 1σ of each axis' scale-factor error, dimensionless; `misalignment_rad`:
    /// 1σ of each off-diagonal element of M, rad. Not validated here ([`Self::validate`] and
    /// the instrument errors' own checks are).
    pub fn with_slave_share(&self, scale_factor: T, misalignment_rad: T) -> Self {
        let v = slave_share_variance(scale_factor, misalignment_rad);
        let b = &self.accel_bias_sigma_m_s2;
        Self {
            accel_bias_sigma_m_s2: b.component_mul(b).zip_map(&v, |b2, vi| (b2 + vi).sqrt()),
            ..*self
        }
    }
}

/// Variance per slave axis X, Y, Z of the scale-factor and misalignment share `(S + M) f` of
/// the slave's equivalent accelerometer bias at the specific force of level carry, (m/s²)²:
/// `f` along the down axis (the mount's and the aircraft's few degrees of pitch change it
/// by their square), its magnitude gravity at most, [`crate::earth::GRAVITY_POLE_M_S2`]; with
/// independent errors `v_i = σ_S² f_i² + σ_M² (|f|² − f_i²)`: `σ_M² g²` on X and Y,
/// `σ_S² g²` on Z. `scale_factor` dimensionless, `misalignment_rad` rad (1σ each). The share's
/// change from a zero force to [`super::level_carry_force`] ([`super::share_change_variance`]).
pub fn slave_share_variance<T: Real>(scale_factor: T, misalignment_rad: T) -> Vector3<T> {
    super::share_change_variance(scale_factor, misalignment_rad, &super::level_carry_force())
}

#[cold]
#[inline(never)]
pub(super) fn out_of_range(field: &'static str) -> NavError {
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

/// `Ok` when `v` is finite, positive and within `[lo, hi]`.
fn positive_within<T: Real>(field: &'static str, v: T, lo: f64, hi: f64) -> Result<(), NavError> {
    require_positive(field, v)?;
    within(field, v, lo, hi)
}

/// What the filter derives from a validated configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct Derived<T> {
    /// Variance of one rate-difference sample, (rad/s)².
    pub r_rate: T,
    /// Variance of one specific-force-difference sample, (m/s²)².
    pub r_accel: T,
    /// Filter step, µs.
    pub dt_us: u64,
    /// Pairing tolerance, µs.
    pub tol_us: u64,
    /// Epochs of rejections that starve a channel (`None`: recovery disabled).
    pub starved_epochs: Option<u32>,
}

impl<T: Real> TaConfig<T> {
    /// Validates every field against the envelope (typed `InvalidConfig` naming the field):
    /// finiteness and sign first, then the ranges of the `MIN_*`/`MAX_*` constants and the joint
    /// conditions (τ ≥ [`MIN_TAU_STEPS`] dt, tolerance < dt/2, dt a whole number of µs), the
    /// gate (`Nis` threshold within [`NIS_GATE_RANGE`]) and the recovery policy (at least one step,
    /// at most [`MAX_STARVED_AFTER_S`], action `ResetToPrior`).
    pub fn validate(&self) -> Result<(), NavError> {
        self.derived().map(|_| ())
    }

    /// [`Self::validate`], then what the filter derives from the configuration.
    #[inline(never)] // one copy per float type, shared by both filters
    pub(super) fn derived(&self) -> Result<Derived<T>, NavError> {
        for v in self.lever_arm_m.iter() {
            require_finite("lever_arm_m", *v)?;
            within("lever_arm_m", v.abs(), 0.0, MAX_LEVER_ARM_M)?;
        }
        positive_within("dt_s", self.dt_s, MIN_DT_S, MAX_DT_S)?;
        let dt_us = self.dt_us()?;
        for fl in self.flexure.iter() {
            let (s, tau) = (fl.sigma_rad, fl.tau_s);
            positive_within(
                "flexure.sigma_rad",
                s,
                MIN_FLEXURE_SIGMA_RAD,
                MAX_FLEXURE_SIGMA_RAD,
            )?;
            positive_within("flexure.tau_s", tau, MIN_FLEXURE_TAU_S, MAX_FLEXURE_TAU_S)?;
            if tau < T::lit(MIN_TAU_STEPS) * self.dt_s {
                return Err(out_of_range("flexure.tau_s"));
            }
        }
        for v in self.mount_sigma_rad.iter() {
            require_non_negative("mount_sigma_rad", *v)?;
            within("mount_sigma_rad", *v, 0.0, MAX_MOUNT_SIGMA_RAD)?;
        }
        let (rate, accel) = (self.rate_noise_sigma_rad_s, self.accel_noise_sigma_m_s2);
        let (rlo, rhi) = RATE_NOISE_SIGMA_RANGE_RAD_S;
        positive_within("rate_noise_sigma_rad_s", rate, rlo, rhi)?;
        let (alo, ahi) = ACCEL_NOISE_SIGMA_RANGE_M_S2;
        positive_within("accel_noise_sigma_m_s2", accel, alo, ahi)?;
        for v in self.accel_bias_sigma_m_s2.iter() {
            require_non_negative("accel_bias_sigma_m_s2", *v)?;
            within("accel_bias_sigma_m_s2", *v, 0.0, MAX_ACCEL_BIAS_SIGMA_M_S2)?;
        }
        require_non_negative("time_tolerance_s", self.time_tolerance_s)?;
        let tol_us = match seconds_to_micros(self.time_tolerance_s) {
            Some(tol) if 2 * tol < dt_us => tol,
            _ => return Err(out_of_range("time_tolerance_s")),
        };
        if self.max_gap_steps == 0 || self.max_gap_steps > MAX_GAP_STEPS {
            return Err(out_of_range("max_gap_steps"));
        }
        validate_gate(&self.gate)?;
        let starved_epochs = validate_recovery(&self.recovery, dt_us)?;
        Ok(Derived {
            r_rate: rate * rate,
            r_accel: accel * accel,
            dt_us,
            tol_us,
            starved_epochs,
        })
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

/// Validates a gate: [`Gate::Off`], or [`Gate::Nis`] with a finite threshold within
/// [`NIS_GATE_RANGE`] (`InvalidConfig { field: "gate" }`).
pub(super) fn validate_gate<T: Real>(gate: &Gate<T>) -> Result<(), NavError> {
    match *gate {
        Gate::Off => Ok(()),
        Gate::Nis(g) => positive_within("gate", g, NIS_GATE_RANGE.low, NIS_GATE_RANGE.high),
    }
}

/// Validates a recovery policy for a filter step of `dt_us` µs and returns the number of
/// consecutive rejected epochs that starve a channel: `⌈starved_after_s / dt_s⌉` in whole µs
/// (so 0.5 s at 100 Hz is exactly 50 epochs), `None` when recovery is disabled.
///
/// Errors: `InvalidConfig { field: "recovery.starved_after_s" }` unless finite, at least one
/// step and at most [`MAX_STARVED_AFTER_S`]; `InvalidConfig { field: "recovery.action",
/// issue: OutOfRange }` for an action other than [`RecoveryAction::ResetToPrior`].
pub(super) fn validate_recovery<T: Real>(
    policy: &RecoveryPolicy<T>,
    dt_us: u64,
) -> Result<Option<u32>, NavError> {
    if !matches!(policy.action, RecoveryAction::ResetToPrior) {
        return Err(out_of_range("recovery.action"));
    }
    let Some(s) = policy.starved_after_s else {
        return Ok(None);
    };
    const FIELD: &str = "recovery.starved_after_s";
    positive_within(FIELD, s, 0.0, MAX_STARVED_AFTER_S)?;
    let us = seconds_to_micros(s).ok_or_else(|| out_of_range(FIELD))?;
    let dt_us = dt_us.max(1);
    if us < dt_us {
        return Err(out_of_range(FIELD));
    }
    let epochs = us.div_ceil(dt_us);
    u32::try_from(epochs)
        .map(Some)
        .map_err(|_| out_of_range(FIELD))
}

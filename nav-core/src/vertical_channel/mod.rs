//! Baro-inertial vertical channel (spec `vertical-channel.md`): the classical 3rd-order
//! damping loop ([`classical`]) and the velocity-aided loop with Riccati-designed gains
//! ([`aided`]).
//!
//! Both loops are linear observers on `x = [h, V_z, b]` (altitude m up, vertical velocity m/s
//! up, accelerometer bias state m/s²) driven by the vertical specific force and corrected by
//! the aids:
//!
//! ```text
//! x̂' = A₀ x̂ + e₂ A_z + K (z − C x̂),     A_z = f_up − g(ĥ)
//! ```
//!
//! `g(ĥ)` is normal gravity with its altitude dependence, evaluated at the estimate, so the
//! error dynamics contain the destabilising term `c δh` (`c = 2ω_s²`) of the spec. The
//! continuous loop is **discretised exactly at the IMU rate**: with the aids held over one
//! IMU interval (zero-order hold; a held sample is extrapolated to the middle of the interval
//! with `V̂_z · age`), `x̂_{k+1} = Φ_m x̂_k + Γ_m u_k`, evaluated in innovation form (see `Mode`), `u = [A_z, z_h, z_v]`, where
//! `[Φ_m Γ_m]` comes from the exponential of the augmented matrix `[[F_m, G_m], [0, 0]]`
//! (computed once at configuration in `f64`) for each of the four aid modes `m` (which aids are
//! in use). A step costs two 3×3 matrix-vector products and the gravity polynomial.
//!
//! Design and run are separable ([`design`]): `new(config, init)` designs on board, while
//! `from_design(config, &design, init)` takes a [`ClassicalDesign`] / [`AidedDesign`] computed
//! elsewhere (ground, build time, stored as values) and runs no design code.
//!
//! Multi-rate: the IMU drives [`classical::ClassicalLoop::step`] /
//! [`aided::AidedLoop::step`] at its rate; aid samples are passed when they arrive,
//! time-stamped, and may be missing. Each aid has an [`AidStatus`]: `Fresh` and `Stale` samples
//! are used, a `Lost` (or never received) aid is dropped and the loop runs on the IMU alone
//! (pure inertial in that channel), which the per-step [`AidReport`] says.
//!
//! Innovation gating (issue 7): with [`InnovationGate`] installed (`set_gate`), every newly
//! arrived sample is χ²-tested against the estimate before it replaces the held one; the
//! verdict (innovation, gate variance, NIS, fused/rejected, re-acquisition, reset) is in
//! [`AidReport::new_sample`] and [`GateCounters`] count them. The recovery path of a starved
//! loop (re-inflated gate, recovery gate, reset of the measured state on re-acquisition) is
//! described at [`InnovationGate`].
//!
//! Numerics: the step is evaluated in innovation form (see `Mode`), exact and well
//! conditioned in f32. Bad input (non-finite or out-of-range values, time stamps not
//! increasing, an IMU interval off by more than [`IMU_DT_TOLERANCE`], aid samples from the
//! future) returns a typed [`NavError`] and leaves the loop unchanged, bit for bit. A held
//! (`Stale`) sample is extrapolated at constant acceleration: choose `lost_after_s` so that
//! ½ · jerk · age² stays below the aid's noise (with high jerk, a long stale window feeds the
//! loop a wrong reading).

pub mod aided;
pub mod classical;
pub mod design;
pub mod riccati;

use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::math::discretize::discretize;
pub use crate::math::kalman::FusionOutcome;
use crate::{NavError, Real};
use nalgebra::{Matrix3, Matrix3x2, SMatrix, Vector2, Vector3};

/// Largest accepted |specific force|, m/s² (20 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 196.0;
/// Accepted altitude range of the estimate and the baro, m.
pub const ALTITUDE_RANGE_M: (f64, f64) = (-2_000.0, 60_000.0);
/// Range the altitude **estimate** must stay in, m (wider than [`ALTITUDE_RANGE_M`] so a loop
/// coasting through a long outage keeps running and can re-acquire; leaving it means the loop
/// has diverged: the step is refused with `InputOutOfRange { input: "altitude estimate" }`).
pub const ESTIMATE_RANGE_M: (f64, f64) = (-50_000.0, 500_000.0);
/// Largest accepted |vertical velocity| of the aid, m/s.
pub const MAX_VERTICAL_SPEED_M_S: f64 = 1_500.0;
/// Accepted IMU interval relative to the configured one: `|Δt − dt| ≤ 0.25 dt`.
pub const IMU_DT_TOLERANCE: f64 = 0.25;
/// Longest IMU gap bridged by a step, in IMU intervals: a sample whose interval is
/// `n · dt` (±[`IMU_DT_TOLERANCE`] dt, 2 ≤ n ≤ this) is accepted and the loop first coasts
/// the `n − 1` missing intervals on its specific force (no aid), then steps normally. A longer
/// gap is refused (`InvalidTimeStep`); the caller then re-initialises (`reinitialise`).
pub const MAX_IMU_GAP_INTERVALS: u32 = 100;
/// The loops keep the altitude relative to a reference that is moved to the estimate when
/// they differ by more than this, m (f32 resolution 2⁻¹⁶ m here).
pub const RECENTRE_M: f64 = 256.0;
/// Largest accepted configured IMU interval `imu_dt_s`, s.
pub const MAX_IMU_DT_S: f64 = 1.0;
/// Largest accepted classical time constant `tau_s`, s.
pub const MAX_TAU_S: f64 = 1.0e4;
/// Accepted range of the aided design's PSDs and periods (squares of the noise densities,
/// `σ² T` of the aids, the periods): `[MIN_DESIGN_VALUE, MAX_DESIGN_VALUE]`.
pub const MIN_DESIGN_VALUE: f64 = 1.0e-24;
/// Upper end of the aided design's accepted range, see [`MIN_DESIGN_VALUE`].
pub const MAX_DESIGN_VALUE: f64 = 1.0e12;
/// Largest accepted aid timeout (`stale_after_s`, `lost_after_s`), s.
pub const MAX_TIMEOUT_S: f64 = 1.0e6;

/// One IMU sample: the vertical component of the specific force, averaged over the interval
/// that ends at `time_s`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample<T> {
    /// End of the IMU interval, s.
    pub time_s: T,
    /// Vertical specific force, up positive, m/s² (≈ +g at rest).
    pub specific_force_up_m_s2: T,
}

/// One barometric altitude sample.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BaroSample<T> {
    /// Time of validity, s (same clock as the IMU).
    pub time_s: T,
    /// Barometric altitude, m, up positive.
    pub altitude_m: T,
}

/// One vertical-velocity aid sample (GNSS Doppler, air data …).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocitySample<T> {
    /// Time of validity, s.
    pub time_s: T,
    /// Vertical velocity, m/s, up positive.
    pub vz_up_m_s: T,
}

/// Freshness of an aid at the end of a step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AidStatus<T> {
    /// Latest sample not older than `stale_after_s`: used.
    Fresh {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// Latest sample older than `stale_after_s` but not than `lost_after_s`: still used,
    /// extrapolated with the estimated vertical velocity.
    Stale {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// Latest sample older than `lost_after_s`: dropped, the loop runs on the IMU alone.
    Lost {
        /// Age of the latest sample, s.
        age_s: T,
    },
    /// No sample received yet: the loop runs on the IMU alone.
    NoData,
}

impl<T> AidStatus<T> {
    /// `true` for `Fresh` and `Stale` (the aid corrects the loop).
    pub fn in_use(&self) -> bool {
        matches!(self, AidStatus::Fresh { .. } | AidStatus::Stale { .. })
    }
}

/// Per-aid report of one step.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidReport<T> {
    /// Freshness (and whether the aid was used).
    pub status: AidStatus<T>,
    /// Innovation `z − C x̂` at the start of the step (measurement unit), `None` when the aid
    /// was not used. For the baro, `z` is the held sample extrapolated to mid-interval and the
    /// prediction includes the lag compensation `ĥ − lag · V̂_z`.
    pub innovation: Option<T>,
    /// Innovation variance of a fresh sample under the steady-state design,
    /// `C P Cᵀ + σ²` (unit²); `None` for the classical loop (no covariance) or an unused aid.
    pub innovation_variance: Option<T>,
    /// The χ² gate's verdict on a sample that arrived in this step (`None`: no new sample).
    pub new_sample: Option<SampleCheck<T>>,
}

/// What happened to a newly arrived aid sample.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SampleCheck<T> {
    /// Innovation of the new sample, extrapolated to mid-interval (measurement unit).
    pub innovation: T,
    /// Gate variance `S = σ₀² + d(gap)²` (unit²); `+∞` when no gate is configured or for the
    /// first sample of an aid (accepted ungated).
    pub gate_variance: T,
    /// `Fused` (the sample replaces the held one) or `Rejected` (discarded; the previously
    /// accepted sample keeps ageing and the aid eventually goes `Lost`).
    pub outcome: FusionOutcome,
    /// `true` when this accepted sample ended a `Lost` period (re-acquisition).
    pub reacquired: bool,
    /// `true` when the re-acquisition reset the measured state (see [`InnovationGate`]).
    pub reset: bool,
}

impl<T: Real> SampleCheck<T> {
    /// Normalised innovation squared `ν² / S` (χ², 1 dof); 0 when ungated.
    pub fn nis(&self) -> T {
        self.innovation * self.innovation / self.gate_variance
    }
}

/// Gate counters of one aid. `accepted`, `rejected` and `consecutive_rejected` wrap after
/// 2³² samples (≈ 1.4 years at 100 Hz); `reacquisitions` and `resets` saturate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GateCounters {
    /// Samples accepted.
    pub accepted: u32,
    /// Samples rejected by the gate.
    pub rejected: u32,
    /// Rejections since the last accepted sample.
    pub consecutive_rejected: u32,
    /// Accepted samples that ended a `Lost` period (re-acquisitions).
    pub reacquisitions: u32,
    /// Re-acquisitions that reset the measured state (innovation beyond the tracking gate).
    pub resets: u32,
}

/// χ² innovation gate of the aid samples, with re-inflation while an aid is starved and a
/// reset on re-acquisition.
///
/// A new sample with innovation ν (against the estimate at mid-interval, the same innovation
/// the loop corrects with) is rejected when `ν² > nis_threshold · S`, where
///
/// ```text
/// baro:      S = σ_h² + (gap · (σ_v0 + ½ σ_a0 · gap))²
/// velocity:  S = σ_v² + (σ_a0 · gap)²
/// ```
///
/// and `gap` is the time since the last **accepted** sample of that aid. σ₀ is the innovation
/// σ of a tracking loop; the second term is the open-loop (inertial-only) error growth from a
/// velocity uncertainty σ_v0 and an acceleration uncertainty σ_a0. A rejected sample is
/// discarded: the last accepted one keeps ageing (`Stale`, then `Lost`, the loop coasting on
/// the IMU).
///
/// Recovery path when a loop is starved (dropout, or every sample rejected). The loops are
/// fixed-gain observers without a running covariance, so:
///
/// 1. **Re-inflation of the gate**: while starved, S grows as the inertial solution's plausible
///    drift, until a sample consistent with it is accepted. A persistent wrong reading that
///    departs from the inertial solution faster than the drift model (a frozen baro in a climb,
///    a spike) stays rejected.
/// 2. **Recovery gate**: the gate variance that admitted the re-acquiring sample is held
///    (S = max(S(gap), S_reacq)) until the innovations have stayed inside the *tracking* gate
///    (`ν² ≤ nis_threshold · σ₀²`) for `recovery_hold_s`; then tracking gating resumes. Without it
///    the velocity error left by a long coast makes the next samples fail the tracking gate,
///    the aid goes `Lost` again and the loop cycles between coasting and re-acquiring.
/// 3. **Reset on re-acquisition**: when the accepted sample ends a `Lost` period and its
///    innovation fails the *tracking* gate (`ν² > nis_threshold · σ₀²`), the measured state
///    (ĥ for the baro, V̂_z for the velocity aid) is moved by ν so the innovation is zero; the
///    other states are kept. The loop then removes the remaining (velocity, bias) error at its
///    own bandwidth instead of converting a large altitude error into a large velocity and
///    bias transient (with τ = 2 s, a 600 m coast error would otherwise drive V̂_z 200 m/s
///    off). A small re-acquisition innovation is absorbed by the loop (no reset, no jump).
///
/// The first sample an aid ever delivers is accepted ungated (acquisition). Without a gate
/// (`set_gate(None)`) every valid sample is accepted and there is no reset.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InnovationGate {
    /// χ² threshold on ν²/S (1 dof; e.g. 10.83 for a 0.1 % false-alarm rate).
    pub nis_threshold: f64,
    /// Baro innovation σ₀ of a tracking loop, m.
    pub baro_sigma_m: f64,
    /// Velocity-aid innovation σ₀ of a tracking loop, m/s (unused by the classical loop).
    pub velocity_sigma_m_s: f64,
    /// Velocity uncertainty σ_v0 of the inertial solution driving the re-inflation, m/s (≥ 0).
    pub starved_velocity_sigma_m_s: f64,
    /// Acceleration uncertainty σ_a0 driving the re-inflation, m/s² (≥ 0).
    pub starved_accel_sigma_m_s2: f64,
    /// How long the innovations must stay inside the tracking gate after a re-acquisition
    /// before the recovery gate is released, s (> 0; a few loop time constants, e.g. 3τ).
    pub recovery_hold_s: f64,
}

impl InnovationGate {
    /// Validates the gate and converts it to the loop's float type.
    pub(crate) fn compile<T: Real>(&self) -> Result<GateParams<T>, NavError> {
        let thr = require_positive("gate.nis_threshold", self.nis_threshold)?;
        let sh = require_positive("gate.baro_sigma_m", self.baro_sigma_m)?;
        let sv = require_positive("gate.velocity_sigma_m_s", self.velocity_sigma_m_s)?;
        let gv = require_non_negative(
            "gate.starved_velocity_sigma_m_s",
            self.starved_velocity_sigma_m_s,
        )?;
        let ga = require_non_negative(
            "gate.starved_accel_sigma_m_s2",
            self.starved_accel_sigma_m_s2,
        )?;
        let hold = require_positive("gate.recovery_hold_s", self.recovery_hold_s)?;
        if hold > MAX_TIMEOUT_S {
            return Err(NavError::InvalidConfig {
                field: "gate.recovery_hold_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        // The threshold in [10⁻³⁰, 10³⁰), the σ in [10⁻¹⁵, 10¹⁵) (zero drift is legal), so the
        // squares stay finite and (for σ₀) normal in f32. The squares are formed in the loop's
        // float type: no f64 multiply (software floating point on the M4F) in a flight image.
        gate_ranges(&[
            ("gate.nis_threshold", thr, false, 1.0e-30, 1.0e30),
            ("gate.baro_sigma_m", sh, false, 1.0e-15, 1.0e15),
            ("gate.velocity_sigma_m_s", sv, false, 1.0e-15, 1.0e15),
            ("gate.starved_velocity_sigma_m_s", gv, true, 1.0e-15, 1.0e15),
            ("gate.starved_accel_sigma_m_s2", ga, true, 1.0e-15, 1.0e15),
        ])?;
        let (sh, sv, ga) = (T::lit(sh), T::lit(sv), T::lit(ga));
        Ok(GateParams {
            nis_threshold: T::lit(thr),
            baro_var: sh * sh,
            velocity_var: sv * sv,
            growth_v: T::lit(gv),
            growth_half_a: ga * T::lit(0.5),
            growth_a: ga,
            recovery_hold_s: T::lit(hold),
        })
    }
}

/// Each gate value `(field, v, zero_ok, low, high)` must be finite, below `high` and at least
/// `low` (or 0 when `zero_ok`); the first that is not is named. One loop (not unrolled).
#[inline(never)]
fn gate_ranges(values: &[(&'static str, f64, bool, f64, f64)]) -> Result<(), NavError> {
    for &(field, v, zero_ok, low, high) in crate::math::checks::opaque(values) {
        if !(v.is_finite() && v < high && ((zero_ok && v == 0.0) || v >= low)) {
            return Err(NavError::InvalidConfig {
                field,
                issue: ConfigIssue::OutOfRange,
            });
        }
    }
    Ok(())
}

/// [`InnovationGate`] in the loop's float type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GateParams<T> {
    nis_threshold: T,
    baro_var: T,
    velocity_var: T,
    growth_v: T,
    growth_half_a: T,
    growth_a: T,
    recovery_hold_s: T,
}

/// Timeouts of one aid.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidTimeouts {
    /// Age beyond which the aid is reported `Stale` (still used), s.
    pub stale_after_s: f64,
    /// Age beyond which the aid is `Lost` (dropped), s; ≥ `stale_after_s`.
    pub lost_after_s: f64,
}

impl AidTimeouts {
    #[inline(never)]
    fn validate(&self, stale: &'static str, lost: &'static str) -> Result<(), NavError> {
        require_positive(stale, self.stale_after_s)?;
        require_positive(lost, self.lost_after_s)?;
        for (field, v) in [(stale, self.stale_after_s), (lost, self.lost_after_s)] {
            if v > MAX_TIMEOUT_S {
                return Err(NavError::InvalidConfig {
                    field,
                    issue: ConfigIssue::OutOfRange,
                });
            }
        }
        if self.lost_after_s < self.stale_after_s {
            return Err(NavError::InvalidConfig {
                field: lost,
                issue: ConfigIssue::OutOfRange,
            });
        }
        Ok(())
    }
}

/// Initial state of a loop.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InitialState<T> {
    /// Time of the initial state, s (the first IMU sample must end one interval later).
    pub time_s: T,
    /// Initial altitude estimate, m, up positive.
    pub altitude_m: T,
    /// Initial vertical velocity estimate, m/s, up positive.
    pub vz_up_m_s: T,
    /// Initial accelerometer bias estimate (measured − true), m/s².
    pub accel_bias_m_s2: T,
}

/// Normal gravity as a quadratic in altitude at a fixed latitude,
/// `g(h) = g₀ − g₁ h + g₂ h²` (m/s²), fitted exactly to [`crate::earth::normal_gravity_m_s2`]
/// (which is quadratic in h) at configuration.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GravityModel<T> {
    /// Gravity on the ellipsoid, m/s².
    pub g0_m_s2: T,
    /// Vertical gradient −∂g/∂h at h = 0, 1/s².
    pub g1_per_s2: T,
    /// Second-order coefficient, 1/(m s²).
    pub g2_per_m_s2: T,
}

impl GravityModel<f64> {
    /// Model at a geodetic latitude (rad, |lat| ≤ π/2).
    pub fn at_latitude(latitude_rad: f64) -> Result<Self, NavError> {
        if !latitude_rad.is_finite() {
            return Err(NavError::InvalidConfig {
                field: "latitude_rad",
                issue: ConfigIssue::NotFinite,
            });
        }
        if latitude_rad.abs() > core::f64::consts::FRAC_PI_2 {
            return Err(NavError::InvalidConfig {
                field: "latitude_rad",
                issue: ConfigIssue::OutOfRange,
            });
        }
        let g = |h: f64| crate::earth::normal_gravity_m_s2(latitude_rad, h);
        let d = 1000.0;
        let (gm, g0, gp) = (g(-d), g(0.0), g(d));
        Ok(Self {
            g0_m_s2: g0,
            g1_per_s2: -(gp - gm) / (2.0 * d),
            g2_per_m_s2: (gp - 2.0 * g0 + gm) / (2.0 * d * d),
        })
    }

    /// The spec's `c = 2ω_s² = 2 g₀ / R₀`, 1/s² (used in the gain design).
    pub fn c_per_s2(&self) -> f64 {
        2.0 * crate::earth::schuler_frequency_sq(self.g0_m_s2)
    }

    fn cast<T: Real>(&self) -> GravityModel<T> {
        GravityModel {
            g0_m_s2: T::lit(self.g0_m_s2),
            g1_per_s2: T::lit(self.g1_per_s2),
            g2_per_m_s2: T::lit(self.g2_per_m_s2),
        }
    }
}

impl<T: Real> GravityModel<T> {
    /// g(h), m/s².
    #[inline(always)]
    pub fn gravity_m_s2(&self, altitude_m: T) -> T {
        self.g0_m_s2 - altitude_m * (self.g1_per_s2 - self.g2_per_m_s2 * altitude_m)
    }
}

/// One aid mode of the discretised loop in **innovation (delta) form**:
///
/// ```text
/// x̂⁺ = x̂ + N [V̂_z, A_z ± b̂]ᵀ + G [ν_h, ν_v]ᵀ,   N = M [e₁ e₂],  G = M K_m,
/// M = ∫₀^Δt exp(F_m s) ds,   F_m = A₀ − K_m C
/// ```
///
/// which is exactly `Φ x̂ + Γ u` (Φ = I + M F_m, Γ = M [e₂ K_m]) but never multiplies the
/// altitude itself by a coefficient: in f32, `Φ x̂ + Γ z` at 40 km cancels two terms of
/// 40 km · K Δt, and the diagonal of Φ = 1 − O(Δt/τ) keeps only a few digits of its small
/// part. It also costs 12 multiply-adds instead of 18.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Mode<T: Real> {
    pub(crate) n: Matrix3x2<T>,
    pub(crate) g: Matrix3x2<T>,
}

/// The four modes (none / baro / velocity / both) and the continuous gains they come from.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Modes<T: Real> {
    /// Φ of the baro-only mode (analysis only, not used by the step).
    pub(crate) phi_baro: Matrix3<T>,
    pub(crate) none: Mode<T>,
    pub(crate) baro: Mode<T>,
    pub(crate) velocity: Mode<T>,
    pub(crate) both: Mode<T>,
}

impl<T: Real> Modes<T> {
    #[inline(always)]
    pub(crate) fn select(&self, baro: bool, velocity: bool) -> &Mode<T> {
        match (baro, velocity) {
            (false, false) => &self.none,
            (true, false) => &self.baro,
            (false, true) => &self.velocity,
            (true, true) => &self.both,
        }
    }
}

/// Open-loop matrix of the observer state `[h, V_z, b]` (gravity handled outside):
/// `ḣ = V_z`, `V̇_z = A_z + bias_sign · b`.
pub(crate) fn open_loop(bias_sign: f64) -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, bias_sign, 0.0, 0.0, 0.0)
}

/// Exact ZOH discretisation of `x̂' = (A₀ − K_m C) x̂ + [e₂ | K_m] u` for the four aid modes.
/// `k` columns: baro, velocity; `c` rows: baro, velocity.
pub(crate) fn discretise_modes<T: Real>(
    a0: &Matrix3<f64>,
    k: &Matrix3x2<f64>,
    c: &SMatrix<f64, 2, 3>,
    dt_s: f64,
) -> Result<Modes<T>, NavError> {
    let one = |use_baro: bool, use_vel: bool| -> Result<(Mode<T>, Matrix3<T>), NavError> {
        let mut km = *k;
        if !use_baro {
            km.set_column(0, &Vector3::zeros());
        }
        if !use_vel {
            km.set_column(1, &Vector3::zeros());
        }
        let f = a0 - km * c;
        let mut aug = SMatrix::<f64, 7, 7>::zeros();
        aug.fixed_view_mut::<3, 3>(0, 0).copy_from(&f);
        // e₁ and e₂ as inputs (aug columns 3 and 4).
        for (r, col) in [(0, 3), (1, 4)] {
            if let Some(e) = aug.get_mut((r, col)) {
                *e = 1.0;
            }
        }
        aug.fixed_view_mut::<3, 2>(0, 5).copy_from(&km);
        let (phi_aug, _) = discretize(&aug, &SMatrix::<f64, 7, 7>::zeros(), dt_s)?;
        let phi: Matrix3<f64> = phi_aug.fixed_view::<3, 3>(0, 0).into_owned();
        let n: Matrix3x2<f64> = phi_aug.fixed_view::<3, 2>(0, 3).into_owned();
        let g: Matrix3x2<f64> = phi_aug.fixed_view::<3, 2>(0, 5).into_owned();
        if !phi
            .iter()
            .chain(n.iter())
            .chain(g.iter())
            .all(|v| v.is_finite())
        {
            return Err(NavError::NotConverged { iterations: 0 });
        }
        Ok((
            Mode {
                n: n.cast::<T>(),
                g: g.cast::<T>(),
            },
            phi.cast::<T>(),
        ))
    };
    let (baro, phi_baro) = one(true, false)?;
    Ok(Modes {
        phi_baro,
        none: one(false, false)?.0,
        baro,
        velocity: one(false, true)?.0,
        both: one(true, true)?.0,
    })
}

/// A held aid sample and its timeouts (in the loop's float type).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AidChannel<T> {
    pub(crate) last_time_s: T,
    pub(crate) last_value: T,
    pub(crate) received: bool,
    /// Gate variance held after a re-acquisition until the innovations have stayed inside
    /// the tracking gate for `recovery_hold_s` (0: tracking).
    pub(crate) recovery_var: T,
    /// Time since which the innovations are inside the tracking gate during a recovery
    /// (+∞: not inside).
    pub(crate) recovery_clear_since_s: T,
}

/// Timeouts of one aid in the loop's float type.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Timeouts<T> {
    pub(crate) stale_after_s: T,
    pub(crate) lost_after_s: T,
}

impl<T: Real> Timeouts<T> {
    pub(crate) fn new(t: &AidTimeouts) -> Self {
        Self {
            stale_after_s: T::lit(t.stale_after_s),
            lost_after_s: T::lit(t.lost_after_s),
        }
    }
}

impl<T: Real> AidChannel<T> {
    pub(crate) fn new() -> Self {
        Self {
            last_time_s: T::zero(),
            last_value: T::zero(),
            received: false,
            recovery_var: T::zero(),
            recovery_clear_since_s: T::lit(f64::INFINITY),
        }
    }

    /// Validates a new sample against the channel and the current IMU time; returns the
    /// channel as it would be with the sample (self is not modified).
    pub(crate) fn with_sample(
        &self,
        time_s: T,
        value: T,
        now_s: T,
        value_name: &'static str,
        range: (f64, f64),
    ) -> Result<Self, NavError> {
        if !time_s.is_finite() {
            return Err(NavError::NonFiniteInput {
                input: "aid time_s",
            });
        }
        if !value.is_finite() {
            return Err(NavError::NonFiniteInput { input: value_name });
        }
        if value < T::lit(range.0) || value > T::lit(range.1) {
            return Err(NavError::InputOutOfRange { input: value_name });
        }
        if time_s > now_s {
            return Err(NavError::MeasurementTimeOutOfWindow);
        }
        if self.received && time_s <= self.last_time_s {
            return Err(NavError::TimeNotIncreasing);
        }
        Ok(Self {
            last_time_s: time_s,
            last_value: value,
            received: true,
            ..*self
        })
    }

    #[inline(always)]
    pub(crate) fn status(&self, now_s: T, to: &Timeouts<T>) -> AidStatus<T> {
        if !self.received {
            return AidStatus::NoData;
        }
        let age_s = now_s - self.last_time_s;
        if age_s > to.lost_after_s {
            AidStatus::Lost { age_s }
        } else if age_s > to.stale_after_s {
            AidStatus::Stale { age_s }
        } else {
            AidStatus::Fresh { age_s }
        }
    }
}

/// Checks an IMU sample against the loop time; returns the number of missing IMU intervals
/// before it (0 normally, up to [`MAX_IMU_GAP_INTERVALS`] − 1 for a bridged gap).
pub(crate) fn check_imu<T: Real>(imu: &ImuSample<T>, time_s: T, dt_s: T) -> Result<u32, NavError> {
    if !imu.time_s.is_finite() {
        return Err(NavError::NonFiniteInput {
            input: "imu time_s",
        });
    }
    if !imu.specific_force_up_m_s2.is_finite() {
        return Err(NavError::NonFiniteInput {
            input: "specific_force_up_m_s2",
        });
    }
    if imu.specific_force_up_m_s2.abs() > T::lit(MAX_SPECIFIC_FORCE_M_S2) {
        return Err(NavError::InputOutOfRange {
            input: "specific_force_up_m_s2",
        });
    }
    if imu.time_s <= time_s {
        return Err(NavError::TimeNotIncreasing);
    }
    let dt = imu.time_s - time_s;
    let tol = T::lit(IMU_DT_TOLERANCE) * dt_s;
    if (dt - dt_s).abs() <= tol {
        return Ok(0);
    }
    gap_intervals(dt, dt_s, tol)
}

/// A gap of `n` IMU intervals (rare path): `Ok(n − 1)` when bridgeable.
#[cold]
#[inline(never)]
fn gap_intervals<T: Real>(dt: T, dt_s: T, tol: T) -> Result<u32, NavError> {
    let n = (dt / dt_s).round();
    if n >= T::lit(2.0)
        && n <= T::lit(f64::from(MAX_IMU_GAP_INTERVALS))
        && (dt - n * dt_s).abs() <= tol
    {
        // n is an integer in [2, MAX_IMU_GAP_INTERVALS]: the conversion is exact (and
        // saturating in Rust, so it cannot wrap even if it were not).
        let n_u32 = (n.to_f64() as u32).clamp(2, MAX_IMU_GAP_INTERVALS);
        Ok(n_u32 - 1)
    } else {
        Err(NavError::InvalidTimeStep)
    }
}

/// Validates an initial state.
#[inline(never)]
pub(crate) fn check_initial<T: Real>(init: &InitialState<T>) -> Result<(), NavError> {
    for (name, v) in [
        ("initial time_s", init.time_s),
        ("initial altitude_m", init.altitude_m),
        ("initial vz_up_m_s", init.vz_up_m_s),
        ("initial accel_bias_m_s2", init.accel_bias_m_s2),
    ] {
        if !v.is_finite() {
            return Err(NavError::NonFiniteInput { input: name });
        }
    }
    if init.altitude_m < T::lit(ALTITUDE_RANGE_M.0) || init.altitude_m > T::lit(ALTITUDE_RANGE_M.1)
    {
        return Err(NavError::InputOutOfRange {
            input: "initial altitude_m",
        });
    }
    Ok(())
}

/// Gate of one new sample: returns the channel to use and the verdict.
/// `rate = (r₁, r₂)` extrapolates the sample to mid-interval, `z + age (r₁ − r₂ age)`; `pred` is the predicted measurement;
/// `gate = (σ₀², growth₁, growth₂, threshold, recovery hold)` with the drift `d = gap (growth₁ + growth₂ gap)`.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn admit<T: Real, const SECOND_ORDER: bool>(
    old: &AidChannel<T>,
    cand: Option<AidChannel<T>>,
    now: T,
    lost_after_s: T,
    offset: T,
    mid: T,
    rate: (T, T),
    pred: T,
    gate: Option<(T, T, T, T, T)>,
) -> (AidChannel<T>, Option<SampleCheck<T>>) {
    let Some(mut cand) = cand else {
        return (*old, None);
    };
    let age = mid - cand.last_time_s;
    let r = if SECOND_ORDER {
        rate.0 - rate.1 * age
    } else {
        rate.0
    };
    let value = if SECOND_ORDER {
        cand.last_value - offset
    } else {
        cand.last_value
    };
    let innovation = value + age * r - pred;
    let nu2 = innovation * innovation;
    let lost = old.received && now - old.last_time_s > lost_after_s;
    let (gate_variance, pass) = match gate {
        Some((var0, g1, g2, thr, hold)) if old.received => {
            let gap = cand.last_time_s - old.last_time_s;
            let d = gap * (g1 + g2 * gap);
            let mut s = var0 + d * d;
            if old.recovery_var > s {
                s = old.recovery_var;
            }
            let pass = nu2 <= thr * s;
            if pass && lost {
                // Re-acquisition: hold this gate while the loop absorbs the coast error.
                cand.recovery_var = s;
                cand.recovery_clear_since_s = T::lit(f64::INFINITY);
            } else if pass && old.recovery_var > T::zero() {
                if nu2 > thr * var0 {
                    cand.recovery_clear_since_s = T::lit(f64::INFINITY);
                } else if cand.last_time_s - old.recovery_clear_since_s >= hold {
                    cand.recovery_var = T::zero();
                    cand.recovery_clear_since_s = T::lit(f64::INFINITY);
                } else if old.recovery_clear_since_s > cand.last_time_s {
                    cand.recovery_clear_since_s = cand.last_time_s;
                }
            }
            (s, pass)
        }
        _ => (T::lit(f64::INFINITY), true),
    };
    let reacquired = pass && lost;
    let check = SampleCheck {
        innovation,
        gate_variance,
        outcome: if pass {
            FusionOutcome::Fused
        } else {
            FusionOutcome::Rejected
        },
        reacquired,
        reset: false,
    };
    (if pass { cand } else { *old }, Some(check))
}

impl GateCounters {
    #[inline(always)]
    fn count<T>(&mut self, check: &Option<SampleCheck<T>>) {
        if let Some(c) = check {
            if c.outcome == FusionOutcome::Fused {
                self.accepted = self.accepted.wrapping_add(1);
                self.consecutive_rejected = 0;
                if c.reacquired {
                    self.reacquisitions = self.reacquisitions.saturating_add(1);
                    if c.reset {
                        self.resets = self.resets.saturating_add(1);
                    }
                }
            } else {
                self.rejected = self.rejected.wrapping_add(1);
                self.consecutive_rejected = self.consecutive_rejected.wrapping_add(1);
            }
        }
    }
}

/// Checks the configured IMU interval.
#[inline(never)]
pub(crate) fn check_imu_dt(imu_dt_s: f64) -> Result<(), NavError> {
    require_positive("imu_dt_s", imu_dt_s)?;
    if imu_dt_s > MAX_IMU_DT_S {
        return Err(NavError::InvalidConfig {
            field: "imu_dt_s",
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
}

/// The state and machinery shared by both loops.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LoopCore<T: Real> {
    /// `[ĥ − h_ref (m), V̂_z (m/s), b̂ (m/s²)]`: the altitude relative to `h_ref_m`, so that
    /// in f32 the per-step increments V̂_z Δt (µm to mm) are not lost to the altitude's
    /// resolution (4 mm at 40 km).
    pub(crate) x: Vector3<T>,
    /// Reference altitude, m (moved to the estimate when |ĥ − h_ref| > [`RECENTRE_M`]).
    pub(crate) h_ref_m: T,
    pub(crate) time_s: T,
    pub(crate) dt_s: T,
    pub(crate) half_dt_s: T,
    pub(crate) modes: Modes<T>,
    pub(crate) gravity: GravityModel<T>,
    pub(crate) baro: AidChannel<T>,
    pub(crate) velocity: AidChannel<T>,
    pub(crate) baro_timeouts: Timeouts<T>,
    pub(crate) velocity_timeouts: Timeouts<T>,
    /// Baro lag compensation (the classical loop's C4), s.
    pub(crate) baro_lag_s: T,
    /// +1 when `V̇_z = A_z + b` (aided loop, spec's A), −1 when `V̇_z = A_z − b` (classical).
    pub(crate) bias_sign: T,
    /// Innovation gate (`None`: every valid sample is accepted).
    pub(crate) gate: Option<GateParams<T>>,
    pub(crate) baro_counters: GateCounters,
    pub(crate) velocity_counters: GateCounters,
}

impl<T: Real> LoopCore<T> {
    /// The loop at `init` with a design's values (copies only: no f64 arithmetic).
    /// `step`: (IMU interval, half of it, baro lag), s.
    pub(crate) fn new(
        init: &InitialState<T>,
        bias_sign: f64,
        step: (T, T, T),
        modes: Modes<T>,
        gravity: &GravityModel<T>,
        baro: &AidTimeouts,
        velocity: &AidTimeouts,
    ) -> Result<Self, NavError> {
        check_initial(init)?;
        let (dt_s, half_dt_s, baro_lag_s) = step;
        Ok(Self {
            h_ref_m: init.altitude_m,
            x: Vector3::new(
                T::zero(),
                init.vz_up_m_s,
                -init.accel_bias_m_s2 * T::lit(bias_sign),
            ),
            time_s: init.time_s,
            dt_s,
            half_dt_s,
            modes,
            gravity: *gravity,
            baro: AidChannel::new(),
            velocity: AidChannel::new(),
            baro_timeouts: Timeouts::new(baro),
            velocity_timeouts: Timeouts::new(velocity),
            baro_lag_s,
            bias_sign: T::lit(bias_sign),
            gate: None,
            baro_counters: GateCounters::default(),
            velocity_counters: GateCounters::default(),
        })
    }

    /// One IMU step with optional new aid samples. On error nothing changes.
    /// `variances`: innovation variances to report for (baro, velocity) when used.
    /// Inlined into each loop's `step` (the classical loop's velocity path then folds away and
    /// the reports are built in place).
    #[inline(always)]
    pub(crate) fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
    ) -> Result<(AidReport<T>, AidReport<T>, u32), NavError> {
        let missing = check_imu(imu, self.time_s, self.dt_s)?;
        // A gap: coast the missing intervals first (cold, outlined, on a copy), then the
        // normal step from the coasted state (one inlined copy of `advance` for both).
        let (x, h_ref_m) = if missing > 0 {
            self.coast_gap(missing, imu)?
        } else {
            (self.x, self.h_ref_m)
        };
        let (b, v) = self.advance(x, h_ref_m, imu, baro, velocity, variances)?;
        Ok((b, v, missing + 1))
    }

    /// The step after the IMU time check, from the state `x` and reference altitude `h_ref`
    /// (the loop's, or a gap's coasted ones; the loop's clock is not used): aid checks, gate,
    /// propagation. On error nothing changes.
    #[inline(always)]
    fn advance(
        &mut self,
        mut x: Vector3<T>,
        h_ref: T,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
    ) -> Result<(AidReport<T>, AidReport<T>), NavError> {
        let now = imu.time_s;
        let (h, v, b) = (x.x, x.y, x.z);
        let mut az = imu.specific_force_up_m_s2 - self.gravity.gravity_m_s2(h_ref + h);
        let mid = now - self.half_dt_s;
        // Predicted measurements at mid-interval (the baro's relative to h_ref) and the rates
        // a held sample is extrapolated with (baro: second order, h(mid) = h(t) + age (V̂ −
        // ½ a age); velocity: first order).
        let mut h_pred = h - self.baro_lag_s * v;
        let mut v_rate = az + self.bias_sign * b;
        let half = T::lit(0.5);

        // Validate the new samples (nothing is committed before all checks pass).
        let baro_cand = match baro {
            Some(s) => Some(self.baro.with_sample(
                s.time_s,
                s.altitude_m,
                now,
                "altitude_m",
                ALTITUDE_RANGE_M,
            )?),
            None => None,
        };
        let vel_cand = match velocity {
            Some(s) => Some(self.velocity.with_sample(
                s.time_s,
                s.vz_up_m_s,
                now,
                "vz_up_m_s",
                (-MAX_VERTICAL_SPEED_M_S, MAX_VERTICAL_SPEED_M_S),
            )?),
            None => None,
        };
        // χ² gate on the new samples.
        let gate = self.gate.as_ref();
        let (baro_ch, mut baro_check) = admit::<T, true>(
            &self.baro,
            baro_cand,
            now,
            self.baro_timeouts.lost_after_s,
            h_ref,
            mid,
            (v, half * v_rate),
            h_pred,
            gate.map(|g| {
                (
                    g.baro_var,
                    g.growth_v,
                    g.growth_half_a,
                    g.nis_threshold,
                    g.recovery_hold_s,
                )
            }),
        );
        let (vel_ch, mut vel_check) = admit::<T, false>(
            &self.velocity,
            vel_cand,
            now,
            self.velocity_timeouts.lost_after_s,
            T::zero(),
            mid,
            (v_rate, T::zero()),
            v,
            gate.map(|g| {
                (
                    g.velocity_var,
                    g.growth_a,
                    T::zero(),
                    g.nis_threshold,
                    g.recovery_hold_s,
                )
            }),
        );
        // Recovery: a re-acquiring sample (accepted thanks to the re-inflated gate) whose
        // innovation fails the tracking gate resets the measured state so that its innovation
        // is zero (baro: ĥ; velocity: V̂_z); the other states are kept.
        let (mut reset_baro, mut reset_vel) = (false, false);
        if let Some(g) = gate {
            if let Some(c) = baro_check.as_mut().filter(|c| c.reacquired) {
                if c.innovation * c.innovation > g.nis_threshold * g.baro_var {
                    x.x += c.innovation;
                    reset_baro = true;
                    c.reset = true;
                }
            }
            if let Some(c) = vel_check.as_mut().filter(|c| c.reacquired) {
                if c.innovation * c.innovation > g.nis_threshold * g.velocity_var {
                    x.y += c.innovation;
                    reset_vel = true;
                    c.reset = true;
                }
            }
            if reset_baro || reset_vel {
                az = imu.specific_force_up_m_s2 - self.gravity.gravity_m_s2(h_ref + x.x);
                h_pred = x.x - self.baro_lag_s * x.y;
                v_rate = az + self.bias_sign * x.z;
            }
        }
        let v = x.y;

        let baro_status = baro_ch.status(now, &self.baro_timeouts);
        let vel_status = vel_ch.status(now, &self.velocity_timeouts);
        let use_baro = baro_status.in_use();
        let use_vel = vel_status.in_use();

        // Held samples extrapolated to the middle of the interval (ZOH of the continuous loop).
        let nu_h = use_baro.then(|| {
            let age = mid - baro_ch.last_time_s;
            (baro_ch.last_value - h_ref) + age * (v - half * v_rate * age) - h_pred
        });
        let nu_v = use_vel.then(|| vel_ch.last_value + (mid - vel_ch.last_time_s) * v_rate - v);
        let mode = self.modes.select(use_baro, use_vel);
        let mut x_new = x
            + (mode.n * Vector2::new(v, v_rate)
                + mode.g * Vector2::new(nu_h.unwrap_or(T::zero()), nu_v.unwrap_or(T::zero())));
        // One test for all three: a sum of finite values is finite unless it overflows, which
        // is refused as well.
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return Err(NavError::NonFiniteInput {
                input: "state after step",
            });
        }
        // Re-centre the relative altitude (and range-check the estimate) when it has moved.
        let mut h_ref_new = h_ref;
        if x_new.x.abs() > T::lit(RECENTRE_M) {
            h_ref_new = h_ref + x_new.x;
            if h_ref_new < T::lit(ESTIMATE_RANGE_M.0) || h_ref_new > T::lit(ESTIMATE_RANGE_M.1) {
                return Err(NavError::InputOutOfRange {
                    input: "altitude estimate",
                });
            }
            x_new.x = T::zero();
        }
        self.x = x_new;
        self.h_ref_m = h_ref_new;
        self.time_s = now;
        self.baro = baro_ch;
        self.velocity = vel_ch;
        self.baro_counters.count(&baro_check);
        self.velocity_counters.count(&vel_check);
        Ok((
            AidReport {
                status: baro_status,
                innovation: nu_h,
                innovation_variance: if use_baro { variances.0 } else { None },
                new_sample: baro_check,
            },
            AidReport {
                status: vel_status,
                innovation: nu_v,
                innovation_variance: if use_vel { variances.1 } else { None },
                new_sample: vel_check,
            },
        ))
    }

    /// Coasts the `missing` IMU intervals of a gap on the new sample's specific force,
    /// without new aid samples (held ones are used as in a normal step), on a copy of the
    /// loop; returns the coasted state and reference altitude (the loop is not changed).
    #[cold]
    #[inline(never)]
    fn coast_gap(&self, missing: u32, imu: &ImuSample<T>) -> Result<(Vector3<T>, T), NavError> {
        let mut tmp = *self;
        // The gap (already checked to be n intervals) is split evenly; the sub-steps use the
        // loop's fixed Φ and skip the interval check (f32 stamps may not resolve dt). A coast
        // changes only the state, the reference altitude and the clock (no new aid sample).
        let n = T::lit(f64::from(missing + 1));
        let step_s = (imu.time_s - self.time_s) / n;
        let mut k = T::zero();
        for _ in 0..missing {
            k += T::one();
            let sub = ImuSample {
                time_s: self.time_s + step_s * k,
                specific_force_up_m_s2: imu.specific_force_up_m_s2,
            };
            tmp.advance(tmp.x, tmp.h_ref_m, &sub, None, None, (None, None))?;
        }
        Ok((tmp.x, tmp.h_ref_m))
    }

    /// Restarts the state and clock from `init`, keeping the design, the gate and the
    /// counters (held aid samples are dropped). On error nothing changes.
    pub(crate) fn reinitialise(&mut self, init: &InitialState<T>) -> Result<(), NavError> {
        check_initial(init)?;
        self.h_ref_m = init.altitude_m;
        self.x = Vector3::new(
            T::zero(),
            init.vz_up_m_s,
            -init.accel_bias_m_s2 * self.bias_sign,
        );
        self.time_s = init.time_s;
        self.baro = AidChannel::new();
        self.velocity = AidChannel::new();
        Ok(())
    }

    /// Installs (or removes, `None`) the innovation gate. On error nothing changes.
    pub(crate) fn set_gate(&mut self, gate: Option<&InnovationGate>) -> Result<(), NavError> {
        self.gate = match gate {
            Some(g) => Some(g.compile()?),
            None => None,
        };
        Ok(())
    }

    /// Altitude estimate, m.
    pub(crate) fn altitude_m(&self) -> T {
        self.h_ref_m + self.x.x
    }

    /// Accelerometer bias estimate (measured − true), m/s².
    pub(crate) fn accel_bias_m_s2(&self) -> T {
        -self.x.z * self.bias_sign
    }
}

pub use aided::{AidedConfig, AidedGains, AidedLoop, AidedReport};

pub use classical::{ClassicalConfig, ClassicalGains, ClassicalLoop, ClassicalReport};

pub use design::{AidedDesign, ClassicalDesign};

#[cfg(test)]
mod tests;

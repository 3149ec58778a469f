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
//! continuous loop is **discretised exactly at the nominal IMU interval** `dt`: with the aids
//! held over one IMU interval (zero-order hold; a held sample is extrapolated to the middle of
//! the interval with `V̂_z · age`), `x̂_{k+1} = Φ_m x̂_k + Γ_m u_k`, evaluated in innovation form
//! (see `Mode`), `u = [A_z, z_h, z_v]`, where `[Φ_m Γ_m]` comes from the exponential of the
//! augmented matrix `[[F_m, G_m], [0, 0]]` (computed once at configuration in `f64`) for each
//! of the four aid modes `m` (which aids are in use). A nominal step costs two 3×2
//! matrix-vector products and the gravity polynomial.
//!
//! Time: every sample carries a [`Timestamp`] (integer microseconds); intervals are formed in
//! integers and converted to the float type as durations, so a loop that has run for 10⁹ s
//! computes its intervals exactly as in its first second. A step integrates the **actual**
//! interval `Δt` since the last accepted IMU sample (jitter, late and missing samples, gaps):
//!
//! - `Δt = dt`: the stored exact step;
//! - `dt/2 ≤ Δt ≤ 1.5 dt`: `M(Δt) r = M(dt) r + Φ(dt) M(Δt − dt) r` with `M(h) r` (the integral of
//!   the closed loop over `h`) by its Taylor series to `F³` — exact up to a truncation of
//!   ≈ (|λ| |Δt − dt|)⁴/120 (relative error 5·10⁻¹⁴ at dt/τ = 0.001, 8·10⁻⁷ at 0.05, checked at
//!   configuration against [`INTERVAL_ACCURACY`]); `Δt < dt/2`: the series alone;
//! - `1.5 dt < Δt ≤ (MAX_SUBSTEPS + ½) dt`: `round(Δt/dt)` equal sub-steps;
//! - up to [`MAX_BRIDGED_GAP_S`]: an exact inertial coast over `Δt − MAX_SUBSTEPS·dt`, then
//!   [`MAX_SUBSTEPS`] nominal sub-steps (bounded work: at most `MAX_SUBSTEPS` sub-steps and a
//!   coast per call);
//! - longer: not integrated; the loop re-anchors on the next aid samples (see [`LoopStatus`]).
//!
//! Only what is physically impossible is refused: an IMU stamp not after the loop's clock
//! (`TimeNotIncreasing`), an aid stamp after the IMU stamp or older than the aid's
//! `lost_after_s` (`MeasurementTimeOutOfWindow`) or not after the aid's previous one
//! (`TimeNotIncreasing`), non-finite or out-of-range values. A refused call changes nothing and
//! never freezes the clock: the next valid sample is integrated over its whole interval.
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
//! Innovation gating: with [`InnovationGate`] installed (`set_gate`), every newly
//! arrived sample is χ²-tested against the estimate before it replaces the held one; the
//! verdict (innovation, gate variance, NIS, fused/rejected, re-acquisition, reset) is in
//! [`AidReport::new_sample`] and [`GateCounters`] count them. The recovery path of a starved
//! loop (re-inflated gate, recovery gate, reset of the measured state on re-acquisition) is
//! described at [`InnovationGate`].
//!
//! Envelope (configuration): besides each field's range, the joint conditions are checked at
//! design time — the multirate loop (aid samples held and extrapolated between arrivals) must
//! be stable with perfect sensors (Jury test of the error monodromy over one aid period:
//! classical `tau_s` vs `imu_dt_s` and `baro_period_s`, aided design vs both periods), and the
//! variable-interval step must meet [`INTERVAL_ACCURACY`] (`imu_dt_s` vs the loop's bandwidth).
//! The estimate is held inside [`ESTIMATE_RANGE_M`], [`MAX_ESTIMATE_SPEED_M_S`] and
//! [`MAX_ESTIMATE_BIAS_M_S2`] (never a refused step); health and counters are in
//! [`LoopStatus`]. No report carries a non-finite number.
//!
//! Numerics: the step is evaluated in innovation form (see `Mode`), exact and well
//! conditioned in f32. Bad input returns a typed [`NavError`] and leaves the loop unchanged,
//! bit for bit. A held
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
use crate::time::{micros_to_seconds, Timestamp};
use crate::{HealthState, NavError, Real};
use nalgebra::{Matrix3, Matrix3x2, SMatrix, Vector2, Vector3};

/// Largest accepted |specific force|, m/s² (20 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 196.0;
/// Accepted altitude range of the estimate and the baro, m.
pub const ALTITUDE_RANGE_M: (f64, f64) = (-2_000.0, 60_000.0);
/// Range the altitude **estimate** is kept in, m (wider than [`ALTITUDE_RANGE_M`] so a loop
/// coasting through a long outage keeps running and can re-acquire). An estimate that leaves
/// it is held at the limit (the step is not refused): the loop has diverged, its health is
/// `NeedsReinitialisation` and the next aid samples are accepted outside the gate and re-anchor
/// the measured states (see [`HealthState`] and [`InnovationGate`]).
pub const ESTIMATE_RANGE_M: (f64, f64) = (-50_000.0, 500_000.0);
/// Largest |vertical velocity| of the **estimate**, m/s; held at the limit like the altitude.
pub const MAX_ESTIMATE_SPEED_M_S: f64 = 10_000.0;
/// Largest |accelerometer bias| of the **estimate**, m/s² (= the specific-force range); held
/// at the limit like the altitude.
pub const MAX_ESTIMATE_BIAS_M_S2: f64 = MAX_SPECIFIC_FORCE_M_S2;
/// Largest accepted |vertical velocity| of the aid, m/s.
pub const MAX_VERTICAL_SPEED_M_S: f64 = 1_500.0;
/// Largest number of aided sub-steps one IMU interval is integrated in. An interval `Δt` is
/// integrated over its actual length: `n = round(Δt/dt)` sub-steps of `Δt/n` (1 ≤ n ≤ this),
/// each the stored exact step at the nominal `dt` corrected by a short series for the
/// difference (see the module documentation); a longer interval first coasts the excess on the IMU alone
/// (closed form, exact), then takes this many nominal sub-steps. Worst-case work of one call:
/// this many aided sub-steps plus one coast.
pub const MAX_SUBSTEPS: u32 = 8;
/// Longest IMU interval bridged by coasting, s. A longer gap is not integrated (one specific
/// force sample says nothing about so long an interval): the state is kept, the clock moves
/// to the sample, the held aid samples are dropped, the health is `NeedsReinitialisation` and
/// the next sample of each aid is accepted outside the gate and re-anchors the measured state
/// (ĥ for the baro, V̂_z for the velocity aid) — the loop comes back by itself, or by
/// `reinitialise`.
pub const MAX_BRIDGED_GAP_S: f64 = 10.0;
/// Relative accuracy the variable-interval step must reach at configuration (checked against
/// the exact discretisation at 0.25…1.5 dt, every aid mode); a configuration whose loop is
/// too fast for its IMU interval to meet it is refused (`InvalidConfig { field: "imu_dt_s" }`).
pub const INTERVAL_ACCURACY: f64 = 1.0e-4;
/// The loops keep the altitude relative to a reference that is moved to the estimate when
/// they differ by more than this, m (f32 resolution 2⁻¹⁶ m here).
pub const RECENTRE_M: f64 = 256.0;
/// Accepted range of the configured IMU interval `imu_dt_s`, s (10 kHz … 1 Hz).
pub const IMU_DT_RANGE_S: (f64, f64) = (1.0e-4, 1.0);
/// Largest accepted classical time constant `tau_s`, s.
pub const MAX_TAU_S: f64 = 1.0e4;
/// Accepted range of the aided design's PSDs and periods (squares of the noise densities,
/// `σ² T` of the aids, the periods): `[MIN_DESIGN_VALUE, MAX_DESIGN_VALUE]`.
pub const MIN_DESIGN_VALUE: f64 = 1.0e-24;
/// Upper end of the aided design's accepted range, see [`MIN_DESIGN_VALUE`].
pub const MAX_DESIGN_VALUE: f64 = 1.0e12;
/// Largest accepted aid timeout (`stale_after_s`, `lost_after_s`), s.
pub const MAX_TIMEOUT_S: f64 = 1.0e6;
/// Largest aid sample period relative to the IMU interval (the multirate stability analysis
/// runs over one aid period).
pub const MAX_AID_PERIOD_IMU_INTERVALS: f64 = 1.0e5;

/// One IMU sample: the vertical component of the specific force, averaged over the interval
/// that ends at `time`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuSample<T> {
    /// End of the IMU interval (the flight computer's clock).
    pub time: Timestamp,
    /// Vertical specific force, up positive, m/s² (≈ +g at rest).
    pub specific_force_up_m_s2: T,
}

/// One barometric altitude sample.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct BaroSample<T> {
    /// Time of validity (same clock as the IMU).
    pub time: Timestamp,
    /// Barometric altitude, m, up positive.
    pub altitude_m: T,
}

/// One vertical-velocity aid sample (GNSS Doppler, air data …).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VelocitySample<T> {
    /// Time of validity (same clock as the IMU).
    pub time: Timestamp,
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
    /// Gate variance `S = σ₀² + d(gap)²` (unit²), finite (saturated at [`MAX_GATE_VARIANCE`]);
    /// `None` when the sample was not gated (no gate configured, the first sample of an aid,
    /// or a sample accepted outside the gate to re-anchor the loop).
    pub gate_variance: Option<T>,
    /// `Fused` (the sample replaces the held one) or `Rejected` (discarded; the previously
    /// accepted sample keeps ageing and the aid eventually goes `Lost`).
    pub outcome: FusionOutcome,
    /// `true` when this accepted sample ended a `Lost` period or re-anchored the loop
    /// (re-acquisition).
    pub reacquired: bool,
    /// `true` when the re-acquisition reset the measured state (see [`InnovationGate`]).
    pub reset: bool,
}

impl<T: Real> SampleCheck<T> {
    /// Normalised innovation squared `ν² / S` (χ², 1 dof), finite; `None` when not gated.
    pub fn nis(&self) -> Option<T> {
        self.gate_variance
            .map(|s| self.innovation * self.innovation / s)
    }
}

/// Largest gate variance, unit² (the gate saturates here so that every reported number stays
/// finite in f32; a gate this wide admits any valid sample).
pub const MAX_GATE_VARIANCE: f64 = 1.0e30;

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
    /// Samples accepted outside the gate to re-anchor the loop (after a starved period longer
    /// than `starved_reset_after_s`, a gap longer than [`MAX_BRIDGED_GAP_S`] or a diverged
    /// estimate); each also counts as a re-acquisition and a reset.
    pub forced_reanchors: u32,
}

/// Health of a loop and the counters behind it ([`classical::ClassicalLoop::status`],
/// [`aided::AidedLoop::status`]).
///
/// `health` after the last step: `Initialising` before the first accepted step (after `new`
/// or `reinitialise`); `NeedsReinitialisation` while a re-anchoring of the baro is pending (a
/// gap longer than [`MAX_BRIDGED_GAP_S`], or an estimate held at a limit of
/// [`ESTIMATE_RANGE_M`] / [`MAX_ESTIMATE_SPEED_M_S`] / [`MAX_ESTIMATE_BIAS_M_S2`]): the next
/// baro sample re-anchors ĥ and ends it (or `reinitialise`); `Degraded` when the last step
/// bridged an IMU gap (more than one sub-step), the baro is not in use, a velocity aid that
/// has delivered is lost, an aid's last sample was rejected, or a recovery gate is held;
/// `Nominal` otherwise. Counters saturate.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LoopStatus {
    /// Health after the last step.
    pub health: HealthState,
    /// IMU intervals longer than 1.5 nominal intervals integrated in sub-steps (and, beyond
    /// [`MAX_SUBSTEPS`] intervals, a coast).
    pub gaps_bridged: u32,
    /// IMU gaps longer than [`MAX_BRIDGED_GAP_S`] (not integrated; state kept).
    pub gaps_skipped: u32,
    /// Steps whose estimate was held at a limit (diverged).
    pub estimate_limited: u32,
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
/// 4. **Bounded recovery gate**: the held gate is `min(S, σ₀² + ν²)` with ν the re-acquiring
///    sample's innovation — wide enough for that sample's own error, never the full re-inflated
///    width (a 3 km spike cannot pass a gate held open by a long outage).
/// 5. **Starvation reset**: when an aid's samples have been rejected without a break for
///    `starved_reset_after_s`, the next sample is accepted outside the gate and resets the
///    measured state (the inertial solution drifted faster than the re-inflation allows, e.g.
///    a bias estimate gone wrong in a long coast). The same re-anchoring (`reset`, counted in
///    [`GateCounters::forced_reanchors`]) follows a gap longer than [`MAX_BRIDGED_GAP_S`] and an
///    estimate held at its limits, gate or not.
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
    /// Starvation limit, s (> 0): when an aid's samples have been rejected without a break for
    /// this long, the next sample is accepted outside the gate and resets the measured state
    /// (the inertial solution has drifted faster than the re-inflation model allows; as PX4's
    /// height reset on a failed innovation check). Longer than the longest aid fault the gate
    /// should ride out (a frozen baro is accepted after this long).
    pub starved_reset_after_s: f64,
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
        let starve = require_positive("gate.starved_reset_after_s", self.starved_reset_after_s)?;
        for (field, v) in [
            ("gate.recovery_hold_s", hold),
            ("gate.starved_reset_after_s", starve),
        ] {
            if v > MAX_TIMEOUT_S {
                return Err(NavError::InvalidConfig {
                    field,
                    issue: ConfigIssue::OutOfRange,
                });
            }
        }
        // The threshold in [10⁻³, 10⁴), the σ in [10⁻⁶, 10⁶) (zero drift is legal), so the
        // squares stay finite and normal in f32 and threshold · S (S ≤ MAX_GATE_VARIANCE) and
        // ν² / S stay finite. The squares are formed in the loop's float type: no f64 multiply
        // (software floating point on the M4F) in a flight image.
        gate_ranges(&[
            ("gate.nis_threshold", thr, false, 1.0e-3, 1.0e4),
            ("gate.baro_sigma_m", sh, false, 1.0e-6, 1.0e6),
            ("gate.velocity_sigma_m_s", sv, false, 1.0e-6, 1.0e6),
            ("gate.starved_velocity_sigma_m_s", gv, true, 1.0e-6, 1.0e6),
            ("gate.starved_accel_sigma_m_s2", ga, true, 1.0e-6, 1.0e6),
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
            starved_reset_after_s: T::lit(starve),
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
    starved_reset_after_s: T,
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
    /// Time of the initial state (the first IMU sample ends the first interval after it).
    pub time: Timestamp,
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

/// Seconds from `earlier` to `later` in the loop's float type (0 if `later` is earlier).
#[inline(always)]
pub(crate) fn secs_between<T: Real>(later: Timestamp, earlier: Timestamp) -> T {
    micros_to_seconds(later.micros_since(earlier).unwrap_or(0))
}

/// "No time" in the channels' optional time fields (the end of the clock).
const NEVER: Timestamp = Timestamp::from_micros(u64::MAX);

/// A held aid sample, its recovery-gate state and its re-anchoring flag.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AidChannel<T> {
    pub(crate) last_time: Timestamp,
    pub(crate) last_value: T,
    pub(crate) received: bool,
    /// Gate variance held after a re-acquisition until the innovations have stayed inside
    /// the tracking gate for `recovery_hold_s` (0: tracking).
    pub(crate) recovery_var: T,
    /// Time since which the innovations are inside the tracking gate during a recovery
    /// ([`NEVER`]: not inside).
    pub(crate) recovery_clear_since: Timestamp,
    /// Time stamp of the first sample of the current run of gate rejections ([`NEVER`]:
    /// the last sample was accepted).
    pub(crate) rejected_since: Timestamp,
    /// The next sample is accepted outside the gate and re-anchors the measured state.
    pub(crate) reanchor: bool,
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
            last_time: Timestamp::ZERO,
            last_value: T::zero(),
            received: false,
            recovery_var: T::zero(),
            recovery_clear_since: NEVER,
            rejected_since: NEVER,
            reanchor: false,
        }
    }

    /// Validates a new sample against the channel and the current IMU time; returns the
    /// channel as it would be with the sample (self is not modified). A sample older than the
    /// aid's `lost_after_s` at arrival would be `Lost` at once: it is refused
    /// (`MeasurementTimeOutOfWindow`, as one from the future).
    pub(crate) fn with_sample(
        &self,
        time: Timestamp,
        value: T,
        now: Timestamp,
        lost_after_s: T,
        value_name: &'static str,
        range: (f64, f64),
    ) -> Result<Self, NavError> {
        if !value.is_finite() {
            return Err(NavError::NonFiniteInput { input: value_name });
        }
        if value < T::lit(range.0) || value > T::lit(range.1) {
            return Err(NavError::InputOutOfRange { input: value_name });
        }
        match now.micros_since(time) {
            Some(age) if micros_to_seconds::<T>(age) <= lost_after_s => {}
            _ => return Err(NavError::MeasurementTimeOutOfWindow),
        }
        if self.received && time <= self.last_time {
            return Err(NavError::TimeNotIncreasing);
        }
        Ok(Self {
            last_time: time,
            last_value: value,
            received: true,
            ..*self
        })
    }

    /// Freshness with `age_s` the age of the held sample now.
    #[inline(always)]
    pub(crate) fn status(&self, age_s: T, to: &Timeouts<T>) -> AidStatus<T> {
        if !self.received {
            return AidStatus::NoData;
        }
        if age_s > to.lost_after_s {
            AidStatus::Lost { age_s }
        } else if age_s > to.stale_after_s {
            AidStatus::Stale { age_s }
        } else {
            AidStatus::Fresh { age_s }
        }
    }
}

/// Checks an IMU sample's values (the interval is checked by the loop).
#[inline(always)]
pub(crate) fn check_imu_values<T: Real>(imu: &ImuSample<T>) -> Result<(), NavError> {
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
    Ok(())
}

/// Validates an initial state.
#[inline(never)]
pub(crate) fn check_initial<T: Real>(init: &InitialState<T>) -> Result<(), NavError> {
    for (name, v) in [
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
    if init.vz_up_m_s.abs() > T::lit(MAX_ESTIMATE_SPEED_M_S) {
        return Err(NavError::InputOutOfRange {
            input: "initial vz_up_m_s",
        });
    }
    if init.accel_bias_m_s2.abs() > T::lit(MAX_ESTIMATE_BIAS_M_S2) {
        return Err(NavError::InputOutOfRange {
            input: "initial accel_bias_m_s2",
        });
    }
    Ok(())
}

/// Gate parameters of one aid: `(σ₀², growth₁, growth₂, threshold, recovery hold, starvation
/// limit)` with the drift `d = gap (growth₁ + growth₂ gap)`.
type AidGate<T> = (T, T, T, T, T, T);

/// Gate of one new sample: returns the channel to use and the verdict.
/// `rate = (r₁, r₂)` extrapolates the sample to mid-interval (`half_h` before `now`),
/// `z + age (r₁ − r₂ age)`; `pred` is the predicted measurement.
/// `old_age`: the held sample's age now; returns the channel to use, its sample's age now and
/// the verdict.
#[allow(clippy::too_many_arguments)]
#[inline(always)]
fn admit<T: Real, const SECOND_ORDER: bool>(
    old: &AidChannel<T>,
    old_age: T,
    cand: Option<AidChannel<T>>,
    now: Timestamp,
    lost_after_s: T,
    offset: T,
    half_h: T,
    rate: (T, T),
    pred: T,
    gate: Option<AidGate<T>>,
) -> (AidChannel<T>, T, Option<SampleCheck<T>>) {
    let Some(mut cand) = cand else {
        return (*old, old_age, None);
    };
    let cand_age = secs_between::<T>(now, cand.last_time);
    let age = cand_age - half_h;
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
    let max_var = T::lit(MAX_GATE_VARIANCE);
    // Accepted outside the gate: a pending re-anchoring, or a starved gate.
    let starved = match gate {
        Some(g) if old.rejected_since != NEVER => {
            secs_between::<T>(cand.last_time, old.rejected_since) >= g.5
        }
        _ => false,
    };
    if old.reanchor || starved {
        let var0 = gate.map_or(T::zero(), |g| g.0);
        let v = var0 + nu2;
        cand.recovery_var = if gate.is_some() {
            if v < max_var {
                v
            } else {
                max_var
            }
        } else {
            T::zero()
        };
        cand.recovery_clear_since = NEVER;
        cand.rejected_since = NEVER;
        cand.reanchor = false;
        let check = SampleCheck {
            innovation,
            gate_variance: None,
            outcome: FusionOutcome::Fused,
            reacquired: true,
            reset: true,
        };
        return (cand, cand_age, Some(check));
    }
    let lost = old.received && old_age > lost_after_s;
    let (gate_variance, pass) = match gate {
        Some((var0, g1, g2, thr, hold, _)) if old.received => {
            let gap = old_age - cand_age;
            let d = gap * (g1 + g2 * gap);
            let mut s = var0 + d * d;
            // Saturate (also catches an overflow to +∞; s cannot be NaN: every term is finite
            // or +∞): every reported number stays finite.
            if s > max_var {
                s = max_var;
            }
            if old.recovery_var > s {
                s = old.recovery_var;
            }
            let pass = nu2 <= thr * s;
            if pass && lost {
                // Re-acquisition: hold a gate while the loop absorbs the coast error, no wider
                // than this sample's own innovation needs (a sample stamped long ago cannot
                // open the gate for the samples after it).
                let v = var0 + nu2;
                cand.recovery_var = if v < s { v } else { s };
                cand.recovery_clear_since = NEVER;
            } else if pass && old.recovery_var > T::zero() {
                if nu2 > thr * var0 {
                    cand.recovery_clear_since = NEVER;
                } else {
                    let t0 = old.recovery_clear_since;
                    if t0 == NEVER {
                        cand.recovery_clear_since = cand.last_time;
                    } else if secs_between::<T>(cand.last_time, t0) >= hold {
                        cand.recovery_var = T::zero();
                        cand.recovery_clear_since = NEVER;
                    }
                }
            }
            (Some(s), pass)
        }
        _ => (None, true),
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
    if pass {
        cand.rejected_since = NEVER;
        (cand, cand_age, Some(check))
    } else {
        let mut kept = *old;
        if old.rejected_since == NEVER {
            kept.rejected_since = cand.last_time;
        }
        (kept, old_age, Some(check))
    }
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
                        if c.gate_variance.is_none() {
                            self.forced_reanchors = self.forced_reanchors.saturating_add(1);
                        }
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
    if !(IMU_DT_RANGE_S.0..=IMU_DT_RANGE_S.1).contains(&imu_dt_s) {
        return Err(NavError::InvalidConfig {
            field: "imu_dt_s",
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
}

/// `F_m u = A₀ u − K_m C u` of the aid mode with the masks `(m_b, m_v)` (1: aid in use).
#[inline(always)]
fn f_apply<T: Real>(
    k: &Matrix3x2<T>,
    lag: T,
    bias_sign: T,
    mask: (T, T),
    u: &Vector3<T>,
) -> Vector3<T> {
    let c = Vector2::new((u.x - lag * u.y) * mask.0, u.y * mask.1);
    Vector3::new(u.y, bias_sign * u.z, T::zero()) - k * c
}

/// `M(h) r = ∫₀^h exp(F_m s) ds r` by its Taylor series to `F³` (Horner), for `|h|` up to half
/// the nominal interval (relative error ≈ (|λ| h)⁴ / 120 for the loop's fastest pole λ).
#[inline(always)]
pub(crate) fn series_m<T: Real>(
    k: &Matrix3x2<T>,
    lag: T,
    bias_sign: T,
    mask: (T, T),
    h: T,
    r: &Vector3<T>,
) -> Vector3<T> {
    let f = |u: &Vector3<T>| f_apply(k, lag, bias_sign, mask, u);
    let mut w = r + f(r) * (h * T::lit(0.25));
    w = r + f(&w) * (h * T::lit(1.0 / 3.0));
    w = r + f(&w) * (h * T::lit(0.5));
    w * h
}

/// The increment `M(h) r` of one step of length `h` (nominal `dt`), with `y₀ = M(dt) r` from
/// the stored exact modes (`y₀ = N [V̂_z, rate] + G ν`): for `h < dt/2` the series directly,
/// otherwise `M(dt) r + Φ(dt) M(h − dt) r` (`Φ(dt) w = w + N [w₂, ±w₃] − G C w`), exact up
/// to the series' truncation in `|h − dt| ≤ dt/2`.
#[allow(clippy::too_many_arguments)]
#[cold]
#[inline(never)]
pub(crate) fn off_nominal_increment<T: Real>(
    k: &Matrix3x2<T>,
    lag: T,
    bias_sign: T,
    mode: &Mode<T>,
    mask: (T, T),
    (h, dt): (T, T),
    (v, rate): (T, T),
    nu: &Vector2<T>,
) -> Vector3<T> {
    let r = Vector3::new(v, rate, T::zero()) + k * nu;
    if h < dt * T::lit(0.5) {
        return series_m(k, lag, bias_sign, mask, h, &r);
    }
    let w = series_m(k, lag, bias_sign, mask, h - dt, &r);
    let cw = Vector2::new(w.x - lag * w.y, w.y);
    mode.n * Vector2::new(v, rate) + mode.g * nu + w + mode.n * Vector2::new(w.y, bias_sign * w.z)
        - mode.g * cw
}

/// The state and machinery shared by both loops.
///
/// Time: the clock is a [`Timestamp`]; every interval is formed in integer microseconds and
/// converted to the float type as a duration. A step integrates the actual interval `Δt`
/// since the last accepted sample: `Δt ≤ 1.5 dt` in one step (the stored exact step at the
/// nominal `dt`, corrected for `Δt − dt` by [`off_nominal_increment`] when they differ),
/// longer intervals in sub-steps ([`MAX_SUBSTEPS`]), beyond those by an exact inertial coast
/// first, and gaps beyond [`MAX_BRIDGED_GAP_S`] by re-anchoring (see [`LoopStatus`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LoopCore<T: Real> {
    /// `[ĥ − h_ref (m), V̂_z (m/s), b̂ (m/s²)]`: the altitude relative to `h_ref_m`, so that
    /// in f32 the per-step increments V̂_z Δt (µm to mm) are not lost to the altitude's
    /// resolution (4 mm at 40 km).
    pub(crate) x: Vector3<T>,
    /// Reference altitude, m (moved to the estimate when |ĥ − h_ref| > [`RECENTRE_M`]).
    pub(crate) h_ref_m: T,
    pub(crate) time: Timestamp,
    pub(crate) dt_s: T,
    pub(crate) dt_us: u64,
    /// `dt_us` when it is exactly `dt_s` in the float type (the stored step then applies
    /// as is), else 0 (an interval of a whole number of µs is never exactly `dt_s`: every
    /// step takes the corrected path).
    pub(crate) nominal_us: u64,
    pub(crate) half_dt_s: T,
    pub(crate) modes: Modes<T>,
    /// Continuous observer gains (columns baro, velocity) for off-nominal intervals.
    pub(crate) k: Matrix3x2<T>,
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
    pub(crate) status: LoopStatus,
}

/// Longest bridged gap in µs.
const MAX_BRIDGED_GAP_US: u64 = 10_000_000;
const _: () = assert!(MAX_BRIDGED_GAP_US as f64 == MAX_BRIDGED_GAP_S * 1.0e6);

impl<T: Real> LoopCore<T> {
    /// The loop at `init` with a design's values (copies only: no f64 arithmetic).
    /// `step`: (IMU interval, half of it, baro lag), s; `k`: the continuous gains.
    #[allow(clippy::too_many_arguments)]
    pub(crate) fn new(
        init: &InitialState<T>,
        bias_sign: f64,
        step: (T, T, T),
        k: Matrix3x2<T>,
        modes: Modes<T>,
        gravity: &GravityModel<T>,
        baro: &AidTimeouts,
        velocity: &AidTimeouts,
    ) -> Result<Self, NavError> {
        check_initial(init)?;
        let (dt_s, half_dt_s, baro_lag_s) = step;
        let dt_us = match crate::time::seconds_to_micros(dt_s) {
            Some(us) if us > 0 => us,
            _ => {
                return Err(NavError::InvalidConfig {
                    field: "design.imu_dt_s",
                    issue: ConfigIssue::OutOfRange,
                })
            }
        };
        if !k.iter().all(|v| v.is_finite()) {
            return Err(NavError::InvalidConfig {
                field: "design",
                issue: ConfigIssue::NotFinite,
            });
        }
        Ok(Self {
            h_ref_m: init.altitude_m,
            x: Vector3::new(
                T::zero(),
                init.vz_up_m_s,
                -init.accel_bias_m_s2 * T::lit(bias_sign),
            ),
            time: init.time,
            dt_s,
            dt_us,
            nominal_us: if micros_to_seconds::<T>(dt_us) == dt_s {
                dt_us
            } else {
                0
            },
            half_dt_s,
            modes,
            k,
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
            status: LoopStatus::default(),
        })
    }

    /// One IMU step with optional new aid samples, over the actual interval since the last
    /// accepted sample. On error nothing changes. Returns the reports and the sub-steps.
    /// `variances`: innovation variances to report for (baro, velocity) when used.
    #[inline(always)]
    pub(crate) fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
    ) -> Result<(AidReport<T>, AidReport<T>, u32), NavError> {
        check_imu_values(imu)?;
        let us = match imu.time.micros_since(self.time) {
            Some(d) if d > 0 => d,
            _ => return Err(NavError::TimeNotIncreasing),
        };
        if us <= self.dt_us.saturating_add(self.dt_us / 2) {
            let (b, v) = self.advance(
                self.x,
                self.h_ref_m,
                imu.time,
                us,
                imu.specific_force_up_m_s2,
                baro,
                velocity,
                variances,
                false,
            )?;
            return Ok((b, v, 1));
        }
        self.bridge(us, imu, baro, velocity, variances)
    }

    /// An interval longer than 1.5 dt (rare path, on a copy): sub-steps, a coast first if
    /// longer than [`MAX_SUBSTEPS`] intervals, or a re-anchoring beyond
    /// [`MAX_BRIDGED_GAP_S`]. The new aid samples enter the last sub-step.
    #[cold]
    #[inline(never)]
    fn bridge(
        &mut self,
        us: u64,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
    ) -> Result<(AidReport<T>, AidReport<T>, u32), NavError> {
        let mut tmp = *self;
        let f = imu.specific_force_up_m_s2;
        let dt_us = self.dt_us.max(1);
        if us > MAX_BRIDGED_GAP_US {
            // Not integrated: keep the state, restart the clock one interval before the
            // sample, drop the held aid samples and re-anchor on the next ones.
            tmp.time = Timestamp::from_micros(imu.time.as_micros().saturating_sub(dt_us));
            tmp.baro = AidChannel {
                reanchor: true,
                ..AidChannel::new()
            };
            tmp.velocity = AidChannel {
                reanchor: true,
                ..AidChannel::new()
            };
            tmp.status.gaps_skipped = tmp.status.gaps_skipped.saturating_add(1);
            let (b, v) = tmp.advance_outlined(imu.time, dt_us, f, baro, velocity, variances)?;
            *self = tmp;
            return Ok((b, v, 1));
        }
        let max_sub = u64::from(MAX_SUBSTEPS);
        let sub_span = max_sub.saturating_mul(dt_us);
        let (n, coast_us) = if us > sub_span.saturating_add(dt_us / 2) {
            (max_sub, us.saturating_sub(sub_span))
        } else {
            (
                us.saturating_add(dt_us / 2).checked_div(dt_us).unwrap_or(2),
                0,
            )
        };
        let n = n.clamp(2, max_sub);
        if coast_us > 0 {
            tmp.coast(coast_us, f);
        }
        let start = tmp.time;
        let span = us.saturating_sub(coast_us);
        for i in 1..n {
            let end = start.add_micros(span.saturating_mul(i).checked_div(n).unwrap_or(0));
            let h = end.micros_since(tmp.time).unwrap_or(0);
            tmp.advance_outlined(end, h, f, None, None, (None, None))?;
        }
        let h = imu.time.micros_since(tmp.time).unwrap_or(0);
        let (b, v) = tmp.advance_outlined(imu.time, h, f, baro, velocity, variances)?;
        tmp.status.gaps_bridged = tmp.status.gaps_bridged.saturating_add(1);
        *self = tmp;
        // n ≤ MAX_SUBSTEPS: the conversion cannot truncate.
        Ok((b, v, n as u32))
    }

    /// One bridged sub-step (one outlined copy of [`Self::advance`] for every rare path).
    #[inline(never)]
    fn advance_outlined(
        &mut self,
        now: Timestamp,
        h_us: u64,
        specific_force: T,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
    ) -> Result<(AidReport<T>, AidReport<T>), NavError> {
        self.advance(
            self.x,
            self.h_ref_m,
            now,
            h_us,
            specific_force,
            baro,
            velocity,
            variances,
            true,
        )
    }

    /// Exact inertial coast over `us` µs on the specific force `f` (no aid; gravity at the
    /// mid-interval altitude).
    #[inline(never)]
    fn coast(&mut self, us: u64, f: T) {
        let h = micros_to_seconds::<T>(us);
        let half = T::lit(0.5);
        let (alt, v, b) = (self.x.x, self.x.y, self.x.z);
        let g = self.gravity.gravity_m_s2(self.h_ref_m + alt + v * h * half);
        let rate = f - g + self.bias_sign * b;
        let x_new = Vector3::new(alt + h * (v + half * h * rate), v + h * rate, b);
        self.settle(x_new, self.h_ref_m);
        self.time = self.time.add_micros(us);
    }

    /// Commits a new state: re-centres the relative altitude and holds the estimate inside
    /// its limits; a held estimate marks both aids for re-anchoring.
    #[inline(always)]
    fn settle(&mut self, mut x: Vector3<T>, h_ref: T) {
        let mut h_ref_new = h_ref;
        let mut limited = false;
        // `x` is finite here (checked by the caller, or bounded by construction in a coast).
        if x.x.abs() > T::lit(RECENTRE_M) {
            h_ref_new = h_ref + x.x;
            x.x = T::zero();
            let (lo, hi) = (T::lit(ESTIMATE_RANGE_M.0), T::lit(ESTIMATE_RANGE_M.1));
            if h_ref_new < lo || h_ref_new > hi {
                h_ref_new = if h_ref_new < lo { lo } else { hi };
                limited = true;
            }
        }
        let vmax = T::lit(MAX_ESTIMATE_SPEED_M_S);
        if x.y.abs() > vmax {
            x.y = if x.y < T::zero() { -vmax } else { vmax };
            limited = true;
        }
        let bmax = T::lit(MAX_ESTIMATE_BIAS_M_S2);
        if x.z.abs() > bmax {
            x.z = if x.z < T::zero() { -bmax } else { bmax };
            limited = true;
        }
        if limited {
            self.status.estimate_limited = self.status.estimate_limited.saturating_add(1);
            self.baro.reanchor = true;
            self.velocity.reanchor = true;
        }
        self.x = x;
        self.h_ref_m = h_ref_new;
    }

    /// One (sub-)step of `h_us` µs ending at `now`, from the state `x` and reference altitude
    /// `h_ref`: aid checks, gate, propagation, commit. On error nothing changes.
    #[allow(clippy::too_many_arguments)]
    #[inline(always)]
    fn advance(
        &mut self,
        mut x: Vector3<T>,
        h_ref: T,
        now: Timestamp,
        h_us: u64,
        specific_force: T,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
        variances: (Option<T>, Option<T>),
        bridged: bool,
    ) -> Result<(AidReport<T>, AidReport<T>), NavError> {
        let nominal = h_us == self.nominal_us;
        let (h_s, half_h) = if nominal {
            (self.dt_s, self.half_dt_s)
        } else {
            let h = micros_to_seconds::<T>(h_us);
            (h, h * T::lit(0.5))
        };
        let (alt, v, b) = (x.x, x.y, x.z);
        let mut az = specific_force - self.gravity.gravity_m_s2(h_ref + alt);
        // Predicted measurements at mid-interval (the baro's relative to h_ref) and the rates
        // a held sample is extrapolated with (baro: second order, h(mid) = h(t) + age (V̂ −
        // ½ a age); velocity: first order).
        let mut h_pred = alt - self.baro_lag_s * v;
        let mut v_rate = az + self.bias_sign * b;
        let half = T::lit(0.5);

        // Validate the new samples (nothing is committed before all checks pass).
        let baro_cand = match baro {
            Some(s) => Some(self.baro.with_sample(
                s.time,
                s.altitude_m,
                now,
                self.baro_timeouts.lost_after_s,
                "altitude_m",
                ALTITUDE_RANGE_M,
            )?),
            None => None,
        };
        let vel_cand = match velocity {
            Some(s) => Some(self.velocity.with_sample(
                s.time,
                s.vz_up_m_s,
                now,
                self.velocity_timeouts.lost_after_s,
                "vz_up_m_s",
                (-MAX_VERTICAL_SPEED_M_S, MAX_VERTICAL_SPEED_M_S),
            )?),
            None => None,
        };
        // χ² gate on the new samples.
        let gate = self.gate.as_ref();
        // Each held sample's age now: one integer difference and one conversion per aid.
        let age = |ch: &AidChannel<T>| {
            if ch.received {
                secs_between::<T>(now, ch.last_time)
            } else {
                T::zero()
            }
        };
        let baro_age = age(&self.baro);
        let vel_age = age(&self.velocity);
        let (baro_ch, baro_age, mut baro_check) = admit::<T, true>(
            &self.baro,
            baro_age,
            baro_cand,
            now,
            self.baro_timeouts.lost_after_s,
            h_ref,
            half_h,
            (v, half * v_rate),
            h_pred,
            gate.map(|g| {
                (
                    g.baro_var,
                    g.growth_v,
                    g.growth_half_a,
                    g.nis_threshold,
                    g.recovery_hold_s,
                    g.starved_reset_after_s,
                )
            }),
        );
        let (vel_ch, vel_age, mut vel_check) = admit::<T, false>(
            &self.velocity,
            vel_age,
            vel_cand,
            now,
            self.velocity_timeouts.lost_after_s,
            T::zero(),
            half_h,
            (v_rate, T::zero()),
            v,
            gate.map(|g| {
                (
                    g.velocity_var,
                    g.growth_a,
                    T::zero(),
                    g.nis_threshold,
                    g.recovery_hold_s,
                    g.starved_reset_after_s,
                )
            }),
        );
        // Recovery: a re-acquiring sample whose innovation fails the tracking gate (or one
        // accepted outside the gate to re-anchor the loop) resets the measured state so that
        // its innovation is zero (baro: ĥ; velocity: V̂_z); the other states are kept.
        let mut reset_any = false;
        if let Some(c) = baro_check.as_mut().filter(|c| c.reacquired) {
            let big =
                gate.is_some_and(|g| c.innovation * c.innovation > g.nis_threshold * g.baro_var);
            if c.reset || big {
                x.x += c.innovation;
                c.reset = true;
                reset_any = true;
            }
        }
        if let Some(c) = vel_check.as_mut().filter(|c| c.reacquired) {
            let big = gate
                .is_some_and(|g| c.innovation * c.innovation > g.nis_threshold * g.velocity_var);
            if c.reset || big {
                x.y += c.innovation;
                c.reset = true;
                reset_any = true;
            }
        }
        if reset_any {
            az = specific_force - self.gravity.gravity_m_s2(h_ref + x.x);
            h_pred = x.x - self.baro_lag_s * x.y;
            v_rate = az + self.bias_sign * x.z;
        }
        let v = x.y;

        let baro_status = baro_ch.status(baro_age, &self.baro_timeouts);
        let vel_status = vel_ch.status(vel_age, &self.velocity_timeouts);
        let use_baro = baro_status.in_use();
        let use_vel = vel_status.in_use();

        // Held samples extrapolated to the middle of the interval (ZOH of the continuous loop).
        let nu_h = use_baro.then(|| {
            let age = baro_age - half_h;
            (baro_ch.last_value - h_ref) + age * (v - half * v_rate * age) - h_pred
        });
        let nu_v = use_vel.then(|| vel_ch.last_value + (vel_age - half_h) * v_rate - v);
        let mode = self.modes.select(use_baro, use_vel);
        let nu = Vector2::new(nu_h.unwrap_or(T::zero()), nu_v.unwrap_or(T::zero()));
        let dx = if nominal {
            mode.n * Vector2::new(v, v_rate) + mode.g * nu
        } else {
            let mask = (
                if use_baro { T::one() } else { T::zero() },
                if use_vel { T::one() } else { T::zero() },
            );
            off_nominal_increment(
                &self.k,
                self.baro_lag_s,
                self.bias_sign,
                mode,
                mask,
                (h_s, self.dt_s),
                (v, v_rate),
                &nu,
            )
        };
        let x_new = x + dx;
        // One test for all three: a sum of finite values is finite unless it overflows, which
        // is refused as well (unreachable with valid input: every term is bounded).
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return Err(NavError::NonFiniteInput {
                input: "state after step",
            });
        }
        self.baro = baro_ch;
        self.velocity = vel_ch;
        self.settle(x_new, h_ref);
        self.time = now;
        self.baro_counters.count(&baro_check);
        self.velocity_counters.count(&vel_check);
        self.status.health = if self.baro.reanchor {
            HealthState::NeedsReinitialisation
        } else if bridged
            || !use_baro
            || (self.velocity.received && !use_vel)
            || self.baro.rejected_since != NEVER
            || self.velocity.rejected_since != NEVER
            || self.baro.recovery_var > T::zero()
            || self.velocity.recovery_var > T::zero()
        {
            HealthState::Degraded
        } else {
            HealthState::Nominal
        };
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

    /// Restarts the state and clock from `init`, keeping the design, the gate and the
    /// counters (held aid samples are dropped; health `Initialising`). On error nothing
    /// changes.
    pub(crate) fn reinitialise(&mut self, init: &InitialState<T>) -> Result<(), NavError> {
        check_initial(init)?;
        self.h_ref_m = init.altitude_m;
        self.x = Vector3::new(
            T::zero(),
            init.vz_up_m_s,
            -init.accel_bias_m_s2 * self.bias_sign,
        );
        self.time = init.time;
        self.baro = AidChannel::new();
        self.velocity = AidChannel::new();
        self.status.health = HealthState::Initialising;
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

//! Baro-inertial vertical channel (spec `vertical-channel.md`): the classical 3rd-order
//! damping loop ([`ClassicalLoop`]) and the velocity-aided loop with Riccati-designed gains
//! ([`AidedLoop`]), both on the estimator contract ([`crate::contract`]).
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
//! the interval with `V̂_z · age`), `x̂_{k+1} = Φ_m x̂_k + Γ_m u_k`, evaluated in innovation
//! form, `u = [A_z, z_h, z_v]`, where `[Φ_m Γ_m]` comes from the exponential of the augmented
//! matrix `[[F_m, G_m], [0, 0]]` (computed once at configuration in `f64`) for each of the
//! four aid modes `m` (which aids are in use). A nominal step costs two 3×2 matrix-vector
//! products and the gravity polynomial.
//!
//! **Contract.** [`ClassicalConfig`] / [`AidedConfig`] (generic over the float type; the
//! design math runs in `f64` on the values widened) → [`ClassicalDesign`] / [`AidedDesign`]
//! ([`crate::Estimator::design`], on the ground; stored with [`crate::design::DesignValues`],
//! stamped with the configuration's fingerprint) → [`crate::Estimator::from_design`] on board
//! (no design code, no f64 arithmetic). Each new aid sample answers with a
//! [`crate::FusionReport`] ([`AidReport::sample`]) whose innovation variance comes from the
//! aid model ([`AidModel`]: the loops have no running covariance); the χ² gate is a
//! [`crate::Gate`], the starvation recovery a [`crate::RecoveryPolicy`] with
//! [`crate::RecoveryAction::Reanchor`] (the only action a fixed-gain loop can take; the
//! others are refused, `recovery.action`). Counters: [`crate::Health`]
//! (`gaps_bridged`: intervals longer than 1.5 dt integrated in sub-steps; `gaps_reset`: gaps
//! longer than [`MAX_BRIDGED_GAP_S`]; `limits_hit`: steps whose estimate was held at
//! [`ESTIMATE_RANGE_M`], [`MAX_ESTIMATE_SPEED_M_S`] or [`MAX_ESTIMATE_BIAS_M_S2`];
//! `reinitialisations`: calls of `reinitialise`; `imu_refused`: refused IMU samples and
//! steps) and, per [`Aid`], [`crate::AidCounters`] (`recoveries`: re-anchorings of the aid's
//! measured state, [`Reacquisition::Reanchored`]; `refused`: refused samples) plus
//! [`ReacquisitionCounters`].
//!
//! ```
//! use nav_core::design::DesignValues;
//! use nav_core::time::Timestamp;
//! use nav_core::vertical_channel::{
//!     Aid, AidedConfig, AidedDesign, AidedLoop, BaroSample, ImuSample, InitialState,
//!     VelocitySample,
//! };
//! use nav_core::{Estimator, FusionOutcome, Gate, HealthState};
//!
//! // On the ground (or at build time): design and store.
//! let config = AidedConfig::<f32>::paper();
//! let mut stored = [0.0_f64; AidedDesign::<f32>::COUNT];
//! AidedLoop::design(&config)?.write_values(&mut stored)?;
//!
//! // On board: load the stored design and run, no design code.
//! let design = AidedDesign::<f32>::read_values(&stored)?;
//! let init = InitialState {
//!     time: Timestamp::ZERO,
//!     altitude_m: 500.0_f32,
//!     vz_up_m_s: 0.0,
//!     accel_bias_m_s2: 0.0,
//! };
//! let mut lp = AidedLoop::from_design(&config, &design, &init)?;
//! lp.set_gate(Gate::Nis(10.83))?;
//! let g = design.gravity().gravity_m_s2(500.0); // at rest: f_up = g
//! for k in 1..=1000_u64 {
//!     let time = Timestamp::from_micros(k * 10_000); // 100 Hz IMU
//!     let imu = ImuSample { time, specific_force_up_m_s2: g };
//!     let baro = (k % 4 == 0).then_some(BaroSample { time, altitude_m: 500.0 });
//!     let vel = (k % 10 == 0).then_some(VelocitySample { time, vz_up_m_s: 0.0 });
//!     let report = lp.step(&imu, baro.as_ref(), vel.as_ref())?;
//!     if let Some(s) = report.baro.sample {
//!         assert_eq!(s.outcome, FusionOutcome::Fused);
//!         assert!(s.test_ratio < 1.0);
//!     }
//! }
//! assert_eq!(lp.health().state, HealthState::Nominal);
//! assert!((lp.altitude_m() - 500.0).abs() < 0.1);
//! assert_eq!(lp.aid_counters(Aid::Baro).fused, 250);
//!
//! // The way back (e.g. from `NeedsReinitialisation`, with an external altitude).
//! lp.reinitialise(&InitialState { time: Timestamp::from_micros(10_000_000), ..init })?;
//! assert_eq!(lp.health().state, HealthState::Initialising);
//! assert_eq!(lp.health().reinitialisations, 1);
//! # Ok::<(), nav_core::NavError>(())
//! ```
//!
//! Time: every sample carries a [`crate::Timestamp`] (integer microseconds); intervals are
//! formed in integers and converted to the float type as durations, so a loop that has run
//! for 10⁹ s computes its intervals exactly as in its first second. A step integrates the
//! **actual** interval `Δt` since the last accepted IMU sample (jitter, late and missing
//! samples, gaps):
//!
//! - `Δt = dt`: the stored exact step;
//! - `dt/2 ≤ Δt ≤ 1.5 dt`: `M(Δt) r = M(dt) r + Φ(dt) M(Δt − dt) r` with `M(h) r` (the integral of
//!   the closed loop over `h`) by its Taylor series to `F³` — exact up to a truncation of
//!   ≈ (|λ| |Δt − dt|)⁴/120 (relative error 5·10⁻¹⁴ at dt/τ = 0.001, 8·10⁻⁷ at 0.05, checked at
//!   configuration against [`INTERVAL_ACCURACY`]); `Δt < dt/2`: the series alone;
//! - `1.5 dt < Δt ≤ (MAX_SUBSTEPS + ½) dt`: `round(Δt/dt)` equal sub-steps;
//! - up to [`MAX_BRIDGED_GAP_S`]: an exact inertial coast over `Δt − MAX_SUBSTEPS·dt`, then
//!   [`MAX_SUBSTEPS`] nominal sub-steps (bounded work per call);
//! - longer: not integrated; the loop re-anchors on the next aid samples.
//!
//! Only what is physically impossible is refused: an IMU stamp not after the loop's clock
//! (`TimeNotIncreasing`), an aid stamp after the IMU stamp or older than the aid's
//! `lost_after_s` (`MeasurementTimeOutOfWindow`) or not after the aid's previous one
//! (`TimeNotIncreasing`), non-finite or out-of-range values. A refused call changes nothing
//! but the refused-input counter of the input it names, and never freezes the clock: the next
//! valid sample is integrated over its whole interval.
//!
//! Multi-rate: the IMU drives `step` at its rate; aid samples are passed when they arrive,
//! time-stamped, and may be missing. Each aid has an [`AidStatus`]: `Fresh` and `Stale`
//! samples are used, a `Lost` (or never received) aid is dropped and the loop runs on the IMU
//! alone (pure inertial in that channel), which the per-step [`AidReport`] says.
//!
//! Envelope (configuration): besides each field's range, the joint conditions are checked at
//! design time — the multirate loop (aid samples held and extrapolated between arrivals) must
//! be stable with perfect sensors (Jury test of the error monodromy over one aid period:
//! classical `tau_s` vs `imu_dt_s` and `baro_period_s`, aided design vs both periods), and the
//! variable-interval step must meet [`INTERVAL_ACCURACY`] (`imu_dt_s` vs the loop's
//! bandwidth). The estimate is held inside [`ESTIMATE_RANGE_M`], [`MAX_ESTIMATE_SPEED_M_S`]
//! and [`MAX_ESTIMATE_BIAS_M_S2`] (never a refused step). No report carries a non-finite
//! number.
//!
//! Health after the last step: `Initialising` before the first accepted step (after
//! construction or `reinitialise`); `NeedsReinitialisation` while a re-anchoring of the baro
//! is pending (a gap longer than [`MAX_BRIDGED_GAP_S`], or an estimate held at a limit): the
//! next baro sample re-anchors ĥ and ends it (or `reinitialise`); `Degraded` when the last
//! step bridged an IMU gap, the baro is not in use, a velocity aid that has delivered is lost,
//! an aid's last sample was rejected, or a recovery gate is held; `Nominal` otherwise.
//!
//! σ: the loops have no running covariance; `sigma()` / `covariance_h_vz()` give the error
//! covariance of (ĥ, V̂_z) their design implies under the configuration's [`ErrorModel`]
//! (computed at design time: per aid mode the closed loop's error dynamics with the baro's
//! correlated error, the design mode's steady state from the discrete Lyapunov equation;
//! on board propagated every [`COVARIANCE_INTERVAL_S`] from the initial σ until it has settled,
//! without the aids that were out, and moved by re-anchorings; see `steady_sigma()`).
//!
//! Numerics: the step is evaluated in innovation form, exact and well conditioned in f32. A
//! held (`Stale`) sample is extrapolated at constant acceleration: choose `lost_after_s` so
//! that ½ · jerk · age² stays below the aid's noise.

mod age_limits;
mod aided;
mod bridge;
mod classical;
mod common;
mod config;
mod core;
mod design;
mod envelope;
mod gains;
mod gate;
mod gravity;
mod modes;
mod nominal;
mod riccati;
mod samples;
mod sigma;

use crate::Bounds;
pub use aided::{AidedLoop, AidedReport};
pub use classical::{ClassicalLoop, ClassicalReport};
pub use config::{
    AidModel, AidedConfig, ClassicalConfig, AID_SIGMA_RANGE, NIS_THRESHOLD_RANGE,
    PAPER_LATITUDE_RAD,
};
pub use design::{
    aided_stamp, classical_stamp, AidPair, AidedDesign, ClassicalDesign, AIDED_DESIGN_VERSION,
    CLASSICAL_DESIGN_VERSION,
};
pub use gains::{AidedGains, ClassicalGains};
pub use gate::{AidReport, Reacquisition, ReacquisitionCounters};
pub use gravity::GravityModel;
pub use riccati::{solve_filter_care, CareSolution, MAX_SIGN_ITERATIONS};
pub use samples::{
    Aid, AidStatus, AidTimeouts, BaroSample, ImuSample, InitialState, VelocitySample,
};
pub use sigma::{
    ErrorModel, VerticalSigma, COVARIANCE_INTERVAL_S, MAX_COVARIANCE_INTERVALS_PER_STEP,
    SETTLED_TOLERANCE,
};

/// Largest accepted |specific force|, m/s² (20 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 196.0;
/// Accepted altitude range of the estimate and the baro, m.
pub const ALTITUDE_RANGE_M: Bounds = Bounds {
    low: -2_000.0,
    high: 60_000.0,
};
/// Range the altitude **estimate** is kept in, m (wider than [`ALTITUDE_RANGE_M`] so a loop
/// coasting through a long outage keeps running and can re-acquire). An estimate that leaves
/// it is held at the limit (the step is not refused): the loop has diverged, its health is
/// `NeedsReinitialisation` and the next aid samples are accepted outside the gate and re-anchor
/// the measured states (see [`AidModel`]).
pub const ESTIMATE_RANGE_M: Bounds = Bounds {
    low: -50_000.0,
    high: 500_000.0,
};
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
pub const IMU_DT_RANGE_S: Bounds = Bounds {
    low: 1.0e-4,
    high: 1.0,
};
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

/// Largest gate variance, unit² (the aid model's variance saturates here so that every
/// reported number stays finite in f32; a gate this wide admits any valid sample).
pub const MAX_GATE_VARIANCE: f64 = 1.0e30;

#[cfg(test)]
mod tests;

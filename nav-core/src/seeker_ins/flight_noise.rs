//! The flight configuration's account of the instrument errors the 17 states do not model:
//! accelerometer scale factor and misalignment (and the same for the gyros).
//!
//! A real accelerometer triad senses `(I + S + M) f + b + w`, with `S` the scale-factor errors
//! (diagonal), `M` the misalignments (off-diagonal), `b` the bias and `w` white noise. The error
//! that enters the INS error equations through `C_b^n ∇` is therefore the **equivalent bias**
//! `∇_eq = b + (S + M) f_b`: at the specific force of level flight (`f_b ≈ [0, 0, −g]`) a
//! 200 ppm scale factor is a 196 µg error on z (twice a 100 µg bias) and a 10″ misalignment a
//! 48 µg error on x and y, both constant as long as `f_b` is. The paper's filter gives its
//! accelerometer-bias states the σ of `b` alone, so it is overconfident about them, and
//! through them about velocity, position and attitude.
//!
//! The flight configuration keeps the 17 states and makes the accelerometer-bias states the
//! equivalent bias at a **reference specific force** `f_ref` (`∇ = b + (S + M) f_ref`): with
//! `σ_S`, `σ_M` the configured scale-factor and misalignment σ ([`InstrumentErrors`]), the
//! variance of `(S + M) u` on axis `i` for a motion `u` is
//!
//! ```text
//! v_i(u) = σ_S² u_i² + σ_M² (|u|² − u_i²)
//! ```
//!
//! (independent elements of S and M). `v(f_ref)` is added to the accelerometer-bias variances
//! once (the P0 the user gives is that of `b` alone). The reference is the specific force
//! the vehicle flies with: the carry's (the flight navigator sets it at the hand-over,
//! [`super::SeekerIns::set_specific_force_reference`]: the slave's specific force of the last
//! master epoch, the one its alignment saw), or else unaccelerated level flight at the
//! attitude of the first covariance step, `C_n^b (−g)` (a vehicle started in a transient — a
//! drop at ≈ 0 g — would otherwise refer its bias to that transient).
//!
//! Away from the reference the instruments add `(S + M)(f − f_ref)`, a *known function of the
//! specific force* with constant unknown coefficients. How it acts depends on how long the
//! departure lasts. A transient (a drop, a pull-up, a boost: a few seconds) vanishes when the
//! specific force returns to `f_ref`; what it leaves is the velocity error `C_b^n (S + M) D`,
//! `D = Σ (f − f_ref) Δt`. A sustained departure (a weave's mean load factor above 1 g, held
//! for minutes) is a change of the equivalent bias, which the LOS updates estimate as such. The
//! filter splits the departure with its running mean `f̄` (first-order lag, time constant
//! `τ` = [`SUSTAINED_TIME_CONSTANT_S`], long against the transients so that at most a tenth of
//! a 3 s one reaches it, short against an engagement of minutes): the sustained part `f̄` is
//! charged to the accelerometer-bias states per body axis, the rest, `D = Σ (f − f_ref − f̄) Δt`,
//! to the velocity states, each correlated with the reference's share (below); what that
//! correlation does not carry is charged as independent, the part of its largest value so far
//! not added before (for the velocity per NED axis, the largest diagonal of
//! `C_b^n diag(·) C_n^b`, as the gyro errors below). A transient is charged once, at the size of
//! the velocity error it makes, however slowly it builds up; a step held for long reaches the
//! bias in a few `τ` and leaves the velocity at most `v(Δf τ)`. The position follows through the
//! propagation.
//!
//! **The departure's correlation with the reference.** The same S and M make the reference's
//! share of the bias states' error, `(S + M) f_ref`, and the departure's errors, so they are
//! correlated: per axis `i`
//!
//! ```text
//! c_i(a, u) = cov(((S + M) a)_i, ((S + M) u)_i) = σ_S² a_i u_i + σ_M² (a·u − a_i u_i)
//! ```
//!
//! (`c(u, u) = v(u)`; different axes share no element). In a 2 g turn from level flight the
//! lift axis's `c_z(f_ref, f̄) = σ_S² g × 1.24 g` is as large as `v_z(f̄)`: charged as
//! independent, the bias states would get `v(f̄)` where the total equivalent bias's variance
//! grows by `v(f_ref + f̄) − v(f_ref) = v(f̄) + 2 c(f_ref, f̄)`, and the departure's errors would
//! have no covariance with what the hand-over correlated with the bias (the alignment's tilt).
//! The filter carries the correlation by regression on the reference's equivalent bias
//! `∇_ref = b + (S + M) f_ref`, of variance `P_ref` per axis (the bias states' variance when the
//! reference is set, `v(f_ref)` included): at the reference the instruments add nothing else,
//! so what the filter knows of S and M before a departure came through `∇_ref`, and the
//! departure's error splits as `(S + M) u = k ∇_ref + r`, `k_i = c_i(f_ref, u) / P_ref,i`, with
//! `r` independent and `var r_i = v_i(u) − k_i c_i ≥ 0` (Cauchy–Schwarz, `P_ref ≥ v(f_ref)`).
//! The `k ∇` part is applied as the linear map it is, `P ← T P Tᵀ` on the bias states' error:
//!
//! - sustained: the bias error becomes `(1 + k) ∇`, `k = max(0, c(f_ref, f̄) / P_ref)` as the
//!   mean stands (each step scales the bias row and column by `(1 + k) / (1 + k_before)`: the
//!   share grows with the mean and returns with it), and the rest `v(f̄) − k c` is charged as
//!   independent (its largest value so far over `(1 + k)²`, added times `(1 + k)²`: the later
//!   scales scale it). With the bias unobserved (`P_bias = P_ref`) its variance becomes
//!   `(1 + k)² P_ref + v(f̄) − k c = P_ref + v(f_ref + f̄) − v(f_ref)`, the total equivalent
//!   bias's, and its covariances (the tilt's) grow with it. A force opposing the reference (a push-over, `c < 0`) takes `k = 0`
//!   and `v(f̄)` as independent: more than the truth's (whose variance falls), never negative;
//! - transient: each step's `ΔD = (f − f_ref − f̄) Δt` adds `C_b^n diag(c(f_ref, ΔD) / (P_ref
//!   (1 + k))) ∇` to the velocity error (`∇` the bias error as it stands), and the part of `v(D)`
//!   this does not carry, `v(D) − (c(f_ref, D) / (P_ref (1 + k)))² P_bias` with `P_bias` taken at
//!   most `P_ref (1 + k)²`, is charged as independent. A drop to 0 g is anti-correlated with the
//!   share (`c(f_ref, −f_ref Δt) = −v(f_ref) Δt`: while it lasts the instruments lack the share
//!   the bias states hold). Where the LOS updates have narrowed the bias, the transfer carries
//!   little and the independent rest is nearly all of `v(D)` (the share is then in the
//!   estimate, which the filter does not use to predict the departure's error).
//!
//! `E = T − I` is non-zero only in the bias columns of the three velocity and three bias rows:
//! `T P Tᵀ` costs 11 × 12 multiply-adds outside the six rows and ≈ 80 in their block, keeps P
//! symmetric (each mirrored pair written from one value) and PSD (a congruence, as `Φ P Φᵀ`); the rest is a non-negative diagonal. The regression is
//! the reference's alone: what the LOS learns of S during a departure is not followed (a bias
//! the updates narrowed in a long turn is scaled back when the mean returns as if they had
//! not: optimistic by up to the turn's share), nor the correlation of one departure's
//! independent rest with a later one's (the largest-so-far bounds cover it); a Schmidt
//! consider state for S would follow both. Measured on the flight navigator's campaign
//! variant 4 (258 m/s, a 135° turn at 2 g, 100 runs): midcourse east position e²/σ² 1.14 with
//! the independent charge, 0.95 with the correlated one (docs/consistency.md, "The correlated charge").
//!
//! (Charging the whole departure to the velocity treated a weave's load factor as transient:
//! the velocity charge then grew with the square of the time while the LOS updates learned
//! the bias change the bias states had no variance for. Measured on the S-turn, 100 runs:
//! accelerometer-bias e²/σ² 1.16 against 0.93 with the split.)
//!
//! (The model this replaces charged `v(f − f_ref)` to the bias states, with `f_ref` the first
//! step's specific force: a 1 s drop or a 2 g pull-up at release then counted as a permanent
//! change of the bias, and the horizontal bias σ through the whole flight became 1.5 × the
//! truth's — velocity and position e²/σ² 0.6-0.9 in midcourse.)
//!
//! The gyro errors `(S + M) ω` are different: body rates average out over a manoeuvre, so
//! their effect is the bounded attitude error `(S + M) θ`, `θ = Σ Δθ` the body rotation since
//! the first covariance step, not a bias (the gyro-bias states stay the constant bias `b`).
//! The flight configuration charges its variance (gyro σ) to the attitude states the same
//! way: per NED axis, the part of the largest diagonal of `C_b^n diag(v(θ)) C_n^b` so far not
//! added before. Small as it is
//! (10″ × 0.7 rad ≈ 3e-5 rad in an S-turn), it is of the size of the attitude-and-gimbal
//! combination the LOS determines best, so the filter is overconfident without it.
//!
//! Limits of the model: the charges are bounds built for manoeuvres of a few radians and
//! minutes (the seeker's engagement). The bias charge, as a largest-so-far bound, adds nothing
//! when the mean swings back within what was charged, although the LOS updates may have
//! narrowed the bias σ meanwhile. `θ` is the body-axis sum of the increments, so a vehicle that
//! circles for hours is charged the misalignment part of many turns in full, although in NED
//! it partly cancels: the attitude σ then grows more than the truth. Schmidt consider states
//! for S and M would follow it exactly, at about 4 × the covariance work.
//!
//! Cost: two 3-vector rotations, five `v(·)` or `c(·)`, the running mean, the transfer
//! `T P Tᵀ` (≈ 210 multiply-adds, after the covariance kernel in a frame of its own beside
//! the kernel's: the kernel is the non-flight one) and a few compares per covariance step
//! (10 Hz): on the Cortex-M4F the flight configuration's covariance step is 6 191 instructions
//! against the kernel's 4 347 (README); nothing when all σ are zero (the paper's filter, bit
//! for bit).

#[path = "accel_departure.rs"]
mod accel_departure;

use super::error_model::{ACC_BIAS, ATT, STATES, VEL};
use super::mechanization::Ins;
use super::sparse_f::SparseF;
use crate::{NavError, Real};
use accel_departure::accel_departure;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Time constant of the running mean that splits a departure of the specific force from the
/// reference into a sustained part (charged to the accelerometer-bias states) and a transient
/// rest (charged to the velocity), s. Long against the transients (a drop, a pull-up: ≤ 3 s,
/// of which ≤ 10 % reaches the mean), short against an engagement (240 s).
pub const SUSTAINED_TIME_CONSTANT_S: f64 = 30.0;

/// Largest accepted scale-factor σ, dimensionless (1 %).
pub const MAX_SCALE_FACTOR: f64 = 0.01;
/// Largest accepted misalignment σ, rad (≈ 0.57°).
pub const MAX_MISALIGNMENT_RAD: f64 = 0.01;

/// 1σ of the instrument errors the 17 states do not model (module [`super`] docs of the flight
/// configuration). All zero (the [`Default`]) leaves the paper's filter unchanged.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InstrumentErrors<T> {
    /// Accelerometer scale-factor error, 1σ per axis, dimensionless (200 ppm = 2e-4):
    /// [0, [`MAX_SCALE_FACTOR`]].
    pub accel_scale_factor: T,
    /// Accelerometer misalignment, 1σ per off-diagonal element of M, rad (10″ = 4.85e-5):
    /// [0, [`MAX_MISALIGNMENT_RAD`]].
    pub accel_misalignment_rad: T,
    /// Gyro scale-factor error, 1σ per axis, dimensionless: [0, [`MAX_SCALE_FACTOR`]].
    pub gyro_scale_factor: T,
    /// Gyro misalignment, 1σ per off-diagonal element, rad: [0, [`MAX_MISALIGNMENT_RAD`]].
    pub gyro_misalignment_rad: T,
}

impl<T: Real> InstrumentErrors<T> {
    /// `true` when every σ is zero (nothing to add).
    pub fn is_zero(&self) -> bool {
        let z = T::zero();
        self.accel_scale_factor == z
            && self.accel_misalignment_rad == z
            && self.gyro_scale_factor == z
            && self.gyro_misalignment_rad == z
    }
}

/// What the accelerometer part remembers between covariance steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct EquivalentBiasCharge<T> {
    /// Reference specific force `f_ref` of the bias states, body, m/s² (`None` before it is
    /// set or the first covariance step).
    pub(crate) reference_f_b_m_s2: Option<Vector3<T>>,
    /// Body velocity increment in excess of the reference since it was set, `Σ (f − f_ref)
    /// Δt`, m/s.
    pub(crate) excess_dv_b_m_s: Vector3<T>,
    /// Velocity variance of the excess already added per NED axis, (m/s)².
    pub(crate) charged_vel_m2_s2: Vector3<T>,
    /// Sustained part of the departure `f − f_ref`: its running mean over
    /// [`SUSTAINED_TIME_CONSTANT_S`], body, m/s².
    pub(crate) sustained_f_b_m_s2: Vector3<T>,
    /// Accelerometer-bias variance of the sustained part's independent rest already added per
    /// body axis, divided by `(1 + k)²` at its addition (`k` the sustained gain), (m/s²)².
    pub(crate) charged_bias_m2_s4: Vector3<T>,
    /// The bias states' variances when the reference was set (`P_ref`, `v(f_ref)` included),
    /// (m/s²)²: the variance of the reference's equivalent bias the departures regress on.
    pub(crate) reference_var_m2_s4: Vector3<T>,
    /// Regression gain of the sustained part on the reference's bias error at the last step,
    /// `k = max(0, c(f_ref, f̄) / P_ref)` per body axis, dimensionless (module doc).
    pub(crate) sustained_gain: Vector3<T>,
    /// Body rotation integrated since the first covariance step, rad (`Σ Δθ`).
    pub(crate) rotation_b_rad: Vector3<T>,
    /// Attitude variance of the gyro errors already added per NED axis, rad².
    pub(crate) charged_att_rad2: Vector3<T>,
}

impl<T: Real> Default for EquivalentBiasCharge<T> {
    fn default() -> Self {
        Self {
            reference_f_b_m_s2: None,
            excess_dv_b_m_s: Vector3::zeros(),
            charged_vel_m2_s2: Vector3::zeros(),
            sustained_f_b_m_s2: Vector3::zeros(),
            charged_bias_m2_s4: Vector3::zeros(),
            reference_var_m2_s4: Vector3::zeros(),
            sustained_gain: Vector3::zeros(),
            rotation_b_rad: Vector3::zeros(),
            charged_att_rad2: Vector3::zeros(),
        }
    }
}

/// `v_i(u) = σ_S² u_i² + σ_M² (|u|² − u_i²)` per axis (module doc).
fn equivalent_variance<T: Real>(u: &Vector3<T>, sf: T, mis: T) -> Vector3<T> {
    equivalent_covariance(u, u, sf, mis)
}

/// `c_i(a, u) = cov(((S + M) a)_i, ((S + M) u)_i) = σ_S² a_i u_i + σ_M² (a·u − a_i u_i)` per
/// axis (module doc); `c(u, u) = v(u)`.
fn equivalent_covariance<T: Real>(a: &Vector3<T>, u: &Vector3<T>, sf: T, mis: T) -> Vector3<T> {
    let prod = a.component_mul(u);
    let total = prod.x + prod.y + prod.z;
    let (s2, m2) = (sf * sf, mis * mis);
    prod.map(|x| s2 * x + m2 * (total - x))
}

/// Validates the σ ([`InstrumentErrors`] ranges), `InvalidConfig` naming the field.
pub(crate) fn validate<T: Real>(e: &InstrumentErrors<T>) -> Result<(), NavError> {
    use crate::error::in_range;
    let (sf, mis) = (T::lit(MAX_SCALE_FACTOR), T::lit(MAX_MISALIGNMENT_RAD));
    let z = T::zero();
    in_range(
        "instrument_errors.accel_scale_factor",
        e.accel_scale_factor,
        z,
        sf,
    )?;
    in_range(
        "instrument_errors.accel_misalignment_rad",
        e.accel_misalignment_rad,
        z,
        mis,
    )?;
    in_range(
        "instrument_errors.gyro_scale_factor",
        e.gyro_scale_factor,
        z,
        sf,
    )?;
    in_range(
        "instrument_errors.gyro_misalignment_rad",
        e.gyro_misalignment_rad,
        z,
        mis,
    )
}

/// Sets the reference specific force `f_ref` (body, m/s²) of a filter whose charge has none
/// yet, adding `v(f_ref)` to the accelerometer-bias variances (module doc). Returns the new
/// charge (`None`: a reference is already set, or `f_ref` is not finite; nothing to change).
/// P and the charge are the caller's to commit.
pub(crate) fn set_reference<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    f_ref_b_m_s2: &Vector3<T>,
) -> Option<EquivalentBiasCharge<T>> {
    if charge.reference_f_b_m_s2.is_some() || !f_ref_b_m_s2.sum().is_finite() {
        return None;
    }
    let add = equivalent_variance(
        f_ref_b_m_s2,
        errors.accel_scale_factor,
        errors.accel_misalignment_rad,
    );
    let mut reference_var = Vector3::zeros();
    for i in 0..3 {
        if let Some(v) = p.get_mut((ACC_BIAS + i, ACC_BIAS + i)) {
            *v += add.get(i).copied().unwrap_or(T::zero());
            if let Some(r) = reference_var.get_mut(i) {
                *r = *v;
            }
        }
    }
    Some(EquivalentBiasCharge {
        reference_f_b_m_s2: Some(*f_ref_b_m_s2),
        reference_var_m2_s4: reference_var,
        ..*charge
    })
}

/// The part of the largest per-NED-axis variance `C diag(v(u)) Cᵀ` (its diagonal) not yet
/// charged: `(added, new charged)`.
fn charge_ned<T: Real>(
    c_b_n: &Matrix3<T>,
    u_b: &Vector3<T>,
    sf: T,
    mis: T,
    charged: &Vector3<T>,
) -> (Vector3<T>, Vector3<T>) {
    let w = c_b_n.component_mul(c_b_n) * equivalent_variance(u_b, sf, mis);
    charge_above(&w, charged)
}

/// The part of the variances `w` above the largest charged so far, per axis, and the new
/// largest: `(added, new charged)`.
fn charge_above<T: Real>(w: &Vector3<T>, charged: &Vector3<T>) -> (Vector3<T>, Vector3<T>) {
    let add = (w - charged).map(|x| x.max(T::zero()));
    (add, charged.sup(w))
}

/// The hook of the covariance step: after `P ← Φ P Φᵀ + Q_d` over an interval `dt_s` with
/// mean body specific force `f_b_m_s2` and body rotation `dtheta_b_rad`, attitude `c_b_n` at
/// its end, charges the accelerometer errors (the reference's variance to the bias states at
/// the first step without a reference, the excess's to the velocity states) and the gyro
/// errors' to the attitude states (module doc). Returns the new charge; P and the charge are
/// the caller's to commit. Non-finite inputs add nothing.
pub(crate) fn add_instrument_noise<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    c_b_n: &Matrix3<T>,
    f_b_m_s2: &Vector3<T>,
    dtheta_b_rad: &Vector3<T>,
    dt_s: T,
) -> EquivalentBiasCharge<T> {
    let finite = (f_b_m_s2.sum() + dtheta_b_rad.sum() + dt_s).is_finite();
    if errors.is_zero() || !finite {
        return *charge;
    }
    let mut next = *charge;
    let mut add_vel = Vector3::zeros();
    let mut add_bias = Vector3::zeros();
    match charge.reference_f_b_m_s2 {
        None => {
            if let Some(first) = set_reference(p, charge, errors, f_b_m_s2) {
                next = first;
            }
        }
        Some(_) if super::consider::enabled() => {}
        Some(f0) => {
            let (vel, bias) =
                accel_departure(p, charge, &mut next, errors, c_b_n, &f0, f_b_m_s2, dt_s);
            add_vel = vel;
            add_bias = bias;
        }
    }
    // The gyro errors' attitude error `C_b^n (S + M) Σ Δθ`, charged the same way.
    next.rotation_b_rad = charge.rotation_b_rad + dtheta_b_rad;
    let (add_att, charged_att) = charge_ned(
        c_b_n,
        &next.rotation_b_rad,
        errors.gyro_scale_factor,
        errors.gyro_misalignment_rad,
        &charge.charged_att_rad2,
    );
    next.charged_att_rad2 = charged_att;
    for i in 0..3 {
        if let Some(v) = p.get_mut((VEL + i, VEL + i)) {
            *v += add_vel.get(i).copied().unwrap_or(T::zero());
        }
        if let Some(v) = p.get_mut((ATT + i, ATT + i)) {
            *v += add_att.get(i).copied().unwrap_or(T::zero());
        }
        if let Some(v) = p.get_mut((ACC_BIAS + i, ACC_BIAS + i)) {
            *v += add_bias.get(i).copied().unwrap_or(T::zero());
        }
    }
    next
}

/// The hook the covariance steps call after `P ← Φ P Φᵀ + Q_d` over `dt_total_s`, with `ins`
/// the INS at the end of the interval and `f` the step's F at that INS (its C_b^n and its
/// mean NED specific force `dv / Δt`, m/s², of the interval's samples: neither formed
/// again): the mean body specific force is `C_n^b dv / Δt` (attitude at the end of the
/// interval), the body rotation the last IMU increment scaled to the interval. Without a
/// reference yet, level flight's `C_n^b (−g)` becomes it (module doc). Nothing (not
/// even a multiplication) when every σ is zero.
#[inline(never)]
pub(super) fn flight_noise_step<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &mut EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    ins: &Ins<T>,
    f: &SparseF<T>,
    dt_total_s: T,
) {
    if errors.is_zero() || dt_total_s <= T::zero() {
        return;
    }
    let c_b_n = &f.c_b_n;
    if charge.reference_f_b_m_s2.is_none() {
        // No reference set: unaccelerated level flight at this attitude, `C_n^b (−g)`.
        let s = ins.state();
        let g = crate::earth::gravity_ned(T::lit(s.position.lat_rad), T::lit(s.position.alt_m));
        if let Some(first) = set_reference(p, charge, errors, &(c_b_n.transpose() * (-g))) {
            *charge = first;
        }
    }
    let f_b = c_b_n.transpose() * f.f_ned;
    let last_s = ins.last_interval_s();
    let dtheta = match ins.last_increment() {
        Some(inc) if last_s > T::zero() => inc.delta_theta_rad * (dt_total_s / last_s),
        _ => Vector3::zeros(),
    };
    *charge = add_instrument_noise(p, charge, errors, c_b_n, &f_b, &dtheta, dt_total_s);
}

#[cfg(test)]
#[path = "flight_noise_tests.rs"]
mod tests;

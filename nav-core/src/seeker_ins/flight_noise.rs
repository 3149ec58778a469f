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
//! specific force* with constant unknown coefficients: the same S and M make the reference's
//! share in the bias states, the error of one turn and that of the next. The filter carries
//! S and M as **Schmidt consider parameters** (module `consider`): the 17 × 9
//! cross-covariance of the states with the nine elements of S and M, started at the reference
//! with the reference's share (`E[∇ cᵀ] = J(f_ref) P_cc`), propagated with the error
//! `C_b^n (S + M)(f − f_ref) Δt` each covariance step adds to the velocity, and corrected by
//! every update; S and M themselves are never estimated (their σ stays the configured one).
//! No charge of the accelerometers' departure is added to P's diagonal: the consider terms are
//! the exact covariance of the 26-state model, of which the filter keeps the blocks it uses.
//!
//! (The diagonal charges this replaces split the departure into a sustained part, charged to
//! the bias states, and a transient rest, charged to the velocity, each regressed on the
//! reference's share, with largest-so-far bounds for the rest; they could not carry the
//! correlation between one turn's error and the next, and the S-turn's NEES rose over the
//! flight: last fifth over middle fifth 1.067 on the campaign's 16 S-turn variants, 0.981 with
//! the consider parameters. docs/seeker-ins.md has the record.)
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
//! Limits of the gyro charge: it is a bound built for manoeuvres of a few radians and
//! minutes (the seeker's engagement). `θ` is the body-axis sum of the increments, so a vehicle that
//! circles for hours is charged the misalignment part of many turns in full, although in NED
//! it partly cancels: the attitude σ then grows more than the truth. Schmidt consider states
//! for S and M would follow it exactly, at about 4 × the covariance work.
//!
//! Cost: one 3-vector rotation, one `v(·)` and a few compares per covariance step (10 Hz) for
//! the gyros; the consider parameters' cost is module `consider`'s. Nothing when all σ are
//! zero (the paper's filter, bit for bit).

use super::error_model::{ACC_BIAS, ATT, STATES};
use super::mechanization::Ins;
use super::sparse_f::SparseF;
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, Vector3};

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
    /// Body rotation integrated since the first covariance step, rad (`Σ Δθ`).
    pub(crate) rotation_b_rad: Vector3<T>,
    /// Attitude variance of the gyro errors already added per NED axis, rad².
    pub(crate) charged_att_rad2: Vector3<T>,
}

impl<T: Real> Default for EquivalentBiasCharge<T> {
    fn default() -> Self {
        Self {
            reference_f_b_m_s2: None,
            rotation_b_rad: Vector3::zeros(),
            charged_att_rad2: Vector3::zeros(),
        }
    }
}

/// `v_i(u) = σ_S² u_i² + σ_M² (|u|² − u_i²)` per axis (module doc).
fn equivalent_variance<T: Real>(u: &Vector3<T>, sf: T, mis: T) -> Vector3<T> {
    let prod = u.component_mul(u);
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
    for i in 0..3 {
        if let Some(v) = p.get_mut((ACC_BIAS + i, ACC_BIAS + i)) {
            *v += add.get(i).copied().unwrap_or(T::zero());
        }
    }
    Some(EquivalentBiasCharge {
        reference_f_b_m_s2: Some(*f_ref_b_m_s2),
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
/// its end, sets the reference at the first step without one (its variance to the bias
/// states; the departures from it are the consider parameters') and charges the gyro errors'
/// to the attitude states (module doc). Returns the new charge; P and the charge are
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
    if let Some(first) = set_reference(p, charge, errors, f_b_m_s2) {
        next = first;
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
        if let Some(v) = p.get_mut((ATT + i, ATT + i)) {
            *v += add_att.get(i).copied().unwrap_or(T::zero());
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

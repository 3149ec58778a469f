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
//! equivalent bias (`∇ = ∇_eq`): with `σ_S`, `σ_M` the configured scale-factor and
//! misalignment σ ([`InstrumentErrors`]), the variance of `(S + M) u` on axis `i` for a
//! motion `u` is
//!
//! ```text
//! v_i(u) = σ_S² u_i² + σ_M² (|u|² − u_i²)
//! ```
//!
//! (independent elements of S and M). At the first covariance step the filter adds `v(f_b)`
//! to the accelerometer-bias variances (the P0 the user gives is that of `b` alone) and keeps
//! that first specific force as its reference `f_0`. Later steps add the part of
//! `v(f_b − f_0)` (the variance of the change of the equivalent bias since then) not added
//! before: `q_i = max(0, v_i(f_b − f_0) − c_i)`, `c_i ← max(c_i, v_i(f_b − f_0))`. A change of
//! the specific force is charged once, at its full size, however slowly it builds up (a white
//! random walk driven by the increments would charge only the sum of their squares, far too
//! little for a ramp); returning towards `f_0` charges nothing. Adding a non-negative diagonal
//! keeps P symmetric PSD.
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
//! Limits of the model: the charge is a bound built for manoeuvres of a few radians and minutes
//! (the seeker's engagement). `θ` is the body-axis sum of the increments, so a vehicle that
//! circles for hours is charged the misalignment part of many turns in full, although in NED
//! it partly cancels: the attitude σ then grows more than the truth. Schmidt consider states
//! for S and M would follow it exactly, at about 4 × the covariance work.
//!
//! Cost: one 3-vector rotation, two `v(·)` and a few compares per covariance step (10 Hz);
//! nothing when all σ are zero (the paper's filter, bit for bit).

use super::error_model::{ACC_BIAS, ATT, STATES};
use super::mechanization::Ins;
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
    /// Mean body specific force of the first covariance step, m/s² (`None` before it).
    pub(crate) reference_f_b_m_s2: Option<Vector3<T>>,
    /// Variance of the change of the equivalent bias already added per axis, (m/s²)².
    pub(crate) charged_m2_s4: Vector3<T>,
    /// Body rotation integrated since the first covariance step, rad (`Σ Δθ`).
    pub(crate) rotation_b_rad: Vector3<T>,
    /// Attitude variance of the gyro errors already added per NED axis, rad².
    pub(crate) charged_att_rad2: Vector3<T>,
}

impl<T: Real> Default for EquivalentBiasCharge<T> {
    fn default() -> Self {
        Self {
            reference_f_b_m_s2: None,
            charged_m2_s4: Vector3::zeros(),
            rotation_b_rad: Vector3::zeros(),
            charged_att_rad2: Vector3::zeros(),
        }
    }
}

/// `v_i(u) = σ_S² u_i² + σ_M² (|u|² − u_i²)` per axis (module doc).
fn equivalent_variance<T: Real>(u: &Vector3<T>, sf: T, mis: T) -> Vector3<T> {
    let sq = u.component_mul(u);
    let total = sq.x + sq.y + sq.z;
    let (s2, m2) = (sf * sf, mis * mis);
    sq.map(|x| s2 * x + m2 * (total - x))
}

/// Validates the σ ([`InstrumentErrors`] ranges), `InvalidConfig` naming the field.
pub(crate) fn validate<T: Real>(e: &InstrumentErrors<T>) -> Result<(), NavError> {
    use super::config::in_range;
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

/// The hook of the covariance step: after `P ← Φ P Φᵀ + Q_d` over an interval with mean body
/// specific force `f_b_m_s2` and body rotation `dtheta_b_rad`, attitude `c_b_n` at its end, adds the equivalent-bias
/// variance to the accelerometer-bias states and the gyro-error variance to the attitude
/// states (module doc). Returns the new charge; P and the charge are the caller's to commit.
/// Non-finite inputs add nothing.
pub(crate) fn add_instrument_noise<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    c_b_n: &Matrix3<T>,
    f_b_m_s2: &Vector3<T>,
    dtheta_b_rad: &Vector3<T>,
) -> EquivalentBiasCharge<T> {
    let finite = (f_b_m_s2.sum() + dtheta_b_rad.sum()).is_finite();
    if errors.is_zero() || !finite {
        return *charge;
    }
    let (sa, ma) = (errors.accel_scale_factor, errors.accel_misalignment_rad);
    let mut next = *charge;
    let add_acc = match charge.reference_f_b_m_s2 {
        None => {
            next.reference_f_b_m_s2 = Some(*f_b_m_s2);
            equivalent_variance(f_b_m_s2, sa, ma)
        }
        Some(f0) => {
            let w = equivalent_variance(&(f_b_m_s2 - f0), sa, ma);
            next.charged_m2_s4 = charge.charged_m2_s4.sup(&w);
            (w - charge.charged_m2_s4).map(|x| x.max(T::zero()))
        }
    };
    // The gyro errors' attitude error `C_b^n (S + M) Σ Δθ`, charged like the accelerometer's
    // (largest variance so far, per NED axis: the diagonal of C diag(v) Cᵀ).
    next.rotation_b_rad = charge.rotation_b_rad + dtheta_b_rad;
    let v_b = equivalent_variance(
        &next.rotation_b_rad,
        errors.gyro_scale_factor,
        errors.gyro_misalignment_rad,
    );
    let w_att = c_b_n.component_mul(c_b_n) * v_b;
    let add_att = (w_att - charge.charged_att_rad2).map(|x| x.max(T::zero()));
    next.charged_att_rad2 = charge.charged_att_rad2.sup(&w_att);
    for i in 0..3 {
        if let Some(v) = p.get_mut((ACC_BIAS + i, ACC_BIAS + i)) {
            *v += add_acc.get(i).copied().unwrap_or(T::zero());
        }
        if let Some(v) = p.get_mut((ATT + i, ATT + i)) {
            *v += add_att.get(i).copied().unwrap_or(T::zero());
        }
    }
    next
}

/// The hook the covariance steps call after `P ← Φ P Φᵀ + Q_d` over `dt_total_s`, with
/// `dv_ned_m_s` the NED velocity increment of the interval's samples and `ins` the INS at its
/// end: the mean body specific force is `C_n^b dv / Δt` (attitude at the end of the
/// interval), the body rotation the last IMU increment scaled to the interval. Nothing (not
/// even a multiplication) when every σ is zero.
#[inline(never)]
pub(super) fn flight_noise_step<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    charge: &mut EquivalentBiasCharge<T>,
    errors: &InstrumentErrors<T>,
    ins: &Ins<T>,
    dv_ned_m_s: &Vector3<T>,
    dt_total_s: T,
) {
    if errors.is_zero() || dt_total_s <= T::zero() {
        return;
    }
    let c_b_n = ins.c_b_n();
    let f_b = c_b_n.transpose() * (dv_ned_m_s / dt_total_s);
    let last_s = ins.last_interval_s();
    let dtheta = match ins.last_increment() {
        Some(inc) if last_s > T::zero() => inc.delta_theta_rad * (dt_total_s / last_s),
        _ => Vector3::zeros(),
    };
    *charge = add_instrument_noise(p, charge, errors, &c_b_n, &f_b, &dtheta);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn errors() -> InstrumentErrors<f64> {
        InstrumentErrors {
            accel_scale_factor: 200e-6,
            accel_misalignment_rad: 10.0 / 206_264.8,
            gyro_scale_factor: 20e-6,
            gyro_misalignment_rad: 10.0 / 206_264.8,
        }
    }

    /// `v(u)` against the variance of `Σ_j m_ij u_j` written out element by element (σ_S on
    /// the diagonal, σ_M off it).
    #[test]
    fn equivalent_variance_is_the_variance_of_the_error_sum() {
        let e = errors();
        let u = Vector3::new(2.0, -1.0, -9.8);
        let v = equivalent_variance(&u, e.accel_scale_factor, e.accel_misalignment_rad);
        for i in 0..3 {
            let mut want = 0.0;
            for j in 0..3 {
                let s = if i == j {
                    e.accel_scale_factor
                } else {
                    e.accel_misalignment_rad
                };
                want += s * s * u[j] * u[j];
            }
            assert!(
                (v[i] - want).abs() <= 1e-15 * want,
                "axis {i}: {} vs {want}",
                v[i]
            );
        }
        // Level flight: 200 ppm × g ≈ 196 µg on z, 10″ × g ≈ 48 µg on x and y.
        let lv = equivalent_variance(
            &Vector3::new(0.0, 0.0, -9.806_65),
            e.accel_scale_factor,
            e.accel_misalignment_rad,
        );
        let ug = 9.806_65e-6;
        assert!((lv.z.sqrt() / ug - 200.0).abs() < 0.1);
        assert!((lv.x.sqrt() / ug - 48.5).abs() < 0.1);
    }

    /// The first step adds the whole `v(f)`; a slow ramp is charged at its full size once; a
    /// return towards the reference charges nothing; zero σ adds nothing.
    #[test]
    fn charge_covers_ramps_once_and_zero_sigma_is_the_paper_filter() {
        let e = errors();
        let mut p = SMatrix::<f64, STATES, STATES>::identity() * 1e-8;
        let p_start = p;
        let f_level = Vector3::new(0.0, 0.0, -9.8);
        let dth = Vector3::zeros();
        let i3 = Matrix3::identity();
        let c = add_instrument_noise(&mut p, &Default::default(), &e, &i3, &f_level, &dth);
        let v0 = equivalent_variance(&f_level, e.accel_scale_factor, e.accel_misalignment_rad);
        assert!((p[(ACC_BIAS + 2, ACC_BIAS + 2)] - 1e-8 - v0.z).abs() < 1e-20);
        // A ramp of the x specific force to 2 m/s² in 100 steps.
        let mut ch = c;
        for k in 1..=100 {
            let f = f_level + Vector3::new(0.02 * f64::from(k), 0.0, 0.0);
            ch = add_instrument_noise(&mut p, &ch, &e, &i3, &f, &dth);
        }
        let want = equivalent_variance(
            &Vector3::new(2.0, 0.0, 0.0),
            e.accel_scale_factor,
            e.accel_misalignment_rad,
        );
        let added_x = p[(ACC_BIAS, ACC_BIAS)] - 1e-8 - v0.x;
        assert!(
            (added_x - want.x).abs() < 1e-6 * want.x,
            "{added_x} {}",
            want.x
        );
        // Back to level: nothing more.
        let before = p;
        let _ = add_instrument_noise(&mut p, &ch, &e, &i3, &f_level, &dth);
        assert_eq!(p, before);
        // Zero σ: P untouched, charge unchanged.
        let mut q = p_start;
        let none = InstrumentErrors::<f64>::default();
        let c0 = add_instrument_noise(&mut q, &Default::default(), &none, &i3, &f_level, &dth);
        assert_eq!(q, p_start);
        assert_eq!(c0, EquivalentBiasCharge::default());
    }

    /// Each σ outside [0, its maximum] or non-finite is refused naming its field, by the
    /// filter's construction too; the flight configuration itself is accepted.
    #[test]
    fn instrument_errors_are_validated_by_field() {
        use crate::contract::Estimator;
        use crate::error::ConfigIssue;
        use crate::seeker_ins::{Landmark, Position, SeekerIns, SeekerInsConfig};
        let lm = Landmark::new(Position {
            lat_rad: 0.6461,
            lon_rad: 2.2266,
            alt_m: 0.0,
        })
        .unwrap();
        let flight = SeekerInsConfig::<f32>::flight(lm);
        assert!(SeekerIns::design(&flight).is_ok());
        assert!(!flight.instrument_errors.is_zero());
        assert!(SeekerInsConfig::<f32>::paper(lm)
            .instrument_errors
            .is_zero());
        type Set = fn(&mut InstrumentErrors<f32>, f32);
        let fields: [(&str, Set); 4] = [
            ("instrument_errors.accel_scale_factor", |e, v| {
                e.accel_scale_factor = v
            }),
            ("instrument_errors.accel_misalignment_rad", |e, v| {
                e.accel_misalignment_rad = v
            }),
            ("instrument_errors.gyro_scale_factor", |e, v| {
                e.gyro_scale_factor = v
            }),
            ("instrument_errors.gyro_misalignment_rad", |e, v| {
                e.gyro_misalignment_rad = v
            }),
        ];
        for (name, set) in fields {
            for (v, issue) in [
                (-1e-6, ConfigIssue::OutOfRange),
                (0.011, ConfigIssue::OutOfRange),
                (f32::NAN, ConfigIssue::NotFinite),
            ] {
                let mut cfg = flight;
                set(&mut cfg.instrument_errors, v);
                assert_eq!(
                    SeekerIns::design(&cfg).err(),
                    Some(NavError::InvalidConfig { field: name, issue }),
                    "{name} = {v}"
                );
            }
        }
    }
}

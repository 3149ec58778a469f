//! Strapdown INS mechanization in the local-level NED frame with geodetic position on WGS-84
//! (spec "Navigation"; Titterton & Weston ch. 3 and 11, Savage 1998).
//!
//! Continuous equations (navigation frame n = NED at the vehicle, body frame b):
//!
//! ```text
//! L̇ = V_N / (R_M + h),   l̇ = V_E / ((R_N + h) cos L),   ḣ = −V_D
//! V̇ⁿ = C_b^n fᵇ − (2 ω_ie^n + ω_en^n) × Vⁿ + gⁿ(L, h)
//! Ċ_b^n = C_b^n [ω_ib^b ×] − [ω_in^n ×] C_b^n,   ω_in^n = ω_ie^n + ω_en^n
//! ```
//!
//! Discrete algorithm, one IMU interval `Δt` (the time stamp of the sample minus that of the
//! previous one; see [`Ins::step`]) with increments `Δθ = ∫ω_ib^b dt`, `Δv = ∫fᵇ dt`
//! (previous increments `Δθ₋`, `Δv₋`):
//!
//! ```text
//! α     = Δθ + (1/12) Δθ₋ × Δθ                                   (two-sample coning)
//! Δv_b  = Δv + ½ Δθ × Δv + (1/12)(Δθ₋ × Δv + Δv₋ × Δθ)           (rotation + sculling)
//! ζ     = (ω_ie^n + ω_en^n) Δt
//! Vⁿ₊   = Vⁿ + (I − ½[ζ×]) C_b^n Δv_b + (gⁿ − (2ω_ie^n + ω_en^n) × Vⁿ) Δt
//! h₊    = h − ½(V_D + V_D₊) Δt,   L₊, l₊ trapezoidal with the mid-interval radii
//! q_b^n₊ = q(−ζ) ⊗ q_b^n ⊗ q(α)                                   (q(φ) ↔ exp([φ×]))
//! ```
//!
//! Velocity and quaternion are accumulated with Kahan compensated sums (the increment is
//! formed as a small quantity first): without it, in f32, slowly varying increments round the
//! same way for thousands of steps (≈ 0.1 m/s and 2e-4 rad after 240 s of the paper's
//! trajectories; see the cross-crate perfect-IMU test). The quaternion is renormalised when its
//! norm drifts by more than 16 ε, and C_b^n is always formed from q/|q|.
//!
//! Latitude, longitude and altitude are `f64` in every build (flight software practice: an
//! `f32` latitude resolves only ≈ 0.4 m near 37° and accumulates rounding over hours); only
//! the per-step increments are computed in `T`, then added in `f64`.

use crate::earth::{normal_gravity_from_sin_m_s2, normal_gravity_m_s2};
use crate::math::rotation::{quat_from_rotation_vector, quat_mul, quat_normalize};
use crate::time::{micros_to_seconds, seconds_to_micros, Timestamp};
use crate::{NavError, Real};
use nalgebra::{Matrix3, Quaternion, Vector3, Vector4};

mod kinematics;
mod numerics;
pub(crate) use kinematics::{Kinematics, PositionKinematics};
use numerics::{attitude_step, kahan_add, unit_dcm};

/// Geodetic position on WGS-84, always `f64`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Position {
    /// Geodetic latitude L, rad.
    pub lat_rad: f64,
    /// Longitude l, rad.
    pub lon_rad: f64,
    /// Height above the ellipsoid h, m (up positive).
    pub alt_m: f64,
}

/// Largest |latitude| of the model range, rad (86°: the NED mechanization is singular at the
/// poles).
pub const MAX_LAT_RAD: f64 = 1.5;
/// Largest |altitude| of the model range, m (the normal gravity series and the radii hold well
/// below 1000 km).
pub const MAX_ALT_M: f64 = 1.0e6;

impl Position {
    /// `true` when finite and inside the model range (|L| < [`MAX_LAT_RAD`], |h| <
    /// [`MAX_ALT_M`]). Outside it the INS keeps integrating with gravity, radii and rates
    /// evaluated at the nearest point of the range (finite, but not a navigation solution).
    pub fn is_in_range(&self) -> bool {
        self.lat_rad.is_finite()
            && self.lon_rad.is_finite()
            && self.alt_m.is_finite()
            && self.lat_rad.abs() < MAX_LAT_RAD
            && self.alt_m.abs() < MAX_ALT_M
    }

    fn is_finite(&self) -> bool {
        self.lat_rad.is_finite() && self.lon_rad.is_finite() && self.alt_m.is_finite()
    }
}

/// Latitude (rad) and altitude (m) in `T`, clamped into the model range: the point at which
/// gravity, radii and rates are evaluated (the position itself when it is in range).
pub(crate) fn model_lat_alt<T: Real>(pos: &Position) -> (T, T) {
    let lat_max = T::lit(MAX_LAT_RAD);
    let alt_max = T::lit(MAX_ALT_M);
    (
        T::lit(pos.lat_rad).max(-lat_max).min(lat_max),
        T::lit(pos.alt_m).max(-alt_max).min(alt_max),
    )
}

/// One IMU sample: angle and velocity increments over one IMU interval, body axes, with the
/// time stamp of the end of that interval (the interval starts at the previous sample's time).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuIncrement<T> {
    /// End of the interval the increments cover (integer µs of the flight computer's clock).
    pub time: Timestamp,
    /// Δθ = ∫ ω_ib^b dt, rad.
    pub delta_theta_rad: Vector3<T>,
    /// Δv = ∫ fᵇ dt, m/s.
    pub delta_v_m_s: Vector3<T>,
}

impl<T: Real> ImuIncrement<T> {
    /// Zero increments over the interval ending at `time`.
    pub fn zero(time: Timestamp) -> Self {
        Self {
            time,
            delta_theta_rad: Vector3::zeros(),
            delta_v_m_s: Vector3::zeros(),
        }
    }
}

/// Navigation state of the INS.
#[derive(Debug, Clone, Copy)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct InsState<T> {
    /// Geodetic position (f64).
    pub position: Position,
    /// Velocity over the earth in NED, m/s.
    pub vel_ned_m_s: Vector3<T>,
    /// Attitude quaternion q_b^n (Hamilton, scalar first; `C_b^n = quat_to_dcm(q)`).
    pub q_b_n: Quaternion<T>,
}

impl<T: Real> PartialEq for InsState<T> {
    fn eq(&self, other: &Self) -> bool {
        self.position == other.position
            && self.vel_ned_m_s == other.vel_ned_m_s
            && self.q_b_n.coords == other.q_b_n.coords
    }
}

/// Largest accepted angle increment per IMU sample, rad (≈ 57°: far beyond any airframe at
/// 100 Hz; a larger value is a corrupted sample).
pub const MAX_DELTA_THETA_RAD: f64 = 1.0;
/// Largest accepted velocity increment per IMU sample, m/s (1000 g over 10 ms ≈ 98 m/s).
pub const MAX_DELTA_V_M_S: f64 = 100.0;
/// Longest interval between two IMU samples [`Ins::step`] integrates in one step, s (the
/// largest nominal interval [`Ins::new`] accepts): beyond it gravity, transport and earth
/// rate held over the step are no model of the motion (`InvalidTimeStep`).
pub const MAX_INTERVAL_S: f64 = 1.0;
/// [`MAX_INTERVAL_S`] in µs.
const MAX_INTERVAL_US: u64 = 1_000_000;

/// Strapdown INS (mechanization only; the filter corrects it through [`Ins::correct`]).
#[derive(Debug, Clone, Copy)]
pub struct Ins<T> {
    state: InsState<T>,
    /// Nominal IMU interval, s, and the same rounded to whole µs.
    dt_s: T,
    dt_us: u64,
    /// Interval integrated by the last step (the nominal one before the first), s.
    last_interval_s: T,
    prev: ImuIncrement<T>,
    has_prev: bool,
    /// Specific force in NED averaged over the last step, m/s².
    f_ned_m_s2: Vector3<T>,
    /// Compensation terms of the Kahan sums of velocity and quaternion (module doc).
    vel_lo: Vector3<T>,
    q_lo: Vector4<T>,
}

impl<T: Real> PartialEq for Ins<T> {
    fn eq(&self, o: &Self) -> bool {
        self.state == o.state
            && self.dt_s == o.dt_s
            && self.dt_us == o.dt_us
            && self.last_interval_s == o.last_interval_s
            && self.prev == o.prev
            && self.has_prev == o.has_prev
            && self.f_ned_m_s2 == o.f_ned_m_s2
            && self.vel_lo == o.vel_lo
            && self.q_lo == o.q_lo
    }
}

impl<T: Real> Ins<T> {
    /// INS at `initial` with nominal IMU interval `imu_dt_s` (s): the interval the first
    /// sample is integrated over (it has no predecessor to measure it from).
    ///
    /// Errors: `InvalidTimeStep` unless `imu_dt_s` is finite and in (1 µs, [`MAX_INTERVAL_S`]];
    /// `NonFiniteInput` or `InputOutOfRange` for a bad initial state (|L| < 86°, |h| <
    /// 1000 km, unit quaternion).
    pub fn new(initial: InsState<T>, imu_dt_s: T) -> Result<Self, NavError> {
        if !imu_dt_s.is_finite() || imu_dt_s <= T::zero() || imu_dt_s > T::lit(MAX_INTERVAL_S) {
            return Err(NavError::InvalidTimeStep);
        }
        let dt_us = seconds_to_micros(imu_dt_s)
            .filter(|us| *us > 0)
            .ok_or(NavError::InvalidTimeStep)?;
        let state = validate_state(&initial)?;
        Ok(Self {
            state,
            dt_s: imu_dt_s,
            dt_us,
            last_interval_s: imu_dt_s,
            prev: ImuIncrement::zero(Timestamp::ZERO),
            has_prev: false,
            f_ned_m_s2: Vector3::zeros(),
            vel_lo: Vector3::zeros(),
            q_lo: Vector4::zeros(),
        })
    }

    /// Current navigation state.
    pub fn state(&self) -> &InsState<T> {
        &self.state
    }

    /// Nominal IMU interval, s.
    pub fn dt_s(&self) -> T {
        self.dt_s
    }

    /// Nominal IMU interval rounded to whole µs.
    pub fn dt_us(&self) -> u64 {
        self.dt_us
    }

    /// The interval the last [`Ins::step`] integrated over, s (the nominal interval before
    /// the first sample).
    pub fn last_interval_s(&self) -> T {
        self.last_interval_s
    }

    /// Time stamp of the last integrated sample (`None` before the first).
    pub fn time(&self) -> Option<Timestamp> {
        self.has_prev.then_some(self.prev.time)
    }

    /// The interval from the last sample to `time`, s, as [`Ins::step`] would integrate it:
    /// the nominal `imu_dt_s` for the first sample and for an interval equal to it to the µs
    /// (so that a regular-rate stream integrates exactly the configured interval), else the
    /// measured one. Errors: `TimeNotIncreasing` (not strictly later), `InvalidTimeStep`
    /// (longer than [`MAX_INTERVAL_S`]).
    pub fn interval_to(&self, time: Timestamp) -> Result<T, NavError> {
        if !self.has_prev {
            return Ok(self.dt_s);
        }
        let us = time
            .micros_since(self.prev.time)
            .filter(|us| *us > 0)
            .ok_or(NavError::TimeNotIncreasing)?;
        if us > MAX_INTERVAL_US {
            Err(NavError::InvalidTimeStep)
        } else if us == self.dt_us {
            Ok(self.dt_s)
        } else {
            Ok(micros_to_seconds(us))
        }
    }

    /// C_b^n of the current attitude (of the normalised quaternion).
    pub fn c_b_n(&self) -> Matrix3<T> {
        unit_dcm(&self.state.q_b_n)
    }

    /// Specific force resolved in NED, averaged over the last IMU interval, m/s².
    pub fn specific_force_ned_m_s2(&self) -> Vector3<T> {
        self.f_ned_m_s2
    }

    /// The last increment integrated by [`Ins::step`] (`None` before the first sample); the
    /// zero-order hold of the filter's IMU-gap bridging.
    pub fn last_increment(&self) -> Option<ImuIncrement<T>> {
        self.has_prev.then_some(self.prev)
    }

    /// Advances the INS to `inc.time`: gravity, Coriolis, transport and earth rate are
    /// integrated over the interval from the previous sample ([`Ins::interval_to`]; the
    /// nominal interval for the first sample after [`Ins::new`]).
    ///
    /// Errors (state unchanged, the clock too: a later sample is accepted):
    /// `TimeNotIncreasing`, `InvalidTimeStep` (interval beyond [`MAX_INTERVAL_S`]),
    /// `NonFiniteInput`, `InputOutOfRange` (|Δθ| > [`MAX_DELTA_THETA_RAD`], |Δv| >
    /// [`MAX_DELTA_V_M_S`]).
    #[inline]
    pub fn step(&mut self, inc: &ImuIncrement<T>) -> Result<(), NavError> {
        self.step_keeping_radii(inc).map(|_| ())
    }

    /// [`Ins::step`], returning the radii it evaluated at the start of the interval (at the
    /// position before the step): the covariance step's F at the state reached uses them
    /// (`SeekerIns`'s `radii`) instead of evaluating them again — one IMU interval's travel,
    /// |V| Δt, from the position reached (≤ 10 m at 1 000 m/s and 100 Hz: the radii move
    /// by ≤ 1.6e-6 of themselves, the latitude by ≤ 1.6e-6 rad), a fifth or less of what
    /// evaluating F in the middle of a 10-sample covariance interval instead of at its end
    /// would move it. Not inlined: one copy serves the filter and the carry phase's INS.
    #[inline(never)]
    pub(crate) fn step_keeping_radii(
        &mut self,
        inc: &ImuIncrement<T>,
    ) -> Result<PositionKinematics<T>, NavError> {
        let dt = self.interval_to(inc.time)?;
        validate_increment(inc)?;
        let dth = inc.delta_theta_rad;
        let dv = inc.delta_v_m_s;
        let half = T::lit(0.5);
        let s = &self.state;
        let v = s.vel_ned_m_s;
        let radii = PositionKinematics::new(&s.position);
        let k = Kinematics::at(&radii, &v);
        let (alpha, dv_b) = self.coning_sculling(&dth, &dv);
        let w_in = k.w_ie + k.w_en;
        let zeta = w_in * dt;
        let c = unit_dcm(&s.q_b_n);
        let dv_n0 = c * dv_b;
        let dv_n = dv_n0 - zeta.cross(&dv_n0) * half;
        let g = normal_gravity_from_sin_m_s2(k.sin_lat, k.alt_m);
        let coriolis = (k.w_ie * T::lit(2.0) + k.w_en).cross(&v);
        let mut dv_total = dv_n - coriolis * dt;
        dv_total.z += g * dt;
        let (v_new, vel_lo) = kahan_add(&v, &self.vel_lo, &dv_total);
        // Position, trapezoidal in velocity, radii at the mid-interval altitude.
        let v_avg = (v + v_new) * half;
        let dh = -v_avg.z * dt;
        let h_mid = dh * half;
        let d_lat = v_avg.x * dt / (k.rm_h + h_mid);
        let d_lon = v_avg.y * dt / ((k.rn_h + h_mid) * k.cos_lat);
        let position = Position {
            lat_rad: s.position.lat_rad + d_lat.to_f64(),
            lon_rad: s.position.lon_rad + d_lon.to_f64(),
            alt_m: s.position.alt_m + dh.to_f64(),
        };
        let (q_hi, q_lo) = attitude_step(&s.q_b_n, &self.q_lo, &alpha, &zeta)?;
        let new_state = InsState {
            position,
            vel_ned_m_s: v_new,
            q_b_n: Quaternion::from(q_hi),
        };
        // Outside the model range the step still runs (gravity, radii and rates at the
        // nearest point of the range); only a non-finite result is refused.
        if !position.is_finite() || !v_new.iter().all(|x| x.is_finite()) {
            return Err(NavError::NonFiniteInput {
                input: "navigation state after step",
            });
        }
        self.vel_lo = vel_lo;
        self.q_lo = q_lo;
        let inv_dt = T::one() / dt;
        self.f_ned_m_s2 = dv_n * inv_dt;
        self.state = new_state;
        self.last_interval_s = dt;
        self.prev = *inc;
        self.has_prev = true;
        Ok(radii)
    }

    /// Coning (α, rad) and sculling/rotation (Δv_b, m/s) of the increments `dth` (rad) and
    /// `dv` (m/s) with the previous increment (none before the first sample).
    #[inline(always)]
    fn coning_sculling(&self, dth: &Vector3<T>, dv: &Vector3<T>) -> (Vector3<T>, Vector3<T>) {
        let half = T::lit(0.5);
        let twelfth = T::lit(1.0 / 12.0);
        let (dth, dv) = (*dth, *dv);
        if self.has_prev {
            let p = &self.prev;
            (
                dth + p.delta_theta_rad.cross(&dth) * twelfth,
                dv + dth.cross(&dv) * half
                    + (p.delta_theta_rad.cross(&dv) + p.delta_v_m_s.cross(&dth)) * twelfth,
            )
        } else {
            (dth, dv + dth.cross(&dv) * half)
        }
    }

    /// Applies the filter's error estimate (closed loop): subtracts the position and velocity
    /// errors and removes the misalignment, `C_b^n ← (I − [φ×])⁻¹ Ĉ_b^n ≈ exp([φ×]) Ĉ_b^n`.
    ///
    /// `d_lat_rad`, `d_lon_rad` in rad, `d_alt_m` in m, `d_vel_m_s` in m/s, `phi_rad` in rad
    /// (all estimate minus truth). Errors (state unchanged): `NonFiniteInput`. A corrected
    /// position outside the model range is accepted (as [`Ins::step`] accepts it).
    pub fn correct(
        &mut self,
        d_lat_rad: f64,
        d_lon_rad: f64,
        d_alt_m: f64,
        d_vel_m_s: &Vector3<T>,
        phi_rad: &Vector3<T>,
    ) -> Result<(), NavError> {
        let s = self.state;
        let corrected = InsState {
            position: Position {
                lat_rad: s.position.lat_rad - d_lat_rad,
                lon_rad: s.position.lon_rad - d_lon_rad,
                alt_m: s.position.alt_m - d_alt_m,
            },
            vel_ned_m_s: s.vel_ned_m_s - d_vel_m_s,
            q_b_n: quat_mul(&quat_from_rotation_vector(phi_rad), &s.q_b_n),
        };
        self.state = finite_state(&corrected)?;
        self.vel_lo = Vector3::zeros();
        self.q_lo = Vector4::zeros();
        Ok(())
    }
}

/// The increments of a sample: finite, |Δθ| ≤ [`MAX_DELTA_THETA_RAD`], |Δv| ≤
/// [`MAX_DELTA_V_M_S`]. The checks of [`Ins::step`] on its input, for a caller that has to
/// check what it derives from the sample before the INS steps in place.
pub(crate) fn validate_increment<T: Real>(inc: &ImuIncrement<T>) -> Result<(), NavError> {
    let (dth, dv) = (&inc.delta_theta_rad, &inc.delta_v_m_s);
    if !dth.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "delta_theta_rad",
        });
    }
    if !dv.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "delta_v_m_s",
        });
    }
    if dth.norm_squared() > T::lit(MAX_DELTA_THETA_RAD * MAX_DELTA_THETA_RAD) {
        return Err(NavError::InputOutOfRange {
            input: "delta_theta_rad",
        });
    }
    if dv.norm_squared() > T::lit(MAX_DELTA_V_M_S * MAX_DELTA_V_M_S) {
        return Err(NavError::InputOutOfRange {
            input: "delta_v_m_s",
        });
    }
    Ok(())
}

/// An initial state: finite, in the model range, unit-normalisable quaternion.
fn validate_state<T: Real>(s: &InsState<T>) -> Result<InsState<T>, NavError> {
    let st = finite_state(s)?;
    if !st.position.is_in_range() {
        return Err(NavError::InputOutOfRange { input: "position" });
    }
    Ok(st)
}

/// A state reached by integration or correction: finite, quaternion normalised.
fn finite_state<T: Real>(s: &InsState<T>) -> Result<InsState<T>, NavError> {
    let p = &s.position;
    if !p.is_finite() {
        return Err(NavError::NonFiniteInput { input: "position" });
    }
    if !s.vel_ned_m_s.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "vel_ned_m_s",
        });
    }
    let q = quat_normalize(&s.q_b_n).ok_or(NavError::NonFiniteInput { input: "q_b_n" })?;
    Ok(InsState {
        position: *p,
        vel_ned_m_s: s.vel_ned_m_s,
        q_b_n: q,
    })
}

/// Time derivative of the INS state under the continuous nonlinear INS equations (module doc),
/// as [`continuous_derivative`] returns it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct InsDerivative<T> {
    /// L̇, rate of geodetic latitude, rad/s.
    pub lat_rate_rad_s: T,
    /// l̇, rate of longitude, rad/s.
    pub lon_rate_rad_s: T,
    /// ḣ, rate of altitude (up), m/s.
    pub alt_rate_m_s: T,
    /// V̇ⁿ, acceleration in NED, m/s².
    pub vel_ned_rate_m_s2: Vector3<T>,
    /// Ċ_b^n, rate of the body-to-NED direction cosine matrix, 1/s.
    pub c_b_n_rate_per_s: Matrix3<T>,
}

/// Derivative of the continuous nonlinear INS equations (module doc) at a state, for the
/// error-model checks, given the body specific force `f_b_m_s2` and angular rate
/// `w_ib_b_rad_s`.
pub fn continuous_derivative<T: Real>(
    pos: &Position,
    v: &Vector3<T>,
    c_b_n: &Matrix3<T>,
    f_b_m_s2: &Vector3<T>,
    w_ib_b_rad_s: &Vector3<T>,
) -> InsDerivative<T> {
    use crate::math::rotation::skew;
    let k = Kinematics::new(pos, v);
    let g = normal_gravity_m_s2(T::lit(pos.lat_rad), T::lit(pos.alt_m));
    let mut v_dot = c_b_n * f_b_m_s2 - (k.w_ie * T::lit(2.0) + k.w_en).cross(v);
    v_dot.z += g;
    let c_dot = c_b_n * skew(w_ib_b_rad_s) - skew(&(k.w_ie + k.w_en)) * c_b_n;
    InsDerivative {
        lat_rate_rad_s: v.x / k.rm_h,
        lon_rate_rad_s: v.y / (k.rn_h * k.cos_lat),
        alt_rate_m_s: -v.z,
        vel_ned_rate_m_s2: v_dot,
        c_b_n_rate_per_s: c_dot,
    }
}

#[cfg(test)]
#[path = "mechanization_tests.rs"]
mod tests;

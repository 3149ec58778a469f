//! Truth of a vehicle flying any smooth motion over the WGS-84 ellipsoid, and the increments a
//! perfect strapdown IMU on it measures.
//!
//! A [`Motion`] gives, at every time, the velocity over the earth in NED and its derivative, and
//! the attitude `C_b^n` with the body rate `ω_nb^b`, all analytic (Euler angles and their rates
//! through [`Kinematics::from_euler`]). [`generate`] turns it into the truth at the IMU epochs:
//!
//! * latitude, longitude and height integrate `L̇ = V_N/(R_M+h)`, `l̇ = V_E/((R_N+h) cos L)`,
//!   `ḣ = −V_D` with RK4 at the IMU interval;
//! * the specific force is `fⁿ = V̇ⁿ + (2ω_ie + ω_en) × Vⁿ − gⁿ` with the exact normal gravity of
//!   [`crate::truth`] (not the INS's model), the body rate `ω_ib^b = ω_nb^b + C_n^b ω_in^n`;
//! * the IMU increments `Δv = ∫ fᵇ dt`, `Δθ = ∫ ω_ib^b dt` (what a real IMU outputs; coning and
//!   sculling are the INS's business) are integrated over each interval with 3-point
//!   Gauss-Legendre quadrature.
//!
//! Nothing here uses nav-core's earth model or rotations; only its sample types.

use crate::truth::{
    dcm_from_euler, earth_rate_ned_rad_s, gravity_ned_m_s2, radii_of_curvature_m,
    transport_rate_ned_rad_s,
};
use nalgebra::{Matrix3, Vector3};
use nav_core::seeker_ins::{ImuIncrement, Position};
use nav_core::time::Timestamp;

/// The motion at one instant.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Kinematics {
    /// Velocity over the earth, NED, m/s.
    pub vel_ned_m_s: Vector3<f64>,
    /// Its time derivative, NED, m/s².
    pub accel_ned_m_s2: Vector3<f64>,
    /// Attitude `C_b^n`.
    pub c_b_n: Matrix3<f64>,
    /// Body rate relative to the navigation frame, `ω_nb^b`, rad/s.
    pub w_nb_b_rad_s: Vector3<f64>,
}

impl Kinematics {
    /// The kinematics of a velocity and an attitude given as Euler angles (roll φ, pitch θ,
    /// yaw ψ; `C_b^n = C_z(ψ) C_y(θ) C_x(φ)`), rad, with their rates, rad/s:
    /// `ω_nb^b = [φ̇ − ψ̇ sin θ, θ̇ cos φ + ψ̇ sin φ cos θ, −θ̇ sin φ + ψ̇ cos φ cos θ]`.
    pub fn from_euler(
        vel_ned_m_s: Vector3<f64>,
        accel_ned_m_s2: Vector3<f64>,
        euler_rad: Vector3<f64>,
        euler_rate_rad_s: Vector3<f64>,
    ) -> Self {
        let (phi, theta) = (euler_rad.x, euler_rad.y);
        let (pd, td, yd) = (euler_rate_rad_s.x, euler_rate_rad_s.y, euler_rate_rad_s.z);
        let (sp, cp) = phi.sin_cos();
        let (st, ct) = theta.sin_cos();
        Self {
            vel_ned_m_s,
            accel_ned_m_s2,
            c_b_n: dcm_from_euler(euler_rad.x, euler_rad.y, euler_rad.z),
            w_nb_b_rad_s: Vector3::new(
                pd - yd * st,
                td * cp + yd * sp * ct,
                -td * sp + yd * cp * ct,
            ),
        }
    }
}

/// A smooth motion (velocity and attitude analytic in time).
pub trait Motion {
    /// The motion at time `t_s` (s from the start).
    fn at(&self, t_s: f64) -> Kinematics;
}

/// Truth at the IMU epochs and the perfect IMU increments between them.
#[derive(Debug, Clone)]
pub struct FlightTruth {
    /// Epoch times, s.
    pub t_s: Vec<f64>,
    /// Geodetic position.
    pub position: Vec<Position>,
    /// NED velocity, m/s.
    pub vel_ned_m_s: Vec<Vector3<f64>>,
    /// `C_b^n`.
    pub c_b_n: Vec<Matrix3<f64>>,
    /// Specific force in body axes at the epoch, m/s².
    pub specific_force_b_m_s2: Vec<Vector3<f64>>,
    /// Body rate `ω_ib^b` at the epoch, rad/s.
    pub rate_b_rad_s: Vec<Vector3<f64>>,
    /// Increments over `(t_{k−1}, t_k]`, stamped `t_k`; `imu[0]` is zero.
    pub imu: Vec<ImuIncrement<f64>>,
}

fn pos_rate(p: &Position, v: &Vector3<f64>) -> Vector3<f64> {
    let (rm, rn) = radii_of_curvature_m(p.lat_rad);
    Vector3::new(
        v.x / (rm + p.alt_m),
        v.y / ((rn + p.alt_m) * p.lat_rad.cos()),
        -v.z,
    )
}

fn moved(p: &Position, rate: &Vector3<f64>, dt_s: f64) -> Position {
    Position {
        lat_rad: p.lat_rad + rate.x * dt_s,
        lon_rad: p.lon_rad + rate.y * dt_s,
        alt_m: p.alt_m + rate.z * dt_s,
    }
}

/// Specific force and body rate in body axes, at time `t_s` and position `p`.
pub fn sensed(motion: &impl Motion, t_s: f64, p: &Position) -> (Vector3<f64>, Vector3<f64>) {
    let k = motion.at(t_s);
    let c = k.c_b_n;
    let w_ie = earth_rate_ned_rad_s(p.lat_rad);
    let w_en = transport_rate_ned_rad_s(p.lat_rad, p.alt_m, &k.vel_ned_m_s);
    let f_n = k.accel_ned_m_s2 + (w_ie * 2.0 + w_en).cross(&k.vel_ned_m_s)
        - gravity_ned_m_s2(p.lat_rad, p.lon_rad, p.alt_m);
    let ct = c.transpose();
    (ct * f_n, k.w_nb_b_rad_s + ct * (w_ie + w_en))
}

/// The truth of `motion` from `start` at the time stamps `stamps_us` (µs, strictly increasing;
/// the first is t = 0).
pub fn generate(motion: &impl Motion, start: Position, stamps_us: &[u64]) -> FlightTruth {
    let n = stamps_us.len();
    let mut out = FlightTruth {
        t_s: Vec::with_capacity(n),
        position: Vec::with_capacity(n),
        vel_ned_m_s: Vec::with_capacity(n),
        c_b_n: Vec::with_capacity(n),
        specific_force_b_m_s2: Vec::with_capacity(n),
        rate_b_rad_s: Vec::with_capacity(n),
        imu: Vec::with_capacity(n),
    };
    let mut p = start;
    let mut prev_t: Option<f64> = None;
    for &us in stamps_us {
        let t = us as f64 * 1e-6;
        let stamp = Timestamp::from_micros(us);
        match prev_t {
            Some(t0) => {
                let (imu, p_next) = interval(motion, &p, t0, t, stamp);
                out.imu.push(imu);
                p = p_next;
            }
            None => out.imu.push(ImuIncrement::zero(stamp)),
        }
        let k = motion.at(t);
        let (f_b, w_b) = sensed(motion, t, &p);
        out.t_s.push(t);
        out.position.push(p);
        out.vel_ned_m_s.push(k.vel_ned_m_s);
        out.c_b_n.push(k.c_b_n);
        out.specific_force_b_m_s2.push(f_b);
        out.rate_b_rad_s.push(w_b);
        prev_t = Some(t);
    }
    out
}

/// Increments over `(t0, t]` (stamped `stamp`) and the position at `t` from `p0` at `t0`.
fn interval(
    motion: &impl Motion,
    p0: &Position,
    t0: f64,
    t: f64,
    stamp: Timestamp,
) -> (ImuIncrement<f64>, Position) {
    let h = t - t0;
    let gl = [
        (0.5 - 0.5 * 0.6f64.sqrt(), 5.0 / 18.0),
        (0.5, 8.0 / 18.0),
        (0.5 + 0.5 * 0.6f64.sqrt(), 5.0 / 18.0),
    ];
    // RK4 for (L, l, h) with the analytic velocity; the stages also give the position at the
    // quadrature nodes to first order (its effect on gravity and the frame rates over one IMU
    // interval is far below the sensors' resolution).
    let f = |tt: f64, pp: &Position| pos_rate(pp, &motion.at(tt).vel_ned_m_s);
    let k1 = f(t0, p0);
    let k2 = f(t0 + 0.5 * h, &moved(p0, &k1, 0.5 * h));
    let k3 = f(t0 + 0.5 * h, &moved(p0, &k2, 0.5 * h));
    let k4 = f(t, &moved(p0, &k3, h));
    let p = moved(p0, &((k1 + 2.0 * k2 + 2.0 * k3 + k4) / 6.0), h);
    let mut dth = Vector3::zeros();
    let mut dv = Vector3::zeros();
    for (x, w) in gl {
        let tau = x * h;
        let (f_b, w_b) = sensed(motion, t0 + tau, &moved(p0, &k2, tau));
        dv += f_b * (w * h);
        dth += w_b * (w * h);
    }
    (
        ImuIncrement {
            time: stamp,
            delta_theta_rad: dth,
            delta_v_m_s: dv,
        },
        p,
    )
}

/// A smooth step from 0 to 1 over `[0, 1]` (quintic, C²: no jump in the acceleration or the
/// angular acceleration it drives): value, first and second derivative with respect to `u`.
pub fn smooth_step(u: f64) -> (f64, f64, f64) {
    if u <= 0.0 {
        (0.0, 0.0, 0.0)
    } else if u >= 1.0 {
        (1.0, 0.0, 0.0)
    } else {
        let u2 = u * u;
        let u3 = u2 * u;
        (
            u3 * (10.0 - 15.0 * u + 6.0 * u2),
            30.0 * u2 * (1.0 - u) * (1.0 - u),
            60.0 * u * (1.0 - u) * (1.0 - 2.0 * u),
        )
    }
}

/// A change of `delta` spread smoothly over `[start_s, start_s + duration_s]`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Ramp {
    /// Start, s.
    pub start_s: f64,
    /// Duration, s (> 0).
    pub duration_s: f64,
    /// Total change (unit of the schedule it belongs to).
    pub delta: f64,
}

/// A scalar schedule `x(t) = x₀ + Σ ramps + A sin(2π(t − t₀)/T)` on `[t₀, t₁]` — value and
/// its first two derivatives.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Schedule {
    /// Value at t = 0.
    pub initial: f64,
    /// Smooth changes.
    pub ramps: Vec<Ramp>,
    /// Sinusoidal weave: amplitude, period s, start s, end s (faded in and out over one
    /// quarter period each so its derivatives stay continuous).
    pub weave: Option<Weave>,
}

/// A sinusoidal weave of a schedule.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Weave {
    /// Amplitude (unit of the schedule).
    pub amplitude: f64,
    /// Period, s.
    pub period_s: f64,
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
}

impl Schedule {
    /// A constant.
    pub fn constant(value: f64) -> Self {
        Self {
            initial: value,
            ..Self::default()
        }
    }

    /// Value, first and second derivative at `t_s`.
    pub fn eval(&self, t_s: f64) -> (f64, f64, f64) {
        let mut v = (self.initial, 0.0, 0.0);
        for r in &self.ramps {
            let (s, ds, dds) = smooth_step((t_s - r.start_s) / r.duration_s);
            v.0 += r.delta * s;
            v.1 += r.delta * ds / r.duration_s;
            v.2 += r.delta * dds / (r.duration_s * r.duration_s);
        }
        if let Some(w) = self.weave {
            let fade = w.period_s / 4.0;
            let (up, dup, ddup) = smooth_step((t_s - w.start_s) / fade);
            let (dn, ddn, dddn) = smooth_step((t_s - (w.end_s - fade)) / fade);
            // envelope e = up · (1 − dn)
            let e = up * (1.0 - dn);
            let de = dup / fade * (1.0 - dn) - up * ddn / fade;
            let dde = ddup / (fade * fade) * (1.0 - dn)
                - 2.0 * dup * ddn / (fade * fade)
                - up * dddn / (fade * fade);
            let om = 2.0 * std::f64::consts::PI / w.period_s;
            let ph = om * (t_s - w.start_s);
            let (s, c) = ph.sin_cos();
            let a = w.amplitude;
            v.0 += a * e * s;
            v.1 += a * (de * s + e * om * c);
            v.2 += a * (dde * s + 2.0 * de * om * c - e * om * om * s);
        }
        v
    }
}

/// `ω_nb^b` by central differences of `C_b^n` (`Ċ_b^n = C_b^n [ω_nb^b ×]`), for checking a
/// motion's analytic body rate.
#[cfg(test)]
pub(crate) fn body_rate_by_differences(motion: &impl Motion, t_s: f64, h_s: f64) -> Vector3<f64> {
    let c = motion.at(t_s).c_b_n;
    let dc = (motion.at(t_s + h_s).c_b_n - motion.at(t_s - h_s).c_b_n) / (2.0 * h_s);
    let w = c.transpose() * dc;
    Vector3::new(w[(2, 1)], w[(0, 2)], w[(1, 0)])
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The schedule's derivatives agree with central differences of its value.
    #[test]
    fn schedule_derivatives_match_finite_differences() {
        let s = Schedule {
            initial: 1.0,
            ramps: vec![
                Ramp {
                    start_s: 2.0,
                    duration_s: 3.0,
                    delta: 0.7,
                },
                Ramp {
                    start_s: 4.0,
                    duration_s: 1.5,
                    delta: -2.0,
                },
            ],
            weave: Some(Weave {
                amplitude: 0.3,
                period_s: 8.0,
                start_s: 1.0,
                end_s: 30.0,
            }),
        };
        let h = 1e-4;
        for i in 0..400 {
            let t = f64::from(i) * 0.1 + 0.05; // off the ramps' ends (C² only there)
            let (_, d, dd) = s.eval(t);
            let fd = (s.eval(t + h).0 - s.eval(t - h).0) / (2.0 * h);
            let fdd = (s.eval(t + h).1 - s.eval(t - h).1) / (2.0 * h);
            assert!((d - fd).abs() < 1e-6, "t {t}: {d} vs {fd}");
            assert!((dd - fdd).abs() < 1e-5, "t {t}: {dd} vs {fdd}");
        }
    }

    /// `ω_nb^b` from the Euler rates agrees with the finite-difference rate of `C_b^n`
    /// (`Ċ_b^n = C_b^n [ω_nb^b ×]`).
    #[test]
    fn body_rate_matches_attitude_finite_differences() {
        struct Weaving;
        impl Motion for Weaving {
            fn at(&self, t: f64) -> Kinematics {
                Kinematics::from_euler(
                    Vector3::zeros(),
                    Vector3::zeros(),
                    Vector3::new(0.4 * t.sin(), 0.3 * (0.7 * t).cos(), 1.0 + 0.5 * t),
                    Vector3::new(0.4 * t.cos(), -0.21 * (0.7 * t).sin(), 0.5),
                )
            }
        }
        for i in 0..50 {
            let t = f64::from(i) * 0.13;
            let e =
                (body_rate_by_differences(&Weaving, t, 1e-6) - Weaving.at(t).w_nb_b_rad_s).norm();
            assert!(e < 1e-7, "t {t}: {e}");
        }
    }
}

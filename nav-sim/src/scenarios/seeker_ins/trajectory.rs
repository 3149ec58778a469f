//! Truth trajectories of the seeker-aided INS experiment: level flight at constant altitude,
//! straight (constant velocity, then a constant along-track acceleration) or S-turns
//! (heading ψ₀ + A sin(2πt/T)), with coordinated-turn bank.
//!
//! The truth is generated so that a perfect IMU and a perfect INS agree:
//! * velocity `Vⁿ(t) = s(t) [cos ψ, sin ψ, 0]` and attitude `C_b^n = C(φ(t), 0, ψ(t))` are
//!   analytic; latitude and longitude integrate `L̇ = V_N/(R_M+h)`, `l̇ = V_E/((R_N+h) cos L)`
//!   with RK4 at the IMU interval;
//! * the specific force is `fⁿ = V̇ⁿ + (2ω_ie + ω_en) × Vⁿ − gⁿ` (the same WGS-84 normal
//!   gravity as the INS) and the body rate `ω_ib^b = ω_nb^b(Euler rates) + C_n^b ω_in^n`;
//! * the IMU increments `Δv = ∫ fᵇ dt`, `Δθ = ∫ ω_ib^b dt` are integrated over each IMU
//!   interval with 3-point Gauss-Legendre quadrature (error O(Δt⁷)).

use nalgebra::{Matrix3, Vector3};
use nav_core::earth::{earth_rate_ned, gravity_ned, radii_m};
use nav_core::math::rotation::euler_to_dcm;
use nav_core::seeker_ins::{ImuIncrement, Position};
use nav_core::time::Timestamp;
use serde::Deserialize;

/// Shape of the trajectory.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Shape {
    /// Constant heading; constant speed, then constant along-track acceleration.
    Straight,
    /// Constant speed, heading ψ₀ + A sin(2πt/T).
    STurn,
}

/// Trajectory configuration (TOML table `[trajectory]`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrajectoryConfig {
    /// Shape.
    pub shape: Shape,
    /// Start latitude, deg.
    pub start_lat_deg: f64,
    /// Start longitude, deg.
    pub start_lon_deg: f64,
    /// Altitude (constant), m.
    pub alt_m: f64,
    /// Initial speed, m/s.
    pub speed_m_s: f64,
    /// Mean heading ψ₀, deg (90 = east).
    pub heading_deg: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Straight: time at which the along-track acceleration starts, s.
    #[serde(default)]
    pub accel_start_s: f64,
    /// Straight: along-track acceleration, m/s².
    #[serde(default)]
    pub accel_m_s2: f64,
    /// S-turn heading amplitude A, deg.
    #[serde(default)]
    pub s_amplitude_deg: f64,
    /// S-turn period T, s.
    #[serde(default = "default_period")]
    pub s_period_s: f64,
    /// Bank into turns (coordinated turn, φ = atan(s ψ̇ / g)); false keeps wings level.
    #[serde(default = "default_true")]
    pub coordinated_turn: bool,
}

fn default_period() -> f64 {
    80.0
}
fn default_true() -> bool {
    true
}

/// Standard gravity used only for the bank-angle schedule, m/s².
const G_BANK: f64 = 9.806_65;

/// Kinematics at time t.
#[derive(Debug, Clone, Copy)]
struct Kin {
    v_ned: Vector3<f64>,
    a_ned: Vector3<f64>,
    roll: f64,
    roll_rate: f64,
    yaw: f64,
    yaw_rate: f64,
}

impl TrajectoryConfig {
    fn kin(&self, t: f64) -> Kin {
        let psi0 = self.heading_deg.to_radians();
        let (s, s_dot, psi, psi_dot, psi_ddot) = match self.shape {
            Shape::Straight => {
                let ta = (t - self.accel_start_s).max(0.0);
                let acc = if t > self.accel_start_s {
                    self.accel_m_s2
                } else {
                    0.0
                };
                (self.speed_m_s + self.accel_m_s2 * ta, acc, psi0, 0.0, 0.0)
            }
            Shape::STurn => {
                let w = 2.0 * std::f64::consts::PI / self.s_period_s;
                let a = self.s_amplitude_deg.to_radians();
                (
                    self.speed_m_s,
                    0.0,
                    psi0 + a * (w * t).sin(),
                    a * w * (w * t).cos(),
                    -a * w * w * (w * t).sin(),
                )
            }
        };
        let (roll, roll_rate) = if self.coordinated_turn {
            let u = s * psi_dot / G_BANK;
            let u_dot = (s_dot * psi_dot + s * psi_ddot) / G_BANK;
            (u.atan(), u_dot / (1.0 + u * u))
        } else {
            (0.0, 0.0)
        };
        let (sp, cp) = psi.sin_cos();
        Kin {
            v_ned: Vector3::new(s * cp, s * sp, 0.0),
            a_ned: Vector3::new(
                s_dot * cp - s * psi_dot * sp,
                s_dot * sp + s * psi_dot * cp,
                0.0,
            ),
            roll,
            roll_rate,
            yaw: psi,
            yaw_rate: psi_dot,
        }
    }
}

/// Truth at the IMU epochs and the perfect IMU increments between them.
#[derive(Debug, Clone)]
pub struct Truth {
    /// IMU interval, s.
    pub dt_s: f64,
    /// Epoch times t_k = k Δt, s.
    pub t_s: Vec<f64>,
    /// Geodetic position at t_k.
    pub position: Vec<Position>,
    /// NED velocity at t_k, m/s.
    pub vel_ned_m_s: Vec<Vector3<f64>>,
    /// C_b^n at t_k.
    pub c_b_n: Vec<Matrix3<f64>>,
    /// Increments over (t_{k−1}, t_k], stamped t_k (k × the IMU interval in whole µs); `imu[0]`
    /// is zero (no interval before t_0).
    pub imu: Vec<ImuIncrement<f64>>,
}

fn pos_rate(p: &Position, v: &Vector3<f64>) -> (f64, f64) {
    let (rm, rn) = radii_m(p.lat_rad);
    (
        v.x / (rm + p.alt_m),
        v.y / ((rn + p.alt_m) * p.lat_rad.cos()),
    )
}

/// Specific force and body rate at time t with the position there.
fn sensed(cfg: &TrajectoryConfig, t: f64, p: &Position) -> (Vector3<f64>, Vector3<f64>) {
    let k = cfg.kin(t);
    let c = euler_to_dcm(k.roll, 0.0, k.yaw);
    let w_ie = earth_rate_ned(p.lat_rad);
    let w_en = nav_core::earth::transport_rate_ned(p.lat_rad, p.alt_m, &k.v_ned);
    let f_n = k.a_ned + (w_ie * 2.0 + w_en).cross(&k.v_ned) - gravity_ned(p.lat_rad, p.alt_m);
    // ω_nb^b from Euler rates (pitch 0): [φ̇, ψ̇ sin φ, ψ̇ cos φ].
    let w_nb_b = Vector3::new(
        k.roll_rate,
        k.yaw_rate * k.roll.sin(),
        k.yaw_rate * k.roll.cos(),
    );
    let ct = c.transpose();
    (ct * f_n, w_nb_b + ct * (w_ie + w_en))
}

/// Generates the truth at IMU interval `dt_s`.
pub fn generate(cfg: &TrajectoryConfig, dt_s: f64) -> Truth {
    let n = (cfg.duration_s / dt_s).round() as usize;
    let mut out = Truth {
        dt_s,
        t_s: Vec::with_capacity(n + 1),
        position: Vec::with_capacity(n + 1),
        vel_ned_m_s: Vec::with_capacity(n + 1),
        c_b_n: Vec::with_capacity(n + 1),
        imu: Vec::with_capacity(n + 1),
    };
    let mut p = Position {
        lat_rad: cfg.start_lat_deg.to_radians(),
        lon_rad: cfg.start_lon_deg.to_radians(),
        alt_m: cfg.alt_m,
    };
    let gl = [
        (0.5 - 0.5 * (0.6f64).sqrt(), 5.0 / 18.0),
        (0.5, 8.0 / 18.0),
        (0.5 + 0.5 * (0.6f64).sqrt(), 5.0 / 18.0),
    ];
    let dt_us = (dt_s * 1e6).round() as u64;
    for k in 0..=n {
        let t = k as f64 * dt_s;
        let time = Timestamp::from_micros(k as u64 * dt_us);
        let kin = cfg.kin(t);
        if k > 0 {
            let t0 = t - dt_s;
            // Increments over (t0, t]; position inside the interval from the start-of-interval
            // rate (its effect on earth and transport rate over 10 ms is ~1e-12 relative).
            let p0 = *out.position.last().unwrap_or(&p);
            let (dl, dlon) = pos_rate(&p0, &cfg.kin(t0).v_ned);
            let mut dth = Vector3::zeros();
            let mut dv = Vector3::zeros();
            for (x, w) in gl {
                let tau = x * dt_s;
                let pi = Position {
                    lat_rad: p0.lat_rad + dl * tau,
                    lon_rad: p0.lon_rad + dlon * tau,
                    alt_m: p0.alt_m,
                };
                let (f_b, w_b) = sensed(cfg, t0 + tau, &pi);
                dv += f_b * (w * dt_s);
                dth += w_b * (w * dt_s);
            }
            out.imu.push(ImuIncrement {
                time,
                delta_theta_rad: dth,
                delta_v_m_s: dv,
            });
            // RK4 for (L, l) with the analytic velocity.
            let f = |tt: f64, pp: &Position| pos_rate(pp, &cfg.kin(tt).v_ned);
            let add = |pp: &Position, d: (f64, f64), s: f64| Position {
                lat_rad: pp.lat_rad + d.0 * s,
                lon_rad: pp.lon_rad + d.1 * s,
                alt_m: pp.alt_m,
            };
            let k1 = f(t0, &p0);
            let k2 = f(t0 + 0.5 * dt_s, &add(&p0, k1, 0.5 * dt_s));
            let k3 = f(t0 + 0.5 * dt_s, &add(&p0, k2, 0.5 * dt_s));
            let k4 = f(t, &add(&p0, k3, dt_s));
            p = Position {
                lat_rad: p0.lat_rad + dt_s / 6.0 * (k1.0 + 2.0 * k2.0 + 2.0 * k3.0 + k4.0),
                lon_rad: p0.lon_rad + dt_s / 6.0 * (k1.1 + 2.0 * k2.1 + 2.0 * k3.1 + k4.1),
                alt_m: p0.alt_m,
            };
        } else {
            out.imu.push(ImuIncrement::zero(time));
        }
        out.t_s.push(t);
        out.position.push(p);
        out.vel_ned_m_s.push(kin.v_ned);
        out.c_b_n.push(euler_to_dcm(kin.roll, 0.0, kin.yaw));
    }
    out
}

//! Test support, not part of the API: compiled for nav-core's own tests and behind the
//! non-default feature `test-support` (the tests crate enables it; no flight build does).
//!
//! [`World`]: the flight navigator's synthetic chain, in f64 — straight level flight of a
//! master INS (nav-core's [`Ins`] used as a generator: whatever it integrates *is* the
//! truth), the missile on its lever arm under the wing in a fixed mount misalignment, the
//! release and its drop (0 g), then the missile's own INS in level flight. The navigator's
//! unit tests (`navigator::tests`) and its property tests (`tests/tests/navigator_props.rs`)
//! fly the same world, at their own rates and schedules.
// Test code: a failed step of the generator is a broken test, and it may panic.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::panic,
    clippy::indexing_slicing
)]

use super::{
    AidTimeouts, BaroDamping, BaroErrorModel, HandoverPriors, ImuTick, LeverArm, MasterNav,
    NavigatorConfig, NavigatorInitial, SeparationCheck,
};
use crate::earth::{earth_rate_ned, normal_gravity_m_s2, radii_m, transport_rate_ned};
use crate::math::rotation::{dcm_to_quat, exp_so3, quat_to_dcm};
use crate::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles, ImuIncrement, Ins, InsState,
    Landmark, Position, SeekerInsConfig,
};
use crate::time::Timestamp;
use crate::transfer_alignment::{PaperCase, TaConfig};
use crate::Real;
use nalgebra::{Matrix3, Quaternion, SMatrix, Vector3};
use std::vec::Vec;

/// Where the chain starts.
pub const START: Position = Position {
    lat_rad: 0.6458,
    lon_rad: 2.2166,
    alt_m: 3000.0,
};
/// Ground speed, north, m/s.
pub const SPEED_M_S: f64 = 200.0;
/// The slave's true mount misalignment θ (`C_m^s = exp(−[θ×])`), rad.
pub const THETA: [f64; 3] = [0.006, -0.004, 0.008];

/// The landmark: 30 km north of the start, on the ground.
pub fn landmark_position() -> Position {
    Position {
        lat_rad: START.lat_rad + 30_000.0 / 6_360_000.0,
        lon_rad: START.lon_rad,
        alt_m: 0.0,
    }
}

/// The true gimbal angles of the landmark from `truth`.
pub fn gimbal_truth(truth: &InsState<f64>) -> GimbalAngles<f64> {
    let lm = Landmark::new(landmark_position()).unwrap();
    let d = landmark_vector_ned(&truth.position, &lm);
    gimbal_angles_of(&(quat_to_dcm(&truth.q_b_n).transpose() * d))
}

/// The chain's navigator configuration at 100 Hz (the flight configurations' rate): the
/// flight alignment and EKF, the lever arm's σ 1 cm, the separation check, `baro`, the release
/// after `coast_s` of coast, the aid timeouts (master 0.5 s, baro 1 s, seeker 2 s).
pub fn config<T: Real>(baro: BaroDamping<T>, coast_s: f64) -> NavigatorConfig<T> {
    let alignment = TaConfig::<T>::flight(PaperCase::Case1);
    NavigatorConfig {
        lever_arm: LeverArm {
            nominal_m: alignment.lever_arm_m,
            sigma_m: Vector3::from_element(T::lit(0.01)),
        },
        alignment,
        priors: HandoverPriors {
            accel_bias_sigma_m_s2: T::lit(1e-3),
            gyro_bias_sigma_rad_s: T::lit(5e-8),
            gimbal_bias_sigma_rad: T::lit(7e-4),
        },
        ins: SeekerInsConfig::flight(Landmark::new(landmark_position()).unwrap()),
        imu_dt_s: T::lit(0.01),
        max_master_latency_s: T::lit(0.1),
        separation: SeparationCheck {
            specific_force_jump_m_s2: T::lit(4.0),
            confirm_window_s: T::lit(0.3),
            unsignalled_onset_s: T::lit(0.3),
            coast_s: T::lit(coast_s),
        },
        baro,
        timeouts: AidTimeouts {
            master_s: T::lit(0.5),
            baro_s: T::lit(1.0),
            seeker_s: T::lit(2.0),
        },
    }
}

/// The chain's baro error model in the EKF: 1 m white, 5 m Gauss-Markov over 100 s, no lag.
pub fn baro_model<T: Real>() -> BaroErrorModel<T> {
    BaroErrorModel {
        white_sigma_m: T::lit(1.0),
        markov_sigma_m: T::lit(5.0),
        markov_tau_s: T::lit(100.0),
        lag_s: T::lit(0.0),
    }
}

/// A world's schedule.
#[derive(Debug, Clone, Copy)]
pub struct WorldSpec {
    /// IMU rate, Hz (a divisor of 10⁶).
    pub rate_hz: u64,
    /// Time stamp of tick 0, µs.
    pub start_us: u64,
    /// The last tick under the wing: the missile leaves with its state at this tick.
    pub sep_tick: u64,
    /// Ticks of the drop (0 g) after the release.
    pub drop_ticks: u64,
    /// The missile's lever arm in the master's body frame, m.
    pub lever_m: Vector3<f64>,
}

/// The chain's truth (module doc).
#[derive(Debug)]
pub struct World {
    dt_us: u64,
    start_us: u64,
    master: Ins<f64>,
    missile: Option<Ins<f64>>,
    /// The master's state per tick (tick `k` at index `k − 1`), for the late master samples.
    log: Vec<(Timestamp, InsState<f64>)>,
    dth: Vector3<f64>,
    dv: Vector3<f64>,
    dt: f64,
    lever: Vector3<f64>,
    /// The last tick under the wing.
    pub sep_tick: u64,
    /// Ticks of the drop.
    pub drop_ticks: u64,
    /// The current tick (0 at the start).
    pub k: u64,
}

impl World {
    /// The world at tick 0.
    pub fn new(spec: &WorldSpec) -> Self {
        let dt = 1.0 / spec.rate_hz as f64;
        let v = Vector3::new(SPEED_M_S, 0.0, 0.0);
        let lat = START.lat_rad;
        let w_in = earth_rate_ned(lat) + transport_rate_ned(lat, START.alt_m, &v);
        let cor = (earth_rate_ned(lat) * 2.0 + transport_rate_ned(lat, START.alt_m, &v)).cross(&v);
        let f = cor - Vector3::new(0.0, 0.0, normal_gravity_m_s2(lat, START.alt_m));
        let state = InsState {
            position: START,
            vel_ned_m_s: v,
            q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        };
        Self {
            dt_us: 1_000_000 / spec.rate_hz,
            start_us: spec.start_us,
            master: Ins::new(state, dt).unwrap(),
            missile: None,
            log: Vec::new(),
            dth: w_in * dt,
            dv: f * dt,
            dt,
            lever: spec.lever_m,
            sep_tick: spec.sep_tick,
            drop_ticks: spec.drop_ticks,
            k: 0,
        }
    }

    /// The current tick's time stamp.
    pub fn time(&self) -> Timestamp {
        Timestamp::from_micros(self.start_us + self.k * self.dt_us)
    }

    /// `C_m^s`: the master's body frame to the slave's.
    pub fn c_m_s() -> Matrix3<f64> {
        exp_so3(&-Vector3::from(THETA))
    }

    /// The missile's truth at the current tick (under the wing: the master's moved by the
    /// lever arm, its attitude composed with θ).
    pub fn missile_truth(&self) -> InsState<f64> {
        if let Some(m) = &self.missile {
            return *m.state();
        }
        let s = self.master.state();
        let c_m_n = quat_to_dcm(&s.q_b_n);
        let l = c_m_n * self.lever;
        let (rm, rn) = radii_m(s.position.lat_rad);
        let p = s.position;
        InsState {
            position: Position {
                lat_rad: p.lat_rad + l.x / (rm + p.alt_m),
                lon_rad: p.lon_rad + l.y / ((rn + p.alt_m) * p.lat_rad.cos()),
                alt_m: p.alt_m - l.z,
            },
            vel_ned_m_s: s.vel_ned_m_s,
            q_b_n: dcm_to_quat(&(c_m_n * exp_so3(&Vector3::from(THETA)))),
        }
    }

    /// The master's state at the current tick.
    pub fn master_state(&self) -> &InsState<f64> {
        self.master.state()
    }

    /// Advances one tick: the slave's increment.
    pub fn step(&mut self) -> ImuIncrement<f64> {
        if self.k == self.sep_tick {
            self.missile = Some(Ins::new(self.missile_truth(), self.dt).unwrap());
        }
        self.k += 1;
        let t = self.time();
        let c = Self::c_m_s();
        let in_drop = self.k > self.sep_tick && self.k <= self.sep_tick + self.drop_ticks;
        let inc_m = ImuIncrement {
            time: t,
            delta_theta_rad: self.dth,
            delta_v_m_s: self.dv,
        };
        self.master.step(&inc_m).unwrap();
        self.log.push((t, *self.master.state()));
        let inc_s = ImuIncrement {
            time: t,
            delta_theta_rad: c * self.dth,
            delta_v_m_s: if in_drop {
                Vector3::zeros()
            } else {
                c * self.dv
            },
        };
        if let Some(m) = &mut self.missile {
            m.step(&inc_s).unwrap();
        }
        inc_s
    }

    /// The master's sample of tick `k` (its time of validity), as the bus carries it; `None`
    /// before tick 1 or after the current tick.
    pub fn master_sample<T: Real>(&self, k: u64) -> Option<MasterNav<T>> {
        let (t, s) = self.log.get(usize::try_from(k.checked_sub(1)?).ok()?)?;
        Some(MasterNav {
            time: *t,
            c_m_n: quat_to_dcm(&s.q_b_n).cast(),
            vel_ned_m_s: s.vel_ned_m_s.cast(),
            position: s.position,
            angular_rate_rad_s: (self.dth / self.dt).cast(),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: (self.dv / self.dt).cast(),
            attitude_sigma_rad: Vector3::new(T::lit(2e-4), T::lit(2e-4), T::lit(8e-4)),
            velocity_sigma_m_s: Vector3::new(T::lit(0.05), T::lit(0.05), T::lit(0.08)),
            position_sigma_m: Vector3::new(T::lit(3.0), T::lit(3.0), T::lit(5.0)),
        })
    }

    /// The navigator's start: the missile's truth with the master's attitude (θ unknown),
    /// 5 m off in north; σ 10 m, 1 m/s, 10 mrad.
    pub fn initial<T: Real>(&self) -> NavigatorInitial<T> {
        let mut truth = self.missile_truth();
        truth.q_b_n = self.master.state().q_b_n;
        truth.position.lat_rad += 5.0 / 6_360_000.0;
        let d = [100.0, 100.0, 100.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4];
        NavigatorInitial {
            time: self.time(),
            state: InsState {
                position: truth.position,
                vel_ned_m_s: truth.vel_ned_m_s.cast(),
                q_b_n: truth.q_b_n.cast(),
            },
            nav_covariance: SMatrix::from_fn(|i, j| if i == j { T::lit(d[i]) } else { T::zero() }),
        }
    }
}

/// The navigator's IMU tick of a world's increment (nothing clipped).
pub fn imu_tick<T: Real>(i: &ImuIncrement<f64>) -> ImuTick<T> {
    ImuTick {
        increment: ImuIncrement {
            time: i.time,
            delta_theta_rad: i.delta_theta_rad.cast(),
            delta_v_m_s: i.delta_v_m_s.cast(),
        },
        clipped: ClipFlags::default(),
    }
}

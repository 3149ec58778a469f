//! The synthetic chain of the navigator's property tests: the truth (level flight, the
//! master INS, the missile on its lever arm, the release and its drop), the navigator's
//! configuration at the case's IMU rate, the master bus and the per-tick baro and LOS draws.

use nalgebra::{Quaternion, SMatrix, Vector3};
use nav_core::earth::{earth_rate_ned, normal_gravity_m_s2, radii_m, transport_rate_ned};
use nav_core::math::rotation::{dcm_to_quat, exp_so3, quat_to_dcm};
use nav_core::navigator::{
    AidTimeouts, BaroDamping, BaroErrorModel, FlightNavigator, HandoverPriors, ImuTick, LeverArm,
    MasterNav, NavigatorConfig, NavigatorInitial, SeparationCheck,
};
use nav_core::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles, ImuIncrement, Ins, InsState,
    Landmark, LosSample, Position, SeekerInsConfig,
};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{PaperCase, TaConfig, MAX_GAP_STEPS};
use nav_core::vertical_channel::BaroSample;
use nav_core::Real;
use proptest::prelude::*;

/// The histories' depth: `(H − 2) · dt` reaches 0.6 s at 100 Hz, 62 ms at 1 kHz.
pub const H: usize = 64;
pub type Nav<T> = FlightNavigator<T, H>;

const START: Position = Position {
    lat_rad: 0.6458,
    lon_rad: 2.2166,
    alt_m: 3000.0,
};
const SPEED_M_S: f64 = 200.0;
const THETA: [f64; 3] = [0.006, -0.004, 0.008];
const DROP_S: f64 = 0.4;
pub const FLY_S: f64 = 2.0;
/// Master samples at 50 Hz.
const MASTER_HZ: u64 = 50;

/// A small deterministic generator for the per-tick draws of one case.
pub struct Draws(pub u64);

impl Draws {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    pub fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    pub fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
    pub fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

/// One case's schedule (drawn by proptest).
#[derive(Debug, Clone, Copy)]
pub struct Schedule {
    pub rate_hz: u64,
    start_us: u64,
    pub carry_s: f64,
    pub coast_s: f64,
    /// Largest master latency, as a fraction of what the history reaches (≤ 0.1 s).
    pub latency_frac: f64,
    pub master_loss: f64,
    pub p_baro: f64,
    pub p_los: f64,
    /// Probability that a LOS tick carries a baro sample too (coinciding).
    pub p_coincide: f64,
    /// Largest age of a baro sample at its arrival, s.
    pub baro_age_max_s: f64,
    /// A stretch of LOS samples on every tick (s; 0: none): the held sample waits.
    pub los_burst_s: f64,
    /// No baro sample after the burst's first tick while it lasts: the held one expires.
    pub quiet_burst: bool,
    pub hostile: u32,
    pub seed: u64,
}

pub fn schedule() -> impl Strategy<Value = Schedule> {
    (
        prop::sample::select(vec![100_u64, 125, 200, 250, 400, 500, 1000]),
        prop_oneof![Just(0_u64), 1_u64..40],
        (0.8..1.6f64, 0.1..0.5f64, 0.1..1.0f64, 0.0..0.3f64),
        (0.02..1.0f64, 0.01..0.4f64, 0.0..1.0f64, 0.0..0.2f64),
        (
            prop_oneof![Just(0.0), 0.2..1.6f64],
            any::<bool>(),
            0_u32..12,
            any::<u64>(),
        ),
    )
        .prop_map(|(rate_hz, hours, a, b, c)| Schedule {
            rate_hz,
            start_us: hours * 3_600_000_000 + hours * 7_919,
            carry_s: a.0,
            coast_s: a.1,
            latency_frac: a.2,
            master_loss: a.3,
            p_baro: b.0,
            p_los: b.1,
            p_coincide: b.2,
            baro_age_max_s: b.3,
            // A quiet burst outlasts the baro model's age limit.
            los_burst_s: if c.1 && c.0 > 0.0 {
                1.05 + 0.3 * c.0
            } else {
                c.0
            },
            quiet_burst: c.1,
            hostile: c.2,
            seed: c.3 | 1,
        })
}

pub fn landmark_position() -> Position {
    Position {
        lat_rad: START.lat_rad + 30_000.0 / 6_360_000.0,
        lon_rad: START.lon_rad,
        alt_m: 0.0,
    }
}

pub fn config<T: Real>(s: &Schedule) -> NavigatorConfig<T> {
    let dt = 1.0 / s.rate_hz as f64;
    let mut alignment = TaConfig::<T>::flight(PaperCase::Case1);
    alignment.dt_s = T::lit(dt);
    alignment.time_tolerance_s = T::lit(0.1 * dt);
    alignment.max_gap_steps = (s.rate_hz as u32).min(MAX_GAP_STEPS);
    let mut ins = SeekerInsConfig::flight(Landmark::new(landmark_position()).unwrap());
    ins.imu_dt_s = T::lit(dt);
    ins.covariance_interval_steps = (s.rate_hz / 10) as u16;
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
        ins,
        imu_dt_s: T::lit(dt),
        max_master_latency_s: T::lit(max_latency_ticks(s) as f64 * dt),
        separation: SeparationCheck {
            specific_force_jump_m_s2: T::lit(4.0),
            confirm_window_s: T::lit(0.3),
            unsignalled_onset_s: T::lit(0.3),
            coast_s: T::lit(s.coast_s),
        },
        baro: BaroDamping::Ekf(BaroErrorModel {
            white_sigma_m: T::lit(1.0),
            markov_sigma_m: T::lit(5.0),
            markov_tau_s: T::lit(100.0),
            lag_s: T::lit(0.0),
        }),
        timeouts: AidTimeouts {
            master_s: T::lit(0.5),
            baro_s: T::lit(1.0),
            seeker_s: T::lit(2.0),
        },
    }
}

/// The largest master latency in ticks: the history's reach (`H − 2` ticks) and 0.1 s.
pub fn max_latency_ticks(s: &Schedule) -> u64 {
    (s.rate_hz / 10).min(H as u64 - 2)
}

/// The truth: a master INS (nav-core's `Ins` as a generator) in level flight, the missile on
/// its lever arm until the release, then its own INS (0 g for `DROP_S`, then level force).
pub struct World {
    dt_us: u64,
    start_us: u64,
    master: Ins<f64>,
    missile: Option<Ins<f64>>,
    log: Vec<(Timestamp, InsState<f64>)>,
    dth: Vector3<f64>,
    dv: Vector3<f64>,
    lever: Vector3<f64>,
    pub sep_tick: u64,
    pub drop_ticks: u64,
    pub k: u64,
}

impl World {
    pub fn new(s: &Schedule, lever: Vector3<f64>) -> Self {
        let dt = 1.0 / s.rate_hz as f64;
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
            dt_us: 1_000_000 / s.rate_hz,
            start_us: s.start_us,
            master: Ins::new(state, dt).unwrap(),
            missile: None,
            log: Vec::new(),
            dth: w_in * dt,
            dv: f * dt,
            lever,
            sep_tick: (s.carry_s * s.rate_hz as f64).round() as u64,
            drop_ticks: (DROP_S * s.rate_hz as f64).round() as u64,
            k: 0,
        }
    }

    pub fn time(&self) -> Timestamp {
        Timestamp::from_micros(self.start_us + self.k * self.dt_us)
    }

    fn c_m_s() -> nalgebra::Matrix3<f64> {
        exp_so3(&-Vector3::from(THETA))
    }

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

    /// Advances one tick: the slave's increment.
    pub fn step(&mut self) -> ImuIncrement<f64> {
        if self.k == self.sep_tick {
            self.missile = Some(Ins::new(self.missile_truth(), self.dt_us as f64 * 1e-6).unwrap());
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

    /// The master's sample of tick `k` (its time of validity), as the bus carries it.
    pub fn master_sample<T: Real>(&self, k: u64) -> MasterNav<T> {
        let (t, s) = self.log[(k - 1) as usize];
        let dt = self.dt_us as f64 * 1e-6;
        MasterNav {
            time: t,
            c_m_n: quat_to_dcm(&s.q_b_n).cast(),
            vel_ned_m_s: s.vel_ned_m_s.cast(),
            position: s.position,
            angular_rate_rad_s: (self.dth / dt).cast(),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: (self.dv / dt).cast(),
            attitude_sigma_rad: Vector3::new(T::lit(2e-4), T::lit(2e-4), T::lit(8e-4)),
            velocity_sigma_m_s: Vector3::new(T::lit(0.05), T::lit(0.05), T::lit(0.08)),
            position_sigma_m: Vector3::new(T::lit(3.0), T::lit(3.0), T::lit(5.0)),
        }
    }

    pub fn los<T: Real>(&self, rng: &mut Draws) -> LosSample<T> {
        let truth = self.missile_truth();
        let lm = Landmark::new(landmark_position()).unwrap();
        let d = landmark_vector_ned(&truth.position, &lm);
        let g = gimbal_angles_of(&(quat_to_dcm(&truth.q_b_n).transpose() * d));
        LosSample {
            time: self.time(),
            gimbal: GimbalAngles {
                pitch_rad: T::lit(g.pitch_rad + 1e-4 * (rng.unit() - 0.5)),
                yaw_rad: T::lit(g.yaw_rad + 1e-4 * (rng.unit() - 0.5)),
            },
        }
    }

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

/// The master bus: samples at `MASTER_HZ` in carry, lost at random, delivered in order with a
/// random latency up to the configured maximum.
pub struct Bus {
    queue: std::collections::VecDeque<(u64, u64)>,
    last_arrival: u64,
    every: u64,
    max_ticks: u64,
    draw_ticks: u64,
}

impl Bus {
    pub fn new(s: &Schedule) -> Self {
        let max_ticks = max_latency_ticks(s);
        Self {
            queue: Default::default(),
            last_arrival: 0,
            every: (s.rate_hz / MASTER_HZ).max(1),
            max_ticks,
            draw_ticks: (max_ticks as f64 * s.latency_frac) as u64,
        }
    }

    /// The sample arriving at the world's tick, if any.
    pub fn at<T: Real>(
        &mut self,
        w: &World,
        s: &Schedule,
        rng: &mut Draws,
    ) -> Option<MasterNav<T>> {
        let k = w.k;
        if k <= w.sep_tick && k % self.every == 0 && !rng.chance(s.master_loss) {
            let arrival = (k + rng.below(self.draw_ticks + 1)).max(self.last_arrival + 1);
            if arrival - k <= self.max_ticks {
                self.queue.push_back((arrival, k));
                self.last_arrival = arrival;
            }
        }
        let (_, epoch) = self.queue.front().filter(|(a, _)| *a == k).copied()?;
        self.queue.pop_front();
        Some(w.master_sample(epoch))
    }
}

/// This tick's valid baro and LOS samples (after the release signal).
/// `burst`: in the LOS burst, the baro quiet there, a baro sample at its start.
pub fn draw_aids<T: Real>(
    w: &World,
    s: &Schedule,
    rng: &mut Draws,
    last_baro: &mut Option<Timestamp>,
    burst: (bool, bool, bool),
) -> (Option<BaroSample<T>>, Option<LosSample<T>>) {
    if w.k <= w.sep_tick {
        return (None, None);
    }
    let los = (burst.0 || rng.chance(s.p_los)).then(|| w.los::<T>(rng));
    let want_baro = (rng.chance(s.p_baro) || (los.is_some() && rng.chance(s.p_coincide)))
        && !burst.1
        || burst.2;
    let now = w.time().as_micros();
    let age_us = (rng.unit() * s.baro_age_max_s * 1e6) as u64;
    let time = Timestamp::from_micros(now.saturating_sub(age_us));
    let baro = (want_baro && last_baro.is_none_or(|t| time > t)).then(|| {
        *last_baro = Some(time);
        BaroSample {
            time,
            altitude_m: T::lit(w.missile_truth().position.alt_m + 2.0 * (rng.unit() - 0.5)),
        }
    });
    (baro, los)
}

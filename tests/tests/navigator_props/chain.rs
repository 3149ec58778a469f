//! The synthetic chain of the navigator's property tests: the truth
//! (`nav_core::navigator::test_support::World`: level flight, the master INS, the missile on its lever
//! arm, the release and its drop) at the case's schedule, the navigator's configuration at
//! the case's IMU rate, the master bus and the per-tick baro and LOS draws.

use nalgebra::Vector3;
use nav_core::navigator::test_support::{self, baro_model, gimbal_truth, WorldSpec};
pub use nav_core::navigator::test_support::{imu_tick, World};
use nav_core::navigator::{BaroDamping, FlightNavigator, MasterNav, NavigatorConfig};
use nav_core::seeker_ins::{GimbalAngles, LosSample};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::MAX_GAP_STEPS;
use nav_core::vertical_channel::BaroSample;
use nav_core::Real;
use proptest::prelude::*;

/// The histories' depth: `(H − 2) · dt` reaches 0.6 s at 100 Hz, 62 ms at 1 kHz.
pub const H: usize = 64;
pub type Nav<T> = FlightNavigator<T, H>;

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

/// The chain's configuration (`test_support::config`, the EKF's baro damping) at the case's
/// IMU rate: the alignment's step, tolerance and gap, the EKF's step and covariance interval,
/// the master's latency; the release after `coast_s`.
pub fn config<T: Real>(s: &Schedule) -> NavigatorConfig<T> {
    let dt = 1.0 / s.rate_hz as f64;
    let mut c = test_support::config::<T>(BaroDamping::Ekf(baro_model()), s.coast_s);
    c.alignment.dt_s = T::lit(dt);
    c.alignment.time_tolerance_s = T::lit(0.1 * dt);
    c.alignment.max_gap_steps = (s.rate_hz as u32).min(MAX_GAP_STEPS);
    c.ins.imu_dt_s = T::lit(dt);
    c.ins.covariance_interval_steps = (s.rate_hz / 10) as u16;
    c.imu_dt_s = T::lit(dt);
    c.max_master_latency_s = T::lit(max_latency_ticks(s) as f64 * dt);
    c
}

/// The largest master latency in ticks: the history's reach (`H − 2` ticks) and 0.1 s.
pub fn max_latency_ticks(s: &Schedule) -> u64 {
    (s.rate_hz / 10).min(H as u64 - 2)
}

/// The case's world (`nav_core::navigator::test_support::World`, the chain nav-core's own tests fly):
/// the release after `carry_s`, the drop for `DROP_S`.
pub fn world(s: &Schedule, lever: Vector3<f64>) -> World {
    let rate = s.rate_hz as f64;
    World::new(&WorldSpec {
        rate_hz: s.rate_hz,
        start_us: s.start_us,
        sep_tick: (s.carry_s * rate).round() as u64,
        drop_ticks: (DROP_S * rate).round() as u64,
        lever_m: lever,
    })
}

/// The LOS sample at the world's tick: the true gimbal angles plus a small error.
pub fn los<T: Real>(w: &World, rng: &mut Draws) -> LosSample<T> {
    let g = gimbal_truth(&w.missile_truth());
    LosSample {
        time: w.time(),
        gimbal: GimbalAngles {
            pitch_rad: T::lit(g.pitch_rad + 1e-4 * (rng.unit() - 0.5)),
            yaw_rad: T::lit(g.yaw_rad + 1e-4 * (rng.unit() - 0.5)),
        },
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
        w.master_sample(epoch)
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
    let los = (burst.0 || rng.chance(s.p_los)).then(|| los::<T>(w, rng));
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

//! The walk over the IMU epochs of one run: the sensor errors drawn per run (in a fixed
//! order) and, epoch by epoch, the IMU sample, the master's messages over the bus, the release
//! signal, the baro and the seeker.

use super::{inside, inside_v, MasterMessage, MissionConfig, MissionFaults, MissionInputs, Tick};
use crate::rng::{normal, normal3, SimRng};
use crate::scenarios::mission::truth::{offset, MissionTruth};
use crate::scenarios::seeker_ins::sensors::Sensors;
use crate::scenarios::transfer_alignment::truth::ImuErrors;
use crate::scenarios::vertical_channel::sensors::Baro;
use crate::truth::{gimbal_angles_rad, landmark_vector_ned_m, rotation_from_vector};
use nalgebra::Vector3;
use nav_core::seeker_ins::{ClipFlags, GimbalAngles, ImuIncrement, LosSample, Position};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;
use rand::Rng;
use std::collections::VecDeque;

/// First-order Gauss-Markov processes per axis, exactly discretised at a fixed step.
#[derive(Debug, Clone)]
struct Markov3 {
    rho: f64,
    sigma: Vector3<f64>,
    x: Vector3<f64>,
}

impl Markov3 {
    fn new(sigma: [f64; 3], tau_s: f64, dt_s: f64, rng: &mut SimRng) -> Self {
        Self {
            rho: (-dt_s / tau_s).exp(),
            sigma: Vector3::from(sigma),
            x: normal3(rng, sigma),
        }
    }
    fn step(&mut self, rng: &mut SimRng) -> Vector3<f64> {
        let drive = (1.0 - self.rho * self.rho).sqrt();
        for i in 0..3 {
            self.x[i] = self.rho * self.x[i] + normal(rng, self.sigma[i] * drive);
        }
        self.x
    }
}

/// The seeker's search-and-lock state.
#[derive(Debug, Clone, Copy, Default)]
struct Lock {
    visible_since_s: Option<f64>,
}

impl Lock {
    /// Whether the seeker holds lock at `t_s` given that the landmark is `visible` now.
    fn update(&mut self, visible: bool, t_s: f64, acquire_s: f64) -> bool {
        if !visible {
            self.visible_since_s = None;
            return false;
        }
        let since = *self.visible_since_s.get_or_insert(t_s);
        t_s - since >= acquire_s - 1e-9
    }
}

impl Tick {
    /// A tick with no IMU increment (zero, ending at `time`) and no aids.
    fn empty(time: Timestamp) -> Self {
        Self {
            index: 0,
            imu: ImuIncrement::zero(time),
            clipped: ClipFlags::default(),
            master: Vec::new(),
            baro: None,
            seeker: None,
            separation: None,
        }
    }
}

/// One IMU epoch of the walk: its index in the truth's series, its time (s) and timestamp.
#[derive(Debug, Clone, Copy)]
struct Epoch {
    k: usize,
    t_s: f64,
    now: Timestamp,
}

/// The walk over the IMU epochs of one run: the drawn errors and the state the epochs carry.
pub(super) struct Walk<'a> {
    cfg: &'a MissionConfig,
    truth: &'a MissionTruth,
    faults: &'a MissionFaults,
    /// IMU interval, s.
    dt_s: f64,
    /// IMU epochs per master message, per baro sample, per seeker sample.
    master_every: usize,
    baro_every: usize,
    seeker_every: usize,
    pub(super) sensors: Sensors,
    master_imu: ImuErrors,
    att_err: Markov3,
    vel_err: Markov3,
    pos_err: Markov3,
    baro: Baro,
    landmark: Position,
    /// Release time, s, and as a timestamp.
    release_s: f64,
    release_time: Timestamp,
    /// When the release signal is sent, s.
    signal_at_s: f64,
    bus: VecDeque<MasterMessage>,
    last_arrival: Timestamp,
    lock: Lock,
    separation_sent: bool,
    /// The last baro reading, m (NaN before the first).
    last_baro_m: f64,
    /// Aids that arrived while IMU samples were lost, handed over with the next sample.
    pending: Tick,
}

impl<'a> Walk<'a> {
    /// Draws the run's sensor errors, in a fixed order.
    pub(super) fn draw(
        cfg: &'a MissionConfig,
        truth: &'a MissionTruth,
        faults: &'a MissionFaults,
        rng: &mut SimRng,
    ) -> Self {
        let dt_s = cfg.imu_dt_us() as f64 * 1e-6;
        let m = &truth.missile;
        let every = |r: f64| ((cfg.imu_hz / r).round() as usize).max(1);
        let (master_every, baro_every, seeker_every) = (
            every(cfg.master.rate_hz),
            every(cfg.baro.rate_hz),
            every(cfg.seeker.rate_hz),
        );
        let master_dt_s = master_every as f64 * dt_s;

        // Per-run draws, in a fixed order.
        let sensors = Sensors::draw_table3(&cfg.sensors, dt_s, rng);
        let master_imu = ImuErrors::draw(&cfg.master.imu, master_dt_s, rng);
        let mc = &cfg.master;
        let att_err = Markov3::new(mc.attitude_sigma_rad, mc.error_tau_s, master_dt_s, rng);
        let vel_err = Markov3::new(mc.velocity_sigma_m_s, mc.error_tau_s, master_dt_s, rng);
        let pos_err = Markov3::new(mc.position_sigma_m, mc.error_tau_s, master_dt_s, rng);
        let v_up0 = -m.vel_ned_m_s[0].z;
        let baro = Baro::new(
            &cfg.baro,
            true,
            dt_s,
            baro_every as f64 * dt_s,
            (m.position[0].alt_m, v_up0),
            rng,
        );
        let release_s = m.t_s[truth.release_index];
        Self {
            cfg,
            truth,
            faults,
            dt_s,
            master_every,
            baro_every,
            seeker_every,
            sensors,
            master_imu,
            att_err,
            vel_err,
            pos_err,
            baro,
            landmark: cfg.landmark_position(),
            release_s,
            release_time: m.imu[truth.release_index].time,
            signal_at_s: release_s + cfg.separation.delay_s,
            bus: VecDeque::new(),
            last_arrival: Timestamp::ZERO,
            lock: Lock::default(),
            separation_sent: false,
            last_baro_m: f64::NAN,
            pending: Tick::empty(Timestamp::ZERO),
        }
    }

    /// The master IMU's drawn accelerometer bias (master axes), m/s².
    pub(super) fn master_accel_bias_m_s2(&self) -> Vector3<f64> {
        self.master_imu.accel_bias_m_s2()
    }

    /// IMU epoch `k`: the sample and the aids since the previous one; none while in an IMU gap.
    pub(super) fn epoch(
        &mut self,
        k: usize,
        out: &mut MissionInputs,
        rng: &mut SimRng,
    ) -> Option<Tick> {
        let (truth, faults) = (self.truth, self.faults);
        let m = &truth.missile;
        let e = Epoch {
            k,
            t_s: m.t_s[k],
            now: m.imu[k].time,
        };
        let (t, now) = (e.t_s, e.now);
        let ff = &faults.imu_seeker;
        let in_gap = ff.in_imu_gap(t);
        // 1. The IMU sample over the interval since the last one sent (a gap's samples are
        // lost; the next one after it covers only its own interval, as a real IMU's does).
        let (imu, clipped) = self.sensors.sense(&m.imu[k], m.imu[k - 1].time, t, ff, rng);

        // 2. The master's message valid at this epoch (during carry).
        if k <= truth.release_index && k % self.master_every == 0 {
            let errors = self.master_message(e, rng);
            out.master_errors.push((now, errors));
        }
        while self.bus.front().is_some_and(|msg| msg.arrival <= now) {
            if let Some(msg) = self.bus.pop_front() {
                self.pending.master.push(msg);
            }
        }

        // 3. The release signal.
        if !self.separation_sent && t >= self.signal_at_s - 1e-9 {
            self.separation_sent = true;
            self.pending.separation = Some(self.release_time);
        }

        // 4. The baro (its lag follows the truth every IMU interval).
        self.baro
            .advance_lag(m.position[k].alt_m, m.position[k - 1].alt_m);
        if k % self.baro_every == 0 {
            let sample = self.baro_sample(e, rng);
            self.pending.baro = Some(sample);
        }

        // 5. The seeker, searching from a while after release; gimbal angles while locked.
        let search_from_s = self.release_s + self.cfg.seeker.search_after_release_s;
        if k % self.seeker_every == 0 && t >= search_from_s - 1e-9 {
            self.seek(e, in_gap, &mut out.first_lock_s, rng);
        }

        if in_gap {
            return None;
        }
        let tick = std::mem::replace(&mut self.pending, Tick::empty(now));
        Some(Tick {
            index: k,
            imu,
            clipped: ClipFlags {
                accel: clipped,
                gyro: false,
            },
            ..tick
        })
    }

    /// The master's message valid at epoch `e` onto the bus (unless lost); returns the master's
    /// navigation errors at it (attitude φ rad, velocity m/s, position NED m).
    fn master_message(&mut self, e: Epoch, rng: &mut SimRng) -> [Vector3<f64>; 3] {
        let (k, t, now) = (e.k, e.t_s, e.now);
        let (mc, faults) = (&self.cfg.master, self.faults);
        let air = &self.truth.aircraft;
        let dt_s = self.dt_s;
        let phi = self.att_err.step(rng);
        let dv = self.vel_err.step(rng);
        let dr = self.pos_err.step(rng);
        let rate = self.master_imu.gyro(&air.rate_b_rad_s[k], rng);
        let sf = self.master_imu.accel(&air.specific_force_b_m_s2[k], rng);
        let latency: f64 = rng.random_range(mc.latency_s[0]..=mc.latency_s[1]);
        let lost_draw: f64 = rng.random();
        let w_dot = if k + 1 < air.rate_b_rad_s.len() {
            (air.rate_b_rad_s[k + 1] - air.rate_b_rad_s[k - 1]) / (2.0 * dt_s)
        } else {
            (air.rate_b_rad_s[k] - air.rate_b_rad_s[k - 1]) / dt_s
        };
        let extra: f64 = faults
            .master_late
            .iter()
            .filter_map(|w| inside_v(w, t))
            .sum();
        let lost = lost_draw < mc.loss_probability
            || mc.dropouts_s.iter().any(|w| inside(w, t))
            || faults.master_missing.iter().any(|w| inside(w, t));
        if !lost {
            let arrival_us = now.as_micros() + ((latency + extra) * 1e6).round() as u64;
            let arrival = Timestamp::from_micros(arrival_us.max(self.last_arrival.as_micros()));
            self.last_arrival = arrival;
            self.bus.push_back(MasterMessage {
                time: now,
                arrival,
                c_m_n: rotation_from_vector(&(-phi)) * air.c_b_n[k],
                vel_ned_m_s: air.vel_ned_m_s[k] + dv,
                position: offset(&air.position[k], &dr),
                angular_rate_rad_s: rate,
                angular_accel_rad_s2: w_dot,
                specific_force_m_s2: sf,
                attitude_sigma_rad: Vector3::from(mc.attitude_sigma_rad),
                velocity_sigma_m_s: Vector3::from(mc.velocity_sigma_m_s),
                position_sigma_m: Vector3::from(mc.position_sigma_m),
            });
        }
        [phi, dv, dr]
    }

    /// The baro's reading at epoch `e`, with the spikes and freezes of the faults.
    fn baro_sample(&mut self, e: Epoch, rng: &mut SimRng) -> BaroSample<f64> {
        let (t, faults) = (e.t_s, self.faults);
        let mut z = self.baro.sample(rng);
        z += faults
            .baro_spike
            .iter()
            .filter_map(|w| inside_v(w, t))
            .sum::<f64>();
        if faults.baro_freeze.iter().any(|w| inside(w, t)) && self.last_baro_m.is_finite() {
            z = self.last_baro_m;
        }
        self.last_baro_m = z;
        BaroSample {
            time: e.now,
            altitude_m: z,
        }
    }

    /// The seeker at epoch `e`: search and lock (the first lock's time into `first_lock_s`),
    /// its gimbal angles into the pending tick while locked and not faulted.
    fn seek(&mut self, e: Epoch, in_gap: bool, first_lock_s: &mut Option<f64>, rng: &mut SimRng) {
        let (k, t) = (e.k, e.t_s);
        let (m, ff) = (&self.truth.missile, &self.faults.imu_seeker);
        let seeker = &self.cfg.seeker;
        let noise = self.sensors.seeker_noise(rng);
        let p = &m.position[k];
        let landmark = &self.landmark;
        let d = landmark_vector_ned_m(
            (p.lat_rad, p.lon_rad, p.alt_m),
            (landmark.lat_rad, landmark.lon_rad, landmark.alt_m),
        );
        let (pitch, yaw) = gimbal_angles_rad(&(m.c_b_n[k].transpose() * d));
        let limit = seeker.gimbal_limit_deg.to_radians();
        let visible = d.norm() <= seeker.lock_range_m && pitch.abs() <= limit && yaw.abs() <= limit;
        let locked = self.lock.update(visible, t, seeker.acquire_s);
        if locked && first_lock_s.is_none() {
            *first_lock_s = Some(t);
        }
        if locked && !in_gap && !ff.loss_of_lock(t) {
            let false_yaw = ff.false_lock_yaw_rad(t).unwrap_or(0.0);
            let bias = self.sensors.seeker_bias;
            self.pending.seeker = Some(LosSample {
                time: e.now,
                gimbal: GimbalAngles {
                    pitch_rad: pitch + bias.x + noise.x,
                    yaw_rad: yaw + bias.y + noise.y + false_yaw,
                },
            });
        }
    }
}

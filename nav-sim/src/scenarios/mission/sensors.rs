//! The flight computer's inputs on the mission, tick by tick: from a [`MissionTruth`] and a
//! seeded generator, per missile-IMU sample the increments (Table 3 errors, clipping flag)
//! and the aids that arrived since the previous sample — the master INS's messages over the
//! bus (late, sometimes lost), the release signal, the baro, the seeker's gimbal angles while
//! it holds lock.
//!
//! The models are the other scenarios' (one copy each): the missile IMU and the seeker's
//! gimbal-angle errors are the seeker scenario's `Sensors` (seeker paper Table 3), the baro
//! is the vertical-channel scenarios' `Baro` (first-order lag, first-order Gauss-Markov
//! error, white noise), the master's gyros and accelerometers the transfer alignment's
//! `ImuErrors`, the vibration burst that clips the accelerometers and the seeker faults the
//! seeker fault scenario's [`Faults`]. New here: the master's navigation errors (first-order
//! Gauss-Markov per axis with the σ the master reports), the bus, the seeker's search and
//! lock, the release signal.
//!
//! The random numbers are drawn in a fixed order per IMU epoch whatever the faults (a
//! message lost on the bus or a sample lost in an IMU gap still draws its numbers), so a
//! faulted run and its baseline share every other number.

use super::config::MissionConfig;
use super::truth::{offset, MissionTruth};
use crate::rng::{normal, normal3, SimRng};
use crate::scenarios::seeker_ins::fault::{Faults, Window};
use crate::scenarios::seeker_ins::sensors::Sensors;
use crate::scenarios::transfer_alignment::truth::ImuErrors;
use crate::scenarios::vertical_channel::sensors::Baro;
use crate::truth::{gimbal_angles_rad, landmark_vector_ned_m, rotation_from_vector};
use anyhow::Result;
use nalgebra::{Matrix3, Vector3};
use nav_core::seeker_ins::{ClipFlags, GimbalAngles, ImuIncrement, LosSample, Position};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;
use rand::Rng;
use serde::Deserialize;
use std::collections::VecDeque;

/// One message of the master INS as it arrives over the bus (f64; the run casts it).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MasterMessage {
    /// Time of validity.
    pub time: Timestamp,
    /// Arrival at the flight computer.
    pub arrival: Timestamp,
    /// Master attitude `Ĉ_m^n`.
    pub c_m_n: Matrix3<f64>,
    /// Master velocity, NED, m/s.
    pub vel_ned_m_s: Vector3<f64>,
    /// Master position.
    pub position: Position,
    /// Master body rate `ω_im^m` (its gyros), rad/s.
    pub angular_rate_rad_s: Vector3<f64>,
    /// Master angular acceleration, rad/s² (from its rate; taken as exact, as in the transfer
    /// alignment scenarios).
    pub angular_accel_rad_s2: Vector3<f64>,
    /// Master specific force (its accelerometers), m/s².
    pub specific_force_m_s2: Vector3<f64>,
    /// The σ the master reports: attitude per NED axis, rad.
    pub attitude_sigma_rad: Vector3<f64>,
    /// Velocity per NED axis, m/s.
    pub velocity_sigma_m_s: Vector3<f64>,
    /// Position per NED axis, m.
    pub position_sigma_m: Vector3<f64>,
}

/// What the flight computer gets at one missile-IMU sample.
#[derive(Debug, Clone, PartialEq)]
pub struct Tick {
    /// Index of the sample's epoch in the truth's series.
    pub index: usize,
    /// The IMU sample (increments over the interval since the previous sample sent).
    pub imu: ImuIncrement<f64>,
    /// Which instruments of the sample are at their range.
    pub clipped: ClipFlags,
    /// Master messages that arrived since the previous tick, in arrival order.
    pub master: Vec<MasterMessage>,
    /// A baro sample (altitude up, m) taken since the previous tick.
    pub baro: Option<BaroSample<f64>>,
    /// The seeker's gimbal angles, only while it reports lock.
    pub seeker: Option<LosSample<f64>>,
    /// The aircraft's release signal (it carries the release time).
    pub separation: Option<Timestamp>,
}

/// A time window of a fault with a value.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ValueWindow {
    /// Start, s.
    pub start_s: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// The fault's value (unit in the field that holds it).
    pub value: f64,
}

/// Faults injected into the inputs (none by default).
#[derive(Debug, Clone, Default)]
pub struct MissionFaults {
    /// IMU clipping bursts and gaps, seeker loss of lock and false lock.
    pub imu_seeker: Faults,
    /// Extra bus latency of the master messages valid in a window, s (`value`).
    pub master_late: Vec<ValueWindow>,
    /// Master messages valid in these windows are lost, `[start_s, duration_s]`.
    pub master_missing: Vec<Window>,
    /// Baro spikes: `value` m added to the readings in the window.
    pub baro_spike: Vec<ValueWindow>,
    /// Baro freezes: the reading held at its last value through the window.
    pub baro_freeze: Vec<Window>,
}

fn inside(w: &Window, t: f64) -> bool {
    t >= w[0] - 1e-9 && t < w[0] + w[1] - 1e-9
}

fn inside_v(w: &ValueWindow, t: f64) -> Option<f64> {
    inside(&[w.start_s, w.duration_s], t).then_some(w.value)
}

/// The run's drawn sensor errors and the inputs they gave.
#[derive(Debug, Clone)]
pub struct MissionInputs {
    /// The ticks, in time order (none for a sample lost in an IMU gap).
    pub ticks: Vec<Tick>,
    /// The missile IMU's accelerometer bias (m/s²) and gyro bias (rad/s), drawn.
    pub accel_bias_m_s2: Vector3<f64>,
    /// As `accel_bias_m_s2`, gyros, rad/s.
    pub gyro_bias_rad_s: Vector3<f64>,
    /// The accelerometers' `I + S + M` (scale factor and misalignment), drawn.
    pub accel_matrix: Matrix3<f64>,
    /// The gyros' `I + S + M`, drawn.
    pub gyro_matrix: Matrix3<f64>,
    /// The seeker's random-constant gimbal-angle errors (pitch, yaw), rad.
    pub gimbal_bias_rad: [f64; 2],
    /// The master's navigation error at each message's time of validity (attitude φ rad,
    /// velocity m/s, position NED m), for the statistics.
    pub master_errors: Vec<(Timestamp, [Vector3<f64>; 3])>,
    /// Time of the seeker's first lock, s (none: never locked).
    pub first_lock_s: Option<f64>,
}

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

/// The flight computer's inputs of one run: draws the sensor errors (missile IMU and seeker
/// Table 3, master instruments, master navigation errors, baro), then walks the IMU epochs.
pub fn inputs(
    cfg: &MissionConfig,
    truth: &MissionTruth,
    faults: &MissionFaults,
    rng: &mut SimRng,
) -> Result<MissionInputs> {
    cfg.check()?;
    let dt_us = cfg.imu_dt_us();
    let dt_s = dt_us as f64 * 1e-6;
    let m = &truth.missile;
    let air = &truth.aircraft;
    let n = m.t_s.len();
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
    let mut att_err = Markov3::new(mc.attitude_sigma_rad, mc.error_tau_s, master_dt_s, rng);
    let mut vel_err = Markov3::new(mc.velocity_sigma_m_s, mc.error_tau_s, master_dt_s, rng);
    let mut pos_err = Markov3::new(mc.position_sigma_m, mc.error_tau_s, master_dt_s, rng);
    let v_up0 = -m.vel_ned_m_s[0].z;
    let mut baro = Baro::new(
        &cfg.baro,
        true,
        dt_s,
        baro_every as f64 * dt_s,
        (m.position[0].alt_m, v_up0),
        rng,
    );

    let landmark = cfg.landmark_position();
    let release_s = m.t_s[truth.release_index];
    let release_time = m.imu[truth.release_index].time;
    let signal_at_s = release_s + cfg.separation.delay_s;
    let mut out = MissionInputs {
        ticks: Vec::with_capacity(n),
        accel_bias_m_s2: sensors.acc_b,
        gyro_bias_rad_s: sensors.gyr_b,
        accel_matrix: sensors.acc_m,
        gyro_matrix: sensors.gyr_m,
        gimbal_bias_rad: [sensors.seeker_bias.x, sensors.seeker_bias.y],
        master_errors: Vec::new(),
        first_lock_s: None,
    };
    let mut bus: VecDeque<MasterMessage> = VecDeque::new();
    let mut last_arrival = Timestamp::ZERO;
    let mut lock = Lock::default();
    let mut separation_sent = false;
    let mut last_baro_m = f64::NAN;
    // Aids that arrived while IMU samples were lost, handed over with the next sample.
    let mut pending = Tick {
        index: 0,
        imu: ImuIncrement::zero(Timestamp::ZERO),
        clipped: ClipFlags::default(),
        master: Vec::new(),
        baro: None,
        seeker: None,
        separation: None,
    };
    let ff = &faults.imu_seeker;

    for k in 1..n {
        let t = m.t_s[k];
        let now = m.imu[k].time;
        let in_gap = ff.in_imu_gap(t);
        // 1. The IMU sample over the interval since the last one sent (a gap's samples are
        // lost; the next one after it covers only its own interval, as a real IMU's does).
        let (imu, clipped) = sensors.sense(&m.imu[k], m.imu[k - 1].time, t, ff, rng);

        // 2. The master's message valid at this epoch (during carry).
        if k <= truth.release_index && k % master_every == 0 {
            let phi = att_err.step(rng);
            let dv = vel_err.step(rng);
            let dr = pos_err.step(rng);
            let rate = master_imu.gyro(&air.rate_b_rad_s[k], rng);
            let sf = master_imu.accel(&air.specific_force_b_m_s2[k], rng);
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
            out.master_errors.push((now, [phi, dv, dr]));
            if !lost {
                let arrival_us = now.as_micros() + ((latency + extra) * 1e6).round() as u64;
                let arrival = Timestamp::from_micros(arrival_us.max(last_arrival.as_micros()));
                last_arrival = arrival;
                bus.push_back(MasterMessage {
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
        }
        while bus.front().is_some_and(|msg| msg.arrival <= now) {
            if let Some(msg) = bus.pop_front() {
                pending.master.push(msg);
            }
        }

        // 3. The release signal.
        if !separation_sent && t >= signal_at_s - 1e-9 {
            separation_sent = true;
            pending.separation = Some(release_time);
        }

        // 4. The baro (its lag follows the truth every IMU interval).
        baro.advance_lag(m.position[k].alt_m, m.position[k - 1].alt_m);
        if k % baro_every == 0 {
            let mut z = baro.sample(rng);
            z += faults
                .baro_spike
                .iter()
                .filter_map(|w| inside_v(w, t))
                .sum::<f64>();
            if faults.baro_freeze.iter().any(|w| inside(w, t)) && last_baro_m.is_finite() {
                z = last_baro_m;
            }
            last_baro_m = z;
            pending.baro = Some(BaroSample {
                time: now,
                altitude_m: z,
            });
        }

        // 5. The seeker, searching from a while after release; gimbal angles while locked.
        if k % seeker_every == 0 && t >= release_s + cfg.seeker.search_after_release_s - 1e-9 {
            let noise = sensors.seeker_noise(rng);
            let p = &m.position[k];
            let d = landmark_vector_ned_m(
                (p.lat_rad, p.lon_rad, p.alt_m),
                (landmark.lat_rad, landmark.lon_rad, landmark.alt_m),
            );
            let (pitch, yaw) = gimbal_angles_rad(&(m.c_b_n[k].transpose() * d));
            let limit = cfg.seeker.gimbal_limit_deg.to_radians();
            let visible =
                d.norm() <= cfg.seeker.lock_range_m && pitch.abs() <= limit && yaw.abs() <= limit;
            let locked = lock.update(visible, t, cfg.seeker.acquire_s);
            if locked && out.first_lock_s.is_none() {
                out.first_lock_s = Some(t);
            }
            if locked && !in_gap && !ff.loss_of_lock(t) {
                let false_yaw = ff.false_lock_yaw_rad(t).unwrap_or(0.0);
                pending.seeker = Some(LosSample {
                    time: now,
                    gimbal: GimbalAngles {
                        pitch_rad: pitch + sensors.seeker_bias.x + noise.x,
                        yaw_rad: yaw + sensors.seeker_bias.y + noise.y + false_yaw,
                    },
                });
            }
        }

        if in_gap {
            continue;
        }
        let tick = std::mem::replace(
            &mut pending,
            Tick {
                index: 0,
                imu: ImuIncrement::zero(now),
                clipped: ClipFlags::default(),
                master: Vec::new(),
                baro: None,
                seeker: None,
                separation: None,
            },
        );
        out.ticks.push(Tick {
            index: k,
            imu,
            clipped: ClipFlags {
                accel: clipped,
                gyro: false,
            },
            ..tick
        });
    }
    Ok(out)
}

/// The missile's true position, velocity and attitude at a tick.
pub fn truth_at(truth: &MissionTruth, tick: &Tick) -> (Position, Vector3<f64>, Matrix3<f64>) {
    let m = &truth.missile;
    (
        m.position[tick.index],
        m.vel_ned_m_s[tick.index],
        m.c_b_n[tick.index],
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::run_rng;
    use crate::scenarios::mission::truth::simulate;

    pub(crate) fn load(name: &str) -> MissionConfig {
        let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
        let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
        for k in [
            "kind",
            "description",
            "runs",
            "seed",
            "navigator",
            "variants",
        ] {
            doc.remove(k);
        }
        MissionConfig::deserialize(toml::Value::Table(doc)).unwrap()
    }

    const RUNS: u64 = 200;

    /// One truth (the sensors' statistics do not depend on the flexure draw) and the inputs of
    /// `RUNS` sensor draws over it.
    fn draws(faults: &MissionFaults) -> (MissionConfig, MissionTruth, Vec<MissionInputs>) {
        let cfg = load("mission");
        let truth = simulate(
            &cfg.profile,
            &cfg.carry,
            cfg.imu_dt_us(),
            &mut run_rng(5, 0),
        )
        .unwrap();
        let runs = (0..RUNS)
            .map(|r| inputs(&cfg, &truth, faults, &mut run_rng(77, r)).unwrap())
            .collect();
        (cfg, truth, runs)
    }

    fn std(x: &[f64]) -> f64 {
        let m = x.iter().sum::<f64>() / x.len() as f64;
        (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
    }

    fn mean(x: &[f64]) -> f64 {
        x.iter().sum::<f64>() / x.len() as f64
    }

    fn ecef(p: &Position) -> Vector3<f64> {
        crate::truth::geodetic_to_ecef(p.lat_rad, p.lon_rad, p.alt_m)
    }

    /// The master's messages: their errors against the aircraft's truth have the σ the master
    /// reports (per axis, over runs and epochs) and its correlation time; the bus delivers
    /// them in order, 10-100 ms late, loses ≈ 1 %, and nothing after the release.
    #[test]
    fn master_messages_carry_the_errors_they_report_late_and_sometimes_lost() {
        let (cfg, truth, runs) = draws(&MissionFaults::default());
        let air = &truth.aircraft;
        let dt_us = cfg.imu_dt_us();
        let mut err: [Vec<f64>; 9] = Default::default();
        let (mut sent, mut delivered, mut latency) = (0usize, 0usize, Vec::new());
        let mut pairs = Vec::new();
        for inp in &runs {
            sent += inp.master_errors.len();
            let mut last_arrival = Timestamp::ZERO;
            for tick in &inp.ticks {
                for msg in &tick.master {
                    delivered += 1;
                    let j = (msg.time.as_micros() / dt_us) as usize;
                    assert!(j <= truth.release_index, "master message after release");
                    assert!(msg.arrival >= last_arrival, "out of order");
                    last_arrival = msg.arrival;
                    let at = tick.imu.time.as_micros();
                    assert!(at >= msg.arrival.as_micros() && at < msg.arrival.as_micros() + dt_us);
                    latency.push((msg.arrival.as_micros() - msg.time.as_micros()) as f64 * 1e-6);
                    // Attitude: Ĉ = exp(−[φ×]) C → φ = −log(Ĉ Cᵀ).
                    let phi = -crate::truth::vector_from_rotation(
                        &(msg.c_m_n * air.c_b_n[j].transpose()),
                    );
                    let dv = msg.vel_ned_m_s - air.vel_ned_m_s[j];
                    let p = &air.position[j];
                    let dr = crate::truth::ecef_to_ned(p.lat_rad, p.lon_rad)
                        * (ecef(&msg.position) - ecef(p));
                    for a in 0..3 {
                        err[a].push(phi[a] / msg.attitude_sigma_rad[a]);
                        err[3 + a].push(dv[a] / msg.velocity_sigma_m_s[a]);
                        err[6 + a].push(dr[a] / msg.position_sigma_m[a]);
                    }
                }
            }
            // Correlation over 60 s of the recorded errors (velocity north, normalised).
            let lag = (60.0 * cfg.master.rate_hz) as usize;
            for w in 0..inp.master_errors.len().saturating_sub(lag) {
                let a = inp.master_errors[w].1[1].x / cfg.master.velocity_sigma_m_s[0];
                let b = inp.master_errors[w + lag].1[1].x / cfg.master.velocity_sigma_m_s[0];
                pairs.push((a, b));
            }
        }
        for (i, e) in err.iter().enumerate() {
            let s = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
            assert!(
                (0.88..1.12).contains(&s),
                "component {i}: error / reported σ = {s}"
            );
        }
        let r = pairs.iter().map(|(a, b)| a * b).sum::<f64>() / pairs.len() as f64;
        let expect = (-60.0 / cfg.master.error_tau_s).exp();
        assert!(
            (r - expect).abs() < 0.1,
            "correlation over 60 s {r}, expected {expect}"
        );
        let lost = 1.0 - delivered as f64 / sent as f64;
        assert!((0.007..0.013).contains(&lost), "lost fraction {lost}");
        let (lo, hi) = (cfg.master.latency_s[0], cfg.master.latency_s[1]);
        assert!(latency.iter().all(|l| *l >= lo - 1e-6 && *l <= hi + 1e-6));
        // A FIFO bus: a message waits for the one before it, so the mean is above the
        // uniform draw's (measured 63 ms for 10-100 ms at 50 Hz).
        let m = mean(&latency);
        assert!(m > 0.5 * (lo + hi) + 0.002 && m < hi, "mean latency {m}");
    }

    /// The missile IMU: after the drawn scale factor, misalignment and bias are taken out of
    /// the increments, what remains is white with the Table 3 density; across runs the drawn
    /// biases, scale factors and misalignments have the Table 3 σ.
    #[test]
    fn missile_imu_has_the_table3_errors() {
        let (cfg, truth, runs) = draws(&MissionFaults::default());
        let s = &cfg.sensors;
        let g0 = 9.806_65;
        let h = 1.0 / cfg.imu_hz;
        let (mut wv, mut wth, mut lag1) = (Vec::new(), Vec::new(), 0.0);
        let mut prev: Option<f64> = None;
        for inp in runs.iter().take(20) {
            for tick in &inp.ticks {
                let inc = &truth.missile.imu[tick.index];
                let rv = tick.imu.delta_v_m_s
                    - inp.accel_matrix * inc.delta_v_m_s
                    - inp.accel_bias_m_s2 * h;
                let rt = tick.imu.delta_theta_rad
                    - inp.gyro_matrix * inc.delta_theta_rad
                    - inp.gyro_bias_rad_s * h;
                if let Some(p) = prev {
                    lag1 += p * rv.x;
                }
                prev = Some(rv.x);
                wv.extend(rv.iter());
                wth.extend(rt.iter());
            }
        }
        let sd_v = s.accel_noise_ug_rt_hz * 1e-6 * g0 * h.sqrt();
        let sd_th = s.gyro_arw_deg_rt_h.to_radians() / 60.0 * h.sqrt();
        assert!(
            (std(&wv) / sd_v - 1.0).abs() < 0.02,
            "{} vs {sd_v}",
            std(&wv)
        );
        assert!((std(&wth) / sd_th - 1.0).abs() < 0.02);
        let rho = lag1 / (wv.len() as f64 / 3.0) / (sd_v * sd_v);
        assert!(
            rho.abs() < 0.03,
            "lag-1 correlation of the accelerometer noise {rho}"
        );
        let pick = |f: &dyn Fn(&MissionInputs) -> Vec<f64>| -> f64 {
            std(&runs.iter().flat_map(f).collect::<Vec<_>>())
        };
        let checks = [
            (
                pick(&|r| r.accel_bias_m_s2.iter().copied().collect()),
                s.accel_bias_ug * 1e-6 * g0,
            ),
            (
                pick(&|r| r.gyro_bias_rad_s.iter().copied().collect()),
                s.gyro_bias_deg_h.to_radians() / 3600.0,
            ),
            (
                pick(&|r| (0..3).map(|i| r.accel_matrix[(i, i)] - 1.0).collect()),
                s.accel_scale_factor_ppm * 1e-6,
            ),
            (
                pick(&|r| vec![r.gyro_matrix[(0, 1)], r.gyro_matrix[(2, 0)]]),
                s.gyro_misalignment_arcsec.to_radians() / 3600.0,
            ),
        ];
        for (i, (got, want)) in checks.iter().enumerate() {
            assert!(
                (got / want - 1.0).abs() < 0.12,
                "check {i}: {got} vs {want}"
            );
        }
    }

    /// The baro: in level cruise its error has the σ of the correlated and white parts and no
    /// mean; in the steady descent the lag shows as a mean error of −lag · ḣ.
    #[test]
    fn baro_has_correlated_error_white_noise_and_lag() {
        let (cfg, truth, runs) = draws(&MissionFaults::default());
        let m = &truth.missile;
        let (mut level, mut descent, mut lag_expect) = (Vec::new(), Vec::new(), Vec::new());
        for inp in &runs {
            for tick in &inp.ticks {
                let Some(b) = tick.baro else { continue };
                let k = tick.index;
                let e = b.altitude_m - m.position[k].alt_m;
                let t = m.t_s[k];
                if (170.0..310.0).contains(&t) {
                    level.push(e);
                }
                if (105.0..135.0).contains(&t) {
                    descent.push(e);
                    lag_expect.push(cfg.baro.lag_s * m.vel_ned_m_s[k].z);
                }
            }
        }
        let want = cfg.baro.markov_sigma_m.hypot(cfg.baro.noise_m);
        assert!(
            (std(&level) / want - 1.0).abs() < 0.1,
            "{} vs {want}",
            std(&level)
        );
        assert!(mean(&level).abs() < 0.5, "level mean {}", mean(&level));
        let lag = mean(&lag_expect);
        assert!(
            lag > 4.0,
            "the descent is steep enough to show the lag: {lag} m"
        );
        let d = mean(&descent);
        assert!(
            (d - lag).abs() < 0.6,
            "descent mean error {d} vs lag × sink rate {lag}"
        );
    }

    /// The seeker reports only while locked: after the landmark has been in range and in the
    /// field of regard for the acquisition time; its angles carry the drawn random-constant
    /// error and white noise of Table 3.
    #[test]
    fn seeker_reports_only_in_lock_with_table3_errors() {
        let (cfg, truth, runs) = draws(&MissionFaults::default());
        let m = &truth.missile;
        let lm = cfg.landmark_position();
        let los = |k: usize| {
            let p = &m.position[k];
            landmark_vector_ned_m(
                (p.lat_rad, p.lon_rad, p.alt_m),
                (lm.lat_rad, lm.lon_rad, lm.alt_m),
            )
        };
        // First time the landmark is in range, from the truth.
        let in_range_s = (0..m.t_s.len())
            .find(|k| los(*k).norm() <= cfg.seeker.lock_range_m)
            .map(|k| m.t_s[k])
            .unwrap();
        let mut resid = Vec::new();
        let mut bias_err = Vec::new();
        for inp in &runs {
            let first = inp.first_lock_s.unwrap();
            assert!(
                first >= in_range_s + cfg.seeker.acquire_s - 1e-6
                    && first < in_range_s + cfg.seeker.acquire_s + 1.0 / cfg.seeker.rate_hz + 1e-6,
                "first lock {first}, in range {in_range_s}"
            );
            let mut e = Vec::new();
            for tick in &inp.ticks {
                let Some(s) = tick.seeker else { continue };
                let k = tick.index;
                assert!(m.t_s[k] >= first - 1e-9);
                let d = los(k);
                assert!(d.norm() <= cfg.seeker.lock_range_m);
                let (p, y) = gimbal_angles_rad(&(m.c_b_n[k].transpose() * d));
                e.push((s.gimbal.pitch_rad - p, s.gimbal.yaw_rad - y));
            }
            assert!(e.len() > 500, "{} seeker samples", e.len());
            let mp = mean(&e.iter().map(|v| v.0).collect::<Vec<_>>());
            bias_err.push(mp - inp.gimbal_bias_rad[0]);
            resid.extend(e.iter().map(|v| v.0 - inp.gimbal_bias_rad[0]));
            resid.extend(e.iter().map(|v| v.1 - inp.gimbal_bias_rad[1]));
        }
        let sd = cfg.sensors.seeker_noise_deg.to_radians();
        assert!(
            (std(&resid) / sd - 1.0).abs() < 0.03,
            "{} vs {sd}",
            std(&resid)
        );
        // The per-run mean error is the drawn bias (to the noise's σ/√n).
        assert!(std(&bias_err) < 0.2 * cfg.sensors.seeker_bias_deg.to_radians());
    }

    /// Faults in the chain: messages valid in a missing window never arrive, late ones arrive
    /// late; an IMU gap removes its ticks but hands the aids that came during it to the next
    /// tick; a baro freeze holds the reading and a spike offsets it; every other number is the
    /// baseline's.
    #[test]
    fn injected_faults_change_only_what_they_inject() {
        let cfg = load("mission");
        let truth = simulate(
            &cfg.profile,
            &cfg.carry,
            cfg.imu_dt_us(),
            &mut run_rng(5, 0),
        )
        .unwrap();
        let base = inputs(&cfg, &truth, &MissionFaults::default(), &mut run_rng(3, 1)).unwrap();
        let faults = MissionFaults {
            imu_seeker: Faults {
                imu_gap: vec![[30.0, 0.5]],
                ..Faults::default()
            },
            master_late: vec![ValueWindow {
                start_s: 40.0,
                duration_s: 2.0,
                value: 0.3,
            }],
            master_missing: vec![[50.0, 3.0]],
            baro_spike: vec![ValueWindow {
                start_s: 120.0,
                duration_s: 1.0,
                value: 50.0,
            }],
            baro_freeze: vec![[150.0, 5.0]],
        };
        let f = inputs(&cfg, &truth, &faults, &mut run_rng(3, 1)).unwrap();
        assert_eq!(base.ticks.len() - f.ticks.len(), 50, "0.5 s gap at 100 Hz");
        let msgs = |i: &MissionInputs| -> Vec<MasterMessage> {
            i.ticks.iter().flat_map(|t| t.master.clone()).collect()
        };
        let (mb, mf) = (msgs(&base), msgs(&f));
        let missing = mb
            .iter()
            .filter(|m| (50.0..53.0).contains(&m.time.as_secs_f64()))
            .count();
        assert!(missing > 100);
        assert_eq!(
            mb.len() - mf.len(),
            missing,
            "the gap loses no master message"
        );
        for m in &mf {
            let t = m.time.as_secs_f64();
            assert!(!(50.0..53.0 - 1e-9).contains(&t));
            let late = (m.arrival.as_micros() - m.time.as_micros()) as f64 * 1e-6;
            if (40.0..42.0 - 1e-9).contains(&t) {
                assert!(late >= 0.31 - 1e-6, "late by {late}");
            }
        }
        let baro = |i: &MissionInputs, t: f64| {
            i.ticks
                .iter()
                .filter_map(|k| k.baro)
                .find(|b| (b.time.as_secs_f64() - t).abs() < 1e-6)
                .unwrap()
                .altitude_m
        };
        assert!((baro(&f, 120.4) - baro(&base, 120.4) - 50.0).abs() < 1e-9);
        assert_eq!(baro(&f, 151.0), baro(&f, 154.0));
        assert_eq!(baro(&f, 200.0), baro(&base, 200.0));
    }
}

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
use super::truth::MissionTruth;
use crate::rng::SimRng;
use crate::scenarios::seeker_ins::injection::{Faults, Window};
use anyhow::Result;
use nalgebra::{Matrix3, Vector3};
use nav_core::seeker_ins::{ClipFlags, ImuIncrement, LosSample, Position};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;
use serde::Deserialize;
use walk::Walk;

mod walk;

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
    /// The master IMU's accelerometer bias (master axes), m/s², drawn.
    pub master_accel_bias_m_s2: Vector3<f64>,
    /// The master's navigation error at each message's time of validity (attitude φ rad,
    /// velocity m/s, position NED m), for the statistics.
    pub master_errors: Vec<(Timestamp, [Vector3<f64>; 3])>,
    /// Time of the seeker's first lock, s (none: never locked).
    pub first_lock_s: Option<f64>,
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
    let n = truth.missile.t_s.len();
    let mut walk = Walk::draw(cfg, truth, faults, rng);
    let sensors = &walk.sensors;
    let mut out = MissionInputs {
        ticks: Vec::with_capacity(n),
        accel_bias_m_s2: sensors.acc_b,
        gyro_bias_rad_s: sensors.gyr_b,
        accel_matrix: sensors.acc_m,
        gyro_matrix: sensors.gyr_m,
        gimbal_bias_rad: [sensors.seeker_bias.x, sensors.seeker_bias.y],
        master_accel_bias_m_s2: walk.master_accel_bias_m_s2(),
        master_errors: Vec::new(),
        first_lock_s: None,
    };
    for k in 1..n {
        if let Some(tick) = walk.epoch(k, &mut out, rng) {
            out.ticks.push(tick);
        }
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
mod tests;

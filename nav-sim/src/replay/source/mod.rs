//! Flight-log sources for the replay: a directory of CSV files in the documented schema, or a
//! PX4 ULog, both read as one time-ordered stream of [`LogEvent`]s without loading the log
//! into memory (hour-long logs of hundreds of MB replay in constant memory).
//!
//! CSV schema (one file per stream, header row, other columns ignored):
//!
//! | file | columns |
//! | --- | --- |
//! | `imu.csv` | `t_s`, `f_down_m_s2` (down component of the specific force, NED, ≈ −9.8 at rest), optional `acc_{x,y,z}_m_s2` and `gyro_{x,y,z}_rad_s` (body axes forward-right-down), `q_{w,x,y,z}` (the autopilot's attitude, body → NED, Hamilton, scalar first) |
//! | `baro.csv` | `t_s`, `baro_alt_m` |
//! | `gnss.csv` | `t_s`, `gnss_alt_m`, `gnss_vd_m_s` (down positive), optional `gnss_lat_deg`, `gnss_lon_deg`, optional `gnss_vn_m_s`, `gnss_ve_m_s` |
//! | `estimate.csv` | `t_s`, `est_alt_m`, `est_vd_m_s` (the autopilot's own estimate), optional `est_vn_m_s`, `est_ve_m_s` |
//!
//! Optional columns come in groups (the three axes, the four quaternion components, latitude
//! and longitude, the two horizontal velocities): a group is used whole or, if absent, not at
//! all; part of a group is an error naming the missing column.
//!
//! ULog topics (instance 0): `sensor_combined` (`accelerometer_m_s2`, rotated to NED with the
//! latest `vehicle_attitude.q`, and `gyro_rad`, both body FRD), `vehicle_attitude` (`q`,
//! valid at `timestamp_sample`, with `quat_reset_counter` and `delta_q_reset`),
//! `vehicle_air_data.baro_alt_meter`, `vehicle_gps_position` (`altitude_msl_m` or the older `alt`
//! in mm, `vel_d_m_s`, latitude and longitude, `vel_n_m_s`/`vel_e_m_s` where `vel_ned_valid`;
//! used once `fix_type` ≥ 3), `vehicle_local_position` (`z`, `vz`, and `vx`/`vy` where
//! `v_xy_valid`: the autopilot's estimate).
//!
//! Every error names the file, the topic or column and the line or time stamp.

use anyhow::{anyhow, bail, Context, Result};
use nav_core::Timestamp;
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
mod csv_dir;
mod ulog;

pub use csv_dir::CsvLog;
pub use ulog::ULogLog;

/// Which stream an event belongs to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Stream {
    /// Specific force (and attitude) at the IMU rate.
    Imu,
    /// Barometric altitude.
    Baro,
    /// GNSS altitude and vertical velocity.
    Gnss,
    /// The autopilot's own altitude and vertical velocity estimate.
    Estimate,
    /// The autopilot's attitude estimate.
    Attitude,
}

impl Stream {
    /// All streams, in report order.
    pub const ALL: [Stream; 5] = [
        Stream::Imu,
        Stream::Baro,
        Stream::Gnss,
        Stream::Estimate,
        Stream::Attitude,
    ];
    /// Report name.
    pub fn name(self) -> &'static str {
        match self {
            Stream::Imu => "imu",
            Stream::Baro => "baro",
            Stream::Gnss => "gnss",
            Stream::Estimate => "estimate",
            Stream::Attitude => "attitude",
        }
    }
}

/// The IMU sample in body axes (forward-right-down), where the log has it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BodyImu {
    /// Specific force, body axes, m/s² (≈ (0, 0, −9.8) level at rest).
    pub acc_b_m_s2: [f64; 3],
    /// Angular rate, body axes, rad/s; `None` where the log has no gyro.
    pub gyro_b_rad_s: Option<[f64; 3]>,
}

/// The horizontal part of a velocity (NED), m/s.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HorizontalVelocity {
    /// North, m/s.
    pub vn_m_s: f64,
    /// East, m/s.
    pub ve_m_s: f64,
}

/// A GNSS fix's geodetic latitude and longitude, deg.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LatLon {
    /// Latitude, deg.
    pub lat_deg: f64,
    /// Longitude, deg.
    pub lon_deg: f64,
}

/// An attitude reset reported by the autopilot (PX4: `quat_reset_counter`, `delta_q_reset`):
/// from this sample on, `q_new = delta_q ⊗ q_old`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AttitudeReset {
    /// The autopilot's reset counter (it changes at every reset).
    pub counter: u32,
    /// The change of the last reset, (w, x, y, z).
    pub delta_q: [f64; 4],
}

/// One sample of the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LogEvent {
    /// IMU: down component of the specific force in NED, m/s², and the body-axes sample.
    Imu {
        /// Time of validity.
        t: Timestamp,
        /// Specific force, down component (NED), m/s² (≈ −g at rest).
        f_down_m_s2: f64,
        /// Accelerometer and gyro in body axes, where the log has them.
        body: Option<BodyImu>,
    },
    /// The autopilot's attitude, body (FRD) → NED, Hamilton, scalar first, unit norm.
    Attitude {
        /// Time of validity.
        t: Timestamp,
        /// q_b^n (w, x, y, z).
        q_b_n: [f64; 4],
        /// The autopilot's reset bookkeeping, where the log has it.
        reset: Option<AttitudeReset>,
    },
    /// Baro altitude, m (up).
    Baro {
        /// Time of validity.
        t: Timestamp,
        /// Barometric altitude, m.
        alt_m: f64,
    },
    /// GNSS altitude (m, up) and vertical velocity (m/s, down positive).
    Gnss {
        /// Time of validity.
        t: Timestamp,
        /// Altitude, m.
        alt_m: f64,
        /// Vertical velocity, down positive, m/s.
        vd_m_s: f64,
        /// Latitude and longitude, where the log has them.
        lat_lon: Option<LatLon>,
        /// Horizontal velocity, where the log has it (and marks it valid).
        v_ne: Option<HorizontalVelocity>,
    },
    /// The autopilot's estimate: altitude (m, up, its own datum) and vertical velocity (down).
    Estimate {
        /// Time of validity.
        t: Timestamp,
        /// Altitude, m.
        alt_m: f64,
        /// Vertical velocity, down positive, m/s.
        vd_m_s: f64,
        /// Horizontal velocity, where the log has it (and marks it valid).
        v_ne: Option<HorizontalVelocity>,
    },
}

impl LogEvent {
    /// The event's time stamp.
    pub fn time(&self) -> Timestamp {
        match *self {
            LogEvent::Imu { t, .. }
            | LogEvent::Baro { t, .. }
            | LogEvent::Gnss { t, .. }
            | LogEvent::Estimate { t, .. }
            | LogEvent::Attitude { t, .. } => t,
        }
    }
    /// The event's stream.
    pub fn stream(&self) -> Stream {
        match self {
            LogEvent::Imu { .. } => Stream::Imu,
            LogEvent::Baro { .. } => Stream::Baro,
            LogEvent::Gnss { .. } => Stream::Gnss,
            LogEvent::Estimate { .. } => Stream::Estimate,
            LogEvent::Attitude { .. } => Stream::Attitude,
        }
    }
}

/// A time-ordered stream of log events.
pub trait LogSource: Iterator<Item = Result<LogEvent>> {
    /// What is being read (for messages).
    fn describe(&self) -> String;
    /// What the reader found in the log that is not an error but a user should know (values
    /// that are not finite, by file and column; a ULog cut short), as JSON for the summary.
    fn findings(&self) -> serde_json::Value {
        serde_json::Value::Null
    }
}

/// Plausible sample intervals of each stream, s: a median interval outside this band means
/// the time column is not in seconds (or the file is not that stream).
fn plausible_interval_s(stream: Stream) -> (f64, f64) {
    match stream {
        Stream::Imu => (5.0e-5, 0.5),
        Stream::Baro | Stream::Estimate | Stream::Attitude => (1.0e-3, 5.0),
        Stream::Gnss => (1.0e-2, 10.0),
    }
}

/// Intervals a CSV file's time unit is judged on (its first rows).
const UNIT_CHECK_INTERVALS: usize = 32;

/// Two files whose first time stamps differ by more than this are on different clocks (or
/// in different units), s.
const MAX_START_SPREAD_S: f64 = 600.0;

/// "(t_s looks like ms)"-style hint for a time interval `x` that is `factor` too large.
fn unit_hint(x: f64, lo: f64, hi: f64) -> &'static str {
    if (lo..=hi).contains(&(x * 1e-3)) {
        " (`t_s` looks like milliseconds, not seconds)"
    } else if (lo..=hi).contains(&(x * 1e-6)) {
        " (`t_s` looks like microseconds, not seconds)"
    } else if (lo..=hi).contains(&(x * 1e-9)) {
        " (`t_s` looks like nanoseconds, not seconds)"
    } else {
        ""
    }
}

/// A quaternion whose norm is outside this band is not a unit quaternion (a logging or
/// convention error, not rounding).
const UNIT_NORM_BAND: std::ops::Range<f64> = 0.9..1.1;

/// Opens a log: a directory of CSV files, or a `.ulg` file.
pub fn open(path: &Path) -> Result<Box<dyn LogSource>> {
    if path.is_dir() {
        Ok(Box::new(CsvLog::open(path)?))
    } else if path.extension().is_some_and(|e| e == "ulg") {
        Ok(Box::new(ULogLog::open(path)?))
    } else if path.exists() {
        bail!(
            "{}: not a directory of CSV files nor a .ulg file",
            path.display()
        )
    } else {
        bail!("{}: no such file or directory", path.display())
    }
}

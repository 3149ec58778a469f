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

// ---------------------------------------------------------------------------------------------
// CSV

/// Optional column groups of each file, used whole or not at all.
const IMU_GROUPS: [&[&str]; 3] = [
    &["acc_x_m_s2", "acc_y_m_s2", "acc_z_m_s2"],
    &["gyro_x_rad_s", "gyro_y_rad_s", "gyro_z_rad_s"],
    &["q_w", "q_x", "q_y", "q_z"],
];
const GNSS_GROUPS: [&[&str]; 2] = [
    &["gnss_lat_deg", "gnss_lon_deg"],
    &["gnss_vn_m_s", "gnss_ve_m_s"],
];
const ESTIMATE_GROUPS: [&[&str]; 1] = [&["est_vn_m_s", "est_ve_m_s"]];

/// A quaternion whose norm is outside this band is not a unit quaternion (a logging or
/// convention error, not rounding).
const UNIT_NORM_BAND: std::ops::Range<f64> = 0.9..1.1;

/// One CSV file read line by line.
struct CsvStream {
    path: PathBuf,
    stream: Stream,
    lines: std::io::Lines<BufReader<File>>,
    line_no: usize,
    /// Column index of each required field.
    cols: Vec<usize>,
    /// Names of the required fields (messages).
    names: Vec<String>,
    /// Per optional group: the column indices, if the file has the group.
    groups: Vec<Option<Vec<usize>>>,
    last_t: Option<Timestamp>,
    /// An event formed from the same row, released next (the attitude of an `imu.csv` row).
    pending: Option<LogEvent>,
    /// Per required value column (after `t_s`): rows whose value is not finite, first line.
    non_finite: Vec<(u64, usize)>,
}

/// One parsed row: time stamp, required fields (`t_s` first), optional groups.
struct Row {
    t: Timestamp,
    values: Vec<f64>,
    groups: Vec<Option<Vec<f64>>>,
}

impl CsvStream {
    fn open(
        path: PathBuf,
        stream: Stream,
        required: &[&str],
        optional: &[&[&str]],
    ) -> Result<Self> {
        let file = File::open(&path).with_context(|| format!("{}: cannot open", path.display()))?;
        let mut lines = BufReader::new(file).lines();
        let header = lines
            .next()
            .ok_or_else(|| anyhow!("{}: empty file (no header row)", path.display()))?
            .with_context(|| format!("{}: reading the header", path.display()))?;
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        let find = |want: &str| names.iter().position(|n| *n == want);
        let mut cols = Vec::new();
        for want in required {
            let i = find(want).ok_or_else(|| {
                anyhow!(
                    "{}: missing column `{want}` (header: {header})",
                    path.display()
                )
            })?;
            cols.push(i);
        }
        let mut groups = Vec::new();
        for group in optional {
            let found: Vec<Option<usize>> = group.iter().map(|w| find(w)).collect();
            if found.iter().all(Option::is_none) {
                groups.push(None);
                continue;
            }
            if let Some(k) = found.iter().position(Option::is_none) {
                bail!(
                    "{}: missing column `{}` (the columns {} are used together; header: {header})",
                    path.display(),
                    group[k],
                    group.join(", ")
                );
            }
            groups.push(Some(found.into_iter().flatten().collect()));
        }
        Ok(Self {
            path,
            stream,
            lines,
            line_no: 1,
            cols,
            names: required.iter().map(|s| s.to_string()).collect(),
            groups,
            last_t: None,
            pending: None,
            non_finite: vec![(0, 0); required.len().saturating_sub(1)],
        })
    }

    /// The time-unit check before the replay: the median interval of the file's first rows
    /// must be plausible for the stream (rows that do not parse are left to the replay).
    fn check_time_unit(&self) -> Result<()> {
        let file = File::open(&self.path)
            .with_context(|| format!("{}: cannot open", self.path.display()))?;
        let c = self.cols[0];
        let mut last: Option<f64> = None;
        let mut v: Vec<f64> = Vec::with_capacity(UNIT_CHECK_INTERVALS);
        for line in BufReader::new(file).lines().skip(1) {
            let Ok(line) = line else { break };
            let Some(t) = line
                .split(',')
                .nth(c)
                .and_then(|x| x.trim().parse::<f64>().ok())
            else {
                continue;
            };
            if let Some(l) = last {
                if t > l {
                    v.push(t - l);
                }
            }
            last = Some(t);
            if v.len() >= UNIT_CHECK_INTERVALS {
                break;
            }
        }
        if v.len() < 3 {
            return Ok(());
        }
        v.sort_unstable_by(f64::total_cmp);
        let med_s = v[v.len() / 2];
        let (lo, hi) = plausible_interval_s(self.stream);
        if !(lo..=hi).contains(&med_s) {
            bail!(
                "{}: `t_s`: median interval {med_s} s over the first {} rows, expected {lo} … {hi} s for {} samples{}",
                self.path.display(),
                v.len() + 1,
                self.stream.name(),
                unit_hint(med_s, lo, hi)
            );
        }
        Ok(())
    }

    fn parse(&self, fields: &[&str], c: usize, name: &str) -> Result<f64> {
        let raw = fields.get(c).ok_or_else(|| {
            anyhow!(
                "{}: line {}: {} fields, column {} (`{name}`) missing",
                self.path.display(),
                self.line_no,
                fields.len(),
                c + 1
            )
        })?;
        raw.parse().map_err(|_| {
            anyhow!(
                "{}: line {}: column {} (`{name}`): `{raw}` is not a number",
                self.path.display(),
                self.line_no,
                c + 1
            )
        })
    }

    /// The next row or `None` at the end.
    fn next_row(&mut self, optional: &[&[&str]]) -> Result<Option<Row>> {
        loop {
            let Some(line) = self.lines.next() else {
                return Ok(None);
            };
            self.line_no += 1;
            let line = line.with_context(|| {
                format!("{}: line {}: unreadable", self.path.display(), self.line_no)
            })?;
            if line.trim().is_empty() {
                continue;
            }
            let fields: Vec<&str> = line.split(',').map(str::trim).collect();
            let mut values = Vec::with_capacity(self.cols.len());
            for (&c, name) in self.cols.iter().zip(&self.names) {
                values.push(self.parse(&fields, c, name)?);
            }
            if !values[0].is_finite() {
                bail!(
                    "{}: line {}: `t_s` is not finite",
                    self.path.display(),
                    self.line_no
                );
            }
            let mut groups = Vec::with_capacity(self.groups.len());
            for (g, names) in self.groups.iter().zip(optional) {
                groups.push(match g {
                    None => None,
                    Some(cols) => Some(
                        cols.iter()
                            .zip(names.iter())
                            .map(|(&c, name)| self.parse(&fields, c, name))
                            .collect::<Result<Vec<f64>>>()?,
                    ),
                });
            }
            let t = Timestamp::from_secs_f64(values[0]).map_err(|e| {
                anyhow!(
                    "{}: line {}: `t_s` = {}: {e}{}",
                    self.path.display(),
                    self.line_no,
                    values[0],
                    if values[0] > 1.0e10 {
                        " (looks like microseconds or nanoseconds, not seconds)"
                    } else {
                        ""
                    }
                )
            })?;
            for (k, v) in values.iter().enumerate().skip(1) {
                if !v.is_finite() {
                    let n = &mut self.non_finite[k - 1];
                    if n.0 == 0 {
                        n.1 = self.line_no;
                    }
                    n.0 += 1;
                }
            }
            if let Some(last) = self.last_t {
                if t < last {
                    bail!(
                        "{}: line {}: `t_s` goes backwards ({} s after {} s): time stamps must not decrease",
                        self.path.display(),
                        self.line_no,
                        t.as_secs_f64(),
                        last.as_secs_f64()
                    );
                }
            }
            self.last_t = Some(t);
            return Ok(Some(Row { t, values, groups }));
        }
    }

    fn optional(&self) -> &'static [&'static [&'static str]] {
        match self.stream {
            Stream::Imu => &IMU_GROUPS,
            Stream::Gnss => &GNSS_GROUPS,
            Stream::Estimate => &ESTIMATE_GROUPS,
            Stream::Baro | Stream::Attitude => &[],
        }
    }

    fn next_event(&mut self) -> Result<Option<LogEvent>> {
        if let Some(ev) = self.pending.take() {
            return Ok(Some(ev));
        }
        let Some(Row {
            t,
            values: v,
            groups: g,
        }) = self.next_row(self.optional())?
        else {
            return Ok(None);
        };
        // A reference group with a non-finite value is absent from that row (e.g. `nan` while
        // the receiver or the estimator marks it invalid).
        let finite = |k: usize| g[k].as_ref().filter(|v| v.iter().all(|x| x.is_finite()));
        let horizontal = |k: usize| {
            finite(k).map(|h| HorizontalVelocity {
                vn_m_s: h[0],
                ve_m_s: h[1],
            })
        };
        let axes = |k: usize| g[k].as_ref().map(|a| [a[0], a[1], a[2]]);
        Ok(Some(match self.stream {
            Stream::Imu => {
                if let Some(q) = finite(2) {
                    let n = q.iter().map(|x| x * x).sum::<f64>().sqrt();
                    if !UNIT_NORM_BAND.contains(&n) {
                        bail!(
                            "{}: line {}: `q_w`, `q_x`, `q_y`, `q_z` have norm {n} (not a unit quaternion)",
                            self.path.display(),
                            self.line_no
                        );
                    }
                    self.pending = Some(LogEvent::Attitude {
                        t,
                        q_b_n: [q[0] / n, q[1] / n, q[2] / n, q[3] / n],
                        reset: None,
                    });
                }
                LogEvent::Imu {
                    t,
                    f_down_m_s2: v[1],
                    body: axes(0).map(|acc_b_m_s2| BodyImu {
                        acc_b_m_s2,
                        gyro_b_rad_s: axes(1),
                    }),
                }
            }
            Stream::Baro => LogEvent::Baro { t, alt_m: v[1] },
            Stream::Gnss => LogEvent::Gnss {
                t,
                alt_m: v[1],
                vd_m_s: v[2],
                lat_lon: finite(0).map(|p| LatLon {
                    lat_deg: p[0],
                    lon_deg: p[1],
                }),
                v_ne: horizontal(1),
            },
            Stream::Estimate => LogEvent::Estimate {
                t,
                alt_m: v[1],
                vd_m_s: v[2],
                v_ne: horizontal(0),
            },
            Stream::Attitude => bail!("{}: no attitude file in the schema", self.path.display()),
        }))
    }
}

/// A directory of CSV files merged into one time-ordered stream (each file must be ordered).
pub struct CsvLog {
    dir: PathBuf,
    streams: Vec<CsvStream>,
    heads: Vec<Option<LogEvent>>,
    primed: bool,
}

impl CsvLog {
    /// Opens `dir/{imu,baro,gnss,estimate}.csv`; `imu.csv` and `baro.csv` are required, the
    /// other two optional (no velocity aid / no comparison without them).
    pub fn open(dir: &Path) -> Result<Self> {
        let mut streams = Vec::new();
        for (stream, file, cols, optional, required) in [
            (
                Stream::Imu,
                "imu.csv",
                &["t_s", "f_down_m_s2"][..],
                &IMU_GROUPS[..],
                true,
            ),
            (
                Stream::Baro,
                "baro.csv",
                &["t_s", "baro_alt_m"][..],
                &[][..],
                true,
            ),
            (
                Stream::Gnss,
                "gnss.csv",
                &["t_s", "gnss_alt_m", "gnss_vd_m_s"][..],
                &GNSS_GROUPS[..],
                false,
            ),
            (
                Stream::Estimate,
                "estimate.csv",
                &["t_s", "est_alt_m", "est_vd_m_s"][..],
                &ESTIMATE_GROUPS[..],
                false,
            ),
        ] {
            let path = dir.join(file);
            if !path.exists() {
                if required {
                    bail!("{}: missing (the replay needs it)", path.display());
                }
                continue;
            }
            let s = CsvStream::open(path, stream, cols, optional)?;
            s.check_time_unit()?;
            streams.push(s);
        }
        let heads = vec![None; streams.len()];
        Ok(Self {
            dir: dir.to_path_buf(),
            streams,
            heads,
            primed: false,
        })
    }
}

impl Iterator for CsvLog {
    type Item = Result<LogEvent>;
    fn next(&mut self) -> Option<Self::Item> {
        if !self.primed {
            self.primed = true;
            for (h, s) in self.heads.iter_mut().zip(self.streams.iter_mut()) {
                match s.next_event() {
                    Ok(e) => *h = e,
                    Err(e) => return Some(Err(e)),
                }
            }
            if let Err(e) = self.check_clocks() {
                return Some(Err(e));
            }
        }
        // The earliest head (ties: stream order, IMU first).
        let k = self
            .heads
            .iter()
            .enumerate()
            .filter_map(|(k, h)| h.map(|e| (e.time(), k)))
            .min()?
            .1;
        let ev = self.heads[k].take();
        match self.streams[k].next_event() {
            Ok(e) => self.heads[k] = e,
            Err(e) => return Some(Err(e)),
        }
        ev.map(Ok)
    }
}

impl CsvLog {
    /// The files' first time stamps must be on one clock in one unit (within
    /// [`MAX_START_SPREAD_S`] of `imu.csv`'s).
    fn check_clocks(&self) -> Result<()> {
        let (Some(imu), Some(Some(t_imu))) = (
            self.streams.first(),
            self.heads.first().map(|h| h.map(|e| e.time())),
        ) else {
            return Ok(());
        };
        for (s, h) in self.streams.iter().zip(&self.heads).skip(1) {
            let Some(t) = h.map(|e| e.time()) else {
                continue;
            };
            let (a, b) = (t.as_secs_f64(), t_imu.as_secs_f64());
            if (a - b).abs() > MAX_START_SPREAD_S {
                let ratio = if b > 0.0 { a / b } else { f64::NAN };
                let hint = if (500.0..2_000.0).contains(&ratio) {
                    " (this file's `t_s` looks like milliseconds)"
                } else if (5.0e5..2.0e6).contains(&ratio) {
                    " (this file's `t_s` looks like microseconds)"
                } else if (5.0e-4..2.0e-3).contains(&ratio) || (5.0e-7..2.0e-6).contains(&ratio) {
                    " (`imu.csv`'s `t_s` looks like ms or µs)"
                } else {
                    ""
                };
                bail!(
                    "{}: `t_s` starts at {a} s but {} starts at {b} s: the files are not on one clock in seconds{hint}",
                    s.path.display(),
                    imu.path.display()
                );
            }
        }
        Ok(())
    }
}

impl LogSource for CsvLog {
    fn describe(&self) -> String {
        format!("CSV log {}", self.dir.display())
    }
    fn findings(&self) -> serde_json::Value {
        let mut non_finite = Vec::new();
        for s in &self.streams {
            for ((n, line), name) in s.non_finite.iter().zip(s.names.iter().skip(1)) {
                if *n > 0 {
                    non_finite.push(serde_json::json!({
                        "file": s.path.file_name().map(|f| f.to_string_lossy().into_owned()),
                        "column": name,
                        "rows": n,
                        "first_line": line,
                    }));
                }
            }
        }
        serde_json::json!({ "non_finite_values": non_finite })
    }
}

// ---------------------------------------------------------------------------------------------
// ULog

/// How far behind the newest time stamp an event is held to restore time order across topics
/// (ULog writes each topic in order, but topics interleave with publication delays).
const ULOG_REORDER_US: u64 = 500_000;

#[derive(Debug, PartialEq)]
struct Held(LogEvent, u64);
impl Eq for Held {}
impl PartialOrd for Held {
    fn partial_cmp(&self, other: &Self) -> Option<std::cmp::Ordering> {
        Some(self.cmp(other))
    }
}
impl Ord for Held {
    fn cmp(&self, other: &Self) -> std::cmp::Ordering {
        // Min-heap on (time, arrival order).
        (other.0.time(), other.1).cmp(&(self.0.time(), self.1))
    }
}

/// The file reader under the ULog parser, noting when a read found the end of the file: the
/// parser fills a message cut short with zeros instead of failing, so a message read after
/// the end was seen is incomplete.
struct EofWatch {
    inner: BufReader<File>,
    hit: std::rc::Rc<std::cell::Cell<bool>>,
}

impl std::io::Read for EofWatch {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if n == 0 && !buf.is_empty() {
            self.hit.set(true);
        }
        Ok(n)
    }
}

/// A PX4 ULog read as a stream (`yule_log`), topics mapped to [`LogEvent`]s.
pub struct ULogLog {
    path: PathBuf,
    parser: yule_log::parser::ULogParser<EofWatch>,
    eof_hit: std::rc::Rc<std::cell::Cell<bool>>,
    held: BinaryHeap<Held>,
    arrivals: u64,
    newest_us: u64,
    done: bool,
    /// Latest attitude quaternion (w, x, y, z), body → NED.
    attitude: Option<[f64; 4]>,
    last_t: [Option<u64>; 5],
    seen: [bool; 5],
    /// The file ends inside a message (a log cut short, e.g. by a power loss): the time of
    /// the last complete sample, µs.
    truncated_after_us: Option<u64>,
    /// Values the loops read that are not finite: (topic.field) → (count, first time stamp µs).
    non_finite: std::collections::BTreeMap<&'static str, (u64, u64)>,
}

/// The fields the replay reads from each required topic (messages).
const NEEDED: [&str; 3] = [
    "`sensor_combined.accelerometer_m_s2`",
    "`vehicle_attitude.q` to rotate the accelerometer to NED",
    "`vehicle_air_data.baro_alt_meter`",
];

const TOPICS: [&str; 5] = [
    "sensor_combined",
    "vehicle_attitude",
    "vehicle_air_data",
    "vehicle_gps_position",
    "vehicle_local_position",
];

impl ULogLog {
    /// Opens a `.ulg` file.
    pub fn open(path: &Path) -> Result<Self> {
        let file = File::open(path).with_context(|| format!("{}: cannot open", path.display()))?;
        let eof_hit = std::rc::Rc::new(std::cell::Cell::new(false));
        let reader = EofWatch {
            inner: BufReader::new(file),
            hit: eof_hit.clone(),
        };
        let parser = yule_log::builder::ULogParserBuilder::new(reader)
            .set_subscription_allow_list(TOPICS)
            .build()
            .map_err(|e| anyhow!("{}: not a ULog file: {e}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            parser,
            eof_hit,
            held: BinaryHeap::new(),
            arrivals: 0,
            newest_us: 0,
            done: false,
            attitude: None,
            last_t: [None; 5],
            seen: [false; 5],
            truncated_after_us: None,
            non_finite: std::collections::BTreeMap::new(),
        })
    }

    fn field<'a>(
        &self,
        topic: &str,
        d: &'a yule_log::model::inst::Format,
        name: &str,
    ) -> Result<&'a yule_log::model::inst::FieldValue> {
        d.fields
            .iter()
            .find(|f| &*f.name == name)
            .map(|f| &f.value)
            .ok_or_else(|| {
                anyhow!(
                    "{}: topic `{topic}`: no field `{name}`",
                    self.path.display()
                )
            })
    }

    fn scalar(&self, topic: &str, d: &yule_log::model::inst::Format, name: &str) -> Result<f64> {
        use yule_log::model::inst::FieldValue as V;
        Ok(match self.field(topic, d, name)? {
            V::ScalarF32(v) => f64::from(*v),
            V::ScalarF64(v) => *v,
            V::ScalarI32(v) => f64::from(*v),
            V::ScalarU8(v) => f64::from(*v),
            V::ScalarI8(v) => f64::from(*v),
            V::ScalarU16(v) => f64::from(*v),
            V::ScalarI16(v) => f64::from(*v),
            V::ScalarU32(v) => f64::from(*v),
            V::ScalarU64(v) => *v as f64,
            V::ScalarI64(v) => *v as f64,
            V::ScalarBool(v) => f64::from(u8::from(*v)),
            other => bail!(
                "{}: topic `{topic}`: field `{name}` is {other:?}, expected a number",
                self.path.display()
            ),
        })
    }

    fn array(
        &self,
        topic: &str,
        d: &yule_log::model::inst::Format,
        name: &str,
        n: usize,
    ) -> Result<Vec<f64>> {
        use yule_log::model::inst::FieldValue as V;
        match self.field(topic, d, name)? {
            V::ArrayF32(v) if v.len() >= n => Ok(v[..n].iter().map(|x| f64::from(*x)).collect()),
            other => bail!(
                "{}: topic `{topic}`: field `{name}` is {other:?}, expected {n} floats",
                self.path.display()
            ),
        }
    }

    /// A field the older or newer message formats may lack: `None` when absent.
    fn optional_scalar(
        &self,
        topic: &str,
        d: &yule_log::model::inst::Format,
        name: &str,
    ) -> Result<Option<f64>> {
        if d.fields.iter().any(|f| &*f.name == name) {
            self.scalar(topic, d, name).map(Some)
        } else {
            Ok(None)
        }
    }

    /// An array field the message may lack: `None` when absent.
    fn optional_array(
        &self,
        topic: &str,
        d: &yule_log::model::inst::Format,
        name: &str,
        n: usize,
    ) -> Result<Option<Vec<f64>>> {
        if d.fields.iter().any(|f| &*f.name == name) {
            self.array(topic, d, name, n).map(Some)
        } else {
            Ok(None)
        }
    }

    /// `vehicle_attitude`: the attitude event (valid at `timestamp_sample` where the log has
    /// it), with the reset bookkeeping.
    fn attitude_event(
        &mut self,
        topic: &str,
        d: &yule_log::model::inst::Format,
        t_us: u64,
    ) -> Result<LogEvent> {
        let q = self.array(topic, d, "q", 4)?;
        let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
        if !UNIT_NORM_BAND.contains(&n) {
            bail!(
                "{}: topic `{topic}`: field `q` has norm {n} at {t_us} µs (not a unit quaternion)",
                self.path.display()
            );
        }
        let q_b_n = [q[0] / n, q[1] / n, q[2] / n, q[3] / n];
        self.attitude = Some(q_b_n);
        let sample_us = self
            .optional_scalar(topic, d, "timestamp_sample")?
            .map(|v| v as u64)
            .filter(|&s| s > 0 && s <= t_us)
            .unwrap_or(t_us);
        let reset = match (
            self.optional_scalar(topic, d, "quat_reset_counter")?,
            self.optional_array(topic, d, "delta_q_reset", 4)?,
        ) {
            (Some(c), Some(dq)) => Some(AttitudeReset {
                counter: c as u32,
                delta_q: [dq[0], dq[1], dq[2], dq[3]],
            }),
            _ => None,
        };
        Ok(LogEvent::Attitude {
            t: Timestamp::from_micros(sample_us),
            q_b_n,
            reset,
        })
    }

    /// `vehicle_gps_position` with a 3-D fix.
    fn gnss_event(
        &self,
        topic: &str,
        d: &yule_log::model::inst::Format,
        t: Timestamp,
    ) -> Result<LogEvent> {
        let alt_m = match self.optional_scalar(topic, d, "altitude_msl_m")? {
            Some(v) => v,
            None => self.scalar(topic, d, "alt")? * 1e-3,
        };
        let lat_lon = match self.optional_scalar(topic, d, "latitude_deg")? {
            Some(lat_deg) => Some(LatLon {
                lat_deg,
                lon_deg: self.scalar(topic, d, "longitude_deg")?,
            }),
            None => match self.optional_scalar(topic, d, "lat")? {
                // Older messages: degrees × 1e7 as integers.
                Some(lat) => Some(LatLon {
                    lat_deg: lat * 1e-7,
                    lon_deg: self.scalar(topic, d, "lon")? * 1e-7,
                }),
                None => None,
            },
        };
        let valid = self
            .optional_scalar(topic, d, "vel_ned_valid")?
            .unwrap_or(1.0)
            != 0.0;
        let v_ne = match (
            valid,
            self.optional_scalar(topic, d, "vel_n_m_s")?,
            self.optional_scalar(topic, d, "vel_e_m_s")?,
        ) {
            (true, Some(vn_m_s), Some(ve_m_s)) => Some(HorizontalVelocity { vn_m_s, ve_m_s }),
            _ => None,
        };
        Ok(LogEvent::Gnss {
            t,
            alt_m,
            vd_m_s: self.scalar(topic, d, "vel_d_m_s")?,
            lat_lon,
            v_ne,
        })
    }

    /// Maps one data message to at most one event.
    fn map(&mut self, d: &yule_log::model::inst::Format, t_us: u64) -> Result<Option<LogEvent>> {
        if d.multi_id_index.unwrap_or(0) != 0 {
            return Ok(None);
        }
        let topic: &str = &d.name;
        let Some(k) = TOPICS.iter().position(|x| *x == topic) else {
            return Ok(None);
        };
        if let Some(last) = self.last_t[k] {
            if t_us < last {
                bail!(
                    "{}: topic `{topic}`: field `timestamp` goes backwards ({t_us} µs after {last} µs)",
                    self.path.display()
                );
            }
        }
        self.last_t[k] = Some(t_us);
        self.seen[k] = true;
        let t = Timestamp::from_micros(t_us);
        let ev = match k {
            0 => {
                let Some(q) = self.attitude else {
                    return Ok(None); // no attitude yet: the down component is unknown
                };
                let a = self.array(topic, d, "accelerometer_m_s2", 3)?;
                let gyro_b_rad_s = self
                    .optional_array(topic, d, "gyro_rad", 3)?
                    .map(|g| [g[0], g[1], g[2]]);
                // Third row of C_b^n from q = (w, x, y, z) (body → NED).
                let [w, x, y, z] = q;
                let c20 = 2.0 * (x * z - w * y);
                let c21 = 2.0 * (y * z + w * x);
                let c22 = w * w - x * x - y * y + z * z;
                Some(LogEvent::Imu {
                    t,
                    f_down_m_s2: c20 * a[0] + c21 * a[1] + c22 * a[2],
                    body: Some(BodyImu {
                        acc_b_m_s2: [a[0], a[1], a[2]],
                        gyro_b_rad_s,
                    }),
                })
            }
            1 => Some(self.attitude_event(topic, d, t_us)?),
            2 => Some(LogEvent::Baro {
                t,
                alt_m: self.scalar(topic, d, "baro_alt_meter")?,
            }),
            3 => {
                if self.scalar(topic, d, "fix_type")? < 3.0 {
                    return Ok(None);
                }
                Some(self.gnss_event(topic, d, t)?)
            }
            _ => {
                let valid = self.optional_scalar(topic, d, "v_xy_valid")?.unwrap_or(1.0) != 0.0;
                let v_ne = if valid {
                    Some(HorizontalVelocity {
                        vn_m_s: self.scalar(topic, d, "vx")?,
                        ve_m_s: self.scalar(topic, d, "vy")?,
                    })
                } else {
                    None
                };
                Some(LogEvent::Estimate {
                    t,
                    alt_m: -self.scalar(topic, d, "z")?,
                    vd_m_s: self.scalar(topic, d, "vz")?,
                    v_ne,
                })
            }
        };
        if let Some(ev) = &ev {
            self.note_non_finite(ev, t_us);
        }
        Ok(ev)
    }

    /// Counts the values the loops read that are not finite, by topic and field.
    fn note_non_finite(&mut self, ev: &LogEvent, t_us: u64) {
        let fields: [(&'static str, f64); 2] = match *ev {
            LogEvent::Imu { f_down_m_s2, .. } => [
                ("sensor_combined.accelerometer_m_s2", f_down_m_s2),
                ("", 0.0),
            ],
            LogEvent::Baro { alt_m, .. } => [("vehicle_air_data.baro_alt_meter", alt_m), ("", 0.0)],
            LogEvent::Gnss { alt_m, vd_m_s, .. } => [
                ("vehicle_gps_position.altitude_msl_m", alt_m),
                ("vehicle_gps_position.vel_d_m_s", vd_m_s),
            ],
            LogEvent::Estimate { alt_m, vd_m_s, .. } => [
                ("vehicle_local_position.z", alt_m),
                ("vehicle_local_position.vz", vd_m_s),
            ],
            LogEvent::Attitude { .. } => return,
        };
        for (name, v) in fields {
            if !v.is_finite() {
                let e = self.non_finite.entry(name).or_insert((0, t_us));
                e.0 += 1;
            }
        }
    }

    /// Reads until an event can be released from the reorder buffer (or the file ends).
    fn fill(&mut self) -> Result<()> {
        while !self.done
            && self
                .held
                .peek()
                .is_none_or(|h| h.0.time().as_micros() + ULOG_REORDER_US > self.newest_us)
        {
            let end = match self.parser.next() {
                None => true,
                Some(Err(e)) => bail!("{}: corrupt ULog: {e}", self.path.display()),
                Some(Ok(_)) if self.eof_hit.get() => {
                    // The message was cut short (its missing bytes read as zeros).
                    if self.seen.iter().any(|s| *s) {
                        self.truncated_after_us = Some(self.newest_us);
                    }
                    true
                }
                Some(Ok(msg)) => {
                    self.take(msg)?;
                    false
                }
            };
            if end {
                self.done = true;
                for (k, seen) in self.seen.iter().enumerate() {
                    if !seen && k <= 2 {
                        bail!(
                            "{}: topic `{}` missing (the replay needs {}){}",
                            self.path.display(),
                            TOPICS[k],
                            NEEDED[k],
                            if self.truncated_after_us.is_some() {
                                " — the file ends inside a message"
                            } else {
                                ""
                            }
                        );
                    }
                }
            }
        }
        Ok(())
    }

    fn take(&mut self, msg: yule_log::model::msg::UlogMessage) -> Result<()> {
        use yule_log::model::msg::UlogMessage;
        if let UlogMessage::LoggedData(data) = msg {
            let t_us = data.data.timestamp.unwrap_or(data.timestamp);
            if let Some(ev) = self.map(&data.data, t_us)? {
                self.newest_us = self.newest_us.max(t_us);
                self.arrivals += 1;
                self.held.push(Held(ev, self.arrivals));
            }
        }
        Ok(())
    }
}

impl Iterator for ULogLog {
    type Item = Result<LogEvent>;
    fn next(&mut self) -> Option<Self::Item> {
        if let Err(e) = self.fill() {
            self.done = true;
            self.held.clear();
            return Some(Err(e));
        }
        self.held.pop().map(|h| Ok(h.0))
    }
}

impl LogSource for ULogLog {
    fn describe(&self) -> String {
        format!("ULog {}", self.path.display())
    }
    fn findings(&self) -> serde_json::Value {
        serde_json::json!({
            "non_finite_values": self.non_finite.iter().map(|(k, (n, t))| serde_json::json!({
                "topic_field": k, "samples": n, "first_timestamp_us": t,
            })).collect::<Vec<_>>(),
            "truncated": self.truncated_after_us.map(|t| serde_json::json!({
                "note": "the file ends inside a message (a log cut short): replayed up to the last complete one",
                "last_sample_us": t,
            })),
        })
    }
}

impl std::fmt::Debug for CsvLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CsvLog").field("dir", &self.dir).finish()
    }
}

impl std::fmt::Debug for ULogLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ULogLog")
            .field("path", &self.path)
            .field("held", &self.held.len())
            .finish()
    }
}

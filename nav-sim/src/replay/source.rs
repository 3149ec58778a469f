//! Flight-log sources for the replay: a directory of CSV files in the documented schema, or a
//! PX4 ULog, both read as one time-ordered stream of [`LogEvent`]s without loading the log
//! into memory (hour-long logs of hundreds of MB replay in constant memory).
//!
//! CSV schema (one file per stream, header row, other columns ignored):
//!
//! | file | columns |
//! | --- | --- |
//! | `imu.csv` | `t_s`, `f_down_m_s2` (down component of the specific force, NED, ≈ −9.8 at rest), optional `acc_{x,y,z}_m_s2`, `gyro_{x,y,z}_rad_s`, `q_{w,x,y,z}` (body → NED) |
//! | `baro.csv` | `t_s`, `baro_alt_m` |
//! | `gnss.csv` | `t_s`, `gnss_alt_m`, `gnss_vd_m_s` (down positive) |
//! | `estimate.csv` | `t_s`, `est_alt_m`, `est_vd_m_s` (the autopilot's own estimate) |
//!
//! ULog topics (instance 0): `sensor_combined` (`accelerometer_m_s2`, rotated to NED with the
//! latest `vehicle_attitude.q`), `vehicle_air_data.baro_alt_meter`,
//! `vehicle_gps_position` (`altitude_msl_m` or the older `alt` in mm, `vel_d_m_s`, used once
//! `fix_type` ≥ 3), `vehicle_local_position` (`z`, `vz`: the autopilot's estimate).
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
}

impl Stream {
    /// All streams, in report order.
    pub const ALL: [Stream; 4] = [Stream::Imu, Stream::Baro, Stream::Gnss, Stream::Estimate];
    /// Report name.
    pub fn name(self) -> &'static str {
        match self {
            Stream::Imu => "imu",
            Stream::Baro => "baro",
            Stream::Gnss => "gnss",
            Stream::Estimate => "estimate",
        }
    }
}

/// One sample of the log.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LogEvent {
    /// IMU: down component of the specific force in NED, m/s².
    Imu {
        /// Time of validity.
        t: Timestamp,
        /// Specific force, down component (NED), m/s² (≈ −g at rest).
        f_down_m_s2: f64,
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
    },
    /// The autopilot's estimate: altitude (m, up, its own datum) and vertical velocity (down).
    Estimate {
        /// Time of validity.
        t: Timestamp,
        /// Altitude, m.
        alt_m: f64,
        /// Vertical velocity, down positive, m/s.
        vd_m_s: f64,
    },
}

impl LogEvent {
    /// The event's time stamp.
    pub fn time(&self) -> Timestamp {
        match *self {
            LogEvent::Imu { t, .. }
            | LogEvent::Baro { t, .. }
            | LogEvent::Gnss { t, .. }
            | LogEvent::Estimate { t, .. } => t,
        }
    }
    /// The event's stream.
    pub fn stream(&self) -> Stream {
        match self {
            LogEvent::Imu { .. } => Stream::Imu,
            LogEvent::Baro { .. } => Stream::Baro,
            LogEvent::Gnss { .. } => Stream::Gnss,
            LogEvent::Estimate { .. } => Stream::Estimate,
        }
    }
}

/// A time-ordered stream of log events.
pub trait LogSource: Iterator<Item = Result<LogEvent>> {
    /// What is being read (for messages).
    fn describe(&self) -> String;
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

/// One CSV file read line by line.
struct CsvStream {
    path: PathBuf,
    stream: Stream,
    lines: std::io::Lines<BufReader<File>>,
    line_no: usize,
    /// Column index of each required field.
    cols: Vec<usize>,
    last_t: Option<Timestamp>,
}

impl CsvStream {
    fn open(path: PathBuf, stream: Stream, required: &[&str]) -> Result<Self> {
        let file = File::open(&path).with_context(|| format!("{}: cannot open", path.display()))?;
        let mut lines = BufReader::new(file).lines();
        let header = lines
            .next()
            .ok_or_else(|| anyhow!("{}: empty file (no header row)", path.display()))?
            .with_context(|| format!("{}: reading the header", path.display()))?;
        let names: Vec<&str> = header.split(',').map(str::trim).collect();
        let mut cols = Vec::new();
        for want in required {
            let i = names.iter().position(|n| n == want).ok_or_else(|| {
                anyhow!(
                    "{}: missing column `{want}` (header: {header})",
                    path.display()
                )
            })?;
            cols.push(i);
        }
        Ok(Self {
            path,
            stream,
            lines,
            line_no: 1,
            cols,
            last_t: None,
        })
    }

    /// The next row's required fields (`t_s` first) or `None` at the end.
    fn next_row(&mut self) -> Result<Option<(Timestamp, Vec<f64>)>> {
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
            for (k, &c) in self.cols.iter().enumerate() {
                let raw = fields.get(c).ok_or_else(|| {
                    anyhow!(
                        "{}: line {}: {} fields, column {} missing",
                        self.path.display(),
                        self.line_no,
                        fields.len(),
                        c + 1
                    )
                })?;
                let v: f64 = raw.parse().map_err(|_| {
                    anyhow!(
                        "{}: line {}: column {}: `{raw}` is not a number",
                        self.path.display(),
                        self.line_no,
                        c + 1
                    )
                })?;
                if !v.is_finite() && k == 0 {
                    bail!(
                        "{}: line {}: `t_s` is not finite",
                        self.path.display(),
                        self.line_no
                    );
                }
                values.push(v);
            }
            let t = Timestamp::from_secs_f64(values[0]).map_err(|e| {
                anyhow!(
                    "{}: line {}: `t_s` = {}: {e}",
                    self.path.display(),
                    self.line_no,
                    values[0]
                )
            })?;
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
            return Ok(Some((t, values)));
        }
    }

    fn next_event(&mut self) -> Result<Option<LogEvent>> {
        let Some((t, v)) = self.next_row()? else {
            return Ok(None);
        };
        Ok(Some(match self.stream {
            Stream::Imu => LogEvent::Imu {
                t,
                f_down_m_s2: v[1],
            },
            Stream::Baro => LogEvent::Baro { t, alt_m: v[1] },
            Stream::Gnss => LogEvent::Gnss {
                t,
                alt_m: v[1],
                vd_m_s: v[2],
            },
            Stream::Estimate => LogEvent::Estimate {
                t,
                alt_m: v[1],
                vd_m_s: v[2],
            },
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
        for (stream, file, cols, required) in [
            (Stream::Imu, "imu.csv", &["t_s", "f_down_m_s2"][..], true),
            (Stream::Baro, "baro.csv", &["t_s", "baro_alt_m"][..], true),
            (
                Stream::Gnss,
                "gnss.csv",
                &["t_s", "gnss_alt_m", "gnss_vd_m_s"][..],
                false,
            ),
            (
                Stream::Estimate,
                "estimate.csv",
                &["t_s", "est_alt_m", "est_vd_m_s"][..],
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
            streams.push(CsvStream::open(path, stream, cols)?);
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

impl LogSource for CsvLog {
    fn describe(&self) -> String {
        format!("CSV log {}", self.dir.display())
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

/// A PX4 ULog read as a stream (`yule_log`), topics mapped to [`LogEvent`]s.
pub struct ULogLog {
    path: PathBuf,
    parser: yule_log::parser::ULogParser<BufReader<File>>,
    held: BinaryHeap<Held>,
    arrivals: u64,
    newest_us: u64,
    done: bool,
    /// Latest attitude quaternion (w, x, y, z), body → NED.
    attitude: Option<[f64; 4]>,
    last_t: [Option<u64>; 5],
    seen: [bool; 5],
}

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
        let parser = yule_log::builder::ULogParserBuilder::new(BufReader::new(file))
            .set_subscription_allow_list(TOPICS)
            .build()
            .map_err(|e| anyhow!("{}: not a ULog file: {e}", path.display()))?;
        Ok(Self {
            path: path.to_path_buf(),
            parser,
            held: BinaryHeap::new(),
            arrivals: 0,
            newest_us: 0,
            done: false,
            attitude: None,
            last_t: [None; 5],
            seen: [false; 5],
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
        Ok(match k {
            0 => {
                let Some(q) = self.attitude else {
                    return Ok(None); // no attitude yet: the down component is unknown
                };
                let a = self.array(topic, d, "accelerometer_m_s2", 3)?;
                // Third row of C_b^n from q = (w, x, y, z) (body → NED).
                let [w, x, y, z] = q;
                let c20 = 2.0 * (x * z - w * y);
                let c21 = 2.0 * (y * z + w * x);
                let c22 = w * w - x * x - y * y + z * z;
                Some(LogEvent::Imu {
                    t,
                    f_down_m_s2: c20 * a[0] + c21 * a[1] + c22 * a[2],
                })
            }
            1 => {
                let q = self.array(topic, d, "q", 4)?;
                let n = q.iter().map(|v| v * v).sum::<f64>().sqrt();
                if !(0.9..1.1).contains(&n) {
                    bail!(
                        "{}: topic `{topic}`: field `q` has norm {n} at {t_us} µs (not a unit quaternion)",
                        self.path.display()
                    );
                }
                self.attitude = Some([q[0] / n, q[1] / n, q[2] / n, q[3] / n]);
                None
            }
            2 => Some(LogEvent::Baro {
                t,
                alt_m: self.scalar(topic, d, "baro_alt_meter")?,
            }),
            3 => {
                if self.scalar(topic, d, "fix_type")? < 3.0 {
                    return Ok(None);
                }
                let alt_m = match self.scalar(topic, d, "altitude_msl_m") {
                    Ok(v) => v,
                    Err(_) => self.scalar(topic, d, "alt")? * 1e-3,
                };
                Some(LogEvent::Gnss {
                    t,
                    alt_m,
                    vd_m_s: self.scalar(topic, d, "vel_d_m_s")?,
                })
            }
            _ => Some(LogEvent::Estimate {
                t,
                alt_m: -self.scalar(topic, d, "z")?,
                vd_m_s: self.scalar(topic, d, "vz")?,
            }),
        })
    }

    /// Reads until an event can be released from the reorder buffer (or the file ends).
    fn fill(&mut self) -> Result<()> {
        use yule_log::model::msg::UlogMessage;
        while !self.done
            && self
                .held
                .peek()
                .is_none_or(|h| h.0.time().as_micros() + ULOG_REORDER_US > self.newest_us)
        {
            match self.parser.next() {
                None => {
                    self.done = true;
                    for (k, seen) in self.seen.iter().enumerate() {
                        if !seen && k <= 2 {
                            bail!(
                                "{}: topic `{}` missing (the replay needs it)",
                                self.path.display(),
                                TOPICS[k]
                            );
                        }
                    }
                }
                Some(Err(e)) => bail!("{}: corrupt ULog: {e}", self.path.display()),
                Some(Ok(UlogMessage::LoggedData(data))) => {
                    let t_us = data.data.timestamp.unwrap_or(data.timestamp);
                    if let Some(ev) = self.map(&data.data, t_us)? {
                        self.newest_us = self.newest_us.max(t_us);
                        self.arrivals += 1;
                        self.held.push(Held(ev, self.arrivals));
                    }
                }
                Some(Ok(_)) => {}
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

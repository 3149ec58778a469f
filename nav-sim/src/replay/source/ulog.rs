//! A PX4 ULog read as one time-ordered stream: the topics the module's documentation lists,
//! held briefly to restore time order across topics, non-finite values counted.

use super::*;

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

impl std::fmt::Debug for ULogLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ULogLog")
            .field("path", &self.path)
            .field("held", &self.held.len())
            .finish()
    }
}

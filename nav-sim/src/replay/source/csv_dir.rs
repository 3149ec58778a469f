//! A directory of CSV files in the documented schema (the module's documentation), merged
//! into one time-ordered stream, with the time unit and the start times of the files checked.

use super::*;

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

impl std::fmt::Debug for CsvLog {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("CsvLog").field("dir", &self.dir).finish()
    }
}

//! The pass over the log: each event fed to the loops, and what the replay accumulates besides
//! the loops and the INS (the latest references, the differences, the CSV rows, the plot's
//! points, the stream statistics, the baro-unit check).

use super::*;

/// What the pass over the log accumulates, with the settings it needs.
pub(super) struct Pass {
    /// The first IMU sample: time origin of the rows.
    first_imu: Timestamp,
    /// Comparisons start this long after the first IMU sample, µs.
    settle_us: u64,
    /// Interval of the CSV rows, s.
    csv_interval_s: f64,
    /// The baro's altitude field, as errors name it.
    baro_field: String,
    pub(super) stats: BTreeMap<Stream, StreamStats>,
    latest_baro: f64,
    latest_baro_t: Option<Timestamp>,
    /// Latest GNSS altitude (m) and vertical velocity (up, m/s).
    latest_gnss: (f64, f64),
    /// Latest autopilot altitude (m) and vertical velocity (up, m/s).
    latest_est: (f64, f64),
    /// Autopilot − GNSS: altitude, vertical velocity.
    pub(super) ap_vs_gnss: (Moments, Moments),
    last_row: Option<Timestamp>,
    pub(super) plot_rows: Decimated<[f64; 10]>,
    /// Differences at the reference's own time stamps: (t, classical − autopilot altitude,
    /// aided − autopilot, classical − autopilot V_z, aided − autopilot V_z).
    pub(super) ap_diff: Decimated<[f64; 5]>,
    /// (t, GNSS − autopilot altitude, GNSS − autopilot V_z).
    pub(super) gnss_diff: Decimated<[f64; 3]>,
    pub(super) baro_units: BaroUnitCheck,
    pub(super) superseded_baro: u64,
    pub(super) superseded_gnss: u64,
}

impl Pass {
    pub(super) fn new(log: &Path, cfg: &ReplayConfig, first_imu: Timestamp) -> Self {
        let baro_field = if log.is_dir() {
            format!("{}: `baro_alt_m`", log.join("baro.csv").display())
        } else {
            format!(
                "{}: topic `vehicle_air_data`: field `baro_alt_meter`",
                log.display()
            )
        };
        Self {
            first_imu,
            settle_us: (cfg.settle_s.max(0.0) * 1e6) as u64,
            csv_interval_s: cfg.csv_interval_s,
            baro_field,
            stats: BTreeMap::new(),
            latest_baro: f64::NAN,
            latest_baro_t: None,
            latest_gnss: (f64::NAN, f64::NAN),
            latest_est: (f64::NAN, f64::NAN),
            ap_vs_gnss: (Moments::default(), Moments::default()),
            last_row: None,
            plot_rows: Decimated::new(0.05),
            ap_diff: Decimated::new(0.05),
            gnss_diff: Decimated::new(0.05),
            baro_units: BaroUnitCheck::default(),
            superseded_baro: 0,
            superseded_gnss: 0,
        }
    }

    /// Past the settling time: the comparisons count.
    fn settled(&self, t: Timestamp) -> bool {
        t.micros_since(self.first_imu)
            .is_some_and(|d| d >= self.settle_us)
    }

    /// The latest baro sample is close enough to `t` to pair with a reference altitude.
    fn fresh_baro(&self, t: Timestamp) -> bool {
        self.latest_baro_t
            .is_some_and(|b| t.signed_seconds_since::<f64>(b).abs() <= BARO_PAIR_MAX_AGE_S)
    }

    /// One event at or after the first IMU sample: aids are held for the loops' next step,
    /// references compared, an IMU sample steps the loops and writes the CSV row when due.
    pub(super) fn on_event(
        &mut self,
        ev: LogEvent,
        loops: &mut Loops,
        csv: &mut impl Write,
        ins: &ins::InsReplay,
    ) -> Result<()> {
        match ev {
            LogEvent::Baro { t, alt_m } => {
                self.latest_baro = alt_m;
                self.latest_baro_t = Some(t);
                if loops.pending_baro.is_some() {
                    self.superseded_baro += 1;
                }
                loops.pending_baro = Some(BaroSample {
                    time: t,
                    altitude_m: alt_m as f32,
                });
            }
            LogEvent::Gnss {
                t, alt_m, vd_m_s, ..
            } => self.on_gnss(t, alt_m, vd_m_s, loops)?,
            LogEvent::Estimate {
                t, alt_m, vd_m_s, ..
            } => self.on_estimate(t, alt_m, vd_m_s, loops)?,
            LogEvent::Attitude { .. } => {}
            LogEvent::Imu { t, f_down_m_s2, .. } => {
                self.on_imu(t, f_down_m_s2, loops, csv, ins)?;
            }
        }
        Ok(())
    }

    /// A GNSS altitude (m) and down velocity (m/s): the velocity aid, and the comparisons with
    /// the loops and the autopilot.
    fn on_gnss(&mut self, t: Timestamp, alt_m: f64, vd_m_s: f64, loops: &mut Loops) -> Result<()> {
        self.latest_gnss = (alt_m, -vd_m_s);
        if self.fresh_baro(t) {
            self.baro_units
                .add(Stream::Gnss, alt_m, self.latest_baro, &self.baro_field)?;
        }
        let latest_est = self.latest_est;
        if latest_est.0.is_finite() {
            let s = t.signed_seconds_since::<f64>(self.first_imu);
            self.gnss_diff
                .push(t, || [s, alt_m - latest_est.0, -vd_m_s - latest_est.1]);
        }
        if loops.pending_vel.is_some() {
            self.superseded_gnss += 1;
        }
        loops.pending_vel = Some(VelocitySample {
            time: t,
            vz_up_m_s: -vd_m_s as f32,
        });
        if self.settled(t) {
            for tl in &mut loops.tally {
                tl.alt_vs_gnss.add(tl.alt - alt_m);
                tl.vz_vs_gnss.add(tl.vz_up + vd_m_s);
            }
            if latest_est.0.is_finite() {
                self.ap_vs_gnss.0.add(latest_est.0 - alt_m);
                self.ap_vs_gnss.1.add(latest_est.1 + vd_m_s);
            }
        }
        Ok(())
    }

    /// The autopilot's altitude (m) and down velocity (m/s): the comparisons with the loops.
    fn on_estimate(
        &mut self,
        t: Timestamp,
        alt_m: f64,
        vd_m_s: f64,
        loops: &mut Loops,
    ) -> Result<()> {
        self.latest_est = (alt_m, -vd_m_s);
        if self.fresh_baro(t) {
            self.baro_units
                .add(Stream::Estimate, alt_m, self.latest_baro, &self.baro_field)?;
        }
        let (c, a) = (&loops.tally[0], &loops.tally[1]);
        let s = t.signed_seconds_since::<f64>(self.first_imu);
        self.ap_diff.push(t, || {
            [
                s,
                c.alt - alt_m,
                a.alt - alt_m,
                c.vz_up + vd_m_s,
                a.vz_up + vd_m_s,
            ]
        });
        if self.settled(t) {
            for tl in &mut loops.tally {
                tl.alt_vs_autopilot.add(tl.alt - alt_m);
                tl.vz_vs_autopilot.add(tl.vz_up + vd_m_s);
            }
        }
        Ok(())
    }

    /// An IMU sample (down specific force, m/s²): one step of both loops, the CSV row when due,
    /// the plot's point.
    fn on_imu(
        &mut self,
        t: Timestamp,
        f_down_m_s2: f64,
        loops: &mut Loops,
        csv: &mut impl Write,
        ins: &ins::InsReplay,
    ) -> Result<()> {
        loops.step(t, -f_down_m_s2 as f32);
        let row = [
            t.signed_seconds_since::<f64>(self.first_imu),
            -f_down_m_s2,
            self.latest_baro,
            self.latest_gnss.0,
            self.latest_gnss.1,
            self.latest_est.0,
            self.latest_est.1,
            loops.tally[0].alt,
            loops.tally[0].vz_up,
            loops.tally[1].alt,
            loops.tally[1].vz_up,
        ];
        let due = |last: Option<Timestamp>, every_s: f64| {
            last.is_none_or(|l| t.signed_seconds_since::<f64>(l) >= every_s)
        };
        if due(self.last_row, self.csv_interval_s) {
            self.last_row = Some(t);
            let line: Vec<String> = row.iter().map(|v| format!("{v}")).collect();
            writeln!(csv, "{}{}", line.join(","), ins.csv_fields())?;
        }
        self.plot_rows.push(t, || {
            [
                row[0], row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9], row[10],
            ]
        });
        Ok(())
    }
}

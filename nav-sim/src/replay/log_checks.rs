//! What the replay checks and measures in the log itself: the pre-scan (IMU interval, first
//! baro altitude), the baro's units against the autopilot's and the GNSS altitude, each
//! stream's timing (intervals, jitter, gaps, out-of-order samples).

use super::*;

/// Smallest change of the autopilot's altitude estimate over which the baro's units are
/// judged, m.
pub(super) const BARO_UNIT_MIN_SPAN_EST_M: f64 = 2.0;
/// The same against GNSS altitude (its metre-level noise would flatten a fit over a smaller
/// change), m.
pub(super) const BARO_UNIT_MIN_SPAN_GNSS_M: f64 = 10.0;
/// A baro altitude in m follows a reference altitude in m with a slope in this band (feet:
/// 3.28; pressure in hPa: ≈ −0.12 per m; in km: 0.001).
pub(super) const BARO_UNIT_SLOPE_BAND: std::ops::RangeInclusive<f64> = 0.5..=2.0;
/// A baro sample older than this is not paired with a reference sample, s.
pub(super) const BARO_PAIR_MAX_AGE_S: f64 = 0.5;

/// Regression of the baro altitude on a reference altitude (the autopilot's estimate, else
/// GNSS): the baro's units checked by how it follows the vehicle's altitude changes.
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct BaroUnitFit {
    pub(super) n: u64,
    pub(super) mean_r: f64,
    pub(super) mean_b: f64,
    pub(super) c_rb: f64,
    pub(super) c_rr: f64,
    pub(super) r_min: f64,
    pub(super) r_max: f64,
}

impl BaroUnitFit {
    pub(super) fn add(&mut self, r: f64, b: f64) {
        if !(r.is_finite() && b.is_finite()) {
            return;
        }
        if self.n == 0 {
            (self.r_min, self.r_max) = (r, r);
        }
        self.n += 1;
        let n = self.n as f64;
        let dr = r - self.mean_r;
        self.mean_r += dr / n;
        self.mean_b += (b - self.mean_b) / n;
        self.c_rb += dr * (b - self.mean_b);
        self.c_rr += dr * (r - self.mean_r);
        self.r_min = self.r_min.min(r);
        self.r_max = self.r_max.max(r);
    }
    pub(super) fn span_m(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.r_max - self.r_min
        }
    }
    pub(super) fn ready(&self, min_span_m: f64) -> bool {
        self.n >= 20 && self.span_m() >= min_span_m
    }
    pub(super) fn slope(&self) -> f64 {
        self.c_rb / self.c_rr
    }
}

/// The baro units check over the log: decided once the reference has moved enough.
#[derive(Debug, Clone, Default)]
pub(super) struct BaroUnitCheck {
    pub(super) vs_estimate: BaroUnitFit,
    pub(super) vs_gnss: BaroUnitFit,
    pub(super) verdict: Option<(&'static str, f64, f64)>,
}

impl BaroUnitCheck {
    /// Adds a pair; errors once the slope is decided and outside the band.
    /// `baro_field` names the file or topic and the field (messages).
    pub(super) fn add(
        &mut self,
        reference: Stream,
        r: f64,
        b: f64,
        baro_field: &str,
    ) -> Result<()> {
        if self.verdict.is_some() {
            return Ok(());
        }
        match reference {
            Stream::Estimate => self.vs_estimate.add(r, b),
            _ => self.vs_gnss.add(r, b),
        }
        let fit = if self.vs_estimate.ready(BARO_UNIT_MIN_SPAN_EST_M) {
            ("autopilot estimate", self.vs_estimate)
        } else if self.vs_gnss.ready(BARO_UNIT_MIN_SPAN_GNSS_M) && self.vs_estimate.n == 0 {
            ("GNSS altitude", self.vs_gnss)
        } else {
            return Ok(());
        };
        let k = fit.1.slope();
        self.verdict = Some((fit.0, k, fit.1.span_m()));
        if !BARO_UNIT_SLOPE_BAND.contains(&k) {
            let hint = if (-0.2..=-0.05).contains(&k) {
                " (looks like pressure in hPa, not an altitude in m)"
            } else if (-20.0..=-5.0).contains(&k) {
                " (looks like pressure in Pa, not an altitude in m)"
            } else if (2.5..=4.0).contains(&k) {
                " (looks like feet, not m)"
            } else if (0.0005..=0.002).contains(&k) {
                " (looks like km, not m)"
            } else {
                ""
            };
            bail!(
                "{baro_field} changes {k:.4} m per m of the {} over {:.1} m of altitude change, expected ≈ 1{hint}",
                fit.0,
                fit.1.span_m()
            );
        }
        Ok(())
    }
    pub(super) fn summary(&self) -> Value {
        match self.verdict {
            Some((reference, slope, span)) => json!({
                "result": "Consistent",
                "reference": reference,
                "baro_m_per_reference_m": sig(slope, 4),
                "over_altitude_change_m": sig(span, 4),
            }),
            None => json!({
                "result": "NotDecided",
                "reason": format!(
                    "the autopilot's altitude changed by {:.1} m (needed: {BARO_UNIT_MIN_SPAN_EST_M} m), GNSS altitude by {:.1} m (needed without an estimate: {BARO_UNIT_MIN_SPAN_GNSS_M} m)",
                    self.vs_estimate.span_m(), self.vs_gnss.span_m()
                ),
            }),
        }
    }
}

/// Online mean and variance (Welford).
#[derive(Debug, Clone, Copy, Default)]
pub(super) struct Moments {
    pub(super) n: u64,
    pub(super) mean: f64,
    pub(super) m2: f64,
    pub(super) sum_sq: f64,
}

impl Moments {
    pub(super) fn add(&mut self, x: f64) {
        if !x.is_finite() {
            return;
        }
        self.n += 1;
        let d = x - self.mean;
        self.mean += d / self.n as f64;
        self.m2 += d * (x - self.mean);
        self.sum_sq += x * x;
    }
    /// RMS about the mean (the datum offset removed).
    pub(super) fn std(&self) -> f64 {
        if self.n < 2 {
            f64::NAN
        } else {
            (self.m2 / self.n as f64).sqrt()
        }
    }
    pub(super) fn rms(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.sum_sq / self.n as f64).sqrt()
        }
    }
}

/// Interval statistics of one stream, with its gaps.
#[derive(Debug, Clone, Default)]
pub(super) struct StreamStats {
    pub(super) samples: u64,
    pub(super) first: Option<Timestamp>,
    pub(super) last: Option<Timestamp>,
    /// The first 512 intervals, µs (median for the gap threshold).
    pub(super) early_intervals: Vec<u64>,
    /// Their median once all 512 are in (it no longer changes).
    pub(super) median_cache: Option<u64>,
    pub(super) min_us: u64,
    pub(super) max_us: u64,
    pub(super) gaps: Vec<(f64, f64)>,
    pub(super) gap_count: u64,
    pub(super) repeated: u64,
}

impl StreamStats {
    pub(super) fn add(&mut self, t: Timestamp, gap_factor: f64) {
        self.samples += 1;
        if let Some(last) = self.last {
            let d = t.micros_since(last).unwrap_or(0);
            if d == 0 {
                self.repeated += 1;
            }
            if self.early_intervals.len() < 512 {
                self.early_intervals.push(d);
                if self.early_intervals.len() == 512 {
                    self.median_cache = Some(self.sorted_median());
                }
            }
            self.min_us = if self.samples == 2 {
                d
            } else {
                self.min_us.min(d)
            };
            self.max_us = self.max_us.max(d);
            let med = self.median_us();
            if med > 0 && d as f64 > gap_factor * med as f64 {
                self.gap_count += 1;
                if self.gaps.len() < 50 {
                    self.gaps.push((last.as_secs_f64(), d as f64 * 1e-6));
                }
            }
        } else {
            self.first = Some(t);
        }
        self.last = Some(t);
    }
    pub(super) fn median_us(&self) -> u64 {
        self.median_cache.unwrap_or_else(|| self.sorted_median())
    }
    pub(super) fn sorted_median(&self) -> u64 {
        let mut v = self.early_intervals.clone();
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or(0)
    }
    pub(super) fn summary(&self, t0: Timestamp) -> Value {
        let dur = match (self.first, self.last) {
            (Some(a), Some(b)) => b.signed_seconds_since::<f64>(a),
            _ => 0.0,
        };
        json!({
            "samples": self.samples,
            "first_s": self.first.map(|t| t.signed_seconds_since::<f64>(t0)),
            "duration_s": sig(dur, 6),
            "rate_hz": if dur > 0.0 { sig((self.samples.saturating_sub(1)) as f64 / dur, 4) } else { 0.0 },
            "interval_s": {
                "median": self.median_us() as f64 * 1e-6,
                "min": self.min_us as f64 * 1e-6,
                "max": self.max_us as f64 * 1e-6,
            },
            "repeated_time_stamps": self.repeated,
            "gap_count": self.gap_count,
            "gaps": self.gaps.iter().map(|(at, len)| json!({
                "at_s": sig(at - t0.as_secs_f64(), 6), "length_s": sig(*len, 4)
            })).collect::<Vec<_>>(),
        })
    }
}

/// What the pre-scan of the log found: the IMU interval and the first baro altitude.
pub(super) struct PreScan {
    pub(super) imu_dt_s: f64,
    pub(super) first_imu: Timestamp,
    pub(super) first_baro_alt_m: f64,
}

pub(super) fn prescan(log: &Path) -> Result<PreScan> {
    let mut src = source::open(log)?;
    let mut intervals = Vec::new();
    let mut last = None;
    let mut first_imu = None;
    let mut baro = None;
    let mut f_down = Moments::default();
    for ev in src.by_ref() {
        match ev? {
            LogEvent::Imu { t, f_down_m_s2, .. } => {
                first_imu.get_or_insert(t);
                f_down.add(f_down_m_s2);
                if let Some(l) = last {
                    if let Some(d) = Timestamp::micros_since(t, l) {
                        if d > 0 {
                            intervals.push(d);
                        }
                    }
                }
                last = Some(t);
            }
            LogEvent::Baro { alt_m, .. } => {
                baro.get_or_insert(alt_m);
            }
            _ => {}
        }
        if intervals.len() >= 1000 && baro.is_some() {
            break;
        }
    }
    let describe = src.describe();
    let first_imu = first_imu.ok_or_else(|| anyhow!("{describe}: no IMU sample"))?;
    let first_baro_alt_m = baro.ok_or_else(|| anyhow!("{describe}: no baro sample"))?;
    if intervals.len() < 10 {
        bail!("{describe}: fewer than 10 IMU intervals");
    }
    // Units: at rest or in flight the mean down specific force is near −g.
    let m = f_down.mean;
    if !(-15.0..=-5.0).contains(&m) {
        let hint = if (-1.5..=-0.5).contains(&m) {
            " (looks like g, not m/s²)"
        } else if (5.0..=15.0).contains(&m) {
            " (positive: up, not down?)"
        } else {
            ""
        };
        let what = if log.is_dir() {
            format!("{}: `f_down_m_s2`", log.join("imu.csv").display())
        } else {
            format!(
                "{}: topic `sensor_combined`: field `accelerometer_m_s2` (rotated to NED by `vehicle_attitude.q`), down component",
                log.display()
            )
        };
        bail!("{what} averages {m:.3} over the first samples, expected ≈ −9.8 m/s²{hint}");
    }
    if !(-2_000.0..=60_000.0).contains(&first_baro_alt_m) {
        let what = if log.is_dir() {
            format!("{}: `baro_alt_m`", log.join("baro.csv").display())
        } else {
            format!(
                "{}: topic `vehicle_air_data`: field `baro_alt_meter`",
                log.display()
            )
        };
        bail!("{what} = {first_baro_alt_m} m is outside −2 km … 60 km (wrong units?)");
    }
    intervals.sort_unstable();
    let med = intervals[intervals.len() / 2];
    Ok(PreScan {
        imu_dt_s: med as f64 * 1e-6,
        first_imu,
        first_baro_alt_m,
    })
}

//! Replay of recorded flight logs through the vertical-channel loops (`nav-sim replay`,
//! `cargo xtask replay`): a PX4 ULog or a directory of CSV files ([`source`]) is streamed in
//! time order, the IMU drives both loops at the log's own time stamps (jitter, late samples,
//! gaps and glitches as they come) and the baro and GNSS vertical velocity aid them, exactly as
//! a flight loop would call nav-core. The loops are compared with the GNSS altitude and
//! vertical velocity and with the autopilot's own estimate.
//!
//! Where the log has gyro, accelerometer and the autopilot's attitude, nav-core's strapdown INS
//! runs from the same samples and is compared with the autopilot ([`ins`]).
//!
//! Outputs in the output directory: `summary.json`, `timeseries.csv`, `replay.png`, and
//! `ins.png` where the INS ran.

pub mod ins;
pub mod source;

use crate::output::sig;
use crate::plot::{self, Figure, Panel, Series};
use anyhow::{anyhow, bail, Context, Result};
use nav_core::vertical_channel::{
    Aid, AidTimeouts, AidedConfig, AidedLoop, BaroSample, ClassicalConfig, ClassicalLoop,
    ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, Health, NavError, Timestamp};
use serde::Deserialize;
use serde_json::{json, Value};
use source::{LogEvent, Stream};
use std::collections::BTreeMap;
use std::io::Write;
use std::path::Path;

/// The replay's configuration (TOML; every field has a default, units in the names).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ReplayConfig {
    /// Comparisons start this long after the first IMU sample (loop convergence), s.
    pub settle_s: f64,
    /// Geodetic latitude of the flight, deg (gravity model).
    pub latitude_deg: f64,
    /// Interval of the rows of `timeseries.csv`, s (0: every IMU sample).
    pub csv_interval_s: f64,
    /// A stream interval longer than this many median intervals is reported as a gap.
    pub gap_factor: f64,
    /// Classical loop.
    pub classical: ClassicalReplay,
    /// Velocity-aided loop.
    pub aided: AidedReplay,
    /// Aid timeouts (both loops, both aids).
    pub aid_stale_after_s: f64,
    /// Aid timeouts (both loops, both aids).
    pub aid_lost_after_s: f64,
    /// Longest expected baro interval, s (loop stability and the aided design).
    pub baro_period_s: f64,
    /// GNSS vertical-velocity interval, s (the aided design).
    pub velocity_period_s: f64,
    /// Innovation gate of both loops; absent: ungated.
    pub gate: Option<crate::scenarios::vertical_channel_faults::GateConfig>,
    /// Strapdown INS replay (where the log has gyro, accelerometer and attitude).
    pub ins: ins::InsReplayConfig,
}

/// Classical-loop settings.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct ClassicalReplay {
    /// Triple-pole time constant τ, s.
    pub tau_s: f64,
    /// Baro lag compensation C4, s.
    pub baro_lag_s: f64,
}

/// Aided-loop design settings (σ, not variances).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct AidedReplay {
    /// Accelerometer white-noise density, m/s²/√Hz.
    pub accel_noise_m_s2_rt_hz: f64,
    /// Accelerometer bias random walk, m/s²/√s.
    pub accel_bias_rw_m_s2_rt_s: f64,
    /// Baro white noise per sample, 1σ, m.
    pub baro_noise_m: f64,
    /// Baro lag compensation, s.
    pub baro_lag_s: f64,
    /// GNSS vertical-velocity noise per sample, 1σ, m/s.
    pub velocity_noise_m_s: f64,
}

impl Default for ReplayConfig {
    fn default() -> Self {
        Self {
            settle_s: 10.0,
            latitude_deg: 45.0,
            csv_interval_s: 0.0,
            gap_factor: 5.0,
            classical: ClassicalReplay::default(),
            aided: AidedReplay::default(),
            aid_stale_after_s: 0.5,
            aid_lost_after_s: 2.0,
            baro_period_s: 0.05,
            velocity_period_s: 0.2,
            gate: None,
            ins: ins::InsReplayConfig::default(),
        }
    }
}

impl Default for ClassicalReplay {
    fn default() -> Self {
        Self {
            tau_s: 5.0,
            baro_lag_s: 0.0,
        }
    }
}

impl Default for AidedReplay {
    /// A consumer-grade MEMS IMU and baro, a GNSS receiver's vertical velocity.
    fn default() -> Self {
        Self {
            accel_noise_m_s2_rt_hz: 0.03,
            accel_bias_rw_m_s2_rt_s: 1.0e-3,
            baro_noise_m: 0.5,
            baro_lag_s: 0.0,
            velocity_noise_m_s: 0.2,
        }
    }
}

impl ReplayConfig {
    /// Reads a TOML file (absent fields take their defaults).
    pub fn from_file(path: &Path) -> Result<Self> {
        let text = std::fs::read_to_string(path)
            .with_context(|| format!("{}: cannot read", path.display()))?;
        toml::from_str(&text)
            .with_context(|| format!("{}: invalid replay configuration", path.display()))
    }
}

/// Points kept for a figure, however long the log: at most [`Decimated::CAPACITY`]; when
/// full, every other point is dropped and the interval doubled (memory independent of the
/// log's duration).
#[derive(Debug, Clone)]
pub(crate) struct Decimated<T> {
    rows: Vec<T>,
    every_s: f64,
    last: Option<Timestamp>,
}

impl<T> Decimated<T> {
    /// Most points kept per figure buffer.
    pub(crate) const CAPACITY: usize = 20_000;

    /// A buffer keeping one point per `every_s` seconds to begin with.
    pub(crate) fn new(every_s: f64) -> Self {
        Self {
            rows: Vec::new(),
            every_s,
            last: None,
        }
    }
    /// Whether a point at `t` would be kept (one interval since the last kept).
    pub(crate) fn due(&self, t: Timestamp) -> bool {
        self.last
            .is_none_or(|l| t.signed_seconds_since::<f64>(l) >= self.every_s)
    }
    /// Keeps `row` (time of validity `t`) if one interval has passed since the last kept.
    pub(crate) fn push(&mut self, t: Timestamp, row: impl FnOnce() -> T) {
        if !self.due(t) {
            return;
        }
        self.last = Some(t);
        self.rows.push(row());
        if self.rows.len() >= Self::CAPACITY {
            let mut k = 0;
            self.rows.retain(|_| {
                k += 1;
                k % 2 == 1
            });
            self.every_s *= 2.0;
        }
    }
    /// The points kept.
    pub(crate) fn rows(&self) -> &[T] {
        &self.rows
    }
}

/// Smallest change of the autopilot's altitude estimate over which the baro's units are
/// judged, m.
const BARO_UNIT_MIN_SPAN_EST_M: f64 = 2.0;
/// The same against GNSS altitude (its metre-level noise would flatten a fit over a smaller
/// change), m.
const BARO_UNIT_MIN_SPAN_GNSS_M: f64 = 10.0;
/// A baro altitude in m follows a reference altitude in m with a slope in this band (feet:
/// 3.28; pressure in hPa: ≈ −0.12 per m; in km: 0.001).
const BARO_UNIT_SLOPE_BAND: std::ops::RangeInclusive<f64> = 0.5..=2.0;
/// A baro sample older than this is not paired with a reference sample, s.
const BARO_PAIR_MAX_AGE_S: f64 = 0.5;

/// Regression of the baro altitude on a reference altitude (the autopilot's estimate, else
/// GNSS): the baro's units checked by how it follows the vehicle's altitude changes.
#[derive(Debug, Clone, Copy, Default)]
struct BaroUnitFit {
    n: u64,
    mean_r: f64,
    mean_b: f64,
    c_rb: f64,
    c_rr: f64,
    r_min: f64,
    r_max: f64,
}

impl BaroUnitFit {
    fn add(&mut self, r: f64, b: f64) {
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
    fn span_m(&self) -> f64 {
        if self.n == 0 {
            0.0
        } else {
            self.r_max - self.r_min
        }
    }
    fn ready(&self, min_span_m: f64) -> bool {
        self.n >= 20 && self.span_m() >= min_span_m
    }
    fn slope(&self) -> f64 {
        self.c_rb / self.c_rr
    }
}

/// The baro units check over the log: decided once the reference has moved enough.
#[derive(Debug, Clone, Default)]
struct BaroUnitCheck {
    vs_estimate: BaroUnitFit,
    vs_gnss: BaroUnitFit,
    verdict: Option<(&'static str, f64, f64)>,
}

impl BaroUnitCheck {
    /// Adds a pair; errors once the slope is decided and outside the band.
    /// `baro_field` names the file or topic and the field (messages).
    fn add(&mut self, reference: Stream, r: f64, b: f64, baro_field: &str) -> Result<()> {
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
    fn summary(&self) -> Value {
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
struct Moments {
    n: u64,
    mean: f64,
    m2: f64,
    sum_sq: f64,
}

impl Moments {
    fn add(&mut self, x: f64) {
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
    fn std(&self) -> f64 {
        if self.n < 2 {
            f64::NAN
        } else {
            (self.m2 / self.n as f64).sqrt()
        }
    }
    fn rms(&self) -> f64 {
        if self.n == 0 {
            f64::NAN
        } else {
            (self.sum_sq / self.n as f64).sqrt()
        }
    }
}

/// Interval statistics of one stream, with its gaps.
#[derive(Debug, Clone, Default)]
struct StreamStats {
    samples: u64,
    first: Option<Timestamp>,
    last: Option<Timestamp>,
    /// The first 512 intervals, µs (median for the gap threshold).
    early_intervals: Vec<u64>,
    /// Their median once all 512 are in (it no longer changes).
    median_cache: Option<u64>,
    min_us: u64,
    max_us: u64,
    gaps: Vec<(f64, f64)>,
    gap_count: u64,
    repeated: u64,
}

impl StreamStats {
    fn add(&mut self, t: Timestamp, gap_factor: f64) {
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
    fn median_us(&self) -> u64 {
        self.median_cache.unwrap_or_else(|| self.sorted_median())
    }
    fn sorted_median(&self) -> u64 {
        let mut v = self.early_intervals.clone();
        v.sort_unstable();
        v.get(v.len() / 2).copied().unwrap_or(0)
    }
    fn summary(&self, t0: Timestamp) -> Value {
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

/// What one loop did over the log.
#[derive(Debug, Clone, Default)]
struct LoopTally {
    imu_accepted: u64,
    imu_refused: BTreeMap<String, u64>,
    aid_refused: BTreeMap<String, u64>,
    alt_vs_gnss: Moments,
    vz_vs_gnss: Moments,
    alt_vs_autopilot: Moments,
    vz_vs_autopilot: Moments,
    alt: f64,
    vz_up: f64,
}

fn error_kind(e: &NavError) -> String {
    format!("{e:?}")
}

/// The two loops and the last aid samples not yet passed to them.
struct Loops {
    classical: ClassicalLoop<f32>,
    aided: AidedLoop<f32>,
    pending_baro: Option<BaroSample<f32>>,
    pending_vel: Option<VelocitySample<f32>>,
    tally: [LoopTally; 2],
}

impl Loops {
    fn step(&mut self, t: Timestamp, f_up: f32) {
        let imu = ImuSample {
            time: t,
            specific_force_up_m_s2: f_up,
        };
        let baro = self.pending_baro.take();
        let vel = self.pending_vel.take();
        // Classical loop: the baro with the sample; if refused, the IMU alone (a flight loop
        // keeps the navigation running and counts the refused aid).
        let r = self.classical.step(&imu, baro.as_ref());
        let tally = &mut self.tally[0];
        match r {
            Ok(_) => tally.imu_accepted += 1,
            Err(e) if baro.is_some() => match self.classical.step(&imu, None) {
                Ok(_) => {
                    tally.imu_accepted += 1;
                    *tally
                        .aid_refused
                        .entry(format!("baro: {}", error_kind(&e)))
                        .or_default() += 1;
                }
                Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
            },
            Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
        }
        tally.alt = f64::from(self.classical.altitude_m());
        tally.vz_up = f64::from(self.classical.vz_up_m_s());

        let r = self.aided.step(&imu, baro.as_ref(), vel.as_ref());
        let tally = &mut self.tally[1];
        match r {
            Ok(_) => tally.imu_accepted += 1,
            Err(e) if baro.is_some() || vel.is_some() => match self.aided.step(&imu, None, None) {
                Ok(_) => {
                    tally.imu_accepted += 1;
                    *tally
                        .aid_refused
                        .entry(format!("aid: {}", error_kind(&e)))
                        .or_default() += 1;
                }
                Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
            },
            Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
        }
        tally.alt = f64::from(self.aided.altitude_m());
        tally.vz_up = f64::from(self.aided.vz_up_m_s());
    }
}

/// What the pre-scan of the log found: the IMU interval and the first baro altitude.
struct PreScan {
    imu_dt_s: f64,
    first_imu: Timestamp,
    first_baro_alt_m: f64,
}

fn prescan(log: &Path) -> Result<PreScan> {
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

/// Replays `log` with `cfg`, writing into `out`; returns the summary.
pub fn replay(log: &Path, cfg: &ReplayConfig, out: &Path) -> Result<Value> {
    cfg.ins.validate()?;
    let pre = prescan(log)?;
    let lat = cfg.latitude_deg.to_radians();
    let timeouts = AidTimeouts {
        stale_after_s: cfg.aid_stale_after_s as f32,
        lost_after_s: cfg.aid_lost_after_s as f32,
    };
    let ccfg = ClassicalConfig::<f32> {
        imu_dt_s: pre.imu_dt_s as f32,
        latitude_rad: lat as f32,
        tau_s: cfg.classical.tau_s as f32,
        baro_lag_s: cfg.classical.baro_lag_s as f32,
        baro_period_s: cfg.baro_period_s as f32,
        baro_timeouts: timeouts,
        ..ClassicalConfig::paper()
    };
    let acfg = AidedConfig::<f32> {
        imu_dt_s: pre.imu_dt_s as f32,
        latitude_rad: lat as f32,
        accel_noise_m_s2_rt_hz: cfg.aided.accel_noise_m_s2_rt_hz as f32,
        accel_bias_rw_m_s2_rt_s: cfg.aided.accel_bias_rw_m_s2_rt_s as f32,
        baro_noise_m: cfg.aided.baro_noise_m as f32,
        baro_period_s: cfg.baro_period_s as f32,
        baro_lag_s: cfg.aided.baro_lag_s as f32,
        velocity_noise_m_s: cfg.aided.velocity_noise_m_s as f32,
        velocity_period_s: cfg.velocity_period_s as f32,
        baro_timeouts: timeouts,
        velocity_timeouts: timeouts,
        ..AidedConfig::paper()
    };
    let init = InitialState {
        // One nominal interval before the first IMU sample (the log's clock is ≥ it).
        time: Timestamp::from_micros(
            pre.first_imu
                .as_micros()
                .saturating_sub((pre.imu_dt_s * 1e6).round() as u64),
        ),
        altitude_m: pre.first_baro_alt_m as f32,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let e = |what: &'static str| move |e: NavError| anyhow!("{what}: {e}");
    let mut loops = Loops {
        classical: ClassicalLoop::new(&ccfg, &init).map_err(e("classical loop configuration"))?,
        aided: AidedLoop::new(&acfg, &init).map_err(e("aided loop configuration"))?,
        pending_baro: None,
        pending_vel: None,
        tally: Default::default(),
    };
    if let Some(g) = &cfg.gate {
        loops
            .classical
            .set_aid_model(g.aid_model())
            .map_err(e("gate"))?;
        loops
            .classical
            .set_recovery(g.recovery())
            .map_err(e("gate"))?;
        loops.classical.set_gate(g.gate()).map_err(e("gate"))?;
        loops
            .aided
            .set_aid_model(g.aid_model())
            .map_err(e("gate"))?;
        loops.aided.set_recovery(g.recovery()).map_err(e("gate"))?;
        loops.aided.set_gate(g.gate()).map_err(e("gate"))?;
    }

    std::fs::create_dir_all(out).with_context(|| format!("{}: cannot create", out.display()))?;
    let csv_path = out.join("timeseries.csv");
    let mut csv = std::io::BufWriter::new(
        std::fs::File::create(&csv_path)
            .with_context(|| format!("{}: cannot create", csv_path.display()))?,
    );
    writeln!(
        csv,
        "t_s,f_up_m_s2,baro_alt_m,gnss_alt_m,gnss_vz_up_m_s,autopilot_alt_m,autopilot_vz_up_m_s,classical_alt_m,classical_vz_up_m_s,aided_alt_m,aided_vz_up_m_s{}",
        ins::InsReplay::CSV_HEADER
    )?;
    let mut ins = ins::InsReplay::new(&cfg.ins, pre.first_imu, pre.imu_dt_s, cfg.latitude_deg);

    let mut stats: BTreeMap<Stream, StreamStats> = BTreeMap::new();
    let mut latest_baro = f64::NAN;
    let mut latest_gnss = (f64::NAN, f64::NAN);
    let mut latest_est = (f64::NAN, f64::NAN);
    let mut ap_vs_gnss = (Moments::default(), Moments::default());
    let mut last_row: Option<Timestamp> = None;
    let mut plot_rows: Decimated<[f64; 10]> = Decimated::new(0.05);
    // Differences at the reference's own time stamps: (t, classical − autopilot altitude,
    // aided − autopilot, classical − autopilot V_z, aided − autopilot V_z); (t, GNSS −
    // autopilot altitude, GNSS − autopilot V_z).
    let mut ap_diff: Decimated<[f64; 5]> = Decimated::new(0.05);
    let mut gnss_diff: Decimated<[f64; 3]> = Decimated::new(0.05);
    let mut baro_units = BaroUnitCheck::default();
    let mut latest_baro_t: Option<Timestamp> = None;
    let baro_field = if log.is_dir() {
        format!("{}: `baro_alt_m`", log.join("baro.csv").display())
    } else {
        format!(
            "{}: topic `vehicle_air_data`: field `baro_alt_meter`",
            log.display()
        )
    };
    let settle_us = (cfg.settle_s.max(0.0) * 1e6) as u64;
    let settled = |t: Timestamp| {
        t.micros_since(pre.first_imu)
            .is_some_and(|d| d >= settle_us)
    };
    let mut superseded_baro = 0_u64;
    let mut superseded_gnss = 0_u64;
    let fresh = |b: Option<Timestamp>, t: Timestamp| {
        b.is_some_and(|b| t.signed_seconds_since::<f64>(b).abs() <= BARO_PAIR_MAX_AGE_S)
    };

    let mut src = source::open(log)?;
    for ev in src.by_ref() {
        let ev = ev?;
        stats
            .entry(ev.stream())
            .or_default()
            .add(ev.time(), cfg.gap_factor);
        if ev.time() < pre.first_imu {
            continue; // aids before the first IMU sample: nothing to aid yet
        }
        ins.on_event(&ev);
        match ev {
            LogEvent::Baro { t, alt_m } => {
                latest_baro = alt_m;
                latest_baro_t = Some(t);
                if loops.pending_baro.is_some() {
                    superseded_baro += 1;
                }
                loops.pending_baro = Some(BaroSample {
                    time: t,
                    altitude_m: alt_m as f32,
                });
            }
            LogEvent::Gnss {
                t, alt_m, vd_m_s, ..
            } => {
                latest_gnss = (alt_m, -vd_m_s);
                if fresh(latest_baro_t, t) {
                    baro_units.add(Stream::Gnss, alt_m, latest_baro, &baro_field)?;
                }
                if latest_est.0.is_finite() {
                    let s = t.signed_seconds_since::<f64>(pre.first_imu);
                    gnss_diff.push(t, || [s, alt_m - latest_est.0, -vd_m_s - latest_est.1]);
                }
                if loops.pending_vel.is_some() {
                    superseded_gnss += 1;
                }
                loops.pending_vel = Some(VelocitySample {
                    time: t,
                    vz_up_m_s: -vd_m_s as f32,
                });
                if settled(t) {
                    for tl in &mut loops.tally {
                        tl.alt_vs_gnss.add(tl.alt - alt_m);
                        tl.vz_vs_gnss.add(tl.vz_up + vd_m_s);
                    }
                    if latest_est.0.is_finite() {
                        ap_vs_gnss.0.add(latest_est.0 - alt_m);
                        ap_vs_gnss.1.add(latest_est.1 + vd_m_s);
                    }
                }
            }
            LogEvent::Estimate {
                t, alt_m, vd_m_s, ..
            } => {
                latest_est = (alt_m, -vd_m_s);
                if fresh(latest_baro_t, t) {
                    baro_units.add(Stream::Estimate, alt_m, latest_baro, &baro_field)?;
                }
                let (c, a) = (&loops.tally[0], &loops.tally[1]);
                let s = t.signed_seconds_since::<f64>(pre.first_imu);
                ap_diff.push(t, || {
                    [
                        s,
                        c.alt - alt_m,
                        a.alt - alt_m,
                        c.vz_up + vd_m_s,
                        a.vz_up + vd_m_s,
                    ]
                });
                if settled(t) {
                    for tl in &mut loops.tally {
                        tl.alt_vs_autopilot.add(tl.alt - alt_m);
                        tl.vz_vs_autopilot.add(tl.vz_up + vd_m_s);
                    }
                }
            }
            LogEvent::Attitude { .. } => {}
            LogEvent::Imu { t, f_down_m_s2, .. } => {
                loops.step(t, -f_down_m_s2 as f32);
                let row = [
                    t.signed_seconds_since::<f64>(pre.first_imu),
                    -f_down_m_s2,
                    latest_baro,
                    latest_gnss.0,
                    latest_gnss.1,
                    latest_est.0,
                    latest_est.1,
                    loops.tally[0].alt,
                    loops.tally[0].vz_up,
                    loops.tally[1].alt,
                    loops.tally[1].vz_up,
                ];
                let due = |last: Option<Timestamp>, every_s: f64| {
                    last.is_none_or(|l| t.signed_seconds_since::<f64>(l) >= every_s)
                };
                if due(last_row, cfg.csv_interval_s) {
                    last_row = Some(t);
                    let line: Vec<String> = row.iter().map(|v| format!("{v}")).collect();
                    writeln!(csv, "{}{}", line.join(","), ins.csv_fields())?;
                }
                plot_rows.push(t, || {
                    [
                        row[0], row[2], row[3], row[4], row[5], row[6], row[7], row[8], row[9],
                        row[10],
                    ]
                });
            }
        }
    }
    csv.flush()?;
    let describe = src.describe();
    let findings = src.findings();

    let status = |st: &Health| {
        json!({
            "health_at_end": format!("{:?}", st.state),
            "imu_gaps_bridged": st.gaps_bridged,
            "imu_gaps_skipped": st.gaps_reset,
            "estimate_limited_steps": st.limits_hit,
        })
    };
    let loop_summary = |tl: &LoopTally, counters: Value, st: Value| {
        json!({
            "status": st,
            "imu_accepted": tl.imu_accepted,
            "imu_refused": tl.imu_refused,
            "aid_samples_refused": tl.aid_refused,
            "gate": counters,
            "vs_gnss": {
                "alt_rms_m": sig(tl.alt_vs_gnss.std(), 4),
                "alt_datum_offset_m": sig(tl.alt_vs_gnss.mean, 4),
                "vz_rms_m_s": sig(tl.vz_vs_gnss.rms(), 4),
                "samples": tl.alt_vs_gnss.n,
            },
            "vs_autopilot": {
                "alt_rms_m": sig(tl.alt_vs_autopilot.std(), 4),
                "alt_datum_offset_m": sig(tl.alt_vs_autopilot.mean, 4),
                "vz_rms_m_s": sig(tl.vz_vs_autopilot.rms(), 4),
                "samples": tl.alt_vs_autopilot.n,
            },
            "final": { "alt_m": sig(tl.alt, 7), "vz_up_m_s": sig(tl.vz_up, 4) },
        })
    };
    let counters = |c: nav_core::AidCounters,
                    r: nav_core::vertical_channel::ReacquisitionCounters| {
        json!({
            "accepted": c.fused, "rejected": c.rejected,
            "reacquisitions": r.reacquisitions, "resets": r.resets,
        })
    };
    let summary = json!({
        "log": describe,
        "imu_dt_s": pre.imu_dt_s,
        "settle_s": cfg.settle_s,
        "streams": stats.iter().map(|(s, st)| (s.name().to_string(), st.summary(pre.first_imu))).collect::<serde_json::Map<_, _>>(),
        "aid_samples_superseded": { "baro": superseded_baro, "gnss": superseded_gnss },
        "log_findings": findings,
        "baro_units_check": baro_units.summary(),
        "loops": {
            "classical": loop_summary(
                &loops.tally[0],
                json!({ "baro": counters(
                    loops.classical.aid_counters(Aid::Baro),
                    loops.classical.reacquisition_counters(Aid::Baro),
                ) }),
                status(&loops.classical.health()),
            ),
            "aided": loop_summary(&loops.tally[1], json!({
                "baro": counters(
                    loops.aided.aid_counters(Aid::Baro),
                    loops.aided.reacquisition_counters(Aid::Baro),
                ),
                "velocity": counters(
                    loops.aided.aid_counters(Aid::Velocity),
                    loops.aided.reacquisition_counters(Aid::Velocity),
                ),
            }), status(&loops.aided.health())),
        },
        "autopilot_vs_gnss": {
            "alt_rms_m": sig(ap_vs_gnss.0.std(), 4),
            "alt_datum_offset_m": sig(ap_vs_gnss.0.mean, 4),
            "vz_rms_m_s": sig(ap_vs_gnss.1.rms(), 4),
            "samples": ap_vs_gnss.0.n,
        },
        "ins": ins.summary(),
        "notes": "altitude differences are RMS about their mean: the mean (datum_offset) is the constant offset between altitude datums (baro vs GNSS MSL vs the autopilot's local origin); vertical velocities are compared as they are. Comparisons start settle_s after the first IMU sample.",
    });
    crate::output::write_summary(out, &summary)?;
    plot_replay(
        &PlotData {
            rows: plot_rows.rows(),
            ap_diff: ap_diff.rows(),
            gnss_diff: gnss_diff.rows(),
            settle_s: cfg.settle_s,
        },
        &loops.tally,
        // ap_vs_gnss is autopilot − GNSS; the figure draws GNSS − autopilot.
        -ap_vs_gnss.0.mean,
        &out.join("replay.png"),
        &describe,
    )?;
    ins.plot(&out.join("ins.png"), &describe)?;
    Ok(summary)
}

/// What `replay.png` draws.
struct PlotData<'a> {
    /// At the IMU steps (≤ 20 Hz): t, baro, GNSS alt, GNSS V_z, autopilot alt, autopilot V_z,
    /// classical alt, V_z, aided alt, V_z.
    rows: &'a [[f64; 10]],
    /// At the autopilot's samples: t, loops − autopilot (alt ×2, V_z ×2).
    ap_diff: &'a [[f64; 5]],
    /// At the GNSS samples: t, GNSS − autopilot (alt, V_z).
    gnss_diff: &'a [[f64; 3]],
    settle_s: f64,
}

fn plot_replay(
    d: &PlotData,
    tally: &[LoopTally; 2],
    gnss_minus_ap_mean_m: f64,
    path: &Path,
    title: &str,
) -> Result<()> {
    let col = |k: usize| d.rows.iter().map(|r| r[k]).collect::<Vec<f64>>();
    let t = col(0);
    let (baro, gnss, gnss_vz, ap, ap_vz, c_alt, c_vz, a_alt, a_vz) = (
        col(1),
        col(2),
        col(3),
        col(4),
        col(5),
        col(6),
        col(7),
        col(8),
        col(9),
    );
    // References shifted into the classical loop's (baro) datum by their mean offset.
    let shift = |v: &[f64], off: f64| v.iter().map(|x| x + off).collect::<Vec<f64>>();
    let mean_or_zero = |m: &Moments| if m.n > 0 { m.mean } else { 0.0 };
    let gnss_off = mean_or_zero(&tally[0].alt_vs_gnss);
    let ap_off = mean_or_zero(&tally[0].alt_vs_autopilot);
    let gnss_s = shift(&gnss, gnss_off);
    let ap_s = shift(&ap, ap_off);
    let dcol = |k: usize, off: f64| d.ap_diff.iter().map(|r| r[k] - off).collect::<Vec<f64>>();
    let td = dcol(0, 0.0);
    let gcol = |k: usize, off: f64| d.gnss_diff.iter().map(|r| r[k] - off).collect::<Vec<f64>>();
    let tg = gcol(0, 0.0);
    let g_off = if gnss_minus_ap_mean_m.is_finite() {
        gnss_minus_ap_mean_m
    } else {
        0.0
    };
    let settle = format!("statistics from t = {} s", d.settle_s);
    let fig = Figure {
        title: format!("Vertical loops on the log: {title}"),
        x_label: "time since the first IMU sample, s".into(),
        columns: 1,
        panels: vec![
            Panel {
                title: format!(
                    "altitude (baro datum; GNSS shifted {:+.1} m, autopilot {:+.1} m: their mean offsets)",
                    gnss_off, ap_off
                ),
                y_label: "altitude, m".into(),
                series: vec![
                    Series::line("autopilot estimate", &t, &ap_s, 3),
                    Series::line("GNSS", &t, &gnss_s, 2),
                    Series {
                        style: plot::Style::Points,
                        ..Series::line("baro", &t, &baro, 7)
                    },
                    Series::line("classical loop", &t, &c_alt, 0),
                    Series::line("aided loop", &t, &a_alt, 1),
                ],
                y_range: None,
            },
            Panel {
                title: "vertical velocity (up positive)".into(),
                y_label: "V_up, m/s".into(),
                series: vec![
                    Series::line("GNSS", &t, &gnss_vz, 2),
                    Series::line("autopilot estimate", &t, &ap_vz, 3),
                    Series::line("classical loop", &t, &c_vz, 0),
                    Series::line("aided loop", &t, &a_vz, 1),
                ],
                y_range: None,
            },
            Panel {
                title: format!(
                    "altitude difference to the autopilot at its samples, mean offset removed ({settle})"
                ),
                y_label: "Δh, m".into(),
                series: vec![
                    Series::dashed("GNSS − autopilot (at GNSS samples)", &tg, &gcol(1, g_off), 2),
                    Series::line(
                        "classical − autopilot",
                        &td,
                        &dcol(1, mean_or_zero(&tally[0].alt_vs_autopilot)),
                        0,
                    ),
                    Series::line(
                        "aided − autopilot",
                        &td,
                        &dcol(2, mean_or_zero(&tally[1].alt_vs_autopilot)),
                        1,
                    ),
                ],
                y_range: None,
            },
            Panel {
                title: format!("vertical-velocity difference to the autopilot at its samples ({settle})"),
                y_label: "ΔV_up, m/s".into(),
                series: vec![
                    Series::dashed("GNSS − autopilot (at GNSS samples)", &tg, &gcol(2, 0.0), 2),
                    Series::line("classical − autopilot", &td, &dcol(3, 0.0), 0),
                    Series::line("aided − autopilot", &td, &dcol(4, 0.0), 1),
                ],
                y_range: None,
            },
        ],
    };
    plot::render(&fig, path, 1400, 1600)
}

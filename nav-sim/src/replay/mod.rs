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

mod figure;
pub mod ins;
mod log_checks;
mod loops;
mod pass;
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

use figure::*;
use log_checks::*;
use loops::*;
use pass::Pass;

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

/// Replays `log` with `cfg`, writing into `out`; returns the summary.
pub fn replay(log: &Path, cfg: &ReplayConfig, out: &Path) -> Result<Value> {
    cfg.ins.validate()?;
    let pre = prescan(log)?;
    let mut loops = configure_loops(cfg, &pre)?;

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
    let mut pass = Pass::new(log, cfg, pre.first_imu);
    let mut src = source::open(log)?;
    for ev in src.by_ref() {
        let ev = ev?;
        pass.stats
            .entry(ev.stream())
            .or_default()
            .add(ev.time(), cfg.gap_factor);
        if ev.time() < pre.first_imu {
            continue; // aids before the first IMU sample: nothing to aid yet
        }
        ins.on_event(&ev);
        pass.on_event(ev, &mut loops, &mut csv, &ins)?;
    }
    csv.flush()?;
    let describe = src.describe();
    let findings = src.findings();
    let summary = summary_json(&describe, findings, &pre, cfg, &pass, &loops, &ins);
    crate::output::write_summary(out, &summary)?;
    plot_replay(
        &PlotData {
            rows: pass.plot_rows.rows(),
            ap_diff: pass.ap_diff.rows(),
            gnss_diff: pass.gnss_diff.rows(),
            settle_s: cfg.settle_s,
        },
        &loops.tally,
        // ap_vs_gnss is autopilot − GNSS; the figure draws GNSS − autopilot.
        -pass.ap_vs_gnss.0.mean,
        &out.join("replay.png"),
        &describe,
    )?;
    ins.plot(&out.join("ins.png"), &describe)?;
    Ok(summary)
}

/// The two loops for the log (`pre`: its IMU interval, first IMU time and baro altitude)
/// with the replay's settings and gate.
fn configure_loops(cfg: &ReplayConfig, pre: &PreScan) -> Result<Loops> {
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
    Ok(loops)
}

/// A loop's health at the end of the log.
fn status(st: &Health) -> Value {
    json!({
        "health_at_end": format!("{:?}", st.state),
        "imu_gaps_bridged": st.gaps_bridged,
        "imu_gaps_skipped": st.gaps_reset,
        "estimate_limited_steps": st.limits_hit,
    })
}

/// One loop's part of the summary: its status, counters and differences to the GNSS and the
/// autopilot (settled part of the log), and its final estimate.
fn loop_summary(tl: &LoopTally, counters: Value, st: Value) -> Value {
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
}

/// An aid's gate counters.
fn counters(
    c: nav_core::AidCounters,
    r: nav_core::vertical_channel::ReacquisitionCounters,
) -> Value {
    json!({
        "accepted": c.fused, "rejected": c.rejected,
        "reacquisitions": r.reacquisitions, "resets": r.resets,
    })
}

/// `summary.json`: the log, its streams and findings, the baro-unit check, each loop's
/// status, counters and differences to the GNSS and the autopilot, the autopilot against the
/// GNSS, the INS.
fn summary_json(
    describe: &str,
    findings: Value,
    pre: &PreScan,
    cfg: &ReplayConfig,
    pass: &Pass,
    loops: &Loops,
    ins: &ins::InsReplay,
) -> Value {
    json!({
        "log": describe,
        "imu_dt_s": pre.imu_dt_s,
        "settle_s": cfg.settle_s,
        "streams": pass.stats.iter().map(|(s, st)| (s.name().to_string(), st.summary(pre.first_imu))).collect::<serde_json::Map<_, _>>(),
        "aid_samples_superseded": { "baro": pass.superseded_baro, "gnss": pass.superseded_gnss },
        "log_findings": findings,
        "baro_units_check": pass.baro_units.summary(),
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
            "alt_rms_m": sig(pass.ap_vs_gnss.0.std(), 4),
            "alt_datum_offset_m": sig(pass.ap_vs_gnss.0.mean, 4),
            "vz_rms_m_s": sig(pass.ap_vs_gnss.1.rms(), 4),
            "samples": pass.ap_vs_gnss.0.n,
        },
        "ins": ins.summary(),
        "notes": "altitude differences are RMS about their mean: the mean (datum_offset) is the constant offset between altitude datums (baro vs GNSS MSL vs the autopilot's local origin); vertical velocities are compared as they are. Comparisons start settle_s after the first IMU sample.",
    })
}

//! `mission-fault`: faults in the chain on the mission — late and missing master data, baro
//! spike and freeze, seeker loss of lock and false lock, an IMU gap and accelerometer clipping
//! — injected into the flight computer's inputs ([`super::sensors::MissionFaults`]); each run
//! is flown with the faults and without (baseline) on the same numbers. Per fault the summary
//! reports what the navigator did in the window (aid states, phase, degradations), and the
//! error against σ there: the largest ensemble RMS / σ of the position per axis, the mean NEES
//! against its band, and the same for the baseline.

use super::navigator_setup::Variant;
use super::report::{reduce, FlightRecord, VariantStats};
use super::run::simulate_run;
use super::sensors::{MissionFaults, ValueWindow};
use super::MissionScenario;
use crate::consistency::nees_band_95;
use crate::montecarlo::monte_carlo;
use crate::output::sig;
use crate::scenario::{Context, Kind};
use crate::scenarios::seeker_ins::injection::{Clipping, FalseLock, Faults, Window};
use anyhow::{anyhow, Result};
use serde::Deserialize;
use serde_json::{json, Map, Value};

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "mission-fault",
    about: "flight navigator under faults in the chain (master late/missing, baro spike/freeze, seeker loss/false lock, IMU gap/clipping)",
    run,
};

/// The `[faults]` table (times in s from take-off).
#[derive(Debug, Clone, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultTable {
    /// Extra bus latency (`value`, s) of the master messages valid in a window.
    #[serde(default)]
    pub master_late: Vec<ValueWindow>,
    /// Master messages lost, `[start_s, duration_s]`.
    #[serde(default)]
    pub master_missing: Vec<Window>,
    /// Baro offset (`value`, m) in a window.
    #[serde(default)]
    pub baro_spike: Vec<ValueWindow>,
    /// Baro reading frozen through a window.
    #[serde(default)]
    pub baro_freeze: Vec<Window>,
    /// Seeker loss of lock windows.
    #[serde(default)]
    pub loss_of_lock: Vec<Window>,
    /// Seeker false locks.
    #[serde(default)]
    pub false_lock: Vec<FalseLock>,
    /// IMU samples lost.
    #[serde(default)]
    pub imu_gap: Vec<Window>,
    /// Vibration bursts that clip the accelerometers (flagged to the navigator).
    #[serde(default)]
    pub clipping: Vec<Clipping>,
}

impl FaultTable {
    /// The faults as the input generator takes them.
    pub fn faults(&self) -> MissionFaults {
        MissionFaults {
            imu_seeker: Faults {
                loss_of_lock: self.loss_of_lock.clone(),
                false_lock: self.false_lock.clone(),
                clipping: self.clipping.clone(),
                flag_clipped: true,
                imu_gap: self.imu_gap.clone(),
                policy: None,
            },
            master_late: self.master_late.clone(),
            master_missing: self.master_missing.clone(),
            baro_spike: self.baro_spike.clone(),
            baro_freeze: self.baro_freeze.clone(),
        }
    }

    /// Every fault: name, start, end (s).
    pub fn windows(&self) -> Vec<(String, f64, f64)> {
        let mut w = Vec::new();
        let mut add = |name: &str, s: f64, d: f64| w.push((name.to_string(), s, s + d));
        for v in &self.master_late {
            add(
                &format!("master_late_{}ms", (v.value * 1e3).round()),
                v.start_s,
                v.duration_s,
            );
        }
        for v in &self.master_missing {
            add("master_missing", v[0], v[1]);
        }
        for v in &self.baro_spike {
            add(&format!("baro_spike_{}m", v.value), v.start_s, v.duration_s);
        }
        for v in &self.baro_freeze {
            add("baro_freeze", v[0], v[1]);
        }
        for v in &self.loss_of_lock {
            add("seeker_loss_of_lock", v[0], v[1]);
        }
        for v in &self.false_lock {
            add(
                &format!("seeker_false_lock_{}deg", v.offset_deg),
                v.start_s,
                v.duration_s,
            );
        }
        for v in &self.imu_gap {
            add("imu_gap", v[0], v[1]);
        }
        for v in &self.clipping {
            add("accel_clipping", v.start_s, v.duration_s);
        }
        w.sort_by(|a, b| a.1.total_cmp(&b.1));
        w
    }
}

/// Seconds after a fault's end that its window of analysis extends.
pub const AFTER_S: f64 = 10.0;

/// What the navigator did in `[start, end + AFTER_S]`: aid-state tags counted over runs,
/// phases, and the error against σ.
pub fn window_report(
    records: &[&FlightRecord],
    stats: &VariantStats,
    base: &VariantStats,
    start: f64,
    end: f64,
) -> Value {
    let hi = end + AFTER_S;
    let inside = |t: f64| t >= start - 1e-9 && t <= hi + 1e-9;
    let mut tags: Vec<(String, u64)> = Vec::new();
    for r in records {
        for (_, _, ts) in r.events.iter().filter(|(t, _, _)| inside(*t)) {
            for tag in ts {
                match tags.iter_mut().find(|(k, _)| k == tag) {
                    Some((_, n)) => *n += 1,
                    None => tags.push((tag.clone(), 1)),
                }
            }
        }
    }
    let mut tag_map = Map::new();
    for (k, v) in tags {
        tag_map.insert(k, json!(v));
    }
    let mut phases: Vec<&str> = Vec::new();
    for k in 0..stats.t_s.len() {
        if inside(stats.t_s[k]) {
            if let Some(p) = stats.phase[k] {
                if !phases.contains(&p.name()) {
                    phases.push(p.name());
                }
            }
        }
    }
    let measure = |v: &VariantStats| {
        let ks: Vec<usize> = (0..v.t_s.len()).filter(|&k| inside(v.t_s[k])).collect();
        let ratio: Vec<f64> = (0..3)
            .map(|c| {
                ks.iter()
                    .map(|&k| v.rms[c][k] / v.sigma[c][k])
                    .fold(0.0, f64::max)
            })
            .collect();
        let peak: Vec<f64> = (0..3)
            .map(|c| ks.iter().map(|&k| v.rms[c][k]).fold(0.0, f64::max))
            .collect();
        let nees =
            ks.iter().map(|&k| v.consistency.nees_mean[k]).sum::<f64>() / ks.len().max(1) as f64;
        json!({
            "peak_position_rms_m": peak.iter().map(|x| sig(*x, 4)).collect::<Vec<_>>(),
            "max_rms_over_sigma_position": ratio.iter().map(|x| sig(*x, 3)).collect::<Vec<_>>(),
            "nees_mean": sig(nees, 4),
        })
    };
    let (lo, hi_band) = nees_band_95(stats.consistency.dof, stats.consistency.runs);
    json!({
        "window_s": [start, sig(hi, 5)],
        "phases": phases,
        "aid_states_counted_over_runs": Value::Object(tag_map),
        "faulted": measure(stats),
        "baseline": measure(base),
        "nees_band_95": [sig(lo, 4), sig(hi_band, 4)],
    })
}

/// The fault scenario file (besides the header): the mission scenario it flies and the
/// faults.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
struct FaultFile {
    /// Base scenario file (`nav-sim/scenarios/<base>.toml`, kind `mission`).
    base: String,
    /// The faults.
    faults: FaultTable,
}

/// The base scenario and the faults of a fault scenario table.
fn parse(params: &toml::Table) -> Result<(MissionScenario, FaultTable)> {
    let f = FaultFile::deserialize(toml::Value::Table(params.clone()))?;
    let (sc, _) = super::load_scenario(&f.base)?;
    Ok((sc, f.faults))
}

fn run(ctx: &Context) -> Result<Value> {
    let (mut sc, table) = parse(&ctx.params)?;
    sc.variants = vec![Variant::Full];
    let faults = table.faults();
    let results = monte_carlo(&ctx.name, ctx.runs, ctx.seed, ctx.progress, |i, rng| {
        let rng_base = &mut rng.clone();
        let f = simulate_run(
            &sc.mission,
            &sc.navigator,
            &sc.variants,
            &faults,
            false,
            rng,
        )?;
        let b = simulate_run(
            &sc.mission,
            &sc.navigator,
            &sc.variants,
            &MissionFaults::default(),
            false,
            rng_base,
        )?;
        anyhow::Ok((f, b)).map_err(|e| anyhow!("run {i}: {e}"))
    })
    .into_iter()
    .collect::<Result<Vec<_>>>()?;
    let rec_f: Vec<&FlightRecord> = results.iter().map(|(f, _)| &f.records[0]).collect();
    let rec_b: Vec<&FlightRecord> = results.iter().map(|(_, b)| &b.records[0]).collect();
    let stats = reduce("faulted", &rec_f);
    let base = reduce("baseline", &rec_b);
    let mut per_fault = Map::new();
    for (name, s, e) in table.windows() {
        per_fault.insert(name, window_report(&rec_f, &stats, &base, s, e));
    }
    super::report::error_figure(
        &stats,
        &format!(
            "{}: full chain under faults ({} runs)",
            ctx.name, stats.runs
        ),
        &ctx.out_dir.join("errors.png"),
    )?;
    super::report::nees_figure(
        &[&stats, &base],
        &format!("{}: NEES with the faults and without", ctx.name),
        &ctx.out_dir.join("nees.png"),
    )?;
    Ok(json!({
        "faults": Value::Object(per_fault),
        "faulted": stats.summary(),
        "baseline": base.summary(),
        "after_s": AFTER_S,
    }))
}

/// A shipped fault scenario's base and faults (for tests).
pub fn load(name: &str) -> Result<(MissionScenario, FaultTable)> {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
    for k in ["kind", "description", "runs", "seed"] {
        doc.remove(k);
    }
    parse(&doc)
}

//! What a mission run records (the navigator's error against the truth and its σ, NEES of
//! the 9 navigation states, the phase, the hand-over) and the ensemble statistics, summary and
//! figures of a variant.

use crate::consistency::{nees_band_95, Consistency, RunConsistency};
use crate::output::sig;
use crate::plot::{render, Figure, Panel, Series};
use anyhow::Result;
use serde_json::{json, Map, Value};
use std::path::Path;
#[path = "bias.rs"]
pub mod bias;

/// Names of the 9 navigation error components (position NED m, velocity NED m/s, attitude
/// misalignment φ NED rad), in the navigator's covariance order.
pub const COMPONENTS: [&str; 9] = [
    "pos_n", "pos_e", "pos_d", "vel_n", "vel_e", "vel_d", "att_n", "att_e", "att_d",
];
/// States in the NEES.
pub const NAV_DOF: usize = 9;
/// The state groups of the per-group NEES (3 states each: components `3g..3g + 3`).
pub const GROUPS: [&str; 3] = ["position", "velocity", "attitude"];

/// The navigator's phase as recorded (mirrors `nav_core::navigator::Phase`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum PhaseTag {
    /// Under the wing, transfer alignment.
    Carry,
    /// Released, EKF predicting only.
    Released,
    /// Baro-damped midcourse.
    Midcourse,
    /// Seeker updates.
    Terminal,
}

impl PhaseTag {
    /// All phases in mission order.
    pub const ALL: [Self; 4] = [Self::Carry, Self::Released, Self::Midcourse, Self::Terminal];

    /// Name in outputs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Carry => "carry",
            Self::Released => "released",
            Self::Midcourse => "midcourse",
            Self::Terminal => "terminal",
        }
    }
}

/// The attitude at the hand-over: error against the truth and the σ the EKF starts with.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandoverSample {
    /// Time of the hand-over, s.
    pub t_s: f64,
    /// Attitude error φ (NED), rad.
    pub err_rad: [f64; 3],
    /// Its σ per axis, rad.
    pub sigma_rad: [f64; 3],
    /// NEES of the 3 attitude states (full 3 × 3 block).
    pub nees: f64,
}

/// One run of one variant.
#[derive(Debug, Clone, Default)]
pub struct FlightRecord {
    /// Output epochs, s.
    pub t_s: Vec<f64>,
    /// The navigator's phase at each epoch.
    pub phase: Vec<Option<PhaseTag>>,
    /// Error (navigator − truth) of the 9 components ([`COMPONENTS`]).
    pub err: Vec<[f64; 9]>,
    /// The navigator's σ of the same.
    pub sigma: Vec<[f64; 9]>,
    /// NEES of the 9 states and `e²/σ²` per component, per epoch.
    pub consistency: RunConsistency,
    /// NEES of the position, velocity and attitude 3 × 3 blocks ([`GROUPS`]), per epoch.
    pub group_nees: Vec<[f64; 3]>,
    /// The accelerometer-bias states at the same epochs.
    pub bias: bias::BiasRecord,
    /// The hand-over (none if the run never released through the alignment).
    pub handover: Option<HandoverSample>,
    /// Phase transitions: time, new phase.
    pub transitions: Vec<(f64, PhaseTag)>,
    /// Aid outcomes over the run: (aid, outcome) → count.
    pub aid_counts: Vec<(String, u64)>,
    /// Ticks at which an aid was not nominal (rejected, refused, timed out) or the
    /// navigator reported a degradation: time, phase, `aid.state` tags.
    pub events: Vec<(f64, PhaseTag, Vec<String>)>,
}

/// Ensemble statistics of one variant.
#[derive(Debug, Clone)]
pub struct VariantStats {
    /// Variant name.
    pub name: String,
    /// Runs.
    pub runs: usize,
    /// Output epochs, s.
    pub t_s: Vec<f64>,
    /// The phase most runs are in at each epoch.
    pub phase: Vec<Option<PhaseTag>>,
    /// Ensemble RMS of each component per epoch.
    pub rms: [Vec<f64>; 9],
    /// √(mean over runs of the navigator's variance) per component and epoch.
    pub sigma: [Vec<f64>; 9],
    /// NEES of the 9 states over the whole mission.
    pub consistency: Consistency,
    /// Per phase (by the modal phase of the epochs): its consistency (no settling time) and
    /// its span, s.
    pub phases: Vec<(PhaseTag, Consistency, (f64, f64))>,
    /// Per phase (as `phases`): the accelerometer-bias states (`bias::phase_bias`).
    pub bias_phases: Vec<(PhaseTag, Consistency, bias::BiasRms)>,
    /// Per phase (as `phases`): the ensemble mean of each group's NEES ([`GROUPS`], 3 states
    /// each) over runs and the phase's epochs.
    pub group_nees: Vec<(PhaseTag, [f64; 3])>,
    /// Hand-over samples of the runs.
    pub handover: Vec<HandoverSample>,
    /// Mean time of each phase's first entry over the runs that entered it, s.
    pub phase_entry_s: Vec<(PhaseTag, f64, usize)>,
    /// Aid outcome counts summed over runs.
    pub aid_counts: Vec<(String, u64)>,
}

fn modal(phases: &[Option<PhaseTag>]) -> Option<PhaseTag> {
    PhaseTag::ALL
        .iter()
        .map(|p| (*p, phases.iter().filter(|q| **q == Some(*p)).count()))
        .filter(|(_, n)| *n > 0)
        .max_by_key(|(_, n)| *n)
        .map(|(p, _)| p)
}

/// Ensemble statistics of the runs of one variant (all of the same epochs; a shorter run
/// limits the series).
pub fn reduce(name: &str, records: &[&FlightRecord]) -> VariantStats {
    let n = records.iter().map(|r| r.t_s.len()).min().unwrap_or(0);
    let runs = records.len().max(1);
    let t_s: Vec<f64> = records
        .first()
        .map(|r| r.t_s[..n].to_vec())
        .unwrap_or_default();
    let phase: Vec<Option<PhaseTag>> = (0..n)
        .map(|k| modal(&records.iter().map(|r| r.phase[k]).collect::<Vec<_>>()))
        .collect();
    let rms: [Vec<f64>; 9] = std::array::from_fn(|c| {
        (0..n)
            .map(|k| {
                (records.iter().map(|r| r.err[k][c].powi(2)).sum::<f64>() / runs as f64).sqrt()
            })
            .collect()
    });
    let sigma: [Vec<f64>; 9] = std::array::from_fn(|c| {
        (0..n)
            .map(|k| {
                (records.iter().map(|r| r.sigma[k][c].powi(2)).sum::<f64>() / runs as f64).sqrt()
            })
            .collect()
    });
    let cons: Vec<RunConsistency> = records.iter().map(|r| r.consistency.clone()).collect();
    let consistency = Consistency::from_runs(NAV_DOF, &cons);
    let phases = phase_consistency(NAV_DOF, &cons, &phase, &t_s);
    let group_nees = phase_group_nees(records, &phase);
    let phase_entry_s = phase_entries(records);
    let aid_counts = total_aid_counts(records);
    let bias_phases = bias::phase_bias(records, &phase, &t_s);
    VariantStats {
        name: name.to_string(),
        runs: records.len(),
        t_s,
        phase,
        rms,
        sigma,
        consistency,
        phases,
        bias_phases,
        group_nees,
        handover: records.iter().filter_map(|r| r.handover).collect(),
        phase_entry_s,
        aid_counts,
    }
}

/// Per phase (the epochs whose modal phase it is): the consistency of the runs over them and
/// the phase's first and last epoch, s.
pub(super) fn phase_consistency(
    dof: usize,
    cons: &[RunConsistency],
    phase: &[Option<PhaseTag>],
    t_s: &[f64],
) -> Vec<(PhaseTag, Consistency, (f64, f64))> {
    let n = phase.len();
    PhaseTag::ALL
        .iter()
        .filter_map(|p| {
            let keep: Vec<usize> = (0..n).filter(|&k| phase[k] == Some(*p)).collect();
            let (first, last) = (keep.first()?, keep.last()?);
            let sub: Vec<RunConsistency> = cons
                .iter()
                .map(|c| RunConsistency {
                    t_s: keep.iter().map(|&k| c.t_s[k]).collect(),
                    nees: keep.iter().map(|&k| c.nees[k]).collect(),
                    normalized: c
                        .normalized
                        .iter()
                        .map(|(name, v)| (name.clone(), keep.iter().map(|&k| v[k]).collect()))
                        .collect(),
                })
                .collect();
            Some((
                *p,
                Consistency::from_runs_settled(dof, &sub, 0.0),
                (t_s[*first], t_s[*last]),
            ))
        })
        .collect()
}

/// Per phase: the mean over runs and the phase's epochs of the three group NEES.
fn phase_group_nees(
    records: &[&FlightRecord],
    phase: &[Option<PhaseTag>],
) -> Vec<(PhaseTag, [f64; 3])> {
    let n = phase.len();
    PhaseTag::ALL
        .iter()
        .filter_map(|p| {
            let keep: Vec<usize> = (0..n).filter(|&k| phase[k] == Some(*p)).collect();
            if keep.is_empty() {
                return None;
            }
            let count = (keep.len() * records.len()) as f64;
            let mean: [f64; 3] = std::array::from_fn(|g| {
                records
                    .iter()
                    .map(|r| keep.iter().map(|&k| r.group_nees[k][g]).sum::<f64>())
                    .sum::<f64>()
                    / count
            });
            Some((*p, mean))
        })
        .collect()
}

/// Per phase: the mean entry time over the runs that entered it, s, and their number.
fn phase_entries(records: &[&FlightRecord]) -> Vec<(PhaseTag, f64, usize)> {
    PhaseTag::ALL
        .iter()
        .map(|p| {
            let entries: Vec<f64> = records
                .iter()
                .filter_map(|r| r.transitions.iter().find(|(_, q)| q == p).map(|(t, _)| *t))
                .collect();
            let m = entries.iter().sum::<f64>() / entries.len().max(1) as f64;
            (*p, m, entries.len())
        })
        .collect()
}

/// The aids' counts summed over the runs, in order of first appearance.
fn total_aid_counts(records: &[&FlightRecord]) -> Vec<(String, u64)> {
    let mut aid_counts: Vec<(String, u64)> = Vec::new();
    for r in records {
        for (k, v) in &r.aid_counts {
            match aid_counts.iter_mut().find(|(a, _)| a == k) {
                Some((_, s)) => *s += v,
                None => aid_counts.push((k.clone(), *v)),
            }
        }
    }
    aid_counts
}

impl VariantStats {
    /// RMS over runs of component `c` at the last epoch.
    pub fn final_rms(&self, c: usize) -> f64 {
        self.rms[c].last().copied().unwrap_or(f64::NAN)
    }

    /// RMS over runs and the epochs of a phase of component `c` (NaN if the phase is absent).
    pub fn phase_rms(&self, p: PhaseTag, c: usize) -> f64 {
        let v: Vec<f64> = (0..self.t_s.len())
            .filter(|&k| self.phase[k] == Some(p))
            .map(|k| self.rms[c][k].powi(2))
            .collect();
        if v.is_empty() {
            return f64::NAN;
        }
        (v.iter().sum::<f64>() / v.len() as f64).sqrt()
    }

    /// Largest RMS of component `c` over the epochs of a phase (NaN if absent).
    pub fn phase_max_rms(&self, p: PhaseTag, c: usize) -> f64 {
        (0..self.t_s.len())
            .filter(|&k| self.phase[k] == Some(p))
            .map(|k| self.rms[c][k])
            .fold(f64::NAN, f64::max)
    }

    /// Hand-over: RMS attitude error per axis (mrad), mean `e²/σ²` per axis and over the
    /// axes, mean NEES of the 3 attitude states / 3.
    pub fn handover_summary(&self) -> Value {
        if self.handover.is_empty() {
            return Value::Null;
        }
        let n = self.handover.len() as f64;
        // Per axis, the ensemble mean of `f(sample, axis)`.
        let axis_mean = |f: &dyn Fn(&HandoverSample, usize) -> f64| -> Vec<f64> {
            (0..3)
                .map(|a| self.handover.iter().map(|h| f(h, a)).sum::<f64>() / n)
                .collect()
        };
        let rms: Vec<f64> = axis_mean(&|h, a| h.err_rad[a].powi(2))
            .iter()
            .map(|m| m.sqrt() * 1e3)
            .collect();
        let nes = axis_mean(&|h, a| (h.err_rad[a] / h.sigma_rad[a]).powi(2));
        let sig_mrad: Vec<f64> = axis_mean(&|h, a| h.sigma_rad[a].powi(2))
            .iter()
            .map(|m| m.sqrt() * 1e3)
            .collect();
        let nees = self.handover.iter().map(|h| h.nees).sum::<f64>() / n;
        let (lo, hi) = nees_band_95(3, self.handover.len());
        json!({
            "runs": self.handover.len(),
            "time_s": sig(self.handover.iter().map(|h| h.t_s).sum::<f64>() / n, 5),
            "attitude_rms_mrad": rms.iter().map(|v| sig(*v, 4)).collect::<Vec<_>>(),
            "attitude_rms_total_mrad": sig(rms.iter().map(|v| v * v).sum::<f64>().sqrt(), 4),
            "attitude_sigma_mrad": sig_mrad.iter().map(|v| sig(*v, 4)).collect::<Vec<_>>(),
            "normalized_error_sq": nes.iter().map(|v| sig(*v, 4)).collect::<Vec<_>>(),
            "normalized_error_sq_mean": sig(nes.iter().sum::<f64>() / 3.0, 4),
            "attitude_nees_per_dof": sig(nees / 3.0, 4),
            "band_95_of_mean_per_dof": [sig(lo / 3.0, 4), sig(hi / 3.0, 4)],
        })
    }

    /// The variant's `summary.json` object.
    pub fn summary(&self) -> Value {
        let mut phases = Map::new();
        for (p, c, (a, b)) in &self.phases {
            let comp = |i: usize| sig(self.phase_rms(*p, i), 4);
            let groups =
                self.group_nees
                    .iter()
                    .find(|(q, _)| q == p)
                    .map_or(Value::Null, |(_, g)| {
                        let mut m = Map::new();
                        for (name, v) in GROUPS.iter().zip(g) {
                            m.insert((*name).into(), json!(sig(*v, 4)));
                        }
                        Value::Object(m)
                    });
            phases.insert(
                p.name().into(),
                json!({
                    "span_s": [sig(*a, 5), sig(*b, 5)],
                    "rms": {
                        "north_m": comp(0), "east_m": comp(1), "down_m": comp(2),
                        "vel_north_m_s": comp(3), "vel_east_m_s": comp(4), "vel_down_m_s": comp(5),
                        "att_north_mrad": sig(self.phase_rms(*p, 6) * 1e3, 4),
                        "att_east_mrad": sig(self.phase_rms(*p, 7) * 1e3, 4),
                        "att_down_mrad": sig(self.phase_rms(*p, 8) * 1e3, 4),
                    },
                    "max_rms_down_m": sig(self.phase_max_rms(*p, 2), 4),
                    "consistency": c.summary(),
                    "group_nees_mean": groups,
                    "accel_bias_states": self.bias_summary(*p),
                }),
            );
        }
        let mut entries = Map::new();
        for (p, t, n) in &self.phase_entry_s {
            entries.insert(
                p.name().into(),
                json!({ "mean_entry_s": if *n > 0 { json!(sig(*t, 5)) } else { Value::Null }, "runs": n }),
            );
        }
        let mut aids = Map::new();
        for (k, v) in &self.aid_counts {
            aids.insert(k.clone(), json!(v));
        }
        json!({
            "runs": self.runs,
            "final_rms": {
                "north_m": sig(self.final_rms(0), 4),
                "east_m": sig(self.final_rms(1), 4),
                "down_m": sig(self.final_rms(2), 4),
                "horizontal_m": sig(self.final_rms(0).hypot(self.final_rms(1)), 4),
                "vel_m_s": [sig(self.final_rms(3), 4), sig(self.final_rms(4), 4), sig(self.final_rms(5), 4)],
            },
            "handover": self.handover_summary(),
            "consistency": self.consistency.summary(),
            "phases": Value::Object(phases),
            "phase_entries": Value::Object(entries),
            "aid_outcomes": Value::Object(aids),
        })
    }

    /// Phase boundaries (modal phase changes), s.
    pub fn boundaries(&self) -> Vec<(f64, PhaseTag)> {
        let mut out = Vec::new();
        for k in 1..self.t_s.len() {
            if let (Some(p), true) = (self.phase[k], self.phase[k] != self.phase[k - 1]) {
                out.push((self.t_s[k], p));
            }
        }
        out
    }
}

/// Vertical dashed lines at the phase boundaries spanning `(lo, hi)`.
fn boundary_series(b: &[(f64, PhaseTag)], lo: f64, hi: f64) -> Vec<Series> {
    b.iter()
        .enumerate()
        .map(|(i, (t, p))| {
            Series::dashed(
                if i < 4 {
                    format!("→ {}", p.name())
                } else {
                    String::new()
                },
                &[*t, *t],
                &[lo, hi],
                4 + i % 3,
            )
        })
        .collect()
}

/// `errors.csv`: per epoch, the modal phase, the ensemble RMS error and the navigator's σ
/// (root-mean-square over runs) of the 9 components ([`COMPONENTS`]; m, m/s, rad).
pub fn error_csv(v: &VariantStats, path: &Path) -> Result<()> {
    let mut out = String::from("t_s,phase");
    for c in COMPONENTS {
        out.push_str(&format!(",rms_{c}"));
    }
    for c in COMPONENTS {
        out.push_str(&format!(",sigma_{c}"));
    }
    out.push('\n');
    for k in 0..v.t_s.len() {
        out.push_str(&format!(
            "{},{}",
            v.t_s[k],
            v.phase[k].map_or("none", PhaseTag::name)
        ));
        for c in 0..9 {
            out.push_str(&format!(",{:.6e}", v.rms[c][k]));
        }
        for c in 0..9 {
            out.push_str(&format!(",{:.6e}", v.sigma[c][k]));
        }
        out.push('\n');
    }
    std::fs::write(path, out)?;
    Ok(())
}

/// `errors.png`: RMS error and the navigator's σ of position, velocity and attitude (per
/// NED axis) through all phases, phase boundaries marked; values on a log₁₀ axis.
pub fn error_figure(v: &VariantStats, title: &str, path: &Path) -> Result<()> {
    let b = v.boundaries();
    let groups = [
        ("position", "log₁₀ m", 0usize, 1.0),
        ("velocity", "log₁₀ m/s", 3, 1.0),
        ("attitude", "log₁₀ mrad", 6, 1e3),
    ];
    let axes = ["N", "E", "D"];
    let mut panels = Vec::new();
    for (g, unit, c0, scale) in groups {
        let mut series = Vec::new();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (a, axis) in axes.iter().enumerate() {
            let l = |x: &Vec<f64>| -> Vec<f64> {
                x.iter().map(|v| (v * scale).max(1e-6).log10()).collect()
            };
            let r = l(&v.rms[c0 + a]);
            let s = l(&v.sigma[c0 + a]);
            for x in r.iter().chain(&s).filter(|x| x.is_finite()) {
                lo = lo.min(*x);
                hi = hi.max(*x);
            }
            series.push(Series::line(format!("RMS {axis}"), &v.t_s, &r, a));
            series.push(Series::dashed(format!("σ {axis}"), &v.t_s, &s, a));
        }
        series.extend(boundary_series(&b, lo, hi));
        panels.push(Panel {
            title: format!("{g} error: ensemble RMS (solid) and navigator σ (dashed)"),
            y_label: unit.into(),
            series,
            y_range: Some((lo - 0.1, hi + 0.1)),
        });
    }
    render(
        &Figure {
            title: title.into(),
            x_label: "time, s".into(),
            panels,
            columns: 1,
        },
        path,
        1300,
        1100,
    )
}

/// `nees.png`: run-averaged NEES of the 9 states through all phases with its 95 % band, phase
/// boundaries marked (log₁₀ axis).
pub fn nees_figure(vs: &[&VariantStats], title: &str, path: &Path) -> Result<()> {
    let panels = vs
        .iter()
        .map(|v| {
            let c = &v.consistency;
            let (lo, hi) = nees_band_95(c.dof, c.runs);
            let l = |x: f64| x.max(1e-3).log10();
            let y: Vec<f64> = c.nees_mean.iter().map(|x| l(*x)).collect();
            let ymax = y.iter().copied().fold(l(hi), f64::max);
            let ymin = y.iter().copied().fold(l(lo), f64::min);
            let mut series = vec![
                Series::line("NEES (9 states, run mean)", &c.t_s, &y, 0),
                Series::dashed("95 % band", &c.t_s, &vec![l(lo); c.t_s.len()], 3),
                Series::dashed("", &c.t_s, &vec![l(hi); c.t_s.len()], 3),
            ];
            series.extend(boundary_series(&v.boundaries(), ymin, ymax));
            Panel {
                title: format!(
                    "{}: NEES of the 9 navigation states, {} runs, band [{:.1}, {:.1}]",
                    v.name, c.runs, lo, hi
                ),
                y_label: "log₁₀ NEES".into(),
                series,
                y_range: Some((ymin - 0.1, ymax + 0.1)),
            }
        })
        .collect();
    render(
        &Figure {
            title: title.into(),
            x_label: "time, s".into(),
            panels,
            columns: 1,
        },
        path,
        1300,
        300 + 280 * vs.len() as u32,
    )
}

/// `links.png`: what each link buys — horizontal and vertical position RMS of every variant
/// through the mission (log₁₀ axis).
pub fn links_figure(vs: &[&VariantStats], title: &str, path: &Path) -> Result<()> {
    let l = |x: f64| x.max(1e-3).log10();
    let mk = |f: &dyn Fn(&VariantStats, usize) -> f64, what: &str| {
        let mut series = Vec::new();
        let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
        for (i, v) in vs.iter().enumerate() {
            let y: Vec<f64> = (0..v.t_s.len()).map(|k| l(f(v, k))).collect();
            for x in y.iter().filter(|x| x.is_finite()) {
                lo = lo.min(*x);
                hi = hi.max(*x);
            }
            series.push(Series::line(v.name.clone(), &v.t_s, &y, i));
        }
        if let Some(v) = vs.first() {
            series.extend(
                boundary_series(&v.boundaries(), lo, hi)
                    .into_iter()
                    .map(|mut s| {
                        s.label.clear();
                        s
                    }),
            );
        }
        Panel {
            title: what.into(),
            y_label: "log₁₀ m".into(),
            series,
            y_range: Some((lo - 0.1, hi + 0.1)),
        }
    };
    let panels = vec![
        mk(
            &|v, k| v.rms[0][k].hypot(v.rms[1][k]),
            "horizontal position error, ensemble RMS (dashed: phase boundaries of the first variant)",
        ),
        mk(&|v, k| v.rms[2][k], "vertical position error, ensemble RMS"),
    ];
    render(
        &Figure {
            title: title.into(),
            x_label: "time, s".into(),
            panels,
            columns: 1,
        },
        path,
        1300,
        900,
    )
}

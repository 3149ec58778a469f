//! The χ² gate of the aid samples against the aid model, the recovery of a starved aid, the
//! per-aid step report and the counters.

use super::config::RunTime;
use super::samples::{secs_between, AidChannel, AidStatus, ValidSample, NEVER};
use super::MAX_GATE_VARIANCE;
use crate::contract::{AidCounters, FusionOutcome, FusionReport, Gate};
use crate::{NavError, Real};

/// What a newly arrived sample did beyond its fusion (see [`super::AidModel`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Reacquisition {
    /// No re-acquisition: the sample was fused while tracking, or rejected.
    Tracking,
    /// The sample ended a `Lost` period; the loop absorbs its innovation at its bandwidth.
    Absorbed,
    /// The sample ended a `Lost` period with an innovation beyond the tracking gate and reset
    /// the measured state (ĥ for the baro, V̂_z for the velocity aid) by it.
    Reset,
    /// The sample was accepted outside the gate and re-anchored the measured state: the
    /// starvation recovery ([`crate::RecoveryAction::Reanchor`]), or after a gap longer than
    /// [`super::MAX_BRIDGED_GAP_S`] or an estimate held at its limits.
    Reanchored,
}

/// Per-aid part of a step report.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AidReport<T> {
    /// Freshness at the end of the step (and whether the aid corrected the loop).
    pub status: AidStatus<T>,
    /// Innovation the loop corrected with in this step, `z − C x̂` of the held sample
    /// extrapolated to mid-interval (measurement unit; for the baro the prediction includes
    /// the lag compensation `ĥ − lag · V̂_z`); `None` when the aid was not in use.
    pub correction: Option<T>,
    /// The verdict on a sample that arrived in this step (`None`: no new sample). Its
    /// `innovation_variance` is the aid model's `S` ([`super::AidModel`]); `test_ratio` is
    /// `NIS / threshold`, 0 when the sample was not gated ([`Gate::Off`], an aid's first
    /// sample, or a sample accepted outside the gate). Outcomes: `Fused` (the sample
    /// replaces the held one) or `Rejected` (discarded; the held sample keeps ageing).
    pub sample: Option<FusionReport<T>>,
    /// What the new sample did beyond its fusion.
    pub reacquisition: Reacquisition,
}

/// Re-acquisition counters of one aid (saturating): the events of [`Reacquisition`] that
/// [`AidCounters`] does not tell apart.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ReacquisitionCounters {
    /// Accepted samples that ended a `Lost` period or re-anchored the loop (every
    /// [`Reacquisition`] but `Tracking`).
    pub reacquisitions: u32,
    /// Re-acquisitions that moved the measured state (`Reset` and `Reanchored`).
    pub resets: u32,
}

/// The drift model of one aid: `d = gap (rate + accel · gap)`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AidGate<T> {
    /// σ₀², unit².
    pub(crate) tracking_var: T,
    /// Drift growth, unit/s.
    pub(crate) drift_rate: T,
    /// Drift growth, unit/s².
    pub(crate) drift_accel: T,
}

/// The run-time configuration in the loop's form.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct GateParams<T> {
    /// χ² threshold (`None`: [`Gate::Off`]).
    pub(crate) threshold: Option<T>,
    pub(crate) baro: AidGate<T>,
    pub(crate) velocity: AidGate<T>,
    pub(crate) recovery_hold_s: T,
    pub(crate) starved_after_s: Option<T>,
}

impl<T: Real> GateParams<T> {
    /// Validates the run-time configuration and compiles it. Out of line: both loops'
    /// construction and the run-time setter share one copy.
    #[inline(never)]
    pub(crate) fn compile(rt: &RunTime<T>) -> Result<Self, NavError> {
        rt.validate()?;
        let m = &rt.aid_model;
        let ga = m.starved_accel_sigma_m_s2;
        Ok(Self {
            threshold: match rt.gate {
                Gate::Off => None,
                Gate::Nis(t) => Some(t),
            },
            baro: AidGate {
                tracking_var: m.baro_sigma_m * m.baro_sigma_m,
                drift_rate: m.starved_velocity_sigma_m_s,
                drift_accel: ga * T::lit(0.5),
            },
            velocity: AidGate {
                tracking_var: m.velocity_sigma_m_s * m.velocity_sigma_m_s,
                drift_rate: ga,
                drift_accel: T::zero(),
            },
            recovery_hold_s: m.recovery_hold_s,
            starved_after_s: rt.recovery.starved_after_s,
        })
    }
}

/// When a sample is lost (the aid's `lost_after_s`) and how it is extrapolated to
/// mid-interval and predicted: `z − offset + age (r₁ − r₂ age)` against `pred` (first order:
/// `r₂` unused, no offset).
#[derive(Debug, Clone, Copy)]
pub(crate) struct Extrapolation<T> {
    pub(crate) lost_after_s: T,
    pub(crate) offset: T,
    pub(crate) half_h: T,
    pub(crate) rate: T,
    pub(crate) rate_slope: T,
    pub(crate) pred: T,
}

/// The verdict on a new sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Verdict<T> {
    pub(crate) report: FusionReport<T>,
    pub(crate) reacquisition: Reacquisition,
}

/// What [`admit`] returns: the channel after a new sample, the age now of the sample it holds,
/// and the verdict.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Admitted<T> {
    /// The channel to use (`None`: no new sample, the channel is unchanged).
    pub(crate) channel: Option<AidChannel<T>>,
    /// Age now of the sample the channel holds, s.
    pub(crate) age_s: T,
    /// The verdict on the new sample (`None`: no new sample).
    pub(crate) verdict: Option<Verdict<T>>,
}

/// The [`Admitted`] of a new sample: the channel `channel` holding a sample of age `age_s`
/// now, and the verdict on it.
#[inline(always)]
fn admitted<T>(channel: AidChannel<T>, age_s: T, verdict: Verdict<T>) -> Admitted<T> {
    Admitted {
        channel: Some(channel),
        age_s,
        verdict: Some(verdict),
    }
}

#[inline(always)]
pub(crate) fn saturate<T: Real>(s: T) -> T {
    // Also catches an overflow to +∞ (s cannot be NaN: every term is finite or +∞).
    let max_var = T::lit(MAX_GATE_VARIANCE);
    if s > max_var {
        max_var
    } else {
        s
    }
}

/// The report of a sample with innovation variance `s`, tested (`Some(threshold)`) or not.
#[inline(always)]
fn report<T: Real>(innovation: T, s: T, tested: Option<T>, fused: bool) -> FusionReport<T> {
    let nis = innovation * innovation / s;
    FusionReport {
        innovation,
        innovation_variance: s,
        nis,
        test_ratio: tested.map_or(T::zero(), |thr| nis / thr),
        outcome: if fused {
            FusionOutcome::Fused
        } else {
            FusionOutcome::Rejected
        },
    }
}

/// A sample accepted outside the gate (re-anchoring): cold path.
#[cold]
#[inline(never)]
fn reanchor<T: Real>(
    mut cand: AidChannel<T>,
    innovation: T,
    model_var: T,
    params: &GateParams<T>,
    aid: &AidGate<T>,
) -> (AidChannel<T>, Verdict<T>) {
    let gated = params.threshold.is_some();
    let var0 = if gated { aid.tracking_var } else { T::zero() };
    cand.recovery_var = if gated {
        saturate(var0 + innovation * innovation)
    } else {
        T::zero()
    };
    cand.recovery_clear_since = NEVER;
    cand.rejected_since = NEVER;
    cand.reanchor = false;
    let verdict = Verdict {
        report: report(innovation, model_var, None, true),
        reacquisition: Reacquisition::Reanchored,
    };
    (cand, verdict)
}

/// Gate of one new sample (`second_order`: the baro's extrapolation). `old_age`: the held
/// sample's age now (the new sample's is its `age_s`, at the same time).
/// Returns the channel to use (`None`: `old`, unchanged), its sample's age now and the
/// verdict.
#[inline(always)]
pub(crate) fn admit<T: Real>(
    second_order: bool,
    old: &AidChannel<T>,
    old_age: T,
    sample: Option<ValidSample<T>>,
    ex: &Extrapolation<T>,
    params: &GateParams<T>,
    aid: &AidGate<T>,
) -> Admitted<T> {
    match sample {
        None => Admitted {
            channel: None,
            age_s: old_age,
            verdict: None,
        },
        Some(sample) => admit_sample(second_order, old, old_age, sample, ex, params, aid),
    }
}

/// [`admit`] of a sample that arrived: one out-of-line body for both aids (the general step's
/// path; the common case takes the nominal step's own gate).
#[inline(never)]
fn admit_sample<T: Real>(
    second_order: bool,
    old: &AidChannel<T>,
    old_age: T,
    sample: ValidSample<T>,
    ex: &Extrapolation<T>,
    params: &GateParams<T>,
    aid: &AidGate<T>,
) -> Admitted<T> {
    let mut cand = old.with(sample);
    let cand_age = sample.age_s;
    let age = cand_age - ex.half_h;
    let (value, r) = if second_order {
        (cand.last_value - ex.offset, ex.rate - ex.rate_slope * age)
    } else {
        (cand.last_value, ex.rate)
    };
    let innovation = value + age * r - ex.pred;
    let nu2 = innovation * innovation;
    // The aid model's variance: σ₀² plus the drift since the last accepted sample.
    let model_var = if old.received {
        let gap = old_age - cand_age;
        let d = gap * (aid.drift_rate + aid.drift_accel * gap);
        saturate(aid.tracking_var + d * d)
    } else {
        aid.tracking_var
    };
    let starved = match (params.threshold, params.starved_after_s) {
        (Some(_), Some(limit)) if old.rejected_since != NEVER => {
            secs_between::<T>(cand.last_time, old.rejected_since) >= limit
        }
        _ => false,
    };
    if old.reanchor || starved {
        let (cand, verdict) = reanchor(cand, innovation, model_var, params, aid);
        return admitted(cand, cand_age, verdict);
    }
    let lost = old.received && old_age > ex.lost_after_s;
    let (s, tested, pass) = match params.threshold {
        Some(thr) if old.received => {
            let s = if old.recovery_var > model_var {
                old.recovery_var
            } else {
                model_var
            };
            let pass = nu2 <= thr * s;
            if pass && lost {
                // Re-acquisition: hold a gate while the loop absorbs the coast error, no
                // wider than this sample's own innovation needs (a sample stamped long ago
                // cannot open the gate for the samples after it).
                let v = aid.tracking_var + nu2;
                cand.recovery_var = if v < s { v } else { s };
                cand.recovery_clear_since = NEVER;
            } else if pass && old.recovery_var > T::zero() {
                release_recovery(&mut cand, old, nu2 > thr * aid.tracking_var, params);
            }
            (s, Some(thr), pass)
        }
        _ => (model_var, None, true),
    };
    let reacquisition = match tested {
        Some(thr) if pass && lost && nu2 > thr * aid.tracking_var => Reacquisition::Reset,
        _ if pass && lost => Reacquisition::Absorbed,
        _ => Reacquisition::Tracking,
    };
    let verdict = Verdict {
        report: report(innovation, s, tested, pass),
        reacquisition,
    };
    if pass {
        cand.rejected_since = NEVER;
        admitted(cand, cand_age, verdict)
    } else {
        let mut kept = *old;
        if old.rejected_since == NEVER {
            kept.rejected_since = cand.last_time;
        }
        admitted(kept, old_age, verdict)
    }
}

/// The recovery gate of an accepted sample while one is held: released once the innovations
/// have stayed inside the tracking gate (`outside_tracking` false) for `recovery_hold_s`.
#[inline(always)]
fn release_recovery<T: Real>(
    cand: &mut AidChannel<T>,
    old: &AidChannel<T>,
    outside_tracking: bool,
    params: &GateParams<T>,
) {
    if outside_tracking {
        cand.recovery_clear_since = NEVER;
    } else {
        let t0 = old.recovery_clear_since;
        if t0 == NEVER {
            cand.recovery_clear_since = cand.last_time;
        } else if secs_between::<T>(cand.last_time, t0) >= params.recovery_hold_s {
            cand.recovery_var = T::zero();
            cand.recovery_clear_since = NEVER;
        }
    }
}

/// The counters of one aid.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub(crate) struct AidTally {
    pub(crate) counters: AidCounters,
    pub(crate) reacquisition: ReacquisitionCounters,
}

impl AidTally {
    /// Counts a verdict: the outcome, a re-anchoring as a recovery, the re-acquisitions.
    #[inline(always)]
    pub(crate) fn count<T>(&mut self, verdict: &Option<Verdict<T>>) {
        let Some(v) = verdict else { return };
        self.counters.record(v.report.outcome);
        let r = &mut self.reacquisition;
        match v.reacquisition {
            Reacquisition::Tracking => {}
            Reacquisition::Absorbed => r.reacquisitions = r.reacquisitions.saturating_add(1),
            Reacquisition::Reset | Reacquisition::Reanchored => {
                r.reacquisitions = r.reacquisitions.saturating_add(1);
                r.resets = r.resets.saturating_add(1);
            }
        }
        if v.reacquisition == Reacquisition::Reanchored {
            self.counters.record_recovery();
        }
    }
}

//! The flight navigator's contribution to the consistency campaign
//! ([`crate::scenarios::consistency_campaign`]): the whole chain (carry alignment → hand-over
//! → baro-damped midcourse → seeker terminal) flown in f32 as on the target, with the
//! navigator's design built from each variant's configuration exactly as the `mission`
//! scenario builds it from its file (`navigator_setup`; no per-variant tuning), over
//! randomized variants of the `mission` scenario.
//!
//! Variant `v` draws from stream `v` of the campaign seed ([`crate::rng::run_rng`]):
//!
//! | parameter | range |
//! | --- | --- |
//! | lever arm (master IMU → missile IMU, master body axes) | 1–10 m, direction uniform on the sphere |
//! | wing-flexure correlation times (truth and design) | the file's × 0.5–2 (log-uniform, one scale for the three axes) |
//! | carry manoeuvre axis | course (coordinated turn, ±10–45°, back to the course or not), flight path (±2–8°, back to level) or speed (±10–40 m/s, back) |
//! | carry manoeuvre time | start 5 s to its latest, each change over 5–20 s, the way back 2–10 s after |
//! | release | 40–100 s |
//! | speed after the boost | 100–300 m/s (carried at 20 m/s less, the file's boost) |
//! | carry and cruise altitudes | 0.5–5 km each |
//! | initial course | 0–360° |
//! | landmark bearing from the start of the midcourse turn | 0–360° (the turn aims at it, at most 2 g) |
//! | landmark range from there | 30–120 km (on the ground) |
//! | run-in | straight or S-turns (10–30° amplitude, 40–120 s period), even odds |
//!
//! Every variant flies until [`MIN_END_RANGE_M`] from the landmark (a slow, far variant flies
//! long), with the `mission.toml` sensors, master, baro, seeker and navigator settings; its
//! runs draw from the streams of a seed drawn from the variant's stream.
//!
//! Each variant returns one [`VariantResult`] per navigator phase (filter `carry`,
//! `released`, `midcourse`, `terminal`: the epochs whose modal phase it is, the 9 navigation
//! states, as the `mission` summary's `phases`), one for the hand-over (filter `handover`: the
//! attitude error and σ handed to the EKF, one epoch per run, 3 states) and one for the last
//! epoch (filter `final`: the 9 states at the end; its `rms` has the horizontal RMS and σ).

use crate::consistency::{Consistency, RunConsistency};
use crate::flight_path::Motion;
use crate::output::sig;
use crate::rng::run_rng;
use crate::scenarios::campaign_plan::{Campaign, CampaignPlan, VariantResult};
use crate::scenarios::mission::navigator_setup::Variant as ChainVariant;
use crate::scenarios::mission::profile::{CarryManoeuvreAxis, MissionProfile, RAMP_PEAK_RATE};
use crate::scenarios::mission::report::{reduce, FlightRecord, VariantStats, COMPONENTS};
use crate::scenarios::mission::sensors::MissionFaults;
use crate::scenarios::mission::{load_scenario, monte_carlo_runs, MissionScenario};
use anyhow::Result;
use rand::Rng;
use serde_json::{json, Value};

/// The campaign entry.
pub const CAMPAIGN: Campaign = Campaign {
    estimator: "navigator",
    about: "flight navigator (f32) carry → hand-over → midcourse → terminal: lever arm 1-10 m \
            any direction, flexure τ ×0.5-×2, carry manoeuvre course/flight path/speed (time, \
            size), release 40-100 s, speed 100-300 m/s, altitudes 0.5-5 km, landmark bearing \
            0-360 deg and range 30-120 km, straight or S-turn run-in; per phase",
    run,
};

/// Range of the lever arm's length, m.
pub const LEVER_ARM_RANGE_M: (f64, f64) = (1.0, 10.0);
/// Range of the flexure correlation-time scale (log-uniform), dimensionless.
pub const TAU_SCALE_RANGE: (f64, f64) = (0.5, 2.0);
/// Range of the release time, s.
pub const RELEASE_RANGE_S: (f64, f64) = (40.0, 100.0);
/// Range of the speed after the boost, m/s.
pub const SPEED_RANGE_M_S: (f64, f64) = (100.0, 300.0);
/// Range of the carry and of the cruise altitude, m.
pub const ALTITUDE_RANGE_M: (f64, f64) = (500.0, 5000.0);
/// Range of the landmark's distance from the start of the midcourse turn, m.
pub const LANDMARK_RANGE_M: (f64, f64) = (30_000.0, 120_000.0);
/// Carry course change, deg (either sign).
pub const CARRY_TURN_RANGE_DEG: (f64, f64) = (10.0, 45.0);
/// Carry flight-path change, deg (either sign).
pub const CARRY_PITCH_RANGE_DEG: (f64, f64) = (2.0, 8.0);
/// Carry speed change, m/s (either sign).
pub const CARRY_SPEED_RANGE_M_S: (f64, f64) = (10.0, 40.0);
/// Duration of each change of the carry manoeuvre, s.
pub const CARRY_CHANGE_RANGE_S: (f64, f64) = (5.0, 20.0);
/// The carry manoeuvre's way back starts this long after the change, s.
pub const CARRY_BACK_AFTER_RANGE_S: (f64, f64) = (2.0, 10.0);
/// S-turn amplitude, deg, and period, s.
pub const S_TURN_AMPLITUDE_RANGE_DEG: (f64, f64) = (10.0, 30.0);
/// S-turn period, s.
pub const S_TURN_PERIOD_RANGE_S: (f64, f64) = (40.0, 120.0);
/// The mission ends at this distance from the landmark (as the seeker's campaign), m.
pub const MIN_END_RANGE_M: f64 = 10_000.0;
/// Largest lateral acceleration of the midcourse turn at its peak course rate, m/s² (2 g).
const MIDCOURSE_TURN_ACCEL_M_S2: f64 = 2.0 * 9.806_65;
/// Time the altitude change to cruise aims for (its flight-path angle follows, 3–20°), s.
const ALTITUDE_CHANGE_S: f64 = 60.0;
/// The carry manoeuvre starts at least this long after the start and ends at least this long
/// before the release, s.
const CARRY_MARGIN_S: f64 = 5.0;
/// Step of the flat-earth integration of the profile's velocity that aims the midcourse
/// turn, s.
const AIM_STEP_S: f64 = 0.1;

/// Steps of the midcourse turn's aim.
const AIM_ITERATIONS: usize = 25;

/// One drawn variant: its scenario and parameters.
#[derive(Debug, Clone)]
pub struct DrawnVariant {
    /// The mission with the drawn truth; the navigator's settings of `mission.toml`.
    pub scenario: MissionScenario,
    /// The drawn parameters (units in the key names).
    pub params: Value,
    /// Seed of the variant's Monte Carlo runs.
    pub runs_seed: u64,
}

/// Uniform in `r`.
fn uniform(rng: &mut impl Rng, r: (f64, f64)) -> f64 {
    rng.random_range(r.0..=r.1)
}

/// `x` or `−x` with even odds.
fn signed(rng: &mut impl Rng, x: f64) -> f64 {
    if rng.random_bool(0.5) {
        x
    } else {
        -x
    }
}

/// Angle wrapped to (−180, 180], deg.
fn wrap_deg(a: f64) -> f64 {
    let w = a.rem_euclid(360.0);
    if w > 180.0 {
        w - 360.0
    } else {
        w
    }
}

/// The profile's position north-east at `t_s` relative to the start, m (flat-earth integral
/// of its velocity; good to a fraction of a per cent, enough to aim a turn).
fn north_east_m(p: &MissionProfile, t_s: f64) -> (f64, f64) {
    let m = p.motion();
    let steps = (t_s / AIM_STEP_S).ceil().max(1.0) as usize;
    let h = t_s / steps as f64;
    let (mut n, mut e) = (0.0, 0.0);
    for k in 0..steps {
        let v = m.at((k as f64 + 0.5) * h).vel_ned_m_s;
        n += v.x * h;
        e += v.y * h;
    }
    (n, e)
}

/// Duration of a course change of `turn_deg` at `speed_m_s` whose peak lateral acceleration
/// is [`MIDCOURSE_TURN_ACCEL_M_S2`] (at least 10 s), s.
fn turn_duration_s(turn_deg: f64, speed_m_s: f64) -> f64 {
    let peak_rate = MIDCOURSE_TURN_ACCEL_M_S2 / speed_m_s;
    (RAMP_PEAK_RATE * turn_deg.to_radians().abs() / peak_rate).max(10.0)
}

/// A lever arm of length in [`LEVER_ARM_RANGE_M`], direction uniform on the sphere, m.
fn draw_lever_arm(rng: &mut impl Rng) -> ([f64; 3], f64) {
    let len = uniform(rng, LEVER_ARM_RANGE_M);
    let (z, az): (f64, f64) = (
        rng.random_range(-1.0..=1.0),
        rng.random_range(0.0..std::f64::consts::TAU),
    );
    let rxy = (1.0 - z * z).max(0.0).sqrt();
    ([len * rxy * az.cos(), len * rxy * az.sin(), len * z], len)
}

/// The carry manoeuvre of `p` (axis, timing, size; `p.release_s` drawn before): its
/// parameters for the outputs.
fn draw_carry_manoeuvre(rng: &mut impl Rng, p: &mut MissionProfile) -> Value {
    let axis = [
        CarryManoeuvreAxis::Course,
        CarryManoeuvreAxis::FlightPath,
        CarryManoeuvreAxis::Speed,
    ][rng.random_range(0..3usize)];
    p.carry_manoeuvre_axis = axis;
    p.carry_turn_s = uniform(rng, CARRY_CHANGE_RANGE_S);
    let back_after = uniform(rng, CARRY_BACK_AFTER_RANGE_S);
    let back = axis != CarryManoeuvreAxis::Course || rng.random_bool(0.5);
    p.carry_turn_back_after_s = back.then_some(back_after);
    let (range, unit) = match axis {
        CarryManoeuvreAxis::Course => (CARRY_TURN_RANGE_DEG, "deg"),
        CarryManoeuvreAxis::FlightPath => (CARRY_PITCH_RANGE_DEG, "deg"),
        CarryManoeuvreAxis::Speed => (CARRY_SPEED_RANGE_M_S, "m_s"),
    };
    let magnitude = uniform(rng, range);
    let size = signed(rng, magnitude);
    if axis == CarryManoeuvreAxis::Speed {
        p.carry_turn_deg = 0.0;
        p.carry_speed_change_m_s = size;
    } else {
        p.carry_turn_deg = size;
        p.carry_speed_change_m_s = 0.0;
    }
    let mut length = p.carry_turn_s
        + if back {
            back_after + p.carry_turn_s
        } else {
            0.0
        };
    // A long manoeuvre before an early release is compressed to fit.
    let room = 0.95 * (p.release_s - 2.0 * CARRY_MARGIN_S);
    if length > room {
        let k = room / length;
        p.carry_turn_s *= k;
        p.carry_turn_back_after_s = p.carry_turn_back_after_s.map(|a| a * k);
        length = room;
    }
    let latest = (p.release_s - CARRY_MARGIN_S - length).max(CARRY_MARGIN_S);
    p.carry_turn_start_s = rng.random_range(CARRY_MARGIN_S..=latest);
    json!({
        "axis": format!("{axis:?}").to_lowercase(),
        "size": sig(size, 4),
        "size_unit": unit,
        "start_s": sig(p.carry_turn_start_s, 4),
        "change_s": sig(p.carry_turn_s, 4),
        "back_after_s": p.carry_turn_back_after_s.map(|x| sig(x, 4)),
    })
}

/// The landmark `bearing_deg` and `range_m` from the start of the midcourse turn: its
/// position north-east of the start (m), the turn aimed at it, the end of the mission
/// [`MIN_END_RANGE_M`] from it, the cruise flight-path angle; returns the landmark's
/// position and the end of the turn, s.
fn aim_at_landmark(
    p: &mut MissionProfile,
    bearing_deg: f64,
    range_m: f64,
    speed: f64,
) -> ((f64, f64), f64) {
    let turn_start = p.release_s + p.drop_s + p.recover_s;
    let (n0, e0) = north_east_m(p, turn_start);
    let landmark = (
        n0 + range_m * bearing_deg.to_radians().cos(),
        e0 + range_m * bearing_deg.to_radians().sin(),
    );
    let v0 = p.motion().at(turn_start).vel_ned_m_s;
    let course0 = v0.y.atan2(v0.x).to_degrees();
    // Aim the midcourse turn at the landmark from where the turn ends: damped fixed-point
    // steps on the turn's miss (the turn's own displacement moves the aim point).
    let mut turn = wrap_deg(bearing_deg - course0);
    for _ in 0..AIM_ITERATIONS {
        p.midcourse_turn_deg = turn;
        p.midcourse_turn_s = turn_duration_s(turn, speed);
        let (n, e) = north_east_m(p, turn_start + p.midcourse_turn_s);
        let aim = (landmark.1 - e).atan2(landmark.0 - n).to_degrees() - course0;
        // Not wrapped: a turn towards a landmark behind may go on past 180°.
        turn += 0.7 * wrap_deg(aim - turn);
    }
    p.midcourse_turn_deg = turn;
    p.midcourse_turn_s = turn_duration_s(turn, speed);
    let turn_end = turn_start + p.midcourse_turn_s;
    let (n, e) = north_east_m(p, turn_end);
    let left_m = (landmark.0 - n).hypot(landmark.1 - e);
    p.end_s = turn_end + ((left_m - MIN_END_RANGE_M) / speed).max(30.0);
    // The altitude change to cruise in about ALTITUDE_CHANGE_S.
    let dh = (p.cruise_alt_m - p.carry_alt_m).abs();
    p.cruise_flight_path_deg = (dh / (speed * ALTITUDE_CHANGE_S))
        .min(1.0)
        .asin()
        .to_degrees()
        .clamp(3.0, 20.0);
    (landmark, turn_end)
}

/// Draws variant `v` of the campaign seed `seed` from the base scenario `base`.
pub fn draw_variant(base: &MissionScenario, seed: u64, v: usize) -> DrawnVariant {
    draw_variant_at_speed(base, seed, v, None)
}

/// [`draw_variant`] with its speed after the boost replaced by `speed_m_s` (m/s; `None`: the
/// drawn one), every other draw the same (to isolate the speed on one variant).
pub fn draw_variant_at_speed(
    base: &MissionScenario,
    seed: u64,
    v: usize,
    speed_m_s: Option<f64>,
) -> DrawnVariant {
    let mut rng = run_rng(seed, v as u64);
    let mut sc = base.clone();
    sc.variants = vec![ChainVariant::Full];
    let cfg = &mut sc.mission;
    // The carry: lever arm, flexure.
    let (lever, lever_len) = draw_lever_arm(&mut rng);
    let (lo, hi) = (TAU_SCALE_RANGE.0.ln(), TAU_SCALE_RANGE.1.ln());
    let tau_scale = rng.random_range(lo..=hi).exp();
    cfg.carry.lever_arm_m = lever;
    for t in cfg.carry.flexure.tau_s.iter_mut() {
        *t *= tau_scale;
    }
    // The profile.
    let p = &mut cfg.profile;
    let drawn_speed = uniform(&mut rng, SPEED_RANGE_M_S);
    let speed = speed_m_s.unwrap_or(drawn_speed);
    p.carry_speed_m_s = speed - p.boost_speed_gain_m_s;
    p.carry_alt_m = uniform(&mut rng, ALTITUDE_RANGE_M);
    p.cruise_alt_m = uniform(&mut rng, ALTITUDE_RANGE_M);
    p.heading_deg = rng.random_range(0.0..360.0);
    p.release_s = uniform(&mut rng, RELEASE_RANGE_S);
    let manoeuvre = draw_carry_manoeuvre(&mut rng, p);
    // The landmark and the run-in.
    let bearing_deg: f64 = rng.random_range(0.0..360.0);
    let range_m = uniform(&mut rng, LANDMARK_RANGE_M);
    let s_turn = rng.random_bool(0.5);
    let s_amplitude = uniform(&mut rng, S_TURN_AMPLITUDE_RANGE_DEG);
    let s_period = uniform(&mut rng, S_TURN_PERIOD_RANGE_S);
    let runs_seed: u64 = rng.random();
    let (landmark, turn_end) = aim_at_landmark(p, bearing_deg, range_m, speed);
    if s_turn {
        p.weave_amplitude_deg = s_amplitude;
        p.weave_period_s = s_period;
        p.weave_start_s = turn_end + 10.0;
    } else {
        p.weave_amplitude_deg = 0.0;
    }
    cfg.landmark.north_m = landmark.0;
    cfg.landmark.east_m = landmark.1;
    cfg.landmark.alt_m = 0.0;
    let p = &cfg.profile;
    let params = json!({
        "lever_arm_m": lever.map(|x| sig(x, 4)),
        "lever_arm_length_m": sig(lever_len, 4),
        "flexure_tau_scale": sig(tau_scale, 4),
        "flexure_tau_s": cfg.carry.flexure.tau_s.map(|t| sig(t, 4)),
        "carry_manoeuvre": manoeuvre,
        "release_s": sig(p.release_s, 4),
        "speed_m_s": sig(speed, 4),
        "carry_alt_m": sig(p.carry_alt_m, 4),
        "cruise_alt_m": sig(p.cruise_alt_m, 4),
        "heading_deg": sig(p.heading_deg, 4),
        "landmark_bearing_deg": sig(bearing_deg, 4),
        "landmark_range_m": sig(range_m, 5),
        "midcourse_turn_deg": sig(p.midcourse_turn_deg, 4),
        "midcourse_turn_s": sig(p.midcourse_turn_s, 4),
        "run_in": if s_turn {
            json!({"shape": "s_turn", "amplitude_deg": sig(s_amplitude, 4),
                   "period_s": sig(s_period, 4)})
        } else {
            json!({"shape": "straight"})
        },
        "end_s": sig(p.end_s, 5),
    });
    DrawnVariant {
        scenario: sc,
        params,
        runs_seed,
    }
}

/// The RMS axes of a phase row (units in the names; attitude in mrad).
const RMS_AXES: [(&str, f64); 9] = [
    ("north_m", 1.0),
    ("east_m", 1.0),
    ("down_m", 1.0),
    ("vel_north_m_s", 1.0),
    ("vel_east_m_s", 1.0),
    ("vel_down_m_s", 1.0),
    ("att_north_mrad", 1e3),
    ("att_east_mrad", 1e3),
    ("att_down_mrad", 1e3),
];

/// The hand-over: the attitude error and σ handed to the EKF, one epoch per run (the runs
/// that released through the alignment).
fn handover_row(stats: &VariantStats) -> Option<(Consistency, Vec<(String, f64)>)> {
    if stats.handover.is_empty() {
        return None;
    }
    let runs: Vec<RunConsistency> = stats
        .handover
        .iter()
        .map(|h| {
            let mut rc = RunConsistency::new(&["att_n", "att_e", "att_d"]);
            let es: [(f64, f64); 3] = std::array::from_fn(|a| (h.err_rad[a], h.sigma_rad[a]));
            rc.push(h.t_s, h.nees, &es);
            rc
        })
        .collect();
    let n = stats.handover.len() as f64;
    let mut rms: Vec<(String, f64)> = (0..3)
        .map(|a| {
            let m = stats
                .handover
                .iter()
                .map(|h| h.err_rad[a].powi(2))
                .sum::<f64>()
                / n;
            (RMS_AXES[6 + a].0.to_string(), m.sqrt() * 1e3)
        })
        .collect();
    for a in 0..3 {
        let m = stats
            .handover
            .iter()
            .map(|h| h.sigma_rad[a].powi(2))
            .sum::<f64>()
            / n;
        rms.push((format!("sigma_{}", RMS_AXES[6 + a].0), m.sqrt() * 1e3));
    }
    Some((Consistency::from_runs_settled(3, &runs, 0.0), rms))
}

/// The last epoch: the 9 states' consistency there, and the horizontal RMS and σ
/// (`√(mean σ_N² + σ_E²)`), m.
fn final_row(records: &[&FlightRecord]) -> Option<(Consistency, Vec<(String, f64)>)> {
    let n = records.iter().map(|r| r.t_s.len()).min()?;
    let k = n.checked_sub(1)?;
    let runs: Vec<RunConsistency> = records
        .iter()
        .map(|r| {
            let mut rc = RunConsistency::new(&COMPONENTS);
            let es: [(f64, f64); 9] = std::array::from_fn(|c| (r.err[k][c], r.sigma[k][c]));
            rc.push(r.t_s[k], r.consistency.nees[k], &es);
            rc
        })
        .collect();
    let m = records.len().max(1) as f64;
    let mean = |f: &dyn Fn(&FlightRecord) -> f64| records.iter().map(|r| f(r)).sum::<f64>() / m;
    let rms = vec![
        (
            "horizontal_m".to_string(),
            mean(&|r| r.err[k][0].powi(2) + r.err[k][1].powi(2)).sqrt(),
        ),
        (
            "horizontal_sigma_m".to_string(),
            mean(&|r| r.sigma[k][0].powi(2) + r.sigma[k][1].powi(2)).sqrt(),
        ),
        ("down_m".to_string(), mean(&|r| r.err[k][2].powi(2)).sqrt()),
        (
            "down_sigma_m".to_string(),
            mean(&|r| r.sigma[k][2].powi(2)).sqrt(),
        ),
    ];
    Some((Consistency::from_runs_settled(9, &runs, 0.0), rms))
}

/// Flies one variant: its runs through the navigator, one result per phase, the hand-over and
/// the last epoch.
pub fn fly_variant(
    v: usize,
    var: &DrawnVariant,
    runs: usize,
    progress: bool,
) -> Result<Vec<VariantResult>> {
    let label = format!("navigator v{v}");
    let flights = monte_carlo_runs(
        &var.scenario,
        &MissionFaults::default(),
        runs,
        var.runs_seed,
        progress,
        &label,
    )?;
    let records: Vec<&FlightRecord> = flights.iter().map(|r| &r.records[0]).collect();
    let stats = reduce("full", &records);
    let row = |filter: &str, consistency: Consistency, rms: Vec<(String, f64)>| VariantResult {
        variant: v,
        filter: filter.into(),
        params: var.params.clone(),
        consistency,
        rms,
    };
    let mut out: Vec<VariantResult> = stats
        .phases
        .iter()
        .map(|(p, c, _)| {
            let rms = RMS_AXES
                .iter()
                .enumerate()
                .map(|(i, (name, scale))| ((*name).to_string(), stats.phase_rms(*p, i) * scale))
                .collect();
            row(p.name(), c.clone(), rms)
        })
        .collect();
    if let Some((c, rms)) = handover_row(&stats) {
        out.push(row("handover", c, rms));
    }
    if let Some((c, rms)) = final_row(&records) {
        out.push(row("final", c, rms));
    }
    Ok(out)
}

/// The campaign's `run`.
fn run(plan: &CampaignPlan) -> Result<Vec<VariantResult>> {
    let (base, _) = load_scenario("mission")?;
    let mut out = Vec::new();
    for v in 0..plan.variants {
        let var = draw_variant(&base, plan.seed, v);
        out.extend(fly_variant(v, &var, plan.runs, plan.progress)?);
    }
    Ok(out)
}

#[cfg(test)]
#[path = "navigator_campaign_tests.rs"]
mod tests;

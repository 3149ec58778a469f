//! The mission through the flight navigator on a short profile (20 s of carry with a turn,
//! 40 s of free flight towards a landmark close enough for the seeker to lock): the phase
//! sequence, the error against the navigator's σ, and reproducibility with the same seed; and
//! the whole `fault-mission`'s seeker false lock (rejected, counted, harmless).

use nav_sim::scenarios::mission::navigator_setup::Variant;
use nav_sim::scenarios::mission::report::{PhaseTag, COMPONENTS};
use nav_sim::scenarios::mission::sensors::MissionFaults;
use nav_sim::scenarios::mission::{load_scenario, monte_carlo_runs, MissionScenario};

const RUNS: usize = 4;
const SEED: u64 = 11;

/// The shipped scenario shortened: release at 20 s, end at 60 s, landmark 26 km east.
fn short() -> MissionScenario {
    let (mut sc, _) = load_scenario("mission").unwrap();
    let p = &mut sc.mission.profile;
    p.release_s = 20.0;
    p.carry_turn_start_s = 5.0;
    p.carry_turn_s = 8.0;
    p.carry_turn_deg = 20.0;
    p.carry_turn_back_after_s = None;
    p.carry_alt_m = 1500.0;
    p.midcourse_turn_deg = -20.0;
    p.end_s = 60.0;
    sc.mission.landmark.north_m = 0.0;
    sc.mission.landmark.east_m = 26_000.0;
    sc.mission.seeker.search_after_release_s = 5.0;
    sc.variants = vec![Variant::Full, Variant::NoSeeker];
    sc
}

#[test]
fn short_mission_phases_errors_and_reproducibility() {
    let sc = short();
    let runs = monte_carlo_runs(&sc, &MissionFaults::default(), RUNS, SEED, false, "t").unwrap();
    let release_s = sc.mission.profile.release_s;
    for (i, r) in runs.iter().enumerate() {
        let full = &r.records[0];
        // Carry → released (at the truth's release, within the signal delay and the IMU's
        // confirmation window) → midcourse (after the coast) → terminal (after lock).
        let seq: Vec<PhaseTag> = full.transitions.iter().map(|(_, p)| *p).collect();
        assert_eq!(
            seq,
            [
                PhaseTag::Carry,
                PhaseTag::Released,
                PhaseTag::Midcourse,
                PhaseTag::Terminal
            ],
            "run {i}: {:?}",
            full.transitions
        );
        let t_rel = full.transitions[1].0;
        let n = &sc.navigator;
        assert!(
            t_rel >= release_s && t_rel <= release_s + 0.02 + n.separation_window_s,
            "run {i}: released at {t_rel}"
        );
        let t_mid = full.transitions[2].0;
        assert!(
            (t_mid - t_rel - n.coast_s).abs() < 0.02,
            "run {i}: midcourse at {t_mid}"
        );
        let lock = r.first_lock_s.unwrap();
        assert!(
            full.transitions[3].0 >= lock - 1e-9,
            "run {i}: terminal before lock"
        );
        // Without the seeker the navigator never enters terminal.
        let ns: Vec<PhaseTag> = r.records[1].transitions.iter().map(|(_, p)| *p).collect();
        assert_eq!(ns.last(), Some(&PhaseTag::Midcourse), "run {i}: {ns:?}");
        // Position and velocity within 5σ of the navigator's at every epoch of carry.
        for (k, (e, s)) in full.err.iter().zip(&full.sigma).enumerate() {
            if full.phase[k] == Some(PhaseTag::Carry) {
                for c in 0..6 {
                    assert!(
                        e[c].abs() <= 5.0 * s[c],
                        "run {i} t {} {}: {} vs σ {}",
                        full.t_s[k],
                        COMPONENTS[c],
                        e[c],
                        s[c]
                    );
                }
            }
        }
    }
    // The same seed gives the same numbers.
    let again = monte_carlo_runs(&sc, &MissionFaults::default(), 2, SEED, false, "t").unwrap();
    for (a, b) in runs.iter().zip(&again) {
        assert_eq!(a.records[0].err, b.records[0].err);
        assert_eq!(a.records[0].sigma, b.records[0].sigma);
        assert_eq!(a.records[0].transitions, b.records[0].transitions);
    }
}

/// The hand-over attitude lies within 3σ of the truth (the target: normalized error² in
/// [0.5, 2]) and the velocity within 5σ through midcourse, in every run, after a carry turn.
#[test]
fn handover_attitude_within_three_sigma() {
    let sc = short();
    let runs = monte_carlo_runs(&sc, &MissionFaults::default(), RUNS, SEED, false, "t").unwrap();
    for (i, r) in runs.iter().enumerate() {
        let full = &r.records[0];
        for (k, (e, s)) in full.err.iter().zip(&full.sigma).enumerate() {
            if full.phase[k] == Some(PhaseTag::Midcourse) {
                for c in 3..6 {
                    assert!(
                        e[c].abs() <= 5.0 * s[c],
                        "run {i} t {}: {}",
                        full.t_s[k],
                        COMPONENTS[c]
                    );
                }
            }
        }
        let h = full.handover.unwrap();
        for a in 0..3 {
            assert!(
                h.err_rad[a].abs() <= 3.0 * h.sigma_rad[a],
                "run {i} axis {a}: {} vs σ {}",
                h.err_rad[a],
                h.sigma_rad[a]
            );
        }
    }
}

/// The release adds no error of its own: from the last carry epoch to the first released one
/// (0.2 s apart, the EKF predicting from the hand-over) the attitude and vertical-velocity
/// errors move by less than half their σ in every run. Master samples whose slave
/// interpolation reaches past the release signal (the missile already dropping, the wing's
/// flexure gone from its IMU) would kick them by up to several σ.
#[test]
fn release_adds_no_error() {
    let sc = short();
    let runs = monte_carlo_runs(&sc, &MissionFaults::default(), RUNS, SEED, false, "t").unwrap();
    for (i, r) in runs.iter().enumerate() {
        let full = &r.records[0];
        let k = full
            .phase
            .iter()
            .position(|p| *p == Some(PhaseTag::Released))
            .unwrap();
        assert_eq!(full.phase[k - 1], Some(PhaseTag::Carry));
        for c in [5, 6, 7, 8] {
            let d = full.err[k][c] - full.err[k - 1][c];
            assert!(
                d.abs() <= 0.5 * full.sigma[k][c],
                "run {i} {}: moved {d} at release, σ {}",
                COMPONENTS[c],
                full.sigma[k][c]
            );
        }
    }
}

/// The fault mission's seeker false lock (2° in gimbal yaw for 3 s, 25 s after a 5 s loss of
/// lock), flown alone and with every other fault of `fault-mission`: the gate rejects the yaw
/// component of every false-lock sample and the report counts it
/// (`seeker.component_rejected`), true samples are rejected only at the gate's false-alarm
/// rate, and the false lock alone leaves the final horizontal error where the same runs end
/// without it.
#[test]
fn fault_mission_false_lock_is_rejected_and_counted() {
    const FL_RUNS: usize = 3;
    const FL_SEED: u64 = 7200;
    let (mut sc, table) = nav_sim::scenarios::mission::fault::load("fault-mission").unwrap();
    sc.variants = vec![Variant::Full];
    assert_eq!(table.false_lock.len(), 1);
    let fl = table.false_lock[0].clone();
    // Samples of the false lock: the seeker's rate over its window.
    let expected = (fl.duration_s * sc.mission.seeker.rate_hz).round() as u64;
    assert!(expected > 0);
    let rejected_in = |r: &nav_sim::scenarios::mission::report::FlightRecord, lo: f64, hi: f64| {
        r.events
            .iter()
            .filter(|(t, _, _)| *t >= lo - 1e-9 && *t <= hi + 1e-9)
            .filter(|(_, _, tags)| {
                tags.iter()
                    .any(|g| g == "seeker.component_rejected" || g == "seeker.rejected")
            })
            .count() as u64
    };
    let final_horizontal = |runs: &[nav_sim::scenarios::mission::run::MissionRun]| {
        let ms = runs
            .iter()
            .map(|r| {
                let e = r.records[0].err.last().unwrap();
                e[0] * e[0] + e[1] * e[1]
            })
            .sum::<f64>()
            / runs.len() as f64;
        ms.sqrt()
    };
    let only_fl = MissionFaults {
        imu_seeker: nav_sim::scenarios::seeker_ins::injection::Faults {
            false_lock: table.false_lock.clone(),
            ..Default::default()
        },
        ..MissionFaults::default()
    };
    let base =
        monte_carlo_runs(&sc, &MissionFaults::default(), FL_RUNS, FL_SEED, false, "b").unwrap();
    let alone = monte_carlo_runs(&sc, &only_fl, FL_RUNS, FL_SEED, false, "f").unwrap();
    let all = monte_carlo_runs(&sc, &table.faults(), FL_RUNS, FL_SEED, false, "a").unwrap();
    let end = fl.start_s + fl.duration_s;
    for (name, runs) in [("false lock alone", &alone), ("all faults", &all)] {
        for (i, r) in runs.iter().enumerate() {
            let rec = &r.records[0];
            assert_eq!(
                rejected_in(rec, fl.start_s, end),
                expected,
                "{name}, run {i}: false-lock samples rejected"
            );
            // True samples: the gate's false-alarm rate, 2 × P(χ²₁ > 16) ≈ 1.3·10⁻⁴ per sample
            // of the ≈ 1000 of a run (0.13 per run; 12 in the 100 nominal runs of `mission`).
            let outside = rejected_in(rec, f64::NEG_INFINITY, f64::INFINITY) - expected;
            assert!(
                outside <= 1,
                "{name}, run {i}: {outside} true LOS samples rejected"
            );
        }
    }
    for (i, r) in base.iter().enumerate() {
        let n = rejected_in(&r.records[0], f64::NEG_INFINITY, f64::INFINITY);
        assert!(n <= 1, "baseline run {i}: {n} true LOS samples rejected");
    }
    let (b, f) = (final_horizontal(&base), final_horizontal(&alone));
    assert!(
        (f - b).abs() < 0.05 * b,
        "final horizontal RMS {f} m against {b} m without the false lock"
    );
}

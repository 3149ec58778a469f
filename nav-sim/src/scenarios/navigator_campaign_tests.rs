//! Tests of the navigator's campaign: the variant draw's ranges, reproducibility.

use super::*;

fn base() -> MissionScenario {
    load_scenario("mission").unwrap().0
}

/// Smallest and largest of `xs`.
fn span(xs: &[f64]) -> (f64, f64) {
    xs.iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(*x), b.max(*x))
        })
}

/// `xs` stay inside `r` and cover at least 90 % of it.
fn covers(name: &str, xs: &[f64], r: (f64, f64)) {
    let (lo, hi) = span(xs);
    assert!(
        lo >= r.0 - 1e-9 && hi <= r.1 + 1e-9,
        "{name}: [{lo}, {hi}] outside {r:?}"
    );
    assert!(
        hi - lo >= 0.9 * (r.1 - r.0),
        "{name}: [{lo}, {hi}] covers too little of {r:?}"
    );
}

/// 200 draws stay inside the stated ranges and cover them (every range, both signs of
/// every lever-arm axis, every manoeuvre axis, both run-ins), every drawn mission passes
/// the scenario's own checks, the midcourse turn ends aimed at the landmark, the mission
/// ends near [`MIN_END_RANGE_M`] from it, and the navigator's settings are the file's.
#[test]
fn the_variant_draw_covers_the_ranges() {
    let base = base();
    let vs: Vec<DrawnVariant> = (0..200).map(|v| draw_variant(&base, 9100, v)).collect();
    let f = |key: &str| -> Vec<f64> {
        vs.iter()
            .map(|v| v.params[key].as_f64().unwrap_or(f64::NAN))
            .collect()
    };
    covers("lever arm", &f("lever_arm_length_m"), LEVER_ARM_RANGE_M);
    covers("τ scale", &f("flexure_tau_scale"), TAU_SCALE_RANGE);
    covers("release", &f("release_s"), RELEASE_RANGE_S);
    covers("speed", &f("speed_m_s"), SPEED_RANGE_M_S);
    covers("carry altitude", &f("carry_alt_m"), ALTITUDE_RANGE_M);
    covers("cruise altitude", &f("cruise_alt_m"), ALTITUDE_RANGE_M);
    covers("heading", &f("heading_deg"), (0.0, 360.0));
    covers("landmark bearing", &f("landmark_bearing_deg"), (0.0, 360.0));
    covers("landmark range", &f("landmark_range_m"), LANDMARK_RANGE_M);
    for a in 0..3 {
        let l: Vec<f64> = vs
            .iter()
            .map(|v| v.scenario.mission.carry.lever_arm_m[a])
            .collect();
        let (lo, hi) = span(&l);
        assert!(lo < -5.0 && hi > 5.0, "lever arm axis {a}: [{lo}, {hi}]");
    }
    for axis in ["course", "flightpath", "speed"] {
        let sizes: Vec<f64> = vs
            .iter()
            .filter(|v| v.params["carry_manoeuvre"]["axis"] == axis)
            .map(|v| v.params["carry_manoeuvre"]["size"].as_f64().unwrap())
            .collect();
        let r = match axis {
            "course" => CARRY_TURN_RANGE_DEG,
            "flightpath" => CARRY_PITCH_RANGE_DEG,
            _ => CARRY_SPEED_RANGE_M_S,
        };
        assert!(sizes.len() > 40, "{axis}: {} draws", sizes.len());
        let mags: Vec<f64> = sizes.iter().map(|x| x.abs()).collect();
        covers(axis, &mags, r);
        assert!(sizes.iter().any(|x| *x < 0.0) && sizes.iter().any(|x| *x > 0.0));
    }
    let starts: Vec<f64> = vs
        .iter()
        .map(|v| v.params["carry_manoeuvre"]["start_s"].as_f64().unwrap())
        .collect();
    let (lo, hi) = span(&starts);
    assert!(lo < 10.0 && hi > 60.0, "manoeuvre start [{lo}, {hi}]");
    let s_turns = vs
        .iter()
        .filter(|v| v.params["run_in"]["shape"] == "s_turn")
        .count();
    assert!(
        (60..140).contains(&s_turns),
        "{s_turns} S-turn run-ins of 200"
    );
    for v in &vs {
        check_variant(v, &base);
    }
}

/// One drawn variant passes the scenario's checks, keeps the file's navigator settings,
/// ends its midcourse turn aimed at the landmark and ends near [`MIN_END_RANGE_M`] from it.
fn check_variant(v: &DrawnVariant, base: &MissionScenario) {
    let m = &v.scenario.mission;
    m.check().unwrap();
    assert_eq!(v.scenario.variants, vec![ChainVariant::Full]);
    assert_eq!(
        v.scenario.navigator.gate_nis.to_bits(),
        base.navigator.gate_nis.to_bits()
    );
    let p = &m.profile;
    let turn_end = p.release_s + p.drop_s + p.recover_s + p.midcourse_turn_s;
    let (n, e) = north_east_m(p, turn_end);
    let (dn, de) = (m.landmark.north_m - n, m.landmark.east_m - e);
    let vel = p.motion().at(turn_end).vel_ned_m_s;
    let off = wrap_deg(de.atan2(dn).to_degrees() - vel.y.atan2(vel.x).to_degrees());
    assert!(off.abs() < 2.0, "variant {}: aimed {off} deg off", v.params);
    let (n, e) = north_east_m(p, p.end_s);
    let left = (m.landmark.north_m - n).hypot(m.landmark.east_m - e);
    assert!(
        // S-turns and the climb shorten the ground track's progress: it ends
        // farther, never closer.
        left > 0.8 * MIN_END_RANGE_M && left < 2.5 * MIN_END_RANGE_M
            || p.end_s - turn_end <= 30.0 + 1e-9,
        "variant {}: ends {left} m from the landmark",
        v.params
    );
}

/// Same seed, same numbers; another seed, other variants; every phase, the hand-over and
/// the last epoch reported.
#[test]
fn campaign_is_reproducible() {
    let plan = CampaignPlan {
        variants: 1,
        runs: 2,
        seed: 17,
        progress: false,
    };
    let a = run(&plan).unwrap();
    let b = run(&plan).unwrap();
    crate::scenarios::campaign_plan::assert_same_results(&a, &b);
    let filters: Vec<&str> = a.iter().map(|r| r.filter.as_str()).collect();
    for f in ["carry", "released", "midcourse", "handover", "final"] {
        assert!(filters.contains(&f), "{f} missing: {filters:?}");
    }
    let other = draw_variant(&base(), 18, 0);
    assert_ne!(a[0].params, other.params);
}

/// A variant drawn at a given speed is the drawn variant but for the speed and what follows
/// from it (the speed itself, the carry speed, the midcourse turn's duration, the end): the
/// lever arm, altitudes, courses, landmark and run-in are the same draws.
#[test]
fn a_variant_at_another_speed_keeps_every_other_draw() {
    let base = base();
    for v in 0..5 {
        let drawn = draw_variant(&base, 9100, v);
        let same = draw_variant_at_speed(&base, 9100, v, None);
        assert_eq!(drawn.params, same.params);
        let at = draw_variant_at_speed(&base, 9100, v, Some(150.0));
        assert_eq!(at.params["speed_m_s"].as_f64(), Some(150.0));
        assert_eq!(at.runs_seed, drawn.runs_seed);
        let p = &at.scenario.mission.profile;
        assert!((p.carry_speed_m_s + p.boost_speed_gain_m_s - 150.0).abs() < 1e-9);
        for key in [
            "lever_arm_m",
            "carry_alt_m",
            "cruise_alt_m",
            "heading_deg",
            "landmark_bearing_deg",
            "landmark_range_m",
            "run_in",
            "release_s",
        ] {
            assert_eq!(at.params[key], drawn.params[key], "variant {v}: {key}");
        }
    }
}

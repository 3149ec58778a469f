//! The release without the aircraft's signal (module doc, "Separation"): declared on the
//! IMU's unloading that starts with the master's loss, or on free fall; never on a bus
//! dropout while the missile is still on the wing; and the configuration of the cue and of
//! the histories' depth checked.

use super::*;
use crate::error::ConfigIssue;

/// The chain's release time here (the master's last sample goes with it).
const RELEASE_S: f64 = 3.0;

/// The smooth ramp's rate per unit change and duration, `30 u² (1 − u)²`.
fn ramp_rate(u: f64) -> f64 {
    if (0.0..=1.0).contains(&u) {
        30.0 * u * u * (1.0 - u) * (1.0 - u)
    } else {
        0.0
    }
}

/// The change of the specific force (master body axes = NED here, m/s²) `t` s after the
/// release, as the mission's drop: the flight path to −3° in 1 s at the chain's speed (the
/// sink accelerates the missile downwards: it unloads), then the pull-out to level in 3 s and
/// the boost of +20 m/s in 6 s.
fn drop_and_motor(t: f64) -> Vector3<f64> {
    let gamma = 3f64.to_radians();
    let sink = SPEED_M_S * gamma * ramp_rate(t);
    let pull_out = SPEED_M_S * gamma / 3.0 * ramp_rate((t - 1.0) / 3.0);
    let boost = 20.0 / 6.0 * ramp_rate((t - 1.0) / 6.0);
    Vector3::new(boost, 0.0, sink - pull_out)
}

/// Carries with the master until `RELEASE_S`, then flies `extra(t)` (the specific-force
/// change `t` s after `RELEASE_S`, master body axes, turned into the slave's by the mount)
/// for `secs` without a master sample or a signal; the first transition and the navigator.
fn fly_without_master<T: Real>(
    secs: f64,
    extra: &dyn Fn(f64) -> Vector3<f64>,
) -> (Option<Transition>, FlightNavigator<T, 32>, World) {
    let (mut nav, mut world) = carry_for::<T>(RELEASE_S, RELEASE_S);
    let c_m_s = World::c_m_s();
    for _ in 0..(secs / DT).round() as u64 {
        let mut inc = world.step();
        // The interval's mid-point.
        let t = inc.time.as_secs_f64() - RELEASE_S - 0.5 * DT;
        inc.delta_v_m_s += c_m_s * extra(t) * DT;
        let r = nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        if let Some(tr) = r.transition {
            assert_eq!(
                r.degradation.separation,
                SeparationStatus::UnsignalledRelease
            );
            assert_ne!(r.health, HealthState::Nominal);
            return (Some(tr), nav, world);
        }
        assert_eq!(r.phase, Phase::Carry);
    }
    (None, nav, world)
}

fn drop_and_motor_releases<T: Real>() {
    let (tr, nav, _) = fly_without_master::<T>(3.0, &drop_and_motor);
    let tr = tr.expect("released without a signal on the drop");
    assert_eq!(tr.cause, TransitionCause::UnsignalledSeparation);
    assert_eq!((tr.from, tr.to), (Phase::Carry, Phase::Released));
    // The unloading exceeds the 4 m/s² threshold from 0.13 s to 0.87 s after the release
    // (the dwell of 0.3 s is reached at 0.44 s); the master, last fused at the release's
    // tick, times out 0.5 s later: declared at its time-out.
    let delay_s = tr.time.as_secs_f64() - RELEASE_S;
    std::println!("released without a signal {delay_s:.3} s after the drop");
    assert!((0.5..0.53).contains(&delay_s), "{delay_s}");
    assert!(nav.ekf().is_some());
}

#[test]
fn drop_and_motor_without_a_signal_releases_f64() {
    drop_and_motor_releases::<f64>();
}

#[test]
fn drop_and_motor_without_a_signal_releases_f32() {
    drop_and_motor_releases::<f32>();
}

fn no_release_on_the_wing<T: Real>() {
    let g = 9.8;
    // A 2 g pull-up (or a 60° banked turn) entered at the bus's loss, over 0.5 s: the missile
    // on the wing is loaded, not unloaded.
    let pull_up = |t: f64| Vector3::new(0.0, 0.0, -g * (t / 0.5).clamp(0.0, 1.0));
    assert_eq!(fly_without_master::<T>(3.0, &pull_up).0, None);
    // A push-over to 0.5 g from 0.6 s after the bus's loss: it unloads by 4.9 m/s² for 2 s,
    // but starts after the onset bound (0.3 s) of the last master epoch (and 0.5 g is no free
    // fall).
    let push_over = |t: f64| Vector3::new(0.0, 0.0, 0.5 * g * ((t - 0.6) / 0.3).clamp(0.0, 1.0));
    let (tr, nav, _) = fly_without_master::<T>(3.0, &push_over);
    assert_eq!(tr, None);
    assert_eq!(nav.phase(), Phase::Carry);
}

#[test]
fn a_bus_dropout_in_a_manoeuvre_on_the_wing_is_no_release_f64() {
    no_release_on_the_wing::<f64>();
}

#[test]
fn a_bus_dropout_in_a_manoeuvre_on_the_wing_is_no_release_f32() {
    no_release_on_the_wing::<f32>();
}

#[test]
fn the_cue_and_the_history_depth_are_checked_at_construction() {
    let base = config::<f64>(BaroDamping::Off);
    let init = chain_world(&base.lever_arm.nominal_m).initial::<f64>();
    let err = |c: &NavigatorConfig<f64>| FlightNavigator::<f64, 32>::new(c, &init).err();
    let invalid = |field, issue| Some(NavError::InvalidConfig { field, issue });
    let mut c = base;
    c.separation.unsignalled_onset_s = 0.0;
    assert_eq!(
        err(&c),
        invalid("separation.unsignalled_onset_s", ConfigIssue::NotPositive)
    );
    // Later than the master's time-out: no longer "with the master's loss".
    c.separation.unsignalled_onset_s = 0.6;
    assert_eq!(
        err(&c),
        invalid("separation.unsignalled_onset_s", ConfigIssue::OutOfRange)
    );
    c.separation.unsignalled_onset_s = 0.5;
    assert_eq!(err(&c), None);
    // H = 32 at 100 Hz reaches (32 − 2) × 10 ms = 0.3 s of master latency.
    let mut c = base;
    c.max_master_latency_s = 0.3;
    assert_eq!(err(&c), None);
    c.max_master_latency_s = 0.31;
    assert_eq!(
        err(&c),
        invalid("max_master_latency_s", ConfigIssue::OutOfRange)
    );
    assert!(FlightNavigator::<f64, 33>::new(&c, &init).is_ok());
    c.max_master_latency_s = -0.01;
    assert_eq!(
        err(&c),
        invalid("max_master_latency_s", ConfigIssue::Negative)
    );
    c.max_master_latency_s = f64::NAN;
    assert_eq!(
        err(&c),
        invalid("max_master_latency_s", ConfigIssue::NotFinite)
    );
}

//! One heavy EKF update per tick: a baro sample arriving with a LOS sample is held and fused
//! on the next tick at its own time stamp; a newer one supersedes it; a refused one changes
//! nothing; a baro at the IMU rate beside a 10 Hz seeker never stalls.

use super::*;

/// A navigator with the EKF's baro damping, released at the truth, in midcourse after the
/// coast and a second of baro samples every 4th tick; the world.
fn in_midcourse<T: Real>() -> (FlightNavigator<T, 32>, World) {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    release_at_truth(&mut nav, &world);
    while nav.phase() != Phase::Midcourse {
        nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    }
    for k in 0..100 {
        let inc = world.step();
        let b = baro_at(&world, inc.time);
        let baro = (k % 4 == 0).then_some(&b);
        let aids = Aids { baro, ..Aids::NONE };
        nav.tick(&imu_tick(&inc), &aids).unwrap();
    }
    (nav, world)
}

/// The baro reading of the world's missile truth (0.5 m high), stamped `time`.
fn baro_at<T: Real>(world: &World, time: Timestamp) -> BaroSample<T> {
    BaroSample {
        time,
        altitude_m: T::lit(world.missile_truth().position.alt_m + 0.5),
    }
}

/// The seeker's LOS sample of the world's missile truth, stamped `time`.
fn los_of<T: Real>(world: &World, time: Timestamp) -> LosSample<T> {
    let g = gimbal_truth(&world.missile_truth());
    LosSample {
        time,
        gimbal: crate::seeker_ins::GimbalAngles {
            pitch_rad: T::lit(g.pitch_rad),
            yaw_rad: T::lit(g.yaw_rad),
        },
    }
}

fn aids<'a, T>(baro: Option<&'a BaroSample<T>>, seeker: Option<&'a LosSample<T>>) -> Aids<'a, T> {
    Aids {
        baro,
        seeker,
        ..Aids::NONE
    }
}

/// The filter's numbers of two navigators are the same, bit for bit.
fn same_filter<T: Real>(a: &FlightNavigator<T, 32>, b: &FlightNavigator<T, 32>) -> bool {
    a.solution() == b.solution()
        && a.baro_state() == b.baro_state()
        && a.ekf().map(|e| *e.covariance()) == b.ekf().map(|e| *e.covariance())
}

fn held_then_fused<T: Real>() {
    let (nav0, mut world) = in_midcourse::<T>();
    let inc1 = world.step();
    let b1 = baro_at::<T>(&world, inc1.time);
    let los = los_of::<T>(&world, inc1.time);
    let inc2 = world.step();
    let c0 = nav0.blank_report().baro.counters;
    // The coinciding tick: the LOS fused (terminal entry), the baro sample checked and held.
    let mut nav = nav0.clone();
    let r1 = nav
        .tick(&imu_tick(&inc1), &aids(Some(&b1), Some(&los)))
        .unwrap();
    assert_eq!(r1.seeker.state, AidState::Fused);
    assert_eq!(r1.phase, Phase::Terminal);
    assert_eq!(r1.baro.state, AidState::Held);
    assert_eq!(r1.baro.counters, c0);
    assert_eq!(r1.degradation.baro, AidAvailability::Available);
    assert_eq!(nav.held_baro(), Some(&b1));
    // Nothing of the baro sample in the filter yet: as the LOS tick alone.
    let mut late = nav0.clone();
    late.tick(&imu_tick(&inc1), &aids(None, Some(&los)))
        .unwrap();
    assert!(same_filter(&nav, &late));
    let mut restamped = late.clone();
    // The next tick, no sample: the held one fused at its own time stamp, one tick old.
    let r2 = nav.tick(&imu_tick(&inc2), &Aids::NONE).unwrap();
    assert_eq!(r2.baro.state, AidState::Fused);
    assert_eq!(r2.baro.counters.fused, c0.fused + 1);
    assert_eq!(nav.held_baro(), None);
    // As the sample arriving late on that tick.
    late.tick(&imu_tick(&inc2), &aids(Some(&b1), None)).unwrap();
    assert!(same_filter(&nav, &late));
    // Its age counts: the same reading stamped at the tick (age zero) gives other numbers.
    let b0 = BaroSample {
        time: inc2.time,
        ..b1
    };
    restamped
        .tick(&imu_tick(&inc2), &aids(Some(&b0), None))
        .unwrap();
    assert!(!same_filter(&nav, &restamped));
}

#[test]
fn a_coinciding_baro_sample_is_held_and_fused_next_tick_at_its_age_f64() {
    held_then_fused::<f64>();
}

#[test]
fn a_coinciding_baro_sample_is_held_and_fused_next_tick_at_its_age_f32() {
    held_then_fused::<f32>();
}

fn superseded<T: Real>() {
    let (nav0, mut world) = in_midcourse::<T>();
    let c0 = nav0.blank_report().baro.counters;
    let mut ticks = Vec::new();
    for _ in 0..3 {
        let inc = world.step();
        let b = baro_at::<T>(&world, inc.time);
        let los = los_of::<T>(&world, inc.time);
        ticks.push((inc, b, los));
    }
    let [(inc1, b1, los1), (inc2, b2, los2), (inc3, b3, _)] = ticks.as_slice() else {
        panic!("three ticks");
    };
    let mut nav = nav0.clone();
    nav.tick(&imu_tick(inc1), &aids(Some(b1), Some(los1)))
        .unwrap();
    // A LOS again, with a newer baro sample: the newer one held, the older superseded.
    let r2 = nav
        .tick(&imu_tick(inc2), &aids(Some(b2), Some(los2)))
        .unwrap();
    assert_eq!(r2.baro.state, AidState::Held);
    assert_eq!(nav.held_baro(), Some(b2));
    assert_eq!(r2.baro.counters.superseded, c0.superseded + 1);
    // A newer sample on a tick without a LOS: the newest fused, the held one superseded.
    let r3 = nav.tick(&imu_tick(inc3), &aids(Some(b3), None)).unwrap();
    assert_eq!(r3.baro.state, AidState::Fused);
    assert_eq!(nav.held_baro(), None);
    assert_eq!(r3.baro.counters.superseded, c0.superseded + 2);
    assert_eq!(r3.baro.counters.fused, c0.fused + 1);
    // As the two LOS ticks without baro, then the newest sample alone.
    let mut reference = nav0.clone();
    reference
        .tick(&imu_tick(inc1), &aids(None, Some(los1)))
        .unwrap();
    reference
        .tick(&imu_tick(inc2), &aids(None, Some(los2)))
        .unwrap();
    reference
        .tick(&imu_tick(inc3), &aids(Some(b3), None))
        .unwrap();
    assert!(same_filter(&nav, &reference));
}

#[test]
fn a_newer_baro_sample_supersedes_the_held_one_f64() {
    superseded::<f64>();
}

#[test]
fn a_newer_baro_sample_supersedes_the_held_one_f32() {
    superseded::<f32>();
}

/// The navigator after a coinciding tick (its baro sample held), the next IMU sample, the
/// world.
fn holding<T: Real>() -> (FlightNavigator<T, 32>, ImuIncrement<f64>, World) {
    let (mut nav, mut world) = in_midcourse::<T>();
    let inc1 = world.step();
    let b1 = baro_at::<T>(&world, inc1.time);
    let los = los_of::<T>(&world, inc1.time);
    nav.tick(&imu_tick(&inc1), &aids(Some(&b1), Some(&los)))
        .unwrap();
    assert_eq!(nav.held_baro(), Some(&b1));
    let inc2 = world.step();
    (nav, inc2, world)
}

fn refused_with_a_held_sample<T: Real>() {
    let (nav, inc2, world) = holding::<T>();
    let held = *nav.held_baro().unwrap();
    let reading = held.altitude_m;
    let bad = [
        BaroSample {
            time: inc2.time,
            altitude_m: T::lit(f64::NAN),
        },
        // From the future, not later than the held one, older than the model accepts.
        BaroSample {
            time: inc2.time.add_micros(1),
            altitude_m: reading,
        },
        held,
        BaroSample {
            time: Timestamp::from_micros(inc2.time.as_micros() - 1_500_000),
            altitude_m: reading,
        },
    ];
    let los2 = los_of::<T>(&world, inc2.time);
    for (seeker, expected) in [(None, AidState::Fused), (Some(&los2), AidState::Held)] {
        let mut reference = nav.clone();
        let rr = reference
            .tick(&imu_tick(&inc2), &aids(None, seeker))
            .unwrap();
        // Without the bad sample: the held one fused, or held again behind the LOS.
        assert_eq!(rr.baro.state, expected);
        for b in &bad {
            let mut a = nav.clone();
            let ra = a.tick(&imu_tick(&inc2), &aids(Some(b), seeker)).unwrap();
            assert!(matches!(ra.baro.state, AidState::Refused(_)), "{b:?}");
            assert!(same_filter(&a, &reference), "{b:?}");
            assert_eq!(a.held_baro(), reference.held_baro());
            let mut counters = rr.baro.counters;
            counters.refused += 1;
            assert_eq!(ra.baro.counters, counters);
            assert_eq!(ra.degradation, rr.degradation);
        }
    }
    // A refused IMU sample: nothing changed, the held sample included.
    let mut bad_imu = imu_tick::<T>(&inc2);
    bad_imu.increment.delta_v_m_s.x = T::lit(f64::NAN);
    let mut a = nav.clone();
    assert!(a.tick(&bad_imu, &Aids::NONE).is_err());
    assert!(same_filter(&a, &nav));
    assert_eq!(a.held_baro(), Some(&held));
}

#[test]
fn a_refused_baro_sample_leaves_the_held_one_f64() {
    refused_with_a_held_sample::<f64>();
}

#[test]
fn a_refused_baro_sample_leaves_the_held_one_f32() {
    refused_with_a_held_sample::<f32>();
}

/// LOS samples on every tick: the held sample waits (reported held, not timed out) until it
/// is older than the baro model accepts, then it is dropped (skipped), never fused.
#[test]
fn a_held_sample_expires_when_los_updates_take_every_tick_f32() {
    let (mut nav, _, mut world) = holding::<f32>();
    let held = *nav.held_baro().unwrap();
    let c0 = nav.blank_report().baro.counters;
    let mut dropped = None;
    for _ in 0..120 {
        let inc = world.step();
        let los = los_of::<f32>(&world, inc.time);
        let r = nav.tick(&imu_tick(&inc), &aids(None, Some(&los))).unwrap();
        let age = inc.time.micros_since(held.time).unwrap();
        if age <= 1_000_000 {
            assert_eq!(r.baro.state, AidState::Held, "age {age} µs");
            assert_eq!(nav.held_baro(), Some(&held));
        } else if dropped.is_none() {
            assert_eq!(nav.held_baro(), None, "age {age} µs");
            dropped = Some(r.baro.counters);
        }
    }
    let c = dropped.expect("the held sample dropped");
    assert_eq!((c.skipped, c.fused), (c0.skipped + 1, c0.fused));
}

/// A baro at the IMU rate (100 Hz) and the seeker at 10 Hz for 5 s: every LOS tick holds
/// its baro sample, every other tick fuses the newest (the held one superseded); the baro
/// never waits, never times out.
#[test]
fn a_baro_at_the_imu_rate_beside_a_10_hz_seeker_never_stalls_f32() {
    let (mut nav, mut world) = in_midcourse::<f32>();
    let c0 = nav.blank_report().baro.counters;
    let ticks = 500_u32;
    let mut los_ticks = 0_u32;
    for k in 0..ticks {
        let inc = world.step();
        let b = baro_at::<f32>(&world, inc.time);
        let los = (k % 10 == 0).then(|| los_of::<f32>(&world, inc.time));
        let r = nav
            .tick(&imu_tick(&inc), &aids(Some(&b), los.as_ref()))
            .unwrap();
        if los.is_some() {
            los_ticks += 1;
            assert!(
                matches!(r.seeker.state, AidState::Fused | AidState::Rejected),
                "k {k}: {:?}",
                r.seeker.state
            );
            assert_eq!(r.baro.state, AidState::Held, "k {k}");
            assert_eq!(nav.held_baro(), Some(&b));
        } else {
            assert!(
                matches!(r.baro.state, AidState::Fused | AidState::Rejected),
                "k {k}: {:?}",
                r.baro.state
            );
            assert_eq!(nav.held_baro(), None);
        }
        assert_eq!(r.degradation.baro, AidAvailability::Available, "k {k}");
    }
    let c = nav.blank_report().baro.counters;
    assert_eq!(c.superseded - c0.superseded, los_ticks);
    assert_eq!(
        (c.fused + c.rejected) - (c0.fused + c0.rejected),
        ticks - los_ticks
    );
    assert_eq!((c.skipped, c.refused), (c0.skipped, c0.refused));
    assert!(c.fused - c0.fused > (ticks - los_ticks) * 9 / 10);
}

/// An IMU gap longer than the baro model's age limit after the coinciding tick: the held
/// sample is dropped (skipped), not fused at an age the model refuses; a shorter gap fuses it
/// with the gap in its age.
#[test]
fn a_held_sample_across_an_imu_gap_is_fused_within_the_age_limit_else_dropped_f32() {
    for (gap_us, fused) in [(500_000_u64, true), (1_500_000, false)] {
        let (mut nav, inc2, _) = holding::<f32>();
        let held = *nav.held_baro().unwrap();
        let c0 = nav.blank_report().baro.counters;
        let mut late = imu_tick::<f32>(&inc2);
        late.increment.time = inc2.time.add_micros(gap_us);
        let r = nav.tick(&late, &Aids::NONE).unwrap();
        assert_eq!(nav.held_baro(), None, "gap {gap_us} µs");
        let c = r.baro.counters;
        if fused {
            assert_eq!(r.baro.state, AidState::Fused, "gap {gap_us} µs");
            assert_eq!((c.fused, c.skipped), (c0.fused + 1, c0.skipped));
            assert!(r.baro.last.is_some());
        } else {
            assert_eq!((c.fused, c.skipped), (c0.fused, c0.skipped + 1));
            // Nothing accepted for longer than the baro timeout (1 s) since the hold.
            assert_eq!(r.baro.state, AidState::TimedOut);
        }
        assert!(late.increment.time.micros_since(held.time).is_some());
    }
}

//! The chain's phases and hand-over, refused inputs, master timeouts and signals, the
//! configuration checks.

use super::*;

fn chain_phases_and_handover<T: Real>() {
    let run = run_chain::<T>(BaroDamping::Ekf(baro_model()), 90.0);
    let seq: Vec<Phase> = run.phases.iter().map(|p| p.1).collect();
    assert_eq!(
        seq,
        [Phase::Released, Phase::Midcourse, Phase::Terminal],
        "{:?}",
        run.phases
    );
    // Released at the first tick after the signal where the slave sees 0 g.
    let t_rel = run.phases[0].0;
    assert!(
        t_rel > SEPARATION_S && t_rel < SEPARATION_S + 0.05,
        "{t_rel}"
    );
    assert_eq!(
        run.transitions[0].cause,
        TransitionCause::SeparationConfirmed
    );
    let t_mid = run.phases[1].0;
    assert!((t_mid - t_rel - COAST_S).abs() < 0.015, "{t_mid}");
    let t_term = run.phases[2].0;
    assert!(
        (SEEKER_FROM_S..SEEKER_FROM_S + 0.2).contains(&t_term),
        "{t_term}"
    );
    // Hand-over attitude error within 3σ per axis.
    for i in 0..3 {
        assert!(
            run.handover_phi[i].abs() <= 3.0 * run.handover_sigma[i],
            "axis {i}: φ {:?} σ {:?}",
            run.handover_phi,
            run.handover_sigma
        );
    }
    assert!(run.baro_fused > 0);
    assert!(run.seeker_fused > 0);
    assert!(run.terminal_pos_err_m.is_finite());
    // The seeker lost in terminal: TimedOut after seeker_s, the phase stays, the baro damps on.
    assert_eq!(run.final_seeker, AidState::TimedOut);
    assert_eq!(run.final_degradation.seeker, AidAvailability::TimedOut);
    assert_eq!(run.phases.last().map(|p| p.1), Some(Phase::Terminal));
    assert!(run.baro_fused > run.baro_fused_at_seeker_loss);
    assert_eq!(run.final_health, HealthState::Degraded);
    // The joint covariance of the 17 states and the baro error stays positive definite.
    assert!(
        run.joint_min_correlation_eigenvalue > 0.0,
        "{}",
        run.joint_min_correlation_eigenvalue
    );
    // Carry: the solution's error within 3σ of the hand-over covariance on every axis.
    assert!(
        run.carry_worst_normalized < 3.0,
        "{}",
        run.carry_worst_normalized
    );
    std::println!(
        "{}: carry worst |error|/σ {:.2}; smallest joint correlation eigenvalue {:e}",
        core::any::type_name::<T>(),
        run.carry_worst_normalized,
        run.joint_min_correlation_eigenvalue
    );
    std::println!(
        "{}: hand-over φ {:?} rad, σ {:?} rad; terminal position error {:.2} m; health {:?}",
        core::any::type_name::<T>(),
        run.handover_phi,
        run.handover_sigma,
        run.terminal_pos_err_m,
        run.final_health
    );
}

#[test]
fn chain_runs_carry_to_terminal_f64() {
    chain_phases_and_handover::<f64>();
}

#[test]
fn chain_runs_carry_to_terminal_f32() {
    chain_phases_and_handover::<f32>();
}

fn refused_inputs_change_nothing<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(2.0, 10.0);
    let inc = world.step();
    refused_imu_changes_nothing(&mut nav, &inc);
    refused_master_is_counted(&mut nav, &mut world, &inc);
    refused_in_flight_changes_nothing(&mut nav, &mut world);
}

/// A bad or late IMU sample in carry: `Err`, the navigator (and a `tick_into` slot) unchanged.
fn refused_imu_changes_nothing<T: Real>(nav: &mut FlightNavigator<T, 32>, inc: &ImuIncrement<f64>) {
    // A bad IMU sample: Err, the navigator unchanged bit for bit.
    let before = dump(nav);
    let mut bad = imu_tick::<T>(inc);
    bad.increment.delta_v_m_s.x = T::lit(f64::NAN);
    assert!(matches!(
        nav.tick(&bad, &Aids::NONE),
        Err(NavError::NonFiniteInput { .. })
    ));
    assert_eq!(dump(nav), before);
    // Through `tick_into`: the caller's report slot is left as it was too.
    let mut slot = nav.blank_report();
    slot.phase = Phase::Terminal;
    let slot_before = format!("{slot:?}");
    assert!(matches!(
        nav.tick_into(&bad, &Aids::NONE, &mut slot),
        Err(NavError::NonFiniteInput { .. })
    ));
    assert_eq!(dump(nav), before);
    assert_eq!(format!("{slot:?}"), slot_before);
    let mut late = imu_tick::<T>(inc);
    late.increment.time = Timestamp::from_micros(inc.time.as_micros() - DT_US);
    assert_eq!(
        nav.tick(&late, &Aids::NONE),
        Err(NavError::TimeNotIncreasing)
    );
    assert_eq!(dump(nav), before);
}

/// A bad master in carry: refused, counted, nothing of it applied; the next valid tick works.
fn refused_master_is_counted<T: Real>(
    nav: &mut FlightNavigator<T, 32>,
    world: &mut World,
    inc: &ImuIncrement<f64>,
) {
    // A bad master: refused, counted, nothing of it applied (same solution as without it).
    let mut twin = nav.clone();
    let mut m = late_master::<T>(world).or_else(|| {
        world.k -= 1;
        let s = late_master::<T>(world);
        world.k += 1;
        s
    });
    let m = m.as_mut().unwrap();
    m.c_m_n[(0, 0)] = T::lit(f64::NAN);
    let aids = Aids {
        master: Some(m),
        ..Aids::NONE
    };
    let r = nav.tick(&imu_tick(inc), &aids).unwrap();
    assert!(matches!(r.master.state, AidState::Refused(_)));
    assert_eq!(r.master.counters.refused, 1);
    let r2 = twin.tick(&imu_tick(inc), &Aids::NONE).unwrap();
    assert_eq!(r.solution, r2.solution);
    // The next valid tick works.
    let inc = world.step();
    let m = late_master::<T>(world);
    let r = nav
        .tick(
            &imu_tick(&inc),
            &Aids {
                master: m.as_ref(),
                ..Aids::NONE
            },
        )
        .unwrap();
    assert_eq!(r.phase, Phase::Carry);
}

/// In flight: a bad IMU sample is refused with nothing changed, the next tick works.
fn refused_in_flight_changes_nothing<T: Real>(nav: &mut FlightNavigator<T, 32>, world: &mut World) {
    // In flight: a bad LOS sample is refused with nothing changed, the next tick works.
    release_at_truth(nav, world);
    assert_eq!(nav.phase(), Phase::Released);
    let inc = world.step();
    let r = nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    assert_eq!(
        r.transition.map(|t| t.cause),
        Some(TransitionCause::ReleaseCommanded)
    );
    let before = dump(nav);
    let inc = world.step();
    let mut bad = imu_tick::<T>(&inc);
    bad.increment.delta_theta_rad.y = T::lit(f64::INFINITY);
    assert!(nav.tick(&bad, &Aids::NONE).is_err());
    assert_eq!(dump(nav), before);
    assert!(nav.tick(&imu_tick(&inc), &Aids::NONE).is_ok());
}

/// A master sample whose hand-over fails only after the alignment has stepped (the slave's
/// station, through the lever arm, beyond the INS's altitude range while the master is inside
/// it): refused, and the alignment undone — the navigator continues exactly as without it.
fn master_refused_after_the_alignment_step<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(1.0, 10.0);
    // Advance to a tick with a master sample.
    let mut inc = world.step();
    while late_master::<T>(&world).is_none() {
        nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        inc = world.step();
    }
    let mut m = late_master::<T>(&world).unwrap();
    // A banked master whose lever arm points up, at the top of the altitude range.
    let l0 = nav.config().lever_arm.nominal_m;
    let c = [T::lit(0.5), T::lit(-0.5)]
        .map(|roll| crate::math::rotation::euler_to_dcm(roll, T::zero(), T::zero()))
        .into_iter()
        .find(|c| (c * l0).z < T::lit(-1.0))
        .unwrap();
    m.c_m_n = c;
    m.position.alt_m = crate::seeker_ins::MAX_ALT_M - 0.5;
    let mut twin = nav.clone();
    let before = format!("{:?}", nav.alignment());
    let r = nav
        .tick(
            &imu_tick(&inc),
            &Aids {
                master: Some(&m),
                ..Aids::NONE
            },
        )
        .unwrap();
    assert_eq!(
        r.master.state,
        AidState::Refused(NavError::InputOutOfRange {
            input: "master.position"
        })
    );
    assert_eq!(format!("{:?}", nav.alignment()), before);
    let r2 = twin.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    assert_eq!(r.solution, r2.solution);
    assert_eq!(
        format!("{:?}", nav.alignment()),
        format!("{:?}", twin.alignment())
    );
    // The next ticks (with master samples) as the twin's, bit for bit.
    for _ in 0..6 {
        let inc = world.step();
        let m = late_master::<T>(&world);
        let aids = Aids {
            master: m.as_ref(),
            ..Aids::NONE
        };
        let a = nav.tick(&imu_tick(&inc), &aids).unwrap();
        let b = twin.tick(&imu_tick(&inc), &aids).unwrap();
        assert_eq!(a.solution, b.solution);
        assert_eq!(a.master.last, b.master.last);
        // The refusal is the only count that differs.
        assert_eq!(a.master.counters.refused, b.master.counters.refused + 1);
        assert_eq!(a.master.counters.fused, b.master.counters.fused);
    }
    assert_eq!(
        format!("{:?}", nav.alignment()),
        format!("{:?}", twin.alignment())
    );
}

#[test]
fn master_refused_after_the_alignment_step_f64() {
    master_refused_after_the_alignment_step::<f64>();
}

#[test]
fn master_refused_after_the_alignment_step_f32() {
    master_refused_after_the_alignment_step::<f32>();
}

#[test]
fn refused_inputs_change_nothing_f64() {
    refused_inputs_change_nothing::<f64>();
}

#[test]
fn refused_inputs_change_nothing_f32() {
    refused_inputs_change_nothing::<f32>();
}

fn unconfirmed_and_timeout<T: Real>() {
    // Master for 3 s, then lost.
    let (mut nav, mut world) = carry_for::<T>(3.0, 100.0);
    // A release signal the IMU does not confirm (the missile stays on the wing).
    let mut last = None;
    for k in 0..60 {
        let inc = world.step();
        let m = late_master::<T>(&world);
        let aids = Aids {
            master: m.as_ref(),
            separation: (k == 0).then_some(inc.time),
            ..Aids::NONE
        };
        last = Some(nav.tick(&imu_tick(&inc), &aids).unwrap());
    }
    let r = last.unwrap();
    assert_eq!(r.phase, Phase::Carry);
    assert_eq!(
        r.degradation.separation,
        SeparationStatus::SeparationUnconfirmed
    );
    assert_eq!(r.health, HealthState::Degraded);
    assert_eq!(r.degradation.master, AidAvailability::Available);
    // Master lost: TimedOut after master_s (0.5 s).
    let mut states = Vec::new();
    for _ in 0..80 {
        let inc = world.step();
        let r = nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        states.push((r.master.state, r.degradation.master));
    }
    assert_eq!(states[10], (AidState::Waiting, AidAvailability::Available));
    assert_eq!(
        states.last().copied(),
        Some((AidState::TimedOut, AidAvailability::TimedOut))
    );
    assert_eq!(nav.phase(), Phase::Carry);
}

/// While a signalled separation awaits the IMU's confirmation, a master sample whose epoch is
/// later than one IMU interval before the signal's is not fused (nothing counted, the
/// alignment untouched); earlier ones are; after the window closes unconfirmed, all are again.
fn master_after_signal<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(3.0, 100.0);
    let mut signal = None;
    let mut prev: Option<(SeparationStatus, u32)> = None;
    let (mut early, mut withheld, mut resumed) = (0, 0, 0);
    for k in 0..60 {
        let inc = world.step();
        let m = late_master::<T>(&world);
        let sig = *signal.get_or_insert(inc.time);
        let aids = Aids {
            master: m.as_ref(),
            separation: (k == 0).then_some(inc.time),
            ..Aids::NONE
        };
        let ta = format!("{:?}", nav.alignment());
        let r = nav.tick(&imu_tick(&inc), &aids).unwrap();
        let awaiting = prev.is_some_and(|p| p.0 == SeparationStatus::AwaitingConfirmation);
        let fused_before = prev.map(|p| p.1);
        prev = Some((r.degradation.separation, r.master.counters.fused));
        let Some(m) = m else { continue };
        if awaiting && m.time.as_micros() + DT_US > sig.as_micros() {
            assert_eq!(r.master.state, AidState::NotUsedInPhase, "k {k}");
            assert_eq!(Some(r.master.counters.fused), fused_before);
            assert_eq!(format!("{:?}", nav.alignment()), ta);
            withheld += 1;
        } else {
            assert_eq!(r.master.state, AidState::Fused, "k {k}");
            if awaiting || k == 0 {
                early += 1;
            } else {
                resumed += 1;
            }
        }
    }
    assert_eq!(
        prev.map(|p| p.0),
        Some(SeparationStatus::SeparationUnconfirmed)
    );
    // The samples of the latency before the signal, the window's, the ones after it.
    assert!(
        early >= 1 && withheld >= 10 && resumed >= 10,
        "{early} {withheld} {resumed}"
    );
}

#[test]
fn master_after_signal_f64() {
    master_after_signal::<f64>();
}

#[test]
fn master_after_signal_f32() {
    master_after_signal::<f32>();
}

#[test]
fn unconfirmed_separation_and_master_timeout_f64() {
    unconfirmed_and_timeout::<f64>();
}

#[test]
fn unconfirmed_separation_and_master_timeout_f32() {
    unconfirmed_and_timeout::<f32>();
}

#[test]
fn size_of_flight_navigator() {
    let s32 = core::mem::size_of::<FlightNavigator<f32, 32>>();
    let s128 = core::mem::size_of::<FlightNavigator<f32, 128>>();
    std::println!("size_of FlightNavigator<f32, 32> = {s32} B, <f32, 128> = {s128} B");
    assert!(s32 > 0);
}

#[test]
fn bad_configuration_is_named() {
    let mut c = config::<f64>(BaroDamping::Off);
    c.imu_dt_s = 0.02;
    let init = chain_world(&c.lever_arm.nominal_m).initial::<f64>();
    assert_eq!(
        FlightNavigator::<f64, 32>::new(&c, &init).unwrap_err(),
        NavError::InvalidConfig {
            field: "alignment.dt_s",
            issue: crate::error::ConfigIssue::OutOfRange
        }
    );
    let mut c = config::<f64>(BaroDamping::Ekf(BaroErrorModel {
        markov_tau_s: 0.0,
        ..baro_model()
    }));
    c.ins.gate = Gate::Off;
    assert!(matches!(
        FlightNavigator::<f64, 32>::new(&c, &init),
        Err(NavError::InvalidConfig {
            field: "baro.markov_tau_s",
            ..
        })
    ));
}

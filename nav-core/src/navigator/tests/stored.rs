//! The stored design, the in-place baro update, a refused LOS sample, the bias hand-over.

use super::*;

/// `from_design` with the design written to values and read back is `new`, bit for bit, after
/// two seconds of carry; designs of another configuration, or a baro-loop design missing or
/// superfluous, are refused by name.
fn stored_design_is_new<T: Real>() {
    use crate::design::DesignValues;
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let world = chain_world(&lever);
    let init = world.initial::<T>();
    let design = FlightNavigator::<T, 32>::design(&cfg).unwrap();
    let mut values = std::vec![0.0; NavigatorDesign::<T, 5>::COUNT];
    design.write_values(&mut values).unwrap();
    let loaded = NavigatorDesign::<T, 5>::read_values(&values).unwrap();
    assert_eq!(loaded, design);
    let mut a = FlightNavigator::<T, 32>::new(&cfg, &init).unwrap();
    let mut b = FlightNavigator::<T, 32>::from_design(&cfg, &loaded, &init).unwrap();
    let mut wa = chain_world(&lever);
    for _ in 0..200 {
        let inc = wa.step();
        let master = late_master::<T>(&wa);
        let aids = Aids {
            master: master.as_ref(),
            ..Aids::NONE
        };
        let ra = a.tick(&imu_tick(&inc), &aids).unwrap();
        let rb = b.tick(&imu_tick(&inc), &aids).unwrap();
        assert_eq!(format!("{ra:?}"), format!("{rb:?}"));
    }
    assert!(a.alignment().theta().iter().any(|x| *x != T::zero()));
    assert_eq!(dump(&a), dump(&b));
    // The EKF's design of another IMU.
    let mut other = cfg;
    other.ins.gyro_noise_density_rad_s_rt_hz *= T::lit(2.0);
    assert!(matches!(
        FlightNavigator::<T, 32>::from_design(&other, &loaded, &init),
        Err(NavError::InvalidConfig {
            field: "design",
            ..
        })
    ));
    // The alignment's design of another step.
    let mut other = cfg;
    other.alignment.mount_sigma_rad *= T::lit(2.0);
    assert!(FlightNavigator::<T, 32>::from_design(&other, &loaded, &init).is_err());
    // A bad flag value.
    values[TaDesignCount::<T>::N + 4] = 0.5;
    assert!(NavigatorDesign::<T, 5>::read_values(&values).is_err());
    // The loop asked for, no loop design stored.
    let mut vc = crate::vertical_channel::ClassicalConfig::<T>::paper();
    vc.baro_lag_s = T::zero();
    vc.latitude_rad = T::lit(START.lat_rad);
    let lp = config::<T>(BaroDamping::InertialLoop(vc));
    if !cfg!(feature = "baro-inertial-loop") {
        // A build without the loop refuses it by name, with or without a design.
        let refused = NavError::InvalidConfig {
            field: "baro",
            issue: crate::error::ConfigIssue::OutOfRange,
        };
        assert_eq!(
            FlightNavigator::<T, 32>::new(&lp, &init).unwrap_err(),
            refused
        );
        assert_eq!(
            FlightNavigator::<T, 32>::from_design(&lp, &loaded, &init).unwrap_err(),
            refused
        );
        return;
    }
    assert!(FlightNavigator::<T, 32>::new(&lp, &init).is_ok());
    assert_eq!(
        FlightNavigator::<T, 32>::from_design(&lp, &loaded, &init).unwrap_err(),
        NavError::InvalidConfig {
            field: "design.baro_loop",
            issue: crate::error::ConfigIssue::DesignMismatch
        }
    );
}

struct TaDesignCount<T>(core::marker::PhantomData<T>);
impl<T: Real> TaDesignCount<T> {
    const N: usize =
        <crate::transfer_alignment::TaDesign<T, 5> as crate::design::DesignValues>::COUNT;
}

#[test]
fn stored_design_is_new_f64() {
    stored_design_is_new::<f64>();
}

#[test]
fn stored_design_is_new_f32() {
    stored_design_is_new::<f32>();
}

/// The navigator's baro update (the gain over the row's two columns, P updated in place after
/// its check) gives the numbers of the reference [`baro_update`] bit for bit, f32 and f64.
fn baro_update_in_place_is_the_reference<T: Real>() {
    let ekf64 = flight_ekf();
    let p64 = *ekf64.covariance();
    let (c64, s64) = joint_column(&p64);
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let s0 = ekf64.state();
    let ekf = <SeekerIns<T> as crate::contract::Estimator>::new(
        &cfg.ins,
        &SeekerInsInitial {
            state: InsState {
                position: s0.position,
                vel_ned_m_s: s0.vel_ned_m_s.map(|x| T::lit(x)),
                q_b_n: Quaternion::from(s0.q_b_n.coords.map(|x| T::lit(x))),
            },
            covariance: p64.map(|x| T::lit(x)),
        },
    )
    .unwrap();
    let st = BaroState::<T> {
        cross: c64.map(|x| T::lit(x)),
        variance_m2: T::lit(s64),
        bias_m: T::lit(1.5),
        ..BaroState::off()
    };
    let p = *ekf.covariance();
    for (tau, z) in [(0.3, 3004.0), (0.0, 2990.0), (0.05, 3000.5)] {
        let (tau, z) = (T::lit(tau), T::lit(z));
        let y = st.predicted_m(&ekf, tau) - z;
        let r = T::one();
        let reference = baro_update(&p, &st, &BaroState::h_row(tau), y, r, Gate::Off).unwrap();
        let Some(Ok(g)) = super::baro::baro_gain(&p, &st, tau, y, r, Gate::Off) else {
            panic!("the gain is formed");
        };
        let mut e = ekf;
        assert!(e.update_rank_one(&g.dx, &g.u, &g.k, g.delta).unwrap());
        let bits = |m: &[T]| m.iter().map(|v| v.to_f64().to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(e.covariance().as_slice()),
            bits(reference.p.as_slice())
        );
        assert_eq!(bits(g.cross.as_slice()), bits(reference.cross.as_slice()));
        assert_eq!(bits(g.dx.as_slice()), bits(reference.dx.as_slice()));
        assert_eq!(
            g.variance_m2.to_f64().to_bits(),
            reference.variance_m2.to_f64().to_bits()
        );
        assert_eq!(g.db_m.to_f64().to_bits(), reference.db_m.to_f64().to_bits());
        // A gain whose P would not be a covariance is refused with nothing changed.
        let mut f = ekf;
        let huge = g.u * T::lit(1e6);
        assert!(!f.update_rank_one(&g.dx, &huge, &huge, g.delta).unwrap());
        assert_eq!(f, ekf);
    }
}

#[test]
fn baro_update_in_place_is_the_reference_f64() {
    baro_update_in_place_is_the_reference::<f64>();
}

#[test]
fn baro_update_in_place_is_the_reference_f32() {
    baro_update_in_place_is_the_reference::<f32>();
}

/// A LOS sample refused (a non-finite or out-of-range gimbal angle) while
/// IMU samples wait for their covariance step leaves the EKF (P, its pending step, every
/// counter) and the baro column exactly as the same tick without it.
fn refused_los_keeps_the_pending_step<T: Real>() {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    release_at_truth(&mut nav, &world);
    for _ in 0..((COAST_S / DT) as u64 + 2) {
        let inc = world.step();
        nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    }
    assert_eq!(nav.phase(), Phase::Midcourse);
    // A baro sample (the column becomes non-zero), then IMU ticks: steps pending.
    let inc = world.step();
    let truth = world.missile_truth();
    let b = BaroSample {
        time: inc.time,
        altitude_m: T::lit(truth.position.alt_m + 0.5),
    };
    let aids = Aids {
        baro: Some(&b),
        ..Aids::NONE
    };
    assert_eq!(
        nav.tick(&imu_tick(&inc), &aids).unwrap().baro.state,
        AidState::Fused
    );
    for _ in 0..3 {
        let inc = world.step();
        nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    }
    assert!(nav.ekf().unwrap().steps_pending() > 0);
    assert!(nav.baro_state().cross.norm() > T::zero());
    let inc = world.step();
    let gimbal = |pitch: f64| crate::seeker_ins::GimbalAngles {
        pitch_rad: T::lit(pitch),
        yaw_rad: T::zero(),
    };
    let bad = [
        LosSample {
            time: inc.time,
            gimbal: gimbal(f64::NAN),
        },
        LosSample {
            time: inc.time,
            gimbal: gimbal(1.5),
        },
    ];
    for s in &bad {
        let mut a = nav.clone();
        let mut b = nav.clone();
        let aids = Aids {
            seeker: Some(s),
            ..Aids::NONE
        };
        let ra = a.tick(&imu_tick(&inc), &aids).unwrap();
        let rb = b.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        assert!(matches!(ra.seeker.state, AidState::Refused(_)));
        assert!(
            a.ekf().unwrap().steps_pending() > 1,
            "the step still pending"
        );
        assert_eq!(a.ekf(), b.ekf());
        assert_eq!(a.baro_state(), b.baro_state());
        assert_eq!(ra.solution, rb.solution);
    }
}

#[test]
fn refused_los_keeps_the_pending_step_f64() {
    refused_los_keeps_the_pending_step::<f64>();
}

#[test]
fn refused_los_keeps_the_pending_step_f32() {
    refused_los_keeps_the_pending_step::<f32>();
}

/// At the hand-over the EKF's accelerometer-bias states are the equivalent bias at the
/// carry's specific force: their variance is the prior's plus that of the scale factor and
/// misalignment at the last master epoch's specific force (≈ 1 g down), charged at once, not
/// at the drop's first covariance step (where the missile falls at ≈ 0 g).
fn handover_refers_the_bias_to_the_carry<T: Real>() {
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    let e = cfg.ins.instrument_errors;
    let (sf, mis) = (
        e.accel_scale_factor.to_f64(),
        e.accel_misalignment_rad.to_f64(),
    );
    assert!(sf > 0.0 && mis > 0.0);
    let prior = cfg.priors.accel_bias_sigma_m_s2.to_f64().powi(2);
    for _ in 0..((SEPARATION_S + 1.0) / DT).round() as u64 {
        let inc = world.step();
        // Before the coast ends: the master and the release signal only.
        let samples = ChainAids::<T>::at(&world, &inc);
        let aids = samples.aids();
        let r = nav.tick(&imu_tick(&inc), &aids).unwrap();
        if r.phase == Phase::Released {
            let p = nav.ekf().unwrap().covariance();
            let g = 9.8;
            let want = [(mis * g).powi(2), (mis * g).powi(2), (sf * g).powi(2)];
            for (i, w) in want.iter().enumerate() {
                let added = p[(ACC_BIAS + i, ACC_BIAS + i)].to_f64() - prior;
                assert!((added - w).abs() < 0.03 * w, "axis {i}: {added:e} vs {w:e}");
            }
            return;
        }
    }
    panic!("not released");
}

#[test]
fn handover_refers_the_bias_to_the_carry_f64() {
    handover_refers_the_bias_to_the_carry::<f64>();
}

#[test]
fn handover_refers_the_bias_to_the_carry_f32() {
    handover_refers_the_bias_to_the_carry::<f32>();
}

/// The flight alignment the navigator runs has the slave's scale-factor and misalignment
/// share of level carry in its difference-bias prior (`alignment_config`: the instruments'
/// prior plus `slave_share_variance` of the EKF's instrument errors, on every axis); its
/// design's bias states start there and the running filter reports that prior.
fn alignment_bias_prior_holds_the_slave_share<T: Real>() {
    let cfg = config::<T>(BaroDamping::Off);
    let e = cfg.ins.instrument_errors;
    let share = crate::transfer_alignment::slave_share_variance(
        e.accel_scale_factor,
        e.accel_misalignment_rad,
    )
    .map(|v| v.to_f64());
    assert!(share.z > share.x && share.x > 0.0);
    let run = crate::navigator::alignment_config(&cfg).accel_bias_sigma_m_s2;
    let own = cfg.alignment.accel_bias_sigma_m_s2;
    let tol = if T::lit(1.0) + T::lit(1e-9) == T::lit(1.0) {
        1e-6
    } else {
        1e-12
    };
    for i in 0..3 {
        let want = own[i].to_f64().powi(2) + share[i];
        let got = run[i].to_f64().powi(2);
        assert!(
            (got - want).abs() < tol * want,
            "axis {i}: {got:e} vs {want:e}"
        );
    }
    let design = FlightNavigator::<T, 32>::design(&cfg).unwrap();
    let b = crate::transfer_alignment::BIAS_STATE;
    for (i, ch) in design.alignment.chains.iter().enumerate() {
        assert_eq!(ch.p0[(b, b)], run[i] * run[i], "axis {i}");
    }
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let world = chain_world(&lever);
    let nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    assert_eq!(
        nav.alignment().accel_bias_prior_variance(),
        run.component_mul(&run)
    );
}

#[test]
fn alignment_bias_prior_holds_the_slave_share_f64() {
    alignment_bias_prior_holds_the_slave_share::<f64>();
}

#[test]
fn alignment_bias_prior_holds_the_slave_share_f32() {
    alignment_bias_prior_holds_the_slave_share::<f32>();
}

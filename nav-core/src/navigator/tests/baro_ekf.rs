//! The baro EKF (18th state): the cross column, the update against the dense 18-state
//! reference and finite differences, the joint covariance, the chain with the inertial loop,
//! refused flight aids and releases.

use super::*;

/// `transition_times` is the generated kernel's Φ: with the noise off, the kernel maps
/// `v vᵀ` to `(Φ v)(Φ v)ᵀ`.
#[test]
fn cross_column_uses_the_kernels_transition() {
    let ekf = flight_ekf();
    let s = ekf.state();
    let f_ned = Vector3::new(1.5, -0.7, -9.6);
    let f = SparseF::new(&s.position, &s.vel_ned_m_s, &quat_to_dcm(&s.q_b_n), &f_ned);
    let dt = 0.1;
    let v = SVector::<f64, STATES>::from_fn(|i, _| 1e-3 * (1.0 + i as f64).sin());
    let mut p = v * v.transpose();
    propagate_covariance_sparse(&mut p, &f, dt, 0.0, 0.0).unwrap();
    let phi_v = crate::seeker_ins::transition_times_for_tests(&f, dt, &v);
    let reference = phi_v * phi_v.transpose();
    let err = (p - reference).abs().max() / reference.abs().max();
    assert!(err < 1e-12, "relative error {err}");
    assert!(
        (phi_v - v).norm() > 1e-6 * v.norm(),
        "Φ must not be the identity here"
    );
}

/// The block update equals the dense 18-state Joseph-form update to rounding, and H
/// matches finite differences of the predicted reading.
#[test]
fn baro_update_matches_dense_18_state_reference_and_finite_differences() {
    let ekf = flight_ekf();
    let p = *ekf.covariance();
    let (cross, s) = joint_column(&p);
    let st = BaroState {
        cross,
        variance_m2: s,
        bias_m: 1.5,
        ..BaroState::off()
    };
    let tau = 0.3;
    let h = BaroState::h_row(tau);
    let z = 3004.0;
    let y = st.predicted_m(&ekf, tau) - z;
    let r = 1.0;
    let u = baro_update(&p, &st, &h, y, r, Gate::Off).unwrap();
    assert_eq!(u.report.outcome, FusionOutcome::Fused);
    // Dense reference.
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = s;
    assert!(pa.cholesky().is_some());
    let mut ha = SVector::<f64, 18>::zeros();
    ha.fixed_rows_mut::<17>(0).copy_from(&h);
    ha[17] = 1.0;
    let mut xa = SVector::<f64, 18>::zeros();
    let rep = fuse_scalar(&mut xa, &mut pa, &ha, y, r, Gate::Off).unwrap();
    assert!((rep.innovation_variance - u.report.innovation_variance).abs() < 1e-9);
    let scale = pa.abs().max();
    let mut got = SMatrix::<f64, 18, 18>::zeros();
    got.fixed_view_mut::<17, 17>(0, 0).copy_from(&u.p);
    got.fixed_view_mut::<17, 1>(0, 17).copy_from(&u.cross);
    got.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&u.cross.transpose());
    got[(17, 17)] = u.variance_m2;
    let e_p = (got - pa).abs().max() / scale;
    assert!(e_p < 1e-12, "P relative error {e_p}");
    let e_x = (u.dx - xa.fixed_rows::<17>(0)).norm() + (u.db_m - xa[17]).abs();
    assert!(e_x < 1e-9 * xa.norm().max(1e-12), "x error {e_x}");
    assert!(got.cholesky().is_some(), "joint P after the update is PD");
    // H against finite differences of ẑ = ĥ + τ V̂_D + b̂ (error state: estimate − truth).
    let eps = 1e-3;
    let shifted = |dh: f64, dvd: f64| {
        let mut init = SeekerInsInitial {
            state: *ekf.state(),
            covariance: p,
        };
        init.state.position.alt_m += dh;
        init.state.vel_ned_m_s.z += dvd;
        let e = <SeekerIns<f64> as crate::contract::Estimator>::new(ekf.config(), &init).unwrap();
        st.predicted_m(&e, tau)
    };
    let z0 = st.predicted_m(&ekf, tau);
    assert!(((shifted(eps, 0.0) - z0) / eps - h[POS + 2]).abs() < 1e-6);
    assert!(((shifted(0.0, eps) - z0) / eps - h[VEL + 2]).abs() < 1e-6);
    let mut st_b = st;
    st_b.bias_m += eps;
    assert!(((st_b.predicted_m(&ekf, tau) - z0) / eps - 1.0).abs() < 1e-9);
}

/// Prediction of the joint matrix: the column follows `e Φ c` and s the Markov law; the
/// joint matrix stays positive definite through the navigator's deferred covariance steps.
#[test]
fn baro_column_prediction_keeps_the_joint_covariance_pd() {
    let mut ekf = flight_ekf();
    let model = baro_model::<f64>();
    let p = *ekf.covariance();
    let (mut cross, s) = joint_column(&p);
    let mut st = BaroState {
        cross,
        variance_m2: s,
        bias_m: 2.0,
        ..BaroState::off()
    };
    let mut t = Timestamp::from_micros(DT_US);
    for k in 0..25u64 {
        let inc = ImuIncrement {
            time: t,
            delta_theta_rad: Vector3::new(1e-4, -2e-4, 3e-4),
            delta_v_m_s: Vector3::new(0.02, 0.01, -0.098),
        };
        ekf.propagate_deferred(&inc, None).unwrap();
        if k % 10 == 9 {
            let c_before = st.cross;
            let dt = ekf
                .predict_covariance_cross(&mut st.cross)
                .unwrap()
                .unwrap();
            assert!((dt - 0.1).abs() < 1e-12);
            assert!((st.cross - c_before).norm() > 0.0);
            st.decay(&model, dt);
        }
        t = t.add_micros(DT_US);
    }
    cross = st.cross;
    let p = *ekf.covariance();
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = st.variance_m2;
    assert!(pa.cholesky().is_some());
    let e = (-0.2_f64 / 100.0).exp();
    assert!((st.bias_m - 2.0 * e).abs() < 1e-12);
    assert!(ekf.steps_pending() == 5);
}

#[cfg_attr(not(feature = "baro-inertial-loop"), allow(dead_code))]
fn chain_with_inertial_loop<T: Real>() {
    let mut vc = crate::vertical_channel::ClassicalConfig::<T>::paper();
    vc.baro_lag_s = T::zero();
    vc.latitude_rad = T::lit(START.lat_rad);
    let run = run_chain::<T>(BaroDamping::InertialLoop(vc), 27.0);
    let seq: Vec<Phase> = run.phases.iter().map(|p| p.1).collect();
    assert_eq!(seq, [Phase::Released, Phase::Midcourse, Phase::Terminal]);
    assert!(run.baro_fused > 0);
    // The EKF's vertical block is the loop's σ covariance, decoupled from the rest.
    assert_eq!(run.midcourse_vertical_cross, 0.0);
    assert!(run.midcourse_vertical_var[0] > 0.0 && run.midcourse_vertical_var[1] > 0.0);
    // The loop's σ covers the altitude error (truth and baro agree here).
    assert!(
        run.midcourse_alt_err_m.abs() <= 3.0 * run.midcourse_vertical_var[0].sqrt(),
        "{} vs σ {}",
        run.midcourse_alt_err_m,
        run.midcourse_vertical_var[0].sqrt()
    );
    std::println!(
        "{}: inertial loop: midcourse altitude error {:.3} m, σ_h {:.3} m, σ_VD {:.4} m/s",
        core::any::type_name::<T>(),
        run.midcourse_alt_err_m,
        run.midcourse_vertical_var[0].sqrt(),
        run.midcourse_vertical_var[1].sqrt()
    );
}

#[cfg(feature = "baro-inertial-loop")]
#[test]
fn chain_with_inertial_loop_f64() {
    chain_with_inertial_loop::<f64>();
}

#[cfg(feature = "baro-inertial-loop")]
#[test]
fn chain_with_inertial_loop_f32() {
    chain_with_inertial_loop::<f32>();
}

fn flight_aids_refused<T: Real>() {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    let truth = world.missile_truth();
    release_at_truth(&mut nav, &world);
    // A second release is refused.
    assert!(nav
        .release_with(&crate::seeker_ins::SeekerInsInitial {
            state: InsState {
                position: truth.position,
                vel_ned_m_s: Vector3::zeros(),
                q_b_n: Quaternion::identity(),
            },
            covariance: crate::seeker_ins::paper_initial_covariance::<T>(),
        })
        .is_err());
    // Coast to midcourse.
    for _ in 0..((COAST_S / DT) as u64 + 2) {
        let inc = world.step();
        nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    }
    assert_eq!(nav.phase(), Phase::Midcourse);
    // Good baro samples for a while.
    for _ in 0..20 {
        let inc = world.step();
        let truth = world.missile_truth();
        let b = BaroSample {
            time: inc.time,
            altitude_m: T::lit(truth.position.alt_m + 0.5),
        };
        let r = nav
            .tick(
                &imu_tick(&inc),
                &Aids {
                    baro: Some(&b),
                    ..Aids::NONE
                },
            )
            .unwrap();
        assert_eq!(r.baro.state, AidState::Fused);
    }
    // Bad baro and bad LOS: refused; the solution is the one without them.
    let inc = world.step();
    bad_aids_refused(&nav, &inc);
    // The next valid tick works.
    assert!(nav.tick(&imu_tick(&inc), &Aids::NONE).is_ok());
}

/// Bad baro, future baro and bad LOS in midcourse: each refused, the solution and the baro
/// state those of a tick without it.
fn bad_aids_refused<T: Real>(nav: &FlightNavigator<T, 32>, inc: &ImuIncrement<f64>) {
    let bad_baro = BaroSample {
        time: inc.time,
        altitude_m: T::lit(f64::NAN),
    };
    let future_baro = BaroSample {
        time: inc.time.add_micros(1),
        altitude_m: T::lit(3000.0),
    };
    let bad_los = LosSample {
        time: inc.time,
        gimbal: crate::seeker_ins::GimbalAngles {
            pitch_rad: T::lit(f64::NAN),
            yaw_rad: T::zero(),
        },
    };
    for (baro, seeker) in [
        (Some(&bad_baro), None),
        (Some(&future_baro), None),
        (None, Some(&bad_los)),
    ] {
        let mut a = nav.clone();
        let mut b = nav.clone();
        let ra = a
            .tick(
                &imu_tick(inc),
                &Aids {
                    baro,
                    seeker,
                    ..Aids::NONE
                },
            )
            .unwrap();
        let rb = b.tick(&imu_tick(inc), &Aids::NONE).unwrap();
        let refused = |s: AidState| matches!(s, AidState::Refused(_));
        assert!(refused(ra.baro.state) || refused(ra.seeker.state));
        assert_eq!(ra.solution, rb.solution);
        assert_eq!(a.baro_state(), b.baro_state());
        assert_eq!(a.phase(), Phase::Midcourse);
    }
}

#[test]
fn flight_aids_refused_change_nothing_f64() {
    flight_aids_refused::<f64>();
}

#[test]
fn flight_aids_refused_change_nothing_f32() {
    flight_aids_refused::<f32>();
}

fn unsignalled<T: Real>() {
    // Master for 3 s, then lost; the missile drops without a signal at 4 s.
    let (mut nav, mut world) = carry_for::<T>(3.0, 3.0);
    let mut seen = None;
    for _ in 0..200 {
        let mut inc = world.step();
        if inc.time.as_secs_f64() > 3.9 {
            inc.delta_v_m_s = Vector3::zeros();
        }
        let r = nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        if let Some(t) = r.transition {
            seen = Some((t, r.degradation, r.health));
            break;
        }
    }
    let (t, d, h) = seen.unwrap();
    assert_eq!(t.cause, TransitionCause::UnsignalledSeparation);
    assert_eq!(t.to, Phase::Released);
    assert_eq!(d.separation, SeparationStatus::UnsignalledRelease);
    // Falling from 3.91 s (the master lost since 3.5 s, so the unloading is not with its
    // loss): released at the first 0.3 s window, closed every 60 ms, whose mean specific force
    // is below the 4 m/s² threshold: 3.79-4.09 s, 0.12 s at 1 g and 0.18 s falling (3.9 m/s²).
    assert!(
        (t.time.as_secs_f64() - 4.09).abs() < 1e-6,
        "{}",
        t.time.as_secs_f64()
    );
    assert_ne!(h, HealthState::Nominal);
}

/// The master lost in carry while the aircraft manoeuvres: the slave's specific force departs
/// from the stale last master sample by far more than the jump threshold (a 2 g pull-up), but
/// the missile is still on the wing (its IMU never reads free fall): no release.
fn stale_master_is_no_release<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(3.0, 3.0);
    let mut lost = 0;
    for _ in 0..200 {
        let mut inc = world.step();
        if inc.time.as_secs_f64() > 3.9 {
            inc.delta_v_m_s *= 2.0;
        }
        let r = nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
        assert_eq!(r.transition, None);
        assert_eq!(r.degradation.separation, SeparationStatus::NotSignalled);
        lost += usize::from(r.master.state == AidState::TimedOut);
    }
    assert_eq!(nav.phase(), Phase::Carry);
    assert!(lost > 100, "the master was lost for {lost} ticks");
}

#[test]
fn stale_master_is_no_release_f64() {
    stale_master_is_no_release::<f64>();
}

#[test]
fn stale_master_is_no_release_f32() {
    stale_master_is_no_release::<f32>();
}

#[test]
fn unsignalled_release_f64() {
    unsignalled::<f64>();
}

#[test]
fn unsignalled_release_f32() {
    unsignalled::<f32>();
}

/// f32: a baro sample far more precise than the prior (σ_h 10 km, R 0.01 m²) keeps the joint
/// covariance PSD (conditioned R, stabilising noise). Without them the smallest correlation
/// eigenvalue of the result is −0.28 (measured).
#[test]
fn baro_update_keeps_the_joint_covariance_psd_in_f32() {
    let ekf = flight_ekf();
    let mut p: SMatrix<f32, STATES, STATES> = ekf.covariance().map(|x| x as f32);
    p[(POS + 2, POS + 2)] = 1.0e8;
    let (c, s) = joint_column(&p.map(f64::from));
    let st = BaroState::<f32> {
        cross: c.map(|x| x as f32),
        variance_m2: s as f32,
        bias_m: 0.0,
        ..BaroState::off()
    };
    let h = BaroState::h_row(0.2_f32);
    let u = baro_update(&p, &st, &h, 700.0, 0.01, Gate::Off).unwrap();
    assert_eq!(u.report.outcome, FusionOutcome::Fused);
    let mut pa = SMatrix::<f32, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&u.p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&u.cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&u.cross.transpose());
    pa[(17, 17)] = u.variance_m2;
    assert!(crate::math::kalman::asymmetry(&pa) == 0.0);
    // Smallest eigenvalue of the correlation matrix (in f64, of the f32 result).
    let pd = pa.map(f64::from);
    let d = pd.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
    let corr = SMatrix::<f64, 18, 18>::from_fn(|i, j| pd[(i, j)] * d[i] * d[j]);
    let min_eig = corr.symmetric_eigenvalues().min();
    std::println!("f32 baro update: smallest correlation eigenvalue {min_eig:e}");
    assert!(min_eig > 0.0, "{min_eig}");
    // The raised R: the innovation variance is at least hPhᵀ (1 + 1/κ).
    assert!(u.report.innovation_variance > 1.0e8);
}

/// The dense 18-state covariance of the 17-state P, the baro column and the baro variance.
fn joint_matrix(
    p: &SMatrix<f64, STATES, STATES>,
    cross: &SVector<f64, STATES>,
    s: f64,
) -> SMatrix<f64, 18, 18> {
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = s;
    pa
}

/// The baro column through a LOS update equals the dense 18-state sequential update (b not in
/// the LOS rows) to rounding.
#[test]
fn baro_column_through_los_update_matches_dense_18_state_reference() {
    use crate::seeker_ins::{los_model_at, CrossColumn, GimbalAngles};
    let mut ekf = flight_ekf();
    let mut t = Timestamp::ZERO;
    for _ in 0..10 {
        t = t.add_micros(DT_US);
        ekf.propagate(&ImuIncrement {
            time: t,
            delta_theta_rad: Vector3::new(1e-5, 2e-5, -1e-5),
            delta_v_m_s: Vector3::new(0.0, 0.0, -0.098),
        })
        .unwrap();
    }
    let p = *ekf.covariance();
    let (cross, s) = joint_column(&p);
    // A LOS sample slightly off the INS's own.
    let st = *ekf.state();
    let d = landmark_vector_ned(&st.position, &ekf.config().landmark);
    let c_b_n = quat_to_dcm(&st.q_b_n);
    let g0 = gimbal_angles_of(&(c_b_n.transpose() * d));
    let gimbal = GimbalAngles {
        pitch_rad: g0.pitch_rad + 2e-3,
        yaw_rad: g0.yaw_rad - 1.5e-3,
    };
    let model = los_model_at(
        &st.position,
        &d,
        &c_b_n,
        &gimbal,
        ekf.config().seeker_noise_rad,
    )
    .unwrap();
    let mut col = CrossColumn {
        cross,
        variance: s,
        correction: 0.0,
    };
    let rep = ekf
        .update_los_cross(&LosSample { time: t, gimbal }, &mut col)
        .unwrap();
    assert_eq!(rep.pitch.outcome, FusionOutcome::Fused);
    assert_eq!(rep.yaw.outcome, FusionOutcome::Fused);
    // Dense reference.
    let mut pa = joint_matrix(&p, &cross, s);
    let mut xa = SVector::<f64, 18>::zeros();
    let mut h1 = SVector::<f64, 18>::zeros();
    h1.fixed_rows_mut::<17>(0).copy_from(&model.h_pitch);
    let mut h2 = SVector::<f64, 18>::zeros();
    h2.fixed_rows_mut::<17>(0).copy_from(&model.h_yaw);
    fuse_scalar(
        &mut xa,
        &mut pa,
        &h1,
        model.residual_rad.x,
        model.variance_rad2.x,
        Gate::Off,
    )
    .unwrap();
    let nu2 = model.residual_rad.y - h2.dot(&xa);
    fuse_scalar(&mut xa, &mut pa, &h2, nu2, model.variance_rad2.y, Gate::Off).unwrap();
    let ref_cross = pa.fixed_view::<17, 1>(0, 17).into_owned();
    let e_c = (col.cross - ref_cross).abs().max() / ref_cross.abs().max();
    let e_s = (col.variance - pa[(17, 17)]).abs() / pa[(17, 17)];
    let e_b = (col.correction - xa[17]).abs() / xa[17].abs();
    assert!(e_c < 1e-9 && e_s < 1e-12 && e_b < 1e-9, "{e_c} {e_s} {e_b}");
    assert!(
        (col.cross - cross).norm() > 1e-6 * cross.norm(),
        "the update moved c"
    );
    // The 17-state P is the EKF's (simple form plus its stabilising noise).
    let e_p = (ekf.covariance() - pa.fixed_view::<17, 17>(0, 0))
        .abs()
        .max()
        / p.abs().max();
    assert!(e_p < 1e-9, "{e_p}");
}

/// The chain's midcourse and terminal with the baro EKF of `model`: the smallest eigenvalue of
/// the joint (17 + baro) correlation matrix after every tick, and the baro samples fused.
fn precise_baro_chain<T: Real>(model: BaroErrorModel<T>, end_s: f64) -> (f64, u32) {
    let cfg = config::<T>(BaroDamping::Ekf(model));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    let mut worst = f64::INFINITY;
    let mut fused = 0;
    for _ in 0..(end_s / DT).round() as u64 {
        let inc = world.step();
        let samples = ChainAids::<T>::at(&world, &inc);
        let aids = samples.aids();
        let report = nav.tick(&imu_tick(&inc), &aids).unwrap();
        if matches!(report.phase, Phase::Midcourse | Phase::Terminal) {
            let e = if nav.baro_state().variance_m2 > T::zero() {
                joint_min_correlation_eigenvalue(&nav)
            } else {
                ekf_min_correlation_eigenvalue(&nav)
            };
            worst = worst.min(e);
        }
        fused = report.baro.counters.fused;
    }
    (worst, fused)
}

/// A baro far more precise than the EKF's altitude (white σ down to 1 µm, the first updates at
/// the information-ratio limit, ρ = 8 389 in f32): through midcourse and terminal the
/// joint covariance stays positive definite after every tick, in f32 and f64, with and
/// without the correlated error. Measured: f32's smallest correlation eigenvalue stays at
/// ≈ 3.0e-5 (the update's stabilising noise, 256 ε; +3.8e-8 without it), f64's falls with σ
/// (1e-13 at 1 µm); on the mission (10 runs, baro 1 mm or 1 µm) the same 3.0e-5.
#[test]
fn precise_baro_keeps_the_joint_covariance_positive_definite() {
    for white in [1e-3, 1e-6] {
        for markov in [5.0, 0.5, 0.0] {
            let model = BaroErrorModel {
                white_sigma_m: white,
                markov_sigma_m: markov,
                markov_tau_s: 100.0,
                lag_s: 0.0,
            };
            let model32 = BaroErrorModel {
                white_sigma_m: white as f32,
                markov_sigma_m: markov as f32,
                markov_tau_s: 100.0,
                lag_s: 0.0,
            };
            let (e32, n32) = precise_baro_chain::<f32>(model32, 27.0);
            let (e64, n64) = precise_baro_chain::<f64>(model, 27.0);
            std::println!(
                "baro white {white:e} m, correlated {markov} m: smallest correlation \
                 eigenvalue f32 {e32:e} ({n32} fused), f64 {e64:e} ({n64} fused)"
            );
            assert!(e32 > 0.0 && e64 > 0.0, "f32 {e32:e}, f64 {e64:e}");
            assert!(n32 >= 100 && n64 >= 100, "fused {n32} / {n64}");
        }
    }
}

/// Smallest eigenvalue of the EKF's 17-state correlation matrix.
fn ekf_min_correlation_eigenvalue<T: Real>(nav: &FlightNavigator<T, 32>) -> f64 {
    let p = nav.ekf().unwrap().covariance().map(|x| x.to_f64());
    let d = p.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
    let corr = SMatrix::<f64, 17, 17>::from_fn(|i, j| p[(i, j)] * d[i] * d[j]);
    corr.symmetric_eigenvalues().min()
}

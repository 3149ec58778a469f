//! The consider parameters against their definitions: `J` and `Γ` by finite differences of
//! `(S + M) u`, the covariance step and the scalar update against the dense 26-state
//! covariance (`Φ_a P_a Φ_aᵀ + Q_a`, the Kalman update with `h_a = [h, 0]`), f64 and f32, and
//! the filter's joint covariance PSD over a weave with LOS updates.

use super::*;
use crate::seeker_ins::{
    error_model::transition_times, propagate_covariance_sparse, InstrumentErrors, Position,
};
use nalgebra::{Matrix3, Rotation3, SMatrix, SVector, Vector3};

const N: usize = STATES + CONSIDER;

fn errors<T: Real>() -> InstrumentErrors<T> {
    InstrumentErrors {
        accel_scale_factor: T::lit(2e-4),
        accel_misalignment_rad: T::lit(4.85e-5),
        gyro_scale_factor: T::lit(2e-5),
        gyro_misalignment_rad: T::lit(4.85e-5),
    }
}

/// `(I + S + M)` of the parameters `c` (order of [`ROW_COMP`]).
fn s_plus_m(c: &SVector<f64, CONSIDER>) -> Matrix3<f64> {
    let mut m = Matrix3::zeros();
    for (j, (r, k)) in ROW_COMP.iter().enumerate() {
        m[(*r, *k)] += c[j];
    }
    m
}

/// A deterministic pseudo-random number in [−1, 1).
fn rnd(seed: &mut u64) -> f64 {
    *seed = seed
        .wrapping_mul(6_364_136_223_846_793_005)
        .wrapping_add(1_442_695_040_888_963_407);
    ((*seed >> 11) as f64 / (1u64 << 53) as f64) * 2.0 - 1.0
}

#[test]
fn jacobian_and_gamma_are_the_derivatives_of_the_error() {
    let u = Vector3::new(1.3, -0.4, -9.9);
    let c_b_n = *Rotation3::from_euler_angles(0.3, -0.2, 1.1).matrix();
    let dt = 0.1;
    let g = gamma(&c_b_n, &u, dt);
    let c0 = SVector::<f64, CONSIDER>::from_fn(|j, _| 1e-4 * (j as f64 - 4.0));
    for j in 0..CONSIDER {
        // Central difference of `C (S + M) u Δt` in parameter j.
        let h = 1e-6;
        let mut cp = c0;
        let mut cm = c0;
        cp[j] += h;
        cm[j] -= h;
        let fd = (c_b_n * s_plus_m(&cp) * u - c_b_n * s_plus_m(&cm) * u) * dt / (2.0 * h);
        for r in 0..3 {
            assert!(
                (fd[r] - g[(r, j)]).abs() < 1e-9,
                "Γ[{r}, {j}]: {} vs finite difference {}",
                g[(r, j)],
                fd[r]
            );
        }
        // The plain J: one non-zero per column, the row of `(S + M) u` it moves.
        let (row, v) = jacobian_entry(&u, j);
        let d = (s_plus_m(&cp) * u - s_plus_m(&cm) * u) / (2.0 * h);
        assert!((d[row] - v).abs() < 1e-9);
        assert!(d.norm() - d[row].abs() < 1e-9);
    }
}

/// A joint covariance `[[P, P_xc], [P_cx, P_cc]]` PSD by construction: `c = D z`,
/// `x = B z + L w`.
fn joint(seed: &mut u64, pcc: (f64, f64)) -> SMatrix<f64, N, N> {
    let d = SVector::<f64, CONSIDER>::from_fn(|j, _| if j < 3 { pcc.0 } else { pcc.1 }.sqrt());
    let scale = SVector::<f64, STATES>::from_fn(|i, _| match i {
        0..=1 => 1e-6,
        2 => 30.0,
        3..=5 => 0.5,
        6..=8 => 1e-3,
        9..=11 => 1e-3,
        12..=14 => 1e-6,
        _ => 1e-3,
    });
    let b = SMatrix::<f64, STATES, CONSIDER>::from_fn(|i, _| scale[i] * rnd(seed) * 0.5);
    let l = SMatrix::<f64, STATES, STATES>::from_fn(|i, _| scale[i] * rnd(seed));
    let mut pa = SMatrix::<f64, N, N>::zeros();
    let pxx = b * b.transpose() + l * l.transpose();
    let pxc = b * SMatrix::<f64, CONSIDER, CONSIDER>::from_diagonal(&d);
    pa.fixed_view_mut::<STATES, STATES>(0, 0).copy_from(&pxx);
    pa.fixed_view_mut::<STATES, CONSIDER>(0, STATES)
        .copy_from(&pxc);
    pa.fixed_view_mut::<CONSIDER, STATES>(STATES, 0)
        .copy_from(&pxc.transpose());
    for j in 0..CONSIDER {
        pa[(STATES + j, STATES + j)] = d[j] * d[j];
    }
    pa
}

/// A covariance step's kinematics: velocity, attitude and NED specific force.
struct Kin {
    v: Vector3<f64>,
    c_b_n: Matrix3<f64>,
    f_ned: Vector3<f64>,
}

const POS: Position = Position {
    lat_rad: 0.65,
    lon_rad: 2.2,
    alt_m: 1500.0,
};

fn kin(seed: &mut u64) -> Kin {
    let c_b_n =
        *Rotation3::from_euler_angles(0.5 * rnd(seed), 0.2 * rnd(seed), 3.0 * rnd(seed)).matrix();
    Kin {
        v: Vector3::new(150.0, 120.0, -5.0),
        c_b_n,
        f_ned: Vector3::new(3.0 * rnd(seed), 8.0 * rnd(seed), -9.8 - 5.0 * rnd(seed)),
    }
}

fn f_of<T: Real>(k: &Kin) -> crate::seeker_ins::SparseF<T> {
    let c = |x: f64| T::lit(x);
    crate::seeker_ins::SparseF::new(&POS, &k.v.map(c), &k.c_b_n.map(c), &k.f_ned.map(c))
}

/// Max |a − b| relative to the largest |b| of each entry's row and column scale.
fn rel_diff<const R: usize, const C: usize>(
    a: &SMatrix<f64, R, C>,
    b: &SMatrix<f64, R, C>,
    rs: &SVector<f64, R>,
    cs: &SVector<f64, C>,
) -> f64 {
    let mut worst = 0.0_f64;
    for i in 0..R {
        for j in 0..C {
            worst = worst.max((a[(i, j)] - b[(i, j)]).abs() / (rs[i] * cs[j]));
        }
    }
    worst
}

/// The Schmidt step and update of `pa` (the blocks the filter keeps) in float type `T`.
fn schmidt<T: Real>(
    pa: &SMatrix<f64, N, N>,
    k: &Kin,
    u: &Vector3<f64>,
    h: &SVector<f64, STATES>,
    r: f64,
) -> (SMatrix<f64, STATES, STATES>, SMatrix<f64, STATES, CONSIDER>) {
    let cast = |x: f64| T::lit(x);
    let mut p: SMatrix<T, STATES, STATES> = pa.fixed_view::<STATES, STATES>(0, 0).map(cast);
    let mut cons = ConsiderCross::<T> {
        p_xc: pa.fixed_view::<STATES, CONSIDER>(0, STATES).map(cast),
        p_ec: SVector::zeros(),
        active: true,
    };
    let ft = f_of::<T>(k);
    let dt = T::lit(0.1);
    propagate_covariance_sparse(&mut p, &ft, dt, T::lit(1e-8), T::lit(1e-12)).unwrap();
    cons.step(&mut p, &errors::<T>(), &ft, &u.map(cast), dt, false);
    let ht: SVector<T, STATES> = h.map(cast);
    let ph = p * ht;
    let s = ht.dot(&ph) + T::lit(r);
    let kg = ph / s;
    cons.after_scalar(&ht, T::zero(), &kg, T::zero());
    p -= kg * ph.transpose();
    (p.map(|x| x.to_f64()), cons.p_xc.map(|x| x.to_f64()))
}

fn check_against_dense<T: Real>(tol: f64) {
    let mut seed = 7;
    let e = errors::<f64>();
    for case in 0..20 {
        let pa = joint(&mut seed, p_cc(&e));
        let kn = kin(&mut seed);
        let f = f_of::<f64>(&kn);
        let f_ref = Vector3::new(0.2, -0.1, -9.8);
        let u = kn.c_b_n.transpose() * kn.f_ned - f_ref;
        let h = SVector::<f64, STATES>::from_fn(|i, _| match i {
            0..=2 | 6..=8 | 15..=16 => rnd(&mut seed),
            _ => 0.0,
        });
        // Dense reference: Φ_a = [[Φ, Γ_a], [0, I]] (Φ from its columns), Q_a = diag(Q, 0).
        let dt = 0.1;
        let phi = SMatrix::<f64, STATES, STATES>::from_fn(|i, j| {
            transition_times(
                &f,
                dt,
                &SVector::<f64, STATES>::from_fn(|k, _| f64::from(k == j)),
            )[i]
        });
        let mut pk = pa.fixed_view::<STATES, STATES>(0, 0).into_owned();
        propagate_covariance_sparse(&mut pk, &f, dt, 1e-8, 1e-12).unwrap();
        let pxx = pa.fixed_view::<STATES, STATES>(0, 0).into_owned();
        let q = pk - phi * pxx * phi.transpose();
        let g = gamma(&kn.c_b_n, &u, dt);
        let mut phia = SMatrix::<f64, N, N>::identity();
        phia.fixed_view_mut::<STATES, STATES>(0, 0).copy_from(&phi);
        phia.fixed_view_mut::<3, CONSIDER>(VEL, STATES)
            .copy_from(&g);
        let mut qa = SMatrix::<f64, N, N>::zeros();
        qa.fixed_view_mut::<STATES, STATES>(0, 0).copy_from(&q);
        let mut pn = phia * pa * phia.transpose() + qa;
        let mut ha = SVector::<f64, N>::zeros();
        ha.fixed_rows_mut::<STATES>(0).copy_from(&h);
        let pha = pn * ha;
        // Noise of the size of the prior's `hᵀ P h` (information ratio 1: no cancellation
        // beyond the working precision's; the filter's conditioning keeps it bounded too).
        let r = ha.dot(&pha);
        pn -= pha * pha.transpose() / (ha.dot(&pha) + r);
        let (p, pxc) = schmidt::<T>(&pa, &kn, &u, &h, r);
        let sd = pn.diagonal().map(f64::sqrt);
        let sx = sd.fixed_rows::<STATES>(0).into_owned();
        let sc = sd.fixed_rows::<CONSIDER>(STATES).into_owned();
        let dxx = rel_diff(
            &p,
            &pn.fixed_view::<STATES, STATES>(0, 0).into_owned(),
            &sx,
            &sx,
        );
        let dxc = rel_diff(
            &pxc,
            &pn.fixed_view::<STATES, CONSIDER>(0, STATES).into_owned(),
            &sx,
            &sc,
        );
        assert!(
            dxx < tol && dxc < tol,
            "case {case}: P {dxx:e}, P_xc {dxc:e}"
        );
    }
}

#[test]
fn schmidt_blocks_match_the_dense_26_state_covariance_f64() {
    check_against_dense::<f64>(1e-9);
}

#[test]
fn schmidt_blocks_match_the_dense_26_state_covariance_f32() {
    check_against_dense::<f32>(2e-3);
}

#[test]
fn start_is_the_reference_share_and_zero_sigma_stays_inactive() {
    let e = errors::<f64>();
    let f_ref = Vector3::new(0.5, -0.3, -9.8);
    let mut c = ConsiderCross::<f64>::default();
    c.start(&e, &f_ref);
    assert!(c.active);
    // E[∇ cᵀ] J-weighted: `Σ_j P_xc[∇_i, j] u_j-component = v_i(f_ref)` (the variance added).
    let (s2, m2) = p_cc(&e);
    for i in 0..3 {
        let v: f64 = (0..CONSIDER)
            .map(|j| {
                let (r, x) = jacobian_entry(&f_ref, j);
                if r == i {
                    c.p_xc[(ACC_BIAS + i, j)] * x
                } else {
                    0.0
                }
            })
            .sum();
        let want = s2 * f_ref[i] * f_ref[i] + m2 * (f_ref.norm_squared() - f_ref[i] * f_ref[i]);
        assert!((v - want).abs() < 1e-15 * want.max(1e-30) + 1e-30);
    }
    assert!(c.p_xc.fixed_rows::<9>(0).iter().all(|x| *x == 0.0));
    let mut z = ConsiderCross::<f64>::default();
    z.start(&InstrumentErrors::default(), &f_ref);
    assert!(!z.active);
}

/// The flight configuration at 1 km heading east at 200 m/s, the landmark ≈ 60 km east
/// (`north_rad` north of the start).
fn flight_filter<T: Real>(
    north_rad: f64,
) -> (
    crate::seeker_ins::SeekerInsConfig<T>,
    crate::seeker_ins::SeekerIns<T>,
) {
    use crate::contract::Estimator;
    use crate::seeker_ins::{InsState, Landmark, SeekerIns, SeekerInsConfig, SeekerInsInitial};
    let start = Position {
        lat_rad: 0.6458,
        lon_rad: 2.2166,
        alt_m: 1000.0,
    };
    let target = Position {
        lat_rad: 0.6458 + north_rad,
        lon_rad: 2.2166 + 0.012,
        alt_m: 0.0,
    };
    let cfg = SeekerInsConfig::<T>::flight(Landmark::new(target).unwrap());
    let q = nalgebra::UnitQuaternion::from_euler_angles(0.0, 0.0, core::f64::consts::FRAC_PI_2);
    let initial = SeekerInsInitial {
        state: InsState {
            position: start,
            vel_ned_m_s: Vector3::new(T::zero(), T::lit(200.0), T::zero()),
            q_b_n: nalgebra::Quaternion::from(q.into_inner().coords.map(T::lit)),
        },
        covariance: crate::seeker_ins::paper_initial_covariance(),
    };
    let ins = SeekerIns::new(&cfg, &initial).unwrap();
    (cfg, ins)
}

/// IMU sample `k` of a weave of yaw rate `±0.2 rad/s` over `period_s` with the lateral force
/// that goes with it at 200 m/s (and `ax` m/s² along the body x axis).
fn weave_sample<T: Real>(k: u64, period_s: f64, ax: f64) -> crate::seeker_ins::ImuIncrement<T> {
    use crate::seeker_ins::PAPER_IMU_DT_US;
    let dt = PAPER_IMU_DT_US as f64 * 1e-6;
    let w = 0.2 * (2.0 * core::f64::consts::PI * k as f64 * dt / period_s).sin();
    crate::seeker_ins::ImuIncrement {
        time: crate::time::Timestamp::from_micros(k * PAPER_IMU_DT_US),
        delta_theta_rad: Vector3::new(0.0, 0.0, w * dt).map(T::lit),
        delta_v_m_s: Vector3::new(ax * dt, 200.0 * w * dt, -9.8 * dt).map(T::lit),
    }
}

/// The noise-free LOS sample of the filter's own state at `time`.
fn own_los<T: Real>(
    ins: &crate::seeker_ins::SeekerIns<T>,
    time: crate::time::Timestamp,
) -> crate::seeker_ins::LosSample<T> {
    use crate::seeker_ins::{gimbal_angles_of, landmark_vector_ned};
    let d = landmark_vector_ned(&ins.state().position, &ins.config().landmark);
    let gimbal = gimbal_angles_of(&(ins.ins().c_b_n().transpose() * d.normalize()));
    crate::seeker_ins::LosSample { time, gimbal }
}

/// Smallest eigenvalue of the correlation matrix of the joint `[[P, P_xc], [P_cx, P_cc]]`.
fn joint_min_corr_eig<T: Real>(ins: &crate::seeker_ins::SeekerIns<T>) -> f64 {
    let p = ins.covariance().map(|x| x.to_f64());
    let pxc = ins.consider_cross().map(|x| x.to_f64());
    let (s2, m2) = p_cc(&ins.config().instrument_errors);
    let mut pa = SMatrix::<f64, N, N>::zeros();
    pa.fixed_view_mut::<STATES, STATES>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<STATES, CONSIDER>(0, STATES)
        .copy_from(&pxc);
    pa.fixed_view_mut::<CONSIDER, STATES>(STATES, 0)
        .copy_from(&pxc.transpose());
    for j in 0..CONSIDER {
        pa[(STATES + j, STATES + j)] = if j < 3 { s2.to_f64() } else { m2.to_f64() };
    }
    let d = pa
        .diagonal()
        .map(|v| if v > 0.0 { 1.0 / v.sqrt() } else { 0.0 });
    SMatrix::<f64, N, N>::from_fn(|i, j| pa[(i, j)] * d[i] * d[j])
        .symmetric_eigen()
        .eigenvalues
        .min()
}

/// The flight configuration over 60 s of weave (yaw rate ±0.2 rad/s, the lateral force with
/// it) with a LOS update every 0.1 s: the joint covariance with the consider parameters stays
/// PSD (its smallest correlation eigenvalue above −1e-6 in f64, −1e-3 in f32), `P_xc` finite,
/// and its velocity rows grow away from zero (the departures' errors).
fn weave<T: Real>(tol: f64) {
    use crate::contract::Estimator;
    let (_, mut ins) = flight_filter::<T>(0.0);
    let mut worst = f64::INFINITY;
    for k in 1..=6000_u64 {
        let imu = weave_sample::<T>(k, 40.0, 0.0);
        ins.propagate(&imu).unwrap();
        if k % 10 == 0 {
            let _ = ins.update_los(&own_los(&ins, imu.time));
            if k % 500 == 0 {
                worst = worst.min(joint_min_corr_eig(&ins));
            }
        }
    }
    assert!(ins.aid_counters(crate::seeker_ins::SeekerAid::Los).fused > 1000);
    let pxc = ins.consider_cross();
    assert!(pxc.iter().all(|x| x.is_finite()));
    assert!(pxc
        .fixed_rows::<3>(VEL)
        .iter()
        .any(|x| x.to_f64().abs() > 0.0));
    assert!(
        worst > -tol,
        "smallest joint correlation eigenvalue {worst}"
    );
    assert!(ins.health().state != crate::HealthState::NeedsReinitialisation);
}

#[test]
fn joint_covariance_stays_psd_over_a_weave_f64() {
    weave::<f64>(1e-6);
}

#[test]
fn joint_covariance_stays_psd_over_a_weave_f32() {
    weave::<f32>(1e-3);
}

/// The filter's LOS update corrects `P_xc` as the dense 26-state sequential update of its two
/// components (`h_a = [h, 0]`) does, against P and `P_xc` as they were before it.
#[test]
fn los_update_corrects_p_xc_as_the_dense_26_state_update() {
    use crate::seeker_ins::los_model_at;
    let (cfg, mut ins) = flight_filter::<f64>(0.003);
    let mut checked = 0;
    for k in 1..=3000_u64 {
        let imu = weave_sample::<f64>(k, 20.0, 0.1);
        ins.propagate(&imu).unwrap();
        if k % 10 != 0 {
            continue;
        }
        let sample = own_los(&ins, imu.time);
        let (s, c_b_n) = (*ins.state(), ins.ins().c_b_n());
        let (p0, x0, gb) = (
            *ins.covariance(),
            *ins.consider_cross(),
            ins.gimbal_bias_rad(),
        );
        let r = ins.update_los(&sample);
        if k % 500 != 0 || r.is_err() {
            continue;
        }
        // The dense sequential update of the joint (pitch, then yaw).
        let d = crate::seeker_ins::landmark_vector_ned(&s.position, &cfg.landmark);
        let corrected = crate::seeker_ins::GimbalAngles {
            pitch_rad: sample.gimbal.pitch_rad - gb.x,
            yaw_rad: sample.gimbal.yaw_rad - gb.y,
        };
        let m = los_model_at(&s.position, &d, &c_b_n, &corrected, cfg.seeker_noise_rad).unwrap();
        let (s2, m2) = p_cc(&cfg.instrument_errors);
        let mut pa = SMatrix::<f64, N, N>::zeros();
        pa.fixed_view_mut::<STATES, STATES>(0, 0).copy_from(&p0);
        pa.fixed_view_mut::<STATES, CONSIDER>(0, STATES)
            .copy_from(&x0);
        pa.fixed_view_mut::<CONSIDER, STATES>(STATES, 0)
            .copy_from(&x0.transpose());
        for j in 0..CONSIDER {
            pa[(STATES + j, STATES + j)] = if j < 3 { s2 } else { m2 };
        }
        for (h, r) in [(m.h_pitch, m.variance_rad2.x), (m.h_yaw, m.variance_rad2.y)] {
            let mut ha = SVector::<f64, N>::zeros();
            ha.fixed_rows_mut::<STATES>(0).copy_from(&h);
            let pha = pa * ha;
            pa -= pha * pha.transpose() / (ha.dot(&pha) + r);
        }
        let want = pa.fixed_view::<STATES, CONSIDER>(0, STATES).into_owned();
        let scale = want.abs().max();
        let err = (ins.consider_cross() - want).abs().max();
        assert!(err < 1e-6 * scale, "k {k}: |ΔP_xc| {err:e} of {scale:e}");
        // And P_xc moved: the update is not the identity on it.
        assert!((x0 - want).abs().max() > 1e-3 * scale);
        checked += 1;
    }
    assert_eq!(checked, 6);
}

#[test]
fn los_pair_is_the_two_sequential_scalar_corrections() {
    // Random P_xc, P_ec, external column c, LOS rows non-zero at LOS_COLS only, gains; the
    // second component's gain zero in one case (not fused).
    for (case, fused2) in [(0u64, true), (1, false)] {
        let mut seed = 77 + case;
        let p_xc = SMatrix::from_fn(|_, _| rnd(&mut seed));
        let p_ec = SVector::from_fn(|_, _| rnd(&mut seed));
        let cc = ConsiderCross::<f64> {
            p_xc,
            p_ec,
            active: true,
        };
        let col = SVector::<f64, STATES>::from_fn(|_, _| rnd(&mut seed));
        let mut rows = [SVector::<f64, STATES>::zeros(); 2];
        for row in rows.iter_mut() {
            for i in LOS_COLS {
                row[i] = rnd(&mut seed);
            }
        }
        let k1 = SVector::<f64, STATES>::from_fn(|_, _| rnd(&mut seed));
        let k2 = if fused2 {
            SVector::<f64, STATES>::from_fn(|_, _| rnd(&mut seed))
        } else {
            SVector::zeros()
        };
        let s = [1.7, 0.6];
        // Sequential: the column corrected after each component, its gain g / s.
        let mut seq = cc;
        let mut c = col;
        for (n, (h, k)) in rows.iter().zip([&k1, &k2]).enumerate() {
            if n == 1 && !fused2 {
                continue;
            }
            let g = h.dot(&c);
            c -= k * g;
            seq.after_scalar(h, 0.0, k, g / s[n]);
        }
        let h = rows.map(|r| LOS_COLS.map(|i| r[i]));
        let inv_s = [1.0 / s[0], if fused2 { 1.0 / s[1] } else { 0.0 }];
        let mut pair = cc;
        pair.after_los_pair(&h, [&k1.data.0[0], &k2.data.0[0]], Some((&col, inv_s)));
        let d_xc = (pair.p_xc - seq.p_xc).abs().max();
        let d_ec = (pair.p_ec - seq.p_ec).abs().max();
        assert!(
            d_xc < 1e-12 && d_ec < 1e-12,
            "case {case}: {d_xc:e}, {d_ec:e}"
        );
        // And it did change them (a test that can fail).
        assert!((pair.p_xc - cc.p_xc).abs().max() > 1e-3);
        assert!((pair.p_ec - cc.p_ec).abs().max() > 1e-3);
    }
}

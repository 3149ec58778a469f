//! Unit tests of the 17-state error model: sparse and generated propagation against dense,
//! exact symmetry, f32 against f64, F against finite differences of the INS equations.
use super::*;
use crate::math::kalman::{asymmetry, propagate_dense};
use nalgebra::SVector;

#[test]
fn sparse_propagation_equals_dense() {
    let pos = Position {
        lat_rad: 0.65,
        lon_rad: 2.2,
        alt_m: 1000.0,
    };
    let v = Vector3::new(30.0, 200.0, -3.0);
    let c = crate::math::rotation::euler_to_dcm(0.3, 0.05, 1.4);
    let f_n = Vector3::new(0.5, 2.0, -9.8);
    let fb = f_block(&pos, &v, &c, &f_n);
    let dt = 0.1;
    let a = transition_block(&fb, dt);
    // A random-ish SPD P.
    let mut l = SMatrix::<f64, 17, 17>::zeros();
    for i in 0..17 {
        for j in 0..=i {
            l[(i, j)] = ((i * 7 + j * 3) % 11) as f64 * 0.1 + if i == j { 1.0 } else { 0.0 };
        }
    }
    let p0 = l * l.transpose();
    let mut phi = SMatrix::<f64, 17, 17>::identity();
    let blk = phi.fixed_view::<9, 15>(0, 0) + a;
    phi.fixed_view_mut::<9, 15>(0, 0).copy_from(&blk);
    let (qa, qg) = (1e-3, 1e-5);
    let mut qc = SMatrix::<f64, 17, 17>::zeros();
    for i in 3..9 {
        qc[(i, i)] = if i < 6 { qa } else { qg };
    }
    let qd = qc * dt
        + (phi - SMatrix::identity()) * qc * (0.5 * dt)
        + qc * (phi - SMatrix::identity()).transpose() * (0.5 * dt);
    let mut dense = p0;
    propagate_dense(&mut dense, &phi, &qd);
    let mut sparse = p0;
    propagate_covariance(&mut sparse, &a, dt, qa, qg).unwrap();
    assert!((dense - sparse).abs().max() < 1e-9 * dense.abs().max());
    assert_eq!(asymmetry(&sparse), 0.0);
    // Bad dt leaves P untouched.
    let before = sparse;
    assert!(propagate_covariance(&mut sparse, &a, -1.0, qa, qg).is_err());
    assert_eq!(sparse, before);
}

/// The sparse propagation (second-order term restricted to the fast couplings) against the
/// dense `Φ = I + FΔt + ½(FΔt)²`, on a covariance of physical size: every element within
/// 1e-5 of √(P_ii P_jj).
#[test]
fn sparse_propagation_matches_dense_second_order() {
    let pos = Position {
        lat_rad: 0.65,
        lon_rad: 2.2,
        alt_m: 1000.0,
    };
    let v = Vector3::new(30.0, 200.0, -3.0);
    let c = crate::math::rotation::euler_to_dcm(0.3, 0.05, 1.4);
    let f_n = Vector3::new(0.5, 2.0, -9.8);
    let sf = SparseF::new(&pos, &v, &c, &f_n);
    let fb = sf.to_block();
    let p0 = physical_p();
    let (qa, qg) = (2.4e-9, 8.5e-13);
    for dt in [0.01, 0.1, 1.0] {
        let a = transition_block(&fb, dt);
        let mut dense = p0;
        propagate_covariance(&mut dense, &a, dt, qa, qg).unwrap();
        let mut sparse = p0;
        propagate_covariance_sparse(&mut sparse, &sf, dt, qa, qg).unwrap();
        assert_eq!(asymmetry(&sparse), 0.0);
        for i in 0..17 {
            for j in 0..17 {
                let scale = (dense[(i, i)] * dense[(j, j)]).sqrt();
                let tol = if dt <= 0.1 { 1e-5 } else { 1e-3 };
                assert!(
                    (dense[(i, j)] - sparse[(i, j)]).abs() <= tol * scale,
                    "dt {dt} P[{i},{j}] dense {:e} sparse {:e}",
                    dense[(i, j)],
                    sparse[(i, j)]
                );
            }
        }
    }
    // Bad input leaves P untouched.
    let mut p = p0;
    assert!(propagate_covariance_sparse(&mut p, &sf, f64::NAN, qa, qg).is_err());
    assert!(propagate_covariance_sparse(&mut p, &sf.scaled(f64::INFINITY), 0.1, qa, qg).is_err());
    assert_eq!(p, p0);
}

/// A covariance of physical size (σ per state, correlations from a fixed Cholesky factor).
fn physical_p() -> SMatrix<f64, 17, 17> {
    let sig = [
        6e-6, 6e-6, 40.0, 10.0, 10.0, 10.0, 0.017, 0.017, 0.087, 1e-3, 1e-3, 1e-3, 5e-8, 5e-8,
        5e-8, 7e-4, 7e-4,
    ];
    let mut l = SMatrix::<f64, 17, 17>::zeros();
    for i in 0..17 {
        for j in 0..=i {
            l[(i, j)] = ((i * 7 + j * 3) % 11) as f64 * 0.05 + if i == j { 1.0 } else { 0.0 };
        }
    }
    let corr = l * l.transpose();
    let mut p0 = SMatrix::<f64, 17, 17>::zeros();
    for i in 0..17 {
        for j in 0..17 {
            p0[(i, j)] = corr[(i, j)] / (corr[(i, i)] * corr[(j, j)]).sqrt() * sig[i] * sig[j];
        }
    }
    (p0 + p0.transpose()) * 0.5
}

fn test_f<T: Real>() -> SparseF<T> {
    let pos = Position {
        lat_rad: 0.65,
        lon_rad: 2.2,
        alt_m: 1000.0,
    };
    let v = Vector3::new(T::lit(30.0), T::lit(200.0), T::lit(-3.0));
    let c = crate::math::rotation::euler_to_dcm(T::lit(0.3), T::lit(0.05), T::lit(1.4));
    let f_n = Vector3::new(T::lit(0.5), T::lit(2.0), T::lit(-9.8));
    SparseF::new(&pos, &v, &c, &f_n)
}

/// The generated step writes both triangles of rows and columns 0..9 with the same bits
/// (P stays exactly symmetric) and leaves the bias and gimbal block untouched; a non-finite
/// result leaves P unchanged.
#[test]
fn generated_step_is_exactly_symmetric_and_touches_the_navigation_rows_only() {
    let p0 = physical_p();
    let sf = test_f::<f64>();
    let (qa, qg) = (2.4e-9, 8.5e-13);
    let mut p = p0;
    propagate_covariance_sparse(&mut p, &sf, 0.1, qa, qg).unwrap();
    assert_eq!(asymmetry(&p), 0.0);
    for j in 9..17 {
        for i in 9..17 {
            assert_eq!(p[(i, j)].to_bits(), p0[(i, j)].to_bits(), "P[{i},{j}]");
        }
    }
    assert!(p != p0);
    let mut huge = p0;
    huge[(12, 12)] = f64::INFINITY;
    let before = huge;
    assert!(propagate_covariance_sparse(&mut huge, &sf, 0.1, qa, qg).is_err());
    assert_eq!(huge, before);
}

/// The generated step reads whole columns of P (its precondition: P exactly symmetric):
/// a lower triangle of NaN is seen (the step refuses, P unchanged), the symmetric P gives
/// exactly symmetric rows.
#[test]
fn generated_step_reads_whole_columns_of_the_symmetric_p() {
    let p0 = physical_p();
    let sf = test_f::<f64>();
    let (qa, qg) = (2.4e-9, 8.5e-13);
    let mut clean = p0;
    propagate_covariance_sparse(&mut clean, &sf, 0.1, qa, qg).unwrap();
    let mut poisoned = p0;
    for j in 0..17 {
        for i in (j + 1)..17 {
            poisoned[(i, j)] = f64::NAN;
        }
    }
    let before = poisoned;
    assert!(propagate_covariance_sparse(&mut poisoned, &sf, 0.1, qa, qg).is_err());
    assert_eq!(
        poisoned.map(f64::to_bits),
        before.map(f64::to_bits),
        "P unchanged"
    );
    assert_eq!(asymmetry(&clean), 0.0);
}

/// Every single non-finite input the step reads refuses it and leaves P bit for bit as it
/// was: each symmetric pair of P in a row or column 0..15 (the rows G reads; rows 15 and 16
/// are read only as their own results) and each entry of F, as NaN, +∞ and −∞, in f64 and
/// f32. The kernel probes only the results no corner entry reads (a non-finite result that
/// a corner entry reads makes that entry non-finite): a probe left out where it is needed
/// lets one of these through.
#[test]
fn every_non_finite_input_refuses_the_step_and_leaves_p_unchanged() {
    fn check<T: Real + core::fmt::Debug>() {
        let p0 = physical_p().map(T::lit);
        let sf = test_f::<T>();
        let (qa, qg) = (T::lit(2.4e-9), T::lit(8.5e-13));
        let dt = T::lit(0.1);
        let bad = [
            T::lit(f64::NAN),
            T::lit(f64::INFINITY),
            T::lit(f64::NEG_INFINITY),
        ];
        let same = |a: &SMatrix<T, 17, 17>, b: &SMatrix<T, 17, 17>| {
            a.iter()
                .zip(b.iter())
                .all(|(x, y)| x.to_f64().to_bits() == y.to_f64().to_bits())
        };
        for j in 0..17 {
            for i in 0..=j.min(14) {
                for v in bad {
                    let mut p = p0;
                    p[(i, j)] = v;
                    p[(j, i)] = v;
                    let before = p;
                    assert!(
                        propagate_covariance_sparse(&mut p, &sf, dt, qa, qg).is_err(),
                        "P[{i},{j}] = {v:?} accepted"
                    );
                    assert!(same(&p, &before), "P[{i},{j}] = {v:?}: P changed");
                }
            }
        }
        let fields = sparse_f_entries(&mut sf.clone()).len();
        assert_eq!(fields, 46);
        // The entries the prediction leaves out (`NEGLIGIBLE` of xtask/src/gen.rs: f00, f02,
        // f12, vel_h.x, vel_h.y, att_lat.y, att_h) are zero in every F and not read.
        let left_out = [0, 1, 4, 10, 11, 17, 19, 20, 21];
        let mut probe = sf;
        for (k, e) in sparse_f_entries(&mut probe).into_iter().enumerate() {
            assert!(!left_out.contains(&k) || *e == T::zero(), "entry {k}");
        }
        for k in (0..fields).filter(|k| !left_out.contains(k)) {
            for v in bad {
                let mut f = sf;
                if let Some(entry) = sparse_f_entries(&mut f).into_iter().nth(k) {
                    *entry = v;
                }
                let mut p = p0;
                assert!(
                    propagate_covariance_sparse(&mut p, &f, dt, qa, qg).is_err(),
                    "F entry {k} = {v:?} accepted"
                );
                assert!(same(&p, &p0), "F entry {k} = {v:?}: P changed");
            }
        }
    }
    check::<f64>();
    check::<f32>();
}

/// The 46 scalars of `f` (every field; `f25` is the constant −1 of δḣ = −δV_D).
fn sparse_f_entries<T: Real>(f: &mut SparseF<T>) -> std::vec::Vec<&mut T> {
    let mut v: std::vec::Vec<&mut T> = std::vec![
        &mut f.f00, &mut f.f02, &mut f.f03, &mut f.f10, &mut f.f12, &mut f.f14, &mut f.f25,
    ];
    for vec3 in [
        &mut f.vel_lat,
        &mut f.vel_h,
        &mut f.f_ned,
        &mut f.att_lat,
        &mut f.att_h,
        &mut f.att_v,
        &mut f.w_in,
    ] {
        v.extend(vec3.iter_mut());
    }
    v.extend(f.vel_vel.iter_mut());
    v.extend(f.c_b_n.iter_mut());
    v
}

/// Error bound of the f32 step against the same step in f64, on a covariance of physical
/// size, over 100 steps of 0.1 s: every element within 5e-6 of √(P_ii P_jj) (measured 2.2e-6;
/// f32 ε is 1.2e-7, sums of up to 14 terms per step, 100 steps).
#[test]
fn f32_step_stays_within_its_bound_of_f64() {
    let p64_0 = physical_p();
    let (sf32, sf64) = (test_f::<f32>(), test_f::<f64>());
    let (qa, qg) = (2.4e-9, 8.5e-13);
    let mut p64 = p64_0;
    let mut p32 = p64_0.map(|v| v as f32);
    let mut worst = 0.0f64;
    for _ in 0..100 {
        propagate_covariance_sparse(&mut p64, &sf64, 0.1, qa, qg).unwrap();
        propagate_covariance_sparse(&mut p32, &sf32, 0.1, qa as f32, qg as f32).unwrap();
        for i in 0..17 {
            for j in 0..17 {
                let scale = (p64[(i, i)] * p64[(j, j)]).sqrt();
                let err = (f64::from(p32[(i, j)]) - p64[(i, j)]).abs() / scale;
                worst = worst.max(err);
            }
        }
    }
    assert!(worst < 5e-6, "worst relative error {worst:e}");
}

/// F against central finite differences of the nonlinear INS equations: each error
/// component is applied to the truth (p̂ = p + δp, V̂ = V + δV, Ĉ = exp(−[φ×]) C,
/// f̂ = f + ∇, ω̂ = ω + ε) and the error derivative is read off the two derivatives.
#[test]
fn f_matches_finite_differences_of_the_ins_equations() {
    use crate::math::rotation::{exp_so3, unskew};
    use crate::seeker_ins::mechanization::continuous_derivative;
    let pos = Position {
        lat_rad: 0.65,
        lon_rad: 2.2,
        alt_m: 1500.0,
    };
    let v = Vector3::new(40.0, 210.0, -5.0);
    let c = crate::math::rotation::euler_to_dcm(0.4, 0.1, 1.3);
    let f_b = Vector3::new(1.5, -2.0, -9.5);
    let w_b = Vector3::new(0.02, -0.01, 0.04);
    let err_dot = |dx: &SVector<f64, 17>| -> SVector<f64, 17> {
        let p_hat = Position {
            lat_rad: pos.lat_rad + dx[0],
            lon_rad: pos.lon_rad + dx[1],
            alt_m: pos.alt_m + dx[2],
        };
        let v_hat = v + dx.fixed_rows::<3>(3);
        let e = exp_so3(&(-dx.fixed_rows::<3>(6).into_owned()));
        let c_hat = e * c;
        let f_hat = f_b + dx.fixed_rows::<3>(9);
        let w_hat = w_b + dx.fixed_rows::<3>(12);
        let d0 = continuous_derivative(&pos, &v, &c, &f_b, &w_b);
        let d1 = continuous_derivative(&p_hat, &v_hat, &c_hat, &f_hat, &w_hat);
        let e_dot = d1.c_b_n_rate_per_s * c.transpose() + c_hat * d0.c_b_n_rate_per_s.transpose();
        let phi_dot = -unskew(&e_dot);
        let mut out = SVector::<f64, 17>::zeros();
        out[0] = d1.lat_rate_rad_s - d0.lat_rate_rad_s;
        out[1] = d1.lon_rate_rad_s - d0.lon_rate_rad_s;
        out[2] = d1.alt_rate_m_s - d0.alt_rate_m_s;
        out.fixed_rows_mut::<3>(3)
            .copy_from(&(d1.vel_ned_rate_m_s2 - d0.vel_ned_rate_m_s2));
        out.fixed_rows_mut::<3>(6).copy_from(&phi_dot);
        out
    };
    let f = full_f(&f_block(&pos, &v, &c, &(c * f_b)));
    let steps = [
        1e-7, 1e-7, 1.0, 0.01, 0.01, 0.01, 1e-5, 1e-5, 1e-5, 1e-3, 1e-3, 1e-3, 1e-6, 1e-6, 1e-6,
        1e-4, 1e-4,
    ];
    // Left out of the model (`NEGLIGIBLE` of xtask/src/gen.rs): F holds zero and the
    // derivative is within the bound over the envelope given there.
    let left_out = [
        ((0, 0), 9.5e-7),
        ((0, 2), 1.5e-11),
        ((1, 2), 8.4e-11),
        ((3, 2), 5.1e-8),
        ((4, 2), 5.1e-8),
        ((6, 2), 1.5e-11),
        ((7, 0), 9.5e-7),
        ((7, 2), 1.5e-11),
        ((8, 2), 8.3e-11),
    ];
    for (j, &h) in steps.iter().enumerate() {
        let mut dx = SVector::<f64, 17>::zeros();
        dx[j] = h;
        let col = (err_dot(&dx) - err_dot(&(-dx))) / (2.0 * h);
        let scale: f64 = f.column(j).abs().max().max(1e-12);
        for i in 0..17 {
            if let Some((_, bound)) = left_out.iter().find(|(ij, _)| *ij == (i, j)) {
                assert_eq!(f[(i, j)], 0.0, "F[{i},{j}] is left out");
                assert!(col[i].abs() <= *bound, "F[{i},{j}]: {:e}", col[i]);
                continue;
            }
            let diff = (col[i] - f[(i, j)]).abs();
            assert!(
                diff <= 1e-5 * scale,
                "F[{i},{j}] = {:e}, finite difference {:e}",
                f[(i, j)],
                col[i]
            );
        }
    }
}

#[test]
fn transition_times_equals_the_dense_product_bit_for_bit() {
    fn dense<T: Real>(
        f: &SparseF<T>,
        dt: T,
        c: &nalgebra::SVector<T, STATES>,
    ) -> nalgebra::SVector<T, STATES> {
        let g = f.scaled(dt);
        let w: nalgebra::SVector<T, 9> = g.to_block() * c.fixed_rows::<15>(0);
        let half = T::lit(0.5);
        let w_vel: Vector3<T> = w.fixed_rows::<3>(3).into_owned();
        let w_att: Vector3<T> = w.fixed_rows::<3>(6).into_owned();
        let mut hw = nalgebra::SVector::<T, 9>::zeros();
        hw.fixed_rows_mut::<3>(0).copy_from(&Vector3::new(
            half * g.f03 * w_vel.x,
            half * g.f14 * w_vel.y,
            half * g.f25 * w_vel.z,
        ));
        hw.fixed_rows_mut::<3>(3)
            .copy_from(&(g.f_ned * half).cross(&w_att));
        let mut out = *c;
        let add = w + hw;
        out.fixed_rows_mut::<9>(0)
            .iter_mut()
            .zip(add.iter())
            .for_each(|(o, a)| *o += *a);
        out
    }
    fn check<T: Real + core::fmt::Debug>() {
        let pos = Position {
            lat_rad: 0.65,
            lon_rad: 2.2,
            alt_m: 1000.0,
        };
        let v = Vector3::new(T::lit(30.0), T::lit(200.0), T::lit(-3.0));
        let c = crate::math::rotation::euler_to_dcm(T::lit(0.3), T::lit(0.05), T::lit(1.4));
        let f_n = Vector3::new(T::lit(0.5), T::lit(2.0), T::lit(-9.8));
        let sf = SparseF::new(&pos, &v, &c, &f_n);
        for (k, dt) in [0.01, 0.02, 0.1].into_iter().enumerate() {
            let col = nalgebra::SVector::<T, STATES>::from_fn(|i, _| {
                T::lit(((i * 7 + k * 3) % 11) as f64 - 5.0) * T::lit(0.37_f64.powi(i as i32 % 5))
            });
            let a = transition_times(&sf, T::lit(dt), &col);
            let b = dense(&sf, T::lit(dt), &col);
            assert_eq!(a, b, "dt {dt}");
        }
    }
    check::<f32>();
    check::<f64>();
}

/// The INS along a fast, high-latitude climb (|V| ≈ 1 000 m/s, 80°, 20 km, turning), one
/// covariance step every 10 samples at 100 Hz: the F its covariance step uses (the radii
/// of the last sample's start, `Ins::step_keeping_radii`), the F at the state
/// (`SparseF::new`: radii at the current position) and the F with the radii of the
/// interval's middle (5 samples back). Largest relative differences of an entry of F
/// (shared − state, middle − state); of P after 30 steps from the same P, f64, in units of
/// √(P_ii P_jj) (shared − state); and of the `T` filter's P against the f64 P at the state
/// with the shared radii and with the radii at the state.
struct SharedRadii {
    f_shared: f64,
    f_middle: f64,
    p_shared: f64,
    t_shared: f64,
    t_state: f64,
}

/// The INS of [`shared_radii_against_state`] at its start.
fn fast_climb<T: Real>() -> crate::seeker_ins::mechanization::Ins<T> {
    use crate::seeker_ins::mechanization::{Ins, InsState};
    let state = InsState::<T> {
        position: Position {
            lat_rad: 1.39,
            lon_rad: 0.3,
            alt_m: 20_000.0,
        },
        vel_ned_m_s: Vector3::new(T::lit(700.0), T::lit(700.0), T::lit(-30.0)),
        q_b_n: nalgebra::Quaternion::new(T::one(), T::zero(), T::zero(), T::zero()),
    };
    Ins::new(state, T::lit(0.01)).unwrap()
}

/// Sample `k` (10 ms, turning and climbing) of [`fast_climb`]: the radii the step kept.
fn fast_climb_step<T: Real>(
    ins: &mut crate::seeker_ins::mechanization::Ins<T>,
    k: u64,
) -> crate::seeker_ins::mechanization::PositionKinematics<T> {
    let inc = crate::seeker_ins::mechanization::ImuIncrement {
        time: crate::time::Timestamp::from_micros(k * 10_000),
        delta_theta_rad: Vector3::new(0.3, -0.2, 0.5).map(|v| T::lit(v * 0.01)),
        delta_v_m_s: Vector3::new(5.0, 3.0, -9.8).map(|v| T::lit(v * 0.01)),
    };
    ins.step_keeping_radii(&inc).unwrap()
}

/// Largest relative difference of the entries of two F (over the non-zero entries of `a`).
fn rel_f(a: &SparseF<f64>, b: &SparseF<f64>) -> f64 {
    let (a, b) = (a.to_block(), b.to_block());
    a.iter()
        .zip(b.iter())
        .filter(|(x, _)| **x != 0.0)
        .fold(0.0f64, |w, (x, y)| w.max(((x - y) / x).abs()))
}

/// Largest |P − P_ref| in units of √(P_ref,ii P_ref,jj).
fn rel_p<T: Real>(p: &SMatrix<T, 17, 17>, p_ref: &SMatrix<f64, 17, 17>) -> f64 {
    let mut worst = 0.0f64;
    for i in 0..17 {
        for j in 0..17 {
            let scale = (p_ref[(i, i)] * p_ref[(j, j)]).sqrt();
            worst = worst.max((p[(i, j)].to_f64() - p_ref[(i, j)]).abs() / scale);
        }
    }
    worst
}

fn shared_radii_against_state<T: Real>() -> SharedRadii {
    use crate::seeker_ins::mechanization::Kinematics;
    let (mut ins, mut ins64) = (fast_climb::<T>(), fast_climb::<f64>());
    let (qa, qg) = (2.4e-9, 8.5e-13);
    let (ta, tg, tdt) = (T::lit(qa), T::lit(qg), T::lit(0.1));
    let (mut p_state, mut p_shared) = (physical_p(), physical_p());
    let mut p_t = physical_p().map(|v| T::lit(v));
    let mut p_t_state = p_t;
    let mut r = SharedRadii {
        f_shared: 0.0,
        f_middle: 0.0,
        p_shared: 0.0,
        t_shared: 0.0,
        t_state: 0.0,
    };
    let mut middle = ins64.state().position;
    for k in 1..=300u64 {
        let radii64 = fast_climb_step(&mut ins64, k);
        let radii = fast_climb_step(&mut ins, k);
        if k % 10 == 5 {
            middle = ins64.state().position;
        }
        if k % 10 != 0 {
            continue;
        }
        let (s, c, f) = (
            ins64.state(),
            ins64.c_b_n(),
            ins64.specific_force_ned_m_s2(),
        );
        let v = &s.vel_ned_m_s;
        let at_state = SparseF::new(&s.position, v, &c, &f);
        let shared = SparseF::at(&Kinematics::at(&radii64, v), v, &c, &f);
        let at_middle = SparseF::at(&Kinematics::new(&middle, v), v, &c, &f);
        r.f_shared = r.f_shared.max(rel_f(&at_state, &shared));
        r.f_middle = r.f_middle.max(rel_f(&at_state, &at_middle));
        propagate_covariance_sparse(&mut p_state, &at_state, 0.1, qa, qg).unwrap();
        propagate_covariance_sparse(&mut p_shared, &shared, 0.1, qa, qg).unwrap();
        let (st, c_t, f_t) = (ins.state(), ins.c_b_n(), ins.specific_force_ned_m_s2());
        let v_t = &st.vel_ned_m_s;
        let shared_t = SparseF::at(&Kinematics::at(&radii, v_t), v_t, &c_t, &f_t);
        let state_t = SparseF::new(&st.position, v_t, &c_t, &f_t);
        propagate_covariance_sparse(&mut p_t, &shared_t, tdt, ta, tg).unwrap();
        propagate_covariance_sparse(&mut p_t_state, &state_t, tdt, ta, tg).unwrap();
        r.p_shared = r.p_shared.max(rel_p(&p_shared, &p_state));
        r.t_shared = r.t_shared.max(rel_p(&p_t, &p_state));
        r.t_state = r.t_state.max(rel_p(&p_t_state, &p_state));
    }
    r
}

/// F from the radii the INS step kept (`Ins::step_keeping_radii`) against F at the state: its
/// entries move by a fifth or less of what evaluating F in the middle of the covariance
/// interval instead of at its end moves them (the one IMU interval's travel against five),
/// and P by less than f32 rounding of the step does.
#[test]
fn f_from_the_steps_radii_stays_within_its_bound_of_f_at_the_state() {
    let r64 = shared_radii_against_state::<f64>();
    let r32 = shared_radii_against_state::<f32>();
    std::println!(
        "F entries: shared {:e}, middle {:e}; P (f64): {:e} of sqrt(Pii Pjj); f32 against f64 \
         at the state: shared radii {:e}, radii at the state {:e}",
        r64.f_shared,
        r64.f_middle,
        r64.p_shared,
        r32.t_shared,
        r32.t_state
    );
    assert!(r64.f_shared > 0.0 && r64.f_shared <= 0.25 * r64.f_middle);
    assert!(r64.p_shared < 2e-5, "P differs by {:e}", r64.p_shared);
    assert!(r32.t_shared < 2e-5, "f32 P differs by {:e}", r32.t_shared);
}

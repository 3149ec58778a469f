//! Property tests of nav-core's shared math (f32 and f64): the Kalman update keeps P exactly
//! symmetric and positive semi-definite and never increases a variance; sequential scalar
//! updates equal the batch formula; discretisation matches closed forms; rotations round-trip.

use nalgebra::{SMatrix, SVector, Vector3};
use nav_core::math::discretize::discretize;
use nav_core::math::kalman::{asymmetry, fuse_scalar, is_psd, FusionOutcome, Gate};
use nav_core::math::rotation::{
    dcm_to_euler, dcm_to_quat, euler_to_dcm, exp_so3, log_so3, quat_to_dcm,
};
use nav_core::Real;
use proptest::prelude::*;

const N: usize = 6;

fn spd_from(a: &[f64], diag_floor: f64) -> SMatrix<f64, N, N> {
    let m = SMatrix::<f64, N, N>::from_iterator(a.iter().copied());
    m * m.transpose() + SMatrix::<f64, N, N>::identity() * diag_floor
}

fn check_update<T: Real>(p64: &SMatrix<f64, N, N>, h64: &[f64], r: f64, nu: f64, tol: f64) {
    let mut p: SMatrix<T, N, N> = p64.map(T::lit);
    let mut x = SVector::<T, N>::zeros();
    let h = SVector::<T, N>::from_iterator(h64.iter().map(|v| T::lit(*v)));
    let p0 = p;
    let rep = fuse_scalar(&mut x, &mut p, &h, T::lit(nu), T::lit(r), Gate::Off);
    let rep = rep.expect("a valid update must succeed");
    assert_eq!(rep.outcome, FusionOutcome::Fused);
    assert_eq!(asymmetry(&p), T::zero(), "P must stay exactly symmetric");
    assert!(is_psd(&p, T::lit(tol)), "P must stay PSD: {p}");
    for (a, b) in p.diagonal().iter().zip(p0.diagonal().iter()) {
        assert!(*a <= *b * T::lit(1.0 + tol), "a variance increased");
    }
    assert!(x.iter().all(|v| v.is_finite()));
    assert!(rep.nis >= T::zero() && rep.innovation_variance > T::zero());
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 256, .. ProptestConfig::default() })]

    #[test]
    fn update_keeps_p_symmetric_psd_f64_f32(
        a in prop::collection::vec(-3.0f64..3.0, N * N),
        h in prop::collection::vec(-2.0f64..2.0, N),
        log_r in -6.0f64..3.0,
        nu in -10.0f64..10.0,
        floor in 1e-6f64..1.0,
    ) {
        let p = spd_from(&a, floor);
        let r = 10f64.powf(log_r);
        check_update::<f64>(&p, &h, r, nu, 1e-9);
        check_update::<f32>(&p, &h, r.max(1e-3), nu, 1e-4);
    }

    #[test]
    fn sequential_equals_batch(
        a in prop::collection::vec(-2.0f64..2.0, N * N),
        hm in prop::collection::vec(-1.0f64..1.0, 2 * N),
        r in prop::collection::vec(0.1f64..2.0, 2),
        z in prop::collection::vec(-3.0f64..3.0, 2),
    ) {
        let p0 = spd_from(&a, 0.1);
        let hmat = SMatrix::<f64, 2, N>::from_row_slice(&hm);
        let rm = SMatrix::<f64, 2, 2>::new(r[0], 0.0, 0.0, r[1]);
        let zv = nalgebra::Vector2::new(z[0], z[1]);
        let x0 = SVector::<f64, N>::zeros();
        let s = hmat * p0 * hmat.transpose() + rm;
        let k = p0 * hmat.transpose() * s.try_inverse().unwrap();
        let xb = x0 + k * (zv - hmat * x0);
        let pb = (SMatrix::<f64, N, N>::identity() - k * hmat) * p0;
        let (mut x, mut p) = (x0, p0);
        for i in 0..2 {
            let h = hmat.row(i).transpose();
            let nu = zv[i] - h.dot(&x);
            fuse_scalar(&mut x, &mut p, &h, nu, rm[(i, i)], Gate::Off).unwrap();
        }
        let scale = p0.abs().max();
        prop_assert!((x - xb).abs().max() < 1e-9 * (1.0 + xb.abs().max()));
        prop_assert!((p - pb).abs().max() < 1e-9 * scale);
    }

    #[test]
    fn first_order_markov_discretisation_matches_closed_form(
        beta in 1e-3f64..50.0, sigma in 1e-3f64..10.0, dt in 1e-4f64..5.0,
    ) {
        let (phi, qd) = discretize(
            &SMatrix::<f64, 1, 1>::new(-beta),
            &SMatrix::<f64, 1, 1>::new(2.0 * beta * sigma * sigma),
            dt,
        ).unwrap();
        let e = (-beta * dt).exp();
        prop_assert!((phi[0] - e).abs() < 1e-12 * (1.0 + e));
        let exact = sigma * sigma * (1.0 - e * e);
        prop_assert!((qd[0] - exact).abs() < 1e-10 * exact, "{} vs {}", qd[0], exact);
    }

    #[test]
    fn rotations_round_trip(
        v in prop::collection::vec(-1.5f64..1.5, 3),
        roll in -3.1f64..3.1, pitch in -1.5f64..1.5, yaw in -3.1f64..3.1,
    ) {
        let phi = Vector3::new(v[0], v[1], v[2]);
        let c = exp_so3(&phi);
        prop_assert!((log_so3(&c) - phi).norm() < 1e-10);
        prop_assert!((quat_to_dcm(&dcm_to_quat(&c)) - c).abs().max() < 1e-12);
        let ce = euler_to_dcm(roll, pitch, yaw);
        let (r2, p2, y2) = dcm_to_euler(&ce);
        prop_assert!((euler_to_dcm(r2, p2, y2) - ce).abs().max() < 1e-12);
    }
}

#[test]
fn bad_updates_leave_state_untouched_f32() {
    let mut x = SVector::<f32, 3>::new(1.0, 2.0, 3.0);
    let mut p = SMatrix::<f32, 3, 3>::identity();
    let (x0, p0) = (x, p);
    let h = SVector::<f32, 3>::new(1.0, 0.0, 0.0);
    for (nu, r) in [
        (f32::NAN, 1.0),
        (1.0, f32::NAN),
        (1.0, -1.0),
        (f32::INFINITY, 1.0),
    ] {
        assert!(fuse_scalar(&mut x, &mut p, &h, nu, r, Gate::Nis(9.0)).is_err());
        assert_eq!(x.as_slice(), x0.as_slice());
        assert_eq!(p.as_slice(), p0.as_slice());
    }
}

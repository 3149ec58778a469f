//! Tests of the scalar update: hand-computed and batch references, gate, refusal without
//! damage, sparse against dense, the unrolled Joseph pass against the loop.

use super::joseph::{joseph_loop, joseph_unrolled};
use super::*;
use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

#[test]
fn hand_computed_two_state_case() {
    // P = diag(4, 1), h = [1 0], r = 1, ν = 2 → s = 5, k = [0.8, 0], x⁺ = [1.6, 0],
    // P⁺ = diag(4 − 16/5, 1) = diag(0.8, 1).
    let mut x = Vector2::new(0.0_f64, 0.0);
    let mut p = Matrix2::new(4.0, 0.0, 0.0, 1.0);
    let rep = fuse_scalar(&mut x, &mut p, &Vector2::new(1.0, 0.0), 2.0, 1.0, Gate::Off).unwrap();
    assert_eq!(rep.outcome, FusionOutcome::Fused);
    assert!((rep.innovation_variance - 5.0).abs() < 1e-15);
    assert!((rep.nis - 0.8).abs() < 1e-15);
    assert!((x - Vector2::new(1.6, 0.0)).norm() < 1e-15);
    assert!((p - Matrix2::new(0.8, 0.0, 0.0, 1.0)).abs().max() < 1e-15);

    // Correlated case: P = [2 1; 1 2], h = [0 1], r = 2, ν = 1 → s = 4,
    // k = [0.25, 0.5], P⁺ = P − b bᵀ/s = [2−0.25, 1−0.5; ., 2−1].
    let mut x = Vector2::new(0.0_f64, 0.0);
    let mut p = Matrix2::new(2.0, 1.0, 1.0, 2.0);
    fuse_scalar(&mut x, &mut p, &Vector2::new(0.0, 1.0), 1.0, 2.0, Gate::Off).unwrap();
    assert!((x - Vector2::new(0.25, 0.5)).norm() < 1e-15);
    assert!((p - Matrix2::new(1.75, 0.5, 0.5, 1.0)).abs().max() < 1e-15);
}

#[test]
fn sequential_equals_batch() {
    let mut p = Matrix3::new(3.0, 0.4, -0.2, 0.4, 2.0, 0.3, -0.2, 0.3, 1.5_f64);
    let mut x = Vector3::new(0.1, -0.2, 0.3);
    let hm = nalgebra::Matrix2x3::new(1.0, 0.5, 0.0, -0.3, 1.0, 2.0);
    let r = Matrix2::new(0.5, 0.0, 0.0, 0.8);
    let z = Vector2::new(0.7, -1.1);
    // Batch reference.
    let s = hm * p * hm.transpose() + r;
    let kb = p * hm.transpose() * s.try_inverse().unwrap();
    let xb = x + kb * (z - hm * x);
    let pb = (Matrix3::identity() - kb * hm) * p;
    // Sequential: the second innovation uses the state after the first update.
    for i in 0..2 {
        let h = hm.row(i).transpose();
        let nu = z[i] - h.dot(&x);
        fuse_scalar(&mut x, &mut p, &h, nu, r[(i, i)], Gate::Off).unwrap();
    }
    assert!((x - xb).norm() < 1e-14);
    assert!((p - pb).abs().max() < 1e-14);
    assert_eq!(asymmetry(&p), 0.0);
    assert!(is_psd(&p, 1e-12));
}

#[test]
fn gate_rejects_and_leaves_state() {
    let mut x = Vector2::new(1.0_f32, 2.0);
    let mut p = Matrix2::new(1.0, 0.2, 0.2, 1.0);
    let (x0, p0) = (x, p);
    // s = 2, ν = 10 → NIS 50 > 9.
    let rep = fuse_scalar(
        &mut x,
        &mut p,
        &Vector2::new(1.0, 0.0),
        10.0,
        1.0,
        Gate::Nis(9.0),
    )
    .unwrap();
    assert_eq!(rep.outcome, FusionOutcome::Rejected);
    assert!(rep.test_ratio > 5.0);
    assert_eq!(x, x0);
    assert_eq!(p, p0);
}

#[test]
fn bad_input_is_refused_without_damage() {
    let mut x = Vector2::new(1.0_f64, 2.0);
    let mut p = Matrix2::new(1.0, 0.2, 0.2, 1.0);
    let (x0, p0) = (x, p);
    let h = Vector2::new(1.0, 0.0);
    let cases = [
        (h, f64::NAN, 1.0),
        (h, 1.0, 0.0),
        (h, 1.0, -1.0),
        (h, 1.0, f64::INFINITY),
        (Vector2::new(f64::NAN, 0.0), 1.0, 1.0),
    ];
    for (h, nu, r) in cases {
        assert!(fuse_scalar(&mut x, &mut p, &h, nu, r, Gate::Off).is_err());
        assert_eq!(x, x0);
        assert_eq!(p, p0);
    }
    // An indefinite P cannot yield a positive innovation variance.
    let mut bad = Matrix2::new(-5.0, 0.0, 0.0, 1.0);
    assert_eq!(
        fuse_scalar(&mut x, &mut bad, &h, 1.0, 1.0, Gate::Off),
        Err(NavError::InnovationVarianceNotPositive)
    );
}

fn sparse_matches_dense<T: Real>(tol: f64) {
    use nalgebra::{SMatrix, SVector};
    // A full SPD 7×7 P and a row with 3 non-zeros.
    let a = SMatrix::<f64, 7, 7>::from_fn(|i, j| ((i * 7 + j) as f64 * 0.37).sin());
    let p64 = a * a.transpose() + SMatrix::<f64, 7, 7>::identity() * 0.5;
    let p0: SMatrix<T, 7, 7> = p64.map(T::lit);
    let x0 = SVector::<T, 7>::from_fn(|i, _| T::lit(0.1 * i as f64));
    let mut row = SparseRow::<T, 4>::new();
    row.push(1, T::lit(0.7)).unwrap();
    row.push(4, T::lit(-1.3)).unwrap();
    row.push(6, T::lit(2.0)).unwrap();
    let hd: SVector<T, 7> = row.to_dense();
    let (mut xd, mut pd) = (x0, p0);
    let (mut xs, mut ps) = (x0, p0);
    let rd = fuse_scalar(&mut xd, &mut pd, &hd, T::lit(0.3), T::lit(0.2), Gate::Off).unwrap();
    let rs =
        fuse_scalar_sparse(&mut xs, &mut ps, &row, T::lit(0.3), T::lit(0.2), Gate::Off).unwrap();
    assert_eq!(rs.outcome, FusionOutcome::Fused);
    let rel = |a: T, b: T| ((a - b).abs() / (a.abs() + T::lit(1e-30))).to_f64();
    assert!(rel(rd.innovation_variance, rs.innovation_variance) < tol);
    assert!((pd - ps).abs().max().to_f64() < tol * 10.0);
    assert!((xd - xs).abs().max().to_f64() < tol);
    assert_eq!(asymmetry(&ps), T::zero());
    // Gate rejection and bad rows leave the state untouched.
    let (x1, p1) = (xs, ps);
    let rep = fuse_scalar_sparse(
        &mut xs,
        &mut ps,
        &row,
        T::lit(100.0),
        T::lit(0.2),
        Gate::Nis(T::lit(9.0)),
    )
    .unwrap();
    assert_eq!(rep.outcome, FusionOutcome::Rejected);
    let mut bad = row;
    bad.index[1] = 0; // not ascending
    assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
    let mut bad = row;
    bad.index[2] = 7; // out of range
    assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
    let mut bad = row;
    bad.value[0] = T::lit(f64::NAN);
    assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
    assert!(fuse_scalar_sparse(&mut xs, &mut ps, &row, T::one(), T::zero(), Gate::Off).is_err());
    let mut neg = ps;
    neg[(1, 1)] = T::lit(-1e3);
    assert!(fuse_scalar_sparse(&mut xs, &mut neg, &row, T::one(), T::one(), Gate::Off).is_err());
    assert_eq!((xs, ps), (x1, p1));
    prepared_is_sparse_bit_for_bit(xs, ps, &row, &hd);
    let mut full = SparseRow::<T, 1>::new();
    full.push(0, T::one()).unwrap();
    assert_eq!(full.push(1, T::one()), Err(NavError::CapacityExceeded));
}

/// The prepared form (b = P h and hᵀ b by the caller) is the sparse update bit for bit, and
/// refuses a non-finite innovation without damage; from the state `(xs, ps)`, row `row` (dense
/// `hd`).
fn prepared_is_sparse_bit_for_bit<T: Real>(
    xs: nalgebra::SVector<T, 7>,
    ps: nalgebra::SMatrix<T, 7, 7>,
    row: &SparseRow<T, 4>,
    hd: &nalgebra::SVector<T, 7>,
) {
    let b = sparse_covariance_product(&ps, row).unwrap();
    assert_eq!(b, ps * hd);
    let (mut xp, mut pp) = (xs, ps);
    let (mut xq, mut pq) = (xs, ps);
    let rp = fuse_scalar_prepared(
        &mut xp,
        &mut pp,
        &b,
        row.dot(&b),
        T::lit(-0.2),
        T::lit(0.3),
        Gate::Nis(T::lit(25.0)),
    )
    .unwrap();
    let rq = fuse_scalar_sparse(
        &mut xq,
        &mut pq,
        row,
        T::lit(-0.2),
        T::lit(0.3),
        Gate::Nis(T::lit(25.0)),
    )
    .unwrap();
    assert_eq!((rp, xp, pp), (rq, xq, pq));
    assert_eq!(rp.outcome, FusionOutcome::Fused);
    assert!(fuse_scalar_prepared(
        &mut xp,
        &mut pp,
        &b,
        T::lit(f64::NAN),
        T::one(),
        T::one(),
        Gate::Off
    )
    .is_err());
    assert_eq!((xp, pp), (xq, pq));
}

#[test]
fn sparse_update_matches_dense_f32_f64() {
    sparse_matches_dense::<f64>(1e-13);
    sparse_matches_dense::<f32>(2e-5);
}

fn unrolled_equals_loop<T: Real, const N: usize>() {
    use nalgebra::{SMatrix, SVector};
    let a = SMatrix::<f64, N, N>::from_fn(|i, j| ((i * N + j) as f64 * 0.61).cos());
    let p0: SMatrix<T, N, N> = (a * a.transpose()).map(T::lit);
    let k = SVector::<T, N>::from_fn(|i, _| T::lit(0.3 - 0.07 * i as f64));
    let b = SVector::<T, N>::from_fn(|i, _| T::lit(1.1 + 0.13 * i as f64));
    let c = SVector::<T, N>::from_fn(|i, _| T::lit(1e-3 * (i as f64 - 4.0)));
    let (mut pu, mut pl) = (p0, p0);
    joseph_unrolled(&mut pu.data.0, &k.data.0[0], &b.data.0[0], &c.data.0[0]);
    joseph_loop(&mut pl, &k, &b, &c);
    // Bit for bit, including the mirrored lower triangle; and the update did something.
    assert_eq!(pu, pl);
    assert_eq!(asymmetry(&pu), T::zero());
    assert!(pu != p0);
}

#[test]
fn unrolled_joseph_pass_is_the_loop_bit_for_bit() {
    unrolled_equals_loop::<f32, 1>();
    unrolled_equals_loop::<f32, 9>();
    unrolled_equals_loop::<f32, 12>();
    unrolled_equals_loop::<f64, 5>();
    unrolled_equals_loop::<f64, 12>();
    unrolled_equals_loop::<f32, 15>();
    unrolled_equals_loop::<f64, 15>();
}

#[test]
fn propagate_dense_matches_formula() {
    let mut p = Matrix2::new(1.0_f64, 0.1, 0.1, 2.0);
    let phi = Matrix2::new(1.0, 0.1, 0.0, 0.9);
    let q = Matrix2::new(0.01, 0.0, 0.0, 0.02);
    let expect = phi * p * phi.transpose() + q;
    propagate_dense(&mut p, &phi, &q);
    assert!((p - expect).abs().max() < 1e-15);
    assert!(!is_psd(&Matrix2::new(1.0, 2.0, 2.0, 1.0), 1e-9));
}

//! Unit tests of the measurement module: H blocks, rows and their Jacobians, the bounds.
use super::*;

/// `linear_df_dot` is the linear row's `dot` bit for bit (zeros of h and x included).
#[test]
fn linear_df_dot_is_the_linear_rows_dot() {
    const K: usize = 5;
    let mut seed = 7u64;
    let mut next = |zero: bool| {
        seed = seed
            .wrapping_mul(6_364_136_223_846_793_005)
            .wrapping_add(1_442_695_040_888_963_407);
        if zero && seed >> 60 < 4 {
            0.0
        } else {
            ((seed >> 11) as f64 / (1u64 << 53) as f64 - 0.5) * 20.0
        }
    };
    for _ in 0..500 {
        let v = |n: &mut dyn FnMut(bool) -> f64| {
            Vector3::new(n(true) as f32, n(true) as f32, n(true) as f32)
        };
        let (w, wd, f, l) = (v(&mut next), v(&mut next), v(&mut next), v(&mut next));
        let x = SVector::<f32, 15>::from_fn(|_, _| next(true) as f32);
        let terms = ManoeuvreTerms::new(&w, &wd, &l);
        for i in 0..3 {
            let row = h_row_flight_df_with::<f32, K>(i, &Vector3::zeros(), &f, &l, &terms);
            let ours = linear_df_dot::<f32, K, 15>(i, &f, &l, &terms, &x);
            assert_eq!(ours.to_bits(), row.dot(&x).to_bits());
        }
    }
}

/// `clamp_symmetric` is `max(−l).min(l)` bit for bit, NaN, ±∞, ±0 and the limits included.
#[test]
fn clamp_symmetric_is_max_then_min() {
    fn check<T: Real>(values: &[f64]) {
        for &l in &[1e-3, 0.5, 3.0] {
            let l = T::lit(l);
            for &v in values {
                let v = T::lit(v);
                let ours = clamp_symmetric(v, l).to_f64().to_bits();
                let theirs = v.max(-l).min(l).to_f64().to_bits();
                assert_eq!(ours, theirs, "{v:?} {l:?}");
            }
            let nan = clamp_symmetric(T::lit(f64::NAN), l);
            assert_eq!(nan.to_f64().to_bits(), (-l).to_f64().to_bits());
        }
    }
    let values = [
        f64::NEG_INFINITY,
        -4.0,
        -3.0,
        -0.5,
        -1e-3,
        -1e-30,
        -0.0,
        0.0,
        1e-30,
        1e-3,
        0.5,
        0.7,
        3.0,
        1e30,
        f64::INFINITY,
    ];
    check::<f32>(&values);
    check::<f64>(&values);
}

#[test]
fn h_blocks_as_printed() {
    let w = Vector3::new(0.1, -0.2, 0.3);
    let f = Vector3::new(2.0, 1.0, -9.8);
    let l0 = Vector3::new(0.0, 5.0, 0.0);
    let h = h_matrix::<f64, 4, 12>(&w, &f, &l0).unwrap();
    let sk = crate::math::rotation::skew;
    let wx = sk(&w);
    let fx = sk(&f);
    let lx = sk(&l0);
    assert_eq!(h.fixed_view::<3, 3>(0, 0).into_owned(), -wx);
    assert_eq!(h.fixed_view::<3, 3>(0, 3).into_owned(), -wx);
    assert_eq!(
        h.fixed_view::<3, 3>(0, 6).into_owned(),
        -nalgebra::Matrix3::identity()
    );
    assert_eq!(h.fixed_view::<3, 3>(3, 3).into_owned(), -fx);
    assert_eq!(h.fixed_view::<3, 3>(3, 9).into_owned(), lx);
    assert!(h.fixed_view::<3, 3>(3, 6).iter().all(|v| *v == 0.0));
    // L_0 × θ̈_f = [l θ̈_Z, 0, −l θ̈_X]
    let th = Vector3::new(1.0, 2.0, 3.0);
    assert_eq!(lx * th, Vector3::new(5.0 * 3.0, 0.0, -5.0 * 1.0));
    let h9 = h_matrix::<f64, 3, 9>(&w, &f, &l0).unwrap();
    assert_eq!(h9.fixed_view::<3, 3>(3, 0).into_owned(), -fx);
    assert!(h_matrix::<f64, 3, 12>(&w, &f, &l0).is_err());
    // The filters' rows are the dense rows in axis-major order with θ_m replaced by the
    // total θ = θ_m + θ_f: z depends on both through their sum (equal columns), so the
    // θ column keeps that value and the θ_f column vanishes.
    let l1 = Vector3::new(0.3, 5.0, -0.2);
    fn expected<const K: usize, const N: usize>(mut d: SVector<f64, N>) -> SVector<f64, N> {
        for a in 0..3 {
            assert_eq!(d[K * a], d[K * a + 1], "θ_m and θ_f columns differ");
            d[K * a + 1] = 0.0;
        }
        d
    }
    for row in 0..6 {
        let d: SVector<f64, 12> = h_row(FlexureModel::Proposed, row, &w, &f, &l1, |d, a| {
            super::super::model::axis_index::<4>(d, a)
        });
        let sp = h_row_total::<f64, 4, 4>(FlexureModel::Proposed, row, &w, &f, &l1);
        assert_eq!(sp.to_dense::<12>(), expected::<4, 12>(d));
        let d9: SVector<f64, 9> = h_row(FlexureModel::Conventional, row, &w, &f, &l1, |d, a| {
            super::super::model::axis_index::<3>(d, a)
        });
        let sp9 = h_row_total::<f64, 3, 4>(FlexureModel::Conventional, row, &w, &f, &l1);
        assert_eq!(sp9.to_dense::<9>(), expected::<3, 9>(d9));
    }
}

/// The flight df rows are the Jacobian of the second-order model at θ̂ (central finite
/// differences of h in every state it depends on), and equal the linear rows at θ̂ = 0.
#[test]
fn flight_df_rows_are_the_jacobian_of_the_second_order_model() {
    use super::super::model::FLIGHT_CHAIN as K;
    let f = Vector3::new(3.0, -2.0, -9.8);
    let l0 = Vector3::new(0.3, 5.0, -0.2);
    let model = |x: &SVector<f64, 15>| -> Vector3<f64> {
        let th = Vector3::new(x[0], x[K], x[2 * K]);
        let acc = Vector3::new(x[3], x[K + 3], x[2 * K + 3]);
        let b = Vector3::new(x[4], x[K + 4], x[2 * K + 4]);
        -f.cross(&th) + th.cross(&th.cross(&f)) * 0.5 + l0.cross(&acc) + b
    };
    let mut x = SVector::<f64, 15>::zeros();
    for (j, v) in x.iter_mut().enumerate() {
        *v = 0.01 * ((j as f64) * 0.7).sin() + if j % K == 0 { 0.012 } else { 0.0 };
    }
    let theta = Vector3::new(x[0], x[K], x[2 * K]);
    let eps = 1e-6;
    for i in 0..3 {
        let z = Vector3::zeros();
        let row = h_row_flight_df::<f64, K>(i, &theta, &z, &z, &f, &l0).to_dense::<15>();
        for j in 0..15 {
            let (mut xp, mut xm) = (x, x);
            xp[j] += eps;
            xm[j] -= eps;
            let fd = (model(&xp)[i] - model(&xm)[i]) / (2.0 * eps);
            assert!(
                (fd - row[j]).abs() < 1e-8,
                "row {i} col {j}: {fd} vs {}",
                row[j]
            );
        }
        // Beyond the small-angle bound the model's ½ term is built from the bounded θ̂
        // (constant in that axis): the Jacobian is that model's derivative, so its θ column
        // of that axis is the linear row's.
        let lim = MAX_MISALIGNMENT_RAD;
        let bounded_model = |x: &SVector<f64, 15>| -> Vector3<f64> {
            let th = Vector3::new(x[0], x[K], x[2 * K]);
            let c = bounded_misalignment(&th);
            -f.cross(&th) + c.cross(&c.cross(&f)) * 0.5
        };
        let mut xo = x;
        xo[K] = 1.5 * lim; // θ_Y beyond the bound
        xo[2 * K] = -1.2 * lim; // θ_Z beyond it on the other side
        let th_out = Vector3::new(xo[0], xo[K], xo[2 * K]);
        let row = h_row_flight_df::<f64, K>(i, &th_out, &z, &z, &f, &l0).to_dense::<15>();
        let linear0 = h_row_flight::<f64, K, 12>(3 + i, &z, &z, &f, &l0).to_dense::<15>();
        for a in 0..3 {
            let j = a * K;
            let (mut xp, mut xm) = (xo, xo);
            xp[j] += eps;
            xm[j] -= eps;
            let fd = (bounded_model(&xp)[i] - bounded_model(&xm)[i]) / (2.0 * eps);
            assert!(
                (fd - row[j]).abs() < 1e-8,
                "beyond the bound, row {i} θ axis {a}: {fd} vs {}",
                row[j]
            );
            if a > 0 {
                assert_eq!(row[j], linear0[j], "row {i} θ axis {a} beyond the bound");
            } else {
                assert_ne!(row[j], linear0[j], "row {i} θ_X inside the bound");
            }
        }
        // At θ̂ = 0 the Jacobian is the linear row, manoeuvre terms included.
        let (w, wd) = (Vector3::new(0.1, -0.4, 0.3), Vector3::new(-0.5, 0.2, 0.9));
        let linear = h_row_flight::<f64, K, 12>(3 + i, &w, &wd, &f, &l0);
        let at_zero = h_row_flight_df::<f64, K>(i, &Vector3::zeros(), &w, &wd, &f, &l0);
        assert_eq!(at_zero.to_dense::<15>(), linear.to_dense::<15>());
    }
}

#[test]
fn lever_arm_compensation_is_rigid_body_kinematics() {
    let m = MasterSample {
        time: Timestamp::ZERO,
        angular_rate_rad_s: Vector3::new(0.0, 0.0, 0.5),
        angular_accel_rad_s2: Vector3::new(0.0, 0.0, 2.0),
        specific_force_m_s2: Vector3::new(0.0, 0.0, -9.8),
    };
    let l0 = Vector3::new(0.0, 5.0, 0.0);
    let f = compensate_lever_arm(&m, &l0);
    // Yaw acceleration 2 rad/s² at 5 m right: −10 m/s² along X; centripetal −0.25·5 along Y.
    assert!((f - Vector3::new(-10.0, -1.25, -9.8)).norm() < 1e-12);
    let mut bad = m;
    bad.angular_accel_rad_s2.y = f64::NAN;
    assert!(bad.validate().is_err());
    assert!(m.validate().is_ok());
}

//! Unit tests of the LOS update: the generated kernels against the dense forms and the
//! structural zeros of H outside their support.
use super::*;
use crate::math::rotation::euler_to_dcm;
use crate::seeker_ins::generated::los17::p_h_pitch;
use crate::seeker_ins::measurement::los_model;
use crate::seeker_ins::{Landmark, Position};
use nalgebra::SMatrix;

/// The generated LOS kernels read the rows of H in their structurally non-zero columns
/// only (position, attitude, the component's gimbal angle error): every other entry is an
/// exact zero, over attitudes and gimbal angles across the accepted range.
#[test]
fn los_rows_are_zero_outside_the_generated_support() {
    let pos = Position {
        lat_rad: 0.65,
        lon_rad: 2.2,
        alt_m: 1000.0,
    };
    let lm = Landmark::new(Position {
        lat_rad: 0.6503,
        lon_rad: 2.21,
        alt_m: 0.0,
    })
    .unwrap();
    let pitch_support = [0, 1, 2, 6, 7, 8, 15];
    let yaw_support = [0, 1, 2, 6, 7, 8, 16];
    let mut checked = 0;
    for k in 0..40 {
        let kf = f64::from(k);
        let c = euler_to_dcm(0.1 * kf - 2.0, 0.03 * kf - 0.6, 0.17 * kf - 3.0);
        let gimbal = GimbalAngles {
            pitch_rad: 0.035 * kf - 0.7,
            yaw_rad: 0.15 * kf - 3.0,
        };
        let m = los_model(&pos, &c, &gimbal, &lm, 1e-3).unwrap();
        for j in 0..STATES {
            if !pitch_support.contains(&j) {
                assert_eq!(m.h_pitch[j], 0.0, "pitch row, column {j}");
            }
            if !yaw_support.contains(&j) {
                assert_eq!(m.h_yaw[j], 0.0, "yaw row, column {j}");
            }
        }
        assert!(m.h_pitch[15] != 0.0 && m.h_pitch.fixed_rows::<3>(ATT).norm() > 0.0);
        checked += 1;
    }
    assert_eq!(checked, 40);
}

/// The generated `P h` and rank-two update equal their dense forms bit for bit (the
/// skipped terms are zeros) and keep P exactly symmetric.
#[test]
fn generated_los_kernels_equal_the_dense_forms() {
    let mut p = SMatrix::<f64, STATES, STATES>::zeros();
    for i in 0..STATES {
        for j in 0..STATES {
            let (a, b) = (i.min(j) as f64, i.max(j) as f64);
            p[(i, j)] = if i == j {
                2.0 + a
            } else {
                0.1 / (1.0 + a + 0.5 * b)
            };
        }
    }
    let mut h = SVector::<f64, STATES>::zeros();
    for (j, v) in [
        (0, 1.5),
        (1, -0.5),
        (2, 0.25),
        (6, 0.75),
        (7, -1.0),
        (8, 0.1),
        (15, -1.0),
    ] {
        h[j] = v;
    }
    let k = p_h_pitch(&p.data.0, &h.data.0[0]);
    let dense = p * h;
    for i in 0..STATES {
        assert_eq!(k[i].to_bits(), dense[i].to_bits(), "k[{i}]");
    }
    let kk: [f64; STATES] = core::array::from_fn(|i| k[i] * 0.01);
    let k2: [f64; STATES] = core::array::from_fn(|i| 0.5 * k[i] + 0.001 * i as f64);
    let kk2: [f64; STATES] = core::array::from_fn(|i| 0.002 * k2[i]);
    let mut updated = p;
    assert!(rank_two_variances_ok(&p.data.0, &k, &kk, &k2, &kk2));
    rank_two_update(&mut updated.data.0, &k, &kk, &k2, &kk2, 0.0);
    for i in 0..STATES {
        for j in 0..STATES {
            let (r, c) = (i.min(j), i.max(j));
            let expect = p[(r, c)] - k[r] * kk[c] - k2[r] * kk2[c];
            assert_eq!(updated[(i, j)].to_bits(), expect.to_bits(), "P[{i},{j}]");
        }
    }
    let huge: [f64; STATES] = [1e3; STATES];
    assert!(!rank_two_variances_ok(&p.data.0, &huge, &huge, &k2, &kk2));
    // A variance that would become +∞ (passes the sign test, not the finiteness probe)
    // or NaN in one state only.
    for bad in [f64::NEG_INFINITY, f64::NAN] {
        let mut kk_bad = kk;
        kk_bad[5] = bad;
        let mut k_pos = k;
        k_pos[5] = 1.0;
        assert!(!rank_two_variances_ok(
            &p.data.0, &k_pos, &kk_bad, &k2, &kk2
        ));
    }
    // The stabilising noise of the same pass: each variance v + v·δ, nothing else.
    let delta = 1e-6;
    let mut stabilised = p;
    rank_two_update(&mut stabilised.data.0, &k, &kk, &k2, &kk2, delta);
    for i in 0..STATES {
        for j in 0..STATES {
            let v = updated[(i, j)];
            let expect = if i == j { v + v * delta } else { v };
            assert_eq!(stabilised[(i, j)].to_bits(), expect.to_bits(), "P[{i},{j}]");
        }
    }
}

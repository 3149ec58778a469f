//! The EKF's PSD-margin check, deferred to the navigator's quiet ticks (`flight::psd_check`):
//! it runs on the first tick without a covariance step after P changed, lifts a small margin
//! there and nowhere else, and a covariance step from a checked P adds nothing.

use super::*;
use crate::seeker_ins::{ATT, PSD_MARGIN_EPS};

/// The smallest relative LDLᵀ pivot `d_k / P_kk` of `p`, in f64 (the correlation matrix's
/// pivots; every one positive ⇔ P positive definite).
fn min_relative_pivot<T: Real>(p: &SMatrix<T, STATES, STATES>) -> f64 {
    let p = p.map(|v| v.to_f64());
    let mut l = SMatrix::<f64, STATES, STATES>::zeros();
    let mut d = [0.0; STATES];
    let mut min = f64::INFINITY;
    for j in 0..STATES {
        let mut dj = p[(j, j)];
        for k in 0..j {
            dj -= l[(j, k)] * l[(j, k)] * d[k];
        }
        d[j] = dj;
        min = min.min(dj / p[(j, j)]);
        for i in j + 1..STATES {
            let mut v = p[(i, j)];
            for k in 0..j {
                v -= l[(i, k)] * l[(j, k)] * d[k];
            }
            l[(i, j)] = v / dj;
        }
    }
    min
}

/// A tenth of the paper's σ with the north velocity and east tilt errors correlated
/// `1 − 2e-7`: a relative pivot of ≈ 4e-7, below the check's margin in f32 (16 ε = 1.9e-6),
/// far above it in f64.
fn near_singular_p0<T: Real>() -> SMatrix<T, STATES, STATES> {
    let mut p = crate::seeker_ins::paper_initial_covariance::<T>();
    p *= T::lit(0.01);
    let (a, b) = (VEL, ATT + 1);
    let c = (p[(a, a)] * p[(b, b)]).sqrt() * T::lit(1.0 - 2e-7);
    p[(a, b)] = c;
    p[(b, a)] = c;
    p
}

/// Carry for a second, then the EKF released with `p0`; the navigator and the world.
fn released_with<T: Real>(p0: SMatrix<T, STATES, STATES>) -> (FlightNavigator<T, 32>, World) {
    let (mut nav, world) = carry_for::<T>(1.0, 10.0);
    release_at_truth_with(&mut nav, &world, p0);
    (nav, world)
}

fn covariance<T: Real>(nav: &FlightNavigator<T, 32>) -> SMatrix<T, STATES, STATES> {
    *nav.ekf().unwrap().covariance()
}

#[test]
fn the_deferred_check_lifts_a_small_margin_on_a_quiet_tick_f32() {
    let p0 = near_singular_p0::<f32>();
    assert!(min_relative_pivot(&p0) < PSD_MARGIN_EPS * f64::from(f32::EPSILON));
    let (mut nav, mut world) = released_with(p0);
    let interval = usize::from(nav.config().ins.covariance_interval_steps);
    // P0 is new at release: the first tick leaves it alone, the second (no covariance step
    // on either) checks and lifts it, every variance by the same relative δ, the
    // correlations' numerators kept.
    nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    assert_eq!(covariance(&nav), p0);
    nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    let p1 = covariance(&nav);
    let delta = p1[(VEL, VEL)] / p0[(VEL, VEL)] - 1.0;
    assert!(delta > 0.0);
    for i in 0..STATES {
        for j in 0..STATES {
            if i == j {
                assert!(p1[(i, i)] > p0[(i, i)], "variance {i} not lifted");
                let rel = p1[(i, i)] / p0[(i, i)] - 1.0;
                assert!(
                    (rel - delta).abs() <= 2.0 * f32::EPSILON,
                    "{i}: {rel:e} vs {delta:e}"
                );
            } else {
                assert_eq!(p1[(i, j)].to_bits(), p0[(i, j)].to_bits(), "({i}, {j})");
            }
        }
    }
    let margin = PSD_MARGIN_EPS * f64::from(f32::EPSILON);
    assert!(
        min_relative_pivot(&p1) > 0.5 * margin,
        "{:e}",
        min_relative_pivot(&p1)
    );
    // Quiet ticks after the check leave P alone, bit for bit.
    for _ in 3..interval {
        nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
        assert_eq!(covariance(&nav), p1);
    }
    // The covariance step from the checked P adds no stabilising noise: the filter's own step
    // with nothing added, not the one with the constant 4 ε.
    let inc = world.step();
    let mut deferred = *nav.ekf().unwrap();
    let mut constant = deferred;
    let imu = imu_tick::<f32>(&inc).increment;
    deferred.propagate_uncounted(&imu, None).unwrap();
    assert_eq!(deferred.steps_pending(), 0);
    constant.propagate_uncounted(&imu, None).unwrap();
    constant.add_stabilising_noise();
    nav.tick(&imu_tick(&inc), &Aids::NONE).unwrap();
    let stepped = covariance(&nav);
    assert_eq!(stepped, *deferred.covariance());
    assert_ne!(stepped, *constant.covariance());
    // The next (quiet) tick checks the stepped P: a margin at least half the check's after it.
    nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    let checked = covariance(&nav);
    assert_eq!(nav.ekf().unwrap().steps_pending(), 1);
    assert!(min_relative_pivot(&checked) > 0.5 * margin);
    for i in 0..STATES {
        assert!(checked[(i, i)] >= stepped[(i, i)]);
    }
}

#[test]
fn the_deferred_check_keeps_a_healthy_p_bit_for_bit_f64() {
    // The same P0 in f64: its relative pivot (4e-7) is far above 16 ε of f64.
    let p0 = near_singular_p0::<f64>();
    let (mut nav, mut world) = released_with(p0);
    for _ in 0..2 {
        nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    }
    assert_eq!(covariance(&nav), p0);
}

/// The LOS sample of the world's missile truth at `time`.
fn los_at(world: &World, time: Timestamp) -> LosSample<f32> {
    let g = gimbal_truth(&world.missile_truth());
    LosSample {
        time,
        gimbal: crate::seeker_ins::GimbalAngles {
            pitch_rad: g.pitch_rad as f32,
            yaw_rad: g.yaw_rad as f32,
        },
    }
}

/// The EKF after one tick with a LOS sample as the navigator runs it: the IMU sample, the
/// pending covariance step flushed without noise, the constant noise when `noise`, the update.
fn los_tick_reference(
    ekf: &SeekerIns<f32>,
    inc: &ImuIncrement<f64>,
    los: &LosSample<f32>,
    noise: bool,
) -> SMatrix<f32, STATES, STATES> {
    let mut e = *ekf;
    e.propagate_uncounted(&imu_tick::<f32>(inc).increment, None)
        .unwrap();
    e.predict_covariance_with(crate::seeker_ins::PsdMargin::Deferred)
        .unwrap();
    if noise {
        e.add_stabilising_noise();
    }
    e.update_los(los).unwrap();
    *e.covariance()
}

/// One navigator tick with a LOS sample at the world's next IMU sample; the EKF before it,
/// the sample and the LOS sample (for [`los_tick_reference`]).
fn tick_with_los(
    nav: &mut FlightNavigator<f32, 32>,
    world: &mut World,
) -> (SeekerIns<f32>, ImuIncrement<f64>, LosSample<f32>) {
    let inc = world.step();
    let los = los_at(world, inc.time);
    let ekf = *nav.ekf().unwrap();
    let aids = Aids {
        seeker: Some(&los),
        ..Aids::NONE
    };
    nav.tick(&imu_tick(&inc), &aids).unwrap();
    (ekf, inc, los)
}

#[test]
fn a_step_from_an_unchecked_p_gets_the_constant_noise_before_the_update_f32() {
    let mut p0 = crate::seeker_ins::paper_initial_covariance::<f32>();
    p0 *= 0.01;
    let (mut nav, mut world) = released_with(p0);
    while nav.phase() != Phase::Midcourse {
        nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    }
    // Up to a tick whose IMU part runs a covariance step.
    loop {
        nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
        if nav.ekf().unwrap().steps_pending() == 0 {
            break;
        }
    }
    // A LOS sample on the next tick: its flushed step starts from the P of that step, not
    // checked yet (no quiet tick between), so the constant noise comes before the update.
    let (ekf, inc, los) = tick_with_los(&mut nav, &mut world);
    let with_noise = los_tick_reference(&ekf, &inc, &los, true);
    assert_eq!(covariance(&nav), with_noise);
    assert_ne!(with_noise, los_tick_reference(&ekf, &inc, &los, false));
    // A quiet tick checks P; a LOS sample after it flushes a step from a checked P: no noise.
    nav.tick(&imu_tick(&world.step()), &Aids::NONE).unwrap();
    let (ekf, inc, los) = tick_with_los(&mut nav, &mut world);
    assert_eq!(
        covariance(&nav),
        los_tick_reference(&ekf, &inc, &los, false)
    );
}

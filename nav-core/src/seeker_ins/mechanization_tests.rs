//! Unit tests of the strapdown INS (time stamps, stationary INS, refused input).
use super::*;
use crate::math::rotation::{dcm_to_quat, euler_to_dcm, quat_to_dcm};

fn start<T: Real>() -> InsState<T> {
    InsState {
        position: Position {
            lat_rad: 37f64.to_radians(),
            lon_rad: 127f64.to_radians(),
            alt_m: 1000.0,
        },
        vel_ned_m_s: Vector3::new(T::zero(), T::lit(200.0), T::zero()),
        q_b_n: dcm_to_quat(&euler_to_dcm(T::zero(), T::zero(), T::lit(1.0))),
    }
}

#[test]
fn bad_inputs_leave_state_unchanged() {
    let mut ins = Ins::new(start::<f32>(), 0.01).unwrap();
    let before = ins;
    let mut inc = ImuIncrement::zero(Timestamp::from_micros(10_000));
    inc.delta_v_m_s.x = f32::NAN;
    assert!(ins.step(&inc).is_err());
    inc.delta_v_m_s.x = 0.0;
    inc.delta_theta_rad.y = 2.0;
    assert!(ins.step(&inc).is_err());
    assert_eq!(ins, before);
    assert!(ins
        .correct(f64::NAN, 0.0, 0.0, &Vector3::zeros(), &Vector3::zeros())
        .is_err());
    assert_eq!(ins, before);
    assert_eq!(
        Ins::new(start::<f64>(), 0.0).err(),
        Some(NavError::InvalidTimeStep)
    );
}

#[test]
fn stationary_level_ins_stays_put() {
    // At rest on the earth the IMU senses −g up and the earth rate; the INS must not move.
    fn run<T: Real>() -> f64 {
        let mut s = start::<T>();
        s.vel_ned_m_s = Vector3::zeros();
        let lat = s.position.lat_rad;
        let c = quat_to_dcm(&s.q_b_n);
        let g = normal_gravity_m_s2(T::lit(lat), T::lit(1000.0));
        let dt = T::lit(0.01);
        let f_n = Vector3::new(T::zero(), T::zero(), -g);
        let w_n = crate::earth::earth_rate_ned(T::lit(lat));
        let mut inc = ImuIncrement {
            time: Timestamp::ZERO,
            delta_theta_rad: c.transpose() * w_n * dt,
            delta_v_m_s: c.transpose() * f_n * dt,
        };
        let mut ins = Ins::new(s, dt).unwrap();
        for k in 1..=6000 {
            inc.time = Timestamp::from_micros(k * 10_000);
            ins.step(&inc).unwrap();
        }
        let p = ins.state().position;
        let dn = (p.lat_rad - lat) * 6.4e6;
        let de = (p.lon_rad - s.position.lon_rad) * 6.4e6 * lat.cos();
        (dn * dn + de * de + (p.alt_m - 1000.0).powi(2)).sqrt()
    }
    // 60 s: f64 centimetres; f32 metres at most (vertical channel instability is slow).
    assert!(run::<f64>() < 0.05, "{}", run::<f64>());
    assert!(run::<f32>() < 2.0, "{}", run::<f32>());
}

/// A stationary sample over `dt_us` µs ending at `time_us` (the IMU senses −g and the
/// earth rate over the actual interval).
fn at_rest<T: Real>(s: &InsState<T>, time_us: u64, dt_us: u64) -> ImuIncrement<T> {
    let lat = s.position.lat_rad;
    let c = quat_to_dcm(&s.q_b_n);
    let g = normal_gravity_m_s2(T::lit(lat), T::lit(s.position.alt_m));
    let dt: T = micros_to_seconds(dt_us);
    let w_n = crate::earth::earth_rate_ned(T::lit(lat));
    ImuIncrement {
        time: Timestamp::from_micros(time_us),
        delta_theta_rad: c.transpose() * w_n * dt,
        delta_v_m_s: c.transpose() * Vector3::new(T::zero(), T::zero(), -g) * dt,
    }
}

fn resting<T: Real>() -> InsState<T> {
    let mut s = start::<T>();
    s.vel_ned_m_s = Vector3::zeros();
    s
}

#[test]
fn time_stamps_are_checked_and_nothing_changes_on_refusal() {
    fn run<T: Real>() {
        let s = resting::<T>();
        let mut ins = Ins::new(s, T::lit(0.01)).unwrap();
        assert_eq!(ins.time(), None);
        assert_eq!(ins.last_interval_s(), T::lit(0.01));
        // The first sample is integrated over the nominal interval, whatever its stamp.
        ins.step(&at_rest(&s, 5_000_000, 10_000)).unwrap();
        assert_eq!(ins.time(), Some(Timestamp::from_micros(5_000_000)));
        let before = ins;
        for t in [5_000_000, 4_999_999, 0] {
            assert_eq!(
                ins.step(&at_rest(&s, t, 10_000)),
                Err(NavError::TimeNotIncreasing)
            );
            assert_eq!(ins, before);
        }
        assert_eq!(
            ins.step(&at_rest(&s, 5_000_000 + 1_000_001, 10_000)),
            Err(NavError::InvalidTimeStep)
        );
        assert_eq!(ins, before);
        // The clock is not frozen: a later sample is accepted, over its actual interval.
        ins.step(&at_rest(&s, 5_013_000, 13_000)).unwrap();
        assert_eq!(ins.last_interval_s(), T::lit(0.013));
        ins.step(&at_rest(&s, 5_023_000, 10_000)).unwrap();
        assert_eq!(ins.last_interval_s(), T::lit(0.01));
        ins.step(&at_rest(&s, 6_023_000, 1_000_000)).unwrap();
        assert_eq!(ins.last_interval_s(), T::one());
    }
    run::<f32>();
    run::<f64>();
}

/// Gravity and earth rate integrated over the actual interval: a resting INS fed with
/// jittered intervals (±30 %) stays put as with regular ones, and the same stream 10⁶ s
/// later gives the same bits.
#[test]
fn jittered_intervals_and_late_clocks_integrate_the_actual_interval() {
    fn run<T: Real>(t0_us: u64, jitter: bool) -> (f64, InsState<T>) {
        let s = resting::<T>();
        let mut ins = Ins::new(s, T::lit(0.01)).unwrap();
        let mut t = t0_us;
        let mut k = 0u64;
        while t < t0_us + 60_000_000 {
            // Deterministic jitter in [7 ms, 13 ms] after the first sample (which is
            // integrated over the nominal interval).
            let dt_us = if jitter && k > 0 {
                7_000 + (k * 7_919 % 6_001)
            } else {
                10_000
            };
            t += dt_us;
            k += 1;
            ins.step(&at_rest(&s, t, dt_us)).unwrap();
        }
        let p = ins.state().position;
        let dn = (p.lat_rad - s.position.lat_rad) * 6.4e6;
        let de = (p.lon_rad - s.position.lon_rad) * 6.4e6 * s.position.lat_rad.cos();
        let err = (dn * dn + de * de + (p.alt_m - 1000.0).powi(2)).sqrt();
        (err, *ins.state())
    }
    let (regular, _) = run::<f64>(0, false);
    let (jittered, _) = run::<f64>(0, true);
    assert!(regular < 0.05 && jittered < 0.05, "{regular} {jittered}");
    let (_, a) = run::<f32>(0, true);
    let (_, b) = run::<f32>(1_000_000_000_000, true);
    assert_eq!(a, b);
}

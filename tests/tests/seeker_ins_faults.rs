//! Fault injection of the seeker-aided INS: the `fault-seeker` and `fault-imu` scenarios at
//! a reduced run count recover; IMU gaps are detected from the time stamps and bridged like
//! the held samples would (or, beyond the policy's bound, reset); time stamps that do not
//! increase are refused without damage; a clock 10⁶ s after its epoch computes the same bits.

use nalgebra::{SMatrix, Vector3};
use nav_core::contract::{Estimator, Health};
use nav_core::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, ClipFlags, ImuFaultPolicy, ImuIncrement, InsState,
    Landmark, LosSample, Position, SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsInitial,
};
use nav_core::time::Timestamp;
use nav_core::{HealthState, NavError, Real};
use nav_sim::scenarios::seeker_ins::fault::{analyse, load_fault_config, FaultConfig, Summary};

/// IMU interval of these tests, µs (100 Hz).
const DT_US: u64 = 10_000;

fn load(name: &str) -> FaultConfig {
    load_fault_config(name).unwrap()
}

fn fault<'a>(s: &'a Summary, name: &str) -> &'a Summary {
    s["faults"]
        .as_array()
        .unwrap()
        .iter()
        .find(|f| f["fault"] == name)
        .unwrap()
}

#[test]
fn fault_seeker_recovers() {
    let r = analyse(&load("fault-seeker"), 20, 7101, false).unwrap();
    let s = &r.summary;
    // The false lock (2° in yaw) is rejected in yaw every time; the pitch direction is
    // unaffected and fused.
    let did = &s["filter_did"];
    let rej = did["false_lock_components_rejected"].as_u64().unwrap();
    let fused = did["false_lock_components_fused"].as_u64().unwrap();
    assert_eq!(rej, 20 * 100, "{did}");
    assert_eq!(fused, 20 * 100, "{did}");
    assert_eq!(did["seeker_epochs_dropped"].as_u64().unwrap(), 20 * 300);
    assert_eq!(did["updates_refused"].as_u64().unwrap(), 0);
    // Loss of lock: attitude comes back within its pre-fault bound; velocity and position
    // (whose RMS grows without the fault too, the along-LOS error being unobservable) peak
    // within 25 % of the same runs without faults.
    let f = &fault(s, "loss_of_lock")["attitude_rms_deg"];
    assert_eq!(f["recovered"], true, "{f}");
    assert!(f["recovery_time_s"].as_f64().unwrap() < 10.0, "{f}");
    for m in ["velocity_rms_m_s", "position_rms_m"] {
        let f = &fault(s, "loss_of_lock")[m];
        let (p, b) = (
            f["peak"].as_f64().unwrap(),
            f["baseline_peak_same_span"].as_f64().unwrap(),
        );
        assert!(p < 1.25 * b, "{m}: {f}");
    }
    for m in ["attitude_rms_deg", "velocity_rms_m_s", "position_rms_m"] {
        let f = &fault(s, "false_lock")[m];
        assert_eq!(f["recovered"], true, "{m}: {f}");
    }
    // At the end the faulted runs are within 10 % of the same runs without faults.
    let fin = &s["final_rms"];
    for (a, b) in [
        ("position_m", "baseline_position_m"),
        ("attitude_deg", "baseline_attitude_deg"),
    ] {
        let (a, b) = (fin[a].as_f64().unwrap(), fin[b].as_f64().unwrap());
        assert!(a < 1.1 * b, "{fin}");
    }
}

#[test]
fn fault_imu_recovers() {
    let r = analyse(&load("fault-imu"), 6, 7102, false).unwrap();
    let s = &r.summary;
    let did = &s["filter_did"];
    assert_eq!(did["imu_gaps_bridged"].as_u64().unwrap(), 6);
    assert_eq!(did["imu_samples_held"].as_u64().unwrap(), 60);
    assert_eq!(did["imu_samples_clipped"].as_u64().unwrap(), 6 * 100);
    assert_eq!(did["updates_refused"].as_u64().unwrap(), 0);
    // Clipping (3.8 m/s² rectified for 1 s): velocity back within its pre-fault bound.
    let f = &fault(s, "accel_clipping")["velocity_rms_m_s"];
    assert_eq!(f["recovered"], true, "{f}");
    assert!(f["recovery_time_s"].as_f64().unwrap() < 40.0, "{f}");
    // Gap: every metric within its pre-fault bound.
    for m in ["attitude_rms_deg", "velocity_rms_m_s", "position_rms_m"] {
        let f = &fault(s, "imu_gap")[m];
        assert_eq!(f["recovered"], true, "{m}: {f}");
    }
}

fn start() -> Position {
    Position {
        lat_rad: 37f64.to_radians(),
        lon_rad: 127f64.to_radians(),
        alt_m: 1000.0,
    }
}

fn config<T: Real>() -> SeekerInsConfig<T> {
    let start = start();
    let lm = Position {
        lat_rad: start.lat_rad + 2000.0 / 6.378e6,
        lon_rad: start.lon_rad + 70_000.0 / (6.378e6 * 37f64.to_radians().cos()),
        alt_m: 0.0,
    };
    SeekerInsConfig::paper(Landmark::new(lm).unwrap())
}

fn initial<T: Real>() -> SeekerInsInitial<T> {
    let state = InsState {
        position: start(),
        vel_ned_m_s: Vector3::new(T::zero(), T::lit(200.0), T::zero()),
        q_b_n: nalgebra::Quaternion::new(T::one(), T::zero(), T::zero(), T::zero()),
    };
    let mut p0 = SMatrix::<T, 17, 17>::zeros();
    for (i, v) in [1e-11, 1e-11, 100.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-3]
        .iter()
        .enumerate()
    {
        p0[(i, i)] = T::lit(*v);
    }
    for i in 9..17 {
        p0[(i, i)] = T::lit(1e-8);
    }
    SeekerInsInitial {
        state,
        covariance: p0,
    }
}

fn filter_with<T: Real>(cfg: &SeekerInsConfig<T>) -> SeekerIns<T> {
    SeekerIns::new(cfg, &initial()).unwrap()
}

fn filter<T: Real>() -> SeekerIns<T> {
    filter_with(&config())
}

/// Level flight east at 200 m/s: Δv holds gravity off, a small yaw rate.
fn level_at<T: Real>(time_us: u64) -> ImuIncrement<T> {
    ImuIncrement {
        time: Timestamp::from_micros(time_us),
        delta_theta_rad: Vector3::new(T::zero(), T::zero(), T::lit(1e-4)),
        delta_v_m_s: Vector3::new(T::lit(0.01), T::zero(), T::lit(-0.098_066_5)),
    }
}

/// Samples `first..=last` (IMU sample numbers, stamped `t0_us + k × 10 ms`).
fn feed<T: Real>(f: &mut SeekerIns<T>, t0_us: u64, first: u64, last: u64) {
    for k in first..=last {
        f.propagate(&level_at(t0_us + k * DT_US)).unwrap();
    }
}

fn gap_bridges_like_held_samples<T: Real>() {
    let mut f = filter::<T>();
    feed(&mut f, 0, 1, 7);
    // One sample 11 intervals after the last: 10 samples were lost. The filter bridges them
    // with the hold, which moves the INS exactly as 10 real samples equal to the held one.
    let mut real = f;
    let mut gap = f;
    feed(&mut real, 0, 8, 18);
    gap.propagate(&level_at(18 * DT_US)).unwrap();
    assert_eq!(real.state(), gap.state());
    // P grows by the documented (n σ Δt)² on the velocity and attitude diagonals.
    let pol = gap.config().imu_faults;
    let dt = 0.01;
    let dva = (10.0 * pol.gap_accel_sigma_m_s2.to_f64() * dt).powi(2);
    let dwa = (10.0 * pol.gap_rate_sigma_rad_s.to_f64() * dt).powi(2);
    let (pr, pg) = (real.covariance(), gap.covariance());
    let tol = if T::EPS.to_f64() > 1e-10 { 1e-3 } else { 1e-9 };
    for i in 3..6 {
        let d = (pg[(i, i)] - pr[(i, i)]).to_f64();
        assert!((d - dva).abs() <= tol * dva + 1e-6, "vel {i}: {d} vs {dva}");
    }
    for i in 6..9 {
        let d = (pg[(i, i)] - pr[(i, i)]).to_f64();
        assert!(d >= 0.99 * dwa && d <= 1.2 * dwa, "att {i}: {d} vs {dwa}");
    }
    assert_eq!(gap.health().gaps_bridged, 1);
    assert_eq!(gap.seeker_counters().held_samples, 10);
    assert_eq!(gap.health().state, HealthState::Degraded);
    assert_eq!(real.health().gaps_bridged, 0);
    // Jitter up to 1.5 intervals is no gap.
    let mut jit = f;
    jit.propagate(&level_at(7 * DT_US + 14_900)).unwrap();
    assert_eq!(jit.health().gaps_bridged, 0);
    // Clipped sample: same INS step, inflation only of the flagged sensor's block.
    let mut clip = f;
    let mut plain = f;
    let flags = ClipFlags {
        accel: true,
        gyro: false,
    };
    clip.propagate_clipped(&level_at(8 * DT_US), flags).unwrap();
    plain.propagate(&level_at(8 * DT_US)).unwrap();
    assert_eq!(clip.state(), plain.state());
    let (pc, pp) = (clip.covariance(), plain.covariance());
    assert!(pc[(4, 4)] > pp[(4, 4)]);
    assert_eq!(pc[(7, 7)], pp[(7, 7)]);
    assert_eq!(clip.seeker_counters().clipped_samples, 1);
    // Bad clipped sample: refused, nothing changed but the refusal counter.
    let before = clip;
    let mut bad = level_at::<T>(9 * DT_US);
    bad.delta_v_m_s.x = T::lit(f64::NAN);
    assert!(clip.propagate_clipped(&bad, ClipFlags::default()).is_err());
    assert_refused_unchanged(&before, &clip);
}

/// `after` equals `before` but for one more refused IMU sample.
fn assert_refused_unchanged<T: Real>(before: &SeekerIns<T>, after: &SeekerIns<T>) {
    let h = after.health();
    assert_eq!(h.imu_refused, before.health().imu_refused + 1);
    let mut expected = before.health();
    expected.imu_refused = h.imu_refused;
    assert_eq!(h, expected);
    assert_eq!(after.state(), before.state());
    assert_eq!(after.covariance(), before.covariance());
    assert_eq!(after.time(), before.time());
    assert_eq!(after.ins(), before.ins());
    assert_eq!(after.seeker_counters(), before.seeker_counters());
    assert_eq!(
        after.aid_counters(SeekerAid::Los),
        before.aid_counters(SeekerAid::Los)
    );
}

#[test]
fn gaps_and_clipping_f32_f64() {
    gap_bridges_like_held_samples::<f32>();
    gap_bridges_like_held_samples::<f64>();
}

/// A 2 s IMU gap (a policy bridging up to 2.5 s) is bridged by the filter itself: no error,
/// health `Degraded`, the navigation variances grow; with the default policy (0.5 s) the same
/// gap is reset: no error, health `NeedsReinitialisation` until `reinitialise`.
fn two_second_gap<T: Real>() {
    let cfg = SeekerInsConfig {
        imu_faults: ImuFaultPolicy {
            max_gap_s: T::lit(2.5),
            ..ImuFaultPolicy::default()
        },
        ..config::<T>()
    };
    let mut f = filter_with(&cfg);
    feed(&mut f, 0, 1, 100);
    let before = *f.covariance();
    let mut reset = filter::<T>();
    feed(&mut reset, 0, 1, 100);
    // Samples 101..300 lost: the next one is stamped 2.01 s after the last.
    let t = 301 * DT_US;
    f.propagate(&level_at(t)).unwrap();
    let h = f.health();
    assert_eq!(h.state, HealthState::Degraded);
    assert_eq!((h.gaps_bridged, h.gaps_reset), (1, 0));
    assert_eq!(f.seeker_counters().held_samples, 200);
    for i in 0..9 {
        let (a, b) = (f.covariance()[(i, i)], before[(i, i)]);
        assert!(a > b, "state {i}: {a:?} after the gap, {b:?} before");
    }
    // The next regular sample is no gap.
    f.propagate(&level_at(t + DT_US)).unwrap();
    assert_eq!(f.health().gaps_bridged, 1);
    reset.propagate(&level_at(t)).unwrap();
    let h = reset.health();
    assert_eq!(h.state, HealthState::NeedsReinitialisation);
    assert_eq!((h.gaps_bridged, h.gaps_reset), (0, 1));
    reset.propagate(&level_at(t + DT_US)).unwrap();
    reset.reinitialise(&initial()).unwrap();
    reset.propagate(&level_at(t + 2 * DT_US)).unwrap();
    assert_ne!(reset.health().state, HealthState::NeedsReinitialisation);
}

#[test]
fn two_second_gap_f32_f64() {
    two_second_gap::<f32>();
    two_second_gap::<f64>();
}

/// A time stamp that does not increase is refused (`TimeNotIncreasing`) with nothing changed
/// but the refusal counter; the next later sample is accepted. The same for LOS samples.
fn stamps_must_increase<T: Real>() {
    let mut f = filter::<T>();
    feed(&mut f, 0, 1, 20);
    for t in [20 * DT_US, 20 * DT_US - 1, 0] {
        let before = f;
        assert_eq!(f.propagate(&level_at(t)), Err(NavError::TimeNotIncreasing));
        assert_refused_unchanged(&before, &f);
    }
    feed(&mut f, 0, 21, 21);
    assert_eq!(f.time(), Some(Timestamp::from_micros(21 * DT_US)));
    let los = |f: &SeekerIns<T>, time_us: u64| {
        let d = landmark_vector_ned(&f.state().position, &f.config().landmark);
        LosSample {
            time: Timestamp::from_micros(time_us),
            gimbal: gimbal_angles_of(&d.normalize()),
        }
    };
    let s = los(&f, 21 * DT_US);
    f.update_los(&s).unwrap();
    let before = f;
    assert_eq!(f.update_los(&s), Err(NavError::TimeNotIncreasing));
    assert_eq!(f.aid_counters(SeekerAid::Los).refused, 1);
    assert_eq!(f.state(), before.state());
    assert_eq!(f.covariance(), before.covariance());
    // A LOS sample stamped away from the INS time is skipped, not fused.
    let far = los(&f, 40 * DT_US);
    let rep = f.update_los(&far).unwrap();
    assert_eq!(
        rep.skipped,
        Some(nav_core::seeker_ins::LosSkipReason::NotAtInsTime)
    );
}

#[test]
fn stamps_must_increase_f32_f64() {
    stamps_must_increase::<f32>();
    stamps_must_increase::<f64>();
}

/// The same samples stamped from 0 s and from 10⁶ s after the epoch: the same bits (intervals
/// are integer differences; no time stamp is held in a float).
fn late_clock_same_bits<T: Real>() {
    let run = |t0_us: u64| {
        let mut f = filter::<T>();
        for k in 1..=300u64 {
            // Irregular stamps, a gap at k = 150.
            let t = t0_us + k * DT_US + (k % 3) * 1_000 + u64::from(k > 150) * 40_000;
            f.propagate(&level_at(t)).unwrap();
            if k % 10 == 0 {
                let d = landmark_vector_ned(&f.state().position, &f.config().landmark);
                let u = nalgebra::Rotation3::from_euler_angles(0.0, 0.0, 0.001).matrix()
                    * d.normalize().map(|v| v.to_f64());
                let s = LosSample {
                    time: Timestamp::from_micros(t),
                    gimbal: gimbal_angles_of(&u.map(T::lit)),
                };
                f.update_los(&s).unwrap();
            }
        }
        f
    };
    let (a, b) = (run(0), run(1_000_000 * 1_000_000));
    assert_eq!(a.state(), b.state());
    assert_eq!(a.covariance(), b.covariance());
    assert_eq!(a.gyro_bias_rad_s(), b.gyro_bias_rad_s());
    let strip = |h: Health| (h.state, h.gaps_bridged, h.limits_hit);
    assert_eq!(strip(a.health()), strip(b.health()));
    assert_eq!(a.health().gaps_bridged, 1);
    assert_eq!(
        a.aid_counters(SeekerAid::Los),
        b.aid_counters(SeekerAid::Los)
    );
}

#[test]
fn late_clock_same_bits_f32_f64() {
    late_clock_same_bits::<f32>();
    late_clock_same_bits::<f64>();
}

//! Fault injection of the seeker-aided INS: the `fault-seeker` and `fault-imu`
//! scenarios at a reduced run count recover, and the IMU-gap API refuses bad calls without
//! damage and bridges a gap like the held samples would.

use nalgebra::{SMatrix, Vector3};
use nav_core::seeker_ins::{
    ClipFlags, ImuIncrement, InsState, Landmark, LosResidual, Position, SeekerIns, SeekerInsConfig,
};
use nav_core::time::Timestamp;
use nav_core::{NavError, Real};
use nav_sim::scenarios::seeker_ins::fault::{analyse, load_fault_config, FaultConfig, Summary};

/// `inc` stamped one nominal IMU interval after the filter's last sample (the first sample at
/// one interval after the epoch): a regular-rate IMU clock.
fn stamped<T: Real>(f: &SeekerIns<T>, mut inc: ImuIncrement<T>) -> ImuIncrement<T> {
    let dt_us = f.ins().dt_us();
    inc.time = f
        .ins()
        .time()
        .map_or(Timestamp::from_micros(dt_us), |t| t.add_micros(dt_us));
    inc
}

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

fn filter<T: Real>() -> SeekerIns<T> {
    let start = Position {
        lat_rad: 37f64.to_radians(),
        lon_rad: 127f64.to_radians(),
        alt_m: 1000.0,
    };
    let lm = Position {
        lat_rad: start.lat_rad + 2000.0 / 6.378e6,
        lon_rad: start.lon_rad + 70_000.0 / (6.378e6 * 37f64.to_radians().cos()),
        alt_m: 0.0,
    };
    let cfg = SeekerInsConfig {
        imu_dt_s: T::lit(0.01),
        covariance_interval_steps: 10,
        accel_noise_density_m_s2_rt_hz: T::lit(5e-5),
        gyro_noise_density_rad_s_rt_hz: T::lit(3e-6),
        seeker_noise_rad: T::lit(0.003),
        gate_nis: T::lit(16.0),
        landmark: Landmark::new(lm).unwrap(),
        residual: LosResidual::Projected2d,
    };
    let init = InsState {
        position: start,
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
    SeekerIns::new(cfg, init, &p0).unwrap()
}

fn level_increment<T: Real>() -> ImuIncrement<T> {
    ImuIncrement {
        time: Timestamp::ZERO,
        delta_theta_rad: Vector3::new(T::zero(), T::zero(), T::lit(1e-4)),
        delta_v_m_s: Vector3::new(T::lit(0.01), T::zero(), T::lit(-0.098_066_5)),
    }
}

fn gap_api<T: Real>() {
    let mut f = filter::<T>();
    // Nothing to hold before the first sample.
    let before = format!("{f:?}");
    assert!(matches!(
        f.propagate_gap(3),
        Err(NavError::InputOutOfRange { .. })
    ));
    assert_eq!(before, format!("{f:?}"));
    let inc = level_increment::<T>();
    for _ in 0..7 {
        f.propagate(&stamped(&f, inc)).unwrap();
    }
    let before = format!("{f:?}");
    let max = f.imu_fault_policy().max_gap_samples;
    for n in [0, max + 1, u16::MAX] {
        assert_eq!(f.propagate_gap(n), Err(NavError::InvalidTimeStep));
        assert_eq!(before, format!("{f:?}"));
    }
    // A gap of 10 held samples moves the INS exactly as 10 real samples equal to the held
    // one; P grows by the documented (n σ Δt)² on the velocity and attitude diagonals.
    let mut real = f;
    let mut gap = f;
    for _ in 0..10 {
        real.propagate(&stamped(&real, inc)).unwrap();
    }
    gap.propagate_gap(10).unwrap();
    assert_eq!(real.state(), gap.state());
    let pol = gap.imu_fault_policy();
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
    let c = gap.imu_fault_counters();
    assert_eq!((c.gaps, c.held_samples), (1, 10));
    // Clipped sample: same INS step, inflation only of the flagged sensor's block.
    let mut clip = f;
    let mut plain = f;
    clip.propagate_clipped(
        &stamped(&clip, inc),
        ClipFlags {
            accel: true,
            gyro: false,
        },
    )
    .unwrap();
    plain.propagate(&stamped(&plain, inc)).unwrap();
    assert_eq!(clip.state(), plain.state());
    let (pc, pp) = (clip.covariance(), plain.covariance());
    assert!(pc[(4, 4)] > pp[(4, 4)]);
    assert_eq!(pc[(7, 7)], pp[(7, 7)]);
    assert_eq!(clip.imu_fault_counters().clipped_samples, 1);
    // Bad clipped sample: refused, unchanged.
    let before = format!("{clip:?}");
    let mut bad = inc;
    bad.delta_v_m_s.x = T::lit(f64::NAN);
    assert!(clip
        .propagate_clipped(&stamped(&clip, bad), ClipFlags::default())
        .is_err());
    assert_eq!(before, format!("{clip:?}"));
}

#[test]
fn gap_and_clip_api_f32_f64() {
    gap_api::<f32>();
    gap_api::<f64>();
}

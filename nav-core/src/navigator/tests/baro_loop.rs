//! The baro-inertial loop in the navigator: its vertical input (specific force plus the
//! Coriolis and transport-rate terms) and its start from the EKF's vertical covariance.

use super::super::baro::{loop_vertical_input_m_s2, start_inertial_loop};
use super::*;
use crate::contract::Estimator;
use crate::earth::{earth_rate_ned, normal_gravity_m_s2, transport_rate_ned};
use crate::seeker_ins::Position;
use crate::vertical_channel::{ClassicalConfig, ClassicalLoop, ImuSample, InitialState};

/// The input is `−f_D + [(2ω_ie + ω_en) × v]_D`, computed here from the earth module's rate
/// vectors (another code path), and the upward specific force of level flight over the
/// ellipsoid (`f = (2ω_ie + ω_en) × v − g`, as the test world flies) turns into g(h).
#[test]
fn loop_input_is_the_ins_vertical_acceleration() {
    for (lat_deg, v) in [
        (37.0, Vector3::new(0.0, 200.0, 0.0)),
        (-60.0, Vector3::new(150.0, -120.0, 20.0)),
        (5.0, Vector3::new(-250.0, 40.0, -30.0)),
        (80.0, Vector3::new(30.0, 300.0, 0.0)),
    ] {
        let lat: f64 = f64::to_radians(lat_deg);
        let alt = 1500.0;
        let state = InsState {
            position: Position {
                lat_rad: lat,
                lon_rad: 2.0,
                alt_m: alt,
            },
            vel_ned_m_s: v,
            q_b_n: Quaternion::identity(),
        };
        let w = earth_rate_ned(lat) * 2.0 + transport_rate_ned(lat, alt, &v);
        let g = normal_gravity_m_s2(lat, alt);
        let f_level = w.cross(&v) - Vector3::new(0.0, 0.0, g);
        let got = loop_vertical_input_m_s2(&state, &f_level);
        assert!((got - g).abs() < 1e-12, "{lat_deg}°: {got} vs g {g}");
        let f = Vector3::new(0.3, -1.2, -9.1);
        let reference = -f.z + w.cross(&v).z;
        assert!((loop_vertical_input_m_s2(&state, &f) - reference).abs() < 1e-12);
    }
}

/// The mission's loop (τ 20 s, baro at 25 Hz, σ for a 220 µg vertical accelerometer error)
/// started from a tight (h, V_z) covariance, flown level east at 200 m/s at 37° on an exact
/// baro: fed the navigator's input its V̂_z stays within 3σ; fed the specific force alone it
/// leaves 3σ (the 2.9 mg the loop would miss is thirteen times its accelerometer σ).
fn level_east_flight<T: Real>() {
    let lat = 37.0f64.to_radians();
    let alt = 1000.0;
    let v = Vector3::new(0.0, 200.0, 0.0);
    let state = InsState {
        position: Position {
            lat_rad: lat,
            lon_rad: 2.2,
            alt_m: alt,
        },
        vel_ned_m_s: v.map(T::lit),
        q_b_n: Quaternion::identity(),
    };
    let w = earth_rate_ned(lat) * 2.0 + transport_rate_ned(lat, alt, &v);
    let f_ned = (w.cross(&v) - Vector3::new(0.0, 0.0, normal_gravity_m_s2(lat, alt))).map(T::lit);
    let mut cfg = ClassicalConfig::<T>::paper();
    cfg.latitude_rad = T::lit(lat);
    cfg.baro_lag_s = T::zero();
    cfg.error_model.accel_noise_m_s2_rt_hz = T::lit(5e-6 * 9.806_65);
    cfg.error_model.accel_bias_sigma_m_s2 = T::lit(220e-6 * 9.806_65);
    let worst = |input: T| -> f64 {
        let init = InitialState {
            time: Timestamp::from_micros(0),
            altitude_m: T::lit(alt),
            vz_up_m_s: T::zero(),
            accel_bias_m_s2: T::zero(),
        };
        let mut lp = ClassicalLoop::new(&cfg, &init).unwrap();
        let c = nalgebra::Matrix2::new(T::lit(25.0), T::zero(), T::zero(), T::lit(0.0064));
        lp.set_covariance_h_vz(&c).unwrap();
        let mut worst = 0.0f64;
        for k in 1..=6000u64 {
            let time = Timestamp::from_micros(k * DT_US);
            let imu = ImuSample {
                time,
                specific_force_up_m_s2: input,
            };
            let baro = (k % 4 == 0).then(|| BaroSample {
                time,
                altitude_m: T::lit(alt),
            });
            lp.step(&imu, baro.as_ref()).unwrap();
            let e = lp.vz_up_m_s().to_f64().abs() / lp.sigma().vz_m_s.to_f64();
            worst = worst.max(e);
        }
        worst
    };
    let with_coriolis = worst(loop_vertical_input_m_s2(&state, &f_ned));
    let specific_force_only = worst(-f_ned.z);
    assert!(
        with_coriolis < 3.0,
        "navigator input: |δV_z|/σ up to {with_coriolis}"
    );
    assert!(
        specific_force_only > 3.0,
        "specific force alone: |δV_z|/σ only up to {specific_force_only}"
    );
    std::println!(
        "{}: worst |δV_z|/σ over 60 s: {with_coriolis:.3} (navigator input), \
         {specific_force_only:.2} (specific force alone)",
        core::any::type_name::<T>()
    );
}

#[test]
fn loop_holds_level_flight_east_within_its_sigma_f64() {
    level_east_flight::<f64>();
}

#[test]
fn loop_holds_level_flight_east_within_its_sigma_f32() {
    level_east_flight::<f32>();
}

/// At the start of midcourse the loop takes the INS's ĥ, V̂_z and the EKF's (δh, δV_D)
/// covariance (`δV_z = −δV_D`), not the error model's initial σ.
fn start_from_the_ekf<T: Real>() {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let mut p0 = crate::seeker_ins::paper_initial_covariance::<T>();
    let (ih, iv) = (POS + 2, VEL + 2);
    p0[(ih, iv)] = T::lit(0.3) * (p0[(ih, ih)] * p0[(iv, iv)]).sqrt();
    p0[(iv, ih)] = p0[(ih, iv)];
    let init = SeekerInsInitial {
        state: InsState {
            position: START,
            vel_ned_m_s: Vector3::new(T::lit(SPEED_M_S), T::lit(10.0), T::lit(-5.0)),
            q_b_n: Quaternion::identity(),
        },
        covariance: p0,
    };
    let ekf = SeekerIns::<T>::new(&cfg.ins, &init).unwrap();
    let mut vc = ClassicalConfig::<T>::paper();
    vc.latitude_rad = T::lit(START.lat_rad);
    let design = ClassicalLoop::design(&vc).unwrap();
    let time = Timestamp::from_micros(123_000);
    let lp = start_inertial_loop(&vc, &design, &ekf, time).unwrap();
    let p = ekf.covariance();
    let c = lp.covariance_h_vz();
    assert_eq!(c.m11, p[(ih, ih)]);
    assert_eq!(c.m22, p[(iv, iv)]);
    assert_eq!(c.m12, -p[(ih, iv)]);
    assert_eq!(c.m21, -p[(ih, iv)]);
    assert!(p[(ih, iv)] != T::zero());
    assert_eq!(lp.altitude_m(), T::lit(ekf.state().position.alt_m));
    assert_eq!(lp.vz_up_m_s(), -ekf.state().vel_ned_m_s.z);
    // The error model's initial σ (the loop without the seeding) is another covariance.
    let em = vc.error_model;
    assert!(c.m22 != em.initial_vz_sigma_m_s * em.initial_vz_sigma_m_s);
}

#[test]
fn loop_starts_from_the_ekf_vertical_covariance_f64() {
    start_from_the_ekf::<f64>();
}

#[test]
fn loop_starts_from_the_ekf_vertical_covariance_f32() {
    start_from_the_ekf::<f32>();
}

use super::*;
use crate::rng::run_rng;
use crate::scenarios::mission::truth::simulate;
use crate::truth::{gimbal_angles_rad, landmark_vector_ned_m};

pub(crate) fn load(name: &str) -> MissionConfig {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(path).unwrap()).unwrap();
    for k in [
        "kind",
        "description",
        "runs",
        "seed",
        "navigator",
        "variants",
    ] {
        doc.remove(k);
    }
    MissionConfig::deserialize(toml::Value::Table(doc)).unwrap()
}

const RUNS: u64 = 200;

/// One truth (the sensors' statistics do not depend on the flexure draw) and the inputs of
/// `RUNS` sensor draws over it.
fn draws(faults: &MissionFaults) -> (MissionConfig, MissionTruth, Vec<MissionInputs>) {
    let cfg = load("mission");
    let truth = simulate(
        &cfg.profile,
        &cfg.carry,
        cfg.imu_dt_us(),
        &mut run_rng(5, 0),
    )
    .unwrap();
    let runs = (0..RUNS)
        .map(|r| inputs(&cfg, &truth, faults, &mut run_rng(77, r)).unwrap())
        .collect();
    (cfg, truth, runs)
}

fn std(x: &[f64]) -> f64 {
    let m = x.iter().sum::<f64>() / x.len() as f64;
    (x.iter().map(|v| (v - m) * (v - m)).sum::<f64>() / (x.len() - 1) as f64).sqrt()
}

fn mean(x: &[f64]) -> f64 {
    x.iter().sum::<f64>() / x.len() as f64
}

fn ecef(p: &Position) -> Vector3<f64> {
    crate::truth::geodetic_to_ecef(p.lat_rad, p.lon_rad, p.alt_m)
}

/// The master's messages: their errors against the aircraft's truth have the σ the master
/// reports (per axis, over runs and epochs) and its correlation time; the bus delivers
/// them in order, 10-100 ms late, loses ≈ 1 %, and nothing after the release.
#[test]
fn master_messages_carry_the_errors_they_report_late_and_sometimes_lost() {
    let (cfg, truth, runs) = draws(&MissionFaults::default());
    let air = &truth.aircraft;
    let dt_us = cfg.imu_dt_us();
    let mut err: [Vec<f64>; 9] = Default::default();
    let (mut sent, mut delivered, mut latency) = (0usize, 0usize, Vec::new());
    let mut pairs = Vec::new();
    for inp in &runs {
        sent += inp.master_errors.len();
        let mut last_arrival = Timestamp::ZERO;
        for tick in &inp.ticks {
            for msg in &tick.master {
                delivered += 1;
                let j = (msg.time.as_micros() / dt_us) as usize;
                assert!(j <= truth.release_index, "master message after release");
                assert!(msg.arrival >= last_arrival, "out of order");
                last_arrival = msg.arrival;
                let at = tick.imu.time.as_micros();
                assert!(at >= msg.arrival.as_micros() && at < msg.arrival.as_micros() + dt_us);
                latency.push((msg.arrival.as_micros() - msg.time.as_micros()) as f64 * 1e-6);
                // Attitude: Ĉ = exp(−[φ×]) C → φ = −log(Ĉ Cᵀ).
                let phi =
                    -crate::truth::vector_from_rotation(&(msg.c_m_n * air.c_b_n[j].transpose()));
                let dv = msg.vel_ned_m_s - air.vel_ned_m_s[j];
                let p = &air.position[j];
                let dr = crate::truth::ecef_to_ned(p.lat_rad, p.lon_rad)
                    * (ecef(&msg.position) - ecef(p));
                for a in 0..3 {
                    err[a].push(phi[a] / msg.attitude_sigma_rad[a]);
                    err[3 + a].push(dv[a] / msg.velocity_sigma_m_s[a]);
                    err[6 + a].push(dr[a] / msg.position_sigma_m[a]);
                }
            }
        }
        // Correlation over 60 s of the recorded errors (velocity north, normalised).
        let lag = (60.0 * cfg.master.rate_hz) as usize;
        for w in 0..inp.master_errors.len().saturating_sub(lag) {
            let a = inp.master_errors[w].1[1].x / cfg.master.velocity_sigma_m_s[0];
            let b = inp.master_errors[w + lag].1[1].x / cfg.master.velocity_sigma_m_s[0];
            pairs.push((a, b));
        }
    }
    for (i, e) in err.iter().enumerate() {
        let s = (e.iter().map(|v| v * v).sum::<f64>() / e.len() as f64).sqrt();
        assert!(
            (0.88..1.12).contains(&s),
            "component {i}: error / reported σ = {s}"
        );
    }
    let r = pairs.iter().map(|(a, b)| a * b).sum::<f64>() / pairs.len() as f64;
    let expect = (-60.0 / cfg.master.error_tau_s).exp();
    assert!(
        (r - expect).abs() < 0.1,
        "correlation over 60 s {r}, expected {expect}"
    );
    let lost = 1.0 - delivered as f64 / sent as f64;
    assert!((0.007..0.013).contains(&lost), "lost fraction {lost}");
    let (lo, hi) = (cfg.master.latency_s[0], cfg.master.latency_s[1]);
    assert!(latency.iter().all(|l| *l >= lo - 1e-6 && *l <= hi + 1e-6));
    // A FIFO bus: a message waits for the one before it, so the mean is above the
    // uniform draw's (measured 63 ms for 10-100 ms at 50 Hz).
    let m = mean(&latency);
    assert!(m > 0.5 * (lo + hi) + 0.002 && m < hi, "mean latency {m}");
}

/// The missile IMU: after the drawn scale factor, misalignment and bias are taken out of
/// the increments, what remains is white with the Table 3 density; across runs the drawn
/// biases, scale factors and misalignments have the Table 3 σ.
#[test]
fn missile_imu_has_the_table3_errors() {
    let (cfg, truth, runs) = draws(&MissionFaults::default());
    let s = &cfg.sensors;
    let g0 = 9.806_65;
    let h = 1.0 / cfg.imu_hz;
    let (mut wv, mut wth, mut lag1) = (Vec::new(), Vec::new(), 0.0);
    let mut prev: Option<f64> = None;
    for inp in runs.iter().take(20) {
        for tick in &inp.ticks {
            let inc = &truth.missile.imu[tick.index];
            let rv =
                tick.imu.delta_v_m_s - inp.accel_matrix * inc.delta_v_m_s - inp.accel_bias_m_s2 * h;
            let rt = tick.imu.delta_theta_rad
                - inp.gyro_matrix * inc.delta_theta_rad
                - inp.gyro_bias_rad_s * h;
            if let Some(p) = prev {
                lag1 += p * rv.x;
            }
            prev = Some(rv.x);
            wv.extend(rv.iter());
            wth.extend(rt.iter());
        }
    }
    let sd_v = s.accel_noise_ug_rt_hz * 1e-6 * g0 * h.sqrt();
    let sd_th = s.gyro_arw_deg_rt_h.to_radians() / 60.0 * h.sqrt();
    assert!(
        (std(&wv) / sd_v - 1.0).abs() < 0.02,
        "{} vs {sd_v}",
        std(&wv)
    );
    assert!((std(&wth) / sd_th - 1.0).abs() < 0.02);
    let rho = lag1 / (wv.len() as f64 / 3.0) / (sd_v * sd_v);
    assert!(
        rho.abs() < 0.03,
        "lag-1 correlation of the accelerometer noise {rho}"
    );
    let pick = |f: &dyn Fn(&MissionInputs) -> Vec<f64>| -> f64 {
        std(&runs.iter().flat_map(f).collect::<Vec<_>>())
    };
    let checks = [
        (
            pick(&|r| r.accel_bias_m_s2.iter().copied().collect()),
            s.accel_bias_ug * 1e-6 * g0,
        ),
        (
            pick(&|r| r.gyro_bias_rad_s.iter().copied().collect()),
            s.gyro_bias_deg_h.to_radians() / 3600.0,
        ),
        (
            pick(&|r| (0..3).map(|i| r.accel_matrix[(i, i)] - 1.0).collect()),
            s.accel_scale_factor_ppm * 1e-6,
        ),
        (
            pick(&|r| vec![r.gyro_matrix[(0, 1)], r.gyro_matrix[(2, 0)]]),
            s.gyro_misalignment_arcsec.to_radians() / 3600.0,
        ),
    ];
    for (i, (got, want)) in checks.iter().enumerate() {
        assert!(
            (got / want - 1.0).abs() < 0.12,
            "check {i}: {got} vs {want}"
        );
    }
}

/// The baro: in level cruise its error has the σ of the correlated and white parts and no
/// mean; in the steady descent the lag shows as a mean error of −lag · ḣ.
#[test]
fn baro_has_correlated_error_white_noise_and_lag() {
    let (cfg, truth, runs) = draws(&MissionFaults::default());
    let m = &truth.missile;
    let (mut level, mut descent, mut lag_expect) = (Vec::new(), Vec::new(), Vec::new());
    for inp in &runs {
        for tick in &inp.ticks {
            let Some(b) = tick.baro else { continue };
            let k = tick.index;
            let e = b.altitude_m - m.position[k].alt_m;
            let t = m.t_s[k];
            if (170.0..310.0).contains(&t) {
                level.push(e);
            }
            if (105.0..135.0).contains(&t) {
                descent.push(e);
                lag_expect.push(cfg.baro.lag_s * m.vel_ned_m_s[k].z);
            }
        }
    }
    let want = cfg.baro.markov_sigma_m.hypot(cfg.baro.noise_m);
    assert!(
        (std(&level) / want - 1.0).abs() < 0.1,
        "{} vs {want}",
        std(&level)
    );
    assert!(mean(&level).abs() < 0.5, "level mean {}", mean(&level));
    let lag = mean(&lag_expect);
    assert!(
        lag > 4.0,
        "the descent is steep enough to show the lag: {lag} m"
    );
    let d = mean(&descent);
    assert!(
        (d - lag).abs() < 0.6,
        "descent mean error {d} vs lag × sink rate {lag}"
    );
}

/// The seeker reports only while locked: after the landmark has been in range and in the
/// field of regard for the acquisition time; its angles carry the drawn random-constant
/// error and white noise of Table 3.
#[test]
fn seeker_reports_only_in_lock_with_table3_errors() {
    let (cfg, truth, runs) = draws(&MissionFaults::default());
    let m = &truth.missile;
    let lm = cfg.landmark_position();
    let los = |k: usize| {
        let p = &m.position[k];
        landmark_vector_ned_m(
            (p.lat_rad, p.lon_rad, p.alt_m),
            (lm.lat_rad, lm.lon_rad, lm.alt_m),
        )
    };
    // First time the landmark is in range, from the truth.
    let in_range_s = (0..m.t_s.len())
        .find(|k| los(*k).norm() <= cfg.seeker.lock_range_m)
        .map(|k| m.t_s[k])
        .unwrap();
    let mut resid = Vec::new();
    let mut bias_err = Vec::new();
    for inp in &runs {
        let first = inp.first_lock_s.unwrap();
        assert!(
            first >= in_range_s + cfg.seeker.acquire_s - 1e-6
                && first < in_range_s + cfg.seeker.acquire_s + 1.0 / cfg.seeker.rate_hz + 1e-6,
            "first lock {first}, in range {in_range_s}"
        );
        let mut e = Vec::new();
        for tick in &inp.ticks {
            let Some(s) = tick.seeker else { continue };
            let k = tick.index;
            assert!(m.t_s[k] >= first - 1e-9);
            let d = los(k);
            assert!(d.norm() <= cfg.seeker.lock_range_m);
            let (p, y) = gimbal_angles_rad(&(m.c_b_n[k].transpose() * d));
            e.push((s.gimbal.pitch_rad - p, s.gimbal.yaw_rad - y));
        }
        assert!(e.len() > 500, "{} seeker samples", e.len());
        let mp = mean(&e.iter().map(|v| v.0).collect::<Vec<_>>());
        bias_err.push(mp - inp.gimbal_bias_rad[0]);
        resid.extend(e.iter().map(|v| v.0 - inp.gimbal_bias_rad[0]));
        resid.extend(e.iter().map(|v| v.1 - inp.gimbal_bias_rad[1]));
    }
    let sd = cfg.sensors.seeker_noise_deg.to_radians();
    assert!(
        (std(&resid) / sd - 1.0).abs() < 0.03,
        "{} vs {sd}",
        std(&resid)
    );
    // The per-run mean error is the drawn bias (to the noise's σ/√n).
    assert!(std(&bias_err) < 0.2 * cfg.sensors.seeker_bias_deg.to_radians());
}

/// Faults in the chain: messages valid in a missing window never arrive, late ones arrive
/// late; an IMU gap removes its ticks but hands the aids that came during it to the next
/// tick; a baro freeze holds the reading and a spike offsets it; every other number is the
/// baseline's.
#[test]
fn injected_faults_change_only_what_they_inject() {
    let cfg = load("mission");
    let truth = simulate(
        &cfg.profile,
        &cfg.carry,
        cfg.imu_dt_us(),
        &mut run_rng(5, 0),
    )
    .unwrap();
    let base = inputs(&cfg, &truth, &MissionFaults::default(), &mut run_rng(3, 1)).unwrap();
    let faults = MissionFaults {
        imu_seeker: Faults {
            imu_gap: vec![[30.0, 0.5]],
            ..Faults::default()
        },
        master_late: vec![ValueWindow {
            start_s: 40.0,
            duration_s: 2.0,
            value: 0.3,
        }],
        master_missing: vec![[50.0, 3.0]],
        baro_spike: vec![ValueWindow {
            start_s: 120.0,
            duration_s: 1.0,
            value: 50.0,
        }],
        baro_freeze: vec![[150.0, 5.0]],
    };
    let f = inputs(&cfg, &truth, &faults, &mut run_rng(3, 1)).unwrap();
    assert_eq!(base.ticks.len() - f.ticks.len(), 50, "0.5 s gap at 100 Hz");
    let msgs = |i: &MissionInputs| -> Vec<MasterMessage> {
        i.ticks.iter().flat_map(|t| t.master.clone()).collect()
    };
    let (mb, mf) = (msgs(&base), msgs(&f));
    let missing = mb
        .iter()
        .filter(|m| (50.0..53.0).contains(&m.time.as_secs_f64()))
        .count();
    assert!(missing > 100);
    assert_eq!(
        mb.len() - mf.len(),
        missing,
        "the gap loses no master message"
    );
    for m in &mf {
        let t = m.time.as_secs_f64();
        assert!(!(50.0..53.0 - 1e-9).contains(&t));
        let late = (m.arrival.as_micros() - m.time.as_micros()) as f64 * 1e-6;
        if (40.0..42.0 - 1e-9).contains(&t) {
            assert!(late >= 0.31 - 1e-6, "late by {late}");
        }
    }
    let baro = |i: &MissionInputs, t: f64| {
        i.ticks
            .iter()
            .filter_map(|k| k.baro)
            .find(|b| (b.time.as_secs_f64() - t).abs() < 1e-6)
            .unwrap()
            .altitude_m
    };
    assert!((baro(&f, 120.4) - baro(&base, 120.4) - 50.0).abs() < 1e-9);
    assert_eq!(baro(&f, 151.0), baro(&f, 154.0));
    assert_eq!(baro(&f, 200.0), baro(&base, 200.0));
}

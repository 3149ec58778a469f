//! Stress campaign of the seeker-aided INS (public API only, mostly f32).
//!
//! Each case flies a truth INS (`f64`, fed perfect increments) on a 20 km circle around the
//! landmark with random manoeuvres (bursts up to ±30 m/s² and ±0.5 rad/s, damped towards
//! 200 m/s, level, 1 km), and feeds the filter what a flight computer would: increments with
//! bias and noise, IMU gaps (bridged by `propagate_gap`), clipped bursts (`propagate_clipped`,
//! the sensed increment wrong by up to the policy σ), and seeker gimbal angles with bias and
//! noise when the landmark is in the gimbal's field and the scenario's sighting schedule says
//! so. Configurations and policies are the extremes of the documented ranges (hostile but
//! legal). Every call is valid input, so every `Err` counts as a refusal; P is checked after
//! every covariance propagation interval and every LOS update, every output for finiteness.

use super::{EstimatorStress, StressLevel, Tally};
use crate::rng::{gauss, run_rng, SimRng};
use nalgebra::{SMatrix, Vector3};
use nav_core::contract::{Estimator, Gate, RecoveryAction, RecoveryPolicy};
use nav_core::math::rotation::{dcm_to_euler, dcm_to_quat, euler_to_dcm, quat_to_dcm};
use nav_core::seeker_ins::{
    default_recovery, gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles,
    ImuFaultPolicy, ImuIncrement, Ins, InsState, Landmark, LosResidual, LosSample, Position,
    SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsInitial,
};
use nav_core::time::Timestamp;
use nav_core::{HealthState, Real};
use rayon::prelude::*;

const LAT0: f64 = 0.645_771_823_237_901_2; // 37°
const LON0: f64 = 2.216_568_150_032_737; // 127°
/// Radius of the circle flown around the landmark, m.
const CIRCLE_RADIUS_M: f64 = 20_000.0;
/// Truth sensor errors: accelerometer and gyro white noise densities, biases, seeker noise and
/// bias (1σ).
const ACCEL_DENSITY: f64 = 5e-5;
const GYRO_DENSITY: f64 = 3e-6;
const ACCEL_BIAS_M_S2: f64 = 1e-3;
const GYRO_BIAS_RAD_S: f64 = 5e-8;
const SEEKER_NOISE_RAD: f64 = 0.003;
const SEEKER_BIAS_RAD: f64 = 7e-4;
/// Largest gimbal pitch at which the seeker sees the landmark, rad (the model's ±80°, less a
/// margin for the noise).
const GIMBAL_PITCH_LIMIT_RAD: f64 = 1.35;

/// When the seeker sees the landmark.
#[derive(Debug, Clone, Copy)]
enum Sightings {
    /// Every seeker epoch (10 Hz of the IMU time), with a 30 s loss of lock and a 10 s false
    /// lock 2° off every 200 s.
    Continuous,
    /// `on_s` seconds in every `period_s`.
    Rare { on_s: f64, period_s: f64 },
}

/// IMU faults.
#[derive(Debug, Clone, Copy)]
enum Faults {
    None,
    /// A gap of the policy's maximum every `every_s`.
    Gaps {
        every_s: f64,
    },
    /// `samples` consecutive clipped samples (accelerometer and gyro) every `every_s`.
    Clipping {
        samples: u32,
        every_s: f64,
    },
    /// Both.
    Mixed,
}

#[derive(Debug, Clone)]
struct Case {
    name: String,
    steps: u64,
    seed: u64,
    imu_dt_s: f64,
    covariance_interval_steps: u16,
    accel_density: f64,
    gyro_density: f64,
    seeker_noise_rad: f64,
    gate_nis: f64,
    policy: ImuFaultPolicy<f64>,
    recovery: RecoveryPolicy<f64>,
    sightings: Sightings,
    faults: Faults,
    /// Extra vertical accelerometer error the filter does not model, m/s² (drives the
    /// unaided vertical channel away).
    vertical_accel_error_m_s2: f64,
    /// Landmark height relative to the circle's altitude, m, and whether it lies on the
    /// circle (overflown: ranges below the minimum) instead of at its centre.
    landmark_on_path: bool,
    landmark_alt_m: f64,
    /// Call `reinitialise` (truth + 100 m / 5 m/s / 2° errors) at a sighting when the health
    /// is `NeedsReinitialisation`.
    reinitialise: bool,
    /// Run in f64 instead of f32.
    f64: bool,
}

fn default_policy() -> ImuFaultPolicy<f64> {
    ImuFaultPolicy::default()
}

/// Near the extremes of the documented ranges for a 100 Hz IMU: a 1 s gap with the largest σ
/// the joint conditions allow for it, the largest clipping σ.
fn extreme_policy(dt: f64) -> ImuFaultPolicy<f64> {
    let gap_s = (1.0 / dt).round().min(500.0) * dt;
    ImuFaultPolicy {
        max_gap_s: gap_s,
        gap_accel_sigma_m_s2: 100.0 / gap_s,
        gap_rate_sigma_rad_s: 1.0 / gap_s,
        clip_accel_sigma_m_s2: 1000.0,
        clip_rate_sigma_rad_s: 50.0,
    }
}

/// σ = 0 everywhere (legal: the filter then trusts held and clipped samples).
fn zero_policy() -> ImuFaultPolicy<f64> {
    ImuFaultPolicy {
        max_gap_s: 1.0,
        gap_accel_sigma_m_s2: 0.0,
        gap_rate_sigma_rad_s: 0.0,
        clip_accel_sigma_m_s2: 0.0,
        clip_rate_sigma_rad_s: 0.0,
    }
}

fn cases(level: StressLevel) -> Vec<Case> {
    let full = level == StressLevel::Full;
    let long = if full { 1_000_000 } else { 120_000 };
    let medium = if full { 300_000 } else { 40_000 };
    let base = Case {
        name: String::new(),
        steps: medium,
        seed: 0,
        imu_dt_s: 0.01,
        covariance_interval_steps: 10,
        accel_density: ACCEL_DENSITY,
        gyro_density: GYRO_DENSITY,
        seeker_noise_rad: SEEKER_NOISE_RAD,
        gate_nis: 16.0,
        policy: default_policy(),
        recovery: default_recovery(),
        sightings: Sightings::Continuous,
        faults: Faults::None,
        vertical_accel_error_m_s2: 0.0,
        landmark_on_path: false,
        landmark_alt_m: 0.0,
        reinitialise: false,
        f64: false,
    };
    // Inflation at the first fully rejected LOS sample (0.1 s after the one before).
    let hostile_recovery = RecoveryPolicy {
        starved_after_s: Some(0.1),
        action: RecoveryAction::Inflate {
            variance_factor: 100.0,
        },
    };
    let rare = Sightings::Rare {
        on_s: 20.0,
        period_s: 1000.0,
    };
    let mut v = vec![
        Case {
            name: "nominal 100 Hz, continuous LOS with loss and false lock".into(),
            ..base.clone()
        },
        Case {
            name: "rare landmark (20 s per 1000 s), vertical accel error 0.02 m/s²".into(),
            steps: long,
            sightings: rare,
            vertical_accel_error_m_s2: 0.02,
            ..base.clone()
        },
        Case {
            name: "rare landmark, vertical accel error 0.5 m/s² (position leaves the range)".into(),
            steps: long,
            sightings: rare,
            vertical_accel_error_m_s2: 0.5,
            ..base.clone()
        },
        Case {
            name: "rare landmark, vertical error 0.5 m/s², reinitialise when needed".into(),
            steps: long,
            sightings: rare,
            vertical_accel_error_m_s2: 0.5,
            reinitialise: true,
            ..base.clone()
        },
        Case {
            name: "long clipping (6000 consecutive), default policy".into(),
            faults: Faults::Clipping {
                samples: 6000,
                every_s: 150.0,
            },
            ..base.clone()
        },
        Case {
            name: "long clipping (6000 consecutive), extreme policy, hostile recovery".into(),
            faults: Faults::Clipping {
                samples: 6000,
                every_s: 150.0,
            },
            policy: extreme_policy(0.01),
            recovery: hostile_recovery,
            ..base.clone()
        },
        Case {
            name: "long gaps (1 s every 5 s), extreme policy".into(),
            faults: Faults::Gaps { every_s: 5.0 },
            policy: extreme_policy(0.01),
            ..base.clone()
        },
        Case {
            name: "gaps and clipping, zero-σ policy, hostile recovery, gate 1".into(),
            faults: Faults::Mixed,
            policy: zero_policy(),
            recovery: hostile_recovery,
            gate_nis: 1.0,
            ..base.clone()
        },
        Case {
            name: "gaps and clipping, extreme policy, rare landmark, gate 1e4".into(),
            steps: long,
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            sightings: rare,
            gate_nis: 1e4,
            vertical_accel_error_m_s2: 0.1,
            ..base.clone()
        },
        Case {
            name: "seeker σ 0.1 rad, densities at their maxima".into(),
            seeker_noise_rad: 0.1,
            accel_density: 0.1,
            gyro_density: 0.01,
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            ..base.clone()
        },
        Case {
            name: "landmark overflown at 50 m (minimum range), 100 Hz".into(),
            landmark_on_path: true,
            landmark_alt_m: -50.0,
            faults: Faults::Mixed,
            ..base.clone()
        },
        Case {
            name: "10 Hz IMU, covariance every 1 s, extreme policy".into(),
            imu_dt_s: 0.1,
            covariance_interval_steps: 10,
            steps: medium / 4,
            faults: Faults::Mixed,
            policy: extreme_policy(0.1),
            recovery: hostile_recovery,
            ..base.clone()
        },
        Case {
            name: "1 kHz IMU, covariance every sample, extreme policy".into(),
            imu_dt_s: 0.001,
            covariance_interval_steps: 1,
            steps: medium,
            faults: Faults::Mixed,
            policy: extreme_policy(0.001),
            ..base.clone()
        },
        Case {
            name: "f64: gaps and clipping, extreme policy, hostile recovery, rare landmark".into(),
            faults: Faults::Mixed,
            policy: extreme_policy(0.01),
            recovery: hostile_recovery,
            sightings: rare,
            vertical_accel_error_m_s2: 0.5,
            f64: true,
            ..base.clone()
        },
    ];
    // The precision limit: the finest seeker σ with zero process noise (the updates make P as
    // ill-conditioned as they can), several draws, and two coarser σ.
    for (i, sigma) in [1e-5, 1e-5, 1e-5, 1e-5, 3e-5, 1e-4].iter().enumerate() {
        v.push(Case {
            name: format!("seeker σ {sigma:e} rad, densities 0, gaps and clipping (draw {i})"),
            seeker_noise_rad: *sigma,
            accel_density: 0.0,
            gyro_density: 0.0,
            faults: Faults::Mixed,
            ..base.clone()
        });
    }
    for (i, c) in v.iter_mut().enumerate() {
        c.seed = 11_000 + i as u64;
    }
    v
}

/// Runs the campaign at `level`.
pub fn run(level: StressLevel) -> EstimatorStress {
    let results: Vec<(Tally, String)> = cases(level)
        .into_par_iter()
        .map(|c| {
            if c.f64 {
                run_case::<f64>(&c)
            } else {
                run_case::<f32>(&c)
            }
        })
        .collect();
    let mut out = EstimatorStress::default();
    out.coverage.push(
        "seeker INS: f32 (one f64 case), truth INS on a 20 km circle with random manoeuvres; \
         IMU 10 Hz-1 kHz; long clipping (6000 consecutive samples), 1 s gaps, rare landmark \
         (20 s per 1000 s) with the position leaving the model range, overflown landmark, \
         policies and configuration at the extremes of their ranges"
            .into(),
    );
    for (t, summary) in results {
        out.coverage.push(summary);
        out.add(t);
    }
    out
}

/// Landmark and circle: the vehicle starts heading east; the circle's centre is
/// `CIRCLE_RADIUS_M` to the south (right turn).
fn landmark_position(c: &Case) -> Position {
    let north = if c.landmark_on_path {
        0.0
    } else {
        -CIRCLE_RADIUS_M
    };
    Position {
        lat_rad: LAT0 + north / 6_356_000.0,
        lon_rad: LON0,
        alt_m: 1000.0 + c.landmark_alt_m,
    }
}

const SIG0: [f64; 17] = [
    6e-6, 6e-6, 40.0, 1.0, 1.0, 1.0, 0.017, 0.017, 0.087, 1e-3, 1e-3, 1e-3, 5e-8, 5e-8, 5e-8, 7e-4,
    7e-4,
];

fn run_case<T: Real>(c: &Case) -> (Tally, String) {
    let mut t = Tally::new(c.name.clone());
    let mut rng = run_rng(c.seed, 0);
    let dt = c.imu_dt_s;
    let eps = T::EPS.to_f64();
    let lm_pos = landmark_position(c);
    let Ok(lm) = Landmark::<T>::new(lm_pos) else {
        t.call("landmark", &Err::<(), _>("landmark refused"));
        return (t, format!("{}: landmark refused", c.name));
    };
    let Ok(lm64) = Landmark::<f64>::new(lm_pos) else {
        return (t, format!("{}: landmark refused", c.name));
    };
    let speed = 200.0;
    let yaw_rate = speed / CIRCLE_RADIUS_M;
    let truth0 = InsState {
        position: Position {
            lat_rad: LAT0,
            lon_rad: LON0,
            alt_m: 1000.0,
        },
        vel_ned_m_s: Vector3::new(0.0, speed, 0.0),
        q_b_n: dcm_to_quat(&euler_to_dcm(0.0, 0.0, std::f64::consts::FRAC_PI_2)),
    };
    let Ok(mut truth) = Ins::<f64>::new(truth0, dt) else {
        return (t, format!("{}: truth refused", c.name));
    };
    let config = SeekerInsConfig {
        imu_dt_s: T::lit(dt),
        covariance_interval_steps: c.covariance_interval_steps,
        accel_noise_density_m_s2_rt_hz: T::lit(c.accel_density),
        gyro_noise_density_rad_s_rt_hz: T::lit(c.gyro_density),
        seeker_noise_rad: T::lit(c.seeker_noise_rad),
        gate: Gate::Nis(T::lit(c.gate_nis)),
        recovery: recovery_cast(&c.recovery),
        imu_faults: policy_cast(&c.policy),
        landmark: lm,
        residual: LosResidual::Projected2d,
        instrument_errors: Default::default(),
    };
    let init = perturbed::<T>(&truth0, &mut rng);
    let p0 = SMatrix::<T, 17, 17>::from_fn(|i, j| {
        if i == j {
            T::lit(SIG0[i] * SIG0[i])
        } else {
            T::zero()
        }
    });
    let initial = SeekerInsInitial {
        state: init,
        covariance: p0,
    };
    let mut f = match SeekerIns::new(&config, &initial) {
        Ok(f) => f,
        Err(e) => {
            t.call("new", &Err::<(), _>(e));
            return (t, format!("{}: configuration refused: {e:?}", c.name));
        }
    };
    t.call("set_imu_faults", &f.set_imu_faults(config.imu_faults));
    t.call("set_recovery", &f.set_recovery(config.recovery));
    let acc_bias = Vector3::new(
        ACCEL_BIAS_M_S2 * gauss(&mut rng),
        ACCEL_BIAS_M_S2 * gauss(&mut rng),
        ACCEL_BIAS_M_S2 * gauss(&mut rng) + c.vertical_accel_error_m_s2,
    );
    let gyro_bias = Vector3::new(
        GYRO_BIAS_RAD_S * gauss(&mut rng),
        GYRO_BIAS_RAD_S * gauss(&mut rng),
        GYRO_BIAS_RAD_S * gauss(&mut rng),
    );
    let seeker_bias = (
        SEEKER_BIAS_RAD * gauss(&mut rng),
        SEEKER_BIAS_RAD * gauss(&mut rng),
    );
    let sd_dv = ACCEL_DENSITY * dt.sqrt();
    let sd_dth = GYRO_DENSITY * dt.sqrt();
    let seeker_every = ((0.1 / dt).round() as u64).max(1);
    let psd_every = u64::from(c.covariance_interval_steps).max(10);
    let max_gap_s = c.policy.max_gap_s;
    let mut man = [0.0f64; 6];
    let mut health_steps = [0u64; 4];
    let mut reinits = 0u32;
    let mut min_eig = f64::INFINITY;
    let dt_us = (dt * 1e6).round() as u64;
    for k in 1..=c.steps {
        let t_s = k as f64 * dt;
        let time = Timestamp::from_micros(k * dt_us);
        // Random manoeuvre bursts: a new one every 2 s, large ones one time in five.
        if k % ((2.0 / dt) as u64).max(1) == 0 {
            let big = gauss(&mut rng).abs() > 1.28;
            let (a, w) = if big { (30.0, 0.5) } else { (3.0, 0.02) };
            let mut u = |s: f64| s * gauss(&mut rng).clamp(-1.0, 1.0);
            man = [u(a), u(a), u(a), u(w), u(w), u(w)];
            if big {
                // Large bursts last 0.2 s at most (the damping below takes over again).
                man.iter_mut().for_each(|m| *m *= 0.5);
            }
        }
        let st = *truth.state();
        let cbn = quat_to_dcm(&st.q_b_n);
        let v_b = cbn.transpose() * (st.vel_ned_m_s);
        let (roll, pitch, _) = dcm_to_euler(&cbn);
        let dh = st.position.alt_m - 1000.0;
        let g = 9.80;
        let f_b = Vector3::new(
            man[0] - 0.05 * (v_b.x - speed),
            man[1] - 0.05 * v_b.y + yaw_rate * speed,
            -g + man[2] - 0.05 * v_b.z + 0.002 * dh,
        );
        let w_b = Vector3::new(man[3] - 0.2 * roll, man[4] - 0.2 * pitch, yaw_rate + man[5]);
        let true_inc = ImuIncrement {
            time,
            delta_theta_rad: w_b * dt,
            delta_v_m_s: f_b * dt,
        };
        if truth.step(&true_inc).is_err() {
            break; // the truth generator only; cannot happen with these inputs
        }
        let noise =
            |rng: &mut SimRng, s: f64| Vector3::new(s * gauss(rng), s * gauss(rng), s * gauss(rng));
        let mut sensed_dv = true_inc.delta_v_m_s + acc_bias * dt + noise(&mut rng, sd_dv);
        let mut sensed_dth = true_inc.delta_theta_rad + gyro_bias * dt + noise(&mut rng, sd_dth);
        // Faults at this sample.
        let (in_gap, clipped) = fault_at(c, t_s, dt, max_gap_s);
        if clipped {
            // The sensed increment is off by up to the excess the policy's σ models
            // (the truth-side excess: 10 m/s², 0.5 rad/s at most, whatever the policy).
            let mut u = |s: f64| s * dt * gauss(&mut rng).clamp(-1.0, 1.0);
            sensed_dv += Vector3::new(u(10.0), u(10.0), u(10.0));
            sensed_dth += Vector3::new(u(0.5), u(0.5), u(0.5));
        }
        if !in_gap {
            // The filter detects a gap from the time stamps and bridges it itself.
            let inc = ImuIncrement {
                time,
                delta_theta_rad: sensed_dth.map(T::lit),
                delta_v_m_s: sensed_dv.map(T::lit),
            };
            let r = if clipped {
                f.propagate_clipped(
                    &inc,
                    ClipFlags {
                        accel: true,
                        gyro: true,
                    },
                )
            } else {
                f.propagate(&inc)
            };
            t.call("propagate", &r);
        }
        if k % psd_every == 0 {
            min_eig = min_eig.min(check(&mut t, &f, eps, "propagate"));
        }
        let idx = match f.health().state {
            HealthState::Initialising => 0,
            HealthState::Nominal => 1,
            HealthState::Degraded => 2,
            HealthState::NeedsReinitialisation => 3,
        };
        if let Some(h) = health_steps.get_mut(idx) {
            *h += 1;
        }
        // Seeker.
        if k % seeker_every != 0 || in_gap || !sees(c, t_s) {
            continue;
        }
        if c.reinitialise && f.health().state == HealthState::NeedsReinitialisation {
            let s = perturbed::<T>(truth.state(), &mut rng);
            let sig = [1.6e-5, 1.6e-5, 100.0, 5.0, 5.0, 5.0, 0.035, 0.035, 0.035];
            let covariance = SMatrix::<T, 17, 17>::from_fn(|i, j| match sig.get(i) {
                Some(s) if i == j => T::lit(s * s),
                _ => T::zero(),
            });
            let r = f.reinitialise(&SeekerInsInitial {
                state: s,
                covariance,
            });
            t.call("reinitialise", &r);
            reinits += 1;
        }
        let d = landmark_vector_ned(&truth.state().position, &lm64);
        let gimbal = gimbal_angles_of(&(quat_to_dcm(&truth.state().q_b_n).transpose() * d));
        if gimbal.pitch_rad.abs() > GIMBAL_PITCH_LIMIT_RAD {
            continue;
        }
        let false_lock = matches!(c.sightings, Sightings::Continuous)
            && t_s % 200.0 > 150.0
            && t_s % 200.0 < 160.0;
        let mut yaw = gimbal.yaw_rad
            + seeker_bias.1
            + c.seeker_noise_rad.min(SEEKER_NOISE_RAD) * gauss(&mut rng)
            + if false_lock { 2f64.to_radians() } else { 0.0 };
        if yaw > std::f64::consts::PI {
            yaw -= 2.0 * std::f64::consts::PI;
        } else if yaw < -std::f64::consts::PI {
            yaw += 2.0 * std::f64::consts::PI;
        }
        let meas = LosSample {
            time,
            gimbal: GimbalAngles {
                pitch_rad: T::lit(
                    gimbal.pitch_rad
                        + seeker_bias.0
                        + c.seeker_noise_rad.min(SEEKER_NOISE_RAD) * gauss(&mut rng),
                ),
                yaw_rad: T::lit(yaw),
            },
        };
        let before = f;
        let r = f.update_los(&meas);
        if std::env::var("SEEKER_DEBUG").is_ok() {
            let defect = |f: &SeekerIns<T>| {
                let p = f.covariance();
                let rows: Vec<f64> = (0..17)
                    .flat_map(|i| (0..17).map(move |j| (i, j)))
                    .map(|(i, j)| p[(i, j)].to_f64())
                    .collect();
                super::psd_defect(&rows, 17, eps)
            };
            if let Some(d) = defect(&f) {
                eprintln!(
                    "{}: k {k}: after {d}; before {:?}; report {:?}",
                    c.name,
                    defect(&before),
                    r
                );
                let p = before.covariance();
                eprintln!(
                    "diag before {:?}",
                    (0..17).map(|i| p[(i, i)].to_f64()).collect::<Vec<_>>()
                );
                let pf = p.map(|v| v.to_f64());
                let corr = |pf: &SMatrix<f64, 17, 17>| {
                    let d = pf.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
                    SMatrix::<f64, 17, 17>::from_fn(|i, j| pf[(i, j)] * d[i] * d[j])
                        .symmetric_eigen()
                        .eigenvalues
                };
                let mut ev: Vec<f64> = corr(&pf).iter().copied().collect();
                ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
                eprintln!("corr eig before {:?}", &ev[..5]);
                let pa = f.covariance().map(|v| v.to_f64());
                let mut ev: Vec<f64> = corr(&pa).iter().copied().collect();
                ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
                eprintln!("corr eig after {:?}", &ev[..5]);
                // Same update in f64 from the same prior.
                let st = before.state();
                let s64 = InsState {
                    position: st.position,
                    vel_ned_m_s: st.vel_ned_m_s.map(|v| v.to_f64()),
                    q_b_n: nalgebra::Quaternion::from(st.q_b_n.coords.map(|v| v.to_f64())),
                };
                let cfg = before.config();
                let cfg64 = SeekerInsConfig {
                    imu_dt_s: cfg.imu_dt_s.to_f64(),
                    covariance_interval_steps: cfg.covariance_interval_steps,
                    accel_noise_density_m_s2_rt_hz: cfg.accel_noise_density_m_s2_rt_hz.to_f64(),
                    gyro_noise_density_rad_s_rt_hz: cfg.gyro_noise_density_rad_s_rt_hz.to_f64(),
                    seeker_noise_rad: cfg.seeker_noise_rad.to_f64().max(1e-5),
                    gate: Gate::Nis(c.gate_nis),
                    recovery: c.recovery,
                    imu_faults: c.policy,
                    landmark: lm64,
                    residual: LosResidual::Projected2d,
                    instrument_errors: Default::default(),
                };
                let init64 = SeekerInsInitial {
                    state: s64,
                    covariance: pf,
                };
                let mut f64f = SeekerIns::new(&cfg64, &init64).unwrap();
                let m64 = LosSample {
                    time: meas.time,
                    gimbal: GimbalAngles {
                        pitch_rad: meas.gimbal.pitch_rad.to_f64(),
                        yaw_rad: meas.gimbal.yaw_rad.to_f64(),
                    },
                };
                let r64 = f64f.update_los(&m64);
                let pa = *f64f.covariance();
                let mut ev: Vec<f64> = corr(&pa).iter().copied().collect();
                ev.sort_by(|a, b| a.partial_cmp(b).unwrap());
                eprintln!(
                    "f64 from same prior: {r64:?}; corr eig after {:?}",
                    &ev[..5]
                );
                std::process::exit(1);
            }
        }
        t.call("update_los", &r);
        if let Ok(rep) = r {
            let comps = [rep.pitch, rep.yaw];
            t.finite(
                "LOS report",
                comps
                    .iter()
                    .flat_map(|c| [c.innovation, c.innovation_variance, c.nis, c.test_ratio])
                    .chain([rep.range_m])
                    .map(|v| v.to_f64()),
            );
        }
        min_eig = min_eig.min(check(&mut t, &f, eps, "update_los"));
    }
    min_eig = min_eig.min(check(&mut t, &f, eps, "end"));
    let lc = f.aid_counters(SeekerAid::Los);
    let sc = f.seeker_counters();
    let hc = f.health();
    let total = health_steps.iter().sum::<u64>().max(1) as f64;
    let pct = |i: usize| 100.0 * health_steps.get(i).copied().unwrap_or(0) as f64 / total;
    let summary = format!(
        "{}: {} IMU samples; LOS components fused {} rejected {} skipped {} conditioned {}; \
         inflations {}; limits hit {}; gaps bridged {} reset {}; out-of-range samples {}; \
         reinitialisations {}; health nominal {:.1} % degraded {:.1} % needs-reinit {:.1} %; \
         end {:?}; smallest correlation eigenvalue of P {:.2e}",
        c.name,
        c.steps,
        lc.fused,
        lc.rejected,
        lc.skipped,
        sc.conditioned,
        lc.recoveries,
        hc.limits_hit,
        hc.gaps_bridged,
        hc.gaps_reset,
        sc.out_of_range_samples,
        reinits,
        pct(1),
        pct(2),
        pct(3),
        hc.state,
        min_eig
    );
    (t, summary)
}

/// Whether sample time `t_s` is in an IMU gap and whether the sample is clipped.
fn fault_at(c: &Case, t_s: f64, dt: f64, gap_s: f64) -> (bool, bool) {
    let in_gap = |every_s: f64| {
        let ph = (t_s % every_s) - (every_s - gap_s - 1.0);
        ph > 0.0 && ph <= gap_s + 0.5 * dt
    };
    let clip = |samples: u32, every_s: f64| {
        let ph = t_s % every_s - 20.0;
        ph > 0.0 && ph <= f64::from(samples) * dt
    };
    match c.faults {
        Faults::None => (false, false),
        Faults::Gaps { every_s } => (in_gap(every_s), false),
        Faults::Clipping { samples, every_s } => (false, clip(samples, every_s)),
        Faults::Mixed => (in_gap(7.0), clip(300, 45.0)),
    }
}

/// Whether the seeker reports the landmark at `t_s` (loss of lock: 30 s every 200 s).
fn sees(c: &Case, t_s: f64) -> bool {
    match c.sightings {
        Sightings::Continuous => {
            let ph = t_s % 200.0;
            !(100.0..130.0).contains(&ph)
        }
        Sightings::Rare { on_s, period_s } => t_s % period_s < on_s,
    }
}

/// The truth state with 40 m / 1 m/s / 1° (5° in yaw) of error.
fn perturbed<T: Real>(s: &InsState<f64>, rng: &mut SimRng) -> InsState<T> {
    let c = quat_to_dcm(&s.q_b_n);
    let (r, p, y) = dcm_to_euler(&c);
    let deg = std::f64::consts::PI / 180.0;
    let c_err = euler_to_dcm(
        r + deg * gauss(rng),
        p + deg * gauss(rng),
        y + 5.0 * deg * gauss(rng),
    );
    InsState {
        position: Position {
            lat_rad: s.position.lat_rad + 40.0 / 6.36e6 * gauss(rng),
            lon_rad: s.position.lon_rad + 40.0 / 5.1e6 * gauss(rng),
            alt_m: s.position.alt_m + 40.0 * gauss(rng),
        },
        vel_ned_m_s: (s.vel_ned_m_s + Vector3::new(gauss(rng), gauss(rng), gauss(rng))).map(T::lit),
        q_b_n: dcm_to_quat(&c_err.map(T::lit)),
    }
}

/// Smallest eigenvalue of the correlation matrix of P (states with zero variance dropped).
fn min_correlation_eigenvalue<T: Real>(f: &SeekerIns<T>) -> f64 {
    let p = f.covariance();
    let rows: Vec<f64> = (0..17)
        .flat_map(|i| (0..17).map(move |j| (i, j)))
        .map(|(i, j)| p[(i, j)].to_f64())
        .collect();
    super::min_correlation_eigenvalue(&rows, 17)
}

/// P (PSD to the type's precision) and the outputs (finite); returns the smallest eigenvalue
/// of P's correlation matrix.
fn check<T: Real>(t: &mut Tally, f: &SeekerIns<T>, eps: f64, at: &str) -> f64 {
    let m = min_correlation_eigenvalue(f);
    check_outputs(t, f, eps, at);
    m
}

fn check_outputs<T: Real>(t: &mut Tally, f: &SeekerIns<T>, eps: f64, at: &str) {
    let p = f.covariance();
    let rows: Vec<f64> = (0..17)
        .flat_map(|i| (0..17).map(move |j| (i, j)))
        .map(|(i, j)| p[(i, j)].to_f64())
        .collect();
    t.covariance(at, &rows, 17, eps);
    let s = f.state();
    let sig = (0..17).map(|i| p[(i, i)].to_f64().max(0.0).sqrt());
    t.finite(
        at,
        [s.position.lat_rad, s.position.lon_rad, s.position.alt_m]
            .into_iter()
            .chain(s.vel_ned_m_s.iter().map(|v| v.to_f64()))
            .chain(s.q_b_n.coords.iter().map(|v| v.to_f64()))
            .chain(f.accel_bias_m_s2().iter().map(|v| v.to_f64()))
            .chain(f.gyro_bias_rad_s().iter().map(|v| v.to_f64()))
            .chain(f.gimbal_bias_rad().iter().map(|v| v.to_f64()))
            .chain(sig),
    );
}

/// The recovery policy in the filter's precision.
fn recovery_cast<T: Real>(r: &RecoveryPolicy<f64>) -> RecoveryPolicy<T> {
    RecoveryPolicy {
        starved_after_s: r.starved_after_s.map(T::lit),
        action: match r.action {
            RecoveryAction::Inflate { variance_factor } => RecoveryAction::Inflate {
                variance_factor: T::lit(variance_factor),
            },
            RecoveryAction::ResetToPrior => RecoveryAction::ResetToPrior,
            RecoveryAction::Reanchor => RecoveryAction::Reanchor,
        },
    }
}

/// The IMU fault policy in the filter's precision.
fn policy_cast<T: Real>(p: &ImuFaultPolicy<f64>) -> ImuFaultPolicy<T> {
    ImuFaultPolicy {
        max_gap_s: T::lit(p.max_gap_s),
        gap_accel_sigma_m_s2: T::lit(p.gap_accel_sigma_m_s2),
        gap_rate_sigma_rad_s: T::lit(p.gap_rate_sigma_rad_s),
        clip_accel_sigma_m_s2: T::lit(p.clip_accel_sigma_m_s2),
        clip_rate_sigma_rad_s: T::lit(p.clip_rate_sigma_rad_s),
    }
}

//! One case of the campaign: the truth INS flown on its circle, the filter fed what a flight
//! computer would, every call and every covariance checked.

use super::*;
use crate::scenarios::seeker_ins::injection::policy_cast;
use nav_core::seeker_ins::LosReport;
use nav_core::NavError;

const SIG0: [f64; 17] = [
    6e-6, 6e-6, 40.0, 1.0, 1.0, 1.0, 0.017, 0.017, 0.087, 1e-3, 1e-3, 1e-3, 5e-8, 5e-8, 5e-8, 7e-4,
    7e-4,
];

/// Speed on the circle, m/s.
const SPEED_M_S: f64 = 200.0;

/// The sensor errors of one case, drawn once: accelerometer bias (m/s², the case's vertical
/// error included), gyro bias (rad/s), seeker bias (pitch, yaw; rad).
struct SensorErrors {
    acc_bias: Vector3<f64>,
    gyro_bias: Vector3<f64>,
    seeker_bias: (f64, f64),
}

pub(super) fn run_case<T: Real>(c: &Case) -> (Tally, String) {
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
    let truth0 = truth_start();
    let Ok(mut truth) = Ins::<f64>::new(truth0, dt) else {
        return (t, format!("{}: truth refused", c.name));
    };
    let (mut f, config) = match new_filter::<T>(c, lm, &truth0, &mut rng) {
        Ok(fc) => fc,
        Err(e) => {
            t.call("new", &Err::<(), _>(e));
            return (t, format!("{}: configuration refused: {e:?}", c.name));
        }
    };
    t.call("set_imu_faults", &f.set_imu_faults(config.imu_faults));
    t.call("set_recovery", &f.set_recovery(config.recovery));
    let errors = draw_errors(c, &mut rng);
    let seeker_every = ((0.1 / dt).round() as u64).max(1);
    let psd_every = u64::from(c.covariance_interval_steps).max(10);
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
            man = next_manoeuvre(&mut rng);
        }
        let true_inc = truth_increment(truth.state(), &man, time, dt);
        if truth.step(&true_inc).is_err() {
            break; // the truth generator only; cannot happen with these inputs
        }
        let in_gap = feed_imu(&mut t, &mut f, c, &true_inc, &errors, t_s, &mut rng);
        if k % psd_every == 0 {
            min_eig = min_eig.min(check(&mut t, &f, eps, "propagate"));
        }
        if let Some(h) = health_steps.get_mut(health_index(f.health().state)) {
            *h += 1;
        }
        // Seeker.
        if k % seeker_every != 0 || in_gap || !sees(c, t_s) {
            continue;
        }
        if c.reinitialise && f.health().state == HealthState::NeedsReinitialisation {
            reinitialise_near_truth(&mut t, &mut f, truth.state(), &mut rng);
            reinits += 1;
        }
        let Some(meas) = seeker_sample::<T>(c, truth.state(), &lm64, &errors, t_s, time, &mut rng)
        else {
            continue;
        };
        let before = f;
        let r = f.update_los(&meas);
        if std::env::var("SEEKER_DEBUG").is_ok() {
            debug::dump_if_not_psd(c, k, lm64, &before, &f, &meas, &r);
        }
        t.call("update_los", &r);
        check_report(&mut t, &r);
        min_eig = min_eig.min(check(&mut t, &f, eps, "update_los"));
    }
    min_eig = min_eig.min(check(&mut t, &f, eps, "end"));
    let summary = summary(c, &f, reinits, &health_steps, min_eig);
    (t, summary)
}

/// The filter of case `c` and its configuration, started from the truth `truth0` perturbed
/// (`rng`) with the initial σ `SIG0`.
fn new_filter<T: Real>(
    c: &Case,
    lm: Landmark<T>,
    truth0: &InsState<f64>,
    rng: &mut SimRng,
) -> Result<(SeekerIns<T>, SeekerInsConfig<T>), NavError> {
    let config = SeekerInsConfig {
        imu_dt_s: T::lit(c.imu_dt_s),
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
    let init = perturbed::<T>(truth0, rng);
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
    Ok((SeekerIns::new(&config, &initial)?, config))
}

/// The case's sensor errors, drawn from `rng`.
fn draw_errors(c: &Case, rng: &mut SimRng) -> SensorErrors {
    let acc_bias = Vector3::new(
        ACCEL_BIAS_M_S2 * gauss(rng),
        ACCEL_BIAS_M_S2 * gauss(rng),
        ACCEL_BIAS_M_S2 * gauss(rng) + c.vertical_accel_error_m_s2,
    );
    let gyro_bias = Vector3::new(
        GYRO_BIAS_RAD_S * gauss(rng),
        GYRO_BIAS_RAD_S * gauss(rng),
        GYRO_BIAS_RAD_S * gauss(rng),
    );
    let seeker_bias = (SEEKER_BIAS_RAD * gauss(rng), SEEKER_BIAS_RAD * gauss(rng));
    SensorErrors {
        acc_bias,
        gyro_bias,
        seeker_bias,
    }
}

/// A new manoeuvre burst (specific force m/s², rate rad/s, body axes): large ones (±30 m/s²,
/// ±0.5 rad/s, halved) one time in five, small ones (±3 m/s², ±0.02 rad/s) otherwise.
fn next_manoeuvre(rng: &mut SimRng) -> [f64; 6] {
    let big = gauss(rng).abs() > 1.28;
    let (a, w) = if big { (30.0, 0.5) } else { (3.0, 0.02) };
    let mut u = |s: f64| s * gauss(rng).clamp(-1.0, 1.0);
    let mut man = [u(a), u(a), u(a), u(w), u(w), u(w)];
    if big {
        // Large bursts last 0.2 s at most (the damping below takes over again).
        man.iter_mut().for_each(|m| *m *= 0.5);
    }
    man
}

/// The perfect increments over `dt` (s) ending at `time` that keep the truth `st` on its
/// circle (speed, level, 1 km, damped) with the manoeuvre `man` on top.
fn truth_increment(
    st: &InsState<f64>,
    man: &[f64; 6],
    time: Timestamp,
    dt: f64,
) -> ImuIncrement<f64> {
    let yaw_rate = SPEED_M_S / CIRCLE_RADIUS_M;
    let cbn = quat_to_dcm(&st.q_b_n);
    let v_b = cbn.transpose() * (st.vel_ned_m_s);
    let (roll, pitch, _) = dcm_to_euler(&cbn);
    let dh = st.position.alt_m - 1000.0;
    let g = 9.80;
    let f_b = Vector3::new(
        man[0] - 0.05 * (v_b.x - SPEED_M_S),
        man[1] - 0.05 * v_b.y + yaw_rate * SPEED_M_S,
        -g + man[2] - 0.05 * v_b.z + 0.002 * dh,
    );
    let w_b = Vector3::new(man[3] - 0.2 * roll, man[4] - 0.2 * pitch, yaw_rate + man[5]);
    ImuIncrement {
        time,
        delta_theta_rad: w_b * dt,
        delta_v_m_s: f_b * dt,
    }
}

/// Feeds the filter the sensed increment of `true_inc` (bias, noise, and the case's faults at
/// `t_s`: nothing in a gap, a clipped sample off by up to the truth-side excess); returns
/// whether the sample was in a gap.
fn feed_imu<T: Real>(
    t: &mut Tally,
    f: &mut SeekerIns<T>,
    c: &Case,
    true_inc: &ImuIncrement<f64>,
    errors: &SensorErrors,
    t_s: f64,
    rng: &mut SimRng,
) -> bool {
    let dt = c.imu_dt_s;
    let sd_dv = ACCEL_DENSITY * dt.sqrt();
    let sd_dth = GYRO_DENSITY * dt.sqrt();
    let noise =
        |rng: &mut SimRng, s: f64| Vector3::new(s * gauss(rng), s * gauss(rng), s * gauss(rng));
    let mut sensed_dv = true_inc.delta_v_m_s + errors.acc_bias * dt + noise(rng, sd_dv);
    let mut sensed_dth = true_inc.delta_theta_rad + errors.gyro_bias * dt + noise(rng, sd_dth);
    // Faults at this sample.
    let (in_gap, clipped) = fault_at(c, t_s, dt, c.policy.max_gap_s);
    if clipped {
        // The sensed increment is off by up to the excess the policy's σ models
        // (the truth-side excess: 10 m/s², 0.5 rad/s at most, whatever the policy).
        let mut u = |s: f64| s * dt * gauss(rng).clamp(-1.0, 1.0);
        sensed_dv += Vector3::new(u(10.0), u(10.0), u(10.0));
        sensed_dth += Vector3::new(u(0.5), u(0.5), u(0.5));
    }
    if !in_gap {
        // The filter detects a gap from the time stamps and bridges it itself.
        let inc = ImuIncrement {
            time: true_inc.time,
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
    in_gap
}

/// Index of a health state in the per-state step counts.
fn health_index(state: HealthState) -> usize {
    match state {
        HealthState::Initialising => 0,
        HealthState::Nominal => 1,
        HealthState::Degraded => 2,
        HealthState::NeedsReinitialisation => 3,
    }
}

/// The seeker's gimbal angles of the landmark `lm64` seen from the truth `st` at `time`
/// (`t_s`), with bias, noise and the case's false lock; `None` beyond the gimbal's pitch limit.
fn seeker_sample<T: Real>(
    c: &Case,
    st: &InsState<f64>,
    lm64: &Landmark<f64>,
    errors: &SensorErrors,
    t_s: f64,
    time: Timestamp,
    rng: &mut SimRng,
) -> Option<LosSample<T>> {
    let d = landmark_vector_ned(&st.position, lm64);
    let gimbal = gimbal_angles_of(&(quat_to_dcm(&st.q_b_n).transpose() * d));
    if gimbal.pitch_rad.abs() > GIMBAL_PITCH_LIMIT_RAD {
        return None;
    }
    let false_lock =
        matches!(c.sightings, Sightings::Continuous) && t_s % 200.0 > 150.0 && t_s % 200.0 < 160.0;
    let mut yaw = gimbal.yaw_rad
        + errors.seeker_bias.1
        + c.seeker_noise_rad.min(SEEKER_NOISE_RAD) * gauss(rng)
        + if false_lock { 2f64.to_radians() } else { 0.0 };
    if yaw > std::f64::consts::PI {
        yaw -= 2.0 * std::f64::consts::PI;
    } else if yaw < -std::f64::consts::PI {
        yaw += 2.0 * std::f64::consts::PI;
    }
    Some(LosSample {
        time,
        gimbal: GimbalAngles {
            pitch_rad: T::lit(
                gimbal.pitch_rad
                    + errors.seeker_bias.0
                    + c.seeker_noise_rad.min(SEEKER_NOISE_RAD) * gauss(rng),
            ),
            yaw_rad: T::lit(yaw),
        },
    })
}

/// Every value of a LOS report must be finite.
fn check_report<T: Real>(t: &mut Tally, r: &Result<LosReport<T>, NavError>) {
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
}

/// The case's line of the campaign report: the LOS components fused, rejected, skipped and
/// conditioned, recoveries, limits, gaps, re-initialisations, the share of steps in each
/// health state, the final health and the smallest correlation eigenvalue of P seen.
fn summary<T: Real>(
    c: &Case,
    f: &SeekerIns<T>,
    reinits: u32,
    health_steps: &[u64; 4],
    min_eig: f64,
) -> String {
    let lc = f.aid_counters(SeekerAid::Los);
    let sc = f.seeker_counters();
    let hc = f.health();
    let total = health_steps.iter().sum::<u64>().max(1) as f64;
    let pct = |i: usize| 100.0 * health_steps.get(i).copied().unwrap_or(0) as f64 / total;
    format!(
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
    )
}

/// Re-initialises the filter from the truth perturbed (`perturbed`, drawing from `rng`), with
/// σ 100 m, 5 m/s and 2° on position, velocity and attitude.
fn reinitialise_near_truth<T: Real>(
    t: &mut Tally,
    f: &mut SeekerIns<T>,
    truth: &InsState<f64>,
    rng: &mut SimRng,
) {
    let s = perturbed::<T>(truth, rng);
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
}

/// The truth at the start: at `LAT0`, `LON0`, 1 km altitude, heading east at `SPEED_M_S`, level.
fn truth_start() -> InsState<f64> {
    InsState {
        position: Position {
            lat_rad: LAT0,
            lon_rad: LON0,
            alt_m: 1000.0,
        },
        vel_ned_m_s: Vector3::new(0.0, SPEED_M_S, 0.0),
        q_b_n: dcm_to_quat(&euler_to_dcm(0.0, 0.0, std::f64::consts::FRAC_PI_2)),
    }
}

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

mod cases;
mod debug;
mod fly;

use cases::cases;
use fly::run_case;

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

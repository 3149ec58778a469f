//! The navigator on a self-contained synthetic chain: straight level flight, master = truth,
//! slave IMU = the truth's increments in a fixed mount misalignment; then a drop (0 g for
//! 0.5 s), coast, baro, and a landmark.
//!
//! Shared fixtures here; the tests by subject in `chain` (phases, hand-over, refused inputs,
//! master timeouts, configuration), `baro_ekf` (the 18th state) and `stored` (stored design,
//! in-place baro update, refused LOS, bias hand-over).

use super::baro::{baro_update, BaroState};
use super::test_support::{
    self, baro_model, gimbal_truth, imu_tick, World, WorldSpec, SPEED_M_S, START,
};
use super::*;
use crate::contract::FusionOutcome;
use crate::contract::Gate;
use crate::math::kalman::fuse_scalar;
use crate::math::rotation::{log_so3, quat_to_dcm};
use crate::seeker_ins::{gimbal_angles_of, landmark_vector_ned, ImuIncrement, InsState, LosSample};
use crate::seeker_ins::{
    propagate_covariance_sparse, SeekerIns, SeekerInsInitial, SparseF, ACC_BIAS, POS, STATES, VEL,
};
use crate::time::Timestamp;
use crate::vertical_channel::BaroSample;
use crate::{HealthState, NavError, Real};
use nalgebra::SVector;
use nalgebra::{Quaternion, SMatrix, Vector3};
use std::format;
use std::string::String;
use std::vec::Vec;

const DT_US: u64 = 10_000;
const DT: f64 = 0.01;
const LATENCY_TICKS: u64 = 3;
const SEPARATION_S: f64 = 20.0;
const DROP_S: f64 = 0.5;
const COAST_S: f64 = 2.0;
const SEEKER_FROM_S: f64 = 25.0;
/// The seeker loses lock here (terminal continues on the baro).
const SEEKER_UNTIL_S: f64 = 26.5;

/// The chain's configuration (`test_support::config`) with `baro`, the release after
/// `COAST_S`.
fn config<T: Real>(baro: BaroDamping<T>) -> NavigatorConfig<T> {
    test_support::config(baro, COAST_S)
}

/// The chain's world (`test_support::World`, the one the property tests fly) at
/// 100 Hz: the release at `SEPARATION_S`, the drop for `DROP_S`.
fn chain_world(lever: &Vector3<f64>) -> World {
    World::new(&WorldSpec {
        rate_hz: 100,
        start_us: 0,
        sep_tick: (SEPARATION_S / DT).round() as u64,
        drop_ticks: (DROP_S / DT).round() as u64,
        lever_m: *lever,
    })
}

/// The master sample arriving at the world's tick: the one of `LATENCY_TICKS` ago, every
/// second tick.
fn late_master<T: Real>(world: &World) -> Option<MasterNav<T>> {
    if world.k % 2 != 0 || world.k <= LATENCY_TICKS {
        return None;
    }
    world.master_sample(world.k - LATENCY_TICKS)
}

/// Attitude error φ (`Ĉ = exp(−[φ×]) C`) of a solution against the truth.
fn attitude_error<T: Real>(est: &InsState<T>, truth: &InsState<f64>) -> Vector3<f64> {
    let c_hat = quat_to_dcm(&Quaternion::from(est.q_b_n.coords.map(|x| x.to_f64())));
    let c = quat_to_dcm(&truth.q_b_n);
    -log_so3(&(c_hat * c.transpose()))
}

/// Error (estimate − truth) in the solution's convention: δr NED m, δv m/s, φ rad.
fn nav_error<T: Real>(est: &InsState<T>, truth: &InsState<f64>) -> [f64; 9] {
    let (rm, rn) = crate::earth::radii_m(truth.position.lat_rad);
    let h = truth.position.alt_m;
    let dn = (est.position.lat_rad - truth.position.lat_rad) * (rm + h);
    let de =
        (est.position.lon_rad - truth.position.lon_rad) * (rn + h) * truth.position.lat_rad.cos();
    let dd = -(est.position.alt_m - h);
    let dv = est.vel_ned_m_s.map(|x| x.to_f64()) - truth.vel_ned_m_s;
    let phi = attitude_error(est, truth);
    [dn, de, dd, dv.x, dv.y, dv.z, phi.x, phi.y, phi.z]
}

struct Run {
    phases: Vec<(f64, Phase)>,
    transitions: Vec<Transition>,
    handover_phi: Vector3<f64>,
    handover_sigma: Vector3<f64>,
    final_health: HealthState,
    terminal_pos_err_m: f64,
    baro_fused: u32,
    seeker_fused: u32,
    /// Largest |cross-covariance| of δD or δV_D with the other navigation states, and the
    /// vertical variances, at the last midcourse tick.
    midcourse_vertical_cross: f64,
    midcourse_vertical_var: [f64; 2],
    midcourse_alt_err_m: f64,
    final_seeker: AidState,
    final_degradation: Degradation,
    baro_fused_at_seeker_loss: u32,
    /// Largest per-axis |error| / σ in carry (position, velocity, attitude; sampled each
    /// second after the first 2 s).
    carry_worst_normalized: f64,
    /// Smallest eigenvalue of the joint (17 + baro) correlation matrix, sampled each second in
    /// midcourse and terminal (baro EKF only).
    joint_min_correlation_eigenvalue: f64,
}

impl Run {
    fn new() -> Self {
        Run {
            phases: Vec::new(),
            transitions: Vec::new(),
            handover_phi: Vector3::zeros(),
            handover_sigma: Vector3::zeros(),
            final_health: HealthState::Initialising,
            terminal_pos_err_m: f64::NAN,
            baro_fused: 0,
            seeker_fused: 0,
            midcourse_vertical_cross: f64::NAN,
            midcourse_vertical_var: [f64::NAN; 2],
            midcourse_alt_err_m: f64::NAN,
            final_seeker: AidState::NotUsedInPhase,
            final_degradation: Degradation::default(),
            baro_fused_at_seeker_loss: 0,
            carry_worst_normalized: 0.0,
            joint_min_correlation_eigenvalue: f64::INFINITY,
        }
    }
}

/// The chain's aid samples at the world's tick `inc`: the master `LATENCY_TICKS` late until
/// the release, a baro sample (the truth's altitude) every 4th tick after the coast, the
/// seeker's LOS (the truth's gimbal angles) every 10th tick inside the seeker's window, the
/// release signal.
struct ChainAids<T: Real> {
    master: Option<MasterNav<T>>,
    baro: Option<BaroSample<T>>,
    seeker: Option<LosSample<T>>,
    separation: Option<Timestamp>,
}

impl<T: Real> ChainAids<T> {
    fn at(world: &World, inc: &ImuIncrement<f64>) -> Self {
        let (t, k, time) = (inc.time.as_secs_f64(), world.k, inc.time);
        let truth = world.missile_truth();
        Self {
            master: (t <= SEPARATION_S)
                .then(|| late_master::<T>(world))
                .flatten(),
            baro: (t > SEPARATION_S + COAST_S && k % 4 == 0).then(|| BaroSample {
                time,
                altitude_m: T::lit(truth.position.alt_m),
            }),
            seeker: ((SEEKER_FROM_S..SEEKER_UNTIL_S).contains(&t) && k % 10 == 0).then(|| {
                let g = gimbal_truth(&truth);
                LosSample {
                    time,
                    gimbal: crate::seeker_ins::GimbalAngles {
                        pitch_rad: T::lit(g.pitch_rad),
                        yaw_rad: T::lit(g.yaw_rad),
                    },
                }
            }),
            separation: ((t - SEPARATION_S).abs() < 0.5 * DT).then_some(time),
        }
    }

    fn aids(&self) -> Aids<'_, T> {
        Aids {
            master: self.master.as_ref(),
            baro: self.baro.as_ref(),
            seeker: self.seeker.as_ref(),
            separation: self.separation,
        }
    }
}

/// Largest |cross-covariance| of δD or δV_D with the other navigation states.
fn vertical_cross<T: Real>(p: &SMatrix<T, 9, 9>) -> f64 {
    let mut m = 0.0_f64;
    for j in 0..9 {
        if j != 2 && j != 5 {
            m = m
                .max(p[(2, j)].to_f64().abs())
                .max(p[(5, j)].to_f64().abs());
        }
    }
    m
}

/// Smallest eigenvalue of the joint (17 + baro) correlation matrix of the baro EKF.
fn joint_min_correlation_eigenvalue<T: Real>(nav: &FlightNavigator<T, 32>) -> f64 {
    let p = nav.ekf().unwrap().covariance().map(|x| x.to_f64());
    let b = nav.baro_state();
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    let c = b.cross.map(|x| x.to_f64());
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&c);
    pa.fixed_view_mut::<1, 17>(17, 0).copy_from(&c.transpose());
    pa[(17, 17)] = b.variance_m2.to_f64();
    let d = pa.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
    let corr = SMatrix::<f64, 18, 18>::from_fn(|i, j| pa[(i, j)] * d[i] * d[j]);
    corr.symmetric_eigenvalues().min()
}

/// The attitude σ (states 6..9 of the navigation covariance), rad.
fn attitude_sigma<T: Real>(p: &SMatrix<T, 9, 9>) -> Vector3<f64> {
    Vector3::from_fn(|i, _| p[(6 + i, 6 + i)].to_f64().sqrt())
}

/// Largest per-state |error| / σ of the navigation states.
fn worst_normalized<T: Real>(e: &[f64; 9], p: &SMatrix<T, 9, 9>) -> f64 {
    let mut worst = 0.0_f64;
    for (i, ei) in e.iter().enumerate() {
        let sigma = p[(i, i)].to_f64().sqrt();
        worst = worst.max(ei.abs() / sigma);
    }
    worst
}

/// Position error in the north-vertical plane (north from latitude, and altitude), m.
fn north_vertical_error_m<T: Real>(s: &InsState<T>, truth: &InsState<f64>) -> f64 {
    let (rm, _) = crate::earth::radii_m(truth.position.lat_rad);
    ((s.position.lat_rad - truth.position.lat_rad) * rm)
        .hypot(s.position.alt_m - truth.position.alt_m)
}

fn run_chain<T: Real>(baro: BaroDamping<T>, end_s: f64) -> Run {
    let cfg = config::<T>(baro);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    // A twin flown through `tick_into` with one report slot reused for the whole run.
    let mut twin = nav.clone();
    let mut slot = twin.blank_report();
    let mut run = Run::new();
    let mut last_phase = Phase::Carry;
    let steps = (end_s / DT).round() as u64;
    for _ in 0..steps {
        let inc = world.step();
        let t = inc.time.as_secs_f64();
        let truth = world.missile_truth();
        let samples = ChainAids::<T>::at(&world, &inc);
        let aids = samples.aids();
        let report = nav.tick(&imu_tick(&inc), &aids).unwrap();
        twin.tick_into(&imu_tick(&inc), &aids, &mut slot).unwrap();
        assert_eq!(slot, report, "tick_into writes the report tick returns");
        if let Some(tr) = report.transition {
            run.transitions.push(tr);
        }
        if report.phase != last_phase {
            run.phases.push((t, report.phase));
            if report.phase == Phase::Released {
                let phi = attitude_error(&report.solution.state, &truth);
                run.handover_phi = phi;
                run.handover_sigma = attitude_sigma(&report.solution.nav_covariance);
            }
            last_phase = report.phase;
        }
        if report.phase == Phase::Midcourse {
            let p = &report.solution.nav_covariance;
            run.midcourse_vertical_cross = vertical_cross(p);
            run.midcourse_vertical_var = [p[(2, 2)].to_f64(), p[(5, 5)].to_f64()];
            run.midcourse_alt_err_m = report.solution.state.position.alt_m - truth.position.alt_m;
        }
        if report.phase == Phase::Carry && t > 2.0 && world.k % 100 == 0 {
            let e = nav_error(&report.solution.state, &truth);
            let w = worst_normalized(&e, &report.solution.nav_covariance);
            run.carry_worst_normalized = run.carry_worst_normalized.max(w);
        }
        if matches!(report.phase, Phase::Midcourse | Phase::Terminal)
            && matches!(cfg.baro, BaroDamping::Ekf(_))
            && world.k % 100 == 0
        {
            run.joint_min_correlation_eigenvalue = run
                .joint_min_correlation_eigenvalue
                .min(joint_min_correlation_eigenvalue(&nav));
        }
        if (t - SEEKER_UNTIL_S).abs() < 0.5 * DT {
            run.baro_fused_at_seeker_loss = report.baro.counters.fused;
        }
        run.final_seeker = report.seeker.state;
        run.final_degradation = report.degradation;
        run.final_health = report.health;
        run.baro_fused = report.baro.counters.fused;
        run.seeker_fused = report.seeker.counters.fused;
        run.terminal_pos_err_m = north_vertical_error_m(&report.solution.state, &truth);
    }
    run
}

/// Runs the carry phase for `secs` and returns the navigator and the world.
fn carry_for<T: Real>(secs: f64, master_until_s: f64) -> (FlightNavigator<T, 32>, World) {
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = chain_world(&lever);
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &world.initial()).unwrap();
    for _ in 0..(secs / DT).round() as u64 {
        let inc = world.step();
        let master = (inc.time.as_secs_f64() <= master_until_s)
            .then(|| late_master::<T>(&world))
            .flatten();
        let aids = Aids {
            master: master.as_ref(),
            ..Aids::NONE
        };
        nav.tick(&imu_tick(&inc), &aids).unwrap();
    }
    (nav, world)
}

fn dump<T: Real>(nav: &FlightNavigator<T, 32>) -> String {
    format!("{nav:?}")
}

fn flight_ekf() -> SeekerIns<f64> {
    let cfg = config::<f64>(BaroDamping::Ekf(baro_model()));
    let mut p0 = crate::seeker_ins::paper_initial_covariance::<f64>();
    // Correlations, so that every block of the update is exercised.
    p0[(POS + 2, VEL + 2)] = 0.3 * (p0[(POS + 2, POS + 2)] * p0[(VEL + 2, VEL + 2)]).sqrt();
    p0[(VEL + 2, POS + 2)] = p0[(POS + 2, VEL + 2)];
    let init = SeekerInsInitial {
        state: InsState {
            position: START,
            vel_ned_m_s: Vector3::new(SPEED_M_S, 10.0, -5.0),
            q_b_n: crate::math::rotation::dcm_to_quat(&crate::math::rotation::euler_to_dcm(
                0.05, 0.1, 0.3,
            )),
        },
        covariance: p0,
    };
    <SeekerIns<f64> as crate::contract::Estimator>::new(&cfg.ins, &init).unwrap()
}

/// A cross-covariance column and variance that keep the joint matrix positive definite.
fn joint_column(p: &SMatrix<f64, STATES, STATES>) -> (SVector<f64, STATES>, f64) {
    // c = 0.5 P a with a along δh and δV_D: corr(δx, δb) from a regression b = 0.5 aᵀδx + w.
    let mut a = SVector::<f64, STATES>::zeros();
    a[POS + 2] = 0.02;
    a[VEL + 2] = 0.5;
    let c = p * a * 0.5;
    let s = 0.25 * a.dot(&(p * a)) + 4.0;
    (c, s)
}

/// Releases `nav` at the world's missile truth with a tenth of the paper's initial σ.
fn release_at_truth<T: Real>(nav: &mut FlightNavigator<T, 32>, world: &World) {
    let mut p0 = crate::seeker_ins::paper_initial_covariance::<T>();
    p0 *= T::lit(0.01);
    release_at_truth_with(nav, world, p0);
}

/// Releases `nav` at the world's missile truth with the EKF's initial covariance `p0`.
fn release_at_truth_with<T: Real>(
    nav: &mut FlightNavigator<T, 32>,
    world: &World,
    p0: SMatrix<T, STATES, STATES>,
) {
    let truth = world.missile_truth();
    nav.release_with(&crate::seeker_ins::SeekerInsInitial {
        state: InsState {
            position: truth.position,
            vel_ned_m_s: truth.vel_ned_m_s.map(|x| T::lit(x)),
            q_b_n: Quaternion::from(truth.q_b_n.coords.map(|x| T::lit(x))),
        },
        covariance: p0,
    })
    .unwrap();
}

mod baro_ekf;
mod baro_floor;
mod baro_hold;
#[cfg(feature = "baro-inertial-loop")]
mod baro_loop;
mod chain;
mod psd;
mod release;
mod stored;

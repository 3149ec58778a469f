//! The navigator on a self-contained synthetic chain: straight level flight, master = truth,
//! slave IMU = the truth's increments in a fixed mount misalignment; then a drop (0 g for
//! 0.5 s), coast, baro, and a landmark.

use super::*;
use crate::contract::Gate;
use crate::earth::{earth_rate_ned, normal_gravity_m_s2, transport_rate_ned};
use crate::math::rotation::{exp_so3, log_so3, quat_to_dcm};
use crate::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, ClipFlags, ImuIncrement, Ins, InsState, Landmark,
    LosSample, Position, SeekerInsConfig,
};
use crate::time::Timestamp;
use crate::transfer_alignment::{PaperCase, TaConfig};
use crate::vertical_channel::BaroSample;
use crate::{HealthState, NavError, Real};
use nalgebra::{Matrix3, Quaternion, SMatrix, Vector3};
use std::format;
use std::string::String;
use std::vec::Vec;

const DT_US: u64 = 10_000;
const DT: f64 = 0.01;
const START: Position = Position {
    lat_rad: 0.6458,
    lon_rad: 2.2166,
    alt_m: 3000.0,
};
const SPEED_M_S: f64 = 200.0;
/// The slave's true mount misalignment θ (`C_m^s = exp(−[θ×])`), rad.
const THETA: [f64; 3] = [0.006, -0.004, 0.008];
const LATENCY_TICKS: u64 = 3;
const SEPARATION_S: f64 = 20.0;
const DROP_S: f64 = 0.5;
const COAST_S: f64 = 2.0;
const SEEKER_FROM_S: f64 = 25.0;

fn landmark_position() -> Position {
    // 30 km north of the start, on the ground.
    Position {
        lat_rad: START.lat_rad + 30_000.0 / 6_360_000.0,
        lon_rad: START.lon_rad,
        alt_m: 0.0,
    }
}

fn theta() -> Vector3<f64> {
    Vector3::new(THETA[0], THETA[1], THETA[2])
}

fn config<T: Real>(baro: BaroDamping<T>) -> NavigatorConfig<T> {
    let alignment = TaConfig::<T>::flight(PaperCase::Case1);
    NavigatorConfig {
        lever_arm: LeverArm {
            nominal_m: alignment.lever_arm_m,
            sigma_m: Vector3::from_element(T::lit(0.01)),
        },
        alignment,
        priors: HandoverPriors {
            accel_bias_sigma_m_s2: T::lit(1e-3),
            gyro_bias_sigma_rad_s: T::lit(5e-8),
            gimbal_bias_sigma_rad: T::lit(7e-4),
        },
        ins: SeekerInsConfig::flight(Landmark::new(landmark_position()).unwrap()),
        imu_dt_s: T::lit(DT),
        separation: SeparationCheck {
            specific_force_jump_m_s2: T::lit(4.0),
            confirm_window_s: T::lit(0.3),
            coast_s: T::lit(COAST_S),
        },
        baro,
        timeouts: AidTimeouts {
            master_s: T::lit(0.5),
            baro_s: T::lit(1.0),
            seeker_s: T::lit(2.0),
        },
    }
}

fn baro_model<T: Real>() -> BaroErrorModel<T> {
    BaroErrorModel {
        white_sigma_m: T::lit(1.0),
        markov_sigma_m: T::lit(5.0),
        markov_tau_s: T::lit(100.0),
        lag_s: T::lit(0.0),
    }
}

/// Time, state, body rate, specific force of the master at one tick.
type MasterLog = (Timestamp, InsState<f64>, Vector3<f64>, Vector3<f64>);

/// The world of the test, in f64: a master INS mechanization (nav-core's `Ins`, used here as a
/// generator: whatever it integrates *is* the truth) fed with the increments of level flight,
/// and after separation the missile's own.
struct World {
    master: Ins<f64>,
    missile: Option<Ins<f64>>,
    /// Master truth per tick (for the late master samples).
    master_log: Vec<MasterLog>,
    level_dth: Vector3<f64>,
    level_dv: Vector3<f64>,
    k: u64,
}

impl World {
    fn new() -> Self {
        let v = Vector3::new(SPEED_M_S, 0.0, 0.0);
        let lat = START.lat_rad;
        let w_in = earth_rate_ned(lat) + transport_rate_ned(lat, START.alt_m, &v);
        let coriolis =
            (earth_rate_ned(lat) * 2.0 + transport_rate_ned(lat, START.alt_m, &v)).cross(&v);
        let g = normal_gravity_m_s2(lat, START.alt_m);
        let f = coriolis - Vector3::new(0.0, 0.0, g);
        let state = InsState {
            position: START,
            vel_ned_m_s: v,
            q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        };
        Self {
            master: Ins::new(state, DT).unwrap(),
            missile: None,
            master_log: Vec::new(),
            level_dth: w_in * DT,
            level_dv: f * DT,
            k: 0,
        }
    }

    fn time(&self) -> Timestamp {
        Timestamp::from_micros(self.k * DT_US)
    }

    fn c_m_s() -> Matrix3<f64> {
        exp_so3(&(-theta()))
    }

    /// The missile's truth at the current tick (under the wing: the master's moved by the lever
    /// arm, its attitude composed with θ).
    fn missile_truth(&self, lever: &Vector3<f64>) -> InsState<f64> {
        if let Some(m) = &self.missile {
            return *m.state();
        }
        let s = self.master.state();
        let c_m_n = quat_to_dcm(&s.q_b_n);
        let l_n = c_m_n * lever;
        let (rm, rn) = crate::earth::radii_m(s.position.lat_rad);
        let position = Position {
            lat_rad: s.position.lat_rad + l_n.x / (rm + s.position.alt_m),
            lon_rad: s.position.lon_rad
                + l_n.y / ((rn + s.position.alt_m) * s.position.lat_rad.cos()),
            alt_m: s.position.alt_m - l_n.z,
        };
        InsState {
            position,
            vel_ned_m_s: s.vel_ned_m_s,
            q_b_n: crate::math::rotation::dcm_to_quat(&(c_m_n * exp_so3(&theta()))),
        }
    }

    /// Advances one tick; returns the slave increment.
    fn step(&mut self, lever: &Vector3<f64>) -> ImuIncrement<f64> {
        self.k += 1;
        let t = self.time();
        let ts = t.as_secs_f64();
        if ts > SEPARATION_S && self.missile.is_none() {
            // Separation: the missile leaves with its state at the previous tick.
            let truth = self.missile_truth(lever);
            let mut ins = Ins::new(truth, DT).unwrap();
            // Its clock: the previous tick.
            let _ = &mut ins;
            self.missile = Some(ins);
        }
        let c = Self::c_m_s();
        let dth_s = c * self.level_dth;
        let in_drop = ts > SEPARATION_S && ts <= SEPARATION_S + DROP_S;
        let dv_s = if in_drop {
            Vector3::zeros()
        } else {
            c * self.level_dv
        };
        let inc_m = ImuIncrement {
            time: t,
            delta_theta_rad: self.level_dth,
            delta_v_m_s: self.level_dv,
        };
        self.master.step(&inc_m).unwrap();
        self.master_log.push((
            t,
            *self.master.state(),
            self.level_dth / DT,
            self.level_dv / DT,
        ));
        let inc_s = ImuIncrement {
            time: t,
            delta_theta_rad: dth_s,
            delta_v_m_s: dv_s,
        };
        if let Some(m) = &mut self.missile {
            m.step(&inc_s).unwrap();
        }
        inc_s
    }

    /// The master sample of `LATENCY_TICKS` ago (every second tick, before separation).
    fn master_sample<T: Real>(&self) -> Option<MasterNav<T>> {
        if self.k % 2 != 0 || self.k <= LATENCY_TICKS {
            return None;
        }
        let idx = usize::try_from(self.k - LATENCY_TICKS - 1).ok()?;
        let (t, s, w, f) = self.master_log.get(idx)?;
        Some(MasterNav {
            time: *t,
            c_m_n: quat_to_dcm(&s.q_b_n).cast(),
            vel_ned_m_s: s.vel_ned_m_s.cast(),
            position: s.position,
            angular_rate_rad_s: w.cast(),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: f.cast(),
            attitude_sigma_rad: Vector3::new(T::lit(2e-4), T::lit(2e-4), T::lit(8e-4)),
            velocity_sigma_m_s: Vector3::new(T::lit(0.05), T::lit(0.05), T::lit(0.08)),
            position_sigma_m: Vector3::new(T::lit(3.0), T::lit(3.0), T::lit(5.0)),
        })
    }
}

fn cast_inc<T: Real>(i: &ImuIncrement<f64>) -> ImuIncrement<T> {
    ImuIncrement {
        time: i.time,
        delta_theta_rad: i.delta_theta_rad.cast(),
        delta_v_m_s: i.delta_v_m_s.cast(),
    }
}

fn tick_of<T: Real>(i: &ImuIncrement<f64>) -> ImuTick<T> {
    ImuTick {
        increment: cast_inc(i),
        clipped: ClipFlags::default(),
    }
}

fn initial<T: Real>(world: &World, lever: &Vector3<f64>) -> NavigatorInitial<T> {
    let mut truth = world.missile_truth(lever);
    // Start with the master's attitude (θ unknown) and 5 m off in north.
    truth.q_b_n = world.master.state().q_b_n;
    truth.position.lat_rad += 5.0 / 6_360_000.0;
    let mut p = SMatrix::<T, 9, 9>::zeros();
    for i in 0..9 {
        p[(i, i)] = T::lit([100.0, 100.0, 100.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4][i]);
    }
    NavigatorInitial {
        time: world.time(),
        state: InsState {
            position: truth.position,
            vel_ned_m_s: truth.vel_ned_m_s.cast(),
            q_b_n: truth.q_b_n.cast(),
        },
        nav_covariance: p,
    }
}

/// Attitude error φ (`Ĉ = exp(−[φ×]) C`) of a solution against the truth.
fn attitude_error<T: Real>(est: &InsState<T>, truth: &InsState<f64>) -> Vector3<f64> {
    let c_hat = quat_to_dcm(&Quaternion::from(est.q_b_n.coords.map(|x| x.to_f64())));
    let c = quat_to_dcm(&truth.q_b_n);
    -log_so3(&(c_hat * c.transpose()))
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
}

fn gimbal_truth(truth: &InsState<f64>) -> crate::seeker_ins::GimbalAngles<f64> {
    let lm = Landmark::new(landmark_position()).unwrap();
    let d = landmark_vector_ned(&truth.position, &lm);
    let c_b_n = quat_to_dcm(&truth.q_b_n);
    gimbal_angles_of(&(c_b_n.transpose() * d))
}

fn run_chain<T: Real>(baro: BaroDamping<T>, end_s: f64) -> Run {
    let cfg = config::<T>(baro);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = World::new();
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &initial(&world, &lever)).unwrap();
    let mut run = Run {
        phases: Vec::new(),
        transitions: Vec::new(),
        handover_phi: Vector3::zeros(),
        handover_sigma: Vector3::zeros(),
        final_health: HealthState::Initialising,
        terminal_pos_err_m: f64::NAN,
        baro_fused: 0,
        seeker_fused: 0,
    };
    let mut last_phase = Phase::Carry;
    let steps = (end_s / DT).round() as u64;
    for _ in 0..steps {
        let inc = world.step(&lever);
        let t = inc.time.as_secs_f64();
        let master = if t <= SEPARATION_S {
            world.master_sample::<T>()
        } else {
            None
        };
        let truth = world.missile_truth(&lever);
        let baro = (t > SEPARATION_S + COAST_S && world.k % 10 == 0).then(|| BaroSample {
            time: inc.time,
            altitude_m: T::lit(truth.position.alt_m),
        });
        let seeker = (t >= SEEKER_FROM_S && world.k % 10 == 0).then(|| LosSample {
            time: inc.time,
            gimbal: {
                let g = gimbal_truth(&truth);
                crate::seeker_ins::GimbalAngles {
                    pitch_rad: T::lit(g.pitch_rad),
                    yaw_rad: T::lit(g.yaw_rad),
                }
            },
        });
        let separation = ((t - SEPARATION_S).abs() < 0.5 * DT).then_some(inc.time);
        let aids = Aids {
            master: master.as_ref(),
            baro: baro.as_ref(),
            seeker: seeker.as_ref(),
            separation,
        };
        let report = nav.tick(&tick_of(&inc), &aids).unwrap();
        if let Some(tr) = report.transition {
            run.transitions.push(tr);
        }
        if report.phase != last_phase {
            run.phases.push((t, report.phase));
            if report.phase == Phase::Released {
                let phi = attitude_error(&report.solution.state, &truth);
                run.handover_phi = phi;
                run.handover_sigma = Vector3::from_fn(|i, _| {
                    report.solution.nav_covariance[(6 + i, 6 + i)]
                        .to_f64()
                        .sqrt()
                });
            }
            last_phase = report.phase;
        }
        run.final_health = report.health;
        run.baro_fused = report.baro.counters.fused;
        run.seeker_fused = report.seeker.counters.fused;
        let s = &report.solution.state;
        let (rm, _) = crate::earth::radii_m(truth.position.lat_rad);
        run.terminal_pos_err_m = ((s.position.lat_rad - truth.position.lat_rad) * rm)
            .hypot(s.position.alt_m - truth.position.alt_m);
    }
    run
}

fn chain_phases_and_handover<T: Real>() {
    let run = run_chain::<T>(BaroDamping::Ekf(baro_model()), 27.0);
    let seq: Vec<Phase> = run.phases.iter().map(|p| p.1).collect();
    assert_eq!(
        seq,
        [Phase::Released, Phase::Midcourse, Phase::Terminal],
        "{:?}",
        run.phases
    );
    // Released at the first tick after the signal where the slave sees 0 g.
    let t_rel = run.phases[0].0;
    assert!(
        t_rel > SEPARATION_S && t_rel < SEPARATION_S + 0.05,
        "{t_rel}"
    );
    assert_eq!(
        run.transitions[0].cause,
        TransitionCause::SeparationConfirmed
    );
    let t_mid = run.phases[1].0;
    assert!((t_mid - t_rel - COAST_S).abs() < 0.015, "{t_mid}");
    let t_term = run.phases[2].0;
    assert!(
        (SEEKER_FROM_S..SEEKER_FROM_S + 0.2).contains(&t_term),
        "{t_term}"
    );
    // Hand-over attitude error within 3σ per axis.
    for i in 0..3 {
        assert!(
            run.handover_phi[i].abs() <= 3.0 * run.handover_sigma[i],
            "axis {i}: φ {:?} σ {:?}",
            run.handover_phi,
            run.handover_sigma
        );
    }
    assert!(run.baro_fused > 0);
    assert!(run.seeker_fused > 0);
    assert!(run.terminal_pos_err_m.is_finite());
    std::println!(
        "{}: hand-over φ {:?} rad, σ {:?} rad; terminal position error {:.2} m; health {:?}",
        core::any::type_name::<T>(),
        run.handover_phi,
        run.handover_sigma,
        run.terminal_pos_err_m,
        run.final_health
    );
}

#[test]
fn chain_runs_carry_to_terminal_f64() {
    chain_phases_and_handover::<f64>();
}

#[test]
fn chain_runs_carry_to_terminal_f32() {
    chain_phases_and_handover::<f32>();
}

/// Runs the carry phase for `secs` and returns the navigator and the world.
fn carry_for<T: Real>(secs: f64, master_until_s: f64) -> (FlightNavigator<T, 32>, World) {
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = World::new();
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &initial(&world, &lever)).unwrap();
    for _ in 0..(secs / DT).round() as u64 {
        let inc = world.step(&lever);
        let master = (inc.time.as_secs_f64() <= master_until_s)
            .then(|| world.master_sample::<T>())
            .flatten();
        let aids = Aids {
            master: master.as_ref(),
            ..Aids::NONE
        };
        nav.tick(&tick_of(&inc), &aids).unwrap();
    }
    (nav, world)
}

fn dump<T: Real>(nav: &FlightNavigator<T, 32>) -> String {
    format!("{nav:?}")
}

fn refused_inputs_change_nothing<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(2.0, 10.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    let inc = world.step(&lever);
    // A bad IMU sample: Err, the navigator unchanged bit for bit.
    let before = dump(&nav);
    let mut bad = tick_of::<T>(&inc);
    bad.increment.delta_v_m_s.x = T::lit(f64::NAN);
    assert!(matches!(
        nav.tick(&bad, &Aids::NONE),
        Err(NavError::NonFiniteInput { .. })
    ));
    assert_eq!(dump(&nav), before);
    let mut late = tick_of::<T>(&inc);
    late.increment.time = Timestamp::from_micros(inc.time.as_micros() - DT_US);
    assert_eq!(
        nav.tick(&late, &Aids::NONE),
        Err(NavError::TimeNotIncreasing)
    );
    assert_eq!(dump(&nav), before);
    // A bad master: refused, counted, nothing of it applied (same solution as without it).
    let mut twin = nav.clone();
    let mut m = world.master_sample::<T>().or_else(|| {
        world.k -= 1;
        let s = world.master_sample::<T>();
        world.k += 1;
        s
    });
    let m = m.as_mut().unwrap();
    m.c_m_n[(0, 0)] = T::lit(f64::NAN);
    let aids = Aids {
        master: Some(m),
        ..Aids::NONE
    };
    let r = nav.tick(&tick_of(&inc), &aids).unwrap();
    assert!(matches!(r.master.state, AidState::Refused(_)));
    assert_eq!(r.master.counters.refused, 1);
    let r2 = twin.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    assert_eq!(r.solution, r2.solution);
    // The next valid tick works.
    let inc = world.step(&lever);
    let m = world.master_sample::<T>();
    let r = nav
        .tick(
            &tick_of(&inc),
            &Aids {
                master: m.as_ref(),
                ..Aids::NONE
            },
        )
        .unwrap();
    assert_eq!(r.phase, Phase::Carry);
    // In flight: a bad LOS sample is refused with nothing changed, the next tick works.
    let mut nav = nav;
    let truth = world.missile_truth(&lever);
    let p0 = {
        let mut p = crate::seeker_ins::paper_initial_covariance::<T>();
        p *= T::lit(0.01);
        p
    };
    nav.release_with(&crate::seeker_ins::SeekerInsInitial {
        state: InsState {
            position: truth.position,
            vel_ned_m_s: truth.vel_ned_m_s.cast(),
            q_b_n: truth.q_b_n.cast(),
        },
        covariance: p0,
    })
    .unwrap();
    assert_eq!(nav.phase(), Phase::Released);
    let inc = world.step(&lever);
    let r = nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    assert_eq!(
        r.transition.map(|t| t.cause),
        Some(TransitionCause::ReleaseCommanded)
    );
    let before = dump(&nav);
    let inc = world.step(&lever);
    let mut bad = tick_of::<T>(&inc);
    bad.increment.delta_theta_rad.y = T::lit(f64::INFINITY);
    assert!(nav.tick(&bad, &Aids::NONE).is_err());
    assert_eq!(dump(&nav), before);
    assert!(nav.tick(&tick_of(&inc), &Aids::NONE).is_ok());
}

#[test]
fn refused_inputs_change_nothing_f64() {
    refused_inputs_change_nothing::<f64>();
}

#[test]
fn refused_inputs_change_nothing_f32() {
    refused_inputs_change_nothing::<f32>();
}

fn unconfirmed_and_timeout<T: Real>() {
    // Master for 3 s, then lost.
    let (mut nav, mut world) = carry_for::<T>(3.0, 100.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    // A release signal the IMU does not confirm (the missile stays on the wing).
    let mut last = None;
    for k in 0..60 {
        let inc = world.step(&lever);
        let m = world.master_sample::<T>();
        let aids = Aids {
            master: m.as_ref(),
            separation: (k == 0).then_some(inc.time),
            ..Aids::NONE
        };
        last = Some(nav.tick(&tick_of(&inc), &aids).unwrap());
    }
    let r = last.unwrap();
    assert_eq!(r.phase, Phase::Carry);
    assert_eq!(
        r.degradation.separation,
        SeparationStatus::SeparationUnconfirmed
    );
    assert_eq!(r.health, HealthState::Degraded);
    assert_eq!(r.degradation.master, AidAvailability::Available);
    // Master lost: TimedOut after master_s (0.5 s).
    let mut states = Vec::new();
    for _ in 0..80 {
        let inc = world.step(&lever);
        let r = nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        states.push((r.master.state, r.degradation.master));
    }
    assert_eq!(states[10], (AidState::Waiting, AidAvailability::Available));
    assert_eq!(
        states.last().copied(),
        Some((AidState::TimedOut, AidAvailability::TimedOut))
    );
    assert_eq!(nav.phase(), Phase::Carry);
}

#[test]
fn unconfirmed_separation_and_master_timeout_f64() {
    unconfirmed_and_timeout::<f64>();
}

#[test]
fn unconfirmed_separation_and_master_timeout_f32() {
    unconfirmed_and_timeout::<f32>();
}

#[test]
fn size_of_flight_navigator() {
    let s32 = core::mem::size_of::<FlightNavigator<f32, 32>>();
    let s128 = core::mem::size_of::<FlightNavigator<f32, 128>>();
    std::println!("size_of FlightNavigator<f32, 32> = {s32} B, <f32, 128> = {s128} B");
    assert!(s32 > 0);
}

#[test]
fn bad_configuration_is_named() {
    let mut c = config::<f64>(BaroDamping::Off);
    c.imu_dt_s = 0.02;
    let w = World::new();
    let lever = c.lever_arm.nominal_m;
    let init = initial::<f64>(&w, &lever);
    assert_eq!(
        FlightNavigator::<f64, 32>::new(&c, &init).unwrap_err(),
        NavError::InvalidConfig {
            field: "alignment.dt_s",
            issue: crate::error::ConfigIssue::OutOfRange
        }
    );
    let mut c = config::<f64>(BaroDamping::Ekf(BaroErrorModel {
        markov_tau_s: 0.0,
        ..baro_model()
    }));
    c.ins.gate = Gate::Off;
    assert!(matches!(
        FlightNavigator::<f64, 32>::new(&c, &init),
        Err(NavError::InvalidConfig {
            field: "baro.markov_tau_s",
            ..
        })
    ));
}

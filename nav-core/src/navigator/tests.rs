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
/// The seeker loses lock here (terminal continues on the baro).
const SEEKER_UNTIL_S: f64 = 26.5;

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
    // A twin flown through `tick_into` with one report slot reused for the whole run.
    let mut twin = nav.clone();
    let mut slot = twin.blank_report();
    let mut run = Run {
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
        let baro = (t > SEPARATION_S + COAST_S && world.k % 4 == 0).then(|| BaroSample {
            time: inc.time,
            altitude_m: T::lit(truth.position.alt_m),
        });
        let seeker =
            ((SEEKER_FROM_S..SEEKER_UNTIL_S).contains(&t) && world.k % 10 == 0).then(|| {
                LosSample {
                    time: inc.time,
                    gimbal: {
                        let g = gimbal_truth(&truth);
                        crate::seeker_ins::GimbalAngles {
                            pitch_rad: T::lit(g.pitch_rad),
                            yaw_rad: T::lit(g.yaw_rad),
                        }
                    },
                }
            });
        let separation = ((t - SEPARATION_S).abs() < 0.5 * DT).then_some(inc.time);
        let aids = Aids {
            master: master.as_ref(),
            baro: baro.as_ref(),
            seeker: seeker.as_ref(),
            separation,
        };
        let report = nav.tick(&tick_of(&inc), &aids).unwrap();
        twin.tick_into(&tick_of(&inc), &aids, &mut slot).unwrap();
        assert_eq!(slot, report, "tick_into writes the report tick returns");
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
        if report.phase == Phase::Midcourse {
            let p = &report.solution.nav_covariance;
            let mut m = 0.0_f64;
            for j in 0..9 {
                if j != 2 && j != 5 {
                    m = m
                        .max(p[(2, j)].to_f64().abs())
                        .max(p[(5, j)].to_f64().abs());
                }
            }
            run.midcourse_vertical_cross = m;
            run.midcourse_vertical_var = [p[(2, 2)].to_f64(), p[(5, 5)].to_f64()];
            run.midcourse_alt_err_m = report.solution.state.position.alt_m - truth.position.alt_m;
        }
        if report.phase == Phase::Carry && t > 2.0 && world.k % 100 == 0 {
            let e = nav_error(&report.solution.state, &truth);
            for (i, ei) in e.iter().enumerate() {
                let sigma = report.solution.nav_covariance[(i, i)].to_f64().sqrt();
                run.carry_worst_normalized = run.carry_worst_normalized.max(ei.abs() / sigma);
            }
        }
        if matches!(report.phase, Phase::Midcourse | Phase::Terminal)
            && matches!(cfg.baro, BaroDamping::Ekf(_))
            && world.k % 100 == 0
        {
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
            run.joint_min_correlation_eigenvalue = run
                .joint_min_correlation_eigenvalue
                .min(corr.symmetric_eigenvalues().min());
        }
        if (t - SEEKER_UNTIL_S).abs() < 0.5 * DT {
            run.baro_fused_at_seeker_loss = report.baro.counters.fused;
        }
        run.final_seeker = report.seeker.state;
        run.final_degradation = report.degradation;
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
    let run = run_chain::<T>(BaroDamping::Ekf(baro_model()), 90.0);
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
    // The seeker lost in terminal: TimedOut after seeker_s, the phase stays, the baro damps on.
    assert_eq!(run.final_seeker, AidState::TimedOut);
    assert_eq!(run.final_degradation.seeker, AidAvailability::TimedOut);
    assert_eq!(run.phases.last().map(|p| p.1), Some(Phase::Terminal));
    assert!(run.baro_fused > run.baro_fused_at_seeker_loss);
    assert_eq!(run.final_health, HealthState::Degraded);
    // The joint covariance of the 17 states and the baro error stays positive definite.
    assert!(
        run.joint_min_correlation_eigenvalue > 0.0,
        "{}",
        run.joint_min_correlation_eigenvalue
    );
    // Carry: the solution's error within 3σ of the hand-over covariance on every axis.
    assert!(
        run.carry_worst_normalized < 3.0,
        "{}",
        run.carry_worst_normalized
    );
    std::println!(
        "{}: carry worst |error|/σ {:.2}; smallest joint correlation eigenvalue {:e}",
        core::any::type_name::<T>(),
        run.carry_worst_normalized,
        run.joint_min_correlation_eigenvalue
    );
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
    // Through `tick_into`: the caller's report slot is left as it was too.
    let mut slot = nav.blank_report();
    slot.phase = Phase::Terminal;
    let slot_before = format!("{slot:?}");
    assert!(matches!(
        nav.tick_into(&bad, &Aids::NONE, &mut slot),
        Err(NavError::NonFiniteInput { .. })
    ));
    assert_eq!(dump(&nav), before);
    assert_eq!(format!("{slot:?}"), slot_before);
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

/// A master sample whose hand-over fails only after the alignment has stepped (the slave's
/// station, through the lever arm, beyond the INS's altitude range while the master is inside
/// it): refused, and the alignment undone — the navigator continues exactly as without it.
fn master_refused_after_the_alignment_step<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(1.0, 10.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    // Advance to a tick with a master sample.
    let mut inc = world.step(&lever);
    while world.master_sample::<T>().is_none() {
        nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        inc = world.step(&lever);
    }
    let mut m = world.master_sample::<T>().unwrap();
    // A banked master whose lever arm points up, at the top of the altitude range.
    let l0 = nav.config().lever_arm.nominal_m;
    let c = [T::lit(0.5), T::lit(-0.5)]
        .map(|roll| crate::math::rotation::euler_to_dcm(roll, T::zero(), T::zero()))
        .into_iter()
        .find(|c| (c * l0).z < T::lit(-1.0))
        .unwrap();
    m.c_m_n = c;
    m.position.alt_m = crate::seeker_ins::MAX_ALT_M - 0.5;
    let mut twin = nav.clone();
    let before = format!("{:?}", nav.alignment());
    let r = nav
        .tick(
            &tick_of(&inc),
            &Aids {
                master: Some(&m),
                ..Aids::NONE
            },
        )
        .unwrap();
    assert_eq!(
        r.master.state,
        AidState::Refused(NavError::InputOutOfRange {
            input: "master.position"
        })
    );
    assert_eq!(format!("{:?}", nav.alignment()), before);
    let r2 = twin.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    assert_eq!(r.solution, r2.solution);
    assert_eq!(
        format!("{:?}", nav.alignment()),
        format!("{:?}", twin.alignment())
    );
    // The next ticks (with master samples) as the twin's, bit for bit.
    for _ in 0..6 {
        let inc = world.step(&lever);
        let m = world.master_sample::<T>();
        let aids = Aids {
            master: m.as_ref(),
            ..Aids::NONE
        };
        let a = nav.tick(&tick_of(&inc), &aids).unwrap();
        let b = twin.tick(&tick_of(&inc), &aids).unwrap();
        assert_eq!(a.solution, b.solution);
        assert_eq!(a.master.last, b.master.last);
        // The refusal is the only count that differs.
        assert_eq!(a.master.counters.refused, b.master.counters.refused + 1);
        assert_eq!(a.master.counters.fused, b.master.counters.fused);
    }
    assert_eq!(
        format!("{:?}", nav.alignment()),
        format!("{:?}", twin.alignment())
    );
}

#[test]
fn master_refused_after_the_alignment_step_f64() {
    master_refused_after_the_alignment_step::<f64>();
}

#[test]
fn master_refused_after_the_alignment_step_f32() {
    master_refused_after_the_alignment_step::<f32>();
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

/// While a signalled separation awaits the IMU's confirmation, a master sample whose epoch is
/// later than one IMU interval before the signal's is not fused (nothing counted, the
/// alignment untouched); earlier ones are; after the window closes unconfirmed, all are again.
fn master_after_signal<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(3.0, 100.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    let mut signal = None;
    let mut prev: Option<(SeparationStatus, u32)> = None;
    let (mut early, mut withheld, mut resumed) = (0, 0, 0);
    for k in 0..60 {
        let inc = world.step(&lever);
        let m = world.master_sample::<T>();
        let sig = *signal.get_or_insert(inc.time);
        let aids = Aids {
            master: m.as_ref(),
            separation: (k == 0).then_some(inc.time),
            ..Aids::NONE
        };
        let ta = format!("{:?}", nav.alignment());
        let r = nav.tick(&tick_of(&inc), &aids).unwrap();
        let awaiting = prev.is_some_and(|p| p.0 == SeparationStatus::AwaitingConfirmation);
        let fused_before = prev.map(|p| p.1);
        prev = Some((r.degradation.separation, r.master.counters.fused));
        let Some(m) = m else { continue };
        if awaiting && m.time.as_micros() + DT_US > sig.as_micros() {
            assert_eq!(r.master.state, AidState::NotUsedInPhase, "k {k}");
            assert_eq!(Some(r.master.counters.fused), fused_before);
            assert_eq!(format!("{:?}", nav.alignment()), ta);
            withheld += 1;
        } else {
            assert_eq!(r.master.state, AidState::Fused, "k {k}");
            if awaiting || k == 0 {
                early += 1;
            } else {
                resumed += 1;
            }
        }
    }
    assert_eq!(
        prev.map(|p| p.0),
        Some(SeparationStatus::SeparationUnconfirmed)
    );
    // The samples of the latency before the signal, the window's, the ones after it.
    assert!(
        early >= 1 && withheld >= 10 && resumed >= 10,
        "{early} {withheld} {resumed}"
    );
}

#[test]
fn master_after_signal_f64() {
    master_after_signal::<f64>();
}

#[test]
fn master_after_signal_f32() {
    master_after_signal::<f32>();
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

// ------------------------------------------------------------------ baro EKF (18th state)

use super::baro::{baro_update, BaroState};
use crate::contract::FusionOutcome;
use crate::math::kalman::fuse_scalar;
use crate::seeker_ins::{
    propagate_covariance_sparse, SeekerIns, SeekerInsInitial, SparseF, ACC_BIAS, POS, STATES, VEL,
};
use nalgebra::SVector;

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

/// `transition_times` is the generated kernel's Φ: with the noise off, the kernel maps
/// `v vᵀ` to `(Φ v)(Φ v)ᵀ`.
#[test]
fn cross_column_uses_the_kernels_transition() {
    let ekf = flight_ekf();
    let s = ekf.state();
    let f_ned = Vector3::new(1.5, -0.7, -9.6);
    let f = SparseF::new(&s.position, &s.vel_ned_m_s, &quat_to_dcm(&s.q_b_n), &f_ned);
    let dt = 0.1;
    let v = SVector::<f64, STATES>::from_fn(|i, _| 1e-3 * (1.0 + i as f64).sin());
    let mut p = v * v.transpose();
    propagate_covariance_sparse(&mut p, &f, dt, 0.0, 0.0).unwrap();
    let phi_v = crate::seeker_ins::transition_times_for_tests(&f, dt, &v);
    let reference = phi_v * phi_v.transpose();
    let err = (p - reference).abs().max() / reference.abs().max();
    assert!(err < 1e-12, "relative error {err}");
    assert!(
        (phi_v - v).norm() > 1e-6 * v.norm(),
        "Φ must not be the identity here"
    );
}

/// The block update equals the dense 18-state Joseph-form update to rounding, and H
/// matches finite differences of the predicted reading.
#[test]
fn baro_update_matches_dense_18_state_reference_and_finite_differences() {
    let ekf = flight_ekf();
    let p = *ekf.covariance();
    let (cross, s) = joint_column(&p);
    let st = BaroState {
        cross,
        variance_m2: s,
        bias_m: 1.5,
    };
    let tau = 0.3;
    let h = BaroState::h_row(tau);
    let z = 3004.0;
    let y = st.predicted_m(&ekf, tau) - z;
    let r = 1.0;
    let u = baro_update(&p, &st, &h, y, r, Gate::Off).unwrap();
    assert_eq!(u.report.outcome, FusionOutcome::Fused);
    // Dense reference.
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = s;
    assert!(pa.cholesky().is_some());
    let mut ha = SVector::<f64, 18>::zeros();
    ha.fixed_rows_mut::<17>(0).copy_from(&h);
    ha[17] = 1.0;
    let mut xa = SVector::<f64, 18>::zeros();
    let rep = fuse_scalar(&mut xa, &mut pa, &ha, y, r, Gate::Off).unwrap();
    assert!((rep.innovation_variance - u.report.innovation_variance).abs() < 1e-9);
    let scale = pa.abs().max();
    let mut got = SMatrix::<f64, 18, 18>::zeros();
    got.fixed_view_mut::<17, 17>(0, 0).copy_from(&u.p);
    got.fixed_view_mut::<17, 1>(0, 17).copy_from(&u.cross);
    got.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&u.cross.transpose());
    got[(17, 17)] = u.variance_m2;
    let e_p = (got - pa).abs().max() / scale;
    assert!(e_p < 1e-12, "P relative error {e_p}");
    let e_x = (u.dx - xa.fixed_rows::<17>(0)).norm() + (u.db_m - xa[17]).abs();
    assert!(e_x < 1e-9 * xa.norm().max(1e-12), "x error {e_x}");
    assert!(got.cholesky().is_some(), "joint P after the update is PD");
    // H against finite differences of ẑ = ĥ + τ V̂_D + b̂ (error state: estimate − truth).
    let eps = 1e-3;
    let shifted = |dh: f64, dvd: f64| {
        let mut init = SeekerInsInitial {
            state: *ekf.state(),
            covariance: p,
        };
        init.state.position.alt_m += dh;
        init.state.vel_ned_m_s.z += dvd;
        let e = <SeekerIns<f64> as crate::contract::Estimator>::new(ekf.config(), &init).unwrap();
        st.predicted_m(&e, tau)
    };
    let z0 = st.predicted_m(&ekf, tau);
    assert!(((shifted(eps, 0.0) - z0) / eps - h[POS + 2]).abs() < 1e-6);
    assert!(((shifted(0.0, eps) - z0) / eps - h[VEL + 2]).abs() < 1e-6);
    let mut st_b = st;
    st_b.bias_m += eps;
    assert!(((st_b.predicted_m(&ekf, tau) - z0) / eps - 1.0).abs() < 1e-9);
}

/// Prediction of the joint matrix: the column follows `e Φ c` and s the Markov law; the
/// joint matrix stays positive definite through the navigator's deferred covariance steps.
#[test]
fn baro_column_prediction_keeps_the_joint_covariance_pd() {
    let mut ekf = flight_ekf();
    let model = baro_model::<f64>();
    let p = *ekf.covariance();
    let (mut cross, s) = joint_column(&p);
    let mut st = BaroState {
        cross,
        variance_m2: s,
        bias_m: 2.0,
    };
    let mut t = Timestamp::from_micros(DT_US);
    for k in 0..25u64 {
        let inc = ImuIncrement {
            time: t,
            delta_theta_rad: Vector3::new(1e-4, -2e-4, 3e-4),
            delta_v_m_s: Vector3::new(0.02, 0.01, -0.098),
        };
        ekf.propagate_deferred(&inc, None).unwrap();
        if k % 10 == 9 {
            let c_before = st.cross;
            let dt = ekf
                .predict_covariance_cross(&mut st.cross)
                .unwrap()
                .unwrap();
            assert!((dt - 0.1).abs() < 1e-12);
            assert!((st.cross - c_before).norm() > 0.0);
            st.decay(&model, dt);
        }
        t = t.add_micros(DT_US);
    }
    cross = st.cross;
    let p = *ekf.covariance();
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = st.variance_m2;
    assert!(pa.cholesky().is_some());
    let e = (-0.2_f64 / 100.0).exp();
    assert!((st.bias_m - 2.0 * e).abs() < 1e-12);
    assert!(ekf.steps_pending() == 5);
}

fn chain_with_inertial_loop<T: Real>() {
    let mut vc = crate::vertical_channel::ClassicalConfig::<T>::paper();
    vc.baro_lag_s = T::zero();
    vc.latitude_rad = T::lit(START.lat_rad);
    let run = run_chain::<T>(BaroDamping::InertialLoop(vc), 27.0);
    let seq: Vec<Phase> = run.phases.iter().map(|p| p.1).collect();
    assert_eq!(seq, [Phase::Released, Phase::Midcourse, Phase::Terminal]);
    assert!(run.baro_fused > 0);
    // The EKF's vertical block is the loop's σ covariance, decoupled from the rest.
    assert_eq!(run.midcourse_vertical_cross, 0.0);
    assert!(run.midcourse_vertical_var[0] > 0.0 && run.midcourse_vertical_var[1] > 0.0);
    // The loop's σ covers the altitude error (truth and baro agree here).
    assert!(
        run.midcourse_alt_err_m.abs() <= 3.0 * run.midcourse_vertical_var[0].sqrt(),
        "{} vs σ {}",
        run.midcourse_alt_err_m,
        run.midcourse_vertical_var[0].sqrt()
    );
    std::println!(
        "{}: inertial loop: midcourse altitude error {:.3} m, σ_h {:.3} m, σ_VD {:.4} m/s",
        core::any::type_name::<T>(),
        run.midcourse_alt_err_m,
        run.midcourse_vertical_var[0].sqrt(),
        run.midcourse_vertical_var[1].sqrt()
    );
}

#[test]
fn chain_with_inertial_loop_f64() {
    chain_with_inertial_loop::<f64>();
}

#[test]
fn chain_with_inertial_loop_f32() {
    chain_with_inertial_loop::<f32>();
}

/// Releases `nav` at the world's missile truth with a tenth of the paper's initial σ.
fn release_at_truth<T: Real>(
    nav: &mut FlightNavigator<T, 32>,
    world: &World,
    lever: &Vector3<f64>,
) {
    let truth = world.missile_truth(lever);
    let mut p0 = crate::seeker_ins::paper_initial_covariance::<T>();
    p0 *= T::lit(0.01);
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

fn flight_aids_refused<T: Real>() {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = World::new();
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &initial(&world, &lever)).unwrap();
    let truth = world.missile_truth(&lever);
    release_at_truth(&mut nav, &world, &lever);
    // A second release is refused.
    assert!(nav
        .release_with(&crate::seeker_ins::SeekerInsInitial {
            state: InsState {
                position: truth.position,
                vel_ned_m_s: Vector3::zeros(),
                q_b_n: Quaternion::identity(),
            },
            covariance: crate::seeker_ins::paper_initial_covariance::<T>(),
        })
        .is_err());
    // Coast to midcourse.
    for _ in 0..((COAST_S / DT) as u64 + 2) {
        let inc = world.step(&lever);
        nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    }
    assert_eq!(nav.phase(), Phase::Midcourse);
    // Good baro samples for a while.
    for _ in 0..20 {
        let inc = world.step(&lever);
        let truth = world.missile_truth(&lever);
        let b = BaroSample {
            time: inc.time,
            altitude_m: T::lit(truth.position.alt_m + 0.5),
        };
        let r = nav
            .tick(
                &tick_of(&inc),
                &Aids {
                    baro: Some(&b),
                    ..Aids::NONE
                },
            )
            .unwrap();
        assert_eq!(r.baro.state, AidState::Fused);
    }
    // Bad baro and bad LOS: refused; the solution is the one without them.
    let inc = world.step(&lever);
    let bad_baro = BaroSample {
        time: inc.time,
        altitude_m: T::lit(f64::NAN),
    };
    let future_baro = BaroSample {
        time: inc.time.add_micros(1),
        altitude_m: T::lit(3000.0),
    };
    let bad_los = LosSample {
        time: inc.time,
        gimbal: crate::seeker_ins::GimbalAngles {
            pitch_rad: T::lit(f64::NAN),
            yaw_rad: T::zero(),
        },
    };
    for (baro, seeker) in [
        (Some(&bad_baro), None),
        (Some(&future_baro), None),
        (None, Some(&bad_los)),
    ] {
        let mut a = nav.clone();
        let mut b = nav.clone();
        let ra = a
            .tick(
                &tick_of(&inc),
                &Aids {
                    baro,
                    seeker,
                    ..Aids::NONE
                },
            )
            .unwrap();
        let rb = b.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        let refused = |s: AidState| matches!(s, AidState::Refused(_));
        assert!(refused(ra.baro.state) || refused(ra.seeker.state));
        assert_eq!(ra.solution, rb.solution);
        assert_eq!(a.baro_state(), b.baro_state());
        assert_eq!(a.phase(), Phase::Midcourse);
    }
    // The next valid tick works.
    assert!(nav.tick(&tick_of(&inc), &Aids::NONE).is_ok());
}

#[test]
fn flight_aids_refused_change_nothing_f64() {
    flight_aids_refused::<f64>();
}

#[test]
fn flight_aids_refused_change_nothing_f32() {
    flight_aids_refused::<f32>();
}

fn unsignalled<T: Real>() {
    // Master for 3 s, then lost; the missile drops without a signal at 4 s.
    let (mut nav, mut world) = carry_for::<T>(3.0, 3.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    let mut seen = None;
    for _ in 0..200 {
        let mut inc = world.step(&lever);
        if inc.time.as_secs_f64() > 3.9 {
            inc.delta_v_m_s = Vector3::zeros();
        }
        let r = nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        if let Some(t) = r.transition {
            seen = Some((t, r.degradation, r.health));
            break;
        }
    }
    let (t, d, h) = seen.unwrap();
    assert_eq!(t.cause, TransitionCause::UnsignalledSeparation);
    assert_eq!(t.to, Phase::Released);
    assert_eq!(d.separation, SeparationStatus::UnsignalledRelease);
    // Falling from 3.91 s; released once the IMU has read free fall for the 0.3 s window.
    assert!(
        (t.time.as_secs_f64() - 4.21).abs() < 1e-6,
        "{}",
        t.time.as_secs_f64()
    );
    assert_ne!(h, HealthState::Nominal);
}

/// The master lost in carry while the aircraft manoeuvres: the slave's specific force departs
/// from the stale last master sample by far more than the jump threshold (a 2 g pull-up), but
/// the missile is still on the wing (its IMU never reads free fall): no release.
fn stale_master_is_no_release<T: Real>() {
    let (mut nav, mut world) = carry_for::<T>(3.0, 3.0);
    let lever: Vector3<f64> = nav.config().lever_arm.nominal_m.map(|x| x.to_f64());
    let mut lost = 0;
    for _ in 0..200 {
        let mut inc = world.step(&lever);
        if inc.time.as_secs_f64() > 3.9 {
            inc.delta_v_m_s *= 2.0;
        }
        let r = nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        assert_eq!(r.transition, None);
        assert_eq!(r.degradation.separation, SeparationStatus::NotSignalled);
        lost += usize::from(r.master.state == AidState::TimedOut);
    }
    assert_eq!(nav.phase(), Phase::Carry);
    assert!(lost > 100, "the master was lost for {lost} ticks");
}

#[test]
fn stale_master_is_no_release_f64() {
    stale_master_is_no_release::<f64>();
}

#[test]
fn stale_master_is_no_release_f32() {
    stale_master_is_no_release::<f32>();
}

#[test]
fn unsignalled_release_f64() {
    unsignalled::<f64>();
}

#[test]
fn unsignalled_release_f32() {
    unsignalled::<f32>();
}

/// f32: a baro sample far more precise than the prior (σ_h 10 km, R 0.01 m²) keeps the joint
/// covariance PSD (conditioned R, stabilising noise). Without them the smallest correlation
/// eigenvalue of the result is −0.28 (measured).
#[test]
fn baro_update_keeps_the_joint_covariance_psd_in_f32() {
    let ekf = flight_ekf();
    let mut p: SMatrix<f32, STATES, STATES> = ekf.covariance().map(|x| x as f32);
    p[(POS + 2, POS + 2)] = 1.0e8;
    let (c, s) = joint_column(&p.map(f64::from));
    let st = BaroState::<f32> {
        cross: c.map(|x| x as f32),
        variance_m2: s as f32,
        bias_m: 0.0,
    };
    let h = BaroState::h_row(0.2_f32);
    let u = baro_update(&p, &st, &h, 700.0, 0.01, Gate::Off).unwrap();
    assert_eq!(u.report.outcome, FusionOutcome::Fused);
    let mut pa = SMatrix::<f32, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&u.p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&u.cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&u.cross.transpose());
    pa[(17, 17)] = u.variance_m2;
    assert!(crate::math::kalman::asymmetry(&pa) == 0.0);
    // Smallest eigenvalue of the correlation matrix (in f64, of the f32 result).
    let pd = pa.map(f64::from);
    let d = pd.diagonal().map(|v| 1.0 / v.max(1e-300).sqrt());
    let corr = SMatrix::<f64, 18, 18>::from_fn(|i, j| pd[(i, j)] * d[i] * d[j]);
    let min_eig = corr.symmetric_eigenvalues().min();
    std::println!("f32 baro update: smallest correlation eigenvalue {min_eig:e}");
    assert!(min_eig > 0.0, "{min_eig}");
    // The raised R: the innovation variance is at least hPhᵀ (1 + 1/κ).
    assert!(u.report.innovation_variance > 1.0e8);
}

/// The baro column through a LOS update equals the dense 18-state sequential update (b not in
/// the LOS rows) to rounding.
#[test]
fn baro_column_through_los_update_matches_dense_18_state_reference() {
    use crate::seeker_ins::{los_model_at, CrossColumn, GimbalAngles};
    let mut ekf = flight_ekf();
    let mut t = Timestamp::ZERO;
    for _ in 0..10 {
        t = t.add_micros(DT_US);
        ekf.propagate(&ImuIncrement {
            time: t,
            delta_theta_rad: Vector3::new(1e-5, 2e-5, -1e-5),
            delta_v_m_s: Vector3::new(0.0, 0.0, -0.098),
        })
        .unwrap();
    }
    let p = *ekf.covariance();
    let (cross, s) = joint_column(&p);
    // A LOS sample slightly off the INS's own.
    let st = *ekf.state();
    let d = landmark_vector_ned(&st.position, &ekf.config().landmark);
    let c_b_n = quat_to_dcm(&st.q_b_n);
    let g0 = gimbal_angles_of(&(c_b_n.transpose() * d));
    let gimbal = GimbalAngles {
        pitch_rad: g0.pitch_rad + 2e-3,
        yaw_rad: g0.yaw_rad - 1.5e-3,
    };
    let model = los_model_at(
        &st.position,
        &d,
        &c_b_n,
        &gimbal,
        ekf.config().seeker_noise_rad,
    )
    .unwrap();
    let mut col = CrossColumn {
        cross,
        variance: s,
        correction: 0.0,
    };
    let rep = ekf
        .update_los_cross(&LosSample { time: t, gimbal }, &mut col)
        .unwrap();
    assert_eq!(rep.pitch.outcome, FusionOutcome::Fused);
    assert_eq!(rep.yaw.outcome, FusionOutcome::Fused);
    // Dense reference.
    let mut pa = SMatrix::<f64, 18, 18>::zeros();
    pa.fixed_view_mut::<17, 17>(0, 0).copy_from(&p);
    pa.fixed_view_mut::<17, 1>(0, 17).copy_from(&cross);
    pa.fixed_view_mut::<1, 17>(17, 0)
        .copy_from(&cross.transpose());
    pa[(17, 17)] = s;
    let mut xa = SVector::<f64, 18>::zeros();
    let mut h1 = SVector::<f64, 18>::zeros();
    h1.fixed_rows_mut::<17>(0).copy_from(&model.h_pitch);
    let mut h2 = SVector::<f64, 18>::zeros();
    h2.fixed_rows_mut::<17>(0).copy_from(&model.h_yaw);
    fuse_scalar(
        &mut xa,
        &mut pa,
        &h1,
        model.residual_rad.x,
        model.variance_rad2.x,
        Gate::Off,
    )
    .unwrap();
    let nu2 = model.residual_rad.y - h2.dot(&xa);
    fuse_scalar(&mut xa, &mut pa, &h2, nu2, model.variance_rad2.y, Gate::Off).unwrap();
    let ref_cross = pa.fixed_view::<17, 1>(0, 17).into_owned();
    let e_c = (col.cross - ref_cross).abs().max() / ref_cross.abs().max();
    let e_s = (col.variance - pa[(17, 17)]).abs() / pa[(17, 17)];
    let e_b = (col.correction - xa[17]).abs() / xa[17].abs();
    assert!(e_c < 1e-9 && e_s < 1e-12 && e_b < 1e-9, "{e_c} {e_s} {e_b}");
    assert!(
        (col.cross - cross).norm() > 1e-6 * cross.norm(),
        "the update moved c"
    );
    // The 17-state P is the EKF's (simple form plus its stabilising noise).
    let e_p = (ekf.covariance() - pa.fixed_view::<17, 17>(0, 0))
        .abs()
        .max()
        / p.abs().max();
    assert!(e_p < 1e-9, "{e_p}");
}

// ------------------------------------------------------------------ stored design

/// `from_design` with the design written to values and read back is `new`, bit for bit, after
/// two seconds of carry; designs of another configuration, or a baro-loop design missing or
/// superfluous, are refused by name.
fn stored_design_is_new<T: Real>() {
    use crate::design::DesignValues;
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let world = World::new();
    let init = initial::<T>(&world, &lever);
    let design = FlightNavigator::<T, 32>::design(&cfg).unwrap();
    let mut values = std::vec![0.0; NavigatorDesign::<T, 5>::COUNT];
    design.write_values(&mut values).unwrap();
    let loaded = NavigatorDesign::<T, 5>::read_values(&values).unwrap();
    assert_eq!(loaded, design);
    let mut a = FlightNavigator::<T, 32>::new(&cfg, &init).unwrap();
    let mut b = FlightNavigator::<T, 32>::from_design(&cfg, &loaded, &init).unwrap();
    let mut wa = World::new();
    for _ in 0..200 {
        let inc = wa.step(&lever);
        let master = wa.master_sample::<T>();
        let aids = Aids {
            master: master.as_ref(),
            ..Aids::NONE
        };
        let ra = a.tick(&tick_of(&inc), &aids).unwrap();
        let rb = b.tick(&tick_of(&inc), &aids).unwrap();
        assert_eq!(format!("{ra:?}"), format!("{rb:?}"));
    }
    assert!(a.alignment().theta().iter().any(|x| *x != T::zero()));
    assert_eq!(dump(&a), dump(&b));
    // The EKF's design of another IMU.
    let mut other = cfg;
    other.ins.gyro_noise_density_rad_s_rt_hz *= T::lit(2.0);
    assert!(matches!(
        FlightNavigator::<T, 32>::from_design(&other, &loaded, &init),
        Err(NavError::InvalidConfig {
            field: "design",
            ..
        })
    ));
    // The alignment's design of another step.
    let mut other = cfg;
    other.alignment.mount_sigma_rad *= T::lit(2.0);
    assert!(FlightNavigator::<T, 32>::from_design(&other, &loaded, &init).is_err());
    // The loop asked for, no loop design stored.
    let mut vc = crate::vertical_channel::ClassicalConfig::<T>::paper();
    vc.baro_lag_s = T::zero();
    vc.latitude_rad = T::lit(START.lat_rad);
    let lp = config::<T>(BaroDamping::InertialLoop(vc));
    assert!(FlightNavigator::<T, 32>::new(&lp, &init).is_ok());
    assert_eq!(
        FlightNavigator::<T, 32>::from_design(&lp, &loaded, &init).unwrap_err(),
        NavError::InvalidConfig {
            field: "design.baro_loop",
            issue: crate::error::ConfigIssue::DesignMismatch
        }
    );
    // A bad flag value.
    values[TaDesignCount::<T>::N + 4] = 0.5;
    assert!(NavigatorDesign::<T, 5>::read_values(&values).is_err());
}

struct TaDesignCount<T>(core::marker::PhantomData<T>);
impl<T: Real> TaDesignCount<T> {
    const N: usize =
        <crate::transfer_alignment::TaDesign<T, 5> as crate::design::DesignValues>::COUNT;
}

#[test]
fn stored_design_is_new_f64() {
    stored_design_is_new::<f64>();
}

#[test]
fn stored_design_is_new_f32() {
    stored_design_is_new::<f32>();
}

/// The navigator's baro update (the gain over the row's two columns, P updated in place after
/// its check) gives the numbers of the reference [`baro_update`] bit for bit, f32 and f64.
fn baro_update_in_place_is_the_reference<T: Real>() {
    let ekf64 = flight_ekf();
    let p64 = *ekf64.covariance();
    let (c64, s64) = joint_column(&p64);
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let s0 = ekf64.state();
    let ekf = <SeekerIns<T> as crate::contract::Estimator>::new(
        &cfg.ins,
        &SeekerInsInitial {
            state: InsState {
                position: s0.position,
                vel_ned_m_s: s0.vel_ned_m_s.map(|x| T::lit(x)),
                q_b_n: Quaternion::from(s0.q_b_n.coords.map(|x| T::lit(x))),
            },
            covariance: p64.map(|x| T::lit(x)),
        },
    )
    .unwrap();
    let st = BaroState::<T> {
        cross: c64.map(|x| T::lit(x)),
        variance_m2: T::lit(s64),
        bias_m: T::lit(1.5),
    };
    let p = *ekf.covariance();
    for (tau, z) in [(0.3, 3004.0), (0.0, 2990.0), (0.05, 3000.5)] {
        let (tau, z) = (T::lit(tau), T::lit(z));
        let y = st.predicted_m(&ekf, tau) - z;
        let r = T::one();
        let reference = baro_update(&p, &st, &BaroState::h_row(tau), y, r, Gate::Off).unwrap();
        let Some(Ok(g)) = super::baro::baro_gain(&p, &st, tau, y, r, Gate::Off) else {
            panic!("the gain is formed");
        };
        let mut e = ekf;
        assert!(e.update_rank_one(&g.dx, &g.u, &g.k, g.delta).unwrap());
        let bits = |m: &[T]| m.iter().map(|v| v.to_f64().to_bits()).collect::<Vec<_>>();
        assert_eq!(
            bits(e.covariance().as_slice()),
            bits(reference.p.as_slice())
        );
        assert_eq!(bits(g.cross.as_slice()), bits(reference.cross.as_slice()));
        assert_eq!(bits(g.dx.as_slice()), bits(reference.dx.as_slice()));
        assert_eq!(
            g.variance_m2.to_f64().to_bits(),
            reference.variance_m2.to_f64().to_bits()
        );
        assert_eq!(g.db_m.to_f64().to_bits(), reference.db_m.to_f64().to_bits());
        // A gain whose P would not be a covariance is refused with nothing changed.
        let mut f = ekf;
        let huge = g.u * T::lit(1e6);
        assert!(!f.update_rank_one(&g.dx, &huge, &huge, g.delta).unwrap());
        assert_eq!(f, ekf);
    }
}

#[test]
fn baro_update_in_place_is_the_reference_f64() {
    baro_update_in_place_is_the_reference::<f64>();
}

#[test]
fn baro_update_in_place_is_the_reference_f32() {
    baro_update_in_place_is_the_reference::<f32>();
}

/// A LOS sample refused (a non-finite or out-of-range gimbal angle) while
/// IMU samples wait for their covariance step leaves the EKF (P, its pending step, every
/// counter) and the baro column exactly as the same tick without it.
fn refused_los_keeps_the_pending_step<T: Real>() {
    let cfg = config::<T>(BaroDamping::Ekf(baro_model()));
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = World::new();
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &initial(&world, &lever)).unwrap();
    release_at_truth(&mut nav, &world, &lever);
    for _ in 0..((COAST_S / DT) as u64 + 2) {
        let inc = world.step(&lever);
        nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    }
    assert_eq!(nav.phase(), Phase::Midcourse);
    // A baro sample (the column becomes non-zero), then IMU ticks: steps pending.
    let inc = world.step(&lever);
    let truth = world.missile_truth(&lever);
    let b = BaroSample {
        time: inc.time,
        altitude_m: T::lit(truth.position.alt_m + 0.5),
    };
    let aids = Aids {
        baro: Some(&b),
        ..Aids::NONE
    };
    assert_eq!(
        nav.tick(&tick_of(&inc), &aids).unwrap().baro.state,
        AidState::Fused
    );
    for _ in 0..3 {
        let inc = world.step(&lever);
        nav.tick(&tick_of(&inc), &Aids::NONE).unwrap();
    }
    assert!(nav.ekf().unwrap().steps_pending() > 0);
    assert!(nav.baro_state().cross.norm() > T::zero());
    let inc = world.step(&lever);
    let gimbal = |pitch: f64| crate::seeker_ins::GimbalAngles {
        pitch_rad: T::lit(pitch),
        yaw_rad: T::zero(),
    };
    let bad = [
        LosSample {
            time: inc.time,
            gimbal: gimbal(f64::NAN),
        },
        LosSample {
            time: inc.time,
            gimbal: gimbal(1.5),
        },
    ];
    for s in &bad {
        let mut a = nav.clone();
        let mut b = nav.clone();
        let aids = Aids {
            seeker: Some(s),
            ..Aids::NONE
        };
        let ra = a.tick(&tick_of(&inc), &aids).unwrap();
        let rb = b.tick(&tick_of(&inc), &Aids::NONE).unwrap();
        assert!(matches!(ra.seeker.state, AidState::Refused(_)));
        assert!(
            a.ekf().unwrap().steps_pending() > 1,
            "the step still pending"
        );
        assert_eq!(a.ekf(), b.ekf());
        assert_eq!(a.baro_state(), b.baro_state());
        assert_eq!(ra.solution, rb.solution);
    }
}

#[test]
fn refused_los_keeps_the_pending_step_f64() {
    refused_los_keeps_the_pending_step::<f64>();
}

#[test]
fn refused_los_keeps_the_pending_step_f32() {
    refused_los_keeps_the_pending_step::<f32>();
}

/// At the hand-over the EKF's accelerometer-bias states are the equivalent bias at the
/// carry's specific force: their variance is the prior's plus that of the scale factor and
/// misalignment at the last master epoch's specific force (≈ 1 g down), charged at once, not
/// at the drop's first covariance step (where the missile falls at ≈ 0 g).
fn handover_refers_the_bias_to_the_carry<T: Real>() {
    let cfg = config::<T>(BaroDamping::Off);
    let lever: Vector3<f64> = cfg.lever_arm.nominal_m.map(|x| x.to_f64());
    let mut world = World::new();
    let mut nav = FlightNavigator::<T, 32>::new(&cfg, &initial(&world, &lever)).unwrap();
    let e = cfg.ins.instrument_errors;
    let (sf, mis) = (
        e.accel_scale_factor.to_f64(),
        e.accel_misalignment_rad.to_f64(),
    );
    assert!(sf > 0.0 && mis > 0.0);
    let prior = cfg.priors.accel_bias_sigma_m_s2.to_f64().powi(2);
    for _ in 0..((SEPARATION_S + 1.0) / DT).round() as u64 {
        let inc = world.step(&lever);
        let t = inc.time.as_secs_f64();
        let master = if t <= SEPARATION_S {
            world.master_sample::<T>()
        } else {
            None
        };
        let aids = Aids {
            master: master.as_ref(),
            separation: ((t - SEPARATION_S).abs() < 0.5 * DT).then_some(inc.time),
            ..Aids::NONE
        };
        let r = nav.tick(&tick_of(&inc), &aids).unwrap();
        if r.phase == Phase::Released {
            let p = nav.ekf().unwrap().covariance();
            let g = 9.8;
            let want = [(mis * g).powi(2), (mis * g).powi(2), (sf * g).powi(2)];
            for (i, w) in want.iter().enumerate() {
                let added = p[(ACC_BIAS + i, ACC_BIAS + i)].to_f64() - prior;
                assert!((added - w).abs() < 0.03 * w, "axis {i}: {added:e} vs {w:e}");
            }
            return;
        }
    }
    panic!("not released");
}

#[test]
fn handover_refers_the_bias_to_the_carry_f64() {
    handover_refers_the_bias_to_the_carry::<f64>();
}

#[test]
fn handover_refers_the_bias_to_the_carry_f32() {
    handover_refers_the_bias_to_the_carry::<f32>();
}

//! Property tests of the flight navigator (`nav_core::navigator`), f32 and f64: random aid
//! schedules over a short synthetic chain carry → released → midcourse → terminal, with
//! hostile input on random ticks.
//!
//! The chain: straight level flight, the master INS = the truth (its late samples time-tagged,
//! with random latency and loss), the slave IMU = the truth's increments in a fixed mount
//! misalignment on a lever arm; the release signal, a 0 g drop, the coast, then baro and LOS
//! samples (truth plus small errors) at random ticks, coinciding ones included. IMU rates 100
//! to 1000 Hz, start time stamps 0 or hours. After every tick (`check_tick`): `Ok`; solution
//! and σ finite; the EKF's P exactly symmetric with a non-negative diagonal; the phase
//! monotone; the one-heavy-update rule (a valid baro sample on a tick whose LOS sample went
//! through the EKF is `Held`, the held sample fused or superseded on the next tick without a
//! LOS update, dropped only when older than `MAX_BARO_AGE_S`); the baro counters add up to
//! the samples offered; the baro timeout exactly when no valid sample came for `baro_s`.
//! Hostile input (`hostile_imu`, `hostile_aid`): an IMU sample that is refused changes
//! nothing (the navigator's `Debug` output, bit for bit); a refused aid sample changes
//! nothing but its aid's `refused` counter and its reported state.

use nalgebra::{Quaternion, SMatrix, Vector3};
use nav_core::contract::AidCounters;
use nav_core::earth::{earth_rate_ned, normal_gravity_m_s2, radii_m, transport_rate_ned};
use nav_core::math::rotation::{dcm_to_quat, exp_so3, quat_to_dcm};
use nav_core::navigator::{
    AidAvailability, AidState, AidTimeouts, Aids, BaroDamping, BaroErrorModel, FlightNavigator,
    HandoverPriors, ImuTick, LeverArm, MasterNav, NavigatorConfig, NavigatorInitial, Phase,
    SeparationCheck, TickReport, MAX_BARO_AGE_S,
};
use nav_core::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles, ImuIncrement, Ins, InsState,
    Landmark, LosSample, Position, SeekerInsConfig, MAX_DELTA_THETA_RAD,
};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{PaperCase, TaConfig, MAX_GAP_STEPS};
use nav_core::vertical_channel::BaroSample;
use nav_core::Real;
use proptest::prelude::*;

/// The histories' depth: `(H − 2) · dt` reaches 0.6 s at 100 Hz, 62 ms at 1 kHz.
const H: usize = 64;
type Nav<T> = FlightNavigator<T, H>;

const START: Position = Position {
    lat_rad: 0.6458,
    lon_rad: 2.2166,
    alt_m: 3000.0,
};
const SPEED_M_S: f64 = 200.0;
const THETA: [f64; 3] = [0.006, -0.004, 0.008];
const DROP_S: f64 = 0.4;
const FLY_S: f64 = 2.0;
/// Master samples at 50 Hz.
const MASTER_HZ: u64 = 50;

/// A small deterministic generator for the per-tick draws of one case.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        // xorshift64*
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_f491_4f6c_dd1d)
    }
    fn unit(&mut self) -> f64 {
        (self.next() >> 11) as f64 / (1u64 << 53) as f64
    }
    fn chance(&mut self, p: f64) -> bool {
        self.unit() < p
    }
    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

/// One case's schedule (drawn by proptest).
#[derive(Debug, Clone, Copy)]
struct Schedule {
    rate_hz: u64,
    start_us: u64,
    carry_s: f64,
    coast_s: f64,
    /// Largest master latency, as a fraction of what the history reaches (≤ 0.1 s).
    latency_frac: f64,
    master_loss: f64,
    p_baro: f64,
    p_los: f64,
    /// Probability that a LOS tick carries a baro sample too (coinciding).
    p_coincide: f64,
    /// Largest age of a baro sample at its arrival, s.
    baro_age_max_s: f64,
    /// A stretch of LOS samples on every tick (s; 0: none): the held sample waits.
    los_burst_s: f64,
    /// No baro sample after the burst's first tick while it lasts: the held one expires.
    quiet_burst: bool,
    hostile: u32,
    seed: u64,
}

fn schedule() -> impl Strategy<Value = Schedule> {
    (
        prop::sample::select(vec![100_u64, 125, 200, 250, 400, 500, 1000]),
        prop_oneof![Just(0_u64), 1_u64..40],
        (0.8..1.6f64, 0.1..0.5f64, 0.1..1.0f64, 0.0..0.3f64),
        (0.02..1.0f64, 0.01..0.4f64, 0.0..1.0f64, 0.0..0.2f64),
        (
            prop_oneof![Just(0.0), 0.2..1.6f64],
            any::<bool>(),
            0_u32..12,
            any::<u64>(),
        ),
    )
        .prop_map(|(rate_hz, hours, a, b, c)| Schedule {
            rate_hz,
            start_us: hours * 3_600_000_000 + hours * 7_919,
            carry_s: a.0,
            coast_s: a.1,
            latency_frac: a.2,
            master_loss: a.3,
            p_baro: b.0,
            p_los: b.1,
            p_coincide: b.2,
            baro_age_max_s: b.3,
            // A quiet burst outlasts the baro model's age limit.
            los_burst_s: if c.1 && c.0 > 0.0 {
                1.05 + 0.3 * c.0
            } else {
                c.0
            },
            quiet_burst: c.1,
            hostile: c.2,
            seed: c.3 | 1,
        })
}

fn landmark_position() -> Position {
    Position {
        lat_rad: START.lat_rad + 30_000.0 / 6_360_000.0,
        lon_rad: START.lon_rad,
        alt_m: 0.0,
    }
}

fn config<T: Real>(s: &Schedule) -> NavigatorConfig<T> {
    let dt = 1.0 / s.rate_hz as f64;
    let mut alignment = TaConfig::<T>::flight(PaperCase::Case1);
    alignment.dt_s = T::lit(dt);
    alignment.time_tolerance_s = T::lit(0.1 * dt);
    alignment.max_gap_steps = (s.rate_hz as u32).min(MAX_GAP_STEPS);
    let mut ins = SeekerInsConfig::flight(Landmark::new(landmark_position()).unwrap());
    ins.imu_dt_s = T::lit(dt);
    ins.covariance_interval_steps = (s.rate_hz / 10) as u16;
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
        ins,
        imu_dt_s: T::lit(dt),
        max_master_latency_s: T::lit(max_latency_ticks(s) as f64 * dt),
        separation: SeparationCheck {
            specific_force_jump_m_s2: T::lit(4.0),
            confirm_window_s: T::lit(0.3),
            unsignalled_onset_s: T::lit(0.3),
            coast_s: T::lit(s.coast_s),
        },
        baro: BaroDamping::Ekf(BaroErrorModel {
            white_sigma_m: T::lit(1.0),
            markov_sigma_m: T::lit(5.0),
            markov_tau_s: T::lit(100.0),
            lag_s: T::lit(0.0),
        }),
        timeouts: AidTimeouts {
            master_s: T::lit(0.5),
            baro_s: T::lit(1.0),
            seeker_s: T::lit(2.0),
        },
    }
}

/// The largest master latency in ticks: the history's reach (`H − 2` ticks) and 0.1 s.
fn max_latency_ticks(s: &Schedule) -> u64 {
    (s.rate_hz / 10).min(H as u64 - 2)
}

/// The truth: a master INS (nav-core's `Ins` as a generator) in level flight, the missile on
/// its lever arm until the release, then its own INS (0 g for `DROP_S`, then level force).
struct World {
    dt_us: u64,
    start_us: u64,
    master: Ins<f64>,
    missile: Option<Ins<f64>>,
    log: Vec<(Timestamp, InsState<f64>)>,
    dth: Vector3<f64>,
    dv: Vector3<f64>,
    lever: Vector3<f64>,
    sep_tick: u64,
    drop_ticks: u64,
    k: u64,
}

impl World {
    fn new(s: &Schedule, lever: Vector3<f64>) -> Self {
        let dt = 1.0 / s.rate_hz as f64;
        let v = Vector3::new(SPEED_M_S, 0.0, 0.0);
        let lat = START.lat_rad;
        let w_in = earth_rate_ned(lat) + transport_rate_ned(lat, START.alt_m, &v);
        let cor = (earth_rate_ned(lat) * 2.0 + transport_rate_ned(lat, START.alt_m, &v)).cross(&v);
        let f = cor - Vector3::new(0.0, 0.0, normal_gravity_m_s2(lat, START.alt_m));
        let state = InsState {
            position: START,
            vel_ned_m_s: v,
            q_b_n: Quaternion::new(1.0, 0.0, 0.0, 0.0),
        };
        Self {
            dt_us: 1_000_000 / s.rate_hz,
            start_us: s.start_us,
            master: Ins::new(state, dt).unwrap(),
            missile: None,
            log: Vec::new(),
            dth: w_in * dt,
            dv: f * dt,
            lever,
            sep_tick: (s.carry_s * s.rate_hz as f64).round() as u64,
            drop_ticks: (DROP_S * s.rate_hz as f64).round() as u64,
            k: 0,
        }
    }

    fn time(&self) -> Timestamp {
        Timestamp::from_micros(self.start_us + self.k * self.dt_us)
    }

    fn c_m_s() -> nalgebra::Matrix3<f64> {
        exp_so3(&-Vector3::from(THETA))
    }

    fn missile_truth(&self) -> InsState<f64> {
        if let Some(m) = &self.missile {
            return *m.state();
        }
        let s = self.master.state();
        let c_m_n = quat_to_dcm(&s.q_b_n);
        let l = c_m_n * self.lever;
        let (rm, rn) = radii_m(s.position.lat_rad);
        let p = s.position;
        InsState {
            position: Position {
                lat_rad: p.lat_rad + l.x / (rm + p.alt_m),
                lon_rad: p.lon_rad + l.y / ((rn + p.alt_m) * p.lat_rad.cos()),
                alt_m: p.alt_m - l.z,
            },
            vel_ned_m_s: s.vel_ned_m_s,
            q_b_n: dcm_to_quat(&(c_m_n * exp_so3(&Vector3::from(THETA)))),
        }
    }

    /// Advances one tick: the slave's increment.
    fn step(&mut self) -> ImuIncrement<f64> {
        if self.k == self.sep_tick {
            self.missile = Some(Ins::new(self.missile_truth(), self.dt_us as f64 * 1e-6).unwrap());
        }
        self.k += 1;
        let t = self.time();
        let c = Self::c_m_s();
        let in_drop = self.k > self.sep_tick && self.k <= self.sep_tick + self.drop_ticks;
        let inc_m = ImuIncrement {
            time: t,
            delta_theta_rad: self.dth,
            delta_v_m_s: self.dv,
        };
        self.master.step(&inc_m).unwrap();
        self.log.push((t, *self.master.state()));
        let inc_s = ImuIncrement {
            time: t,
            delta_theta_rad: c * self.dth,
            delta_v_m_s: if in_drop {
                Vector3::zeros()
            } else {
                c * self.dv
            },
        };
        if let Some(m) = &mut self.missile {
            m.step(&inc_s).unwrap();
        }
        inc_s
    }

    /// The master's sample of tick `k` (its time of validity), as the bus carries it.
    fn master_sample<T: Real>(&self, k: u64) -> MasterNav<T> {
        let (t, s) = self.log[(k - 1) as usize];
        let dt = self.dt_us as f64 * 1e-6;
        MasterNav {
            time: t,
            c_m_n: quat_to_dcm(&s.q_b_n).cast(),
            vel_ned_m_s: s.vel_ned_m_s.cast(),
            position: s.position,
            angular_rate_rad_s: (self.dth / dt).cast(),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: (self.dv / dt).cast(),
            attitude_sigma_rad: Vector3::new(T::lit(2e-4), T::lit(2e-4), T::lit(8e-4)),
            velocity_sigma_m_s: Vector3::new(T::lit(0.05), T::lit(0.05), T::lit(0.08)),
            position_sigma_m: Vector3::new(T::lit(3.0), T::lit(3.0), T::lit(5.0)),
        }
    }

    fn los<T: Real>(&self, rng: &mut Rng) -> LosSample<T> {
        let truth = self.missile_truth();
        let lm = Landmark::new(landmark_position()).unwrap();
        let d = landmark_vector_ned(&truth.position, &lm);
        let g = gimbal_angles_of(&(quat_to_dcm(&truth.q_b_n).transpose() * d));
        LosSample {
            time: self.time(),
            gimbal: GimbalAngles {
                pitch_rad: T::lit(g.pitch_rad + 1e-4 * (rng.unit() - 0.5)),
                yaw_rad: T::lit(g.yaw_rad + 1e-4 * (rng.unit() - 0.5)),
            },
        }
    }

    fn initial<T: Real>(&self) -> NavigatorInitial<T> {
        let mut truth = self.missile_truth();
        truth.q_b_n = self.master.state().q_b_n;
        truth.position.lat_rad += 5.0 / 6_360_000.0;
        let d = [100.0, 100.0, 100.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4];
        NavigatorInitial {
            time: self.time(),
            state: InsState {
                position: truth.position,
                vel_ned_m_s: truth.vel_ned_m_s.cast(),
                q_b_n: truth.q_b_n.cast(),
            },
            nav_covariance: SMatrix::from_fn(|i, j| if i == j { T::lit(d[i]) } else { T::zero() }),
        }
    }
}

fn imu_tick<T: Real>(i: &ImuIncrement<f64>) -> ImuTick<T> {
    ImuTick {
        increment: ImuIncrement {
            time: i.time,
            delta_theta_rad: i.delta_theta_rad.cast(),
            delta_v_m_s: i.delta_v_m_s.cast(),
        },
        clipped: ClipFlags::default(),
    }
}

fn rank(p: Phase) -> u8 {
    match p {
        Phase::Carry => 0,
        Phase::Released => 1,
        Phase::Midcourse => 2,
        Phase::Terminal => 3,
    }
}

fn sum(c: &AidCounters) -> u64 {
    [c.fused, c.rejected, c.skipped, c.superseded, c.refused]
        .iter()
        .map(|&v| u64::from(v))
        .sum()
}

/// What the test knows of one tick's baro and LOS input.
#[derive(Debug, Clone, Copy, Default)]
struct Offered<T: Real> {
    /// A valid baro sample (later than every baro sample offered before, age ≤ 1 s).
    baro: Option<BaroSample<T>>,
    /// A baro sample that must be refused (hostile).
    bad_baro: bool,
    /// A LOS sample that went to the navigator, and whether it must be refused.
    los: bool,
    bad_los: bool,
}

/// The running record the checks keep between ticks.
struct Track<T: Real> {
    phase: Phase,
    held: Option<BaroSample<T>>,
    baro: AidCounters,
    /// Baro samples offered in a phase that uses them (every one counted somewhere).
    baro_offered: u64,
    midcourse_at: Option<Timestamp>,
    last_valid_baro: Option<Timestamp>,
    ticks: u64,
}

impl<T: Real> Track<T> {
    fn new() -> Self {
        Self {
            phase: Phase::Carry,
            held: None,
            baro: AidCounters::default(),
            baro_offered: 0,
            midcourse_at: None,
            last_valid_baro: None,
            ticks: 0,
        }
    }
}

fn finite<T: Real>(v: &[T]) -> bool {
    v.iter().all(|x| x.is_finite())
}

/// The solution and the EKF's P after a tick.
fn check_numbers<T: Real>(nav: &Nav<T>, r: &TickReport<T>) -> Result<(), String> {
    let s = &r.solution;
    let p = s.state.position;
    if !([p.lat_rad, p.lon_rad, p.alt_m]
        .iter()
        .all(|v| v.is_finite())
        && finite(s.state.vel_ned_m_s.as_slice())
        && finite(s.state.q_b_n.coords.as_slice())
        && finite(s.nav_covariance.as_slice()))
    {
        return Err(format!("solution not finite: {s:?}"));
    }
    if s.nav_covariance.diagonal().iter().any(|v| *v < T::zero()) {
        return Err("negative variance in the solution".into());
    }
    if nav.ekf().is_some() != (r.phase != Phase::Carry) {
        return Err(format!("EKF {} in {:?}", nav.ekf().is_some(), r.phase));
    }
    if let Some(e) = nav.ekf() {
        let pk = e.covariance();
        if !finite(pk.as_slice()) || pk != &pk.transpose() {
            return Err("EKF P not finite or not exactly symmetric".into());
        }
        if pk.diagonal().iter().any(|v| *v < T::zero()) {
            return Err("EKF P with a negative variance".into());
        }
    }
    Ok(())
}

/// Phase order and transitions; the seeker's state by phase.
fn check_phase<T: Real>(nav: &Nav<T>, r: &TickReport<T>, tr: &mut Track<T>) -> Result<(), String> {
    if r.phase != nav.phase() || rank(r.phase) < rank(tr.phase) {
        return Err(format!("phase {:?} after {:?}", r.phase, tr.phase));
    }
    if r.phase != tr.phase {
        let t = r.transition.ok_or("phase change without a transition")?;
        if t.from != tr.phase || rank(t.to) > rank(r.phase) || t.time != r.solution.time {
            return Err(format!(
                "transition {t:?} from {:?} to {:?}",
                tr.phase, r.phase
            ));
        }
        if t.to == Phase::Midcourse {
            tr.midcourse_at = Some(t.time);
        }
    }
    if r.phase == Phase::Terminal
        && tr.phase != Phase::Terminal
        && r.seeker.state != AidState::Fused
    {
        return Err(format!(
            "terminal without a fused LOS: {:?}",
            r.seeker.state
        ));
    }
    let seeker_used = rank(r.phase) >= 2;
    if seeker_used == (r.seeker.state == AidState::NotUsedInPhase) {
        return Err(format!("seeker {:?} in {:?}", r.seeker.state, r.phase));
    }
    tr.phase = r.phase;
    Ok(())
}

/// The baro in a phase that does not use it: ignored, nothing held, nothing counted.
fn check_baro_unused<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    tr: &Track<T>,
) -> Result<(), String> {
    if r.baro.state != AidState::NotUsedInPhase
        || nav.held_baro().is_some()
        || r.baro.counters != tr.baro
    {
        return Err(format!("baro used in {:?}: {:?}", r.phase, r.baro));
    }
    Ok(())
}

/// The one-heavy-update rule, the counters' identity and the baro timeout.
fn check_baro<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    off: &Offered<T>,
    tr: &mut Track<T>,
) -> Result<(), String> {
    let now = r.solution.time;
    let (c0, c) = (tr.baro, r.baro.counters);
    let held = nav.held_baro().copied();
    if off.baro.is_some() || off.bad_baro {
        tr.baro_offered += 1;
    }
    // Every sample offered is fused, rejected, skipped, superseded, refused or still held.
    if sum(&c) + u64::from(held.is_some()) != tr.baro_offered {
        return Err(format!(
            "counters {c:?} + held {} != {} offered",
            held.is_some(),
            tr.baro_offered
        ));
    }
    if c.refused - c0.refused != u32::from(off.bad_baro) {
        return Err(format!(
            "refused {} -> {} (bad sample {})",
            c0.refused, c.refused, off.bad_baro
        ));
    }
    if off.bad_baro != matches!(r.baro.state, AidState::Refused(_)) {
        return Err(format!(
            "baro {:?}, bad sample {}",
            r.baro.state, off.bad_baro
        ));
    }
    if off.los && (off.bad_los != matches!(r.seeker.state, AidState::Refused(_))) {
        return Err(format!(
            "seeker {:?}, bad sample {}",
            r.seeker.state, off.bad_los
        ));
    }
    let los_ran = off.los && !off.bad_los;
    let expired = tr.held.filter(|h| {
        now.micros_since(h.time)
            .is_none_or(|a| a > (MAX_BARO_AGE_S * 1e6) as u64)
    });
    let waiting = tr.held.filter(|_| expired.is_none());
    let candidate = off.baro.or(waiting);
    let done = |c: &AidCounters| u64::from(c.fused) + u64::from(c.rejected) + u64::from(c.skipped);
    let want_done = u64::from(expired.is_some()) + u64::from(candidate.is_some() && !los_ran);
    if done(&c) - done(&c0) != want_done {
        return Err(format!(
            "{c0:?} -> {c:?}: {want_done} fused/rejected/skipped expected"
        ));
    }
    if c.superseded - c0.superseded != u32::from(off.baro.is_some() && waiting.is_some()) {
        return Err(format!("superseded {c0:?} -> {c:?}"));
    }
    match (candidate, los_ran) {
        (Some(b), true) => {
            if held != Some(b) || !(off.bad_baro || r.baro.state == AidState::Held) {
                return Err(format!(
                    "LOS tick: baro {:?}, held {held:?}, want {b:?}",
                    r.baro.state
                ));
            }
        }
        (Some(_), false) => {
            let fused = matches!(
                r.baro.state,
                AidState::Fused | AidState::Rejected | AidState::Waiting
            );
            if held.is_some() || !(off.bad_baro || fused) {
                return Err(format!(
                    "tick without LOS: baro {:?}, held {held:?}",
                    r.baro.state
                ));
            }
        }
        (None, _) => {
            if held.is_some() || matches!(r.baro.state, AidState::Held | AidState::Fused) {
                return Err(format!("no sample: baro {:?}, held {held:?}", r.baro.state));
            }
        }
    }
    if off.baro.is_some() {
        tr.last_valid_baro = Some(now);
    }
    check_baro_timeout(r, tr)?;
    tr.held = held;
    Ok(())
}

/// The baro timeout exactly when no valid sample arrived for `baro_s` (1 s) since midcourse.
fn check_baro_timeout<T: Real>(r: &TickReport<T>, tr: &Track<T>) -> Result<(), String> {
    let since = tr
        .last_valid_baro
        .max(tr.midcourse_at)
        .ok_or("midcourse start unknown")?;
    let gap_s = r.solution.time.signed_seconds_since::<f64>(since);
    let timed_out = r.degradation.baro == AidAvailability::TimedOut;
    if (timed_out && gap_s < 1.0 - 1e-3) || (!timed_out && gap_s > 1.0 + 1e-3) {
        return Err(format!(
            "baro {:?} after {gap_s} s without a sample",
            r.degradation.baro
        ));
    }
    Ok(())
}

/// Every check after a tick.
fn check_tick<T: Real>(
    nav: &Nav<T>,
    r: &TickReport<T>,
    off: &Offered<T>,
    tr: &mut Track<T>,
) -> Result<(), String> {
    check_numbers(nav, r)?;
    check_phase(nav, r, tr)?;
    if rank(r.phase) >= 2 {
        check_baro(nav, r, off, tr)?;
    } else {
        check_baro_unused(nav, r, tr)?;
    }
    tr.baro = r.baro.counters;
    tr.ticks += 1;
    Ok(())
}

/// `Debug` output with every `refused: N` counter blanked.
fn without_refusals(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut rest = s;
    while let Some(i) = rest.find("refused: ") {
        let (head, tail) = rest.split_at(i + "refused: ".len());
        out.push_str(head);
        out.push('#');
        rest = tail.trim_start_matches(|c: char| c.is_ascii_digit());
    }
    out.push_str(rest);
    out
}

/// A refused IMU sample (`imu` corrupted by `kind`, with this tick's aids): `Err`, and the
/// navigator exactly as before (its `Debug` output).
fn hostile_imu<T: Real>(
    nav: &mut Nav<T>,
    imu: &ImuTick<T>,
    aids: &Aids<'_, T>,
    kind: u64,
    axis: usize,
) -> Result<(), String> {
    let mut bad = *imu;
    let last = nav.solution().time;
    let dt_us = imu.increment.time.micros_since(last).unwrap_or(1);
    match kind {
        0 => bad.increment.delta_theta_rad[axis] = T::lit(f64::NAN),
        1 => bad.increment.delta_v_m_s[axis] = T::lit(f64::INFINITY),
        2 => bad.increment.delta_theta_rad[axis] = T::lit(f64::NEG_INFINITY),
        3 => bad.increment.delta_v_m_s[axis] = T::lit(1e30),
        4 => bad.increment.time = last,
        5 => bad.increment.time = Timestamp::from_micros(last.as_micros().saturating_sub(dt_us)),
        _ => bad.increment.delta_theta_rad[axis] = T::lit(2.0 * MAX_DELTA_THETA_RAD),
    }
    let before = format!("{nav:?}");
    match nav.tick(&bad, aids) {
        Ok(r) => Err(format!(
            "bad IMU sample (kind {kind}) accepted: {:?}",
            r.phase
        )),
        Err(_) if format!("{nav:?}") != before => Err(format!(
            "refused IMU sample (kind {kind}) changed the navigator"
        )),
        Err(_) => Ok(()),
    }
}

#[derive(Debug, Clone, Copy, PartialEq)]
enum Which {
    Master,
    Baro,
    Seeker,
}

fn status_mut<T: Real>(r: &mut TickReport<T>, w: Which) -> &mut nav_core::navigator::AidStatus<T> {
    match w {
        Which::Master => &mut r.master,
        Which::Baro => &mut r.baro,
        Which::Seeker => &mut r.seeker,
    }
}

/// A tick with a refused aid sample (`nav`, `ra`) against the same tick without it (`b`,
/// `rb`): the aid `Refused` (or `NotUsedInPhase` in a phase that ignores it), its `refused`
/// counter one up, everything else the same, the navigator's whole state included.
fn same_but_refused<T: Real>(
    nav: &Nav<T>,
    ra: &TickReport<T>,
    b: &Nav<T>,
    rb: &TickReport<T>,
    w: Which,
    used: bool,
) -> Result<(), String> {
    let mut patched = *ra;
    let s = status_mut(&mut patched, w);
    let refused = matches!(s.state, AidState::Refused(_));
    if refused != used && !(w == Which::Master && s.state == AidState::NotUsedInPhase) {
        return Err(format!(
            "bad {w:?} sample: {:?} (used in phase {used})",
            s.state
        ));
    }
    if refused {
        s.counters.refused -= 1;
    }
    s.state = status_mut(&mut rb.clone(), w).state;
    if &patched != rb {
        return Err(format!(
            "bad {w:?} sample changed the report:\n{ra:?}\n{rb:?}"
        ));
    }
    if without_refusals(&format!("{nav:?}")) != without_refusals(&format!("{b:?}")) {
        return Err(format!("bad {w:?} sample changed the navigator"));
    }
    Ok(())
}

/// Hostile aid samples: the slot a bad sample takes, and the sample.
struct BadAids<T: Real> {
    which: Which,
    master: MasterNav<T>,
    baro: BaroSample<T>,
    los: LosSample<T>,
}

fn bad_aid<T: Real>(
    w: &World,
    kind: u64,
    last_baro: Option<Timestamp>,
    last_los: Option<Timestamp>,
    rng: &mut Rng,
) -> BadAids<T> {
    let now = w.time();
    let nan = T::lit(f64::NAN);
    let mut master = w.master_sample::<T>(w.k);
    let mut baro = BaroSample {
        time: now,
        altitude_m: T::lit(3000.0),
    };
    let mut los = w.los::<T>(rng);
    let which = match kind % 3 {
        0 => Which::Master,
        1 => Which::Baro,
        _ => Which::Seeker,
    };
    match (which, kind / 3) {
        (Which::Master, 0) => master.vel_ned_m_s.y = nan,
        (Which::Master, 1) => master.c_m_n[(1, 2)] = T::lit(f64::INFINITY),
        (Which::Master, 2) => {
            master.time = Timestamp::from_micros(now.as_micros().saturating_sub(1_000_000))
        }
        (Which::Master, _) => master.time = now.add_micros(10_000),
        (Which::Baro, 0) => baro.altitude_m = nan,
        (Which::Baro, 1) => baro.altitude_m = T::lit(f64::INFINITY),
        (Which::Baro, 2) => baro.time = now.add_micros(1),
        (Which::Baro, _) => {
            baro.time = last_baro.unwrap_or(Timestamp::from_micros(
                now.as_micros().saturating_sub(1_500_000),
            ))
        }
        (Which::Seeker, 0) => los.gimbal.pitch_rad = nan,
        (Which::Seeker, 1) => los.gimbal.yaw_rad = T::lit(f64::NEG_INFINITY),
        (Which::Seeker, 2) => los.gimbal.pitch_rad = T::lit(3.0),
        (Which::Seeker, _) => match last_los {
            Some(t) => los.time = t,
            None => los.gimbal.yaw_rad = nan,
        },
    }
    BadAids {
        which,
        master,
        baro,
        los,
    }
}

/// The master bus: samples at `MASTER_HZ` in carry, lost at random, delivered in order with a
/// random latency up to the configured maximum.
struct Bus {
    queue: std::collections::VecDeque<(u64, u64)>,
    last_arrival: u64,
    every: u64,
    max_ticks: u64,
    draw_ticks: u64,
}

impl Bus {
    fn new(s: &Schedule) -> Self {
        let max_ticks = max_latency_ticks(s);
        Self {
            queue: Default::default(),
            last_arrival: 0,
            every: (s.rate_hz / MASTER_HZ).max(1),
            max_ticks,
            draw_ticks: (max_ticks as f64 * s.latency_frac) as u64,
        }
    }

    /// The sample arriving at the world's tick, if any.
    fn at<T: Real>(&mut self, w: &World, s: &Schedule, rng: &mut Rng) -> Option<MasterNav<T>> {
        let k = w.k;
        if k <= w.sep_tick && k % self.every == 0 && !rng.chance(s.master_loss) {
            let arrival = (k + rng.below(self.draw_ticks + 1)).max(self.last_arrival + 1);
            if arrival - k <= self.max_ticks {
                self.queue.push_back((arrival, k));
                self.last_arrival = arrival;
            }
        }
        let (_, epoch) = self.queue.front().filter(|(a, _)| *a == k).copied()?;
        self.queue.pop_front();
        Some(w.master_sample(epoch))
    }
}

/// What a case exercised.
#[derive(Debug, Default, Clone, Copy)]
struct Stats {
    ticks: u64,
    held: u32,
    superseded: u32,
    expired: u32,
    baro_fused: u32,
    terminal: bool,
    bad_imu: u32,
    bad_aids: u32,
    /// Samples refused: master, baro, seeker.
    refused: [u32; 3],
}

/// This tick's valid baro and LOS samples (after the release signal).
/// `burst`: in the LOS burst, the baro quiet there, a baro sample at its start.
fn draw_aids<T: Real>(
    w: &World,
    s: &Schedule,
    rng: &mut Rng,
    last_baro: &mut Option<Timestamp>,
    burst: (bool, bool, bool),
) -> (Option<BaroSample<T>>, Option<LosSample<T>>) {
    if w.k <= w.sep_tick {
        return (None, None);
    }
    let los = (burst.0 || rng.chance(s.p_los)).then(|| w.los::<T>(rng));
    let want_baro = (rng.chance(s.p_baro) || (los.is_some() && rng.chance(s.p_coincide)))
        && !burst.1
        || burst.2;
    let now = w.time().as_micros();
    let age_us = (rng.unit() * s.baro_age_max_s * 1e6) as u64;
    let time = Timestamp::from_micros(now.saturating_sub(age_us));
    let baro = (want_baro && last_baro.is_none_or(|t| time > t)).then(|| {
        *last_baro = Some(time);
        BaroSample {
            time,
            altitude_m: T::lit(w.missile_truth().position.alt_m + 2.0 * (rng.unit() - 0.5)),
        }
    });
    (baro, los)
}

fn run<T: Real>(s: &Schedule) -> Result<Stats, String> {
    let cfg = config::<T>(s);
    let mut w = World::new(s, cfg.lever_arm.nominal_m.map(|x| x.to_f64()));
    let mut nav = Nav::<T>::new(&cfg, &w.initial()).map_err(|e| format!("new: {e:?}"))?;
    let mut rng = Rng(s.seed);
    let rate = s.rate_hz as f64;
    let flight = w.sep_tick + w.drop_ticks;
    let total = flight + ((s.coast_s + FLY_S) * rate).round() as u64;
    let hostile: Vec<u64> = (0..s.hostile).map(|_| 1 + rng.below(total - 1)).collect();
    let burst_from = flight + ((s.coast_s + 0.3) * rate) as u64;
    let burst = burst_from..burst_from + (s.los_burst_s * rate) as u64;
    let mut bus = Bus::new(s);
    let (mut tr, mut st) = (Track::<T>::new(), Stats::default());
    let (mut last_baro, mut last_los, mut last_used_baro) = (None, None, None);
    for _ in 0..total {
        let inc = w.step();
        let imu = imu_tick::<T>(&inc);
        let k = w.k;
        let master = bus.at::<T>(&w, s, &mut rng);
        let (baro, los) = draw_aids::<T>(
            &w,
            s,
            &mut rng,
            &mut last_baro,
            (
                burst.contains(&k),
                s.quiet_burst && burst.contains(&k) && k > burst.start,
                s.quiet_burst && k == burst.start && !burst.is_empty(),
            ),
        );
        let separation = (k == w.sep_tick + 1).then_some(inc.time);
        let mut aids = Aids {
            master: master.as_ref(),
            baro: baro.as_ref(),
            seeker: los.as_ref(),
            separation,
        };
        let mut off = Offered {
            baro,
            bad_baro: false,
            los: los.is_some(),
            bad_los: false,
        };
        let kind = hostile.contains(&k).then(|| rng.below(19));
        if let Some(kind) = kind.filter(|k| *k < 7) {
            hostile_imu(&mut nav, &imu, &aids, kind, rng.below(3) as usize)
                .map_err(|e| format!("tick {k}: {e}"))?;
            st.bad_imu += 1;
        }
        let bad = kind
            .filter(|k| *k >= 7)
            .map(|kind| bad_aid::<T>(&w, kind - 7, last_used_baro, last_los, &mut rng));
        let reference = bad.as_ref().map(|_| (nav.clone(), aids));
        if let Some(b) = &bad {
            match b.which {
                Which::Master => aids.master = Some(&b.master),
                Which::Baro => (aids.baro, off.baro, off.bad_baro) = (Some(&b.baro), None, true),
                Which::Seeker => (aids.seeker, off.los, off.bad_los) = (Some(&b.los), true, true),
            }
        }
        let r = nav
            .tick(&imu, &aids)
            .map_err(|e| format!("tick {k}: valid IMU refused: {e:?}"))?;
        let used = rank(r.phase) >= 2;
        if let (Some(b), Some((mut nb, mut ab))) = (&bad, reference) {
            let used = match b.which {
                Which::Master => tr.phase == Phase::Carry,
                _ => used,
            };
            match b.which {
                Which::Master => ab.master = None,
                Which::Baro => ab.baro = None,
                Which::Seeker => ab.seeker = None,
            }
            let rb = nb
                .tick(&imu, &ab)
                .map_err(|e| format!("tick {k}: reference: {e:?}"))?;
            same_but_refused(&nav, &r, &nb, &rb, b.which, used)
                .map_err(|e| format!("tick {k}: {e} ({:?} {:?} {:?})", b.master, b.baro, b.los))?;
            st.bad_aids += 1;
            if !used {
                (off.bad_baro, off.bad_los, off.los) =
                    (false, false, los.is_some() && b.which != Which::Seeker);
            }
        }
        if !used {
            off.los = false;
        }
        let before = tr.baro;
        let held_before = tr.held;
        check_tick(&nav, &r, &off, &mut tr)
            .map_err(|e| format!("tick {k} ({:?}): {e}", r.phase))?;
        if r.baro.state == AidState::Held {
            st.held += 1;
        }
        if held_before.is_some() && r.baro.counters.skipped > before.skipped {
            st.expired += 1;
        }
        if off.los && !off.bad_los && !matches!(r.seeker.state, AidState::Refused(_)) {
            last_los = los.map(|l| l.time).or(last_los);
        }
        if used {
            last_used_baro = off.baro.map(|b| b.time).or(last_used_baro);
        }
        st.ticks += 1;
    }
    let end = nav.blank_report();
    let c = end.baro.counters;
    (st.superseded, st.baro_fused, st.terminal) =
        (c.superseded, c.fused, nav.phase() == Phase::Terminal);
    st.refused = [
        end.master.counters.refused,
        c.refused,
        end.seeker.counters.refused,
    ];
    Ok(st)
}

fn run_both(s: &Schedule) -> Result<(Stats, Stats), String> {
    let a = run::<f32>(s).map_err(|e| format!("f32: {e}"))?;
    let b = run::<f64>(s).map_err(|e| format!("f64: {e}"))?;
    Ok((a, b))
}

proptest! {
    #![proptest_config(ProptestConfig { cases: 24, .. ProptestConfig::default() })]

    /// Random aid schedules and hostile ticks over the chain, f32 and f64: every tick's
    /// checks (`check_tick`, `hostile_imu`, `same_but_refused`) hold.
    #[test]
    fn random_schedules_keep_the_navigator_contract(s in schedule()) {
        let r = run_both(&s);
        prop_assert!(r.is_ok(), "{:?}: {}", s, r.unwrap_err());
    }
}

/// The schedules exercise what the properties check: over the cases the proptest draws (the
/// same strategy, a fixed seed), holds, supersessions, expiries, terminal phases and hostile
/// samples of every kind occur.
#[test]
fn the_random_schedules_exercise_every_rule() {
    use proptest::strategy::ValueTree;
    use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
    let mut runner = TestRunner::new_with_rng(
        Config::default(),
        TestRng::from_seed(RngAlgorithm::ChaCha, &[7; 32]),
    );
    let mut total = Stats::default();
    let mut terminal = 0;
    for _ in 0..12 {
        let s = schedule().new_tree(&mut runner).unwrap().current();
        let st = run::<f32>(&s).unwrap();
        println!("{s:?}\n  {st:?}");
        total.ticks += st.ticks;
        total.held += st.held;
        total.superseded += st.superseded;
        total.expired += st.expired;
        total.baro_fused += st.baro_fused;
        total.bad_imu += st.bad_imu;
        total.bad_aids += st.bad_aids;
        for (t, r) in total.refused.iter_mut().zip(st.refused) {
            *t += r;
        }
        terminal += u32::from(st.terminal);
    }
    println!("{total:?}, terminal {terminal}");
    let t = &total;
    assert!(
        t.held > 0 && t.superseded > 0 && t.expired > 0 && t.baro_fused > 0,
        "{t:?}"
    );
    assert!(
        t.bad_imu > 0 && t.bad_aids > 0 && t.refused.iter().all(|&r| r > 0),
        "{t:?}"
    );
    assert!(terminal > 0);
}

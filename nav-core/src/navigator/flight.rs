//! The navigator value and its tick (module doc of [`super`]).

use super::baro::{baro_age_s, baro_gain, BaroState};
use super::design::NavigatorDesign;
use super::handover::{
    hand_over_checked_master, refer_to_carry, validate_master, AlignmentAtRelease, MasterAtRelease,
    NavBlocks,
};
use super::types::{
    AidAvailability, AidState, AidStatus, Aids, BaroDamping, Degradation, ImuTick, MasterNav,
    NavSolution, NavigatorConfig, NavigatorInitial, Phase, SeparationStatus, TickReport,
    Transition, TransitionCause,
};
use crate::contract::{AidCounters, Estimator, FusionOutcome, FusionReport};
use crate::earth::{earth_rate_ned, radii_m, transport_rate_ned};
use crate::math::rotation::{
    exp_so3, log_so3, quat_from_rotation_vector, quat_mul, quat_normalize, quat_to_dcm,
};
use crate::seeker_ins::{
    ClipFlags, CrossColumn, ImuIncrement, Ins, InsState, LosSample, SeekerIns, SeekerInsDesign,
    SeekerInsInitial, STATES,
};
use crate::time::Timestamp;
use crate::transfer_alignment::{
    compensate_lever_arm, MasterSample, SlaveHistory, SlaveSample, TaInitial, TransferAlignment,
};
use crate::vertical_channel::{
    BaroSample, ClassicalDesign, ClassicalLoop, ImuSample as VerticalImu, InitialState,
};
use crate::{HealthState, NavError, Real};
use heapless::Deque;
use nalgebra::Quaternion;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// One INS state of the carry phase at a tick time (for the master's late epochs).
#[derive(Debug, Clone, Copy)]
struct Snapshot<T> {
    time: Timestamp,
    state: InsState<T>,
}

/// What separation is judged against, from the last fused master sample.
#[derive(Debug, Clone, Copy)]
struct MasterRecord<T> {
    /// Its lever-arm-compensated specific force in slave axes, m/s².
    f_slave_m_s2: Vector3<T>,
}

/// What the baro-inertial loop did with this tick's baro sample.
#[derive(Debug, Clone, Copy)]
enum LoopBaro<T> {
    /// Its report of a new sample (`None`: no new sample).
    Report(Option<FusionReport<T>>),
    /// Refused by the loop.
    Refused(NavError),
}

/// The three aids' reports of a tick.
type AidReports<T> = [AidStatus<T>; 3];

/// One aid's running record.
#[derive(Debug, Clone, Copy, Default)]
struct AidTrack<T> {
    last: Option<FusionReport<T>>,
    counters: AidCounters,
    /// Last usable sample (fused, or accepted for the baro), for the timeout.
    last_ok: Option<Timestamp>,
}

impl<T: Real> AidTrack<T> {
    fn status(&self, state: AidState) -> AidStatus<T> {
        AidStatus {
            state,
            last: self.last,
            counters: self.counters,
        }
    }
}

/// The flight navigator (module doc of [`super`]): generic over the float `T`, the
/// alignment filter's dimensions `K`, `N`, and the depth `H` of the slave and INS histories
/// (≥ master latency × IMU rate).
#[derive(Debug, Clone)]
pub struct Navigator<T: Real, const K: usize, const N: usize, const H: usize> {
    config: NavigatorConfig<T>,
    design: SeekerInsDesign<T>,
    phase: Phase,
    /// Time of the last accepted tick (the initial time before the first).
    time: Timestamp,
    start: Timestamp,
    ticked: bool,
    ins: Ins<T>,
    ta: TransferAlignment<T, K, N>,
    history: SlaveHistory<T, H>,
    snapshots: Deque<Snapshot<T>, H>,
    /// The carry solution's covariance (NED convention).
    carry_cov: SMatrix<T, 9, 9>,
    /// The navigation blocks of the hand-over P0 at the last fused master sample (the EKF's
    /// convention): what the EKF starts from at separation, kept so that the separation tick
    /// does not compute the hand-over again (the alignment has not changed since).
    handover: Option<NavBlocks<T>>,
    /// The last master sample's correction of the INS snapshots, applied on the next tick
    /// (the snapshots are read at the next master sample only).
    snapshot_fix: Option<SnapshotFix<T>>,
    /// Predictions the alignment's last step ran (what the next master sample will likely
    /// need: the ticks before it run them ahead).
    master_steps: u32,
    last_master: Option<MasterRecord<T>>,
    /// The IMU's own free-fall evidence (unsignalled release).
    free_fall: super::carry::FreeFall,
    separation: SeparationStatus,
    signal: Option<Timestamp>,
    ekf: Option<SeekerIns<T>>,
    released_at: Option<Timestamp>,
    midcourse_at: Option<Timestamp>,
    baro_state: BaroState<T>,
    /// The baro-inertial loop's design (computed at construction) and the loop (midcourse on).
    loop_design: Option<ClassicalDesign<T>>,
    vloop: Option<ClassicalLoop<T>>,
    last_baro_time: Option<Timestamp>,
    pending: Option<Transition>,
    master: AidTrack<T>,
    baro: AidTrack<T>,
    seeker: AidTrack<T>,
}

/// Alignment predictions a carry tick without master data runs ahead at most (each ≈ one
/// `TransferAlignment::propagate`).
const MAX_AHEAD_PER_TICK: u32 = 2;

/// The navigator with the flight transfer-alignment filter ([`crate::transfer_alignment::FlightFilter`]).
pub type FlightNavigator<T, const H: usize> = Navigator<T, 5, 15, H>;
/// The navigator with the conventional 9-state alignment ([`crate::transfer_alignment::ConventionalFilter`]).
pub type ConventionalNavigator<T, const H: usize> = Navigator<T, 3, 9, H>;

fn elapsed<T: Real>(now: Timestamp, since: Timestamp) -> T {
    now.signed_seconds_since(since)
}

/// The EKF's 9 × 9 navigation block (δL, δl, δh, δV, φ) → NED metres for position. The
/// scale factors (radii of curvature at the solution) are computed in `T`: a variance needs
/// them to the working precision only, and on the f32 target f64 is emulated in software.
pub(crate) fn nav_block_to_ned<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    state: &InsState<T>,
) -> SMatrix<T, 9, 9> {
    let d = ned_factors(state);
    // Element (r, c) times the scale of each position index among r, c, the smaller first
    // (as [`nav9_to_ned`] scales row i then column i for i = 0, 1, 2): P's column slices,
    // no strided view copied.
    let scale = |i: usize| d.get(i).copied();
    let mut out = SMatrix::<T, 9, 9>::zeros();
    for (c, (dst, src)) in out
        .as_mut_slice()
        .chunks_exact_mut(9)
        .zip(p.as_slice().chunks_exact(STATES))
        .enumerate()
    {
        for (r, (o, v)) in dst.iter_mut().zip(src.iter()).enumerate() {
            let mut x = *v;
            if let Some(s) = scale(r.min(c)) {
                x *= s;
            }
            if let Some(s) = scale(r.max(c)) {
                x *= s;
            }
            *o = x;
        }
    }
    out
}

/// `(R_M + h, (R_N + h) cos L, −1)` at `state`: δL, δl, δh → NED metres.
fn ned_factors<T: Real>(state: &InsState<T>) -> [T; 3] {
    let pos = &state.position;
    let (lat, alt) = (T::lit(pos.lat_rad), T::lit(pos.alt_m));
    let (rm, rn) = radii_m(lat);
    [
        rm + alt,
        (rn + alt) * crate::math::trig::cos(lat),
        -T::one(),
    ]
}

/// The scaling of [`nav_block_to_ned`] on a 9 × 9 navigation block, rows then columns by
/// the factors `d` of the position states.
fn nav9_to_ned<T: Real>(mut out: SMatrix<T, 9, 9>, d: [T; 3]) -> SMatrix<T, 9, 9> {
    for (i, di) in d.iter().enumerate() {
        for v in out.row_mut(i).iter_mut() {
            *v *= *di;
        }
        for v in out.column_mut(i).iter_mut() {
            *v *= *di;
        }
    }
    out
}

/// The master's quality and motion in the hand-over's shape. Its body-rate 1σ is not on the
/// bus: the alignment's rate-difference noise (master and slave gyro noise per sample) bounds
/// it.
fn at_release<T: Real>(m: &MasterNav<T>, rate_sigma_rad_s: T) -> MasterAtRelease<T> {
    let lat = T::lit(m.position.lat_rad);
    let alt = T::lit(m.position.alt_m);
    let w_in = earth_rate_ned(lat) + transport_rate_ned(lat, alt, &m.vel_ned_m_s);
    MasterAtRelease {
        c_m_n: m.c_m_n,
        vel_ned_m_s: m.vel_ned_m_s,
        position: m.position,
        rate_nm_rad_s: m.angular_rate_rad_s - m.c_m_n.transpose() * w_in,
        attitude_sigma_rad: m.attitude_sigma_rad,
        velocity_sigma_m_s: m.velocity_sigma_m_s,
        position_sigma_m: m.position_sigma_m,
        rate_sigma_rad_s,
    }
}

/// A master sample's correction of the INS snapshots stamped `from..=until` (its epoch to
/// its tick), not applied yet.
#[derive(Debug, Clone, Copy)]
struct SnapshotFix<T> {
    correction: Correction<T>,
    from: Timestamp,
    until: Timestamp,
}

/// The error `snapshot − transferred` as the INS's correction arguments.
#[derive(Debug, Clone, Copy)]
struct Correction<T> {
    d_lat_rad: f64,
    d_lon_rad: f64,
    d_alt_m: f64,
    d_vel_m_s: Vector3<T>,
    phi_rad: Vector3<T>,
    /// `φ` as the quaternion `Ins::correct` applies (computed once for every snapshot).
    dq: Quaternion<T>,
}

impl<T: Real> Correction<T> {
    fn between(estimate: &InsState<T>, reference: &InsState<T>) -> Self {
        let c_est = quat_to_dcm(&estimate.q_b_n);
        let c_ref = quat_to_dcm(&reference.q_b_n);
        // Ĉ = exp(−[φ×]) C  ⇒  φ = −log(Ĉ Cᵀ).
        let phi = -log_so3(&(c_est * c_ref.transpose()));
        Self {
            d_lat_rad: estimate.position.lat_rad - reference.position.lat_rad,
            d_lon_rad: estimate.position.lon_rad - reference.position.lon_rad,
            d_alt_m: estimate.position.alt_m - reference.position.alt_m,
            d_vel_m_s: estimate.vel_ned_m_s - reference.vel_ned_m_s,
            phi_rad: phi,
            dq: quat_from_rotation_vector(&phi),
        }
    }

    /// Every number finite: then [`Self::apply`] succeeds on any stored (finite, unit
    /// quaternion) INS state.
    fn is_finite(&self) -> bool {
        let f = |v: f64| v.is_finite();
        f(self.d_lat_rad)
            && f(self.d_lon_rad)
            && f(self.d_alt_m)
            && crate::math::checks::all_finite(self.d_vel_m_s.as_slice())
            && crate::math::checks::all_finite(self.dq.coords.as_slice())
    }

    /// The same correction as `Ins::correct` on a stored state (`None`: not finite).
    fn apply(&self, s: &InsState<T>) -> Option<InsState<T>> {
        let mut p = s.position;
        p.lat_rad -= self.d_lat_rad;
        p.lon_rad -= self.d_lon_rad;
        p.alt_m -= self.d_alt_m;
        let q = quat_normalize(&quat_mul(&self.dq, &s.q_b_n))?;
        Some(InsState {
            position: p,
            vel_ned_m_s: s.vel_ned_m_s - self.d_vel_m_s,
            q_b_n: q,
        })
    }
}

/// Where a master sample's hand-over is committed: the navigator's carry fields.
struct CarryTargets<'a, T: Real> {
    ins: &'a mut Ins<T>,
    carry_cov: &'a mut SMatrix<T, 9, 9>,
    handover: &'a mut Option<NavBlocks<T>>,
    snapshot_fix: &'a mut Option<SnapshotFix<T>>,
}

/// The hand-over at the master's epoch with the (updated) alignment `ta`, and the INS slaved
/// to it, committed into `out` only when nothing failed: the carry covariance (the
/// hand-over's 9×9 navigation block, NED convention, and its blocks in the EKF's), the INS
/// corrected in place (`Ins::correct` is atomic and the last fallible step), and the
/// correction its snapshots since `snap` take (checked finite, applied on the next tick).
/// Nothing is returned by value.
fn slave_to<T: Real, const K: usize, const N: usize>(
    config: &NavigatorConfig<T>,
    ta: &TransferAlignment<T, K, N>,
    master: &MasterAtRelease<T>,
    snap: &Snapshot<T>,
    now: Timestamp,
    out: CarryTargets<'_, T>,
) -> Result<(), NavError> {
    let nav = hand_over_checked_master(
        master,
        &AlignmentAtRelease::from_filter(ta),
        &config.lever_arm,
    )?;
    let corr = Correction::between(&snap.state, &nav.state);
    // A finite correction applies to every stored state (finite, unit quaternion): checked
    // once here instead of on each snapshot.
    if !corr.is_finite() {
        return Err(NavError::NonFiniteInput {
            input: "master correction",
        });
    }
    out.ins.correct(
        corr.d_lat_rad,
        corr.d_lon_rad,
        corr.d_alt_m,
        &corr.d_vel_m_s,
        &corr.phi_rad,
    )?;
    // Commit (nothing below fails).
    *out.carry_cov = nav9_to_ned(nav.blocks.nav9(), ned_factors(&nav.state));
    *out.handover = Some(nav.blocks);
    *out.snapshot_fix = Some(SnapshotFix {
        correction: corr,
        from: snap.time,
        until: now,
    });
    Ok(())
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// The configuration-time design of `config` (the alignment's discretised chains, the
    /// EKF's noise PSDs, the baro-inertial loop's design): computed on the ground and stored,
    /// [`Self::from_design`] builds the navigator from it without the design code. Errors:
    /// `InvalidConfig` ([`NavigatorConfig::validate`], then the estimators' own checks).
    pub fn design(config: &NavigatorConfig<T>) -> Result<NavigatorDesign<T, K>, NavError> {
        config.validate()?;
        Ok(NavigatorDesign {
            ins: SeekerIns::design(&config.ins)?,
            alignment: TransferAlignment::<T, K, N>::design(&config.alignment)?,
            baro_loop: match &config.baro {
                BaroDamping::InertialLoop(c) => Some(ClassicalLoop::design(c)?),
                _ => None,
            },
        })
    }

    /// A navigator in carry at `initial`: [`Self::from_design`] with the design computed here
    /// ([`Self::design`]). Errors: `InvalidConfig` (the navigator's fields,
    /// [`NavigatorConfig::validate`], then the alignment's and the EKF's own checks),
    /// `NonFiniteInput` / `InputOutOfRange` for a bad initial state or covariance.
    pub fn new(
        config: &NavigatorConfig<T>,
        initial: &NavigatorInitial<T>,
    ) -> Result<Self, NavError> {
        Self::from_design(config, &Self::design(config)?, initial)
    }

    /// A navigator in carry at `initial` from a stored design (validated against `config`, then
    /// copied: no design code runs). Identical to [`Self::new`] for the design
    /// [`Self::design`] computes. Errors: as [`Self::new`], and `InvalidConfig` for a design
    /// of another configuration (stamps) or a baro-loop design missing or superfluous.
    pub fn from_design(
        config: &NavigatorConfig<T>,
        design: &NavigatorDesign<T, K>,
        initial: &NavigatorInitial<T>,
    ) -> Result<Self, NavError> {
        config.validate()?;
        design.check_ins(config)?;
        design.check_baro_loop(config)?;
        let ta = TransferAlignment::<T, K, N>::from_design(
            &config.alignment,
            &design.alignment,
            &TaInitial {
                mount_misalignment_rad: Vector3::zeros(),
            },
        )?;
        let ins = Ins::new(initial.state, config.imu_dt_s)?;
        let cov = &initial.nav_covariance;
        if !crate::math::checks::all_finite(cov.as_slice()) {
            return Err(NavError::NonFiniteInput {
                input: "initial.nav_covariance",
            });
        }
        if crate::math::kalman::asymmetry(cov) > T::zero()
            || cov.diagonal().iter().any(|d| *d < T::zero())
        {
            return Err(NavError::InputOutOfRange {
                input: "initial.nav_covariance",
            });
        }
        Ok(Self {
            config: *config,
            design: design.ins,
            phase: Phase::Carry,
            time: initial.time,
            start: initial.time,
            ticked: false,
            ins,
            ta,
            history: SlaveHistory::new(),
            snapshots: Deque::new(),
            carry_cov: *cov,
            handover: None,
            snapshot_fix: None,
            master_steps: 0,
            last_master: None,
            free_fall: super::carry::FreeFall::default(),
            separation: SeparationStatus::NotSignalled,
            signal: None,
            ekf: None,
            released_at: None,
            midcourse_at: None,
            baro_state: match &config.baro {
                BaroDamping::Ekf(m) => BaroState::start(m),
                BaroDamping::Off | BaroDamping::InertialLoop(_) => BaroState {
                    cross: nalgebra::SVector::zeros(),
                    variance_m2: T::zero(),
                    bias_m: T::zero(),
                },
            },
            loop_design: design.baro_loop,
            vloop: None,
            last_baro_time: None,
            pending: None,
            master: AidTrack::default(),
            baro: AidTrack::default(),
            seeker: AidTrack::default(),
        })
    }

    /// The current phase.
    pub fn phase(&self) -> Phase {
        self.phase
    }

    /// The configuration.
    pub fn config(&self) -> &NavigatorConfig<T> {
        &self.config
    }

    /// The transfer-alignment filter (carry; frozen at release).
    pub fn alignment(&self) -> &TransferAlignment<T, K, N> {
        &self.ta
    }

    /// The 17-state EKF (`None` before release).
    pub fn ekf(&self) -> Option<&SeekerIns<T>> {
        self.ekf.as_ref()
    }

    /// The baro-error state (its estimate, variance and cross-covariance with the 17).
    pub fn baro_state(&self) -> &BaroState<T> {
        &self.baro_state
    }

    /// The navigation solution and its covariance.
    pub fn solution(&self) -> NavSolution<T> {
        match &self.ekf {
            Some(e) => NavSolution {
                time: self.time,
                state: *e.state(),
                nav_covariance: nav_block_to_ned(e.covariance(), e.state()),
            },
            None => NavSolution {
                time: self.time,
                state: *self.ins.state(),
                nav_covariance: self.carry_cov,
            },
        }
    }

    /// Release without an alignment (ground launch, or a test of the chain without the carry
    /// phase): the EKF starts from `initial` now (at the last tick's time). Only in carry:
    /// else `InputOutOfRange { input: "release_with: not in carry" }`. Errors of
    /// [`SeekerIns`]'s construction (bad state or P0) leave the navigator unchanged. The
    /// transition is reported by the next tick.
    pub fn release_with(&mut self, initial: &SeekerInsInitial<T>) -> Result<(), NavError> {
        if self.phase != Phase::Carry {
            return Err(NavError::InputOutOfRange {
                input: "release_with: not in carry",
            });
        }
        self.ekf = Some(SeekerIns::from_design(
            &self.config.ins,
            &self.design,
            initial,
        )?);
        self.enter_released(
            SeparationStatus::Commanded,
            TransitionCause::ReleaseCommanded,
        );
        Ok(())
    }

    /// The phase change to released, the EKF in place (`self.ekf`).
    fn enter_released(&mut self, status: SeparationStatus, cause: TransitionCause) {
        self.phase = Phase::Released;
        self.released_at = Some(self.time);
        self.separation = status;
        self.pending = Some(Transition {
            from: Phase::Carry,
            to: Phase::Released,
            cause,
            time: self.time,
        });
    }

    /// One IMU sample plus the aids that arrived since the last one (module doc). A bad IMU
    /// sample (non-finite, beyond range, not later than the last tick, interval too long):
    /// `Err`, nothing changed. A bad aid: refused (its state `Refused`, counted), nothing of
    /// it applied, the tick still runs.
    pub fn tick(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
    ) -> Result<TickReport<T>, NavError> {
        if self.ticked && imu.increment.time <= self.time || imu.increment.time <= self.start {
            return Err(NavError::TimeNotIncreasing);
        }
        let mut transition = self.pending.take();
        let mut degr = Degradation {
            separation: self.separation,
            ..Degradation::default()
        };
        let [master, baro, seeker] = if self.phase == Phase::Carry {
            let r = self.tick_carry_apart(imu, aids, &mut transition);
            if r.is_err() {
                // Nothing committed: restore the pending transition.
                self.pending = transition;
            }
            r?
        } else {
            let r = self.tick_flight(imu, aids, &mut transition);
            if r.is_err() {
                self.pending = transition;
            }
            r?
        };
        self.ticked = true;
        degr.separation = self.separation;
        degr.master = self.master_availability();
        degr.baro = self.baro_availability();
        degr.seeker = self.seeker_availability();
        let health = self.health(&degr);
        Ok(TickReport {
            solution: self.solution(),
            phase: self.phase,
            transition,
            master,
            baro,
            seeker,
            health,
            degradation: degr,
        })
    }

    fn health(&self, d: &Degradation) -> HealthState {
        let degraded = d.master == AidAvailability::TimedOut
            || d.baro == AidAvailability::TimedOut
            || d.seeker == AidAvailability::TimedOut
            || matches!(
                d.separation,
                SeparationStatus::SeparationUnconfirmed | SeparationStatus::UnsignalledRelease
            );
        let base = match &self.ekf {
            Some(e) => e.health().state,
            None if self.last_master.is_none() => HealthState::Initialising,
            None => HealthState::Nominal,
        };
        match base {
            HealthState::Nominal | HealthState::Initialising if degraded => HealthState::Degraded,
            other => other,
        }
    }

    // ---------------------------------------------------------------- carry

    /// [`Self::tick_carry`] in a frame of its own (not inlined): the carry phase's stack is
    /// not on the flight phases' path.
    #[inline(never)]
    fn tick_carry_apart(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
    ) -> Result<AidReports<T>, NavError> {
        self.tick_carry(imu, aids, transition)
    }

    fn tick_carry(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
    ) -> Result<AidReports<T>, NavError> {
        let inc = &imu.increment;
        let mut ins = self.ins;
        ins.step(inc)?;
        let dt = ins.last_interval_s();
        let slave = SlaveSample {
            time: inc.time,
            angular_rate_rad_s: inc.delta_theta_rad / dt,
            specific_force_m_s2: inc.delta_v_m_s / dt,
        };
        slave.validate()?;
        if self.history.newest().is_some_and(|s| s.time >= inc.time) {
            return Err(NavError::TimeNotIncreasing);
        }
        // Commit the IMU part (nothing below fails the tick).
        self.history.push(&slave)?;
        self.ins = ins;
        self.time = inc.time;
        self.apply_snapshot_fix();
        if self.snapshots.is_full() {
            let _ = self.snapshots.pop_front();
        }
        let _ = self.snapshots.push_back(Snapshot {
            time: inc.time,
            state: *ins.state(),
        });
        let mut master_state = AidState::Waiting;
        if let Some(m) = aids.master {
            master_state = match self.fuse_master(m) {
                Ok(s) => s,
                Err(e) => {
                    self.master.counters.record_refused();
                    AidState::Refused(e)
                }
            };
        } else {
            // A tick without master data carries the alignment's next predictions, as many as
            // the last master sample needed (at most two a tick): the master tick then has
            // those less to do.
            let mut run = 0;
            while run < MAX_AHEAD_PER_TICK
                && self.ta.steps_ahead() < self.master_steps
                && self.ta.predict_ahead()
            {
                run += 1;
            }
        }
        let master_lost = self.master_availability() == AidAvailability::TimedOut;
        if master_lost && master_state == AidState::Waiting {
            master_state = AidState::TimedOut;
        }
        // Separation.
        if let Some(sig) = aids.separation {
            if matches!(
                self.separation,
                SeparationStatus::NotSignalled
                    | SeparationStatus::SeparationUnconfirmed
                    | SeparationStatus::AwaitingConfirmation
            ) && self.signal.is_none_or(|s| sig > s)
            {
                self.signal = Some(sig);
                self.separation = SeparationStatus::AwaitingConfirmation;
            }
        }
        let imu_sees = self.last_master.is_some_and(|lm| {
            (slave.specific_force_m_s2 - lm.f_slave_m_s2).norm()
                > self.config.separation.specific_force_jump_m_s2
        });
        let falling_s = self.free_fall.update(
            self.time,
            &slave.specific_force_m_s2,
            self.config.separation.specific_force_jump_m_s2,
        );
        let mut release = None;
        match (self.separation, self.signal) {
            (SeparationStatus::AwaitingConfirmation, Some(sig)) => {
                let age = elapsed::<T>(self.time, sig);
                if imu_sees {
                    release = Some((
                        SeparationStatus::Confirmed,
                        TransitionCause::SeparationConfirmed,
                    ));
                } else if age > self.config.separation.confirm_window_s {
                    self.separation = SeparationStatus::SeparationUnconfirmed;
                }
            }
            _ => {
                if master_lost && falling_s >= self.config.separation.confirm_window_s {
                    release = Some((
                        SeparationStatus::UnsignalledRelease,
                        TransitionCause::UnsignalledSeparation,
                    ));
                }
            }
        }
        if let Some((status, cause)) = release {
            if self.hand_over_now() {
                self.enter_released(status, cause);
                *transition = self.pending.take();
            }
        }
        let not_used = |t: &AidTrack<T>| t.status(AidState::NotUsedInPhase);
        Ok([
            self.master.status(master_state),
            not_used(&self.baro),
            not_used(&self.seeker),
        ])
    }

    /// Starts the EKF (`self.ekf`) at this tick from the last master and the alignment;
    /// `false` (nothing changed) without a master or when the EKF refuses the state: the
    /// current INS state with the hand-over P0 of the last fused master sample (its
    /// navigation blocks kept from that tick: the alignment has not changed since, so the
    /// hand-over would give them again bit for bit), written in place into the new EKF, its
    /// accelerometer-bias states referred to the carry's specific force ([`refer_to_carry`]).
    #[inline(never)]
    fn hand_over_now(&mut self) -> bool {
        let (Some(lm), Some(blocks)) = (self.last_master, self.handover) else {
            return false;
        };
        let priors = self.config.priors;
        let started = if blocks.p0_passes_checks(&priors) {
            SeekerIns::start_in(
                &mut self.ekf,
                &self.config.ins,
                &self.design,
                self.ins.state(),
                |p0| blocks.write_p0(&priors, p0),
            )
            .is_ok()
        } else {
            // Blocks the cheap check cannot vouch for: the EKF's own dense check decides.
            self.hand_over_dense(&blocks)
        };
        started && refer_to_carry(&mut self.ekf, &lm.f_slave_m_s2)
    }

    /// [`Self::hand_over_now`] through the EKF's public constructor and its dense checks.
    #[cold]
    #[inline(never)]
    fn hand_over_dense(&mut self, blocks: &NavBlocks<T>) -> bool {
        let mut initial = SeekerInsInitial {
            state: *self.ins.state(),
            covariance: SMatrix::zeros(),
        };
        blocks.write_p0(&self.config.priors, &mut initial.covariance);
        match SeekerIns::from_design(&self.config.ins, &self.design, &initial) {
            Ok(ekf) => {
                self.ekf = Some(ekf);
                true
            }
            Err(_) => false,
        }
    }

    /// The last master sample's correction into the snapshots it covers (the same
    /// operations, in the same order, as when applied at that master's tick: the snapshots
    /// are read at the next master sample only).
    fn apply_snapshot_fix(&mut self) {
        let Some(fix) = self.snapshot_fix.take() else {
            return;
        };
        for s in self
            .snapshots
            .iter_mut()
            .filter(|s| s.time >= fix.from && s.time <= fix.until)
        {
            if let Some(corrected) = fix.correction.apply(&s.state) {
                s.state = corrected;
            }
        }
    }

    /// Alignment step at the master's epoch, hand-over and the INS slaved to it; atomic: the
    /// cheap checks first, then the alignment steps in place and is undone
    /// ([`TransferAlignment::step_then`]) when the hand-over or the slaving fails (no copy of
    /// the filter).
    #[inline(never)]
    fn fuse_master(&mut self, m: &MasterNav<T>) -> Result<AidState, NavError> {
        // A separation signalled at `s` and awaiting the IMU's confirmation: a master sample
        // whose slave interpolation reaches past `s` (epoch later than one IMU interval before
        // it) would pair the aircraft on the lever arm with the missile already dropping (the
        // flexure's motion gone from its IMU); it is not fused (nothing changes, nothing
        // counted) and the hand-over uses the samples before. Fused again if the IMU does not
        // confirm the separation.
        let imu_dt_us = crate::time::seconds_to_micros(self.config.imu_dt_s).unwrap_or(0);
        if self.separation == SeparationStatus::AwaitingConfirmation
            && self
                .signal
                .is_some_and(|s| m.time.as_micros().saturating_add(imu_dt_us) > s.as_micros())
        {
            return Ok(AidState::NotUsedInPhase);
        }
        let tol = self.ta_tolerance_us();
        let snap = self
            .snapshots
            .iter()
            .rev()
            .find(|s| s.time.as_micros().abs_diff(m.time.as_micros()) <= tol)
            .copied()
            .ok_or(NavError::MeasurementTimeOutOfWindow)?;
        let ms = MasterSample {
            time: m.time,
            angular_rate_rad_s: m.angular_rate_rad_s,
            angular_accel_rad_s2: m.angular_accel_rad_s2,
            specific_force_m_s2: m.specific_force_m_s2,
        };
        ms.validate()?;
        // The hand-over's checks of the master before the alignment steps: a bad master
        // sample does not touch the alignment.
        let at = at_release(m, self.config.alignment.rate_noise_sigma_rad_s);
        validate_master(&at, &self.config.lever_arm, &self.config.priors)?;
        // The slave's interval means interpolated at the master's (instantaneous) epoch; the
        // end-stamped sample of that epoch when they cannot be (the first tick).
        let slave = self
            .history
            .at_time(m.time)
            .or_else(|_| self.history.find(m.time, tol))?;
        let now = self.time;
        let Self {
            ta,
            config,
            ins,
            carry_cov,
            handover,
            snapshot_fix,
            ..
        } = self;
        let (report, ()) = ta.step_then(&ms, &slave, |ta| {
            let out = CarryTargets {
                ins,
                carry_cov,
                handover,
                snapshot_fix,
            };
            slave_to(config, ta, &at, &snap, now, out)
        })?;
        // After the first epoch (nothing predicted) the next sample needs at least one.
        self.master_steps = report.predictions.max(1);
        let f_m = compensate_lever_arm(&ms, &self.config.lever_arm.nominal_m);
        let c_m_s: Matrix3<T> = exp_so3(&(-self.ta.theta()));
        self.last_master = Some(MasterRecord {
            f_slave_m_s2: c_m_s * f_m,
        });
        let mut worst: Option<FusionReport<T>> = None;
        let mut any_fused = false;
        for u in &report.updates {
            self.master.counters.record(u.outcome);
            any_fused |= u.outcome == FusionOutcome::Fused;
            if worst.is_none_or(|w| u.nis > w.nis) {
                worst = Some(*u);
            }
        }
        self.master.last = worst;
        if any_fused {
            self.master.last_ok = Some(self.time);
            Ok(AidState::Fused)
        } else {
            Ok(AidState::Rejected)
        }
    }

    fn ta_tolerance_us(&self) -> u64 {
        crate::time::seconds_to_micros(self.config.alignment.time_tolerance_s).unwrap_or(0)
    }

    // ---------------------------------------------------------------- flight

    fn baro_model(&self) -> Option<super::types::BaroErrorModel<T>> {
        match self.config.baro {
            BaroDamping::Ekf(m) if matches!(self.phase, Phase::Midcourse | Phase::Terminal) => {
                Some(m)
            }
            _ => None,
        }
    }

    /// The flight phases' tick, in place: everything that can refuse the IMU sample is
    /// checked before the filter changes (the EKF's propagation is atomic without a copy of
    /// the filter, `SeekerIns::propagate_cross`), then each aid is validated before it
    /// touches anything. Not inlined: the carry phase's frame is not on this path's stack.
    #[inline(never)]
    fn tick_flight(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
    ) -> Result<AidReports<T>, NavError> {
        let inc = &imu.increment;
        let clip = (imu.clipped.accel || imu.clipped.gyro).then_some(imu.clipped);
        if self.vloop.is_some() {
            return self.tick_flight_loop(inc, clip, aids, transition);
        }
        let model = self.baro_model();
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        if let Some(model) = model {
            let bs = &mut self.baro_state;
            let before = ekf.health();
            if let Some(dt) = ekf.propagate_cross(inc, clip, &mut bs.cross)? {
                bs.decay(&model, dt);
            }
            let after = ekf.health();
            if after.limits_hit != before.limits_hit || after.gaps_reset != before.gaps_reset {
                bs.cross = nalgebra::SVector::zeros();
            }
        } else {
            ekf.propagate_uncounted(inc, clip)?;
        }
        self.time = inc.time;
        self.after_imu(aids, transition, None)
    }

    /// [`Self::tick_flight`] with the baro-inertial loop: the loop can refuse the IMU part
    /// after the EKF has integrated it, so the EKF and the loop step on copies committed
    /// together (more stack; the loop configuration only).
    #[inline(never)]
    fn tick_flight_loop(
        &mut self,
        inc: &ImuIncrement<T>,
        clip: Option<ClipFlags>,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
    ) -> Result<AidReports<T>, NavError> {
        let (Some(mut ekf), Some(mut lp)) = (self.ekf, self.vloop) else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        // On the copy: a refusal is dropped with it, as on the in-place path.
        ekf.propagate_uncounted(inc, clip)?;
        let outcome = Self::loop_step(&mut lp, &mut ekf, inc.time, aids.baro)?;
        self.ekf = Some(ekf);
        self.vloop = Some(lp);
        self.time = inc.time;
        self.after_imu(aids, transition, Some(outcome))
    }

    /// After the committed IMU part: the phase by time, then the aids.
    fn after_imu(
        &mut self,
        aids: &Aids<'_, T>,
        transition: &mut Option<Transition>,
        loop_baro: Option<LoopBaro<T>>,
    ) -> Result<AidReports<T>, NavError> {
        // Phase by time.
        if self.phase == Phase::Released
            && self
                .released_at
                .is_some_and(|t| elapsed::<T>(self.time, t) >= self.config.separation.coast_s)
        {
            self.phase = Phase::Midcourse;
            self.midcourse_at = Some(self.time);
            if let BaroDamping::Ekf(m) = &self.config.baro {
                self.baro_state = BaroState::start(m);
            }
            self.start_loop();
            transition.get_or_insert(Transition {
                from: Phase::Released,
                to: Phase::Midcourse,
                cause: TransitionCause::CoastElapsed,
                time: self.time,
            });
        }
        let baro = match loop_baro {
            Some(outcome) => self.loop_baro_status(outcome),
            None => self.baro_aid(aids.baro),
        };
        let seeker = self.seeker_aid(aids.seeker, transition);
        Ok([self.master.status(AidState::NotUsedInPhase), baro, seeker])
    }

    /// Midcourse start with [`BaroDamping::InertialLoop`]: the loop from the INS's vertical
    /// state. A loop the design refuses to start (an INS altitude outside its range) leaves the
    /// vertical channel free (the baro then reports `NotUsedInPhase`).
    fn start_loop(&mut self) {
        let (BaroDamping::InertialLoop(cfg), Some(design), Some(ekf)) =
            (&self.config.baro, &self.loop_design, &self.ekf)
        else {
            return;
        };
        let s = ekf.state();
        let init = InitialState {
            time: self.time,
            altitude_m: T::lit(s.position.alt_m),
            vz_up_m_s: -s.vel_ned_m_s.z,
            accel_bias_m_s2: T::zero(),
        };
        self.vloop = ClassicalLoop::from_design(cfg, design, &init).ok();
    }

    /// One step of the baro-inertial loop on the INS's vertical specific force, then ĥ, V̂_D
    /// into the INS and the loop's σ into the EKF's (δh, δV_D) block, cross-covariances zero
    /// (P stays PSD: the new P is block diagonal in {δh, δV_D} and the rest, each block PSD —
    /// the rest a principal submatrix of a PSD matrix, the vertical block the loop's
    /// covariance; keeping the old cross terms beside a new vertical block could make P
    /// indefinite). A baro sample the loop refuses is dropped (`Refused`) and the loop steps on
    /// the IMU alone. Returns the baro's outcome.
    fn loop_step(
        lp: &mut ClassicalLoop<T>,
        ekf: &mut SeekerIns<T>,
        time: Timestamp,
        baro: Option<&BaroSample<T>>,
    ) -> Result<LoopBaro<T>, NavError> {
        let imu = VerticalImu {
            time,
            specific_force_up_m_s2: -ekf.ins().specific_force_ned_m_s2().z,
        };
        let mut next = *lp;
        let outcome = match next.step(&imu, baro) {
            Ok(r) => LoopBaro::Report(r.baro.sample),
            Err(e) if baro.is_some() => {
                next = *lp;
                next.step(&imu, None)?;
                LoopBaro::Refused(e)
            }
            Err(e) => return Err(e),
        };
        let s = ekf.state();
        let mut x = nalgebra::SVector::<T, STATES>::zeros();
        let (ih, iv) = (crate::seeker_ins::POS + 2, crate::seeker_ins::VEL + 2);
        if let Some(v) = x.get_mut(ih) {
            *v = T::lit(s.position.alt_m) - next.altitude_m();
        }
        if let Some(v) = x.get_mut(iv) {
            *v = s.vel_ned_m_s.z + next.vz_up_m_s();
        }
        let c = next.covariance_h_vz();
        // (δh, δV_D) with δV_D = −δV_z; P changed in place (no copy).
        ekf.set_vertical_block(&x, c.m11, c.m22, -c.m12)?;
        *lp = next;
        Ok(outcome)
    }

    fn loop_baro_status(&mut self, outcome: LoopBaro<T>) -> AidStatus<T> {
        let state = match outcome {
            LoopBaro::Refused(e) => {
                self.baro.counters.record_refused();
                AidState::Refused(e)
            }
            LoopBaro::Report(None) => AidState::Waiting,
            LoopBaro::Report(Some(r)) => {
                self.baro.counters.record(r.outcome);
                self.baro.last = Some(r);
                self.baro.last_ok = Some(self.time);
                match r.outcome {
                    FusionOutcome::Fused => AidState::Fused,
                    FusionOutcome::Rejected => AidState::Rejected,
                    FusionOutcome::Skipped => AidState::Waiting,
                }
            }
        };
        let state = if state == AidState::Waiting
            && self.baro_availability() == AidAvailability::TimedOut
        {
            AidState::TimedOut
        } else {
            state
        };
        self.baro.status(state)
    }

    fn baro_aid(&mut self, sample: Option<&BaroSample<T>>) -> AidStatus<T> {
        let Some(model) = self.baro_model() else {
            return self.baro.status(AidState::NotUsedInPhase);
        };
        let mut state = AidState::Waiting;
        if let Some(b) = sample {
            state = match self.fuse_baro(&model, b) {
                Ok(s) => s,
                Err(e) => {
                    self.baro.counters.record_refused();
                    AidState::Refused(e)
                }
            };
        }
        if state == AidState::Waiting && self.baro_availability() == AidAvailability::TimedOut {
            state = AidState::TimedOut;
        }
        self.baro.status(state)
    }

    /// The baro's joint update (module `baro`), in place: the sample is checked (finite, time,
    /// age) before anything changes; the pending covariance step runs (atomic), then the
    /// update is checked on the gain and P's result before it is applied
    /// (`SeekerIns::update_rank_one`). A result that is not a covariance, or a correction the
    /// INS refuses, is not applied (`Skipped`): the covariance step stays, as for every
    /// outcome.
    #[inline(never)]
    fn fuse_baro(
        &mut self,
        model: &super::types::BaroErrorModel<T>,
        b: &BaroSample<T>,
    ) -> Result<AidState, NavError> {
        let age = baro_age_s::<T>(b, self.time)?;
        if self.last_baro_time.is_some_and(|t| b.time <= t) {
            return Err(NavError::TimeNotIncreasing);
        }
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        let bs = &mut self.baro_state;
        if let Some(dt) = ekf.predict_covariance_cross(&mut bs.cross)? {
            bs.decay(model, dt);
        }
        let tau = model.lag_s + age;
        let y = bs.predicted_m(ekf, tau) - b.altitude_m;
        let r = model.white_sigma_m * model.white_sigma_m;
        let gate = self.config.ins.gate;
        let outcome = match baro_gain(ekf.covariance(), bs, tau, y, r, gate) {
            None => FusionOutcome::Skipped,
            Some(Err(report)) => {
                self.baro.last = Some(report);
                report.outcome
            }
            Some(Ok(g)) => {
                if ekf
                    .update_rank_one(&g.dx, &g.u, &g.k, g.delta)
                    .unwrap_or(false)
                {
                    bs.cross = g.cross;
                    bs.variance_m2 = g.variance_m2;
                    bs.bias_m -= g.db_m;
                    self.baro.last = Some(g.report);
                    g.report.outcome
                } else {
                    FusionOutcome::Skipped
                }
            }
        };
        self.last_baro_time = Some(b.time);
        self.baro.counters.record(outcome);
        self.baro.last_ok = Some(self.time);
        Ok(match outcome {
            FusionOutcome::Fused => AidState::Fused,
            FusionOutcome::Rejected => AidState::Rejected,
            FusionOutcome::Skipped => AidState::Waiting,
        })
    }

    fn seeker_aid(
        &mut self,
        sample: Option<&LosSample<T>>,
        transition: &mut Option<Transition>,
    ) -> AidStatus<T> {
        if self.phase == Phase::Released {
            return self.seeker.status(AidState::NotUsedInPhase);
        }
        let mut state = AidState::Waiting;
        if let Some(s) = sample {
            state = match self.fuse_los(s) {
                Ok(st) => st,
                Err(e) => {
                    self.seeker.counters.record_refused();
                    AidState::Refused(e)
                }
            };
        }
        if state == AidState::Fused && self.phase == Phase::Midcourse {
            self.phase = Phase::Terminal;
            transition.get_or_insert(Transition {
                from: Phase::Midcourse,
                to: Phase::Terminal,
                cause: TransitionCause::SeekerFused,
                time: self.time,
            });
        }
        if state == AidState::Waiting && self.seeker_availability() == AidAvailability::TimedOut {
            state = AidState::TimedOut;
        }
        self.seeker.status(state)
    }

    /// One LOS sample through the EKF, in place: a sample the EKF would refuse is refused
    /// before the pending covariance step runs (nothing of it changes the filter), then the
    /// step (atomic) and the update, with the baro column when the baro is in the EKF.
    #[inline(never)]
    fn fuse_los(&mut self, s: &LosSample<T>) -> Result<AidState, NavError> {
        let model = self.baro_model();
        let Some(ekf) = self.ekf.as_mut() else {
            return Err(NavError::InputOutOfRange {
                input: "navigator state",
            });
        };
        ekf.check_los(s)?;
        let bs = &mut self.baro_state;
        // The pending covariance step first (in place, atomic; the update then needs no copy
        // of the filter), the baro column in step with it.
        let report = if let Some(model) = model {
            if let Some(dt) = ekf.predict_covariance_cross(&mut bs.cross)? {
                bs.decay(&model, dt);
            }
            // The baro column follows the LOS update (module `baro`).
            let mut col = CrossColumn {
                cross: bs.cross,
                variance: bs.variance_m2,
                correction: T::zero(),
            };
            let r = ekf.update_los_cross(s, &mut col)?;
            bs.cross = col.cross;
            bs.variance_m2 = col.variance;
            bs.bias_m -= col.correction;
            r
        } else {
            if ekf.los_at_ins_time(s) {
                // As `update_los` would on a copy of the filter.
                ekf.predict_covariance()?;
            }
            ekf.update_los(s)?
        };
        let fused = [report.pitch.outcome, report.yaw.outcome]
            .iter()
            .filter(|o| **o == FusionOutcome::Fused)
            .count();
        for r in [report.pitch, report.yaw] {
            self.seeker.counters.record(r.outcome);
        }
        let worst = if report.pitch.nis >= report.yaw.nis {
            report.pitch
        } else {
            report.yaw
        };
        self.seeker.last = Some(worst);
        if fused > 0 {
            self.seeker.last_ok = Some(self.time);
            return Ok(AidState::Fused);
        }
        let rejected =
            [report.pitch.outcome, report.yaw.outcome].contains(&FusionOutcome::Rejected);
        Ok(if rejected {
            AidState::Rejected
        } else {
            AidState::Waiting
        })
    }
}

fn lost_if(lost: bool) -> AidAvailability {
    if lost {
        AidAvailability::TimedOut
    } else {
        AidAvailability::Available
    }
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// Master: in carry, no fused sample for `timeouts.master_s` (since the start).
    fn master_availability(&self) -> AidAvailability {
        let since = self.master.last_ok.unwrap_or(self.start);
        lost_if(
            self.phase == Phase::Carry
                && elapsed::<T>(self.time, since) > self.config.timeouts.master_s,
        )
    }

    /// Baro: with baro damping in midcourse / terminal, no accepted sample for
    /// `timeouts.baro_s` (since midcourse start).
    fn baro_availability(&self) -> AidAvailability {
        let since = self.baro.last_ok.max(self.midcourse_at);
        lost_if(
            self.baro_model().is_some()
                && since.is_some_and(|t| elapsed::<T>(self.time, t) > self.config.timeouts.baro_s),
        )
    }

    /// Seeker: in terminal, no fused component for `timeouts.seeker_s`.
    fn seeker_availability(&self) -> AidAvailability {
        lost_if(
            self.phase == Phase::Terminal
                && self
                    .seeker
                    .last_ok
                    .is_some_and(|t| elapsed::<T>(self.time, t) > self.config.timeouts.seeker_s),
        )
    }
}

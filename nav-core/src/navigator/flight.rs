//! The navigator value and its tick (module doc of [`super`]).

use super::baro::BaroState;
use super::carry::{MasterRecord, ReleaseEvidence};
use super::design::alignment_config;
use super::design::NavigatorDesign;
use super::handover::NavBlocks;
use super::types::{
    AidAvailability, AidState, AidStatus, Aids, BaroDamping, Degradation, ImuTick, NavSolution,
    NavigatorConfig, NavigatorInitial, Phase, SeparationStatus, TickReport, Transition,
    TransitionCause,
};
use crate::contract::{AidCounters, Estimator, FusionReport};
use crate::earth::radii_m;
use crate::math::rotation::{
    log_so3, quat_from_rotation_vector, quat_mul, quat_normalize, quat_to_dcm,
};
use crate::seeker_ins::{Ins, InsState, SeekerIns, SeekerInsDesign, SeekerInsInitial, STATES};
use crate::time::Timestamp;
use crate::transfer_alignment::{SlaveHistory, TaInitial, TransferAlignment};
use crate::vertical_channel::{BaroSample, ClassicalDesign, ClassicalLoop};
use crate::{HealthState, NavError, Real};
use heapless::Deque;
use nalgebra::Quaternion;
use nalgebra::{SMatrix, Vector3};

mod baro_hold;
mod carry_phase;
mod flight_phase;
mod psd_check;

use carry_phase::MasterEpoch;
use psd_check::PsdCheck;

/// One INS state of the carry phase at a tick time (for the master's late epochs).
#[derive(Debug, Clone, Copy)]
struct Snapshot<T> {
    time: Timestamp,
    state: InsState<T>,
}

/// What the baro-inertial loop did with this tick's baro sample.
#[derive(Debug, Clone, Copy)]
enum LoopBaro<T> {
    /// Its report of a new sample (`None`: no new sample).
    Report(Option<FusionReport<T>>),
    /// Refused by the loop.
    Refused(NavError),
}

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

    /// [`Self::status`] written field by field into the report's `dst` (no temporary).
    fn write(&self, state: AidState, dst: &mut AidStatus<T>) {
        dst.state = state;
        dst.last = self.last;
        dst.counters = self.counters;
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
    /// Scratch of the master tick's step ([`MasterEpoch`]: no state).
    epoch: MasterEpoch<T>,
    /// The IMU's own evidence for a release without a signal (unloading, free fall).
    release_evidence: ReleaseEvidence<T>,
    separation: SeparationStatus,
    signal: Option<Timestamp>,
    ekf: Option<SeekerIns<T>>,
    /// The EKF's P and its PSD-margin check (module `psd_check`): P0 is new at release.
    psd: PsdCheck,
    released_at: Option<Timestamp>,
    midcourse_at: Option<Timestamp>,
    baro_state: BaroState<T>,
    /// The baro-inertial loop's design (computed at construction) and the loop (midcourse on).
    loop_design: Option<ClassicalDesign<T>>,
    vloop: Option<ClassicalLoop<T>>,
    last_baro_time: Option<Timestamp>,
    /// A checked baro sample waiting for a tick without a LOS update (module `baro_hold`).
    held_baro: Option<BaroSample<T>>,
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
    out: &mut SMatrix<T, 9, 9>,
) {
    let d = ned_factors(state);
    // Element (r, c) times the scale of each position index among r, c, the smaller first
    // (as [`nav9_to_ned`] scales row i then column i for i = 0, 1, 2): P's column slices,
    // no strided view copied, written straight into `out` (no 9 × 9 temporary).
    let scale = |i: usize| d.get(i).copied();
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

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// The configuration-time design of `config` (the alignment's discretised chains, the
    /// EKF's noise PSDs, the baro-inertial loop's design): computed on the ground and stored,
    /// [`Self::from_design`] builds the navigator from it without the design code. Errors:
    /// `InvalidConfig` ([`NavigatorConfig::validate`], then the estimators' own checks).
    pub fn design(config: &NavigatorConfig<T>) -> Result<NavigatorDesign<T, K>, NavError> {
        config.validate()?;
        Ok(NavigatorDesign {
            ins: SeekerIns::design(&config.ins)?,
            alignment: TransferAlignment::<T, K, N>::design(&alignment_config(config))?,
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
        Self::check_history_depth(config)?;
        design.check_ins(config)?;
        design.check_baro_loop(config)?;
        let ta = TransferAlignment::<T, K, N>::from_design(
            &alignment_config(config),
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
            epoch: MasterEpoch::blank(),
            release_evidence: ReleaseEvidence::new(config.separation.confirm_window_s),
            separation: SeparationStatus::NotSignalled,
            signal: None,
            ekf: None,
            psd: PsdCheck::ChangedNow,
            released_at: None,
            midcourse_at: None,
            baro_state: match &config.baro {
                BaroDamping::Ekf(m) => BaroState::start(m),
                BaroDamping::Off | BaroDamping::InertialLoop(_) => BaroState::off(),
            },
            loop_design: design.baro_loop,
            vloop: None,
            last_baro_time: None,
            held_baro: None,
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
        let mut out = NavSolution {
            time: self.time,
            state: *self.ins.state(),
            nav_covariance: SMatrix::zeros(),
        };
        self.solution_into(&mut out);
        out
    }

    /// [`Self::solution`] written into `out` (no copy of the 9 × 9 covariance through the
    /// stack).
    fn solution_into(&self, out: &mut NavSolution<T>) {
        out.time = self.time;
        match &self.ekf {
            Some(e) => {
                out.state = *e.state();
                nav_block_to_ned(e.covariance(), e.state(), &mut out.nav_covariance);
            }
            None => {
                out.state = *self.ins.state();
                out.nav_covariance = self.carry_cov;
            }
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
    /// sample (non-finite, beyond range, not later than the last tick; in carry, an interval
    /// longer than the INS integrates, [`crate::seeker_ins::MAX_INTERVAL_S`]): `Err`, nothing
    /// changed. After the release a long interval is a gap the EKF handles, not an error:
    /// bridged up to its `ImuFaultPolicy::max_gap_s`, its navigation block restarted after a
    /// longer one (the seeker INS's gap handling, `Health::gaps_bridged` / `gaps_reset`). A
    /// bad aid: refused (its state `Refused`, counted), nothing of it applied, the tick still
    /// runs. The report is returned by value: a flight loop that
    /// keeps one report slot of its own uses [`Self::tick_into`] (less stack, no copy).
    pub fn tick(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
    ) -> Result<TickReport<T>, NavError> {
        let mut out = self.blank_report();
        self.tick_into(imu, aids, &mut out)?;
        Ok(out)
    }

    /// [`Self::tick`] with the report written into the caller's `out` (the 9 × 9 covariance
    /// and the aid reports are not returned through the stack). On `Err` nothing changed,
    /// `out` included.
    pub fn tick_into(
        &mut self,
        imu: &ImuTick<T>,
        aids: &Aids<'_, T>,
        out: &mut TickReport<T>,
    ) -> Result<(), NavError> {
        if self.ticked && imu.increment.time <= self.time || imu.increment.time <= self.start {
            return Err(NavError::TimeNotIncreasing);
        }
        let mut transition = self.pending.take();
        // The phase's tick writes the aid reports into `out` only when it succeeds.
        let r = if self.phase == Phase::Carry {
            self.tick_carry_apart(imu, aids, &mut transition, out)
        } else {
            self.tick_flight(imu, aids, &mut transition, out)
        };
        if let Err(e) = r {
            // Nothing committed: restore the pending transition.
            self.pending = transition;
            return Err(e);
        }
        self.ticked = true;
        let degr = Degradation {
            separation: self.separation,
            master: self.master_availability(),
            baro: self.baro_availability(),
            seeker: self.seeker_availability(),
        };
        out.health = self.health(&degr);
        out.degradation = degr;
        out.phase = self.phase;
        out.transition = transition;
        self.solution_into(&mut out.solution);
        // The EKF's deferred PSD check (module `psd_check`), last: the report carries P as the
        // tick left it (a lift, ≤ 16 ε of each variance, shows from the next tick on), and
        // the tick's frame holds nothing more across the call. From the separation tick on.
        if self.phase != Phase::Carry {
            self.psd_end_of_tick();
        }
        Ok(())
    }

    /// A report slot for [`Self::tick_into`] to overwrite: the current solution without its
    /// covariance (zero), the aids `NotUsedInPhase`, health `Initialising`.
    pub fn blank_report(&self) -> TickReport<T> {
        let none = |t: &AidTrack<T>| t.status(AidState::NotUsedInPhase);
        TickReport {
            solution: NavSolution {
                time: self.time,
                state: *self.ins.state(),
                nav_covariance: SMatrix::zeros(),
            },
            phase: self.phase,
            transition: None,
            master: none(&self.master),
            baro: none(&self.baro),
            seeker: none(&self.seeker),
            health: HealthState::Initialising,
            degradation: Degradation::default(),
        }
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
}

fn lost_if(lost: bool) -> AidAvailability {
    if lost {
        AidAvailability::TimedOut
    } else {
        AidAvailability::Available
    }
}

impl<T: Real, const K: usize, const N: usize, const H: usize> Navigator<T, K, N, H> {
    /// The histories' depth `H` against the master latency the configuration accepts:
    /// `(H − 2) · imu_dt_s ≥ max_master_latency_s` (the slave's interval means are placed at
    /// their mid-points, so the oldest interpolation point is `H − 3/2` ticks back; one tick
    /// of margin for a late tick). `InvalidConfig { field: "max_master_latency_s", issue:
    /// OutOfRange }` when the ring is too short (e.g. `H` = 64 reaches 62 ms at 1 kHz, less
    /// than a bus latency of 100 ms: `H` ≥ 102 there).
    fn check_history_depth(config: &NavigatorConfig<T>) -> Result<(), NavError> {
        let reach_s = T::lit(H.saturating_sub(2) as f64) * config.imu_dt_s;
        if reach_s >= config.max_master_latency_s {
            Ok(())
        } else {
            Err(NavError::InvalidConfig {
                field: "max_master_latency_s",
                issue: crate::error::ConfigIssue::OutOfRange,
            })
        }
    }

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

//! The flight navigator's public types: configuration, inputs, reports.

use super::handover::{HandoverPriors, LeverArm};
use crate::contract::{AidCounters, FusionReport};
use crate::error::{require_non_negative, require_positive};
use crate::seeker_ins::{ClipFlags, ImuIncrement, InsState, LosSample, Position, SeekerInsConfig};
use crate::time::Timestamp;
use crate::transfer_alignment::TaConfig;
use crate::vertical_channel::{BaroSample, ClassicalConfig};
use crate::{HealthState, NavError, Real};
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Everything the navigator is configured with (validated by [`super::Navigator::new`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct NavigatorConfig<T> {
    /// The transfer-alignment filter's configuration (flight or conventional); its `dt_s`
    /// must be `imu_dt_s` and its `lever_arm_m` the nominal lever arm of `lever_arm`.
    pub alignment: TaConfig<T>,
    /// The slave IMU's station in master body axes, m, with its 1σ.
    pub lever_arm: LeverArm<T>,
    /// Priors (1σ) of the EKF states the alignment does not hand over.
    pub priors: HandoverPriors<T>,
    /// The 17-state EKF of free flight (landmark inside); its `imu_dt_s` must be `imu_dt_s`.
    pub ins: SeekerInsConfig<T>,
    /// Nominal IMU interval, s.
    pub imu_dt_s: T,
    /// The largest master latency the navigator must accept: the age of a master sample's
    /// time of validity at the tick it is handed in, s (≥ 0). The slave history and the ring
    /// of INS snapshots, `H` ticks deep, must reach back to it: `(H − 2) · imu_dt_s ≥
    /// max_master_latency_s` (one tick for the interpolation between interval mid-points, one
    /// of margin for a late tick), checked at construction
    /// (`InvalidConfig { field: "max_master_latency_s", issue: OutOfRange }`). A sample older
    /// than the ring reaches is refused (`MeasurementTimeOutOfWindow`).
    pub max_master_latency_s: T,
    /// Release confirmation and coast.
    pub separation: SeparationCheck<T>,
    /// How the baro damps the vertical channel from midcourse on.
    pub baro: BaroDamping<T>,
    /// After how long without a usable sample an aid is declared lost.
    pub timeouts: AidTimeouts<T>,
}

/// The baro's error model for [`BaroDamping::Ekf`] (all 1σ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaroErrorModel<T> {
    /// White noise of one sample, m (> 0).
    pub white_sigma_m: T,
    /// Stationary 1σ of the correlated (first-order Gauss-Markov) error, m (≥ 0).
    pub markov_sigma_m: T,
    /// Correlation time of the correlated error, s (> 0).
    pub markov_tau_s: T,
    /// First-order lag of the baro, s (≥ 0): compensated to first order with the INS's
    /// vertical velocity.
    pub lag_s: T,
}

/// Baro damping of the vertical channel (midcourse and terminal).
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum BaroDamping<T> {
    /// No damping: the free INS vertical channel (baro samples reported `NotUsedInPhase`).
    Off,
    /// Baro altitude as a scalar EKF measurement with the correlated error as an 18th state.
    Ekf(BaroErrorModel<T>),
    /// The classical 3rd-order baro-inertial loop ([`crate::vertical_channel::ClassicalLoop`])
    /// around the INS's vertical channel: driven by the INS's own vertical specific force
    /// (`C_b^n f_b`) plus the vertical Coriolis and transport-rate acceleration, started from
    /// the INS's ĥ, V̂_z and the EKF's (δh, δV_D) covariance, its ĥ and V̂_D fed back into the
    /// INS every tick, the EKF's (δh, δV_D) block replaced by the loop's σ covariance. Its `imu_dt_s` must be the navigator's. The
    /// loop owns the vertical channel: a LOS update's correction of h and V_D is replaced by
    /// the loop's at the next tick, and the loop's accelerometer-bias estimate is not fed back.
    /// Needs the crate feature `baro-inertial-loop` (default); without it the configuration
    /// is refused (`InvalidConfig { field: "baro", issue: OutOfRange }`).
    InertialLoop(ClassicalConfig<T>),
}

/// Release confirmation by the IMU, and the coast before midcourse.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeparationCheck<T> {
    /// Departure of the slave's specific force from the last master's lever-arm-compensated
    /// specific force (in slave axes) that confirms separation, m/s² (> 0). Without a signal,
    /// the unloading (the slave's force along the carried one falling short of it) and the
    /// free fall (`|f_s|` below it) that declare a release (module doc, "Separation").
    pub specific_force_jump_m_s2: T,
    /// How long after the release signal the IMU may confirm it, s (> 0). Without a signal,
    /// how long the unloading or the free fall must last, on every tick, to declare a release.
    pub confirm_window_s: T,
    /// Without a signal: the latest start of the unloading after the last fused master
    /// sample's time of validity for the two to be one event (the umbilical and the bus go
    /// with the release), s (> 0, ≤ `timeouts.master_s`). An unloading that starts later,
    /// the master already silent, is an aircraft manoeuvre during a bus dropout as likely as a
    /// release: only the free fall declares one then.
    pub unsignalled_onset_s: T,
    /// Time from release to midcourse (baro damping enabled), s (≥ 0).
    pub coast_s: T,
}

/// How long an aid may stay without a usable sample before it is declared lost, s (> 0).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidTimeouts<T> {
    /// Master INS in carry (since the last fused master sample, or the start).
    pub master_s: T,
    /// Baro in midcourse and terminal (since the last accepted sample, or midcourse start).
    pub baro_s: T,
    /// Seeker in terminal (since the last fused LOS component).
    pub seeker_s: T,
}

/// Where the navigator starts (power-up, under the wing).
#[derive(Debug, Clone, Copy)]
pub struct NavigatorInitial<T> {
    /// Time of `state` (the first IMU tick must be later).
    pub time: Timestamp,
    /// The missile INS's start, e.g. from the master at power-up.
    pub state: InsState<T>,
    /// Its error covariance in the [`NavSolution::nav_covariance`] convention (9 × 9:
    /// δr NED m, δv NED m/s, φ rad): the solution's σ until the first master sample.
    pub nav_covariance: SMatrix<T, 9, 9>,
}

/// The aircraft master INS over the bus (time of validity `time`; arrives 10–100 ms late,
/// sometimes not at all).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MasterNav<T> {
    /// Time of validity (the flight computer's clock).
    pub time: Timestamp,
    /// Attitude `C_m^n` of the master body.
    pub c_m_n: Matrix3<T>,
    /// Velocity over the earth, NED, m/s.
    pub vel_ned_m_s: Vector3<T>,
    /// Geodetic position of the master IMU.
    pub position: Position,
    /// Inertial angular rate `ω_im^m`, master axes, rad/s.
    pub angular_rate_rad_s: Vector3<T>,
    /// Angular acceleration, master axes, rad/s².
    pub angular_accel_rad_s2: Vector3<T>,
    /// Specific force, master axes, m/s².
    pub specific_force_m_s2: Vector3<T>,
    /// 1σ of the attitude error per NED axis, rad.
    pub attitude_sigma_rad: Vector3<T>,
    /// 1σ of the velocity error per NED axis, m/s.
    pub velocity_sigma_m_s: Vector3<T>,
    /// 1σ of the position error per NED axis, m.
    pub position_sigma_m: Vector3<T>,
}

/// One IMU sample of the missile (slave) IMU.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ImuTick<T> {
    /// Increments and their time stamp (end of the interval).
    pub increment: ImuIncrement<T>,
    /// Axes at their range (used from release on: the EKF inflates P for them).
    pub clipped: ClipFlags,
}

/// What arrived since the last tick (any may be `None`).
#[derive(Debug, Clone, Copy)]
pub struct Aids<'a, T> {
    /// Master INS sample (carry).
    pub master: Option<&'a MasterNav<T>>,
    /// Baro altitude (up, m).
    pub baro: Option<&'a BaroSample<T>>,
    /// Seeker gimbal angles, only when the seeker reports lock.
    pub seeker: Option<&'a LosSample<T>>,
    /// The aircraft's release signal, with its time.
    pub separation: Option<Timestamp>,
}

impl<T> Aids<'_, T> {
    /// Nothing arrived.
    pub const NONE: Self = Self {
        master: None,
        baro: None,
        seeker: None,
        separation: None,
    };
}

/// Flight phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Phase {
    /// Under the wing: INS slaved to the master, transfer alignment running.
    Carry,
    /// Separated: INS + EKF prediction only.
    Released,
    /// Baro damping of the vertical channel.
    Midcourse,
    /// Seeker LOS updates (from the first fused component on).
    Terminal,
}

/// Why a phase changed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum TransitionCause {
    /// Release signal confirmed by the IMU.
    SeparationConfirmed,
    /// Master lost and the IMU saw the separation without a signal (module doc,
    /// "Separation": the unloading with the master's loss, or the free fall).
    UnsignalledSeparation,
    /// [`super::Navigator::release_with`].
    ReleaseCommanded,
    /// `coast_s` elapsed since release.
    CoastElapsed,
    /// First fused LOS component.
    SeekerFused,
}

/// A phase change.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Transition {
    /// Phase before.
    pub from: Phase,
    /// Phase after.
    pub to: Phase,
    /// Why.
    pub cause: TransitionCause,
    /// Tick at which it happened.
    pub time: Timestamp,
}

/// State of one aid at a tick.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AidState {
    /// The phase does not use this aid (a sample that arrives is ignored, not counted).
    NotUsedInPhase,
    /// Used, no sample this tick (and not timed out). A sample that could not be fused for
    /// numerical reasons also leaves the aid `Waiting` (its report says `Skipped`).
    Waiting,
    /// A sample was fused this tick (at least one component).
    Fused,
    /// A sample was rejected by the gate this tick.
    Rejected,
    /// A sample was refused as invalid input this tick: nothing changed.
    Refused(NavError),
    /// A valid baro sample arrived on a tick whose one heavy update went to the seeker's LOS
    /// sample: checked and held, fused at its own time stamp on the next tick without a LOS
    /// sample (module doc, "One heavy update per tick"), or superseded by a newer one.
    Held,
    /// No usable sample for longer than its timeout.
    TimedOut,
}

/// One aid's report at a tick.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidStatus<T> {
    /// This tick's state.
    pub state: AidState,
    /// The last fusion report of this aid (any tick): innovation, variance, NIS, test ratio.
    /// For the master, the transfer alignment's component with the largest NIS; for the
    /// seeker, the LOS component with the largest NIS.
    pub last: Option<FusionReport<T>>,
    /// Counters since start (components fused / rejected / skipped, samples refused).
    pub counters: AidCounters,
}

/// Availability of an aid (for [`Degradation`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum AidAvailability {
    /// Not used in this phase, or within its timeout.
    #[default]
    Available,
    /// Timed out in a phase that uses it.
    TimedOut,
}

/// How the navigator left (or is leaving) the carry phase.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SeparationStatus {
    /// No release signal yet.
    #[default]
    NotSignalled,
    /// Signal received; the IMU has not confirmed it yet (within the window).
    AwaitingConfirmation,
    /// Signal confirmed by the IMU: released.
    Confirmed,
    /// Signal without the IMU's confirmation within the window: stays in carry.
    SeparationUnconfirmed,
    /// Master lost and the IMU saw the separation (the unloading with the master's loss, or
    /// the free fall; module doc, "Separation"): released without a signal.
    UnsignalledRelease,
    /// Released by [`super::Navigator::release_with`].
    Commanded,
}

/// The degraded conditions at a tick (all enums).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Degradation {
    /// Master in carry.
    pub master: AidAvailability,
    /// Baro in midcourse / terminal.
    pub baro: AidAvailability,
    /// Seeker in terminal.
    pub seeker: AidAvailability,
    /// Separation.
    pub separation: SeparationStatus,
}

/// The navigation solution.
#[derive(Debug, Clone, Copy)]
pub struct NavSolution<T> {
    /// Time of validity.
    pub time: Timestamp,
    /// Position, velocity, attitude of the missile body.
    pub state: InsState<T>,
    /// Error covariance (estimate − truth) of `[δr_N, δr_E, δr_D (m), δV_N, δV_E, δV_D
    /// (m/s), φ_N, φ_E, φ_D (rad)]`, φ as in the seeker INS (`Ĉ_b^n = (I − [φ×]) C_b^n`).
    /// The position is in NED metres (the EKF's δL, δl, δh scaled by `R_M + h`,
    /// `(R_N + h) cos L` and −1). In carry: the hand-over covariance of the last master
    /// sample (what the EKF would start from); after release: the EKF's.
    pub nav_covariance: SMatrix<T, 9, 9>,
}

/// What one tick did.
#[derive(Debug, Clone, Copy)]
pub struct TickReport<T> {
    /// The solution after the tick.
    pub solution: NavSolution<T>,
    /// The phase after the tick.
    pub phase: Phase,
    /// A phase change at this tick.
    pub transition: Option<Transition>,
    /// Master INS (carry).
    pub master: AidStatus<T>,
    /// Baro (midcourse, terminal).
    pub baro: AidStatus<T>,
    /// Seeker LOS (midcourse: waiting for the first fusion; terminal).
    pub seeker: AidStatus<T>,
    /// Overall health: the EKF's after release, combined with the degradations.
    pub health: HealthState,
    /// The degraded conditions.
    pub degradation: Degradation,
}

impl<T: Real> NavigatorConfig<T> {
    /// Checks what the navigator itself adds to its estimators' configurations (those are
    /// checked by their own constructors). Errors: `InvalidConfig` naming the field.
    pub fn validate(&self) -> Result<(), NavError> {
        let dt = require_positive("imu_dt_s", self.imu_dt_s)?;
        let same = |a: T| (a - dt).abs() <= dt * T::lit(1e-6);
        if !same(self.alignment.dt_s) {
            return Err(out_of_range("alignment.dt_s"));
        }
        if !same(self.ins.imu_dt_s) {
            return Err(out_of_range("ins.imu_dt_s"));
        }
        if self.alignment.lever_arm_m != self.lever_arm.nominal_m {
            return Err(out_of_range("alignment.lever_arm_m"));
        }
        let s = &self.separation;
        require_positive(
            "separation.specific_force_jump_m_s2",
            s.specific_force_jump_m_s2,
        )?;
        require_positive("separation.confirm_window_s", s.confirm_window_s)?;
        require_positive("separation.unsignalled_onset_s", s.unsignalled_onset_s)?;
        require_non_negative("separation.coast_s", s.coast_s)?;
        require_non_negative("max_master_latency_s", self.max_master_latency_s)?;
        let t = &self.timeouts;
        require_positive("timeouts.master_s", t.master_s)?;
        if s.unsignalled_onset_s > t.master_s {
            return Err(out_of_range("separation.unsignalled_onset_s"));
        }
        require_positive("timeouts.baro_s", t.baro_s)?;
        require_positive("timeouts.seeker_s", t.seeker_s)?;
        if let BaroDamping::Ekf(m) = &self.baro {
            require_positive("baro.white_sigma_m", m.white_sigma_m)?;
            require_non_negative("baro.markov_sigma_m", m.markov_sigma_m)?;
            require_positive("baro.markov_tau_s", m.markov_tau_s)?;
            require_non_negative("baro.lag_s", m.lag_s)?;
        }
        if let BaroDamping::InertialLoop(c) = &self.baro {
            if !INERTIAL_LOOP {
                return Err(out_of_range("baro"));
            }
            if !same(c.imu_dt_s) {
                return Err(out_of_range("baro.imu_dt_s"));
            }
        }
        Ok(())
    }
}

/// `true` when the crate is built with the feature `baro-inertial-loop` (default): the
/// navigator carries [`BaroDamping::InertialLoop`]. Without it the configuration check refuses
/// that damping, and every path to the loop is tested against this constant first, so a flight
/// image links none of the loop's code.
pub(crate) const INERTIAL_LOOP: bool = cfg!(feature = "baro-inertial-loop");

fn out_of_range(field: &'static str) -> NavError {
    NavError::InvalidConfig {
        field,
        issue: crate::error::ConfigIssue::OutOfRange,
    }
}

impl<T: Real> PartialEq for NavigatorInitial<T> {
    fn eq(&self, o: &Self) -> bool {
        self.time == o.time && self.state == o.state && self.nav_covariance == o.nav_covariance
    }
}

impl<T: Real> PartialEq for NavSolution<T> {
    fn eq(&self, o: &Self) -> bool {
        self.time == o.time && self.state == o.state && self.nav_covariance == o.nav_covariance
    }
}

impl<T: Real> PartialEq for TickReport<T> {
    fn eq(&self, o: &Self) -> bool {
        self.solution == o.solution
            && self.phase == o.phase
            && self.transition == o.transition
            && self.master == o.master
            && self.baro == o.baro
            && self.seeker == o.seeker
            && self.health == o.health
            && self.degradation == o.degradation
    }
}

//! The flight navigator's building blocks: the three estimators flown as one chain (spec
//! `flight-navigator.md`). An estimator module never uses another; this module composes them.
//!
//! * [`Navigator`] (`flight`, `types`, `baro`): the phase state machine carry → released →
//!   midcourse → terminal around one missile INS, with the transfer alignment under the wing
//!   and the 17-state EKF after release (see "Flight navigator" below).
//! * [`hand_over`] (`handover`): the launch hand-over from the transfer alignment under the wing to the
//!   free-flight INS and its 17-state EKF — attitude, velocity and position carried through
//!   the lever arm, with their covariance mapped into the EKF's error state.
//!
//! ```
//! use nalgebra::{Matrix3, Vector3};
//! use nav_core::navigator::{hand_over, AlignmentAtRelease, HandoverPriors, LeverArm, MasterAtRelease};
//! use nav_core::seeker_ins::{Position, ATT};
//!
//! let master = MasterAtRelease::<f32> {
//!     c_m_n: Matrix3::identity(),
//!     vel_ned_m_s: Vector3::new(180.0, 0.0, 0.0),
//!     position: Position { lat_rad: 0.6458, lon_rad: 2.2166, alt_m: 3000.0 },
//!     rate_nm_rad_s: Vector3::zeros(),
//!     attitude_sigma_rad: Vector3::new(2e-4, 2e-4, 8e-4),
//!     velocity_sigma_m_s: Vector3::new(0.05, 0.05, 0.08),
//!     position_sigma_m: Vector3::new(3.0, 3.0, 5.0),
//!     rate_sigma_rad_s: 1e-4,
//! };
//! let alignment = AlignmentAtRelease::<f32> {
//!     theta_rad: Vector3::new(0.01, -0.005, 0.02),
//!     theta_covariance_rad2: Matrix3::from_diagonal_element(1e-7),
//!     flexure_rad: Vector3::zeros(),
//!     flexure_rate_rad_s: Vector3::zeros(),
//!     flexure_rate_covariance: Matrix3::from_diagonal_element(1e-6),
//!     theta_bias_covariance: Matrix3::zeros(),
//!     bias_prior_variance_m2_s4: Vector3::zeros(),
//!     slave_share_variance_m2_s4: Vector3::zeros(),
//! };
//! let lever = LeverArm { nominal_m: Vector3::new(1.5, 4.0, 0.6), sigma_m: Vector3::from_element(0.01) };
//! let priors = HandoverPriors { accel_bias_sigma_m_s2: 1e-3, gyro_bias_sigma_rad_s: 5e-8, gimbal_bias_sigma_rad: 7e-4 };
//! let initial = hand_over(&master, &alignment, &lever, &priors)?; // → SeekerIns::new(&config, &initial)
//! // The yaw variance is the master's plus the alignment's.
//! let p_yaw = initial.covariance[(ATT + 2, ATT + 2)];
//! assert!((p_yaw - (8e-4f32 * 8e-4 + 1e-7)).abs() < 1e-9);
//! # Ok::<(), nav_core::NavError>(())
//! ```

//!
//! # Flight navigator
//!
//! [`Navigator`] owns one missile INS through the whole flight and one value per estimator;
//! the firmware calls [`Navigator::tick`] at the IMU rate with the IMU sample and the aids that
//! arrived ([`Aids`]), and reads a [`TickReport`] (solution with its 9 × 9 covariance, phase,
//! transition, one [`AidStatus`] per aid, health, [`Degradation`]).
//!
//! | phase | what runs | aids |
//! | --- | --- | --- |
//! | [`Phase::Carry`] | strapdown INS ([`crate::seeker_ins::Ins`]) on the slave IMU; transfer alignment at each master epoch | master (late, time-tagged) |
//! | [`Phase::Released`] | INS + 17-state EKF, prediction only (`propagate` / `propagate_clipped`) | none |
//! | [`Phase::Midcourse`] | + baro damping ([`BaroDamping`]) | baro; seeker samples tried (first fused component → terminal) |
//! | [`Phase::Terminal`] | + LOS updates | baro, seeker |
//!
//! **Carry.** Every tick the INS integrates the slave increment, the slave sample
//! (rate `Δθ/dt`, specific force `Δv/dt`) goes into a [`crate::transfer_alignment::SlaveHistory`]
//! and the INS state into a ring of `H` snapshots. A master sample of time of validity `t_m`
//! (any latency up to `H − 3/2` ticks; sizing rule, checked at construction against
//! [`NavigatorConfig::max_master_latency_s`]: `(H − 2) · imu_dt_s ≥ max_master_latency_s`,
//! e.g. `H` ≥ 102 for 100 ms at 1 kHz; ≈ 96 B of RAM per tick of depth in f32, no code or
//! stack) is matched with the slave at its epoch: the slave samples are
//! interval means, i.e. values at their interval's mid-point, and are interpolated at `t_m`
//! ([`SlaveHistory::at_time`](crate::transfer_alignment::SlaveHistory::at_time); pairing the
//! end-stamped mean with the instantaneous master would mismatch by half an interval of the
//! roll-in's rate and force changes). The hand-over at `t_m` is computed with the updated alignment
//! ([`hand_over`]), and the INS is slaved to it: the difference between the INS snapshot at
//! `t_m` and the transferred solution is removed from the current INS state (and from the
//! snapshots since `t_m`) — an error-state reset, as the EKF's feedback. The solution's
//! covariance in carry is the hand-over covariance at the last master epoch (what the EKF
//! would start from; not grown over the latency). Master samples are fused only at their
//! epochs: the alignment is not propagated between them (a dropout longer than its
//! `max_gap_steps` re-initialises its flexure states, as the filter documents).
//!
//! **Separation.** The release signal ([`Aids::separation`]) is confirmed when the slave's
//! specific force departs from the last master's lever-arm-compensated specific force (turned
//! into slave axes by the alignment's θ̂) by more than `specific_force_jump_m_s2` within
//! `confirm_window_s` of the signal; then the EKF starts ([`SeekerIns`](crate::seeker_ins::SeekerIns))
//! from the current (slaved) INS state with the hand-over P0 of the last master epoch. A
//! signal the IMU does not confirm in the window: [`SeparationStatus::SeparationUnconfirmed`],
//! the navigator stays in carry (degraded).
//!
//! *Without a signal* ([`SeparationStatus::UnsignalledRelease`], released, degraded) the
//! navigator has the IMU and the bus's silence: the umbilical and the bus go with the release.
//! A missile on the pylon feels the aircraft's specific force at its station (the pylon holds
//! it: ≈ 1 g up in level flight, the load factor in a turn or a pull-up); a released missile
//! only its own aerodynamic forces and thrust, so along the carried force it reads less: it
//! *unloads*. The slave's specific force is averaged over a window of `confirm_window_s`
//! (the mean of the IMU's Δv over five blocks of a fifth each, tested at each block's end:
//! independent of the IMU rate, and a vibration at release — an ejector, a clipped 200 Hz
//! burst sampled at 1 kHz — averages out instead of breaking an every-tick test). A release
//! is declared when the master has timed out (`timeouts.master_s`) and either
//!
//! 1. *unloading with the master's loss*: the window's mean falls short of the last fused
//!    master sample's carried force `f_c` (lever-arm compensated, in slave axes by θ̂) along
//!    it by more than `specific_force_jump_m_s2`, `|f_c| − f̄_s·f_c/|f_c| > jump`, in a window
//!    that starts after that sample's time of validity and at most `unsignalled_onset_s`
//!    after it (the first such window is kept: after a drop the pull-out and the boost need
//!    not unload; a master sample fused later withdraws it — the bus was alive); or
//! 2. *free fall*: the window's mean `|f̄_s|` is below `specific_force_jump_m_s2`, however long
//!    the master has been silent (a release during a bus dropout).
//!
//! Parameters: `specific_force_jump_m_s2` (m/s², > 0), `confirm_window_s` (s, > 0),
//! `unsignalled_onset_s` (s, > 0 and ≤ `timeouts.master_s`, else `InvalidConfig`),
//! `timeouts.master_s` (s). The time from release to declaration is the later of the
//! master's time-out after its last fused sample and the first window's end (≈ 0.57-0.58 s on
//! the mission's drop at 100 and 1000 Hz with a 0.5 s time-out and window).
//!
//! The trade. *False release* (on the wing): a bus dropout during a manoeuvre that unloads by
//! more than the threshold on average over a window starting within `unsignalled_onset_s` of
//! the last master epoch — a push-over or a roll-out of a turn whose onset coincides with the
//! bus's failure (3 m/s² within 0.3 s, a jerk above 10 m/s³) — or one that holds less than
//! `jump` for a whole window (a zero-g manoeuvre). A turn or a pull-up loads the missile and
//! never releases it; an unloading that starts later than the onset bound (the short stress
//! mission's roll-out during a 2 s dropout: 12 m/s² of unloading, crossing 3 m/s² ≈ 1 s after
//! the bus's loss) does not either. Larger `jump` and `confirm_window_s`, smaller
//! `unsignalled_onset_s` make false releases rarer. *Missed release*: a release whose mean
//! unloading over every window starting within the onset bound stays below `jump` (a
//! velocity deficit along the carried force below `jump × confirm_window_s`, 1.5 m/s for the
//! mission: the mission's 1 s drop to −3° at 180 m/s has 9.4 m/s), or whose bus outlives
//! the onset bound; it is then declared only on free fall, else the navigator stays in carry.
//! Releases whose thrust and lift hold the carried force (a powered rail launch) are not
//! seen by either cue: they need the signal.
//!
//! What carries over: position, velocity, attitude and their covariance (the hand-over's),
//! gyro and gimbal biases from their priors. The flight alignment's estimate of the
//! specific-force-difference bias is **not** handed over: the EKF's accelerometer bias starts
//! from its prior (`priors.accel_bias_sigma_m_s2`), zero estimate, but with the attitude–bias
//! cross-covariance the alignment's joint estimate of θ and that bias implies ([`hand_over`]).
//! While a signalled separation awaits the IMU's confirmation, master samples whose epoch is
//! within one IMU interval of the signal's or later are not fused (`NotUsedInPhase`): the
//! slave interpolated at that epoch is already the dropping missile, no longer the wing's
//! (the flexure's motion gone), and one such sample moved the hand-over's attitude and
//! vertical velocity by several σ.
//!
//! **Released → midcourse** after `coast_s`. **Midcourse**: [`BaroDamping::Ekf`] fuses the
//! baro altitude as a scalar EKF measurement with its correlated error as an 18th state kept
//! beside the 17 ([`BaroState`]); [`BaroDamping::InertialLoop`] runs the classical
//! baro-inertial loop around the INS's vertical channel and gives the EKF its σ;
//! [`BaroDamping::Off`] leaves the vertical channel free. **Terminal** from the first fused
//! LOS component; the seeker is `TimedOut` after `timeouts.seeker_s` without one (the phase
//! stays terminal, the baro keeps damping).
//!
//! **One heavy update per tick.** In midcourse and terminal with [`BaroDamping::Ekf`] a
//! tick runs at most one EKF update, LOS or baro (each with its pending covariance step:
//! both on one tick would not fit a flight tick's budget). When a LOS sample the EKF accepts
//! and a baro sample arrive on the same tick, the LOS is fused and the baro sample, checked
//! first, is held in a one-sample slot ([`Navigator::held_baro`]; its state
//! [`AidState::Held`]), then fused on the next tick without a LOS update at its own time
//! stamp (its age is part of the baro update's lag). A newer baro sample replaces a held one
//! (counted [`AidCounters::superseded`](crate::contract::AidCounters::superseded)): the
//! newest is fused, nothing stalls at a baro rate up to the IMU rate. A refused baro sample
//! leaves the held one as it was; a held sample counts as accepted for the baro timeout,
//! keeps across the terminal entry, and is dropped (counted skipped) only if LOS updates
//! took every tick until it was older than [`MAX_BARO_AGE_S`].
//!
//! **Refusals.** A bad IMU sample returns `Err` and changes nothing. A bad aid sample is
//! refused: its [`AidState::Refused`] names the error, its counter counts it, nothing of it is
//! applied, the tick runs. No input stalls the navigator: the next valid tick is processed as
//! usual. In flight the tick works in place, without copies of the filter: what can refuse an
//! input is checked before anything changes (a LOS sample before the pending covariance step
//! runs), and a step whose numbers can still fail (a covariance step, an update's P) is
//! atomic by itself — checked on its small quantities, or on its result before it is written.
//! The baro-inertial loop configuration steps the EKF and the loop on copies (the loop can
//! refuse after the INS has integrated the sample).
//!
//! **Changes to the agreed API** (`navigator-api.md`): [`FlightNavigator`] is
//! `Navigator<T, 5, 15, H>` (the flight alignment filter has chains of 5, not 3);
//! [`NavigatorInitial`] carries `nav_covariance` (the solution's σ until the first master
//! sample); [`NavigatorConfig`] carries `max_master_latency_s` (the histories' sizing rule)
//! and [`SeparationCheck`] `unsignalled_onset_s` (the release without a signal); [`BaroDamping::InertialLoop`] takes a
//! [`ClassicalConfig`](crate::vertical_channel::ClassicalConfig); [`Transition`] is a struct
//! (from, to, cause, time); [`AidState`] has no `Skipped` (a sample that cannot be fused
//! numerically leaves the aid `Waiting`, its report says `Skipped`) and has `Held` (a baro
//! sample waiting for the next tick, above), its counters `superseded`; [`Aids::NONE`];
//! [`MasterNav::angular_rate_rad_s`] is the inertial body rate, and the master's rate 1σ (not
//! on the bus) is taken as the alignment's `rate_noise_sigma_rad_s`; the solution's position
//! covariance is in NED metres ([`NavSolution::nav_covariance`]). The baro timeout counts
//! accepted samples, the master and seeker timeouts fused ones.
//!
//! ```
//! use nalgebra::{Matrix3, SMatrix, Vector3, Quaternion};
//! use nav_core::navigator::*;
//! use nav_core::seeker_ins::{ClipFlags, ImuIncrement, InsState, Landmark, Position, SeekerInsConfig};
//! use nav_core::transfer_alignment::{PaperCase, TaConfig};
//! use nav_core::time::Timestamp;
//!
//! let alignment = TaConfig::<f32>::flight(PaperCase::Case1); // 100 Hz, lever arm [0, 5, 0] m
//! let here = Position { lat_rad: 0.6458, lon_rad: 2.2166, alt_m: 100.0 };
//! let config = NavigatorConfig {
//!     lever_arm: LeverArm { nominal_m: alignment.lever_arm_m, sigma_m: Vector3::from_element(0.01) },
//!     alignment,
//!     priors: HandoverPriors { accel_bias_sigma_m_s2: 1e-3, gyro_bias_sigma_rad_s: 5e-8, gimbal_bias_sigma_rad: 7e-4 },
//!     ins: SeekerInsConfig::flight(Landmark::new(Position { lat_rad: 0.6462, ..here })?),
//!     imu_dt_s: 0.01,
//!     max_master_latency_s: 0.1, // 10 ticks: H = 32 reaches 0.3 s
//!     separation: SeparationCheck {
//!         specific_force_jump_m_s2: 4.0,
//!         confirm_window_s: 0.3,
//!         unsignalled_onset_s: 0.3,
//!         coast_s: 2.0,
//!     },
//!     baro: BaroDamping::Ekf(BaroErrorModel { white_sigma_m: 1.0, markov_sigma_m: 5.0, markov_tau_s: 100.0, lag_s: 0.0 }),
//!     timeouts: AidTimeouts { master_s: 0.5, baro_s: 1.0, seeker_s: 2.0 },
//! };
//! let level = InsState { position: here, vel_ned_m_s: Vector3::zeros(), q_b_n: Quaternion::identity() };
//! let initial = NavigatorInitial {
//!     time: Timestamp::ZERO,
//!     state: level,
//!     nav_covariance: SMatrix::from_diagonal_element(1.0),
//! };
//! let mut nav = FlightNavigator::<f32, 32>::new(&config, &initial)?;
//! let g = 9.80_f32;
//! let mut log = Vec::new(); // the aircraft's master INS (here: at rest, level)
//! for k in 1..=60_u64 {
//!     let time = Timestamp::from_micros(k * 10_000);
//!     // The missile drops at 0.5 s: its IMU reads 0 g.
//!     let fz = if k > 50 { 0.0 } else { -g };
//!     let imu = ImuTick {
//!         increment: ImuIncrement { time, delta_theta_rad: Vector3::zeros(), delta_v_m_s: Vector3::new(0.0, 0.0, fz * 0.01) },
//!         clipped: ClipFlags::default(),
//!     };
//!     log.push(MasterNav {
//!         time,
//!         c_m_n: Matrix3::identity(),
//!         vel_ned_m_s: Vector3::zeros(),
//!         position: here,
//!         angular_rate_rad_s: Vector3::zeros(),
//!         angular_accel_rad_s2: Vector3::zeros(),
//!         specific_force_m_s2: Vector3::new(0.0, 0.0, -g),
//!         attitude_sigma_rad: Vector3::new(2e-4, 2e-4, 8e-4),
//!         velocity_sigma_m_s: Vector3::from_element(0.05),
//!         position_sigma_m: Vector3::from_element(3.0),
//!     });
//!     // Master samples every 20 ms, 30 ms late, until the release.
//!     let master = (k % 2 == 0 && k > 3 && k <= 50).then(|| log[k as usize - 4]);
//!     let aids = Aids { master: master.as_ref(), separation: (k == 51).then_some(time), ..Aids::NONE };
//!     let report = nav.tick(&imu, &aids)?;
//!     if let Some(t) = report.transition {
//!         assert_eq!((t.to, t.cause), (Phase::Released, TransitionCause::SeparationConfirmed));
//!     }
//!     let _sigma_north_m = report.solution.nav_covariance[(0, 0)].sqrt();
//! }
//! assert_eq!(nav.phase(), Phase::Released);
//! # Ok::<(), nav_core::NavError>(())
//! ```

// Flight navigator: see the section above.
mod baro;
mod carry;
mod design;
mod flight;
mod handover;
#[cfg(any(test, feature = "test-support"))]
#[doc(hidden)]
pub mod test_support;
#[cfg(test)]
mod tests;
mod types;

pub use baro::{BaroState, MAX_BARO_AGE_S};
pub use design::{alignment_config, NavigatorDesign};
pub use flight::{ConventionalNavigator, FlightNavigator, Navigator};
pub use handover::{
    hand_over, right_jacobian, AlignmentAtRelease, HandoverPriors, LeverArm, MasterAtRelease,
};
pub use types::{
    AidAvailability, AidState, AidStatus, AidTimeouts, Aids, BaroDamping, BaroErrorModel,
    Degradation, ImuTick, MasterNav, NavSolution, NavigatorConfig, NavigatorInitial, Phase,
    SeparationCheck, SeparationStatus, TickReport, Transition, TransitionCause,
};

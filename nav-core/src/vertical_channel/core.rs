//! The state and machinery shared by both loops: the variable-interval step, the gap
//! handling, the commit with its envelope limits, the health and counters.

use super::age_limits::AgeLimits;
use super::config::RunTime;
use super::gate::{
    admit, Admitted, AidReport, AidTally, Extrapolation, GateParams, Reacquisition, Verdict,
};
use super::gravity::GravityModel;
use super::modes::{off_nominal_increment, AidMask, Feedback, Modes};
use super::samples::{
    check_imu_values, AidChannel, AidTimeouts, BaroSample, ImuSample, SampleRule, ValidSample,
    VelocitySample, NEVER,
};
use super::sigma::{SigmaDesign, SigmaTrack};
use super::{
    ALTITUDE_RANGE_M, ESTIMATE_RANGE_M, MAX_BRIDGED_GAP_S, MAX_ESTIMATE_BIAS_M_S2,
    MAX_ESTIMATE_SPEED_M_S, MAX_VERTICAL_SPEED_M_S, RECENTRE_M,
};
use crate::contract::Health;
use crate::time::{micros_to_seconds, Timestamp};
use crate::Bounds;
use crate::{HealthState, NavError, Real};
use nalgebra::{Matrix3x2, Vector2, Vector3};

/// Longest bridged gap in µs.
pub(crate) const MAX_BRIDGED_GAP_US: u64 = 10_000_000;
const _: () = assert!(MAX_BRIDGED_GAP_US as f64 == MAX_BRIDGED_GAP_S * 1.0e6);

/// The loop's step values, fixed by the design: IMU interval, half of it, baro lag (s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepValues<T> {
    pub(crate) dt_s: T,
    pub(crate) half_dt_s: T,
    pub(crate) baro_lag_s: T,
}

/// What `LoopCore::new` copies from a design.
pub(crate) struct CoreParts<'a, T: Real> {
    pub(crate) bias_sign: f64,
    pub(crate) step: StepValues<T>,
    pub(crate) k: Matrix3x2<T>,
    pub(crate) modes: &'a Modes<T>,
    pub(crate) gravity: &'a GravityModel<T>,
    pub(crate) baro_timeouts: AidTimeouts<T>,
    pub(crate) velocity_timeouts: AidTimeouts<T>,
    pub(crate) run_time: RunTime<T>,
    pub(crate) gate: GateParams<T>,
    pub(crate) sigma: &'a SigmaDesign<T>,
}

/// The new aid samples of a step, validated.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NewSamples<T> {
    pub(crate) baro: Option<ValidSample<T>>,
    pub(crate) velocity: Option<ValidSample<T>>,
}

impl<T> NewSamples<T> {
    pub(crate) const NONE: Self = Self {
        baro: None,
        velocity: None,
    };
}

/// The reports of a step: baro, velocity, sub-steps.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct StepReports<T> {
    pub(crate) baro: AidReport<T>,
    pub(crate) velocity: AidReport<T>,
    pub(crate) imu_intervals: u32,
}

/// The shared state of both loops.
///
/// Time: the clock is a [`Timestamp`]; every interval is formed in integer microseconds and
/// converted to the float type as a duration. A step integrates the actual interval `Δt`
/// since the last accepted sample: `Δt ≤ 1.5 dt` in one step (the stored exact step at the
/// nominal `dt`, corrected for `Δt − dt` by [`off_nominal_increment`] when they differ),
/// longer intervals in sub-steps ([`super::MAX_SUBSTEPS`]), beyond those by an exact inertial coast
/// first, and gaps beyond [`MAX_BRIDGED_GAP_S`] by re-anchoring.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct LoopCore<T: Real> {
    /// `[ĥ − h_ref (m), V̂_z (m/s), b̂ (m/s²)]`: the altitude relative to `h_ref_m`, so that
    /// in f32 the per-step increments V̂_z Δt (µm to mm) are not lost to the altitude's
    /// resolution (4 mm at 40 km).
    pub(crate) x: Vector3<T>,
    /// Reference altitude, m (moved to the estimate when |ĥ − h_ref| > [`RECENTRE_M`]).
    pub(crate) h_ref_m: T,
    pub(crate) time: Timestamp,
    pub(crate) dt_s: T,
    pub(crate) dt_us: u64,
    /// Longest interval integrated in one step, `1.5 dt_us` (longer ones are bridged), µs.
    pub(crate) single_step_max_us: u64,
    /// `dt_us` when it is exactly `dt_s` in the float type (the stored step then applies
    /// as is), else 0 (an interval of a whole number of µs is never exactly `dt_s`: every
    /// step takes the corrected path; so is an interval of 2³² µs or more).
    pub(crate) nominal_us: u32,
    pub(crate) half_dt_s: T,
    pub(crate) modes: Modes<T>,
    pub(crate) feedback: Feedback<T>,
    pub(crate) gravity: GravityModel<T>,
    pub(crate) baro: AidChannel<T>,
    pub(crate) velocity: AidChannel<T>,
    pub(crate) baro_timeouts: AidTimeouts<T>,
    pub(crate) velocity_timeouts: AidTimeouts<T>,
    /// The baro loss timeout as a whole-µs age, for the nominal step (with the aid model: kept
    /// with `gate`).
    pub(crate) baro_limits: AgeLimits,
    /// The same for the velocity aid.
    pub(crate) velocity_limits: AgeLimits,
    /// The aid model, gate and recovery as configured.
    pub(crate) run_time: RunTime<T>,
    /// The same, compiled.
    pub(crate) gate: GateParams<T>,
    pub(crate) baro_tally: AidTally,
    pub(crate) velocity_tally: AidTally,
    pub(crate) health: Health,
    /// The covariance the design implies (σ of the estimate).
    pub(crate) sigma: SigmaTrack<T>,
}

/// The state a sub-step starts from and the interval it covers.
#[derive(Debug, Clone, Copy)]
pub(crate) struct SubStep<T> {
    pub(crate) x: Vector3<T>,
    pub(crate) h_ref: T,
    pub(crate) now: Timestamp,
    pub(crate) h_us: u64,
    pub(crate) specific_force: T,
    pub(crate) bridged: bool,
}

impl<T: Real> LoopCore<T> {
    /// One IMU step with optional new aid samples, over the actual interval since the last
    /// accepted sample. On error nothing changes but the refused-input counter of the input
    /// that was refused. One out-of-line body shared by both loops: the nominal step inlined
    /// (its reports written where the caller wants them), the general step called.
    #[inline(never)]
    pub(crate) fn step(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Result<StepReports<T>, NavError> {
        match self.step_nominal(imu, baro, velocity) {
            Some(r) => Ok(r),
            None => self.step_general(imu, baro, velocity),
        }
    }

    /// [`Self::step`] for every step the nominal one ([`Self::step_nominal`]) leaves: checks
    /// every input, then one sub-step or the gap bridge. One out-of-line body shared by both
    /// loops.
    #[inline(never)]
    pub(crate) fn step_general(
        &mut self,
        imu: &ImuSample<T>,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Result<StepReports<T>, NavError> {
        let us = match self.check_imu(imu) {
            Ok(us) => us,
            Err(e) => return Err(self.refused_imu(e)),
        };
        let samples = self.check_samples(imu.time, us, baro, velocity)?;
        if us <= self.single_step_max_us {
            let sub = SubStep {
                x: self.x,
                h_ref: self.h_ref_m,
                now: imu.time,
                h_us: us,
                specific_force: imu.specific_force_up_m_s2,
                bridged: false,
            };
            return match self.advance(&sub, &samples) {
                Ok(r) => Ok(r),
                Err(e) => Err(self.refused_imu(e)),
            };
        }
        match self.bridge(us, imu, &samples) {
            Ok(r) => Ok(r),
            Err(e) => Err(self.refused_imu(e)),
        }
    }

    /// The IMU sample's values and interval (µs, > 0).
    #[inline(always)]
    fn check_imu(&self, imu: &ImuSample<T>) -> Result<u64, NavError> {
        check_imu_values(imu)?;
        match imu.time.micros_since(self.time) {
            Some(d) if d > 0 => Ok(d),
            _ => Err(NavError::TimeNotIncreasing),
        }
    }

    #[cold]
    #[inline(never)]
    fn refused_imu(&mut self, e: NavError) -> NavError {
        Health::bump(&mut self.health.imu_refused);
        e
    }

    /// Validates the new aid samples against their channels as they will be when the samples
    /// enter (emptied by a gap too long to bridge); a refused sample is counted for its aid.
    #[inline(always)]
    fn check_samples(
        &mut self,
        now: Timestamp,
        us: u64,
        baro: Option<&BaroSample<T>>,
        velocity: Option<&VelocitySample<T>>,
    ) -> Result<NewSamples<T>, NavError> {
        let long_gap = us > MAX_BRIDGED_GAP_US;
        let baro = match baro {
            Some(s) => {
                let rule = SampleRule {
                    value_name: "altitude_m",
                    range: ALTITUDE_RANGE_M,
                    lost_after_s: self.baro_timeouts.lost_after_s,
                };
                match self.baro.check(s.time, s.altitude_m, now, &rule, long_gap) {
                    Ok(v) => Some(v),
                    Err(e) => return Err(self.refused_aid(true, e)),
                }
            }
            None => None,
        };
        let velocity = match velocity {
            Some(s) => {
                let rule = SampleRule {
                    value_name: "vz_up_m_s",
                    range: Bounds {
                        low: -MAX_VERTICAL_SPEED_M_S,
                        high: MAX_VERTICAL_SPEED_M_S,
                    },
                    lost_after_s: self.velocity_timeouts.lost_after_s,
                };
                match self
                    .velocity
                    .check(s.time, s.vz_up_m_s, now, &rule, long_gap)
                {
                    Ok(v) => Some(v),
                    Err(e) => return Err(self.refused_aid(false, e)),
                }
            }
            None => None,
        };
        Ok(NewSamples { baro, velocity })
    }

    #[cold]
    #[inline(never)]
    fn refused_aid(&mut self, baro: bool, e: NavError) -> NavError {
        let tally = if baro {
            &mut self.baro_tally
        } else {
            &mut self.velocity_tally
        };
        tally.counters.record_refused();
        e
    }

    /// Commits a new state: re-centres the relative altitude and holds the estimate inside
    /// its limits; a held estimate marks both aids for re-anchoring.
    #[inline(always)]
    pub(crate) fn settle(&mut self, mut x: Vector3<T>, h_ref: T) {
        let mut h_ref_new = h_ref;
        let mut limited = false;
        // `x` is finite here (checked by the caller, or bounded by construction in a coast).
        if x.x.abs() > T::lit(RECENTRE_M) {
            h_ref_new = h_ref + x.x;
            x.x = T::zero();
            let (lo, hi) = (T::lit(ESTIMATE_RANGE_M.low), T::lit(ESTIMATE_RANGE_M.high));
            if h_ref_new < lo || h_ref_new > hi {
                h_ref_new = if h_ref_new < lo { lo } else { hi };
                limited = true;
            }
        }
        let vmax = T::lit(MAX_ESTIMATE_SPEED_M_S);
        if x.y.abs() > vmax {
            x.y = if x.y < T::zero() { -vmax } else { vmax };
            limited = true;
        }
        let bmax = T::lit(MAX_ESTIMATE_BIAS_M_S2);
        if x.z.abs() > bmax {
            x.z = if x.z < T::zero() { -bmax } else { bmax };
            limited = true;
        }
        if limited {
            Health::bump(&mut self.health.limits_hit);
            self.baro.reanchor = true;
            self.velocity.reanchor = true;
            self.baro.tracking = false;
            self.velocity.tracking = false;
        }
        self.x = x;
        self.h_ref_m = h_ref_new;
    }

    /// One (sub-)step: gate, propagation, commit; the reports of one IMU interval. On error
    /// nothing changes. One out-of-line
    /// body shared by both loops' steps and every bridged sub-step (a 3-state loop does not
    /// need a copy per call site; the call costs a few instructions per step).
    #[inline(never)]
    pub(crate) fn advance(
        &mut self,
        sub: &SubStep<T>,
        samples: &NewSamples<T>,
    ) -> Result<StepReports<T>, NavError> {
        let nominal = sub.h_us == u64::from(self.nominal_us);
        let (h_s, half_h) = if nominal {
            (self.dt_s, self.half_dt_s)
        } else {
            let h = micros_to_seconds::<T>(sub.h_us);
            (h, h * T::lit(0.5))
        };
        let gated = self.gate_samples(sub, half_h, samples);
        let x = gated.x;
        let v = x.y;
        let baro_ch = gated.baro.as_ref().unwrap_or(&self.baro);
        let vel_ch = gated.velocity.as_ref().unwrap_or(&self.velocity);
        let baro_status = baro_ch.status(gated.baro_age, &self.baro_timeouts);
        let vel_status = vel_ch.status(gated.velocity_age, &self.velocity_timeouts);
        let use_baro = baro_status.in_use();
        let use_vel = vel_status.in_use();
        // Held samples extrapolated to the middle of the interval (ZOH of the continuous loop).
        let half = T::lit(0.5);
        let nu_h = use_baro.then(|| {
            let age = gated.baro_age - half_h;
            (baro_ch.last_value - sub.h_ref) + age * (v - half * gated.v_rate * age) - gated.h_pred
        });
        let nu_v =
            use_vel.then(|| vel_ch.last_value + (gated.velocity_age - half_h) * gated.v_rate - v);
        let mode = self.modes.select(use_baro, use_vel);
        let nu = Vector2::new(nu_h.unwrap_or(T::zero()), nu_v.unwrap_or(T::zero()));
        let drive = Vector2::new(v, gated.v_rate);
        let dx = if nominal {
            mode.n * drive + mode.g * nu
        } else {
            let mask = AidMask {
                baro: if use_baro { T::one() } else { T::zero() },
                velocity: if use_vel { T::one() } else { T::zero() },
            };
            off_nominal_increment(&self.feedback, mode, mask, h_s, self.dt_s, &drive, &nu)
        };
        let x_new = x + dx;
        // One test for all three: a sum of finite values is finite unless it overflows, which
        // is refused as well (unreachable with valid input: every term is bounded).
        if !(x_new.x + x_new.y + x_new.z).is_finite() {
            return Err(NavError::NonFiniteInput {
                input: "state after step",
            });
        }
        if let Some(m) = gated.moved {
            self.sigma.reanchored(m.baro, m.velocity);
        }
        self.sigma.tick(sub.h_us, use_baro, use_vel);
        // A channel changes only when a sample arrived.
        if let Some(c) = gated.baro {
            self.baro = c;
            self.baro.refresh_tracking();
        }
        if let Some(c) = gated.velocity {
            self.velocity = c;
            self.velocity.refresh_tracking();
        }
        self.settle(x_new, sub.h_ref);
        self.time = sub.now;
        self.baro_tally.count(&gated.baro_verdict);
        self.velocity_tally.count(&gated.velocity_verdict);
        self.health.state = self.health_state(sub.bridged, use_baro, use_vel);
        Ok(StepReports {
            baro: report(baro_status, nu_h, gated.baro_verdict),
            velocity: report(vel_status, nu_v, gated.velocity_verdict),
            imu_intervals: 1,
        })
    }

    /// Health after a committed step (the rules are in the module documentation).
    #[inline(always)]
    pub(super) fn health_state(&self, bridged: bool, use_baro: bool, use_vel: bool) -> HealthState {
        if self.baro.reanchor {
            HealthState::NeedsReinitialisation
        } else if bridged
            || !use_baro
            || self.baro.rejected_since != NEVER
            || self.baro.recovery_var > T::zero()
            // A channel that never received a sample (the classical loop's velocity) has no
            // rejection run and no recovery gate: one test for it.
            || (self.velocity.received
                && (!use_vel
                    || self.velocity.rejected_since != NEVER
                    || self.velocity.recovery_var > T::zero()))
        {
            HealthState::Degraded
        } else {
            HealthState::Nominal
        }
    }

    /// The gate on the new samples and the resets they call for: the channels to use, the
    /// state after the resets and the rates the held samples are extrapolated with.
    #[inline(always)]
    fn gate_samples(&self, sub: &SubStep<T>, half_h: T, samples: &NewSamples<T>) -> Gated<T> {
        let mut x = sub.x;
        let (alt, v, b) = (x.x, x.y, x.z);
        let bias_sign = self.feedback.bias_sign;
        let lag = self.feedback.lag_s;
        let mut az = sub.specific_force - self.gravity.gravity_m_s2(sub.h_ref + alt);
        // Predicted measurements at mid-interval (the baro's relative to h_ref) and the rates
        // a held sample is extrapolated with (baro: second order, h(mid) = h(t) + age (V̂ −
        // ½ a age); velocity: first order).
        let mut h_pred = alt - lag * v;
        let mut v_rate = az + bias_sign * b;
        let half = T::lit(0.5);
        let now = sub.now;
        let Admitted {
            channel: baro_ch,
            age_s: baro_age,
            verdict: baro_verdict,
        } = admit(
            true,
            &self.baro,
            self.baro.age(now),
            samples.baro,
            &Extrapolation {
                lost_after_s: self.baro_timeouts.lost_after_s,
                offset: sub.h_ref,
                half_h,
                rate: v,
                rate_slope: half * v_rate,
                pred: h_pred,
            },
            &self.gate,
            &self.gate.baro,
        );
        let Admitted {
            channel: vel_ch,
            age_s: vel_age,
            verdict: vel_verdict,
        } = admit(
            false,
            &self.velocity,
            self.velocity.age(now),
            samples.velocity,
            &Extrapolation {
                lost_after_s: self.velocity_timeouts.lost_after_s,
                offset: T::zero(),
                half_h,
                rate: v_rate,
                rate_slope: T::zero(),
                pred: v,
            },
            &self.gate,
            &self.gate.velocity,
        );
        let moved_states = moved_states(&baro_verdict, &vel_verdict, &mut x);
        if moved_states.is_some() {
            az = sub.specific_force - self.gravity.gravity_m_s2(sub.h_ref + x.x);
            h_pred = x.x - lag * x.y;
            v_rate = az + bias_sign * x.z;
        }
        Gated {
            moved: moved_states,
            x,
            h_pred,
            v_rate,
            baro: baro_ch,
            baro_age,
            baro_verdict,
            velocity: vel_ch,
            velocity_age: vel_age,
            velocity_verdict: vel_verdict,
        }
    }

    /// Altitude estimate, m.
    pub(crate) fn altitude_m(&self) -> T {
        self.h_ref_m + self.x.x
    }

    /// Accelerometer bias estimate (measured − true), m/s².
    pub(crate) fn accel_bias_m_s2(&self) -> T {
        -self.x.z * self.feedback.bias_sign
    }
}

/// The outcome of the gate in one sub-step.
struct Gated<T: Real> {
    /// The measured states a reset or re-anchoring moved (rare).
    moved: Option<Moved>,
    x: Vector3<T>,
    h_pred: T,
    v_rate: T,
    /// The baro channel after its new sample (`None`: no sample, unchanged).
    baro: Option<AidChannel<T>>,
    baro_age: T,
    baro_verdict: Option<Verdict<T>>,
    /// The velocity channel after its new sample (`None`: no sample, unchanged).
    velocity: Option<AidChannel<T>>,
    velocity_age: T,
    velocity_verdict: Option<Verdict<T>>,
}

/// Which measured states a reset or re-anchoring moved in a step.
#[derive(Debug, Clone, Copy)]
struct Moved {
    baro: bool,
    velocity: bool,
}

/// A reset or re-anchoring moves the measured state so that its innovation is zero (baro: ĥ,
/// m; velocity: V̂_z, m/s); the other states are kept. The states moved (`None`: none), `x`
/// moved in place.
#[inline(always)]
fn moved_states<T: Real>(
    baro: &Option<Verdict<T>>,
    velocity: &Option<Verdict<T>>,
    x: &mut Vector3<T>,
) -> Option<Moved> {
    let moved = |v: &Option<Verdict<T>>| {
        v.filter(|v| {
            matches!(
                v.reacquisition,
                Reacquisition::Reset | Reacquisition::Reanchored
            )
        })
        .map(|v| v.report.innovation)
    };
    let (dh, dv) = (moved(baro), moved(velocity));
    if dh.is_none() && dv.is_none() {
        return None;
    }
    if let Some(d) = dh {
        x.x += d;
    }
    if let Some(d) = dv {
        x.y += d;
    }
    Some(Moved {
        baro: dh.is_some(),
        velocity: dv.is_some(),
    })
}

#[inline(always)]
pub(super) fn report<T: Real>(
    status: super::AidStatus<T>,
    correction: Option<T>,
    verdict: Option<Verdict<T>>,
) -> AidReport<T> {
    AidReport {
        status,
        correction,
        sample: verdict.map(|v| v.report),
        reacquisition: verdict.map_or(Reacquisition::Tracking, |v| v.reacquisition),
    }
}

#[path = "core_setup.rs"]
mod setup;

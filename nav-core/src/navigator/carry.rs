//! Carry-phase evidence the navigator keeps beside the alignment: the IMU's own evidence for
//! a release nobody signalled (module doc of [`super`], "Separation").
//!
//! Without a release signal the navigator may only conclude that the missile has left the
//! wing from what its own IMU measures, and from the bus going silent. A missile hanging on
//! the pylon feels the aircraft's specific force at its station (≈ 1 g up in level flight,
//! the load factor in a turn or a pull-up: the pylon holds it); a missile that has left it
//! feels only its own aerodynamic forces and thrust, so along the carried force it reads
//! less: it *unloads*. Two cues, each with the master timed out:
//!
//! * **Unloading with the master's loss.** The slave's specific force along the last fused
//!   master sample's carried force (lever-arm compensated, in slave axes) falls short of it by
//!   more than the jump threshold on every tick for the window, and that run starts after the
//!   last master's time of validity and at most `unsignalled_onset_s` after it: the umbilical
//!   and the bus go with the release, so the bus's loss and the unloading are one event. A bus
//!   dropout on the wing during a manoeuvre does not look like that: a turn or a pull-up loads
//!   the missile (the force along the carried one grows), and an unloading manoeuvre (a
//!   push-over, a roll-out of a turn) must reach the threshold within the onset bound of the
//!   dropout's start — a jerk above `jump / onset` (10 m/s³ for 3 m/s² in 0.3 s) at the
//!   instant the bus fails.
//! * **Free fall.** `|f_s|` below the jump threshold on every tick for the window: no carried
//!   missile reads that in any manoeuvre an aircraft flies with stores, however long the
//!   master has been silent (a release during a bus dropout).
//!
//! The comparison with the last master's specific force as such (what confirms a *signalled*
//! release) is not usable without the association in time: when the master is lost its last
//! sample is stale, and the aircraft may have manoeuvred since (a 2 s dropout in level carry
//! was enough for that comparison to exceed its threshold in a quarter of the runs with the
//! missile still on the wing).
use crate::math::rotation::exp_so3;
use crate::time::Timestamp;
use crate::Real;
use nalgebra::{Matrix3, Vector3};

/// The last fused master sample's carried specific force, as the unloading cue reads it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CarriedForce<T> {
    /// The master sample's time of validity.
    pub(crate) epoch: Timestamp,
    /// Its lever-arm-compensated specific force in slave axes, m/s².
    pub(crate) f_m_s2: Vector3<T>,
    /// `|f_m_s2|`, m/s².
    pub(crate) norm_m_s2: T,
}

/// The thresholds of the unsignalled cues (the separation check's, module doc of [`super`]).
#[derive(Debug, Clone, Copy)]
pub(crate) struct CueLimits<T> {
    /// Unloading / free-fall threshold, m/s².
    pub(crate) jump_m_s2: T,
    /// Latest start of the unloading after the last master's time of validity, s.
    pub(crate) onset_s: T,
}

/// Which cue declared an unsignalled release.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum ReleaseCue {
    /// The unloading that started with the master's loss.
    Unloading,
    /// Free fall.
    FreeFall,
}

/// Blocks of the dwell window: the slave's specific force is averaged over the last
/// `BLOCKS` blocks of `dwell / BLOCKS` each, so the window slides by a fifth of the dwell.
const BLOCKS: usize = 5;

/// The slave's velocity increment over one block of ticks.
#[derive(Debug, Clone, Copy, PartialEq)]
struct Block<T> {
    /// The block's start (the tick before its first).
    start: Timestamp,
    /// `Σ f_s Δt` over its ticks, m/s (slave axes).
    dv_m_s: Vector3<T>,
}

/// The IMU's running evidence for an unsignalled release: the slave's specific force
/// averaged over a window of the dwell (the last [`BLOCKS`] blocks), so that a vibration at
/// release (the ejector, a clipped 200 Hz burst at 1 kHz) does not break the evidence that an
/// every-tick test would need unbroken; the window's mean is tested at each block's end.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ReleaseEvidence<T> {
    /// A block's length, µs (the dwell's [`BLOCKS`]th, whole µs).
    block_us: u64,
    /// The previous tick (the next interval's start).
    last: Option<Timestamp>,
    /// The block being filled.
    open: Option<Block<T>>,
    /// The last closed blocks, oldest first (`closed` of them valid, the newest at the end).
    blocks: [Block<T>; BLOCKS],
    closed: usize,
    /// The start of the first window whose mean unloads after the last master epoch (kept
    /// after it: after the drop the boost and the pull-out need not unload).
    unloaded_from: Option<Timestamp>,
    /// The latest window's mean was free fall.
    falling: bool,
}

/// `now − since`, s (0 when not later; integer-to-float conversions only, no `f64`).
fn held<T: Real>(now: Timestamp, since: Timestamp) -> T {
    now.micros_since(since)
        .map_or(T::zero(), crate::time::micros_to_seconds)
}

impl<T: Real> ReleaseEvidence<T> {
    /// No evidence; the window is `dwell_s` (s, the separation check's `confirm_window_s`,
    /// validated > 0: whole µs, at least one per block).
    pub(crate) fn new(dwell_s: T) -> Self {
        let blank = Block {
            start: Timestamp::ZERO,
            dv_m_s: Vector3::zeros(),
        };
        let dwell_us = crate::time::seconds_to_micros(dwell_s).unwrap_or(u64::from(u32::MAX));
        Self {
            block_us: (dwell_us / BLOCKS as u64).max(1),
            last: None,
            open: None,
            blocks: [blank; BLOCKS],
            closed: 0,
            unloaded_from: None,
            falling: false,
        }
    }

    /// Records one tick's slave specific force `f_s_m_s2` (m/s², slave axes, the mean over
    /// the interval ending at `time`) against the last master's `carried` force (none before
    /// the first master sample), and returns the cue that holds now, if any (the caller adds
    /// the master's time-out).
    pub(crate) fn update(
        &mut self,
        time: Timestamp,
        f_s_m_s2: &Vector3<T>,
        carried: Option<&CarriedForce<T>>,
        limits: &CueLimits<T>,
    ) -> Option<ReleaseCue> {
        if let Some(last) = self.last {
            let dt = held::<T>(time, last);
            let open = self.open.get_or_insert(Block {
                start: last,
                dv_m_s: Vector3::zeros(),
            });
            open.dv_m_s += f_s_m_s2 * dt;
            if time.micros_since(open.start).unwrap_or(0) >= self.block_us {
                let done = *open;
                self.open = None;
                self.close(done, time, carried, limits);
            }
        }
        self.last = Some(time);
        // With the master's loss: started after its last epoch, within the onset bound.
        let with_loss = match (self.unloaded_from, carried) {
            (Some(from), Some(c)) => from > c.epoch && held::<T>(from, c.epoch) <= limits.onset_s,
            _ => false,
        };
        if with_loss {
            Some(ReleaseCue::Unloading)
        } else if self.falling {
            Some(ReleaseCue::FreeFall)
        } else {
            None
        }
    }

    /// A block closed at `time`: the window of the last [`BLOCKS`] tested.
    fn close(
        &mut self,
        done: Block<T>,
        time: Timestamp,
        carried: Option<&CarriedForce<T>>,
        limits: &CueLimits<T>,
    ) {
        self.blocks.rotate_left(1);
        if let Some(newest) = self.blocks.last_mut() {
            *newest = done;
        }
        self.closed = (self.closed + 1).min(BLOCKS);
        if self.closed < BLOCKS {
            return;
        }
        let start = self.blocks.first().map_or(done.start, |b| b.start);
        let span = held::<T>(time, start);
        if span <= T::zero() {
            return;
        }
        let dv = self
            .blocks
            .iter()
            .fold(Vector3::zeros(), |acc: Vector3<T>, b| acc + b.dv_m_s);
        let f_mean = dv / span;
        let jump = limits.jump_m_s2;
        self.falling = f_mean.norm_squared() < jump * jump;
        // Unloading: |f_c| − f̄_s·f_c/|f_c| > jump, multiplied through by |f_c|.
        // The first such window after the last master epoch is kept (a later one would move
        // the start away from the master's loss while the missile keeps unloading).
        if let Some(c) = carried
            .filter(|c| c.norm_m_s2 * c.norm_m_s2 - f_mean.dot(&c.f_m_s2) > jump * c.norm_m_s2)
        {
            if self.unloaded_from.is_none_or(|from| from <= c.epoch) {
                self.unloaded_from = Some(start);
            }
        }
    }
}

/// What separation is judged against, from the last fused master sample: its
/// lever-arm-compensated specific force turned into slave axes by the alignment's θ̂ after it,
/// formed once (the signalled confirmation, the unsignalled cue and the EKF's start read it).
#[derive(Debug, Clone, Copy)]
pub(super) struct MasterRecord<T> {
    /// The force in slave axes, `exp(−[θ̂×]) f̃_m`, with its time of validity and norm.
    pub(super) carried: CarriedForce<T>,
    /// Its lever-arm-compensated specific force in master axes, m/s² (the bias charge's
    /// reference for the next sample's change).
    pub(super) f_master_m_s2: Vector3<T>,
}

impl<T: Real> MasterRecord<T> {
    /// The record of a sample of time of validity `epoch` with lever-arm-compensated specific
    /// force `f_master_m_s2` (m/s², master axes) and the alignment's θ̂ `theta_rad` after it.
    /// In a frame of its own (not under the master tick's step).
    #[inline(never)]
    pub(super) fn new(
        epoch: Timestamp,
        f_master_m_s2: &Vector3<T>,
        theta_rad: &Vector3<T>,
    ) -> Self {
        let c_m_s: Matrix3<T> = exp_so3(&(-theta_rad));
        let f = c_m_s * f_master_m_s2;
        Self {
            carried: CarriedForce {
                epoch,
                f_m_s2: f,
                norm_m_s2: f.norm(),
            },
            f_master_m_s2: *f_master_m_s2,
        }
    }

    /// The sample's lever-arm-compensated specific force in slave axes, m/s².
    pub(super) fn f_slave_m_s2(&self) -> Vector3<T> {
        self.carried.f_m_s2
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::vec::Vec;

    const G: f64 = 9.81;
    /// The window, s.
    const DWELL_S: f64 = 0.5;

    fn limits() -> CueLimits<f64> {
        CueLimits {
            jump_m_s2: 3.0,
            onset_s: 0.3,
        }
    }

    fn level(epoch_ms: u64) -> CarriedForce<f64> {
        CarriedForce {
            epoch: Timestamp::from_micros(epoch_ms * 1000),
            f_m_s2: Vector3::new(0.0, 0.0, -G),
            norm_m_s2: G,
        }
    }

    /// The smooth ramp's rate per unit change and duration, `30 u² (1 − u)²` (the mission's).
    fn ramp_rate(u: f64) -> f64 {
        if (0.0..=1.0).contains(&u) {
            30.0 * u * u * (1.0 - u) * (1.0 - u)
        } else {
            0.0
        }
    }

    /// The specific force (body axes, level carry) of the mission's drop `t` s after release:
    /// flight path to −3° in `drop_s` at 180 m/s (the sink accelerates the missile downwards:
    /// it unloads), then the pull-out to level in 3 s and the boost of +20 m/s in 6 s.
    fn drop_and_motor(t: f64, drop_s: f64) -> Vector3<f64> {
        let (v, gamma) = (180.0, 3f64.to_radians());
        let sink = v * gamma / drop_s * ramp_rate(t / drop_s);
        let pull_out = v * gamma / 3.0 * ramp_rate((t - drop_s) / 3.0);
        let boost = 20.0 / 6.0 * ramp_rate((t - drop_s) / 6.0);
        Vector3::new(boost, 0.0, -G + sink - pull_out)
    }

    /// Flies `f(t)` from `t0` to `t1` s at `hz` with the last master epoch at 0; the time of
    /// the first cue.
    fn first_cue(
        hz: f64,
        t1: f64,
        carried: &CarriedForce<f64>,
        f: &dyn Fn(f64) -> Vector3<f64>,
    ) -> Option<(f64, ReleaseCue)> {
        let mut ev = ReleaseEvidence::new(DWELL_S);
        let dt_us = (1e6 / hz).round() as u64;
        (1..)
            .map(|k: u64| k * dt_us)
            .take_while(|us| (*us as f64) * 1e-6 <= t1)
            .find_map(|us| {
                let t = us as f64 * 1e-6;
                ev.update(Timestamp::from_micros(us), &f(t), Some(carried), &limits())
                    .map(|c| (t, c))
            })
    }

    #[test]
    fn the_missions_drop_unloads_at_every_imu_rate() {
        for hz in [100.0, 200.0, 500.0, 1000.0] {
            // The release at 10 ms, the last master epoch at 0.
            let carried = level(0);
            let shifted = |t: f64| drop_and_motor(t - 0.01, 1.0);
            let (t, cue) = first_cue(hz, 10.0, &carried, &shifted).expect("released");
            assert_eq!(cue, ReleaseCue::Unloading, "{hz} Hz");
            // The first window after the master's epoch, 0.5 s long, closes at ≈ 0.5 s.
            assert!((0.5..0.52).contains(&t), "{hz} Hz: {t}");
            // The same with a 25 g, 200 Hz vibration clipped at 20 g on the z axis from 0.3 s
            // to 0.7 s (the stress campaign's burst at release): the means carry through it.
            let shaken = |t: f64| {
                let mut f = shifted(t);
                if (0.3..0.7).contains(&t) {
                    let v = 25.0 * G * (2.0 * core::f64::consts::PI * 200.0 * t).sin();
                    f.z = (f.z + v).clamp(-20.0 * G, 20.0 * G);
                }
                f
            };
            let (t2, _) = first_cue(hz, 10.0, &carried, &shaken).expect("released, shaken");
            assert!((0.5..0.52).contains(&t2), "{hz} Hz: {t2}");
        }
    }

    #[test]
    fn a_short_drop_is_released_and_a_slight_one_missed() {
        // A half-second drop: its velocity deficit (V γ ≈ 9.4 m/s) is in the first window.
        let carried = level(0);
        let cue = first_cue(1000.0, 10.0, &carried, &|t| drop_and_motor(t - 0.01, 0.5));
        assert!(cue.is_some());
        // A release that sinks by less than jump × dwell (1.5 m/s) in every window: missed
        // (the missed-release side of the trade, module doc). 0.8 m/s over 0.4 s here.
        let slight = |t: f64| {
            let sink = if (0.01..0.41).contains(&t) { 2.0 } else { 0.0 };
            Vector3::new(0.0, 0.0, -G + sink)
        };
        assert_eq!(first_cue(1000.0, 10.0, &carried, &slight), None);
    }

    #[test]
    fn loading_manoeuvres_and_late_unloading_are_no_release() {
        let carried = level(0);
        // A 2 g pull-up at the master's loss: loads.
        let pull_up = |_t: f64| Vector3::new(0.0, 0.0, -2.0 * G);
        assert_eq!(first_cue(1000.0, 5.0, &carried, &pull_up), None);
        // A turn at 60° bank entered at the master's loss (body axes: 2 g along −z): loads.
        let turn = |t: f64| Vector3::new(0.0, 0.0, -G * (1.0 + (t / 2.0).min(1.0)));
        assert_eq!(first_cue(1000.0, 5.0, &carried, &turn), None);
        // A push-over to 0.5 g starting 0.6 s after the master's last epoch: unloads, but
        // not with the bus's loss (every window starting within the onset bound, 0.3 s, has
        // a mean unloading below 3 m/s²): no release.
        let push_over = |t: f64| {
            let u = ((t - 0.6) / 0.5).clamp(0.0, 1.0);
            Vector3::new(0.0, 0.0, -G * (1.0 - 0.5 * u))
        };
        assert_eq!(first_cue(1000.0, 5.0, &carried, &push_over), None);
        // A push-over to 0.5 g in 0.2 s at the bus's loss is taken for a release: the rule's
        // false-release case (module doc).
        let early = |t: f64| Vector3::new(0.0, 0.0, -G * (1.0 - 0.5 * (t / 0.2).clamp(0.0, 1.0)));
        assert_eq!(
            first_cue(1000.0, 5.0, &carried, &early).map(|c| c.1),
            Some(ReleaseCue::Unloading)
        );
    }

    #[test]
    fn the_unloading_must_start_after_the_last_master_epoch() {
        let lim = limits();
        let t = |ms: u64| Timestamp::from_micros(ms * 1000);
        let unloaded = Vector3::new(0.0, 0.0, -0.5 * G);
        let one_g = Vector3::new(0.0, 0.0, -G);
        // The master's epoch at 300 ms, the unloading from 0: every window that unloads
        // starts before it or more than 0.3 s after it... until the window from 310 ms.
        let carried = level(300);
        let mut ev = ReleaseEvidence::new(DWELL_S);
        let mut first = None;
        for ms in (0..=2000).step_by(10) {
            let f = if ms < 1000 { unloaded } else { one_g };
            if let Some(c) = ev.update(t(ms), &f, Some(&carried), &lim) {
                first.get_or_insert((ms, c));
            }
        }
        // Windows of 0.5 s every 0.1 s from 0: the one from 400 ms (after the epoch, within
        // the bound) closes at 900 ms.
        assert_eq!(first, Some((900, ReleaseCue::Unloading)));
        // The evidence stays after the unloading…
        assert_eq!(
            ev.update(t(2010), &(one_g * 3.0), Some(&carried), &lim),
            Some(ReleaseCue::Unloading)
        );
        // …until a later master sample (epoch after the window's start) withdraws it: the
        // bus was alive then.
        let later = level(650);
        assert_eq!(ev.update(t(2020), &one_g, Some(&later), &lim), None);
        // Before any master sample: only free fall counts.
        let mut ev = ReleaseEvidence::new(DWELL_S);
        let cues: Vec<_> = (0..=2000)
            .step_by(10)
            .map(|ms| ev.update(t(ms), &unloaded, None, &lim))
            .collect();
        assert!(cues.iter().all(Option::is_none));
    }

    #[test]
    fn free_fall_is_the_windows_mean_near_zero_g() {
        let lim = limits();
        let mut ev = ReleaseEvidence::new(DWELL_S);
        let t = |ms: u64| Timestamp::from_micros(ms * 1000);
        let one_g = Vector3::new(0.0_f64, 0.0, -9.8);
        let falling = Vector3::new(0.3_f64, 0.0, -0.5);
        for ms in (0..=490).step_by(10) {
            let f = if ms <= 100 { one_g } else { falling };
            assert_eq!(ev.update(t(ms), &f, None, &lim), None, "{ms}");
        }
        // The window [0, 500 ms] holds 0.1 s at 1 g and 0.4 s falling: its mean, 2.4 m/s², is
        // below the threshold.
        let mut first = None;
        for ms in (500..=700).step_by(10) {
            if ev.update(t(ms), &falling, None, &lim).is_some() {
                first.get_or_insert(ms);
            }
        }
        assert_eq!(first, Some(500));
        // Back on the wing (1.5 g): the next window's mean is no free fall.
        let mut last = None;
        for ms in (710..=1300).step_by(10) {
            last = ev.update(t(ms), &(one_g * 1.5), None, &lim);
        }
        assert_eq!(last, None);
    }
}

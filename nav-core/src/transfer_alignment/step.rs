//! The per-epoch work of the filters: the time plan, [`TransferAlignment::step`] (predict and
//! fuse the six scalar measurements), [`TransferAlignment::propagate`] (prediction only) and
//! [`TransferAlignment::step_delayed`] (match with the slave history).
use super::covariance::{
    condition, initial_covariance, predict_cov, predict_state, reinit_flexure, set_mount_only,
};
use super::filter::{Ahead, TransferAlignment, Undo};
use super::fusion::{DeferredCheck, Guard, UpdateChecks};
use super::health::Channel;
use super::history::SlaveHistory;
use super::measurement::{all_in_range, check_ranges, measurement, MasterSample, SlaveSample};
use super::model::FlexureModel;
use super::rows::{fuse_rows, not_fused, RowInputs};
use crate::contract::Health;
use crate::math::kalman::FusionReport;
use crate::time::Timestamp;
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector, Vector3};

/// How the filter got from its previous epoch to this one.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum GapOutcome {
    /// The first epoch: the clock started here, nothing predicted.
    Started,
    /// Predicted `predictions` steps (0 when jitter put this sample in the previous one's step).
    Predicted,
    /// The gap was longer than `max_gap_steps`: the flexure states were re-initialised to their
    /// stationary prior (mean 0, stationary covariance, no correlation with θ_m), θ_m was kept
    /// and its variance grown by the flexure's stationary variance (the part of θ that the
    /// filter may have put in θ_m), capped at the initial σ_m² plus that variance. Counted in
    /// [`Health::gaps_reset`].
    FlexureReinitialised,
}

/// What the prediction part of a call did.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Propagation {
    /// Prediction steps run (at most `max_gap_steps`).
    pub predictions: u32,
    /// How the gap was bridged.
    pub gap: GapOutcome,
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport<T> {
    /// Time stamp of the epoch (the slave sample's).
    pub time: Timestamp,
    /// Number of prediction steps done before the update (0 at the first epoch).
    pub predictions: u32,
    /// How the gap from the previous epoch was bridged.
    pub gap: GapOutcome,
    /// One report per scalar update, in the order of [`Channel::ALL`] (dω_X, dω_Y, dω_Z, df_X,
    /// df_Y, df_Z). Every number is finite.
    pub updates: [FusionReport<T>; 6],
}

impl<T: Real> StepReport<T> {
    /// A report slot before its first step (for [`TransferAlignment::step_then`]'s caller):
    /// stamped `time`, nothing predicted, every update a zero `Rejected` placeholder.
    pub fn blank(time: Timestamp) -> Self {
        Self {
            time,
            predictions: 0,
            gap: GapOutcome::Started,
            updates: [not_fused(); 6],
        }
    }
}

impl<T: Copy> StepReport<T> {
    /// The report of one channel's update.
    pub fn update(&self, channel: Channel) -> Option<&FusionReport<T>> {
        self.updates.get(channel.index())
    }
}

/// The time plan of one call: predictions to run and the new grid time.
#[derive(Debug, Clone, Copy)]
struct Plan {
    predictions: u32,
    gap: GapOutcome,
    grid: Timestamp,
}

/// `0` when every component is finite, NaN otherwise (`v·0` is ±0 for finite v and NaN for
/// ±∞ or NaN): a finiteness test that costs one multiply-add per value on the target.
#[inline(always)]
fn zero_if_finite<T: Real>(v: &Vector3<T>) -> T {
    v.x * T::zero() + v.y * T::zero() + v.z * T::zero()
}

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// (current, scratch) covariance buffers.
    fn buffers(&mut self) -> (&SMatrix<T, N, N>, &mut SMatrix<T, N, N>) {
        let [a, b] = &mut self.p;
        if self.second {
            (&*b, a)
        } else {
            (&*a, b)
        }
    }

    /// One prediction on (x, P) in place (tests): P full and symmetric in and out (the
    /// prediction reads and writes its upper triangle).
    #[cfg(test)]
    pub(super) fn predict_into(&self, x: &mut SVector<T, N>, p: &mut SMatrix<T, N, N>) {
        predict_state(&self.phi, x);
        predict_cov(&self.phi, &self.q_d, None, p);
        *p = super::covariance::symmetric_from_upper(p);
    }

    /// Runs the time plan from the current covariance into the scratch buffer: `n`
    /// predictions, a copy (n = 0), or the flexure re-initialisation of a long gap.
    #[inline(never)] // one copy serves `step` and `propagate`
    fn advance_to_scratch(&mut self, x: &mut SVector<T, N>, plan: &Plan) {
        // Borrow the fields separately: no copy of the matrices.
        let Self {
            chains,
            phi,
            q_d,
            p,
            second,
            ahead,
            ..
        } = self;
        // Whatever the plan, the prepared prediction is used up (or overwritten) here.
        let ahead = ahead.take();
        let [a, b] = p;
        let (cur, scratch) = if *second { (&*b, a) } else { (&*a, b) };
        if plan.gap == GapOutcome::FlexureReinitialised {
            scratch.copy_from(cur);
            reinit_flexure(chains, x, scratch);
            return;
        }
        if plan.predictions == 0 {
            scratch.copy_from(cur);
            return;
        }
        // The first predictions: done ahead (`predict_ahead`: their covariance is in the
        // scratch buffer already) unless more than the plan has, or now.
        let done = match ahead {
            Some(a) if a.steps <= plan.predictions => {
                *x = a.x;
                a.steps
            }
            _ => {
                predict_state(phi, x);
                predict_cov(phi, q_d, Some(cur), scratch);
                1
            }
        };
        for _ in done..plan.predictions {
            predict_state(phi, x);
            predict_cov(phi, q_d, None, scratch);
        }
    }

    /// Runs one more prediction of the next epoch now, into the scratch buffer, so that the
    /// next [`Self::step`] or [`Self::propagate`] has one prediction less to do (ticks
    /// without master data carry them, the tick of the master sample does not). The estimate
    /// is unchanged: state, covariance, time, health and every accessor read the current
    /// epoch. The next call whose time plan has at least as many predictions continues from
    /// them with bit-identical results; a plan with fewer (a sample in the same step, a gap
    /// reset), [`crate::contract::Estimator::reinitialise`] or a step undone by
    /// [`Self::step_then`] discards them (the call then predicts from the current epoch, as
    /// without them). Returns `false` (nothing done) before the first epoch or when
    /// `max_gap_steps` predictions are prepared.
    #[inline(never)]
    pub fn predict_ahead(&mut self) -> bool {
        let done = self.steps_ahead();
        if self.grid.is_none() || done >= self.cfg.max_gap_steps {
            return false;
        }
        let Self {
            phi,
            q_d,
            p,
            second,
            x,
            ahead,
            ..
        } = self;
        let [a, b] = p;
        let (cur, scratch) = if *second { (&*b, a) } else { (&*a, b) };
        let (mut xa, src) = match ahead {
            Some(a) => (a.x, None),
            None => (*x, Some(cur)),
        };
        predict_state(phi, &mut xa);
        predict_cov(phi, q_d, src, scratch);
        *ahead = Some(Ahead {
            x: xa,
            steps: done + 1,
        });
        true
    }

    /// Predictions prepared by [`Self::predict_ahead`] for the next epoch (0: none).
    pub fn steps_ahead(&self) -> u32 {
        self.ahead.map_or(0, |a| a.steps)
    }

    /// [`Self::step`], then `then` on the stepped filter; when `then` fails the step is undone
    /// (the estimate, its covariance, time and every counter as before the call — the step
    /// wrote the other covariance buffer only, so nothing larger than the state is saved, and
    /// that in the filter's own undo record, not on the stack) and its error returned. For a
    /// caller whose own commit depends on the updated estimate (the navigator's hand-over),
    /// without a copy of the filter. The step's report is written into `report` (the caller's
    /// slot, not returned by value): untouched when the step refuses the sample, written when
    /// it ran (also when `then` then fails and the step is undone). Errors: those of
    /// [`Self::step`] (nothing changed), then those of `then` (step undone).
    pub fn step_then<R>(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
        report: &mut StepReport<T>,
        then: impl FnOnce(&Self) -> Result<R, NavError>,
    ) -> Result<R, NavError> {
        self.undo = Undo {
            x: self.x,
            grid: self.grid,
            last: self.last,
            monitor: self.monitor,
            second: self.second,
        };
        let plan = match self.try_step_into(master, slave, &mut report.updates, Guard::Deferred) {
            Ok(plan) => plan,
            Err(e) => {
                Health::bump(&mut self.monitor.health.imu_refused);
                return Err(e);
            }
        };
        report.time = slave.time;
        report.predictions = plan.predictions;
        report.gap = plan.gap;
        match then(self) {
            Ok(r) => Ok(r),
            Err(e) => {
                let Self {
                    undo,
                    x,
                    grid,
                    last,
                    monitor,
                    second,
                    ahead,
                    ..
                } = self;
                *x = undo.x;
                *grid = undo.grid;
                *last = undo.last;
                *monitor = undo.monitor;
                *second = undo.second;
                *ahead = None;
                Err(e)
            }
        }
    }

    /// The time plan to a sample stamped `time`: the filter predicts
    /// `round((time − grid) / dt)` steps (possibly 0 when jitter puts two samples in one step),
    /// so the grid never drifts from the flight computer's clock; a gap of more than
    /// `max_gap_steps` re-initialises the flexure instead. `TimeNotIncreasing` unless later
    /// than the last accepted sample.
    fn plan(&self, time: Timestamp) -> Result<Plan, NavError> {
        let (Some(grid), Some(last)) = (self.grid, self.last) else {
            return Ok(Plan {
                predictions: 0,
                gap: GapOutcome::Started,
                grid: time,
            });
        };
        if time <= last {
            return Err(NavError::TimeNotIncreasing);
        }
        // time > last ≥ grid − dt/2, so `ahead` > 0.
        let ahead = time
            .add_micros(self.dt_us / 2)
            .micros_since(grid)
            .unwrap_or(0);
        // A gap below 2³² µs (71 min) divides in 32 bits (a single instruction on the target;
        // the 64-bit division is a library call): the same quotient, and the grid's advance
        // `steps · dt_us` is one 32 × 32 → 64-bit multiply, which cannot overflow: the value of
        // the saturating 64-bit product.
        let (steps, advance) = match (u32::try_from(ahead), u32::try_from(self.dt_us)) {
            (Ok(a), Ok(dt_us)) => {
                let n = a / dt_us.max(1);
                (u64::from(n), u64::from(n) * u64::from(dt_us))
            }
            _ => {
                let n = ahead / self.dt_us.max(1);
                (n, n.saturating_mul(self.dt_us))
            }
        };
        let grid = grid.add_micros(advance);
        match u32::try_from(steps) {
            Ok(n) if n <= self.cfg.max_gap_steps => Ok(Plan {
                predictions: n,
                gap: GapOutcome::Predicted,
                grid,
            }),
            _ => Ok(Plan {
                predictions: 0,
                gap: GapOutcome::FlexureReinitialised,
                grid,
            }),
        }
    }

    /// Processes one epoch: checks the inputs and time stamps, predicts from the previous epoch
    /// to the grid point nearest the slave's time stamp (none at the first epoch, the flexure
    /// re-initialised after a gap longer than `max_gap_steps`), then fuses the six scalar
    /// measurements (the sparse form of [`fuse_scalar`](crate::math::kalman::fuse_scalar)) with the configured gate.
    ///
    /// Refused (`Err`, the estimate unchanged bit for bit, the refusal counted in
    /// [`Health::imu_refused`]) only for invalid input: `NonFiniteInput`, `InputOutOfRange`
    /// (an input beyond the `MAX_*` limits), `TimeNotIncreasing` (the slave's stamp not later
    /// than the last accepted sample's), and `MeasurementTimeOutOfWindow` (master and slave
    /// stamps differ by more than the tolerance; match delayed master data with a
    /// [`SlaveHistory`]). Any later time stamp is accepted.
    ///
    /// A measurement rejected by the χ² gate is reported (`Rejected`) and counted in
    /// [`Self::aid_counters`]; see "Recovery" ([`TransferAlignment`]) for what happens when a
    /// channel is starved. A measurement that cannot be fused numerically is reported
    /// `Skipped` and counted; the step still commits its prediction and the other updates.
    pub fn step(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
    ) -> Result<StepReport<T>, NavError> {
        self.step_guarded(master, slave, Guard::Deferred)
    }

    /// [`Self::step`] starting with the checks `first` (tests: [`Guard::PerUpdate`] is the
    /// reference the deferred checks must reproduce bit for bit).
    #[inline(always)]
    pub(super) fn step_guarded(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
        first: Guard,
    ) -> Result<StepReport<T>, NavError> {
        let mut updates = [not_fused(); 6];
        match self.try_step_into(master, slave, &mut updates, first) {
            Ok(plan) => Ok(StepReport {
                time: slave.time,
                predictions: plan.predictions,
                gap: plan.gap,
                updates,
            }),
            Err(e) => {
                Health::bump(&mut self.monitor.health.imu_refused);
                Err(e)
            }
        }
    }

    /// Checks of [`Self::step`] that need no prediction: the plan, or the refusal.
    fn check_epoch(
        &self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
    ) -> Result<Plan, NavError> {
        // Fast path: one test that all 15 inputs are within their ranges (and so finite); the
        // per-field checks (which name the offending input, a non-finite one first) only run
        // when some input is not.
        if !all_in_range(master, slave) {
            master.validate()?;
            slave.validate()?;
            check_ranges(master, slave)?;
        }
        let skew = master
            .time
            .micros_since(slave.time)
            .or_else(|| slave.time.micros_since(master.time))
            .unwrap_or(u64::MAX);
        if skew > self.tol_us {
            return Err(NavError::MeasurementTimeOutOfWindow);
        }
        self.plan(slave.time)
    }

    /// [`Self::step`]'s work: the six reports written into `updates` (the caller's slot);
    /// returns the time plan it ran. Refused: `updates` untouched, nothing changed.
    #[inline(always)]
    fn try_step_into(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
        updates: &mut [FusionReport<T>; 6],
        first: Guard,
    ) -> Result<Plan, NavError> {
        let plan = self.check_epoch(master, slave)?;
        let matching = measurement(master, slave, &self.cfg.lever_arm_m);
        let (z, f_comp) = (matching.z, matching.master_force_compensated_m_s2);
        let z_probe = z
            .as_slice()
            .iter()
            .fold(zero_if_finite(&f_comp), |acc, v| acc + *v * T::zero());
        if z_probe != T::zero() {
            return Err(NavError::InputOutOfRange {
                input: "measurement",
            });
        }
        let f_h = match self.model {
            FlexureModel::Conventional => f_comp,
            FlexureModel::Proposed => slave.specific_force_m_s2,
        };
        let mut inputs = RowInputs {
            omega_m: master.angular_rate_rad_s,
            omega_dot_m: master.angular_accel_rad_s2,
            f_h,
            lever_arm_m: self.cfg.lever_arm_m,
            r_rate: self.r_rate,
            r_accel: self.r_accel,
            checks: UpdateChecks {
                gate: self.cfg.gate,
                guard: first,
            },
        };
        // With `Guard::Deferred` the updates' results are checked once, at the end
        // (`DeferredCheck`); when that check fails (an update the per-update checks would have
        // refused), the epoch runs again from the current epoch's state with every update
        // checked before it writes (`Guard::PerUpdate`): either way the bits of the
        // per-update checks alone. The prediction runs again too, from the current covariance
        // (the same bits as the predictions prepared ahead, which the first run used up).
        let mut x = self.x;
        loop {
            self.advance_to_scratch(&mut x, &plan);
            let (_, p) = self.buffers();
            let check = DeferredCheck::start(p);
            fuse_rows::<T, K, N>(&mut x, p, &z, &inputs, updates);
            if inputs.checks.guard == Guard::PerUpdate || check.passes(&x, p) {
                break;
            }
            x = self.x;
            inputs.checks.guard = Guard::PerUpdate;
            #[cfg(test)]
            {
                self.reruns += 1;
            }
        }
        self.commit_epoch(x, &plan, updates);
        self.last = Some(slave.time);
        Ok(plan)
    }

    /// Commits an epoch's updates: counters, recovery, conditioning, state, buffer swap, grid
    /// (nothing here can fail: the counters are updated in place).
    fn commit_epoch(&mut self, mut x: SVector<T, N>, plan: &Plan, updates: &[FusionReport<T>; 6]) {
        let count = self.monitor.record_updates(updates, self.starved_epochs);
        let mut anomaly = count.skipped || plan.gap == GapOutcome::FlexureReinitialised;
        Self::count_gap(&mut self.monitor.health, plan);
        if let (true, Some(n)) = (count.starved, self.starved_epochs) {
            anomaly = true;
            self.recover(&mut x, n);
        }
        self.monitor.end_epoch(anomaly, Self::diverged(&x));
        self.finish(x, plan);
    }

    /// The recovery of a starved channel ([`TransferAlignment`], "Recovery"): the scratch
    /// covariance ← P0, the flexure states ← 0, θ_m kept; counted per starved channel.
    #[cold]
    #[inline(never)]
    fn recover(&mut self, x: &mut SVector<T, N>, starved_epochs: u32) {
        self.monitor.record_recovery(starved_epochs);
        let p0 = initial_covariance::<T, K, N>(&self.chains);
        let (_, p) = self.buffers();
        *p = p0;
        let mount = core::array::from_fn::<T, 3, _>(|a| {
            x.get(K * a).copied().unwrap_or_else(T::zero)
                - x.get(K * a + 1).copied().unwrap_or_else(T::zero)
        });
        set_mount_only::<T, K, N>(x, &mount);
    }

    /// Conditions the scratch covariance and makes it current with `x` and the grid.
    fn finish(&mut self, x: SVector<T, N>, plan: &Plan) {
        // The fields borrowed apart: the scratch buffer ([`Self::buffers`]) and the ceilings
        // read in place (no copy of the ceilings).
        let Self {
            p,
            second,
            ceiling,
            monitor,
            ..
        } = self;
        let [a, b] = p;
        let scratch = if *second { a } else { b };
        if condition(scratch, ceiling) {
            Health::bump(&mut monitor.health.limits_hit);
        }
        self.x = x;
        self.second = !self.second;
        self.grid = Some(plan.grid);
        self.ahead = None;
    }

    /// Counts a bridged gap (more than one prediction) or a reset one.
    fn count_gap(health: &mut Health, plan: &Plan) {
        if plan.gap == GapOutcome::FlexureReinitialised {
            Health::bump(&mut health.gaps_reset);
        } else if plan.predictions > 1 {
            Health::bump(&mut health.gaps_bridged);
        }
    }

    /// Prediction only, to the grid point nearest `time`: how a firmware loop keeps the
    /// filter running through a master-data dropout (call it at each slave epoch without
    /// master data). Before the first epoch it starts the clock (nothing predicted). A gap
    /// longer than `max_gap_steps` re-initialises the flexure as in [`Self::step`]. Errors:
    /// `TimeNotIncreasing` (the estimate unchanged, counted in [`Health::imu_refused`]).
    pub fn propagate(&mut self, time: Timestamp) -> Result<Propagation, NavError> {
        let plan = match self.plan(time) {
            Ok(plan) => plan,
            Err(e) => {
                Health::bump(&mut self.monitor.health.imu_refused);
                return Err(e);
            }
        };
        let mut x = self.x;
        self.advance_to_scratch(&mut x, &plan);
        Self::count_gap(&mut self.monitor.health, &plan);
        let reset = plan.gap == GapOutcome::FlexureReinitialised;
        self.monitor.end_prediction(reset, Self::diverged(&x));
        self.finish(x, &plan);
        self.last = Some(time);
        Ok(Propagation {
            predictions: plan.predictions,
            gap: plan.gap,
        })
    }

    /// Matches time-tagged (possibly delayed) master data with the slave sample of the same
    /// epoch in `history` and runs [`Self::step`] on the pair. Errors: those of
    /// [`SlaveHistory::find`] and of [`Self::step`]; on error the estimate is unchanged (the
    /// refusal is counted in [`Health::imu_refused`]).
    pub fn step_delayed<const H: usize>(
        &mut self,
        master: &MasterSample<T>,
        history: &SlaveHistory<T, H>,
    ) -> Result<StepReport<T>, NavError> {
        match history.find(master.time, self.tol_us) {
            Ok(slave) => self.step(master, &slave),
            Err(e) => {
                Health::bump(&mut self.monitor.health.imu_refused);
                Err(e)
            }
        }
    }
}

#[cfg(test)]
mod tests;

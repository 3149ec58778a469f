//! The transfer-alignment filter value: construction from a design ([`Estimator`]), the
//! run-time setters, and what a flight program reads (θ, σ, state, covariance, health).
//! The per-epoch work is in `step.rs`.
use super::config::{validate_gate, validate_recovery, TaConfig, MAX_MISALIGNMENT_RAD};
use super::covariance::{
    ceilings, initial_covariance, set_mount_only, symmetric_from_upper, to_total_cov, to_total_phi,
    upper_at,
};
use super::design::TaDesign;
use super::health::{Channel, Monitor};
use super::model::{
    axis_index, has_accel_bias, spec_index, to_spec_order, AxisChain, FlexureModel, BIAS_STATE,
};
use crate::contract::{AidCounters, Estimator, Gate, Health, RecoveryPolicy};
use crate::math::rotation::exp_so3;
use crate::time::Timestamp;
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// What a coarse alignment hands over to the transfer alignment: its estimate of the mounting
/// misalignment θ_m (rad, per axis, default zero: no prior knowledge beyond the nominal
/// mounting). Its 1σ is the configuration's `mount_sigma_rad`; the flexure starts at its
/// stationary prior (mean zero). Each component within ±[`MAX_MISALIGNMENT_RAD`].
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaInitial<T> {
    /// Initial estimate of the mounting misalignment θ_m (slave relative to master, the
    /// spec's sign: `C_m^s ≈ I − [θ×]`), rad.
    pub mount_misalignment_rad: Vector3<T>,
}

impl<T: Real> Default for TaInitial<T> {
    /// No prior knowledge: θ_m = 0.
    fn default() -> Self {
        Self {
            mount_misalignment_rad: Vector3::zeros(),
        }
    }
}

impl<T: Real> TaInitial<T> {
    /// `NonFiniteInput` / `InputOutOfRange { input: "initial.mount_misalignment_rad" }` unless
    /// every component is finite and within ±[`MAX_MISALIGNMENT_RAD`].
    pub fn validate(&self) -> Result<(), NavError> {
        const INPUT: &str = "initial.mount_misalignment_rad";
        let v = &self.mount_misalignment_rad;
        if !v.iter().all(|c| c.is_finite()) {
            return Err(NavError::NonFiniteInput { input: INPUT });
        }
        if !v.iter().all(|c| c.abs() <= T::lit(MAX_MISALIGNMENT_RAD)) {
            return Err(NavError::InputOutOfRange { input: INPUT });
        }
        Ok(())
    }
}

/// Transfer-alignment filter with `K` states per axis chain and `N = 3 K` states.
/// Use [`ConventionalFilter`] (K = 3) or [`ProposedFilter`] (K = 4); construct it through
/// [`Estimator`] (`new`, or `design` on the ground and `from_design` on board).
///
/// # Recovery
///
/// When one channel ([`Channel`]) has been rejected by the gate for
/// `recovery.starved_after_s` — counted in epochs of `dt_s`, `⌈starved_after_s / dt_s⌉`
/// consecutive rejected epochs (the default 0.5 s is 50 epochs at 100 Hz) — the filter
/// concludes that its covariance is too small for what it sees (a fault it did not model, or
/// a transient that left it overconfident) and applies the only supported action,
/// [`RecoveryAction::ResetToPrior`](crate::RecoveryAction::ResetToPrior): P ← P0 (σ_m² on
/// θ_m, the stationary flexure covariance), the flexure states back to their prior mean 0,
/// θ_m keeps its estimate. Counted in [`AidCounters::recoveries`] of each starved channel.
///
/// The covariance is double-buffered: a step predicts from the current buffer into the other
/// one, fuses there, and only then makes it current, so an error leaves the filter untouched
/// without copying P. The `Debug` output shows the state (current buffer only).
///
/// The scratch buffer also carries a prediction run ahead of the next epoch
/// ([`Self::predict_ahead`]): a tick without master data can do the first prediction of the
/// next step, which then continues from it (bit-identical results).
#[derive(Clone)]
pub struct TransferAlignment<T: Real, const K: usize, const N: usize> {
    pub(super) cfg: TaConfig<T>,
    pub(super) model: FlexureModel,
    /// The design (θ_m parametrisation, as computed by [`TaDesign`]).
    pub(super) chains: [AxisChain<T, K>; 3],
    /// Per-axis transition in the filter's θ parametrisation (first column e₁).
    pub(super) phi: [SMatrix<T, K, K>; 3],
    /// Per-axis discrete process noise in the θ parametrisation.
    pub(super) q_d: [SMatrix<T, K, K>; 3],
    /// Variance ceilings, axis-major (see `covariance::condition`).
    pub(super) ceiling: SVector<T, N>,
    /// State, axis-major, θ parametrisation.
    pub(super) x: SVector<T, N>,
    /// Covariance, axis-major, stored as its upper triangle (the lower triangle is not kept
    /// up to date: read through `covariance::upper_at`): `p[second]` is current, the other
    /// one scratch.
    pub(super) p: [SMatrix<T, N, N>; 2],
    pub(super) second: bool,
    pub(super) r_rate: T,
    pub(super) r_accel: T,
    pub(super) dt_us: u64,
    pub(super) tol_us: u64,
    /// Consecutive rejected epochs that starve a channel (`None`: no recovery).
    pub(super) starved_epochs: Option<u32>,
    /// Time of the state (the prediction grid), once started.
    pub(super) grid: Option<Timestamp>,
    /// Time stamp of the last accepted sample.
    pub(super) last: Option<Timestamp>,
    pub(super) monitor: Monitor,
    /// Predictions run from the current epoch ahead of the next one, their covariance in the
    /// scratch buffer ([`Self::predict_ahead`]); `None`: nothing prepared.
    pub(super) ahead: Option<Ahead<T, N>>,
    /// What [`TransferAlignment::step_then`] restores when its continuation fails (kept in the
    /// filter, not on the stack: the step's frame is the deepest of a master tick). Read only
    /// there, between the step and its continuation.
    pub(super) undo: Undo<T, N>,
    /// Epochs whose deferred checks failed and that ran again (tests).
    #[cfg(test)]
    pub(super) reruns: u32,
}

/// The part of the filter a step changes besides the scratch covariance buffer: the state,
/// clock, counters and which buffer is current ([`TransferAlignment::step_then`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Undo<T: Real, const N: usize> {
    pub(super) x: SVector<T, N>,
    pub(super) grid: Option<Timestamp>,
    pub(super) last: Option<Timestamp>,
    pub(super) monitor: Monitor,
    pub(super) second: bool,
}

/// Predictions run ahead of the next epoch ([`TransferAlignment::predict_ahead`]).
#[derive(Debug, Clone, Copy)]
pub(super) struct Ahead<T: Real, const N: usize> {
    /// The state after `steps` predictions from the current epoch.
    pub(super) x: SVector<T, N>,
    /// Predictions run (≥ 1).
    pub(super) steps: u32,
}

impl<T: Real, const K: usize, const N: usize> core::fmt::Debug for TransferAlignment<T, K, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TransferAlignment")
            .field("cfg", &self.cfg)
            .field("model", &self.model)
            .field("chains", &self.chains)
            .field("phi", &self.phi)
            .field("q_d", &self.q_d)
            .field("ceiling", &self.ceiling)
            .field("x", &self.x)
            .field("p", &symmetric_from_upper(self.p_cur()))
            .field("r_rate", &self.r_rate)
            .field("r_accel", &self.r_accel)
            .field("dt_us", &self.dt_us)
            .field("tol_us", &self.tol_us)
            .field("starved_epochs", &self.starved_epochs)
            .field("grid", &self.grid)
            .field("last", &self.last)
            .field("monitor", &self.monitor)
            .finish()
    }
}

/// The conventional 9-state filter (2nd-order Markov flexure, seed eq. 5).
pub type ConventionalFilter<T> = TransferAlignment<T, 3, 9>;
/// The proposed 12-state filter (3rd-order Markov flexure with θ̈_f, seed eqs. 12-14).
pub type ProposedFilter<T> = TransferAlignment<T, 4, 12>;
/// The flight configuration: the proposed filter with the random-constant bias of each axis'
/// specific-force difference as 13th-15th states (chains `[θ, θ_f, θ̇_f, θ̈_f, b]`; the bias
/// enters df with H entry 1, its prior 1σ is the configuration's `accel_bias_sigma_m_s2`).
/// Its covariance accounts for the accelerometer-bias floor (≈ b/g on θ_X, θ_Y) that the
/// paper's filters cannot see; see the README, "Flight configuration".
pub type FlightFilter<T> = TransferAlignment<T, 5, 15>;

impl<T: Real, const K: usize, const N: usize> Estimator for TransferAlignment<T, K, N> {
    type Config = TaConfig<T>;
    type Design = TaDesign<T, K>;
    type Initial = TaInitial<T>;

    /// Validates the configuration and discretises the per-axis chains at `dt_s`
    /// ([`TaDesign`]). Errors: `InvalidConfig` naming the field, or for a chain length other
    /// than 3, 4 or 5.
    fn design(config: &TaConfig<T>) -> Result<TaDesign<T, K>, NavError> {
        TaDesign::compute(config)
    }

    /// Builds the filter from a stored design without running the discretisation; starts from
    /// θ_m = `initial.mount_misalignment_rad`, the flexure at 0, P = blockdiag(P0_X, P0_Y,
    /// P0_Z) (transformed to the filter's θ parametrisation).
    ///
    /// Checks (cheap): the configuration ([`TaConfig::validate`]), the design's stamp
    /// (`InvalidConfig { field: "design", issue: DesignMismatch }` for a design computed for
    /// another flexure, mount σ or `dt_s`), every Φ, Q_d, P0 value finite (`InvalidConfig {
    /// field: "flexure" }`), the design's structure (`InvalidConfig { field: "design.q_d" |
    /// "design.p0" | "design.phi" }`), then the initial state ([`TaInitial::validate`]).
    // Runs once per flight, or after a failure: cold and out of line, so that the caller's
    // hot path does not carry an inlined copy.
    #[cold]
    #[inline(never)]
    fn from_design(
        config: &TaConfig<T>,
        design: &TaDesign<T, K>,
        initial: &TaInitial<T>,
    ) -> Result<Self, NavError> {
        let model = FlexureModel::for_dims::<K, N>()?;
        let derived = config.derived()?;
        design.check(config)?;
        initial.validate()?;
        let chains = design.chains;
        let p = initial_covariance::<T, K, N>(&chains);
        let mut x = SVector::<T, N>::zeros();
        let m = &initial.mount_misalignment_rad;
        set_mount_only::<T, K, N>(&mut x, &[m.x, m.y, m.z]);
        Ok(Self {
            cfg: *config,
            model,
            chains,
            phi: chains.each_ref().map(|ch| to_total_phi(&ch.phi)),
            q_d: chains.each_ref().map(|ch| to_total_cov(&ch.q_d)),
            ceiling: ceilings::<T, K, N>(&chains),
            x,
            p: [p, p],
            second: false,
            r_rate: derived.r_rate,
            r_accel: derived.r_accel,
            dt_us: derived.dt_us,
            tol_us: derived.tol_us,
            starved_epochs: derived.starved_epochs,
            grid: None,
            last: None,
            monitor: Monitor::new(),
            ahead: None,
            undo: Undo {
                x,
                grid: None,
                last: None,
                monitor: Monitor::new(),
                second: false,
            },
            #[cfg(test)]
            reruns: 0,
        })
    }

    /// The documented way back from [`crate::HealthState::NeedsReinitialisation`] (or any
    /// time, e.g. after a new coarse alignment): restarts from `initial` as
    /// [`Estimator::from_design`] does (θ_m = `initial.mount_misalignment_rad`, flexure 0,
    /// P = P0), keeping the configuration, the design, the clock (time stamps must still
    /// increase) and the totals of the counters; ends every run of rejections and skips,
    /// counts [`Health::reinitialisations`], and reports `Degraded` for
    /// [`super::DEGRADED_HOLD_EPOCHS`] epochs (still `Initialising` before the first sample).
    /// To keep the current mounting estimate, pass `TaInitial { mount_misalignment_rad:
    /// filter.theta_m() }`. Errors (nothing changed): those of [`TaInitial::validate`].
    // Runs once per flight, or after a failure: cold and out of line, so that the caller's
    // hot path does not carry an inlined copy.
    #[cold]
    #[inline(never)]
    fn reinitialise(&mut self, initial: &TaInitial<T>) -> Result<(), NavError> {
        initial.validate()?;
        let m = &initial.mount_misalignment_rad;
        set_mount_only::<T, K, N>(&mut self.x, &[m.x, m.y, m.z]);
        let p = initial_covariance::<T, K, N>(&self.chains);
        self.p = [p, p];
        self.ahead = None;
        let mon = &mut self.monitor;
        Health::bump(&mut mon.health.reinitialisations);
        for c in mon.channels.iter_mut() {
            c.consecutive_rejected = 0;
        }
        mon.all_skipped_run = 0;
        mon.end_prediction(true, false);
        Ok(())
    }

    /// Health state and counters: `gaps_bridged` counts calls that predicted more than one
    /// step, `gaps_reset` gaps longer than `max_gap_steps` (flexure re-initialised),
    /// `limits_hit` committed covariances with a variance held at its ceiling,
    /// `reinitialisations` calls of `reinitialise`, `imu_refused` refused sample pairs
    /// (`step`, `step_delayed`) and time stamps (`propagate`). The state is `Initialising`
    /// until the first epoch; `Degraded` for [`super::DEGRADED_HOLD_EPOCHS`] epochs after a
    /// skipped update, a long gap, a recovery or a re-initialisation; `NeedsReinitialisation`
    /// when every update has been skipped for [`super::SKIPPED_EPOCHS_FOR_REINIT`] epochs or
    /// |θ| left the small-angle range ([`MAX_MISALIGNMENT_RAD`]) — steps still run, and
    /// `reinitialise` is the way back; `Nominal` otherwise.
    fn health(&self) -> Health {
        self.monitor.health
    }

    /// Time stamp of the last accepted sample (`None` before the first).
    fn time(&self) -> Option<Timestamp> {
        self.last
    }
}

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// Counters of one measurement channel. `refused` stays 0: a refused sample pair is
    /// counted once, in [`Health::imu_refused`]. A skipped update ends the channel's run of
    /// rejections (`consecutive_rejected`), as a fused one does.
    pub fn aid_counters(&self, channel: Channel) -> AidCounters {
        self.monitor
            .channels
            .get(channel.index())
            .copied()
            .unwrap_or_default()
    }

    /// Sets the χ² gate of every update; validated as the configuration's `gate`
    /// (`InvalidConfig { field: "gate" }`, nothing changed).
    pub fn set_gate(&mut self, gate: Gate<T>) -> Result<(), NavError> {
        validate_gate(&gate)?;
        self.cfg.gate = gate;
        Ok(())
    }

    /// Sets the recovery policy (see "Recovery" above); validated as the configuration's
    /// `recovery` (`InvalidConfig { field: "recovery.starved_after_s" | "recovery.action" }`,
    /// nothing changed). The current runs of rejections are kept.
    pub fn set_recovery(&mut self, policy: RecoveryPolicy<T>) -> Result<(), NavError> {
        self.starved_epochs = validate_recovery(&policy, self.dt_us)?;
        self.cfg.recovery = policy;
        Ok(())
    }

    /// The configuration in force (with the gate and recovery policy last set).
    pub fn config(&self) -> &TaConfig<T> {
        &self.cfg
    }

    /// Which model this filter runs.
    pub fn model(&self) -> FlexureModel {
        self.model
    }

    /// Per-axis discrete chains of the design (Φ_j, Q_d,j, P0_j in the θ_m parametrisation).
    pub fn chains(&self) -> &[AxisChain<T, K>; 3] {
        &self.chains
    }

    /// Time of the state on the filter's prediction grid (within dt/2 of
    /// [`Estimator::time`]).
    pub fn grid_time(&self) -> Option<Timestamp> {
        self.grid
    }

    /// The filter step in whole µs.
    pub fn dt_us(&self) -> u64 {
        self.dt_us
    }

    /// The current covariance, stored as its upper triangle (column-major `p[col][row]`,
    /// rows `0..=col`; the lower triangle is not kept): read it through `upper_at`.
    pub(super) fn p_cur(&self) -> &SMatrix<T, N, N> {
        let [a, b] = &self.p;
        if self.second {
            b
        } else {
            a
        }
    }

    fn block(&self, d: usize) -> Vector3<T> {
        let g = |a: usize| {
            self.x
                .get(axis_index::<K>(d, a))
                .copied()
                .unwrap_or_else(T::zero)
        };
        Vector3::new(g(0), g(1), g(2))
    }

    /// Estimated mounting misalignment θ_m = θ − θ_f, rad.
    pub fn theta_m(&self) -> Vector3<T> {
        self.block(0) - self.block(1)
    }

    /// Estimated flexure angle θ_f, rad.
    pub fn theta_f(&self) -> Vector3<T> {
        self.block(1)
    }

    /// Estimated flexure rate θ̇_f, rad/s.
    pub fn theta_f_rate(&self) -> Vector3<T> {
        self.block(2)
    }

    /// Estimated flexure angular acceleration θ̈_f, rad/s² (`None` for the conventional filter,
    /// which has no such state).
    pub fn theta_f_accel(&self) -> Option<Vector3<T>> {
        (K >= 4).then(|| self.block(3))
    }

    /// Estimated bias of the specific-force difference per axis (master minus slave
    /// accelerometer bias), m/s², and its 1σ (`None` unless the filter is the flight
    /// configuration, [`FlightFilter`]).
    pub fn accel_bias(&self) -> Option<(Vector3<T>, Vector3<T>)> {
        has_accel_bias::<K>().then(|| {
            let sigma = Vector3::from_fn(|a, _| {
                let i = K * a + BIAS_STATE;
                self.p_at(i, i).max(T::zero()).sqrt()
            });
            (self.block(BIAS_STATE), sigma)
        })
    }

    /// Estimated total misalignment θ = θ_m + θ_f, rad (a state of the filter).
    pub fn theta(&self) -> Vector3<T> {
        self.block(0)
    }

    fn p_at(&self, r: usize, c: usize) -> T {
        upper_at(self.p_cur(), r, c)
    }

    /// Covariance of θ = θ_m + θ_f (rad², the filter's own θ block).
    pub fn theta_covariance(&self) -> Matrix3<T> {
        Matrix3::from_fn(|a, b| self.p_at(K * a, K * b))
    }

    /// Covariance of θ̇_f, (rad/s)² (the filter's own θ̇_f block; read in place).
    pub fn theta_f_rate_covariance(&self) -> Matrix3<T> {
        Matrix3::from_fn(|a, b| self.p_at(K * a + 2, K * b + 2))
    }

    /// Cross-covariance of θ's error (rows, rad) with the specific-force-difference bias's
    /// (columns, m/s²), rad·m/s² (the filter's own block, read in place); zero for a
    /// configuration without the bias state.
    pub fn theta_bias_covariance(&self) -> Matrix3<T> {
        if has_accel_bias::<K>() {
            Matrix3::from_fn(|a, b| self.p_at(K * a, K * b + BIAS_STATE))
        } else {
            Matrix3::zeros()
        }
    }

    /// Prior variance of each axis' specific-force-difference bias (`σ_b²` of the
    /// configuration, X, Y, Z), (m/s²)²; zero for a configuration without the bias state.
    pub fn accel_bias_prior_variance(&self) -> Vector3<T> {
        if has_accel_bias::<K>() {
            let s = &self.config().accel_bias_sigma_m_s2;
            s.component_mul(s)
        } else {
            Vector3::zeros()
        }
    }

    /// Covariance of θ_m = θ − θ_f (rad²): `P_θθ − P_θf − P_fθ + P_ff`.
    pub fn theta_m_covariance(&self) -> Matrix3<T> {
        Matrix3::from_fn(|a, b| {
            let (i, j) = (K * a, K * b);
            self.p_at(i, j) - self.p_at(i, j + 1) - self.p_at(i + 1, j) + self.p_at(i + 1, j + 1)
        })
    }

    /// 1σ of θ per axis, rad.
    pub fn theta_sigma_rad(&self) -> Vector3<T> {
        self.theta_covariance()
            .diagonal()
            .map(|v| v.max(T::zero()).sqrt())
    }

    /// State in derivative-major order `[θ, θ_f, θ̇_f(, θ̈_f)]` (the spec's ordering, with the
    /// total misalignment θ = θ_m + θ_f in place of θ_m: the filter's parametrisation).
    pub fn state(&self) -> SVector<T, N> {
        let mut s = SVector::<T, N>::zeros();
        for a in 0..3 {
            for d in 0..K {
                if let (Some(dst), Some(src)) = (
                    s.get_mut(spec_index(d, a)),
                    self.x.get(axis_index::<K>(d, a)),
                ) {
                    *dst = *src;
                }
            }
        }
        s
    }

    /// Covariance of [`Self::state`], in its ordering.
    pub fn covariance(&self) -> SMatrix<T, N, N> {
        to_spec_order::<T, K, N>(&symmetric_from_upper(self.p_cur()))
    }

    /// Estimated slave attitude `C_n^s = C_m^s C_n^m` given the master's `C_n^m`, with
    /// `C_m^s = exp(−[θ̂×])` (the spec's sign, exact rotation).
    pub fn slave_attitude(&self, c_n_m: &Matrix3<T>) -> Matrix3<T> {
        exp_so3(&(-self.theta())) * c_n_m
    }

    /// `true` when |θ| is beyond [`MAX_MISALIGNMENT_RAD`] on some axis (or not finite).
    pub(super) fn diverged(x: &SVector<T, N>) -> bool {
        let lim = T::lit(MAX_MISALIGNMENT_RAD);
        // `|v| ≤ lim` is false for NaN: one compare per axis, no branch between them.
        let within = |a: usize| x.get(K * a).copied().unwrap_or_else(T::zero).abs() <= lim;
        !(within(0) & within(1) & within(2))
    }
}

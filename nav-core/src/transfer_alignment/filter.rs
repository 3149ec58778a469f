//! The transfer-alignment Kalman filter: one implementation for the conventional 9-state
//! ([`ConventionalFilter`], 2nd-order flexure) and the proposed 12-state
//! ([`ProposedFilter`], 3rd-order flexure with θ̈_f) models.
//!
//! Each [`TransferAlignment::step`] takes a time-stamped master sample and the slave IMU sample
//! of the same epoch (fixed rate `dt_s`), compensates the lever arm, predicts the state to the
//! epoch and fuses the six scalar measurements `dω_X, dω_Y, dω_Z, df_X, df_Y, df_Z` sequentially
//! (Joseph form, [`fuse_scalar`]) with an optional NIS gate, returning one report per update.
//!
//! Structure used for the target:
//! - the state is stored axis-major, so Φ = blockdiag(Φ_X, Φ_Y, Φ_Z) (K×K each, computed once at
//!   configuration, exact discretisation) and `P ← Φ P Φᵀ + Q_d` is done per 3×3 pair of axis
//!   blocks, upper triangle only, mirrored;
//! - H rows are sparse: each of the six rows is built with a constant row number, so its
//!   pattern (at most 6 of the N columns) folds to constants and `hᵀ x`, `hᵀ b` become
//!   straight-line code; `b = P h` ([`covariance_times_row`]) and the Joseph update
//!   ([`fuse_scalar_prepared`]) are shared, one out-of-line copy per N (flash: inlining the
//!   product as well saves ≈ 350 instructions per 9-state step but costs ≈ 10 KB);
//! - all work is done on copies and committed at the end: an error leaves the filter untouched.
use super::design::TaDesign;
use super::measurement::{h_row_sparse, measurement, MasterSample, SlaveSample};
use super::model::{axis_index, to_spec_order, AxisChain, AxisFlexure, FlexureModel};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::math::checks::all_finite_parts;
#[allow(unused_imports)]
use crate::math::kalman::fuse_scalar;
use crate::math::kalman::{
    covariance_times_row, fuse_scalar_prepared, FusionOutcome, FusionReport, Gate,
};
use crate::math::rotation::exp_so3;
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Configuration of a transfer-alignment filter (all units in the names; σ are 1σ).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaConfig<T> {
    /// Nominal lever arm L_0 from the master to the slave IMU, master axes, m (spec: `[0, l, 0]`).
    pub lever_arm_m: Vector3<T>,
    /// Flexure model per axis X, Y, Z: stationary 1σ of θ_f (rad) and correlation time (s).
    pub flexure: [AxisFlexure<T>; 3],
    /// Initial 1σ of the mounting misalignment θ_m per axis, rad (spec: 0.5°).
    pub mount_sigma_rad: Vector3<T>,
    /// 1σ of one angular-rate difference sample dω (master + slave gyro noise), rad/s.
    pub rate_noise_sigma_rad_s: T,
    /// 1σ of one specific-force difference sample df (master + slave accelerometer noise), m/s².
    pub accel_noise_sigma_m_s2: T,
    /// Filter step (= slave IMU sample interval), s.
    pub dt_s: T,
    /// Allowed |t_master − t_slave| and jitter of the slave time step, s.
    pub time_tolerance_s: T,
    /// Largest gap, in steps, bridged by repeated prediction (≥ 1).
    pub max_gap_steps: u32,
    /// χ²(1) NIS gate of each scalar update (e.g. 25 = 5σ); `None` fuses everything.
    pub nis_gate: Option<T>,
}

impl<T: Real> TaConfig<T> {
    /// Validates every field (typed `InvalidConfig` naming the field).
    pub fn validate(&self) -> Result<(), NavError> {
        // (`opaque`: the loops stay rolled, configuration time only.)
        use crate::math::checks::opaque;
        for v in opaque(self.lever_arm_m.as_slice()) {
            crate::error::require_finite("lever_arm_m", *v)?;
        }
        for fl in opaque(self.flexure.as_slice()) {
            require_positive("flexure.sigma_rad", fl.sigma_rad)?;
            require_positive("flexure.tau_s", fl.tau_s)?;
        }
        for v in opaque(self.mount_sigma_rad.as_slice()) {
            require_non_negative("mount_sigma_rad", *v)?;
        }
        require_positive("rate_noise_sigma_rad_s", self.rate_noise_sigma_rad_s)?;
        require_positive("accel_noise_sigma_m_s2", self.accel_noise_sigma_m_s2)?;
        require_positive("dt_s", self.dt_s)?;
        require_non_negative("time_tolerance_s", self.time_tolerance_s)?;
        if self.time_tolerance_s * T::lit(2.0) >= self.dt_s {
            return Err(NavError::InvalidConfig {
                field: "time_tolerance_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        if self.max_gap_steps == 0 {
            return Err(NavError::InvalidConfig {
                field: "max_gap_steps",
                issue: ConfigIssue::OutOfRange,
            });
        }
        if let Some(g) = self.nis_gate {
            require_positive("nis_gate", g)?;
        }
        Ok(())
    }
}

impl<T: Real> TaConfig<T> {
    /// [`Self::validate`], then `(R_rate, R_accel, 1/dt)` (`σ²` of the rate and specific-force
    /// differences, (rad/s)² and (m/s²)², and 1/s), refused with `InvalidConfig { issue:
    /// OutOfRange }` naming the σ (or `dt_s`) when one is not finite and positive (squares of
    /// tiny or huge σ can underflow or overflow: refuse rather than run with R = 0 or ∞).
    /// Shared by both filters' `from_design` (one out-of-line copy per float type).
    #[inline(never)]
    fn validated_noise(&self) -> Result<(T, T, T), NavError> {
        self.validate()?;
        let r_rate = self.rate_noise_sigma_rad_s * self.rate_noise_sigma_rad_s;
        let r_accel = self.accel_noise_sigma_m_s2 * self.accel_noise_sigma_m_s2;
        let inv_dt = T::one() / self.dt_s;
        for (field, v) in [
            ("rate_noise_sigma_rad_s", r_rate),
            ("accel_noise_sigma_m_s2", r_accel),
            ("dt_s", inv_dt),
        ] {
            if !(v.is_finite() && v > T::zero()) {
                return Err(NavError::InvalidConfig {
                    field,
                    issue: ConfigIssue::OutOfRange,
                });
            }
        }
        Ok((r_rate, r_accel, inv_dt))
    }
}

/// What one step did.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct StepReport<T> {
    /// Time of the epoch, s.
    pub time_s: T,
    /// Number of prediction steps done before the update (0 at the first epoch).
    pub predictions: u32,
    /// One report per scalar update, in the order dω_X, dω_Y, dω_Z, df_X, df_Y, df_Z.
    pub updates: [FusionReport<T>; 6],
}

/// Largest |ω_m|, |ω_s| accepted per axis, rad/s (≈ 2 900 °/s, above any tactical gyro's range).
pub const MAX_ANGULAR_RATE_RAD_S: f64 = 50.0;
/// Largest |ω̇_m| accepted per axis, rad/s².
pub const MAX_ANGULAR_ACCEL_RAD_S2: f64 = 1.0e4;
/// Largest |f_m|, |f_s| accepted per axis, m/s² (≈ 200 g).
pub const MAX_SPECIFIC_FORCE_M_S2: f64 = 2.0e3;

/// Recovery from measurement starvation by the χ² gate (see [`TransferAlignment::health`]).
///
/// When one measurement channel has been rejected by the gate at `reset_after_rejections`
/// consecutive epochs, the filter concludes that its covariance is too small for what it sees
/// (a fault it did not model, or a transient that left it overconfident) and re-inflates it:
/// P ← P0 (the initial covariance: σ_m² on θ_m, the stationary flexure covariance), the flexure
/// states are reset to their prior mean 0, θ_m keeps its estimate. The reset is counted in
/// [`TaHealth::covariance_resets`]. `None` disables it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RecoveryPolicy {
    /// Consecutive gated epochs of one channel that trigger the covariance reset (≥ 1).
    pub reset_after_rejections: Option<u32>,
}

impl Default for RecoveryPolicy {
    /// Reset after 50 consecutive rejections of a channel (0.5 s at 100 Hz).
    fn default() -> Self {
        Self {
            reset_after_rejections: Some(50),
        }
    }
}

/// Counters of what the gate and the recovery did (channels dω_X..Z, df_X..Z).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct TaHealth {
    /// Measurements rejected by the χ² gate since construction, per channel.
    pub rejected: [u32; 6],
    /// Current run of consecutive rejections, per channel.
    pub consecutive_rejected: [u32; 6],
    /// Covariance resets done by the [`RecoveryPolicy`].
    pub covariance_resets: u32,
}

/// Transfer-alignment filter with `K` states per axis chain and `N = 3 K` states.
/// Use [`ConventionalFilter`] (K = 3) or [`ProposedFilter`] (K = 4).
///
/// The covariance is double-buffered: a step predicts from the current buffer into the other
/// one, fuses there, and only then makes it current, so an error leaves the filter untouched
/// without copying P. The `Debug` output shows the state (current buffer only).
#[derive(Clone)]
pub struct TransferAlignment<T: Real, const K: usize, const N: usize> {
    cfg: TaConfig<T>,
    model: FlexureModel,
    chains: [AxisChain<T, K>; 3],
    /// State, axis-major.
    x: SVector<T, N>,
    /// Covariance, axis-major: `p[cur]` is current, the other one scratch.
    p: [SMatrix<T, N, N>; 2],
    second: bool,
    r_rate: T,
    r_accel: T,
    inv_dt: T,
    time_s: Option<T>,
    recovery: RecoveryPolicy,
    health: TaHealth,
}

impl<T: Real, const K: usize, const N: usize> core::fmt::Debug for TransferAlignment<T, K, N> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.debug_struct("TransferAlignment")
            .field("cfg", &self.cfg)
            .field("model", &self.model)
            .field("chains", &self.chains)
            .field("x", &self.x)
            .field("p", self.p_cur())
            .field("r_rate", &self.r_rate)
            .field("r_accel", &self.r_accel)
            .field("inv_dt", &self.inv_dt)
            .field("time_s", &self.time_s)
            .field("recovery", &self.recovery)
            .field("health", &self.health)
            .finish()
    }
}

/// The conventional 9-state filter (2nd-order Markov flexure, seed eq. 5).
pub type ConventionalFilter<T> = TransferAlignment<T, 3, 9>;
/// The proposed 12-state filter (3rd-order Markov flexure with θ̈_f, seed eqs. 12-14).
pub type ProposedFilter<T> = TransferAlignment<T, 4, 12>;

#[inline(always)]
fn at<T: Real, const K: usize>(m: &SMatrix<T, K, K>, r: usize, c: usize) -> T {
    m.get((r, c)).copied().unwrap_or_else(T::zero)
}

#[inline(always)]
fn put<T: Real, const K: usize>(m: &mut SMatrix<T, K, K>, r: usize, c: usize, v: T) {
    if let Some(e) = m.get_mut((r, c)) {
        *e = v;
    }
}

/// `Φ_a S Φ_bᵀ` for one K×K block, using Φ = blockdiag(1, Φ_f) (θ_m is a random constant: the
/// first row and column of every chain's Φ are e₁, exactly, since F has a zero first row and
/// column). `upper` computes only the upper triangle of the flexure part and mirrors it (for a
/// diagonal block, which is symmetric).
#[inline(always)]
fn propagate_block<T: Real, const K: usize>(
    pa: &SMatrix<T, K, K>,
    pb: &SMatrix<T, K, K>,
    s: &SMatrix<T, K, K>,
    upper: bool,
) -> SMatrix<T, K, K> {
    // t_mj = Σ_{n≥1} S_mn Φb_jn (j ≥ 1): S Φ_bᵀ without the θ_m column.
    let mut t = SMatrix::<T, K, K>::zeros();
    for j in 1..K {
        for m in 0..K {
            let mut acc = T::zero();
            for n in 1..K {
                acc += at(s, m, n) * at(pb, j, n);
            }
            put(&mut t, m, j, acc);
        }
    }
    let mut d = SMatrix::<T, K, K>::zeros();
    put(&mut d, 0, 0, at(s, 0, 0));
    for j in 1..K {
        put(&mut d, 0, j, at(&t, 0, j));
    }
    for i in 1..K {
        if upper {
            put(&mut d, i, 0, at(&t, 0, i));
        } else {
            let mut acc = T::zero();
            for m in 1..K {
                acc += at(pa, i, m) * at(s, m, 0);
            }
            put(&mut d, i, 0, acc);
        }
        let j0 = if upper { i } else { 1 };
        for j in j0..K {
            let mut acc = T::zero();
            for m in 1..K {
                acc += at(pa, i, m) * at(&t, m, j);
            }
            put(&mut d, i, j, acc);
            if upper {
                put(&mut d, j, i, acc);
            }
        }
    }
    d
}

/// Time stamp checks shared by [`TransferAlignment::step`] and
/// [`TransferAlignment::propagate`]: the number of `dt_s` steps from `last` to `time_s`.
fn steps_between<T: Real>(
    cfg: &TaConfig<T>,
    inv_dt: T,
    last: Option<T>,
    time_s: T,
) -> Result<u32, NavError> {
    let Some(t0) = last else {
        return Ok(0);
    };
    let dt = time_s - t0;
    if dt <= T::zero() {
        return Err(NavError::TimeNotIncreasing);
    }
    let steps = (dt * inv_dt).round();
    if !steps.is_finite()
        || steps < T::one()
        || steps > T::lit(f64::from(cfg.max_gap_steps))
        || (dt - steps * cfg.dt_s).abs() > cfg.time_tolerance_s
    {
        return Err(NavError::InvalidTimeStep);
    }
    // 1 ≤ steps ≤ max_gap_steps (a u32): the loop ends and the conversion is exact.
    let mut n = 0u32;
    while T::lit(f64::from(n)) < steps {
        n += 1;
    }
    Ok(n)
}

/// `0` when every component is finite, NaN otherwise (`v·0` is ±0 for finite v and NaN for
/// ±∞ or NaN): a finiteness test that costs one multiply-add per value on the target.
#[inline(always)]
fn zero_if_finite<T: Real>(v: &Vector3<T>) -> T {
    v.x * T::zero() + v.y * T::zero() + v.z * T::zero()
}

fn in_range3<T: Real>(input: &'static str, v: &Vector3<T>, limit: f64) -> Result<(), NavError> {
    let lim = T::lit(limit);
    if v.as_slice().iter().all(|c| c.abs() <= lim) {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input })
    }
}

/// Writes the `k × k` blocks (column-major slices) on the block diagonal of the column-major
/// `n × n` matrix `p` (block `a` at rows and columns `k·a ..`), leaving the rest of `p` as it
/// is. Configuration time only: not generic over the dimensions and out of line.
#[inline(never)]
fn block_diagonal<T: Real>(p: &mut [T], n: usize, blocks: &[&[T]], k: usize) {
    let (p, n, blocks, k) = crate::math::checks::opaque((p, n, blocks, k));
    if k == 0 {
        return;
    }
    for (a, block) in blocks.iter().enumerate() {
        for (c, col) in block.chunks_exact(k).enumerate() {
            let start = (k * a + c) * n + k * a;
            if let Some(dst) = p.get_mut(start..start + k) {
                dst.copy_from_slice(col);
            }
        }
    }
}

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// Validates the configuration, discretises the per-axis chains at `dt_s` and starts from
    /// x = 0 with P = blockdiag(σ_m², stationary flexure covariance).
    ///
    /// Same as `from_design(cfg, &TaDesign::compute(&cfg)?)`.
    pub fn new(cfg: TaConfig<T>) -> Result<Self, NavError> {
        let design = TaDesign::<T, K>::compute(&cfg)?;
        Self::from_design(cfg, &design)
    }

    /// Builds the filter from a precomputed design ([`TaDesign::compute`] of this
    /// configuration, possibly stored as values, see [`crate::design`]) without running the
    /// discretisation; starts from x = 0 with P = blockdiag(P0_X, P0_Y, P0_Z).
    ///
    /// Checks (cheap): the configuration ([`TaConfig::validate`]), R and 1/dt finite and
    /// positive, every Φ, Q_d, P0 value finite (`InvalidConfig { field: "flexure" }` as
    /// [`Self::new`]), then the design's structure (Q_d and P0 exactly symmetric with a
    /// non-negative diagonal, Φ's θ_m row and column e₁, P0's θ_m variance equal to
    /// `mount_sigma_rad²`: `InvalidConfig { field: "design.q_d" | "design.p0" |
    /// "design.phi" }`). It cannot check that the design was computed for this `flexure` and
    /// `dt_s`: that is the caller's contract.
    pub fn from_design(cfg: TaConfig<T>, design: &TaDesign<T, K>) -> Result<Self, NavError> {
        let model = FlexureModel::for_dims::<K, N>()?;
        let (r_rate, r_accel, inv_dt) = cfg.validated_noise()?;
        let chains = design.chains;
        let mut p = SMatrix::<T, N, N>::zeros();
        // = `initial_covariance(&chains)`, with one looping copy for both filters.
        block_diagonal(
            p.as_mut_slice(),
            N,
            &[
                chains[0].p0.as_slice(),
                chains[1].p0.as_slice(),
                chains[2].p0.as_slice(),
            ],
            K,
        );
        // Every P0 (the blocks of `p`, zero elsewhere), Φ and Q_d value finite.
        let [cx, cy, cz] = &chains;
        if !all_finite_parts(&[
            cx.p0.as_slice(),
            cx.phi.as_slice(),
            cx.q_d.as_slice(),
            cy.p0.as_slice(),
            cy.phi.as_slice(),
            cy.q_d.as_slice(),
            cz.p0.as_slice(),
            cz.phi.as_slice(),
            cz.q_d.as_slice(),
        ]) {
            return Err(NavError::InvalidConfig {
                field: "flexure",
                issue: ConfigIssue::OutOfRange,
            });
        }
        design.check_structure(&cfg)?;
        Ok(Self {
            cfg,
            model,
            chains,
            x: SVector::zeros(),
            p: [p, p],
            second: false,
            r_rate,
            r_accel,
            inv_dt,
            time_s: None,
            recovery: RecoveryPolicy::default(),
            health: TaHealth::default(),
        })
    }

    fn initial_covariance(chains: &[AxisChain<T, K>; 3]) -> SMatrix<T, N, N> {
        let mut p = SMatrix::<T, N, N>::zeros();
        for (a, ch) in chains.iter().enumerate() {
            p.fixed_view_mut::<K, K>(K * a, K * a).copy_from(&ch.p0);
        }
        p
    }

    /// Sets the recovery policy (default [`RecoveryPolicy::default`]); `InvalidConfig` for a
    /// zero count.
    pub fn set_recovery(&mut self, policy: RecoveryPolicy) -> Result<(), NavError> {
        if policy.reset_after_rejections == Some(0) {
            return Err(NavError::InvalidConfig {
                field: "reset_after_rejections",
                issue: ConfigIssue::NotPositive,
            });
        }
        self.recovery = policy;
        Ok(())
    }

    /// The recovery policy in force.
    pub fn recovery(&self) -> RecoveryPolicy {
        self.recovery
    }

    /// Gate rejection and reset counters.
    pub fn health(&self) -> TaHealth {
        self.health
    }

    /// The configuration in force.
    pub fn config(&self) -> &TaConfig<T> {
        &self.cfg
    }

    /// Which model this filter runs.
    pub fn model(&self) -> FlexureModel {
        self.model
    }

    /// Per-axis discrete chains (Φ_j, Q_d,j, P0_j).
    pub fn chains(&self) -> &[AxisChain<T, K>; 3] {
        &self.chains
    }

    /// Time of the last processed epoch, s.
    pub fn time_s(&self) -> Option<T> {
        self.time_s
    }

    fn p_cur(&self) -> &SMatrix<T, N, N> {
        let [a, b] = &self.p;
        if self.second {
            b
        } else {
            a
        }
    }

    /// (current, scratch) covariance buffers.
    fn buffers(&mut self) -> (&SMatrix<T, N, N>, &mut SMatrix<T, N, N>) {
        let [a, b] = &mut self.p;
        if self.second {
            (&*b, a)
        } else {
            (&*a, b)
        }
    }

    /// One prediction over `dt_s`: `x_a ← Φ_a x_a` per axis and, per pair of axes a ≤ b,
    /// `P_ab ← Φ_a P_ab Φ_bᵀ (+ Q_d,a if a = b)` written to both (a, b) and (b, a) of `dst`,
    /// reading `src` (which may hold the same values as `dst`: each block is read before it is
    /// written and read only once).
    fn predict_cov(
        chains: &[AxisChain<T, K>; 3],
        src: Option<&SMatrix<T, N, N>>,
        dst: &mut SMatrix<T, N, N>,
    ) {
        // N = 3 K is checked at construction; stating it here lets the compiler prove every
        // block view below in bounds (no reachable panic on the target).
        if N != 3 * K {
            return;
        }
        for a in 0..3usize {
            for b in a..3usize {
                let (Some(ca), Some(cb)) = (chains.get(a), chains.get(b)) else {
                    continue;
                };
                // copy_from rather than into_owned: the latter builds from an iterator whose
                // length check the compiler cannot remove (a reachable panic on the target).
                let mut s = SMatrix::<T, K, K>::zeros();
                match src {
                    Some(m) => s.copy_from(&m.fixed_view::<K, K>(K * a, K * b)),
                    None => s.copy_from(&dst.fixed_view::<K, K>(K * a, K * b)),
                }
                let mut next = propagate_block(&ca.phi, &cb.phi, &s, a == b);
                if a == b {
                    next += ca.q_d;
                } else {
                    dst.fixed_view_mut::<K, K>(K * b, K * a)
                        .copy_from(&next.transpose());
                }
                dst.fixed_view_mut::<K, K>(K * a, K * b).copy_from(&next);
            }
        }
    }

    fn predict_state(chains: &[AxisChain<T, K>; 3], x: &mut SVector<T, N>) {
        for (a, ch) in chains.iter().enumerate() {
            let xa = ch.phi * x.fixed_rows::<K>(K * a);
            x.fixed_rows_mut::<K>(K * a).copy_from(&xa);
        }
    }

    /// One prediction on (x, P) in place (tests).
    #[cfg(test)]
    fn predict_into(&self, x: &mut SVector<T, N>, p: &mut SMatrix<T, N, N>) {
        Self::predict_state(&self.chains, x);
        Self::predict_cov(&self.chains, None, p);
    }

    /// Predicts `n` steps from the current covariance into the scratch buffer (a copy if n = 0).
    #[inline(never)] // one copy serves `step` and `propagate`
    fn predict_to_scratch(&mut self, x: &mut SVector<T, N>, n: u32) {
        // Borrow the fields separately: no copy of the chains.
        let Self {
            chains, p, second, ..
        } = self;
        let [a, b] = p;
        let (cur, scratch) = if *second { (&*b, a) } else { (&*a, b) };
        if n == 0 {
            scratch.copy_from(cur);
            return;
        }
        Self::predict_state(chains, x);
        Self::predict_cov(chains, Some(cur), scratch);
        for _ in 1..n {
            Self::predict_state(chains, x);
            Self::predict_cov(chains, None, scratch);
        }
    }

    /// Checks the physical range of the inputs (`InputOutOfRange`; limits
    /// [`MAX_ANGULAR_RATE_RAD_S`], [`MAX_ANGULAR_ACCEL_RAD_S2`], [`MAX_SPECIFIC_FORCE_M_S2`]).
    fn check_ranges(master: &MasterSample<T>, slave: &SlaveSample<T>) -> Result<(), NavError> {
        in_range3(
            "master.angular_rate_rad_s",
            &master.angular_rate_rad_s,
            MAX_ANGULAR_RATE_RAD_S,
        )?;
        in_range3(
            "master.angular_accel_rad_s2",
            &master.angular_accel_rad_s2,
            MAX_ANGULAR_ACCEL_RAD_S2,
        )?;
        in_range3(
            "master.specific_force_m_s2",
            &master.specific_force_m_s2,
            MAX_SPECIFIC_FORCE_M_S2,
        )?;
        in_range3(
            "slave.angular_rate_rad_s",
            &slave.angular_rate_rad_s,
            MAX_ANGULAR_RATE_RAD_S,
        )?;
        in_range3(
            "slave.specific_force_m_s2",
            &slave.specific_force_m_s2,
            MAX_SPECIFIC_FORCE_M_S2,
        )
    }

    /// Processes one epoch: checks the inputs and time stamps, predicts from the previous epoch
    /// (once per elapsed `dt_s`; none at the first epoch), then fuses the six scalar
    /// measurements (the sparse form of [`fuse_scalar`]: `b = P h` from the row's few columns,
    /// [`covariance_times_row`], then [`fuse_scalar_prepared`]). On error the
    /// filter is unchanged (bit for bit).
    ///
    /// Errors: `NonFiniteInput`, `InputOutOfRange` (an input beyond the `MAX_*` limits),
    /// `TimeNotIncreasing`, `InvalidTimeStep` (step not a whole number of `dt_s` within the
    /// tolerance, or a gap above `max_gap_steps`; bridge longer master dropouts with
    /// [`Self::propagate`]), `MeasurementTimeOutOfWindow` (master and slave time stamps differ
    /// by more than the tolerance; match delayed master data with a
    /// [`super::SlaveHistory`]), and the numerical refusals of [`fuse_scalar`].
    ///
    /// A measurement rejected by the χ² gate is reported (`Rejected`) and counted in
    /// [`Self::health`]; see [`RecoveryPolicy`] for what happens when a channel is starved.
    pub fn step(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
    ) -> Result<StepReport<T>, NavError> {
        // Fast path: one sum decides that all 17 inputs are finite; the per-field checks (which
        // name the offending input) only run when some input is not.
        let probe = (master.time_s + slave.time_s) * T::zero()
            + zero_if_finite(&master.angular_rate_rad_s)
            + zero_if_finite(&master.angular_accel_rad_s2)
            + zero_if_finite(&master.specific_force_m_s2)
            + zero_if_finite(&slave.angular_rate_rad_s)
            + zero_if_finite(&slave.specific_force_m_s2);
        if probe != T::zero() {
            master.validate()?;
            slave.validate()?;
        }
        Self::check_ranges(master, slave)?;
        if (master.time_s - slave.time_s).abs() > self.cfg.time_tolerance_s {
            return Err(NavError::MeasurementTimeOutOfWindow);
        }
        let predictions = steps_between(&self.cfg, self.inv_dt, self.time_s, slave.time_s)?;
        let (z, f_comp) = measurement(master, slave, &self.cfg.lever_arm_m);
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
        let gate = match self.cfg.nis_gate {
            Some(g) => Gate::Nis(g),
            None => Gate::Off,
        };
        let (model, lever, r_rate, r_accel) =
            (self.model, self.cfg.lever_arm_m, self.r_rate, self.r_accel);
        let mut x = self.x;
        self.predict_to_scratch(&mut x, predictions);
        let (_, p) = self.buffers();
        let empty = FusionReport {
            innovation: T::zero(),
            innovation_variance: T::zero(),
            nis: T::zero(),
            test_ratio: T::zero(),
            outcome: FusionOutcome::Rejected,
        };
        let mut updates = [empty; 6];
        // The six rows are written out with constant row indices (and the model follows from K
        // at compile time), so each row's sparsity pattern is known to the compiler: the
        // index-driven loops of the sparse update become straight-line code.
        let model_k = if K == 4 {
            FlexureModel::Proposed
        } else {
            FlexureModel::Conventional
        };
        debug_assert!(model_k == model);
        macro_rules! fuse_row {
            ($row:literal) => {
                if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                    let h = h_row_sparse::<T, K>(
                        model_k,
                        $row,
                        &master.angular_rate_rad_s,
                        &f_h,
                        &lever,
                    );
                    let r = if $row < 3 { r_rate } else { r_accel };
                    let innovation = zi - h.dot(&x);
                    // Built from validated, range-checked inputs with in-range ascending
                    // indices by construction (tested): no per-entry validation.
                    let b = covariance_times_row(p, &h);
                    let hph = h.dot(&b);
                    *rep = fuse_scalar_prepared(&mut x, p, &b, hph, innovation, r, gate)?;
                }
            };
        }
        fuse_row!(0);
        fuse_row!(1);
        fuse_row!(2);
        fuse_row!(3);
        fuse_row!(4);
        fuse_row!(5);
        // Commit: counters, recovery, state, buffer swap, time.
        let mut health = self.health;
        let mut starved = false;
        for ((rep, total), run) in updates
            .iter()
            .zip(health.rejected.iter_mut())
            .zip(health.consecutive_rejected.iter_mut())
        {
            if rep.outcome == FusionOutcome::Rejected {
                *total = total.saturating_add(1);
                *run = run.saturating_add(1);
                starved |= self
                    .recovery
                    .reset_after_rejections
                    .is_some_and(|n| *run >= n);
            } else {
                *run = 0;
            }
        }
        if starved {
            health.covariance_resets = health.covariance_resets.saturating_add(1);
            health.consecutive_rejected = [0; 6];
            let p0 = Self::initial_covariance(&self.chains);
            let (_, p) = self.buffers();
            *p = p0;
            for (i, v) in x.as_mut_slice().iter_mut().enumerate() {
                if i % K != 0 {
                    *v = T::zero();
                }
            }
        }
        self.health = health;
        self.x = x;
        self.second = !self.second;
        self.time_s = Some(slave.time_s);
        Ok(StepReport {
            time_s: slave.time_s,
            predictions,
            updates,
        })
    }

    /// Prediction only, to `time_s` (a whole number of `dt_s` after the last epoch, at most
    /// `max_gap_steps`): how a firmware loop keeps the filter running through a master-data
    /// dropout (call it at each slave epoch without master data). Returns the number of
    /// predictions. Errors: `NonFiniteInput`, `TimeNotIncreasing`, `InvalidTimeStep`, and
    /// `InvalidTimeStep` before the first [`Self::step`] (no epoch yet). On error the filter is
    /// unchanged.
    pub fn propagate(&mut self, time_s: T) -> Result<u32, NavError> {
        crate::error::input_finite("time_s", time_s)?;
        if self.time_s.is_none() {
            return Err(NavError::InvalidTimeStep);
        }
        let n = steps_between(&self.cfg, self.inv_dt, self.time_s, time_s)?;
        let mut x = self.x;
        self.predict_to_scratch(&mut x, n);
        self.x = x;
        self.second = !self.second;
        self.time_s = Some(time_s);
        Ok(n)
    }

    /// Matches time-tagged (possibly delayed) master data with the slave sample of the same
    /// epoch in `history` and runs [`Self::step`] on the pair. Errors: those of
    /// [`super::SlaveHistory::find`] and of [`Self::step`]; on error the filter is unchanged.
    pub fn step_delayed<const H: usize>(
        &mut self,
        master: &MasterSample<T>,
        history: &super::SlaveHistory<T, H>,
    ) -> Result<StepReport<T>, NavError> {
        let slave = history.find(master.time_s, self.cfg.time_tolerance_s)?;
        self.step(master, &slave)
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

    /// Estimated mounting misalignment θ_m, rad.
    pub fn theta_m(&self) -> Vector3<T> {
        self.block(0)
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
        (K == 4).then(|| self.block(3))
    }

    /// Estimated total misalignment θ = θ_m + θ_f, rad.
    pub fn theta(&self) -> Vector3<T> {
        self.theta_m() + self.theta_f()
    }

    /// Covariance of θ = θ_m + θ_f (rad²): `P_mm + P_mf + P_fm + P_ff`.
    pub fn theta_covariance(&self) -> Matrix3<T> {
        let mut c = Matrix3::zeros();
        for a in 0..3 {
            for b in 0..3 {
                let g = |d: usize, e: usize| {
                    self.p_cur()
                        .get((axis_index::<K>(d, a), axis_index::<K>(e, b)))
                        .copied()
                        .unwrap_or_else(T::zero)
                };
                if let Some(v) = c.get_mut((a, b)) {
                    *v = g(0, 0) + g(0, 1) + g(1, 0) + g(1, 1);
                }
            }
        }
        c
    }

    /// 1σ of θ per axis, rad.
    pub fn theta_sigma_rad(&self) -> Vector3<T> {
        self.theta_covariance()
            .diagonal()
            .map(|v| v.max(T::zero()).sqrt())
    }

    /// State in the spec's ordering `[θ_m, θ_f, θ̇_f(, θ̈_f)]`.
    pub fn state(&self) -> SVector<T, N> {
        let mut s = SVector::<T, N>::zeros();
        for a in 0..3 {
            for d in 0..K {
                if let (Some(dst), Some(src)) = (
                    s.get_mut(super::model::spec_index(d, a)),
                    self.x.get(axis_index::<K>(d, a)),
                ) {
                    *dst = *src;
                }
            }
        }
        s
    }

    /// Covariance in the spec's ordering.
    pub fn covariance(&self) -> SMatrix<T, N, N> {
        to_spec_order::<T, K, N>(self.p_cur())
    }

    /// Estimated slave attitude `C_n^s = C_m^s C_n^m` given the master's `C_n^m`, with
    /// `C_m^s = exp(−[θ̂×])` (the spec's sign, exact rotation).
    pub fn slave_attitude(&self, c_n_m: &Matrix3<T>) -> Matrix3<T> {
        exp_so3(&(-self.theta())) * c_n_m
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::kalman::{propagate_dense, FusionOutcome};
    use crate::transfer_alignment::model::assemble_spec;

    fn cfg<T: Real>() -> TaConfig<T> {
        let d = |x: f64| T::lit(x.to_radians());
        TaConfig {
            lever_arm_m: Vector3::new(T::zero(), T::lit(5.0), T::zero()),
            flexure: [
                AxisFlexure {
                    sigma_rad: d(0.5),
                    tau_s: T::lit(0.358),
                },
                AxisFlexure {
                    sigma_rad: d(0.1),
                    tau_s: T::lit(2.146),
                },
                AxisFlexure {
                    sigma_rad: d(0.1),
                    tau_s: T::lit(2.146),
                },
            ],
            mount_sigma_rad: Vector3::repeat(d(0.5)),
            rate_noise_sigma_rad_s: T::lit(3e-4),
            accel_noise_sigma_m_s2: T::lit(5e-3),
            dt_s: T::lit(0.01),
            time_tolerance_s: T::lit(1e-4),
            max_gap_steps: 3,
            nis_gate: Some(T::lit(25.0)),
        }
    }

    fn samples<T: Real>(t: f64) -> (MasterSample<T>, SlaveSample<T>) {
        let m = MasterSample {
            time_s: T::lit(t),
            angular_rate_rad_s: Vector3::new(T::lit(0.01), T::zero(), T::lit(-0.02)),
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: Vector3::new(T::lit(3.0), T::zero(), T::lit(-9.8)),
        };
        let s = SlaveSample {
            time_s: T::lit(t),
            angular_rate_rad_s: Vector3::new(T::lit(0.0101), T::lit(0.0002), T::lit(-0.0199)),
            specific_force_m_s2: Vector3::new(T::lit(3.02), T::lit(0.03), T::lit(-9.79)),
        };
        (m, s)
    }

    fn structured_predict_equals_dense<T: Real, const K: usize, const N: usize>(tol: f64) {
        let f = TransferAlignment::<T, K, N>::new(cfg()).unwrap();
        // A full symmetric P with cross-axis terms.
        let mut p = SMatrix::<T, N, N>::zeros();
        for i in 0..N {
            for j in 0..N {
                p[(i, j)] = T::lit(1e-4 / (1.0 + (i as f64 - j as f64).abs()));
            }
        }
        let mut x = SVector::<T, N>::from_fn(|i, _| T::lit(1e-3 * (i as f64 + 1.0)));
        let (x0, p0) = (x, p);
        f.predict_into(&mut x, &mut p);
        // Dense reference on the same axis-major layout.
        let mut phi = SMatrix::<T, N, N>::zeros();
        let mut qd = SMatrix::<T, N, N>::zeros();
        for (a, ch) in f.chains.iter().enumerate() {
            phi.fixed_view_mut::<K, K>(K * a, K * a).copy_from(&ch.phi);
            qd.fixed_view_mut::<K, K>(K * a, K * a).copy_from(&ch.q_d);
        }
        let mut pd = p0;
        propagate_dense(&mut pd, &phi, &qd);
        assert!(
            ((pd - p).abs().max()).to_f64() < tol * 1e-4,
            "{}",
            (pd - p).abs().max()
        );
        assert!(((phi * x0 - x).abs().max()).to_f64() < tol * 1e-2);
        assert_eq!(crate::math::kalman::asymmetry(&p), T::zero());
        // And the blocks equal exp(F dt) of the spec-ordered model.
        let (fs, _) =
            crate::transfer_alignment::model::continuous_model::<T, K, N>(&f.cfg.flexure).unwrap();
        let (phis, _) =
            crate::math::discretize::discretize(&fs, &SMatrix::zeros(), f.cfg.dt_s).unwrap();
        let blocks = [&f.chains[0].phi, &f.chains[1].phi, &f.chains[2].phi];
        let phi_spec = assemble_spec::<T, K, N>(blocks);
        assert!(((phis - phi_spec).abs().max()).to_f64() < tol);
    }

    #[test]
    fn structured_predict_f32_f64() {
        structured_predict_equals_dense::<f64, 4, 12>(1e-12);
        structured_predict_equals_dense::<f64, 3, 9>(1e-12);
        structured_predict_equals_dense::<f32, 4, 12>(1e-5);
        structured_predict_equals_dense::<f32, 3, 9>(1e-5);
    }

    fn step_and_errors<T: Real, const K: usize, const N: usize>() {
        let mut f = TransferAlignment::<T, K, N>::new(cfg()).unwrap();
        let (m, s) = samples::<T>(0.0);
        let rep = f.step(&m, &s).unwrap();
        assert_eq!(rep.predictions, 0);
        assert!(rep
            .updates
            .iter()
            .all(|u| u.outcome == FusionOutcome::Fused));
        assert!(rep
            .updates
            .iter()
            .all(|u| u.innovation_variance > T::zero()));
        let (m1, s1) = samples::<T>(0.01);
        assert_eq!(f.step(&m1, &s1).unwrap().predictions, 1);
        let before = (f.state(), f.covariance(), f.time_s());
        let unchanged = |f: &TransferAlignment<T, K, N>| {
            assert_eq!((f.state(), f.covariance(), f.time_s()), before);
        };
        // Same time again.
        assert_eq!(f.step(&m1, &s1), Err(NavError::TimeNotIncreasing));
        unchanged(&f);
        // Half a step.
        let (m2, s2) = samples::<T>(0.015);
        assert_eq!(f.step(&m2, &s2), Err(NavError::InvalidTimeStep));
        unchanged(&f);
        // Gap too long (4 steps, max 3).
        let (m3, s3) = samples::<T>(0.05);
        assert_eq!(f.step(&m3, &s3), Err(NavError::InvalidTimeStep));
        unchanged(&f);
        // Master and slave out of sync.
        let (m4, _) = samples::<T>(0.021);
        let (_, s4) = samples::<T>(0.02);
        assert_eq!(f.step(&m4, &s4), Err(NavError::MeasurementTimeOutOfWindow));
        unchanged(&f);
        // NaN input.
        let (mut m5, s5) = samples::<T>(0.02);
        m5.specific_force_m_s2.x = T::lit(f64::NAN);
        assert!(matches!(
            f.step(&m5, &s5),
            Err(NavError::NonFiniteInput { .. })
        ));
        unchanged(&f);
        // Gap of 2 steps is bridged.
        let (m6, s6) = samples::<T>(0.03);
        assert_eq!(f.step(&m6, &s6).unwrap().predictions, 2);
        // An outlier in df_X is rejected by the gate and reported.
        let (m7, mut s7) = samples::<T>(0.04);
        s7.specific_force_m_s2.x += T::lit(50.0);
        let rep = f.step(&m7, &s7).unwrap();
        assert_eq!(rep.updates[3].outcome, FusionOutcome::Rejected);
        assert!(rep.updates[3].test_ratio > T::one());
        assert_eq!(rep.updates[4].outcome, FusionOutcome::Fused);
    }

    #[test]
    fn step_reports_and_errors_leave_state_f32_f64() {
        step_and_errors::<f64, 4, 12>();
        step_and_errors::<f64, 3, 9>();
        step_and_errors::<f32, 4, 12>();
        step_and_errors::<f32, 3, 9>();
    }

    #[test]
    fn config_validation() {
        let ok = cfg::<f32>();
        assert!(ProposedFilter::new(ok).is_ok());
        let mut c = ok;
        c.flexure[1].tau_s = 0.0;
        assert!(matches!(
            ProposedFilter::new(c),
            Err(NavError::InvalidConfig {
                field: "flexure.tau_s",
                ..
            })
        ));
        let mut c = ok;
        c.accel_noise_sigma_m_s2 = -1.0;
        assert!(matches!(
            ConventionalFilter::new(c),
            Err(NavError::InvalidConfig {
                field: "accel_noise_sigma_m_s2",
                ..
            })
        ));
        let mut c = ok;
        c.lever_arm_m.y = f32::INFINITY;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.time_tolerance_s = 0.006;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.max_gap_steps = 0;
        assert!(ProposedFilter::new(c).is_err());
        let mut c = ok;
        c.nis_gate = Some(0.0);
        assert!(ProposedFilter::new(c).is_err());
        assert!(TransferAlignment::<f32, 4, 9>::new(ok).is_err());
    }

    #[test]
    fn block_diagonal_equals_initial_covariance() {
        fn check<T: Real, const K: usize, const N: usize>() {
            let f = TransferAlignment::<T, K, N>::new(cfg::<T>()).unwrap();
            let mut chains = *f.chains();
            // Distinct values everywhere, so a misplaced element shows.
            for (a, ch) in chains.iter_mut().enumerate() {
                for (i, v) in ch.p0.iter_mut().enumerate() {
                    *v = T::lit((100 * a + i + 1) as f64);
                }
            }
            let mut p = SMatrix::<T, N, N>::zeros();
            let blocks = [
                chains[0].p0.as_slice(),
                chains[1].p0.as_slice(),
                chains[2].p0.as_slice(),
            ];
            block_diagonal(p.as_mut_slice(), N, &blocks, K);
            assert_eq!(p, TransferAlignment::<T, K, N>::initial_covariance(&chains));
        }
        check::<f32, 3, 9>();
        check::<f64, 3, 9>();
        check::<f32, 4, 12>();
        check::<f64, 4, 12>();
    }

    #[test]
    fn initial_covariance_and_outputs() {
        let f = ProposedFilter::<f64>::new(cfg()).unwrap();
        let p = f.covariance();
        let sm = 0.5_f64.to_radians();
        assert!((p[(0, 0)] - sm * sm).abs() < 1e-15);
        // θ covariance = σ_m² + σ_f² per axis at the start.
        let s = f.theta_sigma_rad();
        assert!((s.x - (2.0 * sm * sm).sqrt()).abs() < 1e-12);
        assert!(f.theta_f_accel().is_some());
        assert!(ConventionalFilter::<f64>::new(cfg())
            .unwrap()
            .theta_f_accel()
            .is_none());
        // C_n^s for zero misalignment is C_n^m.
        let c = crate::math::rotation::euler_to_dcm(0.1, 0.2, 0.3).transpose();
        assert!((f.slave_attitude(&c) - c).abs().max() < 1e-15);
    }
}

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
//! - H rows are sparse (fuse_scalar skips the zero columns);
//! - all work is done on copies and committed at the end: an error leaves the filter untouched.
use super::measurement::{h_row, measurement, MasterSample, SlaveSample};
use super::model::{axis_chains, axis_index, to_spec_order, AxisChain, AxisFlexure, FlexureModel};
use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::math::kalman::{fuse_scalar, FusionReport, Gate};
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
        for v in self.lever_arm_m.iter() {
            crate::error::require_finite("lever_arm_m", *v)?;
        }
        for fl in &self.flexure {
            require_positive("flexure.sigma_rad", fl.sigma_rad)?;
            require_positive("flexure.tau_s", fl.tau_s)?;
        }
        for v in self.mount_sigma_rad.iter() {
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

/// Transfer-alignment filter with `K` states per axis chain and `N = 3 K` states.
/// Use [`ConventionalFilter`] (K = 3) or [`ProposedFilter`] (K = 4).
#[derive(Debug, Clone)]
pub struct TransferAlignment<T: Real, const K: usize, const N: usize> {
    cfg: TaConfig<T>,
    model: FlexureModel,
    chains: [AxisChain<T, K>; 3],
    /// State, axis-major.
    x: SVector<T, N>,
    /// Covariance, axis-major.
    p: SMatrix<T, N, N>,
    r_rate: T,
    r_accel: T,
    inv_dt: T,
    time_s: Option<T>,
}

/// The conventional 9-state filter (2nd-order Markov flexure, seed eq. 5).
pub type ConventionalFilter<T> = TransferAlignment<T, 3, 9>;
/// The proposed 12-state filter (3rd-order Markov flexure with θ̈_f, seed eqs. 12-14).
pub type ProposedFilter<T> = TransferAlignment<T, 4, 12>;

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// Validates the configuration, discretises the per-axis chains at `dt_s` and starts from
    /// x = 0 with P = blockdiag(σ_m², stationary flexure covariance).
    pub fn new(cfg: TaConfig<T>) -> Result<Self, NavError> {
        let model = FlexureModel::for_dims::<K, N>()?;
        cfg.validate()?;
        let chains = axis_chains::<T, K>(&cfg.flexure, &cfg.mount_sigma_rad, cfg.dt_s)?;
        let mut p = SMatrix::<T, N, N>::zeros();
        for (a, ch) in chains.iter().enumerate() {
            p.fixed_view_mut::<K, K>(K * a, K * a).copy_from(&ch.p0);
        }
        Ok(Self {
            cfg,
            model,
            chains,
            x: SVector::zeros(),
            p,
            r_rate: cfg.rate_noise_sigma_rad_s * cfg.rate_noise_sigma_rad_s,
            r_accel: cfg.accel_noise_sigma_m_s2 * cfg.accel_noise_sigma_m_s2,
            inv_dt: T::one() / cfg.dt_s,
            time_s: None,
        })
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

    /// One prediction over `dt_s` on (x, P) (axis-major): per axis `x_a ← Φ_a x_a`; per pair of
    /// axes `P_ab ← Φ_a P_ab Φ_bᵀ (+ Q_d,a if a = b)`, upper triangle, mirrored.
    fn predict_into(&self, x: &mut SVector<T, N>, p: &mut SMatrix<T, N, N>) {
        for (a, ch) in self.chains.iter().enumerate() {
            let xa = ch.phi * x.fixed_rows::<K>(K * a);
            x.fixed_rows_mut::<K>(K * a).copy_from(&xa);
        }
        for (a, ca) in self.chains.iter().enumerate() {
            for (b, cb) in self.chains.iter().enumerate().skip(a) {
                let blk = p.fixed_view::<K, K>(K * a, K * b);
                let mut next = ca.phi * blk * cb.phi.transpose();
                if a == b {
                    next += ca.q_d;
                    next = (next + next.transpose()) * T::lit(0.5);
                } else {
                    p.fixed_view_mut::<K, K>(K * b, K * a)
                        .copy_from(&next.transpose());
                }
                p.fixed_view_mut::<K, K>(K * a, K * b).copy_from(&next);
            }
        }
    }

    /// Processes one epoch: checks the inputs and time stamps, predicts from the previous epoch
    /// (once per elapsed `dt_s`; none at the first epoch), then fuses the six scalar
    /// measurements. On error the filter is unchanged.
    ///
    /// Errors: `NonFiniteInput`, `TimeNotIncreasing`, `InvalidTimeStep` (step not a whole
    /// number of `dt_s` within the tolerance, or a gap above `max_gap_steps`),
    /// `MeasurementTimeOutOfWindow` (master and slave time stamps differ by more than the
    /// tolerance), and the errors of [`fuse_scalar`].
    pub fn step(
        &mut self,
        master: &MasterSample<T>,
        slave: &SlaveSample<T>,
    ) -> Result<StepReport<T>, NavError> {
        master.validate()?;
        slave.validate()?;
        let tol = self.cfg.time_tolerance_s;
        if (master.time_s - slave.time_s).abs() > tol {
            return Err(NavError::MeasurementTimeOutOfWindow);
        }
        let predictions = match self.time_s {
            None => 0,
            Some(t0) => {
                let dt = slave.time_s - t0;
                if dt <= T::zero() {
                    return Err(NavError::TimeNotIncreasing);
                }
                let steps = (dt * self.inv_dt).round();
                if steps < T::one()
                    || steps > T::lit(f64::from(self.cfg.max_gap_steps))
                    || (dt - steps * self.cfg.dt_s).abs() > tol
                {
                    return Err(NavError::InvalidTimeStep);
                }
                // steps ≤ max_gap_steps (a u32), so the conversion is exact.
                let mut n = 0u32;
                while T::lit(f64::from(n)) < steps {
                    n += 1;
                }
                n
            }
        };
        let mut x = self.x;
        let mut p = self.p;
        for _ in 0..predictions {
            self.predict_into(&mut x, &mut p);
        }
        let (z, f_comp) = measurement(master, slave, &self.cfg.lever_arm_m);
        let f_h = match self.model {
            FlexureModel::Conventional => f_comp,
            FlexureModel::Proposed => slave.specific_force_m_s2,
        };
        let gate = match self.cfg.nis_gate {
            Some(g) => Gate::Nis(g),
            None => Gate::Off,
        };
        let idx = |d: usize, a: usize| axis_index::<K>(d, a);
        let empty = FusionReport {
            innovation: T::zero(),
            innovation_variance: T::zero(),
            nis: T::zero(),
            test_ratio: T::zero(),
            outcome: crate::math::kalman::FusionOutcome::Rejected,
        };
        let mut updates = [empty; 6];
        for (row, (rep, zi)) in updates.iter_mut().zip(z.iter()).enumerate() {
            let h: SVector<T, N> = h_row(
                self.model,
                row,
                &master.angular_rate_rad_s,
                &f_h,
                &self.cfg.lever_arm_m,
                idx,
            );
            let r = if row < 3 { self.r_rate } else { self.r_accel };
            let innovation = *zi - h.dot(&x);
            *rep = fuse_scalar(&mut x, &mut p, &h, innovation, r, gate)?;
        }
        self.x = x;
        self.p = p;
        self.time_s = Some(slave.time_s);
        Ok(StepReport {
            time_s: slave.time_s,
            predictions,
            updates,
        })
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
                    self.p
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
        to_spec_order::<T, K, N>(&self.p)
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

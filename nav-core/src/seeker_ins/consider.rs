//! Schmidt consider parameters for the accelerometers' scale factor and misalignment
//! (prototype, switched on by [`ACCEL_CONSIDER`]).
//!
//! The accelerometer-bias states are the equivalent bias at the reference specific force,
//! `∇ = b + (S + M) f_ref`, so the velocity error grows as
//! `δV̇ = … + C_b^n ∇ + C_b^n (S + M)(f − f_ref)`. With the nine elements of S and M as
//! consider parameters `c = (S_x, S_y, S_z, M_xy, M_xz, M_yx, M_yz, M_zx, M_zy)`,
//! `(S + M) u = J(u) c` (`J(u)` 3 × 9: row i has `u_i` in the column of `S_i` and `u_j` in
//! that of `M_ij`), and over a covariance step of Δt the error gains `Γ c`,
//! `Γ = C_b^n J(f − f_ref) Δt` (the velocity rows only). The filter keeps the cross-covariance
//! `P_xc = E[δx cᵀ]` (17 × 9) beside its 17 × 17 P, with `P_cc = diag(σ_S² I₃, σ_M² I₆)`
//! constant (never updated: consider, not estimated):
//!
//! ```text
//! P   ← Φ P Φᵀ + Q + Φ P_xc Γᵀ + Γ P_xcᵀ Φᵀ + Γ P_cc Γᵀ
//! P_xc ← Φ P_xc + Γ P_cc
//! ```
//!
//! and each fused scalar LOS component (gain `K = P h / s`, `h_c = 0`) takes
//! `P_xc ← P_xc − K (hᵀ P_xc)`. At the reference `P_xc[∇, ·] = J(f_ref) P_cc` (the reference's
//! share of the bias states' error is `(S + M) f_ref`); every other row starts at zero.

use super::error_model::{transition_times, ACC_BIAS, STATES, VEL};
use super::flight_noise::InstrumentErrors;
use super::measurement::LosModel;
use super::sparse_f::SparseF;
use super::update::LosReport;
use crate::contract::FusionOutcome;
use crate::Real;
use core::sync::atomic::{AtomicBool, Ordering};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Number of consider parameters.
pub const CONSIDER: usize = 9;

/// Prototype switch: the accelerometer part of the flight configuration's charge replaced by
/// the consider parameters (read at each covariance step).
#[doc(hidden)]
pub static ACCEL_CONSIDER: AtomicBool = AtomicBool::new(false);

/// Whether the consider form is switched on.
pub(crate) fn enabled() -> bool {
    ACCEL_CONSIDER.load(Ordering::Relaxed)
}

/// Row of `(S + M) u` and component of `u` each consider parameter multiplies.
const ROW_COMP: [(usize, usize); CONSIDER] = [
    (0, 0),
    (1, 1),
    (2, 2),
    (0, 1),
    (0, 2),
    (1, 0),
    (1, 2),
    (2, 0),
    (2, 1),
];

/// The cross-covariance `P_xc` and whether it is in use (set with the reference).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ConsiderCross<T> {
    pub(crate) p_xc: SMatrix<T, STATES, CONSIDER>,
    pub(crate) active: bool,
}

impl<T: Real> Default for ConsiderCross<T> {
    fn default() -> Self {
        Self {
            p_xc: SMatrix::zeros(),
            active: false,
        }
    }
}

/// `P_cc`'s diagonal.
fn p_cc<T: Real>(e: &InstrumentErrors<T>) -> [T; CONSIDER] {
    let (s2, m2) = (
        e.accel_scale_factor * e.accel_scale_factor,
        e.accel_misalignment_rad * e.accel_misalignment_rad,
    );
    [s2, s2, s2, m2, m2, m2, m2, m2, m2]
}

/// `J(u)`'s non-zero entry of each column: `(row, value)`.
fn jacobian<T: Real>(u: &Vector3<T>) -> [(usize, T); CONSIDER] {
    ROW_COMP.map(|(r, k)| (r, u.get(k).copied().unwrap_or(T::zero())))
}

impl<T: Real> ConsiderCross<T> {
    /// Starts `P_xc` at the reference `f_ref`: bias rows `J(f_ref) P_cc`, the rest zero.
    pub(crate) fn start(&mut self, errors: &InstrumentErrors<T>, f_ref: &Vector3<T>) {
        self.p_xc = SMatrix::zeros();
        let pcc = p_cc(errors);
        for (j, ((r, v), s)) in jacobian(f_ref).iter().zip(pcc.iter()).enumerate() {
            if let Some(x) = self.p_xc.get_mut((ACC_BIAS + r, j)) {
                *x = *v * *s;
            }
        }
        self.active = true;
    }

    /// The consider part of a covariance step (module doc), after the kernel's
    /// `Φ P Φᵀ + Q` in `p`: `f` the step's F (its Φ), `f_b` the mean body specific force and
    /// `f_ref` the reference (m/s²), `dt_s` the interval.
    pub(crate) fn step(
        &mut self,
        p: &mut SMatrix<T, STATES, STATES>,
        errors: &InstrumentErrors<T>,
        f: &SparseF<T>,
        f_b: &Vector3<T>,
        f_ref: &Vector3<T>,
        dt_s: T,
    ) {
        if !self.active {
            return;
        }
        let z = T::zero();
        let u = f_b - f_ref;
        let pcc = p_cc(errors);
        let jac = jacobian(&u);
        let c_b_n: Matrix3<T> = f.c_b_n;
        // Γ (3 × 9, the velocity rows): column j is `C_b^n[:, row_j] u_j Δt`.
        let gamma = SMatrix::<T, 3, CONSIDER>::from_fn(|r, j| {
            let (row, v) = jac.get(j).copied().unwrap_or((0, z));
            c_b_n.get((r, row)).copied().unwrap_or(z) * v * dt_s
        });
        // A = Φ P_xc, column by column.
        let mut a = SMatrix::<T, STATES, CONSIDER>::zeros();
        for j in 0..CONSIDER {
            let col: SVector<T, STATES> = self.p_xc.column(j).into_owned();
            a.set_column(j, &transition_times(f, dt_s, &col));
        }
        // M = A Γᵀ (17 × 3): P[:, V] += M, P[V, :] += Mᵀ; the velocity block
        // M[V, ·] + M[V, ·]ᵀ + Γ P_cc Γᵀ, written symmetric.
        let m = a * gamma.transpose();
        let gpg = SMatrix::<T, 3, 3>::from_fn(|r, s| {
            (0..CONSIDER).fold(z, |acc, j| {
                acc + gamma.get((r, j)).copied().unwrap_or(z)
                    * pcc.get(j).copied().unwrap_or(z)
                    * gamma.get((s, j)).copied().unwrap_or(z)
            })
        });
        for i in 0..STATES {
            if (VEL..VEL + 3).contains(&i) {
                continue;
            }
            for k in 0..3 {
                let v = m.get((i, k)).copied().unwrap_or(z);
                if let Some(x) = p.get_mut((i, VEL + k)) {
                    *x += v;
                }
                if let Some(x) = p.get_mut((VEL + k, i)) {
                    *x += v;
                }
            }
        }
        for r in 0..3 {
            for s in r..3 {
                let add = m.get((VEL + r, s)).copied().unwrap_or(z)
                    + m.get((VEL + s, r)).copied().unwrap_or(z)
                    + gpg.get((r, s)).copied().unwrap_or(z);
                let v = p.get((VEL + r, VEL + s)).copied().unwrap_or(z) + add;
                if let Some(x) = p.get_mut((VEL + r, VEL + s)) {
                    *x = v;
                }
                if let Some(x) = p.get_mut((VEL + s, VEL + r)) {
                    *x = v;
                }
            }
        }
        // P_xc ← A + Γ P_cc.
        for j in 0..CONSIDER {
            let s = pcc.get(j).copied().unwrap_or(z);
            for r in 0..3 {
                if let Some(x) = a.get_mut((VEL + r, j)) {
                    *x += gamma.get((r, j)).copied().unwrap_or(z) * s;
                }
            }
        }
        self.p_xc = a;
        self.zero_known_rows(p);
    }

    /// Rows of states whose variance is zero (repaired, or known exactly) set to zero.
    pub(crate) fn zero_known_rows(&mut self, p: &SMatrix<T, STATES, STATES>) {
        for i in 0..STATES {
            if p.get((i, i)).is_some_and(|d| *d <= T::zero()) {
                self.p_xc.row_mut(i).fill(T::zero());
            }
        }
    }

    /// Rows `0..9` (the navigation states) scaled by `f` (a congruence on P's rows).
    pub(crate) fn scale_row(&mut self, i: usize, f: T) {
        if i < STATES {
            for v in self.p_xc.row_mut(i).iter_mut() {
                *v *= f;
            }
        }
    }

    /// The navigation rows forgotten (P's navigation block restarted independent).
    pub(crate) fn forget_navigation(&mut self) {
        for i in 0..9 {
            self.p_xc.row_mut(i).fill(T::zero());
        }
    }

    /// After the fused components of a committed 2-D LOS update: `P_xc ← P_xc − K (hᵀ P_xc)`
    /// per fused component, `kk` its gain `P h / s` (the second against the first's result).
    pub(crate) fn after_los(
        &mut self,
        report: &LosReport<T>,
        model: &LosModel<T>,
        kk1: &[T; STATES],
        kk2: &[T; STATES],
    ) {
        if !self.active {
            return;
        }
        let steps = [
            (&report.pitch, &model.h_pitch, kk1),
            (&report.yaw, &model.h_yaw, kk2),
        ];
        for (rep, h, kk) in steps {
            if rep.outcome != FusionOutcome::Fused {
                continue;
            }
            let k = SVector::<T, STATES>::from(*kk);
            let g = h.transpose() * self.p_xc; // 1 × 9
            self.p_xc -= k * g;
        }
    }

    /// A rank-one update `P ← P − u kᵀ` with `u = P h`, `k = u / s`: `P_xc ← P_xc − k (hᵀ P_xc)`.
    pub(crate) fn after_rank_one(&mut self, h: &SVector<T, STATES>, k: &SVector<T, STATES>) {
        if !self.active {
            return;
        }
        let g = h.transpose() * self.p_xc;
        self.p_xc -= k * g;
    }
}

//! The accelerometers' scale factor S and misalignment M as **Schmidt consider parameters**
//! (flight configuration, [`super::InstrumentErrors`]).
//!
//! The accelerometer-bias states are the equivalent bias at the reference specific force,
//! `∇ = b + (S + M) f_ref` (module `flight_noise`), so the velocity error grows as
//! `δV̇ = … + C_b^n ∇ + C_b^n (S + M)(f − f_ref)`. With the nine elements of S and M as
//! consider parameters `c = (S_x, S_y, S_z, M_xy, M_xz, M_yx, M_yz, M_zx, M_zy)`,
//! `(S + M) u = J(u) c` (`J(u)` 3 × 9: row i holds `u_i` in the column of `S_i` and `u_j` in
//! that of `M_ij`), and over a covariance step of Δt the error gains `Γ c`,
//! `Γ = C_b^n J(f − f_ref) Δt` (velocity rows only; `f` the step's mean body specific force).
//! The filter keeps the cross-covariance `P_xc = E[δx cᵀ]` (17 × 9) beside its 17 × 17 P;
//! `P_cc = diag(σ_S² I₃, σ_M² I₆)` stays constant (the parameters are considered, never
//! estimated: no feedback, no update of their variance):
//!
//! ```text
//! P    ← Φ P Φᵀ + Q + Φ P_xc Γᵀ + Γ P_xcᵀ Φᵀ + Γ P_cc Γᵀ      (Φ P Φᵀ + Q: the kernel's)
//! P_xc ← Φ P_xc + Γ P_cc
//! ```
//!
//! — the 26-state covariance step with `Φ_a = [[Φ, Γ], [0, I]]`, of which the filter keeps the
//! blocks it uses. A scalar update of row h (`h_c = 0`: no measurement sees S or M directly)
//! has the 17-state gain `K = P h / s` and takes `P_xc ← P_xc − K (hᵀ P_xc)`. At the reference
//! `P_xc[∇, ·] = J(f_ref) P_cc` (the reference's share of the bias states' error is
//! `(S + M) f_ref`, `v(f_ref)` of their variance); every other row starts at zero.
//!
//! What this carries that a diagonal charge cannot: the error `(S + M)(f − f_ref)` of one turn
//! is correlated with that of the next (the same S and M), with the reference's share in the
//! bias states and, through the updates, with everything the LOS has learnt of them. Measured
//! (docs/seeker-ins.md): the S-turn's NEES no longer rises over the flight.
//!
//! A state kept beside the 17 (the flight navigator's baro error `e`, its column
//! `E[δx e]` in [`super::CrossColumn`]) has its own row `P_ec = E[e cᵀ]` (9 values, kept here):
//! the covariance step adds `Γ P_ecᵀ` to its column, its updates and decay are the owner's.
//!
//! Cost per covariance step: `Φ P_xc` (nine columns through the kernel's Φ), `W = P_xc' Jᵀ`
//! (J has one non-zero per column: 9 products a row), `W C_n^b`, the velocity rows and
//! columns of P; per LOS update both components' `hᵀ P_xc` over h's eight non-zero entries and
//! one pass of the rank-two correction of P_xc (`ConsiderCross::after_los_pair`); per baro
//! update `hᵀ P_xc` over its two entries and the rank-one correction.

use super::error_model::{transition_times, ACC_BIAS, STATES, VEL};
use super::flight_noise::InstrumentErrors;
use super::sparse_f::SparseF;
use crate::Real;
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};

/// Number of consider parameters (the accelerometers' S and M).
pub const CONSIDER: usize = 9;

/// Every state's index (a dense row).
#[cfg(test)]
const ALL_STATES: [usize; STATES] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, 16];

/// The non-zero columns of the LOS rows of H: position, attitude, gimbal angle errors.
pub(crate) const LOS_COLS: [usize; 8] = [0, 1, 2, 6, 7, 8, 15, 16];

/// Row of `(S + M) u` and component of `u` each consider parameter multiplies:
/// `S_x, S_y, S_z, M_xy, M_xz, M_yx, M_yz, M_zx, M_zy`.
pub(crate) const ROW_COMP: [(usize, usize); CONSIDER] = [
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

/// The cross-covariances of the consider parameters.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct ConsiderCross<T> {
    /// `P_xc = E[δx cᵀ]`, 17 × 9.
    pub(crate) p_xc: SMatrix<T, STATES, CONSIDER>,
    /// `P_ec = E[e cᵀ]` of the state kept beside the 17 (the navigator's baro error), m.
    pub(crate) p_ec: SVector<T, CONSIDER>,
    /// In use: set with the reference when the accelerometers' σ are not zero.
    pub(crate) active: bool,
}

impl<T: Real> Default for ConsiderCross<T> {
    fn default() -> Self {
        // Array-repeat storage: a plain zero fill, constructed in place.
        let z = T::zero();
        Self {
            p_xc: SMatrix::from_array_storage(nalgebra::ArrayStorage([[z; STATES]; CONSIDER])),
            p_ec: SVector::from_array_storage(nalgebra::ArrayStorage([[z; CONSIDER]; 1])),
            active: false,
        }
    }
}

/// `P_cc`'s diagonal: `(σ_S², σ_M²)`.
pub(crate) fn p_cc<T: Real>(e: &InstrumentErrors<T>) -> (T, T) {
    (
        e.accel_scale_factor * e.accel_scale_factor,
        e.accel_misalignment_rad * e.accel_misalignment_rad,
    )
}

/// `P_cc`'s diagonal element of parameter `j`.
fn pcc_at<T: Real>(pcc: (T, T), j: usize) -> T {
    if j < 3 {
        pcc.0
    } else {
        pcc.1
    }
}

/// `J(u) c` (3-vector) for the nine parameters' values `c` (a row of `P_xc`, or `P_ec`):
/// row i sums `u_k c_j` over the parameters `j` of that row (`ROW_COMP`), scale factor first.
fn j_times<T: Real>(c: [T; CONSIDER], u: &Vector3<T>) -> Vector3<T> {
    let [s0, s1, s2, m01, m02, m10, m12, m20, m21] = c;
    Vector3::new(
        s0 * u.x + m01 * u.y + m02 * u.z,
        s1 * u.y + m10 * u.x + m12 * u.z,
        s2 * u.z + m20 * u.x + m21 * u.y,
    )
}

/// `J(u)`'s one non-zero entry of column `j`: `(row, value)`.
pub(crate) fn jacobian_entry<T: Real>(u: &Vector3<T>, j: usize) -> (usize, T) {
    let (r, k) = ROW_COMP.get(j).copied().unwrap_or((0, 0));
    (r, u.get(k).copied().unwrap_or_else(T::zero))
}

/// `Γ = C_b^n J(u) Δt` (3 × 9; `u = f − f_ref`).
#[cfg(test)]
pub(crate) fn gamma<T: Real>(
    c_b_n: &Matrix3<T>,
    u: &Vector3<T>,
    dt_s: T,
) -> SMatrix<T, 3, CONSIDER> {
    SMatrix::from_fn(|r, j| {
        let (row, v) = jacobian_entry(u, j);
        c_b_n.get((r, row)).copied().unwrap_or_else(T::zero) * (v * dt_s)
    })
}

impl<T: Real> ConsiderCross<T> {
    /// Starts `P_xc` at the reference `f_ref` (body, m/s²): bias rows `J(f_ref) P_cc`, the
    /// rest (and `P_ec`) zero; inactive when both accelerometer σ are zero.
    pub(crate) fn start(&mut self, errors: &InstrumentErrors<T>, f_ref: &Vector3<T>) {
        *self = Self::default();
        let pcc = p_cc(errors);
        if pcc.0 <= T::zero() && pcc.1 <= T::zero() {
            return;
        }
        for j in 0..CONSIDER {
            let (r, v) = jacobian_entry(f_ref, j);
            if let Some(x) = self.p_xc.get_mut((ACC_BIAS + r, j)) {
                *x = v * pcc_at(pcc, j);
            }
        }
        self.active = true;
    }

    /// The consider part of a covariance step (module doc), `p` holding the kernel's
    /// `Φ P Φᵀ + Q` of F = `f` over `dt_s`; `u = f − f_ref` the departure of the step's mean
    /// body specific force (m/s²). Nothing when inactive. Rows of zero variance (repaired)
    /// are zeroed after (`repaired`: the kernel repaired a variance). Column by column on the arrays (no 17 × 3 temporaries: the frame
    /// stays small beside the kernel's).
    #[inline(never)]
    pub(crate) fn step(
        &mut self,
        p: &mut SMatrix<T, STATES, STATES>,
        errors: &InstrumentErrors<T>,
        f: &SparseF<T>,
        u: &Vector3<T>,
        dt_s: T,
        repaired: bool,
    ) {
        if !self.active {
            return;
        }
        let z = T::zero();
        // A = Φ P_xc, in place, column by column through the kernel's Φ (`G = F Δt` formed
        // once: the same products `transition_times` forms per column).
        let fs = f.scaled(dt_s);
        for col in self.p_xc.data.0.iter_mut() {
            let [a] = transition_times(&fs, T::one(), &SVector::from(*col)).data.0;
            *col = a;
        }
        let cdt = f.c_b_n * dt_s;
        let pd = &mut p.data.0;
        // B = A Γᵀ row by row: `w = J A[i, ·]ᵀ` (J one entry a column), `B[i, ·] = Δt C w`;
        // outside the velocity rows into P's velocity columns and rows at once.
        let cols = &self.p_xc.data.0;
        let mut bv = [[z; 3]; 3];
        for i in 0..STATES {
            let row: [T; CONSIDER] =
                core::array::from_fn(|j| cols.get(j).and_then(|c| c.get(i)).copied().unwrap_or(z));
            let b = cdt * j_times(row, u);
            if let Some(row) = i.checked_sub(VEL).and_then(|r| bv.get_mut(r)) {
                *row = [b.x, b.y, b.z];
                continue;
            }
            for (k, bk) in b.iter().enumerate() {
                let v = pd.get(VEL + k).and_then(|c| c.get(i)).copied().unwrap_or(z) + *bk;
                set_sym(pd, i, VEL + k, v);
            }
        }
        // The velocity block: `B[V, ·] + B[V, ·]ᵀ + Γ P_cc Γᵀ`, `Γ P_cc Γᵀ = Δt² C diag(v(u)) Cᵀ`.
        let (s2v, m2v) = p_cc(errors);
        let sq = u.component_mul(u);
        let tot = sq.x + sq.y + sq.z;
        let v = sq.map(|x| s2v * x + m2v * (tot - x));
        let gpg = cdt * Matrix3::from_diagonal(&v) * cdt.transpose();
        for r in 0..3 {
            for c in r..3 {
                let b_rc = bv.get(r).and_then(|x| x.get(c)).copied().unwrap_or(z);
                let b_cr = bv.get(c).and_then(|x| x.get(r)).copied().unwrap_or(z);
                let old = pd
                    .get(VEL + c)
                    .and_then(|x| x.get(VEL + r))
                    .copied()
                    .unwrap_or(z);
                let g = gpg.get((r, c)).copied().unwrap_or(z);
                set_sym(pd, VEL + r, VEL + c, old + (b_rc + b_cr + g));
            }
        }
        // P_xc ← A + Γ P_cc: column j gains `σ_j² u_kj Δt C[·, row_j]` in the velocity rows.
        let [cd0, cd1, cd2] = &cdt.data.0;
        for (j, col) in self.p_xc.data.0.iter_mut().enumerate() {
            let (row, x) = jacobian_entry(u, j);
            let s = pcc_at((s2v, m2v), j) * x;
            let cc = match row {
                0 => cd0,
                1 => cd1,
                _ => cd2,
            };
            for (dst, c) in col.iter_mut().skip(VEL).zip(cc.iter()) {
                *dst += s * *c;
            }
        }
        if repaired {
            self.zero_known_rows(p);
        }
    }

    /// The consider part of a covariance step over `dt_s` with F = `f` for the reference
    /// `f_ref` (`None`: not set yet, nothing to do), after the kernel and before the
    /// instrument-error charge. Returns whether a reference was set before the step (the
    /// caller starts `P_xc` when the charge sets it).
    pub(crate) fn step_at(
        &mut self,
        p: &mut SMatrix<T, STATES, STATES>,
        errors: &InstrumentErrors<T>,
        f_ref: Option<Vector3<T>>,
        f: &SparseF<T>,
        dt_s: T,
        repaired: bool,
    ) -> bool {
        let Some(f_ref) = f_ref else {
            return false;
        };
        let u = f.c_b_n.tr_mul(&f.f_ned) - f_ref;
        if crate::math::checks::all_finite(u.as_slice()) {
            self.step(p, errors, f, &u, dt_s, repaired);
        }
        true
    }

    /// Rows of states whose variance is zero (repaired, or known exactly) set to zero.
    pub(crate) fn zero_known_rows(&mut self, p: &SMatrix<T, STATES, STATES>) {
        for i in 0..STATES {
            if p.get((i, i)).is_some_and(|d| *d <= T::zero()) {
                self.scale_row(i, T::zero());
            }
        }
    }

    /// Row `i` scaled by `f` (P's row and column scaled: a congruence).
    pub(crate) fn scale_row(&mut self, i: usize, f: T) {
        for j in 0..CONSIDER {
            if let Some(v) = self.p_xc.get_mut((i, j)) {
                *v *= f;
            }
        }
    }

    /// The navigation rows (position, velocity, attitude: the states before the biases)
    /// scaled by `f` (P's navigation rows and columns scaled alike).
    pub(crate) fn scale_navigation_rows(&mut self, f: T) {
        for i in 0..ACC_BIAS {
            self.scale_row(i, f);
        }
    }

    /// The navigation rows forgotten: P's navigation block restarted independent.
    pub(crate) fn forget_navigation(&mut self) {
        self.scale_navigation_rows(T::zero());
    }

    /// A scalar update of row `h` with the 17-state gain `k = P h / s` (`h_c = 0`):
    /// `P_xc ← P_xc − k (hᵀ P_xc)`; with `k_e` the gain of the state kept beside the 17 (and
    /// `h_e` its entry in the row), `g = hᵀ P_xc + h_e P_ec`, `P_ec ← P_ec − k_e g`.
    #[cfg(test)]
    pub(crate) fn after_scalar(
        &mut self,
        h: &SVector<T, STATES>,
        h_e: T,
        k: &SVector<T, STATES>,
        k_e: T,
    ) {
        if !self.active {
            return;
        }
        self.after_scalar_at(h, &ALL_STATES, h_e, k, k_e);
    }

    /// The scalar update of `P_xc` and `P_ec` (`P_xc ← P_xc − k (hᵀ P_xc)`, `g = hᵀ P_xc + h_e P_ec`,
    /// `P_ec ← P_ec − k_e g`) for a row `h` whose only non-zero entries are at `cols`.
    pub(crate) fn after_scalar_at<const M: usize>(
        &mut self,
        h: &SVector<T, STATES>,
        cols: &[usize; M],
        h_e: T,
        k: &SVector<T, STATES>,
        k_e: T,
    ) {
        if !self.active {
            return;
        }
        let [ha] = &h.data.0;
        let [ka] = &k.data.0;
        let z = T::zero();
        for (col, pe) in self.p_xc.data.0.iter_mut().zip(self.p_ec.iter_mut()) {
            let g = cols.iter().fold(*pe * h_e, |acc, i| {
                acc + col.get(*i).copied().unwrap_or(z) * ha.get(*i).copied().unwrap_or(z)
            });
            for (c, kk) in col.iter_mut().zip(ka.iter()) {
                *c -= *kk * g;
            }
            *pe -= k_e * g;
        }
    }
}

impl<T: Real> ConsiderCross<T> {
    /// The LOS update's two scalar components in one pass: rows `h[0]`, `h[1]` (their values
    /// at `LOS_COLS`, the rows' only non-zero columns), their gains `k` as fused (the second
    /// against the first's result; zero for a component not fused). The sequential
    /// corrections `P_xc ← P_xc − k₁ g₁ᵀ`, `P_xc ← P_xc − k₂ g₂ᵀ` with `g₁ = h₁ᵀ P_xc` and
    /// `g₂ = h₂ᵀ (P_xc − k₁ g₁ᵀ) = h₂ᵀ P_xc − (h₂ᵀ k₁) g₁`, applied together: `P_xc` read over
    /// h's eight rows and written once. With `cross` the column `c` of a state kept beside
    /// the 17 as it was before the update and `1 / s` of each component (zero for one not
    /// fused), `P_ec ← P_ec − k_e₁ g₁ − k_e₂ g₂` with that state's gains `k_e₁ = h₁ᵀ c / s₁`,
    /// `k_e₂ = (h₂ᵀ c − (h₂ᵀ k₁) h₁ᵀ c) / s₂` (the column after the first component, not
    /// formed).
    pub(crate) fn after_los_pair(
        &mut self,
        h: &[[T; LOS_COLS.len()]; 2],
        k: [&[T; STATES]; 2],
        cross: Option<(&SVector<T, STATES>, [T; 2])>,
    ) {
        let z = T::zero();
        let [h1, h2] = h;
        let [k1, k2] = k;
        let dot = |row: &[T; LOS_COLS.len()], v: &[T; STATES]| {
            LOS_COLS.iter().zip(row.iter()).fold(z, |acc, (i, hv)| {
                acc + v.get(*i).copied().unwrap_or(z) * *hv
            })
        };
        let a = dot(h2, k1);
        let [e1, e2] = match cross {
            Some((c, [inv_s1, inv_s2])) => {
                let [c] = &c.data.0;
                let g1 = dot(h1, c);
                [g1 * inv_s1, (dot(h2, c) - a * g1) * inv_s2]
            }
            None => [z, z],
        };
        let mut g1 = [z; CONSIDER];
        let mut g2 = [z; CONSIDER];
        for ((col, g1j), g2j) in self
            .p_xc
            .data
            .0
            .iter()
            .zip(g1.iter_mut())
            .zip(g2.iter_mut())
        {
            let (mut s1, mut s2) = (z, z);
            for ((i, a1), a2) in LOS_COLS.iter().zip(h1.iter()).zip(h2.iter()) {
                let v = col.get(*i).copied().unwrap_or(z);
                s1 += *a1 * v;
                s2 += *a2 * v;
            }
            *g1j = s1;
            *g2j = s2 - a * s1;
        }
        for (i, (a1, a2)) in k1.iter().zip(k2.iter()).enumerate() {
            for ((col, g1j), g2j) in self.p_xc.data.0.iter_mut().zip(g1.iter()).zip(g2.iter()) {
                if let Some(x) = col.get_mut(i) {
                    *x -= *a1 * *g1j + *a2 * *g2j;
                }
            }
        }
        for ((pe, g1j), g2j) in self.p_ec.iter_mut().zip(g1.iter()).zip(g2.iter()) {
            *pe -= e1 * *g1j + e2 * *g2j;
        }
    }
}

/// `P[r, c] = P[c, r] = v` (column-major arrays, `p[col][row]`): a mirrored pair from one value.
fn set_sym<T: Real>(p: &mut [[T; STATES]; STATES], r: usize, c: usize, v: T) {
    if let Some(x) = p.get_mut(c).and_then(|col| col.get_mut(r)) {
        *x = v;
    }
    if let Some(x) = p.get_mut(r).and_then(|col| col.get_mut(c)) {
        *x = v;
    }
}

impl<T: Real> super::SeekerIns<T> {
    /// The consider part of a covariance step over `dt_s` with F = `f`, after the kernel and
    /// before the instrument-error charge ([`ConsiderCross::step_at`]); whether a reference
    /// was set before the step.
    pub(super) fn consider_step(&mut self, f: &SparseF<T>, dt_s: T, repaired: bool) -> bool {
        let f_ref = self.bias_charge.reference_f_b_m_s2;
        let errors = self.config.instrument_errors;
        self.consider
            .step_at(&mut self.p, &errors, f_ref, f, dt_s, repaired)
    }

    /// [`Self::consider_start`] when `due` (the charge may just have set the reference).
    pub(super) fn consider_start_if(&mut self, due: bool) {
        if due {
            self.consider_start();
        }
    }

    /// `P_xc` started at the reference just set (nothing without one).
    pub(super) fn consider_start(&mut self) {
        if let Some(f_ref) = self.bias_charge.reference_f_b_m_s2 {
            self.consider.start(&self.config.instrument_errors, &f_ref);
        }
    }

    /// The column of a state kept beside the 17, already `Φ c`, gains `Γ P_ecᵀ` of the same
    /// step (F = `f` over `dt_s`).
    pub(super) fn consider_external_step(
        &mut self,
        f: &SparseF<T>,
        dt_s: T,
        cross: &mut SVector<T, STATES>,
    ) {
        let Some(f_ref) = self.bias_charge.reference_f_b_m_s2 else {
            return;
        };
        if !self.consider.active {
            return;
        }
        let u = f.c_b_n.tr_mul(&f.f_ned) - f_ref;
        // `Γ P_ecᵀ = Δt C J P_ecᵀ`: J's rows as in the step.
        let [p_ec] = self.consider.p_ec.data.0;
        let add = f.c_b_n * (j_times(p_ec, &u) * dt_s);
        for (r, a) in add.iter().enumerate() {
            if let Some(x) = cross.get_mut(VEL + r) {
                *x += *a;
            }
        }
    }

    /// After a baro update applied by [`Self::update_rank_one`] (row `h + τ V_D` and `1` on the
    /// baro error; 17-state gain `k`, the baro error's `k_e`).
    pub(crate) fn consider_after_baro(&mut self, tau_s: T, k: &SVector<T, STATES>, k_e: T) {
        let mut h = SVector::<T, STATES>::zeros();
        if let Some(v) = h.get_mut(super::POS + 2) {
            *v = T::one();
        }
        if let Some(v) = h.get_mut(VEL + 2) {
            *v = tau_s;
        }
        let cols = [super::POS + 2, VEL + 2];
        self.consider.after_scalar_at(&h, &cols, T::one(), k, k_e);
    }

    /// The state kept beside the 17 decayed by `e` (its column and `P_ec` scale alike).
    pub(crate) fn consider_external_decay(&mut self, e: T) {
        self.consider.p_ec *= e;
    }

    /// The state kept beside the 17 restarted or its correlations forgotten: `P_ec ← 0`.
    pub(crate) fn consider_external_forget(&mut self) {
        self.consider.p_ec = SVector::zeros();
    }

    /// `P_xc` (tests).
    #[cfg(test)]
    pub(crate) fn consider_cross(&self) -> &SMatrix<T, STATES, CONSIDER> {
        &self.consider.p_xc
    }
}

#[cfg(test)]
#[path = "consider_tests.rs"]
mod tests;

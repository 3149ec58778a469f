//! Kalman measurement update by sequential scalar fusion, and covariance helpers.
//!
//! A vector measurement with diagonal noise covariance `R = diag(r_1 … r_m)` is fused as m
//! scalar updates, which is algebraically identical to the batch update
//! `K = P Hᵀ (H P Hᵀ + R)⁻¹` and needs one division per scalar instead of a matrix inverse.
//!
//! Each scalar update uses the Joseph form, expanded for a scalar measurement so that it costs
//! O(N²):
//!
//! ```text
//! b = P h,  s = hᵀ P h + r,  k = b / s
//! P⁺ = (I − k hᵀ) P (I − k hᵀ)ᵀ + r k kᵀ = P − k bᵀ − b kᵀ + s k kᵀ
//! ```
//!
//! computed as `P⁺_ij = P_ij + k_i c_j − b_i k_j` with `c = s k − b` (two multiply-adds per
//! element) on the upper triangle only, then mirrored, so P stays exactly symmetric. The new diagonal is
//! checked before anything is written: an update that would produce a negative or non-finite
//! variance is refused with [`NavError::CovarianceNotPositiveSemiDefinite`] and leaves x and P
//! untouched.

use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector};

/// Innovation gate of a scalar update.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Gate<T> {
    /// Fuse every finite measurement.
    Off,
    /// Reject when the normalised innovation squared `ν²/s` exceeds this χ² (1 degree of
    /// freedom) threshold; e.g. 9.0 is a 3σ gate (rejects 0.27 % of consistent measurements).
    Nis(T),
}

/// What happened to a measurement.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FusionOutcome {
    /// The measurement was fused into the state and covariance.
    Fused,
    /// The innovation failed the gate; state and covariance are unchanged.
    Rejected,
    /// The measurement was valid but could not be fused without breaking the covariance
    /// (innovation variance not positive, or a variance that would turn negative or
    /// non-finite in the working precision): the update was skipped, the filter keeps running
    /// on its prediction, and the report's numbers are those of the attempted update.
    Skipped,
}

/// Report of one scalar fusion (as PX4 EKF2 reports per sensor).
///
/// The fixed-gain vertical loops have no running covariance: their innovation variance is
/// that of their aid model (`vertical_channel::AidModel`: tracking σ₀², widened by the
/// inertial drift since the last accepted sample), σ₀ chosen from the design's steady state
/// (`AidedLoop::design_innovation_sigmas`).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FusionReport<T> {
    /// Innovation ν = z − ẑ, in the measurement's unit.
    pub innovation: T,
    /// Innovation variance s = hᵀ P h + r, in the measurement's unit squared.
    pub innovation_variance: T,
    /// Normalised innovation squared ν² / s (χ² with 1 degree of freedom when consistent).
    pub nis: T,
    /// NIS divided by the gate threshold (> 1 means rejected); 0 when the gate is off.
    pub test_ratio: T,
    /// Fused or rejected.
    pub outcome: FusionOutcome,
}

/// Fuses one scalar measurement `z = hᵀ x + v`, `var(v) = r`, given its innovation
/// `ν = z − ẑ` (computed by the caller from the nonlinear model for an EKF).
///
/// On `Ok(report)` with `outcome == Fused`, `x` and `p` are updated; on `Rejected` or `Err`,
/// they are untouched. Zero entries of `h` are skipped, so sparse rows cost less.
///
/// Errors: `NonFiniteInput` (innovation, h or r), `InputOutOfRange` (r ≤ 0),
/// `InnovationVarianceNotPositive`, `CovarianceNotPositiveSemiDefinite`.
pub fn fuse_scalar<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    h: &SVector<T, N>,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> Result<FusionReport<T>, NavError> {
    check_scalar_inputs(innovation, r)?;
    if !h.as_slice().iter().all(|v| finite(*v)) {
        return Err(NavError::NonFiniteInput {
            input: "measurement row h",
        });
    }
    // b = P h, skipping zero entries of h (columns of P). Plain slices (P is column-major)
    // keep the inner loops tight on the target.
    let mut b = SVector::<T, N>::zeros();
    for (col, &hj) in p.as_slice().chunks_exact(N).zip(h.as_slice()) {
        if hj != T::zero() {
            for (bi, &pij) in b.as_mut_slice().iter_mut().zip(col) {
                *bi += hj * pij;
            }
        }
    }
    let hph = h.dot(&b);
    fuse_scalar_prepared(x, p, &b, hph, innovation, r, gate)
}

/// A measurement row `h` stored by its non-zero entries: `index[..len]` (strictly ascending,
/// each < N) and `value[..len]`. At most `M` entries.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SparseRow<T, const M: usize> {
    /// Column indices of the stored entries (strictly ascending).
    pub index: [usize; M],
    /// Values of the stored entries, in the measurement's unit per state unit.
    pub value: [T; M],
    /// Number of stored entries (≤ M).
    pub len: usize,
}

impl<T: Real, const M: usize> SparseRow<T, M> {
    /// An empty row (h = 0).
    #[inline(always)]
    pub fn new() -> Self {
        Self {
            index: [0; M],
            value: [T::zero(); M],
            len: 0,
        }
    }

    /// Appends the entry `(index, value)`; `CapacityExceeded` when full. Indices must be pushed
    /// in strictly ascending order ([`fuse_scalar_sparse`] checks).
    #[inline(always)]
    pub fn push(&mut self, index: usize, value: T) -> Result<(), NavError> {
        match (self.index.get_mut(self.len), self.value.get_mut(self.len)) {
            (Some(i), Some(v)) => {
                *i = index;
                *v = value;
                self.len += 1;
                Ok(())
            }
            _ => Err(NavError::CapacityExceeded),
        }
    }

    /// The stored `(index, value)` pairs.
    #[inline(always)]
    pub fn entries(&self) -> impl Iterator<Item = (usize, T)> + Clone + '_ {
        self.index
            .iter()
            .copied()
            .zip(self.value.iter().copied())
            .take(self.len)
    }

    /// `hᵀ v`, summed in ascending index order.
    #[inline(always)]
    pub fn dot<const N: usize>(&self, v: &SVector<T, N>) -> T {
        let mut acc = T::zero();
        for (j, hj) in self.entries() {
            acc += hj * v.get(j).copied().unwrap_or_else(T::zero);
        }
        acc
    }

    /// Checks the row for use with an N-state vector: every stored value finite
    /// (`NonFiniteInput`), indices strictly ascending and < N (`InputOutOfRange`).
    #[inline(always)]
    pub fn validate<const N: usize>(&self) -> Result<(), NavError> {
        let mut prev: Option<usize> = None;
        for (j, hj) in self.entries() {
            if !finite(hj) {
                return Err(NavError::NonFiniteInput {
                    input: "measurement row h",
                });
            }
            if j >= N || prev.is_some_and(|q| q >= j) {
                return Err(NavError::InputOutOfRange {
                    input: "measurement row index",
                });
            }
            prev = Some(j);
        }
        Ok(())
    }

    /// The dense row (for tests and analysis).
    pub fn to_dense<const N: usize>(&self) -> SVector<T, N> {
        let mut h = SVector::<T, N>::zeros();
        for (j, hj) in self.entries() {
            if let Some(e) = h.get_mut(j) {
                *e = hj;
            }
        }
        h
    }
}

impl<T: Real, const M: usize> Default for SparseRow<T, M> {
    fn default() -> Self {
        Self::new()
    }
}

/// [`fuse_scalar`] for a sparse row: the same Joseph-form update, gate, report, exact symmetry
/// and refusal without damage, with `b = P h` computed from the `len` stored columns only and
/// the upper triangle written to both triangles in one pass (no separate mirror).
///
/// Errors: those of [`fuse_scalar`], and `InputOutOfRange` if an index is ≥ N or the indices
/// are not strictly ascending.
pub fn fuse_scalar_sparse<T: Real, const N: usize, const M: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> Result<FusionReport<T>, NavError> {
    // Checked before the row so a bad innovation or r is reported first, as `fuse_scalar`
    // does (`fuse_scalar_prepared` repeats the check: a few instructions).
    check_scalar_inputs(innovation, r)?;
    let b = sparse_covariance_product(p, h)?;
    let hph = h.dot(&b);
    fuse_scalar_prepared(x, p, &b, hph, innovation, r, gate)
}

/// `b = P h` for a sparse row, from the `len` stored columns only (P is column-major: column
/// j is the fixed-size array `p.data.0[j]`, so the inner loop has a constant trip count and no
/// bounds checks). Inlined: when the caller's row pattern is a compile-time constant (the
/// transfer-alignment rows) the column offsets are constants too.
///
/// Errors: `NonFiniteInput` for a non-finite entry, `InputOutOfRange` for an index ≥ N or
/// indices not strictly ascending.
#[inline(always)]
pub fn sparse_covariance_product<T: Real, const N: usize, const M: usize>(
    p: &SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
) -> Result<SVector<T, N>, NavError> {
    h.validate::<N>()?;
    Ok(covariance_times_row(p, h))
}

/// `b = P h` for a row already known valid ([`SparseRow::validate`], or built by the caller
/// from validated inputs with in-range ascending indices): one pass over the `len` stored
/// columns, each a fixed-size column of P (constant trip count, no bounds checks inside). An
/// out-of-range index (impossible for a valid row) contributes nothing.
///
/// Not inlined: one compact copy per (N, M) serves every row of a filter (inlined with
/// constant rows, the unrolled products cost kilobytes of flash per filter for a few tens of
/// instructions per row).
#[inline(never)]
pub fn covariance_times_row<T: Real, const N: usize, const M: usize>(
    p: &SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
) -> SVector<T, N> {
    let mut b = [T::zero(); N];
    for (&j, &hj) in h.index.iter().zip(h.value.iter()).take(h.len) {
        if let Some(col) = p.data.0.get(j) {
            for (bi, &pij) in b.iter_mut().zip(col) {
                *bi += hj * pij;
            }
        }
    }
    SVector::<T, N>::from_array_storage(nalgebra::ArrayStorage([b]))
}

/// The scalar Joseph update of [`fuse_scalar`] given `b = P h` and `hᵀ P h = hᵀ b` computed
/// by the caller (e.g. with [`sparse_covariance_product`] and [`SparseRow::dot`]): checks,
/// gate, report, exact symmetry, refusal without damage. `b` must be `P h` for the `p` passed.
///
/// Errors: those of [`fuse_scalar`] except the checks of h (done by the caller).
pub fn fuse_scalar_prepared<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    b: &SVector<T, N>,
    hph: T,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> Result<FusionReport<T>, NavError> {
    check_scalar_inputs(innovation, r)?;
    let s = hph + r;
    let (report, k, c) = match gain(innovation, hph, s, b, gate)? {
        GainOutcome::Rejected(rep) => return Ok(rep),
        GainOutcome::Fuse { report, k, c } => (report, k, c),
    };
    check_diagonal(p, &k, b, &c)?;
    let dx = k * innovation;
    if !all_finite(dx.as_slice()) {
        return Err(NavError::NonFiniteInput {
            input: "state correction",
        });
    }
    joseph_pass(p, &k, b, &c);
    for (xi, &di) in x.as_mut_slice().iter_mut().zip(dx.as_slice()) {
        *xi += di;
    }
    Ok(report)
}

/// `P⁺_ij = P_ij + k_i c_j − b_i k_j` on the upper triangle (i ≤ j, column j of the
/// column-major storage), each value also written to (j, i): exactly symmetric, N(N+1)/2
/// elements, no separate mirror pass.
///
/// For N ≤ 15 (every filter of this crate but the 17-state ESKF) the triangle is written out
/// element by element at compile time ([`joseph_unrolled`]): constant offsets, no loop
/// counters, no bounds checks, no per-column set-up (the loop form costs ≈ 17 instructions per
/// element on a Cortex-M4F for N = 12, the straight-line form ≈ 5). Larger N use the loop.
/// Both compute every element with the same expression, so the results are bit-identical.
#[inline(always)]
fn joseph_pass<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    k: &SVector<T, N>,
    b: &SVector<T, N>,
    c: &SVector<T, N>,
) {
    if N <= UNROLLED_MAX_N {
        let ([ks], [bs], [cs]) = (&k.data.0, &b.data.0, &c.data.0);
        joseph_unrolled(&mut p.data.0, ks, bs, cs);
    } else {
        joseph_loop(p, k, b, c);
    }
}

/// Largest N for which [`joseph_pass`] is straight-line code.
const UNROLLED_MAX_N: usize = 15;

/// One element of the Joseph pass: `P⁺_ij = P_ij + k_i c_j − b_i k_j` (i ≤ j), written to
/// (i, j) and (j, i). `p` is column-major (`p[col][row]`). With constant indices and a constant
/// N every `get` is resolved at compile time.
#[inline(always)]
fn joseph_elem<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
    i: usize,
    j: usize,
) {
    if let (Some(&ki), Some(&bi), Some(&kj), Some(&cj)) = (k.get(i), b.get(i), k.get(j), c.get(j)) {
        if let Some(pij) = p.get_mut(j).and_then(|col| col.get_mut(i)) {
            let nv = *pij + ki * cj - bi * kj;
            *pij = nv;
            if let Some(pji) = p.get_mut(i).and_then(|col| col.get_mut(j)) {
                *pji = nv;
            }
        }
    }
}

/// The upper triangle of an N ≤ 15 covariance, element by element (columns j ascending, rows
/// i ≤ j ascending); the `j < N` guards are constants after monomorphisation.
#[inline(always)]
fn joseph_unrolled<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
) {
    macro_rules! triangle {
        ($(($i:literal, $j:literal)),* $(,)?) => {
            $(
                if $j < N {
                    joseph_elem(p, k, b, c, $i, $j);
                }
            )*
        };
    }
    triangle!(
        (0, 0),
        (0, 1),
        (1, 1),
        (0, 2),
        (1, 2),
        (2, 2),
        (0, 3),
        (1, 3),
        (2, 3),
        (3, 3),
        (0, 4),
        (1, 4),
        (2, 4),
        (3, 4),
        (4, 4),
        (0, 5),
        (1, 5),
        (2, 5),
        (3, 5),
        (4, 5),
        (5, 5),
        (0, 6),
        (1, 6),
        (2, 6),
        (3, 6),
        (4, 6),
        (5, 6),
        (6, 6),
        (0, 7),
        (1, 7),
        (2, 7),
        (3, 7),
        (4, 7),
        (5, 7),
        (6, 7),
        (7, 7),
        (0, 8),
        (1, 8),
        (2, 8),
        (3, 8),
        (4, 8),
        (5, 8),
        (6, 8),
        (7, 8),
        (8, 8),
        (0, 9),
        (1, 9),
        (2, 9),
        (3, 9),
        (4, 9),
        (5, 9),
        (6, 9),
        (7, 9),
        (8, 9),
        (9, 9),
        (0, 10),
        (1, 10),
        (2, 10),
        (3, 10),
        (4, 10),
        (5, 10),
        (6, 10),
        (7, 10),
        (8, 10),
        (9, 10),
        (10, 10),
        (0, 11),
        (1, 11),
        (2, 11),
        (3, 11),
        (4, 11),
        (5, 11),
        (6, 11),
        (7, 11),
        (8, 11),
        (9, 11),
        (10, 11),
        (11, 11),
        (0, 12),
        (1, 12),
        (2, 12),
        (3, 12),
        (4, 12),
        (5, 12),
        (6, 12),
        (7, 12),
        (8, 12),
        (9, 12),
        (10, 12),
        (11, 12),
        (12, 12),
        (0, 13),
        (1, 13),
        (2, 13),
        (3, 13),
        (4, 13),
        (5, 13),
        (6, 13),
        (7, 13),
        (8, 13),
        (9, 13),
        (10, 13),
        (11, 13),
        (12, 13),
        (13, 13),
        (0, 14),
        (1, 14),
        (2, 14),
        (3, 14),
        (4, 14),
        (5, 14),
        (6, 14),
        (7, 14),
        (8, 14),
        (9, 14),
        (10, 14),
        (11, 14),
        (12, 14),
        (13, 14),
        (14, 14)
    );
}

/// The loop form of [`joseph_pass`] (any N).
#[inline(always)]
fn joseph_loop<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    k: &SVector<T, N>,
    b: &SVector<T, N>,
    c: &SVector<T, N>,
) {
    let (ks, bs, cs) = (k.as_slice(), b.as_slice(), c.as_slice());
    let flat = p.as_mut_slice();
    for (j, ((&kj, &cj), &bj)) in ks.iter().zip(cs).zip(bs).enumerate() {
        // `left` holds columns 0..j, `col_j` column j (column-major storage).
        let (left, right) = flat.split_at_mut(j * N);
        let Some(col_j) = right.get_mut(..N) else {
            break;
        };
        // Rows i < j of column j (upper triangle); each value also goes to row j of column i.
        for (((pij, &ki), &bi), col_i) in col_j
            .iter_mut()
            .zip(ks)
            .zip(bs)
            .zip(left.chunks_exact_mut(N))
        {
            let nv = *pij + ki * cj - bi * kj;
            *pij = nv;
            if let Some(mirror) = col_i.get_mut(j) {
                *mirror = nv;
            }
        }
        if let Some(pjj) = col_j.get_mut(j) {
            *pjj = *pjj + kj * cj - bj * kj;
        }
    }
}

/// `true` if every value is finite: `Σ vᵢ·0` is 0 unless some vᵢ is NaN or ±∞ (one compare
/// instead of a classification per element on the target).
#[inline(always)]
fn all_finite<T: Real>(v: &[T]) -> bool {
    let mut z = T::zero();
    for &x in v {
        z += x * T::zero();
    }
    z == T::zero()
}

fn check_scalar_inputs<T: Real>(innovation: T, r: T) -> Result<(), NavError> {
    if !finite(innovation) {
        return Err(NavError::NonFiniteInput {
            input: "innovation",
        });
    }
    if !finite(r) {
        return Err(NavError::NonFiniteInput {
            input: "measurement variance",
        });
    }
    if r <= T::zero() {
        return Err(NavError::InputOutOfRange {
            input: "measurement variance",
        });
    }
    Ok(())
}

/// The gate every scalar update of the crate shares: innovation variance `s = hᵀPh + r`
/// (given as `hph` and `s`), NIS `ν²/s`, test ratio and outcome (`Fused` when within the gate),
/// with `1/s`. `None` when s is not finite and positive or `hph < 0` (the measurement cannot be
/// fused in the working precision).
#[inline(always)]
pub fn gate_scalar<T: Real>(
    innovation: T,
    hph: T,
    s: T,
    gate: Gate<T>,
) -> Option<(FusionReport<T>, T)> {
    if !finite(s) || s <= T::zero() || hph < T::zero() {
        return None;
    }
    let inv_s = T::one() / s;
    let nis = innovation * innovation * inv_s;
    let (test_ratio, rejected) = match gate {
        Gate::Off => (T::zero(), false),
        Gate::Nis(threshold) => {
            let ratio = nis / threshold;
            // A NaN ratio or a non-positive threshold rejects.
            let within = matches!(
                ratio.partial_cmp(&T::one()),
                Some(core::cmp::Ordering::Less | core::cmp::Ordering::Equal)
            );
            (ratio, !within || threshold <= T::zero())
        }
    };
    let outcome = if rejected {
        FusionOutcome::Rejected
    } else {
        FusionOutcome::Fused
    };
    Some((
        FusionReport {
            innovation,
            innovation_variance: s,
            nis,
            test_ratio,
            outcome,
        },
        inv_s,
    ))
}

enum GainOutcome<T: Real, const N: usize> {
    Rejected(FusionReport<T>),
    Fuse {
        report: FusionReport<T>,
        k: SVector<T, N>,
        c: SVector<T, N>,
    },
}

/// Innovation variance checks, gate, gain k = b / s and c = s k − b.
#[inline(always)]
fn gain<T: Real, const N: usize>(
    innovation: T,
    hph: T,
    s: T,
    b: &SVector<T, N>,
    gate: Gate<T>,
) -> Result<GainOutcome<T, N>, NavError> {
    let (report, inv_s) =
        gate_scalar(innovation, hph, s, gate).ok_or(NavError::InnovationVarianceNotPositive)?;
    if report.outcome == FusionOutcome::Rejected {
        return Ok(GainOutcome::Rejected(report));
    }
    let k = b * inv_s;
    let mut c = SVector::<T, N>::zeros();
    for ((cj, &kj), &bj) in c
        .as_mut_slice()
        .iter_mut()
        .zip(k.as_slice().iter())
        .zip(b.as_slice().iter())
    {
        *cj = s * kj - bj;
    }
    Ok(GainOutcome::Fuse { report, k, c })
}

/// Refuses the update if a diagonal element of P⁺ would be negative or non-finite.
#[inline(always)]
fn check_diagonal<T: Real, const N: usize>(
    p: &SMatrix<T, N, N>,
    k: &SVector<T, N>,
    b: &SVector<T, N>,
    c: &SVector<T, N>,
) -> Result<(), NavError> {
    let ([ks], [bs], [cs]) = (&k.data.0, &b.data.0, &c.data.0);
    // One compare per element; ±∞ and NaN make the sum non-finite.
    let mut negative = false;
    let mut sum = T::zero();
    for (i, col) in p.data.0.iter().enumerate() {
        if let (Some(&ki), Some(&bi), Some(&ci), Some(&pii)) =
            (ks.get(i), bs.get(i), cs.get(i), col.get(i))
        {
            let d = pii + ki * ci - bi * ki;
            // `d < 0` misses NaN, but NaN also makes `sum` non-finite.
            negative |= d < T::zero();
            sum += d;
        }
    }
    if negative || !all_finite(&[sum]) {
        return Err(NavError::CovarianceNotPositiveSemiDefinite);
    }
    Ok(())
}

/// `true` for a finite value (NaN fails the comparison); cheaper on the target than the
/// generic `is_finite`.
#[inline(always)]
fn finite<T: Real>(v: T) -> bool {
    v.abs() < T::lit(f64::INFINITY)
}

/// Copies the upper triangle of a square matrix onto its lower triangle.
#[inline]
pub fn mirror_upper_to_lower<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>) {
    let flat = p.as_mut_slice();
    for i in 0..N {
        for j in (i + 1)..N {
            // Column-major: (row j, column i) at i·N + j, (row i, column j) at j·N + i.
            if let Some(v) = flat.get(j * N + i).copied() {
                if let Some(d) = flat.get_mut(i * N + j) {
                    *d = v;
                }
            }
        }
    }
}

/// Dense covariance propagation `P ← Φ P Φᵀ + Q_d`, re-symmetrised. Filters with structured Φ
/// use their own sparse propagation; this is the reference they are tested against.
pub fn propagate_dense<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    phi: &SMatrix<T, N, N>,
    q_d: &SMatrix<T, N, N>,
) {
    let next = phi * *p * phi.transpose() + q_d;
    *p = (next + next.transpose()) * T::lit(0.5);
}

/// Largest absolute asymmetry `max |P_ij − P_ji|`.
pub fn asymmetry<T: Real, const N: usize>(p: &SMatrix<T, N, N>) -> T {
    // `(p - pᵀ).abs().max()`, one looping copy per float type.
    super::checks::max_asymmetry(p.as_slice(), N)
}

/// `true` if `P + ε·trace(P)·I` has a Cholesky factor (P is symmetric positive semi-definite to
/// the relative tolerance `rel_eps`) and every element is finite.
///
/// Precisely: every element finite and nalgebra's `Cholesky::new((P + Pᵀ)/2 +
/// rel_eps·max(|trace P|, 1e-30)·I)` succeeds; computed by [`super::checks::psd_in_place`]
/// (the same operations, one looping copy per float type) on a copy of `p`.
pub fn is_psd<T: Real, const N: usize>(p: &SMatrix<T, N, N>, rel_eps: T) -> bool {
    let mut work = *p;
    super::checks::psd_in_place(work.as_mut_slice(), N, rel_eps)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix2, Matrix3, Vector2, Vector3};

    #[test]
    fn hand_computed_two_state_case() {
        // P = diag(4, 1), h = [1 0], r = 1, ν = 2 → s = 5, k = [0.8, 0], x⁺ = [1.6, 0],
        // P⁺ = diag(4 − 16/5, 1) = diag(0.8, 1).
        let mut x = Vector2::new(0.0_f64, 0.0);
        let mut p = Matrix2::new(4.0, 0.0, 0.0, 1.0);
        let rep =
            fuse_scalar(&mut x, &mut p, &Vector2::new(1.0, 0.0), 2.0, 1.0, Gate::Off).unwrap();
        assert_eq!(rep.outcome, FusionOutcome::Fused);
        assert!((rep.innovation_variance - 5.0).abs() < 1e-15);
        assert!((rep.nis - 0.8).abs() < 1e-15);
        assert!((x - Vector2::new(1.6, 0.0)).norm() < 1e-15);
        assert!((p - Matrix2::new(0.8, 0.0, 0.0, 1.0)).abs().max() < 1e-15);

        // Correlated case: P = [2 1; 1 2], h = [0 1], r = 2, ν = 1 → s = 4,
        // k = [0.25, 0.5], P⁺ = P − b bᵀ/s = [2−0.25, 1−0.5; ., 2−1].
        let mut x = Vector2::new(0.0_f64, 0.0);
        let mut p = Matrix2::new(2.0, 1.0, 1.0, 2.0);
        fuse_scalar(&mut x, &mut p, &Vector2::new(0.0, 1.0), 1.0, 2.0, Gate::Off).unwrap();
        assert!((x - Vector2::new(0.25, 0.5)).norm() < 1e-15);
        assert!((p - Matrix2::new(1.75, 0.5, 0.5, 1.0)).abs().max() < 1e-15);
    }

    #[test]
    fn sequential_equals_batch() {
        let mut p = Matrix3::new(3.0, 0.4, -0.2, 0.4, 2.0, 0.3, -0.2, 0.3, 1.5_f64);
        let mut x = Vector3::new(0.1, -0.2, 0.3);
        let hm = nalgebra::Matrix2x3::new(1.0, 0.5, 0.0, -0.3, 1.0, 2.0);
        let r = Matrix2::new(0.5, 0.0, 0.0, 0.8);
        let z = Vector2::new(0.7, -1.1);
        // Batch reference.
        let s = hm * p * hm.transpose() + r;
        let kb = p * hm.transpose() * s.try_inverse().unwrap();
        let xb = x + kb * (z - hm * x);
        let pb = (Matrix3::identity() - kb * hm) * p;
        // Sequential: the second innovation uses the state after the first update.
        for i in 0..2 {
            let h = hm.row(i).transpose();
            let nu = z[i] - h.dot(&x);
            fuse_scalar(&mut x, &mut p, &h, nu, r[(i, i)], Gate::Off).unwrap();
        }
        assert!((x - xb).norm() < 1e-14);
        assert!((p - pb).abs().max() < 1e-14);
        assert_eq!(asymmetry(&p), 0.0);
        assert!(is_psd(&p, 1e-12));
    }

    #[test]
    fn gate_rejects_and_leaves_state() {
        let mut x = Vector2::new(1.0_f32, 2.0);
        let mut p = Matrix2::new(1.0, 0.2, 0.2, 1.0);
        let (x0, p0) = (x, p);
        // s = 2, ν = 10 → NIS 50 > 9.
        let rep = fuse_scalar(
            &mut x,
            &mut p,
            &Vector2::new(1.0, 0.0),
            10.0,
            1.0,
            Gate::Nis(9.0),
        )
        .unwrap();
        assert_eq!(rep.outcome, FusionOutcome::Rejected);
        assert!(rep.test_ratio > 5.0);
        assert_eq!(x, x0);
        assert_eq!(p, p0);
    }

    #[test]
    fn bad_input_is_refused_without_damage() {
        let mut x = Vector2::new(1.0_f64, 2.0);
        let mut p = Matrix2::new(1.0, 0.2, 0.2, 1.0);
        let (x0, p0) = (x, p);
        let h = Vector2::new(1.0, 0.0);
        let cases = [
            (h, f64::NAN, 1.0),
            (h, 1.0, 0.0),
            (h, 1.0, -1.0),
            (h, 1.0, f64::INFINITY),
            (Vector2::new(f64::NAN, 0.0), 1.0, 1.0),
        ];
        for (h, nu, r) in cases {
            assert!(fuse_scalar(&mut x, &mut p, &h, nu, r, Gate::Off).is_err());
            assert_eq!(x, x0);
            assert_eq!(p, p0);
        }
        // An indefinite P cannot yield a positive innovation variance.
        let mut bad = Matrix2::new(-5.0, 0.0, 0.0, 1.0);
        assert_eq!(
            fuse_scalar(&mut x, &mut bad, &h, 1.0, 1.0, Gate::Off),
            Err(NavError::InnovationVarianceNotPositive)
        );
    }

    fn sparse_matches_dense<T: Real>(tol: f64) {
        use nalgebra::{SMatrix, SVector};
        // A full SPD 7×7 P and a row with 3 non-zeros.
        let a = SMatrix::<f64, 7, 7>::from_fn(|i, j| ((i * 7 + j) as f64 * 0.37).sin());
        let p64 = a * a.transpose() + SMatrix::<f64, 7, 7>::identity() * 0.5;
        let p0: SMatrix<T, 7, 7> = p64.map(T::lit);
        let x0 = SVector::<T, 7>::from_fn(|i, _| T::lit(0.1 * i as f64));
        let mut row = SparseRow::<T, 4>::new();
        row.push(1, T::lit(0.7)).unwrap();
        row.push(4, T::lit(-1.3)).unwrap();
        row.push(6, T::lit(2.0)).unwrap();
        let hd: SVector<T, 7> = row.to_dense();
        let (mut xd, mut pd) = (x0, p0);
        let (mut xs, mut ps) = (x0, p0);
        let rd = fuse_scalar(&mut xd, &mut pd, &hd, T::lit(0.3), T::lit(0.2), Gate::Off).unwrap();
        let rs = fuse_scalar_sparse(&mut xs, &mut ps, &row, T::lit(0.3), T::lit(0.2), Gate::Off)
            .unwrap();
        assert_eq!(rs.outcome, FusionOutcome::Fused);
        let rel = |a: T, b: T| ((a - b).abs() / (a.abs() + T::lit(1e-30))).to_f64();
        assert!(rel(rd.innovation_variance, rs.innovation_variance) < tol);
        assert!((pd - ps).abs().max().to_f64() < tol * 10.0);
        assert!((xd - xs).abs().max().to_f64() < tol);
        assert_eq!(asymmetry(&ps), T::zero());
        // Gate rejection and bad rows leave the state untouched.
        let (x1, p1) = (xs, ps);
        let rep = fuse_scalar_sparse(
            &mut xs,
            &mut ps,
            &row,
            T::lit(100.0),
            T::lit(0.2),
            Gate::Nis(T::lit(9.0)),
        )
        .unwrap();
        assert_eq!(rep.outcome, FusionOutcome::Rejected);
        let mut bad = row;
        bad.index[1] = 0; // not ascending
        assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
        let mut bad = row;
        bad.index[2] = 7; // out of range
        assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
        let mut bad = row;
        bad.value[0] = T::lit(f64::NAN);
        assert!(fuse_scalar_sparse(&mut xs, &mut ps, &bad, T::one(), T::one(), Gate::Off).is_err());
        assert!(
            fuse_scalar_sparse(&mut xs, &mut ps, &row, T::one(), T::zero(), Gate::Off).is_err()
        );
        let mut neg = ps;
        neg[(1, 1)] = T::lit(-1e3);
        assert!(
            fuse_scalar_sparse(&mut xs, &mut neg, &row, T::one(), T::one(), Gate::Off).is_err()
        );
        assert_eq!((xs, ps), (x1, p1));
        // The prepared form (b = P h and hᵀ b by the caller) is the sparse update bit for bit.
        let b = sparse_covariance_product(&ps, &row).unwrap();
        assert_eq!(b, ps * hd);
        let (mut xp, mut pp) = (xs, ps);
        let (mut xq, mut pq) = (xs, ps);
        let rp = fuse_scalar_prepared(
            &mut xp,
            &mut pp,
            &b,
            row.dot(&b),
            T::lit(-0.2),
            T::lit(0.3),
            Gate::Nis(T::lit(25.0)),
        )
        .unwrap();
        let rq = fuse_scalar_sparse(
            &mut xq,
            &mut pq,
            &row,
            T::lit(-0.2),
            T::lit(0.3),
            Gate::Nis(T::lit(25.0)),
        )
        .unwrap();
        assert_eq!((rp, xp, pp), (rq, xq, pq));
        assert_eq!(rp.outcome, FusionOutcome::Fused);
        assert!(fuse_scalar_prepared(
            &mut xp,
            &mut pp,
            &b,
            T::lit(f64::NAN),
            T::one(),
            T::one(),
            Gate::Off
        )
        .is_err());
        assert_eq!((xp, pp), (xq, pq));
        let mut full = SparseRow::<T, 1>::new();
        full.push(0, T::one()).unwrap();
        assert_eq!(full.push(1, T::one()), Err(NavError::CapacityExceeded));
    }

    #[test]
    fn sparse_update_matches_dense_f32_f64() {
        sparse_matches_dense::<f64>(1e-13);
        sparse_matches_dense::<f32>(2e-5);
    }

    fn unrolled_equals_loop<T: Real, const N: usize>() {
        use nalgebra::{SMatrix, SVector};
        let a = SMatrix::<f64, N, N>::from_fn(|i, j| ((i * N + j) as f64 * 0.61).cos());
        let p0: SMatrix<T, N, N> = (a * a.transpose()).map(T::lit);
        let k = SVector::<T, N>::from_fn(|i, _| T::lit(0.3 - 0.07 * i as f64));
        let b = SVector::<T, N>::from_fn(|i, _| T::lit(1.1 + 0.13 * i as f64));
        let c = SVector::<T, N>::from_fn(|i, _| T::lit(1e-3 * (i as f64 - 4.0)));
        let (mut pu, mut pl) = (p0, p0);
        joseph_unrolled(&mut pu.data.0, &k.data.0[0], &b.data.0[0], &c.data.0[0]);
        joseph_loop(&mut pl, &k, &b, &c);
        // Bit for bit, including the mirrored lower triangle; and the update did something.
        assert_eq!(pu, pl);
        assert_eq!(asymmetry(&pu), T::zero());
        assert!(pu != p0);
    }

    #[test]
    fn unrolled_joseph_pass_is_the_loop_bit_for_bit() {
        unrolled_equals_loop::<f32, 1>();
        unrolled_equals_loop::<f32, 9>();
        unrolled_equals_loop::<f32, 12>();
        unrolled_equals_loop::<f64, 5>();
        unrolled_equals_loop::<f64, 12>();
        unrolled_equals_loop::<f32, 15>();
        unrolled_equals_loop::<f64, 15>();
    }

    #[test]
    fn propagate_dense_matches_formula() {
        let mut p = Matrix2::new(1.0_f64, 0.1, 0.1, 2.0);
        let phi = Matrix2::new(1.0, 0.1, 0.0, 0.9);
        let q = Matrix2::new(0.01, 0.0, 0.0, 0.02);
        let expect = phi * p * phi.transpose() + q;
        propagate_dense(&mut p, &phi, &q);
        assert!((p - expect).abs().max() < 1e-15);
        assert!(!is_psd(&Matrix2::new(1.0, 2.0, 2.0, 1.0), 1e-9));
    }
}

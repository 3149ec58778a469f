//! Sparse measurement rows: [`SparseRow`], `b = P h` from the stored columns only, and the
//! sparse form of the scalar update.

#[cfg(doc)]
use super::fuse_scalar;
use super::{check_scalar_inputs, fuse_scalar_prepared, FusionReport, Gate};
use crate::math::checks::finite;
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector};

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

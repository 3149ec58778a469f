//! The finiteness tests of nav-core (one home: [`finite`], [`all_finite`], [`all_finite_parts`],
//! and the inlined [`all_finite_inline`] of the hot paths), and compact configuration-time
//! checks over slices (column-major `n × n` matrices as `m.as_slice()` plus the dimension).
//!
//! The constructors (`new`, `from_design`) validate many fixed-size matrices. Written with
//! nalgebra's static types each check is instantiated per dimension and fully unrolled at
//! opt-level 3; these helpers take a runtime length and are `#[inline(never)]`, so the image
//! holds one copy per float type (with LTO, a helper that an image calls from one place with
//! one dimension is specialised to it and may be unrolled there: the price is measured in the
//! flight image, about 1 KB, and nothing hides the dimension from the optimiser). Each is
//! documented with the exact expression it is equal to (same result, bit for bit, for any
//! input).
use crate::Real;

/// `true` for a finite value (not NaN or ±∞): `v.is_finite()`, computed as `|v| < ∞` (NaN
/// fails the comparison), one compare on the target instead of a classification. Inlined: it
/// runs in the measurement updates.
#[inline(always)]
pub fn finite<T: Real>(v: T) -> bool {
    v.abs() < T::lit(f64::INFINITY)
}

/// [`all_finite`] inlined into its caller (the measurement updates' check of a correction):
/// `Σ vᵢ·0` is 0 unless some vᵢ is NaN or ±∞ (one compare instead of a classification per
/// element on the target).
#[inline(always)]
pub fn all_finite_inline<T: Real>(v: &[T]) -> bool {
    let mut z = T::zero();
    for &x in v {
        z += x * T::zero();
    }
    z == T::zero()
}

/// `Ok` when every value of the input named `input` is finite, else
/// `NonFiniteInput { input }`: the check of a vector input (a sample's rate, force, velocity).
pub fn require_finite_input<T: Real>(
    input: &'static str,
    values: &[T],
) -> Result<(), crate::NavError> {
    if all_finite(values) {
        Ok(())
    } else {
        Err(crate::NavError::NonFiniteInput { input })
    }
}

/// `true` when every value is finite (not NaN or ±∞): `values.iter().all(|v| v.is_finite())`.
/// Computed without a branch per value (it also runs on step paths, on 17 × 17 covariances):
/// `v · 0` is NaN exactly when `v` is ±∞ or NaN (±0 otherwise), and a sum with a NaN term is
/// NaN, so the sum of the `v · 0` is finite exactly when every value is.
#[inline(never)]
pub fn all_finite<T: Real>(values: &[T]) -> bool {
    values
        .iter()
        .fold(T::zero(), |s, v| s + *v * T::zero())
        .is_finite()
}

/// `true` when every slice of `parts` is [`all_finite`].
#[inline(never)]
pub fn all_finite_parts<T: Real>(parts: &[&[T]]) -> bool {
    parts.iter().all(|p| all_finite(p))
}

/// Lower end of a [`RangeCheck`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum LowerBound<T> {
    /// `value ≥ bound`.
    AtLeast(T),
    /// `value == 0` or `value ≥ bound` (a value that may be switched off with 0).
    ZeroOrAtLeast(T),
}

/// One configuration value and its accepted range: finite, `< high`, and [`LowerBound`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RangeCheck<T> {
    /// Field name reported when the value is outside.
    pub field: &'static str,
    /// The value.
    pub value: T,
    /// Lower end.
    pub low: LowerBound<T>,
    /// Upper end (excluded).
    pub high: T,
}

/// The field of the first check whose value is outside its range (NaN and ±∞ are outside),
/// `None` when all are inside. One looping copy per float type, as the other checks.
#[inline(never)]
pub fn first_outside<T: Real>(checks: &[RangeCheck<T>]) -> Option<&'static str> {
    checks.iter().find_map(|c| {
        let low_ok = match c.low {
            LowerBound::AtLeast(b) => c.value >= b,
            LowerBound::ZeroOrAtLeast(b) => c.value == T::zero() || c.value >= b,
        };
        let inside = c.value.is_finite() && c.value < c.high && low_ok;
        (!inside).then_some(c.field)
    })
}

/// The value at row `i`, column `j` of the column-major `n × n` matrix `m` (`None` out of
/// bounds).
#[inline(always)]
fn at<T: Real>(m: &[T], n: usize, i: usize, j: usize) -> Option<T> {
    m.get(j * n + i).copied()
}

/// Equal to `m == mᵀ && m.diagonal().iter().all(|v| *v >= 0)` for the column-major `n × n`
/// matrix `m` (exactly symmetric, NaN anywhere makes it false, and a non-negative diagonal).
/// `false` if `m.len() != n²`.
#[inline(never)]
pub fn symmetric_non_negative_diagonal<T: Real>(m: &[T], n: usize) -> bool {
    if n.checked_mul(n) != Some(m.len()) {
        return false;
    }
    for j in 0..n {
        // Diagonal: `v >= 0` is false for NaN, as `v == v` would be.
        match at(m, n, j, j) {
            Some(d) if d >= T::zero() => {}
            _ => return false,
        }
        for i in (j + 1)..n {
            if at(m, n, i, j) != at(m, n, j, i) {
                return false;
            }
        }
    }
    true
}

/// Equal to "row 0 is `e₁ᵀ` and column 0 below row 0 is zero" for the column-major `n × n`
/// matrix `m`: `m[0,0] == 1`, `m[0,j] == 0` and `m[j,0] == 0` for `j ≥ 1` (`-0` counts as
/// zero). `false` if `m.len() != n²` or `n == 0`.
#[inline(never)]
pub fn first_row_and_column_unit<T: Real>(m: &[T], n: usize) -> bool {
    if n == 0 || n.checked_mul(n) != Some(m.len()) {
        return false;
    }
    if at(m, n, 0, 0) != Some(T::one()) {
        return false;
    }
    (1..n).all(|j| at(m, n, 0, j) == Some(T::zero()) && at(m, n, j, 0) == Some(T::zero()))
}

/// Writes the `k × k` blocks (column-major slices of `k²` values) on the block diagonal of the
/// column-major `n × n` matrix `p` (block `a` at rows and columns `k·a ..`), leaving the rest
/// of `p` as it is; a block that does not fit is not written. Equal to
/// `p.fixed_view_mut::<K, K>(K a, K a).copy_from(&block_a)` for each block (nalgebra).
/// Configuration time only: not generic over the dimensions and out of line, so the image
/// holds one copy per float type.
#[inline(never)]
pub fn set_block_diagonal<T: Real>(p: &mut [T], n: usize, blocks: &[&[T]], k: usize) {
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

/// Equal to `(m - mᵀ).abs().max()` (nalgebra) for the column-major `n × n` matrix `m`: the
/// values `|m[i,j] − m[j,i]|` in storage order folded with nalgebra's `simd_max`
/// (`if acc >= v { acc } else { v }`, so a NaN is kept or dropped exactly as there), `0` for an
/// empty matrix. Only the first `n²` values are used.
#[inline(never)]
pub fn max_asymmetry<T: Real>(m: &[T], n: usize) -> T {
    let mut acc: Option<T> = None;
    for j in 0..n {
        for i in 0..n {
            let d = match (at(m, n, i, j), at(m, n, j, i)) {
                (Some(a), Some(b)) => (a - b).abs(),
                _ => T::zero(),
            };
            acc = Some(match acc {
                Some(a) if a >= d => a,
                _ => d,
            });
        }
    }
    acc.unwrap_or_else(T::zero)
}

/// Equal to `kalman::is_psd` on the column-major `n × n` matrix `work`, i.e. to
/// `all finite && Cholesky::new((P + Pᵀ)/2 + ε·max(|trace P|, 1e-30)·I).is_some()` with
/// nalgebra's Cholesky, done in place with the same operations in the same order (so the
/// same answer for every input). `work` is overwritten. `false` if `work.len() != n²`.
#[inline(never)]
pub fn psd_in_place<T: Real>(work: &mut [T], n: usize, rel_eps: T) -> bool {
    if n.checked_mul(n) != Some(work.len()) || !all_finite(work) {
        return false;
    }
    // trace (nalgebra sums from zero, in index order).
    let mut trace = T::zero();
    for i in 0..n {
        trace += at(work, n, i, i).unwrap_or_else(T::zero);
    }
    let shift = rel_eps * trace.abs().max(T::lit(1e-30));
    // M = (P + Pᵀ)·0.5 + I·shift (off the diagonal `+ 0·shift`, as the dense sum does).
    let off = T::zero() * shift;
    for j in 0..n {
        for i in j..n {
            let (Some(a), Some(b)) = (at(work, n, i, j), at(work, n, j, i)) else {
                return false;
            };
            let v = (a + b) * T::lit(0.5) + if i == j { shift } else { off };
            if let Some(e) = work.get_mut(j * n + i) {
                *e = v;
            }
            // The upper triangle is not read by the factorisation below.
        }
    }
    // nalgebra `Cholesky::new_internal` (lower triangle, column by column).
    for j in 0..n {
        for k in 0..j {
            let factor = -at(work, n, j, k).unwrap_or_else(T::zero);
            for i in j..n {
                let x = at(work, n, i, k).unwrap_or_else(T::zero);
                if let Some(y) = work.get_mut(j * n + i) {
                    // axpy(a, x, 1): y = a·x·1 + 1·y
                    *y = factor * x + *y;
                }
            }
        }
        let diag = at(work, n, j, j).unwrap_or_else(T::zero);
        // `is_zero`, then `try_sqrt` (`None` unless `diag >= 0`).
        // (`diag == 0 || !(diag >= 0)` ⟺ not strictly positive, NaN included.)
        if diag.partial_cmp(&T::zero()) != Some(core::cmp::Ordering::Greater) {
            return false;
        }
        let denom = diag.sqrt();
        if let Some(e) = work.get_mut(j * n + j) {
            *e = denom;
        }
        for i in (j + 1)..n {
            if let Some(e) = work.get_mut(j * n + i) {
                *e /= denom;
            }
        }
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SMatrix};

    /// Deterministic pseudo-random values in [-1, 1) (xorshift).
    fn noise(seed: &mut u64) -> f64 {
        *seed ^= *seed << 13;
        *seed ^= *seed >> 7;
        *seed ^= *seed << 17;
        (*seed >> 11) as f64 / (1u64 << 52) as f64 - 1.0
    }

    fn dense_is_psd<T: Real, const N: usize>(p: &SMatrix<T, N, N>, rel_eps: T) -> bool
    where
        nalgebra::Const<N>: nalgebra::DimMin<nalgebra::Const<N>, Output = nalgebra::Const<N>>,
    {
        if !p.iter().all(|v| v.is_finite()) {
            return false;
        }
        let shift = rel_eps * p.trace().abs().max(T::lit(1e-30));
        let m = (p + p.transpose()) * T::lit(0.5) + SMatrix::<T, N, N>::identity() * shift;
        nalgebra::linalg::Cholesky::new(m).is_some()
    }

    fn slice_is_psd<T: Real, const N: usize>(p: &SMatrix<T, N, N>, rel_eps: T) -> bool {
        let mut w = *p;
        psd_in_place(w.as_mut_slice(), N, rel_eps)
    }

    /// Random matrices near the PSD boundary (B Bᵀ − c I with a random c, small asymmetric
    /// noise, special values): the slice checks agree with the dense expressions.
    fn agree<T: Real, const N: usize>(seed: u64)
    where
        nalgebra::Const<N>: nalgebra::DimMin<nalgebra::Const<N>, Output = nalgebra::Const<N>>,
    {
        let mut s = seed;
        let specials = [f64::NAN, f64::INFINITY, -0.0, 0.0, 1e300, 1e-300];
        let mut outcomes = [0u32; 2];
        for case in 0..400 {
            let b = SMatrix::<T, N, N>::from_fn(|_, _| T::lit(noise(&mut s)));
            let mut p = b * b.transpose();
            let c = T::lit(0.3 * noise(&mut s));
            for i in 0..N {
                p[(i, i)] -= c;
            }
            if case % 3 == 0 {
                let (i, j) = ((case / 3) % N, (case / 7) % N);
                p[(i, j)] += T::lit(1e-7 * noise(&mut s));
            }
            if case % 5 == 0 {
                let (i, j) = ((case / 5) % N, (case / 11) % N);
                p[(i, j)] = T::lit(specials[(case / 5) % specials.len()]);
            }
            if case % 13 == 0 {
                p = p.transpose() * T::lit(0.5) + p * T::lit(0.5);
                p[(N - 1, N - 1)] = -p[(N - 1, N - 1)].abs();
            }
            for eps in [T::zero(), T::lit(1e-6), T::lit(1e-2)] {
                let psd = slice_is_psd(&p, eps);
                assert_eq!(psd, dense_is_psd(&p, eps), "{p}");
                outcomes[usize::from(psd)] += 1;
            }
            let dense_asym = (p - p.transpose()).abs().max();
            let asym = max_asymmetry(p.as_slice(), N);
            assert!(
                (asym.to_f64().is_nan() && dense_asym.to_f64().is_nan())
                    || asym.to_f64().to_bits() == dense_asym.to_f64().to_bits(),
                "{asym} {dense_asym}"
            );
            let sym = p == p.transpose() && p.diagonal().iter().all(|v| *v >= T::zero());
            assert_eq!(symmetric_non_negative_diagonal(p.as_slice(), N), sym);
            assert_eq!(all_finite(p.as_slice()), p.iter().all(|v| v.is_finite()));
        }
        // Both answers are exercised.
        assert!(outcomes.iter().all(|c| *c > 50), "{outcomes:?}");
    }

    #[test]
    fn slice_checks_equal_dense_f32_f64() {
        agree::<f32, 1>(1);
        agree::<f32, 3>(2);
        agree::<f32, 17>(3);
        agree::<f64, 2>(4);
        agree::<f64, 4>(5);
        agree::<f64, 17>(6);
    }

    #[test]
    fn psd_hand_cases() {
        let mut pd = Matrix3::new(4.0_f64, 1.0, 0.0, 1.0, 3.0, 0.0, 0.0, 0.0, 2.0);
        assert!(psd_in_place(pd.as_mut_slice(), 3, 0.0));
        let mut indef = Matrix3::new(1.0_f32, 2.0, 0.0, 2.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        assert!(!psd_in_place(indef.as_mut_slice(), 3, 1e-6));
        // Singular PSD: refused without a shift, accepted with one.
        let mut sing = Matrix3::new(1.0_f64, 1.0, 0.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0);
        let mut sing2 = sing;
        assert!(!psd_in_place(sing.as_mut_slice(), 3, 0.0));
        assert!(psd_in_place(sing2.as_mut_slice(), 3, 1e-9));
        // Wrong length.
        assert!(!psd_in_place(&mut [1.0_f64, 0.0, 0.0], 2, 0.0));
        // All-zero matrix: the shift 1e-30·ε is positive.
        let mut z = [0.0_f64; 4];
        assert!(psd_in_place(&mut z, 2, 1.0));
        assert!(!psd_in_place(&mut [0.0_f64; 4], 2, 0.0));
    }

    #[test]
    fn structure_hand_cases() {
        let s = Matrix3::new(1.0_f32, 2.0, 3.0, 2.0, 0.0, 4.0, 3.0, 4.0, 5.0);
        assert!(symmetric_non_negative_diagonal(s.as_slice(), 3));
        let mut a = s;
        a[(0, 2)] = 3.5;
        assert!(!symmetric_non_negative_diagonal(a.as_slice(), 3));
        assert_eq!(max_asymmetry(a.as_slice(), 3), 0.5);
        assert_eq!(max_asymmetry(s.as_slice(), 3), 0.0);
        let mut d = s;
        d[(1, 1)] = -1.0;
        assert!(!symmetric_non_negative_diagonal(d.as_slice(), 3));
        let mut nan = s;
        nan[(2, 2)] = f32::NAN;
        assert!(!symmetric_non_negative_diagonal(nan.as_slice(), 3));
        assert!(!symmetric_non_negative_diagonal(s.as_slice(), 2));
        assert!(!all_finite(nan.as_slice()));
        assert!(all_finite(s.as_slice()));
        assert!(all_finite_parts(&[s.as_slice(), a.as_slice()]));
        assert!(!all_finite_parts(&[s.as_slice(), nan.as_slice()]));
        assert!(all_finite::<f64>(&[]));

        let e = Matrix3::new(1.0_f64, 0.0, -0.0, 0.0, 0.5, 0.1, 0.0, 0.2, 0.3);
        assert!(first_row_and_column_unit(e.as_slice(), 3));
        for (i, j) in [(0, 0), (0, 1), (0, 2), (1, 0), (2, 0)] {
            let mut b = e;
            b[(i, j)] += 1e-3;
            assert!(!first_row_and_column_unit(b.as_slice(), 3), "{i} {j}");
        }
        assert!(!first_row_and_column_unit(e.as_slice(), 2));
        assert!(!first_row_and_column_unit::<f64>(&[], 0));
    }
}

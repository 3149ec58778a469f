//! Small dense linear algebra without reachable panics (nalgebra's LU asserts on its indices,
//! which the optimiser cannot always remove on the target).

use crate::Real;
use nalgebra::SMatrix;

/// Inverse and determinant of a square matrix by Gauss-Jordan elimination with partial
/// pivoting. `None` when a pivot is zero or the result is not finite (singular to working
/// precision).
pub fn inverse_and_determinant<T: Real, const N: usize>(
    m: &SMatrix<T, N, N>,
) -> Option<(SMatrix<T, N, N>, T)> {
    // Row-major working copies: a[r][c].
    let mut a = [[T::zero(); N]; N];
    let mut inv = [[T::zero(); N]; N];
    for (r, (ar, ir)) in a.iter_mut().zip(inv.iter_mut()).enumerate() {
        for (c, v) in ar.iter_mut().enumerate() {
            *v = m.get((r, c)).copied().unwrap_or_else(T::zero);
        }
        if let Some(d) = ir.get_mut(r) {
            *d = T::one();
        }
    }
    let mut det = T::one();
    for col in 0..N {
        // Pivot: the largest magnitude in this column at or below the diagonal.
        let mut piv = col;
        let mut best = T::zero();
        for (r, row) in a.iter().enumerate().skip(col) {
            let v = row.get(col).copied().unwrap_or_else(T::zero).abs();
            if v > best {
                best = v;
                piv = r;
            }
        }
        if best <= T::zero() || !best.is_finite() {
            return None;
        }
        // (`piv < N` restated so the swaps are provably in bounds: no reachable panic.)
        if piv != col && piv < N && col < N {
            a.swap(piv, col);
            inv.swap(piv, col);
            det = -det;
        }
        let p = a.get(col).and_then(|row| row.get(col)).copied()?;
        det *= p;
        let inv_p = T::one() / p;
        let (pivot_row, pivot_inv) = {
            let (ar, ir) = (a.get_mut(col)?, inv.get_mut(col)?);
            for v in ar.iter_mut() {
                *v *= inv_p;
            }
            for v in ir.iter_mut() {
                *v *= inv_p;
            }
            (*ar, *ir)
        };
        for (r, (ar, ir)) in a.iter_mut().zip(inv.iter_mut()).enumerate() {
            if r == col {
                continue;
            }
            let f = ar.get(col).copied().unwrap_or_else(T::zero);
            if f != T::zero() {
                for (v, pv) in ar.iter_mut().zip(pivot_row.iter()) {
                    *v -= f * *pv;
                }
                for (v, pv) in ir.iter_mut().zip(pivot_inv.iter()) {
                    *v -= f * *pv;
                }
            }
        }
    }
    let mut out = SMatrix::<T, N, N>::zeros();
    for (r, ir) in inv.iter().enumerate() {
        for (c, v) in ir.iter().enumerate() {
            if let Some(o) = out.get_mut((r, c)) {
                *o = *v;
            }
        }
    }
    if !out.iter().all(|v| v.is_finite()) || !det.is_finite() {
        return None;
    }
    Some((out, det))
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix3, SMatrix};

    #[test]
    fn matches_nalgebra_and_detects_singular() {
        let m = SMatrix::<f64, 6, 6>::from_fn(|r, c| {
            ((r * 7 + c * 3) % 11) as f64 - 5.0 + if r == c { 9.0 } else { 0.0 }
        });
        let (inv, det) = inverse_and_determinant(&m).unwrap();
        assert!((inv * m - SMatrix::<f64, 6, 6>::identity()).abs().max() < 1e-12);
        assert!((det - m.determinant()).abs() < 1e-9 * det.abs());
        // A row swap is needed (zero leading pivot).
        let p = Matrix3::new(0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.0, 2.0_f32);
        let (ip, dp) = inverse_and_determinant(&p).unwrap();
        assert!((ip * p - Matrix3::identity()).abs().max() < 1e-6);
        assert_eq!(dp, -2.0);
        let s = Matrix3::new(1.0, 2.0, 3.0, 2.0, 4.0, 6.0, 0.0, 1.0, 1.0_f64);
        assert!(inverse_and_determinant(&s).is_none());
    }
}

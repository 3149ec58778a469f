//! Observability of the transfer-alignment models (spec "Observability", seed Tables 1 and 2).
//!
//! For a constant segment (F, H) the observability matrix is `O = [H; H F; …; H F^(N−1)]`.
//! For piecewise-constant segments with the same F, the stripped observability matrix of
//! Goshen-Meskin & Bar-Itzhack is `SOM = [O_1; O_2; …; O_r]`; its rank equals that of the total
//! observability matrix when `null(O_j) ⊆ null(F)` for each segment, which holds here (the
//! unobservable direction of a segment is a θ_m direction, and F θ_m = 0).
//!
//! Numerical rank, allocation-free: rows are generated one at a time and orthogonalised
//! (modified Gram-Schmidt, two passes) against the basis found so far; a row whose residual,
//! relative to the row's norm, exceeds `rel_tol` adds one to the rank. Scaling matters (the
//! powers of F span many orders of magnitude, e.g. β³ ≈ 530 s⁻³ up to F¹¹): every row is first
//! normalised, then every column is divided by its largest magnitude over all normalised rows
//! (a first pass), then the row is normalised again. The report gives the smallest accepted and
//! the largest rejected residual so the gap behind the rank can be judged.
use super::measurement::h_matrix;
use super::model::{continuous_model, AxisFlexure};
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector, Vector3};

/// One constant segment of a piecewise-constant system.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Segment<T: Real, const N: usize, const M: usize> {
    /// Continuous dynamics F.
    pub f: SMatrix<T, N, N>,
    /// Measurement matrix H.
    pub h: SMatrix<T, M, N>,
}

/// Numerical rank and the gap behind it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct RankReport<T> {
    /// Numerical rank.
    pub rank: usize,
    /// Smallest relative residual among the rows that raised the rank (1 = orthogonal).
    pub smallest_accepted: T,
    /// Largest relative residual among the rows found dependent (0 if none).
    pub largest_rejected: T,
}

fn inf_norm<T: Real, const N: usize>(v: &SVector<T, N>) -> T {
    v.iter().fold(T::zero(), |m, x| m.max(x.abs()))
}

/// Calls `visit` with every row of every segment's observability matrix, each normalised to unit
/// infinity norm (exactly zero rows are skipped).
fn for_each_row<T: Real, const N: usize, const M: usize>(
    segments: &[Segment<T, N, M>],
    mut visit: impl FnMut(&SVector<T, N>),
) {
    for seg in segments {
        let mut r = seg.h;
        for _ in 0..N {
            for row in r.row_iter() {
                let v: SVector<T, N> = row.transpose();
                let n = inf_norm(&v);
                if n > T::zero() && n.is_finite() {
                    visit(&(v / n));
                }
            }
            r *= seg.f;
        }
    }
}

/// Rank of the stripped observability matrix of `segments` (of the observability matrix if there
/// is one segment). `rel_tol` is the relative residual below which a row counts as dependent
/// (e.g. 1e-8 in f64, 1e-3 in f32).
pub fn som_rank<T: Real, const N: usize, const M: usize>(
    segments: &[Segment<T, N, M>],
    rel_tol: T,
) -> RankReport<T> {
    let mut col = SVector::<T, N>::zeros();
    for_each_row(segments, |v| {
        for (c, x) in col.iter_mut().zip(v.iter()) {
            *c = c.max(x.abs());
        }
    });
    let inv_col = col.map(|c| {
        if c > T::zero() {
            T::one() / c
        } else {
            T::one()
        }
    });
    let mut basis = SMatrix::<T, N, N>::zeros();
    let mut rank = 0usize;
    let mut smallest = T::one();
    let mut largest = T::zero();
    for_each_row(segments, |v| {
        if rank >= N {
            return;
        }
        let mut w = v.component_mul(&inv_col);
        let n0 = w.norm();
        if n0 <= T::zero() {
            return;
        }
        w /= n0;
        for _ in 0..2 {
            for q in basis.column_iter().take(rank) {
                let c = q.dot(&w);
                w.axpy(-c, &q, T::one());
            }
        }
        let res = w.norm();
        if res > rel_tol {
            basis.column_mut(rank).copy_from(&(w / res));
            rank += 1;
            smallest = smallest.min(res);
        } else {
            largest = largest.max(res);
        }
    });
    RankReport {
        rank,
        smallest_accepted: smallest,
        largest_rejected: largest,
    }
}

/// The constant segment of the K-per-axis model (N = 3 K) for a master specific force `f_m_m_s2`
/// and angular rate `omega_m_rad_s` (H uses f_m for both models: at the linearisation point
/// f_s = f_m).
pub fn segment<T: Real, const K: usize, const N: usize>(
    flexure: &[AxisFlexure<T>; 3],
    f_m_m_s2: &Vector3<T>,
    omega_m_rad_s: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
) -> Result<Segment<T, N, 6>, NavError> {
    let (f, _) = continuous_model::<T, K, N>(flexure)?;
    let h = h_matrix::<T, K, N>(omega_m_rad_s, f_m_m_s2, lever_arm_m)?;
    Ok(Segment { f, h })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn flex<T: Real>() -> [AxisFlexure<T>; 3] {
        let d = |x: f64| T::lit(x.to_radians());
        [
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
        ]
    }

    fn ranks<T: Real, const K: usize, const N: usize>(tol: f64) -> [usize; 7] {
        let g = T::lit(9.8);
        let z = T::zero();
        let l0 = Vector3::new(z, T::lit(5.0), z);
        let w = Vector3::zeros();
        let seg = |f: Vector3<T>| segment::<T, K, N>(&flex(), &f, &w, &l0).unwrap();
        let cruise = seg(Vector3::new(z, z, -g));
        let ax = seg(Vector3::new(g, z, -g));
        let ay = seg(Vector3::new(z, g, -g));
        let axy = seg(Vector3::new(g, g, -g));
        let t = T::lit(tol);
        [
            som_rank(&[cruise], t).rank,
            som_rank(&[ax], t).rank,
            som_rank(&[ay], t).rank,
            som_rank(&[axy], t).rank,
            som_rank(&[cruise, ax], t).rank,
            som_rank(&[cruise, ay], t).rank,
            som_rank(&[cruise, axy], t).rank,
        ]
    }

    #[test]
    fn table_ranks_f64_f32() {
        assert_eq!(ranks::<f64, 4, 12>(1e-8), [11, 11, 11, 11, 12, 12, 12]);
        assert_eq!(ranks::<f64, 3, 9>(1e-8), [8, 8, 8, 8, 9, 9, 9]);
        assert_eq!(ranks::<f32, 4, 12>(1e-3), [11, 11, 11, 11, 12, 12, 12]);
    }

    #[test]
    fn unscaled_identity_and_zero() {
        let seg = Segment::<f64, 3, 1> {
            f: SMatrix::zeros(),
            h: SMatrix::<f64, 1, 3>::new(1.0, 0.0, 0.0),
        };
        assert_eq!(som_rank(&[seg], 1e-9).rank, 1);
        let chain = Segment::<f64, 3, 1> {
            f: SMatrix::<f64, 3, 3>::new(0.0, 1.0, 0.0, 0.0, 0.0, 1.0, -1e3, -3e2, -30.0),
            h: SMatrix::<f64, 1, 3>::new(1.0, 0.0, 0.0),
        };
        assert_eq!(som_rank(&[chain], 1e-9).rank, 3);
    }
}

//! The covariance numerics of the filters, in their θ = θ_m + θ_f parametrisation (axis-major,
//! `K` states per chain, `N = 3 K`): the transformation of the design, the structured
//! prediction, the conditioning of every committed covariance, and the flexure
//! re-initialisation after a long gap.
use super::fusion::{fuse_rank_one, UpdateChecks};
use super::model::AxisChain;
use crate::math::checks::set_block_diagonal;
use crate::math::kalman::{FusionOutcome, FusionReport};
use crate::Real;
use nalgebra::{Matrix3, SMatrix, SVector};

mod predict;
pub(super) use predict::{predict_cov, predict_state};

/// One scalar update divides a variance by at most this ratio (`r ≥ hᵀPh / ratio`): keeps the
/// scalar update's subtraction within f32's digits (chosen by the stress campaign).
pub const MAX_VARIANCE_REDUCTION: f64 = 1.0e4;
/// Every committed covariance gets `P_ii ← P_ii (1 + PSD_LOADING_EPS · ε)` (ε the float type's
/// machine epsilon: ≈ 1.5e-5 in f32, 2.8e-14 in f64): a PSD diagonal that keeps the
/// correlation matrix's smallest eigenvalue above the rounding of one step (chosen by the
/// stress campaign).
pub const PSD_LOADING_EPS: f64 = 16.0;

#[inline(always)]
pub(super) fn at<T: Real, const K: usize>(m: &SMatrix<T, K, K>, r: usize, c: usize) -> T {
    m.get((r, c)).copied().unwrap_or_else(T::zero)
}

#[inline(always)]
fn put<T: Real, const K: usize>(m: &mut SMatrix<T, K, K>, r: usize, c: usize, v: T) {
    if let Some(e) = m.get_mut((r, c)) {
        *e = v;
    }
}

/// `T M Tᵀ` (`T` adds row/column 1 onto row/column 0): a θ_m-parametrised covariance block
/// in the θ = θ_m + θ_f parametrisation.
pub(super) fn to_total_cov<T: Real, const K: usize>(m: &SMatrix<T, K, K>) -> SMatrix<T, K, K> {
    let mut out = *m;
    for c in 0..K {
        put(&mut out, 0, c, at(m, 0, c) + at(m, 1, c));
    }
    let rows = out;
    for r in 0..K {
        put(&mut out, r, 0, at(&rows, r, 0) + at(&rows, r, 1));
    }
    out
}

/// `T Φ T⁻¹`: the transition in the θ parametrisation (row 0 += row 1, then column 1 −=
/// column 0).
pub(super) fn to_total_phi<T: Real, const K: usize>(m: &SMatrix<T, K, K>) -> SMatrix<T, K, K> {
    let mut out = *m;
    for c in 0..K {
        put(&mut out, 0, c, at(m, 0, c) + at(m, 1, c));
    }
    for r in 0..K {
        let v = at(&out, r, 1) - at(&out, r, 0);
        put(&mut out, r, 1, v);
    }
    out
}

/// The initial covariance blockdiag(P0_X, P0_Y, P0_Z) in the θ parametrisation.
pub(super) fn initial_covariance<T: Real, const K: usize, const N: usize>(
    chains: &[AxisChain<T, K>; 3],
) -> SMatrix<T, N, N> {
    let mut p = SMatrix::<T, N, N>::zeros();
    let [x, y, z] = chains.each_ref().map(|ch| to_total_cov(&ch.p0));
    set_block_diagonal(
        p.as_mut_slice(),
        N,
        &[x.as_slice(), y.as_slice(), z.as_slice()],
        K,
    );
    p
}

/// Variance ceilings, axis-major (see [`condition`]): `(√(σ_m² + σ_f²) + σ_f)²` for θ, the
/// stationary variance × 1.001 for the flexure states.
pub(super) fn ceilings<T: Real, const K: usize, const N: usize>(
    chains: &[AxisChain<T, K>; 3],
) -> SVector<T, N> {
    let mut ceiling = SVector::<T, N>::zeros();
    for (a, ch) in chains.iter().enumerate() {
        let var_f = at(&ch.p0, 1, 1);
        let theta = (at(&ch.p0, 0, 0) + var_f).sqrt() + var_f.sqrt();
        for d in 0..K {
            if let Some(c) = ceiling.get_mut(K * a + d) {
                *c = if d == 0 {
                    theta * theta
                } else {
                    at(&ch.p0, d, d) * T::lit(1.001)
                };
            }
        }
    }
    ceiling
}

/// Element (r, c) of a covariance stored as its upper triangle (column-major `p[col][row]`,
/// the lower triangle not read): `P_rc = P_cr` is read from the stored one of the two.
#[inline(always)]
pub(super) fn upper_at<T: Real, const N: usize>(p: &SMatrix<T, N, N>, r: usize, c: usize) -> T {
    let (r, c) = if r <= c { (r, c) } else { (c, r) };
    p.data
        .0
        .get(c)
        .and_then(|col| col.get(r))
        .copied()
        .unwrap_or_else(T::zero)
}

/// Makes a covariance stored as its upper triangle a full symmetric matrix, in place (the
/// rare paths written for a full matrix; no second matrix on the stack).
pub(super) fn mirror_upper<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>) {
    for c in 0..N {
        for r in (c + 1)..N {
            // Lower (r, c) ← upper (c, r).
            let v = upper_at(p, c, r);
            if let Some(e) = p.data.0.get_mut(c).and_then(|col| col.get_mut(r)) {
                *e = v;
            }
        }
    }
}

/// The full symmetric matrix of a covariance stored as its upper triangle (outputs, and the
/// rare paths written for a full matrix).
pub(super) fn symmetric_from_upper<T: Real, const N: usize>(
    p: &SMatrix<T, N, N>,
) -> SMatrix<T, N, N> {
    SMatrix::<T, N, N>::from_fn(|r, c| upper_at(p, r, c))
}

/// Conditions a committed covariance (stored as its upper triangle), keeping it PSD (both
/// operations map a PSD matrix to a PSD matrix): the diagonal loading of [`PSD_LOADING_EPS`],
/// then, for a variance above its ceiling (a bound no consistent covariance reaches: see
/// [`ceilings`]), row and column scaled by `√(ceiling / P_ii)` (a congruence). Keeps
/// unobservable directions from growing without bound under the loading. Returns `true` when
/// a variance was held at its ceiling.
#[inline(never)]
pub(super) fn condition<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    ceiling: &SVector<T, N>,
) -> bool {
    let load = T::one() + T::lit(PSD_LOADING_EPS) * T::EPS;
    // The loading and the comparison in one pass (scaling row and column i changes no other
    // diagonal element, so each comparison sees what it saw after a separate loading pass).
    let mut above = false;
    let [ceil] = &ceiling.data.0;
    for (i, (col, &c)) in p.data.0.iter_mut().zip(ceil.iter()).enumerate() {
        if let Some(d) = col.get_mut(i) {
            *d *= load;
            above |= *d > c;
        }
    }
    if above {
        hold_at_ceilings(p, ceiling);
    }
    above
}

/// The ceiling part of [`condition`] (rare): mirrored to the full matrix in place, then the
/// same operations in the same order as on a full symmetric matrix (the upper triangle is what
/// is kept).
#[cold]
#[inline(never)]
fn hold_at_ceilings<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>, ceiling: &SVector<T, N>) {
    mirror_upper(p);
    let full = p;
    for (i, &c) in ceiling.iter().enumerate() {
        let d = full.get((i, i)).copied().unwrap_or_else(T::zero);
        if d > c {
            let s = (c / d).sqrt();
            for j in 0..N {
                if let Some(v) = full.get_mut((i, j)) {
                    *v *= s;
                }
                if let Some(v) = full.get_mut((j, i)) {
                    *v *= s;
                }
            }
        }
    }
}

/// The report of an update that could not be fused: finite numbers only.
#[cold]
#[inline(never)]
pub(super) fn skipped_report<T: Real>(innovation: T, s: T) -> FusionReport<T> {
    let finite_or_zero = |v: T| if v.is_finite() { v } else { T::zero() };
    FusionReport {
        innovation: finite_or_zero(innovation),
        innovation_variance: finite_or_zero(s),
        nis: T::zero(),
        test_ratio: T::zero(),
        outcome: FusionOutcome::Skipped,
    }
}

/// The measurement variance of an update, raised to at least `hph / MAX_VARIANCE_REDUCTION`
/// ([`MAX_VARIANCE_REDUCTION`]; `hph = hᵀ P h`, `r` in the measurement's unit squared).
#[inline(always)]
pub(super) fn bounded_variance<T: Real>(hph: T, r: T) -> T {
    // max(r, floor) without the library call: r is finite and positive (validated at
    // construction), so a NaN floor keeps r as `max` would.
    let floor = hph * T::lit(1.0 / MAX_VARIANCE_REDUCTION);
    if floor > r {
        floor
    } else {
        r
    }
}

/// One scalar update of `x`, `P` with `b = P h`, `hph = hᵀ P h`: the measurement variance is
/// raised to at least `hph / MAX_VARIANCE_REDUCTION` ([`MAX_VARIANCE_REDUCTION`]); a numerical
/// refusal becomes a `Skipped` report (x and P untouched).
#[inline(always)]
pub(super) fn fuse_bounded<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    b: &SVector<T, N>,
    hph: T,
    innovation: T,
    r: T,
    checks: UpdateChecks<T>,
) -> FusionReport<T> {
    let r_eff = bounded_variance(hph, r);
    match fuse_rank_one(x, p, b, hph, innovation, r_eff, checks) {
        Ok(rep) => rep,
        Err(s) => skipped_report(innovation, s),
    }
}

/// Re-initialises the flexure states of (x, P) (θ parametrisation) to their stationary prior
/// after a gap longer than `max_gap_steps`, keeping θ_m = θ − θ_f with its variance grown by
/// the flexure's stationary variance (the part of θ the filter may have put in θ_m), capped at
/// the initial σ_m² plus that variance; no correlation with θ_m is kept.
#[inline(always)]
pub(super) fn reinit_flexure<T: Real, const K: usize, const N: usize>(
    chains: &[AxisChain<T, K>; 3],
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
) {
    // Written for a full matrix (a rare path): mirrored first.
    mirror_upper(p);
    let [cx, cy, cz] = chains;
    reinit_flexure_slices(
        K,
        [cx.p0.as_slice(), cy.p0.as_slice(), cz.p0.as_slice()],
        x.as_mut_slice(),
        p.as_mut_slice(),
    );
}

/// [`reinit_flexure`] on column-major slices: `k` states per axis chain, `p0` the chains'
/// k × k priors, `x` the n states, `p` the n × n covariance. A rare path (a long master
/// dropout), written once for every filter dimension. Same arithmetic in the same order as
/// the per-dimension form it replaces. (LTO may still specialise it per dimension when an
/// image calls it with constant dimensions: `nav-size`, with both filters, keeps two copies,
/// 312 B smaller in all than the two unrolled ones.)
#[cold]
#[inline(never)]
fn reinit_flexure_slices<T: Real>(k: usize, p0: [&[T]; 3], x: &mut [T], p: &mut [T]) {
    let n = x.len();
    let g = |m: &[T], r: usize, c: usize| flat_get(m, n, r, c);
    let at0 = |m: &[T], r: usize, c: usize| flat_get(m, k, r, c);
    // θ_m covariance across axes: P_θθ − P_θf − P_fθ + P_ff.
    let mut c = Matrix3::<T>::zeros();
    for a in 0..3 {
        for b in 0..3 {
            let (ta, tb) = (k * a, k * b);
            let v = g(p, ta, tb) - g(p, ta, tb + 1) - g(p, ta + 1, tb) + g(p, ta + 1, tb + 1);
            if let Some(e) = c.get_mut((a, b)) {
                *e = v;
            }
        }
    }
    let mut mount = [T::zero(); 3];
    for (a, (m, ch)) in mount.iter_mut().zip(p0.iter()).enumerate() {
        *m = x.get(k * a).copied().unwrap_or_else(T::zero)
            - x.get(k * a + 1).copied().unwrap_or_else(T::zero);
        let p0_mm = at0(ch, 0, 0);
        let var_f = at0(ch, 1, 1);
        if let Some(e) = c.get_mut((a, a)) {
            let caa = e.max(T::zero());
            *e = (caa + var_f).min((p0_mm + var_f).max(caa));
        }
    }
    // P in the θ_m parametrisation: θ_m block c, flexure blocks P0, nothing else.
    p.fill(T::zero());
    for a in 0..3 {
        for b in 0..3 {
            if let Some(e) = flat(n, k * a, k * b).and_then(|i| p.get_mut(i)) {
                *e = c.get((a, b)).copied().unwrap_or_else(T::zero);
            }
        }
        if let Some(ch) = p0.get(a) {
            for r in 1..k {
                for col in 1..k {
                    if let Some(e) = flat(n, k * a + r, k * a + col).and_then(|i| p.get_mut(i)) {
                        *e = at0(ch, r, col);
                    }
                }
            }
        }
    }
    to_theta_slices(k, n, p);
    // x ← [θ_m,X, 0 …, θ_m,Y, 0 …, θ_m,Z, 0 …]: θ = θ_m, the flexure states at their prior mean.
    for (a, m) in mount.iter().enumerate() {
        for d in 0..k {
            if let Some(e) = x.get_mut(k * a + d) {
                *e = if d == 0 { *m } else { T::zero() };
            }
        }
    }
}

/// Index of element (r, c) of a column-major d × d matrix; `None` outside it.
#[inline(always)]
fn flat(d: usize, r: usize, c: usize) -> Option<usize> {
    (r < d && c < d)
        .then(|| c.checked_mul(d).and_then(|o| o.checked_add(r)))
        .flatten()
}

/// Element (r, c) of the column-major d × d matrix `m`; 0 outside it (as `SMatrix::get`).
#[inline(always)]
fn flat_get<T: Real>(m: &[T], d: usize, r: usize, c: usize) -> T {
    flat(d, r, c)
        .and_then(|i| m.get(i).copied())
        .unwrap_or_else(T::zero)
}

/// The n × n covariance `p` (column-major, `k` states per axis chain) from the θ_m to the θ
/// parametrisation: row/column θ_a += row/column θ_f,a.
#[inline(always)]
fn to_theta_slices<T: Real>(k: usize, n: usize, p: &mut [T]) {
    for a in 0..3 {
        let (t, f) = (k * a, k * a + 1);
        for col in 0..n {
            let v = flat_get(p, n, t, col) + flat_get(p, n, f, col);
            if let Some(e) = flat(n, t, col).and_then(|i| p.get_mut(i)) {
                *e = v;
            }
        }
        for row in 0..n {
            let v = flat_get(p, n, row, t) + flat_get(p, n, row, f);
            if let Some(e) = flat(n, row, t).and_then(|i| p.get_mut(i)) {
                *e = v;
            }
        }
    }
}

/// `x ← [θ_m,X, 0 …, θ_m,Y, 0 …, θ_m,Z, 0 …]`: θ = θ_m, the flexure states at their prior mean.
pub(super) fn set_mount_only<T: Real, const K: usize, const N: usize>(
    x: &mut SVector<T, N>,
    mount_rad: &[T; 3],
) {
    for (a, m) in mount_rad.iter().enumerate() {
        for d in 0..K {
            if let Some(e) = x.get_mut(K * a + d) {
                *e = if d == 0 { *m } else { T::zero() };
            }
        }
    }
}

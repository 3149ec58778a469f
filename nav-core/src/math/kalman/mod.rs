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

use crate::math::checks::{all_finite_inline, finite};
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector};

mod joseph;
mod sparse;
#[cfg(test)]
mod tests;

use joseph::joseph_pass;
pub use sparse::{covariance_times_row, fuse_scalar_sparse, sparse_covariance_product, SparseRow};

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
    if !all_finite_inline(dx.as_slice()) {
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
    // `s·0` is ±0 for a finite s and NaN for ±∞ and NaN: one multiply and one compare instead of
    // a classification of s (≈ 30 instructions on the target).
    if s * T::zero() != T::zero() || s <= T::zero() || hph < T::zero() {
        return None;
    }
    let inv_s = T::one() / s;
    let nis = innovation * innovation * inv_s;
    let (test_ratio, rejected) = match gate {
        Gate::Off => (T::zero(), false),
        Gate::Nis(threshold) => {
            let ratio = nis / threshold;
            // A NaN ratio (the compare is false) or a non-positive threshold rejects. One
            // compare, not a three-way classification (21 → 10 instructions on the target).
            let within = ratio <= T::one();
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
    if negative || !all_finite_inline(&[sum]) {
        return Err(NavError::CovarianceNotPositiveSemiDefinite);
    }
    Ok(())
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

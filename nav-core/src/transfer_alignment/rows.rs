//! The six scalar measurement rows of an epoch: the second-order prediction of the flight
//! configuration's measurement, and the sparse updates of [`fuse_rows`] (rows with their
//! sparsity pattern known at compile time, `b = P h` from the row's columns of P only, the
//! rank-one update of [`super::fusion`]).
use super::config::MAX_ANGULAR_RATE_RAD_S;
use super::covariance::fuse_bounded;
use super::fusion::UpdateChecks;
use super::measurement::{
    bounded_misalignment, clamp_symmetric, h_row_flight_df_with, h_row_total, linear_df_dot,
    ManoeuvreTerms,
};
use super::model::{has_accel_bias, FlexureModel};
use crate::math::kalman::{FusionOutcome, FusionReport, SparseRow};
use crate::Real;
use nalgebra::{SMatrix, SVector, Vector3};

/// θ̂ of the state `x`, each axis bounded to the small-angle range: the second-order terms
/// built from it stay bounded (and finite) when the estimate has left the model (the filter
/// then reports `NeedsReinitialisation`); without the bound the quadratic term feeds back on
/// itself. (θ̇̂ is bounded to the gyro range the same way.)
#[inline(always)]
pub(super) fn bounded_theta<T: Real, const K: usize, const N: usize>(
    x: &SVector<T, N>,
) -> Vector3<T> {
    bounded_misalignment(&theta_of::<T, K, N>(x))
}

/// θ̂ of the state `x` (unbounded).
#[inline(always)]
pub(super) fn theta_of<T: Real, const K: usize, const N: usize>(x: &SVector<T, N>) -> Vector3<T> {
    let g = |i: usize| x.get(i).copied().unwrap_or_else(T::zero);
    Vector3::new(g(0), g(K), g(2 * K))
}

/// The measurement with the second-order terms of the exact kinematics removed, so that the
/// linear model `H x` predicts it to second order in θ (flight configuration). With
/// `C_m^s = exp(−[θ×]) = I − [θ×] + ½[θ×]² − …` and the slave gyro seeing `J_r(θ) θ̇_f`
/// (`J_r = I − ½[θ×] + …`):
///
/// ```text
/// dω = [θ×] ω_m − θ̇_f + ½ θ × θ̇_f − ½ θ × (θ × ω_m) + O(θ³ ω_m, θ² θ̇_f)
/// df = L_0 × θ̈_f − [f_s×] θ + ½ θ × (θ × f_s) + O(θ³ f)   (H uses f_s = C (f̃ − L_0 × θ̈_f))
/// ```
///
/// The linear rows carry everything but the ½ terms; they are evaluated at the predicted θ̂,
/// θ̇̂ and subtracted from z (five cross products). Beside an accelerometer bias, these
/// terms (θ_X θ_Z g / 2 ≈ 0.5 mm/s² with the paper's 0.5° mounting σ) are the largest
/// constant errors of the linear model.
#[inline(always)]
pub(super) fn second_order_measurement<T: Real, const K: usize, const N: usize>(
    z: &SVector<T, 6>,
    x: &SVector<T, N>,
    f_s: &Vector3<T>,
    omega_m: &Vector3<T>,
) -> SVector<T, 6> {
    let theta = bounded_theta::<T, K, N>(x);
    let g = |i: usize, lim: f64| {
        let l = T::lit(lim);
        clamp_symmetric(x.get(i).copied().unwrap_or_else(T::zero), l)
    };
    let w = MAX_ANGULAR_RATE_RAD_S;
    let rate = Vector3::new(g(2, w), g(K + 2, w), g(2 * K + 2, w));
    let half = T::lit(0.5);
    let cw = (theta.cross(&rate) - theta.cross(&theta.cross(omega_m))) * half;
    let cf = theta.cross(&theta.cross(f_s)) * half;
    SVector::<T, 6>::new(
        z.x - cw.x,
        z.y - cw.y,
        z.z - cw.z,
        z.w - cf.x,
        z.a - cf.y,
        z.b - cf.z,
    )
}

/// What the rows of an epoch are built from (validated, range-checked inputs).
#[derive(Debug, Clone, Copy)]
pub(super) struct RowInputs<T: Real> {
    /// Master angular rate ω_m, rad/s.
    pub omega_m: Vector3<T>,
    /// Master angular acceleration ω̇_m, rad/s².
    pub omega_dot_m: Vector3<T>,
    /// The specific force of the df rows' H (the compensated master's or the slave's), m/s².
    pub f_h: Vector3<T>,
    /// Lever arm L_0 from master to slave, m.
    pub lever_arm_m: Vector3<T>,
    /// Variance of the dω measurements, (rad/s)².
    pub r_rate: T,
    /// Variance of the df measurements, (m/s²)².
    pub r_accel: T,
    /// The χ² gate of every row, and where the checks of each update's result are made.
    pub checks: UpdateChecks<T>,
}

/// Fuses the six scalar measurements `z` (dω_X..Z, df_X..Z) into the predicted `x`, `P` in
/// order; one report per row, written into `updates` (the caller's slot). The rows are
/// written out with constant row indices (and the model follows from K at compile time), so
/// each row's sparsity pattern is known to the compiler. Row capacity: the flight
/// configuration's df rows 12 entries (the bias and the flexure terms of a manoeuvre;
/// innovation from the linear row, gain from the Jacobian at θ̂), its rate rows 5, the paper
/// filters' rows 4.
#[inline(always)]
pub(super) fn fuse_rows<T: Real, const K: usize, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    z: &SVector<T, 6>,
    inputs: &RowInputs<T>,
    updates: &mut [FusionReport<T>; 6],
) {
    let RowInputs {
        omega_m,
        omega_dot_m,
        f_h,
        lever_arm_m: lever,
        r_rate,
        r_accel,
        checks,
    } = *inputs;
    // The flight configuration predicts the measurement to second order in θ (the paper's
    // filters are linear in θ: exactly as specified).
    let z = if has_accel_bias::<K>() {
        second_order_measurement::<T, K, N>(z, x, &f_h, &omega_m)
    } else {
        *z
    };
    // The df rows' gain and covariance use the same second-order model's Jacobian at this θ̂
    // (flight configuration only). It takes θ̂ unbounded: on an axis beyond the small-angle
    // bound the predicted ½ term no longer depends on θ, and neither may the gain (a gain from
    // the slope at the bound let a filter thrown out of its model run away to non-finite
    // values). The manoeuvre terms are the same for the three df rows: computed once.
    let theta_hat = theta_of::<T, K, N>(x);
    let terms = if has_accel_bias::<K>() {
        ManoeuvreTerms::new(&omega_m, &omega_dot_m, &lever)
    } else {
        ManoeuvreTerms::zero()
    };
    *updates = [not_fused(); 6];
    // `b = P h` of each row, in one buffer (one slot of the frame for the six rows).
    let mut b = SVector::<T, N>::zeros();
    let model_k = model_of::<K>();
    macro_rules! fuse_row {
        ($row:literal) => {
            if has_accel_bias::<K>() && $row >= 3 {
                fuse_row!($row, flight_df);
            } else if has_accel_bias::<K>() {
                fuse_row!(
                    $row,
                    h_row_total::<T, K, 5>(model_k, $row, &omega_m, &f_h, &lever)
                );
            } else {
                fuse_row!(
                    $row,
                    h_row_total::<T, K, 4>(model_k, $row, &omega_m, &f_h, &lever)
                );
            }
        };
        ($row:literal, flight_df) => {
            if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                // Innovation z − h(x̂): the ½ term is already out of z, the linear row (the
                // Jacobian at θ̂ = 0) predicts the rest; gain and covariance from the Jacobian
                // at θ̂.
                let innovation = zi - linear_df_dot::<T, K, N>($row - 3, &f_h, &lever, &terms, x);
                let h = h_row_flight_df_with::<T, K>($row - 3, &theta_hat, &f_h, &lever, &terms);
                *rep = fuse_sparse(x, p, &h, innovation, r_accel, checks, &mut b);
            }
        };
        ($row:literal, $h:expr) => {
            if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                let h = $h;
                let r = if $row < 3 { r_rate } else { r_accel };
                *rep = fuse_sparse(x, p, &h, zi - h.dot(x), r, checks, &mut b);
            }
        };
    }
    fuse_row!(0);
    fuse_row!(1);
    fuse_row!(2);
    fuse_row!(3);
    fuse_row!(4);
    fuse_row!(5);
}

/// `b = P h` of a covariance stored as its upper triangle (column-major `p[col][row]`, rows
/// `0..=col` of each column; the lower triangle is not read): `P_ij` is read from column
/// `max(i, j)`, row `min(i, j)`. Summed as [`crate::math::kalman::covariance_times_row`]
/// sums (entries in the row's order, from 0): the same bits for a symmetric P. The entries
/// are written out one by one (at most 12, the flight configuration's df rows), so that with
/// the rows built from constant indices (the callers below) every index and branch folds.
#[inline(always)]
pub(super) fn upper_times_row<T: Real, const N: usize, const M: usize>(
    p: &SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
    out: &mut SVector<T, N>,
) {
    let cols = &p.data.0;
    let [b] = &mut out.data.0;
    // Element by element, written out (each b_i summed in a register over the row's entries,
    // in their order, from 0: the same sums as entry by entry).
    macro_rules! entries {
        ($i:ident, $acc:ident; $($t:literal)*) => {
            $(
                if $t < h.len {
                    if let (Some(&j), Some(&hj)) = (h.index.get($t), h.value.get($t)) {
                        let (c, r) = if $i <= j { (j, $i) } else { ($i, j) };
                        if let Some(&pij) = cols.get(c).and_then(|col| col.get(r)) {
                            // The sum starts from its first product, not from 0.
                            $acc = if $t == 0 { hj * pij } else { $acc + hj * pij };
                        }
                    }
                }
            )*
        };
    }
    macro_rules! elements {
        ($($i:literal)*) => {
            $(
                if $i < N {
                    if let Some(bi) = b.get_mut($i) {
                        let (i, mut acc): (usize, T) = ($i, T::zero());
                        entries!(i, acc; 0 1 2 3 4 5 6 7 8 9 10 11);
                        *bi = acc;
                    }
                }
            )*
        };
    }
    elements!(0 1 2 3 4 5 6 7 8 9 10 11 12 13 14);
    // Any further elements (N > 15; no filter of this module), in a loop.
    for (i, bi) in b.iter_mut().enumerate().skip(15) {
        let mut acc = T::zero();
        for (&j, &hj) in h.index.iter().zip(h.value.iter()).take(h.len) {
            let (c, r) = if i <= j { (j, i) } else { (i, j) };
            if let Some(&pij) = cols.get(c).and_then(|col| col.get(r)) {
                acc += hj * pij;
            }
        }
        *bi = acc;
    }
}

/// One scalar update with the sparse row `h` (built from validated, range-checked inputs with
/// in-range ascending indices by construction, tested: no per-entry validation): `b = P h`
/// from the row's columns of P (upper triangle), `hᵀ P h`, then [`fuse_bounded`].
#[inline(always)]
fn fuse_sparse<T: Real, const N: usize, const M: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
    innovation: T,
    r: T,
    checks: UpdateChecks<T>,
    b: &mut SVector<T, N>,
) -> FusionReport<T> {
    upper_times_row(p, h, b);
    let hph = h.dot(b);
    fuse_bounded(x, p, b, hph, innovation, r, checks)
}

/// The placeholder report of a row not yet fused.
#[inline(always)]
pub(super) fn not_fused<T: Real>() -> FusionReport<T> {
    FusionReport {
        innovation: T::zero(),
        innovation_variance: T::zero(),
        nis: T::zero(),
        test_ratio: T::zero(),
        outcome: FusionOutcome::Rejected,
    }
}

/// The model of a chain of K states: the paper's conventional filter has 3, the proposed and
/// the flight configuration 4 and 5.
#[inline(always)]
const fn model_of<const K: usize>() -> FlexureModel {
    if K >= 4 {
        FlexureModel::Proposed
    } else {
        FlexureModel::Conventional
    }
}

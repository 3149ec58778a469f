//! The six scalar measurement rows of an epoch: the second-order prediction of the flight
//! configuration's measurement, and the sparse updates of [`fuse_rows`] (rows with their
//! sparsity pattern known at compile time, `b = P h` from the row's columns of P only, the
//! rank-one update of [`super::fusion`]). The paper's filters (conventional and proposed) fuse
//! the rows in pairs (0-1, 2-3, 4-5) when the step defers its result checks: the second row's
//! `b` and innovation against the first update's result, then one pass over P for both
//! downdates — the bits of the six updates one after the other (a row the gate rejects takes
//! part as a null update: a pair with one row fused is that row's update alone, through the
//! same straight-line code). Their per-update path (the
//! rare rerun of an epoch) is a compact loop out of line, so that the pairs fit the filters'
//! image's flash.
use super::config::MAX_ANGULAR_RATE_RAD_S;
use super::covariance::{bounded_variance, fuse_bounded, skipped_report};
use super::fusion::{decide, downdate_one, downdate_two, Gain, Guard, UpdateChecks};
use super::measurement::{
    bounded_misalignment, clamp_symmetric, h_row_flight_df_with, h_row_total, linear_df_dot,
    ManoeuvreTerms,
};
use super::model::{has_accel_bias, FlexureModel};
use super::rate_row::{h_row_flight_rate_with, RateJacobianAt};
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

impl<T: Real> RowInputs<T> {
    /// A paper filter's row `row` (0-2: dω, 3-5: df) over chains of `K` states: its `H` (the
    /// model of `K`, up to 4 entries) and its noise variance.
    #[inline(always)]
    fn paper_row<const K: usize>(&self, row: usize) -> (SparseRow<T, 4>, T) {
        let h = h_row_total::<T, K, 4>(
            model_of::<K>(),
            row,
            &self.omega_m,
            &self.f_h,
            &self.lever_arm_m,
        );
        (h, if row < 3 { self.r_rate } else { self.r_accel })
    }
}

/// Fuses the six scalar measurements `z` (dω_X..Z, df_X..Z) into the predicted `x`, `P` in
/// order; one report per row, written into `updates` (the caller's slot). The rows are
/// written out with constant row indices (and the model follows from K at compile time), so
/// each row's sparsity pattern is known to the compiler. Row capacity: the flight
/// configuration's df rows 12 entries (the bias and the flexure terms of a manoeuvre), its rate
/// rows 6, the paper filters' rows 4. The flight configuration's rows take the innovation
/// `z − h(x̂)` as the ½ terms out of z and the linear row (the Jacobian at θ̂ = 0, θ̇̂_f = 0) for
/// the rest, and the gain and covariance from the Jacobian at the predicted state (θ̂ for the
/// df rows, θ̂ and θ̇̂_f for the rate rows: `super::rate_row`).
#[inline(always)]
pub(super) fn fuse_rows<T: Real, const K: usize, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    z: &SVector<T, 6>,
    inputs: &RowInputs<T>,
    updates: &mut [FusionReport<T>; 6],
) {
    if pairs_rows::<K, N>() {
        // The paper's filters: with deferred checks the rows in pairs, each pair's downdate in
        // one pass; the per-update checks (the rare rerun of an epoch whose deferred check
        // failed) one row after the other, out of line and compact.
        return if inputs.checks.guard == Guard::Deferred {
            fuse_rows_paired::<T, K, N>(x, p, z, inputs, updates)
        } else {
            fuse_rows_each::<T, K, N>(x, p, z, inputs, updates)
        };
    }
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
    let (theta_hat, terms, rate_at) = jacobian_inputs::<T, K, N>(x, &omega_m, &omega_dot_m, &lever);
    *updates = [not_fused(); 6];
    // `b = P h` of each row, in one buffer (one slot of the frame for the six rows).
    let mut b = SVector::<T, N>::zeros();
    let model_k = model_of::<K>();
    macro_rules! fuse_row {
        ($row:literal) => {
            if has_accel_bias::<K>() && $row >= 3 {
                fuse_row!($row, flight_df);
            } else if has_accel_bias::<K>() {
                fuse_row!($row, flight_rate);
            } else {
                fuse_row!(
                    $row,
                    h_row_total::<T, K, 4>(model_k, $row, &omega_m, &f_h, &lever)
                );
            }
        };
        ($row:literal, flight_df) => {
            if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                let innovation = zi - linear_df_dot::<T, K, N>($row - 3, &f_h, &lever, &terms, x);
                let h = h_row_flight_df_with::<T, K>($row - 3, &theta_hat, &f_h, &lever, &terms);
                *rep = fuse_sparse(x, p, &h, innovation, r_accel, checks, &mut b);
            }
        };
        ($row:literal, flight_rate) => {
            if let (Some(rep), Some(&zi)) = (updates.get_mut($row), z.as_slice().get($row)) {
                let lin = h_row_total::<T, K, 3>(model_k, $row, &omega_m, &f_h, &lever);
                let h = h_row_flight_rate_with::<T, K>($row, &rate_at, &omega_m);
                *rep = fuse_sparse(x, p, &h, zi - lin.dot(x), r_rate, checks, &mut b);
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

/// `true` for the filters that fuse their rows in pairs with deferred checks
/// ([`fuse_rows_paired`]): the paper's filters (chains of 3 or 4 states, N ≤ 12). The flight
/// configuration fuses them one by one (its df rows carry up to 12 entries).
#[inline(always)]
pub(super) const fn pairs_rows<const K: usize, const N: usize>() -> bool {
    K <= 4 && N <= 12
}

/// [`fuse_rows`] of a paper filter with [`Guard::PerUpdate`]: the six rows one after the
/// other, each row's `b = P h` in a loop ([`upper_times_row_loop`], the same sums), the update
/// [`fuse_bounded`]: the bits of the straight-line rows. The rerun of an epoch whose deferred
/// check failed (rare): out of line, compact, one copy per filter.
#[cold]
#[inline(never)]
fn fuse_rows_each<T: Real, const K: usize, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    z: &SVector<T, 6>,
    inputs: &RowInputs<T>,
    updates: &mut [FusionReport<T>; 6],
) {
    let mut b = SVector::<T, N>::zeros();
    for (row, (rep, &zi)) in updates.iter_mut().zip(z.iter()).enumerate() {
        let (h, r) = inputs.paper_row::<K>(row);
        upper_times_row_loop(p, &h, &mut b);
        let hph = h.dot(&b);
        *rep = fuse_bounded(x, p, &b, hph, zi - h.dot(x), r, inputs.checks);
    }
}

/// [`upper_times_row`] in loops (a row known only at run time): the same sums in the same
/// order (each `b_i` from its first product, entries in the row's order), the same bits —
/// entry by entry over P's column `j` (rows `0..=j` stored in column `j`, the rest in row `j`
/// of the later columns), so that each loop is one load, one multiply-add and one store.
/// Out of line: one copy per filter serves its rare paths (the rerun's rows one by one, a
/// pair's second row when the first is not fused).
#[inline(never)]
fn upper_times_row_loop<T: Real, const N: usize, const M: usize>(
    p: &SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
    out: &mut SVector<T, N>,
) {
    let cols = &p.data.0;
    let [b] = &mut out.data.0;
    if h.len == 0 {
        b.fill(T::zero());
    }
    for (t, (j, hj)) in h.entries().enumerate() {
        let Some(col) = cols.get(j) else {
            continue;
        };
        // P_ij for i ≤ j from column j, for i > j from column i, row j.
        let upper = col.iter().take(j + 1).copied();
        let lower = cols
            .iter()
            .skip(j + 1)
            .map(|c| c.get(j).copied().unwrap_or_else(T::zero));
        for (bi, pij) in b.iter_mut().zip(upper.chain(lower)) {
            *bi = if t == 0 { hj * pij } else { *bi + hj * pij };
        }
    }
}

/// What the flight configuration's df rows' Jacobian is evaluated with: θ̂ of `x` and the
/// manoeuvre terms (zero in the paper's filters). The df rows' gain and covariance use the same
/// second-order model's Jacobian at this θ̂, taken unbounded: on an axis beyond the small-angle
/// bound the predicted ½ term no longer depends on θ, and neither may the gain (a gain from the
/// slope at the bound let a filter thrown out of its model run away to non-finite values). The
/// manoeuvre terms are the same for the three df rows: computed once. With them, what the rate
/// rows' Jacobian is evaluated at.
#[inline(always)]
fn jacobian_inputs<T: Real, const K: usize, const N: usize>(
    x: &SVector<T, N>,
    omega_m: &Vector3<T>,
    omega_dot_m: &Vector3<T>,
    lever: &Vector3<T>,
) -> (Vector3<T>, ManoeuvreTerms<T>, RateJacobianAt<T>) {
    let terms = if has_accel_bias::<K>() {
        ManoeuvreTerms::new(omega_m, omega_dot_m, lever)
    } else {
        ManoeuvreTerms::zero()
    };
    (theta_of::<T, K, N>(x), terms, RateJacobianAt::of::<K, N>(x))
}

/// [`fuse_rows`] of a paper filter with [`Guard::Deferred`]: the rows in pairs (0-1, 2-3, 4-5,
/// [`fuse_pair`]), each report written into its slot of `updates`. Not inlined: one copy per
/// filter, not one per caller of the step (inlined, the filters' image grew by 15 KB).
#[inline(never)]
fn fuse_rows_paired<T: Real, const K: usize, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    z: &SVector<T, 6>,
    inputs: &RowInputs<T>,
    updates: &mut [FusionReport<T>; 6],
) {
    let checks = inputs.checks;
    macro_rules! pair {
        (row $row:literal) => {{
            let (h, r) = inputs.paper_row::<K>($row);
            let z = z.as_slice().get($row).copied().unwrap_or_else(T::zero);
            PairRow { h, z, r }
        }};
        ($first:literal, $second:literal) => {
            let rows = [pair!(row $first), pair!(row $second)];
            let (head, tail) = updates.split_at_mut($second);
            if let (Some(u1), Some(u2)) = (head.get_mut($first), tail.first_mut()) {
                fuse_pair(x, p, &rows, checks, [u1, u2]);
            }
        };
    }
    pair!(0, 1);
    pair!(2, 3);
    pair!(4, 5);
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
    upper_times_row_with(p, h, out, |_, _, pij| pij);
}

/// [`upper_times_row`] of the covariance whose stored element `(r, c)` (`r ≤ c`) is
/// `elem(r, c, P_rc)` (inlined: with constant indices the closure folds).
#[inline(always)]
fn upper_times_row_with<T: Real, const N: usize, const M: usize>(
    p: &SMatrix<T, N, N>,
    h: &SparseRow<T, M>,
    out: &mut SVector<T, N>,
    elem: impl Fn(usize, usize, T) -> T,
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
                        if let Some(&stored) = cols.get(c).and_then(|col| col.get(r)) {
                            let pij = elem(r, c, stored);
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
            if let Some(&stored) = cols.get(c).and_then(|col| col.get(r)) {
                acc += hj * elem(r, c, stored);
            }
        }
        *bi = acc;
    }
}

/// One row of a pair ([`fuse_pair`]): its sparse `h`, the measurement `z` (rad/s or m/s²) and
/// its variance `r` (the unit squared).
struct PairRow<T, const M: usize> {
    h: SparseRow<T, M>,
    z: T,
    r: T,
}

/// Two consecutive scalar updates ([`Guard::Deferred`]), the same bits as [`fuse_sparse`]
/// twice: the second row's innovation and `b = P h` are formed against the first update's
/// result (the state entries and covariance elements they read, with the first update's own
/// expressions), then both downdates run in one pass ([`downdate_two`]). When one row is not
/// fused (rejected by the gate or refused), the other's update runs alone: the first's
/// straight-line ([`downdate_one`]) when the second is not fused; the second's out of line
/// ([`second_row_alone`]: its `b = P h` in the loop form) when the first is not fused. The two
/// reports are written into `u1`, `u2` (the caller's slots).
#[inline(always)]
fn fuse_pair<T: Real, const N: usize, const M: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    [first, second]: &[PairRow<T, M>; 2],
    checks: UpdateChecks<T>,
    [u1, u2]: [&mut FusionReport<T>; 2],
) {
    let nu1 = first.z - first.h.dot(x);
    // `b = P h` of the two rows: each zeroed right before the product writes every element
    // (the zeros are dead stores the compiler drops).
    let mut b1 = SVector::<T, N>::zeros();
    upper_times_row(p, &first.h, &mut b1);
    let b1 = &b1;
    let hph1 = first.h.dot(b1);
    let r1 = bounded_variance(hph1, first.r);
    let d1 = decide(hph1, nu1, r1, checks.gate);
    let inv1 = fused_inv_s(&d1);
    put_report(u1, report_of(d1, nu1));
    let Some(inv1) = inv1 else {
        // The first row not fused (rare): the second alone, out of line.
        return second_row_alone(x, p, second.h, [second.z, second.r], checks, u2);
    };
    // x⁺ on the row's entries, and P⁺ = P − k1 b1ᵀ element by element as the downdate writes
    // them (`k1_r = b1_r / s1`, row r ≤ column c).
    let at = |i: usize| b1.get(i).copied().unwrap_or_else(T::zero);
    let mut acc = T::zero();
    for (j, hj) in second.h.entries() {
        let xj = x.get(j).copied().unwrap_or_else(T::zero);
        acc += hj * (xj + at(j) * inv1 * nu1);
    }
    let mut b2 = SVector::<T, N>::zeros();
    upper_times_row_with(p, &second.h, &mut b2, |r, c, v| v - at(r) * inv1 * at(c));
    let nu2 = second.z - acc;
    let hph2 = second.h.dot(&b2);
    let r2 = bounded_variance(hph2, second.r);
    let d2 = decide(hph2, nu2, r2, checks.gate);
    let inv2 = fused_inv_s(&d2);
    put_report(u2, report_of(d2, nu2));
    // The second row not fused (rare): the first's update alone, straight-line.
    let g1 = Gain {
        inv_s: inv1,
        innovation: nu1,
    };
    let (x, p) = (&mut x.data.0[0], &mut p.data.0);
    match inv2 {
        Some(inv_s) => {
            let g2 = Gain {
                inv_s,
                innovation: nu2,
            };
            downdate_two(x, p, &b1.data.0[0], &b2.data.0[0], [g1, g2]);
        }
        None => downdate_one(x, p, &b1.data.0[0], g1),
    }
}

/// A pair's second row (`h`, `[z, r]`) when the first is not fused (rare): `b = P h` in the
/// loop form ([`upper_times_row_loop`], the same sums), then the row's update alone
/// ([`fuse_bounded`]: the same decision, the straight-line [`super::fusion::downdate_one`]),
/// its report into `u2`. Out of line, so that the common path's `b` needs no zeroing; the row
/// by value, so that the common path does not build it in memory.
#[cold]
#[inline(never)]
fn second_row_alone<T: Real, const N: usize, const M: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    h: SparseRow<T, M>,
    [z, r]: [T; 2],
    checks: UpdateChecks<T>,
    u2: &mut FusionReport<T>,
) {
    let mut b2 = SVector::<T, N>::zeros();
    upper_times_row_loop(p, &h, &mut b2);
    let nu2 = z - h.dot(x);
    *u2 = fuse_bounded(x, p, &b2, h.dot(&b2), nu2, r, checks);
}

/// `1/s` of a decision to fuse.
#[inline(always)]
fn fused_inv_s<T: Real>(d: &Result<(FusionReport<T>, T), T>) -> Option<T> {
    match d {
        Ok((rep, inv_s)) if rep.outcome == FusionOutcome::Fused => Some(*inv_s),
        _ => None,
    }
}

/// Writes `rep` into the slot `u` field by field (so that the report is built in registers
/// and stored once, not built in the frame and copied).
#[inline(always)]
fn put_report<T: Real>(u: &mut FusionReport<T>, rep: FusionReport<T>) {
    u.innovation = rep.innovation;
    u.innovation_variance = rep.innovation_variance;
    u.nis = rep.nis;
    u.test_ratio = rep.test_ratio;
    u.outcome = rep.outcome;
}

/// The report of a decision (a numerical refusal: `Skipped`).
#[inline(always)]
fn report_of<T: Real>(d: Result<(FusionReport<T>, T), T>, innovation: T) -> FusionReport<T> {
    match d {
        Ok((rep, _)) => rep,
        Err(s) => skipped_report(innovation, s),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The loop form of `b = P h` gives the bits of the straight-line one, for rows of 1 to 5
    /// entries over the upper triangle of a 9-, 12- and 15-state covariance.
    fn loop_matches_straight_line<const N: usize>() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 40) as f32) / ((1u64 << 24) as f32) * 2.0 - 1.0
        };
        for len in 1..=5usize {
            let p = SMatrix::<f32, N, N>::from_fn(|_, _| next());
            let mut h = SparseRow::<f32, 5>::new();
            for t in 0..len {
                // Ascending, in range: columns t·(N/5) + 1.
                assert!(h.push(t * (N / 5) + 1, next()).is_ok());
            }
            let (mut a, mut b) = (SVector::<f32, N>::zeros(), SVector::<f32, N>::zeros());
            upper_times_row(&p, &h, &mut a);
            upper_times_row_loop(&p, &h, &mut b);
            let bits =
                |v: &SVector<f32, N>| v.iter().map(|e| e.to_bits()).collect::<std::vec::Vec<_>>();
            assert_eq!(bits(&a), bits(&b), "N {N}, {len} entries");
            assert!(a.iter().any(|e| *e != 0.0));
        }
    }

    #[test]
    fn row_product_loop_and_straight_line_agree() {
        loop_matches_straight_line::<9>();
        loop_matches_straight_line::<12>();
        loop_matches_straight_line::<15>();
    }
}

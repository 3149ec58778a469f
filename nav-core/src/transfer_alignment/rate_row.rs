//! The flight configuration's rate rows: their Jacobian at the predicted state.
//!
//! The rate rows predict `dω = ω_m − ω_s` to second order in θ (see
//! [`super::rows::second_order_measurement`]):
//!
//! ```text
//! dω = −[ω_m×] θ − θ̇_f + ½ θ × θ̇_f − ½ θ × (θ × ω_m)
//! ```
//!
//! The innovation takes the ½ terms at the predicted state out of `z` and the linear row (the
//! Jacobian at θ = 0, θ̇_f = 0) predicts the rest; the gain and the covariance take the
//! Jacobian of the whole prediction at the predicted state. Of its second-order parts only one
//! is not small: `∂(½ θ × θ̇_f)/∂θ = −½ [θ̇_f×]`, beside `−[ω_m×]`. In level flight ω_m is near
//! zero while the wing's flexure rate θ̇_f is not (its σ is of the order of the flexure angle's
//! σ over τ), so the linear row's θ columns are then wrong by all of their value. The other
//! parts are of the order of θ (mrad) against the entries they sit beside: `½ [θ×]` on the
//! θ̇_f columns and `−½ ∂(θ × (θ × ω_m))/∂θ` on the θ columns.
//!
//! θ̂ and θ̇̂_f enter bounded, as in the predicted terms: on an axis beyond its bound the
//! prediction no longer depends on that state, and neither does the row.

use super::config::{MAX_ANGULAR_RATE_RAD_S, MAX_MISALIGNMENT_RAD};
use super::measurement::{bounded_misalignment, clamp_symmetric};
use crate::math::kalman::SparseRow;
use crate::Real;
use nalgebra::{SVector, Vector3};

/// Entries of a flight rate row: θ and θ̇_f of the three axes.
pub(super) const RATE_ROW_ENTRIES: usize = 6;

/// What the rate rows' Jacobian is evaluated at: θ̂ and θ̇̂_f of the predicted state (unbounded:
/// each is bounded where it is used), chains of `K` states `[θ, θ_f, θ̇_f, …]`.
#[derive(Debug, Clone, Copy)]
pub(super) struct RateJacobianAt<T: Real> {
    /// θ̂, rad.
    pub theta: Vector3<T>,
    /// θ̇̂_f, rad/s.
    pub flexure_rate: Vector3<T>,
}

impl<T: Real> RateJacobianAt<T> {
    /// θ̂ and θ̇̂_f of `x`.
    #[inline(always)]
    pub(super) fn of<const K: usize, const N: usize>(x: &SVector<T, N>) -> Self {
        let g = |i: usize| x.get(i).copied().unwrap_or_else(T::zero);
        Self {
            theta: Vector3::new(g(0), g(K), g(2 * K)),
            flexure_rate: Vector3::new(g(2), g(K + 2), g(2 * K + 2)),
        }
    }
}

/// `[v×]_{ia}`, the entry of the cross-product matrix of `v` (`[v×] u = v × u`).
#[inline(always)]
fn cross_entry<T: Real>(v: &Vector3<T>, i: usize, a: usize) -> T {
    let c = |k: usize| v.get(k).copied().unwrap_or_else(T::zero);
    match (i, a) {
        (0, 1) => -c(2),
        (0, 2) => c(1),
        (1, 0) => c(2),
        (1, 2) => -c(0),
        (2, 0) => -c(1),
        (2, 1) => c(0),
        _ => T::zero(),
    }
}

/// Row `i` (0-2) of the rate rows' Jacobian at `at` (module doc), master rate `omega_m` rad/s:
/// on θ_a `−[ω_m×]_{ia} − ½ [θ̇_f×]_{ia} − ½ ∂(θ × (θ × ω_m))_i/∂θ_a`, on θ̇_f,a
/// `−δ_{ia} + ½ [θ×]_{ia}`, the second-order parts zero where their state is beyond its bound.
#[inline(always)]
pub(super) fn h_row_flight_rate_with<T: Real, const K: usize>(
    i: usize,
    at: &RateJacobianAt<T>,
    omega_m: &Vector3<T>,
) -> SparseRow<T, RATE_ROW_ENTRIES> {
    let half = T::lit(0.5);
    let rate_limit = T::lit(MAX_ANGULAR_RATE_RAD_S);
    let c = bounded_misalignment(&at.theta);
    let r = at.flexure_rate.map(|v| clamp_symmetric(v, rate_limit));
    let comp = |v: &Vector3<T>, k: usize| v.get(k).copied().unwrap_or_else(T::zero);
    let (c_i, w_i) = (comp(&c, i), comp(omega_m, i));
    let c_dot_w = c.dot(omega_m);
    let mut h = SparseRow::<T, RATE_ROW_ENTRIES>::new();
    // Two entries per axis: `push` cannot fail.
    for a in 0..3 {
        let (c_a, w_a) = (comp(&c, a), comp(omega_m, a));
        // ∂(½ θ × θ̇_f − ½ θ × (θ × ω_m))_i/∂θ_a.
        let mut second =
            -half * cross_entry(&r, i, a) - half * (c_i * w_a - T::lit(2.0) * w_i * c_a);
        if a == i {
            second -= half * c_dot_w;
        }
        if comp(&at.theta, a).abs() > T::lit(MAX_MISALIGNMENT_RAD) {
            second = T::zero();
        }
        let _ = h.push(K * a, second - cross_entry(omega_m, i, a));
        // ∂(½ θ × θ̇_f)_i/∂θ̇_f,a.
        let mut rate_part = half * cross_entry(&c, i, a);
        if comp(&at.flexure_rate, a).abs() > rate_limit {
            rate_part = T::zero();
        }
        let own = if a == i { T::one() } else { T::zero() };
        let _ = h.push(K * a + 2, rate_part - own);
    }
    h
}

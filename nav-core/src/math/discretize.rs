//! Exact discretisation of a linear time-invariant stochastic system.
//!
//! For `ẋ = F x + w`, `E[w(t) w(τ)ᵀ] = Q_c δ(t − τ)`, sampled every `Δt`:
//!
//! ```text
//! Φ   = exp(F Δt)
//! Q_d = ∫₀^Δt exp(F s) Q_c exp(Fᵀ s) ds
//! ```
//!
//! This is what Van Loan's method computes from the 2N×2N block exponential; here the same two
//! matrices come from N×N work only, by scaling and squaring: for `h = Δt / 2^k` with
//! `‖F‖ h ≤ 1/4`, Taylor series give `Φ(h)` and
//! `Q_d(h) = Σ_j L^j(Q_c) h^{j+1}/(j+1)!` with `L(X) = F X + X Fᵀ`; then k doublings
//! `Q_d(2h) = Q_d(h) + Φ(h) Q_d(h) Φ(h)ᵀ`, `Φ(2h) = Φ(h)²`. Both series are truncated where the
//! next term is below machine precision (at most [`MAX_TAYLOR_TERMS`]).
//!
//! Intended for configuration time (fixed-rate filters compute Φ and Q_d once); it is
//! allocation-free and bounded, so it may also run on the target.

use crate::{NavError, Real};
use nalgebra::SMatrix;

/// Upper bound on Taylor terms in [`discretize`].
pub const MAX_TAYLOR_TERMS: u32 = 20;
/// Upper bound on squarings in [`discretize`] (`‖F‖ Δt` up to 2^30 / 4).
pub const MAX_SQUARINGS: u32 = 30;

/// Infinity norm (max absolute row sum).
pub fn norm_inf<T: Real, const N: usize, const M: usize>(a: &SMatrix<T, N, M>) -> T {
    a.row_iter()
        .map(|r| r.iter().fold(T::zero(), |s, v| s + v.abs()))
        .fold(T::zero(), |m, v| if v > m { v } else { m })
}

/// Discrete transition matrix Φ and process-noise covariance Q_d of `(F, Q_c)` over `dt_s`.
///
/// `q_c` is the power spectral density of the white process noise (units of x² per s).
/// Errors: `InvalidTimeStep` unless `dt_s` is finite and positive, `NonFiniteInput` for NaN/Inf
/// in `F` or `Q_c`, `NotConverged` if `‖F‖ Δt` is too large for [`MAX_SQUARINGS`].
pub fn discretize<T: Real, const N: usize>(
    f: &SMatrix<T, N, N>,
    q_c: &SMatrix<T, N, N>,
    dt_s: T,
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>), NavError> {
    if !dt_s.is_finite() || dt_s <= T::zero() {
        return Err(NavError::InvalidTimeStep);
    }
    if !f.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "F" });
    }
    if !q_c.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "Q_c" });
    }
    let norm = norm_inf(f) * dt_s;
    let mut squarings = 0u32;
    let mut h = dt_s;
    let mut scaled = norm;
    let quarter = T::lit(0.25);
    while scaled > quarter {
        if squarings >= MAX_SQUARINGS {
            return Err(NavError::NotConverged {
                iterations: squarings,
            });
        }
        scaled *= T::lit(0.5);
        h *= T::lit(0.5);
        squarings += 1;
    }

    // Taylor series at step h.
    let fh = f * h;
    let mut phi = SMatrix::<T, N, N>::identity();
    let mut term_phi = SMatrix::<T, N, N>::identity();
    // term_q_j = L^j(Q_c) h^{j+1}/(j+1)!
    let mut term_q = q_c * h;
    let mut qd = term_q;
    let eps = T::EPS;
    let phi_scale = T::one();
    let q_scale = norm_inf(&term_q);
    for j in 1..=MAX_TAYLOR_TERMS {
        let jt = T::lit(f64::from(j));
        term_phi = fh * term_phi / jt;
        phi += term_phi;
        // L(term)·h/(j+1): FX + XFᵀ scaled by h/(j+1).
        let jp1 = T::lit(f64::from(j + 1));
        term_q = (fh * term_q + term_q * fh.transpose()) / jp1;
        qd += term_q;
        let small_phi = norm_inf(&term_phi) <= eps * phi_scale;
        let small_q = norm_inf(&term_q) <= eps * q_scale;
        if small_phi && small_q {
            break;
        }
    }

    for _ in 0..squarings {
        qd += phi * qd * phi.transpose();
        phi = phi * phi;
    }
    // Enforce exact symmetry of the covariance.
    let qd = (qd + qd.transpose()) * T::lit(0.5);
    Ok((phi, qd))
}

/// Stationary covariance P of the stable discrete system `x_{k+1} = Φ x_k + w_k`,
/// `cov(w) = Q_d`: the solution of `P = Φ P Φᵀ + Q_d`, by the doubling iteration
/// `P ← P + A P Aᵀ`, `A ← A²` (each pass doubles the number of summed terms).
///
/// Errors with `NotConverged` if Φ is not (numerically) stable within `max_doublings`.
pub fn stationary_covariance<T: Real, const N: usize>(
    phi: &SMatrix<T, N, N>,
    q_d: &SMatrix<T, N, N>,
    max_doublings: u32,
) -> Result<SMatrix<T, N, N>, NavError> {
    let mut a = *phi;
    let mut p = *q_d;
    for i in 0..max_doublings {
        let increment = a * p * a.transpose();
        p += increment;
        a = a * a;
        if !p.iter().all(|v| v.is_finite()) {
            return Err(NavError::NotConverged { iterations: i + 1 });
        }
        if norm_inf(&increment) <= T::EPS * norm_inf(&p) && norm_inf(&a) < T::lit(1e-3) {
            return Ok((p + p.transpose()) * T::lit(0.5));
        }
    }
    Err(NavError::NotConverged {
        iterations: max_doublings,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1, Matrix2, Matrix3};

    #[test]
    fn first_order_markov_closed_form() {
        // ẋ = −β x + w, q = 2βσ²: Φ = e^{−βΔt}, Q_d = σ² (1 − e^{−2βΔt}).
        let (beta, sigma, dt) = (0.7_f64, 3.0, 0.37);
        let (phi, qd) = discretize(
            &Matrix1::new(-beta),
            &Matrix1::new(2.0 * beta * sigma * sigma),
            dt,
        )
        .unwrap();
        assert!((phi[0] - (-beta * dt).exp()).abs() < 1e-15);
        let exact = sigma * sigma * (1.0 - (-2.0 * beta * dt).exp());
        assert!((qd[0] - exact).abs() < 1e-13 * exact, "{} {}", qd[0], exact);
    }

    #[test]
    fn double_integrator_closed_form() {
        // ẋ = [0 1; 0 0] x + [0; w]: Q_d = q [Δt³/3 Δt²/2; Δt²/2 Δt] (f32 and f64).
        let (q, dt) = (0.2_f64, 1.7);
        let f = Matrix2::new(0.0, 1.0, 0.0, 0.0);
        let (phi, qd) = discretize(&f, &Matrix2::new(0.0, 0.0, 0.0, q), dt).unwrap();
        assert!((phi - Matrix2::new(1.0, dt, 0.0, 1.0)).abs().max() < 1e-14);
        let exact = Matrix2::new(
            q * dt.powi(3) / 3.0,
            q * dt * dt / 2.0,
            q * dt * dt / 2.0,
            q * dt,
        );
        assert!((qd - exact).abs().max() < 1e-14);
        let f32m = Matrix2::new(0.0f32, 1.0, 0.0, 0.0);
        let (_, qd32) =
            discretize(&f32m, &Matrix2::new(0.0, 0.0, 0.0, q as f32), dt as f32).unwrap();
        assert!((qd32[(0, 0)] as f64 - exact[(0, 0)]).abs() < 1e-6);
    }

    #[test]
    fn large_step_needs_squaring_and_matches_exponential() {
        // Damped oscillator with ‖F‖Δt ≫ 1: compare Φ with the analytic exponential.
        let (wn, zeta, dt) = (5.0_f64, 0.1, 3.0);
        let f = Matrix2::new(0.0, 1.0, -wn * wn, -2.0 * zeta * wn);
        let (phi, qd) = discretize(&f, &Matrix2::new(0.0, 0.0, 0.0, 1.0), dt).unwrap();
        let wd = wn * (1.0 - zeta * zeta).sqrt();
        let e = (-zeta * wn * dt).exp();
        let (s, c) = ((wd * dt).sin(), (wd * dt).cos());
        let exact = Matrix2::new(
            e * (c + zeta * wn / wd * s),
            e * s / wd,
            -e * wn * wn / wd * s,
            e * (c - zeta * wn / wd * s),
        );
        assert!((phi - exact).abs().max() < 1e-12, "{phi} {exact}");
        // For a stable system Q_d = P∞ − Φ P∞ Φᵀ, with P∞ = diag(q/(4ζω³), q/(4ζω)).
        let p_inf = Matrix2::new(
            1.0 / (4.0 * zeta * wn.powi(3)),
            0.0,
            0.0,
            1.0 / (4.0 * zeta * wn),
        );
        let exact_qd = p_inf - exact * p_inf * exact.transpose();
        assert!(
            (qd - exact_qd).abs().max() < 1e-12 * p_inf.max(),
            "{qd} {exact_qd}"
        );
    }

    #[test]
    fn stationary_covariance_of_markov_chain() {
        // 2nd-order Gauss-Markov: stationary var θ = σ², var θ̇ = β²σ², cov = 0.
        let (beta, sigma, dt) = (2.0_f64, 0.5, 0.01);
        let f = Matrix2::new(0.0, 1.0, -beta * beta, -2.0 * beta);
        let qc = Matrix2::new(0.0, 0.0, 0.0, 4.0 * beta.powi(3) * sigma * sigma);
        let (phi, qd) = discretize(&f, &qc, dt).unwrap();
        let p = stationary_covariance(&phi, &qd, 64).unwrap();
        assert!((p[(0, 0)] - sigma * sigma).abs() < 1e-10);
        assert!((p[(1, 1)] - beta * beta * sigma * sigma).abs() < 1e-10);
        assert!(p[(0, 1)].abs() < 1e-10);
        // An unstable system does not converge.
        let unstable = Matrix3::identity() * 1.01;
        assert!(matches!(
            stationary_covariance(&unstable, &Matrix3::identity(), 20),
            Err(NavError::NotConverged { .. })
        ));
    }

    #[test]
    fn rejects_bad_input() {
        let f = Matrix1::new(-1.0_f64);
        let q = Matrix1::new(1.0);
        assert_eq!(discretize(&f, &q, 0.0), Err(NavError::InvalidTimeStep));
        assert_eq!(discretize(&f, &q, f64::NAN), Err(NavError::InvalidTimeStep));
        assert!(discretize(&Matrix1::new(f64::NAN), &q, 0.1).is_err());
        assert!(discretize(&f, &Matrix1::new(f64::INFINITY), 0.1).is_err());
    }
}

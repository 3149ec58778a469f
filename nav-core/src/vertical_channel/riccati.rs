//! Continuous algebraic Riccati equation (filter form) for the 3-state vertical channel.
//!
//! Solves the **continuous** ARE of the spec (seed eq. 9, with a general `R`):
//!
//! ```text
//! A P + P Aᵀ + Q − P Cᵀ R⁻¹ C P = 0,       K = P Cᵀ R⁻¹          (seed eq. 8)
//! ```
//!
//! with `Q = B Q_w Bᵀ` (the process-noise PSD mapped onto the states), `C` an `M × 3` output
//! matrix and `R = diag(r)` the measurement-noise PSDs. The stabilising solution `P ≥ 0` is
//! found with the **matrix sign function** of the 6×6 Hamiltonian
//!
//! ```text
//! H = | Aᵀ   −Cᵀ R⁻¹ C |
//!     | −Q   −A        |
//! ```
//!
//! by the Newton iteration `Z ← (μ Z + (μ Z)⁻¹) / 2` with determinant scaling
//! `μ = |det Z|^(−1/6)` (Roberts 1971, Byers 1987). With `W = sign(H)`, P solves the
//! over-determined system `[W₁₂; W₂₂ + I] P = −[W₁₁ + I; W₂₁]` (solved here by its normal
//! equations). The result is accepted only if the iteration converged, the relative residual
//! of the ARE is below `√ε` of the working type and the closed loop `A − K C` is Hurwitz (Routh);
//! otherwise a typed error is returned.
//!
//! Everything is fixed-size (nalgebra static matrices), nothing allocates; intended for
//! configuration time (the loops call it in `f64` even when they run in `f32`).

use crate::math::linalg::inverse_and_determinant;
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, SVector};

/// Upper bound on sign-function iterations (quadratic convergence needs far fewer).
pub const MAX_SIGN_ITERATIONS: u32 = 100;

/// Solution of the continuous ARE.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct CareSolution<T: Real, const M: usize> {
    /// Stabilising solution P (symmetric, ≥ 0): steady-state error covariance, state units².
    pub p: Matrix3<T>,
    /// Steady-state gain `K = P Cᵀ R⁻¹` (3 × M).
    pub gain: SMatrix<T, 3, M>,
    /// Sign-function iterations used.
    pub iterations: u32,
    /// `‖A P + P Aᵀ + Q − P G P‖₁ / (‖A P‖₁ + ‖P Aᵀ‖₁ + ‖Q‖₁ + ‖P G P‖₁)`.
    pub relative_residual: T,
}

/// 1-norm (max absolute column sum).
fn norm1<T: Real, const R: usize, const C: usize>(a: &SMatrix<T, R, C>) -> T {
    a.column_iter()
        .map(|c| c.iter().fold(T::zero(), |s, v| s + v.abs()))
        .fold(T::zero(), |m, v| if v > m { v } else { m })
}

/// Coefficients `[a₂, a₁, a₀]` of the characteristic polynomial `s³ + a₂ s² + a₁ s + a₀` of a
/// 3×3 matrix (`a₂ = −tr F`, `a₁` = sum of the principal 2×2 minors, `a₀ = −det F`).
pub fn char_poly3<T: Real>(f: &Matrix3<T>) -> [T; 3] {
    let a2 = -(f.m11 + f.m22 + f.m33);
    let a1 = (f.m11 * f.m22 - f.m12 * f.m21)
        + (f.m11 * f.m33 - f.m13 * f.m31)
        + (f.m22 * f.m33 - f.m23 * f.m32);
    let a0 = -f.determinant();
    [a2, a1, a0]
}

/// `true` when every eigenvalue of the 3×3 matrix has a negative real part (Routh-Hurwitz:
/// `a₂ > 0, a₀ > 0, a₂ a₁ > a₀`).
pub fn is_hurwitz3<T: Real>(f: &Matrix3<T>) -> bool {
    let [a2, a1, a0] = char_poly3(f);
    a2 > T::zero() && a0 > T::zero() && a2 * a1 > a0
}

/// Residual `A P + P Aᵀ + Q − P Cᵀ R⁻¹ C P` of the filter ARE and its relative size (1-norms).
pub fn care_residual<T: Real, const M: usize>(
    a: &Matrix3<T>,
    q: &Matrix3<T>,
    c: &SMatrix<T, M, 3>,
    r_diag: &SVector<T, M>,
    p: &Matrix3<T>,
) -> (Matrix3<T>, T) {
    let r_inv = SMatrix::<T, M, M>::from_diagonal(&r_diag.map(|r| T::one() / r));
    let g = c.transpose() * r_inv * c;
    let ap = a * p;
    let pat = p * a.transpose();
    let pgp = p * g * p;
    let res = ap + pat + q - pgp;
    let scale = norm1(&ap) + norm1(&pat) + norm1(q) + norm1(&pgp);
    let rel = if scale > T::zero() {
        norm1(&res) / scale
    } else {
        norm1(&res)
    };
    (res, rel)
}

/// Solves the filter-form continuous ARE `A P + P Aᵀ + Q − P Cᵀ R⁻¹ C P = 0` for the
/// stabilising P and the Kalman gain `K = P Cᵀ R⁻¹`.
///
/// * `a`: system matrix (3×3), 1/s.
/// * `q`: process-noise PSD on the states, `B Q_w Bᵀ` (3×3, symmetric, ≥ 0).
/// * `c`: output matrix (M×3).
/// * `r_diag`: measurement-noise PSDs (> 0), measurement unit² · s.
///
/// Errors: `NonFiniteInput` for NaN/Inf, `InputOutOfRange` for a non-positive `r` or a
/// negative diagonal of `q`, `SingularMatrix` if an iterate or the normal equations are
/// singular (e.g. eigenvalues of H on the imaginary axis: the pair is not detectable /
/// stabilisable), `NotConverged` if the iteration does not converge, the residual is not small
/// or the closed loop is not stable.
pub fn solve_filter_care<T: Real, const M: usize>(
    a: &Matrix3<T>,
    q: &Matrix3<T>,
    c: &SMatrix<T, M, 3>,
    r_diag: &SVector<T, M>,
) -> Result<CareSolution<T, M>, NavError> {
    check_care_inputs(a, q, c, r_diag)?;
    let q = (q + q.transpose()) * T::lit(0.5);
    let r_inv = SMatrix::<T, M, M>::from_diagonal(&r_diag.map(|r| T::one() / r));
    let g = c.transpose() * r_inv * c;

    let mut z = SMatrix::<T, 6, 6>::zeros();
    z.fixed_view_mut::<3, 3>(0, 0).copy_from(&a.transpose());
    z.fixed_view_mut::<3, 3>(0, 3).copy_from(&(-g));
    z.fixed_view_mut::<3, 3>(3, 0).copy_from(&(-q));
    z.fixed_view_mut::<3, 3>(3, 3).copy_from(&(-a));

    let (z, iterations) = matrix_sign(z)?;
    let p = p_from_sign(&z, iterations)?;
    let gain = p * c.transpose() * r_inv;
    let (_, relative_residual) = care_residual(a, &q, c, r_diag, &p);
    let small = matches!(
        relative_residual.partial_cmp(&T::EPS.sqrt()),
        Some(core::cmp::Ordering::Less | core::cmp::Ordering::Equal)
    );
    if !small {
        return Err(NavError::NotConverged { iterations });
    }
    if !is_hurwitz3(&(a - gain * c)) {
        return Err(NavError::NotConverged { iterations });
    }
    Ok(CareSolution {
        p,
        gain,
        iterations,
        relative_residual,
    })
}

/// The input checks of [`solve_filter_care`]: `NonFiniteInput` for NaN/Inf in A, Q, C or R,
/// `InputOutOfRange` for a non-positive `r` or a negative diagonal of `q`.
fn check_care_inputs<T: Real, const M: usize>(
    a: &Matrix3<T>,
    q: &Matrix3<T>,
    c: &SMatrix<T, M, 3>,
    r_diag: &SVector<T, M>,
) -> Result<(), NavError> {
    if !a.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "A" });
    }
    if !q.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "Q" });
    }
    if !c.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "C" });
    }
    if !r_diag.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput { input: "R" });
    }
    if r_diag.iter().any(|&r| r <= T::zero()) {
        return Err(NavError::InputOutOfRange { input: "R" });
    }
    if q.diagonal().iter().any(|&v| v < T::zero()) {
        return Err(NavError::InputOutOfRange { input: "Q" });
    }
    Ok(())
}

/// The matrix sign function of the 6×6 Hamiltonian `z`
/// by the scaled Newton iteration, with the number of iterations taken. `SingularMatrix` if an
/// iterate is singular, `NotConverged` if an iterate is not finite or the iteration does not
/// converge within [`MAX_SIGN_ITERATIONS`].
fn matrix_sign<T: Real>(mut z: SMatrix<T, 6, 6>) -> Result<(SMatrix<T, 6, 6>, u32), NavError> {
    let tol = T::lit(100.0) * T::EPS;
    let sixth = T::one() / T::lit(6.0);
    let mut iterations = 0u32;
    let mut converged = false;
    let mut scaling = true;
    while iterations < MAX_SIGN_ITERATIONS {
        iterations += 1;
        let (inv, det) = inverse_and_determinant(&z).ok_or(NavError::SingularMatrix)?;
        let mu = if scaling {
            let det = det.abs();
            if !(det.is_finite() && det > T::zero()) {
                return Err(NavError::SingularMatrix);
            }
            det.powf(-sixth)
        } else {
            T::one()
        };
        let next = (z * mu + inv / mu) * T::lit(0.5);
        if !next.iter().all(|v| v.is_finite()) {
            return Err(NavError::NotConverged { iterations });
        }
        let change = norm1(&(next - z));
        let size = norm1(&next);
        z = next;
        // Scaling only speeds up the early iterations; switch it off near convergence so the
        // final quadratic phase is not disturbed.
        if change <= T::lit(1e-2) * size {
            scaling = false;
        }
        if change <= tol * size {
            converged = true;
            break;
        }
        // In low precision the iteration stalls at the rounding level: accept a sign matrix
        // whose square is the identity to working precision.
        if change <= T::EPS.sqrt() * size {
            let sq = z * z - SMatrix::<T, 6, 6>::identity();
            if norm1(&sq) <= T::lit(10.0) * T::EPS.sqrt() {
                converged = true;
                break;
            }
        }
    }
    if !converged {
        return Err(NavError::NotConverged { iterations });
    }
    Ok((z, iterations))
}

/// The stabilising P (3×3, symmetric, state units²) from the sign matrix `z` of the
/// Hamiltonian: the least-squares solution of `N P = −M` with `[M N] = z + I`.
/// `SingularMatrix` if the normal equations are singular, `NotConverged { iterations }` if P
/// is not finite or has a negative diagonal.
fn p_from_sign<T: Real>(z: &SMatrix<T, 6, 6>, iterations: u32) -> Result<Matrix3<T>, NavError> {
    let w = z + SMatrix::<T, 6, 6>::identity();
    // copy_from rather than into_owned / try_inverse: no reachable panic on the target.
    let mut n = SMatrix::<T, 6, 3>::zeros();
    n.copy_from(&w.fixed_view::<6, 3>(0, 3));
    let mut rhs = SMatrix::<T, 6, 3>::zeros();
    rhs.copy_from(&w.fixed_view::<6, 3>(0, 0));
    let rhs = -rhs;
    let ntn = n.transpose() * n;
    let ntr = n.transpose() * rhs;
    let (ntn_inv, _) = inverse_and_determinant(&ntn).ok_or(NavError::SingularMatrix)?;
    let p = ntn_inv * ntr;
    let p = (p + p.transpose()) * T::lit(0.5);
    if !p.iter().all(|v| v.is_finite()) || p.diagonal().iter().any(|&v| v < T::zero()) {
        return Err(NavError::NotConverged { iterations });
    }
    Ok(p)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Matrix1x3, Matrix2x3, Vector1, Vector2};

    fn vertical_channel(c: f64) -> (Matrix3<f64>, Matrix3<f64>, Matrix2x3<f64>, Vector2<f64>) {
        let a = Matrix3::new(0.0, 1.0, 0.0, c, 0.0, 1.0, 0.0, 0.0, 0.0);
        let q = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.0, 1e-6, 1e-10));
        let cm = Matrix2x3::new(1.0, -0.2, 0.0, 0.0, 1.0, 0.0);
        (a, q, cm, Vector2::new(0.04, 0.001))
    }

    #[test]
    fn residual_small_and_closed_loop_stable_f64() {
        let (a, q, c, r) = vertical_channel(3.08e-6);
        let s = solve_filter_care(&a, &q, &c, &r).unwrap();
        assert!(s.relative_residual < 1e-10, "{}", s.relative_residual);
        assert!(is_hurwitz3(&(a - s.gain * c)));
        assert!(s.p.symmetric_eigenvalues().iter().all(|&e| e > 0.0));
    }

    #[test]
    fn scalar_like_case_matches_closed_form() {
        // Double integrator with position measurement, no bias noise in state 3 — use a
        // decoupled third state with its own measurement so the problem stays detectable:
        // A = diag(-1,-2,-3), C = I (3 measurements), Q = diag(q): p_i solves
        // 2 a_i p − p²/r + q = 0 → p = r (a + √(a² + q/r)).
        let a = Matrix3::from_diagonal(&nalgebra::Vector3::new(-1.0, -2.0, -3.0));
        let q = Matrix3::from_diagonal(&nalgebra::Vector3::new(1.0, 2.0, 3.0));
        let c = Matrix3::<f64>::identity();
        let r = nalgebra::Vector3::new(0.5, 0.25, 2.0);
        let s = solve_filter_care(&a, &q, &c, &r).unwrap();
        for i in 0..3 {
            let (ai, qi, ri) = (a[(i, i)], q[(i, i)], r[i]);
            let exact = ri * (ai + (ai * ai + qi / ri).sqrt());
            assert!(
                (s.p[(i, i)] - exact).abs() < 1e-12,
                "{i}: {} {exact}",
                s.p[(i, i)]
            );
        }
    }

    #[test]
    fn f32_solution_is_close_to_f64() {
        // A well-scaled (normalised-units) vertical channel: f32 meets its √ε residual. The
        // physical one (Q ~ 1e-10 against R⁻¹ ~ 1e3) does not in f32, which is why the loops
        // design their gains in f64.
        let a = Matrix3::new(0.0, 1.0, 0.0, 0.1, 0.0, 1.0, 0.0, 0.0, 0.0);
        let q = Matrix3::from_diagonal(&nalgebra::Vector3::new(0.0, 1.0, 0.1));
        let c = Matrix2x3::new(1.0, -0.2, 0.0, 0.0, 1.0, 0.0);
        let r = Vector2::new(2.0, 0.5);
        let s64 = solve_filter_care(&a, &q, &c, &r).unwrap();
        let s32 = solve_filter_care(&a.cast::<f32>(), &q.cast(), &c.cast(), &r.cast()).unwrap();
        let rel = (s32.gain.cast::<f64>() - s64.gain).abs().max() / s64.gain.abs().max();
        assert!(rel < 1e-2, "{rel}");
    }

    #[test]
    fn typed_errors() {
        let (a, q, c, r) = vertical_channel(3.08e-6);
        assert_eq!(
            solve_filter_care(&a, &q, &c, &Vector2::new(0.0, 1.0)),
            Err(NavError::InputOutOfRange { input: "R" })
        );
        let mut bad = a;
        bad[(0, 1)] = f64::NAN;
        assert_eq!(
            solve_filter_care(&bad, &q, &c, &r),
            Err(NavError::NonFiniteInput { input: "A" })
        );
        // Undetectable: the unstable altitude mode is not seen (velocity-only, c > 0, and no
        // process noise to excite anything): H has eigenvalues on the imaginary axis.
        let c1 = Matrix1x3::new(0.0, 0.0, 1.0);
        let q0 = Matrix3::zeros();
        assert!(solve_filter_care(&a, &q0, &c1, &Vector1::new(1.0)).is_err());
    }
}

//! Exact sampled simulation of linear stochastic processes (truth generation).
//!
//! A continuous process `ẋ = F x + w` sampled every Δt is *exactly* the discrete process
//! `x_{k+1} = Φ x_k + w_k`, `cov(w_k) = Q_d`, with Φ and Q_d from
//! [`nav_core::math::discretize::discretize`]: the truth has no discretisation error.

use crate::rng::{gauss, SimRng};
use anyhow::{anyhow, Result};
use nalgebra::{SMatrix, SVector};
use nav_core::math::discretize::discretize;
use nav_core::math::markov::GaussMarkov;

/// Lower-triangular square root `L` with `L Lᵀ = A` of a symmetric positive semi-definite
/// matrix (Cholesky; a pivot that is zero or negative to working precision zeroes its column,
/// which is the exact factor of a singular PSD matrix).
pub fn psd_sqrt<const N: usize>(a: &SMatrix<f64, N, N>) -> SMatrix<f64, N, N> {
    let mut l = SMatrix::<f64, N, N>::zeros();
    let scale = a.diagonal().abs().max().max(f64::MIN_POSITIVE);
    for j in 0..N {
        let d = a[(j, j)] - (0..j).map(|k| l[(j, k)] * l[(j, k)]).sum::<f64>();
        if d <= 1e-14 * scale {
            continue;
        }
        let ljj = d.sqrt();
        l[(j, j)] = ljj;
        for i in (j + 1)..N {
            let s = a[(i, j)] - (0..j).map(|k| l[(i, k)] * l[(j, k)]).sum::<f64>();
            l[(i, j)] = s / ljj;
        }
    }
    l
}

/// Draws `x ~ N(0, cov)` given `sqrt_cov` from [`psd_sqrt`].
pub fn draw<const N: usize>(rng: &mut SimRng, sqrt_cov: &SMatrix<f64, N, N>) -> SVector<f64, N> {
    let mut u = SVector::<f64, N>::zeros();
    for v in u.iter_mut() {
        *v = gauss(rng);
    }
    sqrt_cov * u
}

/// A linear time-invariant stochastic process simulated exactly at a fixed step.
#[derive(Debug, Clone)]
pub struct LinearProcess<const N: usize> {
    /// Transition over one step.
    pub phi: SMatrix<f64, N, N>,
    /// Square root of the discrete process-noise covariance.
    pub sqrt_qd: SMatrix<f64, N, N>,
    /// Current state.
    pub x: SVector<f64, N>,
}

impl<const N: usize> LinearProcess<N> {
    /// Discretises `(F, Q_c)` at `dt_s` and starts from `x0`.
    pub fn new(
        f: &SMatrix<f64, N, N>,
        q_c: &SMatrix<f64, N, N>,
        dt_s: f64,
        x0: SVector<f64, N>,
    ) -> Result<Self> {
        let (phi, qd) = discretize(f, q_c, dt_s).map_err(|e| anyhow!("discretize: {e}"))?;
        Ok(Self {
            phi,
            sqrt_qd: psd_sqrt(&qd),
            x: x0,
        })
    }

    /// Advances one step.
    pub fn step(&mut self, rng: &mut SimRng) -> SVector<f64, N> {
        self.x = self.phi * self.x + draw(rng, &self.sqrt_qd);
        self.x
    }
}

/// An n-th order Gauss-Markov process (N = order) started in its stationary distribution.
pub fn gauss_markov<const N: usize>(
    gm: &GaussMarkov<f64>,
    dt_s: f64,
    rng: &mut SimRng,
) -> Result<LinearProcess<N>> {
    let (f, q) = gm.continuous_model::<N>().map_err(|e| anyhow!("{e}"))?;
    let p3 = gm.stationary_covariance();
    let p: SMatrix<f64, N, N> = p3.fixed_view::<N, N>(0, 0).into_owned();
    let x0 = draw(rng, &psd_sqrt(&p));
    LinearProcess::new(&f, &q, dt_s, x0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::run_rng;
    use crate::stats::autocorrelation;
    use nav_core::math::markov::MarkovOrder;

    #[test]
    fn third_order_process_has_configured_sigma_and_tau() {
        let gm = GaussMarkov::new(MarkovOrder::Third, 2.0, 0.5).unwrap();
        let dt = 0.01;
        let mut rng = run_rng(11, 0);
        let mut p = gauss_markov::<3>(&gm, dt, &mut rng).unwrap();
        let x: Vec<f64> = (0..400_000).map(|_| p.step(&mut rng)[0]).collect();
        let var = x.iter().map(|v| v * v).sum::<f64>() / x.len() as f64;
        assert!((var.sqrt() / 2.0 - 1.0).abs() < 0.05, "σ {}", var.sqrt());
        let r = autocorrelation(&x, 50);
        assert!((r - (-1f64).exp()).abs() < 0.04, "ρ(τ) {r}");
    }
}

//! n-th order Gauss-Markov processes (n = 1, 2, 3), the flexure and correlated-error models.
//!
//! An n-th order process is white noise through n equal real poles at −β:
//!
//! ```text
//! (d/dt + β)^n x = w,    E[w(t) w(t+τ)] = q δ(τ)
//! ```
//!
//! State `[x, ẋ, …, x^(n−1)]`, companion matrix F with last row `−C(n,k) β^(n−k)`, noise on the
//! last row. The stationary variance is σ² when `q = c_n β^(2n−1) σ²` with
//! `c_1 = 2`, `c_2 = 4`, `c_3 = 16/3` (the transfer-alignment spec's `4β³σ²` and `(16/3)β⁵σ²`;
//! the seed's `4β²σ²` is a misprint). The correlation time τ is the lag at which the
//! autocorrelation falls to σ²/e, which sets `β = k_n / τ` with `k_n` the root of
//! `e^{−k}(1 + k) = e^{−1}` (n = 2, k = 2.14619…) or `e^{−k}(1 + k + k²/3) = e^{−1}`
//! (n = 3, k = 2.90463…; the spec rounds it to 2.903).

use crate::error::require_positive;
use crate::{NavError, Real};
use nalgebra::SMatrix;

/// Order of a Gauss-Markov process.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum MarkovOrder {
    /// 1st order (exponentially correlated).
    First = 1,
    /// 2nd order (Schneider's flexure model).
    Second = 2,
    /// 3rd order (the proposed flexure model: smooth 2nd derivative).
    Third = 3,
}

impl MarkovOrder {
    /// `β τ` that puts the autocorrelation at σ²/e at lag τ.
    pub const fn beta_tau(self) -> f64 {
        match self {
            MarkovOrder::First => 1.0,
            MarkovOrder::Second => 2.146_193_220_620_582_5,
            MarkovOrder::Third => 2.904_629_975_029_914_5,
        }
    }

    /// `c_n` in `q = c_n β^(2n−1) σ²`.
    pub const fn psd_coefficient(self) -> f64 {
        match self {
            MarkovOrder::First => 2.0,
            MarkovOrder::Second => 4.0,
            MarkovOrder::Third => 16.0 / 3.0,
        }
    }

    /// Number of states `n`.
    pub const fn states(self) -> usize {
        self as usize
    }
}

/// One axis of a Gauss-Markov process, parameterised as engineers specify it.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GaussMarkov<T> {
    /// Process order.
    pub order: MarkovOrder,
    /// Stationary standard deviation σ of x (1σ, unit of x).
    pub sigma: T,
    /// Correlation time τ, s: lag where the autocorrelation falls to σ²/e.
    pub correlation_time_s: T,
}

impl<T: Real> GaussMarkov<T> {
    /// Validated constructor: σ ≥ 0 is allowed to be zero only if τ > 0; τ must be > 0.
    pub fn new(order: MarkovOrder, sigma: T, correlation_time_s: T) -> Result<Self, NavError> {
        crate::error::require_non_negative("sigma", sigma)?;
        require_positive("correlation_time_s", correlation_time_s)?;
        Ok(Self {
            order,
            sigma,
            correlation_time_s,
        })
    }

    /// Pole magnitude β, 1/s.
    pub fn beta(&self) -> T {
        T::lit(self.order.beta_tau()) / self.correlation_time_s
    }

    /// Driving white-noise power spectral density q (unit of x^(n) squared per Hz... i.e.
    /// `[x]²/s^(2n−1)`), giving the stationary variance σ².
    pub fn psd(&self) -> T {
        let b = self.beta();
        let mut bp = T::one();
        for _ in 0..(2 * self.order.states() - 1) {
            bp *= b;
        }
        T::lit(self.order.psd_coefficient()) * bp * self.sigma * self.sigma
    }

    /// Companion matrix F (N = order) and continuous noise PSD matrix Q_c (q on the last
    /// diagonal element). Errors with `InvalidConfig` if `N` differs from the order.
    pub fn continuous_model<const N: usize>(
        &self,
    ) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>), NavError> {
        if N != self.order.states() {
            return Err(NavError::InvalidConfig {
                field: "order",
                issue: crate::error::ConfigIssue::OutOfRange,
            });
        }
        let b = self.beta();
        let mut f = SMatrix::<T, N, N>::zeros();
        for i in 0..N.saturating_sub(1) {
            if let Some(v) = f.get_mut((i, i + 1)) {
                *v = T::one();
            }
        }
        // Last row: −C(n,k) β^(n−k), k = 0..n−1.
        let coeffs: [T; 3] = match self.order {
            MarkovOrder::First => [b, T::zero(), T::zero()],
            MarkovOrder::Second => [b * b, T::lit(2.0) * b, T::zero()],
            MarkovOrder::Third => [b * b * b, T::lit(3.0) * b * b, T::lit(3.0) * b],
        };
        for (k, c) in coeffs.iter().take(N).enumerate() {
            if let Some(v) = f.get_mut((N - 1, k)) {
                *v = -*c;
            }
        }
        let mut q = SMatrix::<T, N, N>::zeros();
        if let Some(v) = q.get_mut((N - 1, N - 1)) {
            *v = self.psd();
        }
        Ok((f, q))
    }

    /// Stationary covariance of `[x, ẋ, ẍ]` up to the order (closed form), padded with zeros
    /// to 3×3. For n = 3: var x = σ², var ẋ = β²σ²/3, var ẍ = β⁴σ², cov(x, ẍ) = −β²σ²/3.
    pub fn stationary_covariance(&self) -> SMatrix<T, 3, 3> {
        let b2 = self.beta() * self.beta();
        let s2 = self.sigma * self.sigma;
        let mut p = SMatrix::<T, 3, 3>::zeros();
        match self.order {
            MarkovOrder::First => p.m11 = s2,
            MarkovOrder::Second => {
                p.m11 = s2;
                p.m22 = b2 * s2;
            }
            MarkovOrder::Third => {
                let third = T::lit(1.0 / 3.0);
                p.m11 = s2;
                p.m22 = b2 * s2 * third;
                p.m33 = b2 * b2 * s2;
                p.m13 = -b2 * s2 * third;
                p.m31 = p.m13;
            }
        }
        p
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::discretize::{discretize, stationary_covariance};
    use nalgebra::{Matrix2, Matrix3};

    fn autocorr(order: MarkovOrder, x: f64) -> f64 {
        match order {
            MarkovOrder::First => (-x).exp(),
            MarkovOrder::Second => (-x).exp() * (1.0 + x),
            MarkovOrder::Third => (-x).exp() * (1.0 + x + x * x / 3.0),
        }
    }

    #[test]
    fn beta_tau_puts_autocorrelation_at_one_over_e() {
        for o in [MarkovOrder::First, MarkovOrder::Second, MarkovOrder::Third] {
            let r = autocorr(o, o.beta_tau());
            assert!((r - (-1.0f64).exp()).abs() < 1e-14, "{o:?}");
        }
        // The spec's rounded constants.
        assert!((MarkovOrder::Second.beta_tau() - 2.146).abs() < 5e-4);
        assert!((MarkovOrder::Third.beta_tau() - 2.903).abs() < 2e-3);
    }

    #[test]
    fn closed_form_stationary_covariance_solves_lyapunov() {
        let gm3 = GaussMarkov::new(MarkovOrder::Third, 0.5_f64.to_radians(), 0.358).unwrap();
        let (f, q) = gm3.continuous_model::<3>().unwrap();
        let p = gm3.stationary_covariance();
        // F P + P Fᵀ + Q = 0.
        let res = f * p + p * f.transpose() + q;
        assert!(res.abs().max() < 1e-12 * q.abs().max(), "{res}");
        // And the discrete doubling gives the same P.
        let (phi, qd) = discretize(&f, &q, 0.01).unwrap();
        let pd = stationary_covariance(&phi, &qd, 64).unwrap();
        assert!((pd - p).abs().max() < 1e-9 * p.abs().max());
        // RMS of the 2nd derivative is β²σ (spec identity).
        assert!((p.m33.sqrt() - gm3.beta().powi(2) * gm3.sigma).abs() < 1e-12);

        let gm2 = GaussMarkov::new(MarkovOrder::Second, 0.1_f64, 2.146).unwrap();
        let (f2, q2) = gm2.continuous_model::<2>().unwrap();
        let p2 = gm2
            .stationary_covariance()
            .fixed_view::<2, 2>(0, 0)
            .into_owned();
        let res2: Matrix2<f64> = f2 * p2 + p2 * f2.transpose() + q2;
        assert!(res2.abs().max() < 1e-14);

        let gm1 = GaussMarkov::new(MarkovOrder::First, 3.0_f64, 60.0).unwrap();
        let (f1, q1) = gm1.continuous_model::<1>().unwrap();
        assert!((2.0 * f1[0] * 9.0 + q1[0]).abs() < 1e-14);
    }

    #[test]
    fn rejects_bad_parameters() {
        assert!(GaussMarkov::new(MarkovOrder::Second, -1.0_f32, 1.0).is_err());
        assert!(GaussMarkov::new(MarkovOrder::Second, 1.0_f32, 0.0).is_err());
        assert!(GaussMarkov::new(MarkovOrder::Second, f32::NAN, 1.0).is_err());
        let gm = GaussMarkov::new(MarkovOrder::Second, 1.0_f64, 1.0).unwrap();
        assert!(gm.continuous_model::<3>().is_err());
        let _: (Matrix3<f64>, _) = GaussMarkov::new(MarkovOrder::Third, 1.0, 1.0)
            .unwrap()
            .continuous_model::<3>()
            .unwrap();
    }
}

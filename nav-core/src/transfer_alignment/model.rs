//! Flexure models, state layout and per-axis discretisation (spec "Flexure models", "States").
//!
//! Both filters share the structure `x = [θ_m(3), θ_f(3), θ̇_f(3)(, θ̈_f(3))]` (the spec's
//! ordering, "derivative-major"). The dynamics decouple per axis j ∈ {X, Y, Z}: each axis owns a
//! chain `[θ_m,j, θ_f,j, θ̇_f,j(, θ̈_f,j)]` of `K` states (K = 3 conventional, K = 4 proposed) with
//!
//! ```text
//! F_j = | 0  0      |     the flexure block is the companion matrix of the Markov process:
//!       | 0  F_f,j  |     2nd order: [0 1; −β² −2β],  3rd order: [0 1 0; 0 0 1; −β³ −3β² −3β]
//! ```
//!
//! and driving noise PSD `q_j = 4β³σ²` (2nd order, β = 2.146/τ) or `(16/3)β⁵σ²` (3rd order,
//! β = 2.903/τ) on the last state of the chain (the seed's `4β²σ²` is a misprint; see
//! [`crate::math::markov`]). θ_m is a random constant (Φ = 1, no noise).
//!
//! The filters therefore store the state *axis-major* internally (`[chain X, chain Y, chain Z]`),
//! so Φ is block-diagonal with three K×K blocks, each computed once at configuration by the exact
//! discretisation ([`crate::math::discretize::discretize`], Van Loan equivalent). The public API
//! speaks the spec's ordering; [`spec_index`] and [`axis_index`] convert.
use crate::error::{require_positive, ConfigIssue};
use crate::math::discretize::discretize;
use crate::math::markov::{GaussMarkov, MarkovOrder};
use crate::{NavError, Real};
use nalgebra::{SMatrix, Vector3};

/// Which flexure model (and so which filter) a chain length `K` stands for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum FlexureModel {
    /// Schneider's 2nd-order Markov model: 9 states, the conventional filter (K = 3).
    Conventional,
    /// The proposed 3rd-order Markov model with the flexure angular acceleration: 12 states
    /// (K = 4).
    Proposed,
}

impl FlexureModel {
    /// The model of chain length `K` (states per axis), or `InvalidConfig` if `K` is not 3, 4
    /// or 5 or `N ≠ 3 K`.
    pub fn for_dims<const K: usize, const N: usize>() -> Result<Self, NavError> {
        let model = Self::for_chain::<K>()?;
        if N != 3 * K {
            return Err(NavError::InvalidConfig {
                field: "state dimension",
                issue: ConfigIssue::OutOfRange,
            });
        }
        Ok(model)
    }

    /// The model of chain length `K` (3, 4, or 5: the proposed model with the
    /// specific-force-difference bias, [`has_accel_bias`]), else `InvalidConfig`.
    pub fn for_chain<const K: usize>() -> Result<Self, NavError> {
        match K {
            3 => Ok(FlexureModel::Conventional),
            4 | 5 => Ok(FlexureModel::Proposed),
            _ => Err(NavError::InvalidConfig {
                field: "state dimension",
                issue: ConfigIssue::OutOfRange,
            }),
        }
    }

    /// Order of the flexure Gauss-Markov process.
    pub const fn markov_order(self) -> MarkovOrder {
        match self {
            FlexureModel::Conventional => MarkovOrder::Second,
            FlexureModel::Proposed => MarkovOrder::Third,
        }
    }
}

/// Chain length of the flight configuration ([`super::FlightFilter`]): the proposed chain
/// `[θ_m, θ_f, θ̇_f, θ̈_f]` followed by the bias `b` of the axis' specific-force difference.
pub const FLIGHT_CHAIN: usize = 5;

/// `true` when a chain of length `K` ends with the bias of its axis' specific-force difference
/// (master minus slave accelerometer bias, a random constant; [`FLIGHT_CHAIN`]).
#[inline(always)]
pub const fn has_accel_bias<const K: usize>() -> bool {
    K == FLIGHT_CHAIN
}

/// Position of the bias in a chain of length `K` with [`has_accel_bias`] (its last state).
pub const BIAS_STATE: usize = FLIGHT_CHAIN - 1;

/// Flexure states (θ_f and its derivatives) plus the θ_m state of a chain of length `K`: the
/// chain without its bias.
#[inline(always)]
pub(super) const fn flexure_chain_len<const K: usize>() -> usize {
    if has_accel_bias::<K>() {
        K - 1
    } else {
        K
    }
}

/// Index in the spec's (derivative-major) state ordering of derivative `d` (0 = θ_m, 1 = θ_f,
/// 2 = θ̇_f, 3 = θ̈_f) of axis `a` (0 = X, 1 = Y, 2 = Z): `3 d + a`.
#[inline(always)]
pub const fn spec_index(d: usize, a: usize) -> usize {
    3 * d + a
}

/// Index in the internal (axis-major) ordering: `K a + d`.
#[inline(always)]
pub const fn axis_index<const K: usize>(d: usize, a: usize) -> usize {
    K * a + d
}

/// Flexure statistics of one axis.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct AxisFlexure<T> {
    /// Stationary 1σ of the flexure angle θ_f, rad.
    pub sigma_rad: T,
    /// Correlation time τ (autocorrelation σ²/e), s.
    pub tau_s: T,
}

/// Discrete model of one axis chain `[θ_m, θ_f, θ̇_f(, θ̈_f)]` at the filter step.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AxisChain<T: Real, const K: usize> {
    /// Continuous dynamics F_j (K×K), 1/s.
    pub f: SMatrix<T, K, K>,
    /// Continuous noise PSD Q_c,j (only the last diagonal element, q_j), rad²/s^(2n−1).
    pub q_c: SMatrix<T, K, K>,
    /// Transition Φ_j = exp(F_j Δt).
    pub phi: SMatrix<T, K, K>,
    /// Discrete process-noise covariance Q_d,j (variance, unit of the states squared).
    pub q_d: SMatrix<T, K, K>,
    /// Initial covariance: σ_m² for θ_m, the stationary covariance of the flexure chain.
    pub p0: SMatrix<T, K, K>,
}

/// `(F_j, Q_c,j, Markov process)` of one axis chain.
pub type ChainContinuous<T, const K: usize> = (SMatrix<T, K, K>, SMatrix<T, K, K>, GaussMarkov<T>);

/// Continuous `(F_j, Q_c,j)` of one axis chain of length K (θ_m first, then the flexure
/// companion block of order K − 1; spec "States").
pub fn axis_continuous<T: Real, const K: usize>(
    flex: &AxisFlexure<T>,
) -> Result<ChainContinuous<T, K>, NavError> {
    let model = FlexureModel::for_chain::<K>()?;
    let gm = GaussMarkov::new(model.markov_order(), flex.sigma_rad, flex.tau_s)?;
    let beta = gm.beta();
    let q = gm.psd();
    let mut f = SMatrix::<T, K, K>::zeros();
    // The flexure part of the chain ends at `last`; a bias state after it is a random constant
    // (zero row and column of F, no noise).
    let kf = flexure_chain_len::<K>();
    let last = kf - 1;
    // Chain: d/dt θ_f = θ̇_f (, d/dt θ̇_f = θ̈_f), last row the companion coefficients.
    for d in 1..last {
        if let Some(v) = f.get_mut((d, d + 1)) {
            *v = T::one();
        }
    }
    let b2 = beta * beta;
    let coeffs: [T; 3] = match model {
        FlexureModel::Conventional => [b2, T::lit(2.0) * beta, T::zero()],
        FlexureModel::Proposed => [b2 * beta, T::lit(3.0) * b2, T::lit(3.0) * beta],
    };
    for (k, c) in coeffs.iter().take(last).enumerate() {
        if let Some(v) = f.get_mut((last, k + 1)) {
            *v = -*c;
        }
    }
    let mut q_c = SMatrix::<T, K, K>::zeros();
    if let Some(v) = q_c.get_mut((last, last)) {
        *v = q;
    }
    Ok((f, q_c, gm))
}

impl<T: Real, const K: usize> AxisChain<T, K> {
    /// Builds the chain of one axis: exact Φ and Q_d at `dt_s` and the initial covariance
    /// (θ_m variance `mount_sigma_rad²`, flexure block its closed-form stationary covariance,
    /// which solves `F P + P Fᵀ + Q = 0`). A chain with a bias state ([`has_accel_bias`])
    /// starts it at variance 0: use [`Self::with_bias`].
    pub fn new(flex: &AxisFlexure<T>, mount_sigma_rad: T, dt_s: T) -> Result<Self, NavError> {
        crate::error::require_non_negative("mount_sigma_rad", mount_sigma_rad)?;
        require_positive("dt_s", dt_s)?;
        let (f, q_c, gm) = axis_continuous::<T, K>(flex)?;
        let (phi, q_d) = discretize(&f, &q_c, dt_s)?;
        let ps = gm.stationary_covariance();
        let mut p0 = SMatrix::<T, K, K>::zeros();
        if let Some(v) = p0.get_mut((0, 0)) {
            *v = mount_sigma_rad * mount_sigma_rad;
        }
        let kf = flexure_chain_len::<K>();
        for r in 0..kf - 1 {
            for c in 0..kf - 1 {
                if let (Some(dst), Some(src)) = (p0.get_mut((r + 1, c + 1)), ps.get((r, c))) {
                    *dst = *src;
                }
            }
        }
        Ok(Self {
            f,
            q_c,
            phi,
            q_d,
            p0,
        })
    }
}

impl<T: Real, const K: usize> AxisChain<T, K> {
    /// [`Self::new`] with the initial variance of the bias state (a chain with
    /// [`has_accel_bias`]) set to `bias_sigma_m_s2²` ((m/s²)²); a chain without one is
    /// returned as [`Self::new`] builds it. `InvalidConfig { field: "accel_bias_sigma_m_s2" }`
    /// unless the σ is finite and non-negative.
    pub fn with_bias(
        flex: &AxisFlexure<T>,
        mount_sigma_rad: T,
        bias_sigma_m_s2: T,
        dt_s: T,
    ) -> Result<Self, NavError> {
        crate::error::require_non_negative("accel_bias_sigma_m_s2", bias_sigma_m_s2)?;
        let mut ch = Self::new(flex, mount_sigma_rad, dt_s)?;
        if has_accel_bias::<K>() {
            if let Some(v) = ch.p0.get_mut((BIAS_STATE, BIAS_STATE)) {
                *v = bias_sigma_m_s2 * bias_sigma_m_s2;
            }
        }
        Ok(ch)
    }
}

/// Per-axis chains of the three axes (`accel_bias_sigma_m_s2`: 1σ of each axis' bias state,
/// m/s², used by chains with [`has_accel_bias`] only).
pub fn axis_chains<T: Real, const K: usize>(
    flex: &[AxisFlexure<T>; 3],
    mount_sigma_rad: &Vector3<T>,
    accel_bias_sigma_m_s2: &Vector3<T>,
    dt_s: T,
) -> Result<[AxisChain<T, K>; 3], NavError> {
    let b = accel_bias_sigma_m_s2;
    Ok([
        AxisChain::with_bias(&flex[0], mount_sigma_rad.x, b.x, dt_s)?,
        AxisChain::with_bias(&flex[1], mount_sigma_rad.y, b.y, dt_s)?,
        AxisChain::with_bias(&flex[2], mount_sigma_rad.z, b.z, dt_s)?,
    ])
}

/// Scatters three per-axis K×K blocks into an N×N matrix in the spec's ordering.
pub fn assemble_spec<T: Real, const K: usize, const N: usize>(
    blocks: [&SMatrix<T, K, K>; 3],
) -> SMatrix<T, N, N> {
    let mut m = SMatrix::<T, N, N>::zeros();
    for (a, blk) in blocks.iter().enumerate() {
        for r in 0..K {
            for c in 0..K {
                if let (Some(dst), Some(src)) = (
                    m.get_mut((spec_index(r, a), spec_index(c, a))),
                    blk.get((r, c)),
                ) {
                    *dst = *src;
                }
            }
        }
    }
    m
}

/// Continuous `(F, Q_c)` of the whole N-state model in the spec's ordering (for analysis and
/// tests; the filters use the per-axis chains).
pub fn continuous_model<T: Real, const K: usize, const N: usize>(
    flex: &[AxisFlexure<T>; 3],
) -> Result<(SMatrix<T, N, N>, SMatrix<T, N, N>), NavError> {
    FlexureModel::for_dims::<K, N>()?;
    let (f0, q0, _) = axis_continuous::<T, K>(&flex[0])?;
    let (f1, q1, _) = axis_continuous::<T, K>(&flex[1])?;
    let (f2, q2, _) = axis_continuous::<T, K>(&flex[2])?;
    Ok((
        assemble_spec::<T, K, N>([&f0, &f1, &f2]),
        assemble_spec::<T, K, N>([&q0, &q1, &q2]),
    ))
}

/// Permutes an internal (axis-major) covariance into the spec's (derivative-major) ordering.
pub fn to_spec_order<T: Real, const K: usize, const N: usize>(
    p_axis: &SMatrix<T, N, N>,
) -> SMatrix<T, N, N> {
    let mut out = SMatrix::<T, N, N>::zeros();
    for a in 0..3 {
        for d in 0..K {
            for b in 0..3 {
                for e in 0..K {
                    if let (Some(dst), Some(src)) = (
                        out.get_mut((spec_index(d, a), spec_index(e, b))),
                        p_axis.get((axis_index::<K>(d, a), axis_index::<K>(e, b))),
                    ) {
                        *dst = *src;
                    }
                }
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::discretize::stationary_covariance;

    fn flex() -> [AxisFlexure<f64>; 3] {
        [
            AxisFlexure {
                sigma_rad: 0.5_f64.to_radians(),
                tau_s: 0.358,
            },
            AxisFlexure {
                sigma_rad: 0.1_f64.to_radians(),
                tau_s: 2.146,
            },
            AxisFlexure {
                sigma_rad: 0.1_f64.to_radians(),
                tau_s: 2.146,
            },
        ]
    }

    #[test]
    fn spec_f_has_the_printed_structure() {
        let (f, q) = continuous_model::<f64, 4, 12>(&flex()).unwrap();
        let b = 2.904_629_975_029_914_5 / 0.358;
        // θ̇_f,X row has 1 on θ̈_f,X; θ̈_f,X row has −β³, −3β², −3β.
        assert_eq!(f[(spec_index(1, 0), spec_index(2, 0))], 1.0);
        assert_eq!(f[(spec_index(2, 0), spec_index(3, 0))], 1.0);
        assert!((f[(spec_index(3, 0), spec_index(1, 0))] + b * b * b).abs() < 1e-9);
        assert!((f[(spec_index(3, 0), spec_index(2, 0))] + 3.0 * b * b).abs() < 1e-9);
        assert!((f[(spec_index(3, 0), spec_index(3, 0))] + 3.0 * b).abs() < 1e-12);
        // θ_m rows are zero.
        assert!(f.fixed_rows::<3>(0).iter().all(|v| *v == 0.0));
        let s2 = 0.5_f64.to_radians().powi(2);
        assert!((q[(9, 9)] - 16.0 / 3.0 * b.powi(5) * s2).abs() < 1e-12 * q[(9, 9)]);
        let (f9, q9) = continuous_model::<f64, 3, 9>(&flex()).unwrap();
        let b2 = 2.146_193_220_620_582_5 / 0.358;
        assert!((f9[(6, 3)] + b2 * b2).abs() < 1e-9 && (f9[(6, 6)] + 2.0 * b2).abs() < 1e-12);
        assert!((q9[(6, 6)] - 4.0 * b2.powi(3) * s2).abs() < 1e-12 * q9[(6, 6)]);
        assert!(continuous_model::<f64, 4, 9>(&flex()).is_err());
        assert!(continuous_model::<f64, 6, 18>(&flex()).is_err());
        // The flight chain: the proposed chain, then the bias (a random constant).
        let (f15, q15) = continuous_model::<f64, 5, 15>(&flex()).unwrap();
        assert_eq!(f15.fixed_view::<12, 12>(0, 0), f);
        assert_eq!(q15.fixed_view::<12, 12>(0, 0), q);
        assert!(f15.fixed_rows::<3>(12).iter().all(|v| *v == 0.0));
        assert!(f15.fixed_columns::<3>(12).iter().all(|v| *v == 0.0));
        assert!(q15.fixed_rows::<3>(12).iter().all(|v| *v == 0.0));
    }

    fn check_chain<T: Real, const K: usize>(tol: f64) {
        let f = flex();
        let fl = AxisFlexure {
            sigma_rad: T::lit(f[0].sigma_rad),
            tau_s: T::lit(f[0].tau_s),
        };
        let ch = AxisChain::<T, K>::new(&fl, T::lit(0.5_f64.to_radians()), T::lit(0.01)).unwrap();
        // The flexure block of P0 is stationary for the discrete model: P = Φ P Φᵀ + Q_d.
        let res = ch.phi * ch.p0 * ch.phi.transpose() + ch.q_d - ch.p0;
        let scale = ch.p0.abs().max().to_f64();
        assert!(res.abs().max().to_f64() < tol * scale, "{res}");
        // and agrees with the doubling solution of the flexure block.
        let pd = stationary_covariance(&ch.phi, &ch.q_d, 64);
        assert!(
            pd.is_err(),
            "θ_m is a random constant: the full chain is not stable"
        );
        assert_eq!(ch.phi[(0, 0)], T::one());
        assert!(ch.q_d.row(0).iter().all(|v| *v == T::zero()));
    }

    #[test]
    fn chains_are_stationary_f32_f64() {
        check_chain::<f64, 3>(1e-10);
        check_chain::<f64, 4>(1e-10);
        check_chain::<f32, 3>(2e-5);
        check_chain::<f32, 4>(2e-5);
    }

    #[test]
    fn rejects_bad_flexure() {
        let bad = AxisFlexure {
            sigma_rad: 0.01_f32,
            tau_s: 0.0,
        };
        assert!(matches!(
            AxisChain::<f32, 4>::new(&bad, 0.01, 0.01),
            Err(NavError::InvalidConfig { .. })
        ));
        let good = AxisFlexure {
            sigma_rad: 0.01_f32,
            tau_s: 1.0,
        };
        assert!(AxisChain::<f32, 4>::new(&good, -1.0, 0.01).is_err());
        assert!(AxisChain::<f32, 4>::new(&good, 0.01, f32::NAN).is_err());
    }
}

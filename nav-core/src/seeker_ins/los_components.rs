//! The arithmetic of the LOS update's scalar components: the two components of the 2-D
//! update against P, the conditioning of their noise ([`max_information_ratio`]), their
//! reports through the shared gate ([`crate::math::kalman::gate_scalar`]) and the stabilising
//! noise after a fused update ([`stabilise`]; the baro update's cap [`STABILISING_EPS`]).

use super::error_model::STATES;
use super::generated::los17::{dot_pitch, dot_yaw, p_h_pitch, p_h_yaw};
use super::measurement::LosModel;
use crate::contract::{FusionOutcome, FusionReport, Gate};
use crate::math::kalman::gate_scalar;
use crate::Real;
use nalgebra::SMatrix;

/// Largest ratio `hᵀPh / r` a LOS component is fused with in the working precision:
/// `10⁻³ / ε` (8 389 in f32, 4.5e12 in f64). Beyond it r is raised (module doc of [`super`]).
pub fn max_information_ratio<T: Real>() -> T {
    T::lit(1e-3) / T::EPS
}

/// Largest relative variance added to every state after a fused baro update of the flight
/// navigator, in units of ε of the working precision: `min(ρ, this) ε` for an update of
/// information ratio `ρ`. The LOS update's noise is `ρ ε` up to the conditioning limit
/// ([`max_information_ratio`], `stabilise`).
pub const STABILISING_EPS: f64 = 256.0;

/// The two components of a 2-D update, computed against P without changing it.
pub(super) struct TwoComponents<T> {
    pub(super) rep1: FusionReport<T>,
    pub(super) rep2: FusionReport<T>,
    pub(super) cond1: bool,
    pub(super) cond2: bool,
    /// `P h₁` and the gain `K₁ = P h₁ / s₁` (zero unless fused).
    pub(super) k1: [T; STATES],
    pub(super) kk1: [T; STATES],
    /// `P⁺₁ h₂` and `K₂` (zero unless fused).
    pub(super) k2: [T; STATES],
    pub(super) kk2: [T; STATES],
    /// The correction δx.
    pub(super) x: [T; STATES],
    /// Largest information ratio `hᵀPh / r` of the fused components (r as fused, i.e.
    /// conditioned), dimensionless; 0 when none was fused.
    pub(super) info_ratio: T,
}

/// The two scalar components against P (unchanged): component 1 (pitch direction) against P,
/// component 2 (yaw direction) against P after component 1, `k₂ = P h₂ − k₁ (K₁·h₂)`. The
/// products with the rows of H run over their non-zero columns only (generated,
/// `generated::los17`).
#[inline(always)]
pub(super) fn two_components<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    model: &LosModel<T>,
    gate: Gate<T>,
) -> TwoComponents<T> {
    let zero = T::zero();
    let kappa = max_information_ratio::<T>();
    let p = &p.data.0;
    let [h1] = &model.h_pitch.data.0;
    let [h2] = &model.h_yaw.data.0;
    let k1 = p_h_pitch(p, h1);
    let hph1 = dot_pitch(&k1, h1);
    let (r1, cond1) = conditioned_noise(hph1, model.variance_rad2.x, kappa);
    let (rep1, inv_s1) = scalar_report(hph1, r1, model.residual_rad.x, gate);
    let mut k2 = p_h_yaw(p, h2);
    let mut x = [zero; STATES];
    let mut kk1 = [zero; STATES];
    if rep1.outcome == FusionOutcome::Fused {
        let c = dot_yaw(&k1, h2) * inv_s1;
        let it = k2
            .iter_mut()
            .zip(k1.iter())
            .zip(x.iter_mut())
            .zip(kk1.iter_mut());
        for (((k2i, k1i), xi), kk) in it {
            *k2i -= *k1i * c;
            *kk = *k1i * inv_s1;
            *xi = *kk * rep1.innovation;
        }
    }
    let nu2 = model.residual_rad.y - dot_yaw(&x, h2);
    let hph2 = dot_yaw(&k2, h2);
    let (r2, cond2) = conditioned_noise(hph2, model.variance_rad2.y, kappa);
    let (rep2, inv_s2) = scalar_report(hph2, r2, nu2, gate);
    let mut kk2 = [zero; STATES];
    if rep2.outcome == FusionOutcome::Fused {
        for ((kk, k2i), xi) in kk2.iter_mut().zip(k2.iter()).zip(x.iter_mut()) {
            *kk = *k2i * inv_s2;
            *xi += *kk * rep2.innovation;
        }
    }
    let info_ratio = information_ratio(&rep1, hph1, r1).max(information_ratio(&rep2, hph2, r2));
    TwoComponents {
        info_ratio,
        rep1,
        rep2,
        cond1,
        cond2,
        k1,
        kk1,
        k2,
        kk2,
        x,
    }
}

/// Stabilising noise `P ← P + δ diag(P)` after an update of information ratio `ρ`
/// (dimensionless, `hᵀPh / r`), `δ = ρ ε`, ρ at most [`max_information_ratio`] (the
/// conditioned r), so δ ≤ 10⁻³ in any precision:
/// the correlation matrix becomes `(C + δ I)/(1 + δ)`, so its smallest eigenvalue is at least
/// `δ/(1 + δ)` — a margin above the rounding of the update. The update divides the variance
/// along h by `1 + ρ` while its rounding stays ε relative to the prior, so the rounding
/// relative to the posterior, and the margin it needs, grow with ρ. Without the margin an f32
/// P that the updates have made singular to working precision (a combination of states known
/// to the seeker's precision) turns indefinite, and the next precise LOS, fused into an
/// indefinite prior, commits a P with a correlation eigenvalue of −0.27 (measured, seeker
/// σ = 1e-5 rad). A constant `256 ε` after every update acted as process noise along the
/// directions the seeker observes (their variance is a tiny fraction of the states' own): the
/// f32 flight configuration's final σ lat was 19.7 m for an RMS error of 13.3 m
/// (seeker-straight; f64 12.4 m, 12.2 m; with the ρ-scaled noise 12.5 m, 12.2 m). A cap of
/// 256 ε on δ left updates at the conditioning limit (ρ up to 8 389 in f32, a seeker precise
/// to 1e-5 rad) with too little margin: from a P with a correlation eigenvalue of +3e-5 one
/// update committed −0.11, in 4 of 30 reseeded short stress campaigns (cap 1 024 ε: 5 of 30,
/// 2 048 ε: 1 of 30; uncapped: none).
#[inline(never)]
#[cfg_attr(not(feature = "los-residual-3d"), allow(dead_code))]
pub(super) fn stabilise<T: Real, const N: usize>(p: &mut SMatrix<T, N, N>, info_ratio: T) {
    let delta = stabilising_delta(info_ratio);
    for i in 0..N {
        if let Some(v) = p.get_mut((i, i)) {
            *v += *v * delta;
        }
    }
}

/// The relative stabilising noise `δ = ρ ε` of [`stabilise`] (dimensionless) after an
/// update of information ratio `ρ`, ρ limited to [`max_information_ratio`] (which the
/// conditioning already ensures for a fused component).
#[inline(always)]
pub(super) fn stabilising_delta<T: Real>(info_ratio: T) -> T {
    let cap = max_information_ratio::<T>();
    let rho = if info_ratio < cap { info_ratio } else { cap };
    rho * T::EPS
}

/// Information ratio `hᵀPh / r` of a fused component (dimensionless), 0 when it was not
/// fused. A fused component has `hᵀPh ≥ 0` and `hᵀPh + r` finite ([`gate_scalar`]) and r at
/// least `hᵀPh / max_information_ratio` ([`conditioned_noise`]), so the ratio is finite and at
/// most [`max_information_ratio`].
#[inline(always)]
pub(super) fn information_ratio<T: Real>(rep: &FusionReport<T>, hph: T, r: T) -> T {
    if rep.outcome == FusionOutcome::Fused {
        hph / r
    } else {
        T::zero()
    }
}

/// The noise variance a scalar component is fused with: `r`, or `hph / kappa` when the
/// component would carry more information than the working precision resolves
/// ([`max_information_ratio`]); `true` when raised.
#[inline(always)]
pub(super) fn conditioned_noise<T: Real>(hph: T, r: T, kappa: T) -> (T, bool) {
    let floor = hph / kappa;
    if floor > r {
        (floor, true)
    } else {
        (r, false)
    }
}

/// The report of a component that could not be fused (non-finite numbers reported as 0).
pub(super) fn skipped_report<T: Real>(innovation: T) -> FusionReport<T> {
    let zero = T::zero();
    FusionReport {
        innovation: if innovation.is_finite() {
            innovation
        } else {
            zero
        },
        innovation_variance: zero,
        nis: zero,
        test_ratio: zero,
        outcome: FusionOutcome::Skipped,
    }
}

/// Innovation variance, NIS and gate of one scalar component with `hᵀPh = hph` (the shared
/// [`gate_scalar`]): the report and `1/s`. A component whose s is not finite and > 0 (or
/// hᵀPh < 0, or a non-finite innovation) is reported [`FusionOutcome::Skipped`] with `1/s = 0`.
pub(super) fn scalar_report<T: Real>(
    hph: T,
    r: T,
    innovation: T,
    gate: Gate<T>,
) -> (FusionReport<T>, T) {
    if !innovation.is_finite() {
        return (skipped_report(innovation), T::zero());
    }
    gate_scalar(innovation, hph, hph + r, gate)
        .unwrap_or_else(|| (skipped_report(innovation), T::zero()))
}

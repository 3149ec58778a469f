//! The discretised loop: the four aid modes in innovation form, their exact computation at
//! configuration, and the variable-interval correction of a step.

use crate::math::discretize::discretize;
use crate::{NavError, Real};
use nalgebra::{Matrix3, Matrix3x2, SMatrix, Vector2, Vector3};

/// One aid mode of the discretised loop in **innovation (delta) form**:
///
/// ```text
/// x̂⁺ = x̂ + N [V̂_z, A_z ± b̂]ᵀ + G [ν_h, ν_v]ᵀ,   N = M [e₁ e₂],  G = M K_m,
/// M = ∫₀^Δt exp(F_m s) ds,   F_m = A₀ − K_m C
/// ```
///
/// which is exactly `Φ x̂ + Γ u` (Φ = I + M F_m, Γ = M [e₂ K_m]) but never multiplies the
/// altitude itself by a coefficient: in f32, `Φ x̂ + Γ z` at 40 km cancels two terms of
/// 40 km · K Δt, and the diagonal of Φ = 1 − O(Δt/τ) keeps only a few digits of its small
/// part. It also costs 12 multiply-adds instead of 18.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Mode<T: Real> {
    pub(crate) n: Matrix3x2<T>,
    pub(crate) g: Matrix3x2<T>,
}

/// The four modes (none / baro / velocity / both).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Modes<T: Real> {
    /// Φ of the baro-only mode (analysis only, not used by the step).
    pub(crate) phi_baro: Matrix3<T>,
    pub(crate) none: Mode<T>,
    pub(crate) baro: Mode<T>,
    pub(crate) velocity: Mode<T>,
    pub(crate) both: Mode<T>,
}

impl<T: Real> Modes<T> {
    #[inline(always)]
    pub(crate) fn select(&self, baro: bool, velocity: bool) -> &Mode<T> {
        match (baro, velocity) {
            (false, false) => &self.none,
            (true, false) => &self.baro,
            (false, true) => &self.velocity,
            (true, true) => &self.both,
        }
    }
}

/// The continuous feedback of a loop, for off-nominal intervals: the observer gains
/// (columns baro, velocity), the baro lag compensation (s) and the sign of the bias state.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct Feedback<T: Real> {
    /// Continuous observer gains, columns baro, velocity.
    pub(crate) k: Matrix3x2<T>,
    /// Baro lag compensation (the classical loop's C4), s.
    pub(crate) lag_s: T,
    /// +1 when `V̇_z = A_z + b` (aided loop, spec's A), −1 when `V̇_z = A_z − b` (classical).
    pub(crate) bias_sign: T,
}

/// Which aids are in use in a step, as multipliers (1: in use, 0: not).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct AidMask<T> {
    pub(crate) baro: T,
    pub(crate) velocity: T,
}

/// Open-loop matrix of the observer state `[h, V_z, b]` (gravity handled outside):
/// `ḣ = V_z`, `V̇_z = A_z + bias_sign · b`.
pub(crate) fn open_loop(bias_sign: f64) -> Matrix3<f64> {
    Matrix3::new(0.0, 1.0, 0.0, 0.0, 0.0, bias_sign, 0.0, 0.0, 0.0)
}

/// One mode's discretisation: the mode and its Φ.
type ModeAndPhi<T> = (Mode<T>, Matrix3<T>);

/// Exact ZOH discretisation of `x̂' = (A₀ − K_m C) x̂ + [e₂ | K_m] u` for the four aid modes.
/// `k` columns: baro, velocity; `c` rows: baro, velocity.
pub(crate) fn discretise_modes<T: Real>(
    a0: &Matrix3<f64>,
    k: &Matrix3x2<f64>,
    c: &SMatrix<f64, 2, 3>,
    dt_s: f64,
) -> Result<Modes<T>, NavError> {
    let one = |use_baro: bool, use_vel: bool| -> Result<ModeAndPhi<T>, NavError> {
        let mut km = *k;
        if !use_baro {
            km.set_column(0, &Vector3::zeros());
        }
        if !use_vel {
            km.set_column(1, &Vector3::zeros());
        }
        let f = a0 - km * c;
        let mut aug = SMatrix::<f64, 7, 7>::zeros();
        aug.fixed_view_mut::<3, 3>(0, 0).copy_from(&f);
        // e₁ and e₂ as inputs (aug columns 3 and 4).
        for (r, col) in [(0, 3), (1, 4)] {
            if let Some(e) = aug.get_mut((r, col)) {
                *e = 1.0;
            }
        }
        aug.fixed_view_mut::<3, 2>(0, 5).copy_from(&km);
        let (phi_aug, _) = discretize(&aug, &SMatrix::<f64, 7, 7>::zeros(), dt_s)?;
        let phi: Matrix3<f64> = phi_aug.fixed_view::<3, 3>(0, 0).into_owned();
        let n: Matrix3x2<f64> = phi_aug.fixed_view::<3, 2>(0, 3).into_owned();
        let g: Matrix3x2<f64> = phi_aug.fixed_view::<3, 2>(0, 5).into_owned();
        if !phi
            .iter()
            .chain(n.iter())
            .chain(g.iter())
            .all(|v| v.is_finite())
        {
            return Err(NavError::NotConverged { iterations: 0 });
        }
        Ok((
            Mode {
                n: n.cast::<T>(),
                g: g.cast::<T>(),
            },
            phi.cast::<T>(),
        ))
    };
    let (baro, phi_baro) = one(true, false)?;
    Ok(Modes {
        phi_baro,
        none: one(false, false)?.0,
        baro,
        velocity: one(false, true)?.0,
        both: one(true, true)?.0,
    })
}

/// `F_m u = A₀ u − K_m C u` of the aid mode with the mask (1: aid in use).
#[inline(always)]
fn f_apply<T: Real>(fb: &Feedback<T>, mask: AidMask<T>, u: &Vector3<T>) -> Vector3<T> {
    let c = Vector2::new((u.x - fb.lag_s * u.y) * mask.baro, u.y * mask.velocity);
    Vector3::new(u.y, fb.bias_sign * u.z, T::zero()) - fb.k * c
}

/// `M(h) r = ∫₀^h exp(F_m s) ds r` by its Taylor series to `F³` (Horner), for `|h|` up to half
/// the nominal interval (relative error ≈ (|λ| h)⁴ / 120 for the loop's fastest pole λ).
#[inline(always)]
pub(crate) fn series_m<T: Real>(
    fb: &Feedback<T>,
    mask: AidMask<T>,
    h: T,
    r: &Vector3<T>,
) -> Vector3<T> {
    let f = |u: &Vector3<T>| f_apply(fb, mask, u);
    let mut w = r + f(r) * (h * T::lit(0.25));
    w = r + f(&w) * (h * T::lit(1.0 / 3.0));
    w = r + f(&w) * (h * T::lit(0.5));
    w * h
}

/// The increment `M(h) r` of one step of length `h_s` (nominal `dt_s`), with
/// `drive = [V̂_z, rate]` and `y₀ = M(dt) r` from the stored exact modes
/// (`y₀ = N drive + G ν`): for `h < dt/2` the series directly, otherwise
/// `M(dt) r + Φ(dt) M(h − dt) r` (`Φ(dt) w = w + N [w₂, ±w₃] − G C w`), exact up to the
/// series' truncation in `|h − dt| ≤ dt/2`.
#[cold]
#[inline(never)]
pub(crate) fn off_nominal_increment<T: Real>(
    fb: &Feedback<T>,
    mode: &Mode<T>,
    mask: AidMask<T>,
    h_s: T,
    dt_s: T,
    drive: &Vector2<T>,
    nu: &Vector2<T>,
) -> Vector3<T> {
    let r = Vector3::new(drive.x, drive.y, T::zero()) + fb.k * nu;
    if h_s < dt_s * T::lit(0.5) {
        return series_m(fb, mask, h_s, &r);
    }
    let w = series_m(fb, mask, h_s - dt_s, &r);
    let cw = Vector2::new(w.x - fb.lag_s * w.y, w.y);
    mode.n * drive + mode.g * nu + w + mode.n * Vector2::new(w.y, fb.bias_sign * w.z) - mode.g * cw
}

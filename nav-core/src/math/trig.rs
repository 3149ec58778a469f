//! Sine and cosine for the filters: `f32` computed in `f32` only (the kernel in
//! `sincos_f32`, whose module documentation gives the method, domain and accuracy), `f64` by
//! the library (`RealField::sin`/`cos`: `std` on the host, libm in `no_std`).
//!
//! # Domain and accuracy (`f32`)
//!
//! |x| ≤ [`F32_ACCURATE_DOMAIN_RAD`] = 8192 rad: error ≤ 2 ulp of the correctly rounded result;
//! beyond it the error grows, but the result always stays finite and in [−1, 1] for a finite
//! input; NaN and ±∞ give NaN (no panic).

use crate::real::Real;

/// Upper bound of |x| (rad) on which the `f32` implementation keeps its ≤ 2 ulp accuracy.
pub const F32_ACCURATE_DOMAIN_RAD: f32 = 8192.0;

/// `(sin x, cos x)`, x in rad. See the module documentation for the `f32` domain and accuracy.
#[inline]
pub fn sin_cos<T: Real>(x: T) -> (T, T) {
    x.trig_sin_cos()
}

/// `sin x`, x in rad.
#[inline]
pub fn sin<T: Real>(x: T) -> T {
    x.trig_sin()
}

/// `cos x`, x in rad.
#[inline]
pub fn cos<T: Real>(x: T) -> T {
    x.trig_cos()
}

/// `tan x = sin x / cos x`, x in rad (`f64`: the library `tan`).
#[inline]
pub fn tan<T: Real>(x: T) -> T {
    x.trig_tan()
}

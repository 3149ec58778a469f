//! Sine and cosine for the filters: `f32` computed in `f32` only (the kernel in
//! `real/sincos_f32.rs`, whose module documentation gives the method, domain and accuracy), `f64` by
//! the library (`RealField::sin`/`cos`: `std` on the host, libm in `no_std`).
//!
//! # Domain and accuracy (`f32`)
//!
//! |x| ≤ [`F32_ACCURATE_DOMAIN_RAD`] = 8192 rad: error ≤ 2 ulp of the correctly rounded result;
//! beyond it the error grows, but the result always stays finite and in [−1, 1] for a finite
//! input; NaN and ±∞ give NaN (no panic).

use crate::real::Real;

pub use crate::real::sincos_f32::F32_ACCURATE_DOMAIN_RAD;

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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::real::sincos_f32::sin_cos_f32;
    use crate::real::sincos_f32::tests::uniform;

    #[test]
    fn f32_wrappers_are_the_kernel() {
        assert_eq!(sin(0.3f32), sin_cos_f32(0.3).0);
        assert_eq!(cos(0.3f32), sin_cos_f32(0.3).1);
        assert_eq!(tan(0.3f32), sin_cos_f32(0.3).0 / sin_cos_f32(0.3).1);
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            assert!(sin(x).is_nan() && cos(x).is_nan() && tan(x).is_nan());
        }
    }

    #[test]
    fn f64_path_is_the_library() {
        use nalgebra::ComplexField;
        for x in uniform(11, 10_000, -100.0, 100.0).map(|v| f64::from(v) * 1.000_000_1) {
            assert_eq!(sin(x).to_bits(), ComplexField::sin(x).to_bits());
            assert_eq!(cos(x).to_bits(), ComplexField::cos(x).to_bits());
            assert_eq!(tan(x).to_bits(), ComplexField::tan(x).to_bits());
            let (s, c) = sin_cos(x);
            assert_eq!(
                (s.to_bits(), c.to_bits()),
                (sin(x).to_bits(), cos(x).to_bits())
            );
        }
    }
}

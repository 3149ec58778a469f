//! The float abstraction: every filter is generic over [`Real`], implemented for `f32` (the
//! target) and `f64` (host analysis).

use nalgebra::{ComplexField, RealField};

pub(crate) mod sincos_f32;

/// A real scalar the filters run on: `f32` on the flight computer, `f64` on the host.
///
/// Sealed: only `f32` and `f64` implement it.
pub trait Real: RealField + Copy + Default + sealed::Sealed {
    /// Converts an `f64` literal or parameter (rounding to nearest for `f32`).
    fn lit(x: f64) -> Self;
    /// Widens to `f64` (exact for both implementors).
    fn to_f64(self) -> f64;
    /// Machine epsilon of the type.
    const EPS: Self;
    /// Converts an integer count (exact below 2²⁴ for `f32`; a hardware conversion on the M4F).
    fn from_count(n: u32) -> Self;
    /// Rounds to the nearest `u32`; `None` when not finite, negative or above `u32::MAX`.
    fn to_u32_rounded(self) -> Option<u32>;
    /// `(sin x, cos x)`; use [`crate::math::trig::sin_cos`].
    #[doc(hidden)]
    fn trig_sin_cos(self) -> (Self, Self);
    /// `sin x`; use [`crate::math::trig::sin`].
    #[doc(hidden)]
    fn trig_sin(self) -> Self;
    /// `cos x`; use [`crate::math::trig::cos`].
    #[doc(hidden)]
    fn trig_cos(self) -> Self;
    /// `tan x`; use [`crate::math::trig::tan`].
    #[doc(hidden)]
    fn trig_tan(self) -> Self;
}

impl Real for f32 {
    #[inline(always)]
    fn lit(x: f64) -> Self {
        x as f32
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        f64::from(self)
    }
    const EPS: Self = f32::EPSILON;
    #[inline(always)]
    fn from_count(n: u32) -> Self {
        n as f32
    }
    #[inline]
    fn to_u32_rounded(self) -> Option<u32> {
        // 4 294 967 040 is the largest f32 below 2³².
        if self.is_finite() && (-0.5..4_294_967_040.0).contains(&self) {
            Some((self + 0.5) as u32)
        } else {
            None
        }
    }
    #[inline]
    fn trig_sin_cos(self) -> (Self, Self) {
        sincos_f32::sin_cos_f32(self)
    }
    #[inline]
    fn trig_sin(self) -> Self {
        sincos_f32::sin_cos_f32(self).0
    }
    #[inline]
    fn trig_cos(self) -> Self {
        sincos_f32::sin_cos_f32(self).1
    }
    #[inline]
    fn trig_tan(self) -> Self {
        let (s, c) = sincos_f32::sin_cos_f32(self);
        s / c
    }
}

impl Real for f64 {
    #[inline(always)]
    fn lit(x: f64) -> Self {
        x
    }
    #[inline(always)]
    fn to_f64(self) -> f64 {
        self
    }
    const EPS: Self = f64::EPSILON;
    #[inline(always)]
    fn from_count(n: u32) -> Self {
        f64::from(n)
    }
    #[inline]
    fn to_u32_rounded(self) -> Option<u32> {
        if self.is_finite() && (-0.5..4_294_967_295.5).contains(&self) {
            Some(libm::round(self) as u32)
        } else {
            None
        }
    }
    #[inline]
    fn trig_sin_cos(self) -> (Self, Self) {
        (ComplexField::sin(self), ComplexField::cos(self))
    }
    #[inline]
    fn trig_sin(self) -> Self {
        ComplexField::sin(self)
    }
    #[inline]
    fn trig_cos(self) -> Self {
        ComplexField::cos(self)
    }
    #[inline]
    fn trig_tan(self) -> Self {
        ComplexField::tan(self)
    }
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

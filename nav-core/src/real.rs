//! The float abstraction: every filter is generic over [`Real`], implemented for `f32` (the
//! target) and `f64` (host analysis).

use nalgebra::RealField;

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
}

mod sealed {
    pub trait Sealed {}
    impl Sealed for f32 {}
    impl Sealed for f64 {}
}

/// `true` when every element of the slice-like iterator is finite.
#[inline]
pub fn all_finite<'a, T: Real + 'a>(values: impl IntoIterator<Item = &'a T>) -> bool {
    values.into_iter().all(|v| v.is_finite())
}

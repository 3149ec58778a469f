//! Configuration-time designs as flat `f64` value lists.
//!
//! Every estimator that designs something at configuration (discretisation, Riccati gains,
//! gravity fit …) splits it into a *design* value (`TaDesign`, `ClassicalDesign`,
//! `AidedDesign`) computed by `compute(config)`, and a `from_design(config, &design, …)`
//! constructor that only validates and copies it. A flight computer can store the design
//! (flash, or generated at build time) and never link the design code.
//!
//! [`DesignValues`] writes a design to, and reads it back from, a flat list of `f64` of a fixed
//! length [`DesignValues::COUNT`]. `f32 → f64 → f32` is exact, so
//! `read_values(write_values(d)) == d` bit for bit for both float types. The value order of
//! each design is documented at its implementation; matrices are written column by column
//! (nalgebra's storage order).
//!
//! [`crate::transfer_alignment::TaDesign`]: `2 + 15 K²` values;
//! [`crate::vertical_channel::ClassicalDesign`]: 70 values;
//! [`crate::vertical_channel::AidedDesign`]: 110 values (each with its
//! [`crate::DesignStamp`] first).
//!
//! ```
//! use nav_core::design::DesignValues;
//! use nav_core::vertical_channel::{ClassicalConfig, ClassicalDesign, ClassicalLoop, InitialState};
//! use nav_core::Estimator;
//!
//! let cfg = ClassicalConfig::<f32>::paper();
//! let init = InitialState {
//!     time: nav_core::time::Timestamp::ZERO,
//!     altitude_m: 500.0_f32,
//!     vz_up_m_s: 0.0,
//!     accel_bias_m_s2: 0.0,
//! };
//!
//! // On the ground (or at build time): design and store.
//! let design = ClassicalLoop::design(&cfg)?;
//! let mut stored = [0.0_f64; ClassicalDesign::<f32>::COUNT];
//! design.write_values(&mut stored)?;
//!
//! // On board: load and run, no design code.
//! let loaded = ClassicalDesign::<f32>::read_values(&stored)?;
//! let lp = ClassicalLoop::from_design(&cfg, &loaded, &init)?;
//! assert_eq!(lp, ClassicalLoop::new(&cfg, &init)?);
//! # Ok::<(), nav_core::NavError>(())
//! ```
use crate::error::ConfigIssue;
use crate::{NavError, Real};
use nalgebra::SMatrix;

/// A design that can be stored as a flat list of exactly [`Self::COUNT`] `f64` values.
pub trait DesignValues: Sized {
    /// Number of values of the list.
    const COUNT: usize;

    /// Writes the design to `out`, which must hold exactly [`Self::COUNT`] values
    /// (else `CapacityExceeded`, and `out` is not modified).
    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError>;

    /// Reads a design from exactly [`Self::COUNT`] values. Errors:
    /// `InvalidConfig { field: "design values", issue: OutOfRange }` for a wrong length or a
    /// value out of its domain (e.g. a non-integer iteration count),
    /// `InvalidConfig { field: "design values", issue: NotFinite }` for NaN or ±∞.
    fn read_values(values: &[f64]) -> Result<Self, NavError>;
}

/// The error of a wrong-length or out-of-domain value list.
pub(crate) const BAD_VALUES: NavError = NavError::InvalidConfig {
    field: "design values",
    issue: ConfigIssue::OutOfRange,
};

/// The error of a non-finite value in a value list.
pub(crate) const NOT_FINITE: NavError = NavError::InvalidConfig {
    field: "design values",
    issue: ConfigIssue::NotFinite,
};

/// Sequential writer into a value list whose length has been checked.
pub(crate) struct ValueWriter<'a> {
    out: &'a mut [f64],
    next: usize,
}

impl<'a> ValueWriter<'a> {
    /// A writer over `out`, or `CapacityExceeded` if `out.len() != count`.
    pub(crate) fn new(out: &'a mut [f64], count: usize) -> Result<Self, NavError> {
        if out.len() != count {
            return Err(NavError::CapacityExceeded);
        }
        Ok(Self { out, next: 0 })
    }

    /// Appends one value (ignored past the end, which the length check rules out).
    pub(crate) fn push(&mut self, v: f64) {
        if let Some(slot) = self.out.get_mut(self.next) {
            *slot = v;
        }
        self.next += 1;
    }

    /// Appends one value of the float type.
    pub(crate) fn real<T: Real>(&mut self, v: T) {
        self.push(v.to_f64());
    }

    /// Appends a matrix of the float type, column by column.
    pub(crate) fn matrix<T: Real, const R: usize, const C: usize>(&mut self, m: &SMatrix<T, R, C>) {
        for v in m.iter() {
            self.real(*v);
        }
    }

    /// Appends an `f64` matrix, column by column.
    pub(crate) fn matrix_f64<const R: usize, const C: usize>(&mut self, m: &SMatrix<f64, R, C>) {
        for v in m.iter() {
            self.push(*v);
        }
    }

    /// `Ok` when exactly the checked number of values was written.
    pub(crate) fn finish(self) -> Result<(), NavError> {
        if self.next == self.out.len() {
            Ok(())
        } else {
            Err(NavError::CapacityExceeded)
        }
    }
}

/// Sequential reader of a value list whose length and finiteness have been checked.
pub(crate) struct ValueReader<'a> {
    values: core::slice::Iter<'a, f64>,
}

impl<'a> ValueReader<'a> {
    /// A reader over `values`: `BAD_VALUES` unless `values.len() == count`, `NOT_FINITE` if a
    /// value is NaN or ±∞.
    pub(crate) fn new(values: &'a [f64], count: usize) -> Result<Self, NavError> {
        if values.len() != count {
            return Err(BAD_VALUES);
        }
        if !values.iter().all(|v| v.is_finite()) {
            return Err(NOT_FINITE);
        }
        Ok(Self {
            values: values.iter(),
        })
    }

    /// The next value (`BAD_VALUES` past the end, which the length check rules out).
    pub(crate) fn value(&mut self) -> Result<f64, NavError> {
        self.values.next().copied().ok_or(BAD_VALUES)
    }

    /// The next value in the float type; `NOT_FINITE` if it overflows it (f32).
    pub(crate) fn real<T: Real>(&mut self) -> Result<T, NavError> {
        let v = T::lit(self.value()?);
        if v.is_finite() {
            Ok(v)
        } else {
            Err(NOT_FINITE)
        }
    }

    /// Fills `out` with the next `out.len()` values in the float type, in order ([`Self::real`]
    /// for each; stops at the first error). One looping copy per float type, whatever the
    /// matrix sizes read through it.
    #[inline(never)]
    pub(crate) fn fill<T: Real>(&mut self, out: &mut [T]) -> Result<(), NavError> {
        for v in out.iter_mut() {
            *v = self.real()?;
        }
        Ok(())
    }

    /// [`Self::fill`] for every slice of `parts`, in order.
    #[inline(never)]
    pub(crate) fn fill_parts<T: Real>(&mut self, parts: &mut [&mut [T]]) -> Result<(), NavError> {
        for p in parts.iter_mut() {
            self.fill(p)?;
        }
        Ok(())
    }

    /// Fills `out` with the next `out.len()` `f64` values, in order.
    #[inline(never)]
    pub(crate) fn fill_f64(&mut self, out: &mut [f64]) -> Result<(), NavError> {
        for v in out.iter_mut() {
            *v = self.value()?;
        }
        Ok(())
    }

    /// [`Self::fill_f64`] for every slice of `parts`, in order.
    #[inline(never)]
    pub(crate) fn fill_parts_f64(&mut self, parts: &mut [&mut [f64]]) -> Result<(), NavError> {
        for p in parts.iter_mut() {
            self.fill_f64(p)?;
        }
        Ok(())
    }

    /// `Ok` when every value was read.
    pub(crate) fn finish(mut self) -> Result<(), NavError> {
        if self.values.next().is_none() {
            Ok(())
        } else {
            Err(BAD_VALUES)
        }
    }
}

//! Typed errors shared by every estimator.
//!
//! An operation that returns an error leaves the estimator state exactly as it was.

use core::fmt;

/// Why a configuration value was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ConfigIssue {
    /// NaN or ±Inf.
    NotFinite,
    /// Zero or negative where a strictly positive value is required.
    NotPositive,
    /// Negative where a non-negative value is required.
    Negative,
    /// Outside the documented valid range.
    OutOfRange,
    /// A stored design computed for another configuration, or with another layout version
    /// ([`crate::contract::DesignStamp`]).
    DesignMismatch,
}

/// Every error nav-core can return.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum NavError {
    /// A configuration field was refused; `field` names it as in the config struct.
    InvalidConfig {
        /// Name of the configuration field.
        field: &'static str,
        /// What is wrong with it.
        issue: ConfigIssue,
    },
    /// An input sample contained NaN or ±Inf; `input` names it.
    NonFiniteInput {
        /// Name of the offending input.
        input: &'static str,
    },
    /// An input was finite but outside its documented physical range.
    InputOutOfRange {
        /// Name of the offending input.
        input: &'static str,
    },
    /// A time step was zero, negative, non-finite or larger than allowed.
    InvalidTimeStep,
    /// A time stamp did not increase.
    TimeNotIncreasing,
    /// Master data too old (or too new) to be matched with the slave history.
    MeasurementTimeOutOfWindow,
    /// The innovation variance `h P hᵀ + R` was not strictly positive and finite.
    InnovationVarianceNotPositive,
    /// An update or propagation would have made the covariance lose positive semi-definiteness
    /// (negative or non-finite variance on the diagonal).
    CovarianceNotPositiveSemiDefinite,
    /// An iterative solver (Riccati, Lyapunov, matrix exponential) did not converge.
    NotConverged {
        /// Iterations performed before giving up.
        iterations: u32,
    },
    /// A matrix that must be invertible was singular to working precision.
    SingularMatrix,
    /// A fixed-capacity buffer is full.
    CapacityExceeded,
}

impl fmt::Display for NavError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            NavError::InvalidConfig { field, issue } => {
                write!(f, "invalid configuration field `{field}`: {issue:?}")
            }
            NavError::NonFiniteInput { input } => write!(f, "input `{input}` is not finite"),
            NavError::InputOutOfRange { input } => write!(f, "input `{input}` is out of range"),
            NavError::InvalidTimeStep => f.write_str("invalid time step"),
            NavError::TimeNotIncreasing => f.write_str("time stamp did not increase"),
            NavError::MeasurementTimeOutOfWindow => {
                f.write_str("measurement time outside the matching window")
            }
            NavError::InnovationVarianceNotPositive => {
                f.write_str("innovation variance not strictly positive")
            }
            NavError::CovarianceNotPositiveSemiDefinite => {
                f.write_str("covariance would not be positive semi-definite")
            }
            NavError::NotConverged { iterations } => {
                write!(f, "solver did not converge in {iterations} iterations")
            }
            NavError::SingularMatrix => f.write_str("singular matrix"),
            NavError::CapacityExceeded => f.write_str("fixed capacity exceeded"),
        }
    }
}

impl core::error::Error for NavError {}

/// Checks a configuration value: finite and strictly positive.
///
/// The `require_*` checks are out of line (configuration time only): one copy per float type
/// instead of one per call site.
#[inline(never)]
pub fn require_positive<T: crate::Real>(field: &'static str, v: T) -> Result<T, NavError> {
    if !v.is_finite() {
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotFinite,
        })
    } else if v <= T::zero() {
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotPositive,
        })
    } else {
        Ok(v)
    }
}

/// An accepted range of a physical or configuration value, in the value's units (named ends
/// instead of a `(low, high)` pair). Whether an end is included is said where a range is
/// declared; the checks of the crate include both unless stated.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Bounds {
    /// Lower end.
    pub low: f64,
    /// Upper end.
    pub high: f64,
}

/// Checks a configuration value: finite and in [lo, hi] (`InvalidConfig` naming `field`).
#[inline(never)]
pub(crate) fn in_range<T: crate::Real>(
    field: &'static str,
    v: T,
    lo: T,
    hi: T,
) -> Result<(), NavError> {
    if !v.is_finite() {
        return Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotFinite,
        });
    }
    if v < lo || v > hi {
        return Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
}

/// Checks a configuration value: finite and non-negative.
#[inline(never)]
pub fn require_non_negative<T: crate::Real>(field: &'static str, v: T) -> Result<T, NavError> {
    if !v.is_finite() {
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotFinite,
        })
    } else if v < T::zero() {
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::Negative,
        })
    } else {
        Ok(v)
    }
}

/// Checks a configuration value: finite.
#[inline(never)]
pub fn require_finite<T: crate::Real>(field: &'static str, v: T) -> Result<T, NavError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::NotFinite,
        })
    }
}

/// Checks an input value: finite.
pub fn input_finite<T: crate::Real>(input: &'static str, v: T) -> Result<T, NavError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(NavError::NonFiniteInput { input })
    }
}

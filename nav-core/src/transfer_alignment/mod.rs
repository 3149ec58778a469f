//! Transfer alignment of a wing-mounted slave INS by angular-rate and acceleration matching,
//! with wing flexure (spec `transfer-alignment.md`; Yang & Shim 2000).
//!
//! - [`model`]: the 2nd-order (conventional, 9 states) and 3rd-order (proposed, 12 states)
//!   flexure models, per-axis exact discretisation and stationary initial covariance.
//! - [`measurement`]: samples, lever-arm compensation, z = [dω; df] and H of both filters.
//! - [`design`]: the configuration-time design ([`TaDesign`]: the discrete axis chains),
//!   so a flight build can construct the filter from a stored design without the
//!   discretisation code.
//! - [`filter`]: the filter ([`ConventionalFilter`], [`ProposedFilter`]).
//! - [`observability`]: observability matrix of a constant segment and the stripped
//!   observability matrix of piecewise-constant segments, with a numerical rank.
pub mod design;
pub mod filter;
pub mod measurement;
pub mod model;
pub mod observability;

pub use design::TaDesign;
pub use filter::{
    ConventionalFilter, ProposedFilter, RecoveryPolicy, StepReport, TaConfig, TaHealth,
    TransferAlignment, MAX_ANGULAR_ACCEL_RAD_S2, MAX_ANGULAR_RATE_RAD_S, MAX_SPECIFIC_FORCE_M_S2,
};
pub use measurement::{MasterSample, SlaveHistory, SlaveSample};
pub use model::{AxisFlexure, FlexureModel};

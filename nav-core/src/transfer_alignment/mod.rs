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
    ConventionalFilter, GapOutcome, Propagation, ProposedFilter, RecoveryPolicy, StepReport,
    TaConfig, TaHealth, TransferAlignment, ACCEL_NOISE_SIGMA_RANGE_M_S2, DEGRADED_HOLD_EPOCHS,
    MAX_ANGULAR_ACCEL_RAD_S2, MAX_ANGULAR_RATE_RAD_S, MAX_DT_S, MAX_FLEXURE_SIGMA_RAD,
    MAX_FLEXURE_TAU_S, MAX_GAP_STEPS, MAX_LEVER_ARM_M, MAX_MISALIGNMENT_RAD, MAX_MOUNT_SIGMA_RAD,
    MAX_SPECIFIC_FORCE_M_S2, MAX_VARIANCE_REDUCTION, MIN_DT_S, MIN_FLEXURE_SIGMA_RAD,
    MIN_FLEXURE_TAU_S, MIN_TAU_STEPS, NIS_GATE_RANGE, PSD_LOADING_EPS,
    RATE_NOISE_SIGMA_RANGE_RAD_S, SKIPPED_EPOCHS_FOR_REINIT,
};
pub use measurement::{MasterSample, SlaveHistory, SlaveSample};
pub use model::{AxisFlexure, FlexureModel};

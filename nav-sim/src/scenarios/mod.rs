//! Scenario runners, one module per scenario kind.

pub mod flexure_process;
pub mod vertical_channel;

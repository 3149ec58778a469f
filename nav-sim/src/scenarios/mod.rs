//! Scenario runners, one module per scenario kind.

pub mod consistency_campaign;
pub mod flexure_process;
pub mod mission;
pub mod seeker_ins;
pub mod transfer_alignment;
pub mod vertical_channel;
pub mod vertical_channel_faults;

//! The mission: one truth from captive carry to the landmark area, the ground on which the
//! three estimators are flown as one chain.

pub mod config;
pub mod profile;
pub mod sensors;
pub mod truth;

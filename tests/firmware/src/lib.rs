//! The firmware crate's shared code: [`harness`], what every image and example of
//! `tests/firmware` uses around nav-core (defmt over semihosting, exit codes, the fault and
//! panic handlers, instruction counts, stack painting, the golden comparison).
//!
//! The images are the binaries: `src/main.rs` (`nav-firmware`: golden replay of every filter
//! and the per-kernel costs), `src/bin/nav-mission.rs` (the flight navigator through the
//! recorded mission, per-tick costs), `src/bin/nav-size.rs` and `nav-size-onboard.rs` (the
//! flight program's use of nav-core, linked to measure its flash), and `examples/*.rs` (one
//! flight program per estimator and the navigator).
#![no_std]

pub mod harness;

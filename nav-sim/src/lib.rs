//! # nav-sim
//!
//! Host simulator for `nav-core`: synthetic truth and sensor data, seeded Monte Carlo, and
//! the reproduction of the three papers' experiments as `summary.json`, CSV time series and
//! PNG plots. It drives nav-core only through its public API, as a firmware would.
//!
//! Every scenario is a TOML file in `nav-sim/scenarios/` whose `kind` selects a runner in
//! [`scenarios::REGISTRY`]. One seed gives the same output bit for bit: run `i` draws from
//! ChaCha8 stream `i` of the seed, whatever the thread that runs it.

pub mod consistency;
pub mod flight_path;
pub mod golden;
pub mod montecarlo;
pub mod output;
pub mod plot;
pub mod processes;
pub mod replay;
pub mod rng;
pub mod scenario;
pub mod scenarios;
pub mod stats;
pub mod stress;
pub mod truth;

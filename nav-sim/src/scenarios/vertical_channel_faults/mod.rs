//! Vertical channel fault injection, kind `vc-fault-baro` (scenario `fault-baro`).
//!
//! The base experiment (`base_scenario`, the vertical-channel truth and sensors) is flown with
//! three baro faults in sequence: a spike (the baro reads `offset_m` too high for
//! `duration_s`), a frozen baro (it repeats its last good reading with fresh time stamps), and
//! a dropout (no samples). Both loops run twice on the same sensor stream: with the χ²
//! innovation gate (([`nav_core::vertical_channel::AidModel`], [`nav_core::Gate`])) and without it. A
//! fault-free twin (same noise, no faults) of each gated loop is the reference for "normal".
//!
//! Figures of merit, per loop and run: the pre-fault bound (max |δh| over
//! `pre_fault_window_s`), per fault the peak |δh| from its start to the next fault, and the
//! recovery time: from the end of the fault until |δh| is back within the pre-fault bound and
//! stays there for `hold_within_s` (0 if it never left). Gate counters (rejections,
//! re-acquisitions, resets) and the steps spent with the baro `Lost` are reported.

use crate::consistency::{Consistency, RunConsistency};
use crate::montecarlo::monte_carlo;
use crate::output::write_csv;
use crate::plot::{render, Figure, Panel, Series};
use crate::rng::{normal, SimRng};
use crate::scenario::{Context, Kind};
use crate::scenarios::vertical_channel::{
    load_config, loop_configs, push_consistency, Config, Profile, AXES,
};
use crate::truth::gravity_down_m_s2;
use anyhow::{anyhow, ensure, Result};
use nalgebra::Matrix2;
use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    Aid, AidModel, AidStatus, AidedLoop, BaroSample, ClassicalLoop, ImuSample, InitialState,
    ReacquisitionCounters, VelocitySample,
};
use nav_core::{AidCounters, Estimator, Gate, Real, RecoveryAction, RecoveryPolicy};
use serde::Deserialize;
use serde_json::{json, Value};

mod config;
mod report;
mod sensors;
mod simulate;
use config::faults;
pub use config::{base_config, load_fault_config, FaultConfig, GateConfig, Window};
pub use report::{recovery, summarise, Recovery};
use report::{write_consistency, write_run0};
use sensors::Baro;
pub use simulate::simulate;

/// The JSON summary type (re-exported for the cross-crate tests).
pub type Summary = Value;

/// `vc-fault-baro`.
pub const KIND: Kind = Kind {
    kind: "vc-fault-baro",
    about: "vertical channel: baro spike, frozen baro, baro dropout; gate, recovery",
    run: run_fault_baro,
};

/// The baro counters of one loop.
#[derive(Debug, Clone, Copy, Default)]
pub struct BaroCounts {
    /// Fused, rejected … samples.
    pub counters: AidCounters,
    /// Re-acquisitions and resets.
    pub reacquisition: ReacquisitionCounters,
}

/// The loops of a run: classical and aided, gated and not.
pub const VARIANTS: [&str; 4] = [
    "classical_gated",
    "classical_ungated",
    "aided_gated",
    "aided_ungated",
];

/// One run's series (at the output interval) and figures of merit.
#[derive(Debug, Clone, Default)]
pub struct FaultRun {
    /// Output epochs, s.
    pub t: Vec<f64>,
    /// True altitude, m.
    pub h_true: Vec<f64>,
    /// Baro reading delivered to the loops (NaN when none), m.
    pub h_baro: Vec<f64>,
    /// δh per variant (and the gated twins: index 4 classical, 5 aided), m.
    pub err_h: [Vec<f64>; 6],
    /// |δh| at the IMU rate per variant and twin (for the metrics), m.
    abs_err: [Vec<f64>; 6],
    /// Baro gate counters per variant (and twins).
    pub counters: [BaroCounts; 6],
    /// IMU steps with the baro `Lost` per variant.
    pub lost_steps: [usize; 6],
    /// Consistency samples of (h, V_z) at the output epochs per variant and twin, with the σ
    /// the loops report.
    pub consistency: Vec<RunConsistency>,
}

/// Runs the Monte Carlo (for the runner and the tests).
pub fn run_monte_carlo(
    fc: &FaultConfig,
    runs: usize,
    seed: u64,
    progress: bool,
) -> Result<(Vec<FaultRun>, f64)> {
    let cfg = base_config(fc)?;
    ensure!(
        fc.pre_fault_window_s[0] < fc.pre_fault_window_s[1]
            && fc.pre_fault_window_s[1] <= fc.spike.start_s
            && fc.spike.end_s <= fc.frozen.start_s
            && fc.frozen.end_s <= fc.dropout.start_s
            && fc.dropout.end_s < cfg.duration_s,
        "faults must follow the pre-fault window in order: spike, frozen, dropout"
    );
    let dt = 1.0 / cfg.imu_rate_hz;
    let out = monte_carlo("fault-baro", runs, seed, progress, |_, rng| {
        if cfg.precision == "f64" {
            simulate::<f64>(&cfg, fc, rng)
        } else {
            simulate::<f32>(&cfg, fc, rng)
        }
    });
    Ok((out.into_iter().collect::<Result<Vec<_>>>()?, dt))
}

fn run_fault_baro(ctx: &Context) -> Result<Value> {
    let fc: FaultConfig = ctx.config()?;
    let (runs, dt) = run_monte_carlo(&fc, ctx.runs, ctx.seed, ctx.progress)?;
    let r0 = runs
        .first()
        .ok_or_else(|| anyhow!("at least one run is needed"))?;
    write_run0(ctx, r0)?;
    let consistency = write_consistency(ctx, &runs)?;

    Ok(json!({
        "faults": {
            "spike": { "start_s": fc.spike.start_s, "end_s": fc.spike.end_s, "offset_m": fc.spike_offset_m },
            "frozen": { "start_s": fc.frozen.start_s, "end_s": fc.frozen.end_s },
            "dropout": { "start_s": fc.dropout.start_s, "end_s": fc.dropout.end_s },
        },
        "pre_fault_window_s": fc.pre_fault_window_s,
        "hold_within_s": fc.hold_within_s,
        "consistency": consistency,
        "loops": summarise(&runs, dt, &fc),
    }))
}

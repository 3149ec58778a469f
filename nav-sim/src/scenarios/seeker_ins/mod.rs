//! `seeker-ins`: Monte Carlo reproduction of the INS / image-sensor paper (spec
//! `seeker-aided-ins.md`, seed Figs. 3-4): the 17-state closed-loop EKF of
//! [`nav_core::seeker_ins`] aided by seeker gimbal angles to a known landmark, and the same
//! runs without aiding (free INS).
//!
//! Each run draws the Table 3 sensor errors (scale factor, misalignment, white noise, random
//! bias of the accelerometers and gyros; random-constant and white gimbal angle errors) and
//! the Table 4 initial errors, then flies the truth trajectory of [`trajectory`] twice with
//! the same random numbers: once with seeker updates (aided) and once without (free INS).
//!
//! Files by responsibility: [`trajectory`] (the truth), `sensors` (the drawn sensor errors
//! and their samples), `run` (one run of the filter and the Monte Carlo batches), `report`
//! (statistics, summaries, CSV and plots), `config` (the scenario file), [`fault`] (the
//! fault-injection scenario).

pub mod campaign;
mod config;
pub(crate) mod errors;
pub mod fault;
pub mod injection;
mod model_reduction;
mod report;
pub(crate) mod run;
pub(crate) mod sensors;
pub mod trajectory;

pub use config::{
    landmark_position, load_config, output_epochs, Config, FilterConfig, InitialErrorConfig,
    LandmarkConfig, RatesConfig, SensorConfig,
};
pub use errors::{ImuFaultTally, RunOutput, GROUPS};
pub use report::{statistics, Stats, CHANNELS};
pub use run::{
    monte_carlo_batches, monte_carlo_filters, simulate_run, simulate_run_faulted,
    simulate_run_with, Batches, FilterKind,
};

use crate::output::sig;
use crate::scenario::{Context, Kind};
use anyhow::{bail, Result};
use nav_core::seeker_ins::STATES;
use report::{summary_block, write_outputs};
use serde_json::json;

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "seeker-ins",
    about: "INS aided by seeker gimbal angles to a landmark (17-state EKF) vs free INS",
    run,
};

fn run(ctx: &Context) -> Result<serde_json::Value> {
    let cfg: Config = ctx.config()?;
    if !(cfg.rates.imu_hz > 0.0 && cfg.rates.seeker_hz > 0.0 && cfg.rates.covariance_hz > 0.0) {
        bail!("rates must be positive");
    }
    let truth = trajectory::generate(&cfg.trajectory, 1.0 / cfg.rates.imu_hz);
    let b = monte_carlo_filters(&cfg, &truth, ctx.runs, ctx.seed, ctx.progress, true)?;
    let (aided, free, first) = (&b.paper, &b.free, &b.first);
    write_outputs(ctx, &cfg, &truth, aided, free, first)?;
    let flight = b.flight.as_ref();
    write_consistency_plot(ctx, &cfg, aided, flight)?;
    let mut a = summary_block(aided);
    if let Some(obj) = a.as_object_mut() {
        obj.insert(
            "nis_mean_per_component".into(),
            json!(sig(aided.nis_mean, 4)),
        );
        obj.insert("components_fused".into(), json!(aided.fused));
        obj.insert("components_rejected".into(), json!(aided.rejected));
        obj.insert("updates_refused".into(), json!(aided.errors));
        obj.insert(
            "seeker_epochs_out_of_field_run0".into(),
            json!(aided.out_of_field),
        );
        obj.insert("consistency".into(), aided.consistency.summary());
    }
    let mut f = summary_block(free);
    if let Some(obj) = f.as_object_mut() {
        obj.insert("consistency".into(), free.consistency.summary());
    }
    let fl = flight.map(|st| {
        let mut v = summary_block(st);
        if let Some(obj) = v.as_object_mut() {
            obj.insert("consistency".into(), st.consistency.summary());
            obj.insert("components_fused".into(), json!(st.fused));
            obj.insert("components_rejected".into(), json!(st.rejected));
        }
        v
    });
    for (name, st) in [("paper", Some(aided)), ("flight", flight)] {
        if let Some(st) = st {
            let c = &st.consistency;
            println!(
                "  {name:>6} filter: NEES mean {:.2} (band {:?}), in band {:.2}, e²/σ² per group {:?}",
                c.mean_nees(),
                crate::consistency::nees_band_95(c.dof, c.runs),
                c.frac_in_band(),
                c.normalized_error_sq
                    .iter()
                    .map(|(n, v)| format!("{n} {v:.2}"))
                    .collect::<Vec<_>>()
            );
        }
    }
    println!(
        "  aided final RMS  lat {:.1} m  lon {:.1} m  alt {:.1} m | free INS lat {:.0} m lon {:.0} m alt {:.0} m | NEES mean {:.2} (17 dof)",
        aided.rms[0].last().unwrap_or(&f64::NAN),
        aided.rms[1].last().unwrap_or(&f64::NAN),
        aided.rms[2].last().unwrap_or(&f64::NAN),
        free.rms[0].last().unwrap_or(&f64::NAN),
        free.rms[1].last().unwrap_or(&f64::NAN),
        free.rms[2].last().unwrap_or(&f64::NAN),
        aided.consistency.mean_nees(),
    );
    Ok(json!({
        "trajectory": format!("{:?}", cfg.trajectory.shape),
        "filter_precision": cfg.filter.precision,
        "los_residual": cfg.filter.residual,
        "aided": a,
        "flight": fl,
        "free_ins": f,
        "consistency_groups": GROUPS.iter().map(|g| json!({"name": g.0, "states": [g.1, g.1 + g.2]})).collect::<Vec<_>>(),
        "consistency_note": "per group: NEES of the group / its dimension (mean 1 when consistent); \
            accelerometer and gyro bias truth = b + (S + M) u, the instrument's whole non-white \
            error at the true specific force / body rate u",
    }))
}

/// `consistency.png`: the run-averaged NEES of the paper filter and of the flight
/// configuration with the 95 % band.
fn write_consistency_plot(
    ctx: &Context,
    cfg: &Config,
    paper: &report::Stats,
    flight: Option<&report::Stats>,
) -> Result<()> {
    let mut panels = vec![paper.consistency.nees_panel("paper filter")];
    if let Some(f) = flight {
        panels.push(f.consistency.nees_panel("flight configuration"));
    }
    let (_, hi) = crate::consistency::nees_band_95(STATES, paper.runs);
    for p in &mut panels {
        p.y_range = Some((0.0, 2.5 * hi));
    }
    crate::plot::render(
        &crate::plot::Figure {
            title: format!(
                "{:?} trajectory: NEES of the 17 states, paper filter and flight configuration",
                cfg.trajectory.shape
            ),
            x_label: "time, s".into(),
            panels,
            columns: 1,
        },
        &ctx.out_dir.join("consistency.png"),
        1200,
        800,
    )
}

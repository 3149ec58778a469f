//! `flexure-process`: checks that the simulated Gauss-Markov processes (the wing-flexure truth
//! and the filters' models) have the configured standard deviation and correlation time.
//!
//! For each configured process it simulates long runs exactly (see [`crate::processes`]) and
//! reports the sample σ, the sample autocorrelation at lag τ (theory: 1/e), the lag where the
//! sample autocorrelation first falls below 1/e (theory: τ), and for 3rd-order processes the
//! RMS of the second derivative (theory: β² σ).

use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::processes::gauss_markov;
use crate::rng::SimRng;
use crate::scenario::{Context, Kind};
use crate::stats::autocorrelation;
use anyhow::{bail, Result};
use nav_core::math::markov::{GaussMarkov, MarkovOrder};
use serde::Deserialize;
use serde_json::json;

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "flexure-process",
    about: "simulated Gauss-Markov flexure: σ and correlation time against the configured ones",
    run,
};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Config {
    /// Sample interval, s.
    dt_s: f64,
    /// Length of each run, s.
    duration_s: f64,
    process: Vec<ProcessConfig>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct ProcessConfig {
    name: String,
    /// 1, 2 or 3.
    order: u8,
    /// Stationary 1σ, deg.
    sigma_deg: f64,
    /// Correlation time (autocorrelation at 1/e), s.
    tau_s: f64,
}

struct RunResult {
    sigma: f64,
    rho_at_tau: f64,
    tau_est: f64,
    top_rms: f64,
    acf: Vec<f64>,
}

fn simulate<const N: usize>(
    gm: &GaussMarkov<f64>,
    dt: f64,
    steps: usize,
    rng: &mut SimRng,
) -> Result<(Vec<f64>, Vec<f64>)> {
    let mut p = gauss_markov::<N>(gm, dt, rng)?;
    let mut x = Vec::with_capacity(steps);
    let mut top = Vec::with_capacity(steps);
    for _ in 0..steps {
        let s = p.step(rng);
        x.push(s[0]);
        top.push(s[N - 1]);
    }
    Ok((x, top))
}

fn one_run(pc: &ProcessConfig, cfg: &Config, rng: &mut SimRng) -> Result<RunResult> {
    let order = match pc.order {
        1 => MarkovOrder::First,
        2 => MarkovOrder::Second,
        3 => MarkovOrder::Third,
        o => bail!("process `{}`: order {o} (must be 1, 2 or 3)", pc.name),
    };
    let gm = GaussMarkov::new(order, pc.sigma_deg.to_radians(), pc.tau_s)
        .map_err(|e| anyhow::anyhow!("process `{}`: {e}", pc.name))?;
    let steps = (cfg.duration_s / cfg.dt_s).round() as usize;
    let (x, top) = match order {
        MarkovOrder::First => simulate::<1>(&gm, cfg.dt_s, steps, rng)?,
        MarkovOrder::Second => simulate::<2>(&gm, cfg.dt_s, steps, rng)?,
        MarkovOrder::Third => simulate::<3>(&gm, cfg.dt_s, steps, rng)?,
    };
    let n = x.len() as f64;
    let sigma = (x.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    let lag_tau = (pc.tau_s / cfg.dt_s).round() as usize;
    let max_lag = 3 * lag_tau;
    let acf: Vec<f64> = (0..=max_lag).map(|l| autocorrelation(&x, l)).collect();
    let e_inv = (-1f64).exp();
    let tau_est = acf
        .windows(2)
        .position(|w| w[1] < e_inv)
        .map(|k| {
            // Linear interpolation between lags k and k+1.
            let (a, b) = (acf[k], acf[k + 1]);
            (k as f64 + (a - e_inv) / (a - b)) * cfg.dt_s
        })
        .unwrap_or(f64::NAN);
    let top_rms = (top.iter().map(|v| v * v).sum::<f64>() / n).sqrt();
    Ok(RunResult {
        sigma,
        rho_at_tau: acf[lag_tau],
        tau_est,
        top_rms,
        acf,
    })
}

fn theory_acf(order: u8, x: f64) -> f64 {
    match order {
        1 => (-x).exp(),
        2 => (-x).exp() * (1.0 + x),
        _ => (-x).exp() * (1.0 + x + x * x / 3.0),
    }
}

fn run(ctx: &Context) -> Result<serde_json::Value> {
    let cfg: Config = ctx.config()?;
    if !(cfg.dt_s > 0.0 && cfg.duration_s > cfg.dt_s) {
        bail!("dt_s and duration_s must be positive with duration_s > dt_s");
    }
    let mut processes = Vec::new();
    let mut panels = Vec::new();
    for (pi, pc) in cfg.process.iter().enumerate() {
        let results = crate::montecarlo::monte_carlo(
            &pc.name,
            ctx.runs,
            ctx.seed.wrapping_add(pi as u64 * 1_000_003),
            ctx.progress,
            |_, rng| one_run(pc, &cfg, rng),
        );
        let results: Vec<RunResult> = results.into_iter().collect::<Result<_>>()?;
        let (entry, panel) = process_outputs(ctx, &cfg, pi, pc, &results)?;
        processes.push(entry);
        panels.push(panel);
    }
    render(
        &Figure {
            title: "Gauss-Markov flexure processes: simulated vs configured autocorrelation".into(),
            x_label: "lag, s".into(),
            columns: 2,
            panels,
        },
        &ctx.out_dir.join("autocorrelation.png"),
        1400,
        900,
    )?;
    Ok(json!({ "dt_s": cfg.dt_s, "duration_s": cfg.duration_s, "processes": processes }))
}

/// The outputs of process `pi` (`pc`) from its runs: `acf_<pi>.csv`, its summary entry (σ,
/// τ and the autocorrelation at τ simulated against configured; the second derivative's RMS
/// for the third order) and its autocorrelation panel.
fn process_outputs(
    ctx: &Context,
    cfg: &Config,
    pi: usize,
    pc: &ProcessConfig,
    results: &[RunResult],
) -> Result<(serde_json::Value, Panel)> {
    let m = results.len() as f64;
    let mean = |f: &dyn Fn(&RunResult) -> f64| results.iter().map(f).sum::<f64>() / m;
    let sigma_deg = mean(&|r| r.sigma).to_degrees();
    let rho = mean(&|r| r.rho_at_tau);
    let tau_est = mean(&|r| r.tau_est);
    let beta = MarkovOrder::Third.beta_tau() / pc.tau_s;
    let top_rms = mean(&|r| r.top_rms);
    let lags: Vec<f64> = (0..results[0].acf.len())
        .map(|l| l as f64 * cfg.dt_s)
        .collect();
    let acf_mean: Vec<f64> = (0..lags.len())
        .map(|l| results.iter().map(|r| r.acf[l]).sum::<f64>() / m)
        .collect();
    let beta_order = match pc.order {
        1 => 1.0,
        2 => MarkovOrder::Second.beta_tau(),
        _ => MarkovOrder::Third.beta_tau(),
    } / pc.tau_s;
    let acf_theory: Vec<f64> = lags
        .iter()
        .map(|t| theory_acf(pc.order, beta_order * t))
        .collect();
    let file = format!("acf_{pi}.csv");
    write_csv(
        &ctx.out_dir.join(&file),
        &["lag_s", "acf_simulated", "acf_theory"],
        &[&lags, &acf_mean, &acf_theory],
    )?;
    println!(
        "  {:<28} σ {:.4}° (cfg {:.4}°)  ρ(τ) {:.3} (1/e = 0.368)  τ̂ {:.3} s (cfg {:.3} s)",
        pc.name, sigma_deg, pc.sigma_deg, rho, tau_est, pc.tau_s
    );
    let mut entry = json!({
        "name": pc.name,
        "order": pc.order,
        "sigma_deg_configured": pc.sigma_deg,
        "sigma_deg_simulated": sig(sigma_deg, 5),
        "tau_s_configured": pc.tau_s,
        "tau_s_simulated": sig(tau_est, 5),
        "autocorrelation_at_tau": sig(rho, 5),
        "acf_csv": file,
    });
    if pc.order == 3 {
        entry["second_derivative_rms_rad_s2_simulated"] = json!(sig(top_rms, 5));
        entry["second_derivative_rms_rad_s2_theory"] =
            json!(sig(beta * beta * pc.sigma_deg.to_radians(), 5));
    }
    let panel = Panel {
        title: pc.name.clone(),
        y_label: "autocorrelation / σ²".into(),
        series: vec![
            Series::line("simulated", &lags, &acf_mean, 0),
            Series::dashed("theory", &lags, &acf_theory, 1),
            Series::dashed("1/e", &[0.0, lags[lags.len() - 1]], &[(-1f64).exp(); 2], 7),
        ],
        y_range: None,
    };
    Ok((entry, panel))
}

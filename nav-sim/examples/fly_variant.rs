//! Flies one variant of the navigator's consistency campaign (the same draw as
//! `cargo xtask sim consistency`), optionally with one knob changed, and prints its rows.
//!
//! `cargo run --release -p nav-sim --example fly_variant -- SEED VARIANT RUNS [KEY=VALUE ...]`
//! with keys `accel_sf_ppm`, `accel_mis_arcsec`, `gyro_sf_ppm`, `gyro_mis_arcsec`,
//! `accel_bias_ug`, `accel_noise_ug_rt_hz`, `gyro_bias_deg_h`, `gyro_arw_deg_rt_h` (truth and
//! design alike: the sensors' table), `weave_deg` (S-turn amplitude, 0: straight),
//! `master_att_scale` (the master INS's attitude error σ scaled, truth and reported σ alike),
//! `master_hz` (the master's message rate), `carry_course_deg` (the carry manoeuvre made a
//! course change of that size, same timing), `speed_m_s` (the speed after the boost, every
//! other draw the same), `flex_scale_x`, `flex_scale_y`, `flex_scale_z` (the wing flexure's
//! σ about that slave axis scaled), `mount_scale` (the mounting misalignment's σ scaled) and
//! `lever_scale` (the lever arm scaled), truth and the alignment's design alike; `imu_hz` (the
//! missile IMU's rate and the flight computer's tick: the length of the slave's interval
//! means), `f64=1` (the navigator in f64) and `history_every=N` (instead of the rows: the
//! ensemble RMS and √(mean σ²) of the three attitude components, mrad, every N output epochs
//! of the first 120 s, and at the hand-over).

use anyhow::{anyhow, bail, Result};
use nav_sim::scenarios::mission::report::reduce;
use nav_sim::scenarios::mission::{load_scenario, monte_carlo_runs};
use nav_sim::scenarios::navigator_campaign::{draw_variant_at_speed, fly_variant, DrawnVariant};
use nav_sim::scenarios::transfer_alignment::config::Precision;

fn main() -> Result<()> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let num = |i: usize| -> Result<u64> {
        args.get(i)
            .ok_or_else(|| anyhow!("usage: SEED VARIANT RUNS [KEY=VALUE ...]"))?
            .parse::<u64>()
            .map_err(Into::into)
    };
    let (seed, v, runs) = (num(0)?, num(1)? as usize, num(2)? as usize);
    let (base, _) = load_scenario("mission")?;
    let speed = args
        .iter()
        .skip(3)
        .find_map(|kv| kv.strip_prefix("speed_m_s="))
        .map(str::parse::<f64>)
        .transpose()?;
    let mut var = draw_variant_at_speed(&base, seed, v, speed);
    let mut history_every = None;
    for kv in args
        .iter()
        .skip(3)
        .filter(|kv| !kv.starts_with("speed_m_s="))
    {
        let (k, val) = kv
            .split_once('=')
            .ok_or_else(|| anyhow!("KEY=VALUE: {kv}"))?;
        let x: f64 = val.parse()?;
        if k == "history_every" {
            history_every = Some((x as usize).max(1));
        } else {
            apply(&mut var, k, x)?;
        }
    }
    println!("params {}", var.params);
    match history_every {
        Some(every) => print_history(&var, runs, every),
        None => print_rows(v, &var, runs),
    }
}

/// Sets knob `k` to `x` on the drawn variant.
fn apply(var: &mut DrawnVariant, k: &str, x: f64) -> Result<()> {
    let m = &mut var.scenario.mission;
    let s = &mut m.sensors;
    match k {
        "accel_sf_ppm" => s.accel_scale_factor_ppm = x,
        "accel_mis_arcsec" => s.accel_misalignment_arcsec = x,
        "gyro_sf_ppm" => s.gyro_scale_factor_ppm = x,
        "gyro_mis_arcsec" => s.gyro_misalignment_arcsec = x,
        "accel_bias_ug" => s.accel_bias_ug = x,
        "accel_noise_ug_rt_hz" => s.accel_noise_ug_rt_hz = x,
        "gyro_bias_deg_h" => s.gyro_bias_deg_h = x,
        "gyro_arw_deg_rt_h" => s.gyro_arw_deg_rt_h = x,
        "weave_deg" => m.profile.weave_amplitude_deg = x,
        "carry_course_deg" => {
            let p = &mut m.profile;
            p.carry_manoeuvre_axis =
                nav_sim::scenarios::mission::profile::CarryManoeuvreAxis::Course;
            p.carry_turn_deg = x;
            p.carry_speed_change_m_s = 0.0;
        }
        "master_hz" => m.master.rate_hz = x,
        "master_att_scale" => m.master.attitude_sigma_rad.iter_mut().for_each(|v| *v *= x),
        "flex_scale_x" => m.carry.flexure.sigma_deg[0] *= x,
        "flex_scale_y" => m.carry.flexure.sigma_deg[1] *= x,
        "flex_scale_z" => m.carry.flexure.sigma_deg[2] *= x,
        "mount_scale" => m.carry.mount_sigma_deg.iter_mut().for_each(|v| *v *= x),
        "lever_scale" => m.carry.lever_arm_m.iter_mut().for_each(|v| *v *= x),
        "imu_hz" => m.imu_hz = x,
        "f64" if x != 0.0 => var.scenario.navigator.precision = Precision::F64,
        "f64" => var.scenario.navigator.precision = Precision::F32,
        _ => bail!("unknown key {k}"),
    }
    Ok(())
}

/// The campaign's rows of the variant.
fn print_rows(v: usize, var: &DrawnVariant, runs: usize) -> Result<()> {
    for r in fly_variant(v, var, runs, false)? {
        let c = &r.consistency;
        let nes: Vec<String> = c
            .normalized_error_sq
            .iter()
            .map(|(n, x)| format!("{n}:{x:.2}"))
            .collect();
        let rms: Vec<String> = r.rms.iter().map(|(n, x)| format!("{n}:{x:.3}")).collect();
        println!(
            "{:9} nees/dof {:.3} in_band {:.2} | {} | {}",
            r.filter,
            c.mean_nees() / c.dof as f64,
            c.frac_in_band(),
            nes.join(" "),
            rms.join(" ")
        );
    }
    Ok(())
}

/// The attitude's ensemble RMS and σ over time (every `every` output epochs of the first
/// 120 s, and the last carry epoch).
fn print_history(var: &DrawnVariant, runs: usize, every: usize) -> Result<()> {
    let flights = monte_carlo_runs(
        &var.scenario,
        &Default::default(),
        runs,
        var.runs_seed,
        false,
        "history",
    )?;
    let records: Vec<_> = flights.iter().map(|r| &r.records[0]).collect();
    let st = reduce("full", &records);
    let last_carry = st
        .phase
        .iter()
        .rposition(|p| p.is_some_and(|p| p.name() == "carry"));
    println!("t_s phase | att_n RMS σ | att_e RMS σ | att_d RMS σ (mrad)");
    let picked = (0..st.t_s.len())
        .filter(|&k| k % every == 0 && st.t_s[k] <= 120.0)
        .chain(last_carry);
    for k in picked {
        let phase = st.phase[k].map_or("-", |p| p.name());
        let col = |c: usize| format!("{:.3} {:.3}", st.rms[c][k] * 1e3, st.sigma[c][k] * 1e3);
        println!(
            "{:7.1} {phase:9} | {} | {} | {}",
            st.t_s[k],
            col(6),
            col(7),
            col(8)
        );
    }
    Ok(())
}

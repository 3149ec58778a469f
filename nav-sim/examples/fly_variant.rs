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
//! σ about that slave axis scaled) and `mount_scale` (the mounting misalignment's σ scaled),
//! truth and the alignment's design alike.

use anyhow::{anyhow, bail, Result};
use nav_sim::scenarios::mission::load_scenario;
use nav_sim::scenarios::navigator_campaign::{draw_variant_at_speed, fly_variant};

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
    for kv in args
        .iter()
        .skip(3)
        .filter(|kv| !kv.starts_with("speed_m_s="))
    {
        let (k, val) = kv
            .split_once('=')
            .ok_or_else(|| anyhow!("KEY=VALUE: {kv}"))?;
        let x: f64 = val.parse()?;
        let s = &mut var.scenario.mission.sensors;
        match k {
            "accel_sf_ppm" => s.accel_scale_factor_ppm = x,
            "accel_mis_arcsec" => s.accel_misalignment_arcsec = x,
            "gyro_sf_ppm" => s.gyro_scale_factor_ppm = x,
            "gyro_mis_arcsec" => s.gyro_misalignment_arcsec = x,
            "accel_bias_ug" => s.accel_bias_ug = x,
            "accel_noise_ug_rt_hz" => s.accel_noise_ug_rt_hz = x,
            "gyro_bias_deg_h" => s.gyro_bias_deg_h = x,
            "gyro_arw_deg_rt_h" => s.gyro_arw_deg_rt_h = x,
            "weave_deg" => var.scenario.mission.profile.weave_amplitude_deg = x,
            "carry_course_deg" => {
                let p = &mut var.scenario.mission.profile;
                p.carry_manoeuvre_axis =
                    nav_sim::scenarios::mission::profile::CarryManoeuvreAxis::Course;
                p.carry_turn_deg = x;
                p.carry_speed_change_m_s = 0.0;
            }
            "master_hz" => var.scenario.mission.master.rate_hz = x,
            "master_att_scale" => {
                let a = &mut var.scenario.mission.master.attitude_sigma_rad;
                a.iter_mut().for_each(|v| *v *= x);
            }
            "flex_scale_x" => var.scenario.mission.carry.flexure.sigma_deg[0] *= x,
            "flex_scale_y" => var.scenario.mission.carry.flexure.sigma_deg[1] *= x,
            "flex_scale_z" => var.scenario.mission.carry.flexure.sigma_deg[2] *= x,
            "mount_scale" => var
                .scenario
                .mission
                .carry
                .mount_sigma_deg
                .iter_mut()
                .for_each(|v| *v *= x),
            _ => bail!("unknown key {k}"),
        }
    }
    println!("params {}", var.params);
    for r in fly_variant(v, &var, runs, false)? {
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

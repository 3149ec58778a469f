//! Golden vectors for the firmware: short runs of every filter, generated from the simulator's
//! truth, replayed on the host in f32 through [`nav_golden::replay`] (the same code the
//! firmware runs) and written as little-endian f32 files `<case>.in.f32` / `<case>.out.f32`,
//! with the case's design computed on the host as `<case>.design.f64` (empty for the seeker).

use crate::rng::{normal, run_rng};
use crate::scenarios::seeker_ins::{self, trajectory};
use crate::scenarios::transfer_alignment::{config::load_scenario, config::CaseConfig, truth};
use crate::scenarios::vertical_channel::{self, Profile};
use anyhow::{anyhow, Context, Result};
use nav_core::earth::normal_gravity_m_s2;
use nav_core::seeker_ins::{gimbal_angles_of, landmark_vector_ned, Landmark};
use nav_golden::{
    design_values, replay, replay_with, Case, Stored, CASES, LOS_EVERY, MAX_DESIGN_VALUES,
};
use std::path::Path;

/// Steps recorded per case.
pub const TA_STEPS: usize = 300;
/// VC steps (20 s at 100 Hz).
pub const VC_STEPS: usize = 2000;
/// Seeker INS steps (6 s at 100 Hz, LOS at 10 Hz).
pub const SEEKER_STEPS: usize = 600;

fn ta_inputs(seed: u64) -> Result<Vec<f32>> {
    let (cfg, _, _) = load_scenario::<CaseConfig>("ta-case2")?;
    let mut rng = run_rng(seed, 0);
    let run = truth::simulate(&cfg, &mut rng)?;
    let mut v = Vec::new();
    for (m, s) in run.master.iter().zip(&run.slave).take(TA_STEPS) {
        v.push(m.time.as_micros() as f32);
        v.extend(m.angular_rate_rad_s.iter().map(|x| *x as f32));
        v.extend(m.angular_accel_rad_s2.iter().map(|x| *x as f32));
        v.extend(m.specific_force_m_s2.iter().map(|x| *x as f32));
        v.push(s.time.as_micros() as f32);
        v.extend(s.angular_rate_rad_s.iter().map(|x| *x as f32));
        v.extend(s.specific_force_m_s2.iter().map(|x| *x as f32));
    }
    Ok(v)
}

fn vc_inputs(seed: u64) -> Result<Vec<f32>> {
    let cfg = vertical_channel::load_config("vc-response")?;
    let profile = Profile::new(&cfg.profile)?;
    let mut rng = run_rng(seed, 1);
    let lat = nav_core::vertical_channel::PAPER_LATITUDE_RAD;
    let bias = 9.806_65e-3; // 1 mg, m/s²
    let dt = nav_golden::VC_DT_S;
    let mut v = Vec::new();
    for k in 0..VC_STEPS {
        let t = (k + 1) as f64 * dt;
        let (h, vz, a) = profile.at(t);
        let f_up = a + normal_gravity_m_s2(lat, h) + bias + normal(&mut rng, 0.01);
        let baro_valid = (k + 1) % 4 == 0;
        let vel_valid = (k + 1) % 10 == 0;
        v.extend([
            ((k + 1) as f64 * dt * 1000.0).round() as f32, // ms
            f_up as f32,
            f32::from(u8::from(baro_valid)),
            (h + normal(&mut rng, 1.0)) as f32,
            f32::from(u8::from(vel_valid)),
            (vz + normal(&mut rng, 0.1)) as f32,
        ]);
    }
    Ok(v)
}

fn seeker_inputs(seed: u64) -> Result<Vec<f32>> {
    let cfg = seeker_ins::load_config("seeker-straight")?;
    let truth = trajectory::generate(&cfg.trajectory, f64::from(nav_golden::INS_DT_S));
    let lm = Landmark::<f64>::new(nav_golden::seeker_landmark_position())
        .map_err(|e| anyhow!("landmark: {e}"))?;
    let mut rng = run_rng(seed, 2);
    let sigma = 0.17f64.to_radians();
    let mut v = Vec::new();
    for k in 1..=SEEKER_STEPS {
        let inc = truth.imu.get(k).context("trajectory too short")?;
        v.extend(inc.delta_theta_rad.iter().map(|x| *x as f32));
        v.extend(inc.delta_v_m_s.iter().map(|x| *x as f32));
        if k % LOS_EVERY == 0 {
            let d = landmark_vector_ned(&truth.position[k], &lm);
            let u_b = truth.c_b_n[k].transpose() * d.normalize();
            let g = gimbal_angles_of(&u_b);
            v.extend([
                1.0,
                (g.pitch_rad + normal(&mut rng, sigma)) as f32,
                (g.yaw_rad + normal(&mut rng, sigma)) as f32,
            ]);
        } else {
            v.extend([0.0, 0.0, 0.0]);
        }
    }
    Ok(v)
}

fn to_bytes(v: &[f32]) -> Vec<u8> {
    v.iter().flat_map(|x| x.to_le_bytes()).collect()
}

/// Writes the golden inputs and host outputs of every case into `dir`; returns
/// `(case, steps)` per case.
pub fn record(dir: &Path, seed: u64) -> Result<Vec<(Case, usize)>> {
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    let mut done = Vec::new();
    for case in CASES {
        let inputs = match case {
            Case::Ta9 | Case::Ta12 => ta_inputs(seed)?,
            Case::VcClassical | Case::VcAided => vc_inputs(seed)?,
            Case::SeekerIns => seeker_inputs(seed)?,
        };
        let in_bytes = to_bytes(&inputs);
        let mut outputs: Vec<f32> = Vec::new();
        let steps = replay(case, &in_bytes, &mut |_, out| {
            outputs.extend_from_slice(out)
        })
        .map_err(|e| anyhow!("{}: host replay failed: {e}", case.name()))?;
        anyhow::ensure!(
            outputs.iter().all(|x| x.is_finite()),
            "{}: non-finite host output",
            case.name()
        );
        std::fs::write(dir.join(format!("{}.in.f32", case.name())), &in_bytes)?;
        std::fs::write(
            dir.join(format!("{}.out.f32", case.name())),
            to_bytes(&outputs),
        )?;
        // The design computed on the host, replayed once more through `from_design` here
        // (the firmware does the same on the target): the stored design must give the same
        // outputs bit for bit.
        let mut values = [0f64; MAX_DESIGN_VALUES];
        let n = design_values(case, &mut values)
            .map_err(|e| anyhow!("{}: design failed: {e}", case.name()))?;
        let design: Vec<u8> = values
            .iter()
            .take(n)
            .flat_map(|x| x.to_le_bytes())
            .collect();
        if n > 0 {
            let stored = Stored {
                ta9: &design,
                ta12: &design,
                vc_classical: &design,
                vc_aided: &design,
            };
            let mut again: Vec<f32> = Vec::new();
            replay_with(case, &in_bytes, &stored, &mut |_, out| {
                again.extend_from_slice(out)
            })
            .map_err(|e| anyhow!("{}: replay with the stored design failed: {e}", case.name()))?;
            anyhow::ensure!(
                to_bytes(&again) == to_bytes(&outputs),
                "{}: the stored design does not reproduce the on-board design's outputs",
                case.name()
            );
        }
        std::fs::write(dir.join(format!("{}.design.f64", case.name())), design)?;
        done.push((case, steps));
    }
    Ok(done)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn recording_is_reproducible_and_replays_identically() {
        let a = std::env::temp_dir().join(format!("nav-golden-a-{}", std::process::id()));
        let b = std::env::temp_dir().join(format!("nav-golden-b-{}", std::process::id()));
        let ra = record(&a, 5).unwrap();
        let rb = record(&b, 5).unwrap();
        assert_eq!(ra, rb);
        for case in CASES {
            for f in ["in.f32", "out.f32", "design.f64"] {
                let f = format!("{}.{f}", case.name());
                assert_eq!(
                    std::fs::read(a.join(&f)).unwrap(),
                    std::fs::read(b.join(&f)).unwrap()
                );
            }
            let steps = ra.iter().find(|(c, _)| *c == case).unwrap().1;
            assert!(steps >= 300, "{}: {steps} steps", case.name());
        }
        let _ = std::fs::remove_dir_all(&a);
        let _ = std::fs::remove_dir_all(&b);
    }
}

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

/// Mission ticks (10 s at 100 Hz).
pub const MISSION_TICKS: usize = 1000;
/// Mission: the first master sample arrives at this tick (0.5 s: a late master), then every
/// second tick until the release.
const MISSION_MASTER_FROM: usize = 50;
/// Mission: master latency, ticks (30 ms).
const MISSION_MASTER_LATENCY: usize = 3;
/// Mission: the release signal at this tick (3 s); the missile falls free for 0.3 s, then
/// pulls out (the opposite acceleration for 0.3 s).
const MISSION_RELEASE: usize = 300;
const MISSION_DROP_TICKS: usize = 30;
/// Mission: baro every 4th tick (25 Hz), 1σ noise, m.
const MISSION_BARO_SIGMA_M: f64 = 0.5;
/// Mission: LOS every 10th tick from this tick on (7 s), 1σ noise 0.17°.
const MISSION_LOS_FROM: usize = 700;

/// The mission record's master message valid at tick `m` (26 values: flag, tick, attitude,
/// velocity m/s, position offsets, rate rad/s, angular acceleration rad/s², specific force
/// m/s²) onto `v`; `dt` is the tick, s.
fn master_record(truth: &trajectory::Truth, m: usize, dt: f64, v: &mut Vec<f32>) -> Result<()> {
    use nav_golden::mission::offsets_of;
    let rate = |j: usize| -> Result<nalgebra::Vector3<f64>> {
        Ok(truth.imu.get(j).context("trajectory")?.delta_theta_rad / dt)
    };
    let w = rate(m)?;
    let w_dot = (rate(m + 1)? - rate(m - 1)?) / (2.0 * dt);
    let f = truth.imu.get(m).context("trajectory")?.delta_v_m_s / dt;
    let c_m = truth.c_b_n.get(m).context("trajectory")?;
    let off = offsets_of(truth.position.get(m).context("trajectory")?);
    v.extend([1.0, m as f32]);
    v.extend(c_m.iter().map(|x| *x as f32));
    v.extend(
        truth
            .vel_ned_m_s
            .get(m)
            .context("trajectory")?
            .iter()
            .map(|x| *x as f32),
    );
    v.extend(off.iter().map(|x| *x as f32));
    v.extend(w.iter().map(|x| *x as f32));
    v.extend(w_dot.iter().map(|x| *x as f32));
    v.extend(f.iter().map(|x| *x as f32));
    Ok(())
}

/// The mission's inputs: the missile on an S-turn (±2° heading, 10 s period, banked) at
/// 200 m/s, 1000 m, east, under the aircraft until 3 s; the master INS (the same point: lever
/// arm zero) from 0.5 s every 20 ms, 30 ms late; release signal at 3 s and 0.3 s of free fall
/// then 0.3 s of pull-out; baro at 25 Hz throughout (the navigator uses it from midcourse);
/// LOS to the case's landmark at 10 Hz from 7 s. Noise from `seed` (stream 3).
fn mission_inputs(seed: u64) -> Result<Vec<f32>> {
    use nav_golden::mission::MISSION_INPUT_LEN;
    use trajectory::{Shape, TrajectoryConfig};
    let start = nav_golden::seeker_start();
    let cfg = TrajectoryConfig {
        shape: Shape::STurn,
        start_lat_deg: start.lat_rad.to_degrees(),
        start_lon_deg: start.lon_rad.to_degrees(),
        alt_m: start.alt_m,
        speed_m_s: 200.0,
        heading_deg: 90.0,
        duration_s: (MISSION_TICKS + 1) as f64 * 0.01,
        accel_start_s: 0.0,
        accel_m_s2: 0.0,
        s_amplitude_deg: 2.0,
        s_period_s: 10.0,
        coordinated_turn: true,
    };
    let dt = 0.01;
    let truth = trajectory::generate(&cfg, dt);
    let lm = Landmark::<f64>::new(nav_golden::seeker_landmark_position())
        .map_err(|e| anyhow!("landmark: {e}"))?;
    let mut rng = run_rng(seed, 3);
    let los_sigma = 0.17f64.to_radians();
    let g = 9.80665;
    // The drop: extra downward acceleration, velocity and displacement of the missile.
    let (mut vd, mut dd) = (0.0f64, 0.0f64);
    let mut v = Vec::with_capacity(MISSION_TICKS * MISSION_INPUT_LEN);
    for k in 1..=MISSION_TICKS {
        let inc = truth.imu.get(k).context("trajectory too short")?;
        let c = truth.c_b_n.get(k).context("trajectory too short")?;
        let a_down = if (MISSION_RELEASE..MISSION_RELEASE + MISSION_DROP_TICKS).contains(&k) {
            g
        } else if (MISSION_RELEASE + MISSION_DROP_TICKS..MISSION_RELEASE + 2 * MISSION_DROP_TICKS)
            .contains(&k)
        {
            -g
        } else {
            0.0
        };
        vd += a_down * dt;
        dd += vd * dt;
        let dv = inc.delta_v_m_s + c.transpose() * nalgebra::Vector3::new(0.0, 0.0, a_down * dt);
        v.extend(inc.delta_theta_rad.iter().map(|x| *x as f32));
        v.extend(dv.iter().map(|x| *x as f32));
        // Master: its time of validity `MISSION_MASTER_LATENCY` ticks ago.
        let master = (MISSION_MASTER_FROM..MISSION_RELEASE).contains(&k) && k % 2 == 0;
        if master {
            master_record(&truth, k - MISSION_MASTER_LATENCY, dt, &mut v)?;
        } else {
            v.extend([0.0f32; 26]);
        }
        v.push(f32::from(u8::from(k == MISSION_RELEASE)));
        let mut pos = *truth.position.get(k).context("trajectory")?;
        pos.alt_m -= dd;
        if k % 4 == 0 {
            v.extend([
                1.0,
                (pos.alt_m + normal(&mut rng, MISSION_BARO_SIGMA_M)) as f32,
            ]);
        } else {
            v.extend([0.0, 0.0]);
        }
        if k >= MISSION_LOS_FROM && k % 10 == 0 {
            let d = landmark_vector_ned(&pos, &lm);
            let gim = gimbal_angles_of(&(c.transpose() * d.normalize()));
            v.extend([
                1.0,
                (gim.pitch_rad + normal(&mut rng, los_sigma)) as f32,
                (gim.yaw_rad + normal(&mut rng, los_sigma)) as f32,
            ]);
        } else {
            v.extend([0.0, 0.0, 0.0]);
        }
        anyhow::ensure!(v.len() == k * MISSION_INPUT_LEN, "mission record layout");
    }
    Ok(v)
}

/// Records the mission case into `dir` (`mission.in.f32`, `.out.f32`, `.design.f64`): the
/// design computed on the host, the navigator built from it as stored; returns the ticks and
/// the output records.
pub fn record_mission(dir: &Path, seed: u64) -> Result<(usize, Vec<f32>)> {
    let in_bytes = to_bytes(&mission_inputs(seed)?);
    let design: Vec<u8> = nav_golden::mission::mission_design_values()
        .map_err(|e| anyhow!("mission: design failed: {e}"))?
        .iter()
        .flat_map(|x| x.to_le_bytes())
        .collect();
    let mut outputs: Vec<f32> = Vec::new();
    let ticks = nav_golden::mission::replay_mission(&in_bytes, &design, &mut |_, out| {
        outputs.extend_from_slice(out)
    })
    .map_err(|e| anyhow!("mission: host replay failed: {e}"))?;
    anyhow::ensure!(
        outputs.iter().all(|x| x.is_finite()),
        "mission: non-finite host output"
    );
    std::fs::write(dir.join("mission.in.f32"), &in_bytes)?;
    std::fs::write(dir.join("mission.out.f32"), to_bytes(&outputs))?;
    std::fs::write(dir.join("mission.design.f64"), design)?;
    Ok((ticks, outputs))
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
    record_mission(dir, seed)?;
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

#[cfg(test)]
mod mission_tests {
    use super::*;
    use nav_golden::mission::MISSION_OUTPUT_LEN;

    /// The mission goes through every phase at the planned times, with every aid fused, and is
    /// recorded identically twice.
    #[test]
    fn mission_flies_every_phase_with_every_aid() {
        let dir = std::env::temp_dir().join(format!("nav-mission-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let (ticks, out) = record_mission(&dir, 5).unwrap();
        let (ticks2, out2) = record_mission(&dir, 5).unwrap();
        assert_eq!(ticks, MISSION_TICKS);
        assert_eq!((ticks2, to_bytes(&out2)), (ticks, to_bytes(&out)));
        let rec = |k: usize| &out[k * MISSION_OUTPUT_LEN..(k + 1) * MISSION_OUTPUT_LEN];
        let phase = |k: usize| rec(k)[19] as u8;
        let first = |p: u8| (0..ticks).find(|&k| phase(k) == p);
        let (rel, mid, term) = (first(1).unwrap(), first(2).unwrap(), first(3).unwrap());
        eprintln!("released at tick {rel}, midcourse {mid}, terminal {term}");
        for k in [0, 100, 299, 300, 399, 400, 699, 700, 800, 999] {
            eprintln!("{k}: {:?}", rec(k));
        }
        // Release within the confirmation window of the signal (record 299 = tick 300), coast 1 s,
        // terminal at the first LOS sample (tick 700).
        assert!((299..299 + 30).contains(&rel), "release at {rel}");
        assert_eq!(mid, rel + 100);
        assert_eq!(term, 699);
        assert!((1..ticks).all(|k| phase(k) >= phase(k - 1)));
        let last = rec(ticks - 1);
        assert!(last[22] >= 100.0, "master fused {}", last[22]);
        assert!(last[23] >= 100.0, "baro fused {}", last[23]);
        assert!(last[24] >= 40.0, "LOS components fused {}", last[24]);
        let _ = std::fs::remove_dir_all(&dir);
    }
}

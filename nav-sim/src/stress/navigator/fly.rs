//! One case flown: the mission's truth and inputs through the navigator, every accepted tick
//! checked.

use super::cases::Case;
use super::hostile::{hostile_call, HOSTILE};
use super::Nav;
use crate::rng::run_rng;
use crate::scenarios::mission::navigator_setup::{navigator_config, Variant};
use crate::scenarios::mission::run::{imu_tick, initial_from_master, master_nav};
use crate::scenarios::mission::sensors::{inputs, MasterMessage, MissionInputs, Tick};
use crate::scenarios::mission::truth::simulate;
use crate::stress::{CaseFinding, EstimatorStress, Tally};
use anyhow::{anyhow, Result};
use nalgebra::Vector3;
use nav_core::navigator::{AidState, Aids, MasterNav, Phase, TickReport};
use nav_core::seeker_ins::{GimbalAngles, LosSample};
use nav_core::time::Timestamp;
use nav_core::vertical_channel::BaroSample;

fn shift(t: Timestamp, off: u64) -> Timestamp {
    t.add_micros(off)
}

fn shifted(inp: &mut MissionInputs, off: u64) {
    for t in &mut inp.ticks {
        t.imu.time = shift(t.imu.time, off);
        for m in &mut t.master {
            m.time = shift(m.time, off);
            m.arrival = shift(m.arrival, off);
        }
        if let Some(b) = &mut t.baro {
            b.time = shift(b.time, off);
        }
        if let Some(s) = &mut t.seeker {
            s.time = shift(s.time, off);
        }
        if let Some(s) = &mut t.separation {
            *s = shift(*s, off);
        }
    }
}

fn aid_result(st: &AidState) -> Result<(), String> {
    match st {
        AidState::Refused(e) => Err(format!("{e:?}")),
        _ => Ok(()),
    }
}

fn check_tick(t: &mut Tally, rep: &TickReport<f32>, nav: &Nav) {
    let s = &rep.solution;
    let st = &s.state;
    let vals = [
        st.position.lat_rad,
        st.position.lon_rad,
        st.position.alt_m,
        st.vel_ned_m_s.x as f64,
        st.vel_ned_m_s.y as f64,
        st.vel_ned_m_s.z as f64,
        st.q_b_n.w as f64,
        st.q_b_n.i as f64,
        st.q_b_n.j as f64,
        st.q_b_n.k as f64,
    ];
    t.finite("solution", vals);
    let eps = f32::EPSILON as f64;
    let p9: Vec<f64> = s
        .nav_covariance
        .transpose()
        .iter()
        .map(|&v| v as f64)
        .collect();
    t.covariance("solution P (9)", &p9, 9, eps);
    if let Some(ekf) = nav.ekf() {
        let p: Vec<f64> = ekf
            .covariance()
            .transpose()
            .iter()
            .map(|&v| v as f64)
            .collect();
        t.covariance(&format!("EKF P (17), {:?}", rep.phase), &p, 17, eps);
    }
    if rep.phase == Phase::Carry {
        let p: Vec<f64> = nav
            .alignment()
            .covariance()
            .transpose()
            .iter()
            .map(|&v| v as f64)
            .collect();
        t.covariance("alignment P (15)", &p, 15, eps);
    }
}

fn garbage(m: &MasterMessage) -> MasterMessage {
    let mut g = *m;
    g.position.lat_rad += 5000.0 / 6.371e6;
    g.vel_ned_m_s += Vector3::new(50.0, -30.0, 10.0);
    let r = nalgebra::Rotation3::from_euler_angles(0.0, 0.0, 10f64.to_radians());
    g.c_m_n = r.matrix() * g.c_m_n;
    g
}

/// The aids of one tick in f32 (`garbage`: the master sample is replaced with a wrong one).
struct TickAids {
    master: Option<MasterNav<f32>>,
    baro: Option<BaroSample<f32>>,
    seeker: Option<LosSample<f32>>,
    separation: Option<Timestamp>,
    garbage: bool,
}

fn tick_aids(
    tick: &Tick,
    next: Option<MasterMessage>,
    garbage_now: bool,
    signal: bool,
) -> TickAids {
    TickAids {
        master: next.map(|m| {
            if garbage_now {
                master_nav::<f32>(&garbage(&m))
            } else {
                master_nav::<f32>(&m)
            }
        }),
        baro: tick.baro.map(|b| BaroSample {
            time: b.time,
            altitude_m: b.altitude_m as f32,
        }),
        seeker: tick.seeker.map(|s| LosSample {
            time: s.time,
            gimbal: GimbalAngles {
                pitch_rad: s.gimbal.pitch_rad as f32,
                yaw_rad: s.gimbal.yaw_rad as f32,
            },
        }),
        separation: tick.separation.filter(|_| signal),
        garbage: garbage_now && next.is_some(),
    }
}

/// One case's counts while it flies.
struct Flight {
    ticks: Tally,
    /// Master, baro, seeker.
    aids: [Tally; 3],
    hostile: u64,
    hostile_bad: Vec<String>,
    /// Carry, released, midcourse, terminal reached.
    seen: [bool; 4],
    seeker_after_midcourse: u64,
    separation_signalled: bool,
    /// The truth's release (the missile leaves the wing), and the navigator's.
    truth_release: Timestamp,
    released_at: Option<Timestamp>,
}

impl Flight {
    fn new(name: &str, truth_release: Timestamp) -> Self {
        Self {
            ticks: Tally::new(format!("{name} (ticks)")),
            aids: [
                Tally::new(format!("{name} (master)")),
                Tally::new(format!("{name} (baro)")),
                Tally::new(format!("{name} (seeker)")),
            ],
            hostile: 0,
            hostile_bad: Vec::new(),
            seen: [false; 4],
            seeker_after_midcourse: 0,
            separation_signalled: false,
            truth_release,
            released_at: None,
        }
    }

    /// An accepted tick: the checks and the aid counts.
    fn accepted(&mut self, rep: &TickReport<f32>, nav: &Nav, a: &TickAids) {
        check_tick(&mut self.ticks, rep, nav);
        if a.master.is_some() && !a.garbage {
            self.aids[0].call("master", &aid_result(&rep.master.state));
        }
        if a.baro.is_some() {
            self.aids[1].call("baro", &aid_result(&rep.baro.state));
        }
        if a.seeker.is_some() {
            self.aids[2].call("seeker", &aid_result(&rep.seeker.state));
            if matches!(rep.phase, Phase::Midcourse | Phase::Terminal) {
                self.seeker_after_midcourse += 1;
            }
        }
        if let Some(t) = rep.transition.filter(|t| t.from == Phase::Carry) {
            self.released_at.get_or_insert(t.time);
        }
        let i = match rep.phase {
            Phase::Carry => 0,
            Phase::Released => 1,
            Phase::Midcourse => 2,
            Phase::Terminal => 3,
        };
        self.seen[i] = true;
    }

    /// Phases that should have been reached and were not.
    fn phase_stalls(&self) -> Vec<String> {
        let seen = self.seen;
        let mut stalls = Vec::new();
        if !seen[1] && !seen[2] {
            let why = if self.separation_signalled {
                "signal sent"
            } else {
                "no signal"
            };
            stalls.push(format!("never released ({why})"));
        } else if !seen[2] {
            stalls.push("released but never in midcourse".to_string());
        }
        // A release declared while the missile is on the wing.
        if let Some(early_us) = self
            .released_at
            .and_then(|t| self.truth_release.micros_since(t))
            .filter(|us| *us > 0)
        {
            stalls.push(format!(
                "released {:.3} s before the missile left the wing",
                early_us as f64 * 1e-6
            ));
        }
        if seen[2] && !seen[3] && self.seeker_after_midcourse >= 50 {
            stalls.push(format!(
                "{} seeker samples in midcourse, never terminal",
                self.seeker_after_midcourse
            ));
        }
        stalls
    }

    fn finish(self, case: &Case) -> EstimatorStress {
        let stalls = self.phase_stalls();
        let mut part = EstimatorStress::default();
        part.add(self.ticks);
        for t in self.aids {
            part.add(t);
        }
        part.cases = 1;
        if part.permanent_stalls == 0 && !stalls.is_empty() {
            part.permanent_stalls = 1;
        }
        for s in stalls {
            part.findings.push(CaseFinding {
                case: case.name.clone(),
                finding: format!("stalled: {s}"),
            });
        }
        part.hostile_inputs = self.hostile;
        part.hostile_not_refused = self.hostile_bad.len() as u64;
        if let Some(first) = self.hostile_bad.first() {
            part.findings.push(CaseFinding {
                case: case.name.clone(),
                finding: format!(
                    "{} hostile inputs not refused or not without effect (first: {first})",
                    self.hostile_bad.len()
                ),
            });
        }
        part
    }
}

/// Flies one case.
pub(super) fn fly(case: &Case) -> Result<EstimatorStress> {
    let mut rng = run_rng(case.seed, 0);
    let cfg = &case.cfg;
    let truth = simulate(&cfg.profile, &cfg.carry, cfg.imu_dt_us(), &mut rng)?;
    let mut inp = inputs(cfg, &truth, &case.faults.faults(), &mut rng)?;
    shifted(&mut inp, case.offset_us);
    let config = navigator_config::<f32>(cfg, &case.set, Variant::Full)?;
    let release = truth
        .missile
        .imu
        .get(truth.release_index)
        .map_or(Timestamp::ZERO, |i| i.time);
    let mut f = Flight::new(&case.name, shift(release, case.offset_us));
    let mut nav: Option<Nav> = None;
    let mut queue: std::collections::VecDeque<MasterMessage> = Default::default();
    let mut last_imu_time = Timestamp::ZERO;
    let mut n_master = 0_u64;
    for (k, tick) in inp.ticks.iter().enumerate() {
        queue.extend(tick.master.iter().copied());
        let Some(n) = nav.as_mut() else {
            if let Some(first) = queue.pop_front() {
                let init = initial_from_master::<f32>(&first, cfg, tick.imu.time);
                nav = Some(Nav::new(&config, &init).map_err(|e| anyhow!("new: {e:?}"))?);
            }
            last_imu_time = tick.imu.time;
            continue;
        };
        let next = queue.pop_front();
        n_master += u64::from(next.is_some());
        let a = tick_aids(
            tick,
            next,
            case.garbage_master && n_master % 5 == 0,
            case.signal,
        );
        f.separation_signalled |= a.separation.is_some();
        let imu = imu_tick::<f32>(tick);
        // A hostile input before the genuine tick.
        if k % case.hostile_every == case.hostile_every - 1 {
            let which = (k / case.hostile_every) % HOSTILE.len();
            f.hostile += 1;
            let aids = Aids {
                master: a.master.as_ref(),
                baro: a.baro.as_ref(),
                seeker: a.seeker.as_ref(),
                separation: None,
            };
            if let Some(bad) = hostile_call(n, which, &imu, aids, last_imu_time) {
                let at = tick.imu.time.as_secs_f64();
                f.hostile_bad
                    .push(format!("{} at {at:.3} s: {bad}", HOSTILE[which]));
            }
        }
        let aids = Aids {
            master: a.master.as_ref(),
            baro: a.baro.as_ref(),
            seeker: a.seeker.as_ref(),
            separation: a.separation,
        };
        let r = n.tick(&imu, &aids);
        last_imu_time = tick.imu.time;
        if f.ticks.call("tick", &r) {
            if let Ok(rep) = r {
                f.accepted(&rep, n, &a);
            }
        }
    }
    Ok(f.finish(case))
}

//! One mission run through the flight navigator: the inputs of [`super::sensors::inputs`] fed
//! tick by tick to `nav_core::navigator::Navigator` (f32 as on the target, or f64), its
//! solution compared with the truth at the output epochs; the variants of "what each link
//! buys" fly the same truth and the same inputs.

use super::config::MissionConfig;
use super::navigator_setup::{navigator_config, NavigatorSettings, Variant, HISTORY};
use super::report::bias::{record_bias, BiasRecord};
use super::report::{FlightRecord, HandoverSample, PhaseTag, COMPONENTS};
use super::sensors::{inputs, MasterMessage, MissionFaults, MissionInputs, Tick};
use super::truth::{offset, simulate, MissionTruth};
use crate::consistency::RunConsistency;
use crate::rng::SimRng;
use crate::scenarios::seeker_ins::run::{table4_covariance, table4_state};
use crate::scenarios::transfer_alignment::config::Precision;
use crate::truth::{dcm_from_quaternion, ecef_to_ned, geodetic_to_ecef, vector_from_rotation};
use anyhow::{anyhow, Result};
use nalgebra::{Matrix3, SMatrix, Vector3};
use nav_core::contract::FusionOutcome;
use nav_core::navigator::{
    AidState, Aids, ImuTick, MasterNav, NavSolution, Navigator, NavigatorConfig, NavigatorInitial,
    Phase, SeparationStatus, TickReport,
};
use nav_core::seeker_ins::{ImuIncrement, InsState, LosSample, Position, SeekerInsInitial};
use nav_core::vertical_channel::BaroSample;
use nav_core::Real;

fn phase_tag(p: Phase) -> PhaseTag {
    match p {
        Phase::Carry => PhaseTag::Carry,
        Phase::Released => PhaseTag::Released,
        Phase::Midcourse => PhaseTag::Midcourse,
        Phase::Terminal => PhaseTag::Terminal,
    }
}

pub(crate) fn master_nav<T: Real>(m: &MasterMessage) -> MasterNav<T> {
    let v = |x: &Vector3<f64>| x.map(T::lit);
    MasterNav {
        time: m.time,
        c_m_n: m.c_m_n.map(T::lit),
        vel_ned_m_s: v(&m.vel_ned_m_s),
        position: m.position,
        angular_rate_rad_s: v(&m.angular_rate_rad_s),
        angular_accel_rad_s2: v(&m.angular_accel_rad_s2),
        specific_force_m_s2: v(&m.specific_force_m_s2),
        attitude_sigma_rad: v(&m.attitude_sigma_rad),
        velocity_sigma_m_s: v(&m.velocity_sigma_m_s),
        position_sigma_m: v(&m.position_sigma_m),
    }
}

/// The error (navigator − truth) of a solution: position NED m, velocity NED m/s, attitude
/// misalignment φ (`Ĉ = (I − [φ×]) C`, NED) rad.
fn nav_error<T: Real>(state: &InsState<T>, truth: &MissionTruth, k: usize) -> [f64; 9] {
    let m = &truth.missile;
    let p = &m.position[k];
    let e = &state.position;
    let dr = ecef_to_ned(p.lat_rad, p.lon_rad)
        * (geodetic_to_ecef(e.lat_rad, e.lon_rad, e.alt_m)
            - geodetic_to_ecef(p.lat_rad, p.lon_rad, p.alt_m));
    let dv = state.vel_ned_m_s.map(|x| x.to_f64()) - m.vel_ned_m_s[k];
    let q = state.q_b_n;
    let q64 = nalgebra::Quaternion::new(q.w.to_f64(), q.i.to_f64(), q.j.to_f64(), q.k.to_f64());
    let c = dcm_from_quaternion(&q64);
    let phi = -vector_from_rotation(&(c * m.c_b_n[k].transpose()));
    [dr.x, dr.y, dr.z, dv.x, dv.y, dv.z, phi.x, phi.y, phi.z]
}

/// Records one epoch of a solution.
fn record<T: Real>(
    out: &mut FlightRecord,
    sol: &NavSolution<T>,
    phase: Phase,
    truth: &MissionTruth,
    k: usize,
) {
    let e = nav_error(&sol.state, truth, k);
    let p: SMatrix<f64, 9, 9> = sol.nav_covariance.map(|x| x.to_f64());
    let sigma: [f64; 9] = std::array::from_fn(|i| p[(i, i)].max(0.0).sqrt());
    let ev = nalgebra::SVector::<f64, 9>::from(e);
    let nees = p.try_inverse().map_or(f64::NAN, |pi| ev.dot(&(pi * ev)));
    let es: [(f64, f64); 9] = std::array::from_fn(|i| (e[i], sigma[i]));
    let group: [f64; 3] = std::array::from_fn(|g| {
        let pg: Matrix3<f64> = p.fixed_view::<3, 3>(3 * g, 3 * g).into_owned();
        let eg = Vector3::new(e[3 * g], e[3 * g + 1], e[3 * g + 2]);
        pg.try_inverse().map_or(f64::NAN, |pi| eg.dot(&(pi * eg)))
    });
    out.group_nees.push(group);
    let t = truth.missile.t_s[k];
    out.t_s.push(t);
    out.phase.push(Some(phase_tag(phase)));
    out.err.push(e);
    out.sigma.push(sigma);
    out.consistency.push(t, nees, &es);
}

fn handover_sample<T: Real>(
    sol: &NavSolution<T>,
    truth: &MissionTruth,
    k: usize,
) -> HandoverSample {
    let e = nav_error(&sol.state, truth, k);
    let p: SMatrix<f64, 9, 9> = sol.nav_covariance.map(|x| x.to_f64());
    let pa: Matrix3<f64> = p.fixed_view::<3, 3>(6, 6).into_owned();
    let ea = Vector3::new(e[6], e[7], e[8]);
    HandoverSample {
        t_s: truth.missile.t_s[k],
        err_rad: [e[6], e[7], e[8]],
        sigma_rad: std::array::from_fn(|i| pa[(i, i)].max(0.0).sqrt()),
        nees: pa.try_inverse().map_or(f64::NAN, |pi| ea.dot(&(pi * ea))),
    }
}

/// Counts the aid outcomes of a tick report and logs the ticks that were not nominal.
fn count(out: &mut FlightRecord, rep: &TickReport<impl Real>, t_s: f64) {
    let mut tags = Vec::new();
    let d = &rep.degradation;
    if !matches!(
        d.separation,
        SeparationStatus::NotSignalled | SeparationStatus::Confirmed | SeparationStatus::Commanded
    ) {
        tags.push(format!("separation.{:?}", d.separation));
    }
    for (name, st) in [
        ("master", &rep.master.state),
        ("baro", &rep.baro.state),
        ("seeker", &rep.seeker.state),
    ] {
        let tag = match st {
            AidState::NotUsedInPhase | AidState::Waiting => continue,
            AidState::Fused => "fused",
            // Held for the next tick behind a LOS update: nominal, counted.
            AidState::Held => "held",
            AidState::Rejected => "rejected",
            AidState::Refused(_) => "refused",
            AidState::TimedOut => "timed_out",
        };
        let key = format!("{name}.{tag}");
        if tag != "fused" && tag != "held" {
            tags.push(key.clone());
        }
        bump(&mut out.aid_counts, key);
    }
    // The seeker's tick state is `Fused` when either LOS component was fused; its report
    // (`last`, the component with the larger NIS) then says whether the other one was
    // rejected by the gate: a false lock in one gimbal axis is rejected there and fused in the
    // other, and without this tag it would not show at all.
    if rep.seeker.state == AidState::Fused
        && rep
            .seeker
            .last
            .is_some_and(|l| l.outcome == FusionOutcome::Rejected)
    {
        let key = "seeker.component_rejected".to_string();
        tags.push(key.clone());
        bump(&mut out.aid_counts, key);
    }
    if !tags.is_empty() {
        out.events.push((t_s, phase_tag(rep.phase), tags));
    }
}

/// Adds one to the count of `key`.
fn bump(counts: &mut Vec<(String, u64)>, key: String) {
    match counts.iter_mut().find(|(k, _)| *k == key) {
        Some((_, n)) => *n += 1,
        None => counts.push((key, 1)),
    }
}

/// The aids of a tick in float type T.
struct TickAids<T> {
    master: Option<MasterNav<T>>,
    baro: Option<BaroSample<T>>,
    seeker: Option<LosSample<T>>,
}

fn cast_aids<T: Real>(
    tick: &Tick,
    master: Option<&MasterMessage>,
    variant: Variant,
) -> TickAids<T> {
    TickAids {
        master: master.map(master_nav::<T>),
        baro: tick.baro.map(|b| BaroSample {
            time: b.time,
            altitude_m: T::lit(b.altitude_m),
        }),
        seeker: tick
            .seeker
            .filter(|_| variant != Variant::NoSeeker)
            .map(|s| LosSample {
                time: s.time,
                gimbal: nav_core::seeker_ins::GimbalAngles {
                    pitch_rad: T::lit(s.gimbal.pitch_rad),
                    yaw_rad: T::lit(s.gimbal.yaw_rad),
                },
            }),
    }
}

pub(crate) fn imu_tick<T: Real>(tick: &Tick) -> ImuTick<T> {
    ImuTick {
        increment: ImuIncrement {
            time: tick.imu.time,
            delta_theta_rad: tick.imu.delta_theta_rad.map(T::lit),
            delta_v_m_s: tick.imu.delta_v_m_s.map(T::lit),
        },
        clipped: tick.clipped,
    }
}

/// The missile INS's start on the ground of the first master message: the master's state at
/// its time of validity moved through the nominal lever arm, its position carried forward to
/// the tick's time with its velocity (the bus latency).
/// Its covariance: the master's σ, and for the attitude the mount and flexure σ on top (the
/// missile's attitude is the master's until the alignment has estimated them).
pub(crate) fn initial_from_master<T: Real>(
    m: &MasterMessage,
    cfg: &MissionConfig,
    now: nav_core::time::Timestamp,
) -> NavigatorInitial<T> {
    let age_s = now.as_secs_f64() - m.time.as_secs_f64();
    let mut var = [0.0; 9];
    for a in 0..3 {
        var[a] = m.position_sigma_m[a].powi(2);
        var[3 + a] = m.velocity_sigma_m_s[a].powi(2);
        var[6 + a] = m.attitude_sigma_rad[a].powi(2)
            + cfg.carry.mount_sigma_deg[a].to_radians().powi(2)
            + cfg.carry.flexure.sigma_deg[a].to_radians().powi(2);
    }
    let l = m.c_m_n * Vector3::from(cfg.carry.lever_arm_m);
    let p = offset(&m.position, &(l + m.vel_ned_m_s * age_s));
    NavigatorInitial {
        time: now,
        state: InsState {
            position: Position {
                lat_rad: p.lat_rad,
                lon_rad: p.lon_rad,
                alt_m: p.alt_m,
            },
            vel_ned_m_s: m.vel_ned_m_s.map(T::lit),
            q_b_n: nav_core::math::rotation::dcm_to_quat(&m.c_m_n.map(T::lit)),
        },
        nav_covariance: SMatrix::<f64, 9, 9>::from_diagonal(&nalgebra::SVector::from(var))
            .map(T::lit),
    }
}

/// What a variant needs besides the inputs: the Table 4 initial state and P0 at release.
#[derive(Debug, Clone)]
pub struct Table4Release {
    /// Index of the release epoch.
    pub index: usize,
    /// Initial state (truth + drawn Table 4 errors) and P0.
    pub state: InsState<f64>,
    /// P0 of the 17 states.
    pub covariance: SMatrix<f64, 17, 17>,
}

/// The 9 × 9 navigation block of a Table 4 P0 in NED metres for the position (δL, δl scaled
/// by the mean earth radius, as Table 4 draws them; δh → δr_D with the sign).
fn table4_nav_covariance(p: &SMatrix<f64, 17, 17>) -> SMatrix<f64, 9, 9> {
    let r0 = nav_core::earth::MEAN_RADIUS_M;
    let d = [r0, r0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0];
    SMatrix::<f64, 9, 9>::from_fn(|i, j| p[(i, j)] * d[i] * d[j])
}

/// Draws the Table 4 initial state at release around the truth.
pub fn table4_release(
    cfg: &MissionConfig,
    truth: &MissionTruth,
    rng: &mut SimRng,
) -> Table4Release {
    let k = truth.release_index;
    let m = &truth.missile;
    let s = &cfg.sensors;
    Table4Release {
        index: k,
        state: table4_state(
            &cfg.initial_error,
            &m.position[k],
            &m.vel_ned_m_s[k],
            &m.c_b_n[k],
            rng,
        ),
        covariance: table4_covariance(
            &cfg.initial_error,
            &m.c_b_n[k],
            s.accel_bias_ug * 1e-6 * 9.806_65,
            s.gyro_bias_deg_h.to_radians() / 3600.0,
            s.seeker_bias_deg.to_radians(),
        ),
    }
}

/// A navigator started at the Table 4 release point (`time`): the release state and
/// covariance handed over as if the carry had produced them.
fn table4_start<T: Real, const K: usize, const NS: usize>(
    config: &NavigatorConfig<T>,
    t4: &Table4Release,
    time: nav_core::time::Timestamp,
) -> Result<Navigator<T, K, NS, HISTORY>> {
    let st = &t4.state;
    let p17: SMatrix<T, 17, 17> = t4.covariance.map(T::lit);
    let init = NavigatorInitial {
        time,
        nav_covariance: table4_nav_covariance(&t4.covariance).map(T::lit),
        state: InsState {
            position: st.position,
            vel_ned_m_s: st.vel_ned_m_s.map(T::lit),
            q_b_n: nalgebra::Quaternion::new(
                T::lit(st.q_b_n.w),
                T::lit(st.q_b_n.i),
                T::lit(st.q_b_n.j),
                T::lit(st.q_b_n.k),
            ),
        },
    };
    let mut nav = Navigator::new(config, &init).map_err(|e| anyhow!("{e}"))?;
    nav.release_with(&SeekerInsInitial {
        state: init.state,
        covariance: p17,
    })
    .map_err(|e| anyhow!("release_with: {e}"))?;
    Ok(nav)
}

/// Flies one variant over one run's inputs with the navigator `N` in float type T.
fn fly_with<T: Real, const K: usize, const NS: usize>(
    cfg: &MissionConfig,
    set: &NavigatorSettings,
    variant: Variant,
    truth: &MissionTruth,
    inp: &MissionInputs,
    t4: &Table4Release,
) -> Result<FlightRecord> {
    let config = navigator_config::<T>(cfg, set, variant)?;
    let every = ((cfg.imu_hz / set.output_hz).round() as usize).max(1);
    let mut out = FlightRecord {
        consistency: RunConsistency::new(&COMPONENTS),
        bias: BiasRecord::new(),
        ..FlightRecord::default()
    };
    let mut nav: Option<Navigator<T, K, NS, HISTORY>> = None;
    let mut queue: std::collections::VecDeque<MasterMessage> = Default::default();
    let mut last_phase: Option<Phase> = None;
    for tick in &inp.ticks {
        queue.extend(tick.master.iter().copied());
        if nav.is_none() {
            let start = if variant == Variant::Table4Initial {
                if tick.index < t4.index {
                    continue;
                }
                let n = table4_start::<T, K, NS>(&config, t4, tick.imu.time)?;
                queue.clear();
                n
            } else {
                let Some(first) = queue.pop_front() else {
                    continue;
                };
                let init = initial_from_master::<T>(&first, cfg, tick.imu.time);
                Navigator::new(&config, &init).map_err(|e| anyhow!("{e}"))?
            };
            nav = Some(start);
            continue;
        }
        let Some(n) = nav.as_mut() else { continue };
        let next = queue.pop_front();
        let a = cast_aids::<T>(tick, next.as_ref(), variant);
        let aids = Aids {
            master: a.master.as_ref(),
            baro: a.baro.as_ref(),
            seeker: a.seeker.as_ref(),
            separation: tick.separation,
        };
        let rep = n
            .tick(&imu_tick::<T>(tick), &aids)
            .map_err(|e| anyhow!("tick at {} s: {e}", tick.imu.time.as_secs_f64()))?;
        count(&mut out, &rep, truth.missile.t_s[tick.index]);
        let phase = rep.phase;
        if last_phase != Some(phase) {
            out.transitions
                .push((truth.missile.t_s[tick.index], phase_tag(phase)));
            if phase == Phase::Released && last_phase == Some(Phase::Carry) {
                out.handover = Some(handover_sample(&rep.solution, truth, tick.index));
            }
            last_phase = Some(phase);
        }
        if tick.index % every == 0 && truth.missile.t_s[tick.index] >= 1.0 - 1e-9 {
            record(&mut out, &rep.solution, phase, truth, tick.index);
            record_bias(&mut out, n, truth, inp, tick.index);
        }
    }
    Ok(out)
}

/// Flies one variant in the configured precision.
pub fn fly(
    cfg: &MissionConfig,
    set: &NavigatorSettings,
    variant: Variant,
    truth: &MissionTruth,
    inp: &MissionInputs,
    t4: &Table4Release,
) -> Result<FlightRecord> {
    match (set.precision, variant) {
        (Precision::F32, Variant::ConventionalAlignment) => {
            fly_with::<f32, 3, 9>(cfg, set, variant, truth, inp, t4)
        }
        (Precision::F32, _) => fly_with::<f32, 5, 15>(cfg, set, variant, truth, inp, t4),
        (Precision::F64, Variant::ConventionalAlignment) => {
            fly_with::<f64, 3, 9>(cfg, set, variant, truth, inp, t4)
        }
        (Precision::F64, _) => fly_with::<f64, 5, 15>(cfg, set, variant, truth, inp, t4),
    }
}

/// One Monte Carlo run: truth, inputs, Table 4 draw, then every variant on them.
#[derive(Debug, Clone)]
pub struct MissionRun {
    /// The truth (kept for the first run's figures).
    pub truth: Option<MissionTruth>,
    /// Time of the seeker's first lock, s.
    pub first_lock_s: Option<f64>,
    /// Per variant, its record.
    pub records: Vec<FlightRecord>,
}

/// Simulates run `r` and flies the variants.
pub fn simulate_run(
    cfg: &MissionConfig,
    set: &NavigatorSettings,
    variants: &[Variant],
    faults: &MissionFaults,
    keep_truth: bool,
    rng: &mut SimRng,
) -> Result<MissionRun> {
    let truth = simulate(&cfg.profile, &cfg.carry, cfg.imu_dt_us(), rng)?;
    let inp = inputs(cfg, &truth, faults, rng)?;
    let t4 = table4_release(cfg, &truth, rng);
    let records = variants
        .iter()
        .map(|v| fly(cfg, set, *v, &truth, &inp, &t4).map_err(|e| anyhow!("{}: {e}", v.name())))
        .collect::<Result<Vec<_>>>()?;
    Ok(MissionRun {
        truth: keep_truth.then_some(truth),
        first_lock_s: inp.first_lock_s,
        records,
    })
}

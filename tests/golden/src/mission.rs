//! The mission case: the flight navigator ([`MissionNavigator`]) through a short mission —
//! carry under a manoeuvring aircraft with the master INS arriving late, separation,
//! coast, baro midcourse, terminal with LOS updates — built from a design computed on the
//! host and stored ([`nav_core::navigator::Navigator::from_design`]), as the mission firmware image runs it.
//!
//! Files: `mission.in.f32` (records of [`MISSION_INPUT_LEN`] values, one per 100 Hz tick),
//! `mission.out.f32` (records of [`MISSION_OUTPUT_LEN`] values), `mission.design.f64`
//! ([`NavigatorDesign`] values, little-endian `f64`).

use crate::{decode_f64s, f32s, seeker_landmark_position, seeker_start, v3, val};
use nalgebra::{Matrix3, SMatrix, Vector3};
use nav_core::design::DesignValues;
use nav_core::math::rotation::{dcm_to_quat, euler_to_dcm};
use nav_core::navigator::{
    AidTimeouts, Aids, BaroDamping, BaroErrorModel, FlightNavigator, HandoverPriors, ImuTick,
    LeverArm, MasterNav, NavigatorConfig, NavigatorDesign, NavigatorInitial, SeparationCheck,
    TickReport,
};
use nav_core::seeker_ins::{
    ClipFlags, GimbalAngles, ImuIncrement, InsState, Landmark, LosSample, Position, SeekerInsConfig,
};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{PaperCase, TaConfig};
use nav_core::vertical_channel::BaroSample;
use nav_core::NavError;

/// Depth of the navigator's slave and INS histories, ticks (≥ the master's latency).
pub const MISSION_HISTORY: usize = 16;
/// The mission's navigator: the flight alignment filter, f32.
pub type MissionNavigator = FlightNavigator<f32, MISSION_HISTORY>;
/// The mission's stored design.
pub type MissionDesign = NavigatorDesign<f32, 5>;

/// IMU (and navigator tick) interval, µs (100 Hz).
pub const MISSION_DT_US: u64 = 10_000;
/// Earth radius of the position offsets in the records (both axes), m.
pub const OFFSET_RADIUS_M: f64 = 6_371_000.0;

/// Values per input record: `[Δθ(3) rad, Δv(3) m/s, master_valid (0|1), master time of
/// validity (tick index), C_m^n (9, column by column), master V_NED (3) m/s, master position
/// offsets north, east, up from [`seeker_start`] (3) m, master inertial body rate (3) rad/s,
/// its derivative (3) rad/s², master specific force (3) m/s², separation signal (0|1),
/// baro_valid (0|1), baro altitude m, los_valid (0|1), gimbal pitch, yaw rad]`.
pub const MISSION_INPUT_LEN: usize = 38;
/// Values per output record: `[position offsets north, east, up from [`seeker_start`] (3) m,
/// V_NED (3) m/s, q_b^n (4, i j k w), the 9 variances of the solution's covariance (m², m²/s²,
/// rad²), phase (0 carry … 3 terminal), health, baro error estimate m, fused master, baro, LOS
/// counts]`.
pub const MISSION_OUTPUT_LEN: usize = 25;

/// The 1σ the master INS reports with every sample (attitude rad, velocity m/s, position m).
pub const MASTER_SIGMA: (f32, f32, f32) = (2e-4, 0.05, 3.0);

/// The navigator's configuration: the flight alignment filter (paper case 1 at 100 Hz) with
/// the slave at the master's station (lever arm zero: the synthetic master is the missile's
/// truth), the flight EKF with [`seeker_landmark_position`], baro damping by the EKF, a coast
/// of 1 s.
pub fn mission_config() -> Result<NavigatorConfig<f32>, NavError> {
    let mut alignment = TaConfig::<f32>::flight(PaperCase::Case1);
    alignment.lever_arm_m = Vector3::zeros();
    Ok(NavigatorConfig {
        lever_arm: LeverArm {
            nominal_m: Vector3::zeros(),
            sigma_m: Vector3::from_element(0.01),
        },
        alignment,
        priors: HandoverPriors {
            accel_bias_sigma_m_s2: 1e-3,
            gyro_bias_sigma_rad_s: 5e-8,
            gimbal_bias_sigma_rad: 7e-4,
        },
        ins: SeekerInsConfig::flight(Landmark::new(seeker_landmark_position())?),
        imu_dt_s: 0.01,
        // The recorded master is 30 ms late; H = 16 ticks reach 0.14 s.
        max_master_latency_s: 0.1,
        separation: SeparationCheck {
            specific_force_jump_m_s2: 4.0,
            confirm_window_s: 0.3,
            unsignalled_onset_s: 0.3,
            coast_s: 1.0,
        },
        baro: BaroDamping::Ekf(BaroErrorModel {
            white_sigma_m: 1.0,
            markov_sigma_m: 5.0,
            markov_tau_s: 100.0,
            lag_s: 0.0,
        }),
        timeouts: AidTimeouts {
            master_s: 0.5,
            baro_s: 1.0,
            seeker_s: 2.0,
        },
    })
}

/// Where the navigator starts: at [`seeker_start`], east at 200 m/s, level, heading 90° (the
/// aircraft is banked in its turn: the master's first sample corrects the attitude), with
/// 5 m, 0.5 m/s, 10 mrad 1σ.
pub fn mission_initial() -> NavigatorInitial<f32> {
    let mut p = SMatrix::<f32, 9, 9>::zeros();
    for (i, v) in [25.0, 25.0, 25.0, 0.25, 0.25, 0.25, 1e-4, 1e-4, 1e-4]
        .into_iter()
        .enumerate()
    {
        p[(i, i)] = v;
    }
    NavigatorInitial {
        time: Timestamp::ZERO,
        state: InsState {
            position: seeker_start(),
            vel_ned_m_s: Vector3::new(0.0, 200.0, 0.0),
            q_b_n: dcm_to_quat(&euler_to_dcm(0.0, 0.0, core::f32::consts::FRAC_PI_2)),
        },
        nav_covariance: p,
    }
}

/// The mission's design, computed here (on the host: `nav-sim golden` stores it).
pub fn mission_design() -> Result<MissionDesign, NavError> {
    MissionNavigator::design(&mission_config()?)
}

/// Size of the stored design, `f64` values.
pub const MISSION_DESIGN_VALUES: usize = <MissionDesign as DesignValues>::COUNT;

/// The design's values as written to `mission.design.f64`.
pub fn mission_design_values() -> Result<[f64; MISSION_DESIGN_VALUES], NavError> {
    let mut v = [0f64; MISSION_DESIGN_VALUES];
    mission_design()?.write_values(&mut v)?;
    Ok(v)
}

/// The navigator from a stored design (little-endian `f64` bytes): no design code runs.
pub fn mission_navigator(design: &[u8]) -> Result<MissionNavigator, NavError> {
    let mut v = [0f64; MISSION_DESIGN_VALUES];
    if decode_f64s(design, &mut v) != MISSION_DESIGN_VALUES {
        return Err(NavError::CapacityExceeded);
    }
    MissionNavigator::from_design(
        &mission_config()?,
        &MissionDesign::read_values(&v)?,
        &mission_initial(),
    )
}

/// Lat/lon/alt of offsets north, east, up (m) from [`seeker_start`].
pub fn position_at(north_m: f64, east_m: f64, up_m: f64) -> Position {
    let o = seeker_start();
    Position {
        lat_rad: o.lat_rad + north_m / OFFSET_RADIUS_M,
        lon_rad: o.lon_rad + east_m / (OFFSET_RADIUS_M * libm::cos(o.lat_rad)),
        alt_m: o.alt_m + up_m,
    }
}

/// Offsets north, east, up (m) of `p` from [`seeker_start`] (the inverse of [`position_at`]).
pub fn offsets_of(p: &Position) -> [f64; 3] {
    let o = seeker_start();
    [
        (p.lat_rad - o.lat_rad) * OFFSET_RADIUS_M,
        (p.lon_rad - o.lon_rad) * OFFSET_RADIUS_M * libm::cos(o.lat_rad),
        p.alt_m - o.alt_m,
    ]
}

/// Everything that arrives at one tick, decoded from an input record.
#[derive(Debug, Clone, Copy)]
pub struct MissionTick {
    /// The IMU sample.
    pub imu: ImuTick<f32>,
    /// The master sample that arrived (late: its time of validity is earlier).
    pub master: Option<MasterNav<f32>>,
    /// The baro sample.
    pub baro: Option<BaroSample<f32>>,
    /// The seeker's LOS sample.
    pub los: Option<LosSample<f32>>,
    /// The release signal.
    pub separation: Option<Timestamp>,
}

impl MissionTick {
    /// Record `k` (0-based: the tick at `(k + 1) × 10 ms`).
    pub fn decode(k: usize, r: &[f32]) -> Self {
        let time = Timestamp::from_micros((k as u64 + 1) * MISSION_DT_US);
        let imu = ImuTick {
            increment: ImuIncrement {
                time,
                delta_theta_rad: v3(r, 0),
                delta_v_m_s: v3(r, 3),
            },
            clipped: ClipFlags::default(),
        };
        let master = (val(r, 6) != 0.0).then(|| {
            let (sa, sv, sp) = MASTER_SIGMA;
            let mut c = Matrix3::zeros();
            for (i, v) in c.iter_mut().enumerate() {
                *v = val(r, 8 + i);
            }
            MasterNav {
                // A whole tick index (exact in f32 below 2²⁴).
                time: Timestamp::from_micros(val(r, 7) as u64 * MISSION_DT_US),
                c_m_n: c,
                vel_ned_m_s: v3(r, 17),
                position: position_at(
                    f64::from(val(r, 20)),
                    f64::from(val(r, 21)),
                    f64::from(val(r, 22)),
                ),
                angular_rate_rad_s: v3(r, 23),
                angular_accel_rad_s2: v3(r, 26),
                specific_force_m_s2: v3(r, 29),
                attitude_sigma_rad: Vector3::new(sa, sa, 4.0 * sa),
                velocity_sigma_m_s: Vector3::from_element(sv),
                position_sigma_m: Vector3::from_element(sp),
            }
        });
        Self {
            imu,
            master,
            separation: (val(r, 32) != 0.0).then_some(time),
            baro: (val(r, 33) != 0.0).then_some(BaroSample {
                time,
                altitude_m: val(r, 34),
            }),
            los: (val(r, 35) != 0.0).then_some(LosSample {
                time,
                gimbal: GimbalAngles {
                    pitch_rad: val(r, 36),
                    yaw_rad: val(r, 37),
                },
            }),
        }
    }

    /// The aids of this tick.
    pub fn aids(&self) -> Aids<'_, f32> {
        Aids {
            master: self.master.as_ref(),
            baro: self.baro.as_ref(),
            seeker: self.los.as_ref(),
            separation: self.separation,
        }
    }
}

/// The output record of a tick.
pub fn mission_output(
    nav: &MissionNavigator,
    report: &TickReport<f32>,
    out: &mut [f32; MISSION_OUTPUT_LEN],
) {
    let s = &report.solution;
    let [n, e, u] = offsets_of(&s.state.position);
    let mut vals = [0f32; MISSION_OUTPUT_LEN];
    vals[0] = n as f32;
    vals[1] = e as f32;
    vals[2] = u as f32;
    for (o, v) in vals.iter_mut().skip(3).zip(s.state.vel_ned_m_s.iter()) {
        *o = *v;
    }
    for (o, v) in vals.iter_mut().skip(6).zip(s.state.q_b_n.coords.iter()) {
        *o = *v;
    }
    for (o, v) in vals
        .iter_mut()
        .skip(10)
        .zip(s.nav_covariance.diagonal().iter())
    {
        *o = *v;
    }
    vals[19] = f32::from(report.phase as u8);
    vals[20] = f32::from(report.health as u8);
    vals[21] = nav.baro_state().bias_m;
    vals[22] = report.master.counters.fused as f32;
    vals[23] = report.baro.counters.fused as f32;
    vals[24] = report.seeker.counters.fused as f32;
    *out = vals;
}

/// Replays the recorded mission (`inputs`: records of [`MISSION_INPUT_LEN`] values) through
/// the navigator built from the stored `design`, and calls `sink(tick, output record)` after
/// every tick. Returns the number of ticks; a refused tick is returned as its error (the
/// recording has none).
pub fn replay_mission(
    inputs: &[u8],
    design: &[u8],
    sink: &mut dyn FnMut(usize, &[f32]),
) -> Result<usize, NavError> {
    let mut nav = mission_navigator(design)?;
    let mut rec = [0f32; MISSION_INPUT_LEN];
    let mut out = [0f32; MISSION_OUTPUT_LEN];
    let mut ticks = 0;
    for (k, bytes) in inputs.chunks_exact(4 * MISSION_INPUT_LEN).enumerate() {
        for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
            *d = v;
        }
        let t = MissionTick::decode(k, &rec);
        let report = nav.tick(&t.imu, &t.aids())?;
        mission_output(&nav, &report, &mut out);
        sink(k, &out);
        ticks = k + 1;
    }
    Ok(ticks)
}

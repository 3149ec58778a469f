//! Golden-vector replay, shared by the host recorder and the firmware.
//!
//! `nav-sim golden` generates the inputs of a short run of each filter from its simulated
//! truth, runs them through [`replay`] on the host (f32) and writes both; the firmware image
//! runs the *same* [`replay`] on the recorded inputs on Cortex-M4F/M7 and compares its outputs
//! with the host's, value by value (bits, and the largest distance in units in the last place).
//!
//! Files are little-endian `f32` arrays: `<case>.in.f32` (records of [`Case::input_len`]
//! values) and `<case>.out.f32` (records of [`Case::output_len`] values), one record per step;
//! `<case>.design.f64` holds the case's configuration-time design computed on the host
//! ([`design_values`], little-endian `f64`), which the firmware replays through
//! [`Stored`] as well as with its own on-board design ([`OnBoard`]).
#![no_std]
#![forbid(unsafe_code)]

use nalgebra::Vector3;
use nav_core::design::DesignValues;
use nav_core::math::rotation::{dcm_to_quat, euler_to_dcm};
use nav_core::seeker_ins::{
    paper_initial_covariance, GimbalAngles, ImuIncrement, InsState, Landmark, LosSample, Position,
    SeekerIns, SeekerInsConfig, SeekerInsInitial,
};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{
    ConventionalFilter, MasterSample, PaperCase, ProposedFilter, SlaveSample, TaConfig, TaDesign,
    TaInitial,
};
use nav_core::vertical_channel::{
    AidedConfig, AidedDesign, AidedLoop, BaroSample, ClassicalConfig, ClassicalDesign,
    ClassicalLoop, ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, Gate, NavError};

pub mod mission;

/// A recorded filter run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Case {
    /// Conventional 9-state transfer alignment.
    Ta9,
    /// Proposed 12-state transfer alignment.
    Ta12,
    /// Classical vertical-channel loop.
    VcClassical,
    /// Velocity-aided vertical-channel loop.
    VcAided,
    /// Strapdown INS + 17-state EKF with LOS updates.
    SeekerIns,
}

/// Every case, in file order.
pub const CASES: [Case; 5] = [
    Case::Ta9,
    Case::Ta12,
    Case::VcClassical,
    Case::VcAided,
    Case::SeekerIns,
];

/// Largest output record.
pub const MAX_OUTPUT_LEN: usize = 16;

impl Case {
    /// File stem.
    pub const fn name(self) -> &'static str {
        match self {
            Case::Ta9 => "ta9",
            Case::Ta12 => "ta12",
            Case::VcClassical => "vc_classical",
            Case::VcAided => "vc_aided",
            Case::SeekerIns => "seeker_ins",
        }
    }

    /// Values per input record.
    ///
    /// * TA: `[t_m, ω_m(3), ω̇_m(3), f_m(3), t_s, ω_s(3), f_s(3)]` (s, rad/s, rad/s², m/s²).
    /// * VC: `[t, f_up, baro_valid, h_baro, velocity_valid, v_ref]` (s, m/s², 0|1, m, 0|1, m/s).
    /// * Seeker: `[Δθ(3), Δv(3), los_valid, gimbal_pitch, gimbal_yaw]` (rad, m/s, 0|1, rad).
    pub const fn input_len(self) -> usize {
        match self {
            Case::Ta9 | Case::Ta12 => 17,
            Case::VcClassical | Case::VcAided => 6,
            Case::SeekerIns => 9,
        }
    }

    /// Values per output record.
    ///
    /// * TA: `[θ(3), σ_θ(3)]` (rad).
    /// * VC: `[h, V_z]` (m, m/s).
    /// * Seeker: `[north, east, up offsets from the start (m), V_NED(3), q_b^n(4), σ of δL·R,
    ///   δl·R, δh (m)]`.
    pub const fn output_len(self) -> usize {
        match self {
            Case::Ta9 | Case::Ta12 => 6,
            Case::VcClassical | Case::VcAided => 2,
            Case::SeekerIns => 13,
        }
    }
}

/// Little-endian f32 values of a byte slice (a trailing partial value is ignored).
pub fn f32s(bytes: &[u8]) -> impl Iterator<Item = f32> + '_ {
    bytes.chunks_exact(4).map(|c| match *c {
        [a, b, c, d] => f32::from_le_bytes([a, b, c, d]),
        _ => f32::NAN,
    })
}

// ------------------------------------------------------------------ configurations

/// Filter step of the TA cases, s.
pub const TA_DT_S: f32 = 0.01;
/// IMU interval of the VC cases, s.
pub const VC_DT_S: f64 = 0.01;
/// IMU interval of the seeker case, s.
pub const INS_DT_S: f32 = 0.01;
/// [`INS_DT_S`] in µs (the seeker case's time stamps).
pub const INS_DT_US: u64 = 10_000;
/// Seeker case: LOS update every this many IMU samples.
pub const LOS_EVERY: usize = 10;

/// TA filter configuration: the paper's case 2 ([`TaConfig::paper`]) with the rate-difference
/// noise the vectors were recorded with.
pub fn ta_config() -> TaConfig<f32> {
    TaConfig {
        rate_noise_sigma_rad_s: 2.0e-4,
        ..TaConfig::paper(PaperCase::Case2)
    }
}

/// What the coarse alignment hands over in the TA cases: no prior knowledge (θ_m = 0).
pub fn ta_initial() -> TaInitial<f32> {
    TaInitial::default()
}

/// Classical loop configuration: the papers' ([`ClassicalConfig::paper`], no gate).
pub fn vc_classical_config() -> ClassicalConfig<f32> {
    ClassicalConfig::paper()
}

/// Aided loop configuration: the papers' ([`AidedConfig::paper`], no gate).
pub fn vc_aided_config() -> AidedConfig<f32> {
    AidedConfig::paper()
}

/// The χ² innovation gate the firmware images put on both VC loops (0.1 % false alarms, on
/// the papers' aid model [`nav_core::vertical_channel::AidModel::paper`]). The golden
/// recording runs without a gate.
pub fn vc_gate() -> Gate<f32> {
    Gate::Nis(10.83)
}

/// Initial state of both VC loops (the truth starts at 500 m, level).
pub fn vc_initial() -> InitialState<f32> {
    InitialState {
        time: Timestamp::ZERO,
        altitude_m: 520.0,
        vz_up_m_s: 2.0,
        accel_bias_m_s2: 0.0,
    }
}

/// Start of the seeker case: 37° N, 127° E, 1000 m, east at 200 m/s, level.
pub fn seeker_start() -> Position {
    let deg = core::f64::consts::PI / 180.0;
    Position {
        lat_rad: 37.0 * deg,
        lon_rad: 127.0 * deg,
        alt_m: 1000.0,
    }
}

/// Landmark of the seeker case: 70 km east, 2 km north of the start, on the ground.
pub fn seeker_landmark_position() -> Position {
    let deg = core::f64::consts::PI / 180.0;
    let lat0 = 37.0 * deg;
    Position {
        lat_rad: lat0 + 2000.0 / 6_356_000.0,
        lon_rad: 127.0 * deg + 70_000.0 / (6_386_000.0 * libm::cos(lat0)),
        alt_m: 0.0,
    }
}

/// The INS's initial state (the truth's, perturbed: 30 m north, 1 m/s east, 0.5° yaw).
pub fn seeker_initial() -> InsState<f32> {
    let mut p = seeker_start();
    p.lat_rad += 30.0 / 6_356_000.0;
    InsState {
        position: p,
        vel_ned_m_s: Vector3::new(0.0, 201.0, 0.0),
        q_b_n: dcm_to_quat(&euler_to_dcm(0.0, 0.0, 90.5f32.to_radians())),
    }
}

/// Seeker filter configuration: the paper's ([`SeekerInsConfig::paper`]) with the case's
/// landmark.
pub fn seeker_config() -> Result<SeekerInsConfig<f32>, NavError> {
    Ok(SeekerInsConfig::paper(Landmark::new(
        seeker_landmark_position(),
    )?))
}

/// Where the seeker filter starts: [`seeker_initial`] and the paper's P0.
pub fn seeker_start_state() -> SeekerInsInitial<f32> {
    SeekerInsInitial {
        state: seeker_initial(),
        covariance: paper_initial_covariance(),
    }
}

// ------------------------------------------------------------------ replay

fn v3(r: &[f32], at: usize) -> Vector3<f32> {
    Vector3::new(
        r.get(at).copied().unwrap_or(f32::NAN),
        r.get(at + 1).copied().unwrap_or(f32::NAN),
        r.get(at + 2).copied().unwrap_or(f32::NAN),
    )
}

fn val(r: &[f32], at: usize) -> f32 {
    r.get(at).copied().unwrap_or(f32::NAN)
}

/// A TA time stamp stored as whole µs in an f32 (exact below 2²⁴ µs = 16.7 s, the recorded
/// cases are 3 s long); a value that is not a whole number of µs saturates or truncates.
fn stamp(us: f32) -> Timestamp {
    Timestamp::from_micros(us as u64)
}

fn ta_samples(r: &[f32]) -> (MasterSample<f32>, SlaveSample<f32>) {
    (
        MasterSample {
            time: stamp(val(r, 0)),
            angular_rate_rad_s: v3(r, 1),
            angular_accel_rad_s2: v3(r, 4),
            specific_force_m_s2: v3(r, 7),
        },
        SlaveSample {
            time: stamp(val(r, 10)),
            angular_rate_rad_s: v3(r, 11),
            specific_force_m_s2: v3(r, 14),
        },
    )
}

/// `[t_ms, f_up, baro_valid, h_baro, velocity_valid, v_ref]` → IMU sample and the aid samples
/// that arrived (`t_ms`: the time stamp in whole milliseconds, exact in f32 up to 4.6 h).
fn vc_samples(
    r: &[f32],
) -> (
    ImuSample<f32>,
    Option<BaroSample<f32>>,
    Option<VelocitySample<f32>>,
) {
    // A whole non-negative number of milliseconds (the cast saturates, NaN gives 0).
    let t = Timestamp::from_millis(val(r, 0) as u64);
    let imu = ImuSample {
        time: t,
        specific_force_up_m_s2: val(r, 1),
    };
    let baro = (val(r, 2) != 0.0).then_some(BaroSample {
        time: t,
        altitude_m: val(r, 3),
    });
    let vel = (val(r, 4) != 0.0).then_some(VelocitySample {
        time: t,
        vz_up_m_s: val(r, 5),
    });
    (imu, baro, vel)
}

fn ta_output(theta: Vector3<f32>, sigma: Vector3<f32>, out: &mut [f32; MAX_OUTPUT_LEN]) {
    for (o, v) in out.iter_mut().zip(theta.iter().chain(sigma.iter())) {
        *o = *v;
    }
}

/// Where the filters' configuration-time designs (discretised chains, loop gains and
/// discretised modes) come from.
pub trait DesignSource {
    /// The conventional 9-state transfer-alignment filter for [`ta_config`].
    fn ta9(&self) -> Result<ConventionalFilter<f32>, NavError>;
    /// The proposed 12-state transfer-alignment filter for [`ta_config`].
    fn ta12(&self) -> Result<ProposedFilter<f32>, NavError>;
    /// The classical loop for [`vc_classical_config`], [`vc_initial`].
    fn vc_classical(&self) -> Result<ClassicalLoop<f32>, NavError>;
    /// The aided loop for [`vc_aided_config`], [`vc_initial`].
    fn vc_aided(&self) -> Result<AidedLoop<f32>, NavError>;
}

/// Designs computed by the filters' own constructors (`new`): on board, at start-up.
#[derive(Debug, Clone, Copy, Default)]
pub struct OnBoard;

impl DesignSource for OnBoard {
    fn ta9(&self) -> Result<ConventionalFilter<f32>, NavError> {
        ConventionalFilter::new(&ta_config(), &ta_initial())
    }
    fn ta12(&self) -> Result<ProposedFilter<f32>, NavError> {
        ProposedFilter::new(&ta_config(), &ta_initial())
    }
    fn vc_classical(&self) -> Result<ClassicalLoop<f32>, NavError> {
        ClassicalLoop::new(&vc_classical_config(), &vc_initial())
    }
    fn vc_aided(&self) -> Result<AidedLoop<f32>, NavError> {
        AidedLoop::new(&vc_aided_config(), &vc_initial())
    }
}

/// Designs computed on the ground and stored as [`DesignValues`] lists (little-endian `f64`
/// bytes, as written by [`design_values`] and `nav-sim golden` to `<case>.design.f64`): the
/// filters are built with `from_design`, so an image that only uses this source links none of
/// the design code (discretisation, Riccati solver, f64 gravity fit).
#[derive(Debug, Clone, Copy)]
pub struct Stored<'a> {
    /// [`TaDesign<f32, 3>`] values.
    pub ta9: &'a [u8],
    /// [`TaDesign<f32, 4>`] values.
    pub ta12: &'a [u8],
    /// [`ClassicalDesign<f32>`] values.
    pub vc_classical: &'a [u8],
    /// [`AidedDesign<f32>`] values.
    pub vc_aided: &'a [u8],
}

/// Reads a stored design of exactly `D::COUNT` little-endian f64 values.
fn read_design<D: DesignValues>(bytes: &[u8]) -> Result<D, NavError> {
    let mut v = [0f64; MAX_DESIGN_VALUES];
    let n = decode_f64s(bytes, &mut v);
    if n != D::COUNT {
        return Err(NavError::CapacityExceeded);
    }
    D::read_values(v.get(..n).ok_or(NavError::CapacityExceeded)?)
}

/// Little-endian f64 values of `bytes` into `out`; returns how many (`usize::MAX` when the
/// length is not a whole number of values or does not fit). One copy for every design type.
#[inline(never)]
pub(crate) fn decode_f64s(bytes: &[u8], out: &mut [f64]) -> usize {
    if bytes.len() % 8 != 0 || bytes.len() / 8 > out.len() {
        return usize::MAX;
    }
    for (d, c) in out.iter_mut().zip(bytes.chunks_exact(8)) {
        let mut b = [0u8; 8];
        b.copy_from_slice(c);
        *d = f64::from_le_bytes(b);
    }
    bytes.len() / 8
}

impl DesignSource for Stored<'_> {
    fn ta9(&self) -> Result<ConventionalFilter<f32>, NavError> {
        ConventionalFilter::from_design(&ta_config(), &read_design(self.ta9)?, &ta_initial())
    }
    fn ta12(&self) -> Result<ProposedFilter<f32>, NavError> {
        ProposedFilter::from_design(&ta_config(), &read_design(self.ta12)?, &ta_initial())
    }
    fn vc_classical(&self) -> Result<ClassicalLoop<f32>, NavError> {
        ClassicalLoop::from_design(
            &vc_classical_config(),
            &read_design(self.vc_classical)?,
            &vc_initial(),
        )
    }
    fn vc_aided(&self) -> Result<AidedLoop<f32>, NavError> {
        AidedLoop::from_design(
            &vc_aided_config(),
            &read_design(self.vc_aided)?,
            &vc_initial(),
        )
    }
}

/// Largest [`DesignValues::COUNT`] of the stored designs (the aided vertical loop).
pub const MAX_DESIGN_VALUES: usize = 275;

/// Computes the design of `case` (on the host, in f32 like the filters) and writes its
/// [`DesignValues`] to `out`; returns how many were written (0 for the seeker case, which has
/// no configuration-time design).
pub fn design_values(case: Case, out: &mut [f64; MAX_DESIGN_VALUES]) -> Result<usize, NavError> {
    fn put<D: DesignValues>(d: &D, out: &mut [f64]) -> Result<usize, NavError> {
        d.write_values(out.get_mut(..D::COUNT).ok_or(NavError::CapacityExceeded)?)?;
        Ok(D::COUNT)
    }
    match case {
        Case::Ta9 => put::<TaDesign<f32, 3>>(&ConventionalFilter::design(&ta_config())?, out),
        Case::Ta12 => put::<TaDesign<f32, 4>>(&ProposedFilter::design(&ta_config())?, out),
        Case::VcClassical => put(
            &ClassicalDesign::<f32>::compute(&vc_classical_config())?,
            out,
        ),
        Case::VcAided => put(&AidedDesign::<f32>::compute(&vc_aided_config())?, out),
        Case::SeekerIns => Ok(0),
    }
}

/// Replays recorded inputs (little-endian f32 records of `case.input_len()`) through the
/// case's filter in f32, built with designs computed on board ([`OnBoard`]), and calls
/// `sink(step, output record)` after every step. Returns the number of steps. A filter error
/// is returned as is (the recording has none).
pub fn replay(
    case: Case,
    inputs: &[u8],
    sink: &mut dyn FnMut(usize, &[f32]),
) -> Result<usize, NavError> {
    replay_with(case, inputs, &OnBoard, sink)
}

/// [`replay`] with the filters' designs taken from `designs` (dynamic, so the replay loop
/// and the filters' steps are instantiated once whatever the source).
pub fn replay_with(
    case: Case,
    inputs: &[u8],
    designs: &dyn DesignSource,
    sink: &mut dyn FnMut(usize, &[f32]),
) -> Result<usize, NavError> {
    let n_in = case.input_len();
    let n_out = case.output_len();
    let mut rec = [0f32; 17];
    let mut out = [0f32; MAX_OUTPUT_LEN];
    let records = inputs.chunks_exact(4 * n_in);
    let mut steps = 0usize;
    match case {
        Case::Ta9 => {
            let mut f = designs.ta9()?;
            for (k, bytes) in records.enumerate() {
                for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
                    *d = v;
                }
                let (m, s) = ta_samples(&rec);
                f.step(&m, &s)?;
                ta_output(f.theta(), f.theta_sigma_rad(), &mut out);
                sink(k, out.get(..n_out).unwrap_or(&[]));
                steps = k + 1;
            }
        }
        Case::Ta12 => {
            let mut f = designs.ta12()?;
            for (k, bytes) in records.enumerate() {
                for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
                    *d = v;
                }
                let (m, s) = ta_samples(&rec);
                f.step(&m, &s)?;
                ta_output(f.theta(), f.theta_sigma_rad(), &mut out);
                sink(k, out.get(..n_out).unwrap_or(&[]));
                steps = k + 1;
            }
        }
        Case::VcClassical => {
            let mut cl = designs.vc_classical()?;
            for (k, bytes) in records.enumerate() {
                for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
                    *d = v;
                }
                let (imu, baro, _) = vc_samples(&rec);
                cl.step(&imu, baro.as_ref())?;
                out[0] = cl.altitude_m();
                out[1] = cl.vz_up_m_s();
                sink(k, out.get(..n_out).unwrap_or(&[]));
                steps = k + 1;
            }
        }
        Case::VcAided => {
            let mut ai = designs.vc_aided()?;
            for (k, bytes) in records.enumerate() {
                for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
                    *d = v;
                }
                let (imu, baro, vel) = vc_samples(&rec);
                ai.step(&imu, baro.as_ref(), vel.as_ref())?;
                out[0] = ai.altitude_m();
                out[1] = ai.vz_up_m_s();
                sink(k, out.get(..n_out).unwrap_or(&[]));
                steps = k + 1;
            }
        }
        Case::SeekerIns => {
            let mut f = SeekerIns::<f32>::new(&seeker_config()?, &seeker_start_state())?;
            let start = seeker_start();
            for (k, bytes) in records.enumerate() {
                for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
                    *d = v;
                }
                let inc = ImuIncrement {
                    // Record k covers the interval ending at (k + 1) × INS_DT_S.
                    time: Timestamp::from_micros((k as u64 + 1) * INS_DT_US),
                    delta_theta_rad: v3(&rec, 0),
                    delta_v_m_s: v3(&rec, 3),
                };
                f.propagate(&inc)?;
                if val(&rec, 6) != 0.0 {
                    f.predict_covariance()?;
                    let g = LosSample {
                        time: inc.time,
                        gimbal: GimbalAngles {
                            pitch_rad: val(&rec, 7),
                            yaw_rad: val(&rec, 8),
                        },
                    };
                    f.update_los(&g)?;
                }
                let st = f.state();
                let r = 6_371_000.0;
                out[0] = ((st.position.lat_rad - start.lat_rad) * r) as f32;
                out[1] =
                    ((st.position.lon_rad - start.lon_rad) * r * libm::cos(start.lat_rad)) as f32;
                out[2] = (st.position.alt_m - start.alt_m) as f32;
                for (o, v) in out.iter_mut().skip(3).zip(st.vel_ned_m_s.iter()) {
                    *o = *v;
                }
                for (o, v) in out.iter_mut().skip(6).zip(st.q_b_n.coords.iter()) {
                    *o = *v;
                }
                let p = f.covariance();
                let rf = r as f32;
                out[10] = libm::sqrtf(p[(0, 0)]) * rf;
                out[11] = libm::sqrtf(p[(1, 1)]) * rf;
                out[12] = libm::sqrtf(p[(2, 2)]);
                sink(k, out.get(..n_out).unwrap_or(&[]));
                steps = k + 1;
            }
        }
    }
    Ok(steps)
}

/// Distance between two f32 values in units in the last place (0 when the bits are equal;
/// `u32::MAX` when exactly one is NaN).
pub fn ulps(a: f32, b: f32) -> u32 {
    if a.to_bits() == b.to_bits() {
        return 0;
    }
    if a.is_nan() || b.is_nan() {
        return u32::MAX;
    }
    let key = |x: f32| {
        let i = x.to_bits() as i32;
        if i < 0 {
            i32::MIN.wrapping_sub(i)
        } else {
            i
        }
    };
    (i64::from(key(a)) - i64::from(key(b)))
        .unsigned_abs()
        .min(u64::from(u32::MAX)) as u32
}

//! Strapdown INS replay: where the log has body-axes gyro and accelerometer samples and the
//! autopilot's attitude, nav-core's strapdown INS ([`nav_core::seeker_ins::Ins`], f32 as on
//! the target) is run from the log's own IMU time stamps and compared with the autopilot.
//!
//! Two INS runs share the samples:
//!
//! * **free**: initialised once from the autopilot's attitude (velocity and position where the
//!   log has them) and never corrected again. Its attitude difference to the autopilot grows
//!   with the gyro's bias and noise, its velocity difference with the accelerometer bias and
//!   the tilt error (`g · δθ`): the drift a GNC engineer expects, reported at fixed horizons
//!   next to the growth the stated gyro and accelerometer quality predicts.
//! * **re-levelled**: re-initialised from the autopilot's attitude and velocity every
//!   `reinit_interval_s`: the short-term agreement of the mechanization with the autopilot,
//!   i.e. that frames, units, conventions and time stamps are right (a wrong quaternion
//!   convention or a swapped axis shows within a window, drift hardly does).
//!
//! Increments are formed from the logged rates over the interval the INS actually integrates
//! (`Δθ = ω_k (t_k − t_INS)`, `Δv = f_k (t_k − t_INS)`: PX4's `sensor_combined` values are
//! averages over the interval ending at their time stamp). An interval longer than
//! `max_interval_s` is a gap the rates do not describe: that sample is refused (`Gap`) and the
//! run is re-initialised from the autopilot at its next attitude sample.
//!
//! Frames (checked with the data): body forward-right-down, navigation NED, the log's
//! quaternion body → NED, Hamilton, scalar first, the convention of nav-core's `q_b^n`. Before
//! the INS starts, the specific force rotated by the logged attitude is averaged over
//! `start_after_s`: it must point up with magnitude ≈ g (`C_b^n f_b ≈ (0, 0, −g)`); otherwise
//! the INS is reported not available with the averages, not run.
//!
//! The autopilot's own attitude resets (PX4 `quat_reset_counter`, `delta_q_reset`: a jump of
//! its estimate, not of the vehicle) are removed from the reference each run is compared with.

use crate::output::sig;
use crate::plot::{self, Figure, Panel, Series};
use anyhow::Result;
use nalgebra::{Quaternion, Vector3};
use nav_core::math::rotation::{dcm_to_euler, quat_mul, quat_to_dcm};
use nav_core::seeker_ins::{ImuIncrement, Ins, InsState, Position};
use nav_core::{NavError, Timestamp};
use serde::Deserialize;
use serde_json::{json, Value};
use std::collections::BTreeMap;
use std::path::Path;

use super::source::{AttitudeReset, BodyImu, HorizontalVelocity, LatLon, LogEvent};

/// Standard gravity for the frame check and the expected velocity drift, m/s².
const G_M_S2: f64 = 9.80665;
/// Largest accepted difference of the at-rest-averaged vertical specific force from −g in the
/// frame check, m/s² (a tenth of g: flight manoeuvres average out over a second, a flipped
/// axis or a g-unit log does not).
const FRAME_CHECK_TOLERANCE_M_S2: f64 = 0.1 * G_M_S2;
/// A reference (autopilot or GNSS velocity) older than this is not used to initialise, s.
const REFERENCE_MAX_AGE_S: f64 = 1.0;
/// Longest interval nav-core's `Ins::step` integrates, s (its `MAX_INTERVAL_S`; the path of
/// that constant differs between nav-core versions, its value does not): `max_interval_s` must
/// not exceed it, so that a longer interval is a replay `Gap`, never a refusal that would stop
/// the INS clock.
const INS_MAX_INTERVAL_S: f64 = 1.0;
/// Gaps listed in the summary (all are counted).
const MAX_GAPS_LISTED: usize = 20;
/// Interval of the plotted points, s.
const PLOT_INTERVAL_S: f64 = 0.05;

/// INS replay settings (TOML table `[ins]`; every field has a default, σ not variances).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct InsReplayConfig {
    /// The free INS starts this long after the first IMU sample that has gyro, accelerometer
    /// and an attitude; the frame check averages over this window, s.
    pub start_after_s: f64,
    /// The re-levelled INS is re-initialised from the autopilot this often, s (0: not run).
    pub reinit_interval_s: f64,
    /// An IMU interval longer than this is a gap (rates unknown across it), s.
    pub max_interval_s: f64,
    /// Times after the free INS's initialisation at which its differences are reported, s.
    pub report_after_s: Vec<f64>,
    /// Gyro white-noise density of the logged sensor, rad/s/√Hz (expected drift).
    pub gyro_noise_rad_s_rt_hz: f64,
    /// Gyro bias left after the autopilot's calibration, 1σ per axis, rad/s (expected drift;
    /// the free INS does not estimate it).
    pub gyro_bias_rad_s: f64,
    /// Accelerometer bias left after calibration, 1σ per axis, m/s² (expected drift).
    pub accel_bias_m_s2: f64,
}

impl Default for InsReplayConfig {
    /// A consumer MEMS IMU (PX4-class autopilot).
    fn default() -> Self {
        Self {
            start_after_s: 1.0,
            reinit_interval_s: 5.0,
            max_interval_s: 0.2,
            report_after_s: vec![1.0, 5.0, 10.0, 20.0, 30.0, 60.0],
            gyro_noise_rad_s_rt_hz: 5.0e-4,
            gyro_bias_rad_s: 5.0e-4,
            accel_bias_m_s2: 0.05,
        }
    }
}

impl InsReplayConfig {
    /// Checks every field against its range; the error names the field.
    pub fn validate(&self) -> Result<()> {
        let max_s = INS_MAX_INTERVAL_S;
        let checks = [
            ("start_after_s", self.start_after_s, 0.0, 3600.0),
            ("reinit_interval_s", self.reinit_interval_s, 0.0, 3600.0),
            ("max_interval_s", self.max_interval_s, 1e-4, max_s),
            (
                "gyro_noise_rad_s_rt_hz",
                self.gyro_noise_rad_s_rt_hz,
                0.0,
                1.0,
            ),
            ("gyro_bias_rad_s", self.gyro_bias_rad_s, 0.0, 1.0),
            ("accel_bias_m_s2", self.accel_bias_m_s2, 0.0, 10.0),
        ];
        for (name, v, lo, hi) in checks {
            if !(lo..=hi).contains(&v) {
                anyhow::bail!("[ins] {name} = {v} is outside [{lo}, {hi}]");
            }
        }
        if let Some(h) = self
            .report_after_s
            .iter()
            .find(|h| !h.is_finite() || **h <= 0.0)
        {
            anyhow::bail!("[ins] report_after_s: {h} is not a positive number of seconds");
        }
        if self.report_after_s.windows(2).any(|w| w[1] <= w[0]) {
            anyhow::bail!("[ins] report_after_s must increase");
        }
        Ok(())
    }

    /// Expected 1σ attitude drift per axis after `t_s` of free integration, rad: angle random
    /// walk and bias, `√(N² t + (b t)²)`.
    pub fn expected_attitude_sigma_rad(&self, t_s: f64) -> f64 {
        let n = self.gyro_noise_rad_s_rt_hz;
        let b = self.gyro_bias_rad_s;
        (n * n * t_s + (b * t_s).powi(2)).sqrt()
    }

    /// Expected 1σ horizontal velocity drift per axis after `t_s`, m/s: accelerometer bias
    /// `b_a t`, gyro bias through the tilt `g b_g t²/2`, angle random walk `g N √(t³/3)`.
    pub fn expected_velocity_sigma_m_s(&self, t_s: f64) -> f64 {
        let n = self.gyro_noise_rad_s_rt_hz;
        let bg = self.gyro_bias_rad_s;
        let ba = self.accel_bias_m_s2;
        ((ba * t_s).powi(2)
            + (G_M_S2 * bg * t_s * t_s / 2.0).powi(2)
            + G_M_S2 * G_M_S2 * n * n * t_s.powi(3) / 3.0)
            .sqrt()
    }
}

/// Why the INS part of a replay did not run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Unavailable {
    /// The IMU samples carry no body-axes accelerometer.
    NoAccelerometer,
    /// The IMU samples carry no gyro.
    NoGyro,
    /// The log has no attitude of the autopilot to initialise and compare with.
    NoAttitude,
    /// The specific force rotated by the logged attitude does not point up with magnitude g.
    FrameCheckFailed,
    /// The log ended before the INS could start.
    TooShort,
}

/// RMS and largest magnitude of a difference.
#[derive(Debug, Clone, Copy, Default)]
struct AbsStat {
    n: u64,
    sum_sq: f64,
    max_abs: f64,
}

impl AbsStat {
    fn add(&mut self, x: f64) {
        if x.is_finite() {
            self.n += 1;
            self.sum_sq += x * x;
            self.max_abs = self.max_abs.max(x.abs());
        }
    }
    fn json(&self, scale: f64, unit: &str) -> Value {
        if self.n == 0 {
            return Value::Null;
        }
        json!({
            format!("rms_{unit}"): sig((self.sum_sq / self.n as f64).sqrt() * scale, 4),
            format!("max_abs_{unit}"): sig(self.max_abs * scale, 4),
        })
    }
}

fn add3(stats: &mut [AbsStat; 3], v: &[f64; 3]) {
    for (st, x) in stats.iter_mut().zip(v) {
        st.add(*x);
    }
}

fn axes_json(s: &[AbsStat; 3], names: [&str; 3], scale: f64, unit: &str) -> Value {
    let mut m = serde_json::Map::new();
    for (st, name) in s.iter().zip(names) {
        m.insert(name.into(), st.json(scale, unit));
    }
    m.insert("samples".into(), json!(s.iter().map(|x| x.n).max()));
    Value::Object(m)
}

const RPY: [&str; 3] = ["roll", "pitch", "yaw"];
const NED: [&str; 3] = ["north", "east", "down"];

/// Hamilton product of (w, x, y, z) arrays.
fn qmul(a: &[f64; 4], b: &[f64; 4]) -> [f64; 4] {
    let q = quat_mul(
        &Quaternion::new(a[0], a[1], a[2], a[3]),
        &Quaternion::new(b[0], b[1], b[2], b[3]),
    );
    [q.w, q.i, q.j, q.k]
}

fn qconj(q: &[f64; 4]) -> [f64; 4] {
    [q[0], -q[1], -q[2], -q[3]]
}

fn dcm(q: &[f64; 4]) -> nalgebra::Matrix3<f64> {
    quat_to_dcm(&Quaternion::new(q[0], q[1], q[2], q[3]))
}

/// 3-2-1 Euler angles (roll, pitch, yaw) of a quaternion, rad.
fn euler(q: &[f64; 4]) -> [f64; 3] {
    let (r, p, y) = dcm_to_euler(&dcm(q));
    [r, p, y]
}

fn wrap_pi(a: f64) -> f64 {
    let w = (a + std::f64::consts::PI).rem_euclid(2.0 * std::f64::consts::PI);
    w - std::f64::consts::PI
}

/// Euler-angle difference `a − b` per axis (yaw wrapped), rad.
fn euler_diff(a: &[f64; 4], b: &[f64; 4]) -> [f64; 3] {
    let (ea, eb) = (euler(a), euler(b));
    [ea[0] - eb[0], ea[1] - eb[1], wrap_pi(ea[2] - eb[2])]
}

// ---------------------------------------------------------------------------------------------
// nav-core INS calls (the one place that knows the mechanization's API).

/// A new f32 INS whose first step integrates `first_interval_s` (nav-core measures every later
/// interval from the time stamps; the first has no predecessor to measure it from).
fn new_ins(state: InsState<f32>, first_interval_s: f64) -> Result<Ins<f32>, NavError> {
    Ins::new(state, first_interval_s as f32)
}

/// One step to `time`: the increments are the logged rates times the interval nav-core
/// integrates (`Ins::interval_to`), so the two agree to the µs.
fn step_ins(
    ins: &mut Ins<f32>,
    time: Timestamp,
    body: &BodyImu,
    gyro: &[f64; 3],
) -> Result<(), NavError> {
    let dt_s = f64::from(ins.interval_to(time)?);
    let v = |a: &[f64; 3]| {
        Vector3::new(
            (a[0] * dt_s) as f32,
            (a[1] * dt_s) as f32,
            (a[2] * dt_s) as f32,
        )
    };
    ins.step(&ImuIncrement {
        time,
        delta_theta_rad: v(gyro),
        delta_v_m_s: v(&body.acc_b_m_s2),
    })
}

// ---------------------------------------------------------------------------------------------

/// Where an initial value came from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Source {
    Autopilot,
    Gnss,
    Baro,
    Configuration,
    /// No reference yet: zero.
    Zero,
}

/// One initialisation of a run.
#[derive(Debug, Clone, Copy)]
struct InitRecord {
    t: Timestamp,
    horizontal_velocity: Source,
    vertical_velocity: Source,
    lat_lon: Source,
    altitude: Source,
    lat_deg: f64,
    alt_m: f64,
}

/// A difference reached a reporting horizon.
#[derive(Debug, Clone, Copy)]
struct HorizonHit {
    after_s: f64,
    elapsed_s: f64,
    att_rad: [f64; 3],
    vel_vs_autopilot_m_s: Option<[f64; 3]>,
    vel_vs_gnss_m_s: Option<[f64; 3]>,
}

/// One INS run (free or re-levelled) and what it measured.
#[derive(Debug, Default)]
struct Run {
    ins: Option<Ins<f32>>,
    /// Time of the state: the last integrated IMU sample, or the IMU sample before the
    /// initialisation.
    t_ins: Option<Timestamp>,
    /// The INS was (re-)initialised and has not integrated a sample yet: it is rebuilt with
    /// the actual first interval at the next sample.
    first_pending: bool,
    init_t: Option<Timestamp>,
    inits: Vec<InitRecord>,
    /// Product of the inverse attitude resets since the initialisation (reference without
    /// the autopilot's jumps: `q_cont = reset_acc ⊗ q`).
    reset_acc: Option<[f64; 4]>,
    accepted: u64,
    refused: BTreeMap<String, u64>,
    gap_reinits: u64,
    /// The first gaps: (start, length).
    gaps: Vec<(Timestamp, f64)>,
    /// Initialisations nav-core refused (bad reference values), by reason.
    init_refused: BTreeMap<String, u64>,
    att: [AbsStat; 3],
    vel_ap: [AbsStat; 3],
    vel_gnss: [AbsStat; 3],
    last_att: Option<[f64; 3]>,
    last_vel_ap: Option<[f64; 3]>,
    last_vel_gnss: Option<[f64; 3]>,
    window_att: [AbsStat; 3],
    window_vel_ap: [AbsStat; 3],
    window_vel_gnss: [AbsStat; 3],
    windows: u64,
    horizons: Vec<HorizonHit>,
    horizon_next: usize,
}

impl Run {
    fn refuse(&mut self, why: &str) {
        *self.refused.entry(why.to_string()).or_default() += 1;
    }

    fn reference(&self, q: &[f64; 4]) -> [f64; 4] {
        match &self.reset_acc {
            Some(a) => qmul(a, q),
            None => *q,
        }
    }

    fn q_ins(&self) -> Option<[f64; 4]> {
        self.ins.as_ref().map(|ins| {
            let q = ins.state().q_b_n;
            [q.w, q.i, q.j, q.k].map(f64::from)
        })
    }

    fn vel_ins(&self) -> Option<[f64; 3]> {
        self.ins.as_ref().map(|ins| {
            let v = ins.state().vel_ned_m_s;
            [v.x, v.y, v.z].map(f64::from)
        })
    }

    fn close_window(&mut self) {
        if let Some(a) = self.last_att {
            self.windows += 1;
            add3(&mut self.window_att, &a);
        }
        if let Some(v) = self.last_vel_ap {
            add3(&mut self.window_vel_ap, &v);
        }
        if let Some(v) = self.last_vel_gnss {
            add3(&mut self.window_vel_gnss, &v);
        }
    }
}

/// The latest value of a reference and its time.
#[derive(Debug, Clone, Copy)]
struct Latest<T> {
    t: Timestamp,
    v: T,
}

#[derive(Debug, Clone, Copy)]
struct VelocityRef {
    vd_m_s: f64,
    v_ne: Option<HorizontalVelocity>,
}

/// Averages of the frame check: the specific force in NED with the logged quaternion as it is
/// and as its conjugate (the other convention), m/s².
#[derive(Debug, Clone, Copy, Default)]
struct FrameCheck {
    n: u64,
    f_ned: [f64; 3],
    f_ned_conjugate: [f64; 3],
    f_body: [f64; 3],
}

impl FrameCheck {
    fn add(&mut self, q: &[f64; 4], f_b: &[f64; 3]) {
        let fb = Vector3::new(f_b[0], f_b[1], f_b[2]);
        let a = dcm(q) * fb;
        let b = dcm(&qconj(q)) * fb;
        self.n += 1;
        let w = 1.0 / self.n as f64;
        for k in 0..3 {
            self.f_ned[k] += (a[k] - self.f_ned[k]) * w;
            self.f_ned_conjugate[k] += (b[k] - self.f_ned_conjugate[k]) * w;
            self.f_body[k] += (f_b[k] - self.f_body[k]) * w;
        }
    }
    /// Down within tolerance of −g, and the conjugate quaternion (the other convention) not a
    /// clearly better fit: where the vehicle is tilted, the wrong convention tilts gravity by
    /// twice the attitude.
    fn passes(&self) -> bool {
        let h = |f: &[f64; 3]| f[0].hypot(f[1]);
        let conjugate_better = h(&self.f_ned) > FRAME_CHECK_TOLERANCE_M_S2
            && h(&self.f_ned_conjugate) < 0.5 * h(&self.f_ned);
        self.n > 0
            && (self.f_ned[2] + G_M_S2).abs() <= FRAME_CHECK_TOLERANCE_M_S2
            && !conjugate_better
    }
    fn json(&self) -> Value {
        let r = |v: &[f64; 3]| v.map(|x| sig(x, 4));
        let result = match (self.n, self.passes()) {
            (0, _) => "NotRun",
            (_, true) => "GravityUp",
            (_, false) => "Inconsistent",
        };
        json!({
            "result": result,
            "samples": self.n,
            "f_body_mean_m_s2": r(&self.f_body),
            "f_ned_mean_m_s2": r(&self.f_ned),
            "f_ned_mean_with_conjugate_q_m_s2": r(&self.f_ned_conjugate),
            "tolerance_on_down_m_s2": sig(FRAME_CHECK_TOLERANCE_M_S2, 3),
        })
    }
}

/// A point of the INS plot.
#[derive(Debug, Clone, Copy)]
struct PlotRow {
    t_s: f64,
    free_att_deg: [f64; 3],
    relev_att_deg: [f64; 3],
    free_v: [f64; 3],
    relev_v: [f64; 3],
    ap_v: [f64; 3],
    gnss_v: [f64; 3],
}

/// The INS part of a replay, fed every log event in time order.
#[derive(Debug)]
pub struct InsReplay {
    cfg: InsReplayConfig,
    nominal_dt_s: f64,
    first_imu: Timestamp,
    default_lat_deg: f64,
    imu_samples: u64,
    body_samples: u64,
    gyro_samples: u64,
    attitude_samples: u64,
    latest_att: Option<Latest<[f64; 4]>>,
    last_reset_counter: Option<u32>,
    resets: Vec<(Timestamp, AttitudeReset)>,
    reset_counter_skips: u64,
    latest_est: Option<Latest<VelocityRef>>,
    latest_gnss: Option<Latest<VelocityRef>>,
    latest_gnss_pos: Option<Latest<(LatLon, f64)>>,
    latest_baro_m: Option<f64>,
    last_imu_t: Option<Timestamp>,
    /// First IMU sample with gyro, accelerometer and an attitude (frame-check window start).
    ready_from: Option<Timestamp>,
    frame: FrameCheck,
    frame_failed: bool,
    free: Run,
    relev: Run,
    plot: super::Decimated<PlotRow>,
}

impl InsReplay {
    /// An INS replay for a log whose first IMU sample is `first_imu` with median interval
    /// `nominal_dt_s`; `default_lat_deg` is used until (unless) the log has a GNSS position.
    pub fn new(
        cfg: &InsReplayConfig,
        first_imu: Timestamp,
        nominal_dt_s: f64,
        default_lat_deg: f64,
    ) -> Self {
        Self {
            cfg: cfg.clone(),
            nominal_dt_s,
            first_imu,
            default_lat_deg,
            imu_samples: 0,
            body_samples: 0,
            gyro_samples: 0,
            attitude_samples: 0,
            latest_att: None,
            last_reset_counter: None,
            resets: Vec::new(),
            reset_counter_skips: 0,
            latest_est: None,
            latest_gnss: None,
            latest_gnss_pos: None,
            latest_baro_m: None,
            last_imu_t: None,
            ready_from: None,
            frame: FrameCheck::default(),
            frame_failed: false,
            free: Run::default(),
            relev: Run::default(),
            plot: super::Decimated::new(PLOT_INTERVAL_S),
        }
    }

    /// Feeds one event of the log.
    pub fn on_event(&mut self, ev: &LogEvent) {
        match *ev {
            LogEvent::Imu { t, body, .. } => self.on_imu(t, body.as_ref()),
            LogEvent::Attitude { t, q_b_n, reset } => self.on_attitude(t, &q_b_n, reset.as_ref()),
            LogEvent::Baro { alt_m, .. } => self.latest_baro_m = Some(alt_m),
            LogEvent::Gnss {
                t,
                alt_m,
                vd_m_s,
                lat_lon,
                v_ne,
            } => {
                let v = VelocityRef { vd_m_s, v_ne };
                self.latest_gnss = Some(Latest { t, v });
                if let Some(p) = lat_lon {
                    self.latest_gnss_pos = Some(Latest { t, v: (p, alt_m) });
                }
                self.compare_velocity(t, &v, false);
            }
            LogEvent::Estimate {
                t, vd_m_s, v_ne, ..
            } => {
                let v = VelocityRef { vd_m_s, v_ne };
                self.latest_est = Some(Latest { t, v });
                self.compare_velocity(t, &v, true);
            }
        }
    }

    fn on_imu(&mut self, t: Timestamp, body: Option<&BodyImu>) {
        self.imu_samples += 1;
        self.last_imu_t = Some(t);
        let Some(body) = body else {
            self.free.refuse("NoAccelerometer");
            self.relev.refuse("NoAccelerometer");
            return;
        };
        self.body_samples += 1;
        // The frame check runs wherever there are an accelerometer and an attitude (it checks
        // the log's conventions even where the INS cannot run).
        if let Some(att) = self.latest_att {
            let from = *self.ready_from.get_or_insert(t);
            if self.free.init_t.is_none()
                && t.signed_seconds_since::<f64>(from) < self.cfg.start_after_s
            {
                self.frame.add(&att.v, &body.acc_b_m_s2);
            }
        }
        let Some(gyro) = body.gyro_b_rad_s else {
            self.free.refuse("NoGyro");
            self.relev.refuse("NoGyro");
            return;
        };
        self.gyro_samples += 1;
        let max_dt = self.cfg.max_interval_s;
        for run in [&mut self.free, &mut self.relev] {
            let (Some(ins), Some(t_ins)) = (run.ins.as_mut(), run.t_ins) else {
                run.refuse("NotInitialised");
                continue;
            };
            let dt_s = t.signed_seconds_since::<f64>(t_ins);
            if dt_s > max_dt {
                // Rates across the gap unknown: re-initialised at the next attitude sample.
                run.refuse("Gap");
                run.ins = None;
                run.gap_reinits += 1;
                if run.gaps.len() < MAX_GAPS_LISTED {
                    run.gaps.push((t_ins, dt_s));
                }
                continue;
            }
            if run.first_pending {
                if dt_s <= 0.0 {
                    run.refuse(&format!("{:?}", NavError::TimeNotIncreasing));
                    continue;
                }
                match new_ins(*ins.state(), dt_s) {
                    Ok(fresh) => *ins = fresh,
                    Err(e) => {
                        run.refuse(&format!("{e:?}"));
                        continue;
                    }
                }
            }
            match step_ins(ins, t, body, &gyro) {
                Ok(()) => {
                    run.accepted += 1;
                    run.t_ins = Some(t);
                    run.first_pending = false;
                }
                Err(e) => run.refuse(&format!("{e:?}")),
            }
        }
    }

    fn on_attitude(&mut self, t: Timestamp, q: &[f64; 4], reset: Option<&AttitudeReset>) {
        self.attitude_samples += 1;
        self.latest_att = Some(Latest { t, v: *q });
        if let Some(r) = reset {
            match self.last_reset_counter {
                Some(c) if c != r.counter => {
                    if r.counter.wrapping_sub(c) & 0xff != 1 {
                        // Resets missed between two logged samples: their sum is unknown.
                        self.reset_counter_skips += 1;
                    }
                    self.resets.push((t, *r));
                    let inv = qconj(&r.delta_q);
                    for run in [&mut self.free, &mut self.relev] {
                        if let Some(a) = run.reset_acc {
                            run.reset_acc = Some(qmul(&a, &inv));
                        }
                    }
                }
                _ => {}
            }
            self.last_reset_counter = Some(r.counter);
        }
        self.compare_attitude(t, q);
        self.maybe_initialise(t, q);
        self.record_plot(t, q);
    }

    fn compare_attitude(&mut self, t: Timestamp, q: &[f64; 4]) {
        let horizons = self.cfg.report_after_s.clone();
        for (k, run) in [&mut self.free, &mut self.relev].into_iter().enumerate() {
            let Some(qi) = run.q_ins() else { continue };
            let d = euler_diff(&qi, &run.reference(q));
            add3(&mut run.att, &d);
            run.last_att = Some(d);
            // Horizons of the first, uninterrupted free run only.
            if k == 0 && run.inits.len() == 1 {
                let elapsed = run.init_t.map_or(0.0, |i| t.signed_seconds_since::<f64>(i));
                while let Some(&h) = horizons.get(run.horizon_next) {
                    if elapsed < h {
                        break;
                    }
                    run.horizon_next += 1;
                    run.horizons.push(HorizonHit {
                        after_s: h,
                        elapsed_s: elapsed,
                        att_rad: d,
                        vel_vs_autopilot_m_s: run.last_vel_ap,
                        vel_vs_gnss_m_s: run.last_vel_gnss,
                    });
                }
            }
        }
    }

    fn compare_velocity(&mut self, _t: Timestamp, r: &VelocityRef, autopilot: bool) {
        for run in [&mut self.free, &mut self.relev] {
            let Some(v) = run.vel_ins() else { continue };
            let (n, e) = match r.v_ne {
                Some(h) => (v[0] - h.vn_m_s, v[1] - h.ve_m_s),
                None => (f64::NAN, f64::NAN),
            };
            let d = [n, e, v[2] - r.vd_m_s];
            let (stat, last) = if autopilot {
                (&mut run.vel_ap, &mut run.last_vel_ap)
            } else {
                (&mut run.vel_gnss, &mut run.last_vel_gnss)
            };
            add3(stat, &d);
            *last = Some(d);
        }
    }

    /// Initial state from the autopilot's attitude `q` and the latest references.
    fn initial_state(&self, t: Timestamp, q: &[f64; 4]) -> (InsState<f32>, InitRecord) {
        let fresh = |l: &Option<Latest<VelocityRef>>| {
            l.filter(|x| t.signed_seconds_since::<f64>(x.t).abs() <= REFERENCE_MAX_AGE_S)
        };
        let (est, gnss) = (fresh(&self.latest_est), fresh(&self.latest_gnss));
        let (vertical_velocity, vd) = match (est, gnss) {
            (Some(e), _) => (Source::Autopilot, e.v.vd_m_s),
            (None, Some(g)) => (Source::Gnss, g.v.vd_m_s),
            _ => (Source::Zero, 0.0),
        };
        let (horizontal_velocity, vn, ve) =
            match (est.and_then(|e| e.v.v_ne), gnss.and_then(|g| g.v.v_ne)) {
                (Some(h), _) => (Source::Autopilot, h.vn_m_s, h.ve_m_s),
                (None, Some(h)) => (Source::Gnss, h.vn_m_s, h.ve_m_s),
                _ => (Source::Zero, 0.0, 0.0),
            };
        let (lat_lon, lat_deg, lon_deg) = match &self.latest_gnss_pos {
            Some(p) => (Source::Gnss, p.v.0.lat_deg, p.v.0.lon_deg),
            None => (Source::Configuration, self.default_lat_deg, 0.0),
        };
        let (altitude, alt_m) = match (&self.latest_gnss_pos, self.latest_baro_m) {
            (Some(p), _) => (Source::Gnss, p.v.1),
            (None, Some(b)) => (Source::Baro, b),
            _ => (Source::Zero, 0.0),
        };
        let state = InsState {
            position: Position {
                lat_rad: lat_deg.to_radians(),
                lon_rad: lon_deg.to_radians(),
                alt_m,
            },
            vel_ned_m_s: Vector3::new(vn as f32, ve as f32, vd as f32),
            q_b_n: Quaternion::new(q[0] as f32, q[1] as f32, q[2] as f32, q[3] as f32),
        };
        let rec = InitRecord {
            t,
            horizontal_velocity,
            vertical_velocity,
            lat_lon,
            altitude,
            lat_deg,
            alt_m,
        };
        (state, rec)
    }

    fn maybe_initialise(&mut self, t: Timestamp, q: &[f64; 4]) {
        let (Some(ready), Some(t_imu)) = (self.ready_from, self.last_imu_t) else {
            return;
        };
        if self.frame_failed
            || self.gyro_samples == 0
            || t.signed_seconds_since::<f64>(ready) < self.cfg.start_after_s
        {
            return;
        }
        if self.free.init_t.is_none() && !self.frame.passes() {
            self.frame_failed = true;
            return;
        }
        let (state, rec) = self.initial_state(t, q);
        let nominal = self.nominal_dt_s;
        let interval = self.cfg.reinit_interval_s;
        let runs = [
            (&mut self.free, f64::INFINITY),
            (
                &mut self.relev,
                if interval > 0.0 { interval } else { f64::NAN },
            ),
        ];
        for (run, every) in runs {
            let due = match (run.ins.is_some(), run.init_t) {
                (false, _) => !every.is_nan(),
                (true, Some(i)) => t.signed_seconds_since::<f64>(i) >= every,
                (true, None) => false,
            };
            if !due {
                continue;
            }
            if run.ins.is_some() {
                run.close_window();
            }
            match new_ins(state, nominal) {
                Ok(ins) => {
                    run.ins = Some(ins);
                    run.t_ins = Some(t_imu);
                    run.first_pending = true;
                    run.init_t = Some(t);
                    run.inits.push(rec);
                    run.reset_acc = Some([1.0, 0.0, 0.0, 0.0]);
                    run.last_att = None;
                    run.last_vel_ap = None;
                    run.last_vel_gnss = None;
                }
                Err(e) => {
                    *run.init_refused.entry(format!("{e:?}")).or_default() += 1;
                }
            }
        }
    }

    fn record_plot(&mut self, t: Timestamp, q: &[f64; 4]) {
        if !self.plot.due(t) {
            return;
        }
        let deg = |run: &Run| match run.q_ins() {
            Some(qi) => euler_diff(&qi, &run.reference(q)).map(f64::to_degrees),
            None => [f64::NAN; 3],
        };
        let vel = |run: &Run| run.vel_ins().unwrap_or([f64::NAN; 3]);
        let refv = |l: &Option<Latest<VelocityRef>>| match l {
            Some(x) if t.signed_seconds_since::<f64>(x.t).abs() <= REFERENCE_MAX_AGE_S => {
                let (n, e) =
                    x.v.v_ne
                        .map_or((f64::NAN, f64::NAN), |h| (h.vn_m_s, h.ve_m_s));
                [n, e, x.v.vd_m_s]
            }
            _ => [f64::NAN; 3],
        };
        let row = PlotRow {
            t_s: t.signed_seconds_since::<f64>(self.first_imu),
            free_att_deg: deg(&self.free),
            relev_att_deg: deg(&self.relev),
            free_v: vel(&self.free),
            relev_v: vel(&self.relev),
            ap_v: refv(&self.latest_est),
            gnss_v: refv(&self.latest_gnss),
        };
        self.plot.push(t, || row);
    }

    /// Header of the INS columns of `timeseries.csv` (leading comma included).
    pub const CSV_HEADER: &'static str = ",ap_roll_deg,ap_pitch_deg,ap_yaw_deg,ins_roll_deg,ins_pitch_deg,ins_yaw_deg,ins_droll_deg,ins_dpitch_deg,ins_dyaw_deg,ins_vn_m_s,ins_ve_m_s,ins_vd_m_s,relevelled_droll_deg,relevelled_dpitch_deg,relevelled_dyaw_deg,relevelled_vn_m_s,relevelled_ve_m_s,relevelled_vd_m_s";

    /// The INS columns of the current `timeseries.csv` row (leading comma included): the
    /// autopilot's and the free INS's Euler angles, the latest differences (computed at the
    /// autopilot's attitude samples) and both runs' velocities.
    pub fn csv_fields(&self) -> String {
        let nan3 = [f64::NAN; 3];
        let ap = self
            .latest_att
            .map_or(nan3, |a| euler(&a.v).map(f64::to_degrees));
        let ins = self
            .free
            .q_ins()
            .map_or(nan3, |q| euler(&q).map(f64::to_degrees));
        let d = |r: &Run| r.last_att.map_or(nan3, |a| a.map(f64::to_degrees));
        let v = |r: &Run| r.vel_ins().unwrap_or(nan3);
        let all: Vec<f64> = [
            ap,
            ins,
            d(&self.free),
            v(&self.free),
            d(&self.relev),
            v(&self.relev),
        ]
        .concat();
        all.iter().map(|x| format!(",{x}")).collect()
    }

    fn unavailable(&self) -> Option<(Unavailable, String)> {
        let no_body = "the IMU samples have no body-axes accelerometer (CSV: imu.csv columns `acc_x_m_s2`, `acc_y_m_s2`, `acc_z_m_s2`; ULog: `sensor_combined.accelerometer_m_s2`)";
        let no_gyro = "the IMU samples have no gyro (CSV: imu.csv columns `gyro_x_rad_s`, `gyro_y_rad_s`, `gyro_z_rad_s`; ULog: `sensor_combined.gyro_rad`)";
        let no_att = "the log has no attitude of the autopilot (CSV: imu.csv columns `q_w`, `q_x`, `q_y`, `q_z`; ULog: `vehicle_attitude.q`)";
        if self.body_samples == 0 {
            Some((Unavailable::NoAccelerometer, no_body.into()))
        } else if self.gyro_samples == 0 {
            Some((Unavailable::NoGyro, no_gyro.into()))
        } else if self.attitude_samples == 0 {
            Some((Unavailable::NoAttitude, no_att.into()))
        } else if self.frame_failed {
            let f = self.frame.f_ned;
            Some((
                Unavailable::FrameCheckFailed,
                format!(
                    "the specific force rotated by the logged attitude averages ({:.2}, {:.2}, {:.2}) m/s² NED over the first {} s (with the conjugate quaternion: ({:.2}, {:.2}, {:.2})), expected ≈ (0, 0, −9.8): body axes not forward-right-down, accelerometer not in m/s², or the quaternion not body → NED (Hamilton, scalar first)?",
                    f[0], f[1], f[2], self.cfg.start_after_s,
                    self.frame.f_ned_conjugate[0], self.frame.f_ned_conjugate[1], self.frame.f_ned_conjugate[2]
                ),
            ))
        } else if self.free.inits.is_empty() {
            Some((
                Unavailable::TooShort,
                format!(
                    "the log ends before {} s of IMU samples with gyro, accelerometer and attitude",
                    self.cfg.start_after_s
                ),
            ))
        } else {
            None
        }
    }

    fn init_json(&self, r: &InitRecord) -> Value {
        json!({
            "at_s": sig(r.t.signed_seconds_since::<f64>(self.first_imu), 6),
            "horizontal_velocity_from": format!("{:?}", r.horizontal_velocity),
            "vertical_velocity_from": format!("{:?}", r.vertical_velocity),
            "latitude_from": format!("{:?}", r.lat_lon),
            "altitude_from": format!("{:?}", r.altitude),
            "latitude_deg": sig(r.lat_deg, 8),
            "altitude_m": sig(r.alt_m, 6),
        })
    }

    fn run_json(&self, run: &Run) -> Value {
        let deg = 180.0 / std::f64::consts::PI;
        json!({
            "imu_accepted": run.accepted,
            "imu_refused": run.refused,
            "initialisations": run.inits.len(),
            "reinitialised_after_gap": run.gap_reinits,
            "initialisations_refused": run.init_refused,
            "gaps": run.gaps.iter().map(|(t, len)| json!({
                "at_s": sig(t.signed_seconds_since::<f64>(self.first_imu), 6),
                "length_s": sig(*len, 4),
            })).collect::<Vec<_>>(),
            "first_initialisation": run.inits.first().map(|r| self.init_json(r)),
            "attitude_vs_autopilot": axes_json(&run.att, RPY, deg, "deg"),
            "velocity_vs_autopilot": axes_json(&run.vel_ap, NED, 1.0, "m_s"),
            "velocity_vs_gnss": axes_json(&run.vel_gnss, NED, 1.0, "m_s"),
        })
    }

    /// The `ins` object of `summary.json`.
    pub fn summary(&self) -> Value {
        if let Some((reason, detail)) = self.unavailable() {
            return json!({
                "status": "NotAvailable",
                "reason": format!("{reason:?}"),
                "detail": detail,
                "imu_samples": self.imu_samples,
                "imu_refused": self.free.refused,
                "imu_samples_with_gyro": self.gyro_samples,
                "attitude_samples": self.attitude_samples,
                "frame_check": self.frame.json(),
            });
        }
        let deg = 180.0 / std::f64::consts::PI;
        let cfg = &self.cfg;
        let horizons: Vec<Value> = self
            .free
            .horizons
            .iter()
            .map(|h| {
                let v = |x: Option<[f64; 3]>| x.map(|a| a.map(|y| sig(y, 3)));
                json!({
                    "after_s": h.after_s,
                    "compared_after_s": sig(h.elapsed_s, 4),
                    "attitude_difference_deg": RPY.iter().zip(h.att_rad).map(|(n, a)| (n.to_string(), json!(sig(a * deg, 3)))).collect::<serde_json::Map<_, _>>(),
                    "expected_attitude_drift_1sigma_deg": sig(cfg.expected_attitude_sigma_rad(h.elapsed_s) * deg, 3),
                    "velocity_difference_vs_autopilot_ned_m_s": v(h.vel_vs_autopilot_m_s),
                    "velocity_difference_vs_gnss_ned_m_s": v(h.vel_vs_gnss_m_s),
                    "expected_horizontal_velocity_drift_1sigma_m_s": sig(cfg.expected_velocity_sigma_m_s(h.elapsed_s), 3),
                })
            })
            .collect();
        let mut free = self.run_json(&self.free);
        free["at_horizons"] = json!(horizons);
        let mut relev = self.run_json(&self.relev);
        relev["interval_s"] = json!(cfg.reinit_interval_s);
        relev["windows"] = json!(self.relev.windows);
        relev["at_window_end"] = json!({
            "attitude_vs_autopilot": axes_json(&self.relev.window_att, RPY, deg, "deg"),
            "velocity_vs_autopilot": axes_json(&self.relev.window_vel_ap, NED, 1.0, "m_s"),
            "velocity_vs_gnss": axes_json(&self.relev.window_vel_gnss, NED, 1.0, "m_s"),
            "expected_attitude_drift_1sigma_deg": sig(cfg.expected_attitude_sigma_rad(cfg.reinit_interval_s) * deg, 3),
            "expected_horizontal_velocity_drift_1sigma_m_s": sig(cfg.expected_velocity_sigma_m_s(cfg.reinit_interval_s), 3),
        });
        json!({
            "status": "Available",
            "precision": "f32",
            "imu_samples": self.imu_samples,
            "attitude_samples": self.attitude_samples,
            "frame_check": self.frame.json(),
            "sensor_quality": {
                "gyro_noise_rad_s_rt_hz": cfg.gyro_noise_rad_s_rt_hz,
                "gyro_bias_rad_s": cfg.gyro_bias_rad_s,
                "accel_bias_m_s2": cfg.accel_bias_m_s2,
            },
            "autopilot_attitude_resets": self.resets.iter().map(|(t, r)| {
                let yaw = euler(&r.delta_q)[2] * deg;
                json!({ "at_s": sig(t.signed_seconds_since::<f64>(self.first_imu), 6), "counter": r.counter, "yaw_change_deg": sig(yaw, 3) })
            }).collect::<Vec<_>>(),
            "autopilot_reset_counter_skips": self.reset_counter_skips,
            "free": free,
            "relevelled": relev,
            "notes": "Differences are INS minus autopilot (attitude: 3-2-1 Euler angles, yaw wrapped; the autopilot's own attitude resets removed from its reference) and INS minus reference velocity (NED), compared at the reference's samples with the INS at the latest IMU sample. imu_refused: NotInitialised = before the INS started (frame-check window) or between a gap and the next attitude sample; Gap = interval longer than max_interval_s. expected_*_1sigma: the growth the stated sensor quality predicts for a free INS (gyro angle random walk and bias; accelerometer bias and g times the tilt).",
        })
    }

    /// Draws `ins.png`: attitude differences and velocities. Nothing is drawn when the INS did
    /// not run.
    pub fn plot(&self, path: &Path, title: &str) -> Result<bool> {
        if self.unavailable().is_some() {
            return Ok(false);
        }
        let rows = self.plot.rows();
        let t: Vec<f64> = rows.iter().map(|r| r.t_s).collect();
        let col = |f: &dyn Fn(&PlotRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
        let t0 = self
            .free
            .inits
            .first()
            .map_or(0.0, |r| r.t.signed_seconds_since::<f64>(self.first_imu));
        let sigma1 = |sign: f64| {
            t.iter()
                .map(|&x| {
                    if x < t0 {
                        f64::NAN
                    } else {
                        sign * self.cfg.expected_attitude_sigma_rad(x - t0).to_degrees()
                    }
                })
                .collect::<Vec<f64>>()
        };
        let (up, down) = (sigma1(1.0), sigma1(-1.0));
        let mut panels = Vec::new();
        for (k, name) in RPY.iter().enumerate() {
            panels.push(Panel {
                title: format!("{name}: INS − autopilot"),
                y_label: format!("Δ{name}, deg"),
                series: vec![
                    Series::line("free INS", &t, &col(&|r| r.free_att_deg[k]), 0),
                    Series::line(
                        format!("re-levelled every {} s", self.cfg.reinit_interval_s),
                        &t,
                        &col(&|r| r.relev_att_deg[k]),
                        1,
                    ),
                    Series::dashed("±1σ expected (free, gyro quality)", &t, &up, 7),
                    Series::dashed("", &t, &down, 7),
                ],
                y_range: None,
            });
        }
        for (k, name) in NED.iter().enumerate() {
            panels.push(Panel {
                title: format!("velocity {name}"),
                y_label: format!("V_{}, m/s", &name[..1].to_uppercase()),
                series: vec![
                    Series::line("free INS", &t, &col(&|r| r.free_v[k]), 0),
                    Series::line("re-levelled INS", &t, &col(&|r| r.relev_v[k]), 1),
                    Series::line("GNSS", &t, &col(&|r| r.gnss_v[k]), 2),
                    Series::line("autopilot", &t, &col(&|r| r.ap_v[k]), 3),
                ],
                y_range: None,
            });
        }
        // Attitude in the left column, velocity in the right.
        let order = [0, 3, 1, 4, 2, 5];
        let mut panels: Vec<Option<Panel>> = panels.into_iter().map(Some).collect();
        let panels = order.iter().filter_map(|&i| panels[i].take()).collect();
        let fig = Figure {
            title: format!("Strapdown INS replay (f32, log's own time stamps): {title}"),
            x_label: "time since the first IMU sample, s".into(),
            columns: 2,
            panels,
        };
        plot::render(&fig, path, 1600, 1400)?;
        Ok(true)
    }
}

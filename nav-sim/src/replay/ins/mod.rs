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

mod config;
mod report;
mod run;

pub use config::{InsReplayConfig, Unavailable};
use run::*;

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
}

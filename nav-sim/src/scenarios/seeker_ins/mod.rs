//! `seeker-ins`: Monte Carlo reproduction of the INS / image-sensor paper (spec
//! `seeker-aided-ins.md`, seed Figs. 3-4): the 17-state closed-loop EKF of
//! [`nav_core::seeker_ins`] aided by seeker gimbal angles to a known landmark, and the same
//! runs without aiding (free INS).
//!
//! Each run draws the Table 3 sensor errors (scale factor, misalignment, white noise, random
//! bias of the accelerometers and gyros; random-constant and white gimbal angle errors) and
//! the Table 4 initial errors, then flies the truth trajectory of [`trajectory`] twice with
//! the same random numbers: once with seeker updates (aided) and once without (free INS).

pub mod fault;
pub mod trajectory;

use crate::output::{sig, write_csv};
use crate::plot::{render, Figure, Panel, Series};
use crate::rng::{normal, SimRng};
use crate::scenario::{Context, Kind};
use crate::stats::ensemble;
use anyhow::{bail, Result};
use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};
use nav_core::earth::radii_m;
use nav_core::math::kalman::FusionOutcome;
use nav_core::math::rotation::{dcm_to_euler, dcm_to_quat, euler_to_dcm, log_so3, quat_to_dcm};
use nav_core::seeker_ins::measurement::{gimbal_angles_of, landmark_vector_ned};
use nav_core::seeker_ins::{
    GimbalAngles, ImuIncrement, InsState, Landmark, LosResidual, Position, SeekerIns,
    SeekerInsConfig, STATES,
};
use nav_core::Real;
use serde::Deserialize;
use serde_json::json;
use trajectory::{TrajectoryConfig, Truth};

/// Registry entry.
pub const KIND: Kind = Kind {
    kind: "seeker-ins",
    about: "INS aided by seeker gimbal angles to a landmark (17-state EKF) vs free INS",
    run,
};

/// Standard gravity for µg conversions, m/s².
const G0: f64 = 9.806_65;
/// Mean earth radius R_0 of Table 4, m.
const R0: f64 = nav_core::earth::MEAN_RADIUS_M;
const ARCSEC: f64 = std::f64::consts::PI / 180.0 / 3600.0;

/// The whole scenario configuration (everything but the header).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Config {
    /// Truth trajectory.
    pub trajectory: TrajectoryConfig,
    /// Landmark position relative to the start.
    pub landmark: LandmarkConfig,
    /// Sensor rates and gimbal limits.
    pub rates: RatesConfig,
    /// Sensor errors (Table 3).
    pub sensors: SensorConfig,
    /// Initial errors (Table 4).
    pub initial_error: InitialErrorConfig,
    /// Filter settings.
    pub filter: FilterConfig,
}

/// Landmark relative to the start point.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LandmarkConfig {
    /// North of the start, m.
    pub north_m: f64,
    /// East of the start, m.
    pub east_m: f64,
    /// Height above the ellipsoid, m.
    pub alt_m: f64,
}

/// Rates and field of regard.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RatesConfig {
    /// IMU rate, Hz.
    pub imu_hz: f64,
    /// Seeker rate, Hz (an integer divisor of the IMU rate).
    pub seeker_hz: f64,
    /// Filter covariance propagation rate, Hz (an integer divisor of the IMU rate).
    pub covariance_hz: f64,
    /// Gimbal limits ±, deg (pitch and yaw); outside → no measurement.
    pub gimbal_limit_deg: f64,
    /// Output (statistics) rate, Hz.
    pub output_hz: f64,
}

/// Table 3, 1σ values.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SensorConfig {
    /// Accelerometer scale factor, ppm.
    pub accel_scale_factor_ppm: f64,
    /// Accelerometer misalignment, arcsec.
    pub accel_misalignment_arcsec: f64,
    /// Accelerometer white noise density, µg/√Hz.
    pub accel_noise_ug_rt_hz: f64,
    /// Accelerometer random (constant) bias, µg.
    pub accel_bias_ug: f64,
    /// Gyro scale factor, ppm.
    pub gyro_scale_factor_ppm: f64,
    /// Gyro misalignment, arcsec.
    pub gyro_misalignment_arcsec: f64,
    /// Gyro angle random walk, deg/√h.
    pub gyro_arw_deg_rt_h: f64,
    /// Gyro random (constant) bias, deg/h.
    pub gyro_bias_deg_h: f64,
    /// Seeker random-constant angle error, deg (each gimbal angle).
    pub seeker_bias_deg: f64,
    /// Seeker white noise, deg (each gimbal angle).
    pub seeker_noise_deg: f64,
}

/// Table 4, 1σ values.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InitialErrorConfig {
    /// Latitude error, m (drawn as m / R_0 rad).
    pub lat_m: f64,
    /// Longitude error, m (drawn as m / R_0 rad, as Table 4 states).
    pub lon_m: f64,
    /// Altitude error, m.
    pub alt_m: f64,
    /// Velocity error N, E, D, m/s.
    pub vel_m_s: [f64; 3],
    /// Roll error, deg.
    pub roll_deg: f64,
    /// Pitch error, deg.
    pub pitch_deg: f64,
    /// Yaw error, deg.
    pub yaw_deg: f64,
}

/// Filter tuning (not truth).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FilterConfig {
    /// "f32" or "f64".
    pub precision: String,
    /// χ²(1) gate on each scalar LOS component.
    pub gate_nis: f64,
    /// Initial σ of the accelerometer bias states, µg.
    pub accel_bias_sigma_ug: f64,
    /// Initial σ of the gyro bias states, deg/h.
    pub gyro_bias_sigma_deg_h: f64,
    /// Initial σ of the gimbal angle error states, deg.
    pub gimbal_bias_sigma_deg: f64,
    /// Seeker white noise assumed by the filter, deg.
    pub seeker_noise_deg: f64,
    /// LOS residual form: "projected-2d" (default) or "full-rank-3d" (comparison).
    #[serde(default = "default_residual")]
    pub residual: String,
}

fn default_residual() -> String {
    "projected-2d".into()
}

/// Output of one run (sampled at the output rate).
#[derive(Debug, Clone, Default)]
pub struct RunOutput {
    /// Errors (estimate − truth): lat m, lon m, alt m, V_N, V_E, V_D m/s, roll, pitch, yaw deg.
    pub err: [Vec<f64>; 9],
    /// Filter 1σ of the same quantities.
    pub sigma: [Vec<f64>; 9],
    /// NEES of the 17 states, and of the position, velocity and attitude blocks.
    pub nees: [Vec<f64>; 4],
    /// Sum of the per-component NIS of fused and rejected components.
    pub nis_sum: f64,
    /// Scalar components fused.
    pub fused: usize,
    /// Scalar components rejected by the gate.
    pub rejected: usize,
    /// Seeker epochs with the landmark outside the gimbal limits.
    pub out_of_field: usize,
    /// Updates refused with an error.
    pub errors: usize,
    /// True gimbal angles at the seeker epochs (pitch, yaw), deg (first run only used).
    pub gimbal_deg: Vec<(f64, f64, f64)>,
    /// Filter counters at the end of the run: LOS gate re-inflations.
    pub inflations: u32,
    /// IMU fault counters at the end of the run.
    pub imu_faults: nav_core::seeker_ins::ImuFaultCounters,
    /// Seeker epochs without a measurement because of an injected fault (loss of lock, IMU gap).
    pub seeker_dropped: usize,
    /// Seeker updates during an injected false lock, components fused / rejected.
    pub false_lock_fused: usize,
    /// As `false_lock_fused`, rejected.
    pub false_lock_rejected: usize,
}

/// Loads the configuration of a shipped scenario file (`nav-sim/scenarios/<name>.toml`).
pub fn load_config(name: &str) -> Result<Config> {
    let path = crate::scenario::default_scenario_dir().join(format!("{name}.toml"));
    let mut doc: toml::Table = toml::from_str(&std::fs::read_to_string(&path)?)?;
    for k in ["kind", "description", "runs", "seed"] {
        doc.remove(k);
    }
    Ok(Config::deserialize(toml::Value::Table(doc))?)
}

/// Output sample indices (IMU epochs).
pub fn output_epochs(truth: &Truth, cfg: &Config) -> Vec<usize> {
    let every = (cfg.rates.imu_hz / cfg.rates.output_hz).round().max(1.0) as usize;
    (0..truth.t_s.len()).step_by(every).collect()
}

/// The landmark of the scenario (geodetic, from its offset to the start).
pub fn landmark_position(cfg: &Config) -> Position {
    let lat0 = cfg.trajectory.start_lat_deg.to_radians();
    let (rm, rn) = radii_m(lat0);
    Position {
        lat_rad: lat0 + cfg.landmark.north_m / (rm + cfg.landmark.alt_m),
        lon_rad: cfg.trajectory.start_lon_deg.to_radians()
            + cfg.landmark.east_m / ((rn + cfg.landmark.alt_m) * lat0.cos()),
        alt_m: cfg.landmark.alt_m,
    }
}

/// ∂φ/∂(roll, pitch, yaw) at an attitude (φ of `Ĉ = (I − [φ×]) C`), by central differences.
fn euler_to_phi_jacobian(c: &Matrix3<f64>) -> Matrix3<f64> {
    let (r, p, y) = dcm_to_euler(c);
    let h = 1e-6;
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let mut e1 = [r, p, y];
        let mut e0 = [r, p, y];
        e1[k] += h;
        e0[k] -= h;
        let c1 = euler_to_dcm(e1[0], e1[1], e1[2]);
        let c0 = euler_to_dcm(e0[0], e0[1], e0[2]);
        let phi = -log_so3(&(c1 * c0.transpose())) / (2.0 * h);
        j.set_column(k, &phi);
    }
    j
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// Draws an IMU error model: `(I + S + M)`, bias (per axis).
fn draw_imu(rng: &mut SimRng, sf: f64, mis: f64, bias: f64) -> (Matrix3<f64>, Vector3<f64>) {
    let mut m = Matrix3::identity();
    for i in 0..3 {
        for j in 0..3 {
            m[(i, j)] += if i == j {
                normal(rng, sf)
            } else {
                normal(rng, mis)
            };
        }
    }
    let b = Vector3::new(normal(rng, bias), normal(rng, bias), normal(rng, bias));
    (m, b)
}

/// Simulates one run. `aided = false` flies the same run without seeker updates (the seeker
/// random numbers are drawn anyway so the two share every other number).
pub fn simulate_run<T: Real>(
    cfg: &Config,
    truth: &Truth,
    epochs: &[usize],
    rng: &mut SimRng,
    aided: bool,
) -> Result<RunOutput> {
    simulate_run_faulted::<T>(cfg, truth, epochs, rng, aided, &fault::Faults::default())
}

/// [`simulate_run`] with injected faults ([`fault::Faults`]); with none it is the same run,
/// number for number (the fault models draw no random numbers).
pub fn simulate_run_faulted<T: Real>(
    cfg: &Config,
    truth: &Truth,
    epochs: &[usize],
    rng: &mut SimRng,
    aided: bool,
    faults: &fault::Faults,
) -> Result<RunOutput> {
    let s = &cfg.sensors;
    let dt = truth.dt_s;
    // Sensor errors (Table 3).
    let (acc_m, acc_b) = draw_imu(
        rng,
        s.accel_scale_factor_ppm * 1e-6,
        s.accel_misalignment_arcsec * ARCSEC,
        s.accel_bias_ug * 1e-6 * G0,
    );
    let (gyr_m, gyr_b) = draw_imu(
        rng,
        s.gyro_scale_factor_ppm * 1e-6,
        s.gyro_misalignment_arcsec * ARCSEC,
        s.gyro_bias_deg_h.to_radians() / 3600.0,
    );
    let seeker_bias = Vector2::new(
        normal(rng, s.seeker_bias_deg.to_radians()),
        normal(rng, s.seeker_bias_deg.to_radians()),
    );
    let vrw = s.accel_noise_ug_rt_hz * 1e-6 * G0; // m/s²/√Hz
    let arw = s.gyro_arw_deg_rt_h.to_radians() / 60.0; // rad/√s
    let sd_dv = vrw * dt.sqrt();
    let sd_dth = arw * dt.sqrt();
    let seeker_sd = s.seeker_noise_deg.to_radians();
    // Initial errors (Table 4).
    let ie = &cfg.initial_error;
    let p0 = truth.position[0];
    let c0 = truth.c_b_n[0];
    let (r0, pt0, y0) = dcm_to_euler(&c0);
    let d_euler = Vector3::new(
        normal(rng, ie.roll_deg.to_radians()),
        normal(rng, ie.pitch_deg.to_radians()),
        normal(rng, ie.yaw_deg.to_radians()),
    );
    let init = InsState::<T> {
        position: Position {
            lat_rad: p0.lat_rad + normal(rng, ie.lat_m / R0),
            lon_rad: p0.lon_rad + normal(rng, ie.lon_m / R0),
            alt_m: p0.alt_m + normal(rng, ie.alt_m),
        },
        vel_ned_m_s: (truth.vel_ned_m_s[0]
            + Vector3::new(
                normal(rng, ie.vel_m_s[0]),
                normal(rng, ie.vel_m_s[1]),
                normal(rng, ie.vel_m_s[2]),
            ))
        .cast::<T>(),
        q_b_n: dcm_to_quat(&euler_to_dcm(
            T::lit(r0 + d_euler.x),
            T::lit(pt0 + d_euler.y),
            T::lit(y0 + d_euler.z),
        )),
    };
    // P0 (filter): Table 4 and the bias σ of the filter configuration.
    let fc = &cfg.filter;
    let mut p0m = SMatrix::<f64, STATES, STATES>::zeros();
    p0m[(0, 0)] = (ie.lat_m / R0).powi(2);
    p0m[(1, 1)] = (ie.lon_m / R0).powi(2);
    p0m[(2, 2)] = ie.alt_m.powi(2);
    for i in 0..3 {
        p0m[(3 + i, 3 + i)] = ie.vel_m_s[i].powi(2);
    }
    let j = euler_to_phi_jacobian(&c0);
    let se = Matrix3::from_diagonal(&Vector3::new(
        ie.roll_deg.to_radians().powi(2),
        ie.pitch_deg.to_radians().powi(2),
        ie.yaw_deg.to_radians().powi(2),
    ));
    let patt = j * se * j.transpose();
    let patt = (patt + patt.transpose()) * 0.5;
    p0m.fixed_view_mut::<3, 3>(6, 6).copy_from(&patt);
    for i in 0..3 {
        p0m[(9 + i, 9 + i)] = (fc.accel_bias_sigma_ug * 1e-6 * G0).powi(2);
        p0m[(12 + i, 12 + i)] = (fc.gyro_bias_sigma_deg_h.to_radians() / 3600.0).powi(2);
    }
    for i in 0..2 {
        p0m[(15 + i, 15 + i)] = fc.gimbal_bias_sigma_deg.to_radians().powi(2);
    }
    let lm_pos = landmark_position(cfg);
    let imu_per_seeker = (cfg.rates.imu_hz / cfg.rates.seeker_hz).round() as usize;
    let imu_per_cov = (cfg.rates.imu_hz / cfg.rates.covariance_hz).round() as u16;
    let config = SeekerInsConfig::<T> {
        imu_dt_s: T::lit(dt),
        covariance_interval_steps: imu_per_cov,
        accel_noise_density_m_s2_rt_hz: T::lit(vrw),
        gyro_noise_density_rad_s_rt_hz: T::lit(arw),
        seeker_noise_rad: T::lit(fc.seeker_noise_deg.to_radians()),
        gate_nis: T::lit(fc.gate_nis),
        landmark: Landmark::new(lm_pos).map_err(|e| anyhow::anyhow!("landmark: {e}"))?,
        residual: match fc.residual.as_str() {
            "projected-2d" => LosResidual::Projected2d,
            "full-rank-3d" => LosResidual::FullRank3d,
            r => bail!("filter.residual `{r}`: must be \"projected-2d\" or \"full-rank-3d\""),
        },
    };
    let mut filter = SeekerIns::new(config, init, &p0m.cast::<T>())
        .map_err(|e| anyhow::anyhow!("filter init: {e}"))?;
    if let Some(pol) = &faults.policy {
        filter
            .set_imu_fault_policy(fault::policy_cast::<T>(pol))
            .map_err(|e| anyhow::anyhow!("IMU fault policy: {e}"))?;
    }
    let mut missing: u16 = 0;
    let lm64 = Landmark::<f64>::new(lm_pos).map_err(|e| anyhow::anyhow!("{e}"))?;
    let limit = cfg.rates.gimbal_limit_deg.to_radians();
    let mut out = RunOutput::default();
    let mut next_epoch = epochs.iter().peekable();
    let n = truth.t_s.len();
    for k in 0..n {
        let in_gap = k > 0 && faults.in_imu_gap(truth.t_s[k]);
        if k > 0 {
            let inc = &truth.imu[k];
            let t_k = truth.t_s[k];
            // The sensed increment of the true motion, clipped at the range in a burst.
            let (true_dv, clipped) = faults.accel_increment(t_k, dt, &inc.delta_v_m_s);
            let dv = acc_m * true_dv
                + acc_b * dt
                + Vector3::new(normal(rng, sd_dv), normal(rng, sd_dv), normal(rng, sd_dv));
            let dth = gyr_m * inc.delta_theta_rad
                + gyr_b * dt
                + Vector3::new(
                    normal(rng, sd_dth),
                    normal(rng, sd_dth),
                    normal(rng, sd_dth),
                );
            let sample = ImuIncrement {
                time: inc.time,
                delta_theta_rad: dth.cast::<T>(),
                delta_v_m_s: dv.cast::<T>(),
            };
            if in_gap {
                missing = missing.saturating_add(1);
            } else {
                if missing > 0 {
                    filter
                        .propagate_gap(missing)
                        .map_err(|e| anyhow::anyhow!("gap of {missing} at k = {k}: {e}"))?;
                    missing = 0;
                }
                if clipped && faults.flag_clipped {
                    filter.propagate_clipped(
                        &sample,
                        nav_core::seeker_ins::ClipFlags {
                            accel: true,
                            gyro: false,
                        },
                    )
                } else {
                    filter.propagate(&sample)
                }
                .map_err(|e| anyhow::anyhow!("propagate at k = {k}: {e}"))?;
            }
            if k % imu_per_seeker == 0 {
                let noise = Vector2::new(normal(rng, seeker_sd), normal(rng, seeker_sd));
                let d = landmark_vector_ned(&truth.position[k], &lm64);
                let g = gimbal_angles_of(&(truth.c_b_n[k].transpose() * d));
                out.gimbal_deg
                    .push((t_k, g.pitch_rad.to_degrees(), g.yaw_rad.to_degrees()));
                if g.pitch_rad.abs() > limit || g.yaw_rad.abs() > limit {
                    out.out_of_field += 1;
                } else if aided && (in_gap || faults.loss_of_lock(t_k)) {
                    out.seeker_dropped += 1;
                } else if aided {
                    let false_yaw = faults.false_lock_yaw_rad(t_k);
                    let meas = GimbalAngles {
                        pitch_rad: T::lit(g.pitch_rad + seeker_bias.x + noise.x),
                        yaw_rad: T::lit(
                            g.yaw_rad + seeker_bias.y + noise.y + false_yaw.unwrap_or(0.0),
                        ),
                    };
                    match filter.update_los(&meas) {
                        Ok(rep) => {
                            for c in [rep.pitch, rep.yaw] {
                                out.nis_sum += c.nis.to_f64();
                                match (c.outcome, false_yaw.is_some()) {
                                    (FusionOutcome::Fused, false) => out.fused += 1,
                                    (FusionOutcome::Rejected, false) => out.rejected += 1,
                                    (FusionOutcome::Fused, true) => out.false_lock_fused += 1,
                                    (FusionOutcome::Rejected, true) => out.false_lock_rejected += 1,
                                    (FusionOutcome::Skipped, _) => out.errors += 1,
                                }
                            }
                        }
                        Err(_) => out.errors += 1,
                    }
                }
            }
        }
        if next_epoch.peek() == Some(&&k) {
            next_epoch.next();
            filter
                .predict_covariance()
                .map_err(|e| anyhow::anyhow!("{e}"))?;
            if missing > 0 {
                // Inside an IMU gap: the output a flight computer would give, the INS bridged
                // by the hold up to this epoch (on a copy; the filter bridges at the gap end).
                let mut bridged = filter;
                bridged
                    .propagate_gap(missing)
                    .and_then(|()| bridged.predict_covariance())
                    .map_err(|e| anyhow::anyhow!("gap output at k = {k}: {e}"))?;
                record(&mut out, &bridged, truth, k, &acc_b, &gyr_b, &seeker_bias);
            } else {
                record(&mut out, &filter, truth, k, &acc_b, &gyr_b, &seeker_bias);
            }
        }
    }
    out.inflations = filter.counters().inflations;
    out.imu_faults = filter.imu_fault_counters();
    Ok(out)
}

#[allow(clippy::too_many_arguments)]
fn record<T: Real>(
    out: &mut RunOutput,
    filter: &SeekerIns<T>,
    truth: &Truth,
    k: usize,
    acc_b: &Vector3<f64>,
    gyr_b: &Vector3<f64>,
    seeker_b: &Vector2<f64>,
) {
    let st = filter.state();
    let p_true = truth.position[k];
    let (rm, rn) = radii_m(p_true.lat_rad);
    let c_hat = quat_to_dcm(&st.q_b_n).map(|v| v.to_f64());
    let c = truth.c_b_n[k];
    let d_lat = st.position.lat_rad - p_true.lat_rad;
    let d_lon = st.position.lon_rad - p_true.lon_rad;
    let d_alt = st.position.alt_m - p_true.alt_m;
    let dv = st.vel_ned_m_s.map(|v| v.to_f64()) - truth.vel_ned_m_s[k];
    let e_hat = dcm_to_euler(&c_hat);
    let e_true = dcm_to_euler(&c);
    let de = [
        wrap_pi(e_hat.0 - e_true.0),
        wrap_pi(e_hat.1 - e_true.1),
        wrap_pi(e_hat.2 - e_true.2),
    ];
    let lat_scale = rm + p_true.alt_m;
    let lon_scale = (rn + p_true.alt_m) * p_true.lat_rad.cos();
    let errs = [
        d_lat * lat_scale,
        d_lon * lon_scale,
        d_alt,
        dv.x,
        dv.y,
        dv.z,
        de[0].to_degrees(),
        de[1].to_degrees(),
        de[2].to_degrees(),
    ];
    let p = filter.covariance().map(|v| v.to_f64());
    // Euler σ from the φ covariance: δe = J⁻¹ φ.
    let j = euler_to_phi_jacobian(&c_hat);
    let jinv = j.try_inverse().unwrap_or_else(Matrix3::identity);
    let pe = jinv * p.fixed_view::<3, 3>(6, 6) * jinv.transpose();
    let sig = [
        p[(0, 0)].sqrt() * lat_scale,
        p[(1, 1)].sqrt() * lon_scale,
        p[(2, 2)].sqrt(),
        p[(3, 3)].sqrt(),
        p[(4, 4)].sqrt(),
        p[(5, 5)].sqrt(),
        pe[(0, 0)].sqrt().to_degrees(),
        pe[(1, 1)].sqrt().to_degrees(),
        pe[(2, 2)].sqrt().to_degrees(),
    ];
    for i in 0..9 {
        out.err[i].push(errs[i]);
        out.sigma[i].push(sig[i]);
    }
    // True error state and NEES.
    let phi = -log_so3(&(c_hat * c.transpose()));
    let mut e = SVector::<f64, STATES>::zeros();
    e[0] = d_lat;
    e[1] = d_lon;
    e[2] = d_alt;
    e.fixed_rows_mut::<3>(3).copy_from(&dv);
    e.fixed_rows_mut::<3>(6).copy_from(&phi);
    e.fixed_rows_mut::<3>(9)
        .copy_from(&(acc_b - filter.accel_bias_m_s2().map(|v| v.to_f64())));
    e.fixed_rows_mut::<3>(12)
        .copy_from(&(gyr_b - filter.gyro_bias_rad_s().map(|v| v.to_f64())));
    e.fixed_rows_mut::<2>(15)
        .copy_from(&(seeker_b - filter.gimbal_bias_rad().map(|v| v.to_f64())));
    out.nees[0].push(nees(&p, &e));
    for (b, start) in [(1, 0), (2, 3), (3, 6)] {
        let pb = p.fixed_view::<3, 3>(start, start).into_owned();
        let eb = e.fixed_rows::<3>(start).into_owned();
        out.nees[b].push(nees(&pb, &eb));
    }
}

fn nees<const N: usize>(p: &SMatrix<f64, N, N>, e: &SVector<f64, N>) -> f64 {
    match nalgebra::linalg::Cholesky::new(*p) {
        Some(ch) => e.dot(&ch.solve(e)),
        None => f64::NAN,
    }
}

/// χ² quantile (Wilson-Hilferty), k degrees of freedom, standard normal quantile z.
pub fn chi2_quantile(k: f64, z: f64) -> f64 {
    let a = 2.0 / (9.0 * k);
    k * (1.0 - a + z * a.sqrt()).powi(3)
}

/// Ensemble statistics of a batch of runs.
#[derive(Debug, Clone)]
pub struct Stats {
    /// Output times, s.
    pub t_s: Vec<f64>,
    /// Per channel (9): mean error over runs.
    pub mean: Vec<Vec<f64>>,
    /// Per channel: Monte Carlo σ about the mean.
    pub std: Vec<Vec<f64>>,
    /// Per channel: RMS over runs.
    pub rms: Vec<Vec<f64>>,
    /// Per channel: filter σ (RMS over runs).
    pub filter_sigma: Vec<Vec<f64>>,
    /// NEES averaged over runs (17, pos, vel, att).
    pub nees: Vec<Vec<f64>>,
    /// Totals.
    pub fused: usize,
    /// Totals.
    pub rejected: usize,
    /// Mean NIS per scalar component.
    pub nis_mean: f64,
    /// Out-of-field seeker epochs (run 0).
    pub out_of_field: usize,
    /// Refused updates (all runs).
    pub errors: usize,
    /// Runs.
    pub runs: usize,
}

/// Statistics over runs.
pub fn statistics(runs: &[RunOutput], t_s: Vec<f64>) -> Stats {
    let mut st = Stats {
        t_s,
        mean: vec![],
        std: vec![],
        rms: vec![],
        filter_sigma: vec![],
        nees: vec![],
        fused: runs.iter().map(|r| r.fused).sum(),
        rejected: runs.iter().map(|r| r.rejected).sum(),
        nis_mean: 0.0,
        out_of_field: runs.first().map_or(0, |r| r.out_of_field),
        errors: runs.iter().map(|r| r.errors).sum(),
        runs: runs.len(),
    };
    let comps = st.fused + st.rejected;
    st.nis_mean = runs.iter().map(|r| r.nis_sum).sum::<f64>() / comps.max(1) as f64;
    for i in 0..9 {
        let series: Vec<Vec<f64>> = runs.iter().map(|r| r.err[i].clone()).collect();
        let e = ensemble(&series);
        st.mean.push(e.mean);
        st.std.push(e.std);
        st.rms.push(e.rms);
        let sig: Vec<Vec<f64>> = runs.iter().map(|r| r.sigma[i].clone()).collect();
        st.filter_sigma.push(ensemble(&sig).rms);
    }
    for b in 0..4 {
        let series: Vec<Vec<f64>> = runs.iter().map(|r| r.nees[b].clone()).collect();
        st.nees.push(ensemble(&series).mean);
    }
    st
}

/// Channel names (summary keys) in the order of [`RunOutput::err`].
pub const CHANNELS: [&str; 9] = [
    "lat_m",
    "lon_m",
    "alt_m",
    "vn_mps",
    "ve_mps",
    "vd_mps",
    "roll_deg",
    "pitch_deg",
    "yaw_deg",
];

fn channel_json(values: impl Fn(usize) -> f64, n: usize) -> serde_json::Value {
    let mut m = serde_json::Map::new();
    for (i, name) in CHANNELS.iter().enumerate().take(n) {
        m.insert((*name).into(), json!(sig(values(i), 4)));
    }
    serde_json::Value::Object(m)
}

fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0, |m, x| m.max(x.abs()))
}

fn summary_block(st: &Stats) -> serde_json::Value {
    json!({
        "max_abs_mean_error": channel_json(|i| max_abs(&st.mean[i]), 3),
        "final_rms": channel_json(|i| *st.rms[i].last().unwrap_or(&f64::NAN), 9),
        "max_rms": channel_json(|i| max_abs(&st.rms[i]), 9),
        "final_mc_std": channel_json(|i| *st.std[i].last().unwrap_or(&f64::NAN), 9),
        "final_filter_sigma": channel_json(|i| *st.filter_sigma[i].last().unwrap_or(&f64::NAN), 9),
        "max_abs_mean_error_all": channel_json(|i| max_abs(&st.mean[i]), 9),
    })
}

/// NEES consistency numbers: mean over epochs after the first and the fraction of epochs whose
/// run-averaged NEES lies in the two-sided 95 % χ² bounds for the run count.
pub fn nees_summary(st: &Stats) -> serde_json::Value {
    let runs = st.runs.max(1) as f64;
    let mut m = serde_json::Map::new();
    for (b, (name, dof)) in [("", 17.0), ("_pos", 3.0), ("_vel", 3.0), ("_att", 3.0)]
        .iter()
        .enumerate()
    {
        let v = &st.nees[b];
        let body: Vec<f64> = v
            .iter()
            .skip(1)
            .copied()
            .filter(|x| x.is_finite())
            .collect();
        let mean = body.iter().sum::<f64>() / body.len().max(1) as f64;
        let lo = chi2_quantile(dof * runs, -1.959_964) / runs;
        let hi = chi2_quantile(dof * runs, 1.959_964) / runs;
        let inside = body.iter().filter(|x| **x >= lo && **x <= hi).count() as f64
            / body.len().max(1) as f64;
        m.insert(format!("nees{name}_mean"), json!(sig(mean, 4)));
        m.insert(format!("nees{name}_dof"), json!(dof));
        m.insert(
            format!("nees{name}_95_bounds"),
            json!([sig(lo, 4), sig(hi, 4)]),
        );
        m.insert(
            format!("nees{name}_in_95_bounds_frac"),
            json!(sig(inside, 3)),
        );
        m.insert(
            format!("nees{name}_final"),
            json!(sig(*v.last().unwrap_or(&f64::NAN), 4)),
        );
    }
    serde_json::Value::Object(m)
}

/// Runs the aided and free Monte Carlo batches; returns `(aided, free, first aided run)`.
pub fn monte_carlo_batches(
    cfg: &Config,
    truth: &Truth,
    runs: usize,
    seed: u64,
    progress: bool,
) -> Result<(Stats, Stats, RunOutput)> {
    let epochs = output_epochs(truth, cfg);
    let f32_mode = match cfg.filter.precision.as_str() {
        "f32" => true,
        "f64" => false,
        p => bail!("filter.precision `{p}`: must be \"f32\" or \"f64\""),
    };
    let results = crate::montecarlo::monte_carlo("seeker-ins", runs, seed, progress, |_, rng| {
        let mut rng_free = rng.clone();
        let sim = |rng: &mut SimRng, aided: bool| {
            if f32_mode {
                simulate_run::<f32>(cfg, truth, &epochs, rng, aided)
            } else {
                simulate_run::<f64>(cfg, truth, &epochs, rng, aided)
            }
        };
        let a = sim(rng, true)?;
        let f = sim(&mut rng_free, false)?;
        Ok::<_, anyhow::Error>((a, f))
    });
    let mut aided = Vec::with_capacity(runs);
    let mut free = Vec::with_capacity(runs);
    for r in results {
        let (a, f) = r?;
        aided.push(a);
        free.push(f);
    }
    let t: Vec<f64> = epochs.iter().map(|&k| truth.t_s[k]).collect();
    let first = aided.first().cloned().unwrap_or_default();
    Ok((statistics(&aided, t.clone()), statistics(&free, t), first))
}

fn run(ctx: &Context) -> Result<serde_json::Value> {
    let cfg: Config = ctx.config()?;
    if !(cfg.rates.imu_hz > 0.0 && cfg.rates.seeker_hz > 0.0 && cfg.rates.covariance_hz > 0.0) {
        bail!("rates must be positive");
    }
    let truth = trajectory::generate(&cfg.trajectory, 1.0 / cfg.rates.imu_hz);
    let (aided, free, first) = monte_carlo_batches(&cfg, &truth, ctx.runs, ctx.seed, ctx.progress)?;
    write_outputs(ctx, &cfg, &truth, &aided, &free, &first)?;
    let mut a = summary_block(&aided);
    if let (Some(obj), serde_json::Value::Object(n)) = (a.as_object_mut(), nees_summary(&aided)) {
        for (k, v) in n {
            obj.insert(k, v);
        }
        obj.insert(
            "nis_mean_per_component".into(),
            json!(sig(aided.nis_mean, 4)),
        );
        obj.insert("components_fused".into(), json!(aided.fused));
        obj.insert("components_rejected".into(), json!(aided.rejected));
        obj.insert("updates_refused".into(), json!(aided.errors));
        obj.insert(
            "seeker_epochs_out_of_field_run0".into(),
            json!(aided.out_of_field),
        );
    }
    let f = summary_block(&free);
    println!(
        "  aided final RMS  lat {:.1} m  lon {:.1} m  alt {:.1} m | free INS lat {:.0} m lon {:.0} m alt {:.0} m | NEES mean {:.2} (17 dof)",
        aided.rms[0].last().unwrap_or(&f64::NAN),
        aided.rms[1].last().unwrap_or(&f64::NAN),
        aided.rms[2].last().unwrap_or(&f64::NAN),
        free.rms[0].last().unwrap_or(&f64::NAN),
        free.rms[1].last().unwrap_or(&f64::NAN),
        free.rms[2].last().unwrap_or(&f64::NAN),
        aided.nees[0].iter().skip(1).sum::<f64>() / (aided.nees[0].len().max(2) - 1) as f64,
    );
    Ok(json!({
        "trajectory": format!("{:?}", cfg.trajectory.shape),
        "filter_precision": cfg.filter.precision,
        "los_residual": cfg.filter.residual,
        "aided": a,
        "free_ins": f,
    }))
}

fn write_outputs(
    ctx: &Context,
    cfg: &Config,
    truth: &Truth,
    aided: &Stats,
    free: &Stats,
    first: &RunOutput,
) -> Result<()> {
    // CSV: per channel mean, MC std, filter σ (aided), RMS aided and free; NEES.
    let mut headers: Vec<String> = vec!["t_s".into()];
    let mut cols: Vec<&[f64]> = vec![&aided.t_s];
    for (i, name) in CHANNELS.iter().enumerate() {
        headers.push(format!("{name}_mean"));
        cols.push(&aided.mean[i]);
        headers.push(format!("{name}_mc_std"));
        cols.push(&aided.std[i]);
        headers.push(format!("{name}_filter_sigma"));
        cols.push(&aided.filter_sigma[i]);
        headers.push(format!("{name}_rms"));
        cols.push(&aided.rms[i]);
        headers.push(format!("{name}_free_rms"));
        cols.push(&free.rms[i]);
    }
    for (b, name) in ["nees", "nees_pos", "nees_vel", "nees_att"]
        .iter()
        .enumerate()
    {
        headers.push((*name).into());
        cols.push(&aided.nees[b]);
    }
    let hdr: Vec<&str> = headers.iter().map(String::as_str).collect();
    write_csv(&ctx.out_dir.join("errors.csv"), &hdr, &cols)?;

    let titles = [
        "latitude error",
        "longitude error",
        "altitude error",
        "north velocity error",
        "east velocity error",
        "down velocity error",
        "roll error",
        "pitch error",
        "yaw error",
    ];
    let units = ["m", "m", "m", "m/s", "m/s", "m/s", "deg", "deg", "deg"];
    let t = &aided.t_s;
    let neg = |v: &[f64]| v.iter().map(|x| -x).collect::<Vec<f64>>();
    let mut panels = Vec::new();
    for i in 0..9 {
        panels.push(Panel {
            title: titles[i].into(),
            y_label: units[i].into(),
            series: vec![
                Series::line("error mean", t, &aided.mean[i], 0),
                Series::line("MC σ", t, &aided.std[i], 1),
                Series::line("", t, &neg(&aided.std[i]), 1),
                Series::dashed("filter σ", t, &aided.filter_sigma[i], 2),
                Series::dashed("", t, &neg(&aided.filter_sigma[i]), 2),
            ],
            y_range: None,
        });
    }
    let shape = format!("{:?}", cfg.trajectory.shape);
    render(
        &Figure {
            title: format!(
                "INS/seeker, {shape} trajectory: error mean, Monte Carlo σ and filter σ ({} runs)",
                aided.runs
            ),
            x_label: "time, s".into(),
            panels,
            columns: 3,
        },
        &ctx.out_dir.join("errors.png"),
        1500,
        1100,
    )?;
    // Aided vs free INS, RMS.
    let mut panels = Vec::new();
    for i in [0usize, 1, 2, 4, 7, 8] {
        panels.push(Panel {
            title: format!("{} RMS", titles[i]),
            y_label: units[i].into(),
            series: vec![
                Series::line("aided", t, &aided.rms[i], 0),
                Series::dashed("free INS", t, &free.rms[i], 1),
            ],
            y_range: None,
        });
    }
    render(
        &Figure {
            title: format!("{shape}: RMS error over runs, seeker-aided vs free INS"),
            x_label: "time, s".into(),
            panels,
            columns: 3,
        },
        &ctx.out_dir.join("aided_vs_free.png"),
        1500,
        800,
    )?;
    // NEES.
    let runs = aided.runs.max(1) as f64;
    let mut panels = Vec::new();
    for (b, (name, dof)) in [
        ("17 states", 17.0),
        ("position", 3.0),
        ("velocity", 3.0),
        ("attitude", 3.0),
    ]
    .iter()
    .enumerate()
    {
        let lo = chi2_quantile(dof * runs, -1.959_964) / runs;
        let hi = chi2_quantile(dof * runs, 1.959_964) / runs;
        panels.push(Panel {
            title: format!("NEES, {name} (averaged over runs)"),
            y_label: "NEES".into(),
            series: vec![
                Series::line("NEES", t, &aided.nees[b], 0),
                Series::dashed("95 % bounds", t, &vec![lo; t.len()], 1),
                Series::dashed("", t, &vec![hi; t.len()], 1),
            ],
            y_range: Some((
                0.0,
                (3.0 * hi).max(
                    aided.nees[b]
                        .iter()
                        .skip(1)
                        .fold(0.0, |m: f64, x| m.max(x.min(10.0 * hi))),
                ),
            )),
        });
    }
    render(
        &Figure {
            title: format!("{shape}: filter consistency (NEES)"),
            x_label: "time, s".into(),
            panels,
            columns: 2,
        },
        &ctx.out_dir.join("nees.png"),
        1300,
        900,
    )?;
    // Trajectory and gimbal angles.
    let lat0 = truth.position[0].lat_rad;
    let (rm, rn) = radii_m(lat0);
    let north: Vec<f64> = truth
        .position
        .iter()
        .map(|p| (p.lat_rad - lat0) * (rm + p.alt_m) / 1000.0)
        .collect();
    let east: Vec<f64> = truth
        .position
        .iter()
        .map(|p| (p.lon_rad - truth.position[0].lon_rad) * (rn + p.alt_m) * lat0.cos() / 1000.0)
        .collect();
    let mut lm_series = Series::line(
        "landmark",
        &[cfg.landmark.east_m / 1000.0],
        &[cfg.landmark.north_m / 1000.0],
        1,
    );
    lm_series.style = crate::plot::Style::Points;
    let tg: Vec<f64> = first.gimbal_deg.iter().map(|g| g.0).collect();
    let gp: Vec<f64> = first.gimbal_deg.iter().map(|g| g.1).collect();
    let gy: Vec<f64> = first.gimbal_deg.iter().map(|g| g.2).collect();
    let lim = cfg.rates.gimbal_limit_deg;
    render(
        &Figure {
            title: format!("{shape} trajectory (x: east, km) and true gimbal angles"),
            x_label: "east, km  |  time, s".into(),
            panels: vec![
                Panel {
                    title: "ground track".into(),
                    y_label: "north, km".into(),
                    series: vec![Series::line("truth", &east, &north, 0), lm_series],
                    y_range: Some((-10.0, 10.0)),
                },
                Panel {
                    title: "gimbal angles".into(),
                    y_label: "deg".into(),
                    series: vec![
                        Series::line("pitch θ_s", &tg, &gp, 0),
                        Series::line("yaw ψ_s", &tg, &gy, 2),
                        Series::dashed("limit", &tg, &vec![lim; tg.len()], 1),
                        Series::dashed("", &tg, &vec![-lim; tg.len()], 1),
                    ],
                    y_range: None,
                },
            ],
            columns: 1,
        },
        &ctx.out_dir.join("trajectory.png"),
        1200,
        900,
    )?;
    Ok(())
}

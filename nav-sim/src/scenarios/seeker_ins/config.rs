//! The scenario file: configuration structs, loading, the landmark and the output epochs.

use super::trajectory::{TrajectoryConfig, Truth};
use crate::truth::radii_of_curvature_m as radii_m;
use anyhow::Result;
use nav_core::seeker_ins::Position;
use serde::Deserialize;

/// Standard gravity for µg conversions, m/s².
pub(super) const G0: f64 = 9.806_65;
/// Mean earth radius R_0 of Table 4, m.
pub(super) const R0: f64 = nav_core::earth::MEAN_RADIUS_M;
/// One arcsecond, rad.
pub(super) const ARCSEC: f64 = std::f64::consts::PI / 180.0 / 3600.0;

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

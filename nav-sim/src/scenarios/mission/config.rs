//! The mission scenario file: the truth (profile, carry), the landmark and every sensor of the
//! flight computer. The sensor tables reuse the other scenarios' types: the missile IMU and the
//! seeker's gimbal-angle errors are the seeker paper's Table 3 ([`SensorConfig`]), the baro is
//! the vertical-channel scenarios' ([`BaroConfig`]), the master's instruments the transfer
//! alignment's ([`ImuConfig`]).

use super::profile::MissionProfile;
use super::truth::CarryConfig;
use crate::scenarios::seeker_ins::{InitialErrorConfig, LandmarkConfig, SensorConfig};
use crate::scenarios::transfer_alignment::config::ImuConfig;
use crate::scenarios::vertical_channel::BaroConfig;
use crate::truth::radii_of_curvature_m;
use anyhow::{bail, Result};
use nav_core::seeker_ins::Position;
use serde::Deserialize;

/// The truth and sensors of the mission (everything the flight computer's inputs need).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MissionConfig {
    /// IMU rate (missile IMU, the flight computer's tick), Hz.
    pub imu_hz: f64,
    /// The flight path.
    pub profile: MissionProfile,
    /// The missile under the wing.
    pub carry: CarryConfig,
    /// The landmark, relative to the start point.
    pub landmark: LandmarkConfig,
    /// Missile IMU and seeker gimbal-angle errors (seeker paper Table 3, 1σ).
    pub sensors: SensorConfig,
    /// The aircraft's master INS and the bus.
    pub master: MasterConfig,
    /// The barometric altimeter.
    pub baro: BaroConfig,
    /// The seeker's field of regard and lock.
    pub seeker: SeekerConfig,
    /// The separation (release) signal.
    pub separation: SeparationSignalConfig,
    /// Table 4 initial errors (seeker paper) for the variant that releases without an
    /// alignment.
    pub initial_error: InitialErrorConfig,
}

/// The aircraft's master INS as the missile sees it over the bus: its navigation solution
/// with navigation-grade correlated errors (first-order Gauss-Markov per axis, the σ it
/// reports), its rate and specific force from its own instruments, time-tagged and late.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MasterConfig {
    /// Message rate (time of validity every 1/rate), Hz.
    pub rate_hz: f64,
    /// Attitude error φ (NED, `Ĉ_m^n = exp(−[φ×]) C_m^n`) 1σ per axis, rad.
    pub attitude_sigma_rad: [f64; 3],
    /// Velocity error 1σ per NED axis, m/s.
    pub velocity_sigma_m_s: [f64; 3],
    /// Position error 1σ per NED axis, m.
    pub position_sigma_m: [f64; 3],
    /// Correlation time of the attitude, velocity and position errors, s.
    pub error_tau_s: f64,
    /// The master's gyros and accelerometers (rate and specific force it sends).
    pub imu: ImuConfig,
    /// Bus latency: each message arrives uniformly in [min, max] after its time of validity
    /// (order kept), s.
    pub latency_s: [f64; 2],
    /// Probability that a message is lost, dimensionless.
    #[serde(default)]
    pub loss_probability: f64,
    /// Windows `[start_s, duration_s]` without master data (by time of validity), s.
    #[serde(default)]
    pub dropouts_s: Vec<[f64; 2]>,
}

/// The seeker's search and lock.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SeekerConfig {
    /// Gimbal-angle sample rate while locked, Hz (an integer divisor of the IMU rate).
    pub rate_hz: f64,
    /// Field of regard: gimbal limits ± (pitch and yaw), deg.
    pub gimbal_limit_deg: f64,
    /// Largest range at which the landmark can be locked, m.
    pub lock_range_m: f64,
    /// Time the landmark must stay in range and in the field of regard before lock, s.
    pub acquire_s: f64,
    /// The seeker searches from this long after release, s.
    pub search_after_release_s: f64,
}

/// The aircraft's release signal.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SeparationSignalConfig {
    /// Delay of the signal's arrival after the release, s (it carries the release time).
    pub delay_s: f64,
}

impl MissionConfig {
    /// Checks what the types cannot express.
    pub fn check(&self) -> Result<()> {
        self.profile.validate()?;
        if !(self.imu_hz > 0.0 && (1e6 / self.imu_hz).fract() == 0.0) {
            bail!("imu_hz must give a whole number of µs");
        }
        let per = |r: f64| (self.imu_hz / r).round();
        for (name, r) in [
            ("master.rate_hz", self.master.rate_hz),
            ("baro.rate_hz", self.baro.rate_hz),
            ("seeker.rate_hz", self.seeker.rate_hz),
        ] {
            if !(r > 0.0 && r <= self.imu_hz && (per(r) * r - self.imu_hz).abs() < 1e-9) {
                bail!("{name} must divide imu_hz");
            }
        }
        let [lo, hi] = self.master.latency_s;
        if !(lo >= 0.0 && hi >= lo) {
            bail!("master.latency_s = [min, max] with 0 ≤ min ≤ max");
        }
        if !(0.0..1.0).contains(&self.master.loss_probability) {
            bail!("master.loss_probability in [0, 1)");
        }
        if !(self.master.error_tau_s > 0.0 && self.baro.markov_tau_s > 0.0) {
            bail!("correlation times must be positive");
        }
        Ok(())
    }

    /// IMU interval, µs.
    pub fn imu_dt_us(&self) -> u64 {
        (1e6 / self.imu_hz).round() as u64
    }

    /// The landmark's geodetic position (its offset from the start on the truth's ellipsoid).
    pub fn landmark_position(&self) -> Position {
        let lat0 = self.profile.start_lat_deg.to_radians();
        let (rm, rn) = radii_of_curvature_m(lat0);
        Position {
            lat_rad: lat0 + self.landmark.north_m / (rm + self.landmark.alt_m),
            lon_rad: self.profile.start_lon_deg.to_radians()
                + self.landmark.east_m / ((rn + self.landmark.alt_m) * lat0.cos()),
            alt_m: self.landmark.alt_m,
        }
    }
}

//! The simulated sensors of one run: the Table 3 IMU errors (scale factor, misalignment,
//! bias, white noise) and the seeker's gimbal-angle errors, drawn once per run, and the
//! samples they give of the truth. Shared with the mission scenario (its missile IMU and
//! seeker).

use super::config::{Config, SensorConfig, ARCSEC, G0};
use super::injection::Faults;
use super::trajectory::Truth;
use crate::rng::{normal, SimRng};
use nalgebra::{Matrix3, Vector2, Vector3};
use nav_core::seeker_ins::ImuIncrement;
use nav_core::time::Timestamp;

/// The sensor errors of one run.
pub(crate) struct Sensors {
    /// Accelerometer `(I + S + M)` and bias, m/s².
    pub(crate) acc_m: Matrix3<f64>,
    pub(crate) acc_b: Vector3<f64>,
    /// Gyro `(I + S + M)` and bias, rad/s.
    pub(crate) gyr_m: Matrix3<f64>,
    pub(crate) gyr_b: Vector3<f64>,
    /// Random-constant gimbal angle errors (pitch, yaw), rad.
    pub(crate) seeker_bias: Vector2<f64>,
    /// Velocity random walk, m/s²/√Hz, and angle random walk, rad/√s.
    pub(crate) vrw: f64,
    pub(crate) arw: f64,
    /// White gimbal angle noise, 1σ, rad.
    pub(crate) seeker_sd: f64,
    /// Nominal IMU interval, s and µs; white-noise σ per nominal increment (m/s, rad).
    dt: f64,
    dt_us: u64,
    sd_dv: f64,
    sd_dth: f64,
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

impl Sensors {
    /// Draws the errors of a run (Table 3) for an IMU at interval `dt` (s).
    pub(crate) fn draw(cfg: &Config, dt: f64, rng: &mut SimRng) -> Self {
        Self::draw_table3(&cfg.sensors, dt, rng)
    }

    /// Draws the errors of a run from the Table 3 σ of `s` for an IMU at interval `dt` (s).
    pub(crate) fn draw_table3(s: &SensorConfig, dt: f64, rng: &mut SimRng) -> Self {
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
        Self {
            acc_m,
            acc_b,
            gyr_m,
            gyr_b,
            seeker_bias,
            vrw,
            arw,
            seeker_sd: s.seeker_noise_deg.to_radians(),
            dt,
            dt_us: (dt * 1e6).round() as u64,
            sd_dv: vrw * dt.sqrt(),
            sd_dth: arw * dt.sqrt(),
        }
    }

    /// The IMU sample of truth interval `k` (≥ 1) and whether it is clipped: the increments
    /// over the actual interval of the truth's stamps (a jittered truth), the nominal one at a
    /// regular rate.
    pub(crate) fn imu(
        &self,
        truth: &Truth,
        k: usize,
        faults: &Faults,
        rng: &mut SimRng,
    ) -> (ImuIncrement<f64>, bool) {
        self.sense(
            &truth.imu[k],
            truth.imu[k - 1].time,
            truth.t_s[k],
            faults,
            rng,
        )
    }

    /// The IMU sample of the true increment `inc` over `(prev, inc.time]` ending at `t_s` (s)
    /// and whether it is clipped (by a vibration burst of `faults`).
    pub(crate) fn sense(
        &self,
        inc: &ImuIncrement<f64>,
        prev: Timestamp,
        t_s: f64,
        faults: &Faults,
        rng: &mut SimRng,
    ) -> (ImuIncrement<f64>, bool) {
        let h_us = inc.time.micros_since(prev).unwrap_or(self.dt_us);
        let (h, sd_v, sd_th) = if h_us == self.dt_us {
            (self.dt, self.sd_dv, self.sd_dth)
        } else {
            let h = h_us as f64 * 1e-6;
            (h, self.vrw * h.sqrt(), self.arw * h.sqrt())
        };
        // The sensed increment of the true motion, clipped at the range in a burst.
        let (true_dv, clipped) = faults.accel_increment(t_s, h, &inc.delta_v_m_s);
        let dv = self.acc_m * true_dv
            + self.acc_b * h
            + Vector3::new(normal(rng, sd_v), normal(rng, sd_v), normal(rng, sd_v));
        let dth = self.gyr_m * inc.delta_theta_rad
            + self.gyr_b * h
            + Vector3::new(normal(rng, sd_th), normal(rng, sd_th), normal(rng, sd_th));
        let sample = ImuIncrement {
            time: inc.time,
            delta_theta_rad: dth,
            delta_v_m_s: dv,
        };
        (sample, clipped)
    }

    /// The white gimbal-angle noise of one seeker sample (pitch, yaw), rad.
    pub(crate) fn seeker_noise(&self, rng: &mut SimRng) -> Vector2<f64> {
        Vector2::new(normal(rng, self.seeker_sd), normal(rng, self.seeker_sd))
    }
}

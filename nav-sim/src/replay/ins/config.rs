//! The INS replay's settings and why it may not run.

use super::*;

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

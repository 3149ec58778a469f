//! The simulated sensors of the vertical channel: the vertical accelerometer (random-constant
//! bias and white noise, true normal gravity with its altitude dependence, from the
//! simulator's own earth model [`crate::truth`], not nav-core's), the barometer
//! (first-order lag of the true altitude, 1st-order Gauss-Markov error, white noise) and the
//! vertical-velocity aid (white noise). With the noise off they read the truth (the baro
//! keeps its lag).

use super::{BaroConfig, Config, MG};
use crate::rng::{normal, SimRng};
use crate::truth::gravity_down_m_s2;

/// Sensor switches of a run.
#[derive(Debug, Clone, Copy)]
pub struct Noise {
    /// Sensor noise, biases and correlated errors on.
    pub on: bool,
}

/// The sensors' error states of one run.
#[derive(Debug, Clone)]
pub(crate) struct Sensors {
    noise: Noise,
    latitude_rad: f64,
    /// Accelerometer bias (random constant), m/s².
    bias_m_s2: f64,
    /// Accelerometer white noise per sample, 1σ, m/s².
    sigma_f_m_s2: f64,
    /// The barometric altimeter.
    baro: Baro,
    /// Velocity-aid white noise, 1σ, m/s.
    velocity_noise_m_s: f64,
}

impl Sensors {
    /// The sensors at the start `(altitude m, vertical velocity m/s)`; draws the accelerometer
    /// bias, then the baro's Markov state (with the noise on).
    pub(crate) fn new(
        cfg: &Config,
        noise: Noise,
        dt_s: f64,
        baro_every: usize,
        (h0, v0): (f64, f64),
        rng: &mut SimRng,
    ) -> Self {
        let bias_m_s2 = if noise.on {
            normal(rng, cfg.imu.bias_sigma_mg * MG)
        } else {
            0.0
        };
        let baro = Baro::new(
            &cfg.baro,
            noise.on,
            dt_s,
            baro_every as f64 * dt_s,
            (h0, v0),
            rng,
        );
        Self {
            noise,
            latitude_rad: cfg.latitude_deg.to_radians(),
            bias_m_s2,
            sigma_f_m_s2: cfg.imu.noise_m_s2_rt_hz / dt_s.sqrt(),
            baro,
            velocity_noise_m_s: cfg.velocity_aid.noise_m_s,
        }
    }

    /// Specific force up over an interval of mean acceleration `accel_m_s2` whose middle is at
    /// `h_mid_m`, m/s².
    pub(crate) fn specific_force(&self, accel_m_s2: f64, h_mid_m: f64, rng: &mut SimRng) -> f64 {
        let mut f = accel_m_s2 + gravity_down_m_s2(self.latitude_rad, h_mid_m);
        if self.noise.on {
            f += self.bias_m_s2 + normal(rng, self.sigma_f_m_s2);
        }
        f
    }

    /// Moves the baro's lag over one IMU interval ([`Baro::advance_lag`]).
    pub(crate) fn advance_baro_lag(&mut self, h_m: f64, h_prev_m: f64) {
        self.baro.advance_lag(h_m, h_prev_m);
    }

    /// One baro reading, m ([`Baro::sample`]).
    pub(crate) fn baro(&mut self, rng: &mut SimRng) -> f64 {
        self.baro.sample(rng)
    }

    /// One velocity-aid reading of the true vertical velocity `v_m_s`, m/s.
    pub(crate) fn velocity(&self, v_m_s: f64, rng: &mut SimRng) -> f64 {
        let white = if self.noise.on {
            normal(rng, self.velocity_noise_m_s)
        } else {
            0.0
        };
        v_m_s + white
    }
}

/// The barometric altimeter of [`BaroConfig`]: a first-order lag of the true altitude, a
/// first-order Gauss-Markov error (exactly discretised at the sample interval) and white noise.
/// With the noise off it reads the lagged truth. Shared by the vertical-channel and mission
/// scenarios.
#[derive(Debug, Clone)]
pub(crate) struct Baro {
    on: bool,
    /// IMU interval over which the lag is advanced, s.
    dt_s: f64,
    /// Gauss-Markov error: per-sample correlation, driving noise 1σ (m), state (m).
    rho: f64,
    markov_drive_m: f64,
    markov_m: f64,
    /// White noise, 1σ, m.
    noise_m: f64,
    /// First-order lag, s, and the lagged altitude, m.
    lag_s: f64,
    z_lag_m: f64,
}

impl Baro {
    /// The altimeter in steady state at `(altitude m, vertical velocity up m/s)`: its lag on the
    /// ramp, its Markov error drawn from the stationary distribution (with the noise on).
    /// `dt_s` is the IMU interval of [`Self::advance_lag`], `sample_interval_s` the interval of
    /// [`Self::sample`].
    pub(crate) fn new(
        cfg: &BaroConfig,
        on: bool,
        dt_s: f64,
        sample_interval_s: f64,
        (h0, v0): (f64, f64),
        rng: &mut SimRng,
    ) -> Self {
        let rho = (-sample_interval_s / cfg.markov_tau_s).exp();
        let markov_m = if on {
            normal(rng, cfg.markov_sigma_m)
        } else {
            0.0
        };
        Self {
            on,
            dt_s,
            rho,
            markov_drive_m: cfg.markov_sigma_m * (1.0 - rho * rho).sqrt(),
            markov_m,
            noise_m: cfg.noise_m,
            lag_s: cfg.lag_s,
            z_lag_m: h0 - cfg.lag_s * v0,
        }
    }

    /// Moves the lag over one IMU interval in which the true altitude went linearly from
    /// `h_prev_m` to `h_m` (the exact response of a first-order lag to a ramp).
    pub(crate) fn advance_lag(&mut self, h_m: f64, h_prev_m: f64) {
        if self.lag_s > 0.0 {
            let slope = (h_m - h_prev_m) / self.dt_s;
            let e = (-self.dt_s / self.lag_s).exp();
            self.z_lag_m =
                h_m - slope * self.lag_s + (self.z_lag_m - h_prev_m + slope * self.lag_s) * e;
        } else {
            self.z_lag_m = h_m;
        }
    }

    /// One reading, m (advances the Markov error, then draws the white noise).
    pub(crate) fn sample(&mut self, rng: &mut SimRng) -> f64 {
        if self.on {
            self.markov_m = self.rho * self.markov_m + normal(rng, self.markov_drive_m);
        }
        let white = if self.on {
            normal(rng, self.noise_m)
        } else {
            0.0
        };
        self.z_lag_m + self.markov_m + white
    }
}

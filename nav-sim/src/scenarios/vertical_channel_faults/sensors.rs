//! The sensors of `fault-baro`: the baro with its lag, correlated error, noise and the faults
//! of the faulty stream (the IMU's specific force is formed in `simulate` from the
//! simulator's own gravity).

use super::*;

/// The baro of a run: the lag, the correlated (first-order Gauss-Markov) error, white noise,
/// and the faults of the faulty stream.
pub(super) struct Baro {
    /// Gauss-Markov decay and drive (σ, m) over one baro interval.
    rho: f64,
    markov_drive: f64,
    /// The correlated error, m.
    markov: f64,
    /// Lag time constant, s, and the lagged altitude, m.
    lag: f64,
    z_lag: f64,
    /// The value a frozen baro repeats (NaN until the freeze), m.
    frozen_value: f64,
    /// The last reading delivered without a fault, m.
    last_good: f64,
}

impl Baro {
    /// At the start (altitude `h0` m, vertical velocity `v0` m/s), a reading every `tb` s; the
    /// correlated error drawn from its steady state (`rng`).
    pub(super) fn new(cfg: &Config, tb: f64, h0: f64, v0: f64, rng: &mut SimRng) -> Self {
        let rho = (-tb / cfg.baro.markov_tau_s).exp();
        let markov_drive = cfg.baro.markov_sigma_m * (1.0 - rho * rho).sqrt();
        let markov = normal(rng, cfg.baro.markov_sigma_m);
        let lag = cfg.baro.lag_s;
        Self {
            rho,
            markov_drive,
            markov,
            lag,
            z_lag: h0 - lag * v0,
            frozen_value: f64::NAN,
            last_good: h0,
        }
    }

    /// The lagged altitude after one IMU interval `dt` (s) from `h_prev` to `h` (m; exact for
    /// a linear change).
    pub(super) fn lag(&mut self, h: f64, h_prev: f64, dt: f64) {
        let lag = self.lag;
        if lag > 0.0 {
            let slope = (h - h_prev) / dt;
            let ex = (-dt / lag).exp();
            self.z_lag = h - slope * lag + (self.z_lag - h_prev + slope * lag) * ex;
        } else {
            self.z_lag = h;
        }
    }

    /// A reading at `t` (s): the clean one, and the faulty one (none in a dropout, the last
    /// good value while frozen, offset in a spike).
    pub(super) fn read(
        &mut self,
        cfg: &Config,
        fc: &FaultConfig,
        t: f64,
        rng: &mut SimRng,
    ) -> (Option<f64>, Option<f64>) {
        self.markov = self.rho * self.markov + normal(rng, self.markov_drive);
        let z = self.z_lag + self.markov + normal(rng, cfg.baro.noise_m);
        let faulty = if fc.dropout.has(t) {
            None
        } else if fc.frozen.has(t) {
            if self.frozen_value.is_nan() {
                self.frozen_value = self.last_good;
            }
            Some(self.frozen_value)
        } else if fc.spike.has(t) {
            Some(z + fc.spike_offset_m)
        } else {
            self.last_good = z;
            Some(z)
        };
        (Some(z), faulty)
    }
}

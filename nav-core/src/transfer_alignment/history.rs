//! The slave history: the last `H` slave samples, so that time-tagged master data arriving
//! late (data-link latency) can be matched with the slave sample of its epoch
//! ([`super::TransferAlignment::step_delayed`]).
use super::measurement::SlaveSample;
use crate::time::Timestamp;
use crate::{NavError, Real};
use heapless::Deque;

/// The last `H` slave samples (H ≥ 1, checked at compile time), oldest first: a fixed
/// [`heapless::Deque`]; pushing into a full history drops the oldest sample. Capacity H must
/// cover the master latency plus jitter in slave epochs (e.g. H = 16 covers 150 ms at
/// 100 Hz).
#[derive(Debug, Clone)]
pub struct SlaveHistory<T: Real, const H: usize> {
    samples: Deque<SlaveSample<T>, H>,
}

impl<T: Real, const H: usize> Default for SlaveHistory<T, H> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T: Real, const H: usize> PartialEq for SlaveHistory<T, H> {
    fn eq(&self, other: &Self) -> bool {
        self.samples.iter().eq(other.samples.iter())
    }
}

impl<T: Real, const H: usize> SlaveHistory<T, H> {
    /// An empty history.
    pub const fn new() -> Self {
        Self {
            samples: Deque::new(),
        }
    }

    /// Number of samples held.
    pub fn len(&self) -> usize {
        self.samples.len()
    }

    /// `true` when no sample is held.
    pub fn is_empty(&self) -> bool {
        self.samples.is_empty()
    }

    /// Stores a slave sample, dropping the oldest one when the history is full. Errors
    /// (history unchanged): `NonFiniteInput` (rates, forces), `TimeNotIncreasing` (time stamp
    /// not after the newest held).
    pub fn push(&mut self, slave: &SlaveSample<T>) -> Result<(), NavError> {
        slave.validate()?;
        if self.newest().is_some_and(|last| slave.time <= last.time) {
            return Err(NavError::TimeNotIncreasing);
        }
        if self.samples.is_full() {
            let _ = self.samples.pop_front();
        }
        self.samples
            .push_back(*slave)
            .map_err(|_| NavError::CapacityExceeded)
    }

    /// The newest sample held.
    pub fn newest(&self) -> Option<&SlaveSample<T>> {
        self.samples.back()
    }

    /// The oldest sample held.
    pub fn oldest(&self) -> Option<&SlaveSample<T>> {
        self.samples.front()
    }

    /// The held slave sample whose time stamp is within `tolerance_us` µs of `time` (the
    /// newest such sample). Errors: `MeasurementTimeOutOfWindow` when `time` is older than the
    /// oldest sample held (master data too late for the history), newer than the newest, or
    /// falls between two samples, or the history is empty.
    pub fn find(&self, time: Timestamp, tolerance_us: u64) -> Result<SlaveSample<T>, NavError> {
        self.samples
            .iter()
            .rev()
            .find(|s| {
                let d = s
                    .time
                    .micros_since(time)
                    .or_else(|| time.micros_since(s.time));
                d.is_some_and(|d| d <= tolerance_us)
            })
            .copied()
            .ok_or(NavError::MeasurementTimeOutOfWindow)
    }

    /// The slave's rate and specific force at `time` when the held samples are interval means
    /// (`Δθ/Δt`, `Δv/Δt` stamped at the END of their IMU interval, as the navigator forms them):
    /// an interval mean is the value at the interval's mid-point to first order, so each sample
    /// is placed at the mid-point of its interval (the previous sample's stamp to its own) and
    /// the two mid-points around `time` are interpolated linearly. Pairing the end-stamped mean
    /// with an instantaneous master sample instead mismatches by `ẋ Δt/2` (in a 1.5 g roll-in at
    /// 100 Hz: `ω̇ Δt/2` ≈ 10⁻³ rad/s and `(d f/dt) Δt/2` ≈ 10⁻² m/s², many times the transfer
    /// alignment's noise floor). Interpolated, the residual is second order, `ẍ Δt²/8`.
    ///
    /// `time` after the newest mid-point (the next interval not yet held) is extrapolated from
    /// the newest two, by at most half an interval. The result is stamped `time`. Errors
    /// (`MeasurementTimeOutOfWindow`): fewer than two samples, `time` before the second-oldest
    /// sample's mid-point or after the newest sample's stamp.
    pub fn at_time(&self, time: Timestamp) -> Result<SlaveSample<T>, NavError> {
        let out = NavError::MeasurementTimeOutOfWindow;
        let newest = self.newest().ok_or(out)?;
        if time > newest.time {
            return Err(out);
        }
        // Mid-points (µs, doubled to stay integer) of consecutive samples, each with the later
        // sample of its pair, newest first (the master is late by a few samples: the search
        // starts where the match is; strictly increasing stamps, so the mid-points too).
        let t2 = time.as_micros().saturating_mul(2);
        let mut mids = self
            .samples
            .iter()
            .rev()
            .zip(self.samples.iter().rev().skip(1))
            .map(|(b, a)| (a.time.as_micros() + b.time.as_micros(), b));
        let newest_mid = mids.next().ok_or(out)?;
        // (a, b): the mid-points either side of `time` (b the first at or after it), or the
        // newest two when `time` is after the newest mid-point.
        let (a, b) = if newest_mid.0 < t2 {
            (mids.next().ok_or(out)?, newest_mid)
        } else {
            let mut b = newest_mid;
            loop {
                let m = mids.next().ok_or(out)?;
                if m.0 < t2 {
                    break (m, b);
                }
                b = m;
            }
        };
        let span = b.0.saturating_sub(a.0);
        if span == 0 {
            return Err(out);
        }
        // w = (t − m_a) / (m_b − m_a), in [0, 1] or up to 1.5 when extrapolating; t > m_a, and
        // the differences are formed in integers (exact, as the f64 difference of the two
        // stamps below 2⁵³ µs was), converted from 32 bits when they fit.
        let to_f64 = |n: u64| u32::try_from(n).map_or(n as f64, f64::from);
        let w = T::lit(to_f64(t2.saturating_sub(a.0)) / to_f64(span));
        let (sa, sb) = (a.1, b.1);
        Ok(SlaveSample {
            time,
            angular_rate_rad_s: sa.angular_rate_rad_s
                + (sb.angular_rate_rad_s - sa.angular_rate_rad_s) * w,
            specific_force_m_s2: sa.specific_force_m_s2
                + (sb.specific_force_m_s2 - sa.specific_force_m_s2) * w,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn sample(us: u64) -> SlaveSample<f32> {
        SlaveSample {
            time: Timestamp::from_micros(us),
            angular_rate_rad_s: Vector3::repeat(us as f32),
            specific_force_m_s2: Vector3::zeros(),
        }
    }

    #[test]
    fn keeps_the_newest_h_and_finds_within_tolerance() {
        let mut h = SlaveHistory::<f32, 3>::new();
        assert!(h.is_empty());
        assert_eq!(
            h.find(Timestamp::ZERO, 10),
            Err(NavError::MeasurementTimeOutOfWindow)
        );
        for k in 1..=5u64 {
            h.push(&sample(k * 1000)).unwrap();
        }
        assert_eq!(h.len(), 3);
        assert_eq!(h.oldest().map(|s| s.time.as_micros()), Some(3000));
        assert_eq!(h.newest().map(|s| s.time.as_micros()), Some(5000));
        assert_eq!(
            h.find(Timestamp::from_micros(4010), 20).map(|s| s.time),
            Ok(Timestamp::from_micros(4000))
        );
        // Dropped (too old), between two samples, and in the future.
        for us in [2000, 4500, 6000] {
            assert_eq!(
                h.find(Timestamp::from_micros(us), 20),
                Err(NavError::MeasurementTimeOutOfWindow)
            );
        }
        let before = h.clone();
        assert_eq!(h.push(&sample(5000)), Err(NavError::TimeNotIncreasing));
        let mut bad = sample(6000);
        bad.specific_force_m_s2.x = f32::NAN;
        assert!(matches!(h.push(&bad), Err(NavError::NonFiniteInput { .. })));
        assert_eq!(h, before);
    }

    /// Interval means of a linear signal, stamped at the interval's end, give back the signal
    /// at any time between the mid-points (and half an interval beyond the newest) exactly.
    #[test]
    fn interpolates_interval_means_at_their_mid_points() {
        let mut h = SlaveHistory::<f64, 8>::new();
        let value = |t_s: f64| Vector3::new(1.0 + 3.0 * t_s, -2.0 * t_s, 0.5);
        let dt = 0.01;
        for k in 1..=6u64 {
            let (t0, t1) = ((k - 1) as f64 * dt, k as f64 * dt);
            let mean = (value(t0) + value(t1)) * 0.5; // the mean of a linear signal
            h.push(&SlaveSample {
                time: Timestamp::from_micros(k * 10_000),
                angular_rate_rad_s: mean,
                specific_force_m_s2: mean * 2.0,
            })
            .unwrap();
        }
        for us in [20_000u64, 25_000, 33_000, 50_000, 57_000, 60_000] {
            let s = h.at_time(Timestamp::from_micros(us)).unwrap();
            let expect = value(us as f64 * 1e-6);
            assert!((s.angular_rate_rad_s - expect).norm() < 1e-12, "{us}");
            assert!((s.specific_force_m_s2 - expect * 2.0).norm() < 1e-12);
            assert_eq!(s.time.as_micros(), us);
        }
        // The end-stamped mean itself is off by half an interval of slope.
        let end = h.find(Timestamp::from_micros(40_000), 0).unwrap();
        assert!((end.angular_rate_rad_s.x - value(0.04).x).abs() > 0.01);
        // Before the second-oldest mid-point, after the newest stamp, empty: refused.
        for us in [10_000u64, 60_001] {
            assert_eq!(
                h.at_time(Timestamp::from_micros(us)),
                Err(NavError::MeasurementTimeOutOfWindow)
            );
        }
        assert_eq!(
            SlaveHistory::<f64, 4>::new().at_time(Timestamp::ZERO),
            Err(NavError::MeasurementTimeOutOfWindow)
        );
    }

    /// The search from the newest sample gives what a scan from the oldest gives (the pair of
    /// mid-points around `time`, the newest two beyond the newest mid-point, the same refusals),
    /// bit for bit, over irregular stamps and every query time around them.
    #[test]
    fn newest_first_search_matches_an_oldest_first_scan() {
        fn reference(
            h: &SlaveHistory<f32, 6>,
            time: Timestamp,
        ) -> Result<SlaveSample<f32>, NavError> {
            let out = NavError::MeasurementTimeOutOfWindow;
            let newest = h.newest().ok_or(out)?;
            if time > newest.time {
                return Err(out);
            }
            let s: std::vec::Vec<SlaveSample<f32>> = h.samples.iter().copied().collect();
            let mids: std::vec::Vec<(u64, SlaveSample<f32>)> = s
                .windows(2)
                .map(|w| (w[0].time.as_micros() + w[1].time.as_micros(), w[1]))
                .collect();
            let t2 = time.as_micros() * 2;
            let (a, b) = match mids.iter().position(|m| m.0 >= t2) {
                Some(0) => return Err(out),
                Some(i) => (mids[i - 1], mids[i]),
                None if mids.len() >= 2 => (mids[mids.len() - 2], mids[mids.len() - 1]),
                None => return Err(out),
            };
            let w = ((t2 as f64 - a.0 as f64) / (b.0 - a.0) as f64) as f32;
            Ok(SlaveSample {
                time,
                angular_rate_rad_s: a.1.angular_rate_rad_s
                    + (b.1.angular_rate_rad_s - a.1.angular_rate_rad_s) * w,
                specific_force_m_s2: a.1.specific_force_m_s2
                    + (b.1.specific_force_m_s2 - a.1.specific_force_m_s2) * w,
            })
        }
        let mut h = SlaveHistory::<f32, 6>::new();
        let mut seed = 0x2545_f491_u64;
        let mut next = |m: u64| {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            (seed >> 33) % m
        };
        let mut t = 1_000_000u64;
        let mut checked = 0;
        for _ in 0..40 {
            // Even steps: every mid-point a whole µs.
            t += 2 * (3_500 + next(3_000));
            let v = |k: u64| (k as f32) * 0.37 - 1.1;
            h.push(&SlaveSample {
                time: Timestamp::from_micros(t),
                angular_rate_rad_s: Vector3::new(v(next(50)), v(next(50)), v(next(50))),
                specific_force_m_s2: Vector3::new(v(next(90)), v(next(90)), v(next(90))),
            })
            .unwrap();
            let oldest = h.oldest().map_or(t, |s| s.time.as_micros());
            // Every stamp, every mid-point (even sums: the stamps are whole µs) and times
            // between them.
            let stamps: std::vec::Vec<u64> = h.samples.iter().map(|s| s.time.as_micros()).collect();
            let mut queries: std::vec::Vec<u64> = stamps.clone();
            queries.extend(stamps.windows(2).map(|w| (w[0] + w[1]) / 2));
            let mut q = oldest.saturating_sub(3_000);
            while q <= t + 2_000 {
                queries.push(q);
                q += 250 + next(500);
            }
            for q in queries {
                let time = Timestamp::from_micros(q);
                assert_eq!(h.at_time(time), reference(&h, time), "at {q} µs");
                checked += 1;
            }
        }
        assert!(checked > 1_000);
    }
}

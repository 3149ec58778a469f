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
}

//! Carry-phase evidence the navigator keeps beside the alignment: the IMU's own free-fall
//! evidence for a release nobody signalled.
//!
//! Without a release signal the navigator may only conclude that the missile has left the
//! wing from what its own IMU measures: a missile hanging on the pylon feels the aircraft's
//! specific force (≈ 1 g in level flight, up to the load factor in a turn), a missile that has
//! left it falls, its accelerometers read ≈ 0 g until the aerodynamic forces build. The
//! comparison with the last master's specific force (what confirms a *signalled* release) is
//! not usable then: when the master is lost its last sample is stale, and the aircraft may
//! have manoeuvred since (a 2 s dropout in level carry is enough for that comparison to
//! exceed its threshold in a quarter of the runs with the missile still on the wing).
use crate::time::Timestamp;
use crate::Real;
use nalgebra::Vector3;

/// Free fall seen by the slave IMU alone: `|f_s| < threshold` on every tick since `since`.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub(crate) struct FreeFall {
    since: Option<Timestamp>,
}

impl FreeFall {
    /// Records one tick's specific force `f_s` (m/s², slave axes) at `time`; `threshold_m_s2`
    /// (m/s², the separation check's jump) is the largest specific force counted as falling.
    /// Returns how long (s) the IMU has been falling without interruption (0 when not).
    pub(crate) fn update<T: Real>(
        &mut self,
        time: Timestamp,
        f_s_m_s2: &Vector3<T>,
        threshold_m_s2: T,
    ) -> T {
        if f_s_m_s2.norm() < threshold_m_s2 {
            let since = *self.since.get_or_insert(time);
            time.micros_since(since)
                .map_or(T::zero(), |us| T::lit(us as f64 * 1e-6))
        } else {
            self.since = None;
            T::zero()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_fall_is_held_only_while_the_imu_reads_near_zero_g() {
        let mut ff = FreeFall::default();
        let t = |ms: u64| Timestamp::from_micros(ms * 1000);
        let one_g = Vector3::new(0.0_f64, 0.0, -9.8);
        let falling = Vector3::new(0.3_f64, 0.0, -0.5);
        assert_eq!(ff.update(t(0), &one_g, 3.0), 0.0);
        assert_eq!(ff.update(t(10), &falling, 3.0), 0.0);
        assert!((ff.update(t(110), &falling, 3.0) - 0.1).abs() < 1e-12);
        // One tick on the wing again restarts the evidence.
        assert_eq!(ff.update(t(120), &(one_g * 1.5), 3.0), 0.0);
        assert_eq!(ff.update(t(130), &falling, 3.0), 0.0);
        assert!((ff.update(t(630), &falling, 3.0) - 0.5).abs() < 1e-12);
    }
}

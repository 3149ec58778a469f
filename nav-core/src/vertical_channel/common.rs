//! What the classical and the aided loop share above their [`super::core::LoopCore`]: the
//! run-time setters, counters and estimate accessors, written once. Both loops hold a field
//! `core: LoopCore<T>`; the macros expand inside their `impl` blocks.

/// The `Estimator` items both loops implement the same way (inside `impl Estimator for …`).
macro_rules! loop_estimator_items {
    () => {
        /// Restarts the state and clock from `initial` (e.g. when the health is
        /// `NeedsReinitialisation` and an external altitude is known), keeping the design, the
        /// gate and the counters; held aid samples are dropped and the health is
        /// `Initialising` until the next step. On error nothing changes.
        fn reinitialise(&mut self, initial: &InitialState<T>) -> Result<(), NavError> {
            self.core.reinitialise(initial)
        }

        /// Health after the last step and the counters (see the module documentation).
        fn health(&self) -> Health {
            self.core.health
        }

        /// Time of the estimate: of the last accepted IMU sample, or of the initial state.
        fn time(&self) -> Option<Timestamp> {
            Some(self.core.time)
        }
    };
}

/// The inherent methods both loops share (inside `impl<T: Real> …Loop<T>`).
macro_rules! loop_common_methods {
    () => {
        /// Sets the χ² gate (validated as the configuration's `gate`; refused: nothing
        /// changes).
        pub fn set_gate(&mut self, gate: Gate<T>) -> Result<(), NavError> {
            self.core.set_gate(gate)
        }
        /// Sets the starvation recovery (validated as the configuration's `recovery`).
        pub fn set_recovery(&mut self, recovery: RecoveryPolicy<T>) -> Result<(), NavError> {
            self.core.set_recovery(recovery)
        }
        /// Sets the aid model (validated as the configuration's `aid_model`).
        pub fn set_aid_model(&mut self, aid_model: AidModel<T>) -> Result<(), NavError> {
            self.core.set_aid_model(aid_model)
        }
        /// Counters of one aid (the classical loop's velocity-aid counters stay zero: it has
        /// no velocity aid).
        pub fn aid_counters(&self, aid: Aid) -> AidCounters {
            self.core.aid_counters(aid)
        }
        /// Re-acquisition counters of one aid.
        pub fn reacquisition_counters(&self, aid: Aid) -> ReacquisitionCounters {
            self.core.reacquisition_counters(aid)
        }
        /// Altitude estimate, m (up).
        pub fn altitude_m(&self) -> T {
            self.core.altitude_m()
        }
        /// Vertical velocity estimate, m/s (up).
        pub fn vz_up_m_s(&self) -> T {
            self.core.x.y
        }
        /// Accelerometer bias estimate (measured − true), m/s².
        pub fn accel_bias_m_s2(&self) -> T {
            self.core.accel_bias_m_s2()
        }
        /// σ of the estimate (altitude m, vertical velocity m/s): the covariance the design
        /// implies under the configuration's [`super::ErrorModel`], from the initial σ through
        /// the transient to the steady state, grown open-loop while an aid is not in use and
        /// moved by re-anchorings (updated every covariance interval; see
        /// [`super::COVARIANCE_INTERVAL_S`]).
        pub fn sigma(&self) -> super::VerticalSigma<T> {
            self.core.sigma.sigma()
        }
        /// Covariance of (altitude m, vertical velocity m/s), m², m²/s, (m/s)² (see
        /// [`Self::sigma`]).
        pub fn covariance_h_vz(&self) -> nalgebra::Matrix2<T> {
            self.core.sigma.covariance_h_vz()
        }
        /// Replaces the covariance of (altitude m, vertical velocity m/s) — m², m²/s,
        /// (m/s)², [`Self::covariance_h_vz`]'s layout — with what is known of the state's
        /// error, e.g. at the start from the filter the initial state comes from (the error
        /// model's initial σ is the design's assumption). The bias and baro-error parts keep
        /// their covariance, their cross terms with altitude and velocity become zero; σ then
        /// propagates from there. Refused (nothing changes): an entry not finite
        /// (`NonFiniteInput`), not symmetric, a negative variance or a correlation beyond ±1
        /// (`InputOutOfRange`).
        pub fn set_covariance_h_vz(
            &mut self,
            covariance: &nalgebra::Matrix2<T>,
        ) -> Result<(), NavError> {
            let c = covariance;
            let input = "covariance_h_vz";
            if !crate::math::checks::all_finite(c.as_slice()) {
                return Err(NavError::NonFiniteInput { input });
            }
            let valid = c.m12 == c.m21
                && c.m11 >= T::zero()
                && c.m22 >= T::zero()
                && c.m12 * c.m12 <= c.m11 * c.m22;
            if !valid {
                return Err(NavError::InputOutOfRange { input });
            }
            self.core.sigma.set_covariance_h_vz(c);
            Ok(())
        }
        /// The steady-state σ the design implies (what [`Self::sigma`] settles to).
        pub fn steady_sigma(&self) -> super::VerticalSigma<T> {
            self.core.sigma.design.steady_sigma()
        }
    };
}

pub(super) use {loop_common_methods, loop_estimator_items};

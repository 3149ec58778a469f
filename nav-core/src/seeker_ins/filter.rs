//! The filter value, its construction through the [`Estimator`] contract, re-initialisation,
//! the run-time setters and the read-only accessors.

use super::config::{
    check_design, compute_design, validate_config, validate_gate, validate_imu_faults,
    validate_recovery, ImuFaultPolicy, SeekerInsConfig, SeekerInsDesign, AID_TIMEOUT_US,
    VARIANCE_CEILING,
};
use super::error_model::STATES;
use super::flight_noise::EquivalentBiasCharge;
use super::health::{LastUpdate, SeekerAid, SeekerCounters};
use super::mechanization::{Ins, InsState, PositionKinematics};
use crate::contract::{AidCounters, Estimator, Gate, Health, RecoveryPolicy};
use crate::time::Timestamp;
use crate::{HealthState, NavError, Real};
use nalgebra::{SMatrix, Vector2, Vector3};

/// Where the filter starts (and restarts, [`Estimator::reinitialise`]): the navigation state
/// and the initial error covariance P0 (17 × 17, units of the error state, see the module
/// [`super`] doc).
#[derive(Debug, Clone, Copy)]
pub struct SeekerInsInitial<T> {
    /// Position, velocity and attitude of the INS.
    pub state: InsState<T>,
    /// P0: symmetric PSD, variances within [`VARIANCE_CEILING`].
    pub covariance: SMatrix<T, STATES, STATES>,
}

/// The seeker-aided INS: INS + error covariance + bias and gimbal-error compensations.
///
/// Laid out as declared, P first (`repr(C)`): the hand-over (`start_in`) then clears P
/// in place in its slot instead of building the zero matrix with its neighbour's bytes on
/// the stack and copying it (2568 → 1392 B of stack at the hand-over tick).
#[derive(Debug, Clone, Copy)]
#[repr(C)]
pub struct SeekerIns<T> {
    pub(super) p: SMatrix<T, STATES, STATES>,
    pub(super) ins: Ins<T>,
    pub(super) accel_bias_m_s2: Vector3<T>,
    pub(super) gyro_bias_rad_s: Vector3<T>,
    pub(super) gimbal_bias_rad: Vector2<T>,
    /// IMU samples, their total interval (µs) and NED velocity increment since the last
    /// covariance step.
    pub(super) steps_pending: u16,
    pub(super) pending_us: u64,
    pub(super) dv_ned_pending_m_s: Vector3<T>,
    pub(super) config: SeekerInsConfig<T>,
    pub(super) design: SeekerInsDesign<T>,
    pub(super) los: AidCounters,
    pub(super) counters: SeekerCounters,
    pub(super) health: Health,
    /// Consecutive IMU samples bridged by the hold / clipped (fully correlated inflation).
    pub(super) held_run: u16,
    pub(super) clipped_run: u16,
    /// Time of the last accepted IMU sample (kept across re-initialisation).
    pub(super) clock: Option<Timestamp>,
    /// Time of the last accepted LOS sample (kept across re-initialisation).
    pub(super) last_los: Option<Timestamp>,
    /// Time since which no LOS component was fused (the last fusion, or the start).
    pub(super) fusion_ref: Option<Timestamp>,
    /// Time of the last IMU gap or clipped sample.
    pub(super) last_imu_fault: Option<Timestamp>,
    /// Start of the current run of fully rejected LOS samples (the LOS sample before it).
    pub(super) run_start: Option<Timestamp>,
    /// How the last LOS update went (for the health state).
    pub(super) last_update: LastUpdate,
    /// The equivalent-bias variance added so far (flight configuration; module
    /// `flight_noise`). Kept across re-initialisation, as the bias block is.
    pub(super) bias_charge: EquivalentBiasCharge<T>,
    /// The accelerometers' S and M as consider parameters (module `consider`).
    pub(super) consider: super::consider::ConsiderCross<T>,
    /// The radii the covariance step's F uses: those the last INS step evaluated at the
    /// start of its interval ([`Ins::step_keeping_radii`]); `None` after construction,
    /// re-initialisation or a reset (no step pending: the next step sets them before a
    /// covariance step can run; were one to run, F would evaluate them at the INS's position).
    pub(super) radii: Option<PositionKinematics<T>>,
}

impl<T: Real> PartialEq for SeekerInsInitial<T> {
    fn eq(&self, o: &Self) -> bool {
        self.state == o.state && self.covariance == o.covariance
    }
}

impl<T: Real> PartialEq for SeekerIns<T> {
    fn eq(&self, o: &Self) -> bool {
        self.ins == o.ins
            && self.p == o.p
            && self.accel_bias_m_s2 == o.accel_bias_m_s2
            && self.gyro_bias_rad_s == o.gyro_bias_rad_s
            && self.gimbal_bias_rad == o.gimbal_bias_rad
            && self.steps_pending == o.steps_pending
            && self.pending_us == o.pending_us
            && self.dv_ned_pending_m_s == o.dv_ned_pending_m_s
            && self.config == o.config
            && self.design == o.design
            && self.los == o.los
            && self.counters == o.counters
            && self.health == o.health
            && self.held_run == o.held_run
            && self.clipped_run == o.clipped_run
            && self.clock == o.clock
            && self.last_los == o.last_los
            && self.fusion_ref == o.fusion_ref
            && self.last_imu_fault == o.last_imu_fault
            && self.run_start == o.run_start
            && self.last_update == o.last_update
            && self.bias_charge == o.bias_charge
            && self.consider == o.consider
            && self.radii == o.radii
    }
}

/// P0 (or a re-initialisation covariance): finite, variances within [`VARIANCE_CEILING`],
/// symmetric PSD.
fn validate_covariance<T: Real>(p0: &SMatrix<T, STATES, STATES>) -> Result<(), NavError> {
    if !crate::math::checks::all_finite(p0.as_slice()) {
        return Err(NavError::NonFiniteInput {
            input: "initial covariance",
        });
    }
    for (i, m) in VARIANCE_CEILING.iter().enumerate() {
        if p0.get((i, i)).is_some_and(|v| *v > T::lit(*m)) {
            return Err(NavError::InputOutOfRange {
                input: "initial covariance",
            });
        }
    }
    if crate::math::kalman::asymmetry(p0) > T::zero()
        || !crate::math::kalman::is_psd(p0, T::lit(1e-6))
    {
        return Err(NavError::CovarianceNotPositiveSemiDefinite);
    }
    Ok(())
}

impl<T: Real> Estimator for SeekerIns<T> {
    type Config = SeekerInsConfig<T>;
    type Design = SeekerInsDesign<T>;
    type Initial = SeekerInsInitial<T>;

    /// The noise PSDs of the covariance propagation. Errors: `InvalidConfig` naming the field
    /// outside its range ([`SeekerInsConfig`]).
    fn design(config: &SeekerInsConfig<T>) -> Result<SeekerInsDesign<T>, NavError> {
        validate_config(config)?;
        Ok(compute_design(config))
    }

    /// Errors: `InvalidConfig` (a field outside its range; `field: "design"` for a design of
    /// another configuration), `NonFiniteInput`, `InputOutOfRange` (a variance of P0 beyond
    /// [`VARIANCE_CEILING`], an initial position outside the model range),
    /// `CovarianceNotPositiveSemiDefinite` (P0 not symmetric PSD).
    fn from_design(
        config: &SeekerInsConfig<T>,
        design: &SeekerInsDesign<T>,
        initial: &SeekerInsInitial<T>,
    ) -> Result<Self, NavError> {
        validate_config(config)?;
        check_design(config, design)?;
        validate_covariance(&initial.covariance)?;
        let ins = Ins::new(initial.state, config.imu_dt_s)?;
        let mut ekf = Self::assemble(config, design, ins);
        ekf.p = initial.covariance;
        Ok(ekf)
    }

    /// Restarts the navigation solution: position, velocity and attitude from
    /// `initial.state`, their covariance (states 0..9) from the navigation block of
    /// `initial.covariance`. Kept: the accelerometer, gyro and gimbal-error estimates with
    /// their covariance block (states 9..17; their correlations with the old navigation errors
    /// are dropped, so P stays PSD), the configuration, the design, the clock (time stamps
    /// must still increase) and every counter. Cleared: the pending covariance interval, the
    /// IMU-fault runs, the rejection run; the health restarts at `Initialising` (until the
    /// next IMU sample, which is integrated over the nominal interval). Counted in
    /// [`Health::reinitialisations`].
    ///
    /// Errors (filter unchanged): `NonFiniteInput`, `InputOutOfRange` (position outside the
    /// model range, a variance beyond [`VARIANCE_CEILING`]),
    /// `CovarianceNotPositiveSemiDefinite`.
    // Runs once per flight, or after a failure: cold and out of line, so that the caller's
    // hot path does not carry an inlined copy.
    #[cold]
    #[inline(never)]
    fn reinitialise(&mut self, initial: &SeekerInsInitial<T>) -> Result<(), NavError> {
        validate_covariance(&initial.covariance)?;
        let ins = Ins::new(initial.state, self.config.imu_dt_s)?;
        let zero = T::zero();
        for (j, col) in self.p.as_mut_slice().chunks_exact_mut(STATES).enumerate() {
            for (i, v) in col.iter_mut().enumerate() {
                if i < 9 && j < 9 {
                    *v = initial.covariance.get((i, j)).copied().unwrap_or(zero);
                } else if i < 9 || j < 9 {
                    *v = zero;
                }
            }
        }
        self.consider.forget_navigation();
        self.radii = None;
        self.ins = ins;
        self.steps_pending = 0;
        self.pending_us = 0;
        self.dv_ned_pending_m_s = Vector3::zeros();
        self.held_run = 0;
        self.clipped_run = 0;
        self.los.consecutive_rejected = 0;
        self.run_start = None;
        self.fusion_ref = None;
        self.last_imu_fault = None;
        self.last_update = LastUpdate::None;
        Health::bump(&mut self.health.reinitialisations);
        Ok(())
    }

    fn health(&self) -> Health {
        Health {
            state: self.health_state(),
            ..self.health
        }
    }

    fn time(&self) -> Option<Timestamp> {
        self.clock
    }
}

impl<T: Real> SeekerIns<T> {
    /// The configuration (with the gate, recovery and IMU fault policies in force).
    pub fn config(&self) -> &SeekerInsConfig<T> {
        &self.config
    }

    /// The design in use.
    pub fn design_in_use(&self) -> &SeekerInsDesign<T> {
        &self.design
    }

    /// Replaces the LOS gate. Errors (filter unchanged): `InvalidConfig { field: "gate" }`
    /// unless `Off` or a threshold in [1, 10⁴].
    pub fn set_gate(&mut self, gate: Gate<T>) -> Result<(), NavError> {
        validate_gate(gate)?;
        self.config.gate = gate;
        Ok(())
    }

    /// Replaces the recovery policy. Errors (filter unchanged): `InvalidConfig` naming
    /// `recovery.starved_after_s` or `recovery.action` (only `Inflate` is supported).
    pub fn set_recovery(&mut self, recovery: RecoveryPolicy<T>) -> Result<(), NavError> {
        validate_recovery(&recovery)?;
        self.config.recovery = recovery;
        Ok(())
    }

    /// Replaces the IMU fault policy. Errors (filter unchanged): `InvalidConfig` naming the
    /// field outside its range ([`ImuFaultPolicy`]).
    pub fn set_imu_faults(&mut self, policy: ImuFaultPolicy<T>) -> Result<(), NavError> {
        validate_imu_faults(&policy, self.config.imu_dt_s)?;
        self.config.imu_faults = policy;
        Ok(())
    }

    /// Navigation state (after all feedback so far).
    pub fn state(&self) -> &InsState<T> {
        self.ins.state()
    }

    /// The INS.
    pub fn ins(&self) -> &Ins<T> {
        &self.ins
    }

    /// Error covariance P (propagated up to the last covariance step).
    pub fn covariance(&self) -> &SMatrix<T, STATES, STATES> {
        &self.p
    }

    /// Sets the specific force the accelerometer-bias states refer to (body axes, m/s²;
    /// flight configuration, module `flight_noise`): their variance gains that of the scale
    /// factor and misalignment at it, and the errors of later departures from it are carried
    /// by the accelerometers' S and M as consider parameters (module `consider`). For a filter started from an estimate made at that
    /// specific force (the flight navigator's hand-over: the carry's); without it the
    /// reference is unaccelerated level flight at the first covariance step's attitude. Before the first covariance
    /// step only. Errors (filter unchanged): `NonFiniteInput` for a non-finite force,
    /// `InputOutOfRange` when the reference is already set.
    pub fn set_specific_force_reference(
        &mut self,
        f_ref_b_m_s2: &Vector3<T>,
    ) -> Result<(), NavError> {
        if !crate::math::checks::all_finite(f_ref_b_m_s2.as_slice()) {
            return Err(NavError::NonFiniteInput {
                input: "specific_force_reference",
            });
        }
        if self.config.instrument_errors.is_zero() {
            return Ok(());
        }
        let next = super::flight_noise::set_reference(
            &mut self.p,
            &self.bias_charge,
            &self.config.instrument_errors,
            f_ref_b_m_s2,
        )
        .ok_or(NavError::InputOutOfRange {
            input: "specific_force_reference",
        })?;
        self.bias_charge = next;
        self.consider_start();
        Ok(())
    }

    /// The specific force the accelerometer-bias states refer to (body axes, m/s²): the
    /// equivalent bias they estimate is `b + (S + M) f_ref` ([`Self::set_specific_force_reference`]);
    /// `None` before it is set or the first covariance step, and always for a configuration
    /// without instrument errors (the states are then the bias `b`).
    pub fn specific_force_reference(&self) -> Option<Vector3<T>> {
        self.bias_charge.reference_f_b_m_s2
    }

    /// Estimated accelerometer bias (body), m/s².
    pub fn accel_bias_m_s2(&self) -> Vector3<T> {
        self.accel_bias_m_s2
    }

    /// Estimated gyro bias (body), rad/s.
    pub fn gyro_bias_rad_s(&self) -> Vector3<T> {
        self.gyro_bias_rad_s
    }

    /// Estimated gimbal angle errors `[δθ_s, δψ_s]`, rad.
    pub fn gimbal_bias_rad(&self) -> Vector2<T> {
        self.gimbal_bias_rad
    }

    /// A scalar update computed outside the filter (the flight navigator's baro update,
    /// whose 18th state lives beside the 17), applied in place: the error estimate `x` (the
    /// filter's error-state convention) is fed back through the same path as a LOS update,
    /// then `P ← P − u kᵀ` (upper triangle computed, mirrored: exactly symmetric) and
    /// `P_ii ← P_ii + P_ii δ` (`delta`: the update's relative stabilising noise). Checked
    /// before anything changes: `Ok(false)` (nothing changed) when a variance would be
    /// negative or an entry not finite; `Err` (nothing changed) when the feedback is refused
    /// (a corrected position outside the model range). No copy of P.
    pub(crate) fn update_rank_one(
        &mut self,
        x: &nalgebra::SVector<T, STATES>,
        u: &nalgebra::SVector<T, STATES>,
        k: &nalgebra::SVector<T, STATES>,
        delta: T,
    ) -> Result<bool, NavError> {
        let zero = T::zero();
        let (u, k) = (u.as_slice(), k.as_slice());
        // Check pass over the upper triangle: `v · 0` is zero for a finite v, NaN otherwise.
        let mut probe = zero;
        let mut variances_ok = true;
        for (j, (col, kj)) in self.p.as_slice().chunks_exact(STATES).zip(k).enumerate() {
            for (pij, ui) in col.iter().zip(u).take(j) {
                probe += (*pij - *ui * *kj) * zero;
            }
            if let (Some(pjj), Some(uj)) = (col.get(j), u.get(j)) {
                let v = *pjj - *uj * *kj;
                let d = v + v * delta;
                variances_ok &= d >= zero && d.is_finite();
            }
        }
        if !(variances_ok && probe == zero) {
            return Ok(false);
        }
        self.feed_back_parts(x)?;
        let p = self.p.as_mut_slice();
        // Upper triangle, in place (column j, rows ≤ j: only entries not read again).
        for (j, (col, kj)) in p.chunks_exact_mut(STATES).zip(k).enumerate() {
            for (pij, ui) in col.iter_mut().zip(u).take(j + 1) {
                *pij -= *ui * *kj;
            }
        }
        // Mirrored (exactly symmetric), then the stabilising noise.
        for j in 1..STATES {
            for i in 0..j {
                if let Some(v) = p.get(j * STATES + i).copied() {
                    if let Some(dst) = p.get_mut(i * STATES + j) {
                        *dst = v;
                    }
                }
            }
        }
        for (j, col) in p.chunks_exact_mut(STATES).enumerate() {
            if let Some(v) = col.get_mut(j) {
                *v += *v * delta;
            }
        }
        Ok(true)
    }

    /// The flight navigator's baro-inertial loop owns the vertical channel: the error
    /// estimate `x` is fed back (as a LOS update's), then the (δh, δV_D) rows and columns of
    /// P are replaced by the loop's block `[[var_h, cov_h_vd], [cov_h_vd, var_vd]]` (m², m²/s,
    /// (m/s)²) with zero cross-covariances, in place. Checked first: `Err` (nothing changed)
    /// for a block entry not finite or a refused feedback.
    pub(crate) fn set_vertical_block(
        &mut self,
        x: &nalgebra::SVector<T, STATES>,
        var_h_m2: T,
        var_vd_m2_s2: T,
        cov_h_vd_m2_s: T,
    ) -> Result<(), NavError> {
        if !(var_h_m2.is_finite() && var_vd_m2_s2.is_finite() && cov_h_vd_m2_s.is_finite()) {
            return Err(NavError::NonFiniteInput {
                input: "external covariance update",
            });
        }
        self.feed_back_parts(x)?;
        let (ih, iv) = (super::POS + 2, super::VEL + 2);
        self.consider.scale_row(ih, T::zero());
        self.consider.scale_row(iv, T::zero());
        for k in 0..STATES {
            for (i, j) in [(ih, k), (k, ih), (iv, k), (k, iv)] {
                if let Some(v) = self.p.get_mut((i, j)) {
                    *v = T::zero();
                }
            }
        }
        for (i, j, v) in [
            (ih, ih, var_h_m2),
            (iv, iv, var_vd_m2_s2),
            (ih, iv, cov_h_vd_m2_s),
            (iv, ih, cov_h_vd_m2_s),
        ] {
            if let Some(dst) = self.p.get_mut((i, j)) {
                *dst = v;
            }
        }
        Ok(())
    }
}

impl<T: Real> SeekerIns<T> {
    /// The EKF at the start of its life (every estimate zero, no counts, P zero) from checked
    /// parts. Inlined: built where its caller puts it (the hand-over's slot), not on the
    /// stack; P is a literal zero, cleared in place.
    #[inline(always)]
    fn assemble(config: &SeekerInsConfig<T>, design: &SeekerInsDesign<T>, ins: Ins<T>) -> Self {
        Self {
            ins,
            p: SMatrix::zeros(),
            accel_bias_m_s2: Vector3::zeros(),
            gyro_bias_rad_s: Vector3::zeros(),
            gimbal_bias_rad: Vector2::zeros(),
            steps_pending: 0,
            pending_us: 0,
            dv_ned_pending_m_s: Vector3::zeros(),
            config: *config,
            design: *design,
            los: AidCounters::default(),
            counters: SeekerCounters::default(),
            health: Health::default(),
            held_run: 0,
            clipped_run: 0,
            clock: None,
            last_los: None,
            fusion_ref: None,
            last_imu_fault: None,
            run_start: None,
            last_update: LastUpdate::None,
            bias_charge: EquivalentBiasCharge::default(),
            consider: super::consider::ConsiderCross::default(),
            radii: None,
        }
    }

    /// [`Estimator::from_design`] into `slot`, with P0 written in place into the new EKF by
    /// `write_p0` (every entry), for a P0 its caller has shown to pass the covariance checks
    /// of `from_design` (finite, variances within [`VARIANCE_CEILING`], symmetric PSD): the
    /// navigator's hand-over P0, checked block by block. The same EKF as `from_design`,
    /// without the dense 17 × 17 check, without a P0 built elsewhere and copied, and without
    /// the EKF passing through the stack. Errors (`slot` unchanged): those of the
    /// configuration, the design and the state, as `from_design`.
    pub(crate) fn start_in(
        slot: &mut Option<Self>,
        config: &SeekerInsConfig<T>,
        design: &SeekerInsDesign<T>,
        state: &InsState<T>,
        write_p0: impl FnOnce(&mut SMatrix<T, STATES, STATES>),
    ) -> Result<(), NavError> {
        validate_config(config)?;
        check_design(config, design)?;
        let ins = Ins::new(*state, config.imu_dt_s)?;
        let ekf = slot.insert(Self::assemble(config, design, ins));
        write_p0(&mut ekf.p);
        Ok(())
    }
}

/// 99 % of the navigation states' [`VARIANCE_CEILING`]s, computed at compile time (the health
/// check runs every step; on the f32 target an f64 product per state is emulated).
const NAV_CEILING_99: [f64; 9] = {
    let [a, b, c, d, e, f, g, h, i, ..] = VARIANCE_CEILING;
    [
        0.99 * a,
        0.99 * b,
        0.99 * c,
        0.99 * d,
        0.99 * e,
        0.99 * f,
        0.99 * g,
        0.99 * h,
        0.99 * i,
    ]
};

impl<T: Real> SeekerIns<T> {
    /// How far the solution can be trusted now:
    ///
    /// * `Initialising`: no IMU sample since construction or re-initialisation;
    /// * `NeedsReinitialisation`: the position is outside the model range (|L| ≥ 86°,
    ///   |h| ≥ 1000 km), or a navigation variance is at its ceiling ([`VARIANCE_CEILING`]:
    ///   the filter knows nothing there any more, e.g. after a gap too long to bridge). The
    ///   filter keeps running (and comes back by itself if LOS updates bring the state and P
    ///   back), but its solution is not to be used until then or until `reinitialise`;
    /// * `Degraded`: no LOS component fused for [`super::AID_TIMEOUT_S`], the gate rejecting
    ///   every component of the last LOS samples, the last update conditioned or skipped, or
    ///   an IMU gap or clipped sample within the last [`super::AID_TIMEOUT_S`];
    /// * `Nominal` otherwise.
    pub(super) fn health_state(&self) -> HealthState {
        let Some(now) = self.ins.time() else {
            return HealthState::Initialising;
        };
        let at_ceiling = NAV_CEILING_99
            .iter()
            .enumerate()
            .any(|(i, m)| self.p.get((i, i)).is_some_and(|v| *v >= T::lit(*m)));
        if at_ceiling || !self.ins.state().position.is_in_range() {
            return HealthState::NeedsReinitialisation;
        }
        let since = |t: Option<_>| t.and_then(|t| now.micros_since(t));
        let aid_lost = since(self.fusion_ref).is_some_and(|us| us > AID_TIMEOUT_US);
        let imu_fault = since(self.last_imu_fault).is_some_and(|us| us <= AID_TIMEOUT_US);
        if aid_lost
            || imu_fault
            || self.los.consecutive_rejected > 0
            || self.last_update == LastUpdate::Degraded
        {
            return HealthState::Degraded;
        }
        HealthState::Nominal
    }

    /// Counters of one aid ([`SeekerAid`] says what each counts).
    pub fn aid_counters(&self, aid: SeekerAid) -> AidCounters {
        match aid {
            SeekerAid::Los => self.los,
        }
    }

    /// The counters that do not fit [`crate::contract::Health`].
    pub fn seeker_counters(&self) -> SeekerCounters {
        self.counters
    }
}

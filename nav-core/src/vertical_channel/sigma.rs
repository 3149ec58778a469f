//! The σ of the fixed-gain loops: the error covariance their design implies under a stated
//! noise model ([`ErrorModel`]), computed on the ground and only propagated on board while it
//! is not at its steady state.
//!
//! Error state `e = [δh, δV_z, δb, m]` (estimate − truth; m: the baro's correlated error).
//! Every loop is `x̂' = A₀ x̂ + e₂ A_z + K_m (z − C x̂)` with the aids of mode `m` in use, so
//!
//! ```text
//! e' = F_m e + w,   F_m = | A − K_m C   K_m e₁ |     A = A₀ + c e₂ e₁ᵀ (gravity gradient)
//!                         |    0        −1/τ_m |
//! Q  = diag(0, σ_a², σ_rw², 2σ_m²/τ_m) + K_m diag(σ_h² T_h, σ_v² T_v) K_mᵀ (on e₁…e₃)
//! ```
//!
//! (white aid samples of σ every T as their PSD `σ² T`, as in the aided design; the baro reads
//! `h − C4 V_z + m + w_h`). At design time (`f64`) each mode is discretised exactly over the
//! covariance interval `T_c` ([`COVARIANCE_INTERVAL_S`] rounded to whole IMU intervals):
//! `P ← Φ_m P Φ_mᵀ + Q_m`; the design mode's steady state `P∞` solves the discrete Lyapunov
//! equation `P∞ = Φ P∞ Φᵀ + Q` (doubling). On board the loop starts from
//! `P₀ = diag(σ_h0², σ_v0², σ_b0², σ_m²)` and propagates P once per covariance interval with the
//! weakest mode of that interval (an interval in which the baro was not in use at one step is
//! propagated without the baro: open-loop growth in an outage), re-anchorings move P as they
//! move the state, and once P is within [`SETTLED_TOLERANCE`] of `P∞` in the design mode it is
//! set to `P∞` and no longer propagated (no per-step cost) until a step leaves the design mode.

use crate::error::{require_non_negative, require_positive, ConfigIssue};
use crate::math::checks::{all_finite, first_outside, LowerBound, RangeCheck};
use crate::{NavError, Real};
use nalgebra::{Matrix2, Matrix3x2, Matrix4, SMatrix};

/// Nominal interval of the on-board covariance propagation, s (rounded to a whole number ≥ 1
/// of IMU intervals).
pub const COVARIANCE_INTERVAL_S: f64 = 0.1;
/// P is taken as settled (set to `P∞`, no longer propagated) when every element differs from
/// `P∞` by at most this fraction of `√(P∞_ii P∞_jj)`.
pub const SETTLED_TOLERANCE: f64 = 1.0e-3;
/// Most covariance intervals propagated in one call (a longer IMU gap is followed by a
/// re-anchoring of the baro).
pub const MAX_COVARIANCE_INTERVALS_PER_STEP: u32 = 128;
/// Doubling iterations of the discrete Lyapunov solver (2⁶⁴ intervals).
const LYAPUNOV_DOUBLINGS: u32 = 64;

/// The noise the σ of a loop is computed for: what the sensors and the initial state really do
/// (not the design assumptions of the aided gains, which may differ). Every value is a σ (not a
/// variance) unless it says density; ranges `[10⁻⁶, 10⁶)` ([`super::AID_SIGMA_RANGE`]), 0
/// allowed where stated.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ErrorModel<T> {
    /// Vertical accelerometer white-noise density (σ), m/s²/√Hz; PSD = value².
    pub accel_noise_m_s2_rt_hz: T,
    /// Accelerometer bias at the start (random constant), σ of the initial state's
    /// `accel_bias_m_s2`, m/s².
    pub accel_bias_sigma_m_s2: T,
    /// Accelerometer bias random-walk density (σ), m/s²/√s; 0 = a constant bias.
    pub accel_bias_rw_m_s2_rt_s: T,
    /// Baro white noise per sample, σ, m.
    pub baro_noise_m: T,
    /// Baro correlated error (1st-order Gauss-Markov), stationary σ, m; 0 = none.
    pub baro_markov_sigma_m: T,
    /// Its correlation time, s (> 0, ≤ [`super::MAX_TIMEOUT_S`]).
    pub baro_markov_tau_s: T,
    /// Velocity-aid white noise per sample, σ, m/s (unused by the classical loop).
    pub velocity_noise_m_s: T,
    /// σ of the initial state's (and of a re-initialisation's) altitude, m.
    pub initial_altitude_sigma_m: T,
    /// σ of the initial state's vertical velocity, m/s.
    pub initial_vz_sigma_m_s: T,
}

impl<T: Real> ErrorModel<T> {
    /// The spec's assumed sensors (`vertical-channel.md`): accelerometer noise
    /// 10⁻³ m/s²/√Hz, bias 1 mg random constant, baro 1 m white and a 3 m / 60 s Markov error,
    /// velocity aid 0.1 m/s; initial errors 20 m and 2 m/s (σ).
    pub fn paper() -> Self {
        Self {
            accel_noise_m_s2_rt_hz: T::lit(1.0e-3),
            accel_bias_sigma_m_s2: T::lit(9.806_65e-3),
            accel_bias_rw_m_s2_rt_s: T::zero(),
            baro_noise_m: T::lit(1.0),
            baro_markov_sigma_m: T::lit(3.0),
            baro_markov_tau_s: T::lit(60.0),
            velocity_noise_m_s: T::lit(0.1),
            initial_altitude_sigma_m: T::lit(20.0),
            initial_vz_sigma_m_s: T::lit(2.0),
        }
    }

    /// Validates the model (errors name `error_model.<field>`).
    #[inline(never)]
    pub(crate) fn validate(&self) -> Result<(), NavError> {
        let m = self;
        for (field, v) in [
            (
                "error_model.accel_noise_m_s2_rt_hz",
                m.accel_noise_m_s2_rt_hz,
            ),
            ("error_model.baro_noise_m", m.baro_noise_m),
            ("error_model.baro_markov_tau_s", m.baro_markov_tau_s),
            ("error_model.velocity_noise_m_s", m.velocity_noise_m_s),
            (
                "error_model.initial_altitude_sigma_m",
                m.initial_altitude_sigma_m,
            ),
            ("error_model.initial_vz_sigma_m_s", m.initial_vz_sigma_m_s),
        ] {
            require_positive(field, v)?;
        }
        for (field, v) in [
            ("error_model.accel_bias_sigma_m_s2", m.accel_bias_sigma_m_s2),
            (
                "error_model.accel_bias_rw_m_s2_rt_s",
                m.accel_bias_rw_m_s2_rt_s,
            ),
            ("error_model.baro_markov_sigma_m", m.baro_markov_sigma_m),
        ] {
            require_non_negative(field, v)?;
        }
        let (low, high) = (
            T::lit(super::AID_SIGMA_RANGE.low),
            T::lit(super::AID_SIGMA_RANGE.high),
        );
        let at_least = |field, value| RangeCheck {
            field,
            value,
            low: LowerBound::AtLeast(low),
            high,
        };
        let zero_or = |field, value| RangeCheck {
            field,
            value,
            low: LowerBound::ZeroOrAtLeast(low),
            high,
        };
        let checks = [
            at_least(
                "error_model.accel_noise_m_s2_rt_hz",
                m.accel_noise_m_s2_rt_hz,
            ),
            zero_or("error_model.accel_bias_sigma_m_s2", m.accel_bias_sigma_m_s2),
            zero_or(
                "error_model.accel_bias_rw_m_s2_rt_s",
                m.accel_bias_rw_m_s2_rt_s,
            ),
            at_least("error_model.baro_noise_m", m.baro_noise_m),
            zero_or("error_model.baro_markov_sigma_m", m.baro_markov_sigma_m),
            at_least("error_model.velocity_noise_m_s", m.velocity_noise_m_s),
            at_least(
                "error_model.initial_altitude_sigma_m",
                m.initial_altitude_sigma_m,
            ),
            at_least("error_model.initial_vz_sigma_m_s", m.initial_vz_sigma_m_s),
        ];
        let field = match first_outside(&checks) {
            Some(field) => field,
            None if m.baro_markov_tau_s > T::lit(super::MAX_TIMEOUT_S) => {
                "error_model.baro_markov_tau_s"
            }
            None => return Ok(()),
        };
        Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        })
    }

    /// The model in another float type.
    pub fn cast<U: Real>(&self) -> ErrorModel<U> {
        let to = |v: T| U::lit(v.to_f64());
        ErrorModel {
            accel_noise_m_s2_rt_hz: to(self.accel_noise_m_s2_rt_hz),
            accel_bias_sigma_m_s2: to(self.accel_bias_sigma_m_s2),
            accel_bias_rw_m_s2_rt_s: to(self.accel_bias_rw_m_s2_rt_s),
            baro_noise_m: to(self.baro_noise_m),
            baro_markov_sigma_m: to(self.baro_markov_sigma_m),
            baro_markov_tau_s: to(self.baro_markov_tau_s),
            velocity_noise_m_s: to(self.velocity_noise_m_s),
            initial_altitude_sigma_m: to(self.initial_altitude_sigma_m),
            initial_vz_sigma_m_s: to(self.initial_vz_sigma_m_s),
        }
    }

    /// The model's values in fingerprint order (the order of the fields).
    pub(crate) fn values(&self) -> [T; 9] {
        [
            self.accel_noise_m_s2_rt_hz,
            self.accel_bias_sigma_m_s2,
            self.accel_bias_rw_m_s2_rt_s,
            self.baro_noise_m,
            self.baro_markov_sigma_m,
            self.baro_markov_tau_s,
            self.velocity_noise_m_s,
            self.initial_altitude_sigma_m,
            self.initial_vz_sigma_m_s,
        ]
    }
}

/// σ of the estimate (square roots of the covariance's diagonal).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct VerticalSigma<T> {
    /// σ of the altitude estimate, m.
    pub altitude_m: T,
    /// σ of the vertical velocity estimate, m/s.
    pub vz_m_s: T,
}

/// One aid mode's covariance step over the covariance interval.
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct CovStep<T: Real> {
    pub(crate) phi: Matrix4<T>,
    pub(crate) q: Matrix4<T>,
}

/// What the design stores for the σ (modes none, baro, velocity, both).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SigmaDesign<T: Real> {
    /// Covariance interval, µs (a whole number of IMU intervals).
    pub(crate) interval_us: u64,
    pub(crate) none: CovStep<T>,
    pub(crate) baro: CovStep<T>,
    pub(crate) velocity: CovStep<T>,
    pub(crate) both: CovStep<T>,
    /// The design mode (classical: baro; aided: both): whether it uses the velocity aid.
    pub(crate) design_uses_velocity: bool,
    /// Steady state of the design mode.
    pub(crate) p_steady: Matrix4<T>,
    /// Start (and re-initialisation) covariance.
    pub(crate) p_initial: Matrix4<T>,
    /// Baro white-noise variance (re-anchoring), m².
    pub(crate) baro_var: T,
    /// Velocity-aid white-noise variance (re-anchoring), (m/s)².
    pub(crate) velocity_var: T,
    /// Baro lag compensation, s (re-anchoring moves ĥ so that ĥ − lag V̂_z = z).
    pub(crate) lag_s: T,
}

/// Number of stored values of a [`SigmaDesign`].
pub(crate) const SIGMA_DESIGN_COUNT: usize = 1 + 4 * 32 + 1 + 16 + 16 + 3;

impl<T: Real> CovStep<T> {
    fn select(d: &SigmaDesign<T>, baro: bool, velocity: bool) -> &Self {
        match (baro, velocity) {
            (false, false) => &d.none,
            (true, false) => &d.baro,
            (false, true) => &d.velocity,
            (true, true) => &d.both,
        }
    }
}

/// The design inputs of the σ (in `f64`).
pub(crate) struct SigmaInputs<'a> {
    pub(crate) bias_sign: f64,
    pub(crate) c_grav: f64,
    pub(crate) k: &'a Matrix3x2<f64>,
    pub(crate) c: &'a SMatrix<f64, 2, 3>,
    pub(crate) imu_dt_s: f64,
    pub(crate) baro_period_s: f64,
    pub(crate) velocity_period_s: f64,
    pub(crate) design_uses_velocity: bool,
}

/// The on-board covariance of a loop (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct SigmaTrack<T: Real> {
    pub(crate) design: SigmaDesign<T>,
    /// Covariance of `[δh, δV_z, δb, m]` at the end of the last propagated interval.
    pub(crate) p: Matrix4<T>,
    /// Time accumulated in the current interval, µs.
    elapsed_us: u64,
    /// The baro / velocity aid was in use at every step of the current interval.
    baro_all: bool,
    velocity_all: bool,
    /// P is the design's steady state and is not propagated.
    settled: bool,
}

impl<T: Real> SigmaTrack<T> {
    pub(crate) fn new(design: SigmaDesign<T>) -> Self {
        Self {
            p: design.p_initial,
            design,
            elapsed_us: 0,
            baro_all: true,
            velocity_all: true,
            settled: false,
        }
    }

    /// Back to the initial covariance (re-initialisation).
    pub(crate) fn restart(&mut self) {
        *self = Self::new(self.design);
    }

    /// Whether [`Self::tick`] with these aids would leave σ as it is: settled, in the design's
    /// aid mode.
    #[inline(always)]
    pub(crate) fn holds(&self, use_baro: bool, use_velocity: bool) -> bool {
        self.settled && use_baro && use_velocity == self.design.design_uses_velocity
    }

    /// One committed (sub-)step of `h_us` with the aids used. Costs nothing but a compare while
    /// settled in the design mode.
    #[inline(always)]
    pub(crate) fn tick(&mut self, h_us: u64, use_baro: bool, use_velocity: bool) {
        if self.settled {
            if self.holds(use_baro, use_velocity) {
                return;
            }
            self.settled = false;
            self.elapsed_us = 0;
        }
        self.accumulate(h_us, use_baro, use_velocity);
    }

    #[inline(always)]
    fn accumulate(&mut self, h_us: u64, use_baro: bool, use_velocity: bool) {
        self.baro_all &= use_baro;
        self.velocity_all &= use_velocity;
        self.elapsed_us = self.elapsed_us.saturating_add(h_us);
        if self.elapsed_us >= self.design.interval_us {
            self.propagate();
        }
    }

    /// Propagates over every whole interval accumulated (at most
    /// [`MAX_COVARIANCE_INTERVALS_PER_STEP`]; the rest of a longer gap is dropped).
    #[cold]
    #[inline(never)]
    fn propagate(&mut self) {
        let d = &self.design;
        let step = CovStep::select(d, self.baro_all, self.velocity_all);
        let mut p = self.p;
        let mut n = 0u32;
        while self.elapsed_us >= d.interval_us && n < MAX_COVARIANCE_INTERVALS_PER_STEP {
            p = step.phi * p * step.phi.transpose() + step.q;
            p = (p + p.transpose()) * T::lit(0.5);
            self.elapsed_us = self.elapsed_us.saturating_sub(d.interval_us);
            n += 1;
        }
        if self.elapsed_us >= d.interval_us {
            // The rest of a gap longer than the propagated intervals is dropped.
            self.elapsed_us = self.elapsed_us.checked_rem(d.interval_us).unwrap_or(0);
        }
        if !all_finite(p.as_slice()) {
            // Saturated: a σ beyond anything physical (never reached in the envelope).
            p = Matrix4::from_diagonal_element(T::lit(super::MAX_GATE_VARIANCE));
        }
        let design_mode = self.baro_all && self.velocity_all == d.design_uses_velocity;
        self.p = p;
        self.baro_all = true;
        self.velocity_all = true;
        if design_mode && near(&p, &d.p_steady) {
            self.p = d.p_steady;
            self.settled = true;
            self.elapsed_us = 0;
        }
    }

    /// The re-anchorings of a step (baro first, as the state was moved).
    #[cold]
    #[inline(never)]
    pub(crate) fn reanchored(&mut self, baro: bool, velocity: bool) {
        if baro {
            self.reanchor_baro();
        }
        if velocity {
            self.reanchor_velocity();
        }
    }

    /// A re-anchoring of the baro: ĥ moved so that `ĥ − lag V̂_z = z`, i.e.
    /// `δh ← lag δV_z + m + w_h`.
    #[cold]
    #[inline(never)]
    pub(crate) fn reanchor_baro(&mut self) {
        let mut j = Matrix4::<T>::identity();
        j.m11 = T::zero();
        j.m12 = self.design.lag_s;
        j.m14 = T::one();
        let mut p = j * self.p * j.transpose();
        p.m11 += self.design.baro_var;
        self.p = p;
        self.settled = false;
    }

    /// A re-anchoring of the vertical velocity on the aid: `δV_z ← w_v`.
    #[cold]
    #[inline(never)]
    pub(crate) fn reanchor_velocity(&mut self) {
        let mut j = Matrix4::<T>::identity();
        j.m22 = T::zero();
        let mut p = j * self.p * j.transpose();
        p.m22 += self.design.velocity_var;
        self.p = p;
        self.settled = false;
    }

    /// Replaces the (altitude, vertical velocity) block of P by `c` (m², m²/s, (m/s)²; checked
    /// by the caller: symmetric, PSD, finite) and zeroes its cross terms with the bias and the
    /// baro's correlated error: P stays PSD (block diagonal of two PSD blocks).
    pub(crate) fn set_covariance_h_vz(&mut self, c: &Matrix2<T>) {
        let mut p = self.p;
        let zero = T::zero();
        p.m11 = c.m11;
        p.m12 = c.m12;
        p.m21 = c.m12;
        p.m22 = c.m22;
        (p.m13, p.m14, p.m23, p.m24) = (zero, zero, zero, zero);
        (p.m31, p.m41, p.m32, p.m42) = (zero, zero, zero, zero);
        self.p = p;
        self.settled = false;
    }

    /// Covariance of (altitude m, vertical velocity m/s): m², m²/s, (m/s)².
    pub(crate) fn covariance_h_vz(&self) -> Matrix2<T> {
        Matrix2::new(self.p.m11, self.p.m12, self.p.m21, self.p.m22)
    }

    pub(crate) fn sigma(&self) -> VerticalSigma<T> {
        VerticalSigma {
            altitude_m: self.p.m11.sqrt(),
            vz_m_s: self.p.m22.sqrt(),
        }
    }
}

/// `|a_ij − b_ij| ≤ tol · √(b_ii b_jj)` for every element.
fn near<T: Real>(a: &Matrix4<T>, b: &Matrix4<T>) -> bool {
    let tol = T::lit(SETTLED_TOLERANCE);
    let d = b.diagonal();
    for j in 0..4 {
        for i in 0..4 {
            let (Some(x), Some(y), Some(di), Some(dj)) =
                (a.get((i, j)), b.get((i, j)), d.get(i), d.get(j))
            else {
                return false;
            };
            // NaN compares false: not near.
            let close = (*x - *y).abs() <= tol * (*di * *dj).sqrt();
            if !close {
                return false;
            }
        }
    }
    true
}

#[path = "sigma_design.rs"]
mod design;

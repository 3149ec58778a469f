//! Baro damping as an EKF measurement: the baro's correlated error `b` as an 18th state kept
//! beside the seeker INS's 17 (the generated 17-state kernels stay as they are).
//!
//! The joint covariance is `[[P, c], [cᵀ, s]]`: P the EKF's 17 × 17, `c = E[δx δb]` a
//! 17-vector, `s = var(δb)`, with `δb = b̂ − b` (estimate minus truth, as every error state).
//!
//! * Prediction (each covariance step of the EKF, over its interval Δt, `e = exp(−Δt/τ)`):
//!   P by the EKF itself; `c ← e Φ c` with the EKF's own Φ
//!   (`SeekerIns::predict_covariance_cross`); `s ← e² s + σ_b² (1 − e²)`; `b̂ ← e b̂`.
//! * Measurement: `z = h(t) − τ_b V_up(t) + b + v` (the baro's lag τ_b to first order, its
//!   white noise v of variance `R = max(σ_w², (τ² ā)² + (ε z)²)`: the configured σ_w, or what
//!   the model cannot resolve, `BaroState::measurement_variance_m2`), predicted as
//!   `ẑ = ĥ + τ V̂_D + b̂` with
//!   `τ = τ_b + age` (a sample older than the tick adds its age to the lag). The error-state
//!   measurement `y = ẑ − z = H δx_aug − v` has `H = [e_h + τ e_VD, 1]` (`e_h`: the δh state,
//!   `e_VD`: δV_D).
//! * Update (one scalar, the EKF's gate): `u = P hᵀ + c`, `u_b = cᵀh + s`,
//!   `S = h u + u_b + R`; `δx̂ = u y / S` fed back through the EKF's correction path,
//!   `b̂ ← b̂ − u_b y / S`; `P ← P − u uᵀ/S`, `c ← c − u u_b/S`, `s ← s − u_b²/S` (the
//!   18-state update written in its blocks; checked against the dense 18-state Joseph form
//!   in the tests). As the EKF's LOS update: R is raised to `hPhᵀ / κ` when the sample would
//!   carry more information than the working precision resolves (κ =
//!   [`max_information_ratio`], 8 389 in f32), and every variance gets the stabilising noise
//!   `min(max(ρ, 1), STABILISING_EPS) ε` (ρ = hPhᵀ/R). A result with a negative variance or a
//!   non-finite entry is not applied (`Skipped`).
//! * LOS updates (terminal): the column follows the 18-state sequential update with
//!   `h_aug = [h, 0]` (`SeekerIns::update_los_cross`): per fused component `g = h c`,
//!   `c ← c − K g`, `s ← s − g²/S`, `b̂ ← b̂ − g ν/S`.
//! * What the 17-state EKF does to P other than `Φ P Φᵀ + Q` and the updates above (a variance
//!   held at its ceiling, a long IMU gap, a recovery inflation) is followed by `c ← 0`: the
//!   joint covariance stays PSD (block diagonal of two PSD blocks) and the correlation between
//!   the baro error and the INS errors is forgotten.

use crate::contract::Estimator;
use crate::contract::{FusionOutcome, FusionReport, Gate};
use crate::math::kalman::gate_scalar;
use crate::seeker_ins::{max_information_ratio, SeekerIns, POS, STABILISING_EPS, STATES, VEL};
use crate::vertical_channel::{
    BaroSample, ClassicalConfig, ClassicalDesign, ClassicalLoop, InitialState,
};
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector};

use super::types::BaroErrorModel;

/// Oldest baro sample accepted, s (older: `MeasurementTimeOutOfWindow`).
pub const MAX_BARO_AGE_S: f64 = 1.0;

/// The baro-error state beside the EKF.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BaroState<T> {
    /// `E[δx δb]`, units of the error state × m.
    pub cross: SVector<T, STATES>,
    /// `var(δb)`, m².
    pub variance_m2: T,
    /// Estimate of the correlated baro error b, m.
    pub bias_m: T,
    /// Envelope of the INS's vertical acceleration seen through the baro's lag, m/s²
    /// (`|ΔV̂_D / Δt|` between samples, through a first-order lag of the baro's τ_b): what the
    /// first-order lag compensation leaves, `τ² L(ḧ)`, is bounded by `τ²` times it
    /// (`Self::measurement_variance_m2`).
    pub lag_accel_m_s2: T,
    /// The INS's V̂_D at the previous sample, m/s.
    pub last_vd_m_s: T,
}

impl<T: Real> BaroState<T> {
    /// At the start of damping: no correlation, the stationary variance, zero estimate.
    pub fn start(model: &BaroErrorModel<T>) -> Self {
        Self {
            cross: SVector::zeros(),
            variance_m2: model.markov_sigma_m * model.markov_sigma_m,
            bias_m: T::zero(),
            lag_accel_m_s2: T::zero(),
            last_vd_m_s: T::zero(),
        }
    }

    /// No baro error state (damping off, or by the baro-inertial loop): all zero.
    pub fn off() -> Self {
        Self {
            cross: SVector::zeros(),
            variance_m2: T::zero(),
            bias_m: T::zero(),
            lag_accel_m_s2: T::zero(),
            last_vd_m_s: T::zero(),
        }
    }

    /// The variance of the sample's white error the update uses, m²: the configured
    /// `σ_w²`, or — when larger — what the measurement model cannot resolve below:
    ///
    /// * the first-order lag compensation `z ≈ h − τ ḣ` leaves `z − (h − τ ḣ) = τ² L(ḧ)`
    ///   exactly (a first-order lag `L = 1/(1 + τ_b s)`: `1 − τs − L = −τ²s² L`), bounded by
    ///   `τ² ā` with `ā` the envelope of `|ḧ|` through the lag ([`Self::lag_accel_m_s2`],
    ///   updated here from the INS's V̂_D at this sample and the previous one);
    /// * the innovation `ẑ − z` differences two altitudes rounded to `T`, each by at most
    ///   `ε |z| / 2` (ε = `T::EPS`, the relative spacing of `T`): together `ε |z|`.
    ///
    /// Floor `(τ² ā)² + (ε z)²`. A baro described more precisely than that (white σ 1 µm
    /// behind a 0.2 s lag) would otherwise fuse the neglected lag term as information worth
    /// microns, drive the altitude's σ below its real error and have every later sample
    /// rejected by the gate. `tau_s`: the effective lag (the baro's plus the sample's age), s;
    /// `previous`: the time of the previous sample of damping (`None`: this is the first).
    pub(crate) fn measurement_variance_m2(
        &mut self,
        model: &BaroErrorModel<T>,
        ekf: &SeekerIns<T>,
        tau_s: T,
        sample: &BaroSample<T>,
        previous: Option<crate::time::Timestamp>,
    ) -> T {
        let vd = ekf.state().vel_ned_m_s.z;
        let dt: Option<T> = previous
            .and_then(|t| sample.time.micros_since(t))
            .map(crate::time::micros_to_seconds);
        match dt {
            Some(dt) if dt > T::zero() => {
                let a = ((vd - self.last_vd_m_s) / dt).abs();
                // The baro's first-order lag over Δt (implicit Euler: stable for any Δt / τ_b).
                self.lag_accel_m_s2 += (a - self.lag_accel_m_s2) * (dt / (model.lag_s + dt));
            }
            Some(_) => {}
            // The first sample of damping: no previous V̂_D; the lag taken in steady state on
            // the INS's present vertical acceleration (its specific force, Coriolis and
            // transport-rate term, normal gravity).
            None => {
                let st = ekf.state();
                let g = crate::earth::normal_gravity_m_s2(
                    T::lit(st.position.lat_rad),
                    T::lit(st.position.alt_m),
                );
                let f = ekf.ins().specific_force_ned_m_s2();
                self.lag_accel_m_s2 = (loop_vertical_input_m_s2(st, &f) - g).abs();
            }
        }
        self.last_vd_m_s = vd;
        let white = model.white_sigma_m * model.white_sigma_m;
        let lag = tau_s * tau_s * self.lag_accel_m_s2;
        let rounding = T::EPS * sample.altitude_m;
        let floor = lag * lag + rounding * rounding;
        if floor > white {
            floor
        } else {
            white
        }
    }

    /// The Markov part of a prediction over `dt_s` (the column has been multiplied by Φ).
    pub fn decay(&mut self, model: &BaroErrorModel<T>, dt_s: T) -> T {
        let e = (-dt_s / model.markov_tau_s).exp();
        let e2 = e * e;
        let var = model.markov_sigma_m * model.markov_sigma_m;
        self.cross *= e;
        self.variance_m2 = e2 * self.variance_m2 + var * (T::one() - e2);
        self.bias_m *= e;
        e
    }

    /// The measurement row's 17-part `e_h + τ e_VD` for the effective lag `tau_s`.
    pub fn h_row(tau_s: T) -> SVector<T, STATES> {
        let mut h = SVector::<T, STATES>::zeros();
        if let Some(v) = h.get_mut(POS + 2) {
            *v = T::one();
        }
        if let Some(v) = h.get_mut(VEL + 2) {
            *v = tau_s;
        }
        h
    }

    /// Predicted baro reading `ĥ + τ V̂_D + b̂`, m.
    pub fn predicted_m(&self, ekf: &SeekerIns<T>, tau_s: T) -> T {
        let s = ekf.state();
        T::lit(s.position.alt_m) + tau_s * s.vel_ned_m_s.z + self.bias_m
    }
}

/// The baro-inertial loop's vertical input on a vehicle moving over the earth, m/s² (up):
/// the INS's upward specific force `−f_D` plus the vertical part of its Coriolis and
/// transport-rate acceleration,
/// `[(2ω_ie + ω_en) × v]_D = (2Ω cos L + V_E/(R_N + h)) V_E + V_N²/(R_M + h)`
/// (`state`: the INS's position and NED velocity, m/s; `f_ned_m_s2`: its specific force in
/// NED, m/s²). The loop integrates `V̇_z = input − g(ĥ)`; the INS's vertical velocity obeys
/// `V̇_up = −f_D − g + [(2ω_ie + ω_en) × v]_D`. Fed the specific force alone, the loop misses
/// that term — at 200 m/s east at 37° latitude 0.028 m/s² (2.9 mg), thirteen times the
/// accelerometer error its σ is designed for — and its V̂_z runs off until its bias state has
/// absorbed it (0.5 m/s, thirty seconds after the start, on the mission).
pub(crate) fn loop_vertical_input_m_s2<T: Real>(
    state: &crate::seeker_ins::InsState<T>,
    f_ned_m_s2: &nalgebra::Vector3<T>,
) -> T {
    let lat = T::lit(state.position.lat_rad);
    let alt = T::lit(state.position.alt_m);
    let v = &state.vel_ned_m_s;
    let (r_m, r_n) = crate::earth::radii_m(lat);
    let two_omega_cos = T::lit(2.0 * crate::earth::EARTH_RATE_RAD_S) * crate::math::trig::cos(lat);
    let coriolis_d = (two_omega_cos + v.y / (r_n + alt)) * v.y + v.x * v.x / (r_m + alt);
    coriolis_d - f_ned_m_s2.z
}

/// The baro-inertial loop at the start of midcourse: its state from the INS's (ĥ, V̂_z), its
/// (h, V_z) covariance from the EKF's (δh, δV_D) block (`δV_z = −δV_D`) — what is known of
/// that state's error at the start, not the error model's assumed initial σ (the
/// configuration's, which stays the loop's start wherever no filter seeds it). `None`: the
/// design refuses to start the loop there (an INS altitude outside its range). A block the
/// loop refuses (not PSD) leaves the error model's initial σ.
pub(crate) fn start_inertial_loop<T: Real>(
    config: &ClassicalConfig<T>,
    design: &ClassicalDesign<T>,
    ekf: &SeekerIns<T>,
    time: crate::time::Timestamp,
) -> Option<ClassicalLoop<T>> {
    let s = ekf.state();
    let init = InitialState {
        time,
        altitude_m: T::lit(s.position.alt_m),
        vz_up_m_s: -s.vel_ned_m_s.z,
        accel_bias_m_s2: T::zero(),
    };
    let mut lp = ClassicalLoop::from_design(config, design, &init).ok()?;
    let p = ekf.covariance();
    let at = |i: usize, j: usize| p.get((i, j)).copied().unwrap_or_else(T::zero);
    let (ih, iv) = (POS + 2, VEL + 2);
    let h_vz = -(at(ih, iv) + at(iv, ih)) * T::lit(0.5);
    let c = nalgebra::Matrix2::new(at(ih, ih), h_vz, h_vz, at(iv, iv));
    // Refused (not PSD): the loop keeps the error model's initial σ.
    lp.set_covariance_h_vz(&c).unwrap_or(());
    Some(lp)
}

/// The updated blocks of one baro fusion (before they are applied; the reference the
/// navigator's in-place update is tested against).
#[cfg(test)]
#[derive(Debug, Clone, Copy)]
pub struct BaroUpdate<T> {
    /// The report.
    pub report: FusionReport<T>,
    /// Error estimate of the 17 states (EKF convention).
    pub dx: SVector<T, STATES>,
    /// Error estimate of the baro error, m (`δb̂`).
    pub db_m: T,
    /// Updated P, c, s.
    pub p: SMatrix<T, STATES, STATES>,
    /// Updated cross-covariance.
    pub cross: SVector<T, STATES>,
    /// Updated var(δb), m².
    pub variance_m2: T,
}

/// One baro fusion without its P: the gain, the small blocks updated, and what P's update
/// `P ← P − u kᵀ`, then `P_ii ← P_ii + P_ii δ`, needs (applied in place by the navigator,
/// `SeekerIns::update_rank_one`, which checks it first).
#[derive(Debug, Clone, Copy)]
pub(crate) struct BaroGain<T> {
    /// The report.
    pub(crate) report: FusionReport<T>,
    /// `u = P hᵀ + c` (units of the error state × m).
    pub(crate) u: SVector<T, STATES>,
    /// The gain `k = u / S` (units of the error state / m).
    pub(crate) k: SVector<T, STATES>,
    /// Error estimate of the 17 states (EKF convention).
    pub(crate) dx: SVector<T, STATES>,
    /// Error estimate of the baro error, m (`δb̂`).
    pub(crate) db_m: T,
    /// Updated cross-covariance.
    pub(crate) cross: SVector<T, STATES>,
    /// Updated var(δb) with its stabilising noise, m².
    pub(crate) variance_m2: T,
    /// Relative stabilising noise of every variance (dimensionless).
    pub(crate) delta: T,
    /// The baro error's gain `u_b / S` (dimensionless), for the consider parameters' row.
    pub(crate) k_b: T,
}

/// The joint scalar update's gate and small blocks (module doc) for the measurement row of
/// the effective lag `tau_s` ([`BaroState::h_row`]), over its two non-zero columns only:
/// `u = P[:, h] + τ P[:, V_D] + c` — the numbers of the dense products, whose other terms are
/// zero. `None` when the sample cannot be fused numerically (the baro blocks; P is checked
/// where it is updated); a gate rejection returns the report with `Rejected` (nothing to
/// apply).
pub(crate) fn baro_gain<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    st: &BaroState<T>,
    tau_s: T,
    y: T,
    r: T,
    gate: Gate<T>,
) -> Option<Result<BaroGain<T>, FusionReport<T>>> {
    let zero = T::zero();
    let col = |j: usize| p.as_slice().get(j * STATES..(j + 1) * STATES);
    let (Some(ph), Some(pv)) = (col(POS + 2), col(VEL + 2)) else {
        return None;
    };
    let mut u = st.cross;
    for ((ui, a), b) in u.iter_mut().zip(ph.iter()).zip(pv.iter()) {
        *ui = (*a + *b * tau_s) + *ui;
    }
    let at = |v: &SVector<T, STATES>, i: usize| v.get(i).copied().unwrap_or(zero);
    let u_b = (at(&st.cross, POS + 2) + at(&st.cross, VEL + 2) * tau_s) + st.variance_m2;
    let hph = (at(&u, POS + 2) + at(&u, VEL + 2) * tau_s) + u_b;
    gain_from(u, u_b, hph, st, y, r, gate)
}

/// The gate and the small blocks from `u = P hᵀ + c`, `u_b = cᵀh + s`, `hPhᵀ` of the joint
/// row (module doc).
fn gain_from<T: Real>(
    u: SVector<T, STATES>,
    u_b: T,
    hph: T,
    st: &BaroState<T>,
    y: T,
    r: T,
    gate: Gate<T>,
) -> Option<Result<BaroGain<T>, FusionReport<T>>> {
    // As the LOS update: no more information than the working precision resolves.
    let kappa = max_information_ratio::<T>();
    let r = if hph / kappa > r { hph / kappa } else { r };
    let s = hph + r;
    let (report, inv_s) = gate_scalar(y, hph, s, gate)?;
    if report.outcome != FusionOutcome::Fused {
        return Some(Err(report));
    }
    let k = u * inv_s;
    let k_b = u_b * inv_s;
    let cross = st.cross - u * k_b;
    let mut variance_m2 = st.variance_m2 - u_b * k_b;
    // Stabilising noise as after a LOS update: `δ = min(max(ρ, 1), STABILISING_EPS) ε` of
    // each variance (ρ = hPhᵀ / r), a margin above the rounding of the update. At least one ε:
    // the rounding of `P − u kᵀ` is an ε of P's entries whatever ρ. With `ρ ε` (baro ρ ≈ 0.1)
    // and almost no process noise P went indefinite 10 times in 20 missions (6 on baro ticks,
    // 4 on the LOS updates after them; relative LDLᵀ pivot down to −3.2e-3); with the floor
    // never.
    let rho = hph / r;
    let one = T::one();
    let rho = if rho > one { rho } else { one };
    let cap = T::lit(STABILISING_EPS);
    let delta = if rho < cap { rho } else { cap } * T::EPS;
    variance_m2 += variance_m2 * delta;
    let ok = variance_m2 >= T::zero()
        && variance_m2.is_finite()
        && crate::math::checks::all_finite(cross.as_slice());
    if !ok {
        return None;
    }
    Some(Ok(BaroGain {
        report,
        u,
        k,
        dx: k * y,
        db_m: k_b * y,
        cross,
        variance_m2,
        delta,
        k_b,
    }))
}

/// P after a baro gain: `P − u kᵀ` (upper triangle, mirrored), then `P_ii + P_ii δ` — the
/// numbers `SeekerIns::update_rank_one` writes in place. `None`: a variance negative or an
/// entry not finite.
#[cfg(test)]
pub(crate) fn rank_one_p<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    u: &SVector<T, STATES>,
    k: &SVector<T, STATES>,
    delta: T,
) -> Option<SMatrix<T, STATES, STATES>> {
    let mut p_new = *p;
    for j in 0..STATES {
        for i in 0..=j {
            let (Some(ui), Some(kj)) = (u.get(i), k.get(j)) else {
                continue;
            };
            let v = p.get((i, j)).copied().unwrap_or_else(T::zero) - *ui * *kj;
            if let Some(dst) = p_new.get_mut((i, j)) {
                *dst = v;
            }
            if let Some(dst) = p_new.get_mut((j, i)) {
                *dst = v;
            }
        }
    }
    for i in 0..STATES {
        if let Some(v) = p_new.get_mut((i, i)) {
            *v += *v * delta;
        }
    }
    let ok = p_new.diagonal().iter().all(|d| *d >= T::zero())
        && crate::math::checks::all_finite(p_new.as_slice());
    ok.then_some(p_new)
}

/// The joint scalar update in its blocks (module doc), P included (the reference of the
/// navigator's in-place update). `None` when the sample cannot be fused numerically
/// (skipped); a gate rejection returns the report with `Rejected` and the blocks unchanged.
#[cfg(test)]
pub fn baro_update<T: Real>(
    p: &SMatrix<T, STATES, STATES>,
    st: &BaroState<T>,
    h: &SVector<T, STATES>,
    y: T,
    r: T,
    gate: Gate<T>,
) -> Option<BaroUpdate<T>> {
    let u: SVector<T, STATES> = p * h + st.cross;
    let u_b = st.cross.dot(h) + st.variance_m2;
    let hph = h.dot(&u) + u_b;
    match gain_from(u, u_b, hph, st, y, r, gate)? {
        Err(report) => Some(BaroUpdate {
            report,
            dx: SVector::zeros(),
            db_m: T::zero(),
            p: *p,
            cross: st.cross,
            variance_m2: st.variance_m2,
        }),
        Ok(g) => Some(BaroUpdate {
            report: g.report,
            dx: g.dx,
            db_m: g.db_m,
            p: rank_one_p(p, &g.u, &g.k, g.delta)?,
            cross: g.cross,
            variance_m2: g.variance_m2,
        }),
    }
}

/// Validates a baro sample against the tick time: finite, not in the future, at most
/// [`MAX_BARO_AGE_S`] old. Returns its age, s.
pub fn baro_age_s<T: Real>(
    sample: &BaroSample<T>,
    now: crate::time::Timestamp,
) -> Result<T, NavError> {
    crate::error::input_finite("baro.altitude_m", sample.altitude_m)?;
    let age_us = now
        .micros_since(sample.time)
        .ok_or(NavError::MeasurementTimeOutOfWindow)?;
    let age: T = crate::time::micros_to_seconds(age_us);
    if age > T::lit(MAX_BARO_AGE_S) {
        return Err(NavError::MeasurementTimeOutOfWindow);
    }
    Ok(age)
}

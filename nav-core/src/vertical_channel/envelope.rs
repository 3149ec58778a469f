//! The configuration envelope checked at design time (`f64`): the IMU interval, the aid
//! periods, the accuracy of the variable-interval step and the stability of the multirate
//! loop.

use super::modes::{discretise_modes, off_nominal_increment, AidMask, Feedback};
use super::riccati::char_poly3;
use super::{IMU_DT_RANGE_S, INTERVAL_ACCURACY, MAX_AID_PERIOD_IMU_INTERVALS};
use crate::error::{require_positive, ConfigIssue};
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2, RowVector3, Vector2};

/// Checks the configured IMU interval (compares only: also used by `from_design`).
#[inline(never)]
pub(crate) fn check_imu_dt<T: Real>(imu_dt_s: T) -> Result<(), NavError> {
    require_positive("imu_dt_s", imu_dt_s)?;
    if !(imu_dt_s >= T::lit(IMU_DT_RANGE_S.low) && imu_dt_s <= T::lit(IMU_DT_RANGE_S.high)) {
        return Err(NavError::InvalidConfig {
            field: "imu_dt_s",
            issue: ConfigIssue::OutOfRange,
        });
    }
    Ok(())
}

/// An aid period in IMU intervals, `m = ⌈T / dt⌉` (≥ 1); `InvalidConfig { field }` when the
/// period is not positive, not finite or more than [`MAX_AID_PERIOD_IMU_INTERVALS`] intervals.
pub(crate) fn check_period(field: &'static str, period_s: f64, dt_s: f64) -> Result<u32, NavError> {
    require_positive(field, period_s)?;
    let m = libm::ceil(period_s / dt_s - 1.0e-9);
    if m.is_nan() || m > MAX_AID_PERIOD_IMU_INTERVALS {
        return Err(NavError::InvalidConfig {
            field,
            issue: ConfigIssue::OutOfRange,
        });
    }
    // 1 ≤ m ≤ 10⁵: exact.
    Ok(if m < 1.0 { 1 } else { m as u32 })
}

/// The loop's continuous model at design time (f64), for the envelope checks.
pub(crate) struct LoopModel {
    pub(crate) a0: Matrix3<f64>,
    pub(crate) k: Matrix3x2<f64>,
    pub(crate) c: Matrix2x3<f64>,
    pub(crate) lag: f64,
    pub(crate) bias_sign: f64,
    /// Gravity gradient c = 2ω_s², 1/s².
    pub(crate) c_grav: f64,
    pub(crate) dt: f64,
}

impl LoopModel {
    /// The variable-interval step ([`off_nominal_increment`]) must match the exact
    /// discretisation at 0.25, 0.5, 0.75, 1.25 and 1.5 dt to [`INTERVAL_ACCURACY`] (relative,
    /// per input, every aid mode); otherwise the loop is too fast for its IMU interval
    /// (`InvalidConfig { field: "imu_dt_s" }`).
    pub(crate) fn check_intervals(&self) -> Result<(), NavError> {
        let nominal = discretise_modes::<f64>(&self.a0, &self.k, &self.c, self.dt)?;
        let fb = Feedback {
            k: self.k,
            lag_s: self.lag,
            bias_sign: self.bias_sign,
        };
        for frac in [0.25, 0.5, 0.75, 1.25, 1.5] {
            let h = frac * self.dt;
            let exact = discretise_modes::<f64>(&self.a0, &self.k, &self.c, h)?;
            for (ub, uv) in [(false, false), (true, false), (false, true), (true, true)] {
                let mask = AidMask {
                    baro: f64::from(u8::from(ub)),
                    velocity: f64::from(u8::from(uv)),
                };
                let (mn, me) = (nominal.select(ub, uv), exact.select(ub, uv));
                for input in 0..4 {
                    let mut u = [0.0; 4];
                    if let Some(x) = u.get_mut(input) {
                        *x = 1.0;
                    }
                    let [v, rate, nh, nv] = u;
                    let nu = Vector2::new(nh * mask.baro, nv * mask.velocity);
                    let drive = Vector2::new(v, rate);
                    let y_exact = me.n * drive + me.g * nu;
                    let y = off_nominal_increment(&fb, mn, mask, h, self.dt, &drive, &nu);
                    let scale = y_exact.amax();
                    let err = (y - y_exact).amax();
                    if err.is_nan() || err > INTERVAL_ACCURACY * scale {
                        return Err(NavError::InvalidConfig {
                            field: "imu_dt_s",
                            issue: ConfigIssue::OutOfRange,
                        });
                    }
                }
            }
        }
        Ok(())
    }

    /// Stability of the multirate loop with perfect sensors: each aid sample (every `m` IMU
    /// intervals) is held and extrapolated to the middle of every later interval, so the error
    /// `e = [δh, δV_z, δb]` evolves as `e ← (I + N D₀ + G D_k) e` with the extrapolation age
    /// `a_k = (k − ½) dt` since the sample:
    ///
    /// ```text
    /// D₀ = [[0, 1, 0], [c, 0, ±1]]          (the rates V̂_z, A_z ± b̂ with gravity's c δh)
    /// baro row of D_k:     [−1 − ½ a² c,  τ_b + a,  ∓½ a²]
    /// velocity row of D_k: [a c,  −1,  ±a]
    /// ```
    ///
    /// The loop is stable when the monodromy Ψ over one common period (the least common
    /// multiple of the aid periods, or the longer period for both aids when that exceeds 10⁵
    /// intervals) has all eigenvalues inside the unit circle (Jury test, evaluated on
    /// `Ψ − I` accumulated separately so that slow loops, Ψ ≈ I, are judged correctly).
    pub(crate) fn multirate_stable(
        &self,
        baro: Option<u32>,
        vel: Option<u32>,
    ) -> Result<bool, NavError> {
        Ok(match self.monodromy_minus_identity(baro, vel)? {
            Some(delta) => jury_stable(&delta),
            None => false,
        })
    }

    /// `Ψ − I` over one common aid period (`None` when it overflows: unstable).
    pub(crate) fn monodromy_minus_identity(
        &self,
        baro: Option<u32>,
        vel: Option<u32>,
    ) -> Result<Option<Matrix3<f64>>, NavError> {
        let (ub, uv) = (baro.is_some(), vel.is_some());
        let modes = discretise_modes::<f64>(&self.a0, &self.k, &self.c, self.dt)?;
        let mode = modes.select(ub, uv);
        let (mb, mv) = (baro.unwrap_or(1), vel.unwrap_or(1));
        let mut horizon = u64::from(mb)
            .saturating_mul(u64::from(mv))
            .checked_div(u64::from(gcd(mb, mv)))
            .unwrap_or(u64::MAX);
        let (mut mb, mut mv) = (mb, mv);
        if horizon > 100_000 {
            let m = mb.max(mv);
            (mb, mv, horizon) = (m, m, u64::from(m));
        }
        let s = self.bias_sign;
        let cg = self.c_grav;
        let d0 = Matrix2x3::new(0.0, 1.0, 0.0, cg, 0.0, s);
        let base = mode.n * d0;
        let mut delta = Matrix3::<f64>::zeros();
        for k in 0..horizon {
            let age = |m: u32| (k.checked_rem(u64::from(m)).unwrap_or(0) as f64 - 0.5) * self.dt;
            let (ab, av) = (age(mb), age(mv));
            let mut d = Matrix2x3::zeros();
            if ub {
                d.set_row(
                    0,
                    &RowVector3::new(-1.0 - 0.5 * ab * ab * cg, self.lag + ab, -0.5 * ab * ab * s),
                );
            }
            if uv {
                d.set_row(1, &RowVector3::new(av * cg, -1.0, av * s));
            }
            let e = base + mode.g * d;
            delta += e + e * delta;
            if !delta.iter().all(|v| v.is_finite()) {
                return Ok(None);
            }
        }
        Ok(Some(delta))
    }
}

/// Jury test of `Ψ = I + Δ`: all eigenvalues strictly inside the unit circle.
pub(crate) fn jury_stable(delta: &Matrix3<f64>) -> bool {
    // Ψ = I + Δ; p(z) = det(zI − Ψ) = q(z − 1) with q(μ) = μ³ + b₂μ² + b₁μ + b₀ of Δ.
    let [b2, b1, b0] = char_poly3(delta);
    let u = b2 - b1 + b0; // a₀ + 1
    let p_minus1 = 8.0 - 4.0 * b2 + 2.0 * b1 - b0; // −p(−1)
    b0 > 0.0 && p_minus1 > 0.0 && u > 0.0 && u < 2.0 && u * (2.0 - u) > (u * (b2 - 2.0) - b0).abs()
}

fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a.max(1)
}

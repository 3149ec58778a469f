//! The configuration-time designs of the vertical-channel loops (see [`crate::design`]):
//! gains (pole placement or continuous ARE, `f64`), the exact discretisation of the four aid
//! modes, the gravity fit at the latitude and (aided loop) the design innovation variances.
//!
//! [`ClassicalDesign::compute`] / [`AidedDesign::compute`] run the design code (f64, `sin`,
//! Riccati, matrix exponentials); [`super::ClassicalLoop::from_design`] /
//! [`super::AidedLoop::from_design`] only check and copy the stored result, so a flight build
//! that uses them links none of the design code and runs no f64 arithmetic.
use super::aided::{AidedConfig, AidedGains};
use super::classical::{ClassicalConfig, ClassicalGains};
use super::riccati::char_poly3;
use super::{
    check_imu_dt, discretise_modes, off_nominal_increment, open_loop, GravityModel, Mode, Modes,
    INTERVAL_ACCURACY, MAX_AID_PERIOD_IMU_INTERVALS,
};
use crate::design::{DesignValues, ValueReader, ValueWriter, BAD_VALUES};
use crate::error::ConfigIssue;
use crate::math::checks::all_finite_parts;
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2, Vector2};

/// Values of the loop's time step and baro lag in the loop's float type, fixed by the design.
#[derive(Debug, Clone, Copy, PartialEq)]
struct StepValues<T> {
    /// IMU interval, s.
    dt_s: T,
    /// Half the IMU interval, s (rounded from the `f64` half interval).
    half_dt_s: T,
    /// Baro lag compensation, s.
    baro_lag_s: T,
}

impl<T: Real> StepValues<T> {
    fn new(imu_dt_s: f64, baro_lag_s: f64) -> Self {
        Self {
            dt_s: T::lit(imu_dt_s),
            half_dt_s: T::lit(0.5 * imu_dt_s),
            baro_lag_s: T::lit(baro_lag_s),
        }
    }

    /// The design's step values must be those of the configuration (casts and compares
    /// only), positive (lag non-negative).
    fn check(&self, imu_dt_s: f64, baro_lag_s: f64) -> Result<(), NavError> {
        if !(self.dt_s == T::lit(imu_dt_s) && self.dt_s > T::zero() && self.half_dt_s > T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.imu_dt_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        if !(self.baro_lag_s == T::lit(baro_lag_s) && self.baro_lag_s >= T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.baro_lag_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        Ok(())
    }

    fn write(&self, w: &mut ValueWriter<'_>) {
        w.real(self.dt_s);
        w.real(self.half_dt_s);
        w.real(self.baro_lag_s);
    }
}

fn write_gravity<T: Real>(w: &mut ValueWriter<'_>, g: &GravityModel<T>) {
    w.real(g.g0_m_s2);
    w.real(g.g1_per_s2);
    w.real(g.g2_per_m_s2);
}

/// The gravity model, the step values and the `N` values they were read from.
type GravityStep<T, const N: usize> = (GravityModel<T>, StepValues<T>, [T; N]);

/// Reads `N ≥ 6` values of the float type through one looping reader ([`ValueReader::fill`]):
/// the gravity model and the step values (the first six), and all `N` values.
fn read_gravity_step<T: Real, const N: usize>(
    r: &mut ValueReader<'_>,
) -> Result<GravityStep<T, N>, NavError> {
    let mut v = [T::zero(); N];
    r.fill(&mut v)?;
    let [g0_m_s2, g1_per_s2, g2_per_m_s2, dt_s, half_dt_s, baro_lag_s, ..] = *v.as_slice() else {
        return Err(BAD_VALUES);
    };
    Ok((
        GravityModel {
            g0_m_s2,
            g1_per_s2,
            g2_per_m_s2,
        },
        StepValues {
            dt_s,
            half_dt_s,
            baro_lag_s,
        },
        v,
    ))
}

/// Number of values of [`Modes`]: Φ_baro (9), then N and G (6 each) of the modes none, baro,
/// velocity, both.
const MODES_COUNT: usize = 9 + 4 * 12;

fn write_modes<T: Real>(w: &mut ValueWriter<'_>, m: &Modes<T>) {
    w.matrix(&m.phi_baro);
    for mode in [&m.none, &m.baro, &m.velocity, &m.both] {
        w.matrix(&mode.n);
        w.matrix(&mode.g);
    }
}

#[inline(never)]
fn read_modes<T: Real>(r: &mut ValueReader<'_>) -> Result<Modes<T>, NavError> {
    let z = Matrix3x2::<T>::zeros();
    let zm = Mode { n: z, g: z };
    let mut m = Modes {
        phi_baro: Matrix3::zeros(),
        none: zm,
        baro: zm,
        velocity: zm,
        both: zm,
    };
    // Same order as `write_modes` (one looping reader for all nine matrices).
    r.fill_parts(&mut [
        m.phi_baro.as_mut_slice(),
        m.none.n.as_mut_slice(),
        m.none.g.as_mut_slice(),
        m.baro.n.as_mut_slice(),
        m.baro.g.as_mut_slice(),
        m.velocity.n.as_mut_slice(),
        m.velocity.g.as_mut_slice(),
        m.both.n.as_mut_slice(),
        m.both.g.as_mut_slice(),
    ])?;
    Ok(m)
}

fn modes_finite<T: Real>(m: &Modes<T>) -> bool {
    all_finite_parts(&[
        m.phi_baro.as_slice(),
        m.none.n.as_slice(),
        m.none.g.as_slice(),
        m.baro.n.as_slice(),
        m.baro.g.as_slice(),
        m.velocity.n.as_slice(),
        m.velocity.g.as_slice(),
        m.both.n.as_slice(),
        m.both.g.as_slice(),
    ])
}

fn gravity_finite<T: Real>(g: &GravityModel<T>) -> bool {
    g.g0_m_s2.is_finite() && g.g1_per_s2.is_finite() && g.g2_per_m_s2.is_finite()
}

#[cold]
#[inline(never)]
fn not_finite() -> NavError {
    NavError::InvalidConfig {
        field: "design",
        issue: ConfigIssue::NotFinite,
    }
}

/// An aid period in IMU intervals, `m = ⌈T / dt⌉` (≥ 1); `InvalidConfig { field }` when the
/// period is not positive, not finite or more than [`MAX_AID_PERIOD_IMU_INTERVALS`] intervals.
fn check_period(field: &'static str, period_s: f64, dt_s: f64) -> Result<u32, NavError> {
    crate::error::require_positive(field, period_s)?;
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
    fn check_intervals(&self) -> Result<(), NavError> {
        let nominal = discretise_modes::<f64>(&self.a0, &self.k, &self.c, self.dt)?;
        for frac in [0.25, 0.5, 0.75, 1.25, 1.5] {
            let h = frac * self.dt;
            let exact = discretise_modes::<f64>(&self.a0, &self.k, &self.c, h)?;
            for (ub, uv) in [(false, false), (true, false), (false, true), (true, true)] {
                let mask = (f64::from(u8::from(ub)), f64::from(u8::from(uv)));
                let (mn, me) = (nominal.select(ub, uv), exact.select(ub, uv));
                for input in 0..4 {
                    let mut u = [0.0; 4];
                    if let Some(x) = u.get_mut(input) {
                        *x = 1.0;
                    }
                    let [v, rate, nh, nv] = u;
                    let nu = Vector2::new(nh * mask.0, nv * mask.1);
                    let y_exact = me.n * Vector2::new(v, rate) + me.g * nu;
                    let y = off_nominal_increment(
                        &self.k,
                        self.lag,
                        self.bias_sign,
                        mn,
                        mask,
                        (h, self.dt),
                        (v, rate),
                        &nu,
                    );
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
        let d0 = nalgebra::Matrix2x3::new(0.0, 1.0, 0.0, cg, 0.0, s);
        let base = mode.n * d0;
        let mut delta = Matrix3::<f64>::zeros();
        for k in 0..horizon {
            let age = |m: u32| (k.checked_rem(u64::from(m)).unwrap_or(0) as f64 - 0.5) * self.dt;
            let (ab, av) = (age(mb), age(mv));
            let mut d = nalgebra::Matrix2x3::zeros();
            if ub {
                d.set_row(
                    0,
                    &nalgebra::RowVector3::new(
                        -1.0 - 0.5 * ab * ab * cg,
                        self.lag + ab,
                        -0.5 * ab * ab * s,
                    ),
                );
            }
            if uv {
                d.set_row(1, &nalgebra::RowVector3::new(av * cg, -1.0, av * s));
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
    {
        // Ψ = I + Δ; p(z) = det(zI − Ψ) = q(z − 1) with q(μ) = μ³ + b₂μ² + b₁μ + b₀ of Δ.
        let [b2, b1, b0] = char_poly3(delta);
        let u = b2 - b1 + b0; // a₀ + 1
        let p_minus1 = 8.0 - 4.0 * b2 + 2.0 * b1 - b0; // −p(−1)
        b0 > 0.0
            && p_minus1 > 0.0
            && u > 0.0
            && u < 2.0
            && u * (2.0 - u) > (u * (b2 - 2.0) - b0).abs()
    }
}

fn gcd(mut a: u32, mut b: u32) -> u32 {
    while b != 0 {
        (a, b) = (b, a % b);
    }
    a.max(1)
}

/// Precomputed design of a [`super::ClassicalLoop`]: pole-placement gains, the discretised
/// aid modes, the gravity model and the step values, in the loop's float type `T` (the gains
/// as `f64` data, for reporting only).
///
/// Obtained from [`ClassicalDesign::compute`] or [`DesignValues::read_values`] only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ClassicalDesign<T: Real> {
    gains: ClassicalGains,
    modes: Modes<T>,
    gravity: GravityModel<T>,
    step: StepValues<T>,
}

impl<T: Real> ClassicalDesign<T> {
    /// Validates the configuration (IMU interval, timeouts, latitude, τ, C4; same errors and
    /// order as [`super::ClassicalLoop::new`]), fits the gravity model at the latitude, places
    /// the poles (seed eq. 1) and discretises the four aid modes exactly at `imu_dt_s`.
    pub fn compute(config: &ClassicalConfig) -> Result<Self, NavError> {
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        let gravity = GravityModel::at_latitude(config.latitude_rad)?;
        let gains =
            ClassicalGains::pole_placement(config.tau_s, config.baro_lag_s, gravity.c_per_s2())?;
        let period = check_period("baro_period_s", config.baro_period_s, config.imu_dt_s)?;
        let (k, c) = gains.observer();
        let loop_ = LoopModel {
            a0: open_loop(-1.0),
            k,
            c,
            lag: config.baro_lag_s,
            bias_sign: -1.0,
            c_grav: gravity.c_per_s2(),
            dt: config.imu_dt_s,
        };
        if !loop_.multirate_stable(Some(period), None)? {
            return Err(NavError::InvalidConfig {
                field: "tau_s",
                issue: ConfigIssue::OutOfRange,
            });
        }
        loop_.check_intervals()?;
        let modes = discretise_modes::<T>(&open_loop(-1.0), &k, &c, config.imu_dt_s)?;
        Ok(Self {
            gains,
            modes,
            gravity: gravity.cast(),
            step: StepValues::new(config.imu_dt_s, config.baro_lag_s),
        })
    }

    /// The pole-placement gains.
    pub fn gains(&self) -> &ClassicalGains {
        &self.gains
    }
    /// The gravity model in the loop's float type.
    pub fn gravity(&self) -> &GravityModel<T> {
        &self.gravity
    }
    /// The IMU interval the modes were discretised at, s.
    pub fn imu_dt_s(&self) -> T {
        self.step.dt_s
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.modes.phi_baro
    }

    /// Checks the design against the configuration and its own finiteness (used by
    /// `from_design`; casts and compares only).
    pub(super) fn check(&self, config: &ClassicalConfig) -> Result<(), NavError> {
        self.step.check(config.imu_dt_s, config.baro_lag_s)?;
        if !(modes_finite(&self.modes) && gravity_finite(&self.gravity)) {
            return Err(not_finite());
        }
        Ok(())
    }

    pub(super) fn parts(&self) -> (&ClassicalGains, &Modes<T>, &GravityModel<T>) {
        (&self.gains, &self.modes, &self.gravity)
    }

    pub(super) fn step_values(&self) -> (T, T, T) {
        (self.step.dt_s, self.step.half_dt_s, self.step.baro_lag_s)
    }
}

/// Value order (68 values): the gains `c1_per_s, c2_per_s2, c3_per_s3, c4_s, c_per_s2` (5);
/// gravity `g0_m_s2, g1_per_s2, g2_per_m_s2` (3); `imu_dt_s`, half of it, `baro_lag_s` (3);
/// the modes (57): Φ_baro (3×3), then N and G (3×2 each) of the modes none, baro, velocity,
/// both; matrices column by column.
impl<T: Real> DesignValues for ClassicalDesign<T> {
    const COUNT: usize = 5 + 3 + 3 + MODES_COUNT;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        let g = &self.gains;
        for v in [g.c1_per_s, g.c2_per_s2, g.c3_per_s3, g.c4_s, g.c_per_s2] {
            w.push(v);
        }
        write_gravity(&mut w, &self.gravity);
        self.step.write(&mut w);
        write_modes(&mut w, &self.modes);
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let mut g = [0.0; 5];
        r.fill_f64(&mut g)?;
        let [c1_per_s, c2_per_s2, c3_per_s3, c4_s, c_per_s2] = g;
        let gains = ClassicalGains {
            c1_per_s,
            c2_per_s2,
            c3_per_s3,
            c4_s,
            c_per_s2,
        };
        let (gravity, step, _) = read_gravity_step::<T, 6>(&mut r)?;
        let modes = read_modes(&mut r)?;
        r.finish()?;
        Ok(Self {
            gains,
            modes,
            gravity,
            step,
        })
    }
}

/// Precomputed design of an [`super::AidedLoop`]: the Riccati gains (`f64` data, for
/// reporting), the discretised aid modes, the gravity model, the step values and the design
/// innovation variances, in the loop's float type `T`.
///
/// Obtained from [`AidedDesign::compute`] or [`DesignValues::read_values`] only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AidedDesign<T: Real> {
    gains: AidedGains,
    modes: Modes<T>,
    gravity: GravityModel<T>,
    step: StepValues<T>,
    baro_innovation_variance: T,
    velocity_innovation_variance: T,
}

impl<T: Real> AidedDesign<T> {
    /// Validates the configuration (same errors and order as [`super::AidedLoop::new`]),
    /// solves the continuous ARE for the gains (seed eqs. 8-9), fits the gravity model,
    /// discretises the four aid modes exactly at `imu_dt_s` and computes the design innovation
    /// variances `C P Cᵀ + σ²` of both aids.
    pub fn compute(config: &AidedConfig) -> Result<Self, NavError> {
        check_imu_dt(config.imu_dt_s)?;
        config
            .baro_timeouts
            .validate("baro_timeouts.stale_after_s", "baro_timeouts.lost_after_s")?;
        config.velocity_timeouts.validate(
            "velocity_timeouts.stale_after_s",
            "velocity_timeouts.lost_after_s",
        )?;
        let gains = AidedGains::design(config)?;
        let gravity = GravityModel::at_latitude(config.latitude_rad)?;
        let tb = check_period("baro_period_s", config.baro_period_s, config.imu_dt_s)?;
        let tv = check_period(
            "velocity_period_s",
            config.velocity_period_s,
            config.imu_dt_s,
        )?;
        let loop_ = LoopModel {
            a0: open_loop(1.0),
            k: gains.k,
            c: gains.c,
            lag: config.baro_lag_s,
            bias_sign: 1.0,
            c_grav: gravity.c_per_s2(),
            dt: config.imu_dt_s,
        };
        // The design mode (both aids). A single-aid mode is what the joint design leaves when
        // the other aid drops out: the velocity aid alone cannot hold the altitude (its error
        // diverges slowly through gravity's c δh in any design), and the baro column of a
        // design that leans on the velocity aid can be slowly unstable alone too; the health
        // says `Degraded` while an aid is lost.
        if !loop_.multirate_stable(Some(tb), Some(tv))? {
            return Err(NavError::InvalidConfig {
                field: if tb >= tv {
                    "baro_period_s"
                } else {
                    "velocity_period_s"
                },
                issue: ConfigIssue::OutOfRange,
            });
        }
        loop_.check_intervals()?;
        let modes = discretise_modes::<T>(&open_loop(1.0), &gains.k, &gains.c, config.imu_dt_s)?;
        let cb = gains.c.row(0).transpose();
        let bv = (cb.transpose() * gains.p * cb).x + config.baro_noise_m * config.baro_noise_m;
        let vv = gains.p.m22 + config.velocity_noise_m_s * config.velocity_noise_m_s;
        Ok(Self {
            gains,
            modes,
            gravity: gravity.cast(),
            step: StepValues::new(config.imu_dt_s, config.baro_lag_s),
            baro_innovation_variance: T::lit(bv),
            velocity_innovation_variance: T::lit(vv),
        })
    }

    /// The Riccati design.
    pub fn gains(&self) -> &AidedGains {
        &self.gains
    }
    /// The gravity model in the loop's float type.
    pub fn gravity(&self) -> &GravityModel<T> {
        &self.gravity
    }
    /// The IMU interval the modes were discretised at, s.
    pub fn imu_dt_s(&self) -> T {
        self.step.dt_s
    }
    /// Design innovation variances of (baro m², velocity (m/s)²): `C P Cᵀ + σ²`.
    pub fn innovation_variances(&self) -> (T, T) {
        (
            self.baro_innovation_variance,
            self.velocity_innovation_variance,
        )
    }
    /// Discrete transition matrix with the baro in use (for analysis).
    pub fn phi_with_baro(&self) -> Matrix3<T> {
        self.modes.phi_baro
    }

    /// Checks the design against the configuration and its own values (used by
    /// `from_design`; casts and compares only).
    pub(super) fn check(&self, config: &AidedConfig) -> Result<(), NavError> {
        self.step.check(config.imu_dt_s, config.baro_lag_s)?;
        let (bv, vv) = self.innovation_variances();
        if !(modes_finite(&self.modes)
            && gravity_finite(&self.gravity)
            && bv.is_finite()
            && vv.is_finite())
        {
            return Err(not_finite());
        }
        if !(bv > T::zero() && vv > T::zero()) {
            return Err(NavError::InvalidConfig {
                field: "design.innovation_variances",
                issue: ConfigIssue::NotPositive,
            });
        }
        Ok(())
    }

    pub(super) fn parts(&self) -> (&AidedGains, &Modes<T>, &GravityModel<T>) {
        (&self.gains, &self.modes, &self.gravity)
    }

    pub(super) fn step_values(&self) -> (T, T, T) {
        (self.step.dt_s, self.step.half_dt_s, self.step.baro_lag_s)
    }
}

/// Value order (108 values): the gains (43): `k` (3×2), `p` (3×3), `a` (3×3), `q` (3×3),
/// `c` (2×3), `r` (2), `riccati_iterations` (an integer), `relative_residual`; gravity
/// `g0_m_s2, g1_per_s2, g2_per_m_s2` (3); `imu_dt_s`, half of it, `baro_lag_s` (3); the
/// design innovation variances baro, velocity (2); the modes (57): Φ_baro (3×3), then N and G
/// (3×2 each) of the modes none, baro, velocity, both; matrices column by column.
impl<T: Real> DesignValues for AidedDesign<T> {
    const COUNT: usize = 43 + 3 + 3 + 2 + MODES_COUNT;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        let g = &self.gains;
        w.matrix_f64(&g.k);
        w.matrix_f64(&g.p);
        w.matrix_f64(&g.a);
        w.matrix_f64(&g.q);
        w.matrix_f64(&g.c);
        w.matrix_f64(&g.r);
        w.push(f64::from(g.riccati_iterations));
        w.push(g.relative_residual);
        write_gravity(&mut w, &self.gravity);
        self.step.write(&mut w);
        w.real(self.baro_innovation_variance);
        w.real(self.velocity_innovation_variance);
        write_modes(&mut w, &self.modes);
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let mut gains = AidedGains {
            k: Matrix3x2::zeros(),
            p: Matrix3::zeros(),
            a: Matrix3::zeros(),
            q: Matrix3::zeros(),
            c: Matrix2x3::zeros(),
            r: Vector2::zeros(),
            riccati_iterations: 0,
            relative_residual: 0.0,
        };
        r.fill_parts_f64(&mut [
            gains.k.as_mut_slice(),
            gains.p.as_mut_slice(),
            gains.a.as_mut_slice(),
            gains.q.as_mut_slice(),
            gains.c.as_mut_slice(),
            gains.r.as_mut_slice(),
        ])?;
        let it = r.value()?;
        // An iteration count: a non-negative integer that fits a u32 (exact round trip).
        let iterations = it as u32;
        if f64::from(iterations) != it {
            return Err(BAD_VALUES);
        }
        gains.riccati_iterations = iterations;
        gains.relative_residual = r.value()?;
        let (gravity, step, v) = read_gravity_step::<T, 8>(&mut r)?;
        let [.., baro_innovation_variance, velocity_innovation_variance] = v;
        let modes = read_modes(&mut r)?;
        r.finish()?;
        Ok(Self {
            gains,
            modes,
            gravity,
            step,
            baro_innovation_variance,
            velocity_innovation_variance,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vertical_channel::{AidTimeouts, AidedLoop, ClassicalLoop, InitialState};

    fn timeouts() -> AidTimeouts {
        AidTimeouts {
            stale_after_s: 0.1,
            lost_after_s: 1.0,
        }
    }

    fn classical() -> ClassicalConfig {
        ClassicalConfig {
            imu_dt_s: 0.01,
            latitude_rad: 0.6,
            tau_s: 10.0,
            baro_lag_s: 0.0,
            baro_period_s: 0.04,
            baro_timeouts: timeouts(),
        }
    }

    fn aided() -> AidedConfig {
        AidedConfig {
            imu_dt_s: 0.01,
            latitude_rad: 0.6,
            accel_noise_m_s2_rt_hz: 1e-3,
            accel_bias_rw_m_s2_rt_s: 1e-5,
            baro_noise_m: 1.0,
            baro_period_s: 0.04,
            baro_lag_s: 0.1,
            velocity_noise_m_s: 0.1,
            velocity_period_s: 0.1,
            baro_timeouts: timeouts(),
            velocity_timeouts: timeouts(),
        }
    }

    fn init<T: Real>() -> InitialState<T> {
        InitialState {
            time: crate::time::Timestamp::ZERO,
            altitude_m: T::lit(100.0),
            vz_up_m_s: T::zero(),
            accel_bias_m_s2: T::zero(),
        }
    }

    fn nan_refused<T: Real>() {
        let nf = Err(not_finite());
        let cc = classical();
        let good = ClassicalDesign::<T>::compute(&cc).unwrap();
        assert!(ClassicalLoop::from_design(&cc, &good, &init::<T>()).is_ok());
        let mut d = good;
        d.modes.both.g.m21 = T::lit(f64::NAN);
        assert_eq!(
            ClassicalLoop::from_design(&cc, &d, &init::<T>()).map(|_| ()),
            nf
        );
        let mut d = good;
        d.gravity.g1_per_s2 = T::lit(f64::INFINITY);
        assert_eq!(
            ClassicalLoop::from_design(&cc, &d, &init::<T>()).map(|_| ()),
            nf
        );
        let mut d = good;
        d.step.half_dt_s = T::zero();
        assert!(ClassicalLoop::from_design(&cc, &d, &init::<T>()).is_err());

        let ac = aided();
        let good = AidedDesign::<T>::compute(&ac).unwrap();
        assert!(AidedLoop::from_design(&ac, &good, &init::<T>()).is_ok());
        for corrupt in 0..3 {
            let mut d = good;
            match corrupt {
                0 => d.modes.none.n.m12 = T::lit(f64::NAN),
                1 => d.modes.phi_baro.m33 = T::lit(f64::NAN),
                _ => d.velocity_innovation_variance = T::lit(f64::NAN),
            }
            assert_eq!(
                AidedLoop::from_design(&ac, &d, &init::<T>()).map(|_| ()),
                nf,
                "{corrupt}"
            );
        }
    }

    #[test]
    fn from_design_refuses_non_finite_designs_f32_f64() {
        nan_refused::<f32>();
        nan_refused::<f64>();
    }
}

//! Master/slave samples, lever-arm compensation, the measurement z = [dω; df] and the
//! measurement matrices H of both filters (spec "Measurements", seed eqs. 4, 5, 12-14).
//!
//! ```text
//! dω = ω_m − ω_s          = θ × ω_m − θ̇_f + v                    (seed eq. 4)
//! df = f̃_m − f_s          = θ × f_m + v                            (conventional, seed eq. 5)
//!                          ≈ −[f_s×] θ + L_0 × θ̈_f + v             (proposed, seed eqs. 12-14)
//! f̃_m = f_m + ω̇_m × L_0 + ω_m × (ω_m × L_0)                       (lever-arm compensation)
//! ```
//!
//! with θ = θ_m + θ_f and `C_m^s ≈ I − [θ×]`. The rigid lever-arm terms are removed from the
//! master specific force before matching; the flexure terms cannot be (the proposed filter models
//! the largest one, `L_0 × θ̈_f`; the flight configuration also the terms a manoeuvre excites,
//! `([ω̇×] + [ω×]²)[L_0×] θ_f + 2[ω×][L_0×] θ̇_f`, [`h_row_flight`]).
use super::config::{
    MAX_ANGULAR_ACCEL_RAD_S2, MAX_ANGULAR_RATE_RAD_S, MAX_MISALIGNMENT_RAD, MAX_SPECIFIC_FORCE_M_S2,
};
use super::model::{has_accel_bias, FlexureModel, BIAS_STATE};
use crate::math::kalman::SparseRow;
use crate::time::Timestamp;
use crate::{NavError, Real};
use nalgebra::{SMatrix, SVector, Vector3};

/// One master INS sample (navigation grade), time-stamped.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct MasterSample<T> {
    /// Time stamp (the flight computer's clock, integer µs).
    pub time: Timestamp,
    /// Master angular rate ω_m (inertial, master axes), rad/s.
    pub angular_rate_rad_s: Vector3<T>,
    /// Master angular acceleration ω̇_m (master axes), rad/s², for the lever-arm compensation.
    pub angular_accel_rad_s2: Vector3<T>,
    /// Master specific force f_m (master axes), m/s².
    pub specific_force_m_s2: Vector3<T>,
}

/// One slave IMU sample (tactical grade), time-stamped.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct SlaveSample<T> {
    /// Time stamp (the flight computer's clock, integer µs).
    pub time: Timestamp,
    /// Slave gyro output ω_s (slave axes), rad/s.
    pub angular_rate_rad_s: Vector3<T>,
    /// Slave accelerometer output f_s (slave axes), m/s².
    pub specific_force_m_s2: Vector3<T>,
}

impl<T: Real> MasterSample<T> {
    /// `NonFiniteInput` unless every field is finite.
    pub fn validate(&self) -> Result<(), NavError> {
        finite3("master.angular_rate_rad_s", &self.angular_rate_rad_s)?;
        finite3("master.angular_accel_rad_s2", &self.angular_accel_rad_s2)?;
        finite3("master.specific_force_m_s2", &self.specific_force_m_s2)
    }
}

impl<T: Real> SlaveSample<T> {
    /// `NonFiniteInput` unless every field is finite.
    pub fn validate(&self) -> Result<(), NavError> {
        finite3("slave.angular_rate_rad_s", &self.angular_rate_rad_s)?;
        finite3("slave.specific_force_m_s2", &self.specific_force_m_s2)
    }
}

fn finite3<T: Real>(input: &'static str, v: &Vector3<T>) -> Result<(), NavError> {
    if v.as_slice().iter().all(|c| crate::math::checks::finite(*c)) {
        Ok(())
    } else {
        Err(NavError::NonFiniteInput { input })
    }
}

/// Master specific force moved to the nominal slave station L_0:
/// `f̃_m = f_m + ω̇_m × L_0 + ω_m × (ω_m × L_0)`, m/s².
#[inline]
pub fn compensate_lever_arm<T: Real>(
    master: &MasterSample<T>,
    lever_arm_m: &Vector3<T>,
) -> Vector3<T> {
    let w = &master.angular_rate_rad_s;
    master.specific_force_m_s2
        + master.angular_accel_rad_s2.cross(lever_arm_m)
        + w.cross(&w.cross(lever_arm_m))
}

/// The matched measurement of one epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Matching<T: Real> {
    /// `z = [ω_m − ω_s; f̃_m − f_s]` (rad/s, m/s²), in the order dω_X..Z, df_X..Z.
    pub z: SVector<T, 6>,
    /// The lever-arm compensated master specific force f̃_m, m/s².
    pub master_force_compensated_m_s2: Vector3<T>,
}

/// The measurement of one epoch ([`Matching`]).
#[inline]
pub fn measurement<T: Real>(
    master: &MasterSample<T>,
    slave: &SlaveSample<T>,
    lever_arm_m: &Vector3<T>,
) -> Matching<T> {
    let f_comp = compensate_lever_arm(master, lever_arm_m);
    let dw = master.angular_rate_rad_s - slave.angular_rate_rad_s;
    let df = f_comp - slave.specific_force_m_s2;
    Matching {
        z: SVector::<T, 6>::new(dw.x, dw.y, dw.z, df.x, df.y, df.z),
        master_force_compensated_m_s2: f_comp,
    }
}

/// Row `i` of the skew matrix `[v×]`.
#[inline(always)]
fn skew_row<T: Real>(v: &Vector3<T>, i: usize) -> [T; 3] {
    let z = T::zero();
    match i {
        0 => [z, -v.z, v.y],
        1 => [v.z, z, -v.x],
        _ => [-v.y, v.x, z],
    }
}

#[inline(always)]
fn set<T: Real, const N: usize>(h: &mut SVector<T, N>, i: usize, v: T) {
    if let Some(e) = h.get_mut(i) {
        *e = v;
    }
}

/// Row `row` (0-2: dω_X..Z, 3-5: df_X..Z) of H, placed with the index map `index(d, a)`
/// (derivative d, axis a):
///
/// ```text
/// conventional (6×9):  | −[ω_m×]  −[ω_m×]  −I |      proposed (6×12): | −[ω_m×]  −[ω_m×]  −I   0     |
///                      | −[f_m×]  −[f_m×]   0 |                       | −[f_s×]  −[f_s×]   0  [L_0×] |
/// ```
///
/// `f_h` is the specific force the model puts in H: the compensated master f̃_m (conventional)
/// or the slave's f_s (proposed).
pub fn h_row<T: Real, const N: usize>(
    model: FlexureModel,
    row: usize,
    omega_m: &Vector3<T>,
    f_h: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
    index: impl Fn(usize, usize) -> usize,
) -> SVector<T, N> {
    let mut h = SVector::<T, N>::zeros();
    let (i, gyro) = if row < 3 {
        (row, true)
    } else {
        (row - 3, false)
    };
    let s = if gyro {
        skew_row(omega_m, i)
    } else {
        skew_row(f_h, i)
    };
    for (a, v) in s.iter().enumerate() {
        set(&mut h, index(0, a), -*v);
        set(&mut h, index(1, a), -*v);
    }
    if gyro {
        set(&mut h, index(2, i), -T::one());
    } else if model == FlexureModel::Proposed {
        for (a, v) in skew_row(lever_arm_m, i).iter().enumerate() {
            set(&mut h, index(3, a), *v);
        }
    }
    h
}

/// Row `row` of H in the filters' own parametrisation: per axis chain `[θ, θ_f, θ̇_f(, θ̈_f)]`
/// with the *total* misalignment θ = θ_m + θ_f in place of θ_m (axis-major, `K` states per
/// chain). Since z depends on θ_m and θ_f only through their sum, the θ_f column of [`h_row`]
/// moves onto θ and the θ_f entries vanish:
///
/// ```text
/// dω row i:  −[ω_m×]_i on θ,  −1 on θ̇_f,i                  (3 entries)
/// df row i:  −[f_h×]_i on θ,  [L_0×]_i on θ̈_f (proposed),
///            1 on the axis' bias b_i (flight configuration)    (2, 4 or 5 entries)
/// ```
///
/// Inlined: with a constant `row` the pattern folds to constants in the caller.
///
/// `M` is the row's capacity: 4 for the paper's filters, 5 for the flight configuration (an
/// entry beyond the capacity would be dropped: the callers pick `M` from `K`, tested).
#[inline(always)]
pub fn h_row_total<T: Real, const K: usize, const M: usize>(
    model: FlexureModel,
    row: usize,
    omega_m: &Vector3<T>,
    f_h: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
) -> SparseRow<T, M> {
    let mut h = SparseRow::<T, M>::new();
    let (i, gyro) = if row < 3 {
        (row, true)
    } else {
        (row - 3, false)
    };
    let s = if gyro {
        skew_row(omega_m, i)
    } else {
        skew_row(f_h, i)
    };
    let lever = skew_row(lever_arm_m, i);
    // At most 2 (axes a ≠ i) × 2 entries and the bias: `push` cannot fail.
    for (a, (&v, &l)) in s.iter().zip(lever.iter()).enumerate() {
        if a != i {
            let _ = h.push(K * a, -v);
        }
        if gyro && a == i {
            let _ = h.push(K * a + 2, -T::one());
        }
        if !gyro && model == FlexureModel::Proposed && a != i {
            let _ = h.push(K * a + 3, l);
        }
        if !gyro && has_accel_bias::<K>() && a == i {
            let _ = h.push(K * a + BIAS_STATE, T::one());
        }
    }
    h
}

/// Row `row` of H of the flight configuration (chains `[θ, θ_f, θ̇_f, θ̈_f, b]`, `K` = 5):
/// [`h_row_total`] plus, on the df rows, the flexure terms of the slave's specific force that
/// a manoeuvre excites. The slave station is at `l = L_0 + θ_f × L_0`, so beside `L_0 × θ̈_f`
/// the slave feels `ω̇ × (θ_f × L_0) + ω × (ω × (θ_f × L_0))` (the lever-arm compensation uses
/// L_0 only) and the Coriolis term `2 ω × (θ̇_f × L_0)`:
///
/// ```text
/// df ∋ ([ω̇×] + [ω×]²) [L_0×] θ_f  +  2 [ω×] [L_0×] θ̇_f
/// ```
///
/// In level flight these vanish; in a 1.5 g roll-in (ω ≈ 0.5 rad/s, ω̇ ≈ 1 rad/s²) with 0.5° of
/// flexure σ and τ 0.5 s at a 4 m lever arm they reach 0.03-0.07 m/s², thirty and more times
/// the accelerometer-matching noise. At most 12 entries per df row (`M` ≥ 12).
/// (Tests and documentation: the filter builds this row with [`h_row_flight_df_with`] from
/// the epoch's [`ManoeuvreTerms`].)
#[cfg(any(test, doc))]
#[inline(always)]
pub fn h_row_flight<T: Real, const K: usize, const M: usize>(
    row: usize,
    omega_m: &Vector3<T>,
    omega_dot_m: &Vector3<T>,
    f_h: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
) -> SparseRow<T, M> {
    if row < 3 {
        return h_row_total::<T, K, M>(FlexureModel::Proposed, row, omega_m, f_h, lever_arm_m);
    }
    // The Jacobian at θ̂ = 0 is the linear row (the second-order terms vanish there; the
    // diagonal θ entry it keeps is an exact zero).
    let df = h_row_flight_df::<T, K>(
        row - 3,
        &Vector3::zeros(),
        omega_m,
        omega_dot_m,
        f_h,
        lever_arm_m,
    );
    let mut h = SparseRow::<T, M>::new();
    for (index, value) in df.entries() {
        let _ = h.push(index, value);
    }
    h
}

/// θ̂ with each axis bounded to the small-angle range ±[`MAX_MISALIGNMENT_RAD`]: the value the
/// flight configuration's second-order terms are built from (they stay bounded, and finite,
/// when the estimate has left the model: the filter then reports `NeedsReinitialisation`).
#[inline(always)]
pub fn bounded_misalignment<T: Real>(theta: &Vector3<T>) -> Vector3<T> {
    let l = T::lit(MAX_MISALIGNMENT_RAD);
    theta.map(|v| clamp_symmetric(v, l))
}

/// `v.max(−l).min(l)` for a limit `l > 0`, bit for bit (NaN → −l, as `max` returns its other
/// operand; ±∞ → ±l; −0 kept), by two compares: `max` and `min` are library calls on the
/// target.
#[inline(always)]
pub(super) fn clamp_symmetric<T: Real>(v: T, l: T) -> T {
    let a = if v >= -l { v } else { -l };
    if a <= l {
        a
    } else {
        l
    }
}

/// Row `i` (0-2: df_X..Z) of the flight configuration's specific-force Jacobian at the
/// predicted misalignment θ̂ (unbounded, as in the state): the derivative of the measurement
/// model the filter predicts with,
///
/// ```text
/// h_i(x) = (−[f_s×] θ + ½ c × (c × f_s) + [L_0×] θ̈_f
///           + ([ω̇×] + [ω×]²) [L_0×] θ_f + 2 [ω×] [L_0×] θ̇_f + b)_i ,   c = bound(θ)
/// ∂h/∂θ  = −[f_s×] + ½ ((c·f_s) I + c f_sᵀ − 2 f_s cᵀ) D,   D = diag(∂c_a/∂θ_a)
/// ```
///
/// (θ × (θ × f) = θ (θ·f) − f |θ|²; `c` is [`bounded_misalignment`], whose derivative `D` is 1
/// on an axis inside the small-angle range and 0 beyond it). The linear row
/// ([`h_row_flight`]) predicts the measurement once the ½ term is subtracted, but as gain its θ
/// columns miss the second term, of relative size |θ̂| (1.5 % with the paper's 0.5° mounting σ
/// per axis, a few times the final σ of θ): the covariance would then credit the df rows with
/// an information about θ they do not carry.
///
/// `D` matters: beyond the bound the predicted ½ term is constant in θ, and a gain built from
/// the ½ term's slope at the bound (as if θ̂ were there) no longer matches the innovation's
/// dependence on the state. With `f_s` of tens of m/s² that mismatch is of the order of the
/// linear row itself, and the update then amplifies the state's error instead of shrinking it:
/// a filter thrown out of its model (the stress campaign's hostile corners: flexure τ 0.05 s at
/// 500-1000 Hz with a truth that has no lever-arm flexure) ran away to non-finite values, in
/// f64 as in f32.
///
/// The flexure terms of a manoeuvre are linear and as in [`h_row_flight`]. Entries in
/// ascending order per axis chain `[θ, θ_f, θ̇_f, θ̈_f, b]` (`K` = 5): per axis θ, θ_f, θ̇_f,
/// then θ̈_f (a ≠ i) or b_i (a = i): 12 entries.
/// (Tests and documentation: the filter builds this row with [`h_row_flight_df_with`] from
/// the epoch's [`ManoeuvreTerms`].)
#[cfg(any(test, doc))]
#[inline(always)]
pub fn h_row_flight_df<T: Real, const K: usize>(
    i: usize,
    theta: &Vector3<T>,
    omega_m: &Vector3<T>,
    omega_dot_m: &Vector3<T>,
    f_s: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
) -> SparseRow<T, 12> {
    let terms = ManoeuvreTerms::new(omega_m, omega_dot_m, lever_arm_m);
    h_row_flight_df_with::<T, K>(i, theta, f_s, lever_arm_m, &terms)
}

/// The flexure terms of a manoeuvre in the flight configuration's df rows (the same for the
/// three rows, and for the linear row and the Jacobian at θ̂: computed once per epoch).
#[derive(Debug, Clone, Copy)]
pub(super) struct ManoeuvreTerms<T: Real> {
    /// `([ω̇×] + [ω×]²) [L_0×]`: m/s² per rad of θ_f.
    a_theta_f: nalgebra::Matrix3<T>,
    /// `2 [ω×] [L_0×]`: m/s² per rad/s of θ̇_f.
    a_rate: nalgebra::Matrix3<T>,
}

impl<T: Real> ManoeuvreTerms<T> {
    /// From the master's angular rate (rad/s) and acceleration (rad/s²) and the lever arm (m).
    #[inline(always)]
    pub(super) fn new(
        omega_m: &Vector3<T>,
        omega_dot_m: &Vector3<T>,
        lever_arm_m: &Vector3<T>,
    ) -> Self {
        let l_x = crate::math::rotation::skew(lever_arm_m);
        let w_x = crate::math::rotation::skew(omega_m);
        Self {
            a_theta_f: (crate::math::rotation::skew(omega_dot_m) + w_x * w_x) * l_x,
            a_rate: w_x * l_x * T::lit(2.0),
        }
    }

    /// No manoeuvre terms (the paper filters, which have no such rows).
    #[inline(always)]
    pub(super) fn zero() -> Self {
        Self {
            a_theta_f: nalgebra::Matrix3::zeros(),
            a_rate: nalgebra::Matrix3::zeros(),
        }
    }
}

/// `hᵀ x` of the flight configuration's linear df row `i` (the Jacobian at θ̂ = 0, what
/// [`h_row_flight_df_with`] builds with θ = 0), without building the row: the same products
/// summed in the same (ascending index) order as [`SparseRow::dot`], so the same bits (its θ
/// entries `0 − v` equal `−v`, or are zeros of either sign, which add to a sum started at +0
/// alike).
#[inline(always)]
pub(super) fn linear_df_dot<T: Real, const K: usize, const N: usize>(
    i: usize,
    f_s: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
    terms: &ManoeuvreTerms<T>,
    x: &SVector<T, N>,
) -> T {
    let s = skew_row(f_s, i);
    let lever = skew_row(lever_arm_m, i);
    let xg = |j: usize| x.get(j).copied().unwrap_or_else(T::zero);
    let mut acc = T::zero();
    for (a, (&v, &l)) in s.iter().zip(lever.iter()).enumerate() {
        acc += -v * xg(K * a);
        acc += terms.a_theta_f.get((i, a)).copied().unwrap_or_else(T::zero) * xg(K * a + 1);
        acc += terms.a_rate.get((i, a)).copied().unwrap_or_else(T::zero) * xg(K * a + 2);
        if a != i {
            acc += l * xg(K * a + 3);
        } else if has_accel_bias::<K>() {
            acc += T::one() * xg(K * a + BIAS_STATE);
        }
    }
    acc
}

/// [`h_row_flight_df`] with the manoeuvre terms computed by the caller (same expressions).
#[inline(always)]
pub(super) fn h_row_flight_df_with<T: Real, const K: usize>(
    i: usize,
    theta: &Vector3<T>,
    f_s: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
    terms: &ManoeuvreTerms<T>,
) -> SparseRow<T, 12> {
    let mut h = SparseRow::<T, 12>::new();
    let half = T::lit(0.5);
    let limit = T::lit(MAX_MISALIGNMENT_RAD);
    let c = bounded_misalignment(theta);
    let s = skew_row(f_s, i);
    let lever = skew_row(lever_arm_m, i);
    let c_dot_f = c.dot(f_s);
    let (c_i, f_i) = (
        c.get(i).copied().unwrap_or_else(T::zero),
        f_s.get(i).copied().unwrap_or_else(T::zero),
    );
    // At most 4 entries per axis: `push` cannot fail.
    for (a, (&v, &l)) in s.iter().zip(lever.iter()).enumerate() {
        let (c_a, f_a, th_a) = (
            c.get(a).copied().unwrap_or_else(T::zero),
            f_s.get(a).copied().unwrap_or_else(T::zero),
            theta.get(a).copied().unwrap_or_else(T::zero),
        );
        let mut d = half * (c_i * f_a - T::lit(2.0) * f_i * c_a);
        if a == i {
            d += half * c_dot_f;
        }
        // ∂c_a/∂θ_a: 0 beyond the bound.
        if th_a.abs() > limit {
            d = T::zero();
        }
        let _ = h.push(K * a, d - v);
        let _ = h.push(
            K * a + 1,
            terms.a_theta_f.get((i, a)).copied().unwrap_or_else(T::zero),
        );
        let _ = h.push(
            K * a + 2,
            terms.a_rate.get((i, a)).copied().unwrap_or_else(T::zero),
        );
        if a != i {
            let _ = h.push(K * a + 3, l);
        } else if has_accel_bias::<K>() {
            let _ = h.push(K * a + BIAS_STATE, T::one());
        }
    }
    h
}

/// H (6×N) in the spec's state ordering (the flight configuration's chains: with 1 on the
/// bias `b_i` of each df row, spec index `12 + i`).
pub fn h_matrix<T: Real, const K: usize, const N: usize>(
    omega_m: &Vector3<T>,
    f_h: &Vector3<T>,
    lever_arm_m: &Vector3<T>,
) -> Result<SMatrix<T, 6, N>, NavError> {
    let model = FlexureModel::for_dims::<K, N>()?;
    let mut h = SMatrix::<T, 6, N>::zeros();
    for (row, mut out) in h.row_iter_mut().enumerate() {
        let r: SVector<T, N> = h_row(
            model,
            row,
            omega_m,
            f_h,
            lever_arm_m,
            super::model::spec_index,
        );
        out.copy_from(&r.transpose());
    }
    if has_accel_bias::<K>() {
        for i in 0..3 {
            if let Some(e) = h.get_mut((3 + i, super::model::spec_index(BIAS_STATE, i))) {
                *e = T::one();
            }
        }
    }
    Ok(h)
}

fn in_range3<T: Real>(input: &'static str, v: &Vector3<T>, limit: f64) -> Result<(), NavError> {
    let lim = T::lit(limit);
    if v.as_slice().iter().all(|c| c.abs() <= lim) {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input })
    }
}

/// `true` when every input is within its physical range ([`check_ranges`]' limits) — and so
/// finite: `|v| ≤ limit` is false for NaN and ±∞. No branch per value.
#[inline(always)]
pub(super) fn all_in_range<T: Real>(master: &MasterSample<T>, slave: &SlaveSample<T>) -> bool {
    let within = |v: &Vector3<T>, limit: f64| {
        let lim = T::lit(limit);
        (v.x.abs() <= lim) & (v.y.abs() <= lim) & (v.z.abs() <= lim)
    };
    within(&master.angular_rate_rad_s, MAX_ANGULAR_RATE_RAD_S)
        & within(&master.angular_accel_rad_s2, MAX_ANGULAR_ACCEL_RAD_S2)
        & within(&master.specific_force_m_s2, MAX_SPECIFIC_FORCE_M_S2)
        & within(&slave.angular_rate_rad_s, MAX_ANGULAR_RATE_RAD_S)
        & within(&slave.specific_force_m_s2, MAX_SPECIFIC_FORCE_M_S2)
}

/// Checks the physical range of the inputs (`InputOutOfRange`; limits
/// [`MAX_ANGULAR_RATE_RAD_S`], [`MAX_ANGULAR_ACCEL_RAD_S2`], [`MAX_SPECIFIC_FORCE_M_S2`]).
pub(super) fn check_ranges<T: Real>(
    master: &MasterSample<T>,
    slave: &SlaveSample<T>,
) -> Result<(), NavError> {
    let (rate, accel, force) = (
        MAX_ANGULAR_RATE_RAD_S,
        MAX_ANGULAR_ACCEL_RAD_S2,
        MAX_SPECIFIC_FORCE_M_S2,
    );
    in_range3(
        "master.angular_rate_rad_s",
        &master.angular_rate_rad_s,
        rate,
    )?;
    in_range3(
        "master.angular_accel_rad_s2",
        &master.angular_accel_rad_s2,
        accel,
    )?;
    in_range3(
        "master.specific_force_m_s2",
        &master.specific_force_m_s2,
        force,
    )?;
    in_range3("slave.angular_rate_rad_s", &slave.angular_rate_rad_s, rate)?;
    in_range3(
        "slave.specific_force_m_s2",
        &slave.specific_force_m_s2,
        force,
    )
}

#[cfg(test)]
mod tests;

//! The launch hand-over: from the transfer alignment under the wing to the free-flight INS and
//! its 17-state error-state EKF (spec `flight-navigator.md`, "Hand-over at separation").
//!
//! At the separation epoch the alignment gives the slave's total misalignment relative to the
//! master body, `θ̂ = θ̂_m + θ̂_f` (`C_m^s = exp(−[θ×])`), with covariance `P_θ`, and the
//! flexure deflection and rate `θ̂_f`, `θ̂̇_f`; the master gives its attitude `Ĉ_m^n`,
//! velocity, position, body rate and their quality. Then:
//!
//! * attitude `Ĉ_s^n = Ĉ_m^n exp([θ̂×])`; with the seeker EKF's convention
//!   `Ĉ = (I − [φ×]) C` (n frame) and independent master and alignment errors,
//!   `φ_s = φ_m − C_s^n J_r(θ) δθ`, so `P_φ = P_φm + C_s^n J_r P_θ J_rᵀ C_n^s`
//!   (`J_r` the right Jacobian of SO(3); the first-order form of the spec is `J_r = I`);
//! * lever arm in master axes `l = l₀ + θ̂_f × l₀` (the wing's deflection moves the pylon);
//!   position `r_s = r_m + Ĉ_m^n l`, velocity `v_s = v_m + Ĉ_m^n (ω_nm^m × l + θ̂̇_f × l₀)`;
//!   their covariances add the master's, the attitude error's effect on the lever-arm terms
//!   (`[(Ĉ l)×] P_φm [(Ĉ l)×]ᵀ`), the lever arm's own uncertainty and the flexure-rate
//!   estimate's;
//! * sensor biases and gimbal errors start from their priors (zero estimate, prior variance);
//! * the accelerometer bias's correlation with the attitude error: the flight alignment
//!   estimates θ together with the specific-force-difference bias `b = b_m − b_s` (df =
//!   θ × f + b: in level flight a tilt and a horizontal bias are the same measurement), so
//!   their errors are correlated, `P_θb`. The difference bias is the master's minus the
//!   slave's *equivalent* bias, `b = b_m − b_s^eq`, `b_s^eq = b_s + (S + M) f_carry` (the
//!   alignment's prior holds the slave's scale-factor and misalignment share `v = var((S + M)
//!   f)` of level carry, [`crate::transfer_alignment::TaConfig::with_slave_share`]), and
//!   `b_s^eq` is what the EKF's bias states estimate (referred to the carry's force, below).
//!   Per axis, `b_s^eq` is the part of `b` its prior explains, `E[b_s^eq | b] = −β b` with
//!   `β = (σ_bs² + v) / (σ_bm² + σ_bs² + v)`, and (the estimate being uncorrelated with its
//!   error) `cov(δθ, b_s^eq) = β P_θb` per bias column; the EKF's bias error is `b_s^eq` (zero
//!   estimate), so `cov(φ_s, ∇) = −C_s^n J_r P_θb diag(β)`. Without it the EKF treats the tilt and
//!   the bias as independent and its horizontal velocity σ grows as if their effects added,
//!   where in truth they largely cancel (`g φ ≈ −∇` along the level axes).
//!
//! * the specific force the accelerometer-bias states refer to: the carry's (the last master
//!   epoch's, in slave axes), set on the new EKF at the hand-over (`refer_to_carry`). The
//!   alignment levelled the slave against its own accelerometers at that force, so the
//!   scale-factor and misalignment share of the bias, `(S + M) f_carry`, is part of the error
//!   the tilt and the difference bias absorbed; the drop (≈ 0 g) and the pull-up after it are
//!   departures from it, charged to the velocity (`seeker_ins` flight noise), not new biases.
//!
//! * the accelerometer-bias estimate: the EKF's bias states start from the priors (zero
//!   estimate). Handing over the alignment's `b̂` as `−β b̂` with covariance
//!   `diag(β) P_bb diag(β) + diag(β σ_bm²)` (plus the level axes' misalignment share) was
//!   measured and removed: the alignment's level-axis bias stays overconfident after the
//!   carry's turns (the misalignment share acts there as a tilt), and neither form was
//!   consistent on both `mission` and `mission-s-turn` (docs/navigator.md, "The bias hand-over,
//!   measured again"). The alignment's bias variance itself is charged with the share's
//!   change in a manoeuvre ([`crate::transfer_alignment::share_charge`]).
//!
//! The other cross-covariances between the blocks are neglected (master and alignment errors
//! are independent; the attitude–velocity coupling through the lever arm is `|ω × l| σ_φm`,
//! below 10⁻³ m/s for any pylon).

use crate::earth::radii_m;
use crate::error::{input_finite, NavError};
use crate::math::checks::{all_finite, require_finite_input};
use crate::math::kalman::is_psd;
use crate::math::rotation::{dcm_to_quat, exp_so3, skew};
use crate::seeker_ins::{
    InsState, Position, SeekerInsInitial, ACC_BIAS, ATT, GIMBAL, GYRO_BIAS, POS, STATES,
    VARIANCE_CEILING, VEL,
};
use crate::transfer_alignment::TransferAlignment;
use crate::Real;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// The master (aircraft) INS at the separation epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MasterAtRelease<T> {
    /// Attitude `Ĉ_m^n` of the master body.
    pub c_m_n: Matrix3<T>,
    /// Velocity over the earth, NED, m/s.
    pub vel_ned_m_s: Vector3<T>,
    /// Geodetic position of the master IMU.
    pub position: Position,
    /// Body rate relative to NED, `ω_nm^m`, master axes, rad/s.
    pub rate_nm_rad_s: Vector3<T>,
    /// 1σ of the master's attitude error per NED axis, rad.
    pub attitude_sigma_rad: Vector3<T>,
    /// 1σ of the master's velocity error per NED axis, m/s.
    pub velocity_sigma_m_s: Vector3<T>,
    /// 1σ of the master's position error per NED axis, m.
    pub position_sigma_m: Vector3<T>,
    /// 1σ of the master's body-rate error per axis, rad/s.
    pub rate_sigma_rad_s: T,
}

/// The transfer alignment's estimate at the separation epoch.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AlignmentAtRelease<T> {
    /// Total misalignment θ̂ of the slave relative to the master body (`C_m^s = exp(−[θ×])`),
    /// rad.
    pub theta_rad: Vector3<T>,
    /// Covariance of θ̂, rad².
    pub theta_covariance_rad2: Matrix3<T>,
    /// Flexure part θ̂_f of θ̂ (deflects the lever arm), rad.
    pub flexure_rad: Vector3<T>,
    /// Flexure rate θ̂̇_f, rad/s.
    pub flexure_rate_rad_s: Vector3<T>,
    /// Covariance of θ̂̇_f, (rad/s)².
    pub flexure_rate_covariance: Matrix3<T>,
    /// Cross-covariance of θ̂'s error (rows, rad) with the error of the estimated
    /// specific-force-difference bias `b = b_m − b_s` (columns, m/s²; master minus slave
    /// accelerometer bias), rad·m/s². Zero for a filter without that state.
    pub theta_bias_covariance: Matrix3<T>,
    /// Prior variance of the specific-force-difference bias in the alignment per axis X, Y, Z
    /// (`σ_bm² + σ_bs² + v`), (m/s²)². Zero for a filter without that state.
    pub bias_prior_variance_m2_s4: Vector3<T>,
    /// The part `v` of `bias_prior_variance_m2_s4` that is the slave's scale-factor and
    /// misalignment share (the slave's, like `σ_bs²`), per axis, (m/s²)²
    /// ([`crate::transfer_alignment::slave_share_variance`]); zero when the prior holds the
    /// instruments' biases only.
    pub slave_share_variance_m2_s4: Vector3<T>,
}

impl<T: Real> AlignmentAtRelease<T> {
    /// The estimate of a transfer-alignment filter (any of its configurations): θ̂ and its
    /// covariance, θ̂_f, θ̂̇_f and the covariance of θ̂̇_f (the filter's θ̇_f block, states 6..9
    /// of its derivative-major state).
    pub fn from_filter<const K: usize, const N: usize>(f: &TransferAlignment<T, K, N>) -> Self {
        Self {
            theta_rad: f.theta(),
            theta_covariance_rad2: f.theta_covariance(),
            flexure_rad: f.theta_f(),
            flexure_rate_rad_s: f.theta_f_rate(),
            flexure_rate_covariance: f.theta_f_rate_covariance(),
            theta_bias_covariance: f.theta_bias_covariance(),
            bias_prior_variance_m2_s4: f.accel_bias_prior_variance(),
            slave_share_variance_m2_s4: Vector3::zeros(),
        }
    }

    /// This estimate with `v` ((m/s²)² per axis) as the slave's share of the bias prior
    /// (`slave_share_variance_m2_s4`: the navigator's alignment adds it to the instruments'
    /// prior, [`crate::transfer_alignment::TaConfig::with_slave_share`]).
    pub fn with_slave_share(self, v: &Vector3<T>) -> Self {
        Self {
            slave_share_variance_m2_s4: *v,
            ..self
        }
    }

    /// This estimate with `v` (rad² per axis) added to θ̂'s variances: the slave's
    /// scale-factor share of the flexure's lever-arm acceleration
    /// ([`crate::transfer_alignment::flexure_share_variance`]).
    pub fn with_flexure_share(self, v: &Vector3<T>) -> Self {
        Self {
            theta_covariance_rad2: self.theta_covariance_rad2 + Matrix3::from_diagonal(v),
            ..self
        }
    }
}

/// The pylon's lever arm from the master IMU to the slave IMU, master body axes.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LeverArm<T> {
    /// Nominal lever arm `l₀`, m.
    pub nominal_m: Vector3<T>,
    /// 1σ of its knowledge per axis, m.
    pub sigma_m: Vector3<T>,
}

/// Priors of the states the alignment does not estimate (1σ).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct HandoverPriors<T> {
    /// Accelerometer bias 1σ per axis, m/s².
    pub accel_bias_sigma_m_s2: T,
    /// Gyro bias 1σ per axis, rad/s.
    pub gyro_bias_sigma_rad_s: T,
    /// Gimbal angle bias 1σ per axis, rad.
    pub gimbal_bias_sigma_rad: T,
}

/// Right Jacobian of SO(3): `exp([(θ + δ)×]) = exp([θ×]) exp([(J_r(θ) δ)×])` to first order.
pub fn right_jacobian<T: Real>(theta: &Vector3<T>) -> Matrix3<T> {
    let th2 = theta.norm_squared();
    let k = skew(theta);
    let one = Matrix3::identity();
    if th2 < T::lit(1e-8) {
        return one - k * T::lit(0.5) + k * k * T::lit(1.0 / 6.0);
    }
    let th = th2.sqrt();
    let (s, c) = crate::math::trig::sin_cos(th);
    one - k * ((T::one() - c) / th2) + k * k * ((th - s) / (th2 * th))
}

fn finite3<T: Real>(v: &Vector3<T>, input: &'static str) -> Result<(), NavError> {
    require_finite_input(input, v.as_slice())
}

fn sigma3<T: Real>(v: &Vector3<T>, input: &'static str) -> Result<(), NavError> {
    finite3(v, input)?;
    if v.iter().all(|x| *x >= T::zero()) {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input })
    }
}

/// A symmetric covariance with a non-negative diagonal and finite entries.
fn covariance3<T: Real>(p: &Matrix3<T>, input: &'static str) -> Result<(), NavError> {
    if !all_finite(p.as_slice()) {
        return Err(NavError::NonFiniteInput { input });
    }
    let tol = T::lit(1e-6) * (p[(0, 0)].abs() + p[(1, 1)].abs() + p[(2, 2)].abs());
    let symmetric = (p - p.transpose()).iter().all(|x| x.abs() <= tol);
    if symmetric && (0..3).all(|i| p[(i, i)] >= T::zero()) {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input })
    }
}

/// `diag(σ²)`.
fn diag_var<T: Real>(sigma: &Vector3<T>) -> Matrix3<T> {
    Matrix3::from_diagonal(&sigma.component_mul(sigma))
}

/// `A D` for the diagonal `D = diag(d)`: column j of `A` times `d_j` (the product's one
/// non-zero term per entry; what the full product sums to, up to the sign of an exact zero).
fn times_diag<T: Real>(a: &Matrix3<T>, d: &Vector3<T>) -> Matrix3<T> {
    let mut out = *a;
    for (col, dj) in out.column_iter_mut().zip(d.iter()) {
        for v in col {
            *v *= *dj;
        }
    }
    out
}

/// `A [v×]`: the product's non-zero terms in its order (the full product's numbers up to the
/// sign of an exact zero). `[v×]ᵀ = [(−v)×]` entry for entry, so `A [v×]ᵀ` is
/// `times_skew(A, −v)`.
fn times_skew<T: Real>(a: &Matrix3<T>, v: &Vector3<T>) -> Matrix3<T> {
    // The columns of [v×]: (0, v_z, −v_y), (−v_z, 0, v_x), (v_y, −v_x, 0).
    let (x, y, z) = (v.x, v.y, v.z);
    Matrix3::from_fn(|i, j| {
        let (a0, a1, a2) = (a[(i, 0)], a[(i, 1)], a[(i, 2)]);
        match j {
            0 => a1 * z + a2 * (-y),
            1 => a0 * (-z) + a2 * x,
            _ => a0 * y + a1 * (-x),
        }
    })
}

/// `D A` for the diagonal `D = diag(d)`: row i of `A` times `d_i` (as [`times_diag`]).
fn diag_times<T: Real>(d: &Vector3<T>, a: &Matrix3<T>) -> Matrix3<T> {
    let mut out = *a;
    for (row, di) in out.row_iter_mut().zip(d.iter()) {
        for v in row {
            *v *= *di;
        }
    }
    out
}

/// The INS state and the 17-state P0 of the free-flight EKF at separation.
///
/// Errors (nothing computed): `NonFiniteInput` for a non-finite input, `InputOutOfRange` for a
/// negative σ, an asymmetric covariance, an attitude matrix that is not a rotation (columns
/// orthonormal within 10⁻³) or a master position outside the INS's model range.
pub fn hand_over<T: Real>(
    master: &MasterAtRelease<T>,
    alignment: &AlignmentAtRelease<T>,
    lever: &LeverArm<T>,
    priors: &HandoverPriors<T>,
) -> Result<SeekerInsInitial<T>, NavError> {
    let nav = hand_over_nav(master, alignment, lever, priors)?;
    let mut covariance = SMatrix::<T, STATES, STATES>::zeros();
    nav.blocks.write_p0(priors, &mut covariance);
    Ok(SeekerInsInitial {
        state: nav.state,
        covariance,
    })
}

/// The hand-over's navigation part: the transferred INS state and the three diagonal
/// blocks of its covariance (the cross blocks are zero, module doc).
#[derive(Debug, Clone, Copy)]
pub(crate) struct NavHandover<T> {
    pub(crate) state: InsState<T>,
    pub(crate) blocks: NavBlocks<T>,
}

/// The navigation blocks of the hand-over's P0, symmetrised as P0 is: position (δL rad,
/// δl rad, δh m: rad², rad², m²), velocity NED ((m/s)²), attitude φ (rad²).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(crate) struct NavBlocks<T> {
    pub(crate) pos: Matrix3<T>,
    pub(crate) vel: Matrix3<T>,
    pub(crate) att: Matrix3<T>,
    /// Attitude–accelerometer-bias cross-covariance before the slave's share β of the
    /// difference bias (module doc): `−C_s^n J_r P_θb`, rad·m/s².
    pub(crate) att_bias_unscaled: Matrix3<T>,
    /// The alignment's prior variance of the difference bias per axis (`σ_bm² + σ_bs² + v`),
    /// (m/s²)²; zero on every axis: no cross block.
    pub(crate) bias_prior_variance_m2_s4: Vector3<T>,
    /// The slave's scale-factor and misalignment share `v` of it per axis, (m/s²)² (the
    /// EKF adds it to its bias variances when it refers them to the carry's force).
    pub(crate) slave_share_m2_s4: Vector3<T>,
}

/// `(B + Bᵀ) / 2`, entry by entry as the symmetrisation of the whole P0.
fn symmetrised<T: Real>(b: &Matrix3<T>) -> Matrix3<T> {
    Matrix3::from_fn(|i, j| (b[(i, j)] + b[(j, i)]) * T::lit(0.5))
}

impl<T: Real> NavBlocks<T> {
    /// `true` when the P0 of these blocks and `priors` ([`Self::write_p0`]) passes the
    /// covariance checks of the EKF's constructor — finite, variances within
    /// [`VARIANCE_CEILING`], symmetric, PSD — checked on its blocks (P0 is block diagonal):
    /// each navigation block exactly symmetric with a Cholesky factor of `B + 10⁻⁶ tr(B) I`
    /// (a sufficient condition for the EKF's `P + 10⁻⁶ tr(P) I` of the whole P0, whose shift
    /// is at least as large), the priors' variances finite and within their ceilings. A few
    /// hundred operations instead of the dense 17 × 17 check.
    pub(crate) fn p0_passes_checks(&self, priors: &HandoverPriors<T>) -> bool {
        let blocks = [(POS, &self.pos), (VEL, &self.vel), (ATT, &self.att)];
        let within = |i: usize, v: T| {
            VARIANCE_CEILING
                .get(i)
                .is_some_and(|c| v.is_finite() && v >= T::zero() && v <= T::lit(*c))
        };
        let ab = priors.accel_bias_sigma_m_s2 * priors.accel_bias_sigma_m_s2;
        // With an attitude–bias cross block X, [att X; Xᵀ D] is checked by its Schur
        // complement att − X D⁻¹ Xᵀ (a sufficient condition for the shifted Cholesky of the
        // whole P0 as the diagonal blocks' one is without X), D = diag(ab + v): the bias block
        // once the EKF has referred it to the carry's force (`refer_to_carry`, at the same
        // tick, before any step); with `v` = 0 the P0 as written.
        let d = self.slave_share_m2_s4.map(|v| v + ab);
        let cross_ok = match self.att_bias(ab) {
            None => true,
            Some(x) if d.iter().all(|v| *v > T::zero()) && all_finite(x.as_slice()) => {
                let s = self.att - times_diag(&x, &d.map(|v| T::one() / v)) * x.transpose();
                is_psd(&symmetrised(&s), T::lit(1e-6))
            }
            Some(_) => false,
        };
        let nav_ok = cross_ok
            && blocks.iter().all(|(at, b)| {
                all_finite(b.as_slice())
                    && *b == &b.transpose()
                    && (0..3).all(|k| within(at + k, b[(k, k)]))
                    && is_psd(*b, T::lit(1e-6))
            });
        let gb = priors.gyro_bias_sigma_rad_s * priors.gyro_bias_sigma_rad_s;
        let sb = priors.gimbal_bias_sigma_rad * priors.gimbal_bias_sigma_rad;
        let priors_ok = (0..3).all(|k| within(ACC_BIAS + k, ab) && within(GYRO_BIAS + k, gb))
            && (0..2).all(|k| within(GIMBAL + k, sb));
        nav_ok && priors_ok
    }

    /// Writes the whole 17-state P0 into `p0` (every entry): these blocks, the priors'
    /// variances on the bias and gimbal states, zero elsewhere. In place: a P0 is built once,
    /// where it is used. Out of line: the hand-over's two paths (the EKF started in place, or
    /// through its public constructor) share one copy; it runs once per flight.
    #[inline(never)]
    pub(crate) fn write_p0(&self, priors: &HandoverPriors<T>, p0: &mut SMatrix<T, STATES, STATES>) {
        p0.fill(T::zero());
        p0.fixed_view_mut::<3, 3>(POS, POS).copy_from(&self.pos);
        p0.fixed_view_mut::<3, 3>(VEL, VEL).copy_from(&self.vel);
        p0.fixed_view_mut::<3, 3>(ATT, ATT).copy_from(&self.att);
        let ab = priors.accel_bias_sigma_m_s2 * priors.accel_bias_sigma_m_s2;
        let gb = priors.gyro_bias_sigma_rad_s * priors.gyro_bias_sigma_rad_s;
        let sb = priors.gimbal_bias_sigma_rad * priors.gimbal_bias_sigma_rad;
        // A diagonal entry symmetrised is itself ((v + v)/2 = v exactly).
        p0.fixed_view_mut::<3, 3>(ACC_BIAS, ACC_BIAS)
            .fill_diagonal(ab);
        // Attitude–accelerometer-bias cross-covariance (module doc): −C_s^n J_r P_θb diag(β),
        // β the slave's share of the difference bias's prior variance per axis (at most 1);
        // written with its exact transpose, so P0 stays exactly symmetric.
        if let Some(x) = self.att_bias(ab) {
            p0.fixed_view_mut::<3, 3>(ATT, ACC_BIAS).copy_from(&x);
            p0.fixed_view_mut::<3, 3>(ACC_BIAS, ATT)
                .copy_from(&x.transpose());
        }
        p0.fixed_view_mut::<3, 3>(GYRO_BIAS, GYRO_BIAS)
            .fill_diagonal(gb);
        p0.fixed_view_mut::<2, 2>(GIMBAL, GIMBAL).fill_diagonal(sb);
    }

    /// The β per axis of the slave's share of the difference bias (`(ab + v) / (σ_bm² +
    /// σ_bs² + v)`, at most 1; 0 on an axis without prior), `ab` the slave's bias prior
    /// variance, (m/s²)².
    pub(super) fn beta(&self, ab: T) -> Vector3<T> {
        self.bias_prior_variance_m2_s4
            .zip_map(&self.slave_share_m2_s4, |total, share| {
                if total > T::zero() {
                    ((ab + share) / total).min(T::one())
                } else {
                    T::zero()
                }
            })
    }

    /// The attitude–accelerometer-bias block of P0 for the slave's accelerometer-bias prior
    /// variance `ab` ((m/s²)²): the columns of `att_bias_unscaled` times
    /// `β = (ab + v) / (σ_bm² + σ_bs² + v)` (at most 1; 0 on an axis without prior). `None`
    /// when the alignment has no difference-bias state.
    fn att_bias(&self, ab: T) -> Option<Matrix3<T>> {
        let var = &self.bias_prior_variance_m2_s4;
        var.iter()
            .any(|v| *v > T::zero())
            .then(|| times_diag(&self.att_bias_unscaled, &self.beta(ab)))
    }
}

/// [`hand_over`] without the states the alignment does not hand over: the INS state and the
/// navigation blocks of P0 (what the carry phase needs at every master sample; the 17 × 17 P0
/// is written once, at separation, by [`NavBlocks::write_p0`]). Same checks and errors as
/// [`hand_over`] (the priors included).
pub(crate) fn hand_over_nav<T: Real>(
    master: &MasterAtRelease<T>,
    alignment: &AlignmentAtRelease<T>,
    lever: &LeverArm<T>,
    priors: &HandoverPriors<T>,
) -> Result<NavHandover<T>, NavError> {
    validate_master(master, lever, priors)?;
    hand_over_checked_master(master, alignment, lever)
}

/// [`hand_over_nav`] for a master, lever arm and priors that passed [`validate_master`]:
/// checks the alignment only (its errors as [`hand_over`]'s).
pub(crate) fn hand_over_checked_master<T: Real>(
    master: &MasterAtRelease<T>,
    alignment: &AlignmentAtRelease<T>,
    lever: &LeverArm<T>,
) -> Result<NavHandover<T>, NavError> {
    validate_alignment(alignment)?;
    let c_m_n = master.c_m_n;
    let theta = alignment.theta_rad;
    // Attitude.
    let c_s_n = c_m_n * exp_so3(&theta);
    let jr = right_jacobian(&theta);
    let a = c_s_n * jr;
    let p_phi =
        diag_var(&master.attitude_sigma_rad) + a * alignment.theta_covariance_rad2 * a.transpose();
    // Lever arm, position, velocity.
    let l0 = lever.nominal_m;
    let l = l0 + alignment.flexure_rad.cross(&l0);
    let l_n = c_m_n * l;
    // The products with diagonal covariances as scaled columns (`times_diag`).
    let att_var = master
        .attitude_sigma_rad
        .component_mul(&master.attitude_sigma_rad);
    let lever_var = lever.sigma_m.component_mul(&lever.sigma_m);
    let lever_n = times_diag(&c_m_n, &lever_var) * c_m_n.transpose();
    let p_r_ned = diag_var(&master.position_sigma_m)
        + times_skew(&times_diag(&skew(&l_n), &att_var), &(-l_n))
        + lever_n;
    let w = master.rate_nm_rad_s;
    let rel_m = w.cross(&l) + alignment.flexure_rate_rad_s.cross(&l0);
    let rel_n = c_m_n * rel_m;
    let vel = master.vel_ned_m_s + rel_n;
    // δv from δφ_m, δω, δl and δθ̇_f: [(C rel)×] φ_m, −C [l×] δω, C [ω×] δl, −C [l₀×] δθ̇_f.
    let rate_var = master.rate_sigma_rad_s * master.rate_sigma_rad_s;
    let c_l = times_skew(&c_m_n, &l);
    let c_w = times_skew(&c_m_n, &w);
    let c_l0 = times_skew(&c_m_n, &l0);
    let p_v = diag_var(&master.velocity_sigma_m_s)
        + times_skew(&times_diag(&skew(&rel_n), &att_var), &(-rel_n))
        + c_l * c_l.transpose() * rate_var
        + times_diag(&c_w, &lever_var) * c_w.transpose()
        + c_l0 * alignment.flexure_rate_covariance * c_l0.transpose();
    // Position of the slave (first order in |l|/R: metres over the ellipsoid, in f64).
    // The radii in `T`: the offset is metres (|l| ≪ R), so their working precision is ample
    // for it and for the covariance's scale; on the f32 target f64 is emulated in software.
    let p = master.position;
    let (lat, alt) = (T::lit(p.lat_rad), T::lit(p.alt_m));
    let (rm, rn) = radii_m(lat);
    let cos_lat = crate::math::trig::cos(lat);
    let (r_north, r_east) = (rm + alt, (rn + alt) * cos_lat);
    let position = Position {
        lat_rad: p.lat_rad + (l_n.x / r_north).to_f64(),
        lon_rad: p.lon_rad + (l_n.y / r_east).to_f64(),
        alt_m: p.alt_m - l_n.z.to_f64(),
    };
    if !position.is_in_range() {
        return Err(NavError::InputOutOfRange {
            input: "master.position",
        });
    }
    // NED metres → (δL, δl, δh): rad, rad, m (δh = −δD).
    let d = Vector3::new(T::one() / r_north, T::one() / r_east, -T::one());
    let p_pos = times_diag(&diag_times(&d, &p_r_ned), &d);
    Ok(NavHandover {
        state: InsState {
            position,
            vel_ned_m_s: vel,
            q_b_n: dcm_to_quat(&c_s_n),
        },
        blocks: NavBlocks {
            pos: symmetrised(&p_pos),
            vel: symmetrised(&p_v),
            att: symmetrised(&p_phi),
            att_bias_unscaled: -(a * alignment.theta_bias_covariance),
            bias_prior_variance_m2_s4: alignment.bias_prior_variance_m2_s4,
            slave_share_m2_s4: alignment.slave_share_variance_m2_s4,
        },
    })
}

/// The checks of [`hand_over`] on what does not come from the alignment: the master, the
/// lever arm and the priors (errors as [`hand_over`]'s).
pub(crate) fn validate_master<T: Real>(
    master: &MasterAtRelease<T>,
    lever: &LeverArm<T>,
    priors: &HandoverPriors<T>,
) -> Result<(), NavError> {
    if !all_finite(master.c_m_n.as_slice()) {
        return Err(NavError::NonFiniteInput {
            input: "master.c_m_n",
        });
    }
    let ortho = master.c_m_n.transpose() * master.c_m_n - Matrix3::identity();
    if ortho.iter().any(|x| x.abs() > T::lit(1e-3)) || master.c_m_n.determinant() <= T::zero() {
        return Err(NavError::InputOutOfRange {
            input: "master.c_m_n",
        });
    }
    finite3(&master.vel_ned_m_s, "master.vel_ned_m_s")?;
    finite3(&master.rate_nm_rad_s, "master.rate_nm_rad_s")?;
    let p = master.position;
    if !(p.lat_rad.is_finite() && p.lon_rad.is_finite() && p.alt_m.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "master.position",
        });
    }
    if !p.is_in_range() {
        return Err(NavError::InputOutOfRange {
            input: "master.position",
        });
    }
    sigma3(&master.attitude_sigma_rad, "master.attitude_sigma_rad")?;
    sigma3(&master.velocity_sigma_m_s, "master.velocity_sigma_m_s")?;
    sigma3(&master.position_sigma_m, "master.position_sigma_m")?;
    let scalars = [
        (master.rate_sigma_rad_s, "master.rate_sigma_rad_s"),
        (priors.accel_bias_sigma_m_s2, "priors.accel_bias_sigma_m_s2"),
        (priors.gyro_bias_sigma_rad_s, "priors.gyro_bias_sigma_rad_s"),
        (priors.gimbal_bias_sigma_rad, "priors.gimbal_bias_sigma_rad"),
    ];
    for (v, input) in scalars {
        input_finite(input, v)?;
        if v < T::zero() {
            return Err(NavError::InputOutOfRange { input });
        }
    }
    finite3(&lever.nominal_m, "lever.nominal_m")?;
    sigma3(&lever.sigma_m, "lever.sigma_m")
}

/// The checks of [`hand_over`] on the alignment's estimate.
fn validate_alignment<T: Real>(alignment: &AlignmentAtRelease<T>) -> Result<(), NavError> {
    finite3(&alignment.theta_rad, "alignment.theta_rad")?;
    finite3(&alignment.flexure_rad, "alignment.flexure_rad")?;
    finite3(
        &alignment.flexure_rate_rad_s,
        "alignment.flexure_rate_rad_s",
    )?;
    covariance3(
        &alignment.theta_covariance_rad2,
        "alignment.theta_covariance_rad2",
    )?;
    covariance3(
        &alignment.flexure_rate_covariance,
        "alignment.flexure_rate_covariance",
    )?;
    if !all_finite(alignment.theta_bias_covariance.as_slice()) {
        return Err(NavError::NonFiniteInput {
            input: "alignment.theta_bias_covariance",
        });
    }
    sigma3(
        &alignment.bias_prior_variance_m2_s4,
        "alignment.bias_prior_variance_m2_s4",
    )?;
    sigma3(
        &alignment.slave_share_variance_m2_s4,
        "alignment.slave_share_variance_m2_s4",
    )
}

mod bias;
pub(crate) use bias::refer_to_carry;

#[cfg(test)]
#[path = "handover_tests.rs"]
mod tests;

//! Unit tests of the hand-over: P0 from the alignment blocks and its EKF checks, the Jacobians
//! against finite differences, the alignment from a flight filter, bad inputs named.
use super::*;
use crate::math::rotation::{euler_to_dcm, log_so3, quat_to_dcm};

pub(super) fn master() -> MasterAtRelease<f64> {
    MasterAtRelease {
        c_m_n: euler_to_dcm(0.2, 0.05, 1.3),
        vel_ned_m_s: Vector3::new(40.0, 170.0, -3.0),
        position: Position {
            lat_rad: 0.65,
            lon_rad: 2.2,
            alt_m: 3000.0,
        },
        rate_nm_rad_s: Vector3::new(0.02, -0.01, 0.05),
        attitude_sigma_rad: Vector3::new(2e-4, 2e-4, 8e-4),
        velocity_sigma_m_s: Vector3::new(0.05, 0.05, 0.08),
        position_sigma_m: Vector3::new(3.0, 3.0, 5.0),
        rate_sigma_rad_s: 1e-4,
    }
}

pub(super) fn alignment() -> AlignmentAtRelease<f64> {
    let pt = Matrix3::new(1.0, 0.2, 0.0, 0.2, 2.0, 0.1, 0.0, 0.1, 4.0) * 1e-7;
    AlignmentAtRelease {
        theta_rad: Vector3::new(0.012, -0.008, 0.02),
        theta_covariance_rad2: pt,
        flexure_rad: Vector3::new(0.004, -0.001, 0.001),
        flexure_rate_rad_s: Vector3::new(0.03, 0.005, -0.004),
        flexure_rate_covariance: Matrix3::from_diagonal_element(1e-6),
        // θ's error correlated with the difference bias's (P_bb 5e-7 (m/s²)², ρ ≈ −0.5 on
        // the level axes).
        theta_bias_covariance: Matrix3::from_diagonal(&Vector3::new(-1.1e-7, -1.5e-7, 2e-8)),
        // σ_bs 1e-3 ([`PRIORS`]), σ_bm 0.25e-3 m/s², and the slave's share v of its scale
        // factor and misalignment at level carry (200 ppm, 10″ of 9.8 m/s²).
        bias_prior_variance_m2_s4: Vector3::repeat(1e-6 + 0.25e-3 * 0.25e-3) + SHARE,
        slave_share_variance_m2_s4: SHARE,
    }
}

/// The slave's scale-factor and misalignment share of [`alignment`]'s bias prior, (m/s²)².
const SHARE: Vector3<f64> = Vector3::new(2.3e-7, 2.3e-7, 3.8e-6);

pub(super) const LEVER: LeverArm<f64> = LeverArm {
    nominal_m: Vector3::new(1.5, 4.0, 0.6),
    sigma_m: Vector3::new(0.01, 0.01, 0.01),
};
pub(super) const PRIORS: HandoverPriors<f64> = HandoverPriors {
    accel_bias_sigma_m_s2: 1e-3,
    gyro_bias_sigma_rad_s: 5e-8,
    gimbal_bias_sigma_rad: 7e-4,
};

/// The hand-over's inputs ([`master`], [`alignment`], [`LEVER`], [`PRIORS`]) in `T`.
struct Inputs<T> {
    master: MasterAtRelease<T>,
    align: AlignmentAtRelease<T>,
    lever: LeverArm<T>,
    priors: HandoverPriors<T>,
}

fn inputs<T: Real>() -> Inputs<T> {
    let m = master();
    let cast3 = |v: &Vector3<f64>| v.map(T::lit);
    let master = MasterAtRelease::<T> {
        c_m_n: m.c_m_n.map(T::lit),
        vel_ned_m_s: cast3(&m.vel_ned_m_s),
        position: m.position,
        rate_nm_rad_s: cast3(&m.rate_nm_rad_s),
        attitude_sigma_rad: cast3(&m.attitude_sigma_rad),
        velocity_sigma_m_s: cast3(&m.velocity_sigma_m_s),
        position_sigma_m: cast3(&m.position_sigma_m),
        rate_sigma_rad_s: T::lit(m.rate_sigma_rad_s),
    };
    let a = alignment();
    let align = AlignmentAtRelease::<T> {
        theta_rad: cast3(&a.theta_rad),
        theta_covariance_rad2: a.theta_covariance_rad2.map(T::lit),
        flexure_rad: cast3(&a.flexure_rad),
        flexure_rate_rad_s: cast3(&a.flexure_rate_rad_s),
        flexure_rate_covariance: a.flexure_rate_covariance.map(T::lit),
        theta_bias_covariance: a.theta_bias_covariance.map(T::lit),
        bias_prior_variance_m2_s4: cast3(&a.bias_prior_variance_m2_s4),
        slave_share_variance_m2_s4: cast3(&a.slave_share_variance_m2_s4),
    };
    let lever = LeverArm {
        nominal_m: cast3(&LEVER.nominal_m),
        sigma_m: cast3(&LEVER.sigma_m),
    };
    let priors = HandoverPriors {
        accel_bias_sigma_m_s2: T::lit(PRIORS.accel_bias_sigma_m_s2),
        gyro_bias_sigma_rad_s: T::lit(PRIORS.gyro_bias_sigma_rad_s),
        gimbal_bias_sigma_rad: T::lit(PRIORS.gimbal_bias_sigma_rad),
    };
    Inputs {
        master,
        align,
        lever,
        priors,
    }
}

/// The hand-over's blocks: `hand_over` is their P0; the cheap block check vouches for
/// them, and the EKF built with P0 written in place is the one the public constructor
/// (with its dense checks) builds. Blocks that are not PSD fail both checks.
#[test]
fn p0_from_blocks_is_the_hand_over_and_passes_the_ekf_checks() {
    p0_from_blocks::<f64>();
    p0_from_blocks::<f32>();
}

fn p0_from_blocks<T: Real>() {
    use crate::contract::Estimator;
    use crate::seeker_ins::{Landmark, SeekerIns, SeekerInsConfig};
    let Inputs {
        master,
        align,
        lever,
        priors,
    } = inputs::<T>();
    let full = hand_over(&master, &align, &lever, &priors).unwrap();
    let nav = hand_over_nav(&master, &align, &lever, &priors).unwrap();
    let mut p0 = SMatrix::<T, STATES, STATES>::from_element(T::lit(7.0));
    nav.blocks.write_p0(&priors, &mut p0);
    assert_eq!(p0, full.covariance);
    assert!(nav.blocks.p0_passes_checks(&priors));
    let landmark = Landmark::new(Position {
        lat_rad: 0.651,
        ..master.position
    })
    .unwrap();
    let cfg = SeekerInsConfig::<T>::flight(landmark);
    let design = SeekerIns::design(&cfg).unwrap();
    let dense = SeekerIns::from_design(&cfg, &design, &full).unwrap();
    let mut in_place = None;
    SeekerIns::start_in(&mut in_place, &cfg, &design, &full.state, |p| {
        nav.blocks.write_p0(&priors, p)
    })
    .unwrap();
    let in_place = in_place.unwrap();
    assert!(in_place == dense);
    bad_blocks_refused(&nav.blocks, &priors, &full, &cfg, &design);
}

/// Blocks that are not PSD at their own scale, not symmetric, beyond a ceiling, or with an
/// attitude–bias cross block too large: not vouched for; the dense check refuses what it can.
fn bad_blocks_refused<T: Real>(
    blocks: &NavBlocks<T>,
    priors: &HandoverPriors<T>,
    full: &SeekerInsInitial<T>,
    cfg: &crate::seeker_ins::SeekerInsConfig<T>,
    design: &crate::seeker_ins::SeekerInsDesign<T>,
) {
    use crate::contract::Estimator;
    use crate::seeker_ins::SeekerIns;
    // A velocity block with a negative eigenvalue well beyond the dense check's
    // tolerance: refused by both.
    let mut bad = *blocks;
    bad.vel[(0, 1)] = bad.vel[(0, 0)] * T::lit(3.0);
    bad.vel[(1, 0)] = bad.vel[(0, 1)];
    assert!(!bad.p0_passes_checks(priors));
    let mut p = full.covariance;
    bad.write_p0(priors, &mut p);
    let refused = SeekerIns::from_design(
        cfg,
        design,
        &SeekerInsInitial {
            state: full.state,
            covariance: p,
        },
    );
    assert_eq!(
        refused.err(),
        Some(NavError::CovarianceNotPositiveSemiDefinite)
    );
    // The block check is stricter: the dense check's tolerance is relative to the
    // whole trace (dominated by the altitude's m²), so it accepts an attitude block
    // that is not PSD at its own scale; the navigator then leaves the decision to it.
    let mut small = *blocks;
    small.att[(0, 1)] = small.att[(0, 0)] * T::lit(3.0);
    small.att[(1, 0)] = small.att[(0, 1)];
    assert!(!small.p0_passes_checks(priors));
    // Not symmetric, or a variance beyond its ceiling: not vouched for.
    let mut asym = *blocks;
    asym.vel[(0, 1)] += T::lit(1e-3);
    assert!(!asym.p0_passes_checks(priors));
    let mut huge = *blocks;
    huge.pos[(2, 2)] = T::lit(1e30);
    assert!(!huge.p0_passes_checks(priors));
    // An attitude–bias cross block too large for the two diagonal blocks (the Schur
    // complement att − X Xᵀ/ab indefinite): not vouched for, and the dense check
    // refuses the P0 too.
    assert!(blocks
        .att_bias(priors.accel_bias_sigma_m_s2 * priors.accel_bias_sigma_m_s2)
        .is_some());
    let mut cross = *blocks;
    cross.att_bias_unscaled *= T::lit(1e4);
    assert!(!cross.p0_passes_checks(priors));
    let mut p = full.covariance;
    cross.write_p0(priors, &mut p);
    assert!(!crate::math::kalman::is_psd(&p, T::lit(1e-6)));
}

/// The right Jacobian satisfies its defining relation (finite differences of exp).
#[test]
fn right_jacobian_matches_finite_differences() {
    let th = Vector3::new(0.3, -0.2, 0.5);
    let jr = right_jacobian(&th);
    let h = 1e-6;
    for i in 0..3 {
        let mut d = Vector3::zeros();
        d[i] = h;
        let lhs = log_so3(&(exp_so3(&th).transpose() * exp_so3(&(th + d))));
        let e = (lhs / h - jr.column(i)).norm();
        assert!(e < 1e-5, "column {i}: {e}");
    }
}

/// The attitude block is the covariance of `φ_s` obtained by perturbing the composition
/// `Ĉ_s^n = Ĉ_m^n exp([θ̂×])` itself: finite differences of the exact composition give
/// the Jacobians whose sandwich is P_φ (signs included).
#[test]
fn attitude_mapping_matches_finite_differences_of_the_composition() {
    let m = master();
    let a = alignment();
    let init = hand_over(&m, &a, &LEVER, &PRIORS).unwrap();
    let c_s_n = quat_to_dcm(&init.state.q_b_n);
    // φ of an estimate Ĉ against the truth C: Ĉ = exp(−[φ×]) C.
    let phi_of = |c_hat: &Matrix3<f64>| -log_so3(&(c_hat * c_s_n.transpose()));
    let h = 1e-7;
    let mut j_theta = Matrix3::zeros();
    let mut j_phi_m = Matrix3::zeros();
    for i in 0..3 {
        let mut d = Vector3::zeros();
        d[i] = h;
        // An alignment error δθ: θ̂ = θ + δθ.
        let c_hat = m.c_m_n * exp_so3(&(a.theta_rad + d));
        j_theta.set_column(i, &(phi_of(&c_hat) / h));
        // A master attitude error φ_m: Ĉ_m^n = exp(−[φ_m×]) C_m^n.
        let c_hat = exp_so3(&(-d)) * m.c_m_n * exp_so3(&a.theta_rad);
        j_phi_m.set_column(i, &(phi_of(&c_hat) / h));
    }
    let p_fd = j_phi_m * diag_var(&m.attitude_sigma_rad) * j_phi_m.transpose()
        + j_theta * a.theta_covariance_rad2 * j_theta.transpose();
    let p = init.covariance.fixed_view::<3, 3>(ATT, ATT).into_owned();
    let e = (p - p_fd).abs().max() / p.abs().max();
    assert!(e < 1e-5, "relative error {e}\n{p}\n{p_fd}");
    // And the sign: φ_s = φ_m − C_s^n J_r δθ.
    let expected = -(c_s_n * right_jacobian(&a.theta_rad));
    assert!((j_theta - expected).abs().max() < 1e-6);
}

/// The velocity and position blocks match finite differences of the lever-arm transport
/// (the master's attitude, rate, lever arm and flexure rate perturbed one at a time).
#[test]
fn velocity_and_position_mapping_match_finite_differences() {
    let m = master();
    let a = alignment();
    let init = hand_over(&m, &a, &LEVER, &PRIORS).unwrap();
    let vel_of = |c: &Matrix3<f64>, w: &Vector3<f64>, l0: &Vector3<f64>, fr: &Vector3<f64>| {
        let l = l0 + a.flexure_rad.cross(l0);
        m.vel_ned_m_s + c * (w.cross(&l) + fr.cross(l0))
    };
    let v0 = vel_of(
        &m.c_m_n,
        &m.rate_nm_rad_s,
        &LEVER.nominal_m,
        &a.flexure_rate_rad_s,
    );
    assert!((v0 - init.state.vel_ned_m_s).norm() < 1e-12);
    let h = 1e-6;
    let mut cov = diag_var(&m.velocity_sigma_m_s);
    for i in 0..3 {
        let mut d = Vector3::zeros();
        d[i] = h;
        let dv_phi = (vel_of(
            &(exp_so3(&(-d)) * m.c_m_n),
            &m.rate_nm_rad_s,
            &LEVER.nominal_m,
            &a.flexure_rate_rad_s,
        ) - v0)
            / h;
        let dv_w = (vel_of(
            &m.c_m_n,
            &(m.rate_nm_rad_s + d),
            &LEVER.nominal_m,
            &a.flexure_rate_rad_s,
        ) - v0)
            / h;
        let dv_l = (vel_of(
            &m.c_m_n,
            &m.rate_nm_rad_s,
            &(LEVER.nominal_m + d),
            &a.flexure_rate_rad_s,
        ) - v0)
            / h;
        let dv_f = (vel_of(
            &m.c_m_n,
            &m.rate_nm_rad_s,
            &LEVER.nominal_m,
            &(a.flexure_rate_rad_s + d),
        ) - v0)
            / h;
        cov += dv_phi * dv_phi.transpose() * m.attitude_sigma_rad[i].powi(2)
            + dv_w * dv_w.transpose() * m.rate_sigma_rad_s.powi(2)
            + dv_l * dv_l.transpose() * LEVER.sigma_m[i].powi(2)
            + dv_f * dv_f.transpose() * a.flexure_rate_covariance[(i, i)];
    }
    let p_v = init.covariance.fixed_view::<3, 3>(VEL, VEL).into_owned();
    // The lever-arm σ enters through ω × δl only (δl's effect through the flexure
    // deflection θ_f × δl is second order and left out).
    let e = (p_v - cov).abs().max() / p_v.abs().max();
    assert!(
        e < 1e-4,
        "velocity covariance relative error {e}\n{p_v}\n{cov}"
    );
    // Position: the handed-over position is the master's moved by Ĉ_m^n l.
    let (rm, _) = radii_m(m.position.lat_rad);
    let l = LEVER.nominal_m + a.flexure_rad.cross(&LEVER.nominal_m);
    let north = (init.state.position.lat_rad - m.position.lat_rad) * (rm + m.position.alt_m);
    assert!((north - (m.c_m_n * l).x).abs() < 1e-6);
    let p_h = init.covariance[(POS + 2, POS + 2)];
    assert!(p_h > m.position_sigma_m.z.powi(2));
}

/// A transfer-alignment filter's estimate maps into the hand-over: its θ, θ_f, θ̇_f and
/// their covariance blocks, and the hand-over from it is a valid P0.
#[test]
fn alignment_from_a_flight_filter() {
    use crate::contract::Estimator;
    use crate::transfer_alignment::{FlightFilter, PaperCase, TaConfig, TaInitial};
    let c = TaConfig::<f64>::flight(PaperCase::Case1);
    let init = TaInitial {
        mount_misalignment_rad: Vector3::new(0.01, -0.02, 0.005),
    };
    let f = FlightFilter::<f64>::new(&c, &init).unwrap();
    let a = AlignmentAtRelease::from_filter(&f);
    assert_eq!(a.theta_rad, f.theta());
    assert_eq!(a.theta_covariance_rad2, f.theta_covariance());
    assert_eq!(a.flexure_rate_rad_s, f.theta_f_rate());
    let p = f.covariance();
    for i in 0..3 {
        assert_eq!(a.flexure_rate_covariance[(i, i)], p[(6 + i, 6 + i)]);
        assert!(a.flexure_rate_covariance[(i, i)] > 0.0);
    }
    let out = hand_over(&master(), &a, &LEVER, &PRIORS).unwrap();
    assert!(out.covariance.cholesky().is_some());
    // After one step the θ and difference-bias errors are correlated; the hand-over reads
    // the filter's cross block and its bias prior.
    let mut f = f;
    let t = crate::time::Timestamp::from_micros(10_000);
    let ms = crate::transfer_alignment::MasterSample {
        time: t,
        angular_rate_rad_s: Vector3::new(0.1, -0.05, 0.2),
        angular_accel_rad_s2: Vector3::zeros(),
        specific_force_m_s2: Vector3::new(1.0, 2.0, -9.8),
    };
    let ss = crate::transfer_alignment::SlaveSample {
        time: t,
        angular_rate_rad_s: Vector3::new(0.1, -0.05, 0.2),
        specific_force_m_s2: Vector3::new(1.0, 2.0, -9.8),
    };
    f.step(&ms, &ss).unwrap();
    let a = AlignmentAtRelease::from_filter(&f);
    let p = f.covariance();
    for i in 0..3 {
        for j in 0..3 {
            assert_eq!(a.theta_bias_covariance[(i, j)], p[(i, 12 + j)]);
        }
    }
    assert!(a.theta_bias_covariance.abs().max() > 0.0);
    assert_eq!(
        a.bias_prior_variance_m2_s4,
        c.accel_bias_sigma_m_s2
            .component_mul(&c.accel_bias_sigma_m_s2)
    );
    // The filter alone does not know which part of its prior is the slave's share.
    assert_eq!(a.slave_share_variance_m2_s4, Vector3::zeros());
    let out = hand_over(&master(), &a, &LEVER, &PRIORS).unwrap();
    assert!(out.covariance.cholesky().is_some());
}

/// The attitude–accelerometer-bias block is `−C_s^n J_r P_θb diag(β)` with the slave's
/// share `β = (σ_bs² + v) / (σ_bm² + σ_bs² + v)` per axis (module doc), its transpose below
/// the diagonal, and zero without a difference-bias state.
#[test]
fn attitude_bias_cross_covariance() {
    let a = alignment();
    let out = hand_over(&master(), &a, &LEVER, &PRIORS).unwrap();
    let c_s_n = master().c_m_n * exp_so3(&a.theta_rad);
    let ab = PRIORS.accel_bias_sigma_m_s2.powi(2);
    let beta = Vector3::from_fn(|i, _| {
        (ab + a.slave_share_variance_m2_s4[i]) / a.bias_prior_variance_m2_s4[i]
    });
    // The share makes the slave's part of the down axis' prior almost all of it.
    assert!(beta.z > 0.98 && beta.x < beta.z, "{beta}");
    let want = -(c_s_n * right_jacobian(&a.theta_rad) * a.theta_bias_covariance)
        * Matrix3::from_diagonal(&beta);
    let got = out
        .covariance
        .fixed_view::<3, 3>(ATT, ACC_BIAS)
        .into_owned();
    assert!(
        (got - want).norm() < 1e-12 * want.norm().max(1e-30),
        "{got} vs {want}"
    );
    assert!(want.norm() > 0.0);
    let lower = out
        .covariance
        .fixed_view::<3, 3>(ACC_BIAS, ATT)
        .into_owned();
    assert_eq!(lower, got.transpose());
    assert!(out.covariance.cholesky().is_some());
    let mut none = a;
    none.bias_prior_variance_m2_s4 = Vector3::zeros();
    let out = hand_over(&master(), &none, &LEVER, &PRIORS).unwrap();
    let z = out
        .covariance
        .fixed_view::<3, 3>(ATT, ACC_BIAS)
        .into_owned();
    assert_eq!(z, Matrix3::zeros());
    // A negative prior variance is refused, named.
    let mut bad = a;
    bad.bias_prior_variance_m2_s4.y = -1.0;
    assert_eq!(
        hand_over(&master(), &bad, &LEVER, &PRIORS).unwrap_err(),
        NavError::InputOutOfRange {
            input: "alignment.bias_prior_variance_m2_s4"
        }
    );
    let mut bad = a;
    bad.slave_share_variance_m2_s4.z = f64::NAN;
    assert_eq!(
        hand_over(&master(), &bad, &LEVER, &PRIORS).unwrap_err(),
        NavError::NonFiniteInput {
            input: "alignment.slave_share_variance_m2_s4"
        }
    );
}

/// `slave_share_variance` is the variance of `((S + M) f)_i` at level carry's specific
/// force (`f` = gravity down) for independent scale-factor and misalignment errors of the
/// given σ: checked against draws of S and M (seeded; 20 000 draws, the sample variance
/// within 4 % of it per axis), and `with_slave_share` adds it to a configuration's prior.
#[test]
fn slave_share_is_the_scale_factor_and_misalignment_variance_at_level_carry() {
    let (sf, mis) = (2e-4, 4.848e-5);
    let v = crate::transfer_alignment::slave_share_variance(sf, mis);
    let g = crate::earth::GRAVITY_POLE_M_S2;
    let f = Vector3::new(0.0, 0.0, -g);
    let mut seed = 0x2545_f491_4f6c_dd1d_u64;
    let mut normal = || {
        // Box-Muller from two uniforms of a 64-bit LCG.
        let mut u = || {
            seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
            ((seed >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let (a, b) = (u(), u());
        (-2.0 * a.ln()).sqrt() * (2.0 * core::f64::consts::PI * b).cos()
    };
    let n = 20_000;
    let mut sum = Vector3::<f64>::zeros();
    for _ in 0..n {
        let sm = Matrix3::from_fn(|i, j| if i == j { sf } else { mis } * normal());
        let e = sm * f;
        sum += e.component_mul(&e);
    }
    let sample = sum / n as f64;
    for i in 0..3 {
        assert!(
            (sample[i] / v[i] - 1.0).abs() < 0.04,
            "axis {i}: {:e} vs {:e}",
            sample[i],
            v[i]
        );
    }
    // `TaConfig::with_slave_share` adds it to the instruments' prior on every axis.
    let own = crate::transfer_alignment::TaConfig::<f64>::flight(
        crate::transfer_alignment::PaperCase::Case1,
    );
    let with = own.with_slave_share(sf, mis).accel_bias_sigma_m_s2;
    for i in 0..3 {
        let want = own.accel_bias_sigma_m_s2[i].powi(2) + v[i];
        assert!((with[i] * with[i] - want).abs() < 1e-12 * want, "axis {i}");
    }
}

/// P0 is symmetric and positive definite; refused inputs say which.
#[test]
fn p0_is_positive_definite_and_bad_inputs_are_named() {
    let init = hand_over(&master(), &alignment(), &LEVER, &PRIORS).unwrap();
    let p = init.covariance;
    assert!((p - p.transpose()).abs().max() == 0.0);
    assert!(p.cholesky().is_some());
    let mut m = master();
    m.c_m_n[(0, 0)] = 2.0;
    assert_eq!(
        hand_over(&m, &alignment(), &LEVER, &PRIORS).unwrap_err(),
        NavError::InputOutOfRange {
            input: "master.c_m_n"
        }
    );
    let mut a = alignment();
    a.theta_rad.x = f64::NAN;
    assert_eq!(
        hand_over(&master(), &a, &LEVER, &PRIORS).unwrap_err(),
        NavError::NonFiniteInput {
            input: "alignment.theta_rad"
        }
    );
    let mut l = LEVER;
    l.sigma_m.y = -0.1;
    assert_eq!(
        hand_over(&master(), &alignment(), &l, &PRIORS).unwrap_err(),
        NavError::InputOutOfRange {
            input: "lever.sigma_m"
        }
    );
    // f32 gives the same state to f32 precision.
    let m32 = MasterAtRelease::<f32> {
        c_m_n: master().c_m_n.cast(),
        vel_ned_m_s: master().vel_ned_m_s.cast(),
        position: master().position,
        rate_nm_rad_s: master().rate_nm_rad_s.cast(),
        attitude_sigma_rad: master().attitude_sigma_rad.cast(),
        velocity_sigma_m_s: master().velocity_sigma_m_s.cast(),
        position_sigma_m: master().position_sigma_m.cast(),
        rate_sigma_rad_s: 1e-4,
    };
    let a0 = alignment();
    let a32 = AlignmentAtRelease::<f32> {
        theta_rad: a0.theta_rad.cast(),
        theta_covariance_rad2: a0.theta_covariance_rad2.cast(),
        flexure_rad: a0.flexure_rad.cast(),
        flexure_rate_rad_s: a0.flexure_rate_rad_s.cast(),
        flexure_rate_covariance: a0.flexure_rate_covariance.cast(),
        theta_bias_covariance: a0.theta_bias_covariance.cast(),
        bias_prior_variance_m2_s4: a0.bias_prior_variance_m2_s4.cast(),
        slave_share_variance_m2_s4: a0.slave_share_variance_m2_s4.cast(),
    };
    let l32 = LeverArm::<f32> {
        nominal_m: LEVER.nominal_m.cast(),
        sigma_m: LEVER.sigma_m.cast(),
    };
    let p32 = HandoverPriors::<f32> {
        accel_bias_sigma_m_s2: 1e-3,
        gyro_bias_sigma_rad_s: 5e-8,
        gimbal_bias_sigma_rad: 7e-4,
    };
    let i32 = hand_over(&m32, &a32, &l32, &p32).unwrap();
    let dv = (i32.state.vel_ned_m_s.cast::<f64>() - init.state.vel_ned_m_s).norm();
    assert!(dv < 1e-4, "{dv}");
    assert!(i32.covariance.cast::<f64>().cholesky().is_some());
}

/// The products with a diagonal or a skew-symmetric matrix as written in the hand-over give
/// what the full products give, bit for bit (entries without exact zeros), in f32 and f64.
fn diagonal_products_are_the_full_products<T: Real>() {
    let mut seed = 0x9e37_79b9_u64;
    let mut next = || {
        seed = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        T::lit(((seed >> 11) as f64 / (1u64 << 53) as f64) * 4.0 - 2.0)
    };
    for _ in 0..200 {
        let a = Matrix3::from_fn(|_, _| next());
        let d = Vector3::new(next(), next(), next());
        let dm = Matrix3::from_diagonal(&d);
        assert_eq!(times_diag(&a, &d), a * dm);
        assert_eq!(diag_times(&d, &a), dm * a);
        assert_eq!(times_diag(&diag_times(&d, &a), &d), dm * a * dm);
        assert_eq!(times_skew(&a, &d), a * skew(&d));
        assert_eq!(times_skew(&a, &(-d)), a * skew(&d).transpose());
        let sd = times_diag(&skew(&d), &d);
        assert_eq!(times_skew(&sd, &(-d)), skew(&d) * dm * skew(&d).transpose());
    }
}

#[test]
fn diagonal_products_are_the_full_products_f32_f64() {
    diagonal_products_are_the_full_products::<f32>();
    diagonal_products_are_the_full_products::<f64>();
}

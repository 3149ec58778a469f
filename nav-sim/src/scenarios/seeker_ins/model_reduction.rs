//! What leaving slow entries of the error model F out of the covariance prediction would do
//! to P (f64): the full model and a reduced one step by step along the seeker scenarios'
//! truth, without LOS updates (the unaided P, the largest the filter carries). Reported:
//! the one-step difference of `Φ P Φᵀ + Q_d` from the same P, relative to the step's process
//! noise Q_d (velocity and attitude variances) and to the covariance itself (correlation
//! units, `|ΔP_ij| / √(P_ii P_jj)`), and the σ ratio after the whole flight with each model
//! propagated on its own. `cargo test -p nav-sim --lib model_reduction -- --ignored --nocapture`
//! (docs/cost.md, "The covariance prediction against PX4 EKF2"; the table is in the README).

#[cfg(test)]
mod tests {
    use super::super::config::load_config;
    use super::super::run::initial_covariance;
    use super::super::sensors::Sensors;
    use super::super::trajectory::generate;
    use crate::rng::run_rng;
    use nalgebra::{SMatrix, Vector3};
    use nav_core::seeker_ins::{f_block, propagate_covariance, transition_block, FBlock, STATES};

    /// Entries of the 9 × 15 F block kept by a reduced model: (row, column) predicate.
    type Keep = fn(usize, usize) -> bool;

    /// Position ← velocity, velocity ← attitude (specific force) and accelerometer bias,
    /// attitude ← gyro bias: the couplings a strapdown EKF without earth and transport rate
    /// keeps (PX4 EKF2's).
    fn kinematic(r: usize, c: usize) -> bool {
        matches!((r, c), (0, 3) | (1, 4) | (2, 5))
            || ((3..6).contains(&r) && (6..12).contains(&c))
            || ((6..9).contains(&r) && (12..15).contains(&c))
    }

    /// `kinematic` and the rate couplings: velocity ← velocity (Coriolis, transport),
    /// attitude ← attitude (`−[ω_in×]`).
    fn with_rates(r: usize, c: usize) -> bool {
        kinematic(r, c)
            || ((3..6).contains(&r) && (3..6).contains(&c))
            || ((6..9).contains(&r) && (6..9).contains(&c))
    }

    /// `kinematic` and the vertical gravity gradient (velocity down ← height, `∂g/∂h`, the
    /// vertical channel's instability).
    fn with_gradient(r: usize, c: usize) -> bool {
        kinematic(r, c) || (r, c) == (5, 2)
    }

    /// `with_gradient` and `W_v = ∂ω_en/∂V` (attitude ← velocity, transport rate).
    fn with_transport(r: usize, c: usize) -> bool {
        with_gradient(r, c) || matches!((r, c), (6, 4) | (7, 3) | (8, 4))
    }

    /// Every entry: the control (no difference at all).
    fn everything(_: usize, _: usize) -> bool {
        true
    }

    fn reduced(f: &FBlock<f64>, keep: Keep) -> FBlock<f64> {
        FBlock::from_fn(|r, c| if keep(r, c) { f[(r, c)] } else { 0.0 })
    }

    #[test]
    #[ignore = "measurement (prints); run with --ignored --nocapture"]
    fn reduced_models_against_the_full_one() {
        type P = SMatrix<f64, STATES, STATES>;
        for name in ["seeker-straight", "seeker-s-turn"] {
            let cfg = load_config(name).expect("scenario");
            let dt_imu = 1.0 / cfg.rates.imu_hz;
            let truth = generate(&cfg.trajectory, dt_imu);
            let steps = (cfg.rates.imu_hz / cfg.rates.covariance_hz).round() as usize;
            let dt = truth.dt_s * steps as f64;
            let sensors = Sensors::draw(&cfg, truth.dt_s, &mut run_rng(1, 0));
            let (qa, qg) = (sensors.vrw * sensors.vrw, sensors.arw * sensors.arw);
            let p0: P = initial_covariance(&cfg, &truth.c_b_n[0]);
            for (label, keep) in [
                ("everything", everything as Keep),
                ("kinematic", kinematic),
                ("+ ∂g/∂h", with_gradient),
                ("+ ∂g/∂h, W_v", with_transport),
                ("with rates", with_rates),
            ] {
                let (mut p, mut p_red) = (p0, p0);
                let (mut worst_q, mut worst_corr) = (0.0_f64, 0.0_f64);
                let mut k0 = 0;
                while k0 + steps < truth.t_s.len() {
                    let mut dv = Vector3::zeros();
                    for k in k0 + 1..=k0 + steps {
                        dv += truth.c_b_n[k - 1] * truth.imu[k].delta_v_m_s;
                    }
                    let f = f_block(
                        &truth.position[k0],
                        &truth.vel_ned_m_s[k0],
                        &truth.c_b_n[k0],
                        &(dv / dt),
                    );
                    let a_full = transition_block(&f, dt);
                    let a_red = transition_block(&reduced(&f, keep), dt);
                    let mut one = p;
                    propagate_covariance(&mut one, &a_red, dt, qa, qg).expect("reduced step");
                    propagate_covariance(&mut p, &a_full, dt, qa, qg).expect("full step");
                    propagate_covariance(&mut p_red, &a_red, dt, qa, qg).expect("reduced");
                    let d = one - p;
                    for i in 3..9 {
                        let q = if i < 6 { qa * dt } else { qg * dt };
                        worst_q = worst_q.max(d[(i, i)].abs() / q);
                    }
                    for i in 0..STATES {
                        for j in 0..STATES {
                            let s = (p[(i, i)] * p[(j, j)]).sqrt();
                            if s > 0.0 {
                                worst_corr = worst_corr.max(d[(i, j)].abs() / s);
                            }
                        }
                    }
                    k0 += steps;
                }
                let ratios: Vec<f64> = (0..9)
                    .map(|i| (p_red[(i, i)] / p[(i, i)]).sqrt() - 1.0)
                    .collect();
                let sigma_ratio = ratios.iter().fold(0.0_f64, |m, r| m.max(r.abs()));
                let shown: Vec<String> = ratios.iter().map(|r| format!("{r:+.1e}")).collect();
                println!("    σ_red/σ_full − 1, states 0..9: {}", shown.join(" "));
                println!(
                    "{name:<16} {label:<11} steps {}: one step max |ΔP_ii|/Q_ii (vel, att) \
                     {worst_q:.3e}, max |ΔP_ij|/√(P_ii P_jj) {worst_corr:.3e}; after the \
                     flight max |σ_red/σ_full − 1| (states 0..9) {sigma_ratio:.3e}",
                    k0 / steps
                );
                assert!(worst_q.is_finite() && worst_corr.is_finite() && sigma_ratio.is_finite());
                if label == "everything" {
                    assert!(worst_q == 0.0 && worst_corr == 0.0 && sigma_ratio == 0.0);
                }
            }
        }
    }
}

//! Truth and sensors of the transfer-alignment experiment (spec "Kinematics the simulator must
//! generate"): master trajectory from profile segments, mounting misalignment, wing flexure
//! (3rd-order Markov, 2nd-order Markov or a lightly damped bending mode), slave location
//! `L = L_0 + θ_f × L_0`, slave specific force and angular rate from the exact kinematics (seed
//! eq. 7) and exact rotations `C_m^s = exp(−[θ×])`, and master/slave IMU noise and biases.
use super::config::{CaseConfig, FlexureTruthConfig, ImuConfig, TruthModel, G0_M_S2};
use crate::processes::{draw, psd_sqrt, LinearProcess};
use crate::rng::{normal3, SimRng};
use crate::truth::{cross_matrix, earth_rate_ned_rad_s, gravity_ned_m_s2, rotation_from_vector};
use anyhow::{anyhow, bail, Result};
use nalgebra::{Matrix3, SMatrix, SVector, Vector3};
use nav_core::math::discretize::{discretize, stationary_covariance};
use nav_core::math::markov::{GaussMarkov, MarkovOrder};
use nav_core::time::Timestamp;
use nav_core::transfer_alignment::{MasterSample, SlaveSample};

/// One run of truth and sensor data at every epoch.
#[derive(Debug, Clone)]
pub struct TruthRun {
    /// Epoch times, s.
    pub t_s: Vec<f64>,
    /// True total misalignment θ = θ_m + θ_f (rotation vector of C_s^m), rad.
    pub theta_rad: Vec<Vector3<f64>>,
    /// True mounting misalignment θ_m, rad.
    pub theta_m_rad: Vector3<f64>,
    /// True flexure angular acceleration θ̈_f, rad/s².
    pub theta_f_accel_rad_s2: Vec<Vector3<f64>>,
    /// Master attitude C_n^m.
    pub c_n_m: Vec<Matrix3<f64>>,
    /// Master data as the filter gets it.
    pub master: Vec<MasterSample<f64>>,
    /// Slave IMU output.
    pub slave: Vec<SlaveSample<f64>>,
}

/// Right Jacobian of SO(3): for `R = exp([φ×])`, `Rᵀ Ṙ = [(J_r(φ) φ̇)×]`.
pub fn right_jacobian(phi: &Vector3<f64>) -> Matrix3<f64> {
    let th2 = phi.norm_squared();
    let k = cross_matrix(phi);
    if th2 < 1e-12 {
        return Matrix3::identity() - k * 0.5 + k * k / 6.0;
    }
    let th = th2.sqrt();
    Matrix3::identity() - k * ((1.0 - th.cos()) / th2) + k * k * ((th - th.sin()) / (th2 * th))
}

/// Flexure time series of one axis: θ_f, θ̇_f, θ̈_f at every epoch.
pub(crate) fn flexure_axis(
    cfg: &FlexureTruthConfig,
    axis: usize,
    dt: f64,
    n: usize,
    rng: &mut SimRng,
) -> Result<[Vec<f64>; 3]> {
    let sigma = cfg.sigma_deg[axis].to_radians();
    let tau = cfg.tau_s[axis];
    let mut out = [vec![0.0; n], vec![0.0; n], vec![0.0; n]];
    match cfg.model {
        TruthModel::Markov3 => {
            let gm =
                GaussMarkov::new(MarkovOrder::Third, sigma, tau).map_err(|e| anyhow!("{e}"))?;
            let mut p = crate::processes::gauss_markov::<3>(&gm, dt, rng)?;
            let mut x = p.x;
            for k in 0..n {
                for (o, v) in out.iter_mut().zip(x.iter()) {
                    o[k] = *v;
                }
                x = p.step(rng);
            }
        }
        TruthModel::Markov2 => {
            // θ̈_f of a 2nd-order process is white; the accelerometers see its mean over the
            // sample, here the central difference of θ̇_f.
            let gm =
                GaussMarkov::new(MarkovOrder::Second, sigma, tau).map_err(|e| anyhow!("{e}"))?;
            let mut p = crate::processes::gauss_markov::<2>(&gm, dt, rng)?;
            let mut xs = Vec::with_capacity(n + 1);
            xs.push(p.x);
            for _ in 0..n {
                xs.push(p.step(rng));
            }
            for k in 0..n {
                out[0][k] = xs[k][0];
                out[1][k] = xs[k][1];
                let prev = if k == 0 { xs[0][1] } else { xs[k - 1][1] };
                let span = if k == 0 { dt } else { 2.0 * dt };
                out[2][k] = (xs[k + 1][1] - prev) / span;
            }
        }
        TruthModel::Bending => bending_axis(cfg, axis, sigma, dt, &mut out, rng)?,
    }
    Ok(out)
}

/// The bending-mode truth of `axis` (θ, θ̇, θ̈ in `out`, `dt` s apart): a lightly damped
/// wing-bending mode driven by first-order Markov turbulence, its stationary σ of θ `sigma`
/// (rad).
fn bending_axis(
    cfg: &FlexureTruthConfig,
    axis: usize,
    sigma: f64,
    dt: f64,
    out: &mut [Vec<f64>; 3],
    rng: &mut SimRng,
) -> Result<()> {
    // θ̈ = −ω_n² θ − 2ζω_n θ̇ + u, u̇ = −u/τ_u + w: a lightly damped wing-bending mode
    // driven by 1st-order Markov turbulence; scaled so the stationary σ of θ is σ.
    let wn = 2.0 * std::f64::consts::PI * cfg.bending_frequency_hz[axis];
    let zeta = cfg.bending_damping_ratio;
    let tau_u = cfg.turbulence_tau_s;
    if !(wn > 0.0 && zeta > 0.0 && tau_u > 0.0) {
        bail!("bending mode needs positive frequency, damping ratio and turbulence τ");
    }
    let f = SMatrix::<f64, 3, 3>::new(
        0.0,
        1.0,
        0.0,
        -wn * wn,
        -2.0 * zeta * wn,
        1.0,
        0.0,
        0.0,
        -1.0 / tau_u,
    );
    let mut q = SMatrix::<f64, 3, 3>::zeros();
    q[(2, 2)] = 1.0;
    let (phi, qd) = discretize(&f, &q, dt).map_err(|e| anyhow!("{e}"))?;
    let p_unit = stationary_covariance(&phi, &qd, 200).map_err(|e| anyhow!("{e}"))?;
    let scale = sigma * sigma / p_unit[(0, 0)];
    q[(2, 2)] = scale;
    let x0: SVector<f64, 3> = draw(rng, &psd_sqrt(&(p_unit * scale)));
    let mut p = LinearProcess::new(&f, &q, dt, x0)?;
    let mut x = x0;
    let [th, th_d, th_dd] = out;
    for ((a, b), c) in th.iter_mut().zip(th_d.iter_mut()).zip(th_dd.iter_mut()) {
        *a = x[0];
        *b = x[1];
        *c = -wn * wn * x[0] - 2.0 * zeta * wn * x[1] + x[2];
        x = p.step(rng);
    }
    Ok(())
}

/// IMU error model of one run: per-sample noise σ and drawn random-constant biases (shared
/// with the mission scenario's master INS).
#[derive(Debug, Clone)]
pub(crate) struct ImuErrors {
    gyro_sigma_rad_s: f64,
    accel_sigma_m_s2: f64,
    gyro_bias_rad_s: Vector3<f64>,
    accel_bias_m_s2: Vector3<f64>,
}

impl ImuErrors {
    /// Draws the biases of `cfg`; the white noise is per sample of interval `dt` (s).
    pub(crate) fn draw(cfg: &ImuConfig, dt: f64, rng: &mut SimRng) -> Self {
        let gb = cfg.gyro_bias_deg_h.to_radians() / 3600.0;
        let ab = cfg.accel_bias_ug * 1e-6 * G0_M_S2;
        Self {
            gyro_sigma_rad_s: cfg.gyro_sigma_per_sample_rad_s(dt),
            accel_sigma_m_s2: cfg.accel_sigma_per_sample_m_s2(dt),
            gyro_bias_rad_s: normal3(rng, [gb; 3]),
            accel_bias_m_s2: normal3(rng, [ab; 3]),
        }
    }
    /// The drawn accelerometer bias, m/s².
    pub(crate) fn accel_bias_m_s2(&self) -> Vector3<f64> {
        self.accel_bias_m_s2
    }
    /// The gyro reading of the rate `w`, rad/s.
    pub(crate) fn gyro(&self, w: &Vector3<f64>, rng: &mut SimRng) -> Vector3<f64> {
        w + self.gyro_bias_rad_s + normal3(rng, [self.gyro_sigma_rad_s; 3])
    }
    /// The accelerometer reading of the specific force `f`, m/s².
    pub(crate) fn accel(&self, f: &Vector3<f64>, rng: &mut SimRng) -> Vector3<f64> {
        f + self.accel_bias_m_s2 + normal3(rng, [self.accel_sigma_m_s2; 3])
    }
}

/// Simulates one run.
pub fn simulate(cfg: &CaseConfig, rng: &mut SimRng) -> Result<TruthRun> {
    let dt = cfg.dt_s;
    let n = (cfg.duration_s / dt).round() as usize + 1;
    let theta_m = normal3(rng, cfg.mount_sigma_deg.map(f64::to_radians));
    let fx = flexure_axis(&cfg.truth_flexure, 0, dt, n, rng)?;
    let fy = flexure_axis(&cfg.truth_flexure, 1, dt, n, rng)?;
    let fz = flexure_axis(&cfg.truth_flexure, 2, dt, n, rng)?;
    let master_err = ImuErrors::draw(&cfg.master_imu, dt, rng);
    let slave_err = ImuErrors::draw(&cfg.slave_imu, dt, rng);
    let lat = cfg.latitude_deg.to_radians();
    let g_n = gravity_ned_m_s2(lat, 0.0, cfg.altitude_m);
    let w_ie_n = earth_rate_ned_rad_s(lat);
    let l0 = Vector3::from(cfg.lever_arm_m);
    let mut c_b_n = Matrix3::<f64>::identity(); // master body (m) to NED
    let mut run = TruthRun {
        t_s: Vec::with_capacity(n),
        theta_rad: Vec::with_capacity(n),
        theta_m_rad: theta_m,
        theta_f_accel_rad_s2: Vec::with_capacity(n),
        c_n_m: Vec::with_capacity(n),
        master: Vec::with_capacity(n),
        slave: Vec::with_capacity(n),
    };
    for k in 0..n {
        let t = k as f64 * dt;
        let seg = cfg.segment_at(t);
        let a_b = Vector3::from(seg.accel_g) * G0_M_S2;
        let w_nb = Vector3::from(seg.angular_rate_deg_s).map(f64::to_radians);
        let c_n_b = c_b_n.transpose();
        let w_ie_b = c_n_b * w_ie_n;
        // Master inertial rate and its derivative (ω_nb constant within a segment).
        let w = w_nb + w_ie_b;
        let w_dot = -w_nb.cross(&w_ie_b);
        let f_m = a_b - c_n_b * g_n;
        // Flexure and misalignment.
        let th_f = Vector3::new(fx[0][k], fy[0][k], fz[0][k]);
        let th_f_dot = Vector3::new(fx[1][k], fy[1][k], fz[1][k]);
        let th_f_dd = Vector3::new(fx[2][k], fy[2][k], fz[2][k]);
        let theta = theta_m + th_f;
        // Seed eq. 7 with L = L_0 + θ_f × L_0.
        let l = l0 + th_f.cross(&l0);
        let a_rel = w_dot.cross(&l)
            + w.cross(&w.cross(&l))
            + 2.0 * w.cross(&th_f_dot.cross(&l0))
            + th_f_dd.cross(&l0);
        let f_s_m = f_m + a_rel;
        let c_m_s = rotation_from_vector(&(-theta));
        let f_s = c_m_s * f_s_m;
        let w_s = c_m_s * w + right_jacobian(&theta) * th_f_dot;
        run.t_s.push(t);
        run.theta_rad.push(theta);
        run.theta_f_accel_rad_s2.push(th_f_dd);
        run.c_n_m.push(c_n_b);
        let stamp = Timestamp::from_secs_f64(t).map_err(|e| anyhow!("time stamp: {e}"))?;
        run.master.push(MasterSample {
            time: stamp,
            angular_rate_rad_s: master_err.gyro(&w, rng),
            // The master's angular-acceleration estimate is taken as exact (it only enters the
            // rigid lever-arm compensation; ≈ 1e-9 rad/s² in the default profiles).
            angular_accel_rad_s2: w_dot,
            specific_force_m_s2: master_err.accel(&f_m, rng),
        });
        run.slave.push(SlaveSample {
            time: stamp,
            angular_rate_rad_s: slave_err.gyro(&w_s, rng),
            specific_force_m_s2: slave_err.accel(&f_s, rng),
        });
        c_b_n *= rotation_from_vector(&(w_nb * dt));
    }
    Ok(run)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn right_jacobian_matches_finite_difference() {
        let phi = Vector3::new(0.3, -0.2, 0.5);
        let dphi = Vector3::new(0.7, 0.1, -0.4);
        let h = 1e-6;
        let r0 = rotation_from_vector(&(phi - dphi * h));
        let r1 = rotation_from_vector(&(phi + dphi * h));
        let rdot = (r1 - r0) / (2.0 * h);
        let m = rotation_from_vector(&phi).transpose() * rdot;
        let w = Vector3::new(
            m[(2, 1)] - m[(1, 2)],
            m[(0, 2)] - m[(2, 0)],
            m[(1, 0)] - m[(0, 1)],
        ) * 0.5;
        assert!((w - right_jacobian(&phi) * dphi).norm() < 1e-8);
    }
}

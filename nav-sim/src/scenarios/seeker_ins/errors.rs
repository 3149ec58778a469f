//! What a run records: the navigation errors (estimate − truth) and the filter's σ at the
//! output epochs, the NEES of the 17 states against the true error state (the equivalent
//! instrument errors), and the run's counters ([`RunOutput`]).

use super::trajectory::Truth;
use crate::consistency::RunConsistency;
use crate::truth::radii_of_curvature_m as radii_m;
use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};
use nav_core::math::rotation::{dcm_to_euler, euler_to_dcm, log_so3, quat_to_dcm};
use nav_core::seeker_ins::{SeekerIns, STATES};
use nav_core::Real;

/// The filter's IMU fault counters at the end of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImuFaultTally {
    /// Gaps bridged (`Health::gaps_bridged`).
    pub gaps: u32,
    /// IMU samples bridged by the hold.
    pub held_samples: u32,
    /// Clipped samples integrated.
    pub clipped_samples: u32,
}

/// Output of one run (sampled at the output rate).
#[derive(Debug, Clone, Default)]
pub struct RunOutput {
    /// Errors (estimate − truth): lat m, lon m, alt m, V_N, V_E, V_D m/s, roll, pitch, yaw deg.
    pub err: [Vec<f64>; 9],
    /// Filter 1σ of the same quantities.
    pub sigma: [Vec<f64>; 9],
    /// NEES of the 17 states, and of the position, velocity and attitude blocks.
    pub nees: [Vec<f64>; 4],
    /// The consistency samples of the run: NEES of the 17 states and, per state group
    /// ([`GROUPS`]), the group's NEES divided by its dimension (mean 1 when consistent).
    pub consistency: RunConsistency,
    /// Sum of the per-component NIS of fused and rejected components.
    pub nis_sum: f64,
    /// Scalar components fused.
    pub fused: usize,
    /// Scalar components rejected by the gate.
    pub rejected: usize,
    /// Seeker epochs with the landmark outside the gimbal limits.
    pub out_of_field: usize,
    /// Updates refused with an error.
    pub errors: usize,
    /// True gimbal angles at the seeker epochs (pitch, yaw), deg (first run only used).
    pub gimbal_deg: Vec<(f64, f64, f64)>,
    /// Filter counters at the end of the run: LOS gate re-inflations.
    pub inflations: u32,
    /// IMU fault counters at the end of the run.
    pub imu_faults: ImuFaultTally,
    /// Seeker epochs without a measurement because of an injected fault (loss of lock, IMU gap).
    pub seeker_dropped: usize,
    /// Seeker updates during an injected false lock, components fused / rejected.
    pub false_lock_fused: usize,
    /// As `false_lock_fused`, rejected.
    pub false_lock_rejected: usize,
}

/// The true instrument errors of a run: biases (accelerometer m/s², gyro rad/s, gimbal angles
/// rad) and the accelerometers' `(I + S + M)` (scale factor and misalignment).
pub(super) struct TrueBiases<'a> {
    pub(super) accel_m_s2: &'a Vector3<f64>,
    pub(super) gyro_rad_s: &'a Vector3<f64>,
    pub(super) gimbal_rad: &'a Vector2<f64>,
    pub(super) accel_matrix: &'a Matrix3<f64>,
}

/// State groups of the consistency figures: name, first state, dimension.
pub const GROUPS: [(&str, usize, usize); 6] = [
    ("position", 0, 3),
    ("velocity", 3, 3),
    ("attitude", 6, 3),
    ("accel_bias", 9, 3),
    ("gyro_bias", 12, 3),
    ("gimbal_bias", 15, 2),
];

/// The true value of the accelerometer and gyro error states at IMU epoch `k`.
///
/// Accelerometer: the **equivalent bias** `b + (S + M) f`, the whole non-white error of the
/// instrument, which enters the INS error equations through `C_b^n ∇` and does not average
/// out (gravity), at the specific force the filter's states refer to (`f_ref`, the flight
/// configuration: a departure from it is the velocity's error, not the bias's), or else
/// (`None`: the paper's filter, whose states are the bias) at `f_b`, the true mean specific
/// force of the interval ending there.
/// Gyro: the bias `b` alone: `(S + M) ω` averages out over a manoeuvre and shows as the
/// bounded attitude error `(S + M) ∫ω dt`, which the attitude states carry.
fn equivalent_biases(
    truth: &Truth,
    k: usize,
    b: &TrueBiases<'_>,
    f_ref_b_m_s2: Option<Vector3<f64>>,
) -> (Vector3<f64>, Vector3<f64>) {
    let k = k.max(1).min(truth.imu.len().saturating_sub(1));
    let inc = &truth.imu[k];
    let h = inc
        .time
        .micros_since(truth.imu[k - 1].time)
        .map_or(truth.dt_s, |us| us as f64 * 1e-6);
    let f_b = f_ref_b_m_s2.unwrap_or(inc.delta_v_m_s / h);
    (
        b.accel_m_s2 + (b.accel_matrix - Matrix3::identity()) * f_b,
        *b.gyro_rad_s,
    )
}

/// The navigation errors of the filter at output epoch `k` (estimate − truth): latitude,
/// longitude (rad), altitude (m), velocity (m/s, NED), and the estimated and true `C_b^n`.
struct NavErrors {
    d_lat: f64,
    d_lon: f64,
    d_alt: f64,
    dv: Vector3<f64>,
    c_hat: Matrix3<f64>,
    c: Matrix3<f64>,
}

impl NavErrors {
    fn of<T: Real>(filter: &SeekerIns<T>, truth: &Truth, k: usize) -> Self {
        let st = filter.state();
        let p_true = truth.position[k];
        Self {
            c_hat: quat_to_dcm(&st.q_b_n).map(|v| v.to_f64()),
            c: truth.c_b_n[k],
            d_lat: st.position.lat_rad - p_true.lat_rad,
            d_lon: st.position.lon_rad - p_true.lon_rad,
            d_alt: st.position.alt_m - p_true.alt_m,
            dv: st.vel_ned_m_s.map(|v| v.to_f64()) - truth.vel_ned_m_s[k],
        }
    }
}

/// Records the errors, σ and NEES of the filter at output epoch `k`.
pub(super) fn record<T: Real>(
    out: &mut RunOutput,
    filter: &SeekerIns<T>,
    truth: &Truth,
    k: usize,
    biases: &TrueBiases<'_>,
) {
    let seeker_b = biases.gimbal_rad;
    let f_ref = filter
        .specific_force_reference()
        .map(|f| f.map(|x| x.to_f64()));
    let (acc_b, gyr_b) = equivalent_biases(truth, k, biases, f_ref);
    let n = NavErrors::of(filter, truth, k);
    let p = filter.covariance().map(|v| v.to_f64());
    push_errors_and_sigma(out, &n, &p, truth, k);
    // True error state and NEES.
    let phi = -log_so3(&(n.c_hat * n.c.transpose()));
    let mut e = SVector::<f64, STATES>::zeros();
    e[0] = n.d_lat;
    e[1] = n.d_lon;
    e[2] = n.d_alt;
    e.fixed_rows_mut::<3>(3).copy_from(&n.dv);
    e.fixed_rows_mut::<3>(6).copy_from(&phi);
    e.fixed_rows_mut::<3>(9)
        .copy_from(&(acc_b - filter.accel_bias_m_s2().map(|v| v.to_f64())));
    e.fixed_rows_mut::<3>(12)
        .copy_from(&(gyr_b - filter.gyro_bias_rad_s().map(|v| v.to_f64())));
    e.fixed_rows_mut::<2>(15)
        .copy_from(&(seeker_b - filter.gimbal_bias_rad().map(|v| v.to_f64())));
    push_nees(out, &p, &e, truth.t_s[k]);
}

/// The navigation errors `n` in the output units (lat, lon, alt m; V m/s; roll, pitch, yaw
/// deg) and their σ from the covariance `p` (Euler σ from the φ covariance, `δe = J⁻¹ φ`),
/// appended to `out`.
fn push_errors_and_sigma(
    out: &mut RunOutput,
    n: &NavErrors,
    p: &SMatrix<f64, STATES, STATES>,
    truth: &Truth,
    k: usize,
) {
    let p_true = truth.position[k];
    let (rm, rn) = radii_m(p_true.lat_rad);
    let e_hat = dcm_to_euler(&n.c_hat);
    let e_true = dcm_to_euler(&n.c);
    let de = [
        wrap_pi(e_hat.0 - e_true.0),
        wrap_pi(e_hat.1 - e_true.1),
        wrap_pi(e_hat.2 - e_true.2),
    ];
    let lat_scale = rm + p_true.alt_m;
    let lon_scale = (rn + p_true.alt_m) * p_true.lat_rad.cos();
    let errs = [
        n.d_lat * lat_scale,
        n.d_lon * lon_scale,
        n.d_alt,
        n.dv.x,
        n.dv.y,
        n.dv.z,
        de[0].to_degrees(),
        de[1].to_degrees(),
        de[2].to_degrees(),
    ];
    let j = euler_to_phi_jacobian(&n.c_hat);
    let jinv = j.try_inverse().unwrap_or_else(Matrix3::identity);
    let pe = jinv * p.fixed_view::<3, 3>(6, 6) * jinv.transpose();
    let sig = [
        p[(0, 0)].sqrt() * lat_scale,
        p[(1, 1)].sqrt() * lon_scale,
        p[(2, 2)].sqrt(),
        p[(3, 3)].sqrt(),
        p[(4, 4)].sqrt(),
        p[(5, 5)].sqrt(),
        pe[(0, 0)].sqrt().to_degrees(),
        pe[(1, 1)].sqrt().to_degrees(),
        pe[(2, 2)].sqrt().to_degrees(),
    ];
    for i in 0..9 {
        out.err[i].push(errs[i]);
        out.sigma[i].push(sig[i]);
    }
}

/// The NEES of the error state `e` against `p` at time `t_s` (s): the 17 states', the
/// position, velocity and attitude blocks', and per state group ([`GROUPS`]) for the
/// consistency, appended to `out`.
fn push_nees(
    out: &mut RunOutput,
    p: &SMatrix<f64, STATES, STATES>,
    e: &SVector<f64, STATES>,
    t_s: f64,
) {
    let total = nees(p, e);
    out.nees[0].push(total);
    for (b, start) in [(1, 0), (2, 3), (3, 6)] {
        let pb = p.fixed_view::<3, 3>(start, start).into_owned();
        let eb = e.fixed_rows::<3>(start).into_owned();
        out.nees[b].push(nees(&pb, &eb));
    }
    // Per group: NEES / dimension, passed as (√(NEES/n), 1) so that `e²/σ²` is NEES / n.
    let groups: Vec<(f64, f64)> = GROUPS
        .iter()
        .map(|&(_, start, n)| {
            let pb = p.view((start, start), (n, n)).into_owned();
            let eb = e.rows(start, n).into_owned();
            let v =
                nalgebra::linalg::Cholesky::new(pb).map_or(f64::NAN, |ch| eb.dot(&ch.solve(&eb)));
            ((v / n as f64).sqrt(), 1.0)
        })
        .collect();
    if out.consistency.normalized.is_empty() {
        out.consistency = RunConsistency::new(&GROUPS.map(|g| g.0));
    }
    out.consistency.push(t_s, total, &groups);
}

/// ∂φ/∂(roll, pitch, yaw) at an attitude (φ of `Ĉ = (I − [φ×]) C`), by central differences.
pub(super) fn euler_to_phi_jacobian(c: &Matrix3<f64>) -> Matrix3<f64> {
    let (r, p, y) = dcm_to_euler(c);
    let h = 1e-6;
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let mut e1 = [r, p, y];
        let mut e0 = [r, p, y];
        e1[k] += h;
        e0[k] -= h;
        let c1 = euler_to_dcm(e1[0], e1[1], e1[2]);
        let c0 = euler_to_dcm(e0[0], e0[1], e0[2]);
        let phi = -log_so3(&(c1 * c0.transpose())) / (2.0 * h);
        j.set_column(k, &phi);
    }
    j
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// NEES `eᵀ P⁻¹ e` (NaN when `p` is not positive definite).
fn nees<const N: usize>(p: &SMatrix<f64, N, N>, e: &SVector<f64, N>) -> f64 {
    match nalgebra::linalg::Cholesky::new(*p) {
        Some(ch) => e.dot(&ch.solve(e)),
        None => f64::NAN,
    }
}

//! The 17-state INS error model (seed eq. 2; Titterton & Weston §12.3, Groves §14.2) for the
//! n-frame misalignment φ, `Ĉ_b^n = (I − [φ×]) C_b^n`, and its discrete propagation.
//!
//! With errors "estimate minus truth", `ρ = 2ω_ie + ω_en`, `ω_in = ω_ie + ω_en`:
//!
//! ```text
//! δL̇ = δV_N/(R_M+h) − V_N (R_M' δL + δh)/(R_M+h)²
//! δl̇ = δV_E/((R_N+h) cos L) + V_E tan L sec L δL/(R_N+h) − V_E sec L (R_N' δL + δh)/(R_N+h)²
//! δḣ = −δV_D
//! δV̇ = [fⁿ×] φ + C_b^n ∇ − ρ × δV + V × δρ + [0, 0, ∂g/∂L δL + ∂g/∂h δh]
//! φ̇  = −ω_in × φ + δω_in − C_b^n ε
//! ∇̇ = ε̇ = δθ̇_s = δψ̇_s = 0
//! ```
//!
//! (R' = dR/dL; δρ, δω_in are the first-order changes of ρ, ω_in with δL, δh and δV.)
//! Only the first 9 rows of F are non-zero and only its first 15 columns, so F is stored as a
//! 9×15 block. Noise: `G w` puts the accelerometer white noise (PSD `q_a`, (m/s²)²/Hz) on δV
//! through C_b^n and the gyro white noise (PSD `q_g`, (rad/s)²/Hz) on φ through −C_b^n; both
//! are isotropic, so `G Q Gᵀ = diag(0₃, q_a I₃, q_g I₃, 0₈)`.
//!
//! Discretisation over the filter interval Δt (F frozen over Δt):
//! `Φ = I + A`, `A = FΔt + ½(FΔt)²` (the second-order term carries, e.g., the gyro-bias →
//! attitude → velocity coupling, ≈ 5 % of the first-order terms at Δt = 0.1 s; the third-order
//! remainder is below 1 % of it), and `Q_d = Q_cΔt + ½Δt (A Q_c + Q_c Aᵀ)` (trapezoidal
//! `½(Φ Q_c Φᵀ + Q_c)Δt` to first order in A).

use super::generated::predict17::propagate_in_place;
use super::mechanization::Position;
use super::sparse_f::{FBlock, SparseF};
use crate::{NavError, Real};
use nalgebra::{Matrix3, SMatrix, Vector3};

/// Number of error states.
pub const STATES: usize = 17;
/// Index of δL (then δl, δh).
pub const POS: usize = 0;
/// Index of δV_N (then δV_E, δV_D).
pub const VEL: usize = 3;
/// Index of φ_N (then φ_E, φ_D).
pub const ATT: usize = 6;
/// Index of ∇_x (then ∇_y, ∇_z).
pub const ACC_BIAS: usize = 9;
/// Index of ε_x (then ε_y, ε_z).
pub const GYRO_BIAS: usize = 12;
/// Index of δθ_s (then δψ_s).
pub const GIMBAL: usize = 15;

/// Error-model block F at a navigation state: position, velocity (m/s, NED), C_b^n and the
/// specific force in NED `f_ned_m_s2` (m/s²). Dense form of [`SparseF::new`] (tests, reference).
pub fn f_block<T: Real>(
    pos: &Position,
    v: &Vector3<T>,
    c_b_n: &Matrix3<T>,
    f_ned_m_s2: &Vector3<T>,
) -> FBlock<T> {
    SparseF::new(pos, v, c_b_n, f_ned_m_s2).to_block()
}

/// Covariance propagation `P ← Φ P Φᵀ + Q_d` over `dt_s` with `Φ = I + A`,
/// `A = G + ½ G_f G`, `G = FΔt`, and `Q_d = Q_cΔt + ½Δt (G Q_c + Q_c Gᵀ)`: straight-line code
/// generated from the sparsity of G (`cargo xtask gen`, module `generated::predict17`; the
/// columns of U = Φ P in one loop) that reads P, which must be exactly symmetric (as every
/// covariance of the filter is: validated at construction, every update writes both triangles
/// with the same bits), and writes both triangles. Only rows and columns 0..9 of P change; the
/// result is exactly symmetric.
///
/// `G_f` keeps the entries of G whose products with G are not negligible: velocity → position
/// (`G03`, `G14`, `G25`) and attitude → velocity (`[Δt fⁿ×]`). The entries left out of the
/// second-order term are earth rate, transport rate, Coriolis and gravity gradient
/// (≤ 1.5e-4 /s), so the dropped part of `½G²` is below ≈ 1e-5 of G for Δt ≤ 0.1 s, the size
/// of the third-order remainder already dropped. `q_accel`, `q_gyro`: white-noise PSDs
/// ((m/s²)²/Hz, (rad/s)²/Hz).
///
/// `Φ c` for the transition matrix of [`propagate_covariance_sparse`] over `dt_s`:
/// `Φ = I + G + H G`, `G = F Δt`, `H = ½ G_f` with the nine second-order couplings of the
/// generated kernel (velocity → position `G03`, `G14`, `G25`; attitude → velocity
/// `½[Δt fⁿ×]`). Rows 9..17 of Φ are the identity. Used for a covariance column kept beside
/// the 17 states (the flight navigator's baro error).
#[inline(always)]
pub(crate) fn transition_times<T: Real>(
    f: &SparseF<T>,
    dt_s: T,
    c: &nalgebra::SVector<T, STATES>,
) -> nalgebra::SVector<T, STATES> {
    let w = sparse_times(f, dt_s, c);
    let half = T::lit(0.5);
    let w_att = Vector3::new(w[6], w[7], w[8]);
    let h_att = ((f.f_ned * dt_s) * half).cross(&w_att);
    let hw = [
        half * (f.f03 * dt_s) * w[3],
        half * (f.f14 * dt_s) * w[4],
        half * (f.f25 * dt_s) * w[5],
        h_att.x,
        h_att.y,
        h_att.z,
        T::zero(),
        T::zero(),
        T::zero(),
    ];
    let mut out = *c;
    for ((o, wi), hi) in out.iter_mut().zip(w.iter()).zip(hw.iter()) {
        *o += *wi + *hi;
    }
    out
}

/// `G c` over rows 0..9 for `G = F Δt` (the 9 × 15 block of [`SparseF::to_block`] of
/// `f.scaled(dt_s)`) from its non-zero entries only, each entry `f_ij Δt` formed as `scaled`
/// forms it and each row summed over its columns in ascending order: the numbers of the
/// dense product (whose other terms are zero), without the 9 × 15 block or a scaled copy of
/// F on the stack.
#[inline(always)]
fn sparse_times<T: Real>(f: &SparseF<T>, dt: T, c: &nalgebra::SVector<T, STATES>) -> [T; 9] {
    let x = |i: usize| c.get(i).copied().unwrap_or_else(T::zero);
    let (vv, cb, fv, wv) = (&f.vel_vel, &f.c_b_n, &f.f_ned, &f.w_in);
    let (vl, vh, al, ah, av) = (&f.vel_lat, &f.vel_h, &f.att_lat, &f.att_h, &f.att_v);
    let (x0, x2, x3, x4, x5) = (x(0), x(2), x(3), x(4), x(5));
    let (x6, x7, x8) = (x(6), x(7), x(8));
    let (x9, x10, x11, x12, x13, x14) = (x(9), x(10), x(11), x(12), x(13), x(14));
    let g = |v: T| v * dt;
    [
        g(f.f00) * x0 + g(f.f02) * x2 + g(f.f03) * x3,
        g(f.f10) * x0 + g(f.f12) * x2 + g(f.f14) * x4,
        g(f.f25) * x5,
        g(vl.x) * x0 + g(vh.x) * x2 + g(vv.m11) * x3 + g(vv.m12) * x4 + g(vv.m13) * x5
            - g(fv.z) * x7
            + g(fv.y) * x8
            + g(cb.m11) * x9
            + g(cb.m12) * x10
            + g(cb.m13) * x11,
        g(vl.y) * x0
            + g(vh.y) * x2
            + g(vv.m21) * x3
            + g(vv.m22) * x4
            + g(vv.m23) * x5
            + g(fv.z) * x6
            - g(fv.x) * x8
            + g(cb.m21) * x9
            + g(cb.m22) * x10
            + g(cb.m23) * x11,
        g(vl.z) * x0 + g(vh.z) * x2 + g(vv.m31) * x3 + g(vv.m32) * x4 + g(vv.m33) * x5
            - g(fv.y) * x6
            + g(fv.x) * x7
            + g(cb.m31) * x9
            + g(cb.m32) * x10
            + g(cb.m33) * x11,
        g(al.x) * x0 + g(ah.x) * x2 + g(av.x) * x4 + g(wv.z) * x7
            - g(wv.y) * x8
            - g(cb.m11) * x12
            - g(cb.m12) * x13
            - g(cb.m13) * x14,
        g(al.y) * x0 + g(ah.y) * x2 + g(av.y) * x3 - g(wv.z) * x6 + g(wv.x) * x8
            - g(cb.m21) * x12
            - g(cb.m22) * x13
            - g(cb.m23) * x14,
        g(al.z) * x0 + g(ah.z) * x2 + g(av.z) * x4 + g(wv.y) * x6
            - g(wv.x) * x7
            - g(cb.m31) * x12
            - g(cb.m32) * x13
            - g(cb.m33) * x14,
    ]
}

/// A variance of the navigation block that would round below zero is set to zero with its row
/// and column (PSD kept); the count of such repairs is returned.
///
/// Errors (P unchanged): `InvalidTimeStep`, `NonFiniteInput` (a non-finite entry would
/// result; a non-finite entry of F or of P's rows 0..15 always does).
pub fn propagate_covariance_sparse<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    f: &SparseF<T>,
    dt_s: T,
    q_accel: T,
    q_gyro: T,
) -> Result<u32, NavError> {
    if !dt_s.is_finite() || dt_s <= T::zero() {
        return Err(NavError::InvalidTimeStep);
    }
    let half_dt = T::lit(0.5) * dt_s;
    let committed = propagate_in_place(
        &mut p.data.0,
        f,
        dt_s,
        q_accel * half_dt,
        q_gyro * half_dt,
        q_accel * dt_s,
        q_gyro * dt_s,
    );
    if !committed {
        return Err(NavError::NonFiniteInput {
            input: "propagated covariance",
        });
    }
    Ok(repair_negative_variances(p))
}

/// A navigation variance that rounded below zero (a state the filter knows to the precision
/// limit): its row and column are set to zero, a congruence with a zero on the diagonal, so P
/// stays PSD. Returns the count of such repairs (for the caller's health report). Nine
/// compares when there is none.
fn repair_negative_variances<T: Real>(p: &mut SMatrix<T, STATES, STATES>) -> u32 {
    let zero = T::zero();
    let mut repaired = 0u32;
    for i in 0..9 {
        if p.get((i, i)).is_some_and(|d| *d < zero) {
            repaired += 1;
            p.row_mut(i).fill(zero);
            p.column_mut(i).fill(zero);
        }
    }
    repaired
}

/// The full 17×17 F (zero outside the 9×15 block), for tests and reference.
pub fn full_f<T: Real>(block: &FBlock<T>) -> SMatrix<T, STATES, STATES> {
    let mut f = SMatrix::<T, STATES, STATES>::zeros();
    f.fixed_view_mut::<9, 15>(0, 0).copy_from(block);
    f
}

/// `A = Φ − I = FΔt + ½(FΔt)²` restricted to its non-zero 9×15 block.
pub fn transition_block<T: Real>(f: &FBlock<T>, dt_s: T) -> FBlock<T> {
    // (F²)[0..9, 0..15] = F[0..9, 0..9] F[0..9, 0..15] because rows 9.. of F are zero.
    let f9 = f.fixed_view::<9, 9>(0, 0);
    let f2 = f9 * f;
    f * dt_s + f2 * (T::lit(0.5) * dt_s * dt_s)
}

/// Covariance propagation `P ← Φ P Φᵀ + Q_d` with `Φ = I + A` (A from [`transition_block`])
/// using only A's 9×15 block: `B = A P[0..15, :]`, then the rows 0..9 and the 9×9 corner.
/// `q_accel` and `q_gyro` are the white-noise PSDs ((m/s²)²/Hz and (rad/s)²/Hz).
///
/// Errors (P unchanged): `InvalidTimeStep`, `NonFiniteInput`,
/// `CovarianceNotPositiveSemiDefinite` (a negative or non-finite variance would result).
pub fn propagate_covariance<T: Real>(
    p: &mut SMatrix<T, STATES, STATES>,
    a: &FBlock<T>,
    dt_s: T,
    q_accel: T,
    q_gyro: T,
) -> Result<(), NavError> {
    if !dt_s.is_finite() || dt_s <= T::zero() {
        return Err(NavError::InvalidTimeStep);
    }
    if !a.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "transition matrix",
        });
    }
    // B = A P[0..15, 0..17]  (9×17).
    let b: SMatrix<T, 9, STATES> = a * p.fixed_view::<15, STATES>(0, 0);
    // Rows 0..9 of Φ P.
    let phi_p_top: SMatrix<T, 9, STATES> = p.fixed_view::<9, STATES>(0, 0) + b;
    // Corner 9×9 of Φ P Φᵀ = (Φ P)[0..9, 0..9] + (Φ P)[0..9, 0..15] Aᵀ.
    let corner: SMatrix<T, 9, 9> =
        phi_p_top.fixed_view::<9, 9>(0, 0) + phi_p_top.fixed_view::<9, 15>(0, 0) * a.transpose();
    // Q_d on the corner: Q_c Δt + ½Δt (A Q_c + Q_c Aᵀ), Q_c = diag(0, q_a I, q_g I) on 0..9.
    let mut aq = SMatrix::<T, 9, 9>::zeros();
    let half_dt = T::lit(0.5) * dt_s;
    for c in 3..9 {
        let q = if c < 6 { q_accel } else { q_gyro };
        for r in 0..9 {
            if let (Some(dst), Some(src)) = (aq.get_mut((r, c)), a.get((r, c))) {
                *dst = *src * q * half_dt;
            }
        }
    }
    let mut corner = corner + aq + aq.transpose();
    for i in 3..9 {
        let q = if i < 6 { q_accel } else { q_gyro };
        if let Some(d) = corner.get_mut((i, i)) {
            *d += q * dt_s;
        }
    }
    // Exact symmetry of the corner.
    let corner = (corner + corner.transpose()) * T::lit(0.5);
    if !corner.iter().all(|v| v.is_finite()) || !phi_p_top.iter().all(|v| v.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "propagated covariance",
        });
    }
    if corner.diagonal().iter().any(|d| *d < T::zero()) {
        return Err(NavError::CovarianceNotPositiveSemiDefinite);
    }
    // Commit: off-diagonal blocks rows 0..9 × cols 9..17 (and their transposes), then corner.
    let off = phi_p_top.fixed_view::<9, 8>(0, 9).into_owned();
    p.fixed_view_mut::<9, 8>(0, 9).copy_from(&off);
    p.fixed_view_mut::<8, 9>(9, 0).copy_from(&off.transpose());
    p.fixed_view_mut::<9, 9>(0, 0).copy_from(&corner);
    Ok(())
}

/// `cross ← Φ cross` for the transition of F = `f` over `dt_s` ([`transition_times`]); zero
/// (the correlation forgotten) when the result is not finite. Not inlined: its temporaries
/// are not in the covariance step's frame, under which the kernel runs.
#[inline(never)]
pub(crate) fn transition_column<T: Real>(
    f: &SparseF<T>,
    dt_s: T,
    cross: &mut nalgebra::SVector<T, STATES>,
) {
    let next = transition_times(f, dt_s, cross);
    *cross = if next.iter().all(|v| v.is_finite()) {
        next
    } else {
        nalgebra::SVector::zeros()
    };
}

#[cfg(test)]
#[path = "error_model_tests.rs"]
mod tests;

//! The structurally non-zero entries of the 17-state error model's F (module
//! `error_model`), the layout the generated covariance step (`generated::predict17`) reads
//! entry by entry, and the dense 9×15 block they form.

use super::mechanization::{Ins, Kinematics, Position, PositionKinematics};
use crate::math::rotation::skew;
use crate::Real;
use nalgebra::{Matrix3, SMatrix, Vector3};

/// The non-zero block `F[0..9, 0..15]` of the error-model matrix (module doc).
pub type FBlock<T> = SMatrix<T, 9, 15>;

/// The structurally non-zero entries of F (module doc), 61 of the 9×15 block (nine of them
/// held at zero: left out of the prediction, `NEGLIGIBLE` in xtask/src/gen.rs):
///
/// ```text
/// rows δL, δl:  F00 F02 F03 / F10 F12 F14       row δh: F25 (= −1)
/// rows δV:      [vel_lat  vel_h  vel_vel  [f_ned×]  C_b^n   0    ]   (cols L, h, V, φ, ∇, ε)
/// rows φ:       [att_lat  att_h  W_v      −[w_in×]  0      −C_b^n]
/// W_v = ∂ω_in/∂V: (φ_N, V_E) = att_v[0], (φ_E, V_N) = att_v[1], (φ_D, V_E) = att_v[2]
/// ```
///
/// [`SparseF::scaled`] gives `G = F Δt` in the same layout, which the generated covariance
/// step ([`propagate_covariance_sparse`](super::propagate_covariance_sparse)) reads entry by entry.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SparseF<T> {
    pub(super) f00: T,
    pub(super) f02: T,
    pub(super) f03: T,
    pub(super) f10: T,
    pub(super) f12: T,
    pub(super) f14: T,
    pub(super) f25: T,
    pub(super) vel_lat: Vector3<T>,
    pub(super) vel_h: Vector3<T>,
    pub(super) vel_vel: Matrix3<T>,
    pub(super) f_ned: Vector3<T>,
    pub(super) c_b_n: Matrix3<T>,
    pub(super) att_lat: Vector3<T>,
    pub(super) att_h: Vector3<T>,
    pub(super) att_v: Vector3<T>,
    pub(super) w_in: Vector3<T>,
}

impl<T: Real> SparseF<T> {
    /// F at a navigation state (arguments as [`f_block`](super::f_block)); one `sin`/`cos` pair and one `sqrt`.
    pub fn new(
        pos: &Position,
        v: &Vector3<T>,
        c_b_n: &Matrix3<T>,
        f_ned_m_s2: &Vector3<T>,
    ) -> Self {
        Self::at(&Kinematics::new(pos, v), v, c_b_n, f_ned_m_s2)
    }

    /// [`SparseF::new`] from the kinematics `k` of the state (velocity `v`, m/s), built from the
    /// radii the INS step evaluated
    /// ([`Ins::step_keeping_radii`](super::mechanization::Ins::step_keeping_radii)): no
    /// `sin`/`cos` or `sqrt` of its own.
    pub(crate) fn at(
        k: &Kinematics<T>,
        v: &Vector3<T>,
        c_b_n: &Matrix3<T>,
        f_ned_m_s2: &Vector3<T>,
    ) -> Self {
        let z = T::zero();
        let inv_m = T::one() / k.rm_h;
        let inv_n = T::one() / k.rn_h;
        let sec = T::one() / k.cos_lat;
        let tan = k.sin_lat * sec;
        let w = T::lit(crate::earth::EARTH_RATE_RAD_S);
        // ∂ω_ie/∂L (only column L).
        let dwie_dl = Vector3::new(-w * k.sin_lat, z, -w * k.cos_lat);
        // ∂ω_en/∂(L, h) as columns, ∂ω_en/∂V.
        let inv_n2 = inv_n * inv_n;
        let inv_m2 = inv_m * inv_m;
        let dwen_dlat = Vector3::new(
            -v.y * inv_n2 * k.drn_dlat,
            v.x * inv_m2 * k.drm_dlat,
            -v.y * sec * sec * inv_n + v.y * tan * inv_n2 * k.drn_dlat,
        );
        let dwen_dh = Vector3::new(-v.y * inv_n2, v.x * inv_m2, v.y * tan * inv_n2);
        let dwen_dv = Matrix3::new(z, inv_n, z, -inv_m, z, z, z, -tan * inv_n, z);
        // Velocity rows: [V×] δρ with δρ = 2 δω_ie + δω_en.
        let vx = skew(v);
        let drho_dlat = dwie_dl * T::lit(2.0) + dwen_dlat;
        let mut vel_lat = vx * drho_dlat;
        let mut vel_h = vx * dwen_dh;
        let rho = k.w_ie * T::lit(2.0) + k.w_en;
        // Gravity gradient (module earth: g = g0(L)(1 − (c1 + c1' sin²L) h + c2 h²)).
        // 1/√(1 − e² sin²L) = R_N / a from the radius the kinematics already has (one square
        // root fewer; R_N = (R_N + h) − h to 1e-7).
        let inv_sqrt_d = (k.rn_h - k.alt_m) * T::lit(1.0 / crate::earth::SEMI_MAJOR_AXIS_M);
        let (dg_dlat, dg_dh) = gravity_gradient(k.sin_lat, k.cos_lat, k.alt_m, inv_sqrt_d);
        vel_lat.z += dg_dlat;
        vel_h.z += dg_dh;
        // The entries the prediction leaves out (`NEGLIGIBLE` of the generator,
        // xtask/src/gen.rs, with their bounds) are zero: ∂L̇/∂L and its attitude counterpart
        // (v.x / (R_M + h)² · dR_M/dL), and the height column but for the gravity gradient.
        let att_lat = dwie_dl + dwen_dlat;
        Self {
            f00: z,
            f02: z,
            f03: inv_m,
            f10: v.y * tan * sec * inv_n - v.y * sec * inv_n2 * k.drn_dlat,
            f12: z,
            f14: sec * inv_n,
            f25: -T::one(),
            vel_lat,
            vel_h: Vector3::new(z, z, vel_h.z),
            vel_vel: vx * dwen_dv - skew(&rho),
            f_ned: *f_ned_m_s2,
            c_b_n: *c_b_n,
            att_lat: Vector3::new(att_lat.x, z, att_lat.z),
            att_h: Vector3::zeros(),
            att_v: Vector3::new(inv_n, -inv_m, -tan * inv_n),
            w_in: k.w_ie + k.w_en,
        }
    }

    /// F at the state of `ins` with the radii `radii` its last step kept (no `sin`/`cos`,
    /// `sqrt` or f64 conversion; [`Ins::step_keeping_radii`]; `None`: evaluated at its
    /// position) and the mean specific force of the interval, `dv_ned_m_s / dt_s` (m/s, s).
    /// Not inlined: its temporaries are not in the covariance step's frame, under which the
    /// kernel runs.
    #[inline(never)]
    pub(super) fn at_ins(
        ins: &Ins<T>,
        radii: Option<&PositionKinematics<T>>,
        dv_ned_m_s: &Vector3<T>,
        dt_s: T,
    ) -> Self {
        let v = &ins.state().vel_ned_m_s;
        let k = match radii {
            Some(r) => Kinematics::at(r, v),
            None => Kinematics::new(&ins.state().position, v),
        };
        Self::at(&k, v, &ins.c_b_n(), &(dv_ned_m_s / dt_s))
    }

    /// `G = F Δt` (same layout).
    pub fn scaled(&self, dt_s: T) -> Self {
        Self {
            f00: self.f00 * dt_s,
            f02: self.f02 * dt_s,
            f03: self.f03 * dt_s,
            f10: self.f10 * dt_s,
            f12: self.f12 * dt_s,
            f14: self.f14 * dt_s,
            f25: self.f25 * dt_s,
            vel_lat: self.vel_lat * dt_s,
            vel_h: self.vel_h * dt_s,
            vel_vel: self.vel_vel * dt_s,
            f_ned: self.f_ned * dt_s,
            c_b_n: self.c_b_n * dt_s,
            att_lat: self.att_lat * dt_s,
            att_h: self.att_h * dt_s,
            att_v: self.att_v * dt_s,
            w_in: self.w_in * dt_s,
        }
    }

    /// `true` when every entry is finite.
    pub fn is_finite(&self) -> bool {
        let zero = T::zero();
        let acc = (self.f00 + self.f02 + self.f03 + self.f10 + self.f12 + self.f14 + self.f25)
            * zero
            + (self.vel_lat
                + self.vel_h
                + self.f_ned
                + self.att_lat
                + self.att_h
                + self.att_v
                + self.w_in)
                .sum()
                * zero
            + (self.vel_vel + self.c_b_n).sum() * zero;
        acc == zero
    }

    /// The dense 9×15 block.
    pub fn to_block(&self) -> FBlock<T> {
        let mut f = FBlock::<T>::zeros();
        set(&mut f, 0, 0, self.f00);
        set(&mut f, 0, 2, self.f02);
        set(&mut f, 0, 3, self.f03);
        set(&mut f, 1, 0, self.f10);
        set(&mut f, 1, 2, self.f12);
        set(&mut f, 1, 4, self.f14);
        set(&mut f, 2, 5, self.f25);
        f.fixed_view_mut::<3, 1>(3, 0).copy_from(&self.vel_lat);
        f.fixed_view_mut::<3, 1>(3, 2).copy_from(&self.vel_h);
        f.fixed_view_mut::<3, 3>(3, 3).copy_from(&self.vel_vel);
        f.fixed_view_mut::<3, 3>(3, 6).copy_from(&skew(&self.f_ned));
        f.fixed_view_mut::<3, 3>(3, 9).copy_from(&self.c_b_n);
        f.fixed_view_mut::<3, 1>(6, 0).copy_from(&self.att_lat);
        f.fixed_view_mut::<3, 1>(6, 2).copy_from(&self.att_h);
        set(&mut f, 6, 4, self.att_v.x);
        set(&mut f, 7, 3, self.att_v.y);
        set(&mut f, 8, 4, self.att_v.z);
        f.fixed_view_mut::<3, 3>(6, 6)
            .copy_from(&(-skew(&self.w_in)));
        f.fixed_view_mut::<3, 3>(6, 12).copy_from(&(-self.c_b_n));
        f
    }
}

#[inline]
fn set<T: Real, const R: usize, const C: usize>(
    m: &mut SMatrix<T, R, C>,
    r: usize,
    c: usize,
    v: T,
) {
    if let Some(x) = m.get_mut((r, c)) {
        *x = v;
    }
}

/// `(∂g/∂L, ∂g/∂h)` of the normal gravity model in [`crate::earth::normal_gravity_m_s2`]
/// (`g = g0(L) (1 − (c1 + c1' sin²L) h + c2 h²)`, `g0` Somigliana), in closed form:
/// m/s² per rad and 1/s². `s`, `c`: sin and cos of the latitude; `h`: height, m;
/// `inv_sqrt_d`: `1/√(1 − e² s²)` (dimensionless; the caller has it from R_N).
fn gravity_gradient<T: Real>(s: T, c: T, h: T, inv_sqrt_d: T) -> (T, T) {
    use crate::earth::{
        EARTH_RATE_RAD_S, ECCENTRICITY_SQ, FLATTENING, GM_M3_S2, GRAVITY_EQUATOR_M_S2,
        SEMI_MAJOR_AXIS_M, SEMI_MINOR_AXIS_M, SOMIGLIANA_K,
    };
    let a = SEMI_MAJOR_AXIS_M;
    let m = EARTH_RATE_RAD_S * EARTH_RATE_RAD_S * a * a * SEMI_MINOR_AXIS_M / GM_M3_S2;
    let c1 = T::lit(2.0 / a * (1.0 + FLATTENING + m));
    let c1_lat = T::lit(2.0 / a * (-2.0 * FLATTENING));
    let c2 = T::lit(3.0 / (a * a));
    let s2 = s * s;
    let k = T::lit(SOMIGLIANA_K);
    let e2 = T::lit(ECCENTRICITY_SQ);
    let d = T::one() - e2 * s2;
    let ge = T::lit(GRAVITY_EQUATOR_M_S2);
    let g0 = ge * (T::one() + k * s2) * inv_sqrt_d;
    let dg0 = ge * s * c * (T::lit(2.0) * k + (T::one() + k * s2) * e2 / d) * inv_sqrt_d;
    let alt_factor = T::one() - (c1 + c1_lat * s2) * h + c2 * h * h;
    (
        dg0 * alt_factor - g0 * c1_lat * T::lit(2.0) * s * c * h,
        g0 * (T::lit(2.0) * c2 * h - c1 - c1_lat * s2),
    )
}

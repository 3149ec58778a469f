//! Line-of-sight measurement from the seeker gimbal angles and a known landmark
//! (seed eqs. 4-23, spec "Measurement").
//!
//! Seeker frame s: x along the boresight, reached from b by yaw ψ_s about z then pitch θ_s
//! about the new y, so the LOS in body axes is
//! `u_b(θ_s, ψ_s) = C_s^b [1 0 0]ᵀ = [cos θ_s cos ψ_s, cos θ_s sin ψ_s, −sin θ_s]`.
//!
//! * `ê_gimbal = Ĉ_b^n u_b(θ̃_s, ψ̃_s)`: INS attitude and the measured (bias-corrected) gimbal
//!   angles; measured = true + `δθ_s`/`δψ_s` (random constant) + white noise.
//! * `ê_landmark = D̂ / |D̂|`, `D̂` the vector from the INS position to the landmark in the INS
//!   NED frame. It is computed exactly from the WGS-84 ECEF difference (the seed's flat
//!   `T (p_lm − p)` with `T = diag(R_M+h, (R_N+h) cos L, −1)` misses the earth's curvature:
//!   the landmark 70 km away lies ≈ 385 m lower than the flat formula says, 0.3°, twice the
//!   seeker noise).
//!
//! ## The two open points of the spec, settled
//!
//! 1. **2-D residual.** `ê_landmark − ê_gimbal` is a difference of two unit vectors: to first
//!    order it lies in the plane normal to the LOS, so its 3×3 covariance has rank 2 and a
//!    3-vector update with a full-rank R would invent information along the LOS (or, with R
//!    inflated to full rank, mis-weight it). The residual is therefore projected on the two
//!    unit directions in which the gimbal angles move the LOS:
//!    `n_θ = Ĉ_b^n ∂u_b/∂θ_s = Ĉ_b^n [−sθ cψ, −sθ sψ, −cθ]` and
//!    `n_ψ = Ĉ_b^n (∂u_b/∂ψ_s)/cos θ_s = Ĉ_b^n [−sψ, cψ, 0]` (orthonormal, both ⟂ ê_gimbal):
//!    `z = [n_θ, n_ψ]ᵀ (ê_landmark − ê_gimbal)`, two scalars fused sequentially. The gimbal
//!    white noise σ (per angle) maps to `R = diag(σ², σ² cos² θ_s)` exactly (to first order),
//!    and the two components are uncorrelated, so the scalar updates are exact.
//! 2. **Jacobians** (checked against finite differences of this nonlinear residual in tests):
//!    with `P⊥ = I − ê_L ê_Lᵀ`, `r = |D̂|`, and `δD = (−T + [D×] M) δp`, where
//!    `M = [[0, cos L, 0], [−1, 0, 0], [0, −sin L, 0]]` is the rotation of the NED frame with
//!    the position error (the seed keeps only `−T`),
//!    ```text
//!    H1 (δL, δl, δh)   = n_iᵀ P⊥ (−T + [D×] M) / r
//!    H3 (φ)            = −n_iᵀ [ê_G ×]          (ê_G − e ≈ ê_G × φ for Ĉ = (I − [φ×]) C)
//!    H6 (δθ_s, δψ_s)   = [−1, 0] for n_θ, [0, −cos θ_s] for n_ψ
//!    ```
//!    so `z ≈ [H1 0 H3 0 0 H6] δx + v` (seed eq. 4 with its sign convention).

use super::error_model::{ATT, GIMBAL, POS, STATES};
use super::mechanization::{Kinematics, Position};
use crate::earth::{ECCENTRICITY_SQ, SEMI_MAJOR_AXIS_M};
use crate::math::rotation::skew;
use crate::math::trig;
use crate::{NavError, Real};
use nalgebra::{Matrix3, SVector, Vector2, Vector3};

/// Largest accepted |gimbal pitch| for an update, rad (80°): near ±90° the yaw angle no longer
/// moves the LOS and its noise maps to nothing.
pub const MAX_GIMBAL_PITCH_RAD: f64 = 1.396_263_4;

/// Seeker gimbal angles (b → s: yaw about z, then pitch about the new y).
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct GimbalAngles<T> {
    /// Gimbal pitch θ_s, rad (positive nose-up: LOS above the body x-y plane).
    pub pitch_rad: T,
    /// Gimbal yaw ψ_s, rad (positive to the right).
    pub yaw_rad: T,
}

/// LOS unit vector in body axes from gimbal angles, `u_b = C_s^b [1 0 0]ᵀ`.
pub fn los_body<T: Real>(g: &GimbalAngles<T>) -> Vector3<T> {
    let (st, ct) = trig::sin_cos(g.pitch_rad);
    let (sp, cp) = trig::sin_cos(g.yaw_rad);
    Vector3::new(ct * cp, ct * sp, -st)
}

/// Gimbal angles that point the boresight along the body-axes direction `u_b` (any length > 0).
pub fn gimbal_angles_of<T: Real>(u_b: &Vector3<T>) -> GimbalAngles<T> {
    let horiz = (u_b.x * u_b.x + u_b.y * u_b.y).sqrt();
    GimbalAngles {
        pitch_rad: (-u_b.z).atan2(horiz),
        yaw_rad: u_b.y.atan2(u_b.x),
    }
}

/// A landmark of known geodetic position, with the quantities the LOS needs precomputed.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Landmark<T> {
    position: Position,
    /// (R_N + h) cos L of the landmark: distance from the earth's axis, m.
    axis_distance_m: T,
    /// sin L, cos L of the landmark.
    sin_lat: T,
    cos_lat: T,
    /// Transverse radius R_N at the landmark, m.
    rn_m: T,
    /// √(1 − e² sin² L) at the landmark.
    sqrt_d: T,
}

/// Shortest range to the landmark (from the INS position) at which [`super::SeekerIns`] fuses
/// a LOS, m. Closer, the direction to the landmark is dominated by the position error (and
/// meaningless at the landmark itself): the update is skipped
/// ([`super::LosSkipReason::LandmarkTooClose`]).
pub const MIN_LANDMARK_RANGE_M: f64 = 100.0;

impl<T: Real> Landmark<T> {
    /// Landmark at a geodetic position. Errors: `InvalidConfig` for a non-finite or
    /// out-of-range position (|L| < 86°, |h| < 1000 km).
    pub fn new(position: Position) -> Result<Self, NavError> {
        if !position.is_in_range() {
            return Err(NavError::InvalidConfig {
                field: "landmark position",
                issue: crate::error::ConfigIssue::OutOfRange,
            });
        }
        // In T, as the vehicle's side of [`landmark_vector_ned`] is: these enter it only
        // through products with small differences, where a few ε of relative error is
        // micrometres. (In f64 on the target this linked the soft-float sine with its
        // large-argument reduction, ≈ 7 kB of flash, for a constructor that runs once.)
        let (lat, alt) = super::mechanization::model_lat_alt::<T>(&position);
        let (s, c) = trig::sin_cos(lat);
        let sqrt_d = (T::one() - T::lit(ECCENTRICITY_SQ) * s * s).sqrt();
        let rn = T::lit(SEMI_MAJOR_AXIS_M) / sqrt_d;
        Ok(Self {
            position,
            axis_distance_m: (rn + alt) * c,
            sin_lat: s,
            cos_lat: c,
            rn_m: rn,
            sqrt_d,
        })
    }

    /// Geodetic position of the landmark.
    pub fn position(&self) -> &Position {
        &self.position
    }
}

/// Vector D from `pos` to the landmark resolved in the NED frame at `pos`, m (exact on the
/// WGS-84 ellipsoid: ECEF difference, rotated into NED).
///
/// Precision independent of the absolute position: the latitude, longitude and altitude
/// differences are formed in `f64` (where the positions are kept) and are small numbers in
/// `T`; the ECEF difference is then written in terms of them without cancellation
/// (`sin L₂ − sin L₁ = 2 cos L̄ sin(ΔL/2)`, `cos L₂ − cos L₁ = −2 sin L̄ sin(ΔL/2)`,
/// `R_N₂ − R_N₁` from the difference of `1 − e² sin² L`, `cos Δl − 1 = −2 sin²(Δl/2)`), so the
/// error is a few ε of |D| (in `f32`: micrometres at 100 m) instead of ε of the earth radius
/// (0.5 m in `f32` when the two ECEF positions are formed and subtracted).
pub fn landmark_vector_ned<T: Real>(pos: &Position, lm: &Landmark<T>) -> Vector3<T> {
    let one = T::one();
    let half = T::lit(0.5);
    let two = T::lit(2.0);
    let e2 = T::lit(ECCENTRICITY_SQ);
    let a = T::lit(crate::earth::SEMI_MAJOR_AXIS_M);
    // Differences in f64, small numbers in T.
    let d_lat = T::lit(lm.position.lat_rad - pos.lat_rad);
    let d_lon = T::lit(wrap_pi(lm.position.lon_rad - pos.lon_rad));
    let d_alt = T::lit(lm.position.alt_m - pos.alt_m);
    let (lat, h) = super::mechanization::model_lat_alt::<T>(pos);
    let (sl, cl) = trig::sin_cos(lat);
    let half_dlat = half * d_lat;
    let (sm, cm) = trig::sin_cos(lat + half_dlat);
    let sh = trig::sin(half_dlat);
    // sin L_lm − sin L, cos L_lm − cos L.
    let ds = two * cm * sh;
    let dc = -two * sm * sh;
    // R_N at the vehicle and R_N(lm) − R_N = R_N(lm) R_N (1/R_N − 1/R_N(lm)).
    let sqrt_d = (one - e2 * sl * sl).sqrt();
    let rn = a / sqrt_d;
    let d_rn = lm.rn_m * rn * e2 * ds * (lm.sin_lat + sl) / (a * (sqrt_d + lm.sqrt_d));
    // Differences of the axis distance (R_N + h) cos L and of ECEF z (R_N (1 − e²) + h) sin L.
    let d_axis = (d_rn + d_alt) * lm.cos_lat + (rn + h) * dc;
    let dz = ((one - e2) * d_rn + d_alt) * lm.sin_lat + (rn * (one - e2) + h) * ds;
    // ECEF rotated about z by −l (vehicle in the x-z plane):
    // dx = A_lm cos Δl − A = (A_lm − A) − 2 A_lm sin²(Δl/2), dy = A_lm sin Δl.
    let (shl, chl) = trig::sin_cos(half * d_lon);
    let dx = d_axis - two * lm.axis_distance_m * shl * shl;
    let dy = two * lm.axis_distance_m * shl * chl;
    Vector3::new(-sl * dx + cl * dz, dy, -cl * dx - sl * dz)
}

/// Longitude difference wrapped into [−π, π] (one f64 compare in the common case; any number
/// of turns for a position that left the model range). The turns are counted with a multiply
/// by 1/(2π), not a division: the only f64 division of a flight image would otherwise link
/// the soft-float divider (920 B on the M4F) for this rare path. At a turn boundary the count
/// may differ by one from the exact quotient's, which leaves the result within a few ε of ±π
/// (the same angle for the sine and cosine it feeds).
fn wrap_pi(x: f64) -> f64 {
    use core::f64::consts::{FRAC_1_PI, PI};
    let turns_per_rad = 0.5 * FRAC_1_PI;
    if x > PI {
        x - 2.0 * PI * libm::floor((x + PI) * turns_per_rad)
    } else if x < -PI {
        x + 2.0 * PI * libm::floor((PI - x) * turns_per_rad)
    } else {
        x
    }
}

/// The linearised LOS measurement at the current estimate.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosModel<T> {
    /// Residual `z = [n_θ, n_ψ]ᵀ (ê_landmark − ê_gimbal)`, rad (small-angle LOS differences
    /// along the gimbal pitch and yaw directions).
    pub residual_rad: Vector2<T>,
    /// Row of H for the pitch-direction component (H1, H3, H6 in their columns).
    pub h_pitch: SVector<T, STATES>,
    /// Row of H for the yaw-direction component.
    pub h_yaw: SVector<T, STATES>,
    /// Measurement noise variances `[σ², σ² cos² θ_s]`, rad².
    pub variance_rad2: Vector2<T>,
    /// Range to the landmark from the INS position, m.
    pub range_m: T,
    /// ê_landmark in NED.
    pub los_landmark_ned: Vector3<T>,
    /// ê_gimbal in NED.
    pub los_gimbal_ned: Vector3<T>,
}

/// Builds the residual, H and R (module doc) at the INS position `pos`, attitude `c_b_n`
/// and bias-corrected gimbal angles, for a seeker white noise `sigma_rad` (1σ per angle, rad).
///
/// Errors: `NonFiniteInput`, `InputOutOfRange` (|θ_s| > 80°, |ψ_s| > π, σ ≤ 0, range below
/// [`MIN_LANDMARK_RANGE_M`]).
pub fn los_model<T: Real>(
    pos: &Position,
    c_b_n: &Matrix3<T>,
    gimbal: &GimbalAngles<T>,
    lm: &Landmark<T>,
    sigma_rad: T,
) -> Result<LosModel<T>, NavError> {
    validate_gimbal(gimbal, sigma_rad)?;
    let d = landmark_vector_ned(pos, lm);
    let range = d.norm();
    if !range.is_finite() || range < T::lit(MIN_LANDMARK_RANGE_M) {
        return Err(NavError::InputOutOfRange {
            input: "landmark range",
        });
    }
    los_model_at(pos, &d, c_b_n, gimbal, sigma_rad)
}

/// Checks a gimbal measurement and the seeker σ: `NonFiniteInput`, `InputOutOfRange`
/// (|θ_s| > 80°, |ψ_s| > π, σ not finite and > 0).
pub fn validate_gimbal<T: Real>(gimbal: &GimbalAngles<T>, sigma_rad: T) -> Result<(), NavError> {
    if !(gimbal.pitch_rad.is_finite() && gimbal.yaw_rad.is_finite()) {
        return Err(NavError::NonFiniteInput {
            input: "gimbal angles",
        });
    }
    if gimbal.pitch_rad.abs() > T::lit(MAX_GIMBAL_PITCH_RAD) {
        return Err(NavError::InputOutOfRange {
            input: "gimbal pitch",
        });
    }
    if gimbal.yaw_rad.abs() > T::lit(core::f64::consts::PI) {
        return Err(NavError::InputOutOfRange {
            input: "gimbal yaw",
        });
    }
    if !sigma_rad.is_finite() || sigma_rad <= T::zero() {
        return Err(NavError::InputOutOfRange {
            input: "seeker noise sigma",
        });
    }
    Ok(())
}

/// [`los_model`] with the landmark vector `d` (NED, m, from [`landmark_vector_ned`]) already
/// computed; any range > 0 is accepted (the caller applies its minimum range).
pub fn los_model_at<T: Real>(
    pos: &Position,
    d: &Vector3<T>,
    c_b_n: &Matrix3<T>,
    gimbal: &GimbalAngles<T>,
    sigma_rad: T,
) -> Result<LosModel<T>, NavError> {
    validate_gimbal(gimbal, sigma_rad)?;
    let d = *d;
    let range = d.norm();
    if !range.is_finite() || range <= T::zero() {
        return Err(NavError::InputOutOfRange {
            input: "landmark range",
        });
    }
    let e_l = d / range;
    let (st, ct) = trig::sin_cos(gimbal.pitch_rad);
    let (sp, cp) = trig::sin_cos(gimbal.yaw_rad);
    let e_g = c_b_n * Vector3::new(ct * cp, ct * sp, -st);
    let n_th = c_b_n * Vector3::new(-st * cp, -st * sp, -ct);
    let n_ps = c_b_n * Vector3::new(-sp, cp, T::zero());
    let diff = e_l - e_g;
    // δD/δp = −T + [D×] M.
    let k = Kinematics::new(pos, &Vector3::zeros());
    let z = T::zero();
    let t = Matrix3::new(k.rm_h, z, z, z, k.rn_h * k.cos_lat, z, z, z, -T::one());
    let m = Matrix3::new(z, k.cos_lat, z, -T::one(), z, z, z, -k.sin_lat, z);
    let dd_dp = skew(&d) * m - t;
    let p_perp = Matrix3::identity() - e_l * e_l.transpose();
    let inv_r = T::one() / range;
    let row = |n: &Vector3<T>, gimbal_cols: Vector2<T>| {
        let mut h = SVector::<T, STATES>::zeros();
        let h1 = (n.transpose() * p_perp * dd_dp) * inv_r;
        let h3 = e_g.cross(n);
        h.fixed_rows_mut::<3>(POS).copy_from(&h1.transpose());
        h.fixed_rows_mut::<3>(ATT).copy_from(&h3);
        h.fixed_rows_mut::<2>(GIMBAL).copy_from(&gimbal_cols);
        h
    };
    let s2 = sigma_rad * sigma_rad;
    let model = LosModel {
        residual_rad: Vector2::new(n_th.dot(&diff), n_ps.dot(&diff)),
        h_pitch: row(&n_th, Vector2::new(-T::one(), z)),
        h_yaw: row(&n_ps, Vector2::new(z, -ct)),
        variance_rad2: Vector2::new(s2, s2 * ct * ct),
        range_m: range,
        los_landmark_ned: e_l,
        los_gimbal_ned: e_g,
    };
    let finite = crate::math::checks::all_finite_parts(&[
        model.residual_rad.as_slice(),
        model.h_pitch.as_slice(),
        model.h_yaw.as_slice(),
    ]);
    if !finite {
        return Err(NavError::NonFiniteInput {
            input: "LOS geometry",
        });
    }
    Ok(model)
}

/// The alternative the spec mentions: the full 3-vector residual `ê_landmark − ê_gimbal`
/// (NED components) with a full-rank `R = σ² I₃`, fused as three scalar updates.
///
/// Kept for comparison with [`los_model`] (scenario option `residual = "full-rank-3d"`): the
/// true noise covariance of this residual is `σ² (n_θ n_θᵀ + cos²θ_s n_ψ n_ψᵀ)`, of rank 2;
/// `σ² I₃` adds a fictitious σ² along the LOS (where the residual and its H row are ≈ 0, so
/// that component carries almost no information) and over-weights the yaw direction by
/// `1/cos² θ_s`. Rows: `H1 = P⊥ (−T + [D×] M)/r`, `H3 = −[ê_G ×]`, `H6 = [−n_θ, −cos θ_s n_ψ]`.
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LosModel3<T> {
    /// Residual `ê_landmark − ê_gimbal` in NED (dimensionless, ≈ rad).
    pub residual: Vector3<T>,
    /// H rows of the N, E, D components.
    pub h_north: SVector<T, STATES>,
    /// H row of E.
    pub h_east: SVector<T, STATES>,
    /// H row of D.
    pub h_down: SVector<T, STATES>,
    /// σ², rad² (the same for every component).
    pub variance_rad2: T,
    /// Range to the landmark, m.
    pub range_m: T,
}

/// Builds the 3-vector residual model [`LosModel3`]; same inputs and errors as [`los_model`].
pub fn los_model_3d<T: Real>(
    pos: &Position,
    c_b_n: &Matrix3<T>,
    gimbal: &GimbalAngles<T>,
    lm: &Landmark<T>,
    sigma_rad: T,
) -> Result<LosModel3<T>, NavError> {
    // Validation and the shared geometry come from the 2-D model.
    let m2 = los_model(pos, c_b_n, gimbal, lm, sigma_rad)?;
    let (st, ct) = trig::sin_cos(gimbal.pitch_rad);
    let (sp, cp) = trig::sin_cos(gimbal.yaw_rad);
    let n_th = c_b_n * Vector3::new(-st * cp, -st * sp, -ct);
    let n_ps = c_b_n * Vector3::new(-sp, cp, T::zero());
    let d = landmark_vector_ned(pos, lm);
    let e_l = m2.los_landmark_ned;
    let e_g = m2.los_gimbal_ned;
    let k = Kinematics::new(pos, &Vector3::zeros());
    let z = T::zero();
    let t = Matrix3::new(k.rm_h, z, z, z, k.rn_h * k.cos_lat, z, z, z, -T::one());
    let m = Matrix3::new(z, k.cos_lat, z, -T::one(), z, z, z, -k.sin_lat, z);
    let h1 = (Matrix3::identity() - e_l * e_l.transpose()) * (skew(&d) * m - t) / m2.range_m;
    let h3 = -skew(&e_g);
    let h6a = -n_th;
    let h6b = -n_ps * ct;
    let row = |i: usize| {
        let mut h = SVector::<T, STATES>::zeros();
        h.fixed_rows_mut::<3>(POS).copy_from(&h1.row(i).transpose());
        h.fixed_rows_mut::<3>(ATT).copy_from(&h3.row(i).transpose());
        let g = Vector2::new(*h6a.get(i).unwrap_or(&z), *h6b.get(i).unwrap_or(&z));
        h.fixed_rows_mut::<2>(GIMBAL).copy_from(&g);
        h
    };
    Ok(LosModel3 {
        residual: e_l - e_g,
        h_north: row(0),
        h_east: row(1),
        h_down: row(2),
        variance_rad2: sigma_rad * sigma_rad,
        range_m: m2.range_m,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::rotation::{euler_to_dcm, exp_so3};

    fn geometry() -> (Position, Landmark<f64>, Matrix3<f64>, GimbalAngles<f64>) {
        let pos = Position {
            lat_rad: 37f64.to_radians(),
            lon_rad: 127f64.to_radians(),
            alt_m: 1000.0,
        };
        let lm = Landmark::new(Position {
            lat_rad: pos.lat_rad + 2000.0 / 6.36e6,
            lon_rad: pos.lon_rad + 70_000.0 / (6.39e6 * pos.lat_rad.cos()),
            alt_m: 0.0,
        })
        .unwrap();
        let c = euler_to_dcm(0.3, 0.05, 1.2);
        let d = landmark_vector_ned(&pos, &lm);
        let g = gimbal_angles_of(&(c.transpose() * d));
        (pos, lm, c, g)
    }

    #[test]
    fn true_geometry_gives_zero_residual_and_curvature_is_modelled() {
        let (pos, lm, c, g) = geometry();
        let m = los_model(&pos, &c, &g, &lm, 0.003).unwrap();
        assert!(m.residual_rad.norm() < 1e-12);
        // Range ≈ √(70² + 2² + 1²) km, and the landmark lies below the flat-earth estimate
        // by ≈ d²/(2R) ≈ 385 m.
        let d = landmark_vector_ned(&pos, &lm);
        assert!((d.norm() - 70_036.0).abs() < 200.0, "{}", d.norm());
        assert!(d.z > 1000.0 + 300.0 && d.z < 1000.0 + 450.0, "{}", d.z);
        // f32 agrees with f64 to well below the seeker noise.
        let lm32 = Landmark::<f32>::new(*lm.position()).unwrap();
        let d32 = landmark_vector_ned(&pos, &lm32);
        let ang = (d32.cast::<f64>().normalize() - d.normalize()).norm();
        assert!(ang < 2e-5, "{ang}");
    }

    /// H1, H3, H6 against central differences of the nonlinear residual with the truth
    /// perturbed by each error component (basis n_θ, n_ψ frozen at the nominal point).
    #[test]
    fn h_matches_finite_differences() {
        let (pos, lm, c, g) = geometry();
        let m = los_model(&pos, &c, &g, &lm, 0.003).unwrap();
        let (st, ct) = (g.pitch_rad.sin(), g.pitch_rad.cos());
        let (sp, cp) = (g.yaw_rad.sin(), g.yaw_rad.cos());
        let n_th = c * Vector3::new(-st * cp, -st * sp, -ct);
        let n_ps = c * Vector3::new(-sp, cp, 0.0);
        let resid = |dx: &SVector<f64, STATES>| -> Vector2<f64> {
            let p_hat = Position {
                lat_rad: pos.lat_rad + dx[0],
                lon_rad: pos.lon_rad + dx[1],
                alt_m: pos.alt_m + dx[2],
            };
            let c_hat = exp_so3(&(-dx.fixed_rows::<3>(ATT).into_owned())) * c;
            let g_meas = GimbalAngles {
                pitch_rad: g.pitch_rad + dx[GIMBAL],
                yaw_rad: g.yaw_rad + dx[GIMBAL + 1],
            };
            let e_l = landmark_vector_ned(&p_hat, &lm).normalize();
            let e_g = c_hat * los_body(&g_meas);
            Vector2::new(n_th.dot(&(e_l - e_g)), n_ps.dot(&(e_l - e_g)))
        };
        let steps = [
            1e-6, 1e-6, 10.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1e-4,
            1e-4,
        ];
        for (j, &h) in steps.iter().enumerate() {
            let mut dx = SVector::<f64, STATES>::zeros();
            dx[j] = h;
            let col = (resid(&dx) - resid(&(-dx))) / (2.0 * h);
            for (row, hrow) in [(col.x, &m.h_pitch), (col.y, &m.h_yaw)] {
                let scale = hrow.abs().max();
                let tol = 1e-6 * scale;
                assert!(
                    (row - hrow[j]).abs() <= tol,
                    "H[{j}] = {:e}, finite difference {:e}",
                    hrow[j],
                    row
                );
            }
        }
        // The seed's flat T alone (no frame rotation) would be off by ≈ 1 % in H1.
        assert!(m.h_pitch.fixed_rows::<3>(POS).norm() > 0.0);
    }

    #[test]
    fn bad_inputs_are_refused() {
        let (pos, lm, c, g) = geometry();
        let mut bad = g;
        bad.pitch_rad = f64::NAN;
        assert!(los_model(&pos, &c, &bad, &lm, 0.003).is_err());
        bad.pitch_rad = 1.5;
        assert!(los_model(&pos, &c, &bad, &lm, 0.003).is_err());
        assert!(los_model(&pos, &c, &g, &lm, 0.0).is_err());
        let at_lm = *lm.position();
        assert!(los_model(&at_lm, &c, &g, &lm, 0.003).is_err());
        assert!(Landmark::<f32>::new(Position {
            lat_rad: f64::NAN,
            lon_rad: 0.0,
            alt_m: 0.0
        })
        .is_err());
    }

    #[test]
    fn h3d_matches_finite_differences() {
        let (pos, lm, c, g) = geometry();
        let m = los_model_3d(&pos, &c, &g, &lm, 0.003).unwrap();
        let resid = |dx: &SVector<f64, STATES>| -> Vector3<f64> {
            let p_hat = Position {
                lat_rad: pos.lat_rad + dx[0],
                lon_rad: pos.lon_rad + dx[1],
                alt_m: pos.alt_m + dx[2],
            };
            let c_hat = exp_so3(&(-dx.fixed_rows::<3>(ATT).into_owned())) * c;
            let g_meas = GimbalAngles {
                pitch_rad: g.pitch_rad + dx[GIMBAL],
                yaw_rad: g.yaw_rad + dx[GIMBAL + 1],
            };
            landmark_vector_ned(&p_hat, &lm).normalize() - c_hat * los_body(&g_meas)
        };
        let steps = [1e-6, 1e-6, 10.0, 1.0, 1.0, 1.0, 1e-4, 1e-4, 1e-4];
        for j in [0usize, 1, 2, 6, 7, 8, 15, 16] {
            let h = if j >= GIMBAL { 1e-4 } else { steps[j] };
            let mut dx = SVector::<f64, STATES>::zeros();
            dx[j] = h;
            let col = (resid(&dx) - resid(&(-dx))) / (2.0 * h);
            for (i, hrow) in [&m.h_north, &m.h_east, &m.h_down].iter().enumerate() {
                let tol = 1e-6 * hrow.abs().max();
                assert!((col[i] - hrow[j]).abs() <= tol, "H3d[{i},{j}]");
            }
        }
    }
}

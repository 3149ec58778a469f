//! The `f32` sine and cosine kernel: plain `f32` arithmetic, no dependency on the rest of the
//! crate (the [`crate::Real`] implementation for `f32` calls it; [`crate::math::trig`] is the API).
//!
//! libm's `sinf`/`cosf` evaluate in `f64` (software floating point on a Cortex-M4F, ≈ 1 200
//! instructions a call) and link the Payne-Hanek reduction `rem_pio2_large` for huge arguments:
//! ≈ 8 KB of flash for angles that in this crate never exceed a few radians. Here `f32` uses
//!
//! 1. a Cody-Waite reduction by π/2: `k = round(x·2/π)`, `r = x − k·π/2` with π/2 split into
//!    four `f32` parts `P1 + P2 + P3 + P4` (Cephes style); `P1`, `P2`, `P3` have at most 11
//!    significant bits so `k·P1`, `k·P2`, `k·P3` are exact for |k| < 2¹³ and the subtractions are
//!    exact (Sterbenz), only `k·P4` and the last subtraction round, and the rounding error of
//!    that subtraction is kept (`r_lo`, Fast2Sum) and fed to the polynomials to first order;
//!    |x| ≤ π/4 skips the reduction (bit-identical, cheaper);
//! 2. the Cephes `sinf`/`cosf` minimax polynomials on [−π/4, π/4] (degree 7 odd / degree 8
//!    even), the cosine's leading `1 − r²/2` with the rounding error of the subtraction added
//!    back (as FreeBSD's `k_cosf`);
//! 3. the quadrant `k mod 4` selecting ±sin r / ±cos r.
//!
//! # Domain and accuracy (`f32`)
//!
//! * |x| ≤ [`F32_ACCURATE_DOMAIN_RAD`] = 8192 rad: error ≤ 2 ulp of the correctly rounded
//!   result (measured exhaustively over every positive `f32` ≤ 8192 against `f64` libm: max
//!   1.57 ulp for sin, 1.62 ulp for cos; 0.81 / 0.82 ulp on [0, π/4] where there is no
//!   reduction; the module tests guard it with dense grids, random points and the neighbours
//!   of every multiple of π/2); odd/even symmetry exact (`sin(−x) = −sin x`, `cos(−x) = cos x`
//!   bit for bit for x ≠ 0); `sin ±0 = +0`, `cos ±0 = 1` exactly; |sin² + cos² − 1| < 2.5e-7.
//! * 8192 < |x| < 2¹⁷ rad: `k·P2`, `k·P3` are no longer exact; the absolute error grows like
//!   |x|·2⁻³⁶ (measured: 2.6e-7 at 2¹⁴, 1.9e-6 at 2¹⁷). From 2¹⁷ rad `k·P1` rounds too: the
//!   error jumps to ≈ 1e-2 and reaches ≈ 0.3 at 2²²; from ≈ 2²² rad the result is meaningless.
//!   It always stays finite and in [−1, 1] (the reduced argument is clamped to [−0.8, 0.8]) —
//!   never NaN for a finite input. Angles in this crate are latitudes, attitude and gimbal
//!   angles and rotation-vector norms, all within a few radians.
//! * NaN and ±∞ give NaN (no panic).
//!
//! `f64` (host analysis) keeps calling the library (`RealField::sin`/`cos`: `std` on the host,
//! libm in `no_std`), bit-identical to the code before this module existed. The `f32` code is
//! plain `f32` arithmetic (no FMA contraction in Rust), so host and target agree bit for bit.

use core::f32::consts::FRAC_PI_4;

/// Upper bound of |x| (rad) on which the `f32` implementation keeps its ≤ 2 ulp accuracy.
pub const F32_ACCURATE_DOMAIN_RAD: f32 = 8192.0;

/// 2/π rounded to `f32`.
const TWO_OVER_PI: f32 = core::f32::consts::FRAC_2_PI;
/// 1.5·2²³: `(v + M) − M` rounds `v` to the nearest integer (ties to even) for |v| < 2²².
const ROUND_MAGIC: f32 = 12_582_912.0;
/// π/2 = P1 + P2 + P3 + P4 (+ 8e-20). P1..P3 have ≤ 11 significant bits.
const PIO2_1: f32 = 1.570_312_5; // 0x3fc9_0000
const PIO2_2: f32 = 4.837_513e-4; // 0x39fd_a000
const PIO2_3: f32 = 7.549_533_6e-8; // 0x33a2_2000
const PIO2_4: f32 = 2.563_344e-12; // 0x2c34_611a
/// Clamp of the reduced argument: > π/4 + the rounding of `k` at the domain edge (≈ 5e-4),
/// only active for |x| far beyond the accurate domain.
const R_MAX: f32 = 0.8;

// Cephes sinf/cosf minimax coefficients on [−π/4, π/4].
const S1: f32 = -1.666_665_5e-1;
const S2: f32 = 8.332_161e-3;
const S3: f32 = -1.951_529_6e-4;
const C1: f32 = 4.166_664_6e-2;
const C2: f32 = -1.388_731_6e-3;
const C3: f32 = 2.443_315_7e-5;

/// `(sin x, cos x)` in `f32` arithmetic only (module documentation: method, domain, accuracy).
pub(crate) fn sin_cos_f32(x: f32) -> (f32, f32) {
    // |x| ≤ π/4 (latitudes below 45°, most attitude angles): no reduction. The general path
    // gives bit-identical results there (k = 0, r = x); this only skips its cost. NaN fails.
    if (-FRAC_PI_4..=FRAC_PI_4).contains(&x) {
        return sin_cos_kernel(x, 0.0);
    }
    // Nearest multiple of π/2. For |x| ≥ 2²²·π/2 the sum is already an integer; ∞ stays ∞.
    let kf = (x * TWO_OVER_PI + ROUND_MAGIC) - ROUND_MAGIC;
    // Saturating conversion (NaN → 0): only the two low bits are used.
    let quadrant = (kf as i32) & 3;
    // Exact for |k| < 2¹³ (short P1..P3, Sterbenz subtractions).
    let t = ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
    let p = kf * PIO2_4;
    let mut r = t - p;
    // Rounding error of r = t − p (Fast2Sum), fed to the polynomials to first order.
    let mut r_lo = (t - r) - p;
    // Far outside the accurate domain r is garbage: keep the polynomials bounded. NaN passes.
    if r > R_MAX {
        (r, r_lo) = (R_MAX, 0.0);
    } else if r < -R_MAX {
        (r, r_lo) = (-R_MAX, 0.0);
    }
    let (s, c) = sin_cos_kernel(r, r_lo);
    match quadrant {
        0 => (s, c),
        1 => (c, -s),
        2 => (-s, -c),
        _ => (-c, s),
    }
}

/// `(sin(r + r_lo), cos(r + r_lo))` for |r| ≤ π/4, |r_lo| ≤ ulp(r) (accurate to ≈ 0.8 ulp;
/// usable to [`R_MAX`]).
#[inline(always)]
fn sin_cos_kernel(r: f32, r_lo: f32) -> (f32, f32) {
    let z = r * r;
    // sin(r + r_lo) ≈ sin r + r_lo cos r ≈ sin r + r_lo.
    let s = r + (((S3 * z + S2) * z + S1) * z * r + r_lo);
    // cos r = 1 − z/2 + z²·p(z) − r·r_lo; the rounding error of w = 1 − z/2 is added back.
    let hz = 0.5 * z;
    let w = 1.0 - hz;
    let c = w + (((1.0 - w) - hz) + (((C3 * z + C2) * z + C1) * z * z - r * r_lo));
    (s, c)
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Error of `got` in units in the last place of the `f32` nearest to `exact`.
    fn ulps(got: f32, exact: f64) -> f64 {
        let a = (exact as f32).abs().max(f32::MIN_POSITIVE);
        let e = (a.to_bits() >> 23) as i32 - 127;
        (f64::from(got) - exact).abs() / 2f64.powi(e - 23)
    }

    /// Max (sin, cos) ulp error over the points.
    fn max_err(points: impl Iterator<Item = f32>) -> (f64, f64, f32, f32) {
        let (mut es, mut ec, mut xs, mut xc) = (0.0f64, 0.0f64, 0.0f32, 0.0f32);
        for x in points {
            let (s, c) = sin_cos_f32(x);
            let xd = f64::from(x);
            let (a, b) = (ulps(s, libm::sin(xd)), ulps(c, libm::cos(xd)));
            if a > es {
                (es, xs) = (a, x);
            }
            if b > ec {
                (ec, xc) = (b, x);
            }
            // Pythagorean identity.
            let p = f64::from(s).mul_add(f64::from(s), f64::from(c) * f64::from(c)) - 1.0;
            assert!(p.abs() < 2.5e-7, "sin²+cos²−1 = {p} at {x}");
        }
        (es, ec, xs, xc)
    }

    /// xorshift64*: reproducible uniform points without a dev-dependency (also the trig
    /// wrappers' tests).
    pub(crate) fn uniform(seed: u64, n: usize, lo: f32, hi: f32) -> impl Iterator<Item = f32> {
        let mut state = seed;
        (0..n).map(move |_| {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            let u = (state.wrapping_mul(0x2545_f491_4f6c_dd1d) >> 40) as f32 / (1u64 << 24) as f32;
            lo + (hi - lo) * u
        })
    }

    #[test]
    fn dense_grid_small_angles_within_one_ulp() {
        // Every 7th f32 in [π/16, π/4]: no reduction, polynomial and rounding error only.
        let lo = (core::f32::consts::PI / 16.0).to_bits();
        let hi = core::f32::consts::FRAC_PI_4.to_bits();
        let (es, ec, xs, xc) = max_err((lo..=hi).step_by(7).map(f32::from_bits));
        assert!(es <= 1.0, "sin {es} ulp at {xs}");
        assert!(ec <= 1.0, "cos {ec} ulp at {xc}");
        // Tiny arguments: sin x = x, cos x = 1.
        let (es, ec, xs, xc) = max_err((1u32..=0.1f32.to_bits()).step_by(997).map(f32::from_bits));
        assert!(es <= 1.0, "sin {es} ulp at {xs}");
        assert!(ec <= 1.0, "cos {ec} ulp at {xc}");
    }

    #[test]
    fn dense_grid_and_random_points_over_the_domain() {
        // Dense: every 61st f32 in [1, 8192] (≈ 1.8 M points per sign).
        let lo = 1.0f32.to_bits();
        let hi = F32_ACCURATE_DOMAIN_RAD.to_bits();
        let grid = (lo..=hi).step_by(61).map(f32::from_bits);
        let (es, ec, xs, xc) = max_err(grid.clone().chain(grid.map(|x| -x)));
        assert!(es <= 2.0, "sin {es} ulp at {xs}");
        assert!(ec <= 2.0, "cos {ec} ulp at {xc}");
        // Random over the whole domain.
        let d = F32_ACCURATE_DOMAIN_RAD;
        let (es, ec, xs, xc) = max_err(uniform(0x9e37_79b9_7f4a_7c15, 400_000, -d, d));
        assert!(es <= 2.0, "sin {es} ulp at {xs}");
        assert!(ec <= 2.0, "cos {ec} ulp at {xc}");
    }

    #[test]
    fn near_multiples_of_half_pi() {
        // The f32 neighbours of k·π/2: where the reduction error shows (tiny results).
        for k in (1..5215).step_by(3) {
            let x0 = (f64::from(k) * core::f64::consts::FRAC_PI_2) as f32;
            let pts = (-8i32..=8).map(|d| f32::from_bits(x0.to_bits().wrapping_add_signed(d)));
            let (es, ec, xs, xc) = max_err(pts);
            assert!(es <= 2.0, "sin {es} ulp at {xs}");
            assert!(ec <= 2.0, "cos {ec} ulp at {xc}");
        }
    }

    #[test]
    fn fast_path_matches_the_reduction() {
        // For |x| ≤ π/4 the reduction is the identity (k = 0): the shortcut changes nothing.
        for x in uniform(13, 100_000, -FRAC_PI_4, FRAC_PI_4) {
            let (s, c) = sin_cos_f32(x);
            let kf = (x * TWO_OVER_PI + ROUND_MAGIC) - ROUND_MAGIC;
            assert_eq!(kf, 0.0);
            let t = ((x - kf * PIO2_1) - kf * PIO2_2) - kf * PIO2_3;
            let p = kf * PIO2_4;
            let r = t - p;
            let (s2, c2) = sin_cos_kernel(r, (t - r) - p);
            assert_eq!(
                (s.to_bits(), c.to_bits()),
                (s2.to_bits(), c2.to_bits()),
                "{x}"
            );
        }
    }

    #[test]
    fn symmetry_and_exact_values() {
        assert_eq!(sin_cos_f32(0.0), (0.0, 1.0));
        // sin(−0) = +0 (equal to 0, sign of zero not kept).
        assert_eq!(sin_cos_f32(-0.0), (0.0, 1.0));
        for x in uniform(7, 100_000, 1e-30, F32_ACCURATE_DOMAIN_RAD) {
            let (s, c) = sin_cos_f32(x);
            let (sn, cn) = sin_cos_f32(-x);
            assert_eq!(sn.to_bits(), (-s).to_bits(), "sin odd at {x}");
            assert_eq!(cn.to_bits(), c.to_bits(), "cos even at {x}");
        }
    }

    #[test]
    fn non_finite_gives_nan_and_huge_stays_bounded() {
        for x in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
            let (s, c) = sin_cos_f32(x);
            assert!(s.is_nan() && c.is_nan(), "{x}");
        }
        // Beyond the accurate domain: finite, bounded, never NaN.
        let big = uniform(3, 20_000, 8192.0, 1e7)
            .chain(uniform(4, 20_000, 1e7, f32::MAX))
            .chain([f32::MAX, f32::MIN, 3.0e38, 2.0f32.powi(23), 2.0f32.powi(31)]);
        for x in big {
            for v in [sin_cos_f32(x).0, sin_cos_f32(x).1, sin_cos_f32(-x).0] {
                assert!(v.is_finite() && v.abs() <= 1.0, "{v} at {x}");
            }
        }
        // Loss of accuracy just beyond the domain stays modest (documented |x|·2⁻³⁶ order).
        for x in uniform(5, 20_000, 8192.0, 131_072.0) {
            let (s, c) = sin_cos_f32(x);
            let xd = f64::from(x);
            let err = (f64::from(s) - libm::sin(xd))
                .abs()
                .max((f64::from(c) - libm::cos(xd)).abs());
            assert!(
                err < f64::from(x) * 2f64.powi(-35),
                "abs error {err} at {x}"
            );
        }
    }
}

//! The scalar Joseph update of the transfer-alignment filters: the arithmetic of
//! [`crate::math::kalman::fuse_scalar_prepared`] (same gate, same checks, same expressions in the
//! same order: bit-identical results), arranged so that each diagonal element of `P⁺` is computed
//! once. The positivity check of `P⁺`'s diagonal computes `P⁺_ii = P_ii + k_i c_i − b_i k_i`
//! before anything is written (a refused update leaves `x` and `P` untouched); the update pass
//! then stores those values instead of computing them again, and runs its straight-line
//! off-diagonal code over the strict upper triangle only (each value also written to its mirror).
use crate::math::kalman::{gate_scalar, FusionOutcome, FusionReport, Gate};
use crate::Real;
use nalgebra::{SMatrix, SVector};

/// `true` for a finite value (NaN fails the comparison).
#[inline(always)]
fn finite<T: Real>(v: T) -> bool {
    v.abs() < T::lit(f64::INFINITY)
}

/// One scalar Joseph update of `x`, `P` given `b = P h` and `hph = hᵀ P h` (`r` the measurement
/// variance, in the measurement's unit squared). `Ok(report)` when fused or rejected by the
/// gate; `Err(s)` (with `s = hph + r`, the innovation variance) when the update cannot be
/// fused numerically: a non-finite innovation or `r`, `r ≤ 0`, an innovation variance that is
/// not finite and positive, `hph < 0`, a diagonal element of `P⁺` negative or non-finite, or a
/// non-finite state correction. Nothing is written unless the update is fused.
///
/// Not inlined: one copy per N serves the six rows of a step (inlined six times, the
/// straight-line triangle costs tens of kilobytes of flash).
#[inline(never)]
pub(super) fn fuse_scalar_once<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    b: &SVector<T, N>,
    hph: T,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> Result<FusionReport<T>, T> {
    let s = hph + r;
    if !finite(innovation) || !finite(r) || r <= T::zero() {
        return Err(s);
    }
    let Some((report, inv_s)) = gate_scalar(innovation, hph, s, gate) else {
        return Err(s);
    };
    if report.outcome == FusionOutcome::Rejected {
        return Ok(report);
    }
    let [bs] = &b.data.0;
    // Gain k = b / s, c = s k − b (as `fuse_scalar_prepared`).
    let mut k = [T::zero(); N];
    let mut c = [T::zero(); N];
    for ((ki, ci), &bi) in k.iter_mut().zip(c.iter_mut()).zip(bs.iter()) {
        *ki = bi * inv_s;
        *ci = s * *ki - bi;
    }
    // P⁺'s diagonal, checked before anything is written: one compare per element; ±∞ and NaN
    // make the sum non-finite.
    let mut d = [T::zero(); N];
    let mut negative = false;
    let mut sum = T::zero();
    for (i, (((di, &ki), &ci), &bi)) in d
        .iter_mut()
        .zip(k.iter())
        .zip(c.iter())
        .zip(bs.iter())
        .enumerate()
    {
        if let Some(&pii) = p.data.0.get(i).and_then(|col| col.get(i)) {
            let v = pii + ki * ci - bi * ki;
            // `v < 0` misses NaN, but NaN also makes `sum` non-finite.
            negative |= v < T::zero();
            sum += v;
            *di = v;
        }
    }
    if negative || sum * T::zero() != T::zero() {
        return Err(s);
    }
    let mut dx = [T::zero(); N];
    let mut probe = T::zero();
    for (dxi, &ki) in dx.iter_mut().zip(k.iter()) {
        *dxi = ki * innovation;
        probe += *dxi * T::zero();
    }
    if probe != T::zero() {
        return Err(s);
    }
    if N <= UNROLLED_MAX_N {
        update_unrolled(&mut p.data.0, &k, bs, &c, &d);
    } else {
        update_loop(&mut p.data.0, &k, bs, &c, &d);
    }
    for (xi, &di) in x.as_mut_slice().iter_mut().zip(dx.iter()) {
        *xi += di;
    }
    Ok(report)
}

/// Largest N for which the update pass is straight-line code.
const UNROLLED_MAX_N: usize = 15;

/// The loop form of [`update_unrolled`] (any N; same expressions).
#[inline(always)]
fn update_loop<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
    d: &[T; N],
) {
    for j in 0..N {
        for i in 0..j {
            if let (Some(&ki), Some(&bi), Some(&kj), Some(&cj)) =
                (k.get(i), b.get(i), k.get(j), c.get(j))
            {
                if let Some(pij) = p.get_mut(j).and_then(|col| col.get_mut(i)) {
                    let nv = *pij + ki * cj - bi * kj;
                    *pij = nv;
                    if let Some(pji) = p.get_mut(i).and_then(|col| col.get_mut(j)) {
                        *pji = nv;
                    }
                }
            }
        }
        if let (Some(&dj), Some(pjj)) = (d.get(j), p.get_mut(j).and_then(|col| col.get_mut(j))) {
            *pjj = dj;
        }
    }
}

/// `P⁺_ij = P_ij + k_i c_j − b_i k_j` for i < j, written to (i, j) and (j, i); `P⁺_ii = d_i`.
/// Straight-line code for N ≤ 15 (the guards are constants after monomorphisation; every
/// filter of this module has N ≤ 15), column-major `p[col][row]`.
#[inline(always)]
fn update_unrolled<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
    d: &[T; N],
) {
    macro_rules! strict_upper {
        ($(($i:literal, $j:literal)),* $(,)?) => {
            $(
                if $j < N {
                    if let (Some(&ki), Some(&bi), Some(&kj), Some(&cj)) =
                        (k.get($i), b.get($i), k.get($j), c.get($j))
                    {
                        if let Some(pij) = p.get_mut($j).and_then(|col| col.get_mut($i)) {
                            let nv = *pij + ki * cj - bi * kj;
                            *pij = nv;
                            if let Some(pji) = p.get_mut($i).and_then(|col| col.get_mut($j)) {
                                *pji = nv;
                            }
                        }
                    }
                }
            )*
        };
    }
    macro_rules! diagonal {
        ($($i:literal),* $(,)?) => {
            $(
                if $i < N {
                    if let (Some(&di), Some(pii)) =
                        (d.get($i), p.get_mut($i).and_then(|col| col.get_mut($i)))
                    {
                        *pii = di;
                    }
                }
            )*
        };
    }
    strict_upper!(
        (0, 1),
        (0, 2),
        (1, 2),
        (0, 3),
        (1, 3),
        (2, 3),
        (0, 4),
        (1, 4),
        (2, 4),
        (3, 4),
        (0, 5),
        (1, 5),
        (2, 5),
        (3, 5),
        (4, 5),
        (0, 6),
        (1, 6),
        (2, 6),
        (3, 6),
        (4, 6),
        (5, 6),
        (0, 7),
        (1, 7),
        (2, 7),
        (3, 7),
        (4, 7),
        (5, 7),
        (6, 7),
        (0, 8),
        (1, 8),
        (2, 8),
        (3, 8),
        (4, 8),
        (5, 8),
        (6, 8),
        (7, 8),
        (0, 9),
        (1, 9),
        (2, 9),
        (3, 9),
        (4, 9),
        (5, 9),
        (6, 9),
        (7, 9),
        (8, 9),
        (0, 10),
        (1, 10),
        (2, 10),
        (3, 10),
        (4, 10),
        (5, 10),
        (6, 10),
        (7, 10),
        (8, 10),
        (9, 10),
        (0, 11),
        (1, 11),
        (2, 11),
        (3, 11),
        (4, 11),
        (5, 11),
        (6, 11),
        (7, 11),
        (8, 11),
        (9, 11),
        (10, 11),
        (0, 12),
        (1, 12),
        (2, 12),
        (3, 12),
        (4, 12),
        (5, 12),
        (6, 12),
        (7, 12),
        (8, 12),
        (9, 12),
        (10, 12),
        (11, 12),
        (0, 13),
        (1, 13),
        (2, 13),
        (3, 13),
        (4, 13),
        (5, 13),
        (6, 13),
        (7, 13),
        (8, 13),
        (9, 13),
        (10, 13),
        (11, 13),
        (12, 13),
        (0, 14),
        (1, 14),
        (2, 14),
        (3, 14),
        (4, 14),
        (5, 14),
        (6, 14),
        (7, 14),
        (8, 14),
        (9, 14),
        (10, 14),
        (11, 14),
        (12, 14),
        (13, 14),
    );
    diagonal!(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14,);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::kalman::fuse_scalar_prepared;

    /// A reproducible PSD matrix `A Aᵀ + εI` and row from a seeded linear congruential stream.
    fn case<T: Real, const N: usize>(
        seed: u64,
    ) -> (SMatrix<T, N, N>, SVector<T, N>, SVector<T, N>) {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            // Uniform in [−1, 1).
            T::lit(((state >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0)
        };
        let a = SMatrix::<T, N, N>::from_fn(|_, _| next());
        let p = a * a.transpose() + SMatrix::<T, N, N>::identity() * T::lit(1e-3);
        let h = SVector::<T, N>::from_fn(|_, _| next());
        let x = SVector::<T, N>::from_fn(|_, _| next());
        (p, h, x)
    }

    fn bits<T: Real>(v: &[T]) -> std::vec::Vec<u64> {
        v.iter().map(|e| e.to_f64().to_bits()).collect()
    }

    /// Same x, P and report as the shared kernel, bit for bit, for fused, gated, and refused
    /// updates (refusals: both leave x and P untouched).
    fn same_as_shared<T: Real, const N: usize>() {
        let (mut fused, mut gated, mut refused) = (0, 0, 0);
        for seed in 0..40u64 {
            let (p0, h, x0) = case::<T, N>(seed);
            let b = p0 * h;
            let hph = h.dot(&b);
            // Innovations within and beyond the gate; r from tiny (large reductions) to large;
            // an invalid r and a negative hph (refused by both).
            let (r, hph_used) = match seed % 5 {
                0 => (T::lit(1e-6), hph),
                1 => (T::lit(0.5), hph),
                2 => (T::lit(-1.0), hph),
                3 => (T::lit(2.0), -hph),
                _ => (T::lit(10.0), hph),
            };
            // Up to 6 σ of the innovation: some beyond the gate of 9 (3 σ).
            let innovation = T::lit(((seed % 7) as f64 - 3.0) * 2.0) * (hph.abs() + r.abs()).sqrt();
            let gate = if seed % 2 == 0 {
                Gate::Off
            } else {
                Gate::Nis(T::lit(9.0))
            };
            let (mut xa, mut pa) = (x0, p0);
            let (mut xb, mut pb) = (x0, p0);
            let ours = fuse_scalar_once(&mut xa, &mut pa, &b, hph_used, innovation, r, gate);
            let shared = fuse_scalar_prepared(&mut xb, &mut pb, &b, hph_used, innovation, r, gate);
            match (ours, shared) {
                (Ok(o), Ok(s)) => {
                    assert_eq!(o, s, "seed {seed}");
                    if o.outcome == FusionOutcome::Fused {
                        fused += 1;
                    } else {
                        gated += 1;
                    }
                }
                (Err(_), Err(_)) => {
                    refused += 1;
                    assert_eq!(bits(xa.as_slice()), bits(x0.as_slice()), "seed {seed}");
                    assert_eq!(bits(pa.as_slice()), bits(p0.as_slice()), "seed {seed}");
                }
                (o, s) => panic!("seed {seed}: {o:?} vs {s:?}"),
            }
            assert_eq!(bits(xa.as_slice()), bits(xb.as_slice()), "seed {seed}");
            assert_eq!(bits(pa.as_slice()), bits(pb.as_slice()), "seed {seed}");
        }
        // Every path was exercised.
        assert!(
            fused > 0 && gated > 0 && refused > 0,
            "{fused} {gated} {refused}"
        );
    }

    #[test]
    fn bit_identical_to_the_shared_kernel_f32_f64() {
        same_as_shared::<f32, 9>();
        same_as_shared::<f32, 12>();
        same_as_shared::<f32, 15>();
        same_as_shared::<f64, 15>();
        // The loop form (N > 15).
        same_as_shared::<f32, 17>();
        same_as_shared::<f64, 17>();
    }
}

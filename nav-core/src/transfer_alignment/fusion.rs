//! The scalar update of the transfer-alignment filters in rank-one form: with `b = P h`,
//! `s = hᵀPh + r` and the gain `k = b / s`, `P⁺ = P − k bᵀ`, computed on the upper triangle
//! only (the filters store P as its upper triangle: the lower one is neither read nor
//! written), one multiply-subtract per element. The gate, report and refusals are those of
//! [`crate::math::kalman::fuse_scalar_prepared`] (the shared Joseph form); the arithmetic
//! differs by rounding only: for the optimal gain the Joseph form's expansion
//! `P − k bᵀ − b kᵀ + s k kᵀ` is `P − k bᵀ` plus a rounding-size term. What the Joseph form
//! guards against rounding (a variance driven below zero) is guarded here as there: `P⁺`'s
//! diagonal is computed and checked before anything is written (a refused update leaves `x`
//! and `P` untouched; a step checks the six results once at the end instead and, when that
//! check fails, runs its updates again with these per-update checks: [`Guard`]), one update
//! never divides a variance by more than
//! [`super::MAX_VARIANCE_REDUCTION`] (`fuse_bounded`), and every committed covariance is
//! loaded and conditioned ([`super::covariance::condition`]).
use crate::math::kalman::{gate_scalar, FusionOutcome, FusionReport, Gate};
use crate::Real;
use nalgebra::{SMatrix, SVector};

/// Where the checks of an update's result (`P⁺`'s diagonal, the state correction) are made.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum Guard {
    /// In every update, before anything is written: a refused update changes nothing.
    PerUpdate,
    /// Once, after the epoch's updates ([`DeferredCheck`]): each update checks only what
    /// decides its outcome (finite innovation and `r`, the innovation variance, the gate) and
    /// writes. When the epoch's result fails the check, the caller discards it and runs the
    /// epoch again with [`Guard::PerUpdate`]; when it passes, no update of the epoch would have
    /// been refused by the per-update checks, so the result is the same bits.
    Deferred,
}

/// What an update checks: the χ² gate, and where the checks of its result are made.
#[derive(Debug, Clone, Copy)]
pub(super) struct UpdateChecks<T> {
    /// The χ² gate.
    pub gate: Gate<T>,
    /// Where `P⁺`'s diagonal and the state correction are checked.
    pub guard: Guard,
}

/// The check of [`Guard::Deferred`]: passes exactly when no update of the epoch, run with
/// [`Guard::PerUpdate`] from the same start, would have been refused by the checks of its
/// result — so that the deferred epoch's result is that of the per-update one, bit for bit.
///
/// Why it suffices, given the updates' own checks (`s` finite and positive): each update
/// lowers every variance, `P⁺_ii = P_ii − k_i b_i` with `k_i b_i = (b_i / s) b_i ≥ 0` (rounding
/// is monotone), and a non-finite variance stays non-finite; so every intermediate diagonal
/// lies between the final one and the one at the start. The final diagonal non-negative and
/// finite makes every intermediate one so; every intermediate diagonal sum (non-negative
/// terms, each at most the starting one, summed in the same order) is at most the starting
/// diagonal's sum, finite when that is. A non-finite correction `k_i·innovation` makes `x_i`
/// non-finite, and a non-finite state stays so (a later row's innovation from it is non-finite
/// and skipped): a finite final state rules it out.
#[derive(Debug, Clone, Copy)]
pub(super) struct DeferredCheck<T> {
    /// Sum of the diagonal at the start of the epoch's updates (units of the states squared,
    /// summed as numbers).
    start_sum: T,
}

impl<T: Real> DeferredCheck<T> {
    /// Records the diagonal sum of the predicted covariance, before the updates.
    #[inline(always)]
    pub(super) fn start<const N: usize>(p: &SMatrix<T, N, N>) -> Self {
        let (_, start_sum) = diagonal_scan(p);
        Self { start_sum }
    }

    /// `true` when the result `x`, `P` of the epoch's updates stands (see [`DeferredCheck`]).
    #[inline(always)]
    pub(super) fn passes<const N: usize>(&self, x: &SVector<T, N>, p: &SMatrix<T, N, N>) -> bool {
        let (negative, sum) = diagonal_scan(p);
        let probe = x
            .as_slice()
            .iter()
            .fold(sum * T::zero() + self.start_sum * T::zero(), |acc, v| {
                acc + *v * T::zero()
            });
        !negative && probe == T::zero()
    }
}

/// (a diagonal element negative, the diagonal's sum) of `p`; NaN compares false, but makes
/// the sum NaN.
#[inline(always)]
fn diagonal_scan<T: Real, const N: usize>(p: &SMatrix<T, N, N>) -> (bool, T) {
    let mut negative = false;
    let mut sum = T::zero();
    for (i, col) in p.data.0.iter().enumerate() {
        if let Some(&d) = col.get(i) {
            negative |= d < T::zero();
            sum += d;
        }
    }
    (negative, sum)
}

/// One scalar update of `x`, `P` (P stored as its upper triangle) given `b = P h` and
/// `hph = hᵀ P h` (`r` the measurement variance, in the measurement's unit squared).
/// `Ok(report)` when fused or rejected by the gate; `Err(s)` (with `s = hph + r`, the innovation variance) when the update cannot be
/// fused numerically: a non-finite innovation or `r`, `r ≤ 0`, an innovation variance that is
/// not finite and positive, `hph < 0`, and with [`Guard::PerUpdate`] a diagonal element of
/// `P⁺` negative or non-finite, or a non-finite state correction (with [`Guard::Deferred`]
/// those two are the caller's [`DeferredCheck`]). Nothing is written unless the update is
/// fused.
///
/// Not inlined: one copy per N serves the six rows of a step (inlined six times, the
/// straight-line triangle costs kilobytes of flash). Straight-line: inlined for N = 15 (rows
/// fused one by one); for the paired filters (N ≤ 12) their out-of-line [`downdate_one`].
/// The loop form only beyond N = 15.
#[inline(never)]
pub(super) fn fuse_rank_one<T: Real, const N: usize>(
    x: &mut SVector<T, N>,
    p: &mut SMatrix<T, N, N>,
    b: &SVector<T, N>,
    hph: T,
    innovation: T,
    r: T,
    checks: UpdateChecks<T>,
) -> Result<FusionReport<T>, T> {
    let UpdateChecks { gate, guard } = checks;
    let s = hph + r;
    // Finite innovation and r: `v·0` is ±0 for finite v, NaN for ±∞ and NaN (one multiply-add
    // and one compare instead of two classifications on the target).
    if innovation * T::zero() + r * T::zero() != T::zero() || r <= T::zero() {
        return Err(s);
    }
    let Some((report, inv_s)) = gate_scalar(innovation, hph, s, gate) else {
        return Err(s);
    };
    if report.outcome == FusionOutcome::Rejected {
        return Ok(report);
    }
    let [bs] = &b.data.0;
    if guard == Guard::PerUpdate && !result_acceptable(p, bs, inv_s, innovation) {
        return Err(s);
    }
    let xs = &mut x.data.0[0];
    if N <= PAIRED_MAX_N {
        let g = Gain { inv_s, innovation };
        downdate_one(xs, &mut p.data.0, bs, g);
    } else if N <= UNROLLED_MAX_N {
        downdate_unrolled(&mut p.data.0, bs, inv_s, xs, innovation);
    } else {
        downdate_loop(&mut p.data.0, bs, inv_s, xs, innovation);
    }
    Ok(report)
}

/// What an update's own checks decide, before anything is written: `Ok((report, 1/s))`, the
/// report `Fused` or `Rejected` by the gate; `Err(s)` (`s = hph + r`) when the update cannot be
/// fused numerically (see [`fuse_rank_one`]).
#[inline(always)]
pub(super) fn decide<T: Real>(
    hph: T,
    innovation: T,
    r: T,
    gate: Gate<T>,
) -> Result<(FusionReport<T>, T), T> {
    let s = hph + r;
    // Finite innovation and r: `v·0` is ±0 for finite v, NaN for ±∞ and NaN (one multiply-add
    // and one compare instead of two classifications on the target).
    if innovation * T::zero() + r * T::zero() != T::zero() || r <= T::zero() {
        return Err(s);
    }
    gate_scalar(innovation, hph, s, gate).ok_or(s)
}

/// `1/s` and the innovation of a fused update of a pair ([`downdate_two`]).
#[derive(Clone, Copy)]
pub(super) struct Gain<T> {
    /// `1/s`, s the innovation variance.
    pub inv_s: T,
    /// The innovation, in the measurement's unit.
    pub innovation: T,
}

/// Two consecutive fused updates ([`Guard::Deferred`]) in one pass over the upper triangle,
/// with `b1 = P h1` and `b2 = P⁺ h2` (`P⁺` the first update's result):
/// `P_ij ← (P_ij − k1_i b1_j) − k2_i b2_j`, `x_i ← (x_i + k1_i ν1) + k2_i ν2` (`k_i = b_i / s`,
/// given `1/s`), each element read and written once. The same expressions in the same order
/// as the two updates one after the other ([`fuse_rank_one`] twice): the same bits. Not
/// inlined: one copy per N. (`b1`, `b2` are parameters of their own, so the compiler knows
/// they do not alias P and keeps them in registers.)
#[inline(never)]
pub(super) fn downdate_two<T: Real, const N: usize>(
    x: &mut [T; N],
    p: &mut [[T; N]; N],
    b1: &[T; N],
    b2: &[T; N],
    [g1, g2]: [Gain<T>; 2],
) {
    let (inv1, inv2, nu1, nu2) = (g1.inv_s, g2.inv_s, g1.innovation, g2.innovation);
    macro_rules! row {
        ($i:literal: $($j:literal)*) => {
            if $i < N {
                if let (Some(&b1i), Some(&b2i), Some(xi)) = (b1.get($i), b2.get($i), x.get_mut($i)) {
                    let (k1i, k2i) = (b1i * inv1, b2i * inv2);
                    $(
                        if let (Some(&b1j), Some(&b2j), Some(pij)) =
                            (b1.get($j), b2.get($j), p.get_mut($j).and_then(|col| col.get_mut($i)))
                        {
                            *pij -= k1i * b1j;
                            *pij -= k2i * b2j;
                        }
                    )*
                    *xi += k1i * nu1;
                    *xi += k2i * nu2;
                }
            }
        };
    }
    if N > 12 {
        // No filter of this module pairs its rows with N > 12: the loop form, for safety.
        for (i, xi) in x.iter_mut().enumerate() {
            let (Some(&b1i), Some(&b2i)) = (b1.get(i), b2.get(i)) else {
                continue;
            };
            let (k1i, k2i) = (b1i * inv1, b2i * inv2);
            for ((col, &b1j), &b2j) in p.iter_mut().zip(b1.iter()).zip(b2.iter()).skip(i) {
                if let Some(pij) = col.get_mut(i) {
                    *pij -= k1i * b1j;
                    *pij -= k2i * b2j;
                }
            }
            *xi += k1i * nu1;
            *xi += k2i * nu2;
        }
        return;
    }
    // Straight-line up to N = 12 (the paper filters, 9 and 12 states, pair their rows).
    row!(0: 0 1 2 3 4 5 6 7 8 9 10 11);
    row!(1: 1 2 3 4 5 6 7 8 9 10 11);
    row!(2: 2 3 4 5 6 7 8 9 10 11);
    row!(3: 3 4 5 6 7 8 9 10 11);
    row!(4: 4 5 6 7 8 9 10 11);
    row!(5: 5 6 7 8 9 10 11);
    row!(6: 6 7 8 9 10 11);
    row!(7: 7 8 9 10 11);
    row!(8: 8 9 10 11);
    row!(9: 9 10 11);
    row!(10: 10 11);
    row!(11: 11);
}

/// The update of a pair ([`downdate_two`]) whose other row is not fused: [`downdate_unrolled`],
/// straight-line, the bits of [`fuse_rank_one`] (the same expressions). Not inlined: one copy
/// per N.
#[inline(never)]
pub(super) fn downdate_one<T: Real, const N: usize>(
    x: &mut [T; N],
    p: &mut [[T; N]; N],
    b: &[T; N],
    g: Gain<T>,
) {
    downdate_unrolled(p, b, g.inv_s, x, g.innovation);
}

/// The checks of an update's result, before anything is written: `P⁺`'s diagonal
/// `P_ii − k_i b_i` (`k_i = b_i / s`, given `1/s`) non-negative with a finite sum, and the
/// state correction `k·innovation` finite. (The gains are formed again where they are used,
/// the same expression: no array of them on the stack.)
#[inline(always)]
fn result_acceptable<T: Real, const N: usize>(
    p: &SMatrix<T, N, N>,
    bs: &[T; N],
    inv_s: T,
    innovation: T,
) -> bool {
    // P⁺'s diagonal: one compare per element; ±∞ and NaN make the sum non-finite. The state
    // correction: NaN in `probe` when not finite.
    let mut negative = false;
    let mut sum = T::zero();
    let mut probe = T::zero();
    for (i, &bi) in bs.iter().enumerate() {
        if let Some(&pii) = p.data.0.get(i).and_then(|col| col.get(i)) {
            let ki = bi * inv_s;
            let v = pii - ki * bi;
            // `v < 0` misses NaN, but NaN also makes `sum` non-finite.
            negative |= v < T::zero();
            sum += v;
            probe += ki * innovation * T::zero();
        }
    }
    !negative && sum * T::zero() == T::zero() && probe == T::zero()
}

/// Largest N for which the update pass is straight-line code.
const UNROLLED_MAX_N: usize = 15;

/// Largest N of the filters that fuse their rows in pairs ([`downdate_two`], the hot path):
/// their single updates run the straight-line [`downdate_one`], one copy per N.
const PAIRED_MAX_N: usize = 12;

/// The loop form of [`downdate_unrolled`] (any N; same expressions in the same order).
#[inline(always)]
fn downdate_loop<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    b: &[T; N],
    inv_s: T,
    x: &mut [T; N],
    innovation: T,
) {
    for (i, (&bi, xi)) in b.iter().zip(x.iter_mut()).enumerate() {
        let ki = bi * inv_s;
        for (col, &bj) in p.iter_mut().zip(b.iter()).skip(i) {
            if let Some(pij) = col.get_mut(i) {
                *pij -= ki * bj;
            }
        }
        *xi += ki * innovation;
    }
}

/// `P⁺_ij = P_ij − k_i b_j` for i ≤ j, on the upper triangle only (column-major
/// `p[col][row]`, rows `0..=col`; the lower triangle is neither read nor written), and
/// `x_i += k_i · innovation`, with the gain `k_i = b_i / s` (given `1/s`). Straight-line code
/// for N ≤ 15, row by row: each gain formed once where its row starts (no array of gains),
/// `b` held in registers; the guards are constants after monomorphisation; every filter of
/// this module has N ≤ 15.
#[inline(always)]
fn downdate_unrolled<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    b: &[T; N],
    inv_s: T,
    x: &mut [T; N],
    innovation: T,
) {
    macro_rules! row {
        ($i:literal: $($j:literal)*) => {
            if $i < N {
                if let (Some(&bi), Some(xi)) = (b.get($i), x.get_mut($i)) {
                    let ki = bi * inv_s;
                    $(
                        if let (Some(&bj), Some(pij)) =
                            (b.get($j), p.get_mut($j).and_then(|col| col.get_mut($i)))
                        {
                            *pij -= ki * bj;
                        }
                    )*
                    *xi += ki * innovation;
                }
            }
        };
    }
    row!(0: 0 1 2 3 4 5 6 7 8 9 10 11 12 13 14);
    row!(1: 1 2 3 4 5 6 7 8 9 10 11 12 13 14);
    row!(2: 2 3 4 5 6 7 8 9 10 11 12 13 14);
    row!(3: 3 4 5 6 7 8 9 10 11 12 13 14);
    row!(4: 4 5 6 7 8 9 10 11 12 13 14);
    row!(5: 5 6 7 8 9 10 11 12 13 14);
    row!(6: 6 7 8 9 10 11 12 13 14);
    row!(7: 7 8 9 10 11 12 13 14);
    row!(8: 8 9 10 11 12 13 14);
    row!(9: 9 10 11 12 13 14);
    row!(10: 10 11 12 13 14);
    row!(11: 11 12 13 14);
    row!(12: 12 13 14);
    row!(13: 13 14);
    row!(14: 14);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::math::kalman::fuse_scalar_prepared;

    /// A reproducible PSD matrix `A Aᵀ + εI`, row and state from a seeded linear congruential
    /// stream (f64; the f32 cases round it).
    fn case<const N: usize>(seed: u64) -> (SMatrix<f64, N, N>, SVector<f64, N>, SVector<f64, N>) {
        let mut state = seed.wrapping_mul(6_364_136_223_846_793_005).wrapping_add(1);
        let mut next = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            // Uniform in [−1, 1).
            ((state >> 11) as f64) / ((1u64 << 53) as f64) * 2.0 - 1.0
        };
        let a = SMatrix::<f64, N, N>::from_fn(|_, _| next());
        let p = a * a.transpose() + SMatrix::<f64, N, N>::identity() * 1e-3;
        let h = SVector::<f64, N>::from_fn(|_, _| next());
        let x = SVector::<f64, N>::from_fn(|_, _| next());
        (p, h, x)
    }

    fn bits<T: Real>(v: &[T]) -> std::vec::Vec<u64> {
        v.iter().map(|e| e.to_f64().to_bits()).collect()
    }

    /// Measurement variance, sign of hᵀPh and gate of case `seed`: tiny r (reductions up to
    /// the bound of `fuse_bounded`), moderate and large r, an invalid r and a negative hᵀPh
    /// (both refused by either kernel); gate off or at 3 σ.
    fn variant(seed: u64, hph: f64) -> (f64, f64, Option<f64>) {
        let (r, hph_used) = match seed % 5 {
            0 => (hph * 1e-4, hph),
            1 => (0.5, hph),
            2 => (-1.0, hph),
            3 => (2.0, -hph),
            _ => (10.0, hph),
        };
        let gate = (seed % 2 == 1).then_some(9.0);
        (r, hph_used, gate)
    }

    /// The largest error of (x, P) against the reference (xr, pr), in ε of T and units of
    /// the prior's `√(P_ii P_jj)` (`√P_ii` for x); asserts P exactly symmetric.
    fn error_in_eps<T: Real, const N: usize>(
        x: &SVector<T, N>,
        p: &SMatrix<T, N, N>,
        xr: &SVector<f64, N>,
        pr: &SMatrix<f64, N, N>,
        prior: &SMatrix<f64, N, N>,
    ) -> f64 {
        let eps = T::EPS.to_f64();
        let mut worst = 0.0f64;
        for i in 0..N {
            let si = prior[(i, i)].sqrt();
            worst = worst.max((x[i].to_f64() - xr[i]).abs() / si / eps);
            for j in 0..N {
                let scale = si * prior[(j, j)].sqrt();
                worst = worst.max((p[(i, j)].to_f64() - pr[(i, j)]).abs() / scale / eps);
                assert_eq!(p[(i, j)].to_f64().to_bits(), p[(j, i)].to_f64().to_bits());
            }
        }
        worst
    }

    /// Against the shared Joseph kernel in f64 (the reference): the same outcome, the same
    /// report bit for bit (the gate is shared) when run in the same float type, `x⁺` and `P⁺`
    /// within `bound · ε` of the reference in units of the prior's `√(P_ii P_jj)` (`√P_ii` for
    /// x), exactly symmetric, and a refusal that changes nothing. Returns the largest error
    /// seen, in those units of ε.
    fn against_reference<T: Real, const N: usize>(bound: f64) -> f64 {
        let (mut fused, mut gated, mut refused) = (0, 0, 0);
        let mut worst = 0.0f64;
        for seed in 0..60u64 {
            let (p64, h64, x64) = case::<N>(seed);
            let (p0, h, x0) = (p64.map(T::lit), h64.map(T::lit), x64.map(T::lit));
            let b = p0 * h;
            let hph = h.dot(&b);
            let (r, hph_used, g) = variant(seed, hph.to_f64());
            let gate = g.map_or(Gate::Off, |t| Gate::Nis(T::lit(t)));
            let innovation =
                T::lit(((seed % 7) as f64 - 3.0) * 2.0 * (hph.to_f64().abs() + r.abs()).sqrt());
            let (mut xa, mut pa) = (x0, p0);
            let ours = fuse_rank_one(
                &mut xa,
                &mut pa,
                &b,
                T::lit(hph_used),
                innovation,
                T::lit(r),
                UpdateChecks {
                    gate,
                    guard: Guard::PerUpdate,
                },
            );
            // The shared kernel in the same float type: same outcome and report.
            let (mut xs, mut ps) = (x0, p0);
            let same_type = fuse_scalar_prepared(
                &mut xs,
                &mut ps,
                &b,
                T::lit(hph_used),
                innovation,
                T::lit(r),
                gate,
            );
            // The reference: the shared kernel in f64 from the same (rounded) inputs.
            let (p0r, hr) = (p0.map(|v| v.to_f64()), h.map(|v| v.to_f64()));
            let (mut xr, mut pr) = (x0.map(|v| v.to_f64()), p0r);
            let br = p0r * hr;
            let hph_r = if seed % 5 == 3 {
                -hr.dot(&br)
            } else {
                hr.dot(&br)
            };
            let gate_r = g.map_or(Gate::Off, Gate::Nis);
            let reference =
                fuse_scalar_prepared(&mut xr, &mut pr, &br, hph_r, innovation.to_f64(), r, gate_r);
            match (ours, same_type) {
                (Ok(o), Ok(s)) => {
                    // Ours keeps the upper triangle: the full matrix it stands for.
                    pa = SMatrix::from_fn(|r, c| pa[(r.min(c), r.max(c))]);
                    assert_eq!(o, s, "seed {seed}");
                    assert!(reference.is_ok(), "seed {seed}");
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
                    continue;
                }
                (o, s) => panic!("seed {seed}: {o:?} vs {s:?}"),
            }
            worst = worst.max(error_in_eps(&xa, &pa, &xr, &pr, &p0r));
        }
        assert!(worst <= bound, "error {worst} ε above the bound {bound} ε");
        // Every path was exercised.
        assert!(
            fused > 0 && gated > 0 && refused > 0,
            "{fused} {gated} {refused}"
        );
        worst
    }

    #[test]
    fn rank_one_update_matches_the_joseph_reference() {
        // Bound: a few roundings of terms of size √(P_ii P_jj), the innovation of up to 6 σ
        // (x) and the reduction up to the bound 10⁴ (the case r = hᵀPh·10⁻⁴).
        against_reference::<f32, 9>(64.0);
        against_reference::<f32, 12>(64.0);
        against_reference::<f32, 15>(64.0);
        against_reference::<f64, 15>(64.0);
        // The loop form (N > 15).
        against_reference::<f32, 17>(64.0);
        against_reference::<f64, 17>(64.0);
    }

    /// Two updates in one pass ([`downdate_two`]) give the bits of the two one after the
    /// other ([`downdate_unrolled`] twice, the second's `b` from the first's result), in the
    /// straight-line form (N = 9, 12) and the loop form (N = 15).
    fn two_in_one_pass<const N: usize>() {
        for seed in 0..10u64 {
            let (p64, h64, x64) = case::<N>(seed);
            let (_, h2_64, _) = case::<N>(seed + 100);
            let p = p64.map(|v| v as f32);
            let (h1, h2) = (h64.map(|v| v as f32), h2_64.map(|v| v as f32));
            let x0: [f32; N] = core::array::from_fn(|i| x64[i] as f32);
            let (nu1, nu2) = (0.25f32, -0.125f32);
            let b1 = p * h1;
            let inv1 = 1.0 / (h1.dot(&b1) + 0.5);
            // One update as `fuse_rank_one` runs it.
            let one = |ps: &mut SMatrix<f32, N, N>, xs: &mut [f32; N], b: &[f32; N], inv, nu| {
                if N <= UNROLLED_MAX_N {
                    downdate_unrolled(&mut ps.data.0, b, inv, xs, nu);
                } else {
                    downdate_loop(&mut ps.data.0, b, inv, xs, nu);
                }
            };
            let (mut ps, mut xs) = (p, x0);
            one(&mut ps, &mut xs, &b1.data.0[0], inv1, nu1);
            // b2 = P⁺ h2 from the upper triangle the downdate keeps.
            let b2 = SVector::<f32, N>::from_fn(|i, _| {
                (0..N).map(|j| h2[j] * ps[(i.min(j), i.max(j))]).sum()
            });
            let inv2 = 1.0 / (h2.dot(&b2) + 0.5);
            one(&mut ps, &mut xs, &b2.data.0[0], inv2, nu2);
            let (mut pp, mut xp) = (p, x0);
            let gains = [
                Gain {
                    inv_s: inv1,
                    innovation: nu1,
                },
                Gain {
                    inv_s: inv2,
                    innovation: nu2,
                },
            ];
            downdate_two(&mut xp, &mut pp.data.0, &b1.data.0[0], &b2.data.0[0], gains);
            assert_eq!(bits(pp.as_slice()), bits(ps.as_slice()), "seed {seed}");
            assert_eq!(bits(&xp), bits(&xs), "seed {seed}");
            assert_ne!(bits(pp.as_slice()), bits(p.as_slice()), "seed {seed}");
        }
    }

    #[test]
    fn two_updates_in_one_pass_match_them_one_after_the_other() {
        two_in_one_pass::<9>();
        two_in_one_pass::<12>();
        two_in_one_pass::<17>();
    }

    /// The unrolled and the loop form give the same bits (N ≤ 15 uses the first).
    #[test]
    fn unrolled_and_loop_forms_agree() {
        for seed in 0..10u64 {
            let (p64, h64, _) = case::<15>(seed);
            let (p, h) = (p64.map(|v| v as f32), h64.map(|v| v as f32));
            let b = p * h;
            let s = h.dot(&b) + 0.5;
            let (inv_s, innovation) = (1.0 / s, 0.25f32);
            let (mut pu, mut pl) = (p, p);
            let (mut xu, mut xl) = ([0.5f32; 15], [0.5f32; 15]);
            downdate_unrolled(&mut pu.data.0, &b.data.0[0], inv_s, &mut xu, innovation);
            downdate_loop(&mut pl.data.0, &b.data.0[0], inv_s, &mut xl, innovation);
            assert_eq!(bits(pu.as_slice()), bits(pl.as_slice()), "seed {seed}");
            assert_eq!(bits(&xu), bits(&xl), "seed {seed}");
            assert_ne!(bits(pu.as_slice()), bits(p.as_slice()), "seed {seed}");
            assert_ne!(bits(&xu), bits(&[0.5f32; 15]), "seed {seed}");
        }
    }
}

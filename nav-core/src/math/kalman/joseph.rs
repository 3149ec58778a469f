//! The Joseph pass `P⁺_ij = P_ij + k_i c_j − b_i k_j` of the scalar update: exactly symmetric,
//! straight-line for N ≤ 15, a loop above.

use crate::Real;
use nalgebra::{SMatrix, SVector};

/// `P⁺_ij = P_ij + k_i c_j − b_i k_j` on the upper triangle (i ≤ j, column j of the
/// column-major storage), each value also written to (j, i): exactly symmetric, N(N+1)/2
/// elements, no separate mirror pass.
///
/// For N ≤ 15 (every filter of this crate but the 17-state ESKF) the triangle is written out
/// element by element at compile time ([`joseph_unrolled`]): constant offsets, no loop
/// counters, no bounds checks, no per-column set-up (the loop form costs ≈ 17 instructions per
/// element on a Cortex-M4F for N = 12, the straight-line form ≈ 5). Larger N use the loop.
/// Both compute every element with the same expression, so the results are bit-identical.
#[inline(always)]
pub(super) fn joseph_pass<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    k: &SVector<T, N>,
    b: &SVector<T, N>,
    c: &SVector<T, N>,
) {
    if N <= UNROLLED_MAX_N {
        let ([ks], [bs], [cs]) = (&k.data.0, &b.data.0, &c.data.0);
        joseph_unrolled(&mut p.data.0, ks, bs, cs);
    } else {
        joseph_loop(p, k, b, c);
    }
}

/// Largest N for which [`joseph_pass`] is straight-line code.
const UNROLLED_MAX_N: usize = 15;

/// One element of the Joseph pass: `P⁺_ij = P_ij + k_i c_j − b_i k_j` (i ≤ j), written to
/// (i, j) and (j, i). `p` is column-major (`p[col][row]`). With constant indices and a constant
/// N every `get` is resolved at compile time.
#[inline(always)]
fn joseph_elem<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
    i: usize,
    j: usize,
) {
    if let (Some(&ki), Some(&bi), Some(&kj), Some(&cj)) = (k.get(i), b.get(i), k.get(j), c.get(j)) {
        if let Some(pij) = p.get_mut(j).and_then(|col| col.get_mut(i)) {
            let nv = *pij + ki * cj - bi * kj;
            *pij = nv;
            if let Some(pji) = p.get_mut(i).and_then(|col| col.get_mut(j)) {
                *pji = nv;
            }
        }
    }
}

/// `joseph_elem` for each listed `(i, j)` with `j < N` (a constant after monomorphisation), in
/// the order listed.
macro_rules! triangle {
    ($p:ident, $k:ident, $b:ident, $c:ident; $(($i:literal, $j:literal)),* $(,)?) => {
        $(
            if $j < N {
                joseph_elem($p, $k, $b, $c, $i, $j);
            }
        )*
    };
}

/// The upper triangle of an N ≤ 15 covariance, element by element (columns j ascending, rows
/// i ≤ j ascending); the `j < N` guards are constants after monomorphisation.
#[inline(always)]
pub(super) fn joseph_unrolled<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
) {
    joseph_columns_0_to_9(p, k, b, c);
    joseph_columns_10_to_14(p, k, b, c);
}

/// Columns 0 to 9 of [`joseph_unrolled`].
#[inline(always)]
fn joseph_columns_0_to_9<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
) {
    triangle!(
        p, k, b, c;
        (0, 0),
        (0, 1),
        (1, 1),
        (0, 2),
        (1, 2),
        (2, 2),
        (0, 3),
        (1, 3),
        (2, 3),
        (3, 3),
        (0, 4),
        (1, 4),
        (2, 4),
        (3, 4),
        (4, 4),
        (0, 5),
        (1, 5),
        (2, 5),
        (3, 5),
        (4, 5),
        (5, 5),
        (0, 6),
        (1, 6),
        (2, 6),
        (3, 6),
        (4, 6),
        (5, 6),
        (6, 6),
        (0, 7),
        (1, 7),
        (2, 7),
        (3, 7),
        (4, 7),
        (5, 7),
        (6, 7),
        (7, 7),
        (0, 8),
        (1, 8),
        (2, 8),
        (3, 8),
        (4, 8),
        (5, 8),
        (6, 8),
        (7, 8),
        (8, 8),
        (0, 9),
        (1, 9),
        (2, 9),
        (3, 9),
        (4, 9),
        (5, 9),
        (6, 9),
        (7, 9),
        (8, 9),
        (9, 9),
    );
}

/// Columns 10 to 14 of [`joseph_unrolled`].
#[inline(always)]
fn joseph_columns_10_to_14<T: Real, const N: usize>(
    p: &mut [[T; N]; N],
    k: &[T; N],
    b: &[T; N],
    c: &[T; N],
) {
    triangle!(
        p, k, b, c;
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
        (10, 10),
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
        (11, 11),
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
        (12, 12),
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
        (13, 13),
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
        (14, 14),
    );
}

/// The loop form of [`joseph_pass`] (any N).
#[inline(always)]
pub(super) fn joseph_loop<T: Real, const N: usize>(
    p: &mut SMatrix<T, N, N>,
    k: &SVector<T, N>,
    b: &SVector<T, N>,
    c: &SVector<T, N>,
) {
    let (ks, bs, cs) = (k.as_slice(), b.as_slice(), c.as_slice());
    let flat = p.as_mut_slice();
    for (j, ((&kj, &cj), &bj)) in ks.iter().zip(cs).zip(bs).enumerate() {
        // `left` holds columns 0..j, `col_j` column j (column-major storage).
        let (left, right) = flat.split_at_mut(j * N);
        let Some(col_j) = right.get_mut(..N) else {
            break;
        };
        // Rows i < j of column j (upper triangle); each value also goes to row j of column i.
        for (((pij, &ki), &bi), col_i) in col_j
            .iter_mut()
            .zip(ks)
            .zip(bs)
            .zip(left.chunks_exact_mut(N))
        {
            let nv = *pij + ki * cj - bi * kj;
            *pij = nv;
            if let Some(mirror) = col_i.get_mut(j) {
                *mirror = nv;
            }
        }
        if let Some(pjj) = col_j.get_mut(j) {
            *pjj = *pjj + kj * cj - bj * kj;
        }
    }
}

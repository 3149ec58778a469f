//! The structured prediction of the covariance (stored as its upper triangle, axis-major, Φ
//! block-diagonal per axis chain) and of the state: `P ← Φ P Φᵀ + Q_d` per pair of axis blocks,
//! `x ← Φ x` per chain.
use super::super::model::flexure_chain_len;
use super::{at, put};
use crate::Real;
use nalgebra::{SMatrix, SVector};

/// The K×K block at rows `r0..`, columns `c0..` of a covariance stored as its upper
/// triangle (`c0 ≥ r0`), column-major `[col][row]`: an off-diagonal block (`DIAG` false,
/// c0 > r0) lies in the upper triangle; of a diagonal one (c0 = r0) only the upper half is
/// read (`DIAG`: the caller reads element (m, n), m > n, at (n, m)). One bounds check per
/// column (the offsets are run-time).
#[inline(always)]
fn block_of<T: Real, const K: usize, const N: usize>(
    p: &SMatrix<T, N, N>,
    r0: usize,
    c0: usize,
) -> [[T; K]; K] {
    let mut blk = [[T::zero(); K]; K];
    for (n, dst) in blk.iter_mut().enumerate() {
        if let Some(src) = p.data.0.get(c0 + n).and_then(|col| col.get(r0..r0 + K)) {
            dst.copy_from_slice(src);
        }
    }
    blk
}

/// [`block_times_phi_t`] and [`write_phi_times`] (the same expressions, so the same bits) column
/// by column: column j of `t = S Φ_bᵀ` (`S = P_ab` of `src`, or of `dst` when `None`), then
/// column j of `Φ_a t (+ Q_d,a if DIAG)` into `dst`; only S, one column of t and one row of
/// Φ_a are live at a time (no spills on the target for K ≤ 4).
#[inline(always)]
fn phi_block_phi_t<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    src: Option<&SMatrix<T, N, N>>,
    dst: &mut SMatrix<T, N, N>,
    (r0, c0): (usize, usize),
    pa: &SMatrix<T, K, K>,
    pb: &SMatrix<T, K, K>,
    q: &SMatrix<T, K, K>,
) {
    let kf = flexure_chain_len::<K>();
    let blk = block_of::<T, K, N>(src.unwrap_or(dst), r0, c0);
    let s = |m: usize, n: usize| {
        let (m, n) = if DIAG && m > n { (n, m) } else { (m, n) };
        blk.get(n)
            .and_then(|col| col.get(m))
            .copied()
            .unwrap_or_else(T::zero)
    };
    for j in 0..K {
        let mut t = [T::zero(); K];
        for (m, tm) in t.iter_mut().enumerate() {
            *tm = phi_row_dot(pb, j, kf, |n| s(m, n));
        }
        let tv = |m: usize| t.get(m).copied().unwrap_or_else(T::zero);
        write_column::<T, K, N, DIAG>(dst, (r0, c0), j, pa, q, tv);
    }
}

/// `Σ_m Φ_im v_m`, row `i` of an axis chain's Φ times `v`, summed from its first product
/// (not from 0: every chain has kf ≥ 2), using Φ's first column e₁ (θ_m is a random
/// constant: only the θ row reads `v_0`) and, past the flexure chain (`i ≥ kf`: a bias state,
/// a random constant), Φ's unit row (`v_i` itself). Every product with Φ or Φᵀ of this
/// module's covariance forms is this sum, so the forms give the same bits.
#[inline(always)]
fn phi_row_dot<T: Real, const K: usize>(
    phi: &SMatrix<T, K, K>,
    i: usize,
    kf: usize,
    v: impl Fn(usize) -> T,
) -> T {
    if i >= kf {
        return v(i);
    }
    let first = at(phi, i, 1) * v(1);
    let mut acc = if i == 0 { v(0) + first } else { first };
    for m in 2..kf {
        acc += at(phi, i, m) * v(m);
    }
    acc
}

/// Column `j` of `P_ab ← Φ_a t (+ Q_d,a on a diagonal block)` from column `j` of
/// `t = P_ab Φ_bᵀ` (`tv(m)` = t_mj), written to the block's upper-triangle entries of `p`
/// (rows `r0..r0 + K` of column `c0 + j`; all of them in an off-diagonal block, the upper half
/// of a diagonal one, `DIAG`).
#[inline(always)]
fn write_column<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    p: &mut SMatrix<T, N, N>,
    (r0, c0): (usize, usize),
    j: usize,
    pa: &SMatrix<T, K, K>,
    q: &SMatrix<T, K, K>,
    tv: impl Fn(usize) -> T,
) {
    let kf = flexure_chain_len::<K>();
    let Some(col) = p
        .data
        .0
        .get_mut(c0 + j)
        .and_then(|col| col.get_mut(r0..r0 + K))
    else {
        return;
    };
    let i_end = if DIAG { j + 1 } else { K };
    for i in 0..i_end {
        let mut acc = phi_row_dot(pa, i, kf, &tv);
        if DIAG {
            acc += at(q, i, j);
        }
        if let Some(e) = col.get_mut(i) {
            *e = acc;
        }
    }
}

/// `S Φ_bᵀ` of the block `S = P_ab` (rows `r0..`, columns `c0..` of the covariance `p`, stored
/// as its upper triangle; see [`block_of`]), using Φ's first column e₁ (θ_m is a random
/// constant, so in either parametrisation nothing feeds the first state but itself) and, in a
/// flight chain, the bias's unit row and column (a bias state, the last of a flight chain,
/// index ≥ kf, is a random constant: its row and column of Φ are unit vectors, so its products
/// are copies and it drops out of the sums).
#[inline(always)]
fn block_times_phi_t<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    p: &SMatrix<T, N, N>,
    r0: usize,
    c0: usize,
    pb: &SMatrix<T, K, K>,
) -> SMatrix<T, K, K> {
    let kf = flexure_chain_len::<K>();
    let blk = block_of::<T, K, N>(p, r0, c0);
    let s = |m: usize, n: usize| {
        let (m, n) = if DIAG && m > n { (n, m) } else { (m, n) };
        blk.get(n)
            .and_then(|col| col.get(m))
            .copied()
            .unwrap_or_else(T::zero)
    };
    // t_mj = Σ_n S_mn Φb_jn = S_m0 δ_j0 + Σ_{n≥1} S_mn Φb_jn.
    let mut t = SMatrix::<T, K, K>::zeros();
    for j in 0..K {
        for m in 0..K {
            put(&mut t, m, j, phi_row_dot(pb, j, kf, |n| s(m, n)));
        }
    }
    t
}

/// `P_ab ← Φ_a t (+ Q_d,a on a diagonal block)` with `t = P_ab Φ_bᵀ`: written to the block's
/// upper-triangle entries of `p` (all of an off-diagonal block a < b, the upper half of a
/// diagonal one, `DIAG`).
#[inline(always)]
fn write_phi_times<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    p: &mut SMatrix<T, N, N>,
    r0: usize,
    c0: usize,
    pa: &SMatrix<T, K, K>,
    t: &SMatrix<T, K, K>,
    q: &SMatrix<T, K, K>,
) {
    // d_ij = Σ_m Φa_im t_mj = t_0j δ_i0 + Σ_{m≥1} Φa_im t_mj.
    for j in 0..K {
        write_column::<T, K, N, DIAG>(p, (r0, c0), j, pa, q, |m| at(t, m, j));
    }
}

/// One block of [`predict_cov`]: `P_ab ← Φ_a P_ab Φ_bᵀ (+ Q_d,a if DIAG, a = b)`, the block at
/// rows `K a`, columns `K b`, reading `src` (or `dst` when `None`). Out of line, two copies
/// per N (diagonal and off-diagonal block): measured against six inlined blocks, +25
/// instructions per prediction (12 and 15 states) for 3.3 KB less flash in the filters' image
/// and 48 B less stack. The conventional filter's chains of 3 run the six blocks inlined in one
/// function instead ([`predict_cov_straight`]).
#[inline(never)]
fn predict_block<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    phi: &[SMatrix<T, K, K>; 3],
    q_d: &[SMatrix<T, K, K>; 3],
    src: Option<&SMatrix<T, N, N>>,
    dst: &mut SMatrix<T, N, N>,
    ab: (usize, usize),
) {
    block_into::<T, K, N, DIAG>(phi, q_d, src, dst, ab);
}

/// [`predict_block`]'s work (inlined into [`predict_cov_straight`] with constant blocks).
#[inline(always)]
fn block_into<T: Real, const K: usize, const N: usize, const DIAG: bool>(
    phi: &[SMatrix<T, K, K>; 3],
    q_d: &[SMatrix<T, K, K>; 3],
    src: Option<&SMatrix<T, N, N>>,
    dst: &mut SMatrix<T, N, N>,
    (a, b): (usize, usize),
) {
    let (Some(pa), Some(pb), Some(qa)) = (phi.get(a), phi.get(b), q_d.get(a)) else {
        return;
    };
    // A diagonal block's two transitions are one (a = b): its entries loaded once.
    let pb = if DIAG { pa } else { pb };
    if K <= 4 {
        // The paper's chains: column by column (S, one column of t and one row of Φ_a fit
        // the target's registers).
        phi_block_phi_t::<T, K, N, DIAG>(src, dst, (K * a, K * b), pa, pb, qa);
    } else {
        // The flight chain: S alone fills the registers; t whole, then Φ_a t (measured: the
        // column form costs the flight filter's prediction 68 instructions more).
        let t = match src {
            Some(m) => block_times_phi_t::<T, K, N, DIAG>(m, K * a, K * b, pb),
            None => block_times_phi_t::<T, K, N, DIAG>(dst, K * a, K * b, pb),
        };
        write_phi_times::<T, K, N, DIAG>(dst, K * a, K * b, pa, &t, qa);
    }
}

/// One prediction over `dt_s` of a covariance stored as its upper triangle: per pair of axes
/// a ≤ b, `P_ab ← Φ_a P_ab Φ_bᵀ (+ Q_d,a if a = b)` on the upper-triangle entries of `dst`
/// (the lower triangle is neither read nor written), reading `src` (or `dst` itself when
/// `None`: each block is read before it is written and read only once).
pub(in super::super) fn predict_cov<T: Real, const K: usize, const N: usize>(
    phi: &[SMatrix<T, K, K>; 3],
    q_d: &[SMatrix<T, K, K>; 3],
    src: Option<&SMatrix<T, N, N>>,
    dst: &mut SMatrix<T, N, N>,
) {
    // N = 3 K is checked at construction; stating it here lets the compiler prove every
    // block index below in bounds.
    if N != 3 * K {
        return;
    }
    if K == 3 {
        return predict_cov_straight::<T, K, N>(phi, q_d, src, dst);
    }
    for a in 0..3usize {
        predict_block::<T, K, N, true>(phi, q_d, src, dst, (a, a));
    }
    for ab in [(0, 1), (0, 2), (1, 2)] {
        predict_block::<T, K, N, false>(phi, q_d, src, dst, ab);
    }
}

/// [`predict_cov`] with the six blocks inlined (the same blocks in the same order, the same
/// bits): one call, every block offset a constant. For the chains of 3 states (the
/// conventional filter), where a block's work fits the registers: measured against the six
/// calls (a `qemu -d exec` trace of the 9-state step), 602 → 433 instructions a prediction
/// for +874 B of flash.
#[inline(never)]
fn predict_cov_straight<T: Real, const K: usize, const N: usize>(
    phi: &[SMatrix<T, K, K>; 3],
    q_d: &[SMatrix<T, K, K>; 3],
    src: Option<&SMatrix<T, N, N>>,
    dst: &mut SMatrix<T, N, N>,
) {
    block_into::<T, K, N, true>(phi, q_d, src, dst, (0, 0));
    block_into::<T, K, N, true>(phi, q_d, src, dst, (1, 1));
    block_into::<T, K, N, true>(phi, q_d, src, dst, (2, 2));
    block_into::<T, K, N, false>(phi, q_d, src, dst, (0, 1));
    block_into::<T, K, N, false>(phi, q_d, src, dst, (0, 2));
    block_into::<T, K, N, false>(phi, q_d, src, dst, (1, 2));
}

/// `x ← blockdiag(Φ_X, Φ_Y, Φ_Z) x`, each chain's `Φ x` summed over the columns in ascending
/// order from its first product, as the matrix product sums, using Φ's first column e₁ (the
/// θ row starts from x_θ itself, the other rows from their column-1 product; every chain has
/// K ≥ 3). Only the sign of a zero can differ from the full product's (a row of zeros summed
/// with the first column's 0·x_θ): the chains' diagonal is positive, so a row whose products
/// are all zero has a +0 among them, and the sums agree (the golden vectors replay
/// bit-identical). Not inlined: its callers' frames stay as they were (inlined, the chain's
/// copy took a stack slot of theirs: +72 B in the flight filter's step).
#[inline(never)]
pub(in super::super) fn predict_state<T: Real, const K: usize, const N: usize>(
    phi: &[SMatrix<T, K, K>; 3],
    x: &mut SVector<T, N>,
) {
    for (a, ph) in phi.iter().enumerate() {
        let mut chain = [T::zero(); K];
        for (d, v) in chain.iter_mut().enumerate() {
            *v = x.get(K * a + d).copied().unwrap_or_else(T::zero);
        }
        let xc = |n: usize| chain.get(n).copied().unwrap_or_else(T::zero);
        for i in 0..K {
            let first = at(ph, i, 1) * xc(1);
            let mut acc = if i == 0 { xc(0) + first } else { first };
            for n in 2..K {
                acc += at(ph, i, n) * xc(n);
            }
            if let Some(e) = x.get_mut(K * a + i) {
                *e = acc;
            }
        }
    }
}

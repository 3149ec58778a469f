//! The covariance health monitor of the propagation: an LDLᵀ pivot check of P after each
//! covariance step that runs on an IMU sample, and a lift only when the PSD margin is small.
//!
//! A covariance step's rounding moves the smallest eigenvalue of P's correlation matrix by a
//! few ε in either direction. Where process noise or the measurement updates keep that
//! eigenvalue far above ε (the flight configuration: a relative pivot of 2e-6 was never
//! reached in the consistency campaign's 6.5 million checks) the rounding is harmless and
//! nothing is added. Where they do not (no process noise and a seeker precise to 1e-5 rad,
//! or a long run without any update) the eigenvalue hovers at ε and rounding makes P
//! indefinite; the next precise update then amplifies the defect (a correlation eigenvalue
//! of −5e-6 grew to −1.8e-4 over six updates in the stress campaign). The check finds the
//! small margin before that and lifts it.

use super::error_model::STATES;
use super::filter::SeekerIns;
use crate::Real;
use nalgebra::SMatrix;

/// Relative variance added to every state after a covariance step that runs without the PSD
/// check ([`PSD_MARGIN_EPS`]) and without a check to follow: a step flushed by an update on
/// the same tick or by [`super::SeekerIns::predict_covariance`], and a step of the flight
/// navigator that starts from a P not checked since its last change; in units of ε of the
/// working precision: `P ← P + δ diag(P)`, `δ = 4 ε` (4.8e-7 in f32). The check costs
/// ≈ 8 800 instructions on the M4F, which the update's path and the navigator's
/// 20 000-instruction tick cannot carry on the same tick as a covariance step; 4 ε outpaces
/// the few ε a step's rounding moves the smallest correlation eigenvalue by. Along the
/// directions the seeker observes it acts as process noise: as the only stabilising noise of
/// every step it made the f32 flight configuration conservative (mean NEES per state 0.970
/// against f64's 1.021 over the consistency campaign).
pub const PROPAGATION_STABILISING_EPS: f64 = 4.0;

/// How a covariance step keeps P's PSD margin.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) enum PsdMargin {
    /// The LDLᵀ check of the margin, every variance lifted only when it is small
    /// ([`PSD_MARGIN_EPS`]): the stand-alone filter's step on an IMU sample.
    Checked,
    /// Every variance gains [`PROPAGATION_STABILISING_EPS`] ε: a step flushed by an update or
    /// by [`super::SeekerIns::predict_covariance`], and a step of the flight navigator from a
    /// P not checked since its last change.
    Constant,
    /// Nothing added: the caller checks P ([`super::SeekerIns::check_psd_margin`]) before the
    /// next covariance step — the flight navigator, on its next tick without a covariance
    /// step or an update. From a checked P (relative pivots ≥ [`PSD_MARGIN_EPS`] ε) the
    /// step's rounding moves the pivots by a few ε: P stays positive definite until the
    /// check. From a P not checked since its last change the caller adds the constant noise
    /// after the step ([`super::SeekerIns::add_stabilising_noise`]).
    Deferred,
}

/// Smallest relative LDLᵀ pivot `d_k / P_kk` of P kept after a covariance step, in units of
/// ε of the working precision (dimensionless): 16 ε (1.9e-6 in f32, 3.6e-15 in f64). The
/// relative pivots are the LDLᵀ pivots of P's correlation matrix; every pivot positive means
/// P positive definite, and each pivot bounds the correlation matrix's smallest eigenvalue
/// from above. Below the margin every variance gains `δ = margin − min pivot` of itself,
/// which raises every pivot by at least δ (Schur complement of `C + δ I`).
pub const PSD_MARGIN_EPS: f64 = 16.0;

/// The relative variance to add to every state of the exactly symmetric P
/// (`P ← P + δ diag(P)`) so that its LDLᵀ pivots relative to the diagonal reach
/// [`PSD_MARGIN_EPS`] ε: 0 when they already do (dimensionless). P is factored in place in its
/// strict upper triangle (left-looking: column j holds row j of L, every product a dot
/// product of two contiguous columns; no copy of P on the stack, no scratch in the filter)
/// and restored from the lower triangle, bit for bit; the diagonal is only read. A state of
/// zero variance (a row and column the repairs zeroed) is skipped; a non-positive pivot of a
/// state with a positive variance ends the factorisation (P is not positive definite) and
/// its relative value sets δ.
#[inline(never)]
pub(super) fn psd_lift<T: Real>(p: &mut SMatrix<T, STATES, STATES>) -> T {
    let margin = T::lit(PSD_MARGIN_EPS) * T::EPS;
    let zero = T::zero();
    let mut min_rel = margin;
    // 1 / d_k of the pivots so far (0 for a skipped state: its row of L is zero).
    let mut inv_d = [zero; STATES];
    // Column-major: `cols[c][r]` is P(r, c); the strict upper triangle of column j is r < j.
    let cols = &mut p.data.0;
    for j in 0..STATES {
        let Some((done, rest)) = cols.split_at_mut_checked(j) else {
            break;
        };
        let Some(col_j) = rest.first_mut() else {
            break;
        };
        let pjj = col_j.get(j).copied().unwrap_or(zero);
        if pjj <= zero {
            continue;
        }
        // w_i = P(i, j) − Σ_{k<i} w_k L(i, k), kept in column j; L(i, k) in column i.
        for (i, col_i) in done.iter().enumerate() {
            let Some((w_done, w_rest)) = col_j.split_at_mut_checked(i) else {
                break;
            };
            let Some(w_i) = w_rest.first_mut() else {
                break;
            };
            let dot = w_done
                .iter()
                .zip(col_i.iter())
                .fold(zero, |s, (w, l)| s + *w * *l);
            *w_i -= dot;
        }
        // L(j, i) = w_i / d_i and d_j = P(j, j) − Σ w_i L(j, i).
        let mut d = pjj;
        for (w, inv) in col_j.iter_mut().zip(inv_d.iter()).take(j) {
            let l = *w * *inv;
            d -= *w * l;
            *w = l;
        }
        let rel = d / pjj;
        if rel < min_rel {
            min_rel = rel;
        }
        if d <= zero {
            break;
        }
        if let Some(v) = inv_d.get_mut(j) {
            *v = T::one() / d;
        }
    }
    p.fill_upper_triangle_with_lower_triangle();
    margin - min_rel
}

impl<T: Real> SeekerIns<T> {
    /// Counts the repairs of a covariance step, then the PSD margin: with
    /// [`PsdMargin::Checked`] (the stand-alone filter's step on an IMU sample) P is checked
    /// and lifted only when the margin is small ([`PSD_MARGIN_EPS`]); with
    /// [`PsdMargin::Constant`] (a step flushed by an update or by
    /// [`Self::predict_covariance`], or a step of the flight navigator from a P not checked
    /// since its last change) every variance gains [`PROPAGATION_STABILISING_EPS`] ε; with
    /// [`PsdMargin::Deferred`] nothing (the caller's [`Self::check_psd_margin`] follows).
    /// Then the variances are limited.
    pub(super) fn after_covariance_step(&mut self, repairs: u32, margin: PsdMargin) {
        self.health.limits_hit = self.health.limits_hit.saturating_add(repairs);
        let delta = match margin {
            PsdMargin::Checked => psd_lift(&mut self.p),
            PsdMargin::Constant => T::lit(PROPAGATION_STABILISING_EPS) * T::EPS,
            PsdMargin::Deferred => T::zero(),
        };
        if delta > T::zero() {
            self.lift_variances(delta);
        } else {
            self.limit_variances();
        }
    }

    /// P's PSD-margin check on its own, outside a covariance step (after steps run with
    /// [`PsdMargin::Deferred`], and updates): every variance lifted by the relative `δ` of
    /// [`psd_lift`] when a relative LDLᵀ pivot is below [`PSD_MARGIN_EPS`] ε, then the
    /// variances limited (a limit counted in `Health::limits_hit`, a congruence a column kept
    /// beside the 17 does not follow). Returns `δ`, dimensionless (≤ 0: P unchanged, bit for
    /// bit). The flight navigator runs it on a tick without a covariance step or an update
    /// (≈ 9 000 instructions on the M4F, beside an IMU-only tick's ≈ 3 000).
    #[inline(never)]
    pub(crate) fn check_psd_margin(&mut self) -> T {
        let delta = psd_lift(&mut self.p);
        if delta > T::zero() {
            self.lift_variances(delta);
        }
        delta
    }

    /// The constant [`PROPAGATION_STABILISING_EPS`] ε of every variance after a covariance
    /// step run with [`PsdMargin::Deferred`] from a P not checked since its last change (the
    /// flight navigator's fallback when no quiet tick came between), then the variances
    /// limited (counted in `Health::limits_hit`). The same as the step with
    /// [`PsdMargin::Constant`] but for the ceilings, applied before and after the noise.
    pub(crate) fn add_stabilising_noise(&mut self) {
        self.lift_variances(T::lit(PROPAGATION_STABILISING_EPS) * T::EPS);
    }

    /// `P ← P + δ diag(P)`, then the ceilings. Not inlined: one copy for the step's margin,
    /// the check and the constant noise.
    #[inline(never)]
    fn lift_variances(&mut self, delta: T) {
        for (j, col) in self.p.as_mut_slice().chunks_exact_mut(STATES).enumerate() {
            if let Some(v) = col.get_mut(j) {
                *v += *v * delta;
            }
        }
        self.limit_variances();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn min_corr_eig(p: &SMatrix<f64, STATES, STATES>) -> f64 {
        let d = p.diagonal().map(|v| 1.0 / v.sqrt());
        SMatrix::<f64, STATES, STATES>::from_fn(|i, j| p[(i, j)] * d[i] * d[j])
            .symmetric_eigen()
            .eigenvalues
            .min()
    }

    /// A covariance with a known smallest correlation eigenvalue: `C = Q diag(λ) Qᵀ` scaled
    /// by state σ of very different sizes.
    fn covariance(lambda_min: f64) -> SMatrix<f64, STATES, STATES> {
        let a = SMatrix::<f64, STATES, STATES>::from_fn(|i, j| {
            ((i * 7 + j * 13) % 17) as f64 / 17.0 - 0.5 + if i == j { 0.3 } else { 0.0 }
        });
        let q = a.qr().q();
        let lam = SMatrix::<f64, STATES, STATES>::from_fn(|i, j| {
            if i != j {
                0.0
            } else if i == 5 {
                lambda_min
            } else {
                1.0 + i as f64
            }
        });
        let c = q * lam * q.transpose();
        let s = SMatrix::<f64, STATES, 1>::from_fn(|i, _| 10f64.powi(i as i32 % 7 - 3));
        SMatrix::<f64, STATES, STATES>::from_fn(|i, j| c[(i, j)] * s[i] * s[j])
    }

    /// `P ← P + δ diag(P)` with the lift of the check, until the check is satisfied; the
    /// number of lifts.
    fn lift_until_healthy(p: &mut SMatrix<f32, STATES, STATES>) -> usize {
        for n in 0..4 {
            let delta = psd_lift(p);
            if delta <= 0.0 {
                return n;
            }
            for i in 0..STATES {
                p[(i, i)] += p[(i, i)] * delta;
            }
        }
        usize::MAX
    }

    #[test]
    fn restores_p_bit_for_bit_and_lifts_only_a_small_margin() {
        for lambda in [1e-2, 1e-4, 1e-8, 0.0, -1e-3] {
            let p64 = covariance(lambda);
            let mut p: SMatrix<f32, STATES, STATES> = p64.map(|v| v as f32);
            p.fill_lower_triangle_with_upper_triangle();
            let before = p;
            let delta = psd_lift(&mut p);
            assert_eq!(p, before, "P changed by the check (λ {lambda:e})");
            if lambda >= 1e-4 {
                // Every relative pivot ≥ the correlation matrix's smallest eigenvalue
                // ≥ λ / 17 > the margin: nothing to lift.
                assert!(delta <= 0.0, "lift {delta:e} at λ {lambda:e}");
            }
            if lambda < 0.0 {
                assert!(delta > 0.0, "no lift at λ {lambda:e}");
            }
            let lifts = lift_until_healthy(&mut p);
            assert!(lifts <= 2, "λ {lambda:e}: {lifts} lifts");
            let e = min_corr_eig(&p.map(f64::from));
            assert!(e > 0.0, "λ {lambda:e}: after {lifts} lifts {e:e}");
        }
    }

    #[test]
    fn zero_variance_states_are_skipped() {
        let mut p = covariance(1e-2);
        for k in 0..STATES {
            p[(3, k)] = 0.0;
            p[(k, 3)] = 0.0;
        }
        let p = (p + p.transpose()) * 0.5;
        let mut q = p;
        assert!(psd_lift(&mut q) <= 0.0);
        assert_eq!(q, p);
    }
}

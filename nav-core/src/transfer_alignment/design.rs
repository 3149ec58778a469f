//! The configuration-time design of a transfer-alignment filter: the three per-axis discrete
//! chains (exact Φ_j, Q_d,j and the initial covariance P0_j), computed by
//! [`TaDesign::compute`] and consumed by
//! [`TransferAlignment::from_design`](super::TransferAlignment::from_design), which does not
//! run the discretisation (see [`crate::design`]).
use super::filter::TaConfig;
use super::model::{axis_chains, AxisChain, FlexureModel};
use crate::design::{DesignValues, ValueReader, ValueWriter};
use crate::math::checks::{first_row_and_column_unit, symmetric_non_negative_diagonal};
use crate::{NavError, Real};
use nalgebra::SMatrix;

/// Precomputed design of a transfer-alignment filter with `K` states per axis chain
/// (K = 3: [`super::ConventionalFilter`], K = 4: [`super::ProposedFilter`]).
///
/// It depends on the configuration's `flexure`, `mount_sigma_rad` and `dt_s` only.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaDesign<T: Real, const K: usize> {
    /// Per-axis chains X, Y, Z (F_j, Q_c,j, Φ_j, Q_d,j, P0_j; see [`AxisChain`]).
    pub chains: [AxisChain<T, K>; 3],
}

impl<T: Real, const K: usize> TaDesign<T, K> {
    /// Validates the configuration (as [`TaConfig::validate`]) and discretises the three axis
    /// chains exactly at `dt_s` (spec "Flexure models": Φ_j = exp(F_j Δt), Van Loan Q_d,j,
    /// stationary flexure covariance in P0_j).
    ///
    /// Errors: `InvalidConfig` for a chain length other than 3 or 4 or an invalid field,
    /// the discretisation's errors.
    pub fn compute(cfg: &TaConfig<T>) -> Result<Self, NavError> {
        FlexureModel::for_chain::<K>()?;
        cfg.validate()?;
        let chains = axis_chains::<T, K>(&cfg.flexure, &cfg.mount_sigma_rad, cfg.dt_s)?;
        Ok(Self { chains })
    }
}

/// Value order: for each axis X, Y, Z in turn, the chain's five K×K matrices `f`, `q_c`,
/// `phi`, `q_d`, `p0`, each column by column: `COUNT = 3 · 5 · K²` (135 for K = 3, 240 for
/// K = 4). `read_values` checks the length and finiteness only; the structure (symmetry,
/// non-negative variances) is checked by `from_design`.
impl<T: Real, const K: usize> DesignValues for TaDesign<T, K> {
    const COUNT: usize = 15 * K * K;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        for ch in &self.chains {
            for m in [&ch.f, &ch.q_c, &ch.phi, &ch.q_d, &ch.p0] {
                w.matrix(m);
            }
        }
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let z = SMatrix::<T, K, K>::zeros();
        let mut chains = [AxisChain {
            f: z,
            q_c: z,
            phi: z,
            q_d: z,
            p0: z,
        }; 3];
        // (`opaque`: the loop stays rolled, one call site of `fill_parts`.)
        for ch in crate::math::checks::opaque(chains.as_mut_slice()).iter_mut() {
            r.fill_parts(&mut [
                ch.f.as_mut_slice(),
                ch.q_c.as_mut_slice(),
                ch.phi.as_mut_slice(),
                ch.q_d.as_mut_slice(),
                ch.p0.as_mut_slice(),
            ])?;
        }
        r.finish()?;
        Ok(Self { chains })
    }
}

impl<T: Real, const K: usize> TaDesign<T, K> {
    /// The structural checks of [`super::TransferAlignment::from_design`] (finiteness is
    /// checked there): per chain, `q_d` and `p0` exactly symmetric with a non-negative
    /// diagonal, Φ's first row and column `e₁` (θ_m is a random constant: the prediction
    /// relies on it), and the θ_m variance `p0[0,0] = mount_sigma_rad²` of the configuration.
    /// Errors: `InvalidConfig { field: "design.q_d" | "design.p0" | "design.phi", issue:
    /// OutOfRange }`.
    pub(super) fn check_structure(&self, cfg: &TaConfig<T>) -> Result<(), NavError> {
        let mounts = [
            cfg.mount_sigma_rad.x,
            cfg.mount_sigma_rad.y,
            cfg.mount_sigma_rad.z,
        ];
        let [x, y, z] = &self.chains;
        chains_structure(
            &[
                [x.q_d.as_slice(), x.p0.as_slice(), x.phi.as_slice()],
                [y.q_d.as_slice(), y.p0.as_slice(), y.phi.as_slice()],
                [z.q_d.as_slice(), z.p0.as_slice(), z.phi.as_slice()],
            ],
            &mounts,
            K,
        )
    }
}

/// [`TaDesign::check_structure`] over the chains' `[q_d, p0, phi]` (column-major `k × k`
/// slices) and the mount σ of each axis, in the same order (per chain: Q_d, P0 symmetry and
/// diagonal, P0's θ_m variance, Φ's e₁ row and column). Not generic over `k` and out of line:
/// one copy for both filters.
#[inline(never)]
fn chains_structure<T: Real>(chains: &[[&[T]; 3]], mounts: &[T], k: usize) -> Result<(), NavError> {
    let (chains, mounts, k) = crate::math::checks::opaque((chains, mounts, k));
    for ([q_d, p0, phi], m) in chains.iter().zip(mounts) {
        for (field, mat) in [("design.q_d", q_d), ("design.p0", p0)] {
            // `mat == matᵀ` and a non-negative diagonal.
            if !symmetric_non_negative_diagonal(mat, k) {
                return Err(bad(field));
            }
        }
        if p0.first().copied() != Some(*m * *m) {
            return Err(bad("design.p0"));
        }
        if !first_row_and_column_unit(phi, k) {
            return Err(bad("design.phi"));
        }
    }
    Ok(())
}

#[cold]
#[inline(never)]
fn bad(field: &'static str) -> NavError {
    NavError::InvalidConfig {
        field,
        issue: crate::error::ConfigIssue::OutOfRange,
    }
}

//! The configuration-time design of a transfer-alignment filter: the three per-axis discrete
//! chains (exact Φ_j, Q_d,j and the initial covariance P0_j) and the [`DesignStamp`] of the
//! configuration they were computed for. Computed by
//! [`Estimator::design`](crate::Estimator::design), consumed by
//! [`Estimator::from_design`](crate::Estimator::from_design), which does not run the
//! discretisation (see [`crate::design`]).
use super::config::TaConfig;
use super::model::{axis_chains, has_accel_bias, AxisChain, FlexureModel};
use crate::contract::{DesignStamp, Fingerprint};
use crate::design::{DesignValues, ValueReader, ValueWriter, BAD_VALUES};
use crate::math::checks::{first_row_and_column_unit, symmetric_non_negative_diagonal};
use crate::{NavError, Real};
use nalgebra::SMatrix;

/// Layout version of [`TaDesign`]'s value list.
pub const TA_DESIGN_VERSION: u16 = 1;

/// Precomputed design of a transfer-alignment filter with `K` states per axis chain
/// (K = 3: [`super::ConventionalFilter`], K = 4: [`super::ProposedFilter`], K = 5:
/// [`super::FlightFilter`]).
///
/// It depends on the configuration's `flexure`, `mount_sigma_rad` and `dt_s` only (and, for
/// K = 5, `accel_bias_sigma_m_s2`); its [`stamp`](Self::stamp) fingerprints them
/// ([`TaDesign::stamp_for`]).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TaDesign<T: Real, const K: usize> {
    /// Layout version and fingerprint of the configuration the design was computed for.
    pub stamp: DesignStamp,
    /// Per-axis chains X, Y, Z (F_j, Q_c,j, Φ_j, Q_d,j, P0_j; see [`AxisChain`]).
    pub chains: [AxisChain<T, K>; 3],
}

impl<T: Real, const K: usize> TaDesign<T, K> {
    /// Validates the configuration (as [`TaConfig::validate`]) and discretises the three axis
    /// chains exactly at `dt_s` (spec "Flexure models": Φ_j = exp(F_j Δt), Van Loan Q_d,j,
    /// stationary flexure covariance in P0_j).
    ///
    /// Errors: `InvalidConfig` for a chain length other than 3, 4 or 5 or an invalid field,
    /// the discretisation's errors.
    pub(super) fn compute(cfg: &TaConfig<T>) -> Result<Self, NavError> {
        FlexureModel::for_chain::<K>()?;
        cfg.validate()?;
        let chains = axis_chains::<T, K>(
            &cfg.flexure,
            &cfg.mount_sigma_rad,
            &cfg.accel_bias_sigma_m_s2,
            cfg.dt_s,
        )?;
        Ok(Self {
            stamp: Self::stamp_for(cfg),
            chains,
        })
    }

    /// The stamp of a design of this chain length computed for `cfg`: version
    /// [`TA_DESIGN_VERSION`] and the [`Fingerprint`] of, in this order, the chain length `K`,
    /// then per axis X, Y, Z the flexure `sigma_rad` and `tau_s`, then `mount_sigma_rad` X, Y,
    /// Z, then `dt_s`, and — for the flight configuration's chains with a bias state only
    /// ([`super::FlightFilter`]) — `accel_bias_sigma_m_s2` X, Y, Z after it. The gate, recovery,
    /// noise, lever arm, tolerance and gap settings are not in it: the design does not depend
    /// on them.
    pub fn stamp_for(cfg: &TaConfig<T>) -> DesignStamp {
        let mut fp = Fingerprint::new().count(u32::try_from(K).unwrap_or(u32::MAX));
        for fl in &cfg.flexure {
            fp = fp.real(fl.sigma_rad).real(fl.tau_s);
        }
        for v in cfg.mount_sigma_rad.iter() {
            fp = fp.real(*v);
        }
        fp = fp.real(cfg.dt_s);
        if has_accel_bias::<K>() {
            for v in cfg.accel_bias_sigma_m_s2.iter() {
                fp = fp.real(*v);
            }
        }
        DesignStamp {
            version: TA_DESIGN_VERSION,
            fingerprint: fp.finish(),
        }
    }
}

/// Value order: the stamp's `version` and `fingerprint` (two integers), then for each axis X,
/// Y, Z in turn the chain's five K×K matrices `f`, `q_c`, `phi`, `q_d`, `p0`, each column by
/// column: `COUNT = 2 + 3 · 5 · K²` (137 for K = 3, 242 for K = 4, 377 for K = 5). `read_values` checks the
/// length, finiteness and the stamp's integers only; the structure (symmetry, non-negative
/// variances) and the stamp's match with the configuration are checked by `from_design`.
impl<T: Real, const K: usize> DesignValues for TaDesign<T, K> {
    const COUNT: usize = 2 + 15 * K * K;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        w.push(f64::from(self.stamp.version));
        w.push(f64::from(self.stamp.fingerprint));
        for ch in &self.chains {
            for m in [&ch.f, &ch.q_c, &ch.phi, &ch.q_d, &ch.p0] {
                w.matrix(m);
            }
        }
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let version = integer(r.value()?, u16::MAX.into())?;
        let fingerprint = integer(r.value()?, u32::MAX.into())?;
        let z = SMatrix::<T, K, K>::zeros();
        let chain = AxisChain {
            f: z,
            q_c: z,
            phi: z,
            q_d: z,
            p0: z,
        };
        let [mut x, mut y, mut zc] = [chain; 3];
        r.fill_parts(&mut [
            x.f.as_mut_slice(),
            x.q_c.as_mut_slice(),
            x.phi.as_mut_slice(),
            x.q_d.as_mut_slice(),
            x.p0.as_mut_slice(),
            y.f.as_mut_slice(),
            y.q_c.as_mut_slice(),
            y.phi.as_mut_slice(),
            y.q_d.as_mut_slice(),
            y.p0.as_mut_slice(),
            zc.f.as_mut_slice(),
            zc.q_c.as_mut_slice(),
            zc.phi.as_mut_slice(),
            zc.q_d.as_mut_slice(),
            zc.p0.as_mut_slice(),
        ])?;
        r.finish()?;
        Ok(Self {
            stamp: DesignStamp {
                version: u16::try_from(version).map_err(|_| BAD_VALUES)?,
                fingerprint: u32::try_from(fingerprint).map_err(|_| BAD_VALUES)?,
            },
            chains: [x, y, zc],
        })
    }
}

/// A stored non-negative integer not above `max` (`BAD_VALUES` otherwise).
fn integer(v: f64, max: u64) -> Result<u64, NavError> {
    // Exact for integers below 2⁵³: `max` ≤ u32::MAX.
    if v >= 0.0 && v <= max as f64 && v == libm::floor(v) {
        Ok(v as u64)
    } else {
        Err(BAD_VALUES)
    }
}

impl<T: Real, const K: usize> TaDesign<T, K> {
    /// The checks of `from_design` on the design itself: its stamp against `cfg`
    /// ([`DesignStamp::check`]: `InvalidConfig { field: "design", issue: DesignMismatch }`),
    /// every Φ, Q_d, P0 value finite (`InvalidConfig { field: "flexure" }`), then per chain
    /// `q_d` and `p0` exactly symmetric with a non-negative diagonal, Φ's first row and column
    /// `e₁` (θ_m is a random constant: the prediction relies on it), and the θ_m variance
    /// `p0[0,0] = mount_sigma_rad²` of the configuration (`InvalidConfig { field: "design.q_d"
    /// | "design.p0" | "design.phi", issue: OutOfRange }`).
    pub(super) fn check(&self, cfg: &TaConfig<T>) -> Result<(), NavError> {
        self.stamp.check(&Self::stamp_for(cfg))?;
        let [x, y, z] = &self.chains;
        if !crate::math::checks::all_finite_parts(&[
            x.p0.as_slice(),
            x.phi.as_slice(),
            x.q_d.as_slice(),
            y.p0.as_slice(),
            y.phi.as_slice(),
            y.q_d.as_slice(),
            z.p0.as_slice(),
            z.phi.as_slice(),
            z.q_d.as_slice(),
        ]) {
            return Err(super::config::out_of_range("flexure"));
        }
        let m = &cfg.mount_sigma_rad;
        chain_structure(x.q_d.as_slice(), x.p0.as_slice(), x.phi.as_slice(), m.x, K)?;
        chain_structure(y.q_d.as_slice(), y.p0.as_slice(), y.phi.as_slice(), m.y, K)?;
        chain_structure(z.q_d.as_slice(), z.p0.as_slice(), z.phi.as_slice(), m.z, K)
    }
}

/// The structural checks of one chain (column-major `k × k` slices `q_d`, `p0`, `phi` and the
/// axis' mount σ): Q_d, P0 symmetry and diagonal, P0's θ_m variance, Φ's e₁ row and column.
/// Not generic over `k` and out of line: one copy for both filters.
#[inline(never)]
fn chain_structure<T: Real>(
    q_d: &[T],
    p0: &[T],
    phi: &[T],
    mount_sigma_rad: T,
    k: usize,
) -> Result<(), NavError> {
    if !symmetric_non_negative_diagonal(q_d, k) {
        return Err(super::config::out_of_range("design.q_d"));
    }
    if !symmetric_non_negative_diagonal(p0, k)
        || p0.first().copied() != Some(mount_sigma_rad * mount_sigma_rad)
    {
        return Err(super::config::out_of_range("design.p0"));
    }
    if !first_row_and_column_unit(phi, k) {
        return Err(super::config::out_of_range("design.phi"));
    }
    Ok(())
}

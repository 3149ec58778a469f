//! The value lists of the loops' designs ([`DesignValues`] of [`ClassicalDesign`] and
//! [`AidedDesign`]): what `from_design` reads back and `write_values` stores.

use super::super::gains::{AidedGains, ClassicalGains};
use super::super::sigma::{SigmaDesign, SIGMA_DESIGN_COUNT};
use super::{
    read_gravity_step, read_modes, read_stamp, write_gravity, write_modes, write_stamp,
    AidedDesign, ClassicalDesign, MODES_COUNT,
};
use crate::design::{DesignValues, ValueReader, ValueWriter, BAD_VALUES};
use crate::{NavError, Real};
use nalgebra::{Matrix2x3, Matrix3, Matrix3x2, Vector2};

/// Value order (235 values): the stamp `version, fingerprint` (2); the gains `c1_per_s,
/// c2_per_s2, c3_per_s3, c4_s, c_per_s2` (5); gravity `g0_m_s2, g1_per_s2, g2_per_m_s2` (3);
/// `imu_dt_s`, half of it, `baro_lag_s` (3); the modes (57): Φ_baro (3×3), then N and G (3×2
/// each) of the modes none, baro, velocity, both; then the σ design (165): the covariance
/// interval (µs), Φ and Q (4×4 each) of the modes none, baro, velocity, both, the design mode's
/// use of the velocity aid (0 or 1), P∞ and P₀ (4×4), the baro and velocity-aid white-noise
/// variances and the lag; matrices column by column.
impl<T: Real> DesignValues for ClassicalDesign<T> {
    const COUNT: usize = 2 + 5 + 3 + 3 + MODES_COUNT + SIGMA_DESIGN_COUNT;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        write_stamp(&mut w, &self.stamp);
        let g = &self.gains;
        for v in [g.c1_per_s, g.c2_per_s2, g.c3_per_s3, g.c4_s, g.c_per_s2] {
            w.push(v);
        }
        write_gravity(&mut w, &self.gravity);
        self.step.write(&mut w);
        write_modes(&mut w, &self.modes);
        self.sigma.write(&mut w);
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let stamp = read_stamp(&mut r)?;
        let mut g = [0.0; 5];
        r.fill_f64(&mut g)?;
        let [c1_per_s, c2_per_s2, c3_per_s3, c4_s, c_per_s2] = g;
        let gains = ClassicalGains {
            c1_per_s,
            c2_per_s2,
            c3_per_s3,
            c4_s,
            c_per_s2,
        };
        let (gravity, step, _) = read_gravity_step::<T, 6>(&mut r)?;
        let modes = read_modes(&mut r)?;
        let sigma = SigmaDesign::read(&mut r)?;
        r.finish()?;
        Ok(Self {
            stamp,
            gains,
            modes,
            gravity,
            step,
            sigma,
        })
    }
}

/// Value order (275 values): the stamp `version, fingerprint` (2); the gains (43): `k` (3×2),
/// `p` (3×3), `a` (3×3), `q` (3×3), `c` (2×3), `r` (2), `riccati_iterations` (an integer),
/// `relative_residual`; gravity `g0_m_s2, g1_per_s2, g2_per_m_s2` (3); `imu_dt_s`, half of it,
/// `baro_lag_s` (3); the design innovation variances baro, velocity (2); the modes (57):
/// Φ_baro (3×3), then N and G (3×2 each) of the modes none, baro, velocity, both; the σ design
/// (165, as in [`ClassicalDesign`]'s list); matrices column by column.
impl<T: Real> DesignValues for AidedDesign<T> {
    const COUNT: usize = 2 + 43 + 3 + 3 + 2 + MODES_COUNT + SIGMA_DESIGN_COUNT;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        write_stamp(&mut w, &self.stamp);
        let g = &self.gains;
        w.matrix_f64(&g.k);
        w.matrix_f64(&g.p);
        w.matrix_f64(&g.a);
        w.matrix_f64(&g.q);
        w.matrix_f64(&g.c);
        w.matrix_f64(&g.r);
        w.push(f64::from(g.riccati_iterations));
        w.push(g.relative_residual);
        write_gravity(&mut w, &self.gravity);
        self.step.write(&mut w);
        w.real(self.baro_innovation_variance);
        w.real(self.velocity_innovation_variance);
        write_modes(&mut w, &self.modes);
        self.sigma.write(&mut w);
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let stamp = read_stamp(&mut r)?;
        let mut gains = AidedGains {
            k: Matrix3x2::zeros(),
            p: Matrix3::zeros(),
            a: Matrix3::zeros(),
            q: Matrix3::zeros(),
            c: Matrix2x3::zeros(),
            r: Vector2::zeros(),
            riccati_iterations: 0,
            relative_residual: 0.0,
        };
        r.fill_parts_f64(&mut [
            gains.k.as_mut_slice(),
            gains.p.as_mut_slice(),
            gains.a.as_mut_slice(),
            gains.q.as_mut_slice(),
            gains.c.as_mut_slice(),
            gains.r.as_mut_slice(),
        ])?;
        let it = r.value()?;
        // An iteration count: a non-negative integer that fits a u32 (exact round trip).
        let iterations = it as u32;
        if f64::from(iterations) != it {
            return Err(BAD_VALUES);
        }
        gains.riccati_iterations = iterations;
        gains.relative_residual = r.value()?;
        let (gravity, step, v) = read_gravity_step::<T, 8>(&mut r)?;
        let [.., baro_innovation_variance, velocity_innovation_variance] = v;
        let modes = read_modes(&mut r)?;
        let sigma = SigmaDesign::read(&mut r)?;
        r.finish()?;
        Ok(Self {
            stamp,
            gains,
            modes,
            gravity,
            step,
            sigma,
            baro_innovation_variance,
            velocity_innovation_variance,
        })
    }
}

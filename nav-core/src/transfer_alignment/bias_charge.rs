//! The flight alignment's difference bias in a manoeuvre: the variance its random-constant
//! model needs when the specific force changes.
//!
//! The bias the flight configuration estimates per axis is the master's minus the slave's
//! *equivalent* bias, `b(f) = b_m − b_s − (S + M) f` (slave axes; `S` the slave
//! accelerometers' scale-factor errors, diagonal, 1σ `σ_S` each, dimensionless; `M` their
//! misalignment, off-diagonal, 1σ `σ_M` each, rad; all independent). Its prior holds the
//! share of level carry, `f_level = (0, 0, −g)` ([`super::slave_share_variance`]). When the
//! specific force moves, the bias moves with it, deterministically for a given instrument:
//! `b(f) = b(f_level) − (S + M) d`, `d = f − f_level`, with per-axis variance
//!
//! ```text
//! v_i(d) = σ_S² d_i² + σ_M² (|d|² − d_i²)      (m/s²)²   (d in m/s²)
//! ```
//!
//! The model's random constant takes that change as information unless its variance is given
//! to the bias states ([`share_change_variance`]). The change is one random matrix times a
//! known vector, so its increments are fully correlated: a random walk charging `v(Δf)` per
//! step would add `Σ v(Δf_k) → 0` as the step shrinks (a smooth departure `d` in `n` equal
//! steps gets `v(d)/n`), far below the `v(d)` the departure makes. What is charged instead is
//! every change of `v(d)` itself, in either direction ([`share_charge`]): a monotone departure
//! from level carry adds exactly `v(d)` (the variance of the bias's move away from what level
//! carry taught the filter); the way back adds it again (the filter may have learned the
//! manoeuvre's bias meanwhile, and the return moves the bias by `(S + M)(−d)`, variance
//! `v(d)`). Bounded by the instrument errors' σ; no tuning constant. Conservative where the
//! filter learned only part of the manoeuvre's bias, or where the force reverses without
//! passing level carry (the bound is the total variation of `v(d)` along the path).
//!
//! The charge is added to the bias diagonal of the current covariance (and of the
//! predictions run ahead, which carry it unchanged: the bias is a random constant, its row
//! and column of Φ are unit vectors and it has no process noise), after the step at the new
//! force: the next epoch's updates see it ([`TransferAlignment::charge_accel_bias_variance`]).
use super::filter::TransferAlignment;
use super::model::{has_accel_bias, BIAS_STATE};
use crate::{NavError, Real};
use nalgebra::{Matrix3, Vector3};

/// The specific force of level carry the alignment's prior share refers to, slave axes, m/s²:
/// `(0, 0, −g)` with `g` [`crate::earth::GRAVITY_POLE_M_S2`], as
/// [`super::slave_share_variance`] takes it.
pub fn level_carry_force<T: Real>() -> Vector3<T> {
    Vector3::new(
        T::zero(),
        T::zero(),
        -T::lit(crate::earth::GRAVITY_POLE_M_S2),
    )
}

/// Variance per slave axis X, Y, Z of the error the slave accelerometers' scale factors put
/// into the misalignment θ through the flexure's lever-arm acceleration, rad²: the wing's
/// angular acceleration `θ̈_k` about axis `k` moves the pylon by `u_k θ̈_k`, `u_k = L₀ × e_k`,
/// the rows see θ through `u_k × θ` and the scale factor `S` adds `S u_k θ̈_k`, proportional to
/// the same signal, so it never averages out: the least-squares θ_k is off by
/// `(u_k × S u_k)_k / |u_k|² = L_i L_j (S_i − S_j) / (L_i² + L_j²)` (i, j the other axes),
/// variance `2 σ_S² (L_i L_j / (L_i² + L_j²))²`, at most `σ_S² / 2`. `scale_factor`: 1σ of
/// each axis' scale-factor error, dimensionless; `lever_arm_m`: `L₀`, m. Zero about an axis
/// the lever arm lies along (no acceleration) or across one axis only.
pub fn flexure_share_variance<T: Real>(scale_factor: T, lever_arm_m: &Vector3<T>) -> Vector3<T> {
    let l = lever_arm_m;
    let two_s2 = T::lit(2.0) * scale_factor * scale_factor;
    let axis = |a: T, b: T| {
        let den = a * a + b * b;
        if den > T::zero() {
            let c = a * b / den;
            two_s2 * c * c
        } else {
            T::zero()
        }
    };
    Vector3::new(axis(l.y, l.z), axis(l.z, l.x), axis(l.x, l.y))
}

/// Variance per slave axis X, Y, Z of the change `(S + M) d` of the slave's equivalent
/// accelerometer bias when the specific force changes by `d_m_s2` (m/s², slave axes):
/// `σ_S² d_i² + σ_M² (|d|² − d_i²)`, (m/s²)² (module doc). `scale_factor`: 1σ of each axis'
/// scale-factor error, dimensionless; `misalignment_rad`: 1σ of each off-diagonal element of
/// M, rad.
pub fn share_change_variance<T: Real>(
    scale_factor: T,
    misalignment_rad: T,
    d_m_s2: &Vector3<T>,
) -> Vector3<T> {
    let sq = d_m_s2.component_mul(d_m_s2);
    let total = sq.x + sq.y + sq.z;
    let (s2, m2) = (
        scale_factor * scale_factor,
        misalignment_rad * misalignment_rad,
    );
    sq.map(|x| s2 * x + m2 * (total - x))
}

/// The variance to charge per axis to the alignment's bias states, (m/s²)², when the
/// specific force (slave axes, m/s²; the lever-arm-compensated master force serves, within
/// θ of it) moves from `f_prev_m_s2` to `f_now_m_s2` between two fused epochs: the change of
/// the share's variance about level carry, `|v(f_now − f_level) − v(f_prev − f_level)|`
/// ([`share_change_variance`], [`level_carry_force`]; module doc). At the first epoch pass
/// [`level_carry_force`] as `f_prev_m_s2` (what the prior covers). Non-negative; NaN for a
/// non-finite force (refused by [`TransferAlignment::charge_accel_bias_variance`]).
pub fn share_charge<T: Real>(
    scale_factor: T,
    misalignment_rad: T,
    f_prev_m_s2: &Vector3<T>,
    f_now_m_s2: &Vector3<T>,
) -> Vector3<T> {
    let level = level_carry_force::<T>();
    let before = share_change_variance(scale_factor, misalignment_rad, &(f_prev_m_s2 - level));
    let now = share_change_variance(scale_factor, misalignment_rad, &(f_now_m_s2 - level));
    (now - before).map(|x| x.abs())
}

impl<T: Real, const K: usize, const N: usize> TransferAlignment<T, K, N> {
    /// Adds `add_m2_s4` ((m/s²)² per axis X, Y, Z) to the variances of the
    /// specific-force-difference bias states (the flight configuration; a filter without them
    /// is left as it is): the current covariance, and the predictions run ahead
    /// ([`Self::predict_ahead`]) alike, which carry a bias variance unchanged (module doc).
    /// Errors (nothing changed): `NonFiniteInput` / `InputOutOfRange { input:
    /// "accel_bias_charge" }` unless every component is finite and non-negative.
    pub fn charge_accel_bias_variance(&mut self, add_m2_s4: &Vector3<T>) -> Result<(), NavError> {
        const INPUT: &str = "accel_bias_charge";
        if !add_m2_s4.iter().all(|v| v.is_finite()) {
            return Err(NavError::NonFiniteInput { input: INPUT });
        }
        if !add_m2_s4.iter().all(|v| *v >= T::zero()) {
            return Err(NavError::InputOutOfRange { input: INPUT });
        }
        if !has_accel_bias::<K>() {
            return Ok(());
        }
        let both = self.ahead.is_some();
        let second = self.second;
        for (which, p) in self.p.iter_mut().enumerate() {
            // Buffer `second as usize` is current; the other holds the predictions ahead.
            if (which == usize::from(second)) || both {
                for (a, add) in add_m2_s4.iter().enumerate() {
                    let i = K * a + BIAS_STATE;
                    if let Some(v) = p.get_mut((i, i)) {
                        *v += *add;
                    }
                }
            }
        }
        Ok(())
    }

    /// [`Self::charge_accel_bias_variance`] of [`share_charge`] for the specific force
    /// moving from `f_prev_m_s2` (the last fused epoch's; `None` before the first: level
    /// carry's, what the prior covers) to `f_now_m_s2` (m/s², slave axes), with the slave
    /// accelerometers' `scale_factor` (dimensionless) and `misalignment_rad` (rad) 1σ. A
    /// non-finite force charges nothing (refused, nothing changed).
    pub fn charge_share_change(
        &mut self,
        scale_factor: T,
        misalignment_rad: T,
        f_prev_m_s2: Option<Vector3<T>>,
        f_now_m_s2: &Vector3<T>,
    ) {
        let prev = f_prev_m_s2.unwrap_or_else(level_carry_force);
        let add = share_charge(scale_factor, misalignment_rad, &prev, f_now_m_s2);
        let _ = self.charge_accel_bias_variance(&add);
    }

    /// Covariance of the specific-force-difference bias states across the axes X, Y, Z,
    /// (m/s²)²; zero for a filter without them.
    pub fn accel_bias_covariance(&self) -> Matrix3<T> {
        if has_accel_bias::<K>() {
            Matrix3::from_fn(|a, b| {
                super::covariance::upper_at(self.p_cur(), K * a + BIAS_STATE, K * b + BIAS_STATE)
            })
        } else {
            Matrix3::zeros()
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::contract::Estimator;
    use crate::time::Timestamp;
    use crate::transfer_alignment::{
        FlightFilter, MasterSample, PaperCase, SlaveSample, TaConfig, TaInitial,
    };

    /// Scale-factor 1σ (200 ppm) and misalignment 1σ (10″, rad) of the slave accelerometers.
    const SF: f64 = 2.0e-4;
    const MIS: f64 = 4.848e-5;

    #[test]
    fn share_change_variance_is_the_variance_of_s_plus_m_times_d() {
        // Each element of (S + M) independent: var(Σ_j G_ij d_j) = Σ_j var(G_ij) d_j².
        let d = Vector3::new(1.5_f64, -2.0, 5.5);
        let v = share_change_variance(SF, MIS, &d);
        for i in 0..3 {
            let want: f64 = (0..3)
                .map(|j| if i == j { SF * SF } else { MIS * MIS } * d[j] * d[j])
                .sum();
            assert!(
                (v[i] - want).abs() <= 1e-12 * want,
                "axis {i}: {} vs {want}",
                v[i]
            );
        }
        // Level carry's own force changes nothing; a departure and its return charge alike.
        let level = level_carry_force::<f64>();
        assert_eq!(share_charge(SF, MIS, &level, &level), Vector3::zeros());
        let turn = level * 1.56;
        let out = share_charge(SF, MIS, &level, &turn);
        let back = share_charge(SF, MIS, &turn, &level);
        assert_eq!(out, back);
        assert_eq!(out, share_change_variance(SF, MIS, &(turn - level)));
        // A monotone departure in many steps charges what it does in one (not Σ v(Δf)).
        let n = 100;
        let mut sum = Vector3::zeros();
        for k in 0..n {
            let a = level + (turn - level) * (k as f64 / n as f64);
            let b = level + (turn - level) * ((k + 1) as f64 / n as f64);
            sum += share_charge(SF, MIS, &a, &b);
        }
        assert!((sum - out).norm() <= 1e-9 * out.norm());
    }

    /// The slave's scale factors scale the flexure's lever-arm acceleration `u θ̈` along
    /// with the regressor `θ × (u θ̈)` through which the rows see θ: over many draws of S, the
    /// least-squares θ of a noise-free flexure signal is off with the variance of
    /// [`flexure_share_variance`], however many samples.
    #[test]
    fn flexure_share_variance_is_the_least_squares_error_of_the_scale_factor() {
        let l = Vector3::new(4.0_f64, -2.1, 0.2);
        let want = flexure_share_variance(SF, &l);
        // A small deterministic generator (xorshift) and Box-Muller normals.
        let mut state = 0x9E37_79B9_7F4A_7C15_u64;
        let mut uniform = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            ((state >> 11) as f64 + 0.5) / (1u64 << 53) as f64
        };
        let mut normal = || {
            let (a, b) = (uniform(), uniform());
            (-2.0 * a.ln()).sqrt() * (core::f64::consts::TAU * b).cos()
        };
        let draws = 4_000;
        let mut sum_sq = Vector3::<f64>::zeros();
        for _ in 0..draws {
            let s = Vector3::new(normal() * SF, normal() * SF, normal() * SF);
            for k in 0..3 {
                let e = Vector3::ith(k, 1.0);
                let u = l.cross(&e);
                // 50 samples of the flexure's angular acceleration; θ about axis k only.
                let (mut hy, mut hh) = (0.0, 0.0);
                for n in 0..50 {
                    let a = u * ((n as f64 * 0.37).sin() + 0.1);
                    let h = -e.cross(&a); // ∂(−θ × a)/∂θ_k
                    let y = s.component_mul(&a); // the scale factor's error
                    hy += h.dot(&y);
                    hh += h.dot(&h);
                }
                sum_sq[k] += (hy / hh).powi(2);
            }
        }
        for k in 0..3 {
            let got = sum_sq[k] / draws as f64;
            assert!(
                (got / want[k] - 1.0).abs() < 0.1,
                "axis {k}: {got:e} vs {:e}",
                want[k]
            );
        }
        // Along the lever arm, or with it across one axis only: nothing.
        let along = flexure_share_variance(SF, &Vector3::new(3.0, 0.0, 0.0));
        assert_eq!(along, Vector3::zeros());
    }

    #[test]
    fn charge_adds_to_the_bias_variances_only_and_refuses_bad_input() {
        let cfg = TaConfig::<f64>::flight(PaperCase::Case2);
        let mut ta = FlightFilter::<f64>::new(&cfg, &TaInitial::default()).unwrap();
        let (m, s) = epoch(0, &level_carry_force(), 0.0);
        ta.step(&m, &s).unwrap();
        assert!(ta.predict_ahead());
        let p0 = ta.covariance();
        let add = Vector3::new(1e-8, 2e-8, 3e-8);
        ta.charge_accel_bias_variance(&add).unwrap();
        let p1 = ta.covariance();
        let first = 3 * BIAS_STATE;
        for r in 0..15 {
            for c in 0..15 {
                let want = if r == c && r >= first {
                    add[r - first]
                } else {
                    0.0
                };
                assert!(
                    (p1[(r, c)] - p0[(r, c)] - want).abs() <= 1e-18,
                    "({r}, {c})"
                );
            }
        }
        // The predictions run ahead carry it: the next step is the one of a filter charged
        // before them.
        let mut fresh = FlightFilter::<f64>::new(&cfg, &TaInitial::default()).unwrap();
        fresh.step(&m, &s).unwrap();
        fresh.charge_accel_bias_variance(&add).unwrap();
        let (m1, s1) = epoch(1, &level_carry_force(), 0.0);
        ta.step(&m1, &s1).unwrap();
        fresh.step(&m1, &s1).unwrap();
        assert_eq!(ta.covariance(), fresh.covariance());
        // Refused: nothing changed.
        let before = ta.covariance();
        assert!(ta
            .charge_accel_bias_variance(&Vector3::new(-1e-9, 0.0, 0.0))
            .is_err());
        assert!(ta
            .charge_accel_bias_variance(&Vector3::new(f64::NAN, 0.0, 0.0))
            .is_err());
        assert_eq!(ta.covariance(), before);
    }

    /// The master and slave samples of epoch `k` (100 Hz) at specific force `f` (m/s²,
    /// master = slave axes, no rotation, no misalignment), the slave's z scale-factor error
    /// `s_z` (dimensionless): `f_s = f + S f`, so the difference bias is `b_z = −s_z f_z`.
    fn epoch(k: u64, f: &Vector3<f64>, s_z: f64) -> (MasterSample<f64>, SlaveSample<f64>) {
        let time = Timestamp::from_micros(10_000 * k);
        let f_s = Vector3::new(f.x, f.y, f.z * (1.0 + s_z));
        (
            MasterSample {
                time,
                angular_rate_rad_s: Vector3::zeros(),
                angular_accel_rad_s2: Vector3::zeros(),
                specific_force_m_s2: *f,
            },
            SlaveSample {
                time,
                angular_rate_rad_s: Vector3::zeros(),
                specific_force_m_s2: f_s,
            },
        )
    }

    /// A carry of 60 s level, then a pull-up to 1.56 g, with the slave's z scale factor at
    /// 2σ (noise-free samples): 0.5 s into the pull-up the bias has moved by `−s_z Δf_z`
    /// (≈ 220 µg). The returned ratio is the bias's worst |error| / σ on z over the pull-up.
    fn pull_up_error_ratio(charge: bool) -> f64 {
        // No lever arm: the flexure's acceleration at the pylon (`L_0 × θ̈_f`) cannot take
        // the force difference's step, only the bias can.
        let cfg = TaConfig {
            lever_arm_m: Vector3::zeros(),
            ..TaConfig::<f64>::flight(PaperCase::Case2).with_slave_share(SF, MIS)
        };
        let mut ta = FlightFilter::<f64>::new(&cfg, &TaInitial::default()).unwrap();
        let s_z = 2.0 * SF;
        let level = level_carry_force::<f64>();
        let turn = level * 1.56;
        let mut f_prev = None;
        let mut worst: f64 = 0.0;
        for k in 0..6_200_u64 {
            let f = if k < 6_000 { level } else { turn };
            let (m, s) = epoch(k, &f, s_z);
            ta.step(&m, &s).unwrap();
            if charge {
                ta.charge_share_change(SF, MIS, f_prev, &f);
            }
            f_prev = Some(f);
            if k >= 6_000 {
                let (b, sigma) = ta.accel_bias().unwrap();
                let truth = -s_z * f.z;
                worst = worst.max((b.z - truth).abs() / sigma.z);
            }
        }
        worst
    }

    /// The charge makes the bias's σ cover the scale factor's share in a manoeuvre; without
    /// it the random-constant model, certain of level carry's bias, is off by many σ.
    #[test]
    fn bias_sigma_covers_the_scale_factor_share_in_a_pull_up() {
        let with = pull_up_error_ratio(true);
        let without = pull_up_error_ratio(false);
        assert!(with < 3.0, "with the charge: |error| / σ up to {with}");
        assert!(
            without > 3.0,
            "without the charge: |error| / σ up to {without}"
        );
    }
}

//! The accelerometer-bias states of a mission run: what they are against the truth (in carry
//! the flight alignment's specific-force-difference bias, after the release the EKF's
//! equivalent bias), recorded at the output epochs, and their per-phase statistics in
//! `summary.json` (`phases.<phase>.accel_bias_states`).

use super::super::navigator_setup::HISTORY;
use super::super::sensors::MissionInputs;
use super::super::truth::MissionTruth;
use super::{phase_consistency, FlightRecord, PhaseTag, VariantStats};
use crate::consistency::{Consistency, RunConsistency};
use crate::output::sig;
use nalgebra::{Matrix3, Vector3};
use nav_core::navigator::Navigator;
use nav_core::Real;
use serde_json::{json, Value};

/// Names of the accelerometer-bias states (body / slave axes x, y, z): in carry the flight
/// alignment's specific-force-difference bias, after the release the EKF's equivalent bias.
pub const BIAS_COMPONENTS: [&str; 3] = ["acc_bias_x", "acc_bias_y", "acc_bias_z"];

/// The accelerometer-bias states ([`BIAS_COMPONENTS`]) of one run at its output epochs.
#[derive(Debug, Clone, Default)]
pub struct BiasRecord {
    /// NEES of the 3 and `e²/σ²` per axis (NaN where the navigator has no such state: the
    /// conventional alignment in carry).
    pub consistency: RunConsistency,
    /// Error (estimate − truth) per axis, m/s² (NaN where absent).
    pub err: Vec<[f64; 3]>,
    /// The navigator's σ of the same, m/s².
    pub sigma: Vec<[f64; 3]>,
}

impl BiasRecord {
    /// An empty record.
    pub fn new() -> Self {
        Self {
            consistency: RunConsistency::new(&BIAS_COMPONENTS),
            ..Self::default()
        }
    }
}

/// RMS over runs of the accelerometer-bias states' error and σ per axis, m/s²: over a
/// phase's epochs and at its last epoch.
#[derive(Debug, Clone, Copy)]
pub struct BiasRms {
    /// RMS error over the phase.
    pub err: [f64; 3],
    /// RMS σ over the phase.
    pub sigma: [f64; 3],
    /// RMS error at the phase's last epoch.
    pub err_last: [f64; 3],
    /// RMS σ at the phase's last epoch.
    pub sigma_last: [f64; 3],
}

/// The true mean specific force of the missile IMU's interval ending at epoch `k` (body axes),
/// m/s².
fn true_specific_force(truth: &MissionTruth, k: usize) -> Vector3<f64> {
    let m = &truth.missile;
    let k = k.max(1).min(m.imu.len().saturating_sub(1));
    let h = m.imu[k]
        .time
        .micros_since(m.imu[k - 1].time)
        .map_or(f64::NAN, |us| us as f64 * 1e-6);
    m.imu[k].delta_v_m_s / h
}

/// Records the accelerometer-bias states at epoch `k`. In carry the flight alignment's
/// specific-force-difference bias `b = b_m − b_s^eq` against its truth: the master's bias
/// minus the slave's equivalent bias `b_s + (S + M) f` at the epoch's true specific force `f`
/// (what `f̃_m − f_s` holds besides `θ × f`; the bias state is a constant, so in a turn the
/// truth moves away from it by `(S + M) Δf`). After the release the EKF's equivalent bias
/// against `b_s + (S + M) f_ref` at the specific force its states refer to (the carry's).
pub(crate) fn record_bias<T: Real, const K: usize, const NS: usize>(
    out: &mut FlightRecord,
    nav: &Navigator<T, K, NS, HISTORY>,
    truth: &MissionTruth,
    inp: &MissionInputs,
    k: usize,
) {
    let sm = inp.accel_matrix - Matrix3::identity();
    let f_now = true_specific_force(truth, k);
    let est: Option<(Vector3<f64>, Vector3<f64>, Matrix3<f64>)> = match nav.ekf() {
        Some(ekf) => {
            let f_ref = ekf
                .specific_force_reference()
                .map_or(f_now, |f| f.map(|x| x.to_f64()));
            let p = ekf.covariance().map(|x| x.to_f64());
            let pb: Matrix3<f64> = p
                .fixed_view::<3, 3>(
                    nav_core::seeker_ins::ACC_BIAS,
                    nav_core::seeker_ins::ACC_BIAS,
                )
                .into_owned();
            Some((
                ekf.accel_bias_m_s2().map(|x| x.to_f64()),
                inp.accel_bias_m_s2 + sm * f_ref,
                pb,
            ))
        }
        None => nav.alignment().accel_bias().map(|(b, _)| {
            let p = nav.alignment().covariance().map(|x| x.to_f64());
            // The bias states' spec (derivative-major) indices: 3 · BIAS_STATE + axis (after
            // θ, θ_f, θ̇_f, θ̈_f).
            let first = 3 * nav_core::transfer_alignment::BIAS_STATE;
            let pb = Matrix3::from_fn(|i, j| p[(first + i, first + j)]);
            (
                b.map(|x| x.to_f64()),
                inp.master_accel_bias_m_s2 - (inp.accel_bias_m_s2 + sm * f_now),
                pb,
            )
        }),
    };
    let (e, s, nees) = match est {
        Some((b, t, pb)) => {
            let e = b - t;
            let nees = pb.try_inverse().map_or(f64::NAN, |pi| e.dot(&(pi * e)));
            (
                [e.x, e.y, e.z],
                std::array::from_fn(|i| pb[(i, i)].max(0.0).sqrt()),
                nees,
            )
        }
        None => ([f64::NAN; 3], [f64::NAN; 3], f64::NAN),
    };
    let es: [(f64, f64); 3] = std::array::from_fn(|i| (e[i], s[i]));
    out.bias.consistency.push(truth.missile.t_s[k], nees, &es);
    out.bias.err.push(e);
    out.bias.sigma.push(s);
}

/// Per phase (the epochs whose modal phase it is, as the navigation states'): the
/// accelerometer-bias states' consistency (3 states) and their RMS error and σ.
pub(super) fn phase_bias(
    records: &[&FlightRecord],
    phase: &[Option<PhaseTag>],
    t_s: &[f64],
) -> Vec<(PhaseTag, Consistency, BiasRms)> {
    let n = phase.len();
    let bias_cons: Vec<RunConsistency> =
        records.iter().map(|r| r.bias.consistency.clone()).collect();
    phase_consistency(3, &bias_cons, phase, t_s)
        .into_iter()
        .map(|(p, c, _)| {
            // Every phase of `phase_consistency` has at least one epoch.
            let keep: Vec<usize> = (0..n).filter(|&k| phase[k] == Some(p)).collect();
            // RMS over runs and the epochs `ks` of axis `a` of a per-epoch series (NaN
            // entries left out).
            let ms =
                |ks: &[usize], f: &dyn Fn(&FlightRecord, usize) -> Option<[f64; 3]>, a: usize| {
                    let v: Vec<f64> = records
                        .iter()
                        .flat_map(|r| ks.iter().map(move |&k| (r, k)))
                        .filter_map(|(r, k)| f(r, k))
                        .map(|x| x[a].powi(2))
                        .filter(|x| x.is_finite())
                        .collect();
                    (v.iter().sum::<f64>() / v.len().max(1) as f64).sqrt()
                };
            let err = |r: &FlightRecord, k: usize| r.bias.err.get(k).copied();
            let sigma = |r: &FlightRecord, k: usize| r.bias.sigma.get(k).copied();
            let all = BiasRms {
                err: std::array::from_fn(|a| ms(&keep, &err, a)),
                sigma: std::array::from_fn(|a| ms(&keep, &sigma, a)),
                err_last: std::array::from_fn(|a| ms(&keep[keep.len() - 1..], &err, a)),
                sigma_last: std::array::from_fn(|a| ms(&keep[keep.len() - 1..], &sigma, a)),
            };
            (p, c, all)
        })
        .collect()
}

impl VariantStats {
    /// The accelerometer-bias states of a phase ([`BIAS_COMPONENTS`]): RMS error and RMS σ per
    /// axis, µg, and their consistency (3 states); null where the variant has none.
    pub(super) fn bias_summary(&self, p: PhaseTag) -> Value {
        let Some((_, c, b)) = self.bias_phases.iter().find(|(q, ..)| *q == p) else {
            return Value::Null;
        };
        if !b.err.iter().any(|v| *v > 0.0) {
            return Value::Null;
        }
        let ug = |v: &[f64; 3]| {
            v.iter()
                .map(|x| sig(x / (1e-6 * 9.806_65), 4))
                .collect::<Vec<_>>()
        };
        json!({
            "rms_ug": ug(&b.err),
            "sigma_ug": ug(&b.sigma),
            "rms_at_end_ug": ug(&b.err_last),
            "sigma_at_end_ug": ug(&b.sigma_last),
            "consistency": c.summary(),
        })
    }
}

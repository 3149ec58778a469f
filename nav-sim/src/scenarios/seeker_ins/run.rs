//! One Monte Carlo run: the filter built from the scenario, flown over the truth with the
//! simulated sensors (aided or free INS, with or without injected faults), its errors and σ
//! recorded at the output epochs; and the batches of runs.

use super::config::{landmark_position, output_epochs, Config, InitialErrorConfig, ARCSEC, R0};
use super::fault::{self, Faults};
use super::report::{nees, statistics, Stats};
use super::sensors::Sensors;
use super::trajectory::Truth;
use crate::consistency::RunConsistency;
use crate::rng::{normal, SimRng};
use anyhow::{bail, Result};
use nalgebra::{Matrix3, SMatrix, SVector, Vector2, Vector3};
use nav_core::contract::{Estimator, Gate};
use nav_core::earth::radii_m;
use nav_core::math::kalman::FusionOutcome;
use nav_core::math::rotation::{dcm_to_euler, dcm_to_quat, euler_to_dcm, log_so3, quat_to_dcm};
use nav_core::seeker_ins::{
    default_recovery, gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles,
    ImuFaultPolicy, ImuIncrement, InsState, InstrumentErrors, Landmark, LosResidual, LosSample,
    Position, SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsInitial, STATES,
};
use nav_core::Real;

/// The filter's IMU fault counters at the end of a run.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ImuFaultTally {
    /// Gaps bridged (`Health::gaps_bridged`).
    pub gaps: u32,
    /// IMU samples bridged by the hold.
    pub held_samples: u32,
    /// Clipped samples integrated.
    pub clipped_samples: u32,
}

/// Output of one run (sampled at the output rate).
#[derive(Debug, Clone, Default)]
pub struct RunOutput {
    /// Errors (estimate − truth): lat m, lon m, alt m, V_N, V_E, V_D m/s, roll, pitch, yaw deg.
    pub err: [Vec<f64>; 9],
    /// Filter 1σ of the same quantities.
    pub sigma: [Vec<f64>; 9],
    /// NEES of the 17 states, and of the position, velocity and attitude blocks.
    pub nees: [Vec<f64>; 4],
    /// The consistency samples of the run: NEES of the 17 states and, per state group
    /// ([`GROUPS`]), the group's NEES divided by its dimension (mean 1 when consistent).
    pub consistency: RunConsistency,
    /// Sum of the per-component NIS of fused and rejected components.
    pub nis_sum: f64,
    /// Scalar components fused.
    pub fused: usize,
    /// Scalar components rejected by the gate.
    pub rejected: usize,
    /// Seeker epochs with the landmark outside the gimbal limits.
    pub out_of_field: usize,
    /// Updates refused with an error.
    pub errors: usize,
    /// True gimbal angles at the seeker epochs (pitch, yaw), deg (first run only used).
    pub gimbal_deg: Vec<(f64, f64, f64)>,
    /// Filter counters at the end of the run: LOS gate re-inflations.
    pub inflations: u32,
    /// IMU fault counters at the end of the run.
    pub imu_faults: ImuFaultTally,
    /// Seeker epochs without a measurement because of an injected fault (loss of lock, IMU gap).
    pub seeker_dropped: usize,
    /// Seeker updates during an injected false lock, components fused / rejected.
    pub false_lock_fused: usize,
    /// As `false_lock_fused`, rejected.
    pub false_lock_rejected: usize,
}

/// Which filter a run flies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FilterKind {
    /// The paper's filter, exactly as specified ([`SeekerInsConfig::paper`]'s model: the IMU
    /// errors beyond bias and white noise are not accounted for).
    Paper,
    /// The flight configuration ([`SeekerInsConfig::flight`]'s model): the scale-factor and
    /// misalignment σ of the scenario's IMU in `instrument_errors`.
    Flight,
}

impl FilterKind {
    /// Name in outputs.
    pub fn name(self) -> &'static str {
        match self {
            Self::Paper => "paper",
            Self::Flight => "flight",
        }
    }
}

/// Simulates one run. `aided = false` flies the same run without seeker updates (the seeker
/// random numbers are drawn anyway so the two share every other number).
pub fn simulate_run<T: Real>(
    cfg: &Config,
    truth: &Truth,
    epochs: &[usize],
    rng: &mut SimRng,
    aided: bool,
) -> Result<RunOutput> {
    simulate_run_faulted::<T>(cfg, truth, epochs, rng, aided, &Faults::default())
}

/// The INS's initial state: the truth's with the Table 4 errors drawn.
fn initial_state<T: Real>(cfg: &Config, truth: &Truth, rng: &mut SimRng) -> InsState<T> {
    table4_state(
        &cfg.initial_error,
        &truth.position[0],
        &truth.vel_ned_m_s[0],
        &truth.c_b_n[0],
        rng,
    )
}

/// A true position, velocity and attitude with the Table 4 errors of `ie` drawn (latitude and
/// longitude as m / R_0 rad, Euler angle errors); shared with the mission scenario.
pub(crate) fn table4_state<T: Real>(
    ie: &InitialErrorConfig,
    p0: &Position,
    v0: &Vector3<f64>,
    c0: &Matrix3<f64>,
    rng: &mut SimRng,
) -> InsState<T> {
    let (r0, pt0, y0) = dcm_to_euler(c0);
    let d_euler = Vector3::new(
        normal(rng, ie.roll_deg.to_radians()),
        normal(rng, ie.pitch_deg.to_radians()),
        normal(rng, ie.yaw_deg.to_radians()),
    );
    InsState::<T> {
        position: Position {
            lat_rad: p0.lat_rad + normal(rng, ie.lat_m / R0),
            lon_rad: p0.lon_rad + normal(rng, ie.lon_m / R0),
            alt_m: p0.alt_m + normal(rng, ie.alt_m),
        },
        vel_ned_m_s: (v0
            + Vector3::new(
                normal(rng, ie.vel_m_s[0]),
                normal(rng, ie.vel_m_s[1]),
                normal(rng, ie.vel_m_s[2]),
            ))
        .cast::<T>(),
        q_b_n: dcm_to_quat(&euler_to_dcm(
            T::lit(r0 + d_euler.x),
            T::lit(pt0 + d_euler.y),
            T::lit(y0 + d_euler.z),
        )),
    }
}

/// The filter's P0: Table 4 and the bias σ of the filter configuration.
fn initial_covariance(cfg: &Config, c0: &Matrix3<f64>) -> SMatrix<f64, STATES, STATES> {
    let fc = &cfg.filter;
    table4_covariance(
        &cfg.initial_error,
        c0,
        fc.accel_bias_sigma_ug * 1e-6 * super::config::G0,
        fc.gyro_bias_sigma_deg_h.to_radians() / 3600.0,
        fc.gimbal_bias_sigma_deg.to_radians(),
    )
}

/// [`initial_covariance`] for the model-reduction measurement.
#[cfg(test)]
pub(crate) fn initial_covariance_for_tests(
    cfg: &Config,
    c0: &Matrix3<f64>,
) -> SMatrix<f64, STATES, STATES> {
    initial_covariance(cfg, c0)
}

/// P0 of the 17 states: the Table 4 σ of `ie` (the Euler-angle σ mapped to the misalignment
/// φ at the attitude `c0`) and the bias σ (accelerometer m/s², gyro rad/s, gimbal rad);
/// shared with the mission scenario.
pub(crate) fn table4_covariance(
    ie: &InitialErrorConfig,
    c0: &Matrix3<f64>,
    accel_bias_sigma_m_s2: f64,
    gyro_bias_sigma_rad_s: f64,
    gimbal_bias_sigma_rad: f64,
) -> SMatrix<f64, STATES, STATES> {
    let mut p0m = SMatrix::<f64, STATES, STATES>::zeros();
    p0m[(0, 0)] = (ie.lat_m / R0).powi(2);
    p0m[(1, 1)] = (ie.lon_m / R0).powi(2);
    p0m[(2, 2)] = ie.alt_m.powi(2);
    for i in 0..3 {
        p0m[(3 + i, 3 + i)] = ie.vel_m_s[i].powi(2);
    }
    let j = euler_to_phi_jacobian(c0);
    let se = Matrix3::from_diagonal(&Vector3::new(
        ie.roll_deg.to_radians().powi(2),
        ie.pitch_deg.to_radians().powi(2),
        ie.yaw_deg.to_radians().powi(2),
    ));
    let patt = j * se * j.transpose();
    let patt = (patt + patt.transpose()) * 0.5;
    p0m.fixed_view_mut::<3, 3>(6, 6).copy_from(&patt);
    for i in 0..3 {
        p0m[(9 + i, 9 + i)] = accel_bias_sigma_m_s2.powi(2);
        p0m[(12 + i, 12 + i)] = gyro_bias_sigma_rad_s.powi(2);
    }
    for i in 0..2 {
        p0m[(15 + i, 15 + i)] = gimbal_bias_sigma_rad.powi(2);
    }
    p0m
}

/// The filter configuration of the scenario (the densities of the drawn sensors).
fn filter_config<T: Real>(
    cfg: &Config,
    dt: f64,
    sensors: &Sensors,
    faults: &Faults,
    kind: FilterKind,
) -> Result<SeekerInsConfig<T>> {
    let fc = &cfg.filter;
    let sc = &cfg.sensors;
    let instrument_errors = match kind {
        FilterKind::Paper => InstrumentErrors::default(),
        FilterKind::Flight => InstrumentErrors {
            accel_scale_factor: T::lit(sc.accel_scale_factor_ppm * 1e-6),
            accel_misalignment_rad: T::lit(sc.accel_misalignment_arcsec * ARCSEC),
            gyro_scale_factor: T::lit(sc.gyro_scale_factor_ppm * 1e-6),
            gyro_misalignment_rad: T::lit(sc.gyro_misalignment_arcsec * ARCSEC),
        },
    };
    Ok(SeekerInsConfig::<T> {
        instrument_errors,
        imu_dt_s: T::lit(dt),
        covariance_interval_steps: (cfg.rates.imu_hz / cfg.rates.covariance_hz).round() as u16,
        accel_noise_density_m_s2_rt_hz: T::lit(sensors.vrw),
        gyro_noise_density_rad_s_rt_hz: T::lit(sensors.arw),
        seeker_noise_rad: T::lit(fc.seeker_noise_deg.to_radians()),
        gate: Gate::Nis(T::lit(fc.gate_nis)),
        recovery: default_recovery(),
        imu_faults: faults
            .policy
            .as_ref()
            .map_or_else(ImuFaultPolicy::default, fault::policy_cast::<T>),
        landmark: Landmark::new(landmark_position(cfg))
            .map_err(|e| anyhow::anyhow!("landmark: {e}"))?,
        residual: match fc.residual.as_str() {
            "projected-2d" => LosResidual::Projected2d,
            "full-rank-3d" => LosResidual::FullRank3d,
            r => bail!("filter.residual `{r}`: must be \"projected-2d\" or \"full-rank-3d\""),
        },
    })
}

/// A run in flight: the filter, the sensors, what is recorded.
struct Flight<'a, T: Real> {
    filter: SeekerIns<T>,
    sensors: Sensors,
    truth: &'a Truth,
    faults: &'a Faults,
    landmark: Landmark<f64>,
    gimbal_limit_rad: f64,
    aided: bool,
    /// The last sample sent (the output inside a gap holds it, as the filter's bridge does).
    last_sample: Option<ImuIncrement<T>>,
    out: RunOutput,
}

impl<T: Real> Flight<'_, T> {
    /// IMU sample `k` (≥ 1): sensed, and sent unless in an IMU gap (the filter detects a gap
    /// from the time stamps and bridges it itself).
    fn imu(&mut self, k: usize, in_gap: bool, rng: &mut SimRng) -> Result<()> {
        let (s, clipped) = self.sensors.imu(self.truth, k, self.faults, rng);
        let sample = ImuIncrement {
            time: s.time,
            delta_theta_rad: s.delta_theta_rad.cast::<T>(),
            delta_v_m_s: s.delta_v_m_s.cast::<T>(),
        };
        if in_gap {
            return Ok(());
        }
        self.last_sample = Some(sample);
        let flags = ClipFlags {
            accel: true,
            gyro: false,
        };
        if clipped && self.faults.flag_clipped {
            self.filter.propagate_clipped(&sample, flags)
        } else {
            self.filter.propagate(&sample)
        }
        .map_err(|e| anyhow::anyhow!("propagate at k = {k}: {e}"))
    }

    /// Seeker epoch `k`: the measurement of the true LOS (if in the field of regard, the
    /// lock held and the run aided) fused, its outcome counted.
    fn seeker(&mut self, k: usize, in_gap: bool, rng: &mut SimRng) {
        let noise = self.sensors.seeker_noise(rng);
        let t_k = self.truth.t_s[k];
        let d = landmark_vector_ned(&self.truth.position[k], &self.landmark);
        let g = gimbal_angles_of(&(self.truth.c_b_n[k].transpose() * d));
        let out = &mut self.out;
        out.gimbal_deg
            .push((t_k, g.pitch_rad.to_degrees(), g.yaw_rad.to_degrees()));
        let limit = self.gimbal_limit_rad;
        if g.pitch_rad.abs() > limit || g.yaw_rad.abs() > limit {
            out.out_of_field += 1;
            return;
        }
        if !self.aided {
            return;
        }
        if in_gap || self.faults.loss_of_lock(t_k) {
            out.seeker_dropped += 1;
            return;
        }
        let false_yaw = self.faults.false_lock_yaw_rad(t_k);
        let bias = self.sensors.seeker_bias;
        let meas = LosSample {
            time: self.truth.imu[k].time,
            gimbal: GimbalAngles {
                pitch_rad: T::lit(g.pitch_rad + bias.x + noise.x),
                yaw_rad: T::lit(g.yaw_rad + bias.y + noise.y + false_yaw.unwrap_or(0.0)),
            },
        };
        match self.filter.update_los(&meas) {
            Ok(rep) => {
                for c in [rep.pitch, rep.yaw] {
                    out.nis_sum += c.nis.to_f64();
                    match (c.outcome, false_yaw.is_some()) {
                        (FusionOutcome::Fused, false) => out.fused += 1,
                        (FusionOutcome::Rejected, false) => out.rejected += 1,
                        (FusionOutcome::Fused, true) => out.false_lock_fused += 1,
                        (FusionOutcome::Rejected, true) => out.false_lock_rejected += 1,
                        (FusionOutcome::Skipped, _) => out.errors += 1,
                    }
                }
            }
            Err(_) => out.errors += 1,
        }
    }

    /// Output epoch `k`: P propagated to it, errors and σ recorded. Inside an IMU gap: the
    /// output a flight computer would give, the INS bridged by the hold up to this epoch (on
    /// a copy, fed the last sample again at this epoch's time; the filter bridges at the gap
    /// end).
    fn output(&mut self, k: usize, in_gap: bool) -> Result<()> {
        self.filter
            .predict_covariance()
            .map_err(|e| anyhow::anyhow!("{e}"))?;
        let mut shown = self.filter;
        if let Some(held) = self.last_sample.filter(|_| in_gap) {
            let at_epoch = ImuIncrement {
                time: self.truth.imu[k].time,
                ..held
            };
            shown
                .propagate(&at_epoch)
                .and_then(|()| shown.predict_covariance())
                .map_err(|e| anyhow::anyhow!("gap output at k = {k}: {e}"))?;
        }
        let s = &self.sensors;
        let biases = TrueBiases {
            accel_m_s2: &s.acc_b,
            gyro_rad_s: &s.gyr_b,
            gimbal_rad: &s.seeker_bias,
            accel_matrix: &s.acc_m,
        };
        record(&mut self.out, &shown, self.truth, k, &biases);
        Ok(())
    }
}

/// [`simulate_run`] with injected faults ([`Faults`]); with none it is the same run, number
/// for number (the fault models draw no random numbers). The paper's filter.
pub fn simulate_run_faulted<T: Real>(
    cfg: &Config,
    truth: &Truth,
    epochs: &[usize],
    rng: &mut SimRng,
    aided: bool,
    faults: &Faults,
) -> Result<RunOutput> {
    simulate_run_with::<T>(cfg, truth, epochs, rng, aided, FilterKind::Paper, faults)
}

/// [`simulate_run_faulted`] with the filter to fly. The random numbers drawn do not depend on
/// the filter, so the paper filter and the flight configuration fly the same truth, sensor
/// errors and noise samples from the same stream.
pub fn simulate_run_with<T: Real>(
    cfg: &Config,
    truth: &Truth,
    epochs: &[usize],
    rng: &mut SimRng,
    aided: bool,
    kind: FilterKind,
    faults: &Faults,
) -> Result<RunOutput> {
    let dt = truth.dt_s;
    let sensors = Sensors::draw(cfg, dt, rng);
    let state = initial_state::<T>(cfg, truth, rng);
    let initial = SeekerInsInitial {
        state,
        covariance: initial_covariance(cfg, &truth.c_b_n[0]).cast::<T>(),
    };
    let config = filter_config::<T>(cfg, dt, &sensors, faults, kind)?;
    let filter =
        SeekerIns::new(&config, &initial).map_err(|e| anyhow::anyhow!("filter init: {e}"))?;
    let mut flight = Flight {
        filter,
        sensors,
        truth,
        faults,
        landmark: Landmark::<f64>::new(landmark_position(cfg))
            .map_err(|e| anyhow::anyhow!("{e}"))?,
        gimbal_limit_rad: cfg.rates.gimbal_limit_deg.to_radians(),
        aided,
        last_sample: None,
        out: RunOutput::default(),
    };
    let imu_per_seeker = (cfg.rates.imu_hz / cfg.rates.seeker_hz).round() as usize;
    let mut next_epoch = epochs.iter().peekable();
    for k in 0..truth.t_s.len() {
        let in_gap = k > 0 && faults.in_imu_gap(truth.t_s[k]);
        if k > 0 {
            flight.imu(k, in_gap, rng)?;
            if k % imu_per_seeker == 0 {
                flight.seeker(k, in_gap, rng);
            }
        }
        if next_epoch.peek() == Some(&&k) {
            next_epoch.next();
            flight.output(k, in_gap)?;
        }
    }
    let f = &flight.filter;
    let mut out = flight.out;
    out.inflations = f.aid_counters(SeekerAid::Los).recoveries;
    let counters = f.seeker_counters();
    out.imu_faults = ImuFaultTally {
        gaps: f.health().gaps_bridged,
        held_samples: counters.held_samples,
        clipped_samples: counters.clipped_samples,
    };
    Ok(out)
}

/// The true instrument errors of a run: biases (accelerometer m/s², gyro rad/s, gimbal angles
/// rad) and the accelerometers' `(I + S + M)` (scale factor and misalignment).
struct TrueBiases<'a> {
    accel_m_s2: &'a Vector3<f64>,
    gyro_rad_s: &'a Vector3<f64>,
    gimbal_rad: &'a Vector2<f64>,
    accel_matrix: &'a Matrix3<f64>,
}

/// State groups of the consistency figures: name, first state, dimension.
pub const GROUPS: [(&str, usize, usize); 6] = [
    ("position", 0, 3),
    ("velocity", 3, 3),
    ("attitude", 6, 3),
    ("accel_bias", 9, 3),
    ("gyro_bias", 12, 3),
    ("gimbal_bias", 15, 2),
];

/// The true value of the accelerometer and gyro error states at IMU epoch `k`.
///
/// Accelerometer: the **equivalent bias** `b + (S + M) f`, the whole non-white error of the
/// instrument, which enters the INS error equations through `C_b^n ∇` and does not average
/// out (gravity), at the specific force the filter's states refer to (`f_ref`, the flight
/// configuration: a departure from it is the velocity's error, not the bias's), or else
/// (`None`: the paper's filter, whose states are the bias) at `f_b`, the true mean specific
/// force of the interval ending there.
/// Gyro: the bias `b` alone: `(S + M) ω` averages out over a manoeuvre and shows as the
/// bounded attitude error `(S + M) ∫ω dt`, which the attitude states carry.
fn equivalent_biases(
    truth: &Truth,
    k: usize,
    b: &TrueBiases<'_>,
    f_ref_b_m_s2: Option<Vector3<f64>>,
) -> (Vector3<f64>, Vector3<f64>) {
    let k = k.max(1).min(truth.imu.len().saturating_sub(1));
    let inc = &truth.imu[k];
    let h = inc
        .time
        .micros_since(truth.imu[k - 1].time)
        .map_or(truth.dt_s, |us| us as f64 * 1e-6);
    let f_b = f_ref_b_m_s2.unwrap_or(inc.delta_v_m_s / h);
    (
        b.accel_m_s2 + (b.accel_matrix - Matrix3::identity()) * f_b,
        *b.gyro_rad_s,
    )
}

/// Records the errors, σ and NEES of the filter at output epoch `k`.
fn record<T: Real>(
    out: &mut RunOutput,
    filter: &SeekerIns<T>,
    truth: &Truth,
    k: usize,
    biases: &TrueBiases<'_>,
) {
    let seeker_b = biases.gimbal_rad;
    let f_ref = filter
        .specific_force_reference()
        .map(|f| f.map(|x| x.to_f64()));
    let (acc_b, gyr_b) = equivalent_biases(truth, k, biases, f_ref);
    let st = filter.state();
    let p_true = truth.position[k];
    let (rm, rn) = radii_m(p_true.lat_rad);
    let c_hat = quat_to_dcm(&st.q_b_n).map(|v| v.to_f64());
    let c = truth.c_b_n[k];
    let d_lat = st.position.lat_rad - p_true.lat_rad;
    let d_lon = st.position.lon_rad - p_true.lon_rad;
    let d_alt = st.position.alt_m - p_true.alt_m;
    let dv = st.vel_ned_m_s.map(|v| v.to_f64()) - truth.vel_ned_m_s[k];
    let e_hat = dcm_to_euler(&c_hat);
    let e_true = dcm_to_euler(&c);
    let de = [
        wrap_pi(e_hat.0 - e_true.0),
        wrap_pi(e_hat.1 - e_true.1),
        wrap_pi(e_hat.2 - e_true.2),
    ];
    let lat_scale = rm + p_true.alt_m;
    let lon_scale = (rn + p_true.alt_m) * p_true.lat_rad.cos();
    let errs = [
        d_lat * lat_scale,
        d_lon * lon_scale,
        d_alt,
        dv.x,
        dv.y,
        dv.z,
        de[0].to_degrees(),
        de[1].to_degrees(),
        de[2].to_degrees(),
    ];
    let p = filter.covariance().map(|v| v.to_f64());
    // Euler σ from the φ covariance: δe = J⁻¹ φ.
    let j = euler_to_phi_jacobian(&c_hat);
    let jinv = j.try_inverse().unwrap_or_else(Matrix3::identity);
    let pe = jinv * p.fixed_view::<3, 3>(6, 6) * jinv.transpose();
    let sig = [
        p[(0, 0)].sqrt() * lat_scale,
        p[(1, 1)].sqrt() * lon_scale,
        p[(2, 2)].sqrt(),
        p[(3, 3)].sqrt(),
        p[(4, 4)].sqrt(),
        p[(5, 5)].sqrt(),
        pe[(0, 0)].sqrt().to_degrees(),
        pe[(1, 1)].sqrt().to_degrees(),
        pe[(2, 2)].sqrt().to_degrees(),
    ];
    for i in 0..9 {
        out.err[i].push(errs[i]);
        out.sigma[i].push(sig[i]);
    }
    // True error state and NEES.
    let phi = -log_so3(&(c_hat * c.transpose()));
    let mut e = SVector::<f64, STATES>::zeros();
    e[0] = d_lat;
    e[1] = d_lon;
    e[2] = d_alt;
    e.fixed_rows_mut::<3>(3).copy_from(&dv);
    e.fixed_rows_mut::<3>(6).copy_from(&phi);
    e.fixed_rows_mut::<3>(9)
        .copy_from(&(acc_b - filter.accel_bias_m_s2().map(|v| v.to_f64())));
    e.fixed_rows_mut::<3>(12)
        .copy_from(&(gyr_b - filter.gyro_bias_rad_s().map(|v| v.to_f64())));
    e.fixed_rows_mut::<2>(15)
        .copy_from(&(seeker_b - filter.gimbal_bias_rad().map(|v| v.to_f64())));
    let total = nees(&p, &e);
    out.nees[0].push(total);
    for (b, start) in [(1, 0), (2, 3), (3, 6)] {
        let pb = p.fixed_view::<3, 3>(start, start).into_owned();
        let eb = e.fixed_rows::<3>(start).into_owned();
        out.nees[b].push(nees(&pb, &eb));
    }
    // Per group: NEES / dimension, passed as (√(NEES/n), 1) so that `e²/σ²` is NEES / n.
    let groups: Vec<(f64, f64)> = GROUPS
        .iter()
        .map(|&(_, start, n)| {
            let pb = p.view((start, start), (n, n)).into_owned();
            let eb = e.rows(start, n).into_owned();
            let v =
                nalgebra::linalg::Cholesky::new(pb).map_or(f64::NAN, |ch| eb.dot(&ch.solve(&eb)));
            ((v / n as f64).sqrt(), 1.0)
        })
        .collect();
    if out.consistency.normalized.is_empty() {
        out.consistency = RunConsistency::new(&GROUPS.map(|g| g.0));
    }
    out.consistency.push(truth.t_s[k], total, &groups);
}

/// ∂φ/∂(roll, pitch, yaw) at an attitude (φ of `Ĉ = (I − [φ×]) C`), by central differences.
fn euler_to_phi_jacobian(c: &Matrix3<f64>) -> Matrix3<f64> {
    let (r, p, y) = dcm_to_euler(c);
    let h = 1e-6;
    let mut j = Matrix3::zeros();
    for k in 0..3 {
        let mut e1 = [r, p, y];
        let mut e0 = [r, p, y];
        e1[k] += h;
        e0[k] -= h;
        let c1 = euler_to_dcm(e1[0], e1[1], e1[2]);
        let c0 = euler_to_dcm(e0[0], e0[1], e0[2]);
        let phi = -log_so3(&(c1 * c0.transpose())) / (2.0 * h);
        j.set_column(k, &phi);
    }
    j
}

fn wrap_pi(a: f64) -> f64 {
    let t = std::f64::consts::TAU;
    a - t * ((a + std::f64::consts::PI) / t).floor()
}

/// The Monte Carlo batches of a scenario: the paper filter and the flight configuration aided
/// (same runs), the free INS, and the first paper-filter run.
#[derive(Debug, Clone)]
pub struct Batches {
    /// Paper filter, aided.
    pub paper: Stats,
    /// Flight configuration, aided (`None` when not flown).
    pub flight: Option<Stats>,
    /// Free INS (the paper filter's covariance, no seeker).
    pub free: Stats,
    /// First run of the paper filter.
    pub first: RunOutput,
}

/// Runs the aided and free Monte Carlo batches; returns `(aided, free, first aided run)` of
/// the paper filter.
pub fn monte_carlo_batches(
    cfg: &Config,
    truth: &Truth,
    runs: usize,
    seed: u64,
    progress: bool,
) -> Result<(Stats, Stats, RunOutput)> {
    let b = monte_carlo_filters(cfg, truth, runs, seed, progress, false)?;
    Ok((b.paper, b.free, b.first))
}

/// Runs the paper filter (aided and free) and, with `flight`, the flight configuration on the
/// same runs (run `i` of each from stream `i` of `seed`).
pub fn monte_carlo_filters(
    cfg: &Config,
    truth: &Truth,
    runs: usize,
    seed: u64,
    progress: bool,
    flight: bool,
) -> Result<Batches> {
    let epochs = output_epochs(truth, cfg);
    let f32_mode = match cfg.filter.precision.as_str() {
        "f32" => true,
        "f64" => false,
        p => bail!("filter.precision `{p}`: must be \"f32\" or \"f64\""),
    };
    let none = Faults::default();
    let results = crate::montecarlo::monte_carlo("seeker-ins", runs, seed, progress, |_, rng| {
        let sim = |mut rng: SimRng, aided: bool, kind: FilterKind| {
            if f32_mode {
                simulate_run_with::<f32>(cfg, truth, &epochs, &mut rng, aided, kind, &none)
            } else {
                simulate_run_with::<f64>(cfg, truth, &epochs, &mut rng, aided, kind, &none)
            }
        };
        let a = sim(rng.clone(), true, FilterKind::Paper)?;
        let f = sim(rng.clone(), false, FilterKind::Paper)?;
        let fl = if flight {
            Some(sim(rng.clone(), true, FilterKind::Flight)?)
        } else {
            None
        };
        Ok::<_, anyhow::Error>((a, f, fl))
    });
    let mut aided = Vec::with_capacity(runs);
    let mut free = Vec::with_capacity(runs);
    let mut fl = Vec::with_capacity(runs);
    for r in results {
        let (a, f, x) = r?;
        aided.push(a);
        free.push(f);
        fl.extend(x);
    }
    let t: Vec<f64> = epochs.iter().map(|&k| truth.t_s[k]).collect();
    let first = aided.first().cloned().unwrap_or_default();
    Ok(Batches {
        paper: statistics(&aided, t.clone()),
        flight: flight.then(|| statistics(&fl, t.clone())),
        free: statistics(&free, t),
        first,
    })
}

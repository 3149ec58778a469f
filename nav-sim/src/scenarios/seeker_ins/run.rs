//! One Monte Carlo run: the filter built from the scenario, flown over the truth with the
//! simulated sensors (aided or free INS, with or without injected faults), its errors and σ
//! recorded at the output epochs; and the batches of runs.

use super::config::{landmark_position, output_epochs, Config, InitialErrorConfig, ARCSEC, R0};
use super::errors::{euler_to_phi_jacobian, record, ImuFaultTally, RunOutput, TrueBiases};
use super::injection::{self, Faults};
use super::report::{statistics, Stats};
use super::sensors::Sensors;
use super::trajectory::Truth;
use crate::rng::{normal, SimRng};
use anyhow::{bail, Result};
use nalgebra::{Matrix3, SMatrix, Vector3};
use nav_core::contract::{Estimator, Gate};
use nav_core::math::rotation::{dcm_to_euler, dcm_to_quat, euler_to_dcm};
use nav_core::seeker_ins::{
    default_recovery, gimbal_angles_of, landmark_vector_ned, ClipFlags, GimbalAngles,
    ImuFaultPolicy, ImuIncrement, InsState, InstrumentErrors, Landmark, LosResidual, LosSample,
    Position, SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsInitial, STATES,
};
use nav_core::FusionOutcome;
use nav_core::Real;

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
pub(super) fn initial_covariance(cfg: &Config, c0: &Matrix3<f64>) -> SMatrix<f64, STATES, STATES> {
    let fc = &cfg.filter;
    table4_covariance(
        &cfg.initial_error,
        c0,
        fc.accel_bias_sigma_ug * 1e-6 * super::config::G0,
        fc.gyro_bias_sigma_deg_h.to_radians() / 3600.0,
        fc.gimbal_bias_sigma_deg.to_radians(),
    )
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
            .map_or_else(ImuFaultPolicy::default, injection::policy_cast::<T>),
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

//! The flight navigator as the mission flies it: its settings (TOML table `[navigator]`, the
//! design, not the truth), the variants of the chain compared on the same seeds, and the
//! navigator's configuration of a variant (transfer alignment, seeker INS, baro aid).

use super::config::MissionConfig;
use crate::scenarios::transfer_alignment::config::Precision;
use crate::scenarios::transfer_alignment::estimate::cast_config;
use anyhow::{anyhow, Result};
use nalgebra::Vector3;
use nav_core::contract::Gate;
use nav_core::navigator::{
    AidTimeouts, BaroDamping, BaroErrorModel, HandoverPriors, LeverArm, NavigatorConfig,
    SeparationCheck,
};
use nav_core::seeker_ins::{
    default_recovery, ImuFaultPolicy, InstrumentErrors, Landmark, LosResidual, SeekerInsConfig,
};
use nav_core::transfer_alignment::{AxisFlexure, PaperCase, TaConfig};
use nav_core::vertical_channel::{AidTimeouts as VcTimeouts, ClassicalConfig, ErrorModel};
use nav_core::Real;
use serde::Deserialize;

/// Slave-history depth of the navigator, samples: the sizing rule `(H − 2) · imu_dt ≥` the
/// largest master latency accepted (`NavigatorConfig::max_master_latency_s`, the mission's
/// `[master] latency_s` upper bound), checked at construction. 512 reaches 0.51 s at 1 kHz:
/// the mission's 0.1 s and the stress campaign's late master (0.3 s, and the 0.4 s late
/// fault) at every IMU rate flown (100-1000 Hz). A navigator holds ≈ 96 B per sample in f32
/// (≈ 49 KB here): host memory; the firmware image's depth is its own.
pub const HISTORY: usize = 512;

/// The navigator's settings (TOML table `[navigator]`): everything that is design, not truth.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NavigatorSettings {
    /// Float type the navigator runs in.
    pub precision: Precision,
    /// Output (statistics) rate, Hz.
    pub output_hz: f64,
    /// 1σ of the lever arm's knowledge per axis, m.
    pub lever_arm_sigma_m: [f64; 3],
    /// χ²(1) gate per scalar LOS component and baro update.
    pub gate_nis: f64,
    /// Covariance propagation rate of the EKF, Hz.
    pub covariance_hz: f64,
    /// Separation check: specific-force jump that confirms a release, m/s².
    pub separation_jump_m_s2: f64,
    /// Separation check: window after the signal for the IMU's confirmation, and how long
    /// the IMU's unloading or free fall must last without a signal, s.
    pub separation_window_s: f64,
    /// Separation check without a signal: the latest start of the unloading after the last
    /// fused master sample's time of validity, s.
    pub separation_onset_s: f64,
    /// Released → midcourse (baro enabled) after this coast, s.
    pub coast_s: f64,
    /// Aid time-outs: master (carry), baro (midcourse), seeker (terminal), s.
    pub timeouts_s: [f64; 3],
    /// `baro_loop` variant: time constant of the baro-inertial loop's triple pole, s.
    pub baro_loop_tau_s: f64,
    /// `baro_loop` variant: the loop's error model's σ of the initial altitude and vertical
    /// velocity (m, m/s). The navigator starts the loop's σ from the EKF's vertical covariance
    /// at midcourse; this one is the design's, and the start's only if the EKF's is refused.
    pub baro_loop_initial_sigma: [f64; 2],
}

/// The links of the chain compared on the same seeds.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Variant {
    /// Flight transfer alignment, hand-over, baro EKF, seeker.
    Full,
    /// The conventional 9-state alignment in carry.
    ConventionalAlignment,
    /// Released with the seeker paper's Table 4 initial errors (no alignment).
    Table4Initial,
    /// No baro damping.
    NoBaro,
    /// No seeker.
    NoSeeker,
    /// Baro through the baro-inertial loop around the INS's vertical channel instead of the
    /// EKF.
    BaroLoop,
}

impl Variant {
    /// Every variant, in report order.
    pub const ALL: [Self; 6] = [
        Self::Full,
        Self::ConventionalAlignment,
        Self::Table4Initial,
        Self::NoBaro,
        Self::NoSeeker,
        Self::BaroLoop,
    ];

    /// Name in outputs and scenario files.
    pub fn name(self) -> &'static str {
        match self {
            Self::Full => "full",
            Self::ConventionalAlignment => "conventional_alignment",
            Self::Table4Initial => "table4_initial",
            Self::NoBaro => "no_baro",
            Self::NoSeeker => "no_seeker",
            Self::BaroLoop => "baro_loop",
        }
    }

    /// The variant of a name.
    pub fn from_name(s: &str) -> Result<Self> {
        Self::ALL
            .into_iter()
            .find(|v| v.name() == s)
            .ok_or_else(|| anyhow!("unknown variant `{s}`"))
    }
}

/// The transfer-alignment filter's configuration for the mission: the truth's lever arm and
/// flexure model, the mount σ, the noise of one rate / specific-force difference (the
/// missile IMU's sample at the IMU interval, the master's at its message interval, at least
/// the filter's floor), the
/// specific-force-difference bias σ of both accelerometers; the filter's grid is the IMU
/// interval (the navigator's requirement) and bridges up to 1 s without master data.
fn ta_config(cfg: &MissionConfig) -> TaConfig<f64> {
    let base = TaConfig::<f64>::flight(PaperCase::Case3);
    let dt = 1.0 / cfg.imu_hz;
    let dt_master = 1.0 / cfg.master.rate_hz;
    let fl = &cfg.carry.flexure;
    let s = &cfg.sensors;
    let g0 = 9.806_65;
    let slave_gyro = s.gyro_arw_deg_rt_h.to_radians() / 60.0 / dt.sqrt();
    let slave_acc = s.accel_noise_ug_rt_hz * 1e-6 * g0 / dt.sqrt();
    let mi = &cfg.master.imu;
    // The instruments' noise is below the filter's floor (Table 3 and a navigation-grade
    // master); the floor also covers what the instruments do not: the slave's mean over the
    // IMU interval against the master's sample at the epoch.
    let rate = slave_gyro
        .hypot(mi.gyro_sigma_per_sample_rad_s(dt_master))
        .max(nav_core::transfer_alignment::RATE_NOISE_SIGMA_RANGE_RAD_S.0);
    let acc = slave_acc
        .hypot(mi.accel_sigma_per_sample_m_s2(dt_master))
        .max(nav_core::transfer_alignment::ACCEL_NOISE_SIGMA_RANGE_M_S2.0);
    TaConfig {
        lever_arm_m: Vector3::from(cfg.carry.lever_arm_m),
        flexure: std::array::from_fn(|a| AxisFlexure {
            sigma_rad: fl.sigma_deg[a].to_radians(),
            tau_s: fl.tau_s[a],
        }),
        mount_sigma_rad: Vector3::from(cfg.carry.mount_sigma_deg.map(f64::to_radians)),
        rate_noise_sigma_rad_s: rate,
        accel_noise_sigma_m_s2: acc,
        accel_bias_sigma_m_s2: Vector3::repeat(
            (s.accel_bias_ug * 1e-6 * g0).hypot(mi.accel_bias_ug * 1e-6 * g0),
        ),
        dt_s: dt,
        time_tolerance_s: 0.1 * dt,
        max_gap_steps: (cfg.imu_hz.round() as u32).min(nav_core::transfer_alignment::MAX_GAP_STEPS),
        gate: Gate::Off,
        ..base
    }
}

/// The navigator's configuration of a variant, in float type T.
pub(crate) fn navigator_config<T: Real>(
    cfg: &MissionConfig,
    set: &NavigatorSettings,
    variant: Variant,
) -> Result<NavigatorConfig<T>> {
    let s = &cfg.sensors;
    let g0 = 9.806_65;
    let arcsec = (1.0f64 / 3600.0).to_radians();
    let dt = 1.0 / cfg.imu_hz;
    let landmark = Landmark::new(cfg.landmark_position()).map_err(|e| anyhow!("landmark: {e}"))?;
    let ins = SeekerInsConfig::<T> {
        instrument_errors: InstrumentErrors {
            accel_scale_factor: T::lit(s.accel_scale_factor_ppm * 1e-6),
            accel_misalignment_rad: T::lit(s.accel_misalignment_arcsec * arcsec),
            gyro_scale_factor: T::lit(s.gyro_scale_factor_ppm * 1e-6),
            gyro_misalignment_rad: T::lit(s.gyro_misalignment_arcsec * arcsec),
        },
        imu_dt_s: T::lit(dt),
        covariance_interval_steps: (cfg.imu_hz / set.covariance_hz).round() as u16,
        accel_noise_density_m_s2_rt_hz: T::lit(s.accel_noise_ug_rt_hz * 1e-6 * g0),
        gyro_noise_density_rad_s_rt_hz: T::lit(s.gyro_arw_deg_rt_h.to_radians() / 60.0),
        seeker_noise_rad: T::lit(s.seeker_noise_deg.to_radians()),
        gate: Gate::Nis(T::lit(set.gate_nis)),
        recovery: default_recovery(),
        imu_faults: ImuFaultPolicy::default(),
        landmark,
        residual: LosResidual::Projected2d,
    };
    let b = &cfg.baro;
    let model = BaroErrorModel {
        white_sigma_m: T::lit(b.noise_m),
        markov_sigma_m: T::lit(b.markov_sigma_m),
        markov_tau_s: T::lit(b.markov_tau_s),
        lag_s: T::lit(b.lag_s),
    };
    let baro = match variant {
        Variant::NoBaro => BaroDamping::Off,
        Variant::BaroLoop => BaroDamping::InertialLoop(baro_loop::<T>(cfg, set)),
        _ => BaroDamping::Ekf(model),
    };
    Ok(NavigatorConfig {
        alignment: cast_config(&ta_config(cfg)),
        lever_arm: LeverArm {
            nominal_m: Vector3::from(cfg.carry.lever_arm_m).map(T::lit),
            sigma_m: Vector3::from(set.lever_arm_sigma_m).map(T::lit),
        },
        priors: HandoverPriors {
            accel_bias_sigma_m_s2: T::lit(s.accel_bias_ug * 1e-6 * g0),
            gyro_bias_sigma_rad_s: T::lit(s.gyro_bias_deg_h.to_radians() / 3600.0),
            gimbal_bias_sigma_rad: T::lit(s.seeker_bias_deg.to_radians()),
        },
        ins,
        imu_dt_s: T::lit(dt),
        max_master_latency_s: T::lit(cfg.master.latency_s[1]),
        separation: SeparationCheck {
            specific_force_jump_m_s2: T::lit(set.separation_jump_m_s2),
            confirm_window_s: T::lit(set.separation_window_s),
            unsignalled_onset_s: T::lit(set.separation_onset_s),
            coast_s: T::lit(set.coast_s),
        },
        baro,
        timeouts: AidTimeouts {
            master_s: T::lit(set.timeouts_s[0]),
            baro_s: T::lit(set.timeouts_s[1]),
            seeker_s: T::lit(set.timeouts_s[2]),
        },
    })
}

/// The classical baro-inertial loop of the `baro_loop` variant: the vertical-channel
/// scenarios' design (paper aid model and recovery, no gate) at the mission's IMU and baro
/// rates, its σ computed for the missile's Table 3 accelerometer and the mission's baro.
fn baro_loop<T: Real>(cfg: &MissionConfig, set: &NavigatorSettings) -> ClassicalConfig<T> {
    let g0 = 9.806_65;
    let b = &cfg.baro;
    let baro_period = 1.0 / b.rate_hz;
    ClassicalConfig {
        imu_dt_s: T::lit(1.0 / cfg.imu_hz),
        latitude_rad: T::lit(cfg.profile.start_lat_deg.to_radians()),
        tau_s: T::lit(set.baro_loop_tau_s),
        baro_lag_s: T::lit(b.lag_s),
        baro_period_s: T::lit(baro_period),
        baro_timeouts: VcTimeouts {
            stale_after_s: T::lit(1.5 * baro_period),
            lost_after_s: T::lit(set.timeouts_s[1]),
        },
        error_model: ErrorModel {
            accel_noise_m_s2_rt_hz: T::lit(cfg.sensors.accel_noise_ug_rt_hz * 1e-6 * g0),
            // The loop's input is the vertical specific force: its accelerometer error is the
            // vertical equivalent bias of flight at ≈ 1 g, the bias and the scale factor's
            // share `S g` (the misalignment's, `M f_horizontal`, is ≈ 0 in level flight).
            accel_bias_sigma_m_s2: T::lit(
                (cfg.sensors.accel_bias_ug * 1e-6 * g0)
                    .hypot(cfg.sensors.accel_scale_factor_ppm * 1e-6 * g0),
            ),
            accel_bias_rw_m_s2_rt_s: T::zero(),
            baro_noise_m: T::lit(b.noise_m),
            baro_markov_sigma_m: T::lit(b.markov_sigma_m),
            baro_markov_tau_s: T::lit(b.markov_tau_s),
            // No velocity aid in the classical loop: unused, any valid value.
            velocity_noise_m_s: T::lit(0.1),
            initial_altitude_sigma_m: T::lit(set.baro_loop_initial_sigma[0]),
            initial_vz_sigma_m_s: T::lit(set.baro_loop_initial_sigma[1]),
        },
        ..ClassicalConfig::paper()
    }
}

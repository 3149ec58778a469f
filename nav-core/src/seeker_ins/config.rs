//! Configuration of the seeker-aided INS, its policies and their validation, and the design
//! (what [`crate::contract::Estimator::design`] computes from the configuration).

use super::error_model::STATES;
use super::flight_noise::InstrumentErrors;
use super::measurement::Landmark;
use crate::contract::{DesignStamp, Fingerprint, Gate, RecoveryAction, RecoveryPolicy};
use crate::design::{DesignValues, ValueReader, ValueWriter, BAD_VALUES};
use crate::error::{in_range, ConfigIssue};
use crate::time::{seconds_to_micros, MICROS_PER_SECOND};
use crate::{NavError, Real};

/// Physical ceilings of the error-state variances (units of the error state, see the module
/// [`super`] doc): latitude and longitude (1 rad)², altitude (10⁷ m)², velocity (10⁴ m/s)²,
/// attitude 10 rad² (≈ π², nothing known), accelerometer bias (100 m/s²)², gyro bias
/// (1 rad/s)², gimbal errors 10 rad². The initial covariance may not exceed them; the
/// navigation block (states 0..9) is limited to them at run time.
pub const VARIANCE_CEILING: [f64; STATES] = [
    1.0, 1.0, 1e14, 1e8, 1e8, 1e8, 10.0, 10.0, 10.0, 1e4, 1e4, 1e4, 1.0, 1.0, 1.0, 10.0, 10.0,
];

/// Without a fused LOS component for this long the health is `Degraded` (aid lost), s; an
/// IMU gap or clipped sample keeps it `Degraded` for as long.
pub const AID_TIMEOUT_S: f64 = 10.0;
/// [`AID_TIMEOUT_S`] in µs.
pub(crate) const AID_TIMEOUT_US: u64 = 10 * MICROS_PER_SECOND;

/// Largest number of held IMU samples one gap may need (`max_gap_s / imu_dt_s`): bounds the
/// work of the IMU sample that ends a gap.
pub const MAX_GAP_SAMPLES: u32 = 500;
/// Largest accepted [`ImuFaultPolicy::max_gap_s`], s: beyond it a zero-order hold is no model
/// of the motion.
pub const MAX_GAP_S: f64 = 5.0;
/// Largest accepted accelerometer σ of the IMU fault policy (gap and clipping), m/s² (≈ 100 g).
pub const MAX_FAULT_ACCEL_SIGMA_M_S2: f64 = 1000.0;
/// Largest accepted rate σ of the IMU fault policy (gap and clipping), rad/s.
pub const MAX_FAULT_RATE_SIGMA_RAD_S: f64 = 50.0;
/// Largest attitude σ one full gap may add, `gap_rate_sigma × max_gap_s`, rad (the error model
/// is a small-angle model).
pub const MAX_GAP_ATTITUDE_SIGMA_RAD: f64 = 1.0;
/// Largest velocity σ one full gap may add, `gap_accel_sigma × max_gap_s`, m/s.
pub const MAX_GAP_VELOCITY_SIGMA_M_S: f64 = 100.0;
/// Largest accepted [`RecoveryAction::Inflate`] variance factor (σ × 10).
pub const MAX_INFLATION_FACTOR: f64 = 100.0;
/// Largest accepted [`RecoveryPolicy::starved_after_s`], s.
pub const MAX_STARVED_AFTER_S: f64 = 3600.0;

/// Filter configuration. σ are standard deviations, densities are √PSD. The ranges below are
/// the envelope in which the filter is known to work (stress campaign, README); outside them
/// construction returns `InvalidConfig` naming the field.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeekerInsConfig<T> {
    /// Nominal IMU sample interval, s: [1e-4, 0.1] (10 kHz to 10 Hz). The interval of the
    /// first sample; an IMU interval longer than 1.5 × it is a gap ([`ImuFaultPolicy`]).
    pub imu_dt_s: T,
    /// Covariance propagation every this many IMU samples, ≥ 1, with
    /// `covariance_interval_steps × imu_dt_s ≤ 1 s` (the second-order transition matrix);
    /// e.g. 10 at 100 Hz → 10 Hz.
    pub covariance_interval_steps: u16,
    /// Accelerometer white noise density (velocity random walk), m/s²/√Hz: [0, 0.1].
    pub accel_noise_density_m_s2_rt_hz: T,
    /// Gyro white noise density (angle random walk), rad/s/√Hz = rad/√s: [0, 0.01].
    pub gyro_noise_density_rad_s_rt_hz: T,
    /// Seeker gimbal-angle white noise, 1σ per angle, rad: [1e-5, 0.1] (below 1e-5 rad the
    /// f32 LOS residual, a difference of unit vectors, is no longer resolved).
    pub seeker_noise_rad: T,
    /// χ² gate (1 degree of freedom) on each scalar LOS component: `Off`, or `Nis(threshold)`
    /// with threshold in [1, 10⁴] (e.g. 16: 4σ).
    pub gate: Gate<T>,
    /// Recovery when the gate starves the filter of LOS updates ([`RecoveryPolicy`]); only
    /// [`RecoveryAction::Inflate`] is supported (module doc of [`super`]).
    pub recovery: RecoveryPolicy<T>,
    /// IMU gap bridging and clipped-sample handling.
    pub imu_faults: ImuFaultPolicy<T>,
    /// The landmark the seeker tracks.
    pub landmark: Landmark<T>,
    /// Residual form (the spec's first open point; [`LosResidual::Projected2d`] is the design
    /// choice, the other is kept for comparison).
    pub residual: LosResidual,
    /// 1σ of the scale-factor and misalignment errors of the IMU, which the 17 states do not
    /// model (module `flight_noise`: the accelerometer-bias states become the equivalent bias
    /// `b + (S + M) f_ref` at a reference specific force, departures from it add velocity
    /// noise, the gyro errors attitude noise). All zero (the paper's filter,
    /// [`SeekerInsConfig::paper`]) adds nothing; [`SeekerInsConfig::flight`] sets them.
    pub instrument_errors: InstrumentErrors<T>,
}

/// Form of the LOS residual fused by the LOS update.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum LosResidual {
    /// Two components in the plane normal to the LOS, `R = diag(σ², σ² cos² θ_s)`.
    #[default]
    Projected2d,
    /// The NED 3-vector with full-rank `R = σ² I₃`; the report's `pitch`/`yaw` then hold the
    /// N and E components, the D component is fused as well but reported only through the
    /// state. Needs the crate feature `los-residual-3d` (default); without it construction
    /// refuses it (`InvalidConfig { field: "residual" }`).
    FullRank3d,
}

/// The recovery policy of the seeker INS before time stamps, mapped exactly at the 10 Hz
/// seeker rate: 50 fully rejected LOS samples = 5 s, variance factor 4 (σ × 2) on the
/// navigation block. A 10 s false lock 2° off causes at most two inflations (σ × 4), still
/// rejected.
pub fn default_recovery<T: Real>() -> RecoveryPolicy<T> {
    RecoveryPolicy {
        starved_after_s: Some(T::lit(5.0)),
        action: RecoveryAction::Inflate {
            variance_factor: T::lit(4.0),
        },
    }
}

/// IMU fault handling: bridging of gaps (an IMU interval longer than 1.5 × `imu_dt_s`:
/// samples lost on the bus, a sensor reset) and of samples the IMU flags as clipped at its
/// measurement range.
///
/// In both cases the INS integrates an increment known to be wrong by an unknown amount:
/// the held increment misses the change of specific force / rate since the last good sample,
/// the clipped one the excess beyond the range. That error is modelled as a random constant
/// over a run of consecutive degraded samples (fully correlated: a manoeuvre or a clipped
/// vibration does not average out over 10 ms), per NED axis, with σ `*_accel_sigma_m_s2`
/// and `*_rate_sigma_rad_s`. After `c` consecutive degraded samples of interval Δt it has put
/// `c σ_a Δt` into the velocity error and `c σ_ω Δt` into the misalignment, so sample `c`
/// adds `(2c − 1)(σ Δt)²` to the diagonal of the velocity (states 3..6) and attitude (6..9)
/// blocks of P (the sum over `c = 1..n` is `(n σ Δt)²`); the position follows through Φ.
/// Adding to the diagonal keeps P symmetric PSD. Isotropic in NED (the clipped body axis is
/// not resolved: conservative by at most the two other axes). The variances are limited to
/// [`VARIANCE_CEILING`], so a clipping burst of any length keeps P bounded and PSD.
///
/// Valid ranges: `max_gap_s` in [`imu_dt_s`, [`MAX_GAP_S`]] with `max_gap_s / imu_dt_s ≤`
/// [`MAX_GAP_SAMPLES`]; accelerometer σ in [0, [`MAX_FAULT_ACCEL_SIGMA_M_S2`]] m/s², rate σ in
/// [0, [`MAX_FAULT_RATE_SIGMA_RAD_S`]] rad/s; over one full gap `gap_rate_sigma × max_gap_s ≤`
/// [`MAX_GAP_ATTITUDE_SIGMA_RAD`] and `gap_accel_sigma × max_gap_s ≤`
/// [`MAX_GAP_VELOCITY_SIGMA_M_S`].
///
/// [`imu_dt_s`]: SeekerInsConfig::imu_dt_s
#[derive(Debug, Clone, Copy, PartialEq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ImuFaultPolicy<T> {
    /// Longest gap bridged by the hold, s (the missing samples, `interval − imu_dt_s`). A
    /// longer gap is not bridged: the navigation covariance goes to its ceilings, the health
    /// to `NeedsReinitialisation` (counted in `Health::gaps_reset`).
    pub max_gap_s: T,
    /// σ of the specific-force change the hold misses during a gap, m/s² (per NED axis).
    pub gap_accel_sigma_m_s2: T,
    /// σ of the angular-rate change the hold misses during a gap, rad/s (per axis).
    pub gap_rate_sigma_rad_s: T,
    /// σ of the unknown specific-force excess beyond the range in a clipped sample, m/s².
    pub clip_accel_sigma_m_s2: T,
    /// σ of the unknown rate excess beyond the range in a clipped sample, rad/s.
    pub clip_rate_sigma_rad_s: T,
}

impl<T: Real> Default for ImuFaultPolicy<T> {
    /// 0.5 s (50 samples at 100 Hz); gap: 2 m/s², 0.01 rad/s; clipping: 10 m/s² (≈ 1 g beyond
    /// the range), 0.5 rad/s.
    fn default() -> Self {
        Self {
            max_gap_s: T::lit(0.5),
            gap_accel_sigma_m_s2: T::lit(2.0),
            gap_rate_sigma_rad_s: T::lit(0.01),
            clip_accel_sigma_m_s2: T::lit(10.0),
            clip_rate_sigma_rad_s: T::lit(0.5),
        }
    }
}

/// What [`crate::contract::Estimator::design`] computes from a [`SeekerInsConfig`]: the
/// white-noise PSDs of the covariance propagation. Stored as 4 values
/// ([`DesignValues`]): stamp version, stamp fingerprint, accelerometer PSD, gyro PSD.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SeekerInsDesign<T> {
    /// Layout version and fingerprint of the configuration values the design depends on.
    pub stamp: DesignStamp,
    /// Accelerometer white-noise PSD (velocity random walk²), m²/s³.
    pub accel_psd_m2_s3: T,
    /// Gyro white-noise PSD (angle random walk²), rad²/s.
    pub gyro_psd_rad2_s: T,
}

/// Layout version of [`SeekerInsDesign`]'s value list.
pub const DESIGN_VERSION: u16 = 1;

/// The stamp of the design of `config`: fingerprint over `accel_noise_density_m_s2_rt_hz`,
/// `gyro_noise_density_rad_s_rt_hz`, then the four σ of `instrument_errors` (accelerometer
/// scale factor, misalignment, gyro scale factor, misalignment): the values the process noise
/// depends on, in this order.
pub fn design_stamp<T: Real>(config: &SeekerInsConfig<T>) -> DesignStamp {
    let e = &config.instrument_errors;
    DesignStamp {
        version: DESIGN_VERSION,
        fingerprint: Fingerprint::new()
            .real(config.accel_noise_density_m_s2_rt_hz)
            .real(config.gyro_noise_density_rad_s_rt_hz)
            .real(e.accel_scale_factor)
            .real(e.accel_misalignment_rad)
            .real(e.gyro_scale_factor)
            .real(e.gyro_misalignment_rad)
            .finish(),
    }
}

/// The design of a validated configuration.
pub(crate) fn compute_design<T: Real>(config: &SeekerInsConfig<T>) -> SeekerInsDesign<T> {
    let a = config.accel_noise_density_m_s2_rt_hz;
    let g = config.gyro_noise_density_rad_s_rt_hz;
    SeekerInsDesign {
        stamp: design_stamp(config),
        accel_psd_m2_s3: a * a,
        gyro_psd_rad2_s: g * g,
    }
}

impl<T: Real> DesignValues for SeekerInsDesign<T> {
    const COUNT: usize = 4;

    fn write_values(&self, out: &mut [f64]) -> Result<(), NavError> {
        let mut w = ValueWriter::new(out, Self::COUNT)?;
        w.push(f64::from(self.stamp.version));
        w.push(f64::from(self.stamp.fingerprint));
        w.real(self.accel_psd_m2_s3);
        w.real(self.gyro_psd_rad2_s);
        w.finish()
    }

    fn read_values(values: &[f64]) -> Result<Self, NavError> {
        let mut r = ValueReader::new(values, Self::COUNT)?;
        let version = r.value()?;
        let fingerprint = r.value()?;
        let whole = |v: f64, max: f64| v >= 0.0 && v <= max && libm::trunc(v) == v;
        if !whole(version, f64::from(u16::MAX)) || !whole(fingerprint, f64::from(u32::MAX)) {
            return Err(BAD_VALUES);
        }
        Ok(Self {
            stamp: DesignStamp {
                version: version as u16,
                fingerprint: fingerprint as u32,
            },
            accel_psd_m2_s3: r.real()?,
            gyro_psd_rad2_s: r.real()?,
        })
    }
}

/// Checks a design against the configuration it is used with: stamp, and PSDs finite ≥ 0.
pub(crate) fn check_design<T: Real>(
    config: &SeekerInsConfig<T>,
    design: &SeekerInsDesign<T>,
) -> Result<(), NavError> {
    design.stamp.check(&design_stamp(config))?;
    for v in [design.accel_psd_m2_s3, design.gyro_psd_rad2_s] {
        if !v.is_finite() || v < T::zero() {
            return Err(NavError::InvalidConfig {
                field: "design",
                issue: ConfigIssue::OutOfRange,
            });
        }
    }
    Ok(())
}

fn out_of_range(field: &'static str) -> NavError {
    NavError::InvalidConfig {
        field,
        issue: ConfigIssue::OutOfRange,
    }
}

/// The gate's range: `Off`, or a NIS threshold in [1, 10⁴] (`field: "gate"`).
pub(crate) fn validate_gate<T: Real>(gate: Gate<T>) -> Result<(), NavError> {
    match gate {
        Gate::Off => Ok(()),
        Gate::Nis(t) => in_range("gate", t, T::one(), T::lit(1e4)),
    }
}

/// The recovery policy's range: `starved_after_s` `None` or in (0, [`MAX_STARVED_AFTER_S`]]
/// (`"recovery.starved_after_s"`); only `Inflate` with a factor in (1,
/// [`MAX_INFLATION_FACTOR`]] (`"recovery.action"`).
pub(crate) fn validate_recovery<T: Real>(policy: &RecoveryPolicy<T>) -> Result<(), NavError> {
    if let Some(s) = policy.starved_after_s {
        in_range(
            "recovery.starved_after_s",
            s,
            T::zero(),
            T::lit(MAX_STARVED_AFTER_S),
        )?;
        if s <= T::zero() {
            return Err(out_of_range("recovery.starved_after_s"));
        }
    }
    match policy.action {
        RecoveryAction::Inflate { variance_factor } => {
            in_range(
                "recovery.action",
                variance_factor,
                T::one(),
                T::lit(MAX_INFLATION_FACTOR),
            )?;
            if variance_factor <= T::one() {
                return Err(out_of_range("recovery.action"));
            }
            Ok(())
        }
        RecoveryAction::ResetToPrior | RecoveryAction::Reanchor => {
            Err(out_of_range("recovery.action"))
        }
    }
}

/// The IMU fault policy's ranges ([`ImuFaultPolicy`]) at the IMU interval `imu_dt_s`.
pub(crate) fn validate_imu_faults<T: Real>(
    policy: &ImuFaultPolicy<T>,
    imu_dt_s: T,
) -> Result<(), NavError> {
    let gap_s = policy.max_gap_s;
    in_range("imu_faults.max_gap_s", gap_s, imu_dt_s, T::lit(MAX_GAP_S))?;
    if gap_s / imu_dt_s > T::from_count(MAX_GAP_SAMPLES) {
        return Err(out_of_range("imu_faults.max_gap_s"));
    }
    let (amax, wmax) = (
        T::lit(MAX_FAULT_ACCEL_SIGMA_M_S2),
        T::lit(MAX_FAULT_RATE_SIGMA_RAD_S),
    );
    let p = policy;
    in_range(
        "imu_faults.gap_accel_sigma_m_s2",
        p.gap_accel_sigma_m_s2,
        T::zero(),
        amax,
    )?;
    in_range(
        "imu_faults.gap_rate_sigma_rad_s",
        p.gap_rate_sigma_rad_s,
        T::zero(),
        wmax,
    )?;
    in_range(
        "imu_faults.clip_accel_sigma_m_s2",
        p.clip_accel_sigma_m_s2,
        T::zero(),
        amax,
    )?;
    in_range(
        "imu_faults.clip_rate_sigma_rad_s",
        p.clip_rate_sigma_rad_s,
        T::zero(),
        wmax,
    )?;
    if p.gap_rate_sigma_rad_s * gap_s > T::lit(MAX_GAP_ATTITUDE_SIGMA_RAD) {
        return Err(out_of_range("imu_faults.gap_rate_sigma_rad_s"));
    }
    if p.gap_accel_sigma_m_s2 * gap_s > T::lit(MAX_GAP_VELOCITY_SIGMA_M_S) {
        return Err(out_of_range("imu_faults.gap_accel_sigma_m_s2"));
    }
    Ok(())
}

/// The ranges of [`SeekerInsConfig`] (its field docs).
pub(crate) fn validate_config<T: Real>(config: &SeekerInsConfig<T>) -> Result<(), NavError> {
    use crate::error::{require_non_negative, require_positive};
    let c = config;
    require_positive("imu_dt_s", c.imu_dt_s)?;
    in_range("imu_dt_s", c.imu_dt_s, T::lit(1e-4), T::lit(0.1))?;
    let (a, g) = (
        c.accel_noise_density_m_s2_rt_hz,
        c.gyro_noise_density_rad_s_rt_hz,
    );
    require_non_negative("accel_noise_density_m_s2_rt_hz", a)?;
    in_range("accel_noise_density_m_s2_rt_hz", a, T::zero(), T::lit(0.1))?;
    require_non_negative("gyro_noise_density_rad_s_rt_hz", g)?;
    in_range("gyro_noise_density_rad_s_rt_hz", g, T::zero(), T::lit(0.01))?;
    require_positive("seeker_noise_rad", c.seeker_noise_rad)?;
    in_range(
        "seeker_noise_rad",
        c.seeker_noise_rad,
        T::lit(1e-5),
        T::lit(0.1),
    )?;
    validate_gate(c.gate)?;
    validate_recovery(&c.recovery)?;
    validate_imu_faults(&c.imu_faults, c.imu_dt_s)?;
    super::flight_noise::validate(&c.instrument_errors)?;
    if cfg!(not(feature = "los-residual-3d")) && c.residual == LosResidual::FullRank3d {
        return Err(out_of_range("residual"));
    }
    if c.covariance_interval_steps == 0 {
        return Err(NavError::InvalidConfig {
            field: "covariance_interval_steps",
            issue: ConfigIssue::NotPositive,
        });
    }
    let interval_s = c.imu_dt_s * T::from_count(u32::from(c.covariance_interval_steps));
    if interval_s > T::lit(1.0) {
        return Err(out_of_range("covariance_interval_steps"));
    }
    Ok(())
}

/// `starved_after_s` in whole µs (`None`: recovery off).
pub(crate) fn starved_after_us<T: Real>(policy: &RecoveryPolicy<T>) -> Option<u64> {
    policy.starved_after_s.and_then(seconds_to_micros)
}

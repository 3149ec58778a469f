//! The seed paper's configuration (Oh, Kim, Lee, Lee, Park 2006, Tables 3 and 4; rates and
//! geometry assumed as in the spec), in one place for the golden vectors, the firmware image
//! and the tests.

use super::config::{default_recovery, ImuFaultPolicy, LosResidual, SeekerInsConfig};
use super::error_model::STATES;
use super::flight_noise::InstrumentErrors;
use super::measurement::Landmark;
use crate::contract::Gate;
use crate::Real;
use nalgebra::SMatrix;

/// IMU interval of the paper configuration, s (100 Hz, assumed).
pub const PAPER_IMU_DT_S: f64 = 0.01;
/// [`PAPER_IMU_DT_S`] in µs.
pub const PAPER_IMU_DT_US: u64 = 10_000;
/// Covariance propagation every this many IMU samples in the paper configuration (10 Hz,
/// the seeker rate).
pub const PAPER_COVARIANCE_INTERVAL_STEPS: u16 = 10;

/// One degree in radians, computed in `T` (as the f32 flight build computes it).
fn deg<T: Real>() -> T {
    T::lit(core::f64::consts::PI) / T::lit(180.0)
}

/// Standard gravity × 10⁻⁶ (1 µg), m/s², in `T`.
fn micro_g<T: Real>() -> T {
    T::lit(9.806_65e-6)
}

impl<T: Real> SeekerInsConfig<T> {
    /// The paper's filter: 100 Hz IMU, covariance at 10 Hz, accelerometer noise 5 µg/√Hz,
    /// gyro ARW 0.01 °/√h, seeker noise 0.17° (1σ), χ² gate 16 (4σ), the default recovery
    /// (5 s of rejections → variances × 4) and IMU fault policy, the 2-D projected residual.
    pub fn paper(landmark: Landmark<T>) -> Self {
        let d = deg::<T>();
        Self {
            imu_dt_s: T::lit(PAPER_IMU_DT_S),
            covariance_interval_steps: PAPER_COVARIANCE_INTERVAL_STEPS,
            accel_noise_density_m_s2_rt_hz: T::lit(5.0) * micro_g::<T>(),
            gyro_noise_density_rad_s_rt_hz: T::lit(0.01) * d / T::lit(60.0),
            seeker_noise_rad: T::lit(0.17) * d,
            gate: Gate::Nis(T::lit(16.0)),
            recovery: default_recovery(),
            imu_faults: ImuFaultPolicy::default(),
            landmark,
            residual: LosResidual::Projected2d,
            instrument_errors: InstrumentErrors::default(),
        }
    }

    /// The flight configuration: the paper's filter ([`SeekerInsConfig::paper`]) with the
    /// scale-factor and misalignment σ of the IMU accounted for (module `flight_noise`):
    /// the paper's Table 3 values, 200 ppm and 10″ for the accelerometers, 20 ppm and 10″ for
    /// the gyros. A different IMU: set [`SeekerInsConfig::instrument_errors`] to its data
    /// sheet.
    pub fn flight(landmark: Landmark<T>) -> Self {
        let arcsec = deg::<T>() / T::lit(3600.0);
        Self {
            instrument_errors: InstrumentErrors {
                accel_scale_factor: T::lit(200e-6),
                accel_misalignment_rad: T::lit(10.0) * arcsec,
                gyro_scale_factor: T::lit(20e-6),
                gyro_misalignment_rad: T::lit(10.0) * arcsec,
            },
            ..Self::paper(landmark)
        }
    }
}

/// The paper's initial covariance P0 (Table 4, diagonal): 40 m in latitude, longitude (as
/// 40 m / 6 371 km rad) and altitude, 10 m/s per velocity axis, 1° roll and pitch and 5° yaw
/// misalignment, 100 µg accelerometer bias, 0.01 °/h gyro bias, 0.04° gimbal errors.
pub fn paper_initial_covariance<T: Real>() -> SMatrix<T, STATES, STATES> {
    let d = deg::<T>();
    let ug = micro_g::<T>();
    let r0 = T::lit(6_371_000.0);
    let pos = T::lit(40.0) / r0;
    let gyro = T::lit(0.01) * d / T::lit(3600.0);
    let sig = [
        pos,
        pos,
        T::lit(40.0),
        T::lit(10.0),
        T::lit(10.0),
        T::lit(10.0),
        d,
        d,
        T::lit(5.0) * d,
        T::lit(100.0) * ug,
        T::lit(100.0) * ug,
        T::lit(100.0) * ug,
        gyro,
        gyro,
        gyro,
        T::lit(0.04) * d,
        T::lit(0.04) * d,
    ];
    let mut p0 = SMatrix::<T, STATES, STATES>::zeros();
    for (i, s) in sig.iter().enumerate() {
        if let Some(v) = p0.get_mut((i, i)) {
            *v = *s * *s;
        }
    }
    p0
}

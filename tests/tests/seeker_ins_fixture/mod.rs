//! What the seeker INS's property and envelope tests share: the start point (37° N, 127° E,
//! 1000 m), the paper's P0, the regular IMU clock and LOS samples at the filter's time.

use nalgebra::SMatrix;
use nav_core::contract::Estimator;
use nav_core::seeker_ins::{
    paper_initial_covariance, GimbalAngles, ImuIncrement, LosSample, Position, SeekerIns,
};
use nav_core::time::Timestamp;
use nav_core::Real;

pub const LAT0: f64 = 0.645_771_823_237_901_2; // 37°
pub const LON0: f64 = 2.216_568_150_032_737; // 127°

/// The start: 37° N, 127° E, 1000 m.
pub fn start() -> Position {
    Position {
        lat_rad: LAT0,
        lon_rad: LON0,
        alt_m: 1000.0,
    }
}

/// The paper's initial covariance (Table 4, diagonal).
pub fn p0<T: Real>() -> SMatrix<T, 17, 17> {
    paper_initial_covariance()
}

/// `inc` stamped one nominal IMU interval after the filter's last sample (the first sample at
/// one interval after the epoch): a regular-rate IMU clock.
pub fn stamped<T: Real>(f: &SeekerIns<T>, mut inc: ImuIncrement<T>) -> ImuIncrement<T> {
    let dt_us = f.ins().dt_us();
    inc.time = f
        .time()
        .map_or(Timestamp::from_micros(dt_us), |t| t.add_micros(dt_us));
    inc
}

/// A LOS sample of `gimbal` at the filter's time (its last IMU sample).
pub fn at_ins_time<T: Real>(f: &SeekerIns<T>, gimbal: GimbalAngles<T>) -> LosSample<T> {
    LosSample {
        time: f.time().unwrap_or_default(),
        gimbal,
    }
}

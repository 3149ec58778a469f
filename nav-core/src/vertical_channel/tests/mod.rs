//! Unit tests of the vertical channel (both float types).

use super::core::{CoreParts, LoopCore, StepValues};
use super::envelope::LoopModel;
use super::modes::{discretise_modes, open_loop};
use super::riccati::{care_residual, char_poly3, is_hurwitz3};
use super::*;
use crate::contract::{Estimator, RecoveryAction, RecoveryPolicy};
use crate::design::DesignValues;
use crate::{FusionOutcome, Gate, NavError, Real, Timestamp};
use nalgebra::{Matrix3, Matrix3x2};

mod nominal;
mod running;
mod stability;

fn ts(seconds: f64) -> Timestamp {
    Timestamp::from_secs_f64(seconds).unwrap()
}

const LAT: f64 = 0.6; // rad

fn classical_config<T: Real>(tau_s: f64, lag_s: f64) -> ClassicalConfig<T> {
    ClassicalConfig {
        imu_dt_s: T::lit(0.01),
        latitude_rad: T::lit(LAT),
        tau_s: T::lit(tau_s),
        baro_lag_s: T::lit(lag_s),
        baro_period_s: T::lit(0.04),
        baro_timeouts: AidTimeouts {
            stale_after_s: T::lit(0.1),
            lost_after_s: T::lit(1.0),
        },
        ..ClassicalConfig::paper()
    }
}

fn aided_config<T: Real>() -> AidedConfig<T> {
    AidedConfig {
        latitude_rad: T::lit(LAT),
        baro_timeouts: AidTimeouts {
            stale_after_s: T::lit(0.1),
            lost_after_s: T::lit(1.0),
        },
        velocity_timeouts: AidTimeouts {
            stale_after_s: T::lit(0.25),
            lost_after_s: T::lit(1.0),
        },
        ..AidedConfig::paper()
    }
}

fn c_grav() -> f64 {
    GravityModel::at_latitude(LAT).unwrap().c_per_s2()
}

fn init<T: Real>(h: f64) -> InitialState<T> {
    InitialState {
        time: Timestamp::ZERO,
        altitude_m: T::lit(h),
        vz_up_m_s: T::zero(),
        accel_bias_m_s2: T::zero(),
    }
}

mod contract;
mod sigma;

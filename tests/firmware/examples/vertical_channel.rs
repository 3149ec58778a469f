//! A vertical-channel flight loop on Cortex-M4F/M7 (`f32`): the velocity-aided loop built from
//! a design computed on the ground and stored in flash (`Estimator::from_design`, no design
//! code linked), fed time-stamped IMU, baro and vertical-velocity samples at their own rates,
//! its reports, health and counters read every step, and `reinitialise` as the way back.
//!
//! Build: `cargo build --release --example vertical_channel` in `tests/firmware` (part of
//! `cargo xtask thumb`); run on QEMU: `qemu-system-arm -M mps2-an386 -nographic
//! -semihosting-config enable=on,target=native -kernel
//! target/thumbv7em-none-eabihf/release/examples/vertical_channel | defmt-print -e …`.
//! The stored design is the one `nav-sim golden` writes (`vc_aided.design.f64`, the papers'
//! configuration, little-endian `f64`), copied into the image by `build.rs`.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use nav_core::design::DesignValues;
use nav_core::vertical_channel::{
    Aid, AidedConfig, AidedDesign, AidedLoop, BaroSample, ImuSample, InitialState, VelocitySample,
};
use nav_core::{Estimator, FusionOutcome, Gate, HealthState, NavError, Timestamp};
use nav_firmware::harness;

/// The aided loop's design for [`AidedConfig::paper`], computed on the ground.
static STORED_DESIGN: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/vc_aided.design.f64"));

/// IMU interval, µs (100 Hz).
const IMU_DT_US: u64 = 10_000;
/// IMU samples of the flight (120 s).
const STEPS: u64 = 12_000;

/// Reads the stored design (exactly `AidedDesign::COUNT` little-endian `f64`).
fn stored_design() -> Result<AidedDesign<f32>, NavError> {
    let mut values = [0.0_f64; AidedDesign::<f32>::COUNT];
    if STORED_DESIGN.len() != 8 * values.len() {
        return Err(NavError::CapacityExceeded);
    }
    for (v, bytes) in values.iter_mut().zip(STORED_DESIGN.chunks_exact(8)) {
        let mut b = [0_u8; 8];
        for (d, s) in b.iter_mut().zip(bytes) {
            *d = *s;
        }
        *v = f64::from_le_bytes(b);
    }
    AidedDesign::read_values(&values)
}

/// 120 s at rest at 500 m (the loop starts 20 m off): IMU at 100 Hz, baro at 25 Hz, velocity aid at 10 Hz with a 5 s
/// dropout; then a re-initialisation at a new altitude.
fn flight() -> Result<(), NavError> {
    let config = AidedConfig::<f32>::paper();
    let design = stored_design()?;
    let init = InitialState {
        time: Timestamp::ZERO,
        altitude_m: 520.0_f32,
        vz_up_m_s: 0.0,
        accel_bias_m_s2: 0.0,
    };
    let mut lp = AidedLoop::from_design(&config, &design, &init)?;
    lp.set_gate(Gate::Nis(10.83))?;
    let g = design.gravity().gravity_m_s2(500.0);
    for k in 1..=STEPS {
        let time = Timestamp::from_micros(k * IMU_DT_US);
        let imu = ImuSample {
            time,
            specific_force_up_m_s2: g,
        };
        let baro = (k % 4 == 0).then_some(BaroSample {
            time,
            altitude_m: 500.0,
        });
        let dropout = (1_000..1_500).contains(&k);
        let vel = (k % 10 == 0 && !dropout).then_some(VelocitySample {
            time,
            vz_up_m_s: 0.0,
        });
        let report = lp.step(&imu, baro.as_ref(), vel.as_ref())?;
        if let Some(s) = report.baro.sample {
            if s.outcome == FusionOutcome::Rejected {
                defmt::println!(
                    "t {} ms: baro rejected, test ratio {}",
                    k * 10,
                    s.test_ratio
                );
            }
        }
        if k % 2_000 == 0 {
            defmt::println!(
                "t {} s: h {} m, vz {} m/s, {}, velocity {}",
                k / 100,
                lp.altitude_m(),
                lp.vz_up_m_s(),
                lp.health().state,
                report.velocity.status
            );
        }
    }
    defmt::println!("baro {}", lp.aid_counters(Aid::Baro));
    defmt::println!("velocity {}", lp.aid_counters(Aid::Velocity));
    let converged = (lp.altitude_m() - 500.0).abs() < 1.0;
    // The way back from `NeedsReinitialisation` (here: on demand, with an external altitude).
    lp.reinitialise(&InitialState {
        time: Timestamp::from_micros(STEPS * IMU_DT_US),
        altitude_m: 800.0,
        ..init
    })?;
    defmt::println!("after reinitialise: {}", lp.health());
    if converged && lp.health().state == HealthState::Initialising {
        Ok(())
    } else {
        Err(NavError::NotConverged { iterations: 0 })
    }
}

#[entry]
fn main() -> ! {
    let result = flight();
    match result {
        Ok(()) => defmt::println!("vertical channel example: ok"),
        Err(e) => defmt::println!("vertical channel example: {}", e),
    }
    harness::exit(result.is_ok())
}

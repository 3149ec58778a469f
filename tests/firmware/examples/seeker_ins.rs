//! A flight program for the seeker-aided INS on a Cortex-M4F, as a firmware engineer writes
//! it: the filter built from a stored design, fed time-stamped IMU samples at 100 Hz and
//! seeker samples at 10 Hz, its reports and health read every cycle, and `reinitialise` as
//! the way back. Runs on QEMU (`qemu-system-arm -M mps2-an386 -semihosting …`); `cargo xtask
//! thumb` builds it.
//!
//! The IMU and seeker drivers are stand-ins (level flight east at 200 m/s over a landmark 70 km
//! ahead); a real image reads its sensors and stores the design values in flash.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use nalgebra::{Quaternion, Vector3};
use nav_core::contract::{Estimator, FusionOutcome};
use nav_core::design::DesignValues;
use nav_core::seeker_ins::{
    gimbal_angles_of, landmark_vector_ned, paper_initial_covariance, ImuIncrement, InsState,
    Landmark, LosSample, Position, SeekerAid, SeekerIns, SeekerInsConfig, SeekerInsDesign,
    SeekerInsInitial, PAPER_IMU_DT_US,
};
use nav_core::time::Timestamp;
use nav_core::{HealthState, NavError};
use nav_firmware::harness;

/// Start: 37° N, 127° E, 1000 m.
const START: Position = Position {
    lat_rad: 0.645_771_823_237_901_2,
    lon_rad: 2.216_568_150_032_737,
    alt_m: 1000.0,
};

/// The landmark: 70 km east, 2 km north, on the ground.
const LANDMARK: Position = Position {
    lat_rad: 0.645_771_823_237_901_2 + 2000.0 / 6_356_000.0,
    lon_rad: 2.216_568_150_032_737 + 70_000.0 / (6_386_000.0 * 0.798_635_510_047_292_9),
    alt_m: 0.0,
};

/// Seeker samples every this many IMU samples (10 Hz).
const LOS_EVERY: u64 = 10;

fn initial() -> SeekerInsInitial<f32> {
    let h = core::f32::consts::FRAC_1_SQRT_2;
    SeekerInsInitial {
        state: InsState {
            position: START,
            vel_ned_m_s: Vector3::new(0.0, 200.0, 0.0),
            // Heading east (yaw 90°), level.
            q_b_n: Quaternion::new(h, 0.0, 0.0, h),
        },
        covariance: paper_initial_covariance(),
    }
}

/// The IMU driver's sample `k` (stamped at the end of its interval): level flight.
fn imu_sample(k: u64) -> ImuIncrement<f32> {
    ImuIncrement {
        time: Timestamp::from_micros(k * PAPER_IMU_DT_US),
        delta_theta_rad: Vector3::new(1.0e-7, 4.4e-7, -3.5e-7),
        delta_v_m_s: Vector3::new(0.0, 0.0, -0.098),
    }
}

fn fly() -> Result<(), NavError> {
    let config = SeekerInsConfig::<f32>::paper(Landmark::new(LANDMARK)?);
    // Ground: the design, stored with its stamp (here into RAM; on a real board, flash).
    let mut stored = [0.0_f64; SeekerInsDesign::<f32>::COUNT];
    SeekerIns::design(&config)?.write_values(&mut stored)?;
    // Board: load the design and build the filter; no design code needed.
    let design = SeekerInsDesign::<f32>::read_values(&stored)?;
    let mut ins = SeekerIns::from_design(&config, &design, &initial())?;
    let mut refused = 0u32;
    for k in 1..=3000u64 {
        let sample = imu_sample(k);
        // A refused sample changes nothing: count it and go on.
        refused += u32::from(ins.propagate(&sample).is_err());
        if k % LOS_EVERY == 0 {
            let s = ins.state();
            let d = landmark_vector_ned(&s.position, &config.landmark);
            let c = nalgebra::UnitQuaternion::from_quaternion(s.q_b_n);
            let gimbal = gimbal_angles_of(&(c.inverse() * d.normalize()));
            match ins.update_los(&LosSample {
                time: sample.time,
                gimbal,
            }) {
                Ok(r) if r.pitch.outcome == FusionOutcome::Rejected => {
                    defmt::println!("LOS rejected: test ratio {=f32}", r.pitch.test_ratio)
                }
                Ok(_) => {}
                Err(_) => refused += 1,
            }
        }
        let health = ins.health();
        if health.state == HealthState::NeedsReinitialisation {
            // The way back: a new initial state (here: the start; a real program re-aligns).
            ins.reinitialise(&initial())?;
        }
        if k % 1000 == 0 {
            let los = ins.aid_counters(SeekerAid::Los);
            defmt::println!(
                "t={=u64} ms health={=u8} fused={=u32} rejected={=u32} gaps={=u32} refused={=u32}",
                k * PAPER_IMU_DT_US / 1000,
                health.state as u8,
                los.fused,
                los.rejected,
                health.gaps_bridged,
                refused
            );
        }
    }
    Ok(())
}

#[entry]
fn main() -> ! {
    let result = fly();
    if let Err(e) = result {
        defmt::println!("seeker INS example: {}", e);
    }
    harness::exit(result.is_ok())
}

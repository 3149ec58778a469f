//! A flight program's navigator on a Cortex-M4F: the whole chain in one value
//! (`FlightNavigator<f32, 32>`), ticked at 100 Hz with the missile IMU and the aids that arrived
//! — the aircraft's master INS (every 20 ms, 30 ms late) under the wing, the release signal,
//! the baro after the coast — and its report read every cycle.
//!
//! The drivers are stand-ins (the aircraft at rest, level; the missile drops at 1 s and then
//! reads level flight again); a real image reads its sensors and the bus. The configuration,
//! the place and the master's reported σ are the recorded mission's
//! (`nav_golden::mission::mission_config`, `nav_golden::seeker_start`, `MASTER_SIGMA`): the
//! navigator the mission image replays bit-identical to the host.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask thumb` (with `panic-never`: it links only
//! if no panic is reachable); run it on QEMU with
//! `qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native
//! -kernel <elf> | defmt-print -e <elf>`.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use nalgebra::{Matrix3, Quaternion, SMatrix, Vector3};
use nav_core::navigator::{
    AidState, Aids, FlightNavigator, ImuTick, MasterNav, NavigatorInitial, Phase,
};
use nav_core::seeker_ins::{ClipFlags, ImuIncrement, InsState, Position};
use nav_core::vertical_channel::BaroSample;
use nav_core::{NavError, Timestamp};
use nav_firmware::harness;
use nav_golden::mission::{mission_config, MASTER_SIGMA, MISSION_DT_US as DT_US};
use nav_golden::seeker_start;

/// Master data latency, IMU ticks (30 ms).
const LATENCY: u64 = 3;
/// Release at this tick (1 s); the missile reads 0 g for 0.3 s after it.
const RELEASE_TICK: u64 = 100;
const DROP_TICKS: u64 = 30;
/// Gravity the stand-in IMU reads at rest, m/s².
const G: f32 = 9.80;

/// The bus's master sample with time of validity `time` (the aircraft at rest, level, at
/// `here`).
fn master_at(time: Timestamp, here: Position) -> MasterNav<f32> {
    let (attitude_sigma_rad, velocity_sigma_m_s, position_sigma_m) = MASTER_SIGMA;
    MasterNav {
        time,
        c_m_n: Matrix3::identity(),
        vel_ned_m_s: Vector3::zeros(),
        position: here,
        angular_rate_rad_s: Vector3::zeros(),
        angular_accel_rad_s2: Vector3::zeros(),
        specific_force_m_s2: Vector3::new(0.0, 0.0, -G),
        attitude_sigma_rad: Vector3::new(
            attitude_sigma_rad,
            attitude_sigma_rad,
            4.0 * attitude_sigma_rad,
        ),
        velocity_sigma_m_s: Vector3::from_element(velocity_sigma_m_s),
        position_sigma_m: Vector3::from_element(position_sigma_m),
    }
}

fn run() -> Result<(), NavError> {
    let here = seeker_start();
    let initial = NavigatorInitial {
        time: Timestamp::ZERO,
        state: InsState {
            position: here,
            vel_ned_m_s: Vector3::zeros(),
            q_b_n: Quaternion::identity(),
        },
        nav_covariance: SMatrix::from_diagonal_element(1.0),
    };
    let mut nav = FlightNavigator::<f32, 32>::new(&mission_config()?, &initial)?;
    let mut refused = 0u32;
    for k in 1..=400u64 {
        let time = Timestamp::from_micros(k * DT_US);
        let in_drop = (RELEASE_TICK..RELEASE_TICK + DROP_TICKS).contains(&k);
        let fz = if in_drop { 0.0 } else { -G };
        let imu = ImuTick {
            increment: ImuIncrement {
                time,
                delta_theta_rad: Vector3::zeros(),
                delta_v_m_s: Vector3::new(0.0, 0.0, fz * 0.01),
            },
            clipped: ClipFlags::default(),
        };
        let master = (k % 2 == 0 && k > LATENCY && k < RELEASE_TICK)
            .then(|| master_at(Timestamp::from_micros((k - LATENCY) * DT_US), here));
        let baro = (k % 4 == 0).then_some(BaroSample {
            time,
            altitude_m: 1000.0,
        });
        let aids = Aids {
            master: master.as_ref(),
            baro: baro.as_ref(),
            seeker: None,
            separation: (k == RELEASE_TICK).then_some(time),
        };
        match nav.tick(&imu, &aids) {
            Ok(r) => {
                refused += u32::from(matches!(r.master.state, AidState::Refused(_)));
                refused += u32::from(matches!(r.baro.state, AidState::Refused(_)));
                if let Some(t) = r.transition {
                    defmt::println!(
                        "t={=u64} ms: phase {=u8} -> {=u8}",
                        k * DT_US / 1000,
                        t.from as u8,
                        t.to as u8
                    );
                }
                if k % 100 == 0 {
                    let p = &r.solution.nav_covariance;
                    defmt::println!(
                        "t={=u64} ms phase={=u8} health={=u8} σN={=f32} m σD={=f32} m baro fused={=u32} refused={=u32}",
                        k * DT_US / 1000,
                        r.phase as u8,
                        r.health as u8,
                        libm::sqrtf(p[(0, 0)]),
                        libm::sqrtf(p[(2, 2)]),
                        r.baro.counters.fused,
                        refused
                    );
                }
            }
            // A refused IMU sample changes nothing: count it and go on.
            Err(_) => refused += 1,
        }
    }
    if nav.phase() == Phase::Midcourse {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input: "phase" })
    }
}

#[entry]
fn main() -> ! {
    let ok = run().is_ok();
    defmt::println!("navigator example ok={=bool}", ok);
    harness::exit(ok)
}

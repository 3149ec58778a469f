//! A flight program's transfer alignment on a Cortex-M4F: the proposed 12-state filter built
//! from a design computed on the ground and stored in flash, stepped at 100 Hz with
//! time-stamped master/slave pairs, late master data matched through a slave history, a
//! master-data dropout bridged by `propagate`, reports and health read every cycle, and
//! `reinitialise` as the way back.
//!
//! Built for `thumbv7em-none-eabihf` by `cargo xtask thumb` (with `panic-never`: it links only
//! if no panic is reachable); run it on QEMU with
//! `qemu-system-arm -M mps2-an386 -nographic -semihosting-config enable=on,target=native
//! -kernel <elf> | defmt-print -e <elf>`.
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use nalgebra::Vector3;
use nav_core::design::DesignValues;
use nav_core::transfer_alignment::{
    Channel, MasterSample, ProposedFilter, SlaveHistory, SlaveSample, TaConfig, TaDesign,
    TaInitial,
};
use nav_core::{Estimator, FusionOutcome, HealthState, NavError, Timestamp};
use nav_firmware::harness;

/// The design the ground computed for this configuration (`nav-sim golden` records it from
/// the golden vectors' configuration; empty when not recorded).
static STORED_DESIGN: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/ta12.design.f64"));

/// Filter step, µs (100 Hz).
const DT_US: u64 = 10_000;
/// Master data latency, epochs (the data link delivers the master sample 30 ms late).
const LATENCY: u64 = 3;

/// The configuration the stored design was computed for: the golden vectors'
/// ([`nav_golden::ta_config`], the paper's case 2 with their rate-difference noise).
fn config() -> TaConfig<f32> {
    nav_golden::ta_config()
}

/// The stored design, or (if the image was built without one) the design computed on board.
fn design(cfg: &TaConfig<f32>) -> Result<TaDesign<f32, 4>, NavError> {
    let mut values = [0.0_f64; TaDesign::<f32, 4>::COUNT];
    let mut n = 0;
    for (v, b) in values.iter_mut().zip(STORED_DESIGN.chunks_exact(8)) {
        let mut bytes = [0u8; 8];
        bytes.copy_from_slice(b);
        *v = f64::from_le_bytes(bytes);
        n += 1;
    }
    if n == values.len() && STORED_DESIGN.len() == 8 * n {
        TaDesign::read_values(&values)
    } else {
        defmt::println!("no stored design: computing it on board");
        ProposedFilter::<f32>::design(cfg)
    }
}

/// The aircraft: a 1 g push along X for a second after a second of cruise, a slow turn; the
/// slave sees a fixed misalignment (rad).
fn samples(k: u64) -> (MasterSample<f32>, SlaveSample<f32>) {
    let time = Timestamp::from_micros(DT_US * k);
    let accel_x = if (100..200).contains(&k) { 9.81 } else { 0.0 };
    let w = Vector3::new(0.0_f32, 0.0, 0.02);
    let f = Vector3::new(accel_x, 0.0, -9.81);
    let theta = Vector3::new(0.004_f32, -0.003, 0.006);
    (
        MasterSample {
            time,
            angular_rate_rad_s: w,
            angular_accel_rad_s2: Vector3::zeros(),
            specific_force_m_s2: f,
        },
        SlaveSample {
            time,
            angular_rate_rad_s: w - theta.cross(&w),
            specific_force_m_s2: f - theta.cross(&f),
        },
    )
}

fn run() -> Result<(), NavError> {
    let cfg = config();
    let mut ta = ProposedFilter::from_design(&cfg, &design(&cfg)?, &TaInitial::default())?;
    let mut history = SlaveHistory::<f32, 8>::new();
    let mut refused = 0u32;
    let mut rejected = 0u32;
    for k in 0..1_000u64 {
        let (_, slave) = samples(k);
        // Every slave epoch goes into the history; the master sample of epoch k − LATENCY
        // arrives now, except during a 0.5 s data-link dropout.
        refused += u32::from(history.push(&slave).is_err());
        let Some(j) = k.checked_sub(LATENCY) else {
            continue;
        };
        let (master, _) = samples(j);
        if (600..650).contains(&j) {
            refused += u32::from(ta.propagate(master.time).is_err());
            continue;
        }
        match ta.step_delayed(&master, &history) {
            Ok(report) => {
                let force_x = report.update(Channel::ForceX).map(|u| u.outcome);
                rejected += u32::from(force_x == Some(FusionOutcome::Rejected));
            }
            // A refused pair changes nothing: count it and go on.
            Err(_) => refused += 1,
        }
        if ta.health().state == HealthState::NeedsReinitialisation {
            ta.reinitialise(&TaInitial::default())?;
        }
    }
    let theta = ta.theta();
    let sigma = ta.theta_sigma_rad();
    let health = ta.health();
    defmt::println!(
        "TA theta=[{=f32} {=f32} {=f32}] rad sigma=[{=f32} {=f32} {=f32}] rad",
        theta.x,
        theta.y,
        theta.z,
        sigma.x,
        sigma.y,
        sigma.z
    );
    defmt::println!(
        "TA state={} refused={=u32} rejected(df_X)={=u32} reinitialisations={=u32}",
        health.state,
        refused,
        rejected,
        health.reinitialisations
    );
    // A new coarse alignment keeps the estimate as its prior.
    ta.reinitialise(&TaInitial {
        mount_misalignment_rad: ta.theta_m(),
    })?;
    if (theta - Vector3::new(0.004, -0.003, 0.006)).norm() < 1.0e-3 && refused == 0 {
        Ok(())
    } else {
        Err(NavError::InputOutOfRange { input: "theta" })
    }
}

#[entry]
fn main() -> ! {
    let ok = run().is_ok();
    defmt::println!("TA example ok={=bool}", ok);
    harness::exit(ok)
}

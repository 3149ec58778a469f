//! The mission image: the flight navigator (`FlightNavigator<f32, 16>`) built from the design
//! computed on the host and stored in the image (`from_design`: no design code, no paper
//! filters), ticked at 100 Hz through the recorded mission (carry under a manoeuvring aircraft
//! with a late master, separation, coast, baro midcourse, terminal LOS), every tick's output
//! compared bit for bit with the host's f32 run, and every tick's instructions and peak stack
//! measured. Logs `GOLDEN mission …` and per tick class
//! `BENCH nav_tick_<class> insns=<worst> stack=<worst> ticks=<n> at=<tick of the worst>`.
//!
//! The recorded inputs stand in for the sensors and the bus; the replay loop, the comparison
//! and the counter reads (`nav_firmware::harness`) are the only harness (`cargo xtask bench`
//! reports the `.text`).
#![no_std]
#![no_main]

use cortex_m_rt::entry;
use nav_core::navigator::{Aids, ImuTick, Phase, TickReport};
use nav_core::NavError;
use nav_firmware::harness::{self, golden::Golden, measure};
use nav_golden::f32s;
use nav_golden::mission::{
    mission_navigator, mission_output, MissionNavigator, MissionTick, MISSION_INPUT_LEN,
    MISSION_OUTPUT_LEN,
};

static INPUTS: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/mission.in.f32"));
static OUTPUTS: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/mission.out.f32"));
static DESIGN: &[u8] = include_bytes!(concat!(env!("OUT_DIR"), "/mission.design.f64"));

/// Tick classes: the phase at the start of the tick and what arrived.
const CLASSES: [&str; 10] = [
    "nav_tick_carry",
    "nav_tick_carry_master",
    "nav_tick_separation",
    "nav_tick_released",
    "nav_tick_midcourse",
    "nav_tick_midcourse_baro",
    "nav_tick_terminal",
    "nav_tick_terminal_los",
    "nav_tick_terminal_los_baro",
    "nav_tick_terminal_held_baro",
];

/// The class of a tick (index into [`CLASSES`]). A LOS sample in midcourse is the terminal
/// phase's first (it fuses and switches); after release every LOS tick also runs the
/// covariance prediction (the pending steps are flushed before the update). A baro sample
/// on a LOS tick is held and fused on the next tick (`held`: a sample held before the tick).
fn class(before: Phase, held: bool, t: &MissionTick, report: Option<&TickReport<f32>>) -> usize {
    match before {
        Phase::Carry if report.is_some_and(|r| r.phase != Phase::Carry) => 2,
        Phase::Carry if t.master.is_some() => 1,
        Phase::Carry => 0,
        Phase::Released => 3,
        Phase::Midcourse | Phase::Terminal if t.los.is_some() && t.baro.is_some() => 8,
        Phase::Midcourse | Phase::Terminal if t.los.is_some() => 7,
        Phase::Midcourse | Phase::Terminal if held => 9,
        Phase::Midcourse if t.baro.is_some() => 5,
        Phase::Midcourse => 4,
        Phase::Terminal => 6,
    }
}

/// `NAV_MISSION_PROFILE_TICK=<tick>` at build time: the mission without measurements, the
/// chosen tick (1-based) between two calls of [`profile_marker`] (for a `qemu -d exec` trace).
const PROFILE_TICK: Option<&str> = option_env!("NAV_MISSION_PROFILE_TICK");

#[inline(never)]
fn profile_marker(n: u32) {
    core::hint::black_box(n);
}

/// Bytes painted below the stack pointer before each tick (RAM is 4 MiB).
const PAINT_BYTES: usize = 96 * 1024;

#[derive(Clone, Copy, Default)]
struct Worst {
    insns: u32,
    stack: u32,
    ticks: u32,
    at: u32,
}

/// The navigator's tick as the flight program calls it: one out-of-line call writing the
/// report into the loop's slot (called from one place, the optimiser would otherwise inline it
/// into the measuring closure, and the counts would drop the call).
#[inline(never)]
fn tick(
    nav: &mut MissionNavigator,
    imu: &ImuTick<f32>,
    aids: &Aids<'_, f32>,
    report: &mut TickReport<f32>,
) -> Result<(), NavError> {
    nav.tick_into(imu, aids, report)
}

fn run() -> Result<bool, NavError> {
    let mut nav = mission_navigator(core::hint::black_box(DESIGN))?;
    let mut report = nav.blank_report();
    let mut worst = [Worst::default(); CLASSES.len()];
    let mut rec = [0f32; MISSION_INPUT_LEN];
    let mut out = [0f32; MISSION_OUTPUT_LEN];
    let mut golden = Golden::new(OUTPUTS);
    let mut ticks = 0usize;
    for (k, bytes) in INPUTS.chunks_exact(4 * MISSION_INPUT_LEN).enumerate() {
        for (d, v) in rec.iter_mut().zip(f32s(bytes)) {
            *d = v;
        }
        let t = MissionTick::decode(k, &rec);
        let aids = t.aids();
        let before = nav.phase();
        let held = nav.held_baro().is_some();
        if let Some(at) = PROFILE_TICK {
            // Profiling build: no measurement; the chosen tick between two markers.
            let chosen = at.parse::<usize>().is_ok_and(|a| a == k + 1);
            if chosen {
                profile_marker(1);
            }
            nav.tick_into(&t.imu, &aids, &mut report)?;
            if chosen {
                profile_marker(2);
            }
            mission_output(&nav, &report, &mut out);
            ticks += 1;
            continue;
        }
        // One tick, counted inside the painted stack (no second run on a copy of the
        // navigator for the stack: its clone was 11 kB of harness code in the image); the
        // report slot is the flight loop's own (outside the measured frames).
        let mut result = None;
        let (insns, stack) = measure::instructions_and_stack(
            || result = Some(tick(&mut nav, &t.imu, &aids, &mut report)),
            PAINT_BYTES,
        );
        match result {
            Some(r) => r?,
            None => return Err(NavError::InputOutOfRange { input: "tick" }),
        };
        if let Some(w) = worst.get_mut(class(before, held, &t, Some(&report))) {
            w.ticks += 1;
            if insns > w.insns {
                w.insns = insns;
                w.at = k as u32 + 1;
            }
            w.stack = w.stack.max(stack);
        }
        mission_output(&nav, &report, &mut out);
        golden.compare(&out);
        ticks += 1;
    }
    let verdict = golden.finish();
    verdict.log("mission", ticks);
    for (name, w) in CLASSES.iter().zip(worst.iter()) {
        defmt::println!(
            "BENCH {=str} insns={=u32} stack={=u32} ticks={=u32} at={=u32}",
            name,
            w.insns,
            w.stack,
            w.ticks,
            w.at
        );
    }
    Ok(ticks > 0 && verdict.ok())
}

#[entry]
fn main() -> ! {
    defmt::println!("nav-mission start");
    let ok = match run() {
        Ok(ok) => ok,
        Err(e) => {
            defmt::println!("GOLDEN mission error {}", e);
            false
        }
    };
    defmt::println!("DONE ok={=bool}", ok);
    harness::exit(ok)
}

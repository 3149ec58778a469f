//! nav-core on emulated Cortex-M4F / M7: per-kernel instruction counts and peak stack.
//!
//! Results are logged with defmt over semihosting as
//! `BENCH <kernel> insns=<n> stack=<bytes>` and decoded on the host by `cargo xtask bench`.
//! Counter, stack painting, golden comparison, logger and handlers: `nav_firmware::harness`.
#![no_std]
#![no_main]

mod golden;
mod kernels;

use cortex_m_rt::entry;
use nav_firmware::harness::{self, measure};

#[entry]
fn main() -> ! {
    defmt::println!("nav-firmware start");
    let mut failures = 0u32;
    // NAV_PROFILE_KERNEL=<name> at build time: run only that kernel, once, without the golden
    // replay and the stack measurement (a short, clean trace for `qemu -d exec` profiling).
    let only = option_env!("NAV_PROFILE_KERNEL");
    let golden_failures = if only.is_some() {
        0
    } else {
        golden::check_all()
    };
    for k in kernels::KERNELS
        .iter()
        .filter(|k| only.is_none_or(|name| name == k.name))
    {
        let mut run = || (k.run)();
        (k.setup)();
        let insns = measure::instructions(&mut run);
        let stack = if only.is_some() {
            0
        } else {
            (k.setup)();
            measure::stack_bytes(&mut run)
        };
        if !(k.check)() {
            defmt::println!("CHECK FAILED {=str}", k.name);
            failures += 1;
        }
        defmt::println!(
            "BENCH {=str} insns={=u32} stack={=u32}",
            k.name,
            insns,
            stack
        );
    }
    if golden_failures != 0 {
        defmt::println!("GOLDEN FAILED cases={=u32}", golden_failures);
    }
    let ok = failures == 0 && golden_failures == 0;
    if ok {
        defmt::println!("DONE ok");
    } else {
        defmt::println!("DONE failures={=u32}", failures + golden_failures);
    }
    harness::exit(ok)
}

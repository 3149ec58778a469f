//! nav-core on emulated Cortex-M4F / M7: per-kernel instruction counts and peak stack.
//!
//! Results are logged with defmt over semihosting as
//! `BENCH <kernel> insns=<n> stack=<bytes>` and decoded on the host by `cargo xtask bench`.
#![no_std]
#![no_main]

mod golden;
mod kernels;
mod logger;
mod measure;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;

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
    if failures == 0 && golden_failures == 0 {
        defmt::println!("DONE ok");
        debug::exit(debug::EXIT_SUCCESS);
    } else {
        defmt::println!("DONE failures={=u32}", failures + golden_failures);
        debug::exit(debug::EXIT_FAILURE);
    }
    #[allow(clippy::empty_loop)]
    loop {}
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[cfg(not(feature = "panic-never"))]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    defmt::println!("PANIC");
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

/// The panic-never technique: this handler refers to a symbol nobody defines, so the image only
/// links if the optimiser proved every panic in the code it contains unreachable.
#[cfg(feature = "panic-never")]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    extern "Rust" {
        fn nav_core_contains_a_reachable_panic() -> !;
    }
    // SAFETY: never executed; the link fails if this call survives optimisation.
    unsafe { nav_core_contains_a_reachable_panic() }
}

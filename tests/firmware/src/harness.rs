//! Everything an image runs besides nav-core and its own flight loop, in one place.
//!
//! | piece | what it gives | how |
//! | --- | --- | --- |
//! | [`logger`] | the defmt global logger: `defmt::println!` lines reach the host | defmt frames written to the semihosting stdout (decoded by `defmt-print -e <elf>`); a nested use is dropped and counted in [`logger::DROPPED`] instead of panicking, so images link with `panic-never` |
//! | [`exit`] | the run's verdict as QEMU's exit code (0 ok, 1 failure) | semihosting `SYS_EXIT` (`-semihosting-config enable=on,target=native`) |
//! | `HardFault` handler | a fault ends the run with exit code 1 instead of hanging QEMU | `cortex-m-rt` exception handler calling [`exit`] |
//! | panic handler | without the `panic-never` feature: logs `PANIC` and exits 1; with it: the handler calls a symbol nobody defines, so an image links only if the optimiser proved every panic unreachable | `#[panic_handler]` |
//! | [`measure::instructions`] | instructions a call executes, exact and repeatable (not cycles: QEMU does not model the pipeline; M4F and M7 boards count the same for one binary) | the MPS2 FPGAIO 32-bit counter (`0x4002_8018`, 25 MHz of virtual time) read before and after the call under `-icount shift=10,sleep=off` (one instruction = 25.6 ticks); the reading of an empty call through the same path is subtracted |
//! | [`measure::stack_bytes`], [`measure::stack_bytes_within`] | peak stack of a call, bytes (including the few words of the call into it) | paints a region below the stack pointer with a pattern, runs the call, finds the lowest word it changed; a result equal to the painted size means the region was exhausted |
//! | [`golden::Golden`] | a run's outputs compared with the host's recording: values, bit mismatches, the largest distance in units in the last place, values missing or extra | each output against the next recorded little-endian `f32` ([`nav_golden::ulps`]); logs `GOLDEN <label> steps=… values=… mismatched=… max_ulps=… missing=…` for `cargo xtask qemu` / `bench` |
//!
//! Painting the stack costs instructions: an image measures the stack on one run (or on a copy
//! of the filter) and counts instructions on another.

use cortex_m_rt::{exception, ExceptionFrame};
use cortex_m_semihosting::debug;

pub mod golden;
pub mod logger;
pub mod measure;

/// Ends the run: QEMU exits with code 0 when `success`, 1 otherwise.
pub fn exit(success: bool) -> ! {
    debug::exit(if success {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
    #[allow(clippy::empty_loop)]
    loop {}
}

#[exception]
unsafe fn HardFault(_frame: &ExceptionFrame) -> ! {
    exit(false)
}

#[cfg(not(feature = "panic-never"))]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    defmt::println!("PANIC");
    exit(false)
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

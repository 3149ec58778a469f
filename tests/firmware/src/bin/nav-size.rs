//! The size image: every filter's constructor and step path (through the golden-vector replay
//! driver, fed an opaque empty input so nothing is optimised away), no bench harness and no
//! recorded vectors. `cargo xtask bench` reports its `.text` as the cost in flash of the
//! filters.
#![no_std]
#![no_main]

#[path = "../logger.rs"]
mod logger;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;

#[entry]
fn main() -> ! {
    let inputs: &[u8] = core::hint::black_box(&[]);
    let mut values = 0usize;
    let mut failed = 0u32;
    for case in nav_golden::CASES {
        match nav_golden::replay(case, inputs, &mut |_, out| values += out.len()) {
            Ok(steps) => values += steps,
            Err(_) => failed += 1,
        }
    }
    defmt::println!(
        "SIZE image ran: values={=usize} failed={=u32}",
        values,
        failed
    );
    debug::exit(if failed == 0 {
        debug::EXIT_SUCCESS
    } else {
        debug::EXIT_FAILURE
    });
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
    debug::exit(debug::EXIT_FAILURE);
    #[allow(clippy::empty_loop)]
    loop {}
}

#[cfg(feature = "panic-never")]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    extern "Rust" {
        fn nav_core_contains_a_reachable_panic() -> !;
    }
    // SAFETY: never executed; the link fails if this call survives optimisation.
    unsafe { nav_core_contains_a_reachable_panic() }
}

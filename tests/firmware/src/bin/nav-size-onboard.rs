//! The size image with on-board design: as `nav-size`, but every filter computes its design
//! at start-up (`new`: discretisation, Riccati solver and f64 gravity fit linked).
#![no_std]
#![no_main]

#[path = "../logger.rs"]
mod logger;
#[path = "../size_image.rs"]
mod size_image;

use cortex_m_rt::{entry, exception, ExceptionFrame};
use cortex_m_semihosting::debug;

#[entry]
fn main() -> ! {
    size_image::run(&nav_golden::OnBoard)
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

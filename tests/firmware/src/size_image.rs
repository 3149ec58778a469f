//! Shared body of the size images: every filter's constructor and step path (through the
//! golden-vector replay driver, fed an opaque empty input so nothing is optimised away), no
//! bench harness and no recorded vectors. The design source decides whether the design code
//! (discretisation, Riccati solver, f64 gravity fit) is in the image. Also the size images'
//! exception and panic handlers.

use cortex_m_rt::{exception, ExceptionFrame};
use cortex_m_semihosting::debug;
use nav_golden::DesignSource;

pub fn run(designs: &dyn DesignSource) -> ! {
    let inputs: &[u8] = core::hint::black_box(&[]);
    let mut values = 0usize;
    let mut failed = 0u32;
    for case in nav_golden::CASES {
        match nav_golden::replay_with(case, inputs, designs, &mut |_, out| values += out.len()) {
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

/// The panic-never technique (see `main.rs`): the image only links if no panic is reachable.
#[cfg(feature = "panic-never")]
#[panic_handler]
fn panic(_info: &core::panic::PanicInfo) -> ! {
    extern "Rust" {
        fn nav_core_contains_a_reachable_panic() -> !;
    }
    // SAFETY: never executed; the link fails if this call survives optimisation.
    unsafe { nav_core_contains_a_reachable_panic() }
}

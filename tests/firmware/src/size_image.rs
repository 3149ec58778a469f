//! Shared body of the size images: every filter's constructor and step path (through the
//! golden-vector replay driver, fed an opaque empty input so nothing is optimised away), no
//! bench harness and no recorded vectors. The design source decides whether the design code
//! (discretisation, Riccati solver, f64 gravity fit) is in the image.

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

//! The flight size image: every filter built from designs computed on the host and stored in
//! the image (`from_design`: no design code linked) and its step path, no bench harness and no
//! recorded vectors. `cargo xtask bench` reports its `.text` as the cost in flash of the
//! filters; `nav-size-onboard` is the same with the designs computed on board.
#![no_std]
#![no_main]

#[path = "../size_image.rs"]
mod size_image;

use cortex_m_rt::entry;

macro_rules! design_file {
    ($name:literal) => {
        include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".design.f64")).as_slice()
    };
}

#[entry]
fn main() -> ! {
    // The stored designs are opaque to the optimiser (a flash parameter block).
    let designs = nav_golden::Stored {
        ta9: core::hint::black_box(design_file!("ta9")),
        ta12: core::hint::black_box(design_file!("ta12")),
        vc_classical: core::hint::black_box(design_file!("vc_classical")),
        vc_aided: core::hint::black_box(design_file!("vc_aided")),
    };
    size_image::run(&designs)
}

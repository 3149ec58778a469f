//! The size image with on-board design: as `nav-size`, but every filter computes its design
//! at start-up (`new`: discretisation, Riccati solver and f64 gravity fit linked).
#![no_std]
#![no_main]

#[path = "../size_image.rs"]
mod size_image;

use cortex_m_rt::entry;

#[entry]
fn main() -> ! {
    size_image::run(&nav_golden::OnBoard)
}

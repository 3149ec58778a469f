//! Golden-vector replay: the host's recorded inputs through the same `nav_golden` replay
//! code, outputs compared value by value with the host's f32 outputs. Every case with a
//! configuration-time design is replayed twice: with the design computed here, on the target
//! (`OnBoard`: the filters' `new`), and with the design computed on the host and stored in the
//! image (`Stored`: `from_design`, what a flight image without design code runs).

use nav_firmware::harness::golden::Golden;
use nav_golden::{replay_with, Case, DesignSource, OnBoard, Stored, CASES};

macro_rules! golden_files {
    ($name:literal) => {
        (
            &include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".in.f32"))[..],
            &include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".out.f32"))[..],
        )
    };
}

macro_rules! design_file {
    ($name:literal) => {
        include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".design.f64")).as_slice()
    };
}

fn files(case: Case) -> (&'static [u8], &'static [u8]) {
    match case {
        Case::Ta9 => golden_files!("ta9"),
        Case::Ta12 => golden_files!("ta12"),
        Case::VcClassical => golden_files!("vc_classical"),
        Case::VcAided => golden_files!("vc_aided"),
        Case::SeekerIns => golden_files!("seeker_ins"),
    }
}

/// The designs computed on the host (`nav-sim golden`), stored in the image.
pub const STORED: Stored<'static> = Stored {
    ta9: design_file!("ta9"),
    ta12: design_file!("ta12"),
    vc_classical: design_file!("vc_classical"),
    vc_aided: design_file!("vc_aided"),
};

/// Replays one case with one design source; logs
/// `GOLDEN <label> steps=… values=… mismatched=… max_ulps=… missing=…` and returns `true` when
/// every value is bit-identical.
fn check(case: Case, label: &str, designs: &dyn DesignSource) -> bool {
    let (inputs, expected) = files(case);
    if inputs.is_empty() {
        defmt::println!("GOLDEN {=str} skipped (no recording)", label);
        return true;
    }
    let mut golden = Golden::new(expected);
    let result = replay_with(case, inputs, designs, &mut |_, out| golden.compare(out));
    let verdict = golden.finish();
    match result {
        Ok(steps) => verdict.log(label, steps),
        Err(e) => defmt::println!("GOLDEN {=str} error {}", label, e),
    }
    result.is_ok() && verdict.ok()
}

/// Replays every recorded case (on-board designs, then stored designs); returns the number of
/// replays with a mismatch or an error.
pub fn check_all() -> u32 {
    let mut failed = 0;
    for case in CASES {
        if !check(case, case.name(), &OnBoard) {
            failed += 1;
        }
        let stored_label = match case {
            Case::Ta9 => "ta9/stored-design",
            Case::Ta12 => "ta12/stored-design",
            Case::VcClassical => "vc_classical/stored-design",
            Case::VcAided => "vc_aided/stored-design",
            Case::SeekerIns => continue,
        };
        if !check(case, stored_label, &STORED) {
            failed += 1;
        }
    }
    failed
}

//! Golden-vector replay: the host's recorded inputs through the same `nav_golden::replay`
//! code, outputs compared value by value with the host's f32 outputs.

use nav_golden::{f32s, replay, ulps, Case, CASES};

macro_rules! golden_files {
    ($name:literal) => {
        (
            &include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".in.f32"))[..],
            &include_bytes!(concat!(env!("OUT_DIR"), "/", $name, ".out.f32"))[..],
        )
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

/// Replays every recorded case; logs `GOLDEN <case> steps=… values=… mismatched=… max_ulps=…`
/// and returns the number of cases with a mismatch or an error.
pub fn check_all() -> u32 {
    let mut failed = 0;
    for case in CASES {
        let (inputs, expected) = files(case);
        if inputs.is_empty() {
            defmt::println!("GOLDEN {=str} skipped (no recording)", case.name());
            continue;
        }
        let mut want = f32s(expected);
        let (mut values, mut mismatched, mut max_ulps) = (0u32, 0u32, 0u32);
        let result = replay(case, inputs, &mut |_, out| {
            for &got in out {
                let u = ulps(got, want.next().unwrap_or(f32::NAN));
                values += 1;
                if u != 0 {
                    mismatched += 1;
                    max_ulps = max_ulps.max(u);
                }
            }
        });
        let extra = want.count();
        match result {
            Ok(steps) => defmt::println!(
                "GOLDEN {=str} steps={=usize} values={=u32} mismatched={=u32} max_ulps={=u32} missing={=usize}",
                case.name(),
                steps,
                values,
                mismatched,
                max_ulps,
                extra
            ),
            Err(e) => defmt::println!("GOLDEN {=str} error {}", case.name(), e),
        }
        if result.is_err() || mismatched != 0 || extra != 0 {
            failed += 1;
        }
    }
    failed
}

//! The golden comparison: a run's outputs against the host's f32 recording, value by value.

use nav_golden::ulps;

/// Compares outputs, in order, with a recording of little-endian `f32` values.
pub struct Golden<'a> {
    /// The recorded values not compared yet.
    want: &'a [u8],
    values: u32,
    mismatched: u32,
    max_ulps: u32,
}

/// The outcome of a comparison.
#[derive(Clone, Copy, Debug)]
pub struct Verdict {
    /// Values compared.
    pub values: u32,
    /// Values whose bits differ from the recording's.
    pub mismatched: u32,
    /// The largest distance from the recorded value, units in the last place (`u32::MAX`
    /// when one side is NaN, or a value had no recorded counterpart).
    pub max_ulps: u32,
    /// Recorded values the run did not produce.
    pub missing: usize,
}

impl<'a> Golden<'a> {
    /// A comparison with `recording` (little-endian `f32`, the host's outputs in run order).
    pub fn new(recording: &'a [u8]) -> Self {
        Self {
            want: recording,
            values: 0,
            mismatched: 0,
            max_ulps: 0,
        }
    }

    /// Compares the next outputs of the run (not inlined: one copy for every replay loop).
    #[inline(never)]
    pub fn compare(&mut self, outputs: &[f32]) {
        for &got in outputs {
            let want = match self.want.split_first_chunk::<4>() {
                Some((bytes, rest)) => {
                    self.want = rest;
                    f32::from_le_bytes(*bytes)
                }
                None => f32::NAN,
            };
            let u = ulps(got, want);
            self.values += 1;
            if u != 0 {
                self.mismatched += 1;
                self.max_ulps = self.max_ulps.max(u);
            }
        }
    }

    /// The verdict: what was compared and what was left in the recording.
    pub fn finish(self) -> Verdict {
        Verdict {
            values: self.values,
            mismatched: self.mismatched,
            max_ulps: self.max_ulps,
            missing: self.want.len() / 4,
        }
    }
}

impl Verdict {
    /// Every value bit-identical and none missing.
    pub fn ok(&self) -> bool {
        self.mismatched == 0 && self.missing == 0
    }

    /// Logs `GOLDEN <label> steps=… values=… mismatched=… max_ulps=… missing=…`, the line
    /// `cargo xtask qemu` and `bench` read.
    pub fn log(&self, label: &str, steps: usize) {
        defmt::println!(
            "GOLDEN {=str} steps={=usize} values={=u32} mismatched={=u32} max_ulps={=u32} missing={=usize}",
            label,
            steps,
            self.values,
            self.mismatched,
            self.max_ulps,
            self.missing
        );
    }
}

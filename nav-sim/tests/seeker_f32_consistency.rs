//! The flight configuration of the seeker-aided INS is as consistent in f32 (the flight
//! computer's arithmetic) as in f64: on the straight scenario, the same seeded runs flown in
//! both precisions give per-group normalized errors in the consistency target, the same
//! run-averaged NEES and the same final σ. A stabilising noise that acts as process noise in
//! f32 (the σ it reports larger than its error) fails the NEES and σ comparisons.

use nav_sim::consistency::Consistency;
use nav_sim::scenarios::seeker_ins::{
    load_config, monte_carlo_filters, trajectory, Config, Stats, CHANNELS,
};

/// Runs per precision (the same seeded runs in both).
const RUNS: usize = 20;
const SEED: u64 = 5100;
/// Per-group `mean(e²/σ²)` target (the consistency campaign's).
const GROUP_RANGE: (f64, f64) = (0.5, 2.0);
/// Largest relative difference, f32 against f64 on the same runs, of the run-averaged NEES
/// and of the final filter σ of each position channel.
const MAX_REL_DIFF: f64 = 0.1;

fn flight_batch(cfg: &Config, precision: &str) -> Stats {
    let mut cfg = cfg.clone();
    cfg.filter.precision = precision.into();
    let truth = trajectory::generate(&cfg.trajectory, 1.0 / cfg.rates.imu_hz);
    let b = monte_carlo_filters(&cfg, &truth, RUNS, SEED, false, true).unwrap();
    b.flight.unwrap()
}

fn final_sigma(s: &Stats, channel: &str) -> f64 {
    let i = CHANNELS.iter().position(|c| *c == channel).unwrap();
    *s.filter_sigma[i].last().unwrap()
}

fn groups(c: &Consistency) -> String {
    c.normalized_error_sq
        .iter()
        .map(|(g, v)| format!("{g} {v:.3}"))
        .collect::<Vec<_>>()
        .join(", ")
}

#[test]
fn flight_configuration_is_as_consistent_in_f32_as_in_f64() {
    let cfg = load_config("seeker-straight").unwrap();
    let f64_batch = flight_batch(&cfg, "f64");
    let f32_batch = flight_batch(&cfg, "f32");
    let (c32, c64) = (&f32_batch.consistency, &f64_batch.consistency);
    assert_eq!(c32.runs, RUNS);
    assert!(!c32.normalized_error_sq.is_empty());
    for (g, v) in &c32.normalized_error_sq {
        assert!(
            (GROUP_RANGE.0..=GROUP_RANGE.1).contains(v),
            "f32 group {g}: mean e²/σ² {v} (all: {})",
            groups(c32)
        );
    }
    let (n32, n64) = (c32.mean_nees(), c64.mean_nees());
    eprintln!(
        "NEES f32 {n32:.3}, f64 {n64:.3}; f32 groups: {}",
        groups(c32)
    );
    assert!(
        (n32 / n64 - 1.0).abs() <= MAX_REL_DIFF,
        "NEES f32 {n32:.3} vs f64 {n64:.3} (f32 groups: {}; f64: {})",
        groups(c32),
        groups(c64)
    );
    for ch in ["lat_m", "lon_m", "alt_m"] {
        let (s32, s64) = (final_sigma(&f32_batch, ch), final_sigma(&f64_batch, ch));
        eprintln!("final σ {ch}: f32 {s32:.3}, f64 {s64:.3}");
        assert!(
            (s32 / s64 - 1.0).abs() <= MAX_REL_DIFF,
            "final σ {ch}: f32 {s32:.3} vs f64 {s64:.3}"
        );
    }
}

//! Parallel, reproducible Monte Carlo.

use crate::rng::{run_rng, SimRng};
use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle};
use rayon::prelude::*;

/// Runs `runs` independent simulations in parallel (rayon) and returns their results in run
/// order. Run `i` gets [`run_rng`]`(seed, i)`, so the output does not depend on the number of
/// threads. A progress bar is drawn on stderr when `progress` is true and stderr is a terminal.
pub fn monte_carlo<R, F>(label: &str, runs: usize, seed: u64, progress: bool, f: F) -> Vec<R>
where
    R: Send,
    F: Fn(usize, &mut SimRng) -> R + Sync,
{
    let bar = if progress {
        let b = ProgressBar::with_draw_target(Some(runs as u64), ProgressDrawTarget::stderr());
        if let Ok(style) =
            ProgressStyle::with_template("{prefix:>16} [{bar:40}] {pos}/{len} runs {elapsed}")
        {
            b.set_style(style.progress_chars("=> "));
        }
        b.set_prefix(label.to_string());
        b
    } else {
        ProgressBar::hidden()
    };
    let out: Vec<R> = (0..runs)
        .into_par_iter()
        .map(|i| {
            let mut rng = run_rng(seed, i as u64);
            let r = f(i, &mut rng);
            bar.inc(1);
            r
        })
        .collect();
    bar.finish_and_clear();
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::Rng;

    #[test]
    fn reproducible_and_ordered() {
        let a = monte_carlo("t", 16, 42, false, |i, rng| (i, rng.random::<u64>()));
        let b = monte_carlo("t", 16, 42, false, |i, rng| (i, rng.random::<u64>()));
        assert_eq!(a, b);
        assert!(a.iter().enumerate().all(|(k, (i, _))| k == *i));
        let c = monte_carlo("t", 16, 43, false, |i, rng| (i, rng.random::<u64>()));
        assert_ne!(a, c);
    }
}

//! Ensemble statistics over Monte Carlo runs.

/// Per-epoch ensemble statistics of one scalar over runs.
#[derive(Debug, Clone, Default)]
pub struct Ensemble {
    /// Mean over runs at each epoch.
    pub mean: Vec<f64>,
    /// Standard deviation about the mean (1/n normalisation) at each epoch.
    pub std: Vec<f64>,
    /// Root mean square over runs at each epoch.
    pub rms: Vec<f64>,
}

/// Ensemble statistics of `runs[r][k]` (run r, epoch k) over r. All runs must have the same
/// length; shorter runs end the statistics at their length.
pub fn ensemble(runs: &[Vec<f64>]) -> Ensemble {
    let n = runs.iter().map(Vec::len).min().unwrap_or(0);
    let m = runs.len().max(1) as f64;
    let mut e = Ensemble::default();
    for k in 0..n {
        let (mut s, mut s2) = (0.0, 0.0);
        for r in runs {
            s += r[k];
            s2 += r[k] * r[k];
        }
        let mean = s / m;
        e.mean.push(mean);
        e.rms.push((s2 / m).sqrt());
        e.std.push((s2 / m - mean * mean).max(0.0).sqrt());
    }
    e
}

/// RMS of all samples `runs[r][k]` with `keep(k)` true (over runs and epochs together).
pub fn rms_where(runs: &[Vec<f64>], keep: impl Fn(usize) -> bool) -> f64 {
    let (mut s2, mut n) = (0.0, 0usize);
    for r in runs {
        for (k, v) in r.iter().enumerate() {
            if keep(k) {
                s2 += v * v;
                n += 1;
            }
        }
    }
    if n == 0 {
        f64::NAN
    } else {
        (s2 / n as f64).sqrt()
    }
}

/// Sample autocorrelation of a zero-mean series at the given lag, normalised by the lag-0
/// value (biased estimator).
pub fn autocorrelation(x: &[f64], lag: usize) -> f64 {
    if lag >= x.len() {
        return f64::NAN;
    }
    let mean = x.iter().sum::<f64>() / x.len() as f64;
    let c0: f64 = x.iter().map(|v| (v - mean) * (v - mean)).sum();
    let cl: f64 = x
        .iter()
        .zip(&x[lag..])
        .map(|(a, b)| (a - mean) * (b - mean))
        .sum();
    cl / c0
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ensemble_hand_case() {
        let e = ensemble(&[vec![1.0, 2.0], vec![3.0, -2.0]]);
        assert_eq!(e.mean, vec![2.0, 0.0]);
        assert_eq!(e.std, vec![1.0, 2.0]);
        assert!((e.rms[0] - 5f64.sqrt()).abs() < 1e-15);
        assert!((rms_where(&[vec![3.0, 4.0]], |_| true) - 12.5f64.sqrt()).abs() < 1e-15);
        assert!((autocorrelation(&[1.0, -1.0, 1.0, -1.0], 1) + 0.75).abs() < 1e-15);
    }
}

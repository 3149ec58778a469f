//! The vertical truth of the scenarios: a piecewise-constant-acceleration profile.

use super::ProfileConfig;
use anyhow::{bail, ensure, Result};

/// Piecewise-constant-acceleration vertical truth.
#[derive(Debug, Clone)]
pub struct Profile {
    /// (start time s, start altitude m, start velocity m/s, acceleration m/s²).
    segments: Vec<(f64, f64, f64, f64)>,
}

impl Profile {
    /// Builds the profile from its legs.
    pub fn new(p: &ProfileConfig) -> Result<Self> {
        ensure!(p.accel_m_s2 > 0.0, "profile.accel_m_s2 must be positive");
        let mut segs = Vec::new();
        let (mut t, mut h) = (0.0, p.initial_altitude_m);
        for (i, leg) in p.legs.iter().enumerate() {
            match (leg.hold_s, leg.to_altitude_m, leg.rate_m_s) {
                (Some(d), None, None) => {
                    ensure!(d >= 0.0, "leg {i}: hold_s");
                    segs.push((t, h, 0.0, 0.0));
                    t += d;
                }
                (None, Some(target), Some(rate)) => {
                    ensure!(rate > 0.0, "leg {i}: rate_m_s");
                    let dh = target - h;
                    let s = dh.signum();
                    let ta = rate / p.accel_m_s2;
                    let ha = 0.5 * rate * ta;
                    ensure!(
                        dh.abs() >= 2.0 * ha,
                        "leg {i}: altitude change too small for the rate"
                    );
                    let tc = (dh.abs() - 2.0 * ha) / rate;
                    segs.push((t, h, 0.0, s * p.accel_m_s2));
                    segs.push((t + ta, h + s * ha, s * rate, 0.0));
                    segs.push((t + ta + tc, target - s * ha, s * rate, -s * p.accel_m_s2));
                    t += 2.0 * ta + tc;
                    h = target;
                }
                _ => bail!("leg {i}: either hold_s, or to_altitude_m with rate_m_s"),
            }
        }
        segs.push((t, h, 0.0, 0.0));
        Ok(Self { segments: segs })
    }

    /// (altitude m, vertical velocity m/s, acceleration m/s²) at time t.
    pub fn at(&self, t: f64) -> (f64, f64, f64) {
        let seg = self
            .segments
            .iter()
            .rev()
            .find(|s| s.0 <= t)
            .unwrap_or(&self.segments[0]);
        let dt = t - seg.0;
        (
            seg.1 + seg.2 * dt + 0.5 * seg.3 * dt * dt,
            seg.2 + seg.3 * dt,
            seg.3,
        )
    }
}

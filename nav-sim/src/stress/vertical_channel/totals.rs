//! The campaign's totals over its cases and the coverage lines of the report.

use super::*;

/// The campaign's totals over the cases: configurations refused, checkpoints (gate on, gate
/// off, the slow classical loops), steps and cases in `NeedsReinitialisation`.
#[derive(Default)]
pub(super) struct Totals {
    refused_configs: Vec<String>,
    cp: u64,
    cp_fail_on: u64,
    cp_fail_off: u64,
    worst_on: f64,
    worst_off: f64,
    worst_slow: f64,
    reinit_steps: u64,
    fail_cases: Vec<String>,
    end_reinit: u64,
    reinit_cases: Vec<String>,
}

impl Totals {
    /// Adds case `c` with what it measured; `false` when its configuration was refused (not run).
    pub(super) fn add(&mut self, c: &Case, e: &Extra) -> bool {
        if e.refused_config {
            self.refused_configs.push(c.name());
            return false;
        }
        self.cp += e.checkpoints;
        // A classical τ > 30 s loop needs longer than the 150 s aided window to settle (5τ).
        let slow = !c.aided && c.param > 30.0;
        if slow {
            self.worst_slow = self.worst_slow.max(e.worst_checkpoint_m);
        } else if c.gate {
            self.cp_fail_on += e.checkpoint_failures;
            self.worst_on = self.worst_on.max(e.worst_checkpoint_m);
            if e.checkpoint_failures > 0 && self.fail_cases.len() < 5 {
                self.fail_cases.push(format!(
                    "{}: {} of {} checkpoints, worst {:.0} m",
                    c.name(),
                    e.checkpoint_failures,
                    e.checkpoints,
                    e.worst_checkpoint_m
                ));
            }
        } else {
            self.cp_fail_off += e.checkpoint_failures;
            self.worst_off = self.worst_off.max(e.worst_checkpoint_m);
        }
        self.reinit_steps += e.needs_reinit_steps;
        if e.needs_reinit_steps > 0 && self.reinit_cases.len() < 5 {
            self.reinit_cases
                .push(format!("{}: {} steps", c.name(), e.needs_reinit_steps));
        }
        if e.end_health == Some(HealthState::NeedsReinitialisation) {
            self.end_reinit += 1;
        }
        true
    }

    /// The campaign's coverage lines.
    pub(super) fn coverage(&self, level: StressLevel) -> Vec<String> {
        let Totals {
            cp,
            cp_fail_on,
            cp_fail_off,
            worst_on,
            worst_off,
            worst_slow,
            reinit_steps,
            end_reinit,
            ..
        } = *self;
        let (fail_cases, reinit_cases) = (&self.fail_cases, &self.reinit_cases);
        vec![
        "both loops in f32; IMU 50, 100, 200, 500, 1000 Hz with ±50 % stamp jitter, 2 % \
         missing samples and a 0.5-2 s logging gap every 300 s; stamps from 0, 10⁶ and 10⁹ s"
            .into(),
        "classical τ 0.1, 1, 5, 20, 100 s; aided accelerometer noise 1e-3, 1e-2, 1e-1, 1 m/s²/√Hz; \
         gate off and on (σ_a0 = 0.1 m/s², starvation reset 30 s)"
            .into(),
        "15 g manoeuvres (20 km ± 2.4 km, |V_z| ≤ 590 m/s) or gentle ones, 5 mg bias; per 300 s: \
         1 km baro spike, 15 s frozen baro, 120 s outage of both aids"
            .into(),
        format!(
            "long runs: both loops, 15 g, outages, 1000 Hz and 100 Hz gate on, 1000 Hz gate off, \
             {} steps each",
            if level == StressLevel::Full {
                "10⁷"
            } else {
                "10⁶"
            }
        ),
        format!(
            "configurations refused as outside the envelope: {} ({})",
            self.refused_configs.len(),
            self.refused_configs.join("; ")
        ),
        format!(
            "altitude error at the end of each aided window ({cp} checkpoints; bound \
             {CHECKPOINT_BOUND_M} m for the loops that settle within the window, gate on): \
             {cp_fail_on} findings, worst {worst_on:.1} m; gate off (no fault detection, the \
             frozen baro drags the loop): {cp_fail_off} beyond the bound, worst \
             {worst_off:.1} m; classical τ = 100 s (settles in 5τ = 500 s, longer than the \
             150 s window; not bounded): worst {worst_slow:.1} m{}",
            if fail_cases.is_empty() {
                String::new()
            } else {
                format!(" — {}", fail_cases.join("; "))
            }
        ),
        format!(
            "steps in NeedsReinitialisation: {reinit_steps}; cases ending in it: {end_reinit} ({})",
            reinit_cases.join("; ")
        ),
        ]
    }
}

//! The `fault-baro` configuration: the fault windows, the gate, loading it and its base
//! scenario.

use super::*;

/// A fault over a time window.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Window {
    /// Start, s.
    pub start_s: f64,
    /// End, s.
    pub end_s: f64,
}

impl Window {
    pub(super) fn has(&self, t: f64) -> bool {
        t >= self.start_s && t < self.end_s
    }
}

/// Gate configuration (units in the names; see `nav_core::vertical_channel::AidModel`).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GateConfig {
    /// χ² threshold on ν²/S (1 dof).
    pub nis_threshold: f64,
    /// Baro innovation σ₀ of a tracking loop, m.
    pub baro_sigma_m: f64,
    /// Velocity-aid innovation σ₀, m/s.
    pub velocity_sigma_m_s: f64,
    /// Re-inflation: velocity uncertainty of the inertial solution, m/s.
    pub starved_velocity_sigma_m_s: f64,
    /// Re-inflation: acceleration uncertainty, m/s².
    pub starved_accel_sigma_m_s2: f64,
    /// Recovery gate hold after a re-acquisition, s.
    pub recovery_hold_s: f64,
    /// Starvation limit: samples rejected without a break this long re-anchor the loop, s.
    pub starved_reset_after_s: f64,
}

impl GateConfig {
    /// The nav-core aid model these values describe.
    pub fn aid_model<T: Real>(&self) -> AidModel<T> {
        AidModel {
            baro_sigma_m: T::lit(self.baro_sigma_m),
            velocity_sigma_m_s: T::lit(self.velocity_sigma_m_s),
            starved_velocity_sigma_m_s: T::lit(self.starved_velocity_sigma_m_s),
            starved_accel_sigma_m_s2: T::lit(self.starved_accel_sigma_m_s2),
            recovery_hold_s: T::lit(self.recovery_hold_s),
        }
    }

    /// The nav-core gate.
    pub fn gate<T: Real>(&self) -> Gate<T> {
        Gate::Nis(T::lit(self.nis_threshold))
    }

    /// The nav-core recovery: re-anchor after `starved_reset_after_s` of rejections.
    pub fn recovery<T: Real>(&self) -> RecoveryPolicy<T> {
        RecoveryPolicy {
            starved_after_s: Some(T::lit(self.starved_reset_after_s)),
            action: RecoveryAction::Reanchor,
        }
    }
}

/// `fault-baro` configuration.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FaultConfig {
    /// Scenario whose truth, sensors and loop designs are used (e.g. "vc-response").
    pub base_scenario: String,
    /// Initial altitude error (estimate − truth), m (overrides the base: start converged).
    pub initial_error_m: f64,
    /// Initial vertical-velocity error, m/s.
    pub initial_error_m_s: f64,
    /// Window over which the pre-fault bound (max |δh|) is taken, [start, end) s.
    pub pre_fault_window_s: [f64; 2],
    /// A recovery counts once |δh| stays within the pre-fault bound this long, s.
    pub hold_within_s: f64,
    /// Baro spike: reads `spike_offset_m` too high over the window.
    pub spike: Window,
    /// Spike size, m.
    pub spike_offset_m: f64,
    /// Frozen baro: repeats its last reading (fresh time stamps) over the window.
    pub frozen: Window,
    /// Baro dropout: no samples over the window.
    pub dropout: Window,
    /// The innovation gate of the gated loops.
    pub gate: GateConfig,
}

/// The three faults in time order with their names.
pub(super) fn faults(fc: &FaultConfig) -> [(&'static str, &Window); 3] {
    [
        ("spike", &fc.spike),
        ("frozen", &fc.frozen),
        ("dropout", &fc.dropout),
    ]
}

/// Loads the base configuration of a fault configuration.
pub fn base_config(fc: &FaultConfig) -> Result<Config> {
    load_config(&fc.base_scenario)
}

/// Loads a shipped fault configuration (e.g. `"fault-baro"`), for tests.
pub fn load_fault_config(name: &str) -> Result<FaultConfig> {
    let (_, path) = crate::scenario::resolve(name, &crate::scenario::default_scenario_dir())?;
    let text = std::fs::read_to_string(&path)?;
    let mut doc: toml::Table = toml::from_str(&text)?;
    for key in ["kind", "description", "runs", "seed"] {
        doc.remove(key);
    }
    Ok(FaultConfig::deserialize(toml::Value::Table(doc))?)
}

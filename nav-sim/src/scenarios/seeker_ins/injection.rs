//! The faults a seeker-aided INS run can be flown with (the run loop's view): seeker loss of
//! lock, false lock on a point off the landmark, accelerometer clipping in a vibration burst,
//! IMU sample gaps, and the filter's IMU fault policy. The `seeker-fault` scenario
//! ([`super::fault`]) and the mission's sensors configure them.

use nalgebra::Vector3;
use nav_core::seeker_ins::ImuFaultPolicy;
use nav_core::Real;
use serde::Deserialize;

/// A time window `[start_s, duration_s]`, s.
pub type Window = [f64; 2];

/// False lock: the seeker tracks a point `offset_deg` off the landmark (in gimbal yaw).
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FalseLock {
    /// Start, s.
    pub start_s: f64,
    /// Duration, s.
    pub duration_s: f64,
    /// Offset of the tracked point from the landmark, gimbal yaw, deg.
    pub offset_deg: f64,
}

/// A vibration burst along one body axis, `a(t) = A cos(2π f (t − t₀))` (whole cycles: no net
/// velocity or displacement, so the trajectory truth is unchanged), sensed by an
/// accelerometer of range ±`range_g` that clips each axis.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Clipping {
    /// Start, s.
    pub start_s: f64,
    /// Duration, s (rounded to whole vibration cycles).
    pub duration_s: f64,
    /// Body axis of the vibration, 0 = x, 1 = y, 2 = z.
    pub axis: usize,
    /// Vibration amplitude, g.
    pub amplitude_g: f64,
    /// Vibration frequency, Hz.
    pub frequency_hz: f64,
    /// Accelerometer range, ± g per axis.
    pub range_g: f64,
}

/// Faults as the run loop sees them.
#[derive(Debug, Clone, Default)]
pub struct Faults {
    /// Loss of lock windows.
    pub loss_of_lock: Vec<Window>,
    /// False locks.
    pub false_lock: Vec<FalseLock>,
    /// Clipping bursts.
    pub clipping: Vec<Clipping>,
    /// Whether clipped samples are flagged to the filter.
    pub flag_clipped: bool,
    /// IMU gaps.
    pub imu_gap: Vec<Window>,
    /// Filter policy (f64 values).
    pub policy: Option<ImuFaultPolicy<f64>>,
}

fn inside(w: &Window, t: f64) -> bool {
    t >= w[0] - 1e-9 && t < w[0] + w[1] - 1e-9
}

/// The policy in the filter's precision.
pub fn policy_cast<T: Real>(p: &ImuFaultPolicy<f64>) -> ImuFaultPolicy<T> {
    ImuFaultPolicy {
        max_gap_s: T::lit(p.max_gap_s),
        gap_accel_sigma_m_s2: T::lit(p.gap_accel_sigma_m_s2),
        gap_rate_sigma_rad_s: T::lit(p.gap_rate_sigma_rad_s),
        clip_accel_sigma_m_s2: T::lit(p.clip_accel_sigma_m_s2),
        clip_rate_sigma_rad_s: T::lit(p.clip_rate_sigma_rad_s),
    }
}

impl Faults {
    /// Whether the IMU sample at `t_s` (end of its interval) is lost.
    pub fn in_imu_gap(&self, t_s: f64) -> bool {
        self.imu_gap.iter().any(|w| inside(w, t_s))
    }

    /// Whether the seeker has lost lock at `t_s`.
    pub fn loss_of_lock(&self, t_s: f64) -> bool {
        self.loss_of_lock.iter().any(|w| inside(w, t_s))
    }

    /// The false-lock yaw offset at `t_s`, rad.
    pub fn false_lock_yaw_rad(&self, t_s: f64) -> Option<f64> {
        self.false_lock
            .iter()
            .find(|f| inside(&[f.start_s, f.duration_s], t_s))
            .map(|f| f.offset_deg.to_radians())
    }

    /// The velocity increment the accelerometer senses over the interval ending at `t_s`
    /// (before its scale factor, bias and noise) and whether it clipped: the true increment,
    /// plus the vibration of a burst, each axis clipped at the range (32 sub-samples).
    pub fn accel_increment(&self, t_s: f64, dt: f64, dv: &Vector3<f64>) -> (Vector3<f64>, bool) {
        let Some(c) = self.clipping.iter().find(|c| {
            let cycles = (c.duration_s * c.frequency_hz).round();
            t_s > c.start_s && t_s - dt < c.start_s + cycles / c.frequency_hz
        }) else {
            return (*dv, false);
        };
        const M: usize = 32;
        let g0 = 9.806_65;
        let cycles = (c.duration_s * c.frequency_hz).round();
        let end = c.start_s + cycles / c.frequency_hz;
        let f_nom = dv / dt;
        let range = c.range_g * g0;
        let w = std::f64::consts::TAU * c.frequency_hz;
        let mut sum = Vector3::zeros();
        let mut clipped = false;
        for m in 0..M {
            let t = t_s - dt + (m as f64 + 0.5) * dt / M as f64;
            let mut f = f_nom;
            if t >= c.start_s && t < end {
                f[c.axis.min(2)] += c.amplitude_g * g0 * (w * (t - c.start_s)).cos();
            }
            for v in f.iter_mut() {
                if v.abs() > range {
                    clipped = true;
                    *v = v.signum() * range;
                }
            }
            sum += f;
        }
        (sum * dt / M as f64, clipped)
    }
}

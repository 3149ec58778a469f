//! The flight navigator's stress part: `Navigator<f32, 5, 15, _>` (carry → released →
//! midcourse → terminal) flown over the mission's truth and sensors
//! (`scenarios::mission`: truth, inputs with their fault windows) with the configuration and
//! the inputs pushed to their ranges: IMU 100-1000 Hz, stamps from 0 and from hours in, IMU
//! noise × 0.01 and × 100, seeker and baro very precise and very poor, master data late,
//! missing and garbage, baro spikes and freezes, seeker loss of lock and false lock,
//! accelerometer clipping and IMU gaps, release with and without the aircraft's signal.
//!
//! After every accepted tick: the solution finite, its 9 × 9 covariance, the EKF's P (after
//! release) and the transfer alignment's P (in carry) PSD ([`super::Tally::covariance`]). Valid aid
//! samples refused (`AidState::Refused`) count as refusals of their own aid, so an aid
//! refused forever is a stall even while the ticks are accepted. A phase that never advances
//! when the inputs say it should (no release after a confirmed separation or after the free
//! fall without a signal, no midcourse after the coast, no terminal while the seeker tracks
//! the landmark) is a stall too.
//!
//! Hostile inputs (NaN, ∞, out of range, time going back) are injected every few hundred
//! ticks: an IMU sample must be refused with the navigator unchanged; an aid sample must be
//! refused (or not used in the phase) and leave the navigator as the same tick without it.
//! Each one that is not is counted in `hostile_not_refused`.

mod cases;
mod fly;
mod hostile;

use super::{CaseFinding, EstimatorStress, StressLevel};
use crate::scenarios::mission::navigator_setup::HISTORY;
use anyhow::Result;
use cases::cases;
use hostile::HOSTILE;
use nav_core::navigator::Navigator;
use rayon::prelude::*;

/// The navigator flown: f32 as on the target, the flight alignment (chains of 5, 15 states).
type Nav = Navigator<f32, 5, 15, HISTORY>;

/// The navigator's campaign.
pub fn run(level: StressLevel) -> EstimatorStress {
    let mut total = EstimatorStress::default();
    let list = match cases(level) {
        Ok(l) => l,
        Err(e) => {
            total.findings.push(CaseFinding {
                case: "setup".into(),
                finding: format!("{e}"),
            });
            return total;
        }
    };
    let parts: Vec<(String, Result<EstimatorStress>)> = list
        .par_iter()
        .map(|c| (c.name.clone(), fly::fly(c)))
        .collect();
    for (name, p) in parts {
        match p {
            Ok(p) => total.merge(p),
            Err(e) => {
                total.cases += 1;
                total.permanent_stalls += 1;
                total.findings.push(CaseFinding {
                    case: name,
                    finding: format!("the case could not run: {e}"),
                });
            }
        }
    }
    total.coverage = vec![
        "f32 Navigator<5, 15> over the mission truth and sensors (short: release at 30 s, 120 s; full: 310 s)".into(),
        "IMU 100/1000 Hz (full 100/200/500/1000) × stamps from 0, 3 h and 10^6 s × no faults / all faults".into(),
        "faults: master late 0.4 s and missing, accelerometer clipping at release, IMU gaps 0.05 s and 0.5 s, baro spikes +80 m and -500 m, baro freeze 10 s, seeker loss of lock 5 s and false lock 2°".into(),
        "IMU noise × 0.01 and × 100, seeker 1e-5 rad and 2°, baro 0.01 m and 30 m, the very-low-noise precise combination, garbage master data (every 5th: 5 km, 50 m/s, 10° off), master 20 % lost and 0.3 s late, release without a signal".into(),
        format!("hostile inputs in turn: {}", HOSTILE.join(", ")),
        "checked after every accepted tick: solution finite, solution P (9), EKF P (17) after release, alignment P (15) in carry".into(),
    ];
    total
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_case_list_builds_and_spans_the_ranges() {
        let c = cases(StressLevel::Short).expect("cases");
        assert!(c.iter().any(|c| c.cfg.imu_hz == 1000.0));
        // The release without a signal at 100 and 1000 Hz.
        let unsignalled: Vec<f64> = c
            .iter()
            .filter(|c| !c.signal)
            .map(|c| c.cfg.imu_hz)
            .collect();
        assert_eq!(unsignalled, [100.0, 1000.0]);
        assert!(c.iter().any(|c| c.offset_us >= 3600 * 1_000_000));
        assert!(c.iter().all(|c| c.cfg.check().is_ok()));
        let full = cases(StressLevel::Full).expect("cases");
        assert_eq!(full.iter().filter(|c| !c.signal).count(), 4);
        assert!(full.iter().all(|c| c.cfg.check().is_ok()));
    }
}

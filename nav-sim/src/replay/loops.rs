//! The two vertical loops the replay drives, and what each did over the log.

use super::*;

/// What one loop did over the log.
#[derive(Debug, Clone, Default)]
pub(super) struct LoopTally {
    pub(super) imu_accepted: u64,
    pub(super) imu_refused: BTreeMap<String, u64>,
    pub(super) aid_refused: BTreeMap<String, u64>,
    pub(super) alt_vs_gnss: Moments,
    pub(super) vz_vs_gnss: Moments,
    pub(super) alt_vs_autopilot: Moments,
    pub(super) vz_vs_autopilot: Moments,
    pub(super) alt: f64,
    pub(super) vz_up: f64,
}

pub(super) fn error_kind(e: &NavError) -> String {
    format!("{e:?}")
}

/// The two loops and the last aid samples not yet passed to them.
pub(super) struct Loops {
    pub(super) classical: ClassicalLoop<f32>,
    pub(super) aided: AidedLoop<f32>,
    pub(super) pending_baro: Option<BaroSample<f32>>,
    pub(super) pending_vel: Option<VelocitySample<f32>>,
    pub(super) tally: [LoopTally; 2],
}

impl Loops {
    pub(super) fn step(&mut self, t: Timestamp, f_up: f32) {
        let imu = ImuSample {
            time: t,
            specific_force_up_m_s2: f_up,
        };
        let baro = self.pending_baro.take();
        let vel = self.pending_vel.take();
        // Classical loop: the baro with the sample; if refused, the IMU alone (a flight loop
        // keeps the navigation running and counts the refused aid).
        let r = self.classical.step(&imu, baro.as_ref());
        let tally = &mut self.tally[0];
        match r {
            Ok(_) => tally.imu_accepted += 1,
            Err(e) if baro.is_some() => match self.classical.step(&imu, None) {
                Ok(_) => {
                    tally.imu_accepted += 1;
                    *tally
                        .aid_refused
                        .entry(format!("baro: {}", error_kind(&e)))
                        .or_default() += 1;
                }
                Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
            },
            Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
        }
        tally.alt = f64::from(self.classical.altitude_m());
        tally.vz_up = f64::from(self.classical.vz_up_m_s());

        let r = self.aided.step(&imu, baro.as_ref(), vel.as_ref());
        let tally = &mut self.tally[1];
        match r {
            Ok(_) => tally.imu_accepted += 1,
            Err(e) if baro.is_some() || vel.is_some() => match self.aided.step(&imu, None, None) {
                Ok(_) => {
                    tally.imu_accepted += 1;
                    *tally
                        .aid_refused
                        .entry(format!("aid: {}", error_kind(&e)))
                        .or_default() += 1;
                }
                Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
            },
            Err(e) => *tally.imu_refused.entry(error_kind(&e)).or_default() += 1,
        }
        tally.alt = f64::from(self.aided.altitude_m());
        tally.vz_up = f64::from(self.aided.vz_up_m_s());
    }
}

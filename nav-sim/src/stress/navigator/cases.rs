//! The navigator campaign's cases: the configuration and input ranges.

use super::super::StressLevel;
use crate::scenarios::mission::config::MissionConfig;
use crate::scenarios::mission::fault::FaultTable;
use crate::scenarios::mission::load_scenario;
use crate::scenarios::mission::navigator_setup::NavigatorSettings;
use anyhow::Result;

/// One configuration of the campaign.
#[derive(Debug, Clone)]
pub(super) struct Case {
    pub(super) name: String,
    pub(super) cfg: MissionConfig,
    pub(super) set: NavigatorSettings,
    pub(super) faults: FaultTable,
    /// Added to every time stamp, µs.
    pub(super) offset_us: u64,
    /// The aircraft's release signal is sent.
    pub(super) signal: bool,
    /// Every 5th master message is replaced with a wrong but finite one (position 5 km off,
    /// velocity 50 m/s off, attitude 10° off).
    pub(super) garbage_master: bool,
    /// Hostile inputs every this many ticks.
    pub(super) hostile_every: usize,
    pub(super) seed: u64,
}

/// A short mission for the short campaign: release at 30 s, landmark 31 km ahead (lock soon
/// after release), 120 s in all.
fn shorten(cfg: &mut MissionConfig) {
    let p = &mut cfg.profile;
    p.release_s = 30.0;
    p.carry_turn_start_s = 5.0;
    p.carry_turn_s = 8.0;
    p.carry_turn_back_after_s = Some(3.0);
    p.end_s = 120.0;
    cfg.landmark.north_m = 8000.0;
    cfg.landmark.east_m = 30000.0;
}

/// Every fault of the short mission (times in s from take-off; release at 30 s).
const SHORT_FAULTS: &str = r#"
master_late = [{ start_s = 10.0, duration_s = 3.0, value = 0.4 }]
master_missing = [[20.0, 2.0]]
clipping = [{ start_s = 30.3, duration_s = 0.4, axis = 2, amplitude_g = 25.0, frequency_hz = 200.0, range_g = 20.0 }]
imu_gap = [[40.0, 0.05], [41.0, 0.5]]
baro_spike = [{ start_s = 45.0, duration_s = 1.0, value = 80.0 }, { start_s = 50.0, duration_s = 0.2, value = -500.0 }]
baro_freeze = [[55.0, 10.0]]
loss_of_lock = [[80.0, 5.0]]
false_lock = [{ start_s = 95.0, duration_s = 3.0, offset_deg = 2.0 }]
"#;

/// Every fault of the full mission (release at 70 s).
const FULL_FAULTS: &str = r#"
master_late = [{ start_s = 30.0, duration_s = 3.0, value = 0.4 }]
master_missing = [[50.0, 2.0], [60.0, 5.0]]
clipping = [{ start_s = 70.3, duration_s = 0.4, axis = 2, amplitude_g = 25.0, frequency_hz = 200.0, range_g = 20.0 }]
imu_gap = [[100.0, 0.05], [101.0, 0.5]]
baro_spike = [{ start_s = 120.0, duration_s = 1.0, value = 80.0 }, { start_s = 130.0, duration_s = 0.2, value = -500.0 }]
baro_freeze = [[150.0, 10.0]]
loss_of_lock = [[240.0, 5.0]]
false_lock = [{ start_s = 270.0, duration_s = 3.0, offset_deg = 2.0 }]
"#;

/// Builds the cases from the base mission, each with its own seed.
struct Builder {
    cfg: MissionConfig,
    set: NavigatorSettings,
    seed: u64,
    out: Vec<Case>,
}

impl Builder {
    fn add(&mut self, name: String, f: &dyn Fn(&mut Case)) {
        let mut c = Case {
            name,
            cfg: self.cfg.clone(),
            set: self.set.clone(),
            faults: FaultTable::default(),
            offset_us: 0,
            signal: true,
            garbage_master: false,
            hostile_every: 499,
            seed: self.seed,
        };
        self.seed += 1;
        f(&mut c);
        self.out.push(c);
    }
}

/// The campaign's cases.
pub(super) fn cases(level: StressLevel) -> Result<Vec<Case>> {
    let (base, _) = load_scenario("mission")?;
    let mut cfg = base.mission.clone();
    if level == StressLevel::Short {
        shorten(&mut cfg);
    }
    let faults: FaultTable = toml::from_str(match level {
        StressLevel::Short => SHORT_FAULTS,
        StressLevel::Full => FULL_FAULTS,
    })?;
    let mut b = Builder {
        cfg,
        set: base.navigator.clone(),
        seed: 9100,
        out: Vec::new(),
    };
    grid(&mut b, level, &faults);
    let hz_grid: &[f64] = match level {
        StressLevel::Short => &[100.0],
        StressLevel::Full => &[100.0, 1000.0],
    };
    for &hz in hz_grid {
        variations(&mut b, hz, &faults);
        quiet(&mut b, hz, &faults);
    }
    // The release without a signal at the grid's extremes (short) or at every rate (full).
    let unsignalled_hz: &[f64] = match level {
        StressLevel::Short => &[100.0, 1000.0],
        StressLevel::Full => &[100.0, 200.0, 500.0, 1000.0],
    };
    for &hz in unsignalled_hz {
        unsignalled(&mut b, hz, &faults);
    }
    Ok(b.out)
}

/// IMU rate × stamp offset × faults.
fn grid(b: &mut Builder, level: StressLevel, faults: &FaultTable) {
    let rates: &[f64] = match level {
        StressLevel::Short => &[100.0, 1000.0],
        StressLevel::Full => &[100.0, 200.0, 500.0, 1000.0],
    };
    let offsets: &[u64] = &[0, 3 * 3600 * 1_000_000, 1_000_000 * 1_000_000];
    for &hz in rates {
        for &off in offsets {
            for faulty in [false, true] {
                let fl = faults.clone();
                b.add(
                    format!(
                        "{hz} Hz, stamps from {} s, {}",
                        off / 1_000_000,
                        if faulty { "all faults" } else { "no faults" }
                    ),
                    &move |c| {
                        c.cfg.imu_hz = hz;
                        c.offset_us = off;
                        if faulty {
                            c.faults = fl.clone();
                        }
                    },
                );
            }
        }
    }
}

/// Noise, precision, master and release variations at one IMU rate, every fault on.
fn variations(b: &mut Builder, hz: f64, faults: &FaultTable) {
    let fl = faults.clone();
    let at = |c: &mut Case| {
        c.cfg.imu_hz = hz;
        c.faults = fl.clone();
    };
    b.add(format!("{hz} Hz, IMU noise × 0.01"), &|c: &mut Case| {
        at(c);
        let s = &mut c.cfg.sensors;
        s.accel_noise_ug_rt_hz *= 0.01;
        s.gyro_arw_deg_rt_h *= 0.01;
    });
    b.add(format!("{hz} Hz, IMU noise × 100"), &|c: &mut Case| {
        at(c);
        let s = &mut c.cfg.sensors;
        s.accel_noise_ug_rt_hz *= 100.0;
        s.gyro_arw_deg_rt_h *= 100.0;
    });
    b.add(
        format!("{hz} Hz, IMU noise × 0.01, seeker 1e-5 rad, baro 0.01 m"),
        &|c: &mut Case| {
            at(c);
            let s = &mut c.cfg.sensors;
            s.accel_noise_ug_rt_hz *= 0.01;
            s.gyro_arw_deg_rt_h *= 0.01;
            s.seeker_noise_deg = 1e-5_f64.to_degrees();
            s.seeker_bias_deg = 1e-5_f64.to_degrees();
            c.cfg.baro.noise_m = 0.01;
            c.cfg.baro.markov_sigma_m = 0.01;
        },
    );
    b.add(format!("{hz} Hz, seeker 1e-5 rad"), &|c: &mut Case| {
        at(c);
        c.cfg.sensors.seeker_noise_deg = 1e-5_f64.to_degrees();
        c.cfg.sensors.seeker_bias_deg = 1e-5_f64.to_degrees();
    });
    b.add(format!("{hz} Hz, seeker 2°"), &|c: &mut Case| {
        at(c);
        c.cfg.sensors.seeker_noise_deg = 2.0;
        c.cfg.sensors.seeker_bias_deg = 1.0;
    });
    b.add(format!("{hz} Hz, baro 0.01 m"), &|c: &mut Case| {
        at(c);
        c.cfg.baro.noise_m = 0.01;
        c.cfg.baro.markov_sigma_m = 0.01;
    });
    b.add(format!("{hz} Hz, baro 30 m"), &|c: &mut Case| {
        at(c);
        c.cfg.baro.noise_m = 30.0;
        c.cfg.baro.markov_sigma_m = 50.0;
    });
    b.add(format!("{hz} Hz, garbage master data"), &|c: &mut Case| {
        at(c);
        c.garbage_master = true;
    });
    b.add(
        format!("{hz} Hz, master 20 % lost, 0.01-0.3 s late"),
        &|c: &mut Case| {
            at(c);
            c.cfg.master.loss_probability = 0.2;
            c.cfg.master.latency_s = [0.01, 0.3];
        },
    );
}

/// The release without the aircraft's signal, every fault on: declared on the IMU's unloading
/// that starts with the master's loss (the bus goes with the release); the short campaign's
/// master dropout (20-22 s) falls in the S manoeuvre's turn back, whose roll-out unloads the
/// missile on the wing by ≈ 12 m/s² over the dropout, crossing the 3 m/s² threshold ≈ 1 s
/// after the bus's loss: no release there.
fn unsignalled(b: &mut Builder, hz: f64, faults: &FaultTable) {
    b.add(
        format!("{hz} Hz, release without a signal"),
        &|c: &mut Case| {
            c.cfg.imu_hz = hz;
            c.faults = faults.clone();
            c.signal = false;
        },
    );
}

/// Almost no process noise: the instruments' noise × 0.01, no instrument errors, a seeker
/// precise to 1e-5 rad (four draws), every fault on.
fn quiet(b: &mut Builder, hz: f64, faults: &FaultTable) {
    // Almost no process noise: the instruments' noise × 0.01, no instrument errors, a
    // seeker precise to 1e-5 rad (four draws).
    for draw in 0..4 {
        let name = format!(
            "{hz} Hz, IMU noise × 0.01, no instrument errors, seeker 1e-5 rad, draw {draw}"
        );
        b.add(name, &|c: &mut Case| {
            c.cfg.imu_hz = hz;
            c.faults = faults.clone();
            let s = &mut c.cfg.sensors;
            s.accel_noise_ug_rt_hz *= 0.01;
            s.gyro_arw_deg_rt_h *= 0.01;
            s.accel_bias_ug = 0.0;
            s.gyro_bias_deg_h = 0.0;
            s.accel_scale_factor_ppm = 0.0;
            s.gyro_scale_factor_ppm = 0.0;
            s.accel_misalignment_arcsec = 0.0;
            s.gyro_misalignment_arcsec = 0.0;
            s.seeker_noise_deg = 1e-5_f64.to_degrees();
            s.seeker_bias_deg = 0.0;
        });
    }
}

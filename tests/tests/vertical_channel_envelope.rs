//! The vertical loops' operating envelope (public API only): real time stamps (jitter, late,
//! missing samples, gaps; a real autopilot log replayed at its own stamps), reports that are
//! always finite, aid stamps from the far past, configurations refused when they cannot work,
//! and a gated loop that never starves for good. Each test reproduces a failure of the loops
//! before integer-microsecond time stamps, integration over the actual interval, the bounded
//! recovery gate, the starvation reset and the multirate stability check.

use nav_core::time::Timestamp;
use nav_core::vertical_channel::{
    Aid, AidModel, AidTimeouts, AidedConfig, AidedLoop, BaroSample, ClassicalConfig, ClassicalLoop,
    ImuSample, InitialState, VelocitySample,
};
use nav_core::{
    Estimator, FusionOutcome, Gate, HealthState, NavError, Real, RecoveryAction, RecoveryPolicy,
};
use nav_sim::rng::{normal, run_rng};
use std::path::PathBuf;

const LAT_RAD: f64 = 0.7;

fn ts(seconds: f64) -> Timestamp {
    Timestamp::from_secs_f64(seconds).unwrap()
}

fn gravity(h: f64) -> f64 {
    nav_core::earth::normal_gravity_m_s2(LAT_RAD, h)
}

fn timeouts(stale: f64, lost: f64) -> AidTimeouts<f64> {
    AidTimeouts {
        stale_after_s: stale,
        lost_after_s: lost,
    }
}

/// The configurations are written in `f64` and cast to the loop's type (`cfg.cast()`).
fn classical(dt: f64, tau: f64, baro_period: f64) -> ClassicalConfig<f64> {
    ClassicalConfig {
        imu_dt_s: dt,
        latitude_rad: LAT_RAD,
        tau_s: tau,
        baro_lag_s: 0.0,
        baro_period_s: baro_period,
        baro_timeouts: timeouts(2.5 * baro_period, 1.0),
        ..ClassicalConfig::paper()
    }
}

fn aided(dt: f64, baro_period: f64, vel_period: f64) -> AidedConfig<f64> {
    AidedConfig {
        imu_dt_s: dt,
        latitude_rad: LAT_RAD,
        accel_noise_m_s2_rt_hz: 0.05,
        accel_bias_rw_m_s2_rt_s: 1e-3,
        baro_noise_m: 1.0,
        baro_period_s: baro_period,
        baro_lag_s: 0.0,
        velocity_noise_m_s: 0.2,
        velocity_period_s: vel_period,
        baro_timeouts: timeouts(2.5 * baro_period, 1.0),
        velocity_timeouts: timeouts(2.5 * vel_period, 2.0),
        ..AidedConfig::paper()
    }
}

fn init<T: Real>(t: Timestamp, h: f64, v: f64) -> InitialState<T> {
    InitialState {
        time: t,
        altitude_m: T::lit(h),
        vz_up_m_s: T::lit(v),
        accel_bias_m_s2: T::zero(),
    }
}

/// The gate of these tests: χ² 16 on σ₀ = 3 m, 0.5 m/s, re-inflation from 0.5 m/s and
/// `sigma_a0`, re-anchoring after 30 s of rejections.
fn gated<C: GateFields>(cfg: &C, sigma_a0: f64) -> C {
    cfg.with_gate(
        AidModel {
            baro_sigma_m: 3.0,
            velocity_sigma_m_s: 0.5,
            starved_velocity_sigma_m_s: 0.5,
            starved_accel_sigma_m_s2: sigma_a0,
            recovery_hold_s: 60.0,
        },
        Gate::Nis(16.0),
        RecoveryPolicy {
            starved_after_s: Some(30.0),
            action: RecoveryAction::Reanchor,
        },
    )
}

/// Both configurations' run-time fields.
trait GateFields {
    fn with_gate(&self, m: AidModel<f64>, g: Gate<f64>, r: RecoveryPolicy<f64>) -> Self;
}

impl GateFields for ClassicalConfig<f64> {
    fn with_gate(&self, m: AidModel<f64>, g: Gate<f64>, r: RecoveryPolicy<f64>) -> Self {
        ClassicalConfig {
            aid_model: m,
            gate: g,
            recovery: r,
            ..*self
        }
    }
}

impl GateFields for AidedConfig<f64> {
    fn with_gate(&self, m: AidModel<f64>, g: Gate<f64>, r: RecoveryPolicy<f64>) -> Self {
        AidedConfig {
            aid_model: m,
            gate: g,
            recovery: r,
            ..*self
        }
    }
}

// ------------------------------------------------------------------ real log

/// One CSV file of the shipped log as columns by name.
fn read_csv(name: &str) -> (Vec<String>, Vec<Vec<f64>>) {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../shared/data/px4-sdlog2-csv")
        .join(name);
    let text = std::fs::read_to_string(&path)
        .unwrap_or_else(|e| panic!("{}: {e} (the shipped PX4 log)", path.display()));
    let mut lines = text.lines();
    let header = lines
        .next()
        .unwrap()
        .split(',')
        .map(str::to_string)
        .collect();
    let rows = lines
        .filter(|l| !l.trim().is_empty())
        .map(|l| l.split(',').map(|v| v.trim().parse().unwrap()).collect())
        .collect();
    (header, rows)
}

fn column(csv: &(Vec<String>, Vec<Vec<f64>>), name: &str) -> Vec<f64> {
    let i = csv.0.iter().position(|h| h == name).unwrap();
    csv.1.iter().map(|r| r[i]).collect()
}

/// What happened to every sample of a replay.
#[derive(Debug, Default)]
struct Replay {
    imu_accepted: usize,
    imu_refused: Vec<(f64, NavError)>,
    aid_fused: usize,
    aid_rejected: usize,
    /// Aid samples not passed because a newer one of the same aid arrived in the same IMU
    /// interval (the loops take the newest sample per step).
    aid_superseded: usize,
    aid_total: usize,
    /// (t, loop altitude, PX4 estimate) at the IMU samples.
    track: Vec<(f64, f64, f64)>,
    max_intervals: u32,
}

/// Replays the log through a loop at the log's own time stamps. `drop`: IMU samples in these
/// windows are withheld (logging gaps).
fn replay<T: Real>(aided_loop: bool, drop: &[(f64, f64)]) -> Replay {
    let imu = read_csv("imu.csv");
    let baro = read_csv("baro.csv");
    let gnss = read_csv("gnss.csv");
    let est = read_csv("estimate.csv");
    let (ti, f_down) = (column(&imu, "t_s"), column(&imu, "f_down_m_s2"));
    let (tb, hb) = (column(&baro, "t_s"), column(&baro, "baro_alt_m"));
    let (tg, vd) = (column(&gnss, "t_s"), column(&gnss, "gnss_vd_m_s"));
    let (te, he) = (column(&est, "t_s"), column(&est, "est_alt_m"));
    // Nominal rates of the log: IMU 81 Hz, baro 62 Hz, GNSS 5 Hz.
    let dt = 0.0125;
    let ccfg = ClassicalConfig {
        baro_timeouts: timeouts(0.05, 0.5),
        ..classical(dt, 3.0, 0.016)
    };
    let acfg = AidedConfig {
        accel_noise_m_s2_rt_hz: 0.3,
        accel_bias_rw_m_s2_rt_s: 0.01,
        baro_noise_m: 0.5,
        velocity_noise_m_s: 0.1,
        baro_timeouts: timeouts(0.05, 0.5),
        velocity_timeouts: timeouts(0.5, 1.5),
        ..aided(dt, 0.016, 0.2)
    };
    let t0 = ts(ti[0]);
    let start = init::<T>(t0, hb[0], 0.0);
    let mut cl = ClassicalLoop::<T>::new(&(ccfg).cast(), &start).unwrap();
    let mut al = AidedLoop::<T>::new(&(acfg).cast(), &start).unwrap();
    let mut out = Replay {
        aid_total: tb.len() - 1 + if aided_loop { tg.len() } else { 0 },
        ..Replay::default()
    };
    let (mut ib, mut ig, mut ie) = (1, 0, 0);
    for (k, (&t, &f)) in ti.iter().zip(&f_down).enumerate().skip(1) {
        // The newest aid samples stamped up to this IMU sample.
        let mut newest = |times: &[f64], i: &mut usize| -> Option<usize> {
            let mut got = None;
            while *i < times.len() && times[*i] <= t {
                if got.is_some() {
                    out.aid_superseded += 1;
                }
                got = Some(*i);
                *i += 1;
            }
            got
        };
        let b = newest(&tb, &mut ib).map(|i| BaroSample {
            time: ts(tb[i]),
            altitude_m: T::lit(hb[i]),
        });
        let g = if aided_loop {
            newest(&tg, &mut ig).map(|i| VelocitySample {
                time: ts(tg[i]),
                vz_up_m_s: T::lit(-vd[i]),
            })
        } else {
            None
        };
        if drop.iter().any(|&(a, z)| t >= a && t < z) {
            // The IMU sample is lost; so are the aid samples that would have come with it.
            out.aid_superseded += usize::from(b.is_some()) + usize::from(g.is_some());
            continue;
        }
        let sample = ImuSample {
            time: ts(t),
            specific_force_up_m_s2: T::lit(-f),
        };
        let reports = if aided_loop {
            al.step(&sample, b.as_ref(), g.as_ref())
                .map(|r| (r.imu_intervals, vec![r.baro, r.velocity]))
        } else {
            cl.step(&sample, b.as_ref())
                .map(|r| (r.imu_intervals, vec![r.baro]))
        };
        match reports {
            Ok((n, reps)) => {
                out.imu_accepted += 1;
                out.max_intervals = out.max_intervals.max(n);
                for r in reps {
                    if let Some(c) = r.sample {
                        match c.outcome {
                            FusionOutcome::Fused => out.aid_fused += 1,
                            _ => out.aid_rejected += 1,
                        }
                    }
                }
            }
            Err(e) => {
                out.imu_refused.push((t, e));
                out.aid_superseded += usize::from(b.is_some()) + usize::from(g.is_some());
            }
        }
        while ie + 1 < te.len() && te[ie + 1] <= t {
            ie += 1;
        }
        let h = if aided_loop {
            al.altitude_m()
        } else {
            cl.altitude_m()
        };
        out.track.push((t, h.to_f64(), he[ie]));
        let _ = k;
    }
    out
}

/// Altitude of the loop vs PX4's estimate after `settle_s`: the datum offset (median of the
/// difference) removed, the largest and RMS deviation, m.
fn deviation(track: &[(f64, f64, f64)], settle_s: f64) -> (f64, f64, f64) {
    let late: Vec<f64> = track
        .iter()
        .filter(|p| p.0 >= settle_s)
        .map(|p| p.1 - p.2)
        .collect();
    let mut sorted = late.clone();
    sorted.sort_by(f64::total_cmp);
    let offset = sorted[sorted.len() / 2];
    let max = late.iter().map(|d| (d - offset).abs()).fold(0.0, f64::max);
    let rms = (late.iter().map(|d| (d - offset).powi(2)).sum::<f64>() / late.len() as f64).sqrt();
    (offset, max, rms)
}

fn check_replay<T: Real>(aided_loop: bool, drop: &[(f64, f64)], bound_max_m: f64) {
    let r = replay::<T>(aided_loop, drop);
    let (offset, max, rms) = deviation(&r.track, 20.0);
    println!(
        "{} {}{}: IMU {} accepted, {} refused; aids {} fused, {} rejected, {} superseded of {}; \
         largest step {} sub-steps; vs PX4 after 20 s: offset {offset:.2} m, max {max:.2} m, \
         RMS {rms:.2} m",
        if aided_loop { "aided" } else { "classical" },
        std::any::type_name::<T>(),
        if drop.is_empty() { "" } else { " with gaps" },
        r.imu_accepted,
        r.imu_refused.len(),
        r.aid_fused,
        r.aid_rejected,
        r.aid_superseded,
        r.aid_total,
        r.max_intervals,
    );
    // Every IMU sample of the log is accepted (its stamps increase; none is impossible).
    assert!(
        r.imu_refused.is_empty(),
        "{:?}",
        &r.imu_refused[..3.min(r.imu_refused.len())]
    );
    // Every aid sample is accounted for: fused, rejected by a gate (none here), or superseded
    // by a newer one in the same IMU interval (or lost with a withheld IMU sample).
    assert_eq!(r.aid_fused + r.aid_rejected + r.aid_superseded, r.aid_total);
    assert_eq!(r.aid_rejected, 0);
    assert!(
        r.aid_fused as f64 >= 0.85 * r.aid_total as f64,
        "{} of {}",
        r.aid_fused,
        r.aid_total
    );
    assert!(max < bound_max_m && rms < 0.5, "max {max} rms {rms}");
    if !drop.is_empty() {
        assert!(r.max_intervals > 1);
    }
}

/// The shipped PX4 log (81 Hz IMU with 10-24 ms intervals, 62 Hz baro, 5 Hz GNSS) through
/// both loops at its own time stamps: every IMU sample accepted (the loops used to refuse
/// 2 679 of its 5 741 samples once one late sample put them off their grid), every aid
/// sample fused or superseded, and the altitude within 2.5 m (RMS 0.5 m) of PX4's own
/// estimate after 20 s (datum offset removed; PX4 fuses GNSS altitude too).
#[test]
fn real_px4_log_replays_at_its_own_time_stamps() {
    for aided_loop in [false, true] {
        check_replay::<f32>(aided_loop, &[], 2.5);
        check_replay::<f64>(aided_loop, &[], 2.5);
    }
}

/// The same log with logging gaps of 0.5, 1 and 2 s (IMU and aid samples withheld): bridged,
/// every sample accepted, the altitude within 3 m of PX4's estimate.
#[test]
fn real_px4_log_with_logging_gaps() {
    let gaps = [(25.0, 25.5), (40.0, 41.0), (55.0, 57.0)];
    for aided_loop in [false, true] {
        check_replay::<f32>(aided_loop, &gaps, 3.0);
    }
}

// ------------------------------------------------------------------ time stamps

/// Jittered (15-35 ms at a nominal 20 ms), late, missing and gapped IMU samples on a
/// climbing, accelerating truth: every sample accepted, the clock always at the last sample,
/// and the loops as accurate as with perfect stamps.
#[test]
fn jitter_late_missing_and_gaps_are_integrated_over_the_actual_interval() {
    for f32_loop in [true, false] {
        let mut rng = run_rng(91, 0);
        let truth = |t: f64| {
            let (a, w) = (300.0, 0.05);
            (
                1000.0 + a * (w * t).sin() + 2.0 * t,
                a * w * (w * t).cos() + 2.0,
            )
        };
        let dt = 0.02;
        let (h0, v0) = truth(0.0);
        let mut cl =
            ClassicalLoop::<f64>::new(&classical(dt, 5.0, 0.04).cast(), &init(ts(0.0), h0, v0))
                .unwrap();
        let mut cl32 =
            ClassicalLoop::<f32>::new(&classical(dt, 5.0, 0.04).cast(), &init(ts(0.0), h0, v0))
                .unwrap();
        let mut al =
            AidedLoop::<f64>::new(&aided(dt, 0.04, 0.1).cast(), &init(ts(0.0), h0, v0)).unwrap();
        let mut t_us: u64 = 0;
        let mut v_prev = v0;
        let (mut worst, mut n, mut last_baro_us) = (0.0f64, 0u32, 0u64);
        let mut gaps = 0;
        while t_us < 600_000_000 {
            // 15-35 ms jitter, 3 % of samples missing, a 0.5-2 s gap every 100 s.
            let mut step_us = 15_000 + (normal(&mut rng, 1.0).abs() * 7_000.0) as u64 % 20_000;
            if normal(&mut rng, 1.0) > 1.9 {
                step_us += 20_000;
            }
            if (t_us / 100_000_000) != ((t_us + step_us) / 100_000_000) {
                step_us += 500_000 + (normal(&mut rng, 1.0).abs() * 500_000.0) as u64 % 1_500_000;
                gaps += 1;
            }
            let t0 = t_us as f64 * 1e-6;
            t_us += step_us;
            let t = t_us as f64 * 1e-6;
            let (h, v) = truth(t);
            let (hm, _) = truth(0.5 * (t + t0));
            let f = (v - v_prev) / (t - t0) + gravity(hm) + normal(&mut rng, 0.01);
            v_prev = v;
            let baro = (t_us - last_baro_us >= 40_000).then(|| {
                last_baro_us = t_us;
                (t, h + normal(&mut rng, 0.5))
            });
            let vel = (n % 5 == 0).then(|| (t, v + normal(&mut rng, 0.05)));
            n += 1;
            let imu = ImuSample {
                time: Timestamp::from_micros(t_us),
                specific_force_up_m_s2: f,
            };
            let b = baro.map(|(tt, z)| BaroSample {
                time: ts(tt),
                altitude_m: z,
            });
            let vv = vel.map(|(tt, z)| VelocitySample {
                time: ts(tt),
                vz_up_m_s: z,
            });
            if f32_loop {
                cl32.step(
                    &ImuSample {
                        time: imu.time,
                        specific_force_up_m_s2: f as f32,
                    },
                    b.map(|s| BaroSample {
                        time: s.time,
                        altitude_m: s.altitude_m as f32,
                    })
                    .as_ref(),
                )
                .unwrap();
                assert_eq!(cl32.time(), Some(imu.time));
                if t > 60.0 {
                    worst = worst.max((cl32.altitude_m().to_f64() - h).abs());
                }
            } else {
                cl.step(&imu, b.as_ref()).unwrap();
                al.step(&imu, b.as_ref(), vv.as_ref()).unwrap();
                assert_eq!((cl.time(), al.time()), (Some(imu.time), Some(imu.time)));
                if t > 60.0 {
                    worst = worst
                        .max((cl.altitude_m() - h).abs())
                        .max((al.altitude_m() - h).abs());
                }
            }
        }
        assert!(gaps >= 5);
        assert!(worst < 4.0, "f32 {f32_loop}: worst |δh| {worst} m");
    }
}

/// One off-nominal interval equals the exact discretisation at that interval: a loop designed
/// at 20 ms stepping 11, 27 and 31 ms matches loops designed at those intervals.
#[test]
fn an_off_nominal_interval_matches_the_exact_discretisation() {
    for dt_us in [11_000u64, 27_000, 31_000, 45_000, 3_000] {
        let dt = dt_us as f64 * 1e-6;
        let start = init::<f64>(ts(100.0), 1000.0, 3.0);
        let mut nominal = ClassicalLoop::new(&classical(0.02, 4.0, 0.04).cast(), &start).unwrap();
        let mut exact = ClassicalLoop::new(&classical(dt, 4.0, 0.04).cast(), &start).unwrap();
        let mut an = AidedLoop::new(&aided(0.02, 0.04, 0.1).cast(), &start).unwrap();
        let mut ae = AidedLoop::new(&aided(dt, 0.04, 0.1).cast(), &start).unwrap();
        let t = ts(100.0).add_micros(dt_us);
        let imu = ImuSample {
            time: t,
            specific_force_up_m_s2: gravity(1000.0) + 0.7,
        };
        let b = BaroSample {
            time: t,
            altitude_m: 1012.0,
        };
        let v = VelocitySample {
            time: t,
            vz_up_m_s: 2.0,
        };
        let rn = nominal.step(&imu, Some(&b)).unwrap();
        exact.step(&imu, Some(&b)).unwrap();
        an.step(&imu, Some(&b), Some(&v)).unwrap();
        ae.step(&imu, Some(&b), Some(&v)).unwrap();
        let sub = if dt_us > 30_000 { 2 } else { 1 };
        assert_eq!(rn.imu_intervals, sub);
        let close = |a: f64, b: f64, what: &str| {
            let moved = (b - if what == "h" { 1000.0 } else { 3.0 }).abs();
            // Relative to the step's own increment (1e-6: far below f32's resolution).
            assert!(
                (a - b).abs() <= 1e-6 * moved.max(1e-3),
                "{dt_us} µs {what}: {a} vs {b}"
            );
        };
        if sub == 1 {
            close(nominal.altitude_m(), exact.altitude_m(), "h");
            close(nominal.vz_up_m_s(), exact.vz_up_m_s(), "v");
            close(an.altitude_m(), ae.altitude_m(), "h");
            close(an.vz_up_m_s(), ae.vz_up_m_s(), "v");
        }
    }
}

/// A refused IMU sample (stamp not after the clock) never freezes the clock: the next valid
/// sample is integrated over its actual interval. And stamps past 10⁶ s give the same f32
/// result as stamps near 0 (intervals are formed in integer microseconds).
#[test]
fn refusals_never_freeze_the_clock_and_long_runs_keep_their_resolution() {
    let cfg = classical(0.01, 10.0, 0.04);
    let run = |t0: Timestamp| {
        let mut lp = ClassicalLoop::<f32>::new(&(cfg).cast(), &init(t0, 500.0, 1.0)).unwrap();
        let mut refused = 0;
        for k in 1..=3000u64 {
            let t = t0.add_micros(10_000 * k + (k % 7) * 1_300);
            let imu = ImuSample {
                time: t,
                specific_force_up_m_s2: 9.81,
            };
            let b = BaroSample {
                time: t,
                altitude_m: 500.0 + 0.01 * k as f32,
            };
            lp.step(&imu, Some(&b)).unwrap();
            // A late (duplicate) sample: refused, clock unchanged, nothing changed.
            if k % 100 == 0 {
                let (alt, vz) = (lp.altitude_m(), lp.vz_up_m_s());
                let (t_before, n_before) = (lp.time(), lp.health().imu_refused);
                assert_eq!(lp.step(&imu, None).err(), Some(NavError::TimeNotIncreasing));
                assert_eq!(
                    (lp.altitude_m(), lp.vz_up_m_s(), lp.time()),
                    (alt, vz, t_before)
                );
                assert_eq!(lp.health().imu_refused, n_before + 1);
                refused += 1;
            }
        }
        assert_eq!(refused, 30);
        (lp.altitude_m(), lp.vz_up_m_s())
    };
    let near_zero = run(Timestamp::ZERO);
    let late = run(Timestamp::from_micros(1_000_000 * 1_000_000 + 123_456));
    assert_eq!(near_zero, late);
}

// ------------------------------------------------------------------ finite reports, old stamps

fn all_finite<T: Real>(r: &nav_core::vertical_channel::AidReport<T>) -> bool {
    let ok = |v: Option<T>| v.is_none_or(|x| x.is_finite());
    let age = match r.status {
        nav_core::vertical_channel::AidStatus::Fresh { age_s }
        | nav_core::vertical_channel::AidStatus::Stale { age_s }
        | nav_core::vertical_channel::AidStatus::Lost { age_s } => Some(age_s),
        nav_core::vertical_channel::AidStatus::NoData => None,
    };
    ok(r.correction)
        && ok(age)
        && r.sample.is_none_or(|c| {
            [c.innovation, c.innovation_variance, c.nis, c.test_ratio]
                .iter()
                .all(|v| v.is_finite())
        })
}

/// An aid stamped absurdly long ago (the IMU at 10 000.04 s, a baro sample stamped at the
/// epoch; a stamp of −1e20 s cannot be formed) is refused — the loops used to accept it and
/// report a NaN NIS — and nothing changes; no report ever carries a non-finite number.
#[test]
fn absurdly_old_aid_stamps_are_refused_and_reports_stay_finite() {
    assert!(Timestamp::from_secs_f64(-1e20).is_err());
    assert!(Timestamp::from_secs_f64(-3e38).is_err());
    let mut lp = ClassicalLoop::<f32>::new(
        &classical(0.01, 20.0, 0.04).cast(),
        &init(ts(10_000.0), 500.0, 0.0),
    )
    .unwrap();
    let g = gated(&classical(0.01, 20.0, 0.04), 0.1).cast::<f32>();
    lp.set_aid_model(g.aid_model).unwrap();
    lp.set_recovery(g.recovery).unwrap();
    lp.set_gate(g.gate).unwrap();
    let imu = |t: f64| ImuSample {
        time: ts(t),
        specific_force_up_m_s2: gravity(500.0) as f32,
    };
    let r = lp.step(&imu(10_000.01), None).unwrap();
    assert!(all_finite(&r.baro));
    let before = (
        lp.altitude_m(),
        lp.vz_up_m_s(),
        lp.time(),
        lp.health().state,
    );
    for stamp in [0.0, 1.0, 9_000.0, 10_000.02 - 1.0 - 1e-6] {
        let b = BaroSample {
            time: ts(stamp),
            altitude_m: 500.0,
        };
        assert_eq!(
            lp.step(&imu(10_000.02), Some(&b)).err(),
            Some(NavError::MeasurementTimeOutOfWindow),
            "{stamp}"
        );
        let now = (
            lp.altitude_m(),
            lp.vz_up_m_s(),
            lp.time(),
            lp.health().state,
        );
        assert_eq!(now, before);
    }
    assert_eq!(lp.aid_counters(Aid::Baro).refused, 4);
    // Stamps at the edge of the window and exactly at the IMU time: accepted, finite.
    for (k, stamp) in [(2, 10_000.02 - 1.0), (3, 10_000.03), (4, 10_000.035)] {
        let b = BaroSample {
            time: ts(stamp),
            altitude_m: 500.0,
        };
        let r = lp
            .step(&imu(10_000.0 + 0.01 * f64::from(k)), Some(&b))
            .unwrap();
        assert!(all_finite(&r.baro), "{r:?}");
    }
}

/// The loop runs at 1000 s and its first baro sample is stamped 0 s: refused (it used to be
/// accepted and then hold a recovery gate of σ ≈ 51 km for 60 s). A 3 km spike during the
/// following minute is rejected; so is one during the recovery hold after a genuine 300 s
/// dropout (the held gate is bounded by the re-acquiring sample's own innovation).
#[test]
fn an_old_first_sample_or_a_long_dropout_cannot_hold_the_gate_wide_open() {
    for dropout in [false, true] {
        let t0 = 1000.0;
        let mut lp = ClassicalLoop::<f32>::new(
            &classical(0.01, 20.0, 0.04).cast(),
            &init(ts(t0), 500.0, 0.0),
        )
        .unwrap();
        let g = gated(&classical(0.01, 20.0, 0.04), 0.02).cast::<f32>();
        lp.set_aid_model(g.aid_model).unwrap();
        lp.set_recovery(g.recovery).unwrap();
        lp.set_gate(g.gate).unwrap();
        let mut rng = run_rng(3, 0);
        let g = gravity(500.0) as f32;
        let mut spike_seen = false;
        let mut worst: f64 = 0.0;
        for k in 1..=60_000u32 {
            let t = t0 + f64::from(k) * 0.01;
            let imu = ImuSample {
                time: ts(t),
                specific_force_up_m_s2: g + normal(&mut rng, 0.01) as f32,
            };
            let out = dropout && (10.0..310.0).contains(&(t - t0));
            let hold_start = if dropout { 310.0 } else { 0.0 };
            let spike = (hold_start + 30.0..hold_start + 30.2).contains(&(t - t0));
            let baro = (k % 4 == 0 && !out).then(|| BaroSample {
                time: ts(t),
                altitude_m: (500.0 + normal(&mut rng, 1.0) + if spike { 3000.0 } else { 0.0 })
                    as f32,
            });
            if k == 1 {
                let old = BaroSample {
                    time: ts(0.0),
                    altitude_m: 500.0,
                };
                assert_eq!(
                    lp.step(&imu, Some(&old)).err(),
                    Some(NavError::MeasurementTimeOutOfWindow)
                );
            }
            let r = lp.step(&imu, baro.as_ref()).unwrap();
            assert!(all_finite(&r.baro));
            if spike && baro.is_some() {
                let c = r.baro.sample.unwrap();
                assert_eq!(c.outcome, FusionOutcome::Rejected, "t {t}: {c:?}");
                spike_seen = true;
            }
            if t - t0 > 5.0 {
                worst = worst.max((lp.altitude_m() as f64 - 500.0).abs());
            }
        }
        assert!(spike_seen);
        assert!(worst < 60.0, "dropout {dropout}: worst {worst}");
    }
}

// ------------------------------------------------------------------ configurations

/// τ = 0.01 s with a 1 kHz IMU and a 25 Hz baro diverged in 0.4 s with perfect sensors; it is
/// refused (`tau_s`). Over a grid of τ × IMU interval × baro period, every configuration the
/// classical loop accepts converges with perfect sensors (the refused ones are shown to
/// diverge by nav-core's unit test of the stability analysis).
#[test]
fn classical_tau_must_suit_the_imu_and_baro_rates() {
    let e = ClassicalLoop::<f32>::new(
        &classical(0.001, 0.01, 0.04).cast(),
        &init(ts(0.0), 500.0, 0.0),
    );
    assert!(
        matches!(e, Err(NavError::InvalidConfig { field: "tau_s", .. })),
        "{e:?}"
    );
    let (mut accepted, mut refused) = (0, 0);
    for dt in [0.001, 0.005, 0.01, 0.02] {
        for m in [1u32, 4, 10, 25] {
            for tau in [0.01, 0.03, 0.1, 0.3, 1.0, 3.0] {
                let cfg = classical(dt, tau, f64::from(m) * dt);
                let start = init::<f64>(ts(0.0), 500.001, 1e-3);
                let Ok(mut lp) = ClassicalLoop::<f64>::new(&(cfg).cast(), &start) else {
                    refused += 1;
                    continue;
                };
                accepted += 1;
                let g = gravity(500.0);
                let steps = ((60.0 * tau / dt) as u64).max(100 * u64::from(m));
                let dt_us = (dt * 1e6).round() as u64;
                for k in 1..=steps {
                    let t = Timestamp::from_micros(k * dt_us);
                    let b = (k % u64::from(m) == 0).then_some(BaroSample {
                        time: t,
                        altitude_m: 500.0,
                    });
                    lp.step(
                        &ImuSample {
                            time: t,
                            specific_force_up_m_s2: g,
                        },
                        b.as_ref(),
                    )
                    .unwrap();
                }
                let e = (lp.altitude_m() - 500.0).abs();
                assert!(e < 1e-5, "dt {dt} m {m} τ {tau}: |δh| {e}");
            }
        }
    }
    assert!(accepted > 40 && refused > 10, "{accepted} {refused}");
}

/// A gated aided loop (σ_a0 = 0.1 m/s²) with 15 g manoeuvres and a 120 s outage of both aids
/// every 300 s: it used to reject every sample once its estimate drifted and to refuse every
/// step from 1621 s. Now no step is refused, a starved gate re-anchors the loop, and after
/// each outage the loop is back on the truth.
#[test]
fn gated_aided_loop_with_15g_manoeuvres_and_long_outages_never_starves() {
    let dt = 0.01;
    let mut rng = run_rng(15, 0);
    // 15 g peak: A ω² = 147 m/s² with ω = 0.25 rad/s (A = 2352 m, 588 m/s).
    let (amp, w) = (147.0 / 0.0625, 0.25);
    let truth = |t: f64| (20_000.0 + amp * (w * t).sin(), amp * w * (w * t).cos());
    let (h0, v0) = truth(0.0);
    for f32_loop in [true, false] {
        let cfg = gated(&aided(dt, 0.04, 0.1), 0.1);
        let mut a32 = AidedLoop::<f32>::new(&(cfg).cast(), &init(ts(0.0), h0, v0)).unwrap();
        let mut a64 = AidedLoop::<f64>::new(&(cfg).cast(), &init(ts(0.0), h0, v0)).unwrap();
        let mut v_prev = v0;
        let bias = 0.05; // 5 mg
        let mut err_before_outage = Vec::new();
        for k in 1..=300_000u64 {
            let t = k as f64 * dt;
            let (h, v) = truth(t);
            let (hm, _) = truth(t - 0.5 * dt);
            let f = (v - v_prev) / dt + gravity(hm) + bias + normal(&mut rng, 0.05 / dt.sqrt());
            v_prev = v;
            let phase = t % 300.0;
            let out = (150.0..270.0).contains(&phase);
            let time = Timestamp::from_micros(k * 10_000);
            let b = (k % 4 == 0 && !out).then(|| BaroSample {
                time,
                altitude_m: h + normal(&mut rng, 1.0),
            });
            let vel = (k % 10 == 0 && !out).then(|| VelocitySample {
                time,
                vz_up_m_s: v + normal(&mut rng, 0.2),
            });
            let (eh, health) = if f32_loop {
                a32.step(
                    &ImuSample {
                        time,
                        specific_force_up_m_s2: f as f32,
                    },
                    b.map(|s| BaroSample {
                        time,
                        altitude_m: s.altitude_m as f32,
                    })
                    .as_ref(),
                    vel.map(|s| VelocitySample {
                        time,
                        vz_up_m_s: s.vz_up_m_s as f32,
                    })
                    .as_ref(),
                )
                .unwrap_or_else(|e| panic!("t {t}: {e}"));
                (a32.altitude_m().to_f64() - h, a32.health().state)
            } else {
                a64.step(
                    &ImuSample {
                        time,
                        specific_force_up_m_s2: f,
                    },
                    b.as_ref(),
                    vel.as_ref(),
                )
                .unwrap_or_else(|e| panic!("t {t}: {e}"));
                (a64.altitude_m() - h, a64.health().state)
            };
            // Just before each outage (after 150 s of aiding): on the truth, healthy.
            if (phase - 149.99).abs() < 0.005 && t > 300.0 {
                err_before_outage.push(eh.abs());
                assert_ne!(health, HealthState::NeedsReinitialisation, "t {t}");
            }
        }
        let c = if f32_loop {
            a32.aid_counters(Aid::Baro)
        } else {
            a64.aid_counters(Aid::Baro)
        };
        assert!(
            err_before_outage.iter().all(|&e| e < 10.0),
            "f32 {f32_loop}: {err_before_outage:?} {c:?}"
        );
        assert!(c.consecutive_rejected < 10, "{c:?}");
    }
}

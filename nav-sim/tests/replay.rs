//! Replay of recorded flight logs: the shipped real PX4 flight (CSV) and SITL ULog, and bad
//! logs that must give a clear error naming the file, the column or topic, and the line.

use nav_sim::replay::{replay, ReplayConfig};
use serde_json::Value;
use std::path::{Path, PathBuf};

/// The shipped logs: `$NAV_DATA_DIR`, else `shared/data` beside the repository.
fn data_dir() -> PathBuf {
    std::env::var_os("NAV_DATA_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../../shared/data"))
}

fn shipped(rel: &str) -> PathBuf {
    let p = data_dir().join(rel);
    assert!(
        p.exists(),
        "shipped flight log {} missing (set NAV_DATA_DIR to the folder with px4-sdlog2-csv/)",
        p.display()
    );
    p
}

fn config(name: &str) -> ReplayConfig {
    ReplayConfig::from_file(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("replay/{name}.toml")),
    )
    .unwrap()
}

fn out_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("nav-sim-replay-test-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

fn num(v: &Value, path: &[&str]) -> f64 {
    let mut x = v;
    for k in path {
        x = &x[*k];
    }
    x.as_f64().unwrap_or_else(|| panic!("{path:?} is {x}"))
}

fn refused_total(v: &Value) -> f64 {
    v.as_object()
        .map(|m| m.values().filter_map(Value::as_f64).sum())
        .unwrap_or(0.0)
}

/// Every IMU sample is accepted or refused with a stated reason, essentially all are
/// accepted, and both loops follow the autopilot's own estimate after convergence.
fn check_loops(s: &Value, max_alt_rms_m: f64, max_vz_rms_m_s: f64) {
    let imu_samples = num(s, &["streams", "imu", "samples"]);
    for name in ["classical", "aided"] {
        let l = &s["loops"][name];
        let accepted = num(l, &["imu_accepted"]);
        let refused = refused_total(&l["imu_refused"]);
        assert_eq!(
            accepted + refused,
            imu_samples,
            "{name}: every sample accounted for"
        );
        assert!(
            refused <= 0.001 * imu_samples,
            "{name}: {refused} of {imu_samples} IMU samples refused: {}",
            l["imu_refused"]
        );
        let alt = num(l, &["vs_autopilot", "alt_rms_m"]);
        let vz = num(l, &["vs_autopilot", "vz_rms_m_s"]);
        assert!(
            alt <= max_alt_rms_m,
            "{name}: altitude RMS to the autopilot {alt} m"
        );
        assert!(
            vz <= max_vz_rms_m_s,
            "{name}: V_z RMS to the autopilot {vz} m/s"
        );
        assert!(num(l, &["vs_autopilot", "samples"]) > 100.0);
    }
}

#[test]
fn real_px4_flight_csv_replays_close_to_the_autopilot() {
    let out = out_dir("sdlog2");
    let s = replay(&shipped("px4-sdlog2-csv"), &config("px4-sdlog2-csv"), &out).unwrap();
    // The log as its SOURCE.md describes it: 81 Hz IMU with jitter, 62 Hz baro, 5 Hz GNSS.
    let imu_rate = num(&s, &["streams", "imu", "rate_hz"]);
    assert!((70.0..90.0).contains(&imu_rate), "IMU rate {imu_rate}");
    let iv = &s["streams"]["imu"]["interval_s"];
    assert!(
        num(iv, &["max"]) > 1.4 * num(iv, &["median"]),
        "the log has jitter: {iv}"
    );
    check_loops(&s, 1.0, 0.6);
    for f in ["summary.json", "timeseries.csv", "replay.png"] {
        assert!(out.join(f).metadata().unwrap().len() > 1000, "{f}");
    }
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn px4_sitl_ulog_replays_close_to_the_autopilot() {
    let out = out_dir("sitl");
    let s = replay(
        &shipped("px4-sitl-hop/px4_sitl_hop.ulg"),
        &config("px4-sitl-hop"),
        &out,
    )
    .unwrap();
    // Topics and rates as the log's SOURCE.md lists them.
    let rate = |k: &str| num(&s, &["streams", k, "rate_hz"]);
    assert!(
        (240.0..260.0).contains(&rate("imu")),
        "sensor_combined {}",
        rate("imu")
    );
    assert!(
        (18.0..22.0).contains(&rate("baro")),
        "vehicle_air_data {}",
        rate("baro")
    );
    assert!(
        (8.0..12.0).contains(&rate("estimate")),
        "vehicle_local_position {}",
        rate("estimate")
    );
    assert!(num(&s, &["streams", "gnss", "samples"]) > 300.0);
    check_loops(&s, 1.0, 0.5);
    let _ = std::fs::remove_dir_all(&out);
}

/// Writes a CSV log from the shipped one, transformed line by line.
fn derived_log(name: &str, edit: impl Fn(&str, usize, &str) -> Option<String>) -> PathBuf {
    let src = shipped("px4-sdlog2-csv");
    let dir = out_dir(&format!("log-{name}"));
    std::fs::create_dir_all(&dir).unwrap();
    for f in ["imu.csv", "baro.csv", "gnss.csv", "estimate.csv"] {
        let text = std::fs::read_to_string(src.join(f)).unwrap();
        let lines: Vec<String> = text
            .lines()
            .enumerate()
            .filter_map(|(i, l)| edit(f, i, l))
            .collect();
        std::fs::write(dir.join(f), lines.join("\n") + "\n").unwrap();
    }
    dir
}

/// [`replay_err`], then the derived log directory removed.
fn replay_err_and_remove(log: &Path) -> String {
    let e = replay_err(log);
    let _ = std::fs::remove_dir_all(log);
    e
}

fn replay_err(log: &Path) -> String {
    let out = out_dir("err");
    let e = replay(log, &ReplayConfig::default(), &out).expect_err("bad log accepted");
    let _ = std::fs::remove_dir_all(&out);
    format!("{e:#}")
}

#[test]
fn a_missing_column_is_named_with_its_file() {
    let log = derived_log("nocol", |f, i, l| {
        Some(if f == "baro.csv" && i == 0 {
            l.replace("baro_alt_m", "alt")
        } else {
            l.to_string()
        })
    });
    let e = replay_err(&log);
    assert!(
        e.contains("baro.csv") && e.contains("missing column `baro_alt_m`"),
        "{e}"
    );
}

#[test]
fn time_going_backwards_is_named_with_file_and_line() {
    let log = derived_log("backwards", |f, i, l| {
        Some(if f == "imu.csv" && i == 100 {
            // Time stamp of line 100 set before the previous line's.
            let mut parts: Vec<String> = l.split(',').map(str::to_string).collect();
            parts[0] = "0.5".into();
            parts.join(",")
        } else {
            l.to_string()
        })
    });
    let e = replay_err(&log);
    assert!(
        e.contains("imu.csv") && e.contains("line 101") && e.contains("backwards"),
        "{e}"
    );
}

#[test]
fn wrong_units_are_reported() {
    // Specific force logged in g instead of m/s².
    let log = derived_log("units", |f, i, l| {
        Some(if f == "imu.csv" && i > 0 {
            let mut parts: Vec<String> = l.split(',').map(str::to_string).collect();
            let v: f64 = parts[1].parse().unwrap();
            parts[1] = format!("{}", v / 9.80665);
            parts.join(",")
        } else {
            l.to_string()
        })
    });
    let e = replay_err(&log);
    assert!(
        e.contains("imu.csv") && e.contains("f_down_m_s2") && e.contains("looks like g"),
        "{e}"
    );
}

#[test]
fn a_missing_file_and_a_non_number_are_named() {
    let log = derived_log("nofile", |f, _, l| (f != "imu.csv").then(|| l.to_string()));
    std::fs::remove_file(log.join("imu.csv")).unwrap();
    let e = replay_err(&log);
    assert!(e.contains("imu.csv") && e.contains("missing"), "{e}");
    let log = derived_log("nan", |f, i, l| {
        Some(if f == "gnss.csv" && i == 7 {
            l.replacen(",", ",abc,", 1)
        } else {
            l.to_string()
        })
    });
    let e = replay_err(&log);
    assert!(
        e.contains("gnss.csv") && e.contains("line 8") && e.contains("not a number"),
        "{e}"
    );
}

#[test]
fn a_log_with_gaps_replays_what_it_can_and_reports_the_gaps() {
    // Two IMU dropouts of ≈ 1 s and ≈ 2 s, and a 3 s baro gap.
    let log = derived_log("gaps", |f, i, l| {
        let t: f64 = l
            .split(',')
            .next()
            .and_then(|x| x.parse().ok())
            .unwrap_or(-1.0);
        let drop = match f {
            "imu.csv" => (20.0..21.0).contains(&t) || (40.0..42.0).contains(&t),
            "baro.csv" => (30.0..33.0).contains(&t),
            _ => false,
        };
        (i == 0 || !drop).then(|| l.to_string())
    });
    let out = out_dir("gaps-out");
    let s = replay(&log, &config("px4-sdlog2-csv"), &out).unwrap();
    assert_eq!(
        num(&s, &["streams", "imu", "gap_count"]),
        2.0,
        "{}",
        s["streams"]["imu"]
    );
    assert_eq!(num(&s, &["streams", "baro", "gap_count"]), 1.0);
    let gaps = s["streams"]["imu"]["gaps"].as_array().unwrap();
    assert!((num(&gaps[1], &["length_s"]) - 2.0).abs() < 0.1, "{gaps:?}");
    // Over a gap the loops integrate the specific force they are given; afterwards they
    // converge again (the RMS includes the transient).
    check_loops(&s, 2.0, 1.0);
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn a_truncated_ulog_is_an_error_naming_the_file() {
    let src = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let dir = out_dir("trunc");
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("short.ulg");
    std::fs::write(&log, &src[..2000]).unwrap();
    let e = replay_err(&log);
    assert!(e.contains("short.ulg"), "{e}");
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------------
// Strapdown INS replay

use nav_sim::replay::source::{self, LogEvent};

/// Element `i` of a JSON array of numbers.
fn at(v: &Value, i: usize) -> f64 {
    v[i].as_f64().unwrap_or_else(|| panic!("[{i}] of {v}"))
}

/// Every IMU sample of the log is accepted or refused with a named reason, for both INS runs.
fn check_ins_accounting(s: &Value) {
    let imu = num(s, &["streams", "imu", "samples"]);
    for run in ["free", "relevelled"] {
        let r = &s["ins"][run];
        let accepted = num(r, &["imu_accepted"]);
        let refused = refused_total(&r["imu_refused"]);
        assert_eq!(accepted + refused, imu, "{run}: {}", r["imu_refused"]);
        assert!(accepted > 0.9 * imu, "{run}: {accepted} of {imu} accepted");
    }
}

/// The SITL ULog has `sensor_combined` gyro and accelerometer at 250 Hz and EKF2's attitude:
/// the free INS's roll and pitch difference to the autopilot stays within 3σ of the drift the
/// log's own gyro predicts (white noise 3.8e-4 rad/s/√Hz and bias 4e-4 rad/s measured at rest,
/// nav-sim/replay/px4-sitl-hop.toml), and is a real drift, not a silently re-levelled one.
#[test]
fn sitl_ulog_ins_drifts_as_its_gyro_predicts() {
    let out = out_dir("sitl-ins");
    let cfg = config("px4-sitl-hop");
    let s = replay(&shipped("px4-sitl-hop/px4_sitl_hop.ulg"), &cfg, &out).unwrap();
    let ins = &s["ins"];
    assert_eq!(ins["status"], "Available", "{ins}");
    assert_eq!(ins["frame_check"]["result"], "GravityUp");
    // Gravity at rest through the logged quaternion: (0, 0, −g) within 0.05 m/s² horizontally.
    let f = &ins["frame_check"]["f_ned_mean_m_s2"];
    assert!(
        at(f, 0).hypot(at(f, 1)) < 0.05 && (at(f, 2) + 9.81).abs() < 0.05,
        "{f}"
    );
    check_ins_accounting(&s);
    // Refusals: only the second before the start (250 Hz), no gap, no nav-core refusal.
    let refused = &ins["free"]["imu_refused"];
    assert_eq!(refused.as_object().unwrap().len(), 1, "{refused}");
    assert!(
        (200.0..=300.0).contains(&num(refused, &["NotInitialised"])),
        "{refused}"
    );
    assert_eq!(num(&ins["free"], &["initialisations"]), 1.0);
    let horizons = ins["free"]["at_horizons"].as_array().unwrap();
    assert_eq!(horizons.len(), cfg.ins.report_after_s.len(), "{horizons:?}");
    for h in horizons {
        let t = num(h, &["compared_after_s"]);
        let sigma_deg = cfg.ins.expected_attitude_sigma_rad(t).to_degrees();
        for axis in ["roll", "pitch"] {
            let d = num(h, &["attitude_difference_deg", axis]).abs();
            assert!(
                d <= 3.0 * sigma_deg,
                "{axis} after {t} s: {d}° > 3σ = {}°",
                3.0 * sigma_deg
            );
        }
    }
    // After 20 s the roll difference is a drift of the free INS (the autopilot estimates a
    // −3.4e-4 rad/s x-gyro bias: −0.39° in 20 s).
    let at20 = horizons
        .iter()
        .find(|h| num(h, &["after_s"]) == 20.0)
        .unwrap();
    let roll20 = num(at20, &["attitude_difference_deg", "roll"]);
    assert!((-0.8..-0.2).contains(&roll20), "roll after 20 s: {roll20}°");
    // The re-levelled INS agrees with the autopilot at the end of its 5 s windows to within the
    // 5 s drift of the same gyro (3σ), in roll and pitch.
    let w = &ins["relevelled"]["at_window_end"];
    let sigma5 = cfg.ins.expected_attitude_sigma_rad(5.0).to_degrees();
    for axis in ["roll", "pitch"] {
        let m = num(w, &["attitude_vs_autopilot", axis, "max_abs_deg"]);
        assert!(
            m <= 3.0 * sigma5,
            "re-levelled {axis}: {m}° > {}°",
            3.0 * sigma5
        );
    }
    assert!(num(&ins["relevelled"], &["windows"]) >= 4.0);
    // Velocity: the free INS's horizontal drift after 20 s within 3σ of the prediction; the
    // re-levelled one's within 0.2 m/s of the autopilot's at every window end.
    let v20 = &at20["velocity_difference_vs_autopilot_ned_m_s"];
    let sv = num(at20, &["expected_horizontal_velocity_drift_1sigma_m_s"]);
    for k in [0, 1] {
        assert!(
            at(v20, k).abs() <= 3.0 * sv,
            "v[{k}] after 20 s: {v20} (σ {sv})"
        );
    }
    for axis in ["north", "east"] {
        let m = num(w, &["velocity_vs_autopilot", axis, "max_abs_m_s"]);
        assert!(m < 0.2, "re-levelled V_{axis} at window end: {m} m/s");
    }
    // The CSV has the INS columns and the INS plot was drawn.
    let csv = std::fs::read_to_string(out.join("timeseries.csv")).unwrap();
    let header = csv.lines().next().unwrap();
    for c in [
        "ins_droll_deg",
        "ins_vn_m_s",
        "relevelled_dyaw_deg",
        "ap_yaw_deg",
    ] {
        assert!(header.split(',').any(|h| h == c), "{c} missing: {header}");
    }
    assert!(out.join("ins.png").metadata().unwrap().len() > 10_000);
    let _ = std::fs::remove_dir_all(&out);
}

/// The real flight's `imu.csv` has no gyro columns: the INS is reported not available with the
/// reason, the vertical loops are unaffected, and the gravity check still verifies the logged
/// quaternion's convention on the real data (the conjugate would tilt gravity by ≈ 17°).
#[test]
fn real_csv_without_gyro_reports_the_ins_not_available() {
    let out = out_dir("sdlog2-ins");
    let s = replay(&shipped("px4-sdlog2-csv"), &config("px4-sdlog2-csv"), &out).unwrap();
    let ins = &s["ins"];
    assert_eq!(ins["status"], "NotAvailable", "{ins}");
    assert_eq!(ins["reason"], "NoGyro");
    assert!(
        ins["detail"].as_str().unwrap().contains("gyro_x_rad_s"),
        "{ins}"
    );
    // Every IMU sample accounted for, by that reason.
    assert_eq!(
        num(ins, &["imu_refused", "NoGyro"]),
        num(&s, &["streams", "imu", "samples"])
    );
    let fc = &ins["frame_check"];
    assert_eq!(fc["result"], "GravityUp", "{fc}");
    let h = |k: &str| at(&fc[k], 0).hypot(at(&fc[k], 1));
    assert!(h("f_ned_mean_m_s2") < 0.3, "{fc}");
    assert!(h("f_ned_mean_with_conjugate_q_m_s2") > 2.0, "{fc}");
    assert!(!out.join("ins.png").exists());
    check_loops(&s, 1.0, 0.6);
    let _ = std::fs::remove_dir_all(&out);
}

/// Writes the SITL ULog as a CSV log in the documented schema (IMU rows carry the latest
/// attitude), with `edit_imu` applied to each `imu.csv` row's body accelerometer.
fn ulog_as_csv(name: &str, edit_acc: impl Fn([f64; 3]) -> [f64; 3]) -> PathBuf {
    let dir = out_dir(&format!("ulog-csv-{name}"));
    std::fs::create_dir_all(&dir).unwrap();
    let mut imu = String::from("t_s,f_down_m_s2,acc_x_m_s2,acc_y_m_s2,acc_z_m_s2,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,q_w,q_x,q_y,q_z\n");
    let mut baro = String::from("t_s,baro_alt_m\n");
    let mut gnss = String::from(
        "t_s,gnss_alt_m,gnss_vd_m_s,gnss_lat_deg,gnss_lon_deg,gnss_vn_m_s,gnss_ve_m_s\n",
    );
    let mut est = String::from("t_s,est_alt_m,est_vd_m_s,est_vn_m_s,est_ve_m_s\n");
    let mut q = None;
    let src = source::open(&shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let nan = f64::NAN;
    for ev in src {
        match ev.unwrap() {
            LogEvent::Attitude { q_b_n, .. } => q = Some(q_b_n),
            LogEvent::Imu {
                t,
                f_down_m_s2,
                body,
            } => {
                let (Some(q), Some(b)) = (q, body) else {
                    continue;
                };
                let a = edit_acc(b.acc_b_m_s2);
                let g = b.gyro_b_rad_s.unwrap();
                imu += &format!(
                    "{},{f_down_m_s2},{},{},{},{},{},{},{},{},{},{}\n",
                    t.as_secs_f64(),
                    a[0],
                    a[1],
                    a[2],
                    g[0],
                    g[1],
                    g[2],
                    q[0],
                    q[1],
                    q[2],
                    q[3]
                );
            }
            LogEvent::Baro { t, alt_m } => baro += &format!("{},{alt_m}\n", t.as_secs_f64()),
            LogEvent::Gnss {
                t,
                alt_m,
                vd_m_s,
                lat_lon,
                v_ne,
            } => {
                let (la, lo) = lat_lon.map_or((nan, nan), |p| (p.lat_deg, p.lon_deg));
                let (vn, ve) = v_ne.map_or((nan, nan), |v| (v.vn_m_s, v.ve_m_s));
                gnss += &format!("{},{alt_m},{vd_m_s},{la},{lo},{vn},{ve}\n", t.as_secs_f64());
            }
            LogEvent::Estimate {
                t,
                alt_m,
                vd_m_s,
                v_ne,
            } => {
                let (vn, ve) = v_ne.map_or((nan, nan), |v| (v.vn_m_s, v.ve_m_s));
                est += &format!("{},{alt_m},{vd_m_s},{vn},{ve}\n", t.as_secs_f64());
            }
        }
    }
    for (f, text) in [
        ("imu.csv", imu),
        ("baro.csv", baro),
        ("gnss.csv", gnss),
        ("estimate.csv", est),
    ] {
        std::fs::write(dir.join(f), text).unwrap();
    }
    dir
}

/// The same samples as CSV (gyro, accelerometer, quaternion, GNSS and autopilot velocity
/// columns) give the same INS as the ULog: the same samples accepted (up to the start), and the free INS's
/// roll and pitch difference at rest (5 and 10 s) and the yaw difference's growth equal to 0.02°.
#[test]
fn the_sitl_log_as_csv_gives_the_same_ins() {
    let cfg = config("px4-sitl-hop");
    let out = out_dir("sitl-ins-ulog");
    let a = replay(&shipped("px4-sitl-hop/px4_sitl_hop.ulg"), &cfg, &out).unwrap();
    let log = ulog_as_csv("same", |a| a);
    let out2 = out_dir("sitl-ins-csv");
    let b = replay(&log, &cfg, &out2).unwrap();
    assert_eq!(b["ins"]["status"], "Available", "{}", b["ins"]);
    check_ins_accounting(&b);
    // The ULog's INS starts at an attitude sample (20 Hz), the CSV's at an IMU row carrying
    // the same attitude: at most one 52 ms attitude interval (13 IMU samples) apart.
    let accepted = |s: &Value| num(s, &["ins", "free", "imu_accepted"]);
    assert!(
        (accepted(&a) - accepted(&b)).abs() <= 13.0,
        "{} vs {}",
        accepted(&a),
        accepted(&b)
    );
    let ha = a["ins"]["free"]["at_horizons"].as_array().unwrap();
    let hb = b["ins"]["free"]["at_horizons"].as_array().unwrap();
    let d = |h: &[Value], k: usize, axis: &str| num(&h[k], &["attitude_difference_deg", axis]);
    for k in [1, 2] {
        for axis in ["roll", "pitch"] {
            let (x, y) = (d(ha, k, axis), d(hb, k, axis));
            assert!(
                (x - y).abs() < 0.02,
                "{axis} after {} s: {x} vs {y}",
                ha[k]["after_s"]
            );
        }
    }
    // Yaw: the autopilot's heading still moves ≈ 0.1° per attitude sample just after its reset
    // at 0.8 s, so the two starts differ by a constant; its growth from 5 to 10 s is the same.
    let (x, y) = (
        d(ha, 2, "yaw") - d(ha, 1, "yaw"),
        d(hb, 2, "yaw") - d(hb, 1, "yaw"),
    );
    assert!((x - y).abs() < 0.02, "yaw growth 5 → 10 s: {x} vs {y}");
    // GNSS horizontal velocity read from the CSV columns.
    assert!(num(&b, &["ins", "free", "velocity_vs_gnss", "samples"]) > 300.0);
    for d in [out, out2, log] {
        let _ = std::fs::remove_dir_all(d);
    }
}

/// An accelerometer logged in forward-left-up axes fails the gravity check: the INS is not
/// run (reason and the averages reported), the vertical loops still are.
#[test]
fn body_axes_not_frd_fail_the_frame_check() {
    let log = ulog_as_csv("flu", |a| [a[0], -a[1], -a[2]]);
    let out = out_dir("flu-out");
    let s = replay(&log, &config("px4-sitl-hop"), &out).unwrap();
    assert_eq!(s["ins"]["status"], "NotAvailable", "{}", s["ins"]);
    assert_eq!(s["ins"]["reason"], "FrameCheckFailed");
    assert!(s["ins"]["detail"]
        .as_str()
        .unwrap()
        .contains("forward-right-down"));
    check_loops(&s, 1.0, 0.5);
    for d in [out, log] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn bad_gyro_columns_are_named() {
    // Part of the gyro group.
    let log = derived_log("gyro-part", |f, i, l| {
        Some(match (f, i) {
            ("imu.csv", 0) => format!("{l},gyro_x_rad_s"),
            ("imu.csv", _) => format!("{l},0.01"),
            _ => l.to_string(),
        })
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("imu.csv") && e.contains("missing column `gyro_y_rad_s`"),
        "{e}"
    );
    // A gyro value that is not a number.
    let log = derived_log("gyro-nan", |f, i, l| {
        Some(match (f, i) {
            ("imu.csv", 0) => format!("{l},gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s"),
            ("imu.csv", 50) => format!("{l},0.01,x0.2,0.0"),
            ("imu.csv", _) => format!("{l},0.01,0.02,0.0"),
            _ => l.to_string(),
        })
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("imu.csv")
            && e.contains("line 51")
            && e.contains("`gyro_y_rad_s`")
            && e.contains("not a number"),
        "{e}"
    );
    // A quaternion that is not a unit quaternion.
    let log = derived_log("q-norm", |f, i, l| {
        Some(if f == "imu.csv" && i == 20 {
            let mut p: Vec<String> = l.split(',').map(str::to_string).collect();
            p[5] = "2.0".into();
            p.join(",")
        } else {
            l.to_string()
        })
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("imu.csv") && e.contains("line 21") && e.contains("unit quaternion"),
        "{e}"
    );
}

/// Irregular intervals, a dropout and a glitch as they come (the SITL samples as CSV): single
/// dropped rows (8 ms intervals) are integrated over their actual interval, a 1 s dropout is a
/// gap (that sample refused, the runs re-initialised at the next attitude sample), and a
/// 1000 rad/s gyro glitch is refused by nav-core by name, the next sample integrating over both
/// intervals.
#[test]
fn ins_takes_irregular_intervals_gaps_and_glitches_as_they_come() {
    let log = ulog_as_csv("gaps", |a| a);
    let text = std::fs::read_to_string(log.join("imu.csv")).unwrap();
    let mut lines: Vec<String> = Vec::new();
    let (mut dropped, mut glitched) = (0, 0);
    for (i, l) in text.lines().enumerate() {
        let t: f64 = l.split(',').next().unwrap().parse().unwrap_or(-1.0);
        let rel = t - 1_710_773_350.354;
        if i > 0 && (12.0..13.0).contains(&rel) {
            continue; // a 1 s dropout
        }
        if i > 0 && rel > 3.0 && i % 97 == 0 {
            dropped += 1;
            continue; // single dropped samples: 8 ms intervals
        }
        if i > 0 && glitched == 0 && rel > 15.0 {
            glitched += 1;
            let mut p: Vec<String> = l.split(',').map(str::to_string).collect();
            p[5] = "1000.0".into();
            lines.push(p.join(","));
            continue;
        }
        lines.push(l.to_string());
    }
    assert!(dropped > 50 && glitched == 1);
    std::fs::write(log.join("imu.csv"), lines.join("\n") + "\n").unwrap();
    let out = out_dir("gaps-ins-out");
    let s = replay(&log, &config("px4-sitl-hop"), &out).unwrap();
    check_ins_accounting(&s);
    for run in ["free", "relevelled"] {
        let r = &s["ins"][run];
        let refused = r["imu_refused"].as_object().unwrap();
        assert_eq!(num(r, &["imu_refused", "Gap"]), 1.0, "{run}: {refused:?}");
        assert_eq!(num(r, &["reinitialised_after_gap"]), 1.0);
        let gap = &r["gaps"][0];
        assert!((num(gap, &["length_s"]) - 1.0).abs() < 0.01, "{gap}");
        let glitch = refused
            .iter()
            .filter(|(k, _)| k.contains("InputOutOfRange") && k.contains("delta_theta_rad"))
            .map(|(_, v)| v.as_f64().unwrap())
            .sum::<f64>();
        assert_eq!(glitch, 1.0, "{run}: {refused:?}");
        // Nothing else refused but the samples before the start and between the gap and the
        // next attitude sample (≤ 52 ms at 250 Hz).
        let not_init = num(r, &["imu_refused", "NotInitialised"]);
        assert_eq!(refused.len(), 3, "{run}: {refused:?}");
        assert!(not_init < 300.0, "{run}: {refused:?}");
    }
    // The free INS still drifts as its gyro predicts after re-initialisation (roll and pitch
    // within 3σ of the prediction over the whole run: its largest difference).
    let cfg = config("px4-sitl-hop");
    let sigma = cfg.ins.expected_attitude_sigma_rad(20.0).to_degrees();
    for axis in ["roll", "pitch"] {
        let m = num(
            &s,
            &["ins", "free", "attitude_vs_autopilot", axis, "max_abs_deg"],
        );
        assert!(m <= 3.0 * sigma, "{axis}: {m}°");
    }
    for d in [out, log] {
        let _ = std::fs::remove_dir_all(d);
    }
}

#[test]
fn an_ins_setting_out_of_range_is_named() {
    let mut cfg = config("px4-sitl-hop");
    cfg.ins.max_interval_s = 2.0;
    let out = out_dir("ins-cfg");
    let e = replay(&shipped("px4-sitl-hop/px4_sitl_hop.ulg"), &cfg, &out)
        .expect_err("max_interval_s beyond the mechanization's 1 s accepted");
    assert!(format!("{e:#}").contains("[ins] max_interval_s"), "{e:#}");
    let mut cfg = config("px4-sitl-hop");
    cfg.ins.report_after_s = vec![10.0, 5.0];
    let e = replay(&shipped("px4-sitl-hop/px4_sitl_hop.ulg"), &cfg, &out).expect_err("accepted");
    assert!(format!("{e:#}").contains("report_after_s"), "{e:#}");
    let _ = std::fs::remove_dir_all(&out);
}

// ---------------------------------------------------------------------------------------------
// Wrong units, values that are not finite, bad ULogs

/// Writes a copy of the shipped log with column `col` of `file` replaced by `f(row)` (data
/// rows split at commas, `t_s` first).
fn edited_column(
    name: &str,
    file: &'static str,
    col: usize,
    f: impl Fn(&[&str]) -> String,
) -> PathBuf {
    derived_log(name, move |fname, i, l| {
        Some(if fname == file && i > 0 {
            let p: Vec<&str> = l.split(',').collect();
            let mut q: Vec<String> = p.iter().map(|s| s.to_string()).collect();
            q[col] = f(&p);
            q.join(",")
        } else {
            l.to_string()
        })
    })
}

#[test]
fn baro_in_hpa_or_feet_is_a_wrong_unit_named_with_its_file() {
    // The real log's `baro_press_pa` (third column) in hPa where the altitude should be.
    let log = edited_column("hpa", "baro.csv", 1, |p| {
        format!("{}", p[2].parse::<f64>().unwrap() / 100.0)
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("baro.csv") && e.contains("`baro_alt_m`") && e.contains("hPa"),
        "{e}"
    );
    let log = edited_column("feet", "baro.csv", 1, |p| {
        format!("{}", p[1].parse::<f64>().unwrap() / 0.3048)
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("baro.csv") && e.contains("`baro_alt_m`") && e.contains("feet"),
        "{e}"
    );
    // The shipped log passes the same check, and the summary says what it was judged on.
    let out = out_dir("units-ok");
    let s = replay(&shipped("px4-sdlog2-csv"), &config("px4-sdlog2-csv"), &out).unwrap();
    let u = &s["baro_units_check"];
    assert_eq!(u["result"], "Consistent", "{u}");
    let k = num(u, &["baro_m_per_reference_m"]);
    assert!((0.8..1.2).contains(&k), "{u}");
    let _ = std::fs::remove_dir_all(&out);
}

#[test]
fn time_not_in_seconds_is_a_wrong_unit_named_with_its_file() {
    let scaled = |name: &str, which: &'static str, factor: f64| {
        derived_log(name, move |f, i, l| {
            Some(if (which == "all" || f == which) && i > 0 {
                let mut p: Vec<String> = l.split(',').map(str::to_string).collect();
                p[0] = format!("{}", p[0].parse::<f64>().unwrap() * factor);
                p.join(",")
            } else {
                l.to_string()
            })
        })
    };
    // Every file in µs.
    let log = scaled("us", "all", 1.0e6);
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("imu.csv") && e.contains("`t_s`") && e.contains("microseconds"),
        "{e}"
    );
    // Only the baro in ms.
    let log = scaled("ms", "baro.csv", 1.0e3);
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("baro.csv") && e.contains("`t_s`") && e.contains("milliseconds"),
        "{e}"
    );
}

/// A value that is not a number is an error naming file, line and column; `nan` (a logger's
/// "invalid") is a sample refused by the loops with the reason, and listed by file and column
/// with its first line. A `nan` time stamp is an error.
#[test]
fn nan_values_are_refused_by_name_and_listed_nan_time_is_an_error() {
    let log = derived_log("nanrows", |f, i, l| {
        let mut p: Vec<String> = l.split(',').map(str::to_string).collect();
        match (f, i) {
            ("imu.csv", 200) | ("baro.csv", 300) | ("baro.csv", 301) => p[1] = "nan".into(),
            _ => {}
        }
        Some(p.join(","))
    });
    let out = out_dir("nanrows-out");
    let s = replay(&log, &config("px4-sdlog2-csv"), &out).unwrap();
    let found = s["log_findings"]["non_finite_values"].as_array().unwrap();
    assert_eq!(found.len(), 2, "{found:?}");
    assert_eq!(found[0]["file"], "imu.csv");
    assert_eq!(found[0]["column"], "f_down_m_s2");
    assert_eq!(num(&found[0], &["rows"]), 1.0);
    assert_eq!(num(&found[0], &["first_line"]), 201.0);
    assert_eq!(found[1]["file"], "baro.csv");
    assert_eq!(num(&found[1], &["rows"]), 2.0);
    assert_eq!(num(&found[1], &["first_line"]), 301.0);
    for name in ["classical", "aided"] {
        let l = &s["loops"][name];
        let nonfinite = |m: &Value| {
            m.as_object()
                .unwrap()
                .iter()
                .filter(|(k, _)| k.contains("NonFiniteInput"))
                .map(|(_, v)| v.as_f64().unwrap())
                .sum::<f64>()
        };
        assert_eq!(
            nonfinite(&l["imu_refused"]),
            1.0,
            "{name}: {}",
            l["imu_refused"]
        );
        assert_eq!(
            nonfinite(&l["aid_samples_refused"]),
            2.0,
            "{name}: {}",
            l["aid_samples_refused"]
        );
    }
    check_loops(&s, 1.0, 0.6);
    let _ = std::fs::remove_dir_all(&out);
    let _ = std::fs::remove_dir_all(&log);
    let log = derived_log("nantime", |f, i, l| {
        Some(if f == "gnss.csv" && i == 9 {
            let mut p: Vec<&str> = l.split(',').collect();
            p[0] = "nan";
            p.join(",")
        } else {
            l.to_string()
        })
    });
    let e = replay_err_and_remove(&log);
    assert!(
        e.contains("gnss.csv") && e.contains("line 10") && e.contains("`t_s`"),
        "{e}"
    );
}

/// The messages of a ULog after its 16-byte header: (type, payload).
fn ulog_messages(d: &[u8]) -> Vec<(u8, &[u8])> {
    let mut out = Vec::new();
    let mut i = 16;
    while i + 3 <= d.len() {
        let size = u16::from_le_bytes([d[i], d[i + 1]]) as usize;
        out.push((d[i + 2], &d[i + 3..i + 3 + size]));
        i += 3 + size;
    }
    out
}

fn push_message(buf: &mut Vec<u8>, ty: u8, payload: &[u8]) {
    buf.extend_from_slice(&(payload.len() as u16).to_le_bytes());
    buf.push(ty);
    buf.extend_from_slice(payload);
}

/// The message ids subscribed under `topic` (an `A` message: multi id, msg id, name).
fn msg_ids(msgs: &[(u8, &[u8])], topic: &str) -> Vec<u16> {
    msgs.iter()
        .filter(|(t, p)| *t == b'A' && &p[3..] == topic.as_bytes())
        .map(|(_, p)| u16::from_le_bytes([p[1], p[2]]))
        .collect()
}

fn data_id(p: &[u8]) -> u16 {
    u16::from_le_bytes([p[0], p[1]])
}

/// Writes the shipped SITL ULog with its messages passed through `edit` (`None` drops one).
fn edited_ulog(name: &str, edit: impl Fn(usize, u8, &[u8]) -> Option<Vec<u8>>) -> PathBuf {
    let d = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let mut buf = d[..16].to_vec();
    for (k, (ty, p)) in ulog_messages(&d).into_iter().enumerate() {
        if let Some(p) = edit(k, ty, p) {
            push_message(&mut buf, ty, &p);
        }
    }
    let dir = out_dir(&format!("ulog-{name}"));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join(format!("{name}.ulg"));
    std::fs::write(&path, buf).unwrap();
    path
}

#[test]
fn a_ulog_without_a_needed_topic_is_named() {
    let d = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let ids = msg_ids(&ulog_messages(&d), "vehicle_air_data");
    assert!(!ids.is_empty());
    let log = edited_ulog("no-air-data", |_, ty, p| match ty {
        b'A' if &p[3..] == b"vehicle_air_data" => None,
        b'D' if ids.contains(&data_id(p)) => None,
        _ => Some(p.to_vec()),
    });
    let e = replay_err(&log);
    let _ = std::fs::remove_dir_all(log.parent().unwrap());
    assert!(
        e.contains("no-air-data.ulg")
            && e.contains("topic `vehicle_air_data` missing")
            && e.contains("baro_alt_meter"),
        "{e}"
    );
}

#[test]
fn a_ulog_timestamp_going_backwards_is_named_with_topic_and_field() {
    let d = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let msgs = ulog_messages(&d);
    let ids = msg_ids(&msgs, "sensor_combined");
    // The 600th sensor_combined sample stamped 10 ms before the 599th.
    let stamps: Vec<(usize, u64)> = msgs
        .iter()
        .enumerate()
        .filter(|(_, (t, p))| *t == b'D' && ids.contains(&data_id(p)))
        .map(|(k, (_, p))| (k, u64::from_le_bytes(p[2..10].try_into().unwrap())))
        .collect();
    let (target, prev) = (stamps[599].0, stamps[598].1);
    let log = edited_ulog("backwards", |k, _, p| {
        let mut p = p.to_vec();
        if k == target {
            p[2..10].copy_from_slice(&(prev - 10_000).to_le_bytes());
        }
        Some(p)
    });
    let e = replay_err(&log);
    let _ = std::fs::remove_dir_all(log.parent().unwrap());
    assert!(
        e.contains("backwards.ulg")
            && e.contains("topic `sensor_combined`")
            && e.contains("`timestamp` goes backwards"),
        "{e}"
    );
}

/// A ULog cut inside a message after the data began (a power loss) replays what is complete
/// and says so; cut inside the definitions it is an error naming the file.
#[test]
fn a_ulog_cut_short_replays_what_is_complete() {
    let src = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let dir = out_dir("cut");
    std::fs::create_dir_all(&dir).unwrap();
    let log = dir.join("cut.ulg");
    // 70 % of the file, 5 bytes into a message.
    let mut i = 16;
    while i < src.len() * 7 / 10 {
        i += 3 + u16::from_le_bytes([src[i], src[i + 1]]) as usize;
    }
    std::fs::write(&log, &src[..i + 5]).unwrap();
    let out = dir.join("out");
    let s = replay(&log, &config("px4-sitl-hop"), &out).unwrap();
    let tr = &s["log_findings"]["truncated"];
    assert!(num(tr, &["last_sample_us"]) > 0.0, "{tr}");
    let full = 7762.0;
    let imu = num(&s, &["streams", "imu", "samples"]);
    assert!((0.5 * full..0.9 * full).contains(&imu), "{imu} IMU samples");
    check_loops(&s, 1.0, 0.5);
    let _ = std::fs::remove_dir_all(&dir);
}

// ---------------------------------------------------------------------------------------------
// Hour-long logs: constant memory

/// Peak resident set of this process so far, kB (Linux `VmHWM`).
fn peak_rss_kb() -> u64 {
    std::fs::read_to_string("/proc/self/status")
        .unwrap()
        .lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse().ok())
        .unwrap()
}

/// A synthetic hour of CSV log: 1 kHz IMU with gyro and attitude columns, 50 Hz baro and
/// autopilot estimate, 5 Hz GNSS, a climb-and-descend altitude profile; returns its size, B.
fn write_hour_csv(dir: &Path) -> u64 {
    use std::io::Write;
    std::fs::create_dir_all(dir).unwrap();
    let file = |n: &str, header: &str| {
        let mut w = std::io::BufWriter::new(std::fs::File::create(dir.join(n)).unwrap());
        writeln!(w, "{header}").unwrap();
        w
    };
    let mut imu = file("imu.csv", "t_s,f_down_m_s2,acc_x_m_s2,acc_y_m_s2,acc_z_m_s2,gyro_x_rad_s,gyro_y_rad_s,gyro_z_rad_s,q_w,q_x,q_y,q_z");
    let mut baro = file("baro.csv", "t_s,baro_alt_m");
    let mut gnss = file("gnss.csv", "t_s,gnss_alt_m,gnss_vd_m_s");
    let mut est = file("estimate.csv", "t_s,est_alt_m,est_vd_m_s");
    // Seeded uniform noise (xorshift), zero mean.
    let mut state = 0x2545_f491_4f6c_dd1d_u64;
    let mut noise = move |a: f64| {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        a * ((state >> 11) as f64 / (1u64 << 53) as f64 - 0.5)
    };
    let (w, amp) = (2.0 * std::f64::consts::PI / 120.0, 20.0);
    let g = 9.806;
    for k in 0..(3600 * 1000) {
        let t = 10.0 + k as f64 * 0.001;
        let (h, v, a) = (
            100.0 + amp * (w * t).sin(),
            amp * w * (w * t).cos(),
            -amp * w * w * (w * t).sin(),
        );
        let f_down = -(g + a) + noise(0.1);
        writeln!(
            imu,
            "{t:.6},{f_down:.6},{:.6},{:.6},{f_down:.6},{:.6},{:.6},{:.6},1,0,0,0",
            noise(0.1),
            noise(0.1),
            noise(1e-3),
            noise(1e-3),
            noise(1e-3)
        )
        .unwrap();
        if k % 20 == 0 {
            writeln!(baro, "{t:.6},{:.4}", h + 150.0 + noise(1.0)).unwrap();
            writeln!(est, "{t:.6},{h:.4},{:.4}", -v).unwrap();
        }
        if k % 200 == 0 {
            writeln!(
                gnss,
                "{t:.6},{:.4},{:.4}",
                h + 30.0 + noise(2.0),
                -v + noise(0.2)
            )
            .unwrap();
        }
    }
    ["imu.csv", "baro.csv", "gnss.csv", "estimate.csv"]
        .iter()
        .map(|f| dir.join(f).metadata().unwrap().len())
        .sum()
}

/// The shipped SITL ULog tiled to two hours (232 copies of its data messages, the time stamps
/// of the replayed topics shifted by the log's span per copy); returns its size, B.
fn write_hour_ulog(path: &Path) -> u64 {
    use std::io::Write;
    let d = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let msgs = ulog_messages(&d);
    let topics = [
        "sensor_combined",
        "vehicle_attitude",
        "vehicle_air_data",
        "vehicle_gps_position",
        "vehicle_local_position",
    ];
    // Ids whose payload starts with `timestamp` (and `timestamp_sample`: all but the first).
    let with_sample: Vec<u16> = topics[1..].iter().flat_map(|t| msg_ids(&msgs, t)).collect();
    let ids: Vec<u16> = topics.iter().flat_map(|t| msg_ids(&msgs, t)).collect();
    let stamps: Vec<u64> = msgs
        .iter()
        .filter(|(t, p)| *t == b'D' && ids.contains(&data_id(p)))
        .map(|(_, p)| u64::from_le_bytes(p[2..10].try_into().unwrap()))
        .collect();
    let span = stamps.iter().max().unwrap() - stamps.iter().min().unwrap() + 4_000;
    let copies = 7_200_000_000 / span + 1;
    let mut w = std::io::BufWriter::new(std::fs::File::create(path).unwrap());
    w.write_all(&d[..16]).unwrap();
    let mut buf = Vec::new();
    for (ty, p) in &msgs {
        buf.clear();
        push_message(&mut buf, *ty, p);
        w.write_all(&buf).unwrap();
    }
    for c in 1..copies {
        for (ty, p) in &msgs {
            if *ty != b'D' {
                continue;
            }
            let mut p = p.to_vec();
            let id = data_id(&p);
            if ids.contains(&id) {
                let shift = |p: &mut [u8], at: usize| {
                    let t = u64::from_le_bytes(p[at..at + 8].try_into().unwrap());
                    p[at..at + 8].copy_from_slice(&(t + c * span).to_le_bytes());
                };
                shift(&mut p, 2);
                if with_sample.contains(&id) {
                    shift(&mut p, 10);
                }
            }
            buf.clear();
            push_message(&mut buf, b'D', &p);
            w.write_all(&buf).unwrap();
        }
    }
    w.flush().unwrap();
    path.metadata().unwrap().len()
}

/// Logs of an hour and more, hundreds of MB, replay in memory that does not grow with the
/// log: the peak resident set stays far below the log's size (a 1 h CSV log at 1 kHz and a
/// 2 h ULog; both loops and the INS).
/// Run alone (`cargo test -p nav-sim --test replay -- --ignored hour_long`): the peak is the
/// process's. `NAV_LONG_LOG_DIR` keeps the generated logs there (for `/usr/bin/time -v`).
#[test]
#[ignore = "writes ≈ 650 MB of logs and replays three hours of flight"]
fn hour_long_logs_replay_in_constant_memory() {
    let keep = std::env::var_os("NAV_LONG_LOG_DIR").map(PathBuf::from);
    let dir = keep.clone().unwrap_or_else(|| out_dir("hour"));
    let csv_dir = dir.join("hour-csv");
    let csv_bytes = write_hour_csv(&csv_dir);
    let ulog = dir.join("hour.ulg");
    let ulog_bytes = write_hour_ulog(&ulog);
    let before = peak_rss_kb();
    let mut cfg = config("px4-sdlog2-csv");
    cfg.csv_interval_s = 1.0;
    let out = dir.join("out-csv");
    let s = replay(&csv_dir, &cfg, &out).unwrap();
    let after_csv = peak_rss_kb();
    // The loops follow the synthetic truth (the estimate columns) over the hour.
    assert_eq!(num(&s, &["streams", "imu", "samples"]), 3_600_000.0);
    check_loops(&s, 1.0, 0.3);
    let mut cfg = config("px4-sitl-hop");
    cfg.csv_interval_s = 1.0;
    let out2 = dir.join("out-ulog");
    let s2 = replay(&ulog, &cfg, &out2).unwrap();
    let after_ulog = peak_rss_kb();
    let imu = num(&s2, &["streams", "imu", "samples"]);
    assert!(imu > 250.0 * 7100.0, "{imu}");
    eprintln!(
        "CSV log {:.0} MB, ULog {:.0} MB; peak RSS: {} kB before, {} kB after the CSV, {} kB after the ULog",
        csv_bytes as f64 / 1e6,
        ulog_bytes as f64 / 1e6,
        before,
        after_csv,
        after_ulog
    );
    assert!(csv_bytes > 300_000_000 && ulog_bytes > 300_000_000);
    // Constant memory: the replay's peak stays below 64 MB whatever the log's size.
    assert!(after_ulog < 64 * 1024, "peak RSS {after_ulog} kB");
    if keep.is_none() {
        let _ = std::fs::remove_dir_all(&dir);
    }
}

/// `nan` in a ULog field the loops read is refused by the loops by name and listed by topic,
/// field and first time stamp.
#[test]
fn nan_values_in_a_ulog_are_refused_and_listed() {
    let d = std::fs::read(shipped("px4-sitl-hop/px4_sitl_hop.ulg")).unwrap();
    let msgs = ulog_messages(&d);
    let ids = msg_ids(&msgs, "vehicle_air_data");
    let air: Vec<usize> = msgs
        .iter()
        .enumerate()
        .filter(|(_, (t, p))| *t == b'D' && ids.contains(&data_id(p)))
        .map(|(k, _)| k)
        .collect();
    let hit = [air[300], air[301], air[400]];
    // `baro_alt_meter` follows timestamp, timestamp_sample (u64) and baro_device_id (u32).
    let at = 2 + 8 + 8 + 4;
    let log = edited_ulog("nan-baro", |k, _, p| {
        let mut p = p.to_vec();
        if hit.contains(&k) {
            p[at..at + 4].copy_from_slice(&f32::NAN.to_le_bytes());
        }
        Some(p)
    });
    let out = log.parent().unwrap().join("out");
    let s = replay(&log, &config("px4-sitl-hop"), &out).unwrap();
    let found = s["log_findings"]["non_finite_values"].as_array().unwrap();
    assert_eq!(found.len(), 1, "{found:?}");
    assert_eq!(found[0]["topic_field"], "vehicle_air_data.baro_alt_meter");
    assert_eq!(num(&found[0], &["samples"]), 3.0);
    for name in ["classical", "aided"] {
        let refused = &s["loops"][name]["aid_samples_refused"];
        let n: f64 = refused
            .as_object()
            .unwrap()
            .iter()
            .filter(|(k, _)| k.contains("NonFiniteInput"))
            .map(|(_, v)| v.as_f64().unwrap())
            .sum();
        assert_eq!(n, 3.0, "{name}: {refused}");
    }
    check_loops(&s, 1.0, 0.5);
    let _ = std::fs::remove_dir_all(log.parent().unwrap());
}

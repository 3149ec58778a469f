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
        e.contains("f_down_m_s2") && e.contains("looks like g"),
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

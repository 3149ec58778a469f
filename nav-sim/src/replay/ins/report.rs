//! What the INS replay reports: the CSV columns, the summary and the plot.

use super::*;

impl InsReplay {
    /// The INS columns of the current `timeseries.csv` row (leading comma included): the
    /// autopilot's and the free INS's Euler angles, the latest differences (computed at the
    /// autopilot's attitude samples) and both runs' velocities.
    pub fn csv_fields(&self) -> String {
        let nan3 = [f64::NAN; 3];
        let ap = self
            .latest_att
            .map_or(nan3, |a| euler(&a.v).map(f64::to_degrees));
        let ins = self
            .free
            .q_ins()
            .map_or(nan3, |q| euler(&q).map(f64::to_degrees));
        let d = |r: &Run| r.last_att.map_or(nan3, |a| a.map(f64::to_degrees));
        let v = |r: &Run| r.vel_ins().unwrap_or(nan3);
        let all: Vec<f64> = [
            ap,
            ins,
            d(&self.free),
            v(&self.free),
            d(&self.relev),
            v(&self.relev),
        ]
        .concat();
        all.iter().map(|x| format!(",{x}")).collect()
    }

    fn unavailable(&self) -> Option<(Unavailable, String)> {
        let no_body = "the IMU samples have no body-axes accelerometer (CSV: imu.csv columns `acc_x_m_s2`, `acc_y_m_s2`, `acc_z_m_s2`; ULog: `sensor_combined.accelerometer_m_s2`)";
        let no_gyro = "the IMU samples have no gyro (CSV: imu.csv columns `gyro_x_rad_s`, `gyro_y_rad_s`, `gyro_z_rad_s`; ULog: `sensor_combined.gyro_rad`)";
        let no_att = "the log has no attitude of the autopilot (CSV: imu.csv columns `q_w`, `q_x`, `q_y`, `q_z`; ULog: `vehicle_attitude.q`)";
        if self.body_samples == 0 {
            Some((Unavailable::NoAccelerometer, no_body.into()))
        } else if self.gyro_samples == 0 {
            Some((Unavailable::NoGyro, no_gyro.into()))
        } else if self.attitude_samples == 0 {
            Some((Unavailable::NoAttitude, no_att.into()))
        } else if self.frame_failed {
            let f = self.frame.f_ned;
            Some((
                Unavailable::FrameCheckFailed,
                format!(
                    "the specific force rotated by the logged attitude averages ({:.2}, {:.2}, {:.2}) m/s² NED over the first {} s (with the conjugate quaternion: ({:.2}, {:.2}, {:.2})), expected ≈ (0, 0, −9.8): body axes not forward-right-down, accelerometer not in m/s², or the quaternion not body → NED (Hamilton, scalar first)?",
                    f[0], f[1], f[2], self.cfg.start_after_s,
                    self.frame.f_ned_conjugate[0], self.frame.f_ned_conjugate[1], self.frame.f_ned_conjugate[2]
                ),
            ))
        } else if self.free.inits.is_empty() {
            Some((
                Unavailable::TooShort,
                format!(
                    "the log ends before {} s of IMU samples with gyro, accelerometer and attitude",
                    self.cfg.start_after_s
                ),
            ))
        } else {
            None
        }
    }

    fn init_json(&self, r: &InitRecord) -> Value {
        json!({
            "at_s": sig(r.t.signed_seconds_since::<f64>(self.first_imu), 6),
            "horizontal_velocity_from": format!("{:?}", r.horizontal_velocity),
            "vertical_velocity_from": format!("{:?}", r.vertical_velocity),
            "latitude_from": format!("{:?}", r.lat_lon),
            "altitude_from": format!("{:?}", r.altitude),
            "latitude_deg": sig(r.lat_deg, 8),
            "altitude_m": sig(r.alt_m, 6),
        })
    }

    fn run_json(&self, run: &Run) -> Value {
        let deg = 180.0 / std::f64::consts::PI;
        json!({
            "imu_accepted": run.accepted,
            "imu_refused": run.refused,
            "initialisations": run.inits.len(),
            "reinitialised_after_gap": run.gap_reinits,
            "initialisations_refused": run.init_refused,
            "gaps": run.gaps.iter().map(|(t, len)| json!({
                "at_s": sig(t.signed_seconds_since::<f64>(self.first_imu), 6),
                "length_s": sig(*len, 4),
            })).collect::<Vec<_>>(),
            "first_initialisation": run.inits.first().map(|r| self.init_json(r)),
            "attitude_vs_autopilot": axes_json(&run.att, RPY, deg, "deg"),
            "velocity_vs_autopilot": axes_json(&run.vel_ap, NED, 1.0, "m_s"),
            "velocity_vs_gnss": axes_json(&run.vel_gnss, NED, 1.0, "m_s"),
        })
    }

    /// The `ins` object of `summary.json`.
    pub fn summary(&self) -> Value {
        if let Some((reason, detail)) = self.unavailable() {
            return json!({
                "status": "NotAvailable",
                "reason": format!("{reason:?}"),
                "detail": detail,
                "imu_samples": self.imu_samples,
                "imu_refused": self.free.refused,
                "imu_samples_with_gyro": self.gyro_samples,
                "attitude_samples": self.attitude_samples,
                "frame_check": self.frame.json(),
            });
        }
        let deg = 180.0 / std::f64::consts::PI;
        let cfg = &self.cfg;
        let horizons: Vec<Value> = self
            .free
            .horizons
            .iter()
            .map(|h| {
                let v = |x: Option<[f64; 3]>| x.map(|a| a.map(|y| sig(y, 3)));
                json!({
                    "after_s": h.after_s,
                    "compared_after_s": sig(h.elapsed_s, 4),
                    "attitude_difference_deg": RPY.iter().zip(h.att_rad).map(|(n, a)| (n.to_string(), json!(sig(a * deg, 3)))).collect::<serde_json::Map<_, _>>(),
                    "expected_attitude_drift_1sigma_deg": sig(cfg.expected_attitude_sigma_rad(h.elapsed_s) * deg, 3),
                    "velocity_difference_vs_autopilot_ned_m_s": v(h.vel_vs_autopilot_m_s),
                    "velocity_difference_vs_gnss_ned_m_s": v(h.vel_vs_gnss_m_s),
                    "expected_horizontal_velocity_drift_1sigma_m_s": sig(cfg.expected_velocity_sigma_m_s(h.elapsed_s), 3),
                })
            })
            .collect();
        let mut free = self.run_json(&self.free);
        free["at_horizons"] = json!(horizons);
        let mut relev = self.run_json(&self.relev);
        relev["interval_s"] = json!(cfg.reinit_interval_s);
        relev["windows"] = json!(self.relev.windows);
        relev["at_window_end"] = json!({
            "attitude_vs_autopilot": axes_json(&self.relev.window_att, RPY, deg, "deg"),
            "velocity_vs_autopilot": axes_json(&self.relev.window_vel_ap, NED, 1.0, "m_s"),
            "velocity_vs_gnss": axes_json(&self.relev.window_vel_gnss, NED, 1.0, "m_s"),
            "expected_attitude_drift_1sigma_deg": sig(cfg.expected_attitude_sigma_rad(cfg.reinit_interval_s) * deg, 3),
            "expected_horizontal_velocity_drift_1sigma_m_s": sig(cfg.expected_velocity_sigma_m_s(cfg.reinit_interval_s), 3),
        });
        json!({
            "status": "Available",
            "precision": "f32",
            "imu_samples": self.imu_samples,
            "attitude_samples": self.attitude_samples,
            "frame_check": self.frame.json(),
            "sensor_quality": {
                "gyro_noise_rad_s_rt_hz": cfg.gyro_noise_rad_s_rt_hz,
                "gyro_bias_rad_s": cfg.gyro_bias_rad_s,
                "accel_bias_m_s2": cfg.accel_bias_m_s2,
            },
            "autopilot_attitude_resets": self.resets.iter().map(|(t, r)| {
                let yaw = euler(&r.delta_q)[2] * deg;
                json!({ "at_s": sig(t.signed_seconds_since::<f64>(self.first_imu), 6), "counter": r.counter, "yaw_change_deg": sig(yaw, 3) })
            }).collect::<Vec<_>>(),
            "autopilot_reset_counter_skips": self.reset_counter_skips,
            "free": free,
            "relevelled": relev,
            "notes": "Differences are INS minus autopilot (attitude: 3-2-1 Euler angles, yaw wrapped; the autopilot's own attitude resets removed from its reference) and INS minus reference velocity (NED), compared at the reference's samples with the INS at the latest IMU sample. imu_refused: NotInitialised = before the INS started (frame-check window) or between a gap and the next attitude sample; Gap = interval longer than max_interval_s. expected_*_1sigma: the growth the stated sensor quality predicts for a free INS (gyro angle random walk and bias; accelerometer bias and g times the tilt).",
        })
    }

    /// Draws `ins.png`: attitude differences and velocities. Nothing is drawn when the INS did
    /// not run.
    pub fn plot(&self, path: &Path, title: &str) -> Result<bool> {
        if self.unavailable().is_some() {
            return Ok(false);
        }
        let rows = self.plot.rows();
        let t: Vec<f64> = rows.iter().map(|r| r.t_s).collect();
        let col = |f: &dyn Fn(&PlotRow) -> f64| rows.iter().map(f).collect::<Vec<f64>>();
        let t0 = self
            .free
            .inits
            .first()
            .map_or(0.0, |r| r.t.signed_seconds_since::<f64>(self.first_imu));
        let sigma1 = |sign: f64| {
            t.iter()
                .map(|&x| {
                    if x < t0 {
                        f64::NAN
                    } else {
                        sign * self.cfg.expected_attitude_sigma_rad(x - t0).to_degrees()
                    }
                })
                .collect::<Vec<f64>>()
        };
        let (up, down) = (sigma1(1.0), sigma1(-1.0));
        let mut panels = Vec::new();
        for (k, name) in RPY.iter().enumerate() {
            panels.push(Panel {
                title: format!("{name}: INS − autopilot"),
                y_label: format!("Δ{name}, deg"),
                series: vec![
                    Series::line("free INS", &t, &col(&|r| r.free_att_deg[k]), 0),
                    Series::line(
                        format!("re-levelled every {} s", self.cfg.reinit_interval_s),
                        &t,
                        &col(&|r| r.relev_att_deg[k]),
                        1,
                    ),
                    Series::dashed("±1σ expected (free, gyro quality)", &t, &up, 7),
                    Series::dashed("", &t, &down, 7),
                ],
                y_range: None,
            });
        }
        for (k, name) in NED.iter().enumerate() {
            panels.push(Panel {
                title: format!("velocity {name}"),
                y_label: format!("V_{}, m/s", &name[..1].to_uppercase()),
                series: vec![
                    Series::line("free INS", &t, &col(&|r| r.free_v[k]), 0),
                    Series::line("re-levelled INS", &t, &col(&|r| r.relev_v[k]), 1),
                    Series::line("GNSS", &t, &col(&|r| r.gnss_v[k]), 2),
                    Series::line("autopilot", &t, &col(&|r| r.ap_v[k]), 3),
                ],
                y_range: None,
            });
        }
        // Attitude in the left column, velocity in the right.
        let order = [0, 3, 1, 4, 2, 5];
        let mut panels: Vec<Option<Panel>> = panels.into_iter().map(Some).collect();
        let panels = order.iter().filter_map(|&i| panels[i].take()).collect();
        let fig = Figure {
            title: format!("Strapdown INS replay (f32, log's own time stamps): {title}"),
            x_label: "time since the first IMU sample, s".into(),
            columns: 2,
            panels,
        };
        plot::render(&fig, path, 1600, 1400)?;
        Ok(true)
    }
}

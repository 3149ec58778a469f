//! `replay.png`: the loops against the GNSS and the autopilot.

use super::*;

/// What `replay.png` draws.
pub(super) struct PlotData<'a> {
    /// At the IMU steps (≤ 20 Hz): t, baro, GNSS alt, GNSS V_z, autopilot alt, autopilot V_z,
    /// classical alt, V_z, aided alt, V_z.
    pub(super) rows: &'a [[f64; 10]],
    /// At the autopilot's samples: t, loops − autopilot (alt ×2, V_z ×2).
    pub(super) ap_diff: &'a [[f64; 5]],
    /// At the GNSS samples: t, GNSS − autopilot (alt, V_z).
    pub(super) gnss_diff: &'a [[f64; 3]],
    pub(super) settle_s: f64,
}

pub(super) fn plot_replay(
    d: &PlotData,
    tally: &[LoopTally; 2],
    gnss_minus_ap_mean_m: f64,
    path: &Path,
    title: &str,
) -> Result<()> {
    let mut panels = estimate_panels(d, tally);
    panels.extend(difference_panels(d, tally, gnss_minus_ap_mean_m));
    let fig = Figure {
        title: format!("Vertical loops on the log: {title}"),
        x_label: "time since the first IMU sample, s".into(),
        columns: 1,
        panels,
    };
    plot::render(&fig, path, 1400, 1600)
}

/// The altitude and vertical-velocity panels: the loops, the autopilot, the GNSS and the baro
/// over time (references shifted into the baro datum by their mean offsets).
fn estimate_panels(d: &PlotData, tally: &[LoopTally; 2]) -> Vec<Panel> {
    let col = |k: usize| d.rows.iter().map(|r| r[k]).collect::<Vec<f64>>();
    let t = col(0);
    let (baro, gnss, gnss_vz, ap, ap_vz, c_alt, c_vz, a_alt, a_vz) = (
        col(1),
        col(2),
        col(3),
        col(4),
        col(5),
        col(6),
        col(7),
        col(8),
        col(9),
    );
    // References shifted into the classical loop's (baro) datum by their mean offset.
    let shift = |v: &[f64], off: f64| v.iter().map(|x| x + off).collect::<Vec<f64>>();
    let mean_or_zero = |m: &Moments| if m.n > 0 { m.mean } else { 0.0 };
    let gnss_off = mean_or_zero(&tally[0].alt_vs_gnss);
    let ap_off = mean_or_zero(&tally[0].alt_vs_autopilot);
    let gnss_s = shift(&gnss, gnss_off);
    let ap_s = shift(&ap, ap_off);
    vec![
        Panel {
            title: format!(
            "altitude (baro datum; GNSS shifted {:+.1} m, autopilot {:+.1} m: their mean offsets)",
            gnss_off, ap_off
        ),
            y_label: "altitude, m".into(),
            series: vec![
                Series::line("autopilot estimate", &t, &ap_s, 3),
                Series::line("GNSS", &t, &gnss_s, 2),
                Series {
                    style: plot::Style::Points,
                    ..Series::line("baro", &t, &baro, 7)
                },
                Series::line("classical loop", &t, &c_alt, 0),
                Series::line("aided loop", &t, &a_alt, 1),
            ],
            y_range: None,
        },
        Panel {
            title: "vertical velocity (up positive)".into(),
            y_label: "V_up, m/s".into(),
            series: vec![
                Series::line("GNSS", &t, &gnss_vz, 2),
                Series::line("autopilot estimate", &t, &ap_vz, 3),
                Series::line("classical loop", &t, &c_vz, 0),
                Series::line("aided loop", &t, &a_vz, 1),
            ],
            y_range: None,
        },
    ]
}

/// The panels of the differences to the autopilot at its samples (altitude with the mean
/// offsets removed, vertical velocity), with the GNSS's at the GNSS samples.
fn difference_panels(
    d: &PlotData,
    tally: &[LoopTally; 2],
    gnss_minus_ap_mean_m: f64,
) -> Vec<Panel> {
    let mean_or_zero = |m: &Moments| if m.n > 0 { m.mean } else { 0.0 };
    let dcol = |k: usize, off: f64| d.ap_diff.iter().map(|r| r[k] - off).collect::<Vec<f64>>();
    let td = dcol(0, 0.0);
    let gcol = |k: usize, off: f64| d.gnss_diff.iter().map(|r| r[k] - off).collect::<Vec<f64>>();
    let tg = gcol(0, 0.0);
    let g_off = if gnss_minus_ap_mean_m.is_finite() {
        gnss_minus_ap_mean_m
    } else {
        0.0
    };
    let settle = format!("statistics from t = {} s", d.settle_s);
    vec![
        Panel {
            title: format!(
            "altitude difference to the autopilot at its samples, mean offset removed ({settle})"
        ),
            y_label: "Δh, m".into(),
            series: vec![
                Series::dashed(
                    "GNSS − autopilot (at GNSS samples)",
                    &tg,
                    &gcol(1, g_off),
                    2,
                ),
                Series::line(
                    "classical − autopilot",
                    &td,
                    &dcol(1, mean_or_zero(&tally[0].alt_vs_autopilot)),
                    0,
                ),
                Series::line(
                    "aided − autopilot",
                    &td,
                    &dcol(2, mean_or_zero(&tally[1].alt_vs_autopilot)),
                    1,
                ),
            ],
            y_range: None,
        },
        Panel {
            title: format!(
                "vertical-velocity difference to the autopilot at its samples ({settle})"
            ),
            y_label: "ΔV_up, m/s".into(),
            series: vec![
                Series::dashed("GNSS − autopilot (at GNSS samples)", &tg, &gcol(2, 0.0), 2),
                Series::line("classical − autopilot", &td, &dcol(3, 0.0), 0),
                Series::line("aided − autopilot", &td, &dcol(4, 0.0), 1),
            ],
            y_range: None,
        },
    ]
}

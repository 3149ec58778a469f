//! PNG figures: stacked panels of line series (plotters, bitmap backend, embedded DejaVu font).

use anyhow::{anyhow, Result};
use plotters::prelude::*;
use plotters::style::FontStyle;
use std::path::Path;
use std::sync::Once;

/// Line style of a series.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Style {
    /// Solid line.
    Solid,
    /// Dashed line (e.g. a filter's own σ, a theoretical curve).
    Dashed,
    /// Markers only.
    Points,
}

/// One curve.
#[derive(Debug, Clone)]
pub struct Series {
    /// Legend label.
    pub label: String,
    /// Abscissa values.
    pub x: Vec<f64>,
    /// Ordinate values (non-finite points are skipped).
    pub y: Vec<f64>,
    /// Palette index (0 = blue, 1 = red, 2 = green, 3 = black, …).
    pub color: usize,
    /// Line style.
    pub style: Style,
}

impl Series {
    /// A solid line.
    pub fn line(label: impl Into<String>, x: &[f64], y: &[f64], color: usize) -> Self {
        Self {
            label: label.into(),
            x: x.to_vec(),
            y: y.to_vec(),
            color,
            style: Style::Solid,
        }
    }
    /// A dashed line.
    pub fn dashed(label: impl Into<String>, x: &[f64], y: &[f64], color: usize) -> Self {
        Self {
            label: label.into(),
            x: x.to_vec(),
            y: y.to_vec(),
            color,
            style: Style::Dashed,
        }
    }
}

/// One panel (sub-plot) with its own y axis.
#[derive(Debug, Clone, Default)]
pub struct Panel {
    /// Panel title (drawn above the panel).
    pub title: String,
    /// y-axis label with unit.
    pub y_label: String,
    /// Curves.
    pub series: Vec<Series>,
    /// Fixed y range; `None` fits the data.
    pub y_range: Option<(f64, f64)>,
}

/// A figure: panels stacked in a grid with `columns` columns, sharing the x label.
#[derive(Debug, Clone)]
pub struct Figure {
    /// Figure caption.
    pub title: String,
    /// x-axis label with unit.
    pub x_label: String,
    /// Panels, row-major.
    pub panels: Vec<Panel>,
    /// Panels per row.
    pub columns: usize,
}

const PALETTE: [RGBColor; 8] = [
    RGBColor(31, 119, 180),
    RGBColor(214, 39, 40),
    RGBColor(44, 160, 44),
    RGBColor(0, 0, 0),
    RGBColor(255, 127, 14),
    RGBColor(148, 103, 189),
    RGBColor(140, 86, 75),
    RGBColor(127, 127, 127),
];

fn register_fonts() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
        let _ = plotters::style::register_font("sans-serif", FontStyle::Bold, dejavu::sans::bold());
    });
}

fn finite_range(values: impl Iterator<Item = f64>) -> Option<(f64, f64)> {
    let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
    for v in values.filter(|v| v.is_finite()) {
        lo = lo.min(v);
        hi = hi.max(v);
    }
    if lo > hi {
        return None;
    }
    if hi - lo < 1e-12 * (1.0 + hi.abs()) {
        let pad = 0.5 * (1.0 + hi.abs()) * 1e-3 + 1e-9;
        return Some((lo - pad, hi + pad));
    }
    let pad = 0.05 * (hi - lo);
    Some((lo - pad, hi + pad))
}

/// Renders the figure to a PNG of `width` × `height` pixels.
pub fn render(fig: &Figure, path: &Path, width: u32, height: u32) -> Result<()> {
    register_fonts();
    let root = BitMapBackend::new(path, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|e| anyhow!("{e}"))?;
    let root = root
        .titled(&fig.title, ("sans-serif", 22).into_font())
        .map_err(|e| anyhow!("{e}"))?;
    let cols = fig.columns.max(1);
    let rows = fig.panels.len().div_ceil(cols).max(1);
    let areas = root.split_evenly((rows, cols));
    for (panel, area) in fig.panels.iter().zip(areas.iter()) {
        let xr = finite_range(panel.series.iter().flat_map(|s| s.x.iter().copied()))
            .unwrap_or((0.0, 1.0));
        let yr = panel
            .y_range
            .or_else(|| finite_range(panel.series.iter().flat_map(|s| s.y.iter().copied())))
            .unwrap_or((-1.0, 1.0));
        let mut chart = ChartBuilder::on(area)
            .caption(&panel.title, ("sans-serif", 16).into_font())
            .margin(8)
            .x_label_area_size(36)
            .y_label_area_size(64)
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
            .map_err(|e| anyhow!("{e}"))?;
        chart
            .configure_mesh()
            .x_desc(&fig.x_label)
            .y_desc(&panel.y_label)
            .label_style(("sans-serif", 12))
            .light_line_style(RGBColor(235, 235, 235))
            .draw()
            .map_err(|e| anyhow!("{e}"))?;
        for s in &panel.series {
            let color = PALETTE[s.color % PALETTE.len()];
            let pts: Vec<(f64, f64)> =
                s.x.iter()
                    .zip(&s.y)
                    .filter(|(x, y)| x.is_finite() && y.is_finite())
                    .map(|(x, y)| (*x, y.clamp(yr.0, yr.1)))
                    .collect();
            let style = ShapeStyle::from(&color).stroke_width(2);
            let anno = match s.style {
                Style::Solid => chart
                    .draw_series(LineSeries::new(pts, style))
                    .map_err(|e| anyhow!("{e}"))?,
                Style::Dashed => chart
                    .draw_series(DashedLineSeries::new(pts, 6, 4, style))
                    .map_err(|e| anyhow!("{e}"))?,
                Style::Points => chart
                    .draw_series(pts.into_iter().map(|p| Circle::new(p, 2, color.filled())))
                    .map_err(|e| anyhow!("{e}"))?,
            };
            if !s.label.is_empty() {
                anno.label(s.label.clone()).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 18, y)], color.stroke_width(2))
                });
            }
        }
        if panel.series.iter().any(|s| !s.label.is_empty()) {
            chart
                .configure_series_labels()
                .background_style(WHITE.mix(0.85))
                .border_style(BLACK)
                .label_font(("sans-serif", 12))
                .draw()
                .map_err(|e| anyhow!("{e}"))?;
        }
    }
    root.present().map_err(|e| anyhow!("{e}"))?;
    Ok(())
}

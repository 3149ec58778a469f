//! The figure of an estimator judged on several filters (the flight navigator's phases,
//! hand-over and last epoch) in the consistency campaign's `consistency.png`.

use super::{add_bands, Verdict, RATIO_CLIP};
use crate::plot::{Panel, Series, Style};
use crate::scenarios::campaign_plan::{Campaign, VariantResult};

/// The panels of an estimator judged on several filters (the navigator's phases, hand-over
/// and last epoch): per variant, each filter's mean NEES per state (those outside the band of
/// their time average marked) and fraction of epochs in band, side by side.
pub(super) fn judged_filter_panels(
    c: &Campaign,
    verdicts: &[(&VariantResult, Verdict)],
    judged: &[&str],
) -> Vec<Panel> {
    let mut ratio = Panel {
        title: format!(
            "{}: mean NEES / states per phase (> {RATIO_CLIP} at {RATIO_CLIP}; grey: outside \
             its time average's band)",
            c.estimator
        ),
        y_label: "NEES / states".into(),
        y_range: Some((0.0, RATIO_CLIP * 1.05)),
        ..Panel::default()
    };
    let mut frac = Panel {
        title: format!(
            "{}: fraction of epochs in the NEES band (hand-over, final: one epoch)",
            c.estimator
        ),
        y_label: "fraction in band".into(),
        y_range: Some((0.0, 1.05)),
        ..Panel::default()
    };
    let width = 0.7 / judged.len().max(1) as f64;
    let mut outside = (Vec::new(), Vec::new());
    for (i, filter) in judged.iter().enumerate() {
        let rows: Vec<&(&VariantResult, Verdict)> = verdicts
            .iter()
            .filter(|(r, _)| r.filter == *filter)
            .collect();
        let x: Vec<f64> = rows
            .iter()
            .map(|(r, _)| r.variant as f64 - 0.35 + width * (i as f64 + 0.5))
            .collect();
        let per_state = |r: &VariantResult| {
            (r.consistency.mean_nees() / r.consistency.dof as f64).min(RATIO_CLIP)
        };
        let y_ratio: Vec<f64> = rows.iter().map(|(r, _)| per_state(r)).collect();
        for ((r, v), xi) in rows.iter().zip(&x) {
            if !v.pass_statistical {
                outside.0.push(*xi);
                outside.1.push(per_state(r));
            }
        }
        let lit = rows.iter().filter(|(_, v)| v.pass).count();
        let stat = rows.iter().filter(|(_, v)| v.pass_statistical).count();
        let mut s = Series::line(
            format!(
                "{filter} (literal {lit}, statistical {stat} of {})",
                rows.len()
            ),
            &x,
            &y_ratio,
            i,
        );
        s.style = Style::Points;
        ratio.series.push(s);
        let y_frac: Vec<f64> = rows.iter().map(|(_, v)| v.frac_in_band).collect();
        let mut s = Series::line(*filter, &x, &y_frac, i);
        s.style = Style::Points;
        frac.series.push(s);
    }
    let mut s = Series::line(
        "outside the band of its time average",
        &outside.0,
        &outside.1,
        7,
    );
    s.style = Style::Points;
    ratio.series.push(s);
    add_bands(verdicts, &mut ratio, &mut frac);
    vec![ratio, frac]
}

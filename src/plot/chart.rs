//! The chart helpers every picture is built from: a captioned chart over two states or over
//! any two ranges, the unsafe set's shading, boxes as rectangles, legends and their swatches.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::{Chart, DrawError, View, DARK, OBSTACLE};
use crate::boxes::IntervalBox;
use crate::scenario::Scenario;

/// The caption's font size: 22 px, or less where a long title (a verdict map's with its
/// shares) would run past the picture's edges.
pub(super) fn caption_size<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, title: &str) -> f64 {
    const SIZE: f64 = 22.0;
    let room = 0.96 * root.dim_in_pixel().0 as f64;
    match root.estimate_text_size(title, &("sans-serif", SIZE).into_font().into()) {
        Ok((w, _)) if w as f64 > room => (SIZE * room / w as f64).max(10.0),
        _ => SIZE,
    }
}

pub(super) fn chart<'a, DB: DrawingBackend<ErrorType: 'static>>(
    root: &'a DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    region: &IntervalBox,
    title: &str,
) -> Result<Chart<'a, DB>, DrawError> {
    let n = scenario.n();
    let fits = |k: usize| k < n && k < region.dim();
    if !fits(view.x) || !fits(view.y) || view.slice.iter().any(|&(k, _)| !fits(k)) {
        return Err(DrawError::NotPlanar {
            file: scenario.file.clone(),
            n,
        });
    }
    let title = format!("{title}{}", view.describe(scenario));
    let region = &view.plane(region);
    axes(
        root,
        &title,
        [
            (region.lower[0], region.upper[0]),
            (region.lower[1], region.upper[1]),
        ],
        [
            &scenario.label(&scenario.states[view.x]),
            &scenario.label(&scenario.states[view.y]),
        ],
    )
}

/// A captioned chart over `ranges` (across, up) with a light mesh and the axes' names.
pub(super) fn axes<'a, DB: DrawingBackend<ErrorType: 'static>>(
    root: &'a DrawingArea<DB, Shift>,
    title: &str,
    ranges: [(f64, f64); 2],
    names: [&str; 2],
) -> Result<Chart<'a, DB>, DrawError> {
    let [(x0, x1), (y0, y1)] = ranges;
    let mut chart = ChartBuilder::on(root)
        .caption(title, ("sans-serif", caption_size(root, title)))
        .margin(12)
        .x_label_area_size(48)
        .y_label_area_size(58)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(DrawError::from)?;
    chart
        .configure_mesh()
        .x_desc(names[0])
        .y_desc(names[1])
        .axis_desc_style(("sans-serif", 18))
        .label_style(("sans-serif", 14))
        .light_line_style(RGBColor(245, 245, 245))
        .bold_line_style(RGBColor(225, 225, 225))
        .draw()
        .map_err(DrawError::from)?;
    Ok(chart)
}

/// Shades the cells of a fine grid over `region` where some `hᵢ < 0` at the centre; in a
/// projection (some state neither drawn nor sliced) there is no one point to ask, and nothing
/// is shaded.
pub(super) fn shade_unsafe<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    scenario: &Scenario,
    region: &IntervalBox,
) -> Result<(), DrawError> {
    if !view.is_whole(scenario.n()) {
        return Ok(());
    }
    let (nx, ny) = (240usize, 180usize);
    let cells = view.plane(region).partition(&[nx, ny]);
    let bad: Vec<&IntervalBox> = cells
        .iter()
        .filter(|c| {
            let m = c.center();
            let x = view.lift(region, m[0], m[1]);
            scenario.cbfs.iter().any(|h| h.h.eval(&x) < 0.0)
        })
        .collect();
    if bad.is_empty() {
        return Ok(());
    }
    chart
        .draw_series(bad.iter().map(|c| {
            Rectangle::new(
                [(c.lower[0], c.lower[1]), (c.upper[0], c.upper[1])],
                OBSTACLE.filled(),
            )
        }))
        .map_err(DrawError::from)?
        .label("unsafe set (some h < 0)")
        .legend(|(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], OBSTACLE.filled()));
    Ok(())
}

pub(super) fn legend<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
) -> Result<(), DrawError> {
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.85))
        .border_style(DARK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(DrawError::from)
}

/// A box's rectangle in the picture, clipped to the region.
pub(super) fn clamp_box(view: &View, b: &IntervalBox, r: &IntervalBox) -> [(f64, f64); 2] {
    let (x, y) = (view.x, view.y);
    let c = |v: f64, i: usize| v.clamp(r.lower[i], r.upper[i]);
    [
        (c(b.lower[x], x), c(b.lower[y], y)),
        (c(b.upper[x], x), c(b.upper[y], y)),
    ]
}

/// Boxes of the state space (n-D) as rectangles: those the view's slices meet, projected.
pub(super) fn box_series<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    boxes: &[IntervalBox],
    region: &IntervalBox,
    style: ShapeStyle,
    label: Option<&str>,
) -> Result<(), DrawError> {
    let kept: Vec<&IntervalBox> = boxes.iter().filter(|b| view.keeps(b)).collect();
    if kept.is_empty() {
        return Ok(());
    }
    let series = chart
        .draw_series(
            kept.iter()
                .map(|b| Rectangle::new(clamp_box(view, b, region), style)),
        )
        .map_err(DrawError::from)?;
    if let Some(l) = label {
        series.label(l).legend(swatch(style));
    }
    Ok(())
}

/// A legend's swatch: a small rectangle in `style`.
pub(super) fn swatch(style: ShapeStyle) -> impl Fn((i32, i32)) -> Rectangle<(i32, i32)> {
    move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], style)
}

/// A legend's swatch for a line: a short stroke in `style`.
pub(super) fn line_swatch(style: ShapeStyle) -> impl Fn((i32, i32)) -> PathElement<(i32, i32)> {
    move |(x, y)| PathElement::new(vec![(x, y), (x + 14, y)], style)
}

/// The intervals of `bands` equal bands of `[lo, hi]` along the view's drawn state (`view.y`)
/// where some `hᵢ < 0` at the band's centre, for pictures over one state (time or the error
/// along it); the others states at the view's slices and `region`'s centre.
pub(super) fn unsafe_bands(
    view: &View,
    scenario: &Scenario,
    region: &IntervalBox,
    (lo, hi): (f64, f64),
    bands: usize,
) -> Vec<(f64, f64)> {
    let w = (hi - lo) / bands as f64;
    (0..bands)
        .map(|k| (lo + k as f64 * w, lo + (k + 1) as f64 * w))
        .filter(|&(a, b)| {
            let mid = 0.5 * (a + b);
            !scenario.is_safe(&view.lift(region, mid, mid))
        })
        .collect()
}

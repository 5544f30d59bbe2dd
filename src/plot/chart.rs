//! The chart helpers every picture is built from: a captioned chart over two states or over
//! any two ranges, the unsafe set's shading, boxes as rectangles, legends and their swatches.

use plotters::coord::Shift;
use plotters::prelude::*;
use plotters::style::text_anchor::{HPos, Pos, VPos};

use super::shadow::{Shade, Shadow};
use super::{Chart, DrawError, View, DARK, OBSTACLE, SHADOW};
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

/// The unsafe set's shading of a picture: where it lies over every value of the projected
/// states (in a slice or a planar picture: where it is) and where over some ([`Shadow`]).
#[derive(Debug, Default, PartialEq)]
pub(super) struct Shading<T> {
    pub(super) every: Vec<T>,
    pub(super) some: Vec<T>,
}

impl<T> Shading<T> {
    fn is_empty(&self) -> bool {
        self.every.is_empty() && self.some.is_empty()
    }

    /// The same shading in other coordinates (bands as rectangles).
    pub(super) fn map<U>(&self, f: impl Fn(&T) -> U) -> Shading<U> {
        Shading {
            every: self.every.iter().map(&f).collect(),
            some: self.some.iter().map(&f).collect(),
        }
    }
}

/// The unsafe set over the view's plane as rectangles: runs of a grid at about two pixels of
/// a `pixels`-sized picture, merged along each row by their [`Shade`] at the grid points (a
/// sampled picture, not a proof).
pub(super) fn unsafe_rects(shadow: &Shadow, pixels: (u32, u32)) -> Shading<[(f64, f64); 2]> {
    let plane = shadow.view.plane(shadow.region);
    let (nx, ny) = (
        (pixels.0 / 2).max(8) as usize,
        (pixels.1 / 2).max(8) as usize,
    );
    let (x0, y0) = (plane.lower[0], plane.lower[1]);
    let (dx, dy) = (plane.widths()[0] / nx as f64, plane.widths()[1] / ny as f64);
    let mut shading = Shading::default();
    for j in 0..ny {
        let y = y0 + (j as f64 + 0.5) * dy;
        let mut run = (0, Shade::Clear);
        for i in 0..=nx {
            let shade = match i < nx {
                true => shadow.at(x0 + (i as f64 + 0.5) * dx, y),
                false => Shade::Clear,
            };
            if shade == run.1 {
                continue;
            }
            let rect = [
                (x0 + run.0 as f64 * dx, y0 + j as f64 * dy),
                (x0 + i as f64 * dx, y0 + (j + 1) as f64 * dy),
            ];
            match run.1 {
                Shade::Every => shading.every.push(rect),
                Shade::Some => shading.some.push(rect),
                Shade::Clear => {}
            }
            run = (i, shade);
        }
    }
    shading
}

/// Which of a shading's tones a picture draws.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Tones {
    /// The unsafe set over every value of the projected states, and its pale shadow.
    Both,
    /// Only over every value: where the pale shadow would hide the picture's data.
    Every,
}

/// The unsafe set's shading over the view's plane for a picture of `root`'s size in `tones`,
/// and its legend entries where there are any.
pub(super) fn unsafe_layer<DB: DrawingBackend>(
    root: &DrawingArea<DB, Shift>,
    legend: &mut Legend,
    view: &View,
    scenario: &Scenario,
    region: &IntervalBox,
    tones: Tones,
) -> Shading<[(f64, f64); 2]> {
    let shadow = Shadow::new(view, scenario, region);
    let mut shading = unsafe_rects(&shadow, root.dim_in_pixel());
    if tones == Tones::Every {
        shading.some.clear();
    }
    legend.push_unsafe(&shadow, &shading);
    shading
}

/// The unsafe set's bands along the view's drawn state over `range` (400 of them: [`unsafe_bands`]),
/// and its legend entries where there are any: the shading of the pictures over one state.
pub(super) fn unsafe_band_layer(
    legend: &mut Legend,
    view: &View,
    scenario: &Scenario,
    region: &IntervalBox,
    range: (f64, f64),
) -> Shading<(f64, f64)> {
    let shadow = Shadow::new(view, scenario, region);
    let shading = unsafe_bands(&shadow, range, 400);
    legend.push_unsafe(&shadow, &shading);
    shading
}

/// Draws a shading: the unsafe set over some values of the projected states pale, over every
/// value (or, in a slice, the set itself) as the unsafe set.
pub(super) fn draw_shading<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    shading: &Shading<[(f64, f64); 2]>,
) -> Result<(), DrawError> {
    draw_rects(chart, &shading.some, SHADOW.filled())?;
    draw_rects(chart, &shading.every, OBSTACLE.filled())
}

/// Rectangles of the chart's coordinates, filled or outlined as `style` says.
pub(super) fn draw_rects<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    rects: &[[(f64, f64); 2]],
    style: ShapeStyle,
) -> Result<(), DrawError> {
    chart
        .draw_series(rects.iter().map(|&r| Rectangle::new(r, style)))
        .map_err(DrawError::from)?;
    Ok(())
}

/// What a legend entry shows beside its label.
#[derive(Clone, Copy, Debug)]
pub(super) enum Swatch {
    /// A small rectangle, filled or outlined as the style says: boxes, cells, shading.
    Rect(ShapeStyle),
    /// A short stroke: trajectories, levels.
    Line(ShapeStyle),
    /// A dot.
    Dot(ShapeStyle),
    /// A cross.
    Cross(ShapeStyle),
    /// A triangle.
    Triangle(ShapeStyle),
}

/// A picture's legend: its entries in the order they are drawn, laid out in a strip below the
/// chart in as many columns as fit, so that it hides none of the data.
#[derive(Debug, Default)]
pub(super) struct Legend {
    entries: Vec<(String, Swatch)>,
}

/// The legend's text size, row height, room for a swatch before its label, space between
/// columns and above and below the rows, in pixels.
const LEGEND_FONT: f64 = 14.0;
const LEGEND_ROW: u32 = 20;
const LEGEND_SWATCH: i32 = 24;
const LEGEND_GAP: i32 = 28;
const LEGEND_PAD: u32 = 8;
/// Where the rows start across: the chart's margin and y-label area, so that the legend lines
/// up with the plotting area.
const LEGEND_LEFT: i32 = 12 + 58;

impl Legend {
    /// An entry, unless one with the same label is already there.
    pub(super) fn push(&mut self, label: impl Into<String>, swatch: Swatch) {
        let label = label.into();
        if !self.entries.iter().any(|(l, _)| *l == label) {
            self.entries.push((label, swatch));
        }
    }

    /// The unsafe set's entries, for the tones `shading` has: in a projection they say over
    /// which states the set is seen.
    pub(super) fn push_unsafe<T>(&mut self, shadow: &Shadow, shading: &Shading<T>) {
        if shading.is_empty() {
            return;
        }
        let names: Vec<&str> = shadow.projected().collect();
        let over = match names.len() {
            0 => {
                self.push("unsafe set (some h < 0)", Swatch::Rect(OBSTACLE.filled()));
                return;
            }
            1..=4 => names.join(", "),
            k => format!("the {k} projected states"),
        };
        if !shading.every.is_empty() {
            let label = format!("unsafe set (some h < 0) for every {over}");
            self.push(label, Swatch::Rect(OBSTACLE.filled()));
        }
        if !shading.some.is_empty() {
            let label = match shadow.has_levels() {
                true => format!("some h < 0 as written (not ψ) for some {over}"),
                false => format!("unsafe for some {over}"),
            };
            self.push(label, Swatch::Rect(SHADOW.filled()));
        }
    }

    fn font(&self) -> TextStyle<'static> {
        ("sans-serif", LEGEND_FONT).into_font().color(&DARK)
    }

    /// Columns, each column's width and rows, for a picture `root` wide.
    fn layout<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> (usize, i32, usize) {
        let font = self.font();
        let widest = (self.entries.iter())
            .map(|(l, _)| {
                root.estimate_text_size(l, &font)
                    .map_or(8 * l.len() as u32, |s| s.0)
            })
            .max()
            .unwrap_or(0) as i32;
        let column = widest + LEGEND_SWATCH + LEGEND_GAP;
        let room = root.dim_in_pixel().0 as i32 - LEGEND_LEFT - 12 + LEGEND_GAP;
        let columns = ((room / column.max(1)).max(1) as usize).min(self.entries.len().max(1));
        let rows = self.entries.len().div_ceil(columns);
        (columns, column, rows)
    }

    /// The chart's area and, below it, the legend's strip with its columns (none for no
    /// entries).
    pub(super) fn split<DB: DrawingBackend>(
        &self,
        root: &DrawingArea<DB, Shift>,
    ) -> (DrawingArea<DB, Shift>, Option<Strip<DB>>) {
        if self.entries.is_empty() {
            return (root.clone(), None);
        }
        let (columns, column, rows) = self.layout(root);
        let strip = rows as u32 * LEGEND_ROW + 2 * LEGEND_PAD;
        let height = root.dim_in_pixel().1;
        // A picture too short for its legend keeps at least half its height for the chart.
        let strip = strip.min(height / 2);
        let (chart, area) = root.split_vertically(height - strip);
        let strip = Strip {
            area,
            columns,
            column,
        };
        (chart, Some(strip))
    }

    /// Draws the entries row by row into the strip [`Legend::split`] gave.
    pub(super) fn draw<DB: DrawingBackend<ErrorType: 'static>>(
        &self,
        strip: Option<&Strip<DB>>,
    ) -> Result<(), DrawError> {
        let Some(Strip {
            area: strip,
            columns,
            column,
        }) = strip
        else {
            return Ok(());
        };
        let (columns, column) = (*columns, *column);
        let style = (self.font()).pos(Pos::new(HPos::Left, VPos::Center));
        for (k, (label, swatch)) in self.entries.iter().enumerate() {
            let x = LEGEND_LEFT + (k % columns) as i32 * column;
            let y = (LEGEND_PAD + (k / columns) as u32 * LEGEND_ROW + LEGEND_ROW / 2) as i32;
            let drawn = match *swatch {
                Swatch::Rect(s) => strip.draw(&Rectangle::new([(x, y - 6), (x + 16, y + 6)], s)),
                Swatch::Line(s) => strip.draw(&PathElement::new(vec![(x, y), (x + 16, y)], s)),
                Swatch::Dot(s) => strip.draw(&Circle::new((x + 8, y), 6, s)),
                Swatch::Cross(s) => strip.draw(&Cross::new((x + 8, y), 6, s)),
                Swatch::Triangle(s) => strip.draw(&TriangleMarker::new((x + 8, y), 7, s)),
            };
            drawn.map_err(DrawError::from)?;
            strip
                .draw(&Text::new(label.as_str(), (x + LEGEND_SWATCH, y), &style))
                .map_err(DrawError::from)?;
        }
        Ok(())
    }
}

/// The legend's strip below a chart, and its columns and their width in pixels.
pub(super) struct Strip<DB: DrawingBackend> {
    area: DrawingArea<DB, Shift>,
    columns: usize,
    column: i32,
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

/// Whether the view shows any of `boxes` (a slice meets it, or the view projects).
pub(super) fn any_kept(view: &View, boxes: &[IntervalBox]) -> bool {
    boxes.iter().any(|b| view.keeps(b))
}

/// Boxes of the state space (n-D) as rectangles: those the view's slices meet, projected.
pub(super) fn box_series<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    boxes: &[IntervalBox],
    region: &IntervalBox,
    style: ShapeStyle,
) -> Result<(), DrawError> {
    let kept = boxes.iter().filter(|b| view.keeps(b));
    chart
        .draw_series(kept.map(|b| Rectangle::new(clamp_box(view, b, region), style)))
        .map_err(DrawError::from)?;
    Ok(())
}

/// The shading of `bands` equal bands of `[lo, hi]` along the view's drawn state (`view.y`)
/// by their [`Shade`] at the band's centre, for pictures over one state (time or the error
/// along it); the other states at the view's slices, or projected. Only the unsafe set over
/// every value of projected states is kept: along one state the pale shadow of an obstacle
/// in the others covers much of the picture (x2 over time past spheres3d's two spheres:
/// 2.8 of its 5 units) and says little.
pub(super) fn unsafe_bands(
    shadow: &Shadow,
    (lo, hi): (f64, f64),
    bands: usize,
) -> Shading<(f64, f64)> {
    let w = (hi - lo) / bands as f64;
    let mut shading = Shading::default();
    for k in 0..bands {
        let band = (lo + k as f64 * w, lo + (k + 1) as f64 * w);
        let mid = 0.5 * (band.0 + band.1);
        if shadow.every_at(mid, mid) == Shade::Every {
            shading.every.push(band);
        }
    }
    shading
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The legend takes a strip below the chart, in columns, and draws nothing above it.
    #[test]
    fn the_legend_lies_below_the_chart_in_columns() {
        super::super::register_font();
        let mut legend = Legend::default();
        for k in 0..5 {
            legend.push(format!("entry {k}"), Swatch::Rect(DARK.filled()));
        }
        legend.push("entry 0", Swatch::Line(DARK.stroke_width(1)));
        assert_eq!(legend.entries.len(), 5, "a repeated label is one entry");
        let mut svg = String::new();
        let chart_height = {
            let root = SVGBackend::with_string(&mut svg, (800, 600)).into_drawing_area();
            let (columns, _, rows) = legend.layout(&root);
            assert!(
                columns > 1 && rows < 5 && rows * columns >= 5,
                "{columns} × {rows}"
            );
            let (area, strip) = legend.split(&root);
            let strip_height = strip.as_ref().map(|s| s.area.dim_in_pixel().1).unwrap();
            assert_eq!(strip_height, rows as u32 * LEGEND_ROW + 2 * LEGEND_PAD);
            assert_eq!(area.dim_in_pixel().1 + strip_height, 600);
            legend.draw(strip.as_ref()).unwrap();
            root.present().unwrap();
            area.dim_in_pixel().1 as f64
        };
        let ys: Vec<f64> = (svg.split("<text").skip(1))
            .filter_map(|t| t.split("y=\"").nth(1)?.split('"').next()?.parse().ok())
            .collect();
        assert_eq!(ys.len(), 5, "{svg}");
        assert!(
            ys.iter().all(|&y| y > chart_height),
            "{ys:?} above {chart_height}"
        );
        // No entries: the chart keeps the whole picture.
        let mut svg = String::new();
        let root = SVGBackend::with_string(&mut svg, (800, 600)).into_drawing_area();
        let (area, strip) = Legend::default().split(&root);
        assert!(strip.is_none() && area.dim_in_pixel() == (800, 600));
    }

    /// The unsafe set's runs cover the sampled points where some `h < 0`, and no others.
    #[test]
    fn unsafe_runs_cover_the_unsafe_points() {
        let scenario = crate::scenario::Scenario::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenarios/integrator.toml"
        )))
        .unwrap();
        let region = scenario.reach.region.clone();
        let view = View::first(scenario.n());
        let shading = unsafe_rects(&Shadow::new(&view, &scenario, &region), (400, 300));
        assert!(shading.some.is_empty(), "a planar picture has no shadow");
        let rects = shading.every;
        let inside = |x: f64, y: f64| {
            (rects.iter()).any(|r| r[0].0 <= x && x <= r[1].0 && r[0].1 <= y && y <= r[1].1)
        };
        // The obstacle's disc of radius 1 about (2, 0), within a grid step (0.04 × 0.04).
        for (x, y, unsafe_here) in [
            (2.0, 0.0, true),
            (2.9, 0.0, true),
            (2.0, -0.9, true),
            (3.1, 0.0, false),
            (0.0, 0.0, false),
            (2.0, 1.1, false),
        ] {
            assert_eq!(inside(x, y), unsafe_here, "({x}, {y})");
        }
        // Runs, not cells: about one a row through the disc (50 rows of 0.04).
        assert!(rects.len() <= 60, "{} rectangles", rects.len());
    }
}

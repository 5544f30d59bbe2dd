//! Verdict maps and error maps: boxes of a partition coloured by their verdict, cells of an
//! error map by their certified bound. Where the view projects (a state neither drawn nor
//! sliced), the boxes are gathered on a grid over the drawn states: a verdict map shows in each
//! grid cell the share of each verdict in the volume above it (as stripes), an error map the
//! largest bound above it. Imports the plot module's chart helpers only.

use std::collections::BTreeMap;

use super::chart::{
    any_kept, axes, draw_rects, draw_shading, unsafe_band_layer, unsafe_layer, Legend, Swatch,
    Tones,
};
use super::*;

/// A verdict map's title: the share verified with the QP proven feasible on every set first,
/// the share that also counts boxes covering only the trajectories that exist beside it.
pub fn verdicts_title(report: &VerifyReport) -> String {
    let h = report.headline();
    let refined = report.after.len() != report.before.len();
    let grid: Vec<String> = report.run.grid.iter().map(usize::to_string).collect();
    let mut title = format!(
        "`{}` {}: verified {:.1}% of the safe area, QP proven feasible",
        report.run.scenario,
        grid.join("×"),
        100.0 * h.verified
    );
    if h.verified_existing_trajectories > h.verified {
        title += &format!(
            " ({:.1}% for existing trajectories only)",
            100.0 * h.verified_existing_trajectories
        );
    }
    if refined {
        title += &format!(
            "; {:.1}% before refinement",
            100.0 * h.verified_before_refinement
        );
    }
    title
}

/// A grid over the view's two drawn states of `region`, `counts` cells a side, and where n-D
/// boxes fall on it.
struct PlaneGrid {
    plane: IntervalBox,
    counts: [usize; 2],
}

impl PlaneGrid {
    fn new(view: &View, region: &IntervalBox, counts: [usize; 2]) -> PlaneGrid {
        PlaneGrid {
            plane: view.plane(region),
            counts: [counts[0].max(1), counts[1].max(1)],
        }
    }

    /// The grid cells an n-D box's projection overlaps, with the share of the box's volume
    /// above each (by the overlap's share of the projection's area).
    fn overlaps(&self, view: &View, b: &IntervalBox) -> Vec<(usize, f64)> {
        let p = view.plane(b);
        let span = |axis: usize| {
            let (lo, w) = (self.plane.lower[axis], self.plane.widths()[axis]);
            let k = self.counts[axis];
            let cell = |v: f64| (((v - lo) / w * k as f64).floor().max(0.0) as usize).min(k - 1);
            let (pl, pu) = (p.lower[axis], p.upper[axis]);
            let (a, z) = (cell(pl), cell(pu));
            (a..=z)
                .map(move |i| {
                    let (c0, c1) = (
                        lo + w * i as f64 / k as f64,
                        lo + w * (i + 1) as f64 / k as f64,
                    );
                    let width = pu - pl;
                    let share = if width > 0.0 {
                        (pu.min(c1) - pl.max(c0)).max(0.0) / width
                    } else {
                        1.0 / (z - a + 1) as f64
                    };
                    (i, share)
                })
                .collect::<Vec<_>>()
        };
        let (xs, ys) = (span(0), span(1));
        let mut out = Vec::with_capacity(xs.len() * ys.len());
        for &(j, sy) in &ys {
            for &(i, sx) in &xs {
                // A box that ends on a grid line touches the next cell with no area.
                if sx * sy > 0.0 {
                    out.push((j * self.counts[0] + i, sx * sy));
                }
            }
        }
        out
    }

    /// The rectangle of grid cell `k`.
    fn rect(&self, k: usize) -> [(f64, f64); 2] {
        let (i, j) = (k % self.counts[0], k / self.counts[0]);
        let at = |axis: usize, t: usize| {
            self.plane.lower[axis] + self.plane.widths()[axis] * t as f64 / self.counts[axis] as f64
        };
        [(at(0, i), at(1, j)), (at(0, i + 1), at(1, j + 1))]
    }
}

/// A verdict map's colour classes: each verdict, verified ones split by whether the QP is
/// proven feasible on every set (pale where not: their verdict speaks only of the
/// trajectories that do not meet an infeasible QP).
fn verdict_class(b: &crate::verify::BoxVerdict) -> (Verdict, bool) {
    (b.verdict, b.feasible == Some(false))
}

/// One colour of a verdict map: a verdict, verified ones split by whether the QP is proven
/// feasible on every set.
pub(super) struct VerdictClass<'a> {
    /// `(verdict, feasibility not proven)`, the order classes are stacked in.
    pub key: (Verdict, bool),
    pub colour: RGBAColor,
    /// The legend's label, with the class's share of the safe area.
    pub label: String,
    pub boxes: Vec<&'a BoxVerdict>,
}

/// The report's leaves sorted into their colour classes, those with no leaf left out.
/// Verified boxes whose QP was not proven feasible on every set are pale: their verdict speaks
/// only of the trajectories that do not meet an infeasible QP.
pub(super) fn verdict_classes(report: &VerifyReport) -> Vec<VerdictClass<'_>> {
    let after = report.shares_after();
    let share = |bs: &[&BoxVerdict]| {
        let area: f64 = bs.iter().map(|b| b.initial.volume()).sum();
        100.0 * area / after.safe_area.max(f64::MIN_POSITIVE)
    };
    let mut classes = Vec::new();
    for v in Verdict::ALL {
        let split = report
            .after
            .iter()
            .any(|b| b.verdict == v && b.feasible == Some(false));
        for pale in [false, true] {
            let boxes: Vec<&BoxVerdict> = (report.after.iter())
                .filter(|b| verdict_class(b) == (v, pale))
                .collect();
            if boxes.is_empty() {
                continue;
            }
            let (colour, label) = if pale {
                let label = format!(
                    "{}, QP feasibility not proven ({:.1}%)",
                    v.name(),
                    share(&boxes)
                );
                (verdict_colour(v).mix(0.4), label)
            } else if split {
                let label = format!("{}, QP proven feasible ({:.1}%)", v.name(), share(&boxes));
                (verdict_colour(v).mix(1.0), label)
            } else {
                let label = format!("{} ({:.1}%)", v.name(), 100.0 * after.share(v));
                (verdict_colour(v).mix(1.0), label)
            };
            classes.push(VerdictClass {
                key: (v, pale),
                colour,
                label,
                boxes,
            });
        }
    }
    classes
}

pub(super) fn draw_verdicts<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    report: &VerifyReport,
) -> Result<(), DrawError> {
    let region = &report.run.region;
    let title = verdicts_title(report);
    let classes = verdict_classes(report);
    let traps: Vec<IntervalBox> = report.traps.iter().map(|t| t.region.clone()).collect();
    let goal = std::slice::from_ref(&report.run.goal);
    let mut legend = Legend::default();
    for class in &classes {
        if class.boxes.iter().any(|b| view.keeps(&b.initial)) {
            legend.push(class.label.clone(), Swatch::Rect(class.colour.filled()));
        }
    }
    if any_kept(view, &traps) {
        legend.push("trap boxes", Swatch::Rect(VERMILION.stroke_width(2)));
    }
    if any_kept(view, goal) {
        legend.push("goal set", Swatch::Rect(BLUE.stroke_width(2)));
    }
    let (area, strip) = legend.split(root);
    let mut chart = chart(&area, view, scenario, region, &title)?;
    // In a projection: the volume of each class above each cell of a grid over the plane.
    let projected = (!view.is_whole(scenario.n())).then(|| {
        let grid = PlaneGrid::new(
            view,
            region,
            [report.run.grid[view.x], report.run.grid[view.y]],
        );
        let mut volume: Vec<BTreeMap<(Verdict, bool), f64>> =
            vec![BTreeMap::new(); grid.counts[0] * grid.counts[1]];
        for b in report.after.iter().filter(|b| view.keeps(&b.initial)) {
            let v = b.initial.volume();
            for (k, share) in grid.overlaps(view, &b.initial) {
                *volume[k].entry(verdict_class(b)).or_insert(0.0) += v * share;
            }
        }
        (grid, volume)
    });
    for class in &classes {
        let boxes: Vec<IntervalBox> = class.boxes.iter().map(|b| b.initial.clone()).collect();
        if !any_kept(view, &boxes) {
            continue;
        }
        let colour = class.colour;
        let Some((grid, volume)) = &projected else {
            box_series(&mut chart, view, &boxes, region, colour.filled())?;
            continue;
        };
        // Each grid cell split left to right into stripes, one per class, as wide as the
        // class's share of the volume above the cell.
        let key = class.key;
        let stripes = volume.iter().enumerate().filter_map(|(k, classes)| {
            let total: f64 = classes.values().sum();
            let mine = *classes.get(&key)?;
            let before: f64 = classes.range(..key).map(|(_, a)| a).sum();
            let [(x0, y0), (x1, y1)] = grid.rect(k);
            let at = |a: f64| x0 + (x1 - x0) * a / total;
            Some(Rectangle::new(
                [(at(before), y0), (at(before + mine), y1)],
                colour.filled(),
            ))
        });
        chart.draw_series(stripes).map_err(DrawError::from)?;
    }
    // Thin cell borders so the refinement is visible (left out when cells are tiny or
    // stacked in a projection).
    if report.after.len() <= 3000 && projected.is_none() {
        let all: Vec<IntervalBox> = report.after.iter().map(|b| b.initial.clone()).collect();
        box_series(
            &mut chart,
            view,
            &all,
            region,
            WHITE.mix(0.6).stroke_width(1),
        )?;
    }
    box_series(&mut chart, view, &traps, region, VERMILION.stroke_width(2))?;
    box_series(&mut chart, view, goal, region, BLUE.stroke_width(2))?;
    legend.draw(strip.as_ref())
}

/// Upper ends of the error map's colour classes (the last class is everything finite above).
pub const ERROR_CLASSES: [f64; 7] = [0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.5];

/// The class of a cell bound: `i` for `bound ≤ ERROR_CLASSES[i]` (the first such `i`),
/// `ERROR_CLASSES.len()` for larger finite bounds, one more for +∞ (not certified).
pub fn error_class(bound: f64) -> usize {
    if !bound.is_finite() {
        return ERROR_CLASSES.len() + 1;
    }
    ERROR_CLASSES
        .iter()
        .position(|&t| bound <= t)
        .unwrap_or(ERROR_CLASSES.len())
}

/// Viridis, light (small error) to dark (large), one colour per finite class.
const ERROR_COLOURS: [RGBColor; 8] = [
    RGBColor(253, 231, 37),
    RGBColor(160, 218, 57),
    RGBColor(74, 193, 109),
    RGBColor(31, 161, 135),
    RGBColor(39, 127, 142),
    RGBColor(54, 92, 141),
    RGBColor(70, 50, 126),
    RGBColor(68, 1, 84),
];

/// A class's colour: viridis for the finite ones, vermilion for the uncertified.
fn error_colour(class: usize) -> RGBColor {
    ERROR_COLOURS.get(class).copied().unwrap_or(VERMILION)
}

fn error_class_label(class: usize) -> String {
    match class {
        0 => format!("M ≤ {}", ERROR_CLASSES[0]),
        c if c < ERROR_CLASSES.len() => {
            format!("{} < M ≤ {}", ERROR_CLASSES[c - 1], ERROR_CLASSES[c])
        }
        c if c == ERROR_CLASSES.len() => format!("M > {}", ERROR_CLASSES[c - 1]),
        _ => "not certified (M = ∞)".to_string(),
    }
}

/// An error map's title: the network, the certified and measured maxima, along which state
/// (a picture along one), and whether each place shows the largest bound above it.
fn error_map_title(map: &ErrorMap, along: Option<&str>, whole: bool) -> String {
    let certified = match map.certified_linf {
        Some(m) if m.is_finite() => format!("{m:.3}"),
        Some(_) => "∞".to_string(),
        None => "none".to_string(),
    };
    let along = along.map(|s| format!(" along {s}")).unwrap_or_default();
    let largest = if whole {
        ""
    } else {
        ", largest above each point"
    };
    format!(
        "{}: certified local bound M on ‖N − v‖∞{along} (max {certified}; measured {:.3}){largest}",
        map.network, map.measured_linf
    )
}

pub(super) fn draw_error_map<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    map: &ErrorMap,
) -> Result<(), DrawError> {
    let region = &map.region;
    let title = error_map_title(map, None, view.is_whole(scenario.n()));
    // The cells as boxes, sorted into their classes in one pass; in a projection, the cells
    // of a 96 × 96 grid over the plane, each with the largest bound of the cells above it.
    let uncertified_class = ERROR_CLASSES.len() + 1;
    let mut classes: Vec<Vec<IntervalBox>> = vec![Vec::new(); uncertified_class + 1];
    let cells = map.cells.iter().map(|c| (c.cell(), c.bound));
    if view.is_whole(scenario.n()) {
        for (b, bound) in cells {
            classes[error_class(bound)].push(b);
        }
    } else {
        let grid = PlaneGrid::new(view, region, [96, 96]);
        let mut largest = vec![None::<f64>; 96 * 96];
        for (b, bound) in cells.filter(|(b, _)| view.keeps(b)) {
            for (k, share) in grid.overlaps(view, &b) {
                if share > 0.0 {
                    let m = largest[k].get_or_insert(bound);
                    // +∞ (uncertified) wins; NaN never comes from a loaded map.
                    *m = m.max(bound);
                }
            }
        }
        for (k, bound) in largest.iter().enumerate() {
            if let Some(bound) = bound {
                let [(x0, y0), (x1, y1)] = grid.rect(k);
                // A box in the state space whose view is the grid cell.
                let mut lower = region.center();
                let mut upper = lower.clone();
                (lower[view.x], lower[view.y], upper[view.x], upper[view.y]) = (x0, y0, x1, y1);
                for &(j, v) in &view.slice {
                    (lower[j], upper[j]) = (v, v);
                }
                classes[error_class(*bound)].push(IntervalBox { lower, upper });
            }
        }
    }
    // Shares of the map's volume, or in a projection of the plane's area (the grid cells'
    // boxes are flat along the projected states).
    let whole = view.is_whole(scenario.n());
    let size = |b: &IntervalBox| match whole {
        true => b.volume(),
        false => view.plane(b).volume(),
    };
    let total: f64 = classes.iter().flatten().map(size).sum();
    let mut legend = Legend::default();
    for (class, boxes) in classes
        .iter()
        .enumerate()
        .filter(|(_, b)| any_kept(view, b))
    {
        let colour = error_colour(class);
        let area: f64 = boxes.iter().map(size).sum();
        let label = format!(
            "{} ({} of the mapped area)",
            error_class_label(class),
            percent(100.0 * area / total.max(f64::MIN_POSITIVE))
        );
        legend.push(label, Swatch::Rect(colour.filled()));
    }
    // Over the cells only where every projected value is unsafe: the pale shadow would hide
    // the largest bound above points that are partly safe.
    let shaded = unsafe_layer(root, &mut legend, view, scenario, region, Tones::Every);
    let goal = std::slice::from_ref(&scenario.reach.goal);
    if any_kept(view, goal) {
        legend.push("goal set", Swatch::Rect(BLUE.stroke_width(2)));
    }
    let (area, strip) = legend.split(root);
    let mut chart = chart(&area, view, scenario, region, &title)?;
    for (class, boxes) in classes.iter().enumerate() {
        let colour = error_colour(class);
        box_series(&mut chart, view, boxes, region, colour.filled())?;
    }
    draw_shading(&mut chart, &shaded)?;
    // Uncertified cells are few and tiny (where `L_g h = 0` on S's boundary): ring them, over
    // the shading of the unsafe set they straddle.
    let uncertified = &classes[uncertified_class];
    box_series(
        &mut chart,
        view,
        uncertified,
        region,
        VERMILION.stroke_width(3),
    )?;
    box_series(&mut chart, view, goal, region, BLUE.stroke_width(2))?;
    legend.draw(strip.as_ref())
}

/// A share in percent as the legends give it: one decimal, `< 0.1%` for less.
fn percent(share: f64) -> String {
    if share < 0.05 {
        "< 0.1%".to_string()
    } else {
        format!("{share:.1}%")
    }
}

/// An error map along one state (`--axes t,NAME`, the default for a one-state system): the
/// state across and the certified bound up, each cell a bar as high as its bound, coloured by
/// its class; where other states are projected, the largest bound above each of 400 bands.
pub(super) fn draw_error_map_along<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    map: &ErrorMap,
) -> Result<(), DrawError> {
    let (n, y) = (scenario.n(), view.y);
    let region = &map.region;
    if y >= n || y >= region.dim() || view.slice.iter().any(|&(k, _)| k >= region.dim()) {
        return Err(DrawError::NotPlanar {
            file: scenario.file.clone(),
            n,
        });
    }
    let (lo, hi) = (region.lower[y], region.upper[y]);
    let kept = map.cells.iter().filter(|c| view.keeps(&c.cell()));
    // (from, to, bound) along the state.
    let bars: Vec<(f64, f64, f64)> = if view.is_whole(n) {
        kept.map(|c| (c.lower[y], c.upper[y], c.bound)).collect()
    } else {
        let cells = kept.map(|c| (c.lower[y], c.upper[y], c.bound));
        envelope(cells, (lo, hi), 400)
    };
    let finite = bars.iter().map(|b| b.2).filter(|m| m.is_finite());
    // A little room above the tallest bar and the measured line.
    let top = 1.05
        * finite
            .fold(map.measured_linf, f64::max)
            .max(f64::MIN_POSITIVE);
    let along = Some(scenario.states[y].as_str());
    let title = error_map_title(map, along, view.is_whole(n));
    let title = format!("{title}{}", view.describe(scenario));
    let (state, bound) = (
        scenario.label(&scenario.states[y]),
        match scenario.input_unit() {
            Some(unit) => format!("M [{unit}]"),
            None => "M".to_string(),
        },
    );
    let names = [state.as_str(), bound.as_str()];
    let mut legend = Legend::default();
    let shaded = unsafe_band_layer(&mut legend, view, scenario, region, (lo, hi));
    let uncertified = ERROR_CLASSES.len() + 1;
    let total: f64 = bars.iter().map(|b| b.1 - b.0).sum();
    // Each class's bars and style; uncertified cells reach to the top, pale.
    let mut classes = Vec::new();
    for class in 0..=uncertified {
        let mine: Vec<[(f64, f64); 2]> = (bars.iter())
            .filter(|b| error_class(b.2) == class)
            .map(|&(a, b, m)| [(a, 0.0), (b, if class == uncertified { top } else { m })])
            .collect();
        if mine.is_empty() {
            continue;
        }
        let length: f64 = mine.iter().map(|[a, b]| b.0 - a.0).sum();
        let colour = error_colour(class).mix(if class == uncertified { 0.45 } else { 1.0 });
        let label = format!(
            "{} ({} of the mapped length)",
            error_class_label(class),
            percent(100.0 * length / total.max(f64::MIN_POSITIVE))
        );
        legend.push(label, Swatch::Rect(colour.filled()));
        classes.push((mine, colour.filled()));
    }
    let goal = &scenario.reach.goal;
    let goal_style = BLUE.stroke_width(2);
    legend.push("goal set", Swatch::Rect(goal_style));
    let measured = map.measured_linf;
    let measured_style = DARK.stroke_width(1);
    legend.push(
        format!("measured max ‖N − v‖∞ over C ∩ S ({measured:.3})"),
        Swatch::Line(measured_style),
    );
    let (area, strip) = legend.split(root);
    let mut chart = axes(&area, &title, [(lo, hi), (0.0, top)], names)?;
    draw_shading(&mut chart, &shaded.map(|&(a, b)| [(a, 0.0), (b, top)]))?;
    for (bars, style) in &classes {
        draw_rects(&mut chart, bars, *style)?;
    }
    let (g0, g1) = (goal.lower[y].max(lo), goal.upper[y].min(hi));
    draw_rects(&mut chart, &[[(g0, 0.0), (g1, top)]], goal_style)?;
    chart
        .draw_series(std::iter::once(PathElement::new(
            vec![(lo, measured), (hi, measured)],
            measured_style,
        )))
        .map_err(DrawError::from)?;
    legend.draw(strip.as_ref())
}

/// The largest bound above each of `bands` equal bands of `[lo, hi]`, from cells `(from, to,
/// bound)` along it: `(band's from, band's to, largest bound of the cells that overlap it)`
/// for the bands some cell overlaps. A cell that ends on a band's edge does not reach into the
/// band beyond; +∞ (uncertified) wins.
fn envelope(
    cells: impl Iterator<Item = (f64, f64, f64)>,
    (lo, hi): (f64, f64),
    bands: usize,
) -> Vec<(f64, f64, f64)> {
    let w = (hi - lo) / bands as f64;
    let mut largest = vec![None::<f64>; bands];
    for (a, b, bound) in cells {
        let at = |v: f64| ((v - lo) / w).clamp(0.0, bands as f64);
        let first = (at(a).floor() as usize).min(bands - 1);
        let end = (at(b).ceil() as usize).max(first + 1);
        for m in &mut largest[first..end] {
            *m = Some(m.map_or(bound, |m: f64| m.max(bound)));
        }
    }
    (largest.iter().enumerate())
        .filter_map(|(k, m)| Some((lo + w * k as f64, lo + w * (k + 1) as f64, (*m)?)))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A box's volume is spread over the grid cells its projection overlaps, by the overlap's
    /// share of its area, and nothing is lost: the shares add up to one.
    #[test]
    fn a_projected_box_spreads_its_volume_over_the_cells_it_overlaps() {
        let view = View {
            x: 0,
            y: 2,
            slice: vec![],
            time: false,
        };
        let region = IntervalBox::new(vec![0.0; 3], vec![4.0, 9.0, 2.0]).unwrap();
        let grid = PlaneGrid::new(&view, &region, [4, 2]);
        // x over [0.5, 1.5] (cells 0 and 1, half each), z over [0.5, 1.0] (row 0 alone).
        let b = IntervalBox::new(vec![0.5, 3.0, 0.5], vec![1.5, 7.0, 1.0]).unwrap();
        let mut cells = grid.overlaps(&view, &b);
        cells.sort_by_key(|c| c.0);
        assert_eq!(cells, vec![(0, 0.5), (1, 0.5)]);
        assert_eq!(grid.rect(5), [(1.0, 1.0), (2.0, 2.0)]);
        // Across rows and columns; the total share is one.
        let b = IntervalBox::new(vec![0.0, 0.0, 0.0], vec![4.0, 1.0, 2.0]).unwrap();
        let cells = grid.overlaps(&view, &b);
        assert_eq!(cells.len(), 8);
        let total: f64 = cells.iter().map(|c| c.1).sum();
        assert!((total - 1.0).abs() < 1e-12, "{total}");
    }

    /// A projected error map's legend gives each class's share of the plane's area (its grid
    /// cells' boxes are flat along the projected state: by volume every share read "< 0.1%").
    #[test]
    fn a_projected_error_map_shares_the_planes_area() {
        super::super::register_font();
        let scenario = crate::scenario::Scenario::load(std::path::Path::new(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scenarios/int3.toml"
        )))
        .unwrap();
        // Two cells of int3's region split at x1 = 0.25: a quarter and three quarters.
        let map: ErrorMap = serde_json::from_value(serde_json::json!({
            "format": "cbfreach-errormap-1", "network": "t", "network_hash": "0",
            "region": { "lower": [-1.0, -1.0, -1.5], "upper": [4.0, 4.0, 1.5] },
            "norm": "inf", "measured_linf": 0.01, "measured_l2": 0.01, "certified_linf": 0.5,
            "cells": [
                { "lower": [-1.0, -1.0, -1.5], "upper": [0.25, 4.0, 1.5], "bound": 0.05 },
                { "lower": [0.25, -1.0, -1.5], "upper": [4.0, 4.0, 1.5], "bound": 0.5 },
            ],
        }))
        .unwrap();
        let mut svg = String::new();
        {
            let root = SVGBackend::with_string(&mut svg, (600, 600)).into_drawing_area();
            draw_error_map(&root, &View::default(), &scenario, &map).unwrap();
            root.present().unwrap();
        }
        let text = svg.split_whitespace().collect::<Vec<_>>().join(" ");
        for share in ["(25.0% of the mapped area)", "(75.0% of the mapped area)"] {
            assert!(text.contains(share), "no `{share}`");
        }
        // The spheres' shadows are not drawn over the cells: no pale tone in the legend.
        assert!(!text.contains("for some x3"), "the shadow hides the cells");
    }

    /// Each band carries the largest bound of the cells over it, cells that only touch a
    /// band's edge stay out of it, and an uncertified cell wins.
    #[test]
    fn the_envelope_is_the_largest_bound_above_each_band() {
        let cells = [
            (0.0, 0.5, 0.1),
            (0.25, 0.75, 0.3),
            (0.5, 1.0, 0.2),
            (0.9, 1.0, f64::INFINITY),
        ];
        let e = envelope(cells.into_iter(), (0.0, 1.0), 4);
        let bounds: Vec<f64> = e.iter().map(|b| b.2).collect();
        assert_eq!(bounds, vec![0.1, 0.3, 0.3, f64::INFINITY]);
        assert_eq!((e[1].0, e[1].1), (0.25, 0.5));
        // A cell beyond the range lands in the last band; bands no cell meets are left out.
        let e = envelope(
            [(0.0, 0.2, 1.0), (1.5, 2.0, 2.0)].into_iter(),
            (0.0, 1.0),
            4,
        );
        assert_eq!(e, vec![(0.0, 0.25, 1.0), (0.75, 1.0, 2.0)]);
    }
}

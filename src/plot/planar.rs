//! Pictures over two states of a scenario's own sets: trajectories with the equilibria (paper
//! Fig. 1), tubes (Fig. 2) and Minkowski tubes (Fig. 3). Draws with [`super`]'s palette and
//! [`super::chart`]'s helpers.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::{
    any_kept, box_series, chart, draw_shading, unsafe_layer, Legend, Swatch, Tones,
};
use super::{Chart, DrawError, View, BLUE, DARK, GREEN, GREY, ORANGE, PURPLE, VERMILION};
use crate::boxes::IntervalBox;
use crate::equilibria::{Equilibrium, Stability};
use crate::reach::Tube;
use crate::scenario::Scenario;
use crate::simulate::Trajectory;
use crate::verify::{BoxVerdict, Verdict};

/// The end-point class of a trajectory: 0 the goal, 1 near an undesirable stable equilibrium
/// outside it, 2 other.
pub(super) fn ending(scenario: &Scenario, equilibria: &[Equilibrium], end: &[f64]) -> usize {
    let near = |e: &Equilibrium| {
        e.x.iter()
            .zip(end)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max)
            < 0.05
    };
    // The goal first, as `verify`'s verdicts take it: an undesirable equilibrium inside the
    // goal (a wall the goal touches) is where the user asked to go.
    if scenario.reach.goal.contains(end) {
        0
    } else if equilibria
        .iter()
        .any(|e| e.kind == Stability::Stable && e.undesirable && near(e))
    {
        1
    } else {
        2
    }
}

/// How an equilibrium of one kind is drawn.
#[derive(Clone, Copy)]
enum Marker {
    Dot,
    Cross,
    Triangle,
}

/// The equilibria the view shows, by kind: label, colour, marker, points.
type EquilibriumKind = (&'static str, RGBColor, Marker, Vec<(f64, f64)>);

fn equilibrium_kinds(view: &View, equilibria: &[Equilibrium]) -> Vec<EquilibriumKind> {
    type Kind = (&'static str, fn(&Equilibrium) -> bool, RGBColor, Marker);
    let kinds: [Kind; 4] = [
        (
            "stable equilibrium (goal)",
            |e| e.kind == Stability::Stable && !e.undesirable,
            BLUE,
            Marker::Dot,
        ),
        (
            "stable undesirable equilibrium",
            |e| e.kind == Stability::Stable && e.undesirable,
            VERMILION,
            Marker::Dot,
        ),
        (
            "saddle",
            |e| e.kind == Stability::Saddle,
            DARK,
            Marker::Cross,
        ),
        (
            "unstable / non-hyperbolic",
            |e| matches!(e.kind, Stability::Unstable | Stability::NonHyperbolic),
            PURPLE,
            Marker::Triangle,
        ),
    ];
    (kinds.into_iter())
        .map(|(label, pick, colour, marker)| {
            let pts: Vec<(f64, f64)> = (equilibria.iter())
                .filter(|e| pick(e) && view.keeps_point(&e.x, 1e-6))
                .map(|e| view.point(&e.x))
                .collect();
            (label, colour, marker, pts)
        })
        .filter(|k| !k.3.is_empty())
        .collect()
}

fn legend_equilibria(legend: &mut Legend, kinds: &[EquilibriumKind]) {
    for &(label, colour, marker, _) in kinds {
        legend.push(
            label,
            match marker {
                Marker::Dot => Swatch::Dot(colour.filled()),
                Marker::Cross => Swatch::Cross(colour.stroke_width(3)),
                Marker::Triangle => Swatch::Triangle(colour.filled()),
            },
        );
    }
}

fn draw_equilibria<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    kinds: &[EquilibriumKind],
) -> Result<(), DrawError> {
    for (_, colour, marker, pts) in kinds {
        let (colour, pts) = (*colour, pts.iter().copied());
        match marker {
            Marker::Dot => chart.draw_series(pts.map(|p| {
                EmptyElement::at(p)
                    + Circle::new((0, 0), 7, colour.filled())
                    + Circle::new((0, 0), 7, BLACK.stroke_width(1))
            })),
            Marker::Cross => chart.draw_series(
                pts.map(|p| EmptyElement::at(p) + Cross::new((0, 0), 7, colour.stroke_width(3))),
            ),
            Marker::Triangle => chart.draw_series(
                pts.map(|p| EmptyElement::at(p) + TriangleMarker::new((0, 0), 8, colour.filled())),
            ),
        }
        .map_err(DrawError::from)?;
    }
    Ok(())
}

/// Trajectories as lines through `at(t, x)` (where a point is drawn: the plane's two states,
/// or time and a state), each start as a dot where `starts`.
pub(super) fn draw_lines<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    at: &impl Fn(f64, &[f64]) -> (f64, f64),
    lines: &[&Trajectory],
    style: ShapeStyle,
    starts: bool,
) -> Result<(), DrawError> {
    for t in lines {
        let points = t.t.iter().zip(&t.x).map(|(&ti, x)| at(ti, x));
        chart
            .draw_series(LineSeries::new(points, style))
            .map_err(DrawError::from)?;
        if starts {
            chart
                .draw_series(std::iter::once(Circle::new(
                    at(t.t.first().copied().unwrap_or(0.0), &t.x0),
                    3,
                    style.color.filled(),
                )))
                .map_err(DrawError::from)?;
        }
    }
    Ok(())
}

/// Trajectories sorted by where they end ([`ending`]): label, colour, trajectories, for the
/// classes that have some.
pub(super) type EndingClass<'t> = (&'static str, RGBColor, Vec<&'t Trajectory>);

pub(super) fn by_ending<'t>(
    scenario: &Scenario,
    trajectories: &'t [Trajectory],
    equilibria: &[Equilibrium],
) -> Vec<EndingClass<'t>> {
    let labels = [
        ("ends at the goal", BLUE),
        ("ends at an undesirable equilibrium", VERMILION),
        ("ends elsewhere", GREY),
    ];
    (labels.into_iter().enumerate())
        .map(|(class, (label, colour))| {
            let lines: Vec<&Trajectory> = (trajectories.iter())
                .filter(|t| ending(scenario, equilibria, t.last()) == class)
                .collect();
            (label, colour, lines)
        })
        .filter(|c| !c.2.is_empty())
        .collect()
}

pub(super) fn legend_by_ending(legend: &mut Legend, classes: &[EndingClass]) {
    for (label, colour, _) in classes {
        legend.push(*label, Swatch::Line(colour.stroke_width(3)));
    }
}

/// The trajectories through `at` (as [`draw_lines`]), coloured by where they end.
pub(super) fn draw_by_ending<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    at: &impl Fn(f64, &[f64]) -> (f64, f64),
    classes: &[EndingClass],
) -> Result<(), DrawError> {
    for (_, colour, lines) in classes {
        draw_lines(chart, at, lines, colour.stroke_width(2), true)?;
    }
    Ok(())
}

pub(super) fn draw_trajectories<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    trajectories: &[Trajectory],
    equilibria: &[Equilibrium],
) -> Result<(), DrawError> {
    let region = &scenario.reach.region;
    let title = format!(
        "Filtered system `{}`: trajectories and equilibria",
        scenario.name
    );
    let mut legend = Legend::default();
    let shaded = unsafe_layer(root, &mut legend, view, scenario, region, Tones::Both);
    let classes = by_ending(scenario, trajectories, equilibria);
    legend_by_ending(&mut legend, &classes);
    let kinds = equilibrium_kinds(view, equilibria);
    legend_equilibria(&mut legend, &kinds);
    let (area, strip) = legend.split(root);
    let mut chart = chart(&area, view, scenario, region, &title)?;
    draw_shading(&mut chart, &shaded)?;
    draw_by_ending(&mut chart, &|_, x| view.point(x), &classes)?;
    draw_equilibria(&mut chart, &kinds)?;
    legend.draw(strip.as_ref())
}

/// The colour and label of a tube by its outcome.
pub(super) fn tube_class(scenario: &Scenario, tube: &Tube) -> (RGBColor, &'static str) {
    match tube.last() {
        _ if !tube.valid() => (ORANGE, "invalid (left C, or M = ∞)"),
        Some(s) if s.set.is_subset_of(&scenario.reach.goal) => (BLUE, "reaches the goal"),
        _ => (VERMILION, "does not reach the goal"),
    }
}

fn pick_samples(tube: &Tube, every: usize) -> impl Iterator<Item = &crate::reach::TubeSample> {
    let n = tube.tube.len();
    let every = every.max(1);
    tube.tube
        .iter()
        .enumerate()
        .filter(move |(k, _)| k % every == 0 || k + 1 == n)
        .map(|(_, s)| s)
}

/// Boxes drawn in one style, with the legend's label where they have one.
type BoxLayer = (Vec<IntervalBox>, ShapeStyle, Option<&'static str>);

/// Puts each labelled layer the view shows in the legend.
fn legend_boxes(legend: &mut Legend, view: &View, layers: &[BoxLayer]) {
    for (boxes, style, label) in layers {
        if let Some(label) = label.filter(|_| any_kept(view, boxes)) {
            legend.push(label, Swatch::Rect(*style));
        }
    }
}

/// Draws the layers in order.
fn draw_boxes<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    region: &IntervalBox,
    layers: &[BoxLayer],
) -> Result<(), DrawError> {
    for (boxes, style, _) in layers {
        box_series(chart, view, boxes, region, *style)?;
    }
    Ok(())
}

fn goal_layer(scenario: &Scenario) -> BoxLayer {
    (
        vec![scenario.reach.goal.clone()],
        GREEN.stroke_width(2),
        Some("goal set"),
    )
}

pub(super) fn draw_tubes<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    tubes: &[Tube],
    split: &[(usize, &[BoxVerdict])],
    every: usize,
    title: &str,
) -> Result<(), DrawError> {
    let region = &scenario.reach.region;
    let mut legend = Legend::default();
    let shaded = unsafe_layer(root, &mut legend, view, scenario, region, Tones::Both);
    let mut layers: Vec<BoxLayer> = Vec::new();
    for (k, tube) in tubes.iter().enumerate() {
        if split.iter().any(|&(i, _)| i == k) {
            continue;
        }
        let (colour, label) = tube_class(scenario, tube);
        let boxes: Vec<IntervalBox> = pick_samples(tube, every).map(|s| s.set.clone()).collect();
        layers.push((boxes, colour.mix(0.8).stroke_width(1), Some(label)));
    }
    // A split box's whole sets say nothing (they failed); its pieces and where they end do.
    for (converges, colour, label) in [
        (true, BLUE, "pieces proven to reach the goal, last sets"),
        (false, VERMILION, "pieces proven trapped, last sets"),
    ] {
        let boxes: Vec<IntervalBox> = split
            .iter()
            .flat_map(|(_, leaves)| leaves.iter())
            .filter(|b| (b.verdict == Verdict::Converges) == converges)
            .flat_map(|b| std::iter::once(b.initial.clone()).chain(b.final_set.clone()))
            .collect();
        layers.push((boxes, colour.mix(0.8).stroke_width(1), Some(label)));
    }
    let initial: Vec<IntervalBox> = tubes.iter().map(|t| t.initial.clone()).collect();
    layers.push((initial, BLACK.stroke_width(2), Some("initial boxes")));
    layers.push(goal_layer(scenario));
    legend_boxes(&mut legend, view, &layers);
    let (area, strip) = legend.split(root);
    let mut chart = chart(&area, view, scenario, region, title)?;
    draw_shading(&mut chart, &shaded)?;
    draw_boxes(&mut chart, view, region, &layers)?;
    legend.draw(strip.as_ref())
}

pub(super) fn draw_minkowski<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    tubes: &[Tube],
    trajectories: &[Trajectory],
    every: usize,
) -> Result<(), DrawError> {
    let region = &scenario.reach.region;
    let title = format!(
        "`{}`: NN-system boxes and closeness-inflated sets (Minkowski, paper Thm. 2)",
        scenario.name
    );
    let mut legend = Legend::default();
    let shaded = unsafe_layer(root, &mut legend, view, scenario, region, Tones::Both);
    let mut inflated = Vec::new();
    let mut nn = Vec::new();
    for tube in tubes {
        for s in pick_samples(tube, every) {
            inflated.push(s.set.clone());
            nn.push(IntervalBox {
                lower: s.lower.clone(),
                upper: s.upper.clone(),
            });
        }
    }
    let boxes: Vec<BoxLayer> = vec![
        (
            inflated,
            VERMILION.mix(0.7).stroke_width(1),
            Some("with closeness radius r_t (filtered system)"),
        ),
        (nn, BLUE.stroke_width(1), Some("without (NN system)")),
    ];
    legend_boxes(&mut legend, view, &boxes);
    let lines: Vec<&Trajectory> = trajectories.iter().collect();
    let line_style = BLACK.mix(0.6).stroke_width(1);
    if !lines.is_empty() {
        legend.push("filtered trajectories", Swatch::Line(line_style));
    }
    let goal = [goal_layer(scenario)];
    legend_boxes(&mut legend, view, &goal);
    let (area, strip) = legend.split(root);
    let mut chart = chart(&area, view, scenario, region, &title)?;
    draw_shading(&mut chart, &shaded)?;
    draw_boxes(&mut chart, view, region, &boxes)?;
    draw_lines(&mut chart, &|_, x| view.point(x), &lines, line_style, false)?;
    draw_boxes(&mut chart, view, region, &goal)?;
    legend.draw(strip.as_ref())
}

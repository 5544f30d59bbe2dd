//! Pictures over two states of a scenario's own sets: trajectories with the equilibria (paper
//! Fig. 1), tubes (Fig. 2) and Minkowski tubes (Fig. 3). Draws with [`super`]'s palette and
//! [`super::chart`]'s helpers.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::{box_series, chart, legend, shade_unsafe};
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

fn draw_equilibria<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    equilibria: &[Equilibrium],
) -> Result<(), DrawError> {
    type Kind = (&'static str, fn(&Equilibrium) -> bool, RGBColor, u8);
    let kinds: [Kind; 4] = [
        (
            "stable equilibrium (goal)",
            |e| e.kind == Stability::Stable && !e.undesirable,
            BLUE,
            0,
        ),
        (
            "stable undesirable equilibrium",
            |e| e.kind == Stability::Stable && e.undesirable,
            VERMILION,
            0,
        ),
        ("saddle", |e| e.kind == Stability::Saddle, DARK, 1),
        (
            "unstable / non-hyperbolic",
            |e| matches!(e.kind, Stability::Unstable | Stability::NonHyperbolic),
            PURPLE,
            2,
        ),
    ];
    for (label, pick, colour, shape) in kinds {
        let pts: Vec<(f64, f64)> = equilibria
            .iter()
            .filter(|e| pick(e) && view.keeps_point(&e.x, 1e-6))
            .map(|e| view.point(&e.x))
            .collect();
        if pts.is_empty() {
            continue;
        }
        let series = match shape {
            0 => chart.draw_series(pts.into_iter().map(|p| {
                EmptyElement::at(p)
                    + Circle::new((0, 0), 7, colour.filled())
                    + Circle::new((0, 0), 7, BLACK.stroke_width(1))
            })),
            1 => chart.draw_series(
                pts.into_iter()
                    .map(|p| EmptyElement::at(p) + Cross::new((0, 0), 7, colour.stroke_width(3))),
            ),
            _ => chart
                .draw_series(pts.into_iter().map(|p| {
                    EmptyElement::at(p) + TriangleMarker::new((0, 0), 8, colour.filled())
                })),
        }
        .map_err(DrawError::from)?;
        let style: ShapeStyle = if shape == 1 {
            colour.stroke_width(3)
        } else {
            colour.filled()
        };
        series.label(label).legend(move |(x, y)| {
            if shape == 1 {
                Cross::new((x + 7, y), 6, style).into_dyn()
            } else {
                Circle::new((x + 7, y), 6, style).into_dyn()
            }
        });
    }
    Ok(())
}

/// Trajectories as lines through `at(t, x)` (where a point is drawn: the plane's two states,
/// or time and a state), the first labelled, each start as a dot where `starts`.
pub(super) fn draw_lines<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    at: &impl Fn(f64, &[f64]) -> (f64, f64),
    lines: &[&Trajectory],
    style: ShapeStyle,
    label: Option<&str>,
    starts: bool,
) -> Result<(), DrawError> {
    let mut first = true;
    for t in lines {
        let points = t.t.iter().zip(&t.x).map(|(&ti, x)| at(ti, x));
        let s = chart
            .draw_series(LineSeries::new(points, style))
            .map_err(DrawError::from)?;
        if first {
            if let Some(l) = label {
                s.label(l).legend(move |(x, y)| {
                    PathElement::new(vec![(x, y), (x + 16, y)], style.stroke_width(3))
                });
            }
            first = false;
        }
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

/// The trajectories through `at` (as [`draw_lines`]), coloured by where they end ([`ending`]).
pub(super) fn draw_by_ending<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    at: &impl Fn(f64, &[f64]) -> (f64, f64),
    scenario: &Scenario,
    trajectories: &[Trajectory],
    equilibria: &[Equilibrium],
) -> Result<(), DrawError> {
    let labels = [
        ("ends at the goal", BLUE),
        ("ends at an undesirable equilibrium", VERMILION),
        ("ends elsewhere", GREY),
    ];
    for (class, (label, colour)) in labels.iter().enumerate() {
        let lines: Vec<&Trajectory> = trajectories
            .iter()
            .filter(|t| ending(scenario, equilibria, t.last()) == class)
            .collect();
        draw_lines(chart, at, &lines, colour.stroke_width(2), Some(label), true)?;
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
    let mut chart = chart(root, view, scenario, region, &title)?;
    shade_unsafe(&mut chart, view, scenario, region)?;
    let at = |_: f64, x: &[f64]| view.point(x);
    draw_by_ending(&mut chart, &at, scenario, trajectories, equilibria)?;
    draw_equilibria(&mut chart, view, equilibria)?;
    legend(&mut chart)?;
    Ok(())
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

fn draw_goal<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
    chart: &mut Chart<'a, DB>,
    view: &View,
    scenario: &Scenario,
) -> Result<(), DrawError> {
    box_series(
        chart,
        view,
        std::slice::from_ref(&scenario.reach.goal),
        &scenario.reach.region,
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
    let mut chart = chart(root, view, scenario, region, title)?;
    shade_unsafe(&mut chart, view, scenario, region)?;
    let mut seen: Vec<&str> = Vec::new();
    for (k, tube) in tubes.iter().enumerate() {
        if split.iter().any(|&(i, _)| i == k) {
            continue;
        }
        let (colour, label) = tube_class(scenario, tube);
        let boxes: Vec<IntervalBox> = pick_samples(tube, every).map(|s| s.set.clone()).collect();
        let new = !seen.contains(&label);
        if new {
            seen.push(label);
        }
        box_series(
            &mut chart,
            view,
            &boxes,
            region,
            colour.mix(0.8).stroke_width(1),
            new.then_some(label),
        )?;
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
        if !boxes.is_empty() {
            let style = colour.mix(0.8).stroke_width(1);
            box_series(&mut chart, view, &boxes, region, style, Some(label))?;
        }
    }
    let initial: Vec<IntervalBox> = tubes.iter().map(|t| t.initial.clone()).collect();
    box_series(
        &mut chart,
        view,
        &initial,
        region,
        BLACK.stroke_width(2),
        Some("initial boxes"),
    )?;
    draw_goal(&mut chart, view, scenario)?;
    legend(&mut chart)?;
    Ok(())
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
    let mut chart = chart(root, view, scenario, region, &title)?;
    shade_unsafe(&mut chart, view, scenario, region)?;
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
    box_series(
        &mut chart,
        view,
        &inflated,
        region,
        VERMILION.mix(0.7).stroke_width(1),
        Some("with closeness radius r_t (filtered system)"),
    )?;
    box_series(
        &mut chart,
        view,
        &nn,
        region,
        BLUE.stroke_width(1),
        Some("without (NN system)"),
    )?;
    let lines: Vec<&Trajectory> = trajectories.iter().collect();
    draw_lines(
        &mut chart,
        &|_, x| view.point(x),
        &lines,
        BLACK.mix(0.6).stroke_width(1),
        Some("filtered trajectories"),
        false,
    )?;
    draw_goal(&mut chart, view, scenario)?;
    legend(&mut chart)?;
    Ok(())
}

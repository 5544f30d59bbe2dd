//! Pictures over time (`--axes t,NAME`, as JuliaReach's `vars = (0, k)`): one state's sets and
//! trajectories against `t`, the other states projected (or sliced), and a verdict map as each
//! box's band until its tube ended. With the error map along the state (`maps`), the pictures
//! a one-state system has. Draws with [`super`]'s palette and legend.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::{axes, legend, line_swatch, swatch, unsafe_bands};
use super::maps::{verdict_classes, verdicts_title};
use super::planar::{draw_by_ending, tube_class};
use super::view::View;
use super::{Chart, DrawError, DARK, GREEN, OBSTACLE};
use crate::boxes::IntervalBox;
use crate::equilibria::Equilibrium;
use crate::reach::Tube;
use crate::scenario::Scenario;
use crate::simulate::Trajectory;
use crate::verify::VerifyReport;

/// The chart: `t` from 0 to `horizon` across, the drawn state up over `region`'s extent,
/// with the unsafe set shaded where the state alone decides it (one state, all others sliced)
/// and the goal's band.
fn time_chart<'a, DB: DrawingBackend<ErrorType: 'static>>(
    root: &'a DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    (region, horizon): (&IntervalBox, f64),
    title: &str,
) -> Result<Chart<'a, DB>, DrawError> {
    let n = scenario.n();
    let y = view.y;
    let dim = region.dim().min(n);
    if y >= dim || view.slice.iter().any(|&(k, _)| k >= dim) {
        return Err(DrawError::NotPlanar {
            file: scenario.file.clone(),
            n,
        });
    }
    let (lo, hi) = (region.lower[y], region.upper[y]);
    let title = format!("{title}{}", view.describe(scenario));
    let state = scenario.label(&scenario.states[y]);
    let time = scenario.time_label();
    let names = [time.as_str(), state.as_str()];
    let mut chart = axes(root, &title, [(0.0, horizon), (lo, hi)], names)?;
    if view.is_whole(n) {
        let bands = unsafe_bands(view, scenario, region, (lo, hi), 400);
        let shaded = (bands.into_iter())
            .map(|(a, b)| Rectangle::new([(0.0, a), (horizon, b)], OBSTACLE.filled()));
        chart.draw_series(shaded).map_err(DrawError::from)?;
    }
    let goal = &scenario.reach.goal;
    let style = GREEN.stroke_width(2);
    chart
        .draw_series(std::iter::once(Rectangle::new(
            [
                (0.0, goal.lower[y].max(lo)),
                (horizon, goal.upper[y].min(hi)),
            ],
            style,
        )))
        .map_err(DrawError::from)?
        .label("goal set")
        .legend(swatch(style));
    Ok(chart)
}

/// The tubes against time: in continuous time (and sampled-data) the hull of each `every`
/// recorded samples' flowpipes as a bar over their time interval, which holds every state of
/// that interval; for the Euler map, which has no states between its samples, every
/// `every`-th set as a line at its time.
pub(super) fn draw_tubes_over_time<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    tubes: &[&Tube],
    every: usize,
    title: &str,
) -> Result<(), DrawError> {
    let region = &scenario.reach.region;
    let mut chart = time_chart(
        root,
        view,
        scenario,
        (region, scenario.reach.horizon),
        title,
    )?;
    let y = view.y;
    let (lo, hi) = (region.lower[y], region.upper[y]);
    let clip = |v: f64| v.clamp(lo, hi);
    let mut seen: Vec<&str> = Vec::new();
    for &tube in tubes {
        let (colour, label) = tube_class(scenario, tube);
        let style = colour.mix(0.5).filled();
        let mut bars = Vec::new();
        let mut lines = Vec::new();
        if view.keeps(&tube.initial) {
            let b = &tube.initial;
            lines.push(vec![(0.0, clip(b.lower[y])), (0.0, clip(b.upper[y]))]);
        }
        let mut since = 0.0;
        for chunk in tube.tube.chunks(every.max(1)) {
            let last = &chunk[chunk.len() - 1];
            let pipes: Option<Vec<&IntervalBox>> =
                chunk.iter().map(|s| s.flowpipe.as_ref()).collect();
            match pipes {
                Some(pipes) => {
                    // Slices keep the steps whose flowpipe meets them.
                    let hull = pipes.into_iter().filter(|p| view.keeps(p)).fold(
                        None::<(f64, f64)>,
                        |h, p| {
                            let (lo, hi) = (p.lower[y], p.upper[y]);
                            Some(h.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))))
                        },
                    );
                    if let Some((lo, hi)) = hull {
                        bars.push([(since, clip(lo)), (last.t, clip(hi))]);
                    }
                }
                None if view.keeps(&last.set) => lines.push(vec![
                    (last.t, clip(last.set.lower[y])),
                    (last.t, clip(last.set.upper[y])),
                ]),
                None => {}
            }
            since = last.t;
        }
        let new = !seen.contains(&label);
        if new {
            seen.push(label);
        }
        let series = chart
            .draw_series(bars.into_iter().map(|r| Rectangle::new(r, style)))
            .map_err(DrawError::from)?;
        if new {
            series.label(label).legend(swatch(style));
        }
        chart
            .draw_series(
                lines
                    .into_iter()
                    .map(|l| PathElement::new(l, colour.mix(0.8).stroke_width(2))),
            )
            .map_err(DrawError::from)?;
    }
    legend(&mut chart)
}

/// The trajectories against time, coloured by where they end, and the equilibria's values of
/// the drawn state as thin lines.
pub(super) fn draw_trajectories_over_time<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    trajectories: &[Trajectory],
    equilibria: &[Equilibrium],
) -> Result<(), DrawError> {
    let title = format!("Filtered system `{}`: trajectories", scenario.name);
    let over = (&scenario.reach.region, scenario.reach.horizon);
    let mut chart = time_chart(root, view, scenario, over, &title)?;
    let y = view.y;
    draw_by_ending(
        &mut chart,
        &|t, x| (t, x[y]),
        scenario,
        trajectories,
        equilibria,
    )?;
    if !equilibria.is_empty() {
        let horizon = scenario.reach.horizon;
        let style = DARK.stroke_width(1);
        chart
            .draw_series(
                equilibria
                    .iter()
                    .map(|e| PathElement::new(vec![(0.0, e.x[y]), (horizon, e.x[y])], style)),
            )
            .map_err(DrawError::from)?
            .label("equilibria")
            .legend(line_swatch(style));
    }
    legend(&mut chart)
}

/// A verdict map over time: each leaf's interval of the drawn state as a band from `t = 0` to
/// the time its tube ended (a verified leaf's: when its set was proven in the goal or a trap),
/// coloured by its verdict; a leaf with no tube (it starts unsafe) spans the horizon. Needs
/// every other state sliced ([`super::Kind::check`]), so that the bands tile the state.
pub(super) fn draw_verdicts_over_time<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    view: &View,
    scenario: &Scenario,
    report: &VerifyReport,
) -> Result<(), DrawError> {
    let region = &report.run.region;
    let ends = report.after.iter().filter_map(|b| b.t_end);
    let horizon = ends.fold(scenario.reach.horizon, f64::max);
    let title = format!("{}; each box until its tube ended", verdicts_title(report));
    let mut chart = time_chart(root, view, scenario, (region, horizon), &title)?;
    let y = view.y;
    let clip = |v: f64| v.clamp(region.lower[y], region.upper[y]);
    for class in verdict_classes(report) {
        let style = class.colour.filled();
        let bands = (class.boxes.iter())
            .filter(|b| view.keeps(&b.initial))
            .map(|b| {
                let (lo, hi) = (clip(b.initial.lower[y]), clip(b.initial.upper[y]));
                Rectangle::new([(0.0, lo), (b.t_end.unwrap_or(horizon), hi)], style)
            })
            .collect::<Vec<_>>();
        if bands.is_empty() {
            continue;
        }
        chart
            .draw_series(bands)
            .map_err(DrawError::from)?
            .label(class.label)
            .legend(swatch(style));
    }
    legend(&mut chart)
}

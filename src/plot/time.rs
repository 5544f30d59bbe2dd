//! Pictures over time (`--axes t,NAME`, as JuliaReach's `vars = (0, k)`): one state's sets and
//! trajectories against `t`, the other states projected (or sliced), and a verdict map as each
//! box's band until its tube ended. With the error map along the state (`maps`), the pictures
//! a one-state system has. Draws with [`super`]'s palette and legend.

use plotters::coord::Shift;
use plotters::prelude::*;

use super::chart::{axes, draw_rects, draw_shading, unsafe_band_layer, Legend, Shading, Swatch};
use super::maps::{verdict_classes, verdicts_title};
use super::planar::{by_ending, draw_by_ending, legend_by_ending, tube_class};
use super::view::View;
use super::{Chart, DrawError, DARK, GREEN};
use crate::boxes::IntervalBox;
use crate::equilibria::Equilibrium;
use crate::reach::Tube;
use crate::scenario::Scenario;
use crate::simulate::Trajectory;
use crate::verify::VerifyReport;

/// The time chart's ranges and axis names: `t` from 0 to `horizon` across, the drawn state up
/// over `region`'s extent. Checks that the view fits the scenario.
struct TimeAxes {
    y: usize,
    range: (f64, f64),
    horizon: f64,
    title: String,
    names: [String; 2],
}

impl TimeAxes {
    fn new(
        view: &View,
        scenario: &Scenario,
        (region, horizon): (&IntervalBox, f64),
        title: &str,
    ) -> Result<TimeAxes, DrawError> {
        let n = scenario.n();
        let y = view.y;
        let dim = region.dim().min(n);
        if y >= dim || view.slice.iter().any(|&(k, _)| k >= dim) {
            return Err(DrawError::NotPlanar {
                file: scenario.file.clone(),
                n,
            });
        }
        Ok(TimeAxes {
            y,
            range: (region.lower[y], region.upper[y]),
            horizon,
            title: format!("{title}{}", view.describe(scenario)),
            names: [scenario.time_label(), scenario.label(&scenario.states[y])],
        })
    }

    /// The chart on `area` with the unsafe set's `shaded` bands and the goal's band drawn.
    fn chart<'a, DB: DrawingBackend<ErrorType: 'static>>(
        &self,
        area: &'a DrawingArea<DB, Shift>,
        shaded: &Shading<(f64, f64)>,
        goal: &IntervalBox,
    ) -> Result<Chart<'a, DB>, DrawError> {
        let (lo, hi) = self.range;
        let names = [self.names[0].as_str(), self.names[1].as_str()];
        let mut chart = axes(area, &self.title, [(0.0, self.horizon), (lo, hi)], names)?;
        draw_shading(
            &mut chart,
            &shaded.map(|&(a, b)| [(0.0, a), (self.horizon, b)]),
        )?;
        let (g0, g1) = (goal.lower[self.y].max(lo), goal.upper[self.y].min(hi));
        draw_rects(
            &mut chart,
            &[[(0.0, g0), (self.horizon, g1)]],
            GREEN.stroke_width(2),
        )?;
        Ok(chart)
    }

    /// The unsafe set's bands along the drawn state (the others sliced, or projected: its
    /// shadow) and the legend's first entries: the shading (where any) and the goal.
    fn legend(
        &self,
        view: &View,
        scenario: &Scenario,
        region: &IntervalBox,
    ) -> (Legend, Shading<(f64, f64)>) {
        let mut legend = Legend::default();
        let shaded = unsafe_band_layer(&mut legend, view, scenario, region, self.range);
        legend.push("goal set", Swatch::Rect(GREEN.stroke_width(2)));
        (legend, shaded)
    }
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
    let time = TimeAxes::new(view, scenario, (region, scenario.reach.horizon), title)?;
    let (mut legend, shaded) = time.legend(view, scenario, region);
    let y = view.y;
    let (lo, hi) = time.range;
    let clip = |v: f64| v.clamp(lo, hi);
    // Each tube's bars (flowpipes over time) and lines (sets at one time), in its class's style.
    let mut drawn = Vec::new();
    for &tube in tubes {
        let (colour, label) = tube_class(scenario, tube);
        let style = colour.mix(0.5).filled();
        let mut bars = Vec::new();
        let mut lines = Vec::new();
        if view.keeps(&tube.initial) {
            let b = &tube.initial;
            lines.push(vec![(0.0, clip(b.lower[y])), (0.0, clip(b.upper[y]))]);
        }
        // Steps of continuous time (and sampled data) have flowpipes; the first sample, the
        // initial set, has none and holds the state at t = 0 itself.
        let piped = tube.tube.iter().any(|s| s.flowpipe.is_some());
        let mut since = 0.0;
        for chunk in tube.tube.chunks(every.max(1)) {
            let last = &chunk[chunk.len() - 1];
            if piped {
                // Slices keep the steps whose flowpipe meets them.
                let pipes = chunk.iter().map(|s| s.flowpipe.as_ref().unwrap_or(&s.set));
                let hull = pipes
                    .filter(|p| view.keeps(p))
                    .fold(None::<(f64, f64)>, |h, p| {
                        let (lo, hi) = (p.lower[y], p.upper[y]);
                        Some(h.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))))
                    });
                if let Some((lo, hi)) = hull {
                    bars.push([(since, clip(lo)), (last.t, clip(hi))]);
                }
            } else if view.keeps(&last.set) {
                lines.push(vec![
                    (last.t, clip(last.set.lower[y])),
                    (last.t, clip(last.set.upper[y])),
                ]);
            }
            since = last.t;
        }
        legend.push(label, Swatch::Rect(style));
        drawn.push((bars, style, lines, colour.mix(0.8).stroke_width(2)));
    }
    let (area, strip) = legend.split(root);
    let mut chart = time.chart(&area, &shaded, &scenario.reach.goal)?;
    for (bars, style, lines, line_style) in drawn {
        draw_rects(&mut chart, &bars, style)?;
        chart
            .draw_series(lines.into_iter().map(|l| PathElement::new(l, line_style)))
            .map_err(DrawError::from)?;
    }
    legend.draw(strip.as_ref())
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
    let region = &scenario.reach.region;
    let time = TimeAxes::new(view, scenario, (region, scenario.reach.horizon), &title)?;
    let (mut legend, shaded) = time.legend(view, scenario, region);
    let classes = by_ending(scenario, trajectories, equilibria);
    legend_by_ending(&mut legend, &classes);
    let style = DARK.stroke_width(1);
    if !equilibria.is_empty() {
        legend.push("equilibria", Swatch::Line(style));
    }
    let (area, strip) = legend.split(root);
    let mut chart = time.chart(&area, &shaded, &scenario.reach.goal)?;
    let y = view.y;
    draw_by_ending(&mut chart, &|t, x| (t, x[y]), &classes)?;
    let horizon = time.horizon;
    chart
        .draw_series(
            (equilibria.iter())
                .map(|e| PathElement::new(vec![(0.0, e.x[y]), (horizon, e.x[y])], style)),
        )
        .map_err(DrawError::from)?;
    legend.draw(strip.as_ref())
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
    let time = TimeAxes::new(view, scenario, (region, horizon), &title)?;
    let (mut legend, shaded) = time.legend(view, scenario, region);
    let y = view.y;
    let clip = |v: f64| v.clamp(region.lower[y], region.upper[y]);
    let mut classes = Vec::new();
    for class in verdict_classes(report) {
        let bands: Vec<[(f64, f64); 2]> = (class.boxes.iter())
            .filter(|b| view.keeps(&b.initial))
            .map(|b| {
                let (lo, hi) = (clip(b.initial.lower[y]), clip(b.initial.upper[y]));
                [(0.0, lo), (b.t_end.unwrap_or(horizon), hi)]
            })
            .collect();
        if !bands.is_empty() {
            let style = class.colour.filled();
            legend.push(class.label, Swatch::Rect(style));
            classes.push((bands, style));
        }
    }
    let (area, strip) = legend.split(root);
    let mut chart = time.chart(&area, &shaded, &scenario.reach.goal)?;
    for (bands, style) in &classes {
        draw_rects(&mut chart, bands, *style)?;
    }
    legend.draw(strip.as_ref())
}

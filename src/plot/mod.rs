//! Pictures with plotters: the paper's Figures 1–3 and a verdict map, as PNG or SVG (by the
//! file's extension).
//!
//! - [`Figure::Trajectories`] (paper Fig. 1): filtered-system trajectories, coloured by where
//!   they end, over the unsafe set, with the equilibria marked by kind;
//! - [`Figure::Tubes`] (Fig. 2): the boxes of reach tubes every K recorded samples, coloured by
//!   the tube's outcome, with the initial boxes and the goal;
//! - [`Figure::Minkowski`] (Fig. 3): the NN-system boxes and the same boxes inflated by the
//!   closeness radius `r_t`, with filtered trajectories from points of the initial boxes;
//! - [`Figure::Verdicts`]: every box of a [`VerifyReport`] coloured by its verdict;
//! - [`Figure::ErrorMap`]: every cell of a network's [`ErrorMap`] coloured by its certified
//!   bound on `‖N − v‖∞`, the local `M` the reach engine uses (docs/design.md §2b: where it is
//!   large, tubes grow).
//!
//! The unsafe set is shaded cell by cell: a cell of a fine grid over the plot is grey when some
//! `hᵢ < 0` at its centre (a picture, not a proof). Text uses the embedded DejaVu Sans
//! (`assets/DejaVuSans.ttf`, license beside it), registered once as `sans-serif`.

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::boxes::IntervalBox;
use crate::equilibria::{Equilibrium, Stability};
use crate::error_map::ErrorMap;
use crate::reach::Tube;
use crate::scenario::Scenario;
use crate::simulate::Trajectory;
use crate::verify::{BoxVerdict, Verdict, VerifyReport};

mod maps;
mod time;
mod view;

use maps::{draw_error_map, draw_verdicts};
pub use maps::{error_class, verdicts_title, ERROR_CLASSES};
pub use view::View;

const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// Why a picture could not be made.
#[derive(Debug, thiserror::Error)]
pub enum PlotError {
    /// The output's extension is neither `.png` nor `.svg`.
    #[error("{0}: unknown picture format (use a .png or .svg file name)")]
    Format(String),
    /// Bad figure data or size.
    #[error("{0}")]
    Input(String),
    /// Drawing or writing the file failed.
    #[error("{path}: {source}")]
    Draw {
        /// The output file.
        path: String,
        /// What went wrong.
        source: DrawError,
    },
}

/// Why a figure could not be drawn on its canvas.
#[derive(Debug, thiserror::Error)]
pub enum DrawError {
    /// The view's states are not the scenario's (a view made for another system).
    #[error("the picture's view does not fit {file} ({n} states)")]
    NotPlanar {
        /// The scenario file.
        file: String,
        /// Its number of states.
        n: usize,
    },
    /// A figure drawn over two states was asked over time.
    #[error(
        "{figure} are drawn over two states, not over time ({file}: over time, tubes, \
         trajectories, verdict maps and error maps are)"
    )]
    NotOverTime {
        /// The scenario file.
        file: String,
        /// The figure, in the plural.
        figure: &'static str,
    },
    /// A verdict map over time asked with a state projected: the boxes' bands would cover
    /// each other.
    #[error(
        "verdict maps over time show each box as one band, which needs every other state of \
         {file} sliced (--slice {example}=VALUE): projected, the boxes would cover each other"
    )]
    ProjectedOverTime {
        /// The scenario file.
        file: String,
        /// A projected state's name.
        example: String,
    },
    /// Verdicts or an error map of a system with another number of states than the
    /// scenario's.
    #[error("{what} of a system with {}, not of {file} ({})", states_text(*.states), states_text(*.n))]
    OtherSystem {
        /// The figure's data, in words.
        what: &'static str,
        /// Their number of states.
        states: usize,
        /// The scenario file.
        file: String,
        /// Its number of states.
        n: usize,
    },
    /// plotters or its backend failed (its error type depends on the backend).
    #[error("{0}")]
    Plotters(#[source] Box<dyn std::error::Error + Send + Sync>),
    /// The finished picture could not be moved into place.
    #[error("{0}")]
    Io(#[from] std::io::Error),
}

/// `1 state`, `3 states`.
fn states_text(n: usize) -> String {
    match n {
        1 => "1 state".to_string(),
        n => format!("{n} states"),
    }
}

impl<E: std::error::Error + Send + Sync + 'static> From<DrawingAreaErrorKind<E>> for DrawError {
    fn from(e: DrawingAreaErrorKind<E>) -> DrawError {
        DrawError::Plotters(Box::new(e))
    }
}

/// The kinds of [`Figure`], for what can be checked before a figure's data are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kind {
    /// [`Figure::Trajectories`].
    Trajectories,
    /// [`Figure::Tubes`].
    Tubes,
    /// [`Figure::Minkowski`].
    Minkowski,
    /// [`Figure::Verdicts`].
    Verdicts,
    /// [`Figure::ErrorMap`].
    ErrorMap,
}

impl Kind {
    /// Whether `view` of `scenario` can show this kind of figure: over time, Minkowski tubes
    /// are not drawn (their inflated sets are planar pictures), and verdict maps need every
    /// other state sliced.
    pub fn check(self, view: &View, scenario: &Scenario) -> Result<(), DrawError> {
        let file = || scenario.file.clone();
        match self {
            _ if !view.time => Ok(()),
            Kind::Minkowski => Err(DrawError::NotOverTime {
                file: file(),
                figure: "Minkowski tubes",
            }),
            Kind::Verdicts if !view.is_whole(scenario.n()) => {
                let projected = (0..scenario.n())
                    .find(|&k| k != view.y && view.slice.iter().all(|&(j, _)| j != k))
                    .unwrap_or(view.y);
                Err(DrawError::ProjectedOverTime {
                    file: file(),
                    example: scenario.states[projected].clone(),
                })
            }
            _ => Ok(()),
        }
    }
}

/// What to draw.
pub enum Figure<'a> {
    /// Filtered-system trajectories with the unsafe set and the equilibria.
    Trajectories {
        /// The scenario (region, CBFs, state names).
        scenario: &'a Scenario,
        /// The trajectories.
        trajectories: &'a [Trajectory],
        /// The equilibria.
        equilibria: &'a [Equilibrium],
    },
    /// Reach tubes: boxes every `every` recorded samples.
    Tubes {
        /// The scenario.
        scenario: &'a Scenario,
        /// The tubes.
        tubes: &'a [Tube],
        /// Boxes proven in pieces: the index of the box's tube, drawn as its pieces (outlined
        /// in their verdict's colour, with their last sets) in place of the whole box's sets.
        split: &'a [(usize, &'a [BoxVerdict])],
        /// Draw every K-th recorded sample (and the last).
        every: usize,
        /// The title.
        title: String,
    },
    /// Minkowski-method tubes: NN-system boxes and inflated sets, with filtered trajectories.
    Minkowski {
        /// The scenario.
        scenario: &'a Scenario,
        /// Tubes of the Minkowski method.
        tubes: &'a [Tube],
        /// Filtered trajectories from points of the initial boxes.
        trajectories: &'a [Trajectory],
        /// Draw every K-th recorded sample (and the last).
        every: usize,
    },
    /// A verdict map.
    Verdicts {
        /// The scenario (for names and the unsafe set).
        scenario: &'a Scenario,
        /// The verdicts.
        report: &'a VerifyReport,
    },
    /// An error map: each cell coloured by its certified bound.
    ErrorMap {
        /// The scenario (for names, the unsafe set and the goal).
        scenario: &'a Scenario,
        /// The map (`cbfreach error`).
        map: &'a ErrorMap,
    },
}

/// A pixel size with the region's aspect ratio: about `width` wide, height between 300 and 1000
/// (one state: 0.6 × `width`).
pub fn default_size(region: &IntervalBox, width: u32) -> (u32, u32) {
    let w = region.widths();
    if w.len() < 2 {
        // One state: drawn over time or along the state, a wide picture.
        return (width, (0.6 * width as f64) as u32);
    }
    let ratio = if w[0] > 0.0 { w[1] / w[0] } else { 0.75 };
    let plot_w = width.saturating_sub(120) as f64;
    let h = (plot_w * ratio + 130.0).clamp(300.0, 1000.0) as u32;
    (width, h)
}

/// Draws `figure` into `path` (`.png` or `.svg`) at `size` pixels: the first two states, the
/// others projected (one state: over time).
pub fn save(figure: &Figure, path: &Path, size: (u32, u32)) -> Result<(), PlotError> {
    save_view(figure, &View::first(figure.scenario().n()), path, size)
}

impl Figure<'_> {
    /// Whether the figure's data (verdicts, an error map) are of the scenario's system: a
    /// report or map of another number of states is refused rather than drawn across the
    /// wrong axes.
    pub fn check_data(&self) -> Result<(), DrawError> {
        let (what, states) = match self {
            Figure::Verdicts { report, .. } => ("verdicts", report.run.region.dim()),
            Figure::ErrorMap { map, .. } => ("an error map", map.region.dim()),
            _ => return Ok(()),
        };
        let scenario = self.scenario();
        match states == scenario.n() {
            true => Ok(()),
            false => Err(DrawError::OtherSystem {
                what,
                states,
                file: scenario.file.clone(),
                n: scenario.n(),
            }),
        }
    }

    /// Its kind.
    pub fn kind(&self) -> Kind {
        match self {
            Figure::Trajectories { .. } => Kind::Trajectories,
            Figure::Tubes { .. } => Kind::Tubes,
            Figure::Minkowski { .. } => Kind::Minkowski,
            Figure::Verdicts { .. } => Kind::Verdicts,
            Figure::ErrorMap { .. } => Kind::ErrorMap,
        }
    }

    /// The scenario drawn.
    pub fn scenario(&self) -> &Scenario {
        match self {
            Figure::Trajectories { scenario, .. }
            | Figure::Tubes { scenario, .. }
            | Figure::Minkowski { scenario, .. }
            | Figure::Verdicts { scenario, .. }
            | Figure::ErrorMap { scenario, .. } => scenario,
        }
    }
}

/// Draws `figure` as `view` sees it into `path` (`.png` or `.svg`) at `size` pixels.
pub fn save_view(
    figure: &Figure,
    view: &View,
    path: &Path,
    size: (u32, u32),
) -> Result<(), PlotError> {
    REGISTER.call_once(|| {
        // The embedded font is valid; if registration failed, text would be missing but the
        // drawing itself still errors clearly below.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
    if size.0 < 100 || size.1 < 100 || size.0 > 20_000 || size.1 > 20_000 {
        return Err(PlotError::Input(format!(
            "picture size {}×{}: each side must be between 100 and 20000 pixels",
            size.0, size.1
        )));
    }
    let name = path.display().to_string();
    let draw_err = |source: DrawError| PlotError::Draw {
        path: name.clone(),
        source,
    };
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(str::to_ascii_lowercase);
    // Drawn beside `path` and renamed over it: a failed drawing leaves the old picture.
    let io_err = |source: std::io::Error| PlotError::Draw {
        path: name.clone(),
        source: source.into(),
    };
    match ext.as_deref() {
        Some("png") => crate::output::write_atomic_path(
            path,
            |tmp| {
                let root = BitMapBackend::new(tmp, size).into_drawing_area();
                draw(&root, figure, view).map_err(draw_err)?;
                root.present().map_err(|e| draw_err(e.into()))
            },
            io_err,
        ),
        Some("svg") => crate::output::write_atomic_path(
            path,
            |tmp| {
                let root = SVGBackend::new(tmp, size).into_drawing_area();
                draw(&root, figure, view).map_err(draw_err)?;
                root.present().map_err(|e| draw_err(e.into()))
            },
            io_err,
        ),
        _ => Err(PlotError::Format(name)),
    }
}

// Palette (colour-blind-friendly, Okabe–Ito).
const BLUE: RGBColor = RGBColor(0, 114, 178);
const VERMILION: RGBColor = RGBColor(213, 94, 0);
const GREEN: RGBColor = RGBColor(0, 158, 115);
const ORANGE: RGBColor = RGBColor(230, 159, 0);
const PURPLE: RGBColor = RGBColor(204, 121, 167);
const GREY: RGBColor = RGBColor(150, 150, 150);
const OBSTACLE: RGBColor = RGBColor(205, 205, 205);
const DARK: RGBColor = RGBColor(60, 60, 60);

fn verdict_colour(v: Verdict) -> RGBColor {
    match v {
        Verdict::Converges => GREEN,
        Verdict::Trapped => VERMILION,
        Verdict::Unknown => RGBColor(235, 235, 235),
        Verdict::Invalid => ORANGE,
        Verdict::UnsafeBetweenSamples => PURPLE,
        Verdict::Unsafe => RGBColor(255, 0, 255),
        Verdict::PartlyUnsafe => RGBColor(175, 175, 175),
        Verdict::UnsafeStart => RGBColor(110, 110, 110),
    }
}

type Chart<'a, DB> = ChartContext<'a, DB, Cartesian2d<RangedCoordf64, RangedCoordf64>>;

fn draw<DB: DrawingBackend<ErrorType: 'static>>(
    root: &DrawingArea<DB, Shift>,
    figure: &Figure,
    view: &View,
) -> Result<(), DrawError> {
    figure.kind().check(view, figure.scenario())?;
    figure.check_data()?;
    root.fill(&WHITE).map_err(DrawError::from)?;
    if view.time {
        return match figure {
            Figure::Trajectories {
                scenario,
                trajectories,
                equilibria,
            } => time::draw_trajectories_over_time(root, view, scenario, trajectories, equilibria),
            // A split box's whole tube failed; over time its pieces are not drawn.
            Figure::Tubes {
                scenario,
                tubes,
                split,
                every,
                title,
            } => {
                let whole: Vec<&Tube> = (tubes.iter().enumerate())
                    .filter(|(k, _)| split.iter().all(|&(i, _)| i != *k))
                    .map(|(_, t)| t)
                    .collect();
                time::draw_tubes_over_time(root, view, scenario, &whole, *every, title)
            }
            // Refused over time (the check above has said so already).
            Figure::Minkowski { scenario, .. } => Kind::Minkowski.check(view, scenario),
            Figure::Verdicts { scenario, report } => {
                time::draw_verdicts_over_time(root, view, scenario, report)
            }
            Figure::ErrorMap { scenario, map } => {
                maps::draw_error_map_along(root, view, scenario, map)
            }
        };
    }
    match figure {
        Figure::Trajectories {
            scenario,
            trajectories,
            equilibria,
        } => draw_trajectories(root, view, scenario, trajectories, equilibria),
        Figure::Tubes {
            scenario,
            tubes,
            split,
            every,
            title,
        } => draw_tubes(root, view, scenario, tubes, split, *every, title),
        Figure::Minkowski {
            scenario,
            tubes,
            trajectories,
            every,
        } => draw_minkowski(root, view, scenario, tubes, trajectories, *every),
        Figure::Verdicts { scenario, report } => draw_verdicts(root, view, scenario, report),
        Figure::ErrorMap { scenario, map } => draw_error_map(root, view, scenario, map),
    }
}

/// The caption's font size: 22 px, or less where a long title (a verdict map's with its
/// shares) would run past the picture's edges.
fn caption_size<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, title: &str) -> f64 {
    const SIZE: f64 = 22.0;
    let room = 0.96 * root.dim_in_pixel().0 as f64;
    match root.estimate_text_size(title, &("sans-serif", SIZE).into_font().into()) {
        Ok((w, _)) if w as f64 > room => (SIZE * room / w as f64).max(10.0),
        _ => SIZE,
    }
}

fn chart<'a, DB: DrawingBackend<ErrorType: 'static>>(
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
fn axes<'a, DB: DrawingBackend<ErrorType: 'static>>(
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
fn shade_unsafe<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
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

fn legend<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
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
fn clamp_box(view: &View, b: &IntervalBox, r: &IntervalBox) -> [(f64, f64); 2] {
    let (x, y) = (view.x, view.y);
    let c = |v: f64, i: usize| v.clamp(r.lower[i], r.upper[i]);
    [
        (c(b.lower[x], x), c(b.lower[y], y)),
        (c(b.upper[x], x), c(b.upper[y], y)),
    ]
}

/// Boxes of the state space (n-D) as rectangles: those the view's slices meet, projected.
fn box_series<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
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
        series
            .label(l)
            .legend(move |(x, y)| Rectangle::new([(x, y - 6), (x + 14, y + 6)], style));
    }
    Ok(())
}

/// The end-point class of a trajectory: 0 the goal, 1 near an undesirable stable equilibrium
/// outside it, 2 other.
fn ending(scenario: &Scenario, equilibria: &[Equilibrium], end: &[f64]) -> usize {
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
fn draw_lines<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
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
fn draw_by_ending<'a, DB: DrawingBackend<ErrorType: 'static> + 'a>(
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

fn draw_trajectories<DB: DrawingBackend<ErrorType: 'static>>(
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
fn tube_class(scenario: &Scenario, tube: &Tube) -> (RGBColor, &'static str) {
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

fn draw_tubes<DB: DrawingBackend<ErrorType: 'static>>(
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

fn draw_minkowski<DB: DrawingBackend<ErrorType: 'static>>(
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

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
//! `hᵢ < 0` at its centre (a picture, not a proof). Where states are projected it is shaded
//! grey where it lies over the centre for every value of them and pale where for some
//! (`shadow.rs`). Text uses the embedded DejaVu Sans
//! (`assets/DejaVuSans.ttf`, license beside it), registered once as `sans-serif`.

use std::path::Path;
use std::sync::Once;

use plotters::coord::types::RangedCoordf64;
use plotters::coord::Shift;
use plotters::prelude::*;

use crate::boxes::IntervalBox;
use crate::equilibria::Equilibrium;
use crate::error_map::ErrorMap;
use crate::reach::Tube;
use crate::scenario::Scenario;
use crate::simulate::Trajectory;
use crate::verify::{BoxVerdict, Verdict, VerifyReport};

mod chart;
mod maps;
mod planar;
mod shadow;
mod time;
mod view;

use chart::{box_series, chart};
use maps::{draw_error_map, draw_verdicts};
pub use maps::{error_class, verdicts_title, ERROR_CLASSES};
use planar::{draw_minkowski, draw_trajectories, draw_tubes};
pub use view::View;

const FONT: &[u8] = include_bytes!("../../assets/DejaVuSans.ttf");
static REGISTER: Once = Once::new();

/// Makes the embedded font plotters' `sans-serif`, once.
fn register_font() {
    REGISTER.call_once(|| {
        // The embedded font is valid; if registration failed, text would be missing but the
        // drawing itself still errors clearly.
        let _ = plotters::style::register_font("sans-serif", FontStyle::Normal, FONT);
    });
}

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

/// The kinds of [`Figure`] (`plot --figure`), for what can be checked before a figure's data
/// are read.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum Kind {
    /// Paper Fig. 1: filtered-system trajectories, the unsafe set, equilibria.
    Trajectories,
    /// Paper Fig. 2: reach tubes (disturbance method) from the scenario's initial boxes.
    Tubes,
    /// Paper Fig. 3: NN-system boxes with and without the closeness inflation, and filtered
    /// trajectories inside them.
    Minkowski,
    /// A verdict map from `cbfreach verify --json` (give it with --input).
    Verdicts,
    /// The network's error map (`cbfreach error`): each cell coloured by its certified bound
    /// on ‖N − v‖∞ (the map beside the network, or the one given with --input).
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
                let projected = view.projected(scenario.n()).next().unwrap_or(view.y);
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
    register_font();
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
/// The unsafe set's shadow in a projection: over some values of the projected states.
const SHADOW: RGBColor = RGBColor(226, 226, 232);
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

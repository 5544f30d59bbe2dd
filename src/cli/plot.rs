//! `cbfreach plot <scenario> --figure …`: the paper's figures and verdict maps.

use std::path::{Path, PathBuf};

use cbfreach::bounds::BoundMethod;
use cbfreach::boxes::IntervalBox;
use cbfreach::equilibria::find_equilibria;
use cbfreach::error_map::{error_map_path, ErrorMap};
use cbfreach::filter::SafetyFilter;
use cbfreach::plot::{self, Figure, Kind, View};
use cbfreach::problem::network_path;
use cbfreach::reach::{
    Backend, CpuBackend, ReachMethod, ReachProblem, ReachResult, ReachSettings, TimeModel,
};
use cbfreach::scenario::Scenario;
use cbfreach::simulate::{sample_box, Trajectory};
use cbfreach::verify::{simulate_model, VerifyReport};

use super::args::{compile, ProblemArgs};
use super::{fmt_point, load_scenario, progress_bar, CliResult};

/// Arguments of `cbfreach plot`.
#[derive(clap::Args)]
pub struct PlotArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Which picture.
    #[arg(long, value_enum)]
    pub figure: Kind,
    /// Input data: the verdict JSON for `verdicts`; for `error-map` a map file instead of
    /// the one beside the network.
    #[arg(long)]
    pub input: Option<PathBuf>,
    /// Output file, .png or .svg.
    #[arg(long, short)]
    pub out: PathBuf,
    /// Pixel size WIDTH,HEIGHT or WIDTHxHEIGHT (default: 1000 wide, the region's aspect ratio).
    #[arg(long)]
    pub size: Option<String>,
    /// Draw every K-th step (of dt) of the tubes [default: 10; 1 over time, where each bar
    /// is the hull of K steps' flowpipes].
    #[arg(long, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub every: Option<usize>,
    /// How the network is bounded over each box (tubes, minkowski).
    #[arg(long, value_enum, default_value_t = ReachSettings::default().bounds)]
    pub bounds: BoundMethod,
    /// The two states drawn, e.g. `--axes p,v` (default: the first two), or `t` and one state
    /// (`--axes t,p`: tubes and trajectories over time, the default for one state). Other
    /// states are projected unless sliced.
    #[arg(long, value_name = "A,B")]
    pub axes: Option<String>,
    /// Draw only the sets that meet the hyperplane NAME = VALUE (repeatable), e.g.
    /// `--slice a=0`: a 2-D slice once every state is drawn or sliced.
    #[arg(long, value_name = "NAME=VALUE", allow_hyphen_values = true)]
    pub slice: Vec<String>,
    /// The network, `M_C` and coordinates.
    #[command(flatten)]
    pub problem: ProblemArgs,
}

fn parse_size(text: &str) -> Result<(u32, u32), String> {
    let bad = || format!("--size: expected WIDTH,HEIGHT in pixels, e.g. 1000,750, found `{text}`");
    // `1000,750` or `1000x750` (`×` too), as image tools write sizes.
    let (w, h) = text.split_once([',', 'x', 'X', '×']).ok_or_else(bad)?;
    Ok((
        w.trim().parse().map_err(|_| bad())?,
        h.trim().parse().map_err(|_| bad())?,
    ))
}

/// Starting points for Figure 1: the initial boxes' centres and the safe points of a 7×5 grid
/// over C (7×5×5 in three states; in more, at most 256 cells: a 7×5⁵ grid in six states drew
/// 21,875 trajectories into one projection, a solid blot).
pub fn figure_points(s: &Scenario) -> Vec<Vec<f64>> {
    let mut points: Vec<Vec<f64>> = s.reach.initial.iter().map(IntervalBox::center).collect();
    let n = s.n();
    let counts: Vec<usize> = match n {
        1..=3 => (0..n).map(|i| if i == 0 { 7 } else { 5 }).collect(),
        _ => vec![cbfreach::boxes::per_axis_within(n, 256, 5).max(2); n],
    };
    points.extend(
        s.reach
            .region
            .partition(&counts)
            .iter()
            .map(IntervalBox::center)
            .filter(|x| s.cbfs.iter().all(|c| c.h.eval(x) > 0.0)),
    );
    points
}

/// Filtered trajectories from `points` over the scenario's horizon, of the system its time
/// model names (the ODE by RK4 at `dt`, the held control, or the Euler map).
pub fn trajectories(s: &Scenario, points: &[Vec<f64>]) -> Vec<Trajectory> {
    trajectories_in(s, points, s.reach.time)
}

fn trajectories_in(s: &Scenario, points: &[Vec<f64>], time: TimeModel) -> Vec<Trajectory> {
    let filter = SafetyFilter::new(s);
    points
        .iter()
        .map(|x| simulate_model(&filter, x, time, 1).0)
        .collect()
}

/// `per_box` filtered trajectories from points of each initial box (corners first), of the
/// Euler map: drawn with the paper's Minkowski sets, which its construction takes on that map.
pub fn box_trajectories(s: &Scenario, boxes: &[IntervalBox], per_box: usize) -> Vec<Trajectory> {
    let points: Vec<Vec<f64>> = boxes
        .iter()
        .enumerate()
        .flat_map(|(k, b)| sample_box(b, per_box, k as u64))
        .collect();
    trajectories_in(s, &points, TimeModel::Euler)
}

/// Reach from the scenario's initial boxes with a progress bar.
pub fn reach_initial(
    s: &Scenario,
    problem: &ReachProblem,
    bounds: BoundMethod,
    method: ReachMethod,
    every: usize,
    face_local: bool,
) -> Result<ReachResult, Box<dyn std::error::Error>> {
    let engine = CpuBackend;
    let settings = ReachSettings {
        bounds,
        method,
        every,
        face_local,
        ..ReachSettings::default()
    };
    let (initial, outside) = cbfreach::verify::split_outside_s(s, &s.reach.initial, method);
    for b in &outside {
        eprintln!(
            "initial box {} … {} not drawn: it lies {}, and the sets bound the trajectories \
             that start in S",
            fmt_point(&b.lower),
            fmt_point(&b.upper),
            cbfreach::verify::in_safe_set(s, b)
        );
    }
    let bar = progress_bar(problem.steps as u64, "steps of dt");
    let r = engine.reach(problem, &initial, &settings, &|d, _| {
        bar.set_position(d as u64)
    })?;
    bar.finish_and_clear();
    Ok(r)
}

/// Runs `plot`.
pub fn run(args: &PlotArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    super::check_outputs(&[Some(&args.out)])?;
    let view = View::parse(&s, args.axes.as_deref(), &args.slice)?;
    // Before any input is read: what the view can show.
    args.figure.check(&view, &s)?;
    let size = match &args.size {
        Some(t) => parse_size(t)?,
        None if view.time => (1000, 600),
        None => plot::default_size(&view.plane(&s.reach.region), 1000),
    };
    let out: &Path = &args.out;
    match args.figure {
        Kind::Trajectories => {
            // Past the dense search's size: no equilibria drawn.
            let found = cbfreach::verify::equilibrium_search_for(s.n())
                .map(|q| find_equilibria(&SafetyFilter::new(&s), &s.reach.region, &q))
                .unwrap_or_default();
            let t = trajectories(&s, &figure_points(&s));
            plot::save_view(
                &Figure::Trajectories {
                    scenario: &s,
                    trajectories: &t,
                    equilibria: &found,
                },
                &view,
                out,
                size,
            )?;
        }
        Kind::Tubes | Kind::Minkowski => {
            let problem = compile(&s, &args.problem)?;
            let method = if args.figure == Kind::Tubes {
                ReachMethod::Disturbance
            } else {
                ReachMethod::Minkowski
            };
            let every = args.every.unwrap_or(if view.time { 1 } else { 10 });
            let r = reach_initial(&s, &problem, args.bounds, method, every, false)?;
            if method == ReachMethod::Disturbance {
                plot::save_view(
                    &Figure::Tubes {
                        scenario: &s,
                        tubes: &r.boxes,
                        split: &[],
                        every: 1,
                        title: titled_tubes(&s, &problem, method, every),
                    },
                    &view,
                    out,
                    size,
                )?;
            } else {
                let t = box_trajectories(&s, &s.reach.initial, 8);
                plot::save_view(
                    &Figure::Minkowski {
                        scenario: &s,
                        tubes: &r.boxes,
                        trajectories: &t,
                        every: 1,
                    },
                    &view,
                    out,
                    size,
                )?;
            }
        }
        Kind::Verdicts => {
            let input = args.input.as_ref().ok_or(
                "--figure verdicts needs --input FILE (from `cbfreach verify --json FILE`)",
            )?;
            let name = input.display().to_string();
            let text = std::fs::read_to_string(input).map_err(|e| format!("{name}: {e}"))?;
            let report = VerifyReport::from_json(&text, &name)?;
            let figure = Figure::Verdicts {
                scenario: &s,
                report: &report,
            };
            figure.check_data().map_err(|e| format!("{name}: {e}"))?;
            if report.run.scenario != s.name {
                eprintln!(
                    "note: {name} holds the verdicts of `{}`, drawn over `{}`",
                    report.run.scenario, s.name
                );
            }
            plot::save_view(&figure, &view, out, size)?;
        }
        Kind::ErrorMap => {
            let file = match &args.input {
                Some(f) => f.clone(),
                None => error_map_path(&network_path(&s, args.problem.network.as_deref())?),
            };
            let map = ErrorMap::load(&file)?;
            let figure = Figure::ErrorMap {
                scenario: &s,
                map: &map,
            };
            let name = file.display();
            figure.check_data().map_err(|e| format!("{name}: {e}"))?;
            plot::save_view(&figure, &view, out, size)?;
        }
    }
    println!("{} written ({}×{} px)", out.display(), size.0, size.1);
    Ok(())
}

/// The title of a tubes figure.
pub fn tubes_title(s: &Scenario, m_c: f64, every: usize) -> String {
    format!(
        "`{}`: reachable sets of the filtered system (M_C = {m_c}), every {every} steps",
        s.name
    )
}

/// [`tubes_title`] for sets widened by the error map's local bounds.
pub fn tubes_title_local(s: &Scenario, every: usize) -> String {
    format!(
        "`{}`: reachable sets of the filtered system (certified local M), every {every} steps",
        s.name
    )
}

/// The title of a tubes figure naming the margin the sets were widened by: the error map's
/// local bounds where the problem holds a map and the method uses it (the disturbance
/// method), else the global `M_C`.
pub fn titled_tubes(
    s: &Scenario,
    problem: &ReachProblem,
    method: ReachMethod,
    every: usize,
) -> String {
    if problem.error_map.is_some() && method == ReachMethod::Disturbance {
        tubes_title_local(s, every)
    } else {
        tubes_title(s, problem.m_c, every)
    }
}

/// Draws the tubes of a `reach` run (about 25 boxes per tube) and says where.
pub fn plot_tubes(
    s: &Scenario,
    r: &ReachResult,
    recorded_every: usize,
    problem: &ReachProblem,
    method: ReachMethod,
    out: &Path,
) -> CliResult {
    let samples = r.boxes.iter().map(|t| t.tube.len()).max().unwrap_or(1);
    let every = (samples / 25).max(1);
    plot::save(
        &Figure::Tubes {
            scenario: s,
            tubes: &r.boxes,
            split: &[],
            every,
            title: titled_tubes(s, problem, method, every * recorded_every.max(1)),
        },
        out,
        plot::default_size(&s.reach.region, 1000),
    )?;
    println!("  tubes drawn to {}", out.display());
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::parse_size;

    /// Sizes as `1000,750` or `1000x750`; anything else names what was expected.
    #[test]
    fn sizes_take_a_comma_or_an_x() {
        for text in ["1000,750", "1000x750", "1000 X 750", "1000×750"] {
            assert_eq!(parse_size(text), Ok((1000, 750)), "{text}");
        }
        for text in ["1000", "1000;750", "x750", "1e3,750", "-1,750"] {
            let err = parse_size(text).unwrap_err();
            assert!(
                err.contains("WIDTH,HEIGHT") && err.contains(text),
                "{text}: {err}"
            );
        }
    }
}

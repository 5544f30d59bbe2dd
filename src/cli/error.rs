//! `cbfreach error <scenario>`: measured and certified `M_C`, slope error and bound looseness
//! of the surrogate network, and the error map beside the network.

use std::path::{Path, PathBuf};

use cbfreach::bounds::BoundMethod;
use cbfreach::error_map::{error_map_path, ErrorMap};
use cbfreach::output::check_writable;
use cbfreach::provenance::restamp;
use cbfreach::surrogate_error::{
    asked_counts, certify, looseness, measure, measurement_size, ErrorSettings, Looseness,
    Percentiles, SlopeByCurvature, CURVATURE_BANDS, MAX_MEASUREMENT_POINTS, WITNESS_CELLS,
};
use serde::Serialize;

use super::{fmt_point, load_scenario, progress_bar, CliResult};
use cbfreach::problem::{load_network, network_path};

/// Arguments of `cbfreach error`.
#[derive(clap::Args)]
pub struct ErrorArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Use this network instead of the scenario's.
    #[arg(long)]
    pub network: Option<PathBuf>,
    /// Print JSON instead of text.
    #[arg(long)]
    pub json: bool,
    /// Cell evaluations allowed to the certified bound.
    #[arg(long, default_value_t = 40_000, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub budget: usize,
    /// Refine each cell until its bound is within this many times its sampled error ...
    #[arg(long, default_value_t = 1.5, value_parser = |s: &str| super::number_at_least(s, 1.0, false))]
    pub local_ratio: f64,
    /// ... or below this absolute floor.
    #[arg(long, default_value_t = 0.01, value_parser = |s: &str| super::number_at_least(s, 0.0, false))]
    pub floor: f64,
    /// At most this many cells in the error map (about 80 bytes of JSON each).
    #[arg(long, default_value_t = 24_000, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub max_cells: usize,
    /// When every cell meets its target, bisect further (largest bound × width first) up to
    /// this many cells, so that a set's local bound comes from cells near its size.
    #[arg(long, default_value_t = 4_000)]
    pub detail_cells: usize,
    /// Measurement grid: this many times the training grid's points per axis.
    #[arg(long, default_value_t = 2, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub refine: usize,
    /// Looseness: at most this many boxes across C ∩ S (0 skips the looseness).
    #[arg(long, default_value_t = 300)]
    pub looseness_boxes: usize,
    /// Width of the boxes of the looseness and of the slope error over boxes. The engine's
    /// sets grow wider than 0.1 along the way: a wider box shows how bounds hold up there.
    #[arg(long, default_value_t = 0.1, value_parser = |s: &str| super::number_at_least(s, 0.0, true))]
    pub box_width: f64,
    /// Cells narrower than this are not refined further.
    #[arg(long, default_value_t = 1.0 / 256.0, value_parser = |s: &str| super::number_at_least(s, 0.0, true))]
    pub min_cell: f64,
    /// How the network is bounded on a cell where IBP is not tight enough.
    #[arg(long, value_enum, default_value_t = BoundMethod::ForwardBackward)]
    pub cell_bounds: BoundMethod,
    /// Do not write the error map beside the network.
    #[arg(long)]
    pub no_map: bool,
    /// Replace the error map beside the network even by a looser one (without it, a looser
    /// map is written beside it as `<stem>.errormap.looser.json`).
    #[arg(long)]
    pub force: bool,
    /// Compute nothing: stamp the existing map (which predates provenance) with this
    /// scenario's filter, region and norm, for a map known to be certified for them; the
    /// cells it lacks get bound 0 where some h < 0 is proven on them, else +∞.
    #[arg(long)]
    pub restamp: bool,
}

#[derive(Serialize)]
struct ErrorJson {
    linf: f64,
    l2: f64,
    argmax: Vec<f64>,
    argmax_l2: Vec<f64>,
    mean: f64,
    /// A number, `"inf"` when some cell could not be certified, `null` for a QP filter.
    certified_linf: serde_json::Value,
    cells: usize,
    uncertified_cells: usize,
    certified_linf_finite_cells: Option<f64>,
    /// The largest error found by dense samples of the cells of largest bound, and where.
    witness_linf: Option<f64>,
    witness: Option<Vec<f64>>,
    dropped_cells: usize,
    /// Kept cells whose bound is within `max(local_ratio × sampled error, floor)`.
    satisfied_cells: usize,
    evaluated_cells: usize,
    budget_spent: bool,
    grid_points: usize,
    /// Points on the boundary of `C` measured besides the grid.
    boundary_points: usize,
    samples: usize,
    slope: Percentiles,
    /// The secant slope error over boxes `box_width` wide (what a bound over a box sees).
    box_slope: Percentiles,
    box_width: f64,
    /// The pointwise slope error in bands of the filter's curvature.
    slope_by_curvature: SlopeByCurvature,
    /// Neurons of each hidden layer active somewhere on the measurement grid.
    live_neurons: Vec<usize>,
    looseness: Option<Looseness>,
    error_map: Option<String>,
}

/// Runs the command.
pub fn run(args: &ErrorArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    let path = network_path(&s, args.network.as_deref())?;
    let net = load_network(&s, Some(path.as_path()))?;
    let map_path = error_map_path(&path);
    if args.restamp {
        let mut map = ErrorMap::load(&map_path)?;
        let added = restamp(&mut map, &s, &path)?;
        map.save(&map_path)?;
        println!(
            "{}: stamped for {} and {} ({added} cells added where the map had none)",
            map_path.display(),
            s.file,
            path.display()
        );
        return Ok(());
    }
    if !args.no_map {
        check_writable(&map_path).map_err(|e| format!("{}: {e}", map_path.display()))?;
    }
    let settings = ErrorSettings {
        refine: args.refine,
        budget: args.budget,
        looseness_boxes: args.looseness_boxes,
        looseness_width: args.box_width,
        local_ratio: args.local_ratio,
        floor: args.floor,
        max_cells: args.max_cells,
        detail_cells: args.detail_cells,
        cell_bounds: args.cell_bounds,
        min_cell: args.min_cell,
        ..ErrorSettings::default()
    };

    let bar = progress_bar(0, "filter on the measurement grid");
    let measured = measure(&s, &net, &settings, &|d| bar.set_position(d as u64))?;
    bar.finish_and_clear();

    let loose = if args.looseness_boxes > 0 {
        Some(looseness(&s, &net, &settings)?)
    } else {
        None
    };

    let bar = progress_bar(args.budget as u64, "certifying cells");
    let certified = certify(&s, &net, measured.linf, &settings, &|done, worst| {
        bar.set_position(done as u64);
        bar.set_message(format!("worst cell bound {worst:.4}"));
    })?;
    bar.finish_and_clear();

    let mut refused = None;
    let map_file = if args.no_map {
        None
    } else {
        let mut map = ErrorMap::new(&path, &s.reach.region, &measured, certified.as_ref())?;
        map.stamp(&s, &path)?;
        let (file, why) = save_unless_looser(&map, &map_path, &s, &path, args.force)?;
        refused = why;
        Some(file)
    };

    let out = ErrorJson {
        linf: measured.linf,
        l2: measured.l2,
        argmax: measured.argmax.clone(),
        argmax_l2: measured.argmax_l2.clone(),
        mean: measured.mean,
        certified_linf: match certified.as_ref().map(|c| c.linf) {
            None => serde_json::Value::Null,
            Some(v) if v.is_finite() => serde_json::json!(v),
            Some(_) => serde_json::json!("inf"),
        },
        cells: certified.as_ref().map_or(0, |c| c.cells.len() - c.dropped),
        uncertified_cells: certified.as_ref().map_or(0, |c| c.uncertified),
        certified_linf_finite_cells: certified.as_ref().map(|c| c.finite_linf),
        witness_linf: certified.as_ref().map(|c| c.witness_linf),
        witness: certified.as_ref().map(|c| c.witness.clone()),
        dropped_cells: certified.as_ref().map_or(0, |c| c.dropped),
        satisfied_cells: certified.as_ref().map_or(0, |c| c.satisfied),
        evaluated_cells: certified.as_ref().map_or(0, |c| c.evaluated),
        budget_spent: certified.as_ref().is_some_and(|c| c.budget_spent),
        grid_points: measured.grid_points,
        boundary_points: measured.boundary_points,
        samples: measured.samples,
        slope: measured.slope,
        box_slope: measured.box_slope,
        box_width: measured.box_width,
        slope_by_curvature: measured.slope_by_curvature.clone(),
        live_neurons: measured.live_neurons.clone(),
        looseness: loose,
        error_map: map_file.as_ref().map(|p| p.display().to_string()),
    };
    let outcome = || refused.clone().map_or(Ok(()), |why| Err(why.into()));
    if args.json {
        println!("{}", serde_json::to_string_pretty(&out)?);
        return outcome();
    }
    println!("{}: network {}", s.file, path.display());
    println!(
        "measured on {} points of C ∩ S ({} grid points and {} on C's boundary, {} infeasible skipped):",
        measured.samples, measured.grid_points, measured.boundary_points, measured.infeasible
    );
    let asked = asked_counts(&s, &settings);
    if measured.counts != asked {
        println!(
            "  the grid is {} points per axis: --refine {} would measure {:.0} points, more than the {} allowed",
            measured.counts.iter().map(|k| k.to_string()).collect::<Vec<_>>().join("×"),
            args.refine,
            measurement_size(&asked),
            MAX_MEASUREMENT_POINTS
        );
    }
    println!(
        "  max ℓ∞ error {:.4} at {}, max ℓ2 error {:.4} at {}, mean ℓ∞ {:.4}",
        out.linf,
        fmt_point(&out.argmax),
        out.l2,
        fmt_point(&out.argmax_l2),
        out.mean
    );
    println!(
        "  slope error max_ij |DN − Dv|_ij: median {:.3}, 95th percentile {:.3}, max {:.3}",
        out.slope.median, out.slope.p95, out.slope.max
    );
    println!(
        "  over boxes {} wide (secants over ±{}): median {:.3}, 95th percentile {:.3}, max {:.3}",
        out.box_width,
        out.box_width / 2.0,
        out.box_slope.median,
        out.box_slope.p95,
        out.box_slope.max
    );
    if let Some(line) = curvature_line(&out.slope_by_curvature) {
        println!("{line}");
    }
    let widths = net.widths();
    let hidden = &widths[1..widths.len() - 1];
    println!(
        "  live neurons (active at some measured point) per hidden layer: {}",
        out.live_neurons
            .iter()
            .zip(hidden)
            .map(|(live, width)| format!("{live}/{width}"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    if let Some(l) = &loose {
        println!(
            "bound looseness (width / sampled range) on {} boxes {} wide: IBP median {:.3}, max {:.3}; CROWN median {:.3}, max {:.3}",
            l.boxes, l.width, l.ibp.median, l.ibp.max, l.crown.median, l.crown.max
        );
    }
    match &certified {
        Some(c) => println!(
            "certified M_C over C ∩ S: {:.4} ({} cells kept, {} proven unsafe, {} evaluated{})",
            c.linf,
            c.cells.len() - c.dropped,
            c.dropped,
            c.evaluated,
            if c.budget_spent {
                "; budget or cell cap reached"
            } else {
                ""
            }
        ),
        None => println!(
            "certified M_C: none (the filter's QP has more active sets than are enumerated)"
        ),
    }
    if let Some(c) = certified.as_ref().filter(|c| !c.witness.is_empty()) {
        println!(
            "  the network attains {:.4} at {} (dense samples of the {} cells of largest bound){}",
            c.witness_linf,
            fmt_point(&c.witness),
            WITNESS_CELLS,
            if c.linf.is_finite() && c.witness_linf.max(out.linf) > 0.0 {
                // Against the largest error found: the dense samples' or the grid's.
                let (found, what) = match out.linf > c.witness_linf {
                    true => (out.linf, "the grid's max ℓ∞ error"),
                    false => (c.witness_linf, "it"),
                };
                format!(
                    ": the certified bound exceeds {what} by {:.1} %",
                    100.0 * (c.linf / found - 1.0)
                )
            } else {
                String::new()
            }
        );
    }
    if let Some(c) = &certified {
        println!(
            "  local: {} of {} cells within max({r} × their sampled error, {}), capped at {r} × the measured max",
            c.satisfied,
            c.cells.len(),
            args.floor,
            r = args.local_ratio,
        );
    }
    if let Some(c) = certified.as_ref().filter(|c| c.budget_spent) {
        // Where cells ran out before they met their targets, say how to give it more.
        let loose = c.satisfied < c.cells.len() / 2
            || (c.witness_linf > 0.0 && c.linf > 1.5 * c.witness_linf);
        if loose {
            // Ten times the evaluations make about ten times the cells: the cap too, if so.
            let cap = match c.cells.len().saturating_mul(10) > args.max_cells {
                true => format!(" --max-cells {}", args.max_cells.saturating_mul(10)),
                false => String::new(),
            };
            println!(
                "  the budget ran out with {} of {} cells within their target: `--budget {}{cap}` \
                 (ten times) tightens the bound and the local map, in about ten times the time",
                c.satisfied,
                c.cells.len(),
                args.budget.saturating_mul(10),
            );
        }
    }
    if let Some(c) = certified.as_ref().filter(|c| c.uncertified > 0) {
        println!(
            "  {} cells could not be certified (+∞; e.g. where L_g h = 0 on the boundary of S); \
             the other cells are within {:.4}",
            c.uncertified, c.finite_linf
        );
    }
    if let Some(f) = map_file {
        println!("error map written to {}", f.display());
    }
    outcome()
}

/// Saves `map` at `file` unless a map there, made for the same network and filter, is tighter
/// (a smaller certified bound, then a smaller largest finite cell bound) and `force` is not
/// given: then the new map goes beside it (`….looser.json`), so that neither is lost. Returns
/// where the map was written, and why not at `file` (for an error after the report).
fn save_unless_looser(
    map: &ErrorMap,
    file: &Path,
    s: &cbfreach::Scenario,
    network: &Path,
    force: bool,
) -> Result<(PathBuf, Option<String>), Box<dyn std::error::Error>> {
    let key = |m: &ErrorMap| (m.certified_linf.unwrap_or(f64::INFINITY), m.finite_max());
    let old = ErrorMap::load_certified(network, s).ok().or_else(|| {
        ErrorMap::load_for(network)
            .ok()
            .filter(|m| m.provenance.is_none())
    });
    if let Some(old) = old.filter(|old| !force && key(map) > key(old)) {
        let looser = file.with_extension("looser.json");
        map.save(&looser)?;
        let why = format!(
            "not replacing {} (certified {:.4}, largest finite cell {:.4}) with a looser map (certified {:.4}, {:.4}); the new map is in {} (--force replaces)",
            file.display(),
            key(&old).0,
            key(&old).1,
            key(map).0,
            key(map).1,
            looser.display()
        );
        return Ok((looser, Some(why)));
    }
    map.save(file)?;
    Ok((file.to_path_buf(), None))
}

/// The slope error by the filter's curvature, one line: each band's 95th percentile.
fn curvature_line(c: &SlopeByCurvature) -> Option<String> {
    let [flat, next, steep] = c.bands.as_slice() else {
        return None;
    };
    let [(_, _, flat_name), (_, _, next_name), (_, _, steep_name)] = CURVATURE_BANDS;
    Some(format!(
        "  by the filter's curvature ‖D²v‖ ({} points), 95th percentile: {flat_name} \
         (‖D²v‖ ≤ {}) {:.3}, {next_name} (≤ {}) {:.3}, {steep_name} {:.3}",
        c.points,
        bound_text(flat.curvature[1]),
        flat.slope.p95,
        bound_text(next.curvature[1]),
        next.slope.p95,
        steep.slope.p95,
    ))
}

/// A band's edge: two decimals, or two significant digits below 0.01 (where the filter is
/// inactive on most points `‖D²v‖` is an exact 0, and a small edge is not "0.00").
fn bound_text(x: f64) -> String {
    match x {
        0.0 => "0".into(),
        x if x.abs() < 0.01 => format!("{x:.1e}"),
        x => format!("{x:.2}"),
    }
}

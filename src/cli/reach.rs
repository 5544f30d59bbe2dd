//! `cbfreach reach <scenario>`: tubes from the scenario's initial boxes.

use std::collections::BTreeMap;
use std::path::PathBuf;

use cbfreach::bounds::BoundMethod;
use cbfreach::boxes::{fmt_numbers, IntervalBox};
use cbfreach::reach::{ExactField, ReachMethod, ReachResult, ReachSettings};
use cbfreach::verify::{in_safe_set, rerun_stopped, split_outside_s, InSafeSet, StoppedRerun};
use serde::Serialize;

use super::args::{engine, settings_flag_error, EngineArgs, ProblemArgs, ReachFlags};
use super::{fmt_point, given, load_scenario, progress_bar, CliResult, INTERSECT_X_CLAUSE};

/// Arguments of `cbfreach reach`.
#[derive(clap::Args)]
pub struct ReachArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Engine and GPU options.
    #[command(flatten)]
    pub engine: EngineArgs,
    /// Bounds, method and sets (default: the scenario's `[settings.reach]`, else
    /// `ReachSettings::default()`).
    #[command(flatten)]
    pub reach: ReachFlags,
    /// Record every K-th step (the last is always recorded).
    #[arg(long, default_value_t = ReachSettings::default().every,
          value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub every: usize,
    /// The network, `M_C` and coordinates.
    #[command(flatten)]
    pub problem: ProblemArgs,
    /// Write the tubes as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Draw the tubes here (.png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
}

#[derive(Serialize)]
struct ReachJson<'a> {
    scenario: &'a str,
    /// The states' names, in the order of every set's coordinates.
    states: &'a [String],
    /// Units of states, inputs and time by name (`[system] units`), where given.
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    units: &'a BTreeMap<String, String>,
    backend: String,
    bounds: BoundMethod,
    method: ReachMethod,
    dt: f64,
    time: cbfreach::reach::TimeModel,
    substeps: usize,
    m_c: f64,
    /// Initial boxes not run: they lie outside `S`, and the sets bound the trajectories that
    /// start in `S`.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    outside_s: Vec<IntervalBox>,
    /// Where tubes stopped early: their reruns ([`rerun_stopped`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    what_stops: Option<StoppedRerun>,
    #[serde(flatten)]
    result: &'a ReachResult,
}

/// Runs the command.
pub fn run(args: &ReachArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    super::check_outputs(&[args.json.as_deref(), args.plot.as_deref()])?;
    let problem = super::args::compile(&s, &args.problem)?;
    let m_c = problem.m_c;
    if let Some(t) = &problem.transform {
        let n = s.n();
        let rows: Vec<String> = t.t.chunks(n.max(1)).map(fmt_numbers).collect();
        println!(
            "embedding in z = T x, T = [{}] (ρ = {:.1e})",
            rows.join(", "),
            t.rho
        );
    }
    let mut settings = args.reach.settings(&s.settings.reach);
    if given("every") {
        settings.every = args.every;
    }
    settings.validate().map_err(|e| settings_flag_error(&e))?;
    let (initial, outside_s) = split_outside_s(&s, &s.reach.initial, settings.method);
    let backend = engine(&args.engine, &mut settings, &problem, initial.len())?;
    let bar = progress_bar(problem.steps as u64, "steps of dt");
    let result = backend.reach(&problem, &initial, &settings, &|done, _| {
        bar.set_position(done as u64)
    })?;
    bar.finish_and_clear();

    let margin = match &problem.error_map {
        Some(map) if settings.method == ReachMethod::Disturbance => format!(
            "M = local bounds of the error map (certified global {})",
            map.certified_linf
                .map_or("none".into(), |v| format!("{v:.4}"))
        ),
        _ => format!("M_C = {m_c}"),
    } + settings.exact_field().clause()
        + if problem.frames(&settings).len() > 1 {
            INTERSECT_X_CLAUSE
        } else {
            ""
        }
        + super::sharper_clause_of(&problem, &settings)
        + &super::meet_slabs_clause(
            problem.meet_slabs_applies(&settings),
            problem.turned_frames(&settings),
        );
    let within = super::safe_set_clause(&problem.safe_set_for(settings.method).names());
    println!(
        "{}: {} boxes × {} steps, time {}, {} bounds{}, {} method, {margin}{within}, backend {}",
        s.file,
        result.boxes.len(),
        problem.steps,
        time_clause(&problem),
        settings.bounds,
        if settings.face_local {
            " (face-local)"
        } else {
            ""
        },
        settings.method,
        backend.name()
    );
    for b in &outside_s {
        println!(
            "  {} … {}  →  not run: the box lies {}, and the sets bound the trajectories that \
             start in S",
            fmt_point(&b.lower),
            fmt_point(&b.upper),
            in_safe_set(&s, b)
        );
    }
    for tube in &result.boxes {
        let start = in_safe_set(&s, &tube.initial);
        if let (InSafeSet::Partly(_), ReachMethod::Disturbance) = (&start, settings.method) {
            println!(
                "  (the next box starts {start}: its sets bound the trajectories from its part in S)"
            );
        }
        if let Some(last) = tube.last() {
            let set = last.filtered_set().clone();
            let width = set.widths().iter().fold(0.0_f64, |a, &b| a.max(b));
            let where_ = if set.is_subset_of(&s.reach.goal) {
                "in the goal set".to_string()
            } else {
                format!("max width {width:.3}")
            };
            println!(
                "  {} … {}  →  t = {:.2}: {} … {}  {}{}",
                fmt_point(&tube.initial.lower),
                fmt_point(&tube.initial.upper),
                last.t,
                fmt_point(&set.lower),
                fmt_point(&set.upper),
                where_,
                match tube.note() {
                    None => String::new(),
                    Some(note) if tube.valid() => format!("  ({note})"),
                    Some(note) => format!("  INVALID ({note})"),
                }
            );
            if let Some(found) = &tube.unsafe_between_samples {
                println!("    UNSAFE BETWEEN SAMPLES: {found}");
            }
        }
    }
    // Boxes stop where their sets leave C: the rate counts the steps run.
    let run: usize = result.boxes.iter().map(|t| t.steps_run(problem.dt)).sum();
    let all = result.boxes.len() * problem.steps;
    println!(
        "  time: {:.3} s embedding ({:.0} box-steps/s; {run} of {all} box-steps run), {:.3} s \
         Minkowski",
        result.timing.reach_s,
        run as f64 / result.timing.reach_s.max(1e-12),
        result.timing.minkowski_s.max(0.0)
    );
    if settings.exact_field() != ExactField::Nowhere {
        let exact: usize = result.boxes.iter().map(|t| t.exact_steps).sum();
        let enclosed: usize = result.boxes.iter().map(|t| t.enclosed_steps).sum();
        // Both counts are per engine step: `substeps` of them make one box-step of `dt`; a
        // step that ended a tube counts (its field was computed).
        let k = problem.steps_per_dt();
        let taken: usize = (result.boxes.iter())
            .map(|t| t.engine_steps(problem.dt, k))
            .sum();
        let of = if k > 1 {
            format!("{taken} engine steps ({k} per box-step)")
        } else {
            format!("{taken} box-steps")
        };
        println!(
            "  the filtered system's own field (the filter proven one smooth function on the set) \
             on {exact} of the {of}{}",
            if enclosed > 0 {
                format!(", the closed form's enclosures of v on {enclosed}")
            } else {
                String::new()
            }
        );
    }
    let unsafe_between = result
        .boxes
        .iter()
        .filter(|t| t.unsafe_between_samples.is_some())
        .count();
    if unsafe_between > 0 {
        println!(
            "  {unsafe_between} of {} boxes may leave S between samples (unsafe-between-samples): \
             the held input is not a continuous filter",
            result.boxes.len()
        );
    }
    let stopped: Vec<_> = result
        .boxes
        .iter()
        .filter(|t| !t.valid())
        .map(|t| t.initial.clone())
        .collect();
    let invalid = stopped.len();
    let mut what_stops = None;
    if invalid > 0 {
        // What would tighten the sets and is not on: face-local bounds, and with two frames in
        // continuous time the clipped slabs (on by default).
        let clip = problem.slabs_can_meet(&settings) && !settings.meet_slabs;
        let tighter: Vec<&str> = [
            (!settings.face_local)
                .then_some("bounds on each face of a box (--face-local, 2n× the bound cost)"),
            clip.then_some("slabs clipped by the other frame's sets (without --no-meet-slabs)"),
        ]
        .into_iter()
        .flatten()
        .collect();
        let tighter = match tighter.is_empty() {
            true => String::new(),
            false => format!("{} are tighter, and ", tighter.join(" and ")),
        };
        println!(
            "  {invalid} of {} sets stopped (INVALID): {tighter}`cbfreach verify` splits boxes \
             until they verify",
            result.boxes.len(),
        );
        what_stops = rerun_stopped(backend.as_ref(), &problem, &settings, &stopped)?;
        if let Some(r) = &what_stops {
            println!(
                "  {} of them run again, to the horizon: {}",
                r.boxes,
                super::verify::reruns_clause(&r.reruns, "")
            );
        }
    }
    if let Some(path) = &args.json {
        let json = ReachJson {
            scenario: &s.file,
            states: &s.states,
            units: &s.units,
            backend: backend.name(),
            bounds: settings.bounds,
            method: settings.method,
            dt: problem.dt,
            time: problem.time,
            substeps: problem.steps_per_dt(),
            m_c,
            outside_s,
            what_stops,
            result: &result,
        };
        cbfreach::output::write_atomic(path, serde_json::to_string(&json)?.as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("  tubes written to {}", path.display());
    }
    if let Some(path) = &args.plot {
        super::plot::plot_tubes(&s, &result, settings.every, &problem, settings.method, path)?;
    }
    Ok(())
}

/// For summaries: the time model, with its substeps.
pub fn time_clause(problem: &cbfreach::reach::ReachProblem) -> String {
    match problem.steps_per_dt() {
        1 => problem.time.to_string(),
        k => format!("{} ({k} validated steps per dt)", problem.time),
    }
}

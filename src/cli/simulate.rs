//! `cbfreach simulate`: trajectories of the filtered system as CSV or JSON.

use std::io::Write;
use std::path::PathBuf;

use cbfreach::boxes::IntervalBox;
use cbfreach::filter::SafetyFilter;
use cbfreach::output::{check_writable, write_atomic};
use cbfreach::scenario::limits;
use cbfreach::scenario::Scenario;
use cbfreach::simulate::{sample_box, simulate_filtered, write_csv, Integrator, Trajectory};

use super::{fmt_point, load_scenario, parse_point, CliResult};

/// Arguments of `cbfreach simulate`.
#[derive(clap::Args)]
pub struct SimulateArgs {
    /// The scenario file (TOML).
    scenario: PathBuf,
    /// Start from this point (comma-separated, one number per state); repeatable.
    #[arg(long = "from", value_name = "X1,X2,...", allow_hyphen_values = true)]
    from: Vec<String>,
    /// Start from N random safe points of --box (default: the region C).
    #[arg(long, value_name = "N")]
    samples: Option<usize>,
    /// Box to sample, as LOWER:UPPER with comma-separated corners, e.g. -1,-1:1,1.
    #[arg(long = "box", value_name = "LOWER:UPPER", allow_hyphen_values = true)]
    sample_box: Option<String>,
    /// Seed for the samples.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Time step (default: the scenario's dt; its control period for `zoh` under
    /// `time = "sampled"`).
    #[arg(long)]
    dt: Option<f64>,
    /// Horizon (default: the scenario's).
    #[arg(long)]
    horizon: Option<f64>,
    /// Integration scheme (default: the system the scenario's time model bounds: `rk4` for
    /// `continuous`, `zoh` for `sampled`, `euler` for `euler`).
    #[arg(long, value_enum)]
    integrator: Option<Integrator>,
    /// Output format.
    #[arg(long, value_enum, default_value_t = Format::Csv)]
    format: Format,
    /// Write trajectories here instead of standard output (a summary is then printed).
    #[arg(long, short)]
    out: Option<PathBuf>,
}

#[derive(Clone, Copy, clap::ValueEnum)]
enum Format {
    Csv,
    Json,
}

/// Parses `LOWER:UPPER` into a box of dimension n.
pub fn parse_box(option: &str, text: &str, n: usize) -> Result<IntervalBox, String> {
    let (lo, hi) = text
        .split_once(':')
        .ok_or_else(|| format!("{option}: expected LOWER:UPPER, e.g. -1,-1:1,1, found `{text}`"))?;
    let (lower, upper) = (parse_point(option, lo)?, parse_point(option, hi)?);
    if lower.len() != n || upper.len() != n {
        return Err(format!(
            "{option}: expected {n} numbers on each side of `:`"
        ));
    }
    IntervalBox::new(lower, upper).map_err(|e| format!("{option}: {e}"))
}

/// The starting points the arguments ask for.
fn starts(args: &SimulateArgs, s: &Scenario) -> Result<Vec<Vec<f64>>, String> {
    let mut points = Vec::new();
    for text in &args.from {
        let x = parse_point("--from", text)?;
        if x.iter().any(|v| !v.is_finite()) {
            return Err(format!("--from {text}: coordinates must be finite"));
        }
        if x.len() != s.n() {
            return Err(format!(
                "--from {text}: expected {} numbers ({}), found {}",
                s.n(),
                s.states.join(", "),
                x.len()
            ));
        }
        points.push(x);
    }
    if let Some(count) = args.samples {
        let b = match &args.sample_box {
            Some(t) => parse_box("--box", t, s.n())?,
            None => s.reach.region.clone(),
        };
        points.extend(safe_samples(s, &b, count, args.seed)?);
    }
    if points.is_empty() {
        return Err("give --from X1,X2,... or --samples N".into());
    }
    Ok(points)
}

/// `count` samples of `b` inside the safe set (rejection sampling).
pub fn safe_samples(
    s: &Scenario,
    b: &IntervalBox,
    count: usize,
    seed: u64,
) -> Result<Vec<Vec<f64>>, String> {
    let mut points = Vec::with_capacity(count);
    let mut round = 0;
    while points.len() < count {
        let batch = sample_box(b, 4 * count.max(16), seed.wrapping_add(round));
        points.extend(
            batch
                .into_iter()
                .filter(|x| s.is_safe(x))
                .take(count - points.len()),
        );
        round += 1;
        if round > 64 {
            return Err("the sampled box has (almost) no safe points".into());
        }
    }
    Ok(points)
}

/// Most memory the trajectories of one `simulate` may take.
const MAX_TRAJECTORY_BYTES: f64 = 8e9;

/// Runs the command.
pub fn run(args: &SimulateArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    let integrator = args
        .integrator
        .unwrap_or_else(|| Integrator::for_time(s.reach.time));
    let dt = args
        .dt
        .unwrap_or_else(|| integrator.step(s.reach.time, s.reach.dt));
    let horizon = args.horizon.unwrap_or(s.reach.horizon);
    if !(dt > 0.0 && horizon > 0.0) {
        return Err(
            format!("--dt and --horizon must be positive, found {dt} and {horizon}").into(),
        );
    }
    if let Some(path) = &args.out {
        check_writable(path).map_err(|e| format!("{}: {e}", path.display()))?;
    }
    let steps_f = (horizon / dt - 1e-9).ceil();
    if steps_f.is_nan() || steps_f > limits::MAX_STEPS {
        return Err(format!(
            "--horizon {} / --dt {} is {steps_f:.3e} steps, more than {:.0e}",
            limits::shown(horizon),
            limits::shown(dt),
            limits::MAX_STEPS
        )
        .into());
    }
    let steps = steps_f as usize;
    // Each trajectory keeps every state: refuse before allocating what does not fit.
    let count = args.samples.unwrap_or(0).saturating_add(args.from.len());
    let bytes = (count as f64) * (steps as f64 + 1.0) * (s.n() as f64 + 1.0) * 8.0;
    if bytes > MAX_TRAJECTORY_BYTES {
        return Err(format!(
            "{count} trajectories of {steps} steps need about {:.1} GB, more than {:.0} GB (fewer --samples or a shorter --horizon)",
            bytes / 1e9,
            MAX_TRAJECTORY_BYTES / 1e9
        )
        .into());
    }
    let filter = SafetyFilter::new(&s);
    let trajectories: Vec<Trajectory> = starts(args, &s)?
        .iter()
        .map(|x0| simulate_filtered(&filter, x0, dt, steps, integrator))
        .collect();

    let mut buffer = Vec::new();
    match args.format {
        Format::Csv => write_csv(&mut buffer, &s.states, &trajectories)?,
        Format::Json => serde_json::to_writer_pretty(&mut buffer, &trajectories)?,
    }
    match &args.out {
        Some(path) => {
            write_atomic(path, &buffer).map_err(|e| format!("{}: {e}", path.display()))?;
            println!(
                "{} trajectories of {} steps (dt = {dt}, {}{}) written to {}",
                trajectories.len(),
                steps,
                integrator.name(),
                match args.integrator {
                    Some(_) => String::new(),
                    None => format!(": the system time = \"{}\" bounds", s.reach.time.name()),
                },
                path.display()
            );
            for t in trajectories.iter().take(20) {
                println!("  {} → {}", fmt_point(&t.x0), fmt_point(t.last()));
            }
        }
        None => std::io::stdout().write_all(&buffer)?,
    }
    print_stops(&trajectories);
    print_outside_s(&s, &trajectories);
    Ok(())
}

/// One line for the starts outside `S`, where the filter promises nothing: it keeps `S`
/// invariant, and from outside its QP may have no solution (a Dubins car aimed at its disc
/// stopped at once, "`disc` needs -4.200e-1 ≥ 0 but the input cannot act on it").
fn print_outside_s(s: &Scenario, trajectories: &[Trajectory]) {
    let outside: Vec<(&Trajectory, &str)> = (trajectories.iter())
        .filter_map(|t| {
            let outside = |h: f64| h < 0.0 || h.is_nan();
            let c = s.cbfs.iter().find(|c| outside(c.h.eval(&t.x0)))?;
            Some((t, c.name.as_str()))
        })
        .collect();
    if let Some((first, cbf)) = outside.first() {
        eprintln!(
            "note: {} of {} starts lie outside S (the first, {}: {cbf} < 0): the filter keeps S \
             invariant, it does not bring states into it",
            outside.len(),
            trajectories.len(),
            fmt_point(&first.x0)
        );
    }
}

/// One line for the trajectories that stopped early: how many, how many at an infeasible QP,
/// and the first one's start and reason.
pub fn print_stops(trajectories: &[Trajectory]) {
    let stopped: Vec<&Trajectory> = trajectories
        .iter()
        .filter(|t| t.stopped.is_some())
        .collect();
    let Some(first) = stopped.first() else {
        return;
    };
    let infeasible = stopped
        .iter()
        .filter(|t| t.stopped.as_ref().is_some_and(|s| s.cause.is_infeasible()))
        .count();
    let reason = first
        .stopped
        .as_ref()
        .map_or(String::new(), ToString::to_string);
    eprintln!(
        "warning: {} of {} trajectories stopped early, {infeasible} of them at an infeasible QP \
         (the first, from {}, {reason})",
        stopped.len(),
        trajectories.len(),
        fmt_point(&first.x0)
    );
}

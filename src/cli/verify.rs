//! `cbfreach verify <scenario>`: a verdict per box of a partitioned region, with refinement and
//! shards; `cbfreach merge`: shard files into one verdict map.

use std::path::{Path, PathBuf};

use cbfreach::plot::{self, Figure};
use cbfreach::reach::{Backend, ReachProblem, ReachSettings};
use cbfreach::scenario::Scenario;
use cbfreach::verify::{
    centre_outcomes, explain_unverified, merge, simulation_check, traps_for, Culprit, Reruns,
    Shard, SimulationCheck, Stage, UnverifiedCauses, Verdict, Verifier, VerifyError, VerifyReport,
    VerifySettings, WhatStops, SUBSTEP_FACTOR,
};

use super::args::{engine, settings_flag_error, EngineArgs, ProblemArgs, ReachFlags};
use super::simulate::parse_box;
use super::{fmt_point, given, load_scenario, progress_bar, resume, CliResult, INTERSECT_X_CLAUSE};
use cbfreach::problem::network_path;
use cbfreach::verify::checkpoint::{Journal, NoJournal};

/// Arguments of `cbfreach verify`. Defaults: the scenario's `[settings.verify]` and
/// `[settings.reach]`, else `VerifySettings::default()` and `ReachSettings::default()`.
#[derive(clap::Args)]
pub struct VerifyArgs {
    /// The scenario file (TOML).
    pub scenario: PathBuf,
    /// Region to partition, LOWER:UPPER (e.g. -3.5,-3:4.5,3); default: the region C.
    #[arg(long, value_name = "LOWER:UPPER", allow_hyphen_values = true)]
    pub region: Option<String>,
    /// Cells per axis, e.g. 64,64 (default: the scenario's `[settings.verify] grid`, else 64 per axis
    /// in one or two states and at most 4,096 cells in more: 16,16,16 or 8,8,8,8).
    #[arg(long)]
    pub grid: Option<Grid>,
    /// Engine and GPU options.
    #[command(flatten)]
    pub engine: EngineArgs,
    /// Bounds, method and sets.
    #[command(flatten)]
    pub reach: ReachFlags,
    /// The network, `M_C` and coordinates.
    #[command(flatten)]
    pub problem: ProblemArgs,
    /// Bisection rounds of `unknown` and `invalid` boxes.
    #[arg(long, default_value_t = VerifySettings::default().refine_depth)]
    pub refine: usize,
    /// Most extra boxes refinement may run (per shard).
    #[arg(long, default_value_t = VerifySettings::default().budget)]
    pub budget: usize,
    /// Refinement also bisects verified boxes whose QP feasibility is not proven (after the
    /// unverified ones, within the budget); their halves keep the verdict.
    #[arg(long)]
    pub refine_feasibility: bool,
    /// Refinement also bisects partly-unsafe boxes, the band along the safe set's boundary
    /// (after the others, within the budget); their halves that start safe are run and join
    /// the safe area.
    #[arg(long)]
    pub refine_boundary: bool,
    /// In continuous time, the most substeps refinement cuts a refined box's step into (the
    /// step halves once every n rounds, n states; 1: refinement keeps the step).
    #[arg(long, value_name = "K", default_value_t = VerifySettings::default().max_substeps)]
    pub max_substeps: usize,
    /// Run every tube to the horizon, not only until its set lies in a box proven absorbing
    /// for the goal or a trap (the verdicts stay or improve with absorbing boxes; without,
    /// converging tubes take every step).
    #[arg(long)]
    pub no_absorb: bool,
    /// Skip the reruns that say what stops the leaves whose sets were too loose (the 8 largest,
    /// with M = 0, with twice their substeps and, where off, with face-local bounds: seconds)
    #[arg(long)]
    pub no_what_stops: bool,
    /// Run only the K-th of N contiguous slices of the cells (1 ≤ K ≤ N); merge the JSON files
    /// with `cbfreach merge`.
    #[arg(long, value_name = "K/N")]
    pub shard: Option<String>,
    /// Write the verdicts as JSON here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Draw the verdict map here (.png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// Record finished boxes here as the run goes (default: `<--json>.checkpoint` when --json
    /// is given); removed when the run ends. An interrupt (Ctrl-C) lets the current chunk finish.
    #[arg(long)]
    pub checkpoint: Option<PathBuf>,
    /// Continue the interrupted run whose checkpoint is there (the same command otherwise);
    /// the report is the one an uninterrupted run writes.
    #[arg(long)]
    pub resume: bool,
    /// Check the verdicts against the ground-truth filter: simulate a K × K (× …) grid of
    /// starts in every verified box and report any that ends elsewhere (0: no check).
    #[arg(long, value_name = "K", default_value_t = 0)]
    pub check: usize,
}

/// `--grid`: cell counts per axis, `N,M,…`.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grid(pub Vec<usize>);

impl std::fmt::Display for Grid {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let parts: Vec<String> = self.0.iter().map(usize::to_string).collect();
        f.write_str(&parts.join(","))
    }
}

impl std::str::FromStr for Grid {
    type Err = String;

    fn from_str(text: &str) -> Result<Grid, String> {
        text.split(',')
            .map(|s| {
                s.trim()
                    .parse::<usize>()
                    .map_err(|_| format!("`{s}` is not a whole number (expected e.g. 64,64)"))
            })
            .collect::<Result<_, _>>()
            .map(Grid)
    }
}

/// Arguments of `cbfreach merge`.
#[derive(clap::Args)]
pub struct MergeArgs {
    /// Verdict files written by `cbfreach verify --shard K/N --json …`.
    #[arg(required = true)]
    pub inputs: Vec<PathBuf>,
    /// Write the merged verdicts here.
    #[arg(long)]
    pub json: Option<PathBuf>,
    /// Draw the merged verdict map here (.png or .svg).
    #[arg(long)]
    pub plot: Option<PathBuf>,
    /// The scenario file, for the picture (default: the one named in the inputs).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
}

/// Runs `verify`.
pub fn run(args: &VerifyArgs) -> CliResult {
    let s = load_scenario(&args.scenario)?;
    let mut settings = s.settings.verify.clone();
    if let Some(t) = &args.region {
        settings.region = Some(parse_box("--region", t, s.n())?);
    }
    settings.shard = args
        .shard
        .as_deref()
        .map(str::parse::<Shard>)
        .transpose()
        .map_err(|e| flag_error(&e))?;
    settings.grid = match &args.grid {
        Some(grid) => grid.0.clone(),
        None => settings.grid_for(s.n()),
    };
    if given("refine") {
        settings.refine_depth = args.refine;
    }
    if given("budget") {
        settings.budget = args.budget;
    }
    settings.refine_feasibility |= args.refine_feasibility;
    settings.refine_boundary |= args.refine_boundary;
    if given("max_substeps") {
        settings.max_substeps = args.max_substeps;
    }
    settings.absorb &= !args.no_absorb;
    settings.validate(&s).map_err(|e| flag_error(&e))?;
    let checkpoint = resume::checkpoint_path(args.checkpoint.as_deref(), args.json.as_deref());
    if args.resume && checkpoint.is_none() {
        return Err(
            "--resume: give --checkpoint FILE (or the --json of the interrupted run)".into(),
        );
    }
    if !args.resume {
        super::check_outputs(&[checkpoint.as_deref()])?;
    }
    super::check_outputs(&[args.json.as_deref(), args.plot.as_deref()])?;
    let problem = super::args::compile(&s, &args.problem)?;
    let mut reach = args.reach.settings(&s.settings.reach);
    reach.every = 1;
    reach.validate().map_err(|e| settings_flag_error(&e))?;
    // `auto` picks an engine that runs every round, refinement's shorter steps too.
    let deepest = settings.problem_at(&problem, settings.refine_depth);
    let cells = settings.grid.iter().product();
    let engine = engine(&args.engine, &mut reach, &deepest, cells)?;
    let network = network_path(&s, args.problem.network.as_deref())?;
    // With a checkpoint, chunks small enough that an interrupt ends soon and keeps most work
    // (the engine's preferred batch is 512 boxes on the CPU, minutes on a loaded machine).
    if checkpoint.is_some() && settings.chunk.is_none() {
        settings.chunk = Some(
            engine
                .preferred_batch()
                .min(16 * rayon::current_num_threads()),
        );
    }
    let identity = resume::identity(&s, &problem, &network, &settings, &reach)
        .map_err(|e| format!("{}: {e}", network.display()))?;
    let journal = match &checkpoint {
        Some(p) => Some(resume::open(p, args.resume, identity.clone())?),
        None => None,
    };
    let mut report = match run_verify(
        &s,
        &problem,
        engine.as_ref(),
        reach.clone(),
        &settings,
        journal
            .as_ref()
            .map_or(&NoJournal as &dyn Journal, |j| j as &dyn Journal),
    ) {
        Err(e) if matches!(e.downcast_ref(), Some(VerifyError::Interrupted)) => {
            let path = checkpoint.unwrap_or_default();
            return Err(format!(
                "interrupted; the finished boxes are in {} (run the same command with --resume to continue)",
                path.display()
            )
            .into());
        }
        Err(e) => match e.downcast_ref::<VerifyError>() {
            Some(v @ VerifyError::Settings { .. }) => return Err(flag_error(v).into()),
            _ => return Err(e),
        },
        Ok(r) => r,
    };
    report.run.network_hash = identity["network"].clone();
    report.run.filter_hash = identity["filter"].clone();
    print_summary(&report);
    let outcomes = centre_outcomes(&s, &report);
    let causes = UnverifiedCauses::of(&report, &outcomes);
    print_causes(&causes, &report);
    let verifier = Verifier {
        scenario: &s,
        problem: &problem,
        backend: engine.as_ref(),
        reach,
        traps: report.traps.clone(),
    };
    if !args.no_what_stops {
        report.what_stops = verifier.what_stops(&settings, &report, &outcomes)?;
    }
    if let Some(w) = &report.what_stops {
        print_what_stops(w);
    }
    print_meet_slabs_hint(&report, &causes);
    write_outputs(&s, &report, args.json.as_deref(), args.plot.as_deref())?;
    if let Some(j) = journal {
        j.finish()?;
    }
    if args.check > 0 {
        print_check(&simulation_check(&s, &report, args.check))?;
    }
    fail_if_unsafe(&report)
}

/// A verification error with the option that sets the field (`--grid: …`).
fn flag_error(e: &VerifyError) -> String {
    match e {
        VerifyError::Settings { field, message } => {
            format!("--{}: {message}", field.replace('_', "-"))
        }
        e => e.to_string(),
    }
}

/// Share of the region in cells straddling `∂S` from which `verify` suggests
/// `--refine-boundary` (the paper's scenarios on their grids, 64 × 64 and 40 × 16: 1.9 and 5.6 %).
const STRADDLING_HINT: f64 = 0.2;

/// What ended the tubes of the boxes not verified, largest share first (where any ended
/// early: a run whose tubes all reached the horizon has nothing to add to `print_causes`).
fn print_ends(r: &VerifyReport) {
    let why = r.why_not_verified();
    if why.iter().all(|(k, _)| k.is_none()) {
        return;
    }
    let parts: Vec<String> = why
        .iter()
        .map(|(k, share)| {
            let what = k.map_or("ran to the horizon outside the goal and the traps", |k| {
                k.describe()
            });
            format!("{:.1}% {what}", 100.0 * share)
        })
        .collect();
    println!("    what ended their tubes: {}", parts.join("; "));
}

/// Prints where the true system goes from the boxes that were not verified, and what ended
/// their tubes.
fn print_causes(c: &UnverifiedCauses, r: &VerifyReport) {
    if c.unverified <= 0.0 {
        return;
    }
    println!(
        "  not verified: {:.1}% of the safe area. From each such box's centre the true filtered system",
        100.0 * c.unverified
    );
    if c.unsafe_between_samples > 0.0 {
        println!(
            "    leaves S between samples on {:.1}% (the held input carries it out: the digital \
             filter does not keep S invariant there)",
            100.0 * c.unsafe_between_samples
        );
    }
    println!(
        "    leaves C on {:.1}%, meets an infeasible QP on {:.1}%, ends in neither the goal nor a trap \
         on {:.1}%, and ends in one on {:.1}% (there the sets were too loose)",
        100.0 * c.leaves_region,
        100.0 * c.infeasible,
        100.0 * c.ends_elsewhere,
        100.0 * c.too_loose
    );
    if c.arrives_later > 0.0 {
        println!(
            "    on {:.1}% of the safe area it reaches the goal or a trap after the horizon, all \
             by t = {:.1}: the horizon ends before they arrive (a longer reach.horizon lets their \
             tubes follow)",
            100.0 * c.arrives_later,
            c.latest_arrival,
        );
    }
    print_ends(r);
}

/// What the reruns of the largest leaves whose sets were too loose found, and the knob it
/// points to.
fn print_what_stops(w: &WhatStops) {
    println!(
        "    the {} largest leaves whose sets were too loose ({:.0}% of their area), run again: \
         {}",
        w.leaves.len(),
        100.0 * w.area_share,
        reruns_clause(&w.reruns, " verify"),
    );
}

/// The reruns' counts, one clause a knob (`passing` after the first count: what they do), and
/// what they point to (`verify`'s and `reach`'s).
pub fn reruns_clause(r: &Reruns, passing: &str) -> String {
    let mut clauses = vec![format!(
        "with M = 0 (the network taken as exact) {}{passing}",
        r.without_error
    )];
    if let Some(k) = r.finer_step {
        clauses.push(format!("with {SUBSTEP_FACTOR}× the substeps {k}"));
    }
    if let Some(k) = r.face_local {
        clauses.push(format!("with --face-local {k}"));
    }
    format!("{}: {}", clauses.join(", "), culprit_advice(r.culprit))
}

/// What a [`Culprit`] says to do.
fn culprit_advice(culprit: Culprit) -> &'static str {
    match culprit {
        Culprit::Error => {
            "the network's error margin stops them: a tighter error map (`cbfreach error \
             --budget`, ten times the default) or a more accurate network comes before \
             refinement or substeps"
        }
        Culprit::Step => {
            "the validated step stops them: more substeps (`--substeps`, `--max-substeps`) \
             come first"
        }
        Culprit::Bounds => {
            "the network's bounds stop them: bounds on each face (`--face-local`, 2n× the bound \
             cost) come first"
        }
        Culprit::Neither => {
            "no one knob stops them: the sets' own width does (more refinement, or other \
             coordinates)"
        }
    }
}

/// Where sets too loose left boxes unverified in continuous time with two frames and the
/// slabs unclipped (`--no-meet-slabs`), says what the clip does (ACC's 16 × 6 cells: 1.1 %
/// verified without it, 100 % with it).
fn print_meet_slabs_hint(r: &VerifyReport, c: &UnverifiedCauses) {
    use cbfreach::reach::TimeModel;
    let continuous = TimeModel::from_label(&r.run.time) == Some(TimeModel::Continuous);
    if continuous && r.run.intersect_x && !r.run.meet_slabs && c.too_loose > 0.0 {
        println!(
            "    (without --no-meet-slabs each frame's slabs are clipped by the other frame's set: \
             far tighter where the closed loop turns the sets; docs/design.md §7.1 item 7)"
        );
    }
}

/// Prints what [`simulation_check`] found; an error when a start disagrees with its verdict.
fn print_check(c: &SimulationCheck) -> CliResult {
    println!(
        "  ground-truth check: {} starts in {} verified boxes simulated, {} disagree{}",
        c.starts,
        c.boxes,
        c.disagreements.len(),
        if c.stopped > 0 {
            format!(
                " ({} stopped at an infeasible QP, in boxes whose feasibility was not proven)",
                c.stopped
            )
        } else {
            String::new()
        }
    );
    for (x0, verdict, end) in c.disagreements.iter().take(10) {
        println!(
            "    {} says {}, the trajectory ends at {}",
            fmt_point(x0),
            verdict.name(),
            fmt_point(end)
        );
    }
    if c.disagreements.is_empty() {
        Ok(())
    } else {
        Err(format!(
            "{} simulated starts end elsewhere than their box's verdict says",
            c.disagreements.len()
        )
        .into())
    }
}

/// Finds the traps and runs the verifier with progress bars.
pub fn run_verify(
    s: &Scenario,
    problem: &ReachProblem,
    engine: &dyn Backend,
    reach: ReachSettings,
    settings: &VerifySettings,
    journal: &dyn Journal,
) -> Result<VerifyReport, Box<dyn std::error::Error>> {
    // The equilibria search runs once per run, here (its traps are shared by every box).
    let clock = std::time::Instant::now();
    let traps = traps_for(s);
    let equilibria_s = clock.elapsed().as_secs_f64();
    eprintln!(
        "equilibria: {} trap(s) from the search over C in {equilibria_s:.2} s",
        traps.len(),
    );
    let verifier = Verifier {
        scenario: s,
        problem,
        backend: engine,
        reach,
        traps,
    };
    let bar = std::sync::Mutex::new(None::<(Stage, indicatif::ProgressBar)>);
    let progress = |stage: Stage, done: usize, total: usize| {
        let Ok(mut slot) = bar.lock() else { return };
        if slot.as_ref().map(|(s, _)| *s) != Some(stage) {
            if let Some((_, b)) = slot.take() {
                b.finish_and_clear();
            }
            let what = match stage {
                Stage::Cells => "boxes".to_string(),
                Stage::Refine(d) => format!("refinement {d}"),
            };
            *slot = Some((stage, progress_bar(total as u64, &what)));
        }
        if let Some((_, b)) = slot.as_ref() {
            b.set_length(total as u64);
            b.set_position(done as u64);
        }
    };
    let mut report = verifier.run_journaled(settings, &progress, journal)?;
    report.timing.equilibria_s = equilibria_s;
    report.timing.total_s += equilibria_s;
    if let Ok(mut slot) = bar.lock() {
        if let Some((_, b)) = slot.take() {
            b.finish_and_clear();
        }
    }
    Ok(report)
}

/// The time model, and in continuous time the step of the cells and of the refined boxes.
fn time_clause(r: &VerifyReport) -> String {
    let time = if r.run.time.is_empty() {
        "euler"
    } else {
        &r.run.time
    };
    if time != "continuous" {
        return time.to_string();
    }
    let step = |k: usize| match k {
        1 => "dt".to_string(),
        k => format!("dt/{k}"),
    };
    let deepest = r.after.iter().map(|b| b.depth).max().unwrap_or(0);
    let finest = r.run.max_substeps.max(r.run.substeps);
    match deepest > 0 && finest > r.run.substeps {
        true => format!(
            "continuous (step {}, refined boxes down to {})",
            step(r.run.substeps),
            step(finest)
        ),
        false => format!("continuous (step {})", step(r.run.substeps)),
    }
}

/// The summary table: boxes and area share per verdict, before and after refinement.
pub fn print_summary(r: &VerifyReport) {
    let (b, a) = (r.shares_before(), r.shares_after());
    let refined = r.run.refine_depth > 0;
    let within = super::safe_set_clause(&r.run.safe_set);
    println!(
        "{} ({}): region {:?}…{:?}, grid {:?}{}, time {}, {} bounds{}, {} method, {}{within}",
        r.run.scenario,
        r.run.scenario_file,
        r.run.region.lower,
        r.run.region.upper,
        r.run.grid,
        r.shard.map_or(String::new(), |s| format!(
            ", shard {s} (cells {}..{})",
            r.cells[0], r.cells[1]
        )),
        time_clause(r),
        r.run.bounds,
        if r.run.face_local {
            " (face-local)"
        } else {
            ""
        },
        r.run.method,
        if r.run.local_margin {
            "M = local bounds of the certified error map".to_string()
        } else {
            format!("M_C = {}", r.run.m_c)
        } + r.run.exact.clause()
            + if r.run.intersect_x {
                INTERSECT_X_CLAUSE
            } else {
                ""
            }
            + super::sharper_clause(r.run.taylor3, r.run.lattice)
            + &super::meet_slabs_clause(r.run.meet_slabs, r.run.turned_frames)
    );
    for a in &r.run.absorbing {
        println!(
            "  absorbing for {}: {} … {} (back in it after {} step{}); tubes stop there",
            a.trap
                .map_or("the goal".to_string(), |k| format!("trap {k}")),
            super::fmt_point(&a.inner.lower),
            super::fmt_point(&a.inner.upper),
            a.period,
            if a.period == 1 { "" } else { "s" }
        );
    }
    if refined {
        println!(
            "  {:<22} {:>7} {:>8}   {:>7} {:>8}",
            "verdict", "boxes", "share", "leaves", "share"
        );
    } else {
        println!("  {:<22} {:>7} {:>8}", "verdict", "boxes", "share");
    }
    for v in Verdict::ALL {
        let (nb, na) = (
            b.count.get(&v).copied().unwrap_or(0),
            a.count.get(&v).copied().unwrap_or(0),
        );
        if nb == 0 && na == 0 {
            continue;
        }
        let mut line = format!("  {:<22} {:>7} {:>7.1}%", v.name(), nb, 100.0 * b.share(v));
        if refined {
            line += &format!("   {:>7} {:>7.1}%", na, 100.0 * a.share(v));
        }
        println!("{line}");
    }
    println!("  (shares of the safe area; unsafe-start and partly-unsafe: of the whole region)");
    // The headline is the share with the QP proven feasible on every set; beside it, labelled,
    // the share that also counts verdicts covering only the trajectories that exist.
    let h = r.headline();
    let beside = |proven: f64, existing: f64| {
        if existing > proven {
            format!(
                " ({:.1}% counting boxes where only the trajectories that exist are covered: \
                 the QP's feasibility is not proven on their sets)",
                100.0 * existing
            )
        } else {
            String::new()
        }
    };
    println!(
        "  verified (converges ∪ trapped, the filter proven feasible on every set): {:.1}% of the \
         safe area{}",
        100.0 * h.verified,
        beside(h.verified, h.verified_existing_trajectories)
    );
    if refined {
        println!(
            "    before refinement {:.1}%{}; {} rounds, {} extra boxes",
            100.0 * h.verified_before_refinement,
            beside(
                h.verified_before_refinement,
                h.verified_existing_trajectories_before_refinement
            ),
            r.run.refine_depth,
            r.timing.boxes_run
                - b.count
                    .iter()
                    .filter(|(v, _)| v.starts_safe())
                    .map(|(_, c)| c)
                    .sum::<usize>()
        );
    }
    // The leaves tile the cells: one region area for both.
    if r.run.refine_boundary && b.total_area > 0.0 {
        let share = |s: &cbfreach::verify::Shares| 100.0 * s.safe_area / b.total_area;
        println!(
            "    the band along the safe set's boundary refined: the safe area is {:.1}% of the \
             region, {:.1}% before refinement",
            share(&a),
            share(&b)
        );
    } else if b.total_area > 0.0 {
        // Cells straddling ∂S are skipped, not run: where they are much of the region (S
        // depending on velocities, coarse cells in several states) say how to reach them.
        let straddling = a.area.get(&Verdict::PartlyUnsafe).copied().unwrap_or(0.0) / b.total_area;
        if straddling >= STRADDLING_HINT {
            println!(
                "    {:.1}% of the region lies in cells straddling ∂S, skipped: --refine-boundary \
                 also bisects them, and their halves in S join the safe area",
                100.0 * straddling
            );
        }
    }
    let rate = |steps: usize| steps as f64 / r.timing.reach_s.max(1e-9);
    // Substeps: the box-steps of dt were cut into more steps of the integrator.
    let cut = match r.timing.integration_steps > r.timing.box_steps {
        true => format!(
            "; {:.0} integrator steps/s, substeps included",
            rate(r.timing.integration_steps)
        ),
        false => String::new(),
    };
    println!(
        "  time: {:.2} s ({:.2} s in the engine, {} boxes, {:.0} box-steps/s{cut})",
        r.timing.total_s,
        r.timing.reach_s,
        r.timing.boxes_run,
        rate(r.timing.box_steps)
    );
}

/// Writes `--json` and `--plot`.
pub fn write_outputs(
    s: &Scenario,
    r: &VerifyReport,
    json: Option<&Path>,
    plot_to: Option<&Path>,
) -> CliResult {
    if let Some(path) = json {
        cbfreach::output::write_atomic(path, r.to_json().as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("  verdicts written to {}", path.display());
    }
    if let Some(path) = plot_to {
        let size = plot::default_size(&r.run.region, 1000);
        plot::save(
            &Figure::Verdicts {
                scenario: s,
                report: r,
            },
            path,
            size,
        )?;
        println!("  verdict map drawn to {}", path.display());
    }
    Ok(())
}

/// Prints a loud banner and fails when some set met the unsafe set.
pub fn fail_if_unsafe(r: &VerifyReport) -> CliResult {
    let bad = r.unsafe_boxes();
    if bad.is_empty() {
        return Ok(());
    }
    eprintln!("\n!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!");
    eprintln!(
        "!!! UNSAFE: {} box(es) that start safe have a reachable set lying",
        bad.len()
    );
    eprintln!("!!! entirely in the unsafe set after sets on which the QP is proven feasible.");
    eprintln!("!!! A correct filter cannot do this: this is");
    eprintln!("!!! a bug in the filter, the network's error bound M_C, or the engine.");
    for b in bad.iter().take(10) {
        eprintln!(
            "!!!   {:?}…{:?}: {}",
            b.initial.lower,
            b.initial.upper,
            b.note.as_deref().unwrap_or("")
        );
    }
    eprintln!("!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!!\n");
    Err(format!("{} box(es) judged unsafe (see above)", bad.len()).into())
}

/// Runs `merge`.
pub fn run_merge(args: &MergeArgs) -> CliResult {
    let mut parts = Vec::new();
    for p in &args.inputs {
        let name = p.display().to_string();
        let text = std::fs::read_to_string(p).map_err(|e| format!("{name}: {e}"))?;
        parts.push((name.clone(), VerifyReport::from_json(&text, &name)?));
    }
    let merged = merge(parts)?;
    print_summary(&merged);
    let s =
        match (&args.scenario, args.plot.is_some()) {
            (Some(p), _) => Some(load_scenario(p)?),
            (None, true) => Some(load_scenario(Path::new(&merged.run.scenario_file)).map_err(
                |e| format!("{e} (the picture needs the scenario; give it with --scenario)"),
            )?),
            (None, false) => None,
        };
    if let Some(s) = &s {
        print_causes(&explain_unverified(s, &merged), &merged);
    }
    if let Some(path) = &args.json {
        cbfreach::output::write_atomic(path, merged.to_json().as_bytes())
            .map_err(|e| format!("{}: {e}", path.display()))?;
        println!("  merged verdicts written to {}", path.display());
    }
    if let (Some(s), Some(path)) = (&s, &args.plot) {
        write_outputs(s, &merged, None, Some(path))?;
    }
    fail_if_unsafe(&merged)
}

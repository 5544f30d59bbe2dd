//! `cbfreach paper`: both experiments of the paper end to end — figures, the verdicts of the
//! scenarios' initial boxes, and the run times next to the paper's.

use std::path::{Path, PathBuf};
use std::time::Instant;

use cbfreach::bounds::BoundMethod;
use cbfreach::equilibria::{find_equilibria, Equilibrium, EquilibriumSearch};
use cbfreach::error_map::ErrorMap;
use cbfreach::filter::SafetyFilter;
use cbfreach::plot::{self, Figure};
use cbfreach::problem::network_path;
use cbfreach::reach::{ReachMethod, ReachSettings, Tube};
use cbfreach::scenario::{Margin, Scenario};
use cbfreach::verify::{
    no_journals, traps_for_equilibria, verify_by_pieces, BoxVerdict, PiecesSettings, PiecesVerdict,
    Verdict, VerifyError,
};

use super::args::{compile, ProblemArgs};
use super::equilibria::print_table;
use super::plot::{
    box_trajectories, figure_points, reach_initial, trajectories, tubes_title, tubes_title_local,
};
use super::{fmt_point, resume, CliResult};

/// Arguments of `cbfreach paper`.
#[derive(clap::Args)]
pub struct PaperArgs {
    /// Folder for the figures.
    #[arg(long, short, default_value = "out")]
    pub out: PathBuf,
    /// Network of scenario 1 (default: the scenario's).
    #[arg(long)]
    pub network_1: Option<PathBuf>,
    /// Network of scenario 2 (default: the scenario's).
    #[arg(long)]
    pub network_2: Option<PathBuf>,
    /// How the network is bounded for the sound verdicts (on each face of a box: immrax's
    /// `local` mode).
    #[arg(long, value_enum, default_value_t = ReachSettings::default().bounds)]
    pub bounds: BoundMethod,
    /// Bound methods whose run times are set next to the paper's (comma-separated).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "forward,forward-backward"
    )]
    pub timed: Vec<BoundMethod>,
    /// Rounds of bisection of the pieces of an initial box that are not verified whole, or
    /// whose QP feasibility is not proven (as `verify --refine --refine-feasibility`; at most
    /// 4,096 extra pieces per box). Scenario 2's box at (−1, 1.5), whose trajectories pass
    /// 0.11–0.25 from the jump of `v` at (3, 0), needs 8 under `euler` (576 pieces, the
    /// narrowest eight bisections of a 0.05-wide one), 10 under `continuous`.
    #[arg(long, default_value_t = PiecesSettings::default().refine)]
    pub refine: usize,
    /// What the sound verdicts' sets bound: the paper's Euler map by default (its
    /// experiments step it), or `continuous` (the ODE, validated steps) or `sampled`.
    #[arg(long, default_value = "euler", value_parser = ["continuous", "sampled", "euler"])]
    pub time: String,
    /// Cut each continuous-time step of the sound verdicts in K validated steps (the step's
    /// O(h²) loss: scenario 2's pieces passing (3, 0) need 2; default: the scenario's, else 1).
    #[arg(long, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub substeps: Option<usize>,
    /// In continuous time, the most substeps refinement cuts a refined piece's step into (as
    /// `verify --max-substeps`: the step halves once every n rounds; 1: refinement keeps the
    /// step). Twice verify's default: the deepest pieces of scenario 2's box at (−1, 1.5)
    /// need steps of dt/8.
    #[arg(
        long,
        value_name = "K",
        default_value_t = PiecesSettings::default().max_substeps,
        value_parser = |s: &str| super::whole_at_least(s, 1)
    )]
    pub max_substeps: usize,
    /// Continuous time: bound the sound verdicts' steps on a proven piece of the filter by its
    /// Taylor form to second order too (as `reach`/`verify --taylor3`).
    #[arg(long)]
    pub taylor3: bool,
    /// Continuous time: no lattice of the filter's pieces across a switching surface (as
    /// `reach`/`verify --no-lattice`).
    #[arg(long)]
    pub no_lattice: bool,
    /// Continue an interrupted run (the same command otherwise) from the checkpoints it left
    /// in --out: the split boxes' finished pieces are not run again. Without it, a run
    /// refuses to start over those files.
    #[arg(long)]
    pub resume: bool,
}

/// What the paper reports for one experiment: its times and its sampled `M_C`.
#[derive(Clone, Copy)]
struct PaperFigures {
    /// The embedding for every initial box, seconds.
    embedding_s: f64,
    /// The closeness radius, seconds.
    radius_s: f64,
    /// The sampled network error it used.
    m_c: f64,
}

/// The paper's times (the embedding for every initial box, and the closeness radius) and ours:
/// the paper's construction per timed bound method, and the sound verdicts' run.
struct PaperTimes {
    name: String,
    boxes: usize,
    steps: usize,
    paper: PaperFigures,
    /// `(bounds, embedding s, radius s, box-steps run)` of the Minkowski method.
    minkowski: Vec<(BoundMethod, f64, f64, usize)>,
    /// The sound run: its settings in words, its time and the box-steps it ran.
    sound: (String, f64, usize),
}

/// The paper's scenario 1: 2.15 s and 0.02 s, `M_C = 0.19`.
const SCENARIO_1: PaperFigures = PaperFigures {
    embedding_s: 2.15,
    radius_s: 0.02,
    m_c: 0.19,
};

/// The paper's scenario 2: 2.7 s and 0.015 s, `M_C = 0.26`.
const SCENARIO_2: PaperFigures = PaperFigures {
    embedding_s: 2.7,
    radius_s: 0.015,
    m_c: 0.26,
};

/// Where a scenario of the paper lives: `scenarios/<file>` from the working folder, else the
/// crate's own copy.
fn scenario_path(file: &str) -> PathBuf {
    let here = Path::new("scenarios").join(file);
    if here.exists() {
        here
    } else {
        Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("scenarios")
            .join(file)
    }
}

/// Runs `paper`.
pub fn run(args: &PaperArgs) -> CliResult {
    let clock = Instant::now();
    std::fs::create_dir_all(&args.out).map_err(|e| format!("{}: {e}", args.out.display()))?;
    let experiments = [
        ("integrator.toml", &args.network_1, SCENARIO_1),
        ("double-integrator.toml", &args.network_2, SCENARIO_2),
    ]
    .into_iter()
    .map(|(file, net, paper)| Ok((Scenario::load(&scenario_path(file))?, net, paper)))
    .collect::<Result<Vec<_>, Box<dyn std::error::Error>>>()?;
    let names: Vec<&str> = experiments.iter().map(|(s, ..)| s.name.as_str()).collect();
    let checkpoints = resume::PiecesCheckpoints::new(&args.out, args.resume, &names)?;
    let mut times = Vec::new();
    for (k, (s, net, paper)) in experiments.iter().enumerate() {
        println!("══ Scenario {} ══", k + 1);
        let verdicts = VerdictSettings {
            bounds: args.bounds,
            pieces: PiecesSettings {
                refine: args.refine,
                max_substeps: args.max_substeps,
            },
            time: args.time.clone(),
            substeps: args.substeps,
            taylor3: args.taylor3,
            lattice: !args.no_lattice,
        };
        let run = run_scenario(
            s,
            net.as_ref(),
            &args.out,
            verdicts,
            &args.timed,
            *paper,
            Some(&checkpoints),
        );
        match run {
            Err(e) if matches!(e.downcast_ref(), Some(VerifyError::Interrupted)) => {
                return Err(format!(
                    "interrupted; the split boxes' finished pieces are in {}/*.checkpoint (run \
                     the same command with --resume to continue)",
                    args.out.display()
                )
                .into())
            }
            Err(e) => return Err(e),
            Ok(Some(t)) => times.push(t),
            Ok(None) => {}
        }
        println!();
    }
    checkpoints
        .finish()
        .map_err(|e| format!("removing the checkpoints in {}: {e}", args.out.display()))?;
    print_times(&times);
    println!(
        "\nFigures are in {}/ ({:.1} s in all).",
        args.out.display(),
        clock.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `cbfreach` with no arguments: scenario 1 of the paper, its boxes verified in continuous
/// time, figures into `out/`.
pub fn run_default() -> CliResult {
    let clock = Instant::now();
    let s = match Scenario::load(&scenario_path("integrator.toml")) {
        Ok(s) => s,
        Err(_) => Scenario::builtin()?,
    };
    let out = PathBuf::from("out");
    std::fs::create_dir_all(&out).map_err(|e| format!("{}: {e}", out.display()))?;
    println!(
        "cbfreach — the paper's scenario 1, `{}` ({})",
        s.name, s.file
    );
    println!("  {}\n", s.description.replace('\n', "\n  "));
    let timed = [BoundMethod::Forward, BoundMethod::ForwardBackward];
    // The verdicts speak of the filtered ODE, the system a user runs (the paper's Euler map
    // stays in the table of times below, as the paper's construction). Two of the 12 boxes
    // pass the obstacle at speed and are proven as 16 pieces: four rounds cover them.
    let verdicts = VerdictSettings {
        bounds: ReachSettings::default().bounds,
        pieces: PiecesSettings {
            refine: 4,
            ..PiecesSettings::default()
        },
        time: "continuous".into(),
        substeps: None,
        taylor3: ReachSettings::default().taylor3,
        lattice: ReachSettings::default().lattice,
    };
    // Seconds of work (two boxes in pieces): nothing worth a checkpoint.
    let times = run_scenario(&s, None, &out, verdicts, &timed, SCENARIO_1, None)?;
    if let Some(t) = times {
        println!();
        print_times(&[t]);
    }
    println!(
        "\nPictures are in {}/ ({:.1} s). Next: `cbfreach paper` (both experiments), \
         `cbfreach verify {}` (a verdict per box of C), `cbfreach --help`.",
        out.display(),
        clock.elapsed().as_secs_f64(),
        s.file
    );
    Ok(())
}

/// One experiment: equilibria and trajectories (always), then, when the network exists, tubes
/// of both methods, the initial boxes' verdicts (split boxes' pieces journaled in
/// `checkpoints`) and the times.
fn run_scenario(
    s: &Scenario,
    network: Option<&PathBuf>,
    out: &Path,
    verdict_settings: VerdictSettings,
    timed: &[BoundMethod],
    paper: PaperFigures,
    checkpoints: Option<&resume::PiecesCheckpoints>,
) -> Result<Option<PaperTimes>, Box<dyn std::error::Error>> {
    let bounds = verdict_settings.bounds;
    let filter = SafetyFilter::new(s);
    let found = find_equilibria(&filter, &s.reach.region, &EquilibriumSearch::default());
    println!("Equilibria of the filtered system in C ({}):", found.len());
    print_table(&found);
    endpoint_summary(s, &found);

    let size = plot::default_size(&s.reach.region, 1000);
    let fig = |what: &str| out.join(format!("{}-{what}.png", s.name));
    let traj = trajectories(s, &figure_points(s));
    let path = fig("trajectories");
    plot::save(
        &Figure::Trajectories {
            scenario: s,
            trajectories: &traj,
            equilibria: &found,
        },
        &path,
        size,
    )?;
    println!("Figure 1 (trajectories, equilibria): {}", path.display());

    let net_path = network_path(s, network.map(PathBuf::as_path))?;
    if !net_path.exists() {
        println!(
            "No network at {} — skipping the tubes, verdicts and times of this scenario \
             (train one with `cbfreach train {}`, or give one with --network-N).",
            net_path.display(),
            s.file
        );
        return Ok(None);
    }
    // The sound run: the disturbance method, with the certified local bounds of the error map
    // when the network has one (else the scenario's M_C), face-local bounds.
    let map = ErrorMap::load_for(&net_path).ok();
    let local = map.is_some();
    if let Some(map) = &map {
        let path = fig("error-map");
        plot::save(&Figure::ErrorMap { scenario: s, map }, &path, size)?;
        println!(
            "Error map (certified local bound on ‖N − v‖∞ per cell): {}",
            path.display()
        );
    }
    let problem = compile(
        s,
        &ProblemArgs {
            network: network.cloned(),
            local_margin: local,
            m_c: (!local).then_some(Margin::Value(paper.m_c)),
            time: Some(verdict_settings.time.clone()),
            substeps: verdict_settings.substeps,
            ..ProblemArgs::default()
        },
    )?;
    let continuous = problem.time == cbfreach::reach::TimeModel::Continuous;
    let mut cut = match problem.substeps {
        k if k > 1 && continuous => format!(", each step cut in {k}"),
        _ => String::new(),
    };
    let finest = verdict_settings.pieces.max_substeps;
    if continuous && verdict_settings.pieces.refine > 0 && finest > problem.substeps.max(1) {
        cut += &format!(", refined pieces' steps down to dt/{finest}");
    }
    // The sound verdicts' runs: each piece of a box bounded face by face.
    let pieces = ReachSettings {
        bounds,
        face_local: true,
        taylor3: verdict_settings.taylor3,
        lattice: verdict_settings.lattice,
        ..ReachSettings::default()
    };
    println!(
        "Time model: {} — {}{cut}{}{}",
        problem.time,
        problem.time.clause(),
        super::sharper_clause_of(&problem, &pieces),
        super::meet_slabs_clause(
            problem.meet_slabs_applies(&pieces),
            problem.turned_frames(&pieces),
        )
    );
    if problem.time == cbfreach::reach::TimeModel::Euler {
        println!(
            "  (the paper's experiments step the Euler map; `paper --time continuous` or \
             `reach`/`verify`, continuous by default, bound the ODE)"
        );
    }
    let margin = if local {
        "certified local M of the error map".to_string()
    } else {
        format!(
            "M_C = {}, the paper's sampled error: NOT a certified bound (no error map: run \
             `cbfreach error`)",
            problem.m_c
        )
    };
    let every = 10;
    let dist = reach_initial(s, &problem, bounds, ReachMethod::Disturbance, 1, true)?;
    let traps = traps_for_equilibria(s, &found);
    println!(
        "Sound verdicts of the {} initial boxes (disturbance method, {bounds} bounds on faces, {margin}):",
        s.reach.initial.len(),
    );
    let bar = std::sync::Mutex::new(None::<indicatif::ProgressBar>);
    let verdicts = verify_by_pieces(
        s,
        &problem,
        &pieces,
        &traps,
        &dist.boxes,
        verdict_settings.pieces,
        &|k, run| match checkpoints {
            Some(c) => c.journal(s, &problem, &net_path, run, &pieces, k),
            None => no_journals(k, run),
        },
        &|done, all| {
            let Ok(mut bar) = bar.lock() else { return };
            bar.get_or_insert_with(|| super::progress_bar(all as u64, "initial boxes split"))
                .set_position(done as u64);
        },
    )?;
    if let Ok(Some(bar)) = bar.into_inner() {
        bar.finish_and_clear();
    }
    print_verdicts(&dist.boxes, &verdicts);
    let split: Vec<(usize, &[BoxVerdict])> = verdicts
        .iter()
        .enumerate()
        .filter_map(|(k, v)| Some((k, v.proven_pieces()?)))
        .collect();
    let path = fig("tubes");
    let title = if local {
        tubes_title_local(s, every)
    } else {
        tubes_title(s, problem.m_c, every)
    };
    plot::save(
        &Figure::Tubes {
            scenario: s,
            tubes: &dist.boxes,
            split: &split,
            every,
            title,
        },
        &path,
        size,
    )?;
    println!(
        "Figure 2 (tubes, disturbance method; boxes proven in pieces drawn as their pieces): {}",
        path.display()
    );

    // The paper's construction (Theorem 2) with the scenario's M_C, timed per bound method.
    let paper_problem = compile(
        s,
        &ProblemArgs {
            network: network.cloned(),
            m_c: Some(Margin::Value(paper.m_c)),
            ..ProblemArgs::default()
        },
    )?
    // The paper's construction steps the Euler map (its experiments do), not the ODE.
    .with_time(cbfreach::reach::TimeModel::Euler, 1);
    if problem.time != cbfreach::reach::TimeModel::Euler {
        println!(
            "The paper's construction (Theorem 2) below runs the Euler map x ← x + dt·F(x), as \
             the paper's experiments do; the sound run above: time {}",
            problem.time
        );
    }
    let mut minkowski = Vec::new();
    let mut figure3 = None;
    for &method in timed {
        let mink = reach_initial(s, &paper_problem, method, ReachMethod::Minkowski, 1, false)?;
        minkowski.push((
            method,
            mink.timing.reach_s,
            mink.timing.minkowski_s,
            steps_run(&mink.boxes, problem.dt),
        ));
        figure3.get_or_insert(mink);
    }
    if let Some(mink) = figure3 {
        let lines = box_trajectories(s, &s.reach.initial, 8);
        let path = fig("minkowski");
        plot::save(
            &Figure::Minkowski {
                scenario: s,
                tubes: &mink.boxes,
                trajectories: &lines,
                every,
            },
            &path,
            size,
        )?;
        println!(
            "Figure 3 (the paper's sets with and without the closeness radius, M_C = {}): {}",
            paper_problem.m_c,
            path.display()
        );
        let escapes = count_escapes(&mink.boxes, &lines, s.reach.initial.len(), 8);
        if escapes > 0 {
            println!(
                "  note: {escapes} sampled filtered states lie outside the Minkowski sets (docs/design.md §2.6: \
                 the paper's method is not sound in general)"
            );
        }
    }
    Ok(Some(PaperTimes {
        name: s.name.clone(),
        boxes: s.reach.initial.len(),
        steps: problem.steps,
        paper,
        minkowski,
        sound: (
            format!("{bounds}, faces"),
            dist.timing.reach_s,
            steps_run(&dist.boxes, problem.dt),
        ),
    }))
}

/// Euler steps the tubes actually ran (a box stops where its set leaves `C`).
fn steps_run(tubes: &[Tube], dt: f64) -> usize {
    tubes.iter().map(|t| t.steps_run(dt)).sum()
}

/// How the sound verdicts of the initial boxes are reached.
#[derive(Clone)]
struct VerdictSettings {
    /// Network bounds (on each face of a box).
    bounds: BoundMethod,
    /// Bisection rounds of the pieces not verified, and how far their step is cut.
    pieces: PiecesSettings,
    /// The time model (`euler` by default: the paper's).
    time: String,
    /// Substeps of a continuous step (`None`: the scenario's).
    substeps: Option<usize>,
    /// [`ReachSettings::taylor3`] and [`ReachSettings::lattice`] of the verdicts' runs.
    taylor3: bool,
    lattice: bool,
}

/// One line per initial box: its verdict and note, then the tally.
fn print_verdicts(tubes: &[Tube], verdicts: &[PiecesVerdict]) {
    let mut counts = std::collections::BTreeMap::<Verdict, usize>::new();
    for (tube, p) in tubes.iter().zip(verdicts) {
        let (v, note) = (&p.verdict, p);
        *counts.entry(*v).or_default() += 1;
        println!(
            "  {} … {}  {:<10} {}",
            fmt_point(&tube.initial.lower),
            fmt_point(&tube.initial.upper),
            v.name(),
            note
        );
    }
    let tally: Vec<String> = counts.iter().map(|(v, c)| format!("{c} {v}")).collect();
    println!("  → {}", tally.join(", "));
}

/// Sampled filtered states outside their box's Minkowski set at the recorded times.
fn count_escapes(
    tubes: &[cbfreach::reach::Tube],
    lines: &[cbfreach::simulate::Trajectory],
    boxes: usize,
    per_box: usize,
) -> usize {
    let mut escapes = 0;
    for b in 0..boxes {
        let Some(tube) = tubes.get(b) else { continue };
        for line in lines.iter().skip(b * per_box).take(per_box) {
            for s in &tube.tube {
                let k = (s.t / (line.t.get(1).copied().unwrap_or(1.0))).round() as usize;
                if let Some(x) = line.x.get(k) {
                    if !s.set.contains(x) {
                        escapes += 1;
                    }
                }
            }
        }
    }
    escapes
}

/// Where the filtered trajectories from the initial boxes' centres end.
fn endpoint_summary(s: &Scenario, found: &[Equilibrium]) {
    let integrator = cbfreach::simulate::Integrator::for_time(s.reach.time);
    let step = integrator.step(s.reach.time, s.reach.dt);
    println!(
        "Filtered trajectories from the centres of the {} initial boxes ({}, dt = {step}, T = {}):",
        s.reach.initial.len(),
        integrator.name(),
        s.reach.horizon
    );
    super::report::print_endpoints(s, found);
}

fn print_times(times: &[PaperTimes]) {
    if times.is_empty() {
        println!("No times to compare: no network was available.");
        return;
    }
    println!("Times (this machine, CPU backend, network bounds included) next to the paper's:");
    println!(
        "  {:<18} {:>5} {:>6}  {:<32} {:>10} {:>10} {:>12} {:>12}",
        "scenario", "boxes", "steps", "run", "embedding", "radius", "box-steps/s", "vs paper"
    );
    for t in times {
        let full = t.boxes * t.steps;
        // A box stops where its set leaves C: then the run is not the paper's whole workload.
        let speed = |run: usize, secs: f64| format!("{:.0}", run as f64 / secs.max(1e-9));
        // Rates, not times: a box stops where its set leaves C, so runs differ in length.
        let versus = |run: usize, secs: f64| {
            let ours = run as f64 / secs.max(1e-9);
            let paper = full as f64 / t.paper.embedding_s;
            let ratio = format!("{:.1}×", ours / paper);
            if run == full {
                ratio
            } else {
                format!("{ratio} ({}%)", 100 * run / full.max(1))
            }
        };
        println!(
            "  {:<18} {:>5} {:>6}  {:<32} {:>8.2} s {:>8.3} s {:>12} {:>12}",
            t.name,
            t.boxes,
            t.steps,
            "paper (Theorem 2)",
            t.paper.embedding_s,
            t.paper.radius_s,
            "",
            ""
        );
        for &(method, emb, radius, run) in &t.minkowski {
            println!(
                "  {:<18} {:>5} {:>6}  {:<32} {:>8.3} s {:>8.4} s {:>12} {:>12}",
                "",
                "",
                "",
                format!("Theorem 2, {method}"),
                emb,
                radius,
                speed(run, emb),
                versus(run, emb)
            );
        }
        let (label, secs, run) = &t.sound;
        println!(
            "  {:<18} {:>5} {:>6}  {:<32} {:>8.3} s {:>10} {:>12} {:>12}",
            "",
            "",
            "",
            format!("sound ({label})"),
            secs,
            "",
            speed(*run, *secs),
            versus(*run, *secs)
        );
    }
    println!(
        "  (embedding: the NN-system tubes of every initial box; radius: the closeness radius r_t; \
         sound: the disturbance method's tubes behind the verdicts, with the filter's own field \
         where it is proven one smooth function on the set; ×: our box-steps per second over \
         the paper's; (k%): the share of the box-steps run, as a box stops where its set leaves C)"
    );
}

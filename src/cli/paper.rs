//! `cbfreach paper`: both experiments of the paper end to end — figures, the verdicts of the
//! scenarios' initial boxes, and the run times next to the paper's.

use std::path::{Path, PathBuf};
use std::time::Instant;

use cbfreach::bounds::BoundMethod;
use cbfreach::equilibria::{find_equilibria, Equilibrium, EquilibriumSearch};
use cbfreach::filter::SafetyFilter;
use cbfreach::plot::{self, Figure};
use cbfreach::reach::ReachMethod;
use cbfreach::reach::Tube;
use cbfreach::scenario::Scenario;
use cbfreach::surrogate_error::ErrorMap;
use cbfreach::verify::{judge, traps_from_equilibria, Trap, Verdict};

use super::equilibria::print_table;
use super::plot::{
    box_trajectories, figure_points, reach_initial, trajectories, tubes_title, tubes_title_local,
};
use super::reach::{compile, network_path, ProblemArgs};
use super::{fmt_point, CliResult};

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
    #[arg(long, value_enum, default_value_t = BoundMethod::ForwardBackward)]
    pub bounds: BoundMethod,
    /// Bound methods whose run times are set next to the paper's (comma-separated).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "forward,forward-backward"
    )]
    pub timed: Vec<BoundMethod>,
}

/// The paper's times (the embedding for every initial box, and the closeness radius) and ours:
/// the paper's construction per timed bound method, and the sound verdicts' run.
struct PaperTimes {
    name: String,
    boxes: usize,
    steps: usize,
    paper: (f64, f64),
    /// `(bounds, embedding s, radius s)` of the Minkowski method.
    minkowski: Vec<(BoundMethod, f64, f64)>,
    /// The sound run: its settings in words and its time.
    sound: (String, f64),
}

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
    let mut times = Vec::new();
    for (k, (file, net, paper)) in [
        ("integrator.toml", &args.network_1, (2.15, 0.02)),
        ("double-integrator.toml", &args.network_2, (2.7, 0.015)),
    ]
    .into_iter()
    .enumerate()
    {
        println!("══ Scenario {} ══", k + 1);
        let s = Scenario::load(&scenario_path(file))?;
        if let Some(t) = run_scenario(&s, net.as_ref(), &args.out, args.bounds, &args.timed, paper)?
        {
            times.push(t);
        }
        println!();
    }
    print_times(&times);
    println!(
        "\nFigures are in {}/ ({:.1} s in all).",
        args.out.display(),
        clock.elapsed().as_secs_f64()
    );
    Ok(())
}

/// `cbfreach` with no arguments: scenario 1 of the paper, figures into `out/`.
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
    let times = run_scenario(
        &s,
        None,
        &out,
        BoundMethod::ForwardBackward,
        &timed,
        (2.15, 0.02),
    )?;
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
/// of both methods, the initial boxes' verdicts and the times.
fn run_scenario(
    s: &Scenario,
    network: Option<&PathBuf>,
    out: &Path,
    bounds: BoundMethod,
    timed: &[BoundMethod],
    paper: (f64, f64),
) -> Result<Option<PaperTimes>, Box<dyn std::error::Error>> {
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

    let net_path = network_path(s, network)?;
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
    let local = ErrorMap::load_for(&net_path).is_ok();
    let problem = compile(
        s,
        &ProblemArgs {
            network: network.cloned(),
            local_margin: local,
            ..ProblemArgs::default()
        },
    )?;
    let margin = if local {
        "certified local M of the error map".to_string()
    } else {
        format!("M_C = {} (no error map: run `cbfreach error`)", problem.m_c)
    };
    let every = 10;
    let dist = reach_initial(s, &problem, bounds, ReachMethod::Disturbance, 1, true)?;
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
            every,
            title,
        },
        &path,
        size,
    )?;
    println!("Figure 2 (tubes, disturbance method): {}", path.display());
    let half: Vec<f64> = s.reach.goal.widths().iter().map(|w| 0.5 * w).collect();
    let traps = traps_from_equilibria(&found, &half);
    println!(
        "Sound verdicts of the {} initial boxes (disturbance method, {bounds} bounds on faces, {margin}):",
        s.reach.initial.len(),
    );
    print_verdicts(s, &traps, &dist.boxes);

    // The paper's construction (Theorem 2) with the scenario's M_C, timed per bound method.
    let paper_problem = compile(
        s,
        &ProblemArgs {
            network: network.cloned(),
            ..ProblemArgs::default()
        },
    )?;
    let mut minkowski = Vec::new();
    let mut figure3 = None;
    for &method in timed {
        let mink = reach_initial(s, &paper_problem, method, ReachMethod::Minkowski, 1, false)?;
        minkowski.push((method, mink.timing.reach_s, mink.timing.minkowski_s));
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
                "  note: {escapes} sampled filtered states lie outside the Minkowski sets (DESIGN §2.6: \
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
        sound: (format!("{bounds}, faces"), dist.timing.reach_s),
    }))
}

/// One line per initial box: its verdict and final set, then the tally.
fn print_verdicts(s: &Scenario, traps: &[Trap], tubes: &[Tube]) {
    let mut counts = std::collections::BTreeMap::<Verdict, usize>::new();
    for tube in tubes {
        let (v, _, note) = judge(s, traps, tube);
        *counts.entry(v).or_default() += 1;
        let set = tube.last().map(|l| l.set.clone());
        println!(
            "  {} … {}  {:<10} {}",
            fmt_point(&tube.initial.lower),
            fmt_point(&tube.initial.upper),
            v.name(),
            match (&set, note) {
                (_, Some(n)) => n,
                (Some(b), None) => format!(
                    "final set {} … {}",
                    fmt_point(&b.lower),
                    fmt_point(&b.upper)
                ),
                (None, None) => String::new(),
            }
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
    println!(
        "Filtered trajectories from the centres of the {} initial boxes (Euler, dt = {}, T = {}):",
        s.reach.initial.len(),
        s.reach.dt,
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
        "  {:<18} {:>5} {:>6}  {:<32} {:>10} {:>10} {:>12} {:>10}",
        "scenario", "boxes", "steps", "run", "embedding", "radius", "box-steps/s", "vs paper"
    );
    for t in times {
        let box_steps = (t.boxes * t.steps) as f64;
        println!(
            "  {:<18} {:>5} {:>6}  {:<32} {:>8.2} s {:>8.3} s {:>12} {:>10}",
            t.name, t.boxes, t.steps, "paper (Theorem 2)", t.paper.0, t.paper.1, "", ""
        );
        for &(method, emb, radius) in &t.minkowski {
            println!(
                "  {:<18} {:>5} {:>6}  {:<32} {:>8.3} s {:>8.4} s {:>12.0} {:>9.1}×",
                "",
                "",
                "",
                format!("Theorem 2, {method}"),
                emb,
                radius,
                box_steps / emb.max(1e-9),
                t.paper.0 / emb.max(1e-9)
            );
        }
        println!(
            "  {:<18} {:>5} {:>6}  {:<32} {:>8.3} s {:>10} {:>12.0} {:>10}",
            "",
            "",
            "",
            format!("sound ({})", t.sound.0),
            t.sound.1,
            "",
            box_steps / t.sound.1.max(1e-9),
            ""
        );
    }
    println!(
        "  (embedding: the NN-system tubes of every initial box; radius: the closeness radius r_t; \
         sound: the disturbance method's tubes behind the verdicts; × = the paper's embedding time \
         over ours)"
    );
}

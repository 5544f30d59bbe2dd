//! `cbfreach paper`: both experiments of the paper end to end — figures, the verdicts of the
//! scenarios' initial boxes, and the run times next to the paper's.

use std::path::{Path, PathBuf};
use std::time::Instant;

use cbfreach::bounds::BoundMethod;
use cbfreach::equilibria::{find_equilibria, Equilibrium, EquilibriumSearch};
use cbfreach::filter::SafetyFilter;
use cbfreach::plot::{self, Figure};
use cbfreach::reach::ReachMethod;
use cbfreach::scenario::Scenario;
use cbfreach::verify::{judge, traps_from_equilibria, Verdict};

use super::equilibria::print_table;
use super::plot::{box_trajectories, figure_points, reach_initial, trajectories, tubes_title};
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
    /// How the network is bounded over each box.
    #[arg(long, value_enum, default_value_t = BoundMethod::Crown)]
    pub bounds: BoundMethod,
}

/// The paper's times: the embedding for every initial box, and the closeness radius.
struct PaperTimes {
    name: String,
    boxes: usize,
    paper: (f64, f64),
    minkowski_embedding_s: f64,
    minkowski_radius_s: f64,
    disturbance_s: f64,
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
        if let Some(t) = run_scenario(&s, net.as_ref(), &args.out, args.bounds, paper)? {
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
    let times = run_scenario(&s, None, &out, BoundMethod::Crown, (2.15, 0.02))?;
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
    let problem = compile(
        s,
        &ProblemArgs {
            network: network.cloned(),
            ..ProblemArgs::default()
        },
    )?;
    let every = 10;
    let dist = reach_initial(s, &problem, bounds, ReachMethod::Disturbance, 1)?;
    let path = fig("tubes");
    plot::save(
        &Figure::Tubes {
            scenario: s,
            tubes: &dist.boxes,
            every,
            title: tubes_title(s, problem.m_c, every),
        },
        &path,
        size,
    )?;
    println!("Figure 2 (tubes, disturbance method): {}", path.display());
    let half: Vec<f64> = s.reach.goal.widths().iter().map(|w| 0.5 * w).collect();
    let traps = traps_from_equilibria(&found, &half);
    println!(
        "Verdicts of the {} initial boxes (disturbance method, {bounds} bounds, M_C = {}):",
        s.reach.initial.len(),
        problem.m_c
    );
    let mut counts = std::collections::BTreeMap::<Verdict, usize>::new();
    for tube in &dist.boxes {
        let (v, _, note) = judge(s, &traps, tube);
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

    let mink = reach_initial(s, &problem, bounds, ReachMethod::Minkowski, 1)?;
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
        "Figure 3 (with and without the closeness radius): {}",
        path.display()
    );
    let escapes = count_escapes(&mink.boxes, &lines, s.reach.initial.len(), 8);
    if escapes > 0 {
        println!(
            "  note: {escapes} sampled filtered states lie outside the Minkowski sets (DESIGN §2.6: \
             the paper's method is not sound in general)"
        );
    }
    Ok(Some(PaperTimes {
        name: s.name.clone(),
        boxes: s.reach.initial.len(),
        paper,
        minkowski_embedding_s: mink.timing.reach_s,
        minkowski_radius_s: mink.timing.minkowski_s,
        disturbance_s: dist.timing.reach_s,
    }))
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
    println!("Times (this machine, CPU backend) next to the paper's:");
    println!(
        "  {:<20} {:>6}  {:>28}  {:>26}  {:>16}",
        "scenario",
        "boxes",
        "embedding: paper / cbfreach",
        "radius r_t: paper / ours",
        "disturbance"
    );
    for t in times {
        println!(
            "  {:<20} {:>6}  {:>12.2} s / {:>8.3} s  {:>11.3} s / {:>8.4} s  {:>14.3} s",
            t.name,
            t.boxes,
            t.paper.0,
            t.minkowski_embedding_s,
            t.paper.1,
            t.minkowski_radius_s,
            t.disturbance_s
        );
    }
    println!(
        "  (embedding: the Minkowski method's NN-system tubes, all boxes, network bounds included; \
         radius: the closeness radius; disturbance: the sound default method's tubes)"
    );
}

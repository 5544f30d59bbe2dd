//! Verifies the paper's scenario 1 on a 4 × 3 grid over [−2, 2] × [−1.5, 1.5], as
//! `cbfreach verify scenarios/integrator.toml --region -2,-1.5:2,1.5 --grid 4,3` does, and
//! prints the share of each verdict. With a scenario (and a grid) as arguments, verifies that
//! scenario's region `C` instead.
//!
//! `cargo run --release --example verify [SCENARIO [CELLS,CELLS,…]]`

use cbfreach::verify::Verdict;
use cbfreach::{
    CpuBackend, IntervalBox, ProblemOptions, ReachProblem, Scenario, Verifier, VerifySettings,
};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let (file, region) = match args.next() {
        Some(f) => (std::path::PathBuf::from(f), None),
        None => (
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/integrator.toml"),
            Some(IntervalBox::new(vec![-2.0, -1.5], vec![2.0, 1.5])?),
        ),
    };
    let grid: Vec<usize> = match args.next() {
        Some(g) => g.split(',').map(str::parse).collect::<Result<_, _>>()?,
        None => vec![4, 3],
    };

    let scenario = Scenario::load(&file)?;
    let problem = ReachProblem::from_scenario(&scenario, &ProblemOptions::default())?;
    let verifier = Verifier::new(&scenario, &problem, &CpuBackend);
    let settings = VerifySettings {
        region,
        grid,
        ..scenario.settings.verify.clone()
    };
    let report = verifier.run(&settings, &|_stage, _done, _all| {})?;

    let shares = report.shares_after();
    println!("{} on a {:?} grid:", scenario.name, settings.grid);
    for v in Verdict::ALL {
        if let Some(n) = shares.count.get(&v) {
            println!(
                "  {:<14} {n:>4} boxes  {:>5.1}%",
                v.name(),
                100.0 * shares.share(v)
            );
        }
    }
    println!(
        "verified (converges ∪ trapped, the QP proven feasible on every set): {:.1}% of the safe \
         area ({:.1}% counting boxes where only the trajectories that exist are covered)",
        100.0 * shares.verified_feasible_share,
        100.0 * shares.verified_share
    );
    Ok(())
}

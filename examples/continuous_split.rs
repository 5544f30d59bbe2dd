//! Verifies a scenario with its own settings on both engines and prints, per cell, each
//! engine's verdict and end, the share verified, and how many continuous box-steps the GPU
//! engine took on the device and on the host (`GpuBackend::continuous_steps`, docs/design.md
//! §7.4): the by-hand comparison of docs/results.md.
//!
//! `cargo run --release --example continuous_split [SCENARIO [CELLS,CELLS]]` (default:
//! scenarios/integrator.toml on 8 × 6 cells; the GPU engine in f64 on the first adapter)

use std::sync::Arc;
use std::time::Instant;

use cbfreach::gpu::{GpuBackend, GpuContext, Precision};
use cbfreach::reach::Backend;
use cbfreach::{CpuBackend, ProblemOptions, ReachProblem, Scenario, Verifier, VerifySettings};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let mut args = std::env::args().skip(1);
    let file = args.next().map_or_else(
        || std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/integrator.toml"),
        std::path::PathBuf::from,
    );
    let grid: Vec<usize> = match args.next() {
        Some(g) => g.split(',').map(str::parse).collect::<Result<_, _>>()?,
        None => vec![8, 6],
    };
    let scenario = Scenario::load(&file)?;
    let problem = ReachProblem::from_scenario(&scenario, &ProblemOptions::default())?;
    let settings = VerifySettings {
        grid: grid.clone(),
        ..scenario.settings.verify.clone()
    };
    let gpu = GpuBackend::with_precision(Arc::new(GpuContext::new()?), Precision::F64)?;
    let engines: [(&str, &(dyn Backend + Sync)); 2] = [("cpu", &CpuBackend), ("gpu", &gpu)];
    let mut runs = Vec::new();
    for (name, backend) in engines {
        let clock = Instant::now();
        let report = Verifier::new(&scenario, &problem, backend).run(&settings, &|_, _, _| {})?;
        let s = clock.elapsed().as_secs_f64();
        let share = 100.0 * report.shares_after().verified_feasible_share;
        println!("{name}: {share:.1} % verified in {s:.1} s");
        runs.push(report.before);
    }
    let (on_device, on_host) = gpu.continuous_steps();
    println!(
        "GPU engine: {on_device} box-steps on the device, {on_host} on the host ({:.1} %)",
        100.0 * on_device as f64 / (on_device + on_host).max(1) as f64
    );
    let mut same = 0;
    for (k, (c, g)) in runs[0].iter().zip(&runs[1]).enumerate() {
        let agree = c.verdict == g.verdict && c.t_end == g.t_end;
        same += usize::from(agree);
        println!(
            "cell {k:>3}: cpu {:?} t_end {:?}, gpu {:?} t_end {:?}{}",
            c.verdict,
            c.t_end,
            g.verdict,
            g.t_end,
            if agree { "" } else { "  <- differs" }
        );
    }
    println!(
        "{same} of {} cells with the same verdict and end",
        runs[0].len()
    );
    Ok(())
}

//! `cbfreach bench`: box-steps per second of the reach engines, side by side in one process,
//! with the GFLOP/s they reach by docs/design.md §5's model and by the products run, and the
//! fraction of the CPU's f64 limit (per wall-second, and per CPU-second on a shared machine).

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Instant;

use cbfreach::bounds::{model_multiply_adds, BoundMethod};
use cbfreach::machine::{f64_limit_gflops, f64_limit_isa, process_cpu_seconds};
use cbfreach::network::Mlp;
use cbfreach::reach::{Backend, CpuBackend, ExactField, ReachProblem, ReachSettings};
use cbfreach::scenario::Scenario;
use cbfreach::simulate::spread_boxes;

use super::args::GpuArgs;
use super::{load_scenario, CliResult};

/// The largest batch `bench` runs: its boxes, tubes and the engines' buffers stay a few GB.
const MAX_BOXES: usize = 1 << 20;

/// Arguments of `cbfreach bench`.
#[derive(clap::Args)]
pub struct BenchArgs {
    /// Engines to run: `cpu`, `gpu`, or both (comma-separated).
    #[arg(long, value_delimiter = ',', default_value = "cpu,gpu")]
    pub backend: Vec<String>,
    /// Batch sizes (boxes), each 1 to 1,048,576 (a batch's boxes and sets are held in memory).
    #[arg(
        long,
        value_delimiter = ',',
        default_value = "1,16,256,4096",
        value_parser = |s: &str| super::whole_in(s, 1, MAX_BOXES)
    )]
    pub boxes: Vec<usize>,
    /// Euler steps per run.
    #[arg(long, default_value_t = 10, value_parser = |s: &str| super::whole_at_least(s, 1))]
    pub steps: usize,
    /// Bound methods (comma-separated).
    #[arg(
        long,
        value_enum,
        value_delimiter = ',',
        default_value = "forward,forward-backward"
    )]
    pub bounds: Vec<BoundMethod>,
    /// Scenario (default: the built-in scenario 1).
    #[arg(long)]
    pub scenario: Option<PathBuf>,
    /// Network (default: a seeded random network of the scenario's architecture, its last
    /// layer scaled by 0.05 so that tubes stay in C).
    #[arg(long)]
    pub network: Option<PathBuf>,
    /// Peak rate in GFLOP/s to compare with (default: the CPU's f64 limit, measured with
    /// fused multiply–adds on every thread, `cbfreach::machine::f64_limit_gflops`; none for
    /// the GPU).
    #[arg(long)]
    pub peak: Option<f64>,
    /// Print where a GPU step's time goes: every kind of dispatch timed on its own (stderr);
    /// the rates then include compiling the pipelines (no untimed first run).
    #[arg(long)]
    pub profile: bool,
    /// The GPU engine's GEMM kernel (default: `flat` on software adapters, `tiles` on real
    /// GPUs; all three give the same sets), to compare them on one device.
    #[arg(long, value_enum)]
    pub gemm: Option<cbfreach::gpu::kernels::Gemm>,
    /// GPU adapter and number type (f64 where the adapter has it; `--f32`, `--f64`).
    #[command(flatten)]
    pub gpu: GpuArgs,
}

/// Runs the command.
pub fn run(args: &BenchArgs) -> CliResult {
    let s = match &args.scenario {
        Some(p) => load_scenario(p)?,
        None => Scenario::builtin()?,
    };
    let net = match (&args.network, &s.network) {
        (Some(p), _) => Mlp::load_safetensors(p)?,
        (None, Some(cfg)) => {
            let mut net = Mlp::random(&cfg.architecture, 7);
            if let Some(last) = net.layers.last_mut() {
                last.weight.iter_mut().for_each(|w| *w *= 0.05);
                last.bias.iter_mut().for_each(|b| *b *= 0.05);
            }
            net
        }
        (None, None) => return Err("the scenario has no [network]: give --network".into()),
    };
    let widths = net.widths();
    // The Euler map: the one time model both engines run, so that their rates compare.
    let mut problem =
        ReachProblem::new(&s, net, 0.0)?.with_time(cbfreach::reach::TimeModel::Euler, 1);
    problem.steps = args.steps.max(1);
    let cpu_peak = args.peak.unwrap_or_else(f64_limit_gflops);
    let threads = rayon::current_num_threads().max(1);
    println!(
        "cbfreach bench: `{}`, network {}, {} steps, CPU peak {cpu_peak:.1} GFLOP/s ({})",
        s.name,
        widths
            .iter()
            .map(|w| w.to_string())
            .collect::<Vec<_>>()
            .join("×"),
        problem.steps,
        match args.peak {
            Some(_) => "given".to_string(),
            None => format!(
                "measured: f64 fused multiply-adds ({}) on every thread, the best of 60 short rounds",
                f64_limit_isa()
            ),
        }
    );

    let mut engines: Vec<(String, Box<dyn Backend + Sync>, Option<f64>)> = Vec::new();
    for name in &args.backend {
        match name.as_str() {
            "cpu" => engines.push(("cpu".into(), Box::new(CpuBackend), Some(cpu_peak))),
            "gpu" => match cbfreach::gpu::GpuContext::with_adapter(args.gpu.adapter.as_deref()) {
                Ok(ctx) => {
                    let precision = args.gpu.options().precision_for(&ctx);
                    // The adapter's name without its parenthesised details (lavapipe's
                    // "llvmpipe (LLVM 15.0.7, 256 bits)"), to fit the column.
                    let short = ctx.info.name.split(" (").next().unwrap_or_default();
                    let name: String = short.chars().take(20).collect();
                    let label = format!("gpu ({name}, {})", precision.name());
                    let mut backend =
                        cbfreach::gpu::GpuBackend::with_precision(Arc::new(ctx), precision)?;
                    backend.profile = args.profile;
                    if let Some(g) = args.gemm {
                        backend.gemm = g;
                    }
                    engines.push((label, Box::new(backend), args.peak));
                }
                Err(e) => println!("notice: no GPU engine: {e}"),
            },
            other => return Err(format!("--backend {other}: expected cpu or gpu").into()),
        }
    }
    println!(
        "  {:<34} {:<28} {:>7} {:>14} {:>10} {:>8} {:>10} {:>8} {:>8} {:>8}",
        "engine",
        "bounds",
        "boxes",
        "box-steps/s",
        "GFLOP/s",
        "of peak",
        "run GF/s",
        "of peak",
        "per CPU",
        "× first"
    );
    // The boxes of each size (the same for every engine and bounds), and one for the warm-up.
    let sizes: Vec<(usize, Vec<_>)> = args
        .boxes
        .iter()
        .map(|&count| (count, spread_boxes(&s, count)))
        .collect();
    let one = spread_boxes(&s, 1);
    // Each run's rate, for the ratio of a later engine's to the first engine's.
    let mut first_rates: Vec<((BoundMethod, usize), f64)> = Vec::new();
    for (e, (label, engine, peak)) in engines.iter().enumerate() {
        for &method in &args.bounds {
            let settings = ReachSettings {
                bounds: method,
                exact: ExactField::Nowhere,
                intersect_x: false,
                ..ReachSettings::default()
            };
            if label.starts_with("gpu") && !cbfreach::gpu::GpuBackend::supports(&settings) {
                println!(
                    "  {label:<34} {:<28} (not on the GPU yet)",
                    method.to_string()
                );
                continue;
            }
            // Pipelines are compiled once a process and problem (and kept on disk): an
            // untimed run of one box first, so that the rates are of the engine, not of its
            // compiler (the step count is part of the problem's WGSL: the same problem).
            // Not with --profile, whose report is of the first run.
            if !args.profile {
                engine.reach(&problem, &one, &settings, &|_, _| {})?;
            }
            for (count, boxes) in &sizes {
                let count = *count;
                let (start, counted) = (Instant::now(), cbfreach::matmul::multiply_adds());
                let cpu_start = process_cpu_seconds();
                let result = engine.reach(&problem, boxes, &settings, &|_, _| {})?;
                let seconds = start.elapsed().as_secs_f64();
                let cpu_seconds = process_cpu_seconds().zip(cpu_start).map(|(b, a)| b - a);
                let done = (cbfreach::matmul::multiply_adds() - counted) as f64;
                // Count the box-steps actually run (a tube that leaves C stops).
                let box_steps: f64 = result
                    .boxes
                    .iter()
                    .map(|t| t.steps_run(problem.dt) as f64)
                    .sum();
                let rate = box_steps / seconds;
                let gflops = 2.0 * model_multiply_adds(&widths, method) * rate / 1e9;
                let share = peak.map_or("-".to_string(), |p| format!("{:.0}%", 100.0 * gflops / p));
                // The products the CPU engine ran (it skips rows that are zero: fewer than the
                // model's where neurons are stable), as GFLOP/s and share of the peak.
                // Per CPU-second: the products run over the CPU time the process used, against
                // one thread's share of the peak (other work on the machine takes wall time,
                // not CPU time).
                let (run_gflops, run_share, cpu_share) = match (label.as_str(), peak) {
                    ("cpu", Some(p)) => {
                        let g = 2.0 * done / seconds / 1e9;
                        let per_cpu = cpu_seconds.filter(|&c| c > 0.0).map_or("-".into(), |c| {
                            format!(
                                "{:.0}%",
                                100.0 * 2.0 * done / c / 1e9 / (p / threads as f64)
                            )
                        });
                        (format!("{g:.1}"), format!("{:.0}%", 100.0 * g / p), per_cpu)
                    }
                    _ => ("-".to_string(), "-".to_string(), "-".to_string()),
                };
                let key = (method, count);
                let versus = match first_rates.iter().find(|(k, _)| *k == key) {
                    Some(&(_, first)) if e > 0 => format!("{:.2}", rate / first),
                    _ => "-".to_string(),
                };
                if e == 0 {
                    first_rates.push((key, rate));
                }
                println!(
                    "  {label:<34} {:<28} {:>7} {:>14.0} {:>10.1} {:>8} {:>10} {:>8} {:>8} {:>8}",
                    method.to_string(),
                    boxes.len(),
                    rate,
                    gflops,
                    share,
                    run_gflops,
                    run_share,
                    cpu_share,
                    versus
                );
            }
        }
    }
    println!("  (GFLOP/s by docs/design.md §5's model of the network bounds only, every neuron's dense work: the rate a dense implementation would need, so its share passes 100 % where most neurons are stable; run GF/s: the products the CPU engine ran, counted (it skips neurons inactive over every box), the hardware's share; per CPU: the same per CPU-second of the process against one thread's share of the peak; × first: the rate over the first engine's at the same bounds and boxes; every engine and bounds ran one box untimed first (not with --profile), so GPU times include upload and readback, not compilation)");
    Ok(())
}

//! The `cbfreach` command line: parses arguments, calls the library, prints.

mod cli;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// Sound, batched interval reachability for systems with CBF safety filters.
///
/// With no command, reproduces the paper's scenario 1 and verifies its boxes in continuous time
/// (figures into out/).
#[derive(Parser)]
#[command(name = "cbfreach", version, about, long_about = None)]
struct Cli {
    #[command(subcommand)]
    command: Option<Command>,
}

#[derive(Subcommand)]
enum Command {
    /// Validate a scenario file and summarise it.
    Check {
        /// The scenario file (TOML).
        scenario: PathBuf,
    },
    /// Simulate the filtered system from points or from random samples of a box.
    Simulate(cli::simulate::SimulateArgs),
    /// Evaluate the filter v on the training grid (with its Jacobian).
    Dataset(cli::train::DatasetArgs),
    /// Train the surrogate ReLU network N ≈ v and save it as safetensors.
    Train(cli::train::TrainArgs),
    /// Measured and certified error of the network against the filter (M_C), slope error,
    /// bound looseness; writes the error map beside the network.
    Error(cli::error::ErrorArgs),
    /// Reachable sets of the filtered system from the scenario's initial boxes.
    Reach(cli::reach::ReachArgs),
    /// A verdict per box of a partitioned region (converges, trapped, unknown, invalid, …),
    /// with adaptive refinement and shards.
    Verify(cli::verify::VerifyArgs),
    /// Merge the JSON files of `verify --shard K/N` runs into one verdict map.
    Merge(cli::verify::MergeArgs),
    /// Draw a figure: trajectories, tubes, minkowski, or a verdict map.
    Plot(cli::plot::PlotArgs),
    /// Reproduce both experiments of the paper: figures, verdicts, times.
    Paper(cli::paper::PaperArgs),
    /// Sound affine and interval bounds of a network over a box.
    Bounds(cli::bounds::BoundsArgs),
    /// Box-steps per second of the reach engines (CPU and GPU side by side), GFLOP/s by the
    /// FLOP model and the fraction of a peak rate.
    Bench(cli::bench::BenchArgs),
    /// Find, classify and list the equilibria of the filtered system inside C.
    Equilibria {
        /// The scenario file (TOML).
        scenario: PathBuf,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
    },
}

/// Without a desktop session (no `XDG_RUNTIME_DIR`), Mesa's Vulkan device-selection layer
/// asks libwayland for a display to pick the default GPU, and libwayland prints
/// `error: XDG_RUNTIME_DIR is invalid or not set` once per driver. There is no display to ask,
/// so the layer is turned off through its own switch (`NODEVICE_SELECT`); it only orders
/// adapters, and cbfreach picks its adapter itself. Called first, before any thread exists.
fn quiet_vulkan_device_select() {
    let session = std::env::var_os("XDG_RUNTIME_DIR")
        .is_some_and(|d| !d.is_empty() && std::path::Path::new(&d).is_dir());
    if !session && std::env::var_os("NODEVICE_SELECT").is_none() {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}

fn main() -> ExitCode {
    quiet_vulkan_device_select();
    let matches = Cli::command().get_matches();
    let args = Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit());
    cli::set_matches(matches);
    let result = match args.command {
        None => cli::paper::run_default(),
        Some(Command::Check { scenario }) => cli::check::run(&scenario),
        Some(Command::Simulate(a)) => cli::simulate::run(&a),
        Some(Command::Reach(a)) => cli::reach::run(&a),
        Some(Command::Bench(a)) => cli::bench::run(&a),
        Some(Command::Verify(a)) => cli::verify::run(&a),
        Some(Command::Merge(a)) => cli::verify::run_merge(&a),
        Some(Command::Plot(a)) => cli::plot::run(&a),
        Some(Command::Paper(a)) => cli::paper::run(&a),
        Some(Command::Bounds(a)) => cli::bounds::run(&a),
        Some(Command::Dataset(a)) => cli::train::run_dataset(&a),
        Some(Command::Train(a)) => cli::train::run_train(&a),
        Some(Command::Error(a)) => cli::error::run(&a),
        Some(Command::Equilibria { scenario, json }) => cli::equilibria::run(&scenario, json),
    };
    // Standard output may have failed (closed or full) after the work was done.
    let printed = cli::finish_stdout().map_err(Into::into);
    // A reader that closed the pipe (`| head`) has what it wanted: end quietly, with the
    // status of a process the pipe's signal ended (128 + SIGPIPE), as `cat` would. Any other
    // failure is reported.
    let broken_pipe = |e: &(dyn std::error::Error + 'static)| {
        e.downcast_ref::<std::io::Error>()
            .is_some_and(cli::is_broken_pipe)
    };
    match (result, printed) {
        (Ok(()), Ok(())) => ExitCode::SUCCESS,
        (Err(e), _) if broken_pipe(e.as_ref()) => ExitCode::from(141),
        (Ok(()), Err(_)) if cli::stdout_closed() => ExitCode::from(141),
        (Err(e), _) | (Ok(()), Err(e)) => {
            eprintln!("error: {e}");
            ExitCode::from(2)
        }
    }
}

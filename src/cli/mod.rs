//! One file per subcommand; each turns arguments into library calls and prints the result.

// `println!` and `print!` in every subcommand: standard output through [`out`], which does not
// panic when it is closed (`| head`) or full; `main` reports the failure after the command
// (whose result files are written by then) with a non-zero exit.
macro_rules! println {
    () => {
        $crate::cli::out(format_args!("\n"))
    };
    ($($arg:tt)*) => {
        $crate::cli::out(format_args!("{}\n", format_args!($($arg)*)))
    };
}
#[allow(unused_macros)]
macro_rules! print {
    ($($arg:tt)*) => {
        $crate::cli::out(format_args!($($arg)*))
    };
}

pub mod args;
pub mod bench;
pub mod bounds;
pub mod check;
pub mod equilibria;
pub mod error;
pub mod paper;
pub mod plot;
pub mod reach;
pub mod report;
pub mod resume;
pub mod simulate;
pub mod train;
pub mod verify;

use std::path::Path;
use std::sync::OnceLock;

use cbfreach::scenario::Scenario;

/// The first error writing standard output, if any; later writes are skipped.
static STDOUT_FAILED: OnceLock<std::io::Error> = OnceLock::new();

/// Writes to standard output; on an error (a closed pipe, a full disk) records it and skips
/// every later write instead of panicking as `std::println!` does.
pub fn out(args: std::fmt::Arguments) {
    use std::io::Write;
    if STDOUT_FAILED.get().is_some() {
        return;
    }
    if let Err(e) = std::io::stdout().lock().write_fmt(args) {
        let _ = STDOUT_FAILED.set(e);
    }
}

/// Flushes standard output: the error of [`out`] or of the flush, if any.
pub fn finish_stdout() -> Result<(), String> {
    use std::io::Write;
    if let Err(e) = std::io::stdout().lock().flush() {
        let _ = STDOUT_FAILED.set(e);
    }
    match STDOUT_FAILED.get() {
        Some(e) => Err(format!(
            "writing standard output: {e} (the output is incomplete; result files were written)"
        )),
        None => Ok(()),
    }
}

/// Whether standard output was closed by its reader (`| head`): the end of the output the
/// reader wanted, not an error to report.
pub fn stdout_closed() -> bool {
    STDOUT_FAILED.get().is_some_and(is_broken_pipe)
}

/// Whether `e` is a write to a pipe whose reader is gone.
pub fn is_broken_pipe(e: &std::io::Error) -> bool {
    e.kind() == std::io::ErrorKind::BrokenPipe
}

/// The parsed command line, for [`given`].
static MATCHES: OnceLock<clap::ArgMatches> = OnceLock::new();

/// Keeps the parsed command line, so that options can tell a value given from a default.
pub fn set_matches(matches: clap::ArgMatches) {
    let _ = MATCHES.set(matches);
}

/// Whether the running subcommand's option `id` (its field name) was given on the command
/// line, rather than taken from its default: given options override a scenario's
/// `[settings]`.
pub fn given(id: &str) -> bool {
    let Some((_, sub)) = MATCHES.get().and_then(|m| m.subcommand()) else {
        return false;
    };
    matches!(
        sub.try_get_raw(id)
            .ok()
            .flatten()
            .and_then(|_| sub.value_source(id)),
        Some(clap::parser::ValueSource::CommandLine)
    )
}

/// For summaries: the sets are the meet of a box in x and the parallelotope.
pub const INTERSECT_X_CLAUSE: &str = ", sets met with their x-boxes";

/// For summaries: `ReachSettings::meet_slabs` where it applies, and the turned frames.
pub fn meet_slabs_clause(applies: bool, turned_frames: usize) -> String {
    match (applies, turned_frames) {
        (false, _) => String::new(),
        (true, 0 | 1) => ", slabs clipped by the other frame's sets".into(),
        (true, k) => format!(
            ", z in {k} frames turned by multiples of π/{}, slabs clipped by the other frames' sets",
            2 * k
        ),
    }
}

/// The clause of `ReachSettings::taylor3` and `lattice` in a run's summary line.
pub fn sharper_clause(taylor3: bool, lattice: bool) -> &'static str {
    match (taylor3, lattice) {
        (false, false) => "",
        (true, false) => ", pieces' Taylor forms to second order",
        (false, true) => ", the pieces' lattice across switching surfaces",
        (true, true) => {
            ", pieces' Taylor forms to second order and their lattice across switching surfaces"
        }
    }
}

/// [`sharper_clause`] of a run of `problem` under `settings`: the parts that apply to it.
pub fn sharper_clause_of(
    problem: &cbfreach::reach::ReachProblem,
    settings: &cbfreach::reach::ReachSettings,
) -> &'static str {
    sharper_clause(
        settings.taylor3 && problem.time == cbfreach::reach::TimeModel::Continuous,
        problem.lattice_applies(settings),
    )
}

/// What a subcommand returns: any library or I/O error, printed by `main`.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Loads a scenario file.
pub fn load_scenario(path: &Path) -> Result<Scenario, Box<dyn std::error::Error>> {
    Ok(Scenario::load(path)?)
}

/// Checks, before any work, that each output file given can be written (its folder exists and
/// takes a new file), so that a long run is not lost at the end.
pub fn check_outputs(paths: &[Option<&Path>]) -> CliResult {
    for p in paths.iter().flatten() {
        cbfreach::output::check_writable(p).map_err(|e| format!("{}: {e}", p.display()))?;
    }
    Ok(())
}

/// A progress bar on standard error (hidden when it is not a terminal).
pub fn progress_bar(len: u64, what: &str) -> indicatif::ProgressBar {
    let bar = indicatif::ProgressBar::new(len);
    bar.set_style(
        indicatif::ProgressStyle::with_template("{spinner} {msg} [{bar:40}] {pos}/{len} {elapsed}")
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar.set_message(what.to_string());
    bar
}

/// Parses `a,b,c` into numbers, naming the option on error.
pub fn parse_point(option: &str, text: &str) -> Result<Vec<f64>, String> {
    text.split(',')
        .map(|s| {
            s.trim().parse::<f64>().map_err(|_| {
                format!("{option}: `{s}` is not a number (expected comma-separated numbers, e.g. 1.5,-2)")
            })
        })
        .collect()
}

/// `, sets within S's half-spaces (velocity)` for the CBFs whose half-spaces bounded the sets
/// (`reach::safe_set`), empty for none.
pub fn safe_set_clause<S: AsRef<str>>(names: &[S]) -> String {
    if names.is_empty() {
        return String::new();
    }
    let names: Vec<&str> = names.iter().map(AsRef::as_ref).collect();
    format!(", sets within S's half-spaces ({})", names.join(", "))
}

/// Parses a whole number of at least `min` (a step stride, a refinement factor) for clap.
pub fn whole_at_least(text: &str, min: usize) -> Result<usize, String> {
    text.parse::<usize>()
        .ok()
        .filter(|&k| k >= min)
        .ok_or_else(|| format!("expected a whole number ≥ {min}"))
}

/// Parses a whole number in `min..=max` (a batch size) for clap.
pub fn whole_in(text: &str, min: usize, max: usize) -> Result<usize, String> {
    text.parse::<usize>()
        .ok()
        .filter(|k| (min..=max).contains(k))
        .ok_or_else(|| format!("expected a whole number from {min} to {max}"))
}

/// Parses a finite number of at least `min` (above it where `strict`) for clap.
pub fn number_at_least(text: &str, min: f64, strict: bool) -> Result<f64, String> {
    text.parse::<f64>()
        .ok()
        .filter(|&v| v.is_finite() && if strict { v > min } else { v >= min })
        .ok_or_else(|| match strict {
            true => format!("expected a finite number > {min}"),
            false => format!("expected a finite number ≥ {min}"),
        })
}

pub use cbfreach::boxes::fmt_point;

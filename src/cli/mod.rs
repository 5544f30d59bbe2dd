//! One file per subcommand; each turns arguments into library calls and prints the result.

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
pub mod simulate;
pub mod train;
pub mod verify;

use std::path::Path;
use std::sync::OnceLock;

use cbfreach::scenario::Scenario;

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

/// What a subcommand returns: any library or I/O error, printed by `main`.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Loads a scenario file.
pub fn load_scenario(path: &Path) -> Result<Scenario, Box<dyn std::error::Error>> {
    Ok(Scenario::load(path)?)
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

/// Formats a vector compactly: `(1.000, -2.500)`.
pub fn fmt_point(x: &[f64]) -> String {
    // Values that print as zero print without a sign.
    let parts: Vec<String> = x
        .iter()
        .map(|&v| format!("{:.4}", if v.abs() < 5e-5 { 0.0 } else { v }))
        .collect();
    format!("({})", parts.join(", "))
}

//! One file per subcommand; each turns arguments into library calls and prints the result.

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

use cbfreach::scenario::Scenario;

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

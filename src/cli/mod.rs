//! One file per subcommand; each turns arguments into library calls and prints the result.

pub mod check;
pub mod equilibria;
pub mod report;
pub mod simulate;

use std::path::Path;

use cbfreach::scenario::Scenario;

/// What a subcommand returns: any library or I/O error, printed by `main`.
pub type CliResult = Result<(), Box<dyn std::error::Error>>;

/// Loads a scenario file.
pub fn load_scenario(path: &Path) -> Result<Scenario, Box<dyn std::error::Error>> {
    Ok(Scenario::load(path)?)
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

/// Formats a vector compactly: `(1.000, -2.500)`.
pub fn fmt_point(x: &[f64]) -> String {
    let parts: Vec<String> = x.iter().map(|v| format!("{v:.4}")).collect();
    format!("({})", parts.join(", "))
}

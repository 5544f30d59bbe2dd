//! `cbfreach` with no arguments: the main job on the built-in scenario.
//!
//! For now: equilibria of the filtered system and simulated trajectories from the centres of
//! the scenario's initial boxes, with where each one ends.

use cbfreach::equilibria::{find_equilibria, EquilibriumSearch};
use cbfreach::filter::SafetyFilter;
use cbfreach::scenario::Scenario;
use cbfreach::simulate::{simulate_filtered, Integrator};

use super::{equilibria::print_table, fmt_point, CliResult};

/// Runs the default job.
pub fn run_default() -> CliResult {
    let s = Scenario::builtin()?;
    println!("cbfreach — built-in scenario `{}` ({})", s.name, s.file);
    println!("  {}\n", s.description.replace('\n', "\n  "));
    let filter = SafetyFilter::new(&s);
    let found = find_equilibria(&filter, &s.reach.region, &EquilibriumSearch::default());
    println!("Equilibria of the filtered system in C ({}):", found.len());
    print_table(&found);

    println!(
        "\nFiltered trajectories from the centres of the {} initial boxes (Euler, dt = {}, T = {}):",
        s.reach.initial.len(),
        s.reach.dt,
        s.reach.horizon
    );
    for b in &s.reach.initial {
        let x0 = b.center();
        let t = simulate_filtered(&filter, &x0, s.reach.dt, s.reach.steps(), Integrator::Euler);
        let end = t.last();
        let nearest = found
            .iter()
            .filter(|e| e.kind == cbfreach::equilibria::Stability::Stable)
            .min_by(|a, b| dist(&a.x, end).total_cmp(&dist(&b.x, end)));
        let label = match nearest {
            Some(e) if dist(&e.x, end) < 0.05 => {
                if e.undesirable {
                    format!("trapped at {}", fmt_point(&e.x))
                } else {
                    "reaches the origin".to_string()
                }
            }
            _ => "still moving".to_string(),
        };
        println!("  {} → {}   {label}", fmt_point(&x0), fmt_point(end));
    }
    println!("\nNext: `cbfreach simulate`, `cbfreach equilibria`, `cbfreach check` (see --help).");
    Ok(())
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter().zip(b).map(|(p, q)| (p - q).powi(2)).sum::<f64>().sqrt()
}

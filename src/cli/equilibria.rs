//! `cbfreach equilibria <scenario> [--json]`.

use std::path::Path;

use cbfreach::equilibria::{
    find_equilibria, group_equilibria, Equilibrium, EquilibriumSearch, EquilibriumSet,
};
use cbfreach::filter::SafetyFilter;
use cbfreach::verify::{equilibrium_search_for, MAX_EQUILIBRIUM_STARTS};

use super::{fmt_point, load_scenario, CliResult};

/// Runs the command.
pub fn run(path: &Path, json: bool) -> CliResult {
    let s = load_scenario(path)?;
    let search = equilibrium_search_for(s.n()).ok_or_else(|| {
        format!(
            "{}: {} states: the dense search would start from more than {MAX_EQUILIBRIUM_STARTS} points even at 2 per axis",
            s.file,
            s.n()
        )
    })?;
    if search.starts_per_axis < EquilibriumSearch::default().starts_per_axis {
        eprintln!(
            "note: {} states: {} starts per axis (at most {MAX_EQUILIBRIUM_STARTS} starts)",
            s.n(),
            search.starts_per_axis
        );
    }
    let clock = std::time::Instant::now();
    let found = find_equilibria(&SafetyFilter::new(&s), &s.reach.region, &search);
    let seconds = clock.elapsed().as_secs_f64();
    let sets = group_equilibria(found, &s.reach.region, &search);
    if json {
        println!("{}", serde_json::to_string_pretty(&sets)?);
        return Ok(());
    }
    let points: Vec<Equilibrium> = sets
        .iter()
        .filter_map(|e| match e {
            EquilibriumSet::Point(p) => Some(p.clone()),
            EquilibriumSet::Continuum(_) => None,
        })
        .collect();
    let continua = sets.len() - points.len();
    println!(
        "{} isolated equilibria{} of the filtered system in C (search: {seconds:.2} s):",
        points.len(),
        match continua {
            0 => String::new(),
            k => format!(" and {k} continua"),
        }
    );
    print_table(&points);
    for e in &sets {
        if let EquilibriumSet::Continuum(c) = e {
            println!(
                "  continuum of {} equilibria over {} .. {}: {} found on it, e.g. {}",
                if c.undesirable {
                    "undesirable"
                } else {
                    "desired"
                },
                fmt_point(&c.lower),
                fmt_point(&c.upper),
                c.samples,
                fmt_point(&c.example)
            );
        }
    }
    Ok(())
}

/// A readable table of equilibria.
pub fn print_table(found: &[Equilibrium]) {
    println!("  {:<24} {:<15} {:<11} eigenvalues", "x*", "kind", "");
    for e in found {
        let eig: Vec<String> = e
            .eigenvalues
            .iter()
            .map(|z| {
                if z[1].abs() > 1e-9 {
                    format!("{:.4}{:+.4}i", z[0], z[1])
                } else {
                    format!("{:.4}", z[0])
                }
            })
            .collect();
        println!(
            "  {:<24} {:<15} {:<11} {}",
            fmt_point(&e.x),
            e.kind.to_string(),
            if e.undesirable {
                "undesirable"
            } else {
                "desired"
            },
            eig.join(", ")
        );
    }
}

//! The endpoint summary that `cbfreach` with no arguments and `cbfreach paper` print: where
//! the filtered trajectories from the centres of a scenario's initial boxes end.

use cbfreach::equilibria::{Equilibrium, Stability};
use cbfreach::filter::SafetyFilter;
use cbfreach::scenario::Scenario;
use cbfreach::verify::simulate_model;

use super::fmt_point;

/// One line per initial box: its centre, where its filtered trajectory ends, and which stable
/// equilibrium (if any) that is.
pub fn print_endpoints(s: &Scenario, found: &[Equilibrium]) {
    let filter = SafetyFilter::new(s);
    for b in &s.reach.initial {
        let x0 = b.center();
        let t = simulate_model(&filter, &x0, s.reach.time, 1).0;
        let end = t.last();
        let nearest = found
            .iter()
            .filter(|e| e.kind == Stability::Stable)
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
}

fn dist(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).powi(2))
        .sum::<f64>()
        .sqrt()
}

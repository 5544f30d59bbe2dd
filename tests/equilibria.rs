//! Equilibria of the paper's filtered systems.

mod common;

use cbfreach::equilibria::{
    find_equilibria, group_equilibria, EquilibriumSearch, EquilibriumSet, Stability,
};
use cbfreach::filter::SafetyFilter;
use common::{double_integrator, from_text, integrator};

const EIG_TOL: f64 = 1e-4;

#[test]
fn scenario_1_has_exactly_the_papers_equilibria() {
    let s = integrator();
    let found = find_equilibria(
        &SafetyFilter::new(&s),
        &s.reach.region,
        &EquilibriumSearch::default(),
    );
    let r3 = 3f64.sqrt() / 2.0;
    let expected: [([f64; 2], Stability, [f64; 2], bool); 4] = [
        ([0.0, 0.0], Stability::Stable, [-5.0, -1.0], false),
        ([2.5, -r3], Stability::Saddle, [-1.0, 3.0], true),
        ([2.5, r3], Stability::Saddle, [-1.0, 3.0], true),
        ([3.0, 0.0], Stability::Stable, [-2.0, -1.0], true),
    ];
    assert_eq!(found.len(), 4, "found {found:#?}");
    for (e, (x, kind, eig, undesirable)) in found.iter().zip(expected) {
        assert!(
            (e.x[0] - x[0]).abs() < 1e-6 && (e.x[1] - x[1]).abs() < 1e-6,
            "{e:?}"
        );
        assert_eq!(e.kind, kind, "{e:?}");
        assert_eq!(e.undesirable, undesirable, "{e:?}");
        for (z, want) in e.eigenvalues.iter().zip(eig) {
            assert!(
                (z[0] - want).abs() < EIG_TOL && z[1].abs() < EIG_TOL,
                "{e:?}"
            );
        }
    }
}

#[test]
fn scenario_2_origin_is_stable_and_every_equilibrium_is_a_zero() {
    let s = double_integrator();
    let f = SafetyFilter::new(&s);
    let found = find_equilibria(&f, &s.reach.region, &EquilibriumSearch::default());
    let origin = found
        .iter()
        .find(|e| e.x.iter().all(|v| v.abs() < 1e-8))
        .expect("the origin");
    assert_eq!(origin.kind, Stability::Stable);
    assert!(!origin.undesirable);
    for e in &found {
        let r = f.closed_loop(&e.x).unwrap();
        assert!(
            r.iter().all(|v| v.abs() < 1e-8),
            "{e:?} is not an equilibrium"
        );
        assert!(s.reach.region.contains(&e.x));
    }
}

/// The unicycle steered by its look-ahead point `p + l(cos θ, sin θ)` rests wherever that
/// point is at the origin: the circle `p = −l(cos θ, sin θ)`, one equilibrium per heading. The
/// search reports it as one continuum spanning the headings, not as hundreds of points; the
/// paper's isolated equilibria stay points (scenario 1: four points, no continuum).
#[test]
fn a_curve_of_equilibria_is_one_continuum() {
    let s = from_text(
        r#"
name = "unicycle"
[parameters]
l = 0.3
[system]
states = ["px", "py", "theta"]
inputs = ["v", "w"]
f = ["0", "0", "0"]
g = [["cos(theta)", "0"], ["sin(theta)", "0"], ["0", "1"]]
kappa = [
  "-(cos(theta)*(px + l*cos(theta)) + sin(theta)*(py + l*sin(theta)))",
  "-(-sin(theta)*(px + l*cos(theta)) + cos(theta)*(py + l*sin(theta)))/l",
]
[[cbf]]
name = "obstacle"
h = "(px + l*cos(theta) + 1.5)^2 + (py + l*sin(theta) - 0.2)^2 - 0.25"
[reach]
region = { lower = [-3.5, -1.5, -3.0], upper = [0.5, 1.5, 3.0] }
m_c = 0.1
dt = 0.02
horizon = 1.0
goal = { lower = [-0.5, -0.5, -3.0], upper = [0.5, 0.5, 3.0] }
initial = [ { lower = [-3.1, 0.1, -0.1], upper = [-2.9, 0.3, 0.1] } ]
"#,
    )
    .unwrap();
    let f = SafetyFilter::new(&s);
    let search = EquilibriumSearch::default();
    let found = find_equilibria(&f, &s.reach.region, &search);
    let total = found.len();
    let sets = group_equilibria(found, &s.reach.region, &search);
    let continua: Vec<_> = sets
        .iter()
        .filter_map(|e| match e {
            EquilibriumSet::Continuum(c) => Some(c),
            EquilibriumSet::Point(_) => None,
        })
        .collect();
    // The goal's circle (filter-created curves on the obstacle may be found beside it).
    assert!((1..=4).contains(&continua.len()), "{sets:#?}");
    let c = continua
        .iter()
        .find(|c| !c.undesirable)
        .expect("the goal's circle");
    assert!(c.samples >= 20 && total >= c.samples, "{c:?} of {total}");
    assert!(c.upper[2] - c.lower[2] > 5.0, "headings {c:?}");
    // The circle of radius l about the origin, and nothing else in the continuum's hull.
    for i in 0..2 {
        assert!(
            c.lower[i] >= -0.3 - 1e-6 && c.upper[i] <= 0.3 + 1e-6,
            "{c:?}"
        );
    }
    let r = (c.example[0].powi(2) + c.example[1].powi(2)).sqrt();
    assert!((r - 0.3).abs() < 1e-6, "{c:?}");
    assert!(sets.len() < 20, "{} sets", sets.len());

    let s1 = integrator();
    let found = find_equilibria(&SafetyFilter::new(&s1), &s1.reach.region, &search);
    let sets = group_equilibria(found, &s1.reach.region, &search);
    assert_eq!(sets.len(), 4);
    assert!(sets.iter().all(|e| matches!(e, EquilibriumSet::Point(_))));
}

/// A periodic state's two ends are one angle: the lane keeper's equilibria at `ψ = ±π` are
/// found once each, not twice (three in all: the origin, the saddle heading backwards, and the
/// filter's own one at the lane's edge).
#[test]
fn equilibria_at_both_ends_of_a_period_are_one() {
    let s = common::fixture_with("lane.toml", &[]);
    let found = find_equilibria(
        &SafetyFilter::new(&s),
        &s.reach.region,
        &EquilibriumSearch::default(),
    );
    let at_pi: Vec<_> = found
        .iter()
        .filter(|e| (e.x[1].abs() - std::f64::consts::PI).abs() < 1e-6)
        .collect();
    assert_eq!(found.len(), 3, "{found:#?}");
    assert_eq!(at_pi.len(), 2, "{found:#?}");
    assert!(at_pi
        .iter()
        .any(|e| e.x[0].abs() < 1e-6 && e.kind == Stability::Saddle));
    assert!(at_pi
        .iter()
        .any(|e| (e.x[0] - 1.0).abs() < 1e-6 && e.undesirable));
}

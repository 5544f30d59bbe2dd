//! Equilibria of the paper's filtered systems.

mod common;

use cbfreach::equilibria::{find_equilibria, EquilibriumSearch, Stability};
use cbfreach::filter::SafetyFilter;
use common::{double_integrator, integrator};

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

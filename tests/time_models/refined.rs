//! Refinement in continuous time (design §7.3, "Refinement cuts the step"): a leaf of depth d
//! runs steps of `dt / substeps_at(d)`, and its verdict rests on its own sets. Checked here
//! against the system they name, not against another run of the engine: RK4 trajectories of the
//! continuous-time filtered system from starts in every refined leaf end inside the leaf's last
//! set, at its end time.

use super::*;
use cbfreach::verify::{Verifier, VerifySettings};

#[test]
fn refined_leaves_hold_the_continuous_time_system() {
    let mut s = common::integrator();
    // One second: no leaf reaches the goal, so every round bisects every leaf, and the leaves
    // of the last round (three bisections: steps of dt / 4) keep their own sets.
    s.reach.horizon = 1.0;
    let problem = common::shipped_problem(&s);
    assert_eq!(problem.time, TimeModel::Continuous, "the default");
    let reach = ReachSettings {
        face_local: true,
        ..s.settings.reach.clone()
    };
    let verifier = Verifier {
        reach,
        ..Verifier::new(&s, &problem, &CpuBackend)
    };
    // The paper's box above the obstacle, (3.0, 2.2)…(3.2, 2.4), verified only in pieces.
    let settings = VerifySettings {
        region: Some(IntervalBox::new(vec![3.0, 2.2], vec![3.2, 2.4]).unwrap()),
        grid: vec![1, 1],
        refine_depth: 3,
        ..VerifySettings::default()
    };
    let report = verifier.run(&settings, &|_, _, _| {}).unwrap();
    let filter = SafetyFilter::new(&s);
    // Fine enough for every cut of the step (dt / 4 at most by default): times land on it.
    let fine = s.reach.dt / (10 * settings.max_substeps) as f64;
    let (mut checks, mut escapes, mut deepest) = (0, Vec::new(), 0);
    for leaf in report.after.iter().filter(|b| b.depth > 0) {
        let (Some(set), Some(t)) = (&leaf.final_set, leaf.t_end) else {
            continue;
        };
        deepest = deepest.max(leaf.depth);
        let steps = (t / fine).round() as usize;
        for x0 in sample_box(&leaf.initial, 12, 5) {
            let path = simulate_filtered(&filter, &x0, fine, steps, Integrator::Rk4);
            // A trajectory that stops (an infeasible QP) is not one the set speaks of at `t`.
            let Some(x) = path.x.get(steps) else { continue };
            checks += 1;
            let d = outside(set, x);
            if d > 1e-6 {
                escapes.push((leaf.depth, x0, d));
            }
        }
    }
    assert!(
        escapes.is_empty(),
        "states outside their leaf's set: {escapes:?}"
    );
    // Three bisections of a box of two states run quarter steps: the cut is what is checked.
    assert_eq!(deepest, 3, "{:?}", report.after);
    assert_eq!(settings.substeps_at(&problem, deepest), 4);
    assert!(checks >= 12 * 8, "too few checks: {checks}");
    eprintln!(
        "{} leaves (deepest {deepest}), {checks} end states inside their sets",
        report.after.len()
    );
}

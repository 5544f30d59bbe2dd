//! Absorbing boxes (`verify` stops a tube once its set lies in one): every trajectory of the
//! model from a box proven absorbing lies in its target at every later sample time, checked
//! against the model's own trajectories (the filtered ODE, the exact zero-order hold, the Euler
//! map) over the whole horizon; a goal that trajectories leave gets
//! none; and `verify` with them gives every verdict it gives without them, in fewer steps, on
//! both paper scenarios and in each time model.

use super::*;

use cbfreach::reach::absorb::Absorbers;
use cbfreach::reach::TubeEnd;
use cbfreach::verify::{absorbing_boxes, target_absorbers, traps_for, Absorbing};
use cbfreach::verify::{simulate_model, Verifier};
use cbfreach::verify::{Verdict, VerifySettings};

/// The absorbing boxes of `s` under `time`, with the verification's default settings.
fn proven(s: &Scenario, time: TimeModel) -> (ReachProblem, Vec<Absorbing>) {
    let problem = common::shipped_problem(s).with_time(time, 1);
    let reach = ReachSettings::default();
    let found = absorbing_boxes(s, &problem, &reach, &traps_for(s)).unwrap();
    (problem, found)
}

/// Trajectories of `time`'s model (RK4 at dt/10, the exact zero-order hold, or the Euler map)
/// from 48 starts in each absorbing box, the corners first: states at sample times after the
/// start outside the box's target, and states checked.
fn leaving(s: &Scenario, time: TimeModel, found: &[Absorbing]) -> (usize, usize) {
    let filter = SafetyFilter::new(s);
    let traps = traps_for(s);
    let (mut out, mut checked) = (0, 0);
    for a in found {
        let target = match a.trap {
            None => &s.reach.goal,
            Some(k) => &traps[k].region,
        };
        for x0 in sample_box(&a.inner, 48, 5) {
            let (tr, _) = simulate_model(&filter, &x0, time, 10);
            let every = (tr.x.len() - 1) / s.reach.steps();
            for x in tr.x.iter().step_by(every.max(1)).skip(1) {
                checked += 1;
                out += usize::from(outside(target, x) > 1e-9);
            }
        }
    }
    (out, checked)
}

#[test]
fn absorbing_boxes_hold_each_models_trajectories_in_their_targets() {
    let sampled = |s: &Scenario| TimeModel::Sampled {
        control_period: s.reach.dt,
    };
    for s in [common::integrator(), common::double_integrator()] {
        for time in [TimeModel::Continuous, sampled(&s), TimeModel::Euler] {
            let (_, found) = proven(&s, time);
            assert!(
                found.iter().any(|a| a.trap.is_none()),
                "{} {time}: no absorbing box for the goal: {found:?}",
                s.name
            );
            // Each model's own trajectories: under `euler` the Euler map itself.
            let (out, checked) = leaving(&s, time, &found);
            assert_eq!(out, 0, "{} {time}: {found:?}", s.name);
            assert!(checked >= 48 * 200, "{} {time}: {checked}", s.name);
        }
    }
    // Scenario 1's trap at (3, 0) is proven too (in continuous time).
    let s = common::integrator();
    let (_, found) = proven(&s, TimeModel::Continuous);
    assert!(found.iter().any(|a| a.trap == Some(0)), "{found:?}");
}

/// A goal that the flow leaves (scenario 1's goal moved to the right of the origin, where
/// `κ = −x` carries every state out through its left side) is not absorbing: the prover keeps
/// none of its scales, and the true trajectories do leave it, so a wrong proof would fail the
/// test above.
#[test]
fn a_goal_the_flow_leaves_has_no_absorbing_box() {
    let mut s = common::integrator();
    s.reach.goal = IntervalBox::new(vec![1.0, -0.5], vec![2.0, 0.5]).unwrap();
    let (_, found) = proven(&s, TimeModel::Continuous);
    assert!(found.iter().all(|a| a.trap.is_some()), "{found:?}");
    let fake = Absorbing {
        inner: s.reach.goal.clone(),
        trap: None,
        period: 1,
    };
    let (out, _) = leaving(&s, TimeModel::Continuous, &[fake]);
    assert!(out > 0);
}

/// `verify` (face-local, one round of refinement) on a small grid of each paper scenario, with
/// and without absorbing boxes: the same verdict for every box both runs ran that the run
/// without them verifies (and the feasibility proof), no less area verified, fewer box-steps,
/// tubes that stopped in an absorbing box, and tubes that stopped in a box verified in the
/// round before, whose true trajectories do end in the goal.
#[test]
fn verify_with_absorbing_boxes_keeps_every_verdict_in_fewer_steps() {
    let sampled = |s: &Scenario| TimeModel::Sampled {
        control_period: s.reach.dt,
    };
    // Tubes that stopped in a box verified in the round before (checked against the true
    // system above): the leaves' absorbers are exercised.
    let mut in_leaves = 0;
    for (s, grid) in [
        (common::integrator(), vec![16, 12]),
        (common::double_integrator(), vec![10, 4]),
    ] {
        for time in [TimeModel::Continuous, sampled(&s), TimeModel::Euler] {
            let problem = common::shipped_problem(&s).with_time(time, 1);
            let filter = SafetyFilter::new(&s);
            let traps = traps_for(&s);
            let mut verifier = Verifier::new(&s, &problem, &CpuBackend);
            verifier.reach.face_local = true;
            let run = |absorb: bool| {
                let settings = VerifySettings {
                    grid: grid.clone(),
                    refine_depth: 1,
                    absorb,
                    ..VerifySettings::default()
                };
                verifier.run(&settings, &|_, _, _| {}).unwrap()
            };
            let (with, without) = (run(true), run(false));
            assert!(!with.run.absorbing.is_empty() && without.run.absorbing.is_empty());
            // Refinement may split differently where verdicts differ: compare the leaves that
            // cover the same boxes, and the area.
            let verified = |r: &cbfreach::verify::VerifyReport| r.headline().verified;
            assert!(verified(&with) >= verified(&without), "{} {time}", s.name);
            let mut absorbed = (0, 0);
            for a in &with.after {
                let same = without.after.iter().find(|b| b.initial == a.initial);
                if let Some(b) = same.filter(|b| b.verdict.is_verified()) {
                    assert_eq!(
                        (a.verdict, a.trap),
                        (b.verdict, b.trap),
                        "{} {time}",
                        s.name
                    );
                    assert!(a.feasible >= b.feasible, "{} {time}", s.name);
                }
                let early = a.t_end.is_some_and(|t| t < s.reach.horizon - 1e-9);
                let converges = a.verdict == Verdict::Converges;
                let target = match (a.verdict, a.trap) {
                    (Verdict::Converges, _) => &s.reach.goal,
                    (Verdict::Trapped, Some(k)) => &traps[k].region,
                    _ => continue,
                };
                if !early {
                    continue;
                }
                // It stopped in its target's absorbing box, or in a box verified in an earlier
                // round: then the true trajectories from it do end in the target.
                let last = a.final_set.as_ref().unwrap();
                if with
                    .run
                    .absorbing
                    .iter()
                    .any(|i| last.is_subset_of(&i.inner))
                {
                    absorbed.0 += usize::from(converges);
                    continue;
                }
                absorbed.1 += usize::from(converges);
                let earlier = with.after.iter().any(|b| {
                    b.depth < a.depth && b.verdict == a.verdict && last.is_subset_of(&b.initial)
                });
                assert!(earlier, "{} {time}: {a:?}", s.name);
                for x0 in sample_box(&a.initial, 9, 3) {
                    if !s.is_safe(&x0) {
                        continue;
                    }
                    let (tr, _) = simulate_model(&filter, &x0, time, 10);
                    let end = tr.x.last().unwrap();
                    assert!(outside(target, end) < 1e-9, "{} {time}: {x0:?}", s.name);
                }
            }
            assert!(absorbed.0 > 0, "{} {time}: no tube stopped early", s.name);
            in_leaves += absorbed.1;
            assert!(
                with.timing.box_steps < without.timing.box_steps,
                "{} {time}: {} ≥ {}",
                s.name,
                with.timing.box_steps,
                without.timing.box_steps
            );
        }
    }
    assert!(in_leaves > 0);
}

/// The GPU engine runs tubes to their end and cuts them where the CPU engine stops them: one
/// cut, at the first absorbed sample after the start, the tube's end recorded.
#[test]
fn a_tube_is_cut_at_its_first_absorbed_sample() {
    let s = common::integrator();
    let (problem, found) = proven(&s, TimeModel::Continuous);
    let full = run(&problem, &s.reach.initial[4..5], ExactField::ClosedForm).remove(0);
    assert!(full.valid() && full.end == TubeEnd::Horizon);
    let stopping = ReachProblem {
        absorbing: Absorbers::new(target_absorbers(&found), &problem.region),
        ..problem.clone()
    };
    let mut cut = full.clone();
    cbfreach::reach::absorb::cut(&stopping, &mut cut);
    let first = full
        .tube
        .iter()
        .position(|x| x.t > 0.0 && found.iter().any(|a| x.set.is_subset_of(&a.inner)))
        .unwrap();
    assert_eq!(cut.tube.len(), first + 1);
    assert_eq!(
        cut.end,
        TubeEnd::Absorbed {
            t: full.tube[first].t
        }
    );
    assert!(cut.valid());
    // The CPU engine stops at that sample: the same tube.
    let stopped = run(&stopping, &s.reach.initial[4..5], ExactField::ClosedForm).remove(0);
    assert_eq!(stopped.end, cut.end);
    assert_eq!(stopped.tube.len(), cut.tube.len());
    assert_eq!(
        stopped.tube.last().unwrap().set,
        cut.tube.last().unwrap().set
    );
}

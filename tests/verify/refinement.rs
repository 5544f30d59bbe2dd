//! Refinement in continuous time (the step cut with the boxes) and `verify_by_pieces`
//! (`cbfreach paper`): its pieces refined as `verify` refines, and resumed from their
//! checkpoints.

use super::*;

/// An engine that runs the CPU's steps but no substeps: refinement that would cut the step
/// must be refused before any box runs.
struct NoSubsteps;

impl Backend for NoSubsteps {
    fn name(&self) -> String {
        "no substeps".into()
    }

    fn reach(
        &self,
        _: &ReachProblem,
        _: &[cbfreach::IntervalBox],
        _: &ReachSettings,
        _: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<cbfreach::reach::ReachResult, cbfreach::reach::ReachError> {
        panic!("a box ran although the run's deepest round was refused")
    }

    fn supports(
        &self,
        problem: &ReachProblem,
        _: &ReachSettings,
    ) -> Result<(), cbfreach::reach::Unsupported> {
        match problem.substeps {
            1 => Ok(()),
            _ => Err(cbfreach::reach::Unsupported::Continuous("substeps > 1")),
        }
    }
}

/// The small network's problem in continuous time with one step a `dt`, and the settings the
/// refinement tests run it with (face-local, the network everywhere, one frame, every step
/// recorded).
fn continuous_case(s: &Scenario) -> (ReachProblem, ReachSettings) {
    let (path, m_c) = network();
    let net = Mlp::load_safetensors(path).unwrap();
    let problem = ReachProblem::with_transform(s, net, *m_c, None)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    let reach = ReachSettings {
        face_local: true,
        exact: ExactField::Nowhere,
        intersect_x: false,
        every: 1,
        ..ReachSettings::default()
    };
    (problem, reach)
}

#[test]
fn refinement_cuts_the_validated_step_in_continuous_time() {
    let s = common::integrator();
    let (problem, reach) = continuous_case(&s);
    let verifier = Verifier {
        reach: reach.clone(),
        ..Verifier::new(&s, &problem, &CpuBackend)
    };
    let run = |max_substeps: usize| {
        let settings = VerifySettings {
            grid: vec![4, 3],
            refine_depth: 3,
            budget: 48,
            max_substeps,
            chunk: Some(64),
            // Every tube to the horizon, as the retraced ones run.
            absorb: false,
            ..VerifySettings::default()
        };
        verifier.run(&settings, &|_, _, _| {}).unwrap()
    };
    let cut = run(4);
    // Each leaf as its own tube on `problem` with `substeps` a step: its last set and end.
    let retrace = |leaf: &cbfreach::verify::BoxVerdict, substeps: usize| {
        let p = problem.clone().with_time(TimeModel::Continuous, substeps);
        let r = CpuBackend
            .reach(&p, std::slice::from_ref(&leaf.initial), &reach, &|_, _| {})
            .unwrap();
        r.boxes[0].last().map(|l| (l.set.clone(), l.t))
    };
    // Equal up to the rounding of the batch a box ran in (its network bounds are GEMMs).
    let same = |a: &Option<(cbfreach::IntervalBox, f64)>,
                b: &Option<(cbfreach::IntervalBox, f64)>| {
        match (a, b) {
            (None, None) => true,
            (Some((x, s)), Some((y, t))) => {
                let ends = x
                    .lower
                    .iter()
                    .chain(&x.upper)
                    .zip(y.lower.iter().chain(&y.upper));
                s == t
                    && ends
                        .into_iter()
                        .all(|(p, q)| (p - q).abs() <= 1e-9 * (1.0 + p.abs()))
            }
            _ => false,
        }
    };
    let found = |b: &cbfreach::verify::BoxVerdict| b.final_set.clone().zip(b.t_end);
    assert_eq!((cut.run.substeps, cut.run.max_substeps), (1, 4));
    let refined: Vec<_> = cut.after.iter().filter(|b| b.depth > 0).collect();
    assert!(refined.iter().any(|b| b.depth == 3), "{refined:?}");
    // Two states: steps of dt/2 at depths 1 and 2, dt/4 at depth 3 (the cap).
    let mut moved = 0;
    for leaf in &refined {
        let substeps = [1, 2, 2, 4][leaf.depth];
        let own = retrace(leaf, substeps);
        assert!(
            same(&found(leaf), &own),
            "depth {}: {leaf:?} against {own:?}",
            leaf.depth
        );
        moved += usize::from(!same(&retrace(leaf, 1), &own));
    }
    // The shorter steps change what the leaves' tubes are (else the check above proves nothing).
    assert!(
        moved > 0,
        "no refined leaf's tube differs from its whole-step tube"
    );

    // The integrator's steps count the refined boxes' substeps; box-steps count dt.
    let t = &cut.timing;
    assert!(
        t.box_steps < t.integration_steps && t.integration_steps <= 4 * t.box_steps,
        "{t:?}"
    );

    // max_substeps = 1: refinement keeps the step.
    let kept = run(1);
    assert_eq!(kept.run.max_substeps, 1);
    assert_eq!(kept.timing.integration_steps, kept.timing.box_steps);
    for leaf in kept.after.iter().filter(|b| b.depth > 0) {
        assert!(same(&found(leaf), &retrace(leaf, 1)), "{leaf:?}");
    }

    // An engine without substeps: refused up front, naming the setting.
    let verifier = Verifier {
        reach: reach.clone(),
        ..Verifier::new(&s, &problem, &NoSubsteps)
    };
    let settings = VerifySettings {
        grid: vec![4, 3],
        refine_depth: 1,
        ..VerifySettings::default()
    };
    let err = verifier
        .run(&settings, &|_, _, _| {})
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("max_substeps") && err.contains("substeps > 1"),
        "{err}"
    );
}

/// `verify_by_pieces` (`cbfreach paper`) refines a box's pieces as `verify` does, its step cut
/// down to `PiecesSettings::max_substeps`: with the cap at 1 and at 4 it counts the leaves and
/// the proven ones that `verify` counts on the same box with the same cap, and the two caps
/// give different counts (else the comparison would not show the cap reaching the pieces).
#[test]
fn pieces_cut_the_step_as_verify_does() {
    let s = common::integrator();
    let (problem, reach) = continuous_case(&s);
    let verifier = Verifier {
        reach: reach.clone(),
        ..Verifier::new(&s, &problem, &CpuBackend)
    };
    let region = s.reach.region.clone();
    let whole = CpuBackend
        .reach(&problem, std::slice::from_ref(&region), &reach, &|_, _| {})
        .unwrap();
    let counts = |max_substeps: usize| {
        let pieces = verify_by_pieces(
            &s,
            &problem,
            &reach,
            &verifier.traps,
            &whole.boxes,
            PiecesSettings {
                refine: 2,
                max_substeps,
            },
            &no_journals,
            &|_, _| {},
        )
        .unwrap();
        let PieceOutcome::Undecided { proven, pieces, .. } = pieces[0].outcome else {
            panic!("C itself is not expected to verify: {:?}", pieces[0]);
        };
        let settings = VerifySettings {
            region: Some(region.clone()),
            grid: vec![SPLIT; 2],
            refine_depth: 2,
            budget: REFINE_BUDGET,
            refine_feasibility: true,
            max_substeps,
            chunk: Some(PIECES_CHUNK),
            ..VerifySettings::default()
        };
        let report = verifier.run(&settings, &|_, _, _| {}).unwrap();
        let verified = report.after.iter().filter(|b| b.verdict.is_verified());
        assert_eq!(
            (proven, pieces),
            (verified.count(), report.after.len()),
            "max_substeps {max_substeps}"
        );
        (proven, pieces)
    };
    let (kept, cut) = (counts(1), counts(4));
    assert_ne!(kept, cut, "the cap changes no count");
}

/// `cbfreach paper --resume`: `verify_by_pieces` interrupted after its first journaled chunk
/// resumes from that box's checkpoint without running the recorded pieces again, and ends in
/// the verdict an uninterrupted run gives.
#[test]
fn pieces_resume_from_their_checkpoints() {
    use cbfreach::boxes::IntervalBox;
    use cbfreach::verify::checkpoint::{Checkpoint, Journal};
    use cbfreach::verify::{BoxVerdict, PiecesJournals, VerifyError};
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// A checkpoint that counts the boxes it hands back and, with `stop`, asks to stop once
    /// it has recorded a chunk.
    struct Watched {
        c: Checkpoint,
        stop: bool,
        recorded: AtomicUsize,
        handed_back: Arc<AtomicUsize>,
    }
    impl Journal for Watched {
        fn lookup(&self, c: usize, d: usize, b: &IntervalBox) -> Option<(BoxVerdict, usize)> {
            let found = self.c.lookup(c, d, b);
            self.handed_back
                .fetch_add(usize::from(found.is_some()), Ordering::SeqCst);
            found
        }
        fn record(&self, done: &[(BoxVerdict, usize)]) -> Result<(), VerifyError> {
            self.recorded.fetch_add(done.len(), Ordering::SeqCst);
            self.c.record(done)
        }
        fn stop_requested(&self) -> bool {
            self.stop && self.recorded.load(Ordering::SeqCst) > 0
        }
    }

    let s = common::integrator();
    let problem = euler_problem(&s);
    let verifier = Verifier::new(&s, &problem, &CpuBackend);
    let whole = CpuBackend
        .reach(
            &problem,
            std::slice::from_ref(&s.reach.region),
            &verifier.reach,
            &|_, _| {},
        )
        .unwrap();
    let pieces = |journals: &PiecesJournals<'_>| {
        let settings = PiecesSettings {
            refine: 1,
            ..PiecesSettings::default()
        };
        let (reach, traps) = (&verifier.reach, &verifier.traps);
        verify_by_pieces(
            &s,
            &problem,
            reach,
            traps,
            &whole.boxes,
            settings,
            journals,
            &|_, _| {},
        )
    };
    let straight = pieces(&no_journals).unwrap();
    assert!(
        !matches!(straight[0].outcome, PieceOutcome::Whole { .. }),
        "C itself was expected to need its pieces: {:?}",
        straight[0]
    );
    let tmp = tempfile::tempdir().unwrap();
    let file = tmp.path().join("box.checkpoint");
    let identity = || [("run".to_string(), "test".to_string())].into();
    let handed_back = Arc::new(AtomicUsize::new(0));
    let watched = |c: Checkpoint, stop: bool| -> Box<dyn Journal> {
        Box::new(Watched {
            c,
            stop,
            recorded: AtomicUsize::new(0),
            handed_back: handed_back.clone(),
        })
    };
    let first = pieces(&|_, _| Ok(watched(Checkpoint::create(&file, identity())?, true)));
    assert!(matches!(first, Err(VerifyError::Interrupted)), "{first:?}");
    assert_eq!(handed_back.load(Ordering::SeqCst), 0);
    let recorded = AtomicUsize::new(0);
    let resumed = pieces(&|_, _| {
        let c = Checkpoint::resume(&file, identity())?;
        recorded.store(c.recorded(), Ordering::SeqCst);
        Ok(watched(c, false))
    })
    .unwrap();
    // The first round's pieces that run (those not judged at their start) ran as one chunk
    // before the stop, and came back instead of running again.
    let recorded = recorded.load(Ordering::SeqCst);
    assert!((1..=SPLIT * SPLIT).contains(&recorded), "{recorded}");
    assert_eq!(handed_back.load(Ordering::SeqCst), recorded);
    assert_eq!(resumed, straight);
}

/// `refine_boundary`: around the trap (3, 0) on the obstacle's circle, the cells that straddle
/// the circle are `partly-unsafe` and never run; with the setting their halves that start in
/// `S` are run and join the safe area, and those beside the trap prove `trapped`, as the
/// ground-truth filter agrees from every start checked.
#[test]
fn boundary_refinement_runs_the_halves_of_cells_straddling_the_safe_sets_boundary() {
    use cbfreach::verify::start_verdict;
    use cbfreach::IntervalBox;

    let s = common::integrator();
    let problem = common::shipped_problem(&s).with_time(TimeModel::Euler, 1);
    let verifier = Verifier {
        reach: ReachSettings {
            face_local: true,
            ..ReachSettings::default()
        },
        ..Verifier::new(&s, &problem, &CpuBackend)
    };
    let region = IntervalBox::new(vec![2.8, -0.4], vec![3.6, 0.4]).unwrap();
    let run = |refine_boundary: bool| {
        let settings = VerifySettings {
            region: Some(region.clone()),
            grid: vec![4, 4],
            refine_depth: 4,
            budget: 400,
            refine_boundary,
            chunk: Some(64),
            ..VerifySettings::default()
        };
        verifier.run(&settings, &|_, _, _| {}).unwrap()
    };

    let plain = run(false);
    let band: Vec<usize> = (plain.before.iter())
        .filter(|b| b.verdict == Verdict::PartlyUnsafe)
        .map(|b| b.cell)
        .collect();
    assert!(!band.is_empty(), "no cell straddles the circle");
    let in_band = |b: &&cbfreach::verify::BoxVerdict| band.contains(&b.cell);
    assert!(plain.after.iter().filter(in_band).all(|b| b.depth == 0));
    let safe = |r: &VerifyReport| (r.shares_before().safe_area, r.shares_after().safe_area);
    let (before, after) = safe(&plain);
    assert!((after - before).abs() < 1e-12, "{before} → {after}");

    let refined = run(true);
    assert!(refined.run.refine_boundary);
    let area: f64 = refined.after.iter().map(|b| b.initial.volume()).sum();
    assert!(
        (area - region.volume()).abs() < 1e-12,
        "the leaves do not tile: {area}"
    );
    let (before, after) = safe(&refined);
    assert!(
        after > before + 0.01,
        "the safe area did not grow: {before} → {after}"
    );
    // Each leaf's start is judged on the leaf itself.
    for b in &refined.after {
        let start = start_verdict(&s, &b.initial);
        match b.verdict.starts_safe() {
            true => assert_eq!(start, None, "{b:?}"),
            false => assert_eq!(start, Some(b.verdict), "{b:?}"),
        }
    }
    let trapped: f64 = (refined.after.iter().filter(in_band))
        .filter(|b| b.verdict == Verdict::Trapped)
        .map(|b| b.initial.volume())
        .sum();
    assert!(trapped > 0.0, "no half in the band proved trapped");
    let check = simulation_check(&s, &refined, 3);
    assert!(check.starts > 0);
    assert!(check.disagreements.is_empty(), "{:?}", check.disagreements);
}

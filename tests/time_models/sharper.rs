//! The CPU engine's sharper continuous-time rates (`ReachSettings::taylor3`, `lattice`; design
//! §7.1 items 4b and 6): scenario 2's boxes of depth 6 (`1/32` wide) that slide round the
//! obstacle, where the sets lost to the first-order Taylor form and the enclosures of `v` what
//! they gained on the Euler map. With both, every continuous-time trajectory (RK4 at a tenth of
//! the step) lies in the sets and flowpipes, and boxes that ended `invalid` without them reach
//! the goal.

use super::*;

/// Leaves of `verify --grid 40,16 --face-local --refine 6` (depth 6) that the Euler map verifies
/// and continuous time at four substeps did not (each ended `invalid`, its sets meeting the
/// error map's `M = ∞` cells at (1, 0) or (3, 0) between 1.9 and 3 s; three no longer do since
/// the curved rates' barrier starts from its fixed point); with the sharper rates each reaches
/// the goal.
fn leaves() -> Vec<IntervalBox> {
    [
        ([-1.40625, 1.46875], [-1.375, 1.5]),
        ([-1.03125, 1.78125], [-1.0, 1.8125]),
        ([-0.84375, 1.15625], [-0.8125, 1.1875]),
        ([1.65625, 1.4375], [1.6875, 1.46875]),
        ([-0.59375, 1.625], [-0.5625, 1.65625]),
        ([0.75, 1.46875], [0.78125, 1.5]),
        ([-2.28125, 1.9375], [-2.25, 1.96875]),
    ]
    .into_iter()
    .map(|(l, u)| IntervalBox::new(l.to_vec(), u.to_vec()).unwrap())
    .collect()
}

fn tubes(problem: &ReachProblem, boxes: &[IntervalBox], sharp: bool) -> Vec<Tube> {
    let settings = ReachSettings {
        face_local: true,
        taylor3: sharp,
        lattice: sharp,
        // Measured before the clipped slabs (item 7), which alone keep all seven valid.
        meet_slabs: false,
        ..ReachSettings::default()
    };
    CpuBackend
        .reach(problem, boxes, &settings, &|_, _| {})
        .unwrap()
        .boxes
}

#[test]
fn sharper_rates_hold_the_continuous_time_system_and_keep_more_boxes() {
    let s = common::double_integrator();
    // The substeps refinement gives leaves of depth 6 (`VerifySettings::substeps_at`).
    let problem = common::shipped_problem(&s).with_time(TimeModel::Continuous, 4);
    let boxes = leaves();
    let sharp = tubes(&problem, &boxes, true);
    let e = escapes(&s, &sharp, s.reach.dt, 1e-6);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= boxes.len() * 48 * 20, "too few checks: {e:?}");

    let plain = tubes(&problem, &boxes, false);
    let valid = |t: &[Tube]| t.iter().filter(|t| t.valid()).count();
    // All seven ended invalid before the curved rates' barrier started from its fixed point
    // (`end_rates::fixed_point`); three do now.
    assert!(
        valid(&plain) <= 3,
        "{} of the leaves stay valid at four substeps without the sharper rates",
        valid(&plain)
    );
    assert!(
        valid(&sharp) >= 6 && valid(&sharp) > valid(&plain),
        "{} of {} valid ({} without)",
        valid(&sharp),
        boxes.len(),
        valid(&plain)
    );
    // Where both ran, the sharper sets are no wider, and narrower somewhere.
    let (mut narrower, mut wider) = (0, 0);
    for (a, b) in sharp.iter().zip(&plain) {
        for (x, y) in a.tube.iter().zip(&b.tube) {
            let (wa, wb) = (x.set.widths(), y.set.widths());
            if wa.iter().zip(&wb).any(|(p, q)| p > &(q + 1e-12)) {
                wider += 1;
            }
            if wa.iter().zip(&wb).any(|(p, q)| p < &(q - 1e-9)) {
                narrower += 1;
            }
        }
    }
    eprintln!(
        "{} of {} valid ({} without); {narrower} sets narrower, {wider} wider; {e:?}",
        valid(&sharp),
        boxes.len(),
        valid(&plain)
    );
    assert!(narrower > 100, "{narrower} narrower sets");
    assert!(
        wider <= narrower / 20,
        "{wider} wider sets, {narrower} narrower"
    );
}

/// Every shipped scenario, as `continuous_sets_hold_the_other_shipped_scenarios` runs it, with
/// both settings: the second-order form on every kind of piece (closed forms of one row and of
/// a scalar input, a general QP's active sets, state-dependent `g`), the lattice where it
/// applies (scenario 2, ACC's CBF row and input bounds). Continuous-time trajectories lie in
/// the sets and flowpipes.
#[test]
fn sharper_rates_hold_the_shipped_scenarios() {
    for (file, steps, extra) in [
        ("integrator.toml", 100, 6),
        ("double-integrator.toml", 100, 6),
        ("acc.toml", 200, 4),
        ("acc-si.toml", 200, 4),
        ("spheres3d.toml", 160, 4),
        ("int3.toml", 40, 6),
        ("unicycle.toml", 40, 6),
    ] {
        let s = Scenario::load(&common::scenario_path(file)).expect("loads");
        let mut problem = common::shipped_problem(&s);
        problem.steps = steps.min(problem.steps);
        let mut boxes = s.reach.initial.clone();
        boxes.extend(super::shipped::random_boxes(
            &s.reach.region,
            extra,
            0.04,
            3,
        ));
        let settings = ReachSettings {
            taylor3: true,
            lattice: true,
            ..s.settings.reach.clone()
        };
        let tubes = CpuBackend
            .reach(&problem, &boxes, &settings, &|_, _| {})
            .unwrap()
            .boxes;
        let e = escapes(&s, &tubes, s.reach.dt, 1e-6);
        assert_eq!((e.at_snapshots, e.between), (0, 0), "{file}: {e:?}");
        let seen: usize = tubes.iter().map(|t| t.tube.len() - 1).sum();
        assert!(
            e.checks >= 24 * seen && seen > 0,
            "{file}: too few checks: {e:?}"
        );
        eprintln!(
            "{file}: {seen} snapshots, {} checks, none outside",
            e.checks
        );
    }
}

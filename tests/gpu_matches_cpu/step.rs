//! One box-step of the continuous model's common path on the device (`shaders/slab_step.wgsl`)
//! against the CPU engine's own step from the same state (`CpuBackend::continuous_step`,
//! docs/design.md §7.4): with the network alone, and with the filter's proven pieces and its
//! closed form's enclosures met with it on the slabs.

use super::*;
use cbfreach::bounds::PreparedNetwork;
use cbfreach::gpu::probe_field::{common_step_on_device, NetCase, StepCase};
use cbfreach::reach::cpu::StepState;
use cbfreach::reach::validated;
use cbfreach::rounding::round_up;

/// What [`compare_steps`] saw.
#[derive(Default, Debug)]
struct Seen {
    /// Steps the device proved, and of those compared (the CPU's tube went on).
    proven: usize,
    compared: usize,
    /// Steps the device took the common path on and left to the host.
    flagged: usize,
    /// Proven steps with the filter's proven piece, with its closed form's enclosures.
    pieces: usize,
    enclosed: usize,
    /// The largest difference of a set's end or a kept rate, relative to the magnitudes.
    worst: f64,
}

/// Steps `init` `steps` times with the CPU engine from their state (`continuous_step`); from
/// each state that has rates, the device takes the same step with the network's bounds on the
/// slabs (or the hull) of the CPU's guess and the global margin. The device takes the common
/// path exactly where the CPU guessed (a box within `C` in x), proves it exactly where the CPU's
/// first check held, with the same sources (the proven piece, the enclosures), and there its set
/// and the rates it keeps equal the CPU's to 1e-10 relative (f64; the device rounds each
/// operation outward by 4 ulp, the CPU by 1), and it keeps the rates it started from as the
/// step before's.
fn compare_steps(
    g: &GpuBackend,
    problem: &ReachProblem,
    st: &ReachSettings,
    init: &[IntervalBox],
    steps: usize,
    seen: &mut Seen,
) {
    let (n, h) = (problem.dynamics.n, problem.dt);
    let net = PreparedNetwork::new(&problem.network).unwrap();
    let margin = round_up(problem.m_c + problem.network_slack);
    let within_c = |p: &validated::Flowpipe| {
        problem.transform.is_some() || p.set.is_subset_of(&problem.region)
    };
    let mut states: Vec<StepState> = init.iter().map(|b| StepState::start(b.clone())).collect();
    let (mut cases, mut cpu) = (Vec::new(), Vec::new());
    for _ in 0..steps {
        let out = CpuBackend.continuous_step(problem, st, &states).unwrap();
        let mut next = Vec::new();
        for (state, o) in states.iter().zip(out) {
            if let Some(rates) = &state.rates {
                let before = state.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
                let guess = validated::guessed(&state.set, h, (&rates.0, &rates.1), before)
                    .filter(within_c);
                let nn: Vec<NetCase> = match &guess {
                    Some(pipe) if st.face_local => validated::slabs(&state.set, pipe, h)
                        .map(|(lo, hi)| NetCase::from(&net.bounds(&lo, &hi, st.bounds).unwrap()))
                        .collect(),
                    Some(pipe) => {
                        let b = net.bounds(&pipe.set.lower, &pipe.set.upper, st.bounds);
                        vec![NetCase::from(&b.unwrap()); 2 * n]
                    }
                    None => {
                        let b = net.bounds(&state.set.lower, &state.set.upper, st.bounds);
                        vec![NetCase::from(&b.unwrap()); 2 * n]
                    }
                };
                cases.push(StepCase {
                    set: state.set.clone(),
                    h,
                    rates: state.rates.clone(),
                    before: state.before.clone(),
                    nn,
                    margin,
                });
                cpu.push((state.clone(), guess.is_some(), o.clone()));
            }
            if o.end.is_none() {
                next.push(o.state);
            }
        }
        states = next;
    }
    let dev = common_step_on_device(g.context(), problem, st, &cases).unwrap();
    for ((before, guessed, o), d) in cpu.iter().zip(&dev) {
        let what = format!(
            "face-local {}, exact {:?}: from {before:?}: cpu {o:?}, device {d:?}",
            st.face_local, st.exact
        );
        assert_eq!(*guessed, d.common, "{what}: common path");
        if !d.common {
            continue;
        }
        assert_eq!(o.common, d.proven, "{what}: proven");
        if !d.proven {
            seen.flagged += 1;
            continue;
        }
        seen.proven += 1;
        assert_eq!(
            o.sources,
            (d.piece.is_some(), d.enclosed),
            "{what}: sources"
        );
        seen.pieces += usize::from(d.piece.is_some());
        seen.enclosed += usize::from(d.enclosed);
        if o.end.is_some() {
            continue;
        }
        seen.compared += 1;
        let scale = |v: &[f64]| 1.0 + v.iter().fold(0.0_f64, |a, x| a.max(x.abs()));
        let near = |a: &[f64], b: &[f64]| {
            let s = scale(a);
            a.iter().zip(b).all(|(x, y)| (x - y).abs() <= 1e-10 * s)
        };
        let set = &o.state.set;
        let (rl, ru) = o.state.rates.as_ref().unwrap();
        for (a, b) in [
            (&set.lower, &d.set.lower),
            (&set.upper, &d.set.upper),
            (rl, &d.rates.0),
            (ru, &d.rates.1),
        ] {
            let s = scale(a);
            seen.worst = a
                .iter()
                .zip(b)
                .fold(seen.worst, |w, (x, y)| w.max((x - y).abs() / s));
        }
        assert!(
            near(&set.lower, &d.set.lower) && near(&set.upper, &d.set.upper),
            "{what}: set"
        );
        assert!(
            near(rl, &d.rates.0) && near(ru, &d.rates.1),
            "{what}: rates"
        );
        assert_eq!(d.known_rates, 1 + u32::from(o.state.before.is_some()));
        // The step before's, for the next guess's trend: the rates the step started from.
        let (bl, bu) = o.state.before.as_ref().unwrap();
        assert!(
            bl == &d.before.0 && bu == &d.before.1,
            "{what}: the step before's"
        );
    }
}

/// Scenario 1 with a small network in continuous time (one step a `dt`).
fn scenario_1() -> ReachProblem {
    let s = integrator();
    ReachProblem::new(&s, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Continuous, 1)
}

/// Scenario 1, forward bounds, the network everywhere, a global margin; face-local bounds or
/// bounds over the moving box's hull. Twelve boxes, 0.1 wide, across the region, 16 steps
/// ([`compare_steps`]).
#[test]
fn common_step_matches_the_cpu_engines_step() {
    let Some(g) = gpu_f64() else { return };
    let problem = scenario_1();
    let init = boxes(
        &[
            [-3.0, 2.0],
            [-2.0, -2.5],
            [-1.0, 1.0],
            [0.5, -1.5],
            [1.5, 2.5],
            [2.5, -2.0],
            [3.5, 1.5],
            [4.0, -0.5],
            [-3.0, -1.0],
            [0.0, 2.5],
            [1.0, 0.8],
            [4.0, 2.5],
        ],
        0.05,
    );
    let mut seen = Seen::default();
    for face_local in [true, false] {
        let st = ReachSettings {
            face_local,
            ..settings(ReachMethod::Disturbance)
        };
        compare_steps(&g, &problem, &st, &init, 16, &mut seen);
    }
    eprintln!("common steps, the network alone: {seen:?}");
    assert!(seen.compared >= 200, "{seen:?}");
}

/// The filter's own sources on the slabs (`step_rates` of `shaders/slab_step.wgsl`): the proven
/// piece's slab field, curved and Taylor rates, and the closed form's enclosures of `v` on each
/// slab, met with the network's. Scenario 1 (one row, two inputs) with boxes around the
/// obstacle, where the row binds on some hulls and may on others, and scenario 2 in z (a scalar
/// input, two rows, the transform's slack), under `exact = "closed-form"` (with and without the
/// pieces' lattice, `lattice_rates`) and `"inactive"`,
/// face-local forward bounds, 12 steps ([`compare_steps`]: the same sources as the CPU's step,
/// the same sets and rates to 1e-10).
#[test]
fn closed_form_step_matches_the_cpu_engines_step() {
    let Some(g) = gpu_f64() else { return };
    let p1 = scenario_1();
    let b1 = boxes(
        &[
            [0.8, 0.0],
            [0.7, 0.6],
            [2.0, 1.3],
            [2.0, -1.3],
            [3.2, 0.2],
            [3.4, -0.4],
            [1.2, -1.0],
            [2.8, 1.1],
            [-1.0, 1.0],
            [3.9, 0.0],
        ],
        0.05,
    );
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let p2 = ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 2, 0.05), 0.02, t)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    let b2 = boxes(
        &[
            [-1.0, 0.5],
            [0.5, 1.0],
            [1.5, 1.2],
            [-1.5, -1.0],
            [0.0, -1.5],
            [2.5, 0.0],
        ],
        0.05,
    );
    for (problem, init, name) in [(&p1, &b1, "scenario 1"), (&p2, &b2, "scenario 2")] {
        for (exact, lattice) in [
            (ExactField::ClosedForm, false),
            (ExactField::ClosedForm, true),
            (ExactField::Inactive, false),
        ] {
            let init = &match (name, lattice) {
                // On the obstacle row's switching surface, where the lattice applies.
                ("scenario 2", true) => boxes(
                    &[
                        [-0.83, 1.0],
                        [0.06, 0.5],
                        [-1.71, 1.5],
                        [0.43, 0.3],
                        [3.32, -1.5],
                    ],
                    0.03,
                ),
                _ => init.clone(),
            };
            let st = ReachSettings {
                face_local: true,
                exact,
                lattice,
                ..settings(ReachMethod::Disturbance)
            };
            let mut seen = Seen::default();
            compare_steps(&g, problem, &st, init, 12, &mut seen);
            eprintln!("{name}, exact {exact:?}, lattice {lattice}: {seen:?}");
            assert!(seen.compared >= 30, "{name}, {exact:?}: {seen:?}");
            assert!(seen.pieces > 0, "{name}, {exact:?}: no proven piece");
            if exact == ExactField::ClosedForm && (name == "scenario 1" || lattice) {
                assert!(seen.enclosed > 0, "{name}, lattice {lattice}: no enclosure");
            }
        }
    }
}

/// A high-order CBF written out ([`common::high_order_wall`]): the position bound's row, which
/// no input acts on, is made slack in the device's `filter_rows` as in the CPU's `v_rows`
/// (design §1). Boxes straddling `ψ = 0`, where that row's `b` takes both signs, under
/// `exact = "closed-form"` with and without the lattice: the same sources, sets and rates as
/// the CPU's step ([`compare_steps`]).
#[test]
fn a_high_order_cbfs_step_matches_the_cpu_engines_step() {
    let Some(g) = gpu_f64() else { return };
    let s = common::high_order_wall("horizon = 1");
    let problem = ReachProblem::new(&s, small_network(&[2, 16, 16, 1], 3, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    // On ψ = 0: x₂ = h(x₁)/(1 + 0.3x₁²).
    let init = boxes(
        &[
            [0.9, 0.42],
            [0.6, 0.79],
            [1.1, 0.2],
            [0.3, 1.16],
            [0.0, 1.5],
            [-0.5, 1.6],
        ],
        0.05,
    );
    for lattice in [false, true] {
        let st = ReachSettings {
            face_local: true,
            exact: ExactField::ClosedForm,
            lattice,
            ..settings(ReachMethod::Disturbance)
        };
        let mut seen = Seen::default();
        compare_steps(&g, &problem, &st, &init, 12, &mut seen);
        eprintln!("high-order wall, lattice {lattice}: {seen:?}");
        assert!(
            seen.compared >= 30 && seen.enclosed > 0,
            "lattice {lattice}: {seen:?}"
        );
    }
}

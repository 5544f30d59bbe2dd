//! Face-local bounds and local error margins (error maps, grown sets, the safe set, `v = 0` where the filter is inactive), and the loop limits of llvmpipe.

use super::*;

/// Face-local bounds (immrax's local mode) on the GPU agree with the CPU: in f64 to `F64_TOL`,
/// in f32 within `F32_FACTOR`, for constant `g` (both paper scenarios, with the transform) and
/// a state-dependent `g`; and they are no wider than whole-box bounds.
#[test]
fn face_local_matches_cpu() {
    let Some(gpu32) = gpu() else { return };
    let gpu64 = gpu_f64();
    let [(p1, init1), (p2, init2)] = paper_problems(30);
    let s3 = common::from_text(&common::SMALL.replace(r#"["1"]"#, r#"["1 + 0.2*x"]"#)).unwrap();
    let mut p3 = ReachProblem::new(&s3, small_network(&[2, 8, 8, 1], 9, 0.1), 0.02)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p3.steps = 15;
    let init3 = boxes(&[[-0.3, 0.2], [0.4, -0.1]], 0.05);
    let mut worst = (0.0f64, 0.0f64);
    for bounds in [
        BoundMethod::Forward,
        BoundMethod::ForwardBackward,
        BoundMethod::Crown,
    ] {
        let st = with_faces(bounds);
        // Every method on scenario 1, forward-backward (the default) on the others.
        let others = bounds == BoundMethod::ForwardBackward;
        for (problem, init, name) in [
            (&p1, &init1, "scenario 1"),
            (&p2, &init2, "scenario 2 (transform)"),
            (&p3, &init3, "state-dependent g"),
        ]
        .into_iter()
        .filter(|c| others || c.2 == "scenario 1")
        {
            let (c, g) = run_both_with(&gpu32, problem, init, &st);
            let w = compare_within(
                &c,
                &g,
                &format!("f32 face-local {bounds} {name}"),
                F32_FACTOR,
            );
            worst.0 = worst.0.max(w);
            if let Some(gpu64) = &gpu64 {
                let (c, g) = run_both_with(gpu64, problem, init, &st);
                let w = compare_within(&c, &g, &format!("f64 face-local {bounds} {name}"), F64_TOL);
                worst.1 = worst.1.max(w);
            }
        }
    }
    // Face-local bounds are tighter than whole-box ones (the point of the mode).
    let whole = gpu32
        .reach(
            &p1,
            &init1,
            &with_bounds(BoundMethod::Forward, ReachMethod::Disturbance),
            &|_, _| {},
        )
        .unwrap();
    let local = gpu32
        .reach(&p1, &init1, &with_faces(BoundMethod::Forward), &|_, _| {})
        .unwrap();
    let width = |t: &Tube| t.last().unwrap().set.widths().iter().sum::<f64>();
    for (a, b) in whole.boxes.iter().zip(&local.boxes) {
        assert!(
            width(b) <= width(a) * (1.0 + 1e-6),
            "{} vs {}",
            width(b),
            width(a)
        );
    }
    eprintln!(
        "face-local GPU vs CPU, worst relative difference: f32 {:.2e}, f64 {:.2e}",
        worst.0, worst.1
    );
}

/// Local error margins on the GPU agree with the CPU (f64 to `F64_TOL`, f32 within
/// `F32_FACTOR`), with whole-box and face-local bounds; a box that reaches the cell without a
/// certified bound is marked invalid by both engines at the same step, with the same note.
#[test]
fn local_margins_match_cpu() {
    let Some(gpu32) = gpu() else { return };
    let gpu64 = gpu_f64();
    let s = integrator();
    let net = small_network(&[2, 16, 16, 2], 1, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.5)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let map = small_error_map(&problem.region);
    problem = problem.with_error_map(map).unwrap();
    problem.steps = 40;
    // Box 0 converges into the +∞ cell (x₁ → 0 at rate 1 from 2.2); the others cross cells of
    // finite bounds.
    let init = boxes(&[[2.2, 0.3], [-2.0, 2.0], [-3.0, -1.3], [0.2, 2.5]], 0.1);
    let mut worst = (0.0f64, 0.0f64);
    for st in [
        with_bounds(BoundMethod::ForwardBackward, ReachMethod::Disturbance),
        with_faces(BoundMethod::ForwardBackward),
        with_bounds(BoundMethod::Forward, ReachMethod::Disturbance),
    ] {
        let what = format!("{} face-local {}", st.bounds, st.face_local);
        let (c, g) = run_both_with(&gpu32, &problem, &init, &st);
        assert!(
            !c[0].valid() && c[1..].iter().all(|t| t.valid()),
            "{:?}",
            c[0].note()
        );
        assert!(c[0].note().as_ref().unwrap().contains("M = ∞"));
        assert_eq!(c[0].note(), g[0].note());
        worst.0 = worst.0.max(compare_within(
            &c,
            &g,
            &format!("f32 local margins {what}"),
            F32_FACTOR,
        ));
        if let Some(gpu64) = &gpu64 {
            let (c, g) = run_both_with(gpu64, &problem, &init, &st);
            assert_eq!(c[0].note(), g[0].note());
            worst.1 = worst.1.max(compare_within(
                &c,
                &g,
                &format!("f64 local margins {what}"),
                F64_TOL,
            ));
        }
    }
    eprintln!(
        "local margins GPU vs CPU, worst relative difference: f32 {:.2e}, f64 {:.2e}",
        worst.0, worst.1
    );
}

/// The setting that verifies the most boxes (forward-backward, face-local, local margins) with
/// the shipped network and its certified error map, a few boxes and steps: the GPU agrees with
/// the CPU (f64 to `F64_TOL`, f32 containing the CPU's sets within `F32_FACTOR`).
#[test]
fn shipped_error_map_face_local_matches_cpu() {
    let Some(gpu32) = gpu() else { return };
    let s = integrator();
    let net = Mlp::load_safetensors(&common::scenario_path("integrator.safetensors")).unwrap();
    let map =
        cbfreach::error_map::ErrorMap::load(&common::scenario_path("integrator.errormap.json"))
            .unwrap();
    let m_c = map.certified_linf.unwrap();
    let mut problem = ReachProblem::new(&s, net, m_c)
        .unwrap()
        .with_time(TimeModel::Euler, 1)
        .with_error_map(map)
        .unwrap();
    problem.steps = 3;
    let init = boxes(&[[-2.0, 2.0], [3.0, 1.5]], 0.02);
    let st = with_faces(BoundMethod::ForwardBackward);
    let (c, g) = run_both_with(&gpu32, &problem, &init, &st);
    // f32's rigorous rounding bounds over 400-wide layers widen the sets by more than
    // F32_FACTOR (paper_size_network_end_to_end): check containment and measure the excess.
    let mut w32 = 0.0f64;
    for (a, b) in c.iter().zip(&g) {
        assert_eq!(a.valid(), b.valid(), "{:?} vs {:?}", a.note(), b.note());
        assert_eq!(a.tube.len(), b.tube.len());
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            for i in 0..2 {
                let scale = sa.set.lower[i].abs().max(sa.set.upper[i].abs()).max(1.0);
                assert!(
                    sb.set.lower[i] <= sa.set.lower[i] && sa.set.upper[i] <= sb.set.upper[i],
                    "t = {}: gpu {:?} does not contain cpu {:?}",
                    sa.t,
                    sb.set,
                    sa.set
                );
                let excess =
                    (sa.set.lower[i] - sb.set.lower[i]).max(sb.set.upper[i] - sa.set.upper[i]);
                w32 = w32.max(excess / scale);
            }
        }
    }
    assert!(w32 < 0.05, "f32 widening too large: {w32}");
    if let Some(gpu64) = gpu_f64() {
        let (c, g) = run_both_with(&gpu64, &problem, &init, &st);
        let w64 = compare_within(&c, &g, "shipped map f64", F64_TOL);
        eprintln!(
            "shipped map, forward-backward face-local local margins: f32 {w32:.2e}, f64 {w64:.2e}"
        );
    }
}

/// The shipped network and error map (scenario 1) with two 1.0-wide cells of `verify --grid
/// 8,6`, [1.5, 2.5] × [2, 3] and [1.5, 2.5] × [−3, −2], face-local forward-backward bounds and
/// `--exact inactive`, 14 steps: the second set grows over ~17,000 buckets of the map by t = 0.44.
fn grown_sets_problem() -> (ReachProblem, Vec<IntervalBox>, ReachSettings) {
    let mut problem = common::shipped_problem(&integrator()).with_time(TimeModel::Euler, 1);
    problem.steps = 14;
    let init = boxes(&[[2.0, 2.5], [2.0, -2.5]], 0.5);
    let st = ReachSettings {
        exact: ExactField::Inactive,
        ..with_faces(BoundMethod::ForwardBackward)
    };
    (problem, init, st)
}

/// Regression: the local margin of a set that has grown over thousands of buckets. The exact
/// visit of every bucket used to run more than 65,535 loop iterations, after which llvmpipe
/// silently ended every loop of the invocation, for every box of its SIMD group: a field
/// component came out 0 and the second box's set froze in x₂, narrower than the CPU's sound
/// set, and so did the first box's when run beside it. Then block maxima past a work bound
/// kept it sound but looser than the CPU. Now (the range-maximum structure of `gpu::margins`)
/// each box's tube is the same alone and batched, every set contains the true filtered system's
/// trajectories from 16 starts, and in f64 equals the CPU's to `F64_TOL` (exact margins).
#[test]
fn grown_sets_local_margins_are_sound_and_batch_independent() {
    use cbfreach::filter::SafetyFilter;
    use cbfreach::simulate::simulate_filtered;

    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    let (problem, init, st) = grown_sets_problem();
    let cpu = CpuBackend
        .reach(&problem, &init, &st, &|_, _| {})
        .unwrap()
        .boxes;
    assert!(cpu.iter().all(|t| !t.valid()), "both sets should leave C");
    let scenario = integrator();
    let filter = SafetyFilter::new(&scenario);
    let truth: Vec<Vec<Vec<Vec<f64>>>> = init
        .iter()
        .map(|b| {
            sample_box(b, 16, 3)
                .iter()
                .map(|x0| {
                    simulate_filtered(&filter, x0, problem.dt, problem.steps, Integrator::Euler).x
                })
                .collect()
        })
        .collect();
    for gpu in &engines {
        let label = format!("{:?}", gpu.precision());
        let batched = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        for (k, (c, b)) in cpu.iter().zip(&batched).enumerate() {
            let alone = gpu
                .reach(&problem, &init[k..k + 1], &st, &|_, _| {})
                .unwrap()
                .boxes;
            assert_eq!(alone[0].tube.len(), b.tube.len(), "{label} box {k}");
            for (x, y) in alone[0].tube.iter().zip(&b.tube) {
                assert_eq!(
                    x.set, y.set,
                    "{label} box {k}, t = {}: alone vs batched",
                    x.t
                );
            }
            // f32's rounding bounds over 400-wide layers widen more than that (see
            // shipped_error_map_face_local_matches_cpu): its closeness is not checked.
            if gpu.precision() == Precision::F32 {
                continue;
            }
            for (sc, sg) in c.tube.iter().zip(&b.tube) {
                for i in 0..2 {
                    let scale = sc.set.lower[i].abs().max(sc.set.upper[i].abs()).max(1.0);
                    let gap = (sc.set.lower[i] - sg.set.lower[i])
                        .abs()
                        .max((sc.set.upper[i] - sg.set.upper[i]).abs());
                    assert!(
                        gap <= F64_TOL * scale,
                        "{label} box {k}, t = {}: gpu {:?} vs cpu {:?}",
                        sc.t,
                        sg.set,
                        sc.set
                    );
                }
            }
        }
        let checks = count_contained(&batched, &truth, problem.dt, &label);
        assert!(checks > 300, "too few checks: {checks}");
    }
}

/// The embedding kernel's loop check: with a million extra loop iterations per local-margin
/// query (`pad_loops`, as an unbounded visit of the map's cells once ran), llvmpipe cuts the
/// loops short, and the run fails with an error that says so instead of returning wrong sets;
/// a driver without such a limit runs it.
#[test]
fn a_driver_that_cuts_loops_short_fails_the_run() {
    let Some(mut gpu) = gpu() else { return };
    gpu.pad_loops = 1 << 20;
    let (problem, init, st) = grown_sets_problem();
    let res = gpu.reach(&problem, &init[1..], &st, &|_, _| {});
    if gpu.context().info.name.contains("llvmpipe") {
        let e = res
            .expect_err("llvmpipe should cut the unbounded visit short")
            .to_string();
        assert!(e.contains("cut the embedding kernel's loops short"), "{e}");
    } else {
        assert!(res.is_ok(), "{:?}", res.err());
    }
}

/// A layer so wide that a bound kernel's thread would loop past llvmpipe's limit (60,000
/// neurons: without the check its sets came out narrower than the CPU's) is refused on
/// llvmpipe with an error that names the widths; a 20,000-wide one runs and agrees with the
/// CPU. Elsewhere both run.
#[test]
fn networks_too_wide_for_llvmpipes_loop_limit_are_refused_there() {
    let Some(gpu) = gpu_f64() else { return };
    let s = integrator();
    let init = boxes(&[[-2.0, 2.0]], 0.05);
    let st = with_bounds(BoundMethod::ForwardBackward, ReachMethod::Disturbance);
    let llvmpipe = gpu.context().info.name.contains("llvmpipe");
    for width in [20_000, 60_000] {
        let net = small_network(&[2, width, 2], 5, 0.01);
        let mut problem = ReachProblem::new(&s, net, 0.1)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 1;
        let res = gpu.reach(&problem, &init, &st, &|_, _| {});
        if llvmpipe && width > 20_000 {
            let e = res
                .expect_err("llvmpipe should refuse the network")
                .to_string();
            assert!(e.contains("[2, 60000, 2]") && e.contains("loop"), "{e}");
        } else {
            let cpu = CpuBackend.reach(&problem, &init, &st, &|_, _| {}).unwrap();
            compare_within(&cpu.boxes, &res.unwrap().boxes, "a wide layer", F64_TOL);
        }
    }
}

/// Trajectories of the NN system with a disturbance within the smallest cell bound (so within
/// every local margin) stay in the GPU's face-local, local-margin sets, in f32 and f64.
#[test]
fn face_local_local_margin_sets_contain_trajectories() {
    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    let s = integrator();
    let net = small_network(&[2, 16, 16, 2], 4, 0.2);
    let problem = ReachProblem::new(&s, net.clone(), 0.5)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let map = small_error_map(&problem.region);
    let mut problem = problem.with_error_map(map).unwrap();
    problem.steps = 40;
    let w = 0.01; // the smallest bound of small_error_map
                  // (Away from the +∞ cell.)
    let init = boxes(&[[-2.0, 1.0], [-1.0, -1.0], [-3.0, 0.0]], 0.1);
    let trajectories = nn_trajectories(&s, &net, &init, problem.dt, problem.steps, w);
    for gpu in &engines {
        for st in [
            with_faces(BoundMethod::ForwardBackward),
            with_faces(BoundMethod::Crown),
        ] {
            let tubes = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
            for tube in &tubes {
                assert!(tube.valid(), "{:?}", tube.note());
            }
            let label = format!("{} {:?}", st.bounds, gpu.precision());
            let checks = count_contained(&tubes, &trajectories, problem.dt, &label);
            assert!(checks > 1000, "too few checks: {checks}");
        }
    }
}

/// Scenario 2 in z coordinates with local margins, a box driven into the velocity bound
/// x₂ ≥ −2 (the lower edge of C): the parallelotope's x-box pokes out of C, and only its part in
/// S (src/reach/safe_set.rs) is looked up in the error map, so the margin stays finite. The GPU
/// agrees with the CPU (f32 within `F32_FACTOR`, f64 to `F64_TOL`).
#[test]
fn safe_set_keeps_local_margins_finite_at_the_edge_of_c() {
    let Some(gpu32) = gpu() else { return };
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 2, 0.05);
    let t = Transform::for_scenario(&s, &TransformChoice::Auto).unwrap();
    let mut problem = ReachProblem::with_transform(&s, net, 0.5, t)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let map = small_error_map(&problem.region);
    problem = problem.with_error_map(map).unwrap();
    problem.steps = 30;
    let init = boxes(&[[5.0, -1.85], [-1.0, 0.5]], 0.05);
    let st = with_faces(BoundMethod::ForwardBackward);
    let (c, g) = run_both_with(&gpu32, &problem, &init, &st);
    assert!(c[0].tube.iter().any(|x| x.set.lower[1] == -2.0));
    assert!(
        c[0].tube.iter().any(|x| x.lower[1] < -2.0),
        "the x-box of the z-box should leave C"
    );
    for t in &c {
        assert!(
            !t.note().as_deref().unwrap_or_default().contains("M = ∞"),
            "{:?}",
            t.note()
        );
    }
    compare_within(&c, &g, "f32 safe set, local margins", F32_FACTOR);
    if let Some(gpu64) = gpu_f64() {
        let (c, g) = run_both_with(&gpu64, &problem, &init, &st);
        compare_within(&c, &g, "f64 safe set, local margins", F64_TOL);
    }
}

/// Where the filter is proven inactive both engines take `v = 0` (`ExactField::Inactive`, the
/// same rows evaluated in the same interval arithmetic): on scenario 2 in z coordinates, with
/// a box near the goal (inactive on every step), one where the filter acts and one that comes
/// to rest, the GPU in f64 agrees with the CPU on the sets to `F64_TOL` and on the steps taken
/// exactly; in f32 it takes no step exactly that the CPU does not, and the near-goal box's
/// steps all.
#[test]
fn v_zero_where_the_filter_is_inactive_matches_cpu() {
    let Some(gpu32) = gpu() else { return };
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 6, 0.05);
    let t = Transform::for_scenario(&s, &TransformChoice::Auto).unwrap();
    let mut problem = ReachProblem::with_transform(&s, net, 0.02, t)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 40;
    let init = boxes(&[[0.1, -0.1], [1.0, 1.5], [-2.5, 0.5]], 0.05);
    let settings = ReachSettings {
        exact: ExactField::Inactive,
        ..with_faces(BoundMethod::Forward)
    };
    let (c, g) = run_both_with(&gpu32, &problem, &init, &settings);
    assert_eq!(c[0].exact_steps, problem.steps, "near the goal");
    assert!(
        c[1].exact_steps < c[1].steps_run(problem.dt),
        "the filter acts at (1, 1.5)"
    );
    for (a, b) in c.iter().zip(&g) {
        assert!(
            b.exact_steps <= a.exact_steps,
            "{} vs {}",
            b.exact_steps,
            a.exact_steps
        );
    }
    assert_eq!(g[0].exact_steps, problem.steps);
    if let Some(gpu64) = gpu_f64() {
        let (c, g) = run_both_with(&gpu64, &problem, &init, &settings);
        for (a, b) in c.iter().zip(&g) {
            assert_eq!(a.exact_steps, b.exact_steps);
        }
        compare_within(&c, &g, "v = 0 where inactive, f64", F64_TOL);
    }
}

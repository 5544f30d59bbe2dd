//! Soundness of the CPU reach engine by sampling (docs/design.md §3): NN-system trajectories stay in
//! the embedding boxes, and filtered-system trajectories stay in the disturbance sets when
//! `M_C` is a certified bound on `‖N − v‖∞` over `C`.

mod common;

use cbfreach::reach::TimeModel;

use cbfreach::bounds::{network_bounds, BoundMethod};
use cbfreach::filter::SafetyFilter;
use cbfreach::network::Mlp;
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, Tube,
};
use cbfreach::scenario::Scenario;
use cbfreach::simulate::{integrate, sample_box, simulate_filtered, Integrator};
use common::{double_integrator, from_text, integrator, nn_field, small_network};

/// Runs the engine with M = `m_c` on boxes around the given centres.
fn run(
    s: &Scenario,
    face_local: bool,
    net: &Mlp,
    m_c: f64,
    bounds: BoundMethod,
    centres: &[[f64; 2]],
    half_width: f64,
) -> Vec<Tube> {
    let problem = ReachProblem::new(s, net.clone(), m_c)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let boxes: Vec<_> = centres
        .iter()
        .map(|c| {
            cbfreach::IntervalBox::new(
                c.iter().map(|v| v - half_width).collect(),
                c.iter().map(|v| v + half_width).collect(),
            )
            .unwrap()
        })
        .collect();
    let settings = ReachSettings {
        bounds,
        method: ReachMethod::Disturbance,
        every: 1,
        face_local,
        exact: ExactField::Nowhere,
        intersect_x: false,
        ..ReachSettings::default()
    };
    CpuBackend
        .reach(&problem, &boxes, &settings, &|_, _| {})
        .unwrap()
        .boxes
}

/// Asserts that the trajectory (sampled every `sub` fine steps) lies in the tube while valid,
/// up to `tol(k)` at recorded step k; returns the number of (point, time) checks made.
fn assert_inside(
    tube: &Tube,
    xs: &[Vec<f64>],
    sub: usize,
    tol: impl Fn(usize) -> f64,
    what: &str,
) -> usize {
    let mut checks = 0;
    for sample in &tube.tube {
        let step = (sample.t / tube_dt(tube) + 0.5) as usize;
        let Some(x) = xs.get(step * sub) else { break };
        let set = sample.filtered_set().clone();
        let tol = tol(step);
        for (i, &xi) in x.iter().enumerate() {
            assert!(
                set.lower[i] - tol <= xi && xi <= set.upper[i] + tol,
                "{what}: at t = {} coordinate {i} = {} escapes [{}, {}] (tube from {:?})",
                sample.t,
                xi,
                set.lower[i],
                set.upper[i],
                tube.initial
            );
        }
        checks += 1;
    }
    checks
}

fn tube_dt(tube: &Tube) -> f64 {
    tube.tube.get(1).map_or(1.0, |s| s.t - tube.tube[0].t)
}

/// NN-system trajectories with the same Euler step as the embedding must lie in its boxes
/// exactly (the Euler embedding bounds the Euler map for these step sizes). Trajectories with a
/// ten times finer step (closer to the continuous system) may miss a box by no more than the
/// Euler error of the point simulation itself, `‖x_dt(t) − x_fine(t)‖∞`: that keeps the
/// step's error visible (README, Limitations) without hiding a wrong bound.
fn nn_trajectories_inside(s: &Scenario, net: &Mlp, centres: &[[f64; 2]], bounds: BoundMethod) {
    for face_local in [false, true] {
        nn_trajectories_inside_with(s, net, centres, bounds, face_local);
    }
}

fn nn_trajectories_inside_with(
    s: &Scenario,
    net: &Mlp,
    centres: &[[f64; 2]],
    bounds: BoundMethod,
    face_local: bool,
) {
    let tubes = run(s, face_local, net, 0.0, bounds, centres, 0.1);
    let dt = s.reach.dt;
    let steps = s.reach.steps();
    let mut checks = 0;
    for tube in &tubes {
        for x0 in sample_box(&tube.initial, 12, 7) {
            let same = integrate(
                |x: &[f64]| nn_field(s, net, x),
                &x0,
                dt,
                steps,
                Integrator::Euler,
            );
            checks += assert_inside(tube, &same.x, 1, |_| 1e-12, "same-step NN trajectory");
            let fine = integrate(
                |x: &[f64]| nn_field(s, net, x),
                &x0,
                dt / 10.0,
                steps * 10,
                Integrator::Euler,
            );
            let euler_error = |k: usize| {
                same.x[k]
                    .iter()
                    .zip(&fine.x[10 * k])
                    .map(|(a, b)| (a - b).abs())
                    .fold(0.0, f64::max)
                    + 1e-9
            };
            assert_inside(tube, &fine.x, 10, euler_error, "fine-step NN trajectory");
        }
    }
    assert!(checks > 100, "too few checks ({checks}): tubes died early?");
}

#[test]
fn nn_system_inside_embedding_boxes_scenario_1() {
    let s = integrator();
    let net = small_network(&[2, 16, 16, 2], 1, 0.2);
    for bounds in [
        BoundMethod::Crown,
        BoundMethod::CrownSameSlope,
        BoundMethod::Ibp,
    ] {
        nn_trajectories_inside(&s, &net, &[[-2.0, 2.0], [1.0, -2.0], [-3.0, 0.0]], bounds);
    }
}

#[test]
fn nn_system_inside_embedding_boxes_scenario_2() {
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 2, 0.2);
    nn_trajectories_inside(&s, &net, &[[-2.0, 1.0], [-1.0, -1.0]], BoundMethod::Crown);
}

#[test]
fn nn_system_inside_embedding_boxes_nonlinear_state_dependent_g() {
    // A damped pendulum-like system with state-dependent input gain: exercises the interval
    // Jacobian and the [g](box)·[N] path of the embedding.
    let text = r#"
name = "pendulum"
[system]
states = ["q", "w"]
inputs = ["u"]
f = ["w", "-sin(q) - 0.5*w"]
g = [["0"], ["1 + 0.2*cos(q)"]]
kappa = ["-q - w"]
[reach]
region = { lower = [-4, -4], upper = [4, 4] }
m_c = 0
dt = 0.02
horizon = 3
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
"#;
    let s = from_text(text).unwrap();
    let net = small_network(&[2, 16, 16, 1], 3, 0.2);
    nn_trajectories_inside(&s, &net, &[[1.0, 0.5], [-1.5, 0.0]], BoundMethod::Crown);
}

/// With v ≡ 0 on C (the CBF never acts there) and N a small perturbation, `M_C = sup_C |N|`
/// is certified by IBP over C; then every filtered trajectory must lie in the disturbance sets.
#[test]
fn filtered_system_inside_disturbance_sets_with_certified_margin() {
    let text = r#"
name = "inactive"
[system]
states = ["x1", "x2"]
inputs = ["u1", "u2"]
f = ["0", "0"]
g = [["1", "0"], ["0", "1"]]
kappa = ["-x1", "-5*x2"]
[[cbf]]
h = "100 - x1^2 - x2^2"
[reach]
region = { lower = [-3, -3], upper = [3, 3] }
m_c = 0
dt = 0.04
horizon = 4
goal = { lower = [-0.5, -0.5], upper = [0.5, 0.5] }
"#;
    let s = from_text(text).unwrap();
    let filter = SafetyFilter::new(&s);
    let net = small_network(&[2, 16, 16, 2], 4, 0.05);
    // sup_C |N| by IBP over a partition of C: a certified bound.
    let m_c = s
        .reach
        .region
        .partition(&[24, 24])
        .iter()
        .map(|cell| {
            let b = network_bounds(&net, &cell.lower, &cell.upper, BoundMethod::Ibp).unwrap();
            b.lower
                .iter()
                .chain(&b.upper)
                .fold(0.0_f64, |a, v| a.max(v.abs()))
        })
        .fold(0.0_f64, f64::max);
    assert!(m_c > 0.0 && m_c < 1.0, "M_C = {m_c}");
    let tubes = run(
        &s,
        true,
        &net,
        m_c,
        BoundMethod::Crown,
        &[[-2.0, 2.0], [2.0, -1.0]],
        0.1,
    );
    let mut checks = 0;
    for tube in &tubes {
        assert!(tube.valid(), "{:?}", tube.note());
        for x0 in sample_box(&tube.initial, 16, 9) {
            let t = simulate_filtered(&filter, &x0, s.reach.dt, s.reach.steps(), Integrator::Euler);
            checks += assert_inside(tube, &t.x, 1, |_| 1e-12, "filtered trajectory");
        }
    }
    assert!(checks > 1000);
    // The sets end near the origin and no wider than the disturbance allows (≈ 2M/rate).
    for tube in &tubes {
        let last = tube.last().unwrap();
        let set = last.filtered_set().clone();
        assert!(set.widths()[0] < 2.0 * m_c / 1.0 + 0.25, "{:?}", set);
    }
}

#[test]
fn leaving_c_marks_the_tube_invalid() {
    let s = integrator();
    // A strongly destabilising network pushes the box out of C.
    let mut net = small_network(&[2, 8, 2], 5, 0.0);
    net.layers[1].bias = vec![20.0, 0.0];
    let tubes = run(&s, false, &net, 0.0, BoundMethod::Ibp, &[[0.0, 0.0]], 0.1);
    assert!(!tubes[0].valid());
    assert!(tubes[0]
        .note()
        .as_deref()
        .unwrap_or_default()
        .contains("left the region C"));
}

#[test]
fn wrong_network_shape_is_an_error() {
    let s = integrator();
    let err = ReachProblem::new(&s, Mlp::random(&[2, 8, 1], 0), 0.1).unwrap_err();
    assert!(err.to_string().contains("ℝ^2 → ℝ^1"), "{err}");
}

/// Scenario 2's box at (5, 1) with its shipped network and certified error map: its sets reach
/// the velocity bound `x₂ ≥ −2` (also the lower edge of C) and are intersected with it
/// (src/reach/safe_set.rs). Ground-truth trajectories (Euler with a 10× finer step) stay in
/// the intersected sets at every step, up to the point simulation's own Euler error, and the
/// intersection does act: without it the set leaves C.
#[test]
fn filtered_trajectories_stay_in_sets_intersected_with_the_safe_set() {
    let s = double_integrator();
    let problem = common::shipped_problem(&s).with_time(TimeModel::Euler, 1);
    assert_eq!(problem.safe_set.x.len(), 1, "the velocity bound is affine");
    let settings = ReachSettings {
        bounds: BoundMethod::ForwardBackward,
        method: ReachMethod::Disturbance,
        every: 1,
        face_local: true,
        exact: ExactField::Nowhere,
        intersect_x: false,
        ..ReachSettings::default()
    };
    let initial = [cbfreach::IntervalBox::new(vec![4.9, 0.9], vec![5.1, 1.1]).unwrap()];
    let run = |problem: &ReachProblem| {
        CpuBackend
            .reach(problem, &initial, &settings, &|_, _| {})
            .unwrap()
            .boxes
            .remove(0)
    };
    let tube = run(&problem);
    let plain = run(&problem.clone().without_safe_set());
    assert!(
        matches!(plain.end, cbfreach::reach::TubeEnd::LeftRegion { .. }),
        "{:?}",
        plain.end
    );
    let at_edge = tube
        .tube
        .iter()
        .filter(|sample| sample.set.lower[1] == -2.0)
        .count();
    assert!(at_edge > 0, "the intersection never acted");
    // It goes on past the step where the plain set left C.
    assert!(
        tube.tube.len() > plain.tube.len(),
        "{} vs {} steps",
        tube.tube.len(),
        plain.tube.len()
    );

    let checks = filtered_trajectories_inside(&s, &tube, 12);
    assert!(checks > 500, "{checks} checks");
}

/// Scenario 2's network before certified training (README, Networks): its bounds are loose
/// (IBP 274× the sampled range over 0.1-wide boxes), which is where the engine's ingredients
/// show; the tests that show what each one adds use it.
fn loose_network() -> std::path::PathBuf {
    common::scenario_path("double-integrator-without-ibp.safetensors")
}

/// Asserts that ground-truth filtered trajectories from `samples` random starts in the tube's
/// initial box lie in its sets: exactly with the embedding's step `dt`, and up to the point
/// simulation's own Euler error with `dt/10`. Returns the number of (point, time) checks.
fn filtered_trajectories_inside(s: &Scenario, tube: &Tube, samples: usize) -> usize {
    let filter = SafetyFilter::new(s);
    let (dt, steps, sub) = (s.reach.dt, s.reach.steps(), 10);
    let mut checks = 0;
    for x0 in sample_box(&tube.initial, samples, 3) {
        let coarse = simulate_filtered(&filter, &x0, dt, steps, Integrator::Euler);
        let fine = simulate_filtered(
            &filter,
            &x0,
            dt / sub as f64,
            steps * sub,
            Integrator::Euler,
        );
        // The fine simulation's distance from the embedding's own (dt) Euler map.
        let euler_error = |k: usize| -> f64 {
            (0..=k)
                .map(|i| {
                    coarse.x[i]
                        .iter()
                        .zip(&fine.x[i * sub])
                        .fold(0.0_f64, |a, (p, q)| a.max((p - q).abs()))
                })
                .fold(0.0, f64::max)
        };
        checks += assert_inside(tube, &coarse.x, 1, |_| 0.0, "filtered trajectory (dt)");
        checks += assert_inside(
            tube,
            &fine.x,
            sub,
            euler_error,
            "filtered trajectory (dt/10)",
        );
    }
    checks
}

/// Where the filter is provably one smooth function on the set the engine integrates the
/// filtered system's own field (`v = 0` where inactive, the binding row's closed form met with
/// the network's bounds where one constraint binds): on both paper scenarios with their shipped
/// networks and error maps (and scenario 2's loose network), sets from boxes that pass through
/// the goal region and through the active region still contain the ground-truth filtered
/// trajectories. With the loose network, a box beside the goal of scenario 2 whose tube
/// diverges with the network's error margin there ends in the goal set with `v = 0`, and a box
/// that slides along the obstacle, lost with the network alone there, ends in the goal set
/// with the binding pieces; with the default network both end there too.
#[test]
fn filtered_trajectories_stay_in_sets_where_the_filter_is_one_smooth_piece() {
    let near_goal =
        cbfreach::IntervalBox::new(vec![0.1875, -0.3125], vec![0.25, -0.28125]).unwrap();
    let sliding = cbfreach::IntervalBox::new(vec![4.48, 1.48], vec![4.52, 1.52]).unwrap();
    let scenario_2_boxes = vec![
        near_goal.clone(),
        sliding.clone(),
        cbfreach::IntervalBox::new(vec![-1.1, -1.6], vec![-0.9, -1.4]).unwrap(),
    ];
    let (s2, s1) = (double_integrator(), integrator());
    for (s, problem, loose, initial) in [
        (
            &s2,
            common::shipped_problem(&s2).with_time(TimeModel::Euler, 1),
            false,
            scenario_2_boxes.clone(),
        ),
        (
            &s2,
            common::shipped_problem_with(&s2, &loose_network()).with_time(TimeModel::Euler, 1),
            true,
            scenario_2_boxes,
        ),
        (
            &s1,
            common::shipped_problem(&s1).with_time(TimeModel::Euler, 1),
            false,
            vec![
                cbfreach::IntervalBox::new(vec![-2.1, 1.9], vec![-1.9, 2.1]).unwrap(),
                cbfreach::IntervalBox::new(vec![0.9, 1.9], vec![1.1, 2.1]).unwrap(),
                cbfreach::IntervalBox::new(vec![3.4, -0.6], vec![3.5, -0.5]).unwrap(),
            ],
        ),
    ] {
        let run = |exact| {
            let settings = ReachSettings {
                bounds: BoundMethod::ForwardBackward,
                method: ReachMethod::Disturbance,
                every: 1,
                face_local: true,
                exact,
                intersect_x: false,
                ..ReachSettings::default()
            };
            CpuBackend
                .reach(&problem, &initial, &settings, &|_, _| {})
                .unwrap()
                .boxes
        };
        let plain = run(ExactField::Nowhere);
        let (inactive, pieces) = (run(ExactField::Inactive), run(ExactField::ClosedForm));
        let mut checks = 0;
        for (tubes, exact) in [
            (&inactive, ExactField::Inactive),
            (&pieces, ExactField::ClosedForm),
        ] {
            for (tube, before) in tubes.iter().zip(&plain) {
                assert!(
                    tube.valid() || !before.valid(),
                    "{} {exact:?}: {:?}",
                    s.name,
                    tube.note()
                );
                checks += filtered_trajectories_inside(s, tube, 8);
            }
        }
        assert!(checks > 2000, "{}: {checks} checks", s.name);
        assert!(plain
            .iter()
            .all(|t| t.exact_steps == 0 && t.enclosed_steps == 0));
        assert!(inactive.iter().all(|t| t.enclosed_steps == 0));
        // Some sets straddle a switch of the filter: their steps took the enclosures of `v`.
        assert!(pieces.iter().any(|t| t.enclosed_steps > 0), "{}", s.name);
        for (k, (a, b)) in inactive.iter().zip(&pieces).enumerate() {
            assert!(b.exact_steps >= a.exact_steps, "{} box {k}", s.name);
        }
        let ends_in_goal =
            |t: &Tube| t.valid() && t.last().unwrap().filtered_set().is_subset_of(&s.reach.goal);
        // Scenario 2: the box beside the goal and the sliding box end in the goal set.
        if initial[0] == near_goal {
            assert!(ends_in_goal(&pieces[0]), "{:?}", pieces[0].note());
            assert!(ends_in_goal(&pieces[1]), "{:?}", pieces[1].note());
            // With the loose network, only thanks to the filter's own field.
            if loose {
                assert!(ends_in_goal(&inactive[0]));
                assert!(
                    !plain[0].valid(),
                    "the network's margin alone already converges"
                );
                assert!(inactive[0].exact_steps > 0);
                assert!(
                    !inactive[1].valid(),
                    "the network alone already verifies the sliding box"
                );
                assert!(pieces[1].exact_steps > inactive[1].exact_steps);
            }
        }
    }
}

/// Sets kept as the meet of a box in x and the parallelotope of the transform
/// (`intersect_x`): on scenario 2 with its shipped network and error map (and with its loose
/// network), ground-truth filtered trajectories lie in the recorded x-boxes (with `dt`, and
/// with `dt/10` up to its Euler error) and their `z = T x` in the recorded z-boxes; every
/// recorded set is within the parallelotope's own x-box; and a 0.00625-wide box at (0.9, 1.4)
/// ends in the goal set, where with the loose network the parallelotope alone wraps while it
/// turns over the obstacle until it meets the jump of `v` near (3, 0). Without a transform the
/// setting changes nothing.
#[test]
fn filtered_trajectories_stay_in_sets_met_with_their_x_boxes() {
    let s = double_integrator();
    for loose in [false, true] {
        let problem = if loose {
            common::shipped_problem_with(&s, &loose_network()).with_time(TimeModel::Euler, 1)
        } else {
            common::shipped_problem(&s).with_time(TimeModel::Euler, 1)
        };
        sets_met_with_x_boxes_hold_and_turn(&s, &problem, loose);
    }
}

fn sets_met_with_x_boxes_hold_and_turn(s: &Scenario, problem: &ReachProblem, loose: bool) {
    let turning = cbfreach::IntervalBox::new(vec![0.9, 1.4], vec![0.90625, 1.40625]).unwrap();
    let initial = vec![
        turning.clone(),
        cbfreach::IntervalBox::new(vec![4.48, 1.48], vec![4.52, 1.52]).unwrap(),
        cbfreach::IntervalBox::new(vec![-1.1, -1.6], vec![-0.9, -1.4]).unwrap(),
        cbfreach::IntervalBox::new(vec![-3.02, 0.98], vec![-2.98, 1.02]).unwrap(),
    ];
    let run = |problem: &ReachProblem, intersect_x| {
        let settings = ReachSettings {
            bounds: BoundMethod::ForwardBackward,
            method: ReachMethod::Disturbance,
            every: 1,
            face_local: true,
            exact: ExactField::ClosedForm,
            intersect_x,
            ..ReachSettings::default()
        };
        CpuBackend
            .reach(problem, &initial, &settings, &|_, _| {})
            .unwrap()
            .boxes
    };
    let (alone, met) = (run(problem, false), run(problem, true));
    let t = problem.transform.as_ref().unwrap();
    let mut checks = 0;
    for (tube, plain) in met.iter().zip(&alone) {
        checks += filtered_trajectories_inside(s, tube, 8);
        let filter = SafetyFilter::new(s);
        for x0 in sample_box(&tube.initial, 8, 5) {
            let xs =
                simulate_filtered(&filter, &x0, s.reach.dt, s.reach.steps(), Integrator::Euler).x;
            for sample in &tube.tube {
                let step = (sample.t / s.reach.dt + 0.5) as usize;
                let Some(x) = xs.get(step) else { break };
                let (lo, hi) = (
                    sample.z_lower.as_ref().unwrap(),
                    sample.z_upper.as_ref().unwrap(),
                );
                for i in 0..2 {
                    let z = t.t[2 * i] * x[0] + t.t[2 * i + 1] * x[1];
                    assert!(
                        lo[i] - 1e-9 <= z && z <= hi[i] + 1e-9,
                        "t = {}: z{i} = {z} escapes [{}, {}] (tube from {:?})",
                        sample.t,
                        lo[i],
                        hi[i],
                        tube.initial
                    );
                }
                checks += 1;
            }
        }
        for sample in &tube.tube {
            let (lo, hi) = (
                sample.z_lower.as_ref().unwrap(),
                sample.z_upper.as_ref().unwrap(),
            );
            assert!(
                sample.set.is_subset_of(&t.to_x_box(lo, hi)),
                "t = {}",
                sample.t
            );
        }
        assert!(tube.valid() || !plain.valid(), "{:?}", tube.note());
    }
    assert!(checks > 3000, "{checks} checks");
    let ends_in_goal =
        |t: &Tube| t.valid() && t.last().unwrap().filtered_set().is_subset_of(&s.reach.goal);
    assert_eq!(initial[0], turning);
    assert!(
        !loose || !alone[0].valid(),
        "the parallelotope alone already verifies the turning box"
    );
    assert!(ends_in_goal(&met[0]), "{:?}", met[0].note());

    // Without a transform there is one frame: the same tubes.
    let plain = problem.in_x.as_deref().unwrap();
    assert!(plain.transform.is_none() && plain.in_x.is_none());
    let (a, b) = (run(plain, false), run(plain, true));
    for (a, b) in a.iter().zip(&b) {
        assert_eq!(a.tube.len(), b.tube.len());
        for (p, q) in a.tube.iter().zip(&b.tube) {
            assert_eq!((&p.lower, &p.upper), (&q.lower, &q.upper));
        }
    }
}

/// How the CPU engine splits boxes over threads (chunks integrated over the whole horizon,
/// each with its own buffers) does not change the sets: one thread and three threads give
/// the same tubes up to the products' summation order, with boxes that leave `C` early in
/// some chunks and face-local bounds (2n rows per box) in the mix; and the progress reports
/// end at the horizon.
#[test]
fn tubes_do_not_depend_on_the_thread_count() {
    let s = integrator();
    // A push to the right: boxes on the right of C leave it early, the others stay.
    let mut net = small_network(&[2, 16, 16, 2], 3, 0.5);
    net.layers[2].bias[0] += 5.0;
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = problem.steps.min(60);
    let boxes: Vec<_> = (0..23)
        .map(|k| {
            let c = [-3.4 + 0.35 * k as f64, 2.9 - 0.26 * k as f64];
            cbfreach::IntervalBox::new(
                c.iter().map(|v| v - 0.05).collect(),
                c.iter().map(|v| v + 0.05).collect(),
            )
            .unwrap()
        })
        .collect();
    for face_local in [false, true] {
        let settings = ReachSettings {
            bounds: BoundMethod::Forward,
            method: ReachMethod::Disturbance,
            every: 7,
            face_local,
            exact: ExactField::Nowhere,
            intersect_x: false,
            ..ReachSettings::default()
        };
        let run_on = |threads: usize| {
            let last = std::sync::atomic::AtomicUsize::new(0);
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            let tubes = pool.install(|| {
                CpuBackend
                    .reach(&problem, &boxes, &settings, &|done, total| {
                        assert_eq!(total, problem.steps);
                        last.fetch_max(done, std::sync::atomic::Ordering::Relaxed);
                    })
                    .unwrap()
                    .boxes
            });
            assert_eq!(
                last.into_inner(),
                problem.steps,
                "progress ends at the horizon"
            );
            tubes
        };
        let (one, three) = (run_on(1), run_on(3));
        let invalid = one.iter().filter(|t| !t.valid()).count();
        assert!(
            invalid > 0 && invalid < boxes.len(),
            "the case should mix boxes that stay in C with boxes that leave it ({invalid})"
        );
        for (k, (a, b)) in one.iter().zip(&three).enumerate() {
            assert_eq!((a.valid(), &a.note()), (b.valid(), &b.note()), "box {k}");
            assert_eq!(a.tube.len(), b.tube.len(), "box {k}");
            for (p, q) in a.tube.iter().zip(&b.tube) {
                assert_eq!(p.t, q.t);
                let (ps, qs) = (
                    p.lower.iter().chain(&p.upper),
                    q.lower.iter().chain(&q.upper),
                );
                for (x, y) in ps.zip(qs) {
                    assert!(
                        (x - y).abs() <= 1e-9 * (1.0 + x.abs()),
                        "box {k}: {x} vs {y}"
                    );
                }
            }
        }
    }
}

/// A nominal controller that cancels the drift (feedback linearisation) gives the sets of the
/// closed loop it makes: a Van der Pol oscillator with `κ` cancelling `(1 − x₁²)x₂` has the
/// same Euler sets as the linear system `ẋ₁ = x₂, ẋ₂ = −x₁ − 2x₂` written out (f̃'s like terms
/// collected, docs/design.md §2.3), and they hold the network's closed loop. With both copies
/// of the cancelled term in `f̃`, the sets part from the linear system's at the first step.
#[test]
fn a_controller_that_cancels_the_drift_gives_the_closed_loops_own_sets() {
    let vdp = common::fixture_with("vdp.toml", &[]);
    let linear = common::fixture_with(
        "vdp.toml",
        &[
            ("(1 - x1^2)*x2 - x1", "-x1 - 2*x2"),
            ("-x1 - 2*x2 - (1 - x1^2)*x2 + x1", "0"),
        ],
    );
    let net = small_network(&[2, 16, 16, 1], 3, 0.05);
    let centres = [[-1.1, 1.6], [0.5, -0.5], [0.8, -0.3]];
    for face_local in [false, true] {
        let run_on = |s: &Scenario| {
            run(
                s,
                face_local,
                &net,
                0.02,
                BoundMethod::ForwardBackward,
                &centres,
                0.1,
            )
        };
        let (a, b) = (run_on(&vdp), run_on(&linear));
        for (ta, tb) in a.iter().zip(&b) {
            assert_eq!(ta.tube.len(), tb.tube.len());
            for (sa, sb) in ta.tube.iter().zip(&tb.tube) {
                for i in 0..2 {
                    let scale = 1e-9 * (1.0 + sb.upper[i].abs());
                    assert!(
                        (sa.lower[i] - sb.lower[i]).abs() < scale
                            && (sa.upper[i] - sb.upper[i]).abs() < scale,
                        "face-local {face_local}, t = {}: {:?}…{:?} against {:?}…{:?}",
                        sa.t,
                        sa.lower,
                        sa.upper,
                        sb.lower,
                        sb.upper
                    );
                }
            }
        }
        // The network's closed loop of the oscillator itself (its f̃ as written, point by
        // point: the cancelled terms cancel up to rounding) stays in the sets.
        let field = |x: &[f64]| -> Result<Vec<f64>, String> {
            let u = -x[0] - 2.0 * x[1] - (1.0 - x[0] * x[0]) * x[1] + x[0] + net.forward(x)[0];
            Ok(vec![x[1], (1.0 - x[0] * x[0]) * x[1] - x[0] + u])
        };
        let mut checks = 0;
        for tube in &a {
            for start in tube.initial.corners() {
                let traj = integrate(field, &start, 0.02, 50, Integrator::Euler);
                checks += assert_inside(tube, &traj.x, 1, |_| 1e-9, "vdp");
            }
        }
        assert!(checks > 300, "{checks}");
    }
}

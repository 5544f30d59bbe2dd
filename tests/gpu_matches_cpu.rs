//! The GPU engine against the CPU reference (issues 3 and "GPU engine"), on whatever Vulkan
//! adapter exists (lavapipe in CI). Without an adapter the tests skip with a message, unless
//! `CBFREACH_REQUIRE_GPU=1`, where a missing adapter (or one without f64 shaders, for the f64
//! tests) fails.
//!
//! Every bound method the GPU runs (forward, forward-backward, crown, each relaxation) is
//! checked in f64 against the CPU to `REL_TOL`, in f32 to contain the CPU's sets and be at most
//! `F32_FACTOR` wider, and in both for containing sampled NN-system trajectories. Face-local
//! bounds and local error margins (an error map with a +∞ cell, and the shipped map) are
//! checked in f64 to `F64_TOL`.

#![allow(clippy::needless_range_loop)] // index loops read as the formulas

mod common;

use cbfreach::reach::TimeModel;

use std::sync::Arc;

use cbfreach::bounds::BoundMethod;
use cbfreach::gpu::{GpuBackend, GpuContext, Precision};
use cbfreach::network::{Layer, Mlp};
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, Transform, Tube,
};
use cbfreach::scenario::{Scenario, TransformChoice};
use cbfreach::simulate::{integrate, sample_box, Integrator};
use cbfreach::IntervalBox;
use common::{double_integrator, integrator};

/// Relative agreement of GPU (f32 widened, or f64) and CPU (f64) tubes.
const REL_TOL: f64 = 1e-4;

/// The bound methods with a backward pass (the new GPU methods).
const BACKWARD_METHODS: [BoundMethod; 4] = [
    BoundMethod::ForwardBackward,
    BoundMethod::ForwardBackwardSameSlope,
    BoundMethod::Crown,
    BoundMethod::CrownSameSlope,
];

/// In f32 a GPU set may be wider than the CPU's by this fraction of its scale `max(1, |x|)`
/// (the rigorous f32 rounding bounds, measured ≲ 1e-4 on these networks).
const F32_FACTOR: f64 = 1e-3;

/// f32 with sin and cos (WGSL: 2⁻¹¹ absolute accuracy, widened by that every step).
const F32_TRIG: f64 = 2e-3;

fn require_gpu() -> bool {
    std::env::var("CBFREACH_REQUIRE_GPU").as_deref() == Ok("1")
}

fn gpu() -> Option<GpuBackend> {
    match GpuContext::new() {
        Ok(ctx) => {
            eprintln!("GPU adapter: {}", ctx.describe());
            Some(GpuBackend::with_precision(Arc::new(ctx), Precision::F32).unwrap())
        }
        Err(e) => {
            if require_gpu() {
                panic!("CBFREACH_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("skipping GPU test: {e}");
            None
        }
    }
}

/// The f64 engine, when the adapter has f64 shaders (lavapipe and NVIDIA do).
fn gpu_f64() -> Option<GpuBackend> {
    let ctx = match GpuContext::new() {
        Ok(ctx) => Arc::new(ctx),
        Err(e) => {
            if require_gpu() {
                panic!("CBFREACH_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("skipping GPU test: {e}");
            return None;
        }
    };
    match GpuBackend::with_precision(ctx, Precision::F64) {
        Ok(g) => Some(g),
        Err(e) => {
            if require_gpu() {
                panic!("CBFREACH_REQUIRE_GPU=1 but {e}");
            }
            eprintln!("skipping f64 GPU test: {e}");
            None
        }
    }
}

fn small_network(widths: &[usize], seed: u64, scale: f64) -> Mlp {
    let mut net = Mlp::random(widths, seed);
    if let Some(last) = net.layers.last_mut() {
        last.weight.iter_mut().for_each(|w| *w *= scale);
        last.bias.iter_mut().for_each(|b| *b *= scale);
    }
    net
}

fn boxes(centres: &[[f64; 2]], half: f64) -> Vec<IntervalBox> {
    centres
        .iter()
        .map(|c| {
            IntervalBox::new(
                c.iter().map(|v| v - half).collect(),
                c.iter().map(|v| v + half).collect(),
            )
            .unwrap()
        })
        .collect()
}

fn settings(method: ReachMethod) -> ReachSettings {
    with_bounds(BoundMethod::Forward, method)
}

fn with_bounds(bounds: BoundMethod, method: ReachMethod) -> ReachSettings {
    ReachSettings {
        bounds,
        method,
        every: 1,
        face_local: false,
        // The GPU engine bounds the network everywhere: compare like with like.
        exact: ExactField::Nowhere,
        intersect_x: false,
    }
}

/// Largest relative difference between two runs' sets (and their radii), where both are valid;
/// fails above `REL_TOL`.
fn compare(cpu: &[Tube], gpu: &[Tube], what: &str) -> f64 {
    compare_within(cpu, gpu, what, REL_TOL)
}

/// As [`compare`], failing above `tol`.
fn compare_within(cpu: &[Tube], gpu: &[Tube], what: &str, tol: f64) -> f64 {
    assert_eq!(cpu.len(), gpu.len());
    let mut worst = 0.0f64;
    for (k, (a, b)) in cpu.iter().zip(gpu).enumerate() {
        assert_eq!(
            a.valid(),
            b.valid(),
            "{what} box {k}: validity {:?} vs {:?}",
            a.note(),
            b.note()
        );
        assert_eq!(a.tube.len(), b.tube.len(), "{what} box {k}: samples");
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            assert!((sa.t - sb.t).abs() < 1e-12);
            let pairs = sa
                .set
                .lower
                .iter()
                .zip(&sb.set.lower)
                .chain(sa.set.upper.iter().zip(&sb.set.upper))
                .chain(sa.lower.iter().zip(&sb.lower))
                .chain(sa.upper.iter().zip(&sb.upper));
            for (x, y) in pairs {
                let rel = (x - y).abs() / x.abs().max(1.0);
                worst = worst.max(rel);
                assert!(
                    rel <= tol,
                    "{what} box {k} t = {}: cpu {x} gpu {y} (relative {rel:.2e})",
                    sa.t
                );
            }
            let rel = (sa.radius - sb.radius).abs() / sa.radius.abs().max(1.0);
            assert!(
                rel <= tol,
                "{what} box {k} t = {}: radius {} vs {}",
                sa.t,
                sa.radius,
                sb.radius
            );
        }
    }
    eprintln!("{what}: worst relative difference {worst:.2e}");
    worst
}

fn run_both(
    gpu: &GpuBackend,
    problem: &ReachProblem,
    initial: &[IntervalBox],
    method: ReachMethod,
) -> (Vec<Tube>, Vec<Tube>) {
    run_both_with(gpu, problem, initial, &settings(method))
}

fn run_both_with(
    gpu: &GpuBackend,
    problem: &ReachProblem,
    initial: &[IntervalBox],
    s: &ReachSettings,
) -> (Vec<Tube>, Vec<Tube>) {
    let s = s.clone();
    let cpu = CpuBackend.reach(problem, initial, &s, &|_, _| {}).unwrap();
    let g = gpu.reach(problem, initial, &s, &|_, _| {}).unwrap();
    eprintln!(
        "{} bounds, {} boxes × {} steps: cpu {:.3} s, gpu {:.3} s",
        s.bounds,
        initial.len(),
        problem.steps,
        cpu.timing.reach_s,
        g.timing.reach_s
    );
    (cpu.boxes, g.boxes)
}

#[test]
fn scenario_1_small_network_matches_cpu() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 16, 16, 2], 1, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 60;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [-3.0, 0.0], [3.5, 2.0]], 0.1);
    for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
        let (c, g) = run_both(&gpu, &problem, &init, method);
        compare(&c, &g, &format!("scenario 1 {method:?}"));
    }
}

/// One engine reuses its compiled pipelines while the problem's generated WGSL is unchanged and
/// compiles anew when it changes: a stale pipeline (the previous `M_C`, baked into the WGSL)
/// would make the second problem's sets differ from the CPU's, and a repeat must give the same
/// sets bit for bit.
#[test]
fn pipelines_are_reused_only_for_the_same_problem() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0]], 0.1);
    let mut runs = Vec::new();
    for m_c in [0.05, 0.2, 0.05] {
        let net = small_network(&[2, 16, 16, 2], 1, 0.05);
        let mut problem = ReachProblem::new(&s, net, m_c)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 30;
        let (c, g) = run_both(&gpu, &problem, &init, ReachMethod::Disturbance);
        compare(&c, &g, &format!("M_C = {m_c}"));
        runs.push(g);
    }
    let widest = |tubes: &[Tube]| tubes[0].tube.last().unwrap().set.widths()[0];
    assert!(widest(&runs[1]) > widest(&runs[0]) + 0.1);
    for (a, b) in runs[0].iter().zip(&runs[2]) {
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            assert_eq!(sa.set, sb.set);
        }
    }
}

#[test]
fn scenario_2_small_network_matches_cpu_with_and_without_transform() {
    let Some(gpu) = gpu() else { return };
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 2, 0.05);
    // The last box is driven into the velocity bound x₂ ≥ −2 (κ < 0 there), where the
    // disturbance method's sets are intersected with it: a constant bound in x, a computed one
    // in z with the transform (src/reach/safe_set.rs, shaders/embed.wgsl).
    let init = boxes(&[[-1.0, 0.5], [3.0, -1.0], [0.5, 1.0], [5.0, -1.85]], 0.05);
    for transform in [
        None,
        Transform::for_scenario(&s, &TransformChoice::Auto).unwrap(),
    ] {
        let with = transform.is_some();
        let mut problem = ReachProblem::with_transform(&s, net.clone(), 0.02, transform)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 60;
        for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
            let (c, g) = run_both(&gpu, &problem, &init, method);
            compare(&c, &g, &format!("scenario 2 transform {with} {method:?}"));
            let at_edge = |t: &Tube| t.tube.iter().any(|x| x.set.lower[1] == -2.0);
            if method == ReachMethod::Disturbance {
                assert!(at_edge(&c[3]) && at_edge(&g[3]), "transform {with}");
            } else {
                assert!(
                    !c[3].valid() && !g[3].valid(),
                    "transform {with}: {:?}",
                    c[3].note()
                );
            }
        }
    }
}

#[test]
fn paper_size_network_end_to_end() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 400, 400, 400, 2], 3, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.1)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 5;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.0, 1.5]], 0.02);
    for bounds in [BoundMethod::Forward, BoundMethod::ForwardBackward] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        // f32's rigorous rounding bound grows with Σ|W||a| over 400-wide layers: the GPU's sets
        // are wider than the CPU's f64 ones by more than REL_TOL here. Check that they contain
        // the CPU's (up to REL_TOL) and measure the excess.
        let mut excess = 0.0f64;
        for (k, (a, b)) in c.iter().zip(&g).enumerate() {
            assert_eq!(a.valid(), b.valid());
            for (sa, sb) in a.tube.iter().zip(&b.tube) {
                for i in 0..2 {
                    let scale = sa.set.lower[i].abs().max(sa.set.upper[i].abs()).max(1.0);
                    assert!(
                        sb.set.lower[i] <= sa.set.lower[i] + REL_TOL * scale
                            && sa.set.upper[i] <= sb.set.upper[i] + REL_TOL * scale,
                        "{bounds} box {k} t = {}: gpu {:?} does not contain cpu {:?}",
                        sa.t,
                        sb.set,
                        sa.set
                    );
                    let (wa, wb) = (
                        sa.set.upper[i] - sa.set.lower[i],
                        sb.set.upper[i] - sb.set.lower[i],
                    );
                    excess = excess.max((wb - wa) / scale);
                }
            }
        }
        eprintln!(
            "2×400×400×400×2 {bounds}: the GPU's f32 sets are wider by up to {excess:.2e} \
             (relative)"
        );
        assert!(excess < 0.05, "{bounds}: f32 widening too large: {excess}");
    }
}

/// NN-system trajectories (same Euler step) lie in the GPU's boxes, for every bound method the
/// GPU runs, in f32 and f64.
#[test]
fn gpu_sets_contain_nn_trajectories() {
    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    for (s, net) in [
        (integrator(), small_network(&[2, 16, 16, 2], 4, 0.2)),
        (double_integrator(), small_network(&[2, 16, 16, 1], 5, 0.2)),
    ] {
        let mut problem = ReachProblem::new(&s, net.clone(), 0.0)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 60;
        let init = boxes(&[[-2.0, 1.0], [1.0, -1.0], [-3.0, 0.0]], 0.1);
        let trajectories = nn_trajectories(&s, &net, &init, problem.dt, problem.steps, 0.0);
        for gpu in &engines {
            for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
                let st = with_bounds(bounds, ReachMethod::Disturbance);
                let tubes = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
                let label = format!("{} {bounds} {:?}", s.file, gpu.precision());
                let checks = count_contained(&tubes, &trajectories, problem.dt, &label);
                assert!(checks > 1000, "{bounds}: too few checks: {checks}");
            }
        }
    }
}

/// Euler trajectories of the NN system from 12 sampled points of each box, plus a constant
/// `±w` on each component of the field, its signs fixed per trajectory (the input disturbance
/// of the disturbance method where `g = I`; `w = 0`: none).
fn nn_trajectories(
    s: &Scenario,
    net: &Mlp,
    init: &[IntervalBox],
    dt: f64,
    steps: usize,
    w: f64,
) -> Vec<Vec<Vec<Vec<f64>>>> {
    init.iter()
        .map(|b| {
            sample_box(b, 12, 7)
                .into_iter()
                .enumerate()
                .map(|(k, x0)| {
                    let sign = [
                        if k % 2 == 0 { w } else { -w },
                        if k % 3 == 0 { w } else { -w },
                    ];
                    integrate(
                        |x: &[f64]| {
                            let mut f = nn_field(s, net, x);
                            f.iter_mut().zip(sign).for_each(|(v, d)| *v += d);
                            Ok::<_, String>(f)
                        },
                        &x0,
                        dt,
                        steps,
                        Integrator::Euler,
                    )
                    .x
                })
                .collect()
        })
        .collect()
}

fn nn_field(s: &Scenario, net: &Mlp, x: &[f64]) -> Vec<f64> {
    let (n, m) = (s.n(), s.m());
    let f = s.f_tilde_at(x);
    let g = s.g_at(x);
    let u = net.forward(x);
    (0..n)
        .map(|i| f[i] + (0..m).map(|k| g[i * m + k] * u[k]).sum::<f64>())
        .collect()
}

/// 65,536 boxes run (split into chunks when the limits ask for it, and when forced to).
#[test]
fn batch_of_65536_boxes_runs_and_splits() {
    let Some(mut gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 32, 32, 2], 6, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 3;
    let n = 65_536;
    let centres: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let (i, j) = ((k % 256) as f64, (k / 256) as f64);
            [-3.0 + 7.0 * i / 255.0, -2.5 + 5.0 * j / 255.0]
        })
        .collect();
    let init = boxes(&centres, 0.01);
    let st = settings(ReachMethod::Disturbance);
    for max_chunk in [None, Some(20_000)] {
        gpu.max_chunk = max_chunk;
        eprintln!("chunk size {}", gpu.chunk_size(&problem, &st, n));
        let t = std::time::Instant::now();
        let g = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        eprintln!(
            "{n} boxes × 3 steps on the GPU in {:.2} s ({:.0} box-steps/s)",
            t.elapsed().as_secs_f64(),
            3.0 * n as f64 / t.elapsed().as_secs_f64()
        );
        assert_eq!(g.boxes.len(), n);
        let picks: Vec<usize> = vec![0, 1, 19_999, 20_000, 40_001, n - 1];
        let sub: Vec<IntervalBox> = picks.iter().map(|&k| init[k].clone()).collect();
        let c = CpuBackend.reach(&problem, &sub, &st, &|_, _| {}).unwrap();
        let gsub: Vec<Tube> = picks.iter().map(|&k| g.boxes[k].clone()).collect();
        compare(&c.boxes, &gsub, "65,536 boxes");
    }
}

/// Both paper scenarios with small networks, `steps` Euler steps each, and a few initial boxes:
/// scenario 1 in x, scenario 2 in the automatic coordinates `z = T x`.
fn paper_problems(steps: usize) -> [(ReachProblem, Vec<IntervalBox>); 2] {
    let s1 = integrator();
    let mut p1 = ReachProblem::new(&s1, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p1.steps = steps;
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let mut p2 =
        ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 2, 0.05), 0.02, t)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
    p2.steps = steps;
    [
        (p1, boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.5, 2.0]], 0.1)),
        (p2, boxes(&[[-1.0, 0.5], [0.5, 1.0]], 0.05)),
    ]
}

/// Forward-backward and crown (both relaxations) on the GPU in f64 agree with the CPU to
/// `REL_TOL`, on both paper scenarios (with the transform and the Minkowski method once).
#[test]
fn backward_methods_match_cpu_in_f64() {
    let Some(gpu) = gpu_f64() else { return };
    let [(p1, init1), (p2, init2)] = paper_problems(40);
    let mut worst = Vec::new();
    for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
        let mut w = 0.0f64;
        for (problem, init, method) in [
            (&p1, &init1, ReachMethod::Disturbance),
            (&p2, &init2, ReachMethod::Disturbance),
            (&p1, &init1, ReachMethod::Minkowski),
        ] {
            let st = with_bounds(bounds, method);
            let (c, g) = run_both_with(&gpu, problem, init, &st);
            w = w.max(compare(&c, &g, &format!("f64 {bounds} {method:?}")));
        }
        worst.push((bounds, w));
    }
    eprintln!("f64 GPU vs CPU, worst relative difference per method: {worst:?}");
}

/// In f32 the same runs stay within `F32_FACTOR` of the CPU's f64 sets.
#[test]
fn backward_methods_close_to_cpu_in_f32() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 40;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.5, 2.0]], 0.1);
    let mut worst = Vec::new();
    for bounds in BACKWARD_METHODS {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        let w = compare_within(&c, &g, &format!("f32 {bounds}"), F32_FACTOR);
        worst.push((bounds, w));
    }
    eprintln!("f32 GPU vs CPU, worst relative difference per method: {worst:?}");
}

/// The shipped 2×400×400×400×2 network of scenario 1, forward-backward on the GPU in f64:
/// end to end, agreeing with the CPU to `REL_TOL` (and crown-same-slope for one step).
#[test]
fn paper_network_forward_backward_f64_matches_cpu() {
    let Some(gpu) = gpu_f64() else { return };
    let s = integrator();
    let path = common::scenario_path("integrator.safetensors");
    let net = Mlp::load_safetensors(&path).unwrap();
    assert_eq!(net.widths(), vec![2, 400, 400, 400, 2]);
    let mut problem = ReachProblem::new(&s, net, 0.19)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 4;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.0, 1.5]], 0.05);
    for bounds in [
        BoundMethod::ForwardBackward,
        BoundMethod::ForwardBackwardSameSlope,
    ] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        compare(&c, &g, &format!("2×400³×2 f64 {bounds}"));
    }
    problem.steps = 1;
    let st = with_bounds(BoundMethod::CrownSameSlope, ReachMethod::Disturbance);
    let (c, g) = run_both_with(&gpu, &problem, &init[..1], &st);
    compare(&c, &g, "2×400³×2 f64 crown-same-slope");
}

/// Nonlinear dynamics with every transcendental built-in: f64 (sin, cos as polynomials, exp,
/// ln, sqrt in f32 widened by the WGSL accuracy) agrees with the CPU to `REL_TOL`; f32 within
/// `F32_TRIG`, as WGSL promises sin and cos only to 2⁻¹¹ absolute.
#[test]
fn transcendental_dynamics_match_cpu() {
    let Some(gpu32) = gpu() else { return };
    let text = common::SMALL.replace(
        r#"f = ["y", "-x"]"#,
        r#"f = ["y + 0.1*tanh(x) - 0.05*sqrt(1 + x^2)", "-sin(x) + 0.1*cos(y) + 0.05*exp(-x*x) - 0.02*ln(2 + y)"]"#,
    );
    assert_ne!(text, common::SMALL);
    let s = common::from_text(&text).unwrap();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 8, 8, 1], 9, 0.1), 0.02)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 15;
    let init = boxes(&[[-0.3, 0.2], [0.4, -0.1]], 0.05);
    for bounds in [BoundMethod::Forward, BoundMethod::ForwardBackward] {
        for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
            let st = with_bounds(bounds, method);
            let (c, g) = run_both_with(&gpu32, &problem, &init, &st);
            compare_within(&c, &g, &format!("f32 {bounds} {method:?}"), F32_TRIG);
            if let Some(gpu64) = gpu_f64() {
                let (c, g) = run_both_with(&gpu64, &problem, &init, &st);
                compare(&c, &g, &format!("f64 {bounds} {method:?}"));
            }
        }
    }
    // The NN system's trajectories (M = 0) stay in the f32 sets.
    problem.m_c = 0.0;
    let st = with_bounds(BoundMethod::ForwardBackward, ReachMethod::Disturbance);
    let tubes = gpu32.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
    let mut checks = 0;
    for tube in &tubes {
        for x0 in sample_box(&tube.initial, 16, 3) {
            let traj = integrate(
                |x: &[f64]| Ok::<_, String>(nn_field(&s, &problem.network, x)),
                &x0,
                problem.dt,
                problem.steps,
                Integrator::Euler,
            );
            for sample in &tube.tube {
                let x = &traj.x[(sample.t / problem.dt).round() as usize];
                for i in 0..2 {
                    assert!(sample.set.lower[i] <= x[i] && x[i] <= sample.set.upper[i]);
                }
                checks += 1;
            }
        }
    }
    assert!(checks > 300, "too few checks: {checks}");
}

/// Forward-backward and crown batches split into chunks give the same tubes as one chunk (the
/// Λ, β, record buffers are shared by the chunks), with or without the profile runs.
#[test]
fn backward_methods_split_into_chunks() {
    let Some(mut gpu) = gpu_f64() else { return };
    let s = integrator();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 24, 24, 2], 6, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 3;
    let centres: Vec<[f64; 2]> = (0..300)
        .map(|k| {
            let (i, j) = ((k % 20) as f64, (k / 20) as f64);
            [-3.0 + 7.0 * i / 19.0, -2.5 + 5.0 * j / 14.0]
        })
        .collect();
    let init = boxes(&centres, 0.02);
    for bounds in [BoundMethod::ForwardBackward, BoundMethod::Crown] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let whole = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        gpu.max_chunk = Some(128);
        assert_eq!(gpu.chunk_size(&problem, &st, init.len()), 128);
        let split = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        // `bench --profile` re-runs each chunk's dispatches over its buffers after the
        // readback: neither that chunk's results nor the next chunk may see any of it.
        gpu.profile = true;
        let profiled = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        gpu.profile = false;
        gpu.max_chunk = None;
        compare_within(&whole, &split, &format!("{bounds} split"), 1e-12);
        compare_within(&split, &profiled, &format!("{bounds} profiled"), 0.0);
        let picks = [0usize, 127, 128, 255, 256, 299];
        let sub: Vec<IntervalBox> = picks.iter().map(|&k| init[k].clone()).collect();
        let c = CpuBackend.reach(&problem, &sub, &st, &|_, _| {}).unwrap();
        let gsub: Vec<Tube> = picks.iter().map(|&k| split[k].clone()).collect();
        compare(&c.boxes, &gsub, &format!("{bounds} split vs cpu"));
    }
}

/// Box-steps per second, CPU and GPU side by side (forward bounds, scenario 1, 2×400³×2).
/// `cargo test --release --test gpu_matches_cpu -- --ignored --nocapture`
#[test]
#[ignore]
fn bench_box_steps_per_second() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 400, 400, 400, 2], 7, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.1)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let widths = problem.network.widths();
    let pairs: f64 = widths.windows(2).map(|w| (w[0] * w[1]) as f64).sum();
    let flop = 2.0 * (2.0 * 3.0 + 1.0) * pairs;
    for (n_boxes, steps) in [(64usize, 10usize), (1024, 5), (4096, 3)] {
        problem.steps = steps;
        let centres: Vec<[f64; 2]> = (0..n_boxes)
            .map(|k| {
                [
                    -3.0 + 6.0 * (k % 64) as f64 / 63.0,
                    -2.0 + 4.0 * (k / 64) as f64 / 64.0,
                ]
            })
            .collect();
        let init = boxes(&centres, 0.01);
        let st = settings(ReachMethod::Disturbance);
        let bs = (n_boxes * steps) as f64;
        let c = CpuBackend.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        let g = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        let (tc, tg) = (c.timing.reach_s, g.timing.reach_s);
        eprintln!(
            "2x400x400x400x2 forward, {n_boxes} boxes × {steps} steps: cpu {:.0} box-steps/s \
             ({:.2} GFLOP/s), gpu [{}] {:.0} box-steps/s ({:.2} GFLOP/s)",
            bs / tc,
            bs / tc * flop / 1e9,
            gpu.context().info.name,
            bs / tg,
            bs / tg * flop / 1e9
        );
    }
}

/// `cbfreach reach --backend gpu|auto` prints the adapter and the tubes; a bad adapter name is an
/// error, not a panic.
#[test]
fn cli_backend_gpu_and_auto() {
    let Some(_gpu) = gpu() else { return };
    let gpu = GpuContext::new().expect("the adapter found above");
    let dir = tempfile::tempdir().unwrap();
    let net_path = dir.path().join("net.safetensors");
    small_network(&[2, 16, 16, 2], 8, 0.05)
        .save_safetensors(&net_path, &Default::default())
        .unwrap();
    let scenario = common::scenario_path("integrator.toml");
    let run = |extra: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
            .arg("reach")
            .arg(&scenario)
            .arg("--network")
            .arg(&net_path)
            .args(["--m-c", "0.05", "--every", "25", "--time", "euler"])
            .args(extra)
            // The filter's own pieces make the kernels slow to compile on lavapipe; the first
            // run checks them, the others the flags.
            .args(if extra.contains(&"--exact") {
                &[][..]
            } else {
                &["--exact", "nowhere"][..]
            })
            .output()
            .unwrap();
        (
            out.status.success(),
            String::from_utf8_lossy(&out.stdout).to_string()
                + &String::from_utf8_lossy(&out.stderr),
        )
    };
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward",
        "--exact",
        "closed-form",
    ]);
    assert!(
        ok && text.contains("GPU adapter:") && text.contains("backend gpu"),
        "{text}"
    );
    // The filter's own pieces run there too (the default `--exact closed-form`), no notice.
    assert!(
        text.contains("the filter's pieces") && !text.contains("note:"),
        "{text}"
    );
    // f64 by default where the adapter has f64 shaders (its sets match the CPU's; f32's a-priori
    // rounding bounds cost verdicts), f32 on request.
    let default_type = if gpu.has_f64() { "f64)" } else { "f32)" };
    assert!(text.contains(default_type), "{text}");
    let (ok, text) = run(&["--backend", "auto", "--bounds", "ibp"]);
    assert!(ok && text.contains("using the CPU"), "{text}");
    let (ok, text) = run(&["--backend", "auto", "--bounds", "crown"]);
    if gpu.is_software() {
        // A software adapter is slower than the CPU engine: auto passes it over...
        assert!(
            ok && text.contains("software") && text.contains("using the CPU"),
            "{text}"
        );
        // ... unless it is named.
        let name = gpu.describe();
        let first = name.split_whitespace().next().unwrap_or("");
        let (ok, text) = run(&[
            "--backend",
            "auto",
            "--bounds",
            "forward",
            "--adapter",
            first,
        ]);
        assert!(ok && text.contains("backend gpu"), "{text}");
    } else {
        assert!(ok && text.contains("backend gpu"), "{text}");
    }
    if gpu_f64().is_some() {
        let (ok, text) = run(&["--backend", "gpu", "--bounds", "forward-backward", "--f64"]);
        assert!(ok && text.contains("f64)"), "{text}");
    }
    let (ok, text) = run(&["--backend", "gpu", "--bounds", "forward", "--f32"]);
    assert!(ok && text.contains("f32)"), "{text}");
    let (ok, text) = run(&["--backend", "gpu", "--f32", "--f64"]);
    assert!(
        !ok && text.contains("--f32") && text.contains("--f64"),
        "{text}"
    );
    // Local error margins and face-local bounds run on the GPU (the map beside the network).
    let mut map = small_error_map(&integrator().reach.region);
    // Stamped for the scenario the command runs (provenance, issue 39).
    map.stamp(&integrator(), &net_path).unwrap();
    map.save(&cbfreach::error_map::error_map_path(&net_path))
        .unwrap();
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward-backward",
        "--face-local",
        "--local-margin",
    ]);
    assert!(
        ok && text.contains("backend gpu") && text.contains("local bounds of the error map"),
        "{text}"
    );
    let (ok, text) = run(&["--backend", "cpu", "--f64"]);
    assert!(!ok && text.contains("--f64"), "{text}");
    let (ok, text) = run(&["--backend", "cpu", "--f32"]);
    assert!(!ok && text.contains("--f32"), "{text}");
    let (ok, text) = run(&[
        "--backend",
        "gpu",
        "--bounds",
        "forward",
        "--adapter",
        "no-such-gpu",
    ]);
    assert!(!ok && text.contains("no GPU adapter named like"), "{text}");
    assert!(!text.contains("panicked"), "{text}");
    // `bench --profile`: a step's time, one line per kind of dispatch, one per GEMM.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_cbfreach"))
        .args([
            "bench",
            "--backend",
            "gpu",
            "--profile",
            "--boxes",
            "8",
            "--steps",
            "2",
        ])
        .args(["--bounds", "forward-backward", "--scenario"])
        .arg(&scenario)
        .arg("--network")
        .arg(&net_path)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stderr).to_string();
    assert!(out.status.success(), "{text}");
    assert!(text.contains("profile (8 boxes,"), "{text}");
    let kernel_count = |name: &str| -> usize {
        let line = text
            .lines()
            .find(|l| l.trim_start().starts_with(&format!("{name} ")))
            .unwrap_or_else(|| panic!("no {name} line: {text}"));
        let field = line.split_whitespace().nth(1).unwrap();
        field.trim_end_matches('×').parse().unwrap()
    };
    let gemm_lines = text
        .lines()
        .filter(|l| l.trim_start().starts_with("gemm ") && l.contains("GFLOP/s"))
        .count();
    assert!(gemm_lines > 0, "{text}");
    assert_eq!(kernel_count("gemm"), gemm_lines, "{text}");
    assert_eq!(kernel_count("embed"), 1, "{text}");
}

/// GPU (f64) against CPU for face-local bounds and local error margins: the same arithmetic up
/// to rounding order, so the sets agree far below `REL_TOL`.
const F64_TOL: f64 = 1e-9;

fn with_faces(bounds: BoundMethod) -> ReachSettings {
    ReachSettings {
        face_local: true,
        ..with_bounds(bounds, ReachMethod::Disturbance)
    }
}

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

/// A certified-looking error map over a region: 8 × 6 cells (of width 1 on scenario 1's region)
/// with bounds between 0.01 and 0.03, and no certified bound (+∞) on cell (4, 2) (scenario 1:
/// `[0.5, 1.5] × [-0.5, 0.5]`).
fn small_error_map(region: &IntervalBox) -> cbfreach::error_map::ErrorMap {
    let mut cells = Vec::new();
    let w = [
        (region.upper[0] - region.lower[0]) / 8.0,
        (region.upper[1] - region.lower[1]) / 6.0,
    ];
    for i in 0..8 {
        for j in 0..6 {
            let lower = [
                region.lower[0] + i as f64 * w[0],
                region.lower[1] + j as f64 * w[1],
            ];
            let upper = [lower[0] + w[0], lower[1] + w[1]];
            let bound = if (i, j) == (4, 2) {
                "\"inf\"".to_string()
            } else {
                format!("{}", 0.01 + 0.005 * ((i * 7 + j * 3) % 5) as f64)
            };
            cells.push(format!(
                "{{\"lower\": [{}, {}], \"upper\": [{}, {}], \"bound\": {bound}}}",
                lower[0], lower[1], upper[0], upper[1]
            ));
        }
    }
    let json = format!(
        "{{\"format\": \"cbfreach-errormap-1\", \"network\": \"test\", \"network_hash\": \"0\", \
         \"region\": {{\"lower\": [{}, {}], \"upper\": [{}, {}]}}, \"norm\": \"inf\", \
         \"measured_linf\": 0.03, \"measured_l2\": 0.03, \"certified_linf\": \"inf\", \
         \"cells\": [{}]}}",
        region.lower[0],
        region.lower[1],
        region.upper[0],
        region.upper[1],
        cells.join(", ")
    );
    serde_json::from_str(&json).unwrap()
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

/// Asserts that every recorded set of each tube contains its box's sampled trajectories at that
/// time (trajectories recorded every `dt`); returns the number of checks.
fn count_contained(
    tubes: &[Tube],
    trajectories: &[Vec<Vec<Vec<f64>>>],
    dt: f64,
    label: &str,
) -> usize {
    let mut checks = 0;
    for (tube, trajs) in tubes.iter().zip(trajectories) {
        for traj in trajs {
            for sample in &tube.tube {
                let Some(x) = traj.get((sample.t / dt).round() as usize) else {
                    break;
                };
                for i in 0..x.len() {
                    assert!(
                        sample.set.lower[i] <= x[i] && x[i] <= sample.set.upper[i],
                        "{label}: t = {} x{i} = {} escapes [{}, {}]",
                        sample.t,
                        x[i],
                        sample.set.lower[i],
                        sample.set.upper[i]
                    );
                }
                checks += 1;
            }
        }
    }
    checks
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

/// Point boxes with no error margin: the NN system's trajectory is one point per step, and only
/// the engines' rounding treatment separates it from the sets' edges. Both GPU engines' sets
/// must contain the f64 Euler trajectory. Near the origin, where a state's ulp is far below
/// the rounding of the network's sums, an f32 engine with neither its outward steps nor its
/// a-priori bounds on every sum's rounding fails this at the first step with the random
/// network (checked), though either alone covers that network's sums; with the cancelling
/// network (below) an engine without the a-priori bounds fails at the first step (checked).
#[test]
fn point_boxes_contain_the_nn_trajectory_despite_rounding() {
    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    let s = integrator();
    // Two centres near the origin, one far from it; none exact in f32.
    let init = boxes(
        &[
            [1e-3 / 3.0, -1e-3 / 7.0],
            [2e-4 / 9.0, 1e-4 / 11.0],
            [-2.9, 0.3],
        ],
        0.0,
    );
    for (name, net) in [
        ("random", small_network(&[2, 64, 64, 2], 4, 0.2)),
        ("cancelling", cancelling_network()),
    ] {
        let mut problem = ReachProblem::new(&s, net.clone(), 0.0)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 40;
        let trajectories = nn_trajectories(&s, &net, &init, problem.dt, problem.steps, 0.0);
        for gpu in &engines {
            for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
                let st = with_bounds(bounds, ReachMethod::Disturbance);
                let tubes = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
                let label = format!(
                    "point boxes, {name} network, {bounds} {:?}",
                    gpu.precision()
                );
                for t in &tubes {
                    assert!(t.valid(), "{label}: {:?}", t.note());
                }
                let checks = count_contained(&tubes, &trajectories, problem.dt, &label);
                assert!(checks >= 3 * 12 * 40, "{label}: {checks} checks");
            }
        }
    }
}

/// A 2×64×64×2 network whose second layer sums 64 terms of size ~30 that cancel in pairs to
/// ~0.1 each: its first layer's neurons come in pairs, the second of each 1.0033 times the
/// first, weighed +A and −A. The f32 sums then err by many ulps of their results, so the outward
/// steps alone do not cover them: only the a-priori bounds on every sum's rounding do (an f32
/// engine whose `err_bound` returns 0 fails here; checked).
fn cancelling_network() -> Mlp {
    let base = Mlp::random(&[2, 32, 64, 2], 9);
    let (l1, l2, l3) = (&base.layers[0], &base.layers[1], &base.layers[2]);
    let mut w1 = Vec::with_capacity(128);
    let mut b1 = Vec::with_capacity(64);
    for k in 0..32 {
        let row = &l1.weight[2 * k..2 * k + 2];
        for f in [1.0, 1.0 + 1.0 / 300.0] {
            w1.extend(row.iter().map(|w| f * w));
            b1.push(f * (0.5 + 0.1 * l1.bias[k]));
        }
    }
    let a = 64.0;
    let mut w2 = Vec::with_capacity(64 * 64);
    for i in 0..64 {
        for k in 0..32 {
            let c = a * l2.weight[i * 32 + k].signum();
            w2.extend([c, -c]);
        }
    }
    let layer = |weight: Vec<f64>, bias: Vec<f64>, n_in: usize, n_out: usize| Layer {
        weight,
        bias,
        n_in,
        n_out,
    };
    Mlp {
        layers: vec![
            layer(w1, b1, 2, 64),
            layer(w2, vec![0.5; 64], 64, 64),
            layer(
                l3.weight.iter().map(|w| 0.01 * w).collect(),
                vec![0.0; 2],
                64,
                2,
            ),
        ],
    }
}

/// The filter's closed form on the GPU (`ExactField::ClosedForm`, shaders/filter.wgsl): its own
/// field where it is provably one smooth function on the set (inactive, or one row binding),
/// the closed form's enclosures of `v` on each face elsewhere, each met with the network's
/// bounds. On scenario 1 (one row, `v = b·a/‖a‖²`: a box near the goal, two where the
/// obstacle's row binds, one that crosses the switch) and on scenario 2 in z coordinates (a
/// scalar input, two rows and the dominance between them, and the transform's slack), the GPU
/// in f64 takes the same piece or enclosure on every step as the CPU and agrees on the sets to
/// `F64_TOL`; in f32 its sets contain the CPU's (up to `F32_FACTOR`). Both kinds of step occur,
/// and the closed form makes the binding boxes' sets narrower than `v = 0` where inactive alone.
#[test]
fn closed_form_filter_matches_cpu() {
    let Some(gpu32) = gpu() else { return };
    let gpu64 = gpu_f64();
    let s1 = integrator();
    // A random network with an error bound that holds near the obstacle (|v| ≤ 6 there), so
    // that its bounds are sound and the closed form does the work.
    let mut p1 = ReachProblem::new(&s1, small_network(&[2, 16, 16, 2], 1, 0.05), 8.0)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p1.steps = 40;
    let init1 = boxes(&[[0.1, 0.1], [3.9, 0.0], [3.6, 0.5], [2.6, 1.4]], 0.03);
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let mut p2 = ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 6, 0.05), 8.0, t)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p2.steps = 40;
    let init2 = boxes(&[[0.1, -0.1], [1.0, 1.5], [1.5, 1.5], [-2.5, 0.5]], 0.03);
    let closed = ReachSettings {
        exact: ExactField::ClosedForm,
        ..with_faces(BoundMethod::ForwardBackward)
    };
    let inactive = ReachSettings {
        exact: ExactField::Inactive,
        ..closed.clone()
    };
    for (problem, init, name) in [(&p1, &init1, "scenario 1"), (&p2, &init2, "scenario 2")] {
        let (c, g) = run_both_with(&gpu32, problem, init, &closed);
        let exact: usize = c.iter().map(|t| t.exact_steps).sum();
        let enclosed: usize = c.iter().map(|t| t.enclosed_steps).sum();
        assert!(
            exact > problem.steps && enclosed > 0,
            "{name}: {exact} exact, {enclosed} enclosed"
        );
        for (k, (a, b)) in c.iter().zip(&g).enumerate() {
            assert_eq!(
                a.valid(),
                b.valid(),
                "{name} box {k}: {:?} vs {:?}",
                a.note(),
                b.note()
            );
            for (sa, sb) in a.tube.iter().zip(&b.tube) {
                for i in 0..2 {
                    let scale = sa.set.lower[i].abs().max(sa.set.upper[i].abs()).max(1.0);
                    assert!(
                        sb.set.lower[i] <= sa.set.lower[i] + F32_FACTOR * scale
                            && sa.set.upper[i] <= sb.set.upper[i] + F32_FACTOR * scale,
                        "{name} f32 box {k} t = {}: gpu {:?} does not contain cpu {:?}",
                        sa.t,
                        sb.set,
                        sa.set
                    );
                }
            }
        }
        if let Some(gpu64) = &gpu64 {
            let (c, g) = run_both_with(gpu64, problem, init, &closed);
            for (k, (a, b)) in c.iter().zip(&g).enumerate() {
                assert_eq!(
                    (a.exact_steps, a.enclosed_steps),
                    (b.exact_steps, b.enclosed_steps),
                    "{name} box {k}: steps on a piece and enclosed"
                );
            }
            compare_within(&c, &g, &format!("{name}: closed form, f64"), F64_TOL);
            let (_, loose) = run_both_with(gpu64, problem, init, &inactive);
            // At the last time both recorded, some set is narrower.
            let tighter = g.iter().zip(&loose).any(|(a, b)| {
                let j = a.tube.len().min(b.tube.len());
                j > 1 && a.tube[j - 1].set.widths()[0] < 0.9 * b.tube[j - 1].set.widths()[0]
            });
            assert!(tighter, "{name}: the closed form tightened no set");
        }
    }
}

/// The f64 shaders' `turn_rate` (`shaders/turn.wgsl`: what a face of the Euler step grows by
/// where the step may turn its state around) against the CPU's `euler_turn` that it mirrors, on
/// the rates of a one-state `f̃ = a·x + d·x²` over boxes of several widths and steps: the slope
/// `∂f̃/∂x` over the box as the CPU evaluates it, given to both. Equal to 1e-13 relative (the
/// device steps each operation outward by 4 ulp, the CPU by 1), never below the CPU's, zero
/// where `1 + h·L ≥ 0` (but for the device's own rounding of `1 + h·L` near 0), and many of
/// them not zero.
#[test]
fn turn_rate_matches_the_cpus_euler_turn() {
    use cbfreach::expressions::parse;
    use cbfreach::intervals::Interval;
    use cbfreach::reach::embedding::{euler_turn, Dynamics};
    let Some(g) = gpu_f64() else { return };
    let names = vec!["x".to_string()];
    let (mut inputs, mut cpu) = (Vec::new(), Vec::new());
    for a in [-60.0, -30.0, -20.5, -1.0, 0.0, 5.0] {
        for d in [0.0, 3.0, -7.0] {
            let f = parse(&format!("{a}*x + {d}*x^2"), &names, &Default::default()).unwrap();
            let g1 = parse("1", &names, &Default::default()).unwrap();
            let dynamics = Dynamics::new(1, 1, vec![f], vec![vec![g1]]);
            for (lo, w) in [(-1.0, 0.0), (-1.0, 1e-3), (0.3, 0.5), (-1.3, 2.0)] {
                let hi = lo + w;
                for h in [0.01, 0.05, 0.1] {
                    let (mut dl, mut du) = (vec![0.0], vec![0.0]);
                    euler_turn(&dynamics, &[lo], &[hi], h, None, &mut dl, &mut du);
                    assert_eq!(dl[0], -du[0]);
                    let slope =
                        dynamics.f_tilde_jacobian[0][0].eval_interval(&[Interval::new(lo, hi)]);
                    let width = (Interval::point(hi) - Interval::point(lo)).upper;
                    inputs.push([slope.lower, slope.upper, width, h, h]);
                    cpu.push((du[0], width / h));
                }
            }
        }
    }
    let dev = cbfreach::gpu::probe::turn_rate_on_device(g.context(), &inputs).unwrap();
    assert_eq!(dev.len(), cpu.len());
    let mut turned = 0;
    for ((&d, &(c, scale)), input) in dev.iter().zip(&cpu).zip(&inputs) {
        assert!(d >= c, "{input:?}: device {d} below the CPU's {c}");
        // (Zero widths: both a few smallest normal numbers, from rounding 0 up.)
        assert!(
            d - c <= 1e-13 * c.max(scale) + 1e-300,
            "{input:?}: device {d}, CPU {c}"
        );
        turned += usize::from(c > 0.0);
    }
    assert!(turned >= 40, "only {turned} of {} inputs turn", cpu.len());
    eprintln!("turn_rate: {turned} of {} inputs turn", cpu.len());
}

/// The f64 shaders' `exp` enclosure (`shaders/real_f64.wgsl`) against its Rust mirror
/// (`gpu::exp64`) on 100,001 inputs over [−90, 90]: equal to 1e-15 relative (a driver may fuse
/// a multiply and an add; lavapipe gives 88,579 of them bit for bit), and both enclose libm's
/// `exp` one ulp outward.
#[test]
fn f64_exp_matches_its_rust_mirror() {
    use cbfreach::gpu::exp64;
    let Some(g) = gpu_f64() else { return };
    let xs: Vec<f64> = (0..=100_000)
        .map(|i| -90.0 + 180.0 * i as f64 / 100_000.0 + 1e-11 * (i % 13) as f64)
        .collect();
    let dev = exp64::on_device(g.context(), &xs).unwrap();
    let mut bitwise = 0;
    for (&x, &(lo, hi)) in xs.iter().zip(&dev) {
        let (rlo, rhi) = (exp64::exp_down(x), exp64::exp_up(x));
        bitwise += usize::from(lo == rlo && hi == rhi);
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
        assert!(
            near(lo, rlo) && near(hi, rhi),
            "{x}: device [{lo}, {hi}], Rust [{rlo}, {rhi}]"
        );
        if x.abs() <= exp64::RANGE {
            let e = x.exp();
            assert!(
                lo <= e.next_down() && e.next_up() <= hi,
                "{x}: [{lo}, {hi}] vs {e}"
            );
            assert!((hi - lo) <= 2.5e-13 * e, "{x}: [{lo}, {hi}]");
        }
    }
    eprintln!("exp: {bitwise} of {} inputs bit for bit", xs.len());
}

/// The f64 shaders' `phi_up` (φ(z) = (eᶻ − 1)/z, the closeness radius's factor) against its Rust
/// mirror (equal to 1e-15; bit for bit where the device fuses nothing) and the CPU's
/// `phi_upper` (1e-14 on the series, |z| ≤ 1/2; 3e-13 past it, the width of `exp`'s
/// enclosures), above φ, over z ∈ [−90, 90] and through 0 on both sides down to 1e-15.
#[test]
fn f64_phi_matches_its_rust_mirror_and_the_cpu() {
    use cbfreach::gpu::exp64;
    use cbfreach::reach::closeness::phi_upper;
    let Some(g) = gpu_f64() else { return };
    let mut zs: Vec<f64> = (0..=20_000)
        .map(|i| -90.0 + 180.0 * i as f64 / 20_000.0 + 1e-11 * (i % 13) as f64)
        .collect();
    zs.extend((0..300).flat_map(|e| [1e-15 * 1.13_f64.powi(e), -1e-15 * 1.13_f64.powi(e)]));
    zs.extend([0.0, 0.5, -0.5, 0.5_f64.next_up(), (-0.5_f64).next_down()]);
    let dev = exp64::phi_on_device(g.context(), &zs).unwrap();
    let mut bitwise = 0;
    for (&z, &d) in zs.iter().zip(&dev) {
        let (mirror, cpu) = (exp64::phi_up(z), phi_upper(z));
        bitwise += usize::from(d == mirror);
        assert!(
            (d - mirror).abs() <= 1e-15 * mirror,
            "{z}: device {d}, Rust {mirror}"
        );
        if z.abs() <= exp64::RANGE {
            let exact = if z == 0.0 { 1.0 } else { z.exp_m1() / z };
            assert!(d >= exact * (1.0 - 1e-15), "{z}: {d} < {exact}");
            let tol = if z.abs() <= 0.5 { 1e-14 } else { 3e-13 };
            assert!((d - cpu).abs() <= tol * cpu, "{z}: device {d}, CPU {cpu}");
        }
    }
    eprintln!("phi: {bitwise} of {} inputs bit for bit", zs.len());
}

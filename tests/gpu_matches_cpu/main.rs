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

mod cli;
#[path = "../common/mod.rs"]
mod common;
mod continuous;
mod continuous_f32;
mod field;
mod margins;
mod methods;
mod primitives;
mod sampled;
mod step;
mod validated;

use cbfreach::reach::TimeModel;

use std::sync::Arc;

use cbfreach::bounds::BoundMethod;
use cbfreach::gpu::kernels::Gemm;
use cbfreach::gpu::{GpuBackend, GpuContext, Precision};
use cbfreach::network::{Layer, Mlp};
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, Transform, Tube,
};
use cbfreach::scenario::{Scenario, TransformChoice};
use cbfreach::simulate::{integrate, sample_box, Integrator};
use cbfreach::IntervalBox;
use common::{double_integrator, integrator, small_network};

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

/// Eight boxes 0.1 wide across scenario 1's `C`: around the obstacle, behind it, near the goal.
fn scenario_1_starts() -> Vec<IntervalBox> {
    boxes(
        &[
            [-3.0, 2.0],
            [-1.0, 1.0],
            [0.5, -1.5],
            [1.5, 2.5],
            [3.5, 1.5],
            [4.0, -0.5],
            [1.0, 0.8],
            [4.0, 2.5],
        ],
        0.05,
    )
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
        ..ReachSettings::default()
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

/// GPU (f64) against CPU for face-local bounds and local error margins: the same arithmetic up
/// to rounding order, so the sets agree far below `REL_TOL`.
const F64_TOL: f64 = 1e-9;

fn with_faces(bounds: BoundMethod) -> ReachSettings {
    ReachSettings {
        face_local: true,
        ..with_bounds(bounds, ReachMethod::Disturbance)
    }
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

fn nn_field(s: &Scenario, net: &Mlp, x: &[f64]) -> Vec<f64> {
    let (n, m) = (s.n(), s.m());
    let f = s.f_tilde_at(x);
    let g = s.g_at(x);
    let u = net.forward(x);
    (0..n)
        .map(|i| f[i] + (0..m).map(|k| g[i * m + k] * u[k]).sum::<f64>())
        .collect()
}

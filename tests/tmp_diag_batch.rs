//! WORK IN PROGRESS (branch gpu-closed-form): the batch-dependence diagnostic of session 22.
//! `SUBSET=45,5 ONLY=0 STEPS=14 INACT=1 cargo test --release --test tmp_diag_batch -- --ignored --nocapture`
//! runs cell 45 of `verify --grid 8,6` (scenario 1, shipped network) beside cell 5 on the CPU and
//! the GPU (f64) and prints both tubes; alone (`SUBSET=45`) they agree to 1e-10.
mod common;
use cbfreach::bounds::BoundMethod;
use cbfreach::gpu::{GpuBackend, GpuContext, Precision};
use cbfreach::network::Mlp;
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, Tube,
};
use cbfreach::IntervalBox;
use common::integrator;
use std::sync::Arc;
fn gpu_f64() -> Option<GpuBackend> {
    let ctx = Arc::new(GpuContext::new().ok()?);
    GpuBackend::with_precision(ctx, Precision::F64).ok()
}
fn with_faces(bounds: BoundMethod) -> ReachSettings {
    ReachSettings {
        bounds,
        method: ReachMethod::Disturbance,
        every: 1,
        face_local: true,
        exact: ExactField::Nowhere,
        intersect_x: false,
    }
}
fn run_both_with(
    gpu: &GpuBackend,
    problem: &ReachProblem,
    initial: &[IntervalBox],
    s: &ReachSettings,
) -> (Vec<Tube>, Vec<Tube>) {
    let cpu = CpuBackend.reach(problem, initial, s, &|_, _| {}).unwrap();
    let g = gpu.reach(problem, initial, s, &|_, _| {}).unwrap();
    (cpu.boxes, g.boxes)
}
#[test]
#[ignore]
fn tmp_diag_cell45() {
    let gpu64 = gpu_f64().unwrap();
    let s = integrator();
    let net = Mlp::load_safetensors(&common::scenario_path("integrator.safetensors")).unwrap();
    let map = cbfreach::surrogate_error::ErrorMap::load(&common::scenario_path(
        "integrator.errormap.json",
    ))
    .unwrap();
    let m_c = map.certified_linf.unwrap();
    let mut problem = ReachProblem::new(&s, net, m_c)
        .unwrap()
        .with_error_map(map)
        .unwrap();
    let steps: usize = std::env::var("STEPS")
        .map(|v| v.parse().unwrap())
        .unwrap_or(13);
    problem.steps = steps;
    let mut init = Vec::new();
    for k in 0..48 {
        let (i, j) = (k % 8, k / 8);
        init.push(
            IntervalBox::new(
                vec![-3.5 + i as f64, -3.0 + j as f64],
                vec![-2.5 + i as f64, -2.0 + j as f64],
            )
            .unwrap(),
        );
    }
    if let Ok(list) = std::env::var("SUBSET") {
        let idx: Vec<usize> = list.split(",").map(|v| v.parse().unwrap()).collect();
        init = idx.iter().map(|&k| init[k].clone()).collect();
    }
    if std::env::var("SAME").is_ok() {
        let b = init[45].clone();
        init = vec![b; 48];
    }
    let only: usize = std::env::var("ONLY")
        .map(|v| v.parse().unwrap())
        .unwrap_or(45);
    let exact = if std::env::var("INACT").is_ok() {
        ExactField::Inactive
    } else {
        ExactField::ClosedForm
    };
    let mut st = ReachSettings {
        exact,
        ..with_faces(BoundMethod::ForwardBackward)
    };
    if std::env::var("WHOLE").is_ok() {
        st.face_local = false;
    }
    if std::env::var("FWD").is_ok() {
        st.bounds = BoundMethod::Forward;
    }
    let (c, g) = run_both_with(&gpu64, &problem, &init, &st);
    for (a, b) in c.iter().zip(&g).skip(only).take(1) {
        eprintln!(
            "cpu exact {} enc {} valid {} {:?}",
            a.exact_steps, a.enclosed_steps, a.valid, a.note
        );
        eprintln!(
            "gpu exact {} enc {} valid {} {:?}",
            b.exact_steps, b.enclosed_steps, b.valid, b.note
        );
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            eprintln!(
                "t {:.2} cpu {:?} {:?}\n       gpu {:?} {:?}",
                sa.t, sa.set.lower, sa.set.upper, sb.set.lower, sb.set.upper
            );
        }
    }
}

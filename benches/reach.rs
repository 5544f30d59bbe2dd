//! Box-steps per second of the CPU reach engine, per bound method (issue 5 item 7), and of
//! the GPU engine over batch sizes (`reach_gpu`; `cbfreach bench` prints both side by side).
//!
//! Scenario 1's dynamics with a random 2×400×400×400×2 network whose last layer is scaled by
//! 0.05 (so that the closed loop stays close to the nominal one and tubes stay bounded), the
//! scenario's 12 initial boxes, 250 Euler steps (`dt = 0.04`, horizon 10): the paper's
//! experiment, whose reported wall time is 2.15 s. divan's time per iteration is the wall time of
//! the whole 12 × 250 run; throughput is in box-steps. `CBFREACH_BENCH_QUICK=1` runs 25 steps.
//! `M_C = 0`: the bound method, not the margin, is what is timed.

use std::sync::Arc;

use cbfreach::bounds::BoundMethod;
use cbfreach::gpu::{GpuBackend, GpuContext};
use cbfreach::network::Mlp;
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, TimeModel,
};
use cbfreach::scenario::Scenario;
use divan::counter::ItemsCount;
use divan::Bencher;

fn quick() -> bool {
    std::env::var("CBFREACH_BENCH_QUICK").is_ok_and(|v| !v.is_empty() && v != "0")
}

fn problem() -> (ReachProblem, Vec<cbfreach::boxes::IntervalBox>) {
    let scenario = Scenario::builtin().expect("built-in scenario 1");
    let mut net = Mlp::random(&[2, 400, 400, 400, 2], 1);
    if let Some(last) = net.layers.last_mut() {
        last.weight.iter_mut().for_each(|w| *w *= 0.05);
        last.bias.iter_mut().for_each(|b| *b *= 0.05);
    }
    let mut problem = ReachProblem::new(&scenario, net, 0.0).expect("problem compiles");
    if quick() {
        problem.steps = problem.steps.min(25);
    }
    (problem, scenario.reach.initial.clone())
}

#[divan::bench(args = BoundMethod::ALL, sample_count = 1, sample_size = 1)]
fn reach_12_boxes(bencher: Bencher, method: BoundMethod) {
    let (problem, initial) = problem();
    let settings = ReachSettings {
        bounds: method,
        method: ReachMethod::Disturbance,
        every: 50,
        face_local: false,
        // Every step bounds the network: this measures the bound methods.
        exact: ExactField::Nowhere,
        intersect_x: false,
        ..ReachSettings::default()
    };
    bencher
        .counter(ItemsCount::new(initial.len() * problem.steps))
        .bench_local(|| {
            let result = CpuBackend
                .reach(&problem, &initial, &settings, &|_, _| {})
                .expect("reach runs");
            let valid = result.boxes.iter().filter(|t| t.valid()).count();
            eprintln!(
                "{method}: {valid}/{} tubes valid to the end",
                result.boxes.len()
            );
            divan::black_box(result)
        });
}

/// The GPU engine beside the CPU's (`reach_12_boxes`): forward-backward bounds on `count`
/// boxes, 10 steps of the Euler map (2 with `CBFREACH_BENCH_QUICK=1`), f64 where the adapter has it; the
/// pipelines compiled by an untimed run first. Skipped without a Vulkan adapter.
#[divan::bench(args = [256, 4096, 16384], sample_count = 1, sample_size = 1)]
fn reach_gpu(bencher: Bencher, count: usize) {
    let ctx = match GpuContext::new() {
        Ok(ctx) => ctx,
        Err(e) => {
            eprintln!("reach_gpu skipped: {e}");
            return;
        }
    };
    let engine = GpuBackend::new(Arc::new(ctx));
    // The Euler map, as `cbfreach bench` runs both engines.
    let (problem, _) = problem();
    let mut problem = problem.with_time(TimeModel::Euler, 1);
    problem.steps = if quick() { 2 } else { 10 };
    let scenario = Scenario::builtin().expect("built-in scenario 1");
    let boxes = cbfreach::simulate::spread_boxes(&scenario, count);
    let settings = ReachSettings {
        bounds: BoundMethod::ForwardBackward,
        method: ReachMethod::Disturbance,
        every: 50,
        face_local: false,
        exact: ExactField::Nowhere,
        intersect_x: false,
        ..ReachSettings::default()
    };
    engine
        .reach(&problem, &boxes[..1], &settings, &|_, _| {})
        .expect("the GPU engine runs");
    bencher
        .counter(ItemsCount::new(boxes.len() * problem.steps))
        .bench_local(|| {
            divan::black_box(
                engine
                    .reach(&problem, &boxes, &settings, &|_, _| {})
                    .expect("the GPU engine runs"),
            )
        });
}

fn main() {
    divan::main();
}

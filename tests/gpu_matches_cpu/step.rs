//! One box-step of the continuous model's common path on the device (`shaders/slab_step.wgsl`)
//! against the CPU engine's own step from the same state (`CpuBackend::continuous_step`,
//! docs/design.md §7.4).

use super::*;
use cbfreach::bounds::PreparedNetwork;
use cbfreach::gpu::probe_field::{common_step_on_device, NetCase, StepCase};
use cbfreach::reach::cpu::StepState;
use cbfreach::reach::validated;
use cbfreach::rounding::round_up;

/// Scenario 1 with a small network in continuous time (one step a `dt`), forward bounds, the
/// network everywhere, a global margin; face-local bounds or bounds over the moving box's hull.
/// Twelve boxes, 0.1 wide, across the region, stepped 16 times by the CPU engine from their
/// state (`continuous_step`); from each state that has rates, the device takes the same step
/// with the network's bounds on the slabs (or the hull) of the CPU's guess. The device takes
/// the common path exactly where the CPU guessed a box within `C`, proves it exactly where the
/// CPU's first check held, and there its set and the rates it keeps equal the CPU's to 1e-10
/// relative (f64; the device rounds each operation outward by 4 ulp, the CPU by 1), and it
/// keeps the rates it started from as the step before's.
#[test]
fn common_step_matches_the_cpu_engines_step() {
    let Some(g) = gpu_f64() else { return };
    let s = integrator();
    let problem = ReachProblem::new(&s, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    let n = problem.dynamics.n;
    let h = problem.dt;
    let net = PreparedNetwork::new(&problem.network).unwrap();
    let margin = round_up(problem.m_c + problem.network_slack);
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
    let (mut compared, mut proven, mut flagged) = (0, 0, 0);
    // The largest difference of a set's end or a kept rate, relative to the magnitudes.
    let mut worst = 0.0_f64;
    for face_local in [true, false] {
        let st = ReachSettings {
            face_local,
            ..settings(ReachMethod::Disturbance)
        };
        let mut states: Vec<StepState> = init
            .iter()
            .map(|b| StepState {
                set: b.clone(),
                rates: None,
                before: None,
                guess: None,
            })
            .collect();
        let (mut cases, mut cpu) = (Vec::new(), Vec::new());
        for _ in 0..16 {
            let out = CpuBackend.continuous_step(&problem, &st, &states).unwrap();
            let mut next = Vec::new();
            for (state, o) in states.iter().zip(out) {
                if let Some(rates) = &state.rates {
                    let before = state.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
                    let guess = validated::guessed(&state.set, h, (&rates.0, &rates.1), before)
                        .filter(|p| p.set.is_subset_of(&problem.region));
                    let nn: Vec<NetCase> = match &guess {
                        Some(pipe) if face_local => validated::slabs(&state.set, pipe, h)
                            .map(|(lo, hi)| {
                                NetCase::from(&net.bounds(&lo, &hi, st.bounds).unwrap())
                            })
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
        let dev = common_step_on_device(g.context(), &problem, &st, &cases).unwrap();
        for ((before, guessed, o), d) in cpu.iter().zip(&dev) {
            let what = format!("face-local {face_local}: from {before:?}: cpu {o:?}, device {d:?}");
            assert_eq!(*guessed, d.common, "{what}: common path");
            if !d.common {
                continue;
            }
            assert_eq!(o.common, d.proven, "{what}: proven");
            if !d.proven {
                flagged += 1;
                continue;
            }
            proven += 1;
            if o.end.is_some() {
                continue;
            }
            compared += 1;
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
                worst = a
                    .iter()
                    .zip(b)
                    .fold(worst, |w, (x, y)| w.max((x - y).abs() / s));
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
    eprintln!(
        "common steps: {proven} proven ({compared} compared, largest difference {worst:.1e}), \
         {flagged} flagged"
    );
    assert!(compared >= 200, "{compared} steps compared");
}

//! The CPU reference engine: f64 with outward rounding, rayon over boxes.
//!
//! Each Euler step bounds the network over every live box in one batch (GEMM-batched for
//! forward bounds, one task per box for CROWN and IBP), then advances each box's embedding
//! state in parallel.

use std::time::Instant;

use rayon::prelude::*;

use super::closeness::{closeness_step, log_norm};
use super::embedding::{
    embedding_field, embedding_field_by_face, embedding_step, NetworkBoundsRef,
};
use super::safe_set::{clip_to_safe_set, SafeSet};
use super::{Backend, ReachError, ReachMethod, ReachProblem, ReachResult, ReachSettings};
use super::{ReachTiming, Tube};
use crate::bounds::{AffineBoundsBatch, PreparedNetwork};
use crate::boxes::IntervalBox;
use crate::intervals::{round_down, round_up, Interval};

/// The CPU engine.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuBackend;

/// One box's embedding state while it is integrated.
struct Live {
    lower: Vec<f64>,
    upper: Vec<f64>,
    radius: f64,
    tube: Tube,
    done: bool,
}

impl Backend for CpuBackend {
    fn name(&self) -> String {
        "cpu".into()
    }

    fn reach(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        problem.check_initial(initial)?;
        settings.validate()?;
        let every = settings.every.max(1);
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        // The transformed network's rounding enters as a disturbance in both methods; the
        // disturbance method adds M (global, or local from the error map per box and step).
        let safe = problem.safe_set_for(settings.method);
        let margin_of = |state: &Live| -> Vec<f64> {
            match settings.method {
                ReachMethod::Disturbance => {
                    let x_box = problem.x_box_in_safe_set(&state.lower, &state.upper, safe);
                    vec![round_up(problem.margin_for(&x_box) + problem.network_slack); m]
                }
                ReachMethod::Minkowski => vec![problem.network_slack; m],
            }
        };
        let mut live: Vec<Live> = initial
            .iter()
            .map(|b| {
                let z = problem.initial_state(b, settings.method);
                let mut state = Live {
                    lower: z.lower,
                    upper: z.upper,
                    radius: 0.0,
                    tube: Tube {
                        initial: b.clone(),
                        tube: Vec::new(),
                        valid: true,
                        note: None,
                    },
                    done: false,
                };
                state.tube.tube.push(problem.tube_sample(
                    &state.lower,
                    &state.upper,
                    0.0,
                    0.0,
                    safe,
                ));
                state
            })
            .collect();

        let start = Instant::now();
        let mut minkowski_s = 0.0;
        let network = PreparedNetwork::new(&problem.network)?;
        let mut batch = AffineBoundsBatch::new();
        let (mut flat_lo, mut flat_hi) = (Vec::new(), Vec::new());
        for step in 0..problem.steps {
            let active: Vec<usize> = (0..live.len()).filter(|&k| !live[k].done).collect();
            if active.is_empty() {
                break;
            }
            flat_lo.clear();
            flat_hi.clear();
            for &k in &active {
                let (lo, hi) = (&live[k].lower, &live[k].upper);
                if settings.face_local {
                    // 2n faces per box, in the order (0, lower), (0, upper), (1, lower), …
                    for i in 0..n {
                        for v in [lo[i], hi[i]] {
                            flat_lo.extend(
                                lo.iter()
                                    .enumerate()
                                    .map(|(j, &x)| if j == i { v } else { x }),
                            );
                            flat_hi.extend(
                                hi.iter()
                                    .enumerate()
                                    .map(|(j, &x)| if j == i { v } else { x }),
                            );
                        }
                    }
                } else {
                    flat_lo.extend(lo);
                    flat_hi.extend(hi);
                }
            }
            network.bounds_batch_into(&flat_lo, &flat_hi, settings.bounds, &mut batch)?;
            let t = (step + 1) as f64 * problem.dt;
            let record = (step + 1) % every == 0 || step + 1 == problem.steps;
            let mut selected: Vec<&mut Live> = live.iter_mut().filter(|l| !l.done).collect();
            let mink_time: f64 = selected
                .par_iter_mut()
                .enumerate()
                .map(|(slot, state)| {
                    let margin = margin_of(state);
                    if margin.iter().any(|v| !v.is_finite()) {
                        // The error map has no finite bound where the set is (e.g. where `v`
                        // jumps): nothing sound can be said from here on.
                        state.tube.valid = false;
                        state.tube.note = Some(format!(
                            "t = {:.3}: the set meets cells of the error map with no certified \
                             bound (M = ∞)",
                            t - problem.dt
                        ));
                        state.done = true;
                        return 0.0;
                    }
                    let (nn, (mut dl, mut du)) = if settings.face_local {
                        // (Minkowski is refused with face-local bounds: its rate needs one C.)
                        let face = |i: usize, up: bool| {
                            bounds_of(&batch, slot * 2 * n + 2 * i + usize::from(up), n, m)
                        };
                        let field = embedding_field_by_face(
                            &problem.dynamics,
                            &state.lower,
                            &state.upper,
                            face,
                            &margin,
                        );
                        (face(0, false), field)
                    } else {
                        let nn = bounds_of(&batch, slot, n, m);
                        let field = embedding_field(
                            &problem.dynamics,
                            &state.lower,
                            &state.upper,
                            nn,
                            &margin,
                        );
                        (nn, field)
                    };
                    if problem.field_slack > 0.0 {
                        dl.iter_mut()
                            .for_each(|v| *v = round_down(*v - problem.field_slack));
                        du.iter_mut()
                            .for_each(|v| *v = round_up(*v + problem.field_slack));
                    }
                    let mut mink = 0.0;
                    if settings.method == ReachMethod::Minkowski {
                        let clock = Instant::now();
                        let c = closeness_rate(problem, nn);
                        state.radius = closeness_step(
                            state.radius,
                            c,
                            problem.input_gain,
                            problem.m_c,
                            problem.dt,
                        );
                        mink = clock.elapsed().as_secs_f64();
                    }
                    embedding_step(&mut state.lower, &mut state.upper, &dl, &du, problem.dt);
                    advance(problem, state, t, record, safe);
                    mink
                })
                .sum();
            minkowski_s += mink_time / rayon::current_num_threads() as f64;
            progress(step + 1, problem.steps);
        }
        let elapsed = start.elapsed().as_secs_f64();
        Ok(ReachResult {
            boxes: live.into_iter().map(|l| l.tube).collect(),
            timing: ReachTiming {
                reach_s: elapsed - minkowski_s,
                minkowski_s,
            },
        })
    }
}

fn bounds_of(batch: &AffineBoundsBatch, k: usize, n: usize, m: usize) -> NetworkBoundsRef<'_> {
    NetworkBoundsRef {
        a_lower: &batch.a_lower[k * m * n..(k + 1) * m * n],
        b_lower: &batch.b_lower[k * m..(k + 1) * m],
        a_upper: &batch.a_upper[k * m * n..(k + 1) * m * n],
        b_upper: &batch.b_upper[k * m..(k + 1) * m],
        lower: &batch.lower[k * m..(k + 1) * m],
        upper: &batch.upper[k * m..(k + 1) * m],
    }
}

/// `c_k ≥ sup_{x∈C} μ(Df̃(x) + g(x) C_k)` with `C_k` the hull of the box's `C̲, C̄` (one
/// matrix for the same-slope relaxation, as the paper's theorem assumes).
fn closeness_rate(problem: &ReachProblem, nn: NetworkBoundsRef) -> f64 {
    let (n, m) = (problem.dynamics.n, problem.dynamics.m);
    let c_hull: Vec<Interval> = nn
        .a_lower
        .iter()
        .zip(nn.a_upper)
        .map(|(&a, &b)| Interval::new(a.min(b), a.max(b)))
        .collect();
    let a: Vec<Interval> = (0..n * n)
        .map(|ij| {
            let (i, j) = (ij / n, ij % n);
            (0..m).fold(problem.jacobian_over_region[ij], |s, k| {
                s + problem.g_over_region[i * m + k] * c_hull[k * n + j]
            })
        })
        .collect();
    log_norm(&a, n, problem.norm)
}

/// After a step: checks the box's orientation, intersects it with `S`'s half-spaces, checks
/// the set against `C`, records a sample.
fn advance(problem: &ReachProblem, state: &mut Live, t: f64, record: bool, safe: &SafeSet) {
    let inverted = state.lower.iter().zip(&state.upper).any(|(l, u)| l > u);
    let finite = state
        .lower
        .iter()
        .chain(&state.upper)
        .all(|v| v.is_finite());
    if inverted || !finite {
        state.tube.valid = false;
        state.tube.note = Some(format!(
            "t = {t:.3}: the embedding state became {} (Euler step too large for this system?)",
            if finite { "inverted" } else { "non-finite" }
        ));
        state.done = true;
        return;
    }
    clip_to_safe_set(&mut state.lower, &mut state.upper, &safe.z);
    let sample = problem.tube_sample(&state.lower, &state.upper, state.radius, t, safe);
    if !sample.set.is_subset_of(&problem.region) {
        state.tube.valid = false;
        state.tube.note = Some(format!("t = {t:.3}: the set left the region C"));
        state.tube.tube.push(sample);
        state.done = true;
    } else if record {
        state.tube.tube.push(sample);
    }
}

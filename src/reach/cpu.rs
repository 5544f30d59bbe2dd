//! The CPU reference engine: f64 with outward rounding, rayon over boxes.
//!
//! The boxes are split into chunks, one rayon task each, and a task integrates its chunk over
//! the whole horizon: each Euler step bounds the network over the chunk's live boxes in one
//! batch (GEMM-batched for IBP, forward and forward-backward bounds, box by box for CROWN) in
//! that thread, then advances each box's embedding state. Boxes are independent, so the
//! threads never wait for each other between steps.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::time::Instant;

use rayon::prelude::*;

use super::closeness::{closeness_step, log_norm};
use super::embedding::{
    embedding_field, embedding_field_by_face, embedding_step, NetworkBoundsRef,
};
use super::safe_set::{clip_to_safe_set, SafeSet};
use super::{Backend, ReachError, ReachMethod, ReachProblem, ReachResult, ReachSettings};
use super::{ReachTiming, Tube};
use crate::bounds::{AffineBoundsBatch, BoundsWorkspace, PreparedNetwork};
use crate::boxes::IntervalBox;
use crate::intervals::{round_up, Interval};

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
        let safe = problem.safe_set_for(settings.method);
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
                        exact_steps: 0,
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
        let network = PreparedNetwork::new(&problem.network)?;
        let threads = rayon::current_num_threads().max(1);
        let chunk = chunk_len(live.len(), threads);
        let accounted = AtomicUsize::new(0);
        let (n_boxes, steps) = (live.len(), problem.steps);
        let report = |box_steps: usize| {
            let done = accounted.fetch_add(box_steps, Ordering::Relaxed) + box_steps;
            progress(done / n_boxes.max(1), steps);
        };
        let run = ChunkRun {
            problem,
            settings,
            network: &network,
            safe,
            every,
            report: &report,
        };
        let minkowski_s: f64 = live
            .par_chunks_mut(chunk)
            .map_init(ChunkBuffers::default, |buffers, states| {
                run.horizon(states, buffers)
            })
            .collect::<Result<Vec<f64>, ReachError>>()?
            .iter()
            .sum::<f64>()
            / threads as f64;
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

/// Boxes per chunk: an even share of the threads, at most [`MAX_CHUNK`] so that large batches
/// make many chunks for rayon to balance (boxes that fail early leave their chunk lighter).
fn chunk_len(n_boxes: usize, threads: usize) -> usize {
    n_boxes.div_ceil(threads.max(1)).clamp(1, MAX_CHUNK)
}

/// Largest number of boxes one thread integrates together: a forward-bounds group of 64 boxes
/// is GEMMs of 192–256 columns, wide enough to amortise the pass over `W` (a 400×400 product
/// by 6 columns takes two thirds of the time of one by 18 or 24: the pass over `W` dominates
/// narrow products).
const MAX_CHUNK: usize = 64;

/// Buffers of one thread, reused across its chunks and steps.
#[derive(Default)]
struct ChunkBuffers {
    bounds: BoundsWorkspace,
    batch: AffineBoundsBatch,
    flat_lo: Vec<f64>,
    flat_hi: Vec<f64>,
    /// The error margin per input, `m` copies of the box's bound.
    margin: Vec<f64>,
    /// Per live box this step: its error margin, or `None` where `v = 0` exactly
    /// ([`ChunkRun::step_margin`]).
    margins: Vec<Option<f64>>,
    /// Zeros for [`zero_bounds`] (and the zero margin), sized once per chunk.
    zeros: Vec<f64>,
}

/// What every chunk's run shares.
struct ChunkRun<'a> {
    problem: &'a ReachProblem,
    settings: &'a ReachSettings,
    network: &'a PreparedNetwork<'a>,
    safe: &'a SafeSet,
    every: usize,
    /// Told how many box-steps were accounted for (run, or skipped by finished boxes).
    report: &'a (dyn Fn(usize) + Sync),
}

impl ChunkRun<'_> {
    /// The additive bound on every input of `N`'s error over the state's set, or `None` where
    /// `v = 0` exactly ([`ReachSettings::takes_v_zero_where_inactive`]). The transformed
    /// network's rounding enters as a disturbance in both methods; the disturbance method adds
    /// `M` (global, or local from the error map).
    fn step_margin(&self, state: &Live) -> Option<f64> {
        let problem = self.problem;
        match self.settings.method {
            ReachMethod::Minkowski => Some(problem.network_slack),
            ReachMethod::Disturbance => {
                let x_box = problem.x_box_in_safe_set(&state.lower, &state.upper, self.safe);
                if self.settings.takes_v_zero_where_inactive() && problem.inactive.proves(&x_box) {
                    return None;
                }
                Some(round_up(problem.margin_for(&x_box) + problem.network_slack))
            }
        }
    }

    /// Integrates `states` over the whole horizon in this thread: each Euler step bounds the
    /// network over the chunk's live boxes as one batch, then advances each box. Boxes are
    /// independent, so chunks need no synchronisation between steps. Returns the time spent
    /// on the closeness radius.
    fn horizon(&self, states: &mut [Live], buf: &mut ChunkBuffers) -> Result<f64, ReachError> {
        let (problem, settings) = (self.problem, self.settings);
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let mut minkowski_s = 0.0;
        buf.zeros.clear();
        buf.zeros.resize(m * n.max(1), 0.0);
        for step in 0..problem.steps {
            if states.iter().all(|s| s.done) {
                (self.report)((problem.steps - step) * states.len());
                break;
            }
            buf.flat_lo.clear();
            buf.flat_hi.clear();
            buf.margins.clear();
            for state in states.iter().filter(|s| !s.done) {
                let margin = self.step_margin(state);
                buf.margins.push(margin);
                if margin.is_none() {
                    continue;
                }
                let (lo, hi) = (&state.lower, &state.upper);
                if settings.face_local {
                    // 2n faces per box, in the order (0, lower), (0, upper), (1, lower), …
                    for i in 0..n {
                        for v in [lo[i], hi[i]] {
                            buf.flat_lo.extend(pinned(lo, i, v));
                            buf.flat_hi.extend(pinned(hi, i, v));
                        }
                    }
                } else {
                    buf.flat_lo.extend(lo);
                    buf.flat_hi.extend(hi);
                }
            }
            if !buf.flat_lo.is_empty() {
                self.network.bounds_serial_into(
                    &buf.flat_lo,
                    &buf.flat_hi,
                    settings.bounds,
                    &mut buf.bounds,
                    &mut buf.batch,
                )?;
            }
            let t = (step + 1) as f64 * problem.dt;
            let record = (step + 1) % self.every == 0 || step + 1 == problem.steps;
            let (batch, margin) = (&buf.batch, &mut buf.margin);
            let mut next_slot = 0;
            let live = states.iter_mut().filter(|s| !s.done);
            for (state, &bound) in live.zip(&buf.margins) {
                let (mut dl, mut du) = match bound {
                    None => {
                        // `v = 0` on the whole set: the filtered system's own field, no margin.
                        state.tube.exact_steps += 1;
                        let zero = zero_bounds(&buf.zeros, n, m);
                        embedding_field(
                            &problem.dynamics,
                            &state.lower,
                            &state.upper,
                            zero,
                            zero.b_lower,
                        )
                    }
                    Some(bound) => {
                        // This box's rows in the batch (boxes with `v = 0` have none).
                        let slot = next_slot;
                        next_slot += 1;
                        if !bound.is_finite() {
                            // The error map has no finite bound where the set is (e.g. where
                            // `v` jumps): nothing sound can be said from here on.
                            state.tube.valid = false;
                            state.tube.note = Some(format!(
                                "t = {:.3}: the set meets cells of the error map with no \
                                 certified bound (M = ∞)",
                                t - problem.dt
                            ));
                            state.done = true;
                            continue;
                        }
                        margin.clear();
                        margin.resize(m, bound);
                        if settings.face_local {
                            // (Minkowski is refused with face-local bounds: its rate needs one C.)
                            let face = |i: usize, up: bool| {
                                bounds_of(batch, slot * 2 * n + 2 * i + usize::from(up), n, m)
                            };
                            embedding_field_by_face(
                                &problem.dynamics,
                                &state.lower,
                                &state.upper,
                                face,
                                margin,
                            )
                        } else {
                            let nn = bounds_of(batch, slot, n, m);
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
                                minkowski_s += clock.elapsed().as_secs_f64();
                            }
                            embedding_field(
                                &problem.dynamics,
                                &state.lower,
                                &state.upper,
                                nn,
                                margin,
                            )
                        }
                    }
                };
                problem.widen_by_field_slack(&mut dl, &mut du);
                embedding_step(&mut state.lower, &mut state.upper, &dl, &du, problem.dt);
                advance(problem, state, t, record, self.safe);
            }
            (self.report)(states.len());
        }
        Ok(minkowski_s)
    }
}

/// `x` with coordinate `i` set to `v` (a face of a box).
fn pinned(x: &[f64], i: usize, v: f64) -> impl Iterator<Item = f64> + '_ {
    x.iter()
        .enumerate()
        .map(move |(j, &x_j)| if j == i { v } else { x_j })
}

/// The network's stand-in where `v = 0` exactly: zero forms and bounds (`zeros` holds at least
/// `m·n` and `m` zeros).
fn zero_bounds(zeros: &[f64], n: usize, m: usize) -> NetworkBoundsRef<'_> {
    NetworkBoundsRef {
        a_lower: &zeros[..m * n],
        b_lower: &zeros[..m],
        a_upper: &zeros[..m * n],
        b_upper: &zeros[..m],
        lower: &zeros[..m],
        upper: &zeros[..m],
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

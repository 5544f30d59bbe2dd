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

use super::embedding::{embedding_step, widen_by, NetworkBoundsRef};
use super::end_rates;
use super::safe_set::{clip_to_safe_set, frame_halfspaces, SafeHalfspace, SafeSet};
use super::sampled::Plant;
use super::validated::{self, Enclosure, Flowpipe};
use super::TimeModel;
use super::{Backend, ExactField, ReachError, ReachMethod, ReachProblem, ReachResult};
use super::{ReachSettings, ReachTiming, Tube, TubeEnd, TubeSample};
use crate::bounds::{AffineBounds, AffineBoundsBatch, BoundsWorkspace, PreparedNetwork};
use crate::boxes::IntervalBox;
use crate::filter::FilterPiece;
use crate::intervals::Interval;
use crate::rounding::round_up;

#[path = "cpu_time.rs"]
mod cpu_time;
use cpu_time::in_frame;

#[path = "cpu_enclose.rs"]
mod cpu_enclose;

#[path = "cpu_guess.rs"]
mod cpu_guess;

#[path = "cpu_sampled.rs"]
mod cpu_sampled;

#[path = "cpu_field.rs"]
mod cpu_field;

#[path = "cpu_host.rs"]
mod cpu_host;
use cpu_field::{
    bounds_of, constant_bounds, inverts, meet_fields, piece_dynamics, pinned, zero_bounds,
};
pub use cpu_host::{record_sample, HostStep, MetState, StepOutcome, StepState};

/// The CPU engine.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuBackend;

/// One coordinate frame the sets are kept in: the problem compiled in those coordinates, its
/// network prepared for bounds, and the half-spaces of `S` its sets are clipped to.
struct Frame<'a> {
    problem: &'a ReachProblem,
    network: PreparedNetwork<'a>,
    safe: &'a SafeSet,
    /// What the sets may be clipped to on a step where every true state is proven in `S`:
    /// `safe` itself, except for sampled-data runs, whose `safe` is empty and whose steps
    /// prove `S` only where the filter's constraint or the sets do ([`Live::in_s`]).
    in_s: &'a SafeSet,
    /// `safe`'s walls in this frame's coordinates ([`SafeSet::walls`]): sides no trajectory
    /// crosses, for the continuous step's enclosures.
    walls: Option<IntervalBox>,
}

impl<'a> Frame<'a> {
    /// The frame of problem `p` (one of a run's coordinate frames) under `method`; a digital
    /// filter does not keep the state in `S` between samples, so `sampled` sets are clipped to
    /// it only on steps proven in it.
    fn new(
        p: &'a ReachProblem,
        method: ReachMethod,
        sampled: bool,
    ) -> Result<Frame<'a>, ReachError> {
        let in_s = p.safe_set_for(method);
        let safe = match sampled {
            true => &super::safe_set::NO_SAFE_SET,
            false => in_s,
        };
        Ok(Frame {
            problem: p,
            network: PreparedNetwork::new(&p.network)?,
            safe,
            in_s,
            walls: safe.walls(p.dynamics.n),
        })
    }

    /// The safe set this step's sets are clipped to.
    fn clip(&self, in_s: bool) -> &'a SafeSet {
        match in_s {
            true => self.in_s,
            false => self.safe,
        }
    }
}

/// One box's embedding state while it is integrated.
struct Live {
    /// The embedding state in each frame (the first: the problem's own coordinates).
    sets: Vec<IntervalBox>,
    /// An x-box that every true state lies in: the frames' x-boxes met, within `S`.
    known: IntervalBox,
    radius: f64,
    tube: Tube,
    done: bool,
    /// Continuous time: this step's flowpipe in each frame (empty for the Euler map).
    pipes: Vec<Option<Flowpipe>>,
    /// Continuous time: the x-box of this step's flowpipes, met.
    pipe_known: Option<IntervalBox>,
    /// Continuous time: the hull of the flowpipes' x-boxes since the last sample.
    swept: Option<IntervalBox>,
    /// Continuous time: last step's field bounds per frame, to start the next enclosure from.
    guess: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// Continuous time: per frame, the network's bounds over the enclosure the step's flowpipe
    /// was proven on (where the network was bounded there).
    pipe_nn: Vec<Option<AffineBounds>>,
    /// Continuous time: per frame, the whole enclosure's flowpipe where `pipes` holds a moving
    /// box instead ([`validated::moving`]), to fall back to where the box is not proven.
    whole: Vec<Option<Flowpipe>>,
    /// Continuous time: per frame, last step's rates on the slabs, to guess the moving box from.
    rates: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// Continuous time: per frame, the rates of the step before (their trend guesses too).
    before: Vec<Option<(Vec<f64>, Vec<f64>)>>,
    /// Continuous time: whether this step's moving boxes were guessed without an enclosure
    /// ([`validated::guessed`]), to be proven by the step's rates.
    guessed: bool,
    /// Continuous time: whether the last step was the common path (its guessed moving boxes
    /// proven by the first check: what the GPU engine runs on the device, design §7.4).
    common: bool,
    /// Why this step inverted a set, if it did (found where the field's bounds are met).
    inversion: Option<super::tube::Inversion>,
    /// Sampled-data: what the set holds over the current control period.
    held: Option<cpu_sampled::Held>,
    /// Sampled-data: this step's true states are proven in `S` (the sets may be clipped to it).
    in_s: bool,
}

/// Where a run's network bounds over a batch of sets come from in place of the CPU's own: the
/// GPU engine's device at each sample of a sampled-data run (docs/design.md §7.4,
/// [`CpuBackend::reach_sampled_with`]). Each must be sound, as the CPU's are.
pub trait BatchBounds: Sync {
    /// The network `which` bounded over the boxes `[lower, upper]` (`n` coordinates per box, one
    /// after the other), written to `out` (resized to the boxes).
    fn bound(
        &self,
        which: Bounded,
        lower: &[f64],
        upper: &[f64],
        out: &mut AffineBoundsBatch,
    ) -> Result<(), ReachError>;
}

/// Which network a [`BatchBounds`] bounds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Bounded {
    /// The network of a frame the sets are kept in (an index into [`ReachProblem::frames`]),
    /// over the sets in its coordinates.
    Frame(usize),
    /// The network in x ([`ReachProblem::in_x`], or the problem's own), over the sets' x-boxes:
    /// the held input's enclosure of a sampled-data run.
    X,
}

impl CpuBackend {
    /// A sampled-data run of this engine whose network bounds over every live box's set at each
    /// sample come from `source` (one batch per frame: `initial` is one chunk, stepped in this
    /// thread); everything else (the images, the remainder, the findings, the tubes) is this
    /// engine's own code. The GPU engine runs `time = "sampled"` so, its device the source.
    pub fn reach_sampled_with(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
        source: &dyn BatchBounds,
    ) -> Result<ReachResult, ReachError> {
        if !matches!(problem.time, TimeModel::Sampled { .. }) {
            return Err(ReachError::Settings(format!(
                "network bounds from elsewhere are for time = \"sampled\", not \"{}\"",
                problem.time.name()
            )));
        }
        self.run(problem, initial, settings, progress, Some(source))
    }

    /// [`Backend::reach`], its network bounds from `source` where there is one (in one chunk).
    fn run(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
        source: Option<&dyn BatchBounds>,
    ) -> Result<ReachResult, ReachError> {
        problem.check_initial(initial)?;
        settings.validate()?;
        problem.check_time(settings)?;
        let period = problem.period_steps()?;
        let sampled = matches!(problem.time, TimeModel::Sampled { .. });
        if sampled && settings.method == ReachMethod::Minkowski {
            return Err(ReachError::Settings(
                "time = \"sampled\" works with method = disturbance only (the Minkowski \
                 method's closeness radius speaks of the continuous filter)"
                    .into(),
            ));
        }
        let x_problem = problem.in_x.as_deref().unwrap_or(problem);
        let start = Instant::now();
        let frames = problem
            .frames(settings)
            .into_iter()
            .map(|p| Frame::new(p, settings.method, sampled))
            .collect::<Result<Vec<Frame>, ReachError>>()?;
        let plant = match sampled {
            true => Some((
                Plant::of(problem.pieces.scenario()),
                PreparedNetwork::new(&x_problem.network)?,
            )),
            false => None,
        };
        let threads = rayon::current_num_threads().max(1);
        let accounted = AtomicUsize::new(0);
        let (n_boxes, steps) = (initial.len(), problem.steps);
        let report = |box_steps: usize| {
            let done = accounted.fetch_add(box_steps, Ordering::Relaxed) + box_steps;
            progress(done / n_boxes.max(1), steps);
        };
        let run = ChunkRun {
            frames,
            settings,
            every: settings.every.max(1),
            encloses: settings.exact_field() == ExactField::ClosedForm
                && problem.pieces.has_closed_form(),
            report: &report,
            time: problem.time,
            steps: problem.steps,
            substeps: problem.steps_per_dt(),
            h: problem.dt / problem.steps_per_dt() as f64,
            plant,
            x_problem,
            period,
            absorb: true,
            source,
        };
        let mut live: Vec<Live> = initial.iter().map(|b| run.start(b)).collect();
        let chunk = match source {
            Some(_) => live.len().max(1),
            None => chunk_len(live.len(), threads),
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
        self.run(problem, initial, settings, progress, None)
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

/// One frame's buffers in one thread, reused across its chunks and steps.
#[derive(Default)]
struct FrameBuffers {
    bounds: BoundsWorkspace,
    batch: AffineBoundsBatch,
    flat_lo: Vec<f64>,
    flat_hi: Vec<f64>,
    /// Per live box this step: how `v` is bounded ([`ChunkRun::step_input`]).
    inputs: Vec<StepInput>,
    /// Continuous time: the network's bounds over one candidate enclosure.
    pipe_bounds: BoundsWorkspace,
    pipe_batch: AffineBoundsBatch,
    /// The network's bounds of the last candidate enclosure, where it was bounded there.
    pipe_nn: Option<AffineBounds>,
}

/// Buffers of one thread, reused across its chunks and steps.
#[derive(Default)]
struct ChunkBuffers {
    frames: Vec<FrameBuffers>,
    /// The error margin per input, `m` copies of the box's bound.
    margin: Vec<f64>,
    /// Zeros for [`zero_bounds`] (and the zero margin), sized once per chunk.
    zeros: Vec<f64>,
    /// `v`'s enclosure on each face of one set ([`ChunkRun::enclosure_field`]).
    faces: Vec<f64>,
    /// Per live box this step: what its frames share ([`ChunkRun::set_facts`]).
    facts: Vec<SetFacts>,
    /// Per frame, the next box's rows in the frame's batch.
    slots: Vec<usize>,
    /// Per frame, whether the box's set stepped this step.
    stepped: Vec<bool>,
    /// Continuous time: the Picard enclosures in flight, batched over the chunk's boxes.
    enclosures: cpu_enclose::Enclosures,
    /// Per frame of one box-step: its fields, how `v` is bounded, where the network's bounds are.
    fields: Vec<FrameFields>,
    /// Sampled-data: the x network's bounds over the live boxes' x-boxes at a sample, for the
    /// held input ([`ChunkRun::held_bounds`]).
    held: cpu_sampled::HeldBounds,
}

/// Lower and upper rates of one step, `(dx̲/dt, dx̄/dt)`.
type Rates = (Vec<f64>, Vec<f64>);

/// One frame's box-step: its fields (piece, enclosures, network), how `v` is bounded, and where
/// the network's bounds are (whether the fallback's, and the row).
type FrameFields = ([Option<Rates>; 3], StepInput, Option<(bool, usize)>);

/// What every chunk's run shares.
struct ChunkRun<'a> {
    /// The frames the sets are kept in; more than one only with
    /// [`ReachSettings::intersect_x`].
    frames: Vec<Frame<'a>>,
    settings: &'a ReachSettings,
    every: usize,
    /// Whether sets with no proven piece also meet the network's bounds with the closed form's
    /// enclosures of `v` ([`ExactField::ClosedForm`]).
    encloses: bool,
    /// Told how many box-steps were accounted for (run, or skipped by finished boxes).
    report: &'a (dyn Fn(usize) + Sync),
    /// What the sets bound.
    time: TimeModel,
    /// Steps of `dt` to run (the problem's; one for the host's step from a given state).
    steps: usize,
    /// Engine steps per `dt` (validated substeps in continuous time, else 1).
    substeps: usize,
    /// The engine's step, `dt / substeps`.
    h: f64,
    /// Sampled-data: the plant's parts and the network in x, for the intersample remainder.
    plant: Option<(Plant, PreparedNetwork<'a>)>,
    /// The problem in x coordinates (the first frame's without a transform).
    x_problem: &'a ReachProblem,
    /// Sampled-data: steps per control period (1 otherwise).
    period: usize,
    /// Whether tubes stop in the problem's absorbing boxes (not on the host's single steps,
    /// whose times start at each step).
    absorb: bool,
    /// Where the network's bounds over a step's batch come from, if not this engine.
    source: Option<&'a dyn BatchBounds>,
}

/// What the frames of one box-step share ([`ChunkRun::set_facts`]).
#[derive(Clone, Copy, Debug)]
struct SetFacts {
    /// The piece `v` provably is on the set.
    piece: Option<FilterPiece>,
    /// The bound on the network's error over the set, where the network is bounded.
    m: Option<f64>,
}

/// What bounds `v` on one box-step: the filter's own field where it is provably one smooth
/// function on the set, the network plus an error margin, or both (each sound, neither always
/// the tighter: where a constraint binds, the mean-value form of its closed form can be looser
/// than the network's affine bounds; the field is their meet).
#[derive(Clone, Copy, Debug)]
struct StepInput {
    /// The piece `v` provably is on the set, with the transform's slack for its field there.
    piece: Option<(FilterPiece, f64)>,
    /// The additive bound on every input of the network's error over the set, where the network
    /// is bounded (`None` where `v = 0`, or where the error map has no finite bound).
    margin: Option<f64>,
}

impl ChunkRun<'_> {
    /// A box's state before the first step: its set in every frame, met.
    fn start(&self, initial: &IntervalBox) -> Live {
        let sets = self
            .frames
            .iter()
            .map(|f| f.problem.initial_state(initial, self.settings.method))
            .collect();
        let mut state = Live {
            sets,
            known: initial.clone(),
            radius: 0.0,
            tube: Tube::new(initial.clone()),
            done: false,
            pipes: Vec::new(),
            pipe_known: None,
            swept: None,
            guess: vec![None; self.frames.len()],
            pipe_nn: vec![None; self.frames.len()],
            whole: vec![None; self.frames.len()],
            rates: vec![None; self.frames.len()],
            before: vec![None; self.frames.len()],
            guessed: false,
            common: false,
            inversion: None,
            held: None,
            in_s: false,
        };
        self.settle(&mut state, &vec![true; self.frames.len()]);
        let sample = self.sample(&state, 0.0);
        state.tube.tube.push(sample);
        state
    }

    /// Meets the frames' sets after a step: `known` becomes the meet of the x-boxes of the sets
    /// that stepped, and with several frames each set is met with the box of its coordinates
    /// around `known` (replaced by it where the frame could not step). Every set keeps every
    /// true state: each bounds them on its own.
    fn settle(&self, state: &mut Live, stepped: &[bool]) {
        let known = self
            .frames
            .iter()
            .zip(&state.sets)
            .zip(stepped)
            .filter(|(_, &s)| s)
            .map(|((f, set), _)| {
                let safe = f.clip(state.in_s);
                f.problem.x_box_in_safe_set(&set.lower, &set.upper, safe)
            })
            .reduce(|a, b| a.intersection(&b).unwrap_or(a));
        let Some(known) = known else {
            return;
        };
        if self.frames.len() > 1 {
            let in_s = state.in_s;
            for ((f, set), &s) in self.frames.iter().zip(&mut state.sets).zip(stepped) {
                let around = f.problem.frame_box(&known);
                *set = match s {
                    true => set.intersection(&around).unwrap_or_else(|| set.clone()),
                    false => around,
                };
                clip_to_safe_set(&mut set.lower, &mut set.upper, &f.clip(in_s).z);
            }
        }
        state.known = known;
    }

    /// The recorded sample of a state: the first frame's, its x-box met with `known`.
    fn sample(&self, state: &Live, t: f64) -> TubeSample {
        let (f, set) = (&self.frames[0], &state.sets[0]);
        let mut sample =
            f.problem
                .tube_sample(&set.lower, &set.upper, state.radius, t, f.clip(state.in_s));
        if self.frames.len() > 1 {
            if let Some(met) = sample.set.intersection(&state.known) {
                sample.lower.clone_from(&met.lower);
                sample.upper.clone_from(&met.upper);
                sample.set = met;
            }
        }
        sample
    }

    /// What the frames of one box-step share, as both depend on the x-box `known` alone: the
    /// piece of the filter proven there where the settings take one
    /// ([`ReachSettings::exact_field`]), and the error bound `M` there (global, or local from
    /// the error map) except where `v = 0`.
    fn set_facts(&self, x_box: &IntervalBox) -> SetFacts {
        let problem = self.frames[0].problem;
        let piece = match self.settings.exact_field() {
            ExactField::Nowhere => None,
            ExactField::Inactive => problem
                .pieces
                .proves_inactive(x_box)
                .then_some(FilterPiece::Inactive),
            ExactField::ClosedForm => problem.pieces.piece_on(x_box),
        };
        let m = match (self.settings.method, piece) {
            (ReachMethod::Minkowski, _) | (_, Some(FilterPiece::Inactive)) => None,
            _ => Some(problem.margin_for(x_box)),
        };
        SetFacts { piece, m }
    }

    /// How `v` is bounded over a set whose true states lie in `x_box`, in one frame: the proven
    /// piece of `facts` with this frame's slack for its field, and the network with an additive
    /// bound on every input's error except where `v = 0`. The transformed network's rounding
    /// enters as a disturbance in both methods; the disturbance method adds `M`.
    fn step_input(
        &self,
        problem: &ReachProblem,
        x_box: &IntervalBox,
        facts: SetFacts,
    ) -> StepInput {
        if self.settings.method == ReachMethod::Minkowski {
            return StepInput {
                piece: None,
                margin: Some(problem.network_slack),
            };
        }
        StepInput {
            piece: facts.piece.map(|p| (p, problem.piece_slack(p, x_box))),
            margin: facts
                .m
                .map(|m| round_up(m + problem.network_slack))
                .filter(|m| m.is_finite()),
        }
    }

    /// Integrates `states` over the whole horizon in this thread: each Euler step bounds the
    /// network over the chunk's live boxes as one batch per frame, then advances each box.
    /// Boxes are independent, so chunks need no synchronisation between steps. Returns the time
    /// spent on the closeness radius.
    fn horizon(&self, states: &mut [Live], buf: &mut ChunkBuffers) -> Result<f64, ReachError> {
        let (problem, settings) = (self.frames[0].problem, self.settings);
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let mut minkowski_s = 0.0;
        buf.zeros.clear();
        buf.zeros.resize(m * n.max(1), 0.0);
        buf.frames
            .resize_with(self.frames.len(), FrameBuffers::default);
        let k = self.substeps;
        let steps = self.steps;
        for step in 0..steps * k {
            if states.iter().all(|s| s.done) {
                (self.report)((steps - step / k) * states.len());
                break;
            }
            // Sampled-data within a control period: the sets follow the images held at its
            // sample, with no new bounds.
            let held_j = step % self.period;
            if self.plant.is_some() && held_j != 0 {
                let t = (step + 1) as f64 * problem.dt;
                let record = (step + 1) % self.every == 0 || step + 1 == steps;
                for state in states.iter_mut().filter(|s| !s.done) {
                    self.sampled_step(state, held_j + 1, t, record)?;
                }
                (self.report)(states.len());
                continue;
            }
            let t0 = (step / k) as f64 * problem.dt + (step % k) as f64 * self.h;
            if self.time == TimeModel::Continuous {
                self.enclose_all(states, buf, t0)?;
            }
            buf.facts.clear();
            let live = states.iter().filter(|s| !s.done);
            buf.facts.extend(
                live.map(|state| self.set_facts(state.pipe_known.as_ref().unwrap_or(&state.known))),
            );
            for (f, (frame, fb)) in self.frames.iter().zip(&mut buf.frames).enumerate() {
                fb.flat_lo.clear();
                fb.flat_hi.clear();
                fb.inputs.clear();
                let live = states.iter().filter(|s| !s.done);
                for (state, &facts) in live.zip(&buf.facts) {
                    let known = state.pipe_known.as_ref().unwrap_or(&state.known);
                    let input = self.step_input(frame.problem, known, facts);
                    fb.inputs.push(input);
                    if input.margin.is_none() {
                        continue;
                    }
                    let set = &state.sets[f];
                    if let Some(Some(pipe)) = state.pipes.get(f) {
                        self.push_pipe_boxes(fb, set, pipe);
                        continue;
                    }
                    let (lo, hi) = (&set.lower, &set.upper);
                    // Sampled-data images the held input off the faces too: whole-set bounds.
                    if settings.face_local && self.plant.is_none() {
                        // 2n faces per box, in the order (0, lower), (0, upper), (1, lower), …
                        for i in 0..n {
                            for v in [lo[i], hi[i]] {
                                fb.flat_lo.extend(pinned(lo, i, v));
                                fb.flat_hi.extend(pinned(hi, i, v));
                            }
                        }
                    } else {
                        fb.flat_lo.extend(lo);
                        fb.flat_hi.extend(hi);
                    }
                }
                match self.source {
                    _ if fb.flat_lo.is_empty() => {}
                    Some(s) => {
                        s.bound(Bounded::Frame(f), &fb.flat_lo, &fb.flat_hi, &mut fb.batch)?
                    }
                    None => frame.network.bounds_serial_into(
                        &fb.flat_lo,
                        &fb.flat_hi,
                        settings.bounds,
                        &mut fb.bounds,
                        &mut fb.batch,
                    )?,
                }
            }
            let last_sub = (step + 1) % k == 0;
            let outer = step / k;
            let t = match last_sub {
                true => (outer + 1) as f64 * problem.dt,
                false => outer as f64 * problem.dt + ((step % k) + 1) as f64 * self.h,
            };
            let record = last_sub && ((outer + 1).is_multiple_of(self.every) || outer + 1 == steps);
            buf.slots.clear();
            buf.slots.resize(self.frames.len(), 0);
            if self.plant.is_some() {
                self.held_bounds(states, buf)?;
            }
            let live = states.iter_mut().filter(|s| !s.done);
            for (k, state) in live.enumerate() {
                buf.stepped.clear();
                if self.plant.is_some() {
                    self.hold(state, buf, k, t - self.h)?;
                    if !state.done {
                        self.sampled_step(state, 1, t, record)?;
                    }
                    continue;
                }
                // Every frame's fields first: a guessed moving box stands only if all frames'
                // rates prove it (item 3b); where not, the enclosure and its slabs replace it.
                buf.fields.clear();
                for (f, frame) in self.frames.iter().enumerate() {
                    let input = buf.frames[f].inputs[k];
                    // This box's rows in the batch (boxes without a margin have none).
                    let slot = input.margin.map(|_| {
                        buf.slots[f] += 1;
                        buf.slots[f] - 1
                    });
                    let (fields, s) = self.first_fields(frame, state, f, input, slot, buf);
                    minkowski_s += s;
                    buf.fields.push((fields, input, slot.map(|s| (false, s))));
                }
                state.common = state.guessed && self.guess_holds(state, &buf.fields);
                if state.guessed && !state.common {
                    self.fall_back(state, buf, t0)?;
                    if state.done {
                        continue;
                    }
                }
                for (f, frame) in self.frames.iter().enumerate() {
                    // Taken, not cloned: the box's fields are not read again this step.
                    let (fields, input, rows) = &mut buf.fields[f];
                    let (mut fields, input, rows) = (std::mem::take(fields), *input, *rows);
                    buf.margin.clear();
                    buf.margin.resize(m, input.margin.unwrap_or(0.0));
                    // Continuous time: the moving box checked (else the whole enclosure's
                    // slabs), and second-order rates.
                    let taylor = self.check_step(
                        frame,
                        state,
                        f,
                        input,
                        &mut fields,
                        (&mut buf.frames[f], &buf.zeros, &buf.margin),
                        rows,
                    )?;
                    let [exact, enclosed, network] = fields;
                    let sources: Vec<_> = [exact, taylor, enclosed, network]
                        .into_iter()
                        .flatten()
                        .collect();
                    let field = sources.iter().cloned().reduce(meet_fields);
                    if let Some((dl, du)) = &field {
                        let set = &state.sets[f];
                        if inverts(set, dl, du, self.h) {
                            state.inversion = Some(
                                if sources.len() > 1
                                    && sources.iter().all(|(l, u)| !inverts(set, l, u, self.h))
                                {
                                    super::tube::Inversion::BoundsDisagree
                                } else {
                                    super::tube::Inversion::StepTooLarge
                                },
                            );
                        }
                    }
                    if let Some((dl, du)) = &field {
                        let set = &mut state.sets[f];
                        embedding_step(&mut set.lower, &mut set.upper, dl, du, self.h);
                        if let Some(Some(pipe)) = state.pipes.get(f) {
                            validated::meet_with_pipe(&mut set.lower, &mut set.upper, pipe);
                            let inverted = (set.lower.iter().zip(&set.upper)).any(|(l, u)| l > u);
                            if state.inversion.is_none() && inverted {
                                state.inversion = Some(super::tube::Inversion::PipeDisjoint);
                            }
                        }
                    }
                    buf.stepped.push(field.is_some());
                }
                if !buf.stepped.iter().any(|&s| s) {
                    // The error map has no finite bound where the set is (e.g. where `v`
                    // jumps), in every frame: nothing sound can be said from here on.
                    state.tube.end = TubeEnd::NoCertifiedBound {
                        t: t - self.h,
                        beyond_c: problem.certified_on_all_of_c(),
                    };
                    state.done = true;
                    continue;
                }
                self.advance(state, t, record, &buf.stepped);
            }
            if last_sub {
                (self.report)(states.len());
            }
        }
        Ok(minkowski_s)
    }

    /// After a step: checks the sets' orientation, intersects them with `S`'s half-spaces and
    /// with each other, checks the set against `C`, records a sample.
    fn advance(&self, state: &mut Live, t: f64, record: bool, stepped: &[bool]) {
        let sets = state.sets.iter().zip(stepped).filter(|(_, &s)| s);
        let inverted = sets
            .clone()
            .any(|(set, _)| set.lower.iter().zip(&set.upper).any(|(l, u)| l > u));
        let finite = sets
            .flat_map(|(set, _)| set.lower.iter().chain(&set.upper))
            .all(|v| v.is_finite());
        if inverted || !finite {
            state.tube.end = if finite {
                TubeEnd::Inverted {
                    t,
                    cause: state
                        .inversion
                        .unwrap_or(super::tube::Inversion::Unattributed),
                }
            } else {
                TubeEnd::NonFinite { t }
            };
            state.done = true;
            return;
        }
        let in_s = state.in_s;
        for ((f, set), _) in self
            .frames
            .iter()
            .zip(&mut state.sets)
            .zip(stepped)
            .filter(|(_, &s)| s)
        {
            clip_to_safe_set(&mut set.lower, &mut set.upper, &f.clip(in_s).z);
        }
        self.settle(state, stepped);
        let sample = self.sample(state, t);
        let problem = self.frames[0].problem;
        // Checked on recorded samples alone, which the GPU engine's tubes are cut at too.
        let absorbed =
            record && self.absorb && super::absorb::absorber(problem, t, &sample.set).is_some();
        let pipe = state.pipe_known.as_ref();
        let (tube, swept) = (&mut state.tube, &mut state.swept);
        if record_sample(
            &problem.region,
            tube,
            swept,
            pipe,
            sample,
            (t, self.h),
            record,
        ) {
            state.done = true;
        } else if absorbed {
            state.tube.end = TubeEnd::Absorbed { t };
            state.done = true;
        }
    }
}

#[cfg(test)]
#[path = "cpu_tests.rs"]
mod tests;

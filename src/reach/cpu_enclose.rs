//! The CPU engine's Picard–Lindelöf enclosures (design §7.1 item 1), batched over a chunk's
//! boxes. [`validated::enclose_step`] asks the field over one candidate at a time; one box at a
//! time, each ask was a matrix–vector pass over the network's weights (~30 a box on its first
//! step, most of a continuous run's time). Here every box's enclosure is replayed against the
//! answers found so far up to its next ask, and the asks of all boxes are answered together:
//! their network bounds in one batch (GEMMs), then each field as before. The answers are the
//! same boxes' bounds (up to the batch's rounding, sound either way), so each enclosure is the
//! one the box alone would find.
//! A child of `reach::cpu`; imports what `cpu` imports.

use super::*;
use crate::reach::validated::OpenCause;

/// What [`validated::enclose_step`] asks of the field: a candidate, and whether as the hull over
/// its parts.
type Ask = (IntervalBox, bool);

/// One ask answered: the field's bounds and, over a whole candidate, the network's there.
struct Answer {
    ask: Ask,
    field: Option<Rates>,
    nn: Option<AffineBounds>,
}

/// The enclosures of one chunk and frame in flight: per box, the answers so far; this round's
/// asks and their network bounds.
#[derive(Default)]
pub(super) struct Enclosures {
    answers: Vec<Vec<Answer>>,
    asks: Vec<(usize, Ask)>,
    lo: Vec<f64>,
    hi: Vec<f64>,
    bounds: BoundsWorkspace,
    batch: AffineBoundsBatch,
}

/// A box's x-box within `S` and how `v` is bounded there ([`ChunkRun::field_on_box`]).
pub(super) type BoxInput = (IntervalBox, StepInput);

/// A replay that ended: what it found, the last whole candidate it bounded, and the network's
/// bounds there.
type Replayed = (Enclosure, Option<IntervalBox>, Option<AffineBounds>);

impl ChunkRun<'_> {
    /// Encloses the next step of every frame's set of each of `states` (Picard–Lindelöf), all
    /// boxes' asks answered in rounds of one batch; the step's facts and bounds then come from
    /// the flowpipes. Ends the tube of a box where no enclosure closes.
    pub(super) fn enclose_boxes(
        &self,
        states: &mut [&mut Live],
        buf: &mut ChunkBuffers,
        t0: f64,
    ) -> Result<(), ReachError> {
        for state in states.iter_mut() {
            state.pipes.clear();
        }
        for f in 0..self.frames.len() {
            let enc = &mut buf.enclosures;
            enc.answers.clear();
            enc.answers.resize_with(states.len(), Vec::new);
            // The boxes still enclosing in this frame (a box whose last frame failed is done).
            let mut open: Vec<usize> = (0..states.len()).filter(|&k| !states[k].done).collect();
            while !open.is_empty() {
                enc.asks.clear();
                for &k in &open {
                    match self.replay(states[k], f, &enc.answers[k]) {
                        Ok(found) => self.settle_enclosure(states[k], f, found, t0),
                        Err(ask) => enc.asks.push((k, ask)),
                    }
                }
                self.answer(f, enc, &mut buf.frames[f], &buf.zeros)?;
                open = enc.asks.iter().map(|(k, _)| *k).collect();
            }
        }
        for state in states.iter_mut().filter(|s| !s.done) {
            // Facts hold on the whole enclosures (a moving box lies in its frame's).
            self.meet_pipes(state);
        }
        Ok(())
    }

    /// Runs frame `f`'s enclosure of `state`'s step against `answers`: what it found, or the
    /// first ask they do not answer.
    fn replay(&self, state: &Live, f: usize, answers: &[Answer]) -> Result<Replayed, Ask> {
        let frame = &self.frames[f];
        let guess = state.guess[f].as_ref().map(|(l, u)| (&l[..], &u[..]));
        // `C` bounds the enclosure in x frames (M and the verdicts hold there only).
        let region = frame
            .problem
            .transform
            .is_none()
            .then_some(&frame.problem.region);
        // The box the network's bounds `nn` are over (the last one bounded whole; the parts keep
        // it): a face of `C` (item 1c) or the second half of a halved step (1d) may come last,
        // and the second-order rates need bounds over the whole flowpipe.
        let mut bounded: Option<IntervalBox> = None;
        let mut nn: Option<&AffineBounds> = None;
        // Points proven in `S`, whose trajectories stay there, for item 1e: only for the
        // filtered system (the disturbance method's; the Minkowski method bounds the network's).
        let scenario = frame.problem.pieces.scenario();
        let disturbance = self.settings.method == ReachMethod::Disturbance;
        let safe = |x: &[f64]| disturbance && point_in_safe_set(scenario, x);
        let set = &state.sets[f];
        // None but under the disturbance method (the frame's `safe` is empty otherwise).
        let walls = frame.walls.as_ref();
        let found =
            validated::enclose_within(set, self.h, guess, region, walls, &safe, |a, parts| {
                let Some(answer) = answers.iter().find(|x| x.ask.1 == parts && x.ask.0 == *a)
                else {
                    return Err((a.clone(), parts));
                };
                if !parts {
                    bounded = Some(a.clone());
                    nn = answer.nn.as_ref();
                }
                Ok(answer.field.clone())
            })?;
        Ok((found, bounded, nn.cloned()))
    }

    /// Answers this round's asks of frame `f`: the network bounded over every candidate and
    /// part that takes it in one batch, then each one's field ([`ChunkRun::field_on_box`], the
    /// hull over the parts, parts proven outside `S` dropped: no trajectory visits them).
    fn answer(
        &self,
        f: usize,
        enc: &mut Enclosures,
        fb: &mut FrameBuffers,
        zeros: &[f64],
    ) -> Result<(), ReachError> {
        let frame = &self.frames[f];
        let p = frame.problem;
        let (n, m) = (p.dynamics.n, p.dynamics.m);
        let Enclosures {
            answers,
            asks,
            lo,
            hi,
            bounds,
            batch,
        } = enc;
        lo.clear();
        hi.clear();
        let mut rows = 0;
        // Per ask, its boxes, each with its x-box and input (computed once: the facts are a
        // fifth of an enclosure's interval evaluation) and its row in the batch (where the
        // network is bounded).
        let queued: Vec<Vec<(IntervalBox, BoxInput, Option<usize>)>> = asks
            .iter()
            .map(|(_, (a, parts))| {
                let boxes = match parts {
                    false => vec![a.clone()],
                    true => self.parts_in_safe_set(frame, a),
                };
                boxes
                    .into_iter()
                    .map(|b| {
                        let x_box = p.x_box_in_safe_set(&b.lower, &b.upper, frame.safe);
                        let input = self.step_input(p, &x_box, self.set_facts(&x_box));
                        let row = input.margin.map(|_| {
                            lo.extend(&b.lower);
                            hi.extend(&b.upper);
                            rows += 1;
                            rows - 1
                        });
                        (b, (x_box, input), row)
                    })
                    .collect()
            })
            .collect();
        if rows > 0 {
            let method = self.settings.bounds.for_enclosures();
            frame
                .network
                .bounds_serial_into(lo, hi, method, bounds, batch)?;
        }
        for ((k, ask), boxes) in asks.iter().zip(queued) {
            let mut field: Option<Rates> = None;
            for (b, input, row) in &boxes {
                let nn = row.map(|r| bounds_of(batch, r, n, m));
                let Some((l, u)) = self.field_on_box(frame, b, input, fb, zeros, nn)? else {
                    field = None;
                    break;
                };
                field = Some(match field {
                    None => (l, u),
                    Some((fl, fu)) => (
                        fl.iter().zip(&l).map(|(x, y)| x.min(*y)).collect(),
                        fu.iter().zip(&u).map(|(x, y)| x.max(*y)).collect(),
                    ),
                });
            }
            let nn = match ask.1 {
                false => fb.pipe_nn.take(),
                true => None,
            };
            fb.pipe_nn = None;
            answers[*k].push(Answer {
                ask: ask.clone(),
                field,
                nn,
            });
        }
        Ok(())
    }

    /// The parts of candidate `a` ([`validated::parts`], at most [`PARTS`]) not proven outside
    /// `S`; none where the dimension allows no cut.
    fn parts_in_safe_set(&self, frame: &Frame, a: &IntervalBox) -> Vec<IntervalBox> {
        let p = frame.problem;
        let n = p.dynamics.n;
        // Parts per axis: at most `PARTS` boxes in all.
        let k = crate::boxes::per_axis_within(n, PARTS, 3);
        if k == 1 {
            return Vec::new();
        }
        validated::parts(a, k)
            .into_iter()
            .filter(|part| {
                let x_box = p.x_box_in_safe_set(&part.lower, &part.upper, frame.safe);
                !crate::surrogate_error::proven_unsafe(p.pieces.scenario(), &x_box)
            })
            .collect()
    }

    /// Keeps frame `f`'s enclosure of `state`'s step: its flowpipe (or, where the disturbance
    /// method runs, the moving box from last step's rates within it), the field's bounds there
    /// for the next step's guess, and the network's bounds over the candidate it closed on;
    /// where none closed, ends the tube.
    fn settle_enclosure(&self, state: &mut Live, f: usize, found: Replayed, t0: f64) {
        let (found, bounded, nn) = found;
        state.tube.end = match found {
            Enclosure::Closed(pipe) => {
                state.guess[f] = Some((pipe.f_lower.clone(), pipe.f_upper.clone()));
                let covers = bounded.is_some_and(|b| pipe.set.is_subset_of(&b));
                state.pipe_nn[f] = nn.filter(|_| covers);
                // A moving box from last step's rates, where the disturbance method runs (the
                // Minkowski radius advances once per step, with no fallback).
                let moving = match (self.settings.method, &state.rates[f]) {
                    (ReachMethod::Disturbance, Some((l, u))) => {
                        validated::moving(&state.sets[f], &pipe, self.h, (l, u))
                    }
                    _ => None,
                };
                state
                    .pipes
                    .push(Some(moving.clone().unwrap_or_else(|| pipe.clone())));
                state.whole[f] = moving.map(|_| pipe);
                return;
            }
            // The step's enclosure meets cells of the error map with no certified bound.
            Enclosure::NoField => TubeEnd::NoCertifiedBound {
                t: t0,
                beyond_c: self.frames[0].problem.certified_on_all_of_c(),
            },
            Enclosure::Open(cause) => TubeEnd::NoEnclosure {
                t: t0,
                h: self.h,
                cause: match cause {
                    // At the start the set in x is the initial box; in z it holds more.
                    OpenCause::Exits if t0 == 0.0 && self.frames[f].problem.transform.is_none() => {
                        OpenCause::ExitsFromStart
                    }
                    cause => cause,
                },
            },
        };
        state.done = true;
    }
}

/// Whether every barrier `hᵢ ≥ 0` at the point `x` (by interval evaluation): `x ∈ S`.
fn point_in_safe_set(s: &crate::scenario::Scenario, x: &[f64]) -> bool {
    let xs: Vec<Interval> = x.iter().map(|&v| Interval::point(v)).collect();
    s.cbfs.iter().all(|c| c.h.eval_interval(&xs).lower >= 0.0)
}

/// Most parts a candidate enclosure is cut into ([`ChunkRun::answer`]): 3 × 3 in the plane,
/// 2 × 2 × 2 in space, none beyond.
const PARTS: usize = 9;

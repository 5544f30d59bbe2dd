//! The CPU engine's sampled-data step (issue 36, [`crate::reach::sampled`]): at each sample
//! `t_k` the held input's Euler part is imaged over the set for every step of the control
//! period, and each step's set is that image plus the remainder. A child of `reach::cpu` (it
//! works on that engine's chunk state); imports what `cpu` imports.

use super::*;
use crate::intervals::box_of;
use crate::reach::embedding::input_enclosure;
use crate::reach::sampled::{euler_image, proven_safe, Intersample};
use crate::reach::sampled_second::{frame_speed, held_terms, mix_in_frame, spread_term};

/// The x network's bounds at a sample over the x-boxes of the chunk's live boxes whose held
/// input needs them, in one batch ([`ChunkRun::held_bounds`]).
#[derive(Default)]
pub(super) struct HeldBounds {
    batch: AffineBoundsBatch,
    workspace: BoundsWorkspace,
    lower: Vec<f64>,
    upper: Vec<f64>,
    /// Per live box, its row in `batch` (`None`: its held input bounds no network).
    rows: Vec<Option<usize>>,
}

impl HeldBounds {
    /// Box `live`'s `(N̲, N̄)`, where it has a row.
    fn of(&self, live: usize) -> Option<(&[f64], &[f64])> {
        let r = self.rows.get(live).copied().flatten()?;
        let m = self.batch.n_out;
        Some((
            &self.batch.lower[r * m..(r + 1) * m],
            &self.batch.upper[r * m..(r + 1) * m],
        ))
    }
}

/// What a set holds over one control period.
pub(super) struct Held {
    /// Per frame, the Euler part's images at `τ = 0, dt, …, K·dt` (the first: the set at the
    /// sample); `None` where the frame has no sound field.
    images: Vec<Option<Vec<IntervalBox>>>,
    /// Per frame, the sets at `τ = dt, …, K·dt` by the held motion's second-order image
    /// ([`crate::reach::sampled_second`], remainders included), met with the images' sets;
    /// `None` where it does not apply (state-dependent `g`, a still plant, no field).
    second: Vec<Option<Vec<IntervalBox>>>,
    /// The motion between samples.
    inter: Intersample,
    /// The set's x-box at the sample, and what its box-step's frames shared there.
    sample: IntervalBox,
    facts: SetFacts,
    /// Per CBF, an enclosure of `h(x_k)` over `sample`, its lower end raised to 0 (the true
    /// state is in `S` at the sample) and NaN taken as 0.
    h_k: Vec<Interval>,
    /// Every state since the sample: the hull of the steps' flowpipes (`None` where a step
    /// had none).
    motion: Option<IntervalBox>,
    /// The held input's enclosure for [`Plant::keeps`], the plant's own `U` or, for a still
    /// plant (which needs none to move), made when a check first needs it.
    input: Option<Option<Vec<Interval>>>,
}

impl ChunkRun<'_> {
    /// At a sample, before [`Self::hold`]: the x network bounded over the x-box of every live
    /// box whose held input bounds `v` by the network (a plant that moves, `v` not proven 0, a
    /// finite margin; `buf.facts` this sample's), in one batch, from the run's source where it
    /// has one (the GPU engine's device).
    pub(super) fn held_bounds(
        &self,
        states: &[Live],
        buf: &mut ChunkBuffers,
    ) -> Result<(), ReachError> {
        let (plant, x_net) = self.plant.as_ref().expect("sampled runs have a plant");
        let held = &mut buf.held;
        held.rows.clear();
        held.lower.clear();
        held.upper.clear();
        let n = self.x_problem.dynamics.n;
        let live = states.iter().filter(|s| !s.done);
        for (state, facts) in live.zip(&buf.facts) {
            let needs = !plant.is_still()
                && facts.piece != Some(FilterPiece::Inactive)
                && facts.m.is_some_and(f64::is_finite);
            held.rows.push(needs.then(|| {
                held.lower.extend(&state.known.lower);
                held.upper.extend(&state.known.upper);
                held.lower.len() / n - 1
            }));
        }
        match self.source {
            _ if held.lower.is_empty() => {}
            Some(s) => s.bound(Bounded::X, &held.lower, &held.upper, &mut held.batch)?,
            None => x_net.bounds_serial_into(
                &held.lower,
                &held.upper,
                self.settings.bounds,
                &mut held.workspace,
                &mut held.batch,
            )?,
        }
        Ok(())
    }

    /// At a sample: encloses the period's motion from the set and images its Euler part over
    /// every step of the period, per frame, from the meet of the sound bounds of the field over
    /// the whole set (the filter's proven piece, its enclosure of `v`, the network's bounds
    /// `slot` of the frames' batches plus the margin). Ends the tube where the motion has no
    /// enclosure, or no frame has a field.
    pub(super) fn hold(
        &self,
        state: &mut Live,
        buf: &mut ChunkBuffers,
        live: usize,
        t: f64,
    ) -> Result<(), ReachError> {
        // This box's rows in each frame's batch (boxes without a margin have none), taken
        // before anything can end the tube so that the next box finds its own.
        let slots: Vec<Option<usize>> = (0..self.frames.len())
            .map(|f| {
                buf.frames[f].inputs[live].margin.map(|_| {
                    buf.slots[f] += 1;
                    buf.slots[f] - 1
                })
            })
            .collect();
        let buf = &*buf;
        let facts = buf.facts[live];
        let plant = self.plant.as_ref().expect("sampled runs have a plant");
        let u = match plant.0.is_still() {
            true => Some(Vec::new()),
            false => self.held_input(plant, &state.known, facts, buf.held.of(live))?,
        };
        let Some(u) = u else {
            state.tube.end = TubeEnd::NoIntersampleEnclosure { t };
            state.done = true;
            return Ok(());
        };
        let (n, m) = (state.known.dim(), self.x_problem.dynamics.m);
        let terms = held_terms(&plant.0, &state.known, &u, self.h, self.period);
        let inter = Intersample::start(n, u);
        let zeros = &buf.zeros;
        let mut images = Vec::with_capacity(self.frames.len());
        let mut second = Vec::with_capacity(self.frames.len());
        for (f, frame) in self.frames.iter().enumerate() {
            let p = frame.problem;
            let input = buf.frames[f].inputs[live];
            let set = &state.sets[f];
            let x_box = p.x_box_in_safe_set(&set.lower, &set.upper, frame.safe);
            let enclosure = match input.piece.is_none() && self.encloses {
                true => p.pieces.finite_enclosure(&x_box),
                false => None,
            }
            .map(|v| {
                let slack = p.pieces.field_slack(&x_box, &v);
                let (lo, hi): (Vec<f64>, Vec<f64>) = v.iter().map(|e| (e.lower, e.upper)).unzip();
                (lo, hi, slack)
            });
            let network = input
                .margin
                .zip(slots[f])
                .map(|(bound, slot)| (slot, vec![bound; m]));
            // The sound fields over the set: the filter's proven piece (its own field), its
            // enclosure of `v`, the network's bounds plus the margin; each as (dynamics,
            // bounds of v, margin, slack).
            let zero = zero_bounds(zeros, n, m);
            let mut fields: Vec<(&crate::reach::Dynamics, NetworkBoundsRef, &[f64], f64)> =
                Vec::with_capacity(3);
            if let Some((piece, slack)) = input.piece {
                fields.push((piece_dynamics(p, piece), zero, zero.b_lower, slack));
            }
            if let Some((lo, hi, slack)) = &enclosure {
                let consts = constant_bounds(zeros, lo, hi, n);
                fields.push((&p.dynamics, consts, &zeros[..m], *slack));
            }
            if let Some((slot, margin)) = &network {
                let nn = bounds_of(&buf.frames[f].batch, *slot, n, m);
                fields.push((&p.dynamics, nn, margin, p.field_slack));
            }
            let image = |tau: f64| -> Option<IntervalBox> {
                let (lower, upper) = fields
                    .iter()
                    .map(|&(d, nn, margin, slack)| {
                        euler_image(d, set, tau, nn, margin, slack, None)
                    })
                    .reduce(meet_fields)?;
                Some(IntervalBox { lower, upper })
            };
            if f == 0 {
                state.tube.exact_steps += usize::from(input.piece.is_some());
                state.tube.enclosed_steps += usize::from(enclosure.is_some());
            }
            let held: Option<Vec<IntervalBox>> = std::iter::once(Some(set.clone()))
                .chain((1..=self.period).map(|j| image(j as f64 * self.h)))
                .collect();
            images.push(held);
            // The second-order image of each step, from the same fields; `|F|` over the set
            // is the same for every step.
            let speeds: Vec<Option<Vec<f64>>> = match terms.is_some() {
                true => fields
                    .iter()
                    .map(|&(d, nn, margin, slack)| {
                        frame_speed(d, set, &input_enclosure(nn, margin), slack)
                    })
                    .collect(),
                false => Vec::new(),
            };
            let second_at = |term: &crate::reach::sampled_second::HeldTerm| {
                let mix = mix_in_frame(p.transform.as_ref(), term);
                let (mut lower, mut upper) = fields
                    .iter()
                    .zip(&speeds)
                    .filter_map(|(&(d, nn, margin, slack), speed)| {
                        let w = Some(mix.matrix.as_slice());
                        let (mut lo, mut hi) = euler_image(d, set, term.tau, nn, margin, slack, w);
                        let spread = spread_term(&mix, speed.as_ref()?, term.tau);
                        for i in 0..n {
                            lo[i] = (Interval::point(lo[i]) - Interval::point(spread[i])).lower;
                            hi[i] = (Interval::point(hi[i]) + Interval::point(spread[i])).upper;
                        }
                        Some((lo, hi))
                    })
                    .reduce(meet_fields)?;
                let (rl, ru) = in_frame(p, &term.lower, &term.upper);
                embedding_step(&mut lower, &mut upper, &rl, &ru, 1.0);
                Some(IntervalBox { lower, upper })
            };
            second.push(
                terms
                    .as_ref()
                    .and_then(|terms| terms.iter().map(second_at).collect::<Option<Vec<_>>>()),
            );
        }
        if images.iter().all(Option::is_none) {
            state.tube.end = TubeEnd::NoCertifiedBound {
                t,
                beyond_c: self.x_problem.certified_on_all_of_c(),
            };
            state.done = true;
            return Ok(());
        }
        let at_sample = box_of(&state.known.lower, &state.known.upper);
        let scenario = self.x_problem.pieces.scenario();
        let h_k = scenario
            .cbfs
            .iter()
            .map(|c| c.h.eval_interval(&at_sample))
            .map(|h| {
                let floor = if h.lower > 0.0 { h.lower } else { 0.0 };
                let ceil = if h.upper >= floor {
                    h.upper
                } else {
                    f64::INFINITY
                };
                Interval::new(floor, ceil)
            })
            .collect();
        let input = (!plant.0.is_still()).then(|| Some(inter.input().to_vec()));
        state.held = Some(Held {
            images,
            second,
            inter,
            sample: state.known.clone(),
            facts,
            h_k,
            motion: Some(state.known.clone()),
            input,
        });
        Ok(())
    }

    /// Step `j` (1-based) of the period held in `state`, ending at `t`: encloses the step's
    /// motion from the set (ending the tube where it has no enclosure), then each frame's set
    /// becomes its image at `τ = j·dt` plus the remainder there; the motion over `[τ − dt, τ]`
    /// is enclosed by the hull of the images at both ends plus the remainder over the interval
    /// (per trajectory the Euler part moves on a segment), met across frames and with the
    /// step's a-priori enclosure. A set or enclosure not proven inside `S` is the tube's finding
    /// ([`crate::reach::UnsafeBetweenSamples`]), not an end: the sets stay sound.
    pub(super) fn sampled_step(
        &self,
        state: &mut Live,
        j: usize,
        t: f64,
        record: bool,
    ) -> Result<(), ReachError> {
        let Some(held) = state.held.as_mut() else {
            return Ok(());
        };
        let (plant, _) = self.plant.as_ref().expect("sampled runs have a plant");
        let Some(apriori) = held.inter.step(plant, &state.known, self.h) else {
            state.tube.end = TubeEnd::NoIntersampleEnclosure { t: t - self.h };
            state.done = true;
            return Ok(());
        };
        let held = state.held.as_ref().expect("held above");
        let (a, b) = ((j - 1) as f64 * self.h, j as f64 * self.h);
        let mut stepped = Vec::with_capacity(self.frames.len());
        let mut pipe: Option<IntervalBox> = apriori;
        for (f, frame) in self.frames.iter().enumerate() {
            let Some(images) = &held.images[f] else {
                stepped.push(false);
                continue;
            };
            let p = frame.problem;
            let in_p = |(lower, upper): (Vec<f64>, Vec<f64>)| in_frame(p, &lower, &upper);
            let (rl, ru) = in_p(held.inter.at(b));
            let (bl, bu) = in_p(held.inter.between(a, b));
            let set = &mut state.sets[f];
            set.clone_from(&images[j]);
            embedding_step(&mut set.lower, &mut set.upper, &rl, &ru, 1.0);
            if let Some(second) = &held.second[f] {
                let other = &second[j - 1];
                for i in 0..set.dim() {
                    set.lower[i] = set.lower[i].max(other.lower[i]);
                    set.upper[i] = set.upper[i].min(other.upper[i]);
                }
            }
            let mut swept = images[j - 1].hull(&images[j]);
            embedding_step(&mut swept.lower, &mut swept.upper, &bl, &bu, 1.0);
            let x = p.x_box_in_safe_set(&swept.lower, &swept.upper, frame.safe);
            pipe = Some(match pipe {
                Some(q) => q.intersection(&x).unwrap_or(x),
                None => x,
            });
            stepped.push(true);
        }
        if images_disagree(state) {
            // The meet of sound images cannot be empty: `advance` reports it.
            state.inversion = Some(crate::reach::Inversion::BoundsDisagree);
        }
        if let Some(held) = state.held.as_mut() {
            held.motion = match (held.motion.take(), &pipe) {
                (Some(m), Some(p)) => Some(m.hull(p)),
                _ => None,
            };
        }
        state.pipe_known = pipe;
        let swept = state.pipe_known.clone();
        // Per CBF, whether every true state over the step is proven in it (by the flowpipe, or
        // by the filter's own constraint since the sample); where all are, the sets are
        // clipped to `S` as in continuous time. Not after a finding: the constraint's argument
        // needs the state in `S` at the sample.
        let checking = state.tube.unsafe_between_samples.is_none();
        let mut kept = Vec::new();
        if checking {
            let scenario = self.x_problem.pieces.scenario();
            for c in 0..scenario.cbfs.len() {
                let by_pipe = swept
                    .as_ref()
                    .is_some_and(|s| proven_safe(scenario, c, s).0);
                kept.push(by_pipe || self.filter_keeps(state, c, j)?);
            }
        }
        state.in_s = checking && kept.iter().all(|&k| k);
        if let Some(pipe) = state.pipe_known.as_mut().filter(|_| state.in_s) {
            clip_to_safe_set(&mut pipe.lower, &mut pipe.upper, &self.frames[0].in_s.x);
        }
        let last = j == self.period;
        self.advance(state, t, record, &stepped);
        state.in_s = false;
        state.pipe_known = None;
        if checking {
            if let Some((cbf, entirely)) = self.not_kept(state, &kept, swept.is_some()) {
                state.tube.unsafe_between_samples =
                    Some(crate::reach::UnsafeBetweenSamples { t, cbf, entirely });
            }
        }
        if last {
            state.held = None;
        }
        Ok(())
    }

    /// The first CBF not `kept` over the step; a step without a flowpipe is judged by its set
    /// at `t` alone. With whether the set lies entirely outside it.
    fn not_kept(&self, state: &Live, kept: &[bool], has_pipe: bool) -> Option<(String, bool)> {
        let scenario = self.x_problem.pieces.scenario();
        (0..kept.len()).find_map(|c| {
            let (at_t, entirely) = proven_safe(scenario, c, &state.known);
            let fine = kept[c] || (at_t && !has_pipe);
            (!fine).then(|| (scenario.cbfs[c].name.clone(), entirely))
        })
    }

    /// [`Plant::keeps`] for CBF `c` over the held period's first `j` steps.
    fn filter_keeps(&self, state: &mut Live, c: usize, j: usize) -> Result<bool, ReachError> {
        let Some(plant) = self.plant.as_ref() else {
            return Ok(false);
        };
        let Some(held) = state.held.as_mut() else {
            return Ok(false);
        };
        if held.input.is_none() {
            held.input = Some(self.held_input(plant, &held.sample, held.facts, None)?);
        }
        let (Some(motion), Some(Some(u))) = (&held.motion, &held.input) else {
            return Ok(false);
        };
        let tau = j as f64 * self.h;
        Ok(plant.0.keeps(c, held.h_k[c], motion, u, tau))
    }

    /// The held input's enclosure `κ(X) + v` over the x-box `known` of the set, `v` enclosed by
    /// the network's bounds on `X` (`bounds`, `(N̲, N̄)`, where the sample's batch has them;
    /// else bounded here) plus the error margin (or 0 where the filter is proven inactive), met
    /// with the closed form's enclosure where there is one; `None` where it is unbounded.
    fn held_input(
        &self,
        (plant, x_net): &(Plant, PreparedNetwork),
        known: &IntervalBox,
        facts: SetFacts,
        bounds: Option<(&[f64], &[f64])>,
    ) -> Result<Option<Vec<Interval>>, ReachError> {
        let xp = self.x_problem;
        let m = xp.dynamics.m;
        let mut v = match facts.piece {
            Some(FilterPiece::Inactive) => vec![Interval::point(0.0); m],
            _ => match facts.m.filter(|m| m.is_finite()) {
                Some(margin) => {
                    let here;
                    let (lower, upper) = match bounds {
                        Some(b) => b,
                        None => {
                            here =
                                x_net.bounds(&known.lower, &known.upper, self.settings.bounds)?;
                            (&here.lower[..], &here.upper[..])
                        }
                    };
                    (0..m)
                        .map(|k| {
                            let lo = Interval::point(lower[k]) - Interval::point(margin);
                            let hi = Interval::point(upper[k]) + Interval::point(margin);
                            Interval::new(lo.lower, hi.upper)
                        })
                        .collect()
                }
                None => vec![Interval::new(f64::NEG_INFINITY, f64::INFINITY); m],
            },
        };
        if let Some(e) = xp.pieces.enclosure(known) {
            for (vk, ek) in v.iter_mut().zip(e) {
                if let Some(met) = vk.intersection(&ek) {
                    *vk = met;
                }
            }
        }
        if !v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite()) {
            return Ok(None);
        }
        Ok(Some(plant.held_input(known, &v)))
    }
}

/// Whether some frame's set came out empty (the meet of sound images cannot be).
fn images_disagree(state: &Live) -> bool {
    state
        .sets
        .iter()
        .any(|s| s.lower.iter().zip(&s.upper).any(|(l, u)| l > u))
}

//! The CPU engine's steps for the time models besides the Euler map (issue 36): the
//! continuous-time enclosure of each step and its fields on slabs ([`validated`]), and the
//! sampled-data intersample remainder ([`crate::reach::sampled`]). A child of `reach::cpu`
//! (it works on that engine's chunk state); imports what `cpu` imports.

use super::*;

/// Continuous time ([`TimeModel::Continuous`], [`validated`]): the a-priori enclosure of each
/// step and the field on slabs of it.
impl ChunkRun<'_> {
    /// This step's moving boxes, guessed from last step's rates where they can be (item 3b:
    /// checked after the step's fields, with Picard–Lindelöf where they fail), and the
    /// enclosures of every other live box ([`ChunkRun::enclose_boxes`]).
    pub(super) fn enclose_all(
        &self,
        states: &mut [Live],
        buf: &mut ChunkBuffers,
        t0: f64,
    ) -> Result<(), ReachError> {
        for state in states.iter_mut().filter(|s| !s.done) {
            self.guess_moving(state);
        }
        let mut open: Vec<&mut Live> = states
            .iter_mut()
            .filter(|s| !s.done && !s.guessed)
            .collect();
        self.enclose_boxes(&mut open, buf, t0)
    }

    /// `state.pipe_known` from the frames' flowpipes (the whole enclosures where a moving box
    /// lies in one), and with several frames each flowpipe met with the others.
    pub(super) fn meet_pipes(&self, state: &mut Live) {
        let known = self
            .frames
            .iter()
            .zip(state.pipes.iter().zip(&state.whole))
            .filter_map(|(f, (p, whole))| {
                let p = whole.as_ref().or(p.as_ref())?;
                Some(
                    f.problem
                        .x_box_in_safe_set(&p.set.lower, &p.set.upper, f.safe),
                )
            })
            .reduce(|a, b| a.intersection(&b).unwrap_or(a));
        if self.frames.len() > 1 {
            if let Some(known) = &known {
                let pipes = state.pipes.iter_mut().chain(state.whole.iter_mut());
                let frames = self.frames.iter().chain(&self.frames);
                for (f, pipe) in frames.zip(pipes) {
                    let Some(pipe) = pipe else { continue };
                    let around = f.problem.frame_box(known);
                    if let Some(met) = pipe.set.intersection(&around) {
                        pipe.set = met;
                    }
                }
                if self.settings.meet_slabs {
                    self.meet_slabs(state, known);
                }
            }
        }
        state.pipe_known = known;
    }

    /// Each frame's flowpipes (moving box and whole enclosure) get the other frames' sets over
    /// the step as half-spaces, which clip their slabs (design §7.1 item 7): each frame's
    /// whole enclosure where it has one (proven alone, so sound whichever frames' moving boxes
    /// fail their checks), else its one flowpipe (an enclosure, or a moving box guessed
    /// without one, which is proven with every frame's together). `known` holds every state
    /// of the step.
    fn meet_slabs(&self, state: &mut Live, known: &IntervalBox) {
        let sets: Vec<Option<IntervalBox>> = state
            .pipes
            .iter()
            .zip(&state.whole)
            .map(|(p, w)| w.as_ref().or(p.as_ref()).map(|p| p.set.clone()))
            .collect();
        for (f, frame) in self.frames.iter().enumerate() {
            let others: Vec<SafeHalfspace> = (0..self.frames.len())
                .filter(|&g| g != f)
                .filter_map(|g| Some((g, sets[g].as_ref()?)))
                .flat_map(|(g, set)| {
                    frame_halfspaces(
                        frame.problem.transform.as_ref(),
                        self.frames[g].problem.transform.as_ref(),
                        set,
                        known,
                    )
                })
                .collect();
            for pipe in [&mut state.pipes[f], &mut state.whole[f]]
                .into_iter()
                .flatten()
            {
                pipe.others.clone_from(&others);
            }
        }
    }

    /// Continuous time, after the rates on the slabs (`fields`: the filter's piece, its
    /// enclosures, the network): where the slabs are a moving box's, checks them
    /// ([`validated::verified`]) and, where they fail, falls back to the whole enclosure's slabs
    /// (the network bounded there for this box alone). Keeps the rates for the next step's
    /// guess; returns the second-order rates of every source (met by the caller;
    /// [`end_rates::curved_rates`], [`end_rates::taylor_rates`]). `slot`: the box's rows in the
    /// frame's batch, where the network was bounded. Nothing for the Euler map.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn check_step(
        &self,
        frame: &Frame,
        state: &mut Live,
        f: usize,
        input: StepInput,
        fields: &mut [Option<Rates>; 3],
        (fb, zeros, margin): (&mut FrameBuffers, &[f64], &[f64]),
        rows: Option<(bool, usize)>,
    ) -> Result<Option<Rates>, ReachError> {
        let Some(Some(pipe)) = state.pipes.get(f) else {
            return Ok(None);
        };
        let met = fields.iter().flatten().cloned().reduce(meet_fields);
        let proven = met
            .as_ref()
            .is_some_and(|(l, u)| validated::verified(pipe, (l, u)));
        // The network's bounds on the slabs the step takes: this step's batch, or the
        // fallback's own (one box, row 0).
        let mut rows = rows;
        if !proven {
            if let Some(whole) = state.whole[f].take() {
                state.pipes[f] = Some(whole);
                *fields = self.whole_fields(frame, state, f, input, fb, zeros, margin)?;
                rows = rows.map(|_| (true, 0));
            }
        }
        state.before[f] = state.rates[f].take();
        state.rates[f] = fields.iter().flatten().cloned().reduce(meet_fields);
        let (p, set) = (frame.problem, &state.sets[f]);
        let Some(Some(pipe)) = state.pipes.get(f) else {
            return Ok(None);
        };
        let piece = input
            .piece
            .and_then(|piece| self.piece_taylor(p, set, pipe, piece, zeros));
        let network = input
            .margin
            .and_then(|_| self.network_taylor(p, state, f, margin));
        let curved = self.curved(frame, state, f, input, (fb, zeros, margin), rows);
        Ok([piece, network]
            .into_iter()
            .chain(curved)
            .flatten()
            .reduce(meet_fields))
    }

    /// [`end_rates::curved_rates`] of each source of the step's field on the slabs of
    /// `state.pipes[f]`: the proven piece, the filter's enclosures, the network (`rows`: whether
    /// its bounds are the fallback's, and the box's rows there).
    fn curved(
        &self,
        frame: &Frame,
        state: &Live,
        f: usize,
        input: StepInput,
        (fb, zeros, margin): (&FrameBuffers, &[f64], &[f64]),
        rows: Option<(bool, usize)>,
    ) -> [Option<Rates>; 3] {
        let p = frame.problem;
        let (n, m) = (p.dynamics.n, p.dynamics.m);
        let Some(Some(pipe)) = state.pipes.get(f) else {
            return [None, None, None];
        };
        let set = &state.sets[f];
        let exact = input.piece.map(|(piece, slack)| {
            let dynamics = piece_dynamics(p, piece);
            let zero = zero_bounds(zeros, n, m);
            let (mut dl, mut du) =
                end_rates::curved_rates(dynamics, set, pipe, self.h, |_, _| zero, zero.b_lower);
            widen_by(&mut dl, &mut du, slack);
            (dl, du)
        });
        let enclosed = match input.piece.is_none() && self.encloses {
            true => {
                let known = state.pipe_known.as_ref().unwrap_or(&state.known);
                self.enclosure_slab_rates(frame, set, pipe, known, zeros, true)
            }
            false => None,
        };
        let network = rows.map(|(fallback, slot)| {
            let batch = if fallback { &fb.pipe_batch } else { &fb.batch };
            let face =
                |i: usize, up: bool| bounds_of(batch, slot * 2 * n + 2 * i + usize::from(up), n, m);
            let whole = |_: usize, _: bool| bounds_of(batch, slot, n, m);
            let (mut dl, mut du) = match self.settings.face_local {
                true => end_rates::curved_rates(&p.dynamics, set, pipe, self.h, face, margin),
                false => end_rates::curved_rates(&p.dynamics, set, pipe, self.h, whole, margin),
            };
            widen_by(&mut dl, &mut du, p.field_slack);
            (dl, du)
        });
        [exact, enclosed, network]
    }

    /// The rates on the whole enclosure's slabs (`state.pipes[f]`), the network bounded on them
    /// for this box alone: [`ChunkRun::check_step`]'s fallback.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn whole_fields(
        &self,
        frame: &Frame,
        state: &mut Live,
        f: usize,
        input: StepInput,
        fb: &mut FrameBuffers,
        zeros: &[f64],
        margin: &[f64],
    ) -> Result<[Option<Rates>; 3], ReachError> {
        let p = frame.problem;
        let Some(Some(pipe)) = state.pipes.get(f) else {
            return Ok([None, None, None]);
        };
        let set = &state.sets[f];
        let exact = input
            .piece
            .map(|piece| self.piece_slab_field(p, set, pipe, piece, zeros));
        let enclosed = match input.piece.is_none() && self.encloses {
            true => {
                let known = state.pipe_known.as_ref().unwrap_or(&state.known);
                self.enclosure_slab_field(frame, set, pipe, known, zeros)
            }
            false => None,
        };
        let network = match input.margin {
            Some(_) => {
                let mut boxes = FrameBuffers::default();
                self.push_pipe_boxes(&mut boxes, set, pipe);
                frame.network.bounds_serial_into(
                    &boxes.flat_lo,
                    &boxes.flat_hi,
                    self.settings.bounds,
                    &mut fb.pipe_bounds,
                    &mut fb.pipe_batch,
                )?;
                let (field, _) = self.network_field(p, state, f, &fb.pipe_batch, 0, margin);
                Some(field)
            }
            None => None,
        };
        Ok([exact, enclosed, network])
    }

    /// Bounds of the filtered field (the method's system) over the whole box `a` of one frame:
    /// the meet of the filter's proven piece, its enclosures, and the network's bounds over `a`
    /// plus the error margin there; `None` where none is sound. `(x_box, input)`: `a`'s x-box
    /// within `S` and [`ChunkRun::step_input`] there.
    pub(super) fn field_on_box(
        &self,
        frame: &Frame,
        a: &IntervalBox,
        (x_box, input): &super::cpu_enclose::BoxInput,
        fb: &mut FrameBuffers,
        zeros: &[f64],
        batched: Option<NetworkBoundsRef>,
    ) -> Result<Option<Rates>, ReachError> {
        let p = frame.problem;
        let (n, m) = (p.dynamics.n, p.dynamics.m);
        let input = *input;
        fb.pipe_nn = None;
        let exact = input.piece.map(|(piece, slack)| {
            let dynamics = piece_dynamics(p, piece);
            let zero = zero_bounds(zeros, n, m);
            let (mut dl, mut du) =
                validated::field_over(dynamics, &a.lower, &a.upper, zero, zero.b_lower);
            widen_by(&mut dl, &mut du, slack);
            (dl, du)
        });
        let enclosed = match input.piece.is_none() && self.encloses {
            true => p.pieces.finite_enclosure(x_box),
            false => None,
        }
        .map(|v| {
            let (lo, hi): (Vec<f64>, Vec<f64>) = v.iter().map(|e| (e.lower, e.upper)).unzip();
            let consts = constant_bounds(zeros, &lo, &hi, n);
            let (mut dl, mut du) =
                validated::field_over(&p.dynamics, &a.lower, &a.upper, consts, &zeros[..m]);
            widen_by(&mut dl, &mut du, p.pieces.field_slack(x_box, &v));
            (dl, du)
        });
        let network = match input.margin {
            Some(bound) => {
                let nn = match batched {
                    Some(nn) => nn,
                    None => {
                        frame.network.bounds_serial_into(
                            &a.lower,
                            &a.upper,
                            self.settings.bounds.for_enclosures(),
                            &mut fb.pipe_bounds,
                            &mut fb.pipe_batch,
                        )?;
                        bounds_of(&fb.pipe_batch, 0, n, m)
                    }
                };
                fb.pipe_nn = Some(AffineBounds {
                    a_lower: nn.a_lower.to_vec(),
                    b_lower: nn.b_lower.to_vec(),
                    a_upper: nn.a_upper.to_vec(),
                    b_upper: nn.b_upper.to_vec(),
                    lower: nn.lower.to_vec(),
                    upper: nn.upper.to_vec(),
                    n_in: n,
                    n_out: m,
                });
                let margin = vec![bound; m];
                let (mut dl, mut du) =
                    validated::field_over(&p.dynamics, &a.lower, &a.upper, nn, &margin);
                widen_by(&mut dl, &mut du, p.field_slack);
                Some((dl, du))
            }
            None => None,
        };
        Ok([exact, enclosed, network]
            .into_iter()
            .flatten()
            .reduce(meet_fields))
    }

    /// [`ChunkRun::piece_field`] on the slabs of a flowpipe.
    pub(super) fn piece_slab_field(
        &self,
        problem: &ReachProblem,
        set: &IntervalBox,
        pipe: &Flowpipe,
        (piece, slack): (FilterPiece, f64),
        zeros: &[f64],
    ) -> (Vec<f64>, Vec<f64>) {
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let dynamics = piece_dynamics(problem, piece);
        let zero = zero_bounds(zeros, n, m);
        let (mut dl, mut du) =
            validated::slab_field(dynamics, set, pipe, self.h, |_, _| zero, zero.b_lower);
        widen_by(&mut dl, &mut du, slack);
        (dl, du)
    }

    /// [`ChunkRun::enclosure_field`] on the slabs of a flowpipe: `v` enclosed by its closed form
    /// on each slab's x-box (met with `known`, the flowpipes' x-box).
    /// Met with [`ChunkRun::lattice_slab_field`] where that applies ([`ReachSettings::lattice`]).
    pub(super) fn enclosure_slab_field(
        &self,
        frame: &Frame,
        set: &IntervalBox,
        pipe: &Flowpipe,
        known: &IntervalBox,
        zeros: &[f64],
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let enclosed = self.enclosure_slab_rates(frame, set, pipe, known, zeros, false);
        let lattice = frame
            .problem
            .lattice_applies(self.settings)
            .then(|| self.lattice_slab_field(frame.problem, set, pipe, known, zeros))
            .flatten();
        [enclosed, lattice]
            .into_iter()
            .flatten()
            .reduce(meet_fields)
    }

    /// The field on the slabs from the filter's pieces where `v` is a lattice of them on the
    /// flowpipe's x-box `known` (where [`ReachProblem::lattice_applies`]; [`FilterPieces::lattice`]):
    /// `v = min(hi, max(0, lo))`, so with `cᵢ = gᵢ` (in the frame's coordinates)
    /// `Fᵢ = Φ₀ᵢ + cᵢv` is `min(min_U Φₖᵢ, max(Φ₀ᵢ, max_L Φₖᵢ))` for `cᵢ > 0` and
    /// `max(max_U Φₖᵢ, min(Φ₀ᵢ, min_L Φₖᵢ))` for `cᵢ < 0` (`Φ₀` the inactive piece's field,
    /// `Φₖ` row `k`'s). Both are non-decreasing in every argument, so the pieces' bounds on a
    /// slab, put through the same expression, bound `Fᵢ` there: unlike an enclosure of `v`,
    /// this keeps how `v` moves with the state (a set across the switching surface of one row
    /// gets the larger of two smooth fields, not the field plus the range of `v`).
    pub(super) fn lattice_slab_field(
        &self,
        p: &ReachProblem,
        set: &IntervalBox,
        pipe: &Flowpipe,
        known: &IntervalBox,
        zeros: &[f64],
    ) -> Option<Rates> {
        let n = p.dynamics.n;
        let c = p.dynamics.g_constant.as_ref()?;
        let lattice = p.pieces.lattice(known)?;
        let field = |piece: FilterPiece| {
            self.piece_slab_field(p, set, pipe, (piece, p.piece_slack(piece, known)), zeros)
        };
        let inactive = field(FilterPiece::Inactive);
        let lower: Vec<Rates> = lattice
            .lower
            .iter()
            .map(|&k| field(FilterPiece::Binding(k)))
            .collect();
        let upper: Vec<Rates> = lattice
            .upper
            .iter()
            .map(|&k| field(FilterPiece::Binding(k)))
            .collect();
        let combine = |i: usize, end: &dyn Fn(&Rates) -> f64| -> f64 {
            let e0 = end(&inactive);
            let lo = lower.iter().map(end);
            let up = upper.iter().map(end);
            if c[i] > 0.0 {
                let below = lo.fold(e0, f64::max);
                up.fold(below, f64::min)
            } else if c[i] < 0.0 {
                let below = lo.fold(e0, f64::min);
                up.fold(below, f64::max)
            } else {
                e0
            }
        };
        let mut dl = Vec::with_capacity(n);
        let mut du = Vec::with_capacity(n);
        for i in 0..n {
            dl.push(combine(i, &|r: &Rates| r.0[i]));
            du.push(combine(i, &|r: &Rates| r.1[i]));
        }
        if dl.iter().chain(&du).any(|v| v.is_nan()) {
            return None;
        }
        Some((dl, du))
    }

    /// [`ChunkRun::enclosure_slab_field`], or with `curved` its
    /// [`end_rates::curved_rates`].
    fn enclosure_slab_rates(
        &self,
        frame: &Frame,
        set: &IntervalBox,
        pipe: &Flowpipe,
        known: &IntervalBox,
        zeros: &[f64],
        curved: bool,
    ) -> Option<(Vec<f64>, Vec<f64>)> {
        let problem = frame.problem;
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let mut slack = 0.0_f64;
        let mut ends = Vec::with_capacity(2 * n);
        for (lo, hi) in validated::slabs(set, pipe, self.h) {
            let x_box = problem.x_box_in_safe_set(&lo, &hi, frame.safe);
            let x_box = x_box.intersection(known).unwrap_or(x_box);
            let v = slab_enclosure(problem, &x_box)?;
            if !v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite()) {
                return None;
            }
            slack = slack.max(problem.pieces.field_slack(&x_box, &v));
            let (l, u): (Vec<f64>, Vec<f64>) = v.iter().map(|e| (e.lower, e.upper)).unzip();
            ends.push((l, u));
        }
        let face = |i: usize, up: bool| {
            let (l, u) = &ends[2 * i + usize::from(up)];
            constant_bounds(zeros, l, u, n)
        };
        let dynamics = &problem.dynamics;
        let (mut dl, mut du) = match curved {
            false => validated::slab_field(dynamics, set, pipe, self.h, face, &zeros[..m]),
            true => end_rates::curved_rates(dynamics, set, pipe, self.h, face, &zeros[..m]),
        };
        widen_by(&mut dl, &mut du, slack);
        Some((dl, du))
    }
}

/// Continuous time: the boxes to bound the network on and second-order rates (met with the
/// first-order ones by the caller).
impl ChunkRun<'_> {
    /// Queues the boxes of one set's network bounds: slabs for faces, the flowpipe for the
    /// whole set.
    pub(super) fn push_pipe_boxes(
        &self,
        fb: &mut FrameBuffers,
        set: &IntervalBox,
        pipe: &Flowpipe,
    ) {
        if self.settings.face_local {
            for (lo, hi) in validated::slabs(set, pipe, self.h) {
                fb.flat_lo.extend(lo);
                fb.flat_hi.extend(hi);
            }
        } else {
            fb.flat_lo.extend(&pipe.set.lower);
            fb.flat_hi.extend(&pipe.set.upper);
        }
    }

    /// Where the filter is proven one smooth piece on the set: the Taylor rates of that
    /// piece's field over the flowpipe ([`end_rates::taylor_rates`]; with
    /// [`ReachSettings::taylor3`] met with [`end_rates::taylor3_rates`]).
    pub(super) fn piece_taylor(
        &self,
        p: &ReachProblem,
        set: &IntervalBox,
        pipe: &Flowpipe,
        piece: (FilterPiece, f64),
        zeros: &[f64],
    ) -> Option<Rates> {
        let euler = Self::piece_field(p, set, piece, zeros, self.h);
        let dynamics = piece_dynamics(p, piece.0);
        let both = |pipe: &Flowpipe| {
            let first = end_rates::taylor_rates(dynamics, set, pipe, self.h, euler.clone());
            let third = self
                .settings
                .taylor3
                .then(|| end_rates::taylor3_rates(dynamics, set, pipe, self.h, euler.clone()))
                .flatten();
            [first, third].into_iter().flatten().reduce(meet_fields)
        };
        if pipe.enclosed {
            return both(pipe);
        }
        // A proven moving box holds every trajectory over the step (item 3b), and the piece
        // is proven on its x-box: its field there bounds the motion.
        let (n, m) = (p.dynamics.n, p.dynamics.m);
        let zero = zero_bounds(zeros, n, m);
        let b = &pipe.set;
        let (mut fl, mut fu) =
            validated::field_over(dynamics, &b.lower, &b.upper, zero, zero.b_lower);
        widen_by(&mut fl, &mut fu, piece.1);
        let over = Flowpipe {
            f_lower: fl,
            f_upper: fu,
            enclosed: true,
            ..pipe.clone()
        };
        both(&over)
    }

    /// Network steps: the Taylor rates from the network's bounds over the flowpipe of frame
    /// `f` (where the network was bounded there), widened by the transform's field slack.
    pub(super) fn network_taylor(
        &self,
        p: &ReachProblem,
        state: &Live,
        f: usize,
        margin: &[f64],
    ) -> Option<Rates> {
        match (state.pipes.get(f), state.pipe_nn.get(f)) {
            (Some(Some(pipe)), Some(Some(nn))) => {
                let nn = NetworkBoundsRef {
                    a_lower: &nn.a_lower,
                    b_lower: &nn.b_lower,
                    a_upper: &nn.a_upper,
                    b_upper: &nn.b_upper,
                    lower: &nn.lower,
                    upper: &nn.upper,
                };
                let set = &state.sets[f];
                end_rates::taylor_network_rates(&p.dynamics, set, pipe, self.h, nn, margin).map(
                    |(mut dl, mut du)| {
                        widen_by(&mut dl, &mut du, p.field_slack);
                        (dl, du)
                    },
                )
            }
            _ => None,
        }
    }
}

/// A remainder's bounds (x coordinates) in a frame's coordinates: `T·R` widened by the
/// transform's `ρ`.
pub(super) fn in_frame(
    problem: &ReachProblem,
    lower: &[f64],
    upper: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let Some(t) = &problem.transform else {
        return (lower.to_vec(), upper.to_vec());
    };
    let n = t.n;
    let rx: Vec<Interval> = crate::intervals::box_of(lower, upper);
    let rz: Vec<Interval> = (0..n)
        .map(|i| {
            (0..n).fold(Interval::point(0.0), |acc, j| {
                acc + Interval::point(t.t[i * n + j]) * rx[j]
            })
        })
        .collect();
    let size = rz.iter().map(|e| e.mag()).fold(0.0, f64::max);
    let slack = round_up(t.rho * size);
    (
        rz.iter()
            .map(|e| (Interval::point(e.lower) - Interval::point(slack)).lower)
            .collect(),
        rz.iter()
            .map(|e| (Interval::point(e.upper) + Interval::point(slack)).upper)
            .collect(),
    )
}

thread_local! {
    /// The closed form's last enclosures of `v` on slabs, per problem and x-box: a step's slab
    /// field and its curved rates take them on the same slabs (each computed them once, a fifth
    /// of a continuous run's interval evaluation).
    static SLAB_V: std::cell::RefCell<Vec<SlabV>> = const { std::cell::RefCell::new(Vec::new()) };
}

/// One entry of [`SLAB_V`]: the problem (by address), the x-box, `v`'s enclosure there.
type SlabV = (usize, IntervalBox, Option<Vec<Interval>>);

/// Entries [`SLAB_V`] keeps: the `2n` slabs of a few frames.
const SLAB_V_KEPT: usize = 24;

/// [`FilterPieces::enclosure`](crate::reach::pieces::FilterPieces::enclosure) on `x_box`,
/// through [`SLAB_V`] (a pure function of the problem and the box).
fn slab_enclosure(problem: &ReachProblem, x_box: &IntervalBox) -> Option<Vec<Interval>> {
    let key = problem as *const ReachProblem as usize;
    SLAB_V.with_borrow_mut(|kept| {
        if let Some((_, _, v)) = kept.iter().find(|(p, b, _)| *p == key && b == x_box) {
            return v.clone();
        }
        let v = problem.pieces.enclosure(x_box);
        if kept.len() >= SLAB_V_KEPT {
            kept.remove(0);
        }
        kept.push((key, x_box.clone(), v.clone()));
        v
    })
}

//! The CPU engine's continuous step on moving boxes guessed without an a-priori enclosure
//! (design §7.1 item 3b): the guess from last steps' rates, its check on every frame, and
//! the re-guesses and the enclosure where it fails. A child of `reach::cpu` (it works on that
//! engine's chunk state, beside `cpu_time`); imports what `cpu` imports.

use super::*;

/// Moving boxes guessed without an enclosure (design §7.1 item 3b).
impl ChunkRun<'_> {
    /// Where every frame has last step's rates (the disturbance method), the moving boxes
    /// guessed from them without an enclosure ([`validated::guessed`]); the step's facts are
    /// then taken on their hulls. Not where a hull leaves `C` in x coordinates (the enclosure
    /// handles `C`'s sides, item 1c). Sets `state.guessed`.
    pub(super) fn guess_moving(&self, state: &mut Live) {
        state.guessed = false;
        if self.settings.method != ReachMethod::Disturbance {
            return;
        }
        let mut pipes = Vec::with_capacity(self.frames.len());
        for (f, frame) in self.frames.iter().enumerate() {
            let Some((l, u)) = &state.rates[f] else {
                return;
            };
            let before = state.before[f].as_ref().map(|(l, u)| (&l[..], &u[..]));
            let Some(pipe) = validated::guessed(&state.sets[f], self.h, (l, u), before) else {
                return;
            };
            let p = frame.problem;
            if p.transform.is_none() && !pipe.set.is_subset_of(&p.region) {
                return;
            }
            pipes.push(Some(pipe));
        }
        state.pipes = pipes;
        state.whole.iter_mut().for_each(|w| *w = None);
        state.pipe_nn.iter_mut().for_each(|w| *w = None);
        self.meet_pipes(state);
        state.guessed = true;
    }

    /// Whether the rates of every frame (`fields`, this step's first) prove the moving boxes
    /// guessed without an enclosure (item 3b: all frames together, as the facts were taken on
    /// their hulls met). Where they do, each frame's next enclosure starts from the hull of its
    /// face rates.
    pub(super) fn guess_holds(&self, state: &mut Live, fields: &[FrameFields]) -> bool {
        let holds = state
            .pipes
            .iter()
            .zip(fields)
            .all(|(pipe, (fields, _, _))| {
                let met = fields.iter().flatten().cloned().reduce(meet_fields);
                match (pipe, met) {
                    (Some(pipe), Some((l, u))) => validated::verified(pipe, (&l, &u)),
                    _ => false,
                }
            });
        if holds {
            for (guess, pipe) in state.guess.iter_mut().zip(&state.pipes) {
                if let Some(m) = pipe.as_ref().and_then(|p| p.faces.as_ref()) {
                    let lo = m.lower.iter().zip(&m.upper).map(|(a, b)| a.min(*b));
                    let hi = m.lower.iter().zip(&m.upper).map(|(a, b)| a.max(*b));
                    *guess = Some((lo.collect(), hi.collect()));
                }
            }
        }
        holds
    }

    /// Where a guessed moving box fails: guesses again from the rates its slabs gave
    /// (`buf.fields`) up to [`REGUESSES`] times, the network bounded on the new slabs for this
    /// box alone, then falls back to the enclosure (Picard–Lindelöf) and its whole slabs.
    /// Leaves the step's fields in `buf.fields`; ends the tube where no enclosure closes.
    pub(super) fn fall_back(
        &self,
        state: &mut Live,
        buf: &mut ChunkBuffers,
        t0: f64,
    ) -> Result<(), ReachError> {
        for _ in 0..REGUESSES {
            if !self.reguess(state, &buf.fields) {
                break;
            }
            self.refield(state, buf)?;
            if self.guess_holds(state, &buf.fields) {
                return Ok(());
            }
        }
        state.guessed = false;
        self.enclose_boxes(&mut [state], buf, t0)?;
        if state.done {
            return Ok(());
        }
        for (pipe, whole) in state.pipes.iter_mut().zip(&mut state.whole) {
            if let Some(w) = whole.take() {
                *pipe = Some(w);
            }
        }
        self.refield(state, buf)
    }

    /// New guessed moving boxes from the rates the last ones' slabs gave (`fields`); false
    /// where none can be had (no rates, a box inside out, a hull leaving `C` in x).
    fn reguess(&self, state: &mut Live, fields: &[FrameFields]) -> bool {
        let mut pipes = Vec::with_capacity(self.frames.len());
        for (f, frame) in self.frames.iter().enumerate() {
            let Some((l, u)) = fields[f].0.iter().flatten().cloned().reduce(meet_fields) else {
                return false;
            };
            // Past a face its last guess missed, the next overshoots by the miss (as the
            // trend of [`validated::guessed`]; elsewhere no trend).
            let Some(m) = state.pipes[f].as_ref().and_then(|p| p.faces.as_ref()) else {
                return false;
            };
            let missed_l: Vec<f64> = (0..l.len()).map(|i| l[i].max(m.lower[i])).collect();
            let missed_u: Vec<f64> = (0..u.len()).map(|i| u[i].min(m.upper[i])).collect();
            let before = Some((&missed_l[..], &missed_u[..]));
            let Some(pipe) = validated::guessed(&state.sets[f], self.h, (&l, &u), before) else {
                return false;
            };
            let p = frame.problem;
            if p.transform.is_none() && !pipe.set.is_subset_of(&p.region) {
                return false;
            }
            pipes.push(Some(pipe));
        }
        state.pipes = pipes;
        self.meet_pipes(state);
        true
    }

    /// Each frame's fields on the slabs of `state.pipes` (the network bounded there for this
    /// box alone), with the facts of `state.pipe_known`, into `buf.fields`.
    fn refield(&self, state: &mut Live, buf: &mut ChunkBuffers) -> Result<(), ReachError> {
        let m = self.frames[0].problem.dynamics.m;
        let known = state
            .pipe_known
            .clone()
            .unwrap_or_else(|| state.known.clone());
        let facts = self.set_facts(&known);
        for (f, frame) in self.frames.iter().enumerate() {
            let input = self.step_input(frame.problem, &known, facts);
            buf.margin.clear();
            buf.margin.resize(m, input.margin.unwrap_or(0.0));
            let fields = self.whole_fields(
                frame,
                state,
                f,
                input,
                &mut buf.frames[f],
                &buf.zeros,
                &buf.margin,
            )?;
            buf.fields[f] = (fields, input, input.margin.map(|_| (true, 0)));
        }
        Ok(())
    }
}

/// Guesses of a moving box after the first fails, before the enclosure ([`ChunkRun::fall_back`]).
const REGUESSES: usize = 4;

//! One continuous-time box-step of the CPU engine from a state held elsewhere (docs/design.md
//! §7.4): the GPU engine keeps each box's set and the rates it guesses from on the device, and
//! the box-steps its common path cannot finish (a tube's first step, a guess refused or not
//! proven) are the CPU engine's own step, run here on that state. The GPU's parity tests compare
//! the device's common path with this step too. A child of `reach::cpu` (it builds that engine's
//! chunk state); imports what `cpu` imports.

use super::*;

/// One box's continuous-time state between two steps, in the problem's own frame, as the GPU
/// engine keeps it.
#[derive(Clone, Debug, PartialEq)]
pub struct StepState {
    /// The set.
    pub set: IntervalBox,
    /// The last step's rates on its slabs `(r̲, r̄)`, which the next moving box is guessed from
    /// (`None` before a tube's first step).
    pub rates: Option<(Vec<f64>, Vec<f64>)>,
    /// The step before's (the guess's trend).
    pub before: Option<(Vec<f64>, Vec<f64>)>,
    /// The hull of the last proven moving box's face rates, which a step that falls back to
    /// Picard–Lindelöf starts its enclosure from (`None`: from the set's own field).
    pub guess: Option<(Vec<f64>, Vec<f64>)>,
}

impl StepState {
    /// A tube's state before its first step: the set alone (no rates to guess from).
    pub fn start(set: IntervalBox) -> StepState {
        StepState {
            set,
            rates: None,
            before: None,
            guess: None,
        }
    }
}

/// Where two frames are met (design §2.11): a box's state in x, the second frame, and the
/// x-box the frames share after the last meet ([`HostStep::step_met`]).
#[derive(Clone, Debug, PartialEq)]
pub struct MetState {
    /// The state in x.
    pub x: StepState,
    /// The meet of the frames' x-boxes within `S` after the last step.
    pub known: IntervalBox,
}

/// What one step made of a [`StepState`].
#[derive(Clone, Debug)]
pub struct StepOutcome {
    /// The state after the step (as it was where the tube ended on it).
    pub state: StepState,
    /// Whether the step was the common path: its moving box guessed from the rates and proven
    /// by the first check (design §7.1 item 3b), with no re-guess or enclosure.
    pub common: bool,
    /// Where the tube ended on this step, why (`None`: it goes on).
    pub end: Option<TubeEnd>,
    /// The sample of the set after the step (at `t = h`, without a flowpipe), where the step
    /// got that far (also where the set or its flowpipe then left `C`): what
    /// [`record_sample`] takes.
    pub sample: Option<TubeSample>,
    /// The x-box of the step's flowpipe, where it has one.
    pub flowpipe: Option<IntervalBox>,
    /// Whether the step took the filter's proven piece, and its closed form's enclosures
    /// (each adds one to [`Tube::exact_steps`], [`Tube::enclosed_steps`]).
    pub sources: (bool, bool),
    /// Where two frames are met, the second frame's state and the shared x-box after the step
    /// (as they were where the tube ended on it).
    pub met: Option<MetState>,
}

/// The last of a step's bookkeeping, once its set is sampled (the CPU engine's, and the GPU
/// engine's for the box-steps it takes on the device): the x-box of the step's flowpipe
/// (`pipe`, continuous time) joins `swept`, the hull since the last sample, which must lie in
/// `C`; then the sample must. Pushes `sample` where it is recorded (with the hull) or where the
/// tube ends on it; returns whether it ended. `(t, h)`: the step's end and length.
pub fn record_sample(
    region: &IntervalBox,
    tube: &mut Tube,
    swept: &mut Option<IntervalBox>,
    pipe: Option<&IntervalBox>,
    mut sample: TubeSample,
    (t, h): (f64, f64),
    record: bool,
) -> bool {
    if let Some(pipe) = pipe {
        let hull = match swept.take() {
            Some(s) => s.hull(pipe),
            None => pipe.clone(),
        };
        let left = !hull.is_subset_of(region);
        if record || left {
            sample.flowpipe = Some(hull);
        } else {
            *swept = Some(hull);
        }
        if left {
            tube.end = TubeEnd::FlowpipeLeftRegion { t: t - h };
            tube.tube.push(sample);
            return true;
        }
    }
    if !sample.set.is_subset_of(region) {
        tube.end = TubeEnd::LeftRegion { t };
        tube.tube.push(sample);
        return true;
    }
    if record {
        tube.tube.push(sample);
    }
    false
}

/// The CPU engine's continuous step from given states, prepared once for a problem (its
/// network packed for the bounds) and taken as often as the GPU engine asks: every step of a
/// run with host boxes.
pub struct HostStep<'a> {
    run: ChunkRun<'a>,
}

impl CpuBackend {
    /// One continuous-time step of length `problem.dt / substeps` from each state, as
    /// [`Backend::reach`] takes it: one frame (no meet with x-boxes; two with
    /// [`HostStep::step_met`]), the disturbance method.
    /// Stepping each outcome's state again retraces the engine's tube. A caller that steps
    /// again and again prepares the step once ([`CpuBackend::host_step`]).
    pub fn continuous_step(
        &self,
        problem: &ReachProblem,
        settings: &ReachSettings,
        states: &[StepState],
    ) -> Result<Vec<StepOutcome>, ReachError> {
        self.host_step(problem, settings)?.step(states)
    }

    /// [`CpuBackend::continuous_step`] prepared for `problem` under `settings`: their checks
    /// and the packed network, once.
    pub fn host_step<'a>(
        &self,
        problem: &'a ReachProblem,
        settings: &'a ReachSettings,
    ) -> Result<HostStep<'a>, ReachError> {
        settings.validate()?;
        problem.check_time(settings)?;
        if problem.time != TimeModel::Continuous || settings.method != ReachMethod::Disturbance {
            return Err(ReachError::Settings(
                "one continuous step from a given state needs time = \"continuous\" and the \
                 disturbance method"
                    .into(),
            ));
        }
        // One step of the problem as it is (no copy of its network and error map: the GPU
        // engine asks every step), in each of its frames.
        let frames = problem
            .frames(settings)
            .into_iter()
            .map(|p| Frame::new(p, settings.method, false))
            .collect::<Result<Vec<Frame>, ReachError>>()?;
        const NO_REPORT: &(dyn Fn(usize) + Sync) = &|_: usize| {};
        Ok(HostStep {
            run: ChunkRun {
                frames,
                settings,
                every: 1,
                encloses: settings.exact_field() == ExactField::ClosedForm
                    && problem.pieces.has_closed_form(),
                report: NO_REPORT,
                time: problem.time,
                steps: 1,
                substeps: 1,
                h: problem.dt / problem.steps_per_dt() as f64,
                plant: None,
                x_problem: problem,
                period: 1,
                absorb: false,
                source: None,
            },
        })
    }
}

impl HostStep<'_> {
    /// One step from each state ([`CpuBackend::continuous_step`]), where the run keeps one frame.
    pub fn step(&self, states: &[StepState]) -> Result<Vec<StepOutcome>, ReachError> {
        self.step_met(states, &[])
    }

    /// One step from each state where two frames are met: `states` in the problem's own
    /// coordinates, `met` (one per state) in x with the x-box they shared after the last meet;
    /// the frames are not met again before the step, so stepping each outcome's states again
    /// retraces the engine's tube. With one frame `met` is empty ([`HostStep::step`]).
    pub fn step_met(
        &self,
        states: &[StepState],
        met: &[MetState],
    ) -> Result<Vec<StepOutcome>, ReachError> {
        let (run, problem) = (&self.run, self.run.x_problem);
        if met.len()
            != if run.frames.len() > 1 {
                states.len()
            } else {
                0
            }
        {
            return Err(ReachError::Settings(format!(
                "{} frames and {} states in x for {} states",
                run.frames.len(),
                met.len(),
                states.len()
            )));
        }
        // The states are in the frame's coordinates (z where there is a transform): no check
        // against `C`, which is in x.
        let n = problem.dynamics.n;
        let dims = states.iter().chain(met.iter().map(|m| &m.x));
        if let Some(index) = dims.clone().position(|s| s.set.dim() != n) {
            let dim = dims.clone().nth(index).map_or(0, |s| s.set.dim());
            return Err(ReachError::InitialBox {
                index: index % states.len().max(1),
                message: format!("a state with {dim} coordinates, expected {n}"),
            });
        }
        let mut live: Vec<Live> = states
            .iter()
            .enumerate()
            .map(|(k, s)| {
                let mut state = run.start(&s.set);
                let frames = std::iter::once(s).chain(met.get(k).map(|m| &m.x));
                state.sets = frames.clone().map(|s| s.set.clone()).collect();
                match met.get(k) {
                    Some(m) => state.known = m.known.clone(),
                    None => run.settle(&mut state, &[true]),
                }
                state.rates = frames.clone().map(|s| s.rates.clone()).collect();
                state.before = frames
                    .clone()
                    .map(|s| s.rates.as_ref().and(s.before.clone()))
                    .collect();
                state.guess = frames.map(|s| s.guess.clone()).collect();
                state
            })
            .collect();
        run.horizon(&mut live, &mut ChunkBuffers::default())?;
        Ok(live
            .into_iter()
            .zip(states)
            .enumerate()
            .map(|(k, (l, s))| {
                let end = (l.tube.end != TubeEnd::Horizon).then_some(l.tube.end);
                let sample = l.tube.tube.get(1).cloned().map(|s| TubeSample {
                    flowpipe: None,
                    ..s
                });
                let frame = |f: usize| StepState {
                    set: l.sets[f].clone(),
                    rates: l.rates[f].clone(),
                    before: l.before[f].clone(),
                    guess: l.guess[f].clone(),
                };
                let (state, met) = match end {
                    Some(_) => (s.clone(), met.get(k).cloned()),
                    None => (
                        frame(0),
                        met.get(k).map(|_| MetState {
                            x: frame(1),
                            known: l.known.clone(),
                        }),
                    ),
                };
                StepOutcome {
                    state,
                    common: l.common,
                    end,
                    sample,
                    flowpipe: l.pipe_known,
                    sources: (l.tube.exact_steps > 0, l.tube.enclosed_steps > 0),
                    met,
                }
            })
            .collect())
    }
}

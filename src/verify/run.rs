//! The verifier: a verdict per cell of a grid from its tube ([`judge`]), and refinement by
//! bisection. May import `reach`, `scenario` and `verify`'s report types.

use std::borrow::Cow;
use std::time::Instant;

use rayon::prelude::*;

use super::checkpoint::{Journal, NoJournal};
use super::{
    BoxVerdict, RunInfo, Trap, Verdict, VerifyError, VerifyReport, VerifySettings, VerifyTiming,
    FORMAT,
};
use crate::boxes::IntervalBox;
use crate::intervals::{box_of, Interval};
use crate::reach::absorb::{absorber, Absorbers};
use crate::reach::{
    Backend, EndKind, Inversion, ReachProblem, ReachSettings, TimeModel, Tube, TubeEnd,
};
use crate::scenario::Scenario;

/// Which phase a progress report is about.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Stage {
    /// The grid cells.
    Cells,
    /// Refinement round `d` (1-based).
    Refine(usize),
}

/// `Some(UnsafeStart)`, `Some(PartlyUnsafe)` or `None` (the box starts safe), by interval
/// evaluation of every CBF over the box.
pub fn start_verdict(scenario: &Scenario, b: &IntervalBox) -> Option<Verdict> {
    match in_safe_set(scenario, b) {
        InSafeSet::Inside => None,
        InSafeSet::Partly(_) => Some(Verdict::PartlyUnsafe),
        InSafeSet::Outside(_) => Some(Verdict::UnsafeStart),
    }
}

/// How a box lies in `S`, by interval evaluation of every CBF over it; `Display` says it with
/// the CBF that decides.
#[derive(Clone, Debug, PartialEq)]
pub enum InSafeSet {
    /// Every CBF is proven non-negative on the box.
    Inside,
    /// Not proven inside: this CBF may be negative on part of it.
    Partly(String),
    /// This CBF is negative on the whole box.
    Outside(String),
}

/// [`InSafeSet`] of a box.
pub fn in_safe_set(scenario: &Scenario, b: &IntervalBox) -> InSafeSet {
    let x = box_of(&b.lower, &b.upper);
    let hs: Vec<(Interval, &str)> = (scenario.cbfs.iter())
        .map(|c| (c.h.eval_interval(&x), c.name.as_str()))
        .collect();
    // NaN bounds (an expression undefined somewhere on the box) count as "maybe unsafe".
    let proven = |h: &Interval| h.lower >= 0.0 && !h.is_nan();
    if let Some((_, name)) = hs.iter().find(|(h, _)| h.upper < 0.0) {
        InSafeSet::Outside(name.to_string())
    } else if let Some((_, name)) = hs.iter().find(|(h, _)| !proven(h)) {
        InSafeSet::Partly(name.to_string())
    } else {
        InSafeSet::Inside
    }
}

/// The initial boxes a run bounds trajectories from, and those it does not run: under the
/// disturbance method the sets are clipped to `S` and bound the trajectories that start there,
/// so a box wholly outside `S` has none (the Minkowski method's sets bound the NN system).
pub fn split_outside_s(
    scenario: &Scenario,
    boxes: &[IntervalBox],
    method: crate::reach::ReachMethod,
) -> (Vec<IntervalBox>, Vec<IntervalBox>) {
    (boxes.iter().cloned()).partition(|b| {
        method != crate::reach::ReachMethod::Disturbance
            || !matches!(in_safe_set(scenario, b), InSafeSet::Outside(_))
    })
}

impl std::fmt::Display for InSafeSet {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            InSafeSet::Inside => f.write_str("inside S"),
            InSafeSet::Partly(cbf) => write!(f, "partly outside S ({cbf} not ≥ 0 on all of it)"),
            InSafeSet::Outside(cbf) => write!(f, "outside S ({cbf} < 0 on all of it)"),
        }
    }
}

/// Why a tube got its verdict, where there is more to say than the verdict; `Display` gives
/// the note of the verdict JSON.
#[derive(Clone, Debug, PartialEq)]
pub enum Reason {
    /// `unsafe`: CBF `cbf` is negative on the whole set at `t`, after sets on which the QP is
    /// proven feasible.
    LeftSafeSet {
        /// The time.
        t: f64,
        /// The CBF's name.
        cbf: String,
        /// The set.
        set: IntervalBox,
    },
    /// `unknown`: the same, but after sets on which the QP is not proven feasible: the
    /// trajectories may have met an infeasible QP before.
    LeftSafeSetAfterUnprovenQp {
        /// The time.
        t: f64,
        /// The CBF's name.
        cbf: String,
        /// The set.
        set: IntervalBox,
    },
    /// `invalid`: the tube stopped early; why, as the engine says.
    Stopped(TubeEnd),
    /// `invalid`: the sets turned inside out (not by a step too large) after sets on which
    /// the QP is not proven feasible: where it has no solution no bound of `v` holds, which
    /// is the likelier cause than the one the engine names.
    InvertedAfterUnprovenQp(TubeEnd),
    /// `unknown`: the engine recorded no set.
    EmptyTube,
    /// `unsafe-between-samples`: where the sampled-data sets first may leave `S`.
    BetweenSamples(crate::reach::UnsafeBetweenSamples),
}

impl std::fmt::Display for Reason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let outside = |f: &mut std::fmt::Formatter<'_>, t: &f64, cbf: &str, set: &IntervalBox| {
            write!(
                f,
                "t = {t:.3}: {cbf} < 0 on the whole set {:?}…{:?}",
                set.lower, set.upper
            )
        };
        match self {
            Reason::LeftSafeSet { t, cbf, set } => outside(f, t, cbf, set),
            Reason::LeftSafeSetAfterUnprovenQp { t, cbf, set } => {
                outside(f, t, cbf, set)?;
                f.write_str(
                    ", after sets on which the QP is not proven feasible: the trajectories may \
                     have met an infeasible QP before",
                )
            }
            Reason::Stopped(end) => write!(f, "{end}"),
            Reason::InvertedAfterUnprovenQp(end) => write!(
                f,
                "{end}; after sets on which the QP is not proven feasible: the trajectories may \
                 have met an infeasible QP before"
            ),
            Reason::EmptyTube => f.write_str("empty tube"),
            Reason::BetweenSamples(found) => write!(f, "{found}"),
        }
    }
}

/// A tube's verdict, with the trap it ends in (`trapped`) and why (where there is more to say).
#[derive(Clone, Debug, PartialEq)]
pub struct Judgement {
    /// The verdict.
    pub verdict: Verdict,
    /// Index into the traps, for `trapped`.
    pub trap: Option<usize>,
    /// Why, for `unsafe`, `invalid` and some `unknown`.
    pub reason: Option<Reason>,
}

impl Judgement {
    fn of(verdict: Verdict, trap: Option<usize>, reason: Option<Reason>) -> Judgement {
        Judgement {
            verdict,
            trap,
            reason,
        }
    }
}

/// [`judge`], and for a verified tube whether the filter's QP is proven feasible on every one
/// of its sets (`None` for a tube not verified).
pub fn judge_with_feasibility(
    problem: &ReachProblem,
    scenario: &Scenario,
    traps: &[Trap],
    tube: &Tube,
) -> (Judgement, Option<bool>) {
    let j = judge(problem, scenario, traps, tube);
    let feasible = j
        .verdict
        .is_verified()
        .then(|| problem.proves_feasible_along(tube));
    (j, feasible)
}

/// Judges one tube (see the module docs for the order of the checks).
pub fn judge(
    problem: &ReachProblem,
    scenario: &Scenario,
    traps: &[Trap],
    tube: &Tube,
) -> Judgement {
    // Sampled-data: sets outside `S` are what a digital filter may do, not a bug.
    if let (TimeModel::Sampled { .. }, Some(found)) = (problem.time, &tube.unsafe_between_samples) {
        let why = Reason::BetweenSamples(found.clone());
        return Judgement::of(Verdict::UnsafeBetweenSamples, None, Some(why));
    }
    for (k, s) in tube.tube.iter().enumerate() {
        let x = box_of(&s.set.lower, &s.set.upper);
        for cbf in &scenario.cbfs {
            if cbf.h.eval_interval(&x).upper < 0.0 {
                let (t, cbf, set) = (s.t, cbf.name.clone(), s.set.clone());
                // `S` is forward invariant only while the QP has a solution: where it may have
                // none on an earlier set, every trajectory may have stopped there (the
                // scenario's CBFs may conflict), and a set outside `S` proves nothing.
                if !problem.proves_feasible_on(&tube.tube[..k]) {
                    let why = Reason::LeftSafeSetAfterUnprovenQp { t, cbf, set };
                    return Judgement::of(Verdict::Unknown, None, Some(why));
                }
                let why = Reason::LeftSafeSet { t, cbf, set };
                return Judgement::of(Verdict::Unsafe, None, Some(why));
            }
        }
    }
    if !tube.valid() {
        let why = match tube.end {
            TubeEnd::Inverted { cause, .. }
                if cause != Inversion::StepTooLarge && !problem.proves_feasible_along(tube) =>
            {
                Reason::InvertedAfterUnprovenQp(tube.end)
            }
            end => Reason::Stopped(end),
        };
        return Judgement::of(Verdict::Invalid, None, Some(why));
    }
    let Some(last) = tube.last() else {
        return Judgement::of(Verdict::Unknown, None, Some(Reason::EmptyTube));
    };
    // Stopped in an absorber: its target decides (every later state lies in it).
    if let TubeEnd::Absorbed { t } = tube.end {
        if let Some(a) = absorber(problem, t, &last.set) {
            return match a.trap {
                None => Judgement::of(Verdict::Converges, None, None),
                Some(k) => Judgement::of(Verdict::Trapped, Some(k), None),
            };
        }
    }
    if last.set.is_subset_of(&scenario.reach.goal) {
        return Judgement::of(Verdict::Converges, None, None);
    }
    if let Some(k) = traps.iter().position(|t| last.set.is_subset_of(&t.region)) {
        return Judgement::of(Verdict::Trapped, Some(k), None);
    }
    Judgement::of(Verdict::Unknown, None, None)
}

/// Runs the grid cells of one verification (or shard) and refines.
pub struct Verifier<'a> {
    /// The scenario (CBFs, goal).
    pub scenario: &'a Scenario,
    /// The compiled reach problem.
    pub problem: &'a ReachProblem,
    /// The engine.
    pub backend: &'a dyn Backend,
    /// Reach settings (`every` is forced to 1: the unsafe check looks at every step).
    pub reach: ReachSettings,
    /// Trap boxes.
    pub traps: Vec<Trap>,
}

impl<'a> Verifier<'a> {
    /// A verifier with the scenario's reach settings (`[settings.reach]`, else
    /// `ReachSettings::default()`) and traps ([`super::traps_for`]).
    pub fn new(
        scenario: &'a Scenario,
        problem: &'a ReachProblem,
        backend: &'a dyn Backend,
    ) -> Verifier<'a> {
        Verifier {
            scenario,
            problem,
            backend,
            reach: scenario.settings.reach.clone(),
            traps: super::traps_for(scenario),
        }
    }

    /// Verifies the cells of `settings.region` (of the shard, if any); `progress` gets the
    /// stage, boxes done and boxes in the stage.
    pub fn run(
        &self,
        settings: &VerifySettings,
        progress: &(dyn Fn(Stage, usize, usize) + Sync),
    ) -> Result<VerifyReport, VerifyError> {
        self.run_journaled(settings, progress, &NoJournal)
    }

    /// [`Verifier::run`] with a checkpoint: boxes it recorded are not run again, every
    /// finished chunk is recorded, and the run stops with [`VerifyError::Interrupted`] after
    /// a chunk when it asks.
    pub fn run_journaled(
        &self,
        settings: &VerifySettings,
        progress: &(dyn Fn(Stage, usize, usize) + Sync),
        journal: &dyn Journal,
    ) -> Result<VerifyReport, VerifyError> {
        settings.validate(self.scenario)?;
        let clock = Instant::now();
        // Tubes stop in the boxes proven absorbing (proven once, on the CPU engine).
        let absorbing = match settings.absorb {
            true => super::absorbing_boxes(self.scenario, self.problem, &self.reach, &self.traps)?,
            false => Vec::new(),
        };
        // From the second round on, also the leaves verified so far that stopped in them.
        let absorbers = |leaves: &[BoxVerdict]| {
            let mut list = super::absorb::target_absorbers(&absorbing);
            let horizon = self.problem.steps as f64 * self.problem.dt;
            list.extend(super::absorb::leaf_absorbers(leaves, &absorbing, horizon));
            Absorbers::new(list, &self.problem.region)
        };
        let mut base = Cow::Borrowed(self.problem);
        if !absorbing.is_empty() {
            base.to_mut().absorbing = absorbers(&[]);
        }
        let base = &*base;
        // Refinement's shorter steps must run on this engine too: refused before any box runs
        // (a setting the engine refuses at any step is refused by the first run, by name).
        let deepest = settings.problem_at(base, settings.refine_depth);
        let base_runs = self.backend.supports(base, &self.reach).is_ok();
        if let (true, Err(u)) = (base_runs, self.backend.supports(&deepest, &self.reach)) {
            return Err(VerifyError::Settings {
                field: "max_substeps",
                message: format!(
                    "refinement to depth {} cuts the step into {} substeps (max_substeps = {}), \
                     which this engine refuses: {}; or set max_substeps = 1 (refinement then \
                     keeps the step)",
                    settings.refine_depth,
                    deepest.substeps,
                    settings.max_substeps,
                    crate::reach::refusal(u)
                ),
            });
        }
        let region = settings.region_in(self.scenario);
        let chunk = settings
            .chunk
            .unwrap_or_else(|| self.backend.preferred_batch());
        // Only this shard's cells are made: a shard's memory follows its slice.
        let grid = settings.grid_for(self.scenario.n());
        let total: usize = grid.iter().product();
        let range = settings.shard.map_or(0..total, |s| s.range(total));
        let mut timing = VerifyTiming::default();
        let cells: Vec<(usize, usize, IntervalBox)> = range
            .clone()
            .map(|k| (k, 0, region.partition_cell(&grid, k)))
            .collect();
        let before = self.run_boxes(base, &cells, chunk, &mut timing, journal, &|d, t| {
            progress(Stage::Cells, d, t)
        })?;

        let mut leaves = before.clone();
        let mut left = settings.budget;
        for depth in 1..=settings.refine_depth {
            let latest = |i: &usize| leaves[*i].depth + 1 == depth;
            let undecided =
                (0..leaves.len()).filter(|i| latest(i) && leaves[*i].verdict.is_refinable());
            let unproven_feasible = (0..leaves.len()).filter(|i| {
                settings.refine_feasibility && latest(i) && leaves[*i].lacks_feasibility_proof()
            });
            let boundary = (0..leaves.len()).filter(|i| {
                settings.refine_boundary && latest(i) && leaves[*i].verdict == Verdict::PartlyUnsafe
            });
            // The undecided leaves take the budget first; the halves replace their parents in
            // place, so the parents go in leaf order.
            let mut parents: Vec<usize> = undecided
                .chain(unproven_feasible)
                .chain(boundary)
                .take(left / 2)
                .collect();
            parents.sort_unstable();
            if parents.is_empty() {
                break;
            }
            left -= 2 * parents.len();
            let children: Vec<(usize, usize, IntervalBox)> = parents
                .iter()
                .flat_map(|&i| {
                    let (l, r) = leaves[i].initial.bisect();
                    [(leaves[i].cell, depth, l), (leaves[i].cell, depth, r)]
                })
                .collect();
            // One copy of the problem a round at most: the shorter step's, given this round's
            // absorbers.
            let mut problem = settings.problem_at(base, depth);
            if !absorbing.is_empty() {
                problem.to_mut().absorbing = absorbers(&leaves);
            }
            let judged =
                self.run_boxes(&problem, &children, chunk, &mut timing, journal, &|d, t| {
                    progress(Stage::Refine(depth), d, t)
                })?;
            // Replace each parent by its two halves, in place.
            let mut next = Vec::with_capacity(leaves.len() + parents.len());
            let mut halves = judged.into_iter();
            let mut p = parents.iter().peekable();
            for (i, b) in leaves.into_iter().enumerate() {
                if p.peek() == Some(&&i) {
                    p.next();
                    next.extend(halves.by_ref().take(2).map(|h| h.within(&b)));
                } else {
                    next.push(b);
                }
            }
            leaves = next;
        }
        timing.total_s = clock.elapsed().as_secs_f64();
        Ok(VerifyReport {
            format: FORMAT.into(),
            run: RunInfo {
                scenario: self.scenario.name.clone(),
                scenario_file: self.scenario.file.clone(),
                states: self.scenario.states.clone(),
                units: self.scenario.units.clone(),
                region,
                grid,
                goal: self.scenario.reach.goal.clone(),
                method: self.reach.method.to_string(),
                bounds: self.reach.bounds.name().to_string(),
                m_c: self.problem.m_c,
                local_margin: self.problem.error_map.is_some(),
                face_local: self.reach.face_local,
                exact: self.reach.exact_field(),
                intersect_x: self.problem.frames(&self.reach).len() > 1,
                taylor3: self.reach.taylor3 && self.problem.time == TimeModel::Continuous,
                lattice: self.problem.lattice_applies(&self.reach),
                meet_slabs: self.problem.meet_slabs_applies(&self.reach),
                turned_frames: self.problem.turned_frames(&self.reach),
                dt: self.problem.dt,
                steps: self.problem.steps,
                time: self.problem.time.to_string(),
                substeps: self.problem.steps_per_dt(),
                max_substeps: settings.max_substeps,
                transformed: self.problem.transform.is_some(),
                safe_set: (self.problem.safe_set_for(self.reach.method).names())
                    .into_iter()
                    .map(String::from)
                    .collect(),
                refine_depth: settings.refine_depth,
                budget: settings.budget,
                refine_feasibility: settings.refine_feasibility,
                refine_boundary: settings.refine_boundary,
                absorbing,
                // The caller that knows the files records them (the CLI).
                network_hash: String::new(),
                filter_hash: crate::provenance::filter_hash(self.scenario),
            },
            shard: settings.shard,
            cells: [range.start, range.end],
            traps: self.traps.clone(),
            before,
            after: leaves,
            timing,
            what_stops: None,
        })
    }

    /// Start check, then the engine in chunks on `problem` (the verifier's, or a refinement
    /// round's with shorter steps), then [`judge`]; keeps the input order.
    fn run_boxes(
        &self,
        problem: &ReachProblem,
        boxes: &[(usize, usize, IntervalBox)],
        chunk: usize,
        timing: &mut VerifyTiming,
        journal: &dyn Journal,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<Vec<BoxVerdict>, VerifyError> {
        let mut out: Vec<BoxVerdict> = boxes
            .iter()
            .map(|(cell, depth, b)| BoxVerdict {
                cell: *cell,
                depth: *depth,
                initial: b.clone(),
                verdict: start_verdict(self.scenario, b).unwrap_or(Verdict::Unknown),
                final_set: None,
                t_end: None,
                trap: None,
                note: None,
                ended: None,
                feasible: None,
            })
            .collect();
        let mut to_run: Vec<usize> = (0..out.len())
            .filter(|&i| out[i].verdict.starts_safe())
            .collect();
        let total = to_run.len();
        // Boxes a checkpoint holds are not run again (their verdicts are bit-identical).
        to_run.retain(|&i| {
            let b = &mut out[i];
            match journal.lookup(b.cell, b.depth, &b.initial) {
                Some((v, steps)) => {
                    *b = v;
                    timing.boxes_run += 1;
                    timing.count_steps(steps, problem.steps_per_dt());
                    false
                }
                None => true,
            }
        });
        let cached = total - to_run.len();
        let settings = ReachSettings {
            every: 1,
            ..self.reach.clone()
        };
        let chunk = chunk.max(1);
        progress(cached, total);
        for (c, idx) in to_run.chunks(chunk).enumerate() {
            if journal.stop_requested() {
                return Err(VerifyError::Interrupted);
            }
            let initial: Vec<IntervalBox> = idx.iter().map(|&i| out[i].initial.clone()).collect();
            let done = cached + c * chunk;
            let clock = Instant::now();
            let result = self
                .backend
                .reach(problem, &initial, &settings, &|s, all| {
                    progress(done + idx.len() * s / all.max(1), total)
                })?;
            timing.reach_s += clock.elapsed().as_secs_f64();
            timing.boxes_run += idx.len();
            // Judging (and the feasibility proof along each verified tube, an interval
            // evaluation of the QP's rows at every step) is per tube: in parallel, or it takes
            // longer than a GPU's reach.
            let (scenario, traps) = (self.scenario, &self.traps);
            let judged: Vec<_> = result
                .boxes
                .par_iter()
                .map(|tube| {
                    let (j, feasible) = judge_with_feasibility(problem, scenario, traps, tube);
                    // Sets that left S or turned inside out after an unproven QP: the
                    // summary says so (the engine's cause assumes the filter defined).
                    let unproven = matches!(
                        j.reason,
                        Some(
                            Reason::InvertedAfterUnprovenQp(_)
                                | Reason::LeftSafeSetAfterUnprovenQp { .. }
                        )
                    );
                    let ended = match tube.end {
                        TubeEnd::Inverted { cause, .. }
                            if unproven && cause != Inversion::StepTooLarge =>
                        {
                            Some(EndKind::InvertedAfterUnprovenQp)
                        }
                        end => end.kind(),
                    };
                    let note = j.reason.map(|r| r.to_string());
                    (j.verdict, j.trap, note, feasible, ended)
                })
                .collect();
            let mut finished = Vec::with_capacity(idx.len());
            for ((&i, tube), (verdict, trap, note, feasible, ended)) in
                idx.iter().zip(&result.boxes).zip(judged)
            {
                let last = tube.last();
                let steps = tube.steps_run(self.problem.dt);
                timing.count_steps(steps, problem.steps_per_dt());
                let b = &mut out[i];
                b.verdict = verdict;
                b.trap = trap;
                b.note = note;
                b.ended = ended;
                b.final_set = last.map(|s| s.set.clone());
                b.t_end = last.map(|s| s.t);
                b.feasible = feasible;
                finished.push((b.clone(), steps));
            }
            journal.record(&finished)?;
            progress((done + idx.len()).min(total), total);
        }
        Ok(out)
    }
}

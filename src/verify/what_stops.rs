//! What stops the leaves whose sets were too loose (their centres' true trajectories end in the
//! goal or a trap): the largest few run again with the network taken as exact (`M = 0`) and,
//! in continuous time, with [`SUBSTEP_FACTOR`] times their substeps, so that a run can say
//! which of the two, or neither, stands between them and a verdict. Neither rerun is a proof:
//! the `M = 0` sets do not bound the filtered system; both only point to the knob worth turning.
//! May import `reach`, `scenario` and `verify`'s report types.

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use super::VerifySettings;
use super::{judge_with_feasibility, CentreOutcome, Verifier, VerifyError, VerifyReport};
use crate::boxes::IntervalBox;
use crate::reach::{Backend, ReachError, ReachProblem, ReachSettings, TimeModel, Tube};

/// Leaves run again, the largest first: enough to tell a majority, few enough to cost seconds.
pub const WHAT_STOPS_LEAVES: usize = 8;

/// The second rerun's substeps, as a multiple of each leaf's own (halving the step halves the
/// validated step's `O(h²)` loss a step; deep leaves already take 4, and 4 more made the reruns
/// a quarter of scenario 2's run).
pub const SUBSTEP_FACTOR: usize = 2;

/// What [`Verifier::what_stops`] found (`what_stops` in `verify`'s JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhatStops {
    /// The leaves run again (indices into the report's `after`), the largest first.
    pub leaves: Vec<usize>,
    /// Their share of the area of all leaves whose sets were too loose.
    pub area_share: f64,
    /// How many of them verify, the filter proven feasible on every set, with `M = 0`.
    pub without_error: usize,
    /// How many verify with [`SUBSTEP_FACTOR`] times their substeps: continuous time, on an
    /// engine that runs them (`None` otherwise).
    pub finer_step: Option<usize>,
    /// The knob the counts point to ([`Culprit::of`]).
    pub culprit: Culprit,
}

/// Which knob a [`WhatStops`] points to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Culprit {
    /// The network's certified error: `M = 0` verifies more of them than the finer step, and
    /// at least a third.
    Error,
    /// The validated step: the finer step verifies more of them than `M = 0`, and at least a
    /// third.
    Step,
    /// Neither verifies a third of them: the sets' own looseness (box size, bounds, coordinates).
    Neither,
}

impl Culprit {
    /// The knob that `without_error` and `finer_step` verified leaves of `leaves` rerun point to.
    pub fn of(leaves: usize, without_error: usize, finer_step: Option<usize>) -> Culprit {
        let (e, s) = (without_error, finer_step.unwrap_or(0));
        let third = leaves.div_ceil(3).max(1);
        match (e.max(s) >= third, e.cmp(&s)) {
            (true, std::cmp::Ordering::Greater) => Culprit::Error,
            (true, std::cmp::Ordering::Less) => Culprit::Step,
            // A tie with a third or more each: the error first (the step's knob is dearer).
            (true, std::cmp::Ordering::Equal) => Culprit::Error,
            (false, _) => Culprit::Neither,
        }
    }
}

impl Verifier<'_> {
    /// Runs the [`WHAT_STOPS_LEAVES`] largest leaves of `report` whose centres end in a target
    /// (`outcomes`: [`super::centre_outcomes`] of `report`) again, with `M = 0` and with a finer
    /// step; `None` when there is no such leaf.
    pub fn what_stops(
        &self,
        settings: &VerifySettings,
        report: &VerifyReport,
        outcomes: &[(usize, CentreOutcome)],
    ) -> Result<Option<WhatStops>, VerifyError> {
        let area = |i: &usize| report.after[*i].initial.volume();
        let mut leaves: Vec<usize> = outcomes
            .iter()
            .filter(|(_, o)| *o == CentreOutcome::EndsInTarget)
            .map(|(i, _)| *i)
            .collect();
        let total: f64 = leaves.iter().map(area).sum();
        if leaves.is_empty() || total <= 0.0 {
            return Ok(None);
        }
        leaves.sort_by(|a, b| area(b).total_cmp(&area(a)).then(a.cmp(b)));
        let leaves = largest_spread(&leaves, |i| area(&i), WHAT_STOPS_LEAVES);
        let area_share = leaves.iter().map(area).sum::<f64>() / total;
        let exact = self.problem.clone().without_error();
        let without_error = self
            .verified_among(report, &leaves, |d| settings.problem_at(&exact, d))?
            .unwrap_or(0);
        let finer_step = match self.problem.time {
            TimeModel::Continuous => self.verified_among(report, &leaves, |d| {
                let k = settings.substeps_at(self.problem, d) * SUBSTEP_FACTOR;
                Cow::Owned(self.problem.clone().with_time(TimeModel::Continuous, k))
            })?,
            _ => None,
        };
        Ok(Some(WhatStops {
            culprit: Culprit::of(leaves.len(), without_error, finer_step),
            leaves,
            area_share,
            without_error,
            finer_step,
        }))
    }

    /// How many of `leaves` verify (the filter proven feasible on every set) when each runs
    /// the problem `problem_at` gives for its depth; `None` when the engine refuses one.
    fn verified_among<'p>(
        &self,
        report: &VerifyReport,
        leaves: &[usize],
        problem_at: impl Fn(usize) -> Cow<'p, ReachProblem>,
    ) -> Result<Option<usize>, VerifyError> {
        let settings = ReachSettings {
            every: 1,
            ..self.reach.clone()
        };
        let mut depths: Vec<usize> = leaves.iter().map(|&i| report.after[i].depth).collect();
        depths.sort_unstable();
        depths.dedup();
        let mut verified = 0;
        for depth in depths {
            let problem = problem_at(depth);
            let boxes: Vec<IntervalBox> = leaves
                .iter()
                .map(|&i| &report.after[i])
                .filter(|b| b.depth == depth)
                .map(|b| b.initial.clone())
                .collect();
            let verifies = |tube: &Tube| {
                let (j, feasible) =
                    judge_with_feasibility(&problem, self.scenario, &self.traps, tube);
                j.verdict.is_verified() && feasible == Some(true)
            };
            match count_passing(self.backend, &problem, &settings, &boxes, verifies)? {
                Some(k) => verified += k,
                None => return Ok(None),
            }
        }
        Ok(Some(verified))
    }
}

/// How many of `boxes` give a tube that `passes` on `problem`; `None` where the engine refuses
/// the problem.
fn count_passing(
    backend: &dyn Backend,
    problem: &ReachProblem,
    settings: &ReachSettings,
    boxes: &[IntervalBox],
    passes: impl Fn(&Tube) -> bool,
) -> Result<Option<usize>, ReachError> {
    if backend.supports(problem, settings).is_err() {
        return Ok(None);
    }
    let result = backend.reach(problem, boxes, settings, &|_, _| {})?;
    Ok(Some(result.boxes.iter().filter(|t| passes(t)).count()))
}

/// `reach`'s tubes that stopped early, run again (at most [`WHAT_STOPS_LEAVES`]; `what_stops`
/// in `reach`'s JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StoppedRerun {
    /// Tubes run again.
    pub boxes: usize,
    /// How many of them run to the horizon with `M = 0`.
    pub without_error: usize,
    /// How many run to the horizon with [`SUBSTEP_FACTOR`] times the substeps (continuous time,
    /// on an engine that runs them; `None` otherwise).
    pub finer_step: Option<usize>,
    /// The knob the counts point to.
    pub culprit: Culprit,
}

/// Runs the first [`WHAT_STOPS_LEAVES`] of `stopped` (initial boxes whose tubes ended early on
/// `problem`) again with `M = 0` and with a finer step, and counts the tubes that then run to
/// the horizon: `reach`'s counterpart of [`Verifier::what_stops`]. `None` when `stopped` is
/// empty.
pub fn rerun_stopped(
    backend: &dyn Backend,
    problem: &ReachProblem,
    settings: &ReachSettings,
    stopped: &[IntervalBox],
) -> Result<Option<StoppedRerun>, ReachError> {
    let boxes = &stopped[..stopped.len().min(WHAT_STOPS_LEAVES)];
    if boxes.is_empty() {
        return Ok(None);
    }
    let runs = |t: &Tube| t.valid();
    let exact = problem.clone().without_error();
    let without_error = count_passing(backend, &exact, settings, boxes, runs)?.unwrap_or(0);
    let finer_step = match problem.time {
        TimeModel::Continuous => {
            let k = problem.steps_per_dt() * SUBSTEP_FACTOR;
            let finer = problem.clone().with_time(TimeModel::Continuous, k);
            count_passing(backend, &finer, settings, boxes, runs)?
        }
        _ => None,
    };
    Ok(Some(StoppedRerun {
        boxes: boxes.len(),
        without_error,
        finer_step,
        culprit: Culprit::of(boxes.len(), without_error, finer_step),
    }))
}

/// The first `k` of `sorted` (largest area first), except that where the `k`-th shares its area
/// with leaves beyond it, that last class is sampled evenly across its leaves (in grid order), not
/// taken from its start, which would put every rerun in one corner of the region.
fn largest_spread(sorted: &[usize], area: impl Fn(usize) -> f64, k: usize) -> Vec<usize> {
    if sorted.len() <= k {
        return sorted.to_vec();
    }
    let last = area(sorted[k - 1]);
    let first_of_class = sorted
        .iter()
        .position(|&i| area(i) == last)
        .unwrap_or(k - 1);
    let class: Vec<usize> = sorted[first_of_class..]
        .iter()
        .copied()
        .take_while(|&i| area(i) == last)
        .collect();
    let need = k - first_of_class;
    let mut out = sorted[..first_of_class].to_vec();
    out.extend((0..need).map(|j| class[j * class.len() / need]));
    out
}

//! What stops the leaves whose sets were too loose (their centres' true trajectories end in the
//! goal or a trap), and `reach`'s tubes that stopped early: the largest few run again with one
//! knob turned at a time — the network taken as exact (`M = 0`), a finer step (continuous
//! time), bounds on each face (where they are off) — so that a run can say which of the three
//! terms of a step, or none, stands between them and a verdict. No rerun is a proof (the
//! `M = 0` sets do not bound the filtered system); they only point to the knob worth turning.
//! May import `reach`, `scenario` and `verify`'s report types.

use std::borrow::Cow;

use serde::{Deserialize, Serialize};

use super::VerifySettings;
use super::{judge_with_feasibility, CentreOutcome, Verifier, VerifyError, VerifyReport};
use crate::boxes::IntervalBox;
use crate::reach::{Backend, ReachError, ReachProblem, ReachSettings, TimeModel, Tube};

/// Leaves run again, the largest first: enough to tell a majority, few enough to cost seconds.
pub const WHAT_STOPS_LEAVES: usize = 8;

/// The finer step's substeps, as a multiple of each leaf's own (halving the step halves the
/// validated step's `O(h²)` loss a step; deep leaves already take 4, and 4 more made the reruns
/// a quarter of scenario 2's run).
pub const SUBSTEP_FACTOR: usize = 2;

/// One knob a rerun turns.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Knob {
    /// `M = 0` ([`ReachProblem::without_error`]).
    Error,
    /// [`SUBSTEP_FACTOR`] times the substeps (continuous time).
    Step,
    /// Bounds on each face (`face_local`), where they are off.
    Bounds,
}

impl Knob {
    /// `problem` and `settings` with this knob turned, or `None` where it does not apply.
    fn turn<'p>(
        self,
        problem: &'p ReachProblem,
        settings: &ReachSettings,
    ) -> Option<(Cow<'p, ReachProblem>, ReachSettings)> {
        match self {
            Knob::Error => Some((
                Cow::Owned(problem.clone().without_error()),
                settings.clone(),
            )),
            Knob::Step => (problem.time == TimeModel::Continuous).then(|| {
                let k = problem.steps_per_dt() * SUBSTEP_FACTOR;
                let finer = problem.clone().with_time(TimeModel::Continuous, k);
                (Cow::Owned(finer), settings.clone())
            }),
            Knob::Bounds => (!settings.face_local).then(|| {
                let faces = ReachSettings {
                    face_local: true,
                    ..settings.clone()
                };
                (Cow::Borrowed(problem), faces)
            }),
        }
    }
}

/// How many of the rerun boxes pass with each knob turned, and the knob that stops them.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Reruns {
    /// With `M = 0` (the network taken as exact).
    pub without_error: usize,
    /// With [`SUBSTEP_FACTOR`] times the substeps: continuous time, on an engine that runs them
    /// (`None` otherwise).
    pub finer_step: Option<usize>,
    /// With bounds on each face, where the run had them off (`None` otherwise).
    pub face_local: Option<usize>,
    /// The knob the counts point to ([`Culprit::of`]).
    pub culprit: Culprit,
}

impl Reruns {
    /// The counts `count` gives for each knob (`None`: it does not apply) of `boxes` rerun.
    fn of<E>(boxes: usize, count: impl Fn(Knob) -> Result<Option<usize>, E>) -> Result<Reruns, E> {
        let without_error = count(Knob::Error)?.unwrap_or(0);
        let finer_step = count(Knob::Step)?;
        let face_local = count(Knob::Bounds)?;
        Ok(Reruns {
            culprit: Culprit::of(boxes, without_error, finer_step, face_local),
            without_error,
            finer_step,
            face_local,
        })
    }
}

/// What [`Verifier::what_stops`] found (`what_stops` in `verify`'s JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct WhatStops {
    /// The leaves run again (indices into the report's `after`), the largest first.
    pub leaves: Vec<usize>,
    /// Their share of the area of all leaves whose sets were too loose.
    pub area_share: f64,
    /// How many of them verify, the filter proven feasible on every set, with each knob.
    #[serde(flatten)]
    pub reruns: Reruns,
}

/// `reach`'s tubes that stopped early, run again (at most [`WHAT_STOPS_LEAVES`]; `what_stops`
/// in `reach`'s JSON).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct StoppedRerun {
    /// Tubes run again.
    pub boxes: usize,
    /// How many of them run to the horizon with each knob.
    #[serde(flatten)]
    pub reruns: Reruns,
}

/// Which knob the reruns point to.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Culprit {
    /// The network's certified error: `M = 0` passes most of them, and at least a third.
    Error,
    /// The validated step: the finer step passes most of them, and at least a third.
    Step,
    /// The network's bounds: bounds on each face pass most of them, and at least a third.
    Bounds,
    /// No knob passes a third of them: the sets' own width (box size, coordinates).
    Neither,
}

impl Culprit {
    /// The knob that the counts of `boxes` rerun point to: the one that passes most, if a
    /// third or more; at a tie the cheaper knob (the error map, then face bounds, then the step).
    pub fn of(
        boxes: usize,
        without_error: usize,
        finer_step: Option<usize>,
        face_local: Option<usize>,
    ) -> Culprit {
        let third = boxes.div_ceil(3).max(1);
        [
            (Culprit::Error, without_error),
            (Culprit::Bounds, face_local.unwrap_or(0)),
            (Culprit::Step, finer_step.unwrap_or(0)),
        ]
        .into_iter()
        .filter(|&(_, k)| k >= third)
        // `max_by_key` keeps the last of equals: reversed, the first in the list wins ties.
        .rev()
        .max_by_key(|&(_, k)| k)
        .map_or(Culprit::Neither, |(c, _)| c)
    }
}

impl Verifier<'_> {
    /// Runs the [`WHAT_STOPS_LEAVES`] largest leaves of `report` whose centres end in a target
    /// (`outcomes`: [`super::centre_outcomes`] of `report`) again, each at its depth's step,
    /// once per knob; `None` when there is no such leaf.
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
        let reruns = Reruns::of(leaves.len(), |knob| {
            self.verified_among(settings, report, &leaves, knob)
        })?;
        Ok(Some(WhatStops {
            leaves,
            area_share,
            reruns,
        }))
    }

    /// How many of `leaves` verify (the filter proven feasible on every set) when each runs
    /// its depth's problem with `knob` turned; `None` where the knob does not apply or the
    /// engine refuses the problem.
    fn verified_among(
        &self,
        settings: &VerifySettings,
        report: &VerifyReport,
        leaves: &[usize],
        knob: Knob,
    ) -> Result<Option<usize>, VerifyError> {
        let reach = ReachSettings {
            every: 1,
            ..self.reach.clone()
        };
        let mut depths: Vec<usize> = leaves.iter().map(|&i| report.after[i].depth).collect();
        depths.sort_unstable();
        depths.dedup();
        // `M = 0` once for every depth: the problem's clone holds the whole error map.
        let exact;
        let base = match knob {
            Knob::Error => {
                exact = self.problem.clone().without_error();
                &exact
            }
            _ => self.problem,
        };
        let mut verified = 0;
        for depth in depths {
            let at_depth = settings.problem_at(base, depth);
            let turned = match knob {
                Knob::Error => Some((Cow::Borrowed(&*at_depth), reach.clone())),
                other => other.turn(&at_depth, &reach),
            };
            let Some((problem, reach)) = turned else {
                return Ok(None);
            };
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
            match count_passing(self.backend, &problem, &reach, &boxes, verifies)? {
                Some(k) => verified += k,
                None => return Ok(None),
            }
        }
        Ok(Some(verified))
    }
}

/// Runs the first [`WHAT_STOPS_LEAVES`] of `stopped` (initial boxes whose tubes ended early on
/// `problem`) again once per knob, and counts the tubes that then run to the horizon: `reach`'s
/// counterpart of [`Verifier::what_stops`]. `None` when `stopped` is empty.
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
    let reruns = Reruns::of(boxes.len(), |knob| match knob.turn(problem, settings) {
        Some((problem, settings)) => {
            count_passing(backend, &problem, &settings, boxes, |t| t.valid())
        }
        None => Ok(None),
    })?;
    Ok(Some(StoppedRerun {
        boxes: boxes.len(),
        reruns,
    }))
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

#[cfg(test)]
mod tests {
    use super::*;

    /// The larger leaves come first; the last class of equal areas is sampled evenly over its
    /// leaves, not taken from its start (one corner of the region).
    #[test]
    fn the_leaves_rerun_are_the_largest_spread_over_equal_areas() {
        let area = |i: usize| if i < 2 { 4.0 } else { 1.0 };
        let sorted: Vec<usize> = (0..18).collect();
        assert_eq!(
            largest_spread(&sorted, area, 8),
            vec![0, 1, 2, 4, 7, 10, 12, 15]
        );
        assert_eq!(largest_spread(&sorted[..5], area, 8), sorted[..5].to_vec());
        assert_eq!(largest_spread(&sorted, |_| 1.0, 3), vec![0, 6, 12]);
    }

    /// The knob that passes most wins if it passes a third; ties go to the cheaper knob.
    #[test]
    fn the_culprit_is_the_knob_that_passes_most() {
        assert_eq!(Culprit::of(8, 8, Some(0), None), Culprit::Error);
        assert_eq!(Culprit::of(8, 1, Some(5), Some(2)), Culprit::Step);
        assert_eq!(Culprit::of(8, 1, Some(2), Some(6)), Culprit::Bounds);
        assert_eq!(Culprit::of(8, 2, Some(2), Some(2)), Culprit::Neither);
        assert_eq!(Culprit::of(8, 3, Some(3), Some(3)), Culprit::Error);
        assert_eq!(Culprit::of(8, 0, Some(4), Some(4)), Culprit::Bounds);
        assert_eq!(Culprit::of(1, 0, None, None), Culprit::Neither);
    }
}

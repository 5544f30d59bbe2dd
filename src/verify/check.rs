//! Checks of a report against the ground-truth filter: simulated starts in verified boxes
//! ([`simulation_check`]) and where unverified boxes' centres go ([`explain_unverified`]).
//! May import `filter`, `simulate`, `scenario` and `verify`'s report types.

use rayon::prelude::*;

use super::{BoxVerdict, Shares, Verdict, VerifyReport};
use crate::reach::TimeModel;
use crate::scenario::Scenario;
use crate::simulate::{simulate_filtered, simulate_sampled_watching_s, Integrator, Trajectory};

/// What simulating starts in the verified boxes with the ground-truth filter found
/// ([`simulation_check`]).
#[derive(Clone, Debug, Default)]
pub struct SimulationCheck {
    /// Verified leaves simulated.
    pub boxes: usize,
    /// Starts simulated.
    pub starts: usize,
    /// Starts whose trajectory stopped early (an infeasible QP) in boxes whose feasibility was
    /// not proven: the filtered system is not defined there, so they neither confirm nor refute
    /// the verdict (in boxes proven feasible they count as disagreements).
    pub stopped: usize,
    /// Starts that end elsewhere than their box's verdict says, or stop at an infeasible QP in
    /// a box proven feasible: `(start, verdict, end)`.
    pub disagreements: Vec<(Vec<f64>, Verdict, Vec<f64>)>,
}

/// An independent check of the verdicts: simulates a `per_axis`ⁿ grid of starts (corners
/// included) in every `converges` or `trapped` leaf of `report` with the ground-truth filter
/// (the system the sets bound over the scenario's horizon, [`simulate_model`]) and checks that
/// each trajectory ends in the goal set or in its trap box, and in sampled data that it stays
/// in `S` between samples (those verdicts say it does). The sets bound the filtered system, so
/// a disagreement means a bug or an unsound `M`.
pub fn simulation_check(s: &Scenario, report: &VerifyReport, per_axis: usize) -> SimulationCheck {
    use crate::filter::SafetyFilter;
    let filter = SafetyFilter::new(s);
    let time = model_of(report);
    let k = per_axis.max(1);
    let fraction = |i: usize| {
        if k == 1 {
            0.5
        } else {
            i as f64 / (k - 1) as f64
        }
    };
    let leaves: Vec<&BoxVerdict> = report
        .after
        .iter()
        .filter(|b| b.verdict.is_verified())
        .collect();
    let per_box: Vec<SimulationCheck> = leaves
        .par_iter()
        .map(|b| {
            let mut out = SimulationCheck {
                boxes: 1,
                ..SimulationCheck::default()
            };
            let target = match (b.verdict, b.trap) {
                (Verdict::Trapped, Some(t)) => &report.traps[t].region,
                _ => &s.reach.goal,
            };
            for code in 0..k.pow(s.n() as u32) {
                let at: Vec<f64> = (0..s.n())
                    .map(|d| fraction(code / k.pow(d as u32) % k))
                    .collect();
                let x0 = b.initial.point_at(&at);
                let (tr, left_s) = simulate_model(&filter, &x0, time, 10);
                out.starts += 1;
                // Sampled data: the verdict's sets were proven inside `S` between samples. A
                // stop with the QP proven feasible on every set: the sets hold the trajectory
                // at every step.
                if left_s.is_some() || (tr.stopped.is_some() && b.feasible == Some(true)) {
                    out.disagreements.push((x0, b.verdict, tr.last().to_vec()));
                } else if tr.stopped.is_some() {
                    out.stopped += 1;
                } else if !target.contains(tr.last()) {
                    out.disagreements.push((x0, b.verdict, tr.last().to_vec()));
                }
            }
            out
        })
        .collect();
    per_box
        .into_iter()
        .fold(SimulationCheck::default(), |mut all, one| {
            all.boxes += one.boxes;
            all.starts += one.starts;
            all.stopped += one.stopped;
            all.disagreements.extend(one.disagreements);
            all
        })
}

/// The system a report's sets bound ([`TimeModel::from_label`] of its `run.time`; a label no
/// version wrote is read as the Euler map, the model of reports from before the setting).
fn model_of(report: &VerifyReport) -> TimeModel {
    TimeModel::from_label(&report.run.time).unwrap_or(TimeModel::Euler)
}

/// The ground-truth filter's trajectory from `x0` over the scenario's horizon in the system
/// `time` names: the ODE by RK4 at `dt/fine`, the control held over each period `T_s` (with the
/// first time the plant is outside `S` between samples), or the Euler map at `dt`.
pub fn simulate_model(
    filter: &crate::filter::SafetyFilter,
    x0: &[f64],
    time: TimeModel,
    fine: usize,
) -> (Trajectory, Option<f64>) {
    let s = filter.scenario();
    let (dt, steps, fine) = (s.reach.dt, s.reach.steps(), fine.max(1));
    match time {
        TimeModel::Continuous => {
            let (h, n) = (dt / fine as f64, fine * steps);
            let tr = simulate_filtered(filter, x0, h, n, Integrator::Rk4);
            (tr, None)
        }
        TimeModel::Sampled { control_period } => {
            let periods = (s.reach.horizon / control_period).round() as usize;
            simulate_sampled_watching_s(filter, x0, control_period, periods)
        }
        TimeModel::Euler => {
            let tr = simulate_filtered(filter, x0, dt, steps, Integrator::Euler);
            (tr, None)
        }
    }
}

/// Where the ground-truth filtered system goes from the centre of each leaf that was not
/// verified (`unknown`, `invalid` or `unsafe-between-samples`), as shares of the leaves' safe area
/// ([`explain_unverified`]). A diagnostic, not a proof: it separates what no sound set can
/// show (the system itself leaves `C`, or the horizon ends elsewhere) from what the network's
/// error and the over-approximation left open.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct UnverifiedCauses {
    /// Not verified (the sum of the five below).
    pub unverified: f64,
    /// Sampled data: the centre's held-input trajectory leaves `S` between samples (the
    /// digital filter does not keep `S` invariant: a finding about the system, checked first).
    pub unsafe_between_samples: f64,
    /// The centre's trajectory leaves `C`, where `M_C` no longer holds.
    pub leaves_region: f64,
    /// The centre's trajectory stops at an infeasible QP.
    pub infeasible: f64,
    /// The centre's trajectory ends at `T` in neither the goal nor a trap box.
    pub ends_elsewhere: f64,
    /// Of `ends_elsewhere`, the centres whose trajectory, run on, reaches the goal or a trap
    /// box within [`LATER_HORIZONS`] more horizons: the horizon, not the sets, stopped them.
    pub arrives_later: f64,
    /// The latest time such a trajectory reached its target (0 where none does).
    pub latest_arrival: f64,
    /// The centre's trajectory ends in the goal or a trap box: the sets were too loose.
    pub too_loose: f64,
}

/// How many horizons past `T` [`centre_outcomes`] runs a trajectory that ended elsewhere, to
/// tell a horizon too short from an end away from every target.
pub const LATER_HORIZONS: usize = 3;

/// Where the ground-truth filtered system goes from a leaf's centre (one of
/// [`UnverifiedCauses`]'s classes), checked in this order.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum CentreOutcome {
    /// Sampled data: the held input carries it out of `S` between samples.
    LeavesSBetweenSamples,
    /// It leaves `C`.
    LeavesRegion,
    /// It stops at an infeasible QP.
    Infeasible,
    /// It ends at `T` in neither the goal nor a trap box; run on, it first reaches one at
    /// this time (within [`LATER_HORIZONS`] more horizons), or never (`None`).
    EndsElsewhere(Option<f64>),
    /// It ends in the goal or a trap box: the sets were too loose.
    EndsInTarget,
}

/// Simulates the centre of every leaf of `report` that refinement could still decide
/// (`unknown`, `invalid`, `unsafe-between-samples`) with the ground-truth filter, in the
/// system its sets bound ([`simulate_model`]): the leaf's index in `report.after` and where
/// the trajectory goes.
pub fn centre_outcomes(s: &Scenario, report: &VerifyReport) -> Vec<(usize, CentreOutcome)> {
    use crate::filter::SafetyFilter;
    let filter = SafetyFilter::new(s);
    let time = model_of(report);
    let ends_in_target = in_targets(s, &report.traps);
    (0..report.after.len())
        .into_par_iter()
        .filter(|&i| report.after[i].verdict.is_refinable())
        .map(|i| {
            let x0 = report.after[i].initial.center();
            (i, outcome_from(&filter, &x0, time, &ends_in_target))
        })
        .collect()
}

/// Where the ground-truth filtered system goes from `x0` in the system `time` names, with
/// `in_target` the goal and trap boxes. A diagnostic, one start: the ODE by RK4 at `dt` (a QP
/// filter solves four times a step; the proof-grade check, [`simulation_check`], takes
/// `dt/10`).
pub fn outcome_from(
    filter: &crate::filter::SafetyFilter,
    x0: &[f64],
    time: TimeModel,
    in_target: &(dyn Fn(&[f64]) -> bool + Sync),
) -> CentreOutcome {
    let s = filter.scenario();
    let (tr, left_s) = simulate_model(filter, x0, time, 1);
    if left_s.is_some() {
        CentreOutcome::LeavesSBetweenSamples
    } else if tr.x.iter().any(|x| !s.reach.region.contains(x)) {
        CentreOutcome::LeavesRegion
    } else if tr.stopped.is_some() {
        CentreOutcome::Infeasible
    } else if in_target(tr.last()) {
        CentreOutcome::EndsInTarget
    } else {
        CentreOutcome::EndsElsewhere(arrival(filter, tr.last(), time, in_target))
    }
}

/// Whether a state lies in the goal or one of `traps`' boxes: where the outcomes end well.
fn in_targets<'a>(
    s: &'a Scenario,
    traps: &'a [crate::verify::Trap],
) -> impl Fn(&[f64]) -> bool + Sync + 'a {
    |x: &[f64]| s.reach.goal.contains(x) || traps.iter().any(|t| t.region.contains(x))
}

/// Most starts of [`survey`]: a grid of `kⁿ ≤ 64` cell centres.
const SURVEY_STARTS: usize = 64;

/// [`survey`]'s outcomes counted: of its starts, how many reach the goal or a trap by `T`,
/// after it (and the latest arrival), leave `C`, meet an infeasible QP, leave `S` between
/// samples, or reach no target within [`LATER_HORIZONS`] more horizons.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Survey {
    /// Starts run (the centres in `S`).
    pub starts: usize,
    /// Reach the goal or a trap by `T`.
    pub by_horizon: usize,
    /// Reach one after `T`.
    pub later: usize,
    /// The latest such arrival (0 where none).
    pub latest: f64,
    /// Leave `C`.
    pub leaves_c: usize,
    /// Meet an infeasible QP.
    pub infeasible: usize,
    /// Leave `S` between samples.
    pub leaves_s: usize,
    /// Reach no target within [`LATER_HORIZONS`] more horizons.
    pub elsewhere: usize,
}

impl Survey {
    /// The counts of `outcomes`.
    pub fn of(outcomes: &[CentreOutcome]) -> Survey {
        let mut c = Survey {
            starts: outcomes.len(),
            ..Survey::default()
        };
        for o in outcomes {
            match o {
                CentreOutcome::EndsInTarget => c.by_horizon += 1,
                CentreOutcome::EndsElsewhere(Some(t)) => {
                    c.later += 1;
                    c.latest = c.latest.max(*t);
                }
                CentreOutcome::EndsElsewhere(None) => c.elsewhere += 1,
                CentreOutcome::LeavesRegion => c.leaves_c += 1,
                CentreOutcome::Infeasible => c.infeasible += 1,
                CentreOutcome::LeavesSBetweenSamples => c.leaves_s += 1,
            }
        }
        c
    }
}

/// Where the ground-truth filtered system goes from a grid of starts over `C ∩ S` (the centres
/// in `S` of at most 64 cells), in the scenario's time model, with the goal and `traps` as
/// targets, counted: `cbfreach check` says it before any training, so that a horizon too short
/// or a region the system leaves shows before a run.
pub fn survey(s: &Scenario, traps: &[crate::verify::Trap]) -> Survey {
    use crate::filter::SafetyFilter;
    let n = s.n();
    let per_axis = crate::boxes::per_axis_within(n, SURVEY_STARTS, SURVEY_STARTS);
    let starts: Vec<Vec<f64>> = (s.reach.region.partition(&vec![per_axis; n]).iter())
        .map(|c| c.center())
        .filter(|x| s.is_safe(x))
        .collect();
    let filter = SafetyFilter::new(s);
    let in_target = in_targets(s, traps);
    let outcomes: Vec<CentreOutcome> = (starts.par_iter())
        .map(|x0| outcome_from(&filter, x0, s.reach.time, &in_target))
        .collect();
    Survey::of(&outcomes)
}

/// When the system from `x` (at `T`) first reaches a target, run on for [`LATER_HORIZONS`]
/// horizons in the same model: `None` where it does not, or leaves `C` or `S` or meets an
/// infeasible QP first.
fn arrival(
    filter: &crate::filter::SafetyFilter,
    x: &[f64],
    time: TimeModel,
    in_target: &(dyn Fn(&[f64]) -> bool + Sync),
) -> Option<f64> {
    let s = filter.scenario();
    let mut x = x.to_vec();
    for k in 1..=LATER_HORIZONS {
        let (tr, left_s) = simulate_model(filter, &x, time, 1);
        let from = k as f64 * s.reach.horizon;
        for (t, state) in tr.t.iter().zip(&tr.x) {
            if !s.reach.region.contains(state) {
                return None;
            }
            if in_target(state) {
                return Some(from + t);
            }
        }
        if left_s.is_some() || tr.stopped.is_some() {
            return None;
        }
        x = tr.last().to_vec();
    }
    None
}

/// [`centre_outcomes`], summed as shares of the safe area.
pub fn explain_unverified(s: &Scenario, report: &VerifyReport) -> UnverifiedCauses {
    UnverifiedCauses::of(report, &centre_outcomes(s, report))
}

impl UnverifiedCauses {
    /// The leaves' `outcomes` ([`centre_outcomes`] of `report`) as shares of its safe area.
    pub fn of(report: &VerifyReport, outcomes: &[(usize, CentreOutcome)]) -> UnverifiedCauses {
        let safe_area = Shares::of(&report.after).safe_area;
        let mut c = UnverifiedCauses::default();
        if safe_area <= 0.0 {
            return c;
        }
        for &(i, outcome) in outcomes {
            let share = report.after[i].initial.volume() / safe_area;
            c.unverified += share;
            *match outcome {
                CentreOutcome::LeavesSBetweenSamples => &mut c.unsafe_between_samples,
                CentreOutcome::LeavesRegion => &mut c.leaves_region,
                CentreOutcome::Infeasible => &mut c.infeasible,
                CentreOutcome::EndsElsewhere(_) => &mut c.ends_elsewhere,
                CentreOutcome::EndsInTarget => &mut c.too_loose,
            } += share;
            if let CentreOutcome::EndsElsewhere(Some(t)) = outcome {
                c.arrives_later += share;
                c.latest_arrival = c.latest_arrival.max(t);
            }
        }
        c
    }
}

//! Proves absorbing boxes for the goal and the traps ([`crate::reach::absorb`]) with the CPU
//! engine's own tubes, so that `verify` may stop a tube once its set lies in one
//! (docs/design.md §2.12, "Absorbing boxes").
//!
//! For a target `G` (the goal box, or a trap's box) with centre `c` (the goal's centre, the
//! equilibrium), the candidates are `I = c ± s·(G's half-widths)` met with `G`, for the scales
//! of [`SCALES`]. The engine runs each from `I` over the horizon; `I` is absorbing when, for
//! some sample time `p·dt` (a multiple of the control period), the sets at `dt, 2dt, …, p·dt`
//! lie in `G`, the set at `p·dt` lies in `I`, the tube ran that far, no set up to it lies
//! outside `S`, the filter's QP is proven feasible on each, and (sampled data) no set up to it
//! may leave `S` between samples. The sets bound every trajectory of the model from `I`, so
//! every such trajectory is in `G` at those times and in `I` again at `p·dt`; by induction it
//! is in `G` at every later sample time. Of a target's candidates the largest proven is kept.
//! The proof runs on the CPU engine whatever `--backend` is, so every engine stops tubes at
//! the same boxes.

use serde::{Deserialize, Serialize};

use super::{BoxVerdict, Trap};
use crate::boxes::IntervalBox;
use crate::reach::absorb::Absorber;
use crate::reach::{Backend, CpuBackend, ReachError, ReachProblem, ReachSettings, Tube};
use crate::scenario::Scenario;

/// Scales of a target's half-widths tried as absorbing boxes, largest first.
pub const SCALES: [f64; 4] = [1.0, 0.75, 0.5, 0.25];

/// A box proven absorbing, and for what.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Absorbing {
    /// The box `I`.
    pub inner: IntervalBox,
    /// `None` for the goal, `Some(k)` for trap `k`.
    pub trap: Option<usize>,
    /// The steps of `dt` after which the sets from `I` are back in `I`.
    pub period: usize,
}

/// The absorbing boxes of the goal and of each trap that some scale of [`SCALES`] proves, run
/// on `problem` (whose own absorbing boxes are not used) with the verification's settings.
pub fn absorbing_boxes(
    scenario: &Scenario,
    problem: &ReachProblem,
    reach: &ReachSettings,
    traps: &[Trap],
) -> Result<Vec<Absorbing>, ReachError> {
    let goal = &scenario.reach.goal;
    let goal_centre: Vec<f64> = (0..goal.dim())
        .map(|i| 0.5 * (goal.lower[i] + goal.upper[i]))
        .collect();
    let targets: Vec<(Option<usize>, &IntervalBox, &[f64])> =
        std::iter::once((None, goal, &goal_centre[..]))
            .chain(
                traps
                    .iter()
                    .enumerate()
                    .map(|(k, t)| (Some(k), &t.region, &t.x[..])),
            )
            .collect();
    let mut candidates = Vec::new();
    for &(_, target, centre) in &targets {
        for s in SCALES {
            candidates.push(scaled(target, centre, s));
        }
    }
    // Candidates that are not boxes of C (a trap's box across C's side) are left out.
    let runs: Vec<usize> = (0..candidates.len())
        .filter(|&k| matches!(&candidates[k], Some(b) if b.is_subset_of(&problem.region)))
        .collect();
    let initial: Vec<IntervalBox> = runs.iter().filter_map(|&k| candidates[k].clone()).collect();
    let unabsorbed = ReachProblem {
        absorbing: Default::default(),
        ..problem.clone()
    };
    let settings = ReachSettings {
        every: 1,
        ..reach.clone()
    };
    let result = CpuBackend.reach(&unabsorbed, &initial, &settings, &|_, _| {})?;
    let mut tubes: Vec<Option<Tube>> = vec![None; candidates.len()];
    for (k, tube) in runs.into_iter().zip(result.boxes) {
        tubes[k] = Some(tube);
    }
    let mut found = Vec::new();
    for (t, &(trap, target, _)) in targets.iter().enumerate() {
        // The largest scale that proves it.
        let proven = (0..SCALES.len()).find_map(|s| {
            let k = t * SCALES.len() + s;
            let (inner, tube) = (candidates[k].as_ref()?, tubes[k].as_ref()?);
            let period = period_of(scenario, &unabsorbed, tube, inner, target)?;
            Some(Absorbing {
                inner: inner.clone(),
                trap,
                period,
            })
        });
        found.extend(proven);
    }
    Ok(found)
}

/// `centre ± s·(target's half-widths)`, met with `target`; `None` where that is empty.
fn scaled(target: &IntervalBox, centre: &[f64], s: f64) -> Option<IntervalBox> {
    let w = target.widths();
    let lower = (0..w.len())
        .map(|i| (centre[i] - 0.5 * s * w[i]).max(target.lower[i]))
        .collect();
    let upper = (0..w.len())
        .map(|i| (centre[i] + 0.5 * s * w[i]).min(target.upper[i]))
        .collect();
    IntervalBox::new(lower, upper).ok()
}

/// The first sample time (in steps of `dt`) at which `tube`, run from `inner`, proves `inner`
/// absorbing for `target` (module documentation); `None` where none does.
fn period_of(
    scenario: &Scenario,
    problem: &ReachProblem,
    tube: &Tube,
    inner: &IntervalBox,
    target: &IntervalBox,
) -> Option<usize> {
    let control = problem.period_steps().ok()?.max(1);
    let finding = tube.unsafe_between_samples.as_ref().map(|f| f.t);
    let samples = tube.model_samples();
    for (j, s) in samples.iter().enumerate().skip(1) {
        let outside_s = scenario.cbfs.iter().any(|c| {
            c.h.eval_interval(&crate::intervals::box_of(&s.set.lower, &s.set.upper))
                .upper
                < 0.0
        });
        let before_finding = finding.is_none_or(|t| s.t < t);
        if !s.set.is_subset_of(target) || outside_s || !before_finding {
            return None;
        }
        let steps = (s.t / problem.dt).round() as usize;
        if steps.is_multiple_of(control)
            && s.set.is_subset_of(inner)
            && problem.proves_feasible_on(&samples[..=j])
        {
            return Some(steps);
        }
    }
    None
}

/// The verified leaves whose tubes stopped in one of `proven`'s boxes (at `t_end`, before the
/// horizon `T`), the QP proven feasible on their sets: absorbers with `τ = t_end`, for the next
/// rounds' tubes. Leaves that stopped in another leaf are left out (their `τ` would chain).
pub fn leaf_absorbers(leaves: &[BoxVerdict], proven: &[Absorbing], horizon: f64) -> Vec<Absorber> {
    leaves
        .iter()
        .filter(|b| b.verdict.is_verified() && b.feasible == Some(true))
        .filter_map(|b| {
            let (t, last) = (b.t_end?, b.final_set.as_ref()?);
            let into = proven.iter().find(|a| last.is_subset_of(&a.inner))?;
            (t < horizon * (1.0 - 1e-12)).then(|| Absorber {
                set: b.initial.clone(),
                within: t,
                trap: into.trap,
            })
        })
        .collect()
}

/// `proven`'s boxes as absorbers (`τ = 0`).
pub fn target_absorbers(proven: &[Absorbing]) -> Vec<Absorber> {
    proven
        .iter()
        .map(|a| Absorber {
            set: a.inner.clone(),
            within: 0.0,
            trap: a.trap,
        })
        .collect()
}

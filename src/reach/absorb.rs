//! Absorbing boxes: where a tube may stop before the horizon because what follows is already
//! proven (docs/design.md §2.12, "Absorbing boxes").
//!
//! A box `I` is absorbing for a target `G ⊇ I` (the goal, or a trap's box) when every
//! trajectory of the problem's time model from `I` lies in `G` at each of the next `p` sample
//! times and in `I` again at the `p`-th (`verify` proves it with the engine's own tube from `I`:
//! [`crate::verify::absorbing_boxes`]). Then, by induction over blocks of `p` steps, a
//! trajectory in `I` at a sample time lies in `G` at every later one, the horizon included:
//! once a tube's set lies in `I`, its verdict is decided and its remaining steps are skipped.
//! The check is one containment at the recorded samples, the same for both engines: the CPU
//! engine stops the tube there ([`absorbs`] inside [`super::cpu_host::record_sample`]), the
//! GPU engine's tubes are cut at the same sample afterwards ([`cut`]).

use crate::boxes::IntervalBox;

use super::{ReachProblem, Tube, TubeEnd};

/// Whether the set sampled at `t` lies in one of the problem's absorbing boxes, and `t` is a
/// time at which that decides the rest: a whole number of steps of `dt` after the start (not a
/// substep, not the start), a multiple of the control period in sampled data.
pub fn absorbs(problem: &ReachProblem, t: f64, set: &IntervalBox) -> bool {
    if problem.absorbing.is_empty() {
        return false;
    }
    let steps = (t / problem.dt).round();
    let period = problem.period_steps().unwrap_or(1).max(1);
    (t - steps * problem.dt).abs() <= 1e-9 * problem.dt.max(t)
        && steps >= 1.0
        && (steps as usize).is_multiple_of(period)
        && problem.absorbing.iter().any(|i| set.is_subset_of(i))
}

/// Cuts `tube` at its first recorded sample (after the start, at a sample time, before its end)
/// that lies in an absorbing box, as the CPU engine stops it there. Does nothing where no
/// sample is absorbed.
pub fn cut(problem: &ReachProblem, tube: &mut Tube) {
    if problem.absorbing.is_empty() {
        return;
    }
    // A tube that left `C` keeps the set it left on as its last sample, which the engine did
    // not take as a sample of the model (no other end pushes one).
    let usable = match tube.end {
        TubeEnd::LeftRegion { .. } | TubeEnd::FlowpipeLeftRegion { .. } => {
            tube.tube.len().saturating_sub(1)
        }
        _ => tube.tube.len(),
    };
    let at = tube.tube[..usable]
        .iter()
        .position(|s| absorbs(problem, s.t, &s.set));
    if let Some(k) = at {
        tube.end = TubeEnd::Absorbed { t: tube.tube[k].t };
        tube.tube.truncate(k + 1);
    }
}

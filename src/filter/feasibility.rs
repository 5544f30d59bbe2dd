//! Proofs that a general QP filter is feasible at every point of a box: one `θ` that satisfies
//! every row over the whole box, checked by interval arithmetic (docs/design.md §2.2). It may
//! import the filter's rows and solver, the scenario, intervals and boxes.

use super::SafetyFilter;
use crate::boxes::IntervalBox;
use crate::intervals::Interval;
use crate::scenario::Scenario;

/// Whether one `θ*` satisfies `aₖ(x)·θ* ≤ bₖ(x)` for every `x` of `box ∩ S`, with the rows
/// enclosed over the box (`a` row-major rows × m, `b` one per row). Then `θ*` is feasible at
/// every such point, and so is the QP. Two candidates, each only that (the interval check is
/// the proof): the point deep inside the rows at the box's centre
/// ([`super::solve::margin_point`]), then the one chosen for the enclosed rows themselves
/// ([`super::solve::robust_point`]), which finds one where the feasible `θ` lie far from 0.
pub(crate) fn proves_feasible(
    s: &Scenario,
    cell: &IntervalBox,
    a: &[Interval],
    b: &[Interval],
) -> bool {
    let m = s.m();
    let at_centre = SafetyFilter::new(s)
        .constraint_rows(&cell.center())
        .ok()
        .and_then(|rows| super::solve::margin_point(&rows, m));
    if at_centre.is_some_and(|theta| holds(&theta, a, b, m)) {
        return true;
    }
    let ends: Vec<(f64, f64)> = a.iter().map(|e| (e.lower, e.upper)).collect();
    let least: Vec<f64> = b.iter().map(|e| e.lower).collect();
    super::solve::robust_point(&ends, &least, m, super::solve::RobustGoal::Deepest)
        .is_some_and(|theta| holds(&theta, a, b, m))
}

/// Whether `a(x)·θ ≤ b(x)` on every row for the enclosures `a`, `b` (NaN proves nothing).
pub(crate) fn holds(theta: &[f64], a: &[Interval], b: &[Interval], m: usize) -> bool {
    b.iter().enumerate().all(|(k, &bk)| {
        let lhs = (0..m).fold(Interval::point(0.0), |acc, j| {
            acc + a[k * m + j] * Interval::point(theta[j])
        });
        let r = lhs - bk;
        !r.is_nan() && r.upper <= 0.0
    })
}

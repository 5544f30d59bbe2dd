//! Certification: a certified bound of `‖N − v‖∞` per cell of `C ∩ S` (cell bounds, adaptive
//! refinement, a witness of the error attained). It may import the filter's enclosures, the
//! network's bounds, the error map's cells and the analysis' settings.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use rayon::prelude::*;

use super::joint::{piece_error, split_axis};
use super::{check_dims, random_points, AnalysisError, ErrorSettings};
use crate::bounds::{network_bounds, BoundMethod, PreparedNetwork};
use crate::boxes::IntervalBox;
use crate::dataset::grid_points;
use crate::error_map::CellBound;
use crate::filter::{meet, v_enclosure, FilterMethod, SafetyFilter, VForms};
use crate::intervals::Interval;
use crate::network::Mlp;
use crate::rounding::round_up;
use crate::scenario::Scenario;

pub(super) fn sum(it: impl Iterator<Item = Interval>) -> Interval {
    it.fold(Interval::point(0.0), |a, b| a + b)
}

/// Whether some `hᵢ < 0` on the whole box (by interval evaluation): the box misses `S`.
pub fn proven_unsafe(s: &Scenario, cell: &IntervalBox) -> bool {
    let xs: Vec<Interval> = (0..s.n())
        .map(|i| Interval::new(cell.lower[i], cell.upper[i]))
        .collect();
    s.cbfs.iter().any(|c| {
        let h = c.h.eval_interval(&xs);
        !h.is_nan() && h.upper < 0.0
    })
}

/// `max_j max(N̄ⱼ − v̲ⱼ, v̄ⱼ − N̲ⱼ)`, rounded up; +∞ when anything is unbounded or NaN.
pub(super) fn error_from(n_lo: &[f64], n_hi: &[f64], v: &[Interval]) -> f64 {
    let mut e = 0.0_f64;
    for j in 0..v.len() {
        let a = round_up(n_hi[j] - v[j].lower);
        let b = round_up(v[j].upper - n_lo[j]);
        if a.is_nan() || b.is_nan() {
            return f64::INFINITY;
        }
        e = e.max(a).max(b);
    }
    e
}

/// A certified bound of `‖N(x) − v(x)‖∞` over `box ∩ S` (where `v` is feasible):
/// IBP first, then backward CROWN (intersected with IBP) when the IBP bound exceeds `good_enough`.
/// `None` where [`v_enclosure`] gives none; +∞ when an enclosure is unbounded.
pub fn cell_error_bound(
    s: &Scenario,
    net: &Mlp,
    method: FilterMethod,
    cell: &IntervalBox,
    good_enough: f64,
) -> Result<Option<f64>, AnalysisError> {
    let Some(v) = v_enclosure(s, method, cell) else {
        return Ok(None);
    };
    if v.iter()
        .any(|vi| vi.lower == f64::NEG_INFINITY || vi.upper == f64::INFINITY)
    {
        return Ok(Some(f64::INFINITY));
    }
    let ibp = network_bounds(net, &cell.lower, &cell.upper, BoundMethod::Ibp)?;
    let e = error_from(&ibp.lower, &ibp.upper, &v);
    if e <= good_enough {
        return Ok(Some(e));
    }
    let crown = network_bounds(net, &cell.lower, &cell.upper, BoundMethod::Crown)?;
    let lo: Vec<f64> = (0..v.len())
        .map(|j| ibp.lower[j].max(crown.lower[j]))
        .collect();
    let hi: Vec<f64> = (0..v.len())
        .map(|j| ibp.upper[j].min(crown.upper[j]))
        .collect();
    Ok(Some(e.min(error_from(&lo, &hi, &v))))
}

/// Sub-boxes per axis of a cell for the enclosures of `v` ([`VForms::enclose`] runs on each):
/// the interval Jacobian over a sub-box is that much tighter, and the mean-value forms with it.
/// `k` per axis with `kⁿ ≤ 64` (8 × 8 in the plane).
pub fn enclosure_pieces(cell: &IntervalBox) -> Vec<IntervalBox> {
    let n = cell.dim();
    let k = crate::boxes::per_axis_within(n, 64, 8);
    // Shared cut points, so that the pieces tile the cell whatever the rounding (the cuts are
    // monotone in `j` and the end points are the cell's own).
    let cuts: Vec<Vec<f64>> = (0..n)
        .map(|i| {
            let (l, u) = (cell.lower[i], cell.upper[i]);
            (0..=k)
                .map(|j| match j {
                    0 => l,
                    j if j == k => u,
                    j => (l + (u - l) * j as f64 / k as f64).clamp(l, u),
                })
                .collect()
        })
        .collect();
    let mut pieces = Vec::with_capacity(k.pow(n as u32));
    let mut idx = vec![0usize; n];
    loop {
        let lower = (0..n).map(|i| cuts[i][idx[i]]).collect();
        let upper = (0..n).map(|i| cuts[i][idx[i] + 1]).collect();
        pieces.push(IntervalBox { lower, upper });
        let mut i = 0;
        loop {
            if i == n {
                return pieces;
            }
            idx[i] += 1;
            if idx[i] < k {
                break;
            }
            idx[i] = 0;
            i += 1;
        }
    }
}

/// [`cell_error_bound`] with the mean-value enclosures of `v` ([`VForms::enclose`]) on the
/// pieces of the cell ([`enclosure_pieces`]) and, where `v` is smooth on a piece, the joint
/// affine bound of `N − v` there (`joint_error`): `N` is bounded once over the cell (IBP, and
/// `method`'s affine bounds when IBP does not already meet `good_enough`), and the bound is the
/// max over the pieces of the least of their sound bounds. +∞ when an enclosure is unbounded.
pub fn cell_error_bound_mv(
    forms: &VForms,
    s: &Scenario,
    net: &PreparedNetwork<'_>,
    cell: &IntervalBox,
    method: BoundMethod,
    good_enough: f64,
) -> Result<f64, AnalysisError> {
    Ok(bound_and_split(forms, s, net, cell, method, good_enough)?.0)
}

/// [`cell_error_bound_mv`] and the axis to bisect the cell across ([`split_axis`]; `None`:
/// its widest).
fn bound_and_split(
    forms: &VForms,
    s: &Scenario,
    net: &PreparedNetwork<'_>,
    cell: &IntervalBox,
    method: BoundMethod,
    good_enough: f64,
) -> Result<(f64, Option<usize>), AnalysisError> {
    let v =
        v_enclosure(s, forms.method(), cell).unwrap_or_else(|| vec![Interval::ENTIRE; forms.m()]);
    let unbounded = |v: &[Interval]| {
        v.iter()
            .any(|vi| vi.is_nan() || vi.lower == f64::NEG_INFINITY || vi.upper == f64::INFINITY)
    };
    let ibp = net.bounds(&cell.lower, &cell.upper, BoundMethod::Ibp)?;
    let coarse = if unbounded(&v) {
        f64::INFINITY
    } else {
        error_from(&ibp.lower, &ibp.upper, &v)
    };
    if coarse <= good_enough {
        return Ok((coarse, None));
    }
    let ab = net.bounds(&cell.lower, &cell.upper, method)?;
    let n_lo: Vec<f64> = (0..ab.n_out)
        .map(|j| ibp.lower[j].max(ab.lower[j]))
        .collect();
    let n_hi: Vec<f64> = (0..ab.n_out)
        .map(|j| ibp.upper[j].min(ab.upper[j]))
        .collect();
    let (v_whole, shape_whole) = forms.enclose(s, cell);
    let whole = if unbounded(&v_whole) {
        f64::INFINITY
    } else {
        piece_error(&ab, &n_lo, &n_hi, cell, &v_whole, &shape_whole)
    };
    let coarse = coarse.min(whole);
    let axis = split_axis(&ab, &shape_whole, cell, &s.reach.region);
    if coarse <= good_enough {
        return Ok((coarse, axis));
    }
    let mut worst = 0.0_f64;
    for piece in enclosure_pieces(cell) {
        let (vp, shape) = forms.enclose(s, &piece);
        let vp: Vec<Interval> = vp.iter().zip(&v_whole).map(|(&a, &b)| meet(a, b)).collect();
        if unbounded(&vp) {
            return Ok((coarse, axis));
        }
        worst = worst.max(piece_error(&ab, &n_lo, &n_hi, &piece, &vp, &shape));
        if worst >= coarse {
            return Ok((coarse, axis));
        }
    }
    Ok((worst.min(coarse), axis))
}

/// `max ‖N(x) − v(x)‖∞` over a few points of `cell ∩ S` where the filter is feasible: the
/// corners, the centre and `extra` seeded random points (0 when none is safe and feasible).
pub fn sampled_cell_error(
    s: &Scenario,
    filter: &SafetyFilter,
    net: &Mlp,
    cell: &IntervalBox,
    extra: usize,
    seed: u64,
) -> f64 {
    let mut pts: Vec<Vec<f64>> = cell.corners().collect();
    pts.push(cell.center());
    pts.extend(random_points(cell, extra, seed));
    pts.iter()
        .filter_map(|x| error_at(s, filter, net, x))
        .fold(0.0, f64::max)
}

/// `‖N(x) − v(x)‖∞` at a safe point `x` where the filter is feasible; `None` elsewhere.
fn error_at(s: &Scenario, filter: &SafetyFilter, net: &Mlp, x: &[f64]) -> Option<f64> {
    if !s.is_safe(x) {
        return None;
    }
    let v = filter.eval(x).ok()?;
    Some(
        v.iter()
            .zip(net.forward(x))
            .fold(0.0_f64, |e, (vj, nj)| e.max((vj - nj).abs())),
    )
}

/// Whether the filter is infeasible at a safe corner or at the centre of the cell.
fn meets_infeasibility(s: &Scenario, filter: &SafetyFilter, cell: &IntervalBox) -> bool {
    cell.corners()
        .chain(std::iter::once(cell.center()))
        .any(|x| s.is_safe(&x) && filter.eval(&x).is_err())
}

/// The outcome of [`certify()`].
#[derive(Clone, Debug, PartialEq)]
pub struct Certified {
    /// `max` of the cells' bounds: a certified `M_C` over `C ∩ S`.
    pub linf: f64,
    /// The largest error found by sampling densely the [`WITNESS_CELLS`] cells of largest
    /// bound ([`witness_error`]): an error the network attains, so `linf` is within
    /// `linf / witness_linf` of the truth (0 when no sample was feasible).
    pub witness_linf: f64,
    /// Where `witness_linf` is attained (empty when no sample was feasible).
    pub witness: Vec<f64>,
    /// The cells, tiling `C`; those proven unsafe (dropped) have bound 0.
    pub cells: Vec<CellBound>,
    /// Cells dropped as proven unsafe.
    pub dropped: usize,
    /// Cell evaluations spent.
    pub evaluated: usize,
    /// Whether the refinement stopped on the budget rather than on the target.
    pub budget_spent: bool,
    /// Kept cells whose bound is +∞ (e.g. tiny cells at points where `L_g h = 0` on the
    /// boundary of `S`, where the interval closed form cannot resolve `0/0`).
    pub uncertified: usize,
    /// The max over the cells with a finite bound (a bound over `C ∩ S` minus those cells).
    pub finite_linf: f64,
    /// Kept cells whose bound met their target `max(local_ratio · sampled, floor)`, capped at
    /// `max(local_ratio · measured global error, floor)`.
    pub satisfied: usize,
}

/// A cell waiting for refinement. Cells whose bound exceeds the global goal come first, the
/// largest bound first; the others by their priority (the weighted gap between their bound and
/// their target).
struct Entry {
    above_goal: bool,
    priority: f64,
    bound: f64,
    /// The cell's largest width: at equal keys (the +∞ bounds of coarse cells) the larger cell
    /// first, so that the tree grows breadth-first there rather than into one corner.
    size: f64,
    /// Whether the bound met the cell's target (the second stage refines such cells too).
    met: bool,
    cell: IntervalBox,
    /// The axis to bisect it across (`None`: the widest).
    axis: Option<usize>,
}

impl Entry {
    fn key(&self) -> (bool, f64) {
        let by = if self.above_goal {
            self.bound
        } else {
            self.priority
        };
        (self.above_goal, by)
    }
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Entry {}

impl PartialOrd for Entry {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Entry {
    fn cmp(&self, other: &Self) -> Ordering {
        let ((a, x), (b, y)) = (self.key(), other.key());
        // Ties (the +∞ bounds at singular points) by the cells' lower corners, so that the
        // order, and with it the seeds of the cells' samples, does not rest on the heap's layout.
        a.cmp(&b)
            .then(x.total_cmp(&y))
            .then(self.size.total_cmp(&other.size))
            .then_with(|| {
                self.cell
                    .lower
                    .iter()
                    .zip(&other.cell.lower)
                    .map(|(p, q)| p.total_cmp(q))
                    .find(|o| o.is_ne())
                    .unwrap_or(Ordering::Equal)
            })
    }
}

/// A certified `M_C` over `C ∩ S` with local bounds (see the [analysis docs](super)).
///
/// The cells are the leaves of a bisection tree grown from `C` itself (no starting width, so
/// that the map fits the region and the network in any dimension). Every cell gets a certified
/// bound ([`cell_error_bound_mv`]) and a cheap sampled error `e` (corners, centre and
/// [`ErrorSettings::cell_samples`] random points). A cell is bisected (across the axis
/// [`super::joint::split_axis`] names, else its widest) while its bound exceeds its target
/// `max(local_ratio · e, floor)` ([`ErrorSettings::local_ratio`], [`ErrorSettings::floor`]),
/// the largest gaps
/// `bound − target` times cell width first (weighted by [`ErrorSettings::goal_weight`] on cells
/// that meet the scenario's goal set), down to [`ErrorSettings::min_cell`], in parallel
/// batches, until every cell meets its target, [`ErrorSettings::budget`] cell evaluations are
/// spent, or the map holds [`ErrorSettings::max_cells`] cells. A cell's target is at most
/// `local_ratio · target` (`target`: the measured global error), and cells whose bound exceeds
/// that are refined before all others (the largest bound first, the larger cell at equal
/// bounds): the global certified `M_C` is the max over the cells, and the area-weighted order
/// alone can spend the budget before it reaches a small cell that holds that max. When every
/// cell meets its target with budget left, the cells of largest `bound × width` are bisected
/// further until the map holds [`ErrorSettings::detail_cells`] cells: a box's local bound is
/// the max over the cells it meets, so large cells make it less local. A cell meeting a point
/// where the QP is infeasible is refined like any other until it is a 64th of `C`'s widest
/// side, then kept as it is (there the enclosure of `v` stays wide however small the cell), and
/// the second stage leaves it. `None` when the filter
/// is a QP with more active sets than [`crate::filter::MAX_SETS`] (any filter with fewer is
/// certified through its active-set pieces, [`VForms`]). `progress` is told the evaluations so
/// far and the largest bound still waiting for refinement.
pub fn certify(
    s: &Scenario,
    net: &Mlp,
    target: f64,
    settings: &ErrorSettings,
    progress: &(dyn Fn(usize, f64) + Sync),
) -> Result<Option<Certified>, AnalysisError> {
    check_dims(s, net)?;
    let Some(forms) = VForms::new(s) else {
        return Ok(None);
    };
    let filter = SafetyFilter::new(s);
    let prepared = PreparedNetwork::new(net)?;
    let c = &s.reach.region;
    let ratio = settings.local_ratio.max(1.0);
    let floor = settings.floor.max(0.0);
    let min_cell = settings.min_cell.max(1e-9);
    let goal = &s.reach.goal;
    let weight = |cell: &IntervalBox| {
        let meets = goal.dim() == cell.dim()
            && (0..cell.dim())
                .all(|i| cell.lower[i] <= goal.upper[i] && goal.lower[i] <= cell.upper[i]);
        if meets {
            settings.goal_weight.max(1.0)
        } else {
            1.0
        }
    };
    let global_goal = ratio * target;
    let mut heap: BinaryHeap<Entry> = BinaryHeap::new();
    // Finished cells, whether each met its target, and whether it is settled (meets an
    // infeasible point: the second stage leaves it).
    let mut done: Vec<(CellBound, bool, bool)> = Vec::new();
    let dropped = std::cell::Cell::new(0_usize);
    let mut evaluated = 0;
    // Each cell: dropped (Err) or (bound, its target).
    let width = |cell: &IntervalBox| cell.widths().iter().fold(0.0_f64, |a, &b| a.max(b));
    let settle_width = width(c) / SETTLE_SPLITS;
    let eval = |cells: Vec<IntervalBox>,
                salt: usize|
     -> Result<Vec<Result<CellOutcome, IntervalBox>>, AnalysisError> {
        cells
            .into_par_iter()
            .enumerate()
            .map(|(k, cell)| {
                if proven_unsafe(s, &cell) {
                    return Ok(Err(cell));
                }
                let seed = settings.seed ^ ((salt + k) as u64).wrapping_mul(0x2545_F491_4F6C_DD1D);
                let e = sampled_cell_error(s, &filter, net, &cell, settings.cell_samples, seed);
                // A cell's own error may exceed the global one (it was not sampled there), but
                // its bound must also come within `local_ratio` of the global measured error.
                let tgt = (ratio * e).max(floor).min(global_goal.max(floor));
                let (b, axis) =
                    bound_and_split(&forms, s, &prepared, &cell, settings.cell_bounds, tgt)?;
                // Where the QP is infeasible on part of the cell, the enclosure of `v` stays
                // wide however small the cell: once the cell is small (a 64th of C's widest
                // side), keep its bound as it is (target +∞: settled, not refined further).
                let tgt = if width(&cell) <= settle_width && meets_infeasibility(s, &filter, &cell)
                {
                    f64::INFINITY
                } else {
                    tgt
                };
                Ok(Ok((b, tgt, cell, axis)))
            })
            .collect()
    };
    // `detail`: the second stage, where cells that met their target are bisected further,
    // the largest `bound × width` first.
    let absorb = |res: Vec<Result<CellOutcome, IntervalBox>>,
                  detail: bool,
                  heap: &mut BinaryHeap<Entry>,
                  done: &mut Vec<(CellBound, bool, bool)>| {
        for r in res {
            match r {
                // Dropped cells stay in the map with bound 0, so that its cells tile C and a
                // cell missing from a file is seen (ErrorMap::load_certified).
                Err(cell) => {
                    dropped.set(dropped.get() + 1);
                    let c = CellBound {
                        lower: cell.lower,
                        upper: cell.upper,
                        bound: 0.0,
                    };
                    done.push((c, true, true));
                }
                Ok((bound, tgt, cell, axis)) => {
                    let size = width(&cell);
                    let settled = tgt == f64::INFINITY;
                    let finer = detail && !settled && bound.is_finite() && bound > floor;
                    let met = bound <= tgt;
                    if met && !finer {
                        let c = CellBound {
                            lower: cell.lower,
                            upper: cell.upper,
                            bound,
                        };
                        done.push((c, true, settled));
                    } else {
                        let gap = if bound.is_finite() {
                            (bound - tgt).max(bound * f64::from(u8::from(detail)))
                        } else {
                            f64::MAX
                        };
                        // Larger cells first at equal gaps: a cell's bound reaches every box
                        // that meets it, and tiny cells at singular sets gain nothing.
                        heap.push(Entry {
                            above_goal: bound > global_goal,
                            priority: gap * size * weight(&cell),
                            bound,
                            size,
                            met,
                            cell,
                            axis,
                        });
                    }
                }
            }
        }
    };
    evaluated += 1;
    let res = eval(vec![c.clone()], 0)?;
    absorb(res, false, &mut heap, &mut done);
    let batch = 16 * rayon::current_num_threads().max(1);
    let mut budget_spent = false;
    let mut detail = false;
    loop {
        let worst = heap.iter().map(|e| e.bound).fold(0.0, f64::max);
        progress(evaluated, worst);
        // Dropped cells do not count against `max_cells` (they are not refined).
        let kept = heap.len() + done.len() - dropped.get();
        if heap.is_empty() && !detail && kept < settings.detail_cells {
            // Every cell met its target: on to the second stage, with every finite cell
            // above the floor waiting again.
            detail = true;
            let (wait, keep): (Vec<_>, Vec<_>) = std::mem::take(&mut done)
                .into_iter()
                .partition(|(c, _, settled)| !settled && c.bound.is_finite() && c.bound > floor);
            done = keep;
            for (cb, met, _) in wait {
                let cell = cb.cell();
                let size = width(&cell);
                heap.push(Entry {
                    above_goal: false,
                    priority: cb.bound * size * weight(&cell),
                    bound: cb.bound,
                    size,
                    met,
                    cell,
                    axis: None,
                });
            }
        }
        if heap.is_empty() {
            break;
        }
        // A bisection costs two evaluations.
        if evaluated + 2 > settings.budget || kept >= settings.max_cells {
            budget_spent = true;
            break;
        }
        if detail && kept >= settings.detail_cells {
            break;
        }
        let cap = if detail {
            settings.detail_cells.min(settings.max_cells)
        } else {
            settings.max_cells
        };
        let room = cap
            .saturating_sub(kept)
            .min(settings.budget.saturating_sub(evaluated) / 2)
            .clamp(1, batch);
        let mut children = Vec::new();
        // The parent's bound holds on its halves too: a child keeps the lesser, so that
        // refinement never raises a bound (`CROWN` on a half is not always tighter).
        let mut parents = Vec::new();
        while children.len() < 2 * room {
            let Some(Entry {
                bound,
                met,
                cell,
                axis,
                ..
            }) = heap.pop()
            else {
                break;
            };
            if width(&cell) < min_cell {
                let c = CellBound {
                    lower: cell.lower,
                    upper: cell.upper,
                    bound,
                };
                done.push((c, met, false));
                continue;
            }
            let (l, r) = match axis {
                Some(i) => cell.bisect_along(i),
                None => cell.bisect(),
            };
            children.push(l);
            children.push(r);
            parents.extend([bound, bound]);
        }
        if children.is_empty() {
            continue;
        }
        let salt = evaluated;
        evaluated += children.len();
        let res = eval(children, salt)?
            .into_iter()
            .zip(parents)
            .map(|(r, parent)| r.map(|(b, tgt, cell, axis)| (b.min(parent), tgt, cell, axis)))
            .collect();
        absorb(res, detail, &mut heap, &mut done);
    }
    done.extend(heap.into_iter().map(|e| {
        let c = CellBound {
            lower: e.cell.lower,
            upper: e.cell.upper,
            bound: e.bound,
        };
        (c, e.met, false)
    }));
    let satisfied = done.iter().filter(|(_, met, _)| *met).count() - dropped.get();
    let done: Vec<CellBound> = done.into_iter().map(|(c, ..)| c).collect();
    let linf = done.iter().map(|c| c.bound).fold(0.0, f64::max);
    let uncertified = done.iter().filter(|c| !c.bound.is_finite()).count();
    let finite_linf = done
        .iter()
        .map(|c| c.bound)
        .filter(|b| b.is_finite())
        .fold(0.0, f64::max);
    let (witness_linf, witness) = witness_error(s, &filter, net, &done);
    Ok(Some(Certified {
        linf,
        witness_linf,
        witness,
        uncertified,
        finite_linf,
        cells: done,
        dropped: dropped.get(),
        evaluated,
        budget_spent,
        satisfied,
    }))
}

/// How many cells of largest bound [`witness_error`] samples, and about how many points each.
pub const WITNESS_CELLS: usize = 32;
const WITNESS_POINTS_PER_CELL: usize = 1024;

/// The largest `‖N(x) − v(x)‖∞` on an equispaced grid (edges included, about
/// `WITNESS_POINTS_PER_CELL` points: 32 × 32 in two dimensions) of each of the
/// [`WITNESS_CELLS`] cells of largest bound, at the safe points where the filter is feasible,
/// and where it occurs. The measurement grid can miss a narrow peak (scenario 1's network errs
/// by 0.30 within 0.002 of (4.5, 0.9314), by 0.25 at most on the grid); the cells that hold
/// the certified max are where to look for it.
pub fn witness_error(
    s: &Scenario,
    filter: &SafetyFilter,
    net: &Mlp,
    cells: &[CellBound],
) -> (f64, Vec<f64>) {
    let mut worst: Vec<&CellBound> = cells.iter().collect();
    worst.sort_by(|a, b| b.bound.total_cmp(&a.bound));
    worst.truncate(WITNESS_CELLS);
    let n = cells.first().map_or(1, |c| c.lower.len()).max(1);
    let per_axis = ((WITNESS_POINTS_PER_CELL as f64)
        .powf(1.0 / n as f64)
        .floor() as usize)
        .max(2);
    worst
        .par_iter()
        .flat_map_iter(|c| {
            let cell = c.cell();
            grid_points(&cell, &vec![per_axis; cell.dim()])
        })
        .filter_map(|x| Some((error_at(s, filter, net, &x)?, x)))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap_or((0.0, Vec::new()))
}

/// A cell meeting a point where the QP is infeasible is refined until its widest side is at
/// most `1/SETTLE_SPLITS` of `C`'s, then kept as it is.
const SETTLE_SPLITS: f64 = 64.0;

/// A kept cell's certified bound, its refinement target (+∞: settled), the cell, and the axis
/// to bisect it across (`None`: its widest).
type CellOutcome = (f64, f64, IntervalBox, Option<usize>);

#[cfg(test)]
mod tests {
    use super::*;

    /// A 20 × 80 region: the map grows from `C` (never a grid of fixed-width cells filling
    /// the budget), its cells tile `C`, come in several sizes, and bound the error sampled
    /// inside each.
    #[test]
    fn the_tree_grows_from_c_and_its_cells_bound_the_sampled_error() {
        let text = r#"
name = "wide"
[system]
states = ["x", "y"]
inputs = ["u1", "u2"]
f = ["0", "0"]
g = [["1", "0"], ["0", "1"]]
kappa = ["-x", "-y"]
[[cbf]]
name = "disc"
h = "(x - 5)^2 + (y - 20)^2 - 9"
[reach]
region = { lower = [-10.0, -40.0], upper = [10.0, 40.0] }
m_c = 0.1
dt = 0.1
horizon = 1.0
goal = { lower = [-1.0, -1.0], upper = [1.0, 1.0] }
initial = [ { lower = [-1.0, -1.0], upper = [1.0, 1.0] } ]
"#;
        let s = Scenario::from_toml(text, "wide.toml", std::path::Path::new(".")).unwrap();
        // Small weights: the network errs by about |κ| = |x|, smooth, so that coarse cells
        // can meet their targets and the tree stays uneven.
        let mut net = Mlp::random(&[2, 8, 2], 3);
        for l in &mut net.layers {
            l.weight.iter_mut().for_each(|w| *w *= 0.1);
        }
        let settings = ErrorSettings {
            budget: 600,
            detail_cells: 150,
            ..ErrorSettings::default()
        };
        let c = certify(&s, &net, 10.0, &settings, &|_, _| {})
            .unwrap()
            .unwrap();
        assert!(c.evaluated <= settings.budget, "{}", c.evaluated);
        assert!(c.cells.len() > 8 && c.cells.len() <= settings.budget);
        let boxes: Vec<IntervalBox> = c.cells.iter().map(CellBound::cell).collect();
        assert!(crate::provenance::uncovered(&s.reach.region, &boxes, 1).is_empty());
        let widths: Vec<f64> = boxes
            .iter()
            .map(|b| b.widths()[0] * b.widths()[1])
            .collect();
        let (lo, hi) = widths
            .iter()
            .fold((f64::MAX, 0.0_f64), |(a, b), &w| (a.min(w), b.max(w)));
        assert!(hi >= 4.0 * lo, "cells of one size: {lo} .. {hi}");
        let filter = SafetyFilter::new(&s);
        for (k, cell) in c.cells.iter().enumerate() {
            let e = sampled_cell_error(&s, &filter, &net, &cell.cell(), 16, k as u64);
            assert!(e <= cell.bound, "{cell:?}: sampled {e}");
        }
    }
}

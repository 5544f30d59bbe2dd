//! Building the trainer's [`Dataset`] from a scenario's filter on a grid of its region.
//! May import: the filter, boxes and the trainer's `Dataset`; nothing of reachability.
//!
//! Training data for the surrogate `N ≈ v`: the filter evaluated on an equispaced grid.
//!
//! The grid covers the scenario's training region (default `C`), the unsafe set included
//! wherever the QP is feasible: boxes at equilibria on the obstacle boundary straddle it, and
//! their bounds see the network there (docs/design.md §2b). Points where the QP is infeasible are
//! skipped and counted. Each sample carries `Dv(x)` for the Sobolev term of the trainer.

use rayon::prelude::*;
use serde::Serialize;

use crate::boxes::{lattice_coordinate, IntervalBox};
use crate::filter::SafetyFilter;
use crate::network::train::{Dataset, Oracle, SampleSlopes};
use crate::scenario::Scenario;

pub use crate::boxes::grid_points;

/// What building a data set found.
#[derive(Clone, Debug, Default, Serialize)]
pub struct DatasetSummary {
    /// Grid points in all.
    pub grid_points: usize,
    /// Samples kept (feasible points).
    pub samples: usize,
    /// Points where the filter's QP is infeasible (skipped).
    pub infeasible: usize,
    /// Of those, the points in the safe set `S` where the QP itself has no solution (where it is
    /// meant to have one; a high-order CBF's has none wherever `ψ < 0`, outside `S`). The rest
    /// are outside `S`, or points whose slope's difference quotients reach where it has none.
    pub infeasible_in_s: usize,
    /// Kept samples outside the safe set `S`.
    pub unsafe_samples: usize,
    /// Kept samples where the filter acts (`v ≠ 0`).
    pub active_samples: usize,
}

impl DatasetSummary {
    /// Adds another build's counts (samples appended to this one's).
    pub fn add(&mut self, other: &DatasetSummary) {
        self.grid_points += other.grid_points;
        self.samples += other.samples;
        self.infeasible += other.infeasible;
        self.infeasible_in_s += other.infeasible_in_s;
        self.unsafe_samples += other.unsafe_samples;
        self.active_samples += other.active_samples;
    }
}

/// The slope targets a dataset carries.
#[derive(Clone, Debug, PartialEq)]
pub enum Slopes {
    /// The Jacobian `Dv(x)` at each point ([`SafetyFilter::jacobian`]): what the slope error
    /// is measured against.
    Pointwise,
    /// Secant slopes over `±h` per axis ([`SafetyFilter::secant_jacobian`]): training targets
    /// that a network can meet across a kink of `v` between grid points. A point whose secant
    /// reaches where the filter is infeasible is skipped with it.
    Secant(Vec<f64>),
}

/// `v` and its slopes at every point where the filter is feasible, in parallel; `progress` is
/// told the number of points done (in chunks).
pub fn filter_dataset(
    filter: &SafetyFilter,
    points: &[Vec<f64>],
    slopes: &Slopes,
    progress: &(dyn Fn(usize) + Sync),
) -> (Dataset, DatasetSummary) {
    let scenario = filter.scenario();
    let (n, m) = (scenario.n(), scenario.m());
    let done = std::sync::atomic::AtomicUsize::new(0);
    // `Err(true)`: the QP has no solution at the point; `Err(false)`: only its slope failed
    // (a difference quotient's end beyond a boundary of feasibility).
    type Sample = (Vec<f64>, Vec<f64>);
    let results: Vec<Result<Sample, bool>> = points
        .par_chunks(1024)
        .flat_map_iter(|chunk| {
            let out: Vec<_> = chunk
                .iter()
                .map(|x| {
                    let v = filter.eval(x).map_err(|_| true)?;
                    let dv = match slopes {
                        Slopes::Pointwise => filter.jacobian(x),
                        Slopes::Secant(h) => filter.secant_jacobian(x, h),
                    };
                    Ok((v, dv.map_err(|_| false)?))
                })
                .collect();
            let total = done.fetch_add(chunk.len(), std::sync::atomic::Ordering::Relaxed);
            progress(total + chunk.len());
            out
        })
        .collect();

    let mut data = Dataset {
        n_in: n,
        n_out: m,
        inputs: Vec::new(),
        targets: Vec::new(),
        jacobians: Some(Vec::new()),
        weights: None,
    };
    let mut summary = DatasetSummary {
        grid_points: points.len(),
        ..DatasetSummary::default()
    };
    for (x, r) in points.iter().zip(results) {
        let (v, dv) = match r {
            Ok(sample) => sample,
            Err(at_x) => {
                summary.infeasible += 1;
                summary.infeasible_in_s += usize::from(at_x && scenario.is_safe(x));
                continue;
            }
        };
        summary.samples += 1;
        summary.unsafe_samples += usize::from(!scenario.is_safe(x));
        summary.active_samples += usize::from(v.iter().any(|vi| *vi != 0.0));
        data.inputs.extend(x);
        data.targets.extend(&v);
        if let Some(j) = data.jacobians.as_mut() {
            j.extend(&dv);
        }
    }
    (data, summary)
}

/// The filter as the trainer's [`Oracle`]: fresh points are drawn from the training region
/// and judged on `C ∩ S` (where the validation points lie).
pub struct FilterOracle<'a> {
    filter: SafetyFilter<'a>,
}

impl<'a> FilterOracle<'a> {
    /// The oracle of `scenario`'s filter.
    pub fn new(scenario: &'a Scenario) -> FilterOracle<'a> {
        FilterOracle {
            filter: SafetyFilter::new(scenario),
        }
    }
}

impl Oracle for FilterOracle<'_> {
    fn bounds(&self) -> (Vec<f64>, Vec<f64>) {
        let r = &self.filter.scenario().training.region;
        (r.lower.clone(), r.upper.clone())
    }

    fn judged(&self, x: &[f64]) -> bool {
        let s = self.filter.scenario();
        s.is_safe(x) && s.reach.region.contains(x)
    }

    fn sample(&self, points: &[Vec<f64>], slopes: SampleSlopes) -> Dataset {
        let slopes = match slopes {
            SampleSlopes::Pointwise => Slopes::Pointwise,
            SampleSlopes::Secant(h) => Slopes::Secant(h.to_vec()),
            SampleSlopes::Values => {
                // One solve a point: the rounds score many more points than they keep.
                let values: Vec<Option<Vec<f64>>> = points
                    .par_iter()
                    .map(|x| self.filter.eval(x).ok())
                    .collect();
                let mut data = Dataset {
                    n_in: self.filter.scenario().n(),
                    n_out: self.filter.scenario().m(),
                    ..Dataset::default()
                };
                for (x, v) in points.iter().zip(values) {
                    if let Some(v) = v {
                        data.inputs.extend(x);
                        data.targets.extend(v);
                    }
                }
                return data;
            }
        };
        filter_dataset(&self.filter, points, &slopes, &|_| {}).0
    }
}

/// Points of the grid `factor` times finer per axis than the `counts` grid over `region`
/// (`grid_points(region, counts)`) that lie within one coarse spacing of a seed, the coarse
/// grid's own points left out, each point once, in lattice order.
///
/// Where `v` bends sharply between coarse grid points (scenario 1's kink of slope ~20 near
/// (4.1, 0.8), where even the grid's bilinear interpolant errs by 0.14) the coarse samples
/// do not show the network the shape; these points do.
pub fn refinement_points<'a>(
    region: &IntervalBox,
    counts: &[usize],
    seeds: impl IntoIterator<Item = &'a [f64]>,
    factor: usize,
) -> Vec<Vec<f64>> {
    let n = region.dim();
    let factor = factor.max(1);
    let fine: Vec<usize> = counts
        .iter()
        .map(|&k| (k.max(2) - 1) * factor + 1)
        .collect();
    let spacing = |i: usize| (region.upper[i] - region.lower[i]) / (fine[i] - 1) as f64;
    let reach = factor as i64;
    let mut lattice = std::collections::BTreeSet::new();
    for x in seeds {
        // The fine lattice index nearest the seed, then every offset within one coarse spacing.
        let centre: Vec<i64> = (0..n)
            .map(|i| ((x[i] - region.lower[i]) / spacing(i)).round() as i64)
            .collect();
        let side = (2 * reach + 1) as usize;
        for k in 0..side.pow(n as u32) {
            let mut rest = k;
            let index: Option<Vec<usize>> = (0..n)
                .map(|i| {
                    let j = centre[i] + (rest % side) as i64 - reach;
                    rest /= side;
                    (0..fine[i] as i64).contains(&j).then_some(j as usize)
                })
                .collect();
            if let Some(index) = index {
                if index.iter().any(|j| j % factor != 0) {
                    // Reversed so that the set's order is axis 0 fastest, as in `grid_points`.
                    lattice.insert(index.into_iter().rev().collect::<Vec<usize>>());
                }
            }
        }
    }
    lattice
        .into_iter()
        .map(|rev| {
            (0..n)
                .map(|i| lattice_coordinate(region, i, rev[n - 1 - i], fine[i]))
                .collect()
        })
        .collect()
}

/// The spacing per axis of a training grid of `grid` points per axis (each at least 2, as
/// [`training_points`] checks) on `s`'s training region.
pub fn grid_spacing(s: &Scenario, grid: &[usize]) -> Vec<f64> {
    let r = &s.training.region;
    (0..s.n())
        .map(|i| (r.upper[i] - r.lower[i]) / (grid[i] - 1) as f64)
        .collect()
}

/// A validation grid the training never saw: the training grid shifted by half a spacing,
/// restricted to the safe set, where the filter acts (`C ∩ S`).
pub fn validation_points(s: &Scenario, grid: &[usize]) -> Vec<Vec<f64>> {
    let r = &s.training.region;
    let half: Vec<f64> = grid_spacing(s, grid).iter().map(|h| 0.5 * h).collect();
    let inner = IntervalBox {
        lower: (0..s.n()).map(|i| r.lower[i] + half[i]).collect(),
        upper: (0..s.n()).map(|i| r.upper[i] - half[i]).collect(),
    };
    let counts: Vec<usize> = grid.iter().map(|k| k - 1).collect();
    grid_points(&inner, &counts)
        .into_iter()
        .filter(|x| s.is_safe(x) && s.reach.region.contains(x))
        .collect()
}

/// Gives weight 0 to the unsafe samples with no safe point at distance `band[i]` or
/// `band[i]/2` along some axis `i`; returns how many.
pub fn restrict_to_band(s: &Scenario, data: &mut Dataset, band: &[f64]) -> usize {
    let n = s.n();
    let len = data.len();
    let weights = data.weights.get_or_insert_with(|| vec![1.0; len]);
    let mut excluded = 0;
    for (k, w) in weights.iter_mut().enumerate() {
        let x = &data.inputs[k * n..(k + 1) * n];
        if s.is_safe(x) {
            continue;
        }
        let near = (0..n).any(|i| {
            let b = band[i];
            [b, -b, 0.5 * b, -0.5 * b].iter().any(|&d| {
                let mut y = x.to_vec();
                y[i] += d;
                s.is_safe(&y)
            })
        });
        if !near {
            *w = 0.0;
            excluded += 1;
        }
    }
    excluded
}

/// Multiplies the weights of the samples in `focus` by `weight`; returns how many.
pub fn weigh_box(data: &mut Dataset, focus: &IntervalBox, weight: f64) -> usize {
    let (n, len) = (data.n_in, data.len());
    let weights = data.weights.get_or_insert_with(|| vec![1.0; len]);
    let mut count = 0;
    for (k, w) in weights.iter_mut().enumerate() {
        if focus.contains(&data.inputs[k * n..(k + 1) * n]) {
            *w *= weight;
            count += 1;
        }
    }
    count
}

/// Most grid points a training grid may have (each sample holds `n + m + mn` numbers, twice
/// with secant slopes).
pub const MAX_GRID_POINTS: usize = 20_000_000;

/// Most numbers its samples may hold, `points × (n + m + mn)`: [`MAX_GRID_POINTS`] of a system
/// with two states and two inputs. Six states and three inputs hold 27 numbers a point, so
/// their grids stop at 5.9 million points.
pub const MAX_GRID_NUMBERS: usize = 8 * MAX_GRID_POINTS;

/// The training grid's points over `[training] region` (`grid`, else the scenario's), refused
/// with a message naming the grid where it has the wrong length, a count below 2, or more
/// points than the trainer holds in memory.
pub fn training_points(s: &Scenario, grid: Option<&Vec<usize>>) -> Result<Vec<Vec<f64>>, String> {
    let grid = grid.unwrap_or(&s.training.grid);
    if grid.len() != s.n() || grid.iter().any(|&k| k < 2) {
        return Err(format!(
            "training grid {grid:?} (--grid): expected {} counts, each at least 2",
            s.n()
        ));
    }
    // The points, their targets and slopes are held in memory: refuse a grid that would not
    // fit rather than abort on the allocation.
    let (n, m) = (s.n(), s.m());
    let per_point = n + m + m * n;
    let most = MAX_GRID_POINTS.min(MAX_GRID_NUMBERS / per_point);
    let total = grid
        .iter()
        .try_fold(1usize, |a, &k| a.checked_mul(k))
        .filter(|&t| t <= most);
    if total.is_none() {
        return Err(format!(
            "training grid {grid:?}: {} points, more than the {most} the trainer holds in memory \
             with {n} states and {m} inputs ({per_point} numbers a point); use a coarser grid \
             (the refine stages add samples where v needs them)",
            grid.iter().map(|&k| k as f64).product::<f64>()
        ));
    }
    Ok(grid_points(&s.training.region, grid))
}

/// The inputs of the samples in `S` whose steepest target slope `max |∂vᵢ/∂xⱼ|` exceeds
/// `slope` but not `cap` (inside an obstacle `v` steepens without bound, and `M_C` is not
/// measured there; slopes above `--jacobian-cap` mark jumps of `v`, where no continuous
/// network can be close and finer samples only add error that cannot be trained away).
pub fn steep_samples<'a>(
    s: &Scenario,
    data: &'a Dataset,
    slope: f64,
    cap: Option<f64>,
) -> Vec<&'a [f64]> {
    let Some(jacobians) = &data.jacobians else {
        return Vec::new();
    };
    let mn = data.n_in * data.n_out;
    let cap = cap.unwrap_or(f64::INFINITY);
    (0..data.len())
        .filter(|&k| {
            let steepest = jacobians[k * mn..(k + 1) * mn]
                .iter()
                .fold(0.0f64, |a, d| a.max(d.abs()));
            steepest > slope && steepest <= cap
        })
        .map(|k| &data.inputs[k * data.n_in..(k + 1) * data.n_in])
        .filter(|x| s.is_safe(x))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn region() -> IntervalBox {
        IntervalBox {
            lower: vec![-1.0, 0.0],
            upper: vec![1.0, 3.0],
        }
    }

    #[test]
    fn refinement_points_fill_one_coarse_spacing_around_each_seed() {
        let (r, counts, factor) = (region(), [5, 4], 3);
        let coarse = grid_points(&r, &counts);
        let h = [0.5, 1.0];
        let near = |x: &[f64], y: &[f64]| (0..2).all(|i| (x[i] - y[i]).abs() <= h[i] + 1e-12);
        let on_lattice = |x: &[f64]| {
            (0..2).all(|i| {
                let t = (x[i] - r.lower[i]) / (h[i] / factor as f64);
                (t - t.round()).abs() < 1e-9
            })
        };
        // An interior seed: a 7 × 7 block of the fine lattice less its 3 × 3 coarse points.
        let seed = coarse[counts[0] + 2].clone();
        let block = refinement_points(&r, &counts, [seed.as_slice()], factor);
        assert_eq!(block.len(), 49 - 9);
        // A corner seed: 4 × 4 less 2 × 2; a seed off the lattice snaps to its nearest point.
        let corner = refinement_points(&r, &counts, [coarse[0].as_slice()], factor);
        assert_eq!(corner.len(), 16 - 4);
        let off = [seed[0] + 0.04, seed[1] - 0.1];
        assert_eq!(refinement_points(&r, &counts, [&off[..]], factor), block);
        // Two neighbouring seeds share points: each appears once.
        let seeds = [coarse[counts[0] + 2].clone(), coarse[counts[0] + 3].clone()];
        let both = refinement_points(&r, &counts, seeds.iter().map(Vec::as_slice), factor);
        assert_eq!(both.len(), 7 * 10 - 3 * 4);
        for (k, x) in both.iter().enumerate() {
            assert!(
                on_lattice(x) && r.contains(x),
                "{x:?} off the fine lattice or region"
            );
            assert!(!coarse
                .iter()
                .any(|c| near(c, x) && c.iter().zip(x).all(|(a, b)| (a - b).abs() < 1e-12)));
            assert!(
                seeds.iter().any(|s| near(s, x)),
                "{x:?} farther than a spacing"
            );
            assert!(both[..k].iter().all(|y| y != x), "{x:?} twice");
        }
    }
}

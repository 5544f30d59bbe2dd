//! Training data for the surrogate `N ≈ v`: the filter evaluated on an equispaced grid.
//!
//! The grid covers the scenario's training region (default `C`), the unsafe set included
//! wherever the QP is feasible: boxes at equilibria on the obstacle boundary straddle it, and
//! their bounds see the network there (DESIGN §2b). Points where the QP is infeasible are
//! skipped and counted. Each sample carries `Dv(x)` for the Sobolev term of the trainer.

use rayon::prelude::*;
use serde::Serialize;

use crate::boxes::IntervalBox;
use crate::filter::SafetyFilter;
use crate::network::train::Dataset;

/// What building a data set found.
#[derive(Clone, Debug, Default, Serialize)]
pub struct DatasetSummary {
    /// Grid points in all.
    pub grid_points: usize,
    /// Samples kept (feasible points).
    pub samples: usize,
    /// Points where the filter's QP is infeasible (skipped).
    pub infeasible: usize,
    /// Kept samples outside the safe set `S`.
    pub unsafe_samples: usize,
    /// Kept samples where the filter acts (`v ≠ 0`).
    pub active_samples: usize,
}

/// The points of an equispaced grid with `counts[i]` points along axis i, both ends included,
/// axis 0 fastest.
pub fn grid_points(region: &IntervalBox, counts: &[usize]) -> Vec<Vec<f64>> {
    let n = region.dim();
    let total: usize = counts.iter().product();
    (0..total)
        .map(|mut k| {
            (0..n)
                .map(|i| {
                    let j = k % counts[i];
                    k /= counts[i];
                    let steps = (counts[i].max(2) - 1) as f64;
                    let s = j as f64 / steps;
                    // Exact ends; interior points by interpolation.
                    if j + 1 == counts[i] {
                        region.upper[i]
                    } else {
                        region.lower[i] + s * (region.upper[i] - region.lower[i])
                    }
                })
                .collect()
        })
        .collect()
}

/// `v` and `Dv` at every point where the filter is feasible, in parallel; `progress` is told
/// the number of points done (in chunks).
pub fn filter_dataset(
    filter: &SafetyFilter,
    points: &[Vec<f64>],
    with_jacobians: bool,
    progress: &(dyn Fn(usize) + Sync),
) -> (Dataset, DatasetSummary) {
    let scenario = filter.scenario();
    let (n, m) = (scenario.n(), scenario.m());
    let done = std::sync::atomic::AtomicUsize::new(0);
    let results: Vec<Option<(Vec<f64>, Vec<f64>)>> = points
        .par_chunks(1024)
        .flat_map_iter(|chunk| {
            let out: Vec<_> = chunk
                .iter()
                .map(|x| {
                    let v = filter.eval(x).ok()?;
                    let dv = if with_jacobians {
                        filter.jacobian(x).ok()?
                    } else {
                        Vec::new()
                    };
                    Some((v, dv))
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
        jacobians: with_jacobians.then(Vec::new),
        weights: None,
    };
    let mut summary = DatasetSummary {
        grid_points: points.len(),
        ..DatasetSummary::default()
    };
    for (x, r) in points.iter().zip(results) {
        let Some((v, dv)) = r else {
            summary.infeasible += 1;
            continue;
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

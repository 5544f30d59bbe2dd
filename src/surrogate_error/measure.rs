//! Measurement: the error `N − v` and its slope error sampled on a grid over `C ∩ S` (and on
//! `C`'s boundary). It may import the filter, the network, the dataset and the analysis' settings.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::{check_box_width, check_dims, AnalysisError, ErrorSettings};
use crate::boxes::IntervalBox;
use crate::dataset::{filter_dataset, grid_points, Slopes};
use crate::filter::SafetyFilter;
use crate::network::train::pointwise_errors;
use crate::network::Mlp;
use crate::scenario::Scenario;

/// Median, 95th percentile and max of a sample.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Percentiles {
    /// Median.
    pub median: f64,
    /// 95th percentile (nearest rank).
    pub p95: f64,
    /// Maximum.
    pub max: f64,
}

impl Percentiles {
    /// Of `values` (NaN sorts last); zeros for an empty sample.
    pub fn of(values: &[f64]) -> Percentiles {
        if values.is_empty() {
            return Percentiles::default();
        }
        let mut v = values.to_vec();
        v.sort_by(f64::total_cmp);
        let at = |q: f64| v[((q * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1];
        Percentiles {
            median: at(0.5),
            p95: at(0.95),
            max: v[v.len() - 1],
        }
    }
}

/// The measured error of `N` on a grid over `C ∩ S`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    /// `max ‖N(x) − v(x)‖∞` over the grid points of `C ∩ S`.
    pub linf: f64,
    /// `max ‖N(x) − v(x)‖₂` over the same points.
    pub l2: f64,
    /// Where `linf` is attained.
    pub argmax: Vec<f64>,
    /// Where `l2` is attained.
    pub argmax_l2: Vec<f64>,
    /// Mean `‖N(x) − v(x)‖∞`.
    pub mean: f64,
    /// Points of the full grid over `C`.
    pub grid_points: usize,
    /// The grid's points per axis ([`measurement_counts`]).
    #[serde(default)]
    pub counts: Vec<usize>,
    /// Points on the boundary of `C` besides the grid ([`measurement_points`]).
    pub boundary_points: usize,
    /// Points of `C ∩ S` where the filter is feasible (the ones measured).
    pub samples: usize,
    /// Points of `C ∩ S` where the filter is infeasible (skipped).
    pub infeasible: usize,
    /// `max_ij |DN − Dv|_ij` over the samples (largest absolute entry, not spectral).
    pub slope: Percentiles,
    /// The slope error over boxes [`Self::box_width`] wide: `max_ij` of the secant error
    /// `|((N − v)(x + δeⱼ) − (N − v)(x − δeⱼ)) / 2δ|ᵢ`, `2δ` = the width, at the samples whose
    /// secants stay where the filter is feasible. A ReLU network's slope is piecewise constant
    /// on pieces far narrower than the boxes the reach engine bounds, and a bound over a box sees
    /// their average, so this, not the pointwise [`Self::slope`], is what a tube's contraction
    /// feels (docs/design.md §2b).
    #[serde(default)]
    pub box_slope: Percentiles,
    /// The width `2δ` of [`Self::box_slope`]'s boxes ([`ErrorSettings::looseness_width`]).
    #[serde(default)]
    pub box_width: f64,
    /// Neurons of each hidden layer active at one or more of the samples: the rest are dead
    /// on `C ∩ S` and add no linear regions there.
    #[serde(default)]
    pub live_neurons: Vec<usize>,
    /// The pointwise slope error against the filter's curvature.
    #[serde(default)]
    pub slope_by_curvature: SlopeByCurvature,
}

/// The pointwise slope error against the curvature `‖D²v‖_F` of the filter
/// ([`SafetyFilter::curvature`]). A ReLU network is linear on each of its pieces, so where `v`
/// bends its slope can only follow in steps: a piece `w` wide that fits a curve of curvature
/// `κ` errs in slope by up to `κw/2`. A slope error that grows with the curvature is that
/// limit rather than noise, and only finer pieces where `v` bends lower it.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SlopeByCurvature {
    /// Points whose curvature was measured: evenly spaced through the samples, at most
    /// [`CURVATURE_POINTS`], and only where the filter is feasible at every difference's end.
    pub points: usize,
    /// The points by curvature, one band for each of [`CURVATURE_BANDS`].
    pub bands: Vec<CurvatureBand>,
}

/// The slope error of the points in one band of the filter's curvature.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct CurvatureBand {
    /// Share of [`SlopeByCurvature::points`] in the band.
    pub share: f64,
    /// The band's smallest and largest curvature `‖D²v‖_F`.
    pub curvature: [f64; 2],
    /// The pointwise slope error `max_ij |DN − Dv|_ij` of its points.
    pub slope: Percentiles,
}

/// At most this many samples get their curvature measured (`4n²` filter evaluations each).
pub const CURVATURE_POINTS: usize = 100_000;

/// The bands of [`SlopeByCurvature`]: the share of the points, in order of curvature, from and
/// to which each runs, and its name in reports.
pub const CURVATURE_BANDS: [(f64, f64, &str); 3] = [
    (0.0, 0.5, "flattest half"),
    (0.5, 0.9, "next 40 %"),
    (0.9, 1.0, "steepest tenth"),
];

/// [`SlopeByCurvature`] of the samples `inputs` (flat, `n` per point) with pointwise slope
/// errors `slope`.
pub fn slope_by_curvature(
    filter: &SafetyFilter,
    inputs: &[f64],
    slope: &[f64],
    n: usize,
) -> SlopeByCurvature {
    let stride = slope.len().div_ceil(CURVATURE_POINTS).max(1);
    let mut pairs: Vec<(f64, f64)> = (0..slope.len())
        .into_par_iter()
        .step_by(stride)
        .filter_map(|k| {
            let kappa = filter.curvature(&inputs[k * n..(k + 1) * n]).ok()?;
            kappa.is_finite().then_some((kappa, slope[k]))
        })
        .collect();
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let count = pairs.len();
    let bands = CURVATURE_BANDS
        .into_iter()
        .filter_map(|(from, to, _)| {
            let band = &pairs[(from * count as f64) as usize..(to * count as f64) as usize];
            let slopes: Vec<f64> = band.iter().map(|p| p.1).collect();
            Some(CurvatureBand {
                share: band.len() as f64 / count as f64,
                curvature: [band.first()?.0, band.last()?.0],
                slope: Percentiles::of(&slopes),
            })
        })
        .collect();
    SlopeByCurvature {
        points: count,
        bands,
    }
}

/// At most this many points (the grid and its projections onto `C`'s faces,
/// [`measurement_size`]) when the measurement grid's counts come from the training grid:
/// [`ErrorSettings::refine`] is lowered evenly on every axis until they fit. Twice the
/// training grid per axis is `2ⁿ` times its points, 64 times in six states, where one
/// measurement grew past 19 GB before this cap. Every shipped scenario measures fewer (≤ 400,000).
pub const MAX_MEASUREMENT_POINTS: usize = 1 << 20;

/// An explicit [`ErrorSettings::grid`] larger than this is refused (about 1.5 GB of samples).
pub const MAX_EXPLICIT_MEASUREMENT_POINTS: usize = 4 << 20;

/// Points per axis of the measurement grid as asked: [`ErrorSettings::grid`], or
/// [`ErrorSettings::refine`] times the training grid's ([`measurement_counts`] caps the
/// latter).
pub fn asked_counts(s: &Scenario, settings: &ErrorSettings) -> Vec<usize> {
    match settings.grid.as_ref().filter(|g| g.len() == s.n()) {
        Some(g) => g.iter().map(|&k| k.max(1)).collect(),
        None => s
            .training
            .grid
            .iter()
            .map(|&k| k.max(2) * settings.refine.max(1))
            .collect(),
    }
}

/// Points per axis of the measurement grid: [`asked_counts`], the training grid's refined at
/// most to [`MAX_MEASUREMENT_POINTS`] in all.
pub fn measurement_counts(s: &Scenario, settings: &ErrorSettings) -> Vec<usize> {
    let asked = asked_counts(s, settings);
    let wanted = measurement_size(&asked);
    if settings.grid.as_ref().is_some_and(|g| g.len() == s.n())
        || wanted <= MAX_MEASUREMENT_POINTS as f64
    {
        return asked;
    }
    let training: Vec<f64> = s.training.grid.iter().map(|&k| k.max(2) as f64).collect();
    let counts = |r: f64| -> Vec<usize> {
        training
            .iter()
            .map(|&k| ((k * r).floor() as usize).max(2))
            .collect()
    };
    let refine = settings.refine.max(1) as f64;
    // Evenly on every axis, then down by 1 % until the points fit (the faces' share moves).
    let n = training.len().max(1) as f64;
    let mut r = refine * (MAX_MEASUREMENT_POINTS as f64 / wanted).powf(1.0 / n);
    while r > 1e-3 && measurement_size(&counts(r)) > MAX_MEASUREMENT_POINTS as f64 {
        r *= 0.99;
    }
    counts(r)
}

/// How many points [`measurement_points`] gives for `counts`: the grid, its projections onto
/// the `2n` faces of `C` and the `2ⁿ` corners (as f64: it may not fit a `usize`).
pub fn measurement_size(counts: &[usize]) -> f64 {
    let grid: f64 = counts.iter().map(|&k| k as f64).product();
    let faces: f64 = counts.iter().map(|&k| 2.0 * grid / k.max(1) as f64).sum();
    let corners = if counts.len() > 1 {
        2f64.powi(counts.len() as i32)
    } else {
        0.0
    };
    grid + faces + corners
}

/// The cell-centred grid with `counts[i]` points along axis i: `lᵢ + (j + ½)(uᵢ − lᵢ)/countsᵢ`.
/// With `counts = 2k` over the training region it never lands on the training grid's interior
/// lines except by accident of rounding.
pub fn centred_grid(region: &IntervalBox, counts: &[usize]) -> Vec<Vec<f64>> {
    let h: Vec<f64> = (0..region.dim())
        .map(|i| (region.upper[i] - region.lower[i]) / counts[i].max(1) as f64)
        .collect();
    let inner = IntervalBox {
        lower: (0..region.dim())
            .map(|i| region.lower[i] + 0.5 * h[i])
            .collect(),
        upper: (0..region.dim())
            .map(|i| region.upper[i] - 0.5 * h[i])
            .collect(),
    };
    if counts.iter().any(|&k| k < 2) {
        // A single point per axis: the centre.
        let c = region.center();
        let counts2: Vec<usize> = counts.iter().map(|&k| k.max(1)).collect();
        if counts2.iter().all(|&k| k == 1) {
            return vec![c];
        }
    }
    grid_points(&inner, counts)
}

/// The points [`measure()`] evaluates, before leaving out the unsafe ones: the cell-centred grid
/// over `C` of [`measurement_counts`] (offset from the training grid), then that grid projected
/// onto each face of `C`, then `C`'s corners (in two or more dimensions). The centred grid
/// alone stays half a spacing inside `C`, and the error can peak on its boundary (scenario 1's
/// network errs by 0.30 at (4.5, 0.93), 0.25 at most on the centred grid). Returns the points
/// and how many of them are the grid's.
pub fn measurement_points(s: &Scenario, settings: &ErrorSettings) -> (Vec<Vec<f64>>, usize) {
    let c = &s.reach.region;
    let counts = measurement_counts(s, settings);
    let mut points = centred_grid(c, &counts);
    let grid = points.len();
    for i in 0..c.dim() {
        let mut across = counts.clone();
        across[i] = 1;
        for side in [c.lower[i], c.upper[i]] {
            points.extend(centred_grid(c, &across).into_iter().map(|mut x| {
                x[i] = side;
                x
            }));
        }
    }
    if c.dim() > 1 {
        // In one dimension the faces are the corners.
        points.extend(c.corners());
    }
    (points, grid)
}

/// Measures the error of `net` against the scenario's filter on a grid over `C ∩ S`
/// ([`ErrorSettings::refine`] times the training grid per axis, offset from it) and on the
/// boundary of `C` ([`measurement_points`]).
pub fn measure(
    s: &Scenario,
    net: &Mlp,
    settings: &ErrorSettings,
    progress: &(dyn Fn(usize) + Sync),
) -> Result<Measured, AnalysisError> {
    check_dims(s, net)?;
    check_box_width(settings)?;
    let counts = measurement_counts(s, settings);
    let size = measurement_size(&counts);
    if size > MAX_EXPLICIT_MEASUREMENT_POINTS as f64 {
        return Err(AnalysisError::Setting {
            name: "measurement grid points",
            value: size,
            expected: "at most 4,194,304 (a coarser grid)",
        });
    }
    let (all, grid_points) = measurement_points(s, settings);
    let boundary_points = all.len() - grid_points;
    let safe: Vec<Vec<f64>> = all.into_iter().filter(|x| s.is_safe(x)).collect();
    let filter = SafetyFilter::new(s);
    let (data, summary) = filter_dataset(&filter, &safe, &Slopes::Pointwise, progress);
    if data.is_empty() {
        return Err(AnalysisError::NoSamples);
    }
    let pe = pointwise_errors(net, &data)?;
    let n = s.n();
    let argmax_of = |v: &[f64]| {
        (0..v.len())
            .max_by(|&a, &b| v[a].total_cmp(&v[b]))
            .unwrap_or(0)
    };
    let (k, k2) = (argmax_of(&pe.value), argmax_of(&pe.value_l2));
    let half_width = 0.5 * settings.looseness_width;
    let box_slope = secant_slope_errors(&filter, net, &safe, half_width, progress);
    let slope = pe.slope.as_deref().unwrap_or(&[]);
    Ok(Measured {
        linf: pe.value[k],
        l2: pe.value_l2[k2],
        argmax: data.inputs[k * n..(k + 1) * n].to_vec(),
        argmax_l2: data.inputs[k2 * n..(k2 + 1) * n].to_vec(),
        mean: pe.value.iter().sum::<f64>() / pe.value.len() as f64,
        grid_points,
        counts,
        boundary_points,
        samples: summary.samples,
        infeasible: summary.infeasible,
        slope: Percentiles::of(slope),
        box_slope: Percentiles::of(&box_slope),
        box_width: 2.0 * half_width,
        live_neurons: net.live_neurons(&data.inputs),
        slope_by_curvature: slope_by_curvature(&filter, &data.inputs, slope, n),
    })
}

/// The secant slope error of `net` against the filter over `±δ` per axis,
/// `max_ij |((N − v)(x + δeⱼ) − (N − v)(x − δeⱼ)) / 2δ|ᵢ`, at each of `points` where the filter
/// is feasible at the `2n` ends (the others are skipped).
pub fn secant_slope_errors(
    filter: &SafetyFilter,
    net: &Mlp,
    points: &[Vec<f64>],
    delta: f64,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<f64> {
    // In chunks: a sample's secant ends are 2n² numbers (72 in six states), which for all of
    // a million points at once would be half a gigabyte.
    const CHUNK: usize = 1 << 15;
    let mut errors = Vec::with_capacity(points.len());
    for (c, chunk) in points.chunks(CHUNK).enumerate() {
        let done = c * CHUNK;
        let each = secant_chunk(filter, net, chunk, delta, &|d| progress(done + d));
        errors.extend(each);
    }
    errors
}

fn secant_chunk(
    filter: &SafetyFilter,
    net: &Mlp,
    points: &[Vec<f64>],
    delta: f64,
    progress: &(dyn Fn(usize) + Sync),
) -> Vec<f64> {
    let (data, _) = filter_dataset(filter, points, &Slopes::Secant(vec![delta]), progress);
    let Some(secants) = data.jacobians.as_ref() else {
        return Vec::new();
    };
    let (n, m) = (data.n_in, data.n_out);
    // The 2n ends of each sample's secants, `xⱼ ± δ` as the filter's secants compute them,
    // written straight into one buffer for the batched forward pass.
    let mut ends = Vec::with_capacity(data.len() * 2 * n * n);
    for x in data.inputs.chunks_exact(n) {
        for j in 0..n {
            for end in [x[j] + delta, x[j] - delta] {
                ends.extend_from_slice(x);
                let at = ends.len() - n + j;
                ends[at] = end;
            }
        }
    }
    let outputs = net.forward_many(&ends);
    outputs
        .chunks_exact(2 * n * m)
        .zip(secants.chunks_exact(m * n))
        .map(|(at_ends, dv)| {
            let mut worst = 0.0_f64;
            for j in 0..n {
                let (plus, minus) = (&at_ends[2 * j * m..], &at_ends[(2 * j + 1) * m..]);
                for i in 0..m {
                    let dn = (plus[i] - minus[i]) / (2.0 * delta);
                    worst = worst.max((dn - dv[i * n + j]).abs());
                }
            }
            worst
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_nearest_rank() {
        let v: Vec<f64> = (1..=100).map(f64::from).collect();
        let p = Percentiles::of(&v);
        assert_eq!((p.median, p.p95, p.max), (50.0, 95.0, 100.0));
        assert_eq!(Percentiles::of(&[]), Percentiles::default());
    }

    #[test]
    fn centred_grid_avoids_the_ends() {
        let b = IntervalBox::new(vec![0.0], vec![1.0]).unwrap();
        let g = centred_grid(&b, &[4]);
        assert_eq!(g, vec![vec![0.125], vec![0.375], vec![0.625], vec![0.875]]);
    }
}

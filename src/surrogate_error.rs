//! How far the surrogate network `N` is from the filter `v` (DESIGN §2.1, §2b; issue 6).
//!
//! * [`measure`]: `M_C` *measured* on a grid finer than the training grid and offset from it,
//!   over `C ∩ S` — max ℓ∞ and ℓ2 error and where they occur — and the slope error
//!   `max_ij |DN − Dv|_ij` (the largest absolute entry of the Jacobian difference, `Dv` by
//!   central differences) as median, 95th percentile and max.
//! * [`looseness`]: over small boxes across `C ∩ S`, the ratio of the bound width (IBP and
//!   CROWN) to the output range of `N` seen on samples of the box.
//! * [`certify`]: a **certified** `M_C ≥ sup_{x ∈ C ∩ S} ‖N(x) − v(x)‖∞` for the closed-form
//!   filters (one constraint row, or a scalar input). `C` is cut into cells; cells on which some
//!   `hᵢ < 0` (interval evaluation) are dropped; on every other cell `N` is bounded by IBP (and
//!   forward-backward or CROWN affine bounds when IBP is not tight enough) and `v` by mean-value
//!   forms of the closed form on 8 × 8 pieces of the cell ([`cell_error_bound_mv`]); cells are
//!   bisected until each bound is within a factor of the error sampled on the cell and of the
//!   measured global error (the cells above the latter first), or a budget of cell evaluations
//!   is spent. The bound holds on
//!   `cell ∩ S` for each kept cell (at the points where the filter is feasible), floating-point
//!   error included. Where `v` is unbounded or discontinuous inside `S` (scenario 2 at the
//!   obstacle's ends `(1, 0)`, `(3, 0)`, where `L_g h = 0`) cells stay infinite: the
//!   certified bound is then `+∞` (`null` in JSON), honestly.
//! * [`ErrorMap`]: the certified per-cell bounds, stored beside the network
//!   (`<network stem>.errormap.json`, [`error_map_path`]), so that reachability can use a local
//!   bound over the cells that a box meets ([`ErrorMap::local_bound`]) instead of the global
//!   `M_C`; [`resolve_margin`] turns a scenario's `m_c = "certified"` / `"measured"` into a number.

use std::cmp::Ordering;
use std::collections::BinaryHeap;
use std::path::{Path, PathBuf};

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use crate::bounds::{network_bounds, AffineBounds, BoundMethod, BoundsError, PreparedNetwork};
use crate::boxes::IntervalBox;
use crate::dataset::{filter_dataset, grid_points, Slopes};
use crate::expressions::Expr;
use crate::filter::{FilterMethod, SafetyFilter};
use crate::intervals::Interval;
use crate::network::train::pointwise_errors;
use crate::network::Mlp;
use crate::network::NetworkError;
use crate::rounding::round_up;
use crate::scenario::{Margin, Scenario};

/// Why an error analysis (or an error map) failed.
#[derive(Debug, thiserror::Error)]
pub enum AnalysisError {
    /// The network does not fit the scenario, or evaluating it failed.
    #[error(transparent)]
    Network(#[from] NetworkError),
    /// Bounding the network failed.
    #[error(transparent)]
    Bounds(#[from] BoundsError),
    /// The network's input/output dimensions differ from the scenario's `n`/`m`.
    #[error("the network maps {net_in} → {net_out} but the scenario has n = {n}, m = {m}")]
    Dimensions {
        /// Network input dimension.
        net_in: usize,
        /// Network output dimension.
        net_out: usize,
        /// Scenario state dimension.
        n: usize,
        /// Scenario input dimension.
        m: usize,
    },
    /// A setting is out of its range.
    #[error("{name} = {value}: expected {expected}")]
    Setting {
        /// The setting (as the command line names it).
        name: &'static str,
        /// Its value.
        value: f64,
        /// What it must be.
        expected: &'static str,
    },
    /// No grid point of `C ∩ S` where the filter is feasible.
    #[error("no grid point of C ∩ S where the filter is feasible: nothing to measure")]
    NoSamples,
    /// Reading or writing a file failed.
    #[error("{path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// An error map file is not valid.
    #[error("{path}: not a valid error map: {message}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        message: String,
    },
    /// The error map was computed for another network (its file changed since).
    #[error("{path} was computed for another version of {network} (run `cbfreach error` again)")]
    StaleMap {
        /// The error map.
        path: PathBuf,
        /// The network file.
        network: PathBuf,
    },
    /// The map has no certified bound (the filter is a general QP).
    #[error("{path} holds no certified bound (the scenario's filter has no closed form); use a number or \"measured\"")]
    NotCertified {
        /// The error map.
        path: PathBuf,
    },
    /// A box that the map does not cover.
    #[error("box {lower:?}..{upper:?} is not inside the mapped region {region_lower:?}..{region_upper:?}")]
    OutsideMap {
        /// The box's lower corner.
        lower: Vec<f64>,
        /// The box's upper corner.
        upper: Vec<f64>,
        /// The region's lower corner.
        region_lower: Vec<f64>,
        /// The region's upper corner.
        region_upper: Vec<f64>,
    },
}

/// Settings of the analysis; every field has a default.
#[derive(Clone, Debug)]
pub struct ErrorSettings {
    /// Measurement grid: this many times the training grid's points per axis (default 2, i.e.
    /// 4× the points in the plane), cell-centred on `C` so that it is offset from the training
    /// grid.
    pub refine: usize,
    /// Points per axis of the measurement grid (overrides `refine` when set).
    pub grid: Option<Vec<usize>>,
    /// Cell evaluations allowed to the certification (default 20,000).
    pub budget: usize,
    /// Stop refining when the certified bound is within this fraction of the measured one
    /// (default 0.1).
    pub tolerance: f64,
    /// Width of the initial cells of the certification (default 0.125).
    pub initial_cell: f64,
    /// Width of the looseness boxes (default 0.1).
    pub looseness_width: f64,
    /// At most this many looseness boxes, spread over `C` (default 300).
    pub looseness_boxes: usize,
    /// Random samples per looseness box, besides its corners (default 16).
    pub looseness_samples: usize,
    /// Seed of the looseness samples (default 0).
    pub seed: u64,
    /// Refine a cell while its bound exceeds this many times its sampled error (default 1.5).
    pub local_ratio: f64,
    /// ... or this absolute floor, whichever is larger (default 0.01).
    pub floor: f64,
    /// Random sample points per cell besides its corners and centre (default 4).
    pub cell_samples: usize,
    /// At most this many kept cells in the map (default 24,000: about 2 MB of JSON).
    pub max_cells: usize,
    /// Priority factor of cells that meet the scenario's goal set (default 4).
    pub goal_weight: f64,
    /// Cells narrower than this are not bisected further (default `initial_cell / 32`): where
    /// `v` jumps or the QP is infeasible along a curve (scenario 2 on `x₂ = −2` near
    /// `x₁ ≈ 4`), the bound stays large however fine the cells, and refining there would
    /// spend the whole budget.
    pub min_cell: f64,
    /// Affine bounds of `N` on a cell when IBP is not tight enough (default forward-backward:
    /// within about 1 % of backward CROWN on small cells at a twentieth of its cost).
    pub cell_bounds: BoundMethod,
}

impl Default for ErrorSettings {
    fn default() -> Self {
        ErrorSettings {
            refine: 2,
            grid: None,
            budget: 20_000,
            tolerance: 0.1,
            initial_cell: 0.125,
            looseness_width: 0.1,
            looseness_boxes: 300,
            looseness_samples: 16,
            seed: 0,
            local_ratio: 1.5,
            floor: 0.01,
            cell_samples: 4,
            max_cells: 24_000,
            goal_weight: 4.0,
            cell_bounds: BoundMethod::ForwardBackward,
            min_cell: 0.125 / 32.0,
        }
    }
}

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
    /// feels (DESIGN §2b).
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

fn check_dims(s: &Scenario, net: &Mlp) -> Result<(), AnalysisError> {
    if net.input_dim() != s.n() || net.output_dim() != s.m() {
        return Err(AnalysisError::Dimensions {
            net_in: net.input_dim(),
            net_out: net.output_dim(),
            n: s.n(),
            m: s.m(),
        });
    }
    Ok(())
}

/// Points per axis of the measurement grid.
pub fn measurement_counts(s: &Scenario, settings: &ErrorSettings) -> Vec<usize> {
    match &settings.grid {
        Some(g) if g.len() == s.n() => g.iter().map(|&k| k.max(1)).collect(),
        _ => s
            .training
            .grid
            .iter()
            .map(|&k| k.max(2) * settings.refine.max(1))
            .collect(),
    }
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

/// The points [`measure`] evaluates, before leaving out the unsafe ones: the cell-centred grid
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

/// Median and max of a bound-width-to-sampled-range ratio.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Ratio {
    /// Min over the boxes: below 1 only if a bound missed a sampled output.
    pub min: f64,
    /// Median over the boxes.
    pub median: f64,
    /// Max over the boxes.
    pub max: f64,
}

/// Bound looseness of a network over small boxes across `C ∩ S`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Looseness {
    /// Boxes measured.
    pub boxes: usize,
    /// Their width along every axis ([`ErrorSettings::looseness_width`]).
    pub width: f64,
    /// IBP.
    pub ibp: Ratio,
    /// Backward CROWN (adaptive relaxation).
    pub crown: Ratio,
}

/// A small deterministic generator (splitmix64) for sample points.
struct SplitMix(u64);

impl SplitMix {
    fn next_f64(&mut self) -> f64 {
        self.0 = self.0.wrapping_add(0x9E37_79B9_7F4A_7C15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
        z ^= z >> 31;
        (z >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// The boxes of [`looseness`] and of [`Measured::box_slope`] must have a positive width.
fn check_box_width(settings: &ErrorSettings) -> Result<(), AnalysisError> {
    let w = settings.looseness_width;
    if w.is_finite() && w > 0.0 {
        Ok(())
    } else {
        Err(AnalysisError::Setting {
            name: "box width",
            value: w,
            expected: "a finite width > 0",
        })
    }
}

/// Bound looseness: boxes of width [`ErrorSettings::looseness_width`] centred on a grid over `C`
/// (at most [`ErrorSettings::looseness_boxes`]; those with a safe centre), and for each the ratio
/// `maxⱼ (N̄ⱼ − N̲ⱼ) / maxⱼ rangeⱼ`, where `rangeⱼ` is the spread of `Nⱼ` over the box's corners
/// and [`ErrorSettings::looseness_samples`] random points (floored at 1e-12).
pub fn looseness(
    s: &Scenario,
    net: &Mlp,
    settings: &ErrorSettings,
) -> Result<Looseness, AnalysisError> {
    check_dims(s, net)?;
    check_box_width(settings)?;
    let c = &s.reach.region;
    let n = s.n();
    let w = settings.looseness_width;
    let spacing = w.max((c.volume() / settings.looseness_boxes.max(1) as f64).powf(1.0 / n as f64));
    let counts: Vec<usize> = c
        .widths()
        .iter()
        .map(|&wi| ((wi / spacing).floor() as usize).max(1))
        .collect();
    let boxes: Vec<IntervalBox> = centred_grid(c, &counts)
        .into_iter()
        .filter(|x| s.is_safe(x))
        .map(|x| IntervalBox {
            lower: x.iter().map(|v| v - 0.5 * w).collect(),
            upper: x.iter().map(|v| v + 0.5 * w).collect(),
        })
        .collect();
    let ratios: Vec<Result<(f64, f64), AnalysisError>> = boxes
        .par_iter()
        .enumerate()
        .map(|(k, b)| {
            let mut rng = SplitMix(settings.seed ^ (k as u64).wrapping_mul(0x2545_F491_4F6C_DD1D));
            let mut pts: Vec<Vec<f64>> = b.corners().collect();
            for _ in 0..settings.looseness_samples {
                let u: Vec<f64> = (0..n).map(|_| rng.next_f64()).collect();
                pts.push(b.point_at(&u));
            }
            let m = net.output_dim();
            let (mut lo, mut hi) = (vec![f64::INFINITY; m], vec![f64::NEG_INFINITY; m]);
            for p in &pts {
                for (j, y) in net.forward(p).into_iter().enumerate() {
                    lo[j] = lo[j].min(y);
                    hi[j] = hi[j].max(y);
                }
            }
            let range = (0..m).map(|j| hi[j] - lo[j]).fold(0.0, f64::max).max(1e-12);
            let width = |method| -> Result<f64, AnalysisError> {
                let bd = network_bounds(net, &b.lower, &b.upper, method)?;
                Ok((0..m)
                    .map(|j| bd.upper[j] - bd.lower[j])
                    .fold(0.0, f64::max))
            };
            Ok((
                width(BoundMethod::Ibp)? / range,
                width(BoundMethod::Crown)? / range,
            ))
        })
        .collect();
    let mut ibp = Vec::with_capacity(ratios.len());
    let mut crown = Vec::with_capacity(ratios.len());
    for r in ratios {
        let (a, b) = r?;
        ibp.push(a);
        crown.push(b);
    }
    let ratio = |v: &[f64]| {
        let p = Percentiles::of(v);
        Ratio {
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            median: p.median,
            max: p.max,
        }
    };
    Ok(Looseness {
        boxes: ibp.len(),
        width: w,
        ibp: ratio(&ibp),
        crown: ratio(&crown),
    })
}

fn sum(it: impl Iterator<Item = Interval>) -> Interval {
    it.fold(Interval::point(0.0), |a, b| a + b)
}

/// The constraint rows `aₖ·θ ≤ bₖ` of the filter (as in
/// [`SafetyFilter::constraint_rows`]) enclosed over `box ∩ S` by interval evaluation: `(a, b)`
/// with `a` row-major (rows × m). Each `hᵢ` enters as `hᵢ(box) ∩ [0, ∞)`, since `hᵢ ≥ 0` on `S`.
pub fn interval_rows(s: &Scenario, cell: &IntervalBox) -> (Vec<Interval>, Vec<Interval>) {
    let (n, m) = (s.n(), s.m());
    let xs: Vec<Interval> = (0..n)
        .map(|i| Interval::new(cell.lower[i], cell.upper[i]))
        .collect();
    let ft: Vec<Interval> = s.f_tilde.iter().map(|e| e.eval_interval(&xs)).collect();
    let g: Vec<Interval> = s.g.iter().flatten().map(|e| e.eval_interval(&xs)).collect();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for cbf in &s.cbfs {
        let grad: Vec<Interval> = cbf.gradient.iter().map(|e| e.eval_interval(&xs)).collect();
        // Only the points of S matter (v is bounded on `box ∩ S`), where every `hᵢ ≥ 0`.
        let h_all = cbf.h.eval_interval(&xs);
        let h = if h_all.is_nan() {
            h_all
        } else {
            Interval::new(h_all.lower.max(0.0), h_all.upper.max(0.0))
        };
        for j in 0..m {
            a.push(-sum((0..n).map(|i| grad[i] * g[i * m + j])));
        }
        b.push(sum((0..n).map(|i| grad[i] * ft[i])) + h * cbf.alpha);
    }
    if let Some(bounds) = &s.input_bounds {
        let kappa: Vec<Interval> = s.kappa.iter().map(|e| e.eval_interval(&xs)).collect();
        for j in 0..m {
            let mut row = vec![Interval::point(0.0); m];
            row[j] = Interval::point(1.0);
            a.extend(row.iter().copied());
            b.push(Interval::point(bounds.upper[j]) - kappa[j]);
            row[j] = Interval::point(-1.0);
            a.extend(row);
            b.push(kappa[j] - Interval::point(bounds.lower[j]));
        }
    }
    for c in &s.constraints {
        a.extend(c.a.iter().map(|e| e.eval_interval(&xs)));
        b.push(c.b.eval_interval(&xs));
    }
    (a, b)
}

/// The filter's constraint rows `aₖ(x)·θ ≤ bₖ(x)` as expressions, in the order of
/// [`interval_rows`] (per CBF `aₖ = −∇hᵢ·g`, `bₖ = ∇hᵢ·f̃ + αᵢhᵢ`; per input bound; per extra
/// constraint): `(a, b)` with `a` one row of `m` per constraint. With `clamp_h`, each `hᵢ`
/// enters as `max(hᵢ, 0)` (equal on `S`; tighter over boxes that reach outside it).
pub fn row_expressions(s: &Scenario, clamp_h: bool) -> (Vec<Vec<Expr>>, Vec<Expr>) {
    let (n, m) = (s.n(), s.m());
    let zero = || Expr::constant(0.0);
    let sum_e = |it: &mut dyn Iterator<Item = Expr>| it.fold(zero(), |a, b| a + b);
    let mut a_rows: Vec<Vec<Expr>> = Vec::new();
    let mut b_rows: Vec<Expr> = Vec::new();
    for cbf in &s.cbfs {
        let row: Vec<Expr> = (0..m)
            .map(|j| -sum_e(&mut (0..n).map(|i| cbf.gradient[i].clone() * s.g[i][j].clone())))
            .collect();
        a_rows.push(row);
        let h = if clamp_h {
            cbf.h.clone().max(zero())
        } else {
            cbf.h.clone()
        };
        b_rows.push(
            sum_e(&mut (0..n).map(|i| cbf.gradient[i].clone() * s.f_tilde[i].clone()))
                + Expr::constant(cbf.alpha) * h,
        );
    }
    if let Some(bounds) = &s.input_bounds {
        for j in 0..m {
            let mut row = vec![zero(); m];
            row[j] = Expr::constant(1.0);
            a_rows.push(row.clone());
            b_rows.push(Expr::constant(bounds.upper[j]) - s.kappa[j].clone());
            row[j] = Expr::constant(-1.0);
            a_rows.push(row);
            b_rows.push(s.kappa[j].clone() - Expr::constant(bounds.lower[j]));
        }
    }
    for c in &s.constraints {
        a_rows.push(c.a.clone());
        b_rows.push(c.b.clone());
    }
    (a_rows, b_rows)
}

/// `max(0, −B)` for an interval `B`.
fn neg_part(b: Interval) -> Interval {
    Interval::new((-b.upper).max(0.0), (-b.lower).max(0.0))
}

/// An enclosure of the filter `v` over `box ∩ S`, by interval evaluation of its closed form:
/// `Some(v)` with `v[j] ∋ vⱼ(x)` for every `x ∈ box ∩ S` where the filter is feasible, or `None`
/// when the filter has no closed form ([`FilterMethod::Qp`]). Ends may be infinite (e.g. when
/// `‖L_g h‖²` may vanish on the box): refine the box.
///
/// * One row `a·θ ≤ b`: `v = −max(0, −b)/‖a‖² · a`.
/// * Scalar input: with `cₖ = max(0, −bₖ)`, `v = max(0, max_{aₖ<0} cₖ/|aₖ|) − max(0,
///   max_{aₖ>0} cₖ/aₖ)` (which is `clamp(0, lo, hi)` wherever `lo ≤ hi`); a row whose `aₖ` may
///   vanish with `cₖ > 0` makes the enclosure unbounded.
pub fn v_enclosure(
    s: &Scenario,
    method: FilterMethod,
    cell: &IntervalBox,
) -> Option<Vec<Interval>> {
    let m = s.m();
    let (a, b) = interval_rows(s, cell);
    let bad = || Some(vec![Interval::ENTIRE; m]);
    if a.iter().chain(&b).any(|v| v.is_nan()) {
        return bad();
    }
    match method {
        FilterMethod::Qp => None,
        FilterMethod::ClosedFormSingle => {
            if b.len() != 1 || a.len() != m {
                return bad();
            }
            let c = neg_part(b[0]);
            if c.upper == 0.0 {
                return Some(vec![Interval::point(0.0); m]);
            }
            let norm2 = sum(a.iter().map(|&aj| aj.sqr()));
            if norm2.lower <= 0.0 {
                return bad();
            }
            let scale = c / norm2;
            Some(a.iter().map(|&aj| -(scale * aj)).collect())
        }
        FilterMethod::ClosedFormScalar => {
            if m != 1 || a.len() != b.len() {
                return bad();
            }
            // lo⁺ ∈ [lo_l, lo_u], hi⁻ ∈ [hi_l, hi_u]  (both ≥ 0)
            let (mut lo_l, mut lo_u, mut hi_l, mut hi_u) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
            for (&ak, &bk) in a.iter().zip(&b) {
                let c = neg_part(bk);
                if c.upper == 0.0 {
                    continue;
                }
                if ak.lower > 0.0 {
                    let q = c / ak;
                    hi_l = hi_l.max(q.lower);
                    hi_u = hi_u.max(q.upper);
                } else if ak.upper < 0.0 {
                    let q = c / (-ak);
                    lo_l = lo_l.max(q.lower);
                    lo_u = lo_u.max(q.upper);
                } else {
                    return bad();
                }
            }
            Some(vec![Interval::new(lo_l, lo_u) - Interval::new(hi_l, hi_u)])
        }
    }
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
fn error_from(n_lo: &[f64], n_hi: &[f64], v: &[Interval]) -> f64 {
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
/// `None` without a closed-form filter; +∞ when an enclosure is unbounded.
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

/// A smooth expression with its symbolic gradient, for mean-value (centred) enclosures.
#[derive(Clone, Debug)]
pub struct Smooth {
    /// The expression `e(x)`.
    pub e: Expr,
    /// `∂e/∂xᵢ`, one per state.
    pub grad: Vec<Expr>,
}

/// `e(c)` and `∇e(X)` over a box, and the centred form `e(c) + ∇e(X)·(X − c)`.
struct CentredForm {
    value: Interval,
    grad: Vec<Interval>,
    enclosure: Interval,
}

impl Smooth {
    fn new(e: Expr, n: usize) -> Smooth {
        let grad = (0..n).map(|i| e.derivative(i)).collect();
        Smooth { e, grad }
    }

    /// The mean-value form over `xs` around `c` (a point of the box); valid wherever `e` is
    /// differentiable (or Lipschitz, with the interval derivative enclosing its Clarke gradient)
    /// on the box. Every evaluation is outward rounded.
    fn centred(&self, xs: &[Interval], c: &[Interval], dx: &[Interval]) -> CentredForm {
        let value = self.e.eval_interval(c);
        let grad: Vec<Interval> = self.grad.iter().map(|g| g.eval_interval(xs)).collect();
        let enclosure = value + sum(grad.iter().zip(dx).map(|(&g, &d)| g * d));
        CentredForm {
            value,
            grad,
            enclosure,
        }
    }
}

/// `a ∩ b`, or `a` when they are disjoint or `b` is NaN (both enclose the same values, so
/// disjointness means no point to enclose; keeping `a` is sound either way).
fn meet(a: Interval, b: Interval) -> Interval {
    if b.is_nan() {
        return a;
    }
    a.intersection(&b).unwrap_or(a)
}

/// `v` equals one smooth function on `cell ∩ S` (where feasible): `v(x) ∈ value + jac·(x − c)`
/// for every such `x`, with `jac` (m × n, row-major) enclosing the derivatives over the cell.
#[derive(Clone, Debug)]
pub struct SmoothV {
    /// The centre `c` of the cell.
    pub centre: Vec<f64>,
    /// An enclosure of `v(c)` (of the smooth function that equals `v` on the cell).
    pub value: Vec<Interval>,
    /// An enclosure of its Jacobian over the cell, `m × n` row-major.
    pub jac: Vec<Interval>,
}

/// One smooth piece of a closed-form filter `v` (the filter's active set held fixed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterPiece {
    /// Every row slack: `v = 0`.
    Inactive,
    /// Row `k` binds, every other row is slack.
    Binding(usize),
}

/// A cell as intervals `X`, its centre `c` as points, and `X − c`: what mean-value forms take.
struct Centred {
    xs: Vec<Interval>,
    cs: Vec<Interval>,
    dx: Vec<Interval>,
}

impl Centred {
    fn of(cell: &IntervalBox) -> Centred {
        let xs: Vec<Interval> = (0..cell.dim())
            .map(|i| Interval::new(cell.lower[i], cell.upper[i]))
            .collect();
        let cs: Vec<Interval> = cell.center().into_iter().map(Interval::point).collect();
        let dx = xs.iter().zip(&cs).map(|(&x, &c)| x - c).collect();
        Centred { xs, cs, dx }
    }
}

/// The rows of the filter over a cell ([`VForms::rows`]).
struct Rows {
    a_nat: Vec<Interval>,
    b_nat: Vec<Interval>,
    b_enc: Vec<Interval>,
}

/// The closed-form filter as expressions with symbolic gradients, built once per scenario for
/// [`VForms::enclose`] (mean-value enclosures of `v`, DESIGN §2.1).
#[derive(Clone, Debug)]
pub struct VForms {
    method: FilterMethod,
    n: usize,
    m: usize,
    /// `bₖ(x)` of every row (with `hᵢ` itself, not clamped: equal to the clamped one on `S`).
    b: Vec<Smooth>,
    /// One row: `Fⱼ = b·aⱼ/‖a‖²` (equal to `vⱼ` where the row is active).
    f: Vec<Smooth>,
    /// One row: `pⱼ = aⱼ/‖a‖²`.
    p: Vec<Smooth>,
    /// Scalar input: `rₖ = bₖ/aₖ` per row.
    r: Vec<Smooth>,
    /// Scalar input: `rₖ − rⱼ` at `k·rows + j` (`k ≠ j`), to prove one row dominant; empty
    /// beyond [`MAX_DOMINANCE_ROWS`] rows.
    r_diff: Vec<Option<Smooth>>,
}

/// The expressions behind [`VForms`], for an engine that evaluates them itself (the GPU's
/// generated WGSL, `src/gpu/codegen.rs`); the fields are those of [`VForms`].
#[derive(Clone, Copy, Debug)]
pub struct VFormParts<'a> {
    /// Which closed form.
    pub method: FilterMethod,
    /// `bₖ(x)` of every row (`hᵢ` not clamped).
    pub b: &'a [Smooth],
    /// One row: `Fⱼ = b·aⱼ/‖a‖²`.
    pub f: &'a [Smooth],
    /// One row: `pⱼ = aⱼ/‖a‖²`.
    pub p: &'a [Smooth],
    /// Scalar input: `rₖ = bₖ/aₖ`.
    pub r: &'a [Smooth],
    /// Scalar input: `rₖ − rⱼ` at `k·rows + j` (`None` on the diagonal; empty beyond eight rows).
    pub r_diff: &'a [Option<Smooth>],
}

/// Rows up to which [`VForms`] keeps the pairwise differences `rₖ − rⱼ` (their count grows
/// with the square).
const MAX_DOMINANCE_ROWS: usize = 8;

impl VForms {
    /// The forms of the scenario's closed-form filter; `None` for a general QP.
    pub fn new(s: &Scenario) -> Option<VForms> {
        let method = SafetyFilter::new(s).method();
        if method == FilterMethod::Qp {
            return None;
        }
        let (n, m) = (s.n(), s.m());
        let (a_rows, b_rows) = row_expressions(s, false);
        let sum_e = |it: &mut dyn Iterator<Item = Expr>| it.fold(Expr::constant(0.0), |a, b| a + b);
        let b: Vec<Smooth> = b_rows.iter().map(|e| Smooth::new(e.clone(), n)).collect();
        let (mut f, mut p, mut r) = (Vec::new(), Vec::new(), Vec::new());
        match method {
            FilterMethod::ClosedFormSingle if a_rows.len() == 1 => {
                let a = &a_rows[0];
                let norm2 = sum_e(&mut a.iter().map(|aj| aj.clone() * aj.clone()));
                for aj in a {
                    let pj = aj.clone() / norm2.clone();
                    f.push(Smooth::new(b_rows[0].clone() * pj.clone(), n));
                    p.push(Smooth::new(pj, n));
                }
            }
            FilterMethod::ClosedFormScalar if m == 1 => {
                for (a, bk) in a_rows.iter().zip(&b_rows) {
                    r.push(Smooth::new(bk.clone() / a[0].clone(), n));
                }
            }
            _ => {}
        }
        let rows = r.len();
        let r_diff = if rows <= MAX_DOMINANCE_ROWS {
            (0..rows * rows)
                .map(|kj| {
                    let (k, j) = (kj / rows, kj % rows);
                    (k != j).then(|| Smooth::new(r[k].e.clone() - r[j].e.clone(), n))
                })
                .collect()
        } else {
            Vec::new()
        };
        Some(VForms {
            method,
            n,
            m,
            b,
            f,
            p,
            r,
            r_diff,
        })
    }

    /// The rows over `cell ∩ S`: natural enclosures of `a` and `b`, and `b` met with its
    /// mean-value form; `None` when some row is undefined (NaN) on the cell.
    fn rows(
        &self,
        s: &Scenario,
        xs: &[Interval],
        cs: &[Interval],
        dx: &[Interval],
        cell: &IntervalBox,
    ) -> Option<Rows> {
        let (a_nat, b_nat) = interval_rows(s, cell);
        if b_nat.len() != self.b.len() || a_nat.iter().chain(&b_nat).any(|v| v.is_nan()) {
            return None;
        }
        let b_enc = self
            .b
            .iter()
            .zip(&b_nat)
            .map(|(bk, &nat)| meet(nat, bk.centred(xs, cs, dx).enclosure))
            .collect();
        Some(Rows {
            a_nat,
            b_nat,
            b_enc,
        })
    }

    /// Which smooth piece of the closed form `v` is on the whole of `cell ∩ S` (where the
    /// filter is feasible), if one provably is: every row slack (`bₖ ≥ 0`: `v = 0`), or one row
    /// binding throughout (`bₖ ≤ 0`, its `aₖ` bounded away from 0) while every other row that
    /// may bind is, for a scalar input, on the other side of `θ = 0` or dominated by it
    /// (`rₖ − rⱼ` of one sign on the cell).
    pub fn piece(&self, s: &Scenario, cell: &IntervalBox) -> Option<FilterPiece> {
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Rows {
            a_nat,
            b_nat,
            b_enc,
        } = self.rows(s, &xs, &cs, &dx, cell)?;
        let may_bind: Vec<usize> = (0..b_enc.len()).filter(|&k| b_enc[k].lower < 0.0).collect();
        if may_bind.is_empty() {
            return Some(FilterPiece::Inactive);
        }
        match self.method {
            FilterMethod::ClosedFormSingle if !self.f.is_empty() => {
                let norm2 = sum(a_nat.iter().map(|&aj| aj.sqr()));
                (b_enc[0].upper <= 0.0 && norm2.lower > 0.0).then_some(FilterPiece::Binding(0))
            }
            FilterMethod::ClosedFormScalar if self.r.len() == b_enc.len() => {
                // `v = clamp(0, lo, hi)` with `lo` the largest `rₖ` of the rows with `aₖ < 0`
                // and `hi` the smallest of those with `aₖ > 0`. A row that binds throughout
                // (`bₖ ≤ 0`) fixes the sign of `v`, so only the rows on its own side compete:
                // it is `v` where it dominates each of them that may bind.
                let r_of = |k: usize| {
                    meet(
                        b_nat[k] / a_nat[k],
                        self.r[k].centred(&xs, &cs, &dx).enclosure,
                    )
                };
                let side = |k: usize| {
                    let a = a_nat[k];
                    (a.upper < 0.0)
                        .then_some(false)
                        .or((a.lower > 0.0).then_some(true))
                };
                let dominates = |k: usize, j: usize, upper: bool| {
                    let Some(Some(form)) = self.r_diff.get(k * self.r.len() + j) else {
                        return false;
                    };
                    let d = meet(r_of(k) - r_of(j), form.centred(&xs, &cs, &dx).enclosure);
                    if upper {
                        d.upper <= 0.0
                    } else {
                        d.lower >= 0.0
                    }
                };
                may_bind
                    .iter()
                    .copied()
                    .find(|&k| {
                        let Some(upper) = side(k) else {
                            return false;
                        };
                        b_enc[k].upper <= 0.0
                            && may_bind.iter().all(|&j| {
                                j == k
                                    || match side(j) {
                                        Some(u) if u != upper => true,
                                        Some(_) => dominates(k, j, upper),
                                        None => false,
                                    }
                            })
                    })
                    .map(FilterPiece::Binding)
            }
            _ => None,
        }
    }

    /// Whether the filter's QP is feasible at every point of `cell ∩ S`. One row: `bₖ ≥ 0` or
    /// `aₖ ≠ 0`. Scalar input: each row's set of `θ` is a half-line (or all of ℝ), and in one
    /// dimension sets that meet pairwise have a common point (Helly), so it suffices that every
    /// row alone is feasible and that no two rows point in opposite directions past each
    /// other: `aⱼaₖ ≥ 0`, or `(bⱼaₖ − bₖaⱼ)·aₖ ≥ 0` (that is `bⱼ/aⱼ ≤ bₖ/aₖ` when `aⱼ < 0 < aₖ`),
    /// or both rows slack at `θ = 0`.
    pub fn proves_feasible(&self, s: &Scenario, cell: &IntervalBox) -> bool {
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Some(Rows { a_nat, b_enc, .. }) = self.rows(s, &xs, &cs, &dx, cell) else {
            return false;
        };
        let slack = |k: usize| b_enc[k].lower >= 0.0;
        match self.method {
            FilterMethod::ClosedFormSingle => {
                slack(0) || sum(a_nat.iter().map(|&aj| aj.sqr())).lower > 0.0
            }
            FilterMethod::ClosedFormScalar => {
                let rows = b_enc.len();
                let alone = (0..rows).all(|k| slack(k) || !a_nat[k].contains(0.0));
                alone
                    && (0..rows).all(|j| {
                        (j + 1..rows).all(|k| {
                            let (aj, ak) = (a_nat[j], a_nat[k]);
                            (slack(j) && slack(k))
                                || (aj * ak).lower >= 0.0
                                || ((b_enc[j] * ak - b_enc[k] * aj) * ak).lower >= 0.0
                        })
                    })
            }
            FilterMethod::Qp => (0..b_enc.len()).all(slack),
        }
    }

    /// `v` on a piece, as expressions in x (`m` of them): `0` where every row is slack;
    /// `bₖ aⱼ/‖a‖²` (one row) or `bₖ/aₖ` (scalar input) where row `k` binds.
    pub fn piece_input(&self, piece: FilterPiece) -> Vec<Expr> {
        match piece {
            FilterPiece::Inactive => vec![Expr::constant(0.0); self.m],
            FilterPiece::Binding(k) => match self.method {
                FilterMethod::ClosedFormSingle => self.f.iter().map(|f| f.e.clone()).collect(),
                _ => vec![self.r[k].e.clone()],
            },
        }
    }

    /// Its expressions, for engines that evaluate them elsewhere.
    pub fn parts(&self) -> VFormParts<'_> {
        VFormParts {
            method: self.method,
            b: &self.b,
            f: &self.f,
            p: &self.p,
            r: &self.r,
            r_diff: &self.r_diff,
        }
    }

    /// Number of constraint rows (the pieces are [`FilterPiece::Inactive`] and one
    /// [`FilterPiece::Binding`] per row).
    pub fn rows_len(&self) -> usize {
        self.b.len()
    }

    /// An enclosure of `v` over `cell ∩ S` (where feasible), the natural one of
    /// [`v_enclosure`] intersected with mean-value forms where those apply, and, when `v` is one
    /// smooth function on the cell (the filter provably inactive: `v ≡ 0`; or one row provably
    /// active on the whole cell), its centred form for a joint bound of `N − v`.
    pub fn enclose(&self, s: &Scenario, cell: &IntervalBox) -> (Vec<Interval>, Option<SmoothV>) {
        let (n, m) = (self.n, self.m);
        let natural =
            v_enclosure(s, self.method, cell).unwrap_or_else(|| vec![Interval::ENTIRE; m]);
        let centre = cell.center();
        let Centred { xs, cs, dx } = Centred::of(cell);
        let zero_v = || SmoothV {
            centre: centre.clone(),
            value: vec![Interval::point(0.0); m],
            jac: vec![Interval::point(0.0); m * n],
        };
        let Some(Rows {
            a_nat,
            b_nat,
            b_enc,
        }) = self.rows(s, &xs, &cs, &dx, cell)
        else {
            return (natural, None);
        };
        let smooth_of = |forms: Vec<CentredForm>| SmoothV {
            centre: centre.clone(),
            value: forms.iter().map(|f| f.value).collect(),
            jac: forms.iter().flat_map(|f| f.grad.iter().copied()).collect(),
        };
        match self.method {
            FilterMethod::ClosedFormSingle if !self.f.is_empty() => {
                let b = b_enc[0];
                if b.lower >= 0.0 {
                    return (vec![Interval::point(0.0); m], Some(zero_v()));
                }
                let norm2 = sum(a_nat.iter().map(|&aj| aj.sqr()));
                // (NaN counts as "maybe zero".)
                if norm2.lower.is_nan() || norm2.lower <= 0.0 {
                    return (natural, None);
                }
                let forms: Vec<CentredForm> =
                    self.f.iter().map(|f| f.centred(&xs, &cs, &dx)).collect();
                if forms.iter().any(|f| f.grad.iter().any(|g| g.is_nan())) {
                    return (natural, None);
                }
                if b.upper <= 0.0 {
                    let enc = (0..m)
                        .map(|j| meet(natural[j], forms[j].enclosure))
                        .collect();
                    return (enc, Some(smooth_of(forms)));
                }
                // Active on part of the cell: vⱼ = min(0, b)·pⱼ = min(0, Fⱼ) where pⱼ ≥ 0,
                // max(0, Fⱼ) where pⱼ ≤ 0.
                let zero = Interval::point(0.0);
                let enc = (0..m)
                    .map(|j| {
                        let pj = meet(a_nat[j] / norm2, self.p[j].centred(&xs, &cs, &dx).enclosure);
                        let fj = forms[j].enclosure;
                        let e = if pj.lower >= 0.0 {
                            fj.min(zero)
                        } else if pj.upper <= 0.0 {
                            fj.max(zero)
                        } else {
                            b.min(zero) * pj
                        };
                        meet(natural[j], e)
                    })
                    .collect();
                (enc, None)
            }
            FilterMethod::ClosedFormScalar if self.r.len() == b_enc.len() => {
                let zero = Interval::point(0.0);
                let (mut lo, mut hi) = (zero, zero);
                let mut active: Vec<usize> = Vec::new();
                for k in 0..b_enc.len() {
                    if b_enc[k].lower >= 0.0 {
                        continue; // the row never binds on the cell
                    }
                    let ak = a_nat[k];
                    if ak.lower <= 0.0 && ak.upper >= 0.0 {
                        return (natural, None);
                    }
                    active.push(k);
                    let rk = meet(b_nat[k] / ak, self.r[k].centred(&xs, &cs, &dx).enclosure);
                    if ak.upper < 0.0 {
                        lo = lo.max(rk);
                    } else {
                        hi = hi.min(rk);
                    }
                }
                if active.is_empty() {
                    return (vec![zero], Some(zero_v()));
                }
                let enc = vec![meet(natural[0], lo + hi)];
                if active.len() == 1 && b_enc[active[0]].upper <= 0.0 {
                    let form = self.r[active[0]].centred(&xs, &cs, &dx);
                    if !form.grad.iter().any(|g| g.is_nan()) {
                        return (enc, Some(smooth_of(vec![form])));
                    }
                }
                (enc, None)
            }
            _ => (natural, None),
        }
    }
}

/// `sup ‖N − v‖∞` over the cell from CROWN's affine forms of `N` and the centred form of `v`,
/// both linear in `x − c`, so that their common slope cancels:
/// `N − v ≤ (C̄c + d̄ − v(c)) + (C̄ − Jᵥ(X))(X − c)` and likewise below. +∞ on NaN.
fn joint_error(ab: &AffineBounds, sv: &SmoothV, cell: &IntervalBox) -> f64 {
    let (m, n) = (ab.n_out, ab.n_in);
    let cs: Vec<Interval> = sv.centre.iter().map(|&c| Interval::point(c)).collect();
    let dx: Vec<Interval> = (0..n)
        .map(|i| Interval::new(cell.lower[i], cell.upper[i]) - cs[i])
        .collect();
    let mut e = 0.0_f64;
    for j in 0..m {
        for (a, d, upper) in [
            (ab.a_upper_row(j), ab.b_upper[j], true),
            (ab.a_lower_row(j), ab.b_lower[j], false),
        ] {
            let at_c = sum((0..n).map(|i| Interval::point(a[i]) * cs[i])) + Interval::point(d);
            let slope = sum((0..n).map(|i| (Interval::point(a[i]) - sv.jac[j * n + i]) * dx[i]));
            let diff = at_c - sv.value[j] + slope;
            let side = if upper { diff.upper } else { -diff.lower };
            if side.is_nan() {
                return f64::INFINITY;
            }
            e = e.max(round_up(side));
        }
    }
    e
}

/// Sub-boxes per axis of a cell for the enclosures of `v` ([`VForms::enclose`] runs on each):
/// the interval Jacobian over a sub-box is that much tighter, and the mean-value forms with it.
/// `k` per axis with `kⁿ ≤ 64` (8 × 8 in the plane).
pub fn enclosure_pieces(cell: &IntervalBox) -> Vec<IntervalBox> {
    let n = cell.dim();
    let k = (1..=8usize)
        .rev()
        .find(|k| k.checked_pow(n as u32).is_some_and(|p| p <= 64))
        .unwrap_or(1);
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

/// `[C x + d]` over a box, outward rounded: one side of an affine bound, made concrete.
fn affine_over(a: &[f64], d: f64, b: &IntervalBox) -> Interval {
    sum(a
        .iter()
        .enumerate()
        .map(|(i, &ai)| Interval::point(ai) * Interval::new(b.lower[i], b.upper[i])))
        + Interval::point(d)
}

/// `sup ‖N − v‖∞` over one piece of a cell from affine bounds of `N` valid on the whole cell
/// (made concrete on the piece and intersected with the cell's interval bounds `n_lo, n_hi`)
/// and the piece's enclosure of `v`; with the joint form ([`joint_error`]) where `v` is smooth
/// on the piece. Each bound is sound on `piece ∩ S`; the least is kept.
fn piece_error(
    ab: &AffineBounds,
    n_lo: &[f64],
    n_hi: &[f64],
    piece: &IntervalBox,
    v: &[Interval],
    smooth: Option<&SmoothV>,
) -> f64 {
    let m = v.len();
    let lo: Vec<f64> = (0..m)
        .map(|j| n_lo[j].max(affine_over(ab.a_lower_row(j), ab.b_lower[j], piece).lower))
        .collect();
    let hi: Vec<f64> = (0..m)
        .map(|j| n_hi[j].min(affine_over(ab.a_upper_row(j), ab.b_upper[j], piece).upper))
        .collect();
    let e = error_from(&lo, &hi, v);
    match smooth {
        Some(sv) => e.min(joint_error(ab, sv, piece)),
        None => e,
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
    let v = v_enclosure(s, forms.method, cell).unwrap_or_else(|| vec![Interval::ENTIRE; forms.m]);
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
        return Ok(coarse);
    }
    let ab = net.bounds(&cell.lower, &cell.upper, method)?;
    let n_lo: Vec<f64> = (0..ab.n_out)
        .map(|j| ibp.lower[j].max(ab.lower[j]))
        .collect();
    let n_hi: Vec<f64> = (0..ab.n_out)
        .map(|j| ibp.upper[j].min(ab.upper[j]))
        .collect();
    let (v_whole, smooth_whole) = forms.enclose(s, cell);
    let whole = if unbounded(&v_whole) {
        f64::INFINITY
    } else {
        piece_error(&ab, &n_lo, &n_hi, cell, &v_whole, smooth_whole.as_ref())
    };
    let coarse = coarse.min(whole);
    if coarse <= good_enough {
        return Ok(coarse);
    }
    let mut worst = 0.0_f64;
    for piece in enclosure_pieces(cell) {
        let (vp, smooth) = forms.enclose(s, &piece);
        let vp: Vec<Interval> = vp.iter().zip(&v_whole).map(|(&a, &b)| meet(a, b)).collect();
        if unbounded(&vp) {
            return Ok(coarse);
        }
        worst = worst.max(piece_error(&ab, &n_lo, &n_hi, &piece, &vp, smooth.as_ref()));
        if worst >= coarse {
            return Ok(coarse);
        }
    }
    Ok(worst.min(coarse))
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
    let n = cell.dim();
    let mut pts: Vec<Vec<f64>> = cell.corners().collect();
    pts.push(cell.center());
    let mut rng = SplitMix(seed);
    for _ in 0..extra {
        let u: Vec<f64> = (0..n).map(|_| rng.next_f64()).collect();
        pts.push(cell.point_at(&u));
    }
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

/// One cell of an error map and its certified bound.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct CellBound {
    /// Lower corner.
    pub lower: Vec<f64>,
    /// Upper corner.
    pub upper: Vec<f64>,
    /// `sup ‖N(x) − v(x)‖∞` over `cell ∩ S` is at most this (+∞, written `"inf"`, when
    /// nothing could be certified on the cell).
    #[serde(with = "inf_as_string")]
    pub bound: f64,
}

impl CellBound {
    /// Whether the (closed) cell meets the (closed) box.
    pub fn meets(&self, b: &IntervalBox) -> bool {
        (0..self.lower.len()).all(|i| self.lower[i] <= b.upper[i] && b.lower[i] <= self.upper[i])
    }
}

/// The outcome of [`certify`].
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
    /// The kept cells (they and the dropped ones tile `C`).
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
    cell: IntervalBox,
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
        a.cmp(&b).then(x.total_cmp(&y)).then_with(|| {
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

/// A certified `M_C` over `C ∩ S` with local bounds (see the [module docs](self)).
///
/// `C` is cut into cells of [`ErrorSettings::initial_cell`]; every cell gets a certified bound
/// ([`cell_error_bound_mv`]) and a cheap sampled error `e` (corners, centre and
/// [`ErrorSettings::cell_samples`] random points). A cell is refined (bisected) while its bound
/// exceeds its target `max(local_ratio · e, floor)` ([`ErrorSettings::local_ratio`],
/// [`ErrorSettings::floor`]), the largest gaps `bound − target` times cell width first (weighted
/// by [`ErrorSettings::goal_weight`] on cells that meet the scenario's goal set), down to
/// [`ErrorSettings::min_cell`], in parallel
/// batches, until every cell meets its target, [`ErrorSettings::budget`] cell evaluations are
/// spent, or the map holds [`ErrorSettings::max_cells`] cells. A cell's target is at most
/// `local_ratio · target` (`target`: the measured global error), and cells whose bound exceeds
/// that are refined before all others: the global certified `M_C` is the max over the cells,
/// and the area-weighted order alone can spend the budget before it reaches a small cell that
/// holds that max. `None` when the filter
/// is a general QP. `progress` is told the
/// evaluations so far and the largest bound still waiting for refinement.
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
    let counts: Vec<usize> = c
        .widths()
        .iter()
        .map(|&w| ((w / settings.initial_cell.max(1e-6)).ceil() as usize).max(1))
        .collect();
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
    let mut done: Vec<CellBound> = Vec::new();
    let mut dropped = 0;
    let mut evaluated = 0;
    let mut satisfied = 0;
    // Each cell: dropped (None) or (bound, its target).
    let eval = |cells: Vec<IntervalBox>,
                salt: usize|
     -> Result<Vec<Option<CellOutcome>>, AnalysisError> {
        cells
            .into_par_iter()
            .enumerate()
            .map(|(k, cell)| {
                if proven_unsafe(s, &cell) {
                    return Ok(None);
                }
                let seed = settings.seed ^ ((salt + k) as u64).wrapping_mul(0x2545_F491_4F6C_DD1D);
                let e = sampled_cell_error(s, &filter, net, &cell, settings.cell_samples, seed);
                // A cell's own error may exceed the global one (it was not sampled there), but
                // its bound must also come within `local_ratio` of the global measured error.
                let tgt = (ratio * e).max(floor).min(global_goal.max(floor));
                let b =
                    cell_error_bound_mv(&forms, s, &prepared, &cell, settings.cell_bounds, tgt)?;
                // Where the QP is infeasible on part of the cell, the enclosure of `v` stays
                // wide however small the cell: keep the cell's bound as it is (target = bound).
                let tgt = if meets_infeasibility(s, &filter, &cell) {
                    tgt.max(b)
                } else {
                    tgt
                };
                Ok(Some((b, tgt, cell)))
            })
            .collect()
    };
    let mut absorb = |res: Vec<Option<(f64, f64, IntervalBox)>>,
                      heap: &mut BinaryHeap<Entry>,
                      done: &mut Vec<CellBound>| {
        for r in res {
            match r {
                None => dropped += 1,
                Some((bound, tgt, cell)) => {
                    if bound <= tgt {
                        satisfied += 1;
                        done.push(CellBound {
                            lower: cell.lower,
                            upper: cell.upper,
                            bound,
                        });
                    } else {
                        let gap = if bound.is_finite() {
                            bound - tgt
                        } else {
                            f64::MAX
                        };
                        // Larger cells first at equal gaps: a cell's bound reaches every box
                        // that meets it, and tiny cells at singular sets gain nothing.
                        let size = cell.widths().iter().fold(0.0_f64, |a, &b| a.max(b));
                        heap.push(Entry {
                            above_goal: bound > global_goal,
                            priority: gap * size * weight(&cell),
                            bound,
                            cell,
                        });
                    }
                }
            }
        }
    };
    let initial = c.partition(&counts);
    evaluated += initial.len();
    let res = eval(initial, 0)?;
    absorb(res, &mut heap, &mut done);
    let batch = 16 * rayon::current_num_threads().max(1);
    let mut budget_spent = false;
    loop {
        let worst = heap.iter().map(|e| e.bound).fold(0.0, f64::max);
        progress(evaluated, worst);
        if heap.is_empty() {
            break;
        }
        if evaluated >= settings.budget || heap.len() + done.len() >= settings.max_cells {
            budget_spent = true;
            break;
        }
        let room = settings
            .max_cells
            .saturating_sub(heap.len() + done.len())
            .min(settings.budget.saturating_sub(evaluated) / 2)
            .clamp(1, batch);
        let mut children = Vec::new();
        while children.len() < 2 * room {
            let Some(Entry { bound, cell, .. }) = heap.pop() else {
                break;
            };
            if cell.widths().iter().fold(0.0_f64, |a, &b| a.max(b)) < min_cell {
                done.push(CellBound {
                    lower: cell.lower,
                    upper: cell.upper,
                    bound,
                });
                continue;
            }
            let (l, r) = cell.bisect();
            children.push(l);
            children.push(r);
        }
        if children.is_empty() {
            break;
        }
        let salt = evaluated;
        evaluated += children.len();
        let res = eval(children, salt)?;
        absorb(res, &mut heap, &mut done);
    }
    done.extend(heap.into_iter().map(|e| CellBound {
        lower: e.cell.lower,
        upper: e.cell.upper,
        bound: e.bound,
    }));
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
        dropped,
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
            let cell = IntervalBox {
                lower: c.lower.clone(),
                upper: c.upper.clone(),
            };
            grid_points(&cell, &vec![per_axis; cell.dim()])
        })
        .filter_map(|x| Some((error_at(s, filter, net, &x)?, x)))
        .max_by(|a, b| a.0.total_cmp(&b.0))
        .unwrap_or((0.0, Vec::new()))
}

/// A kept cell's certified bound, its refinement target, and the cell.
type CellOutcome = (f64, f64, IntervalBox);

/// The certified per-cell error bounds of one network, stored beside it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorMap {
    /// Format tag, `cbfreach-errormap-1`.
    pub format: String,
    /// The network file's name (informational).
    pub network: String,
    /// FNV-1a 64 of the network file's bytes, hex: a map for another file is refused.
    pub network_hash: String,
    /// The mapped region `C`.
    pub region: IntervalBox,
    /// The norm of the bounds (`inf`).
    pub norm: String,
    /// Measured `max ‖N − v‖∞` over a grid of `C ∩ S`.
    pub measured_linf: f64,
    /// Measured `max ‖N − v‖₂`.
    pub measured_l2: f64,
    /// The certified global bound (max over the cells; `"inf"` when some cell could not be
    /// certified), `None` for a QP filter.
    #[serde(with = "opt_inf_as_string")]
    pub certified_linf: Option<f64>,
    /// Kept cells with their bounds; cells of `region` not listed were proven to miss `S`
    /// (where the filtered system never goes), so they contribute nothing.
    pub cells: Vec<CellBound>,
    /// Buckets of cells for [`ErrorMap::local_bound`], built on first use (not serialised; a
    /// map whose `cells` are changed afterwards must be rebuilt with [`ErrorMap::reindexed`]).
    #[serde(skip)]
    index: LazyIndex,
}

/// The lazily built [`CellIndex`]; a cache, so it takes no part in equality.
#[derive(Clone, Debug, Default)]
struct LazyIndex(std::sync::OnceLock<CellIndex>);

impl PartialEq for LazyIndex {
    fn eq(&self, _: &Self) -> bool {
        true
    }
}

/// A uniform grid of buckets over the mapped region, each listing the cells whose closed extent
/// meets it (so two closed boxes that meet share a bucket: the bucket of a common point, since
/// the bucket index `⌊(x − l)/h⌋`, clamped, is monotone in `x` in floating point too).
#[derive(Clone, Debug, Default)]
struct CellIndex {
    counts: Vec<usize>,
    lower: Vec<f64>,
    step: Vec<f64>,
    /// Bucket `k` (row-major, axis 0 slowest) lists `cells[start[k]..start[k + 1]]`.
    start: Vec<u32>,
    cells: Vec<u32>,
}

impl CellIndex {
    fn build(region: &IntervalBox, cells: &[CellBound]) -> CellIndex {
        let n = region.dim();
        let per_axis =
            ((cells.len().max(1) as f64).powf(1.0 / n as f64).ceil() as usize).clamp(1, 512);
        let counts = vec![per_axis; n];
        let step: Vec<f64> = (0..n)
            .map(|i| ((region.upper[i] - region.lower[i]) / per_axis as f64).max(f64::MIN_POSITIVE))
            .collect();
        let mut idx = CellIndex {
            counts,
            lower: region.lower.clone(),
            step,
            start: Vec::new(),
            cells: Vec::new(),
        };
        let total: usize = idx.counts.iter().product();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); total];
        for (k, c) in cells.iter().enumerate() {
            idx.for_each_bucket(&c.lower, &c.upper, |b| lists[b].push(k as u32));
        }
        idx.start.push(0);
        for l in lists {
            idx.cells.extend(l);
            idx.start.push(idx.cells.len() as u32);
        }
        idx
    }

    fn bucket(&self, i: usize, x: f64) -> usize {
        let t = ((x - self.lower[i]) / self.step[i]).floor();
        if t.is_nan() || t < 0.0 {
            0
        } else {
            (t as usize).min(self.counts[i] - 1)
        }
    }

    fn for_each_bucket(&self, lower: &[f64], upper: &[f64], mut f: impl FnMut(usize)) {
        let n = self.counts.len();
        let lo: Vec<usize> = (0..n).map(|i| self.bucket(i, lower[i])).collect();
        let hi: Vec<usize> = (0..n).map(|i| self.bucket(i, upper[i])).collect();
        let mut at = lo.clone();
        loop {
            let k = (0..n).fold(0, |acc, i| acc * self.counts[i] + at[i]);
            f(k);
            let mut i = n;
            loop {
                if i == 0 {
                    return;
                }
                i -= 1;
                if at[i] < hi[i] {
                    at[i] += 1;
                    break;
                }
                at[i] = lo[i];
            }
        }
    }
}

/// JSON has no ∞: a non-finite bound is written as the string `"inf"`.
mod inf_as_string {
    use serde::{Deserialize, Deserializer, Serializer};

    #[derive(Deserialize)]
    #[serde(untagged)]
    pub(super) enum NumOrText {
        Num(f64),
        Text(String),
    }

    pub(super) fn to_f64(v: NumOrText) -> Result<f64, String> {
        match v {
            NumOrText::Num(x) => Ok(x),
            NumOrText::Text(s) if s == "inf" => Ok(f64::INFINITY),
            NumOrText::Text(s) => Err(format!("`{s}` is not a bound (a number or \"inf\")")),
        }
    }

    pub fn serialize<S: Serializer>(x: &f64, s: S) -> Result<S::Ok, S::Error> {
        if x.is_finite() {
            s.serialize_f64(*x)
        } else {
            s.serialize_str("inf")
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<f64, D::Error> {
        to_f64(NumOrText::deserialize(d)?).map_err(serde::de::Error::custom)
    }
}

/// [`inf_as_string`] for an optional bound (`null` for `None`).
mod opt_inf_as_string {
    use serde::{Deserialize, Deserializer, Serializer};

    use super::inf_as_string::{to_f64, NumOrText};

    pub fn serialize<S: Serializer>(x: &Option<f64>, s: S) -> Result<S::Ok, S::Error> {
        match x {
            None => s.serialize_none(),
            Some(v) => super::inf_as_string::serialize(v, s),
        }
    }

    pub fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<Option<f64>, D::Error> {
        Option::<NumOrText>::deserialize(d)?
            .map(to_f64)
            .transpose()
            .map_err(serde::de::Error::custom)
    }
}

/// The format tag of [`ErrorMap`] files.
pub const ERROR_MAP_FORMAT: &str = "cbfreach-errormap-1";

/// Whether `[lo, hi]` is not an interval (inverted or NaN).
fn inverted(lo: f64, hi: f64) -> bool {
    lo.is_nan() || hi.is_nan() || lo > hi
}

/// `<network stem>.errormap.json` beside the network.
pub fn error_map_path(network: &Path) -> PathBuf {
    let stem = network
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "network".into());
    network.with_file_name(format!("{stem}.errormap.json"))
}

/// FNV-1a 64 of a byte string, as 16 hex digits.
pub fn fnv1a_hex(bytes: &[u8]) -> String {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for &b in bytes {
        h ^= b as u64;
        h = h.wrapping_mul(0x0000_0100_0000_01b3);
    }
    format!("{h:016x}")
}

fn hash_file(path: &Path) -> Result<String, AnalysisError> {
    let bytes = std::fs::read(path).map_err(|source| AnalysisError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    Ok(fnv1a_hex(&bytes))
}

impl ErrorMap {
    /// A map for the network file `network` from a measurement and (optionally) a certification.
    pub fn new(
        network: &Path,
        region: &IntervalBox,
        measured: &Measured,
        certified: Option<&Certified>,
    ) -> Result<ErrorMap, AnalysisError> {
        Ok(ErrorMap {
            format: ERROR_MAP_FORMAT.into(),
            network: network
                .file_name()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_default(),
            network_hash: hash_file(network)?,
            region: region.clone(),
            norm: "inf".into(),
            measured_linf: measured.linf,
            measured_l2: measured.l2,
            certified_linf: certified.map(|c| c.linf),
            cells: certified.map(|c| c.cells.clone()).unwrap_or_default(),
            index: LazyIndex::default(),
        })
    }

    /// Reads and checks a map file.
    pub fn load(path: &Path) -> Result<ErrorMap, AnalysisError> {
        let text = std::fs::read_to_string(path).map_err(|source| AnalysisError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        let bad = |message: String| AnalysisError::Format {
            path: path.to_path_buf(),
            message,
        };
        let map: ErrorMap = serde_json::from_str(&text).map_err(|e| bad(e.to_string()))?;
        if map.format != ERROR_MAP_FORMAT {
            return Err(bad(format!(
                "format `{}`, expected `{ERROR_MAP_FORMAT}`",
                map.format
            )));
        }
        let n = map.region.dim();
        if n == 0
            || map.region.upper.len() != n
            || (0..n).any(|i| inverted(map.region.lower[i], map.region.upper[i]))
        {
            return Err(bad("`region` is not a box".into()));
        }
        for (k, c) in map.cells.iter().enumerate() {
            if c.lower.len() != n
                || c.upper.len() != n
                || (0..n).any(|i| inverted(c.lower[i], c.upper[i]))
                || c.bound.is_nan()
                || c.bound < 0.0
            {
                return Err(bad(format!("cell {k} is malformed")));
            }
        }
        Ok(map)
    }

    /// Loads the map beside `network` and checks that it was made for that file.
    pub fn load_for(network: &Path) -> Result<ErrorMap, AnalysisError> {
        let path = error_map_path(network);
        let map = ErrorMap::load(&path)?;
        if map.network_hash != hash_file(network)? {
            return Err(AnalysisError::StaleMap {
                path,
                network: network.to_path_buf(),
            });
        }
        Ok(map)
    }

    /// Writes the map as JSON.
    pub fn save(&self, path: &Path) -> Result<(), AnalysisError> {
        let text = serde_json::to_string(self).map_err(|e| AnalysisError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        })?;
        std::fs::write(path, text).map_err(|source| AnalysisError::Io {
            path: path.to_path_buf(),
            source,
        })
    }

    /// The largest finite cell bound: `M_C` over `C ∩ S` minus the cells with no bound.
    pub fn finite_max(&self) -> f64 {
        self.cells
            .iter()
            .map(|c| c.bound)
            .filter(|b| b.is_finite())
            .fold(0.0, f64::max)
    }

    /// The certified bound of `‖N − v‖∞` over `b ∩ S`: the max over the cells that meet `b` (0
    /// when `b` meets only cells proven unsafe). +∞ when `b` is not inside the mapped region (or
    /// the map holds no certified cells); see [`ErrorMap::try_local_bound`] for an error instead.
    pub fn local_bound(&self, b: &IntervalBox) -> f64 {
        self.try_local_bound(b).unwrap_or(f64::INFINITY)
    }

    /// As [`ErrorMap::local_bound`], with an error for a box outside the region.
    pub fn try_local_bound(&self, b: &IntervalBox) -> Result<f64, AnalysisError> {
        if self.certified_linf.is_none() {
            return Ok(f64::INFINITY);
        }
        if b.dim() != self.region.dim() || !b.is_subset_of(&self.region) {
            return Err(AnalysisError::OutsideMap {
                lower: b.lower.clone(),
                upper: b.upper.clone(),
                region_lower: self.region.lower.clone(),
                region_upper: self.region.upper.clone(),
            });
        }
        let index = self
            .index
            .0
            .get_or_init(|| CellIndex::build(&self.region, &self.cells));
        let mut worst = 0.0_f64;
        index.for_each_bucket(&b.lower, &b.upper, |k| {
            for &c in &index.cells[index.start[k] as usize..index.start[k + 1] as usize] {
                let c = &self.cells[c as usize];
                if c.meets(b) {
                    worst = worst.max(c.bound);
                }
            }
        });
        Ok(worst)
    }

    /// The map with its bucket index dropped (to be rebuilt on the next query), for a map
    /// whose `cells` were changed after a query.
    pub fn reindexed(mut self) -> ErrorMap {
        self.index = LazyIndex::default();
        self
    }
}

/// `M_C` for a scenario: its number, or `"certified"` / `"measured"` from the error map beside
/// `network` (written by `cbfreach error`).
pub fn resolve_margin(s: &Scenario, network: &Path) -> Result<f64, AnalysisError> {
    margin_value(s.reach.m_c, network)
}

/// The global `M_C` that `margin` stands for with `network`: a fixed value, or the error
/// map's certified or measured maximum, or (for local bounds) the map's largest finite cell
/// bound.
pub fn margin_value(margin: Margin, network: &Path) -> Result<f64, AnalysisError> {
    match margin {
        Margin::Value(v) => Ok(v),
        Margin::Measured => Ok(ErrorMap::load_for(network)?.measured_linf),
        Margin::Certified => {
            let map = ErrorMap::load_for(network)?;
            map.certified_linf.ok_or(AnalysisError::NotCertified {
                path: error_map_path(network),
            })
        }
        // The global number beside local bounds: the largest finite cell bound, which bounds
        // every local M a set can get without being stopped (cells with +∞ stop it).
        Margin::Local => {
            let map = ErrorMap::load_for(network)?;
            if map.certified_linf.is_none() {
                return Err(AnalysisError::NotCertified {
                    path: error_map_path(network),
                });
            }
            Ok(map.finite_max())
        }
    }
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
    fn infinite_bounds_round_trip_through_json() {
        let c = CellBound {
            lower: vec![0.0],
            upper: vec![1.0],
            bound: f64::INFINITY,
        };
        let text = serde_json::to_string(&c).unwrap();
        assert!(text.contains("\"inf\""), "{text}");
        let back: CellBound = serde_json::from_str(&text).unwrap();
        assert_eq!(back.bound, f64::INFINITY);
        assert!(
            serde_json::from_str::<CellBound>(r#"{"lower":[0],"upper":[1],"bound":"x"}"#).is_err()
        );
    }

    #[test]
    fn map_path_sits_beside_the_network() {
        assert_eq!(
            error_map_path(Path::new("scenarios/integrator.safetensors")),
            PathBuf::from("scenarios/integrator.errormap.json")
        );
    }

    #[test]
    fn centred_grid_avoids_the_ends() {
        let b = IntervalBox::new(vec![0.0], vec![1.0]).unwrap();
        let g = centred_grid(&b, &[4]);
        assert_eq!(g, vec![vec![0.125], vec![0.375], vec![0.625], vec![0.875]]);
    }
}

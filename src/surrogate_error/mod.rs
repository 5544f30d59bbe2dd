//! How far the surrogate network `N` is from the filter `v` (docs/design.md §2.1, §2b; issue 6): the
//! analysis behind `cbfreach error`, in three parts, [`measure()`], [`looseness()`] and
//! [`certify()`]. It may import the filter (and its enclosures), the network and its bounds, the
//! dataset and the error map it writes; the engines (`reach`, `gpu`) do not import it.
//!
//! * `measure`: `M_C` *measured* on a grid finer than the training grid and offset from it,
//!   over `C ∩ S` — max ℓ∞ and ℓ2 error and where they occur — and the slope error
//!   `max_ij |DN − Dv|_ij` (the largest absolute entry of the Jacobian difference, `Dv` by
//!   central differences) as median, 95th percentile and max.
//! * `looseness`: over small boxes across `C ∩ S`, the ratio of the bound width (IBP and
//!   CROWN) to the output range of `N` seen on samples of the box.
//! * `certify`: a **certified** `M_C ≥ sup_{x ∈ C ∩ S} ‖N(x) − v(x)‖∞` for the closed-form
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
//!
//! The certified per-cell bounds are stored as an [`ErrorMap`] (module [`crate::error_map`]),
//! which reachability reads; [`ErrorMap::new`] builds one from a [`Measured`] and a
//! [`Certified`].

mod certify;
mod joint;
mod looseness;
mod measure;

use std::path::Path;

use crate::bounds::{BoundMethod, BoundsError};
use crate::boxes::IntervalBox;
use crate::error_map::{ErrorMap, ErrorMapError};
use crate::network::Mlp;
use crate::network::NetworkError;
use crate::scenario::Scenario;

pub use certify::{
    cell_error_bound, cell_error_bound_mv, certify, enclosure_pieces, proven_unsafe,
    sampled_cell_error, witness_error, Certified, WITNESS_CELLS,
};
pub use looseness::{looseness, Looseness, Ratio};
pub use measure::{
    asked_counts, centred_grid, measure, measurement_counts, measurement_points, measurement_size,
    secant_slope_errors, slope_by_curvature, CurvatureBand, Measured, Percentiles,
    SlopeByCurvature, CURVATURE_BANDS, CURVATURE_POINTS, MAX_EXPLICIT_MEASUREMENT_POINTS,
    MAX_MEASUREMENT_POINTS,
};

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
    /// When every cell meets its target within the budget, cells are bisected further (the
    /// largest `bound × width` first) until the map holds this many (default 4,000), so that
    /// a set's local bound comes from cells near its own size (0: no second stage).
    pub detail_cells: usize,
    /// Priority factor of cells that meet the scenario's goal set (default 4).
    pub goal_weight: f64,
    /// Cells narrower than this are not bisected further (default 1/256, absolute): where
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
            looseness_width: 0.1,
            looseness_boxes: 300,
            looseness_samples: 16,
            seed: 0,
            local_ratio: 1.5,
            floor: 0.01,
            cell_samples: 4,
            max_cells: 24_000,
            detail_cells: 4_000,
            goal_weight: 4.0,
            cell_bounds: BoundMethod::ForwardBackward,
            min_cell: 1.0 / 256.0,
        }
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

/// `k` uniform points of `cell`, from the seeded generator of every sample in the project.
fn random_points(cell: &IntervalBox, k: usize, seed: u64) -> impl Iterator<Item = Vec<f64>> + '_ {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    (0..k).map(move |_| {
        let u: Vec<f64> = (0..cell.dim()).map(|_| rng.random::<f64>()).collect();
        cell.point_at(&u)
    })
}

/// The boxes of [`looseness()`] and of [`Measured::box_slope`] must have a positive width.
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

impl ErrorMap {
    /// A map for the network file `network` from a measurement and (optionally) a certification
    /// ([`ErrorMap::from_bounds`] with their numbers).
    pub fn new(
        network: &Path,
        region: &IntervalBox,
        measured: &Measured,
        certified: Option<&Certified>,
    ) -> Result<ErrorMap, ErrorMapError> {
        ErrorMap::from_bounds(
            network,
            region,
            measured.linf,
            measured.l2,
            certified.map(|c| (c.linf, c.cells.as_slice())),
        )
    }
}

//! Sound affine and interval bounds on a ReLU network over a box (DESIGN.md §2.2, §3, §4, §5).
//!
//! For a network `N : ℝⁿ → ℝᵐ` and a box `[x̲, x̄]` every method returns an [`AffineBounds`]:
//!
//! ```text
//!     C̲ x + d̲ ≤ N(x) ≤ C̄ x + d̄     and     lower ≤ N(x) ≤ upper     for all x ∈ [x̲, x̄]
//! ```
//!
//! with `C̲ = a_lower`, `d̲ = b_lower`, `C̄ = a_upper`, `d̄ = b_upper` (the paper's `C`, `d̲`, `d̄`;
//! with [`BoundMethod::CrownSameSlope`] `a_lower == a_upper` is the paper's single `C`).
//!
//! | method | module | what it is |
//! | --- | --- | --- |
//! | [`BoundMethod::Ibp`] | [`ibp()`] | interval bound propagation, `C = 0` |
//! | [`BoundMethod::Crown`] | [`crown()`] | backward CROWN (auto_LiRPA's `CROWN`), adaptive ReLU relaxation |
//! | [`BoundMethod::CrownSameSlope`] | [`crown()`] | backward CROWN, lower and upper lines share the chord slope |
//! | [`BoundMethod::Forward`] | [`forward()`] | forward linear bounds (auto_LiRPA's `Forward`), GEMM-batched |
//! | [`BoundMethod::ForwardBackward`] | [`forward_backward()`] | forward (∩ IBP) intermediate bounds, one backward CROWN pass from the output (auto_LiRPA's `Forward+Backward`), GEMM-batched |
//! | [`BoundMethod::ForwardBackwardSameSlope`] | [`forward_backward()`] | the same, same-slope relaxation in the backward pass: one `C` |
//!
//! # Floating-point error model (DESIGN.md §3)
//!
//! Everything is computed in f64 with round-to-nearest, and every computed bound is then widened
//! by an a-priori bound on its rounding error, so that the *returned* numbers are rigorous:
//!
//! * **Meaning of the affine forms.** `a·x + b` with the returned f64 coefficients, evaluated in
//!   *exact* real arithmetic, bounds `N(x)` for every real `x` of the box, where `N` is the exact
//!   real-arithmetic network with the stored f64 weights. (A caller evaluating the form in floating
//!   point must round outward itself.) `lower`/`upper` bound the exact `N(x)` over the box.
//! * **Dot products** (Higham, *Accuracy and Stability*, §3.1). If `ŝ` is `Σ_{j≤N} t_j` computed
//!   in any order, each term `t_j` a product of at most three floats (two roundings), with or
//!   without FMA, then `|ŝ − Σ t_j| ≤ γ_{N+2} Σ|t_j| + N·3·η` with `γ_k = k u / (1 − k u)`,
//!   `u = 2⁻⁵³`, and `η = 2⁻¹⁰⁷⁵` the absolute error of an underflowing product. We compute the
//!   magnitude sum `m̂ ≈ Σ|t_j|` alongside (for a GEMM it is `|W|·|X|`, which the centre–radius
//!   form has anyway); `m̂` is itself a sum of non-negative rounded terms, so
//!   `Σ|t_j| ≤ m̂ / (1 − γ_{N+2})`. Hence, for `N ≤ 2³⁰`,
//!   `|ŝ − Σ t_j| ≤ γ̂_N m̂ + N·2⁻¹⁰⁷²` with `γ̂_N = (N+3)·2⁻⁵²` (twice `γ_{N+3}`, which covers
//!   both `1/(1−γ)` factors). `err_bound` evaluates that bound, with the underflow part taken
//!   as `N·2⁻¹⁰²²` (a normal number: subnormal arithmetic is slow), and rounds it up. When the
//!   computed numbers are *coefficients* later multiplied by variables bounded by `mag`, the
//!   absolute (underflow) part is scaled by `1 + Σ mag`; relative errors are already carried
//!   through the magnitude sums.
//! * **Outward steps.** `fl(a + b)` is within half an ulp of `a + b`, so
//!   `next_up(fl(a + b)) ≥ a + b` and `next_down(fl(a + b)) ≤ a + b` (`add_up`, `add_down`).
//!   Every widened bound is `add_up(ŝ, err_bound(N, m̂))` or `add_down(ŝ, −err_bound(N, m̂))`.
//! * **Overflow and NaN.** Inputs and weights are checked finite. If any intermediate bound still
//!   overflows, the affected output rows are replaced by the trivially sound `(0, ∓∞)`; a NaN is
//!   never laundered into a finite bound (see `OutRow::sanitize`).
//!
//! The per-method modules document how the model is applied to their steps (relaxation lines in
//! `relu_lines`, backward products in `crown.rs`, the centre–radius forms in `forward.rs`).

mod crown;
mod forward;
mod forward_backward;
mod ibp;
mod live;
#[cfg(test)]
pub(crate) mod test_support;

pub use crown::crown;
pub use forward::forward;
pub use forward_backward::forward_backward;
pub use ibp::ibp;

use crate::network::Mlp;
use rayon::prelude::*;

/// How to bound a network over a box.
#[derive(
    Clone,
    Copy,
    Debug,
    Default,
    PartialEq,
    Eq,
    Hash,
    serde::Serialize,
    serde::Deserialize,
    clap::ValueEnum,
)]
#[serde(rename_all = "kebab-case")]
pub enum BoundMethod {
    /// Interval bound propagation: `C = 0`, `d̲, d̄` the interval bounds.
    Ibp,
    /// Backward CROWN with the adaptive ReLU relaxation (tightest; `C̲ ≠ C̄` in general).
    #[default]
    Crown,
    /// Backward CROWN with the same-slope relaxation: one `C` for both sides (the paper's theorem).
    CrownSameSlope,
    /// Forward linear bound propagation, batched as GEMMs: fast for low input dimension.
    Forward,
    /// Forward+Backward: intermediate bounds by forward propagation intersected with IBP, then
    /// one backward CROWN pass from the output (adaptive relaxation). Close to forward's cost,
    /// close to CROWN's tightness.
    ForwardBackward,
    /// Forward+Backward with the same-slope relaxation in the backward pass: one `C` for both
    /// sides.
    ForwardBackwardSameSlope,
}

impl std::fmt::Display for BoundMethod {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.name())
    }
}

impl BoundMethod {
    /// Every method, in the order of the documentation table.
    pub const ALL: [BoundMethod; 6] = [
        BoundMethod::Ibp,
        BoundMethod::Crown,
        BoundMethod::CrownSameSlope,
        BoundMethod::Forward,
        BoundMethod::ForwardBackward,
        BoundMethod::ForwardBackwardSameSlope,
    ];

    /// The command-line and JSON name (`forward-backward`, …).
    pub fn name(self) -> &'static str {
        match self {
            BoundMethod::Ibp => "ibp",
            BoundMethod::Crown => "crown",
            BoundMethod::CrownSameSlope => "crown-same-slope",
            BoundMethod::Forward => "forward",
            BoundMethod::ForwardBackward => "forward-backward",
            BoundMethod::ForwardBackwardSameSlope => "forward-backward-same-slope",
        }
    }

    /// The ReLU relaxation of the method's backward pass: same-slope for the `*-same-slope`
    /// methods, adaptive otherwise (IBP and forward have no backward pass).
    pub fn relaxation(self) -> Relaxation {
        match self {
            BoundMethod::CrownSameSlope | BoundMethod::ForwardBackwardSameSlope => {
                Relaxation::SameSlope
            }
            _ => Relaxation::Adaptive,
        }
    }
}

/// The linear relaxation of an unstable ReLU (`l < 0 < u`) used by [`crown()`].
///
/// The upper line is always the chord `u/(u−l)·(z − l)`. Stable neurons are exact (slope 0 or 1).
#[derive(
    Clone, Copy, Debug, Default, PartialEq, Eq, Hash, serde::Serialize, serde::Deserialize,
)]
#[serde(rename_all = "kebab-case")]
pub enum Relaxation {
    /// Lower line `z` if `u ≥ −l`, else `0` (auto_LiRPA's adaptive choice).
    #[default]
    Adaptive,
    /// Lower line `u/(u−l)·z`: the same slope as the upper chord, so `C̲ = C̄`.
    SameSlope,
}

/// Affine and interval bounds of a network `N : ℝⁿ → ℝᵐ` over one box.
///
/// For every `x` in the box (exact real arithmetic, see the module's error model):
/// `a_lower·x + b_lower ≤ N(x) ≤ a_upper·x + b_upper` and `lower ≤ N(x) ≤ upper`.
#[derive(Clone, Debug, PartialEq)]
pub struct AffineBounds {
    /// `C̲`, `m × n` row-major.
    pub a_lower: Vec<f64>,
    /// `d̲`, `m` entries.
    pub b_lower: Vec<f64>,
    /// `C̄`, `m × n` row-major.
    pub a_upper: Vec<f64>,
    /// `d̄`, `m` entries.
    pub b_upper: Vec<f64>,
    /// Concrete lower bounds on `N` over the box, `m` entries.
    pub lower: Vec<f64>,
    /// Concrete upper bounds on `N` over the box, `m` entries.
    pub upper: Vec<f64>,
    /// Input dimension `n`.
    pub n_in: usize,
    /// Output dimension `m`.
    pub n_out: usize,
}

impl AffineBounds {
    /// The trivially sound bounds `C = 0`, `d = ∓∞`.
    pub fn unbounded(n_in: usize, n_out: usize) -> AffineBounds {
        AffineBounds {
            a_lower: vec![0.0; n_out * n_in],
            b_lower: vec![f64::NEG_INFINITY; n_out],
            a_upper: vec![0.0; n_out * n_in],
            b_upper: vec![f64::INFINITY; n_out],
            lower: vec![f64::NEG_INFINITY; n_out],
            upper: vec![f64::INFINITY; n_out],
            n_in,
            n_out,
        }
    }

    /// Row `i` of `C̲`.
    pub fn a_lower_row(&self, i: usize) -> &[f64] {
        &self.a_lower[i * self.n_in..(i + 1) * self.n_in]
    }

    /// Row `i` of `C̄`.
    pub fn a_upper_row(&self, i: usize) -> &[f64] {
        &self.a_upper[i * self.n_in..(i + 1) * self.n_in]
    }
}

/// [`AffineBounds`] for a batch of boxes, flat and box-major, reusable across calls
/// (see [`network_bounds_batch_into`]).
///
/// Box `k`'s `C̲` is `a_lower[k·m·n .. (k+1)·m·n]` (row-major `m × n`), its `d̲` is
/// `b_lower[k·m .. (k+1)·m]`, and likewise for the other fields.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AffineBoundsBatch {
    /// `C̲` of every box, `len × m × n`.
    pub a_lower: Vec<f64>,
    /// `d̲` of every box, `len × m`.
    pub b_lower: Vec<f64>,
    /// `C̄` of every box, `len × m × n`.
    pub a_upper: Vec<f64>,
    /// `d̄` of every box, `len × m`.
    pub b_upper: Vec<f64>,
    /// Concrete lower bounds, `len × m`.
    pub lower: Vec<f64>,
    /// Concrete upper bounds, `len × m`.
    pub upper: Vec<f64>,
    /// Input dimension `n`.
    pub n_in: usize,
    /// Output dimension `m`.
    pub n_out: usize,
    /// Number of boxes.
    pub len: usize,
}

impl AffineBoundsBatch {
    /// An empty batch (no allocation until the first use).
    pub fn new() -> AffineBoundsBatch {
        AffineBoundsBatch::default()
    }

    /// Number of boxes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the batch holds no boxes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// A copy of box `k`'s bounds, or `None` past the end.
    pub fn get(&self, k: usize) -> Option<AffineBounds> {
        if k >= self.len {
            return None;
        }
        let (mn, m) = (self.n_out * self.n_in, self.n_out);
        Some(AffineBounds {
            a_lower: self.a_lower[k * mn..(k + 1) * mn].to_vec(),
            b_lower: self.b_lower[k * m..(k + 1) * m].to_vec(),
            a_upper: self.a_upper[k * mn..(k + 1) * mn].to_vec(),
            b_upper: self.b_upper[k * m..(k + 1) * m].to_vec(),
            lower: self.lower[k * m..(k + 1) * m].to_vec(),
            upper: self.upper[k * m..(k + 1) * m].to_vec(),
            n_in: self.n_in,
            n_out: self.n_out,
        })
    }

    /// Every box's bounds as separate [`AffineBounds`].
    pub fn to_vec(&self) -> Vec<AffineBounds> {
        (0..self.len).filter_map(|k| self.get(k)).collect()
    }

    /// Resizes for `len` boxes, keeping allocations; contents are overwritten by the caller.
    fn reset(&mut self, n_in: usize, n_out: usize, len: usize) {
        self.n_in = n_in;
        self.n_out = n_out;
        self.len = len;
        for v in [&mut self.a_lower, &mut self.a_upper] {
            v.clear();
            v.resize(len * n_out * n_in, 0.0);
        }
        for v in [
            &mut self.b_lower,
            &mut self.b_upper,
            &mut self.lower,
            &mut self.upper,
        ] {
            v.clear();
            v.resize(len * n_out, 0.0);
        }
    }

    /// One [`OutRow`] view per box.
    fn rows_mut(&mut self) -> Vec<OutRow<'_>> {
        let (mn, m) = ((self.n_out * self.n_in).max(1), self.n_out.max(1));
        let n_in = self.n_in;
        self.a_lower
            .chunks_mut(mn)
            .zip(self.b_lower.chunks_mut(m))
            .zip(self.a_upper.chunks_mut(mn))
            .zip(self.b_upper.chunks_mut(m))
            .zip(self.lower.chunks_mut(m))
            .zip(self.upper.chunks_mut(m))
            .map(
                |(((((a_lower, b_lower), a_upper), b_upper), lower), upper)| OutRow {
                    a_lower,
                    b_lower,
                    a_upper,
                    b_upper,
                    lower,
                    upper,
                    n_in,
                },
            )
            .collect()
    }
}

/// A caller error in the arguments of a bounds computation.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BoundsError {
    /// The network has no layers.
    #[error("the network has no layers")]
    EmptyNetwork,
    /// A layer's shapes are inconsistent or its weights are not finite.
    #[error("network layer {layer}: {reason}")]
    InvalidNetwork {
        /// Index of the layer (input first).
        layer: usize,
        /// What is wrong.
        reason: String,
    },
    /// The box's dimension differs from the network's input dimension.
    #[error("box has {got} coordinates but the network's input dimension is {expected}")]
    DimensionMismatch {
        /// The network's input dimension.
        expected: usize,
        /// The box's dimension.
        got: usize,
    },
    /// A flat batch's `lower` and `upper` have different lengths or are not whole boxes.
    #[error(
        "batch: lower has {lower_len} values and upper {upper_len}; both must be the same \
         multiple of the input dimension {n_in}"
    )]
    BatchShape {
        /// Length of the flat lower array.
        lower_len: usize,
        /// Length of the flat upper array.
        upper_len: usize,
        /// The network's input dimension.
        n_in: usize,
    },
    /// A box coordinate is NaN or infinite.
    #[error("box {box_index}, coordinate {coord}: bounds [{lower}, {upper}] are not finite")]
    NonFiniteBox {
        /// Index of the box in the batch (0 for a single box).
        box_index: usize,
        /// The coordinate.
        coord: usize,
        /// Its lower bound.
        lower: f64,
        /// Its upper bound.
        upper: f64,
    },
    /// A box coordinate has `lower > upper`.
    #[error(
        "box {box_index}, coordinate {coord}: lower bound {lower} exceeds upper bound {upper}"
    )]
    InvertedBox {
        /// Index of the box in the batch (0 for a single box).
        box_index: usize,
        /// The coordinate.
        coord: usize,
        /// Its lower bound.
        lower: f64,
        /// Its upper bound.
        upper: f64,
    },
}

/// Multiply–adds per box of a bound method on a network with widths `n_0..n_L`, by DESIGN §5's
/// model (forward: centre and radius forms, `2(n_in+1)+1` products per weight with the rounding
/// magnitudes; CROWN: `Σ_k n_k Σ_{j<k} n_j n_{j−1}` per backward pass, two passes for the
/// adaptive relaxation). Benchmarks turn it into GFLOP/s as `2 × this × boxes/s`.
pub fn model_multiply_adds(widths: &[usize], method: BoundMethod) -> f64 {
    let n_in = widths[0];
    let m = widths[widths.len() - 1];
    let pairs: f64 = widths.windows(2).map(|w| (w[0] * w[1]) as f64).sum();
    let crown_pass: f64 = (1..widths.len())
        .map(|k| {
            widths[k] as f64
                * (1..k)
                    .map(|j| (widths[j] * widths[j - 1]) as f64)
                    .sum::<f64>()
        })
        .sum();
    let fwd = (2 * (n_in + 1) + 1) as f64 * pairs;
    match method {
        BoundMethod::Ibp => 3.0 * pairs,
        BoundMethod::Forward => fwd,
        BoundMethod::ForwardBackward => fwd + (3 + 1 + 2 * m) as f64 * pairs,
        BoundMethod::ForwardBackwardSameSlope => fwd + (3 + 1 + m) as f64 * pairs,
        BoundMethod::Crown => 2.0 * crown_pass,
        BoundMethod::CrownSameSlope => crown_pass,
    }
}

/// Where the groups of a batch run: in parallel (rayon, a fresh workspace per task), or one
/// after another in the calling thread with the caller's workspace (a reach engine that gives
/// each thread its own boxes for the whole horizon, with no fork–join per Euler step).
pub(crate) enum Schedule<'w, W> {
    Parallel,
    Serial(&'w mut W),
}

/// Runs `group_fn` on groups of at most `max_group` boxes as `schedule` says (in parallel, one
/// rayon task per group, each with its own workspace from `W::default()`), then sanitises every
/// row. Shared by the GEMM-batched methods (IBP, forward, forward-backward): a group is one set
/// of matrix products whose columns are boxes.
pub(crate) fn for_each_group<W: Default + Send>(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    max_group: usize,
    schedule: Schedule<'_, W>,
    group_fn: impl Fn(&mut W, &[f64], &[f64], &mut [OutRow<'_>]) + Sync + Send,
) {
    let n0 = net.input_dim();
    if rows.is_empty() {
        return;
    }
    let run = |ws: &mut W, ((rows, lo), hi): ((&mut [OutRow<'_>], &[f64]), &[f64])| {
        group_fn(ws, lo, hi, rows);
        rows.iter_mut().for_each(|row| row.sanitize());
    };
    match schedule {
        Schedule::Serial(ws) => rows
            .chunks_mut(max_group)
            .zip(lower.chunks(max_group * n0))
            .zip(upper.chunks(max_group * n0))
            .for_each(|group| run(ws, group)),
        Schedule::Parallel => {
            let threads = rayon::current_num_threads().max(1);
            let group = rows.len().div_ceil(threads).clamp(1, max_group);
            rows.par_chunks_mut(group)
                .zip(lower.par_chunks(group * n0))
                .zip(upper.par_chunks(group * n0))
                .for_each_init(W::default, run);
        }
    }
}

/// Bounds of `net` over the box `[lower, upper]` by `method`, validated.
pub fn network_bounds(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    method: BoundMethod,
) -> Result<AffineBounds, BoundsError> {
    PreparedNetwork::new(net)?.bounds(lower, upper, method)
}

/// Bounds of `net` over a batch of boxes given flat and box-major: box `k` is
/// `[lower[k·n .. (k+1)·n], upper[k·n .. (k+1)·n]]`, `n = net.input_dim()`.
pub fn network_bounds_batch(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    method: BoundMethod,
) -> Result<AffineBoundsBatch, BoundsError> {
    let mut out = AffineBoundsBatch::new();
    network_bounds_batch_into(net, lower, upper, method, &mut out)?;
    Ok(out)
}

/// As [`network_bounds_batch`], writing into `out` and reusing its allocations.
///
/// Checks the whole network on every call; a reach engine that bounds boxes every Euler step
/// prepares it once with [`PreparedNetwork`] instead.
pub fn network_bounds_batch_into(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    method: BoundMethod,
    out: &mut AffineBoundsBatch,
) -> Result<(), BoundsError> {
    PreparedNetwork::new(net)?.bounds_batch_into(lower, upper, method, out)
}

/// A network checked once for bounding (shapes, widths, finite weights) with `|W_k|` of every
/// layer computed once: what a loop that bounds many batches of boxes holds.
///
/// It borrows the network, so the weights cannot change while `|W|` is kept.
pub struct PreparedNetwork<'a> {
    net: &'a Mlp,
    /// `|W_k|` of every layer, row-major like `W_k`.
    pub(crate) abs_w: Vec<Vec<f64>>,
}

impl<'a> PreparedNetwork<'a> {
    /// Checks `net` ([`BoundsError::InvalidNetwork`], [`BoundsError::EmptyNetwork`]) and
    /// computes `|W|`.
    pub fn new(net: &'a Mlp) -> Result<PreparedNetwork<'a>, BoundsError> {
        validate_network(net)?;
        let abs_w = net
            .layers
            .iter()
            .map(|l| l.weight.iter().map(|w| w.abs()).collect())
            .collect();
        Ok(PreparedNetwork { net, abs_w })
    }

    /// The network.
    pub fn net(&self) -> &'a Mlp {
        self.net
    }

    /// Bounds over one box, as [`network_bounds`].
    pub fn bounds(
        &self,
        lower: &[f64],
        upper: &[f64],
        method: BoundMethod,
    ) -> Result<AffineBounds, BoundsError> {
        let mut out = AffineBoundsBatch::new();
        self.bounds_batch_into(lower, upper, method, &mut out)?;
        out.get(0).ok_or(BoundsError::BatchShape {
            lower_len: lower.len(),
            upper_len: upper.len(),
            n_in: self.net.input_dim(),
        })
    }

    /// Bounds over a batch of boxes given flat and box-major, as [`network_bounds_batch`],
    /// writing into `out` and reusing its allocations.
    ///
    /// Boxes run in parallel (rayon): one box per task for CROWN, groups of boxes as GEMMs for
    /// [`BoundMethod::Ibp`], [`BoundMethod::Forward`] and the Forward+Backward methods.
    pub fn bounds_batch_into(
        &self,
        lower: &[f64],
        upper: &[f64],
        method: BoundMethod,
        out: &mut AffineBoundsBatch,
    ) -> Result<(), BoundsError> {
        self.run_batch(lower, upper, method, None, out)
    }

    /// As [`PreparedNetwork::bounds_batch_into`], but in the calling thread with the buffers
    /// of `ws`: for callers that parallelise over batches themselves (the CPU reach engine runs
    /// each thread's boxes for the whole horizon), so that no step pays a fork–join or fresh
    /// buffers. Same bounds as the parallel call, up to the summation order of the products.
    pub fn bounds_serial_into(
        &self,
        lower: &[f64],
        upper: &[f64],
        method: BoundMethod,
        ws: &mut BoundsWorkspace,
        out: &mut AffineBoundsBatch,
    ) -> Result<(), BoundsError> {
        self.run_batch(lower, upper, method, Some(ws), out)
    }

    /// The validated batch, in parallel (`ws` = `None`) or serially in `ws`.
    fn run_batch(
        &self,
        lower: &[f64],
        upper: &[f64],
        method: BoundMethod,
        ws: Option<&mut BoundsWorkspace>,
        out: &mut AffineBoundsBatch,
    ) -> Result<(), BoundsError> {
        fn schedule<W>(ws: Option<&mut W>) -> Schedule<'_, W> {
            ws.map_or(Schedule::Parallel, Schedule::Serial)
        }
        let net = self.net;
        let n_boxes = validate_boxes(net, lower, upper)?;
        let (n_in, n_out) = (net.input_dim(), net.output_dim());
        out.reset(n_in, n_out, n_boxes);
        let mut rows = out.rows_mut();
        rows.truncate(n_boxes);
        match method {
            BoundMethod::Ibp => {
                let ws = schedule(ws.map(|w| &mut w.ibp));
                ibp::ibp_batch_into(self, lower, upper, ws, &mut rows)
            }
            BoundMethod::Crown | BoundMethod::CrownSameSlope => {
                let relaxation = method.relaxation();
                let ws = ws.map(|w| w.crown.get_or_insert_with(|| crown::Workspace::new(net)));
                run_per_box(
                    net,
                    lower,
                    upper,
                    &mut rows,
                    ws,
                    || crown::Workspace::new(net),
                    |ws, lo, hi, row| crown::crown_into(net, lo, hi, relaxation, ws, row),
                )
            }
            BoundMethod::Forward => {
                let ws = schedule(ws.map(|w| &mut w.forward));
                forward::forward_batch_into(self, lower, upper, ws, &mut rows)
            }
            BoundMethod::ForwardBackward | BoundMethod::ForwardBackwardSameSlope => {
                let ws = schedule(ws.map(|w| &mut w.forward_backward));
                let relaxation = method.relaxation();
                forward_backward::forward_backward_batch_into(
                    self, lower, upper, relaxation, ws, &mut rows,
                )
            }
        }
        Ok(())
    }
}

/// The buffers of every bound method for [`PreparedNetwork::bounds_serial_into`]: one per
/// thread, reused across calls (they grow to the largest batch and stay).
#[derive(Default)]
pub struct BoundsWorkspace {
    ibp: ibp::Workspace,
    forward: forward::Workspace,
    forward_backward: forward_backward::Workspace,
    crown: Option<crown::Workspace>,
}

/// Runs `f` on every box: in parallel with one workspace per rayon task from `init`, or one
/// after another in `serial`.
fn run_per_box<W, I, F>(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    serial: Option<&mut W>,
    init: I,
    f: F,
) where
    I: Fn() -> W + Sync + Send,
    F: Fn(&mut W, &[f64], &[f64], &mut OutRow<'_>) + Sync + Send,
{
    let n = net.input_dim();
    let run = |ws: &mut W, ((row, lo), hi): ((&mut OutRow<'_>, &[f64]), &[f64])| {
        f(ws, lo, hi, row);
        row.sanitize();
    };
    match serial {
        Some(ws) => rows
            .iter_mut()
            .zip(lower.chunks(n))
            .zip(upper.chunks(n))
            .for_each(|one| run(ws, one)),
        None => rows
            .par_iter_mut()
            .zip(lower.par_chunks(n))
            .zip(upper.par_chunks(n))
            .for_each_init(init, run),
    }
}

/// Largest layer width (and input dimension) the error model is stated for.
const MAX_WIDTH: usize = 1 << 30;

/// Checks the flat batch of boxes against a checked network; returns the number of boxes.
fn validate_boxes(net: &Mlp, lower: &[f64], upper: &[f64]) -> Result<usize, BoundsError> {
    let n = net.input_dim();
    if lower.len() != upper.len() || lower.len() % n != 0 {
        return Err(BoundsError::BatchShape {
            lower_len: lower.len(),
            upper_len: upper.len(),
            n_in: n,
        });
    }
    for (idx, (&l, &u)) in lower.iter().zip(upper).enumerate() {
        let (box_index, coord) = (idx / n, idx % n);
        if !l.is_finite() || !u.is_finite() {
            return Err(BoundsError::NonFiniteBox {
                box_index,
                coord,
                lower: l,
                upper: u,
            });
        }
        if l > u {
            return Err(BoundsError::InvertedBox {
                box_index,
                coord,
                lower: l,
                upper: u,
            });
        }
    }
    Ok(lower.len() / n)
}

/// Checks shapes (each layer's input is the previous output), widths and finiteness.
fn validate_network(net: &Mlp) -> Result<(), BoundsError> {
    if net.layers.is_empty() {
        return Err(BoundsError::EmptyNetwork);
    }
    let invalid = |layer: usize, reason: String| BoundsError::InvalidNetwork { layer, reason };
    for (k, layer) in net.layers.iter().enumerate() {
        if layer.n_in == 0 || layer.n_out == 0 {
            return Err(invalid(k, "zero width".into()));
        }
        if layer.n_in > MAX_WIDTH || layer.n_out > MAX_WIDTH {
            return Err(invalid(k, format!("width above {MAX_WIDTH}")));
        }
        if layer.weight.len() != layer.n_in * layer.n_out {
            return Err(invalid(
                k,
                format!(
                    "weight has {} entries, expected {} × {}",
                    layer.weight.len(),
                    layer.n_out,
                    layer.n_in
                ),
            ));
        }
        if layer.bias.len() != layer.n_out {
            return Err(invalid(
                k,
                format!(
                    "bias has {} entries, expected {}",
                    layer.bias.len(),
                    layer.n_out
                ),
            ));
        }
        if k > 0 && net.layers[k - 1].n_out != layer.n_in {
            return Err(invalid(
                k,
                format!(
                    "input width {} differs from the previous layer's output width {}",
                    layer.n_in,
                    net.layers[k - 1].n_out
                ),
            ));
        }
        if let Some(j) = layer.weight.iter().position(|w| !w.is_finite()) {
            return Err(invalid(k, format!("weight entry {j} is not finite")));
        }
        if let Some(j) = layer.bias.iter().position(|b| !b.is_finite()) {
            return Err(invalid(k, format!("bias entry {j} is not finite")));
        }
    }
    Ok(())
}

/// Mutable view of one box's output inside an [`AffineBoundsBatch`].
pub(crate) struct OutRow<'a> {
    pub(crate) a_lower: &'a mut [f64],
    pub(crate) b_lower: &'a mut [f64],
    pub(crate) a_upper: &'a mut [f64],
    pub(crate) b_upper: &'a mut [f64],
    pub(crate) lower: &'a mut [f64],
    pub(crate) upper: &'a mut [f64],
    pub(crate) n_in: usize,
}

impl OutRow<'_> {
    /// Replaces every output row with a non-finite coefficient or bound (overflow, NaN) by the
    /// trivially sound `(0, ∓∞)`. NaN never compares, so `is_finite` catches it.
    pub(crate) fn sanitize(&mut self) {
        let n = self.n_in;
        for i in 0..self.lower.len() {
            let a = &mut self.a_lower[i * n..(i + 1) * n];
            if !(self.b_lower[i].is_finite()
                && self.lower[i].is_finite()
                && a.iter().all(|v| v.is_finite()))
            {
                a.fill(0.0);
                self.b_lower[i] = f64::NEG_INFINITY;
                self.lower[i] = f64::NEG_INFINITY;
            }
            let a = &mut self.a_upper[i * n..(i + 1) * n];
            if !(self.b_upper[i].is_finite()
                && self.upper[i].is_finite()
                && a.iter().all(|v| v.is_finite()))
            {
                a.fill(0.0);
                self.b_upper[i] = f64::INFINITY;
                self.upper[i] = f64::INFINITY;
            }
        }
    }

    /// Sets every row to `(0, ∓∞)`.
    pub(crate) fn set_unbounded(&mut self) {
        self.a_lower.fill(0.0);
        self.a_upper.fill(0.0);
        self.b_lower.fill(f64::NEG_INFINITY);
        self.lower.fill(f64::NEG_INFINITY);
        self.b_upper.fill(f64::INFINITY);
        self.upper.fill(f64::INFINITY);
    }
}

// ---------------------------------------------------------------------------------------------
// Rounding model (see the module documentation).
// ---------------------------------------------------------------------------------------------

/// The next f64 above `x` (`x` itself for `+∞` and NaN).
#[inline]
pub(crate) fn next_up(x: f64) -> f64 {
    if x.is_nan() || x == f64::INFINITY {
        return x;
    }
    if x == 0.0 {
        return f64::from_bits(1);
    }
    let bits = x.to_bits();
    if x > 0.0 {
        f64::from_bits(bits + 1)
    } else {
        f64::from_bits(bits - 1)
    }
}

/// `next_up(x)` for a computed difference `x = fl(a − b)` of floats `a ≥ b`, or a computed sum
/// of non-negative floats, except that 0 stays 0. With gradual underflow such an `x` is 0 only
/// when the exact result is, so 0 needs no widening; `next_up(0)` would be a subnormal, and
/// every product with a subnormal costs a ~100-cycle microcode assist on x86 (the flat
/// coordinate of a face box, the IBP radius of a dead neuron).
#[inline]
pub(crate) fn next_up_keep_zero(x: f64) -> f64 {
    if x == 0.0 {
        0.0
    } else {
        next_up(x)
    }
}

/// The next f64 below `x`.
#[inline]
pub(crate) fn next_down(x: f64) -> f64 {
    -next_up(-x)
}

/// An upper bound of the real `a + b`.
#[inline]
pub(crate) fn add_up(a: f64, b: f64) -> f64 {
    next_up(a + b)
}

/// A lower bound of the real `a + b`.
#[inline]
pub(crate) fn add_down(a: f64, b: f64) -> f64 {
    next_down(a + b)
}

/// `γ̂_N = (N + 3)·2⁻⁵²`, exact in f64 (module documentation).
#[inline]
pub(crate) fn gamma_hat(n_terms: usize) -> f64 {
    (n_terms as f64 + 3.0) * f64::EPSILON
}

/// Rigorous bound on the rounding error of a computed sum of `n_terms` products of at most three
/// floats whose computed magnitude sum is `magnitude`: `γ̂_N·m̂ + N·2⁻¹⁰²²·scale`, rounded up.
///
/// `scale ≥ 1` bounds what an underflowing coefficient is later multiplied by (`1` for a plain
/// sum; `1 + Σ mag` when the computed numbers are coefficients of variables bounded by `mag`):
/// each underflowing product errs by at most `2⁻¹⁰⁷⁵` absolutely, at most 8 per term, so
/// `N·2⁻¹⁰⁷²·scale` would do. The term is taken 2⁵⁰ times larger, `N·2⁻¹⁰²²·scale`, because
/// that is a normal number: arithmetic on subnormals takes a microcode assist of ~100 cycles on
/// x86, and this one product was a quarter of the forward method's time.
#[inline]
pub(crate) fn err_bound(n_terms: usize, magnitude: f64, scale: f64) -> f64 {
    // `N·2⁻¹⁰²²` is exact (N < 2⁵³); the product with `scale ≥ 1` is normal, and rounding it to
    // nearest loses at most a factor 1 − 2⁻⁵³ of a term 2⁵⁰ times larger than needed.
    let underflow = n_terms as f64 * f64::MIN_POSITIVE * scale;
    next_up(next_up(gamma_hat(n_terms) * magnitude) + underflow)
}

/// Slopes below this are flushed to zero in `relu_lines`.
const TINY_SLOPE: f64 = 1e-290;

/// A rigorous upper bound of `max_{x∈[lo,hi]} w·x + b`; `mag[p] ≥ max(|lo[p]|, |hi[p]|)`.
#[inline]
pub(crate) fn affine_max(w: &[f64], b: f64, lo: &[f64], hi: &[f64], mag: &[f64]) -> f64 {
    let (mut s, mut m) = (b, b.abs());
    for p in 0..w.len() {
        let wp = w[p];
        s += if wp >= 0.0 { wp * hi[p] } else { wp * lo[p] };
        m += wp.abs() * mag[p];
    }
    add_up(s, err_bound(w.len() + 1, m, 1.0))
}

/// A rigorous lower bound of `min_{x∈[lo,hi]} w·x + b`; `mag[p] ≥ max(|lo[p]|, |hi[p]|)`.
#[inline]
pub(crate) fn affine_min(w: &[f64], b: f64, lo: &[f64], hi: &[f64], mag: &[f64]) -> f64 {
    let (mut s, mut m) = (b, b.abs());
    for p in 0..w.len() {
        let wp = w[p];
        s += if wp >= 0.0 { wp * lo[p] } else { wp * hi[p] };
        m += wp.abs() * mag[p];
    }
    add_down(s, -err_bound(w.len() + 1, m, 1.0))
}

/// `max(|lo|, |hi|)` per coordinate (exact).
pub(crate) fn magnitudes(lo: &[f64], hi: &[f64], mag: &mut Vec<f64>) {
    mag.clear();
    mag.extend(lo.iter().zip(hi).map(|(l, h)| l.abs().max(h.abs())));
}

/// Linear relaxation lines of `ReLU` on a pre-activation interval `[l, u]`:
/// `s̲·z ≤ ReLU(z) ≤ s̄·z + t̄` for every real `z ∈ [l, u]`, rigorously despite rounding.
///
/// Returns `(s̲, s̄, t̄)`. Stable neurons are exact: `(1, 1, 0)` for `l ≥ 0`, `(0, 0, 0)` for
/// `u ≤ 0`. For unstable ones the chord slope `s = u/(u−l)` is computed in floating point and
/// clamped to `[0, 1]`; then
/// * the lower line `s̲·z` with any `s̲ ∈ [0, 1]` (no intercept) is below ReLU on all of ℝ:
///   `s̲z ≤ 0` for `z ≤ 0` and `s̲z ≤ z` for `z ≥ 0` — so the rounded slope needs no correction;
/// * for the upper line with the rounded slope `s̄`, the intercept is chosen as
///   `t̄ = max(ReLU(l) − s̄l, ReLU(u) − s̄u)` rounded up, so the line lies above ReLU at both
///   endpoints, hence (ReLU being convex) on all of `[l, u]`. `−s̄l` is bounded above by
///   `next_up(fl(−s̄l))`; `u − s̄u` by `next_up(fl(u − next_down(fl(s̄u))))`.
#[inline]
pub(crate) fn relu_lines(l: f64, u: f64, relaxation: Relaxation) -> (f64, f64, f64) {
    if l >= 0.0 {
        return (1.0, 1.0, 0.0);
    }
    if u <= 0.0 {
        return (0.0, 0.0, 0.0);
    }
    // Slopes below 1e-290 are flushed to 0 (still a valid slope, with the intercept below), so
    // that no slope is subnormal and the relative error model holds for products with it.
    let s = (u / (u - l)).clamp(0.0, 1.0);
    let s = if s < TINY_SLOPE { 0.0 } else { s };
    let t = next_up(-s * l).max(next_up(u - next_down(s * u)));
    let s_lower = match relaxation {
        Relaxation::Adaptive => {
            if u >= -l {
                1.0
            } else {
                0.0
            }
        }
        Relaxation::SameSlope => s,
    };
    (s_lower, s, t)
}

/// `C = A·B` for row-major `A (m×k)`, `B (k×n)`, `C (m×n)`, single-threaded (the bound
/// methods run one group of boxes per rayon task).
pub(crate) fn gemm(m: usize, k: usize, n: usize, a: &[f64], b: &[f64], c: &mut [f64]) {
    crate::matmul::matmul((m, k, n), a, b, c, crate::matmul::Threads::One);
}

#[cfg(test)]
mod tests {
    use super::test_support::Dd;
    use super::*;

    /// The serial schedule (one workspace reused across calls, methods and batch sizes) gives
    /// the parallel schedule's bounds: sound at sampled points and equal up to the summation
    /// order of the products (groups are cut differently).
    #[test]
    fn serial_bounds_match_parallel_with_a_reused_workspace() {
        use test_support::{case_rng, check_bounds, random_box, sample_points, BoxKind};
        let net = Mlp::random(&[2, 24, 24, 3], 5);
        let prepared = PreparedNetwork::new(&net).unwrap();
        let mut rng = case_rng(11);
        let mut ws = BoundsWorkspace::default();
        let (mut serial, mut parallel) = (AffineBoundsBatch::new(), AffineBoundsBatch::new());
        // Large batch first, so that later smaller ones run on grown, stale buffers.
        for (round, n_boxes) in [300, 7, 130, 1].into_iter().enumerate() {
            let (mut lo, mut hi, mut points) = (Vec::new(), Vec::new(), Vec::new());
            for b in 0..n_boxes {
                let kind = BoxKind::ALL[(b + round) % BoxKind::ALL.len()];
                let (l, h) = random_box(&mut rng, 2, kind);
                points.push(sample_points(&mut rng, &l, &h, 6));
                lo.extend(l);
                hi.extend(h);
            }
            for method in BoundMethod::ALL {
                prepared
                    .bounds_serial_into(&lo, &hi, method, &mut ws, &mut serial)
                    .unwrap();
                prepared
                    .bounds_batch_into(&lo, &hi, method, &mut parallel)
                    .unwrap();
                assert_eq!(serial.len(), n_boxes);
                for k in 0..n_boxes {
                    let (s, p) = (serial.get(k).unwrap(), parallel.get(k).unwrap());
                    let (l, h) = (&lo[2 * k..2 * k + 2], &hi[2 * k..2 * k + 2]);
                    check_bounds(&net, l, h, &s, &points[k])
                        .unwrap_or_else(|e| panic!("{method}, box {k} of {n_boxes}: {e}"));
                    let pairs = [
                        (&s.lower, &p.lower),
                        (&s.upper, &p.upper),
                        (&s.a_lower, &p.a_lower),
                        (&s.a_upper, &p.a_upper),
                        (&s.b_lower, &p.b_lower),
                        (&s.b_upper, &p.b_upper),
                    ];
                    for (a, b) in pairs {
                        for (x, y) in a.iter().zip(b.iter()) {
                            let tol = 1e-12 * (1.0 + x.abs().max(y.abs()));
                            assert!(
                                (x - y).abs() <= tol,
                                "{method}, box {k} of {n_boxes}: serial {x} vs parallel {y}"
                            );
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn next_up_down_step_one_ulp() {
        assert_eq!(next_up(1.0), 1.0 + f64::EPSILON);
        assert_eq!(next_down(1.0), 1.0 - f64::EPSILON / 2.0);
        assert_eq!(next_up(0.0), f64::from_bits(1));
        assert_eq!(next_up(-0.0), f64::from_bits(1));
        assert_eq!(next_down(0.0), -f64::from_bits(1));
        assert_eq!(next_up(-f64::from_bits(1)), 0.0);
        assert_eq!(next_up(f64::MAX), f64::INFINITY);
        assert_eq!(next_up(f64::INFINITY), f64::INFINITY);
        assert_eq!(next_down(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert!(next_up(f64::NAN).is_nan());
    }

    #[test]
    fn relu_lines_are_valid_at_many_points() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
        for _ in 0..20_000 {
            let scale = 10f64.powi(rng.random_range(-12..6));
            let l = -rng.random::<f64>() * scale;
            let u = rng.random::<f64>() * scale * 10f64.powi(rng.random_range(-6..6));
            for relaxation in [Relaxation::Adaptive, Relaxation::SameSlope] {
                let (sl, su, t) = relu_lines(l, u, relaxation);
                assert!((0.0..=1.0).contains(&sl) && (0.0..=1.0).contains(&su) && t >= 0.0);
                // Checked in double-double, i.e. essentially in exact arithmetic.
                for z in [
                    l,
                    u,
                    0.0,
                    l / 2.0,
                    u / 2.0,
                    l + rng.random::<f64>() * (u - l),
                ] {
                    let r = Dd::from(z.max(0.0));
                    let upper_line = Dd::from(z).mul_f64(su).add(Dd::from(t));
                    assert!(r.le(upper_line), "upper line at {z} for [{l}, {u}]");
                    assert!(
                        Dd::from(z).mul_f64(sl).le(r),
                        "lower line at {z} for [{l}, {u}]"
                    );
                }
            }
        }
    }

    #[test]
    fn validation_names_the_coordinate() {
        let net = Mlp::random(&[2, 4, 1], 0);
        let err = network_bounds(&net, &[0.0, 1.0], &[1.0, 0.5], BoundMethod::Ibp).unwrap_err();
        assert_eq!(
            err,
            BoundsError::InvertedBox {
                box_index: 0,
                coord: 1,
                lower: 1.0,
                upper: 0.5
            }
        );
        assert!(err.to_string().contains("coordinate 1"));
        let err = network_bounds(&net, &[f64::NAN, 0.0], &[1.0, 0.5], BoundMethod::Crown);
        assert!(matches!(
            err,
            Err(BoundsError::NonFiniteBox { coord: 0, .. })
        ));
        let err = network_bounds(&net, &[0.0], &[1.0], BoundMethod::Forward);
        assert!(matches!(err, Err(BoundsError::BatchShape { .. })));
        let err = network_bounds_batch(&net, &[0.0; 4], &[1.0; 6], BoundMethod::Forward);
        assert!(matches!(err, Err(BoundsError::BatchShape { .. })));
        let mut bad = net.clone();
        bad.layers[1].n_in = 3;
        let err = network_bounds(&bad, &[0.0; 2], &[1.0; 2], BoundMethod::Crown);
        assert!(matches!(
            err,
            Err(BoundsError::InvalidNetwork { layer: 1, .. })
        ));
        let err = network_bounds(&Mlp { layers: vec![] }, &[], &[], BoundMethod::Crown);
        assert_eq!(err, Err(BoundsError::EmptyNetwork));
        let err = network_bounds_batch(&net, &[], &[], BoundMethod::Crown).map(|b| b.len());
        assert_eq!(err, Ok(0));
    }

    /// Throughput on the paper's 2×400×400×400×2 network, with the FLOP model of DESIGN.md §5.
    /// `cargo test --release --lib bounds::tests::bench_paper_network -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn bench_paper_network() {
        use std::time::Instant;
        let widths = [2usize, 400, 400, 400, 2];
        let net = Mlp::random(&widths, 1);
        let n_in = widths[0];
        let pairs: f64 = widths.windows(2).map(|w| (w[0] * w[1]) as f64).sum();
        // Forward: centre and radius GEMMs plus the magnitude GEMM, per box.
        let fwd_madds = (2 * (n_in + 1) + 1) as f64 * pairs;
        // CROWN: Σ_k n_k Σ_{j<k} n_j n_{j−1} per pass (layer k's rows times the products below).
        let crown_pass: f64 = (1..widths.len())
            .map(|k| {
                widths[k] as f64
                    * (1..k)
                        .map(|j| (widths[j] * widths[j - 1]) as f64)
                        .sum::<f64>()
            })
            .sum();
        // Forward+Backward: forward forms, IBP (3 columns), the backward magnitudes (1 column)
        // and R = 2m (adaptive) or m backward rows.
        let m_out = widths[widths.len() - 1];
        let fb_madds = |r: usize| (2 * (n_in + 1) + 1 + 3 + 1 + r) as f64 * pairs;
        for width in [0.5, 0.01] {
            let mut rng = test_support::case_rng(3);
            let (mut lo, mut hi) = (Vec::new(), Vec::new());
            for _ in 0..2048 {
                let (l, h) = test_support::random_box(&mut rng, 2, test_support::BoxKind::Wide);
                let c = [0.5 * (l[0] + h[0]), 0.5 * (l[1] + h[1])];
                lo.extend(c.iter().map(|c| c - width / 2.0));
                hi.extend(c.iter().map(|c| c + width / 2.0));
            }
            // Tightness on the first 32 boxes, against CROWN.
            let n_tight = 32;
            let crown_ref = network_bounds_batch(
                &net,
                &lo[..2 * n_tight],
                &hi[..2 * n_tight],
                BoundMethod::Crown,
            )
            .unwrap();
            for (method, n_boxes, madds) in [
                (BoundMethod::Ibp, 2048, 3.0 * pairs),
                (BoundMethod::Forward, 2048, fwd_madds),
                (BoundMethod::ForwardBackward, 2048, fb_madds(2 * m_out)),
                (BoundMethod::ForwardBackwardSameSlope, 2048, fb_madds(m_out)),
                (BoundMethod::CrownSameSlope, 16, crown_pass),
                (BoundMethod::Crown, 16, 2.0 * crown_pass),
            ] {
                let (lo, hi) = (&lo[..2 * n_boxes], &hi[..2 * n_boxes]);
                let mut out = AffineBoundsBatch::new();
                network_bounds_batch_into(&net, lo, hi, method, &mut out).unwrap();
                let t = Instant::now();
                let reps = 3;
                for _ in 0..reps {
                    network_bounds_batch_into(&net, lo, hi, method, &mut out).unwrap();
                }
                let secs = t.elapsed().as_secs_f64() / reps as f64;
                let per_s = n_boxes as f64 / secs;
                let tight = network_bounds_batch(
                    &net,
                    &lo[..2 * n_tight.min(n_boxes)],
                    &hi[..2 * n_tight.min(n_boxes)],
                    method,
                )
                .unwrap();
                let (mut log_ratio, mut n_ratio) = (0.0, 0);
                for o in 0..tight.upper.len() {
                    let wc = crown_ref.upper[o] - crown_ref.lower[o];
                    if wc > 0.0 {
                        log_ratio += ((tight.upper[o] - tight.lower[o]) / wc).ln();
                        n_ratio += 1;
                    }
                }
                eprintln!(
                    "{:<28} box width {width}: {per_s:>8.0} boxes/s ({n_boxes} boxes, {:.3} ms \
                     each), model {:.2} M mult-adds/box -> {:.2} GFLOP/s; width / crown width \
                     (geometric mean) {:.3}",
                    method.name(),
                    1e3 / per_s,
                    madds / 1e6,
                    2.0 * madds * per_s / 1e9,
                    (log_ratio / n_ratio.max(1) as f64).exp()
                );
            }
        }
    }
}

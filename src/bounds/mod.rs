//! Sound affine and interval bounds on a ReLU network over a box (docs/design.md §2.2, §3, §4, §5).
//! May import [`crate::rounding`], [`crate::matmul`] and [`crate::network`].
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
//! # Floating-point error model (docs/design.md §3)
//!
//! Everything is computed in f64 with round-to-nearest, and every computed bound is then widened
//! by an a-priori bound on its rounding error ([`crate::rounding`]: outward steps, the error bound
//! `γ̂_N m̂ + N·2⁻¹⁰²²` of a dot product), so that the *returned* numbers are rigorous:
//!
//! * **Meaning of the affine forms.** `a·x + b` with the returned f64 coefficients, evaluated in
//!   *exact* real arithmetic, bounds `N(x)` for every real `x` of the box, where `N` is the exact
//!   real-arithmetic network with the stored f64 weights. (A caller evaluating the form in floating
//!   point must round outward itself.) `lower`/`upper` bound the exact `N(x)` over the box.
//! * **Widened bounds.** Every widened bound is `add_up(ŝ, err_bound(N, m̂, ·))` or
//!   `add_down(ŝ, −err_bound(N, m̂, ·))`, with the magnitude sum `m̂ ≈ Σ|t_j|` computed alongside
//!   (for a GEMM it is `|W|·|X|`, which the centre–radius form has anyway).
//! * **Overflow and NaN.** Inputs and weights are checked finite. If any intermediate bound still
//!   overflows, the affected output rows are replaced by the trivially sound `(0, ∓∞)`; a NaN is
//!   never laundered into a finite bound (see `OutRow::sanitize`).
//!
//! The per-method modules document how the model is applied to their steps (relaxation lines in
//! `relu_lines`, backward products in `crown.rs`, the centre–radius forms in `forward.rs`).
//! The output types are in `affine.rs`, validation, schedules and workspaces in `batch.rs`.

mod affine;
mod batch;
mod crown;
mod fold;
mod forward;
mod forward_backward;
mod ibp;
mod live;
mod relax;
#[cfg(test)]
pub(crate) mod test_support;

pub use affine::{AffineBounds, AffineBoundsBatch};
pub use batch::BoundsWorkspace;
pub use crown::crown;
pub use fold::FoldBound;
pub use forward::forward;
pub use forward_backward::{forward_backward, FORM_TIE};
pub use ibp::ibp;

pub(crate) use affine::OutRow;
pub(crate) use batch::{for_each_group, Schedule};

use crate::matmul::PackedMatrix;
use crate::network::Mlp;
use crate::rounding::{round_down, round_up};
use batch::{run_per_box, validate_boxes, validate_network};

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

    /// The method a continuous step's Picard–Lindelöf candidates are bounded with: this one
    /// where it costs no more than [`BoundMethod::Forward`], else forward. A candidate only has
    /// to close; the step's sets take their rates from the slabs, bounded by `self`
    /// (docs/design.md §7.1 item 1: forward-backward on the candidates gave the same verdicts
    /// on both paper scenarios at 16–20 % more CPU on scenario 1).
    pub fn for_enclosures(self) -> BoundMethod {
        match self {
            BoundMethod::Ibp => BoundMethod::Ibp,
            _ => BoundMethod::Forward,
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

/// Multiply–adds per box of a bound method on a network with widths `n_0..n_L`, by docs/design.md §5's
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

/// Bounds over one box, for the per-method entry points ([`ibp()`], [`crown()`], …): the
/// trivially sound bounds when the box has no coordinates to bound.
fn one_box(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    method: BoundMethod,
) -> Result<AffineBounds, BoundsError> {
    let mut out = AffineBoundsBatch::new();
    network_bounds_batch_into(net, lower, upper, method, &mut out)?;
    Ok(out
        .get(0)
        .unwrap_or_else(|| AffineBounds::unbounded(net.input_dim(), net.output_dim())))
}

/// A network checked once for bounding (shapes, widths, finite weights) with `|W_k|` of every
/// layer computed once: what a loop that bounds many batches of boxes holds.
///
/// It borrows the network, so the weights cannot change while `|W|` is kept.
pub struct PreparedNetwork<'a> {
    net: &'a Mlp,
    /// `|W_k|` of every layer, row-major like `W_k`.
    pub(crate) abs_w: Vec<Vec<f64>>,
    /// `W_k` packed for the forward method's products ([`crate::matmul::PackedMatrix`],
    /// which also multiplies by `|W_k|`).
    pub(crate) packed_w: Vec<PackedMatrix>,
    /// `W_kᵀ` packed, for every layer but the last (the backward passes start from its `W`):
    /// their `Λ·W_k` over the live neurons, as `W_kᵀ·Λᵀ`.
    pub(crate) packed_wt: Vec<PackedMatrix>,
    /// Upper bounds of the row sums of `|W_k|` (`n_k` per layer): forward bounds bound
    /// `|W_k| V ≤ rowsum · max V` for their rounding instead of computing the product.
    pub(crate) abs_row_sums: Vec<Vec<f64>>,
    /// Layer 0's bounds for the rounding of a face's folded constant.
    pub(crate) fold: FoldBound,
}

/// Upper bounds of the row sums of `|W|` of `layer` (the GPU engine uploads the same).
pub(crate) fn abs_row_sums(layer: &crate::network::Layer) -> Vec<f64> {
    // A sum of n nonnegative terms errs by less than (n + 2)·ε relative.
    let slack = 1.0 + (layer.n_in as f64 + 2.0) * f64::EPSILON;
    layer
        .weight
        .chunks(layer.n_in.max(1))
        .map(|row| {
            let sum: f64 = row.iter().map(|w| w.abs()).sum();
            crate::rounding::round_up_keep_zero(sum * slack)
        })
        .collect()
}

impl<'a> PreparedNetwork<'a> {
    /// Checks `net` ([`BoundsError::InvalidNetwork`], [`BoundsError::EmptyNetwork`]) and
    /// computes `|W|`.
    pub fn new(net: &'a Mlp) -> Result<PreparedNetwork<'a>, BoundsError> {
        validate_network(net)?;
        let abs_w: Vec<Vec<f64>> = net
            .layers
            .iter()
            .map(|l| l.weight.iter().map(|w| w.abs()).collect())
            .collect();
        let pack = |w: &[f64], l: &crate::network::Layer| PackedMatrix::new(l.n_out, l.n_in, w);
        let packed_w = net.layers.iter().map(|l| pack(&l.weight, l)).collect();
        let packed_wt = net
            .layers
            .iter()
            .take(net.layers.len().saturating_sub(1))
            .map(|l| {
                let (m, k) = (l.n_out, l.n_in);
                let wt: Vec<f64> = (0..k * m).map(|x| l.weight[(x % m) * k + x / m]).collect();
                PackedMatrix::new(k, m, &wt)
            })
            .collect();
        let abs_row_sums = net.layers.iter().map(abs_row_sums).collect();
        Ok(PreparedNetwork {
            net,
            abs_w,
            packed_w,
            packed_wt,
            abs_row_sums,
            fold: FoldBound::new(&net.layers[0]),
        })
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

/// Slopes below this are flushed to zero in `relu_lines`.
pub(super) const TINY_SLOPE: f64 = 1e-290;

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
///   `round_up(fl(−s̄l))`; `u − s̄u` by `round_up(fl(u − round_down(fl(s̄u))))`.
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
    let t = round_up(-s * l).max(round_up(u - round_down(s * u)));
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

    /// Throughput on the paper's 2×400×400×400×2 network, with the FLOP model of docs/design.md §5
    /// ([`model_multiply_adds`]).
    /// `cargo test --release --lib bounds::tests::bench_paper_network -- --ignored --nocapture`
    #[test]
    #[ignore]
    fn bench_paper_network() {
        use std::time::Instant;
        let widths = [2usize, 400, 400, 400, 2];
        let net = Mlp::random(&widths, 1);
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
            for (method, n_boxes) in [
                (BoundMethod::Ibp, 2048),
                (BoundMethod::Forward, 2048),
                (BoundMethod::ForwardBackward, 2048),
                (BoundMethod::ForwardBackwardSameSlope, 2048),
                (BoundMethod::CrownSameSlope, 16),
                (BoundMethod::Crown, 16),
            ] {
                let madds = model_multiply_adds(&widths, method);
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

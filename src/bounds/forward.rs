//! Forward linear bound propagation (auto_LiRPA's `Forward` mode; immrax's `crown`), batched as
//! matrix products (docs/design.md §4–5).
//!
//! Every neuron carries affine forms in the input `x` over the box, kept in centre–radius form:
//! an affine centre `Ĉ(x)` and an affine radius `R̂(x)` with the invariant
//!
//! ```text
//!     |z(x) − Ĉ(x)| ≤ R̂(x)      for every x in the box        (lower form Ĉ − R̂, upper Ĉ + R̂)
//! ```
//!
//! * **Input.** `Ĉ = x`, `R̂ = 0`; so the first layer is exact: `Ĉ = W₁x + b₁`, `R̂ = 0`.
//!   A coordinate with `lower = upper` (a face of a box, as `--face-local` bounds ask) is no
//!   form coordinate: `W₁` times its value goes into the constant, so a face of a 2-D box
//!   carries 2 coefficients a form, not 3. The rounding `ε` of that constant is carried beside
//!   `R̂` (`|z − Ĉ| ≤ R̂ + ε`: the concretisation widens by `ε`, the ReLU lines' slopes lie in
//!   `[0, 1]` so the relaxed forms keep it, and the next layer adds `rowsum(|W|)·ε` to `R̂`),
//!   which keeps `R̂` zero where the neurons are stable. One `ε` serves every neuron of a box
//!   ([`super::FoldBound`]), so the GPU engine, one thread a neuron, computes the same number.
//! * **Affine layer** `z' = W a + b`: `|z' − (WĈ + b)| = |W (a − Ĉ)| ≤ |W| R̂`, so
//!   `(Ĉ, R̂) ← (W Ĉ + b, |W| R̂)`. For a group of `G` boxes the forms are `n + 1` planes of
//!   `n_k × G` each (one per coefficient, the constant last), and a layer is the products
//!   `W·Ĉ` and `|W|·[R̂ | V]` plane by plane, with the rounding magnitudes `V` below as one
//!   more plane after `R̂`'s, all in one pass over `W`.
//! * **ReLU.** Concretise `l = min(Ĉ − R̂)`, `u = max(Ĉ + R̂)` over the box (by its centre and
//!   radius); if `u ≤ 0` the forms become 0, if `l ≥ 0` they stay; otherwise with the adaptive
//!   lines `s̲ z ≤ ReLU(z) ≤ s̄ z + t̄` (`relu_lines`) `ReLU(z) ∈ [s̲(Ĉ − R̂), s̄(Ĉ + R̂) + t̄]`,
//!   whose centre–radius form is `Ĉ ← αĈ + βR̂ + t̄/2`, `R̂ ← βĈ + αR̂ + t̄/2` with
//!   `α = (s̄ + s̲)/2`, `β = (s̄ − s̲)/2`.
//! * **Output.** `C̲ = Ĉ − R̂`, `C̄ = Ĉ + R̂`, concretised over the box.
//!
//! Neurons inactive over every box of the group have exact zero forms after the ReLU, so the
//! products leave their rows out (`layer_products`): no sum and no rounding bound changes.
//!
//! # Rounding (module error model of [`crate::bounds`])
//!
//! The invariant is kept in exact real arithmetic for the *computed* forms by adding every
//! rounding error, bounded over the box, to the constant of `R̂` (rounded up). Write
//! `V = Σ_q (|Ĉ_q| + |R̂_q|) mag_q + |Ĉ_0| + |R̂_0|` for a neuron's form magnitude over the box
//! (`mag_q ≥ |x_q|`). Then
//! * affine layer: the computed `WĈ + b` and `|W|R̂` err, over the box, by at most
//!   `γ (|W| V + |b|)` together (the `V` columns of the second GEMM give `|W| V`),
//!   `N = n_{k−1} + 1` terms;
//! * ReLU: computing `αĈ + βR̂ + t̄/2` and `βĈ + αR̂ + t̄/2` (a handful of roundings per
//!   coefficient, `α, |β| ≤ max(s̄, s̲)`) errs by at most `γ (max(s̄, s̲) V + t̄)`;
//!   the concretisation of `l, u` errs by at most `γ V`;
//! * output: forming `Ĉ ∓ R̂` errs by at most `γ V`, subtracted from / added to the constant.
//!
//! The absolute (underflow) part uses the scale `1 + Σ_q mag_q` (`err_bound`).
#![allow(clippy::needless_range_loop)] // index loops read as the formulas

use super::relax::{self, relax};
use super::{
    gemm, one_box, AffineBounds, BoundMethod, BoundsError, OutRow, PreparedNetwork, Schedule,
};
use crate::matmul::PackedMatrix;
use crate::network::Mlp;
use crate::rounding::{
    add_down, add_up, affine_max, affine_min, err_bound, round_up, round_up_keep_zero,
};

/// Largest number of boxes propagated together in one GEMM.
const MAX_GROUP: usize = 128;

/// Forward linear bounds of `net` over `[lower, upper]` (adaptive ReLU relaxation).
pub fn forward(net: &Mlp, lower: &[f64], upper: &[f64]) -> Result<AffineBounds, BoundsError> {
    one_box(net, lower, upper, BoundMethod::Forward)
}

/// What [`forward_group`] does besides the plain forward pass.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct ForwardOptions {
    /// Keep every hidden layer's concrete pre-activation bounds in [`Workspace::pre_lo`] and
    /// [`Workspace::pre_hi`] (for the backward pass of `forward-backward`).
    pub(crate) record: bool,
    /// Propagate IBP alongside, starting each layer from the intersected bounds of the one
    /// before, and intersect every concrete bound (pre-activation and output) with it.
    pub(crate) ibp: bool,
}

/// Buffers for one group of boxes, reused across the groups of one rayon task.
#[derive(Default)]
pub(crate) struct Workspace {
    /// Centre forms `Ĉ` in `d + 1` planes of `n_k × G`: coefficient `p` of neuron `i` in box
    /// `g` at `p·n_kG + i·G + g`; `d` form coordinates per box (the box's free coordinates,
    /// see [`Workspace::free`]), then the constant. A plane is one run over (neuron, box)
    /// pairs, which the relaxation ([`super::relax`]) walks a vector at a time; for the
    /// products each plane is an `n_k × G` right factor.
    c: Vec<f64>,
    c_next: Vec<f64>,
    /// Radius forms `R̂` in `d + 1` planes as `c`, then a plane of form magnitudes `V`, so that
    /// one pass over `|W|` gives both (see [`layer_products`]).
    rv: Vec<f64>,
    rv_next: Vec<f64>,
    /// Per box and form coordinate (`G × d`): the input coordinate it stands for, or
    /// `usize::MAX` for padding (a box with fewer free coordinates than `d`).
    free: Vec<usize>,
    /// Centre, radius and magnitude bound of each form coordinate, `G × d` (0 for padding).
    xc: Vec<f64>,
    xr: Vec<f64>,
    xmag: Vec<f64>,
    /// Underflow scale `1 + Σ mag` per box.
    scale: Vec<f64>,
    /// Per box: a bound on `|z − Ĉ| − R̂` of every neuron of the current layer that is not in
    /// `R̂` (the rounding of the pinned coordinates folded into layer 0's constant); added to
    /// the concretisation, and as `rowsum(|W|)·pending` to the next layer's `R̂`.
    pending: Vec<f64>,
    /// Whether a box's bounds overflowed.
    pub(crate) poisoned: Vec<bool>,
    /// Per hidden layer `k` (with [`ForwardOptions::record`]): concrete bounds of `z_k`,
    /// `n_k × G` neuron-major (`i·G + g`).
    pub(crate) pre_lo: Vec<Vec<f64>>,
    pub(crate) pre_hi: Vec<Vec<f64>>,
    /// Per layer `k ≥ 1` (with [`ForwardOptions::record`] and [`ForwardOptions::ibp`]): the
    /// computed `|W_k|(|ĉ| + r̂)` of IBP's input interval `ĉ ± r̂` (`n_k × G`). `ĉ + r̂` bounds
    /// `max(pre_hi[k − 1], 0)` from above (the interval contains `[0, u]`'s ReLU image), so it
    /// stands for the backward pass's `|W_k| mag_k` in the rounding model.
    pub(crate) input_magnitude_products: Vec<Vec<f64>>,
    /// IBP centre and radius of the current layer's input (post-ReLU) and of its output
    /// (pre-activation), `n × G` neuron-major, with [`ForwardOptions::ibp`].
    ic: Vec<f64>,
    ir: Vec<f64>,
    ipre_c: Vec<f64>,
    ipre_r: Vec<f64>,
    ie: Vec<f64>,
    /// IBP magnitude `|c| + r` of the current layer's input, and its rows not zero in every
    /// box.
    imag: Vec<f64>,
    ilive: Vec<usize>,
    /// The rows of `c`, `R̂` and `V` the next products read (from the relaxation).
    live: relax::LiveRows,
    /// Scratch of the relaxation and of the products' slabs.
    blocks: relax::Blocks,
    slabs: Vec<f64>,
}

/// Forward bounds for a validated batch, into `rows` (one per box).
pub(crate) fn forward_batch_into(
    prepared: &PreparedNetwork<'_>,
    lower: &[f64],
    upper: &[f64],
    schedule: Schedule<'_, Workspace>,
    rows: &mut [OutRow<'_>],
) {
    super::for_each_group(
        prepared.net(),
        lower,
        upper,
        rows,
        MAX_GROUP,
        schedule,
        |ws: &mut Workspace, lo, hi, rows| {
            forward_group(prepared, lo, hi, rows, ws, ForwardOptions::default())
        },
    );
}

/// The box as centre ± radius over its free coordinates (those with `lower < upper`; a face
/// of a box pins one), rigorously containing it, with `|x| ≤ xmag`; returns `d`, the largest
/// number of free coordinates of a box of the group (the forms' coordinates).
fn box_coordinates(
    n0: usize,
    g_count: usize,
    lower: &[f64],
    upper: &[f64],
    ws: &mut Workspace,
) -> usize {
    let d = (0..g_count)
        .map(|g| {
            (0..n0)
                .filter(|&p| lower[g * n0 + p] != upper[g * n0 + p])
                .count()
        })
        .max()
        .unwrap_or(0);
    for v in [&mut ws.xc, &mut ws.xr, &mut ws.xmag] {
        v.clear();
        v.resize(g_count * d, 0.0);
    }
    ws.free.clear();
    ws.free.resize(g_count * d, usize::MAX);
    ws.scale.clear();
    for g in 0..g_count {
        let mut sum = 1.0;
        let mut at = g * d;
        for p in 0..n0 {
            let (l, h) = (lower[g * n0 + p], upper[g * n0 + p]);
            let m = l.abs().max(h.abs());
            sum += m;
            if l == h {
                continue;
            }
            let c = 0.5 * l + 0.5 * h;
            ws.xc[at] = c;
            ws.xr[at] = round_up_keep_zero(h - c).max(round_up_keep_zero(c - l));
            ws.xmag[at] = round_up_keep_zero(c.abs() + ws.xr[at]);
            ws.free[at] = p;
            at += 1;
        }
        ws.scale.push(round_up(sum));
    }
    d
}

/// Propagates one group of `rows.len()` boxes through the network and writes the forward
/// output forms into `rows` (not sanitised).
///
/// With [`ForwardOptions::ibp`], IBP runs alongside (three more GEMMs of `G` columns a layer):
/// layer `k`'s interval is `W_k [ReLU(l_{k−1}), ReLU(u_{k−1})] + b_k` from the *intersected*
/// bounds of layer `k − 1`, with the rounding model of [`super::ibp`]; both enclosures are
/// rigorous, so their intersection is too, and the ReLU lines chosen on it stay valid.
pub(crate) fn forward_group(
    prepared: &PreparedNetwork<'_>,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    ws: &mut Workspace,
    opts: ForwardOptions,
) {
    let (net, abs_w) = (prepared.net(), &prepared.abs_w);
    let n0 = net.input_dim();
    let g_count = rows.len();
    let d = box_coordinates(n0, g_count, lower, upper, ws);
    let k_cols = d + 1;
    let n_layers = net.layers.len();
    ws.poisoned.clear();
    ws.poisoned.resize(g_count, false);
    ws.pending.clear();
    ws.pending.resize(g_count, 0.0);

    // Layer 0: Ĉ = [W₀ on the free coordinates | b₀ + W₀ on the pinned ones], R̂ = 0; the
    // constant is exact unless a coordinate is pinned, whose rounding goes to `pending`.
    let first = &net.layers[0];
    let plane = first.n_out * g_count;
    ws.c.clear();
    ws.c.resize(k_cols * plane, 0.0);
    ws.rv.clear();
    ws.rv.resize((k_cols + 1) * plane, 0.0);
    for g in 0..g_count {
        let free = &ws.free[g * d..(g + 1) * d];
        let (lo, hi) = (&lower[g * n0..(g + 1) * n0], &upper[g * n0..(g + 1) * n0]);
        for i in 0..first.n_out {
            let w_row = &first.weight[i * n0..(i + 1) * n0];
            for (q, &p) in free.iter().enumerate() {
                ws.c[q * plane + i * g_count + g] = if p == usize::MAX { 0.0 } else { w_row[p] };
            }
            let sum = (0..n0)
                .filter(|&p| lo[p] == hi[p])
                .fold(first.bias[i], |s, p| s + w_row[p] * lo[p]);
            ws.c[d * plane + i * g_count + g] = sum;
        }
        ws.pending[g] = prepared.fold.error(lo, hi, ws.scale[g]);
    }

    for k in 0..n_layers {
        let layer = &net.layers[k];
        let n = layer.n_out;
        let plane = n * g_count;
        if k > 0 {
            let n_prev = layer.n_in;
            // The products overwrite their outputs: sizing them needs no zeroing.
            ws.c_next.resize(k_cols * plane, 0.0);
            ws.rv_next.resize((k_cols + 1) * plane, 0.0);
            let w = &prepared.packed_w[k];
            let (ins, outs) = (
                (&ws.c[..], &ws.rv[..]),
                (&mut ws.c_next[..], &mut ws.rv_next[..]),
            );
            let shape = (n_prev, g_count, k_cols);
            layer_products(shape, w, ins, outs, &ws.live, &mut ws.slabs);
            std::mem::swap(&mut ws.c, &mut ws.c_next);
            std::mem::swap(&mut ws.rv, &mut ws.rv_next);
            if opts.ibp {
                let w = (&prepared.packed_w[k], &abs_w[k][..]);
                ibp_layer(layer, w, g_count, ws);
                if opts.record {
                    // Keep `|W_k|(|ĉ| + r̂)` for the backward pass (`ie` is rebuilt each layer).
                    ws.input_magnitude_products.resize(n_layers, Vec::new());
                    std::mem::swap(&mut ws.ie, &mut ws.input_magnitude_products[k]);
                }
            }
        }

        if k + 1 == n_layers {
            if k > 0 {
                output_bias(prepared, k, g_count, d, ws);
            }
            write_output(n, n0, d, ws, lower, upper, rows, opts.ibp && k > 0);
            return;
        }
        if opts.record {
            ws.pre_lo.resize(n_layers - 1, Vec::new());
            ws.pre_hi.resize(n_layers - 1, Vec::new());
            for v in [&mut ws.pre_lo[k], &mut ws.pre_hi[k]] {
                v.clear();
                v.resize(plane, 0.0);
            }
        }
        if opts.ibp {
            ws.ic.clear();
            ws.ic.resize(plane, 0.0);
            ws.ir.clear();
            ws.ir.resize(plane, 0.0);
        }

        // After a product, the bias and its rounding; then the ReLU relaxation, per neuron and
        // box, a vector of them at a time; V of the result for the next layer, and the rows
        // the next products read.
        let bias = (k > 0).then(|| (&layer.bias[..], &prepared.abs_row_sums[k][..], layer.n_in));
        let layer_forms = relax::Layer {
            n,
            g: g_count,
            d,
            c: &mut ws.c[..k_cols * plane],
            rv: &mut ws.rv[..(k_cols + 1) * plane],
            xc: &ws.xc,
            xr: &ws.xr,
            xmag: &ws.xmag,
            scale: &ws.scale,
            pending: &ws.pending,
            bias,
            ibp_pre: (opts.ibp && k > 0).then(|| (&ws.ipre_c[..], &ws.ipre_r[..])),
            ibp_post: opts.ibp.then(|| (&mut ws.ic[..], &mut ws.ir[..])),
            record: match opts.record {
                true => Some((&mut ws.pre_lo[k][..], &mut ws.pre_hi[k][..])),
                false => None,
            },
        };
        relax(layer_forms, &mut ws.poisoned, &mut ws.blocks, &mut ws.live);
        if k > 0 {
            ws.pending.iter_mut().for_each(|p| *p = 0.0);
        }
    }
}

/// The output layer's bias and the rounding of its product, into `Ĉ`'s and `R̂`'s constants
/// (the hidden layers' take theirs in the relaxation); `pending` is then carried and cleared.
fn output_bias(
    prepared: &PreparedNetwork<'_>,
    k: usize,
    g_count: usize,
    d: usize,
    ws: &mut Workspace,
) {
    let layer = &prepared.net().layers[k];
    let (n, n_prev) = (layer.n_out, layer.n_in);
    let plane = n * g_count;
    let row_sums = &prepared.abs_row_sums[k];
    for i in 0..n {
        let b = layer.bias[i];
        for g in 0..g_count {
            let at = d * plane + i * g_count + g;
            ws.c[at] += b;
            let v = ws.rv[(d + 1) * plane + i * g_count + g];
            let err = err_bound(n_prev + 1, v + b.abs(), ws.scale[g]);
            // |W|·(pending, …, pending) ≤ rowsum(|W|)·pending.
            let carried = round_up_keep_zero(row_sums[i] * ws.pending[g]);
            ws.rv[at] = add_up(add_up(ws.rv[at], err), carried);
        }
    }
    ws.pending.iter_mut().for_each(|p| *p = 0.0);
}

/// Groups of at most this many boxes take IBP's products on the packed `W` ([`ibp_layer`]).
/// Measured (`bench --bounds forward-backward`, scenario 1's architecture): 12 boxes +18 %
/// box-steps/s, 256 boxes (groups of 64) −5 % against the GEMM alone.
const IBP_PACKED_BOXES: usize = 32;

/// An affine layer's products, `Ĉ' = W·Ĉ` and `[R̂' | V'] = |W|·[R̂ | V]`, in one pass over the
/// packed `m × k` `W` ([`PackedMatrix::products`]; `|W|` is exact): `Ĉ` is `K = d + 1` planes
/// of `k × G`, `rv` `K` planes of `R̂` then one of `V` ([`Workspace::c`], [`Workspace::rv`]);
/// the outputs the same with `m` rows.
///
/// Each product runs over the rows where its right factor is nonzero (`live`, from the
/// relaxation): after a ReLU the forms of neurons inactive over every box of the group are
/// exact zeros (no sum and no rounding bound changes), after the exact first layer `R̂` is
/// nonzero only for the neurons unstable in some box, and `V` is zero only for those
/// inactive over every box.
fn layer_products(
    (k, g, planes): (usize, usize, usize),
    w: &PackedMatrix,
    (c, rv): (&[f64], &[f64]),
    (c_out, rv_out): (&mut [f64], &mut [f64]),
    live: &relax::LiveRows,
    slabs: &mut Vec<f64>,
) {
    use crate::matmul::Part;
    let m = w.rows();
    let part = |abs, live, b, b_col, planes, out, out_col| Part {
        abs,
        live,
        b,
        b_stride: g,
        b_col,
        n: g,
        planes,
        b_plane: k * g,
        out,
        out_col,
        out_plane: m * g,
    };
    let parts = [
        part(false, &live.c[..], c, 0, planes, 0, 0),
        part(true, &live.r[..], rv, 0, planes, 1, 0),
        part(true, &live.v[..], rv, planes * k * g, 1, 1, planes * m * g),
    ];
    let mut outs = [(c_out, g), (rv_out, g)];
    w.products(&parts, &mut outs, slabs);
}

/// IBP through affine layer `layer` for the group: from `ws.ic ± ws.ir` (post-ReLU, `n_in × G`)
/// to `ws.ipre_c ± ws.ipre_r` (`n_out × G`), rounding as in [`super::ibp`]. For a few boxes the
/// three products (`W·c`, `|W|·r`, `|W|·(|c| + r)`) run in one pass over the packed `W` (`w.0`),
/// as the forms' do: a general GEMM re-packed `W` on every call, most of the cost for a few
/// boxes; for many, the GEMM (on `|W|`, `w.1`) blocks the right factors better.
fn ibp_layer(
    layer: &crate::network::Layer,
    (w, abs_w): (&PackedMatrix, &[f64]),
    g_count: usize,
    ws: &mut Workspace,
) {
    use crate::matmul::Part;
    let (n, n_prev) = (layer.n_out, layer.n_in);
    for buf in [&mut ws.ipre_c, &mut ws.ipre_r, &mut ws.ie] {
        buf.resize(n * g_count, 0.0); // overwritten by the products below
    }
    ws.imag.clear();
    ws.imag
        .extend(ws.ic.iter().zip(&ws.ir).map(|(c, r)| c.abs() + r));
    if g_count > IBP_PACKED_BOXES {
        gemm(n, n_prev, g_count, &layer.weight, &ws.ic, &mut ws.ipre_c);
        gemm(n, n_prev, g_count, abs_w, &ws.ir, &mut ws.ipre_r);
        gemm(n, n_prev, g_count, abs_w, &ws.imag, &mut ws.ie);
    } else {
        // Rows zero in every box (neurons inactive over the group) give exact zeros: left out.
        ws.ilive.clear();
        ws.ilive.extend((0..n_prev).filter(|&q| {
            ws.imag[q * g_count..(q + 1) * g_count]
                .iter()
                .any(|&v| v != 0.0)
        }));
        let part = |abs, b, out| Part {
            abs,
            live: &ws.ilive[..],
            b,
            b_stride: g_count,
            b_col: 0,
            n: g_count,
            planes: 1,
            b_plane: 0,
            out,
            out_col: 0,
            out_plane: 0,
        };
        let parts = [
            part(false, &ws.ic[..], 0),
            part(true, &ws.ir[..], 1),
            part(true, &ws.imag[..], 2),
        ];
        let mut outs = [
            (&mut ws.ipre_c[..], g_count),
            (&mut ws.ipre_r[..], g_count),
            (&mut ws.ie[..], g_count),
        ];
        w.products(&parts, &mut outs, &mut ws.slabs);
    }
    for i in 0..n {
        let b = layer.bias[i];
        for g in 0..g_count {
            let at = i * g_count + g;
            ws.ipre_c[at] += b;
            let err = err_bound(n_prev + 1, ws.ie[at] + b.abs(), 1.0);
            ws.ipre_r[at] = add_up(ws.ipre_r[at], err);
        }
    }
}

/// Output forms `Ĉ ∓ R̂` with widened constants (by the rounding and by `pending`) in the
/// input's `n0` coordinates (0 on a pinned one: its value is in the constant), and their
/// concretisation over each box; with `ibp`, the concrete bounds are intersected with the IBP
/// ones in `ws.ipre_*`.
#[allow(clippy::too_many_arguments)]
fn write_output(
    m: usize,
    n0: usize,
    d: usize,
    ws: &Workspace,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    ibp: bool,
) {
    let g_count = rows.len();
    let plane = m * g_count;
    let mut full_mag = Vec::with_capacity(n0);
    for (g, row) in rows.iter_mut().enumerate() {
        if ws.poisoned[g] {
            row.set_unbounded();
            continue;
        }
        let (lo, hi) = (&lower[g * n0..(g + 1) * n0], &upper[g * n0..(g + 1) * n0]);
        let (free, xmag) = (&ws.free[g * d..(g + 1) * d], &ws.xmag[g * d..(g + 1) * d]);
        full_mag.clear();
        full_mag.extend(lo.iter().zip(hi).map(|(l, h)| l.abs().max(h.abs())));
        for i in 0..m {
            let at = i * g_count + g;
            let (cf, rf) = (
                |q: usize| ws.c[q * plane + at],
                |q: usize| ws.rv[q * plane + at],
            );
            let mut mag = cf(d).abs() + rf(d).abs();
            row.a_lower[i * n0..(i + 1) * n0].fill(0.0);
            row.a_upper[i * n0..(i + 1) * n0].fill(0.0);
            for (q, &p) in free.iter().enumerate() {
                if p == usize::MAX {
                    continue;
                }
                row.a_lower[i * n0 + p] = cf(q) - rf(q);
                row.a_upper[i * n0 + p] = cf(q) + rf(q);
                mag += (cf(q).abs() + rf(q).abs()) * xmag[q];
            }
            let err = add_up(err_bound(2, mag, ws.scale[g]), ws.pending[g]);
            row.b_lower[i] = add_down(cf(d) - rf(d), -err);
            row.b_upper[i] = add_up(cf(d) + rf(d), err);
            let a_lo = &row.a_lower[i * n0..(i + 1) * n0];
            let a_up = &row.a_upper[i * n0..(i + 1) * n0];
            row.lower[i] = affine_min(a_lo, row.b_lower[i], lo, hi, &full_mag);
            row.upper[i] = affine_max(a_up, row.b_upper[i], lo, hi, &full_mag);
            if ibp {
                let (c, r) = (ws.ipre_c[i * g_count + g], ws.ipre_r[i * g_count + g]);
                row.lower[i] = row.lower[i].max(add_down(c, -r));
                row.upper[i] = row.upper[i].min(add_up(c, r));
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;
    use crate::bounds::{crown, Relaxation};

    /// The layer's products give the dense products `W·Ĉ` and `|W|·[R̂ | V]` plane by plane
    /// (each part over its own nonzero rows, in one pass) and write every entry.
    #[test]
    fn layer_products_give_the_dense_products() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let (m, k, g, planes) = (37, 150, 3, 3);
        let a: Vec<f64> = (0..m * k).map(|_| rng.random_range(-1.0..1.0)).collect();
        let abs_a: Vec<f64> = a.iter().map(|x| x.abs()).collect();
        let packed = PackedMatrix::new(m, k, &a);
        for live_count in [0, 3, 25, 26, 97, 150] {
            // `live_count` nonzero rows of Ĉ and of R̂, spread over the 150 (R̂'s shifted);
            // V nonzero on Ĉ's rows.
            let (mut c, mut rv) = (vec![0.0; planes * k * g], vec![0.0; (planes + 1) * k * g]);
            let mut live = relax::LiveRows::default();
            let on = |j: usize| j * live_count / k != (j + 1) * live_count / k;
            for j in 0..k {
                let jr = (j + 7) % k;
                for q in 0..planes {
                    for b in 0..g {
                        if on(j) {
                            c[q * k * g + j * g + b] = rng.random_range(-1.0..1.0);
                        }
                        if on(jr) {
                            rv[q * k * g + j * g + b] = rng.random_range(0.0..1.0);
                        }
                    }
                }
                for b in 0..g {
                    if on(j) {
                        rv[planes * k * g + j * g + b] = rng.random_range(0.0..1.0);
                    }
                }
                if on(j) {
                    live.c.push(j);
                    live.v.push(j);
                }
                if on(jr) {
                    live.r.push(j);
                }
            }
            let (mut c_out, mut rv_out) = (
                vec![f64::NAN; planes * m * g],
                vec![f64::NAN; (planes + 1) * m * g],
            );
            let mut slabs = Vec::new();
            let (ins, outs) = ((&c[..], &rv[..]), (&mut c_out[..], &mut rv_out[..]));
            layer_products((k, g, planes), &packed, ins, outs, &live, &mut slabs);
            let mut dense = vec![0.0; m * g];
            for q in 0..=planes {
                let pairs = [(&a, &c, &c_out), (&abs_a, &rv, &rv_out)];
                for (w, b, got) in pairs.into_iter().take(if q < planes { 2 } else { 1 }) {
                    let (w, b, got) = if q < planes {
                        (w, b, got)
                    } else {
                        (&abs_a, &rv, &rv_out)
                    };
                    gemm(m, k, g, w, &b[q * k * g..(q + 1) * k * g], &mut dense);
                    let got = &got[q * m * g..(q + 1) * m * g];
                    for (x, y) in dense.iter().zip(got) {
                        assert!((x - y).abs() <= 1e-13, "{live_count} live rows: {x} vs {y}");
                    }
                }
            }
        }
    }

    #[test]
    fn forward_is_sound_on_random_networks_and_boxes() {
        for_each_case(40, |case| {
            let b = forward(&case.net, &case.lo, &case.hi).unwrap();
            check_bounds(&case.net, &case.lo, &case.hi, &b, &case.points)
                .unwrap_or_else(|e| panic!("{}: {e}", case.name));
        });
    }

    /// A face (one coordinate pinned, as `--face-local` bounds) folds the pinned coordinate
    /// into layer 0's constant, its rounding carried beside `R̂`: the bounds hold at sampled
    /// points in double-double, and they are those of the box with that coordinate 1e-13
    /// wide (kept as a form coordinate) to 1e-9, alone and in a group with other faces and
    /// whole boxes (padding where boxes have fewer free coordinates).
    #[test]
    fn faces_fold_the_pinned_coordinate_soundly_and_tightly() {
        use rand::Rng;
        for (s, shape) in [[3usize, 24, 24, 2], [2, 40, 30, 3]].iter().enumerate() {
            let net = Mlp::random(shape, 91 + s as u64);
            let n0 = shape[0];
            let mut rng = case_rng(5 + s as u64);
            let (mut all_lo, mut all_hi, mut thin_lo, mut thin_hi) =
                (vec![], vec![], vec![], vec![]);
            for b in 0..12 {
                let (mut lo, mut hi) = random_box(&mut rng, n0, BoxKind::Medium);
                let (mut tlo, mut thi) = (lo.clone(), hi.clone());
                if b % 4 != 3 {
                    // A face: coordinate b % n0 pinned at its lower or upper end.
                    let i = b % n0;
                    let v = if rng.random::<bool>() { lo[i] } else { hi[i] };
                    (lo[i], hi[i]) = (v, v);
                    (tlo[i], thi[i]) = (v, v + 1e-13 * (1.0 + v.abs()));
                }
                let one = forward(&net, &lo, &hi).unwrap();
                let pts = sample_points(&mut rng, &lo, &hi, 32);
                check_bounds(&net, &lo, &hi, &one, &pts).unwrap_or_else(|e| panic!("box {b}: {e}"));
                let thin = forward(&net, &tlo, &thi).unwrap();
                for o in 0..net.output_dim() {
                    let tol = 1e-9 * (1.0 + thin.upper[o] - thin.lower[o]);
                    assert!(
                        (one.lower[o] - thin.lower[o]).abs() <= tol,
                        "box {b} output {o}"
                    );
                    assert!(
                        (one.upper[o] - thin.upper[o]).abs() <= tol,
                        "box {b} output {o}"
                    );
                }
                all_lo.extend(&lo);
                all_hi.extend(&hi);
                thin_lo.extend(tlo);
                thin_hi.extend(thi);
            }
            let batch =
                crate::bounds::network_bounds_batch(&net, &all_lo, &all_hi, BoundMethod::Forward)
                    .unwrap();
            for b in 0..12 {
                let one = forward(
                    &net,
                    &all_lo[b * n0..(b + 1) * n0],
                    &all_hi[b * n0..(b + 1) * n0],
                )
                .unwrap();
                for o in 0..net.output_dim() {
                    let k = b * net.output_dim() + o;
                    assert!(
                        (batch.lower[k] - one.lower[o]).abs() <= 1e-12 * (1.0 + one.lower[o].abs())
                    );
                    assert!(
                        (batch.upper[k] - one.upper[o]).abs() <= 1e-12 * (1.0 + one.upper[o].abs())
                    );
                }
            }
        }
    }

    #[test]
    fn batched_forward_equals_one_box_at_a_time() {
        // Group boundaries must not change any box's result (beyond GEMM summation order).
        let methods = [BoundMethod::Forward, BoundMethod::Crown, BoundMethod::Ibp];
        assert_batch_matches_single(&methods, 1e-12);
    }

    #[test]
    fn forward_vs_crown_measured() {
        // Forward vs backward CROWN: no ordering theorem, so measured only.
        let (mut sum_f, mut sum_c, mut n) = (0.0f64, 0.0f64, 0);
        for_each_case(30, |case| {
            let f = forward(&case.net, &case.lo, &case.hi).unwrap();
            let c = crown(&case.net, &case.lo, &case.hi, Relaxation::Adaptive).unwrap();
            for o in 0..f.n_out {
                let (wf, wc) = (f.upper[o] - f.lower[o], c.upper[o] - c.lower[o]);
                if wc > 1e-9 {
                    sum_f += (wf / wc).ln();
                    sum_c += 1.0;
                    n += 1;
                }
            }
        });
        eprintln!(
            "forward/crown width ratio, geometric mean over {n} outputs of non-tiny boxes: {:.3}",
            (sum_f / sum_c.max(1.0)).exp()
        );
    }
}

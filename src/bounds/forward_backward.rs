//! Forward+Backward bounds (auto_LiRPA's `Forward+Backward`): every hidden pre-activation is
//! bounded by forward linear propagation ([`super::forward`], intersected with IBP), and the
//! output by ONE backward CROWN pass through the ReLU relaxations those bounds define.
//!
//! Backward CROWN ([`super::crown`]) bounds each of the `Σ n_k` intermediate neurons by its own
//! backward pass, `Σ_k n_k Σ_{j<k} n_j n_{j−1}` multiply–adds per box; here only the `m` output
//! rows (`2m` with the adaptive relaxation) go backward, so a box costs about
//! `(2(n+1) + 1 + 3 + 1 + R)·Σ n_k n_{k−1}` multiply–adds (forward forms, IBP, rounding
//! magnitudes, `R = 2m` or `m` backward rows): a few MFLOP for 2×400³×2, near forward's cost,
//! for bounds near CROWN's tightness (the intermediate bounds are forward's, the output's
//! linear form is CROWN's).
//!
//! # Batching
//!
//! Boxes run in groups of `G` (one rayon task a group). The forward part is GEMMs over
//! `G(n+1)` columns. The backward pass keeps `Λ` for all boxes of the group stacked,
//! `G·R × n_{j+1}` box-major, so that each layer is one scaling of `Λ`'s columns by the box's
//! own slopes (`Λ∘s`) followed by ONE GEMM `(G·R × n_j)·(n_j × n_{j−1})` with the shared `W_j`.
//! Neurons dead (`u ≤ 0`) in every box of the group are dropped from that product (exact).
//!
//! # Soundness and rounding (module error model of [`crate::bounds`])
//!
//! * The pre-activation bounds `[l_j, u_j]` are rigorous (forward's and IBP's error models), so
//!   the relaxation lines from `relu_lines` on them hold for every reachable `z_j`.
//! * The backward pass is [`super::crown`]'s, applied to the output layer only, with the same
//!   rounding argument: `Λ̂' = fl(fl(Λ̂∘s)·W_j)` errs against `a_j` (with `|a_j| ≤ mag_j`,
//!   `mag_0 = max(|x̲|, |x̄|)`, `mag_j = max(u_{j−1}, 0)`) by at most
//!   `γ Σ_m |Λ̂∘s|_m (|W_j| mag_j)_m`, and the intercept sums by `γ Σ_m (|Λ̂∘s|_m |b_j|_m +
//!   |Λ̂_m| t_m)`; one magnitude `E = Σ_m |Λ̂∘s|_m w_m + |Λ̂_m| t_m` with
//!   `w = |W_j| mag_j + |b_j|` (one more GEMM of `G` columns per layer) bounds both, and `β̂`
//!   moves outward by `err_bound(2 n_j + 2, E, 1 + Σ w + Σ mag_j)`. A summation order inside the
//!   GEMM changes nothing: the bound holds for any order.
//! * Output: the final forms are concretised with `affine_min`/`affine_max` (rigorous). The
//!   concrete bounds are the intersection of the backward, forward and IBP ones (each rigorous).
//!   With [`Relaxation::Adaptive`] each side's affine form is whichever of the backward and the
//!   forward form concretises tighter (both are valid); with [`Relaxation::SameSlope`] the
//!   backward forms are always kept, so `C̲ = C̄` bit for bit.
#![allow(clippy::needless_range_loop)] // index loops read as the formulas

use super::forward::{forward_group, ForwardOptions, Workspace as FwdWorkspace};
use super::live::LiveLines;
use super::{
    gemm, one_box, relu_lines, AffineBounds, BoundMethod, BoundsError, OutRow, PreparedNetwork,
    Relaxation, Schedule,
};
use crate::matmul::Part;
use crate::network::Mlp;
use crate::rounding::{add_down, add_up, affine_max, affine_min, err_bound};

/// Largest number of boxes propagated together.
const MAX_GROUP: usize = 128;

/// Forward+Backward bounds of `net` over `[lower, upper]` with the given ReLU relaxation for
/// the backward pass ([`Relaxation::SameSlope`] returns `a_lower == a_upper`).
pub fn forward_backward(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    relaxation: Relaxation,
) -> Result<AffineBounds, BoundsError> {
    let method = match relaxation {
        Relaxation::Adaptive => BoundMethod::ForwardBackward,
        Relaxation::SameSlope => BoundMethod::ForwardBackwardSameSlope,
    };
    one_box(net, lower, upper, method)
}

/// Buffers of one rayon task.
#[derive(Default)]
pub(crate) struct Workspace {
    fwd: FwdWorkspace,
    /// `mag_j`, `n_{j−1} × G` neuron-major (the input magnitude for `j = 0`).
    mag: Vec<f64>,
    /// `w = |W_j| mag_j + |b_j|`, `n_j × G` neuron-major.
    wmag: Vec<f64>,
    /// Per box: `1 + Σ w + Σ mag_j`.
    scale: Vec<f64>,
    /// Slopes and intercepts of layer `j`'s relaxation, `G × n_j` box-major.
    s_lo: Vec<f64>,
    s_up: Vec<f64>,
    t_up: Vec<f64>,
    /// Neurons live (`u > 0`) in some box of the group.
    live: Vec<usize>,
    lam: Vec<f64>,
    lam_next: Vec<f64>,
    lam_s: Vec<f64>,
    /// One row of `Λ` on the live neurons.
    lam_live: Vec<f64>,
    /// The current layer's relaxation on the live neurons, for one box.
    lines: LiveLines,
    w_live: Vec<f64>,
    /// [`live_product_packed`]'s `(Λ∘s)ᵀ` (`n_j × G·R`), its product, and the slabs' scratch.
    lam_t: Vec<f64>,
    lam_out: Vec<f64>,
    slabs: Vec<f64>,
    beta_u: Vec<f64>,
    beta_l: Vec<f64>,
    /// Box magnitudes `max(|x̲|, |x̄|)`, `G × n` box-major.
    xmag: Vec<f64>,
}

/// Forward+Backward for a validated batch, into `rows` (one per box).
pub(crate) fn forward_backward_batch_into(
    prepared: &PreparedNetwork<'_>,
    lower: &[f64],
    upper: &[f64],
    relaxation: Relaxation,
    schedule: Schedule<'_, Workspace>,
    rows: &mut [OutRow<'_>],
) {
    let net = prepared.net();
    let opts = ForwardOptions {
        record: true,
        ibp: true,
    };
    super::for_each_group(
        net,
        lower,
        upper,
        rows,
        MAX_GROUP,
        schedule,
        |ws: &mut Workspace, lo, hi, rows| {
            forward_group(prepared, lo, hi, rows, &mut ws.fwd, opts);
            if net.layers.len() > 1 {
                backward_group(prepared, lo, hi, relaxation, rows, ws);
            }
        },
    );
}

/// One backward pass from the output for every box of the group; `rows` hold forward's output
/// (forms and IBP-intersected concrete bounds) on entry.
fn backward_group(
    prepared: &PreparedNetwork<'_>,
    lower: &[f64],
    upper: &[f64],
    relaxation: Relaxation,
    rows: &mut [OutRow<'_>],
    ws: &mut Workspace,
) {
    let (net, abs_w) = (prepared.net(), &prepared.abs_w);
    let n0 = net.input_dim();
    let g_count = rows.len();
    let n_layers = net.layers.len();
    let last = &net.layers[n_layers - 1];
    let m = last.n_out;
    let stacked = relaxation == Relaxation::Adaptive;
    let r_count = if stacked { 2 * m } else { m };
    let rows_total = g_count * r_count;

    ws.xmag.clear();
    ws.xmag
        .extend(lower.iter().zip(upper).map(|(l, h)| l.abs().max(h.abs())));

    // Λ = W_{L−1}, β = b_{L−1} for every box and row copy.
    ws.lam.clear();
    ws.beta_u.clear();
    ws.beta_l.clear();
    for _ in 0..g_count * (r_count / m) {
        ws.lam.extend_from_slice(&last.weight);
        ws.beta_u.extend_from_slice(&last.bias);
        ws.beta_l.extend_from_slice(&last.bias);
    }
    let mut width = last.n_in;
    for j in (0..n_layers - 1).rev() {
        let lj = &net.layers[j];
        let (n_j, n_in) = (lj.n_out, lj.n_in);
        debug_assert_eq!(width, n_j);

        // mag_j (input of layer j) and w = |W_j| mag_j + |b_j|, neuron-major.
        ws.mag.clear();
        ws.mag.resize(n_in * g_count, 0.0);
        if j == 0 {
            for g in 0..g_count {
                for p in 0..n0 {
                    ws.mag[p * g_count + g] = ws.xmag[g * n0 + p];
                }
            }
        } else {
            for (dst, &u) in ws.mag.iter_mut().zip(&ws.fwd.pre_hi[j - 1]) {
                *dst = u.max(0.0);
            }
        }
        ws.wmag.clear();
        if j == 0 {
            ws.wmag.resize(n_j * g_count, 0.0);
            gemm(n_j, n_in, g_count, &abs_w[j], &ws.mag, &mut ws.wmag);
        } else {
            // The forward pass's IBP computed `|W_j|` times a bound of `mag_j` already.
            ws.wmag
                .extend_from_slice(&ws.fwd.input_magnitude_products[j]);
        }
        ws.scale.clear();
        ws.scale.resize(g_count, 1.0);
        for i in 0..n_j {
            let b = lj.bias[i].abs();
            for g in 0..g_count {
                let w = &mut ws.wmag[i * g_count + g];
                *w += b;
                ws.scale[g] += *w;
            }
        }
        for p in 0..n_in {
            for g in 0..g_count {
                ws.scale[g] += ws.mag[p * g_count + g];
            }
        }

        // Relaxation of a_{j+1} = ReLU(z_j) per box, box-major; neurons live in some box.
        for v in [&mut ws.s_lo, &mut ws.s_up, &mut ws.t_up] {
            v.resize(g_count * n_j, 0.0); // every entry written below
        }
        ws.live.clear();
        let (pre_lo, pre_hi) = (&ws.fwd.pre_lo[j], &ws.fwd.pre_hi[j]);
        for i in 0..n_j {
            let mut any = false;
            for g in 0..g_count {
                let (l, u) = (pre_lo[i * g_count + g], pre_hi[i * g_count + g]);
                let (sl, su, t) = relu_lines(l, u, relaxation);
                ws.s_lo[g * n_j + i] = sl;
                ws.s_up[g * n_j + i] = su;
                ws.t_up[g * n_j + i] = t;
                any |= u > 0.0;
            }
            if any {
                ws.live.push(i);
            }
        }
        let n_live = ws.live.len();

        // Λ∘s on the live columns, and the intercept sums with their rounding bound.
        ws.lam_s.resize(rows_total * n_live, 0.0); // every entry written below
        let n_terms = 2 * n_j + 2;
        for g in 0..g_count {
            let span = g * n_j..(g + 1) * n_j;
            let lines = (
                &ws.s_lo[span.clone()],
                &ws.s_up[span.clone()],
                &ws.t_up[span],
            );
            let wmag = &ws.wmag;
            ws.lines
                .gather(&ws.live, lines, &lj.bias, |q| wmag[q * g_count + g]);
            let scale = ws.scale[g];
            for r in 0..r_count {
                let row = g * r_count + r;
                let upper_side = !stacked || r < m;
                let lam_row = &ws.lam[row * width..(row + 1) * width];
                ws.lam_live.clear();
                ws.lam_live.extend(ws.live.iter().map(|&q| lam_row[q]));
                let out = &mut ws.lam_s[row * n_live..(row + 1) * n_live];
                let [su, sl, mag] = ws.lines.relax_row(&ws.lam_live, out, upper_side);
                let err = err_bound(n_terms, mag, scale);
                ws.beta_u[row] = add_up(add_up(ws.beta_u[row], su), err);
                ws.beta_l[row] = add_down(add_down(ws.beta_l[row], sl), -err);
            }
        }

        // Λ ← (Λ∘s)_live · W_j[live], one product for the whole group.
        ws.lam_next.resize(rows_total * n_in, 0.0); // overwritten by either product
        if rows_total <= PACKED_ROWS {
            live_product_packed(&prepared.packed_wt[j], rows_total, ws);
        } else {
            ws.w_live.clear();
            for &q in &ws.live {
                ws.w_live
                    .extend_from_slice(&lj.weight[q * n_in..(q + 1) * n_in]);
            }
            gemm(
                rows_total,
                n_live,
                n_in,
                &ws.lam_s,
                &ws.w_live,
                &mut ws.lam_next,
            );
        }
        std::mem::swap(&mut ws.lam, &mut ws.lam_next);
        width = n_in;
    }

    // Concretise; keep the tighter of the backward and forward forms per side (adaptive), and
    // intersect the concrete bounds.
    for (g, row) in rows.iter_mut().enumerate() {
        if ws.fwd.poisoned[g] {
            row.set_unbounded();
            continue;
        }
        let (lo, hi) = (&lower[g * n0..(g + 1) * n0], &upper[g * n0..(g + 1) * n0]);
        let xmag = &ws.xmag[g * n0..(g + 1) * n0];
        for i in 0..m {
            let ur = g * r_count + i;
            let lr = if stacked { ur + m } else { ur };
            let au = &ws.lam[ur * n0..(ur + 1) * n0];
            let al = &ws.lam[lr * n0..(lr + 1) * n0];
            let (bu, bl) = (ws.beta_u[ur], ws.beta_l[lr]);
            let hi_b = affine_max(au, bu, lo, hi, xmag);
            let lo_b = affine_min(al, bl, lo, hi, xmag);
            let fwd_hi = row.upper[i];
            let fwd_lo = row.lower[i];
            let span = i * n0..(i + 1) * n0;
            let fwd_form_hi = affine_max(&row.a_upper[span.clone()], row.b_upper[i], lo, hi, xmag);
            let fwd_form_lo = affine_min(&row.a_lower[span], row.b_lower[i], lo, hi, xmag);
            let keep_fwd_hi = stacked && tighter_than(-fwd_form_hi, -hi_b);
            if !keep_fwd_hi {
                row.a_upper[i * n0..(i + 1) * n0].copy_from_slice(au);
                row.b_upper[i] = bu;
            }
            let keep_fwd_lo = stacked && tighter_than(fwd_form_lo, lo_b);
            if !keep_fwd_lo {
                row.a_lower[i * n0..(i + 1) * n0].copy_from_slice(al);
                row.b_lower[i] = bl;
            }
            // NaN never wins: `min`/`max` return the other operand, and `sanitize` rejects a
            // NaN form anyway.
            row.upper[i] = hi_b.min(fwd_hi);
            row.lower[i] = lo_b.max(fwd_lo);
        }
    }
}

/// Adaptive: a side keeps the forward form only where it concretises tighter than the backward
/// one by more than `FORM_TIE·(1 + |backward bound|)`. The two often tie in exact arithmetic
/// (both tight at one corner of the box); their rounding terms then decide by ~1e-13, which the
/// GPU engine's order of operations decides otherwise, while the two forms' slopes (the
/// Minkowski rate's `C`) differ by far more (issue 40). Ties go to the backward form on both
/// engines (`shaders/output.wgsl` takes this constant from codegen).
pub const FORM_TIE: f64 = 1e-9;

/// Whether a lower bound `forward` beats `backward` by more than the tie tolerance (upper
/// bounds: pass both negated). False with a NaN.
fn tighter_than(forward: f64, backward: f64) -> bool {
    forward > backward + FORM_TIE * (1.0 + backward.abs())
}

/// Groups of at most this many backward rows (`G·R`) take `Λ`'s product on the packed `W_jᵀ`
/// ([`live_product_packed`]); larger ones gather `W_j`'s live rows for one GEMM. For a few rows
/// (the fallback slabs of one box in continuous time: 4 boxes × 2 rows) the gather of `W_j`
/// (2 MB for a 500-wide layer) and the GEMM's packing of it were most of the pass; over
/// hundreds of rows they are amortised and the GEMM's blocking wins over the transposes.
/// Measured (one thread, continuous `verify --grid 16,12` and `20,8 --face-local`, CPU against
/// the GEMM at every size): at most 32, 96 or 256 rows packed, scenario 1 (400-wide) −7 %,
/// −6 %, −4 %, scenario 2 (500-wide) −5 %, −9 %, −10 %.
const PACKED_ROWS: usize = 96;

/// `Λ' = (Λ∘s)_live · W_j[live]` (`ws.lam_s`, `G·R × n_live` on the live neurons `ws.live`,
/// into `ws.lam_next`, `G·R × n_{j−1}`) as `W_jᵀ (Λ∘s)ᵀ` on the packed `W_jᵀ` (`wt`), which
/// walks the live neurons without copying `W_j`. The same sums as the GEMM's (one accumulator
/// an entry, ascending live index); any order would do ([`crate::rounding`]).
fn live_product_packed(wt: &crate::matmul::PackedMatrix, rows_total: usize, ws: &mut Workspace) {
    let (n_in, n_live) = (wt.rows(), ws.live.len());
    let n_j = wt.cols();
    ws.lam_t.resize(n_j * rows_total, 0.0); // only the live rows are read, each written
    for row in 0..rows_total {
        let lam_s = &ws.lam_s[row * n_live..(row + 1) * n_live];
        for (&q, &v) in ws.live.iter().zip(lam_s) {
            ws.lam_t[q * rows_total + row] = v;
        }
    }
    ws.lam_out.resize(n_in * rows_total, 0.0); // overwritten by the product
    let part = Part {
        abs: false,
        live: &ws.live,
        b: &ws.lam_t,
        b_stride: rows_total,
        b_col: 0,
        n: rows_total,
        planes: 1,
        b_plane: 0,
        out: 0,
        out_col: 0,
        out_plane: 0,
    };
    wt.products(
        &[part],
        &mut [(&mut ws.lam_out[..], rows_total)],
        &mut ws.slabs,
    );
    for p in 0..n_in {
        for row in 0..rows_total {
            ws.lam_next[row * n_in + p] = ws.lam_out[p * rows_total + row];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;
    use crate::bounds::{crown, forward, AffineBoundsBatch};

    /// The packed path of `Λ`'s product gives the gathered GEMM's entries, for row counts on
    /// both sides of a slab and live sets from none to all (random `W`, `Λ∘s`).
    #[test]
    fn packed_live_product_is_the_gathered_gemm() {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        for (n_j, n_in, rows_total, keep) in [
            (37, 29, 8, 0.5),
            (130, 17, 1, 1.0),
            (9, 300, 27, 0.2),
            (64, 64, 32, 0.0),
        ] {
            let w: Vec<f64> = (0..n_j * n_in)
                .map(|_| rng.random_range(-1.0..1.0))
                .collect();
            let wt: Vec<f64> = (0..n_in * n_j)
                .map(|x| w[(x % n_j) * n_in + x / n_j])
                .collect();
            let packed = crate::matmul::PackedMatrix::new(n_in, n_j, &wt);
            let mut ws = Workspace {
                live: (0..n_j).filter(|_| rng.random_bool(keep)).collect(),
                ..Workspace::default()
            };
            let n_live = ws.live.len();
            ws.lam_s = (0..rows_total * n_live)
                .map(|_| rng.random_range(-2.0..2.0))
                .collect();
            ws.lam_next = vec![f64::NAN; rows_total * n_in];
            live_product_packed(&packed, rows_total, &mut ws);
            let w_live: Vec<f64> = ws
                .live
                .iter()
                .flat_map(|&q| w[q * n_in..(q + 1) * n_in].to_vec())
                .collect();
            let mut want = vec![0.0; rows_total * n_in];
            gemm(rows_total, n_live, n_in, &ws.lam_s, &w_live, &mut want);
            for (a, b) in ws.lam_next.iter().zip(&want) {
                assert!(
                    (a - b).abs() <= 1e-12 * (1.0 + b.abs()),
                    "{n_j}×{n_in}, {rows_total} rows: {a} vs {b}"
                );
            }
        }
    }

    /// The forward form wins only by more than the tie tolerance; ties and NaN go backward.
    #[test]
    fn ties_go_to_the_backward_form() {
        let b = 1.6351681024851934e-4;
        assert!(!tighter_than(b + 2.6e-13, b), "a rounding-level tie");
        assert!(tighter_than(b + 2e-9, b));
        assert!(!tighter_than(b - 1e-3, b));
        assert!(
            !tighter_than(-(-b + 1.5e-13), -(-b)),
            "upper bounds, negated"
        );
        assert!(tighter_than(-(-5.0 - 1e-7), -(-5.0)) && !tighter_than(-(-5.0 - 5e-9), -(-5.0)));
        assert!(!tighter_than(f64::NAN, b) && !tighter_than(b, f64::NAN));
    }

    /// The backward pass takes `|W_j| mag_j` from the forward pass's IBP product: that must
    /// bound the product with `mag_j = max(pre_hi, 0)` itself from above (up to the products'
    /// own rounding), layer by layer.
    #[test]
    fn ibp_input_magnitudes_bound_the_backward_magnitudes() {
        let net = Mlp::random(&[2, 30, 30, 30, 2], 4);
        let prepared = PreparedNetwork::new(&net).unwrap();
        let mut rng = case_rng(5);
        let g = 9;
        let (mut lo, mut hi) = (Vec::new(), Vec::new());
        for b in 0..g {
            let (l, h) = random_box(&mut rng, 2, BoxKind::ALL[b % BoxKind::ALL.len()]);
            lo.extend(l);
            hi.extend(h);
        }
        let mut out = AffineBoundsBatch::new();
        out.reset(2, 2, g);
        let mut rows = out.rows_mut();
        let mut ws = FwdWorkspace::default();
        let opts = ForwardOptions {
            record: true,
            ibp: true,
        };
        forward_group(&prepared, &lo, &hi, &mut rows, &mut ws, opts);
        let mut positive = 0;
        for j in 1..net.layers.len() - 1 {
            let (n_j, n_in) = (net.layers[j].n_out, net.layers[j].n_in);
            let mag: Vec<f64> = ws.pre_hi[j - 1].iter().map(|u| u.max(0.0)).collect();
            let mut direct = vec![0.0; n_j * g];
            gemm(n_j, n_in, g, &prepared.abs_w[j], &mag, &mut direct);
            let reused = &ws.input_magnitude_products[j];
            assert_eq!(reused.len(), direct.len(), "layer {j}");
            for (r, d) in reused.iter().zip(&direct) {
                assert!(
                    *r >= d * (1.0 - 1e-12),
                    "layer {j}: reused {r} < direct {d}"
                );
                positive += usize::from(*d > 0.0);
            }
        }
        assert!(positive > 0, "the case should have live neurons");
    }

    #[test]
    fn forward_backward_is_sound_on_random_networks_and_boxes() {
        assert_sound_for_both_relaxations(40, forward_backward);
    }

    #[test]
    fn batched_forward_backward_equals_one_box_at_a_time() {
        // Dropping neurons dead in the whole group changes summation order only.
        let methods = [
            BoundMethod::ForwardBackward,
            BoundMethod::ForwardBackwardSameSlope,
        ];
        assert_batch_matches_single(&methods, 1e-9);
    }

    #[test]
    fn forward_backward_between_forward_and_crown_measured() {
        // Tighter than forward per output is a theorem up to rounding (the concrete bounds are
        // intersected with forward's); against CROWN it is measured only.
        let (mut log_f, mut log_fb, mut log_fbs, mut n) = (0.0f64, 0.0f64, 0.0f64, 0usize);
        for_each_case(30, |case| {
            let f = forward(&case.net, &case.lo, &case.hi).unwrap();
            let c = crown(&case.net, &case.lo, &case.hi, Relaxation::Adaptive).unwrap();
            let fb = forward_backward(&case.net, &case.lo, &case.hi, Relaxation::Adaptive).unwrap();
            let fbs =
                forward_backward(&case.net, &case.lo, &case.hi, Relaxation::SameSlope).unwrap();
            for o in 0..f.n_out {
                assert!(fb.upper[o] <= f.upper[o] && fb.lower[o] >= f.lower[o]);
                let w = |b: &AffineBounds| b.upper[o] - b.lower[o];
                if w(&c) > 1e-9 {
                    log_f += (w(&f) / w(&c)).ln();
                    log_fb += (w(&fb) / w(&c)).ln();
                    log_fbs += (w(&fbs) / w(&c)).ln();
                    n += 1;
                }
            }
        });
        let gm = |s: f64| (s / n.max(1) as f64).exp();
        eprintln!(
            "width / crown width, geometric mean over {n} outputs: forward {:.3}, \
             forward-backward {:.3}, forward-backward-same-slope {:.3}",
            gm(log_f),
            gm(log_fb),
            gm(log_fbs)
        );
        assert!(gm(log_fb) <= gm(log_f));
    }
}

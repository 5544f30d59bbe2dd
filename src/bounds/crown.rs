//! Backward CROWN (Zhang et al. 2018), as auto_LiRPA's `CROWN` method defines it: the bounds of
//! every layer's pre-activation `z_k` come from their own backward pass to the input, and those
//! bounds choose the ReLU relaxations used by every later pass. auto_LiRPA also intersects each
//! layer's bounds with interval bounds, which this does not (so its sets can be ~10⁻⁴ tighter
//! where that makes a neuron stable: README, Benchmarks; `forward-backward` does intersect).
//!
//! # One backward pass
//!
//! Layers are `z_k = W_k a_k + b_k` (`k = 0..L−1`, `a_0 = x`, `a_{k+1} = ReLU(z_k)`). To bound
//! `z_k` from above, start from the exact `z_k = Λ a_k + β` with `Λ = W_k`, `β = b_k`, and for
//! `j = k−1, …, 0` replace `a_{j+1} = ReLU(z_j)` by the upper line `s̄ z_j + t̄` where `Λ ≥ 0` and
//! by the lower line `s̲ z_j` where `Λ < 0` (`relu_lines`), then substitute
//! `z_j = W_j a_j + b_j`:
//!
//! ```text
//!     Λ ← (Λ ∘ s) W_j,      β ← β + Σ_m Λ_m t_m [line with intercept] + (Λ ∘ s) b_j
//! ```
//!
//! ending with `z_k ≤ Λ x + β` on the box, whose maximum over the box is the concrete bound. The
//! lower bound is symmetric (lower line where `Λ ≥ 0`). With [`Relaxation::Adaptive`] the two
//! sides pick different slopes, so both are run, stacked as `2 n_k` rows of one GEMM; with
//! [`Relaxation::SameSlope`] `s̲ = s̄`, so `Λ` is shared and one pass of `n_k` rows serves both
//! sides (only the intercept terms differ): `C̲ = C̄`, bit for bit.
//!
//! Neurons with `u ≤ 0` contribute nothing and are dropped from the products (`Λ` keeps only
//! the columns of live neurons, `W_j` only their rows and the next layer's live columns): exact,
//! and cheaper on small boxes.
//!
//! # Rounding (module error model of [`crate::bounds`])
//!
//! The inequality `z_k ≤ Λ̂ a_j + β̂` is kept valid in exact real arithmetic for the *computed*
//! `Λ̂`. Relaxing is exact in reals (the lines are rigorously valid). For the substitution, the
//! computed `Λ̂' = fl(fl(Λ̂∘s)·W_j)` differs from the real `(Λ̂∘s)·W_j` entrywise by at most
//! `γ Σ_m |Λ̂∘s|_m |W_j|_{m·}`; against `a_j` with `|a_j| ≤ mag_j` (`max(u, 0)` of the previous
//! layer, `max(|x̲|, |x̄|)` for the input) this is at most `γ Σ_m |Λ̂∘s|_m (|W_j| mag_j)_m`. The
//! bias sum (`2 n_j` products) errs by at most `γ Σ_m (|Λ̂∘s|_m |b_j|_m + |Λ̂_m| t_m)`. So one
//! magnitude per row, `E = Σ_m |Λ̂∘s|_m w_m + |Λ̂_m| t_m` with `w = |W_j| mag_j + |b_j|`
//! (a matrix–vector product per layer and box), bounds both, and `β̂` moves outward by
//! `err_bound``(2 n_j + 2, E, 1 + Σ w + Σ mag_j)` (the `+2` counts the two roundings inside
//! each product chain; the scale covers underflowing coefficients times `z_j` and `a_j`).

use super::live::{gather_columns, LiveLines};
use super::{
    gemm, one_box, relu_lines, AffineBounds, BoundMethod, BoundsError, OutRow, Relaxation,
};
use crate::network::Mlp;
use crate::rounding::{add_down, add_up, affine_max, affine_min, err_bound, magnitudes};

/// Backward CROWN bounds of `net` over `[lower, upper]` with the given ReLU relaxation.
///
/// [`Relaxation::SameSlope`] returns `a_lower == a_upper` (the paper's single `C`).
pub fn crown(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    relaxation: Relaxation,
) -> Result<AffineBounds, BoundsError> {
    let method = match relaxation {
        Relaxation::Adaptive => BoundMethod::Crown,
        Relaxation::SameSlope => BoundMethod::CrownSameSlope,
    };
    one_box(net, lower, upper, method)
}

/// Buffers for one box at a time, reused across the boxes of one rayon task.
pub(crate) struct Workspace {
    /// Per hidden layer `j`: lower slope `s̲`, upper slope `s̄`, upper intercept `t̄`.
    s_lo: Vec<Vec<f64>>,
    s_up: Vec<Vec<f64>>,
    t_up: Vec<Vec<f64>>,
    /// Per layer `j`: live neurons (`u > 0`) of its pre-activation (hidden layers only).
    live: Vec<Vec<usize>>,
    /// Per layer `j`: `|W_j| mag_j + |b_j|`.
    wmag: Vec<Vec<f64>>,
    /// Per layer `j`: `1 + Σ wmag_j + Σ mag_j`, the scale of the underflow term.
    scale: Vec<f64>,
    /// `mag` of the current layer's input.
    mag: Vec<f64>,
    xmag: Vec<f64>,
    lam: Vec<f64>,
    lam_next: Vec<f64>,
    lam_s: Vec<f64>,
    w_live: Vec<f64>,
    /// The relaxation of the current layer's live neurons, gathered in `live` order.
    lines: LiveLines,
    beta_u: Vec<f64>,
    beta_l: Vec<f64>,
    z_lo: Vec<f64>,
    z_hi: Vec<f64>,
}

/// Most entries a workspace matrix reserves before it is used (8 MB; 2·500² for scenario 2).
const MAX_RESERVED: usize = 1 << 20;

impl Workspace {
    pub(crate) fn new(net: &Mlp) -> Workspace {
        let n_layers = net.layers.len();
        let n_max = net.widths().into_iter().max().unwrap_or(0);
        // Room for the paper-size networks' matrices up front; a pass that needs more grows
        // them (reserving n_max² for a 65,000-wide layer would ask for 68 GB, most unused).
        let square = |k: usize| (k * n_max * n_max).min(MAX_RESERVED);
        Workspace {
            s_lo: vec![Vec::new(); n_layers],
            s_up: vec![Vec::new(); n_layers],
            t_up: vec![Vec::new(); n_layers],
            live: vec![Vec::new(); n_layers],
            wmag: vec![Vec::new(); n_layers],
            scale: vec![1.0; n_layers],
            mag: Vec::with_capacity(n_max),
            xmag: Vec::with_capacity(n_max),
            lam: Vec::with_capacity(square(2)),
            lam_next: Vec::with_capacity(square(2)),
            lam_s: Vec::with_capacity(square(2)),
            w_live: Vec::with_capacity(square(1)),
            lines: LiveLines::default(),
            beta_u: Vec::with_capacity(2 * n_max),
            beta_l: Vec::with_capacity(2 * n_max),
            z_lo: Vec::with_capacity(n_max),
            z_hi: Vec::with_capacity(n_max),
        }
    }
}

/// CROWN into one output row; assumes a validated network and box.
pub(crate) fn crown_into(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    relaxation: Relaxation,
    ws: &mut Workspace,
    row: &mut OutRow<'_>,
) {
    let n_layers = net.layers.len();
    let n0 = net.input_dim();
    magnitudes(lower, upper, &mut ws.xmag);
    ws.mag.clone_from(&ws.xmag);
    let stacked = relaxation == Relaxation::Adaptive;

    for k in 0..n_layers {
        let layer = &net.layers[k];
        // w = |W_k| mag_k + |b_k|: the magnitude of z_k's terms, for the rounding bound.
        let wmag = &mut ws.wmag[k];
        wmag.clear();
        wmag.extend(
            layer
                .weight
                .chunks_exact(layer.n_in)
                .zip(&layer.bias)
                .map(|(w, b)| {
                    w.iter()
                        .zip(&ws.mag)
                        .fold(b.abs(), |s, (w, m)| s + w.abs() * m)
                }),
        );
        ws.scale[k] = 1.0 + wmag.iter().sum::<f64>() + ws.mag.iter().sum::<f64>();

        backward_pass(net, k, stacked, ws);
        let n = layer.n_out;
        let lam = &ws.lam;
        let lower_row = |i: usize| if stacked { n + i } else { i };
        ws.z_lo.clear();
        ws.z_hi.clear();
        for i in 0..n {
            let au = &lam[i * n0..(i + 1) * n0];
            let al = &lam[lower_row(i) * n0..(lower_row(i) + 1) * n0];
            ws.z_hi
                .push(affine_max(au, ws.beta_u[i], lower, upper, &ws.xmag));
            ws.z_lo.push(affine_min(
                al,
                ws.beta_l[lower_row(i)],
                lower,
                upper,
                &ws.xmag,
            ));
        }
        if !ws.z_lo.iter().chain(&ws.z_hi).all(|v| v.is_finite()) {
            // Overflow: give up soundly rather than relax with infinite bounds.
            row.set_unbounded();
            return;
        }

        if k + 1 == n_layers {
            let m = n;
            row.a_upper.copy_from_slice(&lam[..m * n0]);
            row.b_upper.copy_from_slice(&ws.beta_u[..m]);
            let lo_rows = if stacked { m } else { 0 };
            row.a_lower
                .copy_from_slice(&lam[lo_rows * n0..(lo_rows + m) * n0]);
            row.b_lower
                .copy_from_slice(&ws.beta_l[lo_rows..lo_rows + m]);
            row.upper.copy_from_slice(&ws.z_hi);
            row.lower.copy_from_slice(&ws.z_lo);
        } else {
            // Relaxation of a_{k+1} = ReLU(z_k), and the magnitude of a_{k+1}.
            let (s_lo, s_up, t_up, live) = (
                &mut ws.s_lo[k],
                &mut ws.s_up[k],
                &mut ws.t_up[k],
                &mut ws.live[k],
            );
            s_lo.clear();
            s_up.clear();
            t_up.clear();
            live.clear();
            ws.mag.clear();
            for (i, (&l, &u)) in ws.z_lo.iter().zip(&ws.z_hi).enumerate() {
                let (sl, su, t) = relu_lines(l, u, relaxation);
                s_lo.push(sl);
                s_up.push(su);
                t_up.push(t);
                if u > 0.0 {
                    live.push(i);
                }
                ws.mag.push(u.max(0.0));
            }
        }
    }
}

/// Runs the backward pass for layer `k`'s pre-activation: on return `ws.lam` holds `R × n_0`
/// coefficients (`R = 2 n_k` stacked upper-then-lower rows, or `n_k` shared rows) and
/// `ws.beta_u`, `ws.beta_l` the rigorous intercepts (`beta_u` meaningful on upper rows, `beta_l`
/// on lower rows; both on shared rows).
///
/// `Λ` only ever holds the columns of live neurons: the relaxation zeroes the others, so every
/// product computes just the live columns of the next layer (and all inputs at the end).
fn backward_pass(net: &Mlp, k: usize, stacked: bool, ws: &mut Workspace) {
    let layer = &net.layers[k];
    let n_k = layer.n_out;
    let copies = if stacked { 2 } else { 1 };
    let rows = copies * n_k;
    ws.beta_u.clear();
    ws.beta_l.clear();
    for _ in 0..copies {
        ws.beta_u.extend_from_slice(&layer.bias);
        ws.beta_l.extend_from_slice(&layer.bias);
    }
    // Λ = W_k, on the live neurons of layer k − 1.
    ws.lam.clear();
    for _ in 0..copies {
        gather_columns(
            &layer.weight,
            layer.n_in,
            0..n_k,
            k.checked_sub(1).map(|j| &ws.live[j][..]),
            &mut ws.lam,
        );
    }
    for j in (0..k).rev() {
        let lj = &net.layers[j];
        let live = &ws.live[j];
        let n_live = live.len();
        let wmag = &ws.wmag[j];
        let lines = (&ws.s_lo[j][..], &ws.s_up[j][..], &ws.t_up[j][..]);
        ws.lines.gather(live, lines, &lj.bias, |m| wmag[m]);
        let scale = ws.scale[j];
        ws.lam_s.clear();
        ws.lam_s.resize(rows * n_live, 0.0);
        let n_terms = 2 * lj.n_out + 2;
        for r in 0..rows {
            let upper_side = !stacked || r < n_k;
            let [su, sl, mag] = ws.lines.relax_row(
                &ws.lam[r * n_live..(r + 1) * n_live],
                &mut ws.lam_s[r * n_live..(r + 1) * n_live],
                upper_side,
            );
            let err = err_bound(n_terms, mag, scale);
            ws.beta_u[r] = add_up(add_up(ws.beta_u[r], su), err);
            ws.beta_l[r] = add_down(add_down(ws.beta_l[r], sl), -err);
        }
        // Λ ← (Λ∘s) · W_j[live rows, live columns of layer j − 1 (all inputs at j = 0)].
        let next = j.checked_sub(1).map(|i| &ws.live[i][..]);
        let width = next.map_or(lj.n_in, <[usize]>::len);
        ws.w_live.clear();
        gather_columns(
            &lj.weight,
            lj.n_in,
            live.iter().copied(),
            next,
            &mut ws.w_live,
        );
        ws.lam_next.clear();
        ws.lam_next.resize(rows * width, 0.0);
        if n_live > 0 && width > 0 {
            gemm(rows, n_live, width, &ws.lam_s, &ws.w_live, &mut ws.lam_next);
        }
        std::mem::swap(&mut ws.lam, &mut ws.lam_next);
    }
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;
    use crate::bounds::{ibp, network_bounds};

    #[test]
    fn crown_is_sound_on_random_networks_and_boxes() {
        assert_sound_for_both_relaxations(30, crown);
    }

    #[test]
    fn crown_vs_ibp_measured_per_output_asserted_in_aggregate() {
        // Per output this is NOT a theorem for CROWN with backward intermediate bounds (a
        // slope-1 lower line concretises to `Λ·l > 0` where IBP has 0), and it fails on wide
        // boxes of this test set (e.g. [2,16,16,2] seed 0 box 5: crown upper 7.54, ibp 6.13;
        // the independent reference agrees). So it is measured per output, and asserted in
        // aggregate and on every box narrower than 0.3.
        for relaxation in [Relaxation::Adaptive, Relaxation::SameSlope] {
            let (mut looser, mut total, mut width_c, mut width_i) = (0, 0, 0.0, 0.0);
            for_each_case(30, |case| {
                let i = ibp(&case.net, &case.lo, &case.hi).unwrap();
                let c = crown(&case.net, &case.lo, &case.hi, relaxation).unwrap();
                let narrow = case.lo.iter().zip(&case.hi).all(|(l, h)| h - l < 0.3);
                for o in 0..c.n_out {
                    // On point boxes both widths are rounding alone: CROWN's a-priori bounds
                    // (`γ̂_N = (N+3)·2⁻⁵⁰`, the device's unit) run a few 1e-12 wider than
                    // IBP's outward steps after every operation.
                    let slack = 4e-12 * (1.0 + i.upper[o].abs().max(i.lower[o].abs()));
                    let ok = c.upper[o] <= i.upper[o] + slack && c.lower[o] >= i.lower[o] - slack;
                    total += 1;
                    width_c += c.upper[o] - c.lower[o];
                    width_i += i.upper[o] - i.lower[o];
                    if !ok {
                        looser += 1;
                        assert!(
                            !narrow,
                            "{relaxation:?} {} output {o}: crown [{}, {}] ibp [{}, {}]",
                            case.name, c.lower[o], c.upper[o], i.lower[o], i.upper[o]
                        );
                    }
                }
            });
            eprintln!(
                "{relaxation:?}: crown looser than ibp on {looser}/{total} outputs; \
                 total width crown {width_c:.4e}, ibp {width_i:.4e}"
            );
            assert!(width_c < width_i);
        }
    }

    #[test]
    fn adaptive_vs_same_slope_measured() {
        // Not a theorem either (different intermediate bounds and lower lines), so measured;
        // the aggregate is asserted: adaptive is tighter in total width.
        let (mut tighter, mut looser, mut sum_a, mut sum_s) = (0, 0, 0.0, 0.0);
        for_each_case(30, |case| {
            let a = crown(&case.net, &case.lo, &case.hi, Relaxation::Adaptive).unwrap();
            let s = crown(&case.net, &case.lo, &case.hi, Relaxation::SameSlope).unwrap();
            for o in 0..a.n_out {
                let (wa, wsl) = (a.upper[o] - a.lower[o], s.upper[o] - s.lower[o]);
                sum_a += wa;
                sum_s += wsl;
                if wa <= wsl * (1.0 + 1e-12) + 1e-300 {
                    tighter += 1;
                } else {
                    looser += 1;
                }
            }
        });
        eprintln!(
            "adaptive tighter-or-equal on {tighter} outputs, looser on {looser}; \
             total width adaptive {sum_a:.4e}, same-slope {sum_s:.4e}"
        );
        assert!(sum_a <= sum_s);
    }

    /// Straightforward f64 backward CROWN with plain loops, written independently of the
    /// implementation (no rounding widening, no shared helpers). Returns `(lb, ub, A_l, A_u,
    /// b_l, b_u)` of the output layer.
    #[allow(clippy::type_complexity)]
    fn reference_crown(
        net: &Mlp,
        x_lo: &[f64],
        x_hi: &[f64],
        adaptive: bool,
    ) -> (
        Vec<f64>,
        Vec<f64>,
        Vec<Vec<f64>>,
        Vec<Vec<f64>>,
        Vec<f64>,
        Vec<f64>,
    ) {
        let nl = net.layers.len();
        let mut pre_l: Vec<Vec<f64>> = Vec::new();
        let mut pre_u: Vec<Vec<f64>> = Vec::new();
        let mut result = None;
        for k in 0..nl {
            let lk = &net.layers[k];
            let w = |layer: &crate::network::Layer, i: usize, j: usize| {
                layer.weight[i * layer.n_in + j]
            };
            let mut lb = vec![0.0; lk.n_out];
            let mut ub = vec![0.0; lk.n_out];
            let mut al_all = Vec::new();
            let mut au_all = Vec::new();
            let mut bl_all = Vec::new();
            let mut bu_all = Vec::new();
            for i in 0..lk.n_out {
                for upper in [true, false] {
                    // coefficients on a_k
                    let mut a: Vec<f64> = (0..lk.n_in).map(|j| w(lk, i, j)).collect();
                    let mut c = lk.bias[i];
                    for j in (0..k).rev() {
                        let lj = &net.layers[j];
                        // relax a_{j+1} = relu(z_j)
                        let mut az = vec![0.0; lj.n_out];
                        for m in 0..lj.n_out {
                            let (l, u) = (pre_l[j][m], pre_u[j][m]);
                            let (slope_up, icpt_up, slope_lo) = if l >= 0.0 {
                                (1.0, 0.0, 1.0)
                            } else if u <= 0.0 {
                                (0.0, 0.0, 0.0)
                            } else {
                                let s = u / (u - l);
                                let lo = if adaptive {
                                    if u >= -l {
                                        1.0
                                    } else {
                                        0.0
                                    }
                                } else {
                                    s
                                };
                                (s, -s * l, lo)
                            };
                            let use_up = if upper { a[m] >= 0.0 } else { a[m] < 0.0 };
                            if use_up {
                                az[m] = a[m] * slope_up;
                                c += a[m] * icpt_up;
                            } else {
                                az[m] = a[m] * slope_lo;
                            }
                        }
                        // substitute z_j = W_j a_j + b_j
                        let mut na = vec![0.0; lj.n_in];
                        for m in 0..lj.n_out {
                            c += az[m] * lj.bias[m];
                            for p in 0..lj.n_in {
                                na[p] += az[m] * w(lj, m, p);
                            }
                        }
                        a = na;
                    }
                    let mut v = c;
                    for p in 0..a.len() {
                        let pick_hi = (a[p] >= 0.0) == upper;
                        v += a[p] * if pick_hi { x_hi[p] } else { x_lo[p] };
                    }
                    if upper {
                        ub[i] = v;
                        au_all.push(a);
                        bu_all.push(c);
                    } else {
                        lb[i] = v;
                        al_all.push(a);
                        bl_all.push(c);
                    }
                }
            }
            pre_l.push(lb.clone());
            pre_u.push(ub.clone());
            if k + 1 == nl {
                result = Some((lb, ub, al_all, au_all, bl_all, bu_all));
            }
        }
        result.unwrap()
    }

    #[test]
    fn crown_agrees_with_an_independent_reference() {
        let close =
            |a: f64, b: f64, scale: f64| (a - b).abs() <= 1e-9 * (scale + a.abs().max(b.abs()));
        let mut worst: f64 = 0.0;
        for_each_case(24, |case| {
            for (adaptive, relaxation) in
                [(true, Relaxation::Adaptive), (false, Relaxation::SameSlope)]
            {
                let got = crown(&case.net, &case.lo, &case.hi, relaxation).unwrap();
                let (lb, ub, al, au, bl, bu) =
                    reference_crown(&case.net, &case.lo, &case.hi, adaptive);
                let scale = 1.0 + ub.iter().chain(&lb).fold(0.0f64, |s, v| s.max(v.abs()));
                for o in 0..got.n_out {
                    worst = worst.max((got.upper[o] - ub[o]).abs() / scale);
                    worst = worst.max((got.lower[o] - lb[o]).abs() / scale);
                    assert!(
                        close(got.upper[o], ub[o], scale) && close(got.lower[o], lb[o], scale),
                        "{} {relaxation:?} output {o}: got [{}, {}], reference [{}, {}]",
                        case.name,
                        got.lower[o],
                        got.upper[o],
                        lb[o],
                        ub[o]
                    );
                    assert!(
                        close(got.b_upper[o], bu[o], scale) && close(got.b_lower[o], bl[o], scale)
                    );
                    for p in 0..got.n_in {
                        assert!(
                            close(got.a_upper_row(o)[p], au[o][p], scale),
                            "{}",
                            case.name
                        );
                        assert!(
                            close(got.a_lower_row(o)[p], al[o][p], scale),
                            "{}",
                            case.name
                        );
                    }
                }
            }
        });
        eprintln!("max relative difference to the reference: {worst:e}");
    }

    #[test]
    fn shrinking_crown_by_one_percent_lets_points_escape() {
        // Guards the soundness test itself: the bounds are tight enough that a 1 % shrink of
        // [lower, upper] towards its centre is caught by sampling on some case.
        let mut caught = 0;
        for_each_case(30, |case| {
            let b = crown(&case.net, &case.lo, &case.hi, Relaxation::Adaptive).unwrap();
            let mut shrunk = b.clone();
            for o in 0..b.n_out {
                let (c, r) = (
                    0.5 * (b.lower[o] + b.upper[o]),
                    0.5 * (b.upper[o] - b.lower[o]),
                );
                shrunk.lower[o] = c - 0.99 * r;
                shrunk.upper[o] = c + 0.99 * r;
            }
            if check_bounds(&case.net, &case.lo, &case.hi, &shrunk, &case.points).is_err() {
                caught += 1;
            }
        });
        assert!(caught > 0, "no case detected a 1% shrink");
        eprintln!("1% shrink caught on {caught} cases");
    }

    #[test]
    fn single_layer_network_is_exact_affine() {
        let net = Mlp::random(&[3, 2], 5);
        let b = network_bounds(&net, &[-1.0; 3], &[1.0; 3], BoundMethod::CrownSameSlope).unwrap();
        assert_eq!(b.a_upper, net.layers[0].weight);
        assert_eq!(b.a_lower, net.layers[0].weight);
        assert!(b
            .b_lower
            .iter()
            .zip(&net.layers[0].bias)
            .all(|(l, c)| l <= c));
        assert!(b
            .b_upper
            .iter()
            .zip(&net.layers[0].bias)
            .all(|(u, c)| u >= c));
    }
}

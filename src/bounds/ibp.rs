//! Interval bound propagation (IBP, Gowal et al. 2018): `C = 0`, `d̲, d̄` the interval bounds.
//!
//! Intervals are kept as centre and radius, `z ∈ [c − r, c + r]`; an affine layer maps them to
//! `(W c + b, |W| r)` (equal to `[W⁺l + W⁻u + b, W⁺u + W⁻l + b]`), and `ReLU` is monotone:
//! `[max(l, 0), max(u, 0)]`. For a group of `G` boxes a layer is three GEMMs
//! `(n_k × n_{k−1})·(n_{k−1} × G)`: `W c`, `|W| r`, and the rounding magnitude `|W| (|c| + r)`.
//!
//! Rounding (module error model of [`crate::bounds`]): the computed `W c + b` and `|W| r` err by
//! at most `γ (|W| (|c| + r) + |b|)` together (`n_{k−1} + 1` terms), which is added to `r`
//! rounded up; the centre and radius of an interval are chosen so that `[l, u] ⊆ [c − r, c + r]`
//! exactly (`r` rounded up), and `c ∓ r` are rounded outward.

use super::gemm;
use super::{one_box, AffineBounds, BoundMethod, BoundsError, OutRow, PreparedNetwork, Schedule};
use crate::network::Mlp;
use crate::rounding::{add_down, add_up, err_bound, round_up_keep_zero};

/// IBP bounds of `net` over `[lower, upper]` (affine forms with `C = 0`).
pub fn ibp(net: &Mlp, lower: &[f64], upper: &[f64]) -> Result<AffineBounds, BoundsError> {
    one_box(net, lower, upper, BoundMethod::Ibp)
}

/// Buffers for one group of boxes.
#[derive(Default)]
pub(crate) struct Workspace {
    c: Vec<f64>,
    r: Vec<f64>,
    v: Vec<f64>,
    c_next: Vec<f64>,
    r_next: Vec<f64>,
    e: Vec<f64>,
}

/// IBP for a validated batch, into `rows` (one per box): groups of boxes as GEMMs, in parallel.
pub(crate) fn ibp_batch_into(
    prepared: &PreparedNetwork<'_>,
    lower: &[f64],
    upper: &[f64],
    schedule: Schedule<'_, Workspace>,
    rows: &mut [OutRow<'_>],
) {
    let (net, abs_w) = (prepared.net(), &prepared.abs_w);
    super::for_each_group(
        net,
        lower,
        upper,
        rows,
        MAX_GROUP,
        schedule,
        |ws: &mut Workspace, lo, hi, rows| ibp_group(net, abs_w, lo, hi, rows, ws),
    );
}

/// Largest number of boxes propagated together in one GEMM.
const MAX_GROUP: usize = 256;

/// One group of boxes; intervals as `[c − r, c + r]`, matrices `n_k × G` (column = box).
fn ibp_group(
    net: &Mlp,
    abs_w: &[Vec<f64>],
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    ws: &mut Workspace,
) {
    let n0 = net.input_dim();
    let g_count = rows.len();
    ws.c.clear();
    ws.c.resize(n0 * g_count, 0.0);
    ws.r.clear();
    ws.r.resize(n0 * g_count, 0.0);
    for g in 0..g_count {
        for p in 0..n0 {
            let (l, h) = (lower[g * n0 + p], upper[g * n0 + p]);
            let (c, r) = centre_radius(l, h);
            ws.c[p * g_count + g] = c;
            ws.r[p * g_count + g] = r;
        }
    }
    let n_layers = net.layers.len();
    for (k, layer) in net.layers.iter().enumerate() {
        let (n, n_prev) = (layer.n_out, layer.n_in);
        ws.v.clear();
        ws.v.extend(ws.c.iter().zip(&ws.r).map(|(c, r)| c.abs() + r));
        for buf in [&mut ws.c_next, &mut ws.r_next, &mut ws.e] {
            buf.resize(n * g_count, 0.0); // overwritten by the products below
        }
        gemm(n, n_prev, g_count, &layer.weight, &ws.c, &mut ws.c_next);
        gemm(n, n_prev, g_count, &abs_w[k], &ws.r, &mut ws.r_next);
        gemm(n, n_prev, g_count, &abs_w[k], &ws.v, &mut ws.e);
        for i in 0..n {
            let b = layer.bias[i];
            for g in 0..g_count {
                let at = i * g_count + g;
                ws.c_next[at] += b;
                let err = err_bound(n_prev + 1, ws.e[at] + b.abs(), 1.0);
                ws.r_next[at] = add_up(ws.r_next[at], err);
            }
        }
        std::mem::swap(&mut ws.c, &mut ws.c_next);
        std::mem::swap(&mut ws.r, &mut ws.r_next);
        if k + 1 < n_layers {
            // ReLU is monotone: [max(l, 0), max(u, 0)], back to centre–radius.
            for (c, r) in ws.c.iter_mut().zip(ws.r.iter_mut()) {
                let l = add_down(*c, -*r).max(0.0);
                let u = add_up(*c, *r).max(0.0);
                (*c, *r) = centre_radius(l, u);
            }
        }
    }
    for (g, row) in rows.iter_mut().enumerate() {
        for i in 0..row.lower.len() {
            let (c, r) = (ws.c[i * g_count + g], ws.r[i * g_count + g]);
            row.lower[i] = add_down(c, -r);
            row.upper[i] = add_up(c, r);
        }
        row.a_lower.fill(0.0);
        row.a_upper.fill(0.0);
        row.b_lower.copy_from_slice(row.lower);
        row.b_upper.copy_from_slice(row.upper);
    }
}

/// `(c, r)` with `[l, h] ⊆ [c − r, c + r]` in exact arithmetic (`r` rounded up).
#[inline]
pub(crate) fn centre_radius(l: f64, h: f64) -> (f64, f64) {
    let c = 0.5 * l + 0.5 * h;
    (c, round_up_keep_zero(h - c).max(round_up_keep_zero(c - l)))
}

#[cfg(test)]
#[allow(clippy::needless_range_loop)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;

    #[test]
    fn centre_radius_contains_the_interval_and_keeps_flat_ones_exact() {
        let tiny = f64::from_bits(1);
        let cases = [
            (1.0, 1.0),
            (0.0, 0.0),
            (-3.5, -3.5),
            (tiny, tiny),
            (-tiny, tiny),
            (0.1, 0.3),
            (-1e300, 1e300),
            (1.0, 1.0 + f64::EPSILON),
            (-2.0 * tiny, 3.0 * tiny),
        ];
        for (l, h) in cases {
            let (c, r) = centre_radius(l, h);
            // [l, h] ⊆ [c − r, c + r] in exact arithmetic, compared through TwoSum: c ∓ r is
            // exactly s + e, and rounding is monotone, so s decides unless s equals the bound.
            let two_sum = |a: f64, b: f64| {
                let s = a + b;
                let bb = s - a;
                (s, (a - (s - bb)) + (b - bb))
            };
            let (s_lo, e_lo) = two_sum(c, -r);
            let (s_hi, e_hi) = two_sum(c, r);
            assert!(
                (s_lo < l || s_lo == l && e_lo <= 0.0) && (s_hi > h || s_hi == h && e_hi >= 0.0),
                "[{l}, {h}] → ({c}, {r})"
            );
            if l == h && l.abs() >= f64::MIN_POSITIVE || l == 0.0 && h == 0.0 {
                // Flat intervals of normal numbers: exact centre and no subnormal radius.
                assert_eq!((c, r), (l, 0.0), "[{l}, {h}]");
            }
            assert!(r == 0.0 || r >= tiny);
        }
    }

    #[test]
    fn ibp_is_sound_on_random_networks_and_boxes() {
        for_each_case(40, |case| {
            let b = ibp(&case.net, &case.lo, &case.hi).unwrap();
            assert!(b.a_lower.iter().chain(&b.a_upper).all(|&a| a == 0.0));
            check_bounds(&case.net, &case.lo, &case.hi, &b, &case.points)
                .unwrap_or_else(|e| panic!("{}: {e}", case.name));
        });
    }

    #[test]
    fn ibp_on_a_point_is_a_tight_enclosure() {
        let net = Mlp::random(&[2, 16, 16, 2], 3);
        let x = [0.3, -0.7];
        let b = ibp(&net, &x, &x).unwrap();
        let y = net.forward(&x);
        for i in 0..2 {
            assert!(b.lower[i] <= y[i] + 1e-12 && y[i] <= b.upper[i] + 1e-12);
            assert!(
                b.upper[i] - b.lower[i] < 1e-12,
                "width {}",
                b.upper[i] - b.lower[i]
            );
        }
    }
}

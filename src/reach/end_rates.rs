//! The validated step's second-order end rates (item 4 of [`super::validated`]'s argument):
//! where a face's end may be bounded closer than by the slab rates, by a quadratic barrier on
//! the slab ([`curved_rates`]) or by a Taylor form where the field is one smooth function on the
//! flowpipe ([`taylor_rates`], [`taylor_network_rates`]). Callers meet these with the slab rates.

use super::embedding::{interaction_row, Dynamics, NetworkBoundsRef};
use super::validated::{depth, form_on, point, slab, Flowpipe};
use crate::boxes::IntervalBox;
use crate::intervals::{box_of, Interval};
use crate::rounding::{round_down, round_up};

/// Second-order end rates on the slabs (item 4 of the module's argument): `(r̲, r̄)` with
/// `x̄ᵢ(h) ≤ x̄ᵢ + h·r̄ᵢ` and `x̲ᵢ(h) ≥ x̲ᵢ + h·r̲ᵢ` for every trajectory, where the slab rates
/// bound `Fᵢ` over the whole slab ([`slab_field`](super::validated::slab_field); the loss per step is then about
/// `h²·|∂F|·|F|`, here half that). An end the argument does not reach is `∓∞` (the caller meets
/// these with the other rates). `nn` as for [`slab_field`](super::validated::slab_field).
///
/// Upper end of `i` (the lower mirrored): on the slab, `Fᵢ(x) ≤ c + Σⱼ kⱼ(xⱼ − pⱼ)` with
/// `pᵢ = x̄ᵢ` and `pⱼ` the set's centre (`validated::form_on`); at time `τ` every trajectory
/// lies in `X(τ) = [x̲ + τa̲, x̄ + τā]` (the moving box's rates where the step proved it, else
/// `F̲(A), F̄(A)`). Over `X(τ) ∩ {xᵢ = x̄ᵢ + y}` the form is at most `G₀ + τQ + sup kᵢy`, with
/// `G₀` its sup over the set's face and `Q = Σ_{j≠i} max(kⱼa̲ⱼ, kⱼāⱼ)` (each end's product). The
/// barrier `u(τ) = x̄ᵢ + τa + τ²b/2` with `a = G₀` and `b ≥ Q + sup kᵢ·[w̲, w̄]`,
/// `[w̲, w̄] ∋ a + τb/2` (so `u − x̄ᵢ ∈ τ[w̲, w̄]`), is never crossed: a trajectory first reaching
/// `u + εe^{Lτ}` (`L > |kᵢ|`, `ε → 0`) at `τ*` does so in `X(τ*)` with `xᵢ ≥ u(τ*)`, inside the
/// slab where `u` stays in its `i`-range (checked), with rate at most
/// `G₀ + τ*(Q + sup kᵢw) + |kᵢ|εe^{Lτ*} < u' + εLe^{Lτ*}`. So `r̄ᵢ = a + hb/2`; any `a ≥ G₀`
/// does, and [`barrier`] raises `a` to the slab's depth where `G₀` lies below it.
pub fn curved_rates<'a>(
    dynamics: &Dynamics,
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    nn: impl Fn(usize, bool) -> NetworkBoundsRef<'a>,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = dynamics.n;
    let rates = |j: usize| match &pipe.faces {
        Some(m) => (m.lower[j], m.upper[j]),
        None => (pipe.f_lower[j], pipe.f_upper[j]),
    };
    let mut dl = vec![f64::NEG_INFINITY; n];
    let mut du = vec![f64::INFINITY; n];
    for i in 0..n {
        for up in [false, true] {
            let (lo, hi) = slab(set, pipe, h, i, up);
            let e = if up { set.upper[i] } else { set.lower[i] };
            let mut p: Vec<f64> = (0..n)
                .map(|j| set.lower[j] + 0.5 * (set.upper[j] - set.lower[j]))
                .collect();
            p[i] = e;
            if (0..n).any(|j| !(lo[j] <= p[j] && p[j] <= hi[j])) {
                continue;
            }
            let (c, k) = form_on(dynamics, &lo, &hi, &p, i, up, nn(i, up), margin);
            // The lower end is the upper end of `yᵢ = −xᵢ`: `−Fᵢ ≤ −c̲ + Σ_{j≠i}(−kⱼ)(xⱼ − pⱼ)
            // + kᵢ(yᵢ + x̲ᵢ)`, so `c` and the other slopes are negated, `kᵢ` is not.
            let k: Vec<(f64, f64)> = k
                .iter()
                .enumerate()
                .map(|(j, k)| match up || j == i {
                    true => (k.lower, k.upper),
                    false => (-k.upper, -k.lower),
                })
                .collect();
            let c_up = if up { c.upper } else { -c.lower };
            let others = (0..n).filter(|&j| j != i).map(|j| {
                let d = (set.lower[j] - p[j], set.upper[j] - p[j]);
                let (a_lo, a_hi) = rates(j);
                (k[j], (round_down(d.0), round_up(d.1)), (a_lo, a_hi))
            });
            // The slab's bottom in the end's sign (`slab`'s `min(0, depth)`): `u` stays above it.
            let floor = match up {
                true => depth(pipe, i, true).min(0.0),
                false => (-depth(pipe, i, false)).min(0.0),
            };
            let Some((r, w_lo, w_hi)) = barrier(c_up, others, k[i], h, floor) else {
                continue;
            };
            // `u` must stay in the slab's `i`-range: `x̄ᵢ + h·min(0, w̲) ≥` its bottom (for the
            // lower end: `x̲ᵢ − h·min(0, w̲) ≤` its top).
            let reach = (point(h) * point(w_lo.min(0.0))).lower;
            let inside = match up {
                true => (point(e) + point(reach)).lower >= lo[i],
                false => (point(e) - point(reach)).upper <= hi[i],
            };
            if inside && w_hi.is_finite() {
                match up {
                    true => du[i] = r,
                    false => dl[i] = -r,
                }
            }
        }
    }
    (dl, du)
}

/// [`curved_rates`]' barrier for one upper end, in that end's sign: `c` the form's upper value
/// at `p`, per other coordinate `(k, (d̲, d̄), (a̲, ā))` (slopes, the set's offsets from `p`, its
/// ends' rates), `kᵢ`, and `floor`, the lowest first rate the end's slab was built for
/// (`min(0, depth)` in the end's sign): the barrier's `a` is `max(G₀, floor)`. Any `a ≥ G₀`
/// keeps the argument, and below the floor `u` would leave the slab: where `G₀` dips under it
/// by rounding alone (a face at rest, `G₀ ≈ 0` under a slab that starts at the end) the end
/// keeps its second-order rate instead of losing it to the last ulp of `c`. Returns
/// `(a + hb/2, w̲, w̄)`, rounded up, or `None` where `b` does not settle (`h·k̄ᵢ ≥ 2`, where
/// no `b` bounds the growth) or a value is not finite. `barrier` in `shaders/end_rates.wgsl` mirrors it.
pub fn barrier(
    c: f64,
    others: impl Iterator<Item = ((f64, f64), (f64, f64), (f64, f64))>,
    k_i: (f64, f64),
    h: f64,
    floor: f64,
) -> Option<(f64, f64, f64)> {
    let up = |x: Interval| x.upper;
    let sup = |(k0, k1): (f64, f64), (x0, x1): (f64, f64)| {
        [k0, k1]
            .iter()
            .flat_map(|&k| [x0, x1].map(|x| up(point(k) * point(x))))
            .fold(f64::NEG_INFINITY, f64::max)
    };
    let (mut g0, mut q) = (point(c), point(0.0));
    for (k, d, a) in others {
        g0 = g0 + point(sup(k, d));
        q = q + point(sup(k, a));
    }
    let (a, q) = (g0.upper.max(floor), q.upper);
    let half_h = point(h) * point(0.5);
    let mut b = up(point(q) + point(sup(k_i, (a, a))));
    // Start from the fixed point itself where it has a closed form ([`fixed_point`]): iterated
    // to from below, four steps stopped short of it wherever `h·kᵢ` is not small, and the end
    // lost its second-order rate (scenario 1's leaves that pass under the obstacle, `h·kᵢ` up
    // to 0.13, grew half as wide again by t = 1).
    if let Some(fixed) = fixed_point(q, a, k_i, h) {
        b = b.max(fixed);
    }
    for _ in 0..4 {
        // `a + τb/2` runs from `a` to `a + hb/2`: `a` is one end exactly (rounding it would
        // put a barrier raised to its floor an ulp below the slab).
        let end = point(a) + half_h * point(b);
        let w = match b >= 0.0 {
            true => (a, end.upper.max(a)),
            false => (end.lower.min(a), a),
        };
        let s = sup(k_i, w);
        let need = up(point(q) + point(s));
        if !(need.is_finite() && b.is_finite() && a.is_finite()) {
            return None;
        }
        if need <= b {
            return Some((up(point(a) + half_h * point(b)), w.0, w.1));
        }
        // Past the fixed point by more than the rounding of `need`: any `b` is sound (the check
        // above decides), and without the margin the GPU's coarser outward steps (4 ulp) keep
        // `need` a few ulps above `b` while it creeps up to the fixed point, never settling.
        b = need + BARRIER_OVERSHOOT * (q.abs() + s.abs());
    }
    None
}

/// The least `b` with `b ≥ q + sup kᵢ·[w̲, w̄]`, `{w̲, w̄} = {a, a + hb/2}`, rounded up: the
/// right side is the largest of the lines `q + k·a` and `q + k·a + (k·h/2)·b` (`k` either end
/// of `kᵢ`), each at most `b` exactly where `b ≥ (q + k·a)/(1 − k·h/2)` (slopes `k·h/2 < 1`);
/// a little past it. `None` where a slope is above 1/2: near 1 the rounding of `need` outgrows
/// any margin (and past 1 no `b` bounds its line); the iteration then goes on as before.
/// [`barrier`] checks it.
/// `fixed_point` in `shaders/end_rates.wgsl` mirrors it.
pub fn fixed_point(q: f64, a: f64, (k0, k1): (f64, f64), h: f64) -> Option<f64> {
    let half_h = point(h) * point(0.5);
    let mut b = f64::NEG_INFINITY;
    for k in [k0, k1] {
        let gap = point(1.0) - point(k) * half_h;
        if gap.lower.is_nan() || gap.lower < 0.5 {
            return None;
        }
        let line = point(q) + point(k) * point(a);
        b = b.max(line.upper).max((line / gap).upper);
    }
    // Past it by [`BARRIER_OVERSHOOT`] of `|q| + |s|` (`s = b − q` there), so that `need`'s own
    // rounding does not leave it an ulp above `b`.
    let b = b + BARRIER_OVERSHOOT * (q.abs() + (b - q).abs());
    b.is_finite().then_some(b)
}

/// [`barrier`]'s step past its fixed point, relative to the magnitudes summed (`2¹⁰` ulp; the
/// shaders' `BARRIER_OVERSHOOT` is the same in their unit, 1.2e-4 in f32).
const BARRIER_OVERSHOOT: f64 = 1024.0 * f64::EPSILON;

/// Second-order rates where the field is one smooth function `Φ` on the flowpipe (a proven
/// piece of the filter): `x(h) = x₀ + hΦ(x₀) + ∫₀ʰ (h − s) DΦ(x(s)) ẋ(s) ds`, so
/// `x(h) ∈ x₀ + hΦ(x₀) + h²/2 · DΦ(B)·F(B)`. `euler` bounds the Euler part on the set's faces
/// (the embedding's face bounds), which bound `x₀ + hΦ(x₀)` over the set where `xᵢ + hΦᵢ(x)`
/// grows with `xᵢ`, i.e. `1 + h·∂ᵢΦᵢ ≥ 0` on the set: checked, `None` where it fails. The
/// rates `(euler + h/2·[DΦ(B)F(B)])` then bound the step's end like the slab rates (their meet
/// is sound), with a loss of `O(h²)·width` per step instead of the slabs' `O(h²)·|F|`.
pub fn taylor_rates(
    dynamics: &Dynamics,
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    (dl, du): (Vec<f64>, Vec<f64>),
) -> Option<(Vec<f64>, Vec<f64>)> {
    // `F(B)` is known only where Picard–Lindelöf proved the flowpipe.
    if !pipe.enclosed {
        return None;
    }
    let n = dynamics.n;
    let x: Vec<Interval> = box_of(&set.lower, &set.upper);
    let b: Vec<Interval> = box_of(&pipe.set.lower, &pipe.set.upper);
    let f: Vec<Interval> = box_of(&pipe.f_lower, &pipe.f_upper);
    let half_h = point(h) * point(0.5);
    let mut lo = Vec::with_capacity(n);
    let mut hi = Vec::with_capacity(n);
    for i in 0..n {
        let diag = dynamics.f_tilde_jacobian[i][i].eval_interval(&x);
        let monotone = (point(1.0) + point(h) * diag).lower;
        if monotone.is_nan() || monotone < 0.0 {
            return None;
        }
        let r = (0..n).fold(point(0.0), |acc, j| {
            acc + dynamics.f_tilde_jacobian[i][j].eval_interval(&b) * f[j]
        });
        if !(r.lower.is_finite() && r.upper.is_finite()) {
            return None;
        }
        lo.push((point(dl[i]) + half_h * point(r.lower)).lower);
        hi.push((point(du[i]) + half_h * point(r.upper)).upper);
    }
    Some((lo, hi))
}

/// Third-order-remainder rates where the field is one smooth function `Φ` on the flowpipe:
/// with `G = DΦ·Φ` (`ẍ = G(x)`), `x(h) = x₀ + hΦ(x₀) + h²/2·G(x₀) + ∫₀ʰ (h − s)²/2·DG(x(s))ẋ(s) ds`,
/// so `x(h) ∈ ψ(x₀) + h³/6·DG(B)·F(B)` with `ψ(x) = x + hΦ(x) + h²/2·G(x)`. Where
/// `1 + h·∂ᵢΦᵢ + h²/2·∂ᵢGᵢ ≥ 0` on the set (checked; `None` otherwise) `ψᵢ` is largest on the face
/// `xᵢ = x̄ᵢ`, where it is at most `x̄ᵢ + h·euler` (the face bound of `Φᵢ`) plus `h²/2` times
/// `Gᵢ`'s mean-value form on that face (mirrored below). Against [`taylor_rates`] the
/// `h²/2·G` term is taken on the faces, not over the flowpipe: what the set's own width makes it
/// vary by, not the `h·|F|` the flowpipe adds, and the remainder is `O(h³)`.
pub fn taylor3_rates(
    dynamics: &Dynamics,
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    (dl, du): (Vec<f64>, Vec<f64>),
) -> Option<(Vec<f64>, Vec<f64>)> {
    if !pipe.enclosed {
        return None;
    }
    let n = dynamics.n;
    let second = dynamics.second_order();
    let x: Vec<Interval> = box_of(&set.lower, &set.upper);
    let b: Vec<Interval> = box_of(&pipe.set.lower, &pipe.set.upper);
    let f: Vec<Interval> = box_of(&pipe.f_lower, &pipe.f_upper);
    let half_h = point(h) * point(0.5);
    let h2_6 = point(h) * point(h) / point(6.0);
    let centre: Vec<f64> = (0..n)
        .map(|j| set.lower[j] + 0.5 * (set.upper[j] - set.lower[j]))
        .collect();
    // `DG` (and `∂ᵢf̃ᵢ` after it) over the set and over the flowpipe.
    let mut on_set = vec![point(0.0); n * n + n];
    let mut on_pipe = vec![point(0.0); n * n + n];
    second.g_jacobian.eval_interval(&x, &mut on_set);
    second.g_jacobian.eval_interval(&b, &mut on_pipe);
    let (mut on_face, mut g_at) = (vec![point(0.0); n * n + n], vec![point(0.0); n]);
    // A face of the set and its centre: coordinate `i` pinned to the end, the rest as they are.
    let mut face = x.clone();
    let mut p: Vec<Interval> = centre.iter().map(|&c| point(c)).collect();
    let (mut lo, mut hi) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n {
        let slope =
            point(1.0) + point(h) * on_set[n * n + i] + half_h * point(h) * on_set[i * n + i];
        if slope.lower.is_nan() || slope.lower < 0.0 {
            return None;
        }
        let r = (0..n).fold(point(0.0), |acc, j| acc + on_pipe[i * n + j] * f[j]);
        let mut ends = [0.0; 2];
        for (side, on_upper) in [false, true].into_iter().enumerate() {
            let at = if on_upper { set.upper[i] } else { set.lower[i] };
            face[i] = point(at);
            p[i] = point(at);
            second.g.eval_interval(&p, &mut g_at);
            second.g_jacobian.eval_interval(&face, &mut on_face);
            let g = (0..n).filter(|&j| j != i).fold(g_at[i], |acc, j| {
                acc + on_face[i * n + j] * (face[j] - p[j])
            });
            let end = match on_upper {
                true => (point(du[i]) + half_h * point(g.upper) + h2_6 * point(r.upper)).upper,
                false => (point(dl[i]) + half_h * point(g.lower) + h2_6 * point(r.lower)).lower,
            };
            if !end.is_finite() {
                return None;
            }
            ends[side] = end;
        }
        (face[i], p[i]) = (x[i], point(centre[i]));
        lo.push(ends[0]);
        hi.push(ends[1]);
    }
    Some((lo, hi))
}

/// Second-order rates for the network's field `f̃ + B(N + w)` (constant `g = B`), from affine
/// bounds `C̲x + d̲ ≤ N(x) ≤ C̄x + d̄` valid on the flowpipe `B` (`nn`). Every trajectory stays in
/// `B`, so `xᵢ(h) ≤ x₀ᵢ + ∫₀ʰ φ̄ᵢ(x(s)) ds` with the smooth `φ̄ᵢ(x) = f̃ᵢ(x) + m̄ᵢ·x + δ̄ᵢ` (the
/// interaction-aware row: `m̄ᵢ = B⁺C̄ + B⁻C̲`, `δ̄ᵢ` with `d̄, d̲` widened by `M`), and
/// `∫₀ʰ φ̄ᵢ(x(s)) ds ∈ h·φ̄ᵢ(x₀) + h²/2·(Df̃ᵢ(B) + m̄ᵢ)·F(B)`. The Euler part is maximal on the
/// face `xᵢ = x̄ᵢ` where `1 + h(∂ᵢf̃ᵢ + m̄ᵢᵢ) ≥ 0` on the set (checked; `None` otherwise), and the
/// embedding's face bound (with `nn` over `B`) bounds it there. Mirrored for the lower end.
pub fn taylor_network_rates(
    dynamics: &Dynamics,
    set: &IntervalBox,
    pipe: &Flowpipe,
    h: f64,
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> Option<(Vec<f64>, Vec<f64>)> {
    let b = dynamics.g_constant.as_ref()?;
    if !pipe.enclosed {
        return None;
    }
    let n = dynamics.n;
    let (dl, du) = super::embedding::embedding_field(dynamics, &set.lower, &set.upper, nn, margin);
    let x: Vec<Interval> = box_of(&set.lower, &set.upper);
    let bb: Vec<Interval> = box_of(&pipe.set.lower, &pipe.set.upper);
    let f: Vec<Interval> = box_of(&pipe.f_lower, &pipe.f_upper);
    let half_h = point(h) * point(0.5);
    let (mut lo, mut hi) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n {
        let jac_x = dynamics.f_tilde_jacobian[i][i].eval_interval(&x);
        let jac_b: Vec<Interval> = dynamics.f_tilde_jacobian[i]
            .iter()
            .map(|e| e.eval_interval(&bb))
            .collect();
        let mut ends = [0.0; 2];
        for (side, on_upper) in [false, true].into_iter().enumerate() {
            let (row, _) = interaction_row(b, dynamics, nn, margin, i, on_upper);
            let monotone = (point(1.0) + point(h) * (jac_x + row[i])).lower;
            if monotone.is_nan() || monotone < 0.0 {
                return None;
            }
            let r = (0..n).fold(point(0.0), |acc, j| acc + (jac_b[j] + row[j]) * f[j]);
            if !(r.lower.is_finite() && r.upper.is_finite()) {
                return None;
            }
            ends[side] = if on_upper {
                (point(du[i]) + half_h * point(r.upper)).upper
            } else {
                (point(dl[i]) + half_h * point(r.lower)).lower
            };
        }
        lo.push(ends[0]);
        hi.push(ends[1]);
    }
    Some((lo, hi))
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A face whose own slope `kᵢ ∈ [0.53, 3.25]` makes `h·kᵢ/2` 0.065 (scenario 1's leaves under
    /// the obstacle, `h = 0.04`): four steps from below left `b` short of its fixed point and
    /// the end without a rate. From the closed form it settles, its `b` bounds `need` over the
    /// whole `[w̲, w̄]`, and it lies within a margin of the least such `b` (iterated to the end).
    #[test]
    fn the_barrier_settles_where_the_face_grows_with_itself() {
        let (c, k_i, h) = (1.3037, (0.5317, 3.2527), 0.04);
        let others = || std::iter::once(((-0.2, 0.4), (-0.06, 0.06), (0.72, 0.81)));
        let (r, w_lo, w_hi) = barrier(c, others(), k_i, h, 0.0).expect("the barrier settles");
        // The same sums as `barrier`'s, in f64: `q`, `a` and the least fixed point.
        let q = 0.4 * 0.81;
        let a = c + 0.4 * 0.06;
        let need = |b: f64| {
            q + [a, a + 0.5 * h * b]
                .map(|w| k_i.1 * w)
                .iter()
                .fold(0.0f64, |m, x| m.max(*x))
        };
        let mut least = 0.0;
        for _ in 0..200 {
            least = need(least);
        }
        let b = 2.0 * (r - a) / h;
        assert!(
            b >= least && b - least < 1e-9 * least,
            "{b} against {least}"
        );
        assert!(
            (w_lo - a).abs() < 1e-12 && w_hi >= a + 0.5 * h * least,
            "[{w_lo}, {w_hi}]"
        );
        assert!(need(b) <= b + 1e-12);
    }

    /// Where a slope `k·h/2` passes 1 no `b` bounds the growth: no barrier, as before.
    #[test]
    fn no_barrier_where_the_face_outgrows_the_step() {
        assert_eq!(
            barrier(1.0, std::iter::empty(), (0.0, 60.0), 0.04, 0.0),
            None
        );
        assert_eq!(fixed_point(0.0, 1.0, (0.0, 30.0), 0.04), None);
    }
}

//! Joint bounds of `N − v` over a cell: where `v`'s form is known there (one smooth function,
//! or a closed form's one row binding on part of the cell), `N`'s affine bounds and `v`'s
//! mean-value form share their slope, which cancels, so a cell pays for how far `N` is from `v`
//! rather than for the range of either (design §2.1).

use super::certify::{error_from, sum};
use crate::bounds::AffineBounds;
use crate::boxes::IntervalBox;
use crate::filter::{Kink, SmoothV, VShape};
use crate::intervals::Interval;
use crate::rounding::round_up;

/// Two affine lower bounds over a cell in centred form, `ℓₖ(x) = pₖ·(x − c) + Kₖ` (intervals
/// for the coefficients, so that rounding and the Jacobian's width are inside them), and the
/// cell about its centre, `X − c`.
struct CentredPair {
    p: [Vec<Interval>; 2],
    k: [Interval; 2],
    dx: Vec<Interval>,
}

impl CentredPair {
    /// `ℓ₁ = N`'s affine form `a·x + d`, `ℓ₂ = ℓ₁ − F` by `F`'s mean-value form over the cell,
    /// `N − F ≥ (a·c + d − F(c)) + (a − J_F(X))(x − c)`, so that their common slope cancels. A
    /// lower form of `N` as it is; with `negate` an upper one, both negated, so that the pair
    /// bounds `−N` and `−(N − F)` from below.
    fn of(a: &[f64], d: f64, sv: &SmoothV, cell: &IntervalBox, j: usize, negate: bool) -> Self {
        let n = a.len();
        let sign = Interval::point(if negate { -1.0 } else { 1.0 });
        let c: Vec<Interval> = sv.centre.iter().map(|&x| Interval::point(x)).collect();
        let dx: Vec<Interval> = (0..n)
            .map(|i| Interval::new(cell.lower[i], cell.upper[i]) - c[i])
            .collect();
        let a: Vec<Interval> = a.iter().map(|&ai| Interval::point(ai)).collect();
        let k1 = sum((0..n).map(|i| a[i] * c[i])) + Interval::point(d);
        let p2: Vec<Interval> = (0..n).map(|i| (a[i] - sv.jac[j * n + i]) * sign).collect();
        let p1: Vec<Interval> = a.iter().map(|&ai| ai * sign).collect();
        CentredPair {
            p: [p1, p2],
            k: [k1 * sign, (k1 - sv.value[j]) * sign],
            dx,
        }
    }

    /// A lower bound of `p·(x − c) + K` over the cell; −∞ on NaN.
    fn inf(&self, p: impl Iterator<Item = Interval>, k: Interval) -> f64 {
        let v = (k + sum(p.zip(&self.dx).map(|(pi, &di)| pi * di))).lower;
        if v.is_nan() {
            f64::NEG_INFINITY
        } else {
            v
        }
    }

    /// A lower bound of `ℓ₂` over the cell: of `N − F` (negated: of `F − N`).
    fn joint_inf(&self) -> f64 {
        self.inf(self.p[1].iter().copied(), self.k[1])
    }

    /// A lower bound of `inf_x max(ℓ₁(x), ℓ₂(x))` over the cell: `max(ℓ₁, ℓ₂) ≥ λℓ₁ + (1 − λ)ℓ₂`
    /// for every `λ ∈ [0, 1]`, whose infimum is concave and piecewise linear in `λ` with its
    /// kinks where a coefficient changes sign: the best of `λ = 0, 1` and those kinks (each a
    /// multiple of 2⁻³⁰, so that `1 − λ` is exact). The LP's value where the coefficients are
    /// points.
    fn inf_of_max(&self) -> f64 {
        let [p1, p2] = &self.p;
        let inner = p1.iter().zip(p2).filter_map(|(a, b)| {
            let (a, b) = (a.center(), b.center());
            let l = b / (b - a);
            (l > 0.0 && l < 1.0).then(|| (l * 1_073_741_824.0).round() / 1_073_741_824.0)
        });
        let mixed = inner.map(|l| {
            let (l, m) = (Interval::point(l), Interval::point(1.0 - l));
            let p = p1.iter().zip(p2).map(|(&a, &b)| l * a + m * b);
            self.inf(p, l * self.k[0] + m * self.k[1])
        });
        let first = self.inf(p1.iter().copied(), self.k[0]);
        mixed.fold(first.max(self.joint_inf()), f64::max)
    }
}

/// `‖Nⱼ − vⱼ‖` over the cell from the joint forms of `N − F` ([`CentredPair`]), where `v`'s
/// form is known there (+∞ where it is not), `[n̲, n̄]` bounding `N` there. Where `v` is one
/// smooth `F`, `N − v ∈ [s̲, s̄]`, the joint forms' bounds. Where `vⱼ = min(0, Fⱼ)`,
/// `N − v = max(N, N − F)`, so `N − v ≤ max(n̄, s̄)` and `N − v ≥ max(n̲, s̲)`, or better
/// `inf max(ℓ_N, ℓ_{N−F})` of the two lower forms ([`CentredPair::inf_of_max`]); where
/// `vⱼ = max(0, Fⱼ)`, `N − v = min(N, N − F)`, the mirror image. Where `v` follows `F` the
/// slopes cancel, and where it is 0 `N`'s own bound is small: neither side pays for the range
/// of `v` across its kink.
fn joint_error(
    ab: &AffineBounds,
    shape: &VShape,
    piece: &IntervalBox,
    j: usize,
    (n_lo, n_hi): (f64, f64),
) -> f64 {
    let (sv, kink) = match shape {
        VShape::Unknown => return f64::INFINITY,
        VShape::Smooth(sv) => (sv, None),
        VShape::Kinked { binding, kinks } => match kinks[j] {
            Some(kink) => (binding, Some(kink)),
            None => return f64::INFINITY,
        },
    };
    let below = CentredPair::of(ab.a_lower_row(j), ab.b_lower[j], sv, piece, j, false);
    let above = CentredPair::of(ab.a_upper_row(j), ab.b_upper[j], sv, piece, j, true);
    let (s_lo, s_hi) = (below.joint_inf(), -above.joint_inf());
    let (hi, lo) = match kink {
        None => (s_hi, s_lo),
        Some(Kink::Min) => (n_hi.max(s_hi), n_lo.max(below.inf_of_max())),
        // sup min(u_N, u_{N−F}) = −inf max(−u_N, −u_{N−F}).
        Some(Kink::Max) => (n_hi.min(-above.inf_of_max()), n_lo.min(s_lo)),
    };
    let e = round_up(hi.max(-lo));
    if e.is_nan() {
        f64::INFINITY
    } else {
        e
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
/// and the piece's enclosure of `v`; per output, the least of that and, where `v`'s form is
/// known on the piece, the joint bound of `N − v` ([`joint_error`]). Each bound is sound on
/// `piece ∩ S`.
pub(super) fn piece_error(
    ab: &AffineBounds,
    n_lo: &[f64],
    n_hi: &[f64],
    piece: &IntervalBox,
    v: &[Interval],
    shape: &VShape,
) -> f64 {
    (0..v.len())
        .map(|j| {
            let lo = n_lo[j].max(affine_over(ab.a_lower_row(j), ab.b_lower[j], piece).lower);
            let hi = n_hi[j].min(affine_over(ab.a_upper_row(j), ab.b_upper[j], piece).upper);
            let enclosed = error_from(&[lo], &[hi], &v[j..=j]);
            enclosed.min(joint_error(ab, shape, piece, j, (lo, hi)))
        })
        .fold(0.0, f64::max)
}

/// The axis to bisect a cell across: of the axes at least half as wide as the widest, relative
/// to `C`'s widths (so that cells keep within 2 : 1 of `C`'s shape), the one along which the
/// cell's joint bound of `N − v` varies most, `wᵢ · maxⱼ (mag(C̄ⱼᵢ − Jⱼᵢ) ∨ mag(C̲ⱼᵢ − Jⱼᵢ) +
/// |C̄ⱼᵢ − C̲ⱼᵢ|)`: the slope left after the joint form's cancellation (with `J` the enclosure of
/// `v`'s Jacobian, or across a kink of `F`'s, where `N`'s own slope counts too) and the width of
/// `N`'s relaxation. `None` where `v`'s form is unknown (bisect the widest axis then).
///
/// Why: a cell's bound is the concretisation of these slopes over its widths, so halving the
/// axis with the largest term takes most off it. Widest-first cuts a state with large units
/// that `N − v` barely depends on: on a 4-state cart-pole (results.md) this rule took the
/// certified `M_C` at the default budget from 2.20 to 1.59.
pub(super) fn split_axis(
    ab: &AffineBounds,
    shape: &VShape,
    cell: &IntervalBox,
    region: &IntervalBox,
) -> Option<usize> {
    let (jac, kinked) = match shape {
        VShape::Smooth(f) => (&f.jac, false),
        VShape::Kinked { binding, .. } => (&binding.jac, true),
        VShape::Unknown => return None,
    };
    let (n, w, r) = (cell.dim(), cell.widths(), region.widths());
    let term = |i: usize| {
        let per_output = (0..ab.n_out).map(|j| {
            let (cl, cu) = (ab.a_lower_row(j)[i], ab.a_upper_row(j)[i]);
            let jv = jac[j * n + i];
            let joint = (Interval::point(cu) - jv)
                .mag()
                .max((Interval::point(cl) - jv).mag());
            // Across a kink `v` is 0 on part of the cell: `N`'s own slope is paid there.
            let joint = if kinked {
                joint.max(cu.abs()).max(cl.abs())
            } else {
                joint
            };
            joint + (cu - cl).abs()
        });
        per_output.fold(0.0, f64::max) * w[i]
    };
    let terms: Vec<f64> = (0..n).map(term).collect();
    if terms.iter().any(|t| !t.is_finite()) {
        return None;
    }
    let relative: Vec<f64> = (0..n).map(|i| w[i] / r[i].max(f64::MIN_POSITIVE)).collect();
    let widest = relative.iter().copied().fold(0.0, f64::max);
    (0..n)
        .filter(|&i| w[i] > 0.0 && relative[i] > 0.5 * widest)
        .max_by(|&a, &b| terms[a].total_cmp(&terms[b]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::{BoundMethod, PreparedNetwork};
    use crate::filter::VForms;
    use crate::network::{Layer, Mlp};
    use crate::scenario::Scenario;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// `inf max(ℓ₁, ℓ₂)` over a box is the LP's value: never above the least of `max` on a
    /// fine grid (sound), and within the grid's resolution of it (tight), for random pairs.
    #[test]
    fn inf_of_max_is_the_lp_value() {
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut rnd = move || rng.random_range(-1.0..1.0);
        for _ in 0..200 {
            let p: [Vec<f64>; 2] = [
                vec![rnd() * 3.0, rnd() * 3.0],
                vec![rnd() * 3.0, rnd() * 3.0],
            ];
            let k = [rnd(), rnd()];
            let r = [0.5 + rnd().abs(), 0.5 + rnd().abs()];
            let pair = CentredPair {
                p: p.clone()
                    .map(|v| v.into_iter().map(Interval::point).collect()),
                k: k.map(Interval::point),
                dx: r.iter().map(|&ri| Interval::new(-ri, ri)).collect(),
            };
            let lp = pair.inf_of_max();
            let steps = 400;
            let mut least = f64::INFINITY;
            for a in 0..=steps {
                for b in 0..=steps {
                    let x = [
                        r[0] * (2.0 * a as f64 / steps as f64 - 1.0),
                        r[1] * (2.0 * b as f64 / steps as f64 - 1.0),
                    ];
                    let l = |i: usize| p[i][0] * x[0] + p[i][1] * x[1] + k[i];
                    least = least.min(l(0).max(l(1)));
                }
            }
            assert!(lp <= least, "{lp} above the sampled {least}");
            let resolution = 2.0 * 6.0 * 1.5 / steps as f64;
            assert!(
                lp >= least - resolution,
                "{lp} far below the sampled {least}"
            );
        }
    }

    /// A wall at `x = 2` and a constant push: `v = min(0, 1 − x)`, kinked at `x = 1`. A network
    /// equal to `v` (`−ReLU(x − 1)`, plus `offset`) on the cell `[0.5, 1.5]` across the kink:
    /// the enclosures alone bound its error by the range of `v` (0.5); the kinked form by half
    /// that, and never below the error itself.
    #[test]
    fn a_kinked_cell_pays_for_the_error_not_for_the_range_of_v() {
        let text = r#"
name = "wall"
[system]
states = ["x"]
inputs = ["u"]
f = ["0"]
g = [["1"]]
kappa = ["1"]
[[cbf]]
name = "wall"
h = "2 - x"
[reach]
region = { lower = [0.0], upper = [2.0] }
m_c = 0.1
dt = 0.1
horizon = 1.0
goal = { lower = [1.5], upper = [2.0] }
initial = [ { lower = [0.0], upper = [0.1] } ]
"#;
        let s = Scenario::from_toml(text, "wall.toml", std::path::Path::new(".")).unwrap();
        let cell = IntervalBox::new(vec![0.5], vec![1.5]).unwrap();
        let forms = VForms::new(&s).unwrap();
        let (v, shape) = forms.enclose(&s, &cell);
        assert!(matches!(shape, VShape::Kinked { .. }), "{shape:?}");
        for offset in [0.0, 0.1] {
            let net = Mlp {
                layers: vec![
                    Layer {
                        weight: vec![1.0],
                        bias: vec![-1.0],
                        n_in: 1,
                        n_out: 1,
                    },
                    Layer {
                        weight: vec![-1.0],
                        bias: vec![offset],
                        n_in: 1,
                        n_out: 1,
                    },
                ],
            };
            let p = PreparedNetwork::new(&net).unwrap();
            let ab = p
                .bounds(&cell.lower, &cell.upper, BoundMethod::Crown)
                .unwrap();
            let ibp = p
                .bounds(&cell.lower, &cell.upper, BoundMethod::Ibp)
                .unwrap();
            let enclosures = piece_error(&ab, &ibp.lower, &ibp.upper, &cell, &v, &VShape::Unknown);
            let kinked = piece_error(&ab, &ibp.lower, &ibp.upper, &cell, &v, &shape);
            assert!(enclosures >= 0.5, "{enclosures}");
            assert!(kinked >= offset, "{kinked} below the error {offset}");
            assert!(
                kinked <= 0.25 + offset + 1e-9,
                "{kinked} (enclosures {enclosures})"
            );
        }
    }

    /// The split axis follows what is left of the slopes after the joint form's cancellation,
    /// not the widths alone, and keeps cells within 2 : 1 of `C`'s shape.
    #[test]
    fn a_cell_is_cut_where_n_minus_v_varies_most() {
        // One output, two states: N's slopes `c` on both sides but `gap` apart on the first.
        let bounds = |c: [f64; 2], gap: f64| AffineBounds {
            a_lower: vec![c[0] - gap, c[1]],
            b_lower: vec![0.0],
            a_upper: vec![c[0], c[1]],
            b_upper: vec![0.0],
            lower: vec![0.0],
            upper: vec![0.0],
            n_in: 2,
            n_out: 1,
        };
        let smooth = |jac: [f64; 2]| SmoothV {
            centre: vec![1.0, 0.5],
            value: vec![Interval::point(0.0)],
            jac: jac.iter().map(|&d| Interval::point(d)).collect(),
        };
        let region = IntervalBox::new(vec![0.0, 0.0], vec![4.0, 2.0]).unwrap();
        let cell = IntervalBox::new(vec![0.0, 0.0], vec![2.0, 1.0]).unwrap();
        // `N` varies along the narrower axis, `v` not at all: cut there, not across the widest.
        let v_flat = VShape::Smooth(smooth([0.0, 0.0]));
        assert_eq!(
            split_axis(&bounds([0.0, 3.0], 0.0), &v_flat, &cell, &region),
            Some(1)
        );
        // `v` has `N`'s slopes: they cancel, and the relaxation's width on axis 0 decides.
        let v_same = VShape::Smooth(smooth([1.0, 3.0]));
        let ab = bounds([1.0, 3.0], 0.2);
        assert_eq!(split_axis(&ab, &v_same, &cell, &region), Some(0));
        // Across a kink `v` is 0 on part of the cell, so `N`'s own slope counts: axis 1.
        let kinked = VShape::Kinked {
            binding: smooth([1.0, 3.0]),
            kinks: vec![Some(Kink::Min)],
        };
        assert_eq!(split_axis(&ab, &kinked, &cell, &region), Some(1));
        // A cell already 2 : 1 (relative to C) is cut across its long side whatever the slopes.
        let thin = IntervalBox::new(vec![0.0, 0.0], vec![2.0, 0.5]).unwrap();
        assert_eq!(
            split_axis(&bounds([0.0, 3.0], 0.0), &v_flat, &thin, &region),
            Some(0)
        );
        // Nothing known of `v`: no preference (the caller cuts the widest axis).
        let ab = bounds([0.0, 3.0], 0.0);
        assert_eq!(split_axis(&ab, &VShape::Unknown, &cell, &region), None);
    }
}

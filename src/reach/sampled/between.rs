//! The filter's own constraint between samples (design §7.2 item 4): where a set near `∂S`
//! overlaps it, the QP's row at the sample and the held motion's `ḧ` still prove that every true
//! state stays in `{h ≥ 0}` until the next sample ([`Plant::keeps`]); and the plain interval
//! test of a set against one CBF ([`proven_safe`]). A child of [`super`]: it reads the plant's
//! parts.

use super::Plant;
use crate::boxes::IntervalBox;
use crate::intervals::{box_of, Interval};
use crate::scenario::Scenario;

impl Plant {
    /// Whether the filter's own constraint keeps the true state in `{h_c ≥ 0}` at every
    /// `τ ∈ [0, tau]` after a sample (design §7.2 item 4). The true input `u_k` satisfies the QP's row
    /// `φ(x_k) = ∇h(x_k)·(f(x_k) + g(x_k)u_k) ≥ −α(h(x_k))`, and `φ` is `d/dt h` along the held
    /// motion, so by Taylor's theorem with the integral remainder
    /// `h(x(τ)) ≥ h(x_k) − τα(h(x_k)) + τ²/2·inf φ̇`, the infimum over `motion` (every state
    /// since the sample) and `u` (the held input's enclosure). `h_k` encloses `h(x_k)`, its lower
    /// end at least 0 (the true state is in `S` at the sample: the tube's earlier checks). With
    /// a gain (`α(h) = a·h`) and `aτ ≤ 1` both terms only fall as `τ` grows, so the bound at
    /// `tau` covers the interval ([`Plant::kept`] for other `α`). `ḧ ≥ 0` (a convex `h` on
    /// `ẋ = u`) proves it whatever the floor. NaN (a kink's `delta`, a domain) proves nothing.
    pub fn keeps(
        &self,
        c: usize,
        h_k: Interval,
        motion: &IntervalBox,
        u: &[Interval],
        tau: f64,
    ) -> bool {
        let accel = self.held_acceleration(c, motion, u).lower;
        if accel.is_nan() {
            return false;
        }
        let t = Interval::point(tau);
        let Some(kept) = self.kept(c, h_k, tau) else {
            return false;
        };
        if accel >= 0.0 {
            return kept >= 0.0;
        }
        let half_t2 = (t * t * Interval::point(0.5)).upper;
        let lost = Interval::point(half_t2) * Interval::point(accel);
        (Interval::point(kept) + lost).lower >= 0.0
    }

    /// A lower bound of `h_k − τ'α(h_k)` over `h_k` and `τ' ∈ [0, tau]` (`None` where it may
    /// be negative: `a·tau > 1` for a gain). With a gain, `(1 − a·tau)·h̲`. Otherwise the
    /// expression is affine in `τ'`, so its least value is at `τ' = 0` (`h_k ≥ h̲`) or at `tau`,
    /// where it rises with `h_k` wherever `1 − tau·α' ≥ 0` on `h_k` (then its value at `h̲`,
    /// 0 at `h̲ = 0` since `α(0) = 0`), else is enclosed as a whole. Terms that are exactly 0
    /// stay 0 (outward rounding would push them below).
    fn kept(&self, c: usize, h_k: Interval, tau: f64) -> Option<f64> {
        let (alpha, floor, t) = (&self.alpha[c], h_k.lower, Interval::point(tau));
        if floor.is_nan() {
            return None;
        }
        if let Some(a) = alpha.gain {
            let decay = (Interval::point(1.0) - Interval::point(a) * t).lower;
            return (decay >= 0.0).then(|| match floor > 0.0 {
                true => (Interval::point(decay) * Interval::point(floor)).lower,
                false => 0.0,
            });
        }
        let rising = (Interval::point(1.0) - t * alpha.slope_over(h_k)).lower >= 0.0;
        let at_tau = match (rising, floor > 0.0) {
            (true, true) => {
                let at = Interval::point(floor);
                (at - t * alpha.over(at)).lower
            }
            (true, false) => 0.0,
            (false, _) => (h_k - t * alpha.over(h_k)).lower,
        };
        (at_tau >= 0.0).then_some(at_tau.min(floor))
    }

    /// An enclosure of `ḧ = ẋᵀ∇²h ẋ + ∇h·ẍ` for CBF `c` over the states `motion` with the
    /// input held in `u`: `ẋ = f + g·u`, `ẍ = (Df + Σₖ uₖ Dgₖ)·ẋ`. The quadratic form's diagonal
    /// takes `ẋᵢ²` as a square (never negative), which the expression `φ̇` evaluated term by
    /// term would lose (`u·u` over `[−1, 2]` is `[−2, 4]`); its lower end is also taken row by
    /// row ([`quadratic_floor`]), which keeps a diagonally dominant `∇²h` with a nonnegative
    /// diagonal nonnegative where `ẋ`'s enclosure holds 0 (a state coming to rest on `∂S`).
    fn held_acceleration(&self, c: usize, motion: &IntervalBox, u: &[Interval]) -> Interval {
        let x = box_of(&motion.lower, &motion.upper);
        let v = self.velocity(&x, u);
        let (grad, hess) = (&self.cbf_gradient[c], &self.cbf_hessian[c]);
        let n = self.n;
        // `∇²h` over the motion, symmetrised: off the diagonal `hᵢⱼ + hⱼᵢ` (twice the entry).
        let mut hs = vec![Interval::point(0.0); n * n];
        for i in 0..n {
            hs[i * n + i] = hess[i][i].eval_interval(&x);
            for j in i + 1..n {
                let hij = hess[i][j].eval_interval(&x) + hess[j][i].eval_interval(&x);
                (hs[i * n + j], hs[j * n + i]) = (hij, hij);
            }
        }
        let squares: Vec<Interval> = v.iter().map(|&vi| square(vi)).collect();
        // The quadratic form term by term, and `∇h·ẍ`.
        let (mut quad, mut rest) = (Interval::point(0.0), Interval::point(0.0));
        for (i, gi) in grad.iter().enumerate() {
            quad = quad + signed_mul(hs[i * n + i], squares[i]);
            for j in i + 1..n {
                quad = quad + signed_mul(hs[i * n + j], signed_mul(v[i], v[j]));
            }
            let mut xddot = Interval::point(0.0);
            for (j, vj) in v.iter().enumerate() {
                let mut d = self.df[i][j].eval_interval(&x);
                for (k, uk) in u.iter().enumerate() {
                    d = d + signed_mul(self.dg[i][k][j].eval_interval(&x), *uk);
                }
                xddot = xddot + signed_mul(d, *vj);
            }
            rest = rest + signed_mul(gi.eval_interval(&x), xddot);
        }
        let total = quad + rest;
        let by_rows = Interval::point(quadratic_floor(&hs, &squares, n)) + rest;
        if total.lower.is_nan() || by_rows.lower.is_nan() {
            // NaN proves nothing (`f64::max` would drop it).
            return Interval::new(f64::NAN, total.upper);
        }
        Interval::new(total.lower.max(by_rows.lower), total.upper)
    }
}

/// `v²` of an enclosure, never below 0 (`sqr` of an interval around 0 is `[0, …]` exactly, but
/// its outward rounding may not be).
fn square(v: Interval) -> Interval {
    let s = v.sqr();
    Interval::new(s.lower.max(0.0), s.upper)
}

/// A lower bound on `vᵀHv` for every `v` whose squares lie in `squares` and every symmetric
/// `H` in `hs` (n×n, off the diagonal twice the entry, as [`Plant::held_acceleration`] builds
/// it), row by row: `2|hᵢⱼvᵢvⱼ| ≤ |hᵢⱼ|(vᵢ² + vⱼ²)`, so `vᵀHv ≥ Σᵢ cᵢvᵢ²` with
/// `cᵢ = h̲ᵢᵢ − ½Σⱼ≠ᵢ|hᵢⱼ + hⱼᵢ|`, each `vᵢ²` at the end of its enclosure that makes `cᵢvᵢ²`
/// least. Nonnegative wherever `H` is diagonally dominant with a nonnegative diagonal, whatever
/// `v`'s signs, which the term-by-term product (`vᵢvⱼ` over a box around 0) cannot see.
fn quadratic_floor(hs: &[Interval], squares: &[Interval], n: usize) -> f64 {
    let mut floor = Interval::point(0.0);
    for (i, sq) in squares.iter().enumerate() {
        let off = (0..n)
            .filter(|&j| j != i)
            .fold(Interval::point(0.0), |a, j| {
                a + Interval::point(hs[i * n + j].mag())
            });
        let ci = (Interval::point(hs[i * n + i].lower) - off * Interval::point(0.5)).lower;
        // `cᵢ·vᵢ²`'s lower end: the least square for a positive `cᵢ`, the largest otherwise.
        let term = match ci >= 0.0 {
            true => signed_mul(Interval::point(ci), Interval::point(sq.lower)),
            false => Interval::point(ci) * Interval::point(sq.upper),
        };
        floor = floor + Interval::point(term.lower);
    }
    floor.lower
}

/// `a·b` outward rounded, with the sign the factors' signs give kept exactly (rounding would
/// push an exact 0 end past 0, and a sign is all [`Plant::keeps`] asks of a term that cannot
/// be negative).
fn signed_mul(a: Interval, b: Interval) -> Interval {
    let zero = |x: Interval| x.lower == 0.0 && x.upper == 0.0;
    if zero(a) || zero(b) {
        return Interval::point(0.0);
    }
    let p = a * b;
    let (a_pos, a_neg) = (a.lower >= 0.0, a.upper <= 0.0);
    let (b_pos, b_neg) = (b.lower >= 0.0, b.upper <= 0.0);
    if (a_pos && b_pos) || (a_neg && b_neg) {
        Interval::new(p.lower.max(0.0), p.upper)
    } else if (a_pos && b_neg) || (a_neg && b_pos) {
        Interval::new(p.lower, p.upper.min(0.0))
    } else {
        p
    }
}

/// Whether the x-box `b` is proven inside CBF `c`'s `{h ≥ 0}` (interval evaluation; NaN bounds,
/// undefined somewhere on the box, prove nothing), and whether it lies entirely outside it.
pub fn proven_safe(scenario: &Scenario, c: usize, b: &IntervalBox) -> (bool, bool) {
    let h = scenario.cbfs[c]
        .h
        .eval_interval(&box_of(&b.lower, &b.upper));
    (h.lower >= 0.0, h.upper < 0.0)
}

#[cfg(test)]
mod tests {
    use super::super::tests::{scenario_alpha, scenario_with};
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// [`Plant::keeps`] against the exact held motion of the double integrator past the disc
    /// obstacle, where `ḧ = 2x₂² + 2(x₁ − 2)u + 2u²` takes both signs: from random states in `S`
    /// and inputs that satisfy the QP's row, a proof never meets a trajectory that leaves `S`
    /// before `τ`; some trajectories do leave (a digital filter does not keep `S`), and some
    /// proofs are given (the test is not vacuous either way). With `α(h) = h` and with a
    /// nonlinear `α` (`3h² + 0.2h`: rising in `h − τα(h)` on part of the states, not on others).
    #[test]
    fn the_filter_constraint_proof_holds_on_the_exact_held_motion() {
        held_motion_proofs("1.0", |h| h);
        held_motion_proofs(r#""3*h^2 + 0.2*h""#, |h| 3.0 * h * h + 0.2 * h);
    }

    fn held_motion_proofs(alpha_toml: &str, alpha: impl Fn(f64) -> f64) {
        let s = scenario_alpha(
            r#"["x2", "0"]"#,
            r#"[["0"], ["1"]]"#,
            "(x1 - 2)^2 + x2^2 - 1",
            alpha_toml,
        );
        let plant = Plant::of(&s);
        let h = |x: [f64; 2]| (x[0] - 2.0).powi(2) + x[1] * x[1] - 1.0;
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut uniform = |lo: f64, hi: f64| rng.random_range(lo..hi);
        let (mut proofs, mut exits) = (0, 0);
        for trial in 0..40_000 {
            // Near the disc, where the held input can carry the state into it.
            let (r, angle) = (1.0 + uniform(0.0, 0.2), uniform(0.0, std::f64::consts::TAU));
            let x = [2.0 + r * angle.cos(), r * angle.sin()];
            let u = uniform(-4.0, 4.0);
            let phi = 2.0 * (x[0] - 2.0) * x[1] + 2.0 * x[1] * u;
            if h(x) < 0.0 || phi < -alpha(h(x)) {
                continue;
            }
            let tau = [0.1, 0.3, 0.6, 0.9][trial % 4];
            let at = |t: f64| [x[0] + x[1] * t + u * t * t / 2.0, x[1] + u * t];
            let path: Vec<[f64; 2]> = (0..=400).map(|k| at(tau * k as f64 / 400.0)).collect();
            // The grid's hull, padded past the parabola's sag between grid points.
            let pad = 1e-9 + u.abs() * (tau / 400.0).powi(2);
            let motion = IntervalBox::new(
                (0..2)
                    .map(|i| path.iter().map(|p| p[i]).fold(f64::INFINITY, f64::min) - pad)
                    .collect(),
                (0..2)
                    .map(|i| path.iter().map(|p| p[i]).fold(f64::NEG_INFINITY, f64::max) + pad)
                    .collect(),
            )
            .unwrap();
            let leaves = path.iter().any(|&p| h(p) < -1e-12);
            exits += usize::from(leaves);
            let h_k = Interval::new(h(x) * (1.0 - 1e-12), h(x) * (1.0 + 1e-12) + 1e-15);
            if plant.keeps(0, h_k, &motion, &[Interval::point(u)], tau) {
                proofs += 1;
                assert!(
                    !leaves,
                    "proven at x = {x:?}, u = {u}, τ = {tau}, yet it leaves S"
                );
            }
        }
        assert!(
            proofs > 1_000 && exits > 15,
            "{proofs} proofs, {exits} exits"
        );
    }

    /// `h(x_k) ≥ floor`.
    fn above(floor: f64) -> Interval {
        Interval::new(floor, f64::INFINITY)
    }

    /// A convex `h` on `ẋ = u` (`ḧ = 2|u|² ≥ 0`) is kept whatever the floor, for `aτ ≤ 1`
    /// alone; a concave one near its boundary is not.
    #[test]
    fn convexity_along_the_motion_proves_a_touching_set() {
        let u = [Interval::new(-1.0, 2.0)];
        let motion = IntervalBox::new(vec![0.0, -1.0], vec![1.0, 1.0]).unwrap();
        let convex = Plant::of(&scenario_with(
            r#"["0", "0"]"#,
            r#"[["1"], ["0"]]"#,
            "x1^2 + x2^2 - 1",
        ));
        assert!(convex.keeps(0, above(0.0), &motion, &u, 0.5));
        assert!(convex.keeps(0, above(0.0), &motion, &u, 0.99));
        assert!(!convex.keeps(0, above(0.0), &motion, &u, 1.01), "aτ > 1");
        // A nonlinear α at the floor 0: `α(0) = 0` keeps the set whatever τ where `h − τα(h)`
        // rises over `h_k` (`1 − 3τh² ≥ 0` on [0, 0.5] for τ ≤ 4/3), not where it may fall.
        let cubic = Plant::of(&scenario_alpha(
            r#"["0", "0"]"#,
            r#"[["1"], ["0"]]"#,
            "x1^2 + x2^2 - 1",
            r#""h^3""#,
        ));
        assert!(cubic.keeps(0, Interval::new(0.0, 0.5), &motion, &u, 1.2));
        assert!(!cubic.keeps(0, Interval::new(0.0, 0.5), &motion, &u, 1.4));
        let concave = Plant::of(&scenario_with(
            r#"["0", "0"]"#,
            r#"[["1"], ["0"]]"#,
            "1 - x1^2 - x2^2",
        ));
        assert!(!concave.keeps(0, above(0.0), &motion, &u, 0.1));
        assert!(concave.keeps(0, above(0.5), &motion, &u, 0.1));
    }

    /// A positive definite `∇²h` with cross terms (`h = x₁² + x₁x₂ + x₂² − 1`, `ẋ = (u, u)`,
    /// `ḧ = 6u²`) is kept at the floor 0 where `u`'s enclosure holds 0: term by term the cross
    /// term's `u·u` over `[−1, 2]` is `[−2, 4]` and `ḧ`'s lower end −4; row by row it is 0. An
    /// indefinite one (`x₁² + 3x₁x₂ + x₂²`, `ḧ = 10u²` on this motion but not on others) is not.
    #[test]
    fn a_dominant_hessian_keeps_a_touching_set_whatever_the_inputs_sign() {
        let u = [Interval::new(-1.0, 2.0)];
        let motion = IntervalBox::new(vec![0.0, -1.0], vec![1.0, 1.0]).unwrap();
        let plant = |h: &str| Plant::of(&scenario_with(r#"["0", "0"]"#, r#"[["1"], ["1"]]"#, h));
        let dominant = plant("x1^2 + x1*x2 + x2^2 - 1");
        assert!(dominant.keeps(0, above(0.0), &motion, &u, 0.5));
        assert!(dominant.held_acceleration(0, &motion, &u).lower >= 0.0);
        let indefinite = plant("x1^2 + 3*x1*x2 + x2^2 - 1");
        assert!(!indefinite.keeps(0, above(0.0), &motion, &u, 0.5));
    }

    /// [`quadratic_floor`] against `vᵀHv` at random symmetric matrices and vectors drawn from
    /// random interval enclosures, 2 and 3 dimensions.
    #[test]
    fn the_row_floor_bounds_every_quadratic_form_in_the_enclosures() {
        use rand::Rng;
        let mut rng = crate::bounds::test_support::case_rng(31);
        for trial in 0..400 {
            let n = 2 + trial % 2;
            let mut pick = |scale: f64| {
                let (a, b) = (
                    rng.random_range(-scale..scale),
                    rng.random_range(-scale..scale),
                );
                Interval::new(a.min(b), a.max(b))
            };
            let mut hs = vec![Interval::point(0.0); n * n];
            for i in 0..n {
                hs[i * n + i] = pick(3.0) + Interval::point(2.0);
                for j in i + 1..n {
                    let hij = pick(2.0);
                    (hs[i * n + j], hs[j * n + i]) = (hij, hij);
                }
            }
            let v: Vec<Interval> = (0..n).map(|_| pick(2.0)).collect();
            let squares: Vec<Interval> = v.iter().map(|&vi| square(vi)).collect();
            let floor = quadratic_floor(&hs, &squares, n);
            let mut at = |x: Interval| x.lower + rng.random::<f64>() * (x.upper - x.lower);
            for _ in 0..50 {
                let h: Vec<f64> = hs.iter().map(|&e| at(e)).collect();
                let w: Vec<f64> = v.iter().map(|&e| at(e)).collect();
                // Off the diagonal `hs` holds twice the entry: the form is Σ hᵢᵢwᵢ² + Σᵢ<ⱼ hᵢⱼwᵢwⱼ,
                // with the symmetric pair drawn once.
                let mut q = 0.0;
                for i in 0..n {
                    q += h[i * n + i] * w[i] * w[i];
                    for j in i + 1..n {
                        q += h[i * n + j] * w[i] * w[j];
                    }
                }
                assert!(q >= floor - 1e-12, "trial {trial}: {q} < {floor}");
            }
        }
    }
}

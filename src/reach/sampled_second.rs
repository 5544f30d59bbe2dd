//! The held motion to second order (sampled data, constant `g`; docs/design.md §7.2 item 2b).
//! Imports the plant and the intersample motion of [`super::sampled`], intervals and boxes.
//!
//! With the input held at `u_k`, `ẋ = f(x) + g·u_k`, so `ẋ(s) − ẋ(0) = f(x(s)) − f(x_k)`.
//! Over an a-priori enclosure `H` of the motion, `x(s) − x_k = s·F(x_k) + e(s)` with
//! `e(s) ∈ s²/2·ρ` (`ρ = Df(H)·Ẋ`, [`Intersample`]), and by the mean value theorem
//! `f(x(s)) − f(x_k) = J_s·(x(s) − x_k)` for some `J_s ∈ Df(H)`. Writing `J_s = C + Δ`
//! (`C` the midpoint of `Df(H)`, `|Δ| ≤ R` its radius) and integrating over `[0, τ]`:
//!
//! `x(τ) ∈ x_k + τ(I + τ/2·C)·F(x_k) + τ²/2·R·|F(X)|·[−1, 1] + τ³/6·Df(H)·ρ`,
//!
//! where `F(x_k) = f(x_k) + g·u_k` is the field the embedding bounds at the sample (the
//! network's affine bounds keep `u_k`'s correlation with `x_k`). The first-order form
//! `x_k + τF(x_k) + τ²/2·ρ` takes the whole `τ²` term as an interval, as wide as `Ẋ` over the
//! set: for a set of width `w` about `τ²·|Df|·|DF|·w`, which outgrows a slow contraction
//! (a damped pendulum held over `5·dt` grew without end). Here the `τ²` term moves with `x_k`
//! through the mixing matrix `I + τ/2·C`, and what is left is `O(τ²·R + τ³)`. For a linear
//! plant `R = 0`; for the double integrator `Df·ρ = 0` too, so the image is the exact
//! zero-order hold `x₁ + τx₂ + τ²/2·u_k`.
//!
//! In coordinates `z = T x` (`x = S z` exactly) the mixing matrix is `S⁻¹CS`, enclosed by
//! `T·C·S` in interval arithmetic widened by `ρ_T·‖T·C·S‖∞` (`S⁻¹ = (I − R_T)⁻¹T`), split
//! again into a midpoint and a radius; the x-coordinate terms go to z as the remainder does.

use super::sampled::{Intersample, Plant};
use super::transform::Transform;
use crate::boxes::IntervalBox;
use crate::intervals::{box_of, Interval};
use crate::rounding::round_up;

/// The second-order terms of one step of a control period, at `τ = j·dt`, in x coordinates.
#[derive(Clone, Debug)]
pub struct HeldTerm {
    /// `τ`.
    pub tau: f64,
    /// `C`, the midpoint of `Df(H)` (n×n row-major, a point matrix).
    pub c: Vec<f64>,
    /// Lower ends of `τ²/2·R·|F(X)|·[−1, 1] + τ³/6·Df(H)·ρ`.
    pub lower: Vec<f64>,
    /// Upper ends.
    pub upper: Vec<f64>,
}

/// The mixing matrix of one frame: `I + τ/2·K_c` as the f64 numbers used, and what that leaves
/// out, `τ/2·K_r` (`K_r` the radius of `K ∋ S⁻¹CS`) plus the numbers' own rounding
/// (n×n row-major each).
#[derive(Clone, Debug)]
pub struct Mix {
    /// `I + τ/2·K_c`, a point matrix.
    pub matrix: Vec<f64>,
    /// `τ/2·K_r` plus the rounding of `matrix`, upper bounds (the rounding alone in x
    /// coordinates, where `K = C`).
    pub spread: Vec<f64>,
}

/// The terms of each step `j = 1, …, period` of the period that starts at the x-box `known`
/// with the input held in `u`, over a-priori enclosures of the motion from `known` (each step
/// enclosed from the last one's enclosure, which holds every state at its end). `None` where
/// the plant's `g` is not constant, the plant does not move, or the motion has no enclosure.
pub fn held_terms(
    plant: &Plant,
    known: &IntervalBox,
    u: &[Interval],
    h: f64,
    period: usize,
) -> Option<Vec<HeldTerm>> {
    if plant.is_still() || !plant.g_is_constant() {
        return None;
    }
    let n = known.dim();
    // `mag` would drop a NaN end: an undefined velocity proves nothing.
    let velocity = plant.velocity_over(known, u);
    if !velocity
        .iter()
        .all(|v| v.lower.is_finite() && v.upper.is_finite())
    {
        return None;
    }
    let speed: Vec<f64> = velocity.iter().map(|v| v.mag()).collect();
    let mut motion = Intersample::start(n, u.to_vec());
    let mut from = known.clone();
    let mut terms = Vec::with_capacity(period);
    for j in 1..=period {
        from = motion.step(plant, &from, h)??;
        let hull = motion.hull()?;
        let df = plant.df_over(hull);
        let tau = Interval::point(j as f64 * h);
        let half_t2 = tau * tau * Interval::point(0.5);
        let sixth_t3 = tau * tau * tau / Interval::point(6.0);
        let c: Vec<f64> = df
            .iter()
            .map(|e| e.lower + 0.5 * (e.upper - e.lower))
            .collect();
        let (mut lower, mut upper) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for i in 0..n {
            let mut r = Interval::point(0.0);
            for k in 0..n {
                let d = df[i * n + k];
                let radius = (d - Interval::point(c[i * n + k])).mag();
                r = r + half_t2 * Interval::point(radius) * Interval::new(-speed[k], speed[k]);
                r = r + sixth_t3 * d * motion.rho[k];
            }
            if !(r.lower.is_finite() && r.upper.is_finite()) {
                return None;
            }
            lower.push(r.lower);
            upper.push(r.upper);
        }
        terms.push(HeldTerm {
            tau: tau.lower,
            c,
            lower,
            upper,
        });
    }
    Some(terms)
}

/// The frame's mixing matrix for `term` (`transform`: the frame's `z = T x`, `None` for x).
pub fn mix_in_frame(transform: Option<&Transform>, term: &HeldTerm) -> Mix {
    let n = term.c.len().isqrt();
    let half_tau = Interval::point(0.5) * Interval::point(term.tau);
    let k: Vec<Interval> = match transform {
        None => term.c.iter().map(|&v| Interval::point(v)).collect(),
        Some(t) => {
            let at = |m: &[f64], i: usize, j: usize| Interval::point(m[i * n + j]);
            let cs: Vec<Interval> = (0..n * n)
                .map(|q| {
                    (0..n).fold(Interval::point(0.0), |acc, l| {
                        acc + at(&term.c, q / n, l) * at(&t.s, l, q % n)
                    })
                })
                .collect();
            let tcs: Vec<Interval> = (0..n * n)
                .map(|q| {
                    (0..n).fold(Interval::point(0.0), |acc, l| {
                        acc + at(&t.t, q / n, l) * cs[l * n + q % n]
                    })
                })
                .collect();
            // ‖T·C·S‖∞ (an upper bound), and S⁻¹CS within ρ_T of it (entrywise, by the norm).
            let norm = (0..n)
                .map(|i| {
                    (0..n)
                        .fold(Interval::point(0.0), |acc, j| {
                            acc + Interval::point(tcs[i * n + j].mag())
                        })
                        .upper
                })
                .fold(0.0_f64, f64::max);
            let pad = (Interval::point(t.rho) * Interval::point(norm)).upper;
            tcs.iter().map(|&e| e + Interval::new(-pad, pad)).collect()
        }
    };
    let mut matrix = Vec::with_capacity(n * n);
    let mut spread = Vec::with_capacity(n * n);
    for (q, e) in k.iter().enumerate() {
        let mid = e.lower + 0.5 * (e.upper - e.lower);
        let radius = (*e - Interval::point(mid)).mag();
        let diag = Interval::point(f64::from(u8::from(q / n == q % n)));
        // The matrix is exactly the f64 number used; its rounding goes to the spread.
        let exact = diag + half_tau * Interval::point(mid);
        let used = exact.lower + 0.5 * (exact.upper - exact.lower);
        matrix.push(used);
        let off = (exact - Interval::point(used)).mag();
        spread.push(round_up(
            (half_tau * Interval::point(radius) + Interval::point(off)).upper,
        ));
    }
    Mix { matrix, spread }
}

/// `τ·Σₗ spreadᵢₗ·|Fₗ|` per coordinate with `|F|` bounded by `speed`: the part of the frame's
/// image that the mixing matrix leaves as an interval.
pub fn spread_term(mix: &Mix, speed: &[f64], tau: f64) -> Vec<f64> {
    let n = speed.len();
    (0..n)
        .map(|i| {
            let s = (0..n).fold(Interval::point(0.0), |acc, l| {
                acc + Interval::point(mix.spread[i * n + l]) * Interval::point(speed[l])
            });
            (Interval::point(tau) * s).upper
        })
        .collect()
}

/// `|Fₗ|` over the frame's set: `f̃(X) + g·U` (constant `g`), `U` the input's enclosure, plus
/// the transform's slack.
pub fn frame_speed(
    dynamics: &super::embedding::Dynamics,
    set: &IntervalBox,
    u: &[Interval],
    slack: f64,
) -> Option<Vec<f64>> {
    let g = dynamics.g_constant.as_ref()?;
    let (n, m) = (dynamics.n, dynamics.m);
    let x = box_of(&set.lower, &set.upper);
    let velocity: Vec<Interval> = (0..n)
        .map(|i| {
            (0..m).fold(dynamics.f_tilde[i].eval_interval(&x), |acc, k| {
                acc + Interval::point(g[i * m + k]) * u[k]
            })
        })
        .collect();
    // `mag` would drop a NaN end: an undefined field proves nothing.
    if !velocity
        .iter()
        .all(|v| v.lower.is_finite() && v.upper.is_finite())
    {
        return None;
    }
    let speed: Vec<f64> = velocity
        .iter()
        .map(|v| (Interval::point(v.mag()) + Interval::point(slack)).upper)
        .collect();
    speed.iter().all(|s| s.is_finite()).then_some(speed)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn plant(f: &str) -> Plant {
        Plant::of(&super::super::sampled::tests::scenario(
            f,
            r#"[["0"], ["1"]]"#,
        ))
    }

    /// The double integrator's held motion is `x + τ(I + τ/2·C)F` exactly: `C = Df`, no radius
    /// and `Df·ρ = 0`, so the terms left are 0 (up to rounding dust); a pendulum's `sin`
    /// leaves a radius and a `τ³` term, under a fifth of the first-order remainder near its
    /// rest point and shrinking faster than the box (the point of the form); the mixing matrix
    /// in z encloses `T·C·S`.
    #[test]
    fn the_terms_left_vanish_for_a_linear_plant_and_shrink_with_the_box() {
        let u = [Interval::new(-1.0, 2.0)];
        let b = IntervalBox::new(vec![0.2, -0.3], vec![0.4, -0.1]).unwrap();
        let terms = held_terms(&plant(r#"["x2", "0"]"#), &b, &u, 0.05, 4).unwrap();
        for t in &terms {
            assert_eq!(t.c, [0.0, 1.0, 0.0, 0.0]);
            // Outward rounding of the zero products leaves subnormal dust only.
            assert!(
                t.lower.iter().chain(&t.upper).all(|&v| v.abs() < 1e-300),
                "{t:?}"
            );
        }
        // The pendulum near its rest point with the nominal input held: what the second-order
        // form leaves is a small part of the first-order remainder `τ²/2·ρ`, and it shrinks
        // faster than the box.
        let pendulum = plant(r#"["x2", "sin(x1) - 0.1*x2"]"#);
        let widths = |r: f64| {
            let b = IntervalBox::new(vec![0.05 - r, -0.02 - r], vec![0.05 + r, -0.02 + r]).unwrap();
            let u = pendulum.held_input(&b, &[Interval::point(0.0)]);
            let t = held_terms(&pendulum, &b, &u, 0.05, 4)
                .unwrap()
                .pop()
                .unwrap();
            let second = (0..2).map(|i| t.upper[i] - t.lower[i]).fold(0.0, f64::max);
            let mut first = Intersample::start(2, u);
            let mut from = b.clone();
            for _ in 0..4 {
                from = first.step(&pendulum, &from, 0.05).unwrap().unwrap();
            }
            let (lo, hi) = first.at(0.2);
            (second, (0..2).map(|i| hi[i] - lo[i]).fold(0.0, f64::max))
        };
        let (wide, narrow) = (widths(0.05), widths(0.005));
        assert!(
            wide.0 < 0.2 * wide.1 && narrow.0 < 0.2 * narrow.1,
            "{wide:?} {narrow:?}"
        );
        assert!(narrow.0 < 0.2 * wide.0, "{wide:?} {narrow:?}");
        // In z = Tx: the mixing matrix's midpoint and spread hold T·C·S.
        let t = Transform::from_matrix(vec![2.0, 1.0, 0.5, 3.0], 2).unwrap();
        let term = &terms[3];
        let mix = mix_in_frame(Some(&t), term);
        let c = nalgebra::Matrix2::new(term.c[0], term.c[1], term.c[2], term.c[3]);
        let (tm, sm) = (
            nalgebra::Matrix2::new(t.t[0], t.t[1], t.t[2], t.t[3]),
            nalgebra::Matrix2::new(t.s[0], t.s[1], t.s[2], t.s[3]),
        );
        let k = tm * c * sm;
        for q in 0..4 {
            let (i, j) = (q / 2, q % 2);
            let want = f64::from(u8::from(i == j)) + 0.5 * term.tau * k[(i, j)];
            assert!(
                (mix.matrix[q] - want).abs() <= mix.spread[q] + 1e-15,
                "{q}: {mix:?}"
            );
        }
    }
}

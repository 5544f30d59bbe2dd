//! The sampled-data step (issue 36): a digital controller `u_k = κ(x_k) + v(x_k)` computed at
//! `t_k` and held (zero-order hold) while the plant `ẋ = f(x) + g(x)u_k` evolves.
//! Imports the scenario's expressions, the validated enclosure, intervals and boxes only.
//!
//! The state at `t_k + τ` is the Euler part `x_k + τ(f(x_k) + g(x_k)u_k) = x_k + τF(x_k)` (the
//! filtered field at `x_k`: the embedding's Euler step bounds it, `u_k`'s correlation with
//! `x_k` kept in the network's affine bounds) plus the remainder
//! `∫₀^τ [f(x(s)) − f(x_k) + (g(x(s)) − g(x_k))u_k] ds`. Over an a-priori enclosure `A` of the
//! intersample motion (Picard–Lindelöf with the held input's enclosure `U`, [`super::validated`]),
//! `x(s) − x_k ∈ s·Ẋ` with `Ẋ = f(A) + g(A)U`, so by the mean-value theorem the remainder lies
//! in `τ²/2 · (Df(A)·Ẋ + Σₖ (Dgₖ(A)·Ẋ)·Uₖ)`. For `ẋ = u` it is exactly 0.

use super::validated::{enclose_step, Enclosure};
use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::intervals::Interval;
use crate::scenario::Scenario;

/// The plant's parts, with the derivatives the remainder needs (x coordinates).
#[derive(Clone, Debug)]
pub struct Plant {
    n: usize,
    m: usize,
    f: Vec<Expr>,
    /// `Df`, n×n.
    df: Vec<Vec<Expr>>,
    g: Vec<Vec<Expr>>,
    /// `∂gᵢₖ/∂xⱼ`, indexed `[i][k][j]`.
    dg: Vec<Vec<Vec<Expr>>>,
    kappa: Vec<Expr>,
}

/// The remainder over one control period and the enclosure of the intersample motion.
#[derive(Clone, Debug)]
pub struct Remainder {
    /// Bounds of the remainder at the period's end, x coordinates.
    pub lower: Vec<f64>,
    /// Upper bounds.
    pub upper: Vec<f64>,
    /// `A ⊇ x([t_k, t_k + T_s])`, x coordinates.
    pub pipe: IntervalBox,
}

impl Plant {
    /// The scenario's `f`, `g`, `κ` and their derivatives.
    pub fn of(s: &Scenario) -> Plant {
        let (n, m) = (s.n(), s.m());
        Plant {
            n,
            m,
            f: s.f.clone(),
            df: crate::expressions::jacobian(&s.f, n),
            g: s.g.clone(),
            dg: s
                .g
                .iter()
                .map(|row| {
                    row.iter()
                        .map(|e| (0..n).map(|j| e.derivative(j)).collect())
                        .collect()
                })
                .collect(),
            kappa: s.kappa.clone(),
        }
    }

    /// Whether the remainder is 0 whatever the state (`Df = 0`, `Dg = 0`: `ẋ = u`).
    pub fn is_still(&self) -> bool {
        let zero = |e: &Expr| e.as_constant() == Some(0.0);
        self.df.iter().flatten().all(zero) && self.dg.iter().flatten().flatten().all(zero)
    }

    /// The held input's enclosure `κ(X) + v`, `v` an enclosure of the filter's correction on
    /// the x-box `x`.
    pub fn held_input(&self, x: &IntervalBox, v: &[Interval]) -> Vec<Interval> {
        let xs = intervals(x);
        (0..self.m)
            .map(|k| self.kappa[k].eval_interval(&xs) + v[k])
            .collect()
    }

    /// `f(A) + g(A)·U`.
    fn velocity(&self, a: &[Interval], u: &[Interval]) -> Vec<Interval> {
        (0..self.n)
            .map(|i| {
                (0..self.m).fold(self.f[i].eval_interval(a), |acc, k| {
                    acc + self.g[i][k].eval_interval(a) * u[k]
                })
            })
            .collect()
    }

    /// The remainder over a period of length `h` from the x-box `x` with the input held in
    /// `u`; `None` where the intersample motion has no enclosure (or an unbounded one).
    pub fn remainder(&self, x: &IntervalBox, u: &[Interval], h: f64) -> Option<Remainder> {
        let field = |a: &IntervalBox, parts: bool| -> Result<_, std::convert::Infallible> {
            if parts {
                // The plant's field is one expression: no tighter over parts.
                return Ok(None);
            }
            let v = self.velocity(&intervals(a), u);
            let finite = v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite());
            Ok(finite.then(|| v.iter().map(|e| (e.lower, e.upper)).unzip()))
        };
        let Ok(Enclosure::Closed(pipe)) = enclose_step(x, h, None, None, field) else {
            return None;
        };
        let a = intervals(&pipe.set);
        let xdot: Vec<Interval> = (0..self.n)
            .map(|j| Interval::new(pipe.f_lower[j], pipe.f_upper[j]))
            .collect();
        let half_h2 = Interval::point(h) * Interval::point(h) * Interval::point(0.5);
        let (mut lower, mut upper) = (Vec::new(), Vec::new());
        for i in 0..self.n {
            let mut rho = (0..self.n).fold(Interval::point(0.0), |acc, j| {
                acc + self.df[i][j].eval_interval(&a) * xdot[j]
            });
            for (k, uk) in u.iter().enumerate() {
                let dgk = (0..self.n).fold(Interval::point(0.0), |acc, j| {
                    acc + self.dg[i][k][j].eval_interval(&a) * xdot[j]
                });
                rho = rho + dgk * *uk;
            }
            // `Df = 0` and `Dg = 0` in row i (`ẋ = u`): exactly 0, no rounding dust.
            let zero = |e: &Expr| e.as_constant() == Some(0.0);
            let still = self.df[i].iter().all(zero) && self.dg[i].iter().flatten().all(zero);
            let r = if still {
                Interval::point(0.0)
            } else {
                half_h2 * rho
            };
            if !(r.lower.is_finite() && r.upper.is_finite()) {
                return None;
            }
            lower.push(r.lower);
            upper.push(r.upper);
        }
        Some(Remainder {
            lower,
            upper,
            pipe: pipe.set,
        })
    }
}

fn intervals(b: &IntervalBox) -> Vec<Interval> {
    b.lower
        .iter()
        .zip(&b.upper)
        .map(|(&l, &u)| Interval::new(l, u))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scenario(f: &str, g: &str) -> Scenario {
        let text = format!(
            r#"
name = "t"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = {f}
g = {g}
kappa = ["-x1 - 2*x2"]
[[cbf]]
h = "x2 + 2"
[reach]
region = {{ lower = [-3, -3], upper = [3, 3] }}
m_c = 0.1
dt = 0.05
horizon = 1.0
goal = {{ lower = [-0.1, -0.1], upper = [0.1, 0.1] }}
"#
        );
        Scenario::from_toml(&text, "t.toml", std::path::Path::new(".")).unwrap()
    }

    /// The double integrator: the remainder of x₁ is `τ²/2·u_k` exactly, of x₂ zero.
    #[test]
    fn double_integrator_remainder_is_half_tau_squared_u() {
        let s = scenario(r#"["x2", "0"]"#, r#"[["0"], ["1"]]"#);
        let plant = Plant::of(&s);
        let x = IntervalBox::new(vec![0.9, 0.1], vec![1.1, 0.2]).unwrap();
        let u = [Interval::new(-1.5, -1.0)];
        let r = plant.remainder(&x, &u, 0.05).unwrap();
        let q = 0.05 * 0.05 / 2.0;
        assert!(r.lower[0] <= -1.5 * q && r.upper[0] >= -q);
        assert!(r.lower[0] > -1.5 * q - 1e-12 && r.upper[0] < -q + 1e-12);
        assert_eq!((r.lower[1], r.upper[1]), (0.0, 0.0));
        assert!(r.pipe.contains(&[1.1 + 0.2 * 0.05, 0.2]));
    }

    /// `ẋ = u`: nothing to add.
    #[test]
    fn integrator_remainder_is_zero() {
        let s = scenario(r#"["0", "0"]"#, r#"[["1"], ["1"]]"#);
        let plant = Plant::of(&s);
        let x = IntervalBox::new(vec![0.0, 0.0], vec![1.0, 1.0]).unwrap();
        let r = plant
            .remainder(&x, &[Interval::new(-2.0, 1.0)], 0.04)
            .unwrap();
        assert_eq!((r.lower, r.upper), (vec![0.0; 2], vec![0.0; 2]));
    }
}

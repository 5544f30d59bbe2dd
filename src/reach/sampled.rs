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
//!
//! With `T_s = K·dt` the input is held over `K` integration steps: the set at `t_k + j·dt` is
//! the Euler part's image at `τ = j·dt` ([`euler_image`]: every `x_k + τF(x_k)` over the set
//! at `t_k`, the network's affine bounds over that set keeping `u_k`'s correlation with `x_k`)
//! plus the remainder at `τ` ([`Intersample::at`]), one a-priori enclosure for the period.
//! The image is bounded over the whole set, not face by face: `x_k + τF(x_k)` need not grow
//! with `x_{k,i}` (it does not where `1 + τ∂ᵢFᵢ < 0`, as `τ` grows), and bounds of the network
//! on a face say nothing of the held input off that face.

use super::embedding::{input_enclosure, interaction_row, Dynamics, NetworkBoundsRef};
use super::validated::{enclose_step, Enclosure};
use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::intervals::{box_of, Interval};
use crate::scenario::{ClassK, Scenario};

mod between;
pub use between::proven_safe;

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
    /// Per CBF, `∇h` and `∇²h` ([`Plant::keeps`]).
    cbf_gradient: Vec<Vec<Expr>>,
    cbf_hessian: Vec<Vec<Vec<Expr>>>,
    /// Per CBF, `α`.
    alpha: Vec<ClassK>,
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

/// The motion over one control period, step by step: the held input's enclosure `U`, the hull
/// `H` of the a-priori enclosures of the steps so far, and the remainder's rate over it, so
/// that `R(τ) ∈ τ²/2·ρ` for every `τ` up to the last enclosed step's end (`x(s) − x_k ∈ s·Ẋ`
/// with `Ẋ = f(H) + g(H)U`, the mean value's segments within `H`). Enclosing step by step
/// from each step's set, not the whole period at once, keeps Picard–Lindelöf closing for long
/// periods (it needs `T_s·L < 1` at once).
#[derive(Clone, Debug)]
pub struct Intersample {
    /// `U`.
    u: Vec<Interval>,
    /// `H`, x coordinates (`None` before the first step, and for a still plant).
    hull: Option<IntervalBox>,
    /// `ρ = Df(H)·Ẋ + Σₖ (Dgₖ(H)·Ẋ)·Uₖ` per coordinate (exactly 0 in rows where `Df`, `Dg`
    /// vanish).
    pub rho: Vec<Interval>,
}

impl Intersample {
    /// Before the period's first step, with the held input in `u`.
    pub fn start(n: usize, u: Vec<Interval>) -> Intersample {
        Intersample {
            u,
            hull: None,
            rho: vec![Interval::point(0.0); n],
        }
    }

    /// Encloses the motion over the next step of length `h` from the x-box `from` (the set at
    /// the step's start) and updates `ρ`. Returns the step's a-priori enclosure (`Some(None)`
    /// for a still plant, whose motion needs none), `None` where it has no enclosure (or an
    /// unbounded one).
    pub fn step(
        &mut self,
        plant: &Plant,
        from: &IntervalBox,
        h: f64,
    ) -> Option<Option<IntervalBox>> {
        if plant.is_still() {
            return Some(None);
        }
        let u = &self.u;
        let field = |a: &IntervalBox, parts: bool| -> Result<_, std::convert::Infallible> {
            if parts {
                // The plant's field is one expression: no tighter over parts.
                return Ok(None);
            }
            let v = plant.velocity(&box_of(&a.lower, &a.upper), u);
            let finite = v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite());
            Ok(finite.then(|| v.iter().map(|e| (e.lower, e.upper)).unzip()))
        };
        let Ok(Enclosure::Closed(pipe)) = enclose_step(from, h, None, None, field) else {
            return None;
        };
        let hull = match &self.hull {
            Some(b) => b.hull(&pipe.set),
            None => pipe.set.clone(),
        };
        let a = box_of(&hull.lower, &hull.upper);
        // `Ẋ` over the whole hull (a later step's velocities bound earlier motion too).
        let xdot = plant.velocity(&a, u);
        let mut rho = Vec::with_capacity(plant.n);
        for i in 0..plant.n {
            // `Df = 0` and `Dg = 0` in row i (`ẋ = u`): exactly 0, no rounding dust.
            let zero = |e: &Expr| e.as_constant() == Some(0.0);
            if plant.df[i].iter().all(zero) && plant.dg[i].iter().flatten().all(zero) {
                rho.push(Interval::point(0.0));
                continue;
            }
            let mut r = (0..plant.n).fold(Interval::point(0.0), |acc, j| {
                acc + plant.df[i][j].eval_interval(&a) * xdot[j]
            });
            for (k, uk) in u.iter().enumerate() {
                let dgk = (0..plant.n).fold(Interval::point(0.0), |acc, j| {
                    acc + plant.dg[i][k][j].eval_interval(&a) * xdot[j]
                });
                r = r + dgk * *uk;
            }
            if !(r.lower.is_finite() && r.upper.is_finite()) {
                return None;
            }
            rho.push(r);
        }
        self.hull = Some(hull);
        self.rho = rho;
        Some(Some(pipe.set))
    }

    /// `H`, the hull of the steps' a-priori enclosures so far.
    pub fn hull(&self) -> Option<&IntervalBox> {
        self.hull.as_ref()
    }

    /// `U`, the held input's enclosure (empty for a still plant).
    pub fn input(&self) -> &[Interval] {
        &self.u
    }

    /// The remainder's bounds at `τ`: `τ²/2·ρ`.
    pub fn at(&self, tau: f64) -> (Vec<f64>, Vec<f64>) {
        self.between(tau, tau)
    }

    /// Bounds of the remainder at every `τ ∈ [a, b]`: `[a²/2, b²/2]·ρ` (`τ²/2 ≥ 0` grows with
    /// `τ`).
    pub fn between(&self, a: f64, b: f64) -> (Vec<f64>, Vec<f64>) {
        let half = Interval::point(0.5);
        let q = Interval::new(
            (Interval::point(a) * Interval::point(a) * half).lower,
            (Interval::point(b) * Interval::point(b) * half).upper,
        );
        self.rho
            .iter()
            .map(|r| match (r.lower, r.upper) == (0.0, 0.0) {
                true => (0.0, 0.0),
                false => {
                    let e = q * *r;
                    (e.lower, e.upper)
                }
            })
            .unzip()
    }
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
            cbf_gradient: s.cbfs.iter().map(|c| c.gradient.clone()).collect(),
            cbf_hessian: s
                .cbfs
                .iter()
                .map(|c| crate::expressions::jacobian(&c.gradient, n))
                .collect(),
            alpha: s.cbfs.iter().map(|c| c.alpha.clone()).collect(),
        }
    }

    /// Whether the remainder is 0 whatever the state (`Df = 0`, `Dg = 0`: `ẋ = u`).
    pub fn is_still(&self) -> bool {
        let zero = |e: &Expr| e.as_constant() == Some(0.0);
        self.df.iter().flatten().all(zero) && self.g_is_constant()
    }

    /// The held input's enclosure `κ(X) + v`, `v` an enclosure of the filter's correction on
    /// the x-box `x`.
    pub fn held_input(&self, x: &IntervalBox, v: &[Interval]) -> Vec<Interval> {
        let xs = box_of(&x.lower, &x.upper);
        (0..self.m)
            .map(|k| self.kappa[k].eval_interval(&xs) + v[k])
            .collect()
    }

    /// Whether `g` is constant (the second-order image, [`super::sampled_second`]).
    pub fn g_is_constant(&self) -> bool {
        self.dg
            .iter()
            .flatten()
            .flatten()
            .all(|e| e.as_constant() == Some(0.0))
    }

    /// `Df` over the x-box `a`, n×n row-major.
    pub fn df_over(&self, a: &IntervalBox) -> Vec<Interval> {
        let x = box_of(&a.lower, &a.upper);
        self.df
            .iter()
            .flatten()
            .map(|e| e.eval_interval(&x))
            .collect()
    }

    /// `f(A) + g(A)·U` over the x-box `a`.
    pub fn velocity_over(&self, a: &IntervalBox, u: &[Interval]) -> Vec<Interval> {
        self.velocity(&box_of(&a.lower, &a.upper), u)
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
    /// `u` (one step); `None` where the intersample motion has no enclosure (or an unbounded
    /// one).
    pub fn remainder(&self, x: &IntervalBox, u: &[Interval], h: f64) -> Option<Remainder> {
        let mut m = Intersample::start(self.n, u.to_vec());
        let pipe = m.step(self, x, h)?.unwrap_or_else(|| x.clone());
        let (lower, upper) = m.at(h);
        Some(Remainder { lower, upper, pipe })
    }
}

/// Bounds of the Euler part's image `{x + τF(x) : x ∈ X}` over the set `X = [lower, upper]`,
/// `F` the field of `dynamics` with the network's bounds `nn` over the whole set plus the
/// disturbance `margin`, widened by `τ·slack` (the transform's slack). Per coordinate `i` the
/// function `xᵢ + τ(f̃ᵢ(x) + m̲ᵢ·x + δ̲ᵢ)` (constant `g`; the interaction-aware row) is bounded
/// below by its mean-value form `φ(p) + Σⱼ aᵢⱼ(X)(Xⱼ − pⱼ)`, `aᵢⱼ = δᵢⱼ + τ(∂ⱼf̃ᵢ(X) + m̲ᵢⱼ)`,
/// about the corner where each `aᵢⱼ` has one sign (its low end where `aᵢⱼ ≥ 0`) and the
/// centre elsewhere: exact for affine fields, and sound whatever the sign of `1 + τ∂ᵢFᵢ`.
/// State-dependent `g` takes `g(X)·[N̲ − M, N̄ + M]` (no slopes). Mirrored for the upper end.
///
/// With `mix = Some(W)` (a point matrix, n×n row-major), the image of `x + τ·W·F(x)`: the
/// second-order image's main part ([`super::sampled_second`]), constant `g` only
/// (state-dependent `g` takes the identity). Per coordinate `i` and end the field's forms are
/// mixed row by row, `Σₗ Wᵢₗ·(F̲ₗ or F̄ₗ)` by the sign of `Wᵢₗ`, and the mean-value form is
/// taken of the mix. Entries 1 and 0 of `W` are used without a product, so the identity gives
/// `None`'s bits.
pub fn euler_image(
    dynamics: &Dynamics,
    set: &IntervalBox,
    tau: f64,
    nn: NetworkBoundsRef,
    margin: &[f64],
    slack: f64,
    mix: Option<&[f64]>,
) -> (Vec<f64>, Vec<f64>) {
    let n = dynamics.n;
    let mix = mix.filter(|_| dynamics.g_constant.is_some());
    let x = box_of(&set.lower, &set.upper);
    let t = Interval::point(tau);
    let jac: Vec<Vec<Interval>> = dynamics
        .f_tilde_jacobian
        .iter()
        .map(|row| row.iter().map(|e| e.eval_interval(&x)).collect())
        .collect();
    // State-dependent g: `τ·Σₖ gᵢₖ(X)·Uₖ`, the same for both ends.
    let held: Option<Vec<Interval>> = match dynamics.g_constant {
        Some(_) => None,
        None => {
            let u = input_enclosure(nn, margin);
            Some(
                (0..n)
                    .map(|i| {
                        let s = (0..dynamics.m).fold(Interval::point(0.0), |acc, k| {
                            acc + dynamics.g[i][k].eval_interval(&x) * u[k]
                        });
                        t * s
                    })
                    .collect(),
            )
        }
    };
    // Each coordinate's lower and upper form (zero rows for state-dependent g).
    let forms: Vec<[(Vec<Interval>, Interval); 2]> = (0..n)
        .map(|l| {
            [false, true].map(|on_upper| match &dynamics.g_constant {
                Some(b) => interaction_row(b, dynamics, nn, margin, l, on_upper),
                None => (vec![Interval::point(0.0); n], Interval::point(0.0)),
            })
        })
        .collect();
    // `w·v`, exact where `w` is 1.
    let scaled = |w: f64, v: Interval| if w == 1.0 { v } else { Interval::point(w) * v };
    let mut lower = Vec::with_capacity(n);
    let mut upper = Vec::with_capacity(n);
    for i in 0..n {
        let terms: Vec<(usize, f64)> = match mix {
            Some(w) => (0..n)
                .map(|l| (l, w[i * n + l]))
                .filter(|&(_, c)| c != 0.0)
                .collect(),
            None => vec![(i, 1.0)],
        };
        let sum = |f: &dyn Fn(usize, f64) -> Interval| {
            terms
                .iter()
                .fold(Interval::point(0.0), |acc, &(l, c)| acc + f(l, c))
        };
        let slack = (t * sum(&|_, c| scaled(c.abs(), Interval::point(slack)))).upper;
        for on_upper in [false, true] {
            // Fₗ's form for this end: its upper one where cₗ·Fₗ is bounded above by it.
            let form = |l: usize, c: f64| &forms[l][usize::from((c >= 0.0) == on_upper)];
            let a: Vec<Interval> = (0..n)
                .map(|j| {
                    let slope = sum(&|l, c| scaled(c, jac[l][j] + form(l, c).0[j]));
                    Interval::point(f64::from(u8::from(i == j))) + t * slope
                })
                .collect();
            // The expansion point: the end of Xⱼ where the term is smallest (largest for the
            // upper end) when aᵢⱼ has one sign, the centre otherwise.
            let p: Vec<f64> = (0..n)
                .map(|j| {
                    let (lo, hi) = (set.lower[j], set.upper[j]);
                    let (small, large) = if on_upper { (hi, lo) } else { (lo, hi) };
                    if a[j].lower >= 0.0 {
                        small
                    } else if a[j].upper <= 0.0 {
                        large
                    } else {
                        lo + 0.5 * (hi - lo)
                    }
                })
                .collect();
            let pp: Vec<Interval> = p.iter().map(|&v| Interval::point(v)).collect();
            let phi = sum(&|l, c| {
                let (row, delta) = form(l, c);
                let at_p = (0..n)
                    .fold(dynamics.f_tilde[l].eval_interval(&pp) + *delta, |acc, j| {
                        acc + row[j] * pp[j]
                    });
                scaled(c, at_p)
            });
            let mut total = pp[i] + t * phi;
            for j in 0..n {
                total = total + a[j] * (x[j] - pp[j]);
            }
            if let Some(h) = &held {
                total = total + h[i];
            }
            if on_upper {
                upper.push((total + Interval::point(slack)).upper);
            } else {
                lower.push((total - Interval::point(slack)).lower);
            }
        }
    }
    (lower, upper)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A two-state scenario with this `f` and `g` (also for [`super::super::sampled_second`]).
    pub(in crate::reach) fn scenario(f: &str, g: &str) -> Scenario {
        scenario_with(f, g, "x2 + 2")
    }

    pub(super) fn scenario_with(f: &str, g: &str, h: &str) -> Scenario {
        scenario_alpha(f, g, h, "1.0")
    }

    /// `h ≥ 0` with `alpha` (a TOML value).
    pub(super) fn scenario_alpha(f: &str, g: &str, h: &str, alpha: &str) -> Scenario {
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
h = "{h}"
alpha = {alpha}
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

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

/// Whether the x-box `b` is proven inside CBF `c`'s `{h ≥ 0}` (interval evaluation; NaN bounds,
/// undefined somewhere on the box, prove nothing), and whether it lies entirely outside it.
pub fn proven_safe(scenario: &Scenario, c: usize, b: &IntervalBox) -> (bool, bool) {
    let h = scenario.cbfs[c]
        .h
        .eval_interval(&box_of(&b.lower, &b.upper));
    (h.lower >= 0.0, h.upper < 0.0)
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A two-state scenario with this `f` and `g` (also for [`super::super::sampled_second`]).
    pub(in crate::reach) fn scenario(f: &str, g: &str) -> Scenario {
        scenario_with(f, g, "x2 + 2")
    }

    fn scenario_with(f: &str, g: &str, h: &str) -> Scenario {
        scenario_alpha(f, g, h, "1.0")
    }

    /// `h ≥ 0` with `alpha` (a TOML value).
    fn scenario_alpha(f: &str, g: &str, h: &str, alpha: &str) -> Scenario {
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
        let mut seed = 7u64;
        let mut uniform = |lo: f64, hi: f64| {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            lo + (hi - lo) * ((seed >> 11) as f64 / (1u64 << 53) as f64)
        };
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

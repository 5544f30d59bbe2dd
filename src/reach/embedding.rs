//! The closed-loop, interaction-aware embedding system (docs/design.md §2.3) and its Euler step.
//!
//! For the NN system `ẋ = f̃(x) + g(x)(N(x) + w)`, `w ∈ [−M, M]` (the disturbance method;
//! `M = 0` gives the NN system itself), one trajectory of
//!
//! ```text
//! dx̲ᵢ/dt = inf { Fᵢ(x) : x ∈ [x̲, x̄], xᵢ = x̲ᵢ }     dx̄ᵢ/dt = sup { Fᵢ(x) : x ∈ [x̲, x̄], xᵢ = x̄ᵢ }
//! ```
//!
//! (any sound lower/upper bounds of these) bounds every trajectory from the initial box.
//! We bound them on each face with the point `p` (the box's centre with `pᵢ` on the face):
//!
//! - `f̃ᵢ(x) ∈ f̃ᵢ(p) + Σ_{j≠i} [Jᵢⱼ](xⱼ − pⱼ)`, `[J]` the interval Jacobian of `f̃` over the
//!   face (mean-value form: the segments from `p` stay on the face; exact for affine `f̃`);
//! - for constant `g = B`, `N(x) ≥ C̲x + d̲` gives `Σₖ Bᵢₖ Nₖ(x) ≥ m̲ᵢ·x + δ̲ᵢ` with
//!   `m̲ = B⁺C̲ + B⁻C̄`, `δ̲ = B⁺d̲ + B⁻d̄` — the interaction-aware `M = A + BC` of docs/design.md §2.3;
//! - for state-dependent `g`, `Σₖ [gᵢₖ](box)·[N̲ₖ, N̄ₖ]` in interval arithmetic.
//!
//! Everything is evaluated in interval arithmetic with outward rounding, so the derivative
//! bounds are sound in floating point; the Euler step itself is the paper's (not a validated
//! integrator: README, Limitations).

use crate::expressions::{Expr, Tape};
use crate::intervals::{box_of, Interval};

/// The scenario's dynamics as the embedding needs them.
#[derive(Clone, Debug)]
pub struct Dynamics {
    /// State dimension `n`.
    pub n: usize,
    /// Input dimension `m`.
    pub m: usize,
    /// `f̃ = f + gκ`.
    pub f_tilde: Vec<Expr>,
    /// `Df̃`, n×n.
    pub f_tilde_jacobian: Vec<Vec<Expr>>,
    /// `g`, n×m.
    pub g: Vec<Vec<Expr>>,
    /// `g` as numbers when every entry is constant (the interaction-aware case).
    pub g_constant: Option<Vec<f64>>,
    /// `f̃`'s second-order terms, derived on first use ([`Dynamics::second_order`]).
    second: std::sync::OnceLock<std::sync::Arc<SecondOrder>>,
}

/// The second time derivative of a trajectory of `ẋ = f̃(x)`, `ẍ = G(x) = Df̃(x)·f̃(x)`, and
/// `DG`, for the second-order Taylor rates ([`super::end_rates::taylor3_rates`]). Compiled to
/// tapes: the trees of `DG` repeat `Df̃`'s subexpressions many times over (scenario 1's binding
/// piece: 413 distinct operations, 147,000 characters as trees).
#[derive(Debug)]
pub struct SecondOrder {
    /// `Gᵢ = Σⱼ ∂ⱼf̃ᵢ·f̃ⱼ`, one output per `i`.
    pub g: Tape,
    /// `∂Gᵢ/∂xⱼ` at output `i·n + j`, and `∂ᵢf̃ᵢ` at `n² + i`.
    pub g_jacobian: Tape,
    /// `g`'s outputs as expressions (the GPU's shaders are generated from them).
    pub g_exprs: Vec<Expr>,
    /// `g_jacobian`'s outputs as expressions, in the same order.
    pub g_jacobian_exprs: Vec<Expr>,
}

/// A network's bounds over one box, borrowed from a batch: `C̲x + d̲ ≤ N(x) ≤ C̄x + d̄` and
/// `N̲ ≤ N(x) ≤ N̄` on the box.
#[derive(Clone, Copy, Debug)]
pub struct NetworkBoundsRef<'a> {
    /// `C̲`, m×n row-major.
    pub a_lower: &'a [f64],
    /// `d̲`.
    pub b_lower: &'a [f64],
    /// `C̄`, m×n row-major.
    pub a_upper: &'a [f64],
    /// `d̄`.
    pub b_upper: &'a [f64],
    /// `N̲`.
    pub lower: &'a [f64],
    /// `N̄`.
    pub upper: &'a [f64],
}

impl Dynamics {
    /// The dynamics `ẋ = f̃(x) + g(x)u`, with `Df̃` and `g`'s constant form derived.
    pub fn new(n: usize, m: usize, f_tilde: Vec<Expr>, g: Vec<Vec<Expr>>) -> Dynamics {
        let f_tilde_jacobian = crate::expressions::jacobian(&f_tilde, n);
        let g_constant = g.iter().flatten().map(|e| e.as_constant()).collect();
        Dynamics {
            n,
            m,
            f_tilde,
            f_tilde_jacobian,
            g,
            g_constant,
            second: std::sync::OnceLock::new(),
        }
    }

    /// `G = Df̃·f̃` and `DG`, derived once per dynamics (symbolically, as `Df̃`).
    pub fn second_order(&self) -> &SecondOrder {
        self.second.get_or_init(|| {
            let g: Vec<Expr> = (0..self.n)
                .map(|i| {
                    (0..self.n).fold(Expr::constant(0.0), |acc, j| {
                        acc + self.f_tilde_jacobian[i][j].clone() * self.f_tilde[j].clone()
                    })
                })
                .collect();
            let dg = crate::expressions::jacobian(&g, self.n);
            let diagonal = (0..self.n).map(|i| self.f_tilde_jacobian[i][i].clone());
            let dg: Vec<Expr> = dg.into_iter().flatten().chain(diagonal).collect();
            std::sync::Arc::new(SecondOrder {
                g: Tape::compile(g.iter().map(Expr::node)),
                g_jacobian: Tape::compile(dg.iter().map(Expr::node)),
                g_exprs: g,
                g_jacobian_exprs: dg,
            })
        })
    }
}

fn point(x: f64) -> Interval {
    Interval::point(x)
}

/// Sound bounds `(dx̲/dt, dx̄/dt)` of the embedding system at the box `[lower, upper]`, for the
/// disturbance `w ∈ [−margin, margin]` (per input), with one network bound for the whole box.
pub fn embedding_field(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    embedding_field_by_face(dynamics, lower, upper, |_, _| nn, margin)
}

/// As [`embedding_field`], with the network bounded separately on each face: `nn(i, upper)`
/// gives the bounds over the face `xᵢ = x̄ᵢ` (`upper`) or `xᵢ = x̲ᵢ` (immrax's `local` mode;
/// tighter, since each face is a thinner box).
pub fn embedding_field_by_face<'a>(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    nn: impl Fn(usize, bool) -> NetworkBoundsRef<'a>,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let n = dynamics.n;
    let x = box_of(lower, upper);
    let centre: Vec<f64> = lower
        .iter()
        .zip(upper)
        .map(|(l, u)| l + 0.5 * (u - l))
        .collect();
    // `Df̃` over one face: the mean-value form's segments from `p` stay on the face.
    let jac_over_face = |i: usize, on_upper: bool| -> Vec<Interval> {
        let mut face = x.clone();
        face[i] = point(if on_upper { upper[i] } else { lower[i] });
        dynamics.f_tilde_jacobian[i]
            .iter()
            .map(|e| e.eval_interval(&face))
            .collect()
    };
    // For state-dependent g: [g](box), multiplied by the input enclosure [N̲ − M, N̄ + M].
    let g_box: Vec<Interval> = match dynamics.g_constant {
        Some(_) => Vec::new(),
        None => dynamics
            .g
            .iter()
            .flatten()
            .map(|e| e.eval_interval(&x))
            .collect(),
    };

    let face = |i: usize, on_upper: bool| -> Interval {
        let bounds = nn(i, on_upper);
        let jac = jac_over_face(i, on_upper);
        let mut p: Vec<f64> = centre.clone();
        p[i] = if on_upper { upper[i] } else { lower[i] };
        let p_box: Vec<Interval> = p.iter().map(|&v| point(v)).collect();
        let mut total = dynamics.f_tilde[i].eval_interval(&p_box);
        // Offsets xⱼ − pⱼ over the face (zero for j = i).
        let offset = |j: usize| Interval::new(lower[j], upper[j]) - point(p[j]);
        match &dynamics.g_constant {
            Some(b) => {
                let (row, delta) = interaction_row(b, dynamics, bounds, margin, i, on_upper);
                for j in 0..n {
                    total = total + row[j] * point(p[j]);
                }
                total = total + delta;
                for j in (0..n).filter(|&j| j != i) {
                    total = total + (jac[j] + row[j]) * offset(j);
                }
            }
            None => {
                for j in (0..n).filter(|&j| j != i) {
                    total = total + jac[j] * offset(j);
                }
                for (k, u) in input_enclosure(bounds, margin).into_iter().enumerate() {
                    total = total + g_box[i * dynamics.m + k] * u;
                }
            }
        }
        total
    };
    let d_lower = (0..n).map(|i| face(i, false).lower).collect();
    let d_upper = (0..n).map(|i| face(i, true).upper).collect();
    (d_lower, d_upper)
}

/// Row i of the interaction-aware matrix and its offset for constant `g = B`: for the lower
/// side `m̲ᵢ = Σₖ B⁺ᵢₖ C̲ₖ + B⁻ᵢₖ C̄ₖ`, `δ̲ᵢ = Σₖ B⁺ᵢₖ d̲ₖ + B⁻ᵢₖ d̄ₖ` (so `Σₖ Bᵢₖ Nₖ(x) ≥ m̲ᵢ·x + δ̲ᵢ`),
/// and symmetrically for the upper side; `d̲, d̄` widened by the disturbance.
pub(super) fn interaction_row(
    b: &[f64],
    dynamics: &Dynamics,
    nn: NetworkBoundsRef,
    margin: &[f64],
    i: usize,
    on_upper: bool,
) -> (Vec<Interval>, Interval) {
    let (n, m) = (dynamics.n, dynamics.m);
    let mut row = vec![point(0.0); n];
    let mut delta = point(0.0);
    for k in 0..m {
        let bik = b[i * m + k];
        if bik == 0.0 {
            continue;
        }
        let d_lo = point(nn.b_lower[k]) - point(margin[k]);
        let d_hi = point(nn.b_upper[k]) + point(margin[k]);
        // A lower bound of Bᵢₖ Nₖ takes Nₖ's lower form when Bᵢₖ > 0, its upper one otherwise.
        let (c, d) = if (bik > 0.0) != on_upper {
            (nn.a_lower, d_lo)
        } else {
            (nn.a_upper, d_hi)
        };
        for j in 0..n {
            row[j] = row[j] + point(bik) * point(c[k * n + j]);
        }
        delta = delta + point(bik) * d;
    }
    (row, delta)
}

/// `[N̲ₖ − Mₖ, N̄ₖ + Mₖ]` per input.
pub(super) fn input_enclosure(nn: NetworkBoundsRef, margin: &[f64]) -> Vec<Interval> {
    margin
        .iter()
        .enumerate()
        .map(|(k, &mk)| {
            Interval::new(
                (point(nn.lower[k]) - point(mk)).lower,
                (point(nn.upper[k]) + point(mk)).upper,
            )
        })
        .collect()
}

/// Widens an embedding field `[dl, du]` outward by `slack` on every side (the transform's
/// slack, [`super::Transform::field_slack`]).
pub fn widen_by(dl: &mut [f64], du: &mut [f64], slack: f64) {
    if slack > 0.0 {
        dl.iter_mut()
            .for_each(|v| *v = (point(*v) - point(slack)).lower);
        du.iter_mut()
            .for_each(|v| *v = (point(*v) + point(slack)).upper);
    }
}

/// Makes face rates bound the Euler map over the whole set: where `1 + h·∂ᵢGᵢ` may be negative
/// on the set, `xᵢ + h·Fᵢ(x)` is largest off the face `xᵢ = x̄ᵢ`, and the face's rate alone
/// misses it (docs/design.md §7). Here `F = G + e`, `G` smooth and `e` within a
/// constant bound on the whole set: `G = f̃` with `e = g·(input)` from `[g](set)` or the bounds'
/// constants; for constant `g = B` and `nn` bounding the network over the whole set, `G` is the
/// interaction-aware bound `f̃ᵢ + m̄ᵢ·x + δ̄ᵢ` itself (`m̲ᵢ` for the lower side). For `x` in the
/// set and `x'` its point on the face, `xᵢ + hGᵢ(x) = x̄ᵢ + hGᵢ(x') − (x̄ᵢ − xᵢ)(1 + h·q)` with `q`,
/// the difference quotient of `Gᵢ` in `xᵢ`, at least `Lᵢ = inf ∂ᵢGᵢ` over the set; so
/// `x̄ᵢ + h·du_i + wᵢ·max(0, −(1 + hLᵢ))` bounds it, and the rate grows by that last term over
/// `h` (mirrored for the lower side). Nothing changes where `1 + hLᵢ ≥ 0`.
///
/// Bounds of `v` on faces alone (face-local network bounds, the closed form's enclosures on
/// faces) say nothing of `v` inside the set: with them (`nn = None`) only `f̃`'s part is taken
/// care of, and the step assumes `v` does not turn `xᵢ` around (README, Limitations).
pub fn euler_turn(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    h: f64,
    nn: Option<(NetworkBoundsRef, &[f64])>,
    d_lower: &mut [f64],
    d_upper: &mut [f64],
) {
    let x = box_of(lower, upper);
    for i in 0..dynamics.n {
        let jac = dynamics.f_tilde_jacobian[i][i].eval_interval(&x);
        let w = (point(upper[i]) - point(lower[i])).upper;
        for on_upper in [false, true] {
            let slope = match (nn, &dynamics.g_constant) {
                (Some((nn, margin)), Some(b)) => {
                    jac + interaction_row(b, dynamics, nn, margin, i, on_upper).0[i]
                }
                _ => jac,
            };
            let c = (point(1.0) + point(h) * slope).lower;
            if c >= 0.0 {
                continue;
            }
            // NaN (no bound on the slope) gives an infinite rate: the set ends as non-finite.
            let extra = match c.is_nan() {
                true => f64::INFINITY,
                false => crate::rounding::div_up((point(-c) * point(w)).upper, h),
            };
            if on_upper {
                d_upper[i] = (point(d_upper[i]) + point(extra)).upper;
            } else {
                d_lower[i] = (point(d_lower[i]) - point(extra)).lower;
            }
        }
    }
}

/// One explicit Euler step `x ← x + dt·ẋ` of the embedding state, rounded outward.
pub fn embedding_step(
    lower: &mut [f64],
    upper: &mut [f64],
    d_lower: &[f64],
    d_upper: &[f64],
    dt: f64,
) {
    for i in 0..lower.len() {
        lower[i] = (point(lower[i]) + point(dt) * point(d_lower[i])).lower;
        upper[i] = (point(upper[i]) + point(dt) * point(d_upper[i])).upper;
    }
}

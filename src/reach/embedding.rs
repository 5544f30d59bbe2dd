//! The closed-loop, interaction-aware embedding system (DESIGN §2.3) and its Euler step.
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
//!   box (mean-value form; exact for affine `f̃`);
//! - for constant `g = B`, `N(x) ≥ C̲x + d̲` gives `Σₖ Bᵢₖ Nₖ(x) ≥ m̲ᵢ·x + δ̲ᵢ` with
//!   `m̲ = B⁺C̲ + B⁻C̄`, `δ̲ = B⁺d̲ + B⁻d̄` — the interaction-aware `M = A + BC` of DESIGN §2.3;
//! - for state-dependent `g`, `Σₖ [gᵢₖ](box)·[N̲ₖ, N̄ₖ]` in interval arithmetic.
//!
//! Everything is evaluated in interval arithmetic with outward rounding, so the derivative
//! bounds are sound in floating point; the Euler step itself is the paper's (not a validated
//! integrator: README, Limitations).

use crate::expressions::Expr;
use crate::intervals::Interval;

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

fn point(x: f64) -> Interval {
    Interval::point(x)
}

fn boxed(lower: &[f64], upper: &[f64]) -> Vec<Interval> {
    lower
        .iter()
        .zip(upper)
        .map(|(&l, &u)| Interval::new(l, u))
        .collect()
}

/// Sound bounds `(dx̲/dt, dx̄/dt)` of the embedding system at the box `[lower, upper]`, for the
/// disturbance `w ∈ [−margin, margin]` (per input).
pub fn embedding_field(
    dynamics: &Dynamics,
    lower: &[f64],
    upper: &[f64],
    nn: NetworkBoundsRef,
    margin: &[f64],
) -> (Vec<f64>, Vec<f64>) {
    let (n, m) = (dynamics.n, dynamics.m);
    let x = boxed(lower, upper);
    let centre: Vec<f64> = lower
        .iter()
        .zip(upper)
        .map(|(l, u)| l + 0.5 * (u - l))
        .collect();
    let jac: Vec<Interval> = dynamics
        .f_tilde_jacobian
        .iter()
        .flatten()
        .map(|e| e.eval_interval(&x))
        .collect();
    // Interaction-aware rows m̲, m̄ (n×n) and offsets δ̲, δ̄ (n), for constant g.
    let linear = dynamics.g_constant.as_ref().map(|b| {
        let mut m_lo = vec![point(0.0); n * n];
        let mut m_hi = vec![point(0.0); n * n];
        let mut d_lo = vec![point(0.0); n];
        let mut d_hi = vec![point(0.0); n];
        for i in 0..n {
            for k in 0..m {
                let bik = b[i * m + k];
                if bik == 0.0 {
                    continue;
                }
                let dl = point(nn.b_lower[k]) - point(margin[k]);
                let du = point(nn.b_upper[k]) + point(margin[k]);
                let (c_for_lo, d_for_lo, c_for_hi, d_for_hi) = if bik > 0.0 {
                    (nn.a_lower, dl, nn.a_upper, du)
                } else {
                    (nn.a_upper, du, nn.a_lower, dl)
                };
                for j in 0..n {
                    m_lo[i * n + j] = m_lo[i * n + j] + point(bik) * point(c_for_lo[k * n + j]);
                    m_hi[i * n + j] = m_hi[i * n + j] + point(bik) * point(c_for_hi[k * n + j]);
                }
                d_lo[i] = d_lo[i] + point(bik) * d_for_lo;
                d_hi[i] = d_hi[i] + point(bik) * d_for_hi;
            }
        }
        (m_lo, m_hi, d_lo, d_hi)
    });
    // Input enclosure for state-dependent g: [g](box) · [N̲ − M, N̄ + M].
    let g_box: Vec<Interval> = match dynamics.g_constant {
        Some(_) => Vec::new(),
        None => dynamics
            .g
            .iter()
            .flatten()
            .map(|e| e.eval_interval(&x))
            .collect(),
    };
    let input: Vec<Interval> = (0..m)
        .map(|k| {
            Interval::new(
                (point(nn.lower[k]) - point(margin[k])).lower,
                (point(nn.upper[k]) + point(margin[k])).upper,
            )
        })
        .collect();

    let face = |i: usize, on_upper: bool| -> Interval {
        let mut p: Vec<f64> = centre.clone();
        p[i] = if on_upper { upper[i] } else { lower[i] };
        let p_box: Vec<Interval> = p.iter().map(|&v| point(v)).collect();
        let mut total = dynamics.f_tilde[i].eval_interval(&p_box);
        // Offsets xⱼ − pⱼ over the face (zero for j = i).
        let offset = |j: usize| Interval::new(lower[j], upper[j]) - point(p[j]);
        match &linear {
            Some((m_lo, m_hi, d_lo, d_hi)) => {
                let (rows, delta) = if on_upper { (m_hi, d_hi) } else { (m_lo, d_lo) };
                for j in 0..n {
                    total = total + rows[i * n + j] * point(p[j]);
                }
                total = total + delta[i];
                for j in (0..n).filter(|&j| j != i) {
                    total = total + (jac[i * n + j] + rows[i * n + j]) * offset(j);
                }
            }
            None => {
                for j in (0..n).filter(|&j| j != i) {
                    total = total + jac[i * n + j] * offset(j);
                }
                for k in 0..m {
                    total = total + g_box[i * m + k] * input[k];
                }
            }
        }
        total
    };
    let d_lower = (0..n).map(|i| face(i, false).lower).collect();
    let d_upper = (0..n).map(|i| face(i, true).upper).collect();
    (d_lower, d_upper)
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

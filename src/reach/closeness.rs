//! The paper's closeness radius (Theorem 2) and the log norms it needs (docs/design.md §2.4).
//!
//! With `c_k ≥ sup_{x∈C} μ(Df̃(x) + g(x) C_k)` held over `[t_k, t_k + dt)` and
//! `ℓ = sup_{x∈C} ‖g(x)‖` (induced from the input norm to the state norm),
//!
//! ```text
//! r_{k+1} = e^{c_k dt} r_k + ℓ M_C (e^{c_k dt} − 1)/c_k      (ℓ M_C dt when c_k = 0),  r_0 = 0
//! ```
//!
//! which is `r_t` exactly for piecewise-constant `c`. Log norms of an interval matrix `[A]`
//! bound `μ(A)` for every `A ∈ [A]`: `μ∞ = maxᵢ(āᵢᵢ + Σ_{j≠i} mag aᵢⱼ)`, `μ₁` the same over
//! columns, and for `μ₂` the Gershgorin bound of the symmetric part
//! `maxᵢ(āᵢᵢ + ½Σ_{j≠i} mag(aᵢⱼ + aⱼᵢ))`, which bounds `λ_max((A + Aᵀ)/2)`.

use crate::intervals::Interval;
use crate::rounding::round_up;
use crate::scenario::Norm;

/// An upper bound on `μ(A)` over every `A` in the interval matrix `a` (n×n, row-major).
pub fn log_norm(a: &[Interval], n: usize, norm: Norm) -> f64 {
    let entry = |i: usize, j: usize| a[i * n + j];
    (0..n)
        .map(|i| {
            let off: Interval = (0..n)
                .filter(|&j| j != i)
                .fold(Interval::point(0.0), |s, j| {
                    let m = match norm {
                        Norm::Inf => entry(i, j).mag(),
                        Norm::One => entry(j, i).mag(),
                        Norm::Two => ((entry(i, j) + entry(j, i)) * 0.5).mag(),
                    };
                    s + Interval::point(m)
                });
            (entry(i, i) + off).upper
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

/// An upper bound on the induced norm `‖G‖` (input norm to state norm, both `norm`) over every
/// `G` in the interval matrix `g` (n×m, row-major). For ℓ2 the bound is the Frobenius norm.
pub fn induced_norm(g: &[Interval], n: usize, m: usize, norm: Norm) -> f64 {
    let mag = |i: usize, j: usize| Interval::point(g[i * m + j].mag());
    let zero = Interval::point(0.0);
    match norm {
        Norm::Inf => (0..n)
            .map(|i| (0..m).fold(zero, |s, j| s + mag(i, j)).upper)
            .fold(0.0, f64::max),
        Norm::One => (0..m)
            .map(|j| (0..n).fold(zero, |s, i| s + mag(i, j)).upper)
            .fold(0.0, f64::max),
        Norm::Two => {
            (0..n * m)
                .fold(zero, |s, k| s + mag(k / m, k % m).sqr())
                .sqrt()
                .upper
        }
    }
}

/// One step of the radius recursion, rounded up.
pub fn closeness_step(r: f64, c: f64, ell: f64, m_c: f64, dt: f64) -> f64 {
    let r = Interval::point(r);
    let forcing = Interval::point(ell) * Interval::point(m_c);
    let next = if c == 0.0 {
        r + forcing * Interval::point(dt)
    } else {
        let growth = (Interval::point(c) * Interval::point(dt)).exp();
        // (e^{c dt} − 1)/c, kept positive and sound: computed from the enclosure of e^{c dt}.
        let factor = (growth - Interval::point(1.0)) / Interval::point(c);
        growth * r + forcing * factor
    };
    round_up(next.upper.max(0.0))
}

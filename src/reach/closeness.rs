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

/// One step of the radius recursion, rounded up: `e^z r + ℓ M_C dt φ(z)` with `z = c dt` and
/// `φ(z) = (e^z − 1)/z` ([`phi_upper`]), which is `r + ℓ M_C dt` at `c = 0` with no case of its
/// own. Every term is non-negative (`r, ℓ, M_C ≥ 0`), so upper bounds of each give one of the sum.
/// The GPU engine takes the same formula (`closeness_step` in shaders/embed.wgsl).
pub fn closeness_step(r: f64, c: f64, ell: f64, m_c: f64, dt: f64) -> f64 {
    let z = (Interval::point(c) * Interval::point(dt)).upper;
    let growth = Interval::point(z).exp().upper;
    let forcing = Interval::point(ell) * Interval::point(m_c) * Interval::point(dt);
    let next = Interval::point(growth) * Interval::point(r)
        + Interval::point(forcing.upper) * Interval::point(phi_upper(z));
    round_up(next.upper.max(0.0))
}

/// `|z|` up to which [`phi_upper`] sums the series.
pub const PHI_SERIES: f64 = 0.5;
/// The series' tail past degree 12 is at most `PHI_TAIL·|z|¹³` on `|z| ≤ PHI_SERIES`:
/// `Σ_{k>12} |z|ᵏ/(k+1)! ≤ |z|¹³/14!·1/(1 − |z|/15)`, and `1/(14!·(1 − 1/30)) < 1.19e-11`.
pub const PHI_TAIL: f64 = 1.2e-11;

/// An upper bound on `φ(z) = (eᶻ − 1)/z` (`φ(0) = 1`; increasing in `z`). Near 0, `eᶻ − 1`
/// cancels: from an enclosure of `eᶻ` one ulp wide, `(eᶻ − 1)/z` is off by `2⁻⁵²/|z|`
/// relative, without bound as `z → 0`. So for `|z| ≤ PHI_SERIES` the series
/// `Σ_{k ≤ 12} zᵏ/(k+1)!` in interval arithmetic plus its tail (`PHI_TAIL`), a few ulp wide;
/// elsewhere `(eᶻ − 1)/z` from the enclosure of `eᶻ`, where `|eᶻ − 1| ≥ 0.39`.
pub fn phi_upper(z: f64) -> f64 {
    let zi = Interval::point(z);
    if z.is_nan() || z.abs() > PHI_SERIES {
        return ((zi.exp() - Interval::point(1.0)) / zi).upper;
    }
    // c_k = 1/(k+1)!, enclosed.
    let mut c = [Interval::point(1.0); 13];
    for k in 1..13 {
        c[k] = c[k - 1] / Interval::point((k + 1) as f64);
    }
    let series = c[..12].iter().rev().fold(c[12], |s, &ck| s * zi + ck);
    let t = Interval::point(z.abs());
    let power = (1..13).fold(t, |p, _| p * t);
    (series + power * Interval::point(PHI_TAIL)).upper
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `φ` by its series to degree 40 in f64 (a few ulp) on `|z| ≤ 1`, else from `exp_m1`.
    fn phi_reference(z: f64) -> f64 {
        if z.abs() > 1.0 {
            return z.exp_m1() / z;
        }
        let (mut term, mut sum) = (1.0_f64, 1.0_f64);
        for k in 1..40 {
            term *= z / (k + 1) as f64;
            sum += term;
        }
        sum
    }

    /// `phi_upper` lies above `φ` and within 1e-14 of it over `|z| ≤ 60`, through 0 and both
    /// ends of the series; the quotient of the `exp` enclosure it replaced is ~1e-4 too wide at
    /// `z = 1e-12` (the cancellation).
    #[test]
    fn phi_upper_is_tight_and_above_phi() {
        let mut zs: Vec<f64> = (-6000..=6000).map(|i| i as f64 * 0.01).collect();
        zs.extend((0..300).flat_map(|e| [1e-15 * 1.13_f64.powi(e), -1e-15 * 1.13_f64.powi(e)]));
        zs.extend([
            0.0,
            PHI_SERIES,
            -PHI_SERIES,
            PHI_SERIES.next_up(),
            -PHI_SERIES.next_up(),
        ]);
        for z in zs {
            let (up, exact) = (phi_upper(z), phi_reference(z));
            assert!(up >= exact * (1.0 - 1e-15), "{z}: {up} < {exact}");
            assert!(up <= exact * (1.0 + 1e-14), "{z}: {up} vs {exact}");
        }
        let z = 1e-12;
        let old = (Interval::point(z).exp() - Interval::point(1.0)) / Interval::point(z);
        assert!(old.upper > 1.0 + 1e-4 && phi_upper(z) < 1.0 + 1e-11);
    }

    /// The step is `r + ℓ M_C dt` at `c = 0`, continuous through it, and grows with `c`.
    #[test]
    fn closeness_step_is_continuous_in_c() {
        let (ell, m_c, dt, r) = (1.3, 0.19, 0.04, 0.2);
        let at0 = closeness_step(r, 0.0, ell, m_c, dt);
        let plain = r + ell * m_c * dt;
        assert!(
            at0 >= plain && at0 <= plain * (1.0 + 1e-14),
            "{at0} vs {plain}"
        );
        for c in [1e-300, 1e-14, -1e-14, 1e-8, -1e-8] {
            let s = closeness_step(r, c, ell, m_c, dt);
            assert!(
                (s - plain).abs() <= plain * (c.abs() * dt + 1e-14),
                "{c}: {s}"
            );
        }
        let exact = |c: f64| (c * dt).exp() * r + ell * m_c * (c * dt).exp_m1() / c;
        for c in [-50.0, -1.0, -1e-3, 1e-3, 1.0, 20.0] {
            let s = closeness_step(r, c, ell, m_c, dt);
            assert!(s >= exact(c) * (1.0 - 1e-15), "{c}: {s}");
            assert!(s <= exact(c) * (1.0 + 1e-13), "{c}: {s}");
        }
    }
}

//! `order = r` in a `[[cbf]]`: the high-order CBF of Xiao and Belta written out for the user.
//!
//! A position bound on a double integrator has relative degree two: no input acts on
//! `h`'s row, which then only asks `ψ₁ = L_f̃h + α₁(h) ≥ 0`. The section compiles to the CBFs
//! `ψ₀ = h, ψ₁, …, ψ_{r−1}` with `ψₖ = L_f̃ψₖ₋₁ + αₖ(ψₖ₋₁)` and the class-K function `αₖ₊₁`
//! on `ψₖ`: exactly what writing them out by hand gives, so `S` requires every level and the
//! filter, the engines and the error maps see ordinary CBFs.

use super::compile::Compiler;
use super::*;

/// The largest `order` accepted: each level differentiates the last once more (the filter's
/// rows once again), and higher orders are rare in practice.
pub const MAX_ORDER: usize = 4;

/// The key naming the class-K function of level `level` of section `i`, whose `alpha` is
/// `alpha`.
pub(super) fn alpha_key(i: usize, alpha: &Alpha, level: usize) -> String {
    match alpha {
        Alpha::One(_) => format!("cbf[{i}].alpha"),
        Alpha::Levels(_) => format!("cbf[{i}].alpha[{level}]"),
    }
}

/// The key naming the expression of level `level` of section `i`: its `h`, or its `order`
/// (which wrote `ψ_level`).
pub(super) fn level_key(i: usize, level: usize) -> String {
    match level {
        0 => format!("cbf[{i}].h"),
        k => format!("cbf[{i}].order (ψ{k})"),
    }
}

/// The name of level `level` of the CBF named `name`.
fn level_name(name: &str, level: usize) -> String {
    match level {
        0 => name.to_string(),
        k => format!("{name}.psi{k}"),
    }
}

impl Compiler<'_> {
    /// The CBFs of section `i`: `h` alone, or with `order = r` its `r` levels.
    pub(super) fn high_order_cbf(
        &self,
        i: usize,
        cb: &CbfSection,
        f_tilde: &[Expr],
        g: &[Vec<Expr>],
    ) -> Result<Vec<Cbf>, ScenarioError> {
        let key = format!("cbf[{i}]");
        let order = match cb.order {
            None => 1,
            Some(r) if (1..=MAX_ORDER as i64).contains(&r) => r as usize,
            Some(r) => {
                return Err(self.invalid(
                    format!("{key}.order"),
                    format!("expected h's relative degree, 1 to {MAX_ORDER}, found {r}"),
                ))
            }
        };
        let alphas: Vec<&Number> = match &cb.alpha {
            Alpha::One(a) => vec![a; order],
            Alpha::Levels(list) if list.len() == order => list.iter().collect(),
            Alpha::Levels(list) => {
                return Err(self.invalid(
                    format!("{key}.alpha"),
                    format!(
                        "expected {order} class-K functions (one per level of order = {order}), \
                         found {}",
                        list.len()
                    ),
                ))
            }
        };
        let name = cb.name.clone().unwrap_or_else(|| format!("h{}", i + 1));
        let (n, m) = (f_tilde.len(), g.first().map_or(0, Vec::len));
        let mut h = self.expr(format!("{key}.h"), &cb.h)?;
        let mut levels = Vec::with_capacity(order);
        for (level, alpha) in alphas.into_iter().enumerate() {
            // Before differentiating: the filter's rows differentiate ∇ψ·f̃ again.
            limits::check_derivative_size(&h, Some(f_tilde))
                .map_err(|m| self.invalid(level_key(i, level), m))?;
            let alpha = self.class_k(&alpha_key(i, &cb.alpha, level), alpha)?;
            let gradient = expressions::gradient(&h, n);
            let inert = (0..m).all(|j| {
                (0..n)
                    .map(|i| gradient[i].clone() * g[i][j].clone())
                    .fold(Expr::constant(0.0), |a, b| a + b)
                    .collected()
                    .as_constant()
                    == Some(0.0)
            });
            let last = level + 1 == order;
            if !last && !inert {
                return Err(self.invalid(
                    format!("{key}.order"),
                    format!(
                        "order = {order}, but the input acts on {} already (∇ψ{level}·g does \
                         not simplify to 0): its relative degree is {}, so write order = {}",
                        level_name(&name, level),
                        level + 1,
                        level + 1
                    ),
                ));
            }
            let next = (!last).then(|| {
                let drift = (0..n)
                    .map(|i| gradient[i].clone() * f_tilde[i].clone())
                    .fold(Expr::constant(0.0), |a, b| a + b);
                (drift + alpha.of(h.clone())).collected()
            });
            levels.push(Cbf {
                name: level_name(&name, level),
                gradient,
                h,
                alpha,
                inert,
                section: i,
                level,
            });
            match next {
                Some(psi) => h = psi,
                None => break,
            }
        }
        Ok(levels)
    }
}

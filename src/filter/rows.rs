//! The filter's constraint rows `aₖ(x)·θ ≤ bₖ(x)` over a box (by interval evaluation) and as
//! expressions in `x`. It may import the scenario, expressions, intervals and boxes.

use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::intervals::Interval;
use crate::scenario::Scenario;

fn sum(it: impl Iterator<Item = Interval>) -> Interval {
    it.fold(Interval::point(0.0), |a, b| a + b)
}

/// The constraint rows `aₖ·θ ≤ bₖ` of the filter (as in
/// [`super::SafetyFilter::constraint_rows`]) enclosed over `box ∩ S` by interval evaluation: `(a, b)`
/// with `a` row-major (rows × m). Each `hᵢ` enters as `hᵢ(box) ∩ [0, ∞)`, since `hᵢ ≥ 0` on `S`.
pub fn interval_rows(s: &Scenario, cell: &IntervalBox) -> (Vec<Interval>, Vec<Interval>) {
    let (n, m) = (s.n(), s.m());
    let xs: Vec<Interval> = (0..n)
        .map(|i| Interval::new(cell.lower[i], cell.upper[i]))
        .collect();
    let ft: Vec<Interval> = s.f_tilde.iter().map(|e| e.eval_interval(&xs)).collect();
    let g: Vec<Interval> = s.g.iter().flatten().map(|e| e.eval_interval(&xs)).collect();
    let (mut a, mut b) = (Vec::new(), Vec::new());
    for cbf in &s.cbfs {
        let grad: Vec<Interval> = cbf.gradient.iter().map(|e| e.eval_interval(&xs)).collect();
        // Only the points of S matter (v is bounded on `box ∩ S`), where every `hᵢ ≥ 0`.
        let h_all = cbf.h.eval_interval(&xs);
        let h = if h_all.is_nan() {
            h_all
        } else {
            Interval::new(h_all.lower.max(0.0), h_all.upper.max(0.0))
        };
        for j in 0..m {
            // Exactly 0 where no input acts on h (its enclosure would be ±the least subnormal).
            a.push(match cbf.inert {
                true => Interval::point(0.0),
                false => -sum((0..n).map(|i| grad[i] * g[i * m + j])),
            });
        }
        b.push(sum((0..n).map(|i| grad[i] * ft[i])) + cbf.alpha.over(h));
    }
    if let Some(bounds) = &s.input_bounds {
        let kappa: Vec<Interval> = s.kappa.iter().map(|e| e.eval_interval(&xs)).collect();
        for j in 0..m {
            let mut row = vec![Interval::point(0.0); m];
            row[j] = Interval::point(1.0);
            a.extend(row.iter().copied());
            b.push(Interval::point(bounds.upper[j]) - kappa[j]);
            row[j] = Interval::point(-1.0);
            a.extend(row);
            b.push(kappa[j] - Interval::point(bounds.lower[j]));
        }
    }
    for c in &s.constraints {
        a.extend(c.a.iter().map(|e| e.eval_interval(&xs)));
        b.push(c.b.eval_interval(&xs));
    }
    (a, b)
}

/// The filter's constraint rows `aₖ(x)·θ ≤ bₖ(x)` as expressions, in the order of
/// [`interval_rows`] (per CBF `aₖ = −∇hᵢ·g`, `bₖ = ∇hᵢ·f̃ + αᵢ(hᵢ)`; per input bound; per extra
/// constraint): `(a, b)` with `a` one row of `m` per constraint. With `clamp_h`, each `hᵢ`
/// enters as `max(hᵢ, 0)` (equal on `S`; tighter over boxes that reach outside it).
pub fn row_expressions(s: &Scenario, clamp_h: bool) -> (Vec<Vec<Expr>>, Vec<Expr>) {
    let (n, m) = (s.n(), s.m());
    let zero = || Expr::constant(0.0);
    let sum_e = |it: &mut dyn Iterator<Item = Expr>| it.fold(zero(), |a, b| a + b);
    let mut a_rows: Vec<Vec<Expr>> = Vec::new();
    let mut b_rows: Vec<Expr> = Vec::new();
    for cbf in &s.cbfs {
        let row: Vec<Expr> = (0..m)
            .map(|j| match cbf.inert {
                true => zero(),
                false => -sum_e(&mut (0..n).map(|i| cbf.gradient[i].clone() * s.g[i][j].clone())),
            })
            .collect();
        a_rows.push(row);
        let h = if clamp_h {
            cbf.h.clone().max(zero())
        } else {
            cbf.h.clone()
        };
        b_rows.push(
            sum_e(&mut (0..n).map(|i| cbf.gradient[i].clone() * s.f_tilde[i].clone()))
                + cbf.alpha.of(h),
        );
    }
    if let Some(bounds) = &s.input_bounds {
        for j in 0..m {
            let mut row = vec![zero(); m];
            row[j] = Expr::constant(1.0);
            a_rows.push(row.clone());
            b_rows.push(Expr::constant(bounds.upper[j]) - s.kappa[j].clone());
            row[j] = Expr::constant(-1.0);
            a_rows.push(row);
            b_rows.push(s.kappa[j].clone() - Expr::constant(bounds.lower[j]));
        }
    }
    for c in &s.constraints {
        a_rows.push(c.a.clone());
        b_rows.push(c.b.clone());
    }
    (a_rows, b_rows)
}

//! Limits a scenario is checked against before any work, so that no input makes a command
//! run without end or exhaust memory: initial boxes, steps, the size of the derivatives the
//! filter's enclosures build, and expressions that are NaN or infinite somewhere in `C`.

use crate::boxes::IntervalBox;
use crate::expressions::{Expr, Func, Node};
use crate::intervals::Interval;

/// Most initial boxes a scenario's `[reach.partition]` may make.
pub const MAX_INITIAL_BOXES: usize = 1_000_000;

/// Most steps (`T / dt`, times the substeps) of a run.
pub const MAX_STEPS: f64 = 10_000_000.0;

/// Most frames the continuous-time sets may be kept in (`[reach] turned_frames`, each bounding
/// the network on its own slabs).
pub const MAX_TURNED_FRAMES: usize = 16;

/// Most nodes of an expression's derivative (an upper bound, before simplification); the
/// filter's enclosures differentiate `∇h · f̃` once more, so this bounds their size too.
pub const MAX_DERIVATIVE_NODES: f64 = 200_000.0;

/// Interval evaluations the search for NaN or ∞ over `C` may spend.
const FINITE_BUDGET: usize = 2_000;

/// A number as a message about a limit shows it: plainly, or in scientific notation when it is
/// huge or tiny (`1e300`, not three hundred digits).
pub fn shown(v: f64) -> String {
    match v != 0.0 && v.is_finite() && (v.abs() >= 1e6 || v.abs() < 1e-4) {
        true => format!("{v:e}"),
        false => v.to_string(),
    }
}

/// Nodes of a tree, as the size arithmetic below counts them.
pub fn size(n: &Node) -> f64 {
    n.size() as f64
}

/// An upper bound of the nodes of `∂n/∂x` for any variable (the rules of
/// `Expr::derivative` before simplification, which only shrinks it).
pub fn derivative_size(n: &Node) -> f64 {
    match n {
        Node::Const(_) | Node::Var(_) => 1.0,
        Node::Neg(a) => derivative_size(a) + 1.0,
        Node::Add(a, b) | Node::Sub(a, b) => derivative_size(a) + derivative_size(b) + 1.0,
        Node::Mul(a, b) => size(a) + size(b) + derivative_size(a) + derivative_size(b) + 3.0,
        Node::Div(a, b) => size(a) + 3.0 * size(b) + derivative_size(a) + derivative_size(b) + 6.0,
        Node::Pow(a, _) => 2.0 * size(a) + derivative_size(a) + 4.0,
        Node::Call(f, args) => {
            let s: f64 = args.iter().map(size).sum();
            let d: f64 = args.iter().map(derivative_size).sum();
            let k = match f {
                Func::Min | Func::Max | Func::Atan2 => 3.0,
                _ => 2.0,
            };
            k * (s + d) + 6.0
        }
    }
}

/// Checks the size of `∂e/∂x` and, when `then` is given (`f̃`), of `∂(∂e/∂xᵢ · f̃ᵢ)/∂x`:
/// `Err(message)` past [`MAX_DERIVATIVE_NODES`].
pub fn check_derivative_size(e: &Expr, then: Option<&[Expr]>) -> Result<(), String> {
    let first = derivative_size(e.node());
    let too_big = |d: f64, what: &str| {
        format!(
            "its {what} would have about {d:.0} nodes, more than {MAX_DERIVATIVE_NODES:.0} \
             (simplify the expression or give it in fewer, shared parts)"
        )
    };
    if first > MAX_DERIVATIVE_NODES {
        return Err(too_big(first, "derivative"));
    }
    if let Some(f) = then {
        let mut second = 0.0;
        for (i, fi) in f.iter().enumerate() {
            let gi = e.derivative(i);
            second += size(gi.node())
                + size(fi.node())
                + derivative_size(gi.node())
                + derivative_size(fi.node())
                + 4.0;
            if second > MAX_DERIVATIVE_NODES {
                return Err(too_big(second, "second derivative (∇h·f̃ differentiated)"));
            }
        }
    }
    Ok(())
}

/// Whether an interval is a finite enclosure.
fn finite(v: Interval) -> bool {
    v.lower.is_finite() && v.upper.is_finite()
}

/// Searches `region` for a point where one of `exprs` (`(key, expression)`) is NaN or
/// infinite: interval evaluation over boxes, bisected where an enclosure is not finite,
/// within a budget; a box that stays so is sampled (centre and corners). `Some((key, x,
/// value))` for a point found; `None` when every enclosure became finite or no point was
/// found (then the engines' own NaN checks stay in charge).
pub fn find_non_finite(
    region: &IntervalBox,
    exprs: &[(String, &Expr)],
) -> Option<(String, Vec<f64>, f64)> {
    let mut todo = vec![region.clone()];
    let mut spent = 0;
    let mut suspects: Vec<IntervalBox> = Vec::new();
    while let Some(b) = todo.pop() {
        let x: Vec<Interval> = (0..b.dim())
            .map(|i| Interval::new(b.lower[i], b.upper[i]))
            .collect();
        spent += 1;
        if exprs.iter().all(|(_, e)| finite(e.eval_interval(&x))) {
            continue;
        }
        if spent + todo.len() + 2 > FINITE_BUDGET {
            suspects.push(b);
            continue;
        }
        let (l, r) = b.bisect();
        todo.push(l);
        todo.push(r);
    }
    for b in suspects {
        let n = b.dim();
        let mut points = vec![b.point_at(&vec![0.5; n])];
        for k in 0..(1usize << n.min(6)) {
            let s: Vec<f64> = (0..n).map(|i| ((k >> i) & 1) as f64).collect();
            points.push(b.point_at(&s));
        }
        for p in points {
            for (key, e) in exprs {
                let v = e.eval(&p);
                if !v.is_finite() {
                    return Some((key.clone(), p, v));
                }
            }
        }
    }
    None
}

/// Cells of the grid over `C` at whose nodes [`largest_on`] samples.
const SAMPLE_NODES: usize = 4096;

/// The largest finite value of `e` at the nodes of a grid of at most [`SAMPLE_NODES`] cells
/// over `region` (corners included): where a CBF's `α` must be class-K, `h`'s range on `C`
/// (sampled, so a guard against a mistyped `α`, not a proof). −∞ where no node is finite.
pub fn largest_on(region: &IntervalBox, e: &Expr) -> f64 {
    let n = region.dim();
    let k = crate::boxes::per_axis_within(n, SAMPLE_NODES, 64);
    (crate::boxes::grid_points(region, &vec![k + 1; n]).iter())
        .map(|x| e.eval(x))
        .filter(|v| v.is_finite())
        .fold(f64::NEG_INFINITY, f64::max)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    fn parse(text: &str) -> Expr {
        crate::expressions::parse(text, &["x1".into(), "x2".into()], &BTreeMap::new()).unwrap()
    }

    #[test]
    fn derivative_size_bounds_the_derivative() {
        for text in [
            "x1*x2*sin(x1)",
            "sqrt(1 + x1^2)/(x2^2 + 1)",
            "max(x1, x2)*exp(x1)",
        ] {
            let e = parse(text);
            for j in 0..2 {
                assert!(
                    size(e.derivative(j).node()) <= derivative_size(e.node()),
                    "{text}"
                );
            }
        }
        let product = vec!["(x1 + 1)"; 1000].join("*");
        let e = parse(&product);
        assert!(check_derivative_size(&e, None).is_err());
        assert!(check_derivative_size(&parse("x1*x2"), Some(&[parse("x1"), parse("x2")])).is_ok());
    }

    #[test]
    fn nan_over_the_region_is_found() {
        let c = IntervalBox::new(vec![-3.0, -3.0], vec![3.0, 3.0]).unwrap();
        let bad = parse("1/(x1-x1)");
        let found = find_non_finite(&c, &[("cbf[0].h".into(), &bad)]);
        assert_eq!(found.map(|f| f.0), Some("cbf[0].h".to_string()));
        let pole = parse("1/(x1 - 0.375)");
        assert!(find_non_finite(&c, &[("h".into(), &pole)]).is_some());
        let fine = parse("1/(x1^2 + 1) + x1/(x2^2+2)");
        assert!(find_non_finite(&c, &[("h".into(), &fine)]).is_none());
    }

    #[test]
    fn the_largest_value_on_c_is_found_at_its_corners_and_nodes() {
        let c = IntervalBox::new(vec![-1.0, 0.0], vec![2.0, 1.0]).unwrap();
        let e = crate::expressions::parse(
            "x1^2 - x2",
            &["x1".to_string(), "x2".to_string()],
            &Default::default(),
        )
        .unwrap();
        assert_eq!(largest_on(&c, &e), 4.0);
        let nowhere =
            crate::expressions::parse("ln(x1 - 5)", &["x1".to_string()], &Default::default())
                .unwrap();
        assert_eq!(largest_on(&c, &nowhere), f64::NEG_INFINITY);
    }
}

//! Symbolic differentiation and the simplifying constructors it builds with.
//!
//! Constants fold only when the `f64` result is exact (checked with an error-free transformation:
//! TwoSum for `±`, a fused multiply–add residual for `×`, `÷`), so a folded tree evaluates, point
//! or interval, exactly as the unfolded one.

use super::eval::{apply1, apply2};
use super::{Func, Node};
use Node::Const;

/// Smallest magnitude at which an FMA residual of zero proves a product or quotient exact (below
/// it the residual itself could underflow to zero).
const EXACT_FLOOR: f64 = 1e-280;

pub(super) fn exact_add(a: f64, b: f64) -> Option<f64> {
    let s = a + b;
    let bb = s - a;
    let err = (a - (s - bb)) + (b - bb);
    (s.is_finite() && err == 0.0).then_some(s)
}

pub(super) fn exact_mul(a: f64, b: f64) -> Option<f64> {
    let p = a * b;
    let exact = a == 0.0 || b == 0.0 || (p.abs() >= EXACT_FLOOR && a.mul_add(b, -p) == 0.0);
    (p.is_finite() && exact).then_some(p)
}

pub(super) fn exact_div(a: f64, b: f64) -> Option<f64> {
    let q = a / b;
    let exact = b != 0.0 && (a == 0.0 || (q.abs() >= EXACT_FLOOR && q.mul_add(b, -a) == 0.0));
    (q.is_finite() && exact).then_some(q)
}

/// `a^n` if every product of [`crate::rounding::pow_int`]'s chain is exact.
fn exact_pow(a: f64, n: i32) -> Option<f64> {
    let mut acc = 1.0;
    for _ in 0..n.unsigned_abs().min(64) {
        acc = exact_mul(acc, a)?;
    }
    match n {
        0 => Some(1.0),
        _ if n.unsigned_abs() > 64 => None,
        _ if n > 0 => Some(acc),
        _ => exact_div(1.0, acc),
    }
}

/// Folds `n` to a constant when all its children are constants and the result is exact
/// (transcendental functions of constants are left alone).
pub(super) fn fold(n: Node) -> Node {
    let folded = match &n {
        Node::Neg(u) => match **u {
            Const(a) => Some(-a),
            _ => None,
        },
        Node::Add(u, v) | Node::Sub(u, v) | Node::Mul(u, v) | Node::Div(u, v) => {
            match (&**u, &**v) {
                (Const(a), Const(b)) => match &n {
                    Node::Add(..) => exact_add(*a, *b),
                    Node::Sub(..) => exact_add(*a, -*b),
                    Node::Mul(..) => exact_mul(*a, *b),
                    _ => exact_div(*a, *b),
                },
                _ => None,
            }
        }
        Node::Pow(u, k) => match **u {
            Const(a) => exact_pow(a, *k),
            _ => None,
        },
        Node::Call(f, args) => {
            let exact = matches!(
                f,
                Func::Abs | Func::Min | Func::Max | Func::Sign | Func::Step | Func::Delta
            );
            match args.as_slice() {
                [Const(a)] if exact => Some(apply1(*f, *a)),
                [Const(a), Const(b)] if exact => Some(apply2(*f, *a, *b)),
                _ => None,
            }
            .filter(|v| !v.is_nan())
        }
        Const(_) | Node::Var(_) => None,
    };
    folded.map_or(n, Const)
}

fn is(n: &Node, c: f64) -> bool {
    matches!(n, Const(v) if *v == c)
}

/// `−a`, simplified.
pub(super) fn neg(a: Node) -> Node {
    match a {
        Const(c) => Const(-c),
        Node::Neg(u) => *u,
        a => Node::Neg(Box::new(a)),
    }
}

/// `a + b`, simplified.
pub(super) fn add(a: Node, b: Node) -> Node {
    match (a, b) {
        (a, b) if is(&a, 0.0) => b,
        (a, b) if is(&b, 0.0) => a,
        (a, Node::Neg(b)) => sub(a, *b),
        (Node::Neg(a), b) => sub(b, *a),
        (a, b) => fold(Node::Add(Box::new(a), Box::new(b))),
    }
}

/// `a − b`, simplified.
pub(super) fn sub(a: Node, b: Node) -> Node {
    match (a, b) {
        (a, b) if is(&b, 0.0) => a,
        (a, b) if is(&a, 0.0) => neg(b),
        (a, Node::Neg(b)) => add(a, *b),
        (a, b) => fold(Node::Sub(Box::new(a), Box::new(b))),
    }
}

/// `a · b`, simplified (constants move to the left).
pub(super) fn mul(a: Node, b: Node) -> Node {
    match (a, b) {
        (a, b) if is(&a, 0.0) || is(&b, 0.0) => Const(0.0),
        (a, b) if is(&a, 1.0) => b,
        (a, b) if is(&b, 1.0) => a,
        (a, b) if is(&a, -1.0) => neg(b),
        (a, b) if is(&b, -1.0) => neg(a),
        (Const(a), Const(b)) => fold(Node::Mul(Box::new(Const(a)), Box::new(Const(b)))),
        (a, Const(c)) => mul(Const(c), a),
        (Node::Neg(a), b) => neg(mul(*a, b)),
        (a, Node::Neg(b)) => neg(mul(a, *b)),
        (Const(c1), Node::Mul(u, v)) => match *u {
            Const(c2) if exact_mul(c1, c2).is_some() => mul(Const(c1 * c2), *v),
            u => Node::Mul(Box::new(Const(c1)), Box::new(Node::Mul(Box::new(u), v))),
        },
        (a, b) => Node::Mul(Box::new(a), Box::new(b)),
    }
}

/// `a / b`, simplified.
pub(super) fn div(a: Node, b: Node) -> Node {
    match (a, b) {
        (a, _) if is(&a, 0.0) => Const(0.0),
        (a, b) if is(&b, 1.0) => a,
        (a, b) if is(&b, -1.0) => neg(a),
        (a, b) => fold(Node::Div(Box::new(a), Box::new(b))),
    }
}

/// `a^n`, simplified.
pub(super) fn pow(a: Node, n: i32) -> Node {
    match n {
        0 => Const(1.0),
        1 => a,
        _ => fold(Node::Pow(Box::new(a), n)),
    }
}

fn call(f: Func, u: Node) -> Node {
    fold(Node::Call(f, vec![u]))
}

/// `∂n/∂x_var`, simplified.
/// `n` with every `Var(i)` replaced by `with[i]`, simplified on the way up.
pub(super) fn substitute(n: &Node, with: &[Node]) -> Node {
    let sub = |u: &Node| substitute(u, with);
    match n {
        Node::Const(c) => Node::Const(*c),
        Node::Var(i) => with[*i].clone(),
        Node::Neg(u) => neg(sub(u)),
        Node::Add(a, b) => add(sub(a), sub(b)),
        Node::Sub(a, b) => self::sub(sub(a), sub(b)),
        Node::Mul(a, b) => mul(sub(a), sub(b)),
        Node::Div(a, b) => div(sub(a), sub(b)),
        Node::Pow(u, k) => pow(sub(u), *k),
        Node::Call(f, args) => Node::Call(*f, args.iter().map(sub).collect()),
    }
}

pub(super) fn derivative(n: &Node, var: usize) -> Node {
    let d = |u: &Node| derivative(u, var);
    match n {
        Const(_) => Const(0.0),
        Node::Var(i) => Const(if *i == var { 1.0 } else { 0.0 }),
        Node::Neg(u) => neg(d(u)),
        Node::Add(u, v) => add(d(u), d(v)),
        Node::Sub(u, v) => sub(d(u), d(v)),
        Node::Mul(u, v) => add(mul(d(u), (**v).clone()), mul((**u).clone(), d(v))),
        Node::Div(u, v) => {
            let (du, dv) = (d(u), d(v));
            let quotient = div(du, (**v).clone());
            if is(&dv, 0.0) {
                return quotient;
            }
            sub(quotient, div(mul((**u).clone(), dv), pow((**v).clone(), 2)))
        }
        Node::Pow(u, k) => mul(
            d(u),
            mul(
                Const(f64::from(*k)),
                pow((**u).clone(), k.saturating_sub(1)),
            ),
        ),
        Node::Call(f, args) => match (f, args.as_slice()) {
            (Func::Min | Func::Max, [u, v]) => {
                // d min(u, v) = step(v − u)·u' + step(u − v)·v'; max swaps the selectors.
                let (first, second) = (sub(v.clone(), u.clone()), sub(u.clone(), v.clone()));
                let (su, sv) = if *f == Func::Min {
                    (first, second)
                } else {
                    (second, first)
                };
                add(
                    mul(d(u), call(Func::Step, su)),
                    mul(d(v), call(Func::Step, sv)),
                )
            }
            (Func::Atan2, [y, x]) => {
                // d atan2(y, x) = (x·y' − y·x')/(x² + y²).
                let r2 = add(pow(x.clone(), 2), pow(y.clone(), 2));
                div(sub(mul(x.clone(), d(y)), mul(y.clone(), d(x))), r2)
            }
            (_, [u]) => {
                let u0 = u.clone();
                let outer = match f {
                    Func::Sqrt => return div(d(u), mul(Const(2.0), call(Func::Sqrt, u0))),
                    Func::Ln => return div(d(u), u0),
                    Func::Cos => return neg(mul(d(u), call(Func::Sin, u0))),
                    Func::Exp => call(Func::Exp, u0),
                    Func::Sin => call(Func::Cos, u0),
                    Func::Tanh => sub(Const(1.0), pow(call(Func::Tanh, u0), 2)),
                    Func::Atan => return div(d(u), add(Const(1.0), pow(u0, 2))),
                    Func::Abs => call(Func::Sign, u0),
                    Func::Sign | Func::Step | Func::Delta => call(Func::Delta, u0),
                    Func::Min | Func::Max | Func::Atan2 => Const(f64::NAN),
                };
                mul(d(u), outer)
            }
            _ => Const(f64::NAN),
        },
    }
}

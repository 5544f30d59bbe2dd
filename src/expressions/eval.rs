//! Point and interval evaluation: one rule per node (the [`super::Tape`]'s operations, and the
//! tree walks they are tested against).

use super::Func;
#[cfg(test)]
use super::Node;
use crate::intervals::Interval;
#[cfg(test)]
use crate::rounding::pow_int;

/// `f(u)` for a one-argument function (NaN for `min`/`max`, which take two).
pub(super) fn apply1(f: Func, u: f64) -> f64 {
    let kink = |below: f64, above: f64| {
        if u > 0.0 {
            above
        } else if u < 0.0 {
            below
        } else {
            f64::NAN
        }
    };
    match f {
        Func::Sqrt => u.sqrt(),
        Func::Exp => u.exp(),
        Func::Ln => u.ln(),
        Func::Sin => u.sin(),
        Func::Cos => u.cos(),
        Func::Tanh => u.tanh(),
        Func::Atan => u.atan(),
        Func::Abs => u.abs(),
        Func::Sign => kink(-1.0, 1.0),
        Func::Step => kink(0.0, 1.0),
        Func::Delta => kink(0.0, 0.0),
        Func::Min | Func::Max | Func::Atan2 => f64::NAN,
    }
}

/// `f(u, v)` for `min`/`max`/`atan2` (NaN if either is NaN, or for other functions).
pub(super) fn apply2(f: Func, u: f64, v: f64) -> f64 {
    if u.is_nan() || v.is_nan() {
        return f64::NAN;
    }
    match f {
        Func::Min => u.min(v),
        Func::Max => u.max(v),
        Func::Atan2 => u.atan2(v),
        _ => f64::NAN,
    }
}

/// The tree walk at a point: the reference the [`super::Tape`] is tested against.
#[cfg(test)]
pub(super) fn eval(n: &Node, x: &[f64]) -> f64 {
    match n {
        Node::Const(c) => *c,
        Node::Var(i) => x.get(*i).copied().unwrap_or(f64::NAN),
        Node::Neg(u) => -eval(u, x),
        Node::Add(u, v) => eval(u, x) + eval(v, x),
        Node::Sub(u, v) => eval(u, x) - eval(v, x),
        Node::Mul(u, v) => eval(u, x) * eval(v, x),
        Node::Div(u, v) => eval(u, x) / eval(v, x),
        Node::Pow(u, k) => pow_int(eval(u, x), *k),
        Node::Call(f, args) => match args.as_slice() {
            [u] => apply1(*f, eval(u, x)),
            [u, v] => apply2(*f, eval(u, x), eval(v, x)),
            _ => f64::NAN,
        },
    }
}

/// Interval version of [`apply1`]; the kink functions enclose their generalized derivatives.
pub(super) fn apply1_interval(f: Func, u: Interval) -> Interval {
    if u.is_nan() {
        return Interval::NAN;
    }
    let kink = |below: f64, at: Interval, above: f64| {
        if u.lower > 0.0 {
            Interval::point(above)
        } else if u.upper < 0.0 {
            Interval::point(below)
        } else {
            at
        }
    };
    match f {
        Func::Sqrt => u.sqrt(),
        Func::Exp => u.exp(),
        Func::Ln => u.ln(),
        Func::Sin => u.sin(),
        Func::Cos => u.cos(),
        Func::Tanh => u.tanh(),
        Func::Atan => u.atan(),
        Func::Abs => u.abs(),
        Func::Sign => kink(-1.0, Interval::new(-1.0, 1.0), 1.0),
        Func::Step => kink(0.0, Interval::new(0.0, 1.0), 1.0),
        Func::Delta => kink(0.0, Interval::ENTIRE, 0.0),
        Func::Min | Func::Max | Func::Atan2 => Interval::NAN,
    }
}

/// Interval version of [`apply2`].
pub(super) fn apply2_interval(f: Func, u: Interval, v: Interval) -> Interval {
    match f {
        Func::Min => u.min(v),
        Func::Max => u.max(v),
        Func::Atan2 => u.atan2(v),
        _ => Interval::NAN,
    }
}

/// The tree walk over a box: the reference the [`super::Tape`] is tested against.
#[cfg(test)]
pub(super) fn eval_interval(n: &Node, x: &[Interval]) -> Interval {
    match n {
        Node::Const(c) => Interval::point(*c),
        Node::Var(i) => x.get(*i).copied().unwrap_or(Interval::NAN),
        Node::Neg(u) => -eval_interval(u, x),
        Node::Add(u, v) => eval_interval(u, x) + eval_interval(v, x),
        Node::Sub(u, v) => eval_interval(u, x) - eval_interval(v, x),
        Node::Mul(u, v) => eval_interval(u, x) * eval_interval(v, x),
        Node::Div(u, v) => eval_interval(u, x) / eval_interval(v, x),
        Node::Pow(u, k) => eval_interval(u, x).powi(*k),
        Node::Call(f, args) => match (f, args.as_slice()) {
            (_, [u, v]) => apply2_interval(*f, eval_interval(u, x), eval_interval(v, x)),
            (_, [u]) => apply1_interval(*f, eval_interval(u, x)),
            _ => Interval::NAN,
        },
    }
}

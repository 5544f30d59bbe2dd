//! Like terms collected ([`super::Expr::collected`]): a sum read as `Σ cₖ·∏ factors`, terms with
//! the same factors added, those that cancel dropped.
//!
//! Why: the closed loop `f̃ = f + g·κ` is built from the user's text, and a nominal controller
//! that cancels the drift (feedback linearisation, computed torque) leaves both copies of the
//! cancelled term in the tree. Point evaluation does not mind; interval evaluation does, since
//! each copy ranges over the box on its own: a Van der Pol oscillator's `(1 − x₁²)x₂` twice
//! took the Euler map's verified share from 93 % to 53 % (docs/design.md §2.3).
//!
//! Only what stays exact is done, so the result equals the input as a real function wherever
//! the input is defined:
//! - constants multiply into coefficients, and constants and constant divisors distribute over
//!   sums, only where the `f64` products are exact; a coefficient is `num/den`, so `p/1650` and
//!   `1/1650·p` are like terms although `1/1650` is no `f64` (ACC's drag, cancelled by its
//!   controller); sums are never multiplied out with variables (`(x + 1)²` stays: expanded,
//!   its interval evaluation would be looser);
//! - coefficients of like terms add only where the sum is exact;
//! - only terms whose factors are defined everywhere (no division by a variable, `√`, `ln`)
//!   are combined, so no point where the input is undefined (NaN) gets a value.
//!
//! Where no two terms combine, the tree is returned as it was.

use super::diff::{exact_add, exact_div, exact_mul};
use super::{Func, Node};

/// A constant coefficient `num/den`, both `f64` (the quotient need not be one).
#[derive(Clone, Copy, Debug, PartialEq)]
struct Coef {
    num: f64,
    den: f64,
}

impl Coef {
    const ONE: Coef = Coef { num: 1.0, den: 1.0 };

    /// `self·other`, where both products are exact.
    fn times(self, other: Coef) -> Option<Coef> {
        Some(Coef {
            num: exact_mul(self.num, other.num)?,
            den: exact_mul(self.den, other.den)?,
        })
    }

    fn neg(self) -> Coef {
        Coef {
            num: -self.num,
            den: self.den,
        }
    }
}

/// One term: a coefficient and its factors (sorted by their printed form).
struct Term {
    coef: Coef,
    factors: Vec<Node>,
    key: String,
}

/// `node` with like terms collected, or `None` where nothing combines.
pub(super) fn collect(node: &Node) -> Option<Node> {
    let mut terms = Vec::new();
    push_terms(node, Coef::ONE, &mut terms);
    let mut out: Vec<Term> = Vec::new();
    let mut merged = false;
    for t in terms {
        let sum = |o: &Term| {
            let like = o.key == t.key && o.coef.den == t.coef.den && total(&t.factors);
            like.then(|| exact_add(o.coef.num, t.coef.num)).flatten()
        };
        match out.iter_mut().find_map(|o| sum(o).map(|s| (o, s))) {
            Some((o, s)) => {
                o.coef.num = s;
                merged = true;
            }
            None => out.push(t),
        }
    }
    if !merged {
        return None;
    }
    out.retain(|t| t.coef.num != 0.0 || !total(&t.factors));
    Some(rebuild(out))
}

/// Appends `c·node`'s terms to `out`.
fn push_terms(node: &Node, c: Coef, out: &mut Vec<Term>) {
    match node {
        Node::Add(u, v) => {
            push_terms(u, c, out);
            push_terms(v, c, out);
        }
        Node::Sub(u, v) => {
            push_terms(u, c, out);
            push_terms(v, c.neg(), out);
        }
        Node::Neg(u) => push_terms(u, c.neg(), out),
        // A constant times (or a sum over a constant) distributes; anything else is one term.
        Node::Mul(u, v) => {
            let split = match (constant(u), constant(v)) {
                (Some(k), _) => Some((k, &**v)),
                (None, Some(k)) => Some((k, &**u)),
                (None, None) => None,
            };
            match split.and_then(|(k, other)| Some((c.times(k)?, other))) {
                Some((ck, other)) => push_terms(other, ck, out),
                None => push_product(node, c, out),
            }
        }
        Node::Div(u, v) => {
            let over = constant(v).filter(|k| k.num != 0.0).and_then(|k| {
                c.times(Coef {
                    num: k.den,
                    den: k.num,
                })
            });
            match over {
                Some(ck) => push_terms(u, ck, out),
                None => push_product(node, c, out),
            }
        }
        _ => push_product(node, c, out),
    }
}

/// Appends `c·node` as one term, its constant factors folded in where exact.
fn push_product(node: &Node, c: Coef, out: &mut Vec<Term>) {
    let mut factors = Vec::new();
    let mut coef = c;
    flatten_product(node, &mut factors);
    factors.retain(|f| match constant(f).and_then(|k| coef.times(k)) {
        Some(ck) => {
            coef = ck;
            false
        }
        None => true,
    });
    let mut keyed: Vec<(String, Node)> =
        factors.into_iter().map(|f| (format!("{f:?}"), f)).collect();
    keyed.sort_by(|a, b| a.0.cmp(&b.0));
    let key = keyed
        .iter()
        .map(|(k, _)| k.as_str())
        .collect::<Vec<_>>()
        .join("·");
    out.push(Term {
        coef,
        factors: keyed.into_iter().map(|(_, f)| f).collect(),
        key,
    });
}

fn flatten_product(node: &Node, out: &mut Vec<Node>) {
    match node {
        Node::Mul(u, v) => {
            flatten_product(u, out);
            flatten_product(v, out);
        }
        _ => out.push(node.clone()),
    }
}

/// The value of a constant subtree as `num/den` (products and quotients of constants, where
/// exact).
fn constant(node: &Node) -> Option<Coef> {
    match node {
        Node::Const(k) if k.is_finite() => Some(Coef { num: *k, den: 1.0 }),
        Node::Neg(u) => constant(u).map(Coef::neg),
        Node::Mul(u, v) => constant(u)?.times(constant(v)?),
        Node::Div(u, v) => {
            let (a, b) = (constant(u)?, constant(v)?);
            (b.num != 0.0)
                .then(|| {
                    a.times(Coef {
                        num: b.den,
                        den: b.num,
                    })
                })
                .flatten()
        }
        _ => None,
    }
}

/// Whether every factor is defined at every point (no division by a variable, root or
/// logarithm inside).
fn total(factors: &[Node]) -> bool {
    fn defined(n: &Node) -> bool {
        match n {
            Node::Const(k) => k.is_finite(),
            Node::Var(_) => true,
            Node::Div(u, v) => defined(u) && constant(v).is_some_and(|k| k.num != 0.0),
            Node::Neg(u) => defined(u),
            Node::Pow(u, k) => *k >= 0 && defined(u),
            Node::Add(u, v) | Node::Sub(u, v) | Node::Mul(u, v) => defined(u) && defined(v),
            Node::Call(f, args) => {
                !matches!(
                    f,
                    Func::Sqrt | Func::Ln | Func::Sign | Func::Step | Func::Delta
                ) && args.iter().all(defined)
            }
        }
    }
    factors.iter().all(defined)
}

/// `Σ cₖ·∏ factors` as a tree, in the order the terms first appeared (`0` for no terms).
fn rebuild(terms: Vec<Term>) -> Node {
    let boxed = |a: Node, b: Node| (Box::new(a), Box::new(b));
    let mut sum: Option<Node> = None;
    for t in terms {
        // `num/den` as one f64 where the quotient is exact, else `num·∏/den`.
        let (num, den) = match exact_div(t.coef.num, t.coef.den) {
            Some(q) => (q, 1.0),
            None => (t.coef.num, t.coef.den),
        };
        let product = t.factors.into_iter().reduce(|a, b| {
            let (a, b) = boxed(a, b);
            Node::Mul(a, b)
        });
        let scaled = match (product, num.abs() == 1.0) {
            (Some(p), true) => p,
            (Some(p), false) => Node::Mul(Box::new(Node::Const(num.abs())), Box::new(p)),
            (None, _) => Node::Const(num.abs()),
        };
        let body = match den == 1.0 {
            true => scaled,
            false => Node::Div(Box::new(scaled), Box::new(Node::Const(den))),
        };
        sum = Some(match (sum, num.is_sign_negative()) {
            (None, false) => body,
            (None, true) => Node::Neg(Box::new(body)),
            (Some(s), false) => Node::Add(Box::new(s), Box::new(body)),
            (Some(s), true) => Node::Sub(Box::new(s), Box::new(body)),
        });
    }
    sum.unwrap_or(Node::Const(0.0))
}

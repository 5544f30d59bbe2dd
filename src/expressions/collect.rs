//! Like terms collected ([`super::Expr::collected`]): a sum read as `Σ cₖ·∏ factors`, terms with
//! the same factors added, those that cancel dropped.
//!
//! Why: the closed loop `f̃ = f + g·κ` is built from the user's text, and a nominal controller
//! that cancels the drift (feedback linearisation, computed torque) leaves both copies of the
//! cancelled term in the tree. Point evaluation does not mind; interval evaluation does, since
//! each copy ranges over the box on its own: a Van der Pol oscillator's `(1 − x₁²)x₂` twice
//! held the Euler map's verified share at 53 % where the collected `f̃` gives 90 % (docs/design.md
//! §2.3).
//!
//! Only what stays exact is done, so the result equals the input as a real function wherever
//! the input is defined:
//! - a coefficient is an exact part (small integers, powers of two, signs) times a product of
//!   the scenario's other constants over another, kept as symbols: `1/(m·l²)·(m·l²·…)` cancels to `1`
//!   whatever `m` and `l` are (a computed-torque pendulum), `p/1650` and `1/1650·p` are like
//!   terms (ACC's drag), and no product of constants is ever rounded; constants and constant
//!   divisors distribute over sums, but sums are never multiplied out with variables
//!   (`(x + 1)²` stays: expanded, its interval evaluation would be looser);
//! - like terms (the same factors and the same symbols) add their exact parts, where exact;
//! - only terms whose factors are defined everywhere (no division by a variable, `√`, `ln`)
//!   are combined, so no point where the input is undefined (NaN) gets a value.
//!
//! Where no two terms combine and none is exactly 0, the tree is returned as it was unless the
//! rebuilt sum is smaller: unit factors (`1·κ`, a parameter set to 1) and negated factors
//! (`-x·y + …` as `… - x·y`) go, both exact in interval arithmetic too.

use super::diff::{exact_add, exact_div, exact_mul};
use super::{Func, Node};

/// Integers below this are exact parts of a coefficient ([`Coef::of`]).
const SMALL: f64 = 67_108_864.0; // 2²⁶

/// A constant coefficient: `exact · ∏ num / ∏ den`, the constants kept as symbols (their bits,
/// sorted) so that equal ones cancel and no product of them is rounded.
#[derive(Clone, Debug, PartialEq)]
struct Coef {
    /// A small integer, a power of two, a sign, or an exact sum or product of these.
    exact: f64,
    num: Vec<u64>,
    den: Vec<u64>,
}

impl Coef {
    fn one() -> Coef {
        Coef::of(1.0)
    }

    /// The constant `k`: exact where it is a small integer or a power of two (their products
    /// stay exact), else its sign exact and its magnitude a symbol.
    fn of(k: f64) -> Coef {
        let magnitude = k.abs();
        let plain = magnitude.fract() == 0.0 && magnitude < SMALL
            || exact_div(1.0, magnitude).is_some_and(|r| r.fract() == 0.0);
        match plain {
            true => Coef {
                exact: k,
                num: Vec::new(),
                den: Vec::new(),
            },
            false => Coef {
                exact: k.signum(),
                num: vec![magnitude.to_bits()],
                den: Vec::new(),
            },
        }
    }

    /// `self·other`, equal symbols above and below cancelled.
    fn times(&self, other: &Coef) -> Option<Coef> {
        let mut num: Vec<u64> = self.num.iter().chain(&other.num).copied().collect();
        let mut den: Vec<u64> = Vec::new();
        for &d in self.den.iter().chain(&other.den) {
            match num.iter().position(|&a| a == d) {
                Some(i) => {
                    num.swap_remove(i);
                }
                None => den.push(d),
            }
        }
        let mut exact = exact_mul(self.exact, other.exact)?;
        // A divisor the exact part holds (1650·p/1650) leaves it exactly.
        den.retain(|&d| match exact_div(exact, f64::from_bits(d)) {
            Some(q) => {
                exact = q;
                false
            }
            None => true,
        });
        if exact == 0.0 {
            // 0 times any constants is 0: like every other 0 term.
            (num, den) = (Vec::new(), Vec::new());
        }
        num.sort_unstable();
        den.sort_unstable();
        Some(Coef { exact, num, den })
    }

    /// `1/self` (none for 0): an exact part with no exact inverse becomes a divisor.
    fn inverse(&self) -> Option<Coef> {
        if self.exact == 0.0 {
            return None;
        }
        let mut den = self.num.clone();
        let exact = match exact_div(1.0, self.exact) {
            Some(r) => r,
            None => {
                den.push(self.exact.abs().to_bits());
                den.sort_unstable();
                self.exact.signum()
            }
        };
        Some(Coef {
            exact,
            num: self.den.clone(),
            den,
        })
    }

    fn neg(&self) -> Coef {
        Coef {
            exact: -self.exact,
            ..self.clone()
        }
    }

    /// The symbols' part, for telling like terms.
    fn symbols(&self) -> (&[u64], &[u64]) {
        (&self.num, &self.den)
    }
}

/// One term: a coefficient and its factors (in the order written; `key` sorts them).
struct Term {
    coef: Coef,
    factors: Vec<Node>,
    key: String,
}

/// `node` with like terms collected, or `None` where nothing combines.
pub(super) fn collect(node: &Node) -> Option<Node> {
    let mut terms = Vec::new();
    push_terms(node, &Coef::one(), &mut terms);
    let mut out: Vec<Term> = Vec::new();
    let mut merged = false;
    for t in terms {
        let sum = |o: &Term| {
            let like = o.key == t.key && o.coef.symbols() == t.coef.symbols() && total(&t.factors);
            like.then(|| exact_add(o.coef.exact, t.coef.exact))
                .flatten()
        };
        match out.iter_mut().find_map(|o| sum(o).map(|s| (o, s))) {
            Some((o, s)) => {
                o.coef.exact = s;
                merged = true;
            }
            None => out.push(t),
        }
    }
    // Terms that are exactly 0 (`0·κ₂` of a `g` with a zero entry) go too, with the tree.
    let zero = |t: &Term| t.coef.exact == 0.0 && total(&t.factors);
    let dropped = out.iter().any(zero);
    out.retain(|t| !zero(t));
    let rebuilt = rebuild(out);
    (merged || dropped || rebuilt.size() < node.size()).then_some(rebuilt)
}

/// Appends `c·node`'s terms to `out`.
fn push_terms(node: &Node, c: &Coef, out: &mut Vec<Term>) {
    match node {
        Node::Add(u, v) => {
            push_terms(u, c, out);
            push_terms(v, c, out);
        }
        Node::Sub(u, v) => {
            push_terms(u, c, out);
            push_terms(v, &c.neg(), out);
        }
        Node::Neg(u) => push_terms(u, &c.neg(), out),
        // A constant times (or a sum over a constant) distributes; anything else is one term.
        Node::Mul(u, v) => {
            let split = match (constant(u), constant(v)) {
                (Some(k), _) => Some((k, &**v)),
                (None, Some(k)) => Some((k, &**u)),
                (None, None) => None,
            };
            match split.and_then(|(k, other)| Some((c.times(&k)?, other))) {
                Some((ck, other)) => push_terms(other, &ck, out),
                None => push_product(node, c, out),
            }
        }
        Node::Div(u, v) => {
            let over = constant(v).and_then(|k| c.times(&k.inverse()?));
            match over {
                Some(ck) => push_terms(u, &ck, out),
                None => push_product(node, c, out),
            }
        }
        _ => push_product(node, c, out),
    }
}

/// Appends `c·node` as one term, its constant factors folded into the coefficient.
fn push_product(node: &Node, c: &Coef, out: &mut Vec<Term>) {
    let mut factors = Vec::new();
    let mut coef = match flatten_product(node, &mut factors) {
        true => c.neg(),
        false => c.clone(),
    };
    factors.retain(|f| match constant(f).and_then(|k| coef.times(&k)) {
        Some(ck) => {
            coef = ck;
            false
        }
        None => true,
    });
    let mut keys: Vec<String> = factors.iter().map(|f| format!("{f:?}")).collect();
    keys.sort();
    out.push(Term {
        coef,
        factors,
        key: keys.join("·"),
    });
}

/// Pushes the factors of a product, negations taken out of them (`(−x)·y = −(x·y)`, exact);
/// returns whether an odd number were.
fn flatten_product(node: &Node, out: &mut Vec<Node>) -> bool {
    match node {
        Node::Mul(u, v) => flatten_product(u, out) ^ flatten_product(v, out),
        Node::Neg(u) if !matches!(**u, Node::Const(_)) => !flatten_product(u, out),
        _ => {
            out.push(node.clone());
            false
        }
    }
}

/// A constant subtree (products, quotients and integer powers of constants) as a coefficient.
fn constant(node: &Node) -> Option<Coef> {
    match node {
        Node::Const(k) if k.is_finite() => Some(Coef::of(*k)),
        Node::Neg(u) => constant(u).map(|k| k.neg()),
        Node::Mul(u, v) => constant(u)?.times(&constant(v)?),
        Node::Div(u, v) => constant(u)?.times(&constant(v)?.inverse()?),
        Node::Pow(u, n) if n.unsigned_abs() <= 16 => {
            let base = constant(u)?;
            let base = if *n < 0 { base.inverse()? } else { base };
            (0..n.unsigned_abs()).try_fold(Coef::one(), |acc, _| acc.times(&base))
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
            Node::Div(u, v) => defined(u) && constant(v).is_some_and(|k| k.exact != 0.0),
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

/// A coefficient's magnitude as a tree: one constant where the product of its symbols is
/// exact, else their product over their product.
fn magnitude(c: &Coef) -> Option<Node> {
    let constants = |bits: &[u64]| bits.iter().map(|&b| f64::from_bits(b)).collect::<Vec<_>>();
    let (num, den) = (constants(&c.num), constants(&c.den));
    let folded = num.iter().try_fold(c.exact.abs(), |v, &a| exact_mul(v, a));
    let folded = folded.and_then(|v| den.iter().try_fold(v, |v, &d| exact_div(v, d)));
    let product = |values: &[f64], start: Option<f64>| {
        start
            .into_iter()
            .chain(values.iter().copied())
            .map(Node::Const)
            .reduce(|a, b| Node::Mul(Box::new(a), Box::new(b)))
    };
    match folded {
        Some(1.0) => None,
        Some(v) => Some(Node::Const(v)),
        None => {
            let top = product(&num, (c.exact.abs() != 1.0).then_some(c.exact.abs()))
                .unwrap_or(Node::Const(1.0));
            Some(match product(&den, None) {
                Some(bottom) => Node::Div(Box::new(top), Box::new(bottom)),
                None => top,
            })
        }
    }
}

/// `Σ cₖ·∏ factors` as a tree, in the order the terms first appeared (`0` for no terms).
fn rebuild(terms: Vec<Term>) -> Node {
    let mut sum: Option<Node> = None;
    for t in terms {
        let product = t
            .factors
            .into_iter()
            .reduce(|a, b| Node::Mul(Box::new(a), Box::new(b)));
        let body = match (magnitude(&t.coef), product) {
            (None, Some(p)) => p,
            (None, None) => Node::Const(1.0),
            (Some(k), Some(p)) => Node::Mul(Box::new(k), Box::new(p)),
            (Some(k), None) => k,
        };
        sum = Some(match (sum, t.coef.exact.is_sign_negative()) {
            (None, false) => body,
            (None, true) => Node::Neg(Box::new(body)),
            (Some(s), false) => Node::Add(Box::new(s), Box::new(body)),
            (Some(s), true) => Node::Sub(Box::new(s), Box::new(body)),
        });
    }
    sum.unwrap_or(Node::Const(0.0))
}

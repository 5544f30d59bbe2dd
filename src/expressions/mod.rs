//! Scenario expressions: parse, evaluate, differentiate and interval-evaluate.
//!
//! Scenario files give `f`, `g`, `κ` and the CBFs `hᵢ` as strings over the state names and named
//! parameters. [`parse`] turns one into an [`Expr`], a tree of [`Node`]s over variables `x₀, x₁, …`
//! (parameters and `pi` become constants). The grammar, loosest binding first:
//!
//! ```text
//! expr    := term (("+" | "-") term)*
//! term    := unary (("*" | "/") unary)*
//! unary   := ("-" | "+") unary | power          -x^2 = -(x^2)
//! power   := primary ("^" exponent)?
//! exponent:= ("-" | "+")? INTEGER ("^" exponent)?   right-associative, integers only
//! primary := NUMBER | NAME | NAME "(" expr ("," expr)* ")" | "(" expr ")"
//! ```
//!
//! A tree has three readings, one rule per node each:
//!
//! - [`Expr::eval`]: the `f64` value `e(x)`.
//! - [`Expr::eval_interval`]: the natural inclusion function `E(X) ⊇ {e(x) : x ∈ X}` with
//!   [`Interval`] arithmetic, outward rounded (docs/design.md §3). Constants denote their `f64` values
//!   (a literal is its nearest `f64`, `pi` is `f64::consts::PI`); the enclosure is sound for that
//!   meaning. Points where `e` is NaN (outside a domain) are not covered.
//! - [`Expr::derivative`]: the symbolic `∂e/∂xⱼ`, simplified while it is built (constant folding,
//!   `u·0 = 0`, `u·1 = u`, `u + 0 = u`, `0/u = 0`, `−(−u) = u`, `c₁·(c₂·u) = (c₁c₂)·u`, …).
//!   Constants fold only when the `f64` result is exact, so folding never changes a value.
//!
//! Non-differentiable points are visible: `d|u| = sign(u)·u'`,
//! `d min(u, v) = step(v − u)·u' + step(u − v)·v'` (max alike), and `d sign(u) = d step(u) =
//! delta(u)·u'`, where `sign`, `step` and `delta` are [`Func`]s that evaluate to NaN exactly at the
//! kink (`u = 0`), so a gradient there is NaN and a caller can report "not differentiable". Over an
//! interval holding the kink they give sound enclosures of the generalized derivative:
//! `sign → [−1, 1]`, `step → [0, 1]`, `delta → [−∞, ∞]` (it stands for a jump's Dirac mass).
//!
//! ```
//! use cbfreach::{expressions::parse, Interval};
//! use std::collections::BTreeMap;
//! let names = vec!["x1".to_string(), "x2".to_string()];
//! let r = BTreeMap::from([("r".to_string(), 1.0)]);
//! let h = parse("(x1-2)^2 + x2^2 - r^2", &names, &r)?;
//! assert_eq!(h.eval(&[2.0, 1.0]), 0.0);
//! assert_eq!(h.derivative(0).display(&names).to_string(), "2 * (x1 - 2)");
//! let range = h.eval_interval(&[Interval::new(1.0, 3.0), Interval::new(-1.0, 1.0)]);
//! assert!(range.contains(-1.0) && range.contains(1.0));
//! # Ok::<(), cbfreach::expressions::ExprError>(())
//! ```

mod collect;
mod diff;
mod eval;
mod parse;
mod tape;
#[cfg(test)]
mod tests;

pub use parse::parse;
pub use tape::Tape;

use crate::intervals::Interval;
use std::fmt;
use std::sync::OnceLock;

/// A parsed expression over variables `x₀ … x_{n−1}`: a [`Node`] tree whose calls always have
/// their function's arity, and its [`Tape`] (compiled at the first evaluation).
#[derive(Clone)]
pub struct Expr {
    node: Node,
    tape: OnceLock<Tape>,
}

impl PartialEq for Expr {
    fn eq(&self, other: &Expr) -> bool {
        self.node == other.node
    }
}

impl fmt::Debug for Expr {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_struct("Expr").field("node", &self.node).finish()
    }
}

/// A node of an expression tree. Printing one as code is one recursive `match`
/// (see [`Expr::display`]).
#[derive(Clone, Debug, PartialEq)]
pub enum Node {
    /// A constant.
    Const(f64),
    /// Variable `x_i`.
    Var(usize),
    /// `−u`.
    Neg(Box<Node>),
    /// `u + v`.
    Add(Box<Node>, Box<Node>),
    /// `u − v`.
    Sub(Box<Node>, Box<Node>),
    /// `u · v`.
    Mul(Box<Node>, Box<Node>),
    /// `u / v`.
    Div(Box<Node>, Box<Node>),
    /// `u^n`, integer `n` ([`crate::rounding::pow_int`]; `u⁰ = 1`).
    Pow(Box<Node>, i32),
    /// `f(args…)` with `args.len() == f.arity()`.
    Call(Func, Vec<Node>),
}

impl Node {
    /// Nodes in the tree, a repeated subtree counted each time it stands.
    pub fn size(&self) -> usize {
        1 + match self {
            Node::Const(_) | Node::Var(_) => 0,
            Node::Neg(u) | Node::Pow(u, _) => u.size(),
            Node::Add(u, v) | Node::Sub(u, v) | Node::Mul(u, v) | Node::Div(u, v) => {
                u.size() + v.size()
            }
            Node::Call(_, args) => args.iter().map(Node::size).sum(),
        }
    }
}

/// Functions of the expression language.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Func {
    /// `√u`.
    Sqrt,
    /// `eᵘ`.
    Exp,
    /// Natural logarithm.
    Ln,
    /// Sine.
    Sin,
    /// Cosine.
    Cos,
    /// Hyperbolic tangent.
    Tanh,
    /// `|u|`.
    Abs,
    /// `min(u, v)`.
    Min,
    /// `max(u, v)`.
    Max,
    /// Arc tangent, in `(−π/2, π/2)`.
    Atan,
    /// `atan2(y, x)`: the angle of `(x, y)`, in `(−π, π]`; 0 at the origin (as libm).
    Atan2,
    /// Derivative of `|u|`: `±1`, NaN at `u = 0`. Made by [`Expr::derivative`].
    Sign,
    /// Derivative of `max(u, 0)`: 1 for `u > 0`, 0 for `u < 0`, NaN at 0. Made by
    /// [`Expr::derivative`].
    Step,
    /// Derivative of `sign`/`step`: 0 for `u ≠ 0`, NaN at 0; `[−∞, ∞]` over an interval holding 0.
    /// Made by [`Expr::derivative`].
    Delta,
}

impl Func {
    /// Every function, user-facing ones first.
    pub const ALL: [Func; 14] = [
        Func::Sqrt,
        Func::Exp,
        Func::Ln,
        Func::Sin,
        Func::Cos,
        Func::Tanh,
        Func::Abs,
        Func::Min,
        Func::Max,
        Func::Atan,
        Func::Atan2,
        Func::Sign,
        Func::Step,
        Func::Delta,
    ];

    /// The name in source text.
    pub fn name(self) -> &'static str {
        match self {
            Func::Sqrt => "sqrt",
            Func::Exp => "exp",
            Func::Ln => "ln",
            Func::Sin => "sin",
            Func::Cos => "cos",
            Func::Tanh => "tanh",
            Func::Abs => "abs",
            Func::Min => "min",
            Func::Max => "max",
            Func::Atan => "atan",
            Func::Atan2 => "atan2",
            Func::Sign => "sign",
            Func::Step => "step",
            Func::Delta => "delta",
        }
    }

    /// The number of arguments.
    pub fn arity(self) -> usize {
        match self {
            Func::Min | Func::Max | Func::Atan2 => 2,
            _ => 1,
        }
    }

    /// The function called `name`, if any.
    pub fn from_name(name: &str) -> Option<Func> {
        Func::ALL.into_iter().find(|f| f.name() == name)
    }
}

/// A parse error at a 1-based character column of the source string.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
#[error("column {column}: {message}")]
pub struct ExprError {
    /// 1-based character column (one past the end for "unexpected end of input").
    pub column: usize,
    /// What is wrong.
    pub message: String,
}

impl Expr {
    fn of(node: Node) -> Expr {
        Expr {
            node,
            tape: OnceLock::new(),
        }
    }

    /// The tree.
    pub fn node(&self) -> &Node {
        &self.node
    }

    fn tape(&self) -> &Tape {
        self.tape.get_or_init(|| Tape::compile([&self.node]))
    }

    /// The constant `c`.
    pub fn constant(c: f64) -> Expr {
        Expr::of(Node::Const(c))
    }

    /// The variable `x_i`.
    pub fn variable(i: usize) -> Expr {
        Expr::of(Node::Var(i))
    }

    /// `max(self, other)`.
    pub fn max(self, other: Expr) -> Expr {
        Expr::of(Node::Call(Func::Max, vec![self.node, other.node]))
    }

    /// The expression with `x_i` replaced by `with[i]` (a change of variables, e.g.
    /// `x = T⁻¹z`); `with` must cover every variable the expression uses.
    pub fn substitute(&self, with: &[Expr]) -> Expr {
        let nodes: Vec<Node> = with.iter().map(|e| e.node.clone()).collect();
        Expr::of(diff::substitute(&self.node, &nodes))
    }

    /// The expression with like terms collected (`f − f` of a cancelling controller dropped):
    /// equal as a real function wherever `self` is defined, tighter in interval arithmetic
    /// ([`collect`]); `self` unchanged where no two terms combine.
    pub fn collected(&self) -> Expr {
        collect::collect(&self.node).map_or_else(|| self.clone(), Expr::of)
    }

    /// `Some(c)` when the (simplified) tree is the constant `c`.
    pub fn as_constant(&self) -> Option<f64> {
        match self.node {
            Node::Const(c) => Some(c),
            _ => None,
        }
    }

    /// Whether the tree calls `f`.
    pub fn calls(&self, f: Func) -> bool {
        fn calls(n: &Node, f: Func) -> bool {
            match n {
                Node::Const(_) | Node::Var(_) => false,
                Node::Neg(u) | Node::Pow(u, _) => calls(u, f),
                Node::Add(u, v) | Node::Sub(u, v) | Node::Mul(u, v) | Node::Div(u, v) => {
                    calls(u, f) || calls(v, f)
                }
                Node::Call(g, args) => *g == f || args.iter().any(|a| calls(a, f)),
            }
        }
        calls(&self.node, f)
    }

    /// Whether `x_i` occurs in the tree.
    pub fn uses_variable(&self, i: usize) -> bool {
        fn uses(n: &Node, i: usize) -> bool {
            match n {
                Node::Const(_) => false,
                Node::Var(j) => *j == i,
                Node::Neg(u) | Node::Pow(u, _) => uses(u, i),
                Node::Add(u, v) | Node::Sub(u, v) | Node::Mul(u, v) | Node::Div(u, v) => {
                    uses(u, i) || uses(v, i)
                }
                Node::Call(_, args) => args.iter().any(|a| uses(a, i)),
            }
        }
        uses(&self.node, i)
    }

    /// `e(x)`, `x[i]` being `x_i`; NaN outside the domain, or for a variable missing from `x`.
    pub fn eval(&self, x: &[f64]) -> f64 {
        let mut out = [0.0];
        self.tape().eval(x, &mut out);
        out[0]
    }

    /// The natural inclusion `E(X) ⊇ {e(x) : x ∈ X}` over the box `X`, outward rounded (a variable
    /// missing from `X` gives the NaN interval).
    pub fn eval_interval(&self, x: &[Interval]) -> Interval {
        let mut out = [Interval::NAN];
        self.tape().eval_interval(x, &mut out);
        out[0]
    }

    /// The simplified symbolic derivative `∂e/∂x_var` (see the module docs for kinks).
    pub fn derivative(&self, var: usize) -> Expr {
        Expr::of(diff::derivative(&self.node, var))
    }

    /// `self^n`, simplified.
    pub fn powi(&self, n: i32) -> Expr {
        Expr::of(diff::pow(self.node.clone(), n))
    }

    /// Infix text with the given variable names (`x{i}` for an index past the list), parenthesised
    /// where needed; [`parse`] with the same names reads it back to the same values.
    pub fn display<'a>(&'a self, names: &'a [String]) -> impl fmt::Display + 'a {
        Printer {
            node: &self.node,
            names,
        }
    }
}

/// `∇e = (∂e/∂x₀, …, ∂e/∂x_{n−1})`.
pub fn gradient(e: &Expr, n: usize) -> Vec<Expr> {
    (0..n).map(|j| e.derivative(j)).collect()
}

/// The Jacobian `[i][j] = ∂eᵢ/∂xⱼ`.
pub fn jacobian(es: &[Expr], n: usize) -> Vec<Vec<Expr>> {
    es.iter().map(|e| gradient(e, n)).collect()
}

/// Arithmetic on expressions, simplified as in [`Expr::derivative`] (so `e·0` is `0` even where
/// `e` is NaN).
macro_rules! expr_ops {
    ($($tr:ident $method:ident),*) => {$(
        impl std::ops::$tr for Expr {
            type Output = Expr;
            fn $method(self, rhs: Expr) -> Expr {
                Expr::of(diff::$method(self.node, rhs.node))
            }
        }
    )*};
}
expr_ops!(Add add, Sub sub, Mul mul, Div div);

impl std::ops::Neg for Expr {
    type Output = Expr;
    fn neg(self) -> Expr {
        Expr::of(diff::neg(self.node))
    }
}

impl fmt::Display for Expr {
    /// Infix text over the names `x0, x1, …`.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{}", self.display(&[]))
    }
}

/// Prints a node with precedence-aware parentheses.
struct Printer<'a> {
    node: &'a Node,
    names: &'a [String],
}

/// Binding strength: sums 1, products 2, negation 3, powers 4, atoms 5.
fn precedence(n: &Node) -> u8 {
    match n {
        Node::Add(..) | Node::Sub(..) => 1,
        Node::Mul(..) | Node::Div(..) => 2,
        Node::Neg(_) => 3,
        Node::Const(c) if c.is_sign_negative() => 3,
        Node::Pow(..) => 4,
        Node::Const(_) | Node::Var(_) | Node::Call(..) => 5,
    }
}

impl Printer<'_> {
    /// Writes `n`, in parentheses if it binds looser than `min`. Right operands need one level
    /// more than left ones, so `a − (b − c)` keeps its parentheses and the tree its shape.
    fn write(&self, f: &mut fmt::Formatter<'_>, n: &Node, min: u8) -> fmt::Result {
        if precedence(n) < min {
            write!(f, "(")?;
            self.write(f, n, 0)?;
            return write!(f, ")");
        }
        let mut binary = |u: &Node, op: &str, v: &Node, p: u8| {
            self.write(f, u, p)?;
            write!(f, " {op} ")?;
            // `x - (-1)`, not `x - -1`: a negation right of a sum's sign reads as a typo.
            let negation = p == 1 && precedence(v) == 3;
            self.write(f, v, if negation { 4 } else { p + 1 })
        };
        match n {
            // Shortest round-trip text; integers without ".0".
            Node::Const(c) if c.fract() == 0.0 && c.abs() < 1e15 => write!(f, "{c}"),
            Node::Const(c) => write!(f, "{c:?}"),
            Node::Var(i) => match self.names.get(*i) {
                Some(name) => write!(f, "{name}"),
                None => write!(f, "x{i}"),
            },
            Node::Neg(u) => {
                write!(f, "-")?;
                self.write(f, u, 4)
            }
            Node::Add(u, v) => binary(u, "+", v, 1),
            Node::Sub(u, v) => binary(u, "-", v, 1),
            Node::Mul(u, v) => binary(u, "*", v, 2),
            Node::Div(u, v) => binary(u, "/", v, 2),
            Node::Pow(u, k) => {
                self.write(f, u, 5)?;
                write!(f, "^{k}")
            }
            Node::Call(func, args) => {
                write!(f, "{}(", func.name())?;
                for (i, a) in args.iter().enumerate() {
                    if i > 0 {
                        write!(f, ", ")?;
                    }
                    self.write(f, a, 0)?;
                }
                write!(f, ")")
            }
        }
    }
}

impl fmt::Display for Printer<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        self.write(f, self.node, 0)
    }
}

//! Expressions compiled for evaluation: a [`Tape`] lists the distinct subexpressions of one or
//! more trees once each (hash-consing), in an order where operands come first, and evaluates
//! them into slots. Each operation is the tree walk's rule for its node ([`super::eval`]) on the
//! same operands, and the functions are pure, so every value is the tree walk's, bit for bit;
//! what goes is the pointer chasing, and the repeats: a symbolic derivative repeats its
//! operands' subtrees (the product and quotient rules), and the gradients of one function
//! share most of theirs. Interval evaluation was about a sixth of a reach run's time on
//! scenario 1, nearly all of it the filter's centred forms (their gradients' trees).

use std::cell::Cell;
use std::collections::HashMap;

use super::eval::{apply1, apply1_interval, apply2, apply2_interval};
use super::{Func, Node};
use crate::intervals::Interval;
use crate::rounding::pow_int;

/// One operation; operands are earlier slots. It is also its own identity for hash-consing:
/// a constant is kept by its bits, so `0.0` and `−0.0` (or two NaNs) are told apart exactly as
/// their values are.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
enum Op {
    /// `f64::from_bits` of it.
    Const(u64),
    /// `x[i]` (NaN where `x` has no `i`).
    Var(usize),
    Neg(u32),
    Add(u32, u32),
    Sub(u32, u32),
    Mul(u32, u32),
    Div(u32, u32),
    Pow(u32, i32),
    Call1(Func, u32),
    /// `min`/`max` (any other two-argument call is NaN, as in the tree walk).
    Call2(Func, u32, u32),
}

/// Trees compiled together; [`Tape::eval_interval`] gives each tree's value.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Tape {
    ops: Vec<Op>,
    /// Each tree's slot.
    outputs: Vec<u32>,
}

/// Builds a tape, one distinct subexpression a slot.
struct Builder {
    ops: Vec<Op>,
    seen: HashMap<Op, u32>,
}

impl Builder {
    fn push(&mut self, op: Op) -> u32 {
        *self.seen.entry(op).or_insert_with(|| {
            self.ops.push(op);
            self.ops.len() as u32 - 1
        })
    }

    fn node(&mut self, n: &Node) -> u32 {
        let op = match n {
            Node::Const(c) => Op::Const(c.to_bits()),
            Node::Var(i) => Op::Var(*i),
            Node::Neg(u) => Op::Neg(self.node(u)),
            Node::Add(u, v) => Op::Add(self.node(u), self.node(v)),
            Node::Sub(u, v) => Op::Sub(self.node(u), self.node(v)),
            Node::Mul(u, v) => Op::Mul(self.node(u), self.node(v)),
            Node::Div(u, v) => Op::Div(self.node(u), self.node(v)),
            Node::Pow(u, k) => Op::Pow(self.node(u), *k),
            Node::Call(f, args) => match args.as_slice() {
                [u] => Op::Call1(*f, self.node(u)),
                [u, v] => Op::Call2(*f, self.node(u), self.node(v)),
                _ => Op::Const(f64::NAN.to_bits()),
            },
        };
        self.push(op)
    }
}

thread_local! {
    /// Slots of the evaluations in progress, kept between calls (no allocation per call).
    static SLOTS: Cell<Vec<Interval>> = const { Cell::new(Vec::new()) };
    static POINT_SLOTS: Cell<Vec<f64>> = const { Cell::new(Vec::new()) };
}

impl Tape {
    /// The tape of `trees`, their common subexpressions once.
    pub fn compile<'a>(trees: impl IntoIterator<Item = &'a Node>) -> Tape {
        let mut b = Builder {
            ops: Vec::new(),
            seen: HashMap::new(),
        };
        let outputs = trees.into_iter().map(|t| b.node(t)).collect();
        Tape {
            ops: b.ops,
            outputs,
        }
    }

    /// Each tree's natural inclusion over the box `x` into `out` (one per tree), as
    /// [`super::Expr::eval_interval`] gives it.
    pub fn eval_interval(&self, x: &[Interval], out: &mut [Interval]) {
        let mut slots = SLOTS.take();
        slots.clear();
        for op in &self.ops {
            let at = |i: u32| slots[i as usize];
            let value = match *op {
                Op::Const(c) => Interval::point(f64::from_bits(c)),
                Op::Var(i) => x.get(i).copied().unwrap_or(Interval::NAN),
                Op::Neg(u) => -at(u),
                Op::Add(u, v) => at(u) + at(v),
                Op::Sub(u, v) => at(u) - at(v),
                Op::Mul(u, v) => at(u) * at(v),
                Op::Div(u, v) => at(u) / at(v),
                Op::Pow(u, k) => at(u).powi(k),
                Op::Call1(f, u) => apply1_interval(f, at(u)),
                Op::Call2(f, u, v) => apply2_interval(f, at(u), at(v)),
            };
            slots.push(value);
        }
        for (o, &slot) in out.iter_mut().zip(&self.outputs) {
            *o = slots[slot as usize];
        }
        SLOTS.set(slots);
    }

    /// Each tree's value at the point `x` into `out`, as [`super::Expr::eval`] gives it.
    pub fn eval(&self, x: &[f64], out: &mut [f64]) {
        let mut slots = POINT_SLOTS.take();
        slots.clear();
        for op in &self.ops {
            let at = |i: u32| slots[i as usize];
            let value = match *op {
                Op::Const(c) => f64::from_bits(c),
                Op::Var(i) => x.get(i).copied().unwrap_or(f64::NAN),
                Op::Neg(u) => -at(u),
                Op::Add(u, v) => at(u) + at(v),
                Op::Sub(u, v) => at(u) - at(v),
                Op::Mul(u, v) => at(u) * at(v),
                Op::Div(u, v) => at(u) / at(v),
                Op::Pow(u, k) => pow_int(at(u), k),
                Op::Call1(f, u) => apply1(f, at(u)),
                Op::Call2(f, u, v) => apply2(f, at(u), at(v)),
            };
            slots.push(value);
        }
        for (o, &slot) in out.iter_mut().zip(&self.outputs) {
            *o = slots[slot as usize];
        }
        POINT_SLOTS.set(slots);
    }

    /// Operations on the tape (distinct subexpressions).
    pub fn ops(&self) -> usize {
        self.ops.len()
    }
}

use super::*;
use crate::intervals::Interval;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::collections::BTreeMap;

fn names(n: usize) -> Vec<String> {
    (1..=n).map(|i| format!("x{i}")).collect()
}

fn params() -> BTreeMap<String, f64> {
    BTreeMap::from([("a".to_string(), 2.5), ("k_1".to_string(), -4.0)])
}

fn p(src: &str) -> Expr {
    match parse(src, &names(3), &params()) {
        Ok(e) => e,
        Err(e) => panic!("{src}: {e}"),
    }
}

fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

#[test]
fn precedence_and_hand_values() {
    let x = [3.0, 2.0, 0.5];
    let cases: [(&str, f64); 18] = [
        ("1 + 2 * 3", 7.0),
        ("-x1^2", -9.0),
        ("-2^2", -4.0),
        ("(-2)^2", 4.0),
        ("2^3^2", 512.0),
        ("x1 - x2 - x3", 0.5),
        ("x1 / x2 / x3", 3.0),
        ("2 * -x2", -4.0),
        ("+x1 - -x2", 5.0),
        ("x2^-1", 0.5),
        ("(x1 + 1)^3", 64.0),
        (".5 + 1e-3 + 2.5E+2", 250.501),
        ("a * k_1 + pi - pi", -10.0),
        ("min(x1, x2) + max(x1, x2)", 5.0),
        (
            "sqrt(4) + exp(0) + ln(1) + sin(0) + cos(0) + tanh(0) + abs(-1)",
            5.0,
        ),
        ("x1 * x2 ^ 2 / 4", 3.0),
        ("((x1-5)^2+(x2-1)^2+1)*((x1-2)^2+x2^2-1)", 6.0 * 4.0),
        ("x1x", f64::NAN),
    ];
    for (src, want) in cases {
        if src == "x1x" {
            assert!(parse(src, &names(3), &params()).is_err());
            continue;
        }
        let got = p(src).eval(&x);
        assert!((got - want).abs() < 1e-12, "{src} = {got}, want {want}");
    }
    let cbf = p("((x1-5)^2+(x2-1)^2+1)*((x1-2)^2+x2^2-1)");
    assert_eq!(cbf.eval(&[0.0, 0.0]), 81.0);
    assert_eq!(p("2 * 3 - 1").as_constant(), Some(5.0));
    assert_eq!(p("a").as_constant(), Some(2.5));
    assert_eq!(
        p("sqrt(2)").as_constant(),
        None,
        "inexact constants are not folded"
    );
    assert!(p("x1 + x3").uses_variable(2) && !p("x1 + x3").uses_variable(1));
}

#[test]
fn every_error_class_has_a_column_and_a_reason() {
    let cases: [(&str, usize, &str); 20] = [
        ("x1 + foo", 6, "unknown symbol"),
        ("foo(x1)", 1, "unknown function"),
        ("x1(2)", 1, "not a function"),
        ("2 * min(x1)", 5, "takes 2 arguments"),
        ("sin(x1, x2)", 1, "takes 1 argument"),
        ("cos()", 1, "found 0"),
        ("x1 # x2", 4, "unexpected character"),
        ("(x1 + 1", 1, "unbalanced"),
        ("x1 + 1)", 7, "unbalanced"),
        ("max(x1, (x2)", 4, "unbalanced"),
        ("x1 x2", 4, "after a complete expression"),
        ("", 1, "empty"),
        ("   ", 1, "empty"),
        ("x1^0.5", 4, "integer literal"),
        ("x1 ^ x2", 6, "integer literal"),
        ("x1^(2)", 4, "integer literal"),
        ("x1 ^ 2 ^ -1", 10, "integer"),
        ("x1 +", 5, "end of input"),
        ("1e999", 1, "out of range"),
        ("x1 * / 2", 6, "unexpected `/`"),
    ];
    for (src, column, keyword) in cases {
        match parse(src, &names(2), &params()) {
            Ok(e) => panic!("{src:?} parsed as {e}"),
            Err(e) => {
                assert_eq!(e.column, column, "{src:?}: {e}");
                assert!(e.message.contains(keyword), "{src:?}: {e}");
                assert!(e.to_string().starts_with(&format!("column {column}: ")));
            }
        }
    }
    let e = parse("y", &names(2), &params()).unwrap_err();
    assert!(
        ["x1", "x2", "a", "k_1", "pi"]
            .iter()
            .all(|k| e.message.contains(k)),
        "{e}"
    );
    let deep = "(".repeat(1000) + "x1" + &")".repeat(1000);
    assert!(parse(&deep, &names(2), &params())
        .unwrap_err()
        .message
        .contains("deeply"));
    let nonfinite = BTreeMap::from([("b".to_string(), f64::NAN)]);
    assert!(parse("b", &names(1), &nonfinite).is_err());
}

/// Expressions over `x1, x2, x3` and points where they are smooth.
const BANK: [&str; 18] = [
    "((x1-5)^2+(x2-1)^2+1)*((x1-2)^2+x2^2-1)",
    "x1 * x2 * x3 - 3 * x1^2 * x3",
    "x1 / (x2 + x3) - x3 / x1^2",
    "(x1 + 2*x2)^5 - x3^-3",
    "sin(x1 * x2) * cos(x3 - x1)",
    "exp(-x1^2 / 2) * ln(x2 + x3)",
    "tanh(2*x1 - x2) + sqrt(x1^2 + x2^2 + x3)",
    "sqrt(ln(1 + x1 * x2)) / exp(sin(x3))",
    "-x1^2 + x2 / -x3",
    "cos(sin(cos(x1 + x2)))^2",
    "a * x1 + k_1 * x2^2 + pi",
    "x1^3 * (x2 - 1)^2 / (1 + x3^2)",
    "abs(x1 - 3) * x2 + min(x1, 2*x2) - max(x3, x1 - x2)",
    "ln(x1) - ln(1/x1)",
    "x2 - x2 + x1 * 0 + 1",
    "exp(x1) ^ 2 - exp(2 * x1)",
    "atan(x1 * x2 - 2) + atan2(x3, x1 - 1.5)",
    "atan2(x2 - x3, x1) * atan2(-x1, 1 - x2)",
];

fn random_point(rng: &mut ChaCha8Rng) -> [f64; 3] {
    std::array::from_fn(|_| rng.random_range(0.3..2.7))
}

#[test]
fn derivatives_match_central_differences() {
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let h = 1e-5;
    for src in BANK {
        let e = p(src);
        let grad = gradient(&e, 3);
        let hessian = jacobian(&grad, 3);
        for _ in 0..40 {
            let x = random_point(&mut rng);
            for j in 0..3 {
                let (mut up, mut down) = (x, x);
                up[j] += h;
                down[j] -= h;
                let fd = (e.eval(&up) - e.eval(&down)) / (2.0 * h);
                let sym = grad[j].eval(&x);
                let tol = 1e-5 * (1.0 + sym.abs() + e.eval(&x).abs());
                assert!(
                    (fd - sym).abs() <= tol,
                    "d/dx{} {src} at {x:?}: {sym} vs {fd}",
                    j + 1
                );
                for (k, row) in hessian.iter().enumerate() {
                    let fd2 = (grad[k].eval(&up) - grad[k].eval(&down)) / (2.0 * h);
                    let sym2 = row[j].eval(&x);
                    let tol2 = 1e-4 * (1.0 + sym2.abs() + grad[k].eval(&x).abs());
                    assert!((fd2 - sym2).abs() <= tol2, "second derivative of {src}");
                }
            }
        }
    }
}

#[test]
fn derivatives_are_simplified() {
    let n = names(3);
    let show = |src: &str, j: usize| p(src).derivative(j).display(&n).to_string();
    assert_eq!(show("3 * x1^2", 0), "6 * x1");
    assert_eq!(show("x1 * x2", 0), "x2");
    assert_eq!(show("x1^-1", 0), "-x1^-2");
    assert_eq!(show("sin(2 * x1)", 0), "2 * cos(2 * x1)");
    assert_eq!(show("-(-x1)", 0), "1");
    assert_eq!(p("x1 + x2").derivative(1).as_constant(), Some(1.0));
    assert_eq!(
        p("sin(x1) * exp(x3)").derivative(1).as_constant(),
        Some(0.0)
    );
    assert_eq!(
        p("x2 - x2 + x1 * 0 + 1").derivative(0).as_constant(),
        Some(0.0)
    );
    let grad = gradient(&p("x1 * x2"), 2);
    assert_eq!(grad, vec![Expr::variable(1), Expr::variable(0)]);
}

#[test]
fn kinks_give_nan_derivatives_and_sound_enclosures() {
    let abs = p("abs(x1)").derivative(0);
    assert_eq!((abs.eval(&[2.0]), abs.eval(&[-2.0])), (1.0, -1.0));
    assert!(abs.eval(&[0.0]).is_nan());
    assert_eq!(
        abs.eval_interval(&[Interval::new(-1.0, 1.0)]),
        Interval::new(-1.0, 1.0)
    );
    let min = gradient(&p("min(x1, x2)"), 2);
    assert_eq!(
        (min[0].eval(&[1.0, 2.0]), min[1].eval(&[1.0, 2.0])),
        (1.0, 0.0)
    );
    assert!(min[0].eval(&[1.5, 1.5]).is_nan() && min[1].eval(&[1.5, 1.5]).is_nan());
    assert_eq!(
        min[0].eval_interval(&[Interval::new(0.0, 2.0), Interval::point(1.0)]),
        Interval::new(0.0, 1.0)
    );
    let max = p("max(x1, 1)").derivative(0);
    assert_eq!((max.eval(&[2.0]), max.eval(&[0.0])), (1.0, 0.0));
    assert!(max.eval(&[1.0]).is_nan());
    let second = abs.derivative(0);
    assert_eq!(second.eval(&[3.0]), 0.0);
    assert!(second.eval(&[0.0]).is_nan());
    assert_eq!(
        second.eval_interval(&[Interval::new(-1.0, 1.0)]),
        Interval::ENTIRE
    );
    assert_eq!(
        second.eval_interval(&[Interval::new(1.0, 2.0)]),
        Interval::point(0.0)
    );
}

/// Operations the random generator may use.
#[derive(Clone, Copy, PartialEq)]
enum Ops {
    All,
    Ring,
}

fn random_node(rng: &mut ChaCha8Rng, vars: usize, depth: usize, ops: Ops) -> Node {
    let b = |rng: &mut ChaCha8Rng| Box::new(random_node(rng, vars, depth - 1, ops));
    if depth == 0 || rng.random_range(0..5) == 0 {
        return if rng.random_bool(0.6) {
            Node::Var(rng.random_range(0..vars))
        } else if rng.random_bool(0.5) {
            Node::Const(f64::from(rng.random_range(-3i32..=3)))
        } else {
            Node::Const(rng.random_range(-3.0..3.0))
        };
    }
    let choices = if ops == Ops::Ring { 4 } else { 8 };
    match rng.random_range(0..choices) {
        0 => Node::Neg(b(rng)),
        1 => Node::Add(b(rng), b(rng)),
        2 => Node::Sub(b(rng), b(rng)),
        3 => Node::Mul(b(rng), b(rng)),
        4 => Node::Div(b(rng), b(rng)),
        5 => Node::Pow(b(rng), [-2, -1, 2, 3, 4][rng.random_range(0..5)]),
        _ => {
            let f = Func::ALL[rng.random_range(0..Func::ALL.len())];
            Node::Call(f, (0..f.arity()).map(|_| *b(rng)).collect())
        }
    }
}

fn random_box(rng: &mut ChaCha8Rng, vars: usize) -> Vec<Interval> {
    (0..vars)
        .map(|_| {
            let c = rng.random_range(-3.0..3.0);
            let r = if rng.random_bool(0.2) {
                0.0
            } else {
                rng.random_range(0.0..1.5)
            };
            Interval::new(c - r, c + r)
        })
        .collect()
}

/// Corners and random interior points of a box.
fn box_samples(rng: &mut ChaCha8Rng, b: &[Interval]) -> Vec<Vec<f64>> {
    let corners = (0..1usize << b.len()).map(|m| {
        b.iter()
            .enumerate()
            .map(|(i, x)| if m >> i & 1 == 1 { x.upper } else { x.lower })
            .collect()
    });
    let interior: Vec<Vec<f64>> = (0..16)
        .map(|_| {
            b.iter()
                .map(|x| x.lower + rng.random::<f64>() * (x.upper - x.lower))
                .collect()
        })
        .collect();
    corners.chain(interior).collect()
}

/// Runs the soundness check of `enclose` on random trees and boxes; returns (points checked,
/// points outside their enclosure).
fn soundness(
    ops: Ops,
    seed: u64,
    enclose: impl Fn(&Node, &[Interval]) -> Interval,
) -> (usize, usize) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let (mut checked, mut missed) = (0, 0);
    for _ in 0..1500 {
        let vars = rng.random_range(2..=3);
        let node = random_node(&mut rng, vars, 5, ops);
        for _ in 0..4 {
            let b = random_box(&mut rng, vars);
            let enclosure = enclose(&node, &b);
            for x in box_samples(&mut rng, &b) {
                let v = eval::eval(&node, &x);
                if v.is_nan() {
                    continue;
                }
                checked += 1;
                if !enclosure.contains(v) {
                    missed += 1;
                }
            }
        }
    }
    (checked, missed)
}

#[test]
fn interval_evaluation_encloses_sampled_points() {
    let (checked, missed) = soundness(Ops::All, 11, on_tape);
    assert!(checked > 100_000, "only {checked} finite samples");
    assert_eq!(missed, 0, "{missed} of {checked} samples escaped");
    // Derivative trees (with sign/step/delta and quotient rules) too.
    let mut rng = ChaCha8Rng::seed_from_u64(12);
    for _ in 0..300 {
        let e = Expr::of(random_node(&mut rng, 2, 4, Ops::All)).derivative(0);
        let b = random_box(&mut rng, 2);
        let enclosure = e.eval_interval(&b);
        for x in box_samples(&mut rng, &b) {
            let v = e.eval(&x);
            assert!(
                v.is_nan() || enclosure.contains(v),
                "{e} on {b:?} misses {v} at {x:?}"
            );
        }
    }
}

#[test]
fn soundness_check_catches_a_sign_blind_product() {
    fn naive(n: &Node, x: &[Interval]) -> Interval {
        match n {
            Node::Mul(u, v) => {
                let (a, b) = (naive(u, x), naive(v, x));
                let (p, q) = (a.lower * b.lower, a.upper * b.upper);
                Interval::new(p.min(q), p.max(q))
            }
            Node::Add(u, v) => naive(u, x) + naive(v, x),
            Node::Sub(u, v) => naive(u, x) - naive(v, x),
            Node::Neg(u) => -naive(u, x),
            n => eval::eval_interval(n, x),
        }
    }
    let (checked, missed) = soundness(Ops::Ring, 13, naive);
    assert!(
        missed > checked / 100,
        "naive product missed only {missed} of {checked}"
    );
    assert_eq!(soundness(Ops::Ring, 13, on_tape).1, 0);
}

#[test]
fn display_parses_back_to_the_same_values() {
    let n = names(3);
    let mut rng = ChaCha8Rng::seed_from_u64(17);
    let mut trees: Vec<Expr> = BANK.iter().map(|s| p(s)).collect();
    trees.extend((0..300).map(|_| Expr::of(random_node(&mut rng, 3, 5, Ops::All))));
    let derivatives: Vec<Expr> = trees.iter().map(|e| e.derivative(0)).collect();
    trees.extend(derivatives);
    for e in &trees {
        let text = e.display(&n).to_string();
        let back = match parse(&text, &n, &BTreeMap::new()) {
            Ok(back) => back,
            Err(err) => panic!("{text}: {err}"),
        };
        for _ in 0..10 {
            let x: Vec<f64> = (0..3).map(|_| rng.random_range(-3.0..3.0)).collect();
            assert!(
                same(e.eval(&x), back.eval(&x)),
                "{text} reparsed differently at {x:?}"
            );
        }
    }
    assert_eq!(p("x1 - (x2 - x3)").to_string(), "x0 - (x1 - x2)");
    assert_eq!(
        p("-(x1 * x2) + (-2)^2 * x3").display(&n).to_string(),
        "-(x1 * x2) + 4 * x3"
    );
}

#[test]
fn expression_arithmetic_simplifies() {
    let x = Expr::variable(0);
    let e = x.clone() * Expr::constant(1.0) + Expr::constant(0.0) - -x.clone();
    assert_eq!(e.to_string(), "x0 + x0");
    assert_eq!((x.clone() * Expr::constant(0.0)).as_constant(), Some(0.0));
    assert_eq!(x.powi(2).derivative(0).to_string(), "2 * x0");
}

/// A tree's natural inclusion as the engines take it: from its tape.
fn on_tape(n: &Node, x: &[Interval]) -> Interval {
    let mut out = [Interval::NAN];
    Tape::compile([n]).eval_interval(x, &mut out);
    out[0]
}

/// Whether two intervals are the same bits (two NaN intervals count as the same).
fn same_bits(a: Interval, b: Interval) -> bool {
    (a.is_nan() && b.is_nan())
        || (a.lower.to_bits() == b.lower.to_bits() && a.upper.to_bits() == b.upper.to_bits())
}

/// The tape gives the tree walk's values bit for bit, at points and over boxes, for random
/// trees, their derivatives (repeated subtrees) and a tape of several trees at once (shared
/// ones), while holding fewer operations than the trees have nodes.
#[test]
fn tapes_give_the_tree_walks_bits() {
    let mut rng = ChaCha8Rng::seed_from_u64(23);
    let (mut compared, mut tree_nodes, mut tape_ops) = (0, 0, 0);
    for _ in 0..400 {
        let vars = rng.random_range(2..=3);
        let e = Expr::of(random_node(&mut rng, vars, 5, Ops::All));
        let grad = gradient(&e, vars);
        let trees: Vec<&Node> = std::iter::once(e.node())
            .chain(grad.iter().map(|g| g.node()))
            .collect();
        let tape = Tape::compile(trees.iter().copied());
        tree_nodes += trees.iter().map(|t| Node::size(t)).sum::<usize>();
        tape_ops += tape.ops();
        let mut boxed = vec![Interval::NAN; trees.len()];
        let mut pointed = vec![0.0; trees.len()];
        for _ in 0..4 {
            let b = random_box(&mut rng, vars);
            tape.eval_interval(&b, &mut boxed);
            for (k, t) in trees.iter().enumerate() {
                let walked = eval::eval_interval(t, &b);
                assert!(
                    same_bits(boxed[k], walked),
                    "{t:?} over {b:?}: {:?} against {walked:?}",
                    boxed[k]
                );
                let alone = Expr::of((*t).clone()).eval_interval(&b);
                assert!(same_bits(alone, walked), "{t:?} over {b:?}");
                compared += 1;
            }
            for x in box_samples(&mut rng, &b) {
                tape.eval(&x, &mut pointed);
                for (k, t) in trees.iter().enumerate() {
                    let walked = eval::eval(t, &x);
                    assert!(
                        pointed[k].to_bits() == walked.to_bits()
                            || (pointed[k].is_nan() && walked.is_nan()),
                        "{t:?} at {x:?}"
                    );
                }
            }
        }
    }
    assert!(compared > 4000, "{compared}");
    assert!(
        tape_ops * 2 < tree_nodes,
        "{tape_ops} operations for {tree_nodes} nodes"
    );
}

/// Like terms collected: a cancelling controller's copies drop out (with an f64 coefficient or
/// a constant divisor), the value is the same at random points wherever the input is defined,
/// and interval evaluation is never wider; what must not combine does not.
#[test]
fn like_terms_collect_exactly_and_only_where_defined() {
    let show = |e: &Expr| e.display(&names(3)).to_string();
    // Van der Pol's drift and a controller that cancels it (f̃ as the scenario builds it).
    let vdp = p("(1 - x1^2)*x2 - x1 + (1)*(-1*x1 - 2*x2 - 1*(1 - x1^2)*x2 + x1)");
    assert_eq!(show(&vdp.collected()), "-x1 - 2 * x2");
    // ACC's drag over a mass, cancelled through 1/m (no f64): the divisor is kept exactly.
    let acc =
        p("-(0.1 + 5*x1 + 0.25*x1^2)/1650 + 1/1650*(0.1 + 5*x1 + 0.25*x1^2 - 1650*0.3*(x1 - 18))");
    assert_eq!(show(&acc.collected()), "-(0.3 * x1) + 18 * 0.3");
    // A pendulum under computed torque, m = 1.3 and l = 0.7: 1/(m·l²)·m·l² is 1 in symbols,
    // although no f64 product of these constants is exact.
    let torque = p("-9.81/0.7*sin(x1) - 0.1*x2/(1.3*0.7^2) + 1/(1.3*0.7^2)*(1.3*0.7^2*(9.81/0.7*sin(x1) + 0.1*x2/(1.3*0.7^2) - 2*x1 - 3*x2))");
    assert_eq!(show(&torque.collected()), "-(2 * x1) - 3 * x2");
    // Nothing to combine: the tree as it was.
    for src in [
        "(x1 + 1)^2 - x2",
        "x1*x2 + x2*x3",
        "sqrt(x1) - sqrt(x1)",
        "x1/x2 - x1/x2",
    ] {
        assert_eq!(show(&p(src).collected()), show(&p(src)), "{src}");
    }
    // A zero entry of `g` times its input goes, and so do the unit factors with it (scenario
    // 1's f̃ as built); `0·√x` stays (undefined where `x < 0`).
    assert_eq!(show(&p("0 + 1*(-1*x1) + 0*(-5*x2)").collected()), "-x1");
    assert_eq!(
        show(&p("x2 + 0*sqrt(x1) + 0*x3").collected()),
        "x2 + 0 * sqrt(x1)"
    );
    // A negation right of a sign is parenthesised; collected, it becomes the sign.
    assert_eq!(show(&p("x1 - -1 + -x2")), "x1 - (-1) + (-x2)");
    assert_eq!(show(&p("x1 - -1 + -x2").collected()), "x1 + 1 - x2");
    // Unit factors (a gain set to 1) and negated factors go where nothing combines, the
    // factors in the order written (a harvested predator, `g = -x2`, `κ = k·(x2 − 1)`).
    assert_eq!(
        show(&p("(x2*(x1 - 1)) + (-x2)*(1*(x2 - 1))").collected()),
        "x2 * (x1 - 1) - x2 * (x2 - 1)"
    );
    // Like terms in any order of factors; 0.1 + 0.2 is not exact, so those stay apart.
    assert_eq!(show(&p("x1*x2*3 - 2*x2*x1").collected()), "x1 * x2");
    assert_eq!(
        show(&p("0.1*x1 + 0.2*x1 + x2 - x2").collected()),
        "0.1 * x1 + 0.2 * x1"
    );
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let sources = [
        "(1 - x1^2)*x2 - x1 + (1)*(-1*x1 - 2*x2 - 1*(1 - x1^2)*x2 + x1)",
        "-(0.1 + 5*x1 + 0.25*x1^2)/1650 + 1/1650*(0.1 + 5*x1 + 0.25*x1^2 - 1650*0.3*(x1 - 18))",
        "sin(x3)*x1 + 2*(x2 - sin(x3)*x1) - x2/4 + cos(x1)^2 - 3*x2",
        "-9.81/0.7*sin(x1) - 0.1*x2/(1.3*0.7^2) + 1/(1.3*0.7^2)*(1.3*0.7^2*(9.81/0.7*sin(x1) + 0.1*x2/(1.3*0.7^2) - 2*x1 - 3*x2))",
        "0.1*x1/3 - x1/3*0.1 + x2*0.7^2 + x3",
        "-(x1 - x2)/3 + (x1 - x2)/3 + x3 + sqrt(x1) - 0*sqrt(x1)",
        "(x2*(x1 - 1)) + (-x2)*(1*(x2 - 1)) - (-x1)*x3*(-(x2 + 1))",
    ];
    for src in sources {
        let (e, c) = (p(src), p(src).collected());
        assert!(show(&c).len() < show(&e).len(), "{src}: nothing collected");
        for _ in 0..200 {
            let x: Vec<f64> = (0..3).map(|_| rng.random_range(-3.0..3.0)).collect();
            let (a, b) = (e.eval(&x), c.eval(&x));
            if a.is_nan() {
                continue;
            }
            assert!(
                (a - b).abs() <= 1e-12 * (1.0 + a.abs()),
                "{src} at {x:?}: {a} vs {b}"
            );
            let lo: Vec<f64> = x.iter().map(|v| v - rng.random_range(0.0..0.5)).collect();
            let xs: Vec<Interval> = x
                .iter()
                .zip(&lo)
                .map(|(&h, &l)| Interval::new(l, h))
                .collect();
            let (wide, tight) = (e.eval_interval(&xs), c.eval_interval(&xs));
            if wide.is_nan() {
                continue;
            }
            assert!(
                tight.lower >= wide.lower - 1e-9 && tight.upper <= wide.upper + 1e-9,
                "{src}"
            );
            // The point values are rounded (the uncollected one after a cancellation).
            let tol = 1e-12 * (1.0 + a.abs());
            assert!(
                tight.lower <= a + tol && a - tol <= tight.upper,
                "{src} at {x:?}: {tight:?} ∌ {a}"
            );
        }
    }
}

/// `atan2` over boxes near its cut and around the origin: the corners' range off the cut,
/// `[−π, π]` on it, and every sampled point inside (a dense grid of each box).
#[test]
fn atan2_encloses_its_values_on_and_off_the_cut() {
    use std::f64::consts::PI;
    let yx = |y: (f64, f64), x: (f64, f64)| Interval::new(y.0, y.1).atan2(Interval::new(x.0, x.1));
    // Quadrants and boxes touching the axes but not the cut: tight.
    let second = yx((1.0, 2.0), (-2.0, -1.0));
    assert!(second.lower > PI / 2.0 && second.upper < PI, "{second:?}");
    let right = yx((-1.0, 1.0), (0.5, 2.0));
    assert!(
        right.lower > -PI / 2.0 && right.upper < PI / 2.0,
        "{right:?}"
    );
    // On the cut (y straddling 0 left of the origin) and at the origin: the whole range.
    for (y, x) in [
        ((-0.1, 0.1), (-2.0, -1.0)),
        ((0.0, 1.0), (0.0, 1.0)),
        ((-1.0, 0.0), (-1.0, 1.0)),
    ] {
        let r = yx(y, x);
        assert!(r.lower <= -PI && r.upper >= PI, "{y:?} {x:?}: {r:?}");
    }
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    for _ in 0..2000 {
        let (yc, xc) = (rng.random_range(-2.0..2.0), rng.random_range(-2.0..2.0));
        let (ry, rx) = (rng.random_range(0.0..0.7), rng.random_range(0.0..0.7));
        let (y, x) = ((yc - ry, yc + ry), (xc - rx, xc + rx));
        let r = yx(y, x);
        for i in 0..=12 {
            for j in 0..=12 {
                // Clamped: `y.0 + (y.1 − y.0)` may round past `y.1`.
                let py = (y.0 + (y.1 - y.0) * i as f64 / 12.0).min(y.1);
                let px = (x.0 + (x.1 - x.0) * j as f64 / 12.0).min(x.1);
                let v = py.atan2(px);
                assert!(r.contains(v), "atan2({py}, {px}) = {v} outside {r:?}");
            }
        }
    }
    // Parsed and evaluated as written: atan2(y, x) with y first.
    let e = p("atan2(x2, x1) + atan(x3)");
    let v = e.eval(&[-1.0, 1.0, 1.0]);
    assert!((v - (3.0 * PI / 4.0 + PI / 4.0)).abs() < 1e-15, "{v}");
}

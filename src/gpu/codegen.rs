//! Scenario expressions and problem constants emitted as WGSL (DESIGN §4): "one more visitor"
//! over [`Node`], next to [`Expr::eval`] and [`Expr::eval_interval`].
//!
//! Every expression becomes a sound f32 interval inclusion function built from the helpers of
//! `shaders/common.wgsl` (`iv_add`, `iv_mul`, …, each rounded outward by one ulp, transcendental
//! built-ins widened by the WGSL spec's accuracy). A constant `c` (an f64) becomes the f32
//! interval `[↓c, ↑c]` that contains it, so the enclosure is sound for the f64 expression the
//! CPU evaluates.

use std::fmt::Write;

use super::GpuError;
use crate::expressions::{Expr, Func, Node};
use crate::intervals::Interval;
use crate::reach::{ReachMethod, ReachProblem, ReachSettings};
use crate::scenario::Norm;

/// The largest f32 the shaders treat as a number (`HUGE` in `common.wgsl`).
const HUGE: f32 = 3.0e38;
const MIN_NORMAL: f32 = f32::MIN_POSITIVE;

/// The largest f32 `≤ x` (`−HUGE` for `x < −HUGE` or NaN); subnormals go to the next normal
/// number or zero outward, since the device may flush them.
pub fn f32_down(x: f64) -> f32 {
    if x.is_nan() || x < -(HUGE as f64) {
        return -HUGE;
    }
    if x > HUGE as f64 {
        return HUGE;
    }
    let y = x as f32;
    let y = if (y as f64) > x { next_down_f32(y) } else { y };
    if y.abs() < MIN_NORMAL {
        if y < 0.0 || x < 0.0 {
            -MIN_NORMAL
        } else {
            0.0
        }
    } else {
        y
    }
}

/// The smallest f32 `≥ x` (see [`f32_down`]).
pub fn f32_up(x: f64) -> f32 {
    -f32_down(-x)
}

fn next_down_f32(y: f32) -> f32 {
    if y == 0.0 {
        return -f32::from_bits(1);
    }
    let b = y.to_bits();
    if y > 0.0 {
        f32::from_bits(b - 1)
    } else {
        f32::from_bits(b + 1)
    }
}

/// An f32 as a WGSL literal that parses back to the same value (`1.5f`, `-2e-7f`).
pub fn literal(x: f32) -> String {
    let x = if x.is_finite() { x } else { HUGE.copysign(x) };
    let s = format!("{x:?}");
    if s.contains('.') || s.contains('e') {
        format!("{s}f")
    } else {
        format!("{s}.0f")
    }
}

/// The interval `[↓lo, ↑hi]` as a WGSL `Iv`.
fn iv_literal(lo: f64, hi: f64) -> String {
    format!("Iv({}, {})", literal(f32_down(lo)), literal(f32_up(hi)))
}

/// The WGSL interval inclusion of an expression over `x: array<Iv, N0>`.
pub fn interval_expr(e: &Expr) -> String {
    let mut out = String::new();
    emit(e.node(), &mut out);
    out
}

fn emit(node: &Node, out: &mut String) {
    let call = |name: &str, args: &[&Node], out: &mut String| {
        out.push_str(name);
        out.push('(');
        for (i, a) in args.iter().enumerate() {
            if i > 0 {
                out.push_str(", ");
            }
            emit(a, out);
        }
        out.push(')');
    };
    match node {
        Node::Const(c) => out.push_str(&iv_literal(*c, *c)),
        Node::Var(i) => {
            let _ = write!(out, "x[{i}]");
        }
        Node::Neg(u) => call("iv_neg", &[u], out),
        Node::Add(u, v) => call("iv_add", &[u, v], out),
        Node::Sub(u, v) => call("iv_sub", &[u, v], out),
        Node::Mul(u, v) => call("iv_mul", &[u, v], out),
        Node::Div(u, v) => call("iv_div", &[u, v], out),
        Node::Pow(u, k) => {
            out.push_str("iv_pow(");
            emit(u, out);
            let _ = write!(out, ", {k})");
        }
        Node::Call(f, args) => {
            let a: Vec<&Node> = args.iter().collect();
            match f {
                Func::Sin | Func::Cos => {
                    out.push_str("iv_trig(");
                    emit(a[0], out);
                    out.push_str(if *f == Func::Cos {
                        ", true)"
                    } else {
                        ", false)"
                    });
                }
                Func::Sqrt => call("iv_sqrt", &a, out),
                Func::Exp => call("iv_exp", &a, out),
                Func::Ln => call("iv_ln", &a, out),
                Func::Tanh => call("iv_tanh", &a, out),
                Func::Abs => call("iv_abs", &a, out),
                Func::Min => call("iv_min", &a, out),
                Func::Max => call("iv_max", &a, out),
                Func::Sign => call("iv_sign", &a, out),
                Func::Step => call("iv_step", &a, out),
                Func::Delta => call("iv_delta", &a, out),
            }
        }
    }
}

/// `fn name(i: u32, …, x: array<Iv, N0>) -> Iv`, a `switch` over the flattened index.
fn switch_fn(name: &str, index_args: &str, index: &str, exprs: &[&Expr]) -> String {
    let mut s =
        format!("fn {name}({index_args}, x: array<Iv, N0>) -> Iv {{\n    switch ({index}) {{\n");
    for (k, e) in exprs.iter().enumerate() {
        let _ = writeln!(s, "        case {k}u: {{ return {}; }}", interval_expr(e));
    }
    s.push_str("        default: { return iv_entire(); }\n    }\n}\n");
    s
}

fn private_f32(name: &str, values: impl Iterator<Item = f32>) -> String {
    let v: Vec<String> = values.map(literal).collect();
    format!(
        "var<private> {name}: array<f32, {}> = array<f32, {}>({});\n",
        v.len(),
        v.len(),
        v.join(", ")
    )
}

/// Everything problem-specific the kernels need: sizes, constants and the dynamics' inclusion
/// functions `ft_iv(i, x)`, `jac_iv(i, j, x)`, `g_iv(i, k, x)`.
pub fn problem_wgsl(problem: &ReachProblem, settings: &ReachSettings) -> Result<String, GpuError> {
    let d = &problem.dynamics;
    let (n, m) = (d.n, d.m);
    let every = settings.every.max(1);
    let w_max = problem
        .network
        .layers
        .iter()
        .flat_map(|l| l.weight.iter().chain(&l.bias))
        .fold(0.0_f64, |a, w| a.max(w.abs()));
    // (1 + max|W|)·2⁻¹²⁰, rounded up (common.wgsl: err_bound).
    let abs_unit = f32_up((1.0 + w_max) * 2f64.powi(-120) * (1.0 + 1e-6));
    let margin = match settings.method {
        ReachMethod::Disturbance => {
            (Interval::point(problem.m_c) + Interval::point(problem.network_slack)).upper
        }
        ReachMethod::Minkowski => problem.network_slack,
    };
    let mut s = String::new();
    let _ = writeln!(s, "const N0: u32 = {n}u;");
    let _ = writeln!(s, "const KC: u32 = {}u;", n + 1);
    let _ = writeln!(s, "const M_OUT: u32 = {m}u;");
    let _ = writeln!(s, "const ABS_UNIT: f32 = {};", literal(abs_unit));
    let _ = writeln!(s, "const STEPS: u32 = {}u;", problem.steps);
    let _ = writeln!(s, "const EVERY: u32 = {every}u;");
    let _ = writeln!(s, "const DT_LO: f32 = {};", literal(f32_down(problem.dt)));
    let _ = writeln!(s, "const DT_HI: f32 = {};", literal(f32_up(problem.dt)));
    let _ = writeln!(s, "const MARGIN: f32 = {};", literal(f32_up(margin)));
    let _ = writeln!(
        s,
        "const FIELD_SLACK: f32 = {};",
        literal(if problem.field_slack > 0.0 {
            f32_up(problem.field_slack)
        } else {
            0.0
        })
    );
    let _ = writeln!(
        s,
        "const MINKOWSKI: bool = {};",
        settings.method == ReachMethod::Minkowski
    );
    let ell_mc = (Interval::point(problem.input_gain) * Interval::point(problem.m_c)).upper;
    let _ = writeln!(s, "const ELL_MC: f32 = {};", literal(f32_up(ell_mc)));
    let norm = match problem.norm {
        Norm::Inf => 0,
        Norm::One => 1,
        Norm::Two => 2,
    };
    let _ = writeln!(s, "const NORM: u32 = {norm}u;");
    let _ = writeln!(s, "const G_CONSTANT: bool = {};", d.g_constant.is_some());
    let _ = writeln!(
        s,
        "const TRANSFORM: bool = {};",
        problem.transform.is_some()
    );
    // Region C, rounded inward: a set inside the f32 box is inside C.
    s += &private_f32("REGION_LO", problem.region.lower.iter().map(|&v| f32_up(v)));
    s += &private_f32(
        "REGION_HI",
        problem.region.upper.iter().map(|&v| f32_down(v)),
    );
    let (s_lo, s_hi): (Vec<f32>, Vec<f32>) = match &problem.transform {
        Some(t) => t.s.iter().map(|&v| (f32_down(v), f32_up(v))).unzip(),
        None => (0..n * n)
            .map(|k| {
                if k / n == k % n {
                    (1.0, 1.0)
                } else {
                    (0.0, 0.0)
                }
            })
            .unzip(),
    };
    s += &private_f32("S_LO", s_lo.into_iter());
    s += &private_f32("S_HI", s_hi.into_iter());
    let b: Vec<f64> = d.g_constant.clone().unwrap_or_else(|| vec![0.0; n * m]);
    s += &private_f32("B_LO", b.iter().map(|&v| f32_down(v)));
    s += &private_f32("B_HI", b.iter().map(|&v| f32_up(v)));
    let signs: Vec<String> = b
        .iter()
        .map(|&v| {
            if v > 0.0 {
                "1"
            } else if v < 0.0 {
                "-1"
            } else {
                "0"
            }
            .to_string()
        })
        .collect();
    let _ = writeln!(
        s,
        "var<private> B_SIGN: array<i32, {}> = array<i32, {}>({});",
        n * m,
        n * m,
        signs.join(", ")
    );
    let check = |v: &[Interval], what: &str| -> Result<(), GpuError> {
        if v.len() == n * n || v.len() == n * m {
            Ok(())
        } else {
            Err(GpuError::Problem(format!("{what} has {} entries", v.len())))
        }
    };
    check(&problem.jacobian_over_region, "[Df̃](C)")?;
    check(&problem.g_over_region, "[g](C)")?;
    s += &private_f32(
        "JR_LO",
        problem
            .jacobian_over_region
            .iter()
            .map(|v| f32_down(v.lower)),
    );
    s += &private_f32(
        "JR_HI",
        problem.jacobian_over_region.iter().map(|v| f32_up(v.upper)),
    );
    s += &private_f32(
        "GR_LO",
        problem.g_over_region.iter().map(|v| f32_down(v.lower)),
    );
    s += &private_f32(
        "GR_HI",
        problem.g_over_region.iter().map(|v| f32_up(v.upper)),
    );
    if d.f_tilde.len() != n || d.f_tilde_jacobian.len() != n || d.g.len() != n {
        return Err(GpuError::Problem("dynamics have the wrong shape".into()));
    }
    let ft: Vec<&Expr> = d.f_tilde.iter().collect();
    let jac: Vec<&Expr> = d.f_tilde_jacobian.iter().flatten().collect();
    let g: Vec<&Expr> = d.g.iter().flatten().collect();
    if jac.len() != n * n || g.len() != n * m {
        return Err(GpuError::Problem("dynamics have the wrong shape".into()));
    }
    s += &switch_fn("ft_iv", "i: u32", "i", &ft);
    s += &switch_fn("jac_iv", "i: u32, j: u32", "i * N0 + j", &jac);
    s += &switch_fn("g_iv", "i: u32, k: u32", "i * M_OUT + k", &g);
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn outward_f32_contains_the_f64() {
        for x in [0.04, -0.04, 1.0, 1e-40, -1e-40, 0.1, -7.3e-12, 0.0] {
            let (lo, hi) = (f32_down(x), f32_up(x));
            assert!((lo as f64) <= x && x <= hi as f64, "{x}: [{lo}, {hi}]");
        }
        assert_eq!(f32_down(1.0), 1.0);
        assert_eq!(f32_up(0.5), 0.5);
        assert_eq!(
            f32_up(3.0e39),
            HUGE,
            "beyond HUGE is infinite to the shaders"
        );
    }

    #[test]
    fn literals_are_wgsl_floats() {
        assert_eq!(literal(1.0), "1.0f");
        assert_eq!(literal(-2.5), "-2.5f");
        assert!(literal(1e30).ends_with('f'));
        assert_eq!(literal(f32::INFINITY), literal(HUGE));
    }

    #[test]
    fn expressions_become_interval_calls() {
        let names = vec!["x1".to_string(), "x2".to_string()];
        let e = crate::expressions::parse("-x1 + 2*x2^2 - sin(x1)", &names, &Default::default())
            .unwrap();
        let w = interval_expr(&e);
        assert!(w.contains("iv_pow(x[1], 2)"), "{w}");
        assert!(w.contains("iv_trig(x[0], false)"), "{w}");
        assert!(w.contains("Iv(2.0f, 2.0f)"), "{w}");
    }
}

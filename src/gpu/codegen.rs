//! Scenario expressions and problem constants emitted as WGSL (docs/design.md §4): "one more visitor"
//! over [`Node`], next to [`Expr::eval`] and [`Expr::eval_interval`].
//!
//! Every expression becomes a sound f32 interval inclusion function built from the helpers of
//! `shaders/common.wgsl` (`iv_add`, `iv_mul`, …, each rounded outward by one ulp, transcendental
//! built-ins widened by the WGSL spec's accuracy). A constant `c` (an f64) becomes the f32
//! interval `[↓c, ↑c]` that contains it (in f64 mode: `[c, c]`, flushed subnormals outward), so
//! the enclosure is sound for the f64 expression the CPU evaluates. Literals carry the type's
//! suffix (`f`, `lf`) and print the exact device value (Rust's shortest round-trip form, which
//! naga parses back correctly rounded).

use std::fmt::Write;

use super::margins::MarginMap;
use super::{GpuError, Precision};
use crate::expressions::{Expr, Func, Node};
use crate::filter::{row_expressions, FilterMethod, Smooth};
use crate::intervals::Interval;
use crate::reach::safe_set::{frame_rows, SafeHalfspace, Tightening};
use crate::reach::transform::Transform;
use crate::reach::{ExactField, ReachMethod, ReachProblem, ReachSettings, SafeSet};
use crate::scenario::Norm;

/// The largest f32 the shaders treat as a number (`HUGE` in `real_f32.wgsl`).
pub(crate) const HUGE: f32 = 3.0e38;
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

/// The largest f64 the f64 shaders treat as a number (`HUGE` in `real_f64.wgsl`).
pub(crate) const HUGE_F64: f64 = 1.0e300;

/// The largest device number `≤ x` in `precision`, as an f64 (exact).
pub fn round_down(x: f64, precision: Precision) -> f64 {
    match precision {
        Precision::F32 => f32_down(x) as f64,
        Precision::F64 => {
            if x.is_nan() || x < -HUGE_F64 {
                -HUGE_F64
            } else if x > HUGE_F64 {
                HUGE_F64
            } else if x.abs() < f64::MIN_POSITIVE && x != 0.0 {
                // The device may flush subnormals: step to zero or the smallest normal outward.
                if x < 0.0 {
                    -f64::MIN_POSITIVE
                } else {
                    0.0
                }
            } else {
                x
            }
        }
    }
}

/// The smallest device number `≥ x` in `precision` (see [`round_down`]).
pub fn round_up(x: f64, precision: Precision) -> f64 {
    -round_down(-x, precision)
}

/// `[↓h, ↑h]`: the device numbers around the f64 `h` (both `h` in f64, where it is normal). The
/// continuous step enters every f32 product as this interval, never rounded to nearest
/// (docs/design.md §7.4).
pub fn h_enclosure(h: f64, precision: Precision) -> (f64, f64) {
    (round_down(h, precision), round_up(h, precision))
}

/// A device number (exact in `precision`) as a WGSL literal of type `real`.
pub fn real_literal(x: f64, precision: Precision) -> String {
    match precision {
        Precision::F32 => literal(x as f32),
        Precision::F64 => {
            let x = if x.is_finite() {
                x
            } else {
                HUGE_F64.copysign(x)
            };
            let s = format!("{x:?}");
            if s.contains('.') || s.contains('e') {
                format!("{s}lf")
            } else {
                format!("{s}.0lf")
            }
        }
    }
}

/// The interval `[↓lo, ↑hi]` as a WGSL `Iv`.
fn iv_literal(lo: f64, hi: f64, precision: Precision) -> String {
    format!(
        "Iv({}, {})",
        real_literal(round_down(lo, precision), precision),
        real_literal(round_up(hi, precision), precision)
    )
}

/// The WGSL interval inclusion of an expression over `x: array<Iv, N0>`, as one nested call.
pub fn interval_expr(e: &Expr, precision: Precision) -> String {
    fn nested(node: &Node, precision: Precision) -> String {
        node_code(node, precision, &mut |child| nested(child, precision))
    }
    nested(e.node(), precision)
}

/// One node's WGSL call, its operands written by `operand`.
fn node_code(
    node: &Node,
    precision: Precision,
    operand: &mut dyn FnMut(&Node) -> String,
) -> String {
    let mut call = |name: &str, args: &[&Node]| {
        let args: Vec<String> = args.iter().map(|a| operand(a)).collect();
        format!("{name}({})", args.join(", "))
    };
    match node {
        Node::Const(c) => iv_literal(*c, *c, precision),
        Node::Var(i) => format!("x[{i}]"),
        Node::Neg(u) => call("iv_neg", &[u]),
        Node::Add(u, v) => call("iv_add", &[u, v]),
        Node::Sub(u, v) => call("iv_sub", &[u, v]),
        Node::Mul(u, v) => call("iv_mul", &[u, v]),
        Node::Div(u, v) => call("iv_div", &[u, v]),
        Node::Pow(u, k) => format!("iv_pow({}, {k})", operand(u)),
        Node::Call(f, args) => {
            let a: Vec<&Node> = args.iter().collect();
            match f {
                Func::Sin | Func::Cos => {
                    format!("iv_trig({}, {})", operand(a[0]), *f == Func::Cos)
                }
                Func::Sqrt => call("iv_sqrt", &a),
                Func::Exp => call("iv_exp", &a),
                Func::Ln => call("iv_ln", &a),
                Func::Tanh => call("iv_tanh", &a),
                Func::Abs => call("iv_abs", &a),
                Func::Min => call("iv_min", &a),
                Func::Max => call("iv_max", &a),
                // No device implementation (WGSL's are f32, to 4096 ulp): `problem_wgsl`
                // refuses a program that calls them, by name.
                Func::Atan => call("iv_atan", &a),
                Func::Atan2 => call("iv_atan2", &a),
                Func::Sign => call("iv_sign", &a),
                Func::Step => call("iv_step", &a),
                Func::Delta => call("iv_delta", &a),
            }
        }
    }
}

/// An expression's interval inclusion as `let` statements (appended to `lets`) and the operand
/// that holds it, every repeated subexpression computed once (`names` maps a call to its `let`).
/// Symbolic derivatives repeat their factors many times over (the derivative of scenario 1's
/// closed form `b·a/‖a‖²` is ~45 kB as nested calls), and the shader compiler inlines every
/// function where it is called: nested, lavapipe's compiler ran out of memory. The same
/// operations in the same order: the enclosure is the nested one's.
fn shared_subexpressions(
    node: &Node,
    precision: Precision,
    lets: &mut String,
    names: &mut std::collections::HashMap<String, String>,
) -> String {
    let code = node_code(node, precision, &mut |child| {
        shared_subexpressions(child, precision, lets, names)
    });
    if matches!(node, Node::Const(_) | Node::Var(_)) {
        return code;
    }
    if let Some(name) = names.get(&code) {
        return name.clone();
    }
    let name = format!("t{}", names.len());
    let _ = writeln!(lets, "            let {name} = {code};");
    names.insert(code, name.clone());
    name
}

/// `fn name(i: u32, …, x: array<Iv, N0>) -> Iv`, a `switch` over the flattened index, each case
/// with its shared subexpressions computed once.
fn switch_fn(
    name: &str,
    index_args: &str,
    index: &str,
    exprs: &[&Expr],
    precision: Precision,
) -> String {
    let mut s =
        format!("fn {name}({index_args}, x: array<Iv, N0>) -> Iv {{\n    switch ({index}) {{\n");
    for (k, e) in exprs.iter().enumerate() {
        let (mut lets, mut names) = (String::new(), Default::default());
        let result = shared_subexpressions(e.node(), precision, &mut lets, &mut names);
        let _ = write!(
            s,
            "        case {k}u: {{\n{lets}            return {result};\n        }}\n"
        );
    }
    s.push_str("        default: { return iv_entire(); }\n    }\n}\n");
    s
}

/// A private `array<real, n>` of device numbers.
pub(crate) fn private_real(
    name: &str,
    values: impl Iterator<Item = f64>,
    precision: Precision,
) -> String {
    let v: Vec<String> = values.map(|x| real_literal(x, precision)).collect();
    format!(
        "var<private> {name}: array<real, {}> = array<real, {}>({});\n",
        v.len(),
        v.len(),
        v.join(", ")
    )
}

/// The safe set's half-spaces for `clip_to_safe_set` in shaders/embed.wgsl: the z-state's
/// (`HS_Z` rows), then the x-box's (`HS_X` rows). Per row and coordinate `HS_KIND` says how the
/// coordinate is bounded: 0 not at all, 1/2 below/above by the constant `HS_CONST` (the row
/// holds no other coordinate; computed here as the CPU computes it, so both give −2 for
/// `x₂ + 2 ≥ 0`), 3/4 below/above by interval arithmetic on the device.
fn safe_set_wgsl(safe: &SafeSet, n: usize, precision: Precision) -> String {
    let down = |x: f64| round_down(x, precision);
    let up = |x: f64| round_up(x, precision);
    let rows: Vec<&SafeHalfspace> = safe.z.iter().chain(&safe.x).collect();
    let (mut kind, mut constant) = (Vec::new(), Vec::new());
    let (mut n_lo, mut n_hi, mut o_lo, mut o_hi) = (Vec::new(), Vec::new(), Vec::new(), Vec::new());
    let any = vec![0.0; n];
    for hs in &rows {
        for j in 0..n {
            let (k, c) = match hs.tightening(j, &any, &any) {
                None => (0, 0.0),
                Some(Tightening::Lower(b)) if hs.only_on(j) => (1, down(b)),
                Some(Tightening::Upper(b)) if hs.only_on(j) => (2, up(b)),
                Some(Tightening::Lower(_)) => (3, 0.0),
                Some(Tightening::Upper(_)) => (4, 0.0),
            };
            kind.push(k.to_string() + "u");
            constant.push(c);
            n_lo.push(down(hs.normal[j].lower));
            n_hi.push(up(hs.normal[j].upper));
        }
        o_lo.push(down(hs.offset.lower));
        o_hi.push(up(hs.offset.upper));
    }
    if rows.is_empty() {
        // WGSL has no empty arrays: one row that bounds nothing.
        kind = vec!["0u".to_string(); n];
        (constant, n_lo, n_hi) = (vec![0.0; n], vec![0.0; n], vec![0.0; n]);
        (o_lo, o_hi) = (vec![0.0], vec![0.0]);
    }
    let mut s = String::new();
    let _ = writeln!(s, "const HS_Z: u32 = {}u;", safe.z.len());
    let _ = writeln!(s, "const HS_X: u32 = {}u;", safe.x.len());
    let _ = writeln!(
        s,
        "var<private> HS_KIND: array<u32, {}> = array<u32, {}>({});",
        kind.len(),
        kind.len(),
        kind.join(", ")
    );
    s += &private_real("HS_CONST", constant.into_iter(), precision);
    s += &private_real("HS_N_LO", n_lo.into_iter(), precision);
    s += &private_real("HS_N_HI", n_hi.into_iter(), precision);
    s += &private_real("HS_OFF_LO", o_lo.into_iter(), precision);
    s += &private_real("HS_OFF_HI", o_hi.into_iter(), precision);
    s
}

/// The bound method as the kernels see it (src/gpu/backend.rs decides which passes run).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MethodFlags {
    /// Forward forms through every layer.
    pub forward: bool,
    /// IBP alongside, intersected with the forward bounds.
    pub ibp: bool,
    /// Hidden layers' pre-activation bounds recorded (for backward passes).
    pub record: bool,
    /// A backward pass from the output.
    pub backward: bool,
    /// The backward passes use the same-slope relaxation.
    pub same_slope: bool,
}

/// Bound boxes per box: the 2n faces with face-local bounds (`--face-local`), else the box.
pub fn faces_per_box(n: usize, settings: &ReachSettings) -> usize {
    if settings.face_local {
        2 * n
    } else {
        1
    }
}

/// How a frame's module is met with the other frame's (two frames: z and x).
#[derive(Clone, Copy, Debug)]
pub struct Meet<'a> {
    /// The other frame's transform (`None`: its coordinates are x).
    pub other: Option<&'a Transform>,
    /// Whether each slab is clipped by the other frame's set over the step
    /// (`ReachSettings::meet_slabs`, continuous time).
    pub clip_slabs: bool,
}

/// Functions the device does not evaluate (WGSL's `atan` and `atan2` are f32, to 4096 ulp).
const NOT_ON_DEVICE: [Func; 2] = [Func::Atan2, Func::Atan];

/// The first function of [`NOT_ON_DEVICE`] that the problem's dynamics or the filter's rows
/// call (the rest of the program derives from them; [`problem_wgsl`] checks what it wrote).
pub fn not_on_device(problem: &ReachProblem) -> Option<Func> {
    let d = &problem.dynamics;
    let exprs = (d.f_tilde.iter())
        .chain(d.g.iter().flatten())
        .chain(problem.pieces.slack_rows());
    let exprs: Vec<&Expr> = exprs.collect();
    NOT_ON_DEVICE
        .into_iter()
        .find(|&f| exprs.iter().any(|e| e.calls(f)))
}

/// Everything problem-specific the kernels need: sizes, constants, the local-margin map's
/// geometry (`margins`, with `--local-margin`) and the dynamics' inclusion functions
/// `ft_iv(i, x)`, `jac_iv(i, j, x)`, `g_iv(i, k, x)`, in `precision`. With `meet` the problem
/// is one of two frames met after every step (`shaders/settle.wgsl`, `shaders/cmeet.wgsl`).
/// A program that calls a function of [`NOT_ON_DEVICE`] is refused by name.
pub fn problem_wgsl(
    problem: &ReachProblem,
    settings: &ReachSettings,
    flags: MethodFlags,
    precision: Precision,
    margins: &MarginMap,
    meet: Option<Meet>,
) -> Result<String, GpuError> {
    let d = &problem.dynamics;
    let (n, m) = (d.n, d.m);
    let every = settings.every.max(1);
    let w_max = problem
        .network
        .layers
        .iter()
        .flat_map(|l| l.weight.iter().chain(&l.bias))
        .fold(0.0_f64, |a, w| a.max(w.abs()));
    let down = |x: f64| round_down(x, precision);
    let up = |x: f64| round_up(x, precision);
    let lit = |x: f64| real_literal(x, precision);
    // (1 + max|W|)·64·MIN_NORMAL, rounded up (common.wgsl: err_bound).
    let min_normal_log2 = match precision {
        Precision::F32 => -126,
        Precision::F64 => -1022,
    };
    let abs_unit = up((1.0 + w_max) * 2f64.powi(min_normal_log2 + 6) * (1.0 + 1e-6));
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
    let _ = writeln!(s, "const FLAG_W: u32 = {FLAG_W}u;");
    // The per-box record of the network's bounds (shaders/output.wgsl).
    let _ = writeln!(s, "const NB_W: u32 = {}u;", nnb_width(n, m));
    // Sections of the per-neuron vectors (shaders/relu.wgsl).
    let _ = writeln!(s, "const AUX: u32 = {AUX}u;");
    let _ = writeln!(s, "const S_IC: u32 = 0u;\nconst S_V: u32 = 1u;");
    let _ = writeln!(s, "const S_IR: u32 = 2u;\nconst S_IV: u32 = 3u;");
    for (name, v) in [
        ("FORWARD", flags.forward),
        ("IBP", flags.ibp),
        ("RECORD", flags.record),
        ("BACKWARD", flags.backward),
        ("SAME_SLOPE", flags.same_slope),
    ] {
        let _ = writeln!(s, "const {name}: bool = {v};");
    }
    let _ = writeln!(
        s,
        "const FORM_TIE: real = {};",
        lit(crate::bounds::FORM_TIE)
    );
    let _ = writeln!(s, "const ABS_UNIT: real = {};", lit(abs_unit));
    let _ = writeln!(s, "const STEPS: u32 = {}u;", problem.steps);
    let _ = writeln!(s, "const EVERY: u32 = {every}u;");
    let _ = writeln!(s, "const DT_LO: real = {};", lit(down(problem.dt)));
    let _ = writeln!(s, "const DT_HI: real = {};", lit(up(problem.dt)));
    // The continuous model's step, the CPU engine's `dt / substeps` (an f64), as an enclosure
    // in the device's numbers (a point in f64; f32's neighbours around it in f32).
    let (h_lo, h_hi) = h_enclosure(problem.dt / problem.steps_per_dt() as f64, precision);
    let _ = writeln!(s, "const H_LO: real = {};", lit(h_lo));
    let _ = writeln!(s, "const H_HI: real = {};", lit(h_hi));
    let _ = writeln!(s, "const MARGIN: real = {};", lit(up(margin)));
    // Local margins (disturbance method with an error map): M = local bound + SLACK per box.
    let local = settings.method == ReachMethod::Disturbance && problem.error_map.is_some();
    let _ = writeln!(s, "const LOCAL_MARGIN: bool = {local};");
    let _ = writeln!(s, "const SLACK: real = {};", lit(up(problem.network_slack)));
    s += &margins.wgsl(precision);
    let _ = writeln!(s, "const FACES: u32 = {}u;", faces_per_box(n, settings));
    let _ = writeln!(
        s,
        "const FIELD_SLACK: real = {};",
        lit(if problem.field_slack > 0.0 {
            up(problem.field_slack)
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
    let _ = writeln!(s, "const ELL_MC: real = {};", lit(up(ell_mc)));
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
    s += &safe_set_wgsl(problem.safe_set_for(settings.method), n, precision);
    let arr = |name: &str, v: &mut dyn Iterator<Item = f64>| private_real(name, v, precision);
    // Region C, rounded inward: a set inside the device box is inside C.
    s += &arr(
        "REGION_LO",
        &mut problem.region.lower.iter().map(|&v| up(v)),
    );
    s += &arr(
        "REGION_HI",
        &mut problem.region.upper.iter().map(|&v| down(v)),
    );
    let (s_lo, s_hi): (Vec<f64>, Vec<f64>) = match &problem.transform {
        Some(t) => t.s.iter().map(|&v| (down(v), up(v))).unzip(),
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
    s += &arr("S_LO", &mut s_lo.into_iter());
    s += &arr("S_HI", &mut s_hi.into_iter());
    // T and its ρ for the z-box around an x-box (the meet of frames: shaders/sets.wgsl).
    let (t_lo, t_hi, rho): (Vec<f64>, Vec<f64>, f64) = match &problem.transform {
        Some(t) => {
            let (lo, hi) = t.t.iter().map(|&v| (down(v), up(v))).unzip();
            (lo, hi, up(t.rho))
        }
        None => (vec![0.0; n * n], vec![0.0; n * n], 0.0),
    };
    s += &arr("T_LO", &mut t_lo.into_iter());
    s += &arr("T_HI", &mut t_hi.into_iter());
    let _ = writeln!(s, "const RHO: real = {};", lit(rho));
    let _ = writeln!(s, "const MEET: bool = {};", meet.is_some());
    // The other frame's set as half-spaces of this frame's coordinates (meet_slabs,
    // shaders/validated.wgsl `clip_by_other`): their rows, the same for every set.
    let clip = meet.is_some_and(|m| m.clip_slabs);
    let _ = writeln!(s, "const CLIP_SLABS: bool = {clip};");
    let rows = match meet {
        Some(m) => frame_rows(problem.transform.as_ref(), m.other, n),
        None => vec![Interval::point(0.0); n * n],
    };
    s += &arr("OTHER_LO", &mut rows.iter().map(|v| down(v.lower)));
    s += &arr("OTHER_HI", &mut rows.iter().map(|v| up(v.upper)));
    let b: Vec<f64> = d.g_constant.clone().unwrap_or_else(|| vec![0.0; n * m]);
    s += &arr("B_LO", &mut b.iter().map(|&v| down(v)));
    s += &arr("B_HI", &mut b.iter().map(|&v| up(v)));
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
    let jr = &problem.jacobian_over_region;
    let gr = &problem.g_over_region;
    s += &arr("JR_LO", &mut jr.iter().map(|v| down(v.lower)));
    s += &arr("JR_HI", &mut jr.iter().map(|v| up(v.upper)));
    s += &arr("GR_LO", &mut gr.iter().map(|v| down(v.lower)));
    s += &arr("GR_HI", &mut gr.iter().map(|v| up(v.upper)));
    if d.f_tilde.len() != n || d.f_tilde_jacobian.len() != n || d.g.len() != n {
        return Err(GpuError::Problem("dynamics have the wrong shape".into()));
    }
    let ft: Vec<&Expr> = d.f_tilde.iter().collect();
    let jac: Vec<&Expr> = d.f_tilde_jacobian.iter().flatten().collect();
    let g: Vec<&Expr> = d.g.iter().flatten().collect();
    if jac.len() != n * n || g.len() != n * m {
        return Err(GpuError::Problem("dynamics have the wrong shape".into()));
    }
    // v = 0 where the filter's rows are proven slack (the CPU engine's ExactField::Inactive).
    let _ = writeln!(
        s,
        "const EXACT_INACTIVE: bool = {};",
        settings.exact_field() != ExactField::Nowhere
    );
    let rows: Vec<&Expr> = problem.pieces.slack_rows().iter().collect();
    let _ = writeln!(s, "const ROWS: u32 = {}u;", rows.len());
    s += &switch_fn("row_b_iv", "k: u32", "k", &rows, precision);
    s += &switch_fn("ft_iv", "i: u32", "i", &ft, precision);
    s += &switch_fn("jac_iv", "i: u32, j: u32", "i * N0 + j", &jac, precision);
    s += &switch_fn("g_iv", "i: u32, k: u32", "i * M_OUT + k", &g, precision);
    s += &closed_form_wgsl(problem, settings, precision);
    let called = |f: &Func| s.contains(&format!("iv_{}(", f.name()));
    if let Some(f) = NOT_ON_DEVICE.iter().find(|f| called(f)) {
        return Err(GpuError::Unsupported(format!(
            "the scenario calls {}, which the device does not evaluate: run with --backend cpu",
            f.name()
        )));
    }
    Ok(s)
}

/// The filter's closed form for `shaders/filter.wgsl` (the CPU engine's
/// [`ExactField::ClosedForm`]): the natural rows `aₖ`, the mean-value forms of [`VForms`]
/// (expression and symbolic gradient each), each binding piece's field and its Jacobian in the
/// embedding's coordinates and in x, `f̃` and `g` in x, and the transform's slack per unit of
/// field. With `ENCLOSE` off the functions are emitted all the same (empty switches), so that
/// the shader compiles; nothing calls them.
fn closed_form_wgsl(
    problem: &ReachProblem,
    settings: &ReachSettings,
    precision: Precision,
) -> String {
    let pieces = &problem.pieces;
    let forms = pieces
        .forms()
        .filter(|_| settings.exact_field() == ExactField::ClosedForm);
    let s_ = pieces.scenario();
    let (n, m) = (s_.n(), s_.m());
    let rows = pieces.slack_rows().len();
    let mut s = String::new();
    let _ = writeln!(s, "const ENCLOSE: bool = {};", forms.is_some());
    // The pieces' lattice (cpu_time.rs `lattice_slab_field`): a scalar input with constant `g`.
    let lattice = settings.lattice && problem.dynamics.g_constant.is_some() && m == 1;
    let _ = writeln!(s, "const LATTICE: bool = {lattice};");
    let _ = writeln!(s, "const V_ROWS: u32 = {}u;", rows.max(1));
    let empty: [Smooth; 0] = [];
    let parts = forms.map(|f| f.parts());
    let (method, b, f, p, r) = match &parts {
        Some(v) => (v.method, v.b, v.f, v.p, v.r),
        None => (
            FilterMethod::Qp,
            &empty[..],
            &empty[..],
            &empty[..],
            &empty[..],
        ),
    };
    // 1: one row (`v = b·a/‖a‖²`), 2: a scalar input (`v = bₖ/aₖ` of the binding row).
    let kind = match method {
        FilterMethod::ClosedFormSingle if !f.is_empty() && rows == 1 => 1,
        FilterMethod::ClosedFormScalar if r.len() == rows && m == 1 => 2,
        _ => 0,
    };
    let _ = writeln!(s, "const V_KIND: u32 = {kind}u;");
    let smooth = |s: &mut String, name: &str, forms: &[&Smooth]| {
        let e: Vec<&Expr> = forms.iter().map(|f| &f.e).collect();
        let g: Vec<&Expr> = forms.iter().flat_map(|f| &f.grad).collect();
        *s += &switch_fn(name, "k: u32", "k", &e, precision);
        *s += &switch_fn(&format!("{name}_grad"), "kl: u32", "kl", &g, precision);
    };
    smooth(&mut s, "vb_iv", &b.iter().collect::<Vec<_>>());
    smooth(&mut s, "vf_iv", &f.iter().collect::<Vec<_>>());
    smooth(&mut s, "vp_iv", &p.iter().collect::<Vec<_>>());
    smooth(&mut s, "vr_iv", &r.iter().collect::<Vec<_>>());
    // The pairwise differences `rₖ − rⱼ` at `k·V_ROWS + j` (an empty slot: no form).
    let r_diff = parts.map_or(&[][..], |v| v.r_diff);
    let zero = Expr::constant(0.0);
    let missing = Smooth::new(zero.clone(), n);
    let diffs: Vec<&Smooth> = (0..rows * rows)
        .map(|kj| r_diff.get(kj).and_then(Option::as_ref).unwrap_or(&missing))
        .collect();
    smooth(&mut s, "vrd_iv", &diffs);
    let has: Vec<String> = (0..(rows * rows).max(1))
        .map(|kj| r_diff.get(kj).is_some_and(Option::is_some).to_string())
        .collect();
    let _ = writeln!(
        s,
        "var<private> VRD_HAS: array<bool, {}> = array<bool, {}>({});",
        has.len(),
        has.len(),
        has.join(", ")
    );
    // The rows' natural `aₖⱼ` at `k·M_OUT + j` (their `bₖ` are `row_b_iv`).
    let (a_rows, _) = row_expressions(s_, true);
    let a: Vec<&Expr> = a_rows.iter().flatten().collect();
    s += &switch_fn("row_a_iv", "kj: u32", "kj", &a, precision);
    // Each binding piece's field: in the embedding's coordinates with its Jacobian, and in x.
    let binding: Vec<_> = (0..if forms.is_some() { rows } else { 0 })
        .map(|k| pieces.binding_field(k))
        .collect();
    let bft: Vec<&Expr> = binding.iter().flat_map(|b| &b.dynamics.f_tilde).collect();
    let bjac: Vec<&Expr> = binding
        .iter()
        .flat_map(|b| b.dynamics.f_tilde_jacobian.iter().flatten())
        .collect();
    let bfx: Vec<&Expr> = binding.iter().flat_map(|b| b.field_x()).collect();
    s += &switch_fn("bft_iv", "ki: u32", "ki", &bft, precision);
    s += &switch_fn("bjac_iv", "kij: u32", "kij", &bjac, precision);
    s += &switch_fn("bfx_iv", "ki: u32", "ki", &bfx, precision);
    // Each piece's `G = DΦ·Φ` (at `piece·N0 + i`) and `DG` with `∂ᵢΦᵢ` after it (at
    // `piece·(N0² + N0) + q`), the inactive piece first, for the second-order Taylor rates
    // (end_rates::taylor3_rates); empty without `taylor3`.
    let taylor3 = settings.taylor3 && problem.time == crate::reach::TimeModel::Continuous;
    let _ = writeln!(s, "const TAYLOR3: bool = {taylor3};");
    let seconds: Vec<_> = match taylor3 {
        true => std::iter::once(&problem.dynamics)
            .chain(binding.iter().map(|b| &b.dynamics))
            .map(|d| d.second_order())
            .collect(),
        false => Vec::new(),
    };
    let g2: Vec<&Expr> = seconds.iter().flat_map(|o| &o.g_exprs).collect();
    let dg: Vec<&Expr> = seconds.iter().flat_map(|o| &o.g_jacobian_exprs).collect();
    s += &switch_fn("g2_iv", "pi: u32", "pi", &g2, precision);
    s += &switch_fn("dg_iv", "pq: u32", "pq", &dg, precision);
    // `f̃` and `g` in x, for the transform's slack of an enclosed field.
    let fx: Vec<&Expr> = s_.f_tilde.iter().collect();
    let gx: Vec<&Expr> = s_.g.iter().flatten().collect();
    s += &switch_fn("fx_iv", "i: u32", "i", &fx, precision);
    s += &switch_fn("gx_iv", "ij: u32", "ij", &gx, precision);
    // Transform::field_slack(f) ≤ ↑(TSLACK_UNIT · f): ρ‖T‖∞, rounded up.
    let unit = pieces.transform().map_or(0.0, |t| t.field_slack(1.0));
    let _ = writeln!(
        s,
        "const TSLACK_UNIT: real = {};",
        real_literal(round_up(unit, precision), precision)
    );
    s
}

/// Per box in the flags buffer: the network's non-finite flag, the status, the step it stopped
/// at, the steps on a proven piece of the filter (`v = 0`, or one row binding), the steps
/// with the closed form's enclosures and how this step went in this frame (where frames are
/// met: `embed.wgsl`, `stepped`); the step counter and the loop check (`embed.wgsl`,
/// `loops_ran_in_full`) follow the boxes.
pub const FLAG_W: usize = 6;

/// Words of the flags buffer for `boxes` boxes: theirs, the step counter, the loop check.
pub fn flag_words(boxes: usize) -> usize {
    FLAG_W * boxes + 2
}

/// Sections of the per-neuron vectors (IBP centre, form magnitude, IBP radius, IBP magnitude).
pub const AUX: usize = 4;

/// Reals per box in the record of the network's bounds: `C̲, C̄` (m × n each), `d̲, d̄, N̲, N̄`
/// (m each) and a non-finite flag.
pub fn nnb_width(n: usize, m: usize) -> usize {
    2 * m * n + 4 * m + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The continuous step's enclosure holds the f64 step (0.04/3 and 0.1 are not f32
    /// numbers: their nearest f32 lies on one side, the enclosure on both).
    #[test]
    fn the_step_is_enclosed_not_rounded() {
        for h in [0.04 / 3.0, 0.1, 0.05, 0.01 / 7.0, 0.125] {
            let (lo, hi) = h_enclosure(h, Precision::F32);
            assert!(lo <= h && h <= hi, "{h}: [{lo}, {hi}]");
            assert!(lo as f32 as f64 == lo && hi as f32 as f64 == hi);
            assert!(hi - lo <= 2.0 * f64::from(f32::EPSILON) * h);
            assert_eq!(h_enclosure(h, Precision::F64), (h, h));
        }
        let (lo, hi) = h_enclosure(0.1, Precision::F32);
        assert!(lo < hi, "0.1 is no f32: its enclosure is two numbers");
        assert_eq!(h_enclosure(0.125, Precision::F32), (0.125, 0.125));
    }

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
    fn f64_literals_are_exact_and_suffixed() {
        assert_eq!(real_literal(1.0, Precision::F64), "1.0lf");
        assert_eq!(real_literal(0.1, Precision::F64), "0.1lf");
        assert_eq!(real_literal(1e-300, Precision::F64), "1e-300lf");
        assert_eq!(round_down(0.1, Precision::F64), 0.1);
        assert_eq!(round_down(1e-310, Precision::F64), 0.0);
        assert_eq!(round_up(1e-310, Precision::F64), f64::MIN_POSITIVE);
        assert!(round_down(0.1, Precision::F32) < 0.1 && round_up(0.1, Precision::F32) > 0.1);
    }

    #[test]
    fn expressions_become_interval_calls() {
        let names = vec!["x1".to_string(), "x2".to_string()];
        let e = crate::expressions::parse("-x1 + 2*x2^2 - sin(x1)", &names, &Default::default())
            .unwrap();
        let w = interval_expr(&e, Precision::F32);
        assert!(w.contains("iv_pow(x[1], 2)"), "{w}");
        assert!(w.contains("iv_trig(x[0], false)"), "{w}");
        assert!(w.contains("Iv(2.0f, 2.0f)"), "{w}");
    }
}

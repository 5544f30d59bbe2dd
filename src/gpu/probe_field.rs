//! The field on a slab and the curved rates on the device, for tests against the Rust they
//! mirror (tests/gpu_matches_cpu/field.rs): `bound_on` (`shaders/field.wgsl`, the CPU's
//! `validated::bound_on` and its `form_on`) and `curved_end` (`shaders/curved.wgsl`, one end of
//! `end_rates::curved_rates` on a guessed moving box). Unlike [`super::probe`]'s primitives
//! these read the problem's generated field (`f̃`, `Df̃`, `g`, the filter's pieces), so each
//! probe compiles the problem's WGSL as the engine does.

use super::codegen::{problem_wgsl, MethodFlags};
use super::kernels::{
    COMMON, CURVED, END_RATES, F32_BITS, FIELD, FILTER, MARGINS, PARAMS, REAL_F32, REAL_F64, SETS,
    VALIDATED,
};
use super::margins::MarginMap;
use super::probe::run;
use super::{GpuContext, GpuError, Precision};
use crate::boxes::IntervalBox;
use crate::reach::{ReachProblem, ReachSettings};

/// A network's bounds over one box, as the kernels read them: `C̲x + d̲ ≤ N(x) ≤ C̄x + d̄`
/// (`C` m×n row-major) and `N̲ ≤ N ≤ N̄`.
#[derive(Clone, Debug)]
pub struct NetCase {
    /// `C̲`.
    pub a_lower: Vec<f64>,
    /// `C̄`.
    pub a_upper: Vec<f64>,
    /// `d̲`.
    pub b_lower: Vec<f64>,
    /// `d̄`.
    pub b_upper: Vec<f64>,
    /// `N̲`.
    pub lower: Vec<f64>,
    /// `N̄`.
    pub upper: Vec<f64>,
}

impl NetCase {
    /// As the CPU's field functions take them.
    pub fn as_ref(&self) -> crate::reach::embedding::NetworkBoundsRef<'_> {
        crate::reach::embedding::NetworkBoundsRef {
            a_lower: &self.a_lower,
            b_lower: &self.b_lower,
            a_upper: &self.a_upper,
            b_upper: &self.b_upper,
            lower: &self.lower,
            upper: &self.upper,
        }
    }

    fn push(&self, xs: &mut Vec<f64>) {
        for v in [
            &self.a_lower,
            &self.a_upper,
            &self.b_lower,
            &self.b_upper,
            &self.lower,
            &self.upper,
        ] {
            xs.extend(v);
        }
    }
}

/// One bound of the field on a box: `Fᵢ`'s lower end (`upper` false) or upper end over
/// `[lower, upper]` for `piece` (0: the network's system; `k + 1`: binding piece `k`'s field,
/// whose network is zero) with the network bounded by `nn` and the disturbance `margin`.
#[derive(Clone, Debug)]
pub struct BoundCase {
    /// The box (a slab: every coordinate may be an interval).
    pub set: IntervalBox,
    /// The coordinate.
    pub i: usize,
    /// The upper end (else the lower).
    pub upper: bool,
    /// The field's source, as the kernels number them.
    pub piece: u32,
    /// The network's bounds on the box.
    pub nn: NetCase,
    /// `M`, the same for every input.
    pub margin: f64,
}

/// The module a probe runs: the problem's generated WGSL, the field, the continuous step's
/// primitives, and `kernel`.
fn source(
    problem: &ReachProblem,
    settings: &ReachSettings,
    precision: Precision,
    kernel: &str,
) -> Result<String, GpuError> {
    let flags = MethodFlags {
        forward: true,
        ibp: false,
        record: false,
        backward: false,
        same_slope: false,
    };
    let margins = MarginMap::for_problem(problem, settings, precision);
    let problem_code = problem_wgsl(problem, settings, flags, precision, &margins, false)?;
    let prelude = match precision {
        Precision::F32 => REAL_F32,
        Precision::F64 => REAL_F64,
    };
    let parts = [
        prelude,
        F32_BITS,
        PARAMS,
        COMMON,
        &problem_code,
        SETS,
        FILTER,
        MARGINS,
        FIELD,
        VALIDATED,
        END_RATES,
        CURVED,
        kernel,
    ];
    Ok(parts.join("\n"))
}

/// The kernels' reader of one [`NetCase`] at `xs[at]`.
const READ_NB: &str = "
fn nb_at(at: u32) -> NetBounds {
    var b: NetBounds;
    for (var q = 0u; q < M_OUT * N0; q++) {
        b.a_lo[q] = xs[at + q];
        b.a_hi[q] = xs[at + M_OUT * N0 + q];
    }
    let o = at + 2u * M_OUT * N0;
    for (var q = 0u; q < M_OUT; q++) {
        b.d_lo[q] = xs[o + q];
        b.d_hi[q] = xs[o + M_OUT + q];
        b.n_lo[q] = xs[o + 2u * M_OUT + q];
        b.n_hi[q] = xs[o + 3u * M_OUT + q];
    }
    return b;
}

fn take(at: u32) -> array<real, N0> {
    var a: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        a[j] = xs[at + j];
    }
    return a;
}
";

/// Reals of one [`NetCase`].
fn nb_len(n: usize, m: usize) -> usize {
    2 * m * n + 4 * m
}

/// `bound_on` of `shaders/field.wgsl` on the device (f64) for each case: `[F̲ᵢ, F̄ᵢ]` of the form
/// on the case's box, of which the case's end is the bound (`validated::bound_on`'s interval).
pub fn bound_on_device(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
    cases: &[BoundCase],
) -> Result<Vec<(f64, f64)>, GpuError> {
    let (n, m) = (problem.dynamics.n, problem.dynamics.m);
    let kernel = format!(
        "
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;
{READ_NB}
// Per case lo, hi, i, side, piece, margin, then the network's bounds.
const IN: u32 = 2u * N0 + 4u + {nb}u;

@compute @workgroup_size(64)
fn bound_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let q = id.x;
    if (q >= arrayLength(&xs) / IN) {{
        return;
    }}
    let a = q * IN;
    let c = 2u * N0 + a;
    let v = bound_on(u32(xs[c]), u32(xs[c + 1u]), take(a), take(a + N0), nb_at(c + 4u), xs[c + 3u], u32(xs[c + 2u]));
    ys[2u * q] = v.lo;
    ys[2u * q + 1u] = v.hi;
}}
",
        nb = nb_len(n, m)
    );
    let source = source(problem, settings, Precision::F64, &kernel)?;
    let mut xs = Vec::with_capacity(cases.len() * (2 * n + 4 + nb_len(n, m)));
    for c in cases {
        xs.extend(&c.set.lower);
        xs.extend(&c.set.upper);
        xs.extend([
            c.i as f64,
            f64::from(u8::from(c.upper)),
            f64::from(c.piece),
            c.margin,
        ]);
        c.nn.push(&mut xs);
    }
    let ys = run(ctx, &source, "bound_test", &xs, cases.len(), 2)?;
    Ok(ys.chunks(2).map(|y| (y[0], y[1])).collect())
}

/// One guessed step's curved rates: the set, the step, the rates its guess is made from (as
/// `validated::guessed` takes them), the field's source and, per slab in the order (0, lower),
/// (0, upper), (1, lower), …, the network's bounds there.
#[derive(Clone, Debug)]
pub struct CurvedCase {
    /// The set at the step's start.
    pub set: IntervalBox,
    /// The step.
    pub h: f64,
    /// Last step's slab rates `(r̲, r̄)`.
    pub rates: (Vec<f64>, Vec<f64>),
    /// The step before's, for the trend.
    pub before: Option<(Vec<f64>, Vec<f64>)>,
    /// The field's source, as the kernels number them.
    pub piece: u32,
    /// The network's bounds on each of the 2n slabs.
    pub nn: Vec<NetCase>,
    /// `M`.
    pub margin: f64,
}

/// The curved rates of a [`CurvedCase`] on the device (f64): `None` where the device's guess is
/// refused, else `(r̲, r̄)` with `∓∞` at the ends the argument does not reach
/// (`end_rates::curved_rates` on the moving box `validated::guessed` makes).
pub type CurvedRates = Option<(Vec<f64>, Vec<f64>)>;

/// `curved_end` of `shaders/curved.wgsl` at every end of each case's guessed moving box
/// (`guessed` of `shaders/validated.wgsl`), on the device in f64.
pub fn curved_on_device(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
    cases: &[CurvedCase],
) -> Result<Vec<CurvedRates>, GpuError> {
    let (n, m) = (problem.dynamics.n, problem.dynamics.m);
    let kernel = format!(
        "
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;
{READ_NB}
// Per case lo, hi, r_lo, r_hi, b_lo, b_hi, h, before, piece, margin, then 2N0 network bounds.
const NB: u32 = {nb}u;
const IN: u32 = 6u * N0 + 4u + 2u * N0 * NB;
const OUT: u32 = 1u + 4u * N0;

@compute @workgroup_size(64)
fn curved_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let q = id.x;
    if (q >= arrayLength(&xs) / IN) {{
        return;
    }}
    let a = q * IN;
    let lo = take(a);
    let hi = take(a + N0);
    let c = a + 6u * N0;
    let h = xs[c];
    let mv = guessed(lo, hi, h, take(a + 2u * N0), take(a + 3u * N0), take(a + 4u * N0), take(a + 5u * N0), xs[c + 1u] != 0.0);
    let o = q * OUT;
    ys[o] = select(real(0.0), real(1.0), mv.ok);
    if (!mv.ok) {{
        return;
    }}
    for (var f = 0u; f < 2u * N0; f++) {{
        let e = curved_end(lo, hi, mv, h, f / 2u, f % 2u, nb_at(c + 4u + f * NB), xs[c + 3u], u32(xs[c + 2u]));
        ys[o + 1u + 2u * f] = select(real(0.0), real(1.0), e.ok);
        ys[o + 2u + 2u * f] = e.r;
    }}
}}
",
        nb = nb_len(n, m)
    );
    let source = source(problem, settings, Precision::F64, &kernel)?;
    let mut xs = Vec::new();
    for c in cases {
        if c.nn.len() != 2 * n {
            return Err(GpuError::Problem(format!(
                "{} network bounds for {} slabs",
                c.nn.len(),
                2 * n
            )));
        }
        let (bl, bu) = c
            .before
            .clone()
            .unwrap_or_else(|| (vec![0.0; n], vec![0.0; n]));
        for v in [&c.set.lower, &c.set.upper, &c.rates.0, &c.rates.1, &bl, &bu] {
            xs.extend(v);
        }
        xs.extend([
            c.h,
            f64::from(u8::from(c.before.is_some())),
            f64::from(c.piece),
            c.margin,
        ]);
        for nn in &c.nn {
            nn.push(&mut xs);
        }
    }
    let per = 1 + 4 * n;
    let ys = run(ctx, &source, "curved_test", &xs, cases.len(), per)?;
    Ok(ys
        .chunks(per)
        .map(|y| {
            (y[0] != 0.0).then(|| {
                let end = |i: usize, up: usize, none: f64| {
                    let f = 2 * i + up;
                    if y[1 + 2 * f] != 0.0 {
                        y[2 + 2 * f]
                    } else {
                        none
                    }
                };
                let lo = (0..n).map(|i| end(i, 0, f64::NEG_INFINITY)).collect();
                let hi = (0..n).map(|i| end(i, 1, f64::INFINITY)).collect();
                (lo, hi)
            })
        })
        .collect())
}

/// Compiles `shaders/field.wgsl`'s slab form and `shaders/curved.wgsl` for `problem` with the
/// f32 prelude, every function called (the probes above run f64 alone): the shader's
/// validation error where they do not compile.
pub fn field_compiles_in_f32(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
) -> Result<(), GpuError> {
    let kernel = "
@group(0) @binding(0) var<storage, read_write> ys: array<f32>;

@compute @workgroup_size(1)
fn f32_check() {
    var x: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        x[j] = ys[j];
    }
    var none: array<real, M_OUT>;
    let nb = constant_bounds(none, none);
    let m = guessed(x, x, ys[0], x, x, x, x, true);
    let b = bound_on(0u, 1u, x, x, nb, ys[1], 0u);
    let e = curved_end(x, x, m, ys[0], 0u, 0u, nb, ys[1], 0u);
    ys[0] = b.hi + select(0.0, e.r, e.ok);
}
";
    let source = source(problem, settings, Precision::F32, kernel)?;
    super::probe::compile(&ctx.device, &source, "f32_check").map(|_| ())
}

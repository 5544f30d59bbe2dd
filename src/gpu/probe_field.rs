//! The field on a slab and the curved rates on the device, for tests against the Rust they
//! mirror (tests/gpu_matches_cpu/field.rs): `bound_on` (`shaders/field.wgsl`, the CPU's
//! `validated::bound_on` and its `form_on`) and `curved_end` (`shaders/curved.wgsl`, one end of
//! `end_rates::curved_rates` on a guessed moving box), and one box-step of the continuous
//! model's common path (`shaders/slab_step.wgsl`, the CPU engine's step). Unlike [`super::probe`]'s primitives
//! these read the problem's generated field (`f̃`, `Df̃`, `g`, the filter's pieces), so each
//! probe compiles the problem's WGSL as the engine does.

use super::codegen::{problem_wgsl, MethodFlags};
use super::kernels::{
    COMMON, CURVED, END_RATES, F32_BITS, FIELD, FILTER, GUESS, MARGINS, PARAMS, REAL_F32, REAL_F64,
    SETS, SLAB_STEP, VALIDATED,
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

impl From<&crate::bounds::AffineBounds> for NetCase {
    fn from(b: &crate::bounds::AffineBounds) -> NetCase {
        NetCase {
            a_lower: b.a_lower.clone(),
            a_upper: b.a_upper.clone(),
            b_lower: b.b_lower.clone(),
            b_upper: b.b_upper.clone(),
            lower: b.lower.clone(),
            upper: b.upper.clone(),
        }
    }
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
/// primitives, and `kernel`; with `step` the box-step too (`shaders/slab_step.wgsl`, whose
/// `step_rates` reads the network's bounds through the kernel's `slab_bounds`).
fn source(
    problem: &ReachProblem,
    settings: &ReachSettings,
    (precision, step): (Precision, bool),
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
    let problem_code = problem_wgsl(problem, settings, flags, precision, &margins, None)?;
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
        if step { GUESS } else { "" },
        if step { SLAB_STEP } else { "" },
        kernel,
    ];
    Ok(parts.join("\n"))
}

/// The probes' buffers, and their readers of one [`NetCase`] and of `n` reals at `xs[at]`.
const READ_NB: &str = "
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;

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

/// Appends the network's bounds on a moving box's `2n` slabs, refusing another count.
fn push_slabs(xs: &mut Vec<f64>, nn: &[NetCase], n: usize) -> Result<(), GpuError> {
    if nn.len() != 2 * n {
        return Err(GpuError::Problem(format!(
            "{} network bounds for {} slabs",
            nn.len(),
            2 * n
        )));
    }
    nn.iter().for_each(|b| b.push(xs));
    Ok(())
}

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
    let source = source(problem, settings, (Precision::F64, false), &kernel)?;
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
    let h = iv_point(xs[c]);
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
    let source = source(problem, settings, (Precision::F64, false), &kernel)?;
    let mut xs = Vec::new();
    for c in cases {
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
        push_slabs(&mut xs, &c.nn, n)?;
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

/// One box-step of the common path as [`common_step_on_device`] takes it: the box's state in
/// one frame (its set and the rates it keeps), the step, and the network's bounds on each of the
/// moving box's 2n slabs (face-local; the same bounds over its hull on every slab otherwise)
/// with the disturbance bound.
#[derive(Clone, Debug)]
pub struct StepCase {
    /// The set at the step's start.
    pub set: IntervalBox,
    /// The step.
    pub h: f64,
    /// Last step's slab rates (`None` on a tube's first step).
    pub rates: Option<(Vec<f64>, Vec<f64>)>,
    /// The step before's (where `rates` is known).
    pub before: Option<(Vec<f64>, Vec<f64>)>,
    /// The network's bounds per slab, in the order (0, lower), (0, upper), (1, lower), …
    pub nn: Vec<NetCase>,
    /// `M`.
    pub margin: f64,
}

/// What `shaders/slab_step.wgsl` made of a [`StepCase`].
#[derive(Clone, Debug)]
pub struct StepOnDevice {
    /// `guess_step`'s `on_path`: the common path takes the step (else the rest means nothing).
    pub common: bool,
    /// The check proved the moving box (else the state is the case's, for the host).
    pub proven: bool,
    /// The set at the step's end.
    pub set: IntervalBox,
    /// The rates kept for the next guess.
    pub rates: (Vec<f64>, Vec<f64>),
    /// The step before's, kept beside them.
    pub before: (Vec<f64>, Vec<f64>),
    /// How many of those the box has.
    pub known_rates: u32,
    /// The field's rates on the slabs (clamped, widened), `(dl, du)`.
    pub field: (Vec<f64>, Vec<f64>),
    /// The second-order rates (curved, and the proven piece's Taylor), `∓1e300` where none.
    pub curved: (Vec<f64>, Vec<f64>),
    /// The filter's piece proven on the hull's x-box (0: inactive, `k + 1`: row `k` binding).
    pub piece: Option<u32>,
    /// Whether the closed form's enclosures were a source.
    pub enclosed: bool,
}

/// `guess_step`, `step_rates` (the facts on the hull's x-box, every source at every end) and
/// `finish_step` of `shaders/slab_step.wgsl` on the device (f64), for each case: as
/// `shaders/continuous.wgsl` takes a box-step, with the case's network bounds and margin.
pub fn common_step_on_device(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
    cases: &[StepCase],
) -> Result<Vec<StepOnDevice>, GpuError> {
    let (n, m) = (problem.dynamics.n, problem.dynamics.m);
    let kernel = format!(
        "
{READ_NB}
// Per case lo, hi, r_lo, r_hi, b_lo, b_hi, h, rates, margin, then 2N0 network bounds.
const NB: u32 = {nb}u;
const IN: u32 = 6u * N0 + 3u + 2u * N0 * NB;
const OUT: u32 = 5u + 10u * N0;

// The network's bounds on slab f of the case whose reals after its state start at c.
fn slab_bounds(c: u32, f: u32) -> NetBounds {{
    return nb_at(c + 3u + f * NB);
}}

fn put(at: u32, a: array<real, N0>) {{
    for (var j = 0u; j < N0; j++) {{
        ys[at + j] = a[j];
    }}
}}

@compute @workgroup_size(64)
fn step_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let q = id.x;
    if (q >= arrayLength(&xs) / IN) {{
        return;
    }}
    let a = q * IN;
    let c = a + 6u * N0;
    let h = iv_point(xs[c]);
    let st = StepState(take(a), take(a + N0), take(a + 2u * N0), take(a + 3u * N0), take(a + 4u * N0), take(a + 5u * N0), u32(xs[c + 1u]));
    let g = guess_step(st, h);
    let o = q * OUT;
    ys[o] = select(real(0.0), real(1.0), g.on_path);
    if (!g.on_path) {{
        return;
    }}
    // The facts on the hull's x-box within S, as continuous.wgsl's box_step takes them.
    var hull: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {{
        hull[j] = Iv(g.m.hull_lo[j], g.m.hull_hi[j]);
    }}
    let known = clip_to_safe_set(x_box(hull), HS_Z, HS_X);
    let piece = piece_on(known);
    let ends = select(2u * N0, 0x7fffffffu, arrayLength(&xs) == 0x7fffffffu);
    let r = step_rates(st, g.m, h, known, piece, xs[c + 2u], c, ends);
    ys[o + 3u + 10u * N0] = select(real(piece), -1.0, piece == PIECE_NONE);
    ys[o + 4u + 10u * N0] = select(real(0.0), real(1.0), r.enclosed);
    if (!r.ok) {{
        return;
    }}
    let dl = r.field.lo;
    let du = r.field.hi;
    let cl = r.second.lo;
    let cu = r.second.hi;
    let s = finish_step(st, g.m, h, dl, du, cl, cu);
    ys[o + 1u] = select(real(0.0), real(1.0), s.proven);
    ys[o + 2u] = real(s.st.rates);
    put(o + 3u, s.st.lo);
    put(o + 3u + N0, s.st.hi);
    put(o + 3u + 2u * N0, s.st.r_lo);
    put(o + 3u + 3u * N0, s.st.r_hi);
    put(o + 3u + 4u * N0, s.st.b_lo);
    put(o + 3u + 5u * N0, s.st.b_hi);
    put(o + 3u + 6u * N0, dl);
    put(o + 3u + 7u * N0, du);
    put(o + 3u + 8u * N0, cl);
    put(o + 3u + 9u * N0, cu);
}}
",
        nb = nb_len(n, m)
    );
    let source = source(problem, settings, (Precision::F64, true), &kernel)?;
    let mut xs = Vec::new();
    for c in cases {
        let zero = || (vec![0.0; n], vec![0.0; n]);
        let (rl, ru) = c.rates.clone().unwrap_or_else(zero);
        let (bl, bu) = c.before.clone().unwrap_or_else(zero);
        for v in [&c.set.lower, &c.set.upper, &rl, &ru, &bl, &bu] {
            xs.extend(v);
        }
        let known = match (&c.rates, &c.before) {
            (None, _) => 0.0,
            (Some(_), None) => 1.0,
            (Some(_), Some(_)) => 2.0,
        };
        xs.extend([c.h, known, c.margin]);
        push_slabs(&mut xs, &c.nn, n)?;
    }
    let per = 5 + 10 * n;
    let ys = run(ctx, &source, "step_test", &xs, cases.len(), per)?;
    Ok(ys
        .chunks(per)
        .map(|y| {
            let part = |k: usize| y[3 + k * n..3 + (k + 1) * n].to_vec();
            StepOnDevice {
                common: y[0] != 0.0,
                proven: y[1] != 0.0,
                known_rates: y[2] as u32,
                set: IntervalBox {
                    lower: part(0),
                    upper: part(1),
                },
                rates: (part(2), part(3)),
                before: (part(4), part(5)),
                field: (part(6), part(7)),
                curved: (part(8), part(9)),
                piece: (y[3 + 10 * n] >= 0.0).then_some(y[3 + 10 * n] as u32),
                enclosed: y[4 + 10 * n] != 0.0,
            }
        })
        .collect())
}

/// The proven piece's Taylor rates of one step as `shaders/slab_step.wgsl` takes them: the set,
/// the moving box's hull (every state of the step), the step, the piece (0: inactive, `k + 1`:
/// row `k` binding), its field over the hull and on the set's faces.
#[derive(Clone, Debug)]
pub struct TaylorCase {
    /// The set at the step's start.
    pub set: IntervalBox,
    /// The hull of the step's states.
    pub hull: IntervalBox,
    /// The step.
    pub h: f64,
    /// The piece, as the kernels number them.
    pub piece: u32,
    /// The piece's field over the hull, `(F̲, F̄)`.
    pub over: (Vec<f64>, Vec<f64>),
    /// The piece's field on the set's faces, `(d̲, d̄)`: the Euler part's rates.
    pub euler: (Vec<f64>, Vec<f64>),
}

/// What the device made of a [`TaylorCase`]: `piece_taylor2` (the first-order form,
/// `end_rates::taylor_rates`) and `piece_taylor3` (`end_rates::taylor3_rates`), each `None`
/// where it refuses. (Their meet, `piece_taylor`, is the engine's: the parity tests of whole
/// runs cover it. Calling it here as well would inline both forms twice: lavapipe then took
/// 72 s instead of 22 s to compile the state-dependent field's `DG`.)
#[derive(Clone, Debug)]
pub struct TaylorOnDevice {
    /// `piece_taylor2`.
    pub first: Option<(Vec<f64>, Vec<f64>)>,
    /// `piece_taylor3`.
    pub third: Option<(Vec<f64>, Vec<f64>)>,
}

/// `piece_taylor2` and `piece_taylor3` of `shaders/slab_step.wgsl` on the device (f64) for each
/// case. `piece_taylor3` reads the problem's generated `G` and `DG`, which `settings.taylor3`
/// (and the continuous model) must ask for.
pub fn taylor_on_device(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
    cases: &[TaylorCase],
) -> Result<Vec<TaylorOnDevice>, GpuError> {
    if !(settings.taylor3 && problem.time == crate::reach::TimeModel::Continuous) {
        return Err(GpuError::Problem(
            "piece_taylor3 needs the continuous model with taylor3".into(),
        ));
    }
    let n = problem.dynamics.n;
    let kernel = format!(
        "
{READ_NB}
// Unused: the Taylor rates read no network bounds.
fn slab_bounds(c: u32, f: u32) -> NetBounds {{
    return zero_net();
}}

// Per case lo, hi, hull_lo, hull_hi, over_lo, over_hi, euler_lo, euler_hi, h, piece.
const IN: u32 = 8u * N0 + 2u;
const OUT: u32 = 2u + 4u * N0;

fn put(at: u32, t: Taylor) {{
    for (var j = 0u; j < N0; j++) {{
        ys[at + j] = t.r.lo[j];
        ys[at + N0 + j] = t.r.hi[j];
    }}
}}

@compute @workgroup_size(64)
fn taylor_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let q = id.x;
    if (q >= arrayLength(&xs) / IN) {{
        return;
    }}
    let a = q * IN;
    var z: array<real, N0>;
    let st = StepState(take(a), take(a + N0), z, z, z, z, 0u);
    var m: Moving;
    m.hull_lo = take(a + 2u * N0);
    m.hull_hi = take(a + 3u * N0);
    m.ok = true;
    let over = EndPair(take(a + 4u * N0), take(a + 5u * N0));
    let euler = EndPair(take(a + 6u * N0), take(a + 7u * N0));
    let h = iv_point(xs[a + 8u * N0]);
    let piece = u32(xs[a + 8u * N0 + 1u]);
    let ends = select(2u * N0, 0x7fffffffu, arrayLength(&xs) == 0x7fffffffu);
    let t2 = piece_taylor2(st, m, h, piece, over, euler, ends);
    let t3 = piece_taylor3(st, m, h, piece, over, euler, ends);
    let o = q * OUT;
    ys[o] = select(real(0.0), real(1.0), t2.ok);
    ys[o + 1u] = select(real(0.0), real(1.0), t3.ok);
    put(o + 2u, t2);
    put(o + 2u + 2u * N0, t3);
}}
"
    );

    let source = source(problem, settings, (Precision::F64, true), &kernel)?;
    let mut xs = Vec::with_capacity(cases.len() * (8 * n + 2));
    for c in cases {
        for v in [&c.set.lower, &c.set.upper, &c.hull.lower, &c.hull.upper] {
            xs.extend(v);
        }
        for v in [&c.over.0, &c.over.1, &c.euler.0, &c.euler.1] {
            xs.extend(v);
        }
        xs.extend([c.h, f64::from(c.piece)]);
    }
    let per = 2 + 4 * n;
    let ys = run(ctx, &source, "taylor_test", &xs, cases.len(), per)?;
    Ok(ys
        .chunks(per)
        .map(|y| {
            let rates = |k: usize| {
                let at = 2 + 2 * k * n;
                (y[k] != 0.0).then(|| (y[at..at + n].to_vec(), y[at + n..at + 2 * n].to_vec()))
            };
            TaylorOnDevice {
                first: rates(0),
                third: rates(1),
            }
        })
        .collect())
}

/// Validates `shaders/field.wgsl`'s slab form, `shaders/curved.wgsl` and
/// `shaders/slab_step.wgsl` for `problem` with the f32 prelude, every function called (the
/// probes above run f64 alone): the shader's validation error where they are not valid WGSL
/// (`probe::validate`: naga's checks, not lavapipe's minute-long compile).
pub fn field_compiles_in_f32(
    ctx: &GpuContext,
    problem: &ReachProblem,
    settings: &ReachSettings,
) -> Result<(), GpuError> {
    let kernel = "
@group(0) @binding(0) var<storage, read_write> ys: array<f32>;

fn slab_bounds(c: u32, f: u32) -> NetBounds {
    var none: array<real, M_OUT>;
    return constant_bounds(none, none);
}

@compute @workgroup_size(1)
fn f32_check() {
    var x: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        x[j] = ys[j];
    }
    var none: array<real, M_OUT>;
    let nb = constant_bounds(none, none);
    let h = h_step();
    let m = guessed(x, x, h, x, x, x, x, true);
    let b = bound_on(0u, 1u, x, x, nb, ys[1], 0u);
    let e = curved_end(x, x, m, h, 0u, 0u, nb, ys[1], 0u);
    let st = StepState(x, x, x, x, x, x, 2u);
    let g = guess_step(st, h);
    var k: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        k[j] = Iv(x[j], x[j]);
    }
    let r = step_rates(st, g.m, h, k, piece_on(k), ys[1], 0u, select(2u * N0, 0x7fffffffu, arrayLength(&ys) == 0x7fffffffu));
    let s = finish_step(st, g.m, h, x, x, x, x);
    ys[0] = b.hi + select(0.0, e.r, e.ok) + r.field.lo[0] + r.second.hi[0] + s.st.lo[0];
}
";
    let source = source(problem, settings, (Precision::F32, true), kernel)?;
    super::probe::validate(&ctx.device, &source, "f32_check")
}

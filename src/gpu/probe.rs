//! Single WGSL primitives run on the device, for tests against the Rust they mirror
//! (tests/gpu_matches_cpu/, tests/gpu_pipelines.rs): `turn_rate` (`shaders/turn.wgsl`, the
//! CPU's `euler_turn`), the continuous step's guessed moving box (`shaders/validated.wgsl`,
//! the CPU's `validated`), a face's folded first layer (`shaders/fold.wgsl`, the CPU's
//! `bounds::FoldBound`), the GEMM kernels (tiled and flat) against each other, and the
//! runner that [`super::exp64`] shares.

use wgpu::util::DeviceExt;

use super::buffers::{device_bytes, flatten_network, from_device_bytes, uniform, Params};
use super::codegen::{h_enclosure, private_real, round_down, round_up};
use super::kernels::{
    prelude, Gemm, BOX, COMMON, END_RATES, F32_BITS, FOLD, GEMM, PARAMS, REAL_F32, REAL_F64, TURN,
    VALIDATED,
};
use super::{GpuContext, GpuError, Precision};
use crate::boxes::IntervalBox;
use crate::intervals::Interval;
use crate::reach::validated::MovingFaces;

/// `y` after one dispatch of the GEMM kernel `gemm` (dispatched as the engine does) in
/// `precision` with `p`'s shape and options (`rows`, `inner`, `cols`, `abs_w`, `trans_w`,
/// `relu_x`, `w_off`, `x_off`, `ldx`, `y_off`, `ldy`) on `net`, `x` and `y` (unwritten entries
/// stay; in f32 the inputs rounded to f32 and the result widened back).
pub fn gemm_on_device(
    ctx: &GpuContext,
    precision: Precision,
    gemm: Gemm,
    p: &Params,
    net: &[f64],
    x: &[f64],
    y: &[f64],
) -> Result<Vec<f64>, GpuError> {
    if precision == Precision::F64 && !ctx.has_f64() {
        return Err(GpuError::NoF64(ctx.info.name.clone()));
    }
    let real = prelude(precision);
    let source =
        format!("{real}\n{F32_BITS}\n{PARAMS}\n{COMMON}\nconst ABS_UNIT: real = 0.0;\n{GEMM}");
    let entry = gemm.entry();
    let device = &ctx.device;
    let pipeline = compile(device, &source, entry)?;
    let storage = |label, data: &[f64], usage| {
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: &device_bytes(data, precision),
            usage: wgpu::BufferUsages::STORAGE | usage,
        })
    };
    let params = uniform(device, "probe params", p);
    let net_b = storage("probe net", net, wgpu::BufferUsages::empty());
    let x_b = storage("probe x", x, wgpu::BufferUsages::empty());
    let y_b = storage("probe y", y, wgpu::BufferUsages::COPY_SRC);
    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(entry),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: params.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: net_b.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 2,
                resource: x_b.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 3,
                resource: y_b.as_entire_binding(),
            },
        ],
    });
    let groups = gemm.groups(p.rows, p.cols);
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
    }
    ctx.queue.submit([enc.finish()]);
    let size = y.len() as u64 * precision.bytes();
    Ok(from_device_bytes(
        &read_back_bytes(ctx, &y_b, size)?,
        precision,
    ))
}

/// `len` f64 of `buf` (a `COPY_SRC` buffer), after the queue's work.
pub fn read_back(ctx: &GpuContext, buf: &wgpu::Buffer, len: usize) -> Result<Vec<f64>, GpuError> {
    let bytes = read_back_bytes(ctx, buf, (len * 8) as u64)?;
    Ok(bytemuck::pod_collect_to_vec(&bytes))
}

/// The first `size` bytes of `buf` (a `COPY_SRC` buffer), after the queue's work.
fn read_back_bytes(ctx: &GpuContext, buf: &wgpu::Buffer, size: u64) -> Result<Vec<u8>, GpuError> {
    let device = &ctx.device;
    let staging = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("probe staging"),
        size,
        usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    });
    let mut enc = device.create_command_encoder(&Default::default());
    enc.copy_buffer_to_buffer(buf, 0, &staging, 0, size);
    ctx.queue.submit([enc.finish()]);
    let slice = staging.slice(..);
    let (tx, rx) = std::sync::mpsc::channel();
    slice.map_async(wgpu::MapMode::Read, move |r| {
        let _ = tx.send(r);
    });
    ctx.wait()?;
    rx.recv()
        .map_err(|e| GpuError::Device(e.to_string()))?
        .map_err(|e| GpuError::Device(e.to_string()))?;
    let view = slice
        .get_mapped_range()
        .map_err(|e| GpuError::Device(e.to_string()))?;
    Ok(view.to_vec())
}

/// `turn_rate(slope, w, dt)` of `shaders/turn.wgsl` on the device (f64), for each input
/// `[slope.lo, slope.hi, w, dt.lo, dt.hi]`: the rate a face of the Euler step grows by where the
/// step may turn its state around.
pub fn turn_rate_on_device(ctx: &GpuContext, inputs: &[[f64; 5]]) -> Result<Vec<f64>, GpuError> {
    // common.wgsl's err_bound reads the problem's ABS_UNIT, which turn_rate does not use.
    let kernel = "
const ABS_UNIT: real = 0.0;
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;

@compute @workgroup_size(64)
fn turn_test(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&xs) / 5u) {
        return;
    }
    let a = 5u * i;
    ys[i] = turn_rate(Iv(xs[a], xs[a + 1u]), xs[a + 2u], Iv(xs[a + 3u], xs[a + 4u]));
}
";
    let source = format!("{REAL_F64}\n{F32_BITS}\n{COMMON}\n{TURN}\n{kernel}");
    let xs: Vec<f64> = inputs.iter().flatten().copied().collect();
    run(ctx, &source, "turn_test", &xs, inputs.len(), 1)
}

/// One guessed step of the continuous model, as [`guessed_on_device`] takes it: the set,
/// the step `h`, last step's slab rates and those of the step before (where known), the rates
/// the step's field gave on the guessed box's slabs, and second-order rates (`∓1e300` where
/// none).
#[derive(Clone, Debug)]
pub struct GuessCase {
    /// The set `[x̲, x̄]` at the step's start.
    pub set: IntervalBox,
    /// The step.
    pub h: f64,
    /// `(r̲, r̄)`: last step's slab rates.
    pub rates: (Vec<f64>, Vec<f64>),
    /// The slab rates of the step before, for the trend.
    pub before: Option<(Vec<f64>, Vec<f64>)>,
    /// `(dl, du)`: the field's bounds on the guessed box's slabs.
    pub slab_rates: (Vec<f64>, Vec<f64>),
    /// `(cl, cu)`: second-order rates, met with the clamped slab rates.
    pub curved: (Vec<f64>, Vec<f64>),
    /// The other frame's set that clips the slabs (`meet_slabs`), where one does.
    pub other: Option<OtherSet>,
}

/// Another frame's set over a step as `validated.wgsl`'s `clip_by_other` takes it: the
/// half-spaces' rows (`safe_set::frame_rows`, the same for every case of a probe), the set in
/// the other frame's coordinates and the pad (`safe_set::frame_slack`).
#[derive(Clone, Debug)]
pub struct OtherSet {
    /// `T_g S_f`, row-major `n × n`.
    pub rows: Vec<Interval>,
    /// The other frame's set.
    pub set: IntervalBox,
    /// `ρ_g K`.
    pub pad: f64,
}

/// What `shaders/validated.wgsl` made of a [`GuessCase`] on the device.
#[derive(Clone, Debug)]
pub struct GuessOnDevice {
    /// `guessed`'s `ok` (the Rust's `Some`); the rest means nothing where false.
    pub ok: bool,
    /// The faces' rates and the slabs' depths.
    pub faces: MovingFaces,
    /// The hull over the step.
    pub hull: IntervalBox,
    /// The 2n slabs, in the order (0, lower), (0, upper), (1, lower), …
    pub slabs: Vec<(Vec<f64>, Vec<f64>)>,
    /// `verified` on the case's slab rates.
    pub verified: bool,
    /// `slab_step_end`: the set at the step's end.
    pub end: IntervalBox,
}

/// The primitives of `shaders/validated.wgsl` (`guessed`, `slab`, clipped by the case's other
/// set where it has one, `verified`, `slab_step_end`) on the device (f64), for cases of one
/// dimension `n` (and one pair of frames: the same rows in every other set).
pub fn guessed_on_device(
    ctx: &GpuContext,
    n: usize,
    cases: &[GuessCase],
) -> Result<Vec<GuessOnDevice>, GpuError> {
    guessed_on_device_in(ctx, n, cases, Precision::F64, F32Break::None)
}

/// How [`guessed_on_device_in`] breaks the f32 arithmetic, for tests that must see the break:
/// not at all, or no outward rounding (the prelude's `up` the identity). (`h` rounded to the
/// nearest f32 is no break a containment test sees: the outward steps absorb its half ulp;
/// `codegen::h_enclosure`'s own test checks the enclosure.)
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum F32Break {
    /// As the engine runs.
    None,
    /// `up(x) = x`.
    NoOutward,
}

/// [`guessed_on_device`] in `precision`: the set's ends rounded outward to it, the rates to
/// nearest (a guess's inputs), the step `h` as its enclosure (`codegen::h_enclosure`), the
/// arithmetic as `broken` says.
pub fn guessed_on_device_in(
    ctx: &GpuContext,
    n: usize,
    cases: &[GuessCase],
    precision: Precision,
    broken: F32Break,
) -> Result<Vec<GuessOnDevice>, GpuError> {
    // The rows of the cases' other sets, shared by the probe's cases as by a frame's module.
    let rows = cases
        .iter()
        .filter_map(|c| c.other.as_ref())
        .map(|o| &o.rows);
    let rows = match rows.clone().next() {
        Some(first) if rows.clone().any(|r| r != first) => {
            return Err(GpuError::Problem(
                "a probe's cases clip by different rows".into(),
            ))
        }
        Some(first) => first.clone(),
        None => vec![Interval::point(0.0); n * n],
    };
    let other_lo = private_real(
        "OTHER_LO",
        rows.iter().map(|v| round_down(v.lower, precision)),
        precision,
    );
    let other_hi = private_real(
        "OTHER_HI",
        rows.iter().map(|v| round_up(v.upper, precision)),
        precision,
    );
    let kernel = format!(
        "
const ABS_UNIT: real = 0.0;
const N0: u32 = {n}u;
{other_lo}
{other_hi}
{VALIDATED}
@group(0) @binding(0) var<storage, read> xs: array<real>;
@group(0) @binding(1) var<storage, read_write> ys: array<real>;

// Per case lo, hi, h's lower end, r_lo, r_hi, b_lo, b_hi, before, dl, du, cl, cu, h's upper end,
// the other set's lo, hi, pad and whether it clips.
const IN: u32 = 12u * N0 + 5u;
const OUT: u32 = 2u + 8u * N0 + 4u * N0 * N0;

fn take(at: u32) -> array<real, N0> {{
    var a: array<real, N0>;
    for (var j = 0u; j < N0; j++) {{
        a[j] = xs[at + j];
    }}
    return a;
}}

fn put(at: u32, a: array<real, N0>) {{
    for (var j = 0u; j < N0; j++) {{
        ys[at + j] = a[j];
    }}
}}

@compute @workgroup_size(64)
fn guess_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let k = id.x;
    if (k >= arrayLength(&xs) / IN) {{
        return;
    }}
    let a = k * IN;
    let lo = take(a);
    let hi = take(a + N0);
    let h = Iv(xs[a + 2u * N0], xs[a + 10u * N0 + 2u]);
    var m = guessed(lo, hi, h, take(a + 2u * N0 + 1u), take(a + 3u * N0 + 1u), take(a + 4u * N0 + 1u), take(a + 5u * N0 + 1u), xs[a + 6u * N0 + 1u] != 0.0);
    m.o_lo = take(a + 10u * N0 + 3u);
    m.o_hi = take(a + 11u * N0 + 3u);
    m.o_pad = xs[a + 12u * N0 + 3u];
    m.clip = xs[a + 12u * N0 + 4u] != 0.0;
    let dl = take(a + 6u * N0 + 2u);
    let du = take(a + 7u * N0 + 2u);
    var o = k * OUT;
    ys[o] = select(real(0.0), real(1.0), m.ok);
    put(o + 1u, m.s_lo);
    put(o + 1u + N0, m.s_hi);
    put(o + 1u + 2u * N0, m.d_lo);
    put(o + 1u + 3u * N0, m.d_hi);
    put(o + 1u + 4u * N0, m.hull_lo);
    put(o + 1u + 5u * N0, m.hull_hi);
    o = o + 1u + 6u * N0;
    for (var i = 0u; i < N0; i++) {{
        for (var side = 0u; side < 2u; side++) {{
            let s = slab(lo, hi, m, h, i, side);
            put(o, s.lo);
            put(o + N0, s.hi);
            o = o + 2u * N0;
        }}
    }}
    ys[o] = select(real(0.0), real(1.0), verified(m, dl, du));
    let end = slab_step_end(lo, hi, m, h, dl, du, take(a + 8u * N0 + 2u), take(a + 9u * N0 + 2u));
    put(o + 1u, end.lo);
    put(o + 1u + N0, end.hi);
}}
"
    );
    let prelude = match (precision, broken) {
        (Precision::F64, _) => REAL_F64.to_string(),
        (Precision::F32, F32Break::NoOutward) => {
            // A prelude without this line would leave the break a no-op: say so.
            const UP: &str = "return up32(x);";
            if !REAL_F32.contains(UP) {
                return Err(GpuError::Shader(format!(
                    "the f32 prelude has no `{UP}` to break"
                )));
            }
            REAL_F32.replace(UP, "return x;")
        }
        (Precision::F32, F32Break::None) => REAL_F32.to_string(),
    };
    let source = format!("{prelude}\n{F32_BITS}\n{COMMON}\n{kernel}");
    let mut xs = Vec::with_capacity(cases.len() * (12 * n + 5));
    for c in cases {
        let (bl, bu) = c
            .before
            .clone()
            .unwrap_or_else(|| (vec![0.0; n], vec![0.0; n]));
        xs.extend(c.set.lower.iter().map(|&x| round_down(x, precision)));
        xs.extend(c.set.upper.iter().map(|&x| round_up(x, precision)));
        let (h_lo, h_hi) = h_enclosure(c.h, precision);
        xs.push(h_lo);
        for v in [&c.rates.0, &c.rates.1, &bl, &bu] {
            xs.extend(v);
        }
        xs.push(f64::from(u8::from(c.before.is_some())));
        for v in [&c.slab_rates.0, &c.slab_rates.1, &c.curved.0, &c.curved.1] {
            xs.extend(v);
        }
        xs.push(h_hi);
        let zero = IntervalBox::new(vec![0.0; n], vec![0.0; n]).expect("a point box");
        let (set, pad) = c.other.as_ref().map_or((&zero, 0.0), |o| (&o.set, o.pad));
        xs.extend(set.lower.iter().map(|&x| round_down(x, precision)));
        xs.extend(set.upper.iter().map(|&x| round_up(x, precision)));
        xs.push(round_up(pad, precision));
        xs.push(f64::from(u8::from(c.other.is_some())));
    }
    let per = 2 + 8 * n + 4 * n * n;
    let ys = run_in(
        ctx,
        &source,
        "guess_test",
        &xs,
        (cases.len(), per),
        precision,
    )?;
    Ok(ys
        .chunks(per)
        .map(|y| {
            let part = |k: usize| y[1 + k * n..1 + (k + 1) * n].to_vec();
            let at = 1 + 6 * n;
            let slabs = (0..2 * n)
                .map(|s| {
                    let b = at + 2 * n * s;
                    (y[b..b + n].to_vec(), y[b + n..b + 2 * n].to_vec())
                })
                .collect();
            let end = at + 4 * n * n;
            GuessOnDevice {
                ok: y[0] != 0.0,
                faces: MovingFaces {
                    lower: part(0),
                    upper: part(1),
                    depth_lower: part(2),
                    depth_upper: part(3),
                },
                hull: IntervalBox {
                    lower: part(4),
                    upper: part(5),
                },
                slabs,
                verified: y[end] != 0.0,
                end: IntervalBox {
                    lower: y[end + 1..end + 1 + n].to_vec(),
                    upper: y[end + 1 + n..end + 1 + 2 * n].to_vec(),
                },
            }
        })
        .collect())
}

/// One upper end's barrier of the curved rates, as [`barrier_on_device`] takes it
/// (`end_rates::barrier`'s arguments, the other coordinates' beside `i`'s).
#[derive(Clone, Debug)]
pub struct BarrierCase {
    /// The slab form's upper value at `p`.
    pub c: f64,
    /// Per coordinate the form's slope `[k̲ⱼ, k̄ⱼ]` (at `i`: `kᵢ`).
    pub k: Vec<(f64, f64)>,
    /// Per coordinate the set's offsets from `p` (unused at `i`).
    pub d: Vec<(f64, f64)>,
    /// Per coordinate its ends' rates (unused at `i`).
    pub a: Vec<(f64, f64)>,
    /// The end's coordinate.
    pub i: usize,
    /// The step.
    pub h: f64,
    /// The slab's bottom in the end's sign: the barrier's `a` is at least this.
    pub floor: f64,
}

/// A barrier that settled: `(a + hb/2, w̲, w̄)` (`end_rates::barrier`'s `Some`).
pub type Settled = (f64, f64, f64);

/// `barrier` of `shaders/end_rates.wgsl` on the device (f64), for cases of one dimension `n`:
/// `(a + hb/2, w̲, w̄)` where it settles.
pub fn barrier_on_device(
    ctx: &GpuContext,
    n: usize,
    cases: &[BarrierCase],
) -> Result<Vec<Option<Settled>>, GpuError> {
    let kernel = format!(
        "
const ABS_UNIT: real = 0.0;
const N0: u32 = {n}u;
{END_RATES}
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;

// Per case c, i, h, floor, then per coordinate k, d, a (two ends each).
const IN: u32 = 4u + 6u * N0;

fn iv_at(at: u32) -> Iv {{
    return Iv(xs[at], xs[at + 1u]);
}}

@compute @workgroup_size(64)
fn barrier_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let q = id.x;
    if (q >= arrayLength(&xs) / IN) {{
        return;
    }}
    let at = q * IN;
    var k: array<Iv, N0>;
    var d: array<Iv, N0>;
    var a: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {{
        k[j] = iv_at(at + 4u + 6u * j);
        d[j] = iv_at(at + 6u + 6u * j);
        a[j] = iv_at(at + 8u + 6u * j);
    }}
    let b = barrier(xs[at], k, d, a, u32(xs[at + 1u]), iv_point(xs[at + 2u]), xs[at + 3u]);
    ys[4u * q] = select(real(0.0), real(1.0), b.ok);
    ys[4u * q + 1u] = b.r;
    ys[4u * q + 2u] = b.w_lo;
    ys[4u * q + 3u] = b.w_hi;
}}
"
    );
    let source = format!("{REAL_F64}\n{F32_BITS}\n{COMMON}\n{kernel}");
    let mut xs = Vec::with_capacity(cases.len() * (4 + 6 * n));
    for c in cases {
        xs.extend([c.c, c.i as f64, c.h, c.floor]);
        for j in 0..n {
            xs.extend([c.k[j].0, c.k[j].1, c.d[j].0, c.d[j].1, c.a[j].0, c.a[j].1]);
        }
    }
    let ys = run(ctx, &source, "barrier_test", &xs, cases.len(), 4)?;
    Ok(ys
        .chunks(4)
        .map(|y| (y[0] != 0.0).then_some((y[1], y[2], y[3])))
        .collect())
}

/// What `shaders/fold.wgsl` computes for one box ([`fold_on_device`]).
#[derive(Clone, Copy, Debug)]
pub struct FoldOnDevice {
    /// The box's underflow scale (`box_info`).
    pub scale: f64,
    /// `fold_error`: one bound of every first-layer neuron's folded constant's rounding.
    pub eps: f64,
    /// `fold_carry` for the second layer's neuron `g mod n₂`: `rowsum(|W₂|)·ε`.
    pub carry: f64,
    /// `first_layer_forms`' constant for the first layer's neuron `g mod n₁`: `b + W·x` over
    /// the pinned coordinates.
    pub constant: f64,
}

/// `shaders/fold.wgsl` on the device (f64), with `net`'s buffer as the engine uploads it
/// (`flatten_network`), for the boxes `(lower, upper)` (`lower = upper` pins a coordinate).
pub fn fold_on_device(
    ctx: &GpuContext,
    net: &crate::network::Mlp,
    boxes: &[(Vec<f64>, Vec<f64>)],
) -> Result<Vec<FoldOnDevice>, GpuError> {
    let flat = flatten_network(net);
    let (n0, n1) = (net.input_dim(), net.layers[0].n_out);
    let n2 = net.layers.get(1).map_or(1, |l| l.n_out);
    let at = flat.data.len();
    let ((w_off, b_off), fold_off) = (flat.offsets.layers[0], flat.offsets.fold);
    let kernel = format!(
        "
const ABS_UNIT: real = 0.0;
const N0: u32 = {n0}u;
const KC: u32 = {kc}u;
@group(0) @binding(0) var<storage, read> net: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;
{BOX}
{FOLD}
// box_info reads one box from `state`; the boxes follow the network in `net`.
var<private> state: array<real, SW>;
var<private> p: Params;

@compute @workgroup_size(64)
fn fold_test(@builtin(global_invocation_id) id: vec3<u32>) {{
    let g = id.x;
    if (g >= {cases}u) {{
        return;
    }}
    for (var k = 0u; k < SW; k++) {{
        state[k] = net[{at}u + g * SW + k];
    }}
    p.w_off = {w_off}u;
    p.b_off = {b_off}u;
    p.fold_off = {fold_off}u;
    p.carry = 1u;
    let bx = box_info(0u);
    ys[4u * g] = bx.scale;
    ys[4u * g + 1u] = fold_error(bx);
    ys[4u * g + 2u] = fold_carry(g % {n2}u, bx);
    ys[4u * g + 3u] = first_layer_forms(g % {n1}u, bx).c[N0];
}}
",
        kc = n0 + 1,
        cases = boxes.len(),
    );
    let source = format!("{REAL_F64}\n{F32_BITS}\n{PARAMS}\n{COMMON}\n{kernel}");
    let mut xs = flat.data;
    for (lo, hi) in boxes {
        xs.extend(lo.iter().chain(hi));
        xs.push(0.0);
    }
    let ys = run(ctx, &source, "fold_test", &xs, boxes.len(), 4)?;
    Ok(ys
        .chunks(4)
        .map(|y| FoldOnDevice {
            scale: y[0],
            eps: y[1],
            carry: y[2],
            constant: y[3],
        })
        .collect())
}

/// Validates `shaders/validated.wgsl` and `shaders/end_rates.wgsl` with the f32 prelude, every
/// function called (their probes run f64 alone): the shader's validation error where they are
/// not valid WGSL (`validate`).
pub fn validated_compiles_in_f32(ctx: &GpuContext) -> Result<(), GpuError> {
    let kernel = "
const ABS_UNIT: real = 0.0;
const N0: u32 = 2u;
var<private> OTHER_LO: array<real, 4> = array<real, 4>(1.0, 0.5, 0.0, 1.0);
var<private> OTHER_HI: array<real, 4> = array<real, 4>(1.0, 0.5, 0.0, 1.0);
@group(0) @binding(0) var<storage, read_write> ys: array<f32>;

@compute @workgroup_size(1)
fn f32_check() {
    var x: array<real, N0>;
    x[0] = ys[0];
    x[1] = ys[1];
    let h = Iv(ys[2], ys[3]);
    var m = guessed(x, x, h, x, x, x, x, ys[3] > 0.0);
    m.clip = ys[2] > 0.0;
    let s = slab(x, x, m, h, 0u, 1u);
    let e = slab_step_end(x, x, m, h, x, x, x, x);
    var k: array<Iv, N0>;
    k[0] = Iv(ys[0], ys[1]);
    k[1] = k[0];
    let b = barrier(ys[0], k, k, k, 0u, h, ys[1]);
    ys[4] = s.lo[0] + e.hi[1] + b.r + select(0.0, 1.0, verified(m, x, x));
}
";
    let source = format!("{REAL_F32}\n{F32_BITS}\n{COMMON}\n{VALIDATED}\n{END_RATES}\n{kernel}");
    validate(&ctx.device, &source, "f32_check")
}

/// Runs the kernel `entry` of the f64 WGSL `source` (binding 0: `xs`, read-only; binding 1:
/// `per` outputs for each of `items` invocations) and returns its outputs.
pub(crate) fn run(
    ctx: &GpuContext,
    source: &str,
    entry: &str,
    xs: &[f64],
    items: usize,
    per: usize,
) -> Result<Vec<f64>, GpuError> {
    run_in(ctx, source, entry, xs, (items, per), Precision::F64)
}

/// [`run`] for a `source` whose `xs` and `ys` hold `precision`'s numbers (`xs` converted to
/// nearest: callers round what must be rounded outward).
fn run_in(
    ctx: &GpuContext,
    source: &str,
    entry: &str,
    xs: &[f64],
    (items, per): (usize, usize),
    precision: Precision,
) -> Result<Vec<f64>, GpuError> {
    if precision == Precision::F64 && !ctx.has_f64() {
        return Err(GpuError::NoF64(ctx.info.name.clone()));
    }
    if xs.is_empty() || items == 0 {
        return Ok(Vec::new());
    }
    let device = &ctx.device;
    let pipeline = compile(device, source, entry)?;
    let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("probe xs"),
        contents: &device_bytes(xs, precision),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let size = per as u64 * items as u64 * precision.bytes();
    let output = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("probe ys"),
        size,
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    });
    let bind = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some(entry),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[
            wgpu::BindGroupEntry {
                binding: 0,
                resource: input.as_entire_binding(),
            },
            wgpu::BindGroupEntry {
                binding: 1,
                resource: output.as_entire_binding(),
            },
        ],
    });
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups((items as u32).div_ceil(64), 1, 1);
    }
    ctx.queue.submit([enc.finish()]);
    let bytes = read_back_bytes(ctx, &output, size)?;
    Ok(from_device_bytes(&bytes, precision))
}

/// Validates `source` as a module (naga's parse and validation, which wgpu runs on every
/// module), without the driver's compile of a pipeline: on lavapipe that compile takes tens of
/// seconds for the larger modules, and what a precision's prelude can break (types, overloads)
/// is the module's validity.
pub(crate) fn validate(device: &wgpu::Device, source: &str, label: &str) -> Result<(), GpuError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let _module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(label),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    match pollster::block_on(scope.pop()) {
        Some(e) => Err(GpuError::Shader(e.to_string())),
        None => Ok(()),
    }
}

/// The compute pipeline of `entry` in `source`, with the layout the shader implies; a
/// validation error is the shader's.
pub(crate) fn compile(
    device: &wgpu::Device,
    source: &str,
    entry: &str,
) -> Result<wgpu::ComputePipeline, GpuError> {
    let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some(entry),
        source: wgpu::ShaderSource::Wgsl(source.into()),
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: None,
        module: &module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache: None,
    });
    if let Some(e) = pollster::block_on(scope.pop()) {
        return Err(GpuError::Shader(e.to_string()));
    }
    Ok(pipeline)
}

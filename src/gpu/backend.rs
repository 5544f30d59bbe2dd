//! [`GpuBackend`]: the reach engine on the device (DESIGN §4).
//!
//! Every box of a chunk stays on the device for the whole horizon. One step is a fixed list of
//! dispatches (`StepPlan`), recorded into a few command buffers (a progress report between
//! them, no readback); the snapshots are read back once at the end. By bound method:
//!
//! - `forward`: per layer the GEMMs `W·Ĉ`, `|W|·R̂`, `|W|·V` and the ReLU kernel;
//! - `forward-backward[-same-slope]`: the same with IBP alongside (`W·c`, `|W|·[r, |c| + r]`),
//!   every hidden layer's bounds recorded, `|W_k| max(u, 0)` per layer for the rounding bounds,
//!   then ONE backward pass from the output: per hidden layer a per-box scaling `Λ∘s` and ONE
//!   GEMM `Λ ← Wⱼᵀ·(Λ∘s)` shared by all boxes;
//! - `crown[-same-slope]`: a backward pass from every layer, each layer's bounds from its own
//!   pass (`2 n_k` or `n_k` rows of `Λ` per box).
//!
//! Then the output kernel (the network's bounds per box), the embedding step and the step
//! counter's tick. Batches larger than the device's binding, memory or dispatch limits allow
//! are split into chunks that run one after the other on the same buffers.
//!
//! With face-local bounds (`--face-local`) a step starts with the `faces` kernel, which writes
//! the `2n` faces of every box (`shaders/faces.wgsl`); the bound kernels then run on `2n·B`
//! bound boxes, and the embedding step bounds each face of the field with its own face's
//! network bounds. With local error margins (`--local-margin`, an error map on the problem)
//! the embedding step takes each box's `M` from the map (`margins`), and a box that meets a
//! cell without a certified bound stops as invalid (`status::NO_BOUND`), as on the CPU.

use std::sync::{Arc, Mutex};
use std::time::Instant;

use rayon::prelude::*;

use super::buffers::{
    device_bytes, flatten_network, from_device_bytes, status, storage, storage_init, uniform,
    Params, LOOP_CHECK,
};
use super::codegen::{
    faces_per_box, flag_words, nnb_width, problem_wgsl, round_down, round_up, MethodFlags, AUX,
    FLAG_W,
};
use super::kernels::{Kernel, Kernels, GEMM_TILE, WORKGROUP};
use super::margins::MarginMap;
use super::{GpuContext, GpuError, Precision};
use crate::bounds::{BoundMethod, Relaxation};
use crate::boxes::IntervalBox;
use crate::reach::{
    Backend, ReachError, ReachProblem, ReachResult, ReachSettings, ReachTiming, SafeSet, Tube,
};

/// The largest buffer one chunk binds, whatever the device allows (bytes).
const MAX_BINDING: u64 = 1 << 30;
/// The most device memory one chunk's buffers take together (bytes).
const MAX_CHUNK_BYTES: u64 = 3 << 29;
/// Steps recorded into one command buffer at most (progress is reported between them).
const STEPS_PER_SUBMIT: usize = 25;
/// Storage buffers the widest kernel binds (relu, output).
const STORAGE_BINDINGS: u32 = 8;
/// llvmpipe silently ends every loop of a shader invocation once this many iterations have run
/// in it (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`); the embedding kernel checks for it itself
/// (`loops_ran_in_full`), the bound kernels' loops are refused beyond it ([`bound_kernel_loops`]).
const LLVMPIPE_LOOP_LIMIT: usize = 65_535;

/// The wgpu engine.
#[derive(Clone, Debug)]
pub struct GpuBackend {
    ctx: Arc<GpuContext>,
    precision: Precision,
    /// Most boxes in one chunk (`None`: as many as the limits allow); for tests of the split.
    pub max_chunk: Option<usize>,
    /// Most work of an exact local-margin query (`None`: `margins::EXACT_WORK`); for tests of
    /// the embedding kernel's loop check.
    pub exact_work: Option<usize>,
    /// After each chunk, time every kind of dispatch of a step on its own and print the
    /// breakdown to stderr (`bench --profile`; the chunk's results are read back first).
    pub profile: bool,
    /// The pipelines of the last problem run, reused while its generated WGSL is unchanged
    /// (`verify` calls the engine once per batch; compiling every pipeline takes ~1 s on an
    /// NVIDIA driver).
    kernels: KernelCache,
}

/// Pipelines with the generated WGSL they were compiled from.
type CompiledKernels = (String, Arc<Kernels>);

/// The last pipelines an engine compiled.
#[derive(Clone, Default)]
struct KernelCache(Arc<Mutex<Option<CompiledKernels>>>);

impl std::fmt::Debug for KernelCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KernelCache")
    }
}

impl KernelCache {
    /// The pipelines for `source`, compiled only when it differs from the last one's.
    fn get(
        &self,
        device: &wgpu::Device,
        precision: Precision,
        source: String,
    ) -> Result<Arc<Kernels>, GpuError> {
        let mut last = self
            .0
            .lock()
            .map_err(|_| GpuError::Device("kernel cache poisoned".into()))?;
        if let Some((s, k)) = last.as_ref() {
            if *s == source {
                return Ok(k.clone());
            }
        }
        let kernels = Arc::new(Kernels::new(device, precision, &source)?);
        *last = Some((source, kernels.clone()));
        Ok(kernels)
    }
}

impl GpuBackend {
    /// An f32 engine on a device.
    pub fn new(ctx: Arc<GpuContext>) -> GpuBackend {
        GpuBackend {
            ctx,
            precision: Precision::F32,
            max_chunk: None,
            exact_work: None,
            profile: false,
            kernels: KernelCache::default(),
        }
    }

    /// An engine in `precision`; [`GpuError::NoF64`] when f64 is asked of a device without
    /// `wgpu::Features::SHADER_F64`.
    pub fn with_precision(
        ctx: Arc<GpuContext>,
        precision: Precision,
    ) -> Result<GpuBackend, GpuError> {
        if precision == Precision::F64 && !ctx.has_f64() {
            return Err(GpuError::NoF64(ctx.info.name.clone()));
        }
        Ok(GpuBackend {
            precision,
            ..GpuBackend::new(ctx)
        })
    }

    /// The device.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The device's number type.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Whether this engine runs `settings`: forward, forward-backward and CROWN bounds (either
    /// relaxation, whole-box or face-local), not IBP alone. Local error margins (a problem
    /// with an error map) run on every setting.
    pub fn supports(settings: &ReachSettings) -> bool {
        method_flags(settings.bounds, 2).is_some()
    }

    /// Boxes per chunk for a problem: every buffer of one chunk must fit one binding, all of
    /// them together 1.5 GiB, and the dispatches the device's limits.
    pub fn chunk_size(
        &self,
        problem: &ReachProblem,
        settings: &ReachSettings,
        boxes: usize,
    ) -> usize {
        let lim = &self.ctx.limits;
        let binding = lim
            .max_storage_buffer_binding_size
            .min(lim.max_buffer_size)
            .min(MAX_BINDING);
        let shape = Shape::new(problem, settings);
        let bytes = self.precision.bytes();
        let per_box = shape.per_box();
        let largest = per_box.iter().map(|(_, n, _)| *n).max().unwrap_or(1) * bytes;
        let total: u64 = per_box.iter().map(|(_, n, copies)| n * copies).sum::<u64>() * bytes;
        let by_binding = (binding / largest.max(1)).max(1);
        let by_memory = (MAX_CHUNK_BYTES / total.max(1)).max(1);
        let groups = lim.max_compute_workgroups_per_dimension as u64;
        let widest = (shape.kc.max(shape.r_max).max(3) * shape.faces) as u64;
        let by_dispatch = (groups * GEMM_TILE as u64 / widest).min(groups * WORKGROUP as u64);
        let mut c = by_binding
            .min(by_memory)
            .min(by_dispatch)
            .min(boxes.max(1) as u64) as usize;
        if let Some(m) = self.max_chunk {
            c = c.min(m.max(1));
        }
        c
    }
}

impl From<GpuError> for ReachError {
    fn from(e: GpuError) -> ReachError {
        ReachError::Gpu(e.to_string())
    }
}

/// An upper estimate of the loop iterations one thread of the bound kernels runs for a network
/// of `widths` (input first): `bwd_scale`'s loops over a layer's neurons and its input's, and
/// the GEMM's loop over its inner width in tiles of 16 (with up to 24 inner iterations each
/// where the driver does not unroll them); the other kernels loop over the input's coordinates
/// and the outputs. Measured on lavapipe with [2, w, 2] networks: w = 45,000 (estimate 70,325)
/// agrees with the CPU, w = 60,000 (93,750) gives sets narrower than the CPU's.
fn bound_kernel_loops(widths: &[usize]) -> usize {
    let backward = widths.windows(2).map(|w| w[0] + w[1]).max().unwrap_or(0);
    let gemm = widths
        .iter()
        .map(|w| w.div_ceil(16) * 25)
        .max()
        .unwrap_or(0);
    backward.max(gemm)
}

/// The passes a bound method runs on the device (`None`: not on the GPU).
fn method_flags(bounds: BoundMethod, n_layers: usize) -> Option<MethodFlags> {
    let forward = MethodFlags {
        forward: true,
        ibp: false,
        record: false,
        backward: false,
        same_slope: false,
    };
    let same_slope = bounds.relaxation() == Relaxation::SameSlope;
    match bounds {
        BoundMethod::Ibp => None,
        BoundMethod::Forward => Some(forward),
        // One affine layer: its forward forms are exact (the first layer's), so every method
        // is forward's.
        _ if n_layers < 2 => Some(forward),
        BoundMethod::ForwardBackward | BoundMethod::ForwardBackwardSameSlope => Some(MethodFlags {
            ibp: true,
            record: true,
            backward: true,
            same_slope,
            ..forward
        }),
        BoundMethod::Crown | BoundMethod::CrownSameSlope => Some(MethodFlags {
            forward: false,
            ibp: false,
            record: true,
            backward: true,
            same_slope,
        }),
    }
}

/// Rows of Λ per box in a backward pass from layer k (widths `w`): `n_k` shared rows with the
/// same-slope relaxation, else `2 n_k` (upper, then lower).
fn pass_rows(w: &[usize], same_slope: bool, k: usize) -> usize {
    if same_slope {
        w[k + 1]
    } else {
        2 * w[k + 1]
    }
}

/// Sizes of one problem's device arrays, per box.
struct Shape {
    /// Widths `w[0] = n, w[k+1] = n_k`.
    w: Vec<usize>,
    n: usize,
    kc: usize,
    flags: MethodFlags,
    /// Whether every layer gets its own backward pass (crown).
    crown: bool,
    /// Rows of Λ per box of the largest pass, and Λ's reals per box (height × rows, the
    /// largest over the passes).
    r_max: usize,
    lam: usize,
    slots: usize,
    /// Bound boxes per box (`2n` face-local, else 1).
    faces: usize,
}

impl Shape {
    fn new(problem: &ReachProblem, settings: &ReachSettings) -> Shape {
        let w = problem.network.widths();
        let n_layers = w.len() - 1;
        let flags = method_flags(settings.bounds, n_layers).unwrap_or(MethodFlags {
            forward: true,
            ibp: false,
            record: false,
            backward: false,
            same_slope: false,
        });
        let crown = flags.backward && !flags.forward;
        let rows = |k: usize| pass_rows(&w, flags.same_slope, k);
        // Passes start at every layer ≥ 1 (crown) or at the output; a pass from layer k keeps
        // Λ of heights w[k] … w[0].
        let starts: Vec<usize> = match (flags.backward, crown) {
            (false, _) => vec![],
            (true, true) => (1..n_layers).collect(),
            (true, false) => vec![n_layers - 1],
        };
        let r_max = starts.iter().map(|&k| rows(k)).max().unwrap_or(0);
        let lam = starts
            .iter()
            .map(|&k| w[..=k].iter().copied().max().unwrap_or(0) * rows(k))
            .max()
            .unwrap_or(0);
        let every = settings.every.max(1);
        Shape {
            n: problem.dynamics.n,
            kc: problem.dynamics.n + 1,
            slots: problem.steps.div_ceil(every).max(1),
            faces: faces_per_box(problem.dynamics.n, settings),
            w,
            flags,
            crown,
            r_max,
            lam,
        }
    }

    /// Rows of Λ per box in the pass from layer k.
    fn rows(&self, k: usize) -> usize {
        pass_rows(&self.w, self.flags.same_slope, k)
    }

    /// Per box: (buffer, reals, copies) of every chunk buffer; the bound kernels' buffers hold
    /// `faces` bound boxes per box.
    fn per_box(&self) -> Vec<(&'static str, u64, u64)> {
        let width = *self.w.iter().max().unwrap_or(&1) as u64;
        let sum: u64 = self.w[1..].iter().map(|&x| x as u64).sum();
        let (kc, sw, f) = (self.kc as u64, 2 * self.n as u64 + 1, self.faces as u64);
        let forms = if self.flags.forward { width * kc } else { 0 };
        let record = if self.flags.record { sum } else { 0 };
        let faces = if self.faces > 1 { f * sw } else { 0 };
        vec![
            ("forms", f * forms, 4),
            ("aux", f * width * AUX as u64, 2),
            ("pre", f * 2 * record, 1),
            ("wm", f * record, 1),
            ("lam", f * self.lam as u64, 2),
            ("beta", f * 2 * self.r_max as u64, 1),
            (
                "nnb",
                f * nnb_width(self.n, self.w[self.w.len() - 1]) as u64,
                1,
            ),
            ("faces", faces, 1),
            ("state", sw, 2),
            ("snap", self.slots as u64 * sw, 2),
        ]
    }
}

/// Device buffers of one run, sized for the largest chunk.
struct Buffers {
    net: wgpu::Buffer,
    state: wgpu::Buffer,
    flags: wgpu::Buffer,
    snap: wgpu::Buffer,
    c: [wgpu::Buffer; 2],
    r: [wgpu::Buffer; 2],
    aux: wgpu::Buffer,
    aux_g: wgpu::Buffer,
    pre: wgpu::Buffer,
    wm: wgpu::Buffer,
    lam: [wgpu::Buffer; 2],
    beta: wgpu::Buffer,
    nnb: wgpu::Buffer,
    /// The face boxes (face-local bounds; unused otherwise).
    faces: wgpu::Buffer,
    /// The error map for local margins (`margins::MarginMap`).
    map_index: wgpu::Buffer,
    map_cells: wgpu::Buffer,
    staging: wgpu::Buffer,
}

impl Buffers {
    /// What the bound kernels read as their boxes: the faces, or the states themselves.
    fn bound_boxes(&self, shape: &Shape) -> &wgpu::Buffer {
        if shape.faces > 1 {
            &self.faces
        } else {
            &self.state
        }
    }
}

/// What one chunk's readback holds.
struct ChunkResult {
    snap: Vec<f64>,
    state: Vec<f64>,
    flags: Vec<u32>,
}

impl Backend for GpuBackend {
    /// Thousands of boxes: a step of 4,096 boxes of a 2×400×400×400×2 network takes 2–5 ms
    /// on an H100, of 256 boxes nearly as long.
    fn preferred_batch(&self) -> usize {
        8192
    }

    fn name(&self) -> String {
        match self.precision {
            Precision::F32 => format!("gpu ({}, f32)", self.ctx.info.name),
            Precision::F64 => format!("gpu ({}, f64)", self.ctx.info.name),
        }
    }

    fn reach(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        problem.check_initial(initial)?;
        settings.validate()?;
        if problem.time != crate::reach::TimeModel::Euler {
            return Err(GpuError::Unsupported(format!(
                "time = \"{}\" (the GPU engine runs time = \"euler\" alone: set it, or use \
                 the CPU engine)",
                problem.time.name()
            ))
            .into());
        }
        if !GpuBackend::supports(settings) {
            return Err(GpuError::Unsupported(format!(
                "{} bounds (the GPU engine has forward, forward-backward and crown bounds; use \
                 one of them or the CPU)",
                settings.bounds
            ))
            .into());
        }
        let start = Instant::now();
        let every = settings.every.max(1);
        let (n, steps) = (problem.dynamics.n, problem.steps);
        let slots = steps.div_ceil(every);
        let safe = problem.safe_set_for(settings.method);
        let z_boxes: Vec<IntervalBox> = initial
            .iter()
            .map(|b| problem.initial_state(b, settings.method))
            .collect();
        let mut tubes: Vec<Tube> = initial
            .iter()
            .zip(&z_boxes)
            .map(|(b, z)| Tube {
                initial: b.clone(),
                tube: vec![problem.tube_sample(&z.lower, &z.upper, 0.0, 0.0, safe)],
                valid: true,
                note: None,
                exact_steps: 0,
                enclosed_steps: 0,
            })
            .collect();
        if initial.is_empty() || steps == 0 {
            return Ok(ReachResult {
                boxes: tubes,
                timing: ReachTiming::default(),
            });
        }
        let widths = problem.network.widths();
        if widths.iter().any(|&w| w == 0 || w > 1 << 18) || widths[0] != n {
            return Err(
                GpuError::Problem(format!("network widths {widths:?} not supported")).into(),
            );
        }
        let loops = bound_kernel_loops(&widths);
        if self.ctx.info.name.contains("llvmpipe") && loops > LLVMPIPE_LOOP_LIMIT {
            return Err(GpuError::TooLarge(format!(
                "network widths {widths:?}: a bound kernel would run ~{loops} loop iterations \
                 per thread, and llvmpipe silently ends a shader's loops after \
                 {LLVMPIPE_LOOP_LIMIT}; use the CPU engine (--backend cpu) or a real GPU"
            ))
            .into());
        }
        let stage_limit = self.ctx.limits.max_storage_buffers_per_shader_stage;
        if stage_limit < STORAGE_BINDINGS {
            return Err(GpuError::TooLarge(format!(
                "the kernels bind {STORAGE_BINDINGS} storage buffers; the device allows \
                 {stage_limit}"
            ))
            .into());
        }
        let shape = Shape::new(problem, settings);
        let mut margins = MarginMap::for_problem(problem, settings, self.precision);
        if let Some(w) = self.exact_work {
            margins.exact_work = w;
        }
        let source = problem_wgsl(problem, settings, shape.flags, self.precision, &margins)?;
        let kernels = self.kernels.get(&self.ctx.device, self.precision, source)?;
        let chunk = self.chunk_size(problem, settings, initial.len());
        let bufs = self.buffers(problem, &shape, &margins, chunk)?;
        let n_chunks = initial.len().div_ceil(chunk);
        for (ci, boxes) in z_boxes.chunks(chunk).enumerate() {
            let res = self.run_chunk(problem, &shape, &kernels, &bufs, boxes, slots, &|s| {
                progress(((ci * steps + s) / n_chunks).min(steps), steps)
            })?;
            let first = ci * chunk;
            // Turning snapshots into samples is per box: in parallel, or the host takes longer
            // than the device.
            tubes[first..first + boxes.len()]
                .par_iter_mut()
                .enumerate()
                .for_each(|(g, tube)| fill_tube(problem, safe, tube, &res, g, boxes.len(), every));
        }
        Ok(ReachResult {
            boxes: tubes,
            timing: ReachTiming {
                reach_s: start.elapsed().as_secs_f64(),
                minkowski_s: 0.0,
            },
        })
    }
}

/// One dispatch of a step.
struct Op<'k> {
    kernel: &'k Kernel,
    bind: wgpu::BindGroup,
    groups: [u32; 3],
    /// A GEMM's `[rows, inner, cols]` (profiles report its rate).
    gemm: Option<[u32; 3]>,
}

/// The dispatches of one Euler step for one chunk (see the module documentation).
struct StepPlan<'a> {
    device: &'a wgpu::Device,
    kernels: &'a Kernels,
    bufs: &'a Buffers,
    shape: &'a Shape,
    /// Offsets of every layer's `W` and `b` in `net`.
    offsets: Vec<(u32, u32)>,
    /// Bound boxes in this chunk (`faces` per box): the columns of the bound kernels.
    nb: u32,
    /// Boxes in this chunk.
    boxes: u32,
    ops: Vec<Op<'a>>,
}

impl<'a> StepPlan<'a> {
    fn push(&mut self, kernel: &'a Kernel, p: &Params, bufs: &[&wgpu::Buffer], groups: [u32; 3]) {
        let u = uniform(self.device, "params", p);
        let mut entries = vec![wgpu::BindGroupEntry {
            binding: 0,
            resource: u.as_entire_binding(),
        }];
        for (i, b) in bufs.iter().enumerate() {
            entries.push(wgpu::BindGroupEntry {
                binding: i as u32 + 1,
                resource: b.as_entire_binding(),
            });
        }
        let bind = self.device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: None,
            layout: &kernel.layout,
            entries: &entries,
        });
        self.ops.push(Op {
            kernel,
            bind,
            groups,
            gemm: None,
        });
    }

    /// Width `n_k` of layer k's output.
    fn n(&self, k: usize) -> u32 {
        self.shape.w[k + 1] as u32
    }

    /// Offset of layer k's recorded `l` in `pre` (its `u` follows, `n_k × B` later).
    fn pre_off(&self, k: usize) -> u32 {
        2 * self.nb * self.shape.w[1..=k].iter().sum::<usize>() as u32
    }

    /// Offset of layer k's `|W_k| max(u_{k−1}, 0)` in `wm`.
    fn wm_off(&self, k: usize) -> u32 {
        self.nb * self.shape.w[1..=k].iter().sum::<usize>() as u32
    }

    /// `Y = op(W_k)·X` over `cols` columns.
    fn gemm(
        &mut self,
        k: usize,
        base: Params,
        x: &'a wgpu::Buffer,
        y: &'a wgpu::Buffer,
        cols: u32,
    ) {
        let (rows, inner) = if base.trans_w != 0 {
            (self.shape.w[k] as u32, self.n(k))
        } else {
            (self.n(k), self.shape.w[k] as u32)
        };
        let p = Params {
            rows,
            inner,
            cols,
            w_off: self.offsets[k].0,
            ..base
        };
        let groups = [cols.div_ceil(GEMM_TILE), rows.div_ceil(GEMM_TILE), 1];
        let net = &self.bufs.net;
        self.push(&self.kernels.gemm, &p, &[net, x, y], groups);
        if let Some(op) = self.ops.last_mut() {
            op.gemm = Some([rows, inner, cols]);
        }
    }

    /// Layer k > 0's forward GEMMs: forms, form magnitudes, and IBP with `flags.ibp`.
    fn forward_gemms(&mut self, k: usize) {
        let b = self.bufs;
        let (cur, prev) = (k % 2, 1 - k % 2);
        let cols = self.nb * self.shape.kc as u32;
        let forms = Params {
            ldx: cols,
            ldy: cols,
            ..Default::default()
        };
        self.gemm(k, forms, &b.c[prev], &b.c[cur], cols);
        self.gemm(k, Params { abs_w: 1, ..forms }, &b.r[prev], &b.r[cur], cols);
        // Sections of aux: [c | V | r | |c| + r], `nb` columns each.
        let ld = AUX as u32 * self.nb;
        let vectors = Params {
            ldx: ld,
            ldy: ld,
            ..Default::default()
        };
        if self.shape.flags.ibp {
            self.gemm(k, vectors, &b.aux, &b.aux_g, self.nb);
        }
        let sections = if self.shape.flags.ibp { 3 } else { 1 };
        let mags = Params {
            abs_w: 1,
            x_off: self.nb,
            y_off: self.nb,
            ..vectors
        };
        self.gemm(k, mags, &b.aux, &b.aux_g, sections * self.nb);
    }

    /// `wm_k = |W_k| max(u_{k−1}, 0)`, the magnitudes of layer k's terms (k ≥ 1).
    fn weight_magnitudes(&mut self, k: usize) {
        let p = Params {
            abs_w: 1,
            relu_x: 1,
            x_off: self.pre_off(k - 1) + self.shape.w[k] as u32 * self.nb,
            ldx: self.nb,
            y_off: self.wm_off(k),
            ldy: self.nb,
            ..Default::default()
        };
        let (pre, wm) = (&self.bufs.pre, &self.bufs.wm);
        self.gemm(k, p, pre, wm, self.nb);
    }

    /// Hidden layer k's bias, IBP, record and ReLU relaxation.
    fn relu(&mut self, k: usize) {
        let b = self.bufs;
        let cur = k % 2;
        let p = Params {
            rows: self.n(k),
            w_off: self.offsets[k].0,
            b_off: self.offsets[k].1,
            n_prev: self.shape.w[k] as u32,
            first: (k == 0) as u32,
            boxes: self.nb,
            pre_off: self.pre_off(k),
            ..Default::default()
        };
        let groups = [self.nb.div_ceil(WORKGROUP), p.rows, 1];
        let bufs = [
            &b.net,
            b.bound_boxes(self.shape),
            &b.c[cur],
            &b.r[cur],
            &b.aux_g,
            &b.aux,
            &b.flags,
            &b.pre,
        ];
        self.push(&self.kernels.relu, &p, &bufs, groups);
    }

    /// The backward pass from layer k ≥ 1: returns the index of the Λ buffer holding the final
    /// `N0 × B·R` coefficients (the intercepts are in `beta`).
    fn backward_pass(&mut self, k: usize) -> usize {
        let b = self.bufs;
        let rpb = self.shape.rows(k) as u32;
        let cols = self.nb * rpb;
        let mut cur = 0;
        for j in (0..k).rev() {
            let p = Params {
                rows: self.n(j),
                n_prev: self.shape.w[j] as u32,
                first: (j + 1 == k) as u32,
                boxes: self.nb,
                rpb,
                w_off: self.offsets[j].0,
                b_off: self.offsets[j].1,
                pre_off: self.pre_off(j),
                wm_off: self.wm_off(j),
                prev_u_off: if j > 0 {
                    self.pre_off(j - 1) + self.shape.w[j] as u32 * self.nb
                } else {
                    0
                },
                at_input: (j == 0) as u32,
                k_w_off: self.offsets[k].0,
                k_b_off: self.offsets[k].1,
                k_rows: self.n(k),
                k_wm_off: self.wm_off(k),
                ..Default::default()
            };
            let bufs = [
                &b.net,
                b.bound_boxes(self.shape),
                &b.pre,
                &b.wm,
                &b.lam[cur],
                &b.beta,
                &b.flags,
            ];
            self.push(
                &self.kernels.bwd_scale,
                &p,
                &bufs,
                [cols.div_ceil(WORKGROUP), 1, 1],
            );
            let t = Params {
                trans_w: 1,
                ldx: cols,
                ldy: cols,
                ..Default::default()
            };
            self.gemm(j, t, &b.lam[cur], &b.lam[1 - cur], cols);
            cur = 1 - cur;
        }
        cur
    }

    /// Layer k's concrete bounds from its finished pass (crown), or from `W₀` for k = 0.
    fn pass_bounds(&mut self, k: usize, lam: usize) {
        let b = self.bufs;
        let p = Params {
            boxes: self.nb,
            rpb: self.shape.rows(k) as u32,
            first: (k == 0) as u32,
            pre_off: self.pre_off(k),
            k_w_off: self.offsets[k].0,
            k_b_off: self.offsets[k].1,
            k_rows: self.n(k),
            ..Default::default()
        };
        let bufs = [
            &b.net,
            b.bound_boxes(self.shape),
            &b.pre,
            &b.wm,
            &b.lam[lam],
            &b.beta,
            &b.flags,
        ];
        let groups = [self.nb.div_ceil(WORKGROUP), p.k_rows, 1];
        self.push(&self.kernels.bwd_bounds, &p, &bufs, groups);
    }

    /// The network's bounds per box, the Euler step and the tick.
    fn finish(&mut self, lam: usize) {
        let b = self.bufs;
        let last = self.shape.w.len() - 2;
        let p = Params {
            w_off: self.offsets[last].0,
            b_off: self.offsets[last].1,
            n_prev: self.shape.w[last] as u32,
            first: (last == 0) as u32,
            boxes: self.nb,
            rpb: if self.shape.flags.backward {
                self.shape.rows(last) as u32
            } else {
                0
            },
            ..Default::default()
        };
        let cur = last % 2;
        let groups = [self.nb.div_ceil(WORKGROUP), 1, 1];
        let bufs = [
            &b.net,
            b.bound_boxes(self.shape),
            &b.c[cur],
            &b.r[cur],
            &b.aux_g,
            &b.lam[lam],
            &b.beta,
            &b.nnb,
        ];
        self.push(&self.kernels.output, &p, &bufs, groups);
        let per_box = Params {
            boxes: self.boxes,
            loop_check: LOOP_CHECK,
            ..Default::default()
        };
        let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
        let group = [
            &b.state,
            &b.nnb,
            &b.flags,
            &b.snap,
            &b.map_index,
            &b.map_cells,
        ];
        self.push(&self.kernels.embed, &per_box, &group, groups);
        self.push(&self.kernels.tick, &per_box, &group, [1, 1, 1]);
    }

    /// The face boxes of every box (face-local bounds), first in a step.
    fn faces(&mut self) {
        if self.shape.faces > 1 {
            let p = Params {
                boxes: self.boxes,
                ..Default::default()
            };
            let b = self.bufs;
            let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
            self.push(&self.kernels.faces, &p, &[&b.state, &b.faces], groups);
        }
    }

    /// Every dispatch of one step.
    fn build(mut self) -> Vec<Op<'a>> {
        let n_layers = self.shape.w.len() - 1;
        let last = n_layers - 1;
        self.faces();
        if self.shape.crown {
            self.pass_bounds(0, 0);
            let mut lam = 0;
            for k in 1..n_layers {
                self.weight_magnitudes(k);
                lam = self.backward_pass(k);
                if k < last {
                    self.pass_bounds(k, lam);
                }
            }
            self.finish(lam);
            return self.ops;
        }
        for k in 0..n_layers {
            if k > 0 {
                self.forward_gemms(k);
                if self.shape.flags.record {
                    self.weight_magnitudes(k);
                }
            }
            if k < last {
                self.relu(k);
            }
        }
        let lam = if self.shape.flags.backward {
            self.backward_pass(last)
        } else {
            0
        };
        self.finish(lam);
        self.ops
    }
}

impl GpuBackend {
    fn buffers(
        &self,
        problem: &ReachProblem,
        shape: &Shape,
        margins: &MarginMap,
        chunk: usize,
    ) -> Result<Buffers, GpuError> {
        let d = &self.ctx.device;
        let bytes = self.precision.bytes();
        let b = chunk as u64;
        let sizes: std::collections::HashMap<&str, u64> = shape
            .per_box()
            .into_iter()
            .map(|(name, n, _)| (name, n * b * bytes))
            .collect();
        let limit = self.ctx.limits.max_buffer_size;
        if let Some((name, size)) = sizes.iter().find(|(_, &s)| s > limit) {
            return Err(GpuError::TooLarge(format!(
                "a chunk of {chunk} boxes needs {size} bytes in one buffer ({name})"
            )));
        }
        let (net, _) = flatten_network(&problem.network);
        let flags = flag_words(chunk) as u64 * 4;
        let sz = |name: &str| sizes.get(name).copied().unwrap_or(4);
        let (snap, state) = (sz("snap"), sz("state"));
        Ok(Buffers {
            net: storage_init(d, "net", &device_bytes(&net, self.precision)),
            state: storage(d, "state", state),
            flags: storage(d, "flags", flags),
            snap: storage(d, "snap", snap),
            c: [storage(d, "c0", sz("forms")), storage(d, "c1", sz("forms"))],
            r: [storage(d, "r0", sz("forms")), storage(d, "r1", sz("forms"))],
            aux: storage(d, "aux", sz("aux")),
            aux_g: storage(d, "aux_g", sz("aux")),
            pre: storage(d, "pre", sz("pre")),
            wm: storage(d, "wm", sz("wm")),
            lam: [storage(d, "lam0", sz("lam")), storage(d, "lam1", sz("lam"))],
            beta: storage(d, "beta", sz("beta")),
            nnb: storage(d, "nnb", sz("nnb")),
            faces: storage(d, "faces", sz("faces")),
            map_index: storage_init(
                d,
                "map_index",
                &padded(bytemuck::cast_slice(&margins.index)),
            ),
            map_cells: storage_init(
                d,
                "map_cells",
                &padded(&device_bytes(&margins.device_reals(), self.precision)),
            ),
            staging: d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staging"),
                size: (snap + state + flags).next_multiple_of(8),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        })
    }

    /// Runs every step for one chunk of boxes and reads its results back.
    #[allow(clippy::too_many_arguments)]
    fn run_chunk(
        &self,
        problem: &ReachProblem,
        shape: &Shape,
        kernels: &Kernels,
        bufs: &Buffers,
        boxes: &[IntervalBox],
        slots: usize,
        progress: &dyn Fn(usize),
    ) -> Result<ChunkResult, GpuError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let prec = self.precision;
        let n = problem.dynamics.n;
        let sw = 2 * n + 1;
        // Initial states, rounded outward to the device's numbers.
        let mut init = Vec::with_capacity(boxes.len() * sw);
        for b in boxes {
            init.extend(b.lower.iter().map(|&v| round_down(v, prec)));
            init.extend(b.upper.iter().map(|&v| round_up(v, prec)));
            init.push(0.0);
        }
        if init.iter().any(|v| v.abs() > 1e30) {
            return Err(GpuError::Problem("an initial box exceeds 1e30".into()));
        }
        q.write_buffer(&bufs.state, 0, &device_bytes(&init, prec));
        q.write_buffer(
            &bufs.flags,
            0,
            bytemuck::cast_slice(&vec![0u32; flag_words(boxes.len())]),
        );

        let plan = StepPlan {
            device: d,
            kernels,
            bufs,
            shape,
            offsets: flatten_network(&problem.network).1,
            nb: (shape.faces * boxes.len()) as u32,
            boxes: boxes.len() as u32,
            ops: Vec::new(),
        };
        let ops = plan.build();
        let limit = self.ctx.limits.max_compute_workgroups_per_dimension;
        if let Some(op) = ops.iter().find(|op| op.groups.iter().any(|&g| g > limit)) {
            return Err(GpuError::TooLarge(format!(
                "a dispatch of {:?} workgroups exceeds the device's {limit}",
                op.groups
            )));
        }

        let steps = problem.steps;
        let mut done = 0;
        while done < steps {
            let batch = STEPS_PER_SUBMIT.min(steps - done);
            q.submit([encode_steps(d, ops.iter(), batch)]);
            self.ctx.wait()?;
            done += batch;
            progress(done);
        }

        // One readback: snapshots, final states, flags.
        let bytes = prec.bytes();
        let snap_bytes = (slots * boxes.len() * sw) as u64 * bytes;
        let state_bytes = (boxes.len() * sw) as u64 * bytes;
        let flag_bytes = (flag_words(boxes.len()) * 4) as u64;
        let mut enc = d.create_command_encoder(&Default::default());
        enc.copy_buffer_to_buffer(&bufs.snap, 0, &bufs.staging, 0, snap_bytes);
        enc.copy_buffer_to_buffer(&bufs.state, 0, &bufs.staging, snap_bytes, state_bytes);
        enc.copy_buffer_to_buffer(
            &bufs.flags,
            0,
            &bufs.staging,
            snap_bytes + state_bytes,
            flag_bytes,
        );
        q.submit([enc.finish()]);
        let total = snap_bytes + state_bytes + flag_bytes;
        let slice = bufs.staging.slice(0..total);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.ctx.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Device(e.to_string()))?
            .map_err(|e| GpuError::Device(e.to_string()))?;
        let result = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Device(e.to_string()))?;
            let bytes: &[u8] = &view;
            let (a, rest) = bytes.split_at(snap_bytes as usize);
            let (b, c) = rest.split_at(state_bytes as usize);
            ChunkResult {
                snap: from_device_bytes(a, prec),
                state: from_device_bytes(b, prec),
                flags: bytemuck::pod_collect_to_vec(c),
            }
        };
        bufs.staging.unmap();
        // The loop check is the last word.
        if result.flags.last().is_some_and(|&w| w != 0) {
            return Err(GpuError::Device(format!(
                "the device's driver ({}) cut the embedding kernel's loops short (llvmpipe ends \
                 an invocation's loops after {LLVMPIPE_LOOP_LIMIT} iterations in all); its sets \
                 cannot be trusted: run this problem on the CPU (--backend cpu)",
                self.ctx.info.name
            )));
        }
        if self.profile {
            self.profile_step(&ops, boxes.len())?;
        }
        Ok(result)
    }

    /// Times one step's dispatches by kernel (each kind repeated on its own, then the whole
    /// step) and prints ms per step, share and GFLOP/s of the GEMMs to stderr. The repeats
    /// overwrite the chunk's buffers, so this runs after its readback.
    fn profile_step(&self, ops: &[Op], boxes: usize) -> Result<(), GpuError> {
        const REPEATS: usize = 10;
        let time = |ops: &[&Op]| -> Result<f64, GpuError> {
            let commands = encode_steps(&self.ctx.device, ops.iter().copied(), REPEATS);
            self.ctx.wait()?;
            let start = Instant::now();
            self.ctx.queue.submit([commands]);
            self.ctx.wait()?;
            Ok(start.elapsed().as_secs_f64() * 1e3 / REPEATS as f64)
        };
        let all: Vec<&Op> = ops.iter().collect();
        let step_ms = time(&all)?;
        eprintln!(
            "profile ({boxes} boxes, {} dispatches a step): {step_ms:.3} ms a step",
            ops.len()
        );
        let mut names: Vec<&str> = ops.iter().map(|o| o.kernel.name).collect();
        names.sort_unstable();
        names.dedup();
        for name in names {
            let group: Vec<&Op> = ops.iter().filter(|o| o.kernel.name == name).collect();
            let ms = time(&group)?;
            eprintln!(
                "  {name:<12} {:>3}×  {ms:>9.3} ms  {:>5.1}%",
                group.len(),
                100.0 * ms / step_ms
            );
        }
        for op in ops {
            if let Some([rows, inner, cols]) = op.gemm {
                let ms = time(&[op])?;
                let flops = 2.0 * rows as f64 * inner as f64 * cols as f64;
                eprintln!(
                    "    gemm {rows} × {inner} · {inner} × {cols}: {ms:.3} ms, {:.0} GFLOP/s",
                    flops / ms / 1e6
                );
            }
        }
        Ok(())
    }
}

/// One command buffer that runs `ops` (a step's dispatches, or some of them) `repeats` times.
fn encode_steps<'o, 'k: 'o>(
    device: &wgpu::Device,
    ops: impl Iterator<Item = &'o Op<'k>> + Clone,
    repeats: usize,
) -> wgpu::CommandBuffer {
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        for _ in 0..repeats {
            for op in ops.clone() {
                pass.set_pipeline(&op.kernel.pipeline);
                pass.set_bind_group(0, &op.bind, &[]);
                pass.dispatch_workgroups(op.groups[0], op.groups[1], op.groups[2]);
            }
        }
    }
    enc.finish()
}

/// A tube's samples from a chunk's readback (the CPU engine's recording rules).
fn fill_tube(
    problem: &ReachProblem,
    safe: &SafeSet,
    tube: &mut Tube,
    res: &ChunkResult,
    g: usize,
    nb: usize,
    every: usize,
) {
    let n = problem.dynamics.n;
    let sw = 2 * n + 1; // a box's record: lower, upper, radius
    let steps = problem.steps;
    let st = res.flags[FLAG_W * g + 1];
    let stop = res.flags[FLAG_W * g + 2] as usize + 1; // 1-based step at which it stopped
    tube.exact_steps = res.flags[FLAG_W * g + 3] as usize;
    tube.enclosed_steps = res.flags[FLAG_W * g + 4] as usize;
    let read = |v: &[f64]| -> (Vec<f64>, Vec<f64>, f64) {
        (v[..n].to_vec(), v[n..2 * n].to_vec(), v[2 * n])
    };
    for (slot, s) in (1..=steps)
        .filter(|s| s % every == 0 || *s == steps)
        .enumerate()
    {
        if st != status::LIVE && s >= stop {
            break;
        }
        let at = (slot * nb + g) * sw;
        let (lo, hi, r) = read(&res.snap[at..at + sw]);
        tube.tube
            .push(problem.tube_sample(&lo, &hi, r, s as f64 * problem.dt, safe));
    }
    let t = stop as f64 * problem.dt;
    match st {
        status::NO_BOUND => {
            // The step's start, as the CPU engine reports it.
            tube.valid = false;
            tube.note = Some(format!(
                "t = {:.3}: the set meets cells of the error map with no certified bound (M = ∞)",
                t - problem.dt
            ));
        }
        status::LEFT_REGION => {
            let (lo, hi, r) = read(&res.state[g * sw..(g + 1) * sw]);
            tube.valid = false;
            tube.note = Some(format!("t = {t:.3}: the set left the region C"));
            tube.tube.push(problem.tube_sample(&lo, &hi, r, t, safe));
        }
        status::INVERTED | status::NON_FINITE => {
            tube.valid = false;
            tube.note = Some(format!(
                "t = {t:.3}: the embedding state became {} (Euler step too large for this system?)",
                if st == status::INVERTED {
                    "inverted"
                } else {
                    "non-finite"
                }
            ));
        }
        _ => {}
    }
}

/// `bytes` padded with zeros to a non-empty multiple of 8 (a buffer may not be empty).
fn padded(bytes: &[u8]) -> Vec<u8> {
    let mut v = bytes.to_vec();
    v.resize(bytes.len().max(8).next_multiple_of(8), 0);
    v
}

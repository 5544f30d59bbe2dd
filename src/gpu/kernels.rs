//! The compute pipelines, one struct each, built once per problem (the dynamics are spliced
//! into the WGSL as generated code, `codegen`).
//!
//! Every shader is written once in terms of `real`; a precision prelude
//! (`shaders/real_f32.wgsl` or `shaders/real_f64.wgsl`) fixes the type and its rounding unit, so
//! the f32 and f64 engines share one source.

use super::{GpuError, Precision};

pub(crate) const REAL_F32: &str = include_str!("../../shaders/real_f32.wgsl");
pub(crate) const REAL_F64: &str = include_str!("../../shaders/real_f64.wgsl");
pub(crate) const F32_BITS: &str = include_str!("../../shaders/f32_bits.wgsl");
pub(crate) const COMMON: &str = include_str!("../../shaders/common.wgsl");
pub(crate) const PARAMS: &str = include_str!("../../shaders/params.wgsl");
pub(crate) const BOX: &str = include_str!("../../shaders/box.wgsl");
pub(crate) const GEMM: &str = include_str!("../../shaders/gemm.wgsl");
const RELU: &str = include_str!("../../shaders/relu.wgsl");
/// The first layer's forms, a face's pinned coordinates folded (relu and output kernels).
pub(crate) const FOLD: &str = include_str!("../../shaders/fold.wgsl");
const BACKWARD: &str = include_str!("../../shaders/backward.wgsl");
const OUTPUT: &str = include_str!("../../shaders/output.wgsl");
const EMBED: &str = include_str!("../../shaders/embed.wgsl");
/// The field on a face or slab, shared by the embedding kernel and the probes.
pub(crate) const FIELD: &str = include_str!("../../shaders/field.wgsl");
const FACES: &str = include_str!("../../shaders/faces.wgsl");
pub(crate) const FILTER: &str = include_str!("../../shaders/filter.wgsl");
pub(crate) const MARGINS: &str = include_str!("../../shaders/margins.wgsl");
pub(crate) const TURN: &str = include_str!("../../shaders/turn.wgsl");
pub(crate) const SETS: &str = include_str!("../../shaders/sets.wgsl");
const SETTLE: &str = include_str!("../../shaders/settle.wgsl");
pub(crate) const PHI: &str = include_str!("../../shaders/phi.wgsl");
/// The continuous step's guessed moving box.
pub(crate) const VALIDATED: &str = include_str!("../../shaders/validated.wgsl");
/// The curved rates' barrier.
pub(crate) const END_RATES: &str = include_str!("../../shaders/end_rates.wgsl");
/// The curved rates around the barrier.
pub(crate) const CURVED: &str = include_str!("../../shaders/curved.wgsl");
/// One box-step of the continuous model's common path (the continuous kernels' and
/// [`super::probe_field`]'s).
pub(crate) const SLAB_STEP: &str = include_str!("../../shaders/slab_step.wgsl");
/// The network's bounds per bound box, as the embedding and continuous kernels read them.
const NNB: &str = include_str!("../../shaders/nnb.wgsl");
/// The loop-limit check of the embedding and continuous kernels.
const LOOPS: &str = include_str!("../../shaders/loops.wgsl");
/// The continuous model's slabs and box-step (shaders/continuous.wgsl).
const CONTINUOUS: &str = include_str!("../../shaders/continuous.wgsl");
/// A box's continuous-time state and its guessed moving box (shaders/guess.wgsl).
pub(crate) const GUESS: &str = include_str!("../../shaders/guess.wgsl");
/// The continuous model's meet of two frames (shaders/cmeet.wgsl).
const CMEET: &str = include_str!("../../shaders/cmeet.wgsl");

/// Workgroup size of the one-dimensional kernels (`@workgroup_size(64)` in the shaders).
pub const WORKGROUP: u32 = 64;
/// Output tile of the GEMM kernel (64 × 64), the columns of the narrowest tile.
pub const GEMM_TILE: u32 = 64;
/// Output tile of `gemm_wide` (rows × columns: 64 × 256; `WM`, `WN` in shaders/gemm.wgsl).
pub const GEMM_WIDE_TILE: [u32; 2] = [64, 256];
/// Rows and columns of the block of Y one thread of `gemm_flat` writes.
pub const GEMM_FLAT_BLOCK: u32 = 4;

/// Which kernel computes the GEMMs `Y = op(W)·X` (shaders/gemm.wgsl). All three sum every
/// output over `k` in ascending order, so they give the same `Y` (tests/gpu_pipelines.rs).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, clap::ValueEnum)]
pub enum Gemm {
    /// `gemm_flat`: a 4 × 4 block of Y a thread, no workgroup memory or barriers: for software
    /// adapters, whose barriers are coroutine switches (docs/design.md §4).
    Flat,
    /// `gemm`: 64 × 64 tiles, 16 × 16 threads with 4 × 4 outputs each, depth 16.
    Tiles,
    /// `gemm_wide`: 64 × 256 tiles, 8 × 32 threads with 8 × 8 outputs each, depth 8, operands
    /// read from workgroup memory as vectors: twice the products per workgroup-memory read of
    /// `Tiles` (1 byte a multiply–add in f32, what an SM's workgroup memory delivers).
    Wide,
}

impl Gemm {
    /// The entry point in shaders/gemm.wgsl.
    pub fn entry(self) -> &'static str {
        match self {
            Gemm::Flat => "gemm_flat",
            Gemm::Tiles => "gemm",
            Gemm::Wide => "gemm_wide",
        }
    }

    /// Workgroups of a `rows × cols` product (WebGPU's least limit of 65,535 a dimension kept
    /// by spreading the flat kernel's over two).
    pub fn groups(self, rows: u32, cols: u32) -> [u32; 3] {
        match self {
            Gemm::Flat => {
                let g = (rows.div_ceil(GEMM_FLAT_BLOCK) * cols.div_ceil(GEMM_FLAT_BLOCK))
                    .div_ceil(WORKGROUP);
                let x = g.clamp(1, 65_535);
                [x, g.div_ceil(x), 1]
            }
            Gemm::Tiles => [cols.div_ceil(GEMM_TILE), rows.div_ceil(GEMM_TILE), 1],
            Gemm::Wide => {
                let [tm, tn] = GEMM_WIDE_TILE;
                [cols.div_ceil(tn), rows.div_ceil(tm), 1]
            }
        }
    }
}

/// What a problem's pipelines are compiled with: `settle` for the first of two frames met
/// after every step, the GEMM kernel, the continuous model's kernels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Variant {
    /// The meet of two frames (shaders/settle.wgsl, or in continuous time shaders/cmeet.wgsl).
    pub settle: bool,
    /// The GEMM kernel.
    pub gemm: Gemm,
    /// The continuous model's kernels (shaders/continuous.wgsl).
    pub continuous: bool,
}

/// A pipeline with its bind-group layout.
pub struct Kernel {
    /// The entry point's name (`bench --profile` reports time per kernel).
    pub name: &'static str,
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Layout of group 0.
    pub layout: wgpu::BindGroupLayout,
}

/// Every pipeline of the engine.
pub struct Kernels {
    /// `Y = op(W)·X` (shaders/gemm.wgsl), the entry point of `gemm_kind`.
    pub gemm: Kernel,
    /// Which GEMM kernel `gemm` is.
    pub gemm_kind: Gemm,
    /// Bias, rounding widening, IBP and ReLU relaxation of a hidden layer (shaders/relu.wgsl).
    pub relu: Kernel,
    /// One backward substitution's per-box part: `Λ∘s`, `β` (shaders/backward.wgsl).
    pub bwd_scale: Kernel,
    /// Concrete bounds of a finished backward pass (shaders/backward.wgsl).
    pub bwd_bounds: Kernel,
    /// The network's bounds over each box (shaders/output.wgsl).
    pub output: Kernel,
    /// Embedding field, radius, Euler step, region check, snapshot (shaders/embed.wgsl).
    pub embed: Kernel,
    /// Advances the device's step counter (shaders/embed.wgsl, `tick`).
    pub tick: Kernel,
    /// The 2n face boxes of every box, for face-local bounds (shaders/faces.wgsl).
    pub faces: Kernel,
    /// The meet of two frames after an Euler step (shaders/settle.wgsl), where frames are met.
    pub settle: Option<Kernel>,
    /// The continuous model's slab and step kernels (shaders/continuous.wgsl), for its runs.
    pub continuous: Option<Continuous>,
}

/// The continuous model's kernels.
pub struct Continuous {
    /// Each live box's slabs (or hull) as its bound boxes.
    pub slabs: Kernel,
    /// The box-step of the common path.
    pub step: Kernel,
    /// Where two frames are met (the first frame's kernels): both frames' moving boxes guessed
    /// and met before the step, and the sets met after it (shaders/cmeet.wgsl).
    pub meet: Option<[Kernel; 2]>,
}

/// Which of a problem's modules a run compiles: `settle` for the first of two frames met after
/// every step (shaders/settle.wgsl, or in continuous time shaders/cmeet.wgsl), `continuous` for
/// the continuous time model.
pub fn compiles(module: &str, v: Variant) -> bool {
    let (settle, continuous) = (v.settle, v.continuous);
    match module {
        "settle" => settle && !continuous,
        "cmeet" => settle && continuous,
        "continuous" => continuous,
        _ => true,
    }
}

/// Binding kinds after the uniform at binding 0: `true` = read-only storage.
fn layout(device: &wgpu::Device, label: &str, read_only: &[bool]) -> wgpu::BindGroupLayout {
    let mut entries = vec![wgpu::BindGroupLayoutEntry {
        binding: 0,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }];
    for (k, &ro) in read_only.iter().enumerate() {
        entries.push(wgpu::BindGroupLayoutEntry {
            binding: k as u32 + 1,
            visibility: wgpu::ShaderStages::COMPUTE,
            ty: wgpu::BindingType::Buffer {
                ty: wgpu::BufferBindingType::Storage { read_only: ro },
                has_dynamic_offset: false,
                min_binding_size: None,
            },
            count: None,
        });
    }
    device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
        label: Some(label),
        entries: &entries,
    })
}

fn kernel(
    device: &wgpu::Device,
    cache: Option<&wgpu::PipelineCache>,
    module: &wgpu::ShaderModule,
    entry: &'static str,
    read_only: &[bool],
) -> Kernel {
    let layout = layout(device, entry, read_only);
    let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
        label: Some(entry),
        bind_group_layouts: &[Some(&layout)],
        immediate_size: 0,
    });
    let pipeline = device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
        label: Some(entry),
        layout: Some(&pl),
        module,
        entry_point: Some(entry),
        compilation_options: Default::default(),
        cache,
    });
    Kernel {
        name: entry,
        pipeline,
        layout,
    }
}

/// A pipeline to build: its module, entry point and bindings' kinds ([`layout`]).
type Job<'m> = (&'m wgpu::ShaderModule, &'static str, &'static [bool]);

/// Builds `jobs`' pipelines, in their order, each on a thread of its own: drivers compile
/// pipelines independently, and the few that hold the filter's closed form take most of a
/// problem's compile (`embed` and `cstep` ~5 s each of scenario 1's ~11 s on lavapipe; ~70 s
/// in all on an NVIDIA driver), so a run waits for the slowest pipeline, not for their sum.
/// Error scopes are per thread in wgpu: each thread pops its own.
fn kernels_in_parallel(
    device: &wgpu::Device,
    cache: Option<&wgpu::PipelineCache>,
    jobs: &[Job<'_>],
) -> Result<Vec<Kernel>, GpuError> {
    let build = |&(module, entry, read_only): &Job<'_>| {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let k = kernel(device, cache, module, entry, read_only);
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Shader(e.to_string())),
            None => Ok(k),
        }
    };
    std::thread::scope(|s| {
        let threads: Vec<_> = jobs
            .iter()
            .map(|job| {
                // Translating a large shader recurses deeply (wgpu's note on stack space).
                std::thread::Builder::new()
                    .stack_size(64 << 20)
                    .spawn_scoped(s, move || build(job))
            })
            .collect();
        jobs.iter()
            .zip(threads)
            .map(|(job, thread)| match thread {
                Ok(t) => t.join().unwrap_or_else(|_| {
                    Err(GpuError::Device(format!("compiling {} panicked", job.1)))
                }),
                // No thread to be had: build it here.
                Err(_) => build(job),
            })
            .collect()
    })
}

/// Every module [`Kernels::new`] compiles (`settle` where two frames are met, `continuous` for
/// the continuous time model).
pub const MODULES: [&str; 9] = [
    "gemm",
    "relu",
    "backward",
    "output",
    "faces",
    "embed",
    "settle",
    "continuous",
    "cmeet",
];

/// The precision prelude (`real`, its unit, `up` and `down`) of `precision`'s shaders.
pub(crate) fn prelude(precision: Precision) -> &'static str {
    match precision {
        Precision::F32 => REAL_F32,
        Precision::F64 => REAL_F64,
    }
}

/// The WGSL of a module: the precision prelude, shared helpers, the generated problem constants
/// and the module's kernels (`gemm`, `relu`, `backward`, `output`, `faces`, `settle`,
/// `continuous`, `cmeet`, `embed`).
pub fn shader_source(precision: Precision, problem_wgsl: &str, module: &str) -> String {
    let mut s = String::new();
    for part in [prelude(precision), F32_BITS, PARAMS, COMMON, problem_wgsl] {
        s.push_str(part);
        s.push('\n');
    }
    let body: &[&str] = match module {
        "gemm" => &[GEMM],
        "relu" => &[BOX, FOLD, RELU],
        "backward" => &[BOX, BACKWARD],
        "output" => &[BOX, FOLD, OUTPUT],
        "faces" => &[BOX, FACES],
        "settle" => &[SETS, SETTLE],
        "continuous" => &[
            SETS, FILTER, MARGINS, FIELD, VALIDATED, END_RATES, CURVED, GUESS, SLAB_STEP, NNB,
            LOOPS, CONTINUOUS,
        ],
        "cmeet" => &[SETS, VALIDATED, GUESS, CMEET],
        _ => &[
            BOX, SETS, FILTER, MARGINS, PHI, TURN, FIELD, NNB, LOOPS, EMBED,
        ],
    };
    for part in body {
        s.push_str(part);
        s.push('\n');
    }
    s
}

impl Kernels {
    /// Compiles every pipeline for a problem's generated WGSL (the modules [`compiles`] names),
    /// through
    /// `cache` where given (`disk_cache`), with `variant`'s GEMM kernel and modules;
    /// shader errors become [`GpuError::Shader`].
    pub fn new(
        device: &wgpu::Device,
        cache: Option<&wgpu::PipelineCache>,
        precision: Precision,
        problem_wgsl: &str,
        variant: Variant,
    ) -> Result<Kernels, GpuError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        // wgpu's default guard on every loop (an iteration counter, against infinite loops)
        // keeps the NVIDIA compiler from unrolling the GEMM's inner loops and from keeping its
        // accumulators in registers: measured on an H100, the GEMMs ran at 0.3 TFLOP/s with it
        // (gfx-rs/wgpu#7698). Bounds checks stay on.
        let checks = wgpu::ShaderRuntimeChecks {
            force_loop_bounding: false,
            ..wgpu::ShaderRuntimeChecks::checked()
        };
        let module = |name: &str| {
            let desc = wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(
                    shader_source(precision, problem_wgsl, name).into(),
                ),
            };
            // SAFETY: without the loop guard an infinite loop would be undefined behaviour;
            // every loop in shaders/ and in the generated code ends: `for` loops step a counter
            // by 1 (the GEMM's by its tile depth, towards a width ≤ 2¹⁸ checked in
            // `GpuBackend::reach`, so it cannot wrap) towards a bound they stop at, the ones in
            // real_f64.wgsl count down to 0, and the error map's walk (margins.wgsl) runs
            // binary searches that narrow a range and pops a stack of blocks that only
            // descends the structure's levels.
            unsafe { device.create_shader_module_trusted(desc, checks) }
        };
        let (gemm_m, relu_m, bwd_m, out_m, faces_m, embed_m) = (
            module("gemm"),
            module("relu"),
            module("backward"),
            module("output"),
            module("faces"),
            module("embed"),
        );
        let settle_m = compiles("settle", variant).then(|| module("settle"));
        let cont_m = compiles("continuous", variant).then(|| module("continuous"));
        let meet_m = compiles("cmeet", variant).then(|| module("cmeet"));
        if let Some(e) = pollster::block_on(scope.pop()) {
            return Err(GpuError::Shader(e.to_string()));
        }
        const BACKWARD: &[bool] = &[true, true, false, true, false, false, false];
        const EMBED: &[bool] = &[false, true, false, false, true, true, true];
        // cont, nnb, flags, bound boxes, the error map's (margins.wgsl), pipe_known.
        const CONTINUOUS: &[bool] = &[false, true, false, false, true, true, true];
        let mut jobs: Vec<Job<'_>> = vec![
            (&gemm_m, variant.gemm.entry(), &[true, true, false]),
            (
                &relu_m,
                "relu",
                &[true, true, false, false, true, false, false, false],
            ),
            (&bwd_m, "bwd_scale", BACKWARD),
            (&bwd_m, "bwd_bounds", BACKWARD),
            (
                &out_m,
                "output",
                &[true, true, true, true, true, true, true, false],
            ),
            (&embed_m, "embed", EMBED),
            (&embed_m, "tick", EMBED),
            (&faces_m, "faces_of", &[true, false]),
        ];
        if let Some(m) = &settle_m {
            jobs.push((m, "settle", &[false; 7]));
        }
        if let Some(m) = &cont_m {
            jobs.push((m, "slabs_of", CONTINUOUS));
            jobs.push((m, "cstep", CONTINUOUS));
        }
        if let Some(m) = &meet_m {
            jobs.push((m, "cpipes", &[false; 6]));
            jobs.push((m, "cmeet", &[false; 6]));
        }
        let mut built = kernels_in_parallel(device, cache, &jobs)?.into_iter();
        let mut next = || built.next().expect("one kernel a job");
        let (gemm, relu, bwd_scale, bwd_bounds, output) = (next(), next(), next(), next(), next());
        let (embed, tick, faces) = (next(), next(), next());
        let settle = settle_m.is_some().then(&mut next);
        let continuous = cont_m.is_some().then(|| {
            let (slabs, step) = (next(), next());
            Continuous {
                slabs,
                step,
                meet: meet_m.is_some().then(|| [next(), next()]),
            }
        });
        Ok(Kernels {
            gemm,
            gemm_kind: variant.gemm,
            relu,
            bwd_scale,
            bwd_bounds,
            output,
            embed,
            tick,
            faces,
            settle,
            continuous,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::{GEMM, GEMM_TILE, GEMM_WIDE_TILE, PARAMS, REAL_F32, REAL_F64};
    use crate::gpu::codegen::{HUGE, HUGE_F64};

    /// The value of `const {name}: … = …;` in WGSL source (suffixes `lf`, `u` dropped).
    fn constant(source: &str, name: &str) -> f64 {
        let line = source
            .lines()
            .find(|l| l.starts_with(&format!("const {name}: ")))
            .unwrap_or_else(|| panic!("no constant {name}"));
        let value = line.split('=').nth(1).unwrap().trim();
        value
            .trim_end_matches(';')
            .trim_end_matches("lf")
            .trim_end_matches('u')
            .parse()
            .unwrap()
    }

    /// One rounding model for both engines (`crate::rounding`): the f64 shaders bound a sum's
    /// rounding with the CPU's `γ̂_N`, so the engines' f64 sets agree to ~1e-14 a step.
    #[test]
    fn the_f64_shaders_bound_sums_as_the_cpu_does() {
        assert_eq!(
            constant(REAL_F64, "GAMMA_UNIT"),
            crate::rounding::GAMMA_UNIT
        );
        assert_eq!(constant(REAL_F64, "EPS"), f64::EPSILON);
    }

    /// The host's mirrors of shader constants: the largest number the preludes treat as one
    /// (the host rounds what it uploads into that range) and the GEMM tiles it dispatches by.
    #[test]
    fn host_mirrors_of_shader_constants_agree() {
        // The f32 prelude's literal is an f32.
        assert_eq!(constant(REAL_F32, "HUGE") as f32, HUGE);
        assert_eq!(constant(REAL_F64, "HUGE"), HUGE_F64);
        for name in ["TM", "TN"] {
            assert_eq!(constant(GEMM, name), f64::from(GEMM_TILE), "{name}");
        }
        assert_eq!(constant(GEMM, "WM"), f64::from(GEMM_WIDE_TILE[0]));
        assert_eq!(constant(GEMM, "WN"), f64::from(GEMM_WIDE_TILE[1]));
    }

    /// The host's `Params` (bytes cast as they are) has the uniform's fields, all `u32`, in the
    /// order of shaders/params.wgsl: a field out of order would be read as another.
    #[test]
    fn host_params_mirror_the_shaders_uniform() {
        let fields = |source: &str, start: &str| -> Vec<String> {
            let body = &source[source.find(start).expect(start) + start.len()..];
            let body = &body[..body.find('}').unwrap()];
            body.lines()
                .map(|l| l.trim().trim_start_matches("pub "))
                .filter(|l| !l.starts_with("//") && l.contains(':'))
                .map(|l| l.trim_end_matches(','))
                .map(String::from)
                .collect()
        };
        let host = include_str!("buffers.rs");
        let wgsl = fields(PARAMS, "struct Params {");
        assert_eq!(fields(host, "pub struct Params {"), wgsl);
        assert!(wgsl.iter().all(|f| f.ends_with(": u32")), "{wgsl:?}");
        assert_eq!(
            std::mem::size_of::<crate::gpu::buffers::Params>(),
            4 * wgsl.len()
        );
    }
}

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
const BOX: &str = include_str!("../../shaders/box.wgsl");
pub(crate) const GEMM: &str = include_str!("../../shaders/gemm.wgsl");
const RELU: &str = include_str!("../../shaders/relu.wgsl");
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
/// Output tile of the GEMM kernel (64 × 64).
pub const GEMM_TILE: u32 = 64;
/// Rows and columns of the block of Y one thread of `gemm_flat` writes.
pub const GEMM_FLAT_BLOCK: u32 = 4;

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
    /// `Y = op(W)·X`, tiled (shaders/gemm.wgsl), or `gemm_flat` where `flat`.
    pub gemm: Kernel,
    /// Whether `gemm` is `gemm_flat` (a 4 × 4 block a thread, no workgroup memory).
    pub flat: bool,
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
pub fn compiles(module: &str, [settle, _, continuous]: [bool; 3]) -> bool {
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

/// The WGSL of a module: the precision prelude, shared helpers, the generated problem constants
/// and the module's kernels (`gemm`, `relu`, `backward`, `output`, `faces`, `settle`,
/// `continuous`, `cmeet`, `embed`).
pub fn shader_source(precision: Precision, problem_wgsl: &str, module: &str) -> String {
    let prelude = match precision {
        Precision::F32 => REAL_F32,
        Precision::F64 => REAL_F64,
    };
    let mut s = String::new();
    for part in [prelude, F32_BITS, PARAMS, COMMON, problem_wgsl] {
        s.push_str(part);
        s.push('\n');
    }
    let body: &[&str] = match module {
        "gemm" => &[GEMM],
        "relu" => &[BOX, RELU],
        "backward" => &[BOX, BACKWARD],
        "output" => &[BOX, OUTPUT],
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
    /// `cache` where given (`disk_cache`), with the GEMM without workgroup tiles where `flat`;
    /// shader errors become [`GpuError::Shader`].
    pub fn new(
        device: &wgpu::Device,
        cache: Option<&wgpu::PipelineCache>,
        precision: Precision,
        problem_wgsl: &str,
        [settle, flat, continuous]: [bool; 3],
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
        let backward = [true, true, false, true, false, false, false];
        let embed = [false, true, false, false, true, true, true];
        let kernels = Kernels {
            gemm: kernel(
                device,
                cache,
                &gemm_m,
                if flat { "gemm_flat" } else { "gemm" },
                &[true, true, false],
            ),
            flat,
            relu: kernel(
                device,
                cache,
                &relu_m,
                "relu",
                &[true, true, false, false, true, false, false, false],
            ),
            bwd_scale: kernel(device, cache, &bwd_m, "bwd_scale", &backward),
            bwd_bounds: kernel(device, cache, &bwd_m, "bwd_bounds", &backward),
            output: kernel(
                device,
                cache,
                &out_m,
                "output",
                &[true, true, true, true, true, true, true, false],
            ),
            embed: kernel(device, cache, &embed_m, "embed", &embed),
            tick: kernel(device, cache, &embed_m, "tick", &embed),
            faces: kernel(device, cache, &faces_m, "faces_of", &[true, false]),
            settle: compiles("settle", [settle, flat, continuous])
                .then(|| kernel(device, cache, &module("settle"), "settle", &[false; 7])),
            continuous: continuous.then(|| {
                let m = module("continuous");
                // cont, nnb, flags, bound boxes, the error map's (margins.wgsl), pipe_known.
                let bindings = [false, true, false, false, true, true, true];
                let meet = compiles("cmeet", [settle, flat, continuous]).then(|| {
                    let m = module("cmeet");
                    let bindings = [false; 6];
                    [
                        kernel(device, cache, &m, "cpipes", &bindings),
                        kernel(device, cache, &m, "cmeet", &bindings),
                    ]
                });
                Continuous {
                    slabs: kernel(device, cache, &m, "slabs_of", &bindings),
                    step: kernel(device, cache, &m, "cstep", &bindings),
                    meet,
                }
            }),
        };
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Shader(e.to_string())),
            None => Ok(kernels),
        }
    }
}

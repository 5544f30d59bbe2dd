//! The compute pipelines, one struct each, built once per problem (the dynamics are spliced
//! into the WGSL as generated code, `codegen`).

use super::GpuError;

const COMMON: &str = include_str!("../../shaders/common.wgsl");
const PARAMS: &str = include_str!("../../shaders/params.wgsl");
const BOX: &str = include_str!("../../shaders/box.wgsl");
const GEMM: &str = include_str!("../../shaders/gemm.wgsl");
const RELU: &str = include_str!("../../shaders/relu.wgsl");
const EMBED: &str = include_str!("../../shaders/embed.wgsl");

/// Workgroup size of the one-dimensional kernels (`@workgroup_size(64)` in the shaders).
pub const WORKGROUP: u32 = 64;
/// Output tile of the GEMM kernel (64 × 64).
pub const GEMM_TILE: u32 = 64;

/// A pipeline with its bind-group layout.
pub struct Kernel {
    /// The pipeline.
    pub pipeline: wgpu::ComputePipeline,
    /// Layout of group 0.
    pub layout: wgpu::BindGroupLayout,
}

/// `Y = op(W)·X`, tiled (shaders/gemm.wgsl).
pub struct GemmKernel(pub Kernel);
/// Bias, rounding widening and ReLU relaxation of a hidden layer (shaders/relu.wgsl).
pub struct ReluKernel(pub Kernel);
/// Output bounds, embedding field, radius, Euler step, region check, snapshot
/// (shaders/embed.wgsl).
pub struct EmbedKernel(pub Kernel);
/// Advances the device's step counter (shaders/embed.wgsl, `tick`).
pub struct TickKernel(pub Kernel);

/// Every pipeline of the engine.
pub struct Kernels {
    /// GEMM.
    pub gemm: GemmKernel,
    /// ReLU.
    pub relu: ReluKernel,
    /// Embedding step.
    pub embed: EmbedKernel,
    /// Step counter.
    pub tick: TickKernel,
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
    module: &wgpu::ShaderModule,
    entry: &str,
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
        cache: None,
    });
    Kernel { pipeline, layout }
}

/// The WGSL of a kernel: shared helpers, the generated problem constants and the kernel.
pub fn shader_source(problem_wgsl: &str, kernel: &str) -> String {
    let mut s = String::new();
    for part in [PARAMS, COMMON, problem_wgsl] {
        s.push_str(part);
        s.push('\n');
    }
    match kernel {
        "gemm" => s.push_str(GEMM),
        "relu" => {
            s.push_str(BOX);
            s.push_str(RELU);
        }
        _ => {
            s.push_str(BOX);
            s.push_str(EMBED);
        }
    }
    s
}

impl Kernels {
    /// Compiles every pipeline for a problem's generated WGSL; shader errors become
    /// [`GpuError::Shader`].
    pub fn new(device: &wgpu::Device, problem_wgsl: &str) -> Result<Kernels, GpuError> {
        let scope = device.push_error_scope(wgpu::ErrorFilter::Validation);
        let module = |name: &str| {
            device.create_shader_module(wgpu::ShaderModuleDescriptor {
                label: Some(name),
                source: wgpu::ShaderSource::Wgsl(shader_source(problem_wgsl, name).into()),
            })
        };
        let (gemm_m, relu_m, embed_m) = (module("gemm"), module("relu"), module("embed"));
        let kernels = Kernels {
            gemm: GemmKernel(kernel(device, &gemm_m, "gemm", &[true, true, false])),
            relu: ReluKernel(kernel(
                device,
                &relu_m,
                "relu",
                &[true, true, false, false, true, false, false],
            )),
            embed: EmbedKernel(kernel(
                device,
                &embed_m,
                "embed",
                &[true, false, true, true, true, false, false],
            )),
            tick: TickKernel(kernel(
                device,
                &embed_m,
                "tick",
                &[true, false, true, true, true, false, false],
            )),
        };
        match pollster::block_on(scope.pop()) {
            Some(e) => Err(GpuError::Shader(e.to_string())),
            None => Ok(kernels),
        }
    }
}

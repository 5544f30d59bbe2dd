//! Single WGSL primitives run on the device, for tests against the Rust they mirror
//! (tests/gpu_matches_cpu/, tests/gpu_pipelines.rs): `turn_rate` (`shaders/turn.wgsl`, the
//! CPU's `euler_turn`), the GEMM kernels (tiled and flat) against each other, and the runner
//! that [`super::exp64`] shares.

use wgpu::util::DeviceExt;

use super::buffers::{uniform, Params};
use super::kernels::{
    COMMON, F32_BITS, GEMM, GEMM_FLAT_BLOCK, GEMM_TILE, PARAMS, REAL_F64, TURN, WORKGROUP,
};
use super::{GpuContext, GpuError};

/// `y` after one dispatch of the f64 GEMM kernel (`gemm`, or `gemm_flat` where `flat`) with
/// `p`'s shape and options (`rows`, `inner`, `cols`, `abs_w`, `trans_w`, `relu_x`, `w_off`,
/// `x_off`, `ldx`, `y_off`, `ldy`) on `net`, `x` and `y` (unwritten entries stay).
pub fn gemm_on_device(
    ctx: &GpuContext,
    flat: bool,
    p: &Params,
    net: &[f64],
    x: &[f64],
    y: &[f64],
) -> Result<Vec<f64>, GpuError> {
    if !ctx.has_f64() {
        return Err(GpuError::NoF64(ctx.info.name.clone()));
    }
    let source =
        format!("{REAL_F64}\n{F32_BITS}\n{PARAMS}\n{COMMON}\nconst ABS_UNIT: real = 0.0;\n{GEMM}");
    let entry = if flat { "gemm_flat" } else { "gemm" };
    let device = &ctx.device;
    let pipeline = compile(device, &source, entry)?;
    let storage = |label, data: &[f64], usage| {
        device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some(label),
            contents: bytemuck::cast_slice(data),
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
    // As the engine dispatches them (backend/plan.rs).
    let groups = if flat {
        let g = (p.rows.div_ceil(GEMM_FLAT_BLOCK) * p.cols.div_ceil(GEMM_FLAT_BLOCK))
            .div_ceil(WORKGROUP);
        [g, 1, 1]
    } else {
        [p.cols.div_ceil(GEMM_TILE), p.rows.div_ceil(GEMM_TILE), 1]
    };
    let mut enc = device.create_command_encoder(&Default::default());
    {
        let mut pass = enc.begin_compute_pass(&Default::default());
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind, &[]);
        pass.dispatch_workgroups(groups[0], groups[1], groups[2]);
    }
    ctx.queue.submit([enc.finish()]);
    read_back(ctx, &y_b, y.len())
}

/// `len` f64 of `buf` (a `COPY_SRC` buffer), after the queue's work.
pub fn read_back(ctx: &GpuContext, buf: &wgpu::Buffer, len: usize) -> Result<Vec<f64>, GpuError> {
    let device = &ctx.device;
    let size = (len * 8) as u64;
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
    Ok(bytemuck::pod_collect_to_vec(&view))
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
    if !ctx.has_f64() {
        return Err(GpuError::NoF64(ctx.info.name.clone()));
    }
    if xs.is_empty() || items == 0 {
        return Ok(Vec::new());
    }
    let device = &ctx.device;
    let pipeline = compile(device, source, entry)?;
    let input = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("probe xs"),
        contents: bytemuck::cast_slice(xs),
        usage: wgpu::BufferUsages::STORAGE,
    });
    let size = (per * items * 8) as u64;
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
    read_back(ctx, &output, per * items)
}

/// The compute pipeline of `entry` in `source`, with the layout the shader implies; a
/// validation error is the shader's.
fn compile(
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

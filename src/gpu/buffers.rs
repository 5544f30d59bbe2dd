//! Host-side images of what the kernels read (`#[repr(C)]`, bytemuck) and buffer helpers.
//!
//! Device layout of one chunk of `B` boxes (`n` states, `K = n + 1` columns per form):
//! - `state`: per box `lo[n], hi[n], r` (`2n + 1` f32, the embedding coordinates);
//! - `flags`: per box `[poisoned, status, stop step]` (u32), then the step counter;
//! - `snap`: per recorded slot and box the state, slot-major;
//! - forms `Ĉ, R̂`: `width × B·K`, neuron-major; magnitudes `V`: `width × B`.

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

/// Parameters of one dispatch; the same fields in the same order as `shaders/params.wgsl`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub struct Params {
    /// GEMM rows (a layer's output width).
    pub rows: u32,
    /// GEMM inner dimension (a layer's input width).
    pub inner: u32,
    /// GEMM columns.
    pub cols: u32,
    /// 1: multiply by `|W|`.
    pub abs_w: u32,
    /// Offset of the layer's `W` in the network buffer.
    pub w_off: u32,
    /// Offset of its `b`.
    pub b_off: u32,
    /// Its input width.
    pub n_prev: u32,
    /// 1 for the first layer.
    pub first: u32,
    /// Boxes in the chunk.
    pub boxes: u32,
    /// Padding to 16 bytes.
    pub pad: [u32; 3],
}

/// Box status codes written by the embedding kernel.
pub mod status {
    /// Still integrating.
    pub const LIVE: u32 = 0;
    /// The set left the region `C`.
    pub const LEFT_REGION: u32 = 1;
    /// The embedding state became inverted.
    pub const INVERTED: u32 = 2;
    /// A bound overflowed.
    pub const NON_FINITE: u32 = 3;
}

/// A storage buffer of `bytes` bytes (at least 4).
pub fn storage(device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(4).next_multiple_of(4),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// A storage buffer holding `data`.
pub fn storage_init<T: Pod>(device: &wgpu::Device, label: &str, data: &[T]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytemuck::cast_slice(data),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
    })
}

/// A uniform buffer holding one [`Params`].
pub fn uniform(device: &wgpu::Device, label: &str, p: &Params) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: bytemuck::bytes_of(p),
        usage: wgpu::BufferUsages::UNIFORM,
    })
}

/// The network as one f32 array (each layer's `W` row-major, then its `b`) and the offsets.
pub fn flatten_network(net: &crate::network::Mlp) -> (Vec<f32>, Vec<(u32, u32)>) {
    let mut data = Vec::new();
    let mut offsets = Vec::new();
    for layer in &net.layers {
        let w_off = data.len() as u32;
        data.extend(layer.weight.iter().map(|&w| w as f32));
        let b_off = data.len() as u32;
        data.extend(layer.bias.iter().map(|&b| b as f32));
        offsets.push((w_off, b_off));
    }
    (data, offsets)
}

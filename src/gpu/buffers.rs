//! Host-side images of what the kernels read (`#[repr(C)]`, bytemuck) and buffer helpers.
//!
//! Device layout of one chunk of `B` boxes (`n` states, `K = n + 1` columns per form), every
//! number a `real` (f32, or f64 with `--f64`):
//! - `state`: per box `lo[n], hi[n], r` (`2n + 1` reals, the embedding coordinates);
//! - `flags`: per box `[poisoned, status, stop step]` (u32), then the step counter;
//! - `snap`: per recorded slot and box the state, slot-major;
//! - forms `Ĉ, R̂`: `width × B·K`, neuron-major; per-neuron vectors `aux` (form magnitude `V`,
//!   IBP centre, radius and magnitude): `width × 4B`;
//! - `pre`: per layer its pre-activation bounds `l, u` (`n_k × B` each); `wm`: per layer
//!   `|W_k| max(u_{k−1}, 0)` (`n_k × B`);
//! - `Λ`: `height × B·R` (neuron-major, `R` rows per box), `β`: `2 × B·R`;
//! - `nnb`: per bound box the network's bounds (`codegen::nnb_width`); with face-local bounds
//!   the bound boxes are the `2n` faces of each box (`faces`, `2n` states per box), and every
//!   per-box array of the bound kernels above has `2n·B` boxes;
//! - `map_index`, `map_cells`: the error map for local margins (`margins::MarginMap`).

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use super::Precision;

/// Parameters of one dispatch; the same fields in the same order as `shaders/params.wgsl`
/// (whose comments say what each kernel reads from them).
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
    /// 1 for the first layer, or the first substitution of a backward pass.
    pub first: u32,
    /// Boxes in the chunk.
    pub boxes: u32,
    /// GEMM: 1 for `Wᵀ`.
    pub trans_w: u32,
    /// GEMM: 1 to read `X` through `max(·, 0)`.
    pub relu_x: u32,
    /// GEMM: offset of `X` in its buffer.
    pub x_off: u32,
    /// GEMM: row stride of `X`.
    pub ldx: u32,
    /// GEMM: offset of `Y` in its buffer.
    pub y_off: u32,
    /// GEMM: row stride of `Y`.
    pub ldy: u32,
    /// Backward passes: columns of `Λ` per box.
    pub rpb: u32,
    /// Offset of the layer's recorded `l` (then `u`) in `pre`.
    pub pre_off: u32,
    /// Offset of the layer's `|W| max(u_prev, 0)` in `wm`.
    pub wm_off: u32,
    /// Offset of the previous layer's `u` in `pre`.
    pub prev_u_off: u32,
    /// 1 when the layer's input is the box itself.
    pub at_input: u32,
    /// The backward pass's start layer `k`: offset of `W_k`.
    pub k_w_off: u32,
    /// Offset of `b_k`.
    pub k_b_off: u32,
    /// `n_k`.
    pub k_rows: u32,
    /// Offset of layer `k`'s `|W| max(u_prev, 0)` in `wm`.
    pub k_wm_off: u32,
    /// The embedding step: [`LOOP_CHECK`], the trip count of its loop-limit check.
    pub loop_check: u32,
    /// Offset of the fold constants in the network buffer ([`FlatNetwork`]).
    pub fold_off: u32,
    /// 1 for the layer after the first (forward forms): `R̂` takes `rowsum(|W|)·ε` of the
    /// first layer's fold.
    pub carry: u32,
}

/// Iterations of the embedding kernel's last loop (`loops_ran_in_full` in
/// shaders/embed.wgsl): a driver that cut the invocation's loops short runs it once.
pub const LOOP_CHECK: u32 = 2;

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
    /// The set met error-map cells with no certified bound (`M = ∞`, local margins).
    pub const NO_BOUND: u32 = 4;
}

/// A storage buffer of `bytes` bytes (at least 16, a multiple of 8).
pub fn storage(device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(16).next_multiple_of(8),
        usage: wgpu::BufferUsages::STORAGE
            | wgpu::BufferUsages::COPY_DST
            | wgpu::BufferUsages::COPY_SRC,
        mapped_at_creation: false,
    })
}

/// A storage buffer holding `data`.
pub fn storage_init(device: &wgpu::Device, label: &str, data: &[u8]) -> wgpu::Buffer {
    device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some(label),
        contents: data,
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

/// Where each part of the network lies in the kernels' network buffer ([`flatten_network`]).
#[derive(Clone, Debug)]
pub struct NetworkOffsets {
    /// Every layer's `W` (row-major) and `b`.
    pub layers: Vec<(u32, u32)>,
    /// The constants of a face's folded first layer, after the layers: `max|b₀|`, `max|W₀|`
    /// per input (`bounds::FoldBound`), then the row sums of `|W₁|` (`bounds::abs_row_sums`;
    /// none for a one-layer network).
    pub fold: u32,
}

/// The network buffer's numbers: each layer's `W` then `b`, then the fold constants
/// ([`NetworkOffsets`]).
pub struct FlatNetwork {
    /// The numbers, in f64.
    pub data: Vec<f64>,
    /// Where each part lies.
    pub offsets: NetworkOffsets,
}

impl FlatNetwork {
    /// The data in the device's type. The weights are rounded to nearest in f32 (their
    /// conversion error the kernels bound); the fold constants, bounds themselves, upwards.
    pub fn device_bytes(&self, precision: Precision) -> Vec<u8> {
        let (weights, bounds) = self.data.split_at(self.offsets.fold as usize);
        let mut bytes = device_bytes(weights, precision);
        let bounds: Vec<f64> = match precision {
            Precision::F32 => bounds
                .iter()
                .map(|&x| f64::from(super::codegen::f32_up(x)))
                .collect(),
            Precision::F64 => bounds.to_vec(),
        };
        bytes.extend(device_bytes(&bounds, precision));
        bytes
    }
}

/// The network buffer's numbers ([`FlatNetwork`]).
pub fn flatten_network(net: &crate::network::Mlp) -> FlatNetwork {
    let mut data = Vec::new();
    let mut layers = Vec::with_capacity(net.layers.len());
    for layer in &net.layers {
        let w_off = data.len() as u32;
        data.extend(&layer.weight);
        layers.push((w_off, data.len() as u32));
        data.extend(&layer.bias);
    }
    let fold = data.len() as u32;
    if let Some(first) = net.layers.first() {
        let fold = crate::bounds::FoldBound::new(first);
        data.push(fold.b_max);
        data.extend(&fold.w_max);
    }
    if let Some(second) = net.layers.get(1) {
        data.extend(crate::bounds::abs_row_sums(second));
    }
    FlatNetwork {
        data,
        offsets: NetworkOffsets { layers, fold },
    }
}

/// Numbers in the device's type: f64 as is, or rounded to the nearest f32 (exact for numbers
/// already rounded outward to f32; the network's weights, whose conversion error the kernels
/// bound).
pub fn device_bytes(values: &[f64], precision: Precision) -> Vec<u8> {
    match precision {
        Precision::F32 => {
            let v: Vec<f32> = values.iter().map(|&x| x as f32).collect();
            bytemuck::cast_slice(&v).to_vec()
        }
        Precision::F64 => bytemuck::cast_slice(values).to_vec(),
    }
}

/// Device numbers read back, as f64 (exact).
pub fn from_device_bytes(bytes: &[u8], precision: Precision) -> Vec<f64> {
    match precision {
        Precision::F32 => bytemuck::pod_collect_to_vec::<u8, f32>(bytes)
            .into_iter()
            .map(f64::from)
            .collect(),
        Precision::F64 => bytemuck::pod_collect_to_vec(bytes),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The network buffer holds each layer where its offsets say and the fold constants after
    /// them, those the CPU's forward bounds use; in f32 the weights round to nearest (their
    /// conversion error the kernels bound) and the fold constants, themselves bounds, upwards.
    #[test]
    fn the_network_buffer_holds_the_layers_and_fold_bounds_rounded_up_in_f32() {
        let net = crate::network::Mlp::random(&[3, 17, 11, 2], 5);
        let flat = flatten_network(&net);
        let offsets = &flat.offsets;
        for (layer, &(w, b)) in net.layers.iter().zip(&offsets.layers) {
            let (w, b) = (w as usize, b as usize);
            assert_eq!(&flat.data[w..w + layer.weight.len()], &layer.weight[..]);
            assert_eq!(&flat.data[b..b + layer.bias.len()], &layer.bias[..]);
        }
        let fold = crate::bounds::FoldBound::new(&net.layers[0]);
        let mut bounds = vec![fold.b_max];
        bounds.extend(&fold.w_max);
        bounds.extend(crate::bounds::abs_row_sums(&net.layers[1]));
        let at = offsets.fold as usize;
        assert_eq!(&flat.data[at..], &bounds[..]);

        assert_eq!(
            flat.device_bytes(Precision::F64),
            device_bytes(&flat.data, Precision::F64)
        );
        let f32s = from_device_bytes(&flat.device_bytes(Precision::F32), Precision::F32);
        for (k, (&x, &y)) in flat.data.iter().zip(&f32s).enumerate() {
            if k < at {
                assert_eq!(y, f64::from(x as f32), "weight {k}");
            } else {
                assert!(
                    y >= x && y - x <= x.abs() * 1.2e-7,
                    "fold constant {k}: {y} < {x}"
                );
            }
        }
        // The random network's numbers are not f32s: rounding up is not rounding to nearest.
        assert!((at..flat.data.len()).any(|k| f32s[k] != f64::from(flat.data[k] as f32)));
    }
}

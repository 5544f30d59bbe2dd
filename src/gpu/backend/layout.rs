//! The device arrays of one problem (their sizes per box, [`Shape`]) and the buffers of a run
//! ([`Buffers`]). Imports the GPU's buffer and codegen layouts, the reach problem, wgpu.

use super::super::buffers::{device_bytes, flatten_network, storage, storage_init, NetworkOffsets};
use super::super::codegen::{faces_per_box, flag_words, nnb_width, MethodFlags, AUX};
use super::super::margins::MarginMap;
use super::super::GpuError;
use super::GpuBackend;
use crate::bounds::{BoundMethod, Relaxation};
use crate::reach::{ReachProblem, ReachSettings, TimeModel};

/// The passes a bound method runs on the device (`None`: not on the GPU).
pub(super) fn method_flags(bounds: BoundMethod, n_layers: usize) -> Option<MethodFlags> {
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
pub(super) struct Shape {
    /// Widths `w[0] = n, w[k+1] = n_k`.
    pub(super) w: Vec<usize>,
    pub(super) n: usize,
    pub(super) kc: usize,
    pub(super) flags: MethodFlags,
    /// Whether every layer gets its own backward pass (crown).
    pub(super) crown: bool,
    /// Rows of Λ per box of the largest pass, and Λ's reals per box (height × rows, the
    /// largest over the passes).
    pub(super) r_max: usize,
    pub(super) lam: usize,
    pub(super) slots: usize,
    /// Bound boxes per box (`2n` face-local, else 1).
    pub(super) faces: usize,
    /// The continuous time model: the bound boxes are each box's slabs or hull (`slabs_of`),
    /// and its step the continuous kernel's.
    pub(super) continuous: bool,
}

impl Shape {
    pub(super) fn new(problem: &ReachProblem, settings: &ReachSettings) -> Shape {
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
            continuous: problem.time == TimeModel::Continuous,
            w,
            flags,
            crown,
            r_max,
            lam,
        }
    }

    /// Rows of Λ per box in the pass from layer k.
    pub(super) fn rows(&self, k: usize) -> usize {
        pass_rows(&self.w, self.flags.same_slope, k)
    }

    /// Per box: (buffer, reals, copies) of every chunk buffer; the bound kernels' buffers hold
    /// `faces` bound boxes per box.
    pub(super) fn per_box(&self) -> Vec<(&'static str, u64, u64)> {
        let width = *self.w.iter().max().unwrap_or(&1) as u64;
        let sum: u64 = self.w[1..].iter().map(|&x| x as u64).sum();
        let (kc, sw, f) = (self.kc as u64, 2 * self.n as u64 + 1, self.faces as u64);
        let forms = if self.flags.forward { width * kc } else { 0 };
        let record = if self.flags.record { sum } else { 0 };
        let faces = if self.faces > 1 || self.continuous {
            f * sw
        } else {
            0
        };
        // Continuous: per box its step state and what the step leaves the host
        // (shaders/continuous.wgsl, `CW`); no snapshots (the host records the samples).
        let (cont, snap) = match self.continuous {
            true => (super::continuous::cw(self.n) as u64, 0),
            false => (0, self.slots as u64 * sw),
        };
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
            ("snap", snap, 2),
            ("known", 2 * self.n as u64, 2),
            ("cont", cont, 2),
        ]
    }
}

/// Device buffers of one run, sized for the largest chunk.
pub(super) struct Buffers {
    pub(super) net: wgpu::Buffer,
    /// Where the network's parts lie in `net` (the offsets of the data uploaded there).
    pub(super) network: NetworkOffsets,
    pub(super) state: wgpu::Buffer,
    pub(super) flags: wgpu::Buffer,
    pub(super) snap: wgpu::Buffer,
    pub(super) c: [wgpu::Buffer; 2],
    pub(super) r: [wgpu::Buffer; 2],
    pub(super) aux: wgpu::Buffer,
    pub(super) aux_g: wgpu::Buffer,
    pub(super) pre: wgpu::Buffer,
    pub(super) wm: wgpu::Buffer,
    pub(super) lam: [wgpu::Buffer; 2],
    pub(super) beta: wgpu::Buffer,
    pub(super) nnb: wgpu::Buffer,
    /// The face boxes (face-local bounds; unused otherwise).
    pub(super) faces: wgpu::Buffer,
    /// The error map for local margins (`margins::MarginMap`).
    pub(super) map_index: wgpu::Buffer,
    pub(super) map_cells: wgpu::Buffer,
    /// Per box the x-box that met frames share (frame 0's is the one read; `settle.wgsl`).
    pub(super) known: wgpu::Buffer,
    /// Continuous: per box its step state and the step's hull and rates (continuous.wgsl).
    pub(super) cont: wgpu::Buffer,
    pub(super) staging: wgpu::Buffer,
}

impl Buffers {
    /// What the bound kernels read as their boxes: the faces (or a continuous step's slabs or
    /// hull), or the states themselves.
    pub(super) fn bound_boxes(&self, shape: &Shape) -> &wgpu::Buffer {
        if shape.faces > 1 || shape.continuous {
            &self.faces
        } else {
            &self.state
        }
    }
}

impl GpuBackend {
    pub(super) fn buffers(
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
        let net = flatten_network(&problem.network);
        let flags = flag_words(chunk) as u64 * 4;
        let sz = |name: &str| sizes.get(name).copied().unwrap_or(4);
        let (snap, state, known, cont) = (sz("snap"), sz("state"), sz("known"), sz("cont"));
        Ok(Buffers {
            net: storage_init(d, "net", &net.device_bytes(self.precision)),
            network: net.offsets,
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
                &padded(&device_bytes(&margins.reals, self.precision)),
            ),
            known: storage(d, "known", known),
            cont: storage(d, "cont", cont),
            staging: d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staging"),
                // A sampled run reads the network's bounds back (`sampled`).
                size: (snap + state + flags + known + cont)
                    .max(sz("nnb") + flags)
                    .next_multiple_of(8),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        })
    }
}

/// `bytes` padded with zeros to a non-empty multiple of 8 (a buffer may not be empty).
fn padded(bytes: &[u8]) -> Vec<u8> {
    let mut v = bytes.to_vec();
    v.resize(bytes.len().max(8).next_multiple_of(8), 0);
    v
}

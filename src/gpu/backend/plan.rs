//! One Euler step's dispatches for one chunk ([`StepPlan`], see the engine's documentation for
//! the passes by bound method) and their recording into command buffers. Imports wgpu and the
//! engine's layout.

use super::super::buffers::{uniform, Params, LOOP_CHECK};
use super::super::codegen::AUX;
use super::super::kernels::{Kernel, Kernels, WORKGROUP};
use super::layout::{Buffers, Shape};

/// One dispatch of a step.
pub(super) struct Op<'k> {
    pub(super) kernel: &'k Kernel,
    pub(super) bind: wgpu::BindGroup,
    pub(super) groups: [u32; 3],
    /// A GEMM's `[rows, inner, cols]` (profiles report its rate).
    pub(super) gemm: Option<[u32; 3]>,
}

/// The dispatches of one Euler step for one chunk (see the module documentation).
pub(super) struct StepPlan<'a> {
    pub(super) device: &'a wgpu::Device,
    pub(super) kernels: &'a Kernels,
    pub(super) bufs: &'a Buffers,
    pub(super) shape: &'a Shape,
    /// Bound boxes in this chunk (`faces` per box): the columns of the bound kernels.
    pub(super) nb: u32,
    /// Boxes in this chunk.
    pub(super) boxes: u32,
    /// The x-box per box that met frames share (frame 0's buffer; read where frames are met).
    pub(super) known: &'a wgpu::Buffer,
    /// Whether the step ends with this frame's tick (frame 0's waits for the meet: [`Self::meet`]).
    pub(super) tick: bool,
    pub(super) ops: Vec<Op<'a>>,
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
            w_off: self.bufs.network.layers[k].0,
            ..base
        };
        let groups = self.kernels.gemm_kind.groups(rows, cols);
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
            w_off: self.bufs.network.layers[k].0,
            b_off: self.bufs.network.layers[k].1,
            n_prev: self.shape.w[k] as u32,
            first: (k == 0) as u32,
            fold_off: self.bufs.network.fold,
            carry: (k == 1) as u32,
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
                w_off: self.bufs.network.layers[j].0,
                b_off: self.bufs.network.layers[j].1,
                pre_off: self.pre_off(j),
                wm_off: self.wm_off(j),
                prev_u_off: if j > 0 {
                    self.pre_off(j - 1) + self.shape.w[j] as u32 * self.nb
                } else {
                    0
                },
                at_input: (j == 0) as u32,
                k_w_off: self.bufs.network.layers[k].0,
                k_b_off: self.bufs.network.layers[k].1,
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
            k_w_off: self.bufs.network.layers[k].0,
            k_b_off: self.bufs.network.layers[k].1,
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
        self.output(lam);
        self.step();
    }

    /// The output kernel: the network's bounds per bound box (`nnb`).
    fn output(&mut self, lam: usize) {
        let b = self.bufs;
        let last = self.shape.w.len() - 2;
        let p = Params {
            w_off: self.bufs.network.layers[last].0,
            b_off: self.bufs.network.layers[last].1,
            n_prev: self.shape.w[last] as u32,
            first: (last == 0) as u32,
            fold_off: self.bufs.network.fold,
            carry: (last == 1) as u32,
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
    }

    /// The box-step after the network's bounds: the continuous kernel's, or the Euler
    /// embedding step and the tick.
    fn step(&mut self) {
        let b = self.bufs;
        let per_box = Params {
            boxes: self.boxes,
            loop_check: LOOP_CHECK,
            ..Default::default()
        };
        let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
        if let Some(c) = self.continuous() {
            self.push(&c.step, &per_box, &self.continuous_group(), groups);
            return;
        }
        let group = [
            &b.state,
            &b.nnb,
            &b.flags,
            &b.snap,
            &b.map_index,
            &b.map_cells,
            self.known,
        ];
        self.push(&self.kernels.embed, &per_box, &group, groups);
        if self.tick {
            self.push(&self.kernels.tick, &per_box, &group, [1, 1, 1]);
        }
    }

    /// Frame 0's plan's last dispatches where two frames are met: the meet of this frame's sets
    /// with `other`'s (shaders/settle.wgsl), then this frame's tick.
    pub(super) fn meet(mut self, other: &'a Buffers) -> Vec<Op<'a>> {
        let b = self.bufs;
        let per_box = Params {
            boxes: self.boxes,
            ..Default::default()
        };
        let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
        if let Some(settle) = &self.kernels.settle {
            let group = [
                &b.state,
                &other.state,
                &b.flags,
                &other.flags,
                &b.snap,
                &other.snap,
                &b.known,
            ];
            self.push(settle, &per_box, &group, groups);
        }
        let group = [
            &b.state,
            &b.nnb,
            &b.flags,
            &b.snap,
            &b.map_index,
            &b.map_cells,
            self.known,
        ];
        let tick = Params {
            loop_check: LOOP_CHECK,
            ..per_box
        };
        self.push(&self.kernels.tick, &tick, &group, [1, 1, 1]);
        self.ops
    }

    /// The bindings of shaders/continuous.wgsl, shared by its two entry points (`slabs_of`,
    /// `cstep`); `known` is the flowpipes' shared x-box where frames are met (`pipe_known`).
    fn continuous_group(&self) -> [&'a wgpu::Buffer; 7] {
        let b = self.bufs;
        [
            &b.cont,
            &b.nnb,
            &b.flags,
            &b.faces,
            &b.map_index,
            &b.map_cells,
            self.known,
        ]
    }

    /// Where two frames are met in continuous time, the first frame's plan's dispatches before
    /// and after both frames' steps (shaders/cmeet.wgsl): `cpipes` (both moving boxes guessed,
    /// met, the flowpipes' x-box to `self.known`) and `cmeet` (the sets met, their x-box to this
    /// frame's `known`). None without the kernels.
    pub(super) fn continuous_meet(mut self, other: &'a Buffers) -> Option<[Op<'a>; 2]> {
        let [pipes, meet] = self.continuous()?.meet.as_ref()?;
        let b = self.bufs;
        let p = Params {
            boxes: self.boxes,
            ..Default::default()
        };
        let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
        let group = [
            &b.cont,
            &other.cont,
            &b.flags,
            &other.flags,
            &b.known,
            self.known,
        ];
        self.push(pipes, &p, &group, groups);
        self.push(meet, &p, &group, groups);
        let [a, b]: [Op<'a>; 2] = self.ops.try_into().ok()?;
        Some([a, b])
    }

    /// The continuous kernels, where this run is continuous.
    fn continuous(&self) -> Option<&'a super::super::kernels::Continuous> {
        let kernels: &'a Kernels = self.kernels;
        kernels
            .continuous
            .as_ref()
            .filter(|_| self.shape.continuous)
    }

    /// The face boxes of every box (face-local bounds), or in continuous time each box's slabs
    /// or hull (shaders/continuous.wgsl), first in a step.
    fn faces(&mut self) {
        if let Some(c) = self.continuous() {
            let p = Params {
                boxes: self.boxes,
                ..Default::default()
            };
            let groups = [self.boxes.div_ceil(WORKGROUP), 1, 1];
            self.push(&c.slabs, &p, &self.continuous_group(), groups);
            return;
        }
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
    pub(super) fn build(mut self) -> Vec<Op<'a>> {
        self.faces();
        let lam = self.network();
        self.finish(lam);
        self.ops
    }

    /// The network's bounds over the bound boxes alone (`nnb`), no step: what a sampled-data
    /// run asks of the device at each sample (`sampled`).
    pub(super) fn bounds_only(mut self) -> Vec<Op<'a>> {
        let lam = self.network();
        self.output(lam);
        self.ops
    }

    /// The bound kernels' passes by method, up to the output kernel; returns the index of the
    /// Λ buffer the output reads.
    fn network(&mut self) -> usize {
        let n_layers = self.shape.w.len() - 1;
        let last = n_layers - 1;
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
            return lam;
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
        if self.shape.flags.backward {
            self.backward_pass(last)
        } else {
            0
        }
    }
}

/// One command buffer that runs `ops` (a step's dispatches, or some of them) `repeats` times.
pub(super) fn encode_steps<'o, 'k: 'o>(
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

//! [`GpuBackend`]: the reach engine on the device (DESIGN §4).
//!
//! Every box of a chunk stays on the device for the whole horizon. One step is, per layer,
//! three GEMM dispatches (`W·Ĉ`, `|W|·R̂`, `|W|·V`) and one ReLU dispatch, then the embedding
//! dispatch and the step counter's tick; steps are recorded into a few command buffers (a
//! progress report between them, no readback), and the snapshots are read back once at the end.
//! Batches larger than the device's binding or dispatch limits allow are split into chunks that
//! run one after the other on the same buffers.

use std::sync::Arc;
use std::time::Instant;

use super::buffers::{flatten_network, status, storage, storage_init, uniform, Params};
use super::codegen::{f32_down, f32_up, problem_wgsl};
use super::kernels::{Kernels, GEMM_TILE, WORKGROUP};
use super::{GpuContext, GpuError};
use crate::bounds::BoundMethod;
use crate::boxes::IntervalBox;
use crate::reach::{
    Backend, ReachError, ReachProblem, ReachResult, ReachSettings, ReachTiming, Tube,
};

/// The largest buffer one chunk binds, whatever the device allows (bytes).
const MAX_BINDING: u64 = 1 << 30;
/// Steps recorded into one command buffer at most (progress is reported between them).
const STEPS_PER_SUBMIT: usize = 25;

/// The wgpu engine.
#[derive(Clone, Debug)]
pub struct GpuBackend {
    ctx: Arc<GpuContext>,
    /// Most boxes in one chunk (`None`: as many as the limits allow); for tests of the split.
    pub max_chunk: Option<usize>,
}

impl GpuBackend {
    /// An engine on a device.
    pub fn new(ctx: Arc<GpuContext>) -> GpuBackend {
        GpuBackend {
            ctx,
            max_chunk: None,
        }
    }

    /// The device.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// Whether this engine runs `settings` (forward bounds only, for now).
    pub fn supports(settings: &ReachSettings) -> bool {
        settings.bounds == BoundMethod::Forward && !settings.face_local
    }

    /// Boxes per chunk for a problem: the forms, magnitudes and snapshots of one chunk must fit
    /// one binding and the dispatch limits.
    pub fn chunk_size(&self, problem: &ReachProblem, every: usize, boxes: usize) -> usize {
        let lim = &self.ctx.limits;
        let binding = lim
            .max_storage_buffer_binding_size
            .min(lim.max_buffer_size)
            .min(MAX_BINDING);
        let n = problem.dynamics.n as u64;
        let width = problem.network.widths().into_iter().max().unwrap_or(1) as u64;
        let slots = problem.steps.div_ceil(every.max(1)).max(1) as u64;
        let per_box = (width * (n + 1) * 4).max(slots * (2 * n + 1) * 4);
        let by_binding = (binding / per_box.max(1)).max(1);
        let groups = lim.max_compute_workgroups_per_dimension as u64;
        let by_dispatch = (groups * GEMM_TILE as u64 / (n + 1)).min(groups * WORKGROUP as u64);
        let mut c = by_binding.min(by_dispatch).min(boxes.max(1) as u64) as usize;
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

/// Device buffers of one run, sized for the largest chunk.
struct Buffers {
    net: wgpu::Buffer,
    state: wgpu::Buffer,
    flags: wgpu::Buffer,
    snap: wgpu::Buffer,
    c: [wgpu::Buffer; 2],
    r: [wgpu::Buffer; 2],
    v_in: wgpu::Buffer,
    v_gemm: wgpu::Buffer,
    staging: wgpu::Buffer,
}

/// What one chunk's readback holds.
struct ChunkResult {
    snap: Vec<f32>,
    state: Vec<f32>,
    flags: Vec<u32>,
}

impl Backend for GpuBackend {
    fn name(&self) -> String {
        format!("gpu ({})", self.ctx.info.name)
    }

    fn reach(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        problem.check_initial(initial)?;
        if !GpuBackend::supports(settings) {
            return Err(GpuError::Unsupported(format!(
                "{} bounds (the GPU engine has forward bounds; use --bounds forward or the CPU)",
                settings.bounds
            ))
            .into());
        }
        let start = Instant::now();
        let every = settings.every.max(1);
        let (n, steps) = (problem.dynamics.n, problem.steps);
        let sw = 2 * n + 1;
        let slots = steps.div_ceil(every);
        let z_boxes: Vec<IntervalBox> = initial
            .iter()
            .map(|b| match &problem.transform {
                Some(t) => t.to_z_box(b),
                None => b.clone(),
            })
            .collect();
        let mut tubes: Vec<Tube> = initial
            .iter()
            .zip(&z_boxes)
            .map(|(b, z)| Tube {
                initial: b.clone(),
                tube: vec![problem.tube_sample(&z.lower, &z.upper, 0.0, 0.0)],
                valid: true,
                note: None,
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
        let source = problem_wgsl(problem, settings)?;
        let kernels = Kernels::new(&self.ctx.device, &source)?;
        let chunk = self.chunk_size(problem, every, initial.len());
        let bufs = self.buffers(problem, chunk, slots)?;
        let n_chunks = initial.len().div_ceil(chunk);
        for (ci, boxes) in z_boxes.chunks(chunk).enumerate() {
            let res = self.run_chunk(problem, &kernels, &bufs, boxes, slots, &|s| {
                progress(((ci * steps + s) / n_chunks).min(steps), steps)
            })?;
            let first = ci * chunk;
            for (g, tube) in tubes[first..first + boxes.len()].iter_mut().enumerate() {
                fill_tube(problem, tube, &res, g, boxes.len(), every, sw);
            }
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

impl GpuBackend {
    fn buffers(
        &self,
        problem: &ReachProblem,
        chunk: usize,
        slots: usize,
    ) -> Result<Buffers, GpuError> {
        let d = &self.ctx.device;
        let n = problem.dynamics.n as u64;
        let b = chunk as u64;
        let width = problem.network.widths().into_iter().max().unwrap_or(1) as u64;
        let (net, _) = flatten_network(&problem.network);
        let form = width * b * (n + 1) * 4;
        let state = b * (2 * n + 1) * 4;
        let flags = (3 * b + 1) * 4;
        let snap = slots as u64 * state;
        let limit = self.ctx.limits.max_buffer_size;
        if [form, snap, state].iter().any(|&s| s > limit) {
            return Err(GpuError::TooLarge(format!(
                "a chunk of {chunk} boxes needs {} bytes in one buffer",
                form.max(snap)
            )));
        }
        Ok(Buffers {
            net: storage_init(d, "net", &net),
            state: storage(d, "state", state),
            flags: storage(d, "flags", flags),
            snap: storage(d, "snap", snap),
            c: [storage(d, "c0", form), storage(d, "c1", form)],
            r: [storage(d, "r0", form), storage(d, "r1", form)],
            v_in: storage(d, "v_in", width * b * 4),
            v_gemm: storage(d, "v_gemm", width * b * 4),
            staging: d.create_buffer(&wgpu::BufferDescriptor {
                label: Some("staging"),
                size: (snap + state + flags).next_multiple_of(4),
                usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
        })
    }

    /// Runs every step for one chunk of boxes and reads its results back.
    fn run_chunk(
        &self,
        problem: &ReachProblem,
        kernels: &Kernels,
        bufs: &Buffers,
        boxes: &[IntervalBox],
        slots: usize,
        progress: &dyn Fn(usize),
    ) -> Result<ChunkResult, GpuError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let n = problem.dynamics.n;
        let nb = boxes.len() as u32;
        let kc = (n + 1) as u32;
        let sw = 2 * n + 1;
        // Initial states, rounded outward to f32.
        let mut init = Vec::with_capacity(boxes.len() * sw);
        for b in boxes {
            init.extend(b.lower.iter().map(|&v| f32_down(v)));
            init.extend(b.upper.iter().map(|&v| f32_up(v)));
            init.push(0.0f32);
        }
        if init.iter().any(|v| v.abs() > 1e30) {
            return Err(GpuError::Problem("an initial box exceeds 1e30".into()));
        }
        q.write_buffer(&bufs.state, 0, bytemuck::cast_slice(&init));
        q.write_buffer(
            &bufs.flags,
            0,
            bytemuck::cast_slice(&vec![0u32; 3 * boxes.len() + 1]),
        );

        // Bind groups and parameters of every dispatch of one step.
        let (_, offsets) = flatten_network(&problem.network);
        let layers = &problem.network.layers;
        let n_layers = layers.len();
        let bind = |k: &super::kernels::Kernel, p: &Params, bs: &[&wgpu::Buffer]| {
            let u = uniform(d, "params", p);
            let mut e = vec![wgpu::BindGroupEntry {
                binding: 0,
                resource: u.as_entire_binding(),
            }];
            for (i, b) in bs.iter().enumerate() {
                e.push(wgpu::BindGroupEntry {
                    binding: i as u32 + 1,
                    resource: b.as_entire_binding(),
                });
            }
            d.create_bind_group(&wgpu::BindGroupDescriptor {
                label: None,
                layout: &k.layout,
                entries: &e,
            })
        };
        enum Op {
            Gemm(wgpu::BindGroup, u32, u32),
            Relu(wgpu::BindGroup, u32),
            Embed(wgpu::BindGroup),
            Tick(wgpu::BindGroup),
        }
        let mut ops = Vec::new();
        let groups_1d = nb.div_ceil(WORKGROUP);
        for (k, layer) in layers.iter().enumerate() {
            let (w_off, b_off) = offsets[k];
            let base = Params {
                rows: layer.n_out as u32,
                inner: layer.n_in as u32,
                w_off,
                b_off,
                n_prev: layer.n_in as u32,
                first: (k == 0) as u32,
                boxes: nb,
                ..Default::default()
            };
            let cur = k % 2;
            if k > 0 {
                let prev = 1 - cur;
                for (abs_w, x, y, cols) in [
                    (0, &bufs.c[prev], &bufs.c[cur], nb * kc),
                    (1, &bufs.r[prev], &bufs.r[cur], nb * kc),
                    (1, &bufs.v_in, &bufs.v_gemm, nb),
                ] {
                    let p = Params {
                        cols,
                        abs_w,
                        ..base
                    };
                    let bg = bind(&kernels.gemm.0, &p, &[&bufs.net, x, y]);
                    ops.push(Op::Gemm(
                        bg,
                        cols.div_ceil(GEMM_TILE),
                        p.rows.div_ceil(GEMM_TILE),
                    ));
                }
            }
            let tail = [
                &bufs.net,
                &bufs.state,
                &bufs.c[cur],
                &bufs.r[cur],
                &bufs.v_gemm,
            ];
            if k + 1 < n_layers {
                let bg = bind(
                    &kernels.relu.0,
                    &base,
                    &[
                        tail[0],
                        tail[1],
                        tail[2],
                        tail[3],
                        tail[4],
                        &bufs.v_in,
                        &bufs.flags,
                    ],
                );
                ops.push(Op::Relu(bg, base.rows));
            } else {
                let group = [
                    tail[0],
                    tail[1],
                    tail[2],
                    tail[3],
                    tail[4],
                    &bufs.flags,
                    &bufs.snap,
                ];
                ops.push(Op::Embed(bind(&kernels.embed.0, &base, &group)));
                ops.push(Op::Tick(bind(&kernels.tick.0, &base, &group)));
            }
        }
        let limit = self.ctx.limits.max_compute_workgroups_per_dimension;
        for op in &ops {
            let (x, y) = match op {
                Op::Gemm(_, x, y) => (*x, *y),
                Op::Relu(_, rows) => (groups_1d, *rows),
                _ => (groups_1d, 1),
            };
            if x > limit || y > limit {
                return Err(GpuError::TooLarge(format!(
                    "a dispatch of {x} × {y} workgroups exceeds the device's {limit}"
                )));
            }
        }

        let steps = problem.steps;
        let mut done = 0;
        while done < steps {
            let batch = STEPS_PER_SUBMIT.min(steps - done);
            let mut enc = d.create_command_encoder(&Default::default());
            {
                let mut pass = enc.begin_compute_pass(&Default::default());
                for _ in 0..batch {
                    for op in &ops {
                        match op {
                            Op::Gemm(bg, x, y) => {
                                pass.set_pipeline(&kernels.gemm.0.pipeline);
                                pass.set_bind_group(0, bg, &[]);
                                pass.dispatch_workgroups(*x, *y, 1);
                            }
                            Op::Relu(bg, rows) => {
                                pass.set_pipeline(&kernels.relu.0.pipeline);
                                pass.set_bind_group(0, bg, &[]);
                                pass.dispatch_workgroups(groups_1d, *rows, 1);
                            }
                            Op::Embed(bg) => {
                                pass.set_pipeline(&kernels.embed.0.pipeline);
                                pass.set_bind_group(0, bg, &[]);
                                pass.dispatch_workgroups(groups_1d, 1, 1);
                            }
                            Op::Tick(bg) => {
                                pass.set_pipeline(&kernels.tick.0.pipeline);
                                pass.set_bind_group(0, bg, &[]);
                                pass.dispatch_workgroups(1, 1, 1);
                            }
                        }
                    }
                }
            }
            q.submit([enc.finish()]);
            self.ctx.wait()?;
            done += batch;
            progress(done);
        }

        // One readback: snapshots, final states, flags.
        let snap_bytes = (slots * boxes.len() * sw * 4) as u64;
        let state_bytes = (boxes.len() * sw * 4) as u64;
        let flag_bytes = ((3 * boxes.len() + 1) * 4) as u64;
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
                snap: bytemuck::pod_collect_to_vec(a),
                state: bytemuck::pod_collect_to_vec(b),
                flags: bytemuck::pod_collect_to_vec(c),
            }
        };
        bufs.staging.unmap();
        Ok(result)
    }
}

/// A tube's samples from a chunk's readback (the CPU engine's recording rules).
fn fill_tube(
    problem: &ReachProblem,
    tube: &mut Tube,
    res: &ChunkResult,
    g: usize,
    nb: usize,
    every: usize,
    sw: usize,
) {
    let n = problem.dynamics.n;
    let steps = problem.steps;
    let st = res.flags[3 * g + 1];
    let stop = res.flags[3 * g + 2] as usize + 1; // 1-based step at which it stopped
    let read = |v: &[f32]| -> (Vec<f64>, Vec<f64>, f64) {
        (
            v[..n].iter().map(|&x| x as f64).collect(),
            v[n..2 * n].iter().map(|&x| x as f64).collect(),
            v[2 * n] as f64,
        )
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
            .push(problem.tube_sample(&lo, &hi, r, s as f64 * problem.dt));
    }
    let t = stop as f64 * problem.dt;
    match st {
        status::LEFT_REGION => {
            let (lo, hi, r) = read(&res.state[g * sw..(g + 1) * sw]);
            tube.valid = false;
            tube.note = Some(format!("t = {t:.3}: the set left the region C"));
            tube.tube.push(problem.tube_sample(&lo, &hi, r, t));
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

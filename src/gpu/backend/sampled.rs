//! The sampled-data time model on the GPU engine (docs/design.md §7.2, §7.4), first stage: at
//! each sample the device bounds the network over every live box's whole set in one batch per
//! frame, and the x network over their x-boxes for the held input (the bound kernels
//! unchanged, no step kernel: [`StepPlan::bounds_only`]); the host reads the bounds back and
//! runs the CPU engine's own sampled step on them ([`CpuBackend::reach_sampled_with`]: the
//! held input's images, the remainder, the motion between samples, the filter's constraint,
//! the findings, the tubes). The plant's step is the host's in this stage; the bounds are the
//! whole of what the device computes.

use std::sync::atomic::Ordering::Relaxed;
use std::sync::{Arc, Mutex};
use std::time::Instant;

use super::super::buffers::{device_bytes, from_device_bytes};
use super::super::codegen::{flag_words, nnb_width, problem_wgsl, round_down, round_up, FLAG_W};
use super::super::kernels::{Kernels, Variant};
use super::super::margins::MarginMap;
use super::super::GpuError;
use super::layout::{Buffers, Shape};
use super::plan::{encode_steps, StepPlan};
use super::GpuBackend;
use crate::bounds::AffineBoundsBatch;
use crate::boxes::IntervalBox;
use crate::reach::{
    Backend, BatchBounds, Bounded, CpuBackend, ExactField, ReachError, ReachProblem, ReachResult,
    ReachSettings, ReachTiming,
};

/// The settings the device's bound kernels are compiled for in a sampled run: whole sets (the
/// held input is imaged off the whole set, never with face-local bounds, as on the CPU) and no
/// filter's field on the device (the host's, with the rest of the step).
fn device_settings(settings: &ReachSettings) -> ReachSettings {
    ReachSettings {
        face_local: false,
        exact: ExactField::Nowhere,
        ..settings.clone()
    }
}

/// One frame's pipelines and buffers.
struct FrameSetup<'a> {
    problem: &'a ReachProblem,
    shape: Shape,
    kernels: Arc<Kernels>,
    bufs: Buffers,
}

/// The device as the CPU engine's source of network bounds.
struct DeviceBounds<'a> {
    gpu: &'a GpuBackend,
    /// The run's frames, then the x problem's where it is none of them.
    frames: Vec<FrameSetup<'a>>,
    /// The x problem's index in `frames` ([`Bounded::X`]).
    x: usize,
    /// The frames' buffers are used by one batch at a time.
    busy: Mutex<()>,
}

impl BatchBounds for DeviceBounds<'_> {
    fn bound(
        &self,
        which: Bounded,
        lower: &[f64],
        upper: &[f64],
        out: &mut AffineBoundsBatch,
    ) -> Result<(), ReachError> {
        let _busy = self
            .busy
            .lock()
            .map_err(|_| GpuError::Device("sampled bounds poisoned".into()))?;
        let fr = match which {
            Bounded::Frame(f) => &self.frames[f],
            Bounded::X => &self.frames[self.x],
        };
        let (gpu, prec) = (self.gpu, self.gpu.precision);
        let (d, q) = (&gpu.ctx.device, &gpu.ctx.queue);
        let n = fr.problem.dynamics.n;
        let m = fr.problem.network.output_dim();
        let boxes = lower.len() / n.max(1);
        // The bound boxes as the kernels read them: lower, upper, radius (unused) per box.
        let mut state = Vec::with_capacity(boxes * (2 * n + 1));
        for (lo, hi) in lower.chunks(n).zip(upper.chunks(n)) {
            state.extend(lo.iter().map(|&v| round_down(v, prec)));
            state.extend(hi.iter().map(|&v| round_up(v, prec)));
            state.push(0.0);
        }
        q.write_buffer(&fr.bufs.state, 0, &device_bytes(&state, prec));
        let flags = vec![0u32; flag_words(boxes)];
        q.write_buffer(&fr.bufs.flags, 0, bytemuck::cast_slice(&flags));
        let ops = StepPlan {
            device: d,
            kernels: &fr.kernels,
            bufs: &fr.bufs,
            shape: &fr.shape,
            nb: boxes as u32,
            boxes: boxes as u32,
            known: &fr.bufs.known,
            tick: false,
            ops: Vec::new(),
        }
        .bounds_only();
        gpu.check_groups(&ops)?;
        q.submit([encode_steps(d, ops.iter(), 1)]);
        let w = nnb_width(n, m);
        let nnb_bytes = (boxes * w) as u64 * prec.bytes();
        let flag_bytes = (flags.len() * 4) as u64;
        let copies = [(&fr.bufs.nnb, nnb_bytes), (&fr.bufs.flags, flag_bytes)];
        let (nnb, flags) = gpu.read_staging(&fr.bufs, &copies, |bytes| {
            let (a, b) = bytes.split_at(nnb_bytes as usize);
            let flags: Vec<u32> = bytemuck::pod_collect_to_vec(b);
            (from_device_bytes(a, prec), flags)
        })?;
        unpack(&nnb, &flags, (n, m, boxes), out);
        gpu.sampled_bounds.fetch_add(boxes, Relaxed);
        Ok(())
    }
}

/// The device's record of the network's bounds (`nnb`, shaders/output.wgsl: per box `C̲, C̄`,
/// `d̲, d̄, N̲, N̄`, a non-finite flag) as the CPU's batch. A box whose bounds the kernels
/// found non-finite (or whose ReLU or backward pass did: its poison flag) gets `N ∈ (−∞, ∞)`,
/// which bounds nothing, as the CPU's own non-finite bounds do not.
fn unpack(
    nnb: &[f64],
    flags: &[u32],
    (n, m, boxes): (usize, usize, usize),
    out: &mut AffineBoundsBatch,
) {
    let w = nnb_width(n, m);
    out.reset(n, m, boxes);
    for k in 0..boxes {
        let r = &nnb[k * w..(k + 1) * w];
        let (mn, o) = (m * n, 2 * m * n);
        if flags[k * FLAG_W] != 0 || r[w - 1] != 0.0 {
            out.a_lower[k * mn..(k + 1) * mn].fill(0.0);
            out.a_upper[k * mn..(k + 1) * mn].fill(0.0);
            out.b_lower[k * m..(k + 1) * m].fill(f64::NEG_INFINITY);
            out.lower[k * m..(k + 1) * m].fill(f64::NEG_INFINITY);
            out.b_upper[k * m..(k + 1) * m].fill(f64::INFINITY);
            out.upper[k * m..(k + 1) * m].fill(f64::INFINITY);
            continue;
        }
        out.a_lower[k * mn..(k + 1) * mn].copy_from_slice(&r[..mn]);
        out.a_upper[k * mn..(k + 1) * mn].copy_from_slice(&r[mn..o]);
        out.b_lower[k * m..(k + 1) * m].copy_from_slice(&r[o..o + m]);
        out.b_upper[k * m..(k + 1) * m].copy_from_slice(&r[o + m..o + 2 * m]);
        out.lower[k * m..(k + 1) * m].copy_from_slice(&r[o + 2 * m..o + 3 * m]);
        out.upper[k * m..(k + 1) * m].copy_from_slice(&r[o + 3 * m..o + 4 * m]);
    }
}

impl GpuBackend {
    /// A sampled-data run: per chunk of boxes the CPU engine's run with this device's network
    /// bounds ([`DeviceBounds`]). Runs without a step or a box bound nothing, and are the CPU
    /// engine's as they are.
    pub(super) fn sampled(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        let steps = problem.steps;
        if initial.is_empty() || steps == 0 {
            return CpuBackend.reach(problem, initial, settings, progress);
        }
        let start = Instant::now();
        let gemm = self.check_network(problem)?;
        let device = device_settings(settings);
        // The held input's bounds are the x problem's (design §7.2 item 2): its own pipelines
        // where no frame is in x.
        let mut frames = problem.frames(settings);
        let x_problem = problem.in_x.as_deref().unwrap_or(problem);
        let x = match frames.iter().position(|f| std::ptr::eq(*f, x_problem)) {
            Some(x) => x,
            None => {
                frames.push(x_problem);
                frames.len() - 1
            }
        };
        let share = frames.len() as u64;
        let chunk = frames
            .iter()
            .map(|f| self.frame_chunk_size(f, &device, initial.len(), share))
            .min()
            .unwrap_or(1);
        let frames = frames
            .into_iter()
            .map(|frame| {
                let shape = Shape::new(frame, &device);
                let margins = MarginMap::for_problem(frame, &device, self.precision);
                let source =
                    problem_wgsl(frame, &device, shape.flags, self.precision, &margins, None)?;
                let kernels = self.kernels.get(
                    &self.ctx,
                    self.cache_dir.as_deref(),
                    self.precision,
                    source,
                    Variant {
                        settle: false,
                        gemm,
                        continuous: false,
                    },
                )?;
                let bufs = self.buffers(frame, &shape, &margins, chunk)?;
                Ok(FrameSetup {
                    problem: frame,
                    shape,
                    kernels,
                    bufs,
                })
            })
            .collect::<Result<Vec<_>, GpuError>>()?;
        let source = DeviceBounds {
            gpu: self,
            frames,
            x,
            busy: Mutex::new(()),
        };
        let n_chunks = initial.len().div_ceil(chunk);
        let mut boxes = Vec::with_capacity(initial.len());
        for (ci, part) in initial.chunks(chunk).enumerate() {
            let report =
                |s: usize, _: usize| progress(((ci * steps + s) / n_chunks).min(steps), steps);
            let res = CpuBackend.reach_sampled_with(problem, part, settings, &report, &source)?;
            boxes.extend(res.boxes);
        }
        Ok(ReachResult {
            boxes,
            timing: ReachTiming {
                reach_s: start.elapsed().as_secs_f64(),
                minkowski_s: 0.0,
            },
        })
    }

    /// Sets of this engine's sampled runs whose network bounds the device computed so far.
    pub fn sampled_bounds(&self) -> usize {
        self.sampled_bounds.load(Relaxed)
    }
}

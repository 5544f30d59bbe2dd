//! One chunk of boxes on the device: its initial states uploaded (in each frame, where two are
//! met), every step submitted, the snapshots, states and flags read back (and, asked to, each
//! kernel timed). Imports wgpu and
//! the engine's layout and plan.

use std::time::Instant;

use super::super::buffers::{device_bytes, from_device_bytes};
use super::super::codegen::{flag_words, round_down, round_up};
use super::super::kernels::Kernels;
use super::super::GpuError;
use super::layout::{Buffers, Shape};
use super::plan::{encode_steps, Op, StepPlan};
use super::{GpuBackend, LLVMPIPE_LOOP_LIMIT};
use crate::boxes::IntervalBox;
use crate::reach::ReachProblem;

/// Steps recorded into one command buffer at most (progress is reported between them).
const STEPS_PER_SUBMIT: usize = 25;

/// What one chunk's readback holds, per frame.
pub(super) struct ChunkResult {
    pub(super) snap: Vec<f64>,
    pub(super) state: Vec<f64>,
    pub(super) flags: Vec<u32>,
    /// The x-boxes the frames share at the end (frame 0's, where frames are met).
    pub(super) known: Vec<f64>,
}

/// One frame of a run: its problem, array sizes, pipelines and buffers.
pub(super) struct FrameRun<'a> {
    pub(super) problem: &'a ReachProblem,
    pub(super) shape: &'a Shape,
    pub(super) kernels: &'a Kernels,
    pub(super) bufs: &'a Buffers,
}

impl GpuBackend {
    /// Runs every step for one chunk of boxes and reads its results back: `sets[f]` holds the
    /// boxes' initial sets in frame `f`, `known` their shared x-boxes where two frames are met.
    pub(super) fn run_chunk<'f>(
        &'f self,
        frames: &'f [FrameRun<'f>],
        sets: &[&[IntervalBox]],
        known: &[IntervalBox],
        slots: usize,
        progress: &dyn Fn(usize),
    ) -> Result<Vec<ChunkResult>, GpuError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let prec = self.precision;
        let meet = frames.len() > 1;
        let outward = |boxes: &[IntervalBox], radius: bool| -> Result<Vec<f64>, GpuError> {
            let mut init = Vec::new();
            for b in boxes {
                init.extend(b.lower.iter().map(|&v| round_down(v, prec)));
                init.extend(b.upper.iter().map(|&v| round_up(v, prec)));
                if radius {
                    init.push(0.0);
                }
            }
            if init.iter().any(|v| v.abs() > 1e30) {
                return Err(GpuError::Problem("an initial box exceeds 1e30".into()));
            }
            Ok(init)
        };
        let boxes = sets[0].len();
        // Initial states, rounded outward to the device's numbers.
        for (f, frame_sets) in frames.iter().zip(sets) {
            let bufs = f.bufs;
            q.write_buffer(
                &bufs.state,
                0,
                &device_bytes(&outward(frame_sets, true)?, prec),
            );
            q.write_buffer(
                &bufs.flags,
                0,
                bytemuck::cast_slice(&vec![0u32; flag_words(boxes)]),
            );
        }
        if meet {
            let init = outward(known, false)?;
            q.write_buffer(&frames[0].bufs.known, 0, &device_bytes(&init, prec));
        }

        let known_buf = &frames[0].bufs.known;
        let plan = |f: &'f FrameRun<'f>, tick: bool| StepPlan {
            device: d,
            kernels: f.kernels,
            bufs: f.bufs,
            shape: f.shape,
            nb: (f.shape.faces * boxes) as u32,
            boxes: boxes as u32,
            known: known_buf,
            tick,
            ops: Vec::new(),
        };
        let mut ops = plan(&frames[0], !meet).build();
        if meet {
            ops.extend(plan(&frames[1], true).build());
            ops.extend(plan(&frames[0], false).meet(frames[1].bufs));
        }
        self.check_groups(&ops)?;

        let steps = frames[0].problem.steps;
        let mut done = 0;
        while done < steps {
            let batch = STEPS_PER_SUBMIT.min(steps - done);
            q.submit([encode_steps(d, ops.iter(), batch)]);
            self.ctx.wait()?;
            done += batch;
            progress(done);
        }

        let n = frames[0].problem.dynamics.n;
        let results = frames
            .iter()
            .map(|f| self.read_back(f.bufs, slots, boxes, n))
            .collect::<Result<Vec<ChunkResult>, GpuError>>()?;
        // The loop check is the last word.
        if results
            .iter()
            .any(|r| r.flags.last().is_some_and(|&w| w != 0))
        {
            return Err(self.loops_cut_short());
        }
        if self.profile {
            self.profile_step(&ops, boxes)?;
        }
        Ok(results)
    }

    /// The error of a run whose embedding (or continuous) kernel found its loops cut short.
    pub(super) fn loops_cut_short(&self) -> GpuError {
        GpuError::Device(format!(
            "the device's driver ({}) cut the embedding kernel's loops short (llvmpipe ends an \
             invocation's loops after {LLVMPIPE_LOOP_LIMIT} iterations in all); its sets cannot \
             be trusted: run this problem on the CPU (--backend cpu)",
            self.ctx.info.name
        ))
    }

    /// Refuses a step whose dispatches exceed the device's workgroup limits.
    pub(super) fn check_groups(&self, ops: &[Op]) -> Result<(), GpuError> {
        let limit = self.ctx.limits.max_compute_workgroups_per_dimension;
        if let Some(op) = ops.iter().find(|op| op.groups.iter().any(|&g| g > limit)) {
            return Err(GpuError::TooLarge(format!(
                "a dispatch of {:?} workgroups exceeds the device's {limit}",
                op.groups
            )));
        }
        Ok(())
    }

    /// One readback of a frame's buffers: snapshots, final states, flags, shared x-boxes.
    fn read_back(
        &self,
        bufs: &Buffers,
        slots: usize,
        boxes: usize,
        n: usize,
    ) -> Result<ChunkResult, GpuError> {
        let prec = self.precision;
        let sw = 2 * n + 1;
        let bytes = prec.bytes();
        let snap_bytes = (slots * boxes * sw) as u64 * bytes;
        let state_bytes = (boxes * sw) as u64 * bytes;
        let flag_bytes = (flag_words(boxes) * 4) as u64;
        let known_bytes = (boxes * 2 * n) as u64 * bytes;
        let copies = [
            (&bufs.snap, snap_bytes),
            (&bufs.state, state_bytes),
            (&bufs.flags, flag_bytes),
            (&bufs.known, known_bytes),
        ];
        self.read_staging(bufs, &copies, |bytes| {
            let (a, rest) = bytes.split_at(snap_bytes as usize);
            let (b, rest) = rest.split_at(state_bytes as usize);
            let (c, k) = rest.split_at(flag_bytes as usize);
            ChunkResult {
                snap: from_device_bytes(a, prec),
                state: from_device_bytes(b, prec),
                flags: bytemuck::pod_collect_to_vec(c),
                known: from_device_bytes(k, prec),
            }
        })
    }

    /// `read` of the bytes of `copies` (each buffer's first `size` bytes, one after the other),
    /// copied to the staging buffer in one submit and mapped (not copied again: a chunk's
    /// snapshots may be hundreds of MB).
    pub(super) fn read_staging<T>(
        &self,
        bufs: &Buffers,
        copies: &[(&wgpu::Buffer, u64)],
        read: impl FnOnce(&[u8]) -> T,
    ) -> Result<T, GpuError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let mut enc = d.create_command_encoder(&Default::default());
        let mut at = 0;
        for &(buf, size) in copies {
            enc.copy_buffer_to_buffer(buf, 0, &bufs.staging, at, size);
            at += size;
        }
        q.submit([enc.finish()]);
        let slice = bufs.staging.slice(0..at);
        let (tx, rx) = std::sync::mpsc::channel();
        slice.map_async(wgpu::MapMode::Read, move |r| {
            let _ = tx.send(r);
        });
        self.ctx.wait()?;
        rx.recv()
            .map_err(|e| GpuError::Device(e.to_string()))?
            .map_err(|e| GpuError::Device(e.to_string()))?;
        let out = {
            let view = slice
                .get_mapped_range()
                .map_err(|e| GpuError::Device(e.to_string()))?;
            read(&view)
        };
        bufs.staging.unmap();
        Ok(out)
    }

    /// Times one step's dispatches by kernel (each kind repeated on its own, then the whole
    /// step) and prints ms per step, share and GFLOP/s of the GEMMs to stderr. The repeats
    /// overwrite the chunk's buffers, so this runs after its readback.
    fn profile_step(&self, ops: &[Op], boxes: usize) -> Result<(), GpuError> {
        const REPEATS: usize = 10;
        let time = |ops: &[&Op]| -> Result<f64, GpuError> {
            let commands = encode_steps(&self.ctx.device, ops.iter().copied(), REPEATS);
            self.ctx.wait()?;
            let start = Instant::now();
            self.ctx.queue.submit([commands]);
            self.ctx.wait()?;
            Ok(start.elapsed().as_secs_f64() * 1e3 / REPEATS as f64)
        };
        let all: Vec<&Op> = ops.iter().collect();
        let step_ms = time(&all)?;
        eprintln!(
            "profile ({boxes} boxes, {} dispatches a step): {step_ms:.3} ms a step",
            ops.len()
        );
        let mut names: Vec<&str> = ops.iter().map(|o| o.kernel.name).collect();
        names.sort_unstable();
        names.dedup();
        for name in names {
            let group: Vec<&Op> = ops.iter().filter(|o| o.kernel.name == name).collect();
            let ms = time(&group)?;
            eprintln!(
                "  {name:<12} {:>3}×  {ms:>9.3} ms  {:>5.1}%",
                group.len(),
                100.0 * ms / step_ms
            );
        }
        for op in ops {
            if let Some([rows, inner, cols]) = op.gemm {
                let ms = time(&[op])?;
                let flops = 2.0 * rows as f64 * inner as f64 * cols as f64;
                eprintln!(
                    "    gemm {rows} × {inner} · {inner} × {cols}: {ms:.3} ms, {:.0} GFLOP/s",
                    flops / ms / 1e6
                );
            }
        }
        Ok(())
    }
}

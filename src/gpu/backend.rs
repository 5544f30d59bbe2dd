//! [`GpuBackend`]: the reach engine on the device (docs/design.md §4).
//!
//! Every box of a chunk stays on the device for the whole horizon. One step is a fixed list of
//! dispatches (`StepPlan`), recorded into a few command buffers (a progress report between
//! them, no readback); the snapshots are read back once at the end. By bound method:
//!
//! - `forward`: per layer the GEMMs `W·Ĉ`, `|W|·R̂`, `|W|·V` and the ReLU kernel;
//! - `forward-backward[-same-slope]`: the same with IBP alongside (`W·c`, `|W|·[r, |c| + r]`),
//!   every hidden layer's bounds recorded, `|W_k| max(u, 0)` per layer for the rounding bounds,
//!   then ONE backward pass from the output: per hidden layer a per-box scaling `Λ∘s` and ONE
//!   GEMM `Λ ← Wⱼᵀ·(Λ∘s)` shared by all boxes;
//! - `crown[-same-slope]`: a backward pass from every layer, each layer's bounds from its own
//!   pass (`2 n_k` or `n_k` rows of `Λ` per box).
//!
//! Then the output kernel (the network's bounds per box), the embedding step and the step
//! counter's tick. Batches larger than the device's binding, memory or dispatch limits allow
//! are split into chunks that run one after the other on the same buffers.
//!
//! With face-local bounds (`--face-local`) a step starts with the `faces` kernel, which writes
//! the `2n` faces of every box (`shaders/faces.wgsl`); the bound kernels then run on `2n·B`
//! bound boxes, and the embedding step bounds each face of the field with its own face's
//! network bounds. With local error margins (`--local-margin`, an error map on the problem)
//! the embedding step takes each box's `M` from the map (`margins`), and a box that meets a
//! cell without a certified bound stops as invalid (`status::NO_BOUND`), as on the CPU.
//!
//! In continuous time (docs/design.md §7.4) `slabs_of` replaces the faces kernel (each box's
//! slabs or hull of its guessed moving box), `cstep` the embedding step, and the host reads
//! every step back, steps the boxes the device leaves to it with the CPU engine's step and
//! records the samples (`continuous`).
//!
//! This file holds the engine and its [`Backend`] impl (checks, chunking, the tubes' assembly);
//! `layout` sizes the device arrays and creates the buffers, `plan` records one step's
//! dispatches, `chunk` runs one chunk of boxes and reads it back, `continuous` runs a chunk in
//! continuous time.

mod chunk;
mod continuous;
mod layout;
mod plan;
mod sampled;

use std::sync::{Arc, Mutex};
use std::time::Instant;

use rayon::prelude::*;

use self::chunk::{ChunkResult, FrameRun};
use self::layout::{method_flags, Shape};
use super::buffers::status;
use super::codegen::{problem_wgsl, Meet, FLAG_W};
use super::disk_cache::{cache_dir, DiskCache, Loaded, Saved};
use super::kernels::{
    compiles, shader_source, Gemm, Kernels, Variant, GEMM_TILE, MODULES, WORKGROUP,
};
use super::margins::MarginMap;
use super::{GpuContext, GpuError, Precision};
use crate::boxes::IntervalBox;
use crate::reach::safe_set::clip_to_safe_set;
use crate::reach::{
    Backend, ReachError, ReachMethod, ReachProblem, ReachResult, ReachSettings, ReachTiming,
    SafeSet, TimeModel, Tube, TubeEnd, TubeSample, Unsupported,
};

/// The largest buffer one chunk binds, whatever the device allows (bytes).
const MAX_BINDING: u64 = 1 << 30;
/// The most device memory one chunk's buffers take together (bytes).
const MAX_CHUNK_BYTES: u64 = 3 << 29;
/// Storage buffers the widest kernel binds (relu, output).
const STORAGE_BINDINGS: u32 = 8;
/// llvmpipe silently ends every loop of a shader invocation once this many iterations have run
/// in it (Mesa's `LP_MAX_TGSI_LOOP_ITERATIONS`); the embedding kernel checks for it itself
/// (`loops_ran_in_full`), the bound kernels' loops are refused beyond it ([`bound_kernel_loops`]).
const LLVMPIPE_LOOP_LIMIT: usize = 65_535;

/// The wgpu engine.
#[derive(Clone, Debug)]
pub struct GpuBackend {
    ctx: Arc<GpuContext>,
    precision: Precision,
    /// Most boxes in one chunk (`None`: as many as the limits allow); for tests of the split.
    pub max_chunk: Option<usize>,
    /// Extra loop iterations per local-margin query (0 unless set); for tests of the embedding
    /// kernel's loop check.
    pub pad_loops: u32,
    /// After each chunk, time every kind of dispatch of a step on its own and print the
    /// breakdown to stderr (`bench --profile`; the chunk's results are read back first).
    pub profile: bool,
    /// The pipelines of the last problem run, reused while its generated WGSL is unchanged
    /// (`verify` calls the engine once per batch; compiling every pipeline takes ~1 s on an
    /// NVIDIA driver).
    kernels: KernelCache,
    /// The GEMM kernel: [`Gemm::Flat`] by default on software adapters, where it is ~4×
    /// faster than the tiles (barriers are coroutine switches there; docs/design.md §4), and
    /// runs where every layer is at most as wide as the device's dispatch allows and its loops
    /// stay within llvmpipe's limit (else [`Gemm::Tiles`]); [`Gemm::Tiles`] on real GPUs
    /// (measured on an H200; [`Gemm::Wide`] gives the same products and is not yet measured
    /// on one: `cbfreach bench --gemm wide`).
    pub gemm: Gemm,
    /// Where compiled pipelines are kept between runs (`disk_cache::cache_dir()` unless set;
    /// `None`: nowhere).
    pub cache_dir: Option<std::path::PathBuf>,
    /// Box-steps of continuous runs so far: on the device, on the host
    /// ([`GpuBackend::continuous_steps`]).
    continuous_steps: Arc<[std::sync::atomic::AtomicUsize; 2]>,
    /// Sets of sampled runs bounded on the device so far ([`GpuBackend::sampled_bounds`]).
    sampled_bounds: Arc<std::sync::atomic::AtomicUsize>,
}

/// Pipelines with the generated WGSL and the variant they were compiled from.
type CompiledKernels = (String, Variant, Arc<Kernels>);

/// The last pipelines an engine compiled: one problem's, or both frames' where two are met.
#[derive(Clone, Default)]
struct KernelCache(
    Arc<Mutex<Vec<CompiledKernels>>>,
    Arc<Mutex<Vec<(Loaded, Saved)>>>,
);

impl std::fmt::Debug for KernelCache {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("KernelCache")
    }
}

/// Pipelines the cache keeps: both frames of a met run.
const CACHED: usize = 2;

impl KernelCache {
    /// The pipelines for `source`, compiled only when no cached one was compiled from it;
    /// compiled through the pipeline cache on disk in `dir` (`disk_cache`) where there is one.
    fn get(
        &self,
        ctx: &GpuContext,
        dir: Option<&std::path::Path>,
        precision: Precision,
        source: String,
        variant: Variant,
    ) -> Result<Arc<Kernels>, GpuError> {
        let mut last = self
            .0
            .lock()
            .map_err(|_| GpuError::Device("kernel cache poisoned".into()))?;
        if let Some((_, _, k)) = last.iter().find(|(s, v, _)| *s == source && *v == variant) {
            return Ok(k.clone());
        }
        let modules: Vec<String> = MODULES
            .iter()
            .filter(|&&m| compiles(m, variant))
            .map(|m| shader_source(precision, &source, m))
            .collect();
        let mut sources: Vec<&str> = modules.iter().map(String::as_str).collect();
        sources.push(variant.gemm.entry());
        let disk = DiskCache::open_in(ctx, dir, &sources);
        let kernels = Arc::new(Kernels::new(
            &ctx.device,
            disk.pipeline_cache(),
            precision,
            &source,
            variant,
        )?);
        let saved = disk.save();
        if let Ok(mut log) = self.1.lock() {
            log.push((disk.loaded().clone(), saved));
        }
        if last.len() == CACHED {
            last.remove(0);
        }
        last.push((source, variant, kernels.clone()));
        Ok(kernels)
    }
}

impl GpuBackend {
    /// An engine on a device, in f64 where the device has f64 shaders (as the CLI picks),
    /// else f32.
    pub fn new(ctx: Arc<GpuContext>) -> GpuBackend {
        let precision = if ctx.has_f64() {
            Precision::F64
        } else {
            Precision::F32
        };
        GpuBackend {
            precision,
            max_chunk: None,
            pad_loops: 0,
            profile: false,
            kernels: KernelCache::default(),
            cache_dir: cache_dir(),
            gemm: if ctx.is_software() {
                Gemm::Flat
            } else {
                Gemm::Tiles
            },
            continuous_steps: Arc::default(),
            sampled_bounds: Arc::default(),
            ctx,
        }
    }

    /// Box-steps of this engine's continuous runs so far: `(on the device, on the host)` (the
    /// common path's share, design §7.4).
    pub fn continuous_steps(&self) -> (usize, usize) {
        let [d, h] = &*self.continuous_steps;
        let load =
            |a: &std::sync::atomic::AtomicUsize| a.load(std::sync::atomic::Ordering::Relaxed);
        (load(d), load(h))
    }

    /// An engine in `precision`; [`GpuError::NoF64`] when f64 is asked of a device without
    /// `wgpu::Features::SHADER_F64`.
    pub fn with_precision(
        ctx: Arc<GpuContext>,
        precision: Precision,
    ) -> Result<GpuBackend, GpuError> {
        if precision == Precision::F64 && !ctx.has_f64() {
            return Err(GpuError::NoF64(ctx.info.name.clone()));
        }
        Ok(GpuBackend {
            precision,
            ..GpuBackend::new(ctx)
        })
    }

    /// For every compilation so far, what the pipeline cache on disk held and what was
    /// written back (`disk_cache`).
    pub fn disk_cache_log(&self) -> Vec<(Loaded, Saved)> {
        self.kernels.1.lock().map(|l| l.clone()).unwrap_or_default()
    }

    /// The device.
    pub fn context(&self) -> &GpuContext {
        &self.ctx
    }

    /// The device's number type.
    pub fn precision(&self) -> Precision {
        self.precision
    }

    /// Whether this engine runs `settings`: forward, forward-backward and CROWN bounds (either
    /// relaxation, whole-box or face-local), not IBP alone. Local error margins (a problem
    /// with an error map) run on every setting.
    pub fn supports(settings: &ReachSettings) -> bool {
        method_flags(settings.bounds, 2).is_some()
    }

    /// Whether this engine runs `problem` under `settings` as they are, or the setting it
    /// refuses: bounds without a device kernel (IBP alone), a continuous run with a setting its
    /// device step does not take yet (`continuous::refused`), the exact field of a general QP
    /// filter (on the device's step: a sampled run's is the host's).
    pub fn runs(problem: &ReachProblem, settings: &ReachSettings) -> Result<(), Unsupported> {
        if !GpuBackend::supports(settings) {
            return Err(Unsupported::Bounds(settings.bounds));
        }
        if let Some(f) = super::codegen::not_on_device(problem) {
            return Err(Unsupported::Function(f.name()));
        }
        match problem.time {
            TimeModel::Euler => {}
            // The device meets two frames; turned frames are the CPU engine's.
            TimeModel::Continuous if problem.frames(settings).len() > 2 => {
                return Err(Unsupported::Continuous(
                    "turned frames (reach.turned_frames above 1)",
                ))
            }
            TimeModel::Continuous => continuous::refused(settings)?,
            // The device bounds the network alone; the rest is the CPU engine's (`sampled`).
            TimeModel::Sampled { .. } => return Ok(()),
        }
        let general_qp = problem
            .pieces
            .forms()
            .is_some_and(|f| f.method() == crate::filter::FilterMethod::Qp);
        if general_qp && settings.exact_field() == crate::reach::ExactField::ClosedForm {
            return Err(Unsupported::ExactGeneralQp);
        }
        Ok(())
    }

    /// Boxes per chunk for a problem: every buffer of one chunk must fit one binding, all of
    /// them together (both frames' where two are met) 1.5 GiB, and the dispatches the device's
    /// limits.
    pub fn chunk_size(
        &self,
        problem: &ReachProblem,
        settings: &ReachSettings,
        boxes: usize,
    ) -> usize {
        let frames = problem.frames(settings);
        frames
            .iter()
            .map(|f| self.frame_chunk_size(f, settings, boxes, frames.len() as u64))
            .min()
            .unwrap_or(1)
    }

    /// [`Self::chunk_size`] for one of `frames` frames, which share the memory.
    fn frame_chunk_size(
        &self,
        problem: &ReachProblem,
        settings: &ReachSettings,
        boxes: usize,
        frames: u64,
    ) -> usize {
        let lim = &self.ctx.limits;
        let binding = lim
            .max_storage_buffer_binding_size
            .min(lim.max_buffer_size)
            .min(MAX_BINDING);
        let shape = Shape::new(problem, settings);
        let bytes = self.precision.bytes();
        let per_box = shape.per_box();
        let largest = per_box.iter().map(|(_, n, _)| *n).max().unwrap_or(1) * bytes;
        let total: u64 = per_box.iter().map(|(_, n, copies)| n * copies).sum::<u64>() * bytes;
        let by_binding = (binding / largest.max(1)).max(1);
        let by_memory = (MAX_CHUNK_BYTES / frames.max(1) / total.max(1)).max(1);
        let groups = lim.max_compute_workgroups_per_dimension as u64;
        let widest = (shape.kc.max(shape.r_max).max(3) * shape.faces) as u64;
        let by_dispatch = (groups * GEMM_TILE as u64 / widest).min(groups * WORKGROUP as u64);
        let mut c = by_binding
            .min(by_memory)
            .min(by_dispatch)
            .min(boxes.max(1) as u64) as usize;
        if let Some(m) = self.max_chunk {
            c = c.min(m.max(1));
        }
        c
    }
}

impl GpuBackend {
    /// Refuses a network the bound kernels cannot run on this device (widths, llvmpipe's loop
    /// limit, storage bindings); returns the GEMM kernel the run takes ([`GpuBackend::gemm`]).
    fn check_network(&self, problem: &ReachProblem) -> Result<Gemm, GpuError> {
        let n = problem.dynamics.n;
        let widths = problem.network.widths();
        if widths.iter().any(|&w| w == 0 || w > 1 << 18) || widths[0] != n {
            return Err(GpuError::Problem(format!(
                "network widths {widths:?} not supported"
            )));
        }
        let loops = bound_kernel_loops(&widths);
        if self.ctx.info.name.contains("llvmpipe") && loops > LLVMPIPE_LOOP_LIMIT {
            return Err(GpuError::TooLarge(format!(
                "network widths {widths:?}: a bound kernel would run ~{loops} loop iterations \
                 per thread, and llvmpipe silently ends a shader's loops after \
                 {LLVMPIPE_LOOP_LIMIT}; use the CPU engine (--backend cpu) or a real GPU"
            )));
        }
        let stage_limit = self.ctx.limits.max_storage_buffers_per_shader_stage;
        if stage_limit < STORAGE_BINDINGS {
            return Err(GpuError::TooLarge(format!(
                "the kernels bind {STORAGE_BINDINGS} storage buffers; the device allows \
                 {stage_limit}"
            )));
        }
        let rows_limit = self.ctx.limits.max_compute_workgroups_per_dimension as usize;
        let flat_runs = widths.iter().all(|&w| w <= rows_limit)
            && flat_gemm_loops(&widths) <= LLVMPIPE_LOOP_LIMIT;
        Ok(match self.gemm {
            Gemm::Flat if !flat_runs => Gemm::Tiles,
            g => g,
        })
    }
}

/// An upper estimate of the loop iterations one thread of the bound kernels runs for a network
/// of `widths` (input first): `bwd_scale`'s loops over a layer's neurons and its input's, and
/// the GEMM's loop over its inner width in tiles of 16 (with up to 24 inner iterations each
/// where the driver does not unroll them); the other kernels loop over the input's coordinates
/// and the outputs. Measured on lavapipe with [2, w, 2] networks: w = 45,000 (estimate 70,325)
/// agrees with the CPU, w = 60,000 (93,750) gives sets narrower than the CPU's.
fn bound_kernel_loops(widths: &[usize]) -> usize {
    let backward = widths.windows(2).map(|w| w[0] + w[1]).max().unwrap_or(0);
    let gemm = widths
        .iter()
        .map(|w| w.div_ceil(16) * 25)
        .max()
        .unwrap_or(0);
    backward.max(gemm)
}

/// Loop iterations a thread of `gemm_flat` runs for the widest product (every layer width is
/// an inner dimension, forward or transposed): per `k`, one pass and a load loop of up to
/// `GEMM_FLAT_BLOCK`. It has no loop check, so past llvmpipe's limit the tiles run instead.
fn flat_gemm_loops(widths: &[usize]) -> usize {
    let per_k = 1 + super::kernels::GEMM_FLAT_BLOCK as usize;
    widths.iter().max().map_or(0, |&w| w * per_k)
}

impl Backend for GpuBackend {
    /// Thousands of boxes: a step of 4,096 boxes of a 2×400×400×400×2 network takes 2–5 ms
    /// on an H100, of 256 boxes nearly as long.
    fn preferred_batch(&self) -> usize {
        8192
    }

    fn name(&self) -> String {
        match self.precision {
            Precision::F32 => format!("gpu ({}, f32)", self.ctx.info.name),
            Precision::F64 => format!("gpu ({}, f64)", self.ctx.info.name),
        }
    }

    fn supports(
        &self,
        problem: &ReachProblem,
        settings: &ReachSettings,
    ) -> Result<(), Unsupported> {
        GpuBackend::runs(problem, settings)?;
        // Continuous time runs in f32 too: its step enters as an enclosure (codegen
        // `h_enclosure`), the arithmetic is outward; the sampled model's host step is f64 alone.
        if matches!(problem.time, TimeModel::Sampled { .. }) && self.precision == Precision::F32 {
            return Err(Unsupported::Sampled("f32 (--f32)"));
        }
        Ok(())
    }

    /// The device runs every tube to its end; tubes are cut where a set is absorbed, at the
    /// sample where the CPU engine stops them (`reach::absorb`).
    fn reach(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        let mut result = self.reach_to_the_end(problem, initial, settings, progress)?;
        for tube in &mut result.boxes {
            crate::reach::absorb::cut(problem, tube);
        }
        Ok(result)
    }
}

impl GpuBackend {
    /// [`Backend::reach`] before the tubes are cut at their absorbed samples.
    fn reach_to_the_end(
        &self,
        problem: &ReachProblem,
        initial: &[IntervalBox],
        settings: &ReachSettings,
        progress: &(dyn Fn(usize, usize) + Sync),
    ) -> Result<ReachResult, ReachError> {
        problem.check_initial(initial)?;
        settings.validate()?;
        problem.check_time(settings)?;
        if let Err(u) = Backend::supports(self, problem, settings) {
            return Err(GpuError::Unsupported(crate::reach::refusal(u)).into());
        }
        if matches!(problem.time, TimeModel::Sampled { .. }) {
            return self.sampled(problem, initial, settings, progress);
        }
        let continuous = problem.time == TimeModel::Continuous;
        let start = Instant::now();
        let every = settings.every.max(1);
        let steps = problem.steps;
        let slots = steps.div_ceil(every);
        let safe = problem.safe_set_for(settings.method);
        // The frames the sets are kept in (two where they are met with their x-boxes) and each
        // box's sets in them before the first step, with the x-box they share.
        let frames = problem.frames(settings);
        let meet = frames.len() > 1;
        let starts: Vec<(Vec<IntervalBox>, IntervalBox)> = initial
            .iter()
            .map(|b| start_sets(&frames, settings.method, b))
            .collect();
        let known_of = |k: &IntervalBox| meet.then_some(k.clone());
        let mut tubes: Vec<Tube> = initial
            .iter()
            .zip(&starts)
            .map(|(b, (sets, known))| Tube {
                tube: vec![sample_of(problem, safe, &sets[0], 0.0, known_of(known))],
                ..Tube::new(b.clone())
            })
            .collect();
        if initial.is_empty() || steps == 0 {
            return Ok(ReachResult {
                boxes: tubes,
                timing: ReachTiming::default(),
            });
        }
        let gemm = self.check_network(problem)?;
        let chunk = self.chunk_size(problem, settings, initial.len());
        let mut setups = Vec::new();
        for (f, frame) in frames.iter().enumerate() {
            let shape = Shape::new(frame, settings);
            let mut margins = MarginMap::for_problem(frame, settings, self.precision);
            margins.pad_loops = self.pad_loops;
            // The other frame, where frames are met: its coordinates, and whether this frame's
            // slabs are clipped by its sets (continuous time, `meet_slabs`).
            let with = meet.then(|| Meet {
                other: frames[1 - f].transform.as_ref(),
                clip_slabs: continuous && problem.meet_slabs_applies(settings),
            });
            let source =
                problem_wgsl(frame, settings, shape.flags, self.precision, &margins, with)?;
            let kernels = self.kernels.get(
                &self.ctx,
                self.cache_dir.as_deref(),
                self.precision,
                source,
                Variant {
                    settle: meet && f == 0,
                    gemm,
                    continuous,
                },
            )?;
            let bufs = self.buffers(frame, &shape, &margins, chunk)?;
            setups.push((shape, kernels, bufs));
        }
        let runs: Vec<FrameRun> = frames
            .iter()
            .zip(&setups)
            .map(|(problem, (shape, kernels, bufs))| FrameRun {
                problem,
                shape,
                kernels,
                bufs,
            })
            .collect();
        let n_chunks = initial.len().div_ceil(chunk);
        if continuous {
            for (ci, part) in starts.chunks(chunk).enumerate() {
                let first = ci * chunk;
                self.continuous_chunk(
                    &runs,
                    settings,
                    part,
                    &mut tubes[first..first + part.len()],
                    &|s| progress(((ci * steps + s) / n_chunks).min(steps), steps),
                )?;
            }
            return Ok(ReachResult {
                boxes: tubes,
                timing: ReachTiming {
                    reach_s: start.elapsed().as_secs_f64(),
                    minkowski_s: 0.0,
                },
            });
        }
        for (ci, part) in starts.chunks(chunk).enumerate() {
            let sets: Vec<Vec<IntervalBox>> = (0..frames.len())
                .map(|f| part.iter().map(|(s, _)| s[f].clone()).collect())
                .collect();
            let set_refs: Vec<&[IntervalBox]> = sets.iter().map(Vec::as_slice).collect();
            let known: Vec<IntervalBox> = part.iter().map(|(_, k)| k.clone()).collect();
            let res = self.run_chunk(&runs, &set_refs, &known, slots, &|s| {
                progress(((ci * steps + s) / n_chunks).min(steps), steps)
            })?;
            let first = ci * chunk;
            let met = res.get(1);
            // Turning snapshots into samples is per box: in parallel, or the host takes longer
            // than the device.
            tubes[first..first + part.len()]
                .par_iter_mut()
                .enumerate()
                .for_each(|(g, tube)| {
                    let read = Readback {
                        res: &res[0],
                        met,
                        g,
                        nb: part.len(),
                    };
                    fill_tube(problem, safe, tube, &read, every)
                });
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

/// A box's sets in every frame before the first step and the x-box they share: each frame's
/// initial state, met with the box of its coordinates around the meet of their x-boxes and
/// clipped to `S` where two frames are met (the CPU engine's `start` and `settle`).
fn start_sets(
    frames: &[&ReachProblem],
    method: ReachMethod,
    initial: &IntervalBox,
) -> (Vec<IntervalBox>, IntervalBox) {
    let mut sets: Vec<IntervalBox> = frames
        .iter()
        .map(|f| f.initial_state(initial, method))
        .collect();
    let known = frames
        .iter()
        .zip(&sets)
        .map(|(f, s)| f.x_box_in_safe_set(&s.lower, &s.upper, f.safe_set_for(method)))
        .reduce(|a, b| a.intersection(&b).unwrap_or(a))
        .unwrap_or_else(|| initial.clone());
    if frames.len() > 1 {
        for (f, set) in frames.iter().zip(&mut sets) {
            let around = f.frame_box(&known);
            *set = set.intersection(&around).unwrap_or_else(|| set.clone());
            clip_to_safe_set(&mut set.lower, &mut set.upper, &f.safe_set_for(method).z);
        }
    }
    (sets, known)
}

/// The recorded sample of frame 0's set `z` (radius 0 where frames are met), its x-box met with
/// the shared `known` where there is one (the CPU engine's `sample`).
fn sample_of(
    problem: &ReachProblem,
    safe: &SafeSet,
    z: &IntervalBox,
    t: f64,
    known: Option<IntervalBox>,
) -> TubeSample {
    let mut sample = problem.tube_sample(&z.lower, &z.upper, 0.0, t, safe);
    if let Some(met) = known.and_then(|k| sample.set.intersection(&k)) {
        sample.lower.clone_from(&met.lower);
        sample.upper.clone_from(&met.upper);
        sample.set = met;
    }
    sample
}

/// Box `g` of a chunk of `nb` in its readback: frame 0's, and frame 1's where frames are met
/// (its snapshots hold the shared x-boxes).
struct Readback<'a> {
    res: &'a ChunkResult,
    met: Option<&'a ChunkResult>,
    g: usize,
    nb: usize,
}

/// A tube's samples from a chunk's readback (the CPU engine's recording rules).
fn fill_tube(
    problem: &ReachProblem,
    safe: &SafeSet,
    tube: &mut Tube,
    read: &Readback,
    every: usize,
) {
    let (res, g, nb) = (read.res, read.g, read.nb);
    let n = problem.dynamics.n;
    let sw = 2 * n + 1; // a box's record: lower, upper, radius
    let steps = problem.steps;
    let st = res.flags[FLAG_W * g + 1];
    let stop = res.flags[FLAG_W * g + 2] as usize + 1; // 1-based step at which it stopped
    tube.exact_steps = res.flags[FLAG_W * g + 3] as usize;
    tube.enclosed_steps = res.flags[FLAG_W * g + 4] as usize;
    let sample = |v: &[f64], known: Option<&[f64]>, t: f64| {
        let z = IntervalBox {
            lower: v[..n].to_vec(),
            upper: v[n..2 * n].to_vec(),
        };
        let known = known.map(|k| IntervalBox {
            lower: k[..n].to_vec(),
            upper: k[n..2 * n].to_vec(),
        });
        match known {
            Some(_) => sample_of(problem, safe, &z, t, known),
            None => problem.tube_sample(&z.lower, &z.upper, v[2 * n], t, safe),
        }
    };
    for (slot, s) in (1..=steps)
        .filter(|s| s % every == 0 || *s == steps)
        .enumerate()
    {
        if st != status::LIVE && s >= stop {
            break;
        }
        let at = (slot * nb + g) * sw;
        let known = read.met.map(|m| &m.snap[at..at + sw]);
        tube.tube
            .push(sample(&res.snap[at..at + sw], known, s as f64 * problem.dt));
    }
    let t = stop as f64 * problem.dt;
    tube.end = match st {
        // The step's start, as the CPU engine reports it.
        status::NO_BOUND => TubeEnd::NoCertifiedBound {
            t: t - problem.dt,
            beyond_c: problem.certified_on_all_of_c(),
        },
        status::LEFT_REGION => {
            let known = read.met.map(|_| &res.known[g * 2 * n..(g + 1) * 2 * n]);
            tube.tube
                .push(sample(&res.state[g * sw..(g + 1) * sw], known, t));
            TubeEnd::LeftRegion { t }
        }
        status::INVERTED => TubeEnd::Inverted {
            t,
            cause: crate::reach::Inversion::Unattributed,
        },
        status::NON_FINITE => TubeEnd::NonFinite { t },
        _ => TubeEnd::Horizon,
    };
}

//! The continuous time model on the device (docs/design.md §7.1 item 3b, §7.4): each step of
//! a chunk is one submit of `slabs_of` (each live box's slabs, or hull, as its bound boxes),
//! the bound kernels unchanged and `cstep` (the common path's box-step,
//! `shaders/continuous.wgsl`); then the host reads every box's result back, steps the boxes the
//! device left to it with the CPU engine's own step ([`CpuBackend::continuous_step`]: a tube's
//! first step, guesses refused or not proven, re-guesses, Picard–Lindelöf, the ends), writes
//! their states back, and records every box's sample and flowpipe by the CPU engine's rules
//! ([`record_sample`]). Where two frames are met, `cpipes` guesses and meets both frames' moving
//! boxes before their bounds and steps and `cmeet` meets their sets after
//! (`shaders/cmeet.wgsl`): a box-step is the device's only where both frames' were, else the
//! host's step takes both frames. What the device runs is [`refused`]'s complement.

use std::sync::atomic::Ordering::Relaxed;

use super::super::buffers::{device_bytes, from_device_bytes};
use super::super::codegen::{flag_words, round_down, round_up, FLAG_W};
use super::super::GpuError;
use super::chunk::FrameRun;
use super::plan::{encode_steps, StepPlan};
use super::sample_of;
use super::GpuBackend;
use crate::boxes::IntervalBox;
use crate::reach::cpu::{record_sample, MetState, StepState};
use crate::reach::{CpuBackend, ReachError, ReachMethod, ReachSettings, Tube, Unsupported};

/// A box-step `cstep` took on the device (flags word 5); anything else is the host's.
const C_DEVICE: u32 = 1;

/// Reals per box in `cont` (shaders/continuous.wgsl's `CW`): the step state (`6n + 1`), the
/// step's moving box: its hull (`2n`), faces' rates (`2n`) and slabs' depths (`2n`), and the
/// other frame's set over the step with its pad (`2n + 1`, where slabs are clipped by it).
pub(super) fn cw(n: usize) -> usize {
    14 * n + 2
}

/// The settings of a continuous run the device's step does not take, named as a user sets
/// them: the Minkowski method (the CPU guesses moving boxes under the disturbance method alone,
/// so every step would be the host's). Every `exact` runs (the device's step meets the
/// filter's proven piece and its closed form's enclosures on the slabs as the CPU's does:
/// `shaders/slab_step.wgsl`), in one frame or two met (`shaders/cmeet.wgsl`, the slabs clipped
/// by the other frame's sets with `meet_slabs`), with any number of validated substeps (the
/// device's step is `dt / substeps`, an enclosure of it in f32: `H_LO`, `H_HI`), in f64 or f32,
/// with the pieces' lattice and the second-order Taylor rates (`taylor3`: `piece_taylor3`) as
/// the CPU's step takes them.
pub(super) fn refused(settings: &ReachSettings) -> Result<(), Unsupported> {
    match settings.method {
        ReachMethod::Minkowski => Err(Unsupported::Continuous("method = \"minkowski\"")),
        ReachMethod::Disturbance => Ok(()),
    }
}

/// A box of a chunk while it runs: its state as the host keeps it (the Picard guess lives
/// here alone), in x too where frames are met, the hull of its flowpipes since the last
/// sample, whether its tube ended.
struct Held {
    state: StepState,
    met: Option<MetState>,
    swept: Option<IntervalBox>,
    done: bool,
}
/// A box's state as `cont` holds it, rounded outward to the device's numbers (the rates are
/// a guess's inputs: as they are).
fn put_state(c: &mut [f64], s: &StepState, n: usize, prec: super::super::Precision) {
    for j in 0..n {
        c[j] = round_down(s.set.lower[j], prec);
        c[n + j] = round_up(s.set.upper[j], prec);
    }
    let zero = vec![0.0; n];
    let rates = s.rates.as_ref().map_or((&zero, &zero), |(l, u)| (l, u));
    let before = s.before.as_ref().map_or((&zero, &zero), |(l, u)| (l, u));
    for (k, v) in [rates.0, rates.1, before.0, before.1]
        .into_iter()
        .enumerate()
    {
        c[(2 + k) * n..(3 + k) * n].copy_from_slice(v);
    }
    c[6 * n] = match (&s.rates, &s.before) {
        (None, _) => 0.0,
        (Some(_), None) => 1.0,
        (Some(_), Some(_)) => 2.0,
    };
}

/// The state after a box-step the device took, its hull, and the Picard guess the CPU keeps
/// after a proven guessed box (the hull of its faces' rates, `guess_holds`).
fn stepped(c: &[f64], n: usize) -> (StepState, IntervalBox) {
    let v = |at: usize| c[at..at + n].to_vec();
    let rates = c[6 * n] as u32;
    let (s_lo, s_hi) = (v(8 * n + 1), v(9 * n + 1));
    let guess = (
        s_lo.iter().zip(&s_hi).map(|(a, b)| a.min(*b)).collect(),
        s_lo.iter().zip(&s_hi).map(|(a, b)| a.max(*b)).collect(),
    );
    let state = StepState {
        set: IntervalBox {
            lower: v(0),
            upper: v(n),
        },
        rates: (rates >= 1).then(|| (v(2 * n), v(3 * n))),
        before: (rates >= 2).then(|| (v(4 * n), v(5 * n))),
        guess: Some(guess),
    };
    let hull = IntervalBox {
        lower: v(6 * n + 1),
        upper: v(7 * n + 1),
    };
    (state, hull)
}

/// What one step's readback holds, per frame: `cont` and the flags; where frames are met, the
/// sets' shared x-box after the meet and the flowpipes' (frame 0's and frame 1's `known`).
struct StepRead {
    cont: Vec<Vec<f64>>,
    flags: Vec<Vec<u32>>,
    known: Vec<Vec<f64>>,
}

/// Box `g`'s x-box in a `known` buffer's reals.
fn known_box(k: &[f64], g: usize, n: usize) -> IntervalBox {
    IntervalBox {
        lower: k[g * 2 * n..g * 2 * n + n].to_vec(),
        upper: k[g * 2 * n + n..(g + 1) * 2 * n].to_vec(),
    }
}

impl GpuBackend {
    /// Runs one chunk of boxes over the horizon in continuous time: `starts` are their initial
    /// sets in every frame of `runs` (two where they are met) with the x-box they share,
    /// `tubes` their tubes with the first sample.
    pub(super) fn continuous_chunk(
        &self,
        runs: &[FrameRun],
        settings: &ReachSettings,
        starts: &[(Vec<IntervalBox>, IntervalBox)],
        tubes: &mut [Tube],
        progress: &dyn Fn(usize),
    ) -> Result<(), ReachError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let prec = self.precision;
        let problem = runs[0].problem;
        let meet = runs.len() > 1;
        let (n, boxes, w) = (problem.dynamics.n, starts.len(), cw(problem.dynamics.n));
        let safe = problem.safe_set_for(settings.method);
        // Validated substeps: `k` steps of `h` a `dt` (the device's `[H_LO, H_HI]`), as the CPU
        // engine's `horizon` takes them.
        let k = problem.steps_per_dt();
        let h = problem.dt / k as f64;
        let every = settings.every.max(1);
        let mut held: Vec<Held> = starts
            .iter()
            .map(|(sets, known)| Held {
                state: StepState::start(sets[0].clone()),
                met: meet.then(|| MetState {
                    x: StepState::start(sets[1].clone()),
                    known: known.clone(),
                }),
                swept: None,
                done: false,
            })
            .collect();
        let mut cont = vec![vec![0.0; boxes * w]; runs.len()];
        for (g, b) in held.iter().enumerate() {
            put_states(&mut cont, g, w, b, n, prec);
        }
        if cont.iter().flatten().any(|v| v.abs() > 1e30) {
            return Err(GpuError::Problem("an initial box exceeds 1e30".into()).into());
        }
        // The host's step, its network packed once for the run's steps; with substeps, of a copy
        // of the problem whose `dt` is the substep (the host's step reports its sample, ends and
        // flowpipe as of one `dt` from 0: here `h`, placed at the substep's start below).
        let sub;
        let host_problem = match k {
            1 => problem,
            _ => {
                let mut p = problem.clone().with_time(problem.time, 1);
                p.dt = h;
                if let Some(x) = p.in_x.as_mut() {
                    x.dt = h;
                }
                sub = p;
                &sub
            }
        };
        let host_step = CpuBackend.host_step(host_problem, settings)?;
        let mut flags = vec![0u32; flag_words(boxes)];
        for (r, c) in runs.iter().zip(&cont) {
            q.write_buffer(&r.bufs.cont, 0, &device_bytes(c, prec));
            q.write_buffer(&r.bufs.flags, 0, bytemuck::cast_slice(&flags));
        }
        // Where frames are met, the flowpipes' shared x-box lives in frame 1's `known`.
        let pipe_known = &runs[runs.len() - 1].bufs.known;
        let plan = |f: usize| StepPlan {
            device: d,
            kernels: runs[f].kernels,
            bufs: runs[f].bufs,
            shape: runs[f].shape,
            nb: (runs[f].shape.faces * boxes) as u32,
            boxes: boxes as u32,
            known: pipe_known,
            tick: false,
            ops: Vec::new(),
        };
        let mut ops = Vec::new();
        let met_ops = match meet {
            true => Some(plan(0).continuous_meet(runs[1].bufs).ok_or_else(|| {
                GpuError::Device("the continuous meet's kernels were not compiled".into())
            })?),
            false => None,
        };
        let [pipes, settle] = match met_ops {
            Some([a, b]) => [Some(a), Some(b)],
            None => [None, None],
        };
        ops.extend(pipes);
        for f in 0..runs.len() {
            ops.extend(plan(f).build());
        }
        ops.extend(settle);
        self.check_groups(&ops)?;
        for step in 0..problem.steps * k {
            if held.iter().all(|b| b.done) {
                break;
            }
            q.submit([encode_steps(d, ops.iter(), 1)]);
            let read = self.read_step(runs, boxes * w, boxes, meet)?;
            if read.flags.iter().any(|f| f[FLAG_W * boxes + 1] != 0) {
                return Err(self.loops_cut_short().into());
            }
            let dev_flags = &read.flags[0];
            // The CPU engine's times and recording (`horizon`): samples at the last substep of
            // a `dt` alone.
            let (outer, last_sub) = (step / k, (step + 1) % k == 0);
            let t0 = outer as f64 * problem.dt + (step % k) as f64 * h;
            let t = match last_sub {
                true => (outer + 1) as f64 * problem.dt,
                false => outer as f64 * problem.dt + ((step % k) + 1) as f64 * h,
            };
            let record = last_sub && ((outer + 1) % every == 0 || outer + 1 == problem.steps);
            let live = held.iter().filter(|b| !b.done).count();
            let (mut host, mut changed) = (Vec::new(), false);
            for (g, b) in held.iter_mut().enumerate().filter(|(_, b)| !b.done) {
                if dev_flags[g * FLAG_W + 5] != C_DEVICE {
                    host.push(g);
                    continue;
                }
                for (c, dev) in cont.iter_mut().zip(&read.cont) {
                    c[g * w..(g + 1) * w].copy_from_slice(&dev[g * w..(g + 1) * w]);
                }
                // The step's sources (frame 0's flags words 3 and 4: the proven piece, the
                // enclosures; the CPU counts the first frame's).
                tubes[g].exact_steps += usize::from(dev_flags[g * FLAG_W + 3] != 0);
                tubes[g].enclosed_steps += usize::from(dev_flags[g * FLAG_W + 4] != 0);
                let (state, hull) = stepped(&read.cont[0][g * w..(g + 1) * w], n);
                let (pipe, sample) = match meet {
                    true => {
                        let known = known_box(&read.known[0], g, n);
                        b.met = Some(MetState {
                            x: stepped(&read.cont[1][g * w..(g + 1) * w], n).0,
                            known: known.clone(),
                        });
                        let sample = sample_of(problem, safe, &state.set, t, Some(known));
                        (known_box(&read.known[1], g, n), sample)
                    }
                    false => {
                        let pipe = problem.x_box_in_safe_set(&hull.lower, &hull.upper, safe);
                        let set = &state.set;
                        (
                            pipe,
                            problem.tube_sample(&set.lower, &set.upper, 0.0, t, safe),
                        )
                    }
                };
                b.state = state;
                let ended = record_sample(
                    &problem.region,
                    &mut tubes[g],
                    &mut b.swept,
                    Some(&pipe),
                    sample,
                    (t, h),
                    record,
                );
                b.done = ended;
                changed |= ended;
            }
            changed |= !host.is_empty();
            let [on_device, on_host] = &*self.continuous_steps;
            on_device.fetch_add(live - host.len(), Relaxed);
            on_host.fetch_add(host.len(), Relaxed);
            if !host.is_empty() {
                let states: Vec<StepState> = host.iter().map(|&g| held[g].state.clone()).collect();
                let mets: Vec<MetState> =
                    host.iter().filter_map(|&g| held[g].met.clone()).collect();
                let outcomes = host_step.step_met(&states, &mets)?;
                for (&g, o) in host.iter().zip(outcomes) {
                    let b = &mut held[g];
                    tubes[g].exact_steps += usize::from(o.sources.0);
                    tubes[g].enclosed_steps += usize::from(o.sources.1);
                    match (o.sample, o.end) {
                        (Some(sample), _) => {
                            let sample = crate::reach::TubeSample { t, ..sample };
                            let pipe = o.flowpipe.as_ref();
                            b.done = record_sample(
                                &problem.region,
                                &mut tubes[g],
                                &mut b.swept,
                                pipe,
                                sample,
                                (t, h),
                                record,
                            );
                        }
                        (None, Some(end)) => {
                            tubes[g].end = end.later(t0);
                            b.done = true;
                        }
                        (None, None) => {
                            return Err(GpuError::Device(
                                "the host's step neither stepped nor ended a box".into(),
                            )
                            .into())
                        }
                    }
                    if !b.done {
                        b.state = o.state;
                        b.met = o.met;
                        put_states(&mut cont, g, w, b, n, prec);
                    }
                }
            }
            if changed {
                for (g, b) in held.iter().enumerate() {
                    flags[g * FLAG_W + 1] = u32::from(b.done);
                }
                for (r, c) in runs.iter().zip(&cont) {
                    q.write_buffer(&r.bufs.cont, 0, &device_bytes(c, prec));
                    q.write_buffer(&r.bufs.flags, 0, bytemuck::cast_slice(&flags));
                }
            }
            if last_sub {
                progress(outer + 1);
            }
        }
        Ok(())
    }

    /// One readback after a step: each frame's `cont` (`reals`) and flags, and where frames are
    /// met their `known` buffers (through each frame's own staging buffer).
    fn read_step(
        &self,
        runs: &[FrameRun],
        reals: usize,
        boxes: usize,
        meet: bool,
    ) -> Result<StepRead, GpuError> {
        let n = runs[0].problem.dynamics.n;
        let bytes = self.precision.bytes();
        let cont_bytes = reals as u64 * bytes;
        let flag_bytes = (flag_words(boxes) * 4) as u64;
        let known_bytes = if meet {
            (boxes * 2 * n) as u64 * bytes
        } else {
            0
        };
        let mut read = StepRead {
            cont: Vec::new(),
            flags: Vec::new(),
            known: Vec::new(),
        };
        for r in runs {
            let bufs = r.bufs;
            let mut copies = vec![(&bufs.cont, cont_bytes), (&bufs.flags, flag_bytes)];
            if meet {
                copies.push((&bufs.known, known_bytes));
            }
            let (c, f, k) = self.read_staging(bufs, &copies, |bytes| {
                let (a, rest) = bytes.split_at(cont_bytes as usize);
                let (b, k) = rest.split_at(flag_bytes as usize);
                (
                    from_device_bytes(a, self.precision),
                    bytemuck::pod_collect_to_vec(b),
                    from_device_bytes(k, self.precision),
                )
            })?;
            read.cont.push(c);
            read.flags.push(f);
            read.known.push(k);
        }
        Ok(read)
    }
}

/// Box `g`'s state in every frame's `cont` (`w` reals a box), from the host's copy.
fn put_states(
    cont: &mut [Vec<f64>],
    g: usize,
    w: usize,
    b: &Held,
    n: usize,
    prec: super::super::Precision,
) {
    let frames = std::iter::once(&b.state).chain(b.met.as_ref().map(|m| &m.x));
    for (c, s) in cont.iter_mut().zip(frames) {
        put_state(&mut c[g * w..(g + 1) * w], s, n, prec);
    }
}

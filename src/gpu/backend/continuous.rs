//! The continuous time model on the device (docs/design.md §7.1 item 3b, §7.4): each step of
//! a chunk is one submit of `slabs_of` (each live box's slabs, or hull, as its bound boxes),
//! the bound kernels unchanged and `cstep` (the common path's box-step,
//! `shaders/continuous.wgsl`); then the host reads every box's result back, steps the boxes the
//! device left to it with the CPU engine's own step ([`CpuBackend::continuous_step`]: a tube's
//! first step, guesses refused or not proven, re-guesses, Picard–Lindelöf, the ends), writes
//! their states back, and records every box's sample and flowpipe by the CPU engine's rules
//! ([`record_sample`]). What the device runs is [`refused`]'s complement.

use std::sync::atomic::Ordering::Relaxed;

use super::super::buffers::{device_bytes, flatten_network, from_device_bytes};
use super::super::codegen::{flag_words, round_down, round_up, FLAG_W};
use super::super::GpuError;
use super::chunk::FrameRun;
use super::layout::Buffers;
use super::plan::{encode_steps, StepPlan};
use super::GpuBackend;
use crate::boxes::IntervalBox;
use crate::reach::cpu::{record_sample, StepState};
use crate::reach::{
    CpuBackend, ReachError, ReachMethod, ReachProblem, ReachSettings, Tube, Unsupported,
};

/// A box-step `cstep` took on the device (flags word 5); anything else is the host's.
const C_DEVICE: u32 = 1;

/// Reals per box in `cont` (shaders/continuous.wgsl's `CW`): the step state (`6n + 1`), the
/// step's hull (`2n`) and its faces' rates (`2n`).
fn cw(n: usize) -> usize {
    10 * n + 1
}

/// The settings of a continuous run the device's step does not take yet, named as a user sets
/// them: the Minkowski method (the CPU guesses moving boxes under the disturbance method alone,
/// so every step would be the host's), two frames met, validated substeps. Every `exact` runs:
/// the device's step meets the filter's proven piece and its closed form's enclosures on the
/// slabs as the CPU's does (`shaders/slab_step.wgsl`).
pub(super) fn refused(problem: &ReachProblem, settings: &ReachSettings) -> Result<(), Unsupported> {
    let what = if settings.method == ReachMethod::Minkowski {
        "method = \"minkowski\""
    } else if problem.frames(settings).len() > 1 {
        "intersect_x = true (two frames met)"
    } else if problem.steps_per_dt() > 1 {
        "substeps > 1"
    } else {
        return Ok(());
    };
    Err(Unsupported::Continuous(what))
}

/// A box of a chunk while it runs: its state as the host keeps it (the Picard guess lives
/// here alone), the hull of its flowpipes since the last sample, whether its tube ended.
struct Held {
    state: StepState,
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

impl GpuBackend {
    /// Runs one chunk of boxes over the horizon in continuous time: `sets` are their initial
    /// states in the frame, `tubes` their tubes with the first sample.
    pub(super) fn continuous_chunk(
        &self,
        run: &FrameRun,
        settings: &ReachSettings,
        sets: &[IntervalBox],
        tubes: &mut [Tube],
        progress: &dyn Fn(usize),
    ) -> Result<(), ReachError> {
        let (d, q) = (&self.ctx.device, &self.ctx.queue);
        let prec = self.precision;
        let problem = run.problem;
        let (n, boxes, w) = (problem.dynamics.n, sets.len(), cw(problem.dynamics.n));
        let safe = problem.safe_set_for(settings.method);
        let h = problem.dt;
        let every = settings.every.max(1);
        let mut held: Vec<Held> = sets
            .iter()
            .map(|s| Held {
                state: StepState {
                    set: s.clone(),
                    rates: None,
                    before: None,
                    guess: None,
                },
                swept: None,
                done: false,
            })
            .collect();
        let mut cont = vec![0.0; boxes * w];
        for (c, b) in cont.chunks_mut(w).zip(&held) {
            put_state(c, &b.state, n, prec);
        }
        if cont.iter().any(|v| v.abs() > 1e30) {
            return Err(GpuError::Problem("an initial box exceeds 1e30".into()).into());
        }
        // The host's step, its network packed once for the run's steps.
        let host_step = CpuBackend.host_step(problem, settings)?;
        let mut flags = vec![0u32; flag_words(boxes)];
        q.write_buffer(&run.bufs.cont, 0, &device_bytes(&cont, prec));
        q.write_buffer(&run.bufs.flags, 0, bytemuck::cast_slice(&flags));
        let ops = StepPlan {
            device: d,
            kernels: run.kernels,
            bufs: run.bufs,
            shape: run.shape,
            offsets: flatten_network(&problem.network).1,
            nb: (run.shape.faces * boxes) as u32,
            boxes: boxes as u32,
            known: &run.bufs.known,
            tick: false,
            ops: Vec::new(),
        }
        .build();
        self.check_groups(&ops)?;
        for step in 0..problem.steps {
            if held.iter().all(|b| b.done) {
                break;
            }
            q.submit([encode_steps(d, ops.iter(), 1)]);
            let (dev, dev_flags) = self.read_cont(run.bufs, boxes * w, boxes)?;
            if dev_flags[FLAG_W * boxes + 1] != 0 {
                return Err(self.loops_cut_short().into());
            }
            let t = (step + 1) as f64 * problem.dt;
            let record = (step + 1) % every == 0 || step + 1 == problem.steps;
            let live = held.iter().filter(|b| !b.done).count();
            let (mut host, mut changed) = (Vec::new(), false);
            for (g, b) in held.iter_mut().enumerate().filter(|(_, b)| !b.done) {
                if dev_flags[g * FLAG_W + 5] != C_DEVICE {
                    host.push(g);
                    continue;
                }
                let c = &dev[g * w..(g + 1) * w];
                cont[g * w..(g + 1) * w].copy_from_slice(c);
                // The step's sources (flags words 3 and 4: the proven piece, the enclosures).
                tubes[g].exact_steps += usize::from(dev_flags[g * FLAG_W + 3] != 0);
                tubes[g].enclosed_steps += usize::from(dev_flags[g * FLAG_W + 4] != 0);
                let (state, hull) = stepped(c, n);
                let pipe = problem.x_box_in_safe_set(&hull.lower, &hull.upper, safe);
                let set = &state.set;
                let sample = problem.tube_sample(&set.lower, &set.upper, 0.0, t, safe);
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
                let outcomes = host_step.step(&states)?;
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
                            tubes[g].end = end.later(step as f64 * problem.dt);
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
                        put_state(&mut cont[g * w..(g + 1) * w], &b.state, n, prec);
                    }
                }
            }
            if changed {
                for (g, b) in held.iter().enumerate() {
                    flags[g * FLAG_W + 1] = u32::from(b.done);
                }
                q.write_buffer(&run.bufs.cont, 0, &device_bytes(&cont, prec));
                q.write_buffer(&run.bufs.flags, 0, bytemuck::cast_slice(&flags));
            }
            progress(step + 1);
        }
        Ok(())
    }

    /// One readback of `cont` (`reals`) and the flags after a step.
    fn read_cont(
        &self,
        bufs: &Buffers,
        reals: usize,
        boxes: usize,
    ) -> Result<(Vec<f64>, Vec<u32>), GpuError> {
        let cont_bytes = reals as u64 * self.precision.bytes();
        let flag_bytes = (flag_words(boxes) * 4) as u64;
        let copies = [(&bufs.cont, cont_bytes), (&bufs.flags, flag_bytes)];
        self.read_staging(bufs, &copies, |bytes| {
            let (a, b) = bytes.split_at(cont_bytes as usize);
            (
                from_device_bytes(a, self.precision),
                bytemuck::pod_collect_to_vec(b),
            )
        })
    }
}

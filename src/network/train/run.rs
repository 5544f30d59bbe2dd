//! The training loop: [`train`], [`resume`], each epoch's sample order and the Adam steps.
//! May import: every other part of the trainer, Adam, revival, the batched passes.

use std::path::Path;
use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;

use super::checkpoint::State;
use super::dataset::{check_dims, Dataset};
use super::loss::ChunkWorker;
use super::report::{evaluate, EpochStats, TrainReport};
use super::settings::{Precision, TrainSettings};
use crate::network::batch::{to_mlp, Scalar};
use crate::network::{revive, Mlp, NetworkError};

/// What the callback of [`train_until`] tells the loop after an epoch.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Flow {
    /// Run the next epoch.
    Continue,
    /// End the run here (early stopping): the network as it is is returned.
    Stop,
}

/// Trains `init` on `data`; calls `progress` after every epoch.
///
/// Returns the trained network (f64) and a report whose [`TrainReport::final_errors`] are
/// measured on that network. Writes checkpoints if [`TrainSettings::checkpoint`] is set.
pub fn train(
    init: Mlp,
    data: &Dataset,
    settings: &TrainSettings,
    mut progress: impl FnMut(&EpochStats),
) -> Result<(Mlp, TrainReport), NetworkError> {
    train_until(init, data, settings, |e, _| {
        progress(e);
        Flow::Continue
    })
}

/// As [`train`], with a callback after every epoch that sees the network (built on demand by
/// the closure it is given) and may end the run: early stopping at an accuracy target.
pub fn train_until(
    init: Mlp,
    data: &Dataset,
    settings: &TrainSettings,
    progress: impl FnMut(&EpochStats, &dyn Fn() -> Mlp) -> Flow,
) -> Result<(Mlp, TrainReport), NetworkError> {
    check_inputs(&init, data, settings)?;
    match settings.precision {
        Precision::F32 => {
            let state = State::<f32>::fresh(&init, data, settings);
            run(state, data, settings, progress, None)
        }
        Precision::F64 => {
            let state = State::<f64>::fresh(&init, data, settings);
            run(state, data, settings, progress, None)
        }
    }
}

/// Continues a run from a checkpoint written by [`train`] with the same data. With the same
/// settings the result is bitwise that of the uninterrupted run; `settings.epochs` may be
/// raised to train longer (the cosine schedule then follows the new length).
pub fn resume(
    checkpoint: &Path,
    data: &Dataset,
    settings: &TrainSettings,
    mut progress: impl FnMut(&EpochStats),
) -> Result<(Mlp, TrainReport), NetworkError> {
    resume_until(checkpoint, data, settings, |e, _| {
        progress(e);
        Flow::Continue
    })
}

/// As [`resume`], with [`train_until`]'s callback (early stopping).
pub fn resume_until(
    checkpoint: &Path,
    data: &Dataset,
    settings: &TrainSettings,
    progress: impl FnMut(&EpochStats, &dyn Fn() -> Mlp) -> Flow,
) -> Result<(Mlp, TrainReport), NetworkError> {
    settings.validate()?;
    data.validate()?;
    let bytes = std::fs::read(checkpoint).map_err(|source| NetworkError::Io {
        path: checkpoint.to_path_buf(),
        source,
    })?;
    match settings.precision {
        Precision::F32 => {
            let state = State::<f32>::load(&bytes, checkpoint, data, settings)?;
            check_inputs(&to_mlp(&state.params), data, settings)?;
            let from = state.epoch;
            run(state, data, settings, progress, Some(from))
        }
        Precision::F64 => {
            let state = State::<f64>::load(&bytes, checkpoint, data, settings)?;
            check_inputs(&to_mlp(&state.params), data, settings)?;
            let from = state.epoch;
            run(state, data, settings, progress, Some(from))
        }
    }
}

fn check_inputs(init: &Mlp, data: &Dataset, settings: &TrainSettings) -> Result<(), NetworkError> {
    settings.validate()?;
    data.validate()?;
    init.validate("<initial network>")?;
    check_dims(init, data)?;
    if settings.jacobian_weight > 0.0 && data.jacobians.is_none() {
        return Err(NetworkError::Settings {
            message: "jacobian_weight > 0 needs Dataset::jacobians".into(),
        });
    }
    if settings.ibp_radius.len() != 1 && settings.ibp_radius.len() != data.n_in {
        return Err(NetworkError::Settings {
            message: format!(
                "ibp_radius has {} entries, expected 1 or n_in = {}",
                settings.ibp_radius.len(),
                data.n_in
            ),
        });
    }
    if let Some(h) = &settings.secant_step {
        if h.len() != 1 && h.len() != data.n_in {
            return Err(NetworkError::Settings {
                message: format!(
                    "secant_step has {} entries, expected 1 or n_in = {}",
                    h.len(),
                    data.n_in
                ),
            });
        }
    }
    if let Some(i) = init
        .layers
        .iter()
        .flat_map(|l| l.weight.iter().chain(&l.bias))
        .position(|x| !x.is_finite())
    {
        return Err(NetworkError::NonFinite {
            path: "<initial network>".into(),
            name: "parameters".into(),
            index: i,
        });
    }
    Ok(())
}

/// The sample order of epoch `e`: every sample of positive weight, plus (late in training) the
/// hardest `fraction`, shuffled together.
pub(super) fn epoch_order(
    e: usize,
    active: &[usize],
    score: &[f64],
    settings: &TrainSettings,
) -> Vec<usize> {
    let mut order = active.to_vec();
    if settings.hard_examples_on(e) {
        let k = ((settings.hard_example_fraction * active.len() as f64).round() as usize)
            .min(active.len());
        if k > 0 {
            let mut ranked = active.to_vec();
            // Total order: larger score first, then lower index.
            let cmp = |a: &usize, b: &usize| score[*b].total_cmp(&score[*a]).then(a.cmp(b));
            if k < ranked.len() {
                ranked.select_nth_unstable_by(k - 1, cmp);
            }
            let mut hard = ranked[..k].to_vec();
            hard.sort_unstable();
            for _ in 0..settings.hard_example_repeats {
                order.extend_from_slice(&hard);
            }
        }
    }
    let mut rng = ChaCha8Rng::seed_from_u64(settings.seed);
    rng.set_stream(e as u64);
    order.shuffle(&mut rng);
    order
}

fn run<T: Scalar>(
    mut st: State<T>,
    data: &Dataset,
    settings: &TrainSettings,
    mut progress: impl FnMut(&EpochStats, &dyn Fn() -> Mlp) -> Flow,
    resumed_from: Option<usize>,
) -> Result<(Mlp, TrainReport), NetworkError> {
    let t_start = Instant::now();
    let (n_in, n_out) = (data.n_in, data.n_out);
    let tangents = settings.jacobian_weight > 0.0;
    let active: Vec<usize> = (0..data.len()).filter(|&s| data.weight(s) > 0.0).collect();
    let has_jac = data.jacobians.is_some();
    let mut value_err = vec![0.0f64; data.len()];
    let mut slope_err = vec![0.0f64; data.len()];
    let chunk_size = settings.chunk_size.clamp(1, settings.batch_size);
    let n_chunks = settings.batch_size.div_ceil(chunk_size);
    let mut workers: Vec<ChunkWorker<T>> = (0..n_chunks)
        .map(|_| ChunkWorker::new(&st.params))
        .collect();

    while st.epoch < settings.epochs {
        let e = st.epoch;
        let t0 = Instant::now();
        let lr = settings.lr_at(e);
        let order = epoch_order(e, &active, &st.score, settings);
        let ibp_radius = settings.ibp_radius_at(e, n_in);
        let mut loss_sum = 0.0;
        let (mut width_sum, mut width_count) = (0.0f64, 0usize);
        for batch in order.chunks(settings.batch_size) {
            let chunks: Vec<&[usize]> = batch.chunks(chunk_size).collect();
            let busy = &mut workers[..chunks.len()];
            let params = &st.params;
            busy.par_iter_mut()
                .zip(&chunks)
                .for_each(|(worker, chunk)| {
                    worker.gradient(
                        params,
                        data,
                        chunk,
                        batch.len(),
                        settings,
                        ibp_radius.as_deref(),
                    )
                });
            // Added in chunk order whatever the threads did: the step is deterministic.
            let (first, rest) = busy.split_first_mut().expect("a batch has a chunk");
            for worker in rest.iter() {
                for (g, gi) in first.grads.iter_mut().zip(&worker.grads) {
                    for (d, &v) in g.w.iter_mut().zip(&gi.w).chain(g.b.iter_mut().zip(&gi.b)) {
                        *d += v;
                    }
                }
            }
            for worker in busy.iter() {
                for visit in &worker.visits {
                    loss_sum += visit.loss;
                    st.score[visit.sample] = visit.loss;
                    value_err[visit.sample] = visit.value;
                    slope_err[visit.sample] = visit.slope;
                }
                width_sum += worker.width_sum;
            }
            if ibp_radius.is_some() {
                width_count += batch.len() * n_out;
            }
            st.adam.step(&mut st.params, &busy[0].grads, lr);
        }
        // Slope errors of an epoch without tangents: measure them on demand only at the end.
        let (mut max_e, mut sum_e, mut max_s) = (0.0f64, 0.0, 0.0f64);
        for &s in &active {
            max_e = max_e.max(value_err[s]);
            sum_e += value_err[s];
            max_s = max_s.max(slope_err[s]);
        }
        st.epoch += 1;
        let revived = if settings.revive_every > 0
            && st.epoch.is_multiple_of(settings.revive_every)
            && st.epoch < settings.epochs
        {
            let input = |i: usize| data.input(active[i]);
            let dormant = revive::dormant_neurons(&st.params, active.len(), input);
            let mut rng = revive::revival_rng(settings.seed, st.epoch);
            let (params, adam) = (&mut st.params, &mut st.adam);
            revive::revive_dormant(params, adam, &dormant, active.len(), input, &mut rng)
        } else {
            0
        };
        let stats = EpochStats {
            epoch: st.epoch,
            epochs: settings.epochs,
            loss: loss_sum / order.len().max(1) as f64,
            max_error: max_e,
            mean_error: sum_e / active.len().max(1) as f64,
            max_slope_error: (has_jac && tangents).then_some(max_s),
            lr,
            samples: order.len(),
            seconds: t0.elapsed().as_secs_f64(),
            ibp_width: ibp_radius
                .is_some()
                .then(|| width_sum / width_count.max(1) as f64),
            revived,
        };
        let finite = st
            .params
            .iter()
            .all(|p| p.w.iter().chain(&p.b).all(|x| x.to_f64().is_finite()));
        if !stats.loss.is_finite() || !finite {
            return Err(NetworkError::Diverged {
                epoch: st.epoch,
                loss: stats.loss,
            });
        }
        st.history.push(stats.clone());
        let params = &st.params;
        let flow = progress(&stats, &|| to_mlp(params));
        if let Some(path) = &settings.checkpoint {
            let periodic = settings.checkpoint_every > 0
                && st.epoch.checked_rem(settings.checkpoint_every) == Some(0);
            if periodic || st.epoch == settings.epochs || flow == Flow::Stop {
                st.save(settings, path)?;
            }
        }
        if flow == Flow::Stop {
            break;
        }
    }
    let mlp = to_mlp(&st.params);
    let final_errors = evaluate(&mlp, data)?;
    let report = TrainReport {
        epochs: st.history,
        final_errors,
        seconds: t_start.elapsed().as_secs_f64(),
        resumed_from,
    };
    Ok((mlp, report))
}

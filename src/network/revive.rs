//! Reviving dormant hidden ReLU neurons during training (ReDo).
//! May import: Adam and the batched passes of the network module; rand.
//!
//! Recycling dormant ReLU neurons during training (ReDo: Sokar et al., "The Dormant Neuron
//! Phenomenon in Deep Reinforcement Learning", ICML 2023).
//!
//! A hidden ReLU that is inactive on every training sample has zero gradient, so Adam never
//! brings it back. Trained on a 2-D state, the paper's networks lose most of their deeper
//! neurons this way early on (scenario 1's 2×400×400×400×2 kept 46 live neurons in its second
//! hidden layer and 150 in its third): the network that is left has too few linear regions to
//! follow `v`'s curvature, and its slope error shows it as a sawtooth (README, "Networks").
//!
//! Every few epochs the trainer gives each dormant neuron fresh incoming weights, a bias that
//! makes it active on a random share of the samples, and **zero outgoing weights**: the
//! network's function is unchanged at that moment, and training can move the neuron's kink to
//! where it lowers the loss.
//!
//! Adam's moments of the touched weights restart, but not from zero: Adam's bias correction
//! uses the global step count, so a second moment restarted at 0 late in training stays
//! underestimated for ~1/(1−β₂) steps, and `m̂/√v̂` moves each revived weight by up to ~6× the
//! learning rate per step, all in the gradient's direction (training's max error jumped from
//! 0.7 to 2.5–3.7 in the epoch after every revival). The first moment restarts at 0 and the
//! second at the mean of the live neurons' second moments of the same input or output, so a
//! revived weight steps like its live neighbours.

use rand::seq::index::sample;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use super::adam::Adam;
use super::batch::{Params, Scalar, Workspace};

/// Samples per forward pass when scanning for dormant neurons.
const SCAN_BATCH: usize = 1024;
/// Samples whose activations place a revived neuron's kink.
const PROBE_SAMPLES: usize = 4096;
/// A revived neuron is active on a share of the probe drawn uniformly from this range.
const ACTIVE_SHARE: (f64, f64) = (0.1, 0.9);

/// `dormant[k][j]`: hidden neuron `j` of layer `k` is inactive (pre-activation ≤ 0) at every
/// one of the `n` inputs `x(0..n)`.
pub(crate) fn dormant_neurons<'a, T: Scalar>(
    params: &[Params<T>],
    n: usize,
    x: impl Fn(usize) -> &'a [f64],
) -> Vec<Vec<bool>> {
    let Some(first) = params.first() else {
        return Vec::new();
    };
    let hidden = params.len() - 1;
    let mut dormant: Vec<Vec<bool>> = params[..hidden]
        .iter()
        .map(|p| vec![true; p.n_out])
        .collect();
    let mut ws = Workspace::<T>::new(params.len());
    let n_in = first.n_in;
    for start in (0..n).step_by(SCAN_BATCH) {
        let b = SCAN_BATCH.min(n - start);
        ws.load_inputs(n_in, b, false, |i| x(start + i));
        ws.forward(params);
        for (k, d) in dormant.iter_mut().enumerate() {
            let width = params[k].n_out;
            for row in ws.acts[k + 1].chunks_exact(width) {
                for (dj, &a) in d.iter_mut().zip(row) {
                    if a > T::ZERO {
                        *dj = false;
                    }
                }
            }
        }
    }
    dormant
}

/// Gives every neuron marked in `dormant` new incoming weights (of the typical norm of its
/// layer's live rows, random direction) and a bias that makes it active on a random share of
/// the probe inputs drawn from `x(0..n)`, and zeroes its outgoing weights; restarts Adam's
/// moments of all of these (see the module's documentation). The network's outputs are
/// unchanged. Returns how many neurons were revived.
pub(crate) fn revive_dormant<'a, T: Scalar>(
    params: &mut [Params<T>],
    adam: &mut Adam<T>,
    dormant: &[Vec<bool>],
    n: usize,
    x: impl Fn(usize) -> &'a [f64],
    rng: &mut ChaCha8Rng,
) -> usize {
    let count = dormant.iter().flatten().filter(|&&d| d).count();
    if count == 0 || n == 0 {
        return 0;
    }
    let probe: Vec<usize> = sample(rng, n, PROBE_SAMPLES.min(n)).into_vec();
    let n_in = params[0].n_in;
    let mut ws = Workspace::<T>::new(params.len());
    ws.load_inputs(n_in, probe.len(), false, |i| x(probe[i]));
    for (k, dead) in dormant.iter().enumerate() {
        if !dead.iter().any(|&d| d) {
            continue;
        }
        // The probe's inputs to layer k, with the neurons revived in earlier layers.
        ws.forward(params);
        let inputs: Vec<f64> = ws.acts[k].iter().map(|a| a.to_f64()).collect();
        let scale = typical_row_norm(&params[k], dead);
        for (j, _) in dead.iter().enumerate().filter(|(_, &d)| d) {
            let row = random_row(params[k].n_in, scale, rng);
            let share = rng.random_range(ACTIVE_SHARE.0..ACTIVE_SHARE.1);
            let bias = -quantile_of_projections(&inputs, &row, 1.0 - share);
            set_incoming(&mut params[k], j, &row, bias);
            zero_outgoing(&mut params[k + 1], j);
        }
        restart_moments(adam, k, dead);
    }
    count
}

/// Median Euclidean norm of the rows of `p.w` not marked dead (1 where all are).
fn typical_row_norm<T: Scalar>(p: &Params<T>, dead: &[bool]) -> f64 {
    let mut norms: Vec<f64> =
        p.w.chunks_exact(p.n_in)
            .zip(dead)
            .filter(|(_, &d)| !d)
            .map(|(row, _)| row.iter().map(|w| w.to_f64().powi(2)).sum::<f64>().sqrt())
            .collect();
    if norms.is_empty() {
        return 1.0;
    }
    norms.sort_by(f64::total_cmp);
    norms[norms.len() / 2]
}

/// A row of `n` weights with a uniformly random direction and Euclidean norm `norm`.
fn random_row(n: usize, norm: f64, rng: &mut ChaCha8Rng) -> Vec<f64> {
    loop {
        // Box–Muller normals give a uniformly random direction.
        let row: Vec<f64> = (0..n)
            .map(|_| {
                let (u, v): (f64, f64) = (rng.random_range(f64::EPSILON..1.0), rng.random());
                (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
            })
            .collect();
        let r = row.iter().map(|w| w * w).sum::<f64>().sqrt();
        if r > 0.0 {
            return row.iter().map(|w| w * norm / r).collect();
        }
    }
}

/// The `q`-quantile of `row · a` over the rows `a` of `inputs` (row-major, `row.len()` wide).
fn quantile_of_projections(inputs: &[f64], row: &[f64], q: f64) -> f64 {
    let mut z: Vec<f64> = inputs
        .chunks_exact(row.len())
        .map(|a| a.iter().zip(row).map(|(a, w)| a * w).sum())
        .collect();
    let i = ((q * z.len() as f64) as usize).min(z.len() - 1);
    *z.select_nth_unstable_by(i, f64::total_cmp).1
}

fn set_incoming<T: Scalar>(p: &mut Params<T>, j: usize, row: &[f64], bias: f64) {
    for (w, &r) in p.w[j * p.n_in..(j + 1) * p.n_in].iter_mut().zip(row) {
        *w = T::from_f64(r);
    }
    p.b[j] = T::from_f64(bias);
}

fn zero_outgoing<T: Scalar>(next: &mut Params<T>, j: usize) {
    for o in 0..next.n_out {
        next.w[o * next.n_in + j] = T::ZERO;
    }
}

/// Restarts Adam's moments of the neurons of layer `k` marked in `dead`: first moments 0,
/// second moments the mean over the live neurons of the same input (incoming weights and
/// bias) or the same output (outgoing weights). Where no neuron of the layer is live, 0.
fn restart_moments<T: Scalar>(adam: &mut Adam<T>, k: usize, dead: &[bool]) {
    let (m, v) = (&mut adam.m, &mut adam.v);
    let (n_in, next_in) = (v[k].n_in, v[k + 1].n_in);
    let incoming: Vec<T> = (0..n_in)
        .map(|i| live_mean(v[k].w.iter().skip(i).step_by(n_in), dead))
        .collect();
    let bias = live_mean(&v[k].b, dead);
    let outgoing: Vec<T> = v[k + 1]
        .w
        .chunks_exact(next_in)
        .map(|row| live_mean(row, dead))
        .collect();
    for (j, _) in dead.iter().enumerate().filter(|(_, &d)| d) {
        m[k].w[j * n_in..(j + 1) * n_in].fill(T::ZERO);
        m[k].b[j] = T::ZERO;
        zero_outgoing(&mut m[k + 1], j);
        v[k].w[j * n_in..(j + 1) * n_in].copy_from_slice(&incoming);
        v[k].b[j] = bias;
        for (o, &value) in outgoing.iter().enumerate() {
            v[k + 1].w[o * next_in + j] = value;
        }
    }
}

/// Mean of the `values` whose neuron (same position in `dead`) is live; 0 if none is.
fn live_mean<'a, T: Scalar>(values: impl IntoIterator<Item = &'a T>, dead: &[bool]) -> T {
    let (sum, count) = values
        .into_iter()
        .zip(dead)
        .filter(|(_, &d)| !d)
        .fold((0.0, 0usize), |(s, c), (x, _)| (s + x.to_f64(), c + 1));
    T::from_f64(if count == 0 { 0.0 } else { sum / count as f64 })
}

/// The random stream of the revival after epoch `epoch` (deterministic, so a resumed run
/// revives the same neurons the same way).
pub(crate) fn revival_rng(seed: u64, epoch: usize) -> ChaCha8Rng {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x7265_7669_7665);
    rng.set_stream(epoch as u64);
    rng
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::network::batch::{to_mlp, to_params};
    use crate::network::Mlp;

    fn grid(n: usize) -> Vec<Vec<f64>> {
        (0..n * n)
            .map(|i| {
                let (a, b) = (i / n, i % n);
                vec![
                    -1.0 + 2.0 * a as f64 / (n - 1) as f64,
                    -1.0 + 2.0 * b as f64 / (n - 1) as f64,
                ]
            })
            .collect()
    }

    /// Kills neurons 0..4 of the second hidden layer by a large negative bias.
    fn with_dead_neurons() -> Vec<Params<f64>> {
        let mut p = to_params::<f64>(&Mlp::random(&[2, 16, 12, 2], 5));
        for j in 0..4 {
            p[1].b[j] = -1e3;
        }
        p
    }

    #[test]
    fn finds_exactly_the_neurons_that_never_fire() {
        let xs = grid(30);
        let p = with_dead_neurons();
        let d = dormant_neurons(&p, xs.len(), |i| &xs[i]);
        // Brute force from the pointwise forward pass.
        let mlp = to_mlp(&p);
        for (k, layer) in d.iter().enumerate() {
            for (j, &dead) in layer.iter().enumerate() {
                let fires = xs.iter().any(|x| mlp.pre_activations(x)[k][j] > 0.0);
                assert_eq!(dead, !fires, "layer {k} neuron {j}");
            }
        }
        assert!(d[1][..4].iter().all(|&x| x));
    }

    #[test]
    fn revival_keeps_the_function_and_makes_the_neurons_fire() {
        let xs = grid(30);
        let mut p = with_dead_neurons();
        let before = to_mlp(&p);
        let mut adam = Adam::new(&p, 0.9, 0.999, 1e-8);
        adam.m[1].w.fill(1.0);
        adam.m[2].w.fill(1.0);
        let d = dormant_neurons(&p, xs.len(), |i| &xs[i]);
        let revived = revive_dormant(
            &mut p,
            &mut adam,
            &d,
            xs.len(),
            |i| &xs[i],
            &mut revival_rng(0, 3),
        );
        assert_eq!(revived, d.iter().flatten().filter(|&&x| x).count());
        let after = to_mlp(&p);
        for x in &xs {
            let (a, b) = (before.forward(x), after.forward(x));
            assert_eq!(a, b, "output changed at {x:?}");
        }
        let d2 = dormant_neurons(&p, xs.len(), |i| &xs[i]);
        for (j, &dormant) in d2[1].iter().enumerate().take(4) {
            assert!(!dormant, "neuron {j} still dormant");
            // Active on 10–90 % of the inputs, as drawn (the probe is the whole grid here).
            let share = xs
                .iter()
                .filter(|x| after.pre_activations(x)[1][j] > 0.0)
                .count() as f64
                / xs.len() as f64;
            assert!(
                (0.09..=0.91).contains(&share),
                "neuron {j} active on {share}"
            );
            assert_eq!(adam.m[1].w[j * 16], 0.0);
            assert_eq!(adam.m[2].w[j], 0.0);
        }
        // Untouched neurons keep their moments.
        assert_eq!(adam.m[1].w[4 * 16], 1.0);
    }

    /// A revived weight's first Adam steps are as large as its live neighbours', not a multiple
    /// of the learning rate (moments restarted at 0 under the global bias correction gave
    /// ~3·lr per step after 2,000 steps, 30× a live weight's).
    #[test]
    fn revived_weights_step_like_their_live_neighbours() {
        let xs = grid(30);
        let mut p = with_dead_neurons();
        let d = dormant_neurons(&p, xs.len(), |i| &xs[i]);
        let mut adam = Adam::new(&p, 0.9, 0.999, 1e-8);
        let mut rng = ChaCha8Rng::seed_from_u64(1);
        let mut unit_gradients = |p: &[Params<f64>], dead_zero: bool| {
            let mut g: Vec<Params<f64>> = p.iter().map(|q| q.zeros_like()).collect();
            for q in g.iter_mut() {
                for x in q.w.iter_mut().chain(q.b.iter_mut()) {
                    *x = if rng.random::<bool>() { 1.0 } else { -1.0 };
                }
            }
            if dead_zero {
                // Dead neurons get no gradient, in or out.
                let n_in = g[1].n_in;
                for (j, _) in d[1].iter().enumerate().filter(|(_, &x)| x) {
                    g[1].w[j * n_in..(j + 1) * n_in].fill(0.0);
                    g[1].b[j] = 0.0;
                    zero_outgoing(&mut g[2], j);
                }
            }
            g
        };
        for _ in 0..2000 {
            let g = unit_gradients(&p, true);
            adam.step(&mut p, &g, 1e-12);
        }
        revive_dormant(
            &mut p,
            &mut adam,
            &d,
            xs.len(),
            |i| &xs[i],
            &mut revival_rng(0, 1),
        );
        let before = p.clone();
        let lr = 1e-3;
        let g = unit_gradients(&p, false);
        adam.step(&mut p, &g, lr);
        let step = |k: usize, i: usize| (p[k].w[i] - before[k].w[i]).abs();
        let (mut revived, mut live) = (0.0f64, 0.0f64);
        for (j, &dead) in d[1].iter().enumerate() {
            let (n_in, next_in) = (p[1].n_in, p[2].n_in);
            let incoming = (j * n_in..(j + 1) * n_in).map(|i| step(1, i));
            let outgoing = (0..p[2].n_out).map(|o| step(2, o * next_in + j));
            let largest = incoming.chain(outgoing).fold(0.0, f64::max);
            if dead {
                revived = revived.max(largest);
            } else {
                live = live.max(largest);
            }
        }
        // Adam steps a live weight by at most ~lr; a revived one now by ~0.1·lr (its first
        // moment restarts at 0), before by ~3·lr.
        assert!(live > 0.0 && live <= 1.01 * lr, "live step {live}");
        assert!(
            revived <= live,
            "revived step {revived} against live {live}"
        );
    }
}

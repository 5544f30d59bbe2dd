//! The batch plumbing of the bound methods: validation of networks and boxes, where the groups
//! of a batch run ([`Schedule`]), and the per-thread [`BoundsWorkspace`]. Imports its parent
//! (the error type, the methods' workspaces, `OutRow`) and [`crate::network`].

use super::{crown, forward, forward_backward, ibp, BoundsError, OutRow};
use crate::network::Mlp;
use rayon::prelude::*;

/// Where the groups of a batch run: in parallel (rayon, a fresh workspace per task), or one
/// after another in the calling thread with the caller's workspace (a reach engine that gives
/// each thread its own boxes for the whole horizon, with no fork–join per Euler step).
pub(crate) enum Schedule<'w, W> {
    Parallel,
    Serial(&'w mut W),
}

/// Runs `group_fn` on groups of at most `max_group` boxes as `schedule` says (in parallel, one
/// rayon task per group, each with its own workspace from `W::default()`), then sanitises every
/// row. Shared by the GEMM-batched methods (IBP, forward, forward-backward): a group is one set
/// of matrix products whose columns are boxes.
pub(crate) fn for_each_group<W: Default + Send>(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    max_group: usize,
    schedule: Schedule<'_, W>,
    group_fn: impl Fn(&mut W, &[f64], &[f64], &mut [OutRow<'_>]) + Sync + Send,
) {
    let n0 = net.input_dim();
    if rows.is_empty() {
        return;
    }
    let run = |ws: &mut W, ((rows, lo), hi): ((&mut [OutRow<'_>], &[f64]), &[f64])| {
        group_fn(ws, lo, hi, rows);
        rows.iter_mut().for_each(|row| row.sanitize());
    };
    match schedule {
        Schedule::Serial(ws) => rows
            .chunks_mut(max_group)
            .zip(lower.chunks(max_group * n0))
            .zip(upper.chunks(max_group * n0))
            .for_each(|group| run(ws, group)),
        Schedule::Parallel => {
            let threads = rayon::current_num_threads().max(1);
            let group = rows.len().div_ceil(threads).clamp(1, max_group);
            rows.par_chunks_mut(group)
                .zip(lower.par_chunks(group * n0))
                .zip(upper.par_chunks(group * n0))
                .for_each_init(W::default, run);
        }
    }
}

/// The buffers of every bound method for [`super::PreparedNetwork::bounds_serial_into`]: one per
/// thread, reused across calls (they grow to the largest batch and stay).
#[derive(Default)]
pub struct BoundsWorkspace {
    pub(super) ibp: ibp::Workspace,
    pub(super) forward: forward::Workspace,
    pub(super) forward_backward: forward_backward::Workspace,
    pub(super) crown: Option<crown::Workspace>,
}

/// Runs `f` on every box: in parallel with one workspace per rayon task from `init`, or one
/// after another in `serial`.
pub(super) fn run_per_box<W, I, F>(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
    rows: &mut [OutRow<'_>],
    serial: Option<&mut W>,
    init: I,
    f: F,
) where
    I: Fn() -> W + Sync + Send,
    F: Fn(&mut W, &[f64], &[f64], &mut OutRow<'_>) + Sync + Send,
{
    let n = net.input_dim();
    let run = |ws: &mut W, ((row, lo), hi): ((&mut OutRow<'_>, &[f64]), &[f64])| {
        f(ws, lo, hi, row);
        row.sanitize();
    };
    match serial {
        Some(ws) => rows
            .iter_mut()
            .zip(lower.chunks(n))
            .zip(upper.chunks(n))
            .for_each(|one| run(ws, one)),
        None => rows
            .par_iter_mut()
            .zip(lower.par_chunks(n))
            .zip(upper.par_chunks(n))
            .for_each_init(init, run),
    }
}

/// Largest layer width (and input dimension) the error model is stated for.
const MAX_WIDTH: usize = 1 << 30;

/// Checks the flat batch of boxes against a checked network; returns the number of boxes.
pub(super) fn validate_boxes(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
) -> Result<usize, BoundsError> {
    let n = net.input_dim();
    if lower.len() != upper.len() || !lower.len().is_multiple_of(n) {
        return Err(BoundsError::BatchShape {
            lower_len: lower.len(),
            upper_len: upper.len(),
            n_in: n,
        });
    }
    for (idx, (&l, &u)) in lower.iter().zip(upper).enumerate() {
        let (box_index, coord) = (idx / n, idx % n);
        if !l.is_finite() || !u.is_finite() {
            return Err(BoundsError::NonFiniteBox {
                box_index,
                coord,
                lower: l,
                upper: u,
            });
        }
        if l > u {
            return Err(BoundsError::InvertedBox {
                box_index,
                coord,
                lower: l,
                upper: u,
            });
        }
    }
    Ok(lower.len() / n)
}

/// Checks shapes (each layer's input is the previous output), widths and finiteness.
pub(super) fn validate_network(net: &Mlp) -> Result<(), BoundsError> {
    if net.layers.is_empty() {
        return Err(BoundsError::EmptyNetwork);
    }
    let invalid = |layer: usize, reason: String| BoundsError::InvalidNetwork { layer, reason };
    for (k, layer) in net.layers.iter().enumerate() {
        if layer.n_in == 0 || layer.n_out == 0 {
            return Err(invalid(k, "zero width".into()));
        }
        if layer.n_in > MAX_WIDTH || layer.n_out > MAX_WIDTH {
            return Err(invalid(k, format!("width above {MAX_WIDTH}")));
        }
        if layer.weight.len() != layer.n_in * layer.n_out {
            return Err(invalid(
                k,
                format!(
                    "weight has {} entries, expected {} × {}",
                    layer.weight.len(),
                    layer.n_out,
                    layer.n_in
                ),
            ));
        }
        if layer.bias.len() != layer.n_out {
            return Err(invalid(
                k,
                format!(
                    "bias has {} entries, expected {}",
                    layer.bias.len(),
                    layer.n_out
                ),
            ));
        }
        if k > 0 && net.layers[k - 1].n_out != layer.n_in {
            return Err(invalid(
                k,
                format!(
                    "input width {} differs from the previous layer's output width {}",
                    layer.n_in,
                    net.layers[k - 1].n_out
                ),
            ));
        }
        if let Some(j) = layer.weight.iter().position(|w| !w.is_finite()) {
            return Err(invalid(k, format!("weight entry {j} is not finite")));
        }
        if let Some(j) = layer.bias.iter().position(|b| !b.is_finite()) {
            return Err(invalid(k, format!("bias entry {j} is not finite")));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::super::test_support;
    use super::super::{AffineBoundsBatch, BoundMethod, PreparedNetwork};
    use super::*;

    /// The serial schedule (one workspace reused across calls, methods and batch sizes) gives
    /// the parallel schedule's bounds: sound at sampled points and equal up to the summation
    /// order of the products (groups are cut differently).
    #[test]
    fn serial_bounds_match_parallel_with_a_reused_workspace() {
        use test_support::{case_rng, check_bounds, random_box, sample_points, BoxKind};
        let net = Mlp::random(&[2, 24, 24, 3], 5);
        let prepared = PreparedNetwork::new(&net).unwrap();
        let mut rng = case_rng(11);
        let mut ws = BoundsWorkspace::default();
        let (mut serial, mut parallel) = (AffineBoundsBatch::new(), AffineBoundsBatch::new());
        // Large batch first, so that later smaller ones run on grown, stale buffers.
        for (round, n_boxes) in [300, 7, 130, 1].into_iter().enumerate() {
            let (mut lo, mut hi, mut points) = (Vec::new(), Vec::new(), Vec::new());
            for b in 0..n_boxes {
                let kind = BoxKind::ALL[(b + round) % BoxKind::ALL.len()];
                let (l, h) = random_box(&mut rng, 2, kind);
                points.push(sample_points(&mut rng, &l, &h, 6));
                lo.extend(l);
                hi.extend(h);
            }
            for method in BoundMethod::ALL {
                prepared
                    .bounds_serial_into(&lo, &hi, method, &mut ws, &mut serial)
                    .unwrap();
                prepared
                    .bounds_batch_into(&lo, &hi, method, &mut parallel)
                    .unwrap();
                assert_eq!(serial.len(), n_boxes);
                for k in 0..n_boxes {
                    let (s, p) = (serial.get(k).unwrap(), parallel.get(k).unwrap());
                    let (l, h) = (&lo[2 * k..2 * k + 2], &hi[2 * k..2 * k + 2]);
                    check_bounds(&net, l, h, &s, &points[k])
                        .unwrap_or_else(|e| panic!("{method}, box {k} of {n_boxes}: {e}"));
                    let pairs = [
                        (&s.lower, &p.lower),
                        (&s.upper, &p.upper),
                        (&s.a_lower, &p.a_lower),
                        (&s.a_upper, &p.a_upper),
                        (&s.b_lower, &p.b_lower),
                        (&s.b_upper, &p.b_upper),
                    ];
                    for (a, b) in pairs {
                        for (x, y) in a.iter().zip(b.iter()) {
                            let tol = 1e-12 * (1.0 + x.abs().max(y.abs()));
                            assert!(
                                (x - y).abs() <= tol,
                                "{method}, box {k} of {n_boxes}: serial {x} vs parallel {y}"
                            );
                        }
                    }
                }
            }
        }
    }
}

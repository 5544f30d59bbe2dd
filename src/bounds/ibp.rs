//! Interval bound propagation (IBP, Gowal et al. 2018): `C = 0`, `d̲, d̄` the interval bounds.
//!
//! Layer by layer, `z ∈ [W⁺l + W⁻u + b, W⁺u + W⁻l + b]` and `ReLU` is monotone. Each of those
//! sums is a dot product of `n_in + 1` terms (the bias as a term times 1), widened outward by
//! [`err_bound`] with the magnitude `|W|·max(|l|, |u|) + |b|` (module error model, via
//! [`affine_max`] / [`affine_min`]).

use super::{affine_max, affine_min, magnitudes, AffineBounds, AffineBoundsBatch, BoundsError};
use super::{network_bounds_batch_into, BoundMethod, OutRow};
use crate::network::Mlp;

/// IBP bounds of `net` over `[lower, upper]` (affine forms with `C = 0`).
pub fn ibp(net: &Mlp, lower: &[f64], upper: &[f64]) -> Result<AffineBounds, BoundsError> {
    let mut out = AffineBoundsBatch::new();
    network_bounds_batch_into(net, lower, upper, BoundMethod::Ibp, &mut out)?;
    Ok(out
        .get(0)
        .unwrap_or_else(|| AffineBounds::unbounded(net.input_dim(), net.output_dim())))
}

/// Rigorous interval bounds of every layer's *pre-activation* `z_k` over the box, input first.
/// Assumes a validated network and box.
pub(crate) fn ibp_pre_activations(
    net: &Mlp,
    lower: &[f64],
    upper: &[f64],
) -> Vec<(Vec<f64>, Vec<f64>)> {
    let mut out: Vec<(Vec<f64>, Vec<f64>)> = Vec::with_capacity(net.layers.len());
    let (mut lo, mut hi) = (lower.to_vec(), upper.to_vec());
    let mut mag = Vec::new();
    for (k, layer) in net.layers.iter().enumerate() {
        if k > 0 {
            // a = ReLU(z) is monotone: [max(l, 0), max(u, 0)], exact.
            lo.iter_mut().for_each(|v| *v = v.max(0.0));
            hi.iter_mut().for_each(|v| *v = v.max(0.0));
        }
        magnitudes(&lo, &hi, &mut mag);
        let rows = layer.weight.chunks_exact(layer.n_in).zip(&layer.bias);
        let (zl, zu): (Vec<f64>, Vec<f64>) = rows
            .map(|(w, &b)| {
                (
                    affine_min(w, b, &lo, &hi, &mag),
                    affine_max(w, b, &lo, &hi, &mag),
                )
            })
            .unzip();
        out.push((zl.clone(), zu.clone()));
        lo = zl;
        hi = zu;
    }
    out
}

/// IBP into one output row; assumes a validated network and box.
pub(crate) fn ibp_into(net: &Mlp, lower: &[f64], upper: &[f64], row: &mut OutRow<'_>) {
    let bounds = ibp_pre_activations(net, lower, upper);
    let Some((l, u)) = bounds.last() else {
        row.set_unbounded();
        return;
    };
    row.a_lower.fill(0.0);
    row.a_upper.fill(0.0);
    row.b_lower.copy_from_slice(l);
    row.lower.copy_from_slice(l);
    row.b_upper.copy_from_slice(u);
    row.upper.copy_from_slice(u);
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;

    #[test]
    fn ibp_is_sound_on_random_networks_and_boxes() {
        for_each_case(40, |case| {
            let b = ibp(&case.net, &case.lo, &case.hi).unwrap();
            assert!(b.a_lower.iter().chain(&b.a_upper).all(|&a| a == 0.0));
            check_bounds(&case.net, &case.lo, &case.hi, &b, &case.points)
                .unwrap_or_else(|e| panic!("{}: {e}", case.name));
        });
    }

    #[test]
    fn ibp_on_a_point_is_a_tight_enclosure() {
        let net = Mlp::random(&[2, 16, 16, 2], 3);
        let x = [0.3, -0.7];
        let b = ibp(&net, &x, &x).unwrap();
        let y = net.forward(&x);
        for i in 0..2 {
            assert!(b.lower[i] <= y[i] + 1e-12 && y[i] <= b.upper[i] + 1e-12);
            assert!(
                b.upper[i] - b.lower[i] < 1e-12,
                "width {}",
                b.upper[i] - b.lower[i]
            );
        }
    }
}

//! A face's pinned coordinates folded into the first layer's constant (forward bounds,
//! `super::forward`): one bound of the fold's rounding a box, the same for every neuron, so that
//! both engines compute it alike (docs/design.md §5).

use crate::rounding::err_bound;

/// What the folding of pinned coordinates into layer 0's constant can round by: bounds of the
/// first layer's `|b|` and of each input's `|W|` column over all neurons, so that one box's
/// bound `ε` (the same for every neuron) costs `O(n₀)`, not a pass over the neurons. The GPU
/// engine uploads the same constants (`gpu::buffers::flatten_network`) and computes the same
/// `ε` (`fold_error` in shaders/fold.wgsl).
#[derive(Clone, Debug)]
pub struct FoldBound {
    /// `max_j |b₀ⱼ|`.
    pub(crate) b_max: f64,
    /// `max_j |W₀ⱼₚ|` per input `p`.
    pub(crate) w_max: Vec<f64>,
}

impl FoldBound {
    /// The bounds of `first`, the network's first layer.
    pub fn new(first: &crate::network::Layer) -> FoldBound {
        let n0 = first.n_in;
        let mut w_max = vec![0.0f64; n0];
        for row in first.weight.chunks(n0.max(1)) {
            for (m, w) in w_max.iter_mut().zip(row) {
                *m = m.max(w.abs());
            }
        }
        let b_max = first.bias.iter().fold(0.0f64, |m, b| m.max(b.abs()));
        FoldBound { b_max, w_max }
    }

    /// A bound on the rounding of every neuron's folded constant `b₀ⱼ + Σ_p W₀ⱼₚ x_p` over the
    /// pinned coordinates `p` (`lower = upper`, summed in ascending `p`), 0 if none is pinned:
    /// `err_bound(pinned + 1, M, scale)` with `M = max|b| + Σ_p max|W_p|·|x_p|`, computed in
    /// the same order. Rounding is monotone, so the computed `M` is at least every neuron's
    /// computed magnitude sum, and `err_bound` is monotone in it.
    pub fn error(&self, lower: &[f64], upper: &[f64], scale: f64) -> f64 {
        let (mut m, mut pinned) = (self.b_max, 0);
        for p in 0..lower.len() {
            if lower[p] == upper[p] {
                m += self.w_max[p] * lower[p].abs();
                pinned += 1;
            }
        }
        match pinned {
            0 => 0.0,
            _ => err_bound(pinned + 1, m, scale),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bounds::test_support::*;
    use crate::network::Mlp;

    /// One `FoldBound::error` a box bounds the rounding of every neuron's folded constant (its
    /// sum computed as layer 0 computes it, against double-double), also where the sum cancels
    /// (`b = −Σ w·x`); a whole box has none.
    #[test]
    fn one_fold_error_bounds_every_neurons_folded_constant() {
        use rand::Rng;
        let mut rng = case_rng(17);
        for case in 0..200 {
            let (n0, n1) = (1 + case % 4, 30);
            let mut net = Mlp::random(&[n0, n1, 1], case as u64);
            let (lo, mut hi) = random_box(&mut rng, n0, BoxKind::Wide);
            let pinned: Vec<usize> = (0..n0).filter(|_| rng.random::<bool>()).collect();
            for &p in &pinned {
                hi[p] = lo[p];
            }
            let first = &mut net.layers[0];
            for i in (0..n1).step_by(3) {
                let s: f64 = pinned
                    .iter()
                    .map(|&p| first.weight[i * n0 + p] * lo[p])
                    .sum();
                first.bias[i] = -s;
            }
            let fold = FoldBound::new(first);
            let eps = fold.error(&lo, &hi, 1.0);
            if pinned.is_empty() {
                assert_eq!(eps, 0.0);
                continue;
            }
            assert!(eps > 0.0);
            for i in 0..n1 {
                let w = &first.weight[i * n0..(i + 1) * n0];
                let computed = pinned.iter().fold(first.bias[i], |s, &p| s + w[p] * lo[p]);
                let exact = pinned.iter().fold(Dd::from(first.bias[i]), |s, &p| {
                    s.add(Dd::from(lo[p]).mul_f64(w[p]))
                });
                let (c, e) = (Dd::from(computed), Dd::from(eps));
                assert!(
                    exact.le(c.add(e)) && c.add(e.neg()).le(exact),
                    "case {case}, neuron {i}"
                );
            }
        }
    }
}

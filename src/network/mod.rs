//! The ReLU network: [`Mlp`] and its layers, its value and Jacobian; I/O and the trainer below.
//! May import: its own submodules and `crate::matmul`; nothing of filters or reachability.
//!
//! ReLU multilayer perceptrons `N(x) = W_L σ(… σ(W_1 x + b_1) …) + b_L`, `σ = ReLU`.
//!
//! Weights are stored row-major as `[out, in]`, exactly as PyTorch's `nn.Linear` keeps them, so
//! that a `state_dict` of an `nn.Sequential` loads unchanged.
//!
//! - [`io`]: safetensors load/save (`Mlp::load_safetensors`, `Mlp::save_safetensors`).
//! - [`train`](mod@train): a small Adam trainer with an optional Jacobian (Sobolev) term (docs/design.md §2b, §6).
//! - [`Mlp::jacobian`]: `DN(x) = W_L D_{L−1} W_{L−1} ⋯ D_1 W_1`, `D_k = diag(z_k > 0)`.

mod adam;
mod batch;
mod error;
pub mod io;
mod revive;
pub mod train;

pub use error::NetworkError;
pub use train::{
    evaluate, pointwise_errors, resume, train, Dataset, EpochStats, ErrorStats, LrSchedule,
    PointErrors, Precision, TrainReport, TrainSettings,
};

/// One affine layer `y = W x + b`, `W` of shape `[n_out, n_in]` stored row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct Layer {
    /// `W`, row-major, `n_out * n_in` entries.
    pub weight: Vec<f64>,
    /// `b`, `n_out` entries.
    pub bias: Vec<f64>,
    /// Input width.
    pub n_in: usize,
    /// Output width.
    pub n_out: usize,
}

/// A ReLU MLP: affine layers with a ReLU after every layer but the last.
#[derive(Clone, Debug, PartialEq)]
pub struct Mlp {
    /// The affine layers, input first.
    pub layers: Vec<Layer>,
}

impl Layer {
    /// `y = W x + b` in f64 (no rounding control: this is the network's *value*, not a bound).
    pub fn apply(&self, x: &[f64]) -> Vec<f64> {
        debug_assert_eq!(x.len(), self.n_in);
        self.weight
            .chunks_exact(self.n_in)
            .zip(&self.bias)
            .map(|(row, b)| row.iter().zip(x).map(|(w, xi)| w * xi).sum::<f64>() + b)
            .collect()
    }
}

impl Mlp {
    /// Input dimension `n`.
    pub fn input_dim(&self) -> usize {
        self.layers.first().map_or(0, |l| l.n_in)
    }

    /// Output dimension `m`.
    pub fn output_dim(&self) -> usize {
        self.layers.last().map_or(0, |l| l.n_out)
    }

    /// Layer widths `n_0, n_1, …, n_L` (input first), e.g. `[2, 400, 400, 400, 2]`.
    pub fn widths(&self) -> Vec<usize> {
        let mut w = vec![self.input_dim()];
        w.extend(self.layers.iter().map(|l| l.n_out));
        w
    }

    /// `N(x)` in f64.
    pub fn forward(&self, x: &[f64]) -> Vec<f64> {
        let mut a = x.to_vec();
        for (k, layer) in self.layers.iter().enumerate() {
            a = layer.apply(&a);
            if k + 1 < self.layers.len() {
                a.iter_mut().for_each(|v| *v = v.max(0.0));
            }
        }
        a
    }

    /// `N` at many points (row-major, [`Self::input_dim`] wide; the outputs likewise,
    /// [`Self::output_dim`] wide), in f64 through the trainer's batched GEMMs: the same values
    /// as [`Self::forward`] up to the order of the sums' rounding, many times faster.
    pub fn forward_many(&self, points: &[f64]) -> Vec<f64> {
        const BATCH: usize = 1024;
        let (n, m) = (self.input_dim().max(1), self.output_dim());
        let params = batch::to_params::<f64>(self);
        let mut ws = batch::Workspace::<f64>::new(params.len());
        let mut out = Vec::with_capacity(points.len() / n * m);
        for chunk in points.chunks(BATCH * n) {
            ws.load_inputs(n, chunk.len() / n, false, |i| &chunk[i * n..(i + 1) * n]);
            ws.forward(&params);
            out.extend_from_slice(&ws.out);
        }
        out
    }

    /// The pre-activations `z_k = W_k a_{k−1} + b_k` of the hidden layers at `x` (input side
    /// first), in f64.
    pub fn pre_activations(&self, x: &[f64]) -> Vec<Vec<f64>> {
        let hidden = self.layers.len().saturating_sub(1);
        let mut zs: Vec<Vec<f64>> = Vec::with_capacity(hidden);
        let mut a = x.to_vec();
        for layer in &self.layers[..hidden] {
            let z = layer.apply(&a);
            a = z.iter().map(|v| v.max(0.0)).collect();
            zs.push(z);
        }
        zs
    }

    /// How many neurons of each hidden layer are active (pre-activation `> 0`) at one or more
    /// of `points` (row-major, [`Self::input_dim`] wide). A neuron active nowhere in the
    /// region is dead weight: it adds no linear regions there (see `train`'s revival of
    /// dormant neurons).
    pub fn live_neurons(&self, points: &[f64]) -> Vec<usize> {
        let n = self.input_dim().max(1);
        let params = batch::to_params::<f64>(self);
        revive::dormant_neurons(&params, points.len() / n, |i| &points[i * n..(i + 1) * n])
            .iter()
            .map(|layer| layer.iter().filter(|&&d| !d).count())
            .collect()
    }

    /// The Jacobian `DN(x)`, `m × n` row-major (`J[i * n + j] = ∂N_i/∂x_j`).
    ///
    /// `DN(x) = W_L D_{L−1} W_{L−1} ⋯ D_1 W_1` with `D_k = diag(ReLU'(z_k))`. At a kink
    /// (pre-activation exactly 0) the one-sided convention `ReLU'(0) = 0` is used, i.e. a neuron
    /// counts as active only when its pre-activation is `> 0` — the same rule as the trainer.
    /// Computed forward-mode: the `n` tangent vectors ride along with the activations.
    pub fn jacobian(&self, x: &[f64]) -> Vec<f64> {
        let n = self.input_dim();
        let last = self.layers.len().saturating_sub(1);
        let mut a = x.to_vec();
        // Tangents, `width × n` row-major: column j is ∂a/∂x_j. Starts as the identity.
        let mut t: Vec<f64> = (0..n * n)
            .map(|k| if k / n == k % n { 1.0 } else { 0.0 })
            .collect();
        for (k, layer) in self.layers.iter().enumerate() {
            // t ← W t
            let mut t_next = vec![0.0; layer.n_out * n];
            for (i, row) in layer.weight.chunks_exact(layer.n_in).enumerate() {
                let out = &mut t_next[i * n..(i + 1) * n];
                for (p, w) in row.iter().enumerate() {
                    for (o, tv) in out.iter_mut().zip(&t[p * n..(p + 1) * n]) {
                        *o += w * tv;
                    }
                }
            }
            if k < last {
                // a ← ReLU(W a + b); t ← D t with D = diag(z > 0)
                let z = layer.apply(&a);
                for (i, zi) in z.iter().enumerate() {
                    if zi.is_nan() || *zi <= 0.0 {
                        t_next[i * n..(i + 1) * n].fill(0.0);
                    }
                }
                a = z.into_iter().map(|v| v.max(0.0)).collect();
            }
            t = t_next;
        }
        t
    }

    /// Checks that the layers chain (`n_in` of each is the `n_out` of the one before) and that
    /// every weight and bias has the length its widths say. `name` labels errors.
    pub fn validate(&self, name: &str) -> Result<(), NetworkError> {
        if self.layers.is_empty() {
            return Err(NetworkError::Empty);
        }
        let path = std::path::PathBuf::from(name);
        let mut prev: Option<usize> = None;
        for (k, l) in self.layers.iter().enumerate() {
            let expected_in = prev.unwrap_or(l.n_in);
            if l.n_in != expected_in || l.weight.len() != l.n_out * l.n_in {
                return Err(NetworkError::Shape {
                    path,
                    name: format!("layer {k} weight"),
                    expected: vec![l.n_out, expected_in],
                    found: vec![l.weight.len() / l.n_in.max(1), l.n_in],
                });
            }
            if l.bias.len() != l.n_out {
                return Err(NetworkError::Shape {
                    path,
                    name: format!("layer {k} bias"),
                    expected: vec![l.n_out],
                    found: vec![l.bias.len()],
                });
            }
            prev = Some(l.n_out);
        }
        Ok(())
    }

    /// The architecture string `n_0xn_1x…xn_L`, e.g. `2x400x400x400x2`.
    pub fn architecture(&self) -> String {
        self.widths()
            .iter()
            .map(|w| w.to_string())
            .collect::<Vec<_>>()
            .join("x")
    }

    /// A network with the given widths and He-uniform random weights, deterministic for `seed`.
    /// Used for tests, benchmarks and as the trainer's starting point.
    pub fn random(widths: &[usize], seed: u64) -> Mlp {
        use rand::{Rng, SeedableRng};
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
        let layers = widths
            .windows(2)
            .map(|w| {
                let (n_in, n_out) = (w[0], w[1]);
                let limit = (6.0 / n_in as f64).sqrt();
                let weight = (0..n_in * n_out)
                    .map(|_| rng.random_range(-limit..limit))
                    .collect();
                let bias = (0..n_out).map(|_| rng.random_range(-0.1..0.1)).collect();
                Layer {
                    weight,
                    bias,
                    n_in,
                    n_out,
                }
            })
            .collect();
        Mlp { layers }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn jacobian_matches_finite_differences() {
        let mlp = Mlp::random(&[3, 20, 15, 2], 4);
        let h = 1e-6;
        for s in 0..10 {
            let x: Vec<f64> = (0..3).map(|j| ((s * 3 + j) as f64 * 0.91).sin()).collect();
            let jac = mlp.jacobian(&x);
            assert_eq!(jac.len(), 6);
            for j in 0..3 {
                let mut xp = x.clone();
                xp[j] += h;
                let mut xm = x.clone();
                xm[j] -= h;
                let (yp, ym) = (mlp.forward(&xp), mlp.forward(&xm));
                for i in 0..2 {
                    let fd = (yp[i] - ym[i]) / (2.0 * h);
                    assert!(
                        (fd - jac[i * 3 + j]).abs() < 1e-6,
                        "{fd} vs {}",
                        jac[i * 3 + j]
                    );
                }
            }
        }
    }

    #[test]
    fn forward_many_is_forward_at_each_point() {
        let mlp = Mlp::random(&[3, 20, 15, 2], 7);
        // More points than one batch, and a last batch that is not full.
        let points: Vec<f64> = (0..3 * 1500)
            .map(|k| (k as f64 * 0.37).sin() * 2.0)
            .collect();
        let many = mlp.forward_many(&points);
        assert_eq!(many.len(), 2 * 1500);
        for (x, y) in points.chunks(3).zip(many.chunks(2)) {
            let one = mlp.forward(x);
            for (a, b) in one.iter().zip(y) {
                assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0), "{a} vs {b}");
            }
        }
    }

    #[test]
    fn jacobian_at_a_kink_uses_the_strict_convention() {
        // N(x) = ReLU(x) + ReLU(−x)·0 : at x = 0 the neuron is inactive, DN = 0.
        let mlp = Mlp {
            layers: vec![
                Layer {
                    weight: vec![1.0],
                    bias: vec![0.0],
                    n_in: 1,
                    n_out: 1,
                },
                Layer {
                    weight: vec![2.0],
                    bias: vec![0.5],
                    n_in: 1,
                    n_out: 1,
                },
            ],
        };
        assert_eq!(mlp.jacobian(&[0.0]), vec![0.0]);
        assert_eq!(mlp.jacobian(&[1e-300]), vec![2.0]);
        assert_eq!(mlp.architecture(), "1x1x1");
    }

    #[test]
    fn validate_catches_broken_chains() {
        let mut mlp = Mlp::random(&[2, 4, 3], 0);
        assert!(mlp.validate("m").is_ok());
        mlp.layers[1].n_in = 5;
        assert!(matches!(mlp.validate("m"), Err(NetworkError::Shape { .. })));
        assert!(matches!(
            Mlp { layers: vec![] }.validate("m"),
            Err(NetworkError::Empty)
        ));
    }
}

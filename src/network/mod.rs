//! ReLU multilayer perceptrons `N(x) = W_L σ(… σ(W_1 x + b_1) …) + b_L`, `σ = ReLU`.
//!
//! Weights are stored row-major as `[out, in]`, exactly as PyTorch's `nn.Linear` keeps them, so
//! that a `state_dict` of an `nn.Sequential` loads unchanged.

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

/// Errors in loading or validating a network.
#[derive(Debug, thiserror::Error)]
pub enum NetworkError {
    /// Placeholder until io lands.
    #[error("{0}")]
    Invalid(String),
}

//! The training data [`Dataset`] (inputs, targets `v`, optional `Dv` and sample weights).
//! May import: [`NetworkError`] and [`Mlp`] of the parent network module.

use crate::network::{Mlp, NetworkError};

/// Training data: inputs `x_s`, targets `v(x_s)`, optionally `Dv(x_s)` and sample weights.
#[derive(Clone, Debug, Default)]
pub struct Dataset {
    /// Input dimension `n`.
    pub n_in: usize,
    /// Output dimension `m`.
    pub n_out: usize,
    /// `N × n` row-major.
    pub inputs: Vec<f64>,
    /// `N × m` row-major.
    pub targets: Vec<f64>,
    /// `N × m × n`: for each sample the Jacobian `Dv`, `m × n` row-major
    /// (`[s*m*n + i*n + j] = ∂v_i/∂x_j`). Needed when `jacobian_weight > 0`. A sample with a
    /// NaN entry has no slope target (the Sobolev term and the slope errors skip it).
    pub jacobians: Option<Vec<f64>>,
    /// Per-sample loss weights `w_s ≥ 0`. Samples of weight 0 are skipped by training and
    /// excluded from the reported errors (e.g. points where the filter is infeasible).
    pub weights: Option<Vec<f64>>,
}

impl Dataset {
    /// Number of samples `N`.
    pub fn len(&self) -> usize {
        self.inputs.len().checked_div(self.n_in).unwrap_or(0)
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Input of sample `s` (`s < len()`).
    pub(crate) fn input(&self, s: usize) -> &[f64] {
        &self.inputs[s * self.n_in..(s + 1) * self.n_in]
    }

    /// Target of sample `s` (`s < len()`).
    pub(crate) fn target(&self, s: usize) -> &[f64] {
        &self.targets[s * self.n_out..(s + 1) * self.n_out]
    }

    pub(super) fn weight(&self, s: usize) -> f64 {
        self.weights.as_ref().map_or(1.0, |w| w[s])
    }

    /// Appends `other`'s samples. Both must have the same dimensions and both or neither
    /// carry Jacobians; a side without weights weighs its samples 1.
    pub fn append(&mut self, other: Dataset) -> Result<(), NetworkError> {
        if (self.n_in, self.n_out) != (other.n_in, other.n_out)
            || self.jacobians.is_some() != other.jacobians.is_some()
        {
            return Err(NetworkError::Dataset {
                message: format!(
                    "cannot append samples of {}→{} (Jacobians: {}) to {}→{} (Jacobians: {})",
                    other.n_in,
                    other.n_out,
                    other.jacobians.is_some(),
                    self.n_in,
                    self.n_out,
                    self.jacobians.is_some()
                ),
            });
        }
        // Adaptive rounds grow the set while training: a failed allocation is an error, not an
        // abort.
        let len = self.len();
        let fail = |what: &str, extra: usize| NetworkError::Dataset {
            message: format!(
                "cannot grow the {what} of {len} samples by {extra} values: out of memory"
            ),
        };
        self.inputs
            .try_reserve(other.inputs.len())
            .map_err(|_| fail("inputs", other.inputs.len()))?;
        self.targets
            .try_reserve(other.targets.len())
            .map_err(|_| fail("targets", other.targets.len()))?;
        if let (Some(j), Some(o)) = (&mut self.jacobians, &other.jacobians) {
            j.try_reserve(o.len())
                .map_err(|_| fail("slopes", o.len()))?;
        }
        if self.weights.is_some() || other.weights.is_some() {
            let (len, other_len) = (self.len(), other.len());
            let w = self.weights.get_or_insert_with(|| vec![1.0; len]);
            w.extend(other.weights.unwrap_or_else(|| vec![1.0; other_len]));
        }
        self.inputs.extend(other.inputs);
        self.targets.extend(other.targets);
        if let (Some(j), Some(o)) = (&mut self.jacobians, other.jacobians) {
            j.extend(o);
        }
        Ok(())
    }

    /// Checks lengths, dimensions and finiteness.
    pub fn validate(&self) -> Result<(), NetworkError> {
        let bad = |message: String| Err(NetworkError::Dataset { message });
        if self.n_in == 0 || self.n_out == 0 {
            return bad(format!(
                "dimensions must be positive (n_in = {}, n_out = {})",
                self.n_in, self.n_out
            ));
        }
        if self.inputs.len() != self.len() * self.n_in {
            return bad(format!(
                "inputs has {} values, not a multiple of n_in = {}",
                self.inputs.len(),
                self.n_in
            ));
        }
        let n = self.len();
        if n == 0 {
            return bad("no samples".into());
        }
        if self.targets.len() != n * self.n_out {
            return bad(format!(
                "targets has {} values, expected N·n_out = {}·{}",
                self.targets.len(),
                n,
                self.n_out
            ));
        }
        if let Some(j) = &self.jacobians {
            if j.len() != n * self.n_out * self.n_in {
                return bad(format!(
                    "jacobians has {} values, expected N·n_out·n_in = {}·{}·{}",
                    j.len(),
                    n,
                    self.n_out,
                    self.n_in
                ));
            }
        }
        if let Some(w) = &self.weights {
            if w.len() != n {
                return bad(format!("weights has {} values, expected N = {n}", w.len()));
            }
            if let Some(i) = w.iter().position(|x| !(x.is_finite() && *x >= 0.0)) {
                return bad(format!(
                    "weight of sample {i} is {}, must be finite and ≥ 0",
                    w[i]
                ));
            }
            if w.iter().all(|&x| x == 0.0) {
                return bad("every sample has weight 0".into());
            }
        }
        let check = |name: &str, v: &[f64], per: usize, nan_ok: bool| {
            v.iter()
                .position(|x| !(x.is_finite() || nan_ok && x.is_nan()))
                .map_or(Ok(()), |i| {
                    bad(format!("{name} of sample {} is not finite", i / per))
                })
        };
        check("input", &self.inputs, self.n_in, false)?;
        check("target", &self.targets, self.n_out, false)?;
        if let Some(j) = &self.jacobians {
            // NaN: no slope target for that sample (the Sobolev term skips it).
            check("jacobian", j, self.n_in * self.n_out, true)?;
        }
        Ok(())
    }
}

/// Checks that `mlp` maps the data's `n_in` inputs to its `n_out` outputs.
pub(super) fn check_dims(mlp: &Mlp, data: &Dataset) -> Result<(), NetworkError> {
    if mlp.input_dim() != data.n_in || mlp.output_dim() != data.n_out {
        return Err(NetworkError::Dataset {
            message: format!(
                "data are {} → {} but the network {} maps {} → {}",
                data.n_in,
                data.n_out,
                mlp.architecture(),
                mlp.input_dim(),
                mlp.output_dim()
            ),
        });
    }
    Ok(())
}

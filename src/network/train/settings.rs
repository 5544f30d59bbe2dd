//! [`TrainSettings`], one documented default per field, and its schedules ([`LrSchedule`]).
//! May import: [`NetworkError`] of the parent network module; serde.

use std::path::PathBuf;

use serde::{Deserialize, Serialize};

use crate::network::NetworkError;

/// The working precision of the trainer.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    /// `sgemm`; about twice as fast. The trained network is widened exactly to f64.
    #[default]
    F32,
    /// `dgemm` throughout.
    F64,
}

/// How the learning rate moves from `learning_rate` to `lr_min` over the epochs.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum LrSchedule {
    /// `learning_rate` throughout (`lr_min` unused).
    Constant,
    /// `lr_min + (lr − lr_min)(1 + cos(π e/E))/2` at epoch `e` of `E`.
    #[default]
    Cosine,
    /// Multiply by `factor` every `every` epochs, never below `lr_min`.
    Step {
        /// Epochs between decays.
        every: usize,
        /// Decay factor in (0, 1].
        factor: f64,
    },
}

/// Settings of [`train`](super::train). Every field has a default ([`TrainSettings::default`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct TrainSettings {
    /// Passes over the data (default 100).
    pub epochs: usize,
    /// Samples per Adam step (default 256).
    pub batch_size: usize,
    /// Samples per gradient chunk (default 128): each batch's gradient is the sum of its
    /// chunks' gradients, computed side by side on rayon's threads and added in chunk order, so
    /// the result depends on this but not on the number of threads. At least `batch_size`: one
    /// chunk (the arithmetic of runs made before chunks existed).
    pub chunk_size: usize,
    /// Initial learning rate (default 1e-3).
    pub learning_rate: f64,
    /// Final learning rate of the decaying schedules (default 1e-5).
    pub lr_min: f64,
    /// Learning-rate schedule (default cosine).
    pub lr_schedule: LrSchedule,
    /// `λ` of the Sobolev term `λ‖DN − Dv‖²` (default 0; needs
    /// [`Dataset::jacobians`](super::Dataset::jacobians)).
    pub jacobian_weight: f64,
    /// Leave a sample out of the Sobolev term when some `|∂vᵢ/∂xⱼ|` of its target exceeds this
    /// (default none): where `v` jumps (scenario 2 at the obstacle's ends, where `L_g h = 0`)
    /// the central-difference targets are of order 1/step, and a few such samples would
    /// otherwise dominate the loss.
    pub jacobian_cap: Option<f64>,
    /// Huber threshold `δ` of the Sobolev term (default none: squared everywhere). A slope
    /// residual `d` then costs `d²` up to `|d| = δ` and `2δ|d| − δ²` beyond, so the few samples
    /// on a steep kink (scenario 1: 0.3 % of them held 38 % of the squared slope error) keep
    /// a bounded pull instead of steering every step.
    pub jacobian_huber: Option<f64>,
    /// Fraction of the samples, those of largest loss in the previous epoch, visited a second
    /// time in each late epoch (default 0.1; 0 disables).
    pub hard_example_fraction: f64,
    /// Fraction of the epochs after which hard examples are oversampled (default 0.5).
    pub hard_example_start: f64,
    /// Extra visits of each hard example per late epoch (default 1). A steep kink of `v`
    /// (scenario 1 near (4.1, 0.8), where `|∇h|` is small) holds under 1 % of the samples but
    /// decides the maximum error; a small fraction visited many times aims the steps there
    /// without changing the loss elsewhere.
    pub hard_example_repeats: usize,
    /// Seed of the shuffles (default 0).
    pub seed: u64,
    /// Working precision (default f32).
    pub precision: Precision,
    /// Where to write checkpoints (default none).
    pub checkpoint: Option<PathBuf>,
    /// Write a checkpoint every this many epochs and after the last (default 10; 0: only after
    /// the last).
    pub checkpoint_every: usize,
    /// Adam's `β₁` (default 0.9).
    pub adam_beta1: f64,
    /// Adam's `β₂` (default 0.999).
    pub adam_beta2: f64,
    /// Adam's `ε` (default 1e-8).
    pub adam_eps: f64,
    /// `λ_ibp` of the certified-training term `λ_ibp · mean_{s,o} 2 r_o(x_s, ε)`: the mean
    /// interval-bound-propagation (IBP) width of the outputs over the boxes `[x_s − ε, x_s + ε]`
    /// around the batch's inputs (Gowal et al. 2018; docs/design.md §2b). Default 0 (off).
    pub ibp_weight: f64,
    /// Half-width `ε` of the IBP boxes: one entry for every input, or one per input
    /// (default `[0.05]`).
    pub ibp_radius: Vec<f64>,
    /// Epoch (0-based, counted over the whole run including epochs before a resume) from which
    /// the IBP term is on (default 0).
    pub ibp_start: usize,
    /// Epochs over which `ε` ramps linearly from `ε/ibp_ramp` to `ε` after `ibp_start`
    /// (default 0: full `ε` at once).
    pub ibp_ramp: usize,
    /// Penalise the IBP width in excess of the network's linear range at the box's centre,
    /// `2 r_o − Σⱼ |∂N_o/∂xⱼ(x_s)| 2εⱼ`, instead of the width itself (default false). The width
    /// of a box on which `N` is affine is that range, so the plain term also pulls every slope
    /// towards 0, against the Sobolev term where `v` is steep; the excess is the looseness
    /// alone. Computes the tangents even where the Sobolev weight is 0.
    pub ibp_excess: bool,
    /// Every this many epochs (0: never, the default), give the hidden neurons that no
    /// training sample activates fresh incoming weights and zero outgoing ones (see
    /// `network::revive`): the function is unchanged, and the neurons can learn again.
    pub revive_every: usize,
    /// Steps `h_j` (one, or one per input) of the network's own central differences
    /// `(N(x + h_j e_j) − N(x − h_j e_j))/2h_j`, compared by the Sobolev term with the slope
    /// targets instead of the pointwise Jacobian `DN(x)` (default none). The Jacobian is
    /// constant on each linear region, so its loss cannot move where the ReLUs switch; the
    /// differences can, and they see the region-to-region scatter of the values that makes
    /// the pointwise slope error. Pair with secant targets over the same steps. Costs
    /// `(1 + 2n)` rows per sample against `(1 + n)`.
    pub secant_step: Option<Vec<f64>>,
}

impl Default for TrainSettings {
    fn default() -> Self {
        TrainSettings {
            epochs: 100,
            batch_size: 256,
            chunk_size: 128,
            learning_rate: 1e-3,
            lr_min: 1e-5,
            lr_schedule: LrSchedule::Cosine,
            jacobian_weight: 0.0,
            jacobian_cap: None,
            jacobian_huber: None,
            hard_example_fraction: 0.1,
            hard_example_start: 0.5,
            hard_example_repeats: 1,
            seed: 0,
            precision: Precision::F32,
            checkpoint: None,
            checkpoint_every: 10,
            adam_beta1: 0.9,
            adam_beta2: 0.999,
            adam_eps: 1e-8,
            ibp_weight: 0.0,
            ibp_radius: vec![0.05],
            ibp_start: 0,
            ibp_ramp: 0,
            ibp_excess: false,
            revive_every: 0,
            secant_step: None,
        }
    }
}

impl TrainSettings {
    /// Checks ranges; [`NetworkError::Settings`] names the offending field.
    pub fn validate(&self) -> Result<(), NetworkError> {
        let bad = |message: String| Err(NetworkError::Settings { message });
        let pos = |x: f64| x.is_finite() && x > 0.0;
        if self.batch_size == 0 {
            return bad("batch_size must be ≥ 1".into());
        }
        if self.chunk_size == 0 {
            return bad("chunk_size must be ≥ 1".into());
        }
        if !pos(self.learning_rate) {
            return bad(format!(
                "learning_rate = {} must be > 0",
                self.learning_rate
            ));
        }
        if !(self.lr_min.is_finite() && self.lr_min >= 0.0 && self.lr_min <= self.learning_rate) {
            return bad(format!(
                "lr_min = {} must be in [0, learning_rate = {}]",
                self.lr_min, self.learning_rate
            ));
        }
        if let LrSchedule::Step { every, factor } = self.lr_schedule {
            if every == 0 || !(factor > 0.0 && factor <= 1.0) {
                return bad(format!(
                    "step schedule needs every ≥ 1 and factor in (0, 1], got {every} and {factor}"
                ));
            }
        }
        if let Some(cap) = self.jacobian_cap {
            if !pos(cap) {
                return bad(format!("jacobian_cap = {cap} must be > 0"));
            }
        }
        if let Some(delta) = self.jacobian_huber {
            if !pos(delta) {
                return bad(format!("jacobian_huber = {delta} must be > 0"));
            }
        }
        if !(self.jacobian_weight.is_finite() && self.jacobian_weight >= 0.0) {
            return bad(format!(
                "jacobian_weight = {} must be ≥ 0",
                self.jacobian_weight
            ));
        }
        if !(0.0..=1.0).contains(&self.hard_example_fraction) {
            return bad(format!(
                "hard_example_fraction = {} must be in [0, 1]",
                self.hard_example_fraction
            ));
        }
        if !(0.0..=1.0).contains(&self.hard_example_start) {
            return bad(format!(
                "hard_example_start = {} must be in [0, 1]",
                self.hard_example_start
            ));
        }
        if !(0.0..1.0).contains(&self.adam_beta1)
            || !(0.0..1.0).contains(&self.adam_beta2)
            || !pos(self.adam_eps)
        {
            return bad("Adam needs β₁, β₂ in [0, 1) and ε > 0".into());
        }
        if !(self.ibp_weight.is_finite() && self.ibp_weight >= 0.0) {
            return bad(format!("ibp_weight = {} must be ≥ 0", self.ibp_weight));
        }
        if self.ibp_radius.is_empty()
            || self
                .ibp_radius
                .iter()
                .any(|r| !(r.is_finite() && *r >= 0.0))
        {
            return bad(format!(
                "ibp_radius = {:?} must be one or more finite values ≥ 0",
                self.ibp_radius
            ));
        }
        if let Some(h) = &self.secant_step {
            if h.is_empty() || h.iter().any(|h| !(h.is_finite() && *h > 0.0)) {
                return bad(format!(
                    "secant_step = {h:?} must be one or more finite steps > 0"
                ));
            }
        }
        Ok(())
    }

    /// The IBP radius per input at epoch `e` (0-based) for `n_in` inputs, or `None` where the
    /// term is off.
    pub fn ibp_radius_at(&self, e: usize, n_in: usize) -> Option<Vec<f64>> {
        if self.ibp_weight <= 0.0 || e < self.ibp_start {
            return None;
        }
        let f = if self.ibp_ramp == 0 {
            1.0
        } else {
            ((e - self.ibp_start + 1) as f64 / self.ibp_ramp as f64).min(1.0)
        };
        Some(
            (0..n_in)
                .map(|j| f * self.ibp_radius[j.min(self.ibp_radius.len() - 1)])
                .collect(),
        )
    }

    /// Learning rate of epoch `e` (0-based).
    pub fn lr_at(&self, e: usize) -> f64 {
        let (lr, lo) = (self.learning_rate, self.lr_min);
        match self.lr_schedule {
            LrSchedule::Constant => lr,
            LrSchedule::Cosine => {
                let frac = e as f64 / self.epochs.max(1) as f64;
                lo + (lr - lo) * 0.5 * (1.0 + (std::f64::consts::PI * frac).cos())
            }
            LrSchedule::Step { every, factor } => {
                let k = (e / every.max(1)).min(i32::MAX as usize) as i32;
                (lr * factor.powi(k)).max(lo)
            }
        }
    }

    pub(super) fn hard_examples_on(&self, e: usize) -> bool {
        self.hard_example_fraction > 0.0
            && self.hard_example_repeats > 0
            && e > 0
            && e as f64 >= self.hard_example_start * self.epochs as f64
    }
}

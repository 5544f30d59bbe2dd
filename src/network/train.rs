//! Training a ReLU [`Mlp`] `N ≈ v` with Adam and an optional Jacobian (Sobolev) term.
//!
//! Loss per batch `B` (DESIGN.md §2b: slope errors matter as much as value errors):
//!
//! ```text
//! L = (1/|B|) Σ_{s∈B} w_s ( ‖N(x_s) − v_s‖² + λ ‖DN(x_s) − Dv_s‖_F² )
//! ```
//!
//! `λ` = [`TrainSettings::jacobian_weight`], `w_s` the optional per-sample weights. `DN` is
//! computed forward-mode (the `n` input tangents ride along the activations, masked by the
//! primal ReLU pattern) and back-propagated through the same GEMMs, so a step with the Jacobian
//! term costs about `(1 + n)×` one without (the batched passes are in `network/batch.rs`).
//!
//! **Secant term.** With [`TrainSettings::secant_step`] `h` the Sobolev term compares the
//! network's own central differences `(N(x + h e_j) − N(x − h e_j))/2h` with the targets
//! instead of `DN(x)`: the Jacobian is constant on each linear region, so a loss on it cannot
//! move the ReLUs' kinks, and the region-to-region scatter of the values (which *is* the
//! pointwise slope error) goes unseen. The `2n` shifted points are extra primal rows of the
//! same GEMMs (`(1 + 2n)` rows a sample against `(1 + n)`; about 4.4 s against 3.5 s an epoch
//! for the paper's scenario-1 network at batch 4096). Four stages of it took that network's
//! slope error's 95th percentile from 0.313 to 0.222 and its max error from 0.231 to 0.140;
//! leaving the steepest secant targets out ([`TrainSettings::jacobian_cap`]) then took it
//! below 0.2 (README, Networks).
//!
//! **Certified training** (DESIGN.md §2b: equally accurate networks differ by orders of
//! magnitude in how tightly they can be bounded). With [`TrainSettings::ibp_weight`] `λ_ibp > 0`
//! each batch adds
//!
//! ```text
//! λ_ibp · (1/(|B| m)) Σ_{s∈B} Σ_o 2 r_o(x_s, ε)
//! ```
//!
//! the mean width of the interval-bound-propagation (IBP) output intervals over the boxes
//! `[x_s − ε, x_s + ε]` (Gowal et al. 2018), with `ε` = [`TrainSettings::ibp_radius`], optionally
//! switched on at [`TrainSettings::ibp_start`] and ramped up linearly over
//! [`TrainSettings::ibp_ramp`] epochs. The boxes travel in centre–radius form (`W c + b`,
//! `|W| r`: two GEMMs per layer over the batch) and the gradient goes back through both
//! (`sign(W)` for `|W|`); see `IbpWorkspace` in `network/batch.rs`. Small IBP widths bound the
//! backward-CROWN widths too. Cost: six GEMMs over `B` rows per layer, +80% per epoch on
//! top of the Jacobian term for the paper's network (below). Fine-tuning the shipped scenario-1
//! network for 150 epochs with `λ_ibp = 0.005`, `ε = 0.05` (ramped over 20 epochs) cut its
//! backward-CROWN widths on `[−0.1, 0.1]²` from 0.66 / 0.46 to 0.007 / 0.009 and its median IBP
//! looseness from 168 to 2.1, while its max error fell from 0.87 to 0.51 (mean 0.0089 → 0.0099).
//!
//! With [`TrainSettings::ibp_excess`] each width is taken less the network's linear range
//! over its box, `Σⱼ |∂N_o/∂xⱼ(x_s)| 2εⱼ` (the tangents of the Sobolev term give it): the
//! looseness alone, so the term no longer pulls slopes towards 0 where `v` is steep. On the
//! shipped scenario-1 network (32-epoch fine-tunes, same settings) it moved the slope error's
//! 95th percentile from 0.369 to 0.357 and the certified `M_C` from 0.360 to 0.343 at the same
//! IBP looseness (1.70) with `λ_ibp = 0.005`, and changed nothing that matters at 0.01 (slope
//! 0.402 against 0.400, certified 0.335 against 0.297): the term's cost to the slopes is the
//! looseness penalty itself, not its pull on the linear range.
//!
//! **Largest errors.** The reachability bound uses the *maximum* error `M_C`, so late in
//! training (from [`TrainSettings::hard_example_start`]) each epoch also revisits the
//! [`TrainSettings::hard_example_fraction`] of samples whose loss was largest in the previous
//! epoch (hard-example oversampling). Unlike a p-norm loss with growing `p`, this keeps the
//! gradient scale (and hence the learning rate) unchanged and never lets a single outlier
//! dominate a step, while the extra visits still pull the tail down; the errors it needs come
//! for free from the forward passes.
//!
//! **Precision.** [`Precision::F32`] (default) trains on `sgemm`, about twice as fast as `dgemm`;
//! the result is widened exactly to f64. Reported final errors are always measured on that f64
//! network with f64 arithmetic.
//!
//! **Speed** (release, 2 cores, `2×400×400×400×2`, 100k points, batch 256, chunks of 128,
//! `cargo test --release --lib bench_epoch -- --ignored --nocapture`): f32 2.0 s per epoch,
//! 4.5 s with the Jacobian term, 9.0 s with the IBP term too; f64 with the Jacobian term 7.5 s.
//! Batch 1024 is faster (3.9 s with the Jacobian term) but converges much more slowly per epoch.
//!
//! **Parallelism.** A batch is cut into chunks of [`TrainSettings::chunk_size`] samples whose
//! gradients are computed side by side on rayon's threads (each chunk's products may split
//! further) and added in chunk order. The matrix products of one 256-sample batch are too small
//! to keep two threads busy on their own (150 % CPU): in the same run as above, one chunk of 256
//! took 5.5 s (Jacobian term), 11.1 s (with IBP) and 8.9 s (f64), so two chunks of 128 are
//! 1.2× faster. Smaller chunks lose it again (with IBP, 64: 10.6 s, 32: 12.5 s): every chunk
//! writes a whole weight gradient, and those products grow inefficient as the chunk shrinks.
//!
//! **Determinism.** For a fixed seed and chunk size the result is bitwise reproducible on any
//! number of threads: the shuffle of epoch `e` comes from `ChaCha8Rng` seeded with `seed` on
//! stream `e`, the hard examples are chosen with a total order (score, then index), the GEMMs'
//! threads split only output blocks, never a sum, and the chunks' gradients are added in a
//! fixed order. A run resumed from a checkpoint (weights, Adam moments and step, per-sample
//! scores, epoch) continues bit-identically.

use std::collections::{BTreeMap, HashMap};
use std::path::{Path, PathBuf};
use std::time::Instant;

use rand::seq::SliceRandom;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::adam::Adam;
use super::batch::{to_mlp, to_params, IbpWorkspace, Params, Scalar, Workspace};
use super::io::{serialize, write_atomically, RawTensor, RawTensors};
use super::revive;
use super::{Mlp, NetworkError};

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
    /// (`[s*m*n + i*n + j] = ∂v_i/∂x_j`). Needed when `jacobian_weight > 0`.
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

    fn weight(&self, s: usize) -> f64 {
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
        let check = |name: &str, v: &[f64], per: usize| {
            v.iter().position(|x| !x.is_finite()).map_or(Ok(()), |i| {
                bad(format!("{name} of sample {} is not finite", i / per))
            })
        };
        check("input", &self.inputs, self.n_in)?;
        check("target", &self.targets, self.n_out)?;
        if let Some(j) = &self.jacobians {
            check("jacobian", j, self.n_in * self.n_out)?;
        }
        Ok(())
    }
}

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

/// Settings of [`train`]. Every field has a default ([`TrainSettings::default`]).
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
    /// `λ` of the Sobolev term `λ‖DN − Dv‖²` (default 0; needs [`Dataset::jacobians`]).
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
    /// around the batch's inputs (Gowal et al. 2018; DESIGN.md §2b). Default 0 (off).
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
    /// [`revive`](super::revive)): the function is unchanged, and the neurons can learn again.
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

    fn hard_examples_on(&self, e: usize) -> bool {
        self.hard_example_fraction > 0.0
            && self.hard_example_repeats > 0
            && e > 0
            && e as f64 >= self.hard_example_start * self.epochs as f64
    }
}

/// What one epoch did, passed to the progress callback and kept in the report.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct EpochStats {
    /// Epochs completed (1-based).
    pub epoch: usize,
    /// Total epochs of the run.
    pub epochs: usize,
    /// Mean weighted loss over the epoch's samples.
    pub loss: f64,
    /// Max over samples of `‖N(x_s) − v_s‖∞`, each measured when the sample was visited
    /// (weights move during the epoch; [`TrainReport::final_errors`] is exact).
    pub max_error: f64,
    /// Mean over samples of `‖N(x_s) − v_s‖∞`, measured likewise.
    pub mean_error: f64,
    /// Max over samples of `max |DN − Dv|` (entrywise), when the Jacobian term is on.
    pub max_slope_error: Option<f64>,
    /// Learning rate used.
    pub lr: f64,
    /// Sample visits (data plus hard-example repeats).
    pub samples: usize,
    /// Wall-clock seconds of the epoch.
    pub seconds: f64,
    /// Mean IBP output width `2 r_o` over the epoch's boxes, when the IBP term is on.
    #[serde(default)]
    pub ibp_width: Option<f64>,
    /// Dormant hidden neurons revived after this epoch ([`TrainSettings::revive_every`]).
    #[serde(default)]
    pub revived: usize,
}

impl EpochStats {
    /// Numbers per history row in a checkpoint.
    const ROW: usize = 11;

    fn to_row(&self) -> [f64; Self::ROW] {
        [
            self.epoch as f64,
            self.epochs as f64,
            self.loss,
            self.max_error,
            self.mean_error,
            self.max_slope_error.unwrap_or(f64::NAN),
            self.lr,
            self.samples as f64,
            self.seconds,
            self.ibp_width.unwrap_or(f64::NAN),
            self.revived as f64,
        ]
    }

    fn from_row(r: &[f64]) -> Self {
        EpochStats {
            epoch: r[0] as usize,
            epochs: r[1] as usize,
            loss: r[2],
            max_error: r[3],
            mean_error: r[4],
            max_slope_error: (!r[5].is_nan()).then_some(r[5]),
            lr: r[6],
            samples: r[7] as usize,
            seconds: r[8],
            // Checkpoints from before the IBP term have 9 columns.
            ibp_width: r.get(9).copied().filter(|x| !x.is_nan()),
            revived: r.get(10).map_or(0, |&x| x as usize),
        }
    }
}

/// Errors of a network on a data set, in f64, over the samples of positive weight.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct ErrorStats {
    /// Samples measured.
    pub samples: usize,
    /// `max_s ‖N(x_s) − v_s‖∞`.
    pub max_error: f64,
    /// Sample index where `max_error` is attained.
    pub argmax: usize,
    /// `mean_s ‖N(x_s) − v_s‖∞`.
    pub mean_error: f64,
    /// `max_s ‖N(x_s) − v_s‖₂`.
    pub max_error_l2: f64,
    /// `max_s max_ij |DN − Dv|_ij`, when the data have Jacobians.
    pub max_slope_error: Option<f64>,
    /// `mean_s max_ij |DN − Dv|_ij`, when the data have Jacobians.
    pub mean_slope_error: Option<f64>,
}

/// Per-sample errors of a network on a data set (see [`pointwise_errors`]).
#[derive(Clone, Debug, PartialEq)]
pub struct PointErrors {
    /// `‖N(x_s) − v_s‖∞` for every sample.
    pub value: Vec<f64>,
    /// `‖N(x_s) − v_s‖₂` for every sample.
    pub value_l2: Vec<f64>,
    /// `max_ij |DN(x_s) − Dv_s|_ij` for every sample, when the data have Jacobians.
    pub slope: Option<Vec<f64>>,
}

/// The outcome of [`train`].
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct TrainReport {
    /// One entry per epoch, including those run before a resume.
    pub epochs: Vec<EpochStats>,
    /// Errors of the returned (f64) network on the whole data set.
    pub final_errors: ErrorStats,
    /// Wall-clock seconds of this call (training and final evaluation).
    pub seconds: f64,
    /// Epoch the run resumed from, if it did.
    pub resumed_from: Option<usize>,
}

impl TrainReport {
    /// The report as string metadata for [`Mlp::save_safetensors`]: `max_error`,
    /// `mean_error`, `max_slope_error`, `epochs`, `final_loss`, and the full report as JSON
    /// under `train_report`.
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        m.insert("max_error".into(), self.final_errors.max_error.to_string());
        m.insert(
            "mean_error".into(),
            self.final_errors.mean_error.to_string(),
        );
        if let Some(s) = self.final_errors.max_slope_error {
            m.insert("max_slope_error".into(), s.to_string());
        }
        m.insert("epochs".into(), self.epochs.len().to_string());
        if let Some(last) = self.epochs.last() {
            m.insert("final_loss".into(), last.loss.to_string());
        }
        if let Ok(json) = serde_json::to_string(self) {
            m.insert("train_report".into(), json);
        }
        m
    }
}

/// Trains `init` on `data`; calls `progress` after every epoch.
///
/// Returns the trained network (f64) and a report whose [`TrainReport::final_errors`] are
/// measured on that network. Writes checkpoints if [`TrainSettings::checkpoint`] is set.
pub fn train(
    init: Mlp,
    data: &Dataset,
    settings: &TrainSettings,
    progress: impl FnMut(&EpochStats),
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
    progress: impl FnMut(&EpochStats),
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

/// Errors of `mlp` on `data` in f64, over the samples of positive weight.
pub fn evaluate(mlp: &Mlp, data: &Dataset) -> Result<ErrorStats, NetworkError> {
    let pe = pointwise_errors(mlp, data)?;
    let mut st = ErrorStats {
        samples: 0,
        max_error: 0.0,
        argmax: 0,
        mean_error: 0.0,
        max_error_l2: 0.0,
        max_slope_error: pe.slope.as_ref().map(|_| 0.0),
        mean_slope_error: pe.slope.as_ref().map(|_| 0.0),
    };
    let (mut sum, mut sum_slope) = (0.0, 0.0);
    for s in 0..data.len() {
        if data.weight(s) <= 0.0 {
            continue;
        }
        st.samples += 1;
        sum += pe.value[s];
        if pe.value[s] > st.max_error {
            st.max_error = pe.value[s];
            st.argmax = s;
        }
        st.max_error_l2 = st.max_error_l2.max(pe.value_l2[s]);
        if let Some(sl) = &pe.slope {
            sum_slope += sl[s];
            st.max_slope_error = st.max_slope_error.map(|m| m.max(sl[s]));
        }
    }
    let n = st.samples.max(1) as f64;
    st.mean_error = sum / n;
    st.mean_slope_error = st.mean_slope_error.map(|_| sum_slope / n);
    Ok(st)
}

/// Per-sample value (and, with Jacobians in the data, slope) errors of `mlp` on every sample
/// of `data`, in f64 — e.g. for a local error bound per cell instead of one global `M_C`.
pub fn pointwise_errors(mlp: &Mlp, data: &Dataset) -> Result<PointErrors, NetworkError> {
    mlp.validate("<network>")?;
    data.validate()?;
    check_dims(mlp, data)?;
    let params = to_params::<f64>(mlp);
    let n = data.len();
    let tangents = data.jacobians.is_some();
    let mut ws = Workspace::<f64>::new(params.len());
    let mut out = PointErrors {
        value: vec![0.0; n],
        value_l2: vec![0.0; n],
        slope: tangents.then(|| vec![0.0; n]),
    };
    const CHUNK: usize = 1024;
    let idx: Vec<usize> = (0..n).collect();
    for chunk in idx.chunks(CHUNK) {
        ws.load_inputs(data.n_in, chunk.len(), tangents, |i| data.input(chunk[i]));
        ws.forward(&params);
        for (i, &s) in chunk.iter().enumerate() {
            let e = sample_errors(&ws, data, i, s, &TrainSettings::default());
            out.value[s] = e.value;
            out.value_l2[s] = e.value_sq.sqrt();
            if let Some(sl) = &mut out.slope {
                sl[s] = e.slope;
            }
        }
    }
    Ok(out)
}

fn check_dims(mlp: &Mlp, data: &Dataset) -> Result<(), NetworkError> {
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

/// Errors of sample `s`, sitting at batch row `i` of a forward pass.
struct SampleErrors {
    /// `‖e‖∞`.
    value: f64,
    /// `‖e‖₂²`.
    value_sq: f64,
    /// `max |E|`.
    slope: f64,
    /// `‖E‖_F²`, or the sum of the Huber costs of `E`'s entries.
    slope_sq: f64,
}

/// Sample `s`'s Jacobian target `Dv` (`m × n`, row-major), unless the data has none or one of
/// its entries is not finite or exceeds `cap` ([`TrainSettings::jacobian_cap`]).
fn slope_target(data: &Dataset, s: usize, cap: Option<f64>) -> Option<&[f64]> {
    let k = data.n_out * data.n_in;
    let dv = &data.jacobians.as_ref()?[s * k..(s + 1) * k];
    let cap = cap.unwrap_or(f64::INFINITY);
    dv.iter().all(|d| d.abs() <= cap).then_some(dv)
}

/// The Sobolev term's cost of a slope residual `d`: `d²`, or Huber's `2δ|d| − δ²` beyond `δ`
/// ([`TrainSettings::jacobian_huber`]).
fn slope_cost(d: f64, huber: Option<f64>) -> f64 {
    match huber {
        Some(delta) if d.abs() > delta => 2.0 * delta * d.abs() - delta * delta,
        _ => d * d,
    }
}

/// Half the derivative of [`slope_cost`]: `d`, clamped to `[−δ, δ]` under Huber.
fn slope_cost_half_derivative(d: f64, huber: Option<f64>) -> f64 {
    match huber {
        Some(delta) => d.clamp(-delta, delta),
        None => d,
    }
}

fn sample_errors<T: Scalar>(
    ws: &Workspace<T>,
    data: &Dataset,
    i: usize,
    s: usize,
    settings: &TrainSettings,
) -> SampleErrors {
    let (n, m) = (data.n_in, data.n_out);
    let mut e = SampleErrors {
        value: 0.0,
        value_sq: 0.0,
        slope: 0.0,
        slope_sq: 0.0,
    };
    for (o, &t) in data.target(s).iter().enumerate() {
        let d = ws.out[i * m + o].to_f64() - t;
        e.value = e.value.max(d.abs());
        e.value_sq += d * d;
    }
    if ws.has_slopes() {
        if let Some(dv) = slope_target(data, s, settings.jacobian_cap) {
            for j in 0..n {
                for o in 0..m {
                    let d = ws.slope(i, j, o, m) - dv[o * n + j];
                    e.slope = e.slope.max(d.abs());
                    e.slope_sq += slope_cost(d, settings.jacobian_huber);
                }
            }
        }
    }
    e
}

/// Everything a run needs to continue: the checkpoint contents.
struct State<T> {
    params: Vec<Params<T>>,
    adam: Adam<T>,
    /// Epochs completed.
    epoch: usize,
    /// Per-sample loss from the last visit (hard-example scores).
    score: Vec<f64>,
    history: Vec<EpochStats>,
}

const CHECKPOINT_FORMAT: &str = "cbfreach-train-checkpoint";

impl<T: Scalar> State<T> {
    fn fresh(init: &Mlp, data: &Dataset, s: &TrainSettings) -> Self {
        let params = to_params::<T>(init);
        let adam = Adam::new(&params, s.adam_beta1, s.adam_beta2, s.adam_eps);
        State {
            params,
            adam,
            epoch: 0,
            score: vec![0.0; data.len()],
            history: Vec::new(),
        }
    }

    fn to_bytes(&self, settings: &TrainSettings, path: &Path) -> Result<Vec<u8>, NetworkError> {
        let mut t: Vec<RawTensor> = Vec::new();
        let groups = [
            ("net", &self.params),
            ("adam_m", &self.adam.m),
            ("adam_v", &self.adam.v),
        ];
        for (g, ps) in groups {
            for (k, p) in ps.iter().enumerate() {
                t.push((
                    format!("{g}.{k}.weight"),
                    T::DTYPE,
                    vec![p.n_out, p.n_in],
                    T::to_bytes(&p.w),
                ));
                t.push((
                    format!("{g}.{k}.bias"),
                    T::DTYPE,
                    vec![p.n_out],
                    T::to_bytes(&p.b),
                ));
            }
        }
        t.push((
            "score".into(),
            safetensors::Dtype::F64,
            vec![self.score.len()],
            super::io::f64_bytes(&self.score),
        ));
        let mut meta = HashMap::new();
        meta.insert("format".into(), CHECKPOINT_FORMAT.into());
        meta.insert("epoch".into(), self.epoch.to_string());
        meta.insert("adam_t".into(), self.adam.t.to_string());
        meta.insert("architecture".into(), to_mlp(&self.params).architecture());
        meta.insert("samples".into(), self.score.len().to_string());
        let json = |e: serde_json::Error| NetworkError::Format {
            path: path.to_path_buf(),
            message: e.to_string(),
        };
        meta.insert(
            "precision".into(),
            serde_json::to_string(&settings.precision).map_err(json)?,
        );
        meta.insert(
            "settings".into(),
            serde_json::to_string(settings).map_err(json)?,
        );
        // History as an f64 tensor: JSON would not round-trip every float exactly.
        let hist: Vec<f64> = self.history.iter().flat_map(EpochStats::to_row).collect();
        t.push((
            "history".into(),
            safetensors::Dtype::F64,
            vec![self.history.len(), EpochStats::ROW],
            super::io::f64_bytes(&hist),
        ));
        serialize(&t, meta, path)
    }

    fn load(
        bytes: &[u8],
        path: &Path,
        data: &Dataset,
        settings: &TrainSettings,
    ) -> Result<Self, NetworkError> {
        let raw = RawTensors::parse(bytes, path)?;
        let mismatch = |message: String| NetworkError::Checkpoint {
            path: path.to_path_buf(),
            message,
        };
        let meta = |key: &str| {
            raw.metadata
                .get(key)
                .cloned()
                .ok_or_else(|| mismatch(format!("metadata key `{key}` missing")))
        };
        if meta("format")? != CHECKPOINT_FORMAT {
            return Err(mismatch("not a cbfreach training checkpoint".into()));
        }
        let precision: Precision = serde_json::from_str(&meta("precision")?)
            .map_err(|e| mismatch(format!("bad precision: {e}")))?;
        if precision != settings.precision {
            return Err(mismatch(format!(
                "checkpoint precision {precision:?}, settings ask for {:?}",
                settings.precision
            )));
        }
        let num = |key: &str| {
            meta(key)?
                .parse::<u64>()
                .map_err(|e| mismatch(format!("metadata `{key}`: {e}")))
        };
        let epoch = num("epoch")? as usize;
        let adam_t = num("adam_t")?;
        let cols = match raw.shape("history")?.as_slice() {
            [_, c] if *c > 0 => *c,
            _ => EpochStats::ROW,
        };
        let history: Vec<EpochStats> = raw
            .f64s_unchecked("history")?
            .chunks_exact(cols)
            .map(EpochStats::from_row)
            .collect();
        let score = raw.f64s("score")?;
        if score.len() != data.len() {
            return Err(mismatch(format!(
                "checkpoint was written for {} samples, the data have {}",
                score.len(),
                data.len()
            )));
        }
        let read_group = |g: &str| -> Result<Vec<Params<T>>, NetworkError> {
            let mut out = Vec::new();
            let mut prev: Option<usize> = None;
            for k in 0.. {
                let wn = format!("{g}.{k}.weight");
                let shape = match raw.shape(&wn) {
                    Ok(s) => s,
                    Err(_) => break,
                };
                let bn = format!("{g}.{k}.bias");
                let w = T::read(&raw, &wn)?;
                let b = T::read(&raw, &bn)?;
                if shape.len() != 2
                    || prev.is_some_and(|p| p != shape[1])
                    || b.len() != shape[0]
                    || w.len() != shape[0] * shape[1]
                {
                    return Err(NetworkError::Shape {
                        path: path.to_path_buf(),
                        name: wn,
                        expected: vec![b.len(), prev.unwrap_or(shape.last().copied().unwrap_or(0))],
                        found: shape,
                    });
                }
                prev = Some(shape[0]);
                out.push(Params {
                    w,
                    b,
                    n_in: shape[1],
                    n_out: shape[0],
                });
            }
            Ok(out)
        };
        let params = read_group("net")?;
        if params.is_empty() {
            return Err(NetworkError::Empty);
        }
        let m = read_group("adam_m")?;
        let v = read_group("adam_v")?;
        let dims = |ps: &[Params<T>]| ps.iter().map(|p| (p.n_in, p.n_out)).collect::<Vec<_>>();
        if dims(&m) != dims(&params) || dims(&v) != dims(&params) {
            return Err(mismatch(
                "Adam moments do not match the network's shapes".into(),
            ));
        }
        check_dims(&to_mlp(&params), data)?;
        let adam = Adam {
            m,
            v,
            t: adam_t,
            beta1: settings.adam_beta1,
            beta2: settings.adam_beta2,
            eps: settings.adam_eps,
        };
        Ok(State {
            params,
            adam,
            epoch,
            score,
            history,
        })
    }

    fn save(&self, settings: &TrainSettings, path: &Path) -> Result<(), NetworkError> {
        let bytes = self.to_bytes(settings, path)?;
        write_atomically(path, &bytes)
    }
}

/// The sample order of epoch `e`: every sample of positive weight, plus (late in training) the
/// hardest `fraction`, shuffled together.
fn epoch_order(e: usize, active: &[usize], score: &[f64], settings: &TrainSettings) -> Vec<usize> {
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

/// What one visit of a sample found: its loss (the hard-example score) and errors.
struct Visit {
    sample: usize,
    loss: f64,
    value: f64,
    slope: f64,
}

/// Buffers for one chunk of a batch ([`TrainSettings::chunk_size`]): its share of the batch's
/// gradient, the visits of its samples and the sum of its IBP widths.
struct ChunkWorker<T> {
    ws: Workspace<T>,
    ibp: IbpWorkspace<T>,
    grads: Vec<Params<T>>,
    ibp_grads: Vec<Params<T>>,
    visits: Vec<Visit>,
    width_sum: f64,
}

impl<T: Scalar> ChunkWorker<T> {
    fn new(params: &[Params<T>]) -> Self {
        ChunkWorker {
            ws: Workspace::new(params.len()),
            ibp: IbpWorkspace::new(params.len()),
            grads: params.iter().map(|p| p.zeros_like()).collect(),
            ibp_grads: params.iter().map(|p| p.zeros_like()).collect(),
            visits: Vec::new(),
            width_sum: 0.0,
        }
    }

    /// The gradient of the samples `chunk` of a batch of `batch_len` samples into `grads`
    /// (overwritten): their terms of the batch loss (a mean over the whole batch), the IBP term
    /// too where `ibp_radius` is given.
    fn gradient(
        &mut self,
        params: &[Params<T>],
        data: &Dataset,
        chunk: &[usize],
        batch_len: usize,
        settings: &TrainSettings,
        ibp_radius: Option<&[f64]>,
    ) {
        let (n_in, n_out) = (data.n_in, data.n_out);
        let lambda = settings.jacobian_weight;
        let ws = &mut self.ws;
        let b = chunk.len();
        let excess = settings.ibp_excess.then_some(ibp_radius).flatten();
        let slopes = lambda > 0.0 || excess.is_some();
        match (&settings.secant_step, slopes) {
            (Some(h), true) => ws.load_stencil(n_in, b, h, |i| data.input(chunk[i])),
            _ => ws.load_inputs(n_in, b, slopes, |i| data.input(chunk[i])),
        }
        ws.forward(params);
        // ∂L/∂out, L = (1/batch_len) Σ w_s (‖e‖² + λ‖E‖²).
        ws.g.clear();
        ws.g.resize(ws.out.len(), T::ZERO);
        self.visits.clear();
        for (i, &s) in chunk.iter().enumerate() {
            let w = data.weight(s);
            let c = 2.0 * w / batch_len as f64;
            for (o, &t) in data.target(s).iter().enumerate() {
                let d = ws.out[i * n_out + o].to_f64() - t;
                ws.g[i * n_out + o] = T::from_f64(c * d);
            }
            if ws.has_slopes() {
                let dv = slope_target(data, s, settings.jacobian_cap).filter(|_| lambda > 0.0);
                for j in 0..n_in {
                    for o in 0..n_out {
                        let slope = ws.slope(i, j, o, n_out);
                        let mut g = 0.0;
                        if let Some(dv) = dv {
                            let d = slope - dv[o * n_in + j];
                            g +=
                                c * lambda * slope_cost_half_derivative(d, settings.jacobian_huber);
                        }
                        if let Some(radius) = excess {
                            // −λ_ibp |∂N_o/∂x_j| 2ε_j / (batch widths), the linear range's part.
                            let count = (batch_len * n_out) as f64;
                            if slope != 0.0 {
                                g -= settings.ibp_weight * 2.0 * radius[j] * slope.signum() / count;
                            }
                        }
                        ws.set_slope_gradient(i, j, o, n_out, g);
                    }
                }
            }
            let se = sample_errors(ws, data, i, s, settings);
            self.visits.push(Visit {
                sample: s,
                loss: w * (se.value_sq + lambda * se.slope_sq),
                value: se.value,
                slope: se.slope,
            });
        }
        ws.backward(params, &mut self.grads);
        self.width_sum = 0.0;
        if let Some(radius) = ibp_radius {
            let (lambda_ibp, count) = (settings.ibp_weight, batch_len * n_out);
            let centre = |i: usize| data.input(chunk[i]);
            let (ibp, grads) = (&mut self.ibp, &mut self.ibp_grads);
            self.width_sum = ibp_term(ibp, params, grads, lambda_ibp, count, b, centre, radius);
            for (g, gi) in self.grads.iter_mut().zip(&self.ibp_grads) {
                for (d, &v) in g.w.iter_mut().zip(&gi.w).chain(g.b.iter_mut().zip(&gi.b)) {
                    *d += v;
                }
            }
        }
    }
}

fn run<T: Scalar>(
    mut st: State<T>,
    data: &Dataset,
    settings: &TrainSettings,
    mut progress: impl FnMut(&EpochStats),
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
            && st.epoch % settings.revive_every == 0
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
        progress(&stats);
        if let Some(path) = &settings.checkpoint {
            let periodic = settings.checkpoint_every > 0
                && st.epoch.checked_rem(settings.checkpoint_every) == Some(0);
            if periodic || st.epoch == settings.epochs {
                st.save(settings, path)?;
            }
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

/// The IBP term `λ · (1/count) Σ_{i,o} 2 r_o(c_i, ε)` over the boxes of centres `centre(i)`,
/// `i < b` (`count`: the widths of the whole batch, of which these are a part): its gradient
/// goes to `grads` (overwritten); returns the sum of the widths `2 r_o`.
#[allow(clippy::too_many_arguments)]
fn ibp_term<'a, T: Scalar>(
    ws: &mut IbpWorkspace<T>,
    params: &[Params<T>],
    grads: &mut [Params<T>],
    lambda: f64,
    count: usize,
    b: usize,
    centre: impl Fn(usize) -> &'a [f64],
    radius: &[f64],
) -> f64 {
    ws.forward(params, b, centre, radius);
    let n = ws.out_r.len();
    let g_c = vec![T::ZERO; n];
    let g_r = vec![T::from_f64(2.0 * lambda / count.max(1) as f64); n];
    ws.backward(params, &g_c, &g_r, grads);
    ws.out_r.iter().map(|r| 2.0 * r.to_f64()).sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `v(x) = (sin x₁, x₁ x₂)` on an `k × k` grid over `[−1, 1]²`, with `Dv`.
    fn smooth_data(k: usize) -> Dataset {
        let mut d = Dataset {
            n_in: 2,
            n_out: 2,
            jacobians: Some(Vec::new()),
            ..Default::default()
        };
        for i in 0..k {
            for j in 0..k {
                let x1 = -1.0 + 2.0 * i as f64 / (k - 1) as f64;
                let x2 = -1.0 + 2.0 * j as f64 / (k - 1) as f64;
                d.inputs.extend([x1, x2]);
                d.targets.extend([x1.sin(), x1 * x2]);
                if let Some(jac) = &mut d.jacobians {
                    jac.extend([x1.cos(), 0.0, x2, x1]);
                }
            }
        }
        d
    }

    fn quick(epochs: usize, lambda: f64) -> TrainSettings {
        TrainSettings {
            epochs,
            batch_size: 32,
            learning_rate: 1e-2,
            lr_min: 1e-4,
            jacobian_weight: lambda,
            seed: 7,
            ..Default::default()
        }
    }

    /// Worst slope error on a finer off-grid set, from `Mlp::jacobian`.
    fn max_slope_error(mlp: &Mlp) -> f64 {
        let mut worst = 0.0f64;
        for i in 0..41 {
            for j in 0..41 {
                let x1 = -0.99 + 1.98 * i as f64 / 40.0;
                let x2 = -0.99 + 1.98 * j as f64 / 40.0;
                let jn = mlp.jacobian(&[x1, x2]);
                let jv = [x1.cos(), 0.0, x2, x1];
                for (a, b) in jn.iter().zip(jv) {
                    worst = worst.max((a - b).abs());
                }
            }
        }
        worst
    }

    #[test]
    fn fits_a_smooth_function() {
        let data = smooth_data(21);
        let mut calls = 0;
        let (mlp, rep) = train(
            Mlp::random(&[2, 16, 16, 2], 1),
            &data,
            &quick(1000, 0.0),
            |s| {
                calls += 1;
                assert_eq!(s.epoch, calls);
            },
        )
        .unwrap();
        assert_eq!(calls, 1000);
        assert_eq!(rep.epochs.len(), 1000);
        // The returned network is what the report measured.
        assert_eq!(evaluate(&mlp, &data).unwrap(), rep.final_errors);
        eprintln!("fit: {:?}", rep.final_errors);
        assert!(rep.final_errors.max_error < 0.03, "{:?}", rep.final_errors);
        assert!(rep.final_errors.mean_error < 0.01, "{:?}", rep.final_errors);
        assert!(rep.epochs[999].loss < rep.epochs[0].loss / 100.0);
    }

    /// `smooth_data(21)` with three samples' slope target `∂v₀/∂x₀` set to `value`, as at a
    /// jump of `v`.
    fn absurd_slopes(value: f64) -> Dataset {
        let mut d = smooth_data(21);
        if let Some(jac) = &mut d.jacobians {
            for s in [40, 200, 330] {
                jac[4 * s] = value;
            }
        }
        d
    }

    #[test]
    fn appended_samples_follow_with_their_weights() {
        let mut a = smooth_data(5);
        let mut b = smooth_data(3);
        let (la, lb) = (a.len(), b.len());
        b.weights = Some(vec![2.0; lb]);
        let (b_inputs, b_jac) = (b.inputs.clone(), b.jacobians.clone().unwrap());
        a.append(b).unwrap();
        a.validate().unwrap();
        assert_eq!(a.len(), la + lb);
        assert_eq!(&a.inputs[la * 2..], &b_inputs[..]);
        assert_eq!(&a.jacobians.as_ref().unwrap()[la * 4..], &b_jac[..]);
        let w = a.weights.unwrap();
        assert!(w[..la].iter().all(|&x| x == 1.0) && w[la..].iter().all(|&x| x == 2.0));
        let mut no_jacobians = smooth_data(3);
        no_jacobians.jacobians = None;
        assert!(smooth_data(3).append(no_jacobians).is_err());
    }

    #[test]
    fn capped_slope_targets_leave_the_sobolev_term() {
        // A few samples with absurd slope targets, as at a jump of `v`: with the cap, what the
        // targets are no longer matters (bit-identical weights for two different absurd values),
        // and training matches the smooth data's slope; without it, they wreck the fit.
        let init = Mlp::random(&[2, 16, 16, 2], 3);
        let capped = TrainSettings {
            jacobian_cap: Some(50.0),
            ..quick(60, 0.1)
        };
        let (a, _) = train(init.clone(), &absurd_slopes(1e4), &capped, |_| {}).unwrap();
        let (b, _) = train(init.clone(), &absurd_slopes(-3e5), &capped, |_| {}).unwrap();
        assert_eq!(a, b, "capped targets still steer the training");
        let (c, _) = train(init, &absurd_slopes(1e4), &quick(60, 0.1), |_| {}).unwrap();
        let (ea, ec) = (max_slope_error(&a), max_slope_error(&c));
        assert!(ea < 0.5 * ec, "capped {ea} vs uncapped {ec}");
        assert!(TrainSettings {
            jacobian_cap: Some(0.0),
            ..quick(1, 0.1)
        }
        .validate()
        .is_err());
    }

    #[test]
    fn huber_slope_residuals_pull_with_bounded_force() {
        // Beyond δ a residual pulls with force δ whatever its size: two absurd targets of the
        // same sign give bit-identical weights (the plain square does not), and a δ above
        // every residual is the plain square exactly.
        let init = Mlp::random(&[2, 16, 16, 2], 3);
        let plain = TrainSettings {
            hard_example_fraction: 0.0,
            ..quick(20, 0.1)
        };
        let huber = |delta: f64| TrainSettings {
            jacobian_huber: Some(delta),
            ..plain.clone()
        };
        let run = |data: &Dataset, settings: &TrainSettings| {
            train(init.clone(), data, settings, |_| {}).unwrap().0
        };
        let (a, b) = (
            run(&absurd_slopes(1e3), &huber(1.0)),
            run(&absurd_slopes(1e4), &huber(1.0)),
        );
        assert_eq!(a, b, "Huber residuals beyond δ still pull by their size");
        assert_ne!(
            run(&absurd_slopes(1e3), &plain),
            run(&absurd_slopes(1e4), &plain)
        );
        let data = absurd_slopes(1e3);
        assert_eq!(run(&data, &huber(1e9)), run(&data, &plain));
        assert!(huber(0.0).validate().is_err());
        assert!(huber(f64::NAN).validate().is_err());
    }

    #[test]
    fn hard_examples_are_revisited_as_often_as_asked() {
        // Scores 0..100: the top 5 % are samples 95..99; each must appear 1 + repeats times.
        let active: Vec<usize> = (0..100).collect();
        let score: Vec<f64> = (0..100).map(|s| s as f64).collect();
        for repeats in [0, 1, 4] {
            let settings = TrainSettings {
                epochs: 10,
                hard_example_fraction: 0.05,
                hard_example_start: 0.0,
                hard_example_repeats: repeats,
                ..TrainSettings::default()
            };
            let order = epoch_order(3, &active, &score, &settings);
            assert_eq!(order.len(), 100 + 5 * repeats);
            for s in 0..100 {
                let visits = order.iter().filter(|&&o| o == s).count();
                assert_eq!(visits, if s >= 95 { 1 + repeats } else { 1 }, "sample {s}");
            }
            // Epoch 0 never oversamples: there are no scores yet.
            assert_eq!(epoch_order(0, &active, &score, &settings).len(), 100);
        }
    }

    #[test]
    fn jacobian_term_lowers_slope_error() {
        let data = smooth_data(21);
        let init = Mlp::random(&[2, 16, 16, 2], 3);
        let (plain, rp) = train(init.clone(), &data, &quick(150, 0.0), |_| {}).unwrap();
        let (sob, rs) = train(init, &data, &quick(150, 0.1), |_| {}).unwrap();
        let (ep, es) = (max_slope_error(&plain), max_slope_error(&sob));
        eprintln!(
            "slope error max: plain {ep:.3} (data {:?}), sobolev {es:.3} (data {:?}); value max {:.4} vs {:.4}",
            rp.final_errors.max_slope_error,
            rs.final_errors.max_slope_error,
            rp.final_errors.max_error,
            rs.final_errors.max_error
        );
        assert!(es < ep, "Sobolev {es} not below plain {ep}");
        assert!(rs.final_errors.max_slope_error < rp.final_errors.max_slope_error);
        assert!(rs.final_errors.max_error < 0.1, "{:?}", rs.final_errors);
    }

    /// With `secant_step` the Sobolev term is `λ Σ ((N(x + h e_j) − N(x − h e_j))/2h − Dv)²`:
    /// the worker's gradient equals the finite differences of that loss computed from
    /// `Mlp::forward`, and the slope term moves the biases (where the ReLUs switch), which a
    /// slope term on the pointwise Jacobian cannot.
    #[test]
    fn secant_term_gradient_is_its_loss_gradient() {
        let data = smooth_data(5);
        let net = to_params::<f64>(&Mlp::random(&[2, 7, 6, 2], 11));
        let h = [0.1, 0.07];
        let s = TrainSettings {
            jacobian_weight: 0.3,
            secant_step: Some(h.to_vec()),
            ..Default::default()
        };
        let batch: Vec<usize> = (0..data.len()).collect();
        let loss = |net: &[Params<f64>]| {
            let mlp = to_mlp(net);
            let mut sum = 0.0;
            for &i in &batch {
                let x = data.input(i);
                let y = mlp.forward(x);
                let value: f64 = y
                    .iter()
                    .zip(data.target(i))
                    .map(|(a, t)| (a - t).powi(2))
                    .sum();
                let dv = slope_target(&data, i, None).unwrap();
                let mut slope = 0.0;
                for (j, &hj) in h.iter().enumerate() {
                    let (mut plus, mut minus) = (x.to_vec(), x.to_vec());
                    plus[j] += hj;
                    minus[j] -= hj;
                    let (yp, ym) = (mlp.forward(&plus), mlp.forward(&minus));
                    for o in 0..2 {
                        slope += ((yp[o] - ym[o]) / (2.0 * hj) - dv[o * 2 + j]).powi(2);
                    }
                }
                sum += value + 0.3 * slope;
            }
            sum / batch.len() as f64
        };
        let mut worker = ChunkWorker::new(&net);
        worker.gradient(&net, &data, &batch, batch.len(), &s, None);
        let visited: f64 = worker.visits.iter().map(|v| v.loss).sum::<f64>() / batch.len() as f64;
        assert!((visited - loss(&net)).abs() < 1e-12 * loss(&net));
        let fd_step = 1e-6;
        for k in 0..net.len() {
            for idx in 0..net[k].w.len() + net[k].b.len() {
                let nudge = |d: f64| {
                    let mut p = net.clone();
                    match idx.checked_sub(p[k].w.len()) {
                        None => p[k].w[idx] += d,
                        Some(bi) => p[k].b[bi] += d,
                    }
                    loss(&p)
                };
                let fd = (nudge(fd_step) - nudge(-fd_step)) / (2.0 * fd_step);
                let g = match idx.checked_sub(net[k].w.len()) {
                    None => worker.grads[k].w[idx],
                    Some(bi) => worker.grads[k].b[bi],
                };
                assert!(
                    (fd - g).abs() < 1e-5 * (1.0 + fd.abs()),
                    "layer {k} parameter {idx}: finite differences {fd}, gradient {g}"
                );
            }
        }
        // The slope term's own share of the biases' gradient: none from the pointwise
        // Jacobian, some from the differences.
        let bias_share = |secant_step: Option<Vec<f64>>| {
            let with = |jacobian_weight: f64| {
                let s = TrainSettings {
                    jacobian_weight,
                    secant_step: secant_step.clone(),
                    ..Default::default()
                };
                let mut worker = ChunkWorker::new(&net);
                worker.gradient(&net, &data, &batch, batch.len(), &s, None);
                worker.grads
            };
            let (on, off) = (with(0.3), with(0.0));
            on.iter()
                .zip(&off)
                .flat_map(|(a, b)| a.b.iter().zip(&b.b).map(|(x, y)| (x - y).abs()))
                .fold(0.0f64, f64::max)
        };
        assert_eq!(bias_share(None), 0.0);
        assert!(bias_share(Some(h.to_vec())) > 1e-3);
        // One step, or one per input: three steps for two inputs are refused by name.
        let three = TrainSettings {
            secant_step: Some(vec![0.1; 3]),
            ..s
        };
        let err = train(to_mlp(&net), &data, &three, |_| {}).unwrap_err();
        assert!(err.to_string().contains("secant_step"), "{err}");
    }

    /// A batch's gradient summed from uneven chunks is the whole batch's gradient (value,
    /// Sobolev and IBP terms: each chunk's part is a mean over the whole batch), and each
    /// sample's visit is the same.
    #[test]
    fn chunked_gradient_is_the_batch_gradient() {
        let data = smooth_data(6);
        let net = to_params::<f64>(&Mlp::random(&[2, 12, 12, 2], 5));
        let radius = [0.05, 0.05];
        let batch: Vec<usize> = (0..data.len()).rev().collect();
        let gradient = |chunks: &[&[usize]], ibp_weight: f64| {
            let s = TrainSettings {
                jacobian_weight: 0.3,
                ibp_weight,
                ..Default::default()
            };
            let mut sum: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
            let (mut visits, mut width) = (Vec::new(), 0.0);
            for chunk in chunks {
                let mut worker = ChunkWorker::new(&net);
                worker.gradient(&net, &data, chunk, batch.len(), &s, Some(&radius));
                for (g, gi) in sum.iter_mut().zip(&worker.grads) {
                    for (d, &v) in g.w.iter_mut().zip(&gi.w).chain(g.b.iter_mut().zip(&gi.b)) {
                        *d += v;
                    }
                }
                visits.extend(worker.visits.iter().map(|v| (v.sample, v.loss)));
                width += worker.width_sum;
            }
            let flat: Vec<f64> = sum
                .iter()
                .flat_map(|p| p.w.iter().chain(&p.b))
                .copied()
                .collect();
            (flat, visits, width)
        };
        let uneven: Vec<&[usize]> = batch.chunks(7).collect();
        let (whole, whole_visits, whole_width) = gradient(&[&batch], 0.02);
        let (chunked, chunked_visits, chunked_width) = gradient(&uneven, 0.02);
        let (no_ibp, _, _) = gradient(&[&batch], 0.0);
        let scale = whole.iter().fold(0.0f64, |m, g| m.max(g.abs()));
        let gap = |a: &[f64], b: &[f64]| {
            a.iter()
                .zip(b)
                .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
        };
        assert!(
            gap(&whole, &chunked) <= 1e-12 * scale,
            "{}",
            gap(&whole, &chunked)
        );
        // The IBP term's share is far above that tolerance: a chunk weighing it by its own
        // size instead of the batch's would fail the test.
        assert!(gap(&whole, &no_ibp) > 1e-3 * scale);
        assert_eq!(whole_visits.len(), batch.len());
        for ((s, a), (t, b)) in whole_visits.iter().zip(&chunked_visits) {
            assert_eq!(s, t);
            assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0));
        }
        assert!((whole_width - chunked_width).abs() <= 1e-12 * whole_width);
    }

    /// With [`TrainSettings::ibp_excess`] the IBP term subtracts the network's linear range
    /// `λ_ibp/(B m) Σ_{s,o,j} |∂N_o/∂x_j(x_s)| 2ε_j`: the gradients with and without it differ
    /// by that range's gradient, taken here by central differences over the weights with
    /// `Mlp::jacobian`.
    #[test]
    fn ibp_excess_subtracts_the_linear_range() {
        let data = smooth_data(4);
        let mlp = Mlp::random(&[2, 8, 8, 2], 9);
        let net = to_params::<f64>(&mlp);
        let (radius, lambda_ibp) = ([0.05, 0.03], 0.7);
        let batch: Vec<usize> = (0..data.len()).collect();
        let gradient = |ibp_excess: bool| {
            let s = TrainSettings {
                ibp_weight: lambda_ibp,
                ibp_excess,
                ..Default::default()
            };
            let mut worker = ChunkWorker::new(&net);
            worker.gradient(&net, &data, &batch, batch.len(), &s, Some(&radius));
            let g = worker.grads;
            g.iter()
                .flat_map(|p| p.w.iter().chain(&p.b))
                .copied()
                .collect::<Vec<f64>>()
        };
        let (plain, excess) = (gradient(false), gradient(true));
        let range = |m: &Mlp| {
            let mut sum = 0.0;
            for s in &batch {
                let jac = m.jacobian(data.input(*s));
                for o in 0..2 {
                    sum += (0..2)
                        .map(|j| jac[o * 2 + j].abs() * 2.0 * radius[j])
                        .sum::<f64>();
                }
            }
            lambda_ibp * sum / (batch.len() * 2) as f64
        };
        let mut checked = 0;
        let mut index = 0;
        for (k, layer) in mlp.layers.iter().enumerate() {
            // Weights only: the range does not depend on the output bias.
            for (i, _) in layer.weight.iter().enumerate().step_by(3) {
                let h = 1e-6;
                let (mut up, mut down) = (mlp.clone(), mlp.clone());
                up.layers[k].weight[i] += h;
                down.layers[k].weight[i] -= h;
                let fd = (range(&up) - range(&down)) / (2.0 * h);
                let d = excess[index + i] - plain[index + i];
                assert!(
                    (d + fd).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "layer {k} w{i}: {d} vs −{fd}"
                );
                checked += usize::from(fd != 0.0);
            }
            index += layer.weight.len() + layer.bias.len();
        }
        assert!(checked > 20, "{checked} weights move the range");
    }

    /// Chunks are added in a fixed order: one thread or three give the same network.
    #[test]
    fn chunked_training_does_not_depend_on_threads() {
        let data = smooth_data(9);
        let s = TrainSettings {
            chunk_size: 8,
            ibp_weight: 0.01,
            hard_example_start: 0.3,
            ..quick(4, 0.1)
        };
        let init = Mlp::random(&[2, 16, 16, 2], 2);
        let on = |threads: usize| {
            let pool = rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap();
            pool.install(|| train(init.clone(), &data, &s, |_| {}).unwrap().0)
        };
        assert_eq!(on(1), on(3));
    }

    #[test]
    fn same_seed_is_bitwise_identical_and_f64_works() {
        let data = smooth_data(9);
        for precision in [Precision::F32, Precision::F64] {
            let s = TrainSettings {
                precision,
                hard_example_start: 0.3,
                ..quick(10, 0.1)
            };
            let init = Mlp::random(&[2, 16, 16, 2], 2);
            let (a, _) = train(init.clone(), &data, &s, |_| {}).unwrap();
            let (b, _) = train(init.clone(), &data, &s, |_| {}).unwrap();
            assert_eq!(a, b);
            let (c, _) = train(init, &data, &TrainSettings { seed: 8, ..s }, |_| {}).unwrap();
            assert_ne!(a, c);
        }
    }

    #[test]
    fn bad_inputs_are_errors_not_panics() {
        let data = smooth_data(5);
        let net = Mlp::random(&[2, 4, 2], 0);
        let s = quick(1, 0.0);
        let mut d = data.clone();
        d.targets.pop();
        assert!(matches!(
            train(net.clone(), &d, &s, |_| {}),
            Err(NetworkError::Dataset { .. })
        ));
        let mut d = data.clone();
        d.inputs[3] = f64::NAN;
        assert!(matches!(
            train(net.clone(), &d, &s, |_| {}),
            Err(NetworkError::Dataset { .. })
        ));
        let d = Dataset {
            jacobians: None,
            ..data.clone()
        };
        assert!(matches!(
            train(net.clone(), &d, &quick(1, 0.1), |_| {}),
            Err(NetworkError::Settings { .. })
        ));
        let bad = TrainSettings {
            batch_size: 0,
            ..s.clone()
        };
        assert!(matches!(
            train(net.clone(), &data, &bad, |_| {}),
            Err(NetworkError::Settings { .. })
        ));
        let wrong = Mlp::random(&[3, 4, 2], 0);
        assert!(matches!(
            train(wrong, &data, &s, |_| {}),
            Err(NetworkError::Dataset { .. })
        ));
        // A diverging run is reported, not returned as NaN weights.
        let wild = TrainSettings {
            learning_rate: 1e30,
            lr_min: 0.0,
            ..s.clone()
        };
        let r = train(net.clone(), &data, &wild, |_| {});
        assert!(
            matches!(r, Err(NetworkError::Diverged { .. }))
                || r.is_ok_and(|(m, _)| m
                    .layers
                    .iter()
                    .all(|l| l.weight.iter().all(|x| x.is_finite())))
        );
        // Checkpoints of other data or precision are refused.
        let dir = tempfile::tempdir().unwrap();
        let ck = dir.path().join("ck.safetensors");
        let with_ck = TrainSettings {
            checkpoint: Some(ck.clone()),
            ..s.clone()
        };
        train(net, &data, &with_ck, |_| {}).unwrap();
        let other = smooth_data(6);
        assert!(matches!(
            resume(&ck, &other, &s, |_| {}),
            Err(NetworkError::Checkpoint { .. })
        ));
        let f64s = TrainSettings {
            precision: Precision::F64,
            ..s.clone()
        };
        assert!(matches!(
            resume(&ck, &data, &f64s, |_| {}),
            Err(NetworkError::Checkpoint { .. })
        ));
        assert!(matches!(
            resume(&dir.path().join("none"), &data, &s, |_| {}),
            Err(NetworkError::Io { .. })
        ));
    }

    #[test]
    fn resume_matches_uninterrupted_run() {
        let data = smooth_data(9);
        let dir = tempfile::tempdir().unwrap();
        let ck = dir.path().join("ck.safetensors");
        let mut init = Mlp::random(&[2, 16, 16, 2], 4);
        // Dead neurons, revived after epochs 3, 6 and 9: across the interruption too.
        init.layers[1].bias[..3].fill(-100.0);
        for precision in [Precision::F32, Precision::F64] {
            // The IBP term (f32 run), ramping across the interruption, resumes bit-identically.
            let ibp = precision == Precision::F32;
            let full = TrainSettings {
                precision,
                hard_example_start: 0.2,
                ibp_weight: if ibp { 0.01 } else { 0.0 },
                ibp_start: 2,
                ibp_ramp: 6,
                revive_every: 3,
                ..quick(12, 0.1)
            };
            let (a, ra) = train(init.clone(), &data, &full, |_| {}).unwrap();
            // Interrupt at epoch 5: the checkpoint written after epoch 5 is copied away when
            // epoch 6 reports (checkpoints are written after the progress callback).
            let part = TrainSettings {
                checkpoint: Some(ck.clone()),
                checkpoint_every: 5,
                ..full.clone()
            };
            let ck5 = dir.path().join("ck5.safetensors");
            train(init.clone(), &data, &part, |s| {
                if s.epoch == 6 {
                    std::fs::copy(&ck, &ck5).unwrap();
                }
            })
            .unwrap();
            let mut seen = Vec::new();
            let (b, rb) = resume(&ck5, &data, &full, |s| seen.push(s.epoch)).unwrap();
            assert_eq!(seen, (6..=12).collect::<Vec<_>>());
            assert_eq!(ra.epochs[1].ibp_width, None);
            assert_eq!(ra.epochs[2].ibp_width.is_some(), ibp);
            assert!(ra.epochs[2].revived >= 3, "{:?}", ra.epochs[2]);
            assert_eq!(a, b);
            assert_eq!(rb.resumed_from, Some(5));
            assert_eq!(rb.epochs.len(), 12);
            let untimed = |v: &[EpochStats]| {
                v.iter()
                    .map(|e| EpochStats {
                        seconds: 0.0,
                        ..e.clone()
                    })
                    .collect::<Vec<_>>()
            };
            assert_eq!(untimed(&ra.epochs), untimed(&rb.epochs));
            // Resuming the final checkpoint has nothing left to do.
            let (c, _) = resume(&ck, &data, &full, |_| panic!("no epochs left")).unwrap();
            assert_eq!(a, c);
            assert_eq!(ra.final_errors, rb.final_errors);
        }
    }

    /// A network whose second hidden layer is mostly dead fits worse than one whose dead
    /// neurons are revived during training, and revival leaves them live.
    #[test]
    fn revived_neurons_learn() {
        let data = smooth_data(21);
        let mut init = Mlp::random(&[2, 16, 16, 2], 1);
        init.layers[1].bias[..12].fill(-100.0);
        let points = &data.inputs;
        assert_eq!(init.live_neurons(points), vec![16, 4]);
        let run = |revive_every| {
            let settings = TrainSettings {
                revive_every,
                ..quick(300, 0.0)
            };
            let (mlp, rep) = train(init.clone(), &data, &settings, |_| {}).unwrap();
            let revived: usize = rep.epochs.iter().map(|e| e.revived).sum();
            (
                mlp.live_neurons(points),
                rep.final_errors.mean_error,
                revived,
            )
        };
        let (live_dead, err_dead, none) = run(0);
        let (live, err, revived) = run(50);
        eprintln!("without revival: live {live_dead:?}, mean error {err_dead}");
        eprintln!("with revival: live {live:?}, mean error {err}, {revived} revivals");
        assert_eq!(none, 0);
        assert_eq!(
            live_dead[1], 4,
            "dead neurons have no gradient and stay dead"
        );
        assert!(revived >= 12);
        assert!(live[1] >= 14, "{live:?}");
        assert!(err < 0.75 * err_dead, "{err} vs {err_dead}");
    }

    /// The IBP workspace's intervals are those of `crate::bounds` (IBP), and its gradient of
    /// `L = Σ a·out_c + Σ b·out_r` matches central finite differences.
    #[test]
    fn ibp_term_matches_bounds_and_finite_differences() {
        use crate::bounds::{network_bounds, BoundMethod};
        let mlp = Mlp::random(&[2, 6, 5, 2], 11);
        let centres: Vec<Vec<f64>> = (0..5)
            .map(|i| vec![0.3 * i as f64 - 0.6, 0.25 - 0.15 * i as f64])
            .collect();
        let radius = [0.1, 0.2];
        let net = to_params::<f64>(&mlp);
        let mut ws = IbpWorkspace::<f64>::new(net.len());
        ws.forward(&net, centres.len(), |i| &centres[i], &radius);
        for (i, c) in centres.iter().enumerate() {
            let lo: Vec<f64> = c.iter().zip(radius).map(|(x, r)| x - r).collect();
            let hi: Vec<f64> = c.iter().zip(radius).map(|(x, r)| x + r).collect();
            let bd = network_bounds(&mlp, &lo, &hi, BoundMethod::Ibp).unwrap();
            for o in 0..2 {
                let (oc, or) = (ws.out_c[i * 2 + o], ws.out_r[i * 2 + o]);
                assert!(
                    (oc - or - bd.lower[o]).abs() < 1e-9,
                    "{} vs {}",
                    oc - or,
                    bd.lower[o]
                );
                assert!((oc + or - bd.upper[o]).abs() < 1e-9);
            }
        }
        let a: Vec<f64> = (0..10).map(|k| (k as f64 * 0.9).cos()).collect();
        let bw: Vec<f64> = (0..10).map(|k| 1.0 + (k as f64 * 0.7).sin()).collect();
        let loss = |net: &[Params<f64>]| {
            let mut w = IbpWorkspace::<f64>::new(net.len());
            w.forward(net, centres.len(), |i| &centres[i], &radius);
            w.out_c.iter().zip(&a).map(|(x, y)| x * y).sum::<f64>()
                + w.out_r.iter().zip(&bw).map(|(x, y)| x * y).sum::<f64>()
        };
        let mut grads: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
        ws.backward(&net, &a, &bw, &mut grads);
        let h = 1e-6;
        let mut checked = 0;
        for k in 0..net.len() {
            for (is_w, len) in [(true, net[k].w.len()), (false, net[k].b.len())] {
                for idx in 0..len {
                    let (mut plus, mut minus) = (net.clone(), net.clone());
                    if is_w {
                        plus[k].w[idx] += h;
                        minus[k].w[idx] -= h;
                    } else {
                        plus[k].b[idx] += h;
                        minus[k].b[idx] -= h;
                    }
                    let fd = (loss(&plus) - loss(&minus)) / (2.0 * h);
                    let g = if is_w {
                        grads[k].w[idx]
                    } else {
                        grads[k].b[idx]
                    };
                    assert!(
                        (fd - g).abs() < 1e-6 * (1.0 + fd.abs()),
                        "layer {k} {} [{idx}]: fd {fd} vs {g}",
                        if is_w { "w" } else { "b" }
                    );
                    checked += 1;
                }
            }
        }
        assert_eq!(checked, 6 * 2 + 6 + 5 * 6 + 5 + 2 * 5 + 2);
        // The training term: λ · mean 2 r, gradient 2λ/(B m) on every output radius.
        let mut g2: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
        let sum = ibp_term(
            &mut ws,
            &net,
            &mut g2,
            0.3,
            2 * centres.len(),
            centres.len(),
            |i| &centres[i],
            &radius,
        );
        let want: f64 = ws.out_r.iter().map(|r| 2.0 * r).sum();
        assert_eq!(sum, want);
        let mut g3: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
        let s = 2.0 * 0.3 / 10.0;
        ws.backward(&net, &[0.0; 10], &[s; 10], &mut g3);
        assert_eq!(g2, g3);
    }

    /// Mean (IBP, CROWN) output width and mean sampled range over boxes of half-width `eps`
    /// centred on a 7 × 7 grid of `[−0.8, 0.8]²`.
    fn looseness(mlp: &Mlp, eps: f64) -> (f64, f64, f64) {
        use crate::bounds::{network_bounds, BoundMethod};
        let (mut ibp, mut crown, mut range) = (0.0, 0.0, 0.0);
        let mut count = 0.0;
        for i in 0..7 {
            for j in 0..7 {
                let c = [-0.8 + 0.8 * i as f64 / 3.0, -0.8 + 0.8 * j as f64 / 3.0];
                let lo = [c[0] - eps, c[1] - eps];
                let hi = [c[0] + eps, c[1] + eps];
                let bi = network_bounds(mlp, &lo, &hi, BoundMethod::Ibp).unwrap();
                let bc = network_bounds(mlp, &lo, &hi, BoundMethod::Crown).unwrap();
                let (mut smin, mut smax) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
                for p in 0..11 {
                    for q in 0..11 {
                        let x = [lo[0] + 0.2 * eps * p as f64, lo[1] + 0.2 * eps * q as f64];
                        let y = mlp.forward(&x);
                        for o in 0..2 {
                            smin[o] = smin[o].min(y[o]);
                            smax[o] = smax[o].max(y[o]);
                        }
                    }
                }
                for o in 0..2 {
                    ibp += bi.upper[o] - bi.lower[o];
                    crown += bc.upper[o] - bc.lower[o];
                    range += smax[o] - smin[o];
                    count += 1.0;
                }
            }
        }
        (ibp / count, crown / count, range / count)
    }

    /// Certified training: with the IBP term the widths on small boxes shrink towards the
    /// true ranges, at a modest cost in accuracy.
    #[test]
    fn ibp_term_tightens_bounds() {
        let data = smooth_data(21);
        let init = Mlp::random(&[2, 32, 32, 2], 5);
        let (eps, lam) = (0.05, 0.01);
        let plain_s = quick(300, 0.1);
        let cert_s = TrainSettings {
            ibp_weight: lam,
            ibp_radius: vec![eps],
            ibp_ramp: 30,
            ..plain_s.clone()
        };
        let (plain, rp) = train(init.clone(), &data, &plain_s, |_| {}).unwrap();
        let (cert, rc) = train(init, &data, &cert_s, |_| {}).unwrap();
        assert!(rp.epochs.iter().all(|e| e.ibp_width.is_none()));
        assert!(rc.epochs.iter().all(|e| e.ibp_width.is_some()));
        let (pi, pc, pr) = looseness(&plain, eps);
        let (ci, cc, cr) = looseness(&cert, eps);
        eprintln!(
            "plain: IBP {pi:.4} CROWN {pc:.4} range {pr:.4} max err {:.4} mean {:.4}\n\
             cert:  IBP {ci:.4} CROWN {cc:.4} range {cr:.4} max err {:.4} mean {:.4}\n\
             IBP/range {:.2} → {:.2}, CROWN/range {:.2} → {:.2}",
            rp.final_errors.max_error,
            rp.final_errors.mean_error,
            rc.final_errors.max_error,
            rc.final_errors.mean_error,
            pi / pr,
            ci / cr,
            pc / pr,
            cc / cr
        );
        // Measured (release): IBP/range 6.77 → 1.38, CROWN/range 1.05 → 1.03, max error
        // 0.012 → 0.031, mean 0.0034 → 0.0039.
        assert!(
            ci / cr < 0.3 * (pi / pr),
            "IBP looseness {} vs {}",
            ci / cr,
            pi / pr
        );
        assert!(cc - cr < pc - pr, "CROWN excess {} vs {}", cc - cr, pc - pr);
        assert!(rc.final_errors.max_error < 3.0 * rp.final_errors.max_error.max(0.01));
        assert!(rc.final_errors.mean_error < 2.0 * rp.final_errors.mean_error);
    }
}

/// Epoch timing for the paper's scenario-1 size (run with
/// `cargo test --release --lib bench_epoch -- --ignored --nocapture`).
#[cfg(test)]
mod bench {
    use super::*;

    #[test]
    #[ignore = "timing; run in release"]
    fn bench_epoch_2x400x400x400x2_100k() {
        let n = 100_000;
        let mut d = Dataset {
            n_in: 2,
            n_out: 2,
            jacobians: Some(Vec::new()),
            ..Default::default()
        };
        for s in 0..n {
            let x1 = -3.5 + 8.0 * ((s * 7919) % n) as f64 / n as f64;
            let x2 = -3.0 + 6.0 * ((s * 104_729) % n) as f64 / n as f64;
            d.inputs.extend([x1, x2]);
            d.targets.extend([x1.sin(), x1 * x2]);
            if let Some(j) = &mut d.jacobians {
                j.extend([x1.cos(), 0.0, x2, x1]);
            }
        }
        let init = Mlp::random(&[2, 400, 400, 400, 2], 1);
        // Chunk = batch: one chunk whose products use every thread (the arithmetic before
        // chunks); smaller chunks run side by side.
        for (precision, batch, chunk, lambda, ibp) in [
            (Precision::F32, 256, 256, 0.0, 0.0),
            (Precision::F32, 256, 128, 0.0, 0.0),
            (Precision::F32, 256, 256, 0.1, 0.0),
            (Precision::F32, 256, 128, 0.1, 0.0),
            (Precision::F32, 256, 256, 0.1, 0.005),
            (Precision::F32, 256, 128, 0.1, 0.005),
            (Precision::F32, 256, 64, 0.1, 0.005),
            (Precision::F32, 256, 32, 0.1, 0.005),
            (Precision::F32, 1024, 1024, 0.1, 0.0),
            (Precision::F32, 1024, 128, 0.1, 0.0),
            (Precision::F64, 256, 256, 0.1, 0.0),
            (Precision::F64, 256, 128, 0.1, 0.0),
        ] {
            let s = TrainSettings {
                epochs: 2,
                batch_size: batch,
                chunk_size: chunk,
                jacobian_weight: lambda,
                ibp_weight: ibp,
                precision,
                hard_example_fraction: 0.0,
                ..Default::default()
            };
            let t = Instant::now();
            let (_, rep) = train(init.clone(), &d, &s, |_| {}).unwrap();
            let total = t.elapsed().as_secs_f64();
            let ep: Vec<String> = rep
                .epochs
                .iter()
                .map(|e| format!("{:.2}", e.seconds))
                .collect();
            eprintln!(
                "{precision:?} batch {batch} chunk {chunk} λ {lambda} λ_ibp {ibp}: epochs {} s, final f64 evaluation {:.2} s, loss {:.4}",
                ep.join(" / "),
                total - rep.epochs.iter().map(|e| e.seconds).sum::<f64>(),
                rep.epochs[1].loss
            );
        }
    }
}

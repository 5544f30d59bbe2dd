//! The trainer of the surrogate `N ≈ v`: data, settings, loss terms, checkpoints and the loop.
//! May import: its own submodules, the rest of [`crate::network`]; nothing outside it.
//!
//! Training a ReLU [`Mlp`](crate::network::Mlp) `N ≈ v` with Adam and an optional Jacobian
//! (Sobolev) term.
//!
//! Loss per batch `B` (docs/design.md §2b: slope errors matter as much as value errors):
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
//! **Certified training** (docs/design.md §2b: equally accurate networks differ by orders of
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
//!
//! **Layout.** `dataset` (the [`Dataset`]), `settings` ([`TrainSettings`]), `loss` (the terms
//! above, per sample and per chunk of a batch), `checkpoint` (a run's state on disk), `run`
//! (the loop: [`train`], [`resume`], [`train_until`]), `report` (what a run reports;
//! [`evaluate`]), `normalise` (the data's affine maps, folded into the saved network:
//! [`Normalisation`]), `accuracy` (the [`Target`] and what a network [`Measured`]),
//! `recipe` (the default staged schedule to an accuracy target: [`train_to_target`]), `staged` (its progress on disk between stages:
//! [`StagedCheckpoint`]), `adaptive` (more samples where the network errs most:
//! [`refine_round`]), `resolution` (how finely the training grid resolves `v`:
//! [`grid_resolution`]), `steep` (the slope targets the Sobolev term leaves out:
//! [`SlopeCap`]).

mod accuracy;
mod adaptive;
mod checkpoint;
mod dataset;
mod loss;
mod normalise;
mod recipe;
mod report;
mod resolution;
mod run;
mod settings;
mod staged;
mod steep;

#[cfg(test)]
mod bench;
#[cfg(test)]
mod tests;

pub use accuracy::{ibp_looseness, measure, Measured, Target};
pub use adaptive::{refine_round, Added, Oracle, Refinement, RoundReport, SampleSlopes};
pub use dataset::Dataset;
pub use normalise::{Normalisation, METADATA_KEY as NORMALISATION_KEY};
pub use recipe::{
    hidden_layers, train_to_target, Recipe, RecipeData, RecipeProgress, RecipeReport, Stage,
    StageKind, StageReport, CERTIFY_WEIGHTS, DEEP_HIDDEN_LAYERS,
};
pub use report::{evaluate, pointwise_errors, EpochStats, ErrorStats, PointErrors, TrainReport};
pub use resolution::{grid_resolution, Resolution};
pub use run::{resume, resume_until, train, train_until, Flow};
pub use settings::{LrSchedule, Precision, TrainSettings};
pub use staged::StagedCheckpoint;
pub use steep::{SlopeCap, SlopeLimit, SteepReport, OUTLIER_FACTOR};

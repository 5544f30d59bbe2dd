//! [`Normalisation`]: the affine maps that put a data set's inputs in `[−1, 1]` and its targets
//! near unit scale for training, and their folding into the first and last layers afterwards.
//! May import: the trainer's [`Dataset`] and [`TrainSettings`], [`Mlp`], [`NetworkError`].
//!
//! Adam's step moves every weight by about the learning rate whatever the units, so a system
//! in newtons (targets ~10³) or with states of very different ranges trains badly with the
//! same defaults as one in units of order 1 (issue 38: adaptive cruise control in newtons
//! reached a mean error of 5,935 N). The trainer therefore works on
//!
//! ```text
//! x̂ = (x − cₓ) / sₓ   (per input: the data's range mapped to [−1, 1])
//! v̂ = (v − c_v) / s_v (per output centre, one scale: the largest output's standard deviation)
//! ```
//!
//! and the trained `N̂` is folded back, `N(x) = c_v + s_v N̂((x − cₓ)/sₓ)`, into the first
//! layer (`W diag(1/sₓ)`, `b − W (cₓ/sₓ)`) and the last (`s_v W`, `s_v b + c_v`): the saved file
//! is a plain MLP in the scenario's units. One output scale keeps `‖N − v‖∞ = s_v ‖N̂ − v̂‖∞`
//! exact, so value targets carry over; slopes scale per entry, `∂v̂ᵢ/∂x̂ⱼ = ∂vᵢ/∂xⱼ · sⱼ/s_v`.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::dataset::Dataset;
use super::settings::TrainSettings;
use super::steep::SlopeLimit;
use crate::network::{Mlp, NetworkError};

/// The metadata key under which [`Normalisation::metadata`] stores the maps (JSON).
pub const METADATA_KEY: &str = "normalisation";

/// Input and output affine maps of training (see this module's documentation).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Normalisation {
    /// `cₓ`, one per input.
    pub input_centre: Vec<f64>,
    /// `sₓ > 0`, one per input.
    pub input_scale: Vec<f64>,
    /// `c_v`, one per output.
    pub output_centre: Vec<f64>,
    /// `s_v > 0`, shared by the outputs.
    pub output_scale: f64,
}

/// A scale of 0 (a constant input or target) or a non-finite one is taken as 1.
fn usable(scale: f64) -> f64 {
    if scale.is_finite() && scale > 1e-12 {
        scale
    } else {
        1.0
    }
}

impl Normalisation {
    /// The maps that change nothing.
    pub fn identity(n_in: usize, n_out: usize) -> Self {
        Normalisation {
            input_centre: vec![0.0; n_in],
            input_scale: vec![1.0; n_in],
            output_centre: vec![0.0; n_out],
            output_scale: 1.0,
        }
    }

    /// From the samples of positive weight: each input's range to `[−1, 1]`, each output's
    /// mean to 0 and the largest output standard deviation to 1.
    pub fn from_data(data: &Dataset) -> Self {
        let (n, m) = (data.n_in, data.n_out);
        let mut lo = vec![f64::INFINITY; n];
        let mut hi = vec![f64::NEG_INFINITY; n];
        let (mut sum, mut sum_sq, mut count) = (vec![0.0; m], vec![0.0; m], 0.0);
        for s in (0..data.len()).filter(|&s| data.weight(s) > 0.0) {
            for (j, &x) in data.input(s).iter().enumerate() {
                lo[j] = lo[j].min(x);
                hi[j] = hi[j].max(x);
            }
            for (o, &v) in data.target(s).iter().enumerate() {
                sum[o] += v;
                sum_sq[o] += v * v;
            }
            count += 1.0;
        }
        let count = f64::max(count, 1.0);
        let output_centre: Vec<f64> = sum.iter().map(|s| s / count).collect();
        let spread = (0..m)
            .map(|o| (sum_sq[o] / count - output_centre[o] * output_centre[o]).max(0.0))
            .fold(0.0f64, f64::max)
            .sqrt();
        Normalisation {
            input_centre: (0..n).map(|j| 0.5 * (lo[j] + hi[j])).collect(),
            input_scale: (0..n).map(|j| usable(0.5 * (hi[j] - lo[j]))).collect(),
            output_centre,
            output_scale: usable(spread),
        }
    }

    fn check(&self, n_in: usize, n_out: usize) -> Result<(), NetworkError> {
        let ok = self.input_centre.len() == n_in
            && self.input_scale.len() == n_in
            && self.output_centre.len() == n_out
            && self.input_scale.iter().all(|s| s.is_finite() && *s > 0.0)
            && self.input_centre.iter().all(|c| c.is_finite())
            && self.output_centre.iter().all(|c| c.is_finite())
            && self.output_scale.is_finite()
            && self.output_scale > 0.0;
        if ok {
            Ok(())
        } else {
            Err(NetworkError::Settings {
                message: format!("normalisation {self:?} does not fit {n_in} inputs and {n_out} outputs, or has a scale ≤ 0"),
            })
        }
    }

    /// A normalised input `x` in the data's units.
    pub fn raw_input(&self, x: &[f64]) -> Vec<f64> {
        x.iter()
            .enumerate()
            .map(|(j, &v)| self.input_centre[j] + self.input_scale[j] * v)
            .collect()
    }

    /// `data` in normalised units. A sample whose slope target `limit` leaves out
    /// ([`SlopeLimit`]; `--jacobian-cap` in the data's units, or the staged schedule's
    /// outliers) gets NaN slopes, which the Sobolev term skips.
    pub fn dataset(
        &self,
        data: &Dataset,
        limit: Option<SlopeLimit>,
    ) -> Result<Dataset, NetworkError> {
        let (n, m) = (data.n_in, data.n_out);
        self.check(n, m)?;
        let inputs = data
            .inputs
            .chunks_exact(n)
            .flat_map(|x| (0..n).map(move |j| (x[j] - self.input_centre[j]) / self.input_scale[j]))
            .collect();
        let targets = data
            .targets
            .chunks_exact(m)
            .flat_map(|v| (0..m).map(move |o| (v[o] - self.output_centre[o]) / self.output_scale))
            .collect();
        let jacobians = data.jacobians.as_ref().map(|jac| {
            jac.chunks_exact(m * n)
                .flat_map(|dv| {
                    let capped = limit.is_some_and(|l| l.leaves_out(self, dv));
                    (0..m * n).map(move |k| {
                        if capped {
                            f64::NAN
                        } else {
                            self.slope_entry(k, dv[k])
                        }
                    })
                })
                .collect()
        });
        Ok(Dataset {
            n_in: n,
            n_out: m,
            inputs,
            targets,
            jacobians,
            weights: data.weights.clone(),
        })
    }

    /// Entry `k` (row-major in the `m × n` Jacobian) of a slope target in normalised units:
    /// `∂v̂ᵢ/∂x̂ⱼ = ∂vᵢ/∂xⱼ · sⱼ/s_v`.
    pub fn slope_entry(&self, k: usize, d: f64) -> f64 {
        d * self.input_scale[k % self.input_scale.len()] / self.output_scale
    }

    /// Per-input lengths (IBP radii, secant steps; one entry for all or one per input) in
    /// normalised units.
    pub fn lengths(&self, h: &[f64]) -> Vec<f64> {
        (0..self.input_scale.len())
            .map(|j| h[j.min(h.len().saturating_sub(1))] / self.input_scale[j])
            .collect()
    }

    /// `settings` for training on [`Normalisation::dataset`]: IBP radii and secant steps in
    /// normalised units, the slope cap already applied by the data.
    pub fn settings(&self, settings: &TrainSettings) -> TrainSettings {
        TrainSettings {
            ibp_radius: self.lengths(&settings.ibp_radius),
            secant_step: settings.secant_step.as_deref().map(|h| self.lengths(h)),
            jacobian_cap: None,
            ..settings.clone()
        }
    }

    /// The network in the data's units from one trained on normalised data:
    /// `N(x) = c_v + s_v N̂((x − cₓ)/sₓ)`, folded into the first and last layers.
    pub fn fold(&self, normalised: &Mlp) -> Result<Mlp, NetworkError> {
        normalised.validate("<normalised network>")?;
        self.check(normalised.input_dim(), normalised.output_dim())?;
        let mut net = normalised.clone();
        let first = &mut net.layers[0];
        let n = first.n_in;
        for (row, b) in first.weight.chunks_exact_mut(n).zip(&mut first.bias) {
            for ((w, s), c) in row
                .iter_mut()
                .zip(&self.input_scale)
                .zip(&self.input_centre)
            {
                *w /= s;
                *b -= *w * c;
            }
        }
        let last = net
            .layers
            .last_mut()
            .expect("validated: at least one layer");
        let s = self.output_scale;
        last.weight.iter_mut().for_each(|w| *w *= s);
        for (b, c) in last.bias.iter_mut().zip(&self.output_centre) {
            *b = s * *b + c;
        }
        Ok(net)
    }

    /// The inverse of [`Normalisation::fold`]: a network in the data's units as one on
    /// normalised data (to fine-tune a saved network).
    pub fn unfold(&self, net: &Mlp) -> Result<Mlp, NetworkError> {
        net.validate("<network>")?;
        self.check(net.input_dim(), net.output_dim())?;
        let mut out = net.clone();
        let last = out
            .layers
            .last_mut()
            .expect("validated: at least one layer");
        let s = self.output_scale;
        last.weight.iter_mut().for_each(|w| *w /= s);
        for (b, c) in last.bias.iter_mut().zip(&self.output_centre) {
            *b = (*b - c) / s;
        }
        let first = &mut out.layers[0];
        let n = first.n_in;
        for (row, b) in first.weight.chunks_exact_mut(n).zip(&mut first.bias) {
            for ((w, s), c) in row
                .iter_mut()
                .zip(&self.input_scale)
                .zip(&self.input_centre)
            {
                *b += *w * c;
                *w *= s;
            }
        }
        Ok(out)
    }

    /// The maps as file metadata (JSON under [`METADATA_KEY`]): the saved network is already
    /// folded, so they are a record of training, not needed to evaluate it.
    pub fn metadata(&self) -> BTreeMap<String, String> {
        let mut m = BTreeMap::new();
        if let Ok(json) = serde_json::to_string(self) {
            m.insert(METADATA_KEY.into(), json);
        }
        m
    }

    /// The maps recorded by [`Normalisation::metadata`], if any.
    pub fn from_metadata(
        metadata: &BTreeMap<String, String>,
    ) -> Result<Option<Self>, NetworkError> {
        metadata
            .get(METADATA_KEY)
            .map(|json| {
                serde_json::from_str(json).map_err(|e| NetworkError::Settings {
                    message: format!("metadata `{METADATA_KEY}`: {e}"),
                })
            })
            .transpose()
    }
}

//! How accurate a network is against the filter, in the scenario's units: the [`Target`] a
//! run trains to, what a network [`Measured`] on the validation points ([`measure`], with the
//! IBP looseness of its bounds), and how closely it fits its own training samples
//! ([`training_fit`]). May import: [`Mlp`], the trainer's data and reports.

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::adaptive::Oracle;
use super::normalise::Normalisation;
use super::report::pointwise_errors;
use super::Dataset;
use crate::network::{Mlp, NetworkError};

/// The accuracy a network must reach, in the scenario's units (`[training] target`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Target {
    /// Largest `‖N(x) − v(x)‖∞` over the validation points.
    pub linf: Option<f64>,
    /// 95th percentile over the validation points of `max_ij |DN − Dv|_ij`.
    pub slope_p95: Option<f64>,
}

/// What a network measures on the validation data, in the scenario's units.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct Measured {
    /// Max ℓ∞ error.
    pub linf: f64,
    /// Mean ℓ∞ error.
    pub mean: f64,
    /// 95th percentile of the slope error (NaN without slope targets).
    pub slope_p95: f64,
    /// Median over small boxes around validation points of the IBP output width over the
    /// sampled output range (1 is exact; [`Recipe::ibp_radius`] wide).
    pub ibp_looseness: f64,
}

impl std::fmt::Display for Target {
    /// `max ℓ∞ ≤ …, slope p95 ≤ …`, or a line saying that the whole schedule runs.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match (self.linf, self.slope_p95) {
            (None, None) => write!(f, "none ([training] target: the whole schedule)"),
            (Some(v), None) => write!(f, "max ℓ∞ ≤ {v}"),
            (None, Some(s)) => write!(f, "slope p95 ≤ {s}"),
            (Some(v), Some(s)) => write!(f, "max ℓ∞ ≤ {v}, slope p95 ≤ {s}"),
        }
    }
}

impl Target {
    /// Whether `m` meets every bound that is set.
    pub fn met(&self, m: &Measured) -> bool {
        self.linf.is_none_or(|t| m.linf <= t) && self.slope_p95.is_none_or(|t| m.slope_p95 <= t)
    }
}

/// The `q`-quantile of `v` (NaNs left out; NaN if none is left).
fn quantile(v: &[f64], q: f64) -> f64 {
    let mut v: Vec<f64> = v.iter().copied().filter(|x| !x.is_nan()).collect();
    if v.is_empty() {
        return f64::NAN;
    }
    v.sort_by(f64::total_cmp);
    v[((q * (v.len() - 1) as f64).round() as usize).min(v.len() - 1)]
}

/// [`Measured`] of `net` on `validation` (both in the scenario's units).
pub fn measure(
    net: &Mlp,
    validation: &Dataset,
    ibp_radius: &[f64],
) -> Result<Measured, NetworkError> {
    let errors = pointwise_errors(net, validation)?;
    let n = validation.len().max(1) as f64;
    Ok(Measured {
        linf: errors.value.iter().copied().fold(0.0, f64::max),
        mean: errors.value.iter().sum::<f64>() / n,
        slope_p95: errors
            .slope
            .as_deref()
            .map_or(f64::NAN, |s| quantile(s, 0.95)),
        ibp_looseness: ibp_looseness(net, validation, ibp_radius),
    })
}

/// Median over up to 200 boxes `[x − ε, x + ε]` around validation points of the summed IBP
/// output width ([`crate::bounds::ibp`]) over the summed sampled output range (32 points a box);
/// boxes on which the network is constant to sampling are left out.
pub fn ibp_looseness(net: &Mlp, validation: &Dataset, radius: &[f64]) -> f64 {
    let n = validation.n_in;
    let stride = validation.len().div_ceil(200).max(1);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let r = |j: usize| radius[j.min(radius.len().saturating_sub(1))];
    let mut ratios = Vec::new();
    for s in (0..validation.len()).step_by(stride) {
        let x = validation.input(s);
        let lower: Vec<f64> = (0..n).map(|j| x[j] - r(j)).collect();
        let upper: Vec<f64> = (0..n).map(|j| x[j] + r(j)).collect();
        // Non-finite inputs or weights: no width to compare.
        let Ok(b) = crate::bounds::ibp(net, &lower, &upper) else {
            continue;
        };
        let m = b.upper.len();
        let (mut lo, mut hi) = (vec![f64::INFINITY; m], vec![f64::NEG_INFINITY; m]);
        for _ in 0..32 {
            let p: Vec<f64> = (0..n)
                .map(|j| x[j] + r(j) * rng.random_range(-1.0..=1.0))
                .collect();
            for (o, y) in net.forward(&p).into_iter().enumerate() {
                lo[o] = lo[o].min(y);
                hi[o] = hi[o].max(y);
            }
        }
        let range: f64 = (0..m).map(|o| hi[o] - lo[o]).sum();
        let width: f64 = (0..m).map(|o| b.upper[o] - b.lower[o]).sum();
        if range > 1e-12 * (1.0 + width) {
            ratios.push(width / range);
        }
    }
    quantile(&ratios, 0.5)
}

/// [`super::RecipeReport::training_fit`]: `net` and `data` in normalised units, the error in the
/// scenario's (one output scale for all outputs); samples of weight 0 and those not judged
/// (outside `C ∩ S`) left out; 0 where no sample is judged.
pub(super) fn training_fit(
    net: &Mlp,
    data: &Dataset,
    norm: &Normalisation,
    oracle: &dyn Oracle,
) -> Result<f64, NetworkError> {
    let errors = pointwise_errors(net, data)?;
    Ok((0..data.len())
        .filter(|&s| data.weight(s) > 0.0 && oracle.judged(&norm.raw_input(data.input(s))))
        .map(|s| errors.value[s] * norm.output_scale)
        .fold(0.0, f64::max))
}

//! Which slope targets the Sobolev term leaves out ([`SlopeCap`]).
//! May import: the trainer's [`Dataset`], [`Normalisation`].
//!
//! Where `v` jumps (scenario 2 at (1, 0) and (3, 0), where `L_g h = 0`) or has a kink the grid
//! does not resolve, a secant target is of order `jump / step` and a pointwise one can be as
//! large: scenario 2's grid has targets up to 4,400 in normalised units against a median of
//! 1.3. Under a squared loss one such sample outweighs hundreds of thousands of ordinary ones,
//! and a few hundred of them steer every step: with them (and unsafe samples 0.3 deep in the
//! obstacle) scenario 2's secant stage took the max error from 1.25 to 3.2 (docs/networks.md). Both shipped paper networks were made
//! with such samples left out (`--jacobian-cap 20`: 0.2 % of scenario 1's, 0.6 % of scenario
//! 2's). The staged schedule leaves out, by default, the samples whose steepest target is more
//! than [`OUTLIER_FACTOR`] times the grid's 99th percentile: a jump or an unresolved kink,
//! never the steep but smooth part of `v` that the network must follow (the unicycle's, up to
//! 76 in data units: 3 of its 12,825 samples). Their values are still trained on. A jump lies
//! on a curve (a surface in three states), so its samples are a thin share of a grid, well
//! under the 1 % the percentile leaves room for (scenario 2: 0.3 % steeper than 50).

use serde::{Deserialize, Serialize};

use super::dataset::Dataset;
use super::normalise::Normalisation;

/// How many times the grid's 99th percentile of steepness a slope target may reach before
/// the staged schedule leaves it out ([`SlopeCap::Outliers`]). At 3: 70 of the 83,803
/// samples scenario 2 trains on, 12 of the README example's 5,517 (the refine rounds add
/// theirs where the network errs, beside kinks), none of ACC's; at 10 scenario 2 kept
/// enough of its jumps to end at slope p95 0.81 instead of 0.46 (docs/networks.md).
pub const OUTLIER_FACTOR: f64 = 3.0;

/// Which slope targets the Sobolev term leaves out (this module's documentation).
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum SlopeCap {
    /// None.
    Off,
    /// Those with some `|∂vᵢ/∂xⱼ|` above this, in the data's units (`--jacobian-cap`).
    Above(f64),
    /// Those whose steepest entry, in normalised units, is above this many times the 99th
    /// percentile of the data set's own (the staged schedule's default: [`OUTLIER_FACTOR`]).
    Outliers(f64),
}

/// A [`SlopeCap`] resolved for one data set: the bound a sample's slope target is held to.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SlopeLimit {
    /// Every entry at most this, in the data's units.
    Data(f64),
    /// The steepest entry at most this, in normalised units.
    Normalised(f64),
}

impl SlopeLimit {
    /// Whether `dv` (one sample's `m × n` target, in the data's units) is left out.
    pub fn leaves_out(&self, norm: &Normalisation, dv: &[f64]) -> bool {
        match *self {
            SlopeLimit::Data(cap) => dv.iter().any(|d| d.abs() > cap),
            SlopeLimit::Normalised(cap) => steepness(norm, dv) > cap,
        }
    }
}

/// The steepest entry of `dv` in normalised units, `max |∂vᵢ/∂xⱼ| sⱼ / s_v`.
fn steepness(norm: &Normalisation, dv: &[f64]) -> f64 {
    dv.iter()
        .enumerate()
        .map(|(k, d)| norm.slope_entry(k, *d).abs())
        .fold(0.0, f64::max)
}

impl SlopeCap {
    /// The limit for `data` (its slope targets in the data's units), or none: no cap, or no
    /// finite slope targets to take a percentile of.
    pub fn limit(&self, norm: &Normalisation, data: &Dataset) -> Option<SlopeLimit> {
        match *self {
            SlopeCap::Off => None,
            SlopeCap::Above(cap) => Some(SlopeLimit::Data(cap)),
            SlopeCap::Outliers(factor) => {
                let k = data.n_in * data.n_out;
                // The samples trained on: those far inside an obstacle weigh 0.
                let mut steep: Vec<f64> = data
                    .jacobians
                    .as_deref()?
                    .chunks_exact(k)
                    .enumerate()
                    .filter(|&(s, dv)| data.weight(s) > 0.0 && dv.iter().all(|d| d.is_finite()))
                    .map(|(_, dv)| steepness(norm, dv))
                    .collect();
                if steep.is_empty() {
                    return None;
                }
                let at = ((steep.len() - 1) as f64 * 0.99).round() as usize;
                let (_, p99, _) = steep.select_nth_unstable_by(at, f64::total_cmp);
                // A grid where v is flat on 99 % of the points has nothing to call an outlier.
                (*p99 > 0.0).then_some(SlopeLimit::Normalised(factor * *p99))
            }
        }
    }
}

/// What the cap left out of the data sets of a staged run.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SteepReport {
    /// The bound on the pointwise targets' steepness, in normalised units (none: no cap).
    pub pointwise_limit: Option<f64>,
    /// Pointwise samples left out of the slope term (the grid's and the refine rounds').
    pub pointwise_left_out: usize,
    /// The same for the secant targets.
    pub secant_limit: Option<f64>,
    /// Secant samples left out.
    pub secant_left_out: usize,
}

/// Counts the samples trained on (weight > 0) of a normalised data set whose slopes are NaN
/// (left out).
pub fn left_out(data: &Dataset) -> usize {
    let k = data.n_in * data.n_out;
    data.jacobians.as_deref().map_or(0, |jac| {
        jac.chunks_exact(k)
            .enumerate()
            .filter(|&(s, dv)| data.weight(s) > 0.0 && dv.iter().any(|d| d.is_nan()))
            .count()
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(slopes: &[f64]) -> Dataset {
        Dataset {
            n_in: 1,
            n_out: 1,
            inputs: (0..slopes.len()).map(|i| i as f64).collect(),
            targets: vec![0.0; slopes.len()],
            jacobians: Some(slopes.to_vec()),
            weights: None,
        }
    }

    #[test]
    fn outliers_are_judged_against_the_data_sets_own_percentile() {
        // 1,000 samples of slope 1 … 1,000 (p99 ≈ 990) and one jump of 10⁵.
        let mut slopes: Vec<f64> = (1..=1000).map(f64::from).collect();
        slopes.push(1e5);
        let d = data(&slopes);
        let norm = Normalisation::identity(1, 1);
        let limit = SlopeCap::Outliers(3.0).limit(&norm, &d).unwrap();
        let SlopeLimit::Normalised(cap) = limit else {
            panic!("{limit:?}")
        };
        assert!((cap - 3.0 * 991.0).abs() < 1e-9, "{cap}");
        let out: Vec<usize> = (0..d.len())
            .filter(|&s| limit.leaves_out(&norm, &d.jacobians.as_ref().unwrap()[s..s + 1]))
            .collect();
        assert_eq!(out, vec![1000]);
        // Scaling every input alike scales the percentile and each sample's steepness alike:
        // the same samples are left out.
        let scaled = Normalisation {
            input_scale: vec![2.0],
            ..norm.clone()
        };
        let again = SlopeCap::Outliers(3.0).limit(&scaled, &d).unwrap();
        assert!(again.leaves_out(&scaled, &[1e5]) && !again.leaves_out(&scaled, &[1000.0]));
        // Samples of weight 0 (far inside an obstacle) neither set the percentile nor count.
        let mut heavy = data(&[1e5; 20]);
        heavy
            .jacobians
            .as_mut()
            .unwrap()
            .extend((1..=1000).map(f64::from));
        heavy.inputs.extend((0..1000).map(f64::from));
        heavy.targets.extend([0.0; 1000]);
        heavy.weights = Some([vec![0.0; 20], vec![1.0; 1000]].concat());
        let limit = SlopeCap::Outliers(3.0).limit(&norm, &heavy);
        assert_eq!(limit, Some(SlopeLimit::Normalised(3.0 * 990.0)));
        let unit = norm.dataset(&heavy, limit).unwrap();
        assert_eq!(left_out(&unit), 0);
        assert!(unit.jacobians.as_ref().unwrap()[..20]
            .iter()
            .all(|d| d.is_nan()));
        // Flat data and data without slopes have no limit.
        assert_eq!(
            SlopeCap::Outliers(3.0).limit(&norm, &data(&[0.0; 10])),
            None
        );
        assert_eq!(SlopeCap::Off.limit(&norm, &d), None);
        assert_eq!(
            SlopeCap::Above(20.0).limit(&norm, &d),
            Some(SlopeLimit::Data(20.0))
        );
    }
}

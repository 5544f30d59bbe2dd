//! Looseness: how much wider the bounds of `N` (IBP, CROWN) are than its range sampled on
//! small boxes across `C ∩ S`. It may import the network, its bounds and the analysis' settings.

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::measure::{centred_grid, Percentiles};
use super::{check_box_width, check_dims, random_points, AnalysisError, ErrorSettings};
use crate::bounds::{network_bounds, BoundMethod};
use crate::boxes::IntervalBox;
use crate::network::Mlp;
use crate::scenario::Scenario;

/// Median and max of a bound-width-to-sampled-range ratio.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Ratio {
    /// Min over the boxes: below 1 only if a bound missed a sampled output.
    pub min: f64,
    /// Median over the boxes.
    pub median: f64,
    /// Max over the boxes.
    pub max: f64,
}

/// Bound looseness of a network over small boxes across `C ∩ S`.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Looseness {
    /// Boxes measured.
    pub boxes: usize,
    /// Their width along every axis ([`ErrorSettings::looseness_width`]).
    pub width: f64,
    /// IBP.
    pub ibp: Ratio,
    /// Backward CROWN (adaptive relaxation).
    pub crown: Ratio,
}

/// Bound looseness: boxes of width [`ErrorSettings::looseness_width`] centred on a grid over `C`
/// (at most [`ErrorSettings::looseness_boxes`]; those with a safe centre), and for each the ratio
/// `maxⱼ (N̄ⱼ − N̲ⱼ) / maxⱼ rangeⱼ`, where `rangeⱼ` is the spread of `Nⱼ` over the box's corners
/// and [`ErrorSettings::looseness_samples`] random points (floored at 1e-12).
pub fn looseness(
    s: &Scenario,
    net: &Mlp,
    settings: &ErrorSettings,
) -> Result<Looseness, AnalysisError> {
    check_dims(s, net)?;
    check_box_width(settings)?;
    let c = &s.reach.region;
    let n = s.n();
    let w = settings.looseness_width;
    let spacing = w.max((c.volume() / settings.looseness_boxes.max(1) as f64).powf(1.0 / n as f64));
    let counts: Vec<usize> = c
        .widths()
        .iter()
        .map(|&wi| ((wi / spacing).floor() as usize).max(1))
        .collect();
    let boxes: Vec<IntervalBox> = centred_grid(c, &counts)
        .into_iter()
        .filter(|x| s.is_safe(x))
        .map(|x| IntervalBox {
            lower: x.iter().map(|v| v - 0.5 * w).collect(),
            upper: x.iter().map(|v| v + 0.5 * w).collect(),
        })
        .collect();
    let ratios: Vec<Result<(f64, f64), AnalysisError>> = boxes
        .par_iter()
        .enumerate()
        .map(|(k, b)| {
            let seed = settings.seed ^ (k as u64).wrapping_mul(0x2545_F491_4F6C_DD1D);
            let mut pts: Vec<Vec<f64>> = b.corners().collect();
            pts.extend(random_points(b, settings.looseness_samples, seed));
            let m = net.output_dim();
            let (mut lo, mut hi) = (vec![f64::INFINITY; m], vec![f64::NEG_INFINITY; m]);
            for p in &pts {
                for (j, y) in net.forward(p).into_iter().enumerate() {
                    lo[j] = lo[j].min(y);
                    hi[j] = hi[j].max(y);
                }
            }
            let range = (0..m).map(|j| hi[j] - lo[j]).fold(0.0, f64::max).max(1e-12);
            let width = |method| -> Result<f64, AnalysisError> {
                let bd = network_bounds(net, &b.lower, &b.upper, method)?;
                Ok((0..m)
                    .map(|j| bd.upper[j] - bd.lower[j])
                    .fold(0.0, f64::max))
            };
            Ok((
                width(BoundMethod::Ibp)? / range,
                width(BoundMethod::Crown)? / range,
            ))
        })
        .collect();
    let mut ibp = Vec::with_capacity(ratios.len());
    let mut crown = Vec::with_capacity(ratios.len());
    for r in ratios {
        let (a, b) = r?;
        ibp.push(a);
        crown.push(b);
    }
    let ratio = |v: &[f64]| {
        let p = Percentiles::of(v);
        Ratio {
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            median: p.median,
            max: p.max,
        }
    };
    Ok(Looseness {
        boxes: ibp.len(),
        width: w,
        ibp: ratio(&ibp),
        crown: ratio(&crown),
    })
}

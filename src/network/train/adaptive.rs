//! Adaptive data: more samples of `v` where the network errs most ([`Oracle`],
//! [`Refinement`], [`refine_round`]).
//! May import: the trainer's [`Dataset`] and error measures, [`Mlp`], [`NetworkError`].
//!
//! A fixed grid says nothing about `v` between its points: where `v` has a kink or steepens
//! between them (ACC in newtons: 217 N at the kink where the input bound meets the CBF row,
//! against a target of 20 N; docs/networks.md), no fit to the grid's samples is known to be
//! close there. A round draws fresh quasi-random points of `C ∩ S` (Halton, shifted per seed),
//! measures the network against the true `v` on them, and adds the worst points and random
//! points around each (within half a grid spacing) to the training set. The validation points
//! stay unseen: the rounds draw off the grid.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};

use super::report::pointwise_errors;
use super::Dataset;
use crate::network::{Mlp, NetworkError};

/// The slopes [`Oracle::sample`] returns with the values.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum SampleSlopes<'a> {
    /// None (`Dataset::jacobians` is `None`): for scoring, a solve a point.
    Values,
    /// The pointwise Jacobian `Dv`.
    Pointwise,
    /// Secant slopes over `±h` per axis.
    Secant(&'a [f64]),
}

/// The true `v` (the filter), asked for wherever a round needs samples.
pub trait Oracle: Sync {
    /// Lower and upper corners of the box fresh points are drawn from (the training region).
    fn bounds(&self) -> (Vec<f64>, Vec<f64>);
    /// Whether accuracy is judged at `x` (`C ∩ S`): only such points are scored.
    fn judged(&self, x: &[f64]) -> bool;
    /// `v` (with `slopes`) at those `points` where the filter is defined (the rest left out,
    /// in order).
    fn sample(&self, points: &[Vec<f64>], slopes: SampleSlopes) -> Dataset;
}

/// How a round of adaptive sampling chooses its points ([`refine_round`]).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Refinement {
    /// Fresh points drawn per round (those of `C ∩ S` are scored).
    pub candidates: usize,
    /// The worst-scored points taken per round, each with its neighbours.
    pub worst: usize,
    /// Random points drawn around each of them.
    pub neighbours: usize,
    /// Half-widths per axis of the box around each worst point (half the grid's spacing).
    pub radius: Vec<f64>,
    /// Most samples the training set may hold: the rounds add nothing beyond it.
    pub max_samples: usize,
    /// Seed of the sequence's shift and the neighbours.
    pub seed: u64,
}

impl Refinement {
    /// The defaults for a training set of `samples` points on a grid of `spacing` per axis:
    /// 32,768 candidates a round (one solve each: ACC's worst spot, beside `∂S` near the
    /// kink, was missed by 8,192), the worst 64 with 8 neighbours each, at most 4× the grid's
    /// samples (at least 50,000 more, at most 4 million in all).
    pub fn for_data(samples: usize, spacing: &[f64], seed: u64) -> Refinement {
        Refinement {
            candidates: 32_768,
            worst: 64,
            neighbours: 8,
            radius: spacing.iter().map(|h| 0.5 * h).collect(),
            max_samples: (4 * samples).max(samples + 50_000).min(4_000_000),
            seed,
        }
    }
}

/// What one round found and added.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct RoundReport {
    /// Fresh points scored (where the filter is defined): the candidates of `C ∩ S` and the
    /// points drawn around the worst.
    pub scored: usize,
    /// The largest ℓ∞ error among them, in the scenario's units.
    pub max_error: f64,
    /// Where (empty if none was scored).
    pub at: Vec<f64>,
    /// How many of them err by more than the threshold (the target's `linf`).
    pub above: usize,
    /// Samples added to the training set.
    pub added: usize,
}

/// The samples a round adds, in the scenario's units.
#[derive(Clone, Debug)]
pub struct Added {
    /// With pointwise slopes.
    pub pointwise: Dataset,
    /// The same points with secant slopes (where asked for).
    pub secant: Option<Dataset>,
    /// What the round found.
    pub report: RoundReport,
}

/// Point `index` of the Halton sequence in `[0, 1)^n`, shifted by `shift` modulo 1
/// (Cranley–Patterson): low-discrepancy, and a fresh set for each index range and seed.
fn halton(index: u64, shift: &[f64]) -> Vec<f64> {
    const PRIMES: [u64; 16] = [2, 3, 5, 7, 11, 13, 17, 19, 23, 29, 31, 37, 41, 43, 47, 53];
    shift
        .iter()
        .enumerate()
        .map(|(j, s)| {
            let base = PRIMES[j % PRIMES.len()];
            let (mut i, mut f, mut r) = (index + 1, 1.0, 0.0);
            while i > 0 {
                f /= base as f64;
                r += f * (i % base) as f64;
                i /= base;
            }
            (r + s).fract()
        })
        .collect()
}

/// One round: scores `refinement.candidates` fresh points (round `round` of the seed's
/// sequence: rounds draw disjoint index ranges) by `net`'s ℓ∞ error against `oracle`, and
/// returns the worst (at most [`Refinement::worst`] of those erring by more than half of
/// `threshold`) with [`Refinement::neighbours`] random points around each, as samples of `v`
/// with pointwise slopes and (with `secant`) secant slopes. The points around the worst are
/// scored too (a local search: the largest error is often beside the worst candidate). Adds
/// nothing once the training set holds `current` ≥ [`Refinement::max_samples`] samples.
pub fn refine_round(
    net: &Mlp,
    oracle: &dyn Oracle,
    refinement: &Refinement,
    round: u64,
    threshold: f64,
    current: usize,
    secant: Option<&[f64]>,
) -> Result<Added, NetworkError> {
    let (lower, upper) = oracle.bounds();
    let n = lower.len();
    if upper.len() != n || refinement.radius.len() != n || n != net.input_dim() {
        return Err(NetworkError::Settings {
            message: format!(
                "refinement: bounds of {} and {} entries and radius of {} for a network of {} inputs",
                n,
                upper.len(),
                refinement.radius.len(),
                net.input_dim()
            ),
        });
    }
    let mut rng = ChaCha8Rng::seed_from_u64(refinement.seed);
    let shift: Vec<f64> = (0..n).map(|_| rng.random::<f64>()).collect();
    rng.set_stream(round.wrapping_add(1));
    let start = round.saturating_mul(refinement.candidates as u64);
    let candidates: Vec<Vec<f64>> = (0..refinement.candidates as u64)
        .map(|k| {
            halton(start + k, &shift)
                .iter()
                .enumerate()
                .map(|(j, t)| lower[j] + t * (upper[j] - lower[j]))
                .collect::<Vec<f64>>()
        })
        .filter(|x| oracle.judged(x))
        .collect();
    let scored = oracle.sample(&candidates, SampleSlopes::Values);
    let mut report = RoundReport {
        scored: scored.len(),
        max_error: 0.0,
        at: Vec::new(),
        above: 0,
        added: 0,
    };
    let empty = || Dataset {
        n_in: n,
        n_out: net.output_dim(),
        jacobians: Some(Vec::new()),
        ..Dataset::default()
    };
    if scored.is_empty() {
        return Ok(Added {
            pointwise: empty(),
            secant: secant.map(|_| empty()),
            report,
        });
    }
    let errors = pointwise_errors(net, &scored)?.value;
    // Largest error first, then the lower index: the same points on every run.
    let mut ranked: Vec<usize> = (0..errors.len()).collect();
    ranked.sort_by(|&a, &b| errors[b].total_cmp(&errors[a]).then(a.cmp(&b)));
    report.max_error = errors[ranked[0]];
    report.at = scored.input(ranked[0]).to_vec();
    report.above = errors.iter().filter(|&&e| e > threshold).count();
    let room = refinement.max_samples.saturating_sub(current);
    let per_point = 1 + refinement.neighbours;
    let take = refinement.worst.min(room / per_point);
    let (mut worst, mut around) = (Vec::new(), Vec::new());
    for &s in ranked
        .iter()
        .take(take)
        .take_while(|&&s| errors[s] > 0.5 * threshold)
    {
        let x = scored.input(s);
        worst.push(x.to_vec());
        for _ in 0..refinement.neighbours {
            around.push(
                (0..n)
                    .map(|j| {
                        let r = refinement.radius[j];
                        (x[j] + r * rng.random_range(-1.0..=1.0)).clamp(lower[j], upper[j])
                    })
                    .collect::<Vec<f64>>(),
            );
        }
    }
    let mut pointwise = oracle.sample(&worst, SampleSlopes::Pointwise);
    let neighbours = oracle.sample(&around, SampleSlopes::Pointwise);
    if !neighbours.is_empty() {
        for (s, &e) in pointwise_errors(net, &neighbours)?.value.iter().enumerate() {
            // Trained on wherever they fall, judged only in `C ∩ S` (inside an obstacle `v`
            // may grow without bound).
            if !oracle.judged(neighbours.input(s)) {
                continue;
            }
            report.scored += 1;
            report.above += usize::from(e > threshold);
            if e > report.max_error {
                report.max_error = e;
                report.at = neighbours.input(s).to_vec();
            }
        }
    }
    if pointwise.is_empty() {
        pointwise = empty();
    }
    if !neighbours.is_empty() {
        pointwise.append(neighbours)?;
    }
    let points: Vec<Vec<f64>> = worst.into_iter().chain(around).collect();
    let secant = secant.map(|h| oracle.sample(&points, SampleSlopes::Secant(h)));
    report.added = pointwise.len();
    Ok(Added {
        pointwise,
        secant,
        report,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `v(x) = 5 max(0, 0.05 − ‖x − (0.7, 0.3)‖∞)`: a narrow spike on `[0, 1]²` that a grid of
    /// spacing 0.25 never sees; the feasible set is all of it, `C ∩ S` the part with
    /// `x₁ ≥ 0.1`.
    struct Spike;

    fn spike(x: &[f64]) -> f64 {
        let d = (x[0] - 0.7).abs().max((x[1] - 0.3).abs());
        5.0 * (0.05 - d).max(0.0)
    }

    impl Oracle for Spike {
        fn bounds(&self) -> (Vec<f64>, Vec<f64>) {
            (vec![0.0, 0.0], vec![1.0, 1.0])
        }
        fn judged(&self, x: &[f64]) -> bool {
            x[0] >= 0.1
        }
        fn sample(&self, points: &[Vec<f64>], _slopes: SampleSlopes) -> Dataset {
            Dataset {
                n_in: 2,
                n_out: 1,
                inputs: points.iter().flatten().copied().collect(),
                targets: points.iter().map(|x| spike(x)).collect(),
                jacobians: Some(vec![0.0; 2 * points.len()]),
                weights: None,
            }
        }
    }

    /// The zero network: its error is `v` itself.
    fn zero() -> Mlp {
        let mut net = Mlp::random(&[2, 4, 1], 1);
        for l in &mut net.layers {
            l.weight
                .iter_mut()
                .chain(&mut l.bias)
                .for_each(|w| *w = 0.0);
        }
        net
    }

    fn refinement(max_samples: usize) -> Refinement {
        Refinement {
            candidates: 4096,
            worst: 16,
            neighbours: 4,
            radius: vec![0.02, 0.02],
            max_samples,
            seed: 3,
        }
    }

    #[test]
    fn a_round_adds_points_where_the_error_is_largest() {
        let r = refinement(1_000_000);
        let added =
            refine_round(&zero(), &Spike, &r, 0, 0.1, 100, Some(&[0.01, 0.01])).expect("refines");
        let rep = &added.report;
        // The candidates of C ∩ S and the 16 × 4 points around the worst.
        assert!(rep.scored > 3000 && rep.scored < 4096 + 64, "{rep:?}");
        // The spike is 0.01 of the square: about 37 candidates fall on it, some above 0.1.
        assert!(rep.max_error > 0.15 && rep.above > 0, "{rep:?}");
        assert!((rep.at[0] - 0.7).abs() < 0.05 && (rep.at[1] - 0.3).abs() < 0.05);
        assert_eq!(rep.added, 16 * 5);
        // Every added point lies within a radius of the spike: none is spent elsewhere.
        for x in added.pointwise.inputs.chunks_exact(2) {
            let d = (x[0] - 0.7).abs().max((x[1] - 0.3).abs());
            assert!(d <= 0.05 + 0.02 + 1e-12, "{x:?} is off the spike");
        }
        assert!(added.pointwise.targets.iter().sum::<f64>() > 16.0 * 0.05);
        assert_eq!(added.secant.as_ref().map(Dataset::len), Some(16 * 5));
        // The next round draws other candidates.
        let next = refine_round(&zero(), &Spike, &r, 1, 0.1, 180, None).expect("refines");
        assert_ne!(next.report.at, rep.at);
        assert!(next.secant.is_none());
    }

    #[test]
    fn a_round_adds_nothing_where_the_network_is_accurate_or_the_set_is_full() {
        // Only points erring by more than half the threshold are added.
        let added = refine_round(&zero(), &Spike, &refinement(1_000_000), 0, 1.0, 0, None)
            .expect("refines");
        assert_eq!(added.report.added, 0);
        assert_eq!(added.report.above, 0);
        // The set's bound: room for 2 points with their neighbours (5 each), no more.
        let added =
            refine_round(&zero(), &Spike, &refinement(110), 0, 0.1, 100, None).expect("refines");
        assert_eq!(added.report.added, 10);
        let full =
            refine_round(&zero(), &Spike, &refinement(100), 0, 0.1, 100, None).expect("refines");
        assert_eq!(full.report.added, 0);
        assert!(
            full.report.max_error > 0.15,
            "still scored: {:?}",
            full.report
        );
    }
}

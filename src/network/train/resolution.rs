//! How finely the training grid resolves `v`: the grid's own multilinear interpolant measured
//! at the validation points ([`grid_resolution`], [`Resolution`]).
//! May import: the trainer's [`Dataset`]; nothing else.
//!
//! The trainer only ever sees `v` at the grid's points. Where `v` bends or steepens between
//! them by more than the accuracy target, the samples do not say what `v` does there, and the
//! validation points (the cells' centres) measure what the network happened to do. The
//! multilinear interpolant of the grid's own samples is a cheap yardstick: on the unicycle
//! (25×19×27 points, `v` up to 76 per unit near the obstacle) it misses by 1.41 at the
//! centres, 0.57 on a grid twice as fine, against a target of 0.1 (docs/networks.md). A
//! network can do better than the interpolant only by luck of its shape, so a target below
//! this figure asks for a finer grid first.

use std::collections::HashMap;

use serde::{Deserialize, Serialize};

use super::Dataset;

/// What [`grid_resolution`] found.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Resolution {
    /// Validation points inside a cell whose corners all have samples.
    pub points: usize,
    /// Largest `‖interpolant − v‖∞` over them (0 if none).
    pub max: f64,
    /// Where it is attained (empty if none).
    pub at: Vec<f64>,
    /// How many of them miss by more than `threshold`.
    pub above: usize,
    /// The threshold counted against (the target's `linf`, or +∞).
    pub threshold: f64,
}

/// The multilinear interpolant of `training`'s samples on the grid of `counts[i]` points per
/// axis over `[lower, upper]` (points off the grid are ignored), compared with `validation`'s
/// targets at each of its points whose cell has a sample at every corner (cells touching an
/// infeasible point are left out).
pub fn grid_resolution(
    lower: &[f64],
    upper: &[f64],
    counts: &[usize],
    training: &Dataset,
    validation: &Dataset,
    threshold: f64,
) -> Resolution {
    let n = counts.len();
    let mut out = Resolution {
        points: 0,
        max: 0.0,
        at: Vec::new(),
        above: 0,
        threshold,
    };
    if n == 0
        || n != training.n_in
        || n != validation.n_in
        || training.n_out != validation.n_out
        || counts.iter().any(|&k| k < 2)
    {
        return out;
    }
    let spacing: Vec<f64> = (0..n)
        .map(|i| (upper[i] - lower[i]) / (counts[i] - 1) as f64)
        .collect();
    // Grid index of a training sample that sits on the lattice (to 1e-6 of a spacing).
    let on_grid = |x: &[f64]| -> Option<Vec<usize>> {
        (0..n)
            .map(|i| {
                let t = (x[i] - lower[i]) / spacing[i];
                let j = t.round();
                ((t - j).abs() < 1e-6 && j >= 0.0 && (j as usize) < counts[i]).then_some(j as usize)
            })
            .collect()
    };
    let index: HashMap<Vec<usize>, usize> = (0..training.len())
        .filter_map(|s| on_grid(training.input(s)).map(|k| (k, s)))
        .collect();
    let m = validation.n_out;
    'points: for s in 0..validation.len() {
        let x = validation.input(s);
        let mut cell = vec![0usize; n];
        let mut frac = vec![0.0; n];
        for i in 0..n {
            let t = (x[i] - lower[i]) / spacing[i];
            if !(t >= 0.0 && t <= (counts[i] - 1) as f64) {
                continue 'points;
            }
            cell[i] = (t.floor() as usize).min(counts[i] - 2);
            frac[i] = t - cell[i] as f64;
        }
        let mut value = vec![0.0; m];
        for corner in 0..1usize << n {
            let mut weight = 1.0;
            let key: Vec<usize> = (0..n)
                .map(|i| {
                    let up = corner >> i & 1 == 1;
                    weight *= if up { frac[i] } else { 1.0 - frac[i] };
                    cell[i] + usize::from(up)
                })
                .collect();
            let Some(&k) = index.get(&key) else {
                continue 'points;
            };
            for (v, t) in value.iter_mut().zip(training.target(k)) {
                *v += weight * t;
            }
        }
        let miss = value
            .iter()
            .zip(validation.target(s))
            .fold(0.0f64, |a, (v, t)| a.max((v - t).abs()));
        out.points += 1;
        if miss > threshold {
            out.above += 1;
        }
        if miss > out.max || out.at.is_empty() {
            out.max = miss;
            out.at = x.to_vec();
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn data(points: &[[f64; 2]], f: impl Fn(f64, f64) -> f64) -> Dataset {
        Dataset {
            n_in: 2,
            n_out: 1,
            inputs: points.iter().flatten().copied().collect(),
            targets: points.iter().map(|p| f(p[0], p[1])).collect(),
            ..Dataset::default()
        }
    }

    fn grid(k: usize) -> Vec<[f64; 2]> {
        let h = 1.0 / (k - 1) as f64;
        (0..k * k)
            .map(|s| [(s % k) as f64 * h, (s / k) as f64 * h])
            .collect()
    }

    fn centres(k: usize) -> Vec<[f64; 2]> {
        let h = 1.0 / (k - 1) as f64;
        (0..(k - 1) * (k - 1))
            .map(|s| {
                [
                    (s % (k - 1)) as f64 * h + h / 2.0,
                    (s / (k - 1)) as f64 * h + h / 2.0,
                ]
            })
            .collect()
    }

    #[test]
    fn bilinear_data_are_resolved_exactly_and_a_kink_is_not() {
        let bilinear = |x: f64, y: f64| 3.0 * x - 2.0 * y + 5.0 * x * y;
        let r = grid_resolution(
            &[0.0, 0.0],
            &[1.0, 1.0],
            &[5, 5],
            &data(&grid(5), bilinear),
            &data(&centres(5), bilinear),
            0.01,
        );
        assert_eq!(r.points, 16);
        assert!(r.max < 1e-12, "{r:?}");
        assert_eq!(r.above, 0);
        // A kink of slope jump 10 between grid lines x = 0.25 and 0.5: the interpolant misses
        // it at the centre x = 0.375 by 10 · 0.125 / 2.
        let kink = |x: f64, _: f64| 10.0 * (x - 0.375).max(0.0);
        let r = grid_resolution(
            &[0.0, 0.0],
            &[1.0, 1.0],
            &[5, 5],
            &data(&grid(5), kink),
            &data(&centres(5), kink),
            0.1,
        );
        assert!((r.max - 0.625).abs() < 1e-12, "{r:?}");
        assert!((r.at[0] - 0.375).abs() < 1e-12);
        assert_eq!(r.above, 4, "the four centres on the kink's line");
    }

    #[test]
    fn cells_with_a_missing_corner_are_left_out() {
        let f = |x: f64, y: f64| x + y;
        let mut points = grid(3);
        points.remove(4); // the centre point (0.5, 0.5): every cell has it as a corner
        let r = grid_resolution(
            &[0.0, 0.0],
            &[1.0, 1.0],
            &[3, 3],
            &data(&points, f),
            &data(&centres(3), f),
            0.1,
        );
        assert_eq!(r.points, 0);
        assert!(r.at.is_empty());
    }
}

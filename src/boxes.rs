//! Boxes (hyper-rectangles) `[x̲, x̄] = {x : x̲ ≤ x ≤ x̄}`: the sets that initial conditions,
//! the region `C`, goal sets and reachable-set bounds are made of, and [`BoxError`].
//! Imports nothing of the crate.

use serde::{Deserialize, Serialize};

/// A non-empty box `[lower, upper]` in ℝⁿ.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct IntervalBox {
    /// `x̲`.
    pub lower: Vec<f64>,
    /// `x̄`.
    pub upper: Vec<f64>,
}

/// Why [`IntervalBox::new`] rejected its corners; the message names the coordinate.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BoxError {
    /// `lower` and `upper` have different lengths.
    #[error("lower has {lower_len} entries but upper has {upper_len}")]
    LengthMismatch {
        /// Entries of `lower`.
        lower_len: usize,
        /// Entries of `upper`.
        upper_len: usize,
    },
    /// Both corners are empty.
    #[error("a box needs at least one coordinate")]
    NoCoordinates,
    /// A bound is NaN or infinite.
    #[error("coordinate {coord}: bounds must be finite, found [{lower}, {upper}]")]
    NonFinite {
        /// The coordinate.
        coord: usize,
        /// Its lower bound.
        lower: f64,
        /// Its upper bound.
        upper: f64,
    },
    /// `lower > upper` on a coordinate.
    #[error(
        "coordinate {coord}: inverted bounds, lower {lower} > upper {upper} (the box is empty)"
    )]
    Inverted {
        /// The coordinate.
        coord: usize,
        /// Its lower bound.
        lower: f64,
        /// Its upper bound.
        upper: f64,
    },
}

/// The most cells per axis, at most `most`, that keep a grid over `n` axes within `cells`
/// cells (`kⁿ ≤ cells`); 1 where even two per axis would pass it.
pub fn per_axis_within(n: usize, cells: usize, most: usize) -> usize {
    let fits = |k: usize| {
        (u32::try_from(n).ok())
            .and_then(|n| k.checked_pow(n))
            .is_some_and(|c| c <= cells)
    };
    (2..=most).rev().find(|&k| fits(k)).unwrap_or(1)
}

/// The points of an equispaced grid with `counts[i]` points along axis i, both ends included,
/// axis 0 fastest.
pub fn grid_points(region: &IntervalBox, counts: &[usize]) -> Vec<Vec<f64>> {
    let n = region.dim();
    let total: usize = counts.iter().product();
    (0..total)
        .map(|mut k| {
            (0..n)
                .map(|i| {
                    let j = k % counts[i];
                    k /= counts[i];
                    lattice_coordinate(region, i, j, counts[i])
                })
                .collect()
        })
        .collect()
}

/// Coordinate `i` of point `j` of `count` equispaced points over the region's axis `i`: the
/// ends exact, interior points by interpolation.
pub(crate) fn lattice_coordinate(region: &IntervalBox, i: usize, j: usize, count: usize) -> f64 {
    if j + 1 == count {
        region.upper[i]
    } else {
        let s = j as f64 / (count.max(2) - 1) as f64;
        region.lower[i] + s * (region.upper[i] - region.lower[i])
    }
}

impl IntervalBox {
    /// A box, checked: equal lengths, finite corners, `lower ≤ upper` on every axis.
    /// The error says which axis is wrong and how.
    pub fn new(lower: Vec<f64>, upper: Vec<f64>) -> Result<IntervalBox, BoxError> {
        if lower.len() != upper.len() {
            return Err(BoxError::LengthMismatch {
                lower_len: lower.len(),
                upper_len: upper.len(),
            });
        }
        if lower.is_empty() {
            return Err(BoxError::NoCoordinates);
        }
        for (coord, (&l, &u)) in lower.iter().zip(&upper).enumerate() {
            if !l.is_finite() || !u.is_finite() {
                return Err(BoxError::NonFinite {
                    coord,
                    lower: l,
                    upper: u,
                });
            }
            if l > u {
                return Err(BoxError::Inverted {
                    coord,
                    lower: l,
                    upper: u,
                });
            }
        }
        Ok(IntervalBox { lower, upper })
    }

    /// Dimension `n`.
    pub fn dim(&self) -> usize {
        self.lower.len()
    }

    /// Centre `(x̲ + x̄)/2`.
    pub fn center(&self) -> Vec<f64> {
        self.lower
            .iter()
            .zip(&self.upper)
            .map(|(l, u)| 0.5 * (l + u))
            .collect()
    }

    /// The `2ⁿ` corners, corner `k` taking `x̄ᵢ` where bit `i` of `k` is set (exact: no
    /// arithmetic on the coordinates).
    pub fn corners(&self) -> impl Iterator<Item = Vec<f64>> + '_ {
        let n = self.dim();
        (0..1usize << n).map(move |mask| {
            (0..n)
                .map(|i| {
                    if mask >> i & 1 == 1 {
                        self.upper[i]
                    } else {
                        self.lower[i]
                    }
                })
                .collect()
        })
    }

    /// Widths `x̄ − x̲`.
    pub fn widths(&self) -> Vec<f64> {
        self.lower
            .iter()
            .zip(&self.upper)
            .map(|(l, u)| u - l)
            .collect()
    }

    /// Volume (area in 2-D).
    pub fn volume(&self) -> f64 {
        self.widths().iter().product()
    }

    /// `x ∈ [x̲, x̄]`.
    pub fn contains(&self, x: &[f64]) -> bool {
        x.iter()
            .zip(self.lower.iter().zip(&self.upper))
            .all(|(v, (l, u))| l <= v && v <= u)
    }

    /// `self ⊆ other`.
    pub fn is_subset_of(&self, other: &IntervalBox) -> bool {
        (0..self.dim()).all(|i| other.lower[i] <= self.lower[i] && self.upper[i] <= other.upper[i])
    }

    /// The smallest box holding both.
    pub fn hull(&self, other: &IntervalBox) -> IntervalBox {
        let (lower, upper) = (0..self.dim())
            .map(|i| {
                (
                    self.lower[i].min(other.lower[i]),
                    self.upper[i].max(other.upper[i]),
                )
            })
            .unzip();
        IntervalBox { lower, upper }
    }

    /// `self ∩ other`, or `None` when they are disjoint.
    pub fn intersection(&self, other: &IntervalBox) -> Option<IntervalBox> {
        let lower: Vec<f64> = (0..self.dim())
            .map(|i| self.lower[i].max(other.lower[i]))
            .collect();
        let upper: Vec<f64> = (0..self.dim())
            .map(|i| self.upper[i].min(other.upper[i]))
            .collect();
        lower
            .iter()
            .zip(&upper)
            .all(|(l, u)| l <= u)
            .then_some(IntervalBox { lower, upper })
    }

    /// The point `x̲ + s ⊙ (x̄ − x̲)` for `s ∈ [0, 1]ⁿ` (for sampling).
    pub fn point_at(&self, s: &[f64]) -> Vec<f64> {
        (0..self.dim())
            .map(|i| self.lower[i] + s[i] * (self.upper[i] - self.lower[i]))
            .collect()
    }

    /// The box cut into `counts[i]` equal cells along axis i, axis 0 fastest. The caller
    /// bounds the number of cells (`Π counts[i]`; checked against overflow here).
    pub fn partition(&self, counts: &[usize]) -> Vec<IntervalBox> {
        let total = counts
            .iter()
            .try_fold(1usize, |a, &k| a.checked_mul(k))
            .expect("partition: the number of cells overflows (callers check their limits)");
        (0..total).map(|k| self.partition_cell(counts, k)).collect()
    }

    /// Cell `k` (axis 0 fastest) of [`IntervalBox::partition`], without making the others.
    pub fn partition_cell(&self, counts: &[usize], mut k: usize) -> IntervalBox {
        let n = self.dim();
        let mut lower = vec![0.0; n];
        let mut upper = vec![0.0; n];
        for i in 0..n {
            let j = k % counts[i];
            k /= counts[i];
            let w = (self.upper[i] - self.lower[i]) / counts[i] as f64;
            lower[i] = self.lower[i] + j as f64 * w;
            // The last cell ends exactly at the box's edge, so the cells cover it.
            upper[i] = if j + 1 == counts[i] {
                self.upper[i]
            } else {
                self.lower[i] + (j + 1) as f64 * w
            };
        }
        IntervalBox { lower, upper }
    }

    /// The two halves of the box cut across its widest axis.
    pub fn bisect(&self) -> (IntervalBox, IntervalBox) {
        let widths = self.widths();
        let axis = (0..self.dim())
            .max_by(|&a, &b| widths[a].total_cmp(&widths[b]))
            .unwrap_or(0);
        self.bisect_along(axis)
    }

    /// The two halves across `axis`, at its midpoint.
    pub fn bisect_along(&self, axis: usize) -> (IntervalBox, IntervalBox) {
        let mid = 0.5 * (self.lower[axis] + self.upper[axis]);
        let mut left = self.clone();
        let mut right = self.clone();
        left.upper[axis] = mid;
        right.lower[axis] = mid;
        (left, right)
    }
}

/// Formats a point compactly for messages: `(1.0000, -2.5000)`; values that print as zero
/// print without a sign.
pub fn fmt_point(x: &[f64]) -> String {
    let parts: Vec<String> = x
        .iter()
        .map(|&v| format!("{:.4}", if v.abs() < 5e-5 { 0.0 } else { v }))
        .collect();
    format!("({})", parts.join(", "))
}

/// Formats numbers of any magnitude for messages, to four significant digits or so:
/// `(0.8400, 2.640, 1846, 3.000e-7)`.
pub fn fmt_numbers(x: &[f64]) -> String {
    let parts: Vec<String> = (x.iter())
        .map(|&v| match v.abs() {
            a if a < 5e-13 => "0".to_string(),
            a if (1e-3..1e4).contains(&a) => {
                let digits = 3 - a.log10().floor().clamp(-3.0, 3.0) as i32;
                format!("{v:.*}", digits as usize)
            }
            _ => format!("{v:.3e}"),
        })
        .collect();
    format!("({})", parts.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn per_axis_counts_keep_the_grid_within_its_cells() {
        assert_eq!(per_axis_within(2, 4096, 64), 64);
        assert_eq!(per_axis_within(3, 4096, 64), 16);
        assert_eq!(per_axis_within(5, 4096, 64), 5);
        assert_eq!(per_axis_within(2, 64, 8), 8);
        assert_eq!(per_axis_within(7, 64, 64), 1);
        assert_eq!(per_axis_within(0, 1, 30), 30);
        // No overflow where `kⁿ` would pass `usize`.
        assert_eq!(per_axis_within(200, usize::MAX, 3), 1);
    }

    #[test]
    fn grid_points_run_from_corner_to_corner_axis_0_fastest() {
        let b = IntervalBox::new(vec![0.0, -1.0], vec![1.0, 1.0]).unwrap();
        let nodes = grid_points(&b, &[3, 3]);
        assert_eq!(nodes.len(), 9);
        assert_eq!(nodes[0], vec![0.0, -1.0]);
        assert_eq!(nodes[1], vec![0.5, -1.0]);
        assert_eq!(nodes[3], vec![0.0, 0.0]);
        assert_eq!(nodes[8], vec![1.0, 1.0]);
    }

    #[test]
    fn hull_holds_both_and_nothing_wider() {
        let a = IntervalBox::new(vec![0.0, -2.0], vec![1.0, 0.5]).unwrap();
        let b = IntervalBox::new(vec![-1.0, -1.0], vec![0.5, 3.0]).unwrap();
        let h = a.hull(&b);
        assert_eq!((h.lower, h.upper), (vec![-1.0, -2.0], vec![1.0, 3.0]));
    }

    #[test]
    fn rejects_inverted_empty_and_nan_boxes() {
        let err = IntervalBox::new(vec![1.0], vec![0.0]).unwrap_err();
        assert_eq!(
            err.to_string(),
            "coordinate 0: inverted bounds, lower 1 > upper 0 (the box is empty)"
        );
        assert!(IntervalBox::new(vec![], vec![]).is_err());
        assert!(IntervalBox::new(vec![f64::NAN], vec![1.0])
            .unwrap_err()
            .to_string()
            .contains("finite"));
        assert_eq!(
            IntervalBox::new(vec![0.0, 0.0], vec![1.0]).unwrap_err(),
            BoxError::LengthMismatch {
                lower_len: 2,
                upper_len: 1
            }
        );
    }

    #[test]
    fn partition_covers_the_box_exactly() {
        let b = IntervalBox::new(vec![-1.0, 0.0], vec![2.0, 0.3]).unwrap();
        let cells = b.partition(&[3, 7]);
        assert_eq!(cells.len(), 21);
        let area: f64 = cells.iter().map(|c| c.volume()).sum();
        assert!((area - b.volume()).abs() < 1e-12);
        assert!(cells.iter().all(|c| c.is_subset_of(&b)));
        assert_eq!(cells[20].upper, b.upper);
        let (l, r) = b.bisect();
        assert_eq!(l.upper[0], 0.5);
        assert_eq!(r.lower[0], 0.5);
    }
    /// Numbers of every magnitude keep about four significant digits; zero is "0".
    #[test]
    fn numbers_print_to_four_digits_whatever_their_size() {
        assert_eq!(
            fmt_numbers(&[
                5.551115123125783e-17,
                0.8400000000000001,
                2.6399999999999997
            ]),
            "(0, 0.8400, 2.640)"
        );
        assert_eq!(
            fmt_numbers(&[1845.5, -0.43972, 3e-7, 2.5e6]),
            "(1846, -0.4397, 3.000e-7, 2.500e6)"
        );
        assert_eq!(fmt_point(&[1.0, -2.5, -1e-9]), "(1.0000, -2.5000, 0.0000)");
    }
}

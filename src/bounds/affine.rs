//! The output of a bounds computation: [`AffineBounds`] of one box, [`AffineBoundsBatch`] of
//! many (flat, reusable), and `OutRow`, one box's mutable view. Imports nothing of the crate.

/// Affine and interval bounds of a network `N : ℝⁿ → ℝᵐ` over one box.
///
/// For every `x` in the box (exact real arithmetic, see [`crate::bounds`]' error model):
/// `a_lower·x + b_lower ≤ N(x) ≤ a_upper·x + b_upper` and `lower ≤ N(x) ≤ upper`.
#[derive(Clone, Debug, PartialEq)]
pub struct AffineBounds {
    /// `C̲`, `m × n` row-major.
    pub a_lower: Vec<f64>,
    /// `d̲`, `m` entries.
    pub b_lower: Vec<f64>,
    /// `C̄`, `m × n` row-major.
    pub a_upper: Vec<f64>,
    /// `d̄`, `m` entries.
    pub b_upper: Vec<f64>,
    /// Concrete lower bounds on `N` over the box, `m` entries.
    pub lower: Vec<f64>,
    /// Concrete upper bounds on `N` over the box, `m` entries.
    pub upper: Vec<f64>,
    /// Input dimension `n`.
    pub n_in: usize,
    /// Output dimension `m`.
    pub n_out: usize,
}

impl AffineBounds {
    /// The trivially sound bounds `C = 0`, `d = ∓∞`.
    pub fn unbounded(n_in: usize, n_out: usize) -> AffineBounds {
        AffineBounds {
            a_lower: vec![0.0; n_out * n_in],
            b_lower: vec![f64::NEG_INFINITY; n_out],
            a_upper: vec![0.0; n_out * n_in],
            b_upper: vec![f64::INFINITY; n_out],
            lower: vec![f64::NEG_INFINITY; n_out],
            upper: vec![f64::INFINITY; n_out],
            n_in,
            n_out,
        }
    }

    /// Row `i` of `C̲`.
    pub fn a_lower_row(&self, i: usize) -> &[f64] {
        &self.a_lower[i * self.n_in..(i + 1) * self.n_in]
    }

    /// Row `i` of `C̄`.
    pub fn a_upper_row(&self, i: usize) -> &[f64] {
        &self.a_upper[i * self.n_in..(i + 1) * self.n_in]
    }
}

/// [`AffineBounds`] for a batch of boxes, flat and box-major, reusable across calls
/// (see [`super::network_bounds_batch_into`]).
///
/// Box `k`'s `C̲` is `a_lower[k·m·n .. (k+1)·m·n]` (row-major `m × n`), its `d̲` is
/// `b_lower[k·m .. (k+1)·m]`, and likewise for the other fields.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AffineBoundsBatch {
    /// `C̲` of every box, `len × m × n`.
    pub a_lower: Vec<f64>,
    /// `d̲` of every box, `len × m`.
    pub b_lower: Vec<f64>,
    /// `C̄` of every box, `len × m × n`.
    pub a_upper: Vec<f64>,
    /// `d̄` of every box, `len × m`.
    pub b_upper: Vec<f64>,
    /// Concrete lower bounds, `len × m`.
    pub lower: Vec<f64>,
    /// Concrete upper bounds, `len × m`.
    pub upper: Vec<f64>,
    /// Input dimension `n`.
    pub n_in: usize,
    /// Output dimension `m`.
    pub n_out: usize,
    /// Number of boxes.
    pub len: usize,
}

impl AffineBoundsBatch {
    /// An empty batch (no allocation until the first use).
    pub fn new() -> AffineBoundsBatch {
        AffineBoundsBatch::default()
    }

    /// Number of boxes.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether the batch holds no boxes.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// A copy of box `k`'s bounds, or `None` past the end.
    pub fn get(&self, k: usize) -> Option<AffineBounds> {
        if k >= self.len {
            return None;
        }
        let (mn, m) = (self.n_out * self.n_in, self.n_out);
        Some(AffineBounds {
            a_lower: self.a_lower[k * mn..(k + 1) * mn].to_vec(),
            b_lower: self.b_lower[k * m..(k + 1) * m].to_vec(),
            a_upper: self.a_upper[k * mn..(k + 1) * mn].to_vec(),
            b_upper: self.b_upper[k * m..(k + 1) * m].to_vec(),
            lower: self.lower[k * m..(k + 1) * m].to_vec(),
            upper: self.upper[k * m..(k + 1) * m].to_vec(),
            n_in: self.n_in,
            n_out: self.n_out,
        })
    }

    /// Every box's bounds as separate [`AffineBounds`].
    pub fn to_vec(&self) -> Vec<AffineBounds> {
        (0..self.len).filter_map(|k| self.get(k)).collect()
    }

    /// Resizes for `len` boxes, keeping allocations; contents are overwritten by the caller.
    pub(crate) fn reset(&mut self, n_in: usize, n_out: usize, len: usize) {
        self.n_in = n_in;
        self.n_out = n_out;
        self.len = len;
        for v in [&mut self.a_lower, &mut self.a_upper] {
            v.clear();
            v.resize(len * n_out * n_in, 0.0);
        }
        for v in [
            &mut self.b_lower,
            &mut self.b_upper,
            &mut self.lower,
            &mut self.upper,
        ] {
            v.clear();
            v.resize(len * n_out, 0.0);
        }
    }

    /// One [`OutRow`] view per box.
    pub(crate) fn rows_mut(&mut self) -> Vec<OutRow<'_>> {
        let (mn, m) = ((self.n_out * self.n_in).max(1), self.n_out.max(1));
        let n_in = self.n_in;
        self.a_lower
            .chunks_mut(mn)
            .zip(self.b_lower.chunks_mut(m))
            .zip(self.a_upper.chunks_mut(mn))
            .zip(self.b_upper.chunks_mut(m))
            .zip(self.lower.chunks_mut(m))
            .zip(self.upper.chunks_mut(m))
            .map(
                |(((((a_lower, b_lower), a_upper), b_upper), lower), upper)| OutRow {
                    a_lower,
                    b_lower,
                    a_upper,
                    b_upper,
                    lower,
                    upper,
                    n_in,
                },
            )
            .collect()
    }
}

/// Mutable view of one box's output inside an [`AffineBoundsBatch`].
pub(crate) struct OutRow<'a> {
    pub(crate) a_lower: &'a mut [f64],
    pub(crate) b_lower: &'a mut [f64],
    pub(crate) a_upper: &'a mut [f64],
    pub(crate) b_upper: &'a mut [f64],
    pub(crate) lower: &'a mut [f64],
    pub(crate) upper: &'a mut [f64],
    pub(crate) n_in: usize,
}

impl OutRow<'_> {
    /// Replaces every output row with a non-finite coefficient or bound (overflow, NaN) by the
    /// trivially sound `(0, ∓∞)`. NaN never compares, so `is_finite` catches it.
    pub(crate) fn sanitize(&mut self) {
        let n = self.n_in;
        for i in 0..self.lower.len() {
            let a = &mut self.a_lower[i * n..(i + 1) * n];
            if !(self.b_lower[i].is_finite()
                && self.lower[i].is_finite()
                && a.iter().all(|v| v.is_finite()))
            {
                a.fill(0.0);
                self.b_lower[i] = f64::NEG_INFINITY;
                self.lower[i] = f64::NEG_INFINITY;
            }
            let a = &mut self.a_upper[i * n..(i + 1) * n];
            if !(self.b_upper[i].is_finite()
                && self.upper[i].is_finite()
                && a.iter().all(|v| v.is_finite()))
            {
                a.fill(0.0);
                self.b_upper[i] = f64::INFINITY;
                self.upper[i] = f64::INFINITY;
            }
        }
    }

    /// Sets every row to `(0, ∓∞)`.
    pub(crate) fn set_unbounded(&mut self) {
        self.a_lower.fill(0.0);
        self.a_upper.fill(0.0);
        self.b_lower.fill(f64::NEG_INFINITY);
        self.lower.fill(f64::NEG_INFINITY);
        self.b_upper.fill(f64::INFINITY);
        self.upper.fill(f64::INFINITY);
    }
}

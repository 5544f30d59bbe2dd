//! Live neurons in backward passes: gathering the weights they touch, and relaxing one row of
//! `Λ` over them (shared by [`super::crown`] and [`super::forward_backward`]).
//!
//! A neuron with `u ≤ 0` has the zero relaxation, so it adds nothing to a backward pass; the
//! passes keep the live neurons' lines contiguous ([`LiveLines`]) so that the row relaxation
//! runs without indirection or branches.

/// Appends the given rows of the row-major `w` (`n_in` columns), restricted to `columns` (all
/// when `None`), to `out`.
pub(crate) fn gather_columns(
    w: &[f64],
    n_in: usize,
    rows: impl Iterator<Item = usize>,
    columns: Option<&[usize]>,
    out: &mut Vec<f64>,
) {
    for i in rows {
        let row = &w[i * n_in..(i + 1) * n_in];
        match columns {
            Some(cols) => out.extend(cols.iter().map(|&c| row[c])),
            None => out.extend_from_slice(row),
        }
    }
}

/// A layer's ReLU lines `s̲, s̄, t̄`, bias and rounding magnitude `w` on its live neurons, in
/// `live` order.
#[derive(Default)]
pub(crate) struct LiveLines {
    s_lo: Vec<f64>,
    s_up: Vec<f64>,
    t_up: Vec<f64>,
    bias: Vec<f64>,
    wmag: Vec<f64>,
}

/// What one entry `Λ_m` adds to a row: `(Λ_m s_m, upper intercept, lower intercept,
/// magnitude)`. Slope: the upper line where this side needs an upper bound of `Λ_m a_m`
/// (`Λ ≥ 0` on the upper side, `Λ < 0` on the lower); intercept: the upper side uses the upper
/// line's `t̄` where `Λ ≥ 0`, the lower side where `Λ < 0` (for shared rows `s̲ = s̄`, so both
/// sides hold with one `Λ∘s`).
#[inline(always)]
fn relax_entry(lam: f64, [s_lo, s_up, t_up, bias, wmag]: [f64; 5], upper_side: bool) -> [f64; 4] {
    let pos = lam >= 0.0;
    let ls = lam * if pos == upper_side { s_up } else { s_lo };
    let lt = lam * t_up;
    let lb = ls * bias;
    [
        ls,
        lb + if pos { lt } else { 0.0 },
        lb + if pos { 0.0 } else { lt },
        ls.abs() * wmag + lt.abs(),
    ]
}

impl LiveLines {
    /// Gathers the lines (indexed by neuron), the layer's bias and `wmag(neuron)` over `live`.
    pub(crate) fn gather(
        &mut self,
        live: &[usize],
        (s_lo, s_up, t_up): (&[f64], &[f64], &[f64]),
        bias: &[f64],
        wmag: impl Fn(usize) -> f64,
    ) {
        for (dst, src) in [
            (&mut self.s_lo, s_lo),
            (&mut self.s_up, s_up),
            (&mut self.t_up, t_up),
            (&mut self.bias, bias),
        ] {
            dst.clear();
            dst.extend(live.iter().map(|&m| src[m]));
        }
        self.wmag.clear();
        self.wmag.extend(live.iter().map(|&m| wmag(m)));
    }

    /// The lines of live neurons `at..at + N`, as arrays (one bounds check each, not one per
    /// entry).
    fn lanes<const N: usize>(&self, at: usize) -> [[f64; 5]; N] {
        let pick = |v: &[f64]| -> [f64; N] { v[at..at + N].try_into().unwrap() };
        let [s_lo, s_up, t_up, bias, wmag] = [
            pick(&self.s_lo),
            pick(&self.s_up),
            pick(&self.t_up),
            pick(&self.bias),
            pick(&self.wmag),
        ];
        std::array::from_fn(|q| [s_lo[q], s_up[q], t_up[q], bias[q], wmag[q]])
    }

    /// One row of `Λ∘s` (`lam` over the live neurons) into `out`, and the row's upper and
    /// lower intercept sums and rounding magnitude `(Σ_upper, Σ_lower, E)` ([`relax_entry`]).
    /// Four partial sums, so that the loop vectorises; the error bound holds for any order of
    /// summation.
    pub(crate) fn relax_row(&self, lam: &[f64], out: &mut [f64], upper_side: bool) -> [f64; 3] {
        const LANES: usize = 4;
        let (mut su, mut sl, mut mag) = ([0.0; LANES], [0.0; LANES], [0.0; LANES]);
        let whole = lam.len() - lam.len() % LANES;
        for at in (0..whole).step_by(LANES) {
            let lines = self.lanes::<LANES>(at);
            let l: [f64; LANES] = lam[at..at + LANES].try_into().unwrap();
            let mut ls = [0.0; LANES];
            for q in 0..LANES {
                let [s, u, d, m] = relax_entry(l[q], lines[q], upper_side);
                ls[q] = s;
                su[q] += u;
                sl[q] += d;
                mag[q] += m;
            }
            out[at..at + LANES].copy_from_slice(&ls);
        }
        for c in whole..lam.len() {
            let [line] = self.lanes::<1>(c);
            let [s, u, d, m] = relax_entry(lam[c], line, upper_side);
            out[c] = s;
            su[0] += u;
            sl[0] += d;
            mag[0] += m;
        }
        [su, sl, mag].map(|v| (v[0] + v[1]) + (v[2] + v[3]))
    }
}

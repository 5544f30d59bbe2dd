//! Local error margins on the device (docs/design.md §2.7): the largest certified bound of the
//! error map's cells that a set's x-box meets, exactly [`crate::error_map::ErrorMap::local_bound`]
//! for any set size, read from a range-maximum structure in O(log) entries per cell shape
//! (`local_margin` in `shaders/margins.wgsl` walks it; [`MarginMap::bound`] is the same walk on
//! the host).
//!
//! # The structure
//!
//! A closed cell `[l, h]` meets a closed box `[a, b]` iff `lᵢ ≤ bᵢ` and `hᵢ ≥ aᵢ` on every
//! axis. The cells are grouped by shape (their widths: the levels of the map's bisection tree,
//! 13 in the shipped maps). Within one shape, sorting by `l₀` sorts `h₀` too, so the cells that
//! meet the box along axis 0 are one range of ranks `[i₀, i₁)`, found by two binary searches;
//! along axis 1 likewise within any subset sorted by `l₁`. Over the ranks sits a merge-sort
//! tree: at level `h` each block of `2^h` ranks holds its cells sorted by `l₁`, with a sparse
//! table of their bounds (the maximum over any run of positions from two entries) and, per
//! position, how many of the cells before it come from the block's left half (fractional
//! cascading: the axis-1 range found once at the root maps to every block on the way down in
//! O(1)). The rank range splits into at most `2·log K` whole blocks; each gives its maximum
//! over the axis-1 range from two table entries. A query reads `O(log K)` entries per shape,
//! whatever the set's size; the structure holds `O(K log² K)` numbers (5.1–5.5 M for the shipped
//! maps).
//!
//! # Soundness and exactness
//!
//! On the device, cells are rounded outward and bounds up (`+∞` and anything past `HUGE`
//! become `HUGE`, read as "no certified bound"); rounding is monotone, so the sorted orders
//! survive it (the build checks them, and puts a cell that would break one in a shape of its
//! own). The walk only compares numbers, so it finds exactly the (rounded) cells that meet the
//! computed x-box: in f64 the CPU's cells and bound, in f32 a superset of them with bounds
//! rounded up. A box outside the map's region (rounded outward) or with a non-finite end gets
//! `HUGE`, as the CPU's `+∞`. Axes past the second are not looked at (a superset of the cells
//! met, still sound); a one-dimensional map gets a second axis on which everything meets.
//!
//! This module reads the map only through its region, its cells' corners and bounds, and
//! whether it is certified.

use std::fmt::Write;

use super::codegen::{real_literal, round_down, round_up};
use super::Precision;
use crate::error_map::ErrorMap;
use crate::reach::{ReachMethod, ReachProblem, ReachSettings};

/// Header words per shape in [`MarginMap::index`]: reals offset, words offset, cells, levels.
const HEADER: usize = 4;

/// An error map laid out for the device as a range-maximum structure (module documentation).
#[derive(Clone, Debug, PartialEq)]
pub struct MarginMap {
    /// Whether the map has certified bounds at all (else every margin is `+∞`).
    pub certified: bool,
    /// The map's region rounded outward to device numbers (two axes).
    pub region_lo: [f64; 2],
    /// Its upper corner, rounded up.
    pub region_hi: [f64; 2],
    /// Shapes (groups of cells of equal widths).
    pub shapes: usize,
    /// Per shape `[reals offset, words offset, K, H]`, then the cascade counts.
    pub index: Vec<u32>,
    /// Per shape: `l₀[K]`, `h₀[K]`, per level `l₁[K]`, `h₁[K]`, then the sparse tables.
    pub reals: Vec<f64>,
    /// Extra loop iterations per query (0; tests raise it to show the embedding kernel's loop
    /// check at work).
    pub pad_loops: u32,
}

/// The device's `HUGE` (shaders' "unbounded") as an f64.
fn huge(precision: Precision) -> f64 {
    round_up(f64::INFINITY, precision)
}

/// One cell on the device: corners on two axes (rounded outward) and its bound (rounded up).
#[derive(Clone, Copy, Debug)]
struct Cell {
    lo: [f64; 2],
    hi: [f64; 2],
    bound: f64,
}

/// `⌈log₂ k⌉` (0 for k ≤ 1).
fn levels_for(k: usize) -> usize {
    k.max(1).next_power_of_two().trailing_zeros() as usize
}

/// The first position in `0..len` at which `pred` holds, `pred` false then true.
fn partition_point(len: usize, pred: impl Fn(usize) -> bool) -> usize {
    let (mut lo, mut hi) = (0, len);
    while lo < hi {
        let mid = lo + (hi - lo) / 2;
        if pred(mid) {
            hi = mid;
        } else {
            lo = mid + 1;
        }
    }
    lo
}

/// Whether `cells` in the order `ids` have both corners non-decreasing along `axis`.
fn monotone(cells: &[Cell], ids: &[usize], axis: usize) -> bool {
    ids.windows(2).all(|w| {
        let (a, b) = (&cells[w[0]], &cells[w[1]]);
        a.lo[axis] <= b.lo[axis] && a.hi[axis] <= b.hi[axis]
    })
}

impl MarginMap {
    /// The device image of `map` in `precision`.
    pub fn new(map: &ErrorMap, precision: Precision) -> MarginMap {
        let (down, up) = (
            |x: f64| round_down(x, precision),
            |x: f64| round_up(x, precision),
        );
        let huge = huge(precision);
        let n = map.region.dim();
        let axis = |v: &[f64], i: usize| if i < n { v[i] } else { 0.0 };
        let region_lo = [
            down(axis(&map.region.lower, 0)),
            down(axis(&map.region.lower, 1)),
        ];
        let region_hi = [
            up(axis(&map.region.upper, 0)),
            up(axis(&map.region.upper, 1)),
        ];
        // Shapes by the cells' widths on the first two axes.
        let mut keys: Vec<([u64; 2], usize)> = Vec::with_capacity(map.cells.len());
        let cells: Vec<Cell> = map
            .cells
            .iter()
            .enumerate()
            .map(|(k, c)| {
                let w = |i| (axis(&c.upper, i) - axis(&c.lower, i)).to_bits();
                keys.push(([w(0), w(1)], k));
                Cell {
                    lo: [down(axis(&c.lower, 0)), down(axis(&c.lower, 1))],
                    hi: [up(axis(&c.upper, 0)), up(axis(&c.upper, 1))],
                    bound: match c.bound.is_finite() {
                        true => up(c.bound).min(huge),
                        false => huge,
                    },
                }
            })
            .collect();
        keys.sort_unstable();
        let mut groups: Vec<Vec<usize>> = Vec::new();
        for (i, (key, k)) in keys.iter().enumerate() {
            match i > 0 && keys[i - 1].0 == *key {
                true => groups.last_mut().expect("a group").push(*k),
                false => groups.push(vec![*k]),
            }
        }
        let mut m = MarginMap {
            certified: map.certified_linf.is_some(),
            region_lo,
            region_hi,
            shapes: 0,
            index: Vec::new(),
            reals: Vec::new(),
            pad_loops: 0,
        };
        let mut shapes: Vec<Vec<usize>> = Vec::new();
        for mut ids in groups {
            ids.sort_by(|&a, &b| {
                let (a, b) = (&cells[a], &cells[b]);
                (a.lo[0], a.hi[0], a.lo[1])
                    .partial_cmp(&(b.lo[0], b.hi[0], b.lo[1]))
                    .expect("finite")
            });
            let mut by_y = ids.clone();
            by_y.sort_by(|&a, &b| {
                let (a, b) = (&cells[a], &cells[b]);
                (a.lo[1], a.hi[1])
                    .partial_cmp(&(b.lo[1], b.hi[1]))
                    .expect("finite")
            });
            if monotone(&cells, &ids, 0) && monotone(&cells, &by_y, 1) {
                shapes.push(ids);
            } else {
                // Rounding broke an order (never seen): each cell a shape of its own.
                shapes.extend(ids.into_iter().map(|k| vec![k]));
            }
        }
        m.index.resize(HEADER * shapes.len(), 0);
        for (s, ids) in shapes.iter().enumerate() {
            m.push_shape(s, &cells, ids);
        }
        m.shapes = shapes.len();
        m
    }

    /// Appends one shape's arrays (`ids` sorted by `l₀`) and writes its header.
    fn push_shape(&mut self, s: usize, cells: &[Cell], ids: &[usize]) {
        let k = ids.len();
        let levels = levels_for(k);
        let header = [self.reals.len(), self.index.len(), k, levels];
        for (i, v) in header.into_iter().enumerate() {
            self.index[HEADER * s + i] = u32::try_from(v).expect("error map too large");
        }
        self.reals.extend(ids.iter().map(|&c| cells[c].lo[0]));
        self.reals.extend(ids.iter().map(|&c| cells[c].hi[0]));
        // Level h: per block of 2^h ranks, its cells by (l₁, h₁, rank); merged from level h − 1.
        let key = |r: usize| {
            let c = &cells[ids[r]];
            (c.lo[1], c.hi[1], r)
        };
        let mut order: Vec<usize> = (0..k).collect();
        let mut lists = Vec::with_capacity(levels + 1);
        for h in 0..=levels {
            if h > 0 {
                let half = 1 << (h - 1);
                let mut next = Vec::with_capacity(k);
                let mut left = Vec::with_capacity(k);
                for start in (0..k).step_by(1 << h) {
                    let mid = (start + half).min(k);
                    let end = (start + 2 * half).min(k);
                    let (mut a, mut b) = (start, mid);
                    let mut from_left = 0u32;
                    while a < mid || b < end {
                        left.push(from_left);
                        let take_left = b == end
                            || (a < mid
                                && key(order[a]).partial_cmp(&key(order[b]))
                                    == Some(std::cmp::Ordering::Less));
                        if take_left {
                            next.push(order[a]);
                            a += 1;
                            from_left += 1;
                        } else {
                            next.push(order[b]);
                            b += 1;
                        }
                    }
                }
                self.index.extend(left);
                order = next;
            }
            lists.push(order.clone());
        }
        for list in &lists {
            self.reals.extend(list.iter().map(|&r| cells[ids[r]].lo[1]));
            self.reals.extend(list.iter().map(|&r| cells[ids[r]].hi[1]));
        }
        // Sparse tables: level h, run 2^j (j ≤ h): the largest bound of positions
        // [p, p + 2^j) within p's block.
        for (h, list) in lists.iter().enumerate() {
            let mut run: Vec<f64> = list.iter().map(|&r| cells[ids[r]].bound).collect();
            self.reals.extend_from_slice(&run);
            for j in 1..=h {
                let step = 1 << (j - 1);
                let prev = run.clone();
                for p in 0..k {
                    let block_end = ((p >> h) + 1) << h;
                    if p + step < block_end.min(k) {
                        run[p] = prev[p].max(prev[p + step]);
                    }
                }
                self.reals.extend_from_slice(&run);
            }
        }
    }

    /// A map of no cells, for problems without local margins (the kernels still declare its
    /// constants and buffers).
    pub fn placeholder() -> MarginMap {
        MarginMap {
            certified: false,
            region_lo: [0.0; 2],
            region_hi: [0.0; 2],
            shapes: 0,
            index: Vec::new(),
            reals: Vec::new(),
            pad_loops: 0,
        }
    }

    /// The map for a problem: its error map's with local margins (the disturbance method with a
    /// map), else [`MarginMap::placeholder`].
    pub fn for_problem(
        problem: &ReachProblem,
        settings: &ReachSettings,
        precision: Precision,
    ) -> MarginMap {
        match &problem.error_map {
            Some(map) if settings.method == ReachMethod::Disturbance => {
                if map.region.dim() == problem.dynamics.n {
                    MarginMap::new(map, precision)
                } else {
                    // No bound anywhere, as ErrorMap::local_bound for a box of another dimension.
                    MarginMap::placeholder()
                }
            }
            _ => MarginMap::placeholder(),
        }
    }

    /// The local bound over the box `[lo, hi]` (its first two axes), as the kernel computes it:
    /// `f64::INFINITY` where the kernel gives `HUGE`.
    pub fn bound(&self, lo: &[f64], hi: &[f64], precision: Precision) -> f64 {
        let huge = huge(precision);
        let axis = |v: &[f64], i: usize| v.get(i).copied().unwrap_or(0.0);
        let (a, b) = ([axis(lo, 0), axis(lo, 1)], [axis(hi, 0), axis(hi, 1)]);
        let inside = (0..2).all(|i| {
            a[i].is_finite()
                && b[i].is_finite()
                && a[i] >= self.region_lo[i]
                && b[i] <= self.region_hi[i]
        });
        if !self.certified || !inside {
            return f64::INFINITY;
        }
        // Bounds are ≥ 0: -1 marks a box that meets no cell, where nothing was certified
        // (+∞, never 0, as `ErrorMap::local_bound`).
        let mut worst = -1.0_f64;
        for s in 0..self.shapes {
            worst = worst.max(self.shape_bound(s, a, b));
        }
        match worst >= huge || worst < 0.0 {
            true => f64::INFINITY,
            false => worst,
        }
    }

    /// The largest bound of shape `s`'s cells that meet `[a, b]` (-1 if none): the walk of
    /// `shape_margin` in `shaders/margins.wgsl`.
    fn shape_bound(&self, s: usize, a: [f64; 2], b: [f64; 2]) -> f64 {
        let h = &self.index[HEADER * s..HEADER * (s + 1)];
        let (base_r, base_u, k, levels) =
            (h[0] as usize, h[1] as usize, h[2] as usize, h[3] as usize);
        let r = &self.reals;
        let i0 = partition_point(k, |p| r[base_r + k + p] >= a[0]);
        let i1 = partition_point(k, |p| r[base_r + p] > b[0]);
        let y = |level: usize, upper: usize| base_r + 2 * k + (2 * level + upper) * k;
        let top = levels;
        let j0 = partition_point(k, |p| r[y(top, 1) + p] >= a[1]);
        let j1 = partition_point(k, |p| r[y(top, 0) + p] > b[1]);
        let table = |level: usize, j: usize| {
            base_r + 2 * k * (levels + 2) + k * (level * (level + 1) / 2 + j)
        };
        let mut worst = -1.0_f64;
        let mut stack = vec![(top, 0usize, j0, j1)];
        while let Some((level, start, pa, pc)) = stack.pop() {
            let end = (start + (1 << level)).min(k);
            if end <= i0 || start >= i1 || pa >= pc {
                continue;
            }
            if i0 <= start && end <= i1 {
                let run = pc - pa;
                let j = (usize::BITS - 1 - run.leading_zeros()) as usize;
                let t = table(level, j);
                worst = worst
                    .max(r[t + start + pa])
                    .max(r[t + start + pc - (1 << j)]);
                continue;
            }
            let half = 1 << (level - 1);
            let left_len = half.min(k - start);
            let left = |pos: usize| match start + pos == end {
                true => left_len,
                false => self.index[base_u + (level - 1) * k + start + pos] as usize,
            };
            let (la, lc) = (left(pa), left(pc));
            if start + half < k {
                stack.push((level - 1, start + half, pa - la, pc - lc));
            }
            stack.push((level - 1, start, la, lc));
        }
        worst
    }

    /// The WGSL constants of the map (`MAP_*`, read by `shaders/margins.wgsl`).
    pub fn wgsl(&self, precision: Precision) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "const MAP_CERTIFIED: bool = {};", self.certified);
        let _ = writeln!(s, "const MAP_SHAPES: u32 = {}u;", self.shapes);
        let _ = writeln!(s, "const MAP_PAD_LOOPS: u32 = {}u;", self.pad_loops);
        let _ = writeln!(s, "const MAP_REALS: u32 = {}u;", self.reals.len().max(1));
        for (name, v) in [("MAP_LO", &self.region_lo), ("MAP_HI", &self.region_hi)] {
            let _ = writeln!(
                s,
                "const {name}: array<real, 2> = array<real, 2>({}, {});",
                real_literal(v[0], precision),
                real_literal(v[1], precision)
            );
        }
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::boxes::IntervalBox;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A map over [0, 1]² bisected like `cbfreach error`'s (x then y, deeper towards a ring),
    /// with bounds that vary over the cells, one +∞, and gaps (cells proven to miss S).
    fn tree_map() -> ErrorMap {
        let mut cells = Vec::new();
        let mut stack = vec![([0.0, 0.0], [1.0, 1.0], 0usize)];
        let mut k = 0usize;
        while let Some((lo, hi, depth)) = stack.pop() {
            let c = [(lo[0] + hi[0]) / 2.0, (lo[1] + hi[1]) / 2.0];
            let ring = ((c[0] - 0.4f64).powi(2) + (c[1] - 0.55f64).powi(2)).sqrt();
            let size = hi[0] - lo[0];
            if depth < 12 && (depth < 3 || (ring - 0.3).abs() < 1.5 * size) {
                let axis = depth % 2;
                let mid = (lo[axis] + hi[axis]) / 2.0;
                let (mut h1, mut l2) = (hi, lo);
                h1[axis] = mid;
                l2[axis] = mid;
                stack.push((lo, h1, depth + 1));
                stack.push((l2, hi, depth + 1));
                continue;
            }
            k += 1;
            if k % 17 == 5 {
                continue; // a gap
            }
            let bound = match k {
                40 => "\"inf\"".to_string(),
                _ => format!("{}", ((k * 37) % 101) as f64 / 1000.0),
            };
            cells.push(format!(
                "{{\"lower\": [{}, {}], \"upper\": [{}, {}], \"bound\": {bound}}}",
                lo[0], lo[1], hi[0], hi[1]
            ));
        }
        let json = format!(
            "{{\"format\": \"cbfreach-errormap-1\", \"network\": \"t\", \"network_hash\": \"0\", \
             \"region\": {{\"lower\": [0, 0], \"upper\": [1, 1]}}, \"norm\": \"inf\", \
             \"measured_linf\": 0, \"measured_l2\": 0, \"certified_linf\": \"inf\", \
             \"cells\": [{}]}}",
            cells.join(", ")
        );
        serde_json::from_str(&json).unwrap()
    }

    /// The structure's bound is the CPU's `local_bound` (f64: exactly; f32: at least it, and
    /// within the outward rounding), for boxes of every size from a point to the region,
    /// touching cell edges exactly, and outside the region.
    #[test]
    fn bound_is_the_cpus_local_bound() {
        let map = tree_map();
        assert!(map.cells.len() > 300, "{} cells", map.cells.len());
        let m64 = MarginMap::new(&map, Precision::F64);
        let m32 = MarginMap::new(&map, Precision::F32);
        assert!(m64.shapes >= 8, "{} shapes", m64.shapes);
        assert!(m64.shapes < 12, "{} shapes", m64.shapes);
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut rnd = || rng.random::<f64>();
        let mut checked = 0;
        for t in 0..4000 {
            let w = [rnd().powi(3), rnd().powi(3)];
            let mut lo = [rnd() * 1.1 - 0.05, rnd() * 1.1 - 0.05];
            if t % 5 == 0 {
                // On a cell edge.
                lo = [
                    (lo[0] * 64.0).round() / 64.0,
                    (lo[1] * 512.0).round() / 512.0,
                ];
            }
            let hi = [lo[0] + w[0], lo[1] + if t % 7 == 0 { 0.0 } else { w[1] }];
            let want = map.local_bound(&IntervalBox::new(lo.to_vec(), hi.to_vec()).unwrap());
            let got = m64.bound(&lo, &hi, Precision::F64);
            assert_eq!(got, want, "box {lo:?}..{hi:?}");
            let got32 = m32.bound(&lo, &hi, Precision::F32);
            assert!(got32 >= want, "f32 box {lo:?}..{hi:?}: {got32} < {want}");
            checked += usize::from(want.is_finite() && want > 0.0);
        }
        assert!(
            checked > 1000,
            "{checked} boxes with a finite positive bound"
        );
    }

    #[test]
    fn uncertified_and_empty_maps() {
        let mut map = tree_map();
        map.certified_linf = None;
        let m = MarginMap::new(&map, Precision::F64);
        assert_eq!(
            m.bound(&[0.1, 0.1], &[0.2, 0.2], Precision::F64),
            f64::INFINITY
        );
        let mut map = tree_map();
        map.cells.clear();
        let m = MarginMap::new(&map.reindexed(), Precision::F64);
        assert_eq!(m.shapes, 0);
        // No cell certifies anything: +∞, as the CPU's local bound.
        assert_eq!(
            m.bound(&[0.1, 0.1], &[0.2, 0.2], Precision::F64),
            f64::INFINITY
        );
    }
}

//! Local error margins on the device (`--local-margin`, docs/design.md §2b): the error map's cells and a
//! bucket index over its region, uploaded once, so that the embedding kernel
//! (`local_margin` in `shaders/embed.wgsl`) takes per box and step the same maximum as
//! [`crate::error_map::ErrorMap::local_bound`] on the CPU: `M = max { M_c : c meets the
//! set's x-bounding box }` over the map's closed cells `c` (`+∞` where a cell met has no
//! certified bound, and for a box outside the map's region).
//!
//! # Soundness
//!
//! The buckets are defined by the device numbers `L` (origin) and `ι` (inverse step) per axis:
//! bucket `b` is `{x : b ≤ (x − L)·ι ≤ b + 1}` (closed), the first and last extended to `∓∞`, so
//! every point lies in a bucket. A cell is listed in every bucket its closed extent meets
//! ([`bucket_range`] in f64 with a safety margin `δ` that only widens the range). The kernel
//! visits every bucket the box's x-box meets (the same range in device arithmetic: the computed
//! `(x − L)·ι` errs by at most `3u·|t|` plus an underflow term, far below its margin
//! `KERNEL_DELTA` while `|t| ≤ count + 1`; beyond that the clamp gives the edge bucket, the only
//! one met), and tests each listed cell against the box with the cell rounded outward to device
//! numbers. So a cell that meets the exact set meets the computed x-box, shares a visited bucket
//! with it (the bucket of a common point) and passes the outward test: the device's maximum is
//! at least the CPU's. Bounds are rounded up; `+∞` (and anything past the device's `HUGE`)
//! becomes `HUGE`, which the kernel reads as "no certified bound". The test of the x-box against
//! the map's region (rounded outward) mirrors the CPU's; soundness does not rest on it, since
//! the exact set lies in `C ⊆` the map's region whenever a margin is taken (initial boxes are
//! checked, and every step's set is checked against `C`, rounded inward, before the next).
//!
//! # Bounded work
//!
//! A set that has grown over many buckets would make that exact visit long: thousands of
//! iterations a step, and llvmpipe (lavapipe) silently ends every loop of an invocation after
//! 65,535 iterations in all, cutting the loops of the other boxes of its SIMD group short too.
//! So the exact visit runs only while it reads at most [`EXACT_WORK`] buckets and cell entries
//! (the kernel gives up at the first entry beyond); past that, the kernel takes the maximum of
//! precomputed block maxima instead: level `ℓ` holds, per block of `2^ℓ` buckets a side, the
//! largest bound of the cells listed in its buckets, and the kernel reads the finest level at
//! which the set meets at most [`BLOCK_BUDGET`] blocks. Every cell that meets the set is listed
//! in a bucket the set meets, hence in a block read, so this maximum is never below the exact
//! one: still sound, looser by at most one block a side (`BLOCK_BUDGET^(1/n)` blocks span the
//! set: in 2-D about 1/16 of its extent).

use std::fmt::Write;

use super::codegen::{real_literal, round_down, round_up};
use super::Precision;
use crate::error_map::ErrorMap;
use crate::reach::{ReachMethod, ReachProblem, ReachSettings};

/// Most buckets per axis, and in all.
const MAX_PER_AXIS: usize = 1024;
const MAX_BUCKETS: usize = 1 << 20;
/// The host's safety margin in bucket units (its f64 error is ~1e-12 at these sizes).
const HOST_DELTA: f64 = 1e-6;
/// The kernel's safety margin in bucket units (`(MAX_PER_AXIS + 2)·3u` is below 1e-3 in f32).
pub const KERNEL_DELTA: f64 = 1.0 / 16.0;
/// Most buckets plus cell entries one exact query reads before it gives up for block maxima.
pub const EXACT_WORK: usize = 2048;
/// Most blocks one block-maximum query reads (at the finest level that allows it).
pub const BLOCK_BUDGET: usize = 256;

/// An error map laid out for the device.
#[derive(Clone, Debug, PartialEq)]
pub struct MarginMap {
    /// Whether the map has certified bounds at all (else every margin is `+∞`).
    pub certified: bool,
    /// Buckets per axis.
    pub counts: Vec<usize>,
    /// Bucket origin `L` per axis (a device number).
    pub origin: Vec<f64>,
    /// Inverse bucket step `ι` per axis (a device number).
    pub inv_step: Vec<f64>,
    /// The map's region rounded outward to device numbers.
    pub region_lo: Vec<f64>,
    /// Its upper corner, rounded up.
    pub region_hi: Vec<f64>,
    /// `start[0..=B]` then the cell ids: bucket `k` lists `ids[start[k]..start[k + 1]]`, at
    /// offset `B + 1` of this array.
    pub index: Vec<u32>,
    /// Per cell `lo[n]` (rounded down), `hi[n]` (rounded up), bound (rounded up, `HUGE` for ∞).
    pub cells: Vec<f64>,
    /// The block maxima of levels `0..=levels` (level 0: per bucket), each row-major over
    /// [`MarginMap::level_counts`] blocks, starting at `level_at[ℓ]`.
    pub blocks: Vec<f64>,
    /// Where each level starts in `blocks`.
    pub level_at: Vec<usize>,
    /// Most buckets plus entries an exact query reads ([`EXACT_WORK`]; tests raise it to
    /// show the loop check of the embedding kernel at work).
    pub exact_work: usize,
}

/// The device's `HUGE` (shaders' "unbounded") as an f64.
fn huge(precision: Precision) -> f64 {
    round_up(f64::INFINITY, precision)
}

/// Buckets per axis for `cells` cells in `n` dimensions: about one cell per bucket.
fn bucket_counts(cells: usize, n: usize) -> Vec<usize> {
    let per_axis = ((cells.max(1) as f64).powf(1.0 / n as f64).ceil() as usize).max(1);
    let cap = (MAX_BUCKETS as f64).powf(1.0 / n as f64).floor() as usize;
    vec![per_axis.clamp(1, MAX_PER_AXIS.min(cap.max(1))); n]
}

/// The buckets `[lo, hi]` (clamped to `0..count`) whose closed extent may meet `[a, b]` along
/// one axis, for `t(x) = (x − origin)·inv_step`, widened by `delta` bucket units.
pub fn bucket_range(
    a: f64,
    b: f64,
    origin: f64,
    inv_step: f64,
    count: usize,
    delta: f64,
) -> (usize, usize) {
    let last = (count - 1) as f64;
    let index = |x: f64, d: f64| {
        let t = ((x - origin) * inv_step + d).floor();
        if t.is_nan() {
            if d < 0.0 {
                0.0
            } else {
                last
            }
        } else {
            t.clamp(0.0, last)
        }
    };
    (index(a, -delta) as usize, index(b, delta) as usize)
}

impl MarginMap {
    /// The device image of `map` in `precision`.
    pub fn new(map: &ErrorMap, precision: Precision) -> MarginMap {
        let n = map.region.dim();
        let (down, up) = (
            |x: f64| round_down(x, precision),
            |x: f64| round_up(x, precision),
        );
        let counts = bucket_counts(map.cells.len(), n);
        let origin: Vec<f64> = map.region.lower.iter().map(|&l| down(l)).collect();
        let inv_step: Vec<f64> = (0..n)
            .map(|i| {
                let width = (map.region.upper[i] - origin[i]).max(f64::MIN_POSITIVE);
                // Any positive device number defines valid buckets; this one spans the region.
                down(counts[i] as f64 / width).max(round_up(f64::MIN_POSITIVE, precision))
            })
            .collect();
        let total: usize = counts.iter().product();
        let mut lists: Vec<Vec<u32>> = vec![Vec::new(); total];
        for (k, c) in map.cells.iter().enumerate() {
            let ranges: Vec<(usize, usize)> = (0..n)
                .map(|i| {
                    let (a, b) = (c.lower[i], c.upper[i]);
                    bucket_range(a, b, origin[i], inv_step[i], counts[i], HOST_DELTA)
                })
                .collect();
            for_each_bucket(&counts, &ranges, |b| lists[b].push(k as u32));
        }
        let mut index = Vec::with_capacity(total + 1 + map.cells.len());
        let mut at = 0u32;
        index.push(0);
        for l in &lists {
            at += l.len() as u32;
            index.push(at);
        }
        index.extend(lists.into_iter().flatten());
        let huge = huge(precision);
        let bounds: Vec<f64> = map
            .cells
            .iter()
            .map(|c| {
                if c.bound.is_finite() {
                    up(c.bound).min(huge)
                } else {
                    huge
                }
            })
            .collect();
        let mut cells = Vec::with_capacity(map.cells.len() * (2 * n + 1));
        for (c, &bound) in map.cells.iter().zip(&bounds) {
            cells.extend(c.lower.iter().map(|&v| down(v)));
            cells.extend(c.upper.iter().map(|&v| up(v)));
            cells.push(bound);
        }
        let mut m = MarginMap {
            certified: map.certified_linf.is_some(),
            counts,
            origin,
            inv_step,
            region_lo: map.region.lower.iter().map(|&v| down(v)).collect(),
            region_hi: map.region.upper.iter().map(|&v| up(v)).collect(),
            index,
            cells,
            blocks: Vec::new(),
            level_at: Vec::new(),
            exact_work: EXACT_WORK,
        };
        m.build_blocks(&bounds);
        m
    }

    /// Levels of block maxima above the buckets: the last has one block.
    pub fn levels(&self) -> usize {
        let widest = self.counts.iter().copied().max().unwrap_or(1);
        widest.next_power_of_two().trailing_zeros() as usize
    }

    /// Blocks per axis at `level` (`2^level` buckets a side, the last one perhaps fewer).
    pub fn level_counts(&self, level: usize) -> Vec<usize> {
        self.counts
            .iter()
            .map(|&c| c.div_ceil(1 << level))
            .collect()
    }

    /// Fills `blocks`: level 0 from the cells listed per bucket (`bounds` per cell), each
    /// higher level from the one below (a block's maximum over its up to `2^n` children).
    fn build_blocks(&mut self, bounds: &[f64]) {
        let n = self.counts.len();
        let buckets: usize = self.counts.iter().product();
        let ids = &self.index[buckets + 1..];
        let mut level: Vec<f64> = (0..buckets)
            .map(|k| {
                let (a, b) = (self.index[k] as usize, self.index[k + 1] as usize);
                ids[a..b]
                    .iter()
                    .map(|&c| bounds[c as usize])
                    .fold(0.0, f64::max)
            })
            .collect();
        self.level_at = vec![0];
        self.blocks = level.clone();
        for l in 1..=self.levels() {
            let (below, here) = (self.level_counts(l - 1), self.level_counts(l));
            let mut next = vec![0.0f64; here.iter().product()];
            let full: Vec<(usize, usize)> = below.iter().map(|&c| (0, c - 1)).collect();
            for_each_bucket(&below, &full, |k| {
                // Row-major index k at the level below → its parent block.
                let (mut rest, mut parent, mut stride) = (k, 0, 1);
                for i in (0..n).rev() {
                    parent += (rest % below[i]) / 2 * stride;
                    rest /= below[i];
                    stride *= here[i];
                }
                next[parent] = next[parent].max(level[k]);
            });
            self.level_at.push(self.blocks.len());
            self.blocks.extend_from_slice(&next);
            level = next;
        }
    }

    /// The reals the kernel reads (`map_cells`): the cells, then the block maxima.
    pub fn device_reals(&self) -> Vec<f64> {
        let mut v = self.cells.clone();
        v.extend_from_slice(&self.blocks);
        v
    }

    /// A map of no cells in `n` dimensions, for problems without local margins (the kernels
    /// still declare its constants and buffers).
    pub fn placeholder(n: usize) -> MarginMap {
        MarginMap {
            certified: false,
            counts: vec![1; n],
            origin: vec![0.0; n],
            inv_step: vec![1.0; n],
            region_lo: vec![0.0; n],
            region_hi: vec![0.0; n],
            index: vec![0, 0],
            cells: Vec::new(),
            blocks: vec![0.0],
            level_at: vec![0],
            exact_work: EXACT_WORK,
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
                    MarginMap::placeholder(problem.dynamics.n)
                }
            }
            _ => MarginMap::placeholder(problem.dynamics.n),
        }
    }

    /// The WGSL constants of the map's geometry (`MAP_*`, read by `local_margin`).
    pub fn wgsl(&self, precision: Precision) -> String {
        let reals = |v: &[f64]| {
            v.iter()
                .map(|&x| real_literal(x, precision))
                .collect::<Vec<_>>()
                .join(", ")
        };
        let n = self.counts.len();
        let mut s = String::new();
        let _ = writeln!(s, "const MAP_CERTIFIED: bool = {};", self.certified);
        let buckets: usize = self.counts.iter().product();
        let _ = writeln!(s, "const MAP_BUCKETS: u32 = {buckets}u;");
        let _ = writeln!(
            s,
            "const MAP_DELTA: real = {};",
            real_literal(KERNEL_DELTA, precision)
        );
        // The kernel's capped products `buckets · width` stay below 2³².
        let exact_work = self.exact_work.min(u32::MAX as usize / MAX_PER_AXIS - 1);
        let _ = writeln!(s, "const MAP_EXACT_WORK: u32 = {exact_work}u;");
        let _ = writeln!(s, "const MAP_BLOCK_BUDGET: u32 = {BLOCK_BUDGET}u;");
        let levels = self.levels();
        let _ = writeln!(s, "const MAP_LEVELS: u32 = {levels}u;");
        // Block maxima follow the cells in `map_cells`.
        let _ = writeln!(s, "const MAP_BLOCKS_AT: u32 = {}u;", self.cells.len());
        let level_at: Vec<String> = self.level_at.iter().map(|a| format!("{a}u")).collect();
        let _ = writeln!(
            s,
            "var<private> MAP_LEVEL_AT: array<u32, {}> = array<u32, {}>({});",
            levels + 1,
            levels + 1,
            level_at.join(", ")
        );
        let counts: Vec<String> = self.counts.iter().map(|c| format!("{c}u")).collect();
        let _ = writeln!(
            s,
            "var<private> MAP_COUNT: array<u32, {n}> = array<u32, {n}>({});",
            counts.join(", ")
        );
        for (name, v) in [
            ("MAP_ORIGIN", &self.origin),
            ("MAP_INV_STEP", &self.inv_step),
            ("MAP_LO", &self.region_lo),
            ("MAP_HI", &self.region_hi),
        ] {
            let _ = writeln!(
                s,
                "var<private> {name}: array<real, {n}> = array<real, {n}>({});",
                reals(v)
            );
        }
        s
    }
}

/// Calls `f` with the row-major index (axis 0 slowest) of every bucket in the product of
/// `ranges`.
fn for_each_bucket(counts: &[usize], ranges: &[(usize, usize)], mut f: impl FnMut(usize)) {
    let n = counts.len();
    let mut at: Vec<usize> = ranges.iter().map(|r| r.0).collect();
    loop {
        f((0..n).fold(0, |acc, i| acc * counts[i] + at[i]));
        let mut i = n;
        loop {
            if i == 0 {
                return;
            }
            i -= 1;
            if at[i] < ranges[i].1 {
                at[i] += 1;
                break;
            }
            at[i] = ranges[i].0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bucket_ranges_cover_touching_boxes() {
        // Buckets of width 1 from 0: [1, 2] meets buckets 0, 1 and 2 (closed).
        assert_eq!(bucket_range(1.0, 2.0, 0.0, 1.0, 10, HOST_DELTA), (0, 2));
        assert_eq!(bucket_range(1.5, 1.6, 0.0, 1.0, 10, HOST_DELTA), (1, 1));
        assert_eq!(bucket_range(-5.0, 50.0, 0.0, 1.0, 10, HOST_DELTA), (0, 9));
        assert_eq!(
            bucket_range(f64::NAN, 1.5, 0.0, 1.0, 10, HOST_DELTA),
            (0, 1)
        );
    }

    /// A map of `k × k` cells over [0, 1]² with bounds that vary over the cells, a few of
    /// them +∞, plus one cell spanning several buckets.
    fn checker_map(k: usize) -> ErrorMap {
        let mut cells = Vec::new();
        let h = 1.0 / k as f64;
        for i in 0..k {
            for j in 0..k {
                let bound = if (i * 7 + j * 3) % 23 == 0 {
                    "\"inf\"".to_string()
                } else {
                    format!("{}", ((i * 31 + j * 17) % 29) as f64 / 100.0)
                };
                cells.push(format!(
                    "{{\"lower\": [{}, {}], \"upper\": [{}, {}], \"bound\": {bound}}}",
                    i as f64 * h,
                    j as f64 * h,
                    (i + 1) as f64 * h,
                    (j + 1) as f64 * h
                ));
            }
        }
        cells.push(r#"{"lower": [0.1, 0.2], "upper": [0.55, 0.3], "bound": 0.9}"#.into());
        let json = format!(
            "{{\"format\": \"cbfreach-errormap-1\", \"network\": \"t\", \"network_hash\": \"0\", \
             \"region\": {{\"lower\": [0, 0], \"upper\": [1, 1]}}, \"norm\": \"inf\", \
             \"measured_linf\": 0, \"measured_l2\": 0, \"certified_linf\": \"inf\", \
             \"cells\": [{}]}}",
            cells.join(", ")
        );
        serde_json::from_str(&json).unwrap()
    }

    /// Every block of every level holds the largest bound listed in its buckets (brute force
    /// over the buckets), the last level is one block holding the largest bound of all, and
    /// a +∞ bound stays `HUGE` up the levels.
    #[test]
    fn block_maxima_are_the_maxima_of_their_buckets() {
        for (k, precision) in [(13, Precision::F64), (20, Precision::F32)] {
            let map = checker_map(k);
            let m = MarginMap::new(&map, precision);
            let counts = m.counts.clone();
            let buckets: usize = counts.iter().product();
            let ids = &m.index[buckets + 1..];
            let bucket_max = |b: usize| {
                ids[m.index[b] as usize..m.index[b + 1] as usize]
                    .iter()
                    .map(|&c| m.cells[c as usize * 5 + 4])
                    .fold(0.0, f64::max)
            };
            assert_eq!(m.level_at.len(), m.levels() + 1);
            assert!(m.level_counts(m.levels()).iter().all(|&c| c == 1));
            for level in 0..=m.levels() {
                let here = m.level_counts(level);
                for bx in 0..here[0] {
                    for by in 0..here[1] {
                        let mut want = 0.0f64;
                        for x in 0..counts[0] {
                            for y in 0..counts[1] {
                                if x >> level == bx && y >> level == by {
                                    want = want.max(bucket_max(x * counts[1] + y));
                                }
                            }
                        }
                        let got = m.blocks[m.level_at[level] + bx * here[1] + by];
                        assert_eq!(got, want, "level {level} block ({bx}, {by})");
                    }
                }
            }
            let top = m.blocks[m.level_at[m.levels()]];
            assert_eq!(top, huge(precision));
            let reals = m.device_reals();
            assert_eq!(reals.len(), m.cells.len() + m.blocks.len());
            assert_eq!(reals[m.cells.len()..], m.blocks[..]);
        }
    }

    #[test]
    fn counts_respect_the_caps() {
        assert_eq!(bucket_counts(40_000, 2), vec![200, 200]);
        assert_eq!(bucket_counts(0, 3), vec![1, 1, 1]);
        assert!(bucket_counts(1 << 30, 2).iter().product::<usize>() <= MAX_BUCKETS);
    }
}

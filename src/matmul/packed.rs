//! Products `A·B` and `|A|·B` with a fixed left factor (a layer's `W`) packed once, over a
//! chosen subset of the inner dimension, several right factors in one pass over `A`.
//!
//! The forward bound method multiplies each weight matrix by thin panels (`2`–`3` columns a
//! face or box: 18–48 columns a thread at the paper's 12 boxes), many times a second, skipping
//! the rows of the right factor that are zero (neurons inactive over every box). Through a
//! general GEMM that meant gathering the live columns of `W` and the GEMM packing them again on
//! every call; here `W` is packed once, in panels of [`MR`] rows with the [`MR`] entries of each
//! column on one cache line, and the kernel walks the live inner indices directly.
//!
//! A layer's three products (`W·Ĉ`, `|W|·R̂`, `|W|·V`) run as [`Part`]s of one
//! [`PackedMatrix::products`] call: `|W|` is `W` with the sign bit cleared as it is loaded, and
//! the packed matrix is stored block by block ([`KB`] inner indices), each block's panels one
//! after another, so that one sequential pass over `W` (which does not fit in L2 beside the
//! next layer's) serves all three; each block of a panel is read from memory once and reused
//! from L1 by every part. Three passes over `W`, `|W|`, `|W|` before.
//!
//! Soundness does not depend on the kernel: the rounding model ([`crate::rounding`]) bounds the
//! error of any order of summation, with or without fused multiply–adds; `|w|` is exact.
#![allow(clippy::needless_range_loop)] // index loops over registers read as the formulas

use std::sync::atomic::Ordering;

/// Rows of a panel: two AVX2 registers of f64.
const MR: usize = 8;
/// Columns of the right factor a kernel call keeps in registers (`MR × NR` accumulators).
const NR: usize = 6;
/// Inner indices a block of the packed storage (8 KiB of a panel): blocks are stored one after
/// another, each block's panels in order.
const KB: usize = 128;

/// An `m × k` matrix packed in panels of [`MR`] rows (the last one padded with zeros), stored
/// block-major: block `b` (columns `b·KB ..`, `w_b` of them) holds panel 0's columns, then
/// panel 1's, …, each column's [`MR`] rows on one cache line.
#[derive(Clone, Debug, Default)]
pub struct PackedMatrix {
    m: usize,
    k: usize,
    columns: Vec<Column>,
}

/// One column of a panel: [`MR`] entries on one 64-byte cache line (the allocator aligns a
/// `Vec<f64>` to 16 bytes only, so an unaligned column's second half split across two lines
/// on every load).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Column([f64; MR]);

/// One product of a [`PackedMatrix::products`] call, for each of `planes` right factors `q`:
/// `out[i·stride + out_col + q·out_plane + c] = Σ_{j ∈ live} A'[i][j] · b[j·b_stride + b_col +
/// q·b_plane + c]` for every row `i` and `c < n`, with `A' = |A|` if `abs`, else `A`; the rows
/// of `b` not in `live` are taken as zero. (The forward method's forms are stored as planes,
/// one per coefficient: `planes` products of `n` columns.)
#[derive(Clone, Copy, Debug)]
pub struct Part<'a> {
    /// Multiply by `|A|` (every entry's sign bit cleared: exact).
    pub abs: bool,
    /// The inner indices to sum over, ascending, each `< k`.
    pub live: &'a [usize],
    /// The right factor.
    pub b: &'a [f64],
    /// Its row stride.
    pub b_stride: usize,
    /// Its first column read.
    pub b_col: usize,
    /// Columns.
    pub n: usize,
    /// Right factors: plane `q` of `b` starts `q·b_plane` further on.
    pub planes: usize,
    /// Offset between planes in `b`.
    pub b_plane: usize,
    /// Which of the call's outputs.
    pub out: usize,
    /// The first column written there.
    pub out_col: usize,
    /// Offset between the planes' products in the output.
    pub out_plane: usize,
}

impl PackedMatrix {
    /// Packs the row-major `m × k` matrix `a`.
    pub fn new(m: usize, k: usize, a: &[f64]) -> PackedMatrix {
        assert!(a.len() >= m * k, "packed matrix: buffer too small");
        let n_panels = m.div_ceil(MR);
        let mut columns = vec![Column::default(); n_panels * k];
        for i in 0..m {
            let (p, r) = (i / MR, i % MR);
            for j in 0..k {
                let (b, w) = (j / KB, KB.min(k - j / KB * KB));
                columns[b * KB * n_panels + p * w + j % KB].0[r] = a[i * k + j];
            }
        }
        PackedMatrix { m, k, columns }
    }

    /// Rows `m`.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// Columns `k`.
    pub fn cols(&self) -> usize {
        self.k
    }

    /// Panel `p`'s columns of block `b` (`j − b·KB` indexes them).
    fn block(&self, b: usize, p: usize) -> &[Column] {
        let w = KB.min(self.k - b * KB);
        let at = b * KB * self.m.div_ceil(MR) + p * w;
        &self.columns[at..at + w]
    }

    /// The [`Part`]s' products in one pass over `A`; `outs` are the outputs as (buffer, row
    /// stride). Parts may share an output (disjoint columns). `scratch` holds each part's live
    /// rows of `b` packed in slabs of [`NR`] columns (each slab contiguous, so that it stays
    /// in L1 while the panels run over it).
    ///
    /// Panics only on an internal shape bug (a slice shorter than its view, unsorted `live`).
    pub fn products(
        &self,
        parts: &[Part<'_>],
        outs: &mut [(&mut [f64], usize)],
        scratch: &mut Vec<f64>,
    ) {
        for q in parts {
            let (out, stride) = &outs[q.out];
            let last = q.planes.saturating_sub(1);
            assert!(
                q.live.windows(2).all(|w| w[0] < w[1])
                    && q.live.last().is_none_or(|&j| j < self.k)
                    && q.live.last().is_none_or(|&j| {
                        q.planes == 0
                            || j * q.b_stride + q.b_col + last * q.b_plane + q.n <= q.b.len()
                    })
                    && (self.m == 0
                        || q.planes == 0
                        || (self.m - 1) * stride + q.out_col + last * q.out_plane + q.n
                            <= out.len()),
                "packed product: shape bug"
            );
        }
        if self.m == 0 {
            return;
        }
        let madds: usize = parts
            .iter()
            .map(|q| self.m * q.live.len() * q.n * q.planes)
            .sum();
        super::MULTIPLY_ADDS.fetch_add(madds as u64, Ordering::Relaxed);
        // Part by part, plane by plane, slab by slab (columns `c0 ..`, [`NR`] of them, the last
        // one narrower): for each live row in order, its entries of those columns; the kernel
        // walks them in the same order.
        scratch.clear();
        for q in parts {
            for plane in 0..q.planes {
                for c0 in (0..q.n).step_by(NR) {
                    let c1 = q.n.min(c0 + NR);
                    for &j in q.live {
                        let at = j * q.b_stride + q.b_col + plane * q.b_plane;
                        scratch.extend_from_slice(&q.b[at + c0..at + c1]);
                    }
                }
            }
        }
        let job = Job {
            a: self,
            parts,
            slabs: scratch,
        };
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has the features the function is compiled for.
            unsafe { products_fma(&job, outs) };
            return;
        }
        products_body::<false>(&job, outs);
    }
}

/// One call: the packed `A`, the parts and their slabs.
struct Job<'a> {
    a: &'a PackedMatrix,
    parts: &'a [Part<'a>],
    slabs: &'a [f64],
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn products_fma(job: &Job<'_>, outs: &mut [(&mut [f64], usize)]) {
    products_body::<true>(job, outs);
}

/// The products, panel by panel, each part's slabs in turn, each slab's sum over every block
/// of [`KB`] inner indices kept in registers and stored once. A panel's blocks (`k·MR`
/// entries, 25 KiB at `k = 400`) stay in L1 while every part's slabs run over them; the slabs
/// stream from L2. (Blocks outermost, partial sums stored and added after each block, ran as
/// fast, within the noise of a shared machine; this order sums each entry in one register,
/// with no partial sums to add.) `FMA` selects fused multiply–adds (compiled where the CPU has
/// them: `mul_add` is a library call elsewhere).
#[inline(always)]
fn products_body<const FMA: bool>(job: &Job<'_>, outs: &mut [(&mut [f64], usize)]) {
    let a = job.a;
    for p in 0..a.m.div_ceil(MR) {
        let at = (p * MR, MR.min(a.m - p * MR));
        let mut s0 = 0;
        for q in job.parts {
            let (out, stride) = &mut outs[q.out];
            let len = q.live.len();
            for (c0, plane) in
                (0..q.planes).flat_map(|pl| (0..q.n).step_by(NR).map(move |c| (c, pl)))
            {
                let w = NR.min(q.n - c0);
                let slab = &job.slabs[s0..s0 + len * w];
                s0 += len * w;
                let dst = (
                    &mut **out,
                    *stride,
                    at,
                    q.out_col + plane * q.out_plane + c0,
                );
                match (q.abs, w) {
                    (false, 6) => store(&sum::<FMA, false, 6>(a, p, q.live, slab), dst),
                    (false, 5) => store(&sum::<FMA, false, 5>(a, p, q.live, slab), dst),
                    (false, 4) => store(&sum::<FMA, false, 4>(a, p, q.live, slab), dst),
                    (false, 3) => store(&sum::<FMA, false, 3>(a, p, q.live, slab), dst),
                    (false, 2) => store(&sum::<FMA, false, 2>(a, p, q.live, slab), dst),
                    (false, _) => store(&sum::<FMA, false, 1>(a, p, q.live, slab), dst),
                    (true, 6) => store(&sum::<FMA, true, 6>(a, p, q.live, slab), dst),
                    (true, 5) => store(&sum::<FMA, true, 5>(a, p, q.live, slab), dst),
                    (true, 4) => store(&sum::<FMA, true, 4>(a, p, q.live, slab), dst),
                    (true, 3) => store(&sum::<FMA, true, 3>(a, p, q.live, slab), dst),
                    (true, 2) => store(&sum::<FMA, true, 2>(a, p, q.live, slab), dst),
                    (true, _) => store(&sum::<FMA, true, 1>(a, p, q.live, slab), dst),
                }
            }
        }
    }
}

/// Panel `p`'s `MR × C` sums over all `live` indices against a slab of `C` columns (one row
/// per live index), block by block.
#[inline(always)]
fn sum<const FMA: bool, const ABS: bool, const C: usize>(
    a: &PackedMatrix,
    p: usize,
    live: &[usize],
    slab: &[f64],
) -> [[f64; MR]; C] {
    let mut acc = [[0.0; MR]; C];
    let mut from = 0;
    while from < live.len() {
        let b = live[from] / KB;
        let to = from + live[from..].partition_point(|&j| j < b * KB + KB);
        let cols = a.block(b, p);
        block::<FMA, ABS, C>(
            &mut acc,
            cols,
            b * KB,
            &live[from..to],
            &slab[from * C..to * C],
        );
        from = to;
    }
    acc
}

/// Adds to `MR × C` accumulators one panel's block (its columns `j0 ..`) times a slab of `C`
/// columns of the live rows; with `ABS`, `|A|`'s.
#[inline(always)]
fn block<const FMA: bool, const ABS: bool, const C: usize>(
    acc: &mut [[f64; MR]; C],
    cols: &[Column],
    j0: usize,
    live: &[usize],
    slab: &[f64],
) {
    for (&j, row) in live.iter().zip(slab.chunks_exact(C)) {
        debug_assert!(j >= j0 && j - j0 < cols.len());
        // SAFETY: the live indices of a block lie in `j0 .. j0 + cols.len()` (ascending,
        // checked in `products`, and cut at the block's ends).
        let col = unsafe { &cols.get_unchecked(j - j0).0 };
        let col = if ABS { col.map(f64::abs) } else { *col };
        for c in 0..C {
            let x = row[c];
            for r in 0..MR {
                acc[c][r] = if FMA {
                    col[r].mul_add(x, acc[c][r])
                } else {
                    col[r] * x + acc[c][r]
                };
            }
        }
    }
}

/// Writes the first `rows` rows of the accumulators to `out` at row `i0`, column `c0`.
#[inline(always)]
fn store<const C: usize>(
    acc: &[[f64; MR]; C],
    (out, out_stride, (i0, rows), c0): (&mut [f64], usize, (usize, usize), usize),
) {
    for r in 0..rows {
        let dst = &mut out[(i0 + r) * out_stride + c0..(i0 + r) * out_stride + c0 + C];
        for c in 0..C {
            dst[c] = acc[c][r];
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dyadic entries with small numerators: every product and sum is exact in f64, so the
    /// packed products must equal a triple loop over the live rows exactly, for shapes with
    /// partial panels, partial blocks and partial column slabs, strided operands, `A` and
    /// `|A|` parts sharing an output, and both kernels.
    #[test]
    fn packed_products_equal_a_triple_loop_over_the_live_rows() {
        for &(m, k, n) in &[
            (1, 1, 1),
            (3, 5, 2),
            (8, 7, 6),
            (17, 33, 13),
            (64, 70, 48),
            (9, 300, 7),
        ] {
            let a: Vec<f64> = (0..m * k)
                .map(|i| ((i * 37 % 101) as f64 - 50.0) / 16.0)
                .collect();
            let b_stride = 2 * n + 3;
            let b: Vec<f64> = (0..k * b_stride)
                .map(|i| ((i * 53 % 97) as f64 - 48.0) / 8.0)
                .collect();
            let packed = PackedMatrix::new(m, k, &a);
            let lives: [Vec<usize>; 3] = [(0..k).collect(), (0..k).step_by(3).collect(), vec![]];
            for (l0, l1) in [(0, 1), (1, 0), (2, 0), (1, 2)] {
                let (live0, live1) = (&lives[l0], &lives[l1]);
                // Part 0: A on b's first n columns into out0; parts 1 and 2: |A| on b's next
                // n columns (live1) and on its first n (live0), side by side in out1; part 3:
                // A on two planes of b (columns 1 .. n + 1 and n + 1 .. 2n + 1, live1) into
                // out0's columns n + 2 .. 3n + 2.
                let (s0, s1) = (3 * n + 2, 2 * n + 1);
                let want = |abs: bool, live: &[usize], col: usize, i: usize, c: usize| -> f64 {
                    live.iter()
                        .map(|&j| {
                            let w = a[i * k + j];
                            (if abs { w.abs() } else { w }) * b[j * b_stride + col + c]
                        })
                        .sum()
                };
                let parts = [
                    Part {
                        abs: false,
                        live: live0,
                        b: &b,
                        b_stride,
                        b_col: 0,
                        n,
                        planes: 1,
                        b_plane: 0,
                        out: 0,
                        out_col: 0,
                        out_plane: 0,
                    },
                    Part {
                        abs: true,
                        live: live1,
                        b: &b,
                        b_stride,
                        b_col: n,
                        n,
                        planes: 1,
                        b_plane: 0,
                        out: 1,
                        out_col: 0,
                        out_plane: 0,
                    },
                    Part {
                        abs: true,
                        live: live0,
                        b: &b,
                        b_stride,
                        b_col: 0,
                        n,
                        planes: 1,
                        b_plane: 0,
                        out: 1,
                        out_col: n,
                        out_plane: 0,
                    },
                    Part {
                        abs: false,
                        live: live1,
                        b: &b,
                        b_stride,
                        b_col: 1,
                        n,
                        planes: 2,
                        b_plane: n,
                        out: 0,
                        out_col: n + 2,
                        out_plane: n,
                    },
                ];
                for fma in [true, false] {
                    let (mut o0, mut o1) = (vec![-1.0; m * s0], vec![-1.0; m * s1]);
                    let mut scratch = vec![];
                    let mut outs = [(&mut o0[..], s0), (&mut o1[..], s1)];
                    if fma {
                        packed.products(&parts, &mut outs, &mut scratch);
                    } else {
                        // The slabs as `products` packs them, then the portable kernel.
                        packed.products(&parts, &mut outs, &mut scratch);
                        for (o, _) in outs.iter_mut() {
                            o.fill(-1.0);
                        }
                        let job = Job {
                            a: &packed,
                            parts: &parts,
                            slabs: &scratch,
                        };
                        products_body::<false>(&job, &mut outs);
                    }
                    for i in 0..m {
                        for c in 0..n {
                            let tag =
                                format!("{m}×{k}×{n}, lives {l0} {l1}, fma {fma}, ({i}, {c})");
                            assert_eq!(o0[i * s0 + c], want(false, live0, 0, i, c), "{tag}");
                            assert_eq!(o1[i * s1 + c], want(true, live1, n, i, c), "{tag}");
                            assert_eq!(o1[i * s1 + n + c], want(true, live0, 0, i, c), "{tag}");
                            for q in 0..2 {
                                let got = o0[i * s0 + n + 2 + q * n + c];
                                assert_eq!(got, want(false, live1, 1 + q * n, i, c), "{tag}");
                            }
                        }
                        // Columns past the parts stay untouched.
                        assert!(o0[i * s0 + n..i * s0 + n + 2].iter().all(|&x| x == -1.0));
                        assert!(o1[i * s1 + 2 * n..(i + 1) * s1].iter().all(|&x| x == -1.0));
                    }
                }
            }
        }
    }
}

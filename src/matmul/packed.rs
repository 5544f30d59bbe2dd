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
//! Three kernels, chosen at run time ([`Isa`]): AVX-512 (a panel column is one register; two
//! panels at a time against slabs of up to [`NR_512`] columns, 24 accumulators), AVX2 (two
//! registers a column, one panel against [`NR`] columns) and portable code.
//!
//! Soundness does not depend on the kernel: the rounding model ([`crate::rounding`]) bounds the
//! error of any order of summation of the `N` terms, with or without fused multiply–adds, by
//! `γ̂_N` times the computed magnitude sum; `|w|` is exact. Every kernel sums each output entry
//! in one accumulator, from 0, over the live indices in ascending order (blocks and slabs only
//! decide which entries share a pass, not the order within one), so the AVX2 and AVX-512
//! kernels give the same bits; the portable one rounds each product before adding it.
#![allow(clippy::needless_range_loop)] // index loops over registers read as the formulas

use std::sync::atomic::Ordering;

use crate::machine::Isa;

/// Rows of a panel: two AVX2 registers of f64, one AVX-512 register.
const MR: usize = 8;
/// Columns of the right factor an AVX2 or portable kernel call keeps in registers (`MR × NR`
/// accumulators: 12 AVX2 registers).
const NR: usize = 6;
/// Columns an AVX-512 kernel call keeps in registers, for two panels at once (`2·MR × NR_512`
/// accumulators: 24 of the 32 registers). Per inner index that is 2 loads of `A` and up to 12
/// broadcasts for 24 fused multiply–adds: one panel at a time would load as often as it
/// multiplies, and the loads would limit it.
const NR_512: usize = 12;
/// Inner indices a block of the packed storage (8 KiB of a panel): blocks are stored one after
/// another, each block's panels in order.
const KB: usize = 128;

/// An `m × k` matrix packed in panels of `MR` (8) rows (the last one padded with zeros), stored
/// block-major: block `b` (columns `b·KB ..`, `w_b` of them) holds panel 0's columns, then
/// panel 1's, …, each column's `MR` rows on one cache line.
#[derive(Clone, Debug, Default)]
pub struct PackedMatrix {
    m: usize,
    k: usize,
    columns: Vec<Column>,
}

/// One column of a panel: [`MR`] entries on one 64-byte cache line (the allocator aligns a
/// `Vec<f64>` to 16 bytes only, so an unaligned column's second half split across two lines
/// on every load; the AVX-512 kernel's aligned loads rely on it).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Column([f64; MR]);

/// One product of a [`PackedMatrix::products`] call, for each of `planes` right factors `q`:
/// `out[i·stride + out_col + q·out_plane + c] = Σ_{j ∈ live} A'[i][j] · b[j·b_stride + b_col +
/// q·b_plane + c]` for every row `i` and `c < n`, with `A' = |A|` if `abs`, else `A`; the rows
/// of `b` not in `live` are taken as zero. (The forward method's forms are stored as planes,
/// one per coefficient: `planes` products of `n` columns. The kernels take the `planes · n`
/// (plane, column) pairs in order, in slabs that may span planes.)
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

impl Part<'_> {
    /// Where (plane, column) pair `v` (`v = plane·n + column`) sits in a row of `b`.
    fn b_offset(&self, v: usize) -> usize {
        self.b_col + v / self.n * self.b_plane + v % self.n
    }

    /// Where pair `v`'s product sits in a row of the output.
    fn out_offset(&self, v: usize) -> usize {
        self.out_col + v / self.n * self.out_plane + v % self.n
    }
}

/// `$body` with `$c` a constant equal to the slab width `$w`, one of `$n`.
macro_rules! with_width {
    ($w:expr, $c:ident in [$($n:literal),*] => $body:expr) => {
        match $w {
            $($n => {
                const $c: usize = $n;
                $body
            })*
            _ => unreachable!("slab width"),
        }
    };
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
    /// rows of `b` packed in slabs of a few columns (each slab contiguous, so that it stays in
    /// L1 while the panels run over it). Runs the widest kernel the CPU has.
    ///
    /// Panics only on an internal shape bug (a slice shorter than its view, unsorted `live`).
    pub fn products(
        &self,
        parts: &[Part<'_>],
        outs: &mut [(&mut [f64], usize)],
        scratch: &mut Vec<f64>,
    ) {
        self.products_on(Isa::detect(), parts, outs, scratch);
    }

    /// [`PackedMatrix::products`] on `isa`'s kernel (panics where the CPU lacks it).
    fn products_on(
        &self,
        isa: Isa,
        parts: &[Part<'_>],
        outs: &mut [(&mut [f64], usize)],
        scratch: &mut Vec<f64>,
    ) {
        assert!(isa.available(), "packed product: no {} here", isa.name());
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
        let nr = match isa {
            Isa::Avx512 => NR_512,
            _ => NR,
        };
        // Part by part, slab by slab (its (plane, column) pairs `v0 .. v0 + w`): for each live
        // row in order, its entries of those pairs; the kernels walk them in the same order.
        scratch.clear();
        for q in parts {
            for (v0, w) in slabs(q.planes * q.n, nr) {
                // Where each pair of the slab sits in a row of `b`: the rows are copied by
                // these offsets, unrolled for the width (runs of a few entries through
                // `memcpy` had cost as much as a tenth of the kernel's time).
                let mut offs = [0; NR_512];
                for (c, off) in offs[..w].iter_mut().enumerate() {
                    *off = q.b_offset(v0 + c);
                }
                let at = scratch.len();
                scratch.resize(at + q.live.len() * w, 0.0);
                let dst = &mut scratch[at..];
                with_width!(w, C in [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12] => {
                    for (&j, dst) in q.live.iter().zip(dst.chunks_exact_mut(C)) {
                        let row = &q.b[j * q.b_stride..];
                        for c in 0..C {
                            dst[c] = row[offs[c]];
                        }
                    }
                })
            }
        }
        let job = Job {
            a: self,
            parts,
            slabs: scratch,
            nr,
        };
        match isa {
            // SAFETY: the CPU has the features the functions are compiled for (asserted).
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => unsafe { products_avx512(&job, outs) },
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => unsafe { products_fma(&job, outs) },
            _ => products_body::<false>(&job, outs),
        }
    }
}

/// The slabs of a part's `total` (plane, column) pairs, at most `nr` wide, as even as their
/// number allows: `(first pair, width)`.
fn slabs(total: usize, nr: usize) -> impl Iterator<Item = (usize, usize)> {
    let count = total.div_ceil(nr);
    (0..count).map(move |s| {
        let (base, extra) = (total / count, total % count);
        (s * base + s.min(extra), base + usize::from(s < extra))
    })
}

/// The blocks of [`KB`] inner indices that ascending `live` indices fall in: each block and
/// the range of `live` (and of a slab's rows) inside it.
fn live_blocks(live: &[usize]) -> impl Iterator<Item = (usize, std::ops::Range<usize>)> + '_ {
    let mut from = 0;
    std::iter::from_fn(move || {
        let &first = live.get(from)?;
        let b = first / KB;
        let to = from + live[from..].partition_point(|&j| j < b * KB + KB);
        let at = from..to;
        from = to;
        Some((b, at))
    })
}

/// One call: the packed `A`, the parts and their slabs, at most `nr` columns each.
struct Job<'a> {
    a: &'a PackedMatrix,
    parts: &'a [Part<'a>],
    slabs: &'a [f64],
    nr: usize,
}

/// Where a block of sums goes: the output and its row stride, the first row and the rows.
type Dst<'a> = (&'a mut [f64], usize, (usize, usize));

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
        let rows = (p * MR, MR.min(a.m - p * MR));
        let mut s0 = 0;
        for q in job.parts {
            let (out, stride) = &mut outs[q.out];
            let len = q.live.len();
            for (v0, w) in slabs(q.planes * q.n, job.nr) {
                let slab = &job.slabs[s0..s0 + len * w];
                s0 += len * w;
                let dst = (&mut **out, *stride, rows);
                with_width!(w, C in [1, 2, 3, 4, 5, 6] => if q.abs {
                    store(&sum::<FMA, true, C>(a, p, q.live, slab), q, v0, dst)
                } else {
                    store(&sum::<FMA, false, C>(a, p, q.live, slab), q, v0, dst)
                })
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
    for (b, at) in live_blocks(live) {
        let cols = a.block(b, p);
        let slab = &slab[at.start * C..at.end * C];
        block::<FMA, ABS, C>(&mut acc, cols, b * KB, &live[at], slab);
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

/// Writes the first `rows` rows of an `MR × C` block of sums, the part's (plane, column) pairs
/// `v0 ..`, to its output at row `i0`.
#[inline(always)]
fn store<const C: usize>(
    acc: &[[f64; MR]; C],
    q: &Part<'_>,
    v0: usize,
    (out, out_stride, (i0, rows)): Dst<'_>,
) {
    for c in 0..C {
        let col = q.out_offset(v0 + c);
        for r in 0..rows {
            out[(i0 + r) * out_stride + col] = acc[c][r];
        }
    }
}

/// [`products_body`] on AVX-512 registers: panels two at a time (`2·MR × C` sums in 24
/// registers at most), the same sums in the same order.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn products_avx512(job: &Job<'_>, outs: &mut [(&mut [f64], usize)]) {
    let a = job.a;
    let panels = a.m.div_ceil(MR);
    for p in (0..panels).step_by(2) {
        let two = p + 1 < panels;
        let rows = (p * MR, (2 * MR).min(a.m - p * MR));
        let mut s0 = 0;
        for q in job.parts {
            let (out, stride) = &mut outs[q.out];
            let len = q.live.len();
            for (v0, w) in slabs(q.planes * q.n, job.nr) {
                let slab = &job.slabs[s0..s0 + len * w];
                s0 += len * w;
                let dst = (&mut **out, *stride, rows);
                with_width!(w, C in [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12] => match (q.abs, two) {
                    (false, false) => panels_avx512::<false, 1, C>(a, p, q, v0, slab, dst),
                    (false, true) => panels_avx512::<false, 2, C>(a, p, q, v0, slab, dst),
                    (true, false) => panels_avx512::<true, 1, C>(a, p, q, v0, slab, dst),
                    (true, true) => panels_avx512::<true, 2, C>(a, p, q, v0, slab, dst),
                })
            }
        }
    }
}

/// Panels `p .. p + P`'s sums against a slab of `C` columns over all the part's live indices,
/// block by block, one register per panel and column, stored once.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
#[inline]
unsafe fn panels_avx512<const ABS: bool, const P: usize, const C: usize>(
    a: &PackedMatrix,
    p: usize,
    q: &Part<'_>,
    v0: usize,
    slab: &[f64],
    (out, stride, (i0, rows)): Dst<'_>,
) {
    use std::arch::x86_64::*;
    let live = q.live;
    let mut acc = [[_mm512_setzero_pd(); C]; P];
    for (b, at) in live_blocks(live) {
        let cols: [&[Column]; P] = std::array::from_fn(|h| a.block(b, p + h));
        let j0 = b * KB;
        let slab = &slab[at.start * C..at.end * C];
        for (&j, row) in live[at].iter().zip(slab.chunks_exact(C)) {
            let mut w = [_mm512_setzero_pd(); P];
            for h in 0..P {
                debug_assert!(j >= j0 && j - j0 < cols[h].len());
                // SAFETY: as in `block`; a column is 64-byte aligned.
                let col = _mm512_load_pd(cols[h].get_unchecked(j - j0).0.as_ptr());
                w[h] = if ABS { _mm512_abs_pd(col) } else { col };
            }
            for c in 0..C {
                let x = _mm512_set1_pd(row[c]);
                for h in 0..P {
                    acc[h][c] = _mm512_fmadd_pd(w[h], x, acc[h][c]);
                }
            }
        }
    }
    for h in 0..P {
        let mut sums = [[0.0; MR]; C];
        for c in 0..C {
            _mm512_storeu_pd(sums[c].as_mut_ptr(), acc[h][c]);
        }
        let dst = (&mut *out, stride, (i0 + h * MR, MR.min(rows - h * MR)));
        store(&sums, q, v0, dst);
    }
}

#[cfg(test)]
mod tests;

//! Products `A·B` with a fixed left factor (a layer's `W` or `|W|`) packed once, over a chosen
//! subset of the inner dimension.
//!
//! The forward bound method multiplies each weight matrix by thin panels (`2`–`3` columns a
//! face or box: 48–72 columns at the paper's 12 boxes), many times a second, skipping the rows
//! of the right factor that are zero (neurons inactive over every box). Through a general
//! GEMM that meant gathering the live columns of `W` and the GEMM packing them again on every
//! call, a quarter of the step's time; here `W` is packed once, in panels of [`MR`] rows with
//! the [`MR`] entries of each column contiguous, and the kernel walks the live inner indices
//! directly (no copy of either factor).
//!
//! Soundness does not depend on the kernel: the rounding model ([`crate::rounding`]) bounds the
//! error of any order of summation, with or without fused multiply–adds.
#![allow(clippy::needless_range_loop)] // index loops over registers read as the formulas

use std::sync::atomic::Ordering;

/// Rows of a panel: two AVX2 registers of f64.
const MR: usize = 8;
/// Columns of the right factor a kernel call keeps in registers (`MR × NR` accumulators).
const NR: usize = 6;
/// Live inner indices a chunk: a panel's chunk (8 KiB) and a slab's (6 KiB) stay in L1.
const KC: usize = 128;

/// An `m × k` matrix packed in panels of [`MR`] rows (the last one padded with zeros): panel
/// `p` holds, for each column `j`, rows `p·MR .. p·MR + MR` contiguously.
#[derive(Clone, Debug, Default)]
pub struct PackedMatrix {
    m: usize,
    k: usize,
    panels: Vec<Column>,
}

/// One column of a panel: [`MR`] entries on one 64-byte cache line (the allocator aligns a
/// `Vec<f64>` to 16 bytes only, so an unaligned column's second half split across two lines
/// on every load).
#[derive(Clone, Copy, Debug, Default)]
#[repr(C, align(64))]
struct Column([f64; MR]);

impl PackedMatrix {
    /// Packs the row-major `m × k` matrix `a`.
    pub fn new(m: usize, k: usize, a: &[f64]) -> PackedMatrix {
        assert!(a.len() >= m * k, "packed matrix: buffer too small");
        let n_panels = m.div_ceil(MR);
        let mut panels = vec![Column::default(); n_panels * k];
        for i in 0..m {
            let (p, r) = (i / MR, i % MR);
            for j in 0..k {
                panels[p * k + j].0[r] = a[i * k + j];
            }
        }
        PackedMatrix { m, k, panels }
    }

    /// Rows `m`.
    pub fn rows(&self) -> usize {
        self.m
    }

    /// Columns `k`.
    pub fn cols(&self) -> usize {
        self.k
    }

    /// `out[i·out_stride + c] = Σ_{j ∈ live} A[i][j] · b[j·b_stride + c]` for every row `i` and
    /// `c < n`: the product of `A` with the rows `live` of `b` (the other rows taken as zero).
    /// Every `j` in `live` must be `< k`. `scratch` holds the live rows of `b` packed in slabs
    /// of [`NR`] columns (each slab contiguous, so that it stays in L1 while a panel of `A`
    /// runs over it).
    ///
    /// Panics only on an internal shape bug (a slice shorter than its view).
    pub fn product(
        &self,
        live: &[usize],
        (b, b_stride): (&[f64], usize),
        n: usize,
        (out, out_stride): (&mut [f64], usize),
        scratch: &mut Vec<f64>,
    ) {
        if self.m == 0 || n == 0 {
            return;
        }
        assert!(
            live.iter()
                .all(|&j| j < self.k && j * b_stride + n <= b.len())
                && (self.m - 1) * out_stride + n <= out.len(),
            "packed product: shape bug"
        );
        super::MULTIPLY_ADDS.fetch_add((self.m * live.len() * n) as u64, Ordering::Relaxed);
        // Slab `s` (columns `s·NR ..`, the last one narrower): for each live row in order, its
        // entries of those columns.
        scratch.clear();
        for c0 in (0..n).step_by(NR) {
            let c1 = n.min(c0 + NR);
            for &j in live {
                scratch.extend_from_slice(&b[j * b_stride + c0..j * b_stride + c1]);
            }
        }
        let job = Job {
            a: self,
            live,
            slabs: scratch,
            n,
        };
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx2") && std::arch::is_x86_feature_detected!("fma")
        {
            // SAFETY: the CPU has the features the function is compiled for.
            unsafe { product_fma(&job, (out, out_stride)) };
            return;
        }
        product_body::<false>(&job, (out, out_stride));
    }
}

/// One product: the packed `A`, the live inner indices and the slabs of `B` over them.
struct Job<'a> {
    a: &'a PackedMatrix,
    live: &'a [usize],
    slabs: &'a [f64],
    n: usize,
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn product_fma(job: &Job<'_>, out: (&mut [f64], usize)) {
    product_body::<true>(job, out);
}

/// The product, in chunks of [`KC`] live inner indices (a panel's chunk, `KC·MR` entries,
/// stays in L1 while it runs over every slab's chunk), panel by panel and slab by slab; the
/// first chunk writes `out`, later ones add to it. `FMA` selects fused multiply–adds
/// (compiled where the CPU has them: `mul_add` is a library call elsewhere).
#[inline(always)]
fn product_body<const FMA: bool>(job: &Job<'_>, (out, out_stride): (&mut [f64], usize)) {
    let (a, live, n) = (job.a, job.live, job.n);
    let whole = n - n % NR;
    let chunks = live.len().div_ceil(KC).max(1);
    for chunk in 0..chunks {
        let (j0, j1) = (chunk * KC, live.len().min(chunk * KC + KC));
        let lv = &live[j0..j1];
        let add = chunk > 0;
        for p in 0..a.m.div_ceil(MR) {
            let panel = &a.panels[p * a.k..(p + 1) * a.k];
            let at = (p * MR, MR.min(a.m - p * MR));
            let mut c0 = 0;
            while c0 < whole {
                let slab = &job.slabs[c0 * live.len() + j0 * NR..c0 * live.len() + j1 * NR];
                let acc = block::<FMA, NR>(panel, lv, slab);
                store(&acc, out, out_stride, at, c0, add);
                c0 += NR;
            }
            let r = n - whole;
            let slab = &job.slabs[c0 * live.len() + j0 * r..c0 * live.len() + j1 * r];
            match r {
                0 => {}
                1 => store(
                    &block::<FMA, 1>(panel, lv, slab),
                    out,
                    out_stride,
                    at,
                    c0,
                    add,
                ),
                2 => store(
                    &block::<FMA, 2>(panel, lv, slab),
                    out,
                    out_stride,
                    at,
                    c0,
                    add,
                ),
                3 => store(
                    &block::<FMA, 3>(panel, lv, slab),
                    out,
                    out_stride,
                    at,
                    c0,
                    add,
                ),
                4 => store(
                    &block::<FMA, 4>(panel, lv, slab),
                    out,
                    out_stride,
                    at,
                    c0,
                    add,
                ),
                _ => store(
                    &block::<FMA, 5>(panel, lv, slab),
                    out,
                    out_stride,
                    at,
                    c0,
                    add,
                ),
            }
        }
    }
}

/// `MR × C` accumulators of one panel against a slab of `C` columns of the live rows.
#[inline(always)]
fn block<const FMA: bool, const C: usize>(
    panel: &[Column],
    live: &[usize],
    slab: &[f64],
) -> [[f64; MR]; C] {
    let mut acc = [[0.0; MR]; C];
    for (&j, row) in live.iter().zip(slab.chunks_exact(C)) {
        // SAFETY: `product` checked every live index against the panel's length.
        let col = unsafe { &panel.get_unchecked(j).0 };
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
    acc
}

/// Writes (or, with `add`, adds) the first `rows` rows of the accumulators to `out` at row
/// `i0`, column `c0`.
#[inline(always)]
fn store<const C: usize>(
    acc: &[[f64; MR]; C],
    out: &mut [f64],
    out_stride: usize,
    (i0, rows): (usize, usize),
    c0: usize,
    add: bool,
) {
    for r in 0..rows {
        let dst = &mut out[(i0 + r) * out_stride + c0..(i0 + r) * out_stride + c0 + C];
        for c in 0..C {
            dst[c] = if add { dst[c] + acc[c][r] } else { acc[c][r] };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Dyadic entries with small numerators: every product and sum is exact in f64, so the
    /// packed product must equal a triple loop over the live rows exactly, for shapes with
    /// partial panels and partial column blocks, strided operands, and both kernels.
    #[test]
    fn packed_products_equal_a_triple_loop_over_the_live_rows() {
        for &(m, k, n) in &[
            (1, 1, 1),
            (3, 5, 2),
            (8, 7, 6),
            (17, 33, 13),
            (64, 40, 48),
            (9, 300, 7),
        ] {
            let a: Vec<f64> = (0..m * k)
                .map(|i| ((i * 37 % 101) as f64 - 50.0) / 16.0)
                .collect();
            let b_stride = n + 3;
            let b: Vec<f64> = (0..k * b_stride)
                .map(|i| ((i * 53 % 97) as f64 - 48.0) / 8.0)
                .collect();
            let packed = PackedMatrix::new(m, k, &a);
            for live in [
                (0..k).collect::<Vec<_>>(),
                (0..k).step_by(3).collect(),
                vec![],
            ] {
                let out_stride = n + 2;
                let mut want = vec![-1.0; m * out_stride];
                for i in 0..m {
                    for c in 0..n {
                        want[i * out_stride + c] = live
                            .iter()
                            .map(|&j| a[i * k + j] * b[j * b_stride + c])
                            .sum();
                    }
                }
                let (mut got, mut scratch) = (vec![-1.0; m * out_stride], vec![]);
                let b_view = (&b[..], b_stride);
                packed.product(&live, b_view, n, (&mut got, out_stride), &mut scratch);
                assert_eq!(got, want, "{m}×{k}×{n}, {} live", live.len());
                let job = Job {
                    a: &packed,
                    live: &live,
                    slabs: &scratch,
                    n,
                };
                let mut plain = vec![-1.0; m * out_stride];
                product_body::<false>(&job, (&mut plain, out_stride));
                assert_eq!(plain, want, "{m}×{k}×{n} without FMA");
            }
        }
    }
}

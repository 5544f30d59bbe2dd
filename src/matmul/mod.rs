//! Matrix products `C = A·B`, the one kernel every hot loop of cbfreach runs on (network bounds,
//! training, the benchmark's peak rate).
//!
//! Backed by the `gemm` crate, which picks AVX-512, AVX2+FMA or portable kernels at run time.
//! On the 2-core AVX-512 machine cbfreach is developed on it ran the shapes of the bound methods
//! (`400×400` times `400×18 … 400×768`) 1.3–1.7× faster in f64 and 1.3–1.8× faster in f32 than
//! `matrixmultiply`, the crate used before.
//!
//! Soundness does not depend on the kernel: the rounding model of [`crate::rounding`] bounds the
//! error of *any* order of summation, with or without fused multiply–adds.

use std::sync::atomic::{AtomicU64, Ordering};

mod packed;
pub use packed::{PackedMatrix, Part};

use gemm::Parallelism;

/// Multiply–adds of every product since the process started (`m·k·n` each): what a benchmark
/// divides by its time for the rate actually run, not a model's.
static MULTIPLY_ADDS: AtomicU64 = AtomicU64::new(0);

/// The multiply–adds [`matmul_strided`] has run in this process, all threads together.
pub fn multiply_adds() -> u64 {
    MULTIPLY_ADDS.load(Ordering::Relaxed)
}

/// Element types with a matrix product: `f32` and `f64`.
pub trait MatmulScalar: Copy + Send + Sync + 'static {
    /// Zero of the type.
    const ZERO: Self;
    /// One of the type.
    const ONE: Self;
}

impl MatmulScalar for f32 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
}

impl MatmulScalar for f64 {
    const ZERO: Self = 0.0;
    const ONE: Self = 1.0;
}

/// Row and column strides `(rs, cs)` of a matrix view: element `(i, j)` is at `i·rs + j·cs`.
pub type Strides = (usize, usize);

/// Whether one product may use several threads (rayon's pool). The bound methods run one
/// product per rayon task already and ask for [`Threads::One`].
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Threads {
    /// Single-threaded.
    One,
    /// Rayon's current pool.
    Pool,
}

/// Smallest buffer length that holds an `rows × cols` view with these strides.
fn needed(rows: usize, cols: usize, (rs, cs): Strides) -> usize {
    if rows == 0 || cols == 0 {
        0
    } else {
        (rows - 1) * rs + (cols - 1) * cs + 1
    }
}

/// `C = A·B` for strided views `A: m×k`, `B: k×n`, `C: m×n`.
///
/// Panics only on an internal shape bug (a slice shorter than its view), never on user input:
/// every caller derives the shapes from a validated network.
#[allow(clippy::too_many_arguments)]
pub fn matmul_strided<T: MatmulScalar>(
    (m, k, n): (usize, usize, usize),
    a: &[T],
    sa: Strides,
    b: &[T],
    sb: Strides,
    c: &mut [T],
    sc: Strides,
    threads: Threads,
) {
    assert!(
        a.len() >= needed(m, k, sa) && b.len() >= needed(k, n, sb) && c.len() >= needed(m, n, sc),
        "matmul buffer too small"
    );
    if m == 0 || n == 0 {
        return;
    }
    MULTIPLY_ADDS.fetch_add((m * k * n) as u64, Ordering::Relaxed);
    if k == 0 {
        for i in 0..m {
            for j in 0..n {
                c[i * sc.0 + j * sc.1] = T::ZERO;
            }
        }
        return;
    }
    let parallelism = match threads {
        Threads::One => Parallelism::None,
        Threads::Pool => Parallelism::Rayon(0),
    };
    // SAFETY: the assertion above keeps every strided access inside the three slices; `c` is
    // exclusively borrowed, so it aliases neither `a` nor `b`. `read_dst = false` with
    // `alpha = 0` makes `C = 1·A·B` whatever `C` held (gemm's `alpha` scales the old `C`,
    // its `beta` the product). `T` is f32 or f64, both of which gemm implements.
    unsafe {
        gemm::gemm(
            m,
            n,
            k,
            c.as_mut_ptr(),
            sc.1 as isize,
            sc.0 as isize,
            false,
            a.as_ptr(),
            sa.1 as isize,
            sa.0 as isize,
            b.as_ptr(),
            sb.1 as isize,
            sb.0 as isize,
            T::ZERO,
            T::ONE,
            false,
            false,
            false,
            parallelism,
        );
    }
}

/// `C = A·B` for row-major contiguous `A (m×k)`, `B (k×n)`, `C (m×n)`.
pub fn matmul<T: MatmulScalar>(
    (m, k, n): (usize, usize, usize),
    a: &[T],
    b: &[T],
    c: &mut [T],
    threads: Threads,
) {
    matmul_strided((m, k, n), a, (k, 1), b, (n, 1), c, (n, 1), threads);
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Plain triple loop in f64, the reference.
    fn naive(m: usize, k: usize, n: usize, a: &[f64], sa: Strides, b: &[f64]) -> Vec<f64> {
        let mut c = vec![0.0; m * n];
        for i in 0..m {
            for j in 0..n {
                c[i * n + j] = (0..k).map(|p| a[i * sa.0 + p * sa.1] * b[p * n + j]).sum();
            }
        }
        c
    }

    #[test]
    fn products_match_a_triple_loop_in_both_precisions_and_layouts() {
        for &(m, k, n) in &[(1, 1, 1), (3, 5, 2), (17, 33, 9), (64, 130, 70)] {
            let a: Vec<f64> = (0..m * k)
                .map(|i| ((i * 37 % 101) as f64 - 50.0) / 16.0)
                .collect();
            let b: Vec<f64> = (0..k * n)
                .map(|i| ((i * 53 % 97) as f64 - 48.0) / 8.0)
                .collect();
            // Dyadic entries with small numerators: every product and sum is exact in f64.
            let want = naive(m, k, n, &a, (k, 1), &b);
            for threads in [Threads::One, Threads::Pool] {
                let mut c = vec![f64::NAN; m * n];
                matmul((m, k, n), &a, &b, &mut c, threads);
                assert_eq!(c, want, "{m}×{k}×{n} f64 {threads:?}");
                let (a32, b32): (Vec<f32>, Vec<f32>) = (
                    a.iter().map(|&x| x as f32).collect(),
                    b.iter().map(|&x| x as f32).collect(),
                );
                let mut c32 = vec![f32::NAN; m * n];
                matmul((m, k, n), &a32, &b32, &mut c32, threads);
                for (x, y) in c32.iter().zip(&want) {
                    assert!(
                        (*x as f64 - y).abs() <= 1e-6 * (1.0 + y.abs()),
                        "{m}×{k}×{n} f32"
                    );
                }
            }
            // A transposed view of the same A (column-major storage).
            let at: Vec<f64> = (0..k * m).map(|i| a[(i % m) * k + i / m]).collect();
            let mut c = vec![f64::NAN; m * n];
            matmul_strided(
                (m, k, n),
                &at,
                (1, m),
                &b,
                (n, 1),
                &mut c,
                (n, 1),
                Threads::One,
            );
            assert_eq!(c, want, "{m}×{k}×{n} transposed A");
        }
    }

    #[test]
    fn empty_inner_dimension_gives_zeros() {
        let mut c = vec![7.0f64; 6];
        matmul((2, 0, 3), &[], &[], &mut c, Threads::One);
        assert_eq!(c, vec![0.0; 6]);
    }
}

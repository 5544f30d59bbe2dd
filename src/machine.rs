//! What the machine can do and what a process has used of it: the f64 floating-point limit of
//! the cores (what `cbfreach bench` divides by) and the process's CPU time (so that a rate on
//! a machine shared with other work can be stated per CPU-second, not only per wall-second).

use std::hint::black_box;
use std::time::Instant;

/// Independent accumulator chains of the limit loop: enough to cover the FMA latency of
/// current x86 cores (4–5 cycles, two pipes).
const CHAINS: usize = 12;

/// The vector instructions the hand-written kernels (`matmul::PackedMatrix`, the forward
/// method's relaxation) run on: each has a path per kind, chosen at run time, since the
/// binary is built for baseline x86-64 and CI machines may lack AVX-512 or even AVX2.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Isa {
    /// Portable code (SSE2 on x86-64).
    Scalar,
    /// Four f64 lanes with fused multiply–adds (AVX2 and FMA).
    Avx2,
    /// Eight f64 lanes (AVX-512 F; it implies AVX2 and FMA).
    Avx512,
}

impl Isa {
    /// The widest kind this CPU has (std caches the CPUID answer: cheap per call).
    pub fn detect() -> Isa {
        [Isa::Avx512, Isa::Avx2]
            .into_iter()
            .find(|isa| isa.available())
            .unwrap_or(Isa::Scalar)
    }

    /// Whether this CPU runs this kind's code.
    pub fn available(self) -> bool {
        match self {
            Isa::Scalar => true,
            #[cfg(target_arch = "x86_64")]
            Isa::Avx2 => {
                std::arch::is_x86_feature_detected!("avx2")
                    && std::arch::is_x86_feature_detected!("fma")
            }
            #[cfg(target_arch = "x86_64")]
            Isa::Avx512 => std::arch::is_x86_feature_detected!("avx512f"),
            #[cfg(not(target_arch = "x86_64"))]
            _ => false,
        }
    }

    /// f64 lanes of one of its registers.
    pub fn lanes(self) -> usize {
        match self {
            Isa::Scalar => 1,
            Isa::Avx2 => 4,
            Isa::Avx512 => 8,
        }
    }

    /// `"AVX-512"`, `"AVX2"` or `"scalar"`.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Scalar => "scalar",
            Isa::Avx2 => "AVX2",
            Isa::Avx512 => "AVX-512",
        }
    }
}

/// The widest fused multiply–add [`f64_limit_gflops`] measures on this CPU: `"AVX-512"`,
/// `"AVX2"` or `"scalar"` ([`Isa::detect`]).
pub fn f64_limit_isa() -> &'static str {
    Isa::detect().name()
}

/// The cores' f64 limit in GFLOP/s: fused multiply–adds on independent registers (no memory
/// traffic) on every rayon thread at once, each thread timing its own short rounds and keeping
/// its best (a round that other work on the machine interrupted, or a thread that started
/// late, does not count); the threads' rates summed. On x86-64 that is `threads × FMA pipes ×
/// lanes × 2 FLOP × clock` with the widest registers the CPU has ([`f64_limit_isa`]: 8 lanes
/// with AVX-512, whose two pipes on server cores double AVX2's limit, 4 with AVX2), the ceiling
/// no matrix product can pass; elsewhere a scalar loop, a lower bound of the limit.
pub fn f64_limit_gflops() -> f64 {
    use rayon::prelude::*;
    let threads = rayon::current_num_threads().max(1);
    let iters = 20_000;
    let isa = Isa::detect();
    let flops = (iters * CHAINS * isa.lanes() * 2) as f64;
    let per_thread: Vec<f64> = (0..threads)
        .into_par_iter()
        .map(|_| {
            let mut best = f64::INFINITY;
            for _ in 0..60 {
                let start = Instant::now();
                black_box(fma_loop(isa, iters));
                best = best.min(start.elapsed().as_secs_f64());
            }
            flops / best / 1e9
        })
        .collect();
    per_thread.iter().sum()
}

/// The limit loop on `isa`'s registers (the lanes counted are the ones run).
fn fma_loop(isa: Isa, iters: usize) -> f64 {
    match isa {
        // SAFETY: `isa` is what `Isa::detect` found, so the CPU has the features the functions
        // are compiled for.
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { fma_loop_avx512(iters) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { fma_loop_avx2(iters) },
        _ => {
            let (x, y) = (black_box(0.999_999_9), black_box(1e-9));
            let mut acc = [1.0f64; CHAINS];
            for _ in 0..iters {
                for a in acc.iter_mut() {
                    *a = a.mul_add(x, y);
                }
            }
            acc.iter().sum()
        }
    }
}

/// [`CHAINS`] independent AVX2 registers, each `acc ← acc·x + y` per iteration (written with
/// intrinsics: the compiler does not vectorise the plain loop's chains).
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn fma_loop_avx2(iters: usize) -> f64 {
    use std::arch::x86_64::*;
    let x = _mm256_set1_pd(black_box(0.999_999_9));
    let y = _mm256_set1_pd(black_box(1e-9));
    let mut acc = [_mm256_set1_pd(1.0); CHAINS];
    for _ in 0..iters {
        for a in acc.iter_mut() {
            *a = _mm256_fmadd_pd(*a, x, y);
        }
    }
    let mut lanes = [0.0; 4];
    let sum = acc
        .iter()
        .fold(_mm256_setzero_pd(), |s, &a| _mm256_add_pd(s, a));
    _mm256_storeu_pd(lanes.as_mut_ptr(), sum);
    lanes.iter().sum()
}

/// [`fma_loop_avx2`] on AVX-512 registers.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn fma_loop_avx512(iters: usize) -> f64 {
    use std::arch::x86_64::*;
    let x = _mm512_set1_pd(black_box(0.999_999_9));
    let y = _mm512_set1_pd(black_box(1e-9));
    let mut acc = [_mm512_set1_pd(1.0); CHAINS];
    for _ in 0..iters {
        for a in acc.iter_mut() {
            *a = _mm512_fmadd_pd(*a, x, y);
        }
    }
    let sum = acc
        .iter()
        .fold(_mm512_setzero_pd(), |s, &a| _mm512_add_pd(s, a));
    _mm512_reduce_add_pd(sum)
}

/// User plus system CPU time of this process so far, all threads, in seconds (`getrusage`);
/// `None` where it cannot be read.
pub fn process_cpu_seconds() -> Option<f64> {
    // SAFETY: `getrusage` writes only into the zeroed struct it is given.
    let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
    if unsafe { libc::getrusage(libc::RUSAGE_SELF, &mut usage) } != 0 {
        return None;
    }
    let secs = |t: libc::timeval| t.tv_sec as f64 + t.tv_usec as f64 * 1e-6;
    Some(secs(usage.ru_utime) + secs(usage.ru_stime))
}

#[cfg(test)]
mod tests {
    /// The limit is a positive finite rate, and CPU time only grows.
    #[test]
    fn limit_and_cpu_time_are_sane() {
        let limit = super::f64_limit_gflops();
        assert!(limit.is_finite() && limit > 0.1, "{limit}");
        let a = super::process_cpu_seconds().unwrap();
        let b = super::process_cpu_seconds().unwrap();
        assert!(a > 0.0 && b >= a);
    }
}

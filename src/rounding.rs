//! Outward-rounding primitives on `f64` (one-ulp steps, sums, quotients, powers, libm values,
//! dot-product error bounds) and the rounding model they implement. Imports nothing of the crate.
//!
//! # Rounding model (docs/design.md §3)
//!
//! [`crate::intervals`], [`crate::bounds`] and the CPU engine round with these primitives; the
//! rounding of host numbers to device numbers (f32, flushed subnormals) is the GPU module's.
//!
//! The CPU computes in IEEE 754 binary64 with round-to-nearest. A bound is *outward rounded*
//! when the number returned bounds the exact real result, not just the computed one:
//!
//! * **Single operations.** `+ − × ÷ √` are correctly rounded, so the exact result lies within
//!   half an ulp of the computed `x`: `round_down(x) ≤ exact ≤ round_up(x)` (one step through the
//!   bit pattern, [`round_down`] / [`round_up`]). [`add_down`] / [`add_up`] take that step after
//!   every sum; [`add_down_tight`] / [`add_up_tight`] keep the computed sum when TwoSum shows it
//!   is already on the right side (exact sums stay exact); [`div_down`] / [`div_up`] keep a
//!   quotient whose FMA residual is 0. `round_up_keep_zero` keeps a 0 that can only be exact.
//! * **libm.** `exp ln sin cos tanh` are not correctly rounded (glibc states ≤ 1–2 ulp): their
//!   values move outward by a relative `2⁻⁵⁰` (≥ 4 ulp) plus the smallest normal number, then one
//!   more step (`widen_down`, `widen_up`).
//! * **Powers.** `x^m` by repeated squaring with every product rounded outward (`pow_down`,
//!   `pow_up`); [`pow_int`] is the same chain rounded to nearest, so it lies between them.
//! * **Dot products, f64** (Higham, *Accuracy and Stability*, §3.1). If `ŝ` is `Σ_{j≤N} t_j`
//!   computed in any order, each term `t_j` a product of at most three floats (two roundings),
//!   with or without FMA, then `|ŝ − Σ t_j| ≤ γ_{N+2} Σ|t_j| + N·3·η` with
//!   `γ_k = k u / (1 − k u)`, `u = 2⁻⁵³`, and `η = 2⁻¹⁰⁷⁵` the absolute error of an underflowing
//!   product. The magnitude sum `m̂ ≈ Σ|t_j|` is computed alongside (for a GEMM it is `|W|·|X|`);
//!   `m̂` is itself a sum of non-negative rounded terms, so `Σ|t_j| ≤ m̂ / (1 − γ_{N+2})`. Hence,
//!   for `N ≤ 2³⁰`, `|ŝ − Σ t_j| ≤ γ̂_N m̂ + N·2⁻¹⁰⁷²` with `γ̂_N = (N+3)·2⁻⁵²` (twice
//!   `γ_{N+3}`, which covers both `1/(1−γ)` factors). The CPU takes `γ̂_N = (N+3)·2⁻⁵⁰`
//!   ([`GAMMA_UNIT`]), four times that: the GPU's f64 unit (its devices may round towards
//!   zero), so that both engines bound every sum by the same amount and their f64 sets agree
//!   to ~10⁻¹⁴ a step instead of ~10⁻¹² (`tests/gpu_parity.rs` holds them to 10⁻¹⁰), at a cost
//!   of `3(N+3)·2⁻⁵²` of a sum's magnitude (~3·10⁻¹³ of it for a 400-wide layer).
//!   `err_bound` evaluates that bound, with the underflow part taken as `N·2⁻¹⁰²²` (a normal
//!   number: subnormal arithmetic is slow), and rounds it up. When the computed numbers are
//!   *coefficients* later multiplied by variables bounded by `mag`, the absolute (underflow)
//!   part is scaled by `1 + Σ mag`; relative errors are already carried through the magnitude
//!   sums. A widened bound is
//!   `add_up(ŝ, err_bound(N, m̂, scale))` or `add_down(ŝ, −err_bound(N, m̂, scale))`
//!   (`affine_max`, `affine_min`).
//! * **Dot products, f32 (the GPU engine).** The same bound with the device's unit: `u = 2⁻²³`,
//!   `γ̂_N = (N+3)·2⁻²¹`, an absolute part for flushed subnormals, and one step outward per
//!   operation. The device code holds it (the GPU module's "Error model", `err_bound` in
//!   `shaders/common.wgsl`, the preludes `shaders/real_f32.wgsl` and `real_f64.wgsl`); it
//!   mirrors this module and is checked against it by `tests/gpu_matches_cpu/`.

/// Relative widening of libm results: `2⁻⁵⁰`, at least 4 ulp of the result.
const LIBM_REL: f64 = 4.0 * f64::EPSILON;

/// The next `f64` above `x` (`f64::next_up`, spelled out for the crate's MSRV 1.85; `x` itself
/// for `+∞` and NaN): an upper bound for the exact result of a correctly rounded operation whose
/// computed result is `x`.
#[inline]
pub fn round_up(x: f64) -> f64 {
    if x.is_nan() || x == f64::INFINITY {
        return x;
    }
    if x == 0.0 {
        return f64::from_bits(1); // the smallest subnormal
    }
    let bits = x.to_bits();
    f64::from_bits(if x > 0.0 { bits + 1 } else { bits - 1 })
}

/// The next `f64` below `x` (`f64::next_down`): a lower bound for the exact result of a
/// correctly rounded operation whose computed result is `x`.
#[inline]
pub fn round_down(x: f64) -> f64 {
    -round_up(-x)
}

/// `round_up(x)` for a computed difference `x = fl(a − b)` of floats `a ≥ b`, or a computed sum
/// of non-negative floats, except that 0 stays 0. With gradual underflow such an `x` is 0 only
/// when the exact result is, so 0 needs no widening; `round_up(0)` would be a subnormal, and
/// every product with a subnormal costs a ~100-cycle microcode assist on x86 (the flat
/// coordinate of a face box, the IBP radius of a dead neuron).
#[inline]
pub fn round_up_keep_zero(x: f64) -> f64 {
    if x == 0.0 {
        0.0
    } else {
        round_up(x)
    }
}

/// An upper bound of the real `a + b`: the computed sum one step up.
#[inline]
pub fn add_up(a: f64, b: f64) -> f64 {
    round_up(a + b)
}

/// A lower bound of the real `a + b`: the computed sum one step down.
#[inline]
pub fn add_down(a: f64, b: f64) -> f64 {
    round_down(a + b)
}

/// The rounding error `(a + b) − s` of the computed sum `s = a + b` (Knuth's TwoSum: exact
/// under round-to-nearest when `s` is finite).
fn sum_error(a: f64, b: f64, s: f64) -> f64 {
    let bb = s - a;
    (a - (s - bb)) + (b - bb)
}

/// A lower bound of the exact `a + b`: the computed sum itself when TwoSum shows that it is not
/// above the exact one (exact sums such as `x₂ − x₂,min = 0` stay exact), else one ulp below
/// (also near overflow, where TwoSum's own steps could overflow).
pub fn add_down_tight(a: f64, b: f64) -> f64 {
    let s = a + b;
    if s.is_finite() && a.abs().max(b.abs()) < 1e300 && sum_error(a, b, s) >= 0.0 {
        s
    } else {
        round_down(s)
    }
}

/// An upper bound of the exact `a + b` (see [`add_down_tight`]).
pub fn add_up_tight(a: f64, b: f64) -> f64 {
    let s = a + b;
    if s.is_finite() && a.abs().max(b.abs()) < 1e300 && sum_error(a, b, s) <= 0.0 {
        s
    } else {
        round_up(s)
    }
}

/// A lower bound for `a / b` (finite `a`, `b ≠ 0`): the rounded quotient itself when the
/// division was exact (its residual `q·b − a`, exact under FMA away from underflow, is 0), else
/// the next number below.
pub fn div_down(a: f64, b: f64) -> f64 {
    let q = a / b;
    if q.is_finite() && q.abs() >= f64::MIN_POSITIVE && q.mul_add(b, -a) == 0.0 {
        q
    } else {
        round_down(q)
    }
}

/// An upper bound for `a / b`, as [`div_down`].
pub fn div_up(a: f64, b: f64) -> f64 {
    -div_down(-a, b)
}

/// A lower bound for the exact value of a libm function whose computed value is `x`.
pub fn widen_down(x: f64) -> f64 {
    if x.is_nan() || x == f64::NEG_INFINITY {
        return x;
    }
    let x = x.min(f64::MAX);
    round_down(x - (x.abs() * LIBM_REL + f64::MIN_POSITIVE))
}

/// An upper bound for the exact value of a libm function whose computed value is `x`.
pub fn widen_up(x: f64) -> f64 {
    -widen_down(-x)
}

/// `x` to the power `m ≥ 1` by repeated squaring, with `round` applied after every product.
fn pow_chain(x: f64, mut m: u32, round: impl Fn(f64) -> f64) -> f64 {
    let mut base = x;
    let mut acc: Option<f64> = None;
    loop {
        if m & 1 == 1 {
            acc = Some(acc.map_or(base, |a| round(a * base)));
        }
        m >>= 1;
        if m == 0 {
            return acc.unwrap_or(1.0);
        }
        base = round(base * base);
    }
}

/// Lower bound of `a^m` for `a ≥ 0`.
pub fn pow_down(a: f64, m: u32) -> f64 {
    pow_chain(a, m, |v| round_down(v).max(0.0))
}

/// Upper bound of `a^m` for `a ≥ 0`.
pub fn pow_up(a: f64, m: u32) -> f64 {
    pow_chain(a, m, round_up)
}

/// `x^n` for a point, by the same products as [`crate::intervals::Interval::powi`] rounded to
/// nearest, so that `Interval::point(x).powi(n)` always contains it. `x^0 = 1` for every `x`.
pub fn pow_int(x: f64, n: i32) -> f64 {
    let p = pow_chain(x, n.unsigned_abs(), |v| v);
    if n >= 0 {
        p
    } else {
        1.0 / p
    }
}

/// The unit of [`gamma_hat`]: `2⁻⁵⁰`, the GPU's f64 `GAMMA_UNIT` (`shaders/real_f64.wgsl`),
/// four times what round-to-nearest needs (module documentation: one rounding model for both
/// engines).
pub const GAMMA_UNIT: f64 = 4.0 * f64::EPSILON;

/// `γ̂_N = (N + 3)·2⁻⁵⁰`, exact in f64 (module documentation).
#[inline]
pub fn gamma_hat(n_terms: usize) -> f64 {
    (n_terms as f64 + 3.0) * GAMMA_UNIT
}

/// Rigorous bound on the rounding error of a computed sum of `n_terms` products of at most three
/// floats whose computed magnitude sum is `magnitude`: `γ̂_N·m̂ + N·2⁻¹⁰²²·scale`, rounded up.
///
/// `scale ≥ 1` bounds what an underflowing coefficient is later multiplied by (`1` for a plain
/// sum; `1 + Σ mag` when the computed numbers are coefficients of variables bounded by `mag`):
/// each underflowing product errs by at most `2⁻¹⁰⁷⁵` absolutely, at most 8 per term, so
/// `N·2⁻¹⁰⁷²·scale` would do. The term is taken 2⁵⁰ times larger, `N·2⁻¹⁰²²·scale`, because
/// that is a normal number: arithmetic on subnormals takes a microcode assist of ~100 cycles on
/// x86, and this one product was a quarter of the forward method's time.
#[inline]
pub fn err_bound(n_terms: usize, magnitude: f64, scale: f64) -> f64 {
    // `N·2⁻¹⁰²²` is exact (N < 2⁵³); the product with `scale ≥ 1` is normal, and rounding it to
    // nearest loses at most a factor 1 − 2⁻⁵³ of a term 2⁵⁰ times larger than needed.
    let underflow = n_terms as f64 * f64::MIN_POSITIVE * scale;
    round_up(round_up(gamma_hat(n_terms) * magnitude) + underflow)
}

/// A rigorous upper bound of `max_{x∈[lo,hi]} w·x + b`; `mag[p] ≥ max(|lo[p]|, |hi[p]|)`.
#[inline]
pub fn affine_max(w: &[f64], b: f64, lo: &[f64], hi: &[f64], mag: &[f64]) -> f64 {
    let (mut s, mut m) = (b, b.abs());
    for p in 0..w.len() {
        let wp = w[p];
        s += if wp >= 0.0 { wp * hi[p] } else { wp * lo[p] };
        m += wp.abs() * mag[p];
    }
    add_up(s, err_bound(w.len() + 1, m, 1.0))
}

/// A rigorous lower bound of `min_{x∈[lo,hi]} w·x + b`; `mag[p] ≥ max(|lo[p]|, |hi[p]|)`.
#[inline]
pub fn affine_min(w: &[f64], b: f64, lo: &[f64], hi: &[f64], mag: &[f64]) -> f64 {
    let (mut s, mut m) = (b, b.abs());
    for p in 0..w.len() {
        let wp = w[p];
        s += if wp >= 0.0 { wp * lo[p] } else { wp * hi[p] };
        m += wp.abs() * mag[p];
    }
    add_down(s, -err_bound(w.len() + 1, m, 1.0))
}

/// `max(|lo|, |hi|)` per coordinate (exact), into `mag`.
pub fn magnitudes(lo: &[f64], hi: &[f64], mag: &mut Vec<f64>) {
    mag.clear();
    mag.extend(lo.iter().zip(hi).map(|(l, h)| l.abs().max(h.abs())));
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn rounding_steps_one_ulp() {
        assert_eq!(round_up(1.0), 1.0 + f64::EPSILON);
        assert_eq!(round_down(1.0), 1.0 - f64::EPSILON / 2.0);
        assert_eq!(round_up(0.0), f64::from_bits(1));
        assert_eq!(round_up(-0.0), f64::from_bits(1));
        assert_eq!(round_down(0.0), -f64::from_bits(1));
        assert_eq!(round_up(-f64::from_bits(1)), 0.0);
        assert_eq!(round_up(f64::MAX), f64::INFINITY);
        assert_eq!(round_up(f64::NEG_INFINITY), -f64::MAX);
        assert_eq!(round_down(f64::INFINITY), f64::MAX);
        assert_eq!(round_up(f64::INFINITY), f64::INFINITY);
        assert_eq!(round_down(f64::NEG_INFINITY), f64::NEG_INFINITY);
        assert!(round_up(f64::NAN).is_nan());
        assert!(round_down(f64::NAN).is_nan());
        assert_eq!(round_up_keep_zero(0.0), 0.0);
        assert_eq!(round_up_keep_zero(1.0), round_up(1.0));
    }

    #[test]
    fn quotients_are_bounded_and_exact_ones_kept() {
        // Exact quotients stay themselves (what keeps `x₂ ≥ −2` at −2 in reach::safe_set).
        assert_eq!((div_down(-2.0, 1.0), div_up(-2.0, 1.0)), (-2.0, -2.0));
        assert_eq!((div_down(3.0, -4.0), div_up(3.0, -4.0)), (-0.75, -0.75));
        // Inexact ones straddle the real quotient: by the exact FMA residual's sign,
        // lo·b ≤ a ≤ hi·b for b > 0 (reversed for b < 0), and they differ by one step.
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        for _ in 0..20_000 {
            let a: f64 = rng.random_range(-1e3..1e3);
            let b: f64 =
                rng.random_range(0.1..10.0) * if rng.random::<bool>() { 1.0 } else { -1.0 };
            let (lo, hi) = (div_down(a, b), div_up(a, b));
            assert!(
                lo <= hi && hi <= round_up(round_up(lo)),
                "{a}/{b}: [{lo}, {hi}]"
            );
            let (rl, rh) = (lo.mul_add(b, -a), hi.mul_add(b, -a));
            if b > 0.0 {
                assert!(rl <= 0.0 && rh >= 0.0, "{a}/{b}: [{lo}, {hi}]");
            } else {
                assert!(rl >= 0.0 && rh <= 0.0, "{a}/{b}: [{lo}, {hi}]");
            }
        }
    }
}

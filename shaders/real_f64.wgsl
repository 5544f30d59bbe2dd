// Precision prelude, f64 (`--f64`, wgpu::Features::SHADER_F64; src/gpu/mod.rs, "Error model").
// Assumes IEEE-754 f64 `+ − ×` (correctly rounded; Vulkan itself promises f64 only single
// precision, but lavapipe, NVIDIA and AMD are IEEE), and widens by one ulp, u = 2⁻⁵² relative
// (2⁻⁵³ is the round-to-nearest unit; one ulp also covers rounding towards zero).
alias real = f64;

// u = 2⁻⁵², one ulp relative.
const EPS: real = 2.220446049250313e-16lf;
// γ̂_n = (n + 3)·GAMMA_UNIT = 4(n + 3)u ≥ 2γ_{n+3} (err_bound).
const GAMMA_UNIT: real = 8.881784197001252e-16lf;
// The device's copy of the network is the host's f64, exactly (common.wgsl: conversion_error).
const WEIGHTS_ROUNDED: bool = false;
const HUGE: real = 1.0e300lf;
const MIN_NORMAL: real = 2.2250738585072014e-308lf;
const TINY_SLOPE: real = 1.0e-290lf;

// An upper bound of the exact result x̃ of one rounded operation whose computed value is x
// (|x − x̃| ≤ ulp(x)). WGSL has no 64-bit integers to step through the bit pattern, so the
// step is arithmetic: δ = max(|x|·2⁻⁵⁰, MIN_NORMAL) ≥ 4 ulp(x) (exact: a power-of-two scaling,
// or the smallest normal number where that would underflow), and fl(x + δ) ≥ x + δ − ulp(x)
// ≥ x + 3 ulp(x) under either rounding mode (for x < 0 the sum moves towards zero, where the
// spacing is no larger). Values below MIN_NORMAL (perhaps flushed) step to MIN_NORMAL.
fn up(x: real) -> real {
    if (abs(x) < MIN_NORMAL) {
        return MIN_NORMAL;
    }
    return x + max(abs(x) * 8.881784197001252e-16lf, MIN_NORMAL);
}

// Transcendental built-ins are evaluated in f32 (SPIR-V's GLSL.std.450 has them for 16- and
// 32-bit floats only) at an argument on the safe side: to32_up(x) ≥ x, to32_down(x) ≤ x for
// |x| ≤ 1e37 (callers check the range; one f32 ulp outward after the conversion's rounding).
fn to32_up(x: real) -> f32 {
    return up32(f32(clamp(x, -1.0e37lf, 1.0e37lf)));
}

fn to32_down(x: real) -> f32 {
    return down32(f32(clamp(x, -1.0e37lf, 1.0e37lf)));
}

fn from32(x: f32) -> real {
    return f64(x);
}

// sin, cos for |m| ≤ 3 (iv_trig checks), in f64 arithmetic: the Taylor polynomials of degree
// 27 and 26 in nested form, sin m = m(1 − m²/(2·3)(1 − m²/(4·5)(…))), cos m = 1 − m²/(1·2)(…),
// with the reciprocals as correctly rounded literals (no division). Truncation ≤ 3²⁹/29! and
// 3²⁸/28! (< 1e-16); rounding ≤ ~100 u Σ|terms| ≤ 100·2⁻⁵²·cosh 3 < 3e-13. TRIG_ERR covers both
// with a margin of 30.
const TRIG_ERR: real = 1.0e-11lf;
var<private> SIN_R: array<f64, 13> = array<f64, 13>(0.16666666666666666lf, 0.05lf, 0.023809523809523808lf, 0.013888888888888888lf, 0.00909090909090909lf, 0.00641025641025641lf, 0.004761904761904762lf, 0.003676470588235294lf, 0.0029239766081871343lf, 0.002380952380952381lf, 0.001976284584980237lf, 0.0016666666666666668lf, 0.0014245014245014246lf);
var<private> COS_R: array<f64, 13> = array<f64, 13>(0.5lf, 0.08333333333333333lf, 0.03333333333333333lf, 0.017857142857142856lf, 0.011111111111111112lf, 0.007575757575757576lf, 0.005494505494505495lf, 0.004166666666666667lf, 0.0032679738562091504lf, 0.002631578947368421lf, 0.0021645021645021645lf, 0.0018115942028985507lf, 0.0015384615384615385lf);

fn trig(m: real, is_cos: bool) -> real {
    let z = m * m;
    var s: real = 1.0;
    for (var k = 12i; k >= 0i; k--) {
        if (is_cos) {
            s = 1.0 - z * COS_R[k] * s;
        } else {
            s = 1.0 - z * SIN_R[k] * s;
        }
    }
    if (is_cos) {
        return s;
    }
    return m * s;
}

// exp in f64 arithmetic (src/gpu/exp64.rs mirrors it operation for operation, and a test
// compares the two on the device). For |x| ≤ 80: x = k ln 2 + r with k = round(x/ln 2) taken in
// f32 (any integer is sound; near keeps |r| ≤ ln 2/2 + 2e-5 < EXP_R_MAX), r enclosed in
// [r̲, r̄] from ln 2 ∈ [EXP_LN2_LO, EXP_LN2_HI] with outward steps; e^r by the Taylor polynomial
// of degree 13 in nested form, e^r = 1 + r(1 + r/2(1 + r/3(…))), with the reciprocals 1/j as
// correctly rounded literals. On |r| ≤ 0.35 the truncation is ≤ 0.35¹⁴/14!·e^0.35 < 1e-17 and
// the rounding ≤ Σ_j 4u·(0.35)^j·e^0.35/(1 − 0.35) < 3e-15 (each level's three roundings, or two
// with a fused multiply–add, damped by |r|/j ≤ 0.35 on the way out); EXP_POLY_ERR = 1e-14
// covers both. e^r is increasing, so p(r̲) − ERR ≤ e^x·2^-k ≤ p(r̄) + ERR, and 2^k scales both
// exactly (a power of two, built by squaring; 2^-116·0.7 is normal).
const EXP_LN2_LO: real = 0.6931471805599453lf;
const EXP_LN2_HI: real = 0.6931471805599454lf;
const EXP_R_MAX: real = 0.35lf;
const EXP_POLY_ERR: real = 1.0e-14lf;
var<private> EXP_R: array<f64, 13> = array<f64, 13>(1.0lf, 0.5lf, 0.3333333333333333lf, 0.25lf, 0.2lf, 0.16666666666666666lf, 0.14285714285714285lf, 0.125lf, 0.1111111111111111lf, 0.1lf, 0.09090909090909091lf, 0.08333333333333333lf, 0.07692307692307693lf);

// Σ_{j ≤ 13} r^j/j!, nested.
fn exp_poly(r: real) -> real {
    var s: real = 1.0;
    for (var j = 12i; j >= 0i; j--) {
        s = 1.0 + r * EXP_R[j] * s;
    }
    return s;
}

// 2^k for |k| < 256, exactly.
fn exp_pow2(k: i32) -> real {
    var b: real = 2.0;
    if (k < 0i) {
        b = 0.5;
    }
    var m = abs(k);
    var s: real = 1.0;
    for (var i = 0u; i < 8u; i++) {
        if ((m & 1i) == 1i) {
            s = s * b;
        }
        b = b * b;
        m = m >> 1u;
    }
    return s;
}

// [e̲, ē] ∋ e^x for |x| ≤ 80 (callers check the range); [0, HUGE] where the reduced argument
// falls outside EXP_R_MAX (it cannot, for a finite x in range).
fn exp_enclosure(x: real) -> vec2<f64> {
    let kf = round(f32(x) * 1.442695);
    let k = f64(kf);
    var kl_lo: real;
    var kl_hi: real;
    if (k >= 0.0) {
        kl_lo = down(k * EXP_LN2_LO);
        kl_hi = up(k * EXP_LN2_HI);
    } else {
        kl_lo = down(k * EXP_LN2_HI);
        kl_hi = up(k * EXP_LN2_LO);
    }
    let r_lo = down(x - kl_hi);
    let r_hi = up(x - kl_lo);
    if (!(r_lo >= -EXP_R_MAX && r_hi <= EXP_R_MAX)) {
        return vec2<f64>(0.0, HUGE);
    }
    let p_lo = down(exp_poly(r_lo) - EXP_POLY_ERR);
    let p_hi = up(exp_poly(r_hi) + EXP_POLY_ERR);
    let s = exp_pow2(i32(kf));
    return vec2<f64>(max(p_lo * s, 0.0), p_hi * s);
}

fn exp_down(x: real) -> real {
    if (x < -80.0) {
        return 0.0;
    }
    if (x > 80.0) {
        return exp_enclosure(80.0).x;
    }
    return exp_enclosure(x).x;
}

fn exp_up(x: real) -> real {
    if (x > 80.0) {
        return HUGE;
    }
    if (x < -80.0) {
        return exp_enclosure(-80.0).y;
    }
    return exp_enclosure(x).y;
}

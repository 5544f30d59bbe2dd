// Precision prelude, f64 (`--f64`, wgpu::Features::SHADER_F64; src/gpu/mod.rs, "Error model").
// Assumes IEEE-754 f64 `+ − ×` (correctly rounded; Vulkan itself promises f64 only single
// precision, but lavapipe, NVIDIA and AMD are IEEE), and widens by one ulp, u = 2⁻⁵² relative
// (2⁻⁵³ is the round-to-nearest unit; one ulp also covers rounding towards zero).
alias real = f64;

// u = 2⁻⁵², one ulp relative.
const EPS: real = 2.220446049250313e-16lf;
// γ̂_n = (n + 3)·GAMMA_UNIT = 4(n + 3)u ≥ 2γ_{n+3} (err_bound).
const GAMMA_UNIT: real = 8.881784197001252e-16lf;
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

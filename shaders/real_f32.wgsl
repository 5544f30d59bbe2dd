// Precision prelude, f32 (src/gpu/mod.rs, "Error model"): the type `real` of every bound.
// Vulkan rounds f32 `+ − ×` to nearest or towards zero: one ulp, u = 2⁻²³ relative.
alias real = f32;

// u = 2⁻²³, one ulp relative.
const EPS: real = 1.1920929e-7;
// γ̂_n = (n + 3)·GAMMA_UNIT = 4(n + 3)u ≥ 2γ_{n+3} (err_bound).
const GAMMA_UNIT: real = 4.76837158e-7;
// The device's copy of the network is rounded to f32 (common.wgsl: conversion_error).
const WEIGHTS_ROUNDED: bool = true;
// The largest number the kernels treat as finite-but-unbounded (iv_entire).
const HUGE: real = 3.0e38;
const MIN_NORMAL: real = 1.17549435e-38;
// Unstable-ReLU chord slopes below this are flushed to 0 (relu_lines).
const TINY_SLOPE: real = 1.0e-30;

// One ulp outward through the bit pattern (shaders/f32_bits.wgsl).
fn up(x: real) -> real {
    return up32(x);
}

// The f32 evaluation of transcendental built-ins needs no conversion in f32.
fn to32_up(x: real) -> f32 {
    return x;
}

fn to32_down(x: real) -> f32 {
    return x;
}

fn from32(x: f32) -> real {
    return x;
}

// sin, cos: WGSL promises an absolute error of 2⁻¹¹ on [−π, π] (iv_trig checks |x| ≤ 3);
// TRIG_ERR = 2⁻¹¹·1.004.
const TRIG_ERR: real = 4.9e-4;

fn trig(m: real, is_cos: bool) -> real {
    if (is_cos) {
        return cos(m);
    }
    return sin(m);
}

// exp: 3 + 2|x| ulp accurate (WGSL); widened by 4 + 2|x| ulp.
fn exp_down(x: real) -> real {
    if (x < -80.0) {
        return 0.0;
    }
    let xf = to32_down(x);
    return from32(max(down_rel32(exp(xf), 4.0 + 2.0 * abs(xf)), 0.0));
}

fn exp_up(x: real) -> real {
    if (x > 80.0) {
        return HUGE;
    }
    if (x < -80.0) {
        return 1.0e-30;
    }
    let xf = to32_up(x);
    return from32(up_rel32(exp(xf), 4.0 + 2.0 * abs(xf)));
}

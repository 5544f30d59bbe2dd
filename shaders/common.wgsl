// Shared by every cbfreach kernel: outward rounding in f32 and interval arithmetic.
//
// Error model (DESIGN §3, written out in src/gpu/mod.rs): WGSL/Vulkan round f32 `+ − ×` either
// to nearest or towards zero, so a computed result is within one ulp of the exact one; `up(x)` /
// `down(x)` step one ulp outward through the bit pattern, so `up(fl(a ∘ b)) ≥ a ∘ b` and
// `down(fl(a ∘ b)) ≤ a ∘ b` for every single operation. Subnormals may be flushed to zero, so
// the step from 0 (or from a subnormal) is to the smallest normal number. Division is 2.5 ulp
// accurate: three steps. Infinities and NaN are not reliable in WGSL: every magnitude is checked
// against BIG instead, and a box whose numbers exceed it is poisoned (reported invalid).

const BIG: f32 = 1.0e30;
const HUGE: f32 = 3.0e38;
const MIN_NORMAL: f32 = 1.17549435e-38;

fn up(x: f32) -> f32 {
    if (abs(x) < MIN_NORMAL) {
        return MIN_NORMAL;
    }
    let b = bitcast<u32>(x);
    if (x > 0.0) {
        return bitcast<f32>(b + 1u);
    }
    return bitcast<f32>(b - 1u);
}

fn down(x: f32) -> f32 {
    return -up(-x);
}

fn up3(x: f32) -> f32 {
    return up(up(up(x)));
}

fn down3(x: f32) -> f32 {
    return down(down(down(x)));
}

// `x` widened by `k` ulps of relative error (k·2⁻²³·|x|) and one more step, upward.
fn up_rel(x: f32, k: f32) -> f32 {
    return up(up(x + up(abs(x) * k * 1.1920929e-7)));
}

fn down_rel(x: f32, k: f32) -> f32 {
    return -up_rel(-x, k);
}

fn finite(x: f32) -> bool {
    return abs(x) <= BIG;
}

// Rigorous bound on the rounding error of a computed sum of `n` products (each of at most three
// floats, two roundings, f64 weights rounded to f32 counting as one), whose computed magnitude
// sum is `mag`: γ̂_n·mag + n·scale·ABS_UNIT, with γ̂_n = (n+3)·2⁻²¹ ≥ 2γ_{n+3} for u = 2⁻²³
// (one ulp: round-to-nearest or towards zero) and n ≤ 2¹⁸, and ABS_UNIT = (1 + max|W|)·2⁻¹²⁰
// covering flushed subnormal operands and results (each at most 2⁻¹²⁶ times the other factor).
fn err_bound(n: u32, mag: f32, scale: f32) -> f32 {
    let g = f32(n + 3u) * 4.76837158e-7;
    let rel = up(g * mag);
    let a = up(up(f32(n) * scale) * ABS_UNIT);
    return up(rel + a);
}

struct Iv {
    lo: f32,
    hi: f32,
}

fn iv_point(x: f32) -> Iv {
    return Iv(x, x);
}

fn iv_entire() -> Iv {
    return Iv(-HUGE, HUGE);
}

fn iv_add(a: Iv, b: Iv) -> Iv {
    return Iv(down(a.lo + b.lo), up(a.hi + b.hi));
}

fn iv_sub(a: Iv, b: Iv) -> Iv {
    return Iv(down(a.lo - b.hi), up(a.hi - b.lo));
}

fn iv_neg(a: Iv) -> Iv {
    return Iv(-a.hi, -a.lo);
}

fn iv_mul(a: Iv, b: Iv) -> Iv {
    let p1 = a.lo * b.lo;
    let p2 = a.lo * b.hi;
    let p3 = a.hi * b.lo;
    let p4 = a.hi * b.hi;
    return Iv(down(min(min(p1, p2), min(p3, p4))), up(max(max(p1, p2), max(p3, p4))));
}

fn iv_mag(a: Iv) -> f32 {
    return max(abs(a.lo), abs(a.hi));
}

fn iv_contains0(a: Iv) -> bool {
    return a.lo <= 0.0 && 0.0 <= a.hi;
}

fn iv_div(a: Iv, b: Iv) -> Iv {
    if (iv_contains0(b) || !finite(b.lo) || !finite(b.hi)) {
        return iv_entire();
    }
    let q1 = a.lo / b.lo;
    let q2 = a.lo / b.hi;
    let q3 = a.hi / b.lo;
    let q4 = a.hi / b.hi;
    return Iv(down3(min(min(q1, q2), min(q3, q4))), up3(max(max(q1, q2), max(q3, q4))));
}

// x^n for x ≥ 0, rounded down / up (every product of non-negative numbers is monotone).
fn pow_down(x: f32, n: u32) -> f32 {
    var r = 1.0;
    for (var i = 0u; i < n; i++) {
        r = max(down(r * x), 0.0);
    }
    return r;
}

fn pow_up(x: f32, n: u32) -> f32 {
    var r = 1.0;
    for (var i = 0u; i < n; i++) {
        r = up(r * x);
    }
    return r;
}

fn iv_pow(a: Iv, n: i32) -> Iv {
    if (n == 0) {
        return iv_point(1.0);
    }
    let m = u32(abs(n));
    var p: Iv;
    if ((m & 1u) == 0u) {
        var mig = min(abs(a.lo), abs(a.hi));
        if (iv_contains0(a)) {
            mig = 0.0;
        }
        p = Iv(pow_down(mig, m), pow_up(iv_mag(a), m));
    } else {
        var lo: f32;
        var hi: f32;
        if (a.lo >= 0.0) {
            lo = pow_down(a.lo, m);
        } else {
            lo = -pow_up(-a.lo, m);
        }
        if (a.hi >= 0.0) {
            hi = pow_up(a.hi, m);
        } else {
            hi = -pow_down(-a.hi, m);
        }
        p = Iv(lo, hi);
    }
    if (n > 0) {
        return p;
    }
    return iv_div(iv_point(1.0), p);
}

// sqrt: WGSL's accuracy is inherited from 1/inverseSqrt (2 + 2.5 ulp); widened by 8 ulp.
fn iv_sqrt(a: Iv) -> Iv {
    if (a.hi < 0.0) {
        return iv_entire();
    }
    return Iv(max(down_rel(sqrt(max(a.lo, 0.0)), 8.0), 0.0), up_rel(sqrt(a.hi), 8.0));
}

// exp: 3 + 2|x| ulp accurate (WGSL); widened by 4 + 2|x| ulp.
fn exp_down(x: f32) -> f32 {
    if (x < -80.0) {
        return 0.0;
    }
    return max(down_rel(exp(x), 4.0 + 2.0 * abs(x)), 0.0);
}

fn exp_up(x: f32) -> f32 {
    if (x > 80.0) {
        return HUGE;
    }
    if (x < -80.0) {
        return 1.0e-30;
    }
    return up_rel(exp(x), 4.0 + 2.0 * abs(x));
}

fn iv_exp(a: Iv) -> Iv {
    return Iv(exp_down(a.lo), exp_up(a.hi));
}

// ln: absolute error 2⁻²¹ on [0.5, 2], 3 ulp elsewhere (WGSL); widened by both.
fn ln_down(x: f32) -> f32 {
    if (x <= 0.0) {
        return -HUGE;
    }
    let v = log(x);
    return down_rel(down(v - 9.5367431640625e-7), 4.0);
}

fn ln_up(x: f32) -> f32 {
    if (x <= 0.0) {
        return -HUGE;
    }
    let v = log(x);
    return up_rel(up(v + 9.5367431640625e-7), 4.0);
}

fn iv_ln(a: Iv) -> Iv {
    if (a.hi <= 0.0) {
        return iv_entire();
    }
    return Iv(ln_down(a.lo), ln_up(a.hi));
}

// sin, cos: WGSL promises an absolute error of 2⁻¹¹ on [−π, π] only. Mean-value enclosure
// around the (computed) centre m with radius r ≥ max(hi − m, m − lo): f(m) ± (r + 2⁻¹¹·1.01),
// and [−1, 1] when |m| > 3 or r ≥ 1.
fn iv_trig(a: Iv, is_cos: bool) -> Iv {
    let m = a.lo + 0.5 * (a.hi - a.lo);
    let r = up(max(up(a.hi - m), up(m - a.lo)));
    if (!(abs(m) <= 3.0) || !(r < 1.0)) {
        return Iv(-1.0, 1.0);
    }
    var v = sin(m);
    if (is_cos) {
        v = cos(m);
    }
    let e = up(r + 4.9e-4);
    return Iv(max(down(v - e), -1.0), min(up(v + e), 1.0));
}

// tanh(x) = 1 − 2/(e^{2x} + 1), in interval arithmetic on exp's enclosure; clamped to [−1, 1].
fn iv_tanh(a: Iv) -> Iv {
    let e = iv_exp(iv_mul(iv_point(2.0), a));
    let t = iv_sub(iv_point(1.0), iv_div(iv_point(2.0), iv_add(e, iv_point(1.0))));
    return Iv(max(t.lo, -1.0), min(t.hi, 1.0));
}

fn iv_abs(a: Iv) -> Iv {
    if (a.lo >= 0.0) {
        return a;
    }
    if (a.hi <= 0.0) {
        return iv_neg(a);
    }
    return Iv(0.0, iv_mag(a));
}

fn iv_min(a: Iv, b: Iv) -> Iv {
    return Iv(min(a.lo, b.lo), min(a.hi, b.hi));
}

fn iv_max(a: Iv, b: Iv) -> Iv {
    return Iv(max(a.lo, b.lo), max(a.hi, b.hi));
}

fn iv_sign(a: Iv) -> Iv {
    if (a.lo > 0.0) {
        return iv_point(1.0);
    }
    if (a.hi < 0.0) {
        return iv_point(-1.0);
    }
    return Iv(-1.0, 1.0);
}

fn iv_step(a: Iv) -> Iv {
    if (a.lo > 0.0) {
        return iv_point(1.0);
    }
    if (a.hi < 0.0) {
        return iv_point(0.0);
    }
    return Iv(0.0, 1.0);
}

fn iv_delta(a: Iv) -> Iv {
    if (iv_contains0(a)) {
        return iv_entire();
    }
    return iv_point(0.0);
}

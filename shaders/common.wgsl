// Shared by every cbfreach kernel: outward rounding and interval arithmetic in `real` (f32, or
// f64 with --f64: the precision prelude real_f32.wgsl / real_f64.wgsl comes first).
//
// Error model (docs/design.md §3, written out in src/gpu/mod.rs): WGSL/Vulkan round `+ − ×` either
// to nearest or towards zero, so a computed result is within one ulp of the exact one; `up(x)` /
// `down(x)` (the prelude's) step outward, so `up(fl(a ∘ b)) ≥ a ∘ b` and
// `down(fl(a ∘ b)) ≤ a ∘ b` for every single operation. Subnormals may be flushed to zero, so
// the step from 0 (or from a subnormal) is to the smallest normal number. Division is 2.5 ulp
// accurate: three steps. Infinities and NaN are not reliable in WGSL: every magnitude is checked
// against BIG instead, and a box whose numbers exceed it is poisoned (reported invalid).

const BIG: real = 1.0e30;

fn down(x: real) -> real {
    return -up(-x);
}

fn up3(x: real) -> real {
    return up(up(up(x)));
}

fn down3(x: real) -> real {
    return down(down(down(x)));
}

fn finite(x: real) -> bool {
    return abs(x) <= BIG;
}

// Rigorous bound on the rounding error of a computed sum of `n` products (each of at most three
// floats, two roundings, f64 weights rounded to f32 counting as one), whose computed magnitude
// sum is `mag`: γ̂_n·mag + n·scale·ABS_UNIT, with γ̂_n = (n+3)·GAMMA_UNIT ≥ 2γ_{n+3} for the
// prelude's u (one ulp: round-to-nearest or towards zero) and n ≤ 2¹⁸, and
// ABS_UNIT = (1 + max|W|)·64·MIN_NORMAL covering flushed subnormal operands and results (each
// at most MIN_NORMAL times the other factor).
fn err_bound(n: u32, mag: real, scale: real) -> real {
    let g = real(n + 3u) * GAMMA_UNIT;
    let rel = up(g * mag);
    let a = up(up(real(n) * scale) * ABS_UNIT);
    return up(rel + a);
}

// How far the device's copy of a layer's weights and bias, applied to inputs whose magnitude
// sum (with |b|) is `mag`, can be from the f64 originals: rounded to f32, at most 2⁻²⁴ relative
// (err_bound(2, mag, scale) covers it); in f64 they are exact, and only the absolute part for
// a flushed subnormal weight is left. (The CPU holds them exactly and adds nothing; the term
// this added in f64 too had kept the engines ~4e-13 a step apart.)
fn conversion_error(mag: real, scale: real) -> real {
    return err_bound(2u, select(0.0, mag, WEIGHTS_ROUNDED), scale);
}

struct Iv {
    lo: real,
    hi: real,
}

fn iv_point(x: real) -> Iv {
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

fn iv_mag(a: Iv) -> real {
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
fn pow_down(x: real, n: u32) -> real {
    var r: real = 1.0;
    for (var i = 0u; i < n; i++) {
        r = max(down(r * x), 0.0);
    }
    return r;
}

fn pow_up(x: real, n: u32) -> real {
    var r: real = 1.0;
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
        var lo: real;
        var hi: real;
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

// Transcendental built-ins are evaluated in f32 (both precisions: see to32_up in the f64
// prelude) at arguments on the safe side of a monotone function, and widened by the WGSL
// accuracy table; the f32 result converts exactly to `real`.

// sqrt: WGSL's accuracy is inherited from 1/inverseSqrt (2 + 2.5 ulp); widened by 8 ulp.
fn iv_sqrt(a: Iv) -> Iv {
    if (a.hi < 0.0) {
        return iv_entire();
    }
    var hi = HUGE;
    if (a.hi <= 1.0e37) {
        hi = from32(up_rel32(sqrt(to32_up(a.hi)), 8.0));
    }
    let lo = max(down_rel32(sqrt(max(to32_down(max(a.lo, 0.0)), 0.0)), 8.0), 0.0);
    return Iv(from32(lo), hi);
}

// exp_down, exp_up: the precision prelude's (f32: the built-in, widened; f64: a polynomial).
fn iv_exp(a: Iv) -> Iv {
    return Iv(exp_down(a.lo), exp_up(a.hi));
}

// ln: absolute error 2⁻²¹ on [0.5, 2], 3 ulp elsewhere (WGSL); widened by both.
fn ln_down(x: real) -> real {
    let xf = to32_down(x);
    if (xf <= 0.0) {
        return -HUGE;
    }
    let v = log(xf);
    return from32(down_rel32(down32(v - 9.5367431640625e-7), 4.0));
}

fn ln_up(x: real) -> real {
    if (x <= 0.0) {
        return -HUGE;
    }
    if (x > 1.0e37) {
        return HUGE;
    }
    let v = log(to32_up(x));
    return from32(up_rel32(up32(v + 9.5367431640625e-7), 4.0));
}

fn iv_ln(a: Iv) -> Iv {
    if (a.hi <= 0.0) {
        return iv_entire();
    }
    return Iv(ln_down(a.lo), ln_up(a.hi));
}

// sin, cos over [lo, hi] ⊆ [−3, 3] ⊂ (−π, π) (else [−1, 1]): the range of the values at the ends
// (the prelude's `trig`, within TRIG_ERR: WGSL's built-ins in f32, a polynomial in f64), and the
// extrema inside: sin's ±1 at ±π/2, cos's 1 at 0 (π/2 ∈ [1.5707963, 1.5707964]).
fn iv_trig(a: Iv, is_cos: bool) -> Iv {
    if (!(a.lo >= -3.0 && a.hi <= 3.0)) {
        return Iv(-1.0, 1.0);
    }
    let fl = trig(a.lo, is_cos);
    let fh = trig(a.hi, is_cos);
    var lo = down(min(fl, fh) - TRIG_ERR);
    var hi = up(max(fl, fh) + TRIG_ERR);
    let half_pi_lo: real = 1.5707963;
    let half_pi_hi: real = 1.5707964;
    if (is_cos) {
        if (a.lo <= 0.0 && 0.0 <= a.hi) {
            hi = 1.0;
        }
    } else {
        if (a.lo <= half_pi_hi && half_pi_lo <= a.hi) {
            hi = 1.0;
        }
        if (a.lo <= -half_pi_lo && -half_pi_hi <= a.hi) {
            lo = -1.0;
        }
    }
    return Iv(max(lo, -1.0), min(hi, 1.0));
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

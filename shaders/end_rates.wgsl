// The curved rates' barrier on the device (docs/design.md §7.1 item 4, §7.4): end_rates::barrier
// in src/reach/end_rates.rs, term for term, for the upper end of coordinate i in that end's sign
// (the caller negates for the lower end, as curved_rates does). src/gpu/probe.rs runs it and
// tests/gpu_matches_cpu/validated.rs compares it with the Rust. Needs N0 and common.wgsl.

struct Barrier {
    // a + hb/2, rounded up (its largest over the enclosure of h): the end's rate.
    r: real,
    // [w̲, w̄] ∋ a + τb/2 for τ ∈ [0, h̄] (h̄ the enclosure's upper end).
    w_lo: real,
    w_hi: real,
    // false where b does not settle (from the fixed point, four rounds) or a value is not
    // finite (the Rust's None).
    ok: bool,
}

// The largest of the four products of k's and x's ends, each rounded up (the Rust's `sup`).
fn sup_products(k: Iv, x: Iv) -> real {
    return max(max(up(k.lo * x.lo), up(k.lo * x.hi)), max(up(k.hi * x.lo), up(k.hi * x.hi)));
}

struct FixedPoint {
    b: real,
    // false where a slope k·h/2 is above 1/2, or b is not finite (the Rust's None).
    ok: bool,
}

// The least b ≥ (q + k·a)/(1 − k·h/2) and ≥ q + k·a for one end k of kᵢ, rounded up.
fn line_fixed_point(q: real, a: real, k: real, half_h: Iv) -> FixedPoint {
    let gap = iv_sub(iv_point(1.0), iv_mul(iv_point(k), half_h));
    if (!(gap.lo >= 0.5)) {
        return FixedPoint(0.0, false);
    }
    let line = iv_add(iv_point(q), iv_mul(iv_point(k), iv_point(a)));
    let b = max(line.hi, iv_div(line, gap).hi);
    return FixedPoint(b, finite(b));
}

// end_rates::fixed_point: the least b with b ≥ q + sup kᵢ·{a, a + hb/2}, over both ends of kᵢ,
// a little past it.
fn fixed_point(q: real, a: real, k: Iv, h: Iv) -> FixedPoint {
    let half_h = iv_mul(h, iv_point(0.5));
    let lo = line_fixed_point(q, a, k.lo, half_h);
    let hi = line_fixed_point(q, a, k.hi, half_h);
    // Past it by the barrier's overshoot of |q| + |s| (s = b − q there), as the Rust.
    var b = max(lo.b, hi.b);
    b = b + (abs(q) + abs(b - q)) * EPS * 1024.0;
    return FixedPoint(b, lo.ok && hi.ok && finite(b));
}

// `c` the slab form's upper value at p; per coordinate j ≠ i the slopes k[j], the set's offsets
// from p d[j] and its ends' rates a[j]; k[i] the slope in xᵢ. G₀ = c + Σ sup k·d (the face's
// bound), a = max(G₀, bottom) (the slab's bottom), Q = Σ sup k·a, then b ≥ Q + sup kᵢ·[w̲, w̄] with
// [w̲, w̄] ∋ a + τb/2, from the fixed point where it has a closed form, four rounds.
fn barrier(c: real, k: array<Iv, N0>, d: array<Iv, N0>, a: array<Iv, N0>, i: u32, h: Iv, bottom: real) -> Barrier {
    var g0 = c;
    var q: real = 0.0;
    for (var j = 0u; j < N0; j++) {
        if (j != i) {
            g0 = up(g0 + sup_products(k[j], d[j]));
            q = up(q + sup_products(k[j], a[j]));
        }
    }
    // a = max(G₀, bottom): u stays in the slab (end_rates::barrier's floor).
    g0 = max(g0, bottom);
    let half_h = iv_mul(h, iv_point(0.5));
    var b = up(q + sup_products(k[i], iv_point(g0)));
    // Start from the fixed point where it has a closed form (end_rates::fixed_point).
    let fixed = fixed_point(q, g0, k[i], h);
    if (fixed.ok) {
        b = max(b, fixed.b);
    }
    for (var it = 0u; it < 4u; it++) {
        let end = iv_add(iv_point(g0), iv_mul(half_h, iv_point(b)));
        // a + τb/2 runs from a to a + hb/2: a is one end exactly (the Rust's `w`).
        var w = Iv(g0, max(end.hi, g0));
        if (b < 0.0) {
            w = Iv(min(end.lo, g0), g0);
        }
        let s = sup_products(k[i], w);
        let need = up(q + s);
        if (!(finite(need) && finite(b) && finite(g0))) {
            return Barrier(0.0, 0.0, 0.0, false);
        }
        if (need <= b) {
            return Barrier(end.hi, w.lo, w.hi, true);
        }
        // Past the fixed point by more than need's rounding (else the outward steps keep need a
        // few ulps above b as it creeps up to the fixed point, and b never settles): 2¹⁰ ulp of
        // the magnitudes summed, in the prelude's unit (end_rates::BARRIER_OVERSHOOT; both
        // factors powers of two, and f64 constant expressions are not folded here).
        b = need + (abs(q) + abs(s)) * EPS * 1024.0;
    }
    return Barrier(0.0, 0.0, 0.0, false);
}

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
    // false where b does not settle in four rounds or a value is not finite (the Rust's None).
    ok: bool,
}

// The largest of the four products of k's and x's ends, each rounded up (the Rust's `sup`).
fn sup_products(k: Iv, x: Iv) -> real {
    return max(max(up(k.lo * x.lo), up(k.lo * x.hi)), max(up(k.hi * x.lo), up(k.hi * x.hi)));
}

// `c` the slab form's upper value at p; per coordinate j ≠ i the slopes k[j], the set's offsets
// from p d[j] and its ends' rates a[j]; k[i] the slope in xᵢ. G₀ = c + Σ sup k·d (the face's
// bound), a = max(G₀, bottom) (the slab's bottom), Q = Σ sup k·a, then b ≥ Q + sup kᵢ·[w̲, w̄] with
// [w̲, w̄] ∋ a + τb/2, four rounds.
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

// The curved rates on the slabs of a proven moving box (docs/design.md §7.1 item 4, §7.4):
// end_rates::curved_rates in src/reach/end_rates.rs for one end, around its barrier
// (shaders/end_rates.wgsl). src/gpu/probe_field.rs runs it and tests/gpu_matches_cpu/field.rs
// compares it with the Rust. Needs shaders/validated.wgsl (Moving, slab), shaders/field.wgsl
// (form_on) and shaders/end_rates.wgsl (barrier).

// One end's second-order rate: x̄ᵢ(h) ≤ x̄ᵢ + h·r at the upper end (side 1), x̲ᵢ(h) ≥ x̲ᵢ + h·r at
// the lower; `ok` false where the argument does not reach it (the Rust's ∓∞).
struct CurvedEnd {
    r: real,
    ok: bool,
}

// End (i, side) of the set [lo, hi] whose step proved the moving box m, the field's form on that
// end's slab from the network's bounds nb there (the filter's piece: zero bounds, margin 0).
// The form is taken about p, the set's centre with pᵢ on the end; the lower end is the upper end
// of yᵢ = −xᵢ (c and the other slopes negated, kᵢ not); the barrier's u must stay within the
// slab's i-range.
fn curved_end(lo: array<real, N0>, hi: array<real, N0>, m: Moving, h: Iv, i: u32, side: u32, nb: NetBounds, margin: real, piece: u32) -> CurvedEnd {
    let none = CurvedEnd(0.0, false);
    let s = slab(lo, hi, m, h, i, side);
    let upper = side == 1u;
    var e = lo[i];
    if (upper) {
        e = hi[i];
    }
    var p: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        p[j] = lo[j] + 0.5 * (hi[j] - lo[j]);
    }
    p[i] = e;
    for (var j = 0u; j < N0; j++) {
        if (!(s.lo[j] <= p[j] && p[j] <= s.hi[j])) {
            return none;
        }
    }
    let f = form_on(i, side, s.lo, s.hi, p, nb, margin, piece);
    var k: array<Iv, N0>;
    var d: array<Iv, N0>;
    var a: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        k[j] = f.k[j];
        if (!upper && j != i) {
            k[j] = iv_neg(f.k[j]);
        }
        d[j] = Iv(down(lo[j] - p[j]), up(hi[j] - p[j]));
        a[j] = Iv(m.s_lo[j], m.s_hi[j]);
    }
    var c = f.c.hi;
    if (!upper) {
        c = -f.c.lo;
    }
    // The slab's bottom in the end's sign (end_rates::curved_rates' floor).
    var bottom = min(m.d_hi[i], 0.0);
    if (!upper) {
        bottom = min(-m.d_lo[i], 0.0);
    }
    let b = barrier(c, k, d, a, i, h, bottom);
    if (!b.ok) {
        return none;
    }
    let reach = iv_mul(h, iv_point(min(b.w_lo, 0.0))).lo;
    var inside = iv_add(iv_point(e), iv_point(reach)).lo >= s.lo[i];
    if (!upper) {
        inside = iv_sub(iv_point(e), iv_point(reach)).hi <= s.hi[i];
    }
    if (!(inside && finite(b.w_hi))) {
        return none;
    }
    if (upper) {
        return CurvedEnd(b.r, true);
    }
    return CurvedEnd(-b.r, true);
}

// The rate a face of the Euler step needs beyond its own where the step may turn a state around
// (euler_turn in src/reach/embedding.rs, docs/design.md §7, term for term): with L the lower end
// of ∂ᵢGᵢ over the set (`slope`), w ≥ the set's width in xᵢ and h ∈ dt, the map xᵢ + h·Gᵢ(x) is
// largest off the face by at most w·max(0, −(1 + hL)), so the rate grows by that over h. 0 where
// 1 + hL ≥ 0; HUGE where L has no bound (the set ends as non-finite, as on the CPU).
fn turn_rate(slope: Iv, w: real, dt: Iv) -> real {
    let c = iv_add(iv_point(1.0), iv_mul(dt, slope)).lo;
    if (c >= 0.0) {
        return 0.0;
    }
    if (!finite(c)) {
        return HUGE;
    }
    let e = iv_mul(iv_point(-c), iv_point(w)).hi;
    return iv_div(iv_point(e), dt).hi;
}

// The continuous-time step's common path on the device (docs/design.md §7.1 items 3b and 7,
// §7.4): the moving box guessed without an a-priori enclosure, its 2n slabs (clipped by the other
// frame's set where frames are met), the strict check of the rates found on them, and the step's
// end. Mirrors src/reach/validated.rs term for term (`guessed`, `moving_hull`, `slab` of a moving
// box with its `others`, `verified` without an enclosure, `clamp_to_depths`, `embedding_step`,
// `meet_with_pipe`) and safe_set.rs (`frame_halfspaces`, `clip_to_safe_set`); src/gpu/probe.rs
// runs each on the device and tests/gpu_matches_cpu/validated.rs compares them with the Rust.
// Needs N0 (the frame's states), OTHER_LO and OTHER_HI (`clip_by_other`'s rows) and
// common.wgsl's intervals. Plain arithmetic where the Rust's is plain (the guess is a heuristic:
// soundness rests on the check), outward steps where the Rust's is outward.

// validated::GUESS_MARGIN.
const GUESS_MARGIN: real = 0.05;

// A guessed moving box X(τ) = [x̲ + τs̲, x̄ + τs̄], τ ∈ [0, h] (validated::MovingFaces with its hull):
// the faces' rates s̲, s̄, the slabs' depths ρ̲, ρ̄, and the hull H over the step (the flowpipe,
// where the check passes). `ok` false where validated::guessed returns None: a value not finite
// (here |x| > BIG, common.wgsl's `finite`) or the box inside out at the step's end.
struct Moving {
    s_lo: array<real, N0>,
    s_hi: array<real, N0>,
    d_lo: array<real, N0>,
    d_hi: array<real, N0>,
    hull_lo: array<real, N0>,
    hull_hi: array<real, N0>,
    ok: bool,
    // The other frame's set over the step (validated::Flowpipe::others, meet_slabs): its box in
    // its coordinates and the pad ρK, the slabs clipped by them where `clip` (`clip_by_other`).
    o_lo: array<real, N0>,
    o_hi: array<real, N0>,
    o_pad: real,
    clip: bool,
}

// `e + h·s` as an interval (the Rust's point(e) + point(h)·point(s)). The step `h` is an
// enclosure [h̲, h̄] of the f64 step (a point in f64; in f32 its two neighbours, H_LO and
// H_HI): the result holds e + τs for every τ in it, whatever the sign of s.
fn moved(e: real, h: Iv, s: real) -> Iv {
    return iv_add(iv_point(e), iv_mul(h, iv_point(s)));
}

// validated::guessed: face rates from last step's slab rates (r̲, r̄) and, where `before`, the
// trend r̂ = 2r − r_before: s̄ = max(r̄, r̂) + δ, ρ̄ = min(r̄, r̂) − δ (mirrored below), δ = 5 % of
// |r̄ − r̲| + max(|r̲|, |r̄|) plus 1e-9; then validated::moving_hull.
fn guessed(lo: array<real, N0>, hi: array<real, N0>, h: Iv, r_lo: array<real, N0>, r_hi: array<real, N0>, b_lo: array<real, N0>, b_hi: array<real, N0>, before: bool) -> Moving {
    var m: Moving;
    for (var i = 0u; i < N0; i++) {
        let rl = r_lo[i];
        let ru = r_hi[i];
        var tl = rl;
        var tu = ru;
        if (before) {
            tl = 2.0 * rl - b_lo[i];
            tu = 2.0 * ru - b_hi[i];
        }
        let delta = GUESS_MARGIN * (abs(ru - rl) + max(abs(rl), abs(ru))) + 1e-9;
        m.s_lo[i] = min(rl, tl) - delta;
        m.d_lo[i] = max(rl, tl) + delta;
        m.s_hi[i] = max(ru, tu) + delta;
        m.d_hi[i] = min(ru, tu) - delta;
    }
    m.ok = true;
    m.clip = false;
    for (var i = 0u; i < N0; i++) {
        if (!(finite(m.s_lo[i]) && finite(m.s_hi[i]) && finite(m.d_lo[i]) && finite(m.d_hi[i]))) {
            m.ok = false;
        }
    }
    if (!m.ok) {
        return m;
    }
    for (var i = 0u; i < N0; i++) {
        let e_lo = moved(lo[i], h, m.s_lo[i]);
        let e_hi = moved(hi[i], h, m.s_hi[i]);
        // Linear in τ: the box is inside out somewhere on the step iff it is at its end.
        if (e_lo.hi > e_hi.lo) {
            m.ok = false;
        }
        // The sweep X + h·[min(0, s̲), max(0, s̄)]; a side that does not move stays exactly.
        m.hull_lo[i] = select(e_lo.lo, lo[i], m.s_lo[i] >= 0.0);
        m.hull_hi[i] = select(e_hi.hi, hi[i], m.s_hi[i] <= 0.0);
    }
    return m;
}

// A box of N0 states.
struct Box {
    lo: array<real, N0>,
    hi: array<real, N0>,
}

// validated::slab of a moving box: coordinate i's slab at the set's upper (side 1) or lower end,
// the hull with xᵢ ∈ [x̄ᵢ + h·min(0, ρ̄ᵢ), x̄ᵢ + h·max(0, s̄ᵢ)] (at the lower end
// [x̲ᵢ + h·min(0, s̲ᵢ), x̲ᵢ + h·max(0, ρ̲ᵢ)]), met with the hull. The step's network is bounded
// over these 2n boxes (the order (0, lower), (0, upper), (1, lower), …, as Euler's faces).
fn slab(lo: array<real, N0>, hi: array<real, N0>, m: Moving, h: Iv, i: u32, side: u32) -> Box {
    var end = lo[i];
    var down_rate = m.s_lo[i];
    var up_rate = m.d_lo[i];
    if (side == 1u) {
        end = hi[i];
        down_rate = m.d_hi[i];
        up_rate = m.s_hi[i];
    }
    let a = moved(end, h, min(down_rate, 0.0)).lo;
    let b = moved(end, h, max(up_rate, 0.0)).hi;
    var s = Box(m.hull_lo, m.hull_hi);
    s.lo[i] = max(a, m.hull_lo[i]);
    s.hi[i] = min(b, m.hull_hi[i]);
    if (s.lo[i] > s.hi[i]) {
        // Only rounding can get here (the slab holds the end, a state of the hull).
        s.lo[i] = end;
        s.hi[i] = end;
    }
    if (m.clip) {
        return clip_by_other(s, m.o_lo, m.o_hi, m.o_pad);
    }
    return s;
}

// The other frame's set [o̲, ō] as the 2·N0 half-spaces of safe_set::frame_halfspaces, row r of
// OTHER_LO/OTHER_HI (its `frame_rows`, T_g S_f enclosed) holding rᵣ·v ∈ [o̲ᵣ − pad, ōᵣ + pad], and
// the box clipped by them one coordinate at a time as safe_set::clip_to_safe_set
// (SafeHalfspace::tightening: a row entry that is exactly 0 is skipped, one whose enclosure holds
// 0 bounds nothing). An empty meet (no trajectory reaches the box) leaves it whole.
fn clip_by_other(b: Box, o_lo: array<real, N0>, o_hi: array<real, N0>, pad: real) -> Box {
    var v = b;
    let slack = iv_point(pad);
    for (var r = 0u; r < N0; r++) {
        for (var side = 0u; side < 2u; side++) {
            // Lower: row·v − (o̲ᵣ − pad) ≥ 0; upper: −row·v + (ōᵣ + pad) ≥ 0.
            var off = iv_neg(iv_sub(iv_point(o_lo[r]), slack));
            if (side == 1u) {
                off = iv_add(iv_point(o_hi[r]), slack);
            }
            for (var j = 0u; j < N0; j++) {
                let c = other_row(r, j, side);
                if (iv_contains0(c)) {
                    continue;
                }
                var rest = off;
                for (var k = 0u; k < N0; k++) {
                    if (k != j && !(OTHER_LO[r * N0 + k] == 0.0 && OTHER_HI[r * N0 + k] == 0.0)) {
                        rest = iv_add(rest, iv_mul(other_row(r, k, side), Iv(v.lo[k], v.hi[k])));
                    }
                }
                let l = -rest.hi;
                let q = iv_div(Iv(l, l), c);
                if (c.lo > 0.0) {
                    v.lo[j] = max(v.lo[j], q.lo);
                } else {
                    v.hi[j] = min(v.hi[j], q.hi);
                }
            }
        }
    }
    for (var j = 0u; j < N0; j++) {
        if (!(v.lo[j] <= v.hi[j])) {
            return b;
        }
    }
    return v;
}

// Entry (r, j) of clip_by_other's half-space normal: the row's for the lower side, negated for
// the upper.
fn other_row(r: u32, j: u32, side: u32) -> Iv {
    let c = Iv(OTHER_LO[r * N0 + j], OTHER_HI[r * N0 + j]);
    if (side == 1u) {
        return iv_neg(c);
    }
    return c;
}

// validated::verified for a box guessed without an enclosure: the rates (dl, du) found on its
// slabs (met over the field's sources, and over the frames where two are met) prove it only
// where every face moves strictly faster than the field on its slab.
fn verified(m: Moving, dl: array<real, N0>, du: array<real, N0>) -> bool {
    for (var i = 0u; i < N0; i++) {
        if (!(du[i] < m.s_hi[i] && dl[i] > m.s_lo[i])) {
            return false;
        }
    }
    return true;
}

// The step's end from a proven moving box: the slab rates (dl, du) clamped to the slabs' depths
// (validated::clamp_to_depths: a rate past ρ̄ reaches a state outside the slab), met with the
// second-order rates (cl, cu: end_rates::curved_rates, ∓HUGE where there are none), the Euler
// step x ← x + h·rate rounded outward (embedding::embedding_step), met with the hull
// (validated::meet_with_pipe).
fn slab_step_end(lo: array<real, N0>, hi: array<real, N0>, m: Moving, h: Iv, dl: array<real, N0>, du: array<real, N0>, cl: array<real, N0>, cu: array<real, N0>) -> Box {
    var out: Box;
    for (var i = 0u; i < N0; i++) {
        let l = max(min(dl[i], m.d_lo[i]), cl[i]);
        let u = min(max(du[i], m.d_hi[i]), cu[i]);
        out.lo[i] = max(moved(lo[i], h, l).lo, m.hull_lo[i]);
        out.hi[i] = min(moved(hi[i], h, u).hi, m.hull_hi[i]);
    }
    return out;
}

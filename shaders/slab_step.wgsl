// One box-step of the continuous model's common path in one frame (docs/design.md §7.1 item 3b,
// §7.4): the moving box guessed from the rates the box keeps, the field's rates on its 2n slabs
// from every source the CPU's step meets there (the filter's proven piece: its slab field,
// curved and Taylor rates; the closed form's enclosures of v on each slab: their slab field and
// curved rates; the network's bounds: its slab field and curved rates), the strict check, the
// rates kept for the next guess, the step's end. The CPU engine's order (src/reach/cpu.rs
// `horizon`; cpu_guess.rs `guess_moving`; cpu_field.rs `first_fields`, `network_field`;
// cpu_time.rs `check_step`, `curved`, `piece_slab_field`, `enclosure_slab_rates`,
// `piece_taylor`). A box-step this cannot finish is flagged and keeps its state, for the host.
// continuous.wgsl runs it in the engine's pipeline; src/gpu/probe_field.rs runs it alone,
// tests/gpu_matches_cpu/step.rs compares it with the CPU's. Needs validated.wgsl, end_rates.wgsl,
// field.wgsl, curved.wgsl, filter.wgsl, sets.wgsl, and from the module that includes it
// `slab_bounds(at, f)`: the network's bounds on slab f (in the order (0, lower), (0, upper), …)
// of the box or case at `at`.

// What one box keeps between steps in one frame: its set, the slab rates of the last step and
// of the step before, and how many of those it has (0 on a tube's first step).
struct StepState {
    lo: array<real, N0>,
    hi: array<real, N0>,
    r_lo: array<real, N0>,
    r_hi: array<real, N0>,
    b_lo: array<real, N0>,
    b_hi: array<real, N0>,
    rates: u32,
}

// The step's moving box (cpu_guess.rs guess_moving); `on_path` false where the common path
// cannot take the step: no rates yet, the guess refused (inside out, not finite) or, in x
// coordinates, its hull not within C (the enclosure handles C's sides, §7.1 item 1c).
struct Guess {
    m: Moving,
    on_path: bool,
}

fn guess_step(st: StepState, h: real) -> Guess {
    var g: Guess;
    g.on_path = false;
    if (st.rates == 0u) {
        return g;
    }
    g.m = guessed(st.lo, st.hi, h, st.r_lo, st.r_hi, st.b_lo, st.b_hi, st.rates >= 2u);
    if (!g.m.ok) {
        return g;
    }
    if (!TRANSFORM) {
        for (var i = 0u; i < N0; i++) {
            if (!(REGION_LO[i] <= g.m.hull_lo[i] && g.m.hull_hi[i] <= REGION_HI[i])) {
                return g;
            }
        }
    }
    g.on_path = true;
    return g;
}

// The step from every end's rates (dl, du: the field's; cl, cu: the second-order): where the check
// proves the moving box (validated::verified), the rates kept for the next guess (the last
// step's become the step before's) and the set at the step's end (slab_step_end: the meet with
// the curved rates, the outward step, the meet with the hull); else the state as it was, for the
// host (`proven` false).
struct Stepped {
    st: StepState,
    proven: bool,
}

fn finish_step(st: StepState, m: Moving, h: real, dl: array<real, N0>, du: array<real, N0>, cl: array<real, N0>, cu: array<real, N0>) -> Stepped {
    if (!verified(m, dl, du)) {
        return Stepped(st, false);
    }
    var out = st;
    out.b_lo = st.r_lo;
    out.b_hi = st.r_hi;
    out.r_lo = dl;
    out.r_hi = du;
    out.rates = min(st.rates + 1u, 2u);
    let end = slab_step_end(st.lo, st.hi, m, h, dl, du, cl, cu);
    out.lo = end.lo;
    out.hi = end.hi;
    return Stepped(out, true);
}

// Rates (lower, upper) per coordinate, ∓HUGE where a source says nothing.
struct EndPair {
    lo: array<real, N0>,
    hi: array<real, N0>,
}

fn no_rates() -> EndPair {
    var r: EndPair;
    for (var i = 0u; i < N0; i++) {
        r.lo[i] = -HUGE;
        r.hi[i] = HUGE;
    }
    return r;
}

// The meet of two sound bounds of the same rates (cpu_field.rs meet_fields).
fn meet_pair(a: EndPair, b: EndPair) -> EndPair {
    var r: EndPair;
    for (var i = 0u; i < N0; i++) {
        r.lo[i] = max(a.lo[i], b.lo[i]);
        r.hi[i] = min(a.hi[i], b.hi[i]);
    }
    return r;
}

// One source's rates on the slabs of the moving box m: its slab field (validated::slab_field:
// bound_on each end's slab, clamped to the slab's depth) and its curved rates (curved_end, ∓HUGE
// where none), each widened by `slack` (widen_by). The source is `piece`'s field with the
// network bounded by `nb` plus `margin`, or (piece 0, zero slopes) v's constant bounds.
struct SourceRates {
    field: EndPair,
    curved: EndPair,
}

// End (i, side)'s rates of one source: the slab field and the curved rate, widened.
struct EndRate {
    field: real,
    curved: real,
}

fn end_rate(st: StepState, m: Moving, h: real, i: u32, side: u32, nb: NetBounds, margin: real, piece: u32, slack: real) -> EndRate {
    let s = slab(st.lo, st.hi, m, h, i, side);
    let b = bound_on(i, side, s.lo, s.hi, nb, margin, piece);
    let c = curved_end(st.lo, st.hi, m, h, i, side, nb, margin, piece);
    if (side == 0u) {
        return EndRate(widen_down(min(b.lo, m.d_lo[i]), slack), select(-HUGE, widen_down(c.r, slack), c.ok));
    }
    return EndRate(widen_up(max(b.hi, m.d_hi[i]), slack), select(HUGE, widen_up(c.r, slack), c.ok));
}

// `r` with end (i, side) set to `e`.
fn with_end(r: SourceRates, i: u32, side: u32, e: EndRate) -> SourceRates {
    var out = r;
    if (side == 0u) {
        out.field.lo[i] = e.field;
        out.curved.lo[i] = e.curved;
    } else {
        out.field.hi[i] = e.field;
        out.curved.hi[i] = e.curved;
    }
    return out;
}

fn zero_net() -> NetBounds {
    var none: array<real, M_OUT>;
    for (var k = 0u; k < M_OUT; k++) {
        none[k] = 0.0;
    }
    return constant_bounds(none, none);
}

// The proven piece's field on the slabs and its curved rates (cpu_time.rs piece_slab_field and
// `curved`'s exact source): the piece's own field, zero bounds, the piece's slack.
fn piece_rates(st: StepState, m: Moving, h: real, piece: u32, slack: real) -> SourceRates {
    var r = SourceRates(no_rates(), no_rates());
    let zero = zero_net();
    for (var f = 0u; f < 2u * N0; f++) {
        r = with_end(r, f / 2u, f % 2u, end_rate(st, m, h, f / 2u, f % 2u, zero, 0.0, piece, slack));
    }
    return r;
}

// The proven piece's Taylor rates over the step (cpu_time.rs piece_taylor on a proven guessed
// moving box, end_rates::taylor_rates): the piece's field F over the hull (every state of the
// step lies there) bounds the motion, so x(h) ∈ x₀ + hΦ(x₀) + h²/2·DΦ(hull)·F; the Euler part is
// bounded on the set's faces (the embedding's face bounds) where 1 + h·∂ᵢΦᵢ ≥ 0 on the set
// (checked: where it holds the CPU's turn of the Euler part adds nothing, so none is taken).
// `ok` false where the check fails or a value is not finite (the Rust's None).
struct Taylor {
    r: EndPair,
    ok: bool,
}

fn piece_taylor(st: StepState, m: Moving, h: real, piece: u32, slack: real) -> Taylor {
    var t: Taylor;
    t.ok = false;
    let zero = zero_net();
    var xb: array<Iv, N0>;
    var cen: array<real, N0>;
    var hull: array<Iv, N0>;
    var f: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        xb[j] = Iv(st.lo[j], st.hi[j]);
        cen[j] = clamp(st.lo[j] + 0.5 * (st.hi[j] - st.lo[j]), st.lo[j], st.hi[j]);
        hull[j] = Iv(m.hull_lo[j], m.hull_hi[j]);
    }
    // validated::field_over on the hull, widened by the slack.
    for (var j = 0u; j < N0; j++) {
        let lo = bound_on(j, 0u, m.hull_lo, m.hull_hi, zero, 0.0, piece).lo;
        let hi = bound_on(j, 1u, m.hull_lo, m.hull_hi, zero, 0.0, piece).hi;
        f[j] = Iv(widen_down(lo, slack), widen_up(hi, slack));
    }
    let half_h = iv_mul(iv_point(h), iv_point(0.5));
    for (var i = 0u; i < N0; i++) {
        let diag = field_jac(piece, i, i, xb);
        let monotone = iv_add(iv_point(1.0), iv_mul(iv_point(h), diag)).lo;
        if (!(monotone >= 0.0)) {
            return t;
        }
        var r = iv_point(0.0);
        for (var j = 0u; j < N0; j++) {
            r = iv_add(r, iv_mul(field_jac(piece, i, j, hull), f[j]));
        }
        if (!(finite(r.lo) && finite(r.hi))) {
            return t;
        }
        let el = widen_down(face_field(i, 0u, xb, cen, zero, 0.0, piece).lo, slack);
        let eu = widen_up(face_field(i, 1u, xb, cen, zero, 0.0, piece).hi, slack);
        t.r.lo[i] = iv_add(iv_point(el), iv_mul(half_h, iv_point(r.lo))).lo;
        t.r.hi[i] = iv_add(iv_point(eu), iv_mul(half_h, iv_point(r.hi))).hi;
    }
    t.ok = true;
    return t;
}

// The closed form's enclosures of v on every slab (cpu_time.rs enclosure_slab_rates): each
// slab's x-box within S, met with `known` (the hull's), gives an enclosure (filter.wgsl
// enclose_v), taken as constant bounds of the input on that slab; every source is widened by the
// largest slack of them. `ok` false where one is unbounded (the Rust's None: near a jump of v).
struct Enclosed {
    r: SourceRates,
    ok: bool,
}

fn enclosed_rates(st: StepState, m: Moving, h: real, known: array<Iv, N0>) -> Enclosed {
    var e: Enclosed;
    e.ok = false;
    var vs: array<Iv, 2u * N0 * M_OUT>;
    var slack: real = 0.0;
    for (var f = 0u; f < 2u * N0; f++) {
        let s = slab(st.lo, st.hi, m, h, f / 2u, f % 2u);
        var sb: array<Iv, N0>;
        for (var j = 0u; j < N0; j++) {
            sb[j] = Iv(s.lo[j], s.hi[j]);
        }
        let x = meet_or(clip_to_safe_set(x_box(sb), HS_Z, HS_X), known);
        let v = enclose_v(x);
        if (!v.ok) {
            return e;
        }
        slack = max(slack, enclosed_slack(x, v.v));
        for (var k = 0u; k < M_OUT; k++) {
            vs[f * M_OUT + k] = v.v[k];
        }
    }
    e.r = SourceRates(no_rates(), no_rates());
    for (var f = 0u; f < 2u * N0; f++) {
        var lo: array<real, M_OUT>;
        var hi: array<real, M_OUT>;
        for (var k = 0u; k < M_OUT; k++) {
            lo[k] = vs[f * M_OUT + k].lo;
            hi[k] = vs[f * M_OUT + k].hi;
        }
        let er = end_rate(st, m, h, f / 2u, f % 2u, constant_bounds(lo, hi), 0.0, 0u, slack);
        e.r = with_end(e.r, f / 2u, f % 2u, er);
    }
    e.ok = true;
    return e;
}

// The step's rates from every source of the CPU's step on the moving box m (cpu.rs `horizon`):
// with `known` the hull's x-box within S, the proven piece there (`piece`: piece_on(known),
// which the caller takes for M too) brings its slab field,
// curved and Taylor rates; where none is proven, the closed form's enclosures (ENCLOSE) their
// slab field and curved rates; the network, except on the inactive piece (v = 0), its slab
// field and curved rates with the disturbance bound `margin` (≥ HUGE: no finite bound, no
// network), its bounds on the slabs from `slab_bounds(at, f)`. `field` meets the first-order
// rates (the check's and the ones kept), `second` the curved and Taylor ones; `ok` false where
// no source bounds the field (the host's step ends the box as the CPU does).
struct StepRates {
    field: EndPair,
    second: EndPair,
    piece: u32,
    enclosed: bool,
    ok: bool,
}

fn step_rates(st: StepState, m: Moving, h: real, known: array<Iv, N0>, piece: u32, margin: real, at: u32) -> StepRates {
    var out = StepRates(no_rates(), no_rates(), piece, false, false);
    if (out.piece != PIECE_NONE) {
        var slack = FIELD_SLACK;
        if (out.piece != PIECE_INACTIVE) {
            slack = binding_slack(out.piece - 1u, known);
        }
        let p = piece_rates(st, m, h, out.piece, slack);
        out.field = p.field;
        out.second = p.curved;
        let t = piece_taylor(st, m, h, out.piece, slack);
        if (t.ok) {
            out.second = meet_pair(out.second, t.r);
        }
        out.ok = true;
    } else if (ENCLOSE) {
        let e = enclosed_rates(st, m, h, known);
        if (e.ok) {
            out.field = e.r.field;
            out.second = e.r.curved;
            out.enclosed = true;
            out.ok = true;
        }
    }
    if (out.piece != PIECE_INACTIVE && margin < HUGE) {
        var r = SourceRates(no_rates(), no_rates());
        for (var f = 0u; f < 2u * N0; f++) {
            let er = end_rate(st, m, h, f / 2u, f % 2u, slab_bounds(at, f), margin, 0u, FIELD_SLACK);
            r = with_end(r, f / 2u, f % 2u, er);
        }
        out.field = meet_pair(out.field, r.field);
        out.second = meet_pair(out.second, r.curved);
        out.ok = true;
    }
    return out;
}

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
// tests/gpu_matches_cpu/step.rs compares it with the CPU's. Needs guess.wgsl, validated.wgsl,
// end_rates.wgsl, field.wgsl, curved.wgsl, filter.wgsl, sets.wgsl, and from the module that includes it
// `slab_bounds(at, f)`: the network's bounds on slab f (in the order (0, lower), (0, upper), …)
// of the box or case at `at`.

// The step from every end's rates (dl, du: the field's; cl, cu: the second-order): where the check
// proves the moving box (validated::verified), the rates kept for the next guess (the last
// step's become the step before's) and the set at the step's end (slab_step_end: the meet with
// the curved rates, the outward step, the meet with the hull); else the state as it was, for the
// host (`proven` false).
struct Stepped {
    st: StepState,
    proven: bool,
}

fn finish_step(st: StepState, m: Moving, h: Iv, dl: array<real, N0>, du: array<real, N0>, cl: array<real, N0>, cu: array<real, N0>) -> Stepped {
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

// End (i, side)'s rates of one source: its slab field (validated::slab_field: the bound on the
// end's slab, clamped to the slab's depth) and its curved rate (curved_end, ∓HUGE where none),
// each widened by the source's slack (widen_by).
struct EndRate {
    field: real,
    curved: real,
}

fn zero_net() -> NetBounds {
    var none: array<real, M_OUT>;
    for (var k = 0u; k < M_OUT; k++) {
        none[k] = 0.0;
    }
    return constant_bounds(none, none);
}

// One source's first-order and curved rates.
struct SourceRates {
    field: EndPair,
    curved: EndPair,
}

// `r` met with the rate `v` at end (i, side).
fn meet_end(r: EndPair, i: u32, side: u32, v: real) -> EndPair {
    var out = r;
    if (side == 0u) {
        out.lo[i] = max(out.lo[i], v);
    } else {
        out.hi[i] = min(out.hi[i], v);
    }
    return out;
}

// `r` widened by `slack` (widen_by).
fn widen_pair(r: EndPair, slack: real) -> EndPair {
    var out: EndPair;
    for (var i = 0u; i < N0; i++) {
        out.lo[i] = widen_down(r.lo[i], slack);
        out.hi[i] = widen_up(r.hi[i], slack);
    }
    return out;
}

// The proven piece's Taylor rates over the step (cpu_time.rs piece_taylor on a proven guessed
// moving box, end_rates::taylor_rates): the piece's field `over` the hull (every state of the
// step lies there) bounds the motion, so x(h) ∈ x₀ + hΦ(x₀) + h²/2·DΦ(hull)·F; the Euler part
// x₀ + hΦ(x₀) is bounded by the piece's field on the set's faces (`euler`) where
// 1 + h·∂ᵢΦᵢ ≥ 0 on the set (checked: where it holds the CPU's turn of the Euler part adds
// nothing, so none is taken). `over` and `euler` are widened by the piece's slack (step_rates
// takes both). `ok` false where the check fails or a value is not finite (the Rust's None).
struct Taylor {
    r: EndPair,
    ok: bool,
}

fn piece_taylor(st: StepState, m: Moving, h: Iv, piece: u32, over: EndPair, euler: EndPair, ends: u32) -> Taylor {
    let first = piece_taylor2(st, m, h, piece, over, euler, ends);
    if (!TAYLOR3) {
        return first;
    }
    // With taylor3 the second-order form too, met with the first (cpu_time.rs piece_taylor).
    let third = piece_taylor3(st, m, h, piece, over, euler, ends);
    if (!first.ok) {
        return third;
    }
    if (!third.ok) {
        return first;
    }
    var t = first;
    for (var i = 0u; i < N0; i++) {
        t.r.lo[i] = max(first.r.lo[i], third.r.lo[i]);
        t.r.hi[i] = min(first.r.hi[i], third.r.hi[i]);
    }
    return t;
}

// end_rates::taylor3_rates: with G = DΦ·Φ (ẍ = G(x)), x(h) ∈ ψ(x₀) + h³/6·DG(hull)·F, ψ(x) =
// x + hΦ(x) + h²/2·G(x). Where 1 + h·∂ᵢΦᵢ + h²/2·∂ᵢGᵢ ≥ 0 on the set (checked) ψᵢ is largest on
// the face xᵢ = x̄ᵢ: there at most `euler` (the piece's field on that face) plus h²/2 times
// Gᵢ's mean-value form on the face about its centre (mirrored below). G and DG come from the
// generated g2_iv and dg_iv, one call each in a loop the driver keeps (n0 from `ends`).
fn piece_taylor3(st: StepState, m: Moving, h: Iv, piece: u32, over: EndPair, euler: EndPair, ends: u32) -> Taylor {
    var t: Taylor;
    t.ok = false;
    let n0 = ends / 2u;
    let base = piece * (N0 * N0 + N0);
    var xb: array<Iv, N0>;
    var hull: array<Iv, N0>;
    var centre: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        xb[j] = Iv(st.lo[j], st.hi[j]);
        hull[j] = Iv(m.hull_lo[j], m.hull_hi[j]);
        centre[j] = iv_point(st.lo[j] + 0.5 * (st.hi[j] - st.lo[j]));
    }
    let half_h = iv_mul(h, iv_point(0.5));
    let h2_6 = iv_div(iv_mul(h, h), iv_point(6.0));
    for (var i = 0u; i < n0; i++) {
        let slope = iv_add(
            iv_add(iv_point(1.0), iv_mul(h, dg_iv(base + N0 * N0 + i, xb))),
            iv_mul(iv_mul(half_h, h), dg_iv(base + i * N0 + i, xb))
        );
        if (!(slope.lo >= 0.0)) {
            return t;
        }
        var r = iv_point(0.0);
        for (var j = 0u; j < n0; j++) {
            r = iv_add(r, iv_mul(dg_iv(base + i * N0 + j, hull), Iv(over.lo[j], over.hi[j])));
        }
        for (var side = 0u; side < 2u; side++) {
            // The face x_i = its end, and its centre.
            var face = xb;
            var p = centre;
            let at = select(st.lo[i], st.hi[i], side == 1u);
            face[i] = iv_point(at);
            p[i] = iv_point(at);
            var g = g2_iv(piece * N0 + i, p);
            for (var j = 0u; j < n0; j++) {
                if (j != i) {
                    g = iv_add(g, iv_mul(dg_iv(base + i * N0 + j, face), iv_sub(face[j], p[j])));
                }
            }
            // The side's ends of `euler`, `g` and `r`: (euler + h/2·g) + h²/6·r, rounded outward.
            let up = side == 1u;
            let e = iv_add(
                iv_add(iv_point(select(euler.lo[i], euler.hi[i], up)), iv_mul(half_h, iv_point(select(g.lo, g.hi, up)))),
                iv_mul(h2_6, iv_point(select(r.lo, r.hi, up)))
            );
            let end = select(e.lo, e.hi, up);
            if (!finite(end)) {
                return t;
            }
            if (up) {
                t.r.hi[i] = end;
            } else {
                t.r.lo[i] = end;
            }
        }
    }
    t.ok = true;
    return t;
}

fn piece_taylor2(st: StepState, m: Moving, h: Iv, piece: u32, over: EndPair, euler: EndPair, ends: u32) -> Taylor {
    var t: Taylor;
    t.ok = false;
    var xb: array<Iv, N0>;
    var hull: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        xb[j] = Iv(st.lo[j], st.hi[j]);
        hull[j] = Iv(m.hull_lo[j], m.hull_hi[j]);
    }
    // DΦ over the hull and its diagonal over the set, from one call in a loop the driver keeps
    // (N0 from `ends`).
    let n0 = ends / 2u;
    var jac: array<Iv, N0 * N0>;
    var diag: array<Iv, N0>;
    for (var q = 0u; q < n0 * (n0 + 1u); q++) {
        var at = hull;
        var i = q / N0;
        var j = q % N0;
        if (q >= n0 * n0) {
            at = xb;
            i = q - n0 * n0;
            j = i;
        }
        let d = field_jac(piece, i, j, at);
        if (q < n0 * n0) {
            jac[q] = d;
        } else {
            diag[i] = d;
        }
    }
    let half_h = iv_mul(h, iv_point(0.5));
    for (var i = 0u; i < n0; i++) {
        let monotone = iv_add(iv_point(1.0), iv_mul(h, diag[i])).lo;
        if (!(monotone >= 0.0)) {
            return t;
        }
        var r = iv_point(0.0);
        for (var j = 0u; j < N0; j++) {
            r = iv_add(r, iv_mul(jac[i * N0 + j], Iv(over.lo[j], over.hi[j])));
        }
        if (!(finite(r.lo) && finite(r.hi))) {
            return t;
        }
        t.r.lo[i] = iv_add(iv_point(euler.lo[i]), iv_mul(half_h, iv_point(r.lo))).lo;
        t.r.hi[i] = iv_add(iv_point(euler.hi[i]), iv_mul(half_h, iv_point(r.hi))).hi;
    }
    t.ok = true;
    return t;
}

// The step's rates from every source of the CPU's step on the moving box m (cpu.rs `horizon`,
// cpu_field.rs `first_fields`, cpu_time.rs `check_step`), with `known` the hull's x-box within S:
// - the proven piece there (`piece`: piece_on(known), which the caller takes for M too): its
//   own field on the slabs and its curved rates (cpu_time.rs piece_slab_field, `curved`),
//   widened by its slack, and its Taylor rates (piece_taylor: its field over the hull and on
//   the set's faces, validated::field_over and the embedding's face bounds);
// - where none is proven, the closed form's enclosures (ENCLOSE; cpu_time.rs
//   enclosure_slab_rates): each slab's x-box within S, met with `known`, gives an enclosure of
//   v (filter.wgsl enclose_v), taken as constant bounds of the input on that slab; slab field
//   and curved rates, widened by the largest slack of them; none where one is unbounded (near
//   a jump of v);
// - the network, except on the inactive piece (v = 0), with the disturbance bound `margin`
//   (≥ HUGE: no finite bound, no network), its bounds on the slabs from `slab_bounds(at, f)`:
//   slab field and curved rates, widened by the transform's slack (cpu_field.rs network_field).
// `field` meets the first-order rates (the check's and the ones kept), `second` the curved and
// Taylor ones; `ok` false where no source bounds the field (the host's step ends the box as the
// CPU does). One loop over the ends and the sources with one call of each bound, the source
// picking its box and bounds of v, and `ends` (2N0) passed in from a value the driver cannot
// see through: lavapipe compiled the unrolled copies of the piece's generated field (one per
// call and coordinate) for minutes.
struct StepRates {
    field: EndPair,
    second: EndPair,
    piece: u32,
    enclosed: bool,
    ok: bool,
}

// One piece's first-order rate at end (i, side) of the moving box's slab (as the piece's source
// in step_rates: validated::slab_field's bound clamped to the slab's depth, widened by `sl`).
fn piece_end(i: u32, side: u32, s: Box, m: Moving, piece: u32, sl: real) -> real {
    let b = bound_on(i, side, s.lo, s.hi, zero_net(), 0.0, piece);
    if (side == 0u) {
        return widen_down(min(b.lo, m.d_lo[i]), sl);
    }
    return widen_up(max(b.hi, m.d_hi[i]), sl);
}

// The field on the slabs from the lattice of the filter's pieces on `known` (cpu_time.rs
// lattice_slab_field, design §7.1 item 6): with cᵢ = Bᵢ, min(min_U Φₖ, max(Φ₀, max_L Φₖ)) for
// cᵢ > 0, max(max_U Φₖ, min(Φ₀, min_L Φₖ)) for cᵢ < 0, Φ₀ for cᵢ = 0, each Φ its own slab end
// (piece_end). `ok` false where the lattice does not apply.
struct LatticeRates {
    r: EndPair,
    ok: bool,
}

fn lattice_rates(st: StepState, m: Moving, h: Iv, known: array<Iv, N0>, ends: u32) -> LatticeRates {
    var out = LatticeRates(no_rates(), false);
    if (!LATTICE) {
        return out;
    }
    let rows = lattice_rows(known);
    if (!rows.ok) {
        return out;
    }
    for (var f = 0u; f < ends; f++) {
        let i = f / 2u;
        let side = f % 2u;
        let s = slab(st.lo, st.hi, m, h, i, side);
        let e0 = piece_end(i, side, s, m, PIECE_INACTIVE, FIELD_SLACK);
        let up = B_HI[i] > 0.0;
        let down = B_LO[i] < 0.0;
        var v = e0;
        if (up || down) {
            for (var k = 0u; k < ROWS; k++) {
                if ((rows.lower & (1u << k)) == 0u) {
                    continue;
                }
                let e = piece_end(i, side, s, m, k + 1u, binding_slack(k, known));
                v = select(min(v, e), max(v, e), up);
            }
            for (var k = 0u; k < ROWS; k++) {
                if ((rows.upper & (1u << k)) == 0u) {
                    continue;
                }
                let e = piece_end(i, side, s, m, k + 1u, binding_slack(k, known));
                v = select(max(v, e), min(v, e), up);
            }
        }
        if (v != v) {
            return out;
        }
        if (side == 0u) {
            out.r.lo[i] = v;
        } else {
            out.r.hi[i] = v;
        }
    }
    out.ok = true;
    return out;
}

// The sources of step_rates' loop: the piece on the slabs, the enclosures, the network, the
// piece over the hull and on the set's faces (the last two for its Taylor rates).
const SOURCES: u32 = 5u;

fn step_rates(st: StepState, m: Moving, h: Iv, known: array<Iv, N0>, piece: u32, margin: real, at: u32, ends: u32) -> StepRates {
    var out = StepRates(no_rates(), no_rates(), piece, false, false);
    var slack = FIELD_SLACK;
    if (piece != PIECE_NONE && piece != PIECE_INACTIVE) {
        slack = binding_slack(piece - 1u, known);
    }
    let network = piece != PIECE_INACTIVE && margin < HUGE;
    // The enclosures' rates before their slack, which is the largest over every slab.
    var enclosing = ENCLOSE && piece == PIECE_NONE;
    var enc_slack: real = 0.0;
    var enc = SourceRates(no_rates(), no_rates());
    var over = no_rates();
    var euler = no_rates();
    let zero = zero_net();
    for (var k = 0u; k < SOURCES * ends; k++) {
        let f = k / SOURCES;
        let src = k % SOURCES;
        let i = f / 2u;
        let side = f % 2u;
        let on_piece = src == 0u || src >= 3u;
        if ((on_piece && piece == PIECE_NONE) || (src == 1u && !enclosing) || (src == 2u && !network)) {
            continue;
        }
        // The box the source is bounded on: the end's slab, the hull, or the set's face.
        let s = slab(st.lo, st.hi, m, h, i, side);
        var lo = s.lo;
        var hi = s.hi;
        if (src == 3u) {
            lo = m.hull_lo;
            hi = m.hull_hi;
        } else if (src == 4u) {
            lo = st.lo;
            hi = st.hi;
            if (side == 0u) {
                hi[i] = st.lo[i];
            } else {
                lo[i] = st.hi[i];
            }
        }
        // The source's bounds of v, M, field and slack.
        var nb = zero;
        var mg: real = 0.0;
        var pc: u32 = 0u;
        var sl = slack;
        if (on_piece) {
            pc = piece;
        } else if (src == 1u) {
            var sb: array<Iv, N0>;
            for (var j = 0u; j < N0; j++) {
                sb[j] = Iv(s.lo[j], s.hi[j]);
            }
            let x = meet_or(clip_to_safe_set(x_box(sb), HS_Z, HS_X), known);
            let v = enclose_v(x);
            if (!v.ok) {
                enclosing = false;
                continue;
            }
            enc_slack = max(enc_slack, enclosed_slack(x, v.v));
            var vl: array<real, M_OUT>;
            var vh: array<real, M_OUT>;
            for (var q = 0u; q < M_OUT; q++) {
                vl[q] = v.v[q].lo;
                vh[q] = v.v[q].hi;
            }
            nb = constant_bounds(vl, vh);
            sl = 0.0;
        } else {
            nb = slab_bounds(at, f);
            mg = margin;
            sl = FIELD_SLACK;
        }
        let b = bound_on(i, side, lo, hi, nb, mg, pc);
        if (src >= 3u) {
            var v = widen_up(b.hi, sl);
            if (side == 0u) {
                v = widen_down(b.lo, sl);
            }
            if (src == 3u) {
                over = meet_end(over, i, side, v);
            } else {
                euler = meet_end(euler, i, side, v);
            }
            continue;
        }
        // validated::slab_field's clamp to the slab's depth, and the curved rate.
        let c = curved_end(st.lo, st.hi, m, h, i, side, nb, mg, pc);
        var e = EndRate(widen_up(max(b.hi, m.d_hi[i]), sl), select(HUGE, widen_up(c.r, sl), c.ok));
        if (side == 0u) {
            e = EndRate(widen_down(min(b.lo, m.d_lo[i]), sl), select(-HUGE, widen_down(c.r, sl), c.ok));
        }
        if (src == 1u) {
            enc.field = meet_end(enc.field, i, side, e.field);
            enc.curved = meet_end(enc.curved, i, side, e.curved);
        } else {
            out.field = meet_end(out.field, i, side, e.field);
            out.second = meet_end(out.second, i, side, e.curved);
        }
    }
    if (piece != PIECE_NONE) {
        let t = piece_taylor(st, m, h, piece, over, euler, ends);
        if (t.ok) {
            out.second = meet_pair(out.second, t.r);
        }
    }
    if (enclosing) {
        out.field = meet_pair(out.field, widen_pair(enc.field, enc_slack));
        out.second = meet_pair(out.second, widen_pair(enc.curved, enc_slack));
        out.enclosed = true;
    }
    var lattice = false;
    if (ENCLOSE && piece == PIECE_NONE) {
        let l = lattice_rates(st, m, h, known, ends);
        if (l.ok) {
            out.field = meet_pair(out.field, l.r);
            out.enclosed = true;
            lattice = true;
        }
    }
    out.ok = piece != PIECE_NONE || enclosing || network || lattice;
    return out;
}

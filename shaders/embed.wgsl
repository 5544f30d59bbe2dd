// One Euler step of the embedding system per box (src/reach/embedding.rs is the original):
// takes the disturbance bound M (global, or the error map's local bound over the box's x-box:
// LOCAL_MARGIN), then from the network's bounds C̲x + d̲ ≤ N(x) ≤ C̄x + d̄ and N̲ ≤ N ≤ N̄ over the
// box, or over each of its 2n faces (FACES = 2N0, face-local; output.wgsl), bounds the embedding
// field on each face in interval arithmetic (generated ft_iv, jac_iv, g_iv), meets it with the
// filter's own field where the filter is provably one smooth function on the set and with its
// closed form's enclosures elsewhere (shaders/filter.wgsl), advances the closeness radius
// (Minkowski), takes the Euler step, checks the set against C and writes the recorded
// snapshot. `tick` then advances the step counter. Needs nnb.wgsl (the network's bounds) and loops.wgsl.

// Params (boxes).
@group(0) @binding(0) var<uniform> p: Params;
// Per box lo[N0], hi[N0], radius (embedding coordinates).
@group(0) @binding(1) var<storage, read_write> state: array<real>;
// Per box [poisoned, status, stop step, exact steps, enclosed steps], then the step counter and
// the loop check (1: the device cut a loop short; loops_ran_in_full).
@group(0) @binding(3) var<storage, read_write> flags: array<atomic<u32>>;
// Recorded states: slot-major, SW reals per box.
@group(0) @binding(4) var<storage, read_write> snap: array<real>;
// Per box the x-box the frames share, lo[N0], hi[N0] (MEET; shaders/settle.wgsl writes it).
@group(0) @binding(7) var<storage, read> known_x: array<real>;

fn stepped(g: u32, result: u32) {
    atomicStore(&flags[g * FLAG_W + 5u], result);
}

fn stop(g: u32, status: u32, step: u32) {
    atomicStore(&flags[g * FLAG_W + 1u], status);
    atomicStore(&flags[g * FLAG_W + 2u], step);
}

// One step of the radius recursion r ← e^z r + ℓM dt φ(z), z = c dt, φ(z) = (eᶻ − 1)/z
// (shaders/phi.wgsl), rounded up: closeness_step in src/reach/closeness.rs, term for term (each
// non-negative, so upper bounds of each bound the sum). φ is increasing: z's upper end.
fn closeness_step(r: real, c: real) -> real {
    let z = iv_mul(iv_point(c), Iv(DT_LO, DT_HI)).hi;
    let forcing = up(ELL_MC * DT_HI);
    return max(up(up(exp_up(z) * r) + up(forcing * phi_up(z))), 0.0);
}

@compute @workgroup_size(1)
fn tick() {
    atomicAdd(&flags[FLAG_W * p.boxes], 1u);
}

// Face rates of the embedding field: dx̲/dt (lo) and dx̄/dt (hi) per state.
struct Rates {
    lo: array<real, N0>,
    hi: array<real, N0>,
}

// The face rates `r` of `piece`'s field over the box xb made to bound the Euler map over the
// whole set where a step may turn a state around (euler_turn in src/reach/embedding.rs, before
// any slack, as there): the slope is ∂ᵢf̃ᵢ over the box, plus with `row` (the network bounded
// over the whole box, constant g) the interaction row's diagonal of that side.
fn turned(r: Rates, xb: array<Iv, N0>, piece: u32, nb: NetBounds, margin: real, row: bool) -> Rates {
    var out = r;
    let dt = Iv(DT_LO, DT_HI);
    for (var i = 0u; i < N0; i++) {
        let jac = field_jac(piece, i, i, xb);
        let w = iv_sub(iv_point(xb[i].hi), iv_point(xb[i].lo)).hi;
        for (var side = 0u; side < 2u; side++) {
            var slope = jac;
            if (row && G_CONSTANT) {
                slope = iv_add(jac, interaction_row(nb, margin, i, side).row[i]);
            }
            let extra = turn_rate(slope, w, dt);
            if (extra > 0.0) {
                if (side == 0u) {
                    out.lo[i] = down(out.lo[i] - extra);
                } else {
                    out.hi[i] = up(out.hi[i] + extra);
                }
            }
        }
    }
    return out;
}

// Bounds of the embedding field; `ok` false where there are none.
struct Field {
    lo: array<real, N0>,
    hi: array<real, N0>,
    ok: bool,
}

// The filtered system's field with v enclosed by the closed form on each face (enclosure_field
// in src/reach/cpu.rs): each face's x-box within S gives an enclosure of v (shaders/filter.wgsl),
// taken as constant bounds of the input (each face's x-box met with `known` where the frames are
// met), widened by the transform's slack; `ok` false where an enclosure is unbounded (near a jump
// of v).
fn enclosure_field(xb: array<Iv, N0>, cen: array<real, N0>, known: array<Iv, N0>) -> Field {
    var out: Field;
    out.ok = false;
    var slack: real = 0.0;
    var r: Rates;
    for (var f = 0u; f < 2u * N0; f++) {
        let i = f / 2u;
        let side = f % 2u;
        var face = xb;
        if (side == 0u) {
            face[i] = iv_point(xb[i].lo);
        } else {
            face[i] = iv_point(xb[i].hi);
        }
        var x = clip_to_safe_set(x_box(face), HS_Z, HS_X);
        if (MEET) {
            x = meet_or(x, known);
        }
        let v = enclose_v(x);
        if (!v.ok) {
            return out;
        }
        slack = max(slack, enclosed_slack(x, v.v));
        var lo: array<real, M_OUT>;
        var hi: array<real, M_OUT>;
        for (var k = 0u; k < M_OUT; k++) {
            lo[k] = v.v[k].lo;
            hi[k] = v.v[k].hi;
        }
        let field = face_field(i, side, xb, cen, constant_bounds(lo, hi), 0.0, 0u);
        if (side == 0u) {
            r.lo[i] = field.lo;
        } else {
            r.hi[i] = field.hi;
        }
    }
    // Face enclosures say nothing of v inside the set: f̃'s part alone turns (design §7).
    var none: array<real, M_OUT>;
    r = turned(r, xb, 0u, constant_bounds(none, none), 0.0, false);
    for (var i = 0u; i < N0; i++) {
        out.lo[i] = widen_down(r.lo[i], slack);
        out.hi[i] = widen_up(r.hi[i], slack);
    }
    out.ok = true;
    return out;
}

@compute @workgroup_size(64)
fn embed(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    if (atomicLoad(&flags[g * FLAG_W + 1u]) != LIVE) {
        return;
    }
    let step = atomicLoad(&flags[FLAG_W * p.boxes]);
    let status = embedding_step(g, step);
    if (!loops_ran_in_full()) {
        atomicStore(&flags[FLAG_W * p.boxes + 1u], 1u);
    }
    if (status != LIVE) {
        stop(g, status, step);
    }
}

// One Euler step of box g (step `step`): writes its state (and snapshot); its status after
// the step.
fn embedding_step(g: u32, step: u32) -> u32 {
    var lo: array<real, N0>;
    var hi: array<real, N0>;
    var xb: array<Iv, N0>;
    var cen: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        lo[j] = state[g * SW + j];
        hi[j] = state[g * SW + N0 + j];
        xb[j] = Iv(lo[j], hi[j]);
        cen[j] = clamp(lo[j] + 0.5 * (hi[j] - lo[j]), lo[j], hi[j]);
    }
    var radius = state[g * SW + 2u * N0];

    // What bounds v on this step (src/reach/cpu.rs, horizon): the filter's own field where it is
    // provably one smooth function on the set, else its closed form's enclosures on each face
    // (ENCLOSE), and the network plus the error margin except where v = 0; their meet.
    // Where the frames are met (MEET), the x-box every frame shares (shaders/settle.wgsl);
    // else this set's own.
    var known = clip_to_safe_set(x_box(xb), HS_Z, HS_X);
    if (MEET) {
        for (var j = 0u; j < N0; j++) {
            known[j] = Iv(known_x[g * 2u * N0 + j], known_x[g * 2u * N0 + N0 + j]);
        }
    }
    let piece = piece_on(known);
    var dxl: array<real, N0>;
    var dxu: array<real, N0>;
    for (var i = 0u; i < N0; i++) {
        dxl[i] = -HUGE;
        dxu[i] = HUGE;
    }
    var have = false;
    if (piece != PIECE_NONE) {
        atomicAdd(&flags[g * FLAG_W + 3u], 1u);
        var slack = FIELD_SLACK;
        if (piece != PIECE_INACTIVE) {
            slack = binding_slack(piece - 1u, known);
        }
        var none: array<real, M_OUT>;
        for (var k = 0u; k < M_OUT; k++) {
            none[k] = 0.0;
        }
        let zero = constant_bounds(none, none);
        var r: Rates;
        for (var f = 0u; f < 2u * N0; f++) {
            let i = f / 2u;
            let side = f % 2u;
            let v = face_field(i, side, xb, cen, zero, 0.0, piece);
            if (side == 0u) {
                r.lo[i] = v.lo;
            } else {
                r.hi[i] = v.hi;
            }
        }
        // v = the piece's own closed form, inside the set as on its faces: the piece's whole
        // field turns (its interaction row with zero bounds is zero).
        r = turned(r, xb, piece, zero, 0.0, false);
        for (var i = 0u; i < N0; i++) {
            dxl[i] = widen_down(r.lo[i], slack);
            dxu[i] = widen_up(r.hi[i], slack);
        }
        have = true;
    } else if (ENCLOSE) {
        let enclosed = enclosure_field(xb, cen, known);
        if (enclosed.ok) {
            atomicAdd(&flags[g * FLAG_W + 4u], 1u);
            dxl = enclosed.lo;
            dxu = enclosed.hi;
            have = true;
        }
    }
    var margin: real = 0.0;
    if (piece != PIECE_INACTIVE) {
        // The disturbance bound first, as src/reach/cpu.rs: M = ∞ leaves the network out, and
        // ends the box where nothing else bounds v.
        margin = margin_of(known);
        let poisoned = atomicLoad(&flags[g * FLAG_W]) != 0u || !bounds_finite(g);
        if (margin < HUGE && !poisoned) {
            // The embedding field, face by face (embedding_field_by_face in
            // src/reach/embedding.rs).
            var r: Rates;
            for (var f = 0u; f < 2u * N0; f++) {
                let i = f / 2u;
                let side = f % 2u;
                let v = face_field(i, side, xb, cen, load_bounds(face_index(g, i, side)), margin, 0u);
                if (side == 0u) {
                    r.lo[i] = v.lo;
                } else {
                    r.hi[i] = v.hi;
                }
            }
            // Bounds over the whole box bound v inside the set too: their slope turns with f̃'s;
            // face-local bounds say nothing of it there (design §7).
            r = turned(r, xb, 0u, load_bounds(face_index(g, 0u, 0u)), margin, FACES == 1u);
            for (var i = 0u; i < N0; i++) {
                dxl[i] = max(dxl[i], widen_down(r.lo[i], FIELD_SLACK));
                dxu[i] = min(dxu[i], widen_up(r.hi[i], FIELD_SLACK));
            }
            have = true;
        } else if (!have) {
            if (MEET) {
                // The meet ends the box where no frame stepped (shaders/settle.wgsl).
                stepped(g, select(STEP_NON_FINITE, STEP_NONE, margin >= HUGE));
                return LIVE;
            }
            return select(NON_FINITE, NO_BOUND, margin >= HUGE);
        }
    }

    // The closeness radius (Minkowski): c ≥ μ([Df̃](C) + [g](C)·hull(C̲, C̄)).
    if (MINKOWSKI) {
        let nb0 = load_bounds(face_index(g, 0u, 0u));
        let a_lo = nb0.a_lo;
        let a_hi = nb0.a_hi;
        var rate = -HUGE;
        var am: array<Iv, N0 * N0>;
        for (var i = 0u; i < N0; i++) {
            for (var j = 0u; j < N0; j++) {
                var s = Iv(JR_LO[i * N0 + j], JR_HI[i * N0 + j]);
                for (var k = 0u; k < M_OUT; k++) {
                    let h = Iv(min(a_lo[k * N0 + j], a_hi[k * N0 + j]), max(a_lo[k * N0 + j], a_hi[k * N0 + j]));
                    s = iv_add(s, iv_mul(Iv(GR_LO[i * M_OUT + k], GR_HI[i * M_OUT + k]), h));
                }
                am[i * N0 + j] = s;
            }
        }
        for (var i = 0u; i < N0; i++) {
            var off: real = 0.0;
            for (var j = 0u; j < N0; j++) {
                if (j == i) {
                    continue;
                }
                var m = iv_mag(am[i * N0 + j]);
                if (NORM == 1u) {
                    m = iv_mag(am[j * N0 + i]);
                } else if (NORM == 2u) {
                    m = iv_mag(iv_mul(iv_add(am[i * N0 + j], am[j * N0 + i]), iv_point(0.5)));
                }
                off = up(off + m);
            }
            rate = max(rate, up(am[i * N0 + i].hi + off));
        }
        radius = closeness_step(radius, rate);
        if (!finite(radius)) {
            return NON_FINITE;
        }
    }

    // Euler step, rounded outward (dt ∈ [DT_LO, DT_HI]).
    var inverted = false;
    var fin = true;
    for (var j = 0u; j < N0; j++) {
        lo[j] = down(lo[j] + min(down(DT_LO * dxl[j]), down(DT_HI * dxl[j])));
        hi[j] = up(hi[j] + max(up(DT_LO * dxu[j]), up(DT_HI * dxu[j])));
        inverted = inverted || lo[j] > hi[j];
        fin = fin && finite(lo[j]) && finite(hi[j]) && finite(dxl[j]) && finite(dxu[j]);
    }
    if (MEET) {
        // The frames' sets are clipped, met, checked against C and recorded together
        // (shaders/settle.wgsl), as src/reach/cpu.rs advances them.
        if (!fin) {
            stepped(g, STEP_NON_FINITE);
        } else if (inverted) {
            stepped(g, STEP_INVERTED);
        } else {
            for (var j = 0u; j < N0; j++) {
                state[g * SW + j] = lo[j];
                state[g * SW + N0 + j] = hi[j];
            }
            stepped(g, STEP_OK);
        }
        return LIVE;
    }
    if (!fin) {
        return NON_FINITE;
    }
    if (inverted) {
        return INVERTED;
    }
    if (HS_Z > 0u) {
        var zb: array<Iv, N0>;
        for (var j = 0u; j < N0; j++) {
            zb[j] = Iv(lo[j], hi[j]);
        }
        zb = clip_to_safe_set(zb, 0u, HS_Z);
        for (var j = 0u; j < N0; j++) {
            lo[j] = zb[j].lo;
            hi[j] = zb[j].hi;
        }
    }
    for (var j = 0u; j < N0; j++) {
        state[g * SW + j] = lo[j];
        state[g * SW + N0 + j] = hi[j];
    }
    state[g * SW + 2u * N0] = radius;

    // The filtered system's set in x (within S) against C (C rounded inward).
    var sb: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        if (radius > 0.0) {
            sb[j] = Iv(down(lo[j] - radius), up(hi[j] + radius));
        } else {
            sb[j] = Iv(lo[j], hi[j]);
        }
    }
    let xs = clip_to_safe_set(x_box(sb), HS_Z, HS_X);
    var inside = true;
    for (var i = 0u; i < N0; i++) {
        inside = inside && REGION_LO[i] <= xs[i].lo && xs[i].hi <= REGION_HI[i];
    }
    if (!inside) {
        return LEFT_REGION;
    }
    let done = step + 1u;
    if (done % EVERY == 0u || done == STEPS) {
        let slot = (done + EVERY - 1u) / EVERY - 1u;
        let at = (slot * p.boxes + g) * SW;
        for (var j = 0u; j < SW; j++) {
            snap[at + j] = state[g * SW + j];
        }
    }
    return LIVE;
}

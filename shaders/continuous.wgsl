// The continuous time model's common path in a pipeline (docs/design.md §7.1 item 3b, §7.4),
// one frame, the facts taken on the hull's x-box within S: the filter's proven piece and its
// closed form's enclosures (filter.wgsl), and the disturbance bound M (global, or the error
// map's local bound: margins.wgsl) for the network's field. `slabs_of` writes each live
// box's 2n slabs of its guessed moving box (face-local, FACES = 2N0) or its hull (FACES = 1) as
// its bound boxes, so the GEMM, ReLU, backward and output kernels run on them unchanged; `cstep`
// then takes the box-step (slab_step.wgsl: guess_step, step_rates, finish_step), clips the set to
// S and keeps the hull and the faces' rates for the host. A box-step it cannot finish (a tube's
// first step, a guess refused, a check failed, bounds not finite, a set inside out) keeps its
// state and is flagged: the host steps it with the CPU engine's own step
// (src/gpu/backend/continuous.rs). The host reads every box's result after each step and
// records the samples and flowpipes (the CPU engine's rules). Where two frames are met (MEET),
// `cpipes` (cmeet.wgsl, in the first frame's module) has guessed both frames' moving boxes, met
// their hulls and written them to `cont` with the flowpipes' shared x-box (`pipe_known`): both
// kernels take the step's moving box from there, `cstep` its facts on `pipe_known`, and it leaves
// the clip to S to the meet after the step (`cmeet`). Needs slab_step.wgsl and what it needs
// (guess.wgsl, filter.wgsl, sets.wgsl), margins.wgsl, nnb.wgsl, loops.wgsl.

// Params (boxes).
@group(0) @binding(0) var<uniform> p: Params;
// Per box CW reals: the StepState (lo, hi, r_lo, r_hi, b_lo, b_hi: N0 each; the rates it has),
// then the step's moving box: its hull (lo, hi) and faces' rates (s_lo, s_hi), which the step
// leaves for the host, and its slabs' depths (d_lo, d_hi), the other frame's set over the step
// (lo, hi) and its pad (these three written by `cpipes` where frames are met).
@group(0) @binding(1) var<storage, read_write> cont: array<real>;
// Per box [poisoned, status, -, piece, enclosed, result]: status is the host's (LIVE while it
// steps), result this step's (C_DEVICE, C_HOST); piece and enclosed whether a step the device
// took had the filter's proven piece, its closed form's enclosures (the tube's exact and
// enclosed steps).
@group(0) @binding(3) var<storage, read_write> flags: array<atomic<u32>>;
// The bound boxes, FACES per box: lo[N0], hi[N0], radius (as shaders/faces.wgsl writes faces).
@group(0) @binding(4) var<storage, read_write> bound_boxes: array<real>;
// Where frames are met, per box the x-box of this step's flowpipes within S, met over the frames
// (`cpipes`; the CPU's `pipe_known`): the step's facts are taken there.
@group(0) @binding(7) var<storage, read> pipe_known: array<real>;

const CW: u32 = 14u * N0 + 2u;
// Offsets in a box's CW reals of its moving box's hull, faces' rates and depths, and of the
// other frame's set over the step with its pad (where slabs are clipped by it, CLIP_SLABS).
const C_HULL: u32 = 6u * N0 + 1u;
const C_RATES: u32 = 8u * N0 + 1u;
const C_DEPTHS: u32 = 10u * N0 + 1u;
const C_OTHER: u32 = 12u * N0 + 1u;

const SWB: u32 = 2u * N0 + 1u;

fn part(g: u32, k: u32) -> array<real, N0> {
    var a: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        a[j] = cont[g * CW + k * N0 + j];
    }
    return a;
}

fn put(g: u32, k: u32, a: array<real, N0>) {
    for (var j = 0u; j < N0; j++) {
        cont[g * CW + k * N0 + j] = a[j];
    }
}

fn reals_at(g: u32, at: u32) -> array<real, N0> {
    var a: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        a[j] = cont[g * CW + at + j];
    }
    return a;
}

// The step's moving box: guessed from the box's state, or where frames are met the one `cpipes`
// guessed and met with the other frame's (on the common path only where both frames' were).
fn step_guess(g: u32, st: StepState) -> Guess {
    if (!MEET) {
        return guess_step(st, h_step());
    }
    var gs: Guess;
    gs.on_path = atomicLoad(&flags[g * FLAG_W + 2u]) == MET_GUESSED;
    gs.m.hull_lo = reals_at(g, C_HULL);
    gs.m.hull_hi = reals_at(g, C_HULL + N0);
    gs.m.s_lo = reals_at(g, C_RATES);
    gs.m.s_hi = reals_at(g, C_RATES + N0);
    gs.m.d_lo = reals_at(g, C_DEPTHS);
    gs.m.d_hi = reals_at(g, C_DEPTHS + N0);
    gs.m.ok = gs.on_path;
    gs.m.clip = CLIP_SLABS;
    if (CLIP_SLABS) {
        gs.m.o_lo = reals_at(g, C_OTHER);
        gs.m.o_hi = reals_at(g, C_OTHER + N0);
        gs.m.o_pad = cont[g * CW + C_OTHER + 2u * N0];
    }
    return gs;
}

fn load_state(g: u32) -> StepState {
    return StepState(part(g, 0u), part(g, 1u), part(g, 2u), part(g, 3u), part(g, 4u), part(g, 5u), u32(cont[g * CW + 6u * N0]));
}

fn put_bound_box(k: u32, lo: array<real, N0>, hi: array<real, N0>) {
    for (var j = 0u; j < N0; j++) {
        bound_boxes[k * SWB + j] = lo[j];
        bound_boxes[k * SWB + N0 + j] = hi[j];
    }
    bound_boxes[k * SWB + 2u * N0] = 0.0;
}

@compute @workgroup_size(64)
fn slabs_of(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    let st = load_state(g);
    let gs = step_guess(g, st);
    // Boxes the device does not step this time get their set (finite, bounds unused).
    let live = atomicLoad(&flags[g * FLAG_W + 1u]) == LIVE && gs.on_path;
    for (var f = 0u; f < FACES; f++) {
        if (!live) {
            put_bound_box(g * FACES + f, st.lo, st.hi);
        } else if (FACES == 1u) {
            put_bound_box(g, gs.m.hull_lo, gs.m.hull_hi);
        } else {
            let s = slab(st.lo, st.hi, gs.m, h_step(), f / 2u, f % 2u);
            put_bound_box(g * FACES + f, s.lo, s.hi);
        }
    }
}

@compute @workgroup_size(64)
fn cstep(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    if (atomicLoad(&flags[g * FLAG_W + 1u]) != LIVE) {
        return;
    }
    box_step(g);
    if (!loops_ran_in_full()) {
        atomicStore(&flags[FLAG_W * p.boxes + 1u], 1u);
    }
}

fn box_step(g: u32) {
    let poisoned = atomicLoad(&flags[g * FLAG_W]) != 0u;
    // A bound kernel marks a box whose bounds overflowed; the host's step decides what it means.
    atomicStore(&flags[g * FLAG_W], 0u);
    atomicStore(&flags[g * FLAG_W + 5u], C_HOST);
    let st = load_state(g);
    let gs = step_guess(g, st);
    if (!gs.on_path || poisoned || !bounds_finite(g)) {
        return;
    }
    // The facts on the hull's x-box within S, met over the frames where they are (the CPU's
    // `pipe_known`): the piece, M there; where nothing bounds the field (M = +∞ and no piece or
    // enclosure) the host's step ends the box as the CPU does.
    var hull: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        hull[j] = Iv(gs.m.hull_lo[j], gs.m.hull_hi[j]);
    }
    var known = clip_to_safe_set(x_box(hull), HS_Z, HS_X);
    if (MEET) {
        for (var j = 0u; j < N0; j++) {
            known[j] = Iv(pipe_known[g * 2u * N0 + j], pipe_known[g * 2u * N0 + N0 + j]);
        }
    }
    // Every source of the CPU's step (slab_step.wgsl step_rates): the proven piece, the closed
    // form's enclosures, the network with M (not on the inactive piece: v = 0 there).
    let piece = piece_on(known);
    var margin = HUGE;
    if (piece != PIECE_INACTIVE) {
        margin = margin_of(known);
    }
    // 2N0 ends, from a value the driver cannot fold (step_rates keeps its loop then).
    let ends = select(2u * N0, 0x7fffffffu, arrayLength(&cont) == 0x7fffffffu);
    let r = step_rates(st, gs.m, h_step(), known, piece, margin, g, ends);
    if (!r.ok) {
        return;
    }
    let dl = r.field.lo;
    let du = r.field.hi;
    let cl = r.second.lo;
    let cu = r.second.hi;
    let s = finish_step(st, gs.m, h_step(), dl, du, cl, cu);
    if (!s.proven) {
        return;
    }
    // The CPU engine's advance: a set inside out or not finite ends the tube (the host's step
    // ends it as the CPU does); else the set is clipped to S's half-spaces in its coordinates
    // (where frames are met, by the meet after the step: cmeet.wgsl).
    var zb: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        if (!(s.st.lo[j] <= s.st.hi[j] && finite(s.st.lo[j]) && finite(s.st.hi[j]))) {
            return;
        }
        zb[j] = Iv(s.st.lo[j], s.st.hi[j]);
    }
    if (HS_Z > 0u && !MEET) {
        zb = clip_to_safe_set(zb, 0u, HS_Z);
    }
    var lo: array<real, N0>;
    var hi: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        lo[j] = zb[j].lo;
        hi[j] = zb[j].hi;
    }
    put(g, 0u, lo);
    put(g, 1u, hi);
    put(g, 2u, s.st.r_lo);
    put(g, 3u, s.st.r_hi);
    put(g, 4u, s.st.b_lo);
    put(g, 5u, s.st.b_hi);
    cont[g * CW + 6u * N0] = real(s.st.rates);
    for (var j = 0u; j < N0; j++) {
        cont[g * CW + C_HULL + j] = gs.m.hull_lo[j];
        cont[g * CW + C_HULL + N0 + j] = gs.m.hull_hi[j];
        cont[g * CW + C_RATES + j] = gs.m.s_lo[j];
        cont[g * CW + C_RATES + N0 + j] = gs.m.s_hi[j];
    }
    atomicStore(&flags[g * FLAG_W + 3u], u32(r.piece != PIECE_NONE));
    atomicStore(&flags[g * FLAG_W + 4u], u32(r.enclosed));
    atomicStore(&flags[g * FLAG_W + 5u], C_DEVICE);
}

// The network's bounds on slab f of box g (slab_step.wgsl's step_rates): the bound kernels'.
fn slab_bounds(g: u32, f: u32) -> NetBounds {
    return load_bounds(face_index(g, f / 2u, f % 2u));
}

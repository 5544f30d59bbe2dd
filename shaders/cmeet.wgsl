// The continuous model's meet of two frames (docs/design.md §2.11, §7.4; src/reach/cpu_guess.rs
// `guess_moving`, cpu_time.rs `meet_pipes`, cpu.rs `advance` and `settle` are the originals), in
// the first frame's module (z = T x): frame 0 keeps the set in z, frame 1 in x; each frame's
// `cont` as continuous.wgsl lays it out. Before the step, `cpipes` guesses both frames' moving
// boxes (no rates, a guess refused, or the x frame's hull not within C: the host's step), meets
// the x-boxes of their hulls within S into `pipe_known` (the step's facts are taken there) and
// each hull with the box of its coordinates around it, and writes both moving boxes to `cont`
// for `slabs_of` and `cstep` of each frame. After both frames' `cstep`, `cmeet` takes the step
// on the device only where both frames did (the CPU proves the guess on every frame together,
// `guess_holds`): then their sets are met (sets.wgsl meet_frames) and `known` is their shared
// x-box; else both frames' results say C_HOST and the host steps the box from its state before
// the step. Needs sets.wgsl, validated.wgsl, guess.wgsl.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> cont0: array<real>;
@group(0) @binding(2) var<storage, read_write> cont1: array<real>;
@group(0) @binding(3) var<storage, read_write> flags0: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> flags1: array<atomic<u32>>;
// Per box the frames' shared x-box after the meet (lo, hi).
@group(0) @binding(5) var<storage, read_write> known: array<real>;
// Per box the x-box of this step's flowpipes within S, met over the frames (lo, hi).
@group(0) @binding(6) var<storage, read_write> pipe_known: array<real>;

const CW: u32 = 14u * N0 + 2u;
const C_HULL: u32 = 6u * N0 + 1u;
const C_RATES: u32 = 8u * N0 + 1u;
const C_DEPTHS: u32 = 10u * N0 + 1u;
const C_OTHER: u32 = 12u * N0 + 1u;

fn cont_at(f: u32, at: u32) -> real {
    if (f == 0u) {
        return cont0[at];
    }
    return cont1[at];
}

fn cont_put(f: u32, at: u32, v: real) {
    if (f == 0u) {
        cont0[at] = v;
    } else {
        cont1[at] = v;
    }
}

fn reals(f: u32, at: u32) -> array<real, N0> {
    var a: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        a[j] = cont_at(f, at + j);
    }
    return a;
}

fn put_reals(f: u32, at: u32, a: array<real, N0>) {
    for (var j = 0u; j < N0; j++) {
        cont_put(f, at + j, a[j]);
    }
}

fn state_of(f: u32, g: u32) -> StepState {
    let b = g * CW;
    return StepState(reals(f, b), reals(f, b + N0), reals(f, b + 2u * N0), reals(f, b + 3u * N0), reals(f, b + 4u * N0), reals(f, b + 5u * N0), u32(cont_at(f, b + 6u * N0)));
}

fn set_of(f: u32, g: u32) -> array<Iv, N0> {
    var s: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        s[j] = Iv(cont_at(f, g * CW + j), cont_at(f, g * CW + N0 + j));
    }
    return s;
}

fn put_set(f: u32, g: u32, s: array<Iv, N0>) {
    for (var j = 0u; j < N0; j++) {
        cont_put(f, g * CW + j, s[j].lo);
        cont_put(f, g * CW + N0 + j, s[j].hi);
    }
}

// Frame f's moving box m with its hull met (`hull`), and the other frame's set over the step
// (`other`, in its coordinates) with its pad, for continuous.wgsl's step_guess.
fn put_moving(f: u32, g: u32, m: Moving, hull: array<Iv, N0>, other: array<Iv, N0>, pad: real) {
    var lo: array<real, N0>;
    var hi: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        lo[j] = hull[j].lo;
        hi[j] = hull[j].hi;
    }
    let b = g * CW;
    put_reals(f, b + C_HULL, lo);
    put_reals(f, b + C_HULL + N0, hi);
    put_reals(f, b + C_RATES, m.s_lo);
    put_reals(f, b + C_RATES + N0, m.s_hi);
    put_reals(f, b + C_DEPTHS, m.d_lo);
    put_reals(f, b + C_DEPTHS + N0, m.d_hi);
    for (var j = 0u; j < N0; j++) {
        cont_put(f, b + C_OTHER + j, other[j].lo);
        cont_put(f, b + C_OTHER + N0 + j, other[j].hi);
    }
    cont_put(f, b + C_OTHER + 2u * N0, pad);
}

fn hull_of(m: Moving) -> array<Iv, N0> {
    var h: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        h[j] = Iv(m.hull_lo[j], m.hull_hi[j]);
    }
    return h;
}

@compute @workgroup_size(64)
fn cpipes(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes || atomicLoad(&flags0[g * FLAG_W + 1u]) != LIVE) {
        return;
    }
    atomicStore(&flags0[g * FLAG_W + 2u], 0u);
    atomicStore(&flags1[g * FLAG_W + 2u], 0u);
    let g0 = guess_in(state_of(0u, g), h_step(), !TRANSFORM);
    let g1 = guess_in(state_of(1u, g), h_step(), true);
    if (!g0.on_path || !g1.on_path) {
        return;
    }
    // meet_pipes: the hulls' x-boxes within S met (frame 1's half-spaces of S are the x rows of
    // this module's tables), each hull met with the box of its coordinates around that.
    let h0 = hull_of(g0.m);
    let h1 = hull_of(g1.m);
    let k = meet_or(clip_to_safe_set(x_box(h0), HS_Z, HS_X), clip_to_safe_set(h1, HS_Z, HS_X));
    let p0 = meet_or(h0, z_box_of(k));
    let p1 = meet_or(h1, k);
    // Each frame's slabs clipped by the other's met hull (cpu_time.rs `meet_slabs`; both
    // guessed, so proven together): frame 0's in x (no pad), frame 1's in z, padded by ρ‖T k‖∞.
    put_moving(0u, g, g0.m, p0, p1, 0.0);
    put_moving(1u, g, g1.m, p1, p0, t_pad(t_times(k)));
    for (var j = 0u; j < N0; j++) {
        pipe_known[g * 2u * N0 + j] = k[j].lo;
        pipe_known[g * 2u * N0 + N0 + j] = k[j].hi;
    }
    atomicStore(&flags0[g * FLAG_W + 2u], MET_GUESSED);
    atomicStore(&flags1[g * FLAG_W + 2u], MET_GUESSED);
}

@compute @workgroup_size(64)
fn cmeet(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes || atomicLoad(&flags0[g * FLAG_W + 1u]) != LIVE) {
        return;
    }
    if (atomicLoad(&flags0[g * FLAG_W + 5u]) != C_DEVICE || atomicLoad(&flags1[g * FLAG_W + 5u]) != C_DEVICE) {
        atomicStore(&flags0[g * FLAG_W + 5u], C_HOST);
        atomicStore(&flags1[g * FLAG_W + 5u], C_HOST);
        return;
    }
    let met = meet_frames(set_of(0u, g), set_of(1u, g), true, true);
    put_set(0u, g, met.z);
    put_set(1u, g, met.x);
    for (var j = 0u; j < N0; j++) {
        known[g * 2u * N0 + j] = met.known[j].lo;
        known[g * 2u * N0 + N0 + j] = met.known[j].hi;
    }
}

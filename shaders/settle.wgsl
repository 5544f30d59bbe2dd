// The meet of the frames after both stepped (MEET: a transform with intersect_x; `settle` and
// `advance` in src/reach/cpu.rs are the originals): frame 0 keeps the set in z = T x (this
// module's problem), frame 1 in x. Of the frames that stepped, a non-finite or inverted set ends
// the box; each set is clipped to S, `known` becomes the meet of their x-boxes within S, and each
// set is met with `known`'s box in its coordinates (replaced by it where the frame could not
// step) and clipped again (sets.wgsl meet_frames); a box ends only where no frame stepped. The recorded sample is frame
// 0's x-box met with `known`: checked against C here, written to frame 0's snapshot (its z-set)
// and frame 1's (`known`) for the host.

@group(0) @binding(0) var<uniform> p: Params;
@group(0) @binding(1) var<storage, read_write> state0: array<real>;
@group(0) @binding(2) var<storage, read_write> state1: array<real>;
@group(0) @binding(3) var<storage, read_write> flags0: array<atomic<u32>>;
@group(0) @binding(4) var<storage, read_write> flags1: array<atomic<u32>>;
@group(0) @binding(5) var<storage, read_write> snap0: array<real>;
@group(0) @binding(6) var<storage, read_write> snap1: array<real>;
@group(0) @binding(7) var<storage, read_write> known_x: array<real>;

const SW: u32 = 2u * N0 + 1u;

// Ends box g in both frames.
fn end_box(g: u32, status: u32, step: u32) {
    atomicStore(&flags0[g * FLAG_W + 1u], status);
    atomicStore(&flags0[g * FLAG_W + 2u], step);
    atomicStore(&flags1[g * FLAG_W + 1u], status);
    atomicStore(&flags1[g * FLAG_W + 2u], step);
}

@compute @workgroup_size(64)
fn settle(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes || atomicLoad(&flags0[g * FLAG_W + 1u]) != LIVE) {
        return;
    }
    let step = atomicLoad(&flags0[FLAG_W * p.boxes]);
    let r0 = atomicLoad(&flags0[g * FLAG_W + 5u]);
    let r1 = atomicLoad(&flags1[g * FLAG_W + 5u]);
    if (r0 == STEP_NONE && r1 == STEP_NONE) {
        end_box(g, NO_BOUND, step);
        return;
    }
    if (r0 == STEP_NON_FINITE || r1 == STEP_NON_FINITE) {
        end_box(g, NON_FINITE, step);
        return;
    }
    if (r0 == STEP_INVERTED || r1 == STEP_INVERTED) {
        end_box(g, INVERTED, step);
        return;
    }
    var z: array<Iv, N0>;
    var x: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        z[j] = Iv(state0[g * SW + j], state0[g * SW + N0 + j]);
        x[j] = Iv(state1[g * SW + j], state1[g * SW + N0 + j]);
    }
    let met = meet_frames(z, x, r0 != STEP_NONE, r1 != STEP_NONE);
    z = met.z;
    x = met.x;
    let known = met.known;
    for (var j = 0u; j < N0; j++) {
        state0[g * SW + j] = z[j].lo;
        state0[g * SW + N0 + j] = z[j].hi;
        state1[g * SW + j] = x[j].lo;
        state1[g * SW + N0 + j] = x[j].hi;
        known_x[g * 2u * N0 + j] = known[j].lo;
        known_x[g * 2u * N0 + N0 + j] = known[j].hi;
    }
    let sample = meet_or(clip_to_safe_set(x_box(z), HS_Z, HS_X), known);
    var inside = true;
    for (var i = 0u; i < N0; i++) {
        inside = inside && REGION_LO[i] <= sample[i].lo && sample[i].hi <= REGION_HI[i];
    }
    if (!inside) {
        end_box(g, LEFT_REGION, step);
        return;
    }
    let done = step + 1u;
    if (done % EVERY == 0u || done == STEPS) {
        let at = (((done + EVERY - 1u) / EVERY - 1u) * p.boxes + g) * SW;
        for (var j = 0u; j < N0; j++) {
            snap0[at + j] = z[j].lo;
            snap0[at + N0 + j] = z[j].hi;
            snap1[at + j] = known[j].lo;
            snap1[at + N0 + j] = known[j].hi;
        }
        snap0[at + 2u * N0] = 0.0;
        snap1[at + 2u * N0] = 0.0;
    }
}

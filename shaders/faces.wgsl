// Face-local bounds (immrax's local mode; src/reach/cpu.rs builds the same boxes): the network is
// bounded over each of the 2n faces of every box, so the bound batch holds FACES = 2N0 boxes per
// box. One thread per box writes, for each face (i, side), the box with coordinate i fixed at
// lo_i (side 0) or hi_i (side 1) at bound index g·FACES + 2i + side, in the layout of `state`.
// Exact copies: the faces are subsets of the box, so bounds over them are bounds over the faces.

// Params (boxes).
@group(0) @binding(0) var<uniform> p: Params;
// Per box lo[N0], hi[N0], radius.
@group(0) @binding(1) var<storage, read> state: array<real>;
// Per face box lo[N0], hi[N0], radius.
@group(0) @binding(2) var<storage, read_write> faces: array<real>;

@compute @workgroup_size(64)
fn faces_of(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    for (var i = 0u; i < N0; i++) {
        for (var side = 0u; side < 2u; side++) {
            let at = (g * FACES + 2u * i + side) * SW;
            let v = state[g * SW + side * N0 + i];
            for (var j = 0u; j < N0; j++) {
                faces[at + j] = select(state[g * SW + j], v, j == i);
                faces[at + N0 + j] = select(state[g * SW + N0 + j], v, j == i);
            }
            faces[at + 2u * N0] = state[g * SW + 2u * N0];
        }
    }
}

// The network's bounds per bound box as shaders/output.wgsl records them (`nnb`, binding 2), read
// by the Euler embedding kernel (embed.wgsl) and the continuous step (continuous.wgsl).

// The network's bounds over each bound box, FACES per box.
@group(0) @binding(2) var<storage, read> nnb: array<real>;

// The network's bounds over bound box k, as shaders/output.wgsl records them.
fn load_bounds(k: u32) -> NetBounds {
    var b: NetBounds;
    let at = k * NB_W;
    for (var q = 0u; q < M_OUT * N0; q++) {
        b.a_lo[q] = nnb[at + q];
        b.a_hi[q] = nnb[at + M_OUT * N0 + q];
    }
    let o = at + 2u * M_OUT * N0;
    for (var q = 0u; q < M_OUT; q++) {
        b.d_lo[q] = nnb[o + q];
        b.d_hi[q] = nnb[o + M_OUT + q];
        b.n_lo[q] = nnb[o + 2u * M_OUT + q];
        b.n_hi[q] = nnb[o + 3u * M_OUT + q];
    }
    return b;
}

// The bound box of face (i, side) of box g: g·2N0 + 2i + side with face-local bounds (the order
// of src/reach/cpu.rs and shaders/faces.wgsl), else the box itself.
fn face_index(g: u32, i: u32, side: u32) -> u32 {
    if (FACES == 1u) {
        return g;
    }
    return g * FACES + 2u * i + side;
}

// Whether every bound box of box g is finite.
fn bounds_finite(g: u32) -> bool {
    var fin = true;
    for (var f = 0u; f < FACES; f++) {
        fin = fin && nnb[(g * FACES + f) * NB_W + NB_W - 1u] == 0.0;
    }
    return fin;
}


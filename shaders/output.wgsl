// The network's bounds over each box, one thread per box: C̲x + d̲ ≤ N(x) ≤ C̄x + d̄ and
// N̲ ≤ N ≤ N̄, written to `nnb` for the embedding step. By the method's constants:
// - FORWARD: the output layer's forward forms (write_output in src/bounds/forward.rs);
// - IBP: the concrete bounds intersected with IBP's (forward-backward);
// - BACKWARD: the backward pass's forms (crown; forward-backward keeps, per side, whichever of
//   the backward and forward forms concretises tighter, unless SAME_SLOPE, and intersects the
//   concrete bounds: backward_group in src/bounds/forward_backward.rs).

// Params of the output layer (for BACKWARD: rpb = columns of Λ per box).
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b.
@group(0) @binding(1) var<storage, read> net: array<real>;
// Per bound box lo[N0], hi[N0], radius (embedding coordinates): the boxes, or their faces
// (FACES per box, shaders/faces.wgsl).
@group(0) @binding(2) var<storage, read> state: array<real>;
// Output layer's W·Ĉ, M_OUT × boxes·KC.
@group(0) @binding(3) var<storage, read> cf: array<real>;
// Output layer's |W|·R̂.
@group(0) @binding(4) var<storage, read> rf: array<real>;
// Output layer's GEMMs of the per-neuron vectors (shaders/relu.wgsl: aux sections).
@group(0) @binding(5) var<storage, read> aux_g: array<real>;
// The finished backward pass: Λ, N0 × boxes·rpb, and per column [β̄, β̲].
@group(0) @binding(6) var<storage, read> lamb: array<real>;
@group(0) @binding(7) var<storage, read> beta: array<real>;
// Per box: C̲ (M_OUT × N0), C̄, d̲, d̄, N̲, N̄ (M_OUT each), then 1 if not finite.
@group(0) @binding(8) var<storage, read_write> nnb: array<real>;

// One output's affine bounds.
struct Row {
    a_lo: array<real, N0>,
    a_hi: array<real, N0>,
    d_lo: real,
    d_hi: real,
    // Their concretisation over the box.
    n_lo: real,
    n_hi: real,
}

// Output i's forward forms Ĉ ∓ R̂ with the widened constants.
fn forward_row(i: u32, g: u32, bx: BoxInfo) -> Row {
    var c: array<real, KC>;
    var r: array<real, KC>;
    let b = net[p.b_off + i];
    if (p.first != 0u) {
        let f = first_layer_forms(i, bx);
        c = f.c;
        r = f.r;
    } else {
        let base = i * p.boxes * KC + g * KC;
        for (var q = 0u; q < KC; q++) {
            c[q] = cf[base + q];
            r[q] = rf[base + q];
        }
        c[N0] = c[N0] + b;
        let vg = aux_g[(i * AUX + S_V) * p.boxes + g];
        let e = err_bound(p.n_prev + 1u, up(vg + abs(b)), bx.scale);
        r[N0] = widened(up(r[N0] + e), fold_carry(i, bx));
    }
    var row: Row;
    var mag = abs(c[N0]) + abs(r[N0]);
    for (var q = 0u; q < N0; q++) {
        row.a_lo[q] = c[q] - r[q];
        row.a_hi[q] = c[q] + r[q];
        mag += (abs(c[q]) + abs(r[q])) * bx.xmag[q];
    }
    // Forming Ĉ ∓ R̂ errs by at most γ̂ V, moved into the constants; a first layer's forms are
    // off by the fold's rounding besides (fold.wgsl).
    var e = err_bound(2u, mag, bx.scale);
    if (p.first != 0u) {
        e = widened(e, fold_error(bx));
    }
    row.d_lo = down(down(c[N0] - r[N0]) - e);
    row.d_hi = up(up(c[N0] + r[N0]) + e);
    row.n_lo = affine_min(row.a_lo, row.d_lo, bx);
    row.n_hi = affine_max(row.a_hi, row.d_hi, bx);
    return row;
}

// Output i's backward forms: upper row g·rpb + i, lower row + M_OUT (stacked) or the same.
fn backward_row(i: u32, g: u32, bx: BoxInfo) -> Row {
    let ncols = p.boxes * p.rpb;
    let ur = g * p.rpb + i;
    var lr = ur;
    if (!SAME_SLOPE) {
        lr = ur + M_OUT;
    }
    var row: Row;
    for (var q = 0u; q < N0; q++) {
        row.a_hi[q] = lamb[q * ncols + ur];
        row.a_lo[q] = lamb[q * ncols + lr];
    }
    row.d_hi = beta[2u * ur];
    row.d_lo = beta[2u * lr + 1u];
    row.n_lo = affine_min(row.a_lo, row.d_lo, bx);
    row.n_hi = affine_max(row.a_hi, row.d_hi, bx);
    return row;
}

@compute @workgroup_size(64)
fn output(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    let bx = box_info(g);
    let at = g * NB_W;
    var bad = false;
    for (var i = 0u; i < M_OUT; i++) {
        var row: Row;
        if (FORWARD) {
            row = forward_row(i, g, bx);
            // The concrete bounds before the intersections, to choose forms by.
            let form_lo = row.n_lo;
            let form_hi = row.n_hi;
            if (IBP && p.first == 0u) {
                let b = net[p.b_off + i];
                let ic = aux_g[(i * AUX + S_IC) * p.boxes + g] + b;
                let iv = up(aux_g[(i * AUX + S_IV) * p.boxes + g] + abs(b));
                let ir = up(aux_g[(i * AUX + S_IR) * p.boxes + g] + err_bound(p.n_prev + 1u, iv, 1.0));
                row.n_lo = max(row.n_lo, down(ic - ir));
                row.n_hi = min(row.n_hi, up(ic + ir));
            }
            if (BACKWARD) {
                let bw = backward_row(i, g, bx);
                // Ties within FORM_TIE go to the backward form, as on the CPU
                // (tighter_than in src/bounds/forward_backward.rs).
                if (SAME_SLOPE || !(-form_hi > -bw.n_hi + FORM_TIE * (1.0 + abs(bw.n_hi)))) {
                    row.a_hi = bw.a_hi;
                    row.d_hi = bw.d_hi;
                }
                if (SAME_SLOPE || !(form_lo > bw.n_lo + FORM_TIE * (1.0 + abs(bw.n_lo)))) {
                    row.a_lo = bw.a_lo;
                    row.d_lo = bw.d_lo;
                }
                row.n_lo = max(row.n_lo, bw.n_lo);
                row.n_hi = min(row.n_hi, bw.n_hi);
            }
        } else {
            row = backward_row(i, g, bx);
        }
        var fin = finite(row.d_lo) && finite(row.d_hi) && finite(row.n_lo) && finite(row.n_hi);
        for (var q = 0u; q < N0; q++) {
            fin = fin && finite(row.a_lo[q]) && finite(row.a_hi[q]);
            nnb[at + i * N0 + q] = row.a_lo[q];
            nnb[at + (M_OUT + i) * N0 + q] = row.a_hi[q];
        }
        let o = at + 2u * M_OUT * N0;
        nnb[o + i] = row.d_lo;
        nnb[o + M_OUT + i] = row.d_hi;
        nnb[o + 2u * M_OUT + i] = row.n_lo;
        nnb[o + 3u * M_OUT + i] = row.n_hi;
        bad = bad || !fin;
    }
    nnb[at + NB_W - 1u] = select(real(0.0), real(1.0), bad);
}

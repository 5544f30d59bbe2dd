// Finishes a hidden layer and applies its ReLU relaxation, one thread per (neuron i, box g):
// adds the bias, widens the radius's constant by the layer's rounding error, concretises the
// neuron's bounds over the box, intersects them with IBP (IBP, forward-backward), records them
// for the backward pass (RECORD), and replaces the centre–radius forms by those of the adaptive
// relaxation (src/bounds/forward.rs is the f64 original; its comments give the algebra).
//
// Forms are stored neuron-major: C[i, g·KC + q], q < N0 the coefficients, q = N0 the constant.
// Per-neuron vectors (`aux`) hold AUX sections of `boxes` entries per neuron:
// [IBP centre | form magnitude V | IBP radius | IBP magnitude |c| + r].

// Params of this layer.
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b.
@group(0) @binding(1) var<storage, read> net: array<real>;
// Per bound box lo[N0], hi[N0], radius: the boxes, or their faces (FACES per box,
// shaders/faces.wgsl).
@group(0) @binding(2) var<storage, read> state: array<real>;
// Centre forms Ĉ, rows × boxes·KC (in: W·Ĉ of the layer's input; out: relaxed).
@group(0) @binding(3) var<storage, read_write> cf: array<real>;
// Radius forms R̂, the same shape.
@group(0) @binding(4) var<storage, read_write> rf: array<real>;
// The layer's GEMMs of the per-neuron vectors: W·c, |W|·V, |W|·r, |W|·(|c| + r).
@group(0) @binding(5) var<storage, read> aux_g: array<real>;
// The per-neuron vectors of this layer's output (after ReLU), for the next layer.
@group(0) @binding(6) var<storage, read_write> aux: array<real>;
// Per box [poisoned, status, stop step], then the step counter; bound box g poisons box
// g / FACES.
@group(0) @binding(7) var<storage, read_write> flags: array<atomic<u32>>;
// Recorded pre-activation bounds l, u of every layer (RECORD).
@group(0) @binding(8) var<storage, read_write> pre: array<real>;

fn aux_at(i: u32, section: u32, g: u32) -> u32 {
    return (i * AUX + section) * p.boxes + g;
}

@compute @workgroup_size(64)
fn relu(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    let i = gid.y;
    if (g >= p.boxes || i >= p.rows) {
        return;
    }
    let bx = box_info(g);
    let cols = p.boxes * KC;
    let base = i * cols + g * KC;
    let b = net[p.b_off + i];
    var c: array<real, KC>;
    var r: array<real, KC>;
    if (p.first != 0u) {
        let f = first_layer_forms(i, bx);
        c = f.c;
        r = f.r;
    } else {
        for (var q = 0u; q < KC; q++) {
            c[q] = cf[base + q];
            r[q] = rf[base + q];
        }
        c[N0] = c[N0] + b;
        let e = err_bound(p.n_prev + 1u, up(aux_g[aux_at(i, S_V, g)] + abs(b)), bx.scale);
        r[N0] = widened(up(r[N0] + e), fold_carry(i, bx));
    }
    // Concretise l ≤ z ≤ u over the box.
    var su = c[N0] + r[N0];
    var sl = c[N0] - r[N0];
    var mag = abs(c[N0]) + abs(r[N0]);
    for (var q = 0u; q < N0; q++) {
        let hi_q = c[q] + r[q];
        let lo_q = c[q] - r[q];
        su += hi_q * bx.xc[q] + abs(hi_q) * bx.xr[q];
        sl += lo_q * bx.xc[q] - abs(lo_q) * bx.xr[q];
        mag += (abs(c[q]) + abs(r[q])) * bx.xmag[q];
    }
    // The first layer's forms are off by the fold's rounding beside R̂ (fold.wgsl).
    var err = err_bound(3u * bx.free + 3u, mag, bx.scale);
    if (p.first != 0u) {
        err = widened(err, fold_error(bx));
    }
    var l = down(sl - err);
    var u = up(su + err);
    if (!(finite(l) && finite(u) && finite(mag))) {
        atomicStore(&flags[(g / FACES) * FLAG_W], 1u);
    }
    if (IBP) {
        // IBP through this layer from the previous layer's intersected bounds (ibp_layer in
        // forward.rs): W·c + b ± (|W|·r + err_bound(n + 1, |W|·(|c| + r) + |b|)); both
        // enclosures are rigorous, so is their intersection.
        if (p.first == 0u) {
            let ic = aux_g[aux_at(i, S_IC, g)] + b;
            let ie = err_bound(p.n_prev + 1u, up(aux_g[aux_at(i, S_IV, g)] + abs(b)), 1.0);
            let ir = up(aux_g[aux_at(i, S_IR, g)] + ie);
            l = max(l, down(ic - ir));
            u = min(u, up(ic + ir));
        }
        // ReLU is monotone: the next layer's IBP input [max(l, 0), max(u, 0)].
        let cr = centre_radius(max(l, 0.0), max(u, 0.0));
        aux[aux_at(i, S_IC, g)] = cr.x;
        aux[aux_at(i, S_IR, g)] = cr.y;
        aux[aux_at(i, S_IV, g)] = abs(cr.x) + cr.y;
    }
    if (RECORD) {
        pre[p.pre_off + i * p.boxes + g] = l;
        pre[p.pre_off + (p.rows + i) * p.boxes + g] = u;
    }
    var v: real = 0.0;
    if (u <= 0.0) {
        for (var q = 0u; q < KC; q++) {
            c[q] = 0.0;
            r[q] = 0.0;
        }
    } else if (l >= 0.0) {
        v = mag;
    } else {
        let ln = relu_lines(l, u, false);
        let alpha = 0.5 * (ln.s_up + ln.s_lo);
        let beta = 0.5 * (ln.s_up - ln.s_lo);
        for (var q = 0u; q < KC; q++) {
            let cq = c[q];
            let rq = r[q];
            c[q] = alpha * cq + beta * rq;
            r[q] = beta * cq + alpha * rq;
        }
        c[N0] = c[N0] + 0.5 * ln.t;
        r[N0] = r[N0] + 0.5 * ln.t;
        let e = err_bound(8u, up(up(max(ln.s_up, ln.s_lo) * mag) + ln.t), bx.scale);
        r[N0] = up(r[N0] + e);
        v = abs(c[N0]) + abs(r[N0]);
        for (var q = 0u; q < N0; q++) {
            v += (abs(c[q]) + abs(r[q])) * bx.xmag[q];
        }
    }
    for (var q = 0u; q < KC; q++) {
        cf[base + q] = c[q];
        rf[base + q] = r[q];
    }
    aux[aux_at(i, S_V, g)] = v;
}

// The first layer's forms, with a face's pinned coordinates folded into the constant
// (src/bounds/forward.rs: layer 0; src/bounds/fold.rs; the same numbers): the forms keep the free
// coordinates only, so no later magnitude sum, nor the rounding bound taken from it, carries a
// pinned coordinate's |w|·|x| where the constant cancels it. For the kernels that read `net`
// and `p` (relu.wgsl, output.wgsl).

struct Forms {
    c: array<real, KC>,
    r: array<real, KC>,
}

// Neuron i of the first layer (W at p.w_off, b at p.b_off): Ĉ = [W on the free coordinates |
// b + W·x on the pinned ones], R̂ = 0 but for the error of W and b as the device holds them in
// R̂'s constant (the fold's own rounding is `fold_error`).
fn first_layer_forms(i: u32, bx: BoxInfo) -> Forms {
    var f: Forms;
    let b = net[p.b_off + i];
    var mag = abs(b);
    f.c[N0] = b;
    for (var q = 0u; q < N0; q++) {
        let w = net[p.w_off + i * N0 + q];
        f.r[q] = 0.0;
        mag = up(mag + up(abs(w) * bx.xmag[q]));
        if (bx.lo[q] == bx.hi[q]) {
            f.c[N0] = f.c[N0] + w * bx.lo[q];
            f.c[q] = 0.0;
        } else {
            f.c[q] = w;
        }
    }
    f.r[N0] = conversion_error(mag, bx.scale);
    return f;
}

// A bound ε on the rounding of every first-layer neuron's folded constant, one for all of them
// (FoldBound::error): err_bound(pinned + 1, max|b| + Σ_pinned max|W_q|·|x_q|) from the
// constants at p.fold_off (src/gpu/buffers.rs: NetworkOffsets); 0 for a whole box.
fn fold_error(bx: BoxInfo) -> real {
    var m = net[p.fold_off];
    var pinned = 0u;
    for (var q = 0u; q < N0; q++) {
        if (bx.lo[q] == bx.hi[q]) {
            m = m + net[p.fold_off + 1u + q] * abs(bx.lo[q]);
            pinned += 1u;
        }
    }
    if (pinned == 0u) {
        return 0.0;
    }
    return err_bound(pinned + 1u, m, bx.scale);
}

// What the layer after the first (p.carry) adds to neuron i's R̂ constant for the fold:
// rowsum(|W|)ᵢ·ε bounds |W|·ε of its input's error (the ReLU lines' slopes lie in [0, 1]).
fn fold_carry(i: u32, bx: BoxInfo) -> real {
    if (p.carry == 0u) {
        return 0.0;
    }
    let e = fold_error(bx);
    if (e == 0.0) {
        // Nothing folded (a whole box): `up` would turn the exact 0 into MIN_NORMAL, and
        // `widened` would then move R̂ by an ulp.
        return 0.0;
    }
    return up(net[p.fold_off + 1u + N0 + i] * e);
}

// `x` widened by `e` (rounded up), or `x` itself where `e` is 0 (a whole box: its bits as before
// folding existed).
fn widened(x: real, e: real) -> real {
    if (e == 0.0) {
        return x;
    }
    return up(x + e);
}

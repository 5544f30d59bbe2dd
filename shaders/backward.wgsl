// Backward CROWN on the device (src/bounds/crown.rs and forward_backward.rs are the f64
// originals; their comments give the algebra and the rounding argument).
//
// A pass bounds z_k (k the start layer; the output for forward-backward, every layer for
// crown) by z_k ≤ Λ a_j + β̄, z_k ≥ Λ' a_j + β̲, one column of Λ per (box g, row r): rows
// r < n_k bound z_k,i from above, rows n_k ≤ r < 2 n_k from below (stacked, adaptive), or each
// row both sides (SAME_SLOPE: s̲ = s̄, one Λ). Λ is stored transposed, neuron-major:
// Λ[q, g·rpb + r], so the substitution Λ ← (Λ∘s)·W_j is one GEMM `Wⱼᵀ·(Λ∘s)` for every box
// (shaders/gemm.wgsl). `bwd_scale` does the per-box part: Λ∘s in place and β += intercepts;
// `bwd_bounds` concretises a finished pass over the box (crown's intermediate layers).
//
// Rounding (module doc of src/bounds/crown.rs, with the prelude's γ̂): the computed
// Λ̂' = fl(fl(Λ̂∘s)·W̃ⱼ) errs against a_j (|a_j| ≤ mag_j) by at most γ Σ_q |Λ̂∘s|_q (|W_j| mag_j)_q,
// and the intercept sums by γ Σ_q (|Λ̂∘s|_q |b_j|_q + |Λ̂_q| t_q) — each product has at most three
// roundings (Λ∘s, the f32 weight, the product), inside the count of err_bound. So one magnitude
// E = Σ_q |Λ̂∘s|_q w_q + |Λ̂_q t_q| with w = |W_j| mag_j + |b_j| bounds both, and β moves outward
// by err_bound(2 n_j + 2, E, 1 + Σ w + Σ mag_j). The pass starts from Λ = W̃_k, β = b̃_k, whose
// conversion from f64 errs by at most 2⁻²⁴(|W_k| |a_k| + |b_k|) ≤ err_bound(2, wm_k + |b_k|,
// 1 + Σ|a_k|) (common.wgsl: conversion_error; in f64 they are exact), with wm_k = |W_k|
// max(u_{k−1}, 0) from a GEMM and |a_k| ≤ max(u_{k−1}, 0).

// Params of this substitution (layer j = the one substituted).
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b.
@group(0) @binding(1) var<storage, read> net: array<real>;
// Per bound box lo[N0], hi[N0], radius: the boxes, or their faces (FACES per box,
// shaders/faces.wgsl).
@group(0) @binding(2) var<storage, read> state: array<real>;
// Recorded pre-activation bounds: per layer l then u, `n_j × boxes` each.
@group(0) @binding(3) var<storage, read_write> pre: array<real>;
// Per layer |W_j| max(u_{j−1}, 0), `n_j × boxes`.
@group(0) @binding(4) var<storage, read> wm: array<real>;
// Λ, `n_j × boxes·rpb` (neuron-major).
@group(0) @binding(5) var<storage, read_write> lamb: array<real>;
// Per column [β̄, β̲].
@group(0) @binding(6) var<storage, read_write> beta: array<real>;
// Per box [poisoned, status, stop step], then the step counter; bound box g poisons box
// g / FACES.
@group(0) @binding(7) var<storage, read_write> flags: array<atomic<u32>>;

// Σ_p mag_j[p]: the magnitudes of layer j's input (the box, or max(u_{j−1}, 0)).
fn input_magnitude(g: u32, bx: BoxInfo) -> real {
    var s: real = 0.0;
    if (p.at_input != 0u) {
        for (var q = 0u; q < N0; q++) {
            s += bx.xmag[q];
        }
    } else {
        for (var q = 0u; q < p.n_prev; q++) {
            s += max(pre[p.prev_u_off + q * p.boxes + g], 0.0);
        }
    }
    return s;
}

// w_q = |W_j| mag_j + |b_j| for neuron q of layer j (inline for the first layer: N0 terms).
fn weight_magnitude(q: u32, g: u32, bx: BoxInfo) -> real {
    let b = abs(net[p.b_off + q]);
    if (p.at_input != 0u) {
        var w = b;
        for (var s = 0u; s < N0; s++) {
            w += abs(net[p.w_off + q * N0 + s]) * bx.xmag[s];
        }
        return w;
    }
    return wm[p.wm_off + q * p.boxes + g] + b;
}

// One thread per column (box g, row r) of Λ: Λ ← Λ∘s in place, β ← β + intercepts ± rounding.
@compute @workgroup_size(64)
fn bwd_scale(@builtin(global_invocation_id) gid: vec3<u32>) {
    let ncols = p.boxes * p.rpb;
    let col = gid.x;
    if (col >= ncols) {
        return;
    }
    let g = col / p.rpb;
    let row = col % p.rpb;
    let i = row % p.k_rows;
    let upper_side = SAME_SLOPE || row < p.k_rows;
    let bx = box_info(g);
    let n_j = p.rows;
    var su: real = 0.0;
    var sl: real = 0.0;
    var mag: real = 0.0;
    var wsum: real = 0.0;
    var a_mag: real = 0.0;
    for (var q = 0u; q < n_j; q++) {
        var lam: real;
        if (p.first != 0u) {
            lam = net[p.k_w_off + i * n_j + q];
        } else {
            lam = lamb[q * ncols + col];
        }
        let u = pre[p.pre_off + (n_j + q) * p.boxes + g];
        let ln = relu_lines(pre[p.pre_off + q * p.boxes + g], u, SAME_SLOPE);
        let w = weight_magnitude(q, g, bx);
        let bq = net[p.b_off + q];
        // The upper line where this side needs an upper bound of Λ_q a_q; the intercept on the
        // side whose line it is (for shared rows s̲ = s̄, so one product serves both).
        let upper_line = (lam >= 0.0) == upper_side;
        let ls = lam * select(ln.s_lo, ln.s_up, upper_line);
        let lt = lam * ln.t;
        let lb = ls * bq;
        if (lam >= 0.0) {
            su += lb + lt;
            sl += lb;
        } else {
            su += lb;
            sl += lb + lt;
        }
        mag += abs(ls) * w + abs(lt);
        wsum += w;
        a_mag += max(u, 0.0);
        lamb[q * ncols + col] = ls;
    }
    let err = err_bound(2u * n_j + 2u, mag, 1.0 + wsum + input_magnitude(g, bx));
    var bu: real;
    var bl: real;
    if (p.first != 0u) {
        let bk = net[p.k_b_off + i];
        let conv = conversion_error(up(wm[p.k_wm_off + i * p.boxes + g] + abs(bk)), up(1.0 + a_mag));
        bu = up(bk + conv);
        bl = down(bk - conv);
    } else {
        bu = beta[2u * col];
        bl = beta[2u * col + 1u];
    }
    beta[2u * col] = up(up(bu + su) + err);
    beta[2u * col + 1u] = down(down(bl + sl) - err);
}

// Concretises a finished pass from layer k (crown's intermediate bounds), one thread per
// (box g, neuron i): l ≤ z_k,i ≤ u into `pre`. For k = 0 (first) z_0 = W̃₀x + b̃₀ directly,
// its conversion error in the constant.
@compute @workgroup_size(64)
fn bwd_bounds(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    let i = gid.y;
    if (g >= p.boxes || i >= p.k_rows) {
        return;
    }
    let bx = box_info(g);
    var au: array<real, N0>;
    var al: array<real, N0>;
    var bu: real;
    var bl: real;
    if (p.first != 0u) {
        let b = net[p.k_b_off + i];
        var m = abs(b);
        for (var q = 0u; q < N0; q++) {
            let w = net[p.k_w_off + i * N0 + q];
            au[q] = w;
            al[q] = w;
            m = up(m + up(abs(w) * bx.xmag[q]));
        }
        let e = conversion_error(m, bx.scale);
        bu = up(b + e);
        bl = down(b - e);
    } else {
        let ncols = p.boxes * p.rpb;
        let ur = g * p.rpb + i;
        var lr = ur;
        if (!SAME_SLOPE) {
            lr = ur + p.k_rows;
        }
        for (var q = 0u; q < N0; q++) {
            au[q] = lamb[q * ncols + ur];
            al[q] = lamb[q * ncols + lr];
        }
        bu = beta[2u * ur];
        bl = beta[2u * lr + 1u];
    }
    let u = affine_max(au, bu, bx);
    let l = affine_min(al, bl, bx);
    if (!(finite(l) && finite(u))) {
        atomicStore(&flags[(g / FACES) * FLAG_W], 1u);
    }
    pre[p.pre_off + i * p.boxes + g] = l;
    pre[p.pre_off + (p.k_rows + i) * p.boxes + g] = u;
}

// One Euler step of the embedding system per box (src/reach/embedding.rs is the original):
// from the network's bounds C̲x + d̲ ≤ N(x) ≤ C̄x + d̄ and N̲ ≤ N ≤ N̄ over the box (output.wgsl),
// bounds the embedding field on each face in interval arithmetic (generated ft_iv, jac_iv, g_iv),
// advances the closeness radius (Minkowski), takes the Euler step, checks the set against C and
// writes the recorded snapshot. `tick` then advances the step counter.

// Params (boxes).
@group(0) @binding(0) var<uniform> p: Params;
// Per box lo[N0], hi[N0], radius (embedding coordinates).
@group(0) @binding(1) var<storage, read_write> state: array<real>;
// The network's bounds over each box (shaders/output.wgsl).
@group(0) @binding(2) var<storage, read> nnb: array<real>;
// Per box [poisoned, status, stop step], then the step counter.
@group(0) @binding(3) var<storage, read_write> flags: array<atomic<u32>>;
// Recorded states: slot-major, SW reals per box.
@group(0) @binding(4) var<storage, read_write> snap: array<real>;

const LIVE: u32 = 0u;
const LEFT_REGION: u32 = 1u;
const INVERTED: u32 = 2u;
const NON_FINITE: u32 = 3u;

fn stop(g: u32, status: u32, step: u32) {
    atomicStore(&flags[g * 3u + 1u], status);
    atomicStore(&flags[g * 3u + 2u], step);
}

// φ(z) = (eᶻ − 1)/z ≤ phi_up(z): Taylor with a remainder bound for |z| ≤ 1/2, else from exp.
fn phi_up(z: real) -> real {
    if (abs(z) <= 0.5) {
        let z2 = up(z * z);
        let s = up(up(1.0 + 0.5 * z) + up3(z2 / 6.0));
        if (z <= 0.0) {
            return s;
        }
        let den = down(24.0 * down(1.0 - up3(z / 5.0)));
        return up(s + up3(up(z2 * z) / den));
    }
    if (z > 0.0) {
        return up3(up(exp_up(z) - 1.0) / z);
    }
    return up3(up(1.0 - exp_down(z)) / (-z));
}

@compute @workgroup_size(1)
fn tick() {
    atomicAdd(&flags[3u * p.boxes], 1u);
}

@compute @workgroup_size(64)
fn embed(@builtin(global_invocation_id) gid: vec3<u32>) {
    let g = gid.x;
    if (g >= p.boxes) {
        return;
    }
    if (atomicLoad(&flags[g * 3u + 1u]) != LIVE) {
        return;
    }
    let step = atomicLoad(&flags[3u * p.boxes]);
    var lo: array<real, N0>;
    var hi: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        lo[j] = state[g * SW + j];
        hi[j] = state[g * SW + N0 + j];
    }
    var radius = state[g * SW + 2u * N0];
    var bad = atomicLoad(&flags[g * 3u]) != 0u;

    // The network's bounds over the box (shaders/output.wgsl).
    var a_lo: array<real, M_OUT * N0>;
    var a_hi: array<real, M_OUT * N0>;
    var d_lo: array<real, M_OUT>;
    var d_hi: array<real, M_OUT>;
    var n_lo: array<real, M_OUT>;
    var n_hi: array<real, M_OUT>;
    let at = g * NB_W;
    for (var k = 0u; k < M_OUT * N0; k++) {
        a_lo[k] = nnb[at + k];
        a_hi[k] = nnb[at + M_OUT * N0 + k];
    }
    let o = at + 2u * M_OUT * N0;
    for (var k = 0u; k < M_OUT; k++) {
        d_lo[k] = nnb[o + k];
        d_hi[k] = nnb[o + M_OUT + k];
        n_lo[k] = nnb[o + 2u * M_OUT + k];
        n_hi[k] = nnb[o + 3u * M_OUT + k];
    }
    if (bad || nnb[at + NB_W - 1u] != 0.0) {
        stop(g, NON_FINITE, step);
        return;
    }

    // The embedding field (embedding_field in src/reach/embedding.rs).
    var xb: array<Iv, N0>;
    var cen: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        xb[j] = Iv(lo[j], hi[j]);
        cen[j] = clamp(lo[j] + 0.5 * (hi[j] - lo[j]), lo[j], hi[j]);
    }
    var jac: array<Iv, N0 * N0>;
    for (var i = 0u; i < N0; i++) {
        for (var j = 0u; j < N0; j++) {
            jac[i * N0 + j] = jac_iv(i, j, xb);
        }
    }
    var rows_lo: array<Iv, N0 * N0>;
    var rows_hi: array<Iv, N0 * N0>;
    var delta_lo: array<Iv, N0>;
    var delta_hi: array<Iv, N0>;
    var g_box: array<Iv, N0 * M_OUT>;
    var input: array<Iv, M_OUT>;
    for (var i = 0u; i < N0; i++) {
        delta_lo[i] = iv_point(0.0);
        delta_hi[i] = iv_point(0.0);
        for (var j = 0u; j < N0; j++) {
            rows_lo[i * N0 + j] = iv_point(0.0);
            rows_hi[i * N0 + j] = iv_point(0.0);
        }
    }
    if (G_CONSTANT) {
        for (var i = 0u; i < N0; i++) {
            for (var k = 0u; k < M_OUT; k++) {
                let sign = B_SIGN[i * M_OUT + k];
                if (sign == 0) {
                    continue;
                }
                let bik = Iv(B_LO[i * M_OUT + k], B_HI[i * M_OUT + k]);
                let dl = iv_sub(iv_point(d_lo[k]), iv_point(MARGIN));
                let du = iv_add(iv_point(d_hi[k]), iv_point(MARGIN));
                for (var j = 0u; j < N0; j++) {
                    var c_for_lo = a_lo[k * N0 + j];
                    var c_for_hi = a_hi[k * N0 + j];
                    if (sign < 0) {
                        c_for_lo = a_hi[k * N0 + j];
                        c_for_hi = a_lo[k * N0 + j];
                    }
                    rows_lo[i * N0 + j] = iv_add(rows_lo[i * N0 + j], iv_mul(bik, iv_point(c_for_lo)));
                    rows_hi[i * N0 + j] = iv_add(rows_hi[i * N0 + j], iv_mul(bik, iv_point(c_for_hi)));
                }
                if (sign > 0) {
                    delta_lo[i] = iv_add(delta_lo[i], iv_mul(bik, dl));
                    delta_hi[i] = iv_add(delta_hi[i], iv_mul(bik, du));
                } else {
                    delta_lo[i] = iv_add(delta_lo[i], iv_mul(bik, du));
                    delta_hi[i] = iv_add(delta_hi[i], iv_mul(bik, dl));
                }
            }
        }
    } else {
        for (var i = 0u; i < N0; i++) {
            for (var k = 0u; k < M_OUT; k++) {
                g_box[i * M_OUT + k] = g_iv(i, k, xb);
            }
        }
        for (var k = 0u; k < M_OUT; k++) {
            input[k] = Iv(down(n_lo[k] - MARGIN), up(n_hi[k] + MARGIN));
        }
    }
    var dxl: array<real, N0>;
    var dxu: array<real, N0>;
    for (var i = 0u; i < N0; i++) {
        for (var side = 0u; side < 2u; side++) {
            var pt = cen;
            if (side == 0u) {
                pt[i] = lo[i];
            } else {
                pt[i] = hi[i];
            }
            var pb: array<Iv, N0>;
            for (var j = 0u; j < N0; j++) {
                pb[j] = iv_point(pt[j]);
            }
            var total = ft_iv(i, pb);
            if (G_CONSTANT) {
                for (var j = 0u; j < N0; j++) {
                    var row = rows_lo[i * N0 + j];
                    if (side == 1u) {
                        row = rows_hi[i * N0 + j];
                    }
                    total = iv_add(total, iv_mul(row, iv_point(pt[j])));
                    if (j != i) {
                        let off = iv_sub(xb[j], iv_point(pt[j]));
                        total = iv_add(total, iv_mul(iv_add(jac[i * N0 + j], row), off));
                    }
                }
                if (side == 0u) {
                    total = iv_add(total, delta_lo[i]);
                } else {
                    total = iv_add(total, delta_hi[i]);
                }
            } else {
                for (var j = 0u; j < N0; j++) {
                    if (j != i) {
                        let off = iv_sub(xb[j], iv_point(pt[j]));
                        total = iv_add(total, iv_mul(jac[i * N0 + j], off));
                    }
                }
                for (var k = 0u; k < M_OUT; k++) {
                    total = iv_add(total, iv_mul(g_box[i * M_OUT + k], input[k]));
                }
            }
            if (side == 0u) {
                dxl[i] = total.lo;
            } else {
                dxu[i] = total.hi;
            }
        }
        if (FIELD_SLACK > 0.0) {
            dxl[i] = down(dxl[i] - FIELD_SLACK);
            dxu[i] = up(dxu[i] + FIELD_SLACK);
        }
    }

    // The closeness radius (Minkowski): c ≥ μ([Df̃](C) + [g](C)·hull(C̲, C̄)).
    if (MINKOWSKI) {
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
        let z = iv_mul(iv_point(rate), Iv(DT_LO, DT_HI));
        let growth = exp_up(z.hi);
        let factor = up(DT_HI * phi_up(z.hi));
        radius = max(up(up(growth * radius) + up(ELL_MC * factor)), 0.0);
        if (!finite(radius)) {
            stop(g, NON_FINITE, step);
            return;
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
    if (!fin) {
        stop(g, NON_FINITE, step);
        return;
    }
    if (inverted) {
        stop(g, INVERTED, step);
        return;
    }
    for (var j = 0u; j < N0; j++) {
        state[g * SW + j] = lo[j];
        state[g * SW + N0 + j] = hi[j];
    }
    state[g * SW + 2u * N0] = radius;

    // The filtered system's set in x against C (C rounded inward).
    var sb: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        if (radius > 0.0) {
            sb[j] = Iv(down(lo[j] - radius), up(hi[j] + radius));
        } else {
            sb[j] = Iv(lo[j], hi[j]);
        }
    }
    var inside = true;
    for (var i = 0u; i < N0; i++) {
        var xi = sb[i];
        if (TRANSFORM) {
            xi = iv_point(0.0);
            for (var j = 0u; j < N0; j++) {
                xi = iv_add(xi, iv_mul(Iv(S_LO[i * N0 + j], S_HI[i * N0 + j]), sb[j]));
            }
        }
        inside = inside && REGION_LO[i] <= xi.lo && xi.hi <= REGION_HI[i];
    }
    if (!inside) {
        stop(g, LEFT_REGION, step);
        return;
    }
    let done = step + 1u;
    if (done % EVERY == 0u || done == STEPS) {
        let slot = (done + EVERY - 1u) / EVERY - 1u;
        let at = (slot * p.boxes + g) * SW;
        for (var j = 0u; j < SW; j++) {
            snap[at + j] = state[g * SW + j];
        }
    }
}

// Finishes a hidden layer and applies its ReLU relaxation, one thread per (neuron i, box g):
// adds the bias, widens the radius's constant by the layer's rounding error, concretises the
// neuron's bounds over the box and replaces the centre–radius forms by those of the adaptive
// relaxation (src/bounds/forward.rs is the f64 original; its comments give the algebra).
//
// Forms are stored neuron-major: C[i, g·KC + q], q < N0 the coefficients, q = N0 the constant.

// Params of this layer.
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b, f32.
@group(0) @binding(1) var<storage, read> net: array<f32>;
// Per box lo[N0], hi[N0], radius.
@group(0) @binding(2) var<storage, read> state: array<f32>;
// Centre forms Ĉ, rows × boxes·KC (in: W·Ĉ of the layer's input; out: relaxed).
@group(0) @binding(3) var<storage, read_write> cf: array<f32>;
// Radius forms R̂, the same shape.
@group(0) @binding(4) var<storage, read_write> rf: array<f32>;
// |W|·V of the layer's input, rows × boxes.
@group(0) @binding(5) var<storage, read> vg: array<f32>;
// V of this layer's output (after ReLU), rows × boxes, for the next layer.
@group(0) @binding(6) var<storage, read_write> vout: array<f32>;
// Per box [poisoned, status, stop step], then the step counter.
@group(0) @binding(7) var<storage, read_write> flags: array<atomic<u32>>;

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
    var c: array<f32, KC>;
    var r: array<f32, KC>;
    if (p.first != 0u) {
        // Ĉ = [W₁ᵢ | b₁ᵢ] rounded to f32; the rounding (≤ 2⁻²⁴ relative) goes into R̂'s constant.
        var mag = abs(b);
        for (var q = 0u; q < N0; q++) {
            let w = net[p.w_off + i * N0 + q];
            c[q] = w;
            r[q] = 0.0;
            mag = up(mag + up(abs(w) * bx.xmag[q]));
        }
        c[N0] = b;
        r[N0] = err_bound(2u, mag, bx.scale);
    } else {
        for (var q = 0u; q < KC; q++) {
            c[q] = cf[base + q];
            r[q] = rf[base + q];
        }
        c[N0] = c[N0] + b;
        let e = err_bound(p.n_prev + 1u, up(vg[i * p.boxes + g] + abs(b)), bx.scale);
        r[N0] = up(r[N0] + e);
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
    let err = err_bound(3u * N0 + 3u, mag, bx.scale);
    let l = down(sl - err);
    let u = up(su + err);
    if (!(finite(l) && finite(u) && finite(mag))) {
        atomicStore(&flags[g * 3u], 1u);
    }
    var v = 0.0;
    if (u <= 0.0) {
        for (var q = 0u; q < KC; q++) {
            c[q] = 0.0;
            r[q] = 0.0;
        }
    } else if (l >= 0.0) {
        v = mag;
    } else {
        // relu_lines: s̄ the chord slope (flushed to 0 below 1e-30), s̲ adaptive, t̄ rounded up
        // so that the upper line lies above ReLU at both ends.
        var s = clamp(u / (u - l), 0.0, 1.0);
        if (s < 1.0e-30) {
            s = 0.0;
        }
        let t = max(up(-s * l), up(u - down(s * u)));
        var s_lo = 0.0;
        if (u >= -l) {
            s_lo = 1.0;
        }
        let alpha = 0.5 * (s + s_lo);
        let beta = 0.5 * (s - s_lo);
        for (var q = 0u; q < KC; q++) {
            let cq = c[q];
            let rq = r[q];
            c[q] = alpha * cq + beta * rq;
            r[q] = beta * cq + alpha * rq;
        }
        c[N0] = c[N0] + 0.5 * t;
        r[N0] = r[N0] + 0.5 * t;
        let e = err_bound(8u, up(up(max(s, s_lo) * mag) + t), bx.scale);
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
    vout[i * p.boxes + g] = v;
}

// Y (rows × cols) = op(W) (rows × inner) · X (inner × cols), op = W, |W|, Wᵀ or |W|ᵀ; X read as
// x[k·ldx + x_off + c] (through max(·, 0) with relu_x), Y written at y[r·ldy + y_off + c].
// `gemm`: 64 × 64 output tiles, 16 × 16 threads with 4 × 4 outputs each; W and X tiles of depth 16
// are staged in workgroup memory, so every weight is read once per tile of 64 columns
// (docs/design.md §4); `gemm_wide` and `gemm_flat` below (kernels.rs: `Gemm`).
// Forward layers are `W·Ĉ`, `|W|·R̂`, `|W|·V`; backward substitutions are `Λ ← Wᵀ·(Λ∘s)` with
// Λ stored transposed (neuron-major), so one GEMM serves every box: the shared weights are the
// left factor, each box only scales its own columns (shaders/backward.wgsl). Rounding: the
// consumers bound it by γ̂·(magnitude GEMM) for any summation order (common.wgsl: err_bound).

// Params of this dispatch.
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b.
@group(0) @binding(1) var<storage, read> net: array<real>;
// X.
@group(0) @binding(2) var<storage, read> x: array<real>;
// Y.
@group(0) @binding(3) var<storage, read_write> y: array<real>;

const TM: u32 = 64u;
const TN: u32 = 64u;
const TK: u32 = 16u;

var<workgroup> a_tile: array<real, 1024>;
var<workgroup> x_tile: array<real, 1024>;

// op(W)[r, k] (0 outside).
fn weight(r: u32, k: u32) -> real {
    if (r >= p.rows || k >= p.inner) {
        return 0.0;
    }
    var v: real;
    if (p.trans_w != 0u) {
        v = net[p.w_off + k * p.rows + r];
    } else {
        v = net[p.w_off + r * p.inner + k];
    }
    if (p.abs_w != 0u) {
        v = abs(v);
    }
    return v;
}

@compute @workgroup_size(16, 16)
fn gemm(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let row0 = wid.y * TM;
    let col0 = wid.x * TN;
    let t = lid.y * 16u + lid.x;
    var acc0 = vec4<real>(0.0);
    var acc1 = vec4<real>(0.0);
    var acc2 = vec4<real>(0.0);
    var acc3 = vec4<real>(0.0);
    for (var k0 = 0u; k0 < p.inner; k0 += TK) {
        for (var e = 0u; e < 4u; e++) {
            let idx = t + e * 256u;
            // Consecutive threads read consecutive addresses of W (or of Wᵀ's storage).
            var r = idx / TK;
            var kk = idx % TK;
            if (p.trans_w != 0u) {
                r = idx % TM;
                kk = idx / TM;
            }
            a_tile[kk * TM + r] = weight(row0 + r, k0 + kk);
        }
        for (var e = 0u; e < 4u; e++) {
            let idx = t + e * 256u;
            let kk = idx / TN;
            let c = idx % TN;
            let gk = k0 + kk;
            let gc = col0 + c;
            var v: real = 0.0;
            if (gk < p.inner && gc < p.cols) {
                v = x[gk * p.ldx + p.x_off + gc];
                if (p.relu_x != 0u) {
                    v = max(v, 0.0);
                }
            }
            x_tile[kk * TN + c] = v;
        }
        workgroupBarrier();
        // Accumulators in named vectors, not an indexed array: the driver then keeps them in
        // registers (row i of the thread's 4 × 4 block is acc_i, its columns the components).
        for (var kk = 0u; kk < TK; kk++) {
            let a = vec4<real>(
                a_tile[kk * TM + lid.y],
                a_tile[kk * TM + lid.y + 16u],
                a_tile[kk * TM + lid.y + 32u],
                a_tile[kk * TM + lid.y + 48u],
            );
            let b = vec4<real>(
                x_tile[kk * TN + lid.x],
                x_tile[kk * TN + lid.x + 16u],
                x_tile[kk * TN + lid.x + 32u],
                x_tile[kk * TN + lid.x + 48u],
            );
            acc0 += a.x * b;
            acc1 += a.y * b;
            acc2 += a.z * b;
            acc3 += a.w * b;
        }
        workgroupBarrier();
    }
    store_row(row0 + lid.y, col0 + lid.x, acc0);
    store_row(row0 + lid.y + 16u, col0 + lid.x, acc1);
    store_row(row0 + lid.y + 32u, col0 + lid.x, acc2);
    store_row(row0 + lid.y + 48u, col0 + lid.x, acc3);
}

// Row `gr` of Y at columns gc, gc + 16, gc + 32, gc + 48 (those inside Y).
fn store_row(gr: u32, gc: u32, v: vec4<real>) {
    if (gr >= p.rows) {
        return;
    }
    let base = gr * p.ldy + p.y_off;
    for (var j = 0u; j < 4u; j++) {
        if (gc + 16u * j < p.cols) {
            y[base + gc + 16u * j] = v[j];
        }
    }
}

// The same product in 64 × 256 tiles (`Gemm::Wide`, for real GPUs): 8 × 32 threads, each with
// an 8 × 8 block of Y (rows 8·ty … 8·ty + 7; columns 4·tx … 4·tx + 3 and 128 + 4·tx …), W and X
// staged in workgroup memory as vectors of 4 at depth 8. A thread reads 4 vectors for 64
// multiply–adds (the 4 × 4 tiles: 8 scalars for 16), so workgroup memory no longer bounds the
// rate. Each output is summed over k in ascending order, as in `gemm` and `gemm_flat`.
const WM: u32 = 64u;
const WN: u32 = 256u;
const WK: u32 = 8u;

// W's tile as [kk][4 rows], X's as [kk][4 columns].
var<workgroup> w_wide: array<vec4<real>, 128>;
var<workgroup> x_wide: array<vec4<real>, 512>;

// X[k, c] as read (through max(·, 0) with relu_x; 0 outside).
fn x_at(k: u32, c: u32) -> real {
    if (k >= p.inner || c >= p.cols) {
        return 0.0;
    }
    let v = x[k * p.ldx + p.x_off + c];
    if (p.relu_x != 0u) {
        return max(v, 0.0);
    }
    return v;
}

@compute @workgroup_size(32, 8)
fn gemm_wide(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let row0 = wid.y * WM;
    let col0 = wid.x * WN;
    let t = lid.y * 32u + lid.x;
    // Row i of the block is c{i}0 (columns 4·tx …) and c{i}1 (128 + 4·tx …): named vectors,
    // so that the driver keeps them in registers.
    var c00 = vec4<real>(0.0);
    var c01 = vec4<real>(0.0);
    var c10 = vec4<real>(0.0);
    var c11 = vec4<real>(0.0);
    var c20 = vec4<real>(0.0);
    var c21 = vec4<real>(0.0);
    var c30 = vec4<real>(0.0);
    var c31 = vec4<real>(0.0);
    var c40 = vec4<real>(0.0);
    var c41 = vec4<real>(0.0);
    var c50 = vec4<real>(0.0);
    var c51 = vec4<real>(0.0);
    var c60 = vec4<real>(0.0);
    var c61 = vec4<real>(0.0);
    var c70 = vec4<real>(0.0);
    var c71 = vec4<real>(0.0);
    for (var k0 = 0u; k0 < p.inner; k0 += WK) {
        if (t < 128u) {
            // Consecutive threads read consecutive addresses of W (or of Wᵀ's storage).
            var kk = t % WK;
            var r4 = t / WK;
            if (p.trans_w != 0u) {
                kk = t / 16u;
                r4 = t % 16u;
            }
            let r = row0 + 4u * r4;
            let k = k0 + kk;
            w_wide[kk * 16u + r4] =
                vec4<real>(weight(r, k), weight(r + 1u, k), weight(r + 2u, k), weight(r + 3u, k));
        }
        for (var e = 0u; e < 2u; e++) {
            let idx = t + e * 256u;
            let kk = idx / 64u;
            let c4 = idx % 64u;
            let c = col0 + 4u * c4;
            let k = k0 + kk;
            x_wide[kk * 64u + c4] =
                vec4<real>(x_at(k, c), x_at(k, c + 1u), x_at(k, c + 2u), x_at(k, c + 3u));
        }
        workgroupBarrier();
        for (var kk = 0u; kk < WK; kk++) {
            let a0 = w_wide[kk * 16u + 2u * lid.y];
            let a1 = w_wide[kk * 16u + 2u * lid.y + 1u];
            let b0 = x_wide[kk * 64u + lid.x];
            let b1 = x_wide[kk * 64u + lid.x + 32u];
            c00 += a0.x * b0;
            c01 += a0.x * b1;
            c10 += a0.y * b0;
            c11 += a0.y * b1;
            c20 += a0.z * b0;
            c21 += a0.z * b1;
            c30 += a0.w * b0;
            c31 += a0.w * b1;
            c40 += a1.x * b0;
            c41 += a1.x * b1;
            c50 += a1.y * b0;
            c51 += a1.y * b1;
            c60 += a1.z * b0;
            c61 += a1.z * b1;
            c70 += a1.w * b0;
            c71 += a1.w * b1;
        }
        workgroupBarrier();
    }
    let c = col0 + 4u * lid.x;
    store_wide(row0 + 8u * lid.y + 0u, c, c00, c01);
    store_wide(row0 + 8u * lid.y + 1u, c, c10, c11);
    store_wide(row0 + 8u * lid.y + 2u, c, c20, c21);
    store_wide(row0 + 8u * lid.y + 3u, c, c30, c31);
    store_wide(row0 + 8u * lid.y + 4u, c, c40, c41);
    store_wide(row0 + 8u * lid.y + 5u, c, c50, c51);
    store_wide(row0 + 8u * lid.y + 6u, c, c60, c61);
    store_wide(row0 + 8u * lid.y + 7u, c, c70, c71);
}

// Row `gr` of Y at columns gc … gc + 3 (`lo`) and gc + 128 … gc + 131 (`hi`), those inside Y.
fn store_wide(gr: u32, gc: u32, lo: vec4<real>, hi: vec4<real>) {
    if (gr >= p.rows) {
        return;
    }
    let base = gr * p.ldy + p.y_off;
    for (var j = 0u; j < 4u; j++) {
        if (gc + j < p.cols) {
            y[base + gc + j] = lo[j];
        }
        if (gc + 128u + j < p.cols) {
            y[base + gc + 128u + j] = hi[j];
        }
    }
}

// The same product without workgroup memory or barriers, for software adapters (`flat_gemm`):
// a 4 × 4 block of Y a thread (8 loads for 16 products), each output summed over k in the
// tiles' order. llvmpipe runs a workgroup's invocations as SIMD loops and every barrier as a
// switch between them: the tiles took 160 ms for 400 × 400 · 400 × 36 there, mostly padding
// and barriers (docs/design.md §4).
@compute @workgroup_size(64)
fn gemm_flat(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) groups: vec3<u32>,
) {
    // Threads numbered row-major over (4 rows, 4 columns) blocks, so no lane idles past a row.
    let quads = (p.cols + 3u) / 4u;
    let i = gid.x + gid.y * groups.x * 64u;
    if (i >= (p.rows + 3u) / 4u * quads) {
        return;
    }
    let r = i / quads * 4u;
    let c = (i % quads) * 4u;
    let width = min(4u, p.cols - c);
    var acc0 = vec4<real>(0.0);
    var acc1 = vec4<real>(0.0);
    var acc2 = vec4<real>(0.0);
    var acc3 = vec4<real>(0.0);
    for (var k = 0u; k < p.inner; k++) {
        let base = k * p.ldx + p.x_off + c;
        var b = vec4<real>(0.0);
        for (var j = 0u; j < width; j++) {
            var v = x[base + j];
            if (p.relu_x != 0u) {
                v = max(v, 0.0);
            }
            b[j] = v;
        }
        acc0 += weight(r, k) * b;
        acc1 += weight(r + 1u, k) * b;
        acc2 += weight(r + 2u, k) * b;
        acc3 += weight(r + 3u, k) * b;
    }
    store_block(r, c, width, acc0);
    store_block(r + 1u, c, width, acc1);
    store_block(r + 2u, c, width, acc2);
    store_block(r + 3u, c, width, acc3);
}

// Row `gr` of Y at columns gc … gc + width − 1 (nothing past the last row).
fn store_block(gr: u32, gc: u32, width: u32, v: vec4<real>) {
    if (gr >= p.rows) {
        return;
    }
    let base = gr * p.ldy + p.y_off + gc;
    for (var j = 0u; j < width; j++) {
        y[base + j] = v[j];
    }
}

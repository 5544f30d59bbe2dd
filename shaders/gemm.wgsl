// Y (rows × cols) = op(W) (rows × inner) · X (inner × cols), row-major, op = identity or |·|.
// 64 × 64 output tiles, 16 × 16 threads with 4 × 4 outputs each; W and X tiles of depth 16 are
// staged in workgroup memory, so every weight is read once per tile of 64 columns (DESIGN §4).

// Params of this dispatch.
@group(0) @binding(0) var<uniform> p: Params;
// Every layer's W and b, f32.
@group(0) @binding(1) var<storage, read> net: array<f32>;
// X, inner × cols.
@group(0) @binding(2) var<storage, read> x: array<f32>;
// Y, rows × cols.
@group(0) @binding(3) var<storage, read_write> y: array<f32>;

const TM: u32 = 64u;
const TN: u32 = 64u;
const TK: u32 = 16u;

var<workgroup> a_tile: array<f32, 1024>;
var<workgroup> x_tile: array<f32, 1024>;

@compute @workgroup_size(16, 16)
fn gemm(@builtin(local_invocation_id) lid: vec3<u32>, @builtin(workgroup_id) wid: vec3<u32>) {
    let row0 = wid.y * TM;
    let col0 = wid.x * TN;
    let t = lid.y * 16u + lid.x;
    var acc: array<f32, 16>;
    for (var k0 = 0u; k0 < p.inner; k0 += TK) {
        for (var e = 0u; e < 4u; e++) {
            let idx = t + e * 256u;
            let r = idx / TK;
            let kk = idx % TK;
            let gr = row0 + r;
            let gk = k0 + kk;
            var v = 0.0;
            if (gr < p.rows && gk < p.inner) {
                v = net[p.w_off + gr * p.inner + gk];
                if (p.abs_w != 0u) {
                    v = abs(v);
                }
            }
            a_tile[kk * TM + r] = v;
        }
        for (var e = 0u; e < 4u; e++) {
            let idx = t + e * 256u;
            let kk = idx / TN;
            let c = idx % TN;
            let gk = k0 + kk;
            let gc = col0 + c;
            var v = 0.0;
            if (gk < p.inner && gc < p.cols) {
                v = x[gk * p.cols + gc];
            }
            x_tile[kk * TN + c] = v;
        }
        workgroupBarrier();
        for (var kk = 0u; kk < TK; kk++) {
            var a: array<f32, 4>;
            var b: array<f32, 4>;
            for (var i = 0u; i < 4u; i++) {
                a[i] = a_tile[kk * TM + lid.y + 16u * i];
                b[i] = x_tile[kk * TN + lid.x + 16u * i];
            }
            for (var i = 0u; i < 4u; i++) {
                for (var j = 0u; j < 4u; j++) {
                    acc[i * 4u + j] += a[i] * b[j];
                }
            }
        }
        workgroupBarrier();
    }
    for (var i = 0u; i < 4u; i++) {
        let gr = row0 + lid.y + 16u * i;
        for (var j = 0u; j < 4u; j++) {
            let gc = col0 + lid.x + 16u * j;
            if (gr < p.rows && gc < p.cols) {
                y[gr * p.cols + gc] = acc[i * 4u + j];
            }
        }
    }
}

// A box as centre ± radius, rigorously containing it, with |x| ≤ xmag and the underflow scale
// 1 + Σ xmag (as `forward.rs` on the CPU). `state` holds per box lo[N0], hi[N0], radius.
const SW: u32 = 2u * N0 + 1u;

struct BoxInfo {
    xc: array<f32, N0>,
    xr: array<f32, N0>,
    xmag: array<f32, N0>,
    scale: f32,
}

fn box_info(g: u32) -> BoxInfo {
    var b: BoxInfo;
    var sum = 1.0;
    for (var q = 0u; q < N0; q++) {
        let l = state[g * SW + q];
        let h = state[g * SW + N0 + q];
        let c = 0.5 * l + 0.5 * h;
        let r = max(up(h - c), up(c - l));
        let m = up(abs(c) + r);
        b.xc[q] = c;
        b.xr[q] = r;
        b.xmag[q] = m;
        sum = up(sum + m);
    }
    b.scale = sum;
    return b;
}

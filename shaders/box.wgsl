// A box as centre ± radius, rigorously containing it, with |x| ≤ xmag and the underflow scale
// 1 + Σ xmag (as `forward.rs` on the CPU). `state` holds per box lo[N0], hi[N0], radius.
const SW: u32 = 2u * N0 + 1u;

struct BoxInfo {
    lo: array<real, N0>,
    hi: array<real, N0>,
    xc: array<real, N0>,
    xr: array<real, N0>,
    xmag: array<real, N0>,
    scale: real,
    // The coordinates with lo < hi (a face pins one): the forms' coordinates on the CPU.
    free: u32,
}

fn box_info(g: u32) -> BoxInfo {
    var b: BoxInfo;
    var sum: real = 1.0;
    for (var q = 0u; q < N0; q++) {
        let l = state[g * SW + q];
        let h = state[g * SW + N0 + q];
        let c = 0.5 * l + 0.5 * h;
        let r = max(up(h - c), up(c - l));
        let m = up(abs(c) + r);
        b.lo[q] = l;
        b.hi[q] = h;
        b.xc[q] = c;
        b.xr[q] = r;
        b.xmag[q] = m;
        sum = up(sum + m);
        b.free += select(1u, 0u, l == h);
    }
    b.scale = sum;
    return b;
}

// A rigorous upper bound of max over the box of w·x + d (affine_max in src/rounding.rs):
// the corner sum plus err_bound(N0 + 1) of its magnitude.
fn affine_max(w: array<real, N0>, d: real, bx: BoxInfo) -> real {
    var s = d;
    var m = abs(d);
    for (var q = 0u; q < N0; q++) {
        s += select(w[q] * bx.lo[q], w[q] * bx.hi[q], w[q] >= 0.0);
        m += abs(w[q]) * bx.xmag[q];
    }
    return up(s + err_bound(N0 + 1u, m, 1.0));
}

// A rigorous lower bound of min over the box of w·x + d.
fn affine_min(w: array<real, N0>, d: real, bx: BoxInfo) -> real {
    var s = d;
    var m = abs(d);
    for (var q = 0u; q < N0; q++) {
        s += select(w[q] * bx.hi[q], w[q] * bx.lo[q], w[q] >= 0.0);
        m += abs(w[q]) * bx.xmag[q];
    }
    return down(s - err_bound(N0 + 1u, m, 1.0));
}

// `(c, r)` with [l, h] ⊆ [c − r, c + r] exactly, whatever the rounding of c (ibp.rs).
fn centre_radius(l: real, h: real) -> vec2<real> {
    let c = 0.5 * l + 0.5 * h;
    return vec2<real>(c, max(up(h - c), up(c - l)));
}

// ReLU relaxation lines s̲·z ≤ ReLU(z) ≤ s̄·z + t̄ on [l, u] (relu_lines in src/bounds/mod.rs):
// stable neurons exact, unstable ones the chord slope s̄ = u/(u − l) (clamped to [0, 1], flushed
// to 0 below TINY_SLOPE; any slope in [0, 1] is valid) with t̄ rounded up so that the upper line
// lies above ReLU at both ends; the lower slope is 1 if u ≥ −l else 0 (adaptive), or s̄.
struct Lines {
    s_lo: real,
    s_up: real,
    t: real,
}

fn relu_lines(l: real, u: real, same_slope: bool) -> Lines {
    if (l >= 0.0) {
        return Lines(1.0, 1.0, 0.0);
    }
    if (u <= 0.0) {
        return Lines(0.0, 0.0, 0.0);
    }
    var s = clamp(u / (u - l), 0.0, 1.0);
    if (s < TINY_SLOPE) {
        s = 0.0;
    }
    let t = max(up(-s * l), up(u - down(s * u)));
    var s_lo: real = 0.0;
    if (same_slope) {
        s_lo = s;
    } else if (u >= -l) {
        s_lo = 1.0;
    }
    return Lines(s_lo, s, t);
}

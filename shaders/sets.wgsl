// Boxes between coordinates and the safe set S (shared by the embedding step, shaders/embed.wgsl,
// and the meet of the frames, shaders/settle.wgsl; src/reach/mod.rs and safe_set.rs are the
// originals).

// A box's status (src/gpu/buffers.rs `status`, the host's copy).
const LIVE: u32 = 0u;
const LEFT_REGION: u32 = 1u;
const INVERTED: u32 = 2u;
const NON_FINITE: u32 = 3u;
const NO_BOUND: u32 = 4u;

// How a frame's step of a box went: the embedding step writes it, the meet reads it.
const STEP_NONE: u32 = 0u;
const STEP_OK: u32 = 1u;
const STEP_NON_FINITE: u32 = 2u;
const STEP_INVERTED: u32 = 3u;

// The x-box of an embedding-coordinate box: S·z in interval arithmetic (identity without a
// transform), as Transform::to_x_box.
fn x_box(z: array<Iv, N0>) -> array<Iv, N0> {
    if (!TRANSFORM) {
        return z;
    }
    var x: array<Iv, N0>;
    for (var i = 0u; i < N0; i++) {
        var xi = iv_point(0.0);
        for (var j = 0u; j < N0; j++) {
            xi = iv_add(xi, iv_mul(Iv(S_LO[i * N0 + j], S_HI[i * N0 + j]), z[j]));
        }
        x[i] = xi;
    }
    return x;
}

// The intersection of a box with the safe set's half-spaces `normal·v + offset ≥ 0`, rows
// [first, first + count) of the HS_ tables (src/gpu/codegen.rs: safe_set_wgsl), one coordinate
// at a time as src/reach/safe_set.rs: clip_to_safe_set. The filtered system stays in S, so the
// result still holds every true state. An empty intersection (a set outside S, which no true
// trajectory can reach) leaves the box as it was, as on the CPU.
fn clip_to_safe_set(b: array<Iv, N0>, first: u32, count: u32) -> array<Iv, N0> {
    var v = b;
    for (var k = first; k < first + count; k++) {
        for (var j = 0u; j < N0; j++) {
            let kind = HS_KIND[k * N0 + j];
            if (kind == 0u) {
                continue;
            }
            var bound = HS_CONST[k * N0 + j];
            if (kind >= 3u) {
                // normalⱼ vⱼ ≥ −offset − Σ_{i≠j} normalᵢ vᵢ, divided by every normalⱼ.
                var rest = Iv(HS_OFF_LO[k], HS_OFF_HI[k]);
                for (var i = 0u; i < N0; i++) {
                    if (i != j) {
                        rest = iv_add(rest, iv_mul(Iv(HS_N_LO[k * N0 + i], HS_N_HI[k * N0 + i]), v[i]));
                    }
                }
                let l = -rest.hi;
                let q = iv_div(Iv(l, l), Iv(HS_N_LO[k * N0 + j], HS_N_HI[k * N0 + j]));
                bound = select(q.hi, q.lo, kind == 3u);
            }
            if (kind == 1u || kind == 3u) {
                v[j].lo = max(v[j].lo, bound);
            } else {
                v[j].hi = min(v[j].hi, bound);
            }
        }
    }
    for (var j = 0u; j < N0; j++) {
        if (!(v[j].lo <= v[j].hi)) {
            return b;
        }
    }
    return v;
}

// The meet of two boxes, or `a` where they do not meet (IntervalBox::intersection, unwrap_or).
fn meet_or(a: array<Iv, N0>, b: array<Iv, N0>) -> array<Iv, N0> {
    var v: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        v[j] = Iv(max(a[j].lo, b[j].lo), min(a[j].hi, b[j].hi));
        if (!(v[j].lo <= v[j].hi)) {
            return a;
        }
    }
    return v;
}

// The z-box around an x-box (Transform::to_z_box): T·x in interval arithmetic, padded by
// ρ·max|zᵢ| for using T for S⁻¹ (docs/design.md §2.11); the x-box itself without a transform.
fn z_box_of(x: array<Iv, N0>) -> array<Iv, N0> {
    if (!TRANSFORM) {
        return x;
    }
    var z = t_times(x);
    let pad = t_pad(z);
    for (var i = 0u; i < N0; i++) {
        z[i] = Iv(down(z[i].lo - pad), up(z[i].hi + pad));
    }
    return z;
}

// T·x in interval arithmetic (Transform::t_times).
fn t_times(x: array<Iv, N0>) -> array<Iv, N0> {
    var z: array<Iv, N0>;
    for (var i = 0u; i < N0; i++) {
        var zi = iv_point(0.0);
        for (var j = 0u; j < N0; j++) {
            zi = iv_add(zi, iv_mul(Iv(T_LO[i * N0 + j], T_HI[i * N0 + j]), x[j]));
        }
        z[i] = zi;
    }
    return z;
}

// ρ·‖z‖∞ for z = T·x, rounded up (Transform::pad): by how much T x may miss S⁻¹x.
fn t_pad(z: array<Iv, N0>) -> real {
    var size: real = 0.0;
    for (var i = 0u; i < N0; i++) {
        size = max(size, iv_mag(z[i]));
    }
    return up(up(RHO * size));
}

// Two frames' sets after a step, met (src/reach/cpu.rs `advance` and `settle`): frame 0's `z` in
// this module's coordinates, frame 1's `x` in x (its half-spaces of S are the x rows of this
// module's tables). Of the frames that stepped (`s0`, `s1`), each set is clipped to S, `known`
// becomes the meet of their x-boxes within S, and each set is met with `known`'s box in its
// coordinates (replaced by it where the frame did not step) and clipped again. Shared by the
// Euler engine's meet (settle.wgsl) and the continuous model's (cmeet.wgsl).
struct Met {
    z: array<Iv, N0>,
    x: array<Iv, N0>,
    known: array<Iv, N0>,
}

fn meet_frames(z_in: array<Iv, N0>, x_in: array<Iv, N0>, s0: bool, s1: bool) -> Met {
    var z = z_in;
    var x = x_in;
    var known: array<Iv, N0>;
    if (s0) {
        z = clip_to_safe_set(z, 0u, HS_Z);
        known = clip_to_safe_set(x_box(z), HS_Z, HS_X);
    }
    if (s1) {
        x = clip_to_safe_set(x, HS_Z, HS_X);
        let own = clip_to_safe_set(x, HS_Z, HS_X);
        if (s0) {
            known = meet_or(known, own);
        } else {
            known = own;
        }
    }
    let around = z_box_of(known);
    if (s0) {
        z = meet_or(z, around);
    } else {
        z = around;
    }
    z = clip_to_safe_set(z, 0u, HS_Z);
    if (s1) {
        x = meet_or(x, known);
    } else {
        x = known;
    }
    x = clip_to_safe_set(x, HS_Z, HS_X);
    return Met(z, x, known);
}

// The embedding field on one face or slab of a box (src/reach/embedding.rs and
// src/reach/validated.rs are the originals): the network's bounds over a bound box, the
// interaction-aware row of the constant-g case, and the mean-value forms of the field on a face
// (`face_field`, the Euler step's) and on a slab (`form_on`, `bound_on`, the continuous step's:
// the face's form with the i-th coordinate an interval). No bindings: shaders/embed.wgsl and the
// probes (src/gpu/probe_field.rs) include it. Needs the generated field (ft_iv, jac_iv, g_iv,
// bft_iv, bjac_iv, B_*) and common.wgsl.

// The network's bounds over one bound box (a box, or one of its faces with FACES > 1):
// C̲x + d̲ ≤ N(x) ≤ C̄x + d̄ and N̲ ≤ N ≤ N̄ (shaders/output.wgsl).
struct NetBounds {
    a_lo: array<real, M_OUT * N0>,
    a_hi: array<real, M_OUT * N0>,
    d_lo: array<real, M_OUT>,
    d_hi: array<real, M_OUT>,
    n_lo: array<real, M_OUT>,
    n_hi: array<real, M_OUT>,
}

// Constant bounds lo ≤ N ≤ hi (zero slopes): the filter's own field (zero) or its enclosure of v.
fn constant_bounds(lo: array<real, M_OUT>, hi: array<real, M_OUT>) -> NetBounds {
    var b: NetBounds;
    for (var q = 0u; q < M_OUT * N0; q++) {
        b.a_lo[q] = 0.0;
        b.a_hi[q] = 0.0;
    }
    b.d_lo = lo;
    b.d_hi = hi;
    b.n_lo = lo;
    b.n_hi = hi;
    return b;
}

// f̃ᵢ and its Jacobian for the field being bounded: the scenario's (piece 0: the network's system,
// or v = 0) or binding piece k's, f̃ + g·v with v the row's closed form (piece k + 1).
fn field_ft(piece: u32, i: u32, x: array<Iv, N0>) -> Iv {
    if (piece == 0u) {
        return ft_iv(i, x);
    }
    return bft_iv((piece - 1u) * N0 + i, x);
}

fn field_jac(piece: u32, i: u32, j: u32, x: array<Iv, N0>) -> Iv {
    if (piece == 0u) {
        return jac_iv(i, j, x);
    }
    return bjac_iv(((piece - 1u) * N0 + i) * N0 + j, x);
}

// Row i of the interaction-aware matrix and its offset for one side of the embedding
// (interaction_row in src/reach/embedding.rs): for the lower side (side 0) m̲ᵢ = Σₖ B⁺ᵢₖ C̲ₖ +
// B⁻ᵢₖ C̄ₖ, δ̲ᵢ = Σₖ B⁺ᵢₖ d̲ₖ + B⁻ᵢₖ d̄ₖ with d̲, d̄ widened by the margin; symmetrically above.
struct InteractionRow {
    row: array<Iv, N0>,
    delta: Iv,
}

fn interaction_row(nb: NetBounds, margin: real, i: u32, side: u32) -> InteractionRow {
    var r: InteractionRow;
    r.delta = iv_point(0.0);
    for (var j = 0u; j < N0; j++) {
        r.row[j] = iv_point(0.0);
    }
    for (var k = 0u; k < M_OUT; k++) {
        let sign = B_SIGN[i * M_OUT + k];
        if (sign == 0) {
            continue;
        }
        let bik = Iv(B_LO[i * M_OUT + k], B_HI[i * M_OUT + k]);
        // A lower bound of Bᵢₖ Nₖ takes Nₖ's lower form when Bᵢₖ > 0, its upper one otherwise.
        let lower_form = (sign > 0) == (side == 0u);
        var d = iv_add(iv_point(nb.d_hi[k]), iv_point(margin));
        if (lower_form) {
            d = iv_sub(iv_point(nb.d_lo[k]), iv_point(margin));
        }
        for (var j = 0u; j < N0; j++) {
            var c = nb.a_hi[k * N0 + j];
            if (lower_form) {
                c = nb.a_lo[k * N0 + j];
            }
            r.row[j] = iv_add(r.row[j], iv_mul(bik, iv_point(c)));
        }
        r.delta = iv_add(r.delta, iv_mul(bik, d));
    }
    return r;
}

// The embedding field's bound on face (i, side) of the box (embedding_field_by_face in
// src/reach/embedding.rs), with the network bounded over that face (or the whole box): f̃ᵢ at
// the face's centre point p, the interval Jacobian over the face (the mean-value form's
// segments from p stay on it) times the offsets over the face, and the
// network's affine forms (constant g) or [g](box)·[N̲ − M, N̄ + M] (state-dependent g).
fn face_field(i: u32, side: u32, xb: array<Iv, N0>, cen: array<real, N0>, nb: NetBounds, margin: real, piece: u32) -> Iv {
    var pt = cen;
    if (side == 0u) {
        pt[i] = xb[i].lo;
    } else {
        pt[i] = xb[i].hi;
    }
    var pb: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        pb[j] = iv_point(pt[j]);
    }
    var face = xb;
    face[i] = pb[i];
    var jac: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        jac[j] = field_jac(piece, i, j, face);
    }
    var total = field_ft(piece, i, pb);
    if (G_CONSTANT) {
        let ir = interaction_row(nb, margin, i, side);
        for (var j = 0u; j < N0; j++) {
            total = iv_add(total, iv_mul(ir.row[j], iv_point(pt[j])));
            if (j != i) {
                let off = iv_sub(xb[j], iv_point(pt[j]));
                total = iv_add(total, iv_mul(iv_add(jac[j], ir.row[j]), off));
            }
        }
        total = iv_add(total, ir.delta);
    } else {
        for (var j = 0u; j < N0; j++) {
            if (j != i) {
                let off = iv_sub(xb[j], iv_point(pt[j]));
                total = iv_add(total, iv_mul(jac[j], off));
            }
        }
        for (var k = 0u; k < M_OUT; k++) {
            let input = Iv(down(nb.n_lo[k] - margin), up(nb.n_hi[k] + margin));
            total = iv_add(total, iv_mul(g_iv(i, k, xb), input));
        }
    }
    return total;
}


// The mean-value form of the field on a slab (validated::form_on): Fᵢ(x) ∈ c + Σⱼ kⱼ(xⱼ − pⱼ)
// for x in the box [lo, hi] (within S), p a point of it. f̃ᵢ at p; the slopes are [Df̃ᵢ] over
// the whole box, plus (constant g) the interaction-aware row of that side, whose offset is in c;
// for state-dependent g, c takes [g](box)·[N̲ − M, N̄ + M]. face_field is this form pinned to a
// face (its i-th offset zero), the Euler step's.
struct SlabForm {
    c: Iv,
    k: array<Iv, N0>,
}

fn form_on(i: u32, side: u32, lo: array<real, N0>, hi: array<real, N0>, p: array<real, N0>, nb: NetBounds, margin: real, piece: u32) -> SlabForm {
    var x: array<Iv, N0>;
    var pb: array<Iv, N0>;
    for (var j = 0u; j < N0; j++) {
        x[j] = Iv(lo[j], hi[j]);
        pb[j] = iv_point(p[j]);
    }
    var f: SlabForm;
    f.c = field_ft(piece, i, pb);
    if (G_CONSTANT) {
        let ir = interaction_row(nb, margin, i, side);
        for (var j = 0u; j < N0; j++) {
            f.c = iv_add(f.c, iv_mul(ir.row[j], pb[j]));
        }
        for (var j = 0u; j < N0; j++) {
            f.k[j] = iv_add(field_jac(piece, i, j, x), ir.row[j]);
        }
        f.c = iv_add(f.c, ir.delta);
    } else {
        for (var j = 0u; j < N0; j++) {
            f.k[j] = field_jac(piece, i, j, x);
        }
        for (var k = 0u; k < M_OUT; k++) {
            let input = Iv(down(nb.n_lo[k] - margin), up(nb.n_hi[k] + margin));
            f.c = iv_add(f.c, iv_mul(g_iv(i, k, x), input));
        }
    }
    return f;
}

// A bound of Fᵢ over the box [lo, hi] (validated::bound_on): its lower end for side 0, its upper
// end for side 1 — form_on about the box's centre, every offset an interval (on a slab the i-th
// too).
fn bound_on(i: u32, side: u32, lo: array<real, N0>, hi: array<real, N0>, nb: NetBounds, margin: real, piece: u32) -> Iv {
    var p: array<real, N0>;
    for (var j = 0u; j < N0; j++) {
        p[j] = lo[j] + 0.5 * (hi[j] - lo[j]);
    }
    let f = form_on(i, side, lo, hi, p, nb, margin, piece);
    var total = f.c;
    for (var j = 0u; j < N0; j++) {
        total = iv_add(total, iv_mul(f.k[j], iv_sub(Iv(lo[j], hi[j]), iv_point(p[j]))));
    }
    return total;
}

// A lower / upper bound moved outward by a slack (none for a zero slack, as widen_by).
fn widen_down(v: real, slack: real) -> real {
    if (slack > 0.0) {
        return down(v - slack);
    }
    return v;
}

fn widen_up(v: real, slack: real) -> real {
    if (slack > 0.0) {
        return up(v + slack);
    }
    return v;
}

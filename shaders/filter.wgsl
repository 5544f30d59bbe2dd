// The filter's closed form over a set, as the CPU engine's ExactField::ClosedForm
// (src/surrogate_error.rs: VForms::piece and VForms::enclose; src/reach/pieces.rs): which smooth
// piece `v` provably is on an x-box ∩ S, and an enclosure of `v` there. The generated code
// (src/gpu/codegen.rs, closed_form_wgsl) supplies the natural rows `row_a_iv`, `row_b_iv`, the
// expressions and symbolic gradients of the mean-value forms (`vb_iv`, `vf_iv`, `vp_iv`,
// `vr_iv`, `vrd_iv` and their `_grad`), V_KIND (1: one row, 2: a scalar input) and V_ROWS.
// Every evaluation is the interval arithmetic of common.wgsl, rounded outward; where the CPU
// asks whether an interval is NaN, this asks `!(lo <= hi)`, and a non-finite gradient counts as
// NaN (its form would be unbounded, and the CPU's meet keeps the natural enclosure then).

const PIECE_NONE: u32 = 0xffffffffu;
const PIECE_INACTIVE: u32 = 0u;

fn iv_nan(a: Iv) -> bool {
    return !(a.lo <= a.hi);
}

// a ∩ b, or a where they are disjoint or b is NaN (both enclose the same values).
fn iv_meet(a: Iv, b: Iv) -> Iv {
    if (iv_nan(b)) {
        return a;
    }
    let lo = max(a.lo, b.lo);
    let hi = min(a.hi, b.hi);
    if (!(lo <= hi)) {
        return a;
    }
    return Iv(lo, hi);
}

fn iv_sqr(a: Iv) -> Iv {
    return iv_pow(a, 2);
}

// A box X, its centre c as points, and X − c: what the mean-value forms take.
struct Centred {
    xs: array<Iv, N0>,
    cs: array<Iv, N0>,
    dx: array<Iv, N0>,
}

fn centred_of(x: array<Iv, N0>) -> Centred {
    var c: Centred;
    c.xs = x;
    for (var i = 0u; i < N0; i++) {
        let mid = clamp(0.5 * (x[i].lo + x[i].hi), x[i].lo, x[i].hi);
        c.cs[i] = iv_point(mid);
        c.dx[i] = iv_sub(x[i], c.cs[i]);
    }
    return c;
}

// The mean-value form e(c) + ∇e(X)·(X − c) of a generated smooth expression, from e(c) and
// ∇e(X), and whether the gradient was finite.
struct Form {
    enc: Iv,
    ok: bool,
}
fn form_of(value: Iv, grad: array<Iv, N0>, c: Centred) -> Form {
    var f: Form;
    f.enc = value;
    f.ok = true;
    for (var l = 0u; l < N0; l++) {
        f.ok = f.ok && finite(grad[l].lo) && finite(grad[l].hi);
        f.enc = iv_add(f.enc, iv_mul(grad[l], c.dx[l]));
    }
    return f;
}

// One function per kind of expression (below), each calling its own generated code, not one
// over a switch of kinds: the driver inlines every call, so a switch would put all five
// generated families at each call site (tried: lavapipe compiled the embedding kernel in 3× the
// time with 2.9× the memory).

// bₖ (hᵢ not clamped).
fn vb_form(k: u32, c: Centred) -> Form {
    var g: array<Iv, N0>;
    for (var l = 0u; l < N0; l++) {
        g[l] = vb_iv_grad(k * N0 + l, c.xs);
    }
    return form_of(vb_iv(k, c.cs), g, c);
}

// One row: Fⱼ = b·aⱼ/‖a‖².
fn vf_form(j: u32, c: Centred) -> Form {
    var g: array<Iv, N0>;
    for (var l = 0u; l < N0; l++) {
        g[l] = vf_iv_grad(j * N0 + l, c.xs);
    }
    return form_of(vf_iv(j, c.cs), g, c);
}

// One row: pⱼ = aⱼ/‖a‖².
fn vp_form(j: u32, c: Centred) -> Form {
    var g: array<Iv, N0>;
    for (var l = 0u; l < N0; l++) {
        g[l] = vp_iv_grad(j * N0 + l, c.xs);
    }
    return form_of(vp_iv(j, c.cs), g, c);
}

// Scalar input: rₖ = bₖ/aₖ.
fn vr_form(k: u32, c: Centred) -> Form {
    var g: array<Iv, N0>;
    for (var l = 0u; l < N0; l++) {
        g[l] = vr_iv_grad(k * N0 + l, c.xs);
    }
    return form_of(vr_iv(k, c.cs), g, c);
}

// Scalar input: rₖ − rⱼ at kj = k·V_ROWS + j.
fn vrd_form(kj: u32, c: Centred) -> Form {
    var g: array<Iv, N0>;
    for (var l = 0u; l < N0; l++) {
        g[l] = vrd_iv_grad(kj * N0 + l, c.xs);
    }
    return form_of(vrd_iv(kj, c.cs), g, c);
}

// The rows over the box: natural a and b, and b met with its mean-value form (VForms::v_rows,
// rows no input acts on made slack); `ok` false where some row is NaN.
struct Rows {
    a: array<Iv, V_ROWS * M_OUT>,
    b_nat: array<Iv, V_ROWS>,
    b_enc: array<Iv, V_ROWS>,
    ok: bool,
}

fn filter_rows(c: Centred) -> Rows {
    var r: Rows;
    r.ok = true;
    for (var k = 0u; k < ROWS; k++) {
        for (var j = 0u; j < M_OUT; j++) {
            r.a[k * M_OUT + j] = row_a_iv(k * M_OUT + j, c.xs);
            r.ok = r.ok && !iv_nan(r.a[k * M_OUT + j]);
        }
        r.b_nat[k] = row_b_iv(k, c.xs);
        r.ok = r.ok && !iv_nan(r.b_nat[k]);
        r.b_enc[k] = iv_meet(r.b_nat[k], vb_form(k, c).enc);
        // A row no input acts on (its a exactly 0) binds nowhere v exists (VForms::v_rows).
        var inert = true;
        for (var j = 0u; j < M_OUT; j++) {
            let a = r.a[k * M_OUT + j];
            inert = inert && a.lo == 0.0 && a.hi == 0.0;
        }
        if (inert) {
            r.b_nat[k] = Iv(max(r.b_nat[k].lo, 0.0), max(r.b_nat[k].hi, 0.0));
            r.b_enc[k] = Iv(max(r.b_enc[k].lo, 0.0), max(r.b_enc[k].hi, 0.0));
        }
    }
    return r;
}

fn norm2_of(r: Rows) -> Iv {
    var s = iv_point(0.0);
    for (var j = 0u; j < M_OUT; j++) {
        s = iv_add(s, iv_sqr(r.a[j]));
    }
    return s;
}

// Scalar input: rₖ = bₖ/aₖ, natural met with its mean-value form.
fn r_of(r: Rows, k: u32, c: Centred) -> Iv {
    return iv_meet(iv_div(r.b_nat[k], r.a[k]), vr_form(k, c).enc);
}

// Scalar input: which side of θ = 0 row k bounds (1: above, aₖ > 0; 0: below; 2: unknown).
fn side_of(r: Rows, k: u32) -> u32 {
    if (r.a[k].hi < 0.0) {
        return 0u;
    }
    if (r.a[k].lo > 0.0) {
        return 1u;
    }
    return 2u;
}

// Scalar input: whether row k's bound dominates row j's on the box (rₖ ≤ rⱼ above, ≥ below).
fn dominates(r: Rows, k: u32, j: u32, upper: bool, c: Centred) -> bool {
    let kj = k * V_ROWS + j;
    if (!VRD_HAS[kj]) {
        return false;
    }
    let d = iv_meet(iv_sub(r_of(r, k, c), r_of(r, j, c)), vrd_form(kj, c).enc);
    if (upper) {
        return d.hi <= 0.0;
    }
    return d.lo >= 0.0;
}

// Which smooth piece `v` provably is on the whole of x ∩ S (VForms::piece): PIECE_INACTIVE
// (every row slack), k + 1 (row k binds throughout and every other row that may bind is on
// the other side of θ = 0 or dominated by it), or PIECE_NONE.
fn proven_piece(x: array<Iv, N0>) -> u32 {
    let c = centred_of(x);
    let r = filter_rows(c);
    if (!r.ok) {
        return PIECE_NONE;
    }
    var any_may_bind = false;
    for (var k = 0u; k < ROWS; k++) {
        any_may_bind = any_may_bind || r.b_enc[k].lo < 0.0;
    }
    if (!any_may_bind) {
        return PIECE_INACTIVE;
    }
    if (V_KIND == 1u) {
        if (r.b_enc[0].hi <= 0.0 && norm2_of(r).lo > 0.0) {
            return 1u;
        }
        return PIECE_NONE;
    }
    if (V_KIND == 2u) {
        for (var k = 0u; k < ROWS; k++) {
            let sk = side_of(r, k);
            if (!(r.b_enc[k].lo < 0.0) || sk == 2u || !(r.b_enc[k].hi <= 0.0)) {
                continue;
            }
            var wins = true;
            for (var j = 0u; j < ROWS; j++) {
                if (j == k || !(r.b_enc[j].lo < 0.0)) {
                    continue;
                }
                let sj = side_of(r, j);
                if (sj == 2u) {
                    wins = false;
                } else if (sj == sk) {
                    wins = wins && dominates(r, k, j, sk == 1u, c);
                }
            }
            if (wins) {
                return k + 1u;
            }
        }
    }
    return PIECE_NONE;
}

// A scalar input's rows that may bind on x ∩ S by the side of θ they bound (VForms::lattice):
// bit k of `lower` (aₖ < 0) or `upper` (aₖ > 0); `ok` false for other filters, a NaN row, or a
// row that may bind with aₖ of either sign.
struct LatticeRows {
    lower: u32,
    upper: u32,
    ok: bool,
}

fn lattice_rows(x: array<Iv, N0>) -> LatticeRows {
    var l = LatticeRows(0u, 0u, false);
    if (V_KIND != 2u) {
        return l;
    }
    let c = centred_of(x);
    let r = filter_rows(c);
    if (!r.ok) {
        return l;
    }
    for (var k = 0u; k < ROWS; k++) {
        if (r.b_enc[k].lo >= 0.0) {
            continue;
        }
        let side = side_of(r, k);
        if (side == 0u) {
            l.lower |= 1u << k;
        } else if (side == 1u) {
            l.upper |= 1u << k;
        } else {
            return l;
        }
    }
    l.ok = true;
    return l;
}

// max(0, −B).
fn neg_part(b: Iv) -> Iv {
    return Iv(max(-b.hi, 0.0), max(-b.lo, 0.0));
}

// An enclosure of `v` over x ∩ S; `ok` false where an end may be infinite.
struct VEnclosure {
    v: array<Iv, M_OUT>,
    ok: bool,
}

fn entire_v() -> VEnclosure {
    var e: VEnclosure;
    for (var j = 0u; j < M_OUT; j++) {
        e.v[j] = iv_entire();
    }
    e.ok = false;
    return e;
}

fn zero_v() -> VEnclosure {
    var e: VEnclosure;
    for (var j = 0u; j < M_OUT; j++) {
        e.v[j] = iv_point(0.0);
    }
    e.ok = true;
    return e;
}

// Whether every end of the enclosure is a finite number.
fn checked(e: VEnclosure) -> VEnclosure {
    var out = e;
    out.ok = true;
    for (var j = 0u; j < M_OUT; j++) {
        out.ok = out.ok && finite(e.v[j].lo) && finite(e.v[j].hi) && !iv_nan(e.v[j]);
    }
    return out;
}

// The natural enclosure of `v` (v_enclosure in src/surrogate_error.rs).
fn natural_v(r: Rows) -> VEnclosure {
    for (var k = 0u; k < ROWS; k++) {
        if (iv_nan(r.b_nat[k])) {
            return entire_v();
        }
        for (var j = 0u; j < M_OUT; j++) {
            if (iv_nan(r.a[k * M_OUT + j])) {
                return entire_v();
            }
        }
    }
    if (V_KIND == 1u) {
        let c = neg_part(r.b_nat[0]);
        if (c.hi == 0.0) {
            return zero_v();
        }
        let norm2 = norm2_of(r);
        if (norm2.lo <= 0.0) {
            return entire_v();
        }
        let scale = iv_div(c, norm2);
        var e: VEnclosure;
        for (var j = 0u; j < M_OUT; j++) {
            e.v[j] = iv_neg(iv_mul(scale, r.a[j]));
        }
        return checked(e);
    }
    if (V_KIND != 2u) {
        return entire_v();
    }
    // Scalar input: v = max(0, max_{aₖ<0} cₖ/|aₖ|) − max(0, max_{aₖ>0} cₖ/aₖ), cₖ = max(0, −bₖ).
    var lo_l: real = 0.0;
    var lo_u: real = 0.0;
    var hi_l: real = 0.0;
    var hi_u: real = 0.0;
    for (var k = 0u; k < ROWS; k++) {
        let c = neg_part(r.b_nat[k]);
        if (c.hi == 0.0) {
            continue;
        }
        let ak = r.a[k];
        if (ak.lo > 0.0) {
            let q = iv_div(c, ak);
            hi_l = max(hi_l, q.lo);
            hi_u = max(hi_u, q.hi);
        } else if (ak.hi < 0.0) {
            let q = iv_div(c, iv_neg(ak));
            lo_l = max(lo_l, q.lo);
            lo_u = max(lo_u, q.hi);
        } else {
            return entire_v();
        }
    }
    var e: VEnclosure;
    e.v[0] = iv_sub(Iv(lo_l, lo_u), Iv(hi_l, hi_u));
    return checked(e);
}

// An enclosure of `v` over x ∩ S where the filter is feasible (VForms::enclose): the natural
// one met with the mean-value forms where one row binds on the whole box, or, for one row
// binding on part of it, with min(0, F) or max(0, F) by the sign of p = a/‖a‖².
fn enclose_v(x: array<Iv, N0>) -> VEnclosure {
    let c = centred_of(x);
    let r = filter_rows(c);
    let natural = natural_v(r);
    if (!r.ok) {
        return natural;
    }
    let zero = iv_point(0.0);
    var e = natural;
    if (V_KIND == 1u) {
        let b = r.b_enc[0];
        if (b.lo >= 0.0) {
            return zero_v();
        }
        let norm2 = norm2_of(r);
        if (!(norm2.lo > 0.0)) {
            return natural;
        }
        var f: array<Iv, M_OUT>;
        for (var j = 0u; j < M_OUT; j++) {
            let form = vf_form(j, c);
            if (!form.ok) {
                return natural;
            }
            f[j] = form.enc;
        }
        for (var j = 0u; j < M_OUT; j++) {
            if (b.hi <= 0.0) {
                e.v[j] = iv_meet(natural.v[j], f[j]);
            } else {
                let pj = iv_meet(iv_div(r.a[j], norm2), vp_form(j, c).enc);
                var ej: Iv;
                if (pj.lo >= 0.0) {
                    ej = iv_min(f[j], zero);
                } else if (pj.hi <= 0.0) {
                    ej = iv_max(f[j], zero);
                } else {
                    ej = iv_mul(iv_min(b, zero), pj);
                }
                e.v[j] = iv_meet(natural.v[j], ej);
            }
        }
        return checked(e);
    }
    if (V_KIND == 2u) {
        var lo = zero;
        var hi = zero;
        var any_active = false;
        for (var k = 0u; k < ROWS; k++) {
            if (r.b_enc[k].lo >= 0.0) {
                continue;
            }
            let ak = r.a[k];
            if (ak.lo <= 0.0 && ak.hi >= 0.0) {
                return natural;
            }
            any_active = true;
            let rk = r_of(r, k, c);
            if (ak.hi < 0.0) {
                lo = iv_max(lo, rk);
            } else {
                hi = iv_min(hi, rk);
            }
        }
        if (!any_active) {
            return zero_v();
        }
        e.v[0] = iv_meet(natural.v[0], iv_add(lo, hi));
        return checked(e);
    }
    return natural;
}

// The transform's slack for the filtered field f̃ + g·v over an x-box with v ∈ v
// (FilterPieces::field_slack): ρ‖T‖∞ · max_i |f̃ᵢ + Σⱼ gᵢⱼ vⱼ|, HUGE where unbounded.
fn enclosed_slack(x: array<Iv, N0>, v: array<Iv, M_OUT>) -> real {
    if (!TRANSFORM) {
        return 0.0;
    }
    var f_max: real = 0.0;
    for (var i = 0u; i < N0; i++) {
        var fi = fx_iv(i, x);
        for (var j = 0u; j < M_OUT; j++) {
            fi = iv_add(fi, iv_mul(gx_iv(i * M_OUT + j, x), v[j]));
        }
        if (iv_nan(fi) || !finite(fi.lo) || !finite(fi.hi)) {
            return HUGE;
        }
        f_max = max(f_max, iv_mag(fi));
    }
    return up(TSLACK_UNIT * f_max);
}

// The transform's slack for binding piece k's field over an x-box (FilterPieces::binding_slack).
fn binding_slack(k: u32, x: array<Iv, N0>) -> real {
    if (!TRANSFORM) {
        return 0.0;
    }
    var f_max: real = 0.0;
    for (var i = 0u; i < N0; i++) {
        let fi = bfx_iv(k * N0 + i, x);
        if (iv_nan(fi) || !finite(fi.lo) || !finite(fi.hi)) {
            return HUGE;
        }
        f_max = max(f_max, iv_mag(fi));
    }
    return up(TSLACK_UNIT * f_max);
}

// The smooth piece `v` provably is on an x-box (within S) of the set (set_facts in
// src/reach/cpu.rs): with ENCLOSE (the filter's closed form), VForms::piece's mean-value forms
// (shaders/filter.wgsl); with EXACT_INACTIVE alone, PIECE_INACTIVE where every row's b(x) ≥ 0
// by natural interval evaluation (row_b_iv, src/reach/pieces.rs slack_rows); else PIECE_NONE.
fn piece_on(x: array<Iv, N0>) -> u32 {
    if (ENCLOSE) {
        return proven_piece(x);
    }
    if (!EXACT_INACTIVE) {
        return PIECE_NONE;
    }
    for (var k = 0u; k < ROWS; k++) {
        if (!(row_b_iv(k, x).lo >= 0.0)) {
            return PIECE_NONE;
        }
    }
    return PIECE_INACTIVE;
}

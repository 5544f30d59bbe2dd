// One box-step of the continuous model's common path in one frame (docs/design.md §7.1 item 3b,
// §7.4): the moving box guessed from the rates the box keeps, the field's rates on its 2n slabs
// from the network's bounds there, the strict check, the rates kept for the next guess, the
// step's end. The CPU engine's order (src/reach/cpu.rs `horizon`; cpu_guess.rs `guess_moving`;
// cpu_field.rs `network_field`; cpu_time.rs `check_step`, `curved`), for the network's field
// (no proven piece, no closed-form enclosures yet). A box-step this cannot finish is flagged
// and keeps its state, for the host. continuous.wgsl runs it in the engine's pipeline;
// src/gpu/probe_field.rs runs it alone, tests/gpu_matches_cpu/step.rs compares it with the
// CPU's. Needs validated.wgsl, end_rates.wgsl, field.wgsl, curved.wgsl.

// What one box keeps between steps in one frame: its set, the slab rates of the last step and
// of the step before, and how many of those it has (0 on a tube's first step).
struct StepState {
    lo: array<real, N0>,
    hi: array<real, N0>,
    r_lo: array<real, N0>,
    r_hi: array<real, N0>,
    b_lo: array<real, N0>,
    b_hi: array<real, N0>,
    rates: u32,
}

// The step's moving box (cpu_guess.rs guess_moving); `on_path` false where the common path
// cannot take the step: no rates yet, the guess refused (inside out, not finite) or, in x
// coordinates, its hull not within C (the enclosure handles C's sides, §7.1 item 1c).
struct Guess {
    m: Moving,
    on_path: bool,
}

fn guess_step(st: StepState, h: real) -> Guess {
    var g: Guess;
    g.on_path = false;
    if (st.rates == 0u) {
        return g;
    }
    g.m = guessed(st.lo, st.hi, h, st.r_lo, st.r_hi, st.b_lo, st.b_hi, st.rates >= 2u);
    if (!g.m.ok) {
        return g;
    }
    if (!TRANSFORM) {
        for (var i = 0u; i < N0; i++) {
            if (!(REGION_LO[i] <= g.m.hull_lo[i] && g.m.hull_hi[i] <= REGION_HI[i])) {
                return g;
            }
        }
    }
    g.on_path = true;
    return g;
}

// End (i, side)'s rates from the network's bounds nb on its slab (face-local) or on the hull,
// with the disturbance bound `margin`: the field's bound on the slab clamped to the slab's depth
// (validated::slab_field) and the curved end (curved_end; ∓HUGE where none), each widened by
// the transform's slack (network_field, curved).
struct EndRates {
    field: real,
    curved: real,
}

fn end_rates(st: StepState, m: Moving, h: real, i: u32, side: u32, nb: NetBounds, margin: real) -> EndRates {
    let s = slab(st.lo, st.hi, m, h, i, side);
    let b = bound_on(i, side, s.lo, s.hi, nb, margin, 0u);
    let c = curved_end(st.lo, st.hi, m, h, i, side, nb, margin, 0u);
    if (side == 0u) {
        let field = widen_down(min(b.lo, m.d_lo[i]), FIELD_SLACK);
        return EndRates(field, select(-HUGE, widen_down(c.r, FIELD_SLACK), c.ok));
    }
    let field = widen_up(max(b.hi, m.d_hi[i]), FIELD_SLACK);
    return EndRates(field, select(HUGE, widen_up(c.r, FIELD_SLACK), c.ok));
}

// The step from every end's rates (dl, du: the field's; cl, cu: the curved): where the check
// proves the moving box (validated::verified), the rates kept for the next guess (the last
// step's become the step before's) and the set at the step's end (slab_step_end: the meet with
// the curved rates, the outward step, the meet with the hull); else the state as it was, for the
// host (`proven` false).
struct Stepped {
    st: StepState,
    proven: bool,
}

fn finish_step(st: StepState, m: Moving, h: real, dl: array<real, N0>, du: array<real, N0>, cl: array<real, N0>, cu: array<real, N0>) -> Stepped {
    if (!verified(m, dl, du)) {
        return Stepped(st, false);
    }
    var out = st;
    out.b_lo = st.r_lo;
    out.b_hi = st.r_hi;
    out.r_lo = dl;
    out.r_hi = du;
    out.rates = min(st.rates + 1u, 2u);
    let end = slab_step_end(st.lo, st.hi, m, h, dl, du, cl, cu);
    out.lo = end.lo;
    out.hi = end.hi;
    return Stepped(out, true);
}

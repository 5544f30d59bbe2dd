// A box's continuous-time state in one frame and the moving box guessed from it (docs/design.md
// §7.1 item 3b; src/reach/cpu_host.rs StepState, cpu_guess.rs guess_moving): shared by the
// box-step (slab_step.wgsl) and the meet of two frames (cmeet.wgsl). Needs validated.wgsl.

// A box-step's result (flags word 5): stepped on the device, or left to the host.
const C_DEVICE: u32 = 1u;
const C_HOST: u32 = 2u;
// Flags word 2 where frames are met: `cpipes` guessed both frames' boxes (the common path).
const MET_GUESSED: u32 = 1u;

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

// The validated step h = dt / substeps (the CPU engine's, an f64) as the problem's enclosure
// [H_LO, H_HI] of it: a point in f64; in f32 the neighbouring f32 numbers, so that every
// product with it (validated.wgsl `moved`, the Taylor and curved rates) holds the exact step's.
fn h_step() -> Iv {
    return Iv(H_LO, H_HI);
}

fn guess_step(st: StepState, h: Iv) -> Guess {
    return guess_in(st, h, !TRANSFORM);
}

// guess_step for a frame in x coordinates (`in_x`: its hull must lie within C) or not: the meet
// of two frames (cmeet.wgsl) guesses the x frame's box in the first frame's module.
fn guess_in(st: StepState, h: Iv, in_x: bool) -> Guess {
    var g: Guess;
    g.on_path = false;
    if (st.rates == 0u) {
        return g;
    }
    g.m = guessed(st.lo, st.hi, h, st.r_lo, st.r_hi, st.b_lo, st.b_hi, st.rates >= 2u);
    if (!g.m.ok) {
        return g;
    }
    if (in_x) {
        for (var i = 0u; i < N0; i++) {
            if (!(REGION_LO[i] <= g.m.hull_lo[i] && g.m.hull_hi[i] <= REGION_HI[i])) {
                return g;
            }
        }
    }
    g.on_path = true;
    return g;
}

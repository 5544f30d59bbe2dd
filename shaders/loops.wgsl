// The loop-limit check of the kernels whose loops a driver may cut short (the error map's walk,
// margins.wgsl): the Euler embedding kernel (embed.wgsl) and the continuous step
// (continuous.wgsl) run it last. Needs `p` (Params).

// Whether this invocation's loops still run to their end: a loop of p.loop_check (2)
// iterations, a count the compiler cannot unroll, runs once only after a driver has cut the
// invocation's loops short (llvmpipe ends them all after 65,535 iterations in all, shared by
// the lanes of a SIMD group: src/gpu/margins.rs). The host then fails the run.
fn loops_ran_in_full() -> bool {
    var ran = 0u;
    for (var k = 0u; k < p.loop_check; k++) {
        ran += 1u;
    }
    return ran == p.loop_check;
}

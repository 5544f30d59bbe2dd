// One uniform struct for every kernel (src/gpu/buffers.rs: `Params`, same field order).
struct Params {
    // GEMM: Y (rows × cols) = op(W) (rows × inner) · X (inner × cols); other kernels: the
    // layer's output width in `rows`.
    rows: u32,
    inner: u32,
    cols: u32,
    // 1: use |W| instead of W.
    abs_w: u32,
    // Offsets of the layer's W (row-major, n_out × n_in) and b in `net`.
    w_off: u32,
    b_off: u32,
    // Width of the layer's input (the number of terms of its dot products).
    n_prev: u32,
    // 1 for the first layer (its forms are built from W₁ directly); in the backward kernels,
    // 1 for the first substitution of a pass (Λ = W_k is read from `net`).
    first: u32,
    // Boxes in this chunk.
    boxes: u32,
    // GEMM: 1: op(W) = Wᵀ (W stored n_inner × rows); 1: X read through max(·, 0).
    trans_w: u32,
    relu_x: u32,
    // GEMM: X[k, c] = x[k·ldx + x_off + c], Y[r, c] = y[r·ldy + y_off + c].
    x_off: u32,
    ldx: u32,
    y_off: u32,
    ldy: u32,
    // Backward passes: columns of Λ per box (2 n_k stacked upper/lower rows, or n_k shared).
    rpb: u32,
    // Offset in `pre` of this layer's recorded bounds l (then u, `rows × boxes` each), and in
    // `wm` of its |W| max(u_prev, 0) (`rows × boxes`).
    pre_off: u32,
    wm_off: u32,
    // Offset in `pre` of u of the layer before (the magnitude of this layer's input); the
    // input box itself when `at_input` is 1.
    prev_u_off: u32,
    at_input: u32,
    // The pass's start layer k: W_k and b_k offsets, its width n_k, its `wm` offset.
    k_w_off: u32,
    k_b_off: u32,
    k_rows: u32,
    k_wm_off: u32,
    // The embedding step: 2, the trip count of its loop-limit check (loops_ran_in_full).
    loop_check: u32,
    // Offset in `net` of the constants of a face's folded first layer (src/gpu/buffers.rs:
    // FlatNetwork; shaders/fold.wgsl).
    fold_off: u32,
    // 1 for the layer after the first: R̂ takes rowsum(|W|)·ε of the first layer's fold.
    carry: u32,
}

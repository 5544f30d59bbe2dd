// One uniform struct for every kernel (src/gpu/buffers.rs: `Params`, same field order).
struct Params {
    // GEMM: Y (rows × cols) = op(W) (rows × inner) · X (inner × cols).
    rows: u32,
    inner: u32,
    cols: u32,
    // 1: use |W| instead of W.
    abs_w: u32,
    // Offsets of the layer's W (row-major, rows × inner) and b in `net`.
    w_off: u32,
    b_off: u32,
    // Width of the layer's input (the number of terms of its dot products).
    n_prev: u32,
    // 1 for the first layer (its forms are built from W₁ directly).
    first: u32,
    // Boxes in this chunk.
    boxes: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

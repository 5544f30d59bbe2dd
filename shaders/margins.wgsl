// Local error margins (LOCAL_MARGIN): the largest certified bound of the error map's cells that
// a box meets, from the range-maximum structure of src/gpu/margins.rs (which documents it, and
// whose MarginMap::bound is this walk on the host). map_index: per shape [reals offset, words
// offset, K, H], then the cascade counts; map_cells: per shape l0[K], h0[K], per level l1[K],
// h1[K], then the sparse tables.
@group(0) @binding(5) var<storage, read> map_index: array<u32>;
@group(0) @binding(6) var<storage, read> map_cells: array<real>;

// The first position p in [0, k) with map_cells[at + p] >= q (ge) or > q (!ge): the entries
// there are sorted.
fn map_first(at: u32, k: u32, q: real, ge: bool) -> u32 {
    var lo = 0u;
    var hi = k;
    while (lo < hi) {
        let mid = lo + (hi - lo) / 2u;
        let v = map_cells[at + mid];
        if ((ge && v >= q) || (!ge && v > q)) {
            hi = mid;
        } else {
            lo = mid + 1u;
        }
    }
    return lo;
}

// The largest bound of shape s's cells that meet the box [a, b] (first two axes), -1 if none
// (bounds are ≥ 0, so a box that meets no cell of any shape is told apart from one that meets
// only cells of bound 0).
fn shape_margin(s: u32, a: array<real, 2>, b: array<real, 2>) -> real {
    let base_r = map_index[4u * s];
    let base_u = map_index[4u * s + 1u];
    let k = map_index[4u * s + 2u];
    let levels = map_index[4u * s + 3u];
    let i0 = map_first(base_r + k, k, a[0], true);
    let i1 = map_first(base_r, k, b[0], false);
    if (i0 >= i1) {
        return -1.0;
    }
    let top_y = base_r + 2u * k + 2u * levels * k;
    let j0 = map_first(top_y + k, k, a[1], true);
    let j1 = map_first(top_y, k, b[1], false);
    let tables = base_r + 2u * k * (levels + 2u);
    var worst: real = -1.0;
    // Blocks still to visit: (level, start, first, end) of the axis-1 range in the block.
    var stack: array<vec4<u32>, 40>;
    var top = 1u;
    stack[0] = vec4<u32>(levels, 0u, j0, j1);
    while (top > 0u) {
        top -= 1u;
        let node = stack[top];
        let level = node.x;
        let start = node.y;
        let pa = node.z;
        let pc = node.w;
        let end = min(start + (1u << level), k);
        if (end <= i0 || start >= i1 || pa >= pc) {
            continue;
        }
        if (i0 <= start && end <= i1) {
            let j = firstLeadingBit(pc - pa);
            let t = tables + k * (level * (level + 1u) / 2u + j);
            worst = max(worst, max(map_cells[t + start + pa], map_cells[t + start + pc - (1u << j)]));
            continue;
        }
        let half = 1u << (level - 1u);
        let left_len = min(half, k - start);
        let row = base_u + (level - 1u) * k + start;
        var la = left_len;
        if (start + pa != end) {
            la = map_index[row + pa];
        }
        var lc = left_len;
        if (start + pc != end) {
            lc = map_index[row + pc];
        }
        if (start + half < k) {
            stack[top] = vec4<u32>(level - 1u, start + half, pa - la, pc - lc);
            top += 1u;
        }
        stack[top] = vec4<u32>(level - 1u, start, la, lc);
        top += 1u;
    }
    return worst;
}

// The local error bound M over the x-box xb (ErrorMap::local_bound): HUGE (+∞) for an
// uncertified map, a box outside the map's region or with a non-finite end, or a cell met
// without a certified bound.
fn local_margin(xb: array<Iv, N0>) -> real {
    if (!MAP_CERTIFIED) {
        return HUGE;
    }
    var a: array<real, 2>;
    var b: array<real, 2>;
    a[1] = 0.0;
    b[1] = 0.0;
    for (var i = 0u; i < min(N0, 2u); i++) {
        a[i] = xb[i].lo;
        b[i] = xb[i].hi;
    }
    for (var i = 0u; i < 2u; i++) {
        if (!(finite(a[i]) && finite(b[i])) || a[i] < MAP_LO[i] || b[i] > MAP_HI[i]) {
            return HUGE;
        }
    }
    var worst: real = -1.0;
    for (var s = 0u; s < MAP_SHAPES; s++) {
        worst = max(worst, shape_margin(s, a, b));
    }
    // A box that meets no cell is where nothing was certified: +∞, never 0.
    if (worst < 0.0) {
        worst = HUGE;
    }
    // Tests only (MAP_PAD_LOOPS > 0): a long loop, to show the loop check at work.
    var pad: real = 0.0;
    for (var k = 0u; k < MAP_PAD_LOOPS; k++) {
        pad = max(pad, map_cells[k % MAP_REALS]);
    }
    return max(worst, min(pad, 0.0));
}

// The disturbance bound of a box whose true states lie in the x-box `known` (within S): the error
// map's local bound over it plus the network slack (LOCAL_MARGIN), else the global MARGIN; HUGE
// for +∞.
fn margin_of(known: array<Iv, N0>) -> real {
    if (!LOCAL_MARGIN) {
        return MARGIN;
    }
    let m = local_margin(known);
    if (m >= HUGE) {
        return HUGE;
    }
    return up(m + SLACK);
}

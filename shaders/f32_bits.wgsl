// f32 outward rounding through the bit pattern, for both precisions (`up` in real_f32.wgsl,
// the f32 evaluation of transcendental built-ins in either). Subnormals may be flushed, so the
// step from 0 (or from a subnormal) is to the smallest normal f32.

const MIN_NORMAL32: f32 = 1.17549435e-38;
const EPS32: f32 = 1.1920929e-7;

fn up32(x: f32) -> f32 {
    if (abs(x) < MIN_NORMAL32) {
        return MIN_NORMAL32;
    }
    let b = bitcast<u32>(x);
    if (x > 0.0) {
        return bitcast<f32>(b + 1u);
    }
    return bitcast<f32>(b - 1u);
}

fn down32(x: f32) -> f32 {
    return -up32(-x);
}

// `x` widened by `k` f32 ulps of relative error (k·2⁻²³·|x|) and one more step, upward.
fn up_rel32(x: f32, k: f32) -> f32 {
    return up32(up32(x + up32(abs(x) * k * EPS32)));
}

fn down_rel32(x: f32, k: f32) -> f32 {
    return -up_rel32(-x, k);
}

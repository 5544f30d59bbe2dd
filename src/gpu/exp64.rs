//! The f64 shaders' `exp` enclosure (`exp_enclosure` in `shaders/real_f64.wgsl`), mirrored
//! operation for operation, and a one-kernel run of the shader's own on the device, so that a
//! test compares the two on many inputs (tests/gpu_matches_cpu/).
//!
//! SPIR-V has `exp` for 32-bit floats only; taken in f32 and widened, it cost the Minkowski
//! radius ~2e-7 relative a step against the CPU's libm `exp` (5e-4 at t = 5.2 on the paper's
//! boxes). The f64 shaders instead reduce `x = k ln 2 + r` with `r` enclosed from an interval
//! for `ln 2`, take the Taylor polynomial of degree 13 on `|r| ≤ 0.35` with a bound on its
//! truncation and rounding (`POLY_ERR`, derivation in the shader), and scale by `2^k` exactly:
//! an enclosure 2e-14 (near 0) to 2e-13 (at |x| = 80)
//! relative wide, never narrower than the CPU's (4 ulp each side).
//!
//! The same for `φ(z) = (eᶻ − 1)/z` (`phi_up` in `shaders/phi.wgsl`, the closeness radius's
//! factor), whose series near 0 avoids the cancellation of `eᶻ − 1`.

use super::kernels::{F32_BITS, PHI, REAL_F64};
use super::{GpuContext, GpuError};

/// `ln 2` lies in `[LN2_LO, LN2_HI]` (`LN2_LO` is `f64::consts::LN_2`, which is below it).
pub const LN2_LO: f64 = std::f64::consts::LN_2;
/// The next f64 above [`LN2_LO`] (the shader's literal).
#[allow(clippy::approx_constant)]
pub const LN2_HI: f64 = 0.693_147_180_559_945_4;
/// The reduced argument's bound, on which [`POLY_ERR`] holds.
pub const R_MAX: f64 = 0.35;
/// Truncation and rounding of the degree-13 polynomial on `|r| ≤ R_MAX` (absolute).
pub const POLY_ERR: f64 = 1.0e-14;
/// Arguments past this are not reduced: `exp_up` is `HUGE` above it, `exp_down` 0 below `−`it.
pub const RANGE: f64 = 80.0;
/// The f64 prelude's `HUGE`.
const HUGE: f64 = 1.0e300;
const MIN_NORMAL: f64 = f64::MIN_POSITIVE;

/// The f64 prelude's `up`: an upper bound of the exact result of one rounded operation whose
/// computed value is `x` (a step of `max(|x|·2⁻⁵⁰, MIN_NORMAL)`).
fn up(x: f64) -> f64 {
    if x.abs() < MIN_NORMAL {
        return MIN_NORMAL;
    }
    x + (x.abs() * 8.881_784_197_001_252e-16).max(MIN_NORMAL)
}

fn down(x: f64) -> f64 {
    -up(-x)
}

/// `Σ_{j ≤ 13} r^j/j!`, nested: `1 + r(1 + r/2(1 + r/3(…)))`, the reciprocals correctly rounded.
fn poly(r: f64) -> f64 {
    let mut s = 1.0;
    for j in (1..=13).rev() {
        s = 1.0 + r * (1.0 / j as f64) * s;
    }
    s
}

/// `2^k` for `|k| < 256`, by squaring (every product exact).
fn pow2(k: i32) -> f64 {
    let mut b = if k < 0 { 0.5 } else { 2.0 };
    let mut m = k.abs();
    let mut s = 1.0;
    for _ in 0..8 {
        if m & 1 == 1 {
            s *= b;
        }
        b *= b;
        m >>= 1;
    }
    s
}

/// `[e̲, ē] ∋ eˣ` for `|x| ≤ RANGE`, as the shader computes it.
#[allow(clippy::approx_constant)] // the shader's f32 literal for 1/ln 2, as written there
pub fn exp_enclosure(x: f64) -> (f64, f64) {
    // Any integer k is sound; round(x / ln 2) keeps |r| ≤ ln 2 / 2 + 2e-5.
    let kf = ((x as f32) * 1.442_695_f32).round_ties_even();
    let k = f64::from(kf);
    let (kl_lo, kl_hi) = match k >= 0.0 {
        true => (down(k * LN2_LO), up(k * LN2_HI)),
        false => (down(k * LN2_HI), up(k * LN2_LO)),
    };
    let (r_lo, r_hi) = (down(x - kl_hi), up(x - kl_lo));
    if !(r_lo >= -R_MAX && r_hi <= R_MAX) {
        return (0.0, HUGE);
    }
    let p_lo = down(poly(r_lo) - POLY_ERR);
    let p_hi = up(poly(r_hi) + POLY_ERR);
    let s = pow2(kf as i32);
    ((p_lo * s).max(0.0), p_hi * s)
}

/// A lower bound of `eˣ` (the shader's `exp_down`).
pub fn exp_down(x: f64) -> f64 {
    if x < -RANGE {
        0.0
    } else {
        exp_enclosure(x.min(RANGE)).0
    }
}

/// An upper bound of `eˣ` (the shader's `exp_up`).
pub fn exp_up(x: f64) -> f64 {
    if x > RANGE {
        HUGE
    } else {
        exp_enclosure(x.max(-RANGE)).1
    }
}

/// `(eᶻ − 1)/z ≤ phi_up(z)`, as `shaders/phi.wgsl` computes it in f64 (the CPU's is
/// `reach::closeness::phi_upper`).
pub fn phi_up(z: f64) -> f64 {
    let up3 = |x: f64| up(up(up(x)));
    let down3 = |x: f64| down(down(down(x)));
    if z.is_nan() || z.abs() > 0.5 {
        return match z > 0.0 {
            true => up3(up(exp_up(z) - 1.0) / z),
            false => up3(up(1.0 - exp_down(z)) / (-z)),
        };
    }
    let (mut cl, mut ch) = ([1.0; 13], [1.0; 13]);
    for k in 1..13 {
        cl[k] = down3(cl[k - 1] / (k + 1) as f64);
        ch[k] = up3(ch[k - 1] / (k + 1) as f64);
    }
    let (mut lo, mut hi) = (cl[12], ch[12]);
    for k in (0..12).rev() {
        let (pl, ph) = match z >= 0.0 {
            true => (down(z * lo), up(z * hi)),
            false => (down(z * hi), up(z * lo)),
        };
        lo = down(pl + cl[k]);
        hi = up(ph + ch[k]);
    }
    let t = z.abs();
    let p = (0..12).fold(t, |p, _| up(p * t));
    up(hi + up(p * crate::reach::closeness::PHI_TAIL))
}

/// The kernels: `[exp_down(xᵢ), exp_up(xᵢ)]`, or `phi_up(xᵢ)`, for each input.
const KERNEL: &str = "
@group(0) @binding(0) var<storage, read> xs: array<f64>;
@group(0) @binding(1) var<storage, read_write> ys: array<f64>;

@compute @workgroup_size(64)
fn exp_test(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&xs)) {
        return;
    }
    ys[2u * i] = exp_down(xs[i]);
    ys[2u * i + 1u] = exp_up(xs[i]);
}

@compute @workgroup_size(64)
fn phi_test(@builtin(global_invocation_id) id: vec3<u32>) {
    let i = id.x;
    if (i >= arrayLength(&xs)) {
        return;
    }
    ys[i] = phi_up(xs[i]);
}
";

/// The shader's `exp_down` and `exp_up` of every input, run on the device (f64).
pub fn on_device(ctx: &GpuContext, xs: &[f64]) -> Result<Vec<(f64, f64)>, GpuError> {
    let ys = run(ctx, xs, "exp_test", 2)?;
    Ok(ys.chunks(2).map(|p| (p[0], p[1])).collect())
}

/// The shader's `phi_up` of every input, run on the device (f64).
pub fn phi_on_device(ctx: &GpuContext, xs: &[f64]) -> Result<Vec<f64>, GpuError> {
    run(ctx, xs, "phi_test", 1)
}

/// Runs the test kernel `entry`, `per` outputs an input.
fn run(ctx: &GpuContext, xs: &[f64], entry: &str, per: usize) -> Result<Vec<f64>, GpuError> {
    // The prelude's helpers use `down`, `up3` and `down3` (common.wgsl); they alone are
    // stated here.
    let helpers = "fn down(x: real) -> real {\n    return -up(-x);\n}\n\
                   fn up3(x: real) -> real {\n    return up(up(up(x)));\n}\n\
                   fn down3(x: real) -> real {\n    return down(down(down(x)));\n}\n";
    let source = format!("{REAL_F64}\n{F32_BITS}\n{helpers}{PHI}\n{KERNEL}");
    super::probe::run(ctx, &source, entry, xs, xs.len(), per)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// ln 2 = 0.693147180559945309417232121458…: the bracket holds it, and is one ulp wide.
    #[test]
    fn ln2_bracket_holds_ln2() {
        assert_eq!(LN2_LO, std::f64::consts::LN_2);
        assert_eq!(LN2_HI, LN2_LO.next_up());
        let digits = "0.693147180559945309417232121458";
        assert!(format!("{LN2_LO:.30}").as_str() < digits);
        assert!(format!("{LN2_HI:.30}").as_str() > digits);
    }

    /// The mirror of the shader's `phi_up` lies above `φ` (the CPU's own bound, which is a few
    /// ulp above it) and within 1e-14 of the CPU's on the series (|z| ≤ 1/2, through 0), within
    /// 3e-13 past it (the f64 shaders' `exp` enclosure's width).
    #[test]
    fn phi_up_is_tight_and_near_the_cpus() {
        use crate::reach::closeness::phi_upper;
        let mut zs: Vec<f64> = (-6000..=6000).map(|i| i as f64 * 0.01).collect();
        zs.extend((0..300).flat_map(|e| [1e-15 * 1.13_f64.powi(e), -1e-15 * 1.13_f64.powi(e)]));
        zs.extend([0.0, 0.5, -0.5, 0.5_f64.next_up(), (-0.5_f64).next_down()]);
        for z in zs {
            let (gpu, cpu) = (phi_up(z), phi_upper(z));
            let exact = if z == 0.0 { 1.0 } else { z.exp_m1() / z };
            assert!(gpu >= exact * (1.0 - 1e-15), "{z}: {gpu} < {exact}");
            // Past the series, as wide as the exp enclosures allow (2.5e-13 at |z| = 80).
            let tol = if z.abs() <= 0.5 { 1e-14 } else { 3e-13 };
            assert!((gpu - cpu).abs() <= tol * cpu, "{z}: {gpu} vs {cpu}");
        }
    }

    /// Over [−80, 80] the enclosure holds libm's `exp` one ulp outward (libm is within 1 ulp),
    /// is at most 2.5e-13 relative wide (1e-14
    /// near 0; at |x| = 80 the reduction's steps on k ln 2 ≈ 80 dominate), and holds the CPU's own enclosure (the radius on the
    /// GPU is never below the CPU's).
    #[test]
    fn encloses_exp_tightly() {
        let mut worst: f64 = 0.0;
        for i in 0..=200_000 {
            let x = -80.0 + 160.0 * i as f64 / 200_000.0 + 1e-9 * (i % 7) as f64;
            let (lo, hi) = exp_enclosure(x);
            let e = x.exp();
            let cpu = crate::intervals::Interval::point(x).exp();
            assert!(
                lo <= e.next_down() && e.next_up() <= hi,
                "{x}: [{lo}, {hi}] vs {e}"
            );
            assert!(
                lo <= cpu.lower && cpu.upper <= hi,
                "{x}: [{lo}, {hi}] vs {cpu:?}"
            );
            worst = worst.max((hi - lo) / e);
        }
        assert!(worst < 2.5e-13, "{worst}");
        assert_eq!(exp_down(-100.0), 0.0);
        assert_eq!(exp_up(100.0), HUGE);
        assert!(exp_down(100.0) > 5e34 && exp_up(-100.0) < 2e-34);
    }
}

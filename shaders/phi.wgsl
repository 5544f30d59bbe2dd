// φ(z) = (eᶻ − 1)/z ≤ phi_up(z), for the closeness radius (shaders/embed.wgsl). The CPU's is
// phi_upper in src/reach/closeness.rs (the same method in its own interval arithmetic);
// src/gpu/exp64.rs mirrors this one operation for operation, and a test compares the two on the
// device. Near 0, eᶻ − 1 cancels (from an enclosure of eᶻ, off by its width over |z|, without
// bound as z → 0): for |z| ≤ 1/2 the series Σ_{k ≤ 12} zᵏ/(k+1)! by Horner over an interval,
// the coefficients enclosed on the way, plus the tail Σ_{k>12} |z|ᵏ/(k+1)! ≤ PHI_TAIL·|z|¹³
// (1/(14!·(1 − 1/30)) < 1.19e-11); elsewhere from exp_up / exp_down, where |eᶻ − 1| ≥ 0.39.
const PHI_TAIL: real = 1.2e-11;

fn phi_up(z: real) -> real {
    if (!(abs(z) <= 0.5)) {
        if (z > 0.0) {
            return up3(up(exp_up(z) - 1.0) / z);
        }
        return up3(up(1.0 - exp_down(z)) / (-z));
    }
    var cl: array<real, 13>;
    var ch: array<real, 13>;
    cl[0] = 1.0;
    ch[0] = 1.0;
    for (var k = 1u; k < 13u; k++) {
        cl[k] = down3(cl[k - 1u] / real(k + 1u));
        ch[k] = up3(ch[k - 1u] / real(k + 1u));
    }
    var lo = cl[12];
    var hi = ch[12];
    for (var k = 11i; k >= 0i; k--) {
        var pl: real;
        var ph: real;
        if (z >= 0.0) {
            pl = down(z * lo);
            ph = up(z * hi);
        } else {
            pl = down(z * hi);
            ph = up(z * lo);
        }
        lo = down(pl + cl[k]);
        hi = up(ph + ch[k]);
    }
    let t = abs(z);
    var p = t;
    for (var k = 0u; k < 12u; k++) {
        p = up(p * t);
    }
    return up(hi + up(p * PHI_TAIL));
}

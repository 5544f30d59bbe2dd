//! The forward method's work between two layers' products, across 4 or 8 neurons and boxes at
//! a time (AVX2 or AVX-512 registers, chosen at run time): the bias and its rounding, the concretisation of each neuron's forms over its
//! box, the ReLU relaxation, the result's form magnitude `V`, and which rows the next products
//! read (docs/design.md §5).
//!
//! The forms are stored in planes ([`super::forward::Workspace`]): coefficient `p` of neuron
//! `i` in box `g` at `p·nG + i·G + g`, so that one plane is a contiguous run over (neuron,
//! box) pairs and the relaxation walks it `L` entries at a time, whatever the number of
//! boxes `G`. What depends on the box (its centre, radius, magnitudes, scale) is laid out once
//! per call in blocks of `lcm(G, L)` entries, what depends on the neuron (bias, `|W|`'s
//! row sum) once per block; the loads are then plain vector loads.
//!
//! Every lane computes what the scalar code of the rounding model computes, operation for
//! operation ([`Lanes`] holds no fused or reordered arithmetic; its `round_up` is
//! [`crate::rounding::round_up`] without branches): the bounds are bit for bit the scalar
//! code's, which the tests of this module check.
#![allow(clippy::needless_range_loop)] // lane loops read as the formulas

use crate::machine::Isa;

/// Lanes of a vector step: four f64 in an AVX2 register (and in the portable code, which the
/// compiler vectorises as it can), eight in an AVX-512 one.
const LANES: usize = 4;
const LANES_512: usize = 8;

/// `L` values computed lane by lane: each method is one loop of one operation, which the
/// compiler turns into one vector instruction (where the function is compiled for AVX2).
#[derive(Clone, Copy, Debug)]
pub(super) struct Lanes<const L: usize>(pub(super) [f64; L]);

impl<const L: usize> Lanes<L> {
    #[inline(always)]
    pub(super) fn splat(x: f64) -> Self {
        Lanes([x; L])
    }
    #[inline(always)]
    pub(super) fn load(s: &[f64], at: usize) -> Self {
        Lanes(s[at..at + L].try_into().expect("L lanes"))
    }
    #[inline(always)]
    pub(super) fn store(self, s: &mut [f64], at: usize) {
        s[at..at + L].copy_from_slice(&self.0);
    }
    #[inline(always)]
    fn map(self, f: impl Fn(f64) -> f64) -> Self {
        let mut r = self.0;
        for l in 0..L {
            r[l] = f(self.0[l]);
        }
        Lanes(r)
    }
    #[inline(always)]
    fn zip(self, o: Self, f: impl Fn(f64, f64) -> f64) -> Self {
        let mut r = self.0;
        for l in 0..L {
            r[l] = f(self.0[l], o.0[l]);
        }
        Lanes(r)
    }
    #[inline(always)]
    pub(super) fn add(self, o: Self) -> Self {
        self.zip(o, |a, b| a + b)
    }
    #[inline(always)]
    pub(super) fn sub(self, o: Self) -> Self {
        self.zip(o, |a, b| a - b)
    }
    #[inline(always)]
    pub(super) fn mul(self, o: Self) -> Self {
        self.zip(o, |a, b| a * b)
    }
    #[inline(always)]
    fn div(self, o: Self) -> Self {
        self.zip(o, |a, b| a / b)
    }
    #[inline(always)]
    pub(super) fn neg(self) -> Self {
        self.map(|a| -a)
    }
    #[inline(always)]
    pub(super) fn abs(self) -> Self {
        self.map(f64::abs)
    }
    /// `f64::max` lane by lane (a NaN operand gives the other).
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.zip(o, f64::max)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.zip(o, f64::min)
    }
    /// `a` where `test(self, than)`, else `b`.
    #[inline(always)]
    fn pick(self, than: Self, test: impl Fn(f64, f64) -> bool, a: Self, b: Self) -> Self {
        let mut r = b.0;
        for l in 0..L {
            r[l] = if test(self.0[l], than.0[l]) {
                a.0[l]
            } else {
                b.0[l]
            };
        }
        Lanes(r)
    }
    /// [`crate::rounding::round_up`] lane by lane: the next f64 above (`+∞` and NaN kept, `±0` to the smallest
    /// subnormal), by integer steps on the bits rather than branches.
    #[inline(always)]
    pub(super) fn up(self) -> Self {
        self.map(|x| {
            let bits = x.to_bits() as i64;
            // Away from zero on the bits for x > 0, towards it for x < 0 (−∞ to −MAX):
            // `bits ± 1` as `bits + (sign mask | 1)`.
            let step = -((bits < 0) as i64) | 1;
            let next = f64::from_bits(if x == 0.0 {
                1
            } else {
                bits.wrapping_add(step) as u64
            });
            // `+∞` and NaN stay (`x < ∞` fails for both).
            if x < f64::INFINITY {
                next
            } else {
                x
            }
        })
    }
    /// [`Lanes::up`] where every lane is `+0` or positive (a magnitude, an error bound): one
    /// integer step. A `+∞` lane becomes NaN there, which poisons the box as `+∞` would.
    #[inline(always)]
    fn up_nonneg(self) -> Self {
        self.map(|x| f64::from_bits(x.to_bits().wrapping_add(1)))
    }
    /// [`crate::rounding::round_up_keep_zero`].
    #[inline(always)]
    fn up_keep_zero(self) -> Self {
        let zero = Self::splat(0.0);
        self.pick(zero, |a, b| a == b, zero, self.up())
    }
    /// [`Lanes::up_keep_zero`] where every lane is `±0` or positive.
    #[inline(always)]
    fn up_nonneg_keep_zero(self) -> Self {
        let zero = Self::splat(0.0);
        self.pick(zero, |a, b| a == b, zero, self.up_nonneg())
    }
    /// [`crate::rounding::add_up`].
    #[inline(always)]
    pub(super) fn add_up(self, o: Self) -> Self {
        self.add(o).up()
    }
    /// [`crate::rounding::add_down`].
    #[inline(always)]
    fn add_down(self, o: Self) -> Self {
        self.add(o).neg().up().neg()
    }
    /// [`crate::rounding::err_bound`] for `n_terms` terms (`magnitude ≥ +0`, `scale ≥ 1`).
    #[inline(always)]
    pub(super) fn err_bound(n_terms: usize, magnitude: Self, scale: Self) -> Self {
        let underflow = Self::splat(n_terms as f64 * f64::MIN_POSITIVE).mul(scale);
        let gamma = Self::splat(crate::rounding::gamma_hat(n_terms));
        gamma.mul(magnitude).up_nonneg().add(underflow).up_nonneg()
    }
}

/// What varies per box, laid out in a block of `lcm(G, L)` entries (entry `o` belongs to
/// box `o mod G`), and per neuron, refilled per block of rows.
#[derive(Default)]
pub(super) struct Blocks {
    /// Centre, radius and magnitude bound of each form coordinate, `d` runs of a block.
    xc: Vec<f64>,
    xr: Vec<f64>,
    xmag: Vec<f64>,
    scale: Vec<f64>,
    /// `pending` as carried into the bias (`|W|·pending`) and as added to the concretisation.
    carry: Vec<f64>,
    widen: Vec<f64>,
    bias: Vec<f64>,
    row_sum: Vec<f64>,
    /// Per entry of a block: `Σ|Ĉ'|`, `Σ|R̂'|` and `V'` of the result (nonzero ⇔ its row is
    /// read by the next products).
    nz_c: Vec<f64>,
    nz_r: Vec<f64>,
    nz_v: Vec<f64>,
    /// Per entry: a bound of the layer there was not finite.
    bad: Vec<f64>,
}

/// A hidden layer's forms and what the relaxation reads beside them.
pub(super) struct Layer<'a> {
    /// Neurons `n`, boxes `G`, form coordinates `d`.
    pub(super) n: usize,
    pub(super) g: usize,
    pub(super) d: usize,
    /// `d + 1` planes of `Ĉ`, `n × G` each.
    pub(super) c: &'a mut [f64],
    /// `d + 1` planes of `R̂`, then `V` (as the products left it; the result's on return).
    pub(super) rv: &'a mut [f64],
    /// Per box (`G × d`, `G`, `G`): the box's form coordinates, scale and pending error.
    pub(super) xc: &'a [f64],
    pub(super) xr: &'a [f64],
    pub(super) xmag: &'a [f64],
    pub(super) scale: &'a [f64],
    pub(super) pending: &'a [f64],
    /// After a product (layer `k > 0`): the bias, `rowsum(|W|)` and the product's inner
    /// dimension `n_{k−1}`; `Ĉ`'s constant takes the bias, `R̂`'s the rounding of the layer
    /// and `rowsum(|W|)·pending`, and the concretisation no longer adds `pending`.
    pub(super) bias: Option<(&'a [f64], &'a [f64], usize)>,
    /// With IBP alongside: its interval of this layer (`n × G` centres and radii), if any, to
    /// intersect with; and where its interval after the ReLU goes.
    pub(super) ibp_pre: Option<(&'a [f64], &'a [f64])>,
    pub(super) ibp_post: Option<(&'a mut [f64], &'a mut [f64])>,
    /// Where the concrete bounds go (`n × G`), if kept.
    pub(super) record: Option<(&'a mut [f64], &'a mut [f64])>,
}

/// The rows of `Ĉ`, `R̂` and `V` that are not all zero, ascending (what the next products read).
#[derive(Default)]
pub(super) struct LiveRows {
    pub(super) c: Vec<usize>,
    pub(super) r: Vec<usize>,
    pub(super) v: Vec<usize>,
}

/// Relaxes `layer` in place; boxes whose bounds are not finite are marked in `poisoned`. Runs
/// the widest vector code the CPU has.
pub(super) fn relax(
    layer: Layer<'_>,
    poisoned: &mut [bool],
    blocks: &mut Blocks,
    live: &mut LiveRows,
) {
    relax_on(Isa::detect(), layer, poisoned, blocks, live);
}

/// [`relax`] on `isa`'s code (panics where the CPU lacks it). Every path computes the same
/// numbers (no fused or reordered arithmetic in [`Lanes`]), only so many lanes at a time.
fn relax_on(
    isa: Isa,
    layer: Layer<'_>,
    poisoned: &mut [bool],
    b: &mut Blocks,
    live: &mut LiveRows,
) {
    assert!(isa.available(), "relaxation: no {} here", isa.name());
    match isa {
        // SAFETY: the CPU has the features the functions are compiled for (asserted).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { relax_avx512(layer, poisoned, b, live) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { relax_avx2(layer, poisoned, b, live) },
        _ => relax_dispatch::<LANES>(layer, poisoned, b, live),
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn relax_avx2(layer: Layer<'_>, poisoned: &mut [bool], b: &mut Blocks, live: &mut LiveRows) {
    relax_dispatch::<LANES>(layer, poisoned, b, live);
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn relax_avx512(
    layer: Layer<'_>,
    poisoned: &mut [bool],
    b: &mut Blocks,
    live: &mut LiveRows,
) {
    relax_dispatch::<LANES_512>(layer, poisoned, b, live);
}

/// The common form sizes get their own copy, the loops over coefficients unrolled; `L` lanes.
#[inline(always)]
fn relax_dispatch<const L: usize>(
    layer: Layer<'_>,
    poisoned: &mut [bool],
    b: &mut Blocks,
    live: &mut LiveRows,
) {
    match layer.d {
        1 => relax_body::<2, L>(layer, poisoned, b, live),
        2 => relax_body::<3, L>(layer, poisoned, b, live),
        3 => relax_body::<4, L>(layer, poisoned, b, live),
        4 => relax_body::<5, L>(layer, poisoned, b, live),
        _ => relax_body::<0, L>(layer, poisoned, b, live),
    }
}

/// `K` is `d + 1` when it is a compile-time constant, or 0 to read `d` at run time.
#[inline(always)]
fn relax_body<const K: usize, const L: usize>(
    mut layer: Layer<'_>,
    poisoned: &mut [bool],
    b: &mut Blocks,
    live: &mut LiveRows,
) {
    let (n, g_count, d) = (layer.n, layer.g, layer.d);
    debug_assert!(K == 0 || K == d + 1);
    let block = g_count * L / gcd(g_count, L);
    let rows_per_block = block / g_count;
    b.xc.clear();
    b.xr.clear();
    b.xmag.clear();
    for p in 0..d {
        for o in 0..block {
            let at = (o % g_count) * d + p;
            b.xc.push(layer.xc[at]);
            b.xr.push(layer.xr[at]);
            b.xmag.push(layer.xmag[at]);
        }
    }
    let repeat = |v: &mut Vec<f64>, f: &dyn Fn(usize) -> f64| {
        v.clear();
        v.extend((0..block).map(|o| f(o % g_count)));
    };
    repeat(&mut b.scale, &|g| layer.scale[g]);
    let with_bias = layer.bias.is_some();
    repeat(&mut b.carry, &|g| {
        if with_bias {
            layer.pending[g]
        } else {
            0.0
        }
    });
    repeat(&mut b.widen, &|g| {
        if with_bias {
            0.0
        } else {
            layer.pending[g]
        }
    });
    for v in [
        &mut b.bias,
        &mut b.row_sum,
        &mut b.nz_c,
        &mut b.nz_r,
        &mut b.nz_v,
        &mut b.bad,
    ] {
        v.clear();
        v.resize(block, 0.0);
    }
    live.c.clear();
    live.r.clear();
    live.v.clear();
    let mut i0 = 0;
    while i0 < n {
        let rows = rows_per_block.min(n - i0);
        let len = rows * g_count;
        if let Some((bias, row_sum, _)) = layer.bias {
            for r in 0..rows {
                b.bias[r * g_count..(r + 1) * g_count].fill(bias[i0 + r]);
                b.row_sum[r * g_count..(r + 1) * g_count].fill(row_sum[i0 + r]);
            }
        }
        let t0 = i0 * g_count;
        let mut o = 0;
        while o + L <= len {
            lanes::<K, L>(&mut layer, b, t0 + o, o);
            o += L;
        }
        while o < len {
            lanes::<K, 1>(&mut layer, b, t0 + o, o);
            o += 1;
        }
        for r in 0..rows {
            let span = r * g_count..(r + 1) * g_count;
            let nonzero = |v: &[f64]| v[span.clone()].iter().any(|&x| x != 0.0);
            if nonzero(&b.nz_c) {
                live.c.push(i0 + r);
            }
            if nonzero(&b.nz_r) {
                live.r.push(i0 + r);
            }
            if nonzero(&b.nz_v) {
                live.v.push(i0 + r);
            }
        }
        i0 += rows;
    }
    // Entry `o` of the block belongs to box `o mod G`.
    for (o, &x) in b.bad.iter().enumerate() {
        poisoned[o % g_count] |= x != 0.0;
    }
}

fn gcd(a: usize, b: usize) -> usize {
    if b == 0 {
        a
    } else {
        gcd(b, a % b)
    }
}

/// `L` consecutive entries from `t` (block offset `o`): the relaxation of `forward`'s module
/// documentation, in the scalar code's order of operations.
#[inline(always)]
fn lanes<const K: usize, const L: usize>(
    layer: &mut Layer<'_>,
    b: &mut Blocks,
    t: usize,
    o: usize,
) {
    type V<const L: usize> = Lanes<L>;
    let d = if K == 0 { layer.d } else { K - 1 };
    let k_cols = d + 1;
    let plane = layer.n * layer.g;
    let ld = |s: &[f64], at: usize| V::<L>::load(s, at);
    let scale = ld(&b.scale, o);
    let (c, rv) = (&mut *layer.c, &mut *layer.rv);
    let (mut cd, mut rd) = (ld(c, d * plane + t), ld(rv, d * plane + t));
    if let Some((_, _, n_prev)) = layer.bias {
        let (bias, v) = (ld(&b.bias, o), ld(rv, k_cols * plane + t));
        cd = cd.add(bias);
        let err = V::err_bound(n_prev + 1, v.add(bias.abs()), scale);
        // |W|·(pending, …, pending) ≤ rowsum(|W|)·pending.
        let carried = ld(&b.row_sum, o).mul(ld(&b.carry, o)).up_nonneg_keep_zero();
        rd = rd.add_up(err).add_up(carried);
    }
    let (mut su, mut sl, mut mag) = (cd.add(rd), cd.sub(rd), cd.abs().add(rd.abs()));
    for p in 0..d {
        let (cp, rp) = (ld(c, p * plane + t), ld(rv, p * plane + t));
        let (xc, xr) = (
            ld(&b.xc, p * b.scale.len() + o),
            ld(&b.xr, p * b.scale.len() + o),
        );
        let xmag = ld(&b.xmag, p * b.scale.len() + o);
        let (up, lo) = (cp.add(rp), cp.sub(rp));
        su = su.add(up.mul(xc).add(up.abs().mul(xr)));
        sl = sl.add(lo.mul(xc).sub(lo.abs().mul(xr)));
        mag = mag.add(cp.abs().add(rp.abs()).mul(xmag));
    }
    let err = V::err_bound(3 * d + 3, mag, scale)
        .add(ld(&b.widen, o))
        .up_nonneg();
    let (mut l, mut u) = (sl.add_down(err.neg()), su.add_up(err));
    let not_finite = |x: V<L>| {
        let (inf, zero, one) = (V::splat(f64::INFINITY), V::splat(0.0), V::splat(1.0));
        x.abs().pick(inf, |a, m| a < m, zero, one)
    };
    // Kept over the whole layer, read once at its end.
    let bad = not_finite(l).max(not_finite(u)).max(V::load(&b.bad, o));
    bad.store(&mut b.bad, o);
    if let Some((pc, pr)) = layer.ibp_pre {
        let (pc, pr) = (ld(pc, t), ld(pr, t));
        l = l.max(pc.add_down(pr.neg()));
        u = u.min(pc.add_up(pr));
    }
    if let Some((ic, ir)) = &mut layer.ibp_post {
        // `centre_radius` of ReLU's image `[max(l, 0), max(u, 0)]`.
        let zero = V::splat(0.0);
        let (lp, hp) = (l.max(zero), u.max(zero));
        let half = V::splat(0.5);
        let cen = half.mul(lp).add(half.mul(hp));
        let rad = hp.sub(cen).up_keep_zero().max(cen.sub(lp).up_keep_zero());
        cen.store(ic, t);
        rad.store(ir, t);
    }
    if let Some((lo_out, hi_out)) = &mut layer.record {
        l.store(lo_out, t);
        u.store(hi_out, t);
    }
    // `relu_lines(l, u, Adaptive)` for the unstable case, computed in every lane and kept
    // where `l < 0 < u`. Stable lanes compute it on `[−1, 1]`: on their own `l, u` the
    // slopes and intercepts come out as subnormal numbers, and arithmetic on those takes a
    // microcode assist of ~100 cycles (a fifth of the relaxation's time when it did).
    let (zero, one) = (V::splat(0.0), V::splat(1.0));
    if (0..L).all(|q| u.0[q] <= 0.0 || l.0[q] >= 0.0) {
        // Every lane stable (the common case): dead → 0, active → kept.
        let keep = |x: V<L>| u.pick(zero, |a, m| a <= m, zero, x);
        let (mut nz_c, mut nz_r) = (zero, zero);
        for p in 0..k_cols {
            let (cp, rp) = match p == d {
                true => (cd, rd),
                false => (ld(c, p * plane + t), ld(rv, p * plane + t)),
            };
            let (c3, r3) = (keep(cp), keep(rp));
            c3.store(c, p * plane + t);
            r3.store(rv, p * plane + t);
            nz_c = nz_c.add(c3.abs());
            nz_r = nz_r.add(r3.abs());
        }
        let v = keep(mag);
        v.store(rv, k_cols * plane + t);
        nz_c.store(&mut b.nz_c, o);
        nz_r.store(&mut b.nz_r, o);
        v.store(&mut b.nz_v, o);
        return;
    }
    let (lr, ur) = {
        let stable = |x: V<L>, y: V<L>| {
            let active = l.pick(zero, |a, m| a >= m, y, x);
            u.pick(zero, |a, m| a <= m, y, active)
        };
        (stable(l, one.neg()), stable(u, one))
    };
    let s = ur.div(ur.sub(lr)).map(|x| x.clamp(0.0, 1.0));
    let s_up = s.pick(V::splat(super::TINY_SLOPE), |a, m| a < m, zero, s);
    let t_up = s_up
        .neg()
        .mul(lr)
        .up_nonneg()
        .max(ur.sub(s_up.mul(ur).neg().up().neg()).up_nonneg());
    let s_lo = ur.pick(lr.neg(), |a, m| a >= m, one, zero);
    let half = V::splat(0.5);
    let (alpha, beta) = (half.mul(s_up.add(s_lo)), half.mul(s_up.sub(s_lo)));
    // Per lane: dead (`u ≤ 0`) → 0, active (`l ≥ 0`) → kept, else the relaxed value.
    let choose = |relaxed: V<L>, kept: V<L>| {
        let stable = l.pick(zero, |a, m| a >= m, kept, relaxed);
        u.pick(zero, |a, m| a <= m, zero, stable)
    };
    // The constant first: `V` sums it first, then the coefficients in order.
    let (mut c2, mut r2) = (
        alpha.mul(cd).add(beta.mul(rd)),
        beta.mul(cd).add(alpha.mul(rd)),
    );
    let ht = half.mul(t_up);
    c2 = c2.add(ht);
    r2 = r2.add(ht);
    let worst = s_up.max(s_lo).mul(mag).add(t_up);
    r2 = r2.add_up(V::err_bound(8, worst, scale));
    let mut v = c2.abs().add(r2.abs());
    let (c3, r3) = (choose(c2, cd), choose(r2, rd));
    c3.store(c, d * plane + t);
    r3.store(rv, d * plane + t);
    let (mut nz_c, mut nz_r) = (c3.abs(), r3.abs());
    for p in 0..d {
        let (cp, rp) = (ld(c, p * plane + t), ld(rv, p * plane + t));
        let (c2, r2) = (
            alpha.mul(cp).add(beta.mul(rp)),
            beta.mul(cp).add(alpha.mul(rp)),
        );
        let xmag = ld(&b.xmag, p * b.scale.len() + o);
        v = v.add(c2.abs().add(r2.abs()).mul(xmag));
        let (c3, r3) = (choose(c2, cp), choose(r2, rp));
        c3.store(c, p * plane + t);
        r3.store(rv, p * plane + t);
        nz_c = nz_c.add(c3.abs());
        nz_r = nz_r.add(r3.abs());
    }
    let v = choose(v, mag);
    v.store(rv, k_cols * plane + t);
    nz_c.store(&mut b.nz_c, o);
    nz_r.store(&mut b.nz_r, o);
    v.store(&mut b.nz_v, o);
}

#[cfg(test)]
mod tests;

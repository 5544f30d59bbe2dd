use super::*;
use crate::bounds::ibp::centre_radius;
use crate::bounds::{relu_lines, Relaxation};
use crate::rounding::{add_down, add_up, err_bound, round_up, round_up_keep_zero};
use rand::{Rng, SeedableRng};

/// The vector paths this CPU runs (each called by name, not only the one dispatch picks).
fn kernels() -> Vec<Isa> {
    [Isa::Scalar, Isa::Avx2, Isa::Avx512]
        .into_iter()
        .filter(|isa| isa.available())
        .collect()
}

fn same(a: f64, b: f64) -> bool {
    a.to_bits() == b.to_bits() || (a.is_nan() && b.is_nan())
}

/// `Lanes::up` is `round_up` bit for bit (zeros, subnormals, the largest finite numbers,
/// infinities, NaN, random bit patterns), four lanes and one, and eight in every path's
/// registers; `up_nonneg` on `+0` and positive finite numbers too.
#[test]
fn lane_round_up_is_round_up() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(11);
    let mut xs = vec![
        0.0,
        -0.0,
        f64::from_bits(1),
        -f64::from_bits(1),
        f64::MIN_POSITIVE,
        -f64::MIN_POSITIVE,
        f64::MAX,
        -f64::MAX,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NAN,
        1.0,
        -1.0,
    ];
    xs.extend((0..20_000).map(|_| f64::from_bits(rng.random::<u64>())));
    xs.extend((0..20_000).map(|_| rng.random_range(-1e3..1e3)));
    while xs.len() % 8 != 0 {
        xs.push(0.5);
    }
    for chunk in xs.chunks(4) {
        let four = Lanes::<4>::load(chunk, 0).up();
        for (q, &x) in chunk.iter().enumerate() {
            let one = Lanes::<1>::splat(x).up().0[0];
            assert!(same(four.0[q], round_up(x)), "{x:e}: {:e}", four.0[q]);
            assert!(same(one, round_up(x)), "{x:e}: {one:e}");
            if x.is_finite() && x.is_sign_positive() {
                let nonneg = Lanes::<1>::splat(x).up_nonneg().0[0];
                assert!(same(nonneg, round_up(x)), "{x:e}: {nonneg:e}");
            }
        }
    }
    // The same in the AVX2 and AVX-512 registers the relaxation runs them in.
    for isa in kernels() {
        let ups = lanes_up(isa, &xs);
        for (&x, &up) in xs.iter().zip(&ups) {
            assert!(same(up, round_up(x)), "{isa:?}, {x:e}: {up:e}");
        }
    }
}

/// `Lanes::up` over `xs` (a multiple of 8 long), eight lanes at a time in `isa`'s code.
fn lanes_up(isa: Isa, xs: &[f64]) -> Vec<f64> {
    #[inline(always)]
    fn body(xs: &[f64]) -> Vec<f64> {
        let mut out = vec![0.0; xs.len()];
        for at in (0..xs.len()).step_by(8) {
            Lanes::<8>::load(xs, at).up().store(&mut out, at);
        }
        out
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx2")]
    unsafe fn avx2(xs: &[f64]) -> Vec<f64> {
        body(xs)
    }
    #[cfg(target_arch = "x86_64")]
    #[target_feature(enable = "avx512f")]
    unsafe fn avx512(xs: &[f64]) -> Vec<f64> {
        body(xs)
    }
    assert!(isa.available());
    match isa {
        // SAFETY: the CPU has the features (asserted).
        #[cfg(target_arch = "x86_64")]
        Isa::Avx2 => unsafe { avx2(xs) },
        #[cfg(target_arch = "x86_64")]
        Isa::Avx512 => unsafe { avx512(xs) },
        _ => body(xs),
    }
}

/// Per box: centres, radii, magnitudes, scales, pending errors.
type PerBox<'a> = (&'a [f64], &'a [f64], &'a [f64], &'a [f64], &'a [f64]);

/// What the relaxation computed neuron by neuron and box by box before it ran in lanes
/// (the formulas of `forward`'s module documentation, scalar rounding functions).
#[allow(clippy::too_many_arguments)]
fn scalar(
    (n, g_count, d): (usize, usize, usize),
    c: &mut [f64],
    rv: &mut [f64],
    (xc, xr, xmag, scale, pending): PerBox<'_>,
    bias: Option<(&[f64], &[f64], usize)>,
    ibp_pre: Option<(&[f64], &[f64])>,
    post: &mut [f64],
    poisoned: &mut [bool],
) {
    let plane = n * g_count;
    for i in 0..n {
        for g in 0..g_count {
            let at = i * g_count + g;
            let (ci, ri) = (|p: usize| p * plane + at, |p: usize| p * plane + at);
            let mut widen = pending[g];
            if let Some((b, rs, n_prev)) = bias {
                c[ci(d)] += b[i];
                let err = err_bound(n_prev + 1, rv[ri(d + 1)] + b[i].abs(), scale[g]);
                let carried = round_up_keep_zero(rs[i] * pending[g]);
                rv[ri(d)] = add_up(add_up(rv[ri(d)], err), carried);
                widen = 0.0;
            }
            let (cd, rd) = (c[ci(d)], rv[ri(d)]);
            let (mut su, mut sl, mut mag) = (cd + rd, cd - rd, cd.abs() + rd.abs());
            for p in 0..d {
                let (cp, rp) = (c[ci(p)], rv[ri(p)]);
                let (up, lo) = (cp + rp, cp - rp);
                let (xc, xr) = (xc[g * d + p], xr[g * d + p]);
                su += up * xc + up.abs() * xr;
                sl += lo * xc - lo.abs() * xr;
                mag += (cp.abs() + rp.abs()) * xmag[g * d + p];
            }
            let err = add_up(err_bound(3 * d + 3, mag, scale[g]), widen);
            let (mut l, mut u) = (add_down(sl, -err), add_up(su, err));
            if !(l.is_finite() && u.is_finite()) {
                poisoned[g] = true;
            }
            if let Some((pc, pr)) = ibp_pre {
                l = l.max(add_down(pc[at], -pr[at]));
                u = u.min(add_up(pc[at], pr[at]));
            }
            let (ic, ir) = centre_radius(l.max(0.0), u.max(0.0));
            post[4 * at..4 * at + 4].copy_from_slice(&[l, u, ic, ir]);
            let v = if u <= 0.0 {
                (0..=d).for_each(|p| (c[ci(p)], rv[ri(p)]) = (0.0, 0.0));
                0.0
            } else if l >= 0.0 {
                mag
            } else {
                let (s_lo, s_up, t) = relu_lines(l, u, Relaxation::Adaptive);
                let (alpha, beta) = (0.5 * (s_up + s_lo), 0.5 * (s_up - s_lo));
                for p in 0..=d {
                    let (cp, rp) = (c[ci(p)], rv[ri(p)]);
                    c[ci(p)] = alpha * cp + beta * rp;
                    rv[ri(p)] = beta * cp + alpha * rp;
                }
                c[ci(d)] += 0.5 * t;
                rv[ri(d)] += 0.5 * t;
                let err = err_bound(8, s_up.max(s_lo) * mag + t, scale[g]);
                rv[ri(d)] = add_up(rv[ri(d)], err);
                let mut v = c[ci(d)].abs() + rv[ri(d)].abs();
                for p in 0..d {
                    v += (c[ci(p)].abs() + rv[ri(p)].abs()) * xmag[g * d + p];
                }
                v
            };
            rv[ri(d + 1)] = v;
        }
    }
}

/// The relaxation in lanes gives the scalar relaxation's forms, `V`, concrete bounds, IBP
/// interval and poisoned boxes bit for bit, and the rows that are not all zero, on every path
/// the CPU has (portable, AVX2, AVX-512), for numbers of boxes that fill the lanes or leave a
/// tail (1, 2, 3, 5, 6, 7, 12), form sizes that have their own copy and one that does not
/// (d = 1, 2, 3, 4, 6), with and without the bias stage and IBP; neurons dead, active and
/// unstable, some rows zero, a box overflowing.
#[test]
fn lanes_relax_as_the_scalar_code() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    for (g_count, d, with_bias) in [
        (1, 1, false),
        (3, 2, true),
        (6, 2, true),
        (7, 6, true),
        (6, 1, false),
        (12, 2, true),
        (5, 3, false),
        (2, 4, true),
    ] {
        let n = 41;
        let plane = n * g_count;
        let mut c: Vec<f64> = (0..(d + 1) * plane)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let mut rv: Vec<f64> = (0..(d + 2) * plane)
            .map(|_| rng.random_range(0.0..0.3))
            .collect();
        for i in 0..n {
            for g in 0..g_count {
                let at = i * g_count + g;
                // Constants spread so that neurons are dead, active or unstable.
                c[d * plane + at] = rng.random_range(-4.0..4.0);
                if i % 5 == 0 {
                    (0..=d).for_each(|p| (c[p * plane + at], rv[p * plane + at]) = (0.0, 0.0));
                }
            }
        }
        if g_count > 2 {
            c[d * plane + g_count + 2] = f64::MAX; // box 2 overflows
        }
        let xc: Vec<f64> = (0..g_count * d)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let xr: Vec<f64> = (0..g_count * d)
            .map(|_| rng.random_range(0.0..0.5))
            .collect();
        let xmag: Vec<f64> = xc
            .iter()
            .zip(&xr)
            .map(|(c, r)| round_up(c.abs() + r))
            .collect();
        let scale: Vec<f64> = (0..g_count).map(|_| rng.random_range(1.0..3.0)).collect();
        let pending: Vec<f64> = (0..g_count).map(|_| rng.random_range(0.0..1e-12)).collect();
        let b: Vec<f64> = (0..n).map(|_| rng.random_range(-0.5..0.5)).collect();
        let rs: Vec<f64> = (0..n).map(|_| rng.random_range(0.0..9.0)).collect();
        let bias = with_bias.then_some((&b[..], &rs[..], 77));
        let pc: Vec<f64> = (0..plane).map(|_| rng.random_range(-3.0..3.0)).collect();
        let pr: Vec<f64> = (0..plane).map(|_| rng.random_range(0.0..3.0)).collect();
        let ibp_pre = with_bias.then_some((&pc[..], &pr[..]));

        let (mut c0, mut rv0) = (c.clone(), rv.clone());
        let (mut post, mut poisoned0) = (vec![0.0; 4 * plane], vec![false; g_count]);
        let per_box = (&xc[..], &xr[..], &xmag[..], &scale[..], &pending[..]);
        let shape = (n, g_count, d);
        scalar(
            shape,
            &mut c0,
            &mut rv0,
            per_box,
            bias,
            ibp_pre,
            &mut post,
            &mut poisoned0,
        );

        for isa in kernels() {
            let (mut c, mut rv) = (c.clone(), rv.clone());
            let (mut lo, mut hi, mut ic, mut ir) = (
                vec![0.0; plane],
                vec![0.0; plane],
                vec![0.0; plane],
                vec![0.0; plane],
            );
            let mut poisoned = vec![false; g_count];
            let (mut blocks, mut live) = (Blocks::default(), LiveRows::default());
            let layer = Layer {
                n,
                g: g_count,
                d,
                c: &mut c,
                rv: &mut rv,
                xc: &xc,
                xr: &xr,
                xmag: &xmag,
                scale: &scale,
                pending: &pending,
                bias,
                ibp_pre,
                ibp_post: Some((&mut ic, &mut ir)),
                record: Some((&mut lo, &mut hi)),
            };
            relax_on(isa, layer, &mut poisoned, &mut blocks, &mut live);
            let tag = format!("{isa:?}, G = {g_count}, d = {d}, bias {with_bias}");
            assert_eq!(poisoned, poisoned0, "{tag}");
            let bad = |at: usize| g_count > 2 && at % g_count == 2;
            for at in (0..plane).filter(|&at| !bad(at)) {
                let want = &post[4 * at..4 * at + 4];
                for (q, (got, want)) in [lo[at], hi[at], ic[at], ir[at]]
                    .into_iter()
                    .zip(want)
                    .enumerate()
                {
                    assert!(
                        same(got, *want),
                        "{tag}, entry {at}, l/u/c/r {q}: {got:e} vs {want:e}"
                    );
                }
                for p in 0..=d {
                    assert!(
                        same(c[p * plane + at], c0[p * plane + at]),
                        "{tag}, Ĉ {p} at {at}"
                    );
                }
                for p in 0..d + 2 {
                    assert!(
                        same(rv[p * plane + at], rv0[p * plane + at]),
                        "{tag}, R̂/V {p} at {at}"
                    );
                }
            }
            let rows = |v: &[f64], planes: std::ops::Range<usize>| -> Vec<usize> {
                (0..n)
                    .filter(|i| {
                        planes
                            .clone()
                            .any(|p| (0..g_count).any(|g| v[p * plane + i * g_count + g] != 0.0))
                    })
                    .collect()
            };
            assert_eq!(live.c, rows(&c, 0..d + 1), "{tag}");
            assert_eq!(live.r, rows(&rv, 0..d + 1), "{tag}");
            assert_eq!(live.v, rows(&rv, d + 1..d + 2), "{tag}");
        }
        let counts = (0..plane).fold([0; 3], |mut k, at| {
            let (l, u) = (post[4 * at], post[4 * at + 1]);
            k[if u <= 0.0 {
                0
            } else if l >= 0.0 {
                1
            } else {
                2
            }] += 1;
            k
        });
        assert!(
            counts.iter().all(|&k| k > 0),
            "G = {g_count}, d = {d}: dead/active/unstable {counts:?}"
        );
    }
}

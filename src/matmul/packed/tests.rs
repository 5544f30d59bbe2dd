use super::*;

/// The kernels this CPU runs (each called by name, not only the one dispatch picks).
fn kernels() -> Vec<Isa> {
    [Isa::Scalar, Isa::Avx2, Isa::Avx512]
        .into_iter()
        .filter(|isa| isa.available())
        .collect()
}

/// A part of `n` columns a plane over `planes` planes, the strides the test gives.
#[allow(clippy::too_many_arguments)]
fn part<'a>(
    abs: bool,
    live: &'a [usize],
    b: &'a [f64],
    (b_stride, b_col, b_plane): (usize, usize, usize),
    (n, planes): (usize, usize),
    (out, out_col, out_plane): (usize, usize, usize),
) -> Part<'a> {
    Part {
        abs,
        live,
        b,
        b_stride,
        b_col,
        n,
        planes,
        b_plane,
        out,
        out_col,
        out_plane,
    }
}

/// Dyadic entries with small numerators: every product and sum is exact in f64, so the packed
/// products must equal a triple loop over the live rows exactly, for shapes with partial
/// panels, an odd number of panels, partial blocks and partial column slabs, slabs spanning
/// planes, strided operands, `A` and `|A|` parts sharing an output, and every kernel.
#[test]
fn packed_products_equal_a_triple_loop_over_the_live_rows() {
    for &(m, k, n) in &[
        (1, 1, 1),
        (3, 5, 2),
        (8, 7, 6),
        (17, 33, 13),
        (24, 40, 7),
        (64, 70, 48),
        (9, 300, 7),
    ] {
        let a: Vec<f64> = (0..m * k)
            .map(|i| ((i * 37 % 101) as f64 - 50.0) / 16.0)
            .collect();
        let b_stride = 2 * n + 3;
        let b: Vec<f64> = (0..k * b_stride)
            .map(|i| ((i * 53 % 97) as f64 - 48.0) / 8.0)
            .collect();
        let packed = PackedMatrix::new(m, k, &a);
        let lives: [Vec<usize>; 3] = [(0..k).collect(), (0..k).step_by(3).collect(), vec![]];
        for (l0, l1) in [(0, 1), (1, 0), (2, 0), (1, 2)] {
            let (live0, live1) = (&lives[l0], &lives[l1]);
            // Part 0: A on b's first n columns into out0; parts 1 and 2: |A| on b's next n
            // columns (live1) and on its first n (live0), side by side in out1; part 3: A on
            // two planes of b (columns 1 .. n + 1 and n + 1 .. 2n + 1, live1) into out0's
            // columns n + 2 .. 3n + 2.
            let (s0, s1) = (3 * n + 2, 2 * n + 1);
            let want = |abs: bool, live: &[usize], col: usize, i: usize, c: usize| -> f64 {
                live.iter()
                    .map(|&j| {
                        let w = a[i * k + j];
                        (if abs { w.abs() } else { w }) * b[j * b_stride + col + c]
                    })
                    .sum()
            };
            let parts = [
                part(false, live0, &b, (b_stride, 0, 0), (n, 1), (0, 0, 0)),
                part(true, live1, &b, (b_stride, n, 0), (n, 1), (1, 0, 0)),
                part(true, live0, &b, (b_stride, 0, 0), (n, 1), (1, n, 0)),
                part(false, live1, &b, (b_stride, 1, n), (n, 2), (0, n + 2, n)),
            ];
            for isa in kernels() {
                let (mut o0, mut o1) = (vec![-1.0; m * s0], vec![-1.0; m * s1]);
                let mut outs = [(&mut o0[..], s0), (&mut o1[..], s1)];
                packed.products_on(isa, &parts, &mut outs, &mut vec![]);
                for i in 0..m {
                    for c in 0..n {
                        let tag = format!("{m}×{k}×{n}, lives {l0} {l1}, {isa:?}, ({i}, {c})");
                        assert_eq!(o0[i * s0 + c], want(false, live0, 0, i, c), "{tag}");
                        assert_eq!(o1[i * s1 + c], want(true, live1, n, i, c), "{tag}");
                        assert_eq!(o1[i * s1 + n + c], want(true, live0, 0, i, c), "{tag}");
                        for q in 0..2 {
                            let got = o0[i * s0 + n + 2 + q * n + c];
                            assert_eq!(got, want(false, live1, 1 + q * n, i, c), "{tag}");
                        }
                    }
                    // Columns past the parts stay untouched.
                    assert!(o0[i * s0 + n..i * s0 + n + 2].iter().all(|&x| x == -1.0));
                    assert!(o1[i * s1 + 2 * n..(i + 1) * s1].iter().all(|&x| x == -1.0));
                }
            }
        }
    }
}

/// Slabs cover a part's (plane, column) pairs in order, none wider than asked, as even as
/// their number allows.
#[test]
fn slabs_tile_the_pairs_evenly() {
    for total in 0..60 {
        for nr in [6, 12] {
            let s: Vec<_> = slabs(total, nr).collect();
            assert_eq!(s.len(), total.div_ceil(nr));
            let mut next = 0;
            for &(v0, w) in &s {
                assert_eq!(v0, next);
                assert!(w >= 1 && w <= nr && w + 1 >= total / s.len());
                next += w;
            }
            assert_eq!(next, total);
        }
    }
}

/// Full-precision entries (53-bit numerators over `2³⁰`, of spread magnitudes), so that the
/// kernels round: every kernel's `A·B` lies within `err_bound(N, m̂, 1)` of the exact sum (in
/// 128-bit integers: every product is an integer over `2⁶⁰`), `m̂` its own `|A|·|B|`, as the
/// forward method bounds it; the AVX2 and AVX-512 kernels agree bit for bit (the same sum of
/// fused multiply–adds in the same order), and every kernel lies within its bound of the
/// portable one.
#[test]
fn kernels_round_within_the_a_priori_bound_of_the_exact_product() {
    use crate::rounding::err_bound;
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(40);
    let mut draw = |n: usize| -> Vec<i64> {
        (0..n)
            .map(|_| rng.random_range(-(1i64 << 53) + 1..1i64 << 53) >> rng.random_range(0..24))
            .collect()
    };
    let unit = (2.0f64).powi(-30);
    for &(m, k, n, planes) in &[(24, 300, 6, 3), (17, 130, 7, 2), (40, 400, 12, 1)] {
        let (ai, bi) = (draw(m * k), draw(k * n * planes));
        let a: Vec<f64> = ai.iter().map(|&x| x as f64 * unit).collect();
        let b: Vec<f64> = bi.iter().map(|&x| x as f64 * unit).collect();
        let b_abs: Vec<f64> = b.iter().map(|x| x.abs()).collect();
        let packed = PackedMatrix::new(m, k, &a);
        let live: Vec<usize> = (0..k).filter(|j| j % 5 != 3).collect();
        // Plane q of b is rows × n at q·k·n; the products side by side, plane after plane.
        let stride = n * planes;
        let parts = [
            part(false, &live, &b, (n, 0, k * n), (n, planes), (0, 0, n)),
            part(true, &live, &b_abs, (n, 0, k * n), (n, planes), (1, 0, n)),
        ];
        let run = |isa: Isa| {
            let (mut s, mut mag) = (vec![f64::NAN; m * stride], vec![f64::NAN; m * stride]);
            let mut outs = [(&mut s[..], stride), (&mut mag[..], stride)];
            packed.products_on(isa, &parts, &mut outs, &mut vec![]);
            (s, mag)
        };
        let portable = run(Isa::Scalar);
        let fused = Isa::Avx2.available().then(|| run(Isa::Avx2));
        for isa in kernels() {
            let (s, mag) = run(isa);
            if let (Isa::Avx512, Some(f)) = (isa, &fused) {
                let same = s.iter().zip(&f.0).all(|(x, y)| x.to_bits() == y.to_bits());
                assert!(same, "{m}×{k}: AVX-512 and AVX2 sums differ");
            }
            let mut rounded = 0;
            for i in 0..m {
                for q in 0..planes {
                    for c in 0..n {
                        let exact: i128 = live
                            .iter()
                            .map(|&j| ai[i * k + j] as i128 * bi[q * k * n + j * n + c] as i128)
                            .sum();
                        let at = i * stride + q * n + c;
                        let bound = err_bound(live.len(), mag[at], 1.0);
                        // Both are integers in units of 2⁻⁶⁰ (exact scalings by 2⁶⁰).
                        let got = (s[at] * 2f64.powi(60)) as i128;
                        let slack = (bound * 2f64.powi(60)).floor() as i128;
                        let tag = format!("{m}×{k}×{n}, {isa:?}, ({i}, {q}, {c})");
                        assert!((got - exact).abs() <= slack, "{tag}: past the bound");
                        rounded += usize::from(got != exact);
                        let apart = (s[at] - portable.0[at]).abs();
                        assert!(apart <= 2.0 * bound, "{tag}: {apart:e} from portable");
                    }
                }
            }
            // The data make the kernels round (else the bound is not put to the test).
            assert!(
                2 * rounded > m * n * planes,
                "{m}×{k}, {isa:?}: {rounded} sums rounded"
            );
        }
    }
}

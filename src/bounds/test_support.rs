//! Shared test fixtures for the bounds modules: seeded random networks and boxes, sample points,
//! and a containment check that evaluates the network and the affine forms in double-double
//! arithmetic (≈ 106 bits), so that a sound bound is never failed by the check's own rounding.
#![allow(clippy::needless_range_loop)] // index loops read as the formulas

use super::{
    network_bounds, network_bounds_batch, AffineBounds, BoundMethod, BoundsError, Relaxation,
};
use crate::network::Mlp;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// Network shapes every soundness test runs on.
pub(crate) const SHAPES: &[&[usize]] = &[
    &[2, 16, 16, 2],
    &[2, 64, 64, 1],
    &[3, 32, 32, 32, 2],
    &[1, 8, 1],
    &[4, 24, 3],
    // Past the input dimensions that forward's ReLU loop is compiled for: its run-time path.
    &[5, 12, 12, 2],
];

/// Kinds of random boxes.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(crate) enum BoxKind {
    /// Widths between 0.5 and 3.
    Wide,
    /// Widths between 0.01 and 0.3.
    Medium,
    /// Widths below 1e-6.
    Tiny,
    /// `lower == upper`.
    Degenerate,
    /// Each coordinate wide, tiny or degenerate.
    Mixed,
}

impl BoxKind {
    pub(crate) const ALL: [BoxKind; 5] = [
        BoxKind::Wide,
        BoxKind::Medium,
        BoxKind::Tiny,
        BoxKind::Degenerate,
        BoxKind::Mixed,
    ];
}

/// A seeded RNG.
pub(crate) fn case_rng(seed: u64) -> ChaCha8Rng {
    ChaCha8Rng::seed_from_u64(seed)
}

/// A random box of the given kind in dimension `n`, centred in `[−2, 2]ⁿ`.
pub(crate) fn random_box(rng: &mut ChaCha8Rng, n: usize, kind: BoxKind) -> (Vec<f64>, Vec<f64>) {
    let mut lo = Vec::with_capacity(n);
    let mut hi = Vec::with_capacity(n);
    for _ in 0..n {
        let c: f64 = rng.random_range(-2.0..2.0);
        let kind = if kind == BoxKind::Mixed {
            [BoxKind::Wide, BoxKind::Tiny, BoxKind::Degenerate][rng.random_range(0..3)]
        } else {
            kind
        };
        let w = match kind {
            BoxKind::Wide => rng.random_range(0.5..3.0),
            BoxKind::Medium => rng.random_range(0.01..0.3),
            BoxKind::Tiny => rng.random_range(0.0..1e-6),
            _ => 0.0,
        };
        lo.push(c - 0.5 * w);
        hi.push(c + 0.5 * w);
    }
    (lo, hi)
}

/// Corners (at most 16) and `n_random` uniform points of the box, plus its centre.
pub(crate) fn sample_points(
    rng: &mut ChaCha8Rng,
    lo: &[f64],
    hi: &[f64],
    n_random: usize,
) -> Vec<Vec<f64>> {
    let n = lo.len();
    let mut pts = Vec::new();
    if n <= 4 {
        for mask in 0..(1usize << n) {
            pts.push(
                (0..n)
                    .map(|p| if mask >> p & 1 == 1 { hi[p] } else { lo[p] })
                    .collect(),
            );
        }
    }
    pts.push(
        (0..n)
            .map(|p| (0.5 * (lo[p] + hi[p])).clamp(lo[p], hi[p]))
            .collect(),
    );
    for _ in 0..n_random {
        pts.push(
            (0..n)
                .map(|p| (lo[p] + rng.random::<f64>() * (hi[p] - lo[p])).clamp(lo[p], hi[p]))
                .collect(),
        );
    }
    pts
}

/// One soundness case: a network, a box and points inside it.
pub(crate) struct Case {
    pub(crate) name: String,
    pub(crate) net: Mlp,
    pub(crate) lo: Vec<f64>,
    pub(crate) hi: Vec<f64>,
    pub(crate) points: Vec<Vec<f64>>,
}

/// Runs `f` on `boxes_per_net` boxes (cycling through [`BoxKind::ALL`]) for every shape in
/// [`SHAPES`] and two network seeds each.
pub(crate) fn for_each_case(boxes_per_net: usize, mut f: impl FnMut(&Case)) {
    for (s, shape) in SHAPES.iter().enumerate() {
        for seed in 0..2u64 {
            let net = Mlp::random(shape, 1000 * s as u64 + seed);
            let mut rng = case_rng(77 + 31 * s as u64 + seed);
            for b in 0..boxes_per_net {
                let kind = BoxKind::ALL[b % BoxKind::ALL.len()];
                let (lo, hi) = random_box(&mut rng, shape[0], kind);
                let points = sample_points(&mut rng, &lo, &hi, 24);
                let case = Case {
                    name: format!("net {shape:?} seed {seed}, box {b} ({kind:?}) [{lo:?}, {hi:?}]"),
                    net: net.clone(),
                    lo,
                    hi,
                    points,
                };
                f(&case);
            }
        }
    }
}

/// Checks `method` (a bound function with a relaxation) on `boxes_per_net` cases per network for
/// both relaxations; same-slope must give one `C`.
pub(crate) fn assert_sound_for_both_relaxations(
    boxes_per_net: usize,
    method: impl Fn(&Mlp, &[f64], &[f64], Relaxation) -> Result<AffineBounds, BoundsError>,
) {
    for relaxation in [Relaxation::Adaptive, Relaxation::SameSlope] {
        for_each_case(boxes_per_net, |case| {
            let b = method(&case.net, &case.lo, &case.hi, relaxation).unwrap();
            check_bounds(&case.net, &case.lo, &case.hi, &b, &case.points)
                .unwrap_or_else(|e| panic!("{relaxation:?} {}: {e}", case.name));
            if relaxation == Relaxation::SameSlope {
                assert_eq!(b.a_lower, b.a_upper, "same-slope must share C");
            }
        });
    }
}

/// Bounds 300 boxes of a `[3, 32, 32, 2]` network as one batch and compares the boxes at group
/// boundaries with one-box calls: grouping may change the summation order only (relative `tol`).
pub(crate) fn assert_batch_matches_single(methods: &[BoundMethod], tol: f64) {
    let net = Mlp::random(&[3, 32, 32, 2], 11);
    let mut rng = case_rng(5);
    let (mut lo, mut hi) = (Vec::new(), Vec::new());
    for k in 0..300 {
        let (l, h) = random_box(&mut rng, 3, BoxKind::ALL[k % BoxKind::ALL.len()]);
        lo.extend(l);
        hi.extend(h);
    }
    let close = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .all(|(x, y)| (x - y).abs() <= tol * (1.0 + x.abs()))
    };
    for &method in methods {
        let batch = network_bounds_batch(&net, &lo, &hi, method).unwrap();
        assert_eq!(batch.len(), 300);
        for k in [0, 1, 127, 128, 299] {
            let (l, h) = (&lo[3 * k..3 * k + 3], &hi[3 * k..3 * k + 3]);
            let one = network_bounds(&net, l, h, method).unwrap();
            let b = batch.get(k).unwrap();
            assert!(
                close(&one.lower, &b.lower) && close(&one.upper, &b.upper),
                "{method:?} box {k}"
            );
            assert!(
                close(&one.a_lower, &b.a_lower) && close(&one.b_upper, &b.b_upper),
                "{method:?} box {k}"
            );
        }
    }
}

/// A double-double number `hi + lo`.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Dd(pub(crate) f64, pub(crate) f64);

fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    (s, (a - (s - bb)) + (b - bb))
}

fn quick_two_sum(a: f64, b: f64) -> Dd {
    let s = a + b;
    Dd(s, b - (s - a))
}

impl Dd {
    pub(crate) fn from(a: f64) -> Dd {
        Dd(a, 0.0)
    }
    pub(crate) fn add(self, o: Dd) -> Dd {
        let (s, e) = two_sum(self.0, o.0);
        let (t, f) = two_sum(self.1, o.1);
        let d = quick_two_sum(s, e + t);
        quick_two_sum(d.0, d.1 + f)
    }
    pub(crate) fn mul_f64(self, b: f64) -> Dd {
        let p = self.0 * b;
        let e = self.0.mul_add(b, -p);
        quick_two_sum(p, e + self.1 * b)
    }
    pub(crate) fn neg(self) -> Dd {
        Dd(-self.0, -self.1)
    }
    /// The sign of the value: `> 0`, `0`, `< 0` as `1`, `0`, `-1`.
    pub(crate) fn sign(self) -> i32 {
        let v = if self.0 != 0.0 { self.0 } else { self.1 };
        if v > 0.0 {
            1
        } else if v < 0.0 {
            -1
        } else {
            0
        }
    }
    pub(crate) fn relu(self) -> Dd {
        if self.sign() > 0 {
            self
        } else {
            Dd(0.0, 0.0)
        }
    }
    /// Whether `self ≤ o` (up to ~2⁻¹⁰⁵ relative).
    pub(crate) fn le(self, o: Dd) -> bool {
        o.add(self.neg()).sign() >= 0
    }
}

/// `N(x)` in double-double arithmetic.
pub(crate) fn dd_forward(net: &Mlp, x: &[f64]) -> Vec<Dd> {
    let mut a: Vec<Dd> = x.iter().map(|&v| Dd::from(v)).collect();
    for (k, layer) in net.layers.iter().enumerate() {
        let mut z: Vec<Dd> = (0..layer.n_out)
            .map(|i| {
                let row = &layer.weight[i * layer.n_in..(i + 1) * layer.n_in];
                row.iter()
                    .zip(&a)
                    .fold(Dd::from(layer.bias[i]), |s, (&w, &ai)| s.add(ai.mul_f64(w)))
            })
            .collect();
        if k + 1 < net.layers.len() {
            z.iter_mut().for_each(|v| *v = v.relu());
        }
        a = z;
    }
    a
}

/// `a·x + b` in double-double arithmetic.
pub(crate) fn dd_affine(a: &[f64], b: f64, x: &[f64]) -> Dd {
    a.iter()
        .zip(x)
        .fold(Dd::from(b), |s, (&ai, &xi)| s.add(Dd::from(xi).mul_f64(ai)))
}

/// Why [`check_bounds`] failed.
#[derive(Debug, thiserror::Error)]
pub(crate) enum CheckError {
    /// The bounds' dimensions differ from the network's.
    #[error("bounds have the wrong shape")]
    WrongShape,
    /// A sample point lies outside the box.
    #[error("sample {x:?} outside the box")]
    SampleOutside { x: Vec<f64> },
    /// A bound fails at a sample point.
    #[error(
        "{what} bound violated at x = {x:?}, output {output}: N(x) = {value:e}, bounds \
         [{lower:e}, {upper:e}], forms [{form_lower:e}, {form_upper:e}]"
    )]
    Violated {
        what: &'static str,
        x: Vec<f64>,
        output: usize,
        value: f64,
        lower: f64,
        upper: f64,
        form_lower: f64,
        form_upper: f64,
    },
}

/// Checks `lower ≤ N(x) ≤ upper` and both affine forms at every point (all in double-double).
pub(crate) fn check_bounds(
    net: &Mlp,
    lo: &[f64],
    hi: &[f64],
    b: &AffineBounds,
    points: &[Vec<f64>],
) -> Result<(), CheckError> {
    let (n, m) = (net.input_dim(), net.output_dim());
    if b.n_in != n || b.n_out != m || b.a_lower.len() != n * m || b.lower.len() != m {
        return Err(CheckError::WrongShape);
    }
    for x in points {
        if x.iter()
            .zip(lo.iter().zip(hi))
            .any(|(v, (l, h))| v < l || v > h)
        {
            return Err(CheckError::SampleOutside { x: x.clone() });
        }
        let y = dd_forward(net, x);
        for o in 0..m {
            let yo = y[o];
            let fl = dd_affine(b.a_lower_row(o), b.b_lower[o], x);
            let fu = dd_affine(b.a_upper_row(o), b.b_upper[o], x);
            let checks = [
                (Dd::from(b.lower[o]).le(yo), "lower"),
                (yo.le(Dd::from(b.upper[o])), "upper"),
                (fl.le(yo), "affine lower"),
                (yo.le(fu), "affine upper"),
            ];
            for (ok, what) in checks {
                if !ok {
                    return Err(CheckError::Violated {
                        what,
                        x: x.clone(),
                        output: o,
                        value: yo.0,
                        lower: b.lower[o],
                        upper: b.upper[o],
                        form_lower: fl.0,
                        form_upper: fu.0,
                    });
                }
            }
        }
    }
    Ok(())
}

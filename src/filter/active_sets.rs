//! Enclosures of `v` over a box for any QP filter, from its active-set pieces
//! (docs/design.md §2.2). It may import the filter's rows and enclosures' helpers, the
//! scenario, expressions, intervals and boxes.
//!
//! With rows `aₖ(x)·θ ≤ bₖ(x)`, the minimiser of `½‖θ‖²` at a feasible `x` satisfies the KKT
//! conditions with multipliers `μ ≥ 0` on the active rows; among the multiplier vectors there is
//! one whose support `𝒜` has linearly independent rows and `μ_𝒜 > 0` (conic Carathéodory).
//! On that `𝒜`, `θ = A_𝒜ᵀ G⁻¹ b_𝒜` with `G = A_𝒜A_𝒜ᵀ`, `μ = −G⁻¹b_𝒜`, and every other row holds.
//! By Cramer's rule, with `D = det G > 0`, `w = adj(G) b_𝒜` and `P = A_𝒜ᵀ w`:
//!
//! ```text
//! θ = P / D,    μ = −w / D > 0  ⇔  w < 0,    aⱼ·θ ≤ bⱼ  ⇔  aⱼ·P − bⱼ D ≤ 0.
//! ```
//!
//! Over a box the piece `𝒜` is discarded when some `wₖ ≥ 0` on the whole box, when some other
//! row's numerator is `> 0` on the whole box, or when `D ≤ 0` throughout (the rows are
//! dependent everywhere: another `𝒜` serves); `∅` (`θ = 0`) is discarded when some `bₖ < 0`
//! throughout. None of these tests divides by `D`, so a set whose `G` is singular somewhere in
//! the box is kept, and its enclosure `P/D` is then unbounded — wide, never tight and wrong.
//! `v` lies in the union of the kept pieces' enclosures, each the meet of the natural `P/D`, the
//! multiplier form `−A_𝒜ᵀ μ` with `μ ≥ 0`, and the mean-value form of `P/D`; every row then
//! contracts the union (`θ` is feasible).

use std::ops::{Add, Mul, Neg, Sub};

use super::enclosures::{meet, Centred, Smooth};
use super::rows::{interval_rows, row_expressions};
use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::intervals::Interval;
use crate::scenario::Scenario;

/// Largest active set enumerated (`|𝒜| ≤ min(m, this)`): Laplace expansion grows with the
/// factorial. A filter whose solutions may need more active rows gets unbounded enclosures.
pub const MAX_ACTIVE: usize = 4;

/// Most active sets a filter may have before its enclosures are given up as unbounded.
pub const MAX_SETS: usize = 128;

/// What the piece algebra needs of a number type: intervals (natural enclosures over a box)
/// and expressions (symbolic pieces, differentiated for mean-value forms).
pub(crate) trait Ring:
    Clone + Add<Output = Self> + Sub<Output = Self> + Mul<Output = Self> + Neg<Output = Self>
{
    fn constant(c: f64) -> Self;

    /// `x²` (for intervals `≥ 0`, tighter than `x·x`).
    fn sq(&self) -> Self {
        self.clone() * self.clone()
    }
}

impl Ring for Interval {
    fn constant(c: f64) -> Self {
        Interval::point(c)
    }

    fn sq(&self) -> Self {
        self.sqr()
    }
}

impl Ring for Expr {
    fn constant(c: f64) -> Self {
        Expr::constant(c)
    }
}

fn dot<T: Ring>(a: &[T], b: &[T]) -> T {
    a.iter()
        .zip(b)
        .fold(T::constant(0.0), |acc, (x, y)| acc + x.clone() * y.clone())
}

/// `‖a‖²` as a sum of squares (`≥ 0` in interval arithmetic too).
fn norm2<T: Ring>(a: &[T]) -> T {
    a.iter().fold(T::constant(0.0), |acc, x| acc + x.sq())
}

fn minor<T: Ring>(g: &[Vec<T>], r: usize, c: usize) -> Vec<Vec<T>> {
    g.iter()
        .enumerate()
        .filter(|(i, _)| *i != r)
        .map(|(_, row)| {
            row.iter()
                .enumerate()
                .filter(|(j, _)| *j != c)
                .map(|(_, v)| v.clone())
                .collect()
        })
        .collect()
}

/// `det g` by Laplace expansion along the first row (`g` square, at most [`MAX_ACTIVE`]).
fn det<T: Ring>(g: &[Vec<T>]) -> T {
    match g.len() {
        0 => T::constant(1.0),
        1 => g[0][0].clone(),
        2 => g[0][0].clone() * g[1][1].clone() - g[0][1].clone() * g[1][0].clone(),
        p => (0..p).fold(T::constant(0.0), |acc, c| {
            let term = g[0][c].clone() * det(&minor(g, 0, c));
            if c % 2 == 0 {
                acc + term
            } else {
                acc - term
            }
        }),
    }
}

/// `adj(g) y`: the vector `w` with `g w = det(g) y`.
fn adj_times<T: Ring>(g: &[Vec<T>], y: &[T]) -> Vec<T> {
    let p = g.len();
    (0..p)
        .map(|i| {
            (0..p).fold(T::constant(0.0), |acc, j| {
                // adj(g)[i][j] = (−1)^{i+j} det(minor(g, j, i))
                let c = if p == 1 {
                    T::constant(1.0)
                } else {
                    det(&minor(g, j, i))
                };
                let term = c * y[j].clone();
                if (i + j) % 2 == 0 {
                    acc + term
                } else {
                    acc - term
                }
            })
        })
        .collect()
}

/// The quantities of one active set `𝒜` (nonempty), in any [`Ring`].
#[derive(Clone, Debug)]
pub(crate) struct PieceAlgebra<T> {
    /// `D = det(A_𝒜A_𝒜ᵀ) ≥ 0`.
    pub d: T,
    /// `w = adj(G) b_𝒜`, one per active row: `μ = −w/D`.
    pub w: Vec<T>,
    /// `P = A_𝒜ᵀ w`, one per input: `θ = P/D`.
    pub p: Vec<T>,
    /// Per row `j ∉ 𝒜`: `aⱼ·P − bⱼD` (`≤ 0` where the row holds at `θ`).
    pub primal: Vec<(usize, T)>,
}

/// [`PieceAlgebra`] of `set` for rows `a` (one `Vec` of m per row) and `b`.
pub(crate) fn piece_algebra<T: Ring>(a: &[Vec<T>], b: &[T], set: &[usize]) -> PieceAlgebra<T> {
    let m = a.first().map_or(0, Vec::len);
    let g: Vec<Vec<T>> = set
        .iter()
        .map(|&k| {
            set.iter()
                .map(|&l| {
                    if k == l {
                        norm2(&a[k])
                    } else {
                        dot(&a[k], &a[l])
                    }
                })
                .collect()
        })
        .collect();
    // A Gram matrix is symmetric: with two rows `g₀₁g₁₀ = g₀₁²` (tighter in intervals).
    let d = if g.len() == 2 {
        g[0][0].clone() * g[1][1].clone() - g[0][1].sq()
    } else {
        det(&g)
    };
    let b_set: Vec<T> = set.iter().map(|&k| b[k].clone()).collect();
    let w = adj_times(&g, &b_set);
    let p: Vec<T> = (0..m)
        .map(|j| {
            set.iter().zip(&w).fold(T::constant(0.0), |acc, (&k, wk)| {
                acc + a[k][j].clone() * wk.clone()
            })
        })
        .collect();
    let primal = (0..a.len())
        .filter(|j| !set.contains(j))
        .map(|j| (j, dot(&a[j], &p) - b[j].clone() * d.clone()))
        .collect();
    PieceAlgebra { d, w, p, primal }
}

/// Every nonempty subset of `0..rows` of at most `max` elements with no two rows whose
/// `normals` are constant (`Some`) and parallel (dependent at every point, as an input's lower
/// and upper bound; [`constant_parallel`]), smaller sets first; `None` when there are more than
/// [`MAX_SETS`]. Sets with a parallel pair are never needed: some multiplier vector of the KKT conditions has a
/// support of linearly independent rows (Carathéodory, docs/design.md §2.1a).
pub(crate) fn active_sets(
    rows: usize,
    max: usize,
    normals: &[Option<Vec<f64>>],
) -> Option<Vec<Vec<usize>>> {
    let parallel = |i: usize, j: usize| {
        normals
            .get(i)
            .zip(normals.get(j))
            .is_some_and(|(a, b)| constant_parallel(a, b))
    };
    let mut out: Vec<Vec<usize>> = Vec::new();
    let mut layer: Vec<Vec<usize>> = vec![Vec::new()];
    for _ in 0..max.min(rows) {
        let mut next = Vec::new();
        for set in &layer {
            let from = set.last().map_or(0, |&l| l + 1);
            for k in from..rows {
                if set.iter().any(|&j| parallel(j, k)) || inert(normals.get(k)) {
                    continue;
                }
                let mut s = set.clone();
                s.push(k);
                next.push(s);
            }
        }
        out.extend(next.iter().cloned());
        if out.len() > MAX_SETS {
            return None;
        }
        layer = next;
    }
    Some(out)
}

/// Whether a row's normal is the constant 0 (`0·θ ≤ bₖ`): where the QP is feasible `bₖ ≥ 0`,
/// so the row never binds, and `v` is the solution of the other rows. Such a row is in no
/// active set, and the enclosures of `v` take its `bₖ` as nonnegative ([`slack_inert`]): `v`
/// exists only where it is (the feasibility proofs, which keep the row, see the rest).
fn inert(normal: Option<&Option<Vec<f64>>>) -> bool {
    normal.is_some_and(|a| a.as_ref().is_some_and(|a| a.iter().all(|&x| x == 0.0)))
}

/// Raises to 0 the `bₖ` of every row whose normal (`a`, row-major rows × `m`) encloses to the
/// point 0 ([`inert`]): for enclosures of `v`, which exists only where such a `bₖ ≥ 0`.
pub(crate) fn slack_inert(a: &[Interval], m: usize, b: &mut [Interval]) {
    for (ak, bk) in a.chunks(m.max(1)).zip(b.iter_mut()) {
        if ak.iter().all(|e| e.lower == 0.0 && e.upper == 0.0) {
            *bk = Interval::new(bk.lower.max(0.0), bk.upper.max(0.0));
        }
    }
}

/// Whether two rows' normals are both constant (`Some`) and parallel, either way: the two
/// rows are then dependent at every point (an input's lower and upper bound: `−eⱼ`, `eⱼ`).
/// Exact: every 2 × 2 minor `aₖbₗ − aₗbₖ` vanishes, the products compared as error-free pairs
/// (`p + e`, `e` by a fused multiply-add), with every entry 0 or of moderate size so that
/// nothing underflows; anything else counts as not parallel (a set kept is never unsound).
fn constant_parallel(a: &Option<Vec<f64>>, b: &Option<Vec<f64>>) -> bool {
    let (Some(a), Some(b)) = (a, b) else {
        return false;
    };
    let moderate = |v: &[f64]| {
        v.iter()
            .all(|&x| x == 0.0 || (1e-100..1e100).contains(&x.abs()))
    };
    let product = |x: f64, y: f64| {
        let p = x * y;
        (p, x.mul_add(y, -p))
    };
    a.len() == b.len()
        && moderate(a)
        && moderate(b)
        && a.iter().any(|&x| x != 0.0)
        && b.iter().any(|&x| x != 0.0)
        && (0..a.len())
            .all(|k| (k + 1..a.len()).all(|l| product(a[k], b[l]) == product(a[l], b[k])))
}

/// Whether the piece's discarding conditions prove it is not `v`'s piece anywhere on the box.
fn discarded(alg: &PieceAlgebra<Interval>) -> bool {
    alg.d.upper <= 0.0
        || alg.w.iter().any(|w| w.lower >= 0.0)
        || alg.primal.iter().any(|(_, r)| r.lower > 0.0)
}

/// The piece's enclosure of `θ` from the interval algebra: `P/D` met with `−A_𝒜ᵀ μ`, `μ ≥ 0`.
fn piece_enclosure(
    alg: &PieceAlgebra<Interval>,
    a: &[Vec<Interval>],
    b: &[Interval],
    set: &[usize],
) -> Vec<Interval> {
    let nonneg = Interval::new(0.0, f64::INFINITY);
    let mu: Vec<Interval> = alg.w.iter().map(|&w| meet(nonneg, -(w / alg.d))).collect();
    alg.p
        .iter()
        .enumerate()
        .map(|(j, &p)| {
            let by_mu = set
                .iter()
                .zip(&mu)
                .fold(Interval::point(0.0), |acc, (&k, &mk)| acc - a[k][j] * mk);
            let direct = match set {
                // One active row: `bₖ/aₖ` (scalar input) or `bₖ·aₖⱼ/‖aₖ‖²`, as the closed forms.
                [k] if a[*k].len() == 1 => b[*k] / a[*k][0],
                [k] => b[*k] * (a[*k][j] / alg.d),
                _ => p / alg.d,
            };
            meet(meet(p / alg.d, direct), by_mu)
        })
        .collect()
}

/// Contracts `theta` with every row `aₖ·θ ≤ bₖ` (the solution is feasible): for an input `i`
/// whose coefficient has one sign on the box, `θᵢ` lies on one side of the rest's slack over it.
fn contract(theta: &mut [Interval], a: &[Vec<Interval>], b: &[Interval]) {
    for _ in 0..2 {
        for (ak, &bk) in a.iter().zip(b) {
            for i in 0..theta.len() {
                let aki = ak[i];
                if !(aki.lower > 0.0 || aki.upper < 0.0) {
                    continue;
                }
                let rest = (0..theta.len())
                    .filter(|&l| l != i)
                    .fold(bk, |acc, l| acc - ak[l] * theta[l]);
                if rest.is_nan() {
                    continue;
                }
                let q = rest / aki;
                let bound = if aki.lower > 0.0 {
                    Interval::new(f64::NEG_INFINITY, q.upper)
                } else {
                    Interval::new(q.lower, f64::INFINITY)
                };
                theta[i] = meet(theta[i], bound);
            }
        }
    }
}

/// The union of the possible pieces' enclosures, by interval evaluation only: the enclosure of
/// `v` over `box ∩ S` for any QP with natural rows `a` (rows × m, row-major) and `b`.
/// Unbounded where no piece survives (the QP is then infeasible on the box, or the rows are NaN).
pub fn natural_qp_enclosure(a: &[Interval], b: &[Interval], m: usize) -> Vec<Interval> {
    let rows = b.len();
    let entire = vec![Interval::ENTIRE; m];
    if a.len() != rows * m || a.iter().chain(b).any(|v| v.is_nan()) {
        return entire;
    }
    let mut b = b.to_vec();
    slack_inert(a, m, &mut b);
    let b = &b;
    // `θ = 0` feasible throughout: it is the least-norm point ([`QpForms::enclose`]).
    if b.iter().all(|bk| bk.lower >= 0.0) {
        return vec![Interval::point(0.0); m];
    }
    let a: Vec<Vec<Interval>> = a.chunks(m.max(1)).map(<[Interval]>::to_vec).collect();
    // A row's normal is constant over the box where its enclosure is a point.
    let normals: Vec<Option<Vec<f64>>> = a
        .iter()
        .map(|row| {
            row.iter()
                .map(|e| (e.lower == e.upper).then_some(e.lower))
                .collect()
        })
        .collect();
    let Some(sets) = active_sets(rows, m.min(MAX_ACTIVE), &normals) else {
        return entire;
    };
    if m > MAX_ACTIVE && rows > MAX_ACTIVE {
        return entire;
    }
    let mut union: Option<Vec<Interval>> =
        inactive_possible(&a, b).then(|| vec![Interval::point(0.0); m]);
    for set in &sets {
        let alg = piece_algebra(&a, b, set);
        if discarded(&alg) {
            continue;
        }
        let mut enc = piece_enclosure(&alg, &a, b, set);
        contract(&mut enc, &a, b);
        union = Some(hull(union, enc));
    }
    let mut v = union.unwrap_or(entire);
    contract(&mut v, &a, b);
    v
}

/// Whether `θ = 0` may be `v`'s piece somewhere on the box: unless some `bₖ < 0` throughout.
/// A row with `bₖ ≤ 0` throughout, `bₖ < 0` somewhere and `aₖ ≠ 0` also rules it out: where
/// `bₖ = 0` the piece `{k}` gives the same `θ = 0`, and that piece survives every test.
fn inactive_possible(a: &[Vec<Interval>], b: &[Interval]) -> bool {
    !b.iter().zip(a).any(|(bk, ak)| {
        bk.upper < 0.0 || (bk.upper <= 0.0 && bk.lower < 0.0 && norm2(ak).lower > 0.0)
    })
}

fn hull(acc: Option<Vec<Interval>>, enc: Vec<Interval>) -> Vec<Interval> {
    match acc {
        None => enc,
        Some(u) => u.iter().zip(&enc).map(|(x, y)| x.hull(y)).collect(),
    }
}

/// One active set's symbolic forms, with gradients for mean-value enclosures.
#[derive(Clone, Debug)]
struct PieceForms {
    set: Vec<usize>,
    d: Smooth,
    w: Vec<Smooth>,
    /// `θⱼ = Pⱼ/D`.
    theta: Vec<Smooth>,
    primal: Vec<(usize, Smooth)>,
}

/// What the pieces prove over one box.
#[derive(Clone, Debug)]
pub struct QpCell {
    /// An enclosure of `v` over `box ∩ S` (where feasible).
    pub v: Vec<Interval>,
    /// The one piece `v` is on the whole box, if proven: `None` inside for `θ = 0`, else the
    /// index of its active set in [`QpForms::sets`]; with the centre, value and Jacobian
    /// enclosures of that smooth function.
    pub piece: Option<(Option<usize>, super::SmoothV)>,
    /// Where only `θ = 0` and one single-row piece are possible on the box: `v` is that
    /// row's closed form, kinked where it starts to bind ([`super::VShape::Kinked`]).
    pub kinked: Option<super::VShape>,
}

/// A general QP filter's pieces as expressions, built once per scenario.
#[derive(Clone, Debug)]
pub struct QpForms {
    n: usize,
    m: usize,
    /// `bₖ(x)` of every row (`hᵢ` not clamped; equal to the clamped rows on `S`).
    b: Vec<Smooth>,
    pieces: Vec<PieceForms>,
    /// Whether the enumeration covers every active set a solution may need.
    complete: bool,
}

impl QpForms {
    /// The pieces of the scenario's filter (any structure).
    pub fn new(s: &Scenario) -> QpForms {
        let (n, m) = (s.n(), s.m());
        let (a_rows, b_rows) = row_expressions(s, false);
        let rows = b_rows.len();
        let b = b_rows.iter().map(|e| Smooth::new(e.clone(), n)).collect();
        let normals: Vec<Option<Vec<f64>>> = a_rows
            .iter()
            .map(|row| row.iter().map(Expr::as_constant).collect())
            .collect();
        let sets = active_sets(rows, m.min(MAX_ACTIVE), &normals);
        let complete = sets.is_some() && (m <= MAX_ACTIVE || rows <= MAX_ACTIVE);
        let pieces = sets
            .unwrap_or_default()
            .into_iter()
            .map(|set| {
                let alg = piece_algebra(&a_rows, &b_rows, &set);
                let smooth = |e: Expr| Smooth::new(e, n);
                // One active row: the closed forms' own expressions (`bₖ/aₖ` for a scalar
                // input, `bₖ·aₖⱼ/‖aₖ‖²` otherwise), equal to `Pⱼ/D` where `D > 0` and with
                // tighter interval evaluations.
                let theta: Vec<Expr> = match set.as_slice() {
                    [k] if m == 1 => vec![b_rows[*k].clone() / a_rows[*k][0].clone()],
                    [k] => a_rows[*k]
                        .iter()
                        .map(|akj| b_rows[*k].clone() * (akj.clone() / alg.d.clone()))
                        .collect(),
                    _ => alg.p.iter().map(|p| p.clone() / alg.d.clone()).collect(),
                };
                PieceForms {
                    theta: theta.into_iter().map(smooth).collect(),
                    d: smooth(alg.d),
                    w: alg.w.into_iter().map(smooth).collect(),
                    primal: alg
                        .primal
                        .into_iter()
                        .map(|(j, e)| (j, smooth(e)))
                        .collect(),
                    set,
                }
            })
            .collect();
        QpForms {
            n,
            m,
            b,
            pieces,
            complete,
        }
    }

    /// The nonempty active sets, in the order of the pieces' indices.
    pub fn sets(&self) -> Vec<Vec<usize>> {
        self.pieces.iter().map(|p| p.set.clone()).collect()
    }

    /// `v` on piece `k` as expressions in x (`θ = P/D` of the `k`-th active set).
    pub fn piece_input(&self, k: usize) -> Vec<Expr> {
        self.pieces[k].theta.iter().map(|t| t.e.clone()).collect()
    }

    /// Whether the enumeration covers every active set a solution may need (else every
    /// enclosure is unbounded).
    pub fn is_complete(&self) -> bool {
        self.complete
    }

    /// The number of nonempty active sets.
    pub fn len(&self) -> usize {
        self.pieces.len()
    }

    /// Whether there is no nonempty active set (no rows).
    pub fn is_empty(&self) -> bool {
        self.pieces.is_empty()
    }

    /// The rows' `bₖ` forms.
    pub fn b(&self) -> &[Smooth] {
        &self.b
    }

    /// The enclosure of `v` over `cell ∩ S` from the possible pieces, and the piece `v` is on
    /// the whole cell where only one is possible (its `D > 0` throughout).
    pub fn enclose(&self, s: &Scenario, cell: &IntervalBox) -> QpCell {
        let m = self.m;
        let entire = QpCell {
            v: vec![Interval::ENTIRE; m],
            piece: None,
            kinked: None,
        };
        if !self.complete {
            return entire;
        }
        let (a_flat, b_nat) = interval_rows(s, cell);
        if b_nat.len() != self.b.len() || a_flat.iter().chain(&b_nat).any(|v| v.is_nan()) {
            return entire;
        }
        let a: Vec<Vec<Interval>> = a_flat.chunks(m.max(1)).map(<[Interval]>::to_vec).collect();
        let Centred { xs, cs, dx } = Centred::of(cell);
        let mut b: Vec<Interval> = self
            .b
            .iter()
            .zip(&b_nat)
            .map(|(bk, &nat)| meet(nat, bk.centred(&xs, &cs, &dx).enclosure))
            .collect();
        slack_inert(&a_flat, m, &mut b);
        // A row's own piece can bound its `bₖ` better than `bₖ`'s forms (as the closed form's
        // `F = b·a/‖a‖²` does): where `‖aₖ‖² > 0`, `bₖ = θⱼ‖aₖ‖²/aₖⱼ` for every input `j` with
        // `aₖⱼ ≠ 0`, `θ` the piece's formula (`bₖaₖ/‖aₖ‖²`, or `bₖ/aₖ`).
        for piece in &self.pieces {
            let [k] = piece.set[..] else {
                continue;
            };
            let d = norm2(&a[k]);
            if d.is_nan() || d.lower <= 0.0 {
                continue;
            }
            for (t, &akj) in piece.theta.iter().zip(&a[k]) {
                if akj.lower > 0.0 || akj.upper < 0.0 {
                    let th = t.centred(&xs, &cs, &dx).enclosure;
                    b[k] = meet(b[k], th * d / akj);
                }
            }
        }
        let zero_piece = || super::SmoothV {
            centre: cell.center(),
            value: vec![Interval::point(0.0); m],
            jac: vec![Interval::point(0.0); m * self.n],
        };
        // Every row slack at `θ = 0` on the whole box: `0` is feasible, so it is the least-norm
        // point, whatever the active-set tests below could decide (over wide boxes the
        // multipliers' signs of the pairs of rows are not resolved by interval evaluation).
        if b.iter().all(|bk| bk.lower >= 0.0) {
            return QpCell {
                v: vec![Interval::point(0.0); m],
                piece: Some((None, zero_piece())),
                kinked: None,
            };
        }
        let centred = |f: &Smooth, nat: Interval| meet(nat, f.centred(&xs, &cs, &dx).enclosure);
        let mut union: Option<Vec<Interval>> = None;
        let mut only: Vec<Option<usize>> = Vec::new();
        let mut smooth: Option<super::SmoothV> = None;
        // The last possible piece's row and smooth form, where it has one row.
        let mut single: Option<(usize, super::SmoothV)> = None;
        if inactive_possible(&a, &b) {
            union = Some(vec![Interval::point(0.0); m]);
            only.push(None);
            smooth = Some(zero_piece());
        }
        for (k, piece) in self.pieces.iter().enumerate() {
            let mut alg = piece_algebra(&a, &b, &piece.set);
            if discarded(&alg) {
                continue;
            }
            // The mean-value forms, met with the natural ones, may discard what these did not.
            alg.d = meet(Interval::new(0.0, f64::INFINITY), centred(&piece.d, alg.d));
            for (w, f) in alg.w.iter_mut().zip(&piece.w) {
                *w = centred(f, *w);
            }
            for ((_, r), (_, f)) in alg.primal.iter_mut().zip(&piece.primal) {
                *r = centred(f, *r);
            }
            if discarded(&alg) {
                continue;
            }
            let mut enc = piece_enclosure(&alg, &a, &b, &piece.set);
            let forms: Vec<_> = piece
                .theta
                .iter()
                .map(|t| t.centred(&xs, &cs, &dx))
                .collect();
            let proper = alg.d.lower > 0.0
                && forms
                    .iter()
                    .all(|f| !f.value.is_nan() && f.grad.iter().all(|g| !g.is_nan()));
            if proper {
                for (e, f) in enc.iter_mut().zip(&forms) {
                    *e = meet(*e, f.enclosure);
                }
            }
            contract(&mut enc, &a, &b);
            union = Some(hull(union, enc));
            only.push(Some(k));
            smooth = proper.then(|| super::SmoothV {
                centre: cell.center(),
                value: forms.iter().map(|f| f.value).collect(),
                jac: forms.iter().flat_map(|f| f.grad.iter().copied()).collect(),
            });
            single = match piece.set[..] {
                [row] => smooth.clone().map(|sv| (row, sv)),
                _ => None,
            };
        }
        let Some(mut v) = union else {
            return entire;
        };
        contract(&mut v, &a, &b);
        if m == 1 {
            // A scalar input: row `k` says `θ ≥ rₖ` (`aₖ < 0`) or `θ ≤ rₖ` (`aₖ > 0`) with
            // `rₖ = bₖ/aₖ`, whose mean-value form (piece `{k}`'s) is tighter than `bₖ/aₖ`.
            for piece in &self.pieces {
                let [k] = piece.set[..] else {
                    continue;
                };
                let ak = a[k][0];
                if !(ak.lower > 0.0 || ak.upper < 0.0) {
                    continue;
                }
                let r = meet(b[k] / ak, piece.theta[0].centred(&xs, &cs, &dx).enclosure);
                let side = if ak.lower > 0.0 {
                    Interval::new(f64::NEG_INFINITY, r.upper)
                } else {
                    Interval::new(r.lower, f64::INFINITY)
                };
                v[0] = meet(v[0], side);
            }
        }
        // `θ = 0` or row `r` alone binding: `v = min(0, bᵣ)·aᵣ/‖aᵣ‖²` (the piece's formula has
        // a negative multiplier where `bᵣ > 0`, so `0` is the solution there), which is
        // `min(0, θⱼ)` where `aᵣⱼ > 0` and `max(0, θⱼ)` where `aᵣⱼ < 0`.
        let kinked = match (only.as_slice(), single) {
            ([None, Some(_)], Some((r, binding))) => {
                let kinks: Vec<Option<super::Kink>> = a[r]
                    .iter()
                    .map(|arj| match (arj.lower > 0.0, arj.upper < 0.0) {
                        (true, _) => Some(super::Kink::Min),
                        (_, true) => Some(super::Kink::Max),
                        _ => None,
                    })
                    .collect();
                kinks
                    .iter()
                    .any(Option::is_some)
                    .then_some(super::VShape::Kinked { binding, kinks })
            }
            _ => None,
        };
        let piece = match (only.as_slice(), smooth) {
            ([one], Some(sv)) => Some((*one, sv)),
            _ => None,
        };
        QpCell { v, piece, kinked }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Parallel means exactly parallel: an input's two bounds and scaled copies are, a pair
    /// whose 2 × 2 minor is `2⁻⁶⁰` (zero in f64 products, not in the error-free ones) is not,
    /// nor is a row whose normal is not constant; sets with a parallel pair are not enumerated.
    #[test]
    fn only_exactly_parallel_constant_rows_are_left_out_together() {
        let v = |x: &[f64]| Some(x.to_vec());
        assert!(constant_parallel(&v(&[1.0, 0.0]), &v(&[-1.0, 0.0])));
        assert!(constant_parallel(&v(&[0.5, -1.5]), &v(&[-2.0, 6.0])));
        let e = 2f64.powi(-30);
        // (1 + e)(1 − e) = 1 − 2⁻⁶⁰ rounds to 1 = 1·1.
        assert_eq!((1.0 + e) * (1.0 - e), 1.0);
        assert!(!constant_parallel(&v(&[1.0 + e, 1.0]), &v(&[1.0, 1.0 - e])));
        assert!(!constant_parallel(&None, &v(&[1.0, 0.0])));
        assert!(!constant_parallel(&v(&[0.0, 0.0]), &v(&[1.0, 0.0])));
        // Rows e₁, −e₁, e₂: pairs {0, 2} and {1, 2} only.
        let normals = [v(&[1.0, 0.0]), v(&[-1.0, 0.0]), v(&[0.0, 1.0])];
        let sets = active_sets(3, 2, &normals).unwrap();
        assert_eq!(
            sets,
            vec![vec![0], vec![1], vec![2], vec![0, 2], vec![1, 2]]
        );
        assert_eq!(active_sets(3, 2, &[]).unwrap().len(), 6);
    }
}

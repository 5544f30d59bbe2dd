//! Enclosures of `v` over a box: the natural one of its closed form ([`v_enclosure`]) and the
//! mean-value forms of [`VForms`] (docs/design.md §2.1). It may import the filter's rows, the scenario,
//! expressions, intervals and boxes.

use super::active_sets::{natural_qp_enclosure, slack_inert, QpForms};
use super::rows::{interval_rows, row_expressions};
use super::solve::RobustGoal;
use super::{FilterMethod, SafetyFilter};
use crate::boxes::IntervalBox;
use crate::expressions::{Expr, Tape};
use crate::intervals::Interval;
use crate::scenario::Scenario;

fn sum(it: impl Iterator<Item = Interval>) -> Interval {
    it.fold(Interval::point(0.0), |a, b| a + b)
}

/// `max(0, −B)` for an interval `B`.
fn neg_part(b: Interval) -> Interval {
    Interval::new((-b.upper).max(0.0), (-b.lower).max(0.0))
}

/// An enclosure of the filter `v` over `box ∩ S`, by interval evaluation of its closed form:
/// `Some(v)` with `v[j] ∋ vⱼ(x)` for every `x ∈ box ∩ S` where the filter is feasible (always
/// `Some`; the `Option` is kept for callers). Ends may be infinite (e.g. when `‖L_g h‖²` may
/// vanish on the box): refine the box.
///
/// * One row `a·θ ≤ b`: `v = −max(0, −b)/‖a‖² · a`.
/// * Scalar input: with `cₖ = max(0, −bₖ)`, `v = max(0, max_{aₖ<0} cₖ/|aₖ|) − max(0,
///   max_{aₖ>0} cₖ/aₖ)` (which is `clamp(0, lo, hi)` wherever `lo ≤ hi`); a row whose `aₖ` may
///   vanish with `cₖ > 0` makes the enclosure unbounded.
/// * A general QP: the union of its possible active-set pieces, by interval evaluation
///   ([`natural_qp_enclosure`], docs/design.md §2.2).
pub fn v_enclosure(
    s: &Scenario,
    method: FilterMethod,
    cell: &IntervalBox,
) -> Option<Vec<Interval>> {
    let m = s.m();
    let (a, mut b) = interval_rows(s, cell);
    let bad = || Some(vec![Interval::ENTIRE; m]);
    if a.iter().chain(&b).any(|v| v.is_nan()) {
        return bad();
    }
    // A row no input acts on binds nowhere `v` exists.
    slack_inert(&a, m, &mut b);
    match method {
        FilterMethod::Qp => Some(natural_qp_enclosure(&a, &b, m)),
        FilterMethod::ClosedFormSingle => {
            if b.len() != 1 || a.len() != m {
                return bad();
            }
            let c = neg_part(b[0]);
            if c.upper == 0.0 {
                return Some(vec![Interval::point(0.0); m]);
            }
            let norm2 = sum(a.iter().map(|&aj| aj.sqr()));
            if norm2.lower <= 0.0 {
                return bad();
            }
            let scale = c / norm2;
            Some(a.iter().map(|&aj| -(scale * aj)).collect())
        }
        FilterMethod::ClosedFormScalar => {
            if m != 1 || a.len() != b.len() {
                return bad();
            }
            // lo⁺ ∈ [lo_l, lo_u], hi⁻ ∈ [hi_l, hi_u]  (both ≥ 0)
            let (mut lo_l, mut lo_u, mut hi_l, mut hi_u) = (0.0_f64, 0.0_f64, 0.0_f64, 0.0_f64);
            for (&ak, &bk) in a.iter().zip(&b) {
                let c = neg_part(bk);
                if c.upper == 0.0 {
                    continue;
                }
                if ak.lower > 0.0 {
                    let q = c / ak;
                    hi_l = hi_l.max(q.lower);
                    hi_u = hi_u.max(q.upper);
                } else if ak.upper < 0.0 {
                    let q = c / (-ak);
                    lo_l = lo_l.max(q.lower);
                    lo_u = lo_u.max(q.upper);
                } else {
                    return bad();
                }
            }
            Some(vec![Interval::new(lo_l, lo_u) - Interval::new(hi_l, hi_u)])
        }
    }
}

/// A smooth expression with its symbolic gradient, for mean-value (centred) enclosures.
#[derive(Clone, Debug)]
pub struct Smooth {
    /// The expression `e(x)`.
    pub e: Expr,
    /// `∂e/∂xᵢ`, one per state.
    pub grad: Vec<Expr>,
    /// The gradient on one tape: its entries share most subtrees (the quotient rule's).
    grad_tape: Tape,
}

/// `e(c)` and `∇e(X)` over a box, and the centred form `e(c) + ∇e(X)·(X − c)`.
pub(super) struct CentredForm {
    pub(super) value: Interval,
    pub(super) grad: Vec<Interval>,
    pub(super) enclosure: Interval,
}

impl Smooth {
    pub(crate) fn new(e: Expr, n: usize) -> Smooth {
        let grad: Vec<Expr> = (0..n).map(|i| e.derivative(i)).collect();
        let grad_tape = Tape::compile(grad.iter().map(Expr::node));
        Smooth { e, grad, grad_tape }
    }

    /// The mean-value form over `xs` around `c` (a point of the box); valid wherever `e` is
    /// differentiable (or Lipschitz, with the interval derivative enclosing its Clarke gradient)
    /// on the box. Every evaluation is outward rounded.
    pub(super) fn centred(&self, xs: &[Interval], c: &[Interval], dx: &[Interval]) -> CentredForm {
        let value = self.e.eval_interval(c);
        let mut grad = vec![Interval::NAN; self.grad.len()];
        self.grad_tape.eval_interval(xs, &mut grad);
        let enclosure = value + sum(grad.iter().zip(dx).map(|(&g, &d)| g * d));
        CentredForm {
            value,
            grad,
            enclosure,
        }
    }
}

/// `a ∩ b`, or `a` when they are disjoint or `b` is NaN (both enclose the same values, so
/// disjointness means no point to enclose; keeping `a` is sound either way).
pub(crate) fn meet(a: Interval, b: Interval) -> Interval {
    if b.is_nan() {
        return a;
    }
    a.intersection(&b).unwrap_or(a)
}

/// `v` equals one smooth function on `cell ∩ S` (where feasible): `v(x) ∈ value + jac·(x − c)`
/// for every such `x`, with `jac` (m × n, row-major) enclosing the derivatives over the cell.
#[derive(Clone, Debug)]
pub struct SmoothV {
    /// The centre `c` of the cell.
    pub centre: Vec<f64>,
    /// An enclosure of `v(c)` (of the smooth function that equals `v` on the cell).
    pub value: Vec<Interval>,
    /// An enclosure of its Jacobian over the cell, `m × n` row-major.
    pub jac: Vec<Interval>,
}

/// What an enclosure of `v` over a cell knows of its form, for joint bounds of `N − v` (whose
/// common slope then cancels: `surrogate_error`'s certified cells).
#[derive(Clone, Debug)]
pub enum VShape {
    /// Nothing beyond the enclosure.
    Unknown,
    /// `v` is one smooth function on the cell.
    Smooth(SmoothV),
    /// One row of a closed form binds on part of the cell: `vⱼ = min(0, Fⱼ)` or `max(0, Fⱼ)`
    /// (`kinks[j]`; `None` where neither is proven) on `cell ∩ S`, with `F` (`binding`) the
    /// row's binding formula, smooth on the whole cell. `v` has a kink where the row starts to
    /// bind; `F` has none.
    Kinked {
        /// `F`'s centred form over the cell.
        binding: SmoothV,
        /// Per input: `vⱼ = min(0, Fⱼ)`, `max(0, Fⱼ)`, or not proven.
        kinks: Vec<Option<Kink>>,
    },
}

/// Which side of 0 a kinked `vⱼ` takes ([`VShape::Kinked`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kink {
    /// `vⱼ = min(0, Fⱼ)`.
    Min,
    /// `vⱼ = max(0, Fⱼ)`.
    Max,
}

impl VShape {
    /// The smooth function, where `v` is one.
    pub fn smooth(&self) -> Option<&SmoothV> {
        match self {
            VShape::Smooth(sv) => Some(sv),
            _ => None,
        }
    }
}

/// One smooth piece of the filter `v` (the filter's active set held fixed).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterPiece {
    /// Every row slack: `v = 0`.
    Inactive,
    /// Piece `k` binds: for a closed form row `k` (every other row slack), for a general QP the
    /// `k`-th nonempty active set of [`QpForms::sets`].
    Binding(usize),
}

/// A cell as intervals `X`, its centre `c` as points, and `X − c`: what mean-value forms take.
pub(super) struct Centred {
    pub(super) xs: Vec<Interval>,
    pub(super) cs: Vec<Interval>,
    pub(super) dx: Vec<Interval>,
}

impl Centred {
    pub(super) fn of(cell: &IntervalBox) -> Centred {
        let xs: Vec<Interval> = (0..cell.dim())
            .map(|i| Interval::new(cell.lower[i], cell.upper[i]))
            .collect();
        let cs: Vec<Interval> = cell.center().into_iter().map(Interval::point).collect();
        let dx = xs.iter().zip(&cs).map(|(&x, &c)| x - c).collect();
        Centred { xs, cs, dx }
    }
}

/// A scalar input's filter over a cell as a lattice of its pieces ([`VForms::lattice`]): the
/// rows that may bind there, bounding `θ` from below (`aₖ < 0`) and from above (`aₖ > 0`).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lattice {
    /// Rows with `aₖ < 0` on the cell: `θ ≥ rₖ` where they bind.
    pub lower: Vec<usize>,
    /// Rows with `aₖ > 0` on the cell: `θ ≤ rₖ` where they bind.
    pub upper: Vec<usize>,
}

/// The rows of the filter over a cell ([`VForms::rows`]).
struct Rows {
    a_nat: Vec<Interval>,
    b_nat: Vec<Interval>,
    b_enc: Vec<Interval>,
}

/// The closed-form filter as expressions with symbolic gradients, built once per scenario for
/// [`VForms::enclose`] (mean-value enclosures of `v`, docs/design.md §2.1).
#[derive(Clone, Debug)]
pub struct VForms {
    method: FilterMethod,
    n: usize,
    m: usize,
    /// `bₖ(x)` of every row (with `hᵢ` itself, not clamped: equal to the clamped one on `S`).
    b: Vec<Smooth>,
    /// One row: `Fⱼ = b·aⱼ/‖a‖²` (equal to `vⱼ` where the row is active).
    f: Vec<Smooth>,
    /// One row: `pⱼ = aⱼ/‖a‖²`.
    p: Vec<Smooth>,
    /// Scalar input: `rₖ = bₖ/aₖ` per row.
    r: Vec<Smooth>,
    /// Scalar input: `rₖ − rⱼ` at `k·rows + j` (`k ≠ j`), to prove one row dominant; empty
    /// beyond [`MAX_DOMINANCE_ROWS`] rows.
    r_diff: Vec<Option<Smooth>>,
    /// A general QP: its active-set pieces (`None` for the closed forms).
    qp: Option<QpForms>,
}

/// The expressions behind [`VForms`], for an engine that evaluates them itself (the GPU's
/// generated WGSL, `src/gpu/codegen.rs`); the fields are those of [`VForms`].
#[derive(Clone, Copy, Debug)]
pub struct VFormParts<'a> {
    /// Which closed form.
    pub method: FilterMethod,
    /// `bₖ(x)` of every row (`hᵢ` not clamped).
    pub b: &'a [Smooth],
    /// One row: `Fⱼ = b·aⱼ/‖a‖²`.
    pub f: &'a [Smooth],
    /// One row: `pⱼ = aⱼ/‖a‖²`.
    pub p: &'a [Smooth],
    /// Scalar input: `rₖ = bₖ/aₖ`.
    pub r: &'a [Smooth],
    /// Scalar input: `rₖ − rⱼ` at `k·rows + j` (`None` on the diagonal; empty beyond eight rows).
    pub r_diff: &'a [Option<Smooth>],
}

/// Rows up to which [`VForms`] keeps the pairwise differences `rₖ − rⱼ` (their count grows
/// with the square).
const MAX_DOMINANCE_ROWS: usize = 8;

impl VForms {
    /// The forms of the scenario's filter: its closed form, or for a general QP its active-set
    /// pieces ([`QpForms`]); `None` for a QP with more active sets than are enumerated
    /// ([`super::active_sets::MAX_SETS`]).
    pub fn new(s: &Scenario) -> Option<VForms> {
        let method = SafetyFilter::new(s).method();
        let (n, m) = (s.n(), s.m());
        if method == FilterMethod::Qp {
            let qp = QpForms::new(s);
            if !qp.is_complete() {
                return None;
            }
            return Some(VForms {
                method,
                n,
                m,
                b: qp.b().to_vec(),
                f: Vec::new(),
                p: Vec::new(),
                r: Vec::new(),
                r_diff: Vec::new(),
                qp: Some(qp),
            });
        }
        let (a_rows, b_rows) = row_expressions(s, false);
        let sum_e = |it: &mut dyn Iterator<Item = Expr>| it.fold(Expr::constant(0.0), |a, b| a + b);
        let b: Vec<Smooth> = b_rows.iter().map(|e| Smooth::new(e.clone(), n)).collect();
        let (mut f, mut p, mut r) = (Vec::new(), Vec::new(), Vec::new());
        match method {
            FilterMethod::ClosedFormSingle if a_rows.len() == 1 => {
                let a = &a_rows[0];
                let norm2 = sum_e(&mut a.iter().map(|aj| aj.clone() * aj.clone()));
                for aj in a {
                    let pj = aj.clone() / norm2.clone();
                    f.push(Smooth::new(b_rows[0].clone() * pj.clone(), n));
                    p.push(Smooth::new(pj, n));
                }
            }
            FilterMethod::ClosedFormScalar if m == 1 => {
                for (a, bk) in a_rows.iter().zip(&b_rows) {
                    r.push(Smooth::new(bk.clone() / a[0].clone(), n));
                }
            }
            _ => {}
        }
        let rows = r.len();
        let r_diff = if rows <= MAX_DOMINANCE_ROWS {
            (0..rows * rows)
                .map(|kj| {
                    let (k, j) = (kj / rows, kj % rows);
                    (k != j).then(|| Smooth::new(r[k].e.clone() - r[j].e.clone(), n))
                })
                .collect()
        } else {
            Vec::new()
        };
        Some(VForms {
            method,
            n,
            m,
            b,
            f,
            p,
            r,
            r_diff,
            qp: None,
        })
    }

    /// The general QP's pieces (`None` for a closed form).
    pub fn qp(&self) -> Option<&QpForms> {
        self.qp.as_ref()
    }

    /// The rows over `cell ∩ S`: natural enclosures of `a` and `b`, and `b` met with its
    /// mean-value form; `None` when some row is undefined (NaN) on the cell.
    fn rows(
        &self,
        s: &Scenario,
        xs: &[Interval],
        cs: &[Interval],
        dx: &[Interval],
        cell: &IntervalBox,
    ) -> Option<Rows> {
        let (a_nat, b_nat) = interval_rows(s, cell);
        if b_nat.len() != self.b.len() || a_nat.iter().chain(&b_nat).any(|v| v.is_nan()) {
            return None;
        }
        let b_enc = self
            .b
            .iter()
            .zip(&b_nat)
            .map(|(bk, &nat)| meet(nat, bk.centred(xs, cs, dx).enclosure))
            .collect();
        Some(Rows {
            a_nat,
            b_nat,
            b_enc,
        })
    }

    /// [`VForms::rows`] for enclosing `v`, which exists only where the QP is feasible: the rows
    /// no input acts on made slack there ([`slack_inert`]). Never for proofs of feasibility.
    fn v_rows(
        &self,
        s: &Scenario,
        xs: &[Interval],
        cs: &[Interval],
        dx: &[Interval],
        cell: &IntervalBox,
    ) -> Option<Rows> {
        let mut rows = self.rows(s, xs, cs, dx, cell)?;
        slack_inert(&rows.a_nat, self.m, &mut rows.b_nat);
        slack_inert(&rows.a_nat, self.m, &mut rows.b_enc);
        Some(rows)
    }

    /// Which smooth piece of the closed form `v` is on the whole of `cell ∩ S` (where the
    /// filter is feasible), if one provably is: every row slack (`bₖ ≥ 0`: `v = 0`), or one row
    /// binding throughout (`bₖ ≤ 0`, its `aₖ` bounded away from 0) while every other row that
    /// may bind is, for a scalar input, on the other side of `θ = 0` or dominated by it
    /// (`rₖ − rⱼ` of one sign on the cell).
    pub fn piece(&self, s: &Scenario, cell: &IntervalBox) -> Option<FilterPiece> {
        if let Some(qp) = &self.qp {
            return qp.enclose(s, cell).piece.map(|(k, _)| match k {
                None => FilterPiece::Inactive,
                Some(k) => FilterPiece::Binding(k),
            });
        }
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Rows {
            a_nat,
            b_nat,
            b_enc,
        } = self.v_rows(s, &xs, &cs, &dx, cell)?;
        let may_bind: Vec<usize> = (0..b_enc.len()).filter(|&k| b_enc[k].lower < 0.0).collect();
        if may_bind.is_empty() {
            return Some(FilterPiece::Inactive);
        }
        match self.method {
            FilterMethod::ClosedFormSingle if !self.f.is_empty() => {
                let norm2 = sum(a_nat.iter().map(|&aj| aj.sqr()));
                (b_enc[0].upper <= 0.0 && norm2.lower > 0.0).then_some(FilterPiece::Binding(0))
            }
            FilterMethod::ClosedFormScalar if self.r.len() == b_enc.len() => {
                // `v = clamp(0, lo, hi)` with `lo` the largest `rₖ` of the rows with `aₖ < 0`
                // and `hi` the smallest of those with `aₖ > 0`. A row that binds throughout
                // (`bₖ ≤ 0`) fixes the sign of `v`, so only the rows on its own side compete:
                // it is `v` where it dominates each of them that may bind.
                let r_of = |k: usize| {
                    meet(
                        b_nat[k] / a_nat[k],
                        self.r[k].centred(&xs, &cs, &dx).enclosure,
                    )
                };
                let side = |k: usize| {
                    let a = a_nat[k];
                    (a.upper < 0.0)
                        .then_some(false)
                        .or((a.lower > 0.0).then_some(true))
                };
                let dominates = |k: usize, j: usize, upper: bool| {
                    let Some(Some(form)) = self.r_diff.get(k * self.r.len() + j) else {
                        return false;
                    };
                    let d = meet(r_of(k) - r_of(j), form.centred(&xs, &cs, &dx).enclosure);
                    if upper {
                        d.upper <= 0.0
                    } else {
                        d.lower >= 0.0
                    }
                };
                may_bind
                    .iter()
                    .copied()
                    .find(|&k| {
                        let Some(upper) = side(k) else {
                            return false;
                        };
                        b_enc[k].upper <= 0.0
                            && may_bind.iter().all(|&j| {
                                j == k
                                    || match side(j) {
                                        Some(u) if u != upper => true,
                                        Some(_) => dominates(k, j, upper),
                                        None => false,
                                    }
                            })
                    })
                    .map(FilterPiece::Binding)
            }
            _ => None,
        }
    }

    /// The box around the ball `v` lies in over `cell ∩ S` where one `θ*` satisfies every row
    /// there: `v(x)` is the least-norm point of a convex set that holds `θ*`, so `⟨v, θ* − v⟩ ≥
    /// 0`, that is `‖v − θ*/2‖ ≤ ‖θ*‖/2`. With `θ*` the least such point over the cell
    /// ([`super::solve::robust_point`]) the ball is about as small as `v`'s largest value
    /// there, whatever the pieces: where two rows are nearly parallel (a CBF row beside an
    /// input bound) each piece's `1/det G` leaves its own enclosure unbounded. `None` where no
    /// such `θ*` is found and proven (the interval check of [`super::feasibility::holds`]).
    fn least_feasible_ball(&self, s: &Scenario, cell: &IntervalBox) -> Option<Vec<Interval>> {
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Rows { a_nat, b_enc, .. } = self.v_rows(s, &xs, &cs, &dx, cell)?;
        let ends: Vec<(f64, f64)> = a_nat.iter().map(|e| (e.lower, e.upper)).collect();
        let least: Vec<f64> = b_enc.iter().map(|e| e.lower).collect();
        let theta = super::solve::robust_point(&ends, &least, self.m, RobustGoal::Least)?;
        if !super::feasibility::holds(&theta, &a_nat, &b_enc, self.m) {
            return None;
        }
        let half = Interval::point(0.5);
        let radius = sum(theta.iter().map(|&t| Interval::point(t).sqr())).sqrt() * half;
        Some(
            theta
                .iter()
                .map(|&t| {
                    let centre = Interval::point(t) * half;
                    Interval::new((centre - radius).lower, (centre + radius).upper)
                })
                .collect(),
        )
    }

    /// Whether the filter's QP is feasible at every point of `cell ∩ S`. One row: `bₖ ≥ 0` or
    /// `aₖ ≠ 0`. Scalar input: each row's set of `θ` is a half-line (or all of ℝ), and in one
    /// dimension sets that meet pairwise have a common point (Helly), so it suffices that every
    /// row alone is feasible and that no two rows point in opposite directions past each
    /// other: `aⱼaₖ ≥ 0`, or `(bⱼaₖ − bₖaⱼ)·aₖ ≥ 0` (that is `bⱼ/aⱼ ≤ bₖ/aₖ` when `aⱼ < 0 < aₖ`),
    /// or both rows slack at `θ = 0`. General QP: every row slack at `θ = 0`, or one `θ*`
    /// (found at the centre) that satisfies every row over the whole cell in interval
    /// arithmetic.
    pub fn proves_feasible(&self, s: &Scenario, cell: &IntervalBox) -> bool {
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Some(Rows { a_nat, b_enc, .. }) = self.rows(s, &xs, &cs, &dx, cell) else {
            return false;
        };
        let slack = |k: usize| b_enc[k].lower >= 0.0;
        match self.method {
            FilterMethod::ClosedFormSingle => {
                slack(0) || sum(a_nat.iter().map(|&aj| aj.sqr())).lower > 0.0
            }
            FilterMethod::ClosedFormScalar => {
                let rows = b_enc.len();
                let alone = (0..rows).all(|k| slack(k) || !a_nat[k].contains(0.0));
                alone
                    && (0..rows).all(|j| {
                        (j + 1..rows).all(|k| {
                            let (aj, ak) = (a_nat[j], a_nat[k]);
                            (slack(j) && slack(k))
                                || (aj * ak).lower >= 0.0
                                || ((b_enc[j] * ak - b_enc[k] * aj) * ak).lower >= 0.0
                        })
                    })
            }
            FilterMethod::Qp => {
                (0..b_enc.len()).all(slack)
                    || super::feasibility::proves_feasible(s, cell, &a_nat, &b_enc)
            }
        }
    }

    /// `v` on a piece, as expressions in x (`m` of them): `0` where every row is slack;
    /// `bₖ aⱼ/‖a‖²` (one row) or `bₖ/aₖ` (scalar input) where row `k` binds.
    pub fn piece_input(&self, piece: FilterPiece) -> Vec<Expr> {
        match piece {
            FilterPiece::Inactive => vec![Expr::constant(0.0); self.m],
            FilterPiece::Binding(k) => match self.method {
                FilterMethod::Qp => self
                    .qp
                    .as_ref()
                    .map_or_else(Vec::new, |qp| qp.piece_input(k)),
                FilterMethod::ClosedFormSingle => self.f.iter().map(|f| f.e.clone()).collect(),
                _ => vec![self.r[k].e.clone()],
            },
        }
    }

    /// For a scalar input's closed form, the rows that may bind on `cell ∩ S` by the side of
    /// `θ` they bound: then `v = clamp(0, lo, hi)` with `lo` the largest `rₖ` of `lower` and
    /// `hi` the smallest of `upper`, where feasible (rows proven slack are left out: a slack
    /// row's `rₖ` lies on the far side of 0, or past the other side's bound where the QP is
    /// feasible). `None` for other filters, or where a row that may bind has `aₖ` of either
    /// sign on the cell (`v` may jump there).
    pub fn lattice(&self, s: &Scenario, cell: &IntervalBox) -> Option<Lattice> {
        if self.qp.is_some()
            || self.method != FilterMethod::ClosedFormScalar
            || self.r.len() != self.b.len()
        {
            return None;
        }
        let Centred { xs, cs, dx } = Centred::of(cell);
        let Rows { a_nat, b_enc, .. } = self.v_rows(s, &xs, &cs, &dx, cell)?;
        let mut lattice = Lattice::default();
        for (k, (a, b)) in a_nat.iter().zip(&b_enc).enumerate() {
            if b.lower >= 0.0 {
                continue;
            }
            if a.upper < 0.0 {
                lattice.lower.push(k);
            } else if a.lower > 0.0 {
                lattice.upper.push(k);
            } else {
                return None;
            }
        }
        Some(lattice)
    }

    /// Its expressions, for engines that evaluate them elsewhere.
    pub fn parts(&self) -> VFormParts<'_> {
        VFormParts {
            method: self.method,
            b: &self.b,
            f: &self.f,
            p: &self.p,
            r: &self.r,
            r_diff: &self.r_diff,
        }
    }

    /// Which closed form.
    pub fn method(&self) -> FilterMethod {
        self.method
    }

    /// The input dimension `m` (outputs of `v`).
    pub fn m(&self) -> usize {
        self.m
    }

    /// Number of binding pieces (the pieces are [`FilterPiece::Inactive`] and one
    /// [`FilterPiece::Binding`] per row of a closed form, per nonempty active set of a QP).
    pub fn rows_len(&self) -> usize {
        self.qp.as_ref().map_or(self.b.len(), QpForms::len)
    }

    /// An enclosure of `v` over `cell ∩ S` (where feasible), the natural one of
    /// [`v_enclosure`] intersected with mean-value forms where those apply, and its form for a
    /// joint bound of `N − v`: smooth where `v` is one smooth function on the cell (the filter
    /// provably inactive: `v ≡ 0`; or one row provably active on the whole cell), kinked where
    /// a closed form's one row binds on part of it.
    pub fn enclose(&self, s: &Scenario, cell: &IntervalBox) -> (Vec<Interval>, VShape) {
        let (n, m) = (self.n, self.m);
        let natural =
            v_enclosure(s, self.method, cell).unwrap_or_else(|| vec![Interval::ENTIRE; m]);
        if let Some(qp) = &self.qp {
            let cell_v = qp.enclose(s, cell);
            let mut v: Vec<Interval> = natural
                .iter()
                .zip(&cell_v.v)
                .map(|(&a, &b)| meet(b, a))
                .collect();
            // Where one piece is proven its mean-value form is tight already.
            if cell_v.piece.is_none() && v.iter().any(|e| e.width() > 0.0) {
                if let Some(ball) = self.least_feasible_ball(s, cell) {
                    v = v.iter().zip(&ball).map(|(&a, &b)| meet(a, b)).collect();
                }
            }
            let shape = match (cell_v.piece, cell_v.kinked) {
                (Some((_, sv)), _) => VShape::Smooth(sv),
                (None, Some(kinked)) => kinked,
                (None, None) => VShape::Unknown,
            };
            return (v, shape);
        }
        let centre = cell.center();
        let Centred { xs, cs, dx } = Centred::of(cell);
        let zero_v = || SmoothV {
            centre: centre.clone(),
            value: vec![Interval::point(0.0); m],
            jac: vec![Interval::point(0.0); m * n],
        };
        let Some(Rows {
            a_nat,
            b_nat,
            b_enc,
        }) = self.v_rows(s, &xs, &cs, &dx, cell)
        else {
            return (natural, VShape::Unknown);
        };
        let smooth_of = |forms: Vec<CentredForm>| SmoothV {
            centre: centre.clone(),
            value: forms.iter().map(|f| f.value).collect(),
            jac: forms.iter().flat_map(|f| f.grad.iter().copied()).collect(),
        };
        match self.method {
            FilterMethod::ClosedFormSingle if !self.f.is_empty() => {
                let b = b_enc[0];
                if b.lower >= 0.0 {
                    return (vec![Interval::point(0.0); m], VShape::Smooth(zero_v()));
                }
                let norm2 = sum(a_nat.iter().map(|&aj| aj.sqr()));
                // (NaN counts as "maybe zero".)
                if norm2.lower.is_nan() || norm2.lower <= 0.0 {
                    return (natural, VShape::Unknown);
                }
                let forms: Vec<CentredForm> =
                    self.f.iter().map(|f| f.centred(&xs, &cs, &dx)).collect();
                if forms.iter().any(|f| f.grad.iter().any(|g| g.is_nan())) {
                    return (natural, VShape::Unknown);
                }
                if b.upper <= 0.0 {
                    let enc = (0..m)
                        .map(|j| meet(natural[j], forms[j].enclosure))
                        .collect();
                    return (enc, VShape::Smooth(smooth_of(forms)));
                }
                // Active on part of the cell: vⱼ = min(0, b)·pⱼ = min(0, Fⱼ) where pⱼ ≥ 0,
                // max(0, Fⱼ) where pⱼ ≤ 0.
                let zero = Interval::point(0.0);
                let mut kinks = Vec::with_capacity(m);
                let enc = (0..m)
                    .map(|j| {
                        let pj = meet(a_nat[j] / norm2, self.p[j].centred(&xs, &cs, &dx).enclosure);
                        let fj = forms[j].enclosure;
                        let (e, kink) = if pj.lower >= 0.0 {
                            (fj.min(zero), Some(Kink::Min))
                        } else if pj.upper <= 0.0 {
                            (fj.max(zero), Some(Kink::Max))
                        } else {
                            (b.min(zero) * pj, None)
                        };
                        kinks.push(kink);
                        meet(natural[j], e)
                    })
                    .collect();
                let shape = match kinks.iter().any(Option::is_some) {
                    true => VShape::Kinked {
                        binding: smooth_of(forms),
                        kinks,
                    },
                    false => VShape::Unknown,
                };
                (enc, shape)
            }
            FilterMethod::ClosedFormScalar if self.r.len() == b_enc.len() => {
                let zero = Interval::point(0.0);
                let (mut lo, mut hi) = (zero, zero);
                let mut active: Vec<usize> = Vec::new();
                for k in 0..b_enc.len() {
                    if b_enc[k].lower >= 0.0 {
                        continue; // the row never binds on the cell
                    }
                    let ak = a_nat[k];
                    if ak.lower <= 0.0 && ak.upper >= 0.0 {
                        return (natural, VShape::Unknown);
                    }
                    active.push(k);
                    let rk = meet(b_nat[k] / ak, self.r[k].centred(&xs, &cs, &dx).enclosure);
                    if ak.upper < 0.0 {
                        lo = lo.max(rk);
                    } else {
                        hi = hi.min(rk);
                    }
                }
                if active.is_empty() {
                    return (vec![zero], VShape::Smooth(zero_v()));
                }
                let enc = vec![meet(natural[0], lo + hi)];
                if let [k] = active[..] {
                    let form = self.r[k].centred(&xs, &cs, &dx);
                    if !form.grad.iter().any(|g| g.is_nan()) {
                        let binding = smooth_of(vec![form]);
                        if b_enc[k].upper <= 0.0 {
                            return (enc, VShape::Smooth(binding));
                        }
                        // Binding on part of the cell: `θ ≥ r` (`a < 0`) gives `max(0, r)`,
                        // `θ ≤ r` gives `min(0, r)`.
                        let kink = match a_nat[k].upper < 0.0 {
                            true => Kink::Max,
                            false => Kink::Min,
                        };
                        let kinks = vec![Some(kink)];
                        return (enc, VShape::Kinked { binding, kinks });
                    }
                }
                (enc, VShape::Unknown)
            }
            _ => (natural, VShape::Unknown),
        }
    }
}

//! Solving the filter's QP at one point: the closed forms (one row, a scalar input) and
//! clarabel with an exact polish. It may import the filter's own types (and clarabel, nalgebra).

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};

use super::{ConstraintRows, FilterError, FilterStatus, Infeasibility};

/// Rows whose `‖aₖ‖²` is below this are treated as `θ`-free (`0 ≤ bₖ`).
const DEGENERATE_ROW: f64 = 1e-24;

/// One row `a·θ ≤ b`: `θ = 0` when `b ≥ 0`, else the projection `b a / ‖a‖²`.
pub(super) fn project_half_space(rows: &ConstraintRows, m: usize) -> FilterStatus {
    let a = &rows.g[..m];
    let b = rows.q[0];
    if b >= 0.0 {
        return FilterStatus::Solved(vec![0.0; m]);
    }
    let norm2: f64 = a.iter().map(|v| v * v).sum();
    if norm2 <= DEGENERATE_ROW {
        return FilterStatus::Infeasible(Infeasibility::NoInputOnRow {
            row: rows.labels[0].clone(),
            b,
        });
    }
    FilterStatus::Solved(a.iter().map(|ai| b * ai / norm2).collect())
}

/// Scalar input: each row bounds `θ` from one side; `θ = clamp(0, lo, hi)`.
pub(super) fn clamp_scalar(rows: &ConstraintRows, input: &str) -> FilterStatus {
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut lo_label, mut hi_label) = ("", "");
    for ((&a, &b), label) in rows.g.iter().zip(&rows.q).zip(&rows.labels) {
        if a * a <= DEGENERATE_ROW {
            if b < 0.0 {
                return FilterStatus::Infeasible(Infeasibility::NoInput {
                    row: label.clone(),
                    b,
                });
            }
        } else if a > 0.0 {
            if b / a < hi {
                hi = b / a;
                hi_label = label;
            }
        } else if b / a > lo {
            lo = b / a;
            lo_label = label;
        }
    }
    if lo > hi {
        return FilterStatus::Infeasible(Infeasibility::Conflict {
            lower_row: lo_label.to_string(),
            lower: lo,
            upper_row: hi_label.to_string(),
            upper: hi,
            input: input.to_string(),
            kappa: rows.kappa.first().copied().unwrap_or(0.0),
        });
    }
    FilterStatus::Solved(vec![0.0_f64.clamp(lo, hi)])
}

/// The exact minimiser, from the active sets that clarabel's answer makes plausible.
///
/// Candidates are the rows that are nearly tight at clarabel's `θ` or carry a multiplier; every
/// subset `A` of at most m of them gives a candidate from [`kkt_point`], and the unique KKT
/// point is the one with multipliers `μ ≥ 0` that satisfies every row. `None` if no subset qualifies (then
/// clarabel's own answer, accurate to its tolerance, is used).
fn polish(rows: &ConstraintRows, m: usize, x: &[f64], z: &[f64]) -> Option<Vec<f64>> {
    let k = rows.q.len();
    let slack = |k: usize| rows.q[k] - (0..m).map(|j| rows.g[k * m + j] * x[j]).sum::<f64>();
    let candidates: Vec<usize> = (0..k)
        .filter(|&r| z[r] > 1e-9 || slack(r) <= 1e-6 * rows.q[r].abs().max(1.0))
        .collect();
    if candidates.len() > 12 {
        return None;
    }
    let mut best: Option<Vec<f64>> = None;
    for mask in 0u32..(1 << candidates.len()) {
        if mask.count_ones() as usize > m {
            continue;
        }
        let active: Vec<usize> = (0..candidates.len())
            .filter(|b| mask >> b & 1 == 1)
            .map(|b| candidates[b])
            .collect();
        let Some(theta) = kkt_point(rows, m, &active) else {
            continue;
        };
        let holds = (0..k).all(|r| {
            let lhs: f64 = (0..m).map(|j| rows.g[r * m + j] * theta[j]).sum();
            lhs <= rows.q[r] + 1e-10 * rows.q[r].abs().max(1.0)
        });
        let norm = |t: &[f64]| t.iter().map(|v| v * v).sum::<f64>();
        if holds && best.as_ref().is_none_or(|b| norm(&theta) < norm(b)) {
            best = Some(theta);
        }
    }
    best
}

/// The KKT point for the active set `A`: stationarity `θ = −G_Aᵀ μ` and `G_A θ = q_A` give
/// `μ = −(G_A G_Aᵀ)⁻¹ q_A`, which must be `≥ 0`; `None` otherwise.
fn kkt_point(rows: &ConstraintRows, m: usize, active: &[usize]) -> Option<Vec<f64>> {
    if active.is_empty() {
        return Some(vec![0.0; m]);
    }
    let ga = nalgebra::DMatrix::from_fn(active.len(), m, |r, j| rows.g[active[r] * m + j]);
    let qa = nalgebra::DVector::from_iterator(active.len(), active.iter().map(|&r| rows.q[r]));
    let mu = -(&ga * ga.transpose()).lu().solve(&qa)?;
    if !mu.iter().all(|l| *l >= 0.0) {
        return None;
    }
    Some((-(ga.transpose() * mu)).iter().copied().collect())
}

/// Rows up to which [`solve_by_active_sets`] enumerates (2¹⁰ subsets at most).
const ENUMERATED_ROWS: usize = 10;

/// The exact minimiser by enumeration of the active sets (at most `m` linearly independent
/// rows, smallest first): the KKT point ([`kkt_point`]: `μ ≥ 0`) that satisfies every row is
/// the unique minimiser. `None` when there are too many rows or no set qualifies (degenerate
/// rows, an infeasible QP): clarabel decides those. Microseconds against clarabel's tenth of a
/// millisecond, which is what a Newton search for equilibria or a dataset needs.
pub(super) fn solve_by_active_sets(rows: &ConstraintRows, m: usize) -> Option<Vec<f64>> {
    let k = rows.q.len();
    if k > ENUMERATED_ROWS {
        return None;
    }
    let holds = |theta: &[f64]| {
        (0..k).all(|r| {
            let lhs: f64 = (0..m).map(|j| rows.g[r * m + j] * theta[j]).sum();
            lhs <= rows.q[r] + 1e-10 * rows.q[r].abs().max(1.0)
        })
    };
    let mut layer: Vec<Vec<usize>> = vec![Vec::new()];
    for size in 0..=m.min(k) {
        for active in &layer {
            if let Some(theta) = kkt_point(rows, m, active) {
                if theta.iter().all(|t| t.is_finite()) && holds(&theta) {
                    return Some(theta);
                }
            }
        }
        if size == m.min(k) {
            break;
        }
        layer = layer
            .iter()
            .flat_map(|set| {
                let from = set.last().map_or(0, |&l| l + 1);
                (from..k).map(move |r| {
                    let mut s = set.clone();
                    s.push(r);
                    s
                })
            })
            .collect();
    }
    None
}

/// The general QP `min ½‖θ‖² s.t. G θ ≤ q` by clarabel; an error when clarabel stops
/// without an answer (`x` only names the state in it).
pub(super) fn solve_qp(
    rows: &ConstraintRows,
    m: usize,
    x: &[f64],
) -> Result<FilterStatus, FilterError> {
    let k = rows.q.len();
    if k == 0 {
        return Ok(FilterStatus::Solved(vec![0.0; m]));
    }
    let p = CscMatrix::identity(m);
    // G in compressed-column form, every entry stored (the problems are tiny and dense).
    let colptr = (0..=m).map(|j| j * k).collect();
    let rowval = (0..m).flat_map(|_| 0..k).collect();
    let nzval = (0..m)
        .flat_map(|j| (0..k).map(move |i| rows.g[i * m + j]))
        .collect();
    let a = CscMatrix::new(k, m, colptr, rowval, nzval);
    let cones = [SupportedConeT::NonnegativeConeT(k)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .tol_gap_abs(1e-10)
        .tol_gap_rel(1e-10)
        .tol_feas(1e-10)
        .build()
        .map_err(|e| FilterError::Solver {
            status: format!("settings: {e}"),
            x: x.to_vec(),
        })?;
    let q = vec![0.0; m];
    let mut solver = DefaultSolver::new(&p, &q, &a, &rows.q, &cones, settings).map_err(|e| {
        FilterError::Solver {
            status: format!("setup: {e}"),
            x: x.to_vec(),
        }
    })?;
    solver.solve();
    let sol = &solver.solution;
    match sol.status {
        SolverStatus::Solved | SolverStatus::AlmostSolved | SolverStatus::InsufficientProgress
            if sol.x.iter().all(|v| v.is_finite()) =>
        {
            // Interior-point answers are accurate to the tolerance; the active set they reveal
            // gives the exact minimiser, which we keep when it passes the KKT conditions.
            Ok(FilterStatus::Solved(
                polish(rows, m, &sol.x, &sol.z).unwrap_or_else(|| sol.x.clone()),
            ))
        }
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
            Ok(FilterStatus::Infeasible(Infeasibility::Incompatible {
                rows: rows.labels.clone(),
            }))
        }
        status => Err(FilterError::Solver {
            status: format!("{status:?}"),
            x: x.to_vec(),
        }),
    }
}

/// A point well inside the rows `G θ ≤ q` and near 0: the `θ` of
/// `min ½‖θ‖² + ½t² − t  s.t.  gₖ·θ + t‖gₖ‖ ≤ qₖ`, which trades the margin `t` (the radius of a
/// ball around `θ` inside every row) against the size of `θ`. `None` when clarabel finds no
/// such point with `t > 0` (the rows leave no interior, or clarabel fails).
pub(super) fn margin_point(rows: &ConstraintRows, m: usize) -> Option<Vec<f64>> {
    let k = rows.q.len();
    let norms: Vec<f64> = (0..k)
        .map(|r| {
            (0..m)
                .map(|j| rows.g[r * m + j].powi(2))
                .sum::<f64>()
                .sqrt()
        })
        .collect();
    let cols = m + 1;
    let p = CscMatrix::identity(cols);
    let colptr = (0..=cols).map(|j| j * k).collect();
    let rowval = (0..cols).flat_map(|_| 0..k).collect();
    let nzval = (0..cols)
        .flat_map(|j| {
            let norms = &norms;
            (0..k).map(move |i| if j < m { rows.g[i * m + j] } else { norms[i] })
        })
        .collect();
    let a = CscMatrix::new(k, cols, colptr, rowval, nzval);
    let cones = [SupportedConeT::NonnegativeConeT(k)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .ok()?;
    let mut q = vec![0.0; cols];
    q[m] = -1.0;
    let mut solver = DefaultSolver::new(&p, &q, &a, &rows.q, &cones, settings).ok()?;
    solver.solve();
    let sol = &solver.solution;
    let solved = matches!(
        sol.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    );
    (solved && sol.x[m] > 0.0 && sol.x.iter().all(|v| v.is_finite())).then(|| sol.x[..m].to_vec())
}

/// What [`robust_point`] looks for among the `θ` that satisfy every row over a box.
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum RobustGoal {
    /// The largest margin, up to the rows' own scale, with a small pull towards 0: a
    /// candidate for a feasibility proof.
    Deepest,
    /// The least `‖θ‖` (within a hair of the rows, so that the interval check passes): the
    /// tightest ball `v` is known to lie in ([`super::enclosures`]).
    Least,
}

/// A `θ` that satisfies rows known only as enclosures over a box, `aₖ·θ ≤ bₖ` for every
/// `aₖ ∈ [a̲ₖ, āₖ]` and `bₖ ≥ b̲ₖ`: the robust counterpart `Σⱼ (midₖⱼ θⱼ + radₖⱼ |θⱼ|) +
/// t‖midₖ‖ ≤ b̲ₖ` (exactly what interval arithmetic checks), `|θ| ≤ s` as two rows, and the
/// `goal`. [`margin_point`] at the box's centre trades depth against `‖θ‖` and lands on a row
/// where the feasible `θ` lie far from 0 (a nominal input well past an input bound); this one
/// is chosen for the whole box. `a` row-major rows × m, `b` one per row; `None` where an
/// enclosure is not finite, no such `θ` exists, or clarabel fails. Only a candidate: the
/// caller's interval check is the proof.
pub(super) fn robust_point(
    a: &[(f64, f64)],
    b: &[f64],
    m: usize,
    goal: RobustGoal,
) -> Option<Vec<f64>> {
    let k = b.len();
    let finite =
        a.iter().all(|(l, u)| l.is_finite() && u.is_finite()) && b.iter().all(|v| v.is_finite());
    if !finite || k == 0 {
        return None;
    }
    let mid = |r: usize, j: usize| 0.5 * (a[r * m + j].0 + a[r * m + j].1);
    let rad = |r: usize, j: usize| 0.5 * (a[r * m + j].1 - a[r * m + j].0);
    let norms: Vec<f64> = (0..k)
        .map(|r| (0..m).map(|j| mid(r, j).powi(2)).sum::<f64>().sqrt())
        .collect();
    // The rows' offsets' scale: the deepest margin is capped at it (where the rows leave a
    // cone deeper is not better, the rows' spread grows with |θ|), the least `θ` keeps a
    // hair of it.
    let scale = 1.0
        + (0..k)
            .filter(|&r| norms[r] > 0.0)
            .map(|r| b[r].abs() / norms[r])
            .fold(0.0, f64::max);
    let cols = 2 * m + 1;
    let (rows, t) = (k + 2 * m + 1, 2 * m);
    // Column-major entries of [mid | rad | ‖mid‖] over [I, −I, 0; −I, −I, 0; 0, 0, ±1].
    let mut columns: Vec<Vec<(usize, f64)>> = vec![Vec::new(); cols];
    for (r, &norm) in norms.iter().enumerate() {
        for j in 0..m {
            columns[j].push((r, mid(r, j)));
            columns[m + j].push((r, rad(r, j)));
        }
        columns[t].push((r, norm));
    }
    for j in 0..m {
        columns[j].push((k + 2 * j, 1.0));
        columns[j].push((k + 2 * j + 1, -1.0));
        columns[m + j].push((k + 2 * j, -1.0));
        columns[m + j].push((k + 2 * j + 1, -1.0));
    }
    let mut rhs = b.to_vec();
    rhs.extend(std::iter::repeat_n(0.0, 2 * m));
    let (diagonal, q) = match goal {
        RobustGoal::Deepest => {
            // t ≤ scale; a pull towards 0 small against the depth at the rows' scale.
            columns[t].push((k + 2 * m, 1.0));
            rhs.push(scale);
            let mut q = vec![0.0; cols];
            q[t] = -1.0;
            (vec![1e-3 / (scale * scale); cols], q)
        }
        RobustGoal::Least => {
            // t ≥ a hair of the scale; ‖θ‖² (s and t only kept bounded).
            columns[t].push((k + 2 * m, -1.0));
            rhs.push(-1e-9 * scale);
            let mut diagonal = vec![1e-9; cols];
            diagonal[..m].fill(1.0);
            (diagonal, vec![0.0; cols])
        }
    };
    let mut colptr = vec![0];
    let (mut rowval, mut nzval) = (Vec::new(), Vec::new());
    for column in &columns {
        for &(r, v) in column {
            rowval.push(r);
            nzval.push(v);
        }
        colptr.push(rowval.len());
    }
    let constraints = CscMatrix::new(rows, cols, colptr, rowval, nzval);
    let p = CscMatrix::new(
        cols,
        cols,
        (0..=cols).collect(),
        (0..cols).collect(),
        diagonal,
    );
    let cones = [SupportedConeT::NonnegativeConeT(rows)];
    let settings = DefaultSettingsBuilder::default()
        .verbose(false)
        .build()
        .ok()?;
    let mut solver = DefaultSolver::new(&p, &q, &constraints, &rhs, &cones, settings).ok()?;
    solver.solve();
    let sol = &solver.solution;
    let solved = matches!(
        sol.status,
        SolverStatus::Solved | SolverStatus::AlmostSolved
    );
    (solved && sol.x[t] >= 0.0 && sol.x.iter().all(|v| v.is_finite())).then(|| sol.x[..m].to_vec())
}

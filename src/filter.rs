//! The ground-truth safety filter `v(x)` (DESIGN §1).
//!
//! ```text
//! v(x) = argmin_θ ½‖θ‖²
//!        s.t. ∇hᵢ(x)·(f̃(x) + g(x) θ) + aᵢ hᵢ(x) ≥ 0      i = 1..N   (CBF conditions)
//!             u_min ≤ κ(x) + θ ≤ u_max                             (input bounds)
//!             a(x)·θ ≤ b(x)                                         (further constraints)
//! ```
//!
//! Every constraint is a row `aₖ(x)·θ ≤ bₖ(x)`; a CBF gives `aₖ = −L_g h`, `bₖ = L_f̃ h + a·h`.
//! With one row the solution is the projection of 0 onto a half-space,
//! `v = min(0, b)/‖a‖² · a`, which is the paper's `max(0, −(L_f̃h + α(h)))/‖L_g h‖² · L_g hᵀ`;
//! with a scalar input it is 0 clamped to the interval the rows leave; otherwise clarabel
//! solves the QP. An empty feasible set is reported as [`FilterError::Infeasible`].

use clarabel::algebra::CscMatrix;
use clarabel::solver::{
    DefaultSettingsBuilder, DefaultSolver, IPSolver, SolverStatus, SupportedConeT,
};

use crate::scenario::Scenario;

/// Why `v(x)` could not be computed at a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// No `θ` satisfies the constraints at `x`.
    #[error("the filter's QP is infeasible at x = {x:?}: {reason}")]
    Infeasible {
        /// The state.
        x: Vec<f64>,
        /// Which constraints conflict, as far as known.
        reason: String,
    },
    /// A CBF's gradient (or a constraint) is not defined at `x`.
    #[error("{what} is not differentiable (or not defined) at x = {x:?}")]
    NotDifferentiable {
        /// The CBF or constraint.
        what: String,
        /// The state.
        x: Vec<f64>,
    },
    /// clarabel stopped without a solution.
    #[error("clarabel stopped with status {status} at x = {x:?}")]
    Solver {
        /// clarabel's status.
        status: String,
        /// The state.
        x: Vec<f64>,
    },
}

/// How `v(x)` is computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FilterMethod {
    /// One constraint row: projection onto a half-space.
    ClosedFormSingle,
    /// Scalar input: 0 clamped to the feasible interval.
    ClosedFormScalar,
    /// The general QP, by clarabel.
    Qp,
}

/// The constraint rows `G θ ≤ q` at one state.
#[derive(Clone, Debug)]
pub struct ConstraintRows {
    /// `G`, row-major, one row of m per constraint.
    pub g: Vec<f64>,
    /// `q`.
    pub q: Vec<f64>,
    /// A label per row for messages (`obstacle`, `u1 ≤ u_max`, …).
    pub labels: Vec<String>,
}

/// The filter `v(x)` of a scenario.
#[derive(Clone, Debug)]
pub struct SafetyFilter<'a> {
    scenario: &'a Scenario,
    method: FilterMethod,
}

/// Rows whose `‖aₖ‖²` is below this are treated as `θ`-free (`0 ≤ bₖ`).
const DEGENERATE_ROW: f64 = 1e-24;

impl<'a> SafetyFilter<'a> {
    /// The filter with the cheapest exact method for the scenario's structure.
    pub fn new(scenario: &'a Scenario) -> SafetyFilter<'a> {
        let rows = scenario.cbfs.len()
            + scenario.constraints.len()
            + 2 * scenario.input_bounds.as_ref().map_or(0, |_| scenario.m());
        let method = if rows == 1 {
            FilterMethod::ClosedFormSingle
        } else if scenario.m() == 1 {
            FilterMethod::ClosedFormScalar
        } else {
            FilterMethod::Qp
        };
        SafetyFilter { scenario, method }
    }

    /// The filter with a chosen method (a closed form is only valid for its structure; the QP
    /// always is). Used to cross-check the closed forms against clarabel.
    pub fn with_method(scenario: &'a Scenario, method: FilterMethod) -> SafetyFilter<'a> {
        SafetyFilter { scenario, method }
    }

    /// The method in use.
    pub fn method(&self) -> FilterMethod {
        self.method
    }

    /// The scenario.
    pub fn scenario(&self) -> &'a Scenario {
        self.scenario
    }

    /// The rows `G θ ≤ q` at `x`.
    pub fn constraint_rows(&self, x: &[f64]) -> Result<ConstraintRows, FilterError> {
        let s = self.scenario;
        let (n, m) = (s.n(), s.m());
        let f_tilde = s.f_tilde_at(x);
        let g = s.g_at(x);
        let kappa = s.kappa_at(x);
        let mut rows = ConstraintRows {
            g: Vec::new(),
            q: Vec::new(),
            labels: Vec::new(),
        };
        for cbf in &s.cbfs {
            let grad: Vec<f64> = cbf.gradient.iter().map(|e| e.eval(x)).collect();
            let h = cbf.h.eval(x);
            if !h.is_finite() || grad.iter().any(|v| !v.is_finite()) {
                return Err(FilterError::NotDifferentiable {
                    what: format!("CBF `{}`", cbf.name),
                    x: x.to_vec(),
                });
            }
            // aₖ = −L_g h = −∇hᵀ g,  bₖ = L_f̃ h + a·h.
            rows.g
                .extend((0..m).map(|j| -(0..n).map(|i| grad[i] * g[i * m + j]).sum::<f64>()));
            rows.q
                .push((0..n).map(|i| grad[i] * f_tilde[i]).sum::<f64>() + cbf.alpha * h);
            rows.labels.push(cbf.name.clone());
        }
        if let Some(bounds) = &s.input_bounds {
            for j in 0..m {
                let mut row = vec![0.0; m];
                row[j] = 1.0;
                rows.g.extend(&row);
                rows.q.push(bounds.upper[j] - kappa[j]);
                rows.labels
                    .push(format!("{} ≤ {}", s.inputs[j], bounds.upper[j]));
                row[j] = -1.0;
                rows.g.extend(&row);
                rows.q.push(kappa[j] - bounds.lower[j]);
                rows.labels
                    .push(format!("{} ≥ {}", s.inputs[j], bounds.lower[j]));
            }
        }
        for (k, c) in s.constraints.iter().enumerate() {
            rows.g.extend(c.a.iter().map(|e| e.eval(x)));
            rows.q.push(c.b.eval(x));
            rows.labels.push(format!("constraint[{k}]"));
        }
        if rows.g.iter().chain(&rows.q).any(|v| !v.is_finite()) {
            return Err(FilterError::NotDifferentiable {
                what: "a constraint".into(),
                x: x.to_vec(),
            });
        }
        Ok(rows)
    }

    /// `v(x)`.
    pub fn eval(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        let rows = self.constraint_rows(x)?;
        let m = self.scenario.m();
        match self.method {
            FilterMethod::ClosedFormSingle => project_half_space(&rows, m, x),
            FilterMethod::ClosedFormScalar => clamp_scalar(&rows, x),
            FilterMethod::Qp => solve_qp(&rows, m, x),
        }
    }

    /// The filtered vector field `F(x) = f̃(x) + g(x) v(x)`.
    pub fn closed_loop(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        let v = self.eval(x)?;
        Ok(self.closed_loop_with(x, &v))
    }

    /// `f̃(x) + g(x) θ` for a given input correction `θ`.
    pub fn closed_loop_with(&self, x: &[f64], theta: &[f64]) -> Vec<f64> {
        let s = self.scenario;
        let m = s.m();
        let g = s.g_at(x);
        s.f_tilde_at(x)
            .iter()
            .enumerate()
            .map(|(i, fi)| fi + (0..m).map(|j| g[i * m + j] * theta[j]).sum::<f64>())
            .collect()
    }

    /// The Jacobian `Dv(x)` (m×n, row-major) by central differences with step
    /// `ε·max(1, |xᵢ|)`, `ε = 1e-6`. `v` is piecewise smooth: across a switching surface of the
    /// active set the result mixes the two one-sided Jacobians.
    pub fn jacobian(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        central_jacobian(|y| self.eval(y), x, self.scenario.m(), pointwise_step)
    }

    /// Secant slopes `(v(x + hⱼeⱼ) − v(x − hⱼeⱼ)) / 2hⱼ` (m×n, row-major), `h` one step or one
    /// per state: the mean slope of `v` over `[xⱼ − hⱼ, xⱼ + hⱼ]`. Where `v` has a kink
    /// between two training points, the pointwise slopes on either side cannot both be met by
    /// a network that bends anywhere between them; their secants can.
    pub fn secant_jacobian(&self, x: &[f64], h: &[f64]) -> Result<Vec<f64>, FilterError> {
        central_jacobian(
            |y| self.eval(y),
            x,
            self.scenario.m(),
            |j, _| h[j.min(h.len() - 1)],
        )
    }

    /// The curvature `‖D²v(x)‖_F` (all second derivatives of all outputs) by central
    /// differences of [`Self::jacobian`] with step `10⁻⁴·max(1, |xᵢ|)`. Where the active set
    /// switches within a step, `v` has a kink and this is about the jump of `Dv` over twice
    /// the step: large, as the curvature of a kink is.
    pub fn curvature(&self, x: &[f64]) -> Result<f64, FilterError> {
        let mn = self.scenario.m() * x.len();
        let d2v = central_jacobian(
            |y| self.jacobian(y),
            x,
            mn,
            |_, xj| 1e-4 * xj.abs().max(1.0),
        )?;
        Ok(d2v.iter().map(|d| d * d).sum::<f64>().sqrt())
    }

    /// The Jacobian `DF(x)` (n×n, row-major) of the filtered vector field.
    pub fn closed_loop_jacobian(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        central_jacobian(
            |y| self.closed_loop(y),
            x,
            self.scenario.n(),
            pointwise_step,
        )
    }
}

/// The step of a pointwise central difference along axis `j` at `xⱼ`.
fn pointwise_step(_j: usize, xj: f64) -> f64 {
    1e-6 * xj.abs().max(1.0)
}

/// Central-difference Jacobian of `map: ℝⁿ → ℝᵏ`, row-major k×n, with step `step(j, xⱼ)`.
fn central_jacobian(
    map: impl Fn(&[f64]) -> Result<Vec<f64>, FilterError>,
    x: &[f64],
    k: usize,
    step: impl Fn(usize, f64) -> f64,
) -> Result<Vec<f64>, FilterError> {
    let n = x.len();
    let mut jac = vec![0.0; k * n];
    let mut y = x.to_vec();
    for j in 0..n {
        let step = step(j, x[j]);
        y[j] = x[j] + step;
        let plus = map(&y)?;
        y[j] = x[j] - step;
        let minus = map(&y)?;
        y[j] = x[j];
        for i in 0..k {
            jac[i * n + j] = (plus[i] - minus[i]) / (2.0 * step);
        }
    }
    Ok(jac)
}

/// One row `a·θ ≤ b`: `θ = 0` when `b ≥ 0`, else the projection `b a / ‖a‖²`.
fn project_half_space(rows: &ConstraintRows, m: usize, x: &[f64]) -> Result<Vec<f64>, FilterError> {
    let a = &rows.g[..m];
    let b = rows.q[0];
    if b >= 0.0 {
        return Ok(vec![0.0; m]);
    }
    let norm2: f64 = a.iter().map(|v| v * v).sum();
    if norm2 <= DEGENERATE_ROW {
        return Err(FilterError::Infeasible {
            x: x.to_vec(),
            reason: format!(
                "`{}` needs {b:.3e} ≥ 0 but the input cannot act on it (L_g h = 0)",
                rows.labels[0]
            ),
        });
    }
    Ok(a.iter().map(|ai| b * ai / norm2).collect())
}

/// Scalar input: each row bounds `θ` from one side; `θ = clamp(0, lo, hi)`.
fn clamp_scalar(rows: &ConstraintRows, x: &[f64]) -> Result<Vec<f64>, FilterError> {
    let (mut lo, mut hi) = (f64::NEG_INFINITY, f64::INFINITY);
    let (mut lo_label, mut hi_label) = ("", "");
    for ((&a, &b), label) in rows.g.iter().zip(&rows.q).zip(&rows.labels) {
        if a * a <= DEGENERATE_ROW {
            if b < 0.0 {
                return Err(FilterError::Infeasible {
                    x: x.to_vec(),
                    reason: format!("`{label}` needs {b:.3e} ≥ 0 but the input cannot act on it"),
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
        return Err(FilterError::Infeasible {
            x: x.to_vec(),
            reason: format!("`{lo_label}` needs θ ≥ {lo:.6} but `{hi_label}` needs θ ≤ {hi:.6}"),
        });
    }
    Ok(vec![0.0_f64.clamp(lo, hi)])
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

/// The general QP `min ½‖θ‖² s.t. G θ ≤ q` by clarabel.
fn solve_qp(rows: &ConstraintRows, m: usize, x: &[f64]) -> Result<Vec<f64>, FilterError> {
    let k = rows.q.len();
    if k == 0 {
        return Ok(vec![0.0; m]);
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
            Ok(polish(rows, m, &sol.x, &sol.z).unwrap_or_else(|| sol.x.clone()))
        }
        SolverStatus::PrimalInfeasible | SolverStatus::AlmostPrimalInfeasible => {
            Err(FilterError::Infeasible {
                x: x.to_vec(),
                reason: format!(
                    "clarabel certifies that {} are incompatible",
                    rows.labels.join(", ")
                ),
            })
        }
        status => Err(FilterError::Solver {
            status: format!("{status:?}"),
            x: x.to_vec(),
        }),
    }
}

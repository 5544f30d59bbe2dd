//! The ground-truth safety filter `v(x)` (docs/design.md §1): its constraint rows, its exact solution
//! (closed forms or clarabel, infeasibility as a [`FilterStatus`]) and enclosures of `v` over
//! boxes ([`VForms`], [`v_enclosure`]). It may import the scenario, expressions, intervals and
//! boxes (and clarabel, nalgebra); not the network, its bounds, the engines or the error analysis.
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
//! solves the QP. An empty feasible set is the status [`FilterStatus::Infeasible`] of
//! [`SafetyFilter::solve`], and [`FilterError::Infeasible`] where a value of `v` is needed.

mod active_sets;
mod enclosures;
mod feasibility;
mod findings;
mod rows;
mod solve;

use std::fmt;

use crate::scenario::Scenario;

pub use active_sets::{natural_qp_enclosure, QpCell, QpForms, MAX_ACTIVE, MAX_SETS};
pub use enclosures::{
    v_enclosure, FilterPiece, Kink, Lattice, Smooth, SmoothV, VFormParts, VForms, VShape,
};
pub use findings::{
    findings, inert_cbfs, FilterFindings, Inert, Vanishing, SAMPLE_POINTS, VANISHING,
};
pub use rows::{interval_rows, row_expressions};

pub(crate) use enclosures::meet;

/// Why `v(x)` could not be computed at a point.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FilterError {
    /// No `θ` satisfies the constraints at `x`.
    #[error("the filter's QP is infeasible at x = {x:?}: {reason}")]
    Infeasible {
        /// The state.
        x: Vec<f64>,
        /// Which constraints conflict, as far as known.
        reason: Infeasibility,
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

/// The outcome of solving the filter's QP at one point. As with clarabel's `SolverStatus`, an
/// empty feasible set is an answer about the problem, not a failure of the solver.
#[derive(Debug, Clone, PartialEq)]
pub enum FilterStatus {
    /// The minimiser `θ = v(x)`.
    Solved(Vec<f64>),
    /// No `θ` satisfies the constraints.
    Infeasible(Infeasibility),
}

/// Which constraints leave no `θ`, as far as the method that found it knows.
#[derive(Debug, Clone, PartialEq)]
pub enum Infeasibility {
    /// The single row needs `b ≥ 0` but its `a = −L_g h` vanishes: no input acts on it.
    NoInputOnRow {
        /// The row's label.
        row: String,
        /// Its `b` (negative).
        b: f64,
    },
    /// A row of a scalar-input filter needs `b ≥ 0` but its `a` vanishes.
    NoInput {
        /// The row's label.
        row: String,
        /// Its `b` (negative).
        b: f64,
    },
    /// Two rows of a scalar-input filter bound `θ` past each other: `lower > upper`.
    Conflict {
        /// The row that needs `θ ≥ lower`.
        lower_row: String,
        /// Its bound.
        lower: f64,
        /// The row that needs `θ ≤ upper`.
        upper_row: String,
        /// Its bound.
        upper: f64,
        /// The input's name: the message speaks of `u = κ(x) + θ`, since `θ` reads as a
        /// state in systems that have one so named (a pendulum's angle).
        input: String,
        /// `κ(x)`.
        kappa: f64,
    },
    /// clarabel certifies that the rows (all of them, by label) have no common point.
    Incompatible {
        /// Every row's label.
        rows: Vec<String>,
    },
}

impl fmt::Display for Infeasibility {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Infeasibility::NoInputOnRow { row, b } => write!(
                f,
                "`{row}` needs {b:.3e} ≥ 0 but the input cannot act on it (L_g h = 0)"
            ),
            Infeasibility::NoInput { row, b } => {
                write!(
                    f,
                    "`{row}` needs {b:.3e} ≥ 0 but the input cannot act on it"
                )
            }
            Infeasibility::Conflict {
                lower_row,
                lower,
                upper_row,
                upper,
                input,
                kappa,
            } => write!(
                f,
                "`{lower_row}` needs {input} ≥ {:.6} but `{upper_row}` needs {input} ≤ {:.6}",
                kappa + lower,
                kappa + upper
            ),
            Infeasibility::Incompatible { rows } => write!(
                f,
                "clarabel certifies that {} are incompatible",
                rows.join(", ")
            ),
        }
    }
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

impl fmt::Display for FilterMethod {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            FilterMethod::ClosedFormSingle => {
                "closed form (v projects 0 onto the row's half-space)"
            }
            FilterMethod::ClosedFormScalar => {
                "closed form (scalar input: v is 0 clamped to the interval the rows leave)"
            }
            FilterMethod::Qp => "QP (its active sets, clarabel where they do not settle it)",
        })
    }
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
    /// `κ(x)`, for messages in the inputs `u = κ(x) + θ`.
    pub kappa: Vec<f64>,
}

/// The filter `v(x)` of a scenario.
#[derive(Clone, Debug)]
pub struct SafetyFilter<'a> {
    scenario: &'a Scenario,
    method: FilterMethod,
    /// [`SafetyFilter::field_on_trajectories`]'s rows, found on first use.
    kept_inert: std::sync::OnceLock<Vec<usize>>,
}

impl<'a> SafetyFilter<'a> {
    /// The filter with the cheapest exact method for the scenario's structure.
    pub fn new(scenario: &'a Scenario) -> SafetyFilter<'a> {
        let method = if Self::rows_of(scenario) == 1 {
            FilterMethod::ClosedFormSingle
        } else if scenario.m() == 1 {
            FilterMethod::ClosedFormScalar
        } else {
            FilterMethod::Qp
        };
        SafetyFilter {
            scenario,
            method,
            kept_inert: Default::default(),
        }
    }

    /// The filter with a chosen method (a closed form is only valid for its structure; the QP
    /// always is). Used to cross-check the closed forms against clarabel.
    pub fn with_method(scenario: &'a Scenario, method: FilterMethod) -> SafetyFilter<'a> {
        SafetyFilter {
            scenario,
            method,
            kept_inert: Default::default(),
        }
    }

    /// The number of constraint rows: one per CBF and further constraint, two per input with
    /// bounds.
    pub fn rows(&self) -> usize {
        Self::rows_of(self.scenario)
    }

    fn rows_of(s: &Scenario) -> usize {
        s.cbfs.len() + s.constraints.len() + 2 * s.input_bounds.as_ref().map_or(0, |_| s.m())
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
            kappa: kappa.clone(),
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
            // aₖ = −L_g h = −∇hᵀ g,  bₖ = L_f̃ h + α(h).
            rows.g
                .extend((0..m).map(|j| -(0..n).map(|i| grad[i] * g[i * m + j]).sum::<f64>()));
            rows.q
                .push((0..n).map(|i| grad[i] * f_tilde[i]).sum::<f64>() + cbf.alpha.at(h));
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

    /// The filter's QP at `x`: solved, or infeasible (and which rows conflict). An error only
    /// when the rows cannot be evaluated or clarabel fails.
    pub fn solve(&self, x: &[f64]) -> Result<FilterStatus, FilterError> {
        self.solve_rows(&self.constraint_rows(x)?, x)
    }

    /// [`SafetyFilter::solve`] with the rows at `x` already evaluated.
    fn solve_rows(&self, rows: &ConstraintRows, x: &[f64]) -> Result<FilterStatus, FilterError> {
        let m = self.scenario.m();
        Ok(match self.method {
            FilterMethod::ClosedFormSingle => solve::project_half_space(rows, m),
            FilterMethod::ClosedFormScalar => solve::clamp_scalar(rows, &self.scenario.inputs[0]),
            FilterMethod::Qp => match solve::solve_by_active_sets(rows, m) {
                Some(theta) => FilterStatus::Solved(theta),
                None => solve::solve_qp(rows, m, x)?,
            },
        })
    }

    /// The QP at `x` by clarabel alone (polished), whatever the method: an independent check
    /// of the closed forms, the active-set enumeration and the enclosures.
    pub fn solve_with_clarabel(&self, x: &[f64]) -> Result<FilterStatus, FilterError> {
        let rows = self.constraint_rows(x)?;
        solve::solve_qp(&rows, self.scenario.m(), x)
    }

    /// `v(x)`; an infeasible QP is [`FilterError::Infeasible`] here.
    pub fn eval(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        match self.solve(x)? {
            FilterStatus::Solved(v) => Ok(v),
            FilterStatus::Infeasible(reason) => Err(FilterError::Infeasible {
                x: x.to_vec(),
                reason,
            }),
        }
    }

    /// The filtered vector field `F(x) = f̃(x) + g(x) v(x)`.
    pub fn closed_loop(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        let v = self.eval(x)?;
        Ok(self.closed_loop_with(x, &v))
    }

    /// The filtered vector field for integrating a trajectory that starts where the QP is
    /// feasible: [`Self::closed_loop`], except where the QP is infeasible only by a row no
    /// input acts on that another CBF keeps (a high-order CBF written out, [`inert_cbfs`]).
    /// That row asks `ψ ≥ 0`, which the other CBF's row keeps along the ODE's trajectory; a
    /// numerical integrator sliding along `ψ = 0` errs across it (RK4's stages, at dt = 0.05 on
    /// a 6-state double integrator by 5·10⁻⁵), where the QP would end the trajectory. There the
    /// row is taken as slack, as every enclosure of `v` takes it (design §1).
    pub fn field_on_trajectories(&self, x: &[f64]) -> Result<Vec<f64>, FilterError> {
        // The rows are found on the first infeasible QP, not on every filter's first call.
        let kept = || {
            self.kept_inert.get_or_init(|| {
                inert_cbfs(self.scenario)
                    .into_iter()
                    .filter(|i| i.kept_by.is_some())
                    .map(|i| i.index)
                    .collect()
            })
        };
        match self.closed_loop(x) {
            Err(FilterError::Infeasible { .. }) if !kept().is_empty() => {
                // The CBFs' rows come first, in order.
                let mut rows = self.constraint_rows(x)?;
                for &k in kept() {
                    rows.q[k] = rows.q[k].max(0.0);
                }
                match self.solve_rows(&rows, x)? {
                    FilterStatus::Solved(v) => Ok(self.closed_loop_with(x, &v)),
                    FilterStatus::Infeasible(reason) => Err(FilterError::Infeasible {
                        x: x.to_vec(),
                        reason,
                    }),
                }
            }
            field => field,
        }
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

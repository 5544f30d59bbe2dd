//! Coordinates `z = T x` for the embedding (docs/design.md §2b, the wrapping effect).
//!
//! In scenario 2's x coordinates boxes cannot shrink; in coordinates where the closed loop's
//! linear part contracts in ℓ∞ they can. Sets are then parallelotopes `S·[z̲, z̄]` in x.
//!
//! Floating point: the change of variables is *defined* by the f64 matrix `S` (`x = S z`
//! exactly); `T ≈ S⁻¹` is only approximate. With `R = I − T S` and `‖R‖∞ < 1`,
//! `S⁻¹ y = T y + e`, `‖e‖∞ ≤ ρ ‖T y‖∞`, `ρ = ‖R‖/(1 − ‖R‖)` (Neumann series), all computed
//! in interval arithmetic. Every place that uses `T` for `S⁻¹` widens by that `ρ` term:
//! boxes mapped to z ([`Transform::to_z_box`]) and the vector field `ż = S⁻¹F(Sz)`
//! (the slack of [`Transform::field_slack`]). The network's first layer absorbs `S`
//! (`W₁S`, rounded); its rounding error is bounded in [`Transform::network`].

use nalgebra::{DMatrix, DVector};

use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::filter::{FilterError, SafetyFilter};
use crate::intervals::{box_of, Interval};
use crate::network::Mlp;
use crate::rounding::round_up;
use crate::scenario::{Scenario, TransformChoice};

mod contracting;

pub(in crate::reach) use contracting::schur_blocks;
use contracting::{contracting_matrix, decoupled_parts};

/// Why a transform could not be built.
#[derive(Debug, thiserror::Error)]
pub enum TransformError {
    /// `T` does not hold n×n finite numbers.
    #[error("expected {n}×{n} finite numbers")]
    Shape {
        /// The state dimension.
        n: usize,
    },
    /// `T` has no inverse.
    #[error("the matrix is singular")]
    Singular,
    /// The computed inverse is too far from `T`'s for the coordinates to be sound.
    #[error("the matrix is too ill-conditioned (‖I − TS‖ = {r_norm:.2e})")]
    IllConditioned {
        /// `‖I − TS‖∞`, bounded above.
        r_norm: f64,
    },
    /// A 0×0 system.
    #[error("empty matrix")]
    Empty,
    /// `AᵀP + PA = −I` has no unique solution.
    #[error("A has eigenvalues λᵢ + λⱼ = 0: no Lyapunov function")]
    NoLyapunovFunction,
    /// `A` is not Hurwitz.
    #[error("the closed loop is not stable at the goal (P is not positive definite)")]
    NotStable,
    /// Turned frames were asked of coordinates in which nothing turns.
    #[error("no complex pair of the closed loop's eigenvalues turns in these coordinates")]
    NoPair,
    /// The closed loop's Jacobian at the goal could not be evaluated.
    #[error(transparent)]
    ClosedLoop(#[from] FilterError),
    /// A scenario's `reach.transform` could not be built.
    #[error("{file}: reach.transform{}: {source}", choice_text(.choice))]
    InScenario {
        /// The scenario file.
        file: String,
        /// The choice: `matrix` (given as numbers), `lyapunov` or `auto`.
        choice: &'static str,
        /// Why.
        #[source]
        source: Box<TransformError>,
    },
}

/// ` = "auto"` after `reach.transform` for a named choice; nothing for a matrix.
fn choice_text(choice: &str) -> String {
    match choice {
        "matrix" => String::new(),
        named => format!(" = \"{named}\""),
    }
}

/// `μ∞(A) = maxᵢ (aᵢᵢ + Σ_{j≠i} |aᵢⱼ|)`, the ℓ∞ logarithmic norm of an n×n row-major matrix:
/// negative when `ẋ = Ax` contracts boxes.
pub fn log_norm_inf(a: &[f64], n: usize) -> f64 {
    (0..n)
        .map(|i| {
            a[i * n + i]
                + (0..n)
                    .filter(|&j| j != i)
                    .map(|j| a[i * n + j].abs())
                    .sum::<f64>()
        })
        .fold(f64::NEG_INFINITY, f64::max)
}

/// Why [`Transform::chosen`] picked the coordinates it did (printed by the command line).
#[derive(Clone, Debug, PartialEq)]
pub enum CoordinatesReason {
    /// The closed loop at the goal contracts in ℓ∞ in x: x itself.
    ContractsInX {
        /// `μ∞(A)` in x (< 0).
        mu_x: f64,
    },
    /// It does not: the `auto` coordinates, in which it does.
    NotContractingInX {
        /// `μ∞(A)` in x (≥ 0).
        mu_x: f64,
        /// `μ∞(TAS)` in z.
        mu_z: f64,
    },
    /// It does not, and no `auto` coordinates could be built: x itself.
    AutoUnavailable {
        /// `μ∞(A)` in x.
        mu_x: f64,
        /// Why `auto` failed.
        why: String,
    },
    /// The closed loop could not be linearised at the goal (e.g. the QP is infeasible there):
    /// x itself.
    NoLinearisation {
        /// Why.
        why: String,
    },
}

impl std::fmt::Display for CoordinatesReason {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            CoordinatesReason::ContractsInX { mu_x } => write!(
                f,
                "x itself: the closed loop at the goal contracts in ℓ∞ in x (μ∞(A) = {mu_x:.3} < 0)"
            ),
            CoordinatesReason::NotContractingInX { mu_x, mu_z } => write!(
                f,
                "z = T x (\"auto\"): the closed loop at the goal is not contracting in ℓ∞ in x \
                 (μ∞(A) = {mu_x:.3} ≥ 0), so boxes in x cannot shrink; in z, μ∞ = {mu_z:.3}"
            ),
            CoordinatesReason::AutoUnavailable { mu_x, why } => write!(
                f,
                "x itself, though the closed loop at the goal is not contracting in ℓ∞ in x \
                 (μ∞(A) = {mu_x:.3} ≥ 0): no contracting coordinates ({why})"
            ),
            CoordinatesReason::NoLinearisation { why } => write!(
                f,
                "x itself: the closed loop could not be linearised at the goal ({why})"
            ),
        }
    }
}

/// A change of coordinates `z = T x`, `x = S z`.
#[derive(Clone, Debug, PartialEq)]
pub struct Transform {
    /// State dimension.
    pub n: usize,
    /// `T`, n×n row-major.
    pub t: Vec<f64>,
    /// `S = T⁻¹` as computed, n×n row-major; it defines the coordinates exactly.
    pub s: Vec<f64>,
    /// `ρ`: `‖S⁻¹y − Ty‖∞ ≤ ρ‖Ty‖∞`.
    pub rho: f64,
}

fn ip(x: f64) -> Interval {
    Interval::point(x)
}

/// `[M]·[v]` for an f64 matrix and an interval vector.
fn mat_vec(m: &[f64], v: &[Interval], n: usize) -> Vec<Interval> {
    (0..n)
        .map(|i| (0..n).fold(ip(0.0), |acc, j| acc + ip(m[i * n + j]) * v[j]))
        .collect()
}

impl Transform {
    /// The transform with the given `T` (n×n, row-major); an error if `T` is not safely
    /// invertible.
    pub fn from_matrix(t: Vec<f64>, n: usize) -> Result<Transform, TransformError> {
        if t.len() != n * n || t.iter().any(|v| !v.is_finite()) {
            return Err(TransformError::Shape { n });
        }
        let inv = DMatrix::from_row_slice(n, n, &t)
            .try_inverse()
            .ok_or(TransformError::Singular)?;
        let s: Vec<f64> = (0..n * n).map(|k| inv[(k / n, k % n)]).collect();
        Transform::with_inverse(t, s, n)
    }

    /// The transform `T` (n×n, row-major) with `S` as its inverse, which need not be exact:
    /// `ρ` bounds what `S` misses (an error if it misses by half or more).
    pub fn with_inverse(t: Vec<f64>, s: Vec<f64>, n: usize) -> Result<Transform, TransformError> {
        if t.len() != n * n || s.len() != n * n || t.iter().chain(&s).any(|v| !v.is_finite()) {
            return Err(TransformError::Shape { n });
        }
        // R = I − T S in interval arithmetic; ρ = ‖R‖/(1 − ‖R‖).
        let r_norm = (0..n)
            .map(|i| {
                (0..n)
                    .fold(ip(0.0), |acc, j| {
                        let ts =
                            (0..n).fold(ip(0.0), |a, k| a + ip(t[i * n + k]) * ip(s[k * n + j]));
                        acc + ip((ip(if i == j { 1.0 } else { 0.0 }) - ts).mag())
                    })
                    .upper
            })
            .fold(0.0, f64::max);
        if r_norm >= 0.5 {
            return Err(TransformError::IllConditioned { r_norm });
        }
        let rho = (ip(r_norm) / (ip(1.0) - ip(r_norm))).upper;
        Ok(Transform { n, t, s, rho })
    }

    /// The identity.
    pub fn identity(n: usize) -> Transform {
        let t: Vec<f64> = (0..n * n)
            .map(|k| if k / n == k % n { 1.0 } else { 0.0 })
            .collect();
        Transform {
            n,
            s: t.clone(),
            t,
            rho: 0.0,
        }
    }

    /// Coordinates in which `A` (the closed loop's linearisation at the goal) contracts in ℓ∞
    /// as far as a real Schur form allows: `A = Q U Qᵀ`; each 2 × 2 block of a complex pair
    /// `α ± iβ` is brought to `[[α, β], [−β, α]]` by its own `P` (in ℓ∞ a rotation's best
    /// rate, `α + |β|`); then `T = D⁻¹ W⁻¹ Qᵀ`, `W = diag(P, 1, …)` and `D = diag(δ⁰, δ¹, …)`
    /// (one power a block) shrinking the coupling between blocks until `μ∞(TAT⁻¹)` is within
    /// half of the slowest block's rate, or the smallest `μ∞` the halvings of `δ` found.
    pub fn contracting(a: &[f64], n: usize) -> Result<Transform, TransformError> {
        if n == 0 {
            return Err(TransformError::Empty);
        }
        let parts = decoupled_parts(a, n);
        if parts.len() == 1 {
            return Transform::from_matrix(contracting_matrix(a, n)?, n);
        }
        // Parts of the state that do not act on each other (three axes of a double integrator)
        // get coordinates of their own: one Schur form of all of `A` mixes parts that share an
        // eigenvalue, and the scaling then multiplies the mixing up (entries of 2·10⁴ in six
        // states, against 2.8 for each axis alone).
        let mut t = vec![0.0; n * n];
        let mut row = 0;
        for part in &parts {
            let k = part.len();
            let sub: Vec<f64> = part
                .iter()
                .flat_map(|&i| part.iter().map(move |&j| a[i * n + j]))
                .collect();
            let tp = contracting_matrix(&sub, k)?;
            for r in 0..k {
                for (c, &j) in part.iter().enumerate() {
                    t[(row + r) * n + j] = tp[r * k + c];
                }
            }
            row += k;
        }
        Transform::from_matrix(t, n)
    }

    /// The weighted-ℓ2 coordinates of a quadratic Lyapunov function of `A` (the closed loop's
    /// linearisation at the goal): `P` solves `AᵀP + PA = −I`, `T = P^{1/2}`, so that
    /// `‖z‖₂ = ‖x‖_P` and `μ₂(TAT⁻¹) = −1/(2λ_max(P)) < 0`. With `norm = "2"` the Minkowski
    /// method's radius is then the paper's radius in `‖·‖_P`. Refused unless `A` is Hurwitz.
    pub fn lyapunov(a: &[f64], n: usize) -> Result<Transform, TransformError> {
        let am = DMatrix::from_row_slice(n, n, a);
        // vec(AᵀP + PA) = (I ⊗ Aᵀ + Aᵀ ⊗ I) vec(P), column-major vec.
        let at = am.transpose();
        let eye = DMatrix::<f64>::identity(n, n);
        let k = eye.kronecker(&at) + at.kronecker(&eye);
        let rhs = DVector::from_iterator(
            n * n,
            (0..n * n).map(|i| if i % (n + 1) == 0 { -1.0 } else { 0.0 }),
        );
        let vec_p = k
            .lu()
            .solve(&rhs)
            .ok_or(TransformError::NoLyapunovFunction)?;
        let p = DMatrix::from_column_slice(n, n, vec_p.as_slice());
        let p = (&p + p.transpose()) * 0.5;
        let eig = p.clone().symmetric_eigen();
        if eig.eigenvalues.iter().any(|l| l.is_nan() || *l <= 0.0) {
            return Err(TransformError::NotStable);
        }
        let sqrt = &eig.eigenvectors
            * DMatrix::from_diagonal(&eig.eigenvalues.map(f64::sqrt))
            * eig.eigenvectors.transpose();
        Transform::from_matrix((0..n * n).map(|k| sqrt[(k / n, k % n)]).collect(), n)
    }

    /// The transform a scenario asks for: `None` for x itself, `auto` from the filtered closed
    /// loop's Jacobian at the goal's centre (the filter is usually inactive there, so this is
    /// `Df̃`).
    pub fn for_scenario(
        scenario: &Scenario,
        choice: &TransformChoice,
    ) -> Result<Option<Transform>, TransformError> {
        let n = scenario.n();
        let closed_loop = || {
            let goal = scenario.reach.goal.center();
            SafetyFilter::new(scenario).closed_loop_jacobian(&goal)
        };
        let (name, built) = match choice {
            TransformChoice::Identity => return Ok(None),
            TransformChoice::Chosen => return Ok(Transform::chosen(scenario).0),
            TransformChoice::Matrix(t) => ("matrix", Transform::from_matrix(t.clone(), n)),
            TransformChoice::Lyapunov => (
                "lyapunov",
                closed_loop()
                    .map_err(TransformError::from)
                    .and_then(|a| Transform::lyapunov(&a, n)),
            ),
            TransformChoice::Auto => (
                "auto",
                closed_loop()
                    .map_err(TransformError::from)
                    .and_then(|a| Transform::contracting(&a, n)),
            ),
        };
        built.map(Some).map_err(|e| TransformError::InScenario {
            file: scenario.file.clone(),
            choice: name,
            source: Box::new(e),
        })
    }

    /// The coordinates cbfreach picks when the scenario leaves them open, and why: x itself
    /// where the closed loop's linearisation `A` at the goal's centre contracts in ℓ∞
    /// (`μ∞(A) < 0`: boxes in x can shrink), else [`Transform::contracting`]'s coordinates,
    /// where boxes can shrink (docs/design.md §2b). Either is sound; this is about tightness.
    pub fn chosen(scenario: &Scenario) -> (Option<Transform>, CoordinatesReason) {
        let n = scenario.n();
        let goal = scenario.reach.goal.center();
        let a = match SafetyFilter::new(scenario).closed_loop_jacobian(&goal) {
            Ok(a) => a,
            Err(e) => {
                return (
                    None,
                    CoordinatesReason::NoLinearisation { why: e.to_string() },
                )
            }
        };
        let mu_x = log_norm_inf(&a, n);
        if mu_x < 0.0 {
            return (None, CoordinatesReason::ContractsInX { mu_x });
        }
        match Transform::contracting(&a, n) {
            Ok(t) => {
                let mu_z = log_norm_inf(&t.conjugate(&a), n);
                match mu_z < mu_x {
                    true => (Some(t), CoordinatesReason::NotContractingInX { mu_x, mu_z }),
                    false => (
                        None,
                        CoordinatesReason::AutoUnavailable {
                            mu_x,
                            why: format!("the best found, μ∞ = {mu_z:.3} in z, is no better"),
                        },
                    ),
                }
            }
            Err(e) => (
                None,
                CoordinatesReason::AutoUnavailable {
                    mu_x,
                    why: e.to_string(),
                },
            ),
        }
    }

    /// `T A S`: a matrix in x's coordinates written in z's.
    pub fn conjugate(&self, a: &[f64]) -> Vec<f64> {
        let n = self.n;
        let at = |m: &[f64], i: usize, j: usize| m[i * n + j];
        let as_: Vec<f64> = (0..n * n)
            .map(|k| {
                (0..n)
                    .map(|l| at(a, k / n, l) * at(&self.s, l, k % n))
                    .sum()
            })
            .collect();
        (0..n * n)
            .map(|k| {
                (0..n)
                    .map(|l| at(&self.t, k / n, l) * at(&as_, l, k % n))
                    .sum()
            })
            .collect()
    }

    /// A sound z-box of `S⁻¹·X`.
    pub fn to_z_box(&self, x: &IntervalBox) -> IntervalBox {
        let z = self.t_times(x);
        let pad = self.pad(&z);
        IntervalBox {
            lower: z.iter().map(|v| (ip(v.lower) - ip(pad)).lower).collect(),
            upper: z.iter().map(|v| (ip(v.upper) + ip(pad)).upper).collect(),
        }
    }

    /// `ρ‖T x‖∞` over the x-box `x`, rounded up: by how much `T x` may miss `S⁻¹x` in each
    /// coordinate there.
    pub fn pad_over(&self, x: &IntervalBox) -> f64 {
        self.pad(&self.t_times(x))
    }

    /// `[T]·[x]` over an x-box.
    fn t_times(&self, x: &IntervalBox) -> Vec<Interval> {
        mat_vec(&self.t, &box_of(&x.lower, &x.upper), self.n)
    }

    /// `ρ‖z‖∞` for `z = T x`, rounded up.
    fn pad(&self, z: &[Interval]) -> f64 {
        let size = z.iter().fold(0.0_f64, |a, v| a.max(v.mag()));
        round_up((ip(self.rho) * ip(size)).upper)
    }

    /// The bounding box of the parallelotope `S·[z̲, z̄]`.
    pub fn to_x_box(&self, lower: &[f64], upper: &[f64]) -> IntervalBox {
        let zi: Vec<Interval> = (0..self.n)
            .map(|i| Interval::new(lower[i], upper[i]))
            .collect();
        let x = mat_vec(&self.s, &zi, self.n);
        IntervalBox {
            lower: x.iter().map(|v| v.lower).collect(),
            upper: x.iter().map(|v| v.upper).collect(),
        }
    }

    /// `e ↦ e(S z)`: an expression in x rewritten in z.
    fn in_z(&self, e: &Expr) -> Expr {
        let x_of_z: Vec<Expr> = (0..self.n)
            .map(|i| {
                (0..self.n).fold(Expr::constant(0.0), |acc, j| {
                    acc + Expr::constant(self.s[i * self.n + j]) * Expr::variable(j)
                })
            })
            .collect();
        e.substitute(&x_of_z)
    }

    /// `T·v(Sz)` for a vector of expressions in x (n of them, or the columns of an n×m matrix).
    pub fn vector_field(&self, v: &[Expr]) -> Vec<Expr> {
        let vz: Vec<Expr> = v.iter().map(|e| self.in_z(e)).collect();
        (0..self.n)
            .map(|i| {
                (0..self.n).fold(Expr::constant(0.0), |acc, k| {
                    acc + Expr::constant(self.t[i * self.n + k]) * vz[k].clone()
                })
            })
            .collect()
    }

    /// `T·g(Sz)`, n×m.
    pub fn input_matrix(&self, g: &[Vec<Expr>]) -> Vec<Vec<Expr>> {
        let m = g.first().map_or(0, Vec::len);
        let columns: Vec<Vec<Expr>> = (0..m)
            .map(|k| self.vector_field(&g.iter().map(|row| row[k].clone()).collect::<Vec<_>>()))
            .collect();
        (0..self.n)
            .map(|i| (0..m).map(|k| columns[k][i].clone()).collect())
            .collect()
    }

    /// A bound on `‖S⁻¹F − TF‖∞` given `‖F‖∞ ≤ f_max` on `C`: the slack added to each side of
    /// the embedding's derivative bounds.
    pub fn field_slack(&self, f_max: f64) -> f64 {
        let t_norm = (0..self.n)
            .map(|i| {
                (0..self.n)
                    .fold(ip(0.0), |a, j| a + ip(self.t[i * self.n + j].abs()))
                    .upper
            })
            .fold(0.0, f64::max);
        round_up((ip(self.rho) * ip(t_norm) * ip(f_max)).upper)
    }

    /// The network in z coordinates, `N(S z)`, with `W₁S` rounded, and a bound on
    /// `|N(Sz) − N_z(z)|` over `|z| ≤ z_max` from that rounding: `γ_n·(|W₁||S| z_max)`
    /// carried through the remaining layers by their ∞-norms (ReLU is 1-Lipschitz).
    pub fn network(&self, net: &Mlp, z_max: f64) -> (Mlp, f64) {
        let mut out = net.clone();
        let Some(first) = out.layers.first_mut() else {
            return (out, 0.0);
        };
        let n = self.n;
        let w = first.weight.clone();
        let mut err = 0.0_f64;
        for r in 0..first.n_out {
            let mut row_err = ip(0.0);
            for j in 0..n {
                let exact_ish =
                    (0..n).fold(ip(0.0), |a, k| a + ip(w[r * n + k]) * ip(self.s[k * n + j]));
                let value: f64 = (0..n).map(|k| w[r * n + k] * self.s[k * n + j]).sum();
                first.weight[r * n + j] = value;
                // |value − Σ W S| ≤ width of the enclosure around it.
                let e = (exact_ish - ip(value)).mag();
                row_err = row_err + ip(e) * ip(z_max);
            }
            err = err.max(row_err.upper);
        }
        let lipschitz = net.layers[1..].iter().fold(ip(1.0), |acc, l| {
            let norm = (0..l.n_out)
                .map(|r| {
                    (0..l.n_in)
                        .fold(ip(0.0), |a, c| a + ip(l.weight[r * l.n_in + c].abs()))
                        .upper
                })
                .fold(0.0, f64::max);
            acc * ip(norm)
        });
        (out, round_up((ip(err) * lipschitz).upper))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// `T = P^{1/2}` solves the Lyapunov equation and makes `A` contract in ℓ2: checked on the
    /// double integrator's closed loop (which does not contract in x, `μ₂ > 0`) and a skewed rotation.
    #[test]
    fn lyapunov_coordinates_contract_in_l2() {
        let mu2 = |m: &DMatrix<f64>| (m + m.transpose()).symmetric_eigen().eigenvalues.max() / 2.0;
        for a in [vec![0.0, 1.0, -1.0, -2.0], vec![-0.1, 3.0, -0.3, -0.1]] {
            let am = DMatrix::from_row_slice(2, 2, &a);
            assert!(mu2(&am) >= 0.0, "the test needs a non-contracting A");
            let tr = Transform::lyapunov(&a, 2).unwrap();
            let t = DMatrix::from_row_slice(2, 2, &tr.t);
            let s = DMatrix::from_row_slice(2, 2, &tr.s);
            let p = t.transpose() * &t;
            let residual = am.transpose() * &p + &p * &am + DMatrix::identity(2, 2);
            assert!(residual.norm() < 1e-9, "{residual}");
            let lam_max = p.symmetric_eigen().eigenvalues.max();
            let rate = mu2(&(&t * &am * s));
            assert!(
                (rate + 0.5 / lam_max).abs() < 1e-9,
                "μ₂ = {rate}, λmax(P) = {lam_max}"
            );
        }
        assert!(Transform::lyapunov(&[1.0, 0.0, 0.0, -1.0], 2).is_err());
    }

    /// `μ∞` of `A` in the coordinates of [`Transform::contracting`].
    fn mu_z(a: &[f64], n: usize) -> f64 {
        let t = Transform::contracting(a, n).unwrap();
        log_norm_inf(&t.conjugate(a), n)
    }

    /// Three axes of a double integrator under `κ = −p − 2ṗ` (`x = (p, ṗ)`, eigenvalue −1 six
    /// times): each axis gets the coordinates it gets alone, so `T` is block diagonal with
    /// entries below 3 and contracts at the one axis's rate. One Schur form of all six states
    /// mixed the axes and scaled the mixing to entries of 2·10⁴ (μ∞ −0.75, but a 6-state
    /// region near the goal verified 0.0 % against 29.6 %).
    #[test]
    fn decoupled_parts_get_coordinates_of_their_own() {
        let mut a = vec![0.0; 36];
        for k in 0..3 {
            a[k * 6 + 3 + k] = 1.0;
            a[(3 + k) * 6 + k] = -1.0;
            a[(3 + k) * 6 + 3 + k] = -2.0;
        }
        assert_eq!(decoupled_parts(&a, 6), [[0, 3], [1, 4], [2, 5]]);
        let axis = Transform::contracting(&[0.0, 1.0, -1.0, -2.0], 2).unwrap();
        let t = Transform::contracting(&a, 6).unwrap();
        for k in 0..3 {
            for (r, c) in [(0, 0), (0, 1), (1, 0), (1, 1)] {
                let entry = t.t[(2 * k + r) * 6 + [k, 3 + k][c]];
                assert_eq!(entry, axis.t[r * 2 + c], "axis {k}");
            }
        }
        let largest = t.t.iter().fold(0.0_f64, |m, x| m.max(x.abs()));
        assert!(largest < 3.0, "{:?}", t.t);
        assert_eq!(mu_z(&a, 6), mu_z(&[0.0, 1.0, -1.0, -2.0], 2));
        assert!(mu_z(&a, 6) < -0.4);
        // One part: the Schur form of all of A, as before.
        let coupled = [-1.0, 0.5, 0.0, 0.0, -2.0, 0.3, 0.2, 0.0, -3.0];
        assert_eq!(decoupled_parts(&coupled, 3).len(), 1);
        let whole = Transform::contracting(&coupled, 3).unwrap();
        assert_eq!(whole.t, contracting_matrix(&coupled, 3).unwrap());
    }

    /// Complex eigenvalues `α ± iβ` get `α + |β|`, the best any coordinates give a rotation in
    /// ℓ∞; before, the scaling of the Schur form blew up the pair's entry below the diagonal
    /// (a damped pendulum's closed loop, `λ = −1.55 ± 1.25i`, got `μ∞ = 2.2·10¹²` in z against
    /// 1 in x, and verified nothing).
    #[test]
    fn complex_pairs_contract_at_their_rate() {
        // λ = −1.55 ± 1.2490i.
        let a = [0.0, 1.0, -4.0, -3.1];
        let beta = (4.0_f64 - 1.55 * 1.55).sqrt();
        assert!(
            log_norm_inf(&a, 2) >= 0.0,
            "the test needs A not contracting in x"
        );
        assert!(
            (mu_z(&a, 2) - (-1.55 + beta)).abs() < 1e-9,
            "{}",
            mu_z(&a, 2)
        );
        // A rotation: no coordinates contract it, and none make it worse than α + |β| = 1.
        assert!((mu_z(&[0.0, 1.0, -1.0, 0.0], 2) - 1.0).abs() < 1e-9);
        // 3 × 3: a pair −1 ± 5i coupled to −2, in skewed coordinates. In the pair's own
        // coordinates the rate is 4 > 0 and no better exists: the scaling stops within 1 % of
        // it, its coordinates well scaled (halving on to the end scaled them by 2⁴⁰);
        // −0.5 ± 0.25i with −2 contracts, at its rate.
        let skew = DMatrix::from_row_slice(3, 3, &[1.0, 0.3, -0.2, 0.5, 1.0, 0.4, -0.1, 0.7, 1.0]);
        for (block, best) in [((-1.0, 5.0), 4.0), ((-0.5, 0.25), -0.25)] {
            let (al, be) = block;
            let j = DMatrix::from_row_slice(3, 3, &[al, be, 2.0, -be, al, 3.0, 0.0, 0.0, -2.0]);
            let am = &skew * j * skew.clone().try_inverse().unwrap();
            let a: Vec<f64> = (0..9).map(|k| am[(k / 3, k % 3)]).collect();
            let mu = mu_z(&a, 3);
            let slack = if best > 0.0 { 0.0101 * best } else { 1e-6 };
            assert!(
                mu <= best + slack && mu >= best - 1e-6,
                "{block:?}: μ∞ = {mu}"
            );
            let t = Transform::contracting(&a, 3).unwrap();
            assert!(t.t.iter().all(|v| v.abs() < 1e4), "{block:?}: {:?}", t.t);
        }
        // Two double integrators side by side (`λ = −1` four times, defective): the Schur form
        // leaves a 2 × 2 block unsplit, which gave `μ∞ = 1` in z as in x, and verified nothing.
        let mut two = [0.0; 16];
        for (k, v) in [
            (2, 1.0),
            (7, 1.0),
            (8, -1.0),
            (10, -2.0),
            (13, -1.0),
            (15, -2.0),
        ] {
            two[k] = v;
        }
        assert!(mu_z(&two, 4) <= -0.5 + 1e-9, "{}", mu_z(&two, 4));
        // The same, coupled and in skewed coordinates.
        let skew = DMatrix::from_fn(4, 4, |i, j| {
            if i == j {
                1.0
            } else {
                0.1 * (i + 2 * j) as f64
            }
        });
        let mut j4 = DMatrix::from_row_slice(4, 4, &two);
        j4[(2, 1)] = 0.5;
        let am = &skew * j4 * skew.clone().try_inverse().unwrap();
        let a: Vec<f64> = (0..16).map(|k| am[(k / 4, k % 4)]).collect();
        assert!(log_norm_inf(&a, 4) >= 0.0);
        assert!(mu_z(&a, 4) <= -0.5 + 1e-6, "{}", mu_z(&a, 4));
        // Real eigenvalues, defective or not, as before: within half of the slowest rate.
        for (a, slowest) in [
            ([0.0, 1.0, -1.0, -2.0], -1.0),
            ([0.0, 1.0, -4.0, -4.0], -2.0),
        ] {
            assert!(
                mu_z(&a, 2) <= 0.5 * slowest + 1e-9,
                "{a:?}: {}",
                mu_z(&a, 2)
            );
        }
    }
}

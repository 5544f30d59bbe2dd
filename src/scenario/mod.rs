//! Scenario files: a whole problem in one TOML file.
//!
//! A scenario states the control-affine system `ẋ = f(x) + g(x) u`, the nominal controller
//! `κ(x)`, the CBFs `hᵢ` with their class-K gains `αᵢ(s) = aᵢ s`, optional constraints linear in
//! the filter's correction `θ`, and the reachability settings (region `C`, norm, `M_C`, `dt`,
//! horizon, initial boxes, goal set, network). Expressions are strings in the state names and
//! the scenario's named parameters (see [`crate::expressions`]).
//!
//! Loading is two steps, so that every error can name its file and key: [`ScenarioFile`] is the
//! file as serde reads it, and [`Scenario::from_toml`] checks it and turns it into expression
//! trees and plain arrays (docs/design.md §4's *compiled problem*). An optional `[settings]` table
//! ([`SettingsSection`]) sets how runs of the scenario go: `[settings.reach]` the fields of
//! [`ReachSettings`], `[settings.verify]` those of [`VerifySettings`].

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::expressions::{self, Expr};

mod file;
pub mod limits;
mod values;

pub use file::*;
pub use values::Periodic;
use values::{compile_periodic, resolve_parameters};

/// The built-in default scenario (the paper's scenario 1), so that `cbfreach` runs anywhere.
pub const DEFAULT_SCENARIO: &str = include_str!("../../scenarios/integrator.toml");

/// The file name under which the built-in default scenario is reported.
pub const DEFAULT_SCENARIO_NAME: &str = "scenarios/integrator.toml";

/// An error in a scenario file: which file, which key, and what was expected.
#[derive(Debug, thiserror::Error)]
pub enum ScenarioError {
    /// The file could not be read.
    #[error("{file}: cannot read: {source}")]
    Io {
        /// The scenario file.
        file: String,
        /// The underlying error.
        source: std::io::Error,
    },
    /// The file is not valid TOML or does not have the scenario's shape.
    #[error("{file}: {message}")]
    Syntax {
        /// The scenario file.
        file: String,
        /// The TOML parser's message (it names line, column and key).
        message: String,
    },
    /// An expression does not parse or uses an unknown symbol.
    #[error("{file}: {key}: {source} in `{text}`")]
    Expression {
        /// The scenario file.
        file: String,
        /// The key holding the expression, e.g. `system.g[1][0]`.
        key: String,
        /// The expression's text.
        text: String,
        /// The parser's error (it carries the column).
        source: expressions::ExprError,
    },
    /// A value is present but wrong: a dimension, a sign, an empty box.
    #[error("{file}: {key}: {message}")]
    Invalid {
        /// The scenario file.
        file: String,
        /// The offending key.
        key: String,
        /// What was expected.
        message: String,
    },
}

// ---------------------------------------------------------------------------------------------
// The compiled problem.
// ---------------------------------------------------------------------------------------------

/// The embedding's coordinates, checked.
#[derive(Clone, Debug, PartialEq)]
pub enum TransformChoice {
    /// Chosen for the user (the default when the file names none): x itself where the closed
    /// loop at the goal contracts in ℓ∞ in x, else [`TransformChoice::Auto`]
    /// ([`crate::reach::Transform::chosen`] says which and why).
    Chosen,
    /// x itself.
    Identity,
    /// Chosen from the closed loop's linearisation at the goal's centre.
    Auto,
    /// `T = P^{1/2}` of the Lyapunov equation `AᵀP + PA = −I` at the goal: ℓ2 in z is `‖·‖_P`.
    Lyapunov,
    /// `z = T x` with this `T` (n×n, row-major).
    Matrix(Vec<f64>),
}

/// A CBF `h` with its gradient `∇h` and class-K gain `a` in `α(s) = a·s`.
#[derive(Clone, Debug)]
pub struct Cbf {
    /// Name for reports (`h1`, `h2`, … when the file gives none).
    pub name: String,
    /// `h(x)`.
    pub h: Expr,
    /// `∇h(x)`, n expressions.
    pub gradient: Vec<Expr>,
    /// The gain `a` of `α(s) = a·s`.
    pub alpha: f64,
}

/// A constraint `a(x)·θ ≤ b(x)` on the filter's correction `θ`.
#[derive(Clone, Debug)]
pub struct LinearConstraint {
    /// `a(x)`, m expressions.
    pub a: Vec<Expr>,
    /// `b(x)`.
    pub b: Expr,
}

/// The norm used for the closeness radius.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub enum Norm {
    /// ℓ∞.
    Inf,
    /// ℓ1.
    One,
    /// ℓ2.
    Two,
}

/// Where `M_C` comes from.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub enum Margin {
    /// A fixed number from the scenario file.
    Value(f64),
    /// The network's certified bound (`cbfreach error`).
    Certified,
    /// The network's measured bound (`cbfreach error`).
    Measured,
    /// The certified bound of the error map's cells that the current set meets (a local `M`,
    /// per box and step; `cbfreach error` writes the map). Sound, and much smaller than the
    /// global bound near the goal and the traps (docs/design.md §2b).
    Local,
}

/// A text that names no [`Margin`] or [`TransformChoice`]: what was found and what is
/// expected.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("expected {expected}, found {found:?}")]
pub struct ChoiceError {
    /// The text given.
    pub found: String,
    /// What would have been accepted.
    pub expected: &'static str,
}

impl std::str::FromStr for Margin {
    type Err = ChoiceError;

    /// A number ≥ 0, or `certified`, `measured`, `local` (from the error map).
    fn from_str(text: &str) -> Result<Margin, ChoiceError> {
        match text {
            "certified" => Ok(Margin::Certified),
            "measured" => Ok(Margin::Measured),
            "local" => Ok(Margin::Local),
            _ => match text.parse::<f64>() {
                Ok(v) if v.is_finite() && v >= 0.0 => Ok(Margin::Value(v)),
                _ => Err(ChoiceError {
                    found: text.to_string(),
                    expected: "a number ≥ 0, certified, measured or local",
                }),
            },
        }
    }
}

impl std::str::FromStr for TransformChoice {
    type Err = ChoiceError;

    /// `default`, `none`, `auto` or `lyapunov` (a matrix comes from the scenario file only).
    fn from_str(text: &str) -> Result<TransformChoice, ChoiceError> {
        match text {
            "default" => Ok(TransformChoice::Chosen),
            "none" => Ok(TransformChoice::Identity),
            "auto" => Ok(TransformChoice::Auto),
            "lyapunov" => Ok(TransformChoice::Lyapunov),
            _ => Err(ChoiceError {
                found: text.to_string(),
                expected: "default, none, auto or lyapunov",
            }),
        }
    }
}

/// Reachability settings, checked.
#[derive(Clone, Debug)]
pub struct ReachConfig {
    /// `C`.
    pub region: IntervalBox,
    /// Norm of the closeness radius.
    pub norm: Norm,
    /// `M_C`.
    pub m_c: Margin,
    /// Euler step.
    pub dt: f64,
    /// Horizon `T`.
    pub horizon: f64,
    /// Goal set.
    pub goal: IntervalBox,
    /// Initial boxes: the explicit ones, then the partition's cells.
    pub initial: Vec<IntervalBox>,
    /// Coordinates of the embedding.
    pub transform: TransformChoice,
    /// What the sets bound.
    pub time: crate::reach::TimeModel,
    /// Validated steps per `dt` in continuous time.
    pub substeps: usize,
}

impl ReachConfig {
    /// Number of Euler steps, `⌈T / dt⌉`.
    pub fn steps(&self) -> usize {
        (self.horizon / self.dt - 1e-9).ceil().max(0.0) as usize
    }
}

/// The surrogate network's settings.
#[derive(Clone, Debug)]
pub struct NetworkConfig {
    /// The safetensors file, resolved against the scenario's folder.
    pub file: PathBuf,
    /// Layer widths, input first.
    pub architecture: Vec<usize>,
}

/// The training grid.
#[derive(Clone, Debug)]
pub struct TrainingConfig {
    /// The region of the grid.
    pub region: IntervalBox,
    /// Points per axis.
    pub grid: Vec<usize>,
    /// `[training] target`: max ℓ∞ error and slope-error p95 to train to (each optional).
    pub target: Option<TrainingTarget>,
}

/// The accuracy `cbfreach train` stops at, each bound finite and > 0 where given.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TrainingTarget {
    /// Max ℓ∞ error on unseen points.
    pub linf: Option<f64>,
    /// 95th percentile of the slope error on unseen points.
    pub slope_p95: Option<f64>,
}

/// A checked scenario: expression trees, derivatives and plain arrays.
#[derive(Clone, Debug)]
pub struct Scenario {
    /// Short name.
    pub name: String,
    /// Description.
    pub description: String,
    /// The file it came from (for messages).
    pub file: String,
    /// State names.
    pub states: Vec<String>,
    /// Input names.
    pub inputs: Vec<String>,
    /// Named parameters.
    pub parameters: BTreeMap<String, f64>,
    /// `f(x)`.
    pub f: Vec<Expr>,
    /// `g(x)`, n rows of m.
    pub g: Vec<Vec<Expr>>,
    /// `κ(x)`.
    pub kappa: Vec<Expr>,
    /// `f̃(x) = f(x) + g(x) κ(x)`: the nominal closed loop.
    pub f_tilde: Vec<Expr>,
    /// `Df̃(x)`, n×n.
    pub f_tilde_jacobian: Vec<Vec<Expr>>,
    /// The CBFs.
    pub cbfs: Vec<Cbf>,
    /// Bounds on `u = κ(x) + θ`.
    pub input_bounds: Option<IntervalBox>,
    /// Further linear constraints on `θ`.
    pub constraints: Vec<LinearConstraint>,
    /// Reachability settings.
    pub reach: ReachConfig,
    /// The surrogate network, if the scenario names one.
    pub network: Option<NetworkConfig>,
    /// The training grid.
    pub training: TrainingConfig,
    /// The settings of runs (`[settings]`; defaults where the file has none).
    pub settings: SettingsSection,
    /// States defined modulo a period (`[system] periodic`), by state index.
    pub periodic: Vec<Periodic>,
}

impl Scenario {
    /// Reads and compiles a scenario file.
    pub fn load(path: &Path) -> Result<Scenario, ScenarioError> {
        let file = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ScenarioError::Io {
            file: file.clone(),
            source,
        })?;
        let base = path.parent().unwrap_or(Path::new("."));
        Scenario::from_toml(&text, &file, base)
    }

    /// The built-in default scenario (the paper's scenario 1); its network path resolves
    /// against this crate's `scenarios/` folder.
    pub fn builtin() -> Result<Scenario, ScenarioError> {
        let base = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
        Scenario::from_toml(DEFAULT_SCENARIO, DEFAULT_SCENARIO_NAME, &base)
    }

    /// Parses and compiles TOML text; `file` names it in errors, `base` resolves relative paths.
    pub fn from_toml(text: &str, file: &str, base: &Path) -> Result<Scenario, ScenarioError> {
        let raw: ScenarioFile = toml::from_str(text).map_err(|e| ScenarioError::Syntax {
            file: file.to_string(),
            message: e.to_string().trim_end().to_string(),
        })?;
        raw.compile(file, base)
    }

    /// State dimension `n`.
    pub fn n(&self) -> usize {
        self.states.len()
    }

    /// Input dimension `m`.
    pub fn m(&self) -> usize {
        self.inputs.len()
    }

    /// `f̃(x)`.
    pub fn f_tilde_at(&self, x: &[f64]) -> Vec<f64> {
        self.f_tilde.iter().map(|e| e.eval(x)).collect()
    }

    /// `g(x)`, row-major n×m.
    pub fn g_at(&self, x: &[f64]) -> Vec<f64> {
        self.g.iter().flatten().map(|e| e.eval(x)).collect()
    }

    /// `κ(x)`.
    pub fn kappa_at(&self, x: &[f64]) -> Vec<f64> {
        self.kappa.iter().map(|e| e.eval(x)).collect()
    }

    /// `x ∈ S`, i.e. every `hᵢ(x) ≥ 0`.
    pub fn is_safe(&self, x: &[f64]) -> bool {
        self.cbfs.iter().all(|c| c.h.eval(x) >= 0.0)
    }

    /// `minᵢ hᵢ(x)` (+∞ without CBFs).
    pub fn min_h(&self, x: &[f64]) -> f64 {
        self.cbfs
            .iter()
            .map(|c| c.h.eval(x))
            .fold(f64::INFINITY, f64::min)
    }
}

/// Compiles with the file name and the folder for relative paths at hand.
struct Compiler<'a> {
    file: &'a str,
    states: Vec<String>,
    parameters: &'a BTreeMap<String, f64>,
}

impl Compiler<'_> {
    fn invalid(&self, key: impl Into<String>, message: impl Into<String>) -> ScenarioError {
        ScenarioError::Invalid {
            file: self.file.to_string(),
            key: key.into(),
            message: message.into(),
        }
    }

    fn expr(&self, key: String, text: &str) -> Result<Expr, ScenarioError> {
        expressions::parse(text, &self.states, self.parameters).map_err(|source| {
            ScenarioError::Expression {
                file: self.file.to_string(),
                key,
                text: text.to_string(),
                source,
            }
        })
    }

    fn exprs(&self, key: &str, texts: &[String], len: usize) -> Result<Vec<Expr>, ScenarioError> {
        if texts.len() != len {
            return Err(self.invalid(
                key,
                format!("expected {len} expressions, found {}", texts.len()),
            ));
        }
        texts
            .iter()
            .enumerate()
            .map(|(i, t)| self.expr(format!("{key}[{i}]"), t))
            .collect()
    }

    fn finite(&self, key: &str, v: f64) -> Result<f64, ScenarioError> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.invalid(key, format!("expected a finite number, found {v}")))
        }
    }

    fn boxed(&self, key: &str, b: &BoxSection, n: usize) -> Result<IntervalBox, ScenarioError> {
        let lower = self.numbers(&format!("{key}.lower"), &b.lower)?;
        let upper = self.numbers(&format!("{key}.upper"), &b.upper)?;
        self.box_from(key, &lower, &upper, n)
    }

    fn box_from(
        &self,
        key: &str,
        lower: &[f64],
        upper: &[f64],
        n: usize,
    ) -> Result<IntervalBox, ScenarioError> {
        if lower.len() != n || upper.len() != n {
            return Err(self.invalid(
                key,
                format!(
                    "expected lower and upper of length {n} (one per state), found {} and {}",
                    lower.len(),
                    upper.len()
                ),
            ));
        }
        IntervalBox::new(lower.to_vec(), upper.to_vec())
            .map_err(|m| self.invalid(key, m.to_string()))
    }
}

impl ScenarioFile {
    /// Checks the file and builds the compiled problem.
    pub fn compile(&self, file: &str, base: &Path) -> Result<Scenario, ScenarioError> {
        let sys = &self.system;
        let parameters = resolve_parameters(file, &self.parameters, &sys.states)?;
        let c = Compiler {
            file,
            states: sys.states.clone(),
            parameters: &parameters,
        };
        check_names(&c, "system.states", &sys.states)?;
        check_names(&c, "system.inputs", &sys.inputs)?;
        let (n, m) = (sys.states.len(), sys.inputs.len());

        let f = c.exprs("system.f", &sys.f, n)?;
        if sys.g.len() != n {
            return Err(c.invalid(
                "system.g",
                format!("expected {n} rows (one per state), found {}", sys.g.len()),
            ));
        }
        let g = sys
            .g
            .iter()
            .enumerate()
            .map(|(i, row)| c.exprs(&format!("system.g[{i}]"), row, m))
            .collect::<Result<Vec<_>, _>>()?;
        let kappa = c.exprs("system.kappa", &sys.kappa, m)?;

        // f̃ᵢ = fᵢ + Σⱼ gᵢⱼ κⱼ, built from the source text so that it is one tree per state.
        let f_tilde = (0..n)
            .map(|i| {
                let mut text = format!("({})", sys.f[i]);
                for j in 0..m {
                    text.push_str(&format!(" + ({})*({})", sys.g[i][j], sys.kappa[j]));
                }
                c.expr(format!("system.f[{i}] + g·kappa"), &text)
            })
            .collect::<Result<Vec<_>, _>>()?;
        for (i, e) in f_tilde.iter().enumerate() {
            limits::check_derivative_size(e, None)
                .map_err(|m| c.invalid(format!("system.f[{i}] + g·kappa"), m))?;
        }
        let f_tilde_jacobian = expressions::jacobian(&f_tilde, n);

        let cbfs = self
            .cbfs
            .iter()
            .enumerate()
            .map(|(i, cb)| {
                let key = format!("cbf[{i}]");
                let h = c.expr(format!("{key}.h"), &cb.h)?;
                // Before differentiating: the filter's rows differentiate ∇h·f̃ again.
                limits::check_derivative_size(&h, Some(&f_tilde))
                    .map_err(|m| c.invalid(format!("{key}.h"), m))?;
                let alpha = c.finite(&format!("{key}.alpha"), cb.alpha)?;
                if alpha <= 0.0 {
                    return Err(c.invalid(
                        format!("{key}.alpha"),
                        format!("the class-K gain must be positive, found {alpha}"),
                    ));
                }
                Ok(Cbf {
                    name: cb.name.clone().unwrap_or_else(|| format!("h{}", i + 1)),
                    gradient: expressions::gradient(&h, n),
                    h,
                    alpha,
                })
            })
            .collect::<Result<Vec<_>, _>>()?;

        let input_bounds = self
            .input_bounds
            .as_ref()
            .map(|b| {
                if b.lower.len() != m || b.upper.len() != m {
                    return Err(c.invalid(
                        "input_bounds",
                        format!("expected lower and upper of length {m} (one per input)"),
                    ));
                }
                let lower = c.numbers("input_bounds.lower", &b.lower)?;
                let upper = c.numbers("input_bounds.upper", &b.upper)?;
                IntervalBox::new(lower, upper)
                    .map_err(|msg| c.invalid("input_bounds", msg.to_string()))
            })
            .transpose()?;
        let constraints = self
            .constraints
            .iter()
            .enumerate()
            .map(|(i, k)| {
                let row = LinearConstraint {
                    a: c.exprs(&format!("constraint[{i}].a"), &k.a, m)?,
                    b: c.expr(format!("constraint[{i}].b"), &k.b)?,
                };
                for e in row.a.iter().chain([&row.b]) {
                    limits::check_derivative_size(e, None)
                        .map_err(|msg| c.invalid(format!("constraint[{i}]"), msg))?;
                }
                Ok(row)
            })
            .collect::<Result<Vec<_>, ScenarioError>>()?;

        let reach = compile_reach(&c, &self.reach, n)?;
        let periodic = compile_periodic(&c, &sys.periodic, &reach)?;
        let network = self
            .network
            .as_ref()
            .map(|net| {
                let widths = &net.architecture;
                if widths.len() < 2 || widths.contains(&0) {
                    return Err(c.invalid(
                        "network.architecture",
                        "expected at least two positive widths, e.g. [2, 400, 400, 400, 2]",
                    ));
                }
                if widths[0] != n || widths[widths.len() - 1] != m {
                    return Err(c.invalid(
                        "network.architecture",
                        format!(
                            "the network maps states to inputs: expected {n}×…×{m}, found {}",
                            widths
                                .iter()
                                .map(|w| w.to_string())
                                .collect::<Vec<_>>()
                                .join("×")
                        ),
                    ));
                }
                Ok(NetworkConfig {
                    file: base.join(&net.file),
                    architecture: widths.clone(),
                })
            })
            .transpose()?;
        let training = match &self.training {
            Some(t) => {
                let region = match &t.region {
                    Some(b) => c.boxed("training.region", b, n)?,
                    None => reach.region.clone(),
                };
                if t.grid.len() != n || t.grid.iter().any(|&k| k < 2) {
                    return Err(c.invalid(
                        "training.grid",
                        format!("expected {n} point counts, each at least 2"),
                    ));
                }
                let target = match &t.target {
                    None => None,
                    Some(target) => {
                        for (key, value) in [("linf", target.linf), ("slope_p95", target.slope_p95)]
                        {
                            if let Some(v) = value.filter(|v| !(v.is_finite() && *v > 0.0)) {
                                return Err(c.invalid(
                                    format!("training.target.{key}"),
                                    format!("{v} must be a finite number > 0"),
                                ));
                            }
                        }
                        if target.linf.is_none() && target.slope_p95.is_none() {
                            return Err(
                                c.invalid("training.target", "give linf, slope_p95 or both")
                            );
                        }
                        Some(TrainingTarget {
                            linf: target.linf,
                            slope_p95: target.slope_p95,
                        })
                    }
                };
                TrainingConfig {
                    region,
                    grid: t.grid.clone(),
                    target,
                }
            }
            None => TrainingConfig {
                region: reach.region.clone(),
                grid: vec![100; n],
                target: None,
            },
        };

        if let Err(e) = self.settings.reach.validate() {
            return Err(c.invalid(format!("settings.reach.{}", e.field()), e.to_string()));
        }
        // NaN or ∞ somewhere in C: found by interval evaluation, confirmed at a point.
        let mut exprs: Vec<(String, &Expr)> = Vec::new();
        for (i, cb) in cbfs.iter().enumerate() {
            exprs.push((format!("cbf[{i}].h"), &cb.h));
        }
        for (i, e) in f.iter().enumerate() {
            exprs.push((format!("system.f[{i}]"), e));
        }
        for (i, row) in g.iter().enumerate() {
            for (j, e) in row.iter().enumerate() {
                exprs.push((format!("system.g[{i}][{j}]"), e));
            }
        }
        for (j, e) in kappa.iter().enumerate() {
            exprs.push((format!("system.kappa[{j}]"), e));
        }
        if let Some((key, x, v)) = limits::find_non_finite(&reach.region, &exprs) {
            return Err(c.invalid(
                key,
                format!(
                    "is {v} at x = {x:?} in the region C (every expression must be finite on C)"
                ),
            ));
        }
        Ok(Scenario {
            name: self.name.clone(),
            description: self.description.trim().to_string(),
            file: file.to_string(),
            states: sys.states.clone(),
            inputs: sys.inputs.clone(),
            parameters,
            f,
            g,
            kappa,
            f_tilde,
            f_tilde_jacobian,
            cbfs,
            input_bounds,
            constraints,
            reach,
            network,
            training,
            settings: self.settings.clone(),
            periodic,
        })
    }
}

fn check_names(c: &Compiler, key: &str, names: &[String]) -> Result<(), ScenarioError> {
    if names.is_empty() {
        return Err(c.invalid(key, "expected at least one name"));
    }
    for (i, name) in names.iter().enumerate() {
        let ok = name
            .chars()
            .next()
            .is_some_and(|ch| ch.is_ascii_alphabetic() || ch == '_')
            && name
                .chars()
                .all(|ch| ch.is_ascii_alphanumeric() || ch == '_');
        if !ok {
            return Err(c.invalid(
                format!("{key}[{i}]"),
                format!("`{name}` is not a name (letters, digits, _; not starting with a digit)"),
            ));
        }
        // A name that is a function or a constant would shadow it in every expression.
        if name == "pi" || expressions::Func::from_name(name).is_some() {
            return Err(c.invalid(
                format!("{key}[{i}]"),
                format!("`{name}` is the name of a function or constant of the expressions"),
            ));
        }
        if names[..i].contains(name) {
            return Err(c.invalid(format!("{key}[{i}]"), format!("`{name}` appears twice")));
        }
    }
    Ok(())
}

fn compile_reach(c: &Compiler, r: &ReachSection, n: usize) -> Result<ReachConfig, ScenarioError> {
    let region = c.boxed("reach.region", &r.region, n)?;
    let norm = match r.norm.as_str() {
        "inf" | "linf" | "∞" => Norm::Inf,
        "1" | "l1" => Norm::One,
        "2" | "l2" => Norm::Two,
        other => {
            return Err(c.invalid(
                "reach.norm",
                format!("expected \"inf\", \"1\" or \"2\", found \"{other}\""),
            ))
        }
    };
    let m_c = match &r.m_c {
        MarginSpec::Value(v) if v.is_finite() && *v >= 0.0 => Margin::Value(*v),
        MarginSpec::Value(v) => {
            return Err(c.invalid(
                "reach.m_c",
                format!("expected a finite number ≥ 0, found {v}"),
            ))
        }
        MarginSpec::Source(s) if s == "certified" => Margin::Certified,
        MarginSpec::Source(s) if s == "measured" => Margin::Measured,
        MarginSpec::Source(s) if s == "local" => Margin::Local,
        MarginSpec::Source(s) => {
            return Err(c.invalid(
                "reach.m_c",
                format!(
                    "expected a number, \"certified\", \"measured\" or \"local\", found \"{s}\""
                ),
            ))
        }
    };
    let dt = c.finite("reach.dt", r.dt)?;
    if dt <= 0.0 {
        return Err(c.invalid("reach.dt", format!("expected dt > 0, found {dt}")));
    }
    let horizon = c.finite("reach.horizon", r.horizon)?;
    if horizon <= 0.0 {
        return Err(c.invalid(
            "reach.horizon",
            format!("expected a horizon > 0, found {horizon}"),
        ));
    }
    let goal = c.boxed("reach.goal", &r.goal, n)?;
    let mut initial = r
        .initial
        .iter()
        .enumerate()
        .map(|(i, b)| c.boxed(&format!("reach.initial[{i}]"), b, n))
        .collect::<Result<Vec<_>, _>>()?;
    if let Some(p) = &r.partition {
        let whole = c.box_from("reach.partition", &p.lower, &p.upper, n)?;
        if p.counts.len() != n || p.counts.contains(&0) {
            return Err(c.invalid(
                "reach.partition.counts",
                format!("expected {n} positive cell counts, one per state"),
            ));
        }
        let cells = p.counts.iter().try_fold(1usize, |a, &k| a.checked_mul(k));
        if cells.is_none_or(|k| k > limits::MAX_INITIAL_BOXES) {
            return Err(c.invalid(
                "reach.partition.counts",
                format!(
                    "{:?} makes {} initial boxes, more than {}",
                    p.counts,
                    cells.map_or("more than 2^64".into(), |k| k.to_string()),
                    limits::MAX_INITIAL_BOXES
                ),
            ));
        }
        initial.extend(whole.partition(&p.counts));
    }
    let transform = match &r.transform {
        None => TransformChoice::Chosen,
        Some(TransformSpec::Name(s)) if s == "default" => TransformChoice::Chosen,
        Some(TransformSpec::Name(s)) if s == "none" => TransformChoice::Identity,
        Some(TransformSpec::Name(s)) if s == "auto" => TransformChoice::Auto,
        Some(TransformSpec::Name(s)) if s == "lyapunov" => TransformChoice::Lyapunov,
        Some(TransformSpec::Name(s)) => {
            return Err(c.invalid(
                "reach.transform",
                format!(
                    "expected \"default\", \"none\", \"auto\", \"lyapunov\" or an {n}×{n} matrix, found \"{s}\""
                ),
            ))
        }
        Some(TransformSpec::Matrix(rows)) => {
            if rows.len() != n || rows.iter().any(|r| r.len() != n) {
                return Err(c.invalid(
                    "reach.transform",
                    format!("expected an {n}×{n} matrix (n rows of n numbers)"),
                ));
            }
            let flat: Vec<f64> = rows.iter().flatten().copied().collect();
            if flat.iter().any(|v| !v.is_finite()) {
                return Err(c.invalid("reach.transform", "entries must be finite"));
            }
            TransformChoice::Matrix(flat)
        }
    };
    let time =
        crate::reach::TimeModel::parse(r.time.as_deref().unwrap_or("euler"), r.control_period, dt)
            .map_err(|e| c.invalid("reach.time", e))?;
    let substeps = r.substeps.unwrap_or(1);
    if substeps == 0 {
        return Err(c.invalid("reach.substeps", "expected a whole number ≥ 1"));
    }
    let steps = (horizon / dt).ceil() * substeps as f64;
    if steps.is_nan() || steps > limits::MAX_STEPS {
        return Err(c.invalid(
            "reach.horizon",
            format!(
                "horizon {horizon} / dt {dt} × {substeps} substep(s) is {steps:.3e} steps, more than {:.0e} (a longer dt or a shorter horizon)",
                limits::MAX_STEPS
            ),
        ));
    }
    Ok(ReachConfig {
        time,
        substeps,
        transform,
        region,
        norm,
        m_c,
        dt,
        horizon,
        goal,
        initial,
    })
}

//! Scenario files: a whole problem in one TOML file.
//!
//! A scenario states the control-affine system `ẋ = f(x) + g(x) u`, the nominal controller
//! `κ(x)`, the CBFs `hᵢ` with their class-K functions `αᵢ` (a gain, `αᵢ(h) = aᵢh`, or a
//! function of `h`), optional constraints linear in the filter's correction `θ`, and the
//! reachability settings (region `C`, norm, `M_C`, `dt`, horizon, initial boxes, goal set,
//! network). Expressions are strings in the state names and
//! the scenario's named parameters (see [`crate::expressions`]).
//!
//! Loading is two steps, so that every error can name its file and key: [`ScenarioFile`] is the
//! file as serde reads it, and [`Scenario::from_toml`] checks it and turns it into expression
//! trees and plain arrays (docs/design.md §4's *compiled problem*). An optional `[settings]` table
//! ([`SettingsSection`]) sets how runs of the scenario go: `[settings.reach]` the fields of
//! [`ReachSettings`](crate::reach::ReachSettings), `[settings.verify]` those of
//! [`VerifySettings`](crate::verify::VerifySettings).

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};

use crate::boxes::IntervalBox;
use crate::expressions::{self, Expr};

mod class_k;
mod compile;
mod file;
mod high_order;
pub mod limits;
mod values;

pub use class_k::ClassK;
pub use file::*;
pub use high_order::MAX_ORDER;
pub use values::Periodic;

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
    #[error("{file}: {key}: {source} in {}", excerpt(.text))]
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

/// A CBF `h` with its gradient `∇h` and class-K function `α`.
#[derive(Clone, Debug)]
pub struct Cbf {
    /// Name for reports (`h1`, `h2`, … when the file gives none).
    pub name: String,
    /// `h(x)`.
    pub h: Expr,
    /// `∇h(x)`, n expressions.
    pub gradient: Vec<Expr>,
    /// `α` in `∇h·(f̃ + gθ) ≥ −α(h)`.
    pub alpha: ClassK,
    /// The `[[cbf]]` it comes from (its index in the file).
    pub section: usize,
    /// Its level in that section's high-order CBF: 0 for `h` as written, `k` for `ψₖ`
    /// (`order = r` writes levels `0 … r−1`).
    pub level: usize,
    /// No input acts on `h`: every `∇h·gⱼ` simplifies to the constant 0 (exactly, so its row
    /// `0·θ ≤ L_f̃h + α(h)` holds only where the right side is nonnegative, and binds nowhere).
    pub inert: bool,
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

impl std::fmt::Display for Margin {
    /// As a scenario file writes it: `"local"`, `"certified"`, `"measured"` or the number.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Margin::Value(v) => write!(f, "{v}"),
            Margin::Certified => f.write_str("\"certified\""),
            Margin::Measured => f.write_str("\"measured\""),
            Margin::Local => f.write_str("\"local\""),
        }
    }
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
    /// Frames the continuous-time sets are kept in where the closed loop turns them (`None`:
    /// chosen, [`crate::reach::Turning::frames`]; 1: none turned).
    pub turned_frames: Option<usize>,
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
    /// Units of states and inputs by name (`[system] units`), for axes and reports.
    pub units: BTreeMap<String, String>,
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

    /// A state's or input's name for an axis or a report: `v [m/s]` where `[system] units`
    /// gives its unit, else the name.
    pub fn label(&self, name: &str) -> String {
        match self.units.get(name) {
            Some(unit) => format!("{name} [{unit}]"),
            None => name.to_string(),
        }
    }

    /// The time axis' name: `t [s]` where `[system] units` gives `t` a unit and no state or
    /// input is named `t`, else `t`.
    pub fn time_label(&self) -> String {
        let named = self.states.iter().chain(&self.inputs).any(|x| x == "t");
        match self.units.get("t") {
            Some(unit) if !named => format!("t [{unit}]"),
            _ => "t".to_string(),
        }
    }

    /// The unit the network's error is in, `‖N − v‖∞` taken across the inputs: theirs where
    /// all inputs have one and the same (`None` otherwise).
    pub fn input_unit(&self) -> Option<&str> {
        let first = self.units.get(self.inputs.first()?)?;
        (self.inputs.iter())
            .all(|u| self.units.get(u) == Some(first))
            .then_some(first.as_str())
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

/// An expression as error messages quote it: whole up to 200 characters, else its start and end
/// and its length (a generated file's expression of 90 MB was echoed whole, taking longer to
/// print than to refuse).
fn excerpt(text: &str) -> String {
    const HEAD: usize = 120;
    const TAIL: usize = 40;
    let n = text.chars().count();
    if n <= 200 {
        return format!("`{text}`");
    }
    let head: String = text.chars().take(HEAD).collect();
    let tail: String = text.chars().skip(n - TAIL).collect();
    format!("`{head} … {tail}` ({n} characters)")
}

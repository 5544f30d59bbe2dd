//! A scenario file as written: the TOML tables as serde reads them, before any check
//! ([`super::Scenario::from_toml`] checks them). May import `reach` and `verify` (their
//! settings, for `[settings]`).

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::reach::ReachSettings;
use crate::verify::VerifySettings;

/// A scenario file as written (TOML). See `scenarios/*.toml` for annotated examples.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ScenarioFile {
    /// A short name for reports.
    pub name: String,
    /// One or two sentences about the problem.
    #[serde(default)]
    pub description: String,
    /// Named constants usable in every expression: numbers, or expressions in the other
    /// parameters (`g = 9.81`, `u_min = "-0.25*g"`).
    #[serde(default)]
    pub parameters: BTreeMap<String, Number>,
    /// The control-affine system and the nominal controller.
    pub system: SystemSection,
    /// The CBFs `hᵢ`; the safe set is `S = ∩ᵢ {hᵢ ≥ 0}`.
    #[serde(default, rename = "cbf")]
    pub cbfs: Vec<CbfSection>,
    /// Bounds on the applied input `u = κ(x) + θ`.
    #[serde(default)]
    pub input_bounds: Option<BoxSection>,
    /// Further constraints linear in `θ`: `a(x)·θ ≤ b(x)`.
    #[serde(default, rename = "constraint")]
    pub constraints: Vec<ConstraintSection>,
    /// Reachability settings.
    pub reach: ReachSection,
    /// The surrogate network.
    #[serde(default)]
    pub network: Option<NetworkSection>,
    /// The training grid.
    #[serde(default)]
    pub training: Option<TrainingSection>,
    /// Settings of runs of this scenario (`[settings.reach]`, `[settings.verify]`); command-line
    /// options override them.
    #[serde(default, skip_serializing_if = "SettingsSection::is_default")]
    pub settings: SettingsSection,
}

/// `[settings]`: how runs of this scenario go unless told otherwise. `[settings.reach]` takes
/// the fields of [`ReachSettings`] (e.g. `bounds = "crown"`, `face_local = true`),
/// `[settings.verify]` those of [`VerifySettings`] (e.g. `grid = [32, 32]`,
/// `refine_depth = 4`); a field left out keeps its default, an unknown one is an error.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct SettingsSection {
    /// Reach settings. Default: `ReachSettings::default()`.
    pub reach: ReachSettings,
    /// Verification settings. Default: `VerifySettings::default()`.
    pub verify: VerifySettings,
}

impl SettingsSection {
    /// Whether every setting is its default (the table can be left out).
    pub fn is_default(&self) -> bool {
        *self == SettingsSection::default()
    }
}

/// `[system]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SystemSection {
    /// State names `x₁…xₙ`.
    pub states: Vec<String>,
    /// Input names `u₁…u_m`.
    pub inputs: Vec<String>,
    /// Drift `f(x)`, n expressions.
    pub f: Vec<String>,
    /// Input matrix `g(x)`, n rows of m expressions.
    pub g: Vec<Vec<String>>,
    /// Nominal controller `κ(x)`, m expressions.
    pub kappa: Vec<String>,
    /// Angles and other states defined modulo a period: `{ theta = ["-pi", "pi"] }` says that
    /// `theta` and `theta + 2π` are one state (default: none). Sets are not wrapped: C and
    /// the initial boxes must lie within one period (docs/design.md §2.12).
    #[serde(default)]
    pub periodic: BTreeMap<String, Vec<Number>>,
    /// Units of states and inputs for axes and reports: `{ D = "m", v = "m/s", u = "N" }`, and
    /// of time as `t` (unless a state or input is named so) (default: none; any subset).
    #[serde(default)]
    pub units: BTreeMap<String, String>,
}

/// One `[[cbf]]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CbfSection {
    /// A name for reports.
    #[serde(default)]
    pub name: Option<String>,
    /// `h(x)`.
    pub h: String,
    /// The class-K function `α` of `ḣ ≥ −α(h)`: a gain `a` (`α(h) = a·h`; default 1, as a
    /// number or an expression in the parameters) or an expression in `h` (`"0.5*h + h^3"`).
    /// With `order = r`, one for every level or a list of `r` (`α₁ … α_r`).
    #[serde(default = "one")]
    pub alpha: Alpha,
    /// `h`'s relative degree `r` (default 1): the filter enforces the high-order CBF
    /// `ψ₀ = h`, `ψₖ = L_f̃ψₖ₋₁ + αₖ(ψₖ₋₁)` (`k < r`), each `ψₖ` a CBF of its own with
    /// `αₖ₊₁`, so that `S` requires all of them and the input acts on `ψ_{r−1}`'s row.
    #[serde(default)]
    pub order: Option<i64>,
}

fn one() -> Alpha {
    Alpha::One(Number::Value(1.0))
}

/// A `[[cbf]]`'s `alpha`: one class-K function for every level, or one per level.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "a number, an expression (in the parameters, or a function of h) as a string, \
                 or a list of them, one per level of `order`"
)]
pub enum Alpha {
    /// The same class-K function at every level.
    One(Number),
    /// `α₁ … α_r`, one per level of `order = r`.
    Levels(Vec<Number>),
}

/// A number as written: a TOML number, or an expression in the parameters and `pi`
/// (`"-0.25*9.81"`, `"-pi"`, `"u_max/2"`).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "a number, or an expression in the parameters as a string"
)]
pub enum Number {
    /// A plain number.
    Value(f64),
    /// An expression, evaluated once when the scenario is compiled.
    Expr(String),
}

impl From<f64> for Number {
    fn from(v: f64) -> Number {
        Number::Value(v)
    }
}

/// A box `[lower, upper]` as written (numbers or expressions in the parameters).
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BoxSection {
    /// Lower corner.
    pub lower: Vec<Number>,
    /// Upper corner.
    pub upper: Vec<Number>,
}

/// One `[[constraint]]`: `a(x)·θ ≤ b(x)`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ConstraintSection {
    /// `a(x)`, m expressions.
    pub a: Vec<String>,
    /// `b(x)`.
    pub b: String,
}

/// `M_C` as written: a number, or where to take it from.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "a number ≥ 0, or \"certified\", \"measured\" or \"local\""
)]
pub enum MarginSpec {
    /// A fixed bound on `‖N(x) − v(x)‖` over `C`.
    Value(f64),
    /// `"certified"`, `"measured"` or `"local"`: taken from the network's error map.
    Source(String),
}

/// `[reach]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ReachSection {
    /// The compact region `C` on which `M_C` holds and inside which the theorem needs the sets.
    pub region: BoxSection,
    /// Norm for the closeness radius: `inf`, `1` or `2`.
    #[serde(default = "default_norm")]
    pub norm: String,
    /// `M_C`: a number, `"certified"`, `"measured"` or `"local"` (default: `"local"`, the
    /// per-cell bounds of the error map that `cbfreach error` writes).
    #[serde(default = "default_margin")]
    pub m_c: MarginSpec,
    /// Euler step.
    pub dt: f64,
    /// Time horizon `T`.
    pub horizon: f64,
    /// Goal set used for verdicts (a box around the origin).
    pub goal: BoxSection,
    /// Explicit initial boxes.
    #[serde(default)]
    pub initial: Vec<BoxSection>,
    /// A box partitioned into `counts[i]` cells along axis i.
    #[serde(default)]
    pub partition: Option<PartitionSection>,
    /// Coordinates of the embedding: `"default"` (when left out: x itself where the closed
    /// loop at the goal contracts in ℓ∞ in x, else `"auto"`; runs print which and why),
    /// `"none"` (x itself), `"auto"` (from the closed loop's linearisation at the goal), `"lyapunov"` (`T = P^{1/2}`, for `‖·‖_P`) or a matrix `T`
    /// (`z = T x`, rows).
    #[serde(default)]
    pub transform: Option<TransformSpec>,
    /// What the sets bound: `"continuous"` (default), `"sampled"` or `"euler"`.
    #[serde(default)]
    pub time: Option<String>,
    /// `T_s` of `time = "sampled"`, `K·dt` with `K` a whole number ≥ 1 (default `dt`).
    #[serde(default)]
    pub control_period: Option<f64>,
    /// Validated steps per `dt` in continuous time (default 1).
    #[serde(default)]
    pub substeps: Option<usize>,
    /// Frames the continuous-time sets are kept in where the closed loop turns them (1: none
    /// turned; default: chosen from the turn at the goal, `reach::Turning::frames`).
    #[serde(default)]
    pub turned_frames: Option<usize>,
}

/// `reach.transform` as written.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(
    untagged,
    expecting = "\"none\", \"auto\", \"lyapunov\" or a matrix T as rows, [[t11, t12], [t21, t22]]"
)]
pub enum TransformSpec {
    /// `"none"`, `"auto"` or `"lyapunov"`.
    Name(String),
    /// `T`, as rows.
    Matrix(Vec<Vec<f64>>),
}

fn default_margin() -> MarginSpec {
    MarginSpec::Source("local".into())
}

fn default_norm() -> String {
    "inf".into()
}

/// `[reach.partition]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PartitionSection {
    /// Lower corner of the partitioned box.
    pub lower: Vec<f64>,
    /// Upper corner.
    pub upper: Vec<f64>,
    /// Cells per axis.
    pub counts: Vec<usize>,
}

/// `[network]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct NetworkSection {
    /// safetensors file, relative to the scenario file.
    pub file: String,
    /// Layer widths, input first, e.g. `[2, 400, 400, 400, 2]`.
    pub architecture: Vec<usize>,
}

/// `[training]`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TrainingSection {
    /// Region of the training grid (default: `C`).
    #[serde(default)]
    pub region: Option<BoxSection>,
    /// Grid points per axis.
    pub grid: Vec<usize>,
    /// The accuracy `cbfreach train` trains to (default none: the whole schedule).
    #[serde(default)]
    pub target: Option<TargetSection>,
}

/// `[training] target = { linf = …, slope_p95 = … }`.
#[derive(Clone, Debug, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct TargetSection {
    /// Max ℓ∞ error of the network on unseen points, in the inputs' units.
    pub linf: Option<f64>,
    /// 95th percentile of the slope error on unseen points.
    pub slope_p95: Option<f64>,
}

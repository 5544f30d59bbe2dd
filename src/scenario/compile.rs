//! [`ScenarioFile::compile`]: a scenario file as serde read it, checked key by key and turned
//! into expression trees and plain arrays ([`super::Scenario`]); every error names the file and
//! the key.

use super::high_order::{alpha_key, level_key};
use super::values::{compile_periodic, resolve_parameters};
use super::*;

/// Compiles with the file name and the folder for relative paths at hand.
pub(super) struct Compiler<'a> {
    pub(super) file: &'a str,
    pub(super) states: Vec<String>,
    pub(super) parameters: &'a BTreeMap<String, f64>,
}

impl Compiler<'_> {
    pub(super) fn invalid(
        &self,
        key: impl Into<String>,
        message: impl Into<String>,
    ) -> ScenarioError {
        ScenarioError::Invalid {
            file: self.file.to_string(),
            key: key.into(),
            message: message.into(),
        }
    }

    pub(super) fn expr(&self, key: String, text: &str) -> Result<Expr, ScenarioError> {
        self.parse_over(&key, text, &self.states)
    }

    /// `text` parsed over `variables` and the parameters, its error naming `key`.
    pub(super) fn parse_over(
        &self,
        key: &str,
        text: &str,
        variables: &[String],
    ) -> Result<Expr, ScenarioError> {
        expressions::parse(text, variables, self.parameters).map_err(|source| {
            ScenarioError::Expression {
                file: self.file.to_string(),
                key: key.to_string(),
                text: text.to_string(),
                source,
            }
        })
    }

    pub(super) fn exprs(
        &self,
        key: &str,
        texts: &[String],
        len: usize,
    ) -> Result<Vec<Expr>, ScenarioError> {
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

    /// A CBF's `alpha`: a gain (a number, or an expression in the parameters), or a function
    /// of `h` (checked against `h`'s values on `C` once those are known).
    pub(super) fn class_k(&self, key: &str, alpha: &Number) -> Result<ClassK, ScenarioError> {
        let text = match alpha {
            Number::Value(a) => return Ok(ClassK::gain(*a)),
            Number::Expr(text) => text,
        };
        let e = self.parse_over(key, text, &["h".to_string()])?;
        if !e.uses_variable(0) {
            return Ok(ClassK::gain(e.eval(&[])));
        }
        limits::check_derivative_size(&e, None).map_err(|m| self.invalid(key, m))?;
        Ok(ClassK::function(e, text))
    }

    pub(super) fn finite(&self, key: &str, v: f64) -> Result<f64, ScenarioError> {
        if v.is_finite() {
            Ok(v)
        } else {
            Err(self.invalid(key, format!("expected a finite number, found {v}")))
        }
    }

    pub(super) fn boxed(
        &self,
        key: &str,
        b: &BoxSection,
        n: usize,
    ) -> Result<IntervalBox, ScenarioError> {
        let lower = self.numbers(&format!("{key}.lower"), &b.lower)?;
        let upper = self.numbers(&format!("{key}.upper"), &b.upper)?;
        self.box_from(key, &lower, &upper, n)
    }

    pub(super) fn box_from(
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
                // An input that does not act on the state (gᵢⱼ = 0) adds no term: `0·κⱼ` kept
                // whole (κ divides, so collecting may not drop it) bloated f̃ and ψ's.
                for j in (0..m).filter(|&j| g[i][j].as_constant() != Some(0.0)) {
                    text.push_str(&format!(" + ({})*({})", sys.g[i][j], sys.kappa[j]));
                }
                // A controller that cancels the drift leaves both copies in the text: collected,
                // interval evaluation sees the closed loop it is.
                c.expr(format!("system.f[{i}] + g·kappa"), &text)
                    .map(|e| e.collected())
            })
            .collect::<Result<Vec<_>, _>>()?;
        for (i, e) in f_tilde.iter().enumerate() {
            limits::check_derivative_size(e, None)
                .map_err(|m| c.invalid(format!("system.f[{i}] + g·kappa"), m))?;
        }
        let f_tilde_jacobian = expressions::jacobian(&f_tilde, n);

        let mut cbfs = Vec::new();
        for (i, cb) in self.cbfs.iter().enumerate() {
            cbfs.extend(c.high_order_cbf(i, cb, &f_tilde, &g)?);
        }

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
        for (name, unit) in &sys.units {
            let key = format!("system.units.{name}");
            // `t` is time's unit unless a state or input has that name.
            if !c.states.contains(name) && !sys.inputs.contains(name) && name != "t" {
                return Err(c.invalid(
                    key,
                    format!(
                        "`{name}` is neither a state nor an input nor t, the time (states: {}; \
                         inputs: {})",
                        c.states.join(", "),
                        sys.inputs.join(", ")
                    ),
                ));
            }
            let printable = !unit.chars().any(char::is_control);
            if unit.trim().is_empty() || unit.chars().count() > 24 || !printable {
                return Err(c.invalid(
                    key,
                    format!(
                        "expected a unit such as \"m/s\" (1 to 24 printable characters), \
                         found {unit:?}"
                    ),
                ));
            }
        }
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
        for cb in &cbfs {
            exprs.push((level_key(cb.section, cb.level), &cb.h));
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
        for cb in &cbfs {
            if let Some(why) = cb.alpha.check(|| limits::largest_on(&reach.region, &cb.h)) {
                let key = alpha_key(cb.section, &self.cbfs[cb.section].alpha, cb.level);
                return Err(c.invalid(key, why));
            }
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
            units: sys.units.clone(),
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
    // A step past the horizon would stretch it to one step silently (`steps` rounds up).
    if dt > horizon {
        return Err(c.invalid(
            "reach.dt",
            format!(
                "dt {} is longer than the horizon {}: expected dt ≤ horizon",
                limits::shown(dt),
                limits::shown(horizon)
            ),
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
    let time = crate::reach::TimeModel::parse(
        r.time.as_deref().unwrap_or("continuous"),
        r.control_period,
        dt,
    )
    .map_err(|e| c.invalid(e.field(), e.to_string()))?;
    let substeps = r.substeps.unwrap_or(1);
    if substeps == 0 {
        return Err(c.invalid("reach.substeps", "expected a whole number ≥ 1"));
    }
    time.check_substeps(substeps)
        .map_err(|e| c.invalid("reach.substeps", e))?;
    let steps = (horizon / dt).ceil() * substeps as f64;
    if steps.is_nan() || steps > limits::MAX_STEPS {
        return Err(c.invalid(
            "reach.horizon",
            format!(
                "horizon {} / dt {} × {substeps} substep(s) is {steps:.3e} steps, more than {:.0e} (a longer dt or a shorter horizon)",
                limits::shown(horizon),
                limits::shown(dt),
                limits::MAX_STEPS
            ),
        ));
    }
    if let Some(k) = r.turned_frames {
        if !(1..=limits::MAX_TURNED_FRAMES).contains(&k) {
            return Err(c.invalid(
                "reach.turned_frames",
                format!(
                    "expected a whole number from 1 (none turned) to {}, found {k}",
                    limits::MAX_TURNED_FRAMES
                ),
            ));
        }
    }
    Ok(ReachConfig {
        time,
        substeps,
        turned_frames: r.turned_frames,
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

#[cfg(test)]
mod tests {
    use crate::scenario::Scenario;

    /// An input that does not act on a state adds no term to its closed loop: a Dubins car's
    /// `f̃[x]` read `cos(theta) + 0 * (−2·(…)/sqrt(…))` (the controller divides, so collecting
    /// kept the zero term) and its high-order CBF carried the copy. Where `g` is not zero the
    /// term stays.
    #[test]
    fn an_input_that_does_not_act_on_a_state_adds_no_term() {
        let text = r#"
name = "dubins"
[system]
states = ["x", "y", "theta"]
inputs = ["w"]
f = ["cos(theta)", "sin(theta)", "0"]
g = [["0"], ["0"], ["1"]]
kappa = ["-2*(y*cos(theta) - x*sin(theta))/sqrt(x^2 + y^2 + 0.01)"]
[[cbf]]
h = "(x + 1.5)^2 + (y - 0.3)^2 - 0.16"
order = 2
[reach]
region = { lower = [-3.5, -1.5, -3], upper = [0.5, 1.5, 3] }
m_c = 0.1
dt = 0.02
horizon = 1.0
goal = { lower = [-0.4, -0.4, -3], upper = [0.4, 0.4, 3] }
"#;
        let s = Scenario::from_toml(text, "dubins.toml", std::path::Path::new(".")).unwrap();
        let shown = |e: &crate::expressions::Expr| e.display(&s.states).to_string();
        assert_eq!(shown(&s.f_tilde[0]), "cos(theta)");
        assert_eq!(shown(&s.f_tilde[1]), "sin(theta)");
        assert!(
            shown(&s.f_tilde[2]).contains("sqrt"),
            "{}",
            shown(&s.f_tilde[2])
        );
        let psi = shown(&s.cbfs[1].h);
        assert!(!psi.contains("sqrt") && !psi.contains("0 *"), "{psi}");
        // The same closed loop at points: f̃ = f + g·κ.
        for x in [[-2.0, 0.5, 0.3], [0.2, -1.0, -2.0]] {
            let k = s.kappa_at(&x);
            let f = s.f_tilde_at(&x);
            assert_eq!((f[0], f[1]), (x[2].cos(), x[2].sin()));
            assert!((f[2] - k[0]).abs() < 1e-15, "{f:?} {k:?}");
        }
    }
}

//! Numbers written as expressions (parameters, bounds, boxes) and periodic states: the parts
//! of compiling a scenario that evaluate constants. May import `expressions` and `boxes`.

use std::collections::BTreeMap;

use super::compile::Compiler;
use super::{Number, ReachConfig, ScenarioError};
use crate::expressions;

/// A state defined modulo a period: `x_state` and `x_state + (upper − lower)` are one state.
#[derive(Clone, Debug, PartialEq)]
pub struct Periodic {
    /// Index of the state.
    pub state: usize,
    /// Start of the period.
    pub lower: f64,
    /// End of the period.
    pub upper: f64,
}

impl Periodic {
    /// The period's length.
    pub fn period(&self) -> f64 {
        self.upper - self.lower
    }
}

impl Compiler<'_> {
    /// A number as written: a plain finite number, or an expression in the parameters alone.
    pub(super) fn number(&self, key: &str, v: &Number) -> Result<f64, ScenarioError> {
        match v {
            Number::Value(v) => self.finite(key, *v),
            Number::Expr(text) => {
                let e = self.parse_over(key, text, &[])?;
                let v = e.eval(&[]);
                if v.is_finite() {
                    Ok(v)
                } else {
                    Err(self.invalid(key, format!("`{text}` is {v}, expected a finite number")))
                }
            }
        }
    }

    pub(super) fn numbers(&self, key: &str, vs: &[Number]) -> Result<Vec<f64>, ScenarioError> {
        vs.iter()
            .enumerate()
            .map(|(i, v)| self.number(&format!("{key}[{i}]"), v))
            .collect()
    }
}

/// The parameters' values: numbers as they are, expressions in the other parameters evaluated
/// in the order their names become known (a parameter may use any other, in any order, but
/// not itself, directly or through others).
pub(super) fn resolve_parameters(
    file: &str,
    written: &BTreeMap<String, Number>,
    states: &[String],
) -> Result<BTreeMap<String, f64>, ScenarioError> {
    let invalid = |key: &str, message: String| ScenarioError::Invalid {
        file: file.to_string(),
        key: format!("parameters.{key}"),
        message,
    };
    let mut known = BTreeMap::new();
    for (k, v) in written {
        if k == "pi" || expressions::Func::from_name(k).is_some() {
            return Err(invalid(
                k,
                "the name of a function or constant of the expressions".into(),
            ));
        }
        if states.contains(k) {
            return Err(invalid(
                k,
                "a parameter cannot share its name with a state".into(),
            ));
        }
        if let Number::Value(v) = v {
            if !v.is_finite() {
                return Err(invalid(k, format!("expected a finite number, found {v}")));
            }
            known.insert(k.clone(), *v);
        }
    }
    let mut pending: Vec<(&String, &String)> = written
        .iter()
        .filter_map(|(k, v)| match v {
            Number::Expr(text) => Some((k, text)),
            Number::Value(_) => None,
        })
        .collect();
    while !pending.is_empty() {
        let before = pending.len();
        let mut failed = None;
        pending.retain(|(k, text)| match expressions::parse(text, &[], &known) {
            Ok(e) => {
                known.insert((*k).clone(), e.eval(&[]));
                false
            }
            Err(source) => {
                failed.get_or_insert((k.to_string(), text.to_string(), source));
                true
            }
        });
        // No progress: the first failure is an unknown name, a cycle or a syntax error.
        if let (true, Some((key, text, source))) = (pending.len() == before, failed) {
            return Err(ScenarioError::Expression {
                file: file.to_string(),
                key: format!("parameters.{key}"),
                text,
                source,
            });
        }
    }
    for (k, v) in &known {
        if !v.is_finite() {
            return Err(invalid(
                k,
                format!("evaluates to {v}, expected a finite number"),
            ));
        }
    }
    Ok(known)
}

/// `[system] periodic`: each name a state, each period `[lower, upper]` with `lower < upper`.
/// The embedding does not wrap sets around a period, so `C` and the initial boxes must lie
/// within one period along each periodic state: a set that crosses the period's end then
/// leaves `C` and is reported, never silently wrapped.
pub(super) fn compile_periodic(
    c: &Compiler,
    written: &BTreeMap<String, Vec<Number>>,
    reach: &ReachConfig,
) -> Result<Vec<Periodic>, ScenarioError> {
    let mut out = Vec::new();
    for (name, bounds) in written {
        let key = format!("system.periodic.{name}");
        let Some(state) = c.states.iter().position(|s| s == name) else {
            return Err(c.invalid(
                key,
                format!("`{name}` is not a state (states: {})", c.states.join(", ")),
            ));
        };
        let v = c.numbers(&key, bounds)?;
        let [lower, upper] = v[..] else {
            return Err(c.invalid(
                key,
                "expected a period [lower, upper], e.g. [\"-pi\", \"pi\"]",
            ));
        };
        if lower >= upper {
            return Err(c.invalid(
                key,
                format!("expected lower < upper, found [{lower}, {upper}]"),
            ));
        }
        let p = Periodic {
            state,
            lower,
            upper,
        };
        let named = std::iter::once(("reach.region".to_string(), &reach.region)).chain(
            reach
                .initial
                .iter()
                .enumerate()
                .map(|(k, b)| (format!("reach.initial[{k}]"), b)),
        );
        for (where_, b) in named {
            let (lo, hi) = (b.lower[state], b.upper[state]);
            if lo < lower - 1e-12 * p.period() || hi > upper + 1e-12 * p.period() {
                return Err(c.invalid(
                    where_,
                    format!(
                        "`{name}` spans [{lo}, {hi}], outside its period [{lower}, {upper}]: sets \
                         are not wrapped around a period, so C and the initial boxes must lie \
                         within one (a set that reaches the period's end leaves C and is \
                         reported)"
                    ),
                ));
            }
        }
        out.push(p);
    }
    Ok(out)
}

//! The class-K function `α` of a CBF's constraint `∇h·(f̃ + gθ) ≥ −α(h)` ([`ClassK`]): a gain
//! (`α(h) = a·h`, the paper's) or a function of `h` (`α(h) = 0.5h + h³`, `tanh(h)`, …). Where
//! the filter's rows are built, evaluated or enclosed they ask this type for `α(h)`, so a
//! nonlinear `α` reaches the closed form, the active-set pieces, the enclosures and the GPU's
//! generated code alike; the sampled-data model's proof of `S` between samples asks for its
//! slope ([`ClassK::slope_over`]).
//!
//! What makes `S` invariant (Nagumo) is `α(0) = 0` and a Lipschitz `α`; a class-K `α` is also
//! positive and increasing on `h > 0`. [`ClassK::check`] refuses the rest, naming the value.

use std::fmt;

use crate::expressions::Expr;
use crate::intervals::Interval;

/// `α` of one CBF.
#[derive(Clone, Debug)]
pub struct ClassK {
    /// `α(h)` as an expression in one variable, `h` (variable 0).
    pub expr: Expr,
    /// `a` where `α(h) = a·h` (a number in the file, an expression without `h`, or one whose
    /// derivative is the constant `a` with `α(0) = 0`): evaluated as the product `a·h`, exactly
    /// as before functions were allowed, so that results and the filter's hash stay the same.
    pub gain: Option<f64>,
    /// As written (a gain: its value), for reports.
    pub text: String,
}

/// How close to 0 the outward-rounded enclosure of `α(0)` must lie: interval evaluation widens
/// an exact 0 by the smallest numbers (`h³`, `tanh(h)` pass), not by more (`h + 1e-12` fails,
/// and so does `(1 + h) − 1`, whose enclosure at 0 is a rounding of 1 wide).
const ZERO_WITHIN: f64 = 1e-300;

/// Points of `[0, h_max]` at which [`ClassK::check`] tests that `α` is positive and increasing.
const CHECK_POINTS: usize = 1000;

impl ClassK {
    /// `α(h) = a·h`.
    pub fn gain(a: f64) -> ClassK {
        ClassK {
            expr: Expr::constant(a) * Expr::variable(0),
            gain: Some(a),
            text: format!("{a}"),
        }
    }

    /// `α(h) = expr(h)` written as `text`; a gain where `expr` is one.
    pub fn function(expr: Expr, text: &str) -> ClassK {
        let gain = (expr.derivative(0).as_constant()).filter(|_| expr.eval(&[0.0]) == 0.0);
        ClassK {
            expr,
            gain,
            text: text.trim().to_string(),
        }
    }

    /// `α(h)`.
    pub fn at(&self, h: f64) -> f64 {
        match self.gain {
            Some(a) => a * h,
            None => self.expr.eval(&[h]),
        }
    }

    /// An enclosure of `α` over `h`, outward rounded.
    pub fn over(&self, h: Interval) -> Interval {
        match self.gain {
            Some(a) => h * a,
            None => self.expr.eval_interval(&[h]),
        }
    }

    /// `α(h)` as an expression in whatever `h` is (the CBF's `h(x)`, or `max(h(x), 0)`).
    pub fn of(&self, h: Expr) -> Expr {
        match self.gain {
            Some(a) => Expr::constant(a) * h,
            None => self.expr.substitute(&[h]),
        }
    }

    /// An enclosure of `α'` over `h`.
    pub fn slope_over(&self, h: Interval) -> Interval {
        match self.gain {
            Some(a) => Interval::point(a),
            None => self.expr.derivative(0).eval_interval(&[h]),
        }
    }

    /// Why `α` is not a class-K function on `[0, h_max]` (`h_max()`: the largest `h` on `C`,
    /// asked for by a function alone), or `None`: a gain must be positive; a function must have
    /// `α(0) = 0` (its f64 value, and its outward-rounded enclosure within [`ZERO_WITHIN`] of
    /// 0), a finite slope at 0 (Lipschitz there: `√h` is not, and uniqueness of the filtered
    /// system's trajectories, hence the invariance of `S`, needs it), and be positive and
    /// increasing at [`CHECK_POINTS`] points of `(0, h_max]`.
    pub fn check(&self, h_max: impl FnOnce() -> f64) -> Option<String> {
        if let Some(a) = self.gain {
            return (!(a.is_finite() && a > 0.0))
                .then(|| format!("the class-K gain must be positive and finite, found {a}"));
        }
        let at0 = self.expr.eval(&[0.0]);
        let enclosed = self.expr.eval_interval(&[Interval::point(0.0)]);
        let tiny = ZERO_WITHIN;
        if at0 != 0.0 || !(enclosed.lower >= -tiny && enclosed.upper <= tiny) {
            return Some(format!(
                "α(0) = {at0} (enclosed in [{:e}, {:e}]): a class-K function has α(0) = 0",
                enclosed.lower, enclosed.upper
            ));
        }
        let slope0 = self.expr.derivative(0).eval(&[0.0]);
        if !slope0.is_finite() {
            return Some(format!(
                "α'(0) = {slope0}: α must be Lipschitz at 0 (so that the filtered system's \
                 trajectories are unique and S is invariant), e.g. not √h"
            ));
        }
        let h_max = h_max();
        if !(h_max.is_finite() && h_max > 0.0) {
            return None;
        }
        let mut last = 0.0;
        for k in 1..=CHECK_POINTS {
            let s = h_max * k as f64 / CHECK_POINTS as f64;
            let a = self.expr.eval(&[s]);
            if !(a.is_finite() && a > 0.0) {
                return Some(format!(
                    "α({s:.6}) = {a}: a class-K function is positive for h > 0 (checked on \
                     [0, {h_max:.6}], the values of h on C)"
                ));
            }
            if a < last {
                return Some(format!(
                    "α falls from {last} to {a} at h = {s:.6}: a class-K function increases \
                     (checked on [0, {h_max:.6}], the values of h on C)"
                ));
            }
            last = a;
        }
        None
    }
}

impl fmt::Display for ClassK {
    /// `2·h` for a gain, else the function as written.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.gain {
            Some(a) => write!(f, "{a}·h"),
            None => write!(f, "{}", self.text),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::expressions::parse;
    use std::collections::BTreeMap;

    fn alpha(text: &str) -> ClassK {
        let e = parse(text, &["h".to_string()], &BTreeMap::new()).expect("parses");
        ClassK::function(e, text)
    }

    #[test]
    fn a_linear_function_is_a_gain() {
        for text in ["2*h", "h*2", "h + h"] {
            let a = alpha(text);
            assert_eq!(a.gain, Some(2.0), "{text}");
            assert_eq!(a.at(0.3), ClassK::gain(2.0).at(0.3));
            assert_eq!(a.to_string(), "2·h");
        }
        assert_eq!(ClassK::gain(1.5).to_string(), "1.5·h");
        assert!(alpha("h^3").gain.is_none());
        assert_eq!(alpha(" h^3 ").to_string(), "h^3");
    }

    #[test]
    fn values_enclosures_and_slopes_agree() {
        let a = alpha("0.5*h + h^3");
        assert!((a.at(2.0) - 9.0).abs() < 1e-15);
        let over = a.over(Interval::new(1.0, 2.0));
        assert!(over.lower <= 1.5 && over.upper >= 9.0 && over.upper < 9.0 + 1e-12);
        let slope = a.slope_over(Interval::new(0.0, 1.0));
        assert!(slope.lower <= 0.5 && slope.upper >= 3.5 && slope.upper < 3.5 + 1e-12);
        // Substituted into an expression of x: α(2x₀) at x₀ = 0.5 is α(1).
        let h = Expr::constant(2.0) * Expr::variable(0);
        assert!((a.of(h).eval(&[0.5]) - 1.5).abs() < 1e-15);
    }

    #[test]
    fn what_is_not_class_k_is_refused_by_what_fails() {
        assert!(alpha("h^3").check(|| 10.0).is_none());
        assert_eq!(alpha("tanh(h)").check(|| 10.0), None);
        assert!(alpha("h/(1 + h)").check(|| 10.0).is_none());
        let said = |t: &str| alpha(t).check(|| 4.0).unwrap_or_default();
        assert!(said("h + 1").contains("α(0) = 1"), "{}", said("h + 1"));
        assert!(said("sqrt(h)").contains("Lipschitz"), "{}", said("sqrt(h)"));
        assert!(said("-h^3").contains("positive"), "{}", said("-h^3"));
        // Increasing up to h = 1, falling beyond: refused only where h reaches past 1.
        assert!(said("2*h - h^2").contains("falls"), "{}", said("2*h - h^2"));
        assert!(alpha("2*h - h^2").check(|| 0.9).is_none());
        assert!(ClassK::gain(-1.0)
            .check(|| 1.0)
            .unwrap()
            .contains("positive"));
        assert!(ClassK::gain(f64::NAN).check(|| 1.0).is_some());
    }
}

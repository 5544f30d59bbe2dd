//! Which two states a picture shows and where it cuts the others: pictures of systems with
//! more than two states are projections onto two chosen states, or slices through
//! hyperplanes `x_k = c` (`--axes p,v --slice a=0`), or both. Imports boxes and the scenario.

use crate::boxes::IntervalBox;
use crate::scenario::Scenario;

use super::PlotError;

/// The two states drawn and the slices through the others. A state neither drawn nor sliced
/// is projected: a set is drawn by its extent along the two drawn states whatever its extent
/// along that state.
#[derive(Clone, Debug, PartialEq)]
pub struct View {
    /// The state on the horizontal axis.
    pub x: usize,
    /// The state on the vertical axis.
    pub y: usize,
    /// `(state, value)`: only the sets that contain `value` along `state` are drawn.
    pub slice: Vec<(usize, f64)>,
}

impl Default for View {
    /// The first two states, no slice: the whole picture of a planar system.
    fn default() -> View {
        View {
            x: 0,
            y: 1,
            slice: Vec::new(),
        }
    }
}

impl View {
    /// The view of `--axes A,B` (state names; default the first two states) and `--slice
    /// NAME=VALUE` (repeatable), checked against the scenario's states.
    pub fn parse(
        scenario: &Scenario,
        axes: Option<&str>,
        slices: &[String],
    ) -> Result<View, PlotError> {
        let n = scenario.n();
        let state = |name: &str, option: &str| {
            scenario
                .states
                .iter()
                .position(|s| s == name.trim())
                .ok_or_else(|| {
                    PlotError::Input(format!(
                        "{option}: `{}` is not a state of {} (states: {})",
                        name.trim(),
                        scenario.file,
                        scenario.states.join(", ")
                    ))
                })
        };
        let (x, y) = match axes {
            Some(text) => {
                let (a, b) = text.split_once(',').ok_or_else(|| {
                    PlotError::Input(format!(
                        "--axes: expected two state names, e.g. {}, found `{text}`",
                        scenario.states[..n.min(2)].join(",")
                    ))
                })?;
                (state(a, "--axes")?, state(b, "--axes")?)
            }
            None => (0, 1),
        };
        if n < 2 {
            return Err(PlotError::Input(format!(
                "{}: pictures need at least 2 states, it has {n}",
                scenario.file
            )));
        }
        if x == y {
            return Err(PlotError::Input(format!(
                "--axes: the two axes must be different states, found `{}` twice",
                scenario.states[x]
            )));
        }
        let mut view = View {
            x,
            y,
            slice: Vec::new(),
        };
        for text in slices {
            let (name, value) = text.split_once('=').ok_or_else(|| {
                PlotError::Input(format!(
                    "--slice: expected NAME=VALUE, e.g. {}=0, found `{text}`",
                    scenario.states[n - 1]
                ))
            })?;
            let k = state(name, "--slice")?;
            let value: f64 = value
                .trim()
                .parse()
                .ok()
                .filter(|v: &f64| v.is_finite())
                .ok_or_else(|| {
                    PlotError::Input(format!("--slice {text}: `{value}` is not a finite number"))
                })?;
            if k == x || k == y || view.slice.iter().any(|&(j, _)| j == k) {
                return Err(PlotError::Input(format!(
                    "--slice {text}: `{}` is drawn or sliced already",
                    scenario.states[k]
                )));
            }
            view.slice.push((k, value));
        }
        Ok(view)
    }

    /// Whether the picture shows every state: each is drawn or sliced.
    pub fn is_whole(&self, n: usize) -> bool {
        2 + self.slice.len() == n
    }

    /// Whether a set is drawn: it meets every slice's hyperplane.
    pub fn keeps(&self, b: &IntervalBox) -> bool {
        self.slice
            .iter()
            .all(|&(k, v)| b.lower[k] <= v && v <= b.upper[k])
    }

    /// Whether a point is drawn (it lies within `tol` of every slice's hyperplane).
    pub fn keeps_point(&self, x: &[f64], tol: f64) -> bool {
        self.slice.iter().all(|&(k, v)| (x[k] - v).abs() <= tol)
    }

    /// A point's place in the picture.
    pub fn point(&self, x: &[f64]) -> (f64, f64) {
        (x[self.x], x[self.y])
    }

    /// A box's extent along the drawn states.
    pub fn plane(&self, b: &IntervalBox) -> IntervalBox {
        IntervalBox {
            lower: vec![b.lower[self.x], b.lower[self.y]],
            upper: vec![b.upper[self.x], b.upper[self.y]],
        }
    }

    /// A full point for the picture's point `(px, py)`: the slices' values, the centre of
    /// `region` along the projected states.
    pub fn lift(&self, region: &IntervalBox, px: f64, py: f64) -> Vec<f64> {
        let mut x = region.center();
        x[self.x] = px;
        x[self.y] = py;
        for &(k, v) in &self.slice {
            x[k] = v;
        }
        x
    }

    /// For captions: what the picture is of (empty for a planar system's whole picture).
    pub fn describe(&self, scenario: &Scenario) -> String {
        let n = scenario.n();
        if n == 2 {
            return String::new();
        }
        let mut parts: Vec<String> = self
            .slice
            .iter()
            .map(|&(k, v)| format!("{} = {v}", scenario.states[k]))
            .collect();
        let projected: Vec<&str> = (0..n)
            .filter(|&k| k != self.x && k != self.y && self.slice.iter().all(|&(j, _)| j != k))
            .map(|k| scenario.states[k].as_str())
            .collect();
        if !projected.is_empty() {
            parts.push(format!("projected along {}", projected.join(", ")));
        }
        format!(" [{}]", parts.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chain3() -> Scenario {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/chain3.toml");
        Scenario::load(&path).unwrap()
    }

    #[test]
    fn a_view_names_states_and_refuses_what_is_not_one() {
        let s = chain3();
        let v = View::parse(&s, Some("p,a"), &["v=0.5".into()]).unwrap();
        assert_eq!((v.x, v.y, v.slice.clone()), (0, 2, vec![(1, 0.5)]));
        assert!(v.is_whole(3));
        let b = IntervalBox::new(vec![0.0, 0.0, 1.0], vec![1.0, 1.0, 2.0]).unwrap();
        assert!(v.keeps(&b));
        assert_eq!(v.plane(&b).upper, vec![1.0, 2.0]);
        let off = IntervalBox::new(vec![0.0, 0.6, 1.0], vec![1.0, 1.0, 2.0]).unwrap();
        assert!(!v.keeps(&off));
        assert_eq!(v.lift(&s.reach.region, 1.0, 2.0), vec![1.0, 0.5, 2.0]);
        assert_eq!(v.describe(&s), " [v = 0.5]");
        let projected = View::parse(&s, None, &[]).unwrap();
        assert_eq!(projected.describe(&s), " [projected along a]");
        for (axes, slices, needle) in [
            (Some("p,q"), vec![], "`q` is not a state"),
            (Some("p"), vec![], "expected two state names"),
            (Some("p,p"), vec![], "must be different"),
            (None, vec!["a".to_string()], "expected NAME=VALUE"),
            (None, vec!["a=x".to_string()], "not a finite number"),
            (None, vec!["p=0".to_string()], "drawn or sliced already"),
        ] {
            let e = View::parse(&s, axes, &slices).unwrap_err().to_string();
            assert!(e.contains(needle), "{e}");
        }
    }
}

//! Which two states a picture shows and where it cuts the others: pictures of systems with
//! more than two states are projections onto two chosen states, or slices through
//! hyperplanes `x_k = c` (`--axes p,v --slice a=0`), or both; or one state against time
//! (`--axes t,p`, the default for a one-state system). Imports boxes and the scenario.

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
    /// Time across and the state `y` up (`x == y` then): tubes and trajectories over time.
    pub time: bool,
}

impl Default for View {
    /// The first two states, no slice: the whole picture of a planar system.
    fn default() -> View {
        View {
            x: 0,
            y: 1,
            slice: Vec::new(),
            time: false,
        }
    }
}

impl View {
    /// The first two states, or with one state that state over time: what [`View::parse`]
    /// gives without `--axes` and `--slice`.
    pub fn first(n: usize) -> View {
        match n {
            1 => View {
                x: 0,
                y: 0,
                slice: Vec::new(),
                time: true,
            },
            _ => View::default(),
        }
    }

    /// The view of `--axes A,B` (state names, default the first two states; `t` or `time`
    /// first, where no state has that name, for one state over time, the default with one
    /// state) and `--slice NAME=VALUE` (repeatable), checked against the scenario's states.
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
        let is_time = |name: &str| {
            let name = name.trim();
            matches!(name, "t" | "time") && !scenario.states.iter().any(|s| s == name)
        };
        let (x, y, time) = match axes {
            Some(text) => {
                let (a, b) = text.split_once(',').ok_or_else(|| {
                    PlotError::Input(format!(
                        "--axes: expected two state names (or t and a state), e.g. {}, found \
                         `{text}`",
                        scenario.states[..n.min(2)].join(",")
                    ))
                })?;
                match is_time(a) {
                    true => {
                        let y = state(b, "--axes")?;
                        (y, y, true)
                    }
                    false => (state(a, "--axes")?, state(b, "--axes")?, false),
                }
            }
            None => {
                let first = View::first(n);
                (first.x, first.y, first.time)
            }
        };
        if n < 2 && !time {
            return Err(PlotError::Input(format!(
                "{}: a picture over two states needs 2, it has {n}: draw it over time \
                 (--axes t,{})",
                scenario.file, scenario.states[0]
            )));
        }
        if x == y && !time {
            return Err(PlotError::Input(format!(
                "--axes: the two axes must be different states, found `{}` twice",
                scenario.states[x]
            )));
        }
        let mut view = View {
            x,
            y,
            slice: Vec::new(),
            time,
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
        let drawn = if self.time { 1 } else { 2 };
        drawn + self.slice.len() == n
    }

    /// The projected states of an `n`-state system: neither drawn nor sliced.
    pub fn projected(&self, n: usize) -> impl Iterator<Item = usize> + '_ {
        (0..n).filter(|&k| k != self.x && k != self.y && self.slice.iter().all(|&(j, _)| j != k))
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
        if self.is_whole(n) && self.slice.is_empty() {
            return String::new();
        }
        let mut parts: Vec<String> = self
            .slice
            .iter()
            .map(|&(k, v)| {
                let name = &scenario.states[k];
                match scenario.units.get(name) {
                    Some(unit) => format!("{name} = {v} {unit}"),
                    None => format!("{name} = {v}"),
                }
            })
            .collect();
        let projected: Vec<&str> = (self.projected(n))
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
        // A slice carries its state's unit (`[system] units`).
        let mut with_units = s.clone();
        with_units.units.insert("v".into(), "m/s".into());
        assert_eq!(v.describe(&with_units), " [v = 0.5 m/s]");
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

    /// `t` (or `time`) first draws one state over time, the default for one state; a state
    /// named `t` is that state.
    #[test]
    fn time_is_an_axis_unless_a_state_is_named_so() {
        let s = chain3();
        let v = View::parse(&s, Some("t,v"), &["a=0".into()]).unwrap();
        assert!(v.time && v.y == 1 && v.x == 1, "{v:?}");
        assert!(!v.is_whole(3));
        assert_eq!(v.describe(&s), " [a = 0; projected along p]");
        assert!(View::parse(&s, Some("time, p"), &[]).unwrap().time);
        assert!(!View::parse(&s, None, &[]).unwrap().time);
        let e = View::parse(&s, Some("t,v"), &["v=0".into()]).unwrap_err();
        assert!(e.to_string().contains("drawn or sliced already"), "{e}");
        let mut named_t = s.clone();
        named_t.states[0] = "t".into();
        let v = View::parse(&named_t, Some("t,v"), &[]).unwrap();
        assert!(!v.time && (v.x, v.y) == (0, 1), "{v:?}");
        let mut one = s.clone();
        one.states.truncate(1);
        let v = View::parse(&one, None, &[]).unwrap();
        assert!(v.time && v.y == 0 && v.is_whole(1) && v.describe(&one).is_empty());
    }
}

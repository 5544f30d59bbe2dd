//! The unsafe set seen in a picture that projects states. Over a point of the picture the
//! projected states (neither drawn nor sliced) range over the region, so the unsafe set lies
//! over it for every value of them, for some, or for none: a projection shows its *shadow*,
//! two tones, where a slice shows the set itself. Each point is decided by a best-first
//! branch and bound over the projected states on the CBFs' interval enclosures, with a
//! budget (a picture, not a proof: a sliver of the unsafe set that the search does not find
//! within the budget is not shaded; `Every` is shaded only where the enclosures prove it).
//! `Every` is of `S`'s complement, all CBFs, as a slice shades it; `Some` is of the
//! constraints as written, without the levels `ψₖ` that `order` writes.

use std::cmp::Ordering;
use std::collections::BinaryHeap;

use super::View;
use crate::boxes::IntervalBox;
use crate::intervals::Interval;
use crate::scenario::{Cbf, Scenario};

/// How the unsafe set lies over a point of a picture.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Shade {
    /// Every value of the projected states is safe (or no unsafe value was found).
    Clear,
    /// Some value of the projected states is unsafe by a constraint as written (a witness was
    /// found).
    Some,
    /// Every value is unsafe; in a slice or a planar picture, the point is unsafe.
    Every,
}

/// Boxes of the projected states a point's search may bound, for each of its two questions.
const BUDGET: usize = 48;

/// The shadow of `scenario`'s unsafe set over the pictures of one view of `region`.
pub(super) struct Shadow<'a> {
    scenario: &'a Scenario,
    pub(super) region: &'a IntervalBox,
    pub(super) view: &'a View,
    /// The projected states.
    hidden: Vec<usize>,
    /// The region's widths, to split the projected states in proportion.
    widths: Vec<f64>,
}

impl<'a> Shadow<'a> {
    pub(super) fn new(view: &'a View, scenario: &'a Scenario, region: &'a IntervalBox) -> Self {
        let n = scenario.n().min(region.dim());
        let hidden = view.projected(n).collect();
        Shadow {
            scenario,
            region,
            view,
            hidden,
            widths: region.widths(),
        }
    }

    /// The names of the projected states (none in a slice or a planar picture).
    pub(super) fn projected<'s>(&'s self) -> impl Iterator<Item = &'s str> + 's {
        (self.hidden.iter()).map(|&k| self.scenario.states[k].as_str())
    }

    /// The shade over the picture's point `(px, py)` (`px` is ignored over time).
    pub(super) fn at(&self, px: f64, py: f64) -> Shade {
        self.shade(px, py, Question::SomeUnsafe)
    }

    /// [`Shadow::at`], asking only whether every value is unsafe (`Clear` where not): the
    /// pictures over one state draw nothing else.
    pub(super) fn every_at(&self, px: f64, py: f64) -> Shade {
        self.shade(px, py, Question::EveryUnsafe)
    }

    /// The shade over `(px, py)`, the pale one asked for only down to `last`.
    fn shade(&self, px: f64, py: f64, last: Question) -> Shade {
        let point = self.view.lift(self.region, px, py);
        if self.hidden.is_empty() {
            return match self.scenario.is_safe(&point) {
                true => Shade::Clear,
                false => Shade::Every,
            };
        }
        let whole: Vec<Interval> = (0..point.len())
            .map(|k| match self.hidden.contains(&k) {
                true => Interval::new(self.region.lower[k], self.region.upper[k]),
                false => Interval::point(point[k]),
            })
            .collect();
        if self.search(&whole, Question::EveryUnsafe) {
            Shade::Every
        } else if last == Question::SomeUnsafe && self.search(&whole, Question::SomeUnsafe) {
            Shade::Some
        } else {
            Shade::Clear
        }
    }

    /// Whether some CBF is a level `ψₖ` (k ≥ 1) written by `order`: the pale shadow is then
    /// of the constraints as written, since over the projected velocities some `ψₖ < 0` over
    /// nearly every point (a 6-state point mass past a ball: every point of (px, py)).
    pub(super) fn has_levels(&self) -> bool {
        self.scenario.cbfs.iter().any(|c| c.level > 0)
    }

    /// The CBFs a question asks about: every level for `EveryUnsafe` (outside `S`, as a slice
    /// shades it), the constraints as written (level 0) for `SomeUnsafe`.
    fn cbfs(&self, question: Question) -> impl Iterator<Item = &Cbf> {
        (self.scenario.cbfs.iter())
            .filter(move |c| question == Question::EveryUnsafe || c.level == 0)
    }

    /// `minᵢ hᵢ` of the question's CBFs over a box, enclosed.
    fn enclose(&self, b: &[Interval], question: Question) -> Interval {
        (self.cbfs(question))
            .map(|c| c.h.eval_interval(b))
            .reduce(Interval::min)
            .unwrap_or(Interval::point(f64::INFINITY))
    }

    /// `minᵢ hᵢ` of the question's CBFs at a point.
    fn least(&self, x: &[f64], question: Question) -> f64 {
        (self.cbfs(question))
            .map(|c| c.h.eval(x))
            .fold(f64::INFINITY, f64::min)
    }

    /// Whether the question is answered yes within the budget: best first, the box whose
    /// enclosure is nearest a witness split along its widest projected state (relative to
    /// the region's width there).
    fn search(&self, whole: &[Interval], question: Question) -> bool {
        let mut queue = BinaryHeap::new();
        queue.push(Candidate {
            priority: f64::INFINITY,
            b: whole.to_vec(),
        });
        for _ in 0..BUDGET {
            let Some(Candidate { b, .. }) = queue.pop() else {
                // Every box was settled without a witness: the answer is no for `SomeUnsafe`,
                // and for `EveryUnsafe` every box was proven unsafe.
                return question == Question::EveryUnsafe;
            };
            let g = self.enclose(&b, question);
            let centre: Vec<f64> = b.iter().map(|i| 0.5 * (i.lower + i.upper)).collect();
            let at_centre = self.least(&centre, question);
            match question {
                Question::SomeUnsafe => {
                    if g.upper < 0.0 || at_centre < 0.0 {
                        return true;
                    }
                    if g.lower >= 0.0 || g.is_nan() {
                        continue;
                    }
                }
                Question::EveryUnsafe => {
                    if g.lower >= 0.0 || at_centre >= 0.0 || g.is_nan() {
                        return false;
                    }
                    if g.upper < 0.0 {
                        continue;
                    }
                }
            }
            let priority = match question {
                Question::SomeUnsafe => -g.lower,
                Question::EveryUnsafe => g.upper,
            };
            let widest = (self.hidden.iter().copied()).max_by(|&i, &j| {
                let rel = |k: usize| b[k].width() / self.widths[k].max(f64::MIN_POSITIVE);
                rel(i).total_cmp(&rel(j))
            });
            let Some(k) = widest else { break };
            let mid = 0.5 * (b[k].lower + b[k].upper);
            for half in [
                Interval::new(b[k].lower, mid),
                Interval::new(mid, b[k].upper),
            ] {
                let mut piece = b.clone();
                piece[k] = half;
                queue.push(Candidate { priority, b: piece });
            }
        }
        false
    }
}

/// What a point's search asks of the projected states.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Question {
    /// Is some value unsafe by a constraint as written? Yes on a witness (a centre, or a box
    /// proven unsafe).
    SomeUnsafe,
    /// Is every value unsafe? Yes where every box is proven unsafe.
    EveryUnsafe,
}

/// A box of the projected states waiting to be bounded, by its parent's distance from the
/// question's witness (larger first).
struct Candidate {
    priority: f64,
    b: Vec<Interval>,
}

impl PartialEq for Candidate {
    fn eq(&self, other: &Self) -> bool {
        self.priority.total_cmp(&other.priority) == Ordering::Equal
    }
}

impl Eq for Candidate {}

impl PartialOrd for Candidate {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl Ord for Candidate {
    fn cmp(&self, other: &Self) -> Ordering {
        self.priority.total_cmp(&other.priority)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    /// A point mass in space past a ball (kept by `order = 2`) and a wall at `px = 4.5`.
    fn point_mass() -> Scenario {
        let text = r#"
name = "shadow"
[system]
states = ["px", "py", "pz", "vx", "vy", "vz"]
inputs = ["ax", "ay", "az"]
f = ["vx", "vy", "vz", "0", "0", "0"]
g = [["0","0","0"],["0","0","0"],["0","0","0"],["1","0","0"],["0","1","0"],["0","0","1"]]
kappa = ["-px - 2*vx", "-py - 2*vy", "-pz - 2*vz"]
[[cbf]]
name = "ball"
h = "(px - 2)^2 + (py - 0.2)^2 + (pz - 0.1)^2 - 0.36"
order = 2
[[cbf]]
name = "wall"
h = "4.5 - px"
order = 2
[network]
file = "none.safetensors"
architecture = [6, 8, 3]
[reach]
region = { lower = [-1, -1.5, -1.5, -2, -2, -2], upper = [5, 1.5, 1.5, 2, 2, 2] }
dt = 0.05
horizon = 1.0
goal = { lower = [-0.3, -0.3, -0.3, -0.3, -0.3, -0.3], upper = [0.3, 0.3, 0.3, 0.3, 0.3, 0.3] }
"#;
        Scenario::from_toml(text, "shadow.toml", std::path::Path::new(".")).unwrap()
    }

    /// Over (px, py) the ball's shadow is its disc of radius 0.6 (some pz is inside it), pale;
    /// beyond the wall every state is unsafe. Away from the edges (by 0.01) the search decides
    /// each point, and against 4,000 random values of the projected states each shade holds:
    /// a `Some` point has an unsafe value by a written `h`, an `Every` point none in `S`.
    #[test]
    fn a_projection_shades_the_shadow_and_what_lies_over_every_value() {
        let scenario = point_mass();
        let region = scenario.reach.region.clone();
        let view = View::default();
        let shadow = Shadow::new(&view, &scenario, &region);
        assert_eq!(
            shadow.projected().collect::<Vec<_>>(),
            ["pz", "vx", "vy", "vz"]
        );
        let mut rng = ChaCha8Rng::seed_from_u64(7);
        let mut counts = [0; 3];
        for _ in 0..400 {
            let (px, py) = (rng.random_range(-1.0..5.0), rng.random_range(-1.5..1.5));
            let disc = ((px - 2.0f64).powi(2) + (py - 0.2f64).powi(2)).sqrt() - 0.6;
            let expected = if px > 4.51 {
                Some(Shade::Every)
            } else if disc < -0.01 && px < 4.49 {
                Some(Shade::Some)
            } else if disc > 0.01 && px < 4.49 {
                Some(Shade::Clear)
            } else {
                None
            };
            let shade = shadow.at(px, py);
            if let Some(expected) = expected {
                assert_eq!(shade, expected, "({px}, {py})");
            }
            counts[shade as usize] += 1;
            // Each shade against sampled values of the projected states.
            let mut x = view.lift(&region, px, py);
            let (mut written, mut in_s) = (false, false);
            for _ in 0..4000 {
                for (k, xk) in x.iter_mut().enumerate().skip(2) {
                    *xk = rng.random_range(region.lower[k]..region.upper[k]);
                }
                written |= scenario
                    .cbfs
                    .iter()
                    .any(|c| c.level == 0 && c.h.eval(&x) < 0.0);
                in_s |= scenario.is_safe(&x);
            }
            match shade {
                Shade::Every => assert!(!in_s, "({px}, {py}): a sampled state lies in S"),
                Shade::Clear if px < 4.49 => {
                    assert!(!written, "({px}, {py}): a sampled state is unsafe")
                }
                _ => {}
            }
        }
        assert!(counts.iter().all(|&c| c > 10), "{counts:?}");
    }

    /// Over (px, vx) the wall's level ψ₁ = (4.5 − px) − vx < 0 lies over every other value: the
    /// dark shade, as a slice would draw it, where the written `h` alone says nothing.
    #[test]
    fn a_level_that_the_drawn_states_decide_is_shaded_over_every_value() {
        let scenario = point_mass();
        let region = scenario.reach.region.clone();
        let view = View {
            x: 0,
            y: 3,
            slice: vec![],
            time: false,
        };
        let shadow = Shadow::new(&view, &scenario, &region);
        assert!(shadow.has_levels());
        for (px, vx, expected) in [
            (4.0, 1.0, Shade::Every),
            (3.0, 1.6, Shade::Every),
            (3.0, 1.4, Shade::Clear),
            (4.0, -1.0, Shade::Clear),
            (2.0, 0.0, Shade::Some),
        ] {
            assert_eq!(shadow.at(px, vx), expected, "({px}, {vx})");
            // Asked for the grey alone, the pale shadow reads clear.
            let grey = if expected == Shade::Every {
                Shade::Every
            } else {
                Shade::Clear
            };
            assert_eq!(shadow.every_at(px, vx), grey, "({px}, {vx})");
        }
    }

    /// With every other state sliced there is nothing to project: the shade is the point's.
    #[test]
    fn a_slice_shades_the_point_itself() {
        let scenario = point_mass();
        let region = scenario.reach.region.clone();
        let view = View {
            x: 0,
            y: 1,
            slice: vec![(2, 0.1), (3, 0.0), (4, 0.0), (5, 0.0)],
            time: false,
        };
        let shadow = Shadow::new(&view, &scenario, &region);
        for (px, py) in [(2.0, 0.2), (2.55, 0.2), (2.65, 0.2), (0.0, 0.0), (4.6, 0.0)] {
            let x = view.lift(&region, px, py);
            let expected = match scenario.is_safe(&x) {
                true => Shade::Clear,
                false => Shade::Every,
            };
            assert_eq!(shadow.at(px, py), expected, "({px}, {py})");
        }
    }
}

//! Intersecting the filtered system's sets with the safe set `S = {x : hᵢ(x) ≥ 0}`.
//!
//! The filter imposes `ḣᵢ ≥ −αᵢ(hᵢ)` wherever its QP is feasible, so every `hᵢ ≥ 0` is forward
//! invariant along the filtered system's trajectories (Nagumo; the CBF theorem). A trajectory
//! that starts in `S` stays in `S`, and any set that bounds it may be intersected with `S`.
//! The analysis already assumes the filter is defined along the trajectories it bounds (the
//! disturbance method needs `v(x) ∈ N(x) + [−M, M]` there), so this adds no assumption; it
//! narrows what the sets bound to trajectories that *start* in `S` (the safe part of each
//! initial box, which is all of it for the boxes `verify` runs). It applies to the disturbance
//! method only: the Minkowski method's boxes bound the NN system, which `S` does not constrain.
//!
//! Only the affine `hᵢ` are used (`h(x) = a·x + b`, e.g. scenario 2's velocity bound
//! `x₂ − x₂,min`): `S`'s half-space is then exact in the embedding's coordinates too
//! (`x = S z`, so `a·x + b = (aS)·z + b`), and intersecting a box with it is a closed-form
//! tightening of each coordinate. Why it matters: where the true system runs close to a
//! constraint that is also an edge of `C`, the over-approximation pokes out of `C` and the
//! result would be invalid, although the true set never leaves `S`.

use crate::boxes::IntervalBox;
use crate::intervals::Interval;
use crate::rounding::{div_down, div_up};
use crate::scenario::Scenario;

use super::Transform;

/// One affine CBF as a half-space `normal·z + offset ≥ 0` of the embedding's coordinates,
/// with enclosures of the exact coefficients.
#[derive(Clone, Debug, PartialEq)]
pub struct SafeHalfspace {
    /// The CBF's name, for reports.
    pub name: String,
    /// `aS` (or `a` without a transform), n enclosures.
    pub normal: Vec<Interval>,
    /// `b`.
    pub offset: Interval,
}

/// `S`'s affine half-spaces in the embedding's coordinates (to intersect the z-box with) and
/// in x (to intersect the parallelotope's x-bounding box with: `S·[z̲, z̄] ∩ H` lies in both).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SafeSet {
    /// In the embedding's coordinates `z`.
    pub z: Vec<SafeHalfspace>,
    /// In `x` (the same as `z` without a transform).
    pub x: Vec<SafeHalfspace>,
}

/// No half-spaces: nothing is clipped.
pub static NO_SAFE_SET: SafeSet = SafeSet {
    z: Vec::new(),
    x: Vec::new(),
};

impl SafeSet {
    /// The names of the CBFs whose half-spaces bound the sets (empty when none do).
    pub fn names(&self) -> Vec<&str> {
        self.x.iter().map(|h| h.name.as_str()).collect()
    }

    /// `S`'s walls in the embedding's coordinates (`n` of them): per coordinate, the bounds
    /// that the half-spaces on that coordinate alone put on every state of `S` (∓∞ where
    /// none), rounded outward; `None` where no half-space is on a single coordinate. No
    /// trajectory of the filtered system crosses them (design §7.1 item 1f).
    pub fn walls(&self, n: usize) -> Option<IntervalBox> {
        let mut walls = IntervalBox {
            lower: vec![f64::NEG_INFINITY; n],
            upper: vec![f64::INFINITY; n],
        };
        let zeros = vec![0.0; n];
        for hs in &self.z {
            for j in (0..n).filter(|&j| hs.only_on(j)) {
                match hs.tightening(j, &zeros, &zeros) {
                    Some(Tightening::Lower(b)) => walls.lower[j] = walls.lower[j].max(b),
                    Some(Tightening::Upper(b)) => walls.upper[j] = walls.upper[j].min(b),
                    None => {}
                }
            }
        }
        let any = walls
            .lower
            .iter()
            .chain(&walls.upper)
            .any(|v| v.is_finite());
        any.then_some(walls)
    }

    /// The half-spaces of the scenario's affine CBFs.
    pub fn of(scenario: &Scenario, transform: Option<&Transform>) -> SafeSet {
        SafeSet {
            z: halfspaces(scenario, transform),
            x: halfspaces(scenario, None),
        }
    }
}

fn halfspaces(scenario: &Scenario, transform: Option<&Transform>) -> Vec<SafeHalfspace> {
    let n = scenario.n();
    scenario
        .cbfs
        .iter()
        .filter_map(|cbf| {
            // Affine: no partial derivative depends on x. The coefficients are then enclosed
            // from h itself, `aⱼ = h(eⱼ) − h(0)` (a derivative such as the 1/3 of `x₂/3` has
            // no exact f64 value).
            if cbf
                .gradient
                .iter()
                .any(|d| (0..n).any(|i| d.uses_variable(i)))
            {
                return None;
            }
            let at = |j: Option<usize>| {
                let x: Vec<Interval> = (0..n)
                    .map(|i| Interval::point(if Some(i) == j { 1.0 } else { 0.0 }))
                    .collect();
                cbf.h.eval_interval(&x)
            };
            let offset = at(None);
            let a: Vec<Interval> = (0..n).map(|j| at(Some(j)) - offset).collect();
            let finite = |v: &Interval| v.lower.is_finite() && v.upper.is_finite();
            if !finite(&offset) || !a.iter().all(finite) || a.iter().all(|c| c.contains(0.0)) {
                return None;
            }
            let normal: Vec<Interval> = match transform {
                None => a,
                Some(t) => (0..n)
                    .map(|j| {
                        (0..n).fold(Interval::point(0.0), |acc, i| {
                            acc + a[i] * Interval::point(t.s[i * n + j])
                        })
                    })
                    .collect(),
            };
            Some(SafeHalfspace {
                name: cbf.name.clone(),
                normal,
                offset,
            })
        })
        .collect()
}

/// The set `[lower, upper]` of another frame (coordinates `z_g = S_g⁻¹x`, `other`; x itself
/// for `None`) as `2n` half-spaces of this frame's coordinates (`x = S_f z_f`, `this`), for
/// states in the x-box `x_box` (design §7.1 item 7). With `T_g` for `S_g⁻¹`,
/// `‖S_g⁻¹y − T_g y‖∞ ≤ ρ_g‖T_g y‖∞`, so row `r` holds `(T_g S_f z_f)ᵣ ∈ [lᵣ − ρ_g K, uᵣ + ρ_g K]`
/// with `K ≥ ‖T_g x‖∞` over `x_box` (the pad of [`Transform::to_z_box`],
/// [`Transform::pad_over`]); `T_g S_f` is enclosed entry by entry (`S_f` defines this frame's
/// coordinates exactly).
pub fn frame_halfspaces(
    this: Option<&Transform>,
    other: Option<&Transform>,
    set: &IntervalBox,
    x_box: &IntervalBox,
) -> Vec<SafeHalfspace> {
    let n = set.dim();
    let rows = frame_rows(this, other, n);
    let slack = Interval::point(frame_slack(other, x_box));
    let mut out = Vec::with_capacity(2 * n);
    for (r, row) in rows.chunks(n).enumerate() {
        // `row·z − (lᵣ − ρK) ≥ 0` and `−row·z + (uᵣ + ρK) ≥ 0`.
        out.push(SafeHalfspace {
            name: String::new(),
            normal: row.to_vec(),
            offset: -(Interval::point(set.lower[r]) - slack),
        });
        out.push(SafeHalfspace {
            name: String::new(),
            normal: row.iter().map(|&c| -c).collect(),
            offset: Interval::point(set.upper[r]) + slack,
        });
    }
    out
}

/// The rows of [`frame_halfspaces`]: `T_g S_f` enclosed entry by entry, row-major `n × n`.
/// The same for every set of the pair of frames (the GPU engine's constants for them).
pub fn frame_rows(this: Option<&Transform>, other: Option<&Transform>, n: usize) -> Vec<Interval> {
    let p = Interval::point;
    let t_g = |r: usize, k: usize| match other {
        Some(t) => t.t[r * n + k],
        None => f64::from(u8::from(r == k)),
    };
    let s_f = |k: usize, j: usize| match this {
        Some(t) => t.s[k * n + j],
        None => f64::from(u8::from(k == j)),
    };
    (0..n * n)
        .map(|e| {
            let (r, j) = (e / n, e % n);
            (0..n).fold(p(0.0), |acc, k| acc + p(t_g(r, k)) * p(s_f(k, j)))
        })
        .collect()
}

/// The pad `ρ_g K` of [`frame_halfspaces`] over `x_box`: 0 where the other frame is x itself.
pub fn frame_slack(other: Option<&Transform>, x_box: &IntervalBox) -> f64 {
    other
        .filter(|t| t.rho > 0.0)
        .map_or(0.0, |t| t.pad_over(x_box))
}

/// A bound on one coordinate implied by a half-space.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Tightening {
    /// `zⱼ ≥` this.
    Lower(f64),
    /// `zⱼ ≤` this.
    Upper(f64),
}

impl SafeHalfspace {
    /// Whether coordinate `j` alone enters the half-space (its bound on `zⱼ` is then a
    /// constant, whatever the box).
    pub fn only_on(&self, j: usize) -> bool {
        self.normal
            .iter()
            .enumerate()
            .all(|(k, c)| k == j || *c == Interval::point(0.0))
    }

    /// The bound on coordinate `j` over the box `[lo, hi]`: `normalⱼ zⱼ ≥ L` with
    /// `L ≤ −offset − Σ_{k≠j} normalₖ zₖ`, divided by every `normalⱼ` of its enclosure and
    /// rounded outward (exact where the arithmetic is: `x₂ + 2 ≥ 0` gives −2 itself). `None`
    /// where `normalⱼ`'s enclosure holds 0.
    pub fn tightening(&self, j: usize, lo: &[f64], hi: &[f64]) -> Option<Tightening> {
        let c = self.normal[j];
        if c.contains(0.0) {
            return None;
        }
        let rest = (0..lo.len())
            .filter(|&k| k != j && self.normal[k] != Interval::point(0.0))
            .fold(self.offset, |acc, k| {
                acc + self.normal[k] * Interval::new(lo[k], hi[k])
            });
        let l = (-rest).lower;
        Some(if c.lower > 0.0 {
            Tightening::Lower(div_down(l, c.lower).min(div_down(l, c.upper)))
        } else {
            Tightening::Upper(div_up(l, c.lower).max(div_up(l, c.upper)))
        })
    }
}

/// Intersects the box `[lower, upper]` with every half-space, one coordinate at a time
/// ([`SafeHalfspace::tightening`]); the result contains the exact intersection. Returns false,
/// leaving the box as it was, if the intersection is empty: the set then lies outside `S`,
/// which no true trajectory can, and callers must see that (`verify` reports such a set as
/// `unsafe`). shaders/embed.wgsl does the same on the device.
pub fn clip_to_safe_set(
    lower: &mut [f64],
    upper: &mut [f64],
    halfspaces: &[SafeHalfspace],
) -> bool {
    let (mut lo, mut hi) = (lower.to_vec(), upper.to_vec());
    for hs in halfspaces {
        for j in 0..lo.len() {
            match hs.tightening(j, &lo, &hi) {
                Some(Tightening::Lower(b)) => lo[j] = lo[j].max(b),
                Some(Tightening::Upper(b)) => hi[j] = hi[j].min(b),
                None => {}
            }
        }
    }
    if lo.iter().zip(&hi).any(|(l, h)| l > h) {
        return false;
    }
    lower.copy_from_slice(&lo);
    upper.copy_from_slice(&hi);
    true
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;

    fn halfspace(normal: &[f64], offset: f64) -> SafeHalfspace {
        SafeHalfspace {
            name: "h".into(),
            normal: normal.iter().map(|&v| Interval::point(v)).collect(),
            offset: Interval::point(offset),
        }
    }

    #[test]
    fn walls_are_the_bounds_on_single_coordinates() {
        let on_x2 = SafeSet {
            z: vec![halfspace(&[0.0, 1.0], 2.0), halfspace(&[-2.0, 0.0], 6.0)],
            x: vec![],
        };
        let w = on_x2.walls(2).unwrap();
        assert_eq!(
            (w.lower, w.upper),
            (vec![f64::NEG_INFINITY, -2.0], vec![3.0, f64::INFINITY])
        );
        let slanted = SafeSet {
            z: vec![halfspace(&[1.0, 1.0], 2.0)],
            x: vec![],
        };
        assert_eq!(slanted.walls(2), None);
        assert_eq!(NO_SAFE_SET.walls(2), None);
    }

    #[test]
    fn a_bound_on_one_coordinate_is_applied_exactly() {
        // x₂ + 2 ≥ 0.
        let hs = [halfspace(&[0.0, 1.0], 2.0)];
        let (mut lo, mut hi) = (vec![-1.0, -2.5], vec![1.0, 0.5]);
        assert!(clip_to_safe_set(&mut lo, &mut hi, &hs));
        assert_eq!((lo, hi), (vec![-1.0, -2.0], vec![1.0, 0.5]));
    }

    #[test]
    fn an_oblique_halfspace_keeps_every_point_of_the_intersection() {
        // x₁ + 2x₂ − 1 ≥ 0 and −x₁ + 0.5 ≥ 0 (upper bound on x₁) over [−3, 3]²: each corner
        // of the exact intersection polygon must stay inside the tightened box.
        let hs = [halfspace(&[1.0, 2.0], -1.0), halfspace(&[-1.0, 0.0], 0.5)];
        let (mut lo, mut hi) = (vec![-3.0, -3.0], vec![3.0, 3.0]);
        assert!(clip_to_safe_set(&mut lo, &mut hi, &hs));
        // x₂ ≥ (1 − x₁)/2 ≥ (1 − 3)/2 = −1; x₁ ≤ 0.5; x₁ ≥ 1 − 2·3 = −5 (no change).
        assert!(lo[1] <= -1.0 && lo[1] > -1.0 - 1e-12, "{lo:?}");
        assert!(hi[0] >= 0.5 && hi[0] < 0.5 + 1e-12, "{hi:?}");
        assert_eq!((lo[0], hi[1]), (-3.0, 3.0));
        let mut rng = ChaCha8Rng::seed_from_u64(12345);
        let mut uniform = |a: f64, b: f64| rng.random_range(a..b);
        let mut inside = 0;
        for _ in 0..20_000 {
            let (x1, x2) = (uniform(-3.0, 3.0), uniform(-3.0, 3.0));
            if x1 + 2.0 * x2 - 1.0 >= 0.0 && 0.5 - x1 >= 0.0 {
                inside += 1;
                assert!(lo[0] <= x1 && x1 <= hi[0] && lo[1] <= x2 && x2 <= hi[1]);
            }
        }
        assert!(inside > 1000);
    }

    #[test]
    fn affine_cbfs_become_halfspaces_with_enclosed_coefficients() {
        // `x₂/3 + 1 ≥ 0` is `x₂ ≥ −3`: the folded derivative 1/3 is rounded, the enclosure
        // from h itself is not, and the bound must never cut above −3. The obstacle is not
        // affine and is left out.
        let text = r#"
name = "t"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["x2", "0"]
g = [["0"], ["1"]]
kappa = ["-x1 - x2"]
[[cbf]]
name = "obstacle"
h = "(x1 - 2)^2 + x2^2 - 1"
[[cbf]]
name = "third"
h = "x2/3 + 1"
[reach]
region = { lower = [-4, -4], upper = [4, 4] }
m_c = 0
dt = 0.1
horizon = 1
goal = { lower = [-1, -1], upper = [1, 1] }
"#;
        let s = Scenario::from_toml(text, "t.toml", std::path::Path::new(".")).unwrap();
        let safe = SafeSet::of(&s, None);
        assert_eq!(safe.names(), vec!["third"]);
        let hs = &safe.x[0];
        assert!(
            hs.normal[1].contains(1.0 / 3.0) && hs.normal[1].upper - hs.normal[1].lower < 1e-15
        );
        assert!(hs.normal[0].contains(0.0) && hs.normal[0].upper - hs.normal[0].lower < 1e-15);
        let (mut lo, mut hi) = (vec![-1.0, -5.0], vec![1.0, 0.0]);
        assert!(clip_to_safe_set(&mut lo, &mut hi, &safe.x));
        assert!(lo[1] <= -3.0 && lo[1] > -3.0 - 1e-12, "{lo:?}");
    }

    #[test]
    fn an_empty_intersection_leaves_the_box_alone() {
        let hs = [halfspace(&[0.0, 1.0], 2.0)];
        let (mut lo, mut hi) = (vec![0.0, -5.0], vec![1.0, -3.0]);
        assert!(!clip_to_safe_set(&mut lo, &mut hi, &hs));
        assert_eq!((lo, hi), (vec![0.0, -5.0], vec![1.0, -3.0]));
    }

    /// A frame's set as half-spaces of another frame ([`frame_halfspaces`]) holds every state
    /// of the set, its corners on the boundary (a set shrunk by 1 % of its width loses them),
    /// and clipping a box around it keeps them all: x and z both ways, and two transforms. With
    /// a `T` that misses `S⁻¹` by 0.2 %, the `ρ‖T x‖∞` pad is what keeps them.
    #[test]
    fn another_frames_set_holds_its_states_and_is_tight() {
        let t1 = Transform::from_matrix(vec![0.7, -0.7, 2.8, 2.9], 2).unwrap();
        let t2 = Transform::from_matrix(vec![1.0, 0.3, -0.4, 1.2], 2).unwrap();
        let set = IntervalBox::new(vec![-0.3, 0.2], vec![0.5, 0.9]).unwrap();
        let mul = |m: &[f64], v: &[f64]| [m[0] * v[0] + m[1] * v[1], m[2] * v[0] + m[3] * v[1]];
        let identity = [1.0, 0.0, 0.0, 1.0];
        // The 11 × 11 grid of the set's points, each mapped by `to`.
        let grid = |to: &dyn Fn(&[f64; 2]) -> [f64; 2]| -> Vec<[f64; 2]> {
            (0..=10)
                .flat_map(|a| (0..=10).map(move |b| (a, b)))
                .map(|(a, b)| {
                    to(&[
                        set.lower[0] + 0.1 * a as f64 * (set.upper[0] - set.lower[0]),
                        set.lower[1] + 0.1 * b as f64 * (set.upper[1] - set.lower[1]),
                    ])
                })
                .collect()
        };
        let margin = |h: &SafeHalfspace, z: &[f64; 2]| {
            (h.offset + h.normal[0] * Interval::point(z[0]) + h.normal[1] * Interval::point(z[1]))
                .upper
        };
        for (this, other) in [(Some(&t1), None), (None, Some(&t1)), (Some(&t2), Some(&t1))] {
            // x of a point of the other frame's set, and this frame's coordinates of it.
            let s_g = other.map_or(&identity[..], |t| &t.s[..]);
            let t_f = this.map_or(&identity[..], |t| &t.t[..]);
            let points = grid(&|z| mul(t_f, &mul(s_g, z)));
            let x_box = IntervalBox::new(vec![-5.0, -5.0], vec![5.0, 5.0]).unwrap();
            let hs = frame_halfspaces(this, other, &set, &x_box);
            assert_eq!(hs.len(), 4);
            for z in &points {
                for h in &hs {
                    assert!(
                        margin(h, z) >= -1e-9,
                        "{this:?} {other:?}: {z:?} outside {h:?}"
                    );
                }
            }
            // The corners lie on the boundary: 1 % of the set's width is far outside the
            // rounding.
            let corner = points[0];
            let closest = hs
                .iter()
                .map(|h| margin(h, &corner))
                .fold(f64::INFINITY, f64::min);
            assert!(closest < 1e-3 * (set.upper[0] - set.lower[0]), "{closest}");
            // Clipping a wide box keeps every point.
            let (mut lo, mut hi) = (vec![-5.0, -5.0], vec![5.0, 5.0]);
            assert!(clip_to_safe_set(&mut lo, &mut hi, &hs));
            for j in 0..2 {
                let min = points.iter().map(|z| z[j]).fold(f64::INFINITY, f64::min);
                let max = points
                    .iter()
                    .map(|z| z[j])
                    .fold(f64::NEG_INFINITY, f64::max);
                assert!(lo[j] <= min + 1e-9 && hi[j] >= max - 1e-9, "{lo:?} {hi:?}");
            }
        }
        // `T` 0.2 % off `S⁻¹` in one entry, with the `ρ` every transform has.
        let s: [f64; 4] = [1.0, 0.5, -0.3, 2.0];
        let det = s[0] * s[3] - s[1] * s[2];
        let t = [1.002 * s[3] / det, -s[1] / det, -s[2] / det, s[0] / det];
        let off = Transform::with_inverse(t.to_vec(), s.to_vec(), 2).unwrap();
        assert!(off.rho > 1e-3, "{}", off.rho);
        let no_pad = Transform {
            rho: 0.0,
            ..off.clone()
        };
        let x_box = IntervalBox::new(vec![-3.0, -3.0], vec![3.0, 3.0]).unwrap();
        let xs = grid(&|z| mul(&s, z));
        let lowest = |hs: &[SafeHalfspace]| {
            xs.iter()
                .flat_map(|x| hs.iter().map(move |h| margin(h, x)))
                .fold(f64::INFINITY, f64::min)
        };
        assert!(lowest(&frame_halfspaces(None, Some(&off), &set, &x_box)) >= -1e-9);
        let unpadded = lowest(&frame_halfspaces(None, Some(&no_pad), &set, &x_box));
        assert!(unpadded < -1e-4, "the test needs a T off S⁻¹: {unpadded}");
    }
}

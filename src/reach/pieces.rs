//! What the filter's own rows prove over a set: the smooth piece `v` is on it (and the filtered
//! system's field there), an enclosure of `v`, and the QP's feasibility.
//!
//! The filter's QP `min ½‖θ‖² s.t. aₖ(x)·θ ≤ bₖ(x)` is solved by `θ = 0` wherever every
//! `bₖ(x) ≥ 0`: zero is feasible and minimises the objective. Evaluating the rows over a set's
//! x-box by interval arithmetic ([`FilterPieces::slack_rows`], on `box ∩ S` like the rest of the
//! disturbance method) proves this for the whole set at once. The embedding then integrates
//! the filtered system's own field `f̃` (nominal controller included) with `v = 0`: no network
//! bounds and no error margin. Near the goal, where the nominal controller alone acts, this is
//! what lets tubes contract: there the shipped networks err by 0.01–0.03, about what the
//! closed loop's contraction can absorb (scenario 2's tubes diverge from the goal box with a
//! constant `M` of 0.03 and converge with 0.02).
//!
//! The same holds on the other side: where one piece provably is `v` on the whole set (for the
//! closed forms one row binds and every other is slack, `v = bₖaⱼ/‖a‖²` or `bₖ/aₖ`; for a
//! general QP one active set is the only possible one, `v = P/D`, docs/design.md §2.1a), `v` is
//! a smooth function of `x` ([`VForms::piece`]), and the filtered system's field `f̃ + g·v` is an expression whose
//! mean-value form the embedding evaluates like `f̃`'s — again with no network error. Where the
//! active set changes inside the set, the closed form still gives an enclosure of `v` on each
//! face ([`FilterPieces::enclosure`]), which the engine meets with the network's bounds.
//!
//! The same rows decide whether the QP is feasible on a set ([`FilterPieces::proves_feasible`]):
//! where it is not, the filtered system does not exist, and `verify` says which verdicts hold
//! only for the trajectories that do.

use super::embedding::Dynamics;
use super::transform::Transform;
use crate::boxes::IntervalBox;
use crate::expressions::Expr;
use crate::filter::{row_expressions, FilterPiece, Lattice, VForms};
use crate::intervals::{box_of, Interval};
use crate::scenario::Scenario;

/// Bisections [`FilterPieces::proves_feasible`] tries below a box (at most `2⁶` leaves: sets
/// that straddle a zero of some `aₖ`, as scenario 2's near (3.2, 0), need pieces that do not).
const FEASIBILITY_SPLITS: usize = 6;

/// The filter's pieces over boxes, with the filtered system's field on each binding piece.
#[derive(Clone, Debug)]
pub struct FilterPieces {
    scenario: Scenario,
    /// The closed form or the QP's pieces (`None` for a QP with too many active sets: only
    /// inactivity is proven).
    forms: Option<VForms>,
    /// Per binding piece `k` (row `k` of a closed form, active set `k` of a QP): the filtered system's field where row `k` alone binds, in the embedding's
    /// coordinates, and the same field in x (for the transform's slack).
    binding: Vec<BindingField>,
    /// `bₖ(x)` of every row of the QP `aₖ·θ ≤ bₖ`, each `hᵢ` as `max(hᵢ, 0)` (on `S`, `hᵢ ≥ 0`):
    /// the rows whose natural enclosures prove the filter inactive, the same expressions on the
    /// CPU and in the GPU's shaders.
    slack_rows: Vec<Expr>,
    transform: Option<Transform>,
}

/// The filtered system's field on one binding piece.
#[derive(Clone, Debug)]
pub struct BindingField {
    /// `T(f̃ + g·v)(Sz)` (or in x without a transform), as the embedding reads dynamics.
    pub dynamics: Dynamics,
    /// `f̃ + g·v` in x.
    field_x: Vec<Expr>,
}

impl BindingField {
    /// `f̃ + g·v` in x (for the transform's slack, [`FilterPieces::binding_slack`]).
    pub fn field_x(&self) -> &[Expr] {
        &self.field_x
    }
}

impl FilterPieces {
    /// For the filter of `scenario`, the embedding running on `base` (its coordinates given
    /// by `transform`).
    pub fn new(scenario: &Scenario, base: &Dynamics, transform: Option<&Transform>) -> Self {
        let forms = VForms::new(scenario);
        let binding = forms.as_ref().map_or_else(Vec::new, |forms| {
            (0..forms.rows_len())
                .map(|k| {
                    let v = forms.piece_input(FilterPiece::Binding(k));
                    let field_x: Vec<Expr> = (0..scenario.n())
                        .map(|i| {
                            (0..scenario.m()).fold(scenario.f_tilde[i].clone(), |acc, j| {
                                acc + scenario.g[i][j].clone() * v[j].clone()
                            })
                        })
                        .collect();
                    let f_tilde = match transform {
                        Some(t) => t.vector_field(&field_x),
                        None => field_x.clone(),
                    };
                    BindingField {
                        dynamics: Dynamics::new(base.n, base.m, f_tilde, base.g.clone()),
                        field_x,
                    }
                })
                .collect()
        });
        FilterPieces {
            scenario: scenario.clone(),
            forms,
            binding,
            slack_rows: row_expressions(scenario, true).1,
            transform: transform.cloned(),
        }
    }

    /// `bₖ(x)` of every row, `hᵢ` taken as `max(hᵢ, 0)` ([`FilterPieces::proves_inactive`]).
    pub fn slack_rows(&self) -> &[Expr] {
        &self.slack_rows
    }

    /// Whether `v(x) = 0` for every `x` in `x_box ∩ S`: every row's `bₖ ≥ 0` on it by natural
    /// interval evaluation of [`FilterPieces::slack_rows`] (any filter, QP included; a NaN or an
    /// undefined expression proves nothing). [`FilterPieces::piece_on`] proves more for
    /// closed-form filters, with mean-value forms.
    pub fn proves_inactive(&self, x_box: &IntervalBox) -> bool {
        let xs = box_of(&x_box.lower, &x_box.upper);
        self.slack_rows
            .iter()
            .all(|b| b.eval_interval(&xs).lower >= 0.0)
    }

    /// Whether the filter's QP is feasible at every point of `x_box ∩ S` (for a general QP: one
    /// `θ*` satisfies every row over the box, [`VForms::proves_feasible`]). Feasibility is pointwise, so where
    /// the box as a whole is not proven its halves are tried, `FEASIBILITY_SPLITS` deep: the
    /// interval rows of a smaller box lose less to dependency.
    pub fn proves_feasible(&self, x_box: &IntervalBox) -> bool {
        self.proves_feasible_split(x_box, FEASIBILITY_SPLITS)
    }

    fn proves_feasible_split(&self, x_box: &IntervalBox, splits: usize) -> bool {
        let proven = match &self.forms {
            Some(forms) => forms.proves_feasible(&self.scenario, x_box),
            None => self.proves_inactive(x_box),
        };
        proven
            || splits > 0 && {
                let (left, right) = x_box.bisect();
                self.proves_feasible_split(&left, splits - 1)
                    && self.proves_feasible_split(&right, splits - 1)
            }
    }

    /// The smooth piece `v` provably is on `x_box ∩ S` (where the filter is feasible), if any.
    pub fn piece_on(&self, x_box: &IntervalBox) -> Option<FilterPiece> {
        match &self.forms {
            Some(forms) => forms.piece(&self.scenario, x_box),
            None => self.proves_inactive(x_box).then_some(FilterPiece::Inactive),
        }
    }

    /// The filter on `x_box ∩ S` as a lattice of its pieces, where it has a scalar input's
    /// closed form ([`VForms::lattice`]).
    pub fn lattice(&self, x_box: &IntervalBox) -> Option<Lattice> {
        self.forms
            .as_ref()
            .and_then(|forms| forms.lattice(&self.scenario, x_box))
    }

    /// An enclosure of `v` over `x_box ∩ S` (where the filter is feasible) from its closed form
    /// ([`VForms::enclose`]; ends may be infinite where `v` may jump), or `None` for a filter
    /// that needs the QP.
    pub fn enclosure(&self, x_box: &IntervalBox) -> Option<Vec<Interval>> {
        self.forms
            .as_ref()
            .map(|forms| forms.enclose(&self.scenario, x_box).0)
    }

    /// [`FilterPieces::enclosure`] where every end is finite (an infinite end bounds nothing a
    /// step can use).
    pub fn finite_enclosure(&self, x_box: &IntervalBox) -> Option<Vec<Interval>> {
        self.enclosure(x_box)
            .filter(|v| v.iter().all(|e| e.lower.is_finite() && e.upper.is_finite()))
    }

    /// The scenario whose filter this is.
    pub fn scenario(&self) -> &Scenario {
        &self.scenario
    }

    /// The closed form's expressions (`None` for a filter that needs the QP).
    pub fn forms(&self) -> Option<&VForms> {
        self.forms.as_ref()
    }

    /// The transform the embedding runs in, if any.
    pub fn transform(&self) -> Option<&Transform> {
        self.transform.as_ref()
    }

    /// Whether the filter has a closed form ([`FilterPieces::enclosure`] gives enclosures).
    pub fn has_closed_form(&self) -> bool {
        self.forms.is_some()
    }

    /// The slack of the transform over `x_box` (0 without a transform) for the filtered field
    /// `f̃ + g·v` with `v ∈ v_box`: [`Transform::field_slack`] of the field's bound there.
    pub fn field_slack(&self, x_box: &IntervalBox, v_box: &[Interval]) -> f64 {
        let Some(t) = &self.transform else {
            return 0.0;
        };
        let xs = box_of(&x_box.lower, &x_box.upper);
        let s = &self.scenario;
        let f_max = (0..s.n())
            .map(|i| {
                let gv = (0..s.m()).fold(Interval::point(0.0), |acc, j| {
                    acc + s.g[i][j].eval_interval(&xs) * v_box[j]
                });
                magnitude(s.f_tilde[i].eval_interval(&xs) + gv)
            })
            .fold(0.0, f64::max);
        t.field_slack(f_max)
    }

    /// The filtered system's field where row `k` alone binds.
    pub fn binding_field(&self, k: usize) -> &BindingField {
        &self.binding[k]
    }

    /// The slack of the transform for this field over `x_box` (0 without a transform): the
    /// bound of [`Transform::field_slack`] with `‖f̃ + g·v‖∞` over the box.
    pub fn binding_slack(&self, k: usize, x_box: &IntervalBox) -> f64 {
        let Some(t) = &self.transform else {
            return 0.0;
        };
        let xs = box_of(&x_box.lower, &x_box.upper);
        let f_max = self.binding[k]
            .field_x
            .iter()
            .map(|e| magnitude(e.eval_interval(&xs)))
            .fold(0.0, f64::max);
        t.field_slack(f_max)
    }
}

/// `max |x|` over an interval, `+∞` for NaN.
fn magnitude(v: Interval) -> f64 {
    if v.is_nan() {
        f64::INFINITY
    } else {
        v.mag()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::interval_rows;
    use crate::filter::SafetyFilter;
    use rand::{Rng, SeedableRng};

    fn around(c: [f64; 2], r: f64) -> IntervalBox {
        IntervalBox {
            lower: vec![c[0] - r, c[1] - r],
            upper: vec![c[0] + r, c[1] + r],
        }
    }

    /// What [`sampled_proofs_hold`] found on 600 random small boxes.
    struct Proven {
        inactive: usize,
        /// Boxes proven to lie on each row's binding piece.
        binding: Vec<usize>,
        feasible: usize,
        points: usize,
    }

    /// On 600 random boxes of `s` (half of them near the goal, where the filter rests): every
    /// box proven to lie on one piece has the ground-truth filter equal to that piece at 25
    /// sampled points (exactly 0 where inactive; where a row binds, the piece's field equals
    /// `f̃ + g·v` to 1e-9), and every box proven feasible has a feasible QP at them.
    fn sampled_proofs_hold(s: &Scenario, file: &str) -> Proven {
        let base = Dynamics::new(s.n(), s.m(), s.f_tilde.clone(), s.g.clone());
        let (pieces, filter) = (FilterPieces::new(s, &base, None), SafetyFilter::new(s));
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
        let r = &s.reach.region;
        let mut proven = Proven {
            inactive: 0,
            binding: vec![0; pieces.binding.len()],
            feasible: 0,
            points: 0,
        };
        for _ in 0..600 {
            let w = rng.random_range(0.01..0.3);
            let near = rng.random_bool(0.5);
            let c: Vec<f64> = (0..2)
                .map(|i| {
                    let (lo, hi) = (r.lower[i] + w, r.upper[i] - w);
                    if near {
                        rng.random_range(lo.max(-1.5)..hi.min(1.5))
                    } else {
                        rng.random_range(lo..hi)
                    }
                })
                .collect();
            let b = around([c[0], c[1]], w);
            let samples = (0..25)
                .map(|k| b.point_at(&[(k % 5) as f64 / 4.0, (k / 5) as f64 / 4.0]))
                .filter(|x| s.is_safe(x));
            if pieces.proves_feasible(&b) {
                proven.feasible += 1;
                for x in samples.clone() {
                    assert!(filter.eval(&x).is_ok(), "{file}: infeasible at {x:?}");
                }
            }
            let Some(piece) = pieces.piece_on(&b) else {
                continue;
            };
            match piece {
                FilterPiece::Inactive => proven.inactive += 1,
                FilterPiece::Binding(k) => proven.binding[k] += 1,
            }
            for x in samples {
                let Ok(v) = filter.eval(&x) else {
                    continue; // infeasible: no trajectory to speak of
                };
                proven.points += 1;
                match piece {
                    FilterPiece::Inactive => assert_eq!(v, vec![0.0; s.m()], "{file}: {x:?}"),
                    FilterPiece::Binding(k) => {
                        let field = &pieces.binding_field(k).dynamics.f_tilde;
                        for (i, field_i) in field.iter().enumerate() {
                            let truth = s.f_tilde[i].eval(&x)
                                + (0..s.m()).map(|j| s.g[i][j].eval(&x) * v[j]).sum::<f64>();
                            let piece = field_i.eval(&x);
                            assert!(
                                (truth - piece).abs() <= 1e-9 * (1.0 + truth.abs()),
                                "{file}: row {k} at {x:?}: {piece} vs {truth}"
                            );
                        }
                    }
                }
            }
        }
        proven
    }

    /// A set of scenario 2 that straddles `x₂ = 0` near (3.2, 0), where the obstacle's
    /// `L_g h = 2x₂` changes sign and the velocity row binds (a set of the paper's box at
    /// (1, 1.5) at t = 2): its QP is feasible throughout, at sampled points and by proof on
    /// pieces that keep off the zero or where the obstacle's row is slack.
    #[test]
    fn feasibility_is_proven_across_a_sign_change_of_a_row() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
        let s = Scenario::load(&dir.join("double-integrator.toml")).unwrap();
        let base = Dynamics::new(s.n(), s.m(), s.f_tilde.clone(), s.g.clone());
        let (pieces, filter) = (FilterPieces::new(&s, &base, None), SafetyFilter::new(&s));
        let b = IntervalBox::new(vec![3.112, -0.075], vec![3.25, 0.171]).unwrap();
        for k in 0..121 {
            let x = b.point_at(&[(k % 11) as f64 / 10.0, (k / 11) as f64 / 10.0]);
            assert!(filter.eval(&x).is_ok(), "infeasible at {x:?}");
        }
        let rows = interval_rows(&s, &b).0;
        assert!(rows.iter().any(|a| a.contains(0.0)), "{rows:?}");
        assert!(pieces.proves_feasible(&b));
    }

    /// On both paper scenarios the sampled proofs hold, both kinds of piece are proven (inactive
    /// near the goal, binding where the filter acts), most boxes are proven feasible, and no box
    /// around an infeasible point is (scenario 2's CBFs conflict along x₂ = −2).
    #[test]
    fn proven_pieces_are_the_filter() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
        for (file, active_at) in [
            ("integrator.toml", [3.9, 0.0]),
            ("double-integrator.toml", [0.9, 1.5]),
        ] {
            let s = Scenario::load(&dir.join(file)).unwrap();
            let base = Dynamics::new(s.n(), s.m(), s.f_tilde.clone(), s.g.clone());
            let (pieces, filter) = (FilterPieces::new(&s, &base, None), SafetyFilter::new(&s));
            assert!(
                pieces.proves_inactive(&around([0.0, 0.0], 0.2)),
                "{file}: goal"
            );
            assert!(
                !pieces.proves_inactive(&around(active_at, 0.05)),
                "{file}: {active_at:?}"
            );
            assert!(filter.eval(&active_at).unwrap().iter().any(|v| *v != 0.0));
            if file == "double-integrator.toml" {
                // At (1.5, 1.5) both rows ask for θ > 0 (the velocity row for θ ≥ 1, the
                // obstacle's for θ ≥ 4.5): the obstacle's dominates, and `v` is its closed form.
                let (_, b) = interval_rows(&s, &around([1.5, 1.5], 0.02));
                assert!(b.iter().all(|bk| bk.upper < 0.0), "{b:?}");
                assert_eq!(
                    pieces.piece_on(&around([1.5, 1.5], 0.02)),
                    Some(FilterPiece::Binding(0))
                );
            }
            let proven = sampled_proofs_hold(&s, file);
            let binding: usize = proven.binding.iter().sum();
            assert!(
                proven.inactive >= 10 && binding >= 10,
                "{file}: {} inactive, {binding} binding",
                proven.inactive
            );
            assert!(proven.points >= 2000, "{file}: {} points", proven.points);
            assert!(
                proven.feasible >= 300,
                "{file}: {} of 600 feasible",
                proven.feasible
            );
            let r = &s.reach.region;
            let infeasible = (0..400)
                .map(|k| {
                    [
                        r.lower[0] + k as f64 * r.widths()[0] / 400.0,
                        r.lower[1] + 0.01,
                    ]
                })
                .find(|x| s.is_safe(x) && filter.eval(x).is_err());
            assert_eq!(infeasible.is_some(), file == "double-integrator.toml");
            if let Some(x) = infeasible {
                assert!(!pieces.proves_feasible(&around(x, 1e-6)), "{file}: {x:?}");
            }
        }
    }

    /// With input bounds `|u| ≤ 3` on scenario 2 (four rows on a scalar input, two on each
    /// side of `θ = 0`, so that dominance decides between rows and the bounds conflict with the
    /// CBFs), the sampled proofs still hold, and the input bounds' own pieces are proven.
    #[test]
    fn proven_pieces_hold_with_input_bounds() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
        let text = std::fs::read_to_string(dir.join("double-integrator.toml")).unwrap();
        let text = text.replacen(
            "[parameters]",
            "input_bounds = { lower = [-3.0], upper = [3.0] }\n\n[parameters]",
            1,
        );
        let s = Scenario::from_toml(&text, "bounded.toml", &dir).unwrap();
        assert!(s.input_bounds.is_some());
        let proven = sampled_proofs_hold(&s, "bounded.toml");
        // Rows: the two CBFs, then u ≤ 3 and u ≥ −3.
        assert_eq!(proven.binding.len(), 4);
        assert!(
            proven.binding[2] + proven.binding[3] >= 10,
            "input-bound pieces: {:?}",
            proven.binding
        );
        assert!(proven.inactive >= 10 && proven.points >= 2000);
        assert!(proven.feasible >= 100, "{} feasible", proven.feasible);
    }
}

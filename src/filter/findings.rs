//! What a scenario's filter does before any network is trained: CBFs that no input acts on,
//! and where on `C ∩ S` the QP is infeasible ([`findings`]). A user's first scenario often has
//! a CBF of relative degree two (a position bound on a double integrator): its row
//! `−L_g h·θ ≤ L_f̃ h + αh` has no `θ` in it, so the filter cannot enforce it and the QP is
//! infeasible wherever `L_f̃ h + αh < 0`. Without this the only sign was a count of skipped
//! training samples. It may import what the filter module may.

use super::{interval_rows, FilterStatus, Infeasibility, SafetyFilter};
use crate::intervals::Interval;
use crate::scenario::Scenario;

/// About this many cell centres of `C` are solved (per axis the same count, at least 2).
pub const SAMPLE_POINTS: usize = 4096;

/// How far from 0 an inert row's enclosure may reach: interval products with an exact 0 are
/// rounded out to the smallest subnormals.
pub const INERT: f64 = 1e-300;

/// What [`findings`] found.
#[derive(Clone, Debug, PartialEq)]
pub struct FilterFindings {
    /// The CBFs (by name) whose row `−L_g h` is 0 on all of `C`, proven by interval evaluation:
    /// their relative degree is above one.
    pub inert: Vec<String>,
    /// The points of `C ∩ S` solved: the centres of an equal partition of `C` that lie in `S`.
    pub sampled: usize,
    /// Those where the QP is infeasible.
    pub infeasible: usize,
    /// The first such point and why.
    pub example: Option<(Vec<f64>, Infeasibility)>,
}

/// The CBFs (by name) whose row `−L_g h` encloses to 0 over `C` (within [`INERT`], the width
/// outward rounding gives a product with 0): no input acts on them anywhere in `C`.
pub fn inert_cbfs(s: &Scenario) -> Vec<String> {
    let (a, _) = interval_rows(s, &s.reach.region);
    let m = s.m();
    let zero = |i: &Interval| i.lower.abs() <= INERT && i.upper.abs() <= INERT;
    s.cbfs
        .iter()
        .enumerate()
        .filter(|(k, _)| a[k * m..(k + 1) * m].iter().all(zero))
        .map(|(_, c)| c.name.clone())
        .collect()
}

/// The scenario's filter checked on `C`: inert CBFs, and the QP solved at about
/// [`SAMPLE_POINTS`] points of `C ∩ S`.
pub fn findings(s: &Scenario) -> FilterFindings {
    let region = &s.reach.region;
    let n = s.n();
    let per_axis = ((SAMPLE_POINTS as f64).powf(1.0 / n as f64).floor() as usize).max(2);
    let counts = vec![per_axis; n];
    let filter = SafetyFilter::new(s);
    let (mut sampled, mut infeasible, mut example) = (0, 0, None);
    for k in 0..per_axis.pow(n as u32) {
        let x = region.partition_cell(&counts, k).center();
        if !s.is_safe(&x) {
            continue;
        }
        sampled += 1;
        // A point where v is not defined (a CBF's gradient) is not an infeasible QP.
        if let Ok(FilterStatus::Infeasible(why)) = filter.solve(&x) {
            infeasible += 1;
            example.get_or_insert((x, why));
        }
    }
    FilterFindings {
        inert: inert_cbfs(s),
        sampled,
        infeasible,
        example,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn van_der_pol(h: &str) -> Scenario {
        let text = format!(
            r#"
name = "vdp"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["x2", "(1 - x1^2)*x2 - x1"]
g = [["0"], ["1"]]
kappa = ["-2*x2 - (1 - x1^2)*x2"]
[[cbf]]
name = "wall"
h = "{h}"
[reach]
region = {{ lower = [-2, -2], upper = [2, 2] }}
dt = 0.02
horizon = 1.0
goal = {{ lower = [-0.2, -0.2], upper = [0.2, 0.2] }}
initial = [ {{ lower = [-1.1, 0.9], upper = [-0.9, 1.1] }} ]
"#
        );
        Scenario::from_toml(&text, "vdp.toml", std::path::Path::new(".")).unwrap()
    }

    /// A position bound on a double integrator's position (relative degree two) is found inert,
    /// and the QP infeasible exactly where `L_f h + αh = −x₂ + 1.5 − x₁ < 0`; tilted by the
    /// velocity (relative degree one) it is neither.
    #[test]
    fn a_cbf_no_input_acts_on_is_named_with_where_the_qp_fails() {
        let s = van_der_pol("1.5 - x1");
        let f = findings(&s);
        assert_eq!(f.inert, vec!["wall".to_string()]);
        let counts = vec![64, 64];
        let expected = (0..64 * 64)
            .map(|k| s.reach.region.partition_cell(&counts, k).center())
            .filter(|x| s.is_safe(x) && 1.5 - x[0] - x[1] < 0.0)
            .count();
        assert!(expected > 200, "{expected}");
        assert_eq!(f.infeasible, expected);
        let (x, why) = f.example.expect("an infeasible point");
        assert!(1.5 - x[0] - x[1] < 0.0, "{x:?}");
        assert!(matches!(why, Infeasibility::NoInputOnRow { .. }), "{why:?}");
        let tilted = findings(&van_der_pol("1.5 - x1 - 0.5*x2"));
        assert!(tilted.inert.is_empty());
        assert_eq!(tilted.infeasible, 0);
        assert!(tilted.sampled > 3000, "{}", tilted.sampled);
    }
}

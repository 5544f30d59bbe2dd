//! Where the filter is provably inactive, `v = 0` exactly.
//!
//! The filter's QP `min ½‖θ‖² s.t. aₖ(x)·θ ≤ bₖ(x)` is solved by `θ = 0` wherever every
//! `bₖ(x) ≥ 0`: zero is feasible and minimises the objective. Evaluating the rows over a set's
//! x-box by interval arithmetic ([`interval_rows`], on `box ∩ S` like the rest of the
//! disturbance method) proves this for the whole set at once. The embedding then integrates
//! the filtered system's own field `f̃` (nominal controller included) with `v = 0`: no network
//! bounds and no error margin. Near the goal, where the nominal controller alone acts, this is
//! what lets tubes contract: there the shipped networks err by 0.01–0.03, about what the
//! closed loop's contraction can absorb (scenario 2's tubes diverge from the goal box with a
//! constant `M` of 0.03 and converge with 0.02).

use crate::boxes::IntervalBox;
use crate::scenario::Scenario;
use crate::surrogate_error::interval_rows;

/// The filter's constraint rows, to prove it inactive over boxes.
#[derive(Clone, Debug)]
pub struct InactiveFilter {
    scenario: Scenario,
}

impl InactiveFilter {
    /// For the filter of `scenario`.
    pub fn new(scenario: &Scenario) -> InactiveFilter {
        InactiveFilter {
            scenario: scenario.clone(),
        }
    }

    /// Whether `v(x) = 0` for every `x` in `x_box ∩ S`: every row's `bₖ ≥ 0` on it (a NaN or
    /// an undefined expression proves nothing).
    pub fn proves(&self, x_box: &IntervalBox) -> bool {
        let (_, b) = interval_rows(&self.scenario, x_box);
        b.iter().all(|bk| bk.lower >= 0.0)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::filter::SafetyFilter;
    use rand::{Rng, SeedableRng};

    /// Whenever a box is proven inactive, the ground-truth filter is exactly 0 at sampled
    /// points of it; and the proof succeeds near the goal of both paper scenarios and fails
    /// where the filter acts.
    #[test]
    fn proven_inactive_boxes_have_v_zero() {
        let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
        for (file, active_at) in [
            ("integrator.toml", [3.9, 0.0]),
            ("double-integrator.toml", [0.9, 1.5]),
        ] {
            let s = Scenario::load(&dir.join(file)).unwrap();
            let (inactive, filter) = (InactiveFilter::new(&s), SafetyFilter::new(&s));
            let around = |c: [f64; 2], r: f64| IntervalBox {
                lower: vec![c[0] - r, c[1] - r],
                upper: vec![c[0] + r, c[1] + r],
            };
            assert!(inactive.proves(&around([0.0, 0.0], 0.2)), "{file}: goal");
            assert!(
                !inactive.proves(&around(active_at, 0.05)),
                "{file}: {active_at:?}"
            );
            assert!(filter.eval(&active_at).unwrap().iter().any(|v| *v != 0.0));
            let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(9);
            let (r, mut proven) = (&s.reach.region, 0);
            for _ in 0..400 {
                // Small boxes, half of them near the goal, where the filter rests.
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
                if !inactive.proves(&b) {
                    continue;
                }
                proven += 1;
                for k in 0..25 {
                    let x = b.point_at(&[(k % 5) as f64 / 4.0, (k / 5) as f64 / 4.0]);
                    if s.is_safe(&x) {
                        assert_eq!(filter.eval(&x).unwrap(), vec![0.0; s.m()], "{file}: {x:?}");
                    }
                }
            }
            assert!(proven >= 10, "{file}: only {proven} of 400 boxes proven");
        }
    }
}

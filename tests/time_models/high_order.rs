//! A high-order CBF written out (a position bound no input acts on, beside `ψ = L_f̃h + h` as a
//! CBF of its own): the row of `h` binds nowhere `v` exists, which the filter's pieces and
//! enclosures use on sets across `ψ = 0`; the sets hold the filtered system's RK4 trajectories.

use super::*;

#[test]
fn sets_hold_a_high_order_cbf_written_out() {
    let s = common::high_order_wall(
        r#"m_c = 3.0
horizon = 2.0
initial = [
  { lower = [0.85, 0.35], upper = [0.95, 0.45] },
  { lower = [1.15, 0.02], upper = [1.25, 0.12] },
  { lower = [0.25, 1.05], upper = [0.35, 1.15] },
]"#,
    );
    assert!(s.cbfs[0].inert && !s.cbfs[1].inert);
    // The zero network with M = 3 stands in for a trained one: v stays within it on C ∩ S.
    let filter = SafetyFilter::new(&s);
    let mut worst = 0.0_f64;
    for a in 0..=80 {
        for b in 0..=80 {
            let x = [-2.0 + 4.0 * a as f64 / 80.0, -2.0 + 4.0 * b as f64 / 80.0];
            if s.is_safe(&x) {
                worst = worst.max(filter.eval(&x).unwrap()[0].abs());
            }
        }
    }
    assert!(worst > 0.5 && worst < 2.7, "v up to {worst}");
    let problem = ReachProblem::new(&s, common::zero_network(&[2, 8, 1]), 3.0).unwrap();
    let tubes = run(&problem, &s.reach.initial, ExactField::ClosedForm);
    let e = escapes(&s, &tubes, s.reach.dt, 1e-6);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 3 * 40 * 30, "too few checks: {e:?}");
    // The filter's own field carried steps where the sets straddle ψ = 0.
    let exact: usize = tubes.iter().map(|t| t.exact_steps).sum();
    assert!(exact > 30, "{exact} exact steps");
}

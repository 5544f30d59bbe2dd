//! A high-order CBF written out (a position bound no input acts on, beside `ψ = L_f̃h + h` as a
//! CBF of its own): the row of `h` binds nowhere `v` exists, which the filter's pieces and
//! enclosures use on sets across `ψ = 0`; the sets hold the filtered system's RK4 trajectories.

use super::*;

const REACH: &str = r#"m_c = 3.0
horizon = 2.0
initial = [
  { lower = [0.85, 0.35], upper = [0.95, 0.45] },
  { lower = [1.15, 0.02], upper = [1.25, 0.12] },
  { lower = [0.25, 1.05], upper = [0.35, 1.15] },
]"#;

#[test]
fn sets_hold_a_high_order_cbf_written_out() {
    let s = common::high_order_wall(REACH);
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

/// `order = 2` writes the same CBF as the hand-written one: the same filter at every point and
/// the same sets, to the last bits that the two expression trees' roundings leave.
#[test]
fn order_two_writes_the_high_order_cbf_out() {
    let (by_hand, by_order) = (
        common::high_order_wall(REACH),
        common::high_order_wall_by_order(REACH),
    );
    assert_eq!(by_order.cbfs.len(), 2);
    assert_eq!(by_order.cbfs[1].name, "h1.psi1");
    assert!(by_order.cbfs[0].inert && !by_order.cbfs[1].inert);
    let (f, g) = (SafetyFilter::new(&by_hand), SafetyFilter::new(&by_order));
    let mut compared = 0;
    for a in 0..=40 {
        for b in 0..=40 {
            let x = [-2.0 + 0.1 * a as f64, -2.0 + 0.1 * b as f64];
            assert_eq!(by_hand.is_safe(&x), by_order.is_safe(&x), "{x:?}");
            let diff = by_hand.cbfs[1].h.eval(&x) - by_order.cbfs[1].h.eval(&x);
            assert!(diff.abs() < 1e-12, "ψ differs by {diff} at {x:?}");
            if let (Ok(p), Ok(q)) = (f.eval(&x), g.eval(&x)) {
                assert!((p[0] - q[0]).abs() < 1e-9, "v {p:?} against {q:?} at {x:?}");
                compared += 1;
            }
        }
    }
    assert!(compared > 800, "{compared} points compared");
    let tubes = |s: &Scenario| {
        let problem = ReachProblem::new(s, common::zero_network(&[2, 8, 1]), 3.0).unwrap();
        run(&problem, &s.reach.initial, ExactField::ClosedForm)
    };
    let (p, q) = (tubes(&by_hand), tubes(&by_order));
    for (a, b) in p.iter().zip(&q) {
        assert_eq!((a.tube.len(), &a.end), (b.tube.len(), &b.end));
        for (x, y) in a.tube.iter().zip(&b.tube) {
            for i in 0..2 {
                assert!(
                    (x.lower[i] - y.lower[i]).abs() < 1e-9,
                    "{x:?} against {y:?}"
                );
                assert!(
                    (x.upper[i] - y.upper[i]).abs() < 1e-9,
                    "{x:?} against {y:?}"
                );
            }
        }
    }
}

/// A point mass in the plane past a disc, the high-order CBF by `order = 2` (`order` 1: the
/// position bound alone).
fn planar_disc(order: usize) -> Scenario {
    common::planar_point_mass(
        2.0,
        &format!(
            r#"[[cbf]]
h = "(px - 2)^2 + (py - 0.2)^2 - 0.36"
order = {order}
alpha = 2"#
        ),
        r#"region = { lower = [-1, -1.5, -2, -2], upper = [5, 1.5, 2, 2] }
dt = 0.05
horizon = 10
m_c = 0
goal = { lower = [-0.5, -0.5, -0.5, -0.5], upper = [0.5, 0.5, 0.5, 0.5] }"#,
    )
}

/// Trajectories that slide along `ψ = 0` (the high-order CBF's row holding them there) are
/// integrated through: RK4's stages err across `ψ = 0` by a little, where the position bound's
/// row, which no input acts on, would make the QP infeasible and end them (52 of 917 did with
/// the QP's own field). Without the high-order CBF the QP is really infeasible, and says so.
#[test]
fn integrators_slide_along_a_high_order_cbf() {
    let s = planar_disc(2);
    let filter = SafetyFilter::new(&s);
    let start = IntervalBox::new(vec![3.0, -1.0, -2.0, -2.0], vec![4.8, 1.0, 2.0, 2.0]).unwrap();
    let (mut stopped, mut plain_stopped, mut lowest) = (0, 0, f64::INFINITY);
    let starts: Vec<Vec<f64>> = sample_box(&start, 1000, 3)
        .into_iter()
        .filter(|x| s.is_safe(x))
        .collect();
    for x0 in &starts {
        let x0 = x0.as_slice();
        let tr = simulate_filtered(&filter, x0, s.reach.dt, 200, Integrator::Rk4);
        stopped += usize::from(tr.stopped.is_some());
        let psi =
            tr.x.iter()
                .map(|x| s.cbfs[1].h.eval(x))
                .fold(f64::INFINITY, f64::min);
        lowest = lowest.min(psi);
        // The QP's own field: RK4's stages cross ψ = 0, where it has no value.
        let plain = integrate(
            |x| filter.closed_loop(x),
            x0,
            s.reach.dt,
            200,
            Integrator::Rk4,
        );
        plain_stopped += usize::from(plain.stopped.is_some());
    }
    assert_eq!(stopped, 0, "{stopped} trajectories stopped");
    assert!(lowest > -1e-3, "ψ down to {lowest}");
    assert!(
        plain_stopped > 10,
        "{plain_stopped} of {} stopped with the QP's own field",
        starts.len()
    );
    let alone = planar_disc(1);
    let filter = SafetyFilter::new(&alone);
    let infeasible = sample_box(&start, 100, 3)
        .into_iter()
        .filter(|x| alone.is_safe(x))
        .map(|x0| simulate_filtered(&filter, &x0, alone.reach.dt, 200, Integrator::Rk4))
        .filter(|tr| tr.stopped.as_ref().is_some_and(|s| s.cause.is_infeasible()))
        .count();
    assert!(infeasible > 10, "{infeasible} met an infeasible QP");
}

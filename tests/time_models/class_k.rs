//! A nonlinear class-K function (`alpha = "3*h^3 + 0.1*h"`): the sets hold the filtered system
//! it defines, in continuous time (RK4 at a tenth of the step) and sampled-data (the input held
//! exactly), and they tell it from the same filter with `α(h) = 0.1h`, so a filter built with
//! the wrong `α` would fail this test.

use super::*;

/// [`common::curved_wall`] with `alpha`: the filter's correction is at most ~0.28 on `C`, so
/// the zero network with `M_C = 0.35` (checked on a grid below) stands in for a trained one;
/// where the filter's active set is proven on a set the engine integrates its own field, in
/// which `α` enters.
fn wall(alpha: &str) -> Scenario {
    common::curved_wall(
        alpha,
        r#"m_c = 0.35
horizon = 4.0
initial = [
  { lower = [-0.6, 0.3], upper = [-0.5, 0.4] },
  { lower = [-0.9, -0.5], upper = [-0.85, -0.45] },
  { lower = [-0.3, -0.1], upper = [-0.2, 0.0] },
]"#,
    )
}

#[test]
fn sets_hold_a_nonlinear_class_k_filter_in_continuous_and_sampled_time() {
    let s = wall(r#""3*h^3 + 0.1*h""#);
    assert!(s.cbfs[0].alpha.gain.is_none());
    let filter = SafetyFilter::new(&s);
    let (mut worst, mut active) = (0.0_f64, 0);
    for a in 0..=60 {
        for b in 0..=60 {
            let x = [-1.5 + 3.0 * a as f64 / 60.0, -1.5 + 3.0 * b as f64 / 60.0];
            if !s.is_safe(&x) {
                continue;
            }
            let v = filter.eval(&x).unwrap();
            // The closed form by hand: v = max(0, −(∇h·κ + α(h)))/‖∇h‖²·∇h.
            let (h, grad) = (x[0] + 1.0 + 0.2 * x[1] * x[1], [1.0, 0.4 * x[1]]);
            let kappa = [-0.4 * (x[0] + 1.6), -0.2 * x[1]];
            let need = -(grad[0] * kappa[0] + grad[1] * kappa[1] + 3.0 * h.powi(3) + 0.1 * h);
            let scale = need.max(0.0) / (grad[0] * grad[0] + grad[1] * grad[1]);
            for i in 0..2 {
                assert!((v[i] - scale * grad[i]).abs() < 1e-12, "v({x:?}) = {v:?}");
            }
            let size = v[0].abs().max(v[1].abs());
            worst = worst.max(size);
            active += usize::from(size > 1e-9);
        }
    }
    assert!(
        worst < 0.3 && active > 200,
        "v up to {worst}, active at {active}"
    );
    let problem = ReachProblem::new(&s, common::zero_network(&[2, 8, 2]), 0.35).unwrap();
    let tubes = run(&problem, &s.reach.initial, ExactField::ClosedForm);
    let e = escapes(&s, &tubes, s.reach.dt, 1e-6);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 3 * 48 * 40, "too few checks: {e:?}");
    // The same sets against the filter with the linear part of α alone: its trajectories
    // approach the wall at another rate, and leave them.
    let linear = wall("0.1");
    let e = escapes(&linear, &tubes, s.reach.dt, 1e-6);
    assert!(e.at_snapshots > 0, "the sets hold α(h) = 0.1h too: {e:?}");

    let sampled = problem.with_time(
        TimeModel::Sampled {
            control_period: s.reach.dt,
        },
        1,
    );
    let tubes = run(&sampled, &s.reach.initial, ExactField::ClosedForm);
    let e = escapes_with(&s, &tubes, s.reach.dt, 1e-9, Integrator::Zoh);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 3 * 48 * 40, "too few checks: {e:?}");
}

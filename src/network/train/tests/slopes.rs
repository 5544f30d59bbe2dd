//! The slope terms' targets (capped, Huber, the pointwise Jacobian) and the dataset's sample
//! handling (appended samples, hard examples). May import: the trainer tests' fixtures.

use super::*;

/// `smooth_data(21)` with three samples' slope target `∂v₀/∂x₀` set to `value`, as at a
/// jump of `v`.
fn absurd_slopes(value: f64) -> Dataset {
    let mut d = smooth_data(21);
    if let Some(jac) = &mut d.jacobians {
        for s in [40, 200, 330] {
            jac[4 * s] = value;
        }
    }
    d
}

#[test]
fn appended_samples_follow_with_their_weights() {
    let mut a = smooth_data(5);
    let mut b = smooth_data(3);
    let (la, lb) = (a.len(), b.len());
    b.weights = Some(vec![2.0; lb]);
    let (b_inputs, b_jac) = (b.inputs.clone(), b.jacobians.clone().unwrap());
    a.append(b).unwrap();
    a.validate().unwrap();
    assert_eq!(a.len(), la + lb);
    assert_eq!(&a.inputs[la * 2..], &b_inputs[..]);
    assert_eq!(&a.jacobians.as_ref().unwrap()[la * 4..], &b_jac[..]);
    let w = a.weights.unwrap();
    assert!(w[..la].iter().all(|&x| x == 1.0) && w[la..].iter().all(|&x| x == 2.0));
    let mut no_jacobians = smooth_data(3);
    no_jacobians.jacobians = None;
    assert!(smooth_data(3).append(no_jacobians).is_err());
}

#[test]
fn capped_slope_targets_leave_the_sobolev_term() {
    // A few samples with absurd slope targets, as at a jump of `v`: with the cap, what the
    // targets are no longer matters (bit-identical weights for two different absurd values),
    // and training matches the smooth data's slope; without it, they wreck the fit.
    let init = Mlp::random(&[2, 16, 16, 2], 3);
    let capped = TrainSettings {
        jacobian_cap: Some(50.0),
        ..quick(60, 0.1)
    };
    let (a, _) = train(init.clone(), &absurd_slopes(1e4), &capped, |_| {}).unwrap();
    let (b, _) = train(init.clone(), &absurd_slopes(-3e5), &capped, |_| {}).unwrap();
    assert_eq!(a, b, "capped targets still steer the training");
    let (c, _) = train(init, &absurd_slopes(1e4), &quick(60, 0.1), |_| {}).unwrap();
    let (ea, ec) = (max_slope_error(&a), max_slope_error(&c));
    assert!(ea < 0.5 * ec, "capped {ea} vs uncapped {ec}");
    assert!(TrainSettings {
        jacobian_cap: Some(0.0),
        ..quick(1, 0.1)
    }
    .validate()
    .is_err());
}

#[test]
fn huber_slope_residuals_pull_with_bounded_force() {
    // Beyond δ a residual pulls with force δ whatever its size: two absurd targets of the
    // same sign give bit-identical weights (the plain square does not), and a δ above
    // every residual is the plain square exactly.
    let init = Mlp::random(&[2, 16, 16, 2], 3);
    let plain = TrainSettings {
        hard_example_fraction: 0.0,
        ..quick(20, 0.1)
    };
    let huber = |delta: f64| TrainSettings {
        jacobian_huber: Some(delta),
        ..plain.clone()
    };
    let run = |data: &Dataset, settings: &TrainSettings| {
        train(init.clone(), data, settings, |_| {}).unwrap().0
    };
    let (a, b) = (
        run(&absurd_slopes(1e3), &huber(1.0)),
        run(&absurd_slopes(1e4), &huber(1.0)),
    );
    assert_eq!(a, b, "Huber residuals beyond δ still pull by their size");
    assert_ne!(
        run(&absurd_slopes(1e3), &plain),
        run(&absurd_slopes(1e4), &plain)
    );
    let data = absurd_slopes(1e3);
    assert_eq!(run(&data, &huber(1e9)), run(&data, &plain));
    assert!(huber(0.0).validate().is_err());
    assert!(huber(f64::NAN).validate().is_err());
}

#[test]
fn hard_examples_are_revisited_as_often_as_asked() {
    // Scores 0..100: the top 5 % are samples 95..99; each must appear 1 + repeats times.
    let active: Vec<usize> = (0..100).collect();
    let score: Vec<f64> = (0..100).map(|s| s as f64).collect();
    for repeats in [0, 1, 4] {
        let settings = TrainSettings {
            epochs: 10,
            hard_example_fraction: 0.05,
            hard_example_start: 0.0,
            hard_example_repeats: repeats,
            ..TrainSettings::default()
        };
        let order = epoch_order(3, &active, &score, &settings);
        assert_eq!(order.len(), 100 + 5 * repeats);
        for s in 0..100 {
            let visits = order.iter().filter(|&&o| o == s).count();
            assert_eq!(visits, if s >= 95 { 1 + repeats } else { 1 }, "sample {s}");
        }
        // Epoch 0 never oversamples: there are no scores yet.
        assert_eq!(epoch_order(0, &active, &score, &settings).len(), 100);
    }
}

#[test]
fn jacobian_term_lowers_slope_error() {
    let data = smooth_data(21);
    let init = Mlp::random(&[2, 16, 16, 2], 3);
    let (plain, rp) = train(init.clone(), &data, &quick(150, 0.0), |_| {}).unwrap();
    let (sob, rs) = train(init, &data, &quick(150, 0.1), |_| {}).unwrap();
    let (ep, es) = (max_slope_error(&plain), max_slope_error(&sob));
    eprintln!(
        "slope error max: plain {ep:.3} (data {:?}), sobolev {es:.3} (data {:?}); value max {:.4} vs {:.4}",
        rp.final_errors.max_slope_error,
        rs.final_errors.max_slope_error,
        rp.final_errors.max_error,
        rs.final_errors.max_error
    );
    assert!(es < ep, "Sobolev {es} not below plain {ep}");
    assert!(rs.final_errors.max_slope_error < rp.final_errors.max_slope_error);
    assert!(rs.final_errors.max_error < 0.1, "{:?}", rs.final_errors);
}

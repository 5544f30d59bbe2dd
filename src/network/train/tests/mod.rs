//! Unit tests of the trainer: fits, determinism, resume, revival; the loss terms in
//! [`slopes`] (slope targets, samples) and [`gradients`] (each term's gradient, the IBP term).
//! May import: everything of the trainer and of [`crate::network`], the bounds for IBP checks.

use super::loss::{ibp_term, slope_target, ChunkWorker};
use super::run::epoch_order;
use super::*;
use crate::network::batch::{to_mlp, to_params, IbpWorkspace, Params};
use crate::network::{Mlp, NetworkError};

mod gradients;
mod recipe;
mod slopes;

/// `v(x) = (sin x₁, x₁ x₂)` on an `k × k` grid over `[−1, 1]²`, with `Dv`.
fn smooth_data(k: usize) -> Dataset {
    let mut d = Dataset {
        n_in: 2,
        n_out: 2,
        jacobians: Some(Vec::new()),
        ..Default::default()
    };
    for i in 0..k {
        for j in 0..k {
            let x1 = -1.0 + 2.0 * i as f64 / (k - 1) as f64;
            let x2 = -1.0 + 2.0 * j as f64 / (k - 1) as f64;
            d.inputs.extend([x1, x2]);
            d.targets.extend([x1.sin(), x1 * x2]);
            if let Some(jac) = &mut d.jacobians {
                jac.extend([x1.cos(), 0.0, x2, x1]);
            }
        }
    }
    d
}

fn quick(epochs: usize, lambda: f64) -> TrainSettings {
    TrainSettings {
        epochs,
        batch_size: 32,
        learning_rate: 1e-2,
        lr_min: 1e-4,
        jacobian_weight: lambda,
        seed: 7,
        ..Default::default()
    }
}

/// Worst slope error on a finer off-grid set, from `Mlp::jacobian`.
fn max_slope_error(mlp: &Mlp) -> f64 {
    let mut worst = 0.0f64;
    for i in 0..41 {
        for j in 0..41 {
            let x1 = -0.99 + 1.98 * i as f64 / 40.0;
            let x2 = -0.99 + 1.98 * j as f64 / 40.0;
            let jn = mlp.jacobian(&[x1, x2]);
            let jv = [x1.cos(), 0.0, x2, x1];
            for (a, b) in jn.iter().zip(jv) {
                worst = worst.max((a - b).abs());
            }
        }
    }
    worst
}

#[test]
fn fits_a_smooth_function() {
    let data = smooth_data(21);
    let mut calls = 0;
    let (mlp, rep) = train(
        Mlp::random(&[2, 16, 16, 2], 1),
        &data,
        &quick(1000, 0.0),
        |s| {
            calls += 1;
            assert_eq!(s.epoch, calls);
        },
    )
    .unwrap();
    assert_eq!(calls, 1000);
    assert_eq!(rep.epochs.len(), 1000);
    // The returned network is what the report measured.
    assert_eq!(evaluate(&mlp, &data).unwrap(), rep.final_errors);
    eprintln!("fit: {:?}", rep.final_errors);
    assert!(rep.final_errors.max_error < 0.03, "{:?}", rep.final_errors);
    assert!(rep.final_errors.mean_error < 0.01, "{:?}", rep.final_errors);
    assert!(rep.epochs[999].loss < rep.epochs[0].loss / 100.0);
}

/// Chunks are added in a fixed order: one thread or three give the same network.
#[test]
fn chunked_training_does_not_depend_on_threads() {
    let data = smooth_data(9);
    let s = TrainSettings {
        chunk_size: 8,
        ibp_weight: 0.01,
        hard_example_start: 0.3,
        ..quick(4, 0.1)
    };
    let init = Mlp::random(&[2, 16, 16, 2], 2);
    let on = |threads: usize| {
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads)
            .build()
            .unwrap();
        pool.install(|| train(init.clone(), &data, &s, |_| {}).unwrap().0)
    };
    assert_eq!(on(1), on(3));
}

#[test]
fn same_seed_is_bitwise_identical_and_f64_works() {
    let data = smooth_data(9);
    for precision in [Precision::F32, Precision::F64] {
        let s = TrainSettings {
            precision,
            hard_example_start: 0.3,
            ..quick(10, 0.1)
        };
        let init = Mlp::random(&[2, 16, 16, 2], 2);
        let (a, _) = train(init.clone(), &data, &s, |_| {}).unwrap();
        let (b, _) = train(init.clone(), &data, &s, |_| {}).unwrap();
        assert_eq!(a, b);
        let (c, _) = train(init, &data, &TrainSettings { seed: 8, ..s }, |_| {}).unwrap();
        assert_ne!(a, c);
    }
}

#[test]
fn bad_inputs_are_errors_not_panics() {
    let data = smooth_data(5);
    let net = Mlp::random(&[2, 4, 2], 0);
    let s = quick(1, 0.0);
    let mut d = data.clone();
    d.targets.pop();
    assert!(matches!(
        train(net.clone(), &d, &s, |_| {}),
        Err(NetworkError::Dataset { .. })
    ));
    let mut d = data.clone();
    d.inputs[3] = f64::NAN;
    assert!(matches!(
        train(net.clone(), &d, &s, |_| {}),
        Err(NetworkError::Dataset { .. })
    ));
    let d = Dataset {
        jacobians: None,
        ..data.clone()
    };
    assert!(matches!(
        train(net.clone(), &d, &quick(1, 0.1), |_| {}),
        Err(NetworkError::Settings { .. })
    ));
    let bad = TrainSettings {
        batch_size: 0,
        ..s.clone()
    };
    assert!(matches!(
        train(net.clone(), &data, &bad, |_| {}),
        Err(NetworkError::Settings { .. })
    ));
    let wrong = Mlp::random(&[3, 4, 2], 0);
    assert!(matches!(
        train(wrong, &data, &s, |_| {}),
        Err(NetworkError::Dataset { .. })
    ));
    // A diverging run is reported, not returned as NaN weights.
    let wild = TrainSettings {
        learning_rate: 1e30,
        lr_min: 0.0,
        ..s.clone()
    };
    let r = train(net.clone(), &data, &wild, |_| {});
    assert!(
        matches!(r, Err(NetworkError::Diverged { .. }))
            || r.is_ok_and(|(m, _)| m
                .layers
                .iter()
                .all(|l| l.weight.iter().all(|x| x.is_finite())))
    );
    // Checkpoints of other data or precision are refused.
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("ck.safetensors");
    let with_ck = TrainSettings {
        checkpoint: Some(ck.clone()),
        ..s.clone()
    };
    train(net, &data, &with_ck, |_| {}).unwrap();
    let other = smooth_data(6);
    assert!(matches!(
        resume(&ck, &other, &s, |_| {}),
        Err(NetworkError::Checkpoint { .. })
    ));
    let f64s = TrainSettings {
        precision: Precision::F64,
        ..s.clone()
    };
    assert!(matches!(
        resume(&ck, &data, &f64s, |_| {}),
        Err(NetworkError::Checkpoint { .. })
    ));
    assert!(matches!(
        resume(&dir.path().join("none"), &data, &s, |_| {}),
        Err(NetworkError::Io { .. })
    ));
}

#[test]
fn resume_matches_uninterrupted_run() {
    let data = smooth_data(9);
    let dir = tempfile::tempdir().unwrap();
    let ck = dir.path().join("ck.safetensors");
    let mut init = Mlp::random(&[2, 16, 16, 2], 4);
    // Dead neurons, revived after epochs 3, 6 and 9: across the interruption too.
    init.layers[1].bias[..3].fill(-100.0);
    for precision in [Precision::F32, Precision::F64] {
        // The IBP term (f32 run), ramping across the interruption, resumes bit-identically.
        let ibp = precision == Precision::F32;
        let full = TrainSettings {
            precision,
            hard_example_start: 0.2,
            ibp_weight: if ibp { 0.01 } else { 0.0 },
            ibp_start: 2,
            ibp_ramp: 6,
            revive_every: 3,
            ..quick(12, 0.1)
        };
        let (a, ra) = train(init.clone(), &data, &full, |_| {}).unwrap();
        // Interrupt at epoch 5: the checkpoint written after epoch 5 is copied away when
        // epoch 6 reports (checkpoints are written after the progress callback).
        let part = TrainSettings {
            checkpoint: Some(ck.clone()),
            checkpoint_every: 5,
            ..full.clone()
        };
        let ck5 = dir.path().join("ck5.safetensors");
        train(init.clone(), &data, &part, |s| {
            if s.epoch == 6 {
                std::fs::copy(&ck, &ck5).unwrap();
            }
        })
        .unwrap();
        let mut seen = Vec::new();
        let (b, rb) = resume(&ck5, &data, &full, |s| seen.push(s.epoch)).unwrap();
        assert_eq!(seen, (6..=12).collect::<Vec<_>>());
        assert_eq!(ra.epochs[1].ibp_width, None);
        assert_eq!(ra.epochs[2].ibp_width.is_some(), ibp);
        assert!(ra.epochs[2].revived >= 3, "{:?}", ra.epochs[2]);
        assert_eq!(a, b);
        assert_eq!(rb.resumed_from, Some(5));
        assert_eq!(rb.epochs.len(), 12);
        let untimed = |v: &[EpochStats]| {
            v.iter()
                .map(|e| EpochStats {
                    seconds: 0.0,
                    ..e.clone()
                })
                .collect::<Vec<_>>()
        };
        assert_eq!(untimed(&ra.epochs), untimed(&rb.epochs));
        // Resuming the final checkpoint has nothing left to do.
        let (c, _) = resume(&ck, &data, &full, |_| panic!("no epochs left")).unwrap();
        assert_eq!(a, c);
        assert_eq!(ra.final_errors, rb.final_errors);
    }
}

/// A network whose second hidden layer is mostly dead fits worse than one whose dead
/// neurons are revived during training, and revival leaves them live.
#[test]
fn revived_neurons_learn() {
    let data = smooth_data(21);
    let mut init = Mlp::random(&[2, 16, 16, 2], 1);
    init.layers[1].bias[..12].fill(-100.0);
    let points = &data.inputs;
    assert_eq!(init.live_neurons(points), vec![16, 4]);
    let run = |revive_every| {
        let settings = TrainSettings {
            revive_every,
            ..quick(300, 0.0)
        };
        let (mlp, rep) = train(init.clone(), &data, &settings, |_| {}).unwrap();
        let revived: usize = rep.epochs.iter().map(|e| e.revived).sum();
        (
            mlp.live_neurons(points),
            rep.final_errors.mean_error,
            revived,
        )
    };
    let (live_dead, err_dead, none) = run(0);
    let (live, err, revived) = run(50);
    eprintln!("without revival: live {live_dead:?}, mean error {err_dead}");
    eprintln!("with revival: live {live:?}, mean error {err}, {revived} revivals");
    assert_eq!(none, 0);
    assert_eq!(
        live_dead[1], 4,
        "dead neurons have no gradient and stay dead"
    );
    assert!(revived >= 12);
    assert!(live[1] >= 14, "{live:?}");
    assert!(err < 0.75 * err_dead, "{err} vs {err_dead}");
}

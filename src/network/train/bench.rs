//! Epoch timing for the paper's scenario-1 size (run with
//! `cargo test --release --lib bench_epoch -- --ignored --nocapture`).

use std::time::Instant;

use super::*;
use crate::network::Mlp;

#[test]
#[ignore = "timing; run in release"]
fn bench_epoch_2x400x400x400x2_100k() {
    let n = 100_000;
    let mut d = Dataset {
        n_in: 2,
        n_out: 2,
        jacobians: Some(Vec::new()),
        ..Default::default()
    };
    for s in 0..n {
        let x1 = -3.5 + 8.0 * ((s * 7919) % n) as f64 / n as f64;
        let x2 = -3.0 + 6.0 * ((s * 104_729) % n) as f64 / n as f64;
        d.inputs.extend([x1, x2]);
        d.targets.extend([x1.sin(), x1 * x2]);
        if let Some(j) = &mut d.jacobians {
            j.extend([x1.cos(), 0.0, x2, x1]);
        }
    }
    let init = Mlp::random(&[2, 400, 400, 400, 2], 1);
    // Chunk = batch: one chunk whose products use every thread (the arithmetic before
    // chunks); smaller chunks run side by side.
    for (precision, batch, chunk, lambda, ibp) in [
        (Precision::F32, 256, 256, 0.0, 0.0),
        (Precision::F32, 256, 128, 0.0, 0.0),
        (Precision::F32, 256, 256, 0.1, 0.0),
        (Precision::F32, 256, 128, 0.1, 0.0),
        (Precision::F32, 256, 256, 0.1, 0.005),
        (Precision::F32, 256, 128, 0.1, 0.005),
        (Precision::F32, 256, 64, 0.1, 0.005),
        (Precision::F32, 256, 32, 0.1, 0.005),
        (Precision::F32, 1024, 1024, 0.1, 0.0),
        (Precision::F32, 1024, 128, 0.1, 0.0),
        (Precision::F64, 256, 256, 0.1, 0.0),
        (Precision::F64, 256, 128, 0.1, 0.0),
    ] {
        let s = TrainSettings {
            epochs: 2,
            batch_size: batch,
            chunk_size: chunk,
            jacobian_weight: lambda,
            ibp_weight: ibp,
            precision,
            hard_example_fraction: 0.0,
            ..Default::default()
        };
        let t = Instant::now();
        let (_, rep) = train(init.clone(), &d, &s, |_| {}).unwrap();
        let total = t.elapsed().as_secs_f64();
        let ep: Vec<String> = rep
            .epochs
            .iter()
            .map(|e| format!("{:.2}", e.seconds))
            .collect();
        eprintln!(
            "{precision:?} batch {batch} chunk {chunk} λ {lambda} λ_ibp {ibp}: epochs {} s, final f64 evaluation {:.2} s, loss {:.4}",
            ep.join(" / "),
            total - rep.epochs.iter().map(|e| e.seconds).sum::<f64>(),
            rep.epochs[1].loss
        );
    }
}

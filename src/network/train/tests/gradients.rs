//! Each loss term's gradient against its loss (secant, chunks, IBP excess, the IBP workspace)
//! and what the IBP term does to bounds. May import: the trainer tests' fixtures.

use super::*;

/// With `secant_step` the Sobolev term is `λ Σ ((N(x + h e_j) − N(x − h e_j))/2h − Dv)²`:
/// the worker's gradient equals the finite differences of that loss computed from
/// `Mlp::forward`, and the slope term moves the biases (where the ReLUs switch), which a
/// slope term on the pointwise Jacobian cannot.
#[test]
fn secant_term_gradient_is_its_loss_gradient() {
    let data = smooth_data(5);
    let net = to_params::<f64>(&Mlp::random(&[2, 7, 6, 2], 11));
    let h = [0.1, 0.07];
    let s = TrainSettings {
        jacobian_weight: 0.3,
        secant_step: Some(h.to_vec()),
        ..Default::default()
    };
    let batch: Vec<usize> = (0..data.len()).collect();
    let loss = |net: &[Params<f64>]| {
        let mlp = to_mlp(net);
        let mut sum = 0.0;
        for &i in &batch {
            let x = data.input(i);
            let y = mlp.forward(x);
            let value: f64 = y
                .iter()
                .zip(data.target(i))
                .map(|(a, t)| (a - t).powi(2))
                .sum();
            let dv = slope_target(&data, i, None).unwrap();
            let mut slope = 0.0;
            for (j, &hj) in h.iter().enumerate() {
                let (mut plus, mut minus) = (x.to_vec(), x.to_vec());
                plus[j] += hj;
                minus[j] -= hj;
                let (yp, ym) = (mlp.forward(&plus), mlp.forward(&minus));
                for o in 0..2 {
                    slope += ((yp[o] - ym[o]) / (2.0 * hj) - dv[o * 2 + j]).powi(2);
                }
            }
            sum += value + 0.3 * slope;
        }
        sum / batch.len() as f64
    };
    let mut worker = ChunkWorker::new(&net);
    worker.gradient(&net, &data, &batch, batch.len(), &s, None);
    let visited: f64 = worker.visits.iter().map(|v| v.loss).sum::<f64>() / batch.len() as f64;
    assert!((visited - loss(&net)).abs() < 1e-12 * loss(&net));
    let fd_step = 1e-6;
    for k in 0..net.len() {
        for idx in 0..net[k].w.len() + net[k].b.len() {
            let nudge = |d: f64| {
                let mut p = net.clone();
                match idx.checked_sub(p[k].w.len()) {
                    None => p[k].w[idx] += d,
                    Some(bi) => p[k].b[bi] += d,
                }
                loss(&p)
            };
            let fd = (nudge(fd_step) - nudge(-fd_step)) / (2.0 * fd_step);
            let g = match idx.checked_sub(net[k].w.len()) {
                None => worker.grads[k].w[idx],
                Some(bi) => worker.grads[k].b[bi],
            };
            assert!(
                (fd - g).abs() < 1e-5 * (1.0 + fd.abs()),
                "layer {k} parameter {idx}: finite differences {fd}, gradient {g}"
            );
        }
    }
    // The slope term's own share of the biases' gradient: none from the pointwise
    // Jacobian, some from the differences.
    let bias_share = |secant_step: Option<Vec<f64>>| {
        let with = |jacobian_weight: f64| {
            let s = TrainSettings {
                jacobian_weight,
                secant_step: secant_step.clone(),
                ..Default::default()
            };
            let mut worker = ChunkWorker::new(&net);
            worker.gradient(&net, &data, &batch, batch.len(), &s, None);
            worker.grads
        };
        let (on, off) = (with(0.3), with(0.0));
        on.iter()
            .zip(&off)
            .flat_map(|(a, b)| a.b.iter().zip(&b.b).map(|(x, y)| (x - y).abs()))
            .fold(0.0f64, f64::max)
    };
    // Zero in exact arithmetic; the GEMM kernel (AVX-512 or AVX2, with or without fused
    // multiply-adds) may leave rounding noise of order 1e-17 where the term adds zeros.
    let pointwise = bias_share(None);
    assert!(
        pointwise < 1e-12,
        "pointwise Jacobian term moved the biases by {pointwise}"
    );
    assert!(bias_share(Some(h.to_vec())) > 1e-3);
    // One step, or one per input: three steps for two inputs are refused by name.
    let three = TrainSettings {
        secant_step: Some(vec![0.1; 3]),
        ..s
    };
    let err = train(to_mlp(&net), &data, &three, |_| {}).unwrap_err();
    assert!(err.to_string().contains("secant_step"), "{err}");
}

/// A batch's gradient summed from uneven chunks is the whole batch's gradient (value,
/// Sobolev and IBP terms: each chunk's part is a mean over the whole batch), and each
/// sample's visit is the same.
#[test]
fn chunked_gradient_is_the_batch_gradient() {
    let data = smooth_data(6);
    let net = to_params::<f64>(&Mlp::random(&[2, 12, 12, 2], 5));
    let radius = [0.05, 0.05];
    let batch: Vec<usize> = (0..data.len()).rev().collect();
    let gradient = |chunks: &[&[usize]], ibp_weight: f64| {
        let s = TrainSettings {
            jacobian_weight: 0.3,
            ibp_weight,
            ..Default::default()
        };
        let mut sum: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
        let (mut visits, mut width) = (Vec::new(), 0.0);
        for chunk in chunks {
            let mut worker = ChunkWorker::new(&net);
            worker.gradient(&net, &data, chunk, batch.len(), &s, Some(&radius));
            for (g, gi) in sum.iter_mut().zip(&worker.grads) {
                for (d, &v) in g.w.iter_mut().zip(&gi.w).chain(g.b.iter_mut().zip(&gi.b)) {
                    *d += v;
                }
            }
            visits.extend(worker.visits.iter().map(|v| (v.sample, v.loss)));
            width += worker.width_sum;
        }
        let flat: Vec<f64> = sum
            .iter()
            .flat_map(|p| p.w.iter().chain(&p.b))
            .copied()
            .collect();
        (flat, visits, width)
    };
    let uneven: Vec<&[usize]> = batch.chunks(7).collect();
    let (whole, whole_visits, whole_width) = gradient(&[&batch], 0.02);
    let (chunked, chunked_visits, chunked_width) = gradient(&uneven, 0.02);
    let (no_ibp, _, _) = gradient(&[&batch], 0.0);
    let scale = whole.iter().fold(0.0f64, |m, g| m.max(g.abs()));
    let gap = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
    };
    assert!(
        gap(&whole, &chunked) <= 1e-12 * scale,
        "{}",
        gap(&whole, &chunked)
    );
    // The IBP term's share is far above that tolerance: a chunk weighing it by its own
    // size instead of the batch's would fail the test.
    assert!(gap(&whole, &no_ibp) > 1e-3 * scale);
    assert_eq!(whole_visits.len(), batch.len());
    for ((s, a), (t, b)) in whole_visits.iter().zip(&chunked_visits) {
        assert_eq!(s, t);
        assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0));
    }
    assert!((whole_width - chunked_width).abs() <= 1e-12 * whole_width);
}

/// With [`TrainSettings::ibp_excess`] the IBP term subtracts the network's linear range
/// `λ_ibp/(B m) Σ_{s,o,j} |∂N_o/∂x_j(x_s)| 2ε_j`: the gradients with and without it differ
/// by that range's gradient, taken here by central differences over the weights with
/// `Mlp::jacobian`.
#[test]
fn ibp_excess_subtracts_the_linear_range() {
    let data = smooth_data(4);
    let mlp = Mlp::random(&[2, 8, 8, 2], 9);
    let net = to_params::<f64>(&mlp);
    let (radius, lambda_ibp) = ([0.05, 0.03], 0.7);
    let batch: Vec<usize> = (0..data.len()).collect();
    let gradient = |ibp_excess: bool| {
        let s = TrainSettings {
            ibp_weight: lambda_ibp,
            ibp_excess,
            ..Default::default()
        };
        let mut worker = ChunkWorker::new(&net);
        worker.gradient(&net, &data, &batch, batch.len(), &s, Some(&radius));
        let g = worker.grads;
        g.iter()
            .flat_map(|p| p.w.iter().chain(&p.b))
            .copied()
            .collect::<Vec<f64>>()
    };
    let (plain, excess) = (gradient(false), gradient(true));
    let range = |m: &Mlp| {
        let mut sum = 0.0;
        for s in &batch {
            let jac = m.jacobian(data.input(*s));
            for o in 0..2 {
                sum += (0..2)
                    .map(|j| jac[o * 2 + j].abs() * 2.0 * radius[j])
                    .sum::<f64>();
            }
        }
        lambda_ibp * sum / (batch.len() * 2) as f64
    };
    let mut checked = 0;
    let mut index = 0;
    for (k, layer) in mlp.layers.iter().enumerate() {
        // Weights only: the range does not depend on the output bias.
        for (i, _) in layer.weight.iter().enumerate().step_by(3) {
            let h = 1e-6;
            let (mut up, mut down) = (mlp.clone(), mlp.clone());
            up.layers[k].weight[i] += h;
            down.layers[k].weight[i] -= h;
            let fd = (range(&up) - range(&down)) / (2.0 * h);
            let d = excess[index + i] - plain[index + i];
            assert!(
                (d + fd).abs() <= 1e-6 * (1.0 + fd.abs()),
                "layer {k} w{i}: {d} vs −{fd}"
            );
            checked += usize::from(fd != 0.0);
        }
        index += layer.weight.len() + layer.bias.len();
    }
    assert!(checked > 20, "{checked} weights move the range");
}

/// The IBP workspace's intervals are those of `crate::bounds` (IBP), and its gradient of
/// `L = Σ a·out_c + Σ b·out_r` matches central finite differences.
#[test]
fn ibp_term_matches_bounds_and_finite_differences() {
    use crate::bounds::{network_bounds, BoundMethod};
    let mlp = Mlp::random(&[2, 6, 5, 2], 11);
    let centres: Vec<Vec<f64>> = (0..5)
        .map(|i| vec![0.3 * i as f64 - 0.6, 0.25 - 0.15 * i as f64])
        .collect();
    let radius = [0.1, 0.2];
    let net = to_params::<f64>(&mlp);
    let mut ws = IbpWorkspace::<f64>::new(net.len());
    ws.forward(&net, centres.len(), |i| &centres[i], &radius);
    for (i, c) in centres.iter().enumerate() {
        let lo: Vec<f64> = c.iter().zip(radius).map(|(x, r)| x - r).collect();
        let hi: Vec<f64> = c.iter().zip(radius).map(|(x, r)| x + r).collect();
        let bd = network_bounds(&mlp, &lo, &hi, BoundMethod::Ibp).unwrap();
        for o in 0..2 {
            let (oc, or) = (ws.out_c[i * 2 + o], ws.out_r[i * 2 + o]);
            assert!(
                (oc - or - bd.lower[o]).abs() < 1e-9,
                "{} vs {}",
                oc - or,
                bd.lower[o]
            );
            assert!((oc + or - bd.upper[o]).abs() < 1e-9);
        }
    }
    let a: Vec<f64> = (0..10).map(|k| (k as f64 * 0.9).cos()).collect();
    let bw: Vec<f64> = (0..10).map(|k| 1.0 + (k as f64 * 0.7).sin()).collect();
    let loss = |net: &[Params<f64>]| {
        let mut w = IbpWorkspace::<f64>::new(net.len());
        w.forward(net, centres.len(), |i| &centres[i], &radius);
        w.out_c.iter().zip(&a).map(|(x, y)| x * y).sum::<f64>()
            + w.out_r.iter().zip(&bw).map(|(x, y)| x * y).sum::<f64>()
    };
    let mut grads: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
    ws.backward(&net, &a, &bw, &mut grads);
    let h = 1e-6;
    let mut checked = 0;
    for k in 0..net.len() {
        for (is_w, len) in [(true, net[k].w.len()), (false, net[k].b.len())] {
            for idx in 0..len {
                let (mut plus, mut minus) = (net.clone(), net.clone());
                if is_w {
                    plus[k].w[idx] += h;
                    minus[k].w[idx] -= h;
                } else {
                    plus[k].b[idx] += h;
                    minus[k].b[idx] -= h;
                }
                let fd = (loss(&plus) - loss(&minus)) / (2.0 * h);
                let g = if is_w {
                    grads[k].w[idx]
                } else {
                    grads[k].b[idx]
                };
                assert!(
                    (fd - g).abs() < 1e-6 * (1.0 + fd.abs()),
                    "layer {k} {} [{idx}]: fd {fd} vs {g}",
                    if is_w { "w" } else { "b" }
                );
                checked += 1;
            }
        }
    }
    assert_eq!(checked, 6 * 2 + 6 + 5 * 6 + 5 + 2 * 5 + 2);
    // The training term: λ · mean 2 r, gradient 2λ/(B m) on every output radius.
    let mut g2: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
    let sum = ibp_term(
        &mut ws,
        &net,
        &mut g2,
        0.3,
        2 * centres.len(),
        centres.len(),
        |i| &centres[i],
        &radius,
    );
    let want: f64 = ws.out_r.iter().map(|r| 2.0 * r).sum();
    assert_eq!(sum, want);
    let mut g3: Vec<Params<f64>> = net.iter().map(|p| p.zeros_like()).collect();
    let s = 2.0 * 0.3 / 10.0;
    ws.backward(&net, &[0.0; 10], &[s; 10], &mut g3);
    assert_eq!(g2, g3);
}

/// Mean (IBP, CROWN) output width and mean sampled range over boxes of half-width `eps`
/// centred on a 7 × 7 grid of `[−0.8, 0.8]²`.
fn looseness(mlp: &Mlp, eps: f64) -> (f64, f64, f64) {
    use crate::bounds::{network_bounds, BoundMethod};
    let (mut ibp, mut crown, mut range) = (0.0, 0.0, 0.0);
    let mut count = 0.0;
    for i in 0..7 {
        for j in 0..7 {
            let c = [-0.8 + 0.8 * i as f64 / 3.0, -0.8 + 0.8 * j as f64 / 3.0];
            let lo = [c[0] - eps, c[1] - eps];
            let hi = [c[0] + eps, c[1] + eps];
            let bi = network_bounds(mlp, &lo, &hi, BoundMethod::Ibp).unwrap();
            let bc = network_bounds(mlp, &lo, &hi, BoundMethod::Crown).unwrap();
            let (mut smin, mut smax) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
            for p in 0..11 {
                for q in 0..11 {
                    let x = [lo[0] + 0.2 * eps * p as f64, lo[1] + 0.2 * eps * q as f64];
                    let y = mlp.forward(&x);
                    for o in 0..2 {
                        smin[o] = smin[o].min(y[o]);
                        smax[o] = smax[o].max(y[o]);
                    }
                }
            }
            for o in 0..2 {
                ibp += bi.upper[o] - bi.lower[o];
                crown += bc.upper[o] - bc.lower[o];
                range += smax[o] - smin[o];
                count += 1.0;
            }
        }
    }
    (ibp / count, crown / count, range / count)
}

/// Certified training: with the IBP term the widths on small boxes shrink towards the
/// true ranges, at a modest cost in accuracy.
#[test]
fn ibp_term_tightens_bounds() {
    let data = smooth_data(21);
    let init = Mlp::random(&[2, 32, 32, 2], 5);
    let (eps, lam) = (0.05, 0.01);
    let plain_s = quick(300, 0.1);
    let cert_s = TrainSettings {
        ibp_weight: lam,
        ibp_radius: vec![eps],
        ibp_ramp: 30,
        ..plain_s.clone()
    };
    let (plain, rp) = train(init.clone(), &data, &plain_s, |_| {}).unwrap();
    let (cert, rc) = train(init, &data, &cert_s, |_| {}).unwrap();
    assert!(rp.epochs.iter().all(|e| e.ibp_width.is_none()));
    assert!(rc.epochs.iter().all(|e| e.ibp_width.is_some()));
    let (pi, pc, pr) = looseness(&plain, eps);
    let (ci, cc, cr) = looseness(&cert, eps);
    eprintln!(
        "plain: IBP {pi:.4} CROWN {pc:.4} range {pr:.4} max err {:.4} mean {:.4}\n\
         cert:  IBP {ci:.4} CROWN {cc:.4} range {cr:.4} max err {:.4} mean {:.4}\n\
         IBP/range {:.2} → {:.2}, CROWN/range {:.2} → {:.2}",
        rp.final_errors.max_error,
        rp.final_errors.mean_error,
        rc.final_errors.max_error,
        rc.final_errors.mean_error,
        pi / pr,
        ci / cr,
        pc / pr,
        cc / cr
    );
    // Measured (release): IBP/range 6.77 → 1.38, CROWN/range 1.05 → 1.03, max error
    // 0.012 → 0.031, mean 0.0034 → 0.0039.
    assert!(
        ci / cr < 0.3 * (pi / pr),
        "IBP looseness {} vs {}",
        ci / cr,
        pi / pr
    );
    assert!(cc - cr < pc - pr, "CROWN excess {} vs {}", cc - cr, pc - pr);
    assert!(rc.final_errors.max_error < 3.0 * rp.final_errors.max_error.max(0.01));
    assert!(rc.final_errors.mean_error < 2.0 * rp.final_errors.mean_error);
}

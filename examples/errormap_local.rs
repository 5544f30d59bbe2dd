//! Scratch: local bounds of an error map vs sampled local errors (not part of the product).
use cbfreach::boxes::IntervalBox;
use cbfreach::filter::SafetyFilter;
use cbfreach::network::Mlp;
use cbfreach::scenario::Scenario;
use cbfreach::surrogate_error::{error_map_path, ErrorMap};
use std::path::Path;

fn main() {
    let scen = std::env::args().nth(1).unwrap();
    let s = Scenario::load(Path::new(&scen)).unwrap();
    let netp = s.network.as_ref().unwrap().file.clone();
    let net = Mlp::load_safetensors(&netp).unwrap();
    let map = ErrorMap::load(&error_map_path(&netp)).unwrap();
    let filter = SafetyFilter::new(&s);
    let sampled = |b: &IntervalBox| -> f64 {
        let k = 12;
        let mut e = 0.0f64;
        for i in 0..=k {
            for j in 0..=k {
                let x = b.point_at(&[i as f64 / k as f64, j as f64 / k as f64]);
                if !s.is_safe(&x) {
                    continue;
                }
                let Ok(v) = filter.eval(&x) else { continue };
                let n = net.forward(&x);
                for (a, c) in v.iter().zip(&n) {
                    e = e.max((a - c).abs());
                }
            }
        }
        e
    };
    println!(
        "cells {} certified {:?}",
        map.cells.len(),
        map.certified_linf
    );
    for (c, w) in [
        ((0.0, 0.0), 1.0),
        ((0.0, 0.0), 0.4),
        ((0.0, 0.0), 0.2),
        ((0.0, 0.0), 0.1),
        ((0.5, 0.5), 0.2),
        ((-1.0, 1.0), 0.2),
        ((1.0, -1.5), 0.2),
    ] {
        let b = IntervalBox::new(
            vec![c.0 - w / 2.0, c.1 - w / 2.0],
            vec![c.0 + w / 2.0, c.1 + w / 2.0],
        )
        .unwrap();
        println!(
            "box centre {:?} width {w}: local {:.4} sampled {:.4}",
            c,
            map.local_bound(&b),
            sampled(&b)
        );
    }
    // ratio over a grid of 0.2-wide boxes across C ∩ S
    let r = &s.reach.region;
    let mut ratios = vec![];
    let nb = 40;
    for i in 0..nb {
        for j in 0..nb {
            let w0 = (r.upper[0] - r.lower[0]) / nb as f64;
            let w1 = (r.upper[1] - r.lower[1]) / nb as f64;
            let b = IntervalBox::new(
                vec![r.lower[0] + i as f64 * w0, r.lower[1] + j as f64 * w1],
                vec![
                    r.lower[0] + (i + 1) as f64 * w0,
                    r.lower[1] + (j + 1) as f64 * w1,
                ],
            )
            .unwrap();
            if !s.is_safe(&b.center()) {
                continue;
            }
            let sm = sampled(&b).max(0.01);
            ratios.push(map.local_bound(&b) / sm);
        }
    }
    ratios.sort_by(f64::total_cmp);
    let q = |p: f64| ratios[((p * ratios.len() as f64) as usize).min(ratios.len() - 1)];
    println!("ratio local/max(sampled,0.01) over {} boxes {:.3}x{:.3}: median {:.2} p75 {:.2} p90 {:.2} max {:.2}; share ≤2: {:.2}", ratios.len(), (r.upper[0]-r.lower[0])/nb as f64, (r.upper[1]-r.lower[1])/nb as f64, q(0.5), q(0.75), q(0.9), q(1.0), ratios.iter().filter(|&&x| x <= 2.0).count() as f64 / ratios.len() as f64);
    let t = std::time::Instant::now();
    let mut acc = 0.0;
    for k in 0..10000 {
        let x = -3.0 + 6.0 * (k as f64 / 10000.0);
        let b = IntervalBox::new(vec![x, 0.0], vec![x + 0.1, 0.1]).unwrap();
        acc += map.local_bound(&b);
    }
    println!("10k local_bound calls: {:?} ({acc:.1})", t.elapsed());
}

#[allow(dead_code)]
pub fn probe() {}

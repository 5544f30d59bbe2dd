//! Box bounds per second for every bound method on the paper-size architectures
//! (docs/design.md §5; issue 5 item 7).
//!
//! `cargo bench --bench bounds` (`CBFREACH_BENCH_QUICK=1` for small batches). Throughput is in
//! boxes (divan's "item/s"); the FLOP model per box is printed first, so GFLOP/s is
//! `2 × model mult-adds × boxes/s`. Networks are random (seeded, He-uniform), boxes are 0.1 wide
//! and centred in `[−2, 2]²`. Backward CROWN's batches stop at 256 boxes: it runs one box per
//! task, so its rate does not change with larger batches (only the wall time does).

use std::sync::OnceLock;

use cbfreach::bounds::{network_bounds_batch_into, AffineBoundsBatch, BoundMethod};
use cbfreach::network::Mlp;
use divan::counter::ItemsCount;
use divan::Bencher;

/// The paper's two architectures.
const ARCHS: [&[usize]; 2] = [&[2, 400, 400, 400, 2], &[2, 500, 500, 500, 1]];

fn quick() -> bool {
    std::env::var("CBFREACH_BENCH_QUICK").is_ok_and(|v| !v.is_empty() && v != "0")
}

/// One benchmark case: architecture, method, number of boxes.
#[derive(Clone, Copy, Debug)]
struct Case {
    arch: usize,
    method: BoundMethod,
    boxes: usize,
}

impl std::fmt::Display for Case {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let widths: Vec<String> = ARCHS[self.arch].iter().map(|w| w.to_string()).collect();
        write!(f, "{} {} B={}", widths.join("x"), self.method, self.boxes)
    }
}

fn cases() -> Vec<Case> {
    let sizes: &[usize] = if quick() {
        &[1, 16, 64]
    } else {
        &[1, 16, 256, 4096]
    };
    let mut out = Vec::new();
    for arch in 0..ARCHS.len() {
        for method in BoundMethod::ALL {
            let crown = matches!(method, BoundMethod::Crown | BoundMethod::CrownSameSlope);
            for &boxes in sizes {
                if crown && boxes > 256 {
                    continue;
                }
                out.push(Case {
                    arch,
                    method,
                    boxes,
                });
            }
        }
    }
    out
}

fn network(arch: usize) -> &'static Mlp {
    static NETS: OnceLock<Vec<Mlp>> = OnceLock::new();
    &NETS.get_or_init(|| ARCHS.iter().map(|w| Mlp::random(w, 1)).collect())[arch]
}

/// `boxes` boxes 0.1 wide, deterministic.
fn boxes(boxes: usize) -> (Vec<f64>, Vec<f64>) {
    let (mut lo, mut hi) = (Vec::new(), Vec::new());
    for k in 0..boxes {
        for p in 0..2 {
            let c = 4.0 * (((k * 2 + p) as f64 * 0.618_034).fract()) - 2.0;
            lo.push(c - 0.05);
            hi.push(c + 0.05);
        }
    }
    (lo, hi)
}

#[divan::bench(args = cases(), sample_count = 5, sample_size = 1)]
fn bounds(bencher: Bencher, case: Case) {
    let net = network(case.arch);
    let (lo, hi) = boxes(case.boxes);
    let mut out = AffineBoundsBatch::new();
    bencher
        .counter(ItemsCount::new(case.boxes))
        .bench_local(|| {
            network_bounds_batch_into(net, &lo, &hi, case.method, &mut out)
                .expect("valid benchmark input");
            divan::black_box(&out);
        });
}

fn main() {
    eprintln!(
        "FLOP model (docs/design.md §5), mult-adds per box; GFLOP/s = 2 × this × boxes/s / 1e9:"
    );
    for widths in ARCHS {
        for method in BoundMethod::ALL {
            eprintln!(
                "  {widths:?} {method}: {:.2} M",
                cbfreach::bounds::model_multiply_adds(widths, method) / 1e6
            );
        }
    }
    eprintln!("rayon threads: {}", rayon::current_num_threads());
    divan::main();
}

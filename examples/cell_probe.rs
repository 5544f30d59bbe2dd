//! Scratch: error bound pieces on cells of several widths at a point.
use cbfreach::bounds::{network_bounds, BoundMethod};
use cbfreach::boxes::IntervalBox;
use cbfreach::filter::SafetyFilter;
use cbfreach::network::Mlp;
use cbfreach::scenario::Scenario;
use cbfreach::surrogate_error::v_enclosure;
use std::path::Path;

fn main() {
    let a: Vec<String> = std::env::args().collect();
    let s = Scenario::load(Path::new(&a[1])).unwrap();
    let x0: f64 = a[2].parse().unwrap();
    let y0: f64 = a[3].parse().unwrap();
    let net = Mlp::load_safetensors(&s.network.as_ref().unwrap().file).unwrap();
    let method = SafetyFilter::new(&s).method();
    for w in [0.25, 0.125, 0.0625, 0.03125, 0.015625, 0.0078125] {
        let b = IntervalBox::new(
            vec![x0 - w / 2.0, y0 - w / 2.0],
            vec![x0 + w / 2.0, y0 + w / 2.0],
        )
        .unwrap();
        let v = v_enclosure(&s, method, &b).unwrap();
        let t = std::time::Instant::now();
        let ibp = network_bounds(&net, &b.lower, &b.upper, BoundMethod::Ibp).unwrap();
        let t1 = t.elapsed();
        let cr = network_bounds(&net, &b.lower, &b.upper, BoundMethod::Crown).unwrap();
        let t2 = t.elapsed() - t1;
        println!(
            "w {w}: v {:?} ibp {:?}..{:?} crown {:?}..{:?} N(c) {:?} ({:?} / {:?})",
            v.iter().map(|i| (i.lower, i.upper)).collect::<Vec<_>>(),
            ibp.lower,
            ibp.upper,
            cr.lower,
            cr.upper,
            net.forward(&b.center()),
            t1,
            t2
        );
    }
}

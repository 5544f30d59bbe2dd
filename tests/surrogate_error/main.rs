//! The measured and certified error of a surrogate network, and the error map (issue 6).
//!
//! A 2×16×16×2 network is trained here, in a second or so, on scenario 1 restricted to a small
//! region around the obstacle; every certified number is then checked against dense sampling.

#[path = "../common/mod.rs"]
mod common;
mod measurement;
mod shipped;

use std::path::PathBuf;
use std::sync::OnceLock;

use cbfreach::bounds::{BoundMethod, PreparedNetwork};
use cbfreach::boxes::IntervalBox;
use cbfreach::dataset::{filter_dataset, grid_points, Slopes};
use cbfreach::error_map::{error_map_path, resolve_margin, CellBound, ErrorMap};
use cbfreach::filter::{v_enclosure, FilterMethod, Kink, SafetyFilter, VForms, VShape};
use cbfreach::network::train::{train, TrainSettings};
use cbfreach::network::Mlp;
use cbfreach::scenario::{Margin, Scenario};
use cbfreach::surrogate_error::{
    cell_error_bound_mv, centred_grid, certify, looseness, measure, measurement_counts,
    measurement_points, measurement_size, proven_unsafe, Certified, ErrorSettings, Measured,
    Percentiles, MAX_MEASUREMENT_POINTS, WITNESS_CELLS,
};
use tempfile::TempDir;

/// Scenario 1 on `C = [0.5, 3.5] × [−1.5, 1.5]` (the obstacle and its surroundings).
fn small_scenario() -> Scenario {
    let mut s = common::integrator();
    let region = IntervalBox::new(vec![0.5, -1.5], vec![3.5, 1.5]).unwrap();
    s.reach.region = region.clone();
    s.training.region = region;
    s.training.grid = vec![40, 40];
    s
}

struct Fixture {
    s: Scenario,
    net: Mlp,
    measured: Measured,
    certified: Certified,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let s = small_scenario();
        let filter = SafetyFilter::new(&s);
        let pts = grid_points(&s.training.region, &s.training.grid);
        let (data, _) = filter_dataset(&filter, &pts, &Slopes::Pointwise, &|_| {});
        let settings = TrainSettings {
            epochs: 40,
            learning_rate: 3e-3,
            batch_size: 64,
            jacobian_weight: 0.01,
            ..TrainSettings::default()
        };
        let (net, _) = train(Mlp::random(&[2, 16, 16, 2], 1), &data, &settings, |_| {}).unwrap();
        let es = ErrorSettings {
            budget: 3000,
            ..ErrorSettings::default()
        };
        let measured = measure(&s, &net, &es, &|_| {}).unwrap();
        let certified = certify(&s, &net, measured.linf, &es, &|_, _| {})
            .unwrap()
            .expect("one CBF row: a closed form");
        Fixture {
            s,
            net,
            measured,
            certified,
        }
    })
}

/// `max_i |aᵢ − bᵢ|`.
fn max_abs_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .map(|(p, q)| (p - q).abs())
        .fold(0.0, f64::max)
}

/// `‖N(x) − v(x)‖∞` at the feasible safe points of a dense grid over the region.
fn dense_errors(f: &Fixture, counts: &[usize]) -> Vec<(Vec<f64>, f64)> {
    errors_on_grid(&f.s, &f.net, &f.s.reach.region, counts)
}

/// `‖N(x) − v(x)‖∞` at the safe points of a grid over `region` where the filter is feasible.
fn errors_on_grid(
    s: &Scenario,
    net: &Mlp,
    region: &IntervalBox,
    counts: &[usize],
) -> Vec<(Vec<f64>, f64)> {
    let filter = SafetyFilter::new(s);
    let (points, values): (Vec<Vec<f64>>, Vec<Vec<f64>>) = grid_points(region, counts)
        .into_iter()
        .filter(|x| s.is_safe(x))
        .filter_map(|x| {
            let v = filter.eval(&x).ok()?;
            Some((x, v))
        })
        .unzip();
    let outputs = net.forward_many(&points.concat());
    let m = net.output_dim();
    points
        .into_iter()
        .zip(values)
        .zip(outputs.chunks_exact(m))
        .map(|((x, v), n)| (x, max_abs_diff(&v, n)))
        .collect()
}

#[test]
fn certified_bound_is_never_below_a_sampled_error() {
    let f = fixture();
    let c = &f.certified;
    assert!(c.linf.is_finite(), "certified bound {}", c.linf);
    assert!(
        c.linf >= f.measured.linf,
        "{} < measured {}",
        c.linf,
        f.measured.linf
    );
    let errors = dense_errors(f, &[301, 301]);
    assert!(errors.len() > 50_000);
    let worst = errors.iter().map(|e| e.1).fold(0.0, f64::max);
    assert!(worst > 0.0);
    assert!(
        worst <= c.linf,
        "sampled error {worst} > certified {}",
        c.linf
    );
    // The witness is an error the network attains where it says, no greater than the certified
    // bound, and found in a cell of largest bound.
    let w = &c.witness;
    assert_eq!(w.len(), 2);
    let v = SafetyFilter::new(&f.s).eval(w).unwrap();
    let at = f.net.forward(w);
    let e = (0..2).map(|o| (at[o] - v[o]).abs()).fold(0.0, f64::max);
    assert_eq!(e, c.witness_linf);
    assert!(c.witness_linf > 0.0 && c.witness_linf <= c.linf);
    let mut bounds: Vec<f64> = c.cells.iter().map(|cell| cell.bound).collect();
    bounds.sort_by(|a, b| b.total_cmp(a));
    let top = bounds[WITNESS_CELLS - 1];
    assert!(c
        .cells
        .iter()
        .any(|cell| cell.bound >= top
            && (0..2).all(|i| cell.lower[i] <= w[i] && w[i] <= cell.upper[i])));
    // Per cell too: the error at every sample is within the bound of each kept cell holding it,
    // and every safe sample lies in some kept cell (dropped cells miss S).
    for (x, e) in &errors {
        let holders: Vec<_> = c
            .cells
            .iter()
            .filter(|cell| (0..2).all(|i| cell.lower[i] <= x[i] && x[i] <= cell.upper[i]))
            .collect();
        assert!(!holders.is_empty(), "safe point {x:?} is in no kept cell");
        for cell in holders {
            assert!(
                *e <= cell.bound,
                "error {e} at {x:?} > cell bound {}",
                cell.bound
            );
        }
    }
}

#[test]
fn v_enclosure_contains_sampled_v_on_random_cells() {
    for (s, method) in [
        (common::integrator(), FilterMethod::ClosedFormSingle),
        (common::double_integrator(), FilterMethod::ClosedFormScalar),
    ] {
        let filter = SafetyFilter::new(&s);
        assert_eq!(filter.method(), method);
        let c = &s.reach.region;
        let mut rnd = uniform(12345_u64);
        let (mut finite, mut active) = (0, 0);
        for _ in 0..400 {
            let w = 0.01 + 0.5 * rnd();
            let lo: Vec<f64> = (0..2)
                .map(|i| c.lower[i] + rnd() * (c.upper[i] - c.lower[i] - w))
                .collect();
            let cell = IntervalBox::new(lo.clone(), lo.iter().map(|l| l + w).collect()).unwrap();
            let v = v_enclosure(&s, method, &cell).unwrap();
            if v.iter().all(|i| i.lower.is_finite() && i.upper.is_finite()) {
                finite += 1;
            }
            for _ in 0..40 {
                let x = cell.point_at(&[rnd(), rnd()]);
                if !s.is_safe(&x) {
                    continue; // the enclosure holds on cell ∩ S
                }
                let Ok(vx) = filter.eval(&x) else { continue };
                for j in 0..vx.len() {
                    assert!(
                        v[j].contains(vx[j]),
                        "v_{j}({x:?}) = {} not in {} (cell {cell:?})",
                        vx[j],
                        v[j]
                    );
                    active += usize::from(vx[j] != 0.0);
                }
            }
        }
        assert!(finite > 200, "{}: only {finite} finite enclosures", s.name);
        assert!(
            active > 1000,
            "{}: the filter hardly acted ({active})",
            s.name
        );
    }
}

#[test]
fn mean_value_enclosure_contains_sampled_v_on_random_cells() {
    for (s, method) in [
        (common::integrator(), FilterMethod::ClosedFormSingle),
        (common::double_integrator(), FilterMethod::ClosedFormScalar),
    ] {
        let filter = SafetyFilter::new(&s);
        let forms = VForms::new(&s).expect("closed form");
        let c = &s.reach.region;
        let mut rnd = uniform(424242_u64);
        let (mut smooth_active, mut tighter, mut checked, mut kinked) = (0, 0, 0, 0);
        for k in 0..600 {
            // Small cells too, and cells along the obstacle where the filter acts.
            let w = if k % 2 == 0 {
                0.005 + 0.1 * rnd()
            } else {
                0.01 + 0.5 * rnd()
            };
            let lo: Vec<f64> = (0..2)
                .map(|i| c.lower[i] + rnd() * (c.upper[i] - c.lower[i] - w))
                .collect();
            let cell = IntervalBox::new(lo.clone(), lo.iter().map(|l| l + w).collect()).unwrap();
            let natural = v_enclosure(&s, method, &cell).unwrap();
            let (v, shape) = forms.enclose(&s, &cell);
            for j in 0..v.len() {
                assert!(v[j].is_subset_of(&natural[j]) || natural[j].is_nan());
                if v[j].width() < 0.9 * natural[j].width() {
                    tighter += 1;
                }
            }
            let n = cell.dim();
            if let Some(sv) = shape.smooth() {
                if sv.jac.iter().any(|g| g.width() > 0.0 || g.lower != 0.0) {
                    smooth_active += 1;
                }
            }
            // Where one row binds on part of the cell, `v` is `min(0, F)` or `max(0, F)` of
            // the row's binding formula `F`, whose centred form is checked below.
            let (form, kinks) = match &shape {
                VShape::Smooth(sv) => (Some(sv), None),
                VShape::Kinked { binding, kinks } => {
                    kinked += 1;
                    (Some(binding), Some(kinks))
                }
                VShape::Unknown => (None, None),
            };
            for _ in 0..40 {
                let x = cell.point_at(&[rnd(), rnd()]);
                if !s.is_safe(&x) {
                    continue;
                }
                let Ok(vx) = filter.eval(&x) else { continue };
                checked += 1;
                for j in 0..vx.len() {
                    assert!(
                        v[j].contains(vx[j]),
                        "{}: v_{j}({x:?}) = {} not in the mean-value enclosure {} (cell {cell:?})",
                        s.name,
                        vx[j],
                        v[j]
                    );
                    if let Some(sv) = form {
                        // v(x) ∈ v(c) + J(X)·(x − c), evaluated in intervals (of F where
                        // kinked, then min(0, ·) or max(0, ·)).
                        let mut e = sv.value[j];
                        for (i, (&xi, &ci)) in x.iter().zip(&sv.centre).enumerate() {
                            let d = cbfreach::intervals::Interval::point(xi)
                                - cbfreach::intervals::Interval::point(ci);
                            e = e + sv.jac[j * n + i] * d;
                        }
                        let zero = cbfreach::intervals::Interval::point(0.0);
                        let e = match kinks.map(|k| k[j]) {
                            None => e,
                            Some(Some(Kink::Min)) => e.min(zero),
                            Some(Some(Kink::Max)) => e.max(zero),
                            Some(None) => cbfreach::intervals::Interval::ENTIRE,
                        };
                        assert!(
                            e.contains(vx[j]),
                            "{}: v_{j}({x:?}) = {} not in the centred form {e} (cell {cell:?})",
                            s.name,
                            vx[j]
                        );
                    }
                }
            }
        }
        assert!(checked > 5000, "{}: {checked} samples", s.name);
        assert!(
            smooth_active > 10,
            "{}: {smooth_active} active smooth cells",
            s.name
        );
        assert!(
            tighter > 10,
            "{}: the mean-value form never helped ({tighter})",
            s.name
        );
        assert!(kinked > 10, "{}: {kinked} kinked cells", s.name);
    }
}

#[test]
fn mean_value_cell_bounds_hold_at_samples() {
    let f = fixture();
    let forms = VForms::new(&f.s).unwrap();
    let filter = SafetyFilter::new(&f.s);
    let mut rnd = uniform(99_u64);
    let mut finite = 0;
    let net = PreparedNetwork::new(&f.net).unwrap();
    for _ in 0..300 {
        let w = 0.002 + 0.2 * rnd();
        let lo = [0.5 + (3.0 - w) * rnd(), -1.5 + (3.0 - w) * rnd()];
        let cell = IntervalBox::new(lo.to_vec(), lo.iter().map(|l| l + w).collect()).unwrap();
        // Both affine bound methods, and a cell-sized IBP-only answer, must hold.
        let method = [BoundMethod::Crown, BoundMethod::ForwardBackward][finite % 2];
        let bound = cell_error_bound_mv(&forms, &f.s, &net, &cell, method, 0.0).unwrap();
        finite += usize::from(bound.is_finite());
        for _ in 0..30 {
            let x = cell.point_at(&[rnd(), rnd()]);
            if !f.s.is_safe(&x) {
                continue;
            }
            let Ok(v) = filter.eval(&x) else { continue };
            let n = f.net.forward(&x);
            let e = v
                .iter()
                .zip(&n)
                .map(|(a, b)| (a - b).abs())
                .fold(0.0, f64::max);
            assert!(e <= bound, "error {e} at {x:?} > bound {bound} of {cell:?}");
        }
    }
    assert!(finite > 200, "{finite}");
}

/// A seeded generator of uniform numbers in [0, 1).
fn uniform(seed: u64) -> impl FnMut() -> f64 {
    use rand::{Rng, SeedableRng};
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    move || rng.random::<f64>()
}

/// The fixture's network saved in a fresh temporary folder and its error map (not yet saved):
/// `(folder, network path, map)`. The folder is removed when the caller drops it.
fn saved_network_and_map(f: &Fixture) -> (TempDir, PathBuf, ErrorMap) {
    let dir = tempfile::tempdir().unwrap();
    let net_path = dir.path().join("small.safetensors");
    f.net
        .save_safetensors(&net_path, &Default::default())
        .unwrap();
    let map = ErrorMap::new(
        &net_path,
        &f.s.reach.region,
        &f.measured,
        Some(&f.certified),
    )
    .unwrap();
    (dir, net_path, map)
}

#[test]
fn indexed_local_bounds_equal_a_linear_scan() {
    let f = fixture();
    let (_dir, _net_path, map) = saved_network_and_map(f);
    let mut rnd = uniform(5_u64);
    let r = &f.s.reach.region;
    for k in 0..2000 {
        // Some boxes are points or sit exactly on cell edges.
        let w = if k % 3 == 0 { 0.0 } else { 0.5 * rnd() };
        let mut lo: Vec<f64> = (0..2)
            .map(|i| r.lower[i] + (r.upper[i] - r.lower[i] - w) * rnd())
            .collect();
        if k % 5 == 0 {
            let c = &map.cells[k % map.cells.len()];
            lo = if w == 0.0 {
                c.upper.clone()
            } else {
                vec![c.upper[0], c.lower[1] - w]
            };
            lo[1] = lo[1].max(r.lower[1]);
        }
        let up: Vec<f64> = lo.iter().map(|l| l + w).collect();
        let b = IntervalBox::new(lo, up).unwrap();
        if !b.is_subset_of(r) {
            continue;
        }
        let scan = map
            .cells
            .iter()
            .filter(|c| c.meets(&b))
            .map(|c| c.bound)
            .fold(0.0, f64::max);
        assert_eq!(map.local_bound(&b), scan, "{b:?}");
    }
}

#[test]
fn unsafe_cells_are_dropped_and_safe_ones_kept() {
    let s = common::integrator();
    // Inside the obstacle (radius 1 around (2, 0)).
    let inside = IntervalBox::new(vec![1.7, -0.3], vec![2.3, 0.3]).unwrap();
    assert!(proven_unsafe(&s, &inside));
    // Straddling the boundary, and entirely outside.
    let straddle = IntervalBox::new(vec![2.8, -0.1], vec![3.2, 0.1]).unwrap();
    let outside = IntervalBox::new(vec![-1.0, -1.0], vec![-0.5, -0.5]).unwrap();
    assert!(!proven_unsafe(&s, &straddle));
    assert!(!proven_unsafe(&s, &outside));
    // Random cells: a dropped cell never holds a safe sample.
    let mut rnd = uniform(7_u64);
    let mut dropped = 0;
    for _ in 0..2000 {
        let w = 0.05 + 0.6 * rnd();
        let lo = [0.5 + 3.0 * rnd(), -1.5 + 3.0 * rnd()];
        let cell = IntervalBox::new(lo.to_vec(), lo.iter().map(|l| l + w).collect()).unwrap();
        if proven_unsafe(&s, &cell) {
            dropped += 1;
            for _ in 0..50 {
                let x = cell.point_at(&[rnd(), rnd()]);
                assert!(
                    !s.is_safe(&x),
                    "dropped cell {cell:?} holds the safe point {x:?}"
                );
            }
        }
    }
    assert!(dropped > 20, "only {dropped} cells dropped");
    assert!(fixture().certified.dropped > 0);
}

#[test]
fn error_map_local_bounds_are_sound_and_below_the_global_one() {
    let f = fixture();
    let (_dir, net_path, mut map) = saved_network_and_map(f);
    let map_path = error_map_path(&net_path);
    // Stamped with what it certifies, as `cbfreach error` does: the margins below load it.
    map.stamp(&f.s, &net_path).unwrap();
    map.save(&map_path).unwrap();
    let map = ErrorMap::load_for(&net_path).unwrap();
    let global = map.certified_linf.unwrap();
    assert_eq!(global, f.certified.linf);

    let errors = dense_errors(f, &[121, 121]);
    let mut below = 0;
    for k in 0..200 {
        let t = k as f64 / 200.0;
        let w = 0.05 + 0.4 * ((k * 37 % 200) as f64 / 200.0);
        let lo = [
            0.5 + (3.0 - w) * t,
            -1.5 + (3.0 - w) * ((k * 71 % 200) as f64 / 200.0),
        ];
        let b = IntervalBox::new(lo.to_vec(), lo.iter().map(|l| l + w).collect()).unwrap();
        let local = map.local_bound(&b);
        assert!(local <= global);
        below += usize::from(local < 0.5 * global);
        for (x, e) in &errors {
            if b.contains(x) {
                assert!(
                    *e <= local,
                    "error {e} at {x:?} > local bound {local} of {b:?}"
                );
            }
        }
    }
    assert!(
        below > 0,
        "no box had a local bound below half the global one"
    );
    // Outside the mapped region.
    let out = IntervalBox::new(vec![3.4, 0.0], vec![3.7, 0.2]).unwrap();
    assert_eq!(map.local_bound(&out), f64::INFINITY);
    assert!(map.try_local_bound(&out).is_err());

    // The scenario's m_c resolves from the map; a changed network makes the map stale.
    let mut s = f.s.clone();
    s.reach.m_c = Margin::Certified;
    assert_eq!(resolve_margin(&s, &net_path).unwrap(), global);
    s.reach.m_c = Margin::Measured;
    assert_eq!(resolve_margin(&s, &net_path).unwrap(), f.measured.linf);
    s.reach.m_c = Margin::Local;
    assert_eq!(resolve_margin(&s, &net_path).unwrap(), map.finite_max());
    assert!(map.finite_max() <= global);
    let mut other = f.net.clone();
    other.layers[0].bias[0] += 1.0;
    other
        .save_safetensors(&net_path, &Default::default())
        .unwrap();
    let err = resolve_margin(&s, &net_path).unwrap_err().to_string();
    assert!(err.contains("another version"), "{err}");
}

#[test]
fn live_neurons_are_those_active_at_some_measured_point() {
    let f = fixture();
    let (points, _) = measurement_points(&f.s, &ErrorSettings::default());
    let points: Vec<Vec<f64>> = points.into_iter().filter(|x| f.s.is_safe(x)).collect();
    assert_eq!(f.measured.infeasible, 0, "every safe point is measured");
    let mut fires = [[false; 16]; 2];
    for x in &points {
        for (k, z) in f.net.pre_activations(x).iter().enumerate() {
            for (j, &z) in z.iter().enumerate() {
                fires[k][j] |= z > 0.0;
            }
        }
    }
    let live: Vec<usize> = fires
        .iter()
        .map(|l| l.iter().filter(|&&b| b).count())
        .collect();
    assert_eq!(f.measured.live_neurons, live);
}

/// The box-scale slope error, recomputed point by point from `N` and `v` at the secants' ends:
/// fails if the secants' ends, their step, the samples kept or the reduction differ.
#[test]
fn box_slope_error_is_the_secant_error_of_n_minus_v() {
    let f = fixture();
    let settings = ErrorSettings::default();
    let delta = settings.looseness_width / 2.0;
    assert_eq!(f.measured.box_width, settings.looseness_width);
    let filter = SafetyFilter::new(&f.s);
    let mut expected = Vec::new();
    for x in measurement_points(&f.s, &settings).0 {
        if !f.s.is_safe(&x) || filter.eval(&x).is_err() {
            continue;
        }
        let mut worst = 0.0_f64;
        let mut feasible = true;
        for j in 0..2 {
            let (mut plus, mut minus) = (x.clone(), x.clone());
            plus[j] += delta;
            minus[j] -= delta;
            let (Ok(vp), Ok(vm)) = (filter.eval(&plus), filter.eval(&minus)) else {
                feasible = false;
                break;
            };
            let (np, nm) = (f.net.forward(&plus), f.net.forward(&minus));
            for i in 0..2 {
                let secant = ((np[i] - vp[i]) - (nm[i] - vm[i])) / (2.0 * delta);
                worst = worst.max(secant.abs());
            }
        }
        if feasible {
            expected.push(worst);
        }
    }
    assert!(expected.len() > 1000, "{} samples", expected.len());
    let want = Percentiles::of(&expected);
    let got = f.measured.box_slope;
    for (a, b) in [
        (got.median, want.median),
        (got.p95, want.p95),
        (got.max, want.max),
    ] {
        assert!((a - b).abs() <= 1e-9 * b.max(1.0), "{got:?} vs {want:?}");
    }
}

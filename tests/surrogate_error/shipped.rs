//! The shipped networks and their error maps, checked against their figures and files.

use super::*;

#[test]
fn shipped_networks_have_the_paper_architectures_and_their_error_maps() {
    for (file, widths) in [
        ("integrator.safetensors", vec![2, 400, 400, 400, 2]),
        ("double-integrator.safetensors", vec![2, 500, 500, 500, 1]),
        (
            "double-integrator-without-ibp.safetensors",
            vec![2, 500, 500, 500, 1],
        ),
    ] {
        let path = common::scenario_path(file);
        let net = Mlp::load_safetensors(&path).unwrap();
        assert_eq!(net.widths(), widths, "{file}");
        let size = std::fs::metadata(&path).unwrap().len();
        assert!(size < 3_000_000, "{file}: {size} bytes");
        // The error map beside it was computed for this very file.
        let map = ErrorMap::load_for(&path).unwrap();
        assert!(map.measured_linf > 0.0);
        let certified = map.certified_linf.expect("closed-form filters");
        assert!(
            certified >= map.measured_linf,
            "{file}: certified below measured"
        );
        let local = map.local_bound(&IntervalBox::new(vec![-0.2, -0.2], vec![0.2, 0.2]).unwrap());
        assert!(local <= certified);
    }
    // Scenario 1's network meets the paper's accuracy on the error map's measurement grid
    // (4× the training grid's points): max ℓ∞ ≤ 0.19 and max ℓ2 ≤ 0.2; and its certified
    // bound over all of C ∩ S is below the paper's sampled 0.19 too.
    let map = ErrorMap::load_for(&common::scenario_path("integrator.safetensors")).unwrap();
    assert!(map.measured_linf <= 0.19, "{}", map.measured_linf);
    assert!(map.measured_l2 <= 0.2, "{}", map.measured_l2);
    assert!(map.certified_linf.unwrap() <= 0.19);
    // Scenario 2's `v` jumps at (1, 0) and (3, 0), where every continuous network errs by at
    // least 1 (README, Limitations), so no finite global bound exists; farther than 0.3 from
    // the jumps (cell centres) its certified cells are within the paper's sampled 0.26 (0.223;
    // 0.46 for the network shipped before).
    let map = ErrorMap::load_for(&common::scenario_path("double-integrator.safetensors")).unwrap();
    let from_jumps = |c: &CellBound| {
        let centre = [0, 1].map(|i| 0.5 * (c.lower[i] + c.upper[i]));
        [1.0, 3.0]
            .map(|x1: f64| (centre[0] - x1).hypot(centre[1]))
            .into_iter()
            .fold(f64::INFINITY, f64::min)
    };
    let far: Vec<f64> = map
        .cells
        .iter()
        .filter(|c| from_jumps(c) > 0.3)
        .map(|c| c.bound)
        .collect();
    assert!(far.len() > 30_000, "{} cells", far.len());
    let worst = far.iter().copied().fold(0.0, f64::max);
    assert!(worst <= 0.26, "certified {worst} 0.3 from the jumps");
}

/// The README's figures for the shipped networks, measured as `cbfreach error` measures them
/// (the same grid, 4× the training grid's points, and the same slope error,
/// `max_ij |DN − Dv|_ij` at each point): the slope error's 95th percentile is below the
/// issue's 0.2 target, and the max errors are the ones the error maps record. Minutes of
/// network evaluations on 2 cores for files that change only when a network is retrained:
/// run it then, `cargo test --release --test surrogate_error -- --ignored`. (That the maps
/// belong to their networks and bound their errors is checked in the suite, below.)
#[test]
#[ignore = "minutes: run after retraining a shipped network (--ignored)"]
fn shipped_networks_meet_the_slope_target() {
    for (s, file) in [
        (common::integrator(), "integrator.safetensors"),
        (common::double_integrator(), "double-integrator.safetensors"),
    ] {
        let path = common::scenario_path(file);
        let net = Mlp::load_safetensors(&path).unwrap();
        let m = measure(&s, &net, &ErrorSettings::default(), &|_| {}).unwrap();
        assert!(m.samples > 300_000, "{file}: {} samples", m.samples);
        assert!(m.slope.p95 < 0.2, "{file}: slope p95 {}", m.slope.p95);
        let map = ErrorMap::load_for(&path).unwrap();
        assert!(
            (m.linf - map.measured_linf).abs() < 1e-9,
            "{file}: {} vs {}",
            m.linf,
            map.measured_linf
        );
        assert!(
            (m.l2 - map.measured_l2).abs() < 1e-9,
            "{file}: {} vs {}",
            m.l2,
            map.measured_l2
        );
    }
}

/// The shipped error maps are files made offline; this checks them against their networks
/// where it matters most, on grids far finer than `cbfreach error`'s (spacing 0.001–0.01):
/// scenario 1's peak right of the obstacle, whose maximum lies on C's edge between
/// measurement points; scenario 2's largest error farther than 0.3 from the jumps of `v`
/// (0.22 at (1.04, 0.30)) and its errors of about 1 beside the jump at (1, 0); and each
/// scenario's goal, where the local bounds are smallest. Every sampled error lies within the
/// map's bound at its point. Fails on a map certified for another network or too low anywhere
/// in these windows.
#[test]
fn shipped_error_maps_bound_the_sampled_error_where_it_peaks_and_at_the_goal() {
    let window = |lo: [f64; 2], hi: [f64; 2]| IntervalBox::new(lo.to_vec(), hi.to_vec()).unwrap();
    let goal = window([-0.5, -0.5], [0.5, 0.5]);
    let checks = [
        (
            common::integrator(),
            "integrator.safetensors",
            vec![
                (window([4.35, 0.8], [4.5, 1.05]), [151, 126], 0.1),
                (goal.clone(), [101, 101], 0.0),
            ],
        ),
        (
            common::double_integrator(),
            "double-integrator.safetensors",
            vec![
                (window([0.9, 0.25], [1.2, 0.4]), [151, 76], 0.15),
                (window([0.9, 0.002], [1.0, 0.05]), [101, 49], 0.5),
                (goal, [101, 101], 0.0),
            ],
        ),
    ];
    for (s, file, windows) in checks {
        let path = common::scenario_path(file);
        let net = Mlp::load_safetensors(&path).unwrap();
        let map = ErrorMap::load_for(&path).unwrap();
        for (region, counts, least_peak) in windows {
            let errors = errors_on_grid(&s, &net, &region, &counts);
            assert!(errors.len() > 3_000, "{file}: {} points", errors.len());
            let worst = errors.iter().map(|e| e.1).fold(0.0, f64::max);
            // The peak windows hold the network's largest errors (the test looks where a
            // bound that is too low would show).
            assert!(
                worst > least_peak,
                "{file}: largest error {worst} in {region:?}"
            );
            for (x, e) in &errors {
                let at = IntervalBox::new(x.clone(), x.clone()).unwrap();
                let bound = map.local_bound(&at);
                assert!(
                    *e <= bound,
                    "{file}: error {e} at {x:?} > its map's bound {bound}"
                );
            }
        }
    }
}

#[test]
fn f32_weights_save_exactly_or_are_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("n.safetensors");
    // The trainer works in f32, so its networks are exactly representable.
    let net = &fixture().net;
    net.save_safetensors_f32(&path, &Default::default())
        .unwrap();
    assert_eq!(&Mlp::load_safetensors(&path).unwrap(), net);
    let mut other = net.clone();
    other.layers[0].weight[0] = 0.1; // not an f32
    assert!(other
        .save_safetensors_f32(&path, &Default::default())
        .is_err());
}

/// Scenario 2's default network is IBP-trained (README, Networks), and is what certified
/// training promises: over the same 0.1-wide boxes across C ∩ S its IBP bounds are far tighter
/// than those of the network its training started from without the IBP term (median
/// looseness 3.2 against 274 on `cbfreach error`'s 252 boxes) and its CROWN bounds no looser.
/// Fails if the default is swapped for one trained without the IBP term.
#[test]
fn scenario_2s_default_network_is_ibp_trained_and_tight() {
    let s = common::double_integrator();
    let settings = ErrorSettings {
        looseness_boxes: 60,
        ..ErrorSettings::default()
    };
    let measure = |file: &str| {
        let net = Mlp::load_safetensors(&common::scenario_path(file)).unwrap();
        looseness(&s, &net, &settings).unwrap()
    };
    let (plain, ibp) = (
        measure("double-integrator-without-ibp.safetensors"),
        measure("double-integrator.safetensors"),
    );
    assert!(plain.boxes >= 40 && plain.boxes == ibp.boxes, "{plain:?}");
    assert!(
        ibp.ibp.median * 5.0 < plain.ibp.median,
        "IBP looseness {ibp:?} against {plain:?}"
    );
    assert!(
        ibp.crown.median <= plain.crown.median,
        "{ibp:?} against {plain:?}"
    );
    // Looseness is a ratio of a sound bound's width to a sampled range: never below 1.
    for l in [plain, ibp] {
        assert!(l.ibp.min >= 1.0 && l.crown.min >= 1.0, "{l:?}");
    }
}

//! Measurement points, looseness, refinement towards the goal and the filter's curvature.

use super::*;

/// Looseness at the widths the engine's sets reach: every bound holds every sampled output
/// (ratio ≥ 1 in every box), CROWN is no looser than IBP, and IBP loosens as boxes widen. A
/// width that is not positive is an error naming it, from both functions that use it.
#[test]
fn looseness_holds_at_any_box_width() {
    let f = fixture();
    let at = |w: f64| ErrorSettings {
        looseness_width: w,
        ..ErrorSettings::default()
    };
    let (narrow, wide) = (
        looseness(&f.s, &f.net, &at(0.1)).unwrap(),
        looseness(&f.s, &f.net, &at(0.4)).unwrap(),
    );
    for (l, w) in [(narrow, 0.1), (wide, 0.4)] {
        assert_eq!(l.width, w);
        assert!(l.boxes >= 20, "{l:?}");
        assert!(l.ibp.min >= 1.0 && l.crown.min >= 1.0, "{l:?}");
        assert!(l.crown.median <= l.ibp.median, "{l:?}");
    }
    assert!(wide.ibp.median > narrow.ibp.median, "{narrow:?} {wide:?}");
    for w in [0.0, -0.1, f64::NAN, f64::INFINITY] {
        let e = looseness(&f.s, &f.net, &at(w)).unwrap_err().to_string();
        assert!(e.contains("box width") && e.contains("> 0"), "{e}");
        let e = measure(&f.s, &f.net, &at(w), &|_| {})
            .unwrap_err()
            .to_string();
        assert!(e.contains("box width"), "{e}");
    }
}

/// The measured error is the max over the centred grid *and* the boundary of C (its four edges
/// at the grid's spacing, and its corners), built here independently: fails if the boundary is
/// left out (the centred grid stays half a spacing inside C, where errors can peak).
#[test]
fn measured_error_covers_the_boundary_of_c() {
    let f = fixture();
    let c = &f.s.reach.region;
    let counts = measurement_counts(&f.s, &ErrorSettings::default());
    let centred = |i: usize, j: usize| {
        let h = (c.upper[i] - c.lower[i]) / counts[i] as f64;
        c.lower[i] + (j as f64 + 0.5) * h
    };
    let mut points = centred_grid(c, &counts);
    for i in 0..2 {
        let other = 1 - i;
        for side in [c.lower[i], c.upper[i]] {
            for j in 0..counts[other] {
                let mut x = vec![0.0; 2];
                x[i] = side;
                x[other] = centred(other, j);
                points.push(x);
            }
        }
    }
    points.extend(c.corners());
    assert_eq!(f.measured.boundary_points, 2 * (counts[0] + counts[1]) + 4);
    let filter = SafetyFilter::new(&f.s);
    // ‖N − v‖∞ at the safe points where the filter is feasible.
    let errors = |points: &[Vec<f64>]| -> Vec<f64> {
        points
            .iter()
            .filter(|x| f.s.is_safe(x))
            .filter_map(|x| {
                let v = filter.eval(x).ok()?;
                let y = f.net.forward(x);
                Some((0..2).map(|o| (y[o] - v[o]).abs()).fold(0.0, f64::max))
            })
            .collect()
    };
    let all = errors(&points);
    assert_eq!(f.measured.samples, all.len());
    let max = all.iter().copied().fold(0.0, f64::max);
    assert!(
        (f.measured.linf - max).abs() <= 1e-12 * max,
        "{} vs {max}",
        f.measured.linf
    );
    // On this fixture the max lies on C's boundary: the centred grid alone measures less.
    let (interior, boundary) = points.split_at(points.len() - f.measured.boundary_points);
    let interior_max = errors(interior).into_iter().fold(0.0, f64::max);
    let boundary_max = errors(boundary).into_iter().fold(0.0, f64::max);
    assert!(interior_max < boundary_max, "{interior_max} {boundary_max}");
}

/// Every cell's target is capped at `local_ratio` times the global error it is given, whatever
/// the error sampled on the cell itself: given half the measured max, every cell whose bound
/// stays above the cap is refined until it cannot be (narrower than `min_cell`). Fails if a
/// cell whose own samples err more is left at its looser local target.
#[test]
fn cells_are_refined_towards_the_global_goal() {
    let f = fixture();
    let settings = ErrorSettings {
        budget: 20_000,
        max_cells: 20_000,
        min_cell: 1.0 / 16.0,
        local_ratio: 1.1,
        ..ErrorSettings::default()
    };
    let target = 0.5 * f.measured.linf;
    let c = certify(&f.s, &f.net, target, &settings, &|_, _| {})
        .unwrap()
        .unwrap();
    assert!(!c.budget_spent, "the budget suffices");
    let goal = (settings.local_ratio * target).max(settings.floor);
    let above: Vec<_> = c.cells.iter().filter(|cell| cell.bound > goal).collect();
    assert!(
        !above.is_empty(),
        "half the measured max is out of reach somewhere"
    );
    for cell in above {
        let width = (0..2)
            .map(|i| cell.upper[i] - cell.lower[i])
            .fold(0.0, f64::max);
        assert!(width < settings.min_cell, "{cell:?} above {goal}");
    }
}

/// `ẋ = u` on the interval `C = [lower, upper]` with nominal input `kappa` and one CBF `h`
/// (`α(s) = s`).
fn line(kappa: &str, h: &str, [lower, upper]: [f64; 2]) -> Scenario {
    common::from_text(&format!(
        r#"
name = "line"
[system]
states = ["x"]
inputs = ["u"]
f = ["0"]
g = [["1"]]
kappa = ["{kappa}"]
[[cbf]]
h = "{h}"
[training]
grid = [10]
[reach]
region = {{ lower = [{lower}], upper = [{upper}] }}
m_c = 0.1
dt = 0.05
horizon = 1.0
goal = {{ lower = [-0.1], upper = [0.1] }}
"#
    ))
    .unwrap()
}

/// In one dimension C's faces are its two ends, measured once each besides the grid.
#[test]
fn measurement_points_of_an_interval_add_its_two_ends_once() {
    let s = line("-x", "x + 2", [-1.0, 1.0]);
    let (points, grid) = measurement_points(&s, &ErrorSettings::default());
    assert_eq!(grid, 20, "twice the training grid");
    assert_eq!(points[grid..], [vec![-1.0], vec![1.0]]);
    assert!(points[..grid].iter().all(|x| x[0] > -1.0 && x[0] < 1.0));
}

/// The filter's curvature against its closed form: on the line with `κ = 1`, `h = 4 − x²`,
/// `α(s) = s`, the constraint `−2x + 4 − x² ≥ 0` binds for `x > √5 − 1`, where the filter
/// adds `−x/2 − 1 + 2/x` to `κ`: curvature `4/x³`. Where it does not bind, `v` is constant.
#[test]
fn filter_curvature_matches_the_closed_form() {
    let s = line("1", "4 - x^2", [-1.0, 1.9]);
    let filter = SafetyFilter::new(&s);
    for x in [1.3, 1.5, 1.8] {
        let want = 4.0 / (x * x * x);
        let got = filter.curvature(&[x]).unwrap();
        assert!((got - want).abs() < 1e-4 * want, "at {x}: {got} vs {want}");
    }
    for x in [-0.5, 0.0, 1.0] {
        assert_eq!(filter.curvature(&[x]).unwrap(), 0.0, "at {x}");
    }
}

/// The slope error by curvature, recomputed point by point from `DN`, `Dv` and the filter's
/// curvature at the measured points: fails if the slope errors and the points they belong to
/// are paired wrongly, or the bands are cut elsewhere.
#[test]
fn slope_error_by_curvature_pairs_each_point_with_its_own_curvature() {
    use cbfreach::surrogate_error::CURVATURE_POINTS;
    let f = fixture();
    let filter = SafetyFilter::new(&f.s);
    let mut pairs = Vec::new();
    let points = measurement_points(&f.s, &ErrorSettings::default()).0;
    assert!(points.len() < CURVATURE_POINTS, "every point is measured");
    for x in points.into_iter().filter(|x| f.s.is_safe(x)) {
        let (Ok(_), Ok(dv)) = (filter.eval(&x), filter.jacobian(&x)) else {
            continue;
        };
        let slope = max_abs_diff(&f.net.jacobian(&x), &dv);
        if let Ok(kappa) = filter.curvature(&x) {
            pairs.push((kappa, slope));
        }
    }
    pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
    let got = &f.measured.slope_by_curvature;
    assert_eq!(got.points, pairs.len());
    assert_eq!(got.bands.len(), 3);
    let count = pairs.len() as f64;
    let mut from = 0;
    for (band, to) in got.bands.iter().zip([0.5, 0.9, 1.0]) {
        let to = (to * count) as usize;
        let slopes: Vec<f64> = pairs[from..to].iter().map(|p| p.1).collect();
        let want = Percentiles::of(&slopes);
        assert!(
            (band.slope.p95 - want.p95).abs() <= 1e-9 && (band.slope.max - want.max).abs() <= 1e-9,
            "{band:?} vs {want:?}"
        );
        assert_eq!(band.curvature, [pairs[from].0, pairs[to - 1].0]);
        from = to;
    }
    // Where the filter bends most, a piecewise-linear network's slopes err most.
    assert!(
        got.bands[2].slope.median > got.bands[0].slope.median,
        "{got:?}"
    );
}

/// Twice the training grid per axis is `2ⁿ` times its points (64 times in six states, where one
/// `cbfreach error` took 18 GB): the measurement grid is capped at [`MAX_MEASUREMENT_POINTS`],
/// evenly on every axis, and an explicit grid beyond four times that is refused by name before
/// any point is evaluated. Every shipped scenario still measures twice its training grid.
#[test]
fn the_measurement_grid_is_capped_in_many_states() {
    for name in [
        "integrator",
        "double-integrator",
        "int3",
        "unicycle",
        "acc-si",
        "spheres3d",
    ] {
        let s = Scenario::load(&common::scenario_path(&format!("{name}.toml"))).unwrap();
        let doubled: Vec<usize> = s.training.grid.iter().map(|&k| 2 * k.max(2)).collect();
        assert_eq!(
            measurement_counts(&s, &ErrorSettings::default()),
            doubled,
            "{name}"
        );
    }
    let mut s = Scenario::load(&common::scenario_path("int3.toml")).unwrap();
    s.training.grid = vec![60, 60, 60];
    let counts = measurement_counts(&s, &ErrorSettings::default());
    let size = measurement_size(&counts);
    assert!(
        counts
            .iter()
            .all(|&k| k == counts[0] && (60..120).contains(&k)),
        "{counts:?}"
    );
    let (all, _) = measurement_points(&s, &ErrorSettings::default());
    assert_eq!(all.len() as f64, size);
    assert!(size <= MAX_MEASUREMENT_POINTS as f64 && size > 0.9 * MAX_MEASUREMENT_POINTS as f64);
    let huge = ErrorSettings {
        grid: Some(vec![200, 200, 200]),
        ..ErrorSettings::default()
    };
    let net = common::zero_network(&[3, 4, 3]);
    let e = measure(&s, &net, &huge, &|_| {}).unwrap_err().to_string();
    assert!(
        e.contains("measurement grid points") && e.contains("coarser"),
        "{e}"
    );
}

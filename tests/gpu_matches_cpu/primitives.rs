//! Rounding at its edges (point boxes, cancelling sums) and single WGSL primitives against their Rust mirrors (the closed-form filter, `turn_rate`, `exp`, `φ`, the fold of a face's pinned coordinates).

use super::*;

/// Point boxes with no error margin: the NN system's trajectory is one point per step, and only
/// the engines' rounding treatment separates it from the sets' edges. Both GPU engines' sets
/// must contain the f64 Euler trajectory. Near the origin, where a state's ulp is far below
/// the rounding of the network's sums, an f32 engine with neither its outward steps nor its
/// a-priori bounds on every sum's rounding fails this at the first step with the random
/// network (checked), though either alone covers that network's sums; with the cancelling
/// network (below) an engine without the a-priori bounds fails at the first step (checked).
#[test]
fn point_boxes_contain_the_nn_trajectory_despite_rounding() {
    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    let s = integrator();
    // Two centres near the origin, one far from it; none exact in f32.
    let init = boxes(
        &[
            [1e-3 / 3.0, -1e-3 / 7.0],
            [2e-4 / 9.0, 1e-4 / 11.0],
            [-2.9, 0.3],
        ],
        0.0,
    );
    for (name, net) in [
        ("random", small_network(&[2, 64, 64, 2], 4, 0.2)),
        ("cancelling", cancelling_network()),
    ] {
        let mut problem = ReachProblem::new(&s, net.clone(), 0.0)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 40;
        let trajectories = nn_trajectories(&s, &net, &init, problem.dt, problem.steps, 0.0);
        for gpu in &engines {
            for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
                let st = with_bounds(bounds, ReachMethod::Disturbance);
                let tubes = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
                let label = format!(
                    "point boxes, {name} network, {bounds} {:?}",
                    gpu.precision()
                );
                for t in &tubes {
                    assert!(t.valid(), "{label}: {:?}", t.note());
                }
                let checks = count_contained(&tubes, &trajectories, problem.dt, &label);
                assert!(checks >= 3 * 12 * 40, "{label}: {checks} checks");
            }
        }
    }
}

/// A 2×64×64×2 network whose second layer sums 64 terms of size ~30 that cancel in pairs to
/// ~0.1 each: its first layer's neurons come in pairs, the second of each 1.0033 times the
/// first, weighed +A and −A. The f32 sums then err by many ulps of their results, so the outward
/// steps alone do not cover them: only the a-priori bounds on every sum's rounding do (an f32
/// engine whose `err_bound` returns 0 fails here; checked).
fn cancelling_network() -> Mlp {
    let base = Mlp::random(&[2, 32, 64, 2], 9);
    let (l1, l2, l3) = (&base.layers[0], &base.layers[1], &base.layers[2]);
    let mut w1 = Vec::with_capacity(128);
    let mut b1 = Vec::with_capacity(64);
    for k in 0..32 {
        let row = &l1.weight[2 * k..2 * k + 2];
        for f in [1.0, 1.0 + 1.0 / 300.0] {
            w1.extend(row.iter().map(|w| f * w));
            b1.push(f * (0.5 + 0.1 * l1.bias[k]));
        }
    }
    let a = 64.0;
    let mut w2 = Vec::with_capacity(64 * 64);
    for i in 0..64 {
        for k in 0..32 {
            let c = a * l2.weight[i * 32 + k].signum();
            w2.extend([c, -c]);
        }
    }
    let layer = |weight: Vec<f64>, bias: Vec<f64>, n_in: usize, n_out: usize| Layer {
        weight,
        bias,
        n_in,
        n_out,
    };
    Mlp {
        layers: vec![
            layer(w1, b1, 2, 64),
            layer(w2, vec![0.5; 64], 64, 64),
            layer(
                l3.weight.iter().map(|w| 0.01 * w).collect(),
                vec![0.0; 2],
                64,
                2,
            ),
        ],
    }
}

/// The filter's closed form on the GPU (`ExactField::ClosedForm`, shaders/filter.wgsl): its own
/// field where it is provably one smooth function on the set (inactive, or one row binding),
/// the closed form's enclosures of `v` on each face elsewhere, each met with the network's
/// bounds. On scenario 1 (one row, `v = b·a/‖a‖²`: a box near the goal, two where the
/// obstacle's row binds, one that crosses the switch) and on scenario 2 in z coordinates (a
/// scalar input, two rows and the dominance between them, and the transform's slack), the GPU
/// in f64 takes the same piece or enclosure on every step as the CPU and agrees on the sets to
/// `F64_TOL`; in f32 its sets contain the CPU's (up to `F32_FACTOR`). Both kinds of step occur,
/// and the closed form makes the binding boxes' sets narrower than `v = 0` where inactive alone.
#[test]
fn closed_form_filter_matches_cpu() {
    let Some(gpu32) = gpu() else { return };
    let gpu64 = gpu_f64();
    let s1 = integrator();
    // A random network with an error bound that holds near the obstacle (|v| ≤ 6 there), so
    // that its bounds are sound and the closed form does the work.
    let mut p1 = ReachProblem::new(&s1, small_network(&[2, 16, 16, 2], 1, 0.05), 8.0)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p1.steps = 40;
    let init1 = boxes(&[[0.1, 0.1], [3.9, 0.0], [3.6, 0.5], [2.6, 1.4]], 0.03);
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let mut p2 = ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 6, 0.05), 8.0, t)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    p2.steps = 40;
    let init2 = boxes(&[[0.1, -0.1], [1.0, 1.5], [1.5, 1.5], [-2.5, 0.5]], 0.03);
    let closed = ReachSettings {
        exact: ExactField::ClosedForm,
        ..with_faces(BoundMethod::ForwardBackward)
    };
    let inactive = ReachSettings {
        exact: ExactField::Inactive,
        ..closed.clone()
    };
    for (problem, init, name) in [(&p1, &init1, "scenario 1"), (&p2, &init2, "scenario 2")] {
        let (c, g) = run_both_with(&gpu32, problem, init, &closed);
        let exact: usize = c.iter().map(|t| t.exact_steps).sum();
        let enclosed: usize = c.iter().map(|t| t.enclosed_steps).sum();
        assert!(
            exact > problem.steps && enclosed > 0,
            "{name}: {exact} exact, {enclosed} enclosed"
        );
        for (k, (a, b)) in c.iter().zip(&g).enumerate() {
            assert_eq!(
                a.valid(),
                b.valid(),
                "{name} box {k}: {:?} vs {:?}",
                a.note(),
                b.note()
            );
            for (sa, sb) in a.tube.iter().zip(&b.tube) {
                for i in 0..2 {
                    let scale = sa.set.lower[i].abs().max(sa.set.upper[i].abs()).max(1.0);
                    assert!(
                        sb.set.lower[i] <= sa.set.lower[i] + F32_FACTOR * scale
                            && sa.set.upper[i] <= sb.set.upper[i] + F32_FACTOR * scale,
                        "{name} f32 box {k} t = {}: gpu {:?} does not contain cpu {:?}",
                        sa.t,
                        sb.set,
                        sa.set
                    );
                }
            }
        }
        if let Some(gpu64) = &gpu64 {
            let (c, g) = run_both_with(gpu64, problem, init, &closed);
            for (k, (a, b)) in c.iter().zip(&g).enumerate() {
                assert_eq!(
                    (a.exact_steps, a.enclosed_steps),
                    (b.exact_steps, b.enclosed_steps),
                    "{name} box {k}: steps on a piece and enclosed"
                );
            }
            compare_within(&c, &g, &format!("{name}: closed form, f64"), F64_TOL);
            let (_, loose) = run_both_with(gpu64, problem, init, &inactive);
            // At the last time both recorded, some set is narrower.
            let tighter = g.iter().zip(&loose).any(|(a, b)| {
                let j = a.tube.len().min(b.tube.len());
                j > 1 && a.tube[j - 1].set.widths()[0] < 0.9 * b.tube[j - 1].set.widths()[0]
            });
            assert!(tighter, "{name}: the closed form tightened no set");
        }
    }
}

/// The f64 shaders' `turn_rate` (`shaders/turn.wgsl`: what a face of the Euler step grows by
/// where the step may turn its state around) against the CPU's `euler_turn` that it mirrors, on
/// the rates of a one-state `f̃ = a·x + d·x²` over boxes of several widths and steps: the slope
/// `∂f̃/∂x` over the box as the CPU evaluates it, given to both. Equal to 1e-13 relative (the
/// device steps each operation outward by 4 ulp, the CPU by 1), never below the CPU's, zero
/// where `1 + h·L ≥ 0` (but for the device's own rounding of `1 + h·L` near 0), and many of
/// them not zero.
#[test]
fn turn_rate_matches_the_cpus_euler_turn() {
    use cbfreach::expressions::parse;
    use cbfreach::intervals::Interval;
    use cbfreach::reach::embedding::{euler_turn, Dynamics};
    let Some(g) = gpu_f64() else { return };
    let names = vec!["x".to_string()];
    let (mut inputs, mut cpu) = (Vec::new(), Vec::new());
    for a in [-60.0, -30.0, -20.5, -1.0, 0.0, 5.0] {
        for d in [0.0, 3.0, -7.0] {
            let f = parse(&format!("{a}*x + {d}*x^2"), &names, &Default::default()).unwrap();
            let g1 = parse("1", &names, &Default::default()).unwrap();
            let dynamics = Dynamics::new(1, 1, vec![f], vec![vec![g1]]);
            for (lo, w) in [(-1.0, 0.0), (-1.0, 1e-3), (0.3, 0.5), (-1.3, 2.0)] {
                let hi = lo + w;
                for h in [0.01, 0.05, 0.1] {
                    let (mut dl, mut du) = (vec![0.0], vec![0.0]);
                    euler_turn(&dynamics, &[lo], &[hi], h, None, &mut dl, &mut du);
                    assert_eq!(dl[0], -du[0]);
                    let slope =
                        dynamics.f_tilde_jacobian[0][0].eval_interval(&[Interval::new(lo, hi)]);
                    let width = (Interval::point(hi) - Interval::point(lo)).upper;
                    inputs.push([slope.lower, slope.upper, width, h, h]);
                    cpu.push((du[0], width / h));
                }
            }
        }
    }
    let dev = cbfreach::gpu::probe::turn_rate_on_device(g.context(), &inputs).unwrap();
    assert_eq!(dev.len(), cpu.len());
    let mut turned = 0;
    for ((&d, &(c, scale)), input) in dev.iter().zip(&cpu).zip(&inputs) {
        assert!(d >= c, "{input:?}: device {d} below the CPU's {c}");
        // (Zero widths: both a few smallest normal numbers, from rounding 0 up.)
        assert!(
            d - c <= 1e-13 * c.max(scale) + 1e-300,
            "{input:?}: device {d}, CPU {c}"
        );
        turned += usize::from(c > 0.0);
    }
    assert!(turned >= 40, "only {turned} of {} inputs turn", cpu.len());
    eprintln!("turn_rate: {turned} of {} inputs turn", cpu.len());
}

/// The f64 shaders' `exp` enclosure (`shaders/real_f64.wgsl`) against its Rust mirror
/// (`gpu::exp64`) on 100,001 inputs over [−90, 90]: equal to 1e-15 relative (a driver may fuse
/// a multiply and an add; lavapipe gives 88,579 of them bit for bit), and both enclose libm's
/// `exp` one ulp outward.
#[test]
fn f64_exp_matches_its_rust_mirror() {
    use cbfreach::gpu::exp64;
    let Some(g) = gpu_f64() else { return };
    let xs: Vec<f64> = (0..=100_000)
        .map(|i| -90.0 + 180.0 * i as f64 / 100_000.0 + 1e-11 * (i % 13) as f64)
        .collect();
    let dev = exp64::on_device(g.context(), &xs).unwrap();
    let mut bitwise = 0;
    for (&x, &(lo, hi)) in xs.iter().zip(&dev) {
        let (rlo, rhi) = (exp64::exp_down(x), exp64::exp_up(x));
        bitwise += usize::from(lo == rlo && hi == rhi);
        let near = |a: f64, b: f64| (a - b).abs() <= 1e-15 * a.abs().max(b.abs());
        assert!(
            near(lo, rlo) && near(hi, rhi),
            "{x}: device [{lo}, {hi}], Rust [{rlo}, {rhi}]"
        );
        if x.abs() <= exp64::RANGE {
            let e = x.exp();
            assert!(
                lo <= e.next_down() && e.next_up() <= hi,
                "{x}: [{lo}, {hi}] vs {e}"
            );
            assert!((hi - lo) <= 2.5e-13 * e, "{x}: [{lo}, {hi}]");
        }
    }
    eprintln!("exp: {bitwise} of {} inputs bit for bit", xs.len());
}

/// The f64 shaders' `phi_up` (φ(z) = (eᶻ − 1)/z, the closeness radius's factor) against its Rust
/// mirror (equal to 1e-15; bit for bit where the device fuses nothing) and the CPU's
/// `phi_upper` (1e-14 on the series, |z| ≤ 1/2; 3e-13 past it, the width of `exp`'s
/// enclosures), above φ, over z ∈ [−90, 90] and through 0 on both sides down to 1e-15.
#[test]
fn f64_phi_matches_its_rust_mirror_and_the_cpu() {
    use cbfreach::gpu::exp64;
    use cbfreach::reach::closeness::phi_upper;
    let Some(g) = gpu_f64() else { return };
    let mut zs: Vec<f64> = (0..=20_000)
        .map(|i| -90.0 + 180.0 * i as f64 / 20_000.0 + 1e-11 * (i % 13) as f64)
        .collect();
    zs.extend((0..300).flat_map(|e| [1e-15 * 1.13_f64.powi(e), -1e-15 * 1.13_f64.powi(e)]));
    zs.extend([0.0, 0.5, -0.5, 0.5_f64.next_up(), (-0.5_f64).next_down()]);
    let dev = exp64::phi_on_device(g.context(), &zs).unwrap();
    let mut bitwise = 0;
    for (&z, &d) in zs.iter().zip(&dev) {
        let (mirror, cpu) = (exp64::phi_up(z), phi_upper(z));
        bitwise += usize::from(d == mirror);
        assert!(
            (d - mirror).abs() <= 1e-15 * mirror,
            "{z}: device {d}, Rust {mirror}"
        );
        if z.abs() <= exp64::RANGE {
            let exact = if z == 0.0 { 1.0 } else { z.exp_m1() / z };
            assert!(d >= exact * (1.0 - 1e-15), "{z}: {d} < {exact}");
            let tol = if z.abs() <= 0.5 { 1e-14 } else { 3e-13 };
            assert!((d - cpu).abs() <= tol * cpu, "{z}: device {d}, CPU {cpu}");
        }
    }
    eprintln!("phi: {bitwise} of {} inputs bit for bit", zs.len());
}

/// `shaders/fold.wgsl` (a face's pinned coordinates folded into the first layer's constant)
/// against the CPU's fold, whose bound `bounds::FoldBound` is tested against double-double: on
/// 3 × 300 random boxes of 1–3 inputs with random coordinates pinned (a face pins one, a whole
/// box none), the device's folded constant is the CPU's sum, in the same order; its `ε` is at
/// least `FoldBound::error` at the device's scale and within 1e-14 of it (the device's
/// underflow unit is 0 here); its carry is `rowsum(|W₂|)·ε` rounded up; a whole box folds and
/// carries nothing (its carry was `up(0)`, one `MIN_NORMAL` that widened `R̂` by an ulp).
#[test]
fn the_devices_fold_matches_the_cpus() {
    use cbfreach::bounds::FoldBound;
    use cbfreach::gpu::probe::fold_on_device;
    use rand::{Rng, SeedableRng};
    use rand_chacha::ChaCha8Rng;
    let Some(g) = gpu_f64() else { return };
    let (mut pinned_boxes, mut whole) = (0, 0);
    for n0 in 1..=3usize {
        let net = Mlp::random(&[n0, 24, 16, 1], 40 + n0 as u64);
        let mut rng = ChaCha8Rng::seed_from_u64(90 + n0 as u64);
        let boxes: Vec<(Vec<f64>, Vec<f64>)> = (0..300)
            .map(|_| {
                let lo: Vec<f64> = (0..n0).map(|_| rng.random_range(-3.0..3.0)).collect();
                let hi = lo
                    .iter()
                    .map(|&l| match rng.random_range(0..3) {
                        0 => l,
                        _ => l + rng.random_range(0.0..0.5),
                    })
                    .collect();
                (lo, hi)
            })
            .collect();
        let dev = fold_on_device(g.context(), &net, &boxes).unwrap();
        let (first, second) = (&net.layers[0], &net.layers[1]);
        let fold = FoldBound::new(first);
        for (k, ((lo, hi), d)) in boxes.iter().zip(&dev).enumerate() {
            let pinned: Vec<usize> = (0..n0).filter(|&p| lo[p] == hi[p]).collect();
            let j = k % first.n_out;
            let w = &first.weight[j * n0..(j + 1) * n0];
            let constant = pinned.iter().fold(first.bias[j], |s, &p| s + w[p] * lo[p]);
            assert_eq!(d.constant, constant, "n0 = {n0}, box {k}: folded constant");
            let eps = fold.error(lo, hi, d.scale);
            if pinned.is_empty() {
                whole += 1;
                assert_eq!((d.eps, d.carry), (0.0, 0.0), "n0 = {n0}, box {k}: whole");
                continue;
            }
            pinned_boxes += 1;
            // The prelude's `up` steps by 4u relative where the CPU's `round_up` steps by an
            // ulp: the device's bound is the larger, by a few of those steps.
            assert!(
                d.eps >= eps && d.eps <= eps * (1.0 + 1e-14),
                "n0 = {n0}, box {k}: device ε {} against {eps}",
                d.eps
            );
            let i = k % second.n_out;
            let rowsum: f64 = second.weight[i * 24..(i + 1) * 24]
                .iter()
                .map(|w| w.abs())
                .sum();
            let carry = rowsum * d.eps;
            assert!(
                d.carry >= carry && d.carry <= carry * (1.0 + 1e-13),
                "n0 = {n0}, box {k}: carry {} against {carry}",
                d.carry
            );
        }
    }
    assert!(
        pinned_boxes > 300 && whole > 50,
        "{pinned_boxes} pinned, {whole} whole"
    );
}

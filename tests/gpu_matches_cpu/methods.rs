//! Every bound method and relaxation on small and paper-size networks, in f64 and f32; batches split into chunks; transcendental dynamics.

use super::*;

#[test]
fn scenario_1_small_network_matches_cpu() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 16, 16, 2], 1, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 60;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [-3.0, 0.0], [3.5, 2.0]], 0.1);
    for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
        let (c, g) = run_both(&gpu, &problem, &init, method);
        compare(&c, &g, &format!("scenario 1 {method:?}"));
    }
}

/// One engine reuses its compiled pipelines while the problem's generated WGSL is unchanged and
/// compiles anew when it changes: a stale pipeline (the previous `M_C`, baked into the WGSL)
/// would make the second problem's sets differ from the CPU's, and a repeat must give the same
/// sets bit for bit.
#[test]
fn pipelines_are_reused_only_for_the_same_problem() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0]], 0.1);
    let mut runs = Vec::new();
    for m_c in [0.05, 0.2, 0.05] {
        let net = small_network(&[2, 16, 16, 2], 1, 0.05);
        let mut problem = ReachProblem::new(&s, net, m_c)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 30;
        let (c, g) = run_both(&gpu, &problem, &init, ReachMethod::Disturbance);
        compare(&c, &g, &format!("M_C = {m_c}"));
        runs.push(g);
    }
    let widest = |tubes: &[Tube]| tubes[0].tube.last().unwrap().set.widths()[0];
    assert!(widest(&runs[1]) > widest(&runs[0]) + 0.1);
    for (a, b) in runs[0].iter().zip(&runs[2]) {
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            assert_eq!(sa.set, sb.set);
        }
    }
}

/// The GEMM kernel is where, not what: the flat kernel, the 64 × 64 tiles and the wide tiles
/// give the engine the same sets bit for bit (forward products and the backward pass's
/// transposed ones, f32 and f64), as `bench --gemm` promises; a layer wider than a wide tile's
/// 64 rows and the boxes' columns off its 256 check the edges.
#[test]
fn gemm_kernels_give_the_same_sets() {
    let s = integrator();
    let net = small_network(&[2, 70, 20, 2], 3, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 20;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [-3.0, 0.0]], 0.1);
    let settings = with_bounds(BoundMethod::ForwardBackward, ReachMethod::Disturbance);
    for engine in [gpu(), gpu_f64()] {
        let Some(mut engine) = engine else { continue };
        let mut runs = Vec::new();
        for gemm in [Gemm::Flat, Gemm::Tiles, Gemm::Wide] {
            engine.gemm = gemm;
            let tubes = engine
                .reach(&problem, &init, &settings, &|_, _| {})
                .unwrap();
            runs.push((gemm, tubes.boxes));
        }
        let (_, flat) = &runs[0];
        for (gemm, tubes) in &runs[1..] {
            for (a, b) in flat.iter().zip(tubes) {
                assert_eq!(a.tube.len(), b.tube.len(), "{gemm:?}");
                for (sa, sb) in a.tube.iter().zip(&b.tube) {
                    assert_eq!(sa.set, sb.set, "{gemm:?} at t = {}", sa.t);
                }
            }
        }
    }
}

#[test]
fn scenario_2_small_network_matches_cpu_with_and_without_transform() {
    let Some(gpu) = gpu() else { return };
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 2, 0.05);
    // The last box is driven into the velocity bound x₂ ≥ −2 (κ < 0 there), where the
    // disturbance method's sets are intersected with it: a constant bound in x, a computed one
    // in z with the transform (src/reach/safe_set.rs, shaders/embed.wgsl).
    let init = boxes(&[[-1.0, 0.5], [3.0, -1.0], [0.5, 1.0], [5.0, -1.85]], 0.05);
    for transform in [
        None,
        Transform::for_scenario(&s, &TransformChoice::Auto).unwrap(),
    ] {
        let with = transform.is_some();
        let mut problem = ReachProblem::with_transform(&s, net.clone(), 0.02, transform)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 60;
        for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
            let (c, g) = run_both(&gpu, &problem, &init, method);
            compare(&c, &g, &format!("scenario 2 transform {with} {method:?}"));
            let at_edge = |t: &Tube| t.tube.iter().any(|x| x.set.lower[1] == -2.0);
            if method == ReachMethod::Disturbance {
                assert!(at_edge(&c[3]) && at_edge(&g[3]), "transform {with}");
            } else {
                assert!(
                    !c[3].valid() && !g[3].valid(),
                    "transform {with}: {:?}",
                    c[3].note()
                );
            }
        }
    }
}

#[test]
fn paper_size_network_end_to_end() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 400, 400, 400, 2], 3, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.1)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 5;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.0, 1.5]], 0.02);
    for bounds in [BoundMethod::Forward, BoundMethod::ForwardBackward] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        // f32's rigorous rounding bound grows with Σ|W||a| over 400-wide layers: the GPU's sets
        // are wider than the CPU's f64 ones by more than REL_TOL here. Check that they contain
        // the CPU's (up to REL_TOL) and measure the excess.
        let mut excess = 0.0f64;
        for (k, (a, b)) in c.iter().zip(&g).enumerate() {
            assert_eq!(a.valid(), b.valid());
            for (sa, sb) in a.tube.iter().zip(&b.tube) {
                for i in 0..2 {
                    let scale = sa.set.lower[i].abs().max(sa.set.upper[i].abs()).max(1.0);
                    assert!(
                        sb.set.lower[i] <= sa.set.lower[i] + REL_TOL * scale
                            && sa.set.upper[i] <= sb.set.upper[i] + REL_TOL * scale,
                        "{bounds} box {k} t = {}: gpu {:?} does not contain cpu {:?}",
                        sa.t,
                        sb.set,
                        sa.set
                    );
                    let (wa, wb) = (
                        sa.set.upper[i] - sa.set.lower[i],
                        sb.set.upper[i] - sb.set.lower[i],
                    );
                    excess = excess.max((wb - wa) / scale);
                }
            }
        }
        eprintln!(
            "2×400×400×400×2 {bounds}: the GPU's f32 sets are wider by up to {excess:.2e} \
             (relative)"
        );
        assert!(excess < 0.05, "{bounds}: f32 widening too large: {excess}");
    }
}

/// NN-system trajectories (same Euler step) lie in the GPU's boxes, for every bound method the
/// GPU runs, in f32 and f64.
#[test]
fn gpu_sets_contain_nn_trajectories() {
    let Some(gpu32) = gpu() else { return };
    let mut engines = vec![gpu32];
    engines.extend(gpu_f64());
    for (s, net) in [
        (integrator(), small_network(&[2, 16, 16, 2], 4, 0.2)),
        (double_integrator(), small_network(&[2, 16, 16, 1], 5, 0.2)),
    ] {
        let mut problem = ReachProblem::new(&s, net.clone(), 0.0)
            .unwrap()
            .with_time(TimeModel::Euler, 1);
        problem.steps = 60;
        let init = boxes(&[[-2.0, 1.0], [1.0, -1.0], [-3.0, 0.0]], 0.1);
        let trajectories = nn_trajectories(&s, &net, &init, problem.dt, problem.steps, 0.0);
        for gpu in &engines {
            for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
                let st = with_bounds(bounds, ReachMethod::Disturbance);
                let tubes = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
                let label = format!("{} {bounds} {:?}", s.file, gpu.precision());
                let checks = count_contained(&tubes, &trajectories, problem.dt, &label);
                assert!(checks > 1000, "{bounds}: too few checks: {checks}");
            }
        }
    }
}

/// 65,536 boxes run (split into chunks when the limits ask for it, and when forced to).
#[test]
fn batch_of_65536_boxes_runs_and_splits() {
    let Some(mut gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 32, 32, 2], 6, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 3;
    let n = 65_536;
    let centres: Vec<[f64; 2]> = (0..n)
        .map(|k| {
            let (i, j) = ((k % 256) as f64, (k / 256) as f64);
            [-3.0 + 7.0 * i / 255.0, -2.5 + 5.0 * j / 255.0]
        })
        .collect();
    let init = boxes(&centres, 0.01);
    let st = settings(ReachMethod::Disturbance);
    for max_chunk in [None, Some(20_000)] {
        gpu.max_chunk = max_chunk;
        eprintln!("chunk size {}", gpu.chunk_size(&problem, &st, n));
        let t = std::time::Instant::now();
        let g = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        eprintln!(
            "{n} boxes × 3 steps on the GPU in {:.2} s ({:.0} box-steps/s)",
            t.elapsed().as_secs_f64(),
            3.0 * n as f64 / t.elapsed().as_secs_f64()
        );
        assert_eq!(g.boxes.len(), n);
        let picks: Vec<usize> = vec![0, 1, 19_999, 20_000, 40_001, n - 1];
        let sub: Vec<IntervalBox> = picks.iter().map(|&k| init[k].clone()).collect();
        let c = CpuBackend.reach(&problem, &sub, &st, &|_, _| {}).unwrap();
        let gsub: Vec<Tube> = picks.iter().map(|&k| g.boxes[k].clone()).collect();
        compare(&c.boxes, &gsub, "65,536 boxes");
    }
}

/// Forward-backward and crown (both relaxations) on the GPU in f64 agree with the CPU to
/// `REL_TOL`, on both paper scenarios (with the transform and the Minkowski method once).
#[test]
fn backward_methods_match_cpu_in_f64() {
    let Some(gpu) = gpu_f64() else { return };
    let [(p1, init1), (p2, init2)] = paper_problems(40);
    let mut worst = Vec::new();
    for bounds in [BoundMethod::Forward].into_iter().chain(BACKWARD_METHODS) {
        let mut w = 0.0f64;
        for (problem, init, method) in [
            (&p1, &init1, ReachMethod::Disturbance),
            (&p2, &init2, ReachMethod::Disturbance),
            (&p1, &init1, ReachMethod::Minkowski),
        ] {
            let st = with_bounds(bounds, method);
            let (c, g) = run_both_with(&gpu, problem, init, &st);
            w = w.max(compare(&c, &g, &format!("f64 {bounds} {method:?}")));
        }
        worst.push((bounds, w));
    }
    eprintln!("f64 GPU vs CPU, worst relative difference per method: {worst:?}");
}

/// In f32 the same runs stay within `F32_FACTOR` of the CPU's f64 sets.
#[test]
fn backward_methods_close_to_cpu_in_f32() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 40;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.5, 2.0]], 0.1);
    let mut worst = Vec::new();
    for bounds in BACKWARD_METHODS {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        let w = compare_within(&c, &g, &format!("f32 {bounds}"), F32_FACTOR);
        worst.push((bounds, w));
    }
    eprintln!("f32 GPU vs CPU, worst relative difference per method: {worst:?}");
}

/// The shipped 2×400×400×400×2 network of scenario 1, forward-backward on the GPU in f64:
/// end to end, agreeing with the CPU to `REL_TOL` (and crown-same-slope for one step).
#[test]
fn paper_network_forward_backward_f64_matches_cpu() {
    let Some(gpu) = gpu_f64() else { return };
    let s = integrator();
    let path = common::scenario_path("integrator.safetensors");
    let net = Mlp::load_safetensors(&path).unwrap();
    assert_eq!(net.widths(), vec![2, 400, 400, 400, 2]);
    let mut problem = ReachProblem::new(&s, net, 0.19)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 4;
    let init = boxes(&[[-2.0, 2.0], [1.0, -2.0], [3.0, 1.5]], 0.05);
    for bounds in [
        BoundMethod::ForwardBackward,
        BoundMethod::ForwardBackwardSameSlope,
    ] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let (c, g) = run_both_with(&gpu, &problem, &init, &st);
        compare(&c, &g, &format!("2×400³×2 f64 {bounds}"));
    }
    problem.steps = 1;
    let st = with_bounds(BoundMethod::CrownSameSlope, ReachMethod::Disturbance);
    let (c, g) = run_both_with(&gpu, &problem, &init[..1], &st);
    compare(&c, &g, "2×400³×2 f64 crown-same-slope");
}

/// Nonlinear dynamics with every transcendental built-in: f64 (sin, cos as polynomials, exp,
/// ln, sqrt in f32 widened by the WGSL accuracy) agrees with the CPU to `REL_TOL`; f32 within
/// `F32_TRIG`, as WGSL promises sin and cos only to 2⁻¹¹ absolute.
#[test]
fn transcendental_dynamics_match_cpu() {
    let Some(gpu32) = gpu() else { return };
    let text = common::SMALL.replace(
        r#"f = ["y", "-x"]"#,
        r#"f = ["y + 0.1*tanh(x) - 0.05*sqrt(1 + x^2)", "-sin(x) + 0.1*cos(y) + 0.05*exp(-x*x) - 0.02*ln(2 + y)"]"#,
    );
    assert_ne!(text, common::SMALL);
    let s = common::from_text(&text).unwrap();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 8, 8, 1], 9, 0.1), 0.02)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 15;
    let init = boxes(&[[-0.3, 0.2], [0.4, -0.1]], 0.05);
    for bounds in [BoundMethod::Forward, BoundMethod::ForwardBackward] {
        for method in [ReachMethod::Disturbance, ReachMethod::Minkowski] {
            let st = with_bounds(bounds, method);
            let (c, g) = run_both_with(&gpu32, &problem, &init, &st);
            compare_within(&c, &g, &format!("f32 {bounds} {method:?}"), F32_TRIG);
            if let Some(gpu64) = gpu_f64() {
                let (c, g) = run_both_with(&gpu64, &problem, &init, &st);
                compare(&c, &g, &format!("f64 {bounds} {method:?}"));
            }
        }
    }
    // The NN system's trajectories (M = 0) stay in the f32 sets.
    problem.m_c = 0.0;
    let st = with_bounds(BoundMethod::ForwardBackward, ReachMethod::Disturbance);
    let tubes = gpu32.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
    let mut checks = 0;
    for tube in &tubes {
        for x0 in sample_box(&tube.initial, 16, 3) {
            let traj = integrate(
                |x: &[f64]| Ok::<_, String>(nn_field(&s, &problem.network, x)),
                &x0,
                problem.dt,
                problem.steps,
                Integrator::Euler,
            );
            for sample in &tube.tube {
                let x = &traj.x[(sample.t / problem.dt).round() as usize];
                for i in 0..2 {
                    assert!(sample.set.lower[i] <= x[i] && x[i] <= sample.set.upper[i]);
                }
                checks += 1;
            }
        }
    }
    assert!(checks > 300, "too few checks: {checks}");
}

/// Forward-backward and crown batches split into chunks give the same tubes as one chunk (the
/// Λ, β, record buffers are shared by the chunks), with or without the profile runs.
#[test]
fn backward_methods_split_into_chunks() {
    let Some(mut gpu) = gpu_f64() else { return };
    let s = integrator();
    let mut problem = ReachProblem::new(&s, small_network(&[2, 24, 24, 2], 6, 0.05), 0.05)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    problem.steps = 3;
    let centres: Vec<[f64; 2]> = (0..300)
        .map(|k| {
            let (i, j) = ((k % 20) as f64, (k / 20) as f64);
            [-3.0 + 7.0 * i / 19.0, -2.5 + 5.0 * j / 14.0]
        })
        .collect();
    let init = boxes(&centres, 0.02);
    for bounds in [BoundMethod::ForwardBackward, BoundMethod::Crown] {
        let st = with_bounds(bounds, ReachMethod::Disturbance);
        let whole = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        gpu.max_chunk = Some(128);
        assert_eq!(gpu.chunk_size(&problem, &st, init.len()), 128);
        let split = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        // `bench --profile` re-runs each chunk's dispatches over its buffers after the
        // readback: neither that chunk's results nor the next chunk may see any of it.
        gpu.profile = true;
        let profiled = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap().boxes;
        gpu.profile = false;
        gpu.max_chunk = None;
        compare_within(&whole, &split, &format!("{bounds} split"), 1e-12);
        compare_within(&split, &profiled, &format!("{bounds} profiled"), 0.0);
        let picks = [0usize, 127, 128, 255, 256, 299];
        let sub: Vec<IntervalBox> = picks.iter().map(|&k| init[k].clone()).collect();
        let c = CpuBackend.reach(&problem, &sub, &st, &|_, _| {}).unwrap();
        let gsub: Vec<Tube> = picks.iter().map(|&k| split[k].clone()).collect();
        compare(&c.boxes, &gsub, &format!("{bounds} split vs cpu"));
    }
}

/// Box-steps per second, CPU and GPU side by side (forward bounds, scenario 1, 2×400³×2).
/// `cargo test --release --test gpu_matches_cpu -- --ignored --nocapture`
#[test]
#[ignore]
fn bench_box_steps_per_second() {
    let Some(gpu) = gpu() else { return };
    let s = integrator();
    let net = small_network(&[2, 400, 400, 400, 2], 7, 0.05);
    let mut problem = ReachProblem::new(&s, net, 0.1)
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let widths = problem.network.widths();
    let pairs: f64 = widths.windows(2).map(|w| (w[0] * w[1]) as f64).sum();
    let flop = 2.0 * (2.0 * 3.0 + 1.0) * pairs;
    for (n_boxes, steps) in [(64usize, 10usize), (1024, 5), (4096, 3)] {
        problem.steps = steps;
        let centres: Vec<[f64; 2]> = (0..n_boxes)
            .map(|k| {
                [
                    -3.0 + 6.0 * (k % 64) as f64 / 63.0,
                    -2.0 + 4.0 * (k / 64) as f64 / 64.0,
                ]
            })
            .collect();
        let init = boxes(&centres, 0.01);
        let st = settings(ReachMethod::Disturbance);
        let bs = (n_boxes * steps) as f64;
        let c = CpuBackend.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        let g = gpu.reach(&problem, &init, &st, &|_, _| {}).unwrap();
        let (tc, tg) = (c.timing.reach_s, g.timing.reach_s);
        eprintln!(
            "2x400x400x400x2 forward, {n_boxes} boxes × {steps} steps: cpu {:.0} box-steps/s \
             ({:.2} GFLOP/s), gpu [{}] {:.0} box-steps/s ({:.2} GFLOP/s)",
            bs / tc,
            bs / tc * flop / 1e9,
            gpu.context().info.name,
            bs / tg,
            bs / tg * flop / 1e9
        );
    }
}

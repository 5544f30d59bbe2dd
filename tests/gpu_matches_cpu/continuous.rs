//! `reach` in continuous time on the GPU engine against the CPU engine (docs/design.md §7.4):
//! the device takes the common path's box-steps, the host the rest with the CPU engine's own
//! step. Same verdicts, sets and flowpipes equal to 1e-10 relative in f64, and every set and
//! flowpipe holds RK4 trajectories of the system it bounds.

use super::*;
use cbfreach::filter::SafetyFilter;
use cbfreach::problem::ProblemOptions;
use cbfreach::scenario::Margin;
use cbfreach::simulate::simulate_filtered;

/// Sets and flowpipes agree to this, relative to `max(1, |x|)` (f64; the device rounds each
/// operation outward by 4 ulp, the CPU by 1), with small networks; with the shipped 400-wide
/// one the engines' network bounds themselves part more (the Euler map's sets too: the test
/// prints both), and the tolerance is [`SHIPPED_TOL`].
const TOL: f64 = 1e-10;

/// [`TOL`] for the shipped network: measured 2.7e-12 over 25 steps of scenario 1 (3.6e-9
/// before the CPU bounded sums with the device's `γ̂_N` and the f64 device stopped adding a
/// conversion error its exact weights do not have), and 1.3e-11 under the Euler map, whose
/// boxes that leave `C` grow several times wider (1.9e-9 before the device folded a face's
/// pinned coordinate into the first layer's constant as the CPU does).
pub(super) const SHIPPED_TOL: f64 = 1e-10;

/// Asserts that no state of `trajectories` ([`escapes`]) lies outside the GPU's sets or
/// flowpipes, and that at least 12 starts a box were checked over 10 samples.
pub(super) fn assert_no_escapes(
    dev: &[Tube],
    trajectories: &[Vec<Vec<Vec<f64>>>],
    dt: f64,
    boxes: usize,
    what: &str,
) {
    let (out, checks) = escapes(dev, trajectories, dt);
    assert_eq!(
        out, 0,
        "{what}: {out} of {checks} states outside the GPU's sets or flowpipes"
    );
    assert!(checks >= boxes * 12 * 10, "{what}: {checks} checks");
}

/// States outside their sample's set, or between samples outside its flowpipe, beyond 1e-9
/// (RK4's own error at `dt/10` is far below), of `trajectories[box][start]` sampled every
/// `dt/10`; and how many states were checked.
pub(super) fn escapes(
    tubes: &[Tube],
    trajectories: &[Vec<Vec<Vec<f64>>>],
    dt: f64,
) -> (usize, usize) {
    let outside = |b: &IntervalBox, x: &[f64]| {
        (0..b.dim()).any(|i| x[i] < b.lower[i] - 1e-9 || x[i] > b.upper[i] + 1e-9)
    };
    let (mut out, mut checks) = (0, 0);
    for (tube, paths) in tubes.iter().zip(trajectories) {
        for path in paths {
            for (k, s) in tube.tube.iter().enumerate() {
                let j = (s.t / dt).round() as usize * 10;
                // A trajectory the filter could not continue ends early.
                let Some(x) = path.get(j) else { break };
                checks += 1;
                out += usize::from(outside(&s.set, x));
                if let (Some(pipe), true) = (&s.flowpipe, k > 0) {
                    let j0 = (tube.tube[k - 1].t / dt).round() as usize * 10;
                    checks += j + 1 - j0;
                    out += path[j0..=j].iter().filter(|x| outside(pipe, x)).count();
                }
            }
        }
    }
    (out, checks)
}

/// The network in x of a problem (with a transform, `problem.network` takes z = T x: its first
/// layer absorbs `T⁻¹`).
fn x_network(problem: &ReachProblem) -> &Mlp {
    &problem.in_x.as_deref().unwrap_or(problem).network
}

/// RK4 at `dt/10` from 12 points of each box (its corners first) of the system the disturbance
/// method bounds, `ẋ = f̃(x) + g(x)(N(x) + d)`, with a constant `d = ±m` per input (its signs
/// fixed per trajectory).
fn nn_paths(
    s: &Scenario,
    net: &Mlp,
    init: &[IntervalBox],
    m: f64,
    dt: f64,
    steps: usize,
) -> Vec<Vec<Vec<Vec<f64>>>> {
    let (n, inputs) = (s.n(), s.m());
    init.iter()
        .map(|b| {
            sample_box(b, 12, 7)
                .into_iter()
                .enumerate()
                .map(|(k, x0)| {
                    let d: Vec<f64> = (0..inputs)
                        .map(|q| if (k >> q) % 2 == 0 { m } else { -m })
                        .collect();
                    let field = |x: &[f64]| {
                        let (f, g, u) = (s.f_tilde_at(x), s.g_at(x), net.forward(x));
                        let v = (0..n).map(|i| {
                            f[i] + (0..inputs)
                                .map(|q| g[i * inputs + q] * (u[q] + d[q]))
                                .sum::<f64>()
                        });
                        Ok::<_, String>(v.collect())
                    };
                    integrate(field, &x0, dt / 10.0, steps * 10, Integrator::Rk4).x
                })
                .collect()
        })
        .collect()
}

/// Largest relative difference of two runs' flowpipes (the samples' sets: [`compare_within`]);
/// fails above `tol` or where one has a flowpipe and the other not.
pub(super) fn compare_flowpipes(cpu: &[Tube], gpu: &[Tube], what: &str, tol: f64) -> f64 {
    let mut worst = 0.0_f64;
    for (k, (a, b)) in cpu.iter().zip(gpu).enumerate() {
        for (sa, sb) in a.tube.iter().zip(&b.tube) {
            match (&sa.flowpipe, &sb.flowpipe) {
                (Some(p), Some(q)) => {
                    let ends = p
                        .lower
                        .iter()
                        .zip(&q.lower)
                        .chain(p.upper.iter().zip(&q.upper));
                    for (x, y) in ends {
                        let rel = (x - y).abs() / x.abs().max(1.0);
                        worst = worst.max(rel);
                        assert!(
                            rel <= tol,
                            "{what} box {k} t = {}: flowpipe {p:?} vs {q:?}",
                            sa.t
                        );
                    }
                }
                (None, None) => {}
                _ => panic!(
                    "{what} box {k} t = {}: a flowpipe on one engine alone",
                    sa.t
                ),
            }
        }
    }
    worst
}

/// Both engines on `problem` under `s`: the GPU's sets hold `paths` where given (checked first,
/// so a wrong set fails here even where both engines agree), then the same verdicts, sample
/// times, sets, flowpipes, exact and enclosed steps as the CPU's (to `tol`); the device took
/// most of the box-steps. Returns the device's and the host's box-steps.
fn continuous_parity(
    g: &GpuBackend,
    problem: &ReachProblem,
    init: &[IntervalBox],
    (s, tol): (&ReachSettings, f64),
    paths: Option<&[Vec<Vec<Vec<f64>>>]>,
    what: &str,
) -> (usize, usize) {
    let before = g.continuous_steps();
    let (cpu, dev) = run_both_with(g, problem, init, s);
    let after = g.continuous_steps();
    let (on_device, on_host) = (after.0 - before.0, after.1 - before.1);
    if let Some(paths) = paths {
        assert_no_escapes(&dev, paths, problem.dt, init.len(), what);
    }
    let sets = compare_within(&cpu, &dev, what, tol);
    let exact = |t: &[Tube]| t.iter().map(|t| t.exact_steps).collect::<Vec<_>>();
    assert_eq!(exact(&cpu), exact(&dev), "{what}: exact steps");
    let enclosed = |t: &[Tube]| t.iter().map(|t| t.enclosed_steps).collect::<Vec<_>>();
    assert_eq!(enclosed(&cpu), enclosed(&dev), "{what}: enclosed steps");
    let pipes = compare_flowpipes(&cpu, &dev, what, tol);
    let valid = dev.iter().filter(|t| t.valid()).count();
    eprintln!(
        "{what}: {on_device} box-steps on the device, {on_host} on the host; {valid} of {} \
         valid; sets within {sets:.1e}, flowpipes {pipes:.1e}",
        dev.len()
    );
    assert!(
        on_device > on_host,
        "{what}: {on_device} on the device, {on_host} on the host"
    );
    (on_device, on_host)
}

/// Scenario 1 (x coordinates) and scenario 2 (z = Tx) with small networks in continuous time,
/// the network everywhere with a global `M`, forward bounds face-local and over the moving box's
/// hull and CROWN face-local, f64, 40 steps (scenario 1 also with 2 substeps a step): the GPU
/// engine's tubes are the CPU's (verdicts, sets, flowpipes) and hold the disturbed NN system's
/// RK4 trajectories.
#[test]
fn continuous_runs_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let steps = 40;
    let [(p1, _), (p2, b2)] = paper_problems(steps);
    let b1 = scenario_1_starts();
    let (s1, s2) = (integrator(), double_integrator());
    for (s, problem, init) in [(&s1, p1, b1), (&s2, p2, b2)] {
        let problem = problem.with_time(TimeModel::Continuous, 1);
        let paths = nn_paths(
            s,
            x_network(&problem),
            &init,
            problem.m_c,
            problem.dt,
            steps,
        );
        let cases = [
            (BoundMethod::Forward, true),
            (BoundMethod::Forward, false),
            (BoundMethod::Crown, true),
        ];
        for (bounds, face_local) in cases {
            let st = ReachSettings {
                face_local,
                ..with_bounds(bounds, ReachMethod::Disturbance)
            };
            let what = format!("{}, {bounds} bounds, face-local {face_local}", s.name);
            continuous_parity(&g, &problem, &init, (&st, TOL), Some(&paths), &what);
        }
        if s.name == "integrator" {
            // Validated substeps: the step h = dt/2 on the device and on the host, samples and
            // flowpipes (the hull of two steps') at every dt.
            let problem = problem.with_time(TimeModel::Continuous, 2);
            let st = with_faces(BoundMethod::Forward);
            let what = "integrator, substeps 2, forward bounds, face-local";
            continuous_parity(&g, &problem, &init, (&st, TOL), Some(&paths), what);
        }
    }
}

/// Scenario 2 with a small network in z = T x met with its x-box after every step (two frames,
/// `intersect_x`: the scenario's default, design §2.11), the network everywhere with a global
/// `M`, face-local forward bounds, 40 steps, boxes that pass over the obstacle and near the
/// goal: the device guesses both frames' moving boxes, meets their hulls, proves them on both
/// frames and meets the sets after the step (shaders/cmeet.wgsl); the GPU engine's tubes are
/// the CPU's (verdicts, sets, flowpipes to 1e-10 relative), most box-steps are the device's, and
/// its sets and flowpipes hold the disturbed NN system's RK4 trajectories; first without the
/// slabs clipped by the other frame's sets, then with them (`meet_slabs`, the default), which
/// changes a quarter of the sets, and with them on a `T` off `S⁻¹`, where the pad counts.
#[test]
fn continuous_two_frames_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let steps = 40;
    let [_, (problem, _)] = paper_problems(steps);
    let problem = problem.with_time(TimeModel::Continuous, 1);
    let s = double_integrator();
    let init = boxes(
        &[
            [-1.0, 0.5],
            [0.5, 1.0],
            [-1.09, 1.41],
            [-2.5, 1.0],
            [1.0, 1.3],
            [0.0, -1.0],
        ],
        0.05,
    );
    let st = ReachSettings {
        face_local: true,
        intersect_x: true,
        meet_slabs: false,
        ..settings(ReachMethod::Disturbance)
    };
    assert_eq!(problem.frames(&st).len(), 2);
    assert_eq!(g.supports(&problem, &st), Ok(()));
    let paths = nn_paths(
        &s,
        x_network(&problem),
        &init,
        problem.m_c,
        problem.dt,
        steps,
    );
    let what = "scenario 2, two frames met, forward bounds, face-local";
    let (on_device, on_host) =
        continuous_parity(&g, &problem, &init, (&st, TOL), Some(&paths), what);
    // A substantial share: every tube's first step is the host's (no rates yet), and a step
    // the check fails on either frame.
    assert!(
        on_device >= 3 * on_host,
        "{what}: {on_device} on the device, {on_host} on the host"
    );
    // With each frame's slabs clipped by the other's hull (`meet_slabs`, validated.wgsl
    // `clip_by_other`, the pad from cmeet.wgsl): the same again. The clip changes the CPU's
    // sets on these boxes, so a device that skipped it (or clipped by a wrong set) would differ.
    let clipped = ReachSettings {
        meet_slabs: true,
        ..st.clone()
    };
    assert_eq!(g.supports(&problem, &clipped), Ok(()));
    let cpu_sets = |s: &ReachSettings| {
        let r = CpuBackend.reach(&problem, &init, s, &|_, _| {}).unwrap();
        r.boxes
            .iter()
            .flat_map(|t| t.tube.iter().map(|x| x.set.clone()).collect::<Vec<_>>())
            .collect::<Vec<_>>()
    };
    let (plain, met) = (cpu_sets(&st), cpu_sets(&clipped));
    let changed = plain.iter().zip(&met).filter(|(a, b)| a != b).count();
    assert!(
        changed * 4 >= plain.len(),
        "{changed} of {} sets changed",
        plain.len()
    );
    let what = "scenario 2, two frames met, slabs clipped by the other frame's sets";
    let (on_device, on_host) =
        continuous_parity(&g, &problem, &init, (&clipped, TOL), Some(&paths), what);
    assert!(
        on_device >= 3 * on_host,
        "{what}: {on_device} on the device, {on_host} on the host"
    );
    // With a `T` 1e-4 off `S⁻¹` (`ρ ≥ ‖R‖/(1 − ‖R‖)`, `R = I − TS`, as every transform has
    // it), the x frame's half-spaces of the z frame's set carry the pad `ρ‖T k‖∞` (cmeet.wgsl's
    // `t_pad`, the CPU's `frame_slack`), far above the tolerance: a device without it, or with
    // another, differs from the CPU.
    let exact = problem.transform.clone().unwrap();
    let mut t = exact.t.clone();
    t[0] *= 1.0 + 1e-4;
    let skew = Transform::with_inverse(t, exact.s.clone(), exact.n).unwrap();
    assert!(skew.rho > 1e-5, "{}", skew.rho);
    let mut skewed = ReachProblem::with_transform(
        &s,
        small_network(&[2, 16, 16, 1], 2, 0.05),
        0.02,
        Some(skew),
    )
    .unwrap()
    .with_time(TimeModel::Continuous, 1);
    skewed.steps = steps;
    let what = "scenario 2, T off S⁻¹, slabs clipped by the other frame's sets";
    continuous_parity(&g, &skewed, &init, (&clipped, TOL), Some(&paths), what);
}

/// Scenario 1 (x) and scenario 2 (z) with small networks under the filter's closed form
/// (`exact = "closed-form"`: its proven pieces and its enclosures of `v` met with the network
/// on the slabs, on the device since the fifth stage; with and without the pieces' lattice; with
/// the second-order Taylor rates) and under `"inactive"`, a global `M`,
/// face-local forward bounds, 30 steps, boxes near the obstacle and the rows: the same
/// verdicts, sets, flowpipes, exact and enclosed steps as the CPU engine's, most box-steps on
/// the device. (The small networks' `M` bounds nothing: the sets' soundness is checked on the
/// shipped network, [`continuous_sets_hold_the_filtered_system_on_scenario_1`].)
#[test]
fn continuous_closed_form_runs_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let steps = 30;
    let [(p1, _), (p2, b2)] = paper_problems(steps);
    let b1 = boxes(
        &[
            [0.8, 0.0],
            [2.0, 1.3],
            [3.2, 0.2],
            [1.2, -1.0],
            [-1.0, 1.0],
            [3.9, 0.0],
        ],
        0.05,
    );
    for (name, problem, init) in [("scenario 1", p1, b1), ("scenario 2", p2, b2)] {
        let problem = problem.with_time(TimeModel::Continuous, 1);
        for exact in [ExactField::ClosedForm, ExactField::Inactive] {
            let st = ReachSettings {
                face_local: true,
                exact,
                ..settings(ReachMethod::Disturbance)
            };
            let what = format!("{name}, exact {exact:?}");
            continuous_parity(&g, &problem, &init, (&st, TOL), None, &what);
        }
    }
    // The pieces' lattice (`lattice_rates`): scenario 2's boxes on the obstacle row's switching
    // surface, above and below the disc, where no piece is proven, and a margin (0.5) that
    // leaves the network's rates looser than the lattice's (the CPU's sets change with it).
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let mut problem =
        ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 2, 0.05), 0.5, t)
            .unwrap()
            .with_time(TimeModel::Continuous, 1);
    problem.steps = steps;
    let across = boxes(
        &[
            [-0.83, 1.0],
            [0.06, 0.5],
            [-1.71, 1.5],
            [0.43, 0.3],
            [0.68, -1.5],
            [3.32, -1.5],
        ],
        0.08,
    );
    let st = |lattice: bool| ReachSettings {
        face_local: true,
        exact: ExactField::ClosedForm,
        lattice,
        ..settings(ReachMethod::Disturbance)
    };
    let cpu = |lattice: bool| {
        CpuBackend
            .reach(&problem, &across, &st(lattice), &|_, _| {})
            .unwrap()
            .boxes
    };
    let (plain, sharp) = (cpu(false), cpu(true));
    let changed = plain
        .iter()
        .zip(&sharp)
        .filter(|(a, b)| a.tube.iter().zip(&b.tube).any(|(x, y)| x.set != y.set))
        .count();
    assert!(changed >= 2, "the lattice changed {changed} tubes");
    let what = "scenario 2, the pieces' lattice";
    continuous_parity(&g, &problem, &across, (&st(true), TOL), None, what);
    // The second-order Taylor rates (`taylor3`, `piece_taylor3`) on both scenarios' proven
    // pieces: they change the CPU's sets, and the device's follow.
    let [(p1, _), (p2, b2)] = paper_problems(steps);
    let b1 = boxes(&[[0.8, 0.0], [2.0, 1.3], [1.2, -1.0], [-1.0, 1.0]], 0.05);
    for (name, problem, init) in [("scenario 1", p1, b1), ("scenario 2", p2, b2)] {
        let problem = problem.with_time(TimeModel::Continuous, 1);
        let st = |taylor3: bool| ReachSettings {
            face_local: true,
            exact: ExactField::ClosedForm,
            taylor3,
            ..settings(ReachMethod::Disturbance)
        };
        let cpu = |taylor3: bool| {
            CpuBackend
                .reach(&problem, &init, &st(taylor3), &|_, _| {})
                .unwrap()
                .boxes
        };
        let (plain, sharp) = (cpu(false), cpu(true));
        // By far more than the parity's tolerance: a device that left them out would fail it.
        let moved = plain
            .iter()
            .zip(&sharp)
            .flat_map(|(a, b)| a.tube.iter().zip(&b.tube))
            .flat_map(|(x, y)| {
                let ends = |s: &IntervalBox| s.lower.iter().chain(&s.upper).copied().collect();
                let (x, y): (Vec<f64>, Vec<f64>) = (ends(&x.set), ends(&y.set));
                x.into_iter()
                    .zip(y)
                    .map(|(a, b)| (a - b).abs() / a.abs().max(1.0))
            })
            .fold(0.0f64, f64::max);
        assert!(
            moved > 1e3 * TOL,
            "{name}: taylor3 moved the sets by {moved:.1e}"
        );
        let what = format!("{name}, taylor3");
        continuous_parity(&g, &problem, &init, (&st(true), TOL), None, &what);
    }
}

/// Scenario 1 with its shipped network, face-local forward bounds, the paper's twelve boxes over
/// 25 steps, with its certified global `M_C` (0.179) and the network everywhere, and with its
/// error map's local bounds and the filter's closed form (its pieces and enclosures of `v`: the
/// scenario's default): the GPU engine's sets and flowpipes hold the true filtered system's RK4
/// trajectories (the ground-truth filter) and equal the CPU's to [`SHIPPED_TOL`], exact steps
/// counted alike. (Local margins with the network everywhere or `exact = "inactive"`: the
/// small-grid `verify` tests of `gpu_parity`, at a third of the lavapipe time.)
#[test]
fn continuous_sets_hold_the_filtered_system_on_scenario_1() {
    let Some(g) = gpu_f64() else { return };
    let s = integrator();
    let st = ReachSettings {
        face_local: true,
        ..settings(ReachMethod::Disturbance)
    };
    let filter = SafetyFilter::new(&s);
    let dt = s.reach.dt;
    let paths: Vec<_> = s
        .reach
        .initial
        .iter()
        .map(|b| {
            sample_box(b, 12, 11)
                .into_iter()
                .map(|x0| simulate_filtered(&filter, &x0, dt / 10.0, 250, Integrator::Rk4).x)
                .collect()
        })
        .collect();
    let cases = [
        (
            Some(Margin::Certified),
            ExactField::Nowhere,
            "certified M_C",
        ),
        (None, ExactField::ClosedForm, "local M_C, closed form"),
    ];
    for (m_c, exact, name) in cases {
        let st = ReachSettings {
            exact,
            ..st.clone()
        };
        let options = ProblemOptions {
            m_c,
            time: Some("continuous".into()),
            ..ProblemOptions::default()
        };
        let mut problem = ReachProblem::from_scenario(&s, &options).unwrap();
        assert_eq!(problem.error_map.is_some(), m_c.is_none());
        problem.steps = 25;
        let what = format!("scenario 1, shipped network, {name}");
        continuous_parity(
            &g,
            &problem,
            &s.reach.initial,
            (&st, SHIPPED_TOL),
            Some(&paths),
            &what,
        );
        if exact == ExactField::ClosedForm {
            continue;
        }
        // The same network's bounds on the Euler map's faces, for scale: how far the engines'
        // network bounds alone part.
        let euler = problem.clone().with_time(TimeModel::Euler, 1);
        let (cpu, dev) = run_both_with(&g, &euler, &s.reach.initial, &st);
        compare_within(&cpu, &dev, &format!("{what}, Euler"), SHIPPED_TOL);
    }
}

/// A nonlinear class-K function (`α(h) = 3h³ + 0.1h`, a curved wall `h = x₁ + 1 + 0.2x₂²` on
/// `ẋ = u`, a small network, `M = 0.35`, the filter's closed form and face-local bounds, 30
/// steps): `α` reaches the device's generated code (the pieces' fields, the slack rows), so
/// its tubes are the CPU's, which differ from those with `α(h) = 0.1h`.
#[test]
fn continuous_runs_with_a_nonlinear_class_k_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let wall = |alpha: &str| common::curved_wall(alpha, "horizon = 1.5");
    let init = boxes(
        &[[-0.55, 0.35], [-0.85, -0.45], [-0.25, -0.05], [0.5, 1.0]],
        0.05,
    );
    let net = small_network(&[2, 16, 2], 4, 0.05);
    let st = ReachSettings {
        face_local: true,
        exact: ExactField::ClosedForm,
        ..settings(ReachMethod::Disturbance)
    };
    let problem = |s: &Scenario| {
        ReachProblem::new(s, net.clone(), 0.35)
            .unwrap()
            .with_time(TimeModel::Continuous, 1)
    };
    let (cubic, linear) = (wall(r#""3*h^3 + 0.1*h""#), wall("0.1"));
    let cpu = |s: &Scenario| {
        CpuBackend
            .reach(&problem(s), &init, &st, &|_, _| {})
            .unwrap()
            .boxes
    };
    let differ = cpu(&cubic)
        .iter()
        .zip(&cpu(&linear))
        .filter(|(a, b)| a.tube.iter().zip(&b.tube).any(|(x, y)| x.set != y.set))
        .count();
    assert!(differ >= 2, "α changed {differ} tubes");
    let what = "curved wall, α(h) = 3h³ + 0.1h";
    continuous_parity(&g, &problem(&cubic), &init, (&st, TOL), None, what);
}

/// A high-order CBF written out on a double integrator (`h = 1.5 − x₁ − 0.1x₁³`, which no
/// input acts on, beside `ψ = L_f̃h + h`; a scalar input, so the closed form's rows; neither
/// affine, so the sets are not clipped to them): the row of `h` binds nowhere `v` exists, on the
/// device (shaders/filter.wgsl `filter_rows`) as on the host (`VForms::v_rows`), so sets across
/// `ψ = 0` take the filter's pieces on both, and the tubes agree.
#[test]
fn continuous_runs_with_a_high_order_cbf_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let s = common::high_order_wall("horizon = 1.5");
    assert!(s.cbfs[0].inert);
    let init = boxes(&[[0.9, 0.4], [1.2, 0.07], [0.3, 1.1], [-0.5, 1.6]], 0.05);
    let problem = ReachProblem::new(&s, small_network(&[2, 16, 1], 6, 0.05), 0.2)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    let st = ReachSettings {
        face_local: true,
        exact: ExactField::ClosedForm,
        ..settings(ReachMethod::Disturbance)
    };
    let what = "double integrator, high-order CBF written out";
    continuous_parity(&g, &problem, &init, (&st, TOL), None, what);
}

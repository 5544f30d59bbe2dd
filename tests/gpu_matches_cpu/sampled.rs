//! `reach` with `time = "sampled"` on the GPU engine against the CPU engine (docs/design.md
//! §7.2, §7.4): at each sample the device bounds the network over every live box's set, the
//! host runs the CPU engine's own sampled step on those bounds. The same verdicts, findings and
//! exact steps, sets and flowpipes equal to 1e-10 relative in f64, and the GPU's sets and
//! flowpipes hold exact zero-order-hold trajectories of the system they bound.

use super::continuous::{assert_no_escapes, compare_flowpipes, SHIPPED_TOL};
use super::*;
use cbfreach::filter::SafetyFilter;
use cbfreach::problem::ProblemOptions;
use cbfreach::simulate::step;

/// Sets and flowpipes agree to this, relative to `max(1, |x|)` (f64, small networks).
const TOL: f64 = 1e-10;

/// The filter's correction at a state for trajectory `q` of its box (`None`: undefined there).
type Correction<'a> = &'a dyn Fn(&[f64], usize) -> Option<Vec<f64>>;

/// Zero-order-hold trajectories from 12 points of each box (its corners first): every `k`
/// steps of `dt` the input `u = κ(x) + v(x, q)` is computed and held (`q`: the trajectory's
/// index among its box's; a trajectory ends where `v` has no value) while the plant
/// `ẋ = f(x) + g(x)u` is integrated by RK4 at `dt/10`; the states every `dt/10`.
fn zoh_paths(
    s: &Scenario,
    v: Correction,
    init: &[IntervalBox],
    (dt, k): (f64, usize),
    steps: usize,
) -> Vec<Vec<Vec<Vec<f64>>>> {
    let (n, inputs) = (s.n(), s.m());
    let path = |x0: Vec<f64>, q: usize| {
        let mut x = x0;
        let mut u = vec![0.0; inputs];
        let mut path = vec![x.clone()];
        for i in 0..steps {
            if i % k == 0 {
                let Some(v) = v(&x, q) else { break };
                u = (0..inputs).map(|c| s.kappa_at(&x)[c] + v[c]).collect();
            }
            let plant = |y: &[f64]| -> Result<Vec<f64>, ()> {
                let g = s.g_at(y);
                let gu = |r: usize| (0..inputs).map(|c| g[r * inputs + c] * u[c]).sum::<f64>();
                Ok((0..n).map(|r| s.f[r].eval(y) + gu(r)).collect())
            };
            for _ in 0..10 {
                x = step(plant, &x, dt / 10.0, Integrator::Rk4).unwrap();
                path.push(x.clone());
            }
        }
        path
    };
    init.iter()
        .map(|b| {
            let starts = sample_box(b, 12, 7).into_iter().enumerate();
            starts.map(|(q, x0)| path(x0, q)).collect()
        })
        .collect()
}

/// `v = N(x) + d`, the system the disturbance method bounds with the network alone: `d = ±m`
/// per input, its signs fixed by the trajectory's index.
fn disturbed(net: &Mlp, m: f64) -> impl Fn(&[f64], usize) -> Option<Vec<f64>> + '_ {
    move |x, q| {
        let v = net.forward(x);
        let d = |c: usize| if (q >> c).is_multiple_of(2) { m } else { -m };
        Some(v.iter().enumerate().map(|(c, v)| v + d(c)).collect())
    }
}

/// Both engines on `problem` under `st`: the GPU's sets and flowpipes hold `paths` where given
/// (checked first, so a wrong set fails even where both engines agree), then the same ends, findings
/// between samples, exact and enclosed steps, sample times, sets and flowpipes (to [`TOL`]) as
/// the CPU's; the device bounded the network. Returns the tubes' findings.
fn sampled_parity(
    g: &GpuBackend,
    problem: &ReachProblem,
    init: &[IntervalBox],
    st: &ReachSettings,
    paths: Option<&[Vec<Vec<Vec<f64>>>]>,
    what: &str,
) -> usize {
    sampled_parity_within(g, problem, init, (st, TOL), paths, what)
}

/// [`sampled_parity`] with the sets and flowpipes to `tol`.
fn sampled_parity_within(
    g: &GpuBackend,
    problem: &ReachProblem,
    init: &[IntervalBox],
    (st, tol): (&ReachSettings, f64),
    paths: Option<&[Vec<Vec<Vec<f64>>>]>,
    what: &str,
) -> usize {
    let before = g.sampled_bounds();
    let (cpu, dev) = run_both_with(g, problem, init, st);
    let bounded = g.sampled_bounds() - before;
    if let Some(paths) = paths {
        assert_no_escapes(&dev, paths, problem.dt, init.len(), what);
    }
    for (k, (a, b)) in cpu.iter().zip(&dev).enumerate() {
        assert_eq!(a.end, b.end, "{what} box {k}: end");
        assert_eq!(
            a.unsafe_between_samples, b.unsafe_between_samples,
            "{what} box {k}: finding"
        );
        assert_eq!(
            (a.exact_steps, a.enclosed_steps),
            (b.exact_steps, b.enclosed_steps),
            "{what} box {k}: exact and enclosed steps"
        );
    }
    let sets = compare_within(&cpu, &dev, what, tol);
    let pipes = compare_flowpipes(&cpu, &dev, what, tol);
    let findings = dev
        .iter()
        .filter(|t| t.unsafe_between_samples.is_some())
        .count();
    let ends: Vec<String> = dev.iter().map(|t| format!("{}", t.end)).collect();
    eprintln!(
        "{what}: {bounded} sets bounded on the device; {findings} findings; sets within \
         {sets:.1e}, flowpipes {pipes:.1e}; ends {ends:?}"
    );
    assert!(
        bounded >= init.len(),
        "{what}: {bounded} sets on the device"
    );
    findings
}

/// The network in x (the problem's own, or its x-frame's where it runs in `z = T x`).
fn x_network(problem: &ReachProblem) -> &Mlp {
    problem
        .in_x
        .as_deref()
        .map_or(&problem.network, |p| &p.network)
}

/// Scenario 1 (x coordinates, `T_s = dt`, where the held input's motion is the Euler map's)
/// and scenario 2 (z = Tx, `T_s = 2·dt` and `4·dt`: the remainder `τ²/2·u_k` on x₁; one frame,
/// and met with the x-boxes) with small networks, forward, forward-backward and CROWN bounds,
/// the filter's closed form, its inactive piece or the network alone, 40 steps: the GPU
/// engine's tubes are the CPU's; with the network alone (the small random networks are not the
/// filter: the sets bound the disturbed network's system) they hold its zero-order-hold
/// trajectories.
#[test]
fn sampled_runs_match_the_cpu_engine() {
    let Some(g) = gpu_f64() else { return };
    let steps = 40;
    let [(p1, _), (p2, b2)] = paper_problems(steps);
    let b1 = scenario_1_starts();
    let (s1, s2) = (integrator(), double_integrator());
    let case = |bounds, exact, intersect_x| ReachSettings {
        exact,
        intersect_x,
        // Ignored by sampled runs on both engines (whole-set bounds).
        face_local: true,
        ..with_bounds(bounds, ReachMethod::Disturbance)
    };
    let runs = [
        (
            &s1,
            &p1,
            &b1,
            1,
            case(BoundMethod::Forward, ExactField::ClosedForm, false),
        ),
        (
            &s1,
            &p1,
            &b1,
            1,
            case(BoundMethod::Crown, ExactField::Nowhere, false),
        ),
        (
            &s2,
            &p2,
            &b2,
            2,
            case(BoundMethod::ForwardBackward, ExactField::Inactive, false),
        ),
        (
            &s2,
            &p2,
            &b2,
            2,
            case(BoundMethod::Forward, ExactField::ClosedForm, true),
        ),
        (
            &s2,
            &p2,
            &b2,
            2,
            case(BoundMethod::Forward, ExactField::Nowhere, true),
        ),
        (
            &s2,
            &p2,
            &b2,
            4,
            case(BoundMethod::Crown, ExactField::Nowhere, false),
        ),
    ];
    for (s, problem, init, k, st) in runs {
        let dt = problem.dt;
        let period = TimeModel::Sampled {
            control_period: k as f64 * dt,
        };
        let problem = problem.clone().with_time(period, 1);
        let v = disturbed(x_network(&problem), problem.m_c);
        let paths = zoh_paths(s, &v, init, (dt, k), steps);
        let network_alone = st.exact == ExactField::Nowhere;
        let what = format!(
            "{}, T_s = {k}·dt, {} bounds, exact {:?}, {} frame(s)",
            s.name,
            st.bounds,
            st.exact,
            problem.frames(&st).len()
        );
        let paths = network_alone.then_some(&paths[..]);
        sampled_parity(&g, &problem, init, &st, paths, &what);
    }
}

/// The wall held over `T_s = 1.5` (tests/common `WALL`): the held input carries the state into
/// the obstacle, and both engines record the same finding (`unsafe-between-samples`, its time
/// and CBF) with the same sets.
#[test]
fn a_finding_between_samples_is_the_cpu_engines() {
    let Some(g) = gpu_f64() else { return };
    let s = common::from_text(common::WALL).unwrap();
    let problem = ReachProblem::new(&s, common::wall_network(), 0.01)
        .unwrap()
        .with_time(
            TimeModel::Sampled {
                control_period: 1.5,
            },
            1,
        );
    let st = with_bounds(BoundMethod::Forward, ReachMethod::Disturbance);
    let steps = problem.steps;
    let v = disturbed(&problem.network, problem.m_c);
    let paths = zoh_paths(&s, &v, &s.reach.initial, (problem.dt, 15), steps);
    let init = &s.reach.initial;
    let findings = sampled_parity(&g, &problem, init, &st, Some(&paths), "wall");
    assert_eq!(findings, 1, "the wall's finding");
}

/// Both paper scenarios with their shipped networks, error maps (local margins) and settings
/// (the filter's closed form; scenario 2's parallelotope met with its x-box, two frames), the
/// paper's initial boxes, `T_s = dt` on scenario 1 over 25 steps and `2·dt` on scenario 2 over
/// 20: the GPU engine's sets and flowpipes hold the true filtered system's zero-order-hold
/// trajectories (the ground-truth filter held over each period) and equal the CPU's to
/// [`SHIPPED_TOL`].
#[test]
fn sampled_sets_hold_the_digital_filter_on_the_paper_scenarios() {
    let Some(g) = gpu_f64() else { return };
    for (s, k, steps) in [(integrator(), 1, 25), (double_integrator(), 2, 20)] {
        let options = ProblemOptions {
            time: Some("sampled".into()),
            control_period: Some(k as f64 * s.reach.dt),
            ..ProblemOptions::default()
        };
        let mut problem = ReachProblem::from_scenario(&s, &options).unwrap();
        assert!(problem.error_map.is_some());
        problem.steps = steps;
        let filter = SafetyFilter::new(&s);
        let v = |x: &[f64], _| filter.eval(x).ok();
        let init = &s.reach.initial;
        let paths = zoh_paths(&s, &v, init, (s.reach.dt, k), steps);
        let st = &s.settings.reach;
        let what = format!("{}, shipped, T_s = {k}·dt", s.name);
        sampled_parity_within(&g, &problem, init, (st, SHIPPED_TOL), Some(&paths), &what);
    }
}

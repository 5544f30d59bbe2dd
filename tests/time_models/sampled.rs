//! The sampled-data model: sets against exact zero-order-hold trajectories, the findings
//! between samples, and the filter's own constraint that proves `S` where the sets cannot.

use super::*;
use cbfreach::simulate::simulate_sampled_watching_s;
use cbfreach::verify::simulate_model;

/// Trajectories of the sampled-data system with the input held over `k` steps of `dt`
/// (`u = κ(x) + v(x)` at every `k`-th step, the plant integrated by RK4 at `dt/10` meanwhile),
/// every `dt`: exact zero-order hold up to RK4's error.
fn zoh(filter: &SafetyFilter, x0: &[f64], dt: f64, k: usize, steps: usize) -> Vec<Vec<f64>> {
    let s = filter.scenario();
    let (n, m) = (s.n(), s.m());
    let mut x = x0.to_vec();
    let mut out = vec![x.clone()];
    let mut u = vec![0.0; m];
    for i in 0..steps {
        if i % k == 0 {
            let Ok(v) = filter.eval(&x) else { break };
            u = s.kappa_at(&x).iter().zip(&v).map(|(a, b)| a + b).collect();
        }
        let plant = |y: &[f64]| -> Result<Vec<f64>, ()> {
            let g = s.g_at(y);
            Ok((0..n)
                .map(|r| s.f[r].eval(y) + (0..m).map(|c| g[r * m + c] * u[c]).sum::<f64>())
                .collect())
        };
        for _ in 0..10 {
            x = step(plant, &x, dt / 10.0, Integrator::Rk4).unwrap();
        }
        out.push(x.clone());
    }
    out
}

/// States of held-input trajectories (period `k·dt`, 48 starts per box, corners first) outside
/// their sets at every snapshot, and outside the recorded enclosure of the motion between
/// snapshots; and the checks made.
pub(super) fn zoh_escapes(s: &Scenario, tubes: &[Tube], k: usize, tol: f64) -> Escapes {
    let filter = SafetyFilter::new(s);
    let dt = s.reach.dt;
    let mut e = Escapes::default();
    for tube in tubes {
        let steps = (tube.tube.last().unwrap().t / dt).round() as usize;
        for x0 in sample_box(&tube.initial, 48, 11) {
            if !s.is_safe(&x0) {
                continue;
            }
            let xs = zoh(&filter, &x0, dt, k, steps);
            for sample in &tube.tube {
                let j = (sample.t / dt).round() as usize;
                let Some(x) = xs.get(j) else { break };
                e.checks += 1;
                let d = outside(&sample.set, x);
                if d > tol {
                    e.at_snapshots += 1;
                    e.worst = e.worst.max(d);
                }
                if let Some(pipe) = &sample.flowpipe {
                    e.between += usize::from(j > 0 && outside(pipe, &xs[j - 1]) > tol);
                    e.between += usize::from(outside(pipe, x) > tol);
                }
            }
        }
    }
    e
}

/// Sampled-data at `T_s = dt`: on scenario 1 (`ẋ = u`, no remainder: the held input's motion
/// is the Euler map's) the sets hold the Euler map's trajectories; on scenario 2 they hold
/// zero-order-hold trajectories (the control held over each step, the plant integrated
/// finely), which the Euler map's sets miss.
#[test]
fn sampled_sets_hold_zero_order_hold_trajectories() {
    let s1 = common::integrator();
    let sampled = TimeModel::Sampled {
        control_period: s1.reach.dt,
    };
    let a = paper_run(&s1, 25, sampled, 1);
    let e = zoh_escapes(&s1, &a, 1, 1e-9);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 12 * 48 * 20, "too few checks: {e:?}");

    let s2 = common::double_integrator();
    let dt = s2.reach.dt;
    let sampled = TimeModel::Sampled { control_period: dt };
    let tubes = paper_run(&s2, 200, sampled, 1);
    let e = zoh_escapes(&s2, &tubes, 1, 1e-9);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 9 * 48 * 20, "too few checks: {e:?}");
    let euler = paper_run(&s2, 200, TimeModel::Euler, 1);
    let e = zoh_escapes(&s2, &euler, 1, 1e-9);
    assert!(
        e.at_snapshots > 0,
        "Euler sets held every held-input state: {e:?}"
    );
}

/// The input held over `K = 2` and `4` integration steps (`T_s = K·dt`): the sets hold exact
/// zero-order-hold trajectories at every step and the recorded enclosures between steps hold
/// the states at both ends; the Euler map's sets at `dt` miss them.
#[test]
fn sampled_sets_hold_the_input_over_several_steps() {
    let s = common::double_integrator();
    let dt = s.reach.dt;
    for k in [2, 4] {
        let sampled = TimeModel::Sampled {
            control_period: k as f64 * dt,
        };
        let tubes = paper_run(&s, 80, sampled, 1);
        assert!(
            tubes.iter().all(|t| t.tube.len() > 20),
            "K = {k}: tubes end early"
        );
        let e = zoh_escapes(&s, &tubes, k, 1e-9);
        assert_eq!((e.at_snapshots, e.between), (0, 0), "K = {k}: {e:?}");
        assert!(e.checks >= 9 * 48 * 20, "K = {k}: too few checks: {e:?}");
        let euler = paper_run(&s, 80, TimeModel::Euler, 1);
        let e = zoh_escapes(&s, &euler, k, 1e-9);
        assert!(
            e.at_snapshots > 0,
            "K = {k}: Euler sets held every state: {e:?}"
        );
    }
}

/// The held motion to second order (design §7.2 item 2b) on a nonlinear plant: the damped
/// pendulum of `tests/fixtures/pendulum.toml` (`ω̇ = sin θ − bω + u`, chosen z coordinates)
/// steered to the origin, its input held over `K = 5` steps. Its sets hold exact
/// zero-order-hold trajectories at every step and converge. With the first-order form alone the
/// remainder's `τ²·|Df|·|DF|·w` outgrew the box's contraction: the sets grew to width 1 and
/// more (the same boxes left `C`). The network here is zero and its margin covers all of `v`,
/// so the sets rest on the filter's own pieces where they are proven and its enclosures.
#[test]
fn held_motion_to_second_order_holds_a_nonlinear_plant_and_contracts() {
    // Steered to the origin, underdamped (λ = −1.3 ± 1.14i): boxes contract at only 0.155 in
    // the best coordinates.
    let s = common::fixture_with(
        "pendulum.toml",
        &[
            ("k1 = 4.0", "k1 = 3.0"),
            ("k2 = 3.0", "k2 = 2.6"),
            ("theta_ref = 1.0", "theta_ref = 0.0"),
            (
                "lower = [0.9, -0.1], upper = [1.1, 0.1]",
                "lower = [-0.1, -0.1], upper = [0.1, 0.1]",
            ),
        ],
    );
    let filter = SafetyFilter::new(&s);
    // M ≥ |v| on C: a zero network within its margin everywhere.
    let grid = s.reach.region.partition(&[60, 80]);
    let v_max = grid
        .iter()
        .filter_map(|b| filter.eval(&b.center()).ok())
        .map(|v| v[0].abs())
        .fold(0.0, f64::max);
    let (t, _) = cbfreach::reach::Transform::chosen(&s);
    let network = common::small_network(&[2, 8, 1], 1, 0.0);
    let k = 5;
    let mut problem = ReachProblem::with_transform(&s, network, 1.5 * v_max + 1.0, t)
        .unwrap()
        .with_time(
            TimeModel::Sampled {
                control_period: k as f64 * s.reach.dt,
            },
            1,
        );
    problem.steps = 400;
    let boxes = [
        IntervalBox::new(vec![0.3, -0.1], vec![0.35, -0.05]).unwrap(),
        IntervalBox::new(vec![-0.2, 0.2], vec![-0.15, 0.25]).unwrap(),
        IntervalBox::new(vec![0.5, 0.1], vec![0.55, 0.15]).unwrap(),
    ];
    let tubes = run(&problem, &boxes, ExactField::ClosedForm);
    for tube in &tubes {
        let last = tube.tube.last().unwrap();
        assert!((last.t - 8.0).abs() < 1e-9, "ended at t = {}", last.t);
        let width = (0..2)
            .map(|i| last.set.upper[i] - last.set.lower[i])
            .fold(0.0, f64::max);
        assert!(width < 0.05, "{:?}: final width {width}", tube.initial);
    }
    let e = zoh_escapes(&s, &tubes, k, 1e-9);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 3 * 48 * 400, "too few checks: {e:?}");
}

/// A period that is not a whole number of steps is refused, naming the field and the value.
#[test]
fn a_period_off_the_step_grid_is_refused() {
    let err = common::from_text(&common::SMALL.replace(
        "m_c = 0.1",
        "m_c = 0.1\ntime = \"sampled\"\ncontrol_period = 0.12",
    ))
    .unwrap_err()
    .to_string();
    assert!(
        err.contains("reach.control_period") && err.contains("0.12"),
        "{err}"
    );
}

/// The held input carries the state into the obstacle: the tube records the finding (with the
/// time, the whole set outside `S`), and verify's verdict says so; with a short period the same
/// box gives no finding. Continuous time keeps the set in `S`.
#[test]
fn a_long_period_is_found_unsafe_between_samples() {
    let s = common::from_text(common::WALL).unwrap();
    let filter = SafetyFilter::new(&s);
    let x = [1.05, 0.05];
    assert!((common::wall_network().forward(&x)[0] - filter.eval(&x).unwrap()[0]).abs() < 1e-12);
    let problem = ReachProblem::new(&s, common::wall_network(), 0.01).unwrap();
    let long = problem.clone().with_time(
        TimeModel::Sampled {
            control_period: 1.5,
        },
        1,
    );
    let tubes = run(&long, &s.reach.initial, ExactField::ClosedForm);
    let found = tubes[0].unsafe_between_samples.clone().expect("a finding");
    assert!(found.t > 0.5 && found.t <= 1.1 + 1e-9, "{found:?}");
    assert_eq!(found.cbf, "wall");
    assert!(
        tubes[0].tube.iter().any(|x| x.set.upper[0] < 0.0),
        "no set entirely in the obstacle"
    );
    let xs = zoh(&filter, &s.reach.initial[0].lower, s.reach.dt, 15, 30);
    assert!(
        xs[15][0] < 0.0,
        "the true held-input system stays safe: {:?}",
        xs[15]
    );
    let e = zoh_escapes(&s, &tubes, 15, 1e-9);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    let json = serde_json::to_string(&tubes[0]).unwrap();
    assert!(json.contains("\"unsafe_between_samples\""), "{json}");

    let (j, _) = cbfreach::verify::judge_with_feasibility(&long, &s, &[], &tubes[0]);
    assert_eq!(j.verdict, cbfreach::verify::Verdict::UnsafeBetweenSamples);
    assert_eq!(j.verdict.name(), "unsafe-between-samples");

    let short = problem.clone().with_time(
        TimeModel::Sampled {
            control_period: 0.1,
        },
        1,
    );
    let tubes = run(&short, &s.reach.initial, ExactField::ClosedForm);
    assert_eq!(tubes[0].unsafe_between_samples, None, "{:?}", tubes[0].end);
    let cont = problem.with_time(TimeModel::Continuous, 1);
    let tubes = run(&cont, &s.reach.initial, ExactField::ClosedForm);
    assert_eq!(tubes[0].unsafe_between_samples, None);
    assert!(tubes[0].tube.iter().all(|x| x.set.lower[0] >= 0.0));
}

/// The double integrator pushed down (`κ = −3`) and held at `x₂ ≥ −2` by the filter
/// (`v = max(0, 1 − x₂)`, a one-neuron network, `M = 0.01`): `x₂` decays to −2, the sets' margin
/// reaches past `x₂ = −2`, so interval evaluation alone cannot prove `S` there. The QP's row
/// at each sample proves it (`h` affine: `ḧ = 0`), so no finding is recorded and the sets are
/// met with `x₂ ≥ −2`; zero-order-hold trajectories stay in them.
const VELOCITY: &str = r#"
name = "velocity-bound"
[system]
states = ["x1", "x2"]
inputs = ["u"]
f = ["x2", "0"]
g = [["0"], ["1"]]
kappa = ["-3"]
[[cbf]]
name = "velocity"
h = "x2 + 2"
[reach]
region = { lower = [-5, -2.5], upper = [5, 2.5] }
m_c = 0.01
dt = 0.05
horizon = 2.0
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
initial = [ { lower = [4.0, -1.9], upper = [4.1, -1.8] }, { lower = [3.5, -1.95], upper = [3.6, -1.85] } ]
"#;

#[test]
fn the_filter_constraint_keeps_sampled_sets_in_s() {
    let s = common::from_text(VELOCITY).unwrap();
    let mut net = Mlp::random(&[2, 1, 1], 1);
    net.layers[0].weight = vec![0.0, -1.0];
    net.layers[0].bias = vec![1.0];
    net.layers[1].weight = vec![1.0];
    net.layers[1].bias = vec![0.0];
    let filter = SafetyFilter::new(&s);
    let x = [4.05, -1.85];
    assert!((net.forward(&x)[0] - filter.eval(&x).unwrap()[0]).abs() < 1e-12);
    let problem = ReachProblem::new(&s, net, 0.01).unwrap().with_time(
        TimeModel::Sampled {
            control_period: s.reach.dt,
        },
        1,
    );
    let tubes = run(&problem, &s.reach.initial, ExactField::Nowhere);
    for tube in &tubes {
        assert_eq!(tube.unsafe_between_samples, None, "{:?}", tube.end);
        assert!(tube.tube.len() > 30, "{:?}", tube.end);
        let lowest = tube
            .tube
            .iter()
            .map(|x| x.set.lower[1])
            .fold(f64::INFINITY, f64::min);
        assert!(
            (-2.0 - 1e-12..-1.99).contains(&lowest),
            "lowest x₂ {lowest}"
        );
    }
    let e = zoh_escapes(&s, &tubes, 1, 1e-9);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 2 * 48 * 30, "too few checks: {e:?}");
}

/// The true sampled system can leave `S` between samples, and the checks see it: scenario 1 held
/// over `T_s = 0.4` (ten steps) from (4, 0.5) cuts into the obstacle within the first period
/// (at 0.28 s, by the reference in Python, at the ZOH's substeps of 0.04 s), where the
/// continuous-time filtered system stays in `S`.
#[test]
fn the_held_input_leaves_s_between_samples_and_the_simulation_says_when() {
    let s = common::integrator();
    let filter = SafetyFilter::new(&s);
    let x0 = [4.0, 0.5];
    let (tr, left) = simulate_sampled_watching_s(&filter, &x0, 0.4, 25);
    let t = left.expect("the held input carries the plant into the obstacle");
    assert!((0.0..=0.4).contains(&t), "within the first period, not {t}");
    assert!((t - 0.28).abs() < 1e-9, "at the substep 0.28, not {t}");
    assert_eq!(tr.t.len(), 26, "25 periods recorded");
    let (ode, none) = simulate_model(&filter, &x0, TimeModel::Continuous, 10);
    assert!(none.is_none());
    assert!(ode.x.iter().all(|x| s.is_safe(x)), "the ODE stays in S");
}

/// The checks simulate the model a report names with its control period: held over
/// `T_s = 2·dt`, not over `dt` (which the verdicts' check did before), and the Euler map and
/// the ODE at their own steps.
#[test]
fn the_checks_simulate_the_reports_model_with_its_period() {
    let s = common::double_integrator();
    let filter = SafetyFilter::new(&s);
    let x0 = [-3.0, 1.0];
    let ts = 2.0 * s.reach.dt;
    let time = TimeModel::from_label(&TimeModel::Sampled { control_period: ts }.to_string());
    let (held, left) = simulate_model(&filter, &x0, time.expect("the label reads back"), 10);
    assert!(left.is_none());
    let periods = (s.reach.horizon / ts).round() as usize;
    assert_eq!(held.t.len(), periods + 1);
    assert!(
        (held.t[1] - ts).abs() < 1e-15,
        "one sample every T_s: {}",
        held.t[1]
    );
    // Against the same hold computed here (ZOH over two steps of `dt`).
    let reference = zoh(&filter, &x0, s.reach.dt, 2, 2 * periods);
    for (k, x) in held.x.iter().enumerate() {
        let r = &reference[2 * k];
        assert!(
            (x[0] - r[0]).abs() + (x[1] - r[1]).abs() < 1e-9,
            "t = {}",
            held.t[k]
        );
    }
    let (euler, _) = simulate_model(&filter, &x0, TimeModel::Euler, 10);
    assert!((euler.t[1] - s.reach.dt).abs() < 1e-15);
    let (ode, _) = simulate_model(&filter, &x0, TimeModel::Continuous, 10);
    assert!((ode.t[1] - s.reach.dt / 10.0).abs() < 1e-15);
}

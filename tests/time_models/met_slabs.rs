//! Slabs clipped by the other frame's sets (`ReachSettings::meet_slabs`, design §7.1 item 7):
//! every continuous-time trajectory (RK4 at a tenth of the step, 48 starts per box, corners
//! included) still lies in the sets and flowpipes, on a rotating closed loop (where the clipped
//! faces make the sets contract at several times the rate) and on scenario 2's paper boxes.

use super::*;
use cbfreach::reach::Transform;

/// A damped pendulum held upright, `θ̈ = sin θ − 0.1ω + u`, `κ = −3θ − 2ω`: its closed loop at
/// the origin has `λ = −1.05 ± 0.947i`, so boxes in any fixed coordinates contract at
/// `−1.05 + 0.947 = −0.10` at best. The CBF never binds on the region (`v = 0`: a zero network
/// stands in for the filter, the filter's own field is proven on every set).
const ROTATING: &str = r#"
name = "rotating"
[system]
states = ["theta", "omega"]
inputs = ["u"]
f = ["omega", "sin(theta) - 0.1*omega"]
g = [["0"], ["1"]]
kappa = ["-3*theta - 2*omega"]
[[cbf]]
h = "theta + 100"
[reach]
region = { lower = [-1.5, -2], upper = [1.5, 2] }
m_c = 0.001
dt = 0.02
horizon = 3
goal = { lower = [-0.1, -0.1], upper = [0.1, 0.1] }
initial = [
  { lower = [0.3, 0.3], upper = [0.5, 0.5] },
  { lower = [-1.0, 0.6], upper = [-0.8, 0.8] },
  { lower = [0.9, -1.5], upper = [1.1, -1.3] },
]
"#;

fn tubes(problem: &ReachProblem, boxes: &[IntervalBox], meet_slabs: bool) -> Vec<Tube> {
    let settings = ReachSettings {
        meet_slabs,
        ..ReachSettings::default()
    };
    CpuBackend
        .reach(problem, boxes, &settings, &|_, _| {})
        .unwrap()
        .boxes
}

/// The largest width of each tube's last set.
fn final_widths(tubes: &[Tube]) -> Vec<f64> {
    tubes
        .iter()
        .map(|t| {
            let last = &t.tube.last().unwrap().set;
            (0..last.dim())
                .map(|i| last.upper[i] - last.lower[i])
                .fold(0.0, f64::max)
        })
        .collect()
}

/// Every tube valid, and every RK4 state of the true system (48 starts a box) in its sets and
/// flowpipes, over at least `checks` comparisons.
fn assert_held(s: &Scenario, tubes: &[Tube], checks: usize) {
    assert!(
        tubes.iter().all(|t| t.valid()),
        "{:?}",
        tubes.iter().map(|t| &t.end).collect::<Vec<_>>()
    );
    let e = escapes(s, tubes, s.reach.dt, 1e-6);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= checks, "too few checks: {e:?}");
}

/// A zero network's problem (the filter's own field proven on every set) in the chosen
/// coordinates and x, and the same kept in `frames` turned frames too.
fn two_and_turned(s: &Scenario, frames: usize) -> (ReachProblem, ReachProblem) {
    let net = common::zero_network(&[s.n(), 4, 1]);
    let (transform, _) = Transform::chosen(s);
    let two = ReachProblem::with_transform(s, net, 0.001, transform).unwrap();
    let turned = two.clone().with_turned_frames(s, frames).unwrap();
    assert_eq!(turned.turned_frames(&ReachSettings::default()), frames);
    (two, turned)
}

#[test]
fn clipped_slabs_hold_a_rotating_flow_and_contract_it() {
    let s = common::from_text(ROTATING).unwrap();
    let net = common::zero_network(&[2, 4, 1]);
    let (transform, _) = Transform::chosen(&s);
    assert!(
        transform.is_some(),
        "the rotation needs the auto coordinates"
    );
    let problem = ReachProblem::with_transform(&s, net, 0.001, transform).unwrap();
    let met = tubes(&problem, &s.reach.initial, true);
    assert_held(&s, &met, 3 * 48 * 150);

    // Without the clipping each face sees the whole rotation: after 3 s the sets are several
    // times wider.
    let plain = tubes(&problem, &s.reach.initial, false);
    for (m, p) in final_widths(&met).iter().zip(final_widths(&plain)) {
        assert!(*m < 0.5 * p, "clipped {m}, plain {p}");
    }
}

#[test]
fn clipped_slabs_hold_scenario_2() {
    let s = common::double_integrator();
    let mut problem = common::shipped_problem(&s).with_time(TimeModel::Continuous, 1);
    problem.steps = 40;
    let met = tubes(&problem, &s.reach.initial, true);
    let e = escapes(&s, &met, s.reach.dt, 1e-6);
    assert_eq!((e.at_snapshots, e.between), (0, 0), "{e:?}");
    assert!(e.checks >= 9 * 48 * 20, "too few checks: {e:?}");
    // More boxes stay valid (one ends at step 28 without the clipping), and the sets are
    // narrower on the whole at step 20, when every tube still runs.
    let plain = tubes(&problem, &s.reach.initial, false);
    let valid = |t: &[Tube]| t.iter().filter(|t| t.valid()).count();
    assert!(
        valid(&met) > valid(&plain),
        "{} against {}",
        valid(&met),
        valid(&plain)
    );
    let at_20 = |t: &[Tube]| -> f64 {
        t.iter()
            .map(|t| {
                let set = &t.tube[20].set;
                (0..2)
                    .map(|i| set.upper[i] - set.lower[i])
                    .fold(0.0, f64::max)
            })
            .sum()
    };
    assert!(
        at_20(&met) < at_20(&plain),
        "{} against {}",
        at_20(&met),
        at_20(&plain)
    );
}

/// ACC (`acc.toml`, two frames, input bounds and the CBF row binding where the lead car is
/// near): cells of `verify --region 5,30:18.3,50 --grid 16,6`, which verify only with the
/// clipping; every continuous-time trajectory lies in their sets and flowpipes over 20 s.
#[test]
fn clipped_slabs_hold_acc() {
    let s = Scenario::load(&common::scenario_path("acc.toml")).unwrap();
    let mut problem = common::shipped_problem(&s);
    problem.steps = 400;
    let region = IntervalBox::new(vec![5.0, 30.0], vec![18.3, 50.0]).unwrap();
    let boxes: Vec<IntervalBox> = [0, 23, 47, 70, 95]
        .into_iter()
        .map(|k| region.partition_cell(&[16, 6], k))
        .collect();
    let met = tubes(&problem, &boxes, true);
    assert_held(&s, &met, 5 * 48 * 100);
}

/// The rotating pendulum with less damping, `κ = −2.19θ − 0.9ω`: `λ = −0.5 ± 0.97i`, so boxes
/// in any one frame grow at `α + |β| = 0.47` near the origin, and z and x met still let them.
/// Kept in three frames turned by `π/6` besides x (design §7.1 item 8), every continuous-time
/// trajectory lies in the sets and flowpipes over 6 s, and the sets shrink.
#[test]
fn turned_frames_hold_a_lightly_damped_flow_and_contract_it() {
    let s = common::from_text(
        &ROTATING
            .replace("-3*theta - 2*omega", "-2.19*theta - 0.9*omega")
            .replace("horizon = 3", "horizon = 6"),
    )
    .unwrap();
    let turning = cbfreach::reach::Turning::at_goal(&s).expect("the loop turns");
    assert!(
        (turning.alpha + 0.5).abs() < 1e-6 && turning.box_rate() > 0.4,
        "{turning:?}"
    );
    assert_eq!(turning.frames(), 3);
    let (two, turned) = two_and_turned(&s, 3);
    // The device meets two frames: it refuses more by name, so `auto` runs the CPU engine.
    let refused = cbfreach::gpu::GpuBackend::runs(&turned, &ReachSettings::default());
    assert!(
        refused.is_err_and(|e| e.to_string().contains("turned frames")),
        "the GPU engine must refuse turned frames"
    );
    assert!(cbfreach::gpu::GpuBackend::runs(&two, &ReachSettings::default()).is_ok());
    let met = tubes(&turned, &s.reach.initial, true);
    assert_held(&s, &met, 3 * 48 * 300);
    // Two frames alone: the sets end wider than they started; turned, narrower.
    let plain = tubes(&two, &s.reach.initial, true);
    for ((m, p), b) in final_widths(&met)
        .iter()
        .zip(final_widths(&plain))
        .zip(&s.reach.initial)
    {
        let start = (0..2).map(|i| b.upper[i] - b.lower[i]).fold(0.0, f64::max);
        assert!(
            *m < start && *m < 0.5 * p,
            "turned {m}, two frames {p}, start {start}"
        );
    }
}

/// Turned frames in three states: the lightly damped pendulum with a third state driven by it,
/// `ẏ = −2y + 0.5θ` (the pair turns in its own plane of z, the real coordinate stays). Every
/// continuous-time trajectory lies in the sets kept in z, x and two turned copies of z.
#[test]
fn turned_frames_hold_a_flow_with_a_pair_and_a_real_eigenvalue() {
    let text = ROTATING
        .replace("-3*theta - 2*omega", "-2.19*theta - 0.9*omega")
        .replace(
            r#"states = ["theta", "omega"]"#,
            r#"states = ["theta", "omega", "y"]"#,
        )
        .replace(
            r#"f = ["omega", "sin(theta) - 0.1*omega"]"#,
            r#"f = ["omega", "sin(theta) - 0.1*omega", "-2*y + 0.5*theta"]"#,
        )
        .replace(r#"g = [["0"], ["1"]]"#, r#"g = [["0"], ["1"], ["0"]]"#)
        .replace(
            "lower = [-1.5, -2], upper = [1.5, 2]",
            "lower = [-1.5, -2, -1], upper = [1.5, 2, 1]",
        )
        .replace(
            "lower = [-0.1, -0.1], upper = [0.1, 0.1]",
            "lower = [-0.1, -0.1, -0.1], upper = [0.1, 0.1, 0.1]",
        )
        .replace(
            "lower = [0.3, 0.3], upper = [0.5, 0.5]",
            "lower = [0.3, 0.3, 0.1], upper = [0.5, 0.5, 0.2]",
        )
        .replace(
            "lower = [-1.0, 0.6], upper = [-0.8, 0.8]",
            "lower = [-1.0, 0.6, -0.2], upper = [-0.8, 0.8, -0.1]",
        )
        .replace(
            "lower = [0.9, -1.5], upper = [1.1, -1.3]",
            "lower = [0.9, -1.5, 0.0], upper = [1.1, -1.3, 0.1]",
        );
    let s = common::from_text(&text).unwrap();
    assert_eq!(s.n(), 3);
    let turning = cbfreach::reach::Turning::at_goal(&s).expect("the pair turns");
    assert_eq!(turning.frames(), 3);
    let (two, turned) = two_and_turned(&s, 3);
    let met = tubes(&turned, &s.reach.initial, true);
    assert_held(&s, &met, 3 * 48 * 150);
    let plain = tubes(&two, &s.reach.initial, true);
    for (m, p) in final_widths(&met).iter().zip(final_widths(&plain)) {
        assert!(*m < 0.7 * p, "turned {m}, two frames {p}");
    }
}

//! Soundness of the CPU reach engine in coordinates `z = T x` (docs/design.md §2.11): NN-system
//! trajectories stay in the z-boxes of scenario 2's transform, which lets its boxes shrink where
//! boxes in x cannot, and z-boxes hold the image of x-boxes.

mod common;

use cbfreach::bounds::BoundMethod;
use cbfreach::network::Mlp;
use cbfreach::reach::{
    Backend, CpuBackend, ExactField, ReachMethod, ReachProblem, ReachSettings, TimeModel,
    Transform, Tube,
};
use cbfreach::simulate::{integrate, sample_box, Integrator};
use common::{double_integrator, nn_field, small_network};

/// Runs scenario 2 with the transform the scenario asks for (`auto`) or none.
fn run_double_integrator(net: &Mlp, transform: bool, m_c: f64) -> (Vec<Tube>, Option<Transform>) {
    let s = double_integrator();
    let t = if transform {
        Transform::for_scenario(&s, &s.reach.transform).unwrap()
    } else {
        None
    };
    let problem = ReachProblem::with_transform(&s, net.clone(), m_c, t.clone())
        .unwrap()
        .with_time(TimeModel::Euler, 1);
    let settings = ReachSettings {
        bounds: BoundMethod::Crown,
        method: ReachMethod::Disturbance,
        every: 1,
        face_local: false,
        exact: ExactField::Nowhere,
        intersect_x: false,
        ..ReachSettings::default()
    };
    let boxes = &s.reach.initial[..3];
    let tubes = CpuBackend
        .reach(&problem, boxes, &settings, &|_, _| {})
        .unwrap()
        .boxes;
    (tubes, t)
}

#[test]
fn transformed_embedding_contains_nn_trajectories_in_z() {
    let s = double_integrator();
    let net = small_network(&[2, 16, 16, 1], 6, 0.05);
    let (tubes, t) = run_double_integrator(&net, true, 0.0);
    let t = t.expect("scenario 2 asks for a transform");
    let mut checks = 0;
    for tube in &tubes {
        for x0 in sample_box(&tube.initial, 12, 8) {
            let traj = integrate(
                |x: &[f64]| nn_field(&s, &net, x),
                &x0,
                s.reach.dt,
                s.reach.steps(),
                Integrator::Euler,
            );
            for sample in &tube.tube {
                let k = (sample.t / s.reach.dt + 0.5) as usize;
                let x = &traj.x[k];
                let (zl, zu) = (
                    sample.z_lower.as_ref().unwrap(),
                    sample.z_upper.as_ref().unwrap(),
                );
                for i in 0..2 {
                    // z = T x, evaluated in f64; a sound bound must hold up to that rounding.
                    let z: f64 = (0..2).map(|j| t.t[i * 2 + j] * x[j]).sum();
                    assert!(
                        zl[i] - 1e-9 <= z && z <= zu[i] + 1e-9,
                        "t = {}: z{i} = {z} ∉ [{}, {}]",
                        sample.t,
                        zl[i],
                        zu[i]
                    );
                }
                assert!(sample.filtered_set().contains(x));
                checks += 1;
            }
        }
    }
    assert!(checks > 1000);
}

#[test]
fn transform_lets_scenario_2_boxes_shrink() {
    // docs/design.md §2b: in x coordinates the box embedding of the double integrator cannot shrink.
    let net = small_network(&[2, 16, 16, 1], 6, 0.01);
    let width = |tubes: &[Tube]| -> f64 {
        tubes
            .iter()
            .map(|t| {
                let last = t.last().unwrap().filtered_set();
                last.widths().iter().fold(0.0_f64, |a, &b| a.max(b))
            })
            .fold(0.0, f64::max)
    };
    let (plain, _) = run_double_integrator(&net, false, 0.0);
    let (transformed, _) = run_double_integrator(&net, true, 0.0);
    let w0 = 0.2;
    assert!(
        plain.iter().all(|t| !t.valid()) || width(&plain) >= w0,
        "x coordinates should not contract"
    );
    assert!(transformed.iter().all(|t| t.valid()));
    assert!(
        width(&transformed) < 0.25 * w0,
        "width {}",
        width(&transformed)
    );
}

#[test]
fn z_boxes_contain_the_image_of_x_boxes() {
    let t = Transform::from_matrix(vec![0.3, 1.7, -2.2, 0.9], 2).unwrap();
    let b = cbfreach::IntervalBox::new(vec![-1.0, 0.5], vec![2.0, 0.75]).unwrap();
    let z = t.to_z_box(&b);
    for x in sample_box(&b, 200, 1) {
        let zx: Vec<f64> = (0..2)
            .map(|i| (0..2).map(|j| t.t[i * 2 + j] * x[j]).sum())
            .collect();
        assert!(z.contains(&zx));
        // And back: the parallelotope's bounding box contains x.
        assert!(t.to_x_box(&z.lower, &z.upper).contains(&x));
    }
    assert!(Transform::from_matrix(vec![1.0, 2.0, 2.0, 4.0], 2).is_err());
}

//! Unit tests of the CPU engine (`reach::cpu`).

use super::*;
use crate::network::Mlp;
use crate::reach::Transform;
use crate::scenario::Scenario;

/// With two frames, settling meets them: a frame that stepped keeps its set met with the
/// other's box in its coordinates, a frame that could not step is replaced by it, and
/// `known` is the meet of the x-boxes of the frames that stepped.
#[test]
fn settling_meets_the_frames_and_reseeds_one_that_could_not_step() {
    let problem = scenario_2_problem();
    let settings = two_frames(false);
    let report = |_: usize| {};
    let run = two_frame_run(&problem, &settings, &report);
    let initial = IntervalBox::new(vec![0.9, 1.4], vec![1.1, 1.6]).unwrap();
    let mut state = run.start(&initial);
    // The parallelotope's x-box holds the initial box; their meet is the box itself.
    assert_eq!(state.known, initial);
    assert_eq!(state.sets[1], initial);
    let z = state.sets[0].clone();
    let z_hull = problem.x_box_in_safe_set(&z.lower, &z.upper, &problem.safe_set);
    assert!(initial.is_subset_of(&z_hull) && initial != z_hull);

    // The x frame could not step: whatever its set was, it becomes the parallelotope's x-box.
    state.sets[1] = IntervalBox::new(vec![-100.0; 2], vec![100.0; 2]).unwrap();
    run.settle(&mut state, &[true, false]);
    assert_eq!(state.known, z_hull);
    assert_eq!(state.sets[1], z_hull);
    assert_eq!(state.sets[0], z);

    // Both stepped, the x-box narrower: it is `known`, and the z-box shrinks around it
    // while keeping the image of every one of its corners.
    let narrow = IntervalBox::new(vec![0.95, 1.45], vec![1.0, 1.5]).unwrap();
    state.sets[1] = narrow.clone();
    run.settle(&mut state, &[true, true]);
    assert_eq!(state.known, narrow);
    let met = &state.sets[0];
    assert!(met.is_subset_of(&z) && met.volume() < 0.5 * z.volume());
    let tm = &problem.transform.as_ref().unwrap().t;
    for x in narrow.corners() {
        let zx = [tm[0] * x[0] + tm[1] * x[1], tm[2] * x[0] + tm[3] * x[1]];
        for (i, v) in zx.into_iter().enumerate() {
            assert!(met.lower[i] - 1e-12 <= v && v <= met.upper[i] + 1e-12);
        }
    }
    let sample = run.sample(&state, 0.0);
    assert_eq!(sample.set, narrow);
}

/// Scenario 2 in its coordinates with a small random network.
fn scenario_2_problem() -> ReachProblem {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let s = Scenario::load(&dir.join("double-integrator.toml")).unwrap();
    let t = Transform::for_scenario(&s, &s.reach.transform).unwrap();
    let net = Mlp::random(&[2, 8, 1], 3);
    ReachProblem::with_transform(&s, net, 0.1, t).unwrap()
}

/// Settings that keep the sets in two frames (z and x), the network everywhere.
fn two_frames(meet_slabs: bool) -> ReachSettings {
    ReachSettings {
        bounds: crate::bounds::BoundMethod::Crown,
        exact: crate::reach::ExactField::Nowhere,
        intersect_x: true,
        meet_slabs,
        ..ReachSettings::default()
    }
}

/// The CPU engine's run of `problem` in its two frames.
fn two_frame_run<'a>(
    problem: &'a ReachProblem,
    settings: &'a ReachSettings,
    report: &'a (dyn Fn(usize) + Sync),
) -> ChunkRun<'a> {
    let frames: Vec<Frame> = problem
        .frames(settings)
        .into_iter()
        .map(|p| Frame::new(p, settings.method, false).unwrap())
        .collect();
    assert_eq!(frames.len(), 2);
    ChunkRun {
        frames,
        settings,
        every: 1,
        encloses: false,
        report,
        time: problem.time,
        steps: problem.steps,
        substeps: 1,
        h: problem.dt,
        plant: None,
        x_problem: problem,
        period: 1,
        absorb: false,
        source: None,
    }
}

/// With the slabs clipped by the other frame's sets (`meet_slabs`), a frame's slabs are
/// clipped by the other frame's whole enclosure where it has one, never by its moving box,
/// which is checked alone and may fall back to that enclosure (design §7.1 item 7): every
/// state of the other frame's enclosure lies in the half-spaces of both flowpipes (a clip by
/// the moving box, a third as wide, fails), and where a frame has only a moving box (guessed,
/// proven with every frame's together), its hull clips.
#[test]
fn slabs_are_clipped_by_the_other_frames_whole_enclosure() {
    use crate::reach::validated::MovingFaces;
    let problem = scenario_2_problem();
    let t = problem.transform.clone().unwrap();
    let settings = two_frames(true);
    let report = |_: usize| {};
    let run = two_frame_run(&problem, &settings, &report);
    let pipe = |set: IntervalBox, moving: bool| Flowpipe {
        set,
        f_lower: vec![-1.0; 2],
        f_upper: vec![1.0; 2],
        faces: moving.then(|| MovingFaces {
            lower: vec![-0.5; 2],
            upper: vec![0.5; 2],
            depth_lower: vec![0.5; 2],
            depth_upper: vec![-0.5; 2],
        }),
        enclosed: true,
        others: Vec::new(),
    };
    let x_whole = IntervalBox::new(vec![0.8, 1.3], vec![1.25, 1.75]).unwrap();
    let x_moving = IntervalBox::new(vec![0.95, 1.45], vec![1.1, 1.6]).unwrap();
    // States of an x-box, in x and in z = S⁻¹x (T x to rounding).
    let states = |x: &IntervalBox| -> Vec<([f64; 2], [f64; 2])> {
        (0..=8)
            .flat_map(|a| (0..=8).map(move |b| (a, b)))
            .map(|(a, b)| {
                let at =
                    |i: usize, k: i32| x.lower[i] + f64::from(k) / 8.0 * (x.upper[i] - x.lower[i]);
                let p = [at(0, a), at(1, b)];
                let z = [t.t[0] * p[0] + t.t[1] * p[1], t.t[2] * p[0] + t.t[3] * p[1]];
                (p, z)
            })
            .collect()
    };
    let lowest = |hs: &[SafeHalfspace], v: &[f64; 2]| {
        hs.iter()
            .map(|h| {
                (h.offset
                    + h.normal[0] * Interval::point(v[0])
                    + h.normal[1] * Interval::point(v[1]))
                .upper
            })
            .fold(f64::INFINITY, f64::min)
    };
    for guessed_only in [false, true] {
        let mut state = run.start(&x_whole);
        let z_of = |x: &IntervalBox| t.to_z_box(x);
        state.pipes = vec![
            Some(pipe(z_of(&x_moving), true)),
            Some(pipe(x_moving.clone(), true)),
        ];
        state.whole = match guessed_only {
            false => vec![
                Some(pipe(z_of(&x_whole), false)),
                Some(pipe(x_whole.clone(), false)),
            ],
            true => vec![None, None],
        };
        run.meet_pipes(&mut state);
        let other = if guessed_only { &x_moving } else { &x_whole };
        // The moving box alone would cut most of these states off.
        let moving = frame_halfspaces(Some(&t), None, &x_moving, &x_whole);
        let mut outside = 0;
        for (x, z) in states(other) {
            // Frame 0 (z) is clipped by frame 1's (x) set; frame 1 by frame 0's.
            for (f, v) in [(0, &z), (1, &x)] {
                let flowpipes = [&state.pipes[f], &state.whole[f]];
                for p in flowpipes.into_iter().flatten() {
                    assert_eq!(p.others.len(), 4);
                    assert!(lowest(&p.others, v) >= -1e-9, "frame {f}: {v:?} cut off");
                }
            }
            outside += usize::from(lowest(&moving, &z) < -1e-3);
        }
        assert!(guessed_only || outside > 40, "{outside}");
    }
}

/// `CpuBackend::continuous_step` from each step's outcome retraces the engine's own tubes
/// (scenario 1, a small network, continuous time, 20 steps, the whole set's bounds and the
/// faces'): every set equal bit for bit, every tube ending at the same step; both the common
/// path and the fallback occur.
#[test]
fn host_steps_from_a_state_retrace_the_engines_tubes() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let s = Scenario::load(&dir.join("integrator.toml")).unwrap();
    let net = Mlp::random(&[2, 12, 2], 5);
    let mut problem = ReachProblem::new(&s, net, 0.05)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    problem.steps = 20;
    let boxes: Vec<IntervalBox> = [[-2.0, 2.0], [1.0, -1.5], [2.5, 0.6], [3.5, 2.0], [0.3, 0.2]]
        .iter()
        .map(|c| IntervalBox {
            lower: c.iter().map(|v| v - 0.05).collect(),
            upper: c.iter().map(|v| v + 0.05).collect(),
        })
        .collect();
    let (mut common, mut fallback) = (0, 0);
    for face_local in [false, true] {
        let settings = ReachSettings {
            bounds: crate::bounds::BoundMethod::Forward,
            exact: crate::reach::ExactField::Nowhere,
            face_local,
            every: 1,
            ..ReachSettings::default()
        };
        let tubes = CpuBackend
            .reach(&problem, &boxes, &settings, &|_, _| {})
            .unwrap()
            .boxes;
        for (b, tube) in boxes.iter().zip(&tubes) {
            let mut state = StepState::start(b.clone());
            for k in 1..=problem.steps {
                let out = CpuBackend
                    .continuous_step(&problem, &settings, std::slice::from_ref(&state))
                    .unwrap()
                    .remove(0);
                if let Some(end) = out.end {
                    assert_eq!(end, tube.end, "{b:?}: step {k}");
                    break;
                }
                common += usize::from(out.common);
                fallback += usize::from(!out.common && k > 1);
                let sample = &tube.tube[k];
                assert_eq!(out.state.set, sample.set, "{b:?}: step {k}");
                state = out.state;
            }
        }
    }
    assert!(
        common > 100 && fallback > 0,
        "{common} common, {fallback} fallback"
    );
}

/// Where two frames are met (scenario 2 in z = T x met with x-boxes, a small network,
/// continuous time, 20 steps, face-local bounds), `HostStep::step_met` from each step's outcome
/// (both frames' states and the x-box they share, not met again first) retraces the engine's
/// own tubes: every sample equal bit for bit, every tube ending at the same step; both the
/// common path and the fallback occur. The GPU engine's host steps rest on this.
#[test]
fn host_steps_from_met_states_retrace_the_engines_tubes() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios");
    let s = Scenario::load(&dir.join("double-integrator.toml")).unwrap();
    let t = Transform::for_scenario(&s, &s.reach.transform).unwrap();
    let net = Mlp::random(&[2, 12, 1], 5);
    let mut problem = ReachProblem::with_transform(&s, net, 0.02, t)
        .unwrap()
        .with_time(TimeModel::Continuous, 1);
    problem.steps = 20;
    let settings = ReachSettings {
        bounds: crate::bounds::BoundMethod::Forward,
        exact: crate::reach::ExactField::Nowhere,
        face_local: true,
        intersect_x: true,
        every: 1,
        ..ReachSettings::default()
    };
    let frames = problem.frames(&settings);
    assert_eq!(frames.len(), 2);
    let boxes: Vec<IntervalBox> = [[-1.0, 0.5], [-1.09, 1.41], [-2.5, 1.0], [0.0, -1.0]]
        .iter()
        .map(|c| IntervalBox {
            lower: c.iter().map(|v| v - 0.05).collect(),
            upper: c.iter().map(|v| v + 0.05).collect(),
        })
        .collect();
    let tubes = CpuBackend
        .reach(&problem, &boxes, &settings, &|_, _| {})
        .unwrap()
        .boxes;
    let host = CpuBackend.host_step(&problem, &settings).unwrap();
    let (mut common, mut fallback) = (0, 0);
    for (b, tube) in boxes.iter().zip(&tubes) {
        // The engine's start: each frame's initial set met with the box around the shared
        // x-box and clipped to S.
        let method = settings.method;
        let mut sets: Vec<IntervalBox> =
            frames.iter().map(|f| f.initial_state(b, method)).collect();
        let known = frames
            .iter()
            .zip(&sets)
            .map(|(f, z)| f.x_box_in_safe_set(&z.lower, &z.upper, f.safe_set_for(method)))
            .reduce(|a, c| a.intersection(&c).unwrap_or(a))
            .unwrap();
        for (f, set) in frames.iter().zip(&mut sets) {
            *set = set
                .intersection(&f.frame_box(&known))
                .unwrap_or(set.clone());
            clip_to_safe_set(&mut set.lower, &mut set.upper, &f.safe_set_for(method).z);
        }
        assert_eq!(tube.tube[0].set, {
            let x = frames[0].x_box_in_safe_set(
                &sets[0].lower,
                &sets[0].upper,
                frames[0].safe_set_for(method),
            );
            x.intersection(&known).unwrap_or(x)
        });
        let mut state = StepState::start(sets[0].clone());
        let mut met = MetState {
            x: StepState::start(sets[1].clone()),
            known,
        };
        for k in 1..=problem.steps {
            let out = host
                .step_met(std::slice::from_ref(&state), std::slice::from_ref(&met))
                .unwrap()
                .remove(0);
            if let Some(end) = out.end {
                assert_eq!(end, tube.end, "{b:?}: step {k}");
                break;
            }
            common += usize::from(out.common);
            fallback += usize::from(!out.common && k > 1);
            let sample = out.sample.as_ref().expect("a sample");
            assert_eq!(sample.set, tube.tube[k].set, "{b:?}: step {k}");
            state = out.state;
            met = out.met.expect("the state in x");
        }
    }
    assert!(
        common > 20 && fallback > 0,
        "{common} common, {fallback} fallback"
    );
}

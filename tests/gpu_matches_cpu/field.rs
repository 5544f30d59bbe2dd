//! The field on a slab (`shaders/field.wgsl`'s `bound_on`, `form_on`) and the curved rates
//! around their barrier (`shaders/curved.wgsl`) on the device, against the CPU's
//! `validated::bound_on` and `end_rates::curved_rates` that they mirror (docs/design.md §7.4),
//! on the problem's own generated field: scenario 1 (constant `g`, one filter row), scenario 2
//! in z coordinates (two rows, a scalar input) and a system with state-dependent `g` and
//! transcendental terms.

use super::*;
use cbfreach::gpu::probe_field::{
    bound_on_device, curved_on_device, taylor_on_device, BoundCase, CurvedCase, NetCase, TaylorCase,
};
use cbfreach::reach::embedding::Dynamics;
use cbfreach::reach::{end_rates, validated};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// One problem of the tests below.
struct Problem {
    name: &'static str,
    problem: ReachProblem,
    /// As its WGSL is generated: the closed form where the filter has one, so that its binding
    /// pieces' fields are on the device.
    settings: ReachSettings,
    /// Its binding pieces (the kernels' sources 1..=pieces).
    pieces: u32,
    /// The device's bounds' distance from the CPU's, relative to the result: 4 ulp steps
    /// against the CPU's 1, through the pieces' cancelling sums near the obstacle's centre
    /// (measured 8e-12; 1e-10, issue 40's parity), or the f64 shaders' `sqrt` and `ln`
    /// evaluated in f32 and widened by its accuracy (~1e-6 relative; the CPU's are f64).
    tol: f64,
    /// Boxes are centred within `[−radius, radius]ⁿ`: the device's `sin` and `cos` are tight on
    /// `[−3, 3]` alone (`[−1, 1]` outside: sound, looser than the CPU's).
    radius: f64,
}

fn problems() -> Vec<Problem> {
    let closed = ReachSettings {
        exact: ExactField::ClosedForm,
        ..settings(ReachMethod::Disturbance)
    };
    let s1 = integrator();
    let p1 = ReachProblem::new(&s1, small_network(&[2, 16, 16, 2], 1, 0.05), 0.05).unwrap();
    let s2 = double_integrator();
    let t = Transform::for_scenario(&s2, &TransformChoice::Auto).unwrap();
    let p2 = ReachProblem::with_transform(&s2, small_network(&[2, 16, 16, 1], 2, 0.05), 0.02, t)
        .unwrap();
    let text = common::SMALL
        .replace(
            r#"f = ["y", "-x"]"#,
            r#"f = ["y + 0.1*tanh(x) - 0.05*sqrt(1 + x^2)", "-sin(x) + 0.1*cos(y) + 0.05*exp(-x*x) - 0.02*ln(2 + y)"]"#,
        )
        .replace(r#"g = [["0"], ["1"]]"#, r#"g = [["0.1*x"], ["1 + 0.2*sin(x)"]]"#);
    let s3 = common::from_text(&text).unwrap();
    let p3 = ReachProblem::new(&s3, small_network(&[2, 8, 8, 1], 9, 0.1), 0.02).unwrap();
    assert!(p3.dynamics.g_constant.is_none());
    let rows = |p: &ReachProblem| p.pieces.slack_rows().len() as u32;
    let (r1, r2) = (rows(&p1), rows(&p2));
    let problem = |name, problem, settings, pieces, tol, radius| Problem {
        name,
        problem,
        settings,
        pieces,
        tol,
        radius,
    };
    vec![
        problem("scenario 1", p1, closed.clone(), r1, 1e-10, 4.0),
        problem("scenario 2", p2, closed, r2, 1e-10, 4.0),
        problem(
            "state-dependent g",
            p3,
            settings(ReachMethod::Disturbance),
            0,
            1e-5,
            1.5,
        ),
    ]
}

/// Random bounds of a network with `m` outputs on a box of `n` states: slopes up to ±2, the
/// upper form above the lower, offsets and values up to ±5.
fn net_case(rng: &mut ChaCha8Rng, n: usize, m: usize) -> NetCase {
    let pair = |r: &mut ChaCha8Rng, k: usize, s: f64| -> (Vec<f64>, Vec<f64>) {
        (0..k)
            .map(|_| {
                let a = r.random_range(-s..s);
                (a, a + r.random_range(0.0..0.5 * s))
            })
            .unzip()
    };
    let (a_lower, a_upper) = pair(rng, m * n, 2.0);
    let (b_lower, b_upper) = pair(rng, m, 5.0);
    let (lower, upper) = pair(rng, m, 5.0);
    NetCase {
        a_lower,
        a_upper,
        b_lower,
        b_upper,
        lower,
        upper,
    }
}

/// The zero network (a piece's own field: `v` is the piece's closed form).
fn zero_net(n: usize, m: usize) -> NetCase {
    NetCase {
        a_lower: vec![0.0; m * n],
        a_upper: vec![0.0; m * n],
        b_lower: vec![0.0; m],
        b_upper: vec![0.0; m],
        lower: vec![0.0; m],
        upper: vec![0.0; m],
    }
}

/// The CPU's field for a source as the kernels number them: the network's system (0) or
/// binding piece `piece − 1`'s field.
fn dynamics_of(problem: &ReachProblem, piece: u32) -> &Dynamics {
    match piece {
        0 => &problem.dynamics,
        k => &problem.pieces.binding_field(k as usize - 1).dynamics,
    }
}

/// A random box of `n` states around a point of `[−radius, radius]ⁿ`, each side 0, 1e-7 or up
/// to 1 wide (a slab's i-th side is as wide as any).
fn random_box(rng: &mut ChaCha8Rng, n: usize, radius: f64) -> IntervalBox {
    let (lower, upper) = (0..n)
        .map(|_| {
            let c = rng.random_range(-radius..radius);
            let w = match rng.random_range(0..4) {
                0 => 0.0,
                1 => 1e-7,
                _ => rng.random_range(0.0..1.0),
            };
            (c - 0.5 * w, c + 0.5 * w)
        })
        .unzip();
    IntervalBox { lower, upper }
}

/// `[a, b]` holds `[c, d]` up to `slack`, and each end is within `tol` of the other's.
fn holds_near(dev: (f64, f64), cpu: (f64, f64), slack: f64, tol: f64) -> bool {
    dev.0 <= cpu.0 + slack
        && cpu.1 <= dev.1 + slack
        && (dev.0 - cpu.0).abs() <= tol
        && (dev.1 - cpu.1).abs() <= tol
}

/// A rate of the device beside the CPU's: outside it (above an upper end, below a lower one) or
/// inside by at most its rounding (`1e-13` of `scale`), and within `tol` of `scale`.
fn rate_outside_near(cpu: f64, dev: f64, up: bool, scale: f64, tol: f64) -> bool {
    let outside = if up { dev >= cpu } else { dev <= cpu };
    (outside || (dev - cpu).abs() <= 1e-13 * scale) && (dev - cpu).abs() <= tol * scale
}

/// `shaders/field.wgsl`'s `bound_on` (the slab form `form_on` about the box's centre, every
/// offset an interval) against `validated::bound_on` on 3 × 3,000 random boxes and ends per
/// problem, with random network bounds and margins for the network's system and zero ones for
/// each binding piece of the filter: where the CPU's bound is finite the device's is, holds the
/// CPU's, and is within the problem's tolerance of the magnitudes involved.
#[test]
fn slab_field_matches_the_cpus_bound_on() {
    let Some(g) = gpu_f64() else { return };
    let mut finite = 0;
    for Problem {
        name,
        problem,
        settings: st,
        pieces,
        tol,
        radius,
    } in problems()
    {
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let mut rng = ChaCha8Rng::seed_from_u64(4000 + n as u64 + u64::from(pieces));
        let cases: Vec<BoundCase> = (0..3000)
            .map(|k| {
                let piece = (k % (pieces as usize + 1)) as u32;
                let (nn, margin) = match piece {
                    0 => (net_case(&mut rng, n, m), rng.random_range(0.0..0.5)),
                    _ => (zero_net(n, m), 0.0),
                };
                BoundCase {
                    set: random_box(&mut rng, n, radius),
                    i: rng.random_range(0..n),
                    upper: rng.random_bool(0.5),
                    piece,
                    nn,
                    margin,
                }
            })
            .collect();
        let dev = bound_on_device(g.context(), &problem, &st, &cases).unwrap();
        let mut here = 0;
        for (c, d) in cases.iter().zip(&dev) {
            let dynamics = dynamics_of(&problem, c.piece);
            let margins = vec![c.margin; m];
            let (lo, hi) = (&c.set.lower, &c.set.upper);
            let cpu = validated::bound_on(dynamics, lo, hi, c.i, c.upper, c.nn.as_ref(), &margins);
            if !(cpu.lower.is_finite() && cpu.upper.is_finite()) {
                continue;
            }
            here += 1;
            let scale = 1.0 + cpu.lower.abs().max(cpu.upper.abs());
            assert!(
                holds_near(*d, (cpu.lower, cpu.upper), 1e-15 * scale, tol * scale),
                "{name}: {c:?}: cpu {cpu:?}, device {d:?}"
            );
        }
        eprintln!("{name}: {here} of {} bounds finite", cases.len());
        assert!(here >= 2000, "{name}: {here} finite");
        finite += here;
    }
    assert!(finite >= 6000);
}

/// `shaders/curved.wgsl`'s `curved_end` at every end of a guessed moving box (`guessed` of
/// `shaders/validated.wgsl`) against `end_rates::curved_rates` on the box `validated::guessed`
/// makes, on 2,000 random steps per problem: sets up to 1 wide, steps of 0.004 to 0.04, last
/// rates up to ±15 with and without the step before, random network bounds on each slab (zero
/// for the pieces). The same ends are reached; where they are, the device's rate is outside the
/// CPU's by at most its rounding (upper ends above, lower below) and within the tolerance.
#[test]
fn curved_rates_match_the_cpus() {
    let Some(g) = gpu_f64() else { return };
    let mut reached = 0;
    for Problem {
        name,
        problem,
        settings: st,
        pieces,
        tol,
        radius,
    } in problems()
    {
        let (n, m) = (problem.dynamics.n, problem.dynamics.m);
        let mut rng = ChaCha8Rng::seed_from_u64(5000 + n as u64 + u64::from(pieces));
        let cases: Vec<CurvedCase> = (0..2000)
            .map(|k| {
                let piece = (k % (pieces as usize + 1)) as u32;
                let set = random_box(&mut rng, n, radius);
                let rate = |r: &mut ChaCha8Rng| r.random_range(-15.0..15.0);
                let rl: Vec<f64> = (0..n).map(|_| rate(&mut rng)).collect();
                let ru: Vec<f64> = rl.iter().map(|l| l + rng.random_range(0.0..2.0)).collect();
                let before = rng.random_bool(0.6).then(|| {
                    let l: Vec<f64> = rl.iter().map(|v| v + rng.random_range(-1.0..1.0)).collect();
                    let u: Vec<f64> = ru.iter().map(|v| v + rng.random_range(-1.0..1.0)).collect();
                    (l, u)
                });
                let (nn, margin) = match piece {
                    0 => (
                        (0..2 * n).map(|_| net_case(&mut rng, n, m)).collect(),
                        rng.random_range(0.0..0.5),
                    ),
                    _ => (vec![zero_net(n, m); 2 * n], 0.0),
                };
                CurvedCase {
                    set,
                    h: [0.04, 0.01, 0.004][rng.random_range(0..3)],
                    rates: (rl, ru),
                    before,
                    piece,
                    nn,
                    margin,
                }
            })
            .collect();
        let dev = curved_on_device(g.context(), &problem, &st, &cases).unwrap();
        let (mut ends, mut missed) = (0, 0);
        for (c, d) in cases.iter().zip(&dev) {
            let b = c.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
            let pipe = validated::guessed(&c.set, c.h, (&c.rates.0, &c.rates.1), b);
            assert_eq!(pipe.is_some(), d.is_some(), "{name}: {c:?}: guess accepted");
            let (Some(pipe), Some((dl, du))) = (pipe, d) else {
                continue;
            };
            let dynamics = dynamics_of(&problem, c.piece);
            let margins = vec![c.margin; m];
            let nn = |i: usize, up: bool| c.nn[2 * i + usize::from(up)].as_ref();
            let (cl, cu) = end_rates::curved_rates(dynamics, &c.set, &pipe, c.h, nn, &margins);
            for i in 0..n {
                for (cpu, dev, up) in [(cl[i], dl[i], false), (cu[i], du[i], true)] {
                    assert_eq!(
                        cpu.is_finite(),
                        dev.is_finite(),
                        "{name}: {c:?}: end ({i}, {up}): cpu {cpu}, device {dev}"
                    );
                    if !cpu.is_finite() {
                        missed += 1;
                        continue;
                    }
                    ends += 1;
                    let scale = 1.0 + cpu.abs() + c.rates.0[i].abs().max(c.rates.1[i].abs());
                    assert!(
                        rate_outside_near(cpu, dev, up, scale, tol),
                        "{name}: {c:?}: end ({i}, {up}): cpu {cpu}, device {dev}"
                    );
                }
            }
        }
        eprintln!("{name}: {ends} ends reached, {missed} not");
        assert!(
            ends >= 1000 && missed >= 50,
            "{name}: {ends} reached, {missed} not"
        );
        reached += ends;
    }
    assert!(reached >= 3000);
}

/// `shaders/slab_step.wgsl`'s `piece_taylor2` and `piece_taylor3` (the problem's generated
/// `G = DΦ·Φ` and `DG`) against `end_rates::taylor_rates` and `end_rates::taylor3_rates`
/// (their meet, the engine's, is in continuous.rs's run parity), on 2,000 random steps
/// per problem and each piece of its filter: sets up to 1 wide, hulls up to 0.5 beyond them,
/// steps of 0.004 to 0.2 (the large ones fail the monotonicity checks), field bounds up to ±15.
/// The same forms are refused; where not, every rate lies outside the CPU's by at most its
/// rounding and within the problem's tolerance.
#[test]
fn taylor_rates_match_the_cpus() {
    let Some(g) = gpu_f64() else { return };
    let mut compared = 0;
    for Problem {
        name,
        problem,
        settings: st,
        pieces,
        tol,
        radius,
    } in problems()
    {
        assert_eq!(problem.time, TimeModel::Continuous, "{name}");
        let st = ReachSettings {
            taylor3: true,
            ..st
        };
        let n = problem.dynamics.n;
        let mut rng = ChaCha8Rng::seed_from_u64(6000 + n as u64 + u64::from(pieces));
        let cases: Vec<TaylorCase> = (0..2000)
            .map(|k| {
                let set = random_box(&mut rng, n, radius);
                let mut grow = |x: &[f64], s: f64| -> Vec<f64> {
                    x.iter()
                        .map(|v| v + s * rng.random_range(0.0..0.5))
                        .collect()
                };
                let hull = IntervalBox {
                    lower: grow(&set.lower, -1.0),
                    upper: grow(&set.upper, 1.0),
                };
                let pair = |r: &mut ChaCha8Rng| -> (Vec<f64>, Vec<f64>) {
                    (0..n)
                        .map(|_| {
                            let l = r.random_range(-15.0..15.0);
                            (l, l + r.random_range(0.0..3.0))
                        })
                        .unzip()
                };
                TaylorCase {
                    set,
                    hull,
                    h: [0.2, 0.04, 0.01, 0.004][rng.random_range(0..4)],
                    piece: (k % (pieces as usize + 1)) as u32,
                    over: pair(&mut rng),
                    euler: pair(&mut rng),
                }
            })
            .collect();
        let clock = std::time::Instant::now();
        let dev = taylor_on_device(g.context(), &problem, &st, &cases).unwrap();
        let secs = clock.elapsed().as_secs_f64();
        let (mut ends, mut refused) = ([0; 2], [0; 2]);
        for (c, d) in cases.iter().zip(&dev) {
            let dynamics = dynamics_of(&problem, c.piece);
            let pipe = validated::Flowpipe {
                set: c.hull.clone(),
                f_lower: c.over.0.clone(),
                f_upper: c.over.1.clone(),
                faces: None,
                enclosed: true,
                others: Vec::new(),
            };
            let first = end_rates::taylor_rates(dynamics, &c.set, &pipe, c.h, c.euler.clone());
            let third = end_rates::taylor3_rates(dynamics, &c.set, &pipe, c.h, c.euler.clone());
            let forms = [(&first, &d.first), (&third, &d.third)];
            for (k, (cpu, dev)) in forms.into_iter().enumerate() {
                assert_eq!(
                    cpu.is_some(),
                    dev.is_some(),
                    "{name}: {c:?}: form {k} refused"
                );
                let (Some((cl, cu)), Some((dl, du))) = (cpu, dev) else {
                    refused[k] += 1;
                    continue;
                };
                ends[k] += 1;
                for i in 0..n {
                    for (cpu, dev, up) in [(cl[i], dl[i], false), (cu[i], du[i], true)] {
                        assert!(
                            rate_outside_near(cpu, dev, up, 1.0 + cpu.abs(), tol),
                            "{name}: {c:?}: form {k}, end ({i}, {up}): cpu {cpu}, device {dev}"
                        );
                    }
                }
            }
        }
        eprintln!(
            "{name}: first, second order: {ends:?} compared, {refused:?} refused \
             ({secs:.1} s on the device)"
        );
        assert!(
            ends.iter().all(|&e| e >= 500) && refused[1] >= 20,
            "{name}: {ends:?} compared, {refused:?} refused"
        );
        compared += ends[1];
    }
    assert!(compared >= 3000);
}

/// The slab form, the curved rates and the step (with and without `taylor3`) compile with the
/// f32 prelude for each problem (the engine builds every kernel in both; the tests above run
/// f64 alone).
#[test]
fn field_shaders_compile_in_f32() {
    let Some(g) = gpu() else { return };
    for p in problems() {
        let clock = std::time::Instant::now();
        // With `taylor3` the step also reads the generated `G` and `DG`.
        for taylor3 in [false, true] {
            let st = ReachSettings {
                taylor3,
                ..p.settings.clone()
            };
            cbfreach::gpu::probe_field::field_compiles_in_f32(g.context(), &p.problem, &st)
                .unwrap_or_else(|e| panic!("{} (taylor3 {taylor3}): {e}", p.name));
        }
        eprintln!(
            "{}: compiled in {:.1} s",
            p.name,
            clock.elapsed().as_secs_f64()
        );
    }
}

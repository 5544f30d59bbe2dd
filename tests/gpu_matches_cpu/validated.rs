//! The continuous step's guessed moving box on the device (`shaders/validated.wgsl`) against the
//! CPU's `validated` that it mirrors (docs/design.md §7.4), primitive by primitive.

use super::*;
use cbfreach::gpu::probe::{guessed_on_device, GuessCase};
use cbfreach::reach::embedding::embedding_step;
use cbfreach::reach::validated::{self, Flowpipe};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// A value the device's outward steps may move by (4 ulp a step, a few steps: 1e-13 relative of
/// the numbers involved), on top of the one ulp by which a driver's fused multiply–add may change
/// the guess's trend `2r − r_before`.
const GUESS_TOL: f64 = 1e-13;

/// Random steps in 1, 2 and 3 states: sets of widths from 0 to 1, steps of 0.004 to 0.04, last
/// steps' rates up to ±15 (the paper's scenarios move at up to 15) with and without the step
/// before, some contracting so fast that the guess turns the box inside out; rates on the slabs
/// a little inside or outside each guessed face, second-order rates that bind or not.
fn cases(n: usize, count: usize, seed: u64) -> Vec<GuessCase> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut out = Vec::with_capacity(count);
    for _ in 0..count {
        let width = match rng.random_range(0..4) {
            0 => 0.0,
            1 => 1e-7,
            _ => rng.random_range(0.0..1.0),
        };
        let centre: Vec<f64> = (0..n).map(|_| rng.random_range(-4.0..4.0)).collect();
        let set = IntervalBox {
            lower: centre.iter().map(|c| c - 0.5 * width).collect(),
            upper: centre.iter().map(|c| c + 0.5 * width).collect(),
        };
        let h = [0.04, 0.01, 0.04 / 3.0, 0.004][rng.random_range(0..4)];
        let rate = |r: &mut ChaCha8Rng| r.random_range(-15.0..15.0);
        let rl: Vec<f64> = (0..n).map(|_| rate(&mut rng)).collect();
        let ru: Vec<f64> = (0..n)
            .map(|i| match rng.random_bool(0.5) {
                // A set that grows or drifts: the upper rate a little above the lower.
                true => rl[i] + rng.random_range(0.0..2.0),
                false => rate(&mut rng),
            })
            .collect();
        let before = rng.random_bool(0.6).then(|| {
            let jitter = |v: &[f64], r: &mut ChaCha8Rng| -> Vec<f64> {
                v.iter().map(|x| x + r.random_range(-1.0..1.0)).collect()
            };
            (jitter(&rl, &mut rng), jitter(&ru, &mut rng))
        });
        let b = before.as_ref().map(|(l, u)| (&l[..], &u[..]));
        let pipe = validated::guessed(&set, h, (&rl, &ru), b);
        // Slab rates near the guessed faces: inside by 1e-6 to 1e-4 relative (the check
        // passes), or outside on a fifth of the faces.
        let near = |s: f64, inward: f64, r: &mut ChaCha8Rng| {
            let gap = r.random_range(1e-6..1e-4) * (1.0 + s.abs());
            match r.random_bool(0.9) {
                true => s + inward * gap,
                false => s - inward * gap,
            }
        };
        let (dl, du): (Vec<f64>, Vec<f64>) = match &pipe {
            Some(p) => {
                let m = p.faces.as_ref().unwrap();
                (0..n)
                    .map(|i| {
                        let l = near(m.lower[i], 1.0, &mut rng);
                        (l, near(m.upper[i], -1.0, &mut rng))
                    })
                    .unzip()
            }
            None => (0..n).map(|i| (rl[i], ru[i])).unzip(),
        };
        let (cl, cu): (Vec<f64>, Vec<f64>) = (0..n)
            .map(|i| match rng.random_bool(0.5) {
                true => (-1e300, 1e300),
                false => (
                    dl[i] + rng.random_range(-0.5..0.5),
                    du[i] + rng.random_range(-0.5..0.5),
                ),
            })
            .unzip();
        out.push(GuessCase {
            set,
            h,
            rates: (rl, ru),
            before,
            slab_rates: (dl, du),
            curved: (cl, cu),
            other: None,
        });
    }
    out
}

/// The CPU engine's step end on a proven moving box (reach/cpu.rs): the slab rates clamped to
/// the depths, met with the second-order rates, the Euler step, the meet with the hull.
fn cpu_end(c: &GuessCase, pipe: &Flowpipe) -> IntervalBox {
    let (mut dl, mut du) = c.slab_rates.clone();
    validated::clamp_to_depths(pipe, &mut dl, &mut du);
    for i in 0..dl.len() {
        dl[i] = dl[i].max(c.curved.0[i]);
        du[i] = du[i].min(c.curved.1[i]);
    }
    let mut end = c.set.clone();
    embedding_step(&mut end.lower, &mut end.upper, &dl, &du, c.h);
    validated::meet_with_pipe(&mut end.lower, &mut end.upper, pipe);
    end
}

/// `shaders/validated.wgsl`'s `guessed`, `slab`, `verified` and `slab_step_end` against
/// `validated::guessed`, `slabs`, `verified` and the CPU engine's step end (`clamp_to_depths`,
/// the meet with the second-order rates, `embedding_step`, `meet_with_pipe`) on 3 × 4,000 random
/// steps (`cases`), f64: the same guesses accepted and refused, the same verdicts; the faces'
/// rates, hulls, slabs and ends equal to `GUESS_TOL` of the numbers involved, and where the
/// device's guess is the CPU's bit for bit (no fused trend) the device's hull, slabs and end
/// contain the CPU's (it rounds outward by more).
#[test]
fn guessed_moving_box_matches_the_cpus_validated_step() {
    let Some(g) = gpu_f64() else { return };
    let (mut refused, mut proven, mut failed, mut bitwise) = (0, 0, 0, 0);
    for n in 1..=3 {
        let cases = cases(n, 4000, 36 + n as u64);
        let dev = guessed_on_device(g.context(), n, &cases).unwrap();
        assert_eq!(dev.len(), cases.len());
        for (k, (c, d)) in cases.iter().zip(&dev).enumerate() {
            let b = c.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
            let cpu = validated::guessed(&c.set, c.h, (&c.rates.0, &c.rates.1), b);
            let what = format!("n = {n}, case {k}: {c:?}");
            assert_eq!(cpu.is_some(), d.ok, "{what}: accepted");
            let Some(pipe) = cpu else {
                refused += 1;
                continue;
            };
            let m = pipe.faces.as_ref().unwrap();
            let rate_scale = 1.0
                + [&c.rates.0, &c.rates.1]
                    .into_iter()
                    .chain(c.before.as_ref().map(|(l, u)| [l, u]).into_iter().flatten())
                    .flatten()
                    .fold(0.0_f64, |a, v| a.max(v.abs()));
            let near = |a: f64, b: f64, scale: f64| (a - b).abs() <= GUESS_TOL * scale;
            let pairs = [
                (&m.lower, &d.faces.lower),
                (&m.upper, &d.faces.upper),
                (&m.depth_lower, &d.faces.depth_lower),
                (&m.depth_upper, &d.faces.depth_upper),
            ];
            for (cv, dv) in pairs {
                for i in 0..n {
                    assert!(
                        near(cv[i], dv[i], rate_scale),
                        "{what}: rates {m:?} vs {:?}",
                        d.faces
                    );
                }
            }
            let same_guess = m == &d.faces;
            bitwise += usize::from(same_guess);
            let set_scale = c.set.lower.iter().chain(&c.set.upper);
            let scale = 1.0 + set_scale.fold(0.0_f64, |a, v| a.max(v.abs())) + c.h * rate_scale;
            let check = |cb: (&[f64], &[f64]), db: (&[f64], &[f64]), name: &str| {
                assert_near_box(cb, db, scale, same_guess, &format!("{what}: {name}"));
            };
            check(
                (&pipe.set.lower, &pipe.set.upper),
                (&d.hull.lower, &d.hull.upper),
                "hull",
            );
            let slabs: Vec<_> = validated::slabs(&c.set, &pipe, c.h).collect();
            assert_eq!(slabs.len(), d.slabs.len());
            for (cs, ds) in slabs.iter().zip(&d.slabs) {
                check((&cs.0, &cs.1), (&ds.0, &ds.1), "slab");
            }
            let holds = validated::verified(&pipe, (&c.slab_rates.0, &c.slab_rates.1));
            assert_eq!(holds, d.verified, "{what}: verified");
            if holds {
                proven += 1;
            } else {
                failed += 1;
            }
            let end = cpu_end(c, &pipe);
            check(
                (&end.lower, &end.upper),
                (&d.end.lower, &d.end.upper),
                "end",
            );
        }
    }
    eprintln!(
        "guessed: {refused} refused, {proven} proven, {failed} failed; {bitwise} guesses bit for bit"
    );
    assert!(refused >= 300 && proven >= 1000 && failed >= 1000);
}

/// `shaders/end_rates.wgsl`'s `barrier` (the curved rates' quadratic barrier) against
/// `end_rates::barrier` on 3 × 4,000 random upper ends in 1–3 states: slopes up to ±10 off the
/// diagonal and down to −60 on it, one case in ten from `2/h` to `2/h + 25` (no barrier) and, in
/// 2–3 states, one from `1/h` to `2/h` (the fixed point without its closed form), offsets
/// of sets up to 1 wide, rates up to ±15, slabs' floors none, 0 or down to −15 (at least 1,000
/// cases where the floor raises `a`). The same ends settle; where they do the device's rate
/// is at least the CPU's (it rounds up by more, and settles no earlier) and within `GUESS_TOL`
/// of the numbers involved, and its `[w̲, w̄]` too.
#[test]
fn curved_rates_barrier_matches_the_cpus() {
    use cbfreach::gpu::probe::{barrier_on_device, BarrierCase};
    use cbfreach::reach::end_rates::barrier;
    let Some(g) = gpu_f64() else { return };
    let (mut settled, mut unsettled, mut raised) = (0, 0, 0);
    for n in 1..=3 {
        let mut rng = ChaCha8Rng::seed_from_u64(400 + n as u64);
        let ends = |r: &mut ChaCha8Rng, lo: f64, hi: f64, w: f64| {
            let a = r.random_range(lo..hi);
            (a, a + r.random_range(0.0..w))
        };
        let cases: Vec<BarrierCase> = (0..4000)
            .map(|_| {
                let i = rng.random_range(0..n);
                let h = [0.04, 0.01, 0.004][rng.random_range(0..3)];
                // One case in ten grows in xᵢ about as fast as `2/h` or faster: past it no `b`
                // settles. One in ten between `1/h` and `2/h`: there the fixed point has no
                // closed form (`h·k/2 > 1/2`) and the four rounds alone decide, on both. Not in
                // one state: with `q = 0` and `a` raised to a floor of 0 the CPU's `b` is an exact
                // 0 that settles, while the device's rounding pads 0 to the least normal number
                // and the rounds creep up from there (it then gives no second-order rate: sound).
                let k_i = match rng.random_range(0..10) {
                    0 => ends(&mut rng, 2.0 / h, 2.0 / h + 20.0, 5.0),
                    1 if n > 1 => ends(&mut rng, 1.0 / h, 2.0 / h - 1.0, 1.0),
                    _ => ends(&mut rng, -60.0, 5.0, 5.0),
                };
                let k = (0..n)
                    .map(|j| match j == i {
                        true => k_i,
                        false => ends(&mut rng, -10.0, 10.0, 5.0),
                    })
                    .collect();
                let d = (0..n)
                    .map(|_| {
                        let w = rng.random_range(0.0..1.0);
                        (-0.5 * w, 0.5 * w)
                    })
                    .collect();
                let a = (0..n).map(|_| ends(&mut rng, -15.0, 15.0, 3.0)).collect();
                BarrierCase {
                    c: rng.random_range(-15.0..15.0),
                    k,
                    d,
                    a,
                    i,
                    h,
                    // None, a slab starting at the end, one reaching below it.
                    floor: [-1e300, 0.0, rng.random_range(-15.0..0.0)][rng.random_range(0..3)],
                }
            })
            .collect();
        let dev = barrier_on_device(g.context(), n, &cases).unwrap();
        for (c, d) in cases.iter().zip(&dev) {
            let others = (0..n)
                .filter(|&j| j != c.i)
                .map(|j| (c.k[j], c.d[j], c.a[j]));
            let cpu = barrier(c.c, others.clone(), c.k[c.i], c.h, c.floor);
            raised += usize::from(cpu != barrier(c.c, others, c.k[c.i], c.h, -1e300));
            assert_eq!(
                cpu.is_some(),
                d.is_some(),
                "{c:?}: cpu {cpu:?}, device {d:?}"
            );
            let (Some(cpu), Some(d)) = (cpu, d) else {
                unsettled += 1;
                continue;
            };
            settled += 1;
            let scale = 1.0
                + c.c.abs()
                + (0..n)
                    .map(|j| {
                        let k = c.k[j].0.abs().max(c.k[j].1.abs());
                        k * (1.0 + c.a[j].0.abs().max(c.a[j].1.abs()))
                    })
                    .sum::<f64>();
            let near = |x: f64, y: f64| (x - y).abs() <= GUESS_TOL * scale;
            assert!(d.0 >= cpu.0, "{c:?}: device {d:?} below cpu {cpu:?}");
            assert!(
                near(cpu.0, d.0) && near(cpu.1, d.1) && near(cpu.2, d.2),
                "{c:?}: cpu {cpu:?}, device {d:?}"
            );
        }
    }
    eprintln!("barrier: {settled} settled, {unsettled} not, {raised} raised to their floor");
    assert!(settled >= 6000 && unsettled >= 300 && raised >= 1000);
}

/// The same shaders compile with the f32 prelude (the engine builds every kernel in both; the
/// tests above run f64 alone).
#[test]
fn validated_shaders_compile_in_f32() {
    let Some(g) = gpu() else { return };
    cbfreach::gpu::probe::validated_compiles_in_f32(g.context()).unwrap();
}

/// `shaders/validated.wgsl`'s slabs clipped by another frame's set (`clip_by_other`,
/// `meet_slabs`) against `validated::slab` with the half-spaces of `safe_set::frame_halfspaces`,
/// on 2 × 2 × 1,500 random guessed steps in 2 and 3 states, with a transform in this frame and
/// x in the other and the other way round (its `ρ` raised so that the pad counts): the other
/// frame's set is its image of the guessed hull with each side moved in by up to 40 % of its
/// width (one case in ten out, past the hull: no meet, the slab stays whole), over an x-box
/// around the hull. The device's clipped slabs are the CPU's to `GUESS_TOL` of the numbers
/// involved and hold them where the guess is the CPU's bit for bit; at least a third of the
/// slabs are clipped (a clip that did nothing, or too much, fails).
#[test]
fn slabs_clipped_by_another_frame_match_the_cpus() {
    use cbfreach::gpu::probe::{guessed_on_device, OtherSet};
    use cbfreach::reach::safe_set::{frame_halfspaces, frame_rows, frame_slack};
    use cbfreach::reach::Transform;
    let Some(g) = gpu_f64() else { return };
    let (mut slabs_seen, mut clipped) = (0, 0);
    for n in 2..=3 {
        let mut rng = ChaCha8Rng::seed_from_u64(700 + n as u64);
        // A well-conditioned rotation-and-shear, and ρ far above its rounding.
        let mut t_mat: Vec<f64> = (0..n * n)
            .map(|e| {
                if e / n == e % n {
                    1.0
                } else {
                    rng.random_range(-0.6..0.6)
                }
            })
            .collect();
        t_mat[1] += 0.8;
        let t = Transform {
            rho: 1e-3,
            ..Transform::from_matrix(t_mat, n).unwrap()
        };
        for (this, other) in [(Some(&t), None), (None, Some(&t))] {
            let rows = frame_rows(this, other, n);
            // The other frame's coordinates of a box of this frame's.
            let image = |b: &IntervalBox| {
                let x = this.map_or_else(|| b.clone(), |t| t.to_x_box(&b.lower, &b.upper));
                other.map_or(x.clone(), |t| t.to_z_box(&x))
            };
            let mut cases = cases(n, 1500, 710 + n as u64);
            let mut known = Vec::new();
            for c in &mut cases {
                let b = c.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
                let hull = validated::guessed(&c.set, c.h, (&c.rates.0, &c.rates.1), b)
                    .map_or(c.set.clone(), |p| p.set);
                let x_box =
                    this.map_or_else(|| hull.clone(), |t| t.to_x_box(&hull.lower, &hull.upper));
                let mut set = image(&hull);
                let away = rng.random_bool(0.1);
                for r in 0..n {
                    let w = set.upper[r] - set.lower[r];
                    if away && r == 0 {
                        set.lower[r] = set.upper[r] + 0.1 * w + 1e-3;
                        set.upper[r] = set.lower[r] + w;
                        continue;
                    }
                    set.lower[r] += rng.random_range(0.0..0.4) * w;
                    set.upper[r] -= rng.random_range(0.0..0.4) * w;
                }
                c.other = Some(OtherSet {
                    rows: rows.clone(),
                    set,
                    pad: frame_slack(other, &x_box),
                });
                known.push(x_box);
            }
            let dev = guessed_on_device(g.context(), n, &cases).unwrap();
            for (k, ((c, d), x_box)) in cases.iter().zip(&dev).zip(&known).enumerate() {
                let b = c.before.as_ref().map(|(l, u)| (&l[..], &u[..]));
                let Some(mut pipe) = validated::guessed(&c.set, c.h, (&c.rates.0, &c.rates.1), b)
                else {
                    assert!(!d.ok, "n = {n}, case {k}: accepted");
                    continue;
                };
                let unclipped: Vec<_> = validated::slabs(&c.set, &pipe, c.h).collect();
                let o = c.other.as_ref().unwrap();
                pipe.others = frame_halfspaces(this, other, &o.set, x_box);
                let same_guess = pipe.faces.as_ref() == Some(&d.faces);
                let scale = 1.0
                    + [&pipe.set.lower, &pipe.set.upper, &o.set.lower, &o.set.upper]
                        .into_iter()
                        .flatten()
                        .fold(0.0_f64, |a, v| a.max(v.abs()));
                let what = format!("n = {n}, {this:?} / {other:?}, case {k}: {c:?}");
                for ((cs, ds), un) in validated::slabs(&c.set, &pipe, c.h)
                    .zip(&d.slabs)
                    .zip(&unclipped)
                {
                    slabs_seen += 1;
                    clipped += usize::from(&cs != un);
                    let slab = format!("{what}: slab");
                    assert_near_box((&cs.0, &cs.1), (&ds.0, &ds.1), scale, same_guess, &slab);
                }
            }
        }
    }
    eprintln!("clipped slabs: {clipped} of {slabs_seen} clipped");
    assert!(
        3 * clipped >= slabs_seen && clipped < slabs_seen,
        "{clipped} of {slabs_seen}"
    );
}

/// A box the device computed (`db`) against the CPU's (`cb`): each end within `GUESS_TOL` of
/// `scale`, and where `holds` (the device's inputs are the CPU's bit for bit, so its outward
/// steps only widen) the device's box contains the CPU's.
fn assert_near_box(
    cb: (&[f64], &[f64]),
    db: (&[f64], &[f64]),
    scale: f64,
    holds: bool,
    what: &str,
) {
    let near = |a: f64, b: f64| (a - b).abs() <= GUESS_TOL * scale;
    for i in 0..cb.0.len() {
        assert!(
            near(cb.0[i], db.0[i]) && near(cb.1[i], db.1[i]),
            "{what} cpu {cb:?} device {db:?}"
        );
        if holds {
            assert!(
                db.0[i] <= cb.0[i] && cb.1[i] <= db.1[i],
                "{what} device {db:?} does not contain cpu {cb:?}"
            );
        }
    }
}
